"""Registration with regularization springs (seed paper Eqs. 1-3) on a small mesh: exact
motion is reproduced, noisy weakly tracked motion is corrected by the mechanics, the
springs' tangent matches their residual, and Phi is Eq. 3."""

import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

from liverinv.forward import ForwardModel
from liverinv.identify.register import (Springs, nodal_stiffness, normalized_energy, register,
                                        spring_dofs)
from liverinv.loading import ramp_history

TRUTH = dict(C1=200.0, C2=5000.0, D1=1.5e-3)


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """Truth run on a 630-node mesh, 3 mm in and out, 7 frames."""
    from liverinv.meshgen import generate_indentation_mesh
    path = generate_indentation_mesh(tmp_path_factory.mktemp("mesh") / "tiny.msh", h_far=0.03, h_rim=0.004)
    fm = ForwardModel(path)
    run = fm.run("elastic", TRUTH, ramp_history(3e-3, 2e-3, frames=7, unload=True))
    return fm, run


def noisy_tracking(run, rng):
    """Frame-to-frame motion with noise whose standard deviation grows as the per-node
    confidence falls (c = U^2: many nodes near zero)."""
    u = run.u.values
    du = np.diff(u, axis=0)
    c_node = rng.uniform(0, 1, u.shape[1]) ** 2
    c = np.broadcast_to(c_node[None, :, None], du.shape).copy()
    scale = 0.1 * np.abs(du).max()
    sigma = scale * (1.02 - c)
    return du + sigma * rng.standard_normal(du.shape), c, c_node


def test_exact_motion_with_full_confidence_is_reproduced(problem):
    fm, run = problem
    u, t = run.u.values, run.time.values
    du = np.diff(u, axis=0)
    reg = register(fm, "elastic", TRUTH, t, du, np.ones_like(du), t, run.indenter_depth.values)
    assert np.abs(reg.u_fem - u).max() < 1e-6 * np.abs(u).max()      # measured 1e-7
    assert reg.phi_total < 1e-12 * np.sum(u ** 2)
    np.testing.assert_allclose(reg.force, run.indenter_force.values, rtol=1e-5, atol=1e-7)


@pytest.fixture(scope="module")
def noisy(problem):
    fm, run = problem
    t = run.time.values
    u_of, c, c_node = noisy_tracking(run, np.random.default_rng(1234))
    return register(fm, "elastic", TRUTH, t, u_of, c, t, run.indenter_depth.values, beta=1.0), c_node


def test_registration_corrects_weakly_tracked_nodes(problem, noisy):
    """Measured (beta 1): RMS error at nodes with c < 0.2 falls 6x (raw 1.7e-4 m ->
    2.8e-5 m); at c > 0.8 it also falls (2.4e-5 -> 1.6e-5 m)."""
    fm, run = problem
    reg, c_node = noisy
    u = run.u.values
    free = spring_dofs(fm.model("elastic", TRUTH)) >= 0

    def rms(e, nodes):
        m = np.broadcast_to((nodes[:, None] & free)[None], e.shape)
        return np.sqrt(np.mean(e[m] ** 2))

    low, high = c_node < 0.2, c_node > 0.8
    raw_low, reg_low = rms(reg.u_of - u, low), rms(reg.u_fem - u, low)
    assert low.sum() > 100 and reg_low < raw_low / 3, (raw_low, reg_low)
    assert rms(reg.u_fem - u, high) < rms(reg.u_of - u, high)


def test_phi_is_eq3_and_energy_is_eq1(noisy):
    reg, _ = noisy
    beta = reg.beta
    d = reg.u_of - reg.u_fem
    np.testing.assert_allclose(reg.phi, np.sum(reg.c * d ** 2, axis=(1, 2)), rtol=1e-12)
    np.testing.assert_allclose(reg.phi, normalized_energy(reg.u_of, reg.u_fem, reg.c), rtol=1e-12)
    k = beta * reg.K * reg.c                                              # Eq. 2
    U_S = 0.5 * np.sum(k * d ** 2, axis=(1, 2))                           # Eq. 1
    np.testing.assert_allclose(reg.energy, U_S, rtol=1e-10, atol=1e-30)
    on = reg.K > 0
    eq3 = np.sum(np.where(on, 0.5 * k * d ** 2 / (0.5 * beta * np.where(on, reg.K, 1.0)), 0.0), axis=(1, 2))
    np.testing.assert_allclose(reg.phi, eq3, rtol=1e-10)
    assert reg.phi[0] == 0 and np.all(reg.phi[1:] > 0)
    # constrained dofs carry no spring: zero stiffness and zero confidence
    assert np.all(reg.c[:, ~on] == 0) and np.all(reg.K[~on] == 0) and on.sum() < on.size


