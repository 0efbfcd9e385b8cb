"""Measurement bundle: round trip and rejection of malformed files with clear messages."""

import h5py
import numpy as np
import pytest

from liverinv.cli import UserError
from liverinv.imaging.bundle import FORMAT_VERSION, Indenter, open_bundle, write_bundle
from liverinv.imaging.grid import ImageGrid


def _bundle(path, dtype="uint16", n=3):
    rng = np.random.default_rng(0)
    grid = ImageGrid((6, 5, 8), (0.5e-3, 0.5e-3, 0.3e-3), (-1e-3, -1e-3, -2e-3))
    vols = rng.random((n, *grid.shape)).astype(np.float32)
    ti = np.linspace(0, 1, 11)
    ind = Indenter(ti, 1e-3 * ti, 0.02 * ti, 3.9e-6, 13e-3)
    write_bundle(path, vols, grid, np.arange(n) / 26.0, ind,
                 {"tissue_height_m": 0.0303, "mesh": "m.msh"}, dtype=dtype)
    return grid, vols, ind


@pytest.mark.parametrize("dtype,tol", [("uint16", 1e-4), ("float32", 0.0)])
def test_round_trip(tmp_path, dtype, tol):
    p = tmp_path / "b.h5"
    grid, vols, ind = _bundle(p, dtype)
    with open_bundle(p, check_all_frames=True) as b:
        assert b.grid == grid
        assert b.n_frames == 3
        np.testing.assert_allclose(b.volumes(), vols, atol=tol)
        np.testing.assert_allclose(b.time_s, np.arange(3) / 26.0)
        np.testing.assert_allclose(b.indenter.force_N, ind.force_N)
        assert b.indenter.force_noise_rms_N == pytest.approx(13e-3)
        assert b.geometry["mesh"] == "m.msh"
        assert int(b.attrs["format_version"]) == FORMAT_VERSION


def _corrupt(path, fn):
    with h5py.File(path, "r+") as f:
        fn(f)


@pytest.mark.parametrize("change,words", [
    (lambda f: f.__delitem__("volumes/spacing_m"), ["/volumes/spacing_m", "missing"]),
    (lambda f: (f.__delitem__("volumes/spacing_m"), f.create_dataset("volumes/spacing_m", data=[1e-3, 1e-3])),
     ["/volumes/spacing_m", "length 2"]),
    (lambda f: (f.__delitem__("volumes/spacing_m"), f.create_dataset("volumes/spacing_m", data=[1e-3, 0, 1e-3])),
     ["/volumes/spacing_m", "> 0"]),
    (lambda f: (f.__delitem__("volumes/origin_m"), f.create_dataset("volumes/origin_m", data=[0, np.nan, 0])),
     ["/volumes/origin_m", "NaN"]),
    (lambda f: (f.__delitem__("volumes/time_s"), f.create_dataset("volumes/time_s", data=[0.0, 1.0])),
     ["/volumes/time_s", "length 2, expected 3"]),
    (lambda f: (f.__delitem__("volumes/time_s"), f.create_dataset("volumes/time_s", data=[0.0, 1.0, 0.5])),
     ["/volumes/time_s", "increasing"]),
    (lambda f: (f.__delitem__("volumes/data"), f.create_dataset("volumes/data", data=np.zeros((3, 6, 5)))),
     ["/volumes/data", "4 dimensions"]),
    (lambda f: f.__delitem__("indenter/force_N"), ["/indenter/force_N", "missing"]),
    (lambda f: f.attrs.__setitem__("format_version", 99), ["format_version", "99"]),
    (lambda f: f.attrs.__setitem__("format", "other"), ["format", "other"]),
])
def test_malformed_rejected(tmp_path, change, words):
    p = tmp_path / "bad.h5"
    _bundle(p, "float32")
    _corrupt(p, change)
    with pytest.raises(UserError) as e:
        open_bundle(p)
    msg = str(e.value)
    assert str(p) in msg
    for w in words:
        assert w in msg, msg


def test_nan_volume_rejected(tmp_path):
    p = tmp_path / "nan.h5"
    _bundle(p, "float32")
    _corrupt(p, lambda f: f["volumes/data"].__setitem__((1, 2, 2, 2), np.nan))
    with pytest.raises(UserError, match=r"/volumes/data: frame 1 holds NaN"):
        open_bundle(p, check_all_frames=True)


def test_not_a_bundle(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("hello")
    with pytest.raises(UserError, match="not an HDF5 file"):
        open_bundle(p)
    with pytest.raises(UserError, match="not found"):
        open_bundle(tmp_path / "missing.h5")
