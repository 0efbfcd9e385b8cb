"""`liverinv plot`: force-displacement figure of run files (with an optional ParaView
export), or the convergence figure of fit files (Phi and parameters along each fit)."""

from __future__ import annotations

from pathlib import Path

from ..cli import UserError
from . import parse_assignments


def register(sub):
    p = sub.add_parser("plot", help="plot run files (force-displacement) or fit files (convergence)",
                       description=__doc__)
    p.add_argument("files", nargs="+", help="run files (`liverinv simulate`) or fit files (`liverinv fit`), not mixed")
    p.add_argument("--out", required=True, help="figure file (PNG, PDF or SVG)")
    p.add_argument("--fields", help="runs: also write the displacement field of the first run for ParaView (.pvd)")
    p.add_argument("--truth", action="append", default=[], metavar="NAME=VALUE",
                   help="fits: plot parameters relative to this value (repeatable)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..plots import export_fields, is_fit_file, plot_fits, plot_run
    for r in args.files:
        if not Path(r).is_file():
            raise UserError(f"{r}: file not found")
    for r in args.files:
        what = _kind(r)
        if what not in ("run", "fit"):
            raise UserError(f"{r}: {what}; plot takes run files (liverinv simulate) or fit files (liverinv fit)"
                            + (" -- for a bundle, liverinv check --picture draws it" if what.startswith("a measurement")
                               else " -- liverinv track --picture draws a flow" if what.startswith("a flow") else ""))
    try:
        kinds = {is_fit_file(f) for f in args.files}
        if len(kinds) > 1:
            raise UserError("give either run files or fit files, not both")
        if kinds == {True}:
            plot_fits(args.files, args.out, truth=parse_assignments(args.truth, "--truth"))
        else:
            plot_run(args.files, args.out)
            if args.fields:
                export_fields(args.files[0], args.fields)
    except (KeyError, ValueError, OSError) as e:
        raise UserError(f"cannot plot {args.files}: {e}") from None
    print(f"wrote {args.out}" + (f" and {args.fields}" if args.fields else ""))
    return 0


def _kind(path) -> str:
    """'run', 'fit', or what else the file is, in words."""
    import h5py
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") in ("liverinv-us-bundle", b"liverinv-us-bundle"):
                return "a measurement bundle"
            names = set(f.keys())
    except OSError:
        return "not a netCDF/HDF5 file"
    if "best" in names or f_status(path) == "failed":
        return "fit"
    if "indenter_depth" in names and "u" in names:
        return "run"
    if "u_of" in names:
        return "a flow file"
    return "neither a run file nor a fit file"


def f_status(path):
    import h5py
    with h5py.File(path, "r") as f:
        s = f.attrs.get("status", "")
    return s.decode() if isinstance(s, bytes) else s
