"""The tracker's response to a model's own motion: what the tracker reports when the bundle's
first volume is warped by the model's displacement and tracked with the flow's options.

The observation operator (`observation.TrackingObservation`) is the tracker linearized at
frame 0: a structure-tensor-weighted window average of the motion. It misses what the
tracker does beyond that: the texture's deformation over the test and the nonlinearity of
the warp over a frame pair (0.6 voxel axially on the Table 1 data). Measured on the Table 1
setup (PE truth on the fine mesh, 100 warped volumes, tracked on the coarse mesh), the tracked
axial motion was 1.03-1.06x the operator's prediction of the truth in every tenth of the record,
and the lateral motion 0.91-1.02x, varying with the depth. The fit absorbs such a pattern into
D1 and kappa (-5.6 % and -7.7 % there).

`tracker_response` renders that experiment for a model history: frame k is the first volume
warped by the model's displacement at frame time k (`sequence.warp_volume`, the paper's way of
making synthetic sequences from a real reference volume) and the nodal tracker runs on the
sequence exactly as `liverinv track` ran on the data. The difference between this response and
the operator's prediction of the same motion is the operator's error at that motion; added to
the operator (`Objective.tracker_offset`), it makes the observation right at the motion it was
computed for, and to first order near it. On warped data the response to the true motion is
the tracked data itself.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy import ndimage

from .observation import track_options_of
from .sequence import warp_volume
from .tracking import NodalTracker
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["tracker_response"]


def tracker_response(bundle, flow, tracking_mesh, model_mesh, u_frames: np.ndarray) -> np.ndarray:
    """(K, N, 3) m: the nodal motion the tracker reports, frame pair by frame pair, for the
    first volume of `bundle` warped by the model displacement `u_frames` ((K + 1, n_model, 3),
    m, at the flow's frame times) on `model_mesh`, tracked on `tracking_mesh` with the flow's
    options."""
    opts, stride, window = track_options_of(flow)
    grid = bundle.grid
    u_frames = np.asarray(u_frames, float)
    if u_frames.shape[0] != flow.sizes["frame"] + 1:
        raise ValueError(f"u_frames holds {u_frames.shape[0]} frames; the flow has {flow.sizes['frame'] + 1}")
    t0 = time.perf_counter()
    ref = np.asarray(bundle.frame(0), np.float32)
    coef = ndimage.spline_filter(ref, order=3, output=np.float32, mode="mirror")
    model_vw = VoxelWeights.build(model_mesh.points, model_mesh.cells, grid)
    track_vw = VoxelWeights.build(tracking_mesh.points, tracking_mesh.cells, grid, stride=stride, window=window)
    tracker = NodalTracker(track_vw, tracking_mesh.points, opts)
    tracker.start(warp_volume(ref, model_vw.to_grid(grid.vec_to_vox(u_frames[0])), coef))
    out = np.zeros((u_frames.shape[0] - 1, tracking_mesh.n_nodes, 3))
    for k in range(1, u_frames.shape[0]):
        v, _ = tracker.step(warp_volume(ref, model_vw.to_grid(grid.vec_to_vox(u_frames[k])), coef))
        out[k - 1] = grid.vec_to_m(v)
    log.info("tracker response: %d frame pairs rendered and tracked in %.1f s", len(out), time.perf_counter() - t0)
    return out
