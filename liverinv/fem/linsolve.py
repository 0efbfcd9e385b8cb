"""Sparse direct solves of the reduced tangent, reusing the symbolic analysis.

The reduced tangent's sparsity pattern never changes for a model, so the fill-reducing
ordering and symbolic factorization are done once and every refactorization is numeric
only. PARDISO (Intel MKL through pypardiso) when installed; SuperLU (scipy) otherwise.
Measured on the coarse benchmark tangent (3971 unknowns, 2.7e5 non-zeros, 2 cores):
PARDISO analysis+factorization 125 ms, numeric refactorization 45 ms, solve 10 ms;
SuperLU (MMD on A^T+A) factorization 126 ms, solve 3 ms.

A symmetric matrix (`symmetric=True`: the indentation model's tangent, hyperelastic, QLV
and springs alike, under force and displacement control) is factorized by PARDISO as
symmetric indefinite (mtype -2, Bunch-Kaufman pivoting) from its upper triangle: on the
coarse benchmark tangent of an elastic fit, 1 thread, numeric refactorization 16.3 ms
against 28.8 ms, a solve 1.76 against 1.91 ms, a block of 51 right-hand sides 48.8 against
55.2 ms (factor 0.82e6 against 1.51e6 non-zeros).
"""

from __future__ import annotations

import logging
import os

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

__all__ = ["SparseSolver", "backend"]

log = logging.getLogger(__name__)

try:  # MKL is not available on every platform
    import pypardiso as _pardiso
except Exception:  # pragma: no cover
    _pardiso = None


def backend() -> str:
    return "pardiso" if _pardiso is not None else "superlu"


class SparseSolver:
    """Factorize matrices sharing one CSR pattern, and solve with the last factorization.

    The last factorization stays available (`solve`) until the next `factorize`, so
    sensitivities d u / d parameter can reuse it.
    """

    def __init__(self, method: str | None = None, symmetric: bool = False):
        self.method = method or backend()
        self.symmetric = bool(symmetric) and self.method == "pardiso"
        if self.method not in ("pardiso", "superlu"):
            raise ValueError(f"unknown linear solver {self.method!r}; use 'pardiso' or 'superlu'")
        if self.method == "pardiso" and _pardiso is None:
            raise ValueError("linear solver 'pardiso' needs the pypardiso package")
        self._ps = None
        self._pattern = None
        self._upper = None      # (mask of the pattern's upper-triangle entries, their indices, indptr)
        self.K = None
        self._A = None          # the matrix handed to PARDISO: K, or its upper triangle
        self.n_factorizations = 0

    def factorize(self, K):
        K = K.tocsr()
        if self.method == "superlu":
            self._lu = sla.splu(K.tocsc(), permc_spec="MMD_AT_PLUS_A")
        else:
            if not K.has_sorted_indices:
                K.sort_indices()
            pattern = (K.shape, K.nnz, hash(K.indptr.tobytes()), hash(K.indices.tobytes()))
            if pattern != self._pattern and self.symmetric:
                rows = np.repeat(np.arange(K.shape[0]), np.diff(K.indptr))
                mask = K.indices >= rows
                self._upper = (mask, K.indices[mask], np.concatenate([[0], np.cumsum(np.bincount(
                    rows[mask], minlength=K.shape[0]))]).astype(K.indptr.dtype))
            A = K
            if self.symmetric:
                mask, indices, indptr = self._upper
                A = sp.csr_matrix((K.data[mask], indices, indptr), shape=K.shape)
            if self._ps is None or pattern != self._pattern:
                if self._ps is None:
                    self._ps = _pardiso.PyPardisoSolver(mtype=-2 if self.symmetric else 11)
                    if self.symmetric:
                        self._ps.set_iparm(10, 13)    # pivot perturbation 1e-13, as for mtype 11
                    # pypardiso searches the whole environment tree for libmkl_rt on every
                    # new solver (1 s on this machine, 10 % of a coarse-mesh solve) unless
                    # told where it is: tell it, for every later solver of this process
                    os.environ.setdefault("PYPARDISO_MKL_RT", self._ps.libmkl._name)
                    self._ps.set_statistical_info_off()
                    # no iterative refinement: the Newton/BFGS loop corrects any small
                    # solve error, and each refinement step costs a full solve (2.5x faster)
                    self._ps.set_iparm(8, 0)
                self._ps.set_phase(11)
                self._ps._call_pardiso(A, np.zeros((K.shape[0], 1)))
                self._pattern = pattern
            self._ps.set_phase(22)
            self._ps._call_pardiso(A, np.zeros((K.shape[0], 1)))
            self._A = A
        self.K = K
        self.n_factorizations += 1

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.K is None:
            raise RuntimeError("solve before factorize")
        b = np.asarray(b, dtype=float)
        if self.method == "superlu":
            return self._lu.solve(np.ascontiguousarray(b) if b.ndim == 1 else np.asfortranarray(b))
        self._ps.set_phase(33)
        # several right-hand sides: pardiso reads b column-major
        x = self._ps._call_pardiso(self._A, np.asfortranarray(b if b.ndim == 2 else b[:, None]))
        return x.reshape(b.shape, order="F")

    def free(self):
        if self._ps is not None:
            self._ps.free_memory(everything=True)
            self._ps = None
