"""`liverinv synthesize` and `liverinv track` end to end on a small volume."""

import argparse
import json
import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from liverinv.cli import UserError
from liverinv.commands import fit, plot, synthesize, track
from liverinv.imaging.bundle import open_bundle

MESH = Path(__file__).resolve().parents[2] / "shared" / "benchmark" / "cylinder_coarse.msh"
pytestmark = pytest.mark.skipif(not MESH.is_file(), reason="benchmark mesh not available")

STUDY = f"""
mesh: {MESH}
law: elastic
params: {{C1: 200.0, C2: 5000.0, D1: 1.5e-3}}
loading: {{control: displacement, depth: 9.2e-3, rate: 2.0e-3, steps: 4, unload: true, frames: 5}}
imaging:
  truth: analytic
  seed: 2
  frames: 3
  frame_rate_hz: 26
  volume: {{shape: [40, 12, 48], spacing_m: [1.0e-3, 1.0e-3, 0.8e-3], standoff_m: 0.005}}
  transducer: {{sigma_m: [2.0e-3, 2.0e-3, 1.2e-3]}}
  indenter: {{rate_hz: 50, noise: true}}
"""


def _parser():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command", required=True)
    for command in (synthesize, track, fit, plot):
        command.register(sub)
    return p


@pytest.fixture(scope="module")
def synthesized(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("synth")
    study = tmp_path / "s.yaml"
    study.write_text(STUDY)
    bundle, truth = tmp_path / "b.h5", tmp_path / "t.nc"
    a = _parser().parse_args(["synthesize", str(study), "--out", str(bundle), "--truth-out", str(truth)])
    assert a.func(a) == 0
    return bundle, truth


def test_synthesize_then_track(tmp_path, synthesized):
    bundle, truth = synthesized
    flow, png = tmp_path / "f.nc", tmp_path / "f.png"
    p = _parser()
    with open_bundle(bundle, check_all_frames=True) as b:
        assert b.n_frames == 3 and b.grid.shape == (40, 12, 48)
        np.testing.assert_allclose(np.diff(b.time_s), 1 / 26)
        assert b.indenter.displacement_noise_rms_m == pytest.approx(3.9e-6)
        assert len(b.indenter.time_s) > 400
    t = xr.load_dataset(truth)
    assert t["u"].dims == ("time", "node", "component")
    a = p.parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow),
                      "--stride", "1", "1", "1", "--picture", str(png)])
    assert a.func(a) == 0
    f = xr.load_dataset(flow)
    assert f["u_of"].shape == (2, 1490, 3) and f["c_of"].shape == (2, 1490, 3)
    c = f["c_of"].values
    assert c.min() >= 0 and c.max() == pytest.approx(1.0)
    X = f["X"].values
    outside = np.abs(X[:, 1]) > 7e-3                   # beyond the elevational field of view
    assert np.all(c[:, outside] == 0)
    assert np.isfinite(f["u_of"].values).all()
    assert png.stat().st_size > 1000


def test_bad_imaging_key_is_a_user_error(tmp_path):
    study = tmp_path / "s.yaml"
    study.write_text(STUDY.replace("seed: 2", "sed: 2"))
    a = _parser().parse_args(["synthesize", str(study), "--out", str(tmp_path / "b.h5")])
    with pytest.raises(UserError, match=r"s.yaml: imaging: unknown key 'sed'; allowed keys: truth, analytic, mode, seed,"):
        a.func(a)
    assert not (tmp_path / "b.h5").exists()


