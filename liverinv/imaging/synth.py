"""From a study config to a measurement bundle: truth simulation, rendering, indenter record.

The study's `imaging:` section (all keys optional; SI units)::

    imaging:
      truth: simulate          # simulate (forward model, liverinv.study) | analytic
      mode: warp               # warp | scatter (see liverinv.imaging.sequence)
      seed: 0
      frames: 20               # volumes, evenly spanning the simulated time ...
      frame_rate_hz: null      # ... or this many per second from t = 0
      volume:
        shape: [128, 48, 204]          # lateral, elevational, axial voxels
        spacing_m: [0.5e-3, 0.5e-3, 0.3e-3]
        standoff_m: 0.01               # stand-off pad in view below the tissue (z < 0)
        origin_m: null                 # or the centre of voxel (0,0,0) in mesh coordinates
      scatterers_per_cell: 5
      bmode_noise: 0.0
      noise_db: null           # scatter mode only
      decorrelation: 0.0       # scatter mode only
      transducer: {centre_frequency_hz: 3.0e6, sigma_m: [1.0e-3, 1.2e-3, 0.45e-3],
                   dynamic_range_db: 50}
      indenter: {rate_hz: 100, noise: false}   # noise: the paper's 3.9 um / 13 mN RMS
      storage: uint16          # uint16 | uint8 | float32 | float64

Keys, types and ranges: the `imaging` part of `liverinv/schemas/study.schema.yaml`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .analytic import analytic_run, triangle_depth
from .bundle import Indenter, write_bundle
from .grid import ImageGrid, paper_grid
from .sequence import ImagingOptions, SpeckleScene, rendered_ahead
from .speckle import Transducer
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["synthesize", "imaging_config", "imaging_options", "PAPER_NOISE"]

PAPER_NOISE = {"displacement_m": 3.9e-6, "force_N": 13e-3}   # section 2.1.1, with controller


def _err(msg):
    from ..cli import UserError
    return UserError(msg)


def imaging_config(study: dict, source="study") -> dict:
    """The `imaging:` section with defaults filled in.

    Keys, types, ranges and allowed values are the study schema's (`schemas/study.schema.yaml`,
    checked again here for studies that did not come through `load_study`); here only what a
    schema does not say well: the options that apply to one mode only."""
    from ..study import StudyError, validate_imaging
    try:
        validate_imaging(study.get("imaging"), source)
    except StudyError as e:
        raise _err(str(e)) from None
    im = dict(study.get("imaging") or {})
    im.setdefault("truth", "simulate")
    im.setdefault("mode", "warp")
    im["seed"] = int(im.get("seed", 0))
    im["frames"] = int(im.get("frames", 20))
    im.setdefault("frame_rate_hz", None)
    im.setdefault("volume", {})
    im.setdefault("indenter", {})
    im.setdefault("storage", "uint16")
    if im["mode"] == "warp" and (im.get("noise_db") is not None or im.get("decorrelation", 0) > 0):
        raise _err(f"{source}: imaging: noise_db and decorrelation apply to mode 'scatter'; "
                   "use bmode_noise with mode 'warp'")
    return im


def imaging_options(im: dict, source="study", seed=None) -> ImagingOptions:
    """The renderer's options of a filled-in `imaging:` section (`imaging_config`; a bundle's
    `imaging` attribute), with another speckle `seed` where given."""
    tr_cfg = dict(im.get("transducer") or {})
    try:
        transducer = Transducer(**{k: (tuple(v) if isinstance(v, list) else v)
                                   for k, v in tr_cfg.items()})
        return ImagingOptions(mode=im.get("mode", "warp"), seed=int(im.get("seed", 0) if seed is None else seed),
                              scatterers_per_cell=float(im.get("scatterers_per_cell", 5.0)),
                              bmode_noise=float(im.get("bmode_noise", 0.0)),
                              noise_db=im.get("noise_db"),
                              decorrelation=float(im.get("decorrelation", 0.0)),
                              transducer=transducer)
    except (TypeError, ValueError) as e:
        raise _err(f"{source}: imaging: {e}") from None


def make_grid(vol: dict, source="study") -> ImageGrid:
    try:
        shape = tuple(int(n) for n in vol.get("shape", (128, 48, 204)))
        spacing = tuple(float(s) for s in vol.get("spacing_m", (0.5e-3, 0.5e-3, 0.3e-3)))
        if len(shape) != 3 or len(spacing) != 3 or min(spacing) <= 0 or min(shape) < 4:
            raise ValueError
        if vol.get("origin_m") is not None:
            return ImageGrid(shape, spacing, tuple(float(o) for o in vol["origin_m"]))
        return paper_grid(shape, spacing, float(vol.get("standoff_m", 0.01)))
    except (TypeError, ValueError):
        raise _err(f"{source}: imaging.volume: shape needs 3 integers >= 4, spacing_m 3 "
                   f"positive lengths, origin_m 3 coordinates; got {vol}") from None


def _frame_times(study, im, base_dir, source, t_end=None):
    """Imaging frame times: `frames` at `frame_rate_hz` from t = 0, or evenly spanning the
    loading history."""
    if t_end is None:
        from ..study import StudyError, history_of
        try:
            t_end = float(history_of(study.get("loading", {}), Path(base_dir)).time[-1])
        except (StudyError, ValueError, OSError) as e:
            raise _err(f"{source}: loading: {e}") from None
    if im["frame_rate_hz"]:
        times = np.arange(im["frames"]) / float(im["frame_rate_hz"])
        if times[-1] > t_end + 1e-12:
            raise _err(f"{source}: imaging: {im['frames']} frames at {im['frame_rate_hz']} Hz last "
                       f"{times[-1]:.3g} s, longer than the simulation ({t_end:.3g} s)")
        return times
    return np.linspace(0.0, t_end, im["frames"])


def _truth(study, im, base_dir, source):
    if im["truth"] == "analytic":
        from .weights import mesh_arrays
        mesh = Path(base_dir) / study.get("mesh", "")
        if not mesh.is_file():
            raise _err(f"{source}: mesh: file {mesh} not found")
        P, C = mesh_arrays(str(mesh))
        ld = study.get("loading", {})
        depth, rate = float(ld.get("depth", 9.2e-3)), float(ld.get("rate", 2e-3))
        t = np.linspace(0.0, 2 * depth / rate, int(ld.get("steps", 46)) * 2 + 1)
        return analytic_run(P, C, t, triangle_depth(t, depth, rate), **(im.get("analytic") or {}))
    try:
        from ..study import simulate_study
    except ImportError:
        raise _err(f"{source}: imaging.truth is 'simulate' but the forward engine "
                   "(liverinv.study.simulate_study) is not available; use truth: analytic") from None
    # the imaging frames are simulated frames: each volume shows an equilibrium state
    return simulate_study(study, Path(base_dir), extra_times=_frame_times(study, im, base_dir, source))


def simulate_truth(study: dict, base_dir, source="study"):
    """The truth simulation of a study with an imaging section (its frames simulated), with
    the provenance a truth file carries."""
    from ..fileio import provenance
    im = imaging_config(study, source)
    ds = _truth(study, im, base_dir, source)
    ds.attrs.update(provenance(role="truth", imaging=im))
    return ds


def synthesize(study: dict, base_dir, out, truth_out=None, source="study", truth=None):
    """Run the truth simulation (or take `truth`, a Dataset from `simulate_truth` of the same
    study), render the sequence and write the bundle (and the truth).

    Returns the truth Dataset.
    """
    im = imaging_config(study, source)
    grid = make_grid(im["volume"], source)
    opts = imaging_options(im, source)
    ds = _truth(study, im, base_dir, source) if truth is None else truth
    t_sim = ds["time"].values
    times = _frame_times(study, im, base_dir, source, t_end=float(t_sim[-1]))
    X, cells = ds["X"].values, ds["cells"].values
    vw = VoxelWeights.build(X, cells, grid)
    if len(vw.voxels) == 0:
        raise _err(f"{source}: imaging.volume: the volume does not overlap the mesh")
    scene = SpeckleScene(vw, opts)
    u_frames = ds["u"].interp(time=times).values

    def volumes():
        from tqdm import tqdm
        # rendered ahead in worker threads while the bundle writes (two at once when the
        # scene's frames do not depend on their order)
        frames = rendered_ahead(scene.frame, u_frames, stateless=scene.stateless)
        with tqdm(total=len(times), desc="render", unit="volume", disable=None) as bar:
            for k, vol in enumerate(frames):
                log.info("frame %d/%d", k + 1, len(times))
                yield vol
                bar.update(1)

    ind_cfg = im["indenter"]
    rate = float(ind_cfg.get("rate_hz", 100.0))
    ti = np.arange(t_sim[0], t_sim[-1] + 0.5 / rate, 1.0 / rate)
    depth = np.interp(ti, t_sim, ds["indenter_depth"].values)
    force = np.interp(ti, t_sim, ds["indenter_force"].values)
    dn = fn = 0.0
    if ind_cfg.get("noise", False):
        rng = np.random.default_rng(int(im["seed"]) + 1)
        dn, fn = PAPER_NOISE["displacement_m"], PAPER_NOISE["force_N"]
        depth = depth + dn * rng.standard_normal(len(ti))
        force = force + fn * rng.standard_normal(len(ti))
    r = np.hypot(X[:, 0], X[:, 1])
    geometry = {"tissue_height_m": float(X[:, 2].max() - X[:, 2].min()),
                "tissue_radius_m": float(r.max()),
                "indenter_radius_m": float(study.get("indenter_radius", 0.006)),
                "indenter_axis_m": [0.0, 0.0], "mesh": str(study.get("mesh", ""))}
    write_bundle(out, volumes(), grid, times,
                 Indenter(ti, depth, force, dn, fn), geometry, dtype=im["storage"],
                 imaging=im, truth_law=str(ds.attrs.get("law", "")))
    if truth_out is not None:
        from ..fileio import provenance, write_netcdf
        ds = ds.copy()
        ds.attrs.update(provenance(role="truth", imaging=im))
        write_netcdf(ds, truth_out)
    return ds
