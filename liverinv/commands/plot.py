"""`liverinv plot`: force-displacement figure of run files; optional ParaView export."""

from __future__ import annotations

from pathlib import Path

from ..cli import UserError


def register(sub):
    p = sub.add_parser("plot", help="plot force-displacement curves of run files", description=__doc__)
    p.add_argument("runs", nargs="+", help="run files written by `liverinv simulate`")
    p.add_argument("--out", required=True, help="figure file (PNG, PDF or SVG)")
    p.add_argument("--fields", help="also write the displacement field of the first run for ParaView (.pvd)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..plots import export_fields, plot_run
    for r in args.runs:
        if not Path(r).is_file():
            raise UserError(f"{r}: run file not found")
    try:
        plot_run(args.runs, args.out)
        if args.fields:
            export_fields(args.runs[0], args.fields)
    except (KeyError, ValueError, OSError) as e:
        raise UserError(f"cannot plot {args.runs}: {e}") from None
    print(f"wrote {args.out}" + (f" and {args.fields}" if args.fields else ""))
    return 0
