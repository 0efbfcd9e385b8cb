"""Split work (`liverinv.parallel`): the same numbers to the bit as on one thread."""

import os

import numpy as np
import pytest
from scipy import ndimage
from scipy import sparse as sp

from liverinv import parallel
from liverinv.parallel import RowBlocks, map_coordinates


def test_row_blocks_give_the_product_of_the_whole_matrix_to_the_bit():
    A = sp.random(3000, 20000, density=0.01, format="csr", random_state=3)       # 6e5 nonzeros
    x = np.random.default_rng(4).standard_normal((20000, 3))
    R = RowBlocks(A, parts=3)
    assert len(R.blocks) == 3 and sum(b.shape[0] for b in R.blocks) == 3000
    assert max(b.nnz for b in R.blocks) < 0.4 * A.nnz          # blocks of about equal nonzeros
    assert np.array_equal(R @ x, A @ x)
    assert np.array_equal(R @ x[:, 0], A @ x[:, 0])
    assert R.shape == A.shape


def test_small_matrices_stay_whole():
    A = sp.random(50, 60, density=0.1, format="csr", random_state=1)
    assert len(RowBlocks(A, parts=4).blocks) == 1


def test_split_spline_sampling_gives_the_same_values_to_the_bit():
    rng = np.random.default_rng(5)
    coef = ndimage.spline_filter(rng.random((40, 30, 50)).astype(np.float32), order=3, output=np.float32,
                                 mode="mirror")
    pts = rng.uniform(-2.0, 45.0, size=(parallel.MIN_SPLIT + 7, 3))      # some outside: mirrored
    whole = ndimage.map_coordinates(coef, pts.T, order=3, prefilter=False, mode="mirror")
    assert np.array_equal(map_coordinates(coef, pts, order=3, prefilter=False, mode="mirror"), whole)


def test_the_thread_count_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv("LIVERINV_THREADS", "3")
    assert parallel.n_threads() == 3
    monkeypatch.setenv("LIVERINV_THREADS", "0")
    with pytest.raises(ValueError, match="LIVERINV_THREADS"):
        parallel.n_threads()
    monkeypatch.delenv("LIVERINV_THREADS")
    assert 1 <= parallel.n_threads() <= 4


def _solve_in_order(i):
    """A job that takes a while: a dense solve whose answer depends on i."""
    A = np.eye(60) * (2.0 + i) + np.ones((60, 60)) / 60
    return float(np.linalg.solve(A, np.ones(60)).sum()), os.getpid()


@pytest.mark.parametrize("main_seconds", [0.0, 0.3])
def test_beside_returns_every_job_in_order(main_seconds):
    """Whether this process is busy for long (the worker does the jobs) or not at all (this
    process takes most of them from the back), every job is done once, in its place."""
    import time
    expected = [_solve_in_order(i)[0] for i in range(7)]
    first, results = parallel.beside(lambda: time.sleep(main_seconds) or "main", _solve_in_order, 7)
    assert first == "main"
    assert [r[0] for r in results] == expected
    if main_seconds and parallel.sys.platform == "linux":
        # the forked worker did at least the first job
        assert results[0][1] != os.getpid()


def test_beside_raises_what_a_job_or_main_raised():
    def bad(i):
        if i == 2:
            raise ValueError("job 2 failed")
        return i
    with pytest.raises(ValueError, match="job 2 failed"):
        parallel.beside(lambda: None, bad, 4)

    def bad_main():
        raise RuntimeError("main failed")
    with pytest.raises(RuntimeError, match="main failed"):
        parallel.beside(bad_main, _solve_in_order, 3)
