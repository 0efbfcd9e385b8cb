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
    p.add_argument("--out", type=Path, required=True, help="bundle to write (.h5)")
    p.add_argument("--truth-out", type=Path, default=None,
                   help="also keep the truth simulation (forward-run Dataset, netCDF)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UserError
    from ..fem.solver import ConvergenceError
    from ..imaging.synth import synthesize
    from ..laws import LawError
    from ..mesh import MeshError
    from ..study import StudyError, load_study

    try:
        study, base = load_study(args.study)  # paths in a study are relative to its file
        synthesize(study, base, args.out, args.truth_out, source=str(args.study))
    except (StudyError, LawError, MeshError) as e:
        raise UserError(str(e)) from None
    except ConvergenceError as e:
        raise UserError(f"the truth simulation did not converge: {e}") from None
    except ValueError as e:
        raise UserError(f"{args.study}: {e}") from None
    print(f"wrote {args.out}" + (f" and {args.truth_out}" if args.truth_out else ""))
    return 0
