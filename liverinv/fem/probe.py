"""Evaluate a nodal tet10 field at arbitrary points (e.g. a truth run on a fine mesh at the
nodes of a coarse inverse mesh).

Each point is located in the straight-sided tetrahedron of an element's four corners
(candidates: the elements of the nearest corner nodes; the one with the largest smallest
barycentric coordinate wins, so points on a curved boundary a hair outside every straight
tetrahedron still find their element); Newton iterations on the isoparametric map then
give its local coordinates in the curved element, where the quadratic shape functions are
evaluated. Exact for fields quadratic in the reference coordinates on straight elements.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["Probe", "tet10_shape"]

# meshio/VTK tet10 order: corners 0-3, then edges 01, 12, 20, 03, 13, 23
_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))


def _tet10_dshape(lam):
    """(m, 10, 3) derivatives of the shape functions by xi = (lam1, lam2, lam3)."""
    dl = np.zeros((len(lam), 10, 4))            # by lam_0..lam_3 as independent variables
    for a in range(4):
        dl[:, a, a] = 4 * lam[:, a] - 1
    for j, (a, b) in enumerate(_EDGES):
        dl[:, 4 + j, a] = 4 * lam[:, b]
        dl[:, 4 + j, b] = 4 * lam[:, a]
    return dl[:, :, 1:] - dl[:, :, :1]


def _isoparametric_inverse(Xe, X, lam, iterations=6):
    """Newton on x(xi) = X for curved tet10 elements (nodes Xe (m, 10, 3)) from lam."""
    for _ in range(iterations):
        r = np.einsum("ma,mai->mi", tet10_shape(lam), Xe) - X
        J = np.einsum("mai,maj->mij", Xe, _tet10_dshape(lam))
        dxi = np.linalg.solve(J, r[..., None])[..., 0]
        lam = lam.copy()
        lam[:, 1:] -= dxi
        lam[:, 0] = 1 - lam[:, 1:].sum(1)
    return lam


def tet10_shape(lam: np.ndarray) -> np.ndarray:
    """(m, 10) quadratic shape functions at barycentric coordinates lam (m, 4)."""
    N = np.empty((len(lam), 10))
    N[:, :4] = lam * (2 * lam - 1)
    for j, (a, b) in enumerate(_EDGES):
        N[:, 4 + j] = 4 * lam[:, a] * lam[:, b]
    return N


class Probe:
    """Interpolation from the nodes of a tet10 mesh (points P, cells C) to `targets`.

    Attributes: `element` (m,) containing element, `lam` (m, 4) barycentric coordinates,
    `outside` (m,) how far outside the located straight tetrahedron (0 inside; in
    barycentric units), `matrix` (m, n) sparse interpolation matrix.
    """

    def __init__(self, P, C, targets, candidates=8):
        import scipy.sparse as sp

        P, C, X = np.asarray(P, float), np.asarray(C, np.int64), np.asarray(targets, float)
        corners = np.unique(C[:, :4])
        # elements around each corner node
        inc = sp.csr_matrix((np.ones(C[:, :4].size), (C[:, :4].ravel(), np.repeat(np.arange(len(C)), 4))),
                            shape=(len(P), len(C)))
        _, near = cKDTree(P[corners]).query(X, k=min(candidates, len(corners)))
        near = corners[np.atleast_2d(near.T).T]
        T = P[C[:, :4]]                                         # (ne, 4, 3)
        A = np.linalg.inv(np.stack([T[:, 1] - T[:, 0], T[:, 2] - T[:, 0], T[:, 3] - T[:, 0]], axis=2))
        best_e = np.full(len(X), -1)
        best_min = np.full(len(X), -np.inf)
        best_lam = np.zeros((len(X), 4))
        for j in range(near.shape[1]):
            rows = inc[near[:, j]]
            for k in range(int(np.diff(rows.indptr).max())):
                has = np.diff(rows.indptr) > k
                idx = np.nonzero(has)[0]
                e = rows.indices[rows.indptr[idx] + k]
                xi = np.einsum("mij,mj->mi", A[e], X[idx] - T[e, 0])
                lam = np.column_stack([1 - xi.sum(1), xi])
                m = lam.min(1)
                better = m > best_min[idx]
                best_min[idx[better]], best_e[idx[better]], best_lam[idx[better]] = m[better], e[better], lam[better]
        best_lam = _isoparametric_inverse(P[C[best_e]], X, best_lam)
        self.element, self.lam = best_e, best_lam
        self.outside = np.clip(-best_lam.min(1), 0, None)
        N = tet10_shape(best_lam)
        self.matrix = sp.csr_matrix((N.ravel(), (np.repeat(np.arange(len(X)), 10), C[best_e].ravel())),
                                    shape=(len(X), len(P)))

    def __call__(self, field: np.ndarray) -> np.ndarray:
        """Field at the targets: nodal field (..., n, c) -> (..., m, c)."""
        f = np.moveaxis(np.asarray(field, float), -2, 0)       # (n, ..., c)
        out = self.matrix @ f.reshape(f.shape[0], -1)
        return np.moveaxis(out.reshape((-1,) + f.shape[1:]), 0, -2)
