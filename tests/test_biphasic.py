"""The biphasic (poroelastic) model against analytic solutions, its limits, FEBio, and its
own conservation laws."""

import numpy as np
import pytest

from liverinv.fem.biphasic import Biphasic, febio8_space, pressure_shape
from liverinv.fem.indentation import Indentation
from liverinv.fem.solver import NewtonOptions, solve_history
from liverinv.fem.space import Space
from liverinv.mesh import TetMesh

SOLID = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
PE = dict(SOLID, kappa=1e-7)
_FACES = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]
_MID = {(0, 1): 4, (1, 2): 5, (0, 2): 6, (0, 3): 7, (1, 3): 8, (2, 3): 9}


def column_mesh(width, height, nxy, nz):
    """Structured tet10 mesh of [0, w]^2 x [0, h] (6 Kuhn tets per cell) with the benchmark
    groups: `bottom` (z = 0), `footprint` (the whole top), `side`, and an empty `top_free`."""
    ax = [np.linspace(0, width, nxy + 1)] * 2 + [np.linspace(0, height, nz + 1)]
    shape = (nxy + 1, nxy + 1, nz + 1)
    pts = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(pts.shape[0]).reshape(shape)
    c = np.stack(np.meshgrid(np.arange(nxy), np.arange(nxy), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    v = [idx[c[:, 0] + (k & 1), c[:, 1] + (k >> 1 & 1), c[:, 2] + (k >> 2 & 1)] for k in range(8)]
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    tets = np.concatenate([np.stack([v[a], v[b], v[c_], v[d]], 1) for a, b, c_, d in kuhn])
    e = np.sort(np.stack([tets[:, list(k)] for k in _MID], 1), axis=2)
    uniq, inv = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True)
    cells = np.concatenate([tets, len(pts) + inv.reshape(-1, 6)], axis=1)
    pts = np.concatenate([pts, 0.5 * (pts[uniq[:, 0]] + pts[uniq[:, 1]])])
    tri = np.concatenate([cells[:, [a, b, d, _MID[(a, b)], _MID[(b, d)], _MID[(a, d)]]] for a, b, d in _FACES])
    key = np.sort(tri[:, :3], axis=1)
    _, first, count = np.unique(key, axis=0, return_index=True, return_counts=True)
    tri = tri[first[count == 1]]
    X = pts[tri[:, :3]]
    on = lambda k, val: np.all(np.isclose(X[..., k], val), axis=1)
    facets = {"bottom": tri[on(2, 0.0)], "footprint": tri[on(2, height)],
              "side": tri[on(0, 0) | on(0, width) | on(1, 0) | on(1, width)],
              "top_free": np.zeros((0, 6), dtype=np.int64)}
    return TetMesh(pts, cells, facets)


def test_pressure_shape_functions(coarse_mesh):
    """P1 functions built from the tet10 basis: partition of unity, exact on linear fields
    in straight-sided elements (curved ones on the cylinder's side map them isoparametrically)."""
    sp = Space(coarse_mesh)
    Np, dNp = pressure_shape(sp)
    assert np.allclose(Np.sum(1), 1.0) and np.abs(dNp.sum(2)).max() < 1e-8 * np.abs(dNp).max()
    X, c = coarse_mesh.points, coarse_mesh.cells
    edges = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])
    off = np.linalg.norm(X[c[:, 4:]] - 0.5 * (X[c[:, edges[:, 0]]] + X[c[:, edges[:, 1]]]), axis=-1)
    straight = off.max(axis=1) < 1e-12
    assert straight.mean() > 0.5
    g = np.array([3.0, -2.0, 5.0])
    f = X[sp.conn[:, :4]] @ g
    assert np.allclose(np.einsum("eqij,ei->eqj", dNp, f)[straight], g, rtol=1e-9, atol=1e-9)
    assert np.allclose((f @ Np.T)[straight], (sp.X_q @ g)[straight], atol=1e-12)


