"""Speckle rendering and sequences: seeded, textured where the tissue is, inverse map."""

import numpy as np
import pytest

from liverinv.imaging.analytic import box_tet10
from liverinv.imaging.grid import ImageGrid
from liverinv.imaging.sequence import ImagingOptions, SpeckleScene, inverse_map, rendered_ahead
from liverinv.imaging.weights import VoxelWeights


def _scene(seed, mode="warp", **kw):
    P, C = box_tet10([-4e-3, -4e-3, 0.0], [4e-3, 4e-3, 8e-3], 1)
    grid = ImageGrid((24, 24, 48), (0.5e-3, 0.5e-3, 0.3e-3), (-5.75e-3, -5.75e-3, -2.85e-3))
    vw = VoxelWeights.build(P, C, grid)
    return P, grid, vw, SpeckleScene(vw, ImagingOptions(mode=mode, seed=seed, **kw))


def test_seeded_and_reproducible():
    P, grid, vw, a = _scene(5)
    _, _, _, b = _scene(5)
    _, _, _, c = _scene(6)
    u = np.zeros_like(P)
    assert np.array_equal(a.frame(u), b.frame(u))
    assert not np.array_equal(a.frame(u), c.frame(u))


def test_textures_tissue_pad_water():
    P, grid, vw, sc = _scene(1)
    f = sc.frame(np.zeros_like(P))
    assert f.dtype == np.float32 and f.min() >= 0 and f.max() <= 1
    tissue = vw.mask()
    z = grid.axis_m(2)
    pad = np.zeros_like(tissue)
    pad[:, :, z < -1.5e-3] = True                    # stand-off pad well below the tissue
    water = np.zeros_like(tissue)
    water[:, :, z > 10e-3] = True                    # well above it
    assert f[tissue].mean() > f[pad].mean() > f[water].mean()
    assert f[pad].std() > 0.05                       # the pad is textured, not flat


def test_scatter_mode_moves_speckle_with_tissue():
    P, grid, vw, sc = _scene(2, mode="scatter")
    u = np.tile(grid.vec_to_m([0.0, 0.0, 1.0]), (len(P), 1))     # one axial voxel
    f0, f1 = sc.frame(np.zeros_like(P)), sc.frame(u)
    m = vw.mask()
    m[:, :, -3:] = False
    shifted = np.roll(f0, 1, axis=2)
    assert np.corrcoef(f1[m], shifted[m])[0, 1] > 0.9 > np.corrcoef(f1[m], f0[m])[0, 1]


def test_inverse_map_recovers_reference_positions():
    rng = np.random.default_rng(0)
    shape = (10, 10, 10)
    X = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).astype(float)
    u = 0.3 * np.sin(X / 4.0)                         # smooth, gradient < 0.1
    Xs = rng.uniform(2, 7, size=(50, 3))
    from liverinv.imaging.sequence import _sample_grid
    x = Xs + _sample_grid(u, Xs)
    assert np.abs(inverse_map(u, x, iterations=10) - Xs).max() < 1e-3


def test_inverse_map_from_voxel_centres_takes_the_grid_values_exactly():
    # warp_volume starts the fixed point at voxel centres, where the first interpolation is the
    # grid's own value: the shortcut (at_voxels) must give the interpolated iteration's numbers
    shape = (10, 9, 8)
    X = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).astype(float)
    u = 0.4 * np.sin(X / 3.0) + 0.1 * np.cos(X[..., ::-1] / 2.0)
    flat = np.arange(0, X[..., 0].size, 7)
    x = X.reshape(-1, 3)[flat]
    for it in (1, 3, 6):
        assert np.array_equal(inverse_map(u, x, iterations=it, at_voxels=flat), inverse_map(u, x, iterations=it))


