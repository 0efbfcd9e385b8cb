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
the operator (`identify.response.with_corrected_data` subtracts it from the data), it makes the
observation right at the motion it was computed for, and to first order near it. On warped data the response to the true motion is
the tracked data itself.

Warped volumes with B-mode noise (`bmode_noise`, drawn afresh for every frame, so it does not
move with the tissue) are tracked short: against the noise-free response to the same motion, a
response with the noise has per-component gains 0.977, 0.960 and 0.998 (noise 0.05 against
the speckle's 0.35, the coarse benchmark mesh, 31 volumes), and the data's tracked motion
against the noise-free response at the elastic null's fit 0.967, 0.955 and 0.994 (unweighted).
A noisy response used as it is adds its realization's random error (RMS 23-25 um laterally
against 30-34 um of motion), so the noise-free response is scaled by the noisy one's
gain instead: one more response, no added noise. On the warped elastic null of seed 24 the
corrected fit moved from C1 +4.4, C2 -1.8, D1 -0.3 % to +1.9, +0.3, 0.0 %.

On moved-scatterer volumes (`sequence`, mode scatter) the data's speckle is not a warp of one
volume, and what the tracker misses there is not the warp's error: speckle changes with the
local strain (a lateral shortfall that made D1 +109 % on the Table 3 surrogate). The response
is then rendered as such data are made: a `SpeckleScene` with the bundle's imaging options but
its own speckle seed (`RESPONSE_SEED`: the data's realization, its receiver noise and
decorrelation draws are not known for measured data and must not be used here), the scatterers
moved with the model's motion. Its error holds the tracker's systematic part and, on top, a
realization's random part, as large as the data's own: on PSR data (seed 7) two response seeds
correlated 0.05-0.15 per component and no refit on the corrected motion came closer to the
truth (docs/identification.md), so `discover` corrects warped volumes only.
"""

from __future__ import annotations

import json
import logging
import time

import numpy as np
from scipy import ndimage

from .observation import track_options_of
from .sequence import SpeckleScene, rendered_ahead, warp_volume
from .tracking import NodalTracker
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["tracker_response", "RESPONSE_SEED"]

RESPONSE_SEED = 104_729    # added to the data's seed: the moved-scatterer response's own speckle
#: bounds of the per-component gain of the tracked motion under warped volumes' B-mode noise
#: (measured 0.977, 0.960, 0.998 at noise 0.05 on the coarse benchmark mesh, 31 volumes)
NOISE_GAIN_RANGE = (0.8, 1.0)


def tracker_response(bundle, flow, tracking_mesh, model_mesh, u_frames: np.ndarray, seed=None,
                     bmode_noise=None) -> np.ndarray:
    """(K, N, 3) m: the nodal motion the tracker reports, frame pair by frame pair, for the
    first volume of `bundle` warped by the model displacement `u_frames` ((K + 1, n_model, 3),
    m, at the flow's frame times) on `model_mesh` (moved-scatterer bundles: the volumes
    rendered again with the response's own speckle, see the module's docstring), tracked on
    `tracking_mesh` with the flow's options. `seed`: the moved scatterers' speckle seed
    (default: the data's plus `RESPONSE_SEED`; the data's own reproduces a synthesized bundle).
    `bmode_noise`: the std of the warped volumes' B-mode noise (default: the bundle's imaging
    record's, 0 for measured data): the noise-free response is then scaled per component by the
    tracker's gain under that noise (see the module's docstring)."""
    opts, stride, window = track_options_of(flow)
    grid = bundle.grid
    u_frames = np.asarray(u_frames, float)
    if u_frames.shape[0] != flow.sizes["frame"] + 1:
        raise ValueError(f"u_frames holds {u_frames.shape[0]} frames; the flow has {flow.sizes['frame'] + 1}")
    t0 = time.perf_counter()
    model_vw = VoxelWeights.build(model_mesh.points, model_mesh.cells, grid)
    imaging = bundle_imaging(bundle)
    warped = imaging.get("mode") != "scatter"
    # the warped volumes' B-mode noise (moved scatterers carry theirs in the rendering)
    noise = float((imaging.get("bmode_noise") or 0.0) if bmode_noise is None else bmode_noise) if warped else 0.0
    noise_seed = int(imaging.get("seed", 0)) + RESPONSE_SEED if seed is None else int(seed)
    if not warped:
        from .synth import imaging_options
        if seed is None:
            seed = int(imaging.get("seed", 0)) + RESPONSE_SEED
        scene = SpeckleScene(model_vw, imaging_options(imaging, "the bundle's imaging attribute", seed=seed))

        def volume(u_nodes):
            return scene.frame(u_nodes)
    else:
        ref = np.asarray(bundle.frame(0), np.float32)
        coef = ndimage.spline_filter(ref, order=3, output=np.float32, mode="mirror")

        def volume(u_nodes):
            return warp_volume(ref, model_vw.to_grid(grid.vec_to_vox(u_nodes)), coef)

    def with_noise(k, vol):     # the data's B-mode noise, drawn afresh for every frame after the first
        rng = np.random.default_rng([noise_seed, k])
        return np.clip(vol + noise * rng.standard_normal(vol.shape), 0.0, 1.0).astype(np.float32)

    track_vw = VoxelWeights.build(tracking_mesh.points, tracking_mesh.cells, grid, stride=stride, window=window)
    # the noise-free sequence and, with B-mode noise, the same volumes with the noise added,
    # tracked side by side (each volume warped once)
    trackers = [NodalTracker(track_vw, tracking_mesh.points, opts) for _ in range(2 if noise > 0 else 1)]
    out = np.zeros((len(trackers), u_frames.shape[0] - 1, tracking_mesh.n_nodes, 3))
    conf = np.zeros(out.shape[1:3])
    # warped volumes are independent of each other; moved scatterers draw noise in order
    volumes = rendered_ahead(volume, u_frames, stateless=warped)
    first = next(volumes)
    for tracker in trackers:
        tracker.start(first)
    for k, vol in enumerate(volumes, start=1):
        v, c = trackers[0].step(vol)
        out[0, k - 1], conf[k - 1] = grid.vec_to_m(v), np.mean(c, axis=-1)
        if noise > 0:
            out[1, k - 1] = grid.vec_to_m(trackers[1].step(with_noise(k, vol))[0])
    out, noisy = out[0], out[-1]
    if noise > 0:
        # B-mode noise that does not move with the tissue pulls the tracked motion toward zero
        # (3-4 % laterally at 0.05 on the hidden-effect cases); its realization would add as much
        # random error again. So the noise-free response is scaled, per component, by the gain of
        # a noisy one against it (confidence-weighted least-squares slope).
        w = conf[..., None]
        slope = np.sum(w * out * noisy, axis=(0, 1)) / np.maximum(np.sum(w * out * out, axis=(0, 1)), 1e-300)
        # noise only shrinks the estimate; a slope outside NOISE_GAIN_RANGE is the realization's
        gain = np.clip(np.nan_to_num(slope, nan=1.0), *NOISE_GAIN_RANGE)
        if np.any(gain != slope):
            log.warning("the tracker's gain under the B-mode noise came out %s, outside %s (too little motion to "
                        "measure it?): %s used", np.array2string(slope, precision=3), NOISE_GAIN_RANGE,
                        np.array2string(gain, precision=3))
        log.info("tracker response: gain under the B-mode noise %.3g per component %s", noise,
                 np.array2string(gain, precision=4))
        out = out * gain
    log.info("tracker response (%s): %d frame pairs rendered and tracked in %.1f s",
             imaging.get("mode", "warp"), len(out), time.perf_counter() - t0)
    return out


def bundle_imaging(bundle) -> dict:
    """The `imaging:` section a bundle was synthesized with (its attribute `imaging`), or {}
    for measured data."""
    raw = bundle.attrs.get("imaging") or "{}"
    try:
        im = json.loads(raw)
    except (TypeError, ValueError):
        return {}
    return im if isinstance(im, dict) else {}
