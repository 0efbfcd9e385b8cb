"""The `liverinv` command. Each subcommand lives in `liverinv/commands/<name>.py` and
provides `register(subparsers)`; add a new one to `COMMANDS`."""

from __future__ import annotations

import argparse
import importlib
import logging
import re
import signal
import sys
import threading

from .errors import UserError  # re-exported for the command modules

COMMANDS = ["simulate", "plot", "synthesize", "track", "fit", "register", "gather", "tables", "figures", "importdata", "check", "diagnose", "discover"]


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    parser = argparse.ArgumentParser(prog="liverinv", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"liverinv {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"liverinv.commands.{name}").register(sub)
    return parser


class Interrupted(BaseException):
    """SIGTERM, SIGHUP or SIGINT, raised in the main thread by `main`'s signal handler so that
    every `with` block on the way out runs its cleanup (`fileio.atomic_path` removes its
    temporary file, temporary folders go). A BaseException, so that no `except Exception`
    (nor meshio's SystemExit guard) takes it for an error of the input."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, n))


def _raise_interrupted(signum, frame):
    for s in _SIGNALS:            # a second signal must not interrupt the cleanup
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def _install_handlers() -> dict:
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for s in _SIGNALS:
        try:
            previous[s] = signal.signal(s, _raise_interrupted)
        except (OSError, ValueError):
            pass
    return previous


def _restore_handlers(previous: dict):
    for s, h in previous.items():
        signal.signal(s, h if h is not None else signal.SIG_DFL)


_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _join_negative_values(argv):
    """`--depth -9e-3` as `--depth=-9e-3`: argparse takes a token such as -9e-3 for an option."""
    out = []
    for tok in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE_NUMBER.match(tok):
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


def main(argv=None) -> int:
    previous = _install_handlers()
    argv = _join_negative_values(sys.argv[1:] if argv is None else list(argv))
    command = "?"
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        command = args.command
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(levelname)s %(name)s: %(message)s")
        try:
            return int(args.func(args) or 0)
        except UserError as e:
            print(f"liverinv {command}: error: {e}", file=sys.stderr)
            return 2
        except OSError as e:
            # output writes are turned into UserErrors by fileio.atomic_path; this is the
            # rest (a folder that cannot be made, a file opened directly): one line, no traceback
            where = e.filename if getattr(e, "filename", None) is not None else None
            why = e.strerror or " ".join(str(e).split())
            print(f"liverinv {command}: error: " + (f"{where}: {why}" if where else why), file=sys.stderr)
            return 2
    except (Interrupted, KeyboardInterrupt) as e:
        signum = e.signum if isinstance(e, Interrupted) else signal.SIGINT
        name = signal.Signals(signum).name
        print(f"liverinv {command}: interrupted ({name}); no partial output left", file=sys.stderr)
        return 128 + int(signum)
    finally:
        _restore_handlers(previous)


if __name__ == "__main__":
    sys.exit(main())
