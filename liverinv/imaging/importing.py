"""A measurement bundle from a lab's files: a 3D ultrasound volume sequence (NRRD as 3D Slicer
writes it, MetaImage, NIfTI, a DICOM series per frame, or one 4D file), a frame-time table, an
indenter record and the specimen geometry.

Volumes are read with SimpleITK, one library for every format, which gives each file's
spacing, origin and direction in its physical frame (mm; LPS for DICOM and NIfTI, as ITK
reports them). Those physical coordinates are taken as the mesh's coordinates (converted to
m) unless a rigid transform is given: ``x_mesh = R x_file + t``.

Voxel values are kept exactly: 8- and 16-bit unsigned volumes are stored with the same
integers (value = stored / max of the type), other types as float32 unchanged.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import UserError
from .bundle import Indenter, write_bundle
from .grid import ImageGrid

log = logging.getLogger(__name__)

__all__ = ["read_volumes", "read_frame_times", "read_indenter_csv", "read_geometry", "read_transform",
           "import_bundle", "GEOMETRY_KEYS"]

MM = 1e-3
GEOMETRY_KEYS = {"tissue_height_m": "positive", "tissue_radius_m": "positive", "indenter_radius_m": "positive",
                 "indenter_axis_m": "xy"}
VOLUME_SUFFIXES = (".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz", ".dcm")


def _sitk():
    try:
        import SimpleITK as sitk
    except ImportError:  # pragma: no cover - a dependency
        raise UserError("liverinv import needs SimpleITK (pip install SimpleITK)") from None
    return sitk


def _read_image(path: Path):
    sitk = _sitk()
    if not path.exists():
        raise UserError(f"{path}: volume file not found")
    try:
        if path.is_dir():
            return _read_dicom_folder(path)
        return [sitk.ReadImage(str(path))]
    except RuntimeError as e:
        first = str(e).strip().splitlines()[-1] if str(e).strip() else "unreadable"
        raise UserError(f"{path}: not a readable volume ({first[:200]})") from None


def _read_dicom_folder(folder: Path):
    """One 3D volume per DICOM series in the folder, in order of SeriesNumber (then UID)."""
    sitk = _sitk()
    ids = sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(folder))
    if not ids:
        raise UserError(f"{folder}: no DICOM series in this folder")
    frames = []
    for sid in ids:
        names = sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(folder), sid)
        r = sitk.ImageSeriesReader()
        r.SetFileNames(names)
        r.MetaDataDictionaryArrayUpdateOn()
        img = r.Execute()
        number = r.GetMetaData(0, "0020|0011").strip() if r.HasMetaDataKey(0, "0020|0011") else ""
        frames.append((int(number) if number.lstrip("-").isdigit() else 0, sid, img))
    frames.sort(key=lambda f: (f[0], f[1]))
    return [img for _, _, img in frames]


def _split(img, source):
    """(frames of (lateral, elevational, axial) arrays, spacing_m, origin_m, direction) of one
    3D or 4D image."""
    sitk = _sitk()
    dim = img.GetDimension()
    if img.GetNumberOfComponentsPerPixel() != 1:
        raise UserError(f"{source}: {img.GetNumberOfComponentsPerPixel()} components per voxel; "
                        "expected a scalar (B-mode) volume")
    a = sitk.GetArrayFromImage(img)            # (t,) z, y, x: reversed index order
    if dim == 3:
        frames = [a.transpose(2, 1, 0)]
    elif dim == 4:
        frames = [a[k].transpose(2, 1, 0) for k in range(a.shape[0])]
    else:
        raise UserError(f"{source}: a {dim}D image; expected 3D volumes (or one 4D file)")
    spacing = np.asarray(img.GetSpacing()[:3], float) * MM
    origin = np.asarray(img.GetOrigin()[:3], float) * MM
    D = np.asarray(img.GetDirection(), float).reshape(dim, dim)[:3, :3]
    return frames, spacing, origin, D


def read_volumes(paths) -> tuple[list, ImageGrid]:
    """The volume sequence of `paths` (one 3D file per frame in frame order, one 4D file, or
    a DICOM folder) as a list of (lateral, elevational, axial) arrays and their grid."""
    frames, grid, first = [], None, None
    for p in map(Path, paths):
        for img in _read_image(p):
            vols, spacing, origin, D = _split(img, p)
            if grid is None:
                try:
                    grid = ImageGrid(vols[0].shape, spacing, origin, D)
                except ValueError as e:
                    raise UserError(f"{p}: direction: {e}") from None
                first = p
            else:
                same = (vols[0].shape == grid.shape and np.allclose(spacing, grid.spacing_m, rtol=1e-6)
                        and np.allclose(origin, grid.origin_m, atol=1e-9) and np.allclose(D, grid.R, atol=1e-6))
                if not same:
                    raise UserError(f"{p}: shape {vols[0].shape}, spacing {spacing / MM} mm, origin "
                                    f"{origin / MM} mm differ from {first} ({grid.shape}, "
                                    f"{np.asarray(grid.spacing_m) / MM} mm, {np.asarray(grid.origin_m) / MM} mm): "
                                    "every frame must share one grid")
            frames.extend(vols)
    if not frames:
        raise UserError("--volumes: no volume given")
    if min(grid.shape) < 4:
        raise UserError(f"{first}: volume shape {grid.shape}; each axis needs at least 4 voxels")
    return frames, grid


def _read_csv(path, what):
    import pandas as pd
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: {what} file not found")
    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except Exception as e:
        raise UserError(f"{path}: not a readable CSV ({e})") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _column(df, path, name):
    v = df[name]
    try:
        v = v.to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise UserError(f"{path}: column {name!r} holds values that are not numbers") from None
    if not np.isfinite(v).all():
        bad = int(np.nonzero(~np.isfinite(v))[0][0])
        raise UserError(f"{path}: column {name!r}: row {bad + 1} is empty, NaN or infinite")
    return v


def read_frame_times(path, n_frames: int) -> np.ndarray:
    """Frame times (s) from a CSV with columns `frame,time_s`: one row per frame 0..n-1,
    strictly increasing."""
    df = _read_csv(path, "frame-time")
    missing = [c for c in ("frame", "time_s") if c not in df.columns]
    if missing:
        raise UserError(f"{path}: missing column(s) {missing}; expected frame,time_s (has {list(df.columns)})")
    frame, t = _column(df, path, "frame"), _column(df, path, "time_s")
    order = np.argsort(frame, kind="stable")
    frame, t = frame[order], t[order]
    if len(frame) != n_frames or not np.array_equal(frame, np.arange(n_frames)):
        raise UserError(f"{path}: frames {frame.astype(int).tolist()[:8]}{'...' if len(frame) > 8 else ''}; "
                        f"expected one row for each of the {n_frames} volumes, numbered 0..{n_frames - 1}")
    if np.any(np.diff(t) <= 0):
        k = int(np.nonzero(np.diff(t) <= 0)[0][0])
        raise UserError(f"{path}: time_s is not strictly increasing (frame {k + 1}: {t[k + 1]:g} s after {t[k]:g} s)")
    return t


def read_indenter_csv(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(time_s, displacement_m, force_N, unit) from a CSV with columns `time_s,displacement_m,
    force_N` or `time_s,displacement_mm,force_N`."""
    df = _read_csv(path, "indenter")
    if "displacement_m" in df.columns and "displacement_mm" in df.columns:
        raise UserError(f"{path}: both displacement_m and displacement_mm: give one")
    unit = "mm" if "displacement_mm" in df.columns else "m"
    need = ["time_s", f"displacement_{unit}", "force_N"]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise UserError(f"{path}: missing column(s) {missing}; expected time_s,displacement_m,force_N "
                        f"(or displacement_mm), has {list(df.columns)}")
    t = _column(df, path, "time_s")
    d = _column(df, path, f"displacement_{unit}") * (MM if unit == "mm" else 1.0)
    f = _column(df, path, "force_N")
    if len(t) < 4:
        raise UserError(f"{path}: {len(t)} samples; an indenter record needs at least 4")
    if np.any(np.diff(t) <= 0):
        k = int(np.nonzero(np.diff(t) <= 0)[0][0])
        raise UserError(f"{path}: time_s is not strictly increasing (row {k + 3}: {t[k + 1]:g} s after {t[k]:g} s)")
    if unit == "m" and np.abs(d).max() > 0.1:
        raise UserError(f"{path}: displacement_m reaches {np.abs(d).max():g} m; if the column is in mm, "
                        "name it displacement_mm")
    return t, d, f, unit


