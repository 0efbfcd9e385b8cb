"""Nodal Lucas-Kanade tracking: rigid sub-voxel translation and a smooth known field."""

import numpy as np
import pytest

from liverinv.imaging.analytic import box_tet10
from liverinv.imaging.grid import ImageGrid
from liverinv.imaging.sequence import ImagingOptions, SpeckleScene
from liverinv.imaging.tracking import NodalTracker, TrackOptions
from liverinv.imaging.weights import VoxelWeights

SPACING = (0.5e-3, 0.5e-3, 0.3e-3)


@pytest.fixture(scope="module")
def scene():
    """A 40 x 40 x 64 voxel volume inside a 24 mm tissue cube (3 x 3 x 3 cubes of 6 tet10):
    the nodes in view have whole neighbourhoods; warped speckle."""
    P, C = box_tet10([-12e-3, -12e-3, -3e-3], [12e-3, 12e-3, 21e-3], 3)
    grid = ImageGrid((40, 40, 64), SPACING, (-9.75e-3, -9.75e-3, -0.9e-3))
    vw = VoxelWeights.build(P, C, grid)
    sc = SpeckleScene(vw, ImagingOptions(mode="warp", seed=3))
    return P, C, grid, vw, sc


def _score(v, true, c, th=0.1):
    m = c.min(1) > th
    e = np.linalg.norm(v - true, axis=1)[m]
    return np.sqrt(np.mean(e ** 2)), m.sum()


def test_weights_partition_of_unity_and_linear_exact(scene):
    P, C, grid, vw, _ = scene
    assert np.allclose(np.asarray(vw.Wi.sum(0)).ravel(), 1.0)
    assert vw.W.min() >= 0.0
    f = P @ np.array([1.0, -2.0, 3.0])
    x = grid.centres(vw.voxels)
    assert np.allclose(vw.interpolate(f), x @ np.array([1.0, -2.0, 3.0]), atol=1e-12)


def test_rigid_subvoxel_translation(scene):
    P, C, grid, vw, sc = scene
    shift_vox = np.array([0.23, -0.11, 0.17])
    u1 = np.tile(grid.vec_to_m(shift_vox), (len(P), 1))
    f0, f1 = sc.frame(0 * u1), sc.frame(u1)
    # the Appendix's translation model (exact for rigid motion), then the default options
    for opts, tol in [(TrackOptions(max_iterations=8, tol_vox=1e-4, interpolated_iterations=0), 0.005),
                      (TrackOptions(interpolated_iterations=2), 0.015)]:
        tr = NodalTracker(vw, P, opts)
        tr.start(f0)
        v, c = tr.step(f1)
        rms, n = _score(v, shift_vox, c)
        assert n >= 10
        assert rms < tol, (rms, opts)
    assert c.max() == pytest.approx(1.0) and c.min() >= 0.0


def test_smooth_field_sequence(scene):
    """A smooth field (translation + rotation + compression, up to ~0.3 voxel/frame)
    tracked over 4 frames, following the material point. On this small volume many
    confident nodes have windows cut by the volume faces; measured 0.006-0.012 voxel RMS
    per frame (the 0.005 target is met on the paper's volume: benchmarks/bench_tracking.py)."""
    P, C, grid, vw, sc = scene
    Xc = P - P.mean(0)
    L = np.array([[0.0, 2e-3, 0.0], [-2e-3, 0.0, 0.0], [0.0, 0.0, -3e-3]])   # per frame
    t = grid.vec_to_m([0.05, -0.03, -0.2])
    U = [np.zeros_like(P)]
    for k in range(4):
        U.append(U[-1] + (Xc + U[-1]) @ L.T + t)
    frames = [sc.frame(u) for u in U]
    tr = NodalTracker(vw, P, TrackOptions(max_iterations=4, tol_vox=1e-4))
    tr.start(frames[0])
    errs = []
    for k in range(1, len(frames)):
        v, c = tr.step(frames[k])
        true = grid.vec_to_vox(U[k] - U[k - 1])
        assert 0.2 < np.abs(true).max() < 0.35
        errs.append(_score(v, true, c)[0])
    assert max(errs) < 0.015 and np.mean(errs) < 0.01, errs


def test_nodes_outside_view_have_zero_confidence(scene):
    P, C, grid, vw, sc = scene
    P2 = P.copy()
    P2[:, 2] += 20e-3          # most of the cube above the volume
    vw2 = VoxelWeights.build(P2, C, grid)
    tr = NodalTracker(vw2, P2)
    f = sc.frame(np.zeros_like(P))
    tr.start(f)
    v, c = tr.step(f)
    outside = ~grid.inside(P2)
    assert outside.any()
    assert np.all(c[outside] == 0.0)


