"""Load histories of the punch: displacement ramps and measured force histories."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["LoadHistory", "ramp_history", "read_force_history"]


@dataclass
class LoadHistory:
    control: str          # "displacement" or "force"
    time: np.ndarray      # s, starts at 0
    value: np.ndarray     # m (depth, positive into the tissue) or N (force, compressive)

    def describe(self) -> dict:
        return {"control": self.control, "n_frames": int(len(self.time)),
                "duration_s": float(self.time[-1]), "peak": float(np.max(np.abs(self.value)))}


def ramp_history(depth, rate, steps=None, frames=None, unload=True, hold=0.0) -> LoadHistory:
    """Displacement ramp 0 -> depth at `rate` (m/s), optional hold, then back to 0.

    Either `steps` (equal steps per ramp, so the peak is a frame) or `frames` (number of
    equally spaced frames over the whole history, t = 0 included) sets the sampling.
    """
    if not depth > 0 or not rate > 0:
        raise ValueError(f"depth and rate must be positive (got depth={depth}, rate={rate})")
    if (steps is None) == (frames is None):
        raise ValueError("give exactly one of steps (per ramp) or frames (whole history)")
    if hold < 0:
        raise ValueError(f"hold must be >= 0 s (got {hold})")
    t_ramp = depth / rate
    t_end = t_ramp + hold + (t_ramp if unload else 0.0)

    def d_of_t(t):
        d = np.minimum(t, t_ramp) * rate
        if unload:
            d = np.where(t > t_ramp + hold, np.maximum(depth - (t - t_ramp - hold) * rate, 0.0), d)
        return np.clip(d, 0.0, depth)

    if steps is not None:
        steps = int(steps)
        if steps < 1:
            raise ValueError(f"steps must be >= 1 (got {steps})")
        t = list(np.linspace(0.0, t_ramp, steps + 1))
        if hold > 0:
            t += list(t_ramp + np.linspace(0.0, hold, max(2, int(round(steps * hold / t_ramp)) + 1))[1:])
        if unload:
            t += list(t_ramp + hold + np.linspace(0.0, t_ramp, steps + 1)[1:])
        t = np.array(t)
    else:
        frames = int(frames)
        if frames < 2:
            raise ValueError(f"frames must be >= 2 (got {frames})")
        t = np.linspace(0.0, t_end, frames)
    return LoadHistory("displacement", t, d_of_t(t))


def read_force_history(path) -> LoadHistory:
    """Force history from a CSV with columns time_s, force_N (compressive positive).
    The first row must be t = 0 with zero force."""
    import pandas as pd

    path = Path(path)
    try:
        df = pd.read_csv(path)
    except Exception as e:
        raise ValueError(f"{path}: cannot read the force history CSV ({e})") from None
    missing = [c for c in ("time_s", "force_N") if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; found {list(df.columns)}")
    t = df["time_s"].to_numpy(float)
    f = df["force_N"].to_numpy(float)
    if len(t) < 2 or not np.isfinite(t).all() or not np.isfinite(f).all():
        raise ValueError(f"{path}: needs at least 2 rows of finite time_s, force_N")
    if t[0] != 0 or np.any(np.diff(t) <= 0):
        raise ValueError(f"{path}: time_s must start at 0 and increase strictly")
    if f[0] != 0:
        raise ValueError(f"{path}: force_N must be 0 at time 0 (got {f[0]})")
    return LoadHistory("force", t, f)