def _load_yaml(path, what):
    import yaml
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: {what} file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise UserError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a mapping of keys")
    return data


def read_geometry(path) -> dict:
    """The specimen geometry (the bundle's /geometry attributes) from a YAML file."""
    g = _load_yaml(path, "geometry")
    unknown = sorted(set(g) - set(GEOMETRY_KEYS) - {"mesh"})
    if unknown:
        raise UserError(f"{path}: unknown key(s) {unknown}; allowed: {', '.join([*GEOMETRY_KEYS, 'mesh'])}")
    out = {}
    for k, kind in GEOMETRY_KEYS.items():
        if k not in g:
            raise UserError(f"{path}: missing {k}" + (" (m)" if kind == "positive" else " ([x, y] in m)"))
        v = g[k]
        if kind == "positive":
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or v <= 0:
                raise UserError(f"{path}: {k} is {v!r}; expected a positive number of metres")
            if v > 1.0:
                raise UserError(f"{path}: {k} is {v!r} m; more than a metre: is it in mm?")
            out[k] = float(v)
        else:
            if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v)):
                raise UserError(f"{path}: {k} is {v!r}; expected [x, y] in m")
            out[k] = [float(x) for x in v]
    out["mesh"] = str(g.get("mesh", ""))
    return out


def read_transform(path) -> tuple[np.ndarray, np.ndarray]:
    """A rigid transform file-physical -> mesh coordinates from YAML with `rotation` (3x3,
    rows) and `translation_m` (3)."""
    g = _load_yaml(path, "transform")
    unknown = sorted(set(g) - {"rotation", "translation_m"})
    if unknown:
        raise UserError(f"{path}: unknown key(s) {unknown}; allowed: rotation, translation_m")
    try:
        R = np.asarray(g.get("rotation", np.eye(3).tolist()), float).reshape(3, 3)
        t = np.asarray(g.get("translation_m", [0.0, 0.0, 0.0]), float).reshape(3)
    except (TypeError, ValueError):
        raise UserError(f"{path}: rotation must be 3x3 and translation_m 3 numbers") from None
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise UserError(f"{path}: rotation is not a proper rotation (orthonormal, determinant +1)")
    return R, t