def test_fit_writes_a_complete_fit_file_and_its_convergence_figure(tmp_path, synthesized):
    bundle, _ = synthesized
    flow, out, png = tmp_path / "f.nc", tmp_path / "fit.nc", tmp_path / "conv.png"
    p = _parser()
    a = p.parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH),
                      "--law", "elastic", "--start", "C1=150", "--fixed", "D1=1.5e-3",
                      "--method", "least-squares", "--max-evaluations", "3",
                      "--checkpoint", str(tmp_path / "ck"), "--out", str(out)])
    assert a.func(a) == 0
    ds = xr.load_dataset(out)
    assert list(ds.param.values) == ["C1", "C2"]
    n = ds.sizes["evaluation"]
    assert n == ds.attrs["n_solves"] >= 3               # one solve per evaluation (sensitivities)
    assert set(ds.history_purpose.values) == {"least-squares"} and ds.attrs["jacobian"] == "sensitivity"
    ok = ds.history_ok.values
    assert float(ds.phi) == pytest.approx(ds.history_phi.values[ok].min(), rel=1e-9)
    assert float(ds.phi) == pytest.approx(float(ds.phi_vol + ds.phi_ind), rel=1e-12)
    assert float((ds.residual ** 2).sum()) == pytest.approx(float(ds.phi), rel=1e-9)
    assert ds.v_fem.shape == (2, 1490, 3) and ds.corr.shape == (2, 2)
    assert np.allclose(np.diag(ds.corr.values), 1.0)
    lines = (tmp_path / "ck" / "evaluations.jsonl").read_text().splitlines()
    assert len(lines) == n
    a = p.parse_args(["plot", str(out), "--out", str(png), "--truth", "C1=200", "--truth", "C2=5000"])
    assert a.func(a) == 0
    assert png.stat().st_size > 5000
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH),
                      "--law", "nope", "--out", str(tmp_path / "x.nc")])
    with pytest.raises(UserError, match="nope"):
        a.func(a)
    assert not (tmp_path / "x.nc").exists()
    # the model on another mesh: velocities at the tracked nodes; a flow/mesh mismatch refused
    from liverinv.meshgen import generate_indentation_mesh
    other = generate_indentation_mesh(tmp_path / "other.msh", h_far=0.03, h_rim=0.004)
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(other),
                      "--law", "elastic", "--out", str(tmp_path / "x.nc")])
    with pytest.raises(UserError, match="was it tracked on this mesh"):
        a.func(a)
    out2 = tmp_path / "fit2.nc"
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH),
                      "--model-mesh", str(other), "--law", "elastic", "--start", "C1=150",
                      "--fixed", "D1=1.5e-3", "--fixed", "C2=5000", "--max-evaluations", "2", "--out", str(out2)])
    assert a.func(a) == 0
    ds2 = xr.load_dataset(out2)
    assert ds2.v_fem.shape == (2, 1490, 3) and ds2.attrs["model_mesh"] == str(other)
    assert float((ds2.residual ** 2).sum()) == pytest.approx(float(ds2.phi), rel=1e-9)
    # the model seen through the tracker (window averages): recorded, and a flow without its
    # tracking options refused
    out3 = tmp_path / "fit3.nc"
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH),
                      "--model-mesh", str(other), "--observation", "tracker", "--law", "elastic",
                      "--start", "C1=150", "--fixed", "D1=1.5e-3", "--fixed", "C2=5000",
                      "--max-evaluations", "2", "--out", str(out3)])
    assert a.func(a) == 0
    ds3 = xr.load_dataset(out3)
    assert ds3.attrs["observation"] == "tracker" and ds3.v_fem.shape == (2, 1490, 3)
    assert float((ds3.residual ** 2).sum()) == pytest.approx(float(ds3.phi), rel=1e-9)
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH),
                      "--observation", "tracker", "--law", "elastic", "--start", "C1=150",
                      "--fixed", "D1=1.5e-3", "--fixed", "C2=5000", "--max-evaluations", "1",
                      "--out", str(tmp_path / "fit4.nc")])
    assert a.func(a) == 0                                # the model on the tracking mesh itself
    f = xr.load_dataset(flow)
    del f.attrs["options"]
    f.to_netcdf(tmp_path / "bare.nc", engine="h5netcdf")
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(tmp_path / "bare.nc"), "--mesh", str(MESH),
                      "--observation", "tracker", "--law", "elastic", "--out", str(tmp_path / "x.nc")])
    with pytest.raises(UserError, match="tracking options"):
        a.func(a)


