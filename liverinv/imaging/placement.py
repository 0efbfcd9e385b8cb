"""Can this mesh be tracked in these images? The placement check run by `liverinv check` and
before `liverinv track`: the fraction of mesh nodes inside the field of view, the texture in
the tissue, the frame-to-frame motion scale, and a picture of the mesh over orthogonal slices
of the first volume with the punch drawn.

Refused (one line, what is wrong and what to check): no node in view, a mesh whose size is
off by a unit factor (a mesh in mm against images in m), volumes without texture. Weak but
usable data (few nodes in view, motion near a voxel per frame, frames that do not change)
give warnings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


__all__ = ["PlacementReport", "check_placement", "placement_picture"]

MIN_IN_VIEW = 0.05          # fraction of nodes: below it, a warning; none: refused
MIN_TEXTURE = 1e-3          # RMS intensity gradient per voxel (B-mode in [0, 1]): below it, refused
MAX_MOTION_VOX = 1.0        # frame-to-frame motion estimate (voxels): above it, a warning
UNIT_FACTOR = 30.0          # mesh / field-of-view size ratio beyond which a unit mismatch is assumed


@dataclass
class PlacementReport:
    n_nodes: int
    in_view: float                 # fraction of mesh nodes inside the field of view
    texture: float                 # RMS of |grad I| (per voxel) in the tissue part of volume 0
    motion_vox: float              # median frame-to-frame motion estimate |I_t| / |grad I|, voxels
    size_ratio: float              # mesh bounding-box diagonal / field-of-view diagonal
    problems: list = field(default_factory=list)   # refusals
    warnings: list = field(default_factory=list)

    def lines(self) -> list[str]:
        return [f"{100 * self.in_view:.1f} % of {self.n_nodes} mesh nodes inside the field of view",
                f"texture in the tissue: RMS intensity gradient {self.texture:.3g} per voxel",
                f"frame-to-frame motion: about {self.motion_vox:.3g} voxel (median over the first pairs)",
                f"mesh size / field of view size: {self.size_ratio:.3g}"]


def _tissue_mask(grid, points):
    """Voxels inside the mesh's bounding box (the tissue, roughly)."""
    lo, hi = points.min(0), points.max(0)
    c = grid.centres().reshape(*grid.shape, 3)
    return np.all((c >= lo) & (c <= hi), axis=-1)


def check_placement(bundle, points, max_pairs: int = 3) -> PlacementReport:
    """Measure how trackable `bundle` is on a mesh with nodes `points` (m)."""
    grid = bundle.grid
    points = np.asarray(points, float)
    inside = grid.inside(points)
    fov = np.asarray(grid.shape) * np.asarray(grid.spacing_m)
    size_ratio = float(np.linalg.norm(np.ptp(points, axis=0)) / np.linalg.norm(fov))
    v0 = bundle.frame(0).astype(np.float64)
    mask = _tissue_mask(grid, points)
    if not mask.any():
        mask = np.ones(grid.shape, bool)
    g = np.gradient(v0)
    gmag = np.sqrt(sum(gi ** 2 for gi in g))
    texture = float(np.sqrt(np.mean(gmag[mask] ** 2)))
    motions = []
    prev = v0
    for k in range(1, min(bundle.n_frames, max_pairs + 1)):
        cur = bundle.frame(k).astype(np.float64)
        it = np.abs(cur - prev)[mask]
        motions.append(float(np.median(it) / max(np.median(gmag[mask]), 1e-12)))
        prev = cur
    motion = float(np.median(motions)) if motions else float("nan")
    rep = PlacementReport(len(points), float(inside.mean()), texture, motion, size_ratio)
    src = str(bundle.path)
    if size_ratio > UNIT_FACTOR or size_ratio < 1.0 / UNIT_FACTOR:
        rep.problems.append(f"{src}: the mesh is {size_ratio:.3g} x the size of the field of view: a unit "
                            "mismatch? (mesh coordinates must be in m, like the bundle's)")
    elif not inside.any():
        lo, hi = grid.to_m(np.zeros(3)), grid.to_m(np.asarray(grid.shape) - 1)
        rep.problems.append(f"{src}: no mesh node lies inside the field of view (nodes span "
                            f"{np.round(1e3 * points.min(0), 1)}..{np.round(1e3 * points.max(0), 1)} mm, images "
                            f"{np.round(1e3 * np.minimum(lo, hi), 1)}..{np.round(1e3 * np.maximum(lo, hi), 1)} mm): "
                            "check the mesh's placement and the bundle's origin/direction")
    elif texture < MIN_TEXTURE:
        rep.problems.append(f"{src}: the volumes have no texture in the tissue (RMS gradient {texture:.2g} per "
                            "voxel): constant or empty images cannot be tracked")
    if not rep.problems:
        if rep.in_view < MIN_IN_VIEW:
            rep.warnings.append(f"only {100 * rep.in_view:.1f} % of the mesh nodes are in view: the volumetric "
                                "term will rest on few nodes")
        if np.isfinite(motion) and motion > MAX_MOTION_VOX:
            rep.warnings.append(f"the frames move by about {motion:.2g} voxel each: beyond ~1 voxel per frame the "
                                "tracker loses accuracy (more frames per second, or --frames)")
        if np.isfinite(motion) and motion < 1e-6:
            rep.warnings.append("consecutive volumes are identical: no motion to track")
    return rep


