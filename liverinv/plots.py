"""Figures and field exports of run files (matplotlib, meshio)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .fileio import atomic_path

__all__ = ["plot_run", "export_fields"]


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


def export_fields(run, out):
    """ParaView collection (.pvd) of the displacement field of a run file: one VTU per
    frame in the folder `<out stem>_frames/` beside it, written whole or not at all."""
    import shutil
    import tempfile

    import meshio
    import xarray as xr

    out = Path(out)
    with xr.open_dataset(run, engine="h5netcdf") as ds:
        X, cells = ds.X.values, ds.cells.values
        u, t = ds.u.values, ds.time.values
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = out.with_name(out.stem + "_frames")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{frames.name}.", dir=out.parent))
    try:
        entries = []
        for k in range(len(t)):
            name = f"frame_{k:04d}.vtu"
            meshio.write(tmpdir / name, meshio.Mesh(X, [("tetra10", cells)], point_data={"u": u[k]}))
            entries.append(f'    <DataSet timestep="{t[k]:.9g}" file="{frames.name}/{name}"/>')
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