def test_simulated_truth_has_an_equilibrium_state_at_every_frame(tmp_path):
    """Frames at 26 Hz fall between the loading steps: they are added to the simulated
    history, so each volume shows a solved state (not an interpolation between steps)."""
    study = tmp_path / "s.yaml"
    study.write_text(STUDY.replace("truth: analytic", "truth: simulate").replace(", frames: 5}", "}").replace("frames: 3", "frames: 4"))
    truth = tmp_path / "t.nc"
    a = _parser().parse_args(["synthesize", str(study), "--out", str(tmp_path / "b.h5"), "--truth-out", str(truth)])
    assert a.func(a) == 0
    t = xr.load_dataset(truth)
    frames = np.arange(4) / 26.0
    assert np.abs(t.time.values[:, None] - frames[None, :]).min(axis=0).max() < 1e-9
    assert len(t.time) == 4 * 2 + 1 + 3                 # 4 steps per ramp + the 3 frames after t = 0
    with open_bundle(tmp_path / "b.h5") as b:
        np.testing.assert_allclose(b.time_s, frames)


def test_fits_refuse_stale_checkpoints_drop_torn_lines_and_never_crash(tmp_path, synthesized):
    bundle, _ = synthesized
    flow = tmp_path / "f.nc"
    p = _parser()
    a = p.parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    ck, out = tmp_path / "ck", tmp_path / "fit.nc"
    base = ["fit", "--bundle", str(bundle), "--mesh", str(MESH), "--law", "elastic", "--start", "C1=150",
            "--fixed", "D1=1.5e-3", "--fixed", "C2=5000", "--max-evaluations", "2", "--checkpoint", str(ck)]
    a = p.parse_args(base + ["--flow", str(flow), "--out", str(out)])
    assert a.func(a) == 0
    first = xr.load_dataset(out)
    n_logged = len((ck / "evaluations.jsonl").read_text().splitlines())
    # the same motion tracked again (other run times in the file): the logged solves hold
    again_flow = tmp_path / "f2.nc"
    a = p.parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(again_flow)])
    assert a.func(a) == 0
    assert xr.load_dataset(again_flow).attrs["cpu_seconds"] != xr.load_dataset(flow).attrs["cpu_seconds"]
    a = p.parse_args(base + ["--flow", str(again_flow), "--out", str(tmp_path / "again.nc")])
    assert a.func(a) == 0
    assert len((ck / "evaluations.jsonl").read_text().splitlines()) == n_logged
    assert float(xr.load_dataset(tmp_path / "again.nc").phi) == pytest.approx(float(first.phi), rel=1e-9)
    # another flow with the same checkpoint: refused, nothing written
    f = xr.load_dataset(flow)
    f["u_of"] = f.u_of * 1.01
    f.to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    a = p.parse_args(base + ["--flow", str(tmp_path / "other.nc"), "--out", str(tmp_path / "x.nc")])
    with pytest.raises(UserError, match=r"written for other inputs \(differs in: flow\)"):
        a.func(a)
    assert not (tmp_path / "x.nc").exists()
    # a torn last line (a kill while writing) is dropped and that solve redone: same result
    log = ck / "evaluations.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    log.write_text("".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2])
    a = p.parse_args(base + ["--flow", str(flow), "--out", str(out)])
    assert a.func(a) == 0
    again = xr.load_dataset(out)
    assert float(again.phi) == pytest.approx(float(first.phi), rel=1e-9)
    assert len(log.read_text().splitlines()) == len(lines)
    # --fresh-checkpoint sets the stale one aside
    a = p.parse_args(base + ["--flow", str(tmp_path / "other.nc"), "--out", str(tmp_path / "x.nc"),
                             "--fresh-checkpoint"])
    assert a.func(a) == 0 and (tmp_path / "ck.stale-1" / "evaluations.jsonl").exists()
    # a start on a log-scaled bound: one line
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH), "--law", "elastic",
                      "--start", "C2=0", "--out", str(tmp_path / "y.nc")])
    with pytest.raises(UserError, match="start C2=0: a log-scaled parameter needs a start above 0"):
        a.func(a)
    # every solve fails: the fit file says so and the command fails with one line
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH), "--law", "elastic",
                      "--objective", "paper", "--start", "C1=0.02", "--start", "C2=1", "--fixed", "D1=1.5e-3",
                      "--max-evaluations", "1", "--out", str(tmp_path / "z.nc")])
    with pytest.raises(UserError, match="no forward solve succeeded"):
        a.func(a)
    assert xr.load_dataset(tmp_path / "z.nc").attrs["status"] == "failed"
    # a flow without confident nodes (mesh outside the images): refused unless --indenter-only
    f = xr.load_dataset(flow)
    f["c_of"] = f.c_of * 0.0
    f.to_netcdf(tmp_path / "blind.nc", engine="h5netcdf")
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(tmp_path / "blind.nc"), "--mesh", str(MESH),
                      "--law", "elastic", "--out", str(tmp_path / "w.nc")])
    with pytest.raises(UserError, match="only 0 tracked nodes have confidence"):
        a.func(a)
    a = p.parse_args(["fit", "--bundle", str(bundle), "--flow", str(tmp_path / "blind.nc"), "--mesh", str(MESH),
                      "--law", "elastic", "--objective", "paper", "--fixed", "D1=1.5e-3", "--fixed", "C2=5000",
                      "--start", "C1=150", "--max-evaluations", "1", "--indenter-only", "--out", str(tmp_path / "w.nc")])
    assert a.func(a) == 0
    assert float(xr.load_dataset(tmp_path / "w.nc").phi_vol) == 0.0
    with pytest.raises(SystemExit):
        p.parse_args(base + ["--flow", str(flow), "--out", str(out), "--max-evaluations", "0"])


