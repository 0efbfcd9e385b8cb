"""Vectorized assembly onto a reduced set of unknowns with a fixed sparsity pattern.

Every full dof (3 per node) maps to one reduced unknown with a sign (+1, or -1 for the
footprint u_z tied to the punch depth d, u_z = -d), or to nothing (a fixed dof). The CSR
pattern of the reduced matrix, and where each element-matrix entry lands in it, are
computed once; an assembly is then one `np.bincount`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["ReducedAssembler"]


class ReducedAssembler:
    """Scatter element vectors and matrices onto reduced unknowns.

    Parameters
    ----------
    edofs : (ne, m) int, full dof of each local element dof
    index : (n_full,) int, reduced unknown of each full dof, -1 when fixed
    sign : (n_full,) float, factor of the reduced unknown in the full dof
    n_red : number of reduced unknowns
    """

    def __init__(self, edofs, index, sign, n_red):
        self.edofs = edofs
        self.index = np.asarray(index, dtype=np.int64)
        self.sign = np.asarray(sign, dtype=float)
        self.n_red = int(n_red)
        ne, m = edofs.shape
        ri = self.index[edofs]  # (ne, m)
        rs = self.sign[edofs]
        self._vec_mask = ri >= 0
        self._vec_idx = ri[self._vec_mask]
        self._vec_sign = rs[self._vec_mask]
        rows = np.broadcast_to(ri[:, :, None], (ne, m, m))
        cols = np.broadcast_to(ri[:, None, :], (ne, m, m))
        mask = (rows >= 0) & (cols >= 0)
        self._mat_mask = mask
        self._mat_sign = (rs[:, :, None] * rs[:, None, :])[mask]
        key = rows[mask] * self.n_red + cols[mask]
        uniq, inv = np.unique(key, return_inverse=True)
        self._mat_map = inv
        self.nnz = len(uniq)
        r, c = np.divmod(uniq, self.n_red)
        indptr = np.zeros(self.n_red + 1, dtype=np.int64)
        np.add.at(indptr, r + 1, 1)
        self.indptr = np.cumsum(indptr)
        self.indices = c.astype(np.int32)
        self.rows = r
        self.indptr = self.indptr.astype(np.int32)
        self._fixed = {}       # index -> positions of its row and column, and of its diagonal (`fix`)

    def expand(self, q):
        """Full dof vector from reduced unknowns (n_red,), or full dof vectors (n_full, k)
        from (n_red, k)."""
        q = np.asarray(q)
        out = np.zeros((len(self.index),) + q.shape[1:])
        m = self.index >= 0
        out[m] = (self.sign[m] if q.ndim == 1 else self.sign[m, None]) * q[self.index[m]]
        return out

    def reduce(self, full):
        """Reduced unknowns (n_red,) of a full dof vector (a shorter vector: its leading dofs,
        the rest 0), the inverse of `expand` for a vector that meets the constraints."""
        full = np.asarray(full, float).ravel()
        out = np.zeros(self.n_red)
        m = np.flatnonzero(self.index[: full.size] >= 0)
        out[self.index[m]] = self.sign[m] * full[m]
        return out

    def vector(self, fe):
        """Reduced vector of element vectors fe (ne, m)."""
        return np.bincount(self._vec_idx, weights=self._vec_sign * fe[self._vec_mask], minlength=self.n_red)

    def full_vector(self, fe, n_full):
        """Full dof vector of element vectors fe (ne, m)."""
        return np.bincount(self.edofs.ravel(), weights=fe.ravel(), minlength=n_full)

    def matrix(self, Ke):
        """Reduced CSR matrix of element matrices Ke (ne, m, m); pattern shared by all calls."""
        data = np.bincount(self._mat_map, weights=self._mat_sign * Ke[self._mat_mask], minlength=self.nnz)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_red, self.n_red))

    def fix(self, K, index: int):
        """Make the reduced unknown `index` prescribed in K (a matrix of `matrix`): its row and
        column 0, its diagonal 1 (the positions are found once per index)."""
        at = self._fixed.get(index)
        if at is None:
            pos = self.positions(row=index, col=index)
            at = self._fixed[index] = (pos, pos[(self.rows[pos] == index) & (self.indices[pos] == index)])
        K.data[at[0]] = 0.0
        K.data[at[1]] = 1.0
        return K

    def positions(self, row=None, col=None):
        """Positions in the CSR data of the entries of one row and/or one column."""
        out = []
        if row is not None:
            out.append(np.arange(self.indptr[row], self.indptr[row + 1]))
        if col is not None:
            out.append(np.nonzero(self.indices == col)[0])
        return np.unique(np.concatenate(out)) if out else np.array([], dtype=np.int64)