def test_tangent_matches_finite_differences():
    """Every block of the consistent tangent (incl. the non-symmetric permeation term)
    against central differences of the residual at a random state."""
    mesh = column_mesh(4e-3, 4e-3, 1, 2)
    m = Biphasic(Space(mesh), dict(PE, kappa=3e-7), side="free", drained=("side",))
    rng = np.random.default_rng(1)
    q = rng.normal(size=m.n_red) * 1e-4
    q[m.n_free + 1:] = rng.normal(size=m.n_red - m.n_free - 1) * 50.0 / m.s
    st = m.new_state()
    st.J_n = st.J_n * 0.98
    _check_tangent(m, q, st, rng)


def _check_tangent(m, q, st, rng):
    """Columns of the tangent at q against central differences of the residual."""
    K = m.evaluate(q, 0.3, st, True).K.toarray()
    for j in rng.choice(m.n_red, 25, replace=False).tolist() + [m.punch_index, m.n_red - 1]:
        h = 1e-7 * max(1e-4, abs(q[j]))
        dq = np.zeros(m.n_red)
        dq[j] = h
        fd = (m.evaluate(q + dq, 0.3, st, False).r - m.evaluate(q - dq, 0.3, st, False).r) / (2 * h)
        assert np.allclose(K[:, j], fd, rtol=1e-5, atol=1e-6 * np.abs(K).max()), j


def test_viscous_skeleton_tangent_matches_finite_differences():
    """The same with a QLV skeleton (shear and bulk Prony terms) and a history state."""
    mesh = column_mesh(4e-3, 4e-3, 1, 2)
    m = Biphasic(Space(mesh), dict(PE, kappa=3e-7, g1=0.4, tau_g1=0.2, k1=0.3, tau_k1=0.5), side="free",
                 drained=("side",))
    rng = np.random.default_rng(2)
    q = rng.normal(size=m.n_red) * 1e-4
    q[m.n_free + 1:] = rng.normal(size=m.n_red - m.n_free - 1) * 50.0 / m.s
    st = m.state_after(m.new_state(), 0.5 * q, 0.1)          # a history with nonzero Prony integrals
    assert np.abs(st.H_iso).max() > 0
    _check_tangent(m, q, st, rng)


def _terzaghi_run(nz=20):
    H, W = 0.01, 2e-3
    mesh = column_mesh(W, H, 1, nz)
    kappa, mu, Kb = 1e-7, 2 * PE["C1"], 2 / PE["D1"]
    HA = Kb + 4.0 / 3.0 * mu
    cv = kappa * HA
    Tc = H**2 / cv
    sigma = 1e-3 * HA
    m = Biphasic(Space(mesh), dict(C1=PE["C1"], C2=0.0, D1=PE["D1"], kappa=kappa),
                 side="confined", drained=("footprint",))
    Tv = [0.0, 1e-4]
    while Tv[-1] < 1.0:  # backward Euler: steps of 10% of the time, at most 0.01 Tc
        Tv.append(Tv[-1] + min(0.1 * Tv[-1], 0.01))
    times = Tc * np.array(Tv)
    base = np.nonzero(np.isclose(mesh.points[m.p_nodes, 2], 0.0))[0]
    p_base = np.zeros(len(times))
    def record(k, q, ev):
        p_base[k] = m.pressure(q)[base].mean()
    h = solve_history(m, times, np.r_[0.0, np.full(len(times) - 1, sigma * W**2)], "force",
                      NewtonOptions(method="full", f_floor=1e-12, rtol=1e-8), record)
    return times / Tc, h.depth / (sigma * H / HA), p_base / sigma


def _terzaghi_series(Tv, n=200):
    m = np.arange(n)[:, None]
    M = (2 * m + 1) * np.pi / 2
    decay = np.exp(-M**2 * np.asarray(Tv)[None])
    U = 1 - (2 / M**2 * decay).sum(0)
    p_base = (2 / M * np.sin(M) * decay).sum(0)
    return U, p_base


