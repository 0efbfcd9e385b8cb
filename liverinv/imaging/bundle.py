"""The measurement bundle: one HDF5 file with everything an indentation experiment measured.

Layout (format ``liverinv-us-bundle``, version 1; SI units; see README "Measurement bundle")::

    /                      attrs: format, format_version, provenance attributes
    /volumes/data          (frame, lateral, elevational, axial) B-mode, float32/float64,
                           or uint8/uint16 with attrs scale, offset (value = offset + scale*stored)
    /volumes/time_s        (frame,) acquisition time of each volume, strictly increasing
    /volumes/spacing_m     (3,) voxel size along (lateral, elevational, axial), > 0
    /volumes/origin_m      (3,) mesh coordinates of the centre of voxel (0, 0, 0)
    /volumes/direction     (3, 3) optional; column a = mesh unit vector of image axis a
                           (default identity: lateral = x, elevational = y, axial = +z)
    /indenter/time_s       (sample,) strictly increasing
    /indenter/displacement_m  (sample,) punch depth, positive into the tissue
    /indenter/force_N      (sample,) compressive force, positive
                           attrs: displacement_noise_rms_m, force_noise_rms_N (0 if none)
    /geometry              attrs: tissue_height_m, tissue_radius_m, indenter_radius_m,
                           indenter_axis_m (x, y of the punch axis), mesh (name of the mesh)
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from ..fileio import atomic_path, provenance
from .grid import ImageGrid

log = logging.getLogger(__name__)

__all__ = ["FORMAT", "FORMAT_VERSION", "Indenter", "write_bundle", "open_bundle", "Bundle"]

FORMAT = "liverinv-us-bundle"
FORMAT_VERSION = 1
AXIS_ORDER = "frame,lateral,elevational,axial"


def _error(msg):
    from ..cli import UserError
    return UserError(msg)


@dataclass
class Indenter:
    """Indenter record sampled at its own rate (SI)."""

    time_s: np.ndarray
    displacement_m: np.ndarray
    force_N: np.ndarray
    displacement_noise_rms_m: float = 0.0
    force_noise_rms_N: float = 0.0


def write_bundle(path, volumes, grid: ImageGrid, time_s, indenter: Indenter,
                 geometry: dict | None = None, dtype: str = "uint16", **prov) -> Path:
    """Write a bundle atomically. `volumes` is an array (frame, *grid.shape) or an iterable of
    volumes (written one frame at a time; then `time_s` fixes the number of frames).
    B-mode values are expected in [0, 1] when stored as integers."""
    time_s = np.asarray(time_s, float)
    nf = len(time_s)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        for k, v in provenance(**prov).items():
            f.attrs[k] = v
        g = f.create_group("volumes")
        g.attrs["axis_order"] = AXIS_ORDER
        dt = np.dtype(dtype)
        d = g.create_dataset("data", shape=(nf, *grid.shape), dtype=dt, chunks=(1, *grid.shape))
        if dt.kind == "u":
            scale = 1.0 / np.iinfo(dt).max
            d.attrs["scale"], d.attrs["offset"] = scale, 0.0
        for k, vol in enumerate(volumes):
            if k >= nf:
                raise ValueError("more volumes than frame times")
            vol = np.asarray(vol)
            if vol.shape != grid.shape:
                raise ValueError(f"volume {k} has shape {vol.shape}, grid is {grid.shape}")
            d[k] = (np.rint(np.clip(vol, 0, 1) / scale).astype(dt) if dt.kind == "u" else vol)
        g["time_s"] = time_s
        g["spacing_m"] = np.asarray(grid.spacing_m)
        g["origin_m"] = np.asarray(grid.origin_m)
        g["direction"] = grid.R
        ind = f.create_group("indenter")
        ind["time_s"] = np.asarray(indenter.time_s, float)
        ind["displacement_m"] = np.asarray(indenter.displacement_m, float)
        ind["force_N"] = np.asarray(indenter.force_N, float)
        ind.attrs["displacement_noise_rms_m"] = float(indenter.displacement_noise_rms_m)
        ind.attrs["force_noise_rms_N"] = float(indenter.force_noise_rms_N)
        geo = f.create_group("geometry")
        for k, v in (geometry or {}).items():
            geo.attrs[k] = json.dumps(v) if isinstance(v, (dict, list, tuple)) else v
    return Path(path)


@dataclass
class Bundle:
    """An open, validated bundle. Volumes are read lazily, one frame at a time."""

    path: Path
    grid: ImageGrid
    time_s: np.ndarray
    indenter: Indenter
    geometry: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    _file: h5py.File | None = None

    @property
    def n_frames(self) -> int:
        return len(self.time_s)

    def frame(self, k: int) -> np.ndarray:
        """Volume k as float32 (lateral, elevational, axial); NaN/inf are rejected."""
        d = self._file["volumes/data"]
        v = d[k]
        if v.dtype.kind in "ui":
            v = d.attrs.get("offset", 0.0) + d.attrs.get("scale", 1.0) * v.astype(np.float32)
        v = np.asarray(v, np.float32)
        if not np.isfinite(v).all():
            raise _error(f"{self.path}: /volumes/data: frame {k} holds NaN or infinite values")
        return v

    def volumes(self) -> np.ndarray:
        """All volumes (frame, lateral, elevational, axial) float32."""
        return np.stack([self.frame(k) for k in range(self.n_frames)])

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _get(f, path, name, ndim=None, length=None, positive=False, increasing=False):
    if name not in f:
        raise _error(f"{path}: missing dataset /{name}")
    a = f[name][()]
    if not np.issubdtype(np.asarray(a).dtype, np.number):
        raise _error(f"{path}: /{name} is not numeric")
    a = np.asarray(a, float)
    if ndim is not None and a.ndim != ndim:
        raise _error(f"{path}: /{name} has {a.ndim} dimensions, expected {ndim}")
    if length is not None and a.shape[0] != length:
        raise _error(f"{path}: /{name} has length {a.shape[0]}, expected {length}")
    if not np.isfinite(a).all():
        raise _error(f"{path}: /{name} holds NaN or infinite values")
    if positive and not (a > 0).all():
        raise _error(f"{path}: /{name} must be > 0, got {a.tolist()}")
    if increasing and a.size > 1 and not (np.diff(a) > 0).all():
        raise _error(f"{path}: /{name} must be strictly increasing")
    return a


def open_bundle(path, check_all_frames: bool = False) -> Bundle:
    """Open and validate a bundle; raise UserError naming the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise _error(f"{path}: bundle file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise _error(f"{path}: not an HDF5 file ({e})") from None
    try:
        fmt = f.attrs.get("format")
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
        if fmt != FORMAT:
            raise _error(f"{path}: attribute 'format' is {fmt!r}, expected {FORMAT!r}")
        ver = f.attrs.get("format_version")
        if ver is None or int(ver) != FORMAT_VERSION:
            raise _error(f"{path}: attribute 'format_version' is {ver!r}; this liverinv reads "
                         f"version {FORMAT_VERSION}")
        if "volumes/data" not in f:
            raise _error(f"{path}: missing dataset /volumes/data")
        d = f["volumes/data"]
        if d.ndim != 4:
            raise _error(f"{path}: /volumes/data has shape {d.shape}; expected 4 dimensions "
                         f"({AXIS_ORDER})")
        if d.dtype.kind not in "uif":
            raise _error(f"{path}: /volumes/data has dtype {d.dtype}; expected integer or float")
        if min(d.shape[1:]) < 4:
            raise _error(f"{path}: /volumes/data has shape {d.shape}; each image axis needs >= 4 voxels")
        nf = d.shape[0]
        t = _get(f, path, "volumes/time_s", ndim=1, length=nf, increasing=True)
        spacing = _get(f, path, "volumes/spacing_m", ndim=1, length=3, positive=True)
        origin = _get(f, path, "volumes/origin_m", ndim=1, length=3)
        direction = (_get(f, path, "volumes/direction", ndim=2, length=3)
                     if "volumes/direction" in f else np.eye(3))
        try:
            grid = ImageGrid(d.shape[1:], spacing, origin, direction)
        except ValueError as e:
            raise _error(f"{path}: /volumes/direction: {e}") from None
        ti = _get(f, path, "indenter/time_s", ndim=1, increasing=True)
        ind = Indenter(ti, _get(f, path, "indenter/displacement_m", ndim=1, length=len(ti)),
                       _get(f, path, "indenter/force_N", ndim=1, length=len(ti)),
                       float(f["indenter"].attrs.get("displacement_noise_rms_m", 0.0)),
                       float(f["indenter"].attrs.get("force_noise_rms_N", 0.0)))
        geo = dict(f["geometry"].attrs) if "geometry" in f else {}
        b = Bundle(path, grid, t, ind, geo, dict(f.attrs), f)
        if check_all_frames:
            for k in range(nf):
                b.frame(k)
        return b
    except BaseException:
        f.close()
        raise
