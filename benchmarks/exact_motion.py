"""A flow file whose tracked motion is replaced by the truth's exact frame-to-frame motion at
the flow's nodes (the truth run may be on another mesh): fitting it separates the inverse
mesh's bias from the tracking error. Not a workflow job: a diagnostic of the method.

    python benchmarks/exact_motion.py --truth results/data/table1/truth.nc \
        --flow results/data/table1/flow_cylinder_coarse-44136f.nc --out flow_exact.nc
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def model_mesh_path(name, folder):
    """A mesh file, or a `liverinv.meshgen` preset generated once into folder/model_<name>.msh."""
    from liverinv.meshgen import PRESETS, generate_indentation_mesh
    if Path(name).exists():
        return Path(name)
    if name not in PRESETS:
        raise SystemExit(f"{name}: neither a mesh file nor a preset ({', '.join(PRESETS)})")
    path = Path(folder) / f"model_{name}.msh"
    if not path.exists():
        generate_indentation_mesh(path, **PRESETS[name])
    return path


def exact_flow(truth, flow, out):
    """The tracked flow file with u_of replaced by the truth's frame-to-frame motion at the
    flow's nodes."""
    import xarray as xr

    from liverinv.fem.probe import Probe
    from liverinv.fileio import write_netcdf
    tr = xr.load_dataset(truth, engine="h5netcdf")
    fl = xr.load_dataset(flow, engine="h5netcdf")
    probe = Probe(tr.X.values, tr.cells.values, fl.X.values)
    t = np.concatenate([fl.time_start.values[:1], fl.time_end.values])
    U = probe(tr.u.interp(time=t).values)
    fl["u_of"] = (fl.u_of.dims, U[1:] - U[:-1], fl.u_of.attrs)
    fl.attrs["note"] = f"u_of replaced by the exact motion of {truth} (benchmarks/exact_motion.py)"
    write_netcdf(fl, out)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth", type=Path, required=True, help="truth run (liverinv synthesize --truth-out)")
    ap.add_argument("--flow", type=Path, required=True, help="tracked flow file")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    print(f"wrote {exact_flow(args.truth, args.flow, args.out)}")


if __name__ == "__main__":
    main()
