"""A study's figures, each a function of files only: convergence per law (paper Figs. 5-6),
indenter histories of data and fitted laws (Fig. 7), vertical nodal velocity histories of
tracked and modelled motion (Figs. 8-9), and ParaView fields of tracked motion, model motion
and their difference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from ..fileio import atomic_path

__all__ = ["plot_convergence", "plot_indenter", "plot_velocities", "write_fields", "best_fits"]

SCALE = {"m": (1e3, "mm"), "m/s": (1e3, "mm/s"), "N": (1.0, "N"), "Pa": (1.0, "Pa")}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, out):
    out = Path(out)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format=out.suffix.lstrip(".") or "png")
    _plt().close(fig)
    return out


def best_fits(fits: xr.Dataset) -> dict:
    """law -> (seed, method) of its lowest-Phi fit that did not fail."""
    out = {}
    for law in fits.law.values:
        f = fits.sel(law=law)
        phi = np.where((f.status != "failed").values, f.phi.values, np.nan)
        if np.isfinite(phi).any():
            j, k = np.unravel_index(np.nanargmin(phi), phi.shape)
            out[str(law)] = (str(fits.seed.values[j]), str(fits.method.values[k]))
    return out


def plot_convergence(fits: xr.Dataset, law: str, out):
    """Phi and every parameter against forward solves, one line per seed (solid: least
    squares, dashed: Nelder-Mead), the truth dotted where known. A fit whose multi-start stage
    ran on merged frame pairs (`search_solves`) is drawn from the solve after that search (its
    Phi is on another scale)."""
    plt = _plt()
    f = fits.sel(law=law)
    params = [str(p) for p in fits.param.values if np.isfinite(f.start.sel(param=p).values).any()]
    n = 1 + len(params)
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    axes = axes.ravel()
    styles = {"least-squares": "-", "nelder-mead": "--"}
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    searched = 0
    for j, seed in enumerate(fits.seed.values):
        for method in fits.method.values:
            g = f.sel({"seed": seed, "method": method})
            phi = g.history_phi.values
            ok = np.isfinite(phi)
            if not ok.any():
                continue
            skip = int(g.search_solves) if "search_solves" in g and np.isfinite(g.search_solves) else 0
            x = skip + np.arange(1, len(phi) + 1)[ok]
            searched = max(searched, skip)
            kw = dict(color=colors[j % len(colors)], ls=styles.get(str(method), "-"), lw=1.2,
                      label=f"seed {seed} {method}")
            axes[0].plot(x, np.minimum.accumulate(phi[ok]), **kw)
            for a, p in zip(axes[1:], params):
                a.plot(x, g.history_params.sel(param=p).values[ok], **kw)
    axes[0].set(yscale="log", xlabel="forward solves", ylabel=f"best Phi ({fits.phi.attrs.get('units', '')})",
                title=f"{law}: misfit")
    axes[0].legend(fontsize=7)
    if searched:
        axes[0].set_xlabel(f"forward solves (the first {searched}: multi-start on merged frame pairs, not drawn)",
                           fontsize=8)
    for a, p in zip(axes[1:], params):
        unit = str(fits.param_unit.sel(param=p).values)
        t = float(fits.truth.sel(param=p))
        if np.isfinite(t):
            a.axhline(t, color="k", ls=":", lw=1, label="truth")
        a.set(xlabel="forward solves", ylabel=f"{p} ({unit})", title=p)
        if p in ("D1", "D2", "kappa", "tau_g1", "tau_k1"):
            a.set_yscale("log")
    for a in axes[n:]:
        a.set_visible(False)
    fig.tight_layout()
    return _save(fig, out)


def plot_indenter(bundle, fit_files: dict, out):
    """Force against depth, depth and force against time: the measured record and the model
    of each fitted law (`fit_files`: label -> fit file)."""
    from ..imaging.bundle import open_bundle
    plt = _plt()
    with open_bundle(bundle) as b:
        ind = b.indenter
        t, d, F = ind.time_s, ind.displacement_m, ind.force_N
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    ax[0].plot(1e3 * d, F, ".", ms=2, color="0.6", label="measured")
    ax[1].plot(t, 1e3 * d, ".", ms=2, color="0.6", label="measured")
    ax[2].plot(t, F, ".", ms=2, color="0.6", label="measured")
    for label, path in fit_files.items():
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            if "model_force" not in ds:
                continue
            tm, dm, fm = ds.model_time.values, ds.model_depth.values, ds.model_force.values
        ax[0].plot(1e3 * dm, fm, lw=1.5, label=label)
        ax[1].plot(tm, 1e3 * dm, lw=1.5, label=label)
        ax[2].plot(tm, fm, lw=1.5, label=label)
    ax[0].set(xlabel="indenter depth (mm)", ylabel="force (N)", title="force-displacement")
    ax[1].set(xlabel="time (s)", ylabel="indenter depth (mm)", title="depth")
    ax[2].set(xlabel="time (s)", ylabel="force (N)", title="force")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, out)


def velocity_nodes(X, c, n=4, slice_y=0.0):
    """`n` well-tracked nodes near the plane y = slice_y, spread from the axis outwards:
    the most confident node in each of n radial bands within 3 punch radii."""
    X = np.asarray(X)
    near = np.abs(X[:, 1] - slice_y) <= np.quantile(np.abs(X[:, 1] - slice_y), 0.15)
    r = np.hypot(X[:, 0], X[:, 1])
    cz = np.asarray(c).mean(0)
    picked = []
    edges = np.linspace(0.0, min(r.max(), 0.02), n + 1)
    for lo, hi in zip(edges[:-1], edges[1:]):
        band = np.nonzero(near & (r >= lo) & (r < hi) & (cz > 0))[0]
        if band.size:
            picked.append(int(band[np.argmax(cz[band])]))
    return picked


def plot_velocities(flow, fit_files: dict, out, n_nodes=4, slice_y=0.0):
    """Vertical nodal velocity against time at chosen nodes near a slice: tracked motion
    (dots) and each fitted law (lines)."""
    plt = _plt()
    with xr.open_dataset(flow, engine="h5netcdf") as fl:
        fl = fl.load()
    dt = (fl.time_end - fl.time_start).values
    tm = 0.5 * (fl.time_end + fl.time_start).values
    v_of = fl.u_of.values / dt[:, None, None]
    nodes = velocity_nodes(fl.X.values, fl.c_of.values[..., 2], n_nodes, slice_y)
    models = {}
    for label, path in fit_files.items():
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            if "v_fem" in ds and ds.v_fem.shape == v_of.shape:
                models[label] = ds.v_fem.values
    cols = min(len(nodes), 2) or 1
    rows = -(-max(len(nodes), 1) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 3.2 * rows), squeeze=False)
    for a, node in zip(axes.ravel(), nodes):
        x, y, z = fl.X.values[node]
        a.plot(tm, 1e3 * v_of[:, node, 2], "o", ms=3, color="0.4", label="tracked")
        for label, v in models.items():
            a.plot(tm, 1e3 * v[:, node, 2], lw=1.4, label=label)
        a.set(xlabel="time (s)", ylabel="vertical velocity (mm/s)",
              title=f"node {node} at r = {1e3 * np.hypot(x, y):.1f} mm, z = {1e3 * z:.1f} mm")
        a.grid(alpha=0.3)
    axes.ravel()[0].legend(fontsize=8)
    for a in axes.ravel()[len(nodes):]:
        a.set_visible(False)
    fig.tight_layout()
    return _save(fig, out)


def write_fields(flow, fit_file, mesh, out):
    """ParaView time series (.pvd of VTU files) on the tracking mesh: tracked velocity, model
    velocity, their difference (m/s) and the tracking confidence, one step per frame pair
    (at its mid-time)."""
    from ..mesh import read_mesh
    from ..plots import write_vtu_series

    m = read_mesh(mesh)
    with xr.open_dataset(flow, engine="h5netcdf") as fl:
        fl = fl.load()
    with xr.open_dataset(fit_file, engine="h5netcdf") as ds:
        v_fem = ds.v_fem.values
    dt = (fl.time_end - fl.time_start).values
    v_of = fl.u_of.values / dt[:, None, None]
    if v_of.shape != v_fem.shape or len(m.points) != v_of.shape[1]:
        raise ValueError(f"{flow} ({v_of.shape}), {fit_file} ({v_fem.shape}) and {mesh} "
                         f"({len(m.points)} nodes) do not match")
    tm = 0.5 * (fl.time_end + fl.time_start).values
    c = fl.c_of.values
    return write_vtu_series(out, m.points, m.cells, tm, lambda k: {
        "v_tracked": v_of[k], "v_model": v_fem[k], "v_difference": v_of[k] - v_fem[k], "confidence": c[k]})
