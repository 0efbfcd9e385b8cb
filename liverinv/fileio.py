"""Writing result files whole or not at all, with provenance."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
from pathlib import Path

__all__ = ["atomic_path", "write_netcdf", "file_sha256", "provenance"]


def file_sha256(path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _git_revision() -> str:
    try:
        here = Path(__file__).resolve().parent
        out = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except Exception:
        return "unknown"


def provenance(**extra) -> dict:
    """Attributes every result file carries: package version, git revision, and `extra`
    (dicts and lists are stored as JSON strings so netCDF can hold them)."""
    from . import __version__
    attrs = {"liverinv_version": __version__, "git_revision": _git_revision()}
    for k, v in extra.items():
        attrs[k] = json.dumps(v) if isinstance(v, (dict, list, tuple)) else v
    return attrs


class atomic_path:
    """Context manager yielding a temporary path beside `path`; renamed onto `path` only if
    the block succeeds, removed otherwise. Nothing half-written is ever left at `path`."""

    def __init__(self, path):
        self.path = Path(path)

    def __enter__(self) -> Path:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent)
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            os.chmod(self.tmp, 0o666 & ~umask())   # mkstemp makes 0600: give the umask's mode
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


def umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_netcdf(ds, path) -> Path:
    """Write an xarray Dataset to netCDF (h5netcdf engine) atomically."""
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return Path(path)
