"""Parameter sensitivities of a force-controlled history (direct differentiation, with the
history state carried along) against central differences of whole solves."""

import numpy as np
import pytest

from liverinv.fem.sensitivity import Sensitivity
from liverinv.fem.solver import NewtonOptions, solve_history
from liverinv.forward import ForwardModel
from liverinv.loading import ramp_history

LAWS = {"PE": dict(C1=200.0, C2=5000.0, D1=1.5e-3, kappa=1e-7),           # history: J_n
        "SR": dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.5),  # history: Prony integrals
        "PSR": dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.5, kappa=1e-7)}  # both


@pytest.fixture(scope="module")
def fm(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    return ForwardModel(generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004))


@pytest.mark.parametrize("law", sorted(LAWS))
def test_sensitivities_match_central_differences_of_solves(fm, law):
    """d u / d log10(theta) at every frame of a load-unload force history. Measured on the
    tiny mesh: 2e-6 to 3e-5 relative to the largest value."""
    P, names = LAWS[law], list(LAWS[law])
    hist = ramp_history(5e-3, 2e-3, frames=9, unload=True)
    f = solve_history(fm.model(law, P), hist.time, hist.value, "displacement").force

    def moved(i, h):
        return {**P, names[i]: P[names[i]] * 10 ** h}

    fd = []
    for i in range(len(names)):
        hp = solve_history(fm.model(law, moved(i, 1e-4)), hist.time, f, "force")
        hm = solve_history(fm.model(law, moved(i, -1e-4)), hist.time, f, "force")
        fd.append(((hp.u - hm.u) / 2e-4, (hp.depth - hm.depth) / 2e-4))
    model = fm.model(law, P)
    eps = 1e-6
    sens = Sensitivity([model.with_params(fm.element_params(law, moved(i, eps))) for i in range(len(names))], eps)
    h = solve_history(model, hist.time, f, "force", sensitivity=sens)
    # the same solution, to the solver's tolerance (the sensitivities refactorize)
    u_plain = solve_history(fm.model(law, P), hist.time, f, "force").u
    assert np.abs(h.u - u_plain).max() < 1e-6 * np.abs(u_plain).max()
    for i, (du, dd) in enumerate(fd):
        assert np.abs(du).max() > 1e-4
        assert np.abs(h.du[:, i] - du).max() < 1e-4 * np.abs(du).max(), names[i]
        assert np.abs(h.ddepth[:, i] - dd).max() < 1e-4 * np.abs(dd).max(), names[i]


def test_biphasic_variant_keeps_the_pressure_scale(fm):
    m = fm.model("PE", LAWS["PE"])
    v = m.with_params(fm.element_params("PE", {**LAWS["PE"], "C1": 400.0}))
    assert v.s == m.s and float(v._C1.mean()) == 400.0 and v.asm is m.asm


@pytest.mark.parametrize("method", ["pardiso", "superlu"])
def test_block_back_substitution(method):
    """Several right-hand sides at once (pardiso reads them column-major)."""
    import scipy.sparse as sp
    from liverinv.fem.linsolve import SparseSolver, backend
    if method == "pardiso" and backend() != "pardiso":
        pytest.skip("pypardiso not installed")
    A = (sp.random(50, 50, density=0.2, random_state=1) + 10 * sp.eye(50)).tocsr()
    B = np.random.default_rng(0).normal(size=(50, 4))
    lin = SparseSolver(method)
    lin.factorize(A)
    assert np.abs(A @ lin.solve(B) - B).max() < 1e-12
    assert np.abs(A @ lin.solve(B[:, 1]) - B[:, 1]).max() < 1e-12


@pytest.mark.parametrize("law", ["PE", "SR"])   # (PSR: its central differences above)
def test_force_sensitivities_under_displacement_control(fm, law):
    """d F / d log10(theta) of a depth-driven load-unload history (the noise-aware objective
    drives the model by the measured depth and fits the force) against central differences
    of whole solves."""
    P, names = LAWS[law], list(LAWS[law])
    hist = ramp_history(5e-3, 2e-3, frames=9, unload=True)

    def moved(i, h):
        return {**P, names[i]: P[names[i]] * 10 ** h}

    model = fm.model(law, P)
    eps = 1e-6
    sens = Sensitivity([model.with_params(fm.element_params(law, moved(i, eps))) for i in range(len(names))], eps)
    tight = NewtonOptions(rtol=1e-10)
    h = solve_history(model, hist.time, hist.value, "displacement", tight, sensitivity=sens)
    for i in range(len(names)):
        # tight solves: at rtol 1e-6 the difference quotient itself is off by up to 1e-2
        hp = solve_history(fm.model(law, moved(i, 1e-4)), hist.time, hist.value, "displacement", tight)
        hm = solve_history(fm.model(law, moved(i, -1e-4)), hist.time, hist.value, "displacement", tight)
        dF = (hp.force - hm.force) / 2e-4
        du = (hp.u - hm.u) / 2e-4
        assert np.abs(dF).max() > 1e-4
        assert np.abs(h.dforce[:, i] - dF).max() < 1e-4 * np.abs(dF).max(), names[i]
        # measured on the tiny mesh: dF 1.1e-6 to 1.5e-6, du 1.2e-6 to 8.8e-6 of the largest value
        assert np.abs(h.du[:, i] - du).max() < 1e-4 * np.abs(du).max(), names[i]
        assert np.all(h.ddepth[:, i] == 0.0)


def test_residual_change_on_a_sphere_is_the_whole_residual_difference(fm):
    """The cheap residual change of an inclusion variant (C1, C2 scaled on a sphere's
    elements) equals the difference of two whole residual evaluations of an elastic model,
    and is declined for a viscous one."""
    from liverinv.forward import Inclusion
    P = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
    model = fm.model("elastic", P)
    top = float(fm.mesh.points[:, 2].max())
    inside = Inclusion((0.0, 0.0, top - 0.008), 0.005, {}).elements(fm.mesh)
    assert 0 < inside.sum() < fm.mesh.n_elements // 4
    scale = np.where(inside, 1.3, 1.0)
    other = model.with_params({**P, "C1": 200.0 * scale, "C2": 5000.0 * scale})
    hist = ramp_history(4e-3, 2e-3, frames=3)
    states = []
    solve_history(model, hist.time, hist.value, "displacement", record=lambda k, q, ev: states.append(q.copy()))
    q, state = states[-1], model.new_state()     # 4 mm deep
    whole = other.evaluate(q, 0.1, state, tangent=False).r - model.evaluate(q, 0.1, state, tangent=False).r
    cheap = model.residual_change(other, q)
    assert np.abs(whole).max() > 0
    assert np.abs(cheap - whole).max() < 1e-10 * np.abs(whole).max()
    viscous = fm.model("SR", {**P, "g1": 0.4, "tau_g1": 0.5})
    assert viscous.residual_change(viscous.with_params({**viscous.params, "C1": 200.0 * scale}), q) is None
