"""The discrete displacement space: quadratic tetrahedra (tet10), isoparametric.

Shape-function gradients and quadrature weights come from scikit-fem (`MeshTet2`,
`ElementTetP2`) and are re-indexed to the mesh file's node numbering. The sparsity pattern
of the global matrix is built once per space and reused by every assembly.
"""

from __future__ import annotations

import logging

import numpy as np

from ..mesh import TetMesh
from . import kernels

__all__ = ["Space", "RULES"]

# Named tetrahedron rules beyond scikit-fem's (points as barycentric (3, nq), weights (nq,)).
# "febio8": FEBio's FETet10G8 (degree 3, positive weights), the rule of the benchmark's
# FEBio poroelastic reference.
_a, _b, _c, _d = 0.0158359099, 0.3280546970, 0.6791431780, 0.1069522740
RULES = {
    "febio8": (np.array([[_a, _b, _b], [_b, _a, _b], [_b, _b, _a], [_b, _b, _b],
                         [_c, _d, _d], [_d, _c, _d], [_d, _d, _c], [_d, _d, _d]]).T,
               np.array([0.138527967] * 4 + [0.111472033] * 4) / 6.0),
}

log = logging.getLogger(__name__)


class Space:
    """Tet10 vector space on a mesh.

    Parameters
    ----------
    mesh : TetMesh
    intorder : degree the scikit-fem tetrahedron rule integrates exactly (2: 4 points)
    rule : a named rule of `RULES` instead (e.g. "febio8")

    Attributes
    ----------
    mesh : TetMesh
    dNdX : (ne, nq, 10, 3) shape-function gradients in the reference configuration
    dV : (ne, nq) quadrature weights times det J (reference volume per point)
    N : (nq, 10) shape-function values at the quadrature points
    X_q : (ne, nq, 3) reference positions of the quadrature points
    edofs : (ne, 30) global dof of (local node a, component i) at index 3 a + i
    """

    def __init__(self, mesh: TetMesh, intorder: int = 2, rule: str | None = None):
        from skfem import Basis, ElementTetP2, MeshTet1, MeshTet2

        self.mesh = mesh
        cells = mesh.cells
        p_used = np.unique(cells[:, :4])
        remap = -np.ones(mesh.n_nodes, dtype=np.int64)
        remap[p_used] = np.arange(len(p_used))
        t = remap[cells[:, :4]].T.copy()
        # scikit-fem numbers vertex dofs, then edge dofs; find the file node of each dof,
        # then build the isoparametric mesh with the file's (possibly curved) mid-nodes.
        skm1 = MeshTet1(mesh.points[p_used].T.copy(), t)
        basis1 = Basis(skm1, ElementTetP2(), intorder=intorder)
        file_of_dof = self._match_by_cells(basis1, skm1, cells, remap, p_used)
        self.skfem_dof_to_node = file_of_dof
        skm = MeshTet2(mesh.points[file_of_dof].T.copy(), t)
        if rule is None:
            basis = Basis(skm, ElementTetP2(), intorder=intorder)
        elif rule in RULES:
            basis = Basis(skm, ElementTetP2(), quadrature=RULES[rule])
        else:
            raise ValueError(f"unknown quadrature rule {rule!r}; named rules: {sorted(RULES)}")
        if not np.array_equal(basis.element_dofs, basis1.element_dofs):
            raise RuntimeError("scikit-fem dof numbering changed between linear and quadratic mesh")
        self.basis = basis
        ed = basis.element_dofs.T  # (ne, 10) skfem dofs, local skfem order
        local_nodes = file_of_dof[ed]  # file node of each skfem local dof
        nq = basis.X.shape[1]
        grads = np.stack([basis.basis[i][0].grad for i in range(10)], axis=0)  # (10, 3, ne, nq)
        self.dNdX = np.ascontiguousarray(grads.transpose(2, 3, 0, 1))
        self.N = np.stack([np.asarray(basis.basis[i][0])[0] for i in range(10)], axis=-1)  # (nq, 10)
        self.dV = np.ascontiguousarray(basis.dx)
        self.X_q = np.ascontiguousarray(np.stack([basis.mapping.F(basis.X)[j] for j in range(3)], -1))
        self.conn = local_nodes  # (ne, 10) file node of each local function
        self.edofs = (3 * local_nodes[:, :, None] + np.arange(3)).reshape(len(cells), 30)
        self.n_dofs = 3 * mesh.n_nodes
        self.nq = nq
        # dN_a/dX_J dV as one (10, nq * 3) matrix per element: the internal forces of many stress
        # changes at once are one small matrix product per element (`linearized`)
        G = np.transpose(self.dNdX, (0, 2, 1, 3))
        self._GdV_flat = np.ascontiguousarray((G * self.dV[:, None, :, None]).reshape(len(cells), 10, 3 * nq))
        vol = self.dV.sum()
        log.debug("space: %d elements, %d quadrature points each, volume %.6e", len(cells), nq, vol)

    @staticmethod
    def _match_by_cells(basis, skm, cells, remap, p_used):
        """skfem dof -> file node: vertices through `p_used`, edge dofs through the file
        cells' mid-edge nodes (meshio/VTK order: edges 01, 12, 20, 03, 13, 23)."""
        n_vert = skm.p.shape[1]
        out = -np.ones(basis.N, dtype=np.int64)
        out[basis.nodal_dofs[0]] = p_used
        vtk_edges = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])
        a = remap[cells[:, vtk_edges[:, 0]]]
        b = remap[cells[:, vtk_edges[:, 1]]]
        key_file = np.minimum(a, b) * n_vert + np.maximum(a, b)
        edges = np.sort(skm.edges, axis=0)
        key_sk = edges[0] * n_vert + edges[1]
        order = np.argsort(key_sk)
        pos = np.searchsorted(key_sk, key_file.ravel(), sorter=order)
        edge_idx = order[pos]
        if not np.array_equal(key_sk[edge_idx], key_file.ravel()):
            raise ValueError("mesh cells and scikit-fem edges disagree")
        out[basis.edge_dofs[0][edge_idx]] = cells[:, 4:].ravel()
        if (out < 0).any():
            raise ValueError("some scikit-fem dofs have no node in the mesh file")
        return out

    def internal_force(self, P, S=None, elements=None) -> np.ndarray:
        """Element internal force vectors (ne, 30) of first Piola-Kirchhoff stresses P
        (ne, nq, 3, 3): f_ai = sum_q P_iJ dN_a/dX_J dV; with S, of P = F S (P then holds F);
        of the `elements` only, if given (`kernels.internal_force`)."""
        G, dV = (self.dNdX, self.dV) if elements is None else (self.dNdX[elements], self.dV[elements])
        return kernels.internal_force(G, dV, P, S)

    def volume(self) -> float:
        return float(self.dV.sum())

    def gather(self, u: np.ndarray) -> np.ndarray:
        """(n_nodes, 3) nodal field -> (ne, 10, 3) element values."""
        return u[self.conn]

    def deformation_gradient(self, u: np.ndarray, elements=None) -> np.ndarray:
        """F = I + Grad u at every quadrature point, (ne, nq, 3, 3); of the `elements` only, if given."""
        conn, G = (self.conn, self.dNdX) if elements is None else (self.conn[elements], self.dNdX[elements])
        return kernels.deformation_gradient(u, conn, G)