def test_a_bundle_exported_to_nrrd_and_imported_back_tracks_to_the_same_flow(tmp_path, synthesized):
    """Round trip through the lab's formats: the synthetic bundle's volumes written as NRRD
    files (SimpleITK, mm), its record as CSVs; `liverinv import` gives the same voxels and grid,
    and `liverinv track` the same flow."""
    sitk = pytest.importorskip("SimpleITK")
    import json
    bundle, _ = synthesized
    from liverinv.cli import main
    with open_bundle(bundle) as b:
        raw = b._file["volumes/data"][...]
        g, ind, geo, times = b.grid, b.indenter, dict(b.geometry), b.time_s
    files = []
    for k, v in enumerate(raw):
        img = sitk.GetImageFromArray(v.transpose(2, 1, 0))
        img.SetSpacing(tuple(1e3 * np.asarray(g.spacing_m)))
        img.SetOrigin(tuple(1e3 * np.asarray(g.origin_m)))
        img.SetDirection(tuple(g.R.ravel()))
        files.append(tmp_path / f"frame{k}.nrrd")
        sitk.WriteImage(img, str(files[-1]))
    (tmp_path / "frames.csv").write_text("frame,time_s\n" + "".join(f"{k},{float(t)!r}\n" for k, t in enumerate(times)))
    (tmp_path / "ind.csv").write_text("time_s,displacement_m,force_N\n" + "".join(
        f"{float(t)!r},{float(d)!r},{float(f)!r}\n" for t, d, f in zip(ind.time_s, ind.displacement_m, ind.force_N)))
    axis = geo["indenter_axis_m"]
    axis = json.loads(axis) if isinstance(axis, (str, bytes)) else list(axis)
    (tmp_path / "geo.yaml").write_text("".join(f"{k}: {float(geo[k])!r}\n" for k in
                                               ("tissue_height_m", "tissue_radius_m", "indenter_radius_m"))
                                       + f"indenter_axis_m: [{axis[0]}, {axis[1]}]\n")
    out = tmp_path / "imported.h5"
    assert main(["import", "--volumes", *map(str, files), "--frame-times", str(tmp_path / "frames.csv"), "--indenter",
                 str(tmp_path / "ind.csv"), "--geometry", str(tmp_path / "geo.yaml"), "--out", str(out)]) == 0
    with open_bundle(out) as b2:
        np.testing.assert_array_equal(b2._file["volumes/data"][...], raw)
        np.testing.assert_allclose(b2.grid.origin_m, g.origin_m, atol=1e-12)
        np.testing.assert_allclose(b2.grid.spacing_m, g.spacing_m, rtol=1e-12)
    flows = []
    for src, name in ((bundle, "a.nc"), (out, "b.nc")):
        assert main(["track", str(src), "--mesh", str(MESH), "--out", str(tmp_path / name)]) == 0
        flows.append(xr.load_dataset(tmp_path / name))
    np.testing.assert_allclose(flows[1].u_of.values, flows[0].u_of.values, rtol=0, atol=1e-12)
    np.testing.assert_allclose(flows[1].c_of.values, flows[0].c_of.values, rtol=0, atol=1e-12)