def placement_picture(bundle, points, out, slab_m=2e-3):
    """The first volume's three orthogonal slices through the punch axis (or the image centre),
    the mesh nodes within `slab_m` of each slice, and the punch drawn at the top surface."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..fileio import atomic_path

    grid = bundle.grid
    v0 = bundle.frame(0)
    geo = bundle.geometry
    axis_xy = np.asarray(_json(geo.get("indenter_axis_m", [0.0, 0.0])), float)
    a_r = float(geo.get("indenter_radius_m", 0.006))
    points = np.asarray(points, float)
    top = points[:, 2].max() if len(points) else 0.0
    centre = np.array([axis_xy[0], axis_xy[1], 0.5 * (points[:, 2].min() + top) if len(points) else 0.0])
    idx = np.clip(np.rint(grid.to_vox(centre[None])[0]).astype(int), 0, np.asarray(grid.shape) - 1)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6))
    names = ("x", "y", "z")
    for ax, (cut, (h, vv)) in zip(axes, ((1, (0, 2)), (0, (1, 2)), (2, (0, 1)))):
        sl = [slice(None)] * 3
        sl[cut] = idx[cut]
        img = v0[tuple(sl)].T
        # voxel centres of the slice in mesh coordinates (axis-aligned grids are drawn exactly)
        ij = np.zeros((2, 3))
        ij[1] = np.asarray(grid.shape) - 1
        corners = grid.to_m(ij)
        ext = [1e3 * corners[0, h], 1e3 * corners[1, h], 1e3 * corners[0, vv], 1e3 * corners[1, vv]]
        ax.imshow(img, origin="lower", extent=ext, cmap="gray", aspect="equal")
        plane = grid.to_m(idx[None].astype(float))[0][cut]
        near = np.abs(points[:, cut] - plane) < slab_m
        ax.plot(1e3 * points[near, h], 1e3 * points[near, vv], ".", ms=2, color="tab:orange", label="mesh nodes")
        if cut != 2:
            c = axis_xy[0] if h == 0 else axis_xy[1]
            ax.plot([1e3 * (c - a_r), 1e3 * (c + a_r)], [1e3 * top] * 2, lw=4, color="tab:red", label="punch")
        else:
            t = np.linspace(0, 2 * np.pi, 100)
            ax.plot(1e3 * (axis_xy[0] + a_r * np.cos(t)), 1e3 * (axis_xy[1] + a_r * np.sin(t)), color="tab:red",
                    lw=2, label="punch")
        ax.set(xlabel=f"{names[h]} (mm)", ylabel=f"{names[vv]} (mm)", title=f"volume 0, {names[cut]} = "
               f"{1e3 * plane:.1f} mm")
    axes[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=100, format=str(out).rsplit(".", 1)[-1] if "." in str(out) else "png")
    plt.close(fig)
    return out


def _json(v):
    import json
    return json.loads(v) if isinstance(v, (str, bytes)) else v
