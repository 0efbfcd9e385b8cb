"""`liverinv synthesize`: truth simulation + synthetic 3D ultrasound -> measurement bundle."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers):
    p = subparsers.add_parser(
        "synthesize", help="simulate a study and render its 3D ultrasound measurement bundle",
        description="Run the study's truth simulation, render the ultrasound volume sequence "
                    "(imaging: section of the study) and write the measurement bundle (HDF5).")
    p.add_argument("study", type=Path, help="study config (YAML)")
    p.add_argument("--out", type=Path, default=None, help="bundle to write (.h5)")
    p.add_argument("--truth-out", type=Path, default=None,
                   help="also keep the truth simulation (forward-run Dataset, netCDF)")
    p.add_argument("--truth-only", action="store_true",
                   help="only simulate the truth (to --truth-out); render it later with --truth-in")
    p.add_argument("--truth-in", type=Path, default=None,
                   help="render this truth file (from --truth-only on the same study) instead of simulating")
    p.add_argument("--mesh", type=Path, default=None,
                   help="simulate on this mesh instead of the study's (e.g. one a workflow generated)")
    p.set_defaults(func=run)


def bundle_bytes(im: dict) -> int:
    """About the size of the bundle an imaging config writes (volumes, uncompressed)."""
    import numpy as np
    shape = im["volume"].get("shape", (128, 48, 204))
    return int(im["frames"] * np.prod(shape) * np.dtype(im["storage"]).itemsize)


def run(args) -> int:
    from ..cli import UserError
    from ..fem.solver import ConvergenceError
    from ..fileio import check_writable
    from ..imaging.synth import imaging_config, simulate_truth, synthesize
    from ..laws import LawError
    from ..mesh import MeshError
    from ..study import StudyError, load_study

    if args.truth_only and args.truth_out is None:
        raise UserError("--truth-only needs --truth-out")
    if not args.truth_only and args.out is None:
        raise UserError("--out (the bundle to write) is required unless --truth-only")
    try:
        study, base = load_study(args.study)  # paths in a study are relative to its file
        # before the simulation: a folder that cannot be written (or a full disk) fails now
        if args.truth_out is not None:
            check_writable(args.truth_out)
        if not args.truth_only:
            check_writable(args.out, need_bytes=bundle_bytes(imaging_config(study, str(args.study))))
        if args.mesh is not None:
            study = {**study, "mesh": str(args.mesh.resolve())}
        if args.truth_only:
            from ..fileio import write_netcdf
            write_netcdf(simulate_truth(study, base, source=str(args.study)), args.truth_out)
            print(f"wrote {args.truth_out}")
            return 0
        truth = None
        if args.truth_in is not None:
            import xarray as xr
            if not args.truth_in.is_file():
                raise UserError(f"{args.truth_in}: truth file not found")
            truth = xr.load_dataset(args.truth_in, engine="h5netcdf")
        synthesize(study, base, args.out, args.truth_out, source=str(args.study), truth=truth)
    except (StudyError, LawError, MeshError) as e:
        raise UserError(str(e)) from None
    except ConvergenceError as e:
        raise UserError(f"the truth simulation did not converge: {e}") from None
    except ValueError as e:
        raise UserError(f"{args.study}: {e}") from None
    print(f"wrote {args.out}" + (f" and {args.truth_out}" if args.truth_out else ""))
    return 0
