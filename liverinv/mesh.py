"""Reading and checking the indentation meshes (quadratic tetrahedra with named groups).

A mesh is any file meshio reads that holds `tetra10` cells and the named surface groups of
the canonical benchmark (`bottom`, `side`, `top_free`, `footprint`, as triangle6 facets).
Nodes keep the file's numbering everywhere in liverinv, so a run file's `u(node)` lines up
with the mesh file.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["TetMesh", "read_mesh", "REQUIRED_GROUPS", "MeshError"]

log = logging.getLogger(__name__)

REQUIRED_GROUPS = ("bottom", "side", "top_free", "footprint")


class MeshError(ValueError):
    """A mesh file that cannot be used: the message names the file and what is wrong."""


@dataclass
class TetMesh:
    """Quadratic tetrahedral mesh.

    Attributes
    ----------
    points : (n, 3) float, reference coordinates in m
    cells : (ne, 10) int, tet10 connectivity in meshio (VTK) order (4 corners, then the
        mid-edge nodes of edges 01, 12, 20, 03, 13, 23)
    facets : dict of group name -> (nf, 6) int triangle6 connectivity
    cell_region : (ne,) int region id per element (gmsh physical tag or 0)
    path : the file it came from, or None
    """

    points: np.ndarray
    cells: np.ndarray
    facets: dict = field(default_factory=dict)
    cell_region: np.ndarray | None = None
    path: Path | None = None

    def __post_init__(self):
        self.points = np.ascontiguousarray(self.points, dtype=float)
        self.cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        if self.cell_region is None:
            self.cell_region = np.zeros(len(self.cells), dtype=np.int64)

    @property
    def n_nodes(self) -> int:
        return len(self.points)

    @property
    def n_elements(self) -> int:
        return len(self.cells)

    def nodes(self, group: str) -> np.ndarray:
        """Sorted unique node indices of a facet group."""
        if group not in self.facets:
            raise KeyError(f"mesh has no group {group!r}; it has {sorted(self.facets)}")
        return np.unique(self.facets[group])

    def corner_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes that are tetrahedron corners (the P1 nodes)."""
        return np.unique(self.cells[:, :4])


def read_mesh(path, required=REQUIRED_GROUPS) -> TetMesh:
    """Read a tet10 mesh with named facet groups; raise MeshError naming the file and the
    problem when the file is unreadable, holds no tetra10 cells or lacks a group."""
    import meshio

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: mesh file not found")
    import contextlib
    import io

    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            m = meshio.read(path)
    except (Exception, SystemExit) as e:  # meshio raises many types, and exits on some files
        msg = " ".join((said.getvalue() if isinstance(e, SystemExit) else str(e)).split())
        raise MeshError(f"{path}: meshio cannot read it as a mesh ({type(e).__name__}: {msg})") from None

    types = [c.type for c in m.cells]
    tets = [i for i, t in enumerate(types) if t == "tetra10"]
    if not tets:
        raise MeshError(f"{path}: no tetra10 (quadratic tetrahedron) cells; found {sorted(set(types))}."
                        " liverinv needs quadratic tetrahedra (gmsh: Mesh.ElementOrder = 2)")
    cells = np.concatenate([m.cells[i].data for i in tets])
    phys = m.cell_data.get("gmsh:physical")
    region = (np.concatenate([np.asarray(phys[i]) for i in tets]) if phys is not None
              else np.zeros(len(cells), dtype=np.int64))

    facets = {}
    for name, blocks in (m.cell_sets or {}).items():
        if name.startswith("gmsh:"):
            continue
        tri = [m.cells[i].data[np.asarray(idx)] for i, idx in enumerate(blocks)
               if idx is not None and len(idx) and m.cells[i].type == "triangle6"]
        if tri:
            facets[name] = np.concatenate(tri).astype(np.int64)
    missing = [g for g in required if g not in facets]
    if missing:
        raise MeshError(f"{path}: missing named surface group(s) {missing} (triangle6 physical "
                        f"groups); found {sorted(facets)}")
    used = np.unique(cells)
    pts = np.asarray(m.points, dtype=float)
    if pts.shape[1] == 2:
        raise MeshError(f"{path}: points are 2D; a 3D tetrahedral mesh is needed")
    mesh = TetMesh(points=pts[:, :3], cells=cells, facets=facets, cell_region=region, path=path)
    if len(used) != len(pts):
        log.warning("%s: %d points are not used by any tetra10 cell", path, len(pts) - len(used))
    return mesh
