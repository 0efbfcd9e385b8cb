"""Bad input and hostile conditions: one line, exit status 2 (or 128 + signal), nothing
half-written left behind."""

import errno
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import COARSE

from liverinv.cli import main
from liverinv.errors import UserError
from liverinv.fileio import atomic_path

pytestmark = pytest.mark.skipif(not COARSE.is_file(), reason="benchmark mesh not available")

# modelled on config/truths/quick.yaml; analytic truth, 2 small volumes: nothing heavy runs
STUDY = f"""
mesh: {COARSE}
law: elastic
params: {{C1: 200.0, C2: 5000.0, D1: 1.5e-3}}
loading: {{control: displacement, depth: 6.0e-3, rate: 2.0e-3, steps: 4, unload: true}}
imaging:
  truth: analytic
  mode: warp
  seed: 1
  frames: 2
  frame_rate_hz: 5
  volume:
    shape: [24, 16, 32]
    spacing_m: [1.0e-3, 1.0e-3, 0.8e-3]
    standoff_m: 0.005
  bmode_noise: 0.0
  transducer: {{sigma_m: [2.0e-3, 2.0e-3, 1.2e-3]}}
  indenter: {{rate_hz: 100, noise: true}}
  storage: uint16
"""


def _leftovers(folder: Path):
    return sorted(p.name for p in folder.rglob("*") if p.suffix in (".h5", ".part", ".nc", ".probe"))


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _synthesize(tmp_path, text, capsys, out=None):
    study = tmp_path / "s.yaml"
    study.write_text(text)
    out = out or tmp_path / "b.h5"
    rc = main(["synthesize", str(study), "--out", str(out)])
    return rc, capsys.readouterr().err, study


def test_the_base_study_is_valid_and_cheap(tmp_path, capsys):
    rc, err, _ = _synthesize(tmp_path, STUDY, capsys)
    assert rc == 0, err
    assert _leftovers(tmp_path) == ["b.h5"]


@pytest.mark.parametrize("old, new, where, says", [
    ("    standoff_m: 0.005", "    standoff_m: 0.005\n    shap: [24, 16, 32]", "imaging/volume",
     "unknown key 'shap'; allowed keys: shape, spacing_m, standoff_m, origin_m"),
    ("noise: true}", "nosie: true}", "imaging/indenter",
     "unknown key 'nosie'; allowed keys: rate_hz, noise"),
    ("frame_rate_hz: 5", "frame_rate_hz: -26", "imaging/frame_rate_hz",
     "-26 is out of range; it must be > 0"),
    ("mode: warp", "mode: scan", "imaging/mode",
     "'scan' is not allowed; allowed values: warp, scatter"),
    ("storage: uint16", "storage: int8", "imaging/storage",
     "'int8' is not allowed; allowed values: uint8, uint16, float32, float64"),
    ("sigma_m: [2.0e-3, 2.0e-3, 1.2e-3]", "sigma: [2.0e-3, 2.0e-3, 1.2e-3]", "imaging/transducer",
     "unknown key 'sigma'; allowed keys: centre_frequency_hz, sound_speed_m_s, sigma_m,"),
    ("shape: [24, 16, 32]", "shape: [24, 16]", "imaging/volume/shape",
     "[24, 16] has 2 item(s); it needs exactly 3"),
    ("seed: 1", "sed: 1", "imaging", "unknown key 'sed'; allowed keys: truth, analytic, mode, seed,"),
    ("bmode_noise: 0.0", "bmode_noise: 0.0\n  decorrelation: 0.1", "imaging",
     "noise_db and decorrelation apply to mode 'scatter'"),
], ids=["volume-typo", "indenter-typo", "negative-frame-rate", "mode", "storage",
        "transducer-typo", "shape-length", "top-typo", "warp-decorrelation"])
def test_bad_imaging_keys_at_depth(tmp_path, capsys, old, new, where, says):
    assert old in STUDY
    rc, err, study = _synthesize(tmp_path, STUDY.replace(old, new), capsys)
    assert rc == 2
    line = _one_line(err)
    assert line.startswith(f"liverinv synthesize: error: {study}: {where}: "), line
    assert says in line, line
    assert _leftovers(tmp_path) == []


def test_every_shipped_truth_study_validates():
    from liverinv.imaging.synth import imaging_config
    from liverinv.study import load_study
    paths = sorted((Path(__file__).resolve().parents[1] / "config" / "truths").glob("*.yaml"))
    assert paths
    for path in paths:
        study, _ = load_study(path)
        imaging_config(study, str(path))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=lambda s: s.name)