def test_tracker_response_to_the_true_motion_is_the_tracked_data(tmp_path, synthesized):
    """Warped data: the first volume warped by the truth's own displacement and tracked with
    the flow's options (`imaging.response.tracker_response`) is the tracked flow itself, but for
    the uint16 storage of each frame (measured: 8e-4 of the largest motion)."""
    from liverinv.imaging.response import tracker_response
    from liverinv.mesh import TetMesh, read_mesh

    bundle, truth = synthesized
    flow = tmp_path / "f.nc"
    a = _parser().parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    f, t = xr.load_dataset(flow), xr.load_dataset(truth)
    with open_bundle(bundle) as b:
        u = t.u.interp(time=b.time_s).values
        r = tracker_response(b, f, read_mesh(MESH, required=()), TetMesh(t.X.values, t.cells.values), u)
    tracked = f.u_of.values
    assert np.abs(tracked).max() > 1e-5
    assert np.abs(r - tracked).max() < 3e-3 * np.abs(tracked).max()


def test_tracker_response_to_noisy_warped_volumes_is_the_noise_free_one_times_the_noise_gain(tmp_path):
    """Warped volumes with B-mode noise: the response is the noise-free response (the first
    volume warped, tracked) scaled per component by the slope of a noisy response on it, held in
    `NOISE_GAIN_RANGE` (noise only shrinks the tracked motion); `bmode_noise=0` gives the
    noise-free response."""
    from liverinv.imaging.response import NOISE_GAIN_RANGE, tracker_response
    from liverinv.mesh import TetMesh, read_mesh

    study, bundle, truth, flow = tmp_path / "s.yaml", tmp_path / "b.h5", tmp_path / "t.nc", tmp_path / "f.nc"
    study.write_text(STUDY.replace("  seed: 2\n", "  seed: 2\n  bmode_noise: 0.05\n").replace("frame_rate_hz: 26", "frame_rate_hz: 4"))
    for argv in (["synthesize", str(study), "--out", str(bundle), "--truth-out", str(truth)],
                 ["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)]):
        a = _parser().parse_args(argv)
        assert a.func(a) == 0
    f, t = xr.load_dataset(flow), xr.load_dataset(truth)
    with open_bundle(bundle) as b:
        assert json.loads(b.attrs["imaging"])["bmode_noise"] == 0.05
        u = t.u.interp(time=b.time_s).values
        mesh, truth_mesh = read_mesh(MESH, required=()), TetMesh(t.X.values, t.cells.values)
        clean = tracker_response(b, f, mesh, truth_mesh, u, bmode_noise=0.0)
        scaled = tracker_response(b, f, mesh, truth_mesh, u)
    assert np.abs(clean).max() > 1e-4
    gain = [np.sum(clean[..., c] * scaled[..., c]) / np.sum(clean[..., c] ** 2) for c in range(3)]
    for c in range(3):
        assert NOISE_GAIN_RANGE[0] <= gain[c] <= NOISE_GAIN_RANGE[1]
        np.testing.assert_allclose(scaled[..., c], gain[c] * clean[..., c], rtol=0, atol=1e-12 * np.abs(clean).max())
    assert min(gain) < 1.0


def test_tracker_response_on_moved_scatterers_renders_the_data_again(tmp_path, synthesized):
    """Moved-scatterer data: the response to the truth's motion rendered with the data's own
    speckle seed is the data's tracked flow (the same scatterers, decorrelation and receiver
    noise draws; only the uint16 storage differs: measured 1.2e-4 of the largest motion); with
    the response's own seed (the default) it is another realization, whose difference from the
    data is the random part of the tracker's error (measured: 1.5x the largest motion at the
    worst node of this 3-frame case, on a grid of 1 mm voxels)."""
    import h5py
    from liverinv.imaging.response import tracker_response
    from liverinv.mesh import TetMesh, read_mesh

    bundle, truth = synthesized
    scattered = tmp_path / "scatter.h5"
    study = tmp_path / "s.yaml"
    study.write_text(STUDY.replace("  seed: 2\n", "  seed: 2\n  mode: scatter\n  noise_db: -25\n  decorrelation: 0.01\n"))
    assert "noise_db" in study.read_text()
    a = _parser().parse_args(["synthesize", str(study), "--out", str(scattered)])
    assert a.func(a) == 0
    flow = tmp_path / "f.nc"
    a = _parser().parse_args(["track", str(scattered), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    f, t = xr.load_dataset(flow), xr.load_dataset(truth)
    with open_bundle(scattered) as b:
        im = json.loads(b.attrs["imaging"])
        assert im["mode"] == "scatter"
        u = t.u.interp(time=b.time_s).values
        mesh, truth_mesh = read_mesh(MESH, required=()), TetMesh(t.X.values, t.cells.values)
        same = tracker_response(b, f, mesh, truth_mesh, u, seed=im["seed"])
        other = tracker_response(b, f, mesh, truth_mesh, u)
    tracked = f.u_of.values
    scale = np.abs(tracked).max()
    assert scale > 1e-5
    assert np.abs(same - tracked).max() < 1e-3 * scale
    assert np.abs(other - tracked).max() > 0.1 * scale


def test_objectives_on_the_same_files_share_their_observation_operator(tmp_path, synthesized):
    """`objective_from_files` keeps the latest operators (discover builds an objective per
    trial, 8-10 s each on the coarse benchmark mesh): the same files give the same operator
    object, a rewritten flow a new one, and both predict the same tracked motion."""
    from liverinv.identify import setup
    bundle, _ = synthesized
    flow = tmp_path / "f.nc"
    a = _parser().parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    setup._OBSERVATIONS.clear()
    first, _ = setup.objective_from_files(bundle, flow, MESH, "elastic")
    again, _ = setup.objective_from_files(bundle, flow, MESH, "SR")
    assert again.observation is first.observation and len(setup._OBSERVATIONS) == 1
    u = np.random.default_rng(0).standard_normal((2, first.forward.mesh.n_nodes, 3))
    flow.write_bytes(flow.read_bytes())                  # the same content, a new file
    os.utime(flow, ns=(1, 1))
    renewed, _ = setup.objective_from_files(bundle, flow, MESH, "elastic")
    assert renewed.observation is not first.observation
    np.testing.assert_allclose(renewed.observation(u), first.observation(u), rtol=1e-12, atol=1e-15)
    assert len(setup._OBSERVATIONS) == setup.OBSERVATIONS_KEPT == 2


def test_a_diagnosis_of_warped_volumes_is_held_to_a_stricter_level_with_its_caveat(tmp_path, synthesized):
    """On warped volumes (synthesize's default) the tracker's error is systematic and passed for
    an effect at p 0.005 on each of 3 nulls: their diagnoses need p < 1e-4 and carry the caveat;
    a bundle whose imaging record says otherwise, or that has none (measured data), keeps the
    usual level and no caveat. Only warped data have an inclusion checked against the
    tracker's response (`score.confirm_by_tracker_response`)."""
    import h5py
    from liverinv.diagnose.files import WARPED_ALPHA, WARPED_CAVEAT, imaging_calibration
    from liverinv.diagnose.score import ALPHA
    bundle, _ = synthesized
    assert imaging_calibration(bundle) == dict(alpha=WARPED_ALPHA, caveat=WARPED_CAVEAT, confirm_geometric=True,
                                               correct_final=True)
    assert WARPED_ALPHA == 1e-4 < ALPHA and "3 warped elastic null" in WARPED_CAVEAT
    other = tmp_path / "b.h5"
    other.write_bytes(bundle.read_bytes())
    with h5py.File(other, "a") as f:
        f.attrs["imaging"] = json.dumps({**json.loads(f.attrs["imaging"]), "mode": "scatter"})
    assert imaging_calibration(other) == dict(alpha=ALPHA, caveat="", confirm_geometric=False, correct_final=False)
    with h5py.File(other, "a") as f:
        del f.attrs["imaging"]
    assert imaging_calibration(other) == dict(alpha=ALPHA, caveat="", confirm_geometric=False, correct_final=False)


def test_fit_continues_on_the_tracker_response(tmp_path, synthesized):
    """`fit --tracker-response`: the first stage's optimum and the tracker's error are recorded,
    the fit goes on from that optimum on the corrected motion; refused without the operator."""
    bundle, _ = synthesized
    flow, out = tmp_path / "f.nc", tmp_path / "fit.nc"
    p = _parser()
    a = p.parse_args(["track", str(bundle), "--mesh", str(MESH), "--out", str(flow)])
    assert a.func(a) == 0
    base = ["fit", "--bundle", str(bundle), "--flow", str(flow), "--mesh", str(MESH), "--law", "elastic",
            "--start", "C1=150", "--fixed", "D1=1.5e-3", "--max-evaluations", "3", "--tracker-response",
            "--out", str(out)]
    a = p.parse_args(base + ["--checkpoint", str(tmp_path / "ck")])
    assert a.func(a) == 0
    ds = xr.load_dataset(out)
    rec = json.loads(ds.attrs["tracker_response"])
    assert set(rec["first_stage"]) == {"C1", "C2"} and rec["first_stage_solves"] >= 3
    assert 0 < rec["error_rms_m"] < 1e-4
    assert ds.history_params.sel(param="C1").values[0] == pytest.approx(rec["first_stage"]["C1"], rel=1e-12)
    assert (tmp_path / "ck" / "tracker-response" / "evaluations.jsonl").is_file()
    # the diagnosis's check of an inclusion on warped data computes the same error at those parameters
    from liverinv.commands.diagnose import objective_of_fit
    from liverinv.diagnose.files import tracker_error_for
    obj, _, _ = objective_of_fit(out, bundle, flow, MESH)
    err = tracker_error_for(bundle, flow, MESH)(obj, rec["first_stage"])
    assert err.shape == obj.data.u_of.shape
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(rec["error_rms_m"], rel=1e-6)
    with pytest.raises(UserError, match="observation tracker"):
        a = p.parse_args(base + ["--observation", "nodes"])
        a.func(a)
