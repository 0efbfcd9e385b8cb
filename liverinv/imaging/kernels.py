"""Compiled interpolation kernels (numba), where scipy's generic code is the bottleneck.

`trilinear` samples a vector field on the voxel grid at continuous voxel coordinates, as
``scipy.ndimage.map_coordinates(field[..., c], points.T, order=1, mode="nearest")`` for every
component c does, in one pass over the points (the weights are found once for the three
components). The values agree with scipy's to rounding (1.6e-15 of the largest value on a
128 x 48 x 204 x 3 field, `tests/test_imaging_speckle.py`); it is 5x faster (193 -> 38 ms for
1.25e6 points, one thread). Rendering a warped volume spends most of its time here: the
inverse map's fixed point samples the displacement grid five times per volume
(`sequence.inverse_map`). The kernel releases the GIL, so the rendering threads of
`sequence.rendered_ahead` run it side by side. Compiled on first use and cached on disk.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["trilinear"]


@numba.njit(cache=True, nogil=True)
def _trilinear(field, points, out):
    n0, n1, n2, nc = field.shape
    for k in range(points.shape[0]):
        # "nearest": beyond the grid the edge value, i.e. the coordinate clamped to the grid
        x = min(max(points[k, 0], 0.0), n0 - 1.0)
        y = min(max(points[k, 1], 0.0), n1 - 1.0)
        z = min(max(points[k, 2], 0.0), n2 - 1.0)
        i, j, m = min(int(x), max(n0 - 2, 0)), min(int(y), max(n1 - 2, 0)), min(int(z), max(n2 - 2, 0))
        tx, ty, tz = x - i, y - j, z - m
        i1, j1, m1 = min(i + 1, n0 - 1), min(j + 1, n1 - 1), min(m + 1, n2 - 1)
        for c in range(nc):
            out[k, c] = ((1.0 - tx) * ((1.0 - ty) * ((1.0 - tz) * field[i, j, m, c] + tz * field[i, j, m1, c])
                                       + ty * ((1.0 - tz) * field[i, j1, m, c] + tz * field[i, j1, m1, c]))
                         + tx * ((1.0 - ty) * ((1.0 - tz) * field[i1, j, m, c] + tz * field[i1, j, m1, c])
                                 + ty * ((1.0 - tz) * field[i1, j1, m, c] + tz * field[i1, j1, m1, c])))


def trilinear(field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(m, c) values of the grid field `field` (n0, n1, n2, c) at voxel coordinates `points`
    (m, 3), trilinear, the edge value beyond the grid."""
    field = np.ascontiguousarray(field, dtype=np.float64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    if field.ndim != 4 or points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"trilinear: a (n0, n1, n2, c) field and (m, 3) points, not {field.shape} and {points.shape}")
    out = np.empty((points.shape[0], field.shape[3]))
    _trilinear(field, points, out)
    return out
