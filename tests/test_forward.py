"""The forward indentation model against analytic references and its own invariants."""

import numpy as np
import pytest

from conftest import BENCH_ELASTIC, FINE
from liverinv.fem.solver import NewtonOptions, solve_history
from liverinv.fem.space import Space
from liverinv.loading import ramp_history


def test_mesh_volume(coarse_mesh):
    """Isoparametric tet10 volume of the benchmark cylinder equals pi R^2 H."""
    vol = Space(coarse_mesh).volume()
    assert vol == pytest.approx(np.pi * 0.05**2 * 0.0303, rel=1e-4)


def test_patch_test_affine_field(coarse_mesh):
    """An affine displacement gives uniform stress: zero force at every interior node, and
    the top-face forces add up to the Cauchy traction on the deformed area."""
    from liverinv.fem.indentation import Indentation
    from liverinv.laws import get_law

    space = Space(coarse_mesh)
    model = Indentation(space, get_law("elastic").resolve(BENCH_ELASTIC))
    Hgrad = np.array([[0.02, 0.01, 0.0], [-0.01, -0.03, 0.005], [0.0, 0.004, -0.05]])
    u = coarse_mesh.points @ Hgrad.T
    F = space.deformation_gradient(u)
    assert np.allclose(F, np.eye(3) + Hgrad, atol=1e-12)
    from liverinv.fem.material import hyperelastic_split
    S_iso, S_vol, *_ = hyperelastic_split(F, model._C1, model._C2, model._D1, 0.0, tangent=False)
    P = F @ (S_iso + S_vol)
    fe = np.einsum("eqiJ,eqaJ->eai", P * space.dV[..., None, None], space.dNdX).reshape(-1, 30)
    f = model.asm.full_vector(fe, space.n_dofs).reshape(-1, 3)
    boundary = np.unique(np.concatenate([coarse_mesh.nodes(g) for g in ("bottom", "side", "top_free", "footprint")]))
    interior = np.setdiff1d(np.arange(coarse_mesh.n_nodes), boundary)
    # elements whose mid-nodes sit off the edge midpoints (curved, on the side) are not
    # integrated exactly by the 4-point rule; the patch test holds exactly elsewhere
    X, c = coarse_mesh.points, coarse_mesh.cells
    edges = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])
    off = np.linalg.norm(X[c[:, 4:]] - 0.5 * (X[c[:, edges[:, 0]]] + X[c[:, edges[:, 1]]]), axis=-1)
    curved_nodes = np.unique(c[off.max(axis=1) > 1e-12])
    straight = np.setdiff1d(interior, curved_nodes)
    assert len(straight) > 0.5 * len(interior)
    scale = np.abs(f[boundary]).max()
    assert np.abs(f[straight]).max() < 1e-12 * scale
    assert np.abs(f[interior]).max() < 1e-4 * scale
    # top face: total force = P N A0 (Nanson), N = e_z, A0 = pi R^2
    top = np.unique(np.concatenate([coarse_mesh.nodes("top_free"), coarse_mesh.nodes("footprint")]))
    expected = P[0, 0] @ np.array([0, 0, 1.0]) * np.pi * 0.05**2
    # the top nodes' force includes the side rim nodes' share; compare z-force on the top
    # face against the bottom face (equal and opposite) and the analytic value within the
    # polygonal-area error of the rim
    bottom = coarse_mesh.nodes("bottom")
    assert f[top, 2].sum() == pytest.approx(-f[bottom, 2].sum(), rel=1e-9)
    assert f[top, 2].sum() == pytest.approx(expected[2], rel=2e-3)


def _small_strain_stiffness(mesh_path):
    from liverinv.forward import ForwardModel

    d = 1e-6
    model = ForwardModel(mesh_path).model("elastic", BENCH_ELASTIC)
    return solve_history(model, [0.0, 1.0], [0.0, d], "displacement").force[-1] / d