def test_min_support_window_small_elements():
    """Minimum spatial support: on a mesh of small elements (4 mm cubes, 8 x 8 x 13 voxels)
    the element windows are small; a cone of 20 voxels around each node recovers a rigid
    sub-voxel translation at every node in view (measured 0.0012 voxel RMS, 0.0045 max;
    element windows alone 0.017 RMS, 0.06 max)."""
    P, C = box_tet10([-12e-3, -12e-3, -3e-3], [12e-3, 12e-3, 21e-3], 6)
    grid = ImageGrid((40, 40, 64), SPACING, (-9.75e-3, -9.75e-3, -0.9e-3))
    vw = VoxelWeights.build(P, C, grid)
    R = 20.0
    Wm = vw.with_min_support(P, R)
    assert (Wm - vw.W).min() >= 0.0                       # never smaller than the hat
    xa = np.stack(np.unravel_index(vw.voxels, grid.shape), 1).astype(float)
    n = int(np.argmin(np.linalg.norm(P - P.mean(0), axis=1)))
    d = np.linalg.norm(xa - grid.to_vox(P[n]), axis=1)
    row = Wm[n].toarray().ravel()
    assert np.allclose(np.maximum(row, 0)[d < R], np.maximum(vw.W[n].toarray().ravel(), 1 - d / R)[d < R])
    assert np.all(row[d >= R] == vw.W[n].toarray().ravel()[d >= R])
    sc = SpeckleScene(vw, ImagingOptions(mode="warp", seed=3))
    shift_vox = np.array([0.23, -0.11, 0.17])
    u1 = np.tile(grid.vec_to_m(shift_vox), (len(P), 1))
    f0, f1 = sc.frame(0 * u1), sc.frame(u1)
    out = {}
    for ms in (0.0, R):
        tr = NodalTracker(vw, P, TrackOptions(max_iterations=8, tol_vox=1e-4, min_support_vox=ms))
        tr.start(f0)
        v, c = tr.step(f1)
        m = c.min(1) > 0.05
        assert m.sum() >= 100
        e = np.linalg.norm(v - shift_vox, axis=1)[m]
        out[ms] = (np.sqrt(np.mean(e ** 2)), e.max())
    assert out[R][0] < 0.003 and out[R][1] < 0.01, out
    assert out[R][0] < 0.5 * out[0.0][0], out


def test_observation_operator_predicts_the_window_average():
    """A peaked motion (Gaussian bumps of 3-4 mm width, 0.3 voxel) imaged on a fine mesh and
    tracked on 8 mm elements: the tracker reports the structure-tensor-weighted window
    average, not the nodal motion. The linearized tracker (`TrackingObservation`) applied to
    the model's field predicts it. Measured: 0.0019 voxel RMS against 0.027 at the nodes
    (whose gain is 0.51)."""
    from liverinv.imaging.observation import TrackingObservation

    lo, hi = [-12e-3, -12e-3, -3e-3], [12e-3, 12e-3, 21e-3]
    P, C = box_tet10(lo, hi, 3)
    Pf, Cf = box_tet10(lo, hi, 8)
    grid = ImageGrid((40, 40, 64), SPACING, (-9.75e-3, -9.75e-3, -0.9e-3))
    sc = SpeckleScene(VoxelWeights.build(Pf, Cf, grid), ImagingOptions(mode="warp", seed=3))

    def field(X, a=0.09e-3):
        r2 = X[:, 0] ** 2 + X[:, 1] ** 2 + (X[:, 2] - 9e-3) ** 2
        u = np.zeros_like(X)
        u[:, 2] = -a * np.exp(-r2 / (2 * 3e-3 ** 2))
        u[:, 0] = 0.3 * a * np.exp(-r2 / (2 * 4e-3 ** 2))
        return u

    f0, f1 = sc.frame(0 * Pf), sc.frame(field(Pf))
    opts = TrackOptions(max_iterations=6, tol_vox=1e-4)
    tr = NodalTracker(VoxelWeights.build(P, C, grid), P, opts)
    tr.start(f0)
    v, c = tr.step(f1)
    O = TrackingObservation.build(f0, grid, P, C, Pf, Cf, opts, (1, 1, 1), "subtet")
    assert O(np.zeros((2,) + Pf.shape)).shape == (2,) + P.shape
    m = c.min(1) > 0.1
    at_nodes = grid.vec_to_vox(field(P))
    observed = grid.vec_to_vox(O(field(Pf)))
    assert m.sum() > 50 and np.abs(at_nodes[m]).max() == pytest.approx(0.3, rel=0.01)
    rms = lambda ref: np.sqrt(np.mean(np.sum((v - ref)[m] ** 2, axis=1)))
    assert rms(at_nodes) > 0.02
    assert rms(observed) < 0.004
    assert rms(observed) < 0.15 * rms(at_nodes)
    # the rows of some nodes only (the sensitivities of a fit): the same numbers
    rng = np.random.default_rng(0)
    some = np.flatnonzero(m)[::3]
    u = rng.normal(size=(2, 3) + Pf.shape)
    assert np.allclose(O.at_nodes(u, some), O(u)[..., some, :], rtol=0, atol=1e-12 * np.abs(O(u)).max())


def test_default_refinement_follows_a_reversal_without_lag(scene):
    """Compression growing for three pairs, then reversing. The warm start (the previous
    pair's motion) is wrong by twice the motion at the reversal; the refinement must remove
    it, not leave a lag. Measured RMS error (voxels) at the reversal: 1 iteration 0.136,
    2: 0.067, 4: 0.019, 8 (default): 0.015, the error of the steady pairs."""
    P, C, grid, vw, sc = scene
    Xc = P - P.mean(0)
    step = Xc @ np.diag([0.0, 0.0, -8e-3]) + grid.vec_to_m([0.0, 0.0, -0.3])
    U = [np.zeros_like(P)]
    for s in (1, 1, 1, -1, -1):
        U.append(U[-1] + s * step)
    frames = [sc.frame(u) for u in U]
    tr = NodalTracker(vw, P)
    tr.start(frames[0])
    errs = []
    for k in range(1, len(frames)):
        v, c = tr.step(frames[k])
        errs.append(_score(v, grid.vec_to_vox(U[k] - U[k - 1]), c)[0])
    assert max(errs[1:3]) < 0.025                       # steady pairs
    assert errs[3] < 0.025 and errs[3] < 1.5 * max(errs[1:3]), errs
