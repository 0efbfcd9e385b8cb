"""The `liverinv` command. Each subcommand lives in `liverinv/commands/<name>.py` and
provides `register(subparsers)`; add a new one to `COMMANDS`."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from .errors import UserError  # re-exported for the command modules

COMMANDS = ["simulate", "plot", "synthesize", "track", "fit", "register", "gather", "tables", "figures", "importdata"]


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    parser = argparse.ArgumentParser(prog="liverinv", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"liverinv {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"liverinv.commands.{name}").register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except UserError as e:
        print(f"liverinv {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
