"""Track a whole bundle at the nodes of a mesh and return the flow Dataset.

The flow Dataset (netCDF) holds, for frame pairs k -> k+1 (dim `frame`, k = 0..K-2):
`u_of(frame, node, component)` the nodal motion from frame k to k+1 in m (mesh axes),
`c_of(frame, node, component)` the Eq. A.4 confidence in [0, 1] per image axis (image
axes lateral, elevational, axial = mesh x, y, z for the usual placement), `U_of(frame, node,
component)` the tracked displacement of each node at frame k (where its neighbourhood
sat), `time_start(frame)` / `time_end(frame)` in s, `frame_time(volume)`, reference node
coordinates `X(node, component)`, and `spacing_m(axis)`, `origin_m(axis)`.
"""

from __future__ import annotations

import logging
import time as _time

import numpy as np
import xarray as xr

from .bundle import Bundle
from .tracking import NodalTracker, TrackOptions
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["track_bundle", "score_against_truth"]


def track_bundle(bundle: Bundle, points, cells, options: TrackOptions | None = None,
                 stride=(2, 2, 1), frames=None, window="subtet", progress=None) -> xr.Dataset:
    """Nodal Lucas-Kanade flow of every consecutive frame pair of `bundle` (see module doc).

    `frames` optionally restricts tracking to the first `frames` volumes; `progress(k, n)` is
    called after each of the n frame pairs."""
    opts = options or TrackOptions()
    grid = bundle.grid
    t0, c0 = _time.perf_counter(), _time.process_time()
    vw = VoxelWeights.build(points, cells, grid, stride=stride, window=window)
    t_build = _time.perf_counter() - t0
    nf = bundle.n_frames if frames is None else min(frames, bundle.n_frames)
    n = len(points)
    u_of = np.zeros((nf - 1, n, 3))
    c_of = np.zeros((nf - 1, n, 3))
    U_of = np.zeros((nf - 1, n, 3))
    iters = np.zeros(nf - 1, int)
    tracker = NodalTracker(vw, points, opts)
    tracker.start(bundle.frame(0))
    for k in range(1, nf):
        U_of[k - 1] = grid.vec_to_m(tracker.U)
        v, c = tracker.step(bundle.frame(k))
        u_of[k - 1] = grid.vec_to_m(v)
        c_of[k - 1] = c
        iters[k - 1] = tracker.iterations
        if progress is not None:
            progress(k, nf - 1)
    t_track = _time.perf_counter() - t0 - t_build
    cpu = _time.process_time() - c0
    log.info("tracked %d frame pairs at %d nodes in %.1f s (+%.1f s weights)", nf - 1, n,
             t_track, t_build)
    ts = bundle.time_s[:nf]
    comp = ["x", "y", "z"]
    ds = xr.Dataset(
        {"u_of": (("frame", "node", "component"), u_of,
                  {"units": "m", "long_name": "nodal motion from frame k to k+1"}),
         "c_of": (("frame", "node", "component"), c_of,
                  {"units": "1", "long_name": "Eq. A.4 confidence per image axis"}),
         "U_of": (("frame", "node", "component"), U_of,
                  {"units": "m", "long_name": "tracked displacement at frame k"}),
         "iterations": (("frame",), iters),
         "time_start": (("frame",), ts[:-1], {"units": "s"}),
         "time_end": (("frame",), ts[1:], {"units": "s"}),
         "frame_time": (("volume",), ts, {"units": "s"}),
         "X": (("node", "component"), np.asarray(points, float), {"units": "m"}),
         "spacing_m": (("axis",), np.asarray(grid.spacing_m), {"units": "m"}),
         "origin_m": (("axis",), np.asarray(grid.origin_m), {"units": "m"}),
         "direction": (("component", "axis"), grid.R)},
        coords={"frame": np.arange(nf - 1), "component": comp,
                "axis": ["lateral", "elevational", "axial"]},
        attrs={"tracking_seconds": t_track, "weights_seconds": t_build, "cpu_seconds": cpu,
               "options": str(opts.__dict__), "stride": str(tuple(stride)), "window": window})
    return ds


def score_against_truth(flow: xr.Dataset, truth: xr.Dataset, thresholds=(0.02, 0.05, 0.1)) -> dict:
    """Endpoint error (voxels) of the tracked motion against a truth forward run on the same
    mesh: the truth nodal motion between the frame times (u interpolated linearly in time).
    Returns {threshold: {"rms", "p95", "n_per_pair"}} over nodes with min-axis c > threshold."""
    if truth.sizes["node"] != flow.sizes["node"]:
        raise ValueError(f"truth has {truth.sizes['node']} nodes, flow {flow.sizes['node']}: "
                         "score on the same mesh")
    t = flow["frame_time"].values
    u = truth["u"].interp(time=t).values
    spacing = flow["spacing_m"].values
    R = flow["direction"].values
    true_vox = (np.diff(u, axis=0) @ R) / spacing
    est_vox = (flow["u_of"].values @ R) / spacing
    e = np.linalg.norm(est_vox - true_vox, axis=-1)
    c = flow["c_of"].values.min(-1)
    out = {}
    for th in thresholds:
        m = c > th
        out[th] = {"rms": float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else float("nan"),
                   "p95": float(np.percentile(e[m], 95)) if m.any() else float("nan"),
                   "n_per_pair": float(m.sum() / max(len(e), 1)),
                   "max_true_vox": float(np.abs(true_vox).max())}
    return out
