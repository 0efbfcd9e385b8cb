"""`liverinv simulate` end to end: a run file with everything a user needs, and clear
one-line errors with no output on bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

from conftest import COARSE

LIVERINV = [sys.executable, "-m", "liverinv.cli"]


def run(*args):
    return subprocess.run(LIVERINV + list(args), capture_output=True, text=True)


def test_simulate_writes_a_complete_run_file(tmp_path):
    out = tmp_path / "run.nc"
    p = run("simulate", "--mesh", str(COARSE), "--law", "SR", "--param", "C1=200", "--param", "C2=5000",
            "--param", "D1=1.5e-3", "--param", "g1=0.4", "--param", "tau_g1=0.06",
            "--depth", "2e-3", "--rate", "2e-3", "--steps", "4", "--unload", "--out", str(out))
    assert p.returncode == 0, p.stderr
    ds = xr.open_dataset(out, engine="h5netcdf")
    assert ds.sizes["time"] == 9 and ds.u.dims == ("time", "node", "component")
    assert ds.indenter_depth.attrs["units"] == "m" and ds.indenter_force.attrs["units"] == "N"
    assert ds.indenter_depth.values.max() == pytest.approx(2e-3)
    assert ds.X.shape == (1490, 3) and ds.cells.shape == (819, 10)
    assert json.loads(ds.attrs["params"]) == dict(C1=200, C2=5000, D1=1.5e-3, g1=0.4, tau_g1=0.06)
    assert ds.attrs["law"] == "SR" and len(ds.attrs["mesh_sha256"]) == 64
    assert "liverinv_version" in ds.attrs
    # viscoelastic: unloading force below loading force at the same depth
    F = ds.indenter_force.values
    assert F[6] < F[2]


def test_force_history_csv_drives_the_punch(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("time_s,force_N\n0,0\n0.5,0.01\n1.0,0.03\n")
    out = tmp_path / "run.nc"
    p = run("simulate", "--mesh", str(COARSE), "--law", "elastic", "--force-history", str(csv), "--out", str(out))
    assert p.returncode == 0, p.stderr
    ds = xr.open_dataset(out, engine="h5netcdf")
    assert np.allclose(ds.indenter_force.values, [0, 0.01, 0.03], atol=1e-7)
    assert ds.attrs["control"] == "force" and np.all(np.diff(ds.indenter_depth.values) > 0)


@pytest.mark.parametrize("args, message", [
    (["--law", "nope"], "unknown law 'nope'"),
    (["--law", "elastic", "--param", "C9=1"], "has no parameter(s) ['C9']"),
    (["--law", "SR", "--param", "g1=2"], "outside its bounds"),
    (["--law", "SR_low", "--param", "D1=1e-3"], "fixes ['D1']"),
    (["--law", "elastic", "--param", "C1"], "expected NAME=VALUE"),
])
def test_bad_input_is_one_clear_line_and_no_file(tmp_path, args, message):
    out = tmp_path / "run.nc"
    p = run("simulate", "--mesh", str(COARSE), *args, "--steps", "1", "--depth", "1e-4", "--out", str(out))
    assert p.returncode == 2
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.iterdir())


def test_bad_mesh_files_name_the_file_and_the_problem(tmp_path):
    import meshio
    bad = tmp_path / "linear.msh"
    meshio.write_points_cells(bad, np.eye(4, 3), [("tetra", np.array([[0, 1, 2, 3]]))], file_format="gmsh")
    p = run("simulate", "--mesh", str(bad), "--law", "elastic", "--out", str(tmp_path / "x.nc"))
    assert p.returncode == 2 and str(bad) in p.stderr and "tetra10" in p.stderr
    junk = tmp_path / "junk.msh"
    junk.write_text("not a mesh")
    p = run("simulate", "--mesh", str(junk), "--law", "elastic", "--out", str(tmp_path / "x.nc"))
    assert p.returncode == 2 and str(junk) in p.stderr
    assert not (tmp_path / "x.nc").exists()


def test_missing_group_is_named(tmp_path, coarse_mesh):
    import meshio
    m = meshio.read(COARSE)
    m.field_data["punch"] = m.field_data.pop("footprint")
    path = tmp_path / "nofoot.msh"
    meshio.write(path, m, file_format="gmsh", binary=False)
    from liverinv.mesh import MeshError, read_mesh
    with pytest.raises(MeshError, match="footprint"):
        read_mesh(path)


def test_study_schema_errors_are_reported(tmp_path):
    study = tmp_path / "s.yaml"
    study.write_text(f"mesh: {COARSE}\nlaw: elastic\nloading: {{control: sideways}}\n")
    p = run("simulate", str(study), "--out", str(tmp_path / "x.nc"))
    assert p.returncode == 2 and "loading/control" in p.stderr
