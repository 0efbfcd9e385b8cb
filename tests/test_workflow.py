"""The Snakemake workflow end to end on a tiny study (a small version of the default run)."""

import shutil
import subprocess
from pathlib import Path

import pytest
import xarray as xr

from conftest import COARSE

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake not installed")
def test_workflow_runs_a_tiny_study(tmp_path):
    study = tmp_path / "tiny.yaml"
    study.write_text(f"mesh: {COARSE}\nlaw: elastic\nparams: {{C1: 200.0, C2: 5000.0, D1: 1.5e-3}}\n"
                     "loading: {control: displacement, depth: 1.0e-3, rate: 2.0e-3, steps: 2, unload: true}\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(f"studies:\n  tiny: {study}\nresults: {tmp_path / 'results'}\n")
    p = subprocess.run(["snakemake", "--snakefile", str(ROOT / "Snakefile"), "--configfile", str(cfg),
                        "--directory", str(tmp_path), "--cores", "1", "--quiet"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-3000:]
    out = tmp_path / "results" / "tiny"
    assert (out / "force_displacement.png").stat().st_size > 10_000
    assert (out / "fields.pvd").exists() and len(list((out / "fields_frames").glob("*.vtu"))) == 5
    ds = xr.open_dataset(out / "run.nc", engine="h5netcdf")
    assert ds.indenter_force.values.max() > 0.01


@pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake not installed")
def test_workflow_rejects_a_bad_config_before_any_work(tmp_path):
    cfg = tmp_path / "config.yaml"
    cfg.write_text("studies: {}\n")
    p = subprocess.run(["snakemake", "--snakefile", str(ROOT / "Snakefile"), "--configfile", str(cfg),
                        "--directory", str(tmp_path), "--cores", "1", "-n"], capture_output=True, text=True)
    assert p.returncode != 0 and "studies" in (p.stdout + p.stderr)
    assert not (tmp_path / "results").exists()
