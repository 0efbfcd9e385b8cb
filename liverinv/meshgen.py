"""Tetrahedral meshes of the indentation benchmark cylinder, generated with gmsh.

The tissue is a cylinder of radius ``R`` and height ``H`` (axis z, bottom z = 0, top
z = H). The punch footprint, the disk r <= a on the top face, is embedded in the top face
so that its rim circle is a mesh edge, and the mesh is refined towards that rim, where
the contact stress is singular. Physical groups, as in the benchmark meshes: volume
``tissue``; surfaces ``bottom``, ``side``, ``top_free``, ``footprint``.

Examples
--------
>>> from liverinv.meshgen import PRESETS, generate_indentation_mesh, summarize_mesh
>>> path = generate_indentation_mesh("/tmp/cyl.msh", **PRESETS["fine"])  # doctest: +SKIP
>>> summarize_mesh(path)["n_tetra10"]  # doctest: +SKIP
2720

Command line::

    python -m liverinv.meshgen OUT.msh --preset fine
    python -m liverinv.meshgen OUT.msh --R 0.05 --H 0.0303 --a 0.006 --h-far 0.012 --h-rim 0.0015
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["generate_indentation_mesh", "refined_model_mesh", "summarize_mesh", "tet10_volumes", "tri6_areas",
           "PRESETS", "PHYSICAL_GROUPS"]

#: Physical group name -> (dimension, tag), the numbering of the benchmark meshes.
PHYSICAL_GROUPS = {"bottom": (2, 1), "side": (2, 2), "top_free": (2, 3), "footprint": (2, 4),
                   "tissue": (3, 5)}

#: Size presets (m) comparable to the benchmark meshes (gmsh 4.15): ``coarse``, the
#: default, 1487 nodes / 836 tet10 / 30 rim nodes (cylinder_coarse.msh: 1490 / 819 / 30);
#: ``fine``, 4487 / 2720 / 50 (cylinder_fine.msh: 4589 / 2798 / 50). Both reach the full
#: 9.2 mm indentation of the elastic benchmark law in felupe. Meshes with a rim much finer
#: than the footprint (e.g. h_rim = 1.2 mm with an unrefined disk) showed a local snap at
#: the rim near d = 8.4 mm that stops Newton's method.
#: ``tiny``, 630 nodes / 327 tet10: fast enough for the workflow's quick study and tests.
#: ``medium``, 3494 nodes / 2102 tet10: the fine rim and footprint with a coarser far field, an
#: inverse-model mesh for data simulated on ``cylinder_fine.msh`` (small-strain stiffness
#: 19.21 N/m; coarse 19.94, fine 19.07).
PRESETS = {
    "tiny": {"h_far": 0.03, "h_rim": 0.004},  # 630 nodes / 327 tet10: the quick study's mesh
    "coarse": {"h_far": 0.022, "h_rim": 0.0025},  # = the defaults of generate_indentation_mesh
    "medium": {"h_far": 0.016, "h_rim": 0.0015, "h_footprint": 0.0017},
    "fine": {"h_far": 0.013, "h_rim": 0.0015, "h_footprint": 0.0017, "dist_max": 0.035},
}


def _check_positive(**kwargs):
    for name, value in kwargs.items():
        if value is None:
            continue
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def _classify_surfaces(gmsh, R, H, a):
    """Map the boundary surfaces of the fragmented cylinder to the group names."""
    groups = {"bottom": [], "side": [], "top_free": [], "footprint": []}
    tol = 1e-6 * max(R, H)
    for dim, tag in gmsh.model.getEntities(2):
        zc = gmsh.model.occ.getCenterOfMass(dim, tag)[2]
        area = gmsh.model.occ.getMass(dim, tag)
        if abs(zc) < tol:
            groups["bottom"].append(tag)
        elif abs(zc - H) < tol:
            near_disk = abs(area - np.pi * a**2) < abs(area - np.pi * (R**2 - a**2))
            groups["footprint" if near_disk else "top_free"].append(tag)
        else:
            groups["side"].append(tag)
    for name, tags in groups.items():
        if len(tags) != 1:
            raise RuntimeError(f"expected one {name} surface after fragmenting, got {tags}")
    return {name: tags[0] for name, tags in groups.items()}


def _rim_curves(gmsh, H, a):
    """Tags of the curve(s) forming the footprint rim r = a, z = H."""
    out = []
    tol = 1e-4 * H  # OCC bounding boxes are padded by ~1e-7
    for dim, tag in gmsh.model.getEntities(1):
        xmin, ymin, zmin, xmax, ymax, zmax = gmsh.model.getBoundingBox(dim, tag)
        if abs(zmin - H) < tol and abs(zmax - H) < tol and abs(max(xmax, ymax) - a) < 1e-3 * a:
            out.append(tag)
    if not out:
        raise RuntimeError("footprint rim curve not found")
    return out


def _size_fields(gmsh, rim, R, H, a, h_far, h_rim, h_footprint, dist_max):
    """Distance + Threshold towards the rim, optionally a finer disk under the punch."""
    field = gmsh.model.mesh.field
    dist = field.add("Distance")
    field.setNumbers(dist, "CurvesList", rim)
    field.setNumber(dist, "Sampling", 200)
    thr = field.add("Threshold")
    field.setNumber(thr, "InField", dist)
    field.setNumber(thr, "SizeMin", h_rim)
    field.setNumber(thr, "SizeMax", h_far)
    field.setNumber(thr, "DistMin", 0.0)
    field.setNumber(thr, "DistMax", dist_max)
    background = thr
    if h_footprint is not None:
        cyl = field.add("Cylinder")
        for key, val in (("Radius", a), ("VIn", h_footprint), ("VOut", h_far),
                         ("XCenter", 0.0), ("YCenter", 0.0), ("ZCenter", H),
                         ("XAxis", 0.0), ("YAxis", 0.0), ("ZAxis", 2.0 * h_footprint)):
            field.setNumber(cyl, key, val)
        background = field.add("Min")
        field.setNumbers(background, "FieldsList", [thr, cyl])
    field.setAsBackgroundMesh(background)


def generate_indentation_mesh(path, R=0.05, H=0.0303, a=0.006, h_far=0.022, h_rim=0.0025,
                              h_footprint=None, order=2, dist_max=None, seed=0):
    """Mesh the tissue cylinder with tetrahedra refined towards the punch rim.

    Parameters
    ----------
    path : str or Path
        Output ``.msh`` file (gmsh 4.1 ASCII), written atomically.
    R, H : float
        Cylinder radius and height (m); bottom at z = 0, top at z = H.
    a : float
        Punch (footprint) radius (m), ``a < R``.
    h_far : float
        Element size far from the rim (m).
    h_rim : float
        Element size at the rim circle r = a, z = H (m), ``h_rim <= h_far``.
    h_footprint : float or None
        Element size on and just below the whole footprint disk (m); default
        ``min(1.12 h_rim, h_far)``, a nearly uniform disk as in the benchmark meshes.
    order : {1, 2}
        Element order: 2 gives ``tetra10`` (mid-edge nodes on the curved geometry).
    dist_max : float or None
        Distance from the rim over which the size grows from ``h_rim`` to ``h_far``
        (default ``0.9 (R - a)``).
    seed : int
        gmsh random seed (``Mesh.RandomSeed``), for reproducible meshes.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        On a non-positive size, ``a >= R``, ``h_rim > h_far`` or ``order`` not 1 or 2.
    """
    import gmsh

    _check_positive(R=R, H=H, a=a, h_far=h_far, h_rim=h_rim, h_footprint=h_footprint,
                    dist_max=dist_max)
    if a >= R:
        raise ValueError(f"a must be smaller than R, got a={a!r}, R={R!r}")
    if h_rim > h_far:
        raise ValueError(f"h_rim must not exceed h_far, got h_rim={h_rim!r}, h_far={h_far!r}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    if dist_max is None:
        dist_max = 0.9 * (R - a)
    if h_footprint is None:
        h_footprint = min(1.12 * h_rim, h_far)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    owns_session = not gmsh.isInitialized()
    if owns_session:
        gmsh.initialize(interruptible=False)
    model_name = f"indentation_{os.getpid()}_{id(path)}"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".msh", dir=path.parent)
    os.close(fd)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 1)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(model_name)
        occ = gmsh.model.occ
        cyl = occ.addCylinder(0.0, 0.0, 0.0, 0.0, 0.0, H, R)
        disk = occ.addDisk(0.0, 0.0, H, a, a)
        occ.fragment([(3, cyl)], [(2, disk)])
        occ.synchronize()
        vols = gmsh.model.getEntities(3)
        if len(vols) != 1:
            raise RuntimeError(f"expected one volume after fragmenting, got {vols}")
        surf = _classify_surfaces(gmsh, R, H, a)
        rim = _rim_curves(gmsh, H, a)

        for name, (dim, tag) in PHYSICAL_GROUPS.items():
            entity = vols[0][1] if dim == 3 else surf[name]
            gmsh.model.addPhysicalGroup(dim, [entity], tag, name=name)

        for key, val in (("Mesh.MeshSizeFromPoints", 0), ("Mesh.MeshSizeFromCurvature", 0),
                         ("Mesh.MeshSizeExtendFromBoundary", 0), ("Mesh.MeshSizeMax", h_far),
                         ("Mesh.MeshSizeMin", 0.5 * min(h_rim, h_footprint or h_rim)),
                         ("Mesh.Algorithm", 6), ("Mesh.Algorithm3D", 1),
                         ("Mesh.RandomSeed", seed), ("Mesh.Optimize", 1),
                         ("Mesh.MshFileVersion", 4.1), ("Mesh.Binary", 0),
                         ("Mesh.SaveAll", 0)):
            gmsh.option.setNumber(key, val)
        _size_fields(gmsh, rim, R, H, a, h_far, h_rim, h_footprint, dist_max)

        gmsh.model.mesh.generate(3)
        if order == 2:
            gmsh.model.mesh.setOrder(2)
        gmsh.write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if owns_session:
            gmsh.finalize()
        else:
            gmsh.model.remove()
    logger.info("wrote %s in %.2f s", path, time.perf_counter() - t0)
    return path


# Quadrature exact to degree 3 on the unit tetrahedron (Keast, 5 points, one negative weight);
# det J of a tet10 is cubic, so isoparametric volumes are exact.
_KEAST5 = (np.array([[0.25, 0.25, 0.25], [1 / 6, 1 / 6, 1 / 6], [0.5, 1 / 6, 1 / 6],
                     [1 / 6, 0.5, 1 / 6], [1 / 6, 1 / 6, 0.5]]),
           np.array([-2 / 15, 3 / 40, 3 / 40, 3 / 40, 3 / 40]))


def _tet10_dshape(r, s, t):
    """Shape function derivatives (10, 3) of the tet10 in VTK/meshio node order."""
    t1, t2, t3, t4 = 1 - r - s - t, r, s, t
    dt = np.array([[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    tt = (t1, t2, t3, t4)
    dN = [(4 * tt[i] - 1) * dt[i] for i in range(4)]
    for i, j in ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)):
        dN.append(4 * (tt[i] * dt[j] + tt[j] * dt[i]))
    return np.array(dN)


def tet10_volumes(points, cells):
    """Isoparametric volumes (m^3) of tet10 cells given in meshio (VTK) node order."""
    x = points[cells]  # (c, 10, 3)
    vol = np.zeros(len(cells))
    for q, w in zip(*_KEAST5):
        jac = np.einsum("cai,aj->cij", x, _tet10_dshape(*q))
        vol += w * np.linalg.det(jac)
    return vol


def tri6_areas(points, cells):
    """Areas (m^2) of triangle6 cells (6-point rule, exact for quadratic geometry)."""
    a, b = 0.445948490915965, 0.091576213509771
    pts = [(a, a), (1 - 2 * a, a), (a, 1 - 2 * a), (b, b), (1 - 2 * b, b), (b, 1 - 2 * b)]
    wts = [0.223381589678011] * 3 + [0.109951743655322] * 3
    x = points[cells]
    area = np.zeros(len(cells))
    for (r, s), w in zip(pts, wts):
        l1, l2, l3 = 1 - r - s, r, s
        dr = np.array([1 - 4 * l1, 4 * l2 - 1, 0, 4 * (l1 - l2), 4 * l3, -4 * l3])
        ds = np.array([1 - 4 * l1, 0, 4 * l3 - 1, -4 * l2, 4 * l2, 4 * (l1 - l3)])
        g1, g2 = np.einsum("cai,a->ci", x, dr), np.einsum("cai,a->ci", x, ds)
        area += 0.5 * w * np.linalg.norm(np.cross(g1, g2), axis=1)
    return area


def cylinder_of(mesh, tol=0.02):
    """(R, H, a) of a tet10 mesh of the indentation cylinder (axis z, bottom z = 0, the
    footprint a disk about the axis), or None with the reason when it is not one within `tol`
    (relative) of a cylinder."""
    X = mesh.points
    r = np.hypot(X[:, 0], X[:, 1])
    R, H = float(r.max()), float(X[:, 2].max() - X[:, 2].min())
    side, foot = mesh.nodes("side"), mesh.nodes("footprint")
    if abs(X[:, 2].min()) > tol * H or np.ptp(r[side]) > tol * R:
        return None, "not a cylinder about the z axis with its bottom at z = 0"
    a = float(r[foot].max())
    if not 0 < a < R or np.ptp(X[foot, 2]) > tol * H:
        return None, "its footprint is not a flat disk about the axis"
    return (R, H, a), ""


def refined_model_mesh(mesh, out, preset="medium"):
    """A forward-model mesh for data tracked on `mesh` (a TetMesh of the indentation cylinder):
    the same cylinder and footprint meshed with the `preset`'s sizes (the fine benchmark mesh's
    rim and footprint, a coarser far field), scaled by the punch radius over 6 mm; the coarse
    benchmark mesh is 4.6 % stiffer at the rim than the fine one, medium 0.7 %. Returns (path,
    note): path None, with the reason in the note, when `mesh` is not such a cylinder or has
    at least as many elements as the refined mesh would."""
    dims, why = cylinder_of(mesh)
    if dims is None:
        return None, f"the tracking mesh is kept as the model mesh: {why}"
    R, H, a = (round(v, 6) for v in dims)       # to 1 um: gmsh meshes a 1e-17 change of size otherwise
    scale = a / 0.006
    sizes = {k: v * scale for k, v in PRESETS[preset].items()}
    path = generate_indentation_mesh(out, R=R, H=H, a=a, **sizes)
    n = summarize_mesh(path)["n_tetra10"]
    if n <= mesh.n_elements:
        Path(path).unlink()
        return None, (f"the tracking mesh is kept as the model mesh: it has {mesh.n_elements} elements, "
                      f"the {preset} preset {n}")
    return Path(path), (f"{preset} preset for R {1e3 * R:.3g} mm, H {1e3 * H:.3g} mm, a {1e3 * a:.3g} mm: "
                        f"{n} elements against the tracking mesh's {mesh.n_elements}")


def summarize_mesh(path):
    """Counts, volume and group areas of a tet10 mesh (nodes of the groups included).

    Returns
    -------
    dict
        ``n_nodes``, ``n_tetra10``, ``volume``, and per surface group ``n_<group>`` (cells),
        ``area_<group>`` and ``nodes_<group>`` (sorted node indices).
    """
    import meshio

    m = meshio.read(path)
    out = {"n_nodes": len(m.points), "n_tetra10": len(m.get_cells_type("tetra10"))}
    out["volume"] = float(tet10_volumes(m.points, m.get_cells_type("tetra10")).sum())
    for name in ("bottom", "side", "top_free", "footprint"):
        tri6 = m.get_cells_type("triangle6")
        idx = m.cell_sets_dict.get(name, {}).get("triangle6", np.zeros(0, int))
        tri = tri6[np.asarray(idx, dtype=int)]
        out[f"n_{name}"] = len(tri)
        out[f"area_{name}"] = float(tri6_areas(m.points, tri).sum()) if len(tri) else 0.0
        out[f"nodes_{name}"] = np.unique(tri)
    return out


def main(argv=None):
    """``python -m liverinv.meshgen OUT.msh [--preset coarse|medium|fine] [--R ...]``."""
    p = argparse.ArgumentParser(description="Generate the indentation cylinder tet10 mesh.")
    p.add_argument("out", type=Path)
    p.add_argument("--preset", choices=sorted(PRESETS), default="coarse")
    p.add_argument("--R", type=float, default=0.05)
    p.add_argument("--H", type=float, default=0.0303)
    p.add_argument("--a", type=float, default=0.006)
    p.add_argument("--h-far", type=float)
    p.add_argument("--h-rim", type=float)
    p.add_argument("--h-footprint", type=float)
    p.add_argument("--dist-max", type=float)
    p.add_argument("--order", type=int, default=2, choices=(1, 2))
    args = p.parse_args(argv)
    sizes = dict(PRESETS[args.preset])
    for key in ("h_far", "h_rim", "h_footprint", "dist_max"):
        if getattr(args, key) is not None:
            sizes[key] = getattr(args, key)
    t0 = time.perf_counter()
    path = generate_indentation_mesh(args.out, R=args.R, H=args.H, a=args.a, order=args.order,
                                     **sizes)
    elapsed = time.perf_counter() - t0
    if args.order == 2:
        s = summarize_mesh(path)
        print(f"{path}: {s['n_nodes']} nodes, {s['n_tetra10']} tetra10, volume {s['volume']:.6e}"
              f" m^3 (pi R^2 H = {np.pi * args.R**2 * args.H:.6e}), footprint area"
              f" {s['area_footprint']:.6e} m^2, {elapsed:.2f} s")
    else:
        print(f"{path}: written in {elapsed:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