def test_spring_tangent_matches_the_residual(problem, rng):
    fm, _ = problem
    model = fm.model("elastic", TRUTH)
    n = fm.mesh.n_nodes
    K0 = nodal_stiffness(model)
    targets = 1e-4 * rng.standard_normal((2, n, 3))
    stiffness = K0 * rng.uniform(0, 2, (2, n, 3))
    springs = Springs(model, [0.0, 1.0], targets, stiffness)
    springs.set_time(0.25)  # between the frames: interpolated targets and stiffnesses
    q = 1e-4 * rng.standard_normal(model.n_red)
    state = model.new_state()
    ev, ev0 = springs.evaluate(q, 0.1, state), model.evaluate(q, 0.1, state)
    dofs = spring_dofs(model)
    on = dofs >= 0
    k = (0.75 * stiffness[0] + 0.25 * stiffness[1])[on]
    d_r = ev.r - ev0.r
    np.testing.assert_allclose(d_r[dofs[on]], k * (q[dofs[on]] - (0.75 * targets[0] + 0.25 * targets[1])[on]),
                               rtol=1e-12, atol=1e-20)
    dK = (ev.K - ev0.K).tocsr()
    dK.eliminate_zeros()
    assert dK.nnz == np.count_nonzero(k)
    np.testing.assert_allclose(dK.diagonal()[dofs[on]], k, rtol=1e-12)
    # central differences of the full residual against K dq
    dq = rng.standard_normal(model.n_red)
    dq *= 1e-8 / np.abs(dq).max()
    fd = (springs.evaluate(q + dq, 0.1, state, False).r - springs.evaluate(q - dq, 0.1, state, False).r) / 2
    assert np.linalg.norm(fd - ev.K @ dq) < 1e-6 * np.linalg.norm(fd)


def test_solver_sets_the_time_of_every_step(problem):
    fm, run = problem
    model = fm.model("elastic", TRUTH)
    n = fm.mesh.n_nodes
    t = run.time.values

    class Recorder(Springs):
        seen = []

        def set_time(self, tt):
            self.seen.append(tt)
            super().set_time(tt)

    from liverinv.fem.solver import solve_history
    s = Recorder(model, t, run.u.values, np.zeros((len(t), n, 3)))
    h = solve_history(s, t, run.indenter_depth.values)
    assert set(t[1:]) <= set(Recorder.seen)
    np.testing.assert_allclose(h.u, run.u.values, atol=1e-9)  # zero springs: the plain model


def test_register_command_writes_the_file_and_rejects_bad_input(problem, tmp_path):
    from liverinv.imaging.bundle import Indenter, write_bundle
    from liverinv.imaging.grid import ImageGrid
    fm, run = problem
    t = run.time.values[:3]                      # the first three frames suffice here
    du = np.diff(run.u.values[:3], axis=0)
    grid = ImageGrid((4, 4, 4), (1e-3,) * 3, (0.0,) * 3)
    bundle = write_bundle(tmp_path / "b.h5", np.zeros((len(t), 4, 4, 4)), grid, t,
                          Indenter(run.time.values, run.indenter_depth.values, run.indenter_force.values))
    flow = tmp_path / "f.nc"
    xr.Dataset({"u_of": (("frame", "node", "component"), du),
                "c_of": (("frame", "node", "component"), np.full(du.shape, 0.5)),
                "frame_time": (("volume",), t), "X": (("node", "component"), fm.mesh.points)}
               ).to_netcdf(flow, engine="h5netcdf")
    out = tmp_path / "reg.nc"
    cmd = [sys.executable, "-m", "liverinv.cli", "register", "--bundle", str(bundle), "--flow", str(flow),
           "--mesh", str(fm.mesh.path), "--law", "elastic", "--param", "C1=200", "--param", "C2=5000",
           "--param", "D1=1.5e-3"]
    p = subprocess.run(cmd + ["--out", str(out)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    ds = xr.open_dataset(out, engine="h5netcdf")
    for name in ("u_fem", "u_of", "c"):
        assert ds[name].dims == ("time", "node", "component") and ds[name].shape == (3, *run.u.shape[1:])
    assert ds.u_fem.attrs["units"] == "m" and ds.phi.attrs["units"] == "m^2"
    assert ds.phi.dims == ("time",) and float(ds.phi_total) == pytest.approx(float(ds.phi.sum()))
    assert float(ds.beta) == 1.0 and ds.attrs["law"] == "elastic" and "liverinv_version" in ds.attrs
    assert np.abs(ds.u_fem.values - run.u.values[:3]).max() < 1e-8
    for bad, message in ((["--beta", "-1"], "--beta must be a positive number"),
                         (["--law", "nope"], "unknown law 'nope'"),
                         (["--mesh", str(tmp_path / "none.msh")], "none.msh")):
        bad_out = tmp_path / "bad.nc"
        p = subprocess.run(cmd + bad + ["--out", str(bad_out)], capture_output=True, text=True)
        assert p.returncode == 2 and message in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and not bad_out.exists()