def test_small_strain_punch_stiffness_converges_to_reference(tmp_path):
    """F/d at small depth against the converged axisymmetric reference 18.32 N/m
    (benchmark README). Analytic cross-check: Hayes et al. (1972) give
    2 a E / (1 - nu^2) kappa with kappa = 1.219 for a/H = 0.198, nu = 0.364 (18.38 N/m for
    a laterally unbounded layer; factor as quoted in shared/benchmark/README.md).
    The punch rim is singular, so conforming tet10 converge slowly from above: measured
    19.07 (benchmark fine mesh, 4589 nodes), 18.66 (15468 nodes), 18.47 N/m (46206 nodes)."""
    from liverinv.meshgen import generate_indentation_mesh

    mu, K = 2 * 200.0, 2 / 1.5e-3
    E = 9 * K * mu / (3 * K + mu)
    nu = (3 * K - 2 * mu) / (2 * (3 * K + mu))
    assert 2 * 0.006 * E / (1 - nu**2) * 1.219 == pytest.approx(18.38, abs=0.01)

    path = generate_indentation_mesh(tmp_path / "rim06.msh", h_far=0.008, h_rim=0.0006)
    k_refined = _small_strain_stiffness(path)
    assert k_refined == pytest.approx(18.32, rel=0.03)
    if FINE.exists():
        k_fine = _small_strain_stiffness(FINE)
        assert 18.32 < k_refined < k_fine < 18.32 * 1.06


def test_load_unload_elastic_returns_to_zero(coarse_forward):
    hist = ramp_history(4e-3, 2e-3, steps=8, unload=True)
    ds = coarse_forward.run("elastic", BENCH_ELASTIC, hist)
    F = ds.indenter_force.values
    assert F.max() > 0.05
    assert abs(F[-1]) < 1e-6 * F.max()
    assert np.abs(ds.u.values[-1]).max() < 1e-9
    # elastic: loading and unloading branches coincide (frame k and 2n - k)
    n = 8
    assert np.allclose(F[1:n], F[2 * n - 1:n:-1], rtol=1e-5, atol=1e-7)


def test_benchmark_force_at_4_6_mm_matches_peer_codes(coarse_forward):
    """46 steps to 4.6 mm on the coarse mesh: felupe 0.1985 N, FEBio (4-point rule) 0.198546 N."""
    hist = ramp_history(4.6e-3, 2e-3, steps=23, unload=False)
    ds = coarse_forward.run("elastic", BENCH_ELASTIC, hist)
    assert ds.indenter_force.values[-1] == pytest.approx(0.198546, rel=1e-4)


def test_force_control_reproduces_displacement_run(coarse_forward):
    from liverinv.forward import force_history_of

    params = dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.06)
    hist = ramp_history(6e-3, 2e-3, steps=12, unload=True)
    ds_d = coarse_forward.run("SR", params, hist)
    ds_f = coarse_forward.run("SR", params, force_history_of(ds_d))
    d_ref = ds_d.indenter_depth.values
    assert np.abs(ds_f.indenter_depth.values - d_ref).max() < 1e-5 * d_ref.max()
    assert np.abs(ds_f.u.values - ds_d.u.values).max() < 1e-5 * d_ref.max()


def test_region_parameters_stiffen_the_response(coarse_forward):
    """Per-element parameters: a stiffer copy of the whole region doubles C1 and C2."""
    hist = ramp_history(2e-3, 2e-3, steps=2, unload=False)
    region = int(coarse_forward.mesh.cell_region[0])
    soft = coarse_forward.run("elastic", BENCH_ELASTIC, hist)
    stiff = coarse_forward.run("elastic", BENCH_ELASTIC, hist,
                               region_params={region: dict(C1=400.0, C2=10000.0, D1=0.75e-3)})
    # doubling every modulus doubles the force exactly (the law is homogeneous of degree 1)
    assert stiff.indenter_force.values[-1] == pytest.approx(2 * soft.indenter_force.values[-1], rel=1e-6)


def test_bonded_punch_is_stiffer_and_sliding_support_softer(coarse_forward):
    from liverinv.forward import ForwardModel
    hist = ramp_history(1e-3, 2e-3, steps=1, unload=False)
    base = coarse_forward.run("elastic", BENCH_ELASTIC, hist).indenter_force.values[-1]
    bonded = ForwardModel(coarse_forward.mesh, punch="bonded").run("elastic", BENCH_ELASTIC, hist)
    sliding = ForwardModel(coarse_forward.mesh, support="sliding").run("elastic", BENCH_ELASTIC, hist)
    assert bonded.indenter_force.values[-1] > base * 1.01
    assert sliding.indenter_force.values[-1] < base * 0.99
    assert np.allclose(bonded.u.values[-1][coarse_forward.mesh.nodes("footprint"), :2], 0)


