r"""Tangential springs on a face: the punch footprint's friction and the bottom's slip.

A face group carries a distributed tangential spring of stiffness k per area (Pa/m),
energy ``1/2 k int_face |u_t|^2 dA`` with u_t = (u_x, u_y) (the punch face and the bottom
are horizontal planes), discretized with the consistent tri6 face mass matrix
``M_ab = int N_a N_b dA`` (6-point rule, exact for the degree-4 products). It is linear in
the reference-configuration displacement (slip small against the face size). On reduced
unknowns it is a constant matrix ``k A`` (A per unit stiffness): the residual gains
``k A q`` and the tangent ``k A``, added in place into the tangent's fixed pattern (every
face entry couples nodes of one tetrahedron, so it is already in the pattern).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["FaceSpring", "SpringTerms", "tri6_mass"]

# 6-point Gauss rule on the reference triangle (degree 4), area 1/2 in total
_A, _B = 0.445948490915965, 0.091576213509771
_W1, _W2 = 0.223381589678011 / 2, 0.109951743655322 / 2
_QP = np.array([[_A, _A], [1 - 2 * _A, _A], [_A, 1 - 2 * _A], [_B, _B], [1 - 2 * _B, _B], [_B, 1 - 2 * _B]])
_QW = np.array([_W1] * 3 + [_W2] * 3)


def _tri6_shape(xi, eta):
    l1, l2, l3 = 1 - xi - eta, xi, eta
    return np.array([l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), l3 * (2 * l3 - 1), 4 * l1 * l2, 4 * l2 * l3, 4 * l3 * l1])


def tri6_mass(points, tri6) -> np.ndarray:
    """(nf, 6, 6) consistent mass matrices of straight-sided tri6 faces (meshio order)."""
    x = points[tri6[:, :3]]
    area2 = np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)   # 2 x area
    N = np.stack([_tri6_shape(*q) for q in _QP])                                     # (nq, 6)
    ref = np.einsum("q,qa,qb->ab", _QW, N, N)                                        # on the unit triangle
    return area2[:, None, None] * ref[None]


class FaceSpring:
    """The reduced matrix A (per unit stiffness) of a tangential spring on `faces`, and where
    its entries land in the CSR pattern of the assembler `asm`."""

    def __init__(self, points, faces, asm):
        M = tri6_mass(points, faces)
        rows, cols, vals = [], [], []
        for c in (0, 1):
            d = asm.index[3 * faces + c]                      # (nf, 6) reduced unknowns
            s = asm.sign[3 * faces + c]
            rr = np.broadcast_to(d[:, :, None], M.shape)
            cc = np.broadcast_to(d[:, None, :], M.shape)
            keep = (rr >= 0) & (cc >= 0)
            rows.append(rr[keep])
            cols.append(cc[keep])
            vals.append((M * s[:, :, None] * s[:, None, :])[keep])
        n = asm.n_red
        A = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
        A.sum_duplicates()
        self.A = A
        r = np.repeat(np.arange(n), np.diff(A.indptr))
        key = r.astype(np.int64) * n + A.indices
        pattern = asm.rows.astype(np.int64) * n + asm.indices
        pos = np.searchsorted(pattern, key)
        if np.any(pos >= len(pattern)) or np.any(pattern[np.minimum(pos, len(pattern) - 1)] != key):
            raise ValueError("face spring entries outside the tangent's pattern")
        self.positions, self.values = pos, A.data.copy()

    def force(self, k, q):
        return k * (self.A @ q)

    def add_tangent(self, K, k):
        K.data[self.positions] += k * self.values
        return K


class SpringTerms:
    """The tangential springs of a model (mixed into `Indentation` and `Biphasic`): the
    footprint's (`punch_spring`, stiffness `k_punch`) and the bottom's (`bottom_spring`,
    `k_bottom`), either spring None where the model has none."""

    def _springs(self):
        return [(f, k) for f, k in ((self.punch_spring, self.k_punch), (self.bottom_spring, self.k_bottom))
                if f is not None and k > 0]

    def spring_force(self, q) -> np.ndarray:
        """The tangential springs' part of the reduced residual at q."""
        r = np.zeros(self.n_red)
        for f, k in self._springs():
            r += f.force(k, q)
        return r
