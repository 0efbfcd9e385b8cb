"""Voxel-to-node weights: where each voxel sits in the mesh and how much it belongs to each node.

Choice of shape functions. Every tet10 element is split into 8 linear sub-tetrahedra whose
vertices are its corner and mid-edge nodes (4 corner tets plus the inner octahedron cut
along one diagonal).

* Tracking windows (`W`, the weights N_i of Eqs. A.2-A.4). ``window="subtet"`` (default):
  every node, corner or mid-side, has the linear tetrahedral shape function (Zienkiewicz)
  of the sub-tets around it, a "hat" on the refined P1 mesh; non-negative, summing to one
  at every voxel. ``window="element"``: a corner node gets the linear shape function of
  each whole element around it (its neighbourhood is all elements around it), a mid-side
  node, which has no linear shape function, keeps its sub-tet hat. Quadratic tet10
  functions are not used as weights: they are negative in parts of the element.
  On the coarse benchmark mesh the sub-tet windows track more accurately (the element
  windows of large elements average the motion over strain gradients: a bias), see
  benchmarks/bench_tracking.py.
* Interpolation (`Wi`, nodal motion -> voxels, used to place the neighbourhoods where the
  tissue has moved): ``interpolation="p1"`` (default) the sub-tet hats (the same functions
  as the windows); ``"p2"`` the tet10 quadratic shape functions on the straight-sided
  element (reproduces a forward run's field on this mesh; measured no more accurate on
  the benchmark and slower).

* Minimum support (`VoxelWeights.with_min_support`, used by the tracker): each window is
  widened to at least a cone of a given radius in voxels around its node,
  ``max(N_n, 1 - r / R)``, so that nodes of small elements average over enough speckle.

The weights are built once per mesh and image grid (`VoxelWeights.build`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .grid import ImageGrid

log = logging.getLogger(__name__)

__all__ = ["VoxelWeights", "subtets", "mesh_arrays"]


def mesh_arrays(mesh_or_path):
    """(points, cells) of a tet10 mesh: a `liverinv.mesh.TetMesh`, a path, or a pair."""
    if isinstance(mesh_or_path, tuple):
        return np.asarray(mesh_or_path[0], float), np.asarray(mesh_or_path[1], np.int64)
    if hasattr(mesh_or_path, "points") and hasattr(mesh_or_path, "cells"):
        cells = mesh_or_path.cells
        if isinstance(cells, list):  # a meshio.Mesh
            cells = mesh_or_path.cells_dict["tetra10"]
        return np.asarray(mesh_or_path.points, float), np.asarray(cells, np.int64)
    import meshio
    m = meshio.read(mesh_or_path)
    return np.asarray(m.points[:, :3], float), np.asarray(m.cells_dict["tetra10"], np.int64)


def _edge_slots(points, cells):
    """For local mid-edge slots 4..9, the pair of corner slots they bisect (found from the
    coordinates, so any tet10 node order whose first 4 nodes are the corners works)."""
    p = points[cells]
    pairs = [(a, b) for a in range(4) for b in range(a + 1, 4)]
    slots = {}
    for m in range(4, 10):
        err = [np.abs(p[:, m] - 0.5 * (p[:, a] + p[:, b])).max() for a, b in pairs]
        slots[pairs[int(np.argmin(err))]] = m
    if len(slots) != 6:
        raise ValueError("tet10 cells: mid-edge nodes do not bisect distinct edges")
    return slots


def subtets(points, cells, return_slots=False):
    """(8 ne, 4) node indices of the linear sub-tetrahedra of tet10 `cells` (sub-tet t lies
    in element t // 8); with `return_slots` also the (8, 4) local node slots of each."""
    s = _edge_slots(points, cells)
    e = lambda a, b: s[(min(a, b), max(a, b))]
    local = [(0, e(0, 1), e(0, 2), e(0, 3)), (1, e(0, 1), e(1, 2), e(1, 3)),
             (2, e(0, 2), e(1, 2), e(2, 3)), (3, e(0, 3), e(1, 3), e(2, 3))]
    d0, d1 = e(0, 2), e(1, 3)                       # octahedron diagonal
    ring = [e(0, 1), e(1, 2), e(2, 3), e(0, 3)]     # equator, cyclic
    local += [(d0, d1, ring[i], ring[(i + 1) % 4]) for i in range(4)]
    local = np.asarray(local)
    st = cells[:, local].reshape(-1, 4)
    return (st, local) if return_slots else st


@dataclass
class VoxelWeights:
    """Voxels inside the mesh and their hat-function weights.

    Attributes
    ----------
    voxels : (m,) int, flat (C order) indices of the active voxels (centre inside the mesh)
    W : scipy.sparse.csr_matrix (n_nodes, m), tracking-window weight of node n at voxel a
    Wi : scipy.sparse.csr_matrix (n_nodes, m), interpolation hat of node n at voxel a
    grid : ImageGrid
    n_nodes : int
    """

    voxels: np.ndarray
    W: sp.csr_matrix
    grid: ImageGrid
    n_nodes: int
    Wi: sp.csr_matrix | None = None
    adjacency: sp.csr_matrix | None = None

    def __post_init__(self):
        if self.Wi is None:
            self.Wi = self.W
        self.WT = self.Wi.T.tocsr()

    @staticmethod
    def node_adjacency(cells, n) -> sp.csr_matrix:
        """(n, n) 0/1 matrix: nodes that share an element (without the diagonal)."""
        cells = np.asarray(cells)
        k = cells.shape[1]
        r = np.repeat(cells, k, axis=1).ravel()
        c = np.tile(cells, (1, k)).ravel()
        A = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
        A.setdiag(0)
        A.eliminate_zeros()
        A.data[:] = 1.0
        return A

    @classmethod
    def build(cls, points, cells, grid: ImageGrid, stride=(1, 1, 1),
              window: str = "subtet", interpolation: str = "p1") -> "VoxelWeights":
        """Locate every voxel centre of `grid` in the sub-tets of the mesh (reference
        configuration `points`, m) and build the sparse weight matrix.

        `stride` keeps only every stride[a]-th voxel along image axis a (a sparser
        quadrature of the neighbourhood sums; speckle is correlated over about one PSF
        width, so a stride up to the PSF sigma in voxels loses little information).
        """
        if window not in ("element", "subtet"):
            raise ValueError(f"window must be 'element' or 'subtet', not {window!r}")
        if interpolation not in ("p1", "p2"):
            raise ValueError(f"interpolation must be 'p1' or 'p2', not {interpolation!r}")
        points, cells = np.asarray(points, float), np.asarray(cells, np.int64)
        st, slots = subtets(points, cells, return_slots=True)
        owner_t = []
        vx = grid.to_vox(points)                      # node coords in voxel units
        shape = np.asarray(grid.shape)
        owner_node = []
        owner_w = []
        owner_vox = []
        taken = np.zeros(grid.size, dtype=bool)
        v = vx[st]                                    # (nt, 4, 3)
        lo = np.maximum(np.ceil(v.min(1) - 1e-9).astype(int), 0)
        hi = np.minimum(np.floor(v.max(1) + 1e-9).astype(int), shape - 1)
        T = np.transpose(v[:, 1:] - v[:, :1], (0, 2, 1))   # (nt, 3, 3) columns = edges
        ok = np.all(hi >= lo, axis=1) & (np.abs(np.linalg.det(T)) > 1e-12)
        Tinv = np.zeros_like(T)
        Tinv[ok] = np.linalg.inv(T[ok])
        for t in np.flatnonzero(ok):
            ax = [np.arange(lo[t, a], hi[t, a] + 1) for a in range(3)]
            ijk = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
            lam = (ijk - v[t, 0]) @ Tinv[t].T
            lam = np.column_stack([1.0 - lam.sum(1), lam])
            inside = lam.min(1) >= -1e-9
            if not inside.any():
                continue
            flat = np.ravel_multi_index(ijk[inside].T, grid.shape)
            new = ~taken[flat]
            flat = flat[new]
            taken[flat] = True
            owner_vox.append(flat)
            owner_node.append(np.broadcast_to(st[t], (len(flat), 4)))
            owner_w.append(np.clip(lam[inside][new], 0.0, 1.0))
            owner_t.append(np.full(len(flat), t))
        vox = np.concatenate(owner_vox) if owner_vox else np.zeros(0, np.int64)
        order = np.argsort(vox)
        vox = vox[order]
        nodes = np.concatenate(owner_node)[order] if owner_vox else np.zeros((0, 4), np.int64)
        w = np.concatenate(owner_w)[order] if owner_vox else np.zeros((0, 4))
        tid = np.concatenate(owner_t)[order] if owner_vox else np.zeros(0, np.int64)
        w /= np.maximum(w.sum(1, keepdims=True), 1e-300)
        if tuple(stride) != (1, 1, 1):
            ijk = np.stack(np.unravel_index(vox, grid.shape), 1)
            keep = np.all(ijk % np.asarray(stride) == 0, axis=1)
            vox, nodes, w, tid = vox[keep], nodes[keep], w[keep], tid[keep]
        m, n = len(vox), len(points)
        cols = np.repeat(np.arange(m), 4)
        Wi = sp.csr_matrix((w.ravel(), (nodes.ravel(), cols)), shape=(n, m))
        W = Wi
        if m and (window == "element" or interpolation == "p2"):
            elem = tid // 8
            corners = cells[elem, :4]                              # (m, 4)
            pc = vx[corners]                                       # (m, 4, 3)
            Te = np.transpose(pc[:, 1:] - pc[:, :1], (0, 2, 1))
            ijk = np.stack(np.unravel_index(vox, grid.shape), 1).astype(float)
            lam = np.linalg.solve(Te, (ijk - pc[:, 0])[..., None])[..., 0]
            lam = np.column_stack([1.0 - lam.sum(1), lam])
        if m and interpolation == "p2":
            # quadratic tet10 shape functions on the straight-sided element (affine map)
            es = _edge_slots(points, cells)
            slots_e = [es[k] for k in sorted(es)]
            Nq = np.column_stack([lam * (2 * lam - 1)] + [4 * lam[:, a] * lam[:, b] for a, b in sorted(es)])
            nodes_q = np.column_stack([corners, cells[elem][:, slots_e]])
            Wi = sp.csr_matrix((Nq.ravel(), (nodes_q.ravel(), np.repeat(np.arange(m), 10))),
                               shape=(n, m))
        if m and window == "element":
            lam = np.clip(lam, 0.0, None)
            mid = slots[tid % 8] >= 4                              # sub-tet vertices that are mid-edge
            rows = np.concatenate([corners.ravel(), nodes[mid]])
            cc = np.concatenate([cols, np.broadcast_to(np.arange(m)[:, None], (m, 4))[mid]])
            W = sp.csr_matrix((np.concatenate([lam.ravel(), w[mid]]), (rows, cc)), shape=(n, m))
        log.info("voxel weights: %d of %d voxels inside the mesh, %d window nonzeros",
                 m, grid.size, W.nnz)
        return cls(voxels=vox, W=W, grid=grid, n_nodes=n, Wi=Wi,
                   adjacency=cls.node_adjacency(cells, n))

    def with_min_support(self, points, radius_vox: float) -> sp.csr_matrix:
        """Tracking windows with a minimum spatial support: node n's weight at voxel a is
        ``max(W[n, a], 1 - |x_a - X_n| / radius_vox)`` (a cone of `radius_vox` voxels around
        the node, over the voxels inside the mesh). Nodes whose elements reach further than
        the radius in every direction keep their window; the small windows of small
        elements (rim of the punch, refined surfaces) grow to about the radius."""
        from scipy.spatial import cKDTree
        if radius_vox <= 0 or not len(self.voxels):
            return self.W
        xa = np.stack(np.unravel_index(self.voxels, self.grid.shape), 1).astype(float)
        xn = self.grid.to_vox(np.asarray(points, float))
        lists = cKDTree(xa).query_ball_point(xn, radius_vox)
        rows = np.repeat(np.arange(len(xn)), [len(l) for l in lists])
        cols = np.concatenate([np.asarray(l, np.int64) for l in lists]) if len(rows) else np.zeros(0, np.int64)
        val = 1.0 - np.linalg.norm(xa[cols] - xn[rows], axis=1) / radius_vox
        keep = val > 0
        T = sp.csr_matrix((val[keep], (rows[keep], cols[keep])), shape=self.W.shape)
        return self.W.maximum(T).tocsr()

    def interpolate(self, nodal: np.ndarray) -> np.ndarray:
        """Nodal values (n, ...) interpolated to the active voxels (m, ...)."""
        return self.WT @ nodal

    def to_grid(self, nodal: np.ndarray, fill_outside: bool = True) -> np.ndarray:
        """Nodal vector field (n, 3) as a full grid (*shape, 3); voxels outside the mesh take
        the value of the nearest voxel inside (so interpolation near the surface is smooth)."""
        out = np.zeros((self.grid.size, nodal.shape[1]))
        out[self.voxels] = self.interpolate(nodal)
        out = out.reshape(*self.grid.shape, -1)
        if fill_outside and len(self.voxels):
            idx = self._nearest_inside()
            out = out[idx[0], idx[1], idx[2]]
        return out

    def mask(self) -> np.ndarray:
        """Boolean volume, True at voxels inside the mesh."""
        m = np.zeros(self.grid.size, bool)
        m[self.voxels] = True
        return m.reshape(self.grid.shape)

    def _nearest_inside(self):
        if not hasattr(self, "_near"):
            from scipy.ndimage import distance_transform_edt
            self._near = distance_transform_edt(~self.mask(), return_distances=False,
                                                return_indices=True)
        return self._near
