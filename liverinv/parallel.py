"""Split work over the cores: sparse products by row blocks, spline sampling by point chunks.

scipy's sparse products with a dense array (`csr_matvecs`) and ndimage's `map_coordinates`
release the GIL, so the row blocks of a CSR matrix, or the chunks of a list of sample points,
run on a small thread pool at once. Each output row or point is computed by the same code
as with one thread, so the results are identical to the bit. The nodal tracker spends most of
its time in these two calls (the window products W @ X of its 1490 x 155136 windows with 6e6
nonzeros on the coarse benchmark mesh, and the cubic sampling of the next frame at 155136
voxels, 8 times per frame pair).

The number of threads is ``LIVERINV_THREADS`` if set, else the cores this process may use
(at most 4). Work below `MIN_SPLIT` nonzeros or points stays on the calling thread.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy import ndimage
from scipy import sparse as sp

__all__ = ["n_threads", "RowBlocks", "map_coordinates"]

#: nonzeros (products) or sample points below which one thread is as fast as several
MIN_SPLIT = 100_000

_pool: ThreadPoolExecutor | None = None


def n_threads() -> int:
    """Threads for split work: ``LIVERINV_THREADS``, else the usable cores (at most 4)."""
    env = os.environ.get("LIVERINV_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"LIVERINV_THREADS must be a positive integer, not {env!r}") from None
        if n < 1:
            raise ValueError(f"LIVERINV_THREADS must be a positive integer, not {env!r}")
        return n
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:        # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, 4))


def _map(fn, items) -> list:
    """fn over items on the module's pool (leaf tasks only: nothing submitted from inside)."""
    global _pool
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=max(n_threads(), 2), thread_name_prefix="split")
    return list(_pool.map(fn, items))


class RowBlocks:
    """A CSR matrix whose products with dense arrays (``A @ X``) run in row blocks of about
    equal nonzeros, one per thread; ``A @ X`` equals ``matrix @ X`` to the bit."""

    def __init__(self, matrix, parts: int | None = None):
        self.matrix = sp.csr_matrix(matrix)
        self.parts = n_threads() if parts is None else int(parts)
        self._blocks = None          # made at the first product (a tracker built for its windows only needs none)

    @property
    def shape(self):
        return self.matrix.shape

    @property
    def blocks(self) -> list:
        if self._blocks is None:
            A, parts = self.matrix, self.parts
            if parts < 2 or A.nnz < MIN_SPLIT or A.shape[0] < 2 * parts:
                self._blocks = [A]
            else:
                cuts = np.searchsorted(A.indptr, np.linspace(0, A.nnz, parts + 1)[1:-1])
                edges = np.unique(np.concatenate([[0], cuts, [A.shape[0]]]))
                self._blocks = [A[a:b] for a, b in zip(edges[:-1], edges[1:])]
        return self._blocks

    def __matmul__(self, x):
        blocks = self.blocks
        if len(blocks) == 1:
            return self.matrix @ x
        return np.concatenate(_map(lambda block: block @ x, blocks), axis=0)


def map_coordinates(values: np.ndarray, points: np.ndarray, **options) -> np.ndarray:
    """`scipy.ndimage.map_coordinates(values, points.T, **options)` for points (m, ndim),
    in chunks of points on the threads (the same values to the bit)."""
    points = np.asarray(points, float)
    parts = n_threads()
    if parts < 2 or len(points) < MIN_SPLIT:
        return ndimage.map_coordinates(values, points.T, **options)
    chunks = np.array_split(points, parts)
    return np.concatenate(_map(lambda p: ndimage.map_coordinates(values, p.T, **options), chunks))
