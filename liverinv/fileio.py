"""Writing result files whole or not at all, with provenance."""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import subprocess
from pathlib import Path

from .errors import UserError

__all__ = ["atomic_path", "check_writable", "write_netcdf", "file_sha256", "data_sha256", "provenance"]


def file_sha256(path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def data_sha256(path, attrs=()) -> str:
    """Hex SHA-256 of an HDF5 file's data (netCDF-4 included): every dataset's name, dtype,
    shape and values, in name order, and the root attributes named in `attrs`. Unlike the
    file's bytes, it does not change with what a rerun writes differently for the same data
    (run times, revisions, HDF5 layout). A file that is not HDF5: its bytes' hash."""
    import h5py
    import numpy as np

    try:
        f = h5py.File(path, "r")
    except OSError:
        return file_sha256(path)
    h = hashlib.sha256()
    with f:
        names = []
        f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in sorted(names):
            d = f[name]
            h.update(f"{name}|{d.dtype.str}|{d.shape}|".encode())
            v = np.asarray(d[()])
            h.update(repr(v.tolist()).encode() if v.dtype.kind == "O" else np.ascontiguousarray(v).tobytes())
        for key in attrs:
            h.update(f"@{key}={f.attrs.get(key, '')!r}|".encode())
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


def _cannot_write(path, e: OSError) -> UserError:
    why = e.strerror or " ".join(str(e).split()) or type(e).__name__
    return UserError(f"{path}: cannot write ({why})")


class atomic_path:
    """Context manager yielding a temporary path beside `path`; renamed onto `path` only if
    the block succeeds, removed otherwise (also on SIGTERM/SIGINT, which `liverinv.cli.main`
    turns into an exception). Nothing half-written is ever left at `path`. An OSError while
    writing (no space, no permission, read-only file system) becomes a UserError naming
    `path`."""

    def __init__(self, path):
        self.path = Path(path)
        self.tmp = None

    def __enter__(self) -> Path:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            while True:
                # the name is known before the file exists, so an interruption at any point
                # below still finds what to remove
                self.tmp = self.path.parent / f".{self.path.name}.{secrets.token_hex(4)}.part"
                try:
                    os.close(os.open(self.tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
                    return self.tmp
                except FileExistsError:
                    continue
        except OSError as e:
            self._remove()
            raise _cannot_write(self.path, e) from None
        except BaseException:
            self._remove()
            raise

    def _remove(self):
        if self.tmp is not None:
            try:
                self.tmp.unlink(missing_ok=True)
            except OSError:
                pass

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self._remove()
            if issubclass(exc_type, OSError) and _is_ours(exc, self.tmp, self.path):
                raise _cannot_write(self.path, exc) from None
            return False
        try:
            os.chmod(self.tmp, 0o666 & ~umask())   # whatever the writer made: the umask's mode
            os.replace(self.tmp, self.path)
        except OSError as e:
            self._remove()
            raise _cannot_write(self.path, e) from None
        except BaseException:                      # interrupted before or after the rename
            self._remove()
            raise
        return False


def _is_ours(exc, *paths) -> bool:
    """Whether an OSError is about writing one of `paths` (or names no file, as h5py's and
    netCDF's errors often do) rather than, say, reading an input inside the block."""
    names = [getattr(exc, "filename", None), getattr(exc, "filename2", None)]
    names = [n for n in names if n is not None]
    if not names:
        return True
    own = {str(p) for p in paths if p is not None}
    return any(str(n) in own for n in names)


def check_writable(path, need_bytes: int | None = None) -> None:
    """UserError naming `path` unless a file can be written there: its folder is writable
    (or a missing folder can be created in a writable one), `path` is not a folder, and when
    `need_bytes` is given, the disk has that much space free. Cheap: call it before the work."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{path}: cannot write (it is a folder)")
    folder = path.parent
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise UserError(f"{path}: cannot write ({existing} is not a folder)")
    if existing != folder:
        if not os.access(existing, os.W_OK | os.X_OK):
            raise UserError(f"{path}: cannot write (cannot create folder {folder} in {existing}: "
                            "Permission denied)")
    else:
        probe = folder / f".{path.name}.{secrets.token_hex(4)}.probe"
        try:
            os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except OSError as e:
            raise _cannot_write(path, e) from None
        finally:
            try:
                probe.unlink(missing_ok=True)
            except OSError:
                pass
    if need_bytes:
        import shutil
        free = shutil.disk_usage(existing).free
        if free < need_bytes:
            raise UserError(f"{path}: cannot write (needs about {_size(need_bytes)}, "
                            f"{_size(free)} free)")


def _size(n: int) -> str:
    for unit, f in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.0f} {unit}"
    return f"{n} bytes"


def umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_netcdf(ds, path) -> Path:
    """Write an xarray Dataset to netCDF (h5netcdf engine) atomically."""
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return Path(path)