def import_bundle(volumes, frame_times, indenter, geometry, out, transform=None,
                  force_noise_N=0.0, displacement_noise_m=0.0) -> dict:
    """Read the lab's files, check them and write the bundle `out`; returns a summary."""
    frames, grid = read_volumes(volumes)
    times = read_frame_times(frame_times, len(frames))
    t, d, f, unit = read_indenter_csv(indenter)
    geo = read_geometry(geometry)
    if transform is not None:
        R, tr = read_transform(transform)
        grid = ImageGrid(grid.shape, grid.spacing_m, R @ np.asarray(grid.origin_m) + tr, R @ grid.R)
    if times[0] < t[0] - 1e-9 or times[-1] > t[-1] + 1e-9:
        raise UserError(f"{frame_times}: frames span {times[0]:g}-{times[-1]:g} s, outside the indenter "
                        f"record {t[0]:g}-{t[-1]:g} s ({indenter}): are both on the same clock?")
    dtype = frames[0].dtype
    if dtype in (np.uint8, np.uint16):
        scale = float(np.iinfo(dtype).max)
        vols = (v.astype(np.float64) / scale for v in frames)
        store = dtype.name
    else:
        vols = (v.astype(np.float32) for v in frames)
        store = "float32"
    for k, v in enumerate(frames):
        if dtype.kind == "f" and not np.isfinite(v).all():
            raise UserError(f"{volumes[min(k, len(volumes) - 1)]}: frame {k} holds NaN or infinite values")
    write_bundle(out, vols, grid, times, Indenter(t, d, f, displacement_noise_m, force_noise_N), geo,
                 dtype=store, imported_from=[str(p) for p in volumes], frame_times=str(frame_times),
                 indenter_file=str(indenter), indenter_displacement_unit=unit,
                 transform=str(transform) if transform else "none (file physical coordinates = mesh)")
    return dict(frames=len(frames), shape=grid.shape, spacing_m=grid.spacing_m, origin_m=grid.origin_m,
                dtype=store, samples=len(t), unit=unit)
