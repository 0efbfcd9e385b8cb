"""The Snakemake workflow: study validation, the paper studies' fan-out, lint, the SLURM
profile, and a reduced quick study end to end (truth, render, track, fits, gather, tables,
figures)."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from conftest import COARSE

ROOT = Path(__file__).resolve().parents[1]
needs_snakemake = pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake not installed")


def snakemake(*args, cwd=ROOT):
    return subprocess.run(["snakemake", "--snakefile", str(ROOT / "Snakefile"), *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


def write_study(path, **over):
    """A valid workflow study (quick's truth on the tiny preset), with keys replaced."""
    spec = {"truth": str(ROOT / "config/truths/quick.yaml"), "truth_mesh": "tiny", "mesh": "tiny",
            "fit": {"laws": ["elastic"], "seeds": {"a": {"C1": 140.0, "C2": 6500.0, "D1": 1.05e-3}}}}
    for k, v in over.items():
        if v is None:
            spec.pop(k, None)
        elif k == "fit":
            spec["fit"] = {**spec["fit"], **v}
        else:
            spec[k] = v
    import yaml
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize("over, key, words", [
    (dict(fit={"laws": ["elastik"]}), "fit/laws", "unknown law 'elastik'"),
    (dict(tracking={"iterations": 3}), "(top level)", "allowed keys"),
    (dict(fit={"method": ["least-squares"]}), "fit", "allowed keys"),
    (dict(truth=None, bundle="nowhere.h5"), "bundle", "not found"),
    (dict(bundle="x.h5"), "(top level)", "exactly one of 'truth'"),
    (dict(fit={"seeds": {"a": {"C1": -5.0, "C2": 6500.0, "D1": 1e-3}}}), "fit/seeds/a", "outside its bounds"),
    (dict(fit={"seeds": {"a": {"C1": 140.0, "kapa": 1e-7}}}), "fit/seeds/a", "unknown parameter"),
    (dict(fit={"seeds": {"a": {"C1": 140.0, "g1": 0.3}}}), "fit/seeds/a", "belong to none of the laws"),
    (dict(fit={"seeds": {"a_b": {"C1": 140.0}}}), "fit/seeds", "does not match"),
    (dict(fit={"methods": ["simplex"]}), "fit/methods/0", "is not one of"),
    (dict(mesh="cylinder.msh"), "mesh", "neither a mesh file"),
    (dict(discover={"law": "elastic", "final_mesh": "fine.msh"}), "discover/final_mesh", "neither auto"),
])
def test_bad_studies_are_refused_naming_the_file_and_the_key(tmp_path, over, key, words):
    from liverinv.pipeline.spec import load_workflow_study
    from liverinv.study import StudyError
    path = write_study(tmp_path / "bad.yaml", **over)
    with pytest.raises(StudyError) as e:
        load_workflow_study(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {key}:") and words in msg, msg


def test_fit_jobs_and_their_options_follow_the_study(tmp_path):
    from liverinv.pipeline.spec import load_workflow_study
    s = load_workflow_study(write_study(tmp_path / "s.yaml", fit={
        "laws": ["elastic", "SR"], "methods": ["least-squares", "nelder-mead"], "design_points": 8,
        "seeds": {"a": {"C1": 140.0, "g1": 0.3}, "b": {"C1": 260.0}}, "fixed": {"SR": {"tau_g1": 0.2}}}))
    assert [j.tag for j in s.fit_jobs()][:3] == ["elastic_a_least-squares", "elastic_a_nelder-mead",
                                                 "elastic_b_least-squares"]
    assert len(s.fit_jobs()) == 8
    sr = s.fit_arguments(next(j for j in s.fit_jobs() if j.tag == "SR_a_least-squares"))
    assert "--start=g1=0.3" in sr and "--fixed=tau_g1=0.2" in sr and "--design-points" in sr
    assert not any(a.startswith("--start=tau_g1") for a in sr)          # held fixed, not started
    assert "--start=D1=0.0015" in sr                                    # the law's default
    nm = s.fit_arguments(next(j for j in s.fit_jobs() if j.tag == "SR_a_nelder-mead"))
    assert "--design-points" not in nm and "--tracker-response" not in nm
    assert s.truth_params() == {"C1": 200.0, "C2": 5000.0, "D1": 1.5e-3}
    # the design stage is solved by the first seed's fit and read back by the others
    shared = {j.tag: s.shared_with(j) for j in s.fit_jobs()}
    assert shared["SR_b_least-squares"].tag == "SR_a_least-squares"
    assert shared["SR_a_least-squares"] is None and shared["SR_b_nelder-mead"] is None
    # the first seed goes first (the others wait for it), then the other multi-start fits
    order = {j.tag: s.fit_priority(j) for j in s.fit_jobs()}
    assert order["SR_a_least-squares"] == 2 and order["SR_b_least-squares"] == 1
    assert order["SR_a_nelder-mead"] == 0
    s = load_workflow_study(write_study(tmp_path / "r.yaml", fit={
        "laws": ["elastic"], "seeds": {"a": {"C1": 140.0}}, "observation": "tracker", "tracker_response": True}))
    assert "--tracker-response" in s.fit_arguments(s.fit_jobs()[0])


@needs_snakemake
@pytest.mark.parametrize("study, jobs", [
    ("paper-table1", {"truth": 1, "render": 1, "track": 1, "mesh": 1, "fit": 3, "gather": 1, "tables": 1,
                      "convergence": 1, "figures": 1}),
    ("paper-table2", {"truth": 1, "render": 1, "track": 1, "mesh": 1, "fit": 3, "gather": 1, "tables": 1,
                      "convergence": 1, "figures": 1}),
    ("paper-table3", {"truth": 1, "render": 1, "track": 1, "fit": 5, "gather": 1, "tables": 1,
                      "convergence": 5, "figures": 1}),
    ("discover", {"mesh": 1, "truth": 1, "render": 1, "track": 1, "discover": 1}),
    ("paper-table1,paper-table2", {"truth": 1, "render": 1, "track": 1, "mesh": 1, "fit": 6, "gather": 2,
                                   "tables": 2, "convergence": 2, "figures": 2}),
])
def test_dry_run_of_the_paper_studies_fans_out(tmp_path, study, jobs):
    p = snakemake("-n", "--cores", "2", "--config", f"study={study}", f"results={tmp_path}/results")
    assert p.returncode == 0, p.stderr[-3000:]
    table = p.stdout[p.stdout.index("Job stats"):].splitlines()[3:]
    table = table[:next(i for i, ln in enumerate(table) if ln.startswith("total"))]
    counts = {ln.split()[0]: int(ln.split()[1]) for ln in table}
    assert {k: v for k, v in counts.items() if k != "all"} == jobs


@needs_snakemake
def test_slurm_profile_dry_run():
    pytest.importorskip("snakemake_executor_plugin_slurm")
    p = snakemake("--profile", ROOT / "workflow/profiles/slurm", "--config", "study=paper-table3", "-n")
    assert p.returncode == 0, p.stderr[-3000:]
    assert "fit" in p.stdout and "Job stats" in p.stdout


@needs_snakemake
def test_lint_is_clean():
    p = snakemake("--lint", "--config", "study=quick")
    assert p.returncode == 0 and "Congratulations, your workflow is in a good condition!" in (p.stdout + p.stderr), \
        (p.stdout + p.stderr)[-3000:]


@needs_snakemake
def test_a_bad_study_stops_the_workflow_before_any_job(tmp_path):
    bad = write_study(tmp_path / "bad.yaml", fit={"laws": ["elastik"]})
    cfg = tmp_path / "config.yaml"
    cfg.write_text(f"study: bad\nstudies: {{bad: {bad}}}\nresults: {tmp_path / 'results'}\n")
    p = snakemake("--configfile", cfg, "--cores", "1", "-n")
    assert p.returncode != 0 and "unknown law 'elastik'" in (p.stdout + p.stderr)
    assert not (tmp_path / "results").exists()


@needs_snakemake
def test_reduced_quick_study_end_to_end(tmp_path):
    """The quick study's stages on fewer, smaller volumes: every output is written, the fits
    recover the truth, a failed fit is a row, not a stop; a second run does nothing."""
    truth = tmp_path / "truth.yaml"
    truth.write_text((ROOT / "config/truths/quick.yaml").read_text()
                     .replace("../../../shared/benchmark/cylinder_coarse.msh", str(COARSE))
                     .replace("frames: 31", "frames: 16").replace("frame_rate_hz: 5", "frame_rate_hz: 2.5")
                     .replace("shape: [128, 48, 204]", "shape: [96, 40, 150]"))
    study = write_study(tmp_path / "mini.yaml", truth=str(truth), fit={
        "laws": ["elastic"], "seeds": {"low": {"C1": 140.0, "C2": 6500.0, "D1": 1.05e-3},
                                       "high": {"C1": 260.0, "C2": 3500.0, "D1": 1.95e-3}}},
        discover={"law": "elastic", "max_steps": 1, "final_mesh": "none"})
    cfg = tmp_path / "config.yaml"
    res = tmp_path / "results"
    cfg.write_text(f"study: mini\nstudies: {{mini: {study}}}\nresults: {res}\n")
    p = snakemake("--configfile", cfg, "--cores", "2", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-4000:]
    ds = xr.load_dataset(res / "mini/fits.nc", engine="h5netcdf")
    assert dict(ds.sizes)["seed"] == 2 and list(ds.law.values) == ["elastic"]
    err = ds.best.sel(param=["C1", "C2", "D1"]) / ds.truth.sel(param=["C1", "C2", "D1"]) - 1
    assert float(abs(err).max()) < 0.05, err.values
    assert (ds.status.values != "failed").all()
    # the misfit per residual cluster, kept for the paired comparison of laws, adds up to Phi
    assert np.allclose(ds.phi_cluster_common.sum("cluster"), ds.phi_common, rtol=1e-9, atol=0)
    assert 0 < int(ds.cluster_is_field.sum()) < ds.sizes["cluster"]
    assert json.loads(ds.attrs["fit_files"]) and len(ds.attrs["study_sha256"]) == 64
    md = (res / "mini/table.md").read_text()
    assert "## elastic" in md and "(140)" in md
    rk = pd.read_csv(res / "mini/ranking.csv")            # one law: its row says there is nothing to rank
    assert list(rk.law) == ["elastic"] and "nothing to rank" in rk.note[0]
    for f in ("figures/convergence_elastic.png", "figures/indenter.png", "figures/velocities.png"):
        assert (res / "mini" / f).stat().st_size > 20_000, f
    import meshio
    pvd = (res / "mini/figures/fields.pvd").read_text()
    frames = sorted((res / "mini/figures/fields_frames").glob("*.vtu"))
    assert len(frames) == 15 and pvd.count("<DataSet") == 15
    point_data = meshio.read(frames[3]).point_data
    assert set(point_data) == {"v_tracked", "v_model", "v_difference", "confidence"}
    assert np.allclose(point_data["v_difference"], point_data["v_tracked"] - point_data["v_model"])
    # the discovery (elastic truth: nothing to add) and a diagnosis of one fit, by their contract names
    disc = xr.load_dataset(res / "mini/discovery.nc", engine="h5netcdf")
    assert list(disc.added.values) == [""] and "nothing recommended" in disc.attrs["stopped_because"]
    assert {"phi", "phi_vol", "phi_ind", "predicted_drop", "params"} <= set(disc.data_vars)
    assert json.loads(disc.params.values[0]).keys() >= {"C1", "C2", "D1"}
    # warped volumes: the reported parameters are fitted on the motion corrected for the tracker's response
    response = json.loads(disc.attrs["tracker_response"])
    assert response["mesh"] == "tracking mesh" and response["n_solves"] >= 2     # final_mesh none: the only one
    assert response["params_before"] == pytest.approx(json.loads(disc.params_tracking_mesh.values[-1]))
    reported = json.loads(disc.params.values[-1])
    assert reported != response["params_before"]
    for k, v in dict(C1=200.0, C2=5000.0, D1=1.5e-3).items():
        assert reported[k] == pytest.approx(v, rel=0.05), (k, reported)
    from liverinv.cli import main
    data = next((res / "data").glob("*/bundle.h5")).parent
    rc = main(["diagnose", "--fit", str(res / "mini/fits/elastic_low_least-squares.nc"), "--bundle",
               str(data / "bundle.h5"), "--flow", str(next(data.glob("flow_*.nc"))), "--mesh",
               str(res / "meshes/tiny.msh"), "--out", str(tmp_path / "diag.nc")])
    assert rc == 0
    diag = xr.load_dataset(tmp_path / "diag.nc", engine="h5netcdf")
    from liverinv.diagnose.effects import CATALOG
    assert diag.attrs["recommended"] == "none" and set(diag.effect.values) <= set(CATALOG)
    # warped volumes: the stricter level and its caveat
    assert "warping" in diag.attrs["caveat"] and "warping" in disc.attrs["caveat"]
    assert diag.attrs["alpha"] == disc.attrs["alpha"] == 1e-4 and "(p < 0.0001 after" in disc.attrs["defaults"]
    assert len(diag.effect) == len(CATALOG) - 1          # all but strain stiffening (elastic has C2)
    assert (diag.predicted_drop.values[:-1] >= diag.predicted_drop.values[1:]).all()      # rank order
    assert {"p_value", "estimate", "share_region", "share_time"} <= set(diag.data_vars)
    # rerunning a finished study does nothing
    again = snakemake("--configfile", cfg, "--cores", "2", "-n", cwd=tmp_path)
    assert again.returncode == 0 and "Nothing to be done" in (again.stdout + again.stderr)


def test_a_failed_fit_is_recorded_and_gathered_as_a_failed_row(tmp_path):
    from liverinv.cli import main
    from liverinv.pipeline.gather import gather_fits
    from liverinv.pipeline.spec import FitJob, load_workflow_study
    from liverinv.pipeline.tables import fit_table, markdown_table
    out = tmp_path / "elastic_a_least-squares.nc"
    rc = main(["fit", "--bundle", str(tmp_path / "none.h5"), "--flow", str(tmp_path / "none.nc"), "--mesh",
               str(COARSE), "--law", "elastic", "--start=C1=140", "--keep-going", "--out", str(out)])
    assert rc == 0
    failed = xr.load_dataset(out, engine="h5netcdf")
    assert failed.attrs["status"] == "failed" and "bundle file not found" in failed.attrs["error"]
    s = load_workflow_study(write_study(tmp_path / "s.yaml"))
    ds = gather_fits(s, {FitJob("elastic", "a", "least-squares"): out})
    assert str(ds.status.sel({"law": "elastic", "seed": "a", "method": "least-squares"}).values) == "failed"
    assert np.isnan(ds.best.values).all() and float(ds.start.sel(param="C1").squeeze()) == 140.0
    row = fit_table(ds).iloc[0]
    assert row.status == "failed" and "not found" in row.message
    assert "**failed**" in markdown_table(ds) and "failed: " in markdown_table(ds)
