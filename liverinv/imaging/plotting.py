"""Pictures: a volume slice with the mesh cut and the tracked nodal motion drawn on it."""

from __future__ import annotations

import logging

import numpy as np

from ..fileio import atomic_path

log = logging.getLogger(__name__)

__all__ = ["mesh_cut", "flow_picture"]


def mesh_cut(points, cells, y0: float):
    """Polygons (list of (k, 2) arrays of (x, z)) where the plane y = y0 cuts the corner
    tetrahedra of `cells` (nodes at `points`, m)."""
    tets = points[np.asarray(cells)[:, :4]]                      # (ne, 4, 3)
    d = tets[..., 1] - y0
    cross = (d.min(1) < 0) & (d.max(1) > 0)
    polys = []
    edges = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    for t, dt in zip(tets[cross], d[cross]):
        pts = [t[a] + (t[b] - t[a]) * dt[a] / (dt[a] - dt[b])
               for a, b in edges if dt[a] * dt[b] < 0]
        p = np.asarray(pts)[:, [0, 2]]
        c = p.mean(0)
        polys.append(p[np.argsort(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))])
    return polys


def flow_picture(bundle, flow, cells, out, pair=None, slab_m=1.5e-3, min_confidence=0.02):
    """Draw frame `pair` of `bundle` (elevational mid-slice), the mesh cut at its tracked
    position, and the tracked motion of the nodes near the slice as arrows coloured by
    confidence. Saves a PNG at `out` (written atomically)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    g = bundle.grid
    u = flow["u_of"].values
    c = flow["c_of"].values.min(-1)
    if pair is None:
        pair = int(np.argmax([np.abs(u[k][c[k] > min_confidence]).sum() if (c[k] > min_confidence).any()
                              else 0 for k in range(len(u))]))
    vol = bundle.frame(pair)
    j = g.shape[1] // 2
    y0 = g.to_m([0, j, 0])[1]
    X = flow["X"].values
    x_now = X + flow["U_of"].values[pair]
    ax_x, ax_z = g.axis_m(0), g.axis_m(2)
    fig, ax = plt.subplots(figsize=(7, 7))
    ext = np.array([ax_x[0], ax_x[-1], ax_z[0], ax_z[-1]]) * 1e3
    ax.imshow(vol[:, j, :].T, origin="lower", cmap="gray", extent=ext, vmin=0, vmax=1)
    polys = [p * 1e3 for p in mesh_cut(x_now, cells, y0)]
    ax.add_collection(PolyCollection(polys, facecolors="none", edgecolors="tab:orange",
                                     linewidths=0.5))
    near = (np.abs(x_now[:, 1] - y0) < slab_m) & (c[pair] > min_confidence)
    vv = u[pair][near]
    scale = 3e-3 / max(np.abs(vv[:, [0, 2]]).max(), 1e-12) if near.any() else 1.0   # 3 mm arrows
    q = ax.quiver(x_now[near, 0] * 1e3, x_now[near, 2] * 1e3, vv[:, 0] * scale * 1e3,
                  vv[:, 2] * scale * 1e3, c[pair][near], cmap="viridis", angles="xy",
                  scale_units="xy", scale=1.0, width=0.004, clim=(0, 1))
    fig.colorbar(q, ax=ax, shrink=0.7, label="confidence (min over axes)")
    vmax_vox = np.abs(g.vec_to_vox(vv)).max() if near.any() else 0.0
    ax.set_title(f"frame {pair} -> {pair + 1}, t = {flow['time_start'].values[pair]:.2f} s, "
                 f"y = {y0 * 1e3:.1f} mm\narrows: tracked motion x{scale:.0f} "
                 f"(max {vmax_vox:.2f} voxel)")
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_xlabel("x, lateral (mm)")
    ax.set_ylabel("z, axial (mm); probe below")
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out
