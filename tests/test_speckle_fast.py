"""The spectral (NUFFT) IQ rendering against the exact sum of untruncated Gaussians."""

import numpy as np
import pytest

from liverinv.imaging.grid import ImageGrid
from liverinv.imaging.speckle import Transducer, random_scatterers, render_iq

TR = Transducer()
UNTRUNCATED = Transducer(truncate_sigmas=7.0)       # exp(-24.5): the exact sum, untruncated


def _rotated_grid():
    """Non-cubic, anisotropic voxels, image axes rotated against the mesh axes."""
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return ImageGrid((14, 9, 22), (0.5e-3, 0.6e-3, 0.3e-3), (-3e-3, -2e-3, 1e-3), R)


def _box(grid, margin_m):
    corners = grid.to_m(np.array([[i, j, k] for i in (0, grid.shape[0] - 1)
                                  for j in (0, grid.shape[1] - 1) for k in (0, grid.shape[2] - 1)]))
    return corners.min(0) - margin_m, corners.max(0) + margin_m


def _rel(a, ref):
    return np.abs(a - ref).max() / np.sqrt(np.mean(np.abs(ref) ** 2))


def _gaussian(grid, v, b, tr):
    """Analytic IQ of scatterers at voxel coordinates `v` with weights `b`, untruncated."""
    sig = np.asarray(tr.sigma_m) / np.asarray(grid.spacing_m)
    n = np.stack(np.meshgrid(*[np.arange(m) for m in grid.shape], indexing="ij"), -1)
    out = np.zeros(grid.shape, complex)
    for vs, bs in zip(v, b):
        out += bs * np.exp(-0.5 * (((n - vs) / sig) ** 2).sum(-1))
    return out


def test_nufft_matches_untruncated_exact_sum():
    grid = _rotated_grid()
    rng = np.random.default_rng(3)
    lo, hi = _box(grid, 7 * max(TR.sigma_m))         # many scatterers near and outside the faces
    pos, amp = random_scatterers(rng, lo, hi, 1.0, TR)
    amp = amp * np.exp(2j * np.pi * rng.random(len(amp)))       # complex amplitudes
    fast = render_iq(grid, pos, amp, TR)
    exact = render_iq(grid, pos, amp, UNTRUNCATED, method="exact")
    assert fast.shape == grid.shape and fast.dtype == np.complex64
    assert len(pos) > 1000
    assert _rel(fast, exact) < 5e-6
    # the default 3-sigma exact sum differs by its truncation error only
    assert 1e-4 < _rel(render_iq(grid, pos, amp, TR, method="exact"), exact) < 0.1


@pytest.mark.parametrize("method,tr", [("nufft", TR), ("exact", UNTRUNCATED)])
def test_scatterers_near_and_outside_faces(method, tr):
    grid = ImageGrid((12, 10, 16), (0.5e-3, 0.5e-3, 0.3e-3), (0.0, 0.0, 0.0))
    sig = np.asarray(tr.sigma_m) / np.asarray(grid.spacing_m)
    hi = np.asarray(grid.shape) - 1.0
    mid = hi / 2 + 0.3
    v = []
    for a in range(3):
        for d in (-0.4, 0.2, 1.7, 2.9):              # sigmas outside the face (< 0: inside)
            for lo_face in (True, False):
                p = mid.copy()
                p[a] = -d * sig[a] if lo_face else hi[a] + d * sig[a]
                v.append(p)
    v = np.array(v)
    rng = np.random.default_rng(0)
    b = rng.standard_normal(len(v)) + 1j * rng.standard_normal(len(v))
    pos = grid.to_m(v)
    amp = b * np.exp(2j * tr.k0 * v[:, 2] * grid.spacing_m[2])     # b_s = a_s e^{-2i k0 z_s}
    iq = render_iq(grid, pos, amp, tr, method=method)
    ref = _gaussian(grid, v, b, tr)
    assert _rel(iq, ref) < 2e-6


def test_far_scatterers_and_empty_input():
    grid = ImageGrid((8, 6, 10), (0.5e-3, 0.5e-3, 0.3e-3), (0.0, 0.0, 0.0))
    far = grid.to_m(np.array([[-8 * 2.0, 2.0, 5.0], [3.0, 2.0, 9 + 8 * 1.5]]))   # 8 sigmas out
    for method in ("nufft", "exact"):
        assert np.abs(render_iq(grid, far, [1.0, 1.0], TR, method=method)).max() < 1e-12
        empty = render_iq(grid, np.zeros((0, 3)), np.zeros(0), TR, method=method)
        assert empty.shape == grid.shape and not empty.any()
    with pytest.raises(ValueError):
        render_iq(grid, far, [1.0, 1.0], TR, method="fft")