def test_full_newton_and_bfgs_agree(coarse_forward):
    hist = ramp_history(3e-3, 2e-3, steps=3, unload=False)
    m = coarse_forward.model("elastic", BENCH_ELASTIC)
    a = solve_history(m, hist.time, hist.value, options=NewtonOptions(method="full"))
    b = solve_history(m, hist.time, hist.value, options=NewtonOptions(method="bfgs"))
    assert np.allclose(a.force, b.force, rtol=1e-5)
    assert b.timing["factorizations"] < a.timing["factorizations"]


def test_bad_histories_are_rejected(coarse_forward):
    m = coarse_forward.model("elastic", BENCH_ELASTIC)
    with pytest.raises(ValueError, match="increase"):
        solve_history(m, [0.0, 1.0, 1.0], [0.0, 1e-3, 2e-3])
    with pytest.raises(ValueError, match="zero load"):
        solve_history(m, [0.0, 1.0], [1e-3, 2e-3])
    with pytest.raises(ValueError, match="control"):
        solve_history(m, [0.0, 1.0], [0.0, 1e-3], control="velocity")


def test_kept_factorization_gives_displacement_sensitivity(coarse_forward):
    """du/dC1 from the kept factorized tangent (K du = -dr/dC1) equals the central
    difference of two converged solutions: the tangent the identification will reuse."""
    from liverinv.laws import get_law
    from liverinv.fem.indentation import Indentation

    law = get_law("elastic")
    hist = ramp_history(3e-3, 2e-3, steps=2, unload=False)
    opts = NewtonOptions(rtol=1e-10, keep_factorization=True)
    m = coarse_forward.model("elastic", BENCH_ELASTIC)
    h = solve_history(m, hist.time, hist.value, options=opts)
    dC = 1e-3 * BENCH_ELASTIC["C1"]
    shifted = Indentation(coarse_forward.space, law.resolve(dict(BENCH_ELASTIC, C1=BENCH_ELASTIC["C1"] + dC)))
    st = m.new_state()
    dr = (shifted.evaluate(h.q, 1.0, st, tangent=False).r - m.evaluate(h.q, 1.0, st, tangent=False).r) / dC
    dr[m.punch_index] = 0.0
    du = -h.linear_solver.solve(dr)
    u_pm = []
    for sgn in (1, -1):
        mm = coarse_forward.model("elastic", dict(BENCH_ELASTIC, C1=BENCH_ELASTIC["C1"] + sgn * dC))
        u_pm.append(solve_history(mm, hist.time, hist.value, options=NewtonOptions(rtol=1e-10)).q)
    fd = (u_pm[0] - u_pm[1]) / (2 * dC)
    assert np.linalg.norm(du - fd) < 1e-4 * np.linalg.norm(fd)


@pytest.mark.parametrize("law, params, options", [
    ("elastic", BENCH_ELASTIC, {}),
    ("SBR", dict(BENCH_ELASTIC, g1=0.4, tau_g1=0.3, k1=0.3, tau_k1=0.5, D2=1e-2), {}),
    ("elastic+punch_friction+bottom_slip", dict(BENCH_ELASTIC, k_punch=1e7, c_bottom=1e-5), {}),
])
def test_the_tangent_is_symmetric_and_its_symmetric_factorization_solves_like_the_general_one(
        coarse_mesh, law, params, options):
    """`Indentation.symmetric_tangent` lets the solver factorize the upper triangle (PARDISO
    mtype -2): the tangent at a deformed, relaxing state is symmetric under force and
    displacement control, and the symmetric and general factorizations give one solution."""
    from liverinv.fem.linsolve import SparseSolver, backend
    from liverinv.forward import ForwardModel
    fm = ForwardModel(coarse_mesh, **options)
    m = fm.model(law, params)
    assert m.symmetric_tangent
    hist = ramp_history(3e-3, 2e-3, steps=3, unload=False)
    h = solve_history(m, hist.time, hist.value)
    rng = np.random.default_rng(5)
    b = rng.standard_normal((m.n_red, 3))
    for control in ("force", "displacement"):
        K = m.evaluate(h.q, 0.5, h.state, tangent=True).K.tocsr()
        if control == "displacement":
            K = m.fix_punch(K)
        assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
        if backend() != "pardiso":
            continue
        sym, gen = SparseSolver(symmetric=True), SparseSolver()
        sym.factorize(K)
        gen.factorize(K)
        x_sym, x_gen = sym.solve(b), gen.solve(b)
        assert np.abs(K @ x_sym - b).max() < 1e-9 * np.abs(b).max()
        assert np.abs(x_sym - x_gen).max() <= 1e-8 * np.abs(x_gen).max()