def test_terzaghi_consolidation():
    """Confined compression under a step load, drained at the loaded top only: settlement
    and pore pressure at the base follow Terzaghi's series (small strain) within 2%, and the
    first instant is undrained: the fluid carries the whole load."""
    Tv, U, pb = _terzaghi_run()
    U_ex, pb_ex = _terzaghi_series(Tv)
    assert pb[1] == pytest.approx(1.0, abs=0.01)
    assert abs(U[1]) < 0.02
    for T in (0.05, 0.1, 0.2, 0.5, 1.0):
        k = np.argmin(abs(Tv - T))
        assert U[k] == pytest.approx(U_ex[k], rel=0.02), (Tv[k], U[k], U_ex[k])
        if pb_ex[k] > 0.2:
            assert pb[k] == pytest.approx(pb_ex[k], rel=0.02, abs=0.005), (Tv[k], pb[k], pb_ex[k])


def test_undrained_unconfined_compression_is_incompressible():
    """A sealed block compressed 15% between frictionless plates in one step responds as the
    incompressible solid: J = 1, and the force is 2 W'(I1) (lambda^2 - 1/lambda) A0 / lambda."""
    L = 4e-3
    mesh = column_mesh(L, L, 2, 2)
    m = Biphasic(Space(mesh), dict(PE, kappa=1e-13), support="sliding", drained=())
    lam = 0.85
    h = solve_history(m, [0.0, 1e-3], [0.0, (1 - lam) * L], "displacement",
                      NewtonOptions(method="full", rtol=1e-10))
    ev = m.evaluate(h.q, 1e-3, m.new_state(), False)
    assert abs(ev.J - 1).max() < 1e-8
    I1 = lam**2 + 2 / lam
    Wp = SOLID["C1"] + 2 * SOLID["C2"] * (I1 - 3)
    F_exact = 2 * Wp * (lam**2 - 1 / lam) * L**2 / lam
    assert h.force[-1] == pytest.approx(-F_exact, rel=1e-7)
    p_exact = 2 * Wp * (1 / lam - I1 / 3)  # lateral faces traction free
    assert np.allclose(m.pressure(h.q), p_exact, rtol=1e-7)
    assert m.fluid_force(h.q) == pytest.approx(p_exact * L**2 / lam, rel=1e-7)


def test_drained_limit_is_elastic(coarse_mesh):
    """Very large permeability: the pore pressure vanishes and the force is the elastic one."""
    sp = Space(coarse_mesh)
    t, d = np.linspace(0, 1.0, 5), np.linspace(0, 2e-3, 5)
    he = solve_history(Indentation(sp, SOLID), t, d)
    m = Biphasic(sp, dict(SOLID, kappa=1e-2))
    hb = solve_history(m, t, d, options=NewtonOptions(method="full"))
    assert np.allclose(hb.force, he.force, rtol=1e-4, atol=1e-7)
    assert np.abs(m.pressure(hb.q)).max() < 1e-3 * 2 * SOLID["C1"]


def test_drained_limit_of_a_viscous_skeleton_is_qlv(coarse_mesh):
    """A QLV skeleton with very large permeability relaxes as the QLV solid (load, hold)."""
    sp = Space(coarse_mesh)
    t = np.r_[np.linspace(0, 0.5, 6), 0.6, 0.8, 1.2]
    d = np.minimum(t / 0.5, 1.0) * 2e-3
    qlv = dict(SOLID, g1=0.4, tau_g1=0.3, k1=0.3, tau_k1=0.2)
    he = solve_history(Indentation(sp, qlv), t, d)
    hb = solve_history(Biphasic(sp, dict(qlv, kappa=1e-2)), t, d, options=NewtonOptions(method="full"))
    assert he.force[-1] < 0.9 * he.force[5]                # it relaxes
    assert np.allclose(hb.force, he.force, rtol=1e-4, atol=1e-7)


