"""Figures and field exports of run files (matplotlib, meshio)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .fileio import atomic_path

__all__ = ["plot_run", "plot_fits", "export_fields", "is_fit_file"]


def plot_run(runs, out, labels=None):
    """Force-displacement curve and depth/force histories of one or more run files."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import xarray as xr

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4))
    ax1b = ax1.twinx()
    for i, path in enumerate(runs):
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            d, F, t = ds.indenter_depth.values, ds.indenter_force.values, ds.time.values
            label = labels[i] if labels else f"{ds.attrs['law']} ({Path(path).parent.name}/{Path(path).name})"
        ax0.plot(d * 1e3, F, "-", label=label)
        ax1.plot(t, d * 1e3, "-", label=label)
        ax1b.plot(t, F, "--")
    ax0.set_xlabel("indenter depth (mm)")
    ax0.set_ylabel("indenter force (N)")
    ax0.legend()
    ax0.grid(alpha=0.3)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("depth (mm), solid")
    ax1b.set_ylabel("force (N), dashed")
    ax1.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format=Path(out).suffix.lstrip(".") or "png")
    plt.close(fig)
    return Path(out)


def is_fit_file(path) -> bool:
    """Whether `path` is a fit file (`liverinv fit`) rather than a run file."""
    import xarray as xr
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return "history_phi" in ds


def plot_fits(fits, out, truth=None, labels=None):
    """Convergence of one or more fits, as the seed paper's Figs. 5-6: the misfit Phi of
    every forward solve (dots) and the best so far (line) against the solve count, and each
    parameter along the fit (accepted evaluations: the best so far) relative to `truth`
    (dict, e.g. the synthetic truth) or, without it, to the fit's own optimum."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import xarray as xr

    dss = []
    for path in fits:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            dss.append(ds.load())
    names = list(dict.fromkeys(n for ds in dss for n in ds.param.values))
    fig, axes = plt.subplots(1, 1 + len(names), figsize=(4 + 3.2 * len(names), 3.8), squeeze=False)
    axes = axes[0]
    styles = ["-", "--", ":", "-."]
    for i, ds in enumerate(dss):
        label = labels[i] if labels else f"{ds.attrs.get('law', '')} {ds.attrs.get('method', '')} {Path(fits[i]).stem}"
        phi = np.where(ds.history_ok.values, ds.history_phi.values, np.nan)
        n = np.arange(1, len(phi) + 1)
        best = np.fmin.accumulate(np.where(np.isnan(phi), np.inf, phi))
        line, = axes[0].semilogy(n, best, styles[i % 4], label=label)
        axes[0].semilogy(n, phi, ".", ms=2, color=line.get_color(), alpha=0.5)
        improved = phi < np.concatenate([[np.inf], best[:-1]])           # a new best at j
        k_best = np.maximum.accumulate(np.where(improved, np.arange(len(phi)), 0))
        for j, name in enumerate(names):
            if name not in ds.param.values:
                continue
            v = ds.history_params.sel(param=name).values[k_best]
            ref = (truth or {}).get(name, float(ds.best.sel(param=name)))
            axes[1 + j].plot(n, v / ref, styles[i % 4], color=line.get_color())
    axes[0].set_xlabel("forward solves")
    unit = dss[0].history_phi.attrs.get("units", "m^2/s^2") if dss else "m^2/s^2"
    unit = {"m^2/s^2": "m²/s²", "1": "-2 log L"}.get(unit, unit)
    axes[0].set_ylabel(f"Phi ({unit}): best so far, and each solve")
    axes[0].legend(fontsize=7)
    for j, name in enumerate(names):
        ax = axes[1 + j]
        ax.set_yscale("log")
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_xlabel("forward solves")
        ax.set_title(f"{name} / {'truth' if truth and name in truth else 'optimum'}", fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=120, format=Path(out).suffix.lstrip(".") or "png")
    plt.close(fig)
    return Path(out)


def export_fields(run, out):
    """ParaView collection (.pvd) of the displacement field of a run file: one VTU per
    frame in the folder `<out stem>_frames/` beside it, written whole or not at all."""
    import xarray as xr

    with xr.open_dataset(run, engine="h5netcdf") as ds:
        X, cells = ds.X.values, ds.cells.values
        u, t = ds.u.values, ds.time.values
    return write_vtu_series(out, X, cells, t, lambda k: {"u": u[k]})


def write_vtu_series(out, points, cells, times, point_data):
    """ParaView collection `out` (.pvd) of tet10 VTU files, one per time, in the folder
    `<out stem>_frames/` beside it; `point_data(k)` gives frame k's fields. Written whole or
    not at all (the frames go to a temporary folder renamed at the end)."""
    import shutil
    import tempfile

    import meshio

    from .fileio import umask

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = out.with_name(out.stem + "_frames")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{frames.name}.", dir=out.parent))
    try:
        entries = []
        for k, t in enumerate(times):
            name = f"frame_{k:04d}.vtu"
            meshio.write(tmpdir / name, meshio.Mesh(points, [("tetra10", cells)], point_data=point_data(k)))
            entries.append(f'    <DataSet timestep="{t:.9g}" file="{frames.name}/{name}"/>')
        tmpdir.chmod(0o777 & ~umask())
        if frames.exists():
            shutil.rmtree(frames)
        tmpdir.rename(frames)
    except BaseException:
        shutil.rmtree(tmpdir, ignore_errors=True)
        raise
    text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
            + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    with atomic_path(out) as p:
        p.write_text(text)
    return out
