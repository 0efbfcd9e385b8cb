"""Split work over the cores: sparse products by row blocks, spline sampling by point chunks,
and independent solves beside this process's own work (`beside`).

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

import multiprocessing
import os
import sys
import threading
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np
from scipy import ndimage
from scipy import sparse as sp

__all__ = ["n_threads", "RowBlocks", "map_coordinates", "beside"]

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


#: the options of a prefiltered, mirrored cubic B-spline: `map_coordinates` takes the compiled kernel
_CUBIC_MIRROR = dict(order=3, prefilter=False, mode="mirror")


def map_coordinates(values: np.ndarray, points: np.ndarray, **options) -> np.ndarray:
    """`scipy.ndimage.map_coordinates(values, points.T, **options)` for points (m, ndim),
    in chunks of points on the threads (the same values to the bit). A cubic B-spline of a 3-D
    grid, mirrored beyond it and already prefiltered (the tracker's sampling), is evaluated by
    the compiled `imaging.kernels.cubic_mirror`: scipy's arithmetic in scipy's order, so the
    same values to the bit, 2.5x faster."""
    points = np.asarray(points, float)
    if options == _CUBIC_MIRROR and np.ndim(values) == 3:
        from .imaging.kernels import cubic_mirror

        def sample(p):
            return cubic_mirror(values, p)
    else:
        def sample(p):
            return ndimage.map_coordinates(values, p.T, **options)
    parts = n_threads()
    if parts < 2 or len(points) < MIN_SPLIT:
        return sample(points)
    return np.concatenate(_map(sample, np.array_split(points, parts)))


_BESIDE = None     # the work of `beside`, seen by its forked worker as it was at the fork


def _beside_job(i: int):
    return _BESIDE(i)


def _forget_pool():
    """In a forked worker: the parent's thread pool has no threads here."""
    global _pool
    _pool = None


def beside(main, work, n: int):
    """``main()`` here while ``work(i)`` for i = 0 .. n-1 runs in one more process, from the
    front, one job at a time; the jobs it has not started when ``main`` returns run here, from
    the back (so neither side waits while the other has work). Returns
    ``(main(), [work(0), ...])``.

    The worker is forked (Linux): it sees this process's objects as they are, and only the
    job index and the result are pickled. Where fork is not available, the worker is a
    thread (sparse factorizations and large array operations release the GIL). Run it under
    one thread per BLAS/OpenMP library (`threadpoolctl.threadpool_limits(1)`): the two sides
    each have one core of two."""
    global _BESIDE
    if n == 0:
        return main(), []
    forked = sys.platform == "linux" and "fork" in multiprocessing.get_all_start_methods()
    lock = threading.RLock()
    bounds = [0, n]          # the next job from the front, one past the last from the back
    futures = {}

    def claim(front: bool):
        with lock:
            if bounds[0] >= bounds[1]:
                return None
            if front:
                bounds[0] += 1
                return bounds[0] - 1
            bounds[1] -= 1
            return bounds[1]

    def submit_next(_=None):      # a job is handed over only when the worker is free
        with lock:                # claimed and its future stored at once: `main`'s side reads it
            i = claim(front=True)
            if i is None:
                return
            future = futures[i] = pool.submit(_beside_job if forked else work, i)
        future.add_done_callback(submit_next)

    _BESIDE = work
    try:
        pool = (ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                    initializer=_forget_pool) if forked
                else ThreadPoolExecutor(max_workers=1, thread_name_prefix="beside"))
        with pool:
            submit_next()
            try:
                first = main()
            except BaseException:
                while claim(front=False) is not None:      # nothing more is handed over
                    pass
                raise
            here = {}
            while (i := claim(front=False)) is not None:
                here[i] = work(i)
            return first, [here[i] if i in here else futures[i].result() for i in range(n)]
    finally:
        _BESIDE = None