def test_relaxation_at_fixed_depth_and_fluid_mass_balance(coarse_mesh):
    """Ramp to 2 mm at 2 mm/s, hold: the force relaxes monotonically to the drained
    (elastic) force; at every step the body's volume change equals the net fluid outflow
    through the draining faces (to solver tolerance)."""
    sp = Space(coarse_mesh)
    m = Biphasic(sp, PE)
    times = np.concatenate([np.linspace(0, 1.0, 6), 1.0 + np.geomspace(0.05, 40.0, 14)])
    depth = np.minimum(times, 1.0) * 2e-3
    outflow = np.zeros(len(times))
    dV = np.zeros(len(times))
    def record(k, q, ev):
        outflow[k] = m.drained_outflow(ev)
        dV[k] = m.volume_change(ev)
    h = solve_history(m, times, depth, options=NewtonOptions(rtol=1e-8), record=record)
    F_el = solve_history(Indentation(sp, SOLID), [0.0, 1.0], [0.0, 2e-3]).force[-1]
    hold = h.force[5:]
    assert np.all(np.diff(hold) < 0)
    assert hold[0] > 1.05 * F_el
    assert hold[-1] == pytest.approx(F_el, rel=3e-3)
    scale = np.abs(dV).max()
    assert np.abs(np.cumsum(outflow) + dV).max() < 1e-6 * scale
    assert dV[-1] < 0 and -dV[-1] > 0.5 * np.pi * 6e-3**2 * 2e-3  # fluid was squeezed out


def test_febio_poroelastic_reference(coarse_mesh):
    """Benchmark poroelastic truth, coarse mesh, dt 0.1 s: F(4.6 mm) = 0.220266 N (FEBio 4,
    Taylor-Hood, 8-point rule) to 1e-5; the engine's 4-point rule is within 1%."""
    t = np.linspace(0.0, 2.3, 24)
    h8 = solve_history(Biphasic(febio8_space(coarse_mesh), PE), t, 2e-3 * t)
    assert h8.force[-1] == pytest.approx(0.220266, rel=1e-5)
    h4 = solve_history(Biphasic(Space(coarse_mesh), PE), t, 2e-3 * t)
    assert h4.force[-1] == pytest.approx(0.220266, rel=0.01)


def test_forward_dataset_has_pressure_and_fluid_load_fraction(coarse_forward):
    """`ForwardModel.run` with law PE: p(time, pnode) at the corner nodes (0 on the draining
    faces) and the fluid load fraction, between 0 and 1 on loading."""
    from liverinv.loading import LoadHistory
    hist = LoadHistory("displacement", np.linspace(0, 0.5, 4), np.linspace(0, 1e-3, 4))
    ds = coarse_forward.run("PE", dict(kappa=1e-7), hist)
    assert ds.p.dims == ("time", "pnode") and ds.sizes["pnode"] == len(coarse_forward.mesh.corner_nodes())
    dry = np.isin(ds.pnode.values, coarse_forward.mesh.nodes("side"))
    assert np.all(ds.p.values[:, dry] == 0) and ds.p.values[-1].max() > 0
    f = ds.fluid_load_fraction.values
    assert np.isnan(f[0]) and np.all((f[1:] > 0) & (f[1:] < 1))
    assert ds.attrs["law"] == "PE" and "drained" in ds.attrs and ds.attrs["quadrature_points"] == 8


def test_force_control_reproduces_depth(coarse_mesh):
    """Driven by the force history of a displacement-controlled run (as in the Table 1 fits),
    the force-controlled biphasic model returns the same depth history."""
    m = Biphasic(Space(coarse_mesh), PE)
    t = np.linspace(0.0, 1.0, 6)  # 0.4 mm steps: a larger first step is cut (rim inverts)
    d = 2e-3 * np.minimum(t, 0.6)  # ramp to 1.2 mm, then hold (force relaxes)
    opts = NewtonOptions(rtol=1e-9)
    hd = solve_history(m, t, d, options=opts)
    hf = solve_history(m, t, hd.force, "force", opts)
    assert hd.cuts.sum() == 0 and hf.cuts.sum() == 0  # a cut step changes backward Euler's path
    assert np.abs(hf.depth - d).max() < 1e-6 * d.max()