def test_volumes_rendered_ahead_come_in_order_and_as_in_a_plain_loop():
    P, grid, vw, a = _scene(3, mode="scatter", noise_db=-20.0, decorrelation=0.05)
    _, _, _, b = _scene(3, mode="scatter", noise_db=-20.0, decorrelation=0.05)
    shifts = [np.tile(grid.vec_to_m([0.0, 0.0, 0.3 * k]), (len(P), 1)) for k in range(5)]
    plain = [a.frame(u) for u in shifts]
    ahead = list(rendered_ahead(b.frame, shifts))      # one worker: the same draws
    assert len(ahead) == 5 and all(np.array_equal(p, q) for p, q in zip(plain, ahead))
    _, _, _, w = _scene(3)                                      # warped: stateless, two workers
    assert w.stateless and not a.stateless and not _scene(3, bmode_noise=0.01)[3].stateless
    plain = [w.frame(u) for u in shifts]
    assert all(np.array_equal(p, q) for p, q in zip(plain, rendered_ahead(w.frame, shifts, stateless=True)))
    assert not np.array_equal(plain[0], plain[4])


@pytest.mark.parametrize("shape", [(9, 7, 11), (6, 1, 5)])
def test_trilinear_kernel_is_scipys_linear_interpolation_to_rounding(shape):
    # the compiled sampler of the inverse map and the scatterers' motion against
    # map_coordinates(order=1, mode="nearest") per component, points beyond the grid included
    from scipy import ndimage

    from liverinv.imaging.kernels import trilinear
    rng = np.random.default_rng(2)
    field = rng.standard_normal(shape + (3,))
    pts = rng.uniform(-2.0, 1.2 * max(shape), size=(4000, 3))
    pts[:10] = np.array(shape) - 1.0                     # the last voxel exactly
    ref = np.stack([ndimage.map_coordinates(field[..., c], pts.T, order=1, mode="nearest") for c in range(3)], 1)
    got = trilinear(field, pts)
    assert np.abs(got - ref).max() < 1e-13 * np.abs(field).max()
    with pytest.raises(ValueError, match="trilinear"):
        trilinear(field[..., 0], pts)


@pytest.mark.parametrize("shape", [(9, 7, 11), (6, 2, 5), (1, 4, 3)])
def test_cubic_kernel_is_scipys_mirrored_cubic_spline_to_the_bit(shape):
    # the compiled sampler of the warp and of the tracker against map_coordinates(order=3,
    # prefilter=False, mode="mirror"): inside, at the edges, beyond the grid by several periods
    from scipy import ndimage

    from liverinv.imaging.kernels import cubic_mirror
    from liverinv.parallel import map_coordinates
    rng = np.random.default_rng(3)
    coef = ndimage.spline_filter(rng.random(shape).astype(np.float32), order=3, output=np.float32, mode="mirror")
    n = np.array(shape) - 1.0
    pts = np.concatenate([rng.uniform(-0.3, 1.3, size=(3000, 3)) * n,
                          rng.uniform(-5.0, 5.0, size=(2000, 3)) * np.maximum(n, 1.0),
                          rng.integers(-2, 3, size=(500, 3)) + rng.choice([0.0, 1e-12, -1e-12, 0.5], size=(500, 3)),
                          n + rng.integers(-2, 3, size=(500, 3)) + rng.choice([0.0, 1e-12, -1e-12, 0.5], size=(500, 3))])
    ref = ndimage.map_coordinates(coef, pts.T, order=3, prefilter=False, mode="mirror")
    got = cubic_mirror(coef, pts)
    assert got.dtype == ref.dtype and np.array_equal(got, ref)
    assert np.array_equal(map_coordinates(coef, pts, order=3, prefilter=False, mode="mirror"), ref)
    with pytest.raises(ValueError, match="cubic_mirror"):
        cubic_mirror(coef[0], pts)


def test_inverse_map_of_the_moving_voxels_is_the_iteration_to_the_bit():
    # warp_volume's compiled fixed point against inverse_map at the voxels that move
    from liverinv.imaging.kernels import inverse_map_at_voxels
    shape = (10, 9, 8)
    X = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).astype(float)
    u = 0.4 * np.sin(X / 3.0) + 0.1 * np.cos(X[..., ::-1] / 2.0)
    u[2:5, :, 1:3] = 0.0                                            # voxels that do not move
    moving = np.flatnonzero(np.abs(u).max(axis=-1).ravel() > 1e-6)
    for it in (1, 2, 6):
        index, Xm = inverse_map_at_voxels(u, it, 1e-6)
        assert np.array_equal(index, moving)
        assert np.array_equal(Xm, inverse_map(u, X.reshape(-1, 3)[moving], iterations=it, at_voxels=moving))