def test_a_signal_during_synthesize_leaves_no_partial_output(tmp_path, sig):
    study = tmp_path / "s.yaml"
    # 60 volumes of 64 x 32 x 96: tens of seconds of rendering after the bundle is opened
    study.write_text(STUDY.replace("frames: 2", "frames: 60").replace("frame_rate_hz: 5", "frame_rate_hz: null")
                     .replace("[24, 16, 32]", "[64, 32, 96]")
                     .replace("[1.0e-3, 1.0e-3, 0.8e-3]", "[0.6e-3, 0.6e-3, 0.4e-3]"))
    out = tmp_path / "out"
    out.mkdir()
    p = subprocess.Popen([sys.executable, "-m", "liverinv.cli", "synthesize", str(study),
                          "--out", str(out / "b.h5"), "--truth-out", str(out / "t.nc")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 180
        while not list(out.glob(".*.part")):
            assert p.poll() is None, f"ended before a .part file appeared: {p.communicate()}"
            assert time.monotonic() < deadline, "no .part file after 180 s"
            time.sleep(0.05)
        time.sleep(0.3)                     # well inside the rendering of the frames
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 128 + sig, err
    assert _one_line(err) == f"liverinv synthesize: interrupted ({sig.name}); no partial output left"
    assert list(out.iterdir()) == []


def test_a_folder_that_cannot_exist_is_one_line(tmp_path, capsys):
    """A missing output folder is made; one under a regular file cannot be (not even by root)."""
    (tmp_path / "afile").write_text("")
    out = tmp_path / "afile" / "sub" / "b.h5"
    rc, err, _ = _synthesize(tmp_path, STUDY, capsys, out=out)
    assert rc == 2
    assert _one_line(err) == (f"liverinv synthesize: error: {out}: cannot write "
                              f"({tmp_path / 'afile'} is not a folder)")
    rc = main(["track", str(tmp_path / "missing.h5"), "--mesh", str(COARSE), "--out", str(out)])
    assert rc == 2 and "cannot write" in _one_line(capsys.readouterr().err)
    assert _leftovers(tmp_path) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores folder permissions")
def test_a_read_only_folder_is_one_line(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        rc, err, _ = _synthesize(tmp_path, STUDY, capsys, out=ro / "b.h5")
        assert rc == 2
        assert _one_line(err) == f"liverinv synthesize: error: {ro / 'b.h5'}: cannot write (Permission denied)"
        rc = main(["track", str(tmp_path / "missing.h5"), "--mesh", str(COARSE), "--out", str(ro / "f.nc")])
        assert rc == 2
        assert _one_line(capsys.readouterr().err).endswith(f"{ro / 'f.nc'}: cannot write (Permission denied)")
    finally:
        ro.chmod(0o755)
    assert _leftovers(tmp_path) == []


def test_a_full_disk_is_one_line(tmp_path, capsys, monkeypatch):
    import shutil
    from collections import namedtuple
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 ** 9, 10 ** 9 - 1000, 1000))
    rc, err, _ = _synthesize(tmp_path, STUDY, capsys)
    assert rc == 2
    assert "b.h5: cannot write (needs about 49 kB, 1 kB free)" in _one_line(err)
    assert _leftovers(tmp_path) == []


def test_an_oserror_while_writing_names_the_output(tmp_path):
    out = tmp_path / "x.nc"
    with pytest.raises(UserError, match=rf"^{re.escape(str(out))}: cannot write \(No space left on device\)$"):
        with atomic_path(out) as tmp:
            tmp.write_bytes(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_plot_of_a_bundle_or_a_flow_and_a_negative_depth_are_one_line(tmp_path, capsys):
    import h5py
    import numpy as np
    import xarray as xr
    from liverinv.imaging.bundle import FORMAT
    b = tmp_path / "b.h5"
    with h5py.File(b, "w") as f:
        f.attrs["format"] = FORMAT
    xr.Dataset({"u_of": (("frame", "node"), np.zeros((2, 3)))}).to_netcdf(tmp_path / "f.nc", engine="h5netcdf")
    for path, says in ((b, "a measurement bundle; plot takes run files"), (tmp_path / "f.nc", "a flow file")):
        assert main(["plot", str(path), "--out", str(tmp_path / "x.png")]) == 2
        assert says in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "x.png").exists()
    study = Path(__file__).resolve().parents[1] / "config/truths/benchmark.yaml"
    assert main(["simulate", str(study), "--depth", "-9e-3", "--out", str(tmp_path / "r.nc")]) == 2
    assert "loading/depth: -0.009 is out of range; it must be > 0" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "r.nc").exists()
