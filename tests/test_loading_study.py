"""Load histories, study validation and the workflow's wiring."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from liverinv.loading import ramp_history, read_force_history
from liverinv.study import StudyError, load_study, validate_study

ROOT = Path(__file__).resolve().parents[1]


def test_ramp_with_steps_hits_the_peak():
    h = ramp_history(9.2e-3, 2e-3, steps=46, unload=True)
    assert len(h.time) == 93 and h.time[-1] == pytest.approx(9.2)
    assert h.value[46] == pytest.approx(9.2e-3) and h.value[23] == pytest.approx(4.6e-3)
    assert h.value[-1] == pytest.approx(0, abs=1e-15)
    assert np.allclose(np.diff(h.value[:47]), 2e-4)


def test_ramp_with_frames_and_hold():
    h = ramp_history(1e-3, 1e-3, frames=31, unload=True, hold=1.0)
    assert len(h.time) == 31 and h.time[-1] == pytest.approx(3.0)
    assert np.allclose(h.value[(h.time >= 1) & (h.time <= 2)], 1e-3)
    with pytest.raises(ValueError, match="exactly one"):
        ramp_history(1e-3, 1e-3)
    with pytest.raises(ValueError, match="positive"):
        ramp_history(-1e-3, 1e-3, steps=2)


def test_force_history_csv_is_validated(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text("time_s,force_N\n0,0\n1,0.1\n")
    h = read_force_history(p)
    assert h.control == "force" and np.allclose(h.value, [0, 0.1])
    p.write_text("t,F\n0,0\n1,0.1\n")
    with pytest.raises(ValueError, match="missing column"):
        read_force_history(p)
    p.write_text("time_s,force_N\n0,0.2\n1,0.1\n")
    with pytest.raises(ValueError, match="0 at time 0"):
        read_force_history(p)
    p.write_text("time_s,force_N\n0,0\n0,0.1\n")
    with pytest.raises(ValueError, match="increase"):
        read_force_history(p)


def test_shipped_studies_validate():
    from liverinv.pipeline.spec import load_workflow_study
    for path in sorted((ROOT / "config" / "truths").glob("*.yaml")):
        study, base = load_study(path)
        assert (base / study["mesh"]).exists(), path
    for path in sorted((ROOT / "config" / "studies").glob("*.yaml")):
        if path.stem != "bundle":                  # the template names a bundle made by quick
            s = load_workflow_study(path)
            assert s.fit_jobs() or s.discover, path


def test_schema_rejects_bad_studies():
    with pytest.raises(StudyError, match="law"):
        validate_study({"mesh": "m.msh", "loading": {}})
    with pytest.raises(StudyError, match="punch"):
        validate_study({"mesh": "m.msh", "law": "SR", "loading": {}, "contact": {"punch": "glued"}})


@pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake not installed")
def test_workflow_dry_run_and_lint():
    p = subprocess.run(["snakemake", "-n", "--forceall", "--cores", "1", "--directory", str(ROOT)],
                       capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "truth" in p.stdout and "fit" in p.stdout


def test_yaml_scientific_notation_without_dot_is_a_number(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("mesh: m.msh\nlaw: SR\nparams: {D1: 1e-3, C1: 2E2}\nloading: {depth: 9e-3, rate: 2e-3, steps: 2}\n")
    study, _ = load_study(p)
    assert study["params"] == {"D1": 1e-3, "C1": 200.0} and study["loading"]["depth"] == 9e-3


def test_with_times_adds_frames_on_the_ramp():
    from liverinv.study import with_times
    h = ramp_history(1e-3, 1e-3, steps=2, unload=True)
    h2 = with_times(h, [0.1, 0.5, 1.3, 5.0, 0.5 + 1e-14])
    np.testing.assert_allclose(h2.time, [0, 0.1, 0.5, 1.0, 1.3, 1.5, 2.0])
    np.testing.assert_allclose(h2.value, [0, 1e-4, 5e-4, 1e-3, 7e-4, 5e-4, 0], atol=1e-15)
    assert h2.control == h.control
