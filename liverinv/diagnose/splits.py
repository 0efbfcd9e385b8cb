"""Where a fit fails: its volumetric misfit Phi_vol split into parts a person can read, each
part's share of Phi_vol: by region (under the punch, near the rim, far field), by depth (thirds
of the tissue height, from the bottom), by time window (loading, unloading) and by component
(axial, radial, tangential about the punch axis)."""

from __future__ import annotations

import numpy as np

__all__ = ["misfit_splits"]


def misfit_splits(objective, residual, punch_radius=0.006) -> dict:
    """{split: {part: share of Phi_vol}} of the residual vector of `objective`."""
    d = objective.data
    K, N = objective.K, objective.N
    rv = np.asarray(residual)[: objective.v_of.size].reshape(K, N, 3)
    X = objective.forward.mesh.points if d.X is None else np.asarray(d.X)
    total = float((rv ** 2).sum())
    if total <= 0:
        return {}
    r = np.hypot(X[:, 0], X[:, 1])
    a = punch_radius
    e2 = rv ** 2
    node = e2.sum(axis=(0, 2))
    region = {"under the punch": r < a, "near the rim": (r >= a) & (r < 2 * a), "far field": r >= 2 * a}
    z = X[:, 2]
    cuts = np.linspace(z.min(), z.max(), 4)
    depth = {"bottom third": z < cuts[1], "middle third": (z >= cuts[1]) & (z < cuts[2]), "top third": z >= cuts[2]}
    tm = 0.5 * (d.t0 + d.t1)
    t_rev = objective.t_drive[int(np.argmax(objective.d_drive))]
    frame = e2.sum(axis=(1, 2))
    window = {"loading": tm <= t_rev, "unloading": tm > t_rev}
    with np.errstate(invalid="ignore", divide="ignore"):
        er = np.where(r[:, None] > 0, np.stack([X[:, 0], X[:, 1]], 1) / r[:, None], [1.0, 0.0])
    radial = (rv[..., 0] * er[:, 0] + rv[..., 1] * er[:, 1]) ** 2
    tangential = (-rv[..., 0] * er[:, 1] + rv[..., 1] * er[:, 0]) ** 2
    comp = {"axial": float(e2[..., 2].sum()), "radial": float(radial.sum()), "tangential": float(tangential.sum())}
    return {"region": {k: float(node[m].sum() / total) for k, m in region.items()},
            "depth": {k: float(node[m].sum() / total) for k, m in depth.items()},
            "time": {k: float(frame[m].sum() / total) for k, m in window.items()},
            "component": {k: v / total for k, v in comp.items()}}
