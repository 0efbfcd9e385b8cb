"""Voxel-to-node weights: where each voxel sits in the mesh and how much it belongs to each node.

Choice of shape function. Every tet10 element is split into 8 linear sub-tetrahedra whose
vertices are its corner and mid-edge nodes (4 corner tets plus the inner octahedron cut
along one diagonal). Each node, corner or mid-side, gets the linear "hat" of the sub-tets
around it: the linear tetrahedral shape function of the paper's Appendix (Zienkiewicz),
on the refined P1 mesh. The hats are non-negative (unlike the quadratic tet10 functions,
which are negative in parts of the element and would make negative least-squares
weights) and sum to one at every voxel, so the same matrix also interpolates nodal
motion to voxels (``W.T @ u``).

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


def subtets(points, cells) -> np.ndarray:
    """(8 ne, 4) node indices of the linear sub-tetrahedra of tet10 `cells`."""
    s = _edge_slots(points, cells)
    e = lambda a, b: s[(min(a, b), max(a, b))]
    local = [(0, e(0, 1), e(0, 2), e(0, 3)), (1, e(0, 1), e(1, 2), e(1, 3)),
             (2, e(0, 2), e(1, 2), e(2, 3)), (3, e(0, 3), e(1, 3), e(2, 3))]
    d0, d1 = e(0, 2), e(1, 3)                       # octahedron diagonal
    ring = [e(0, 1), e(1, 2), e(2, 3), e(0, 3)]     # equator, cyclic
    local += [(d0, d1, ring[i], ring[(i + 1) % 4]) for i in range(4)]
    return cells[:, np.asarray(local)].reshape(-1, 4)


@dataclass
class VoxelWeights:
    """Voxels inside the mesh and their hat-function weights.

    Attributes
    ----------
    voxels : (m,) int, flat (C order) indices of the active voxels (centre inside the mesh)
    W : scipy.sparse.csr_matrix (n_nodes, m), W[n, a] = hat of node n at active voxel a
    grid : ImageGrid
    n_nodes : int
    """

    voxels: np.ndarray
    W: sp.csr_matrix
    grid: ImageGrid
    n_nodes: int

    @property
    def WT(self) -> sp.csr_matrix:
        if not hasattr(self, "_WT"):
            self._WT = self.W.T.tocsr()
        return self._WT

    @classmethod
    def build(cls, points, cells, grid: ImageGrid, stride=(1, 1, 1)) -> "VoxelWeights":
        """Locate every voxel centre of `grid` in the sub-tets of the mesh (reference
        configuration `points`, m) and build the sparse weight matrix.

        `stride` keeps only every stride[a]-th voxel along image axis a (a sparser
        quadrature of the neighbourhood sums; speckle is correlated over about one PSF
        width, so a stride up to the PSF sigma in voxels loses little information).
        """
        st = subtets(points, cells)
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
        vox = np.concatenate(owner_vox) if owner_vox else np.zeros(0, np.int64)
        order = np.argsort(vox)
        vox = vox[order]
        nodes = np.concatenate(owner_node)[order] if owner_vox else np.zeros((0, 4), np.int64)
        w = np.concatenate(owner_w)[order] if owner_vox else np.zeros((0, 4))
        w /= np.maximum(w.sum(1, keepdims=True), 1e-300)
        if tuple(stride) != (1, 1, 1):
            ijk = np.stack(np.unravel_index(vox, grid.shape), 1)
            keep = np.all(ijk % np.asarray(stride) == 0, axis=1)
            vox, nodes, w = vox[keep], nodes[keep], w[keep]
        cols = np.repeat(np.arange(len(vox)), 4)
        W = sp.csr_matrix((w.ravel(), (nodes.ravel(), cols)), shape=(len(points), len(vox)))
        log.info("voxel weights: %d of %d voxels inside the mesh, %d nonzeros",
                 len(vox), grid.size, W.nnz)
        return cls(voxels=vox, W=W, grid=grid, n_nodes=len(points))

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
