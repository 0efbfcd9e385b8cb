"""The batched, linearized sensitivity step of the indentation model (`fem.linearized`)
against the generic finite-difference step (`fem.sensitivity`, itself checked against
central differences of whole solves in test_sensitivity.py), along every kind of direction
the diagnosis uses, and its stress linearization against differences of the law."""

import numpy as np
import pytest

from liverinv.diagnose.effects import available_effects
from liverinv.fem.linearized import stress_operator
from liverinv.fem.material import hyperelastic_terms
from liverinv.fem.sensitivity import Sensitivity
from liverinv.fem.solver import NewtonOptions, solve_history
from liverinv.forward import ForwardModel
from liverinv.loading import ramp_history

E = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
BASES = {"elastic": E, "SR": dict(E, g1=0.4, tau_g1=0.5), "BR": dict(E, D2=1000.0, k1=0.5, tau_k1=0.3)}


@pytest.fixture(scope="module")
def fm(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    return ForwardModel(generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004))


def test_stress_operator_is_the_derivative_of_the_stresses():
    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.2 * rng.normal(size=(5, 4, 3, 3))
    dF = rng.normal(size=(5, 4, 3, 3))
    p = (200.0, 5000.0, 1.5e-3, 3e-4)
    _, _, t, _ = hyperelastic_terms(F, *p)
    dS = (stress_operator(t, F) @ dF.reshape(5, 4, 9, 1)).reshape(5, 4, 2, 3, 3)
    h = 1e-6
    Sp_iso, Sp_vol, _, _ = hyperelastic_terms(F + h * dF, *p)
    Sm_iso, Sm_vol, _, _ = hyperelastic_terms(F - h * dF, *p)
    for d, Sp, Sm in ((dS[:, :, 0], Sp_iso, Sm_iso), (dS[:, :, 1], Sp_vol, Sm_vol)):
        ref = (Sp - Sm) / (2 * h)
        assert np.abs(d - ref).max() < 1e-6 * np.abs(ref).max()


@pytest.mark.parametrize("law", sorted(BASES))
@pytest.mark.parametrize("control", ["force", "displacement"])
def test_linearized_step_equals_the_generic_step(fm, law, control):
    """The fitted parameters' directions and every candidate effect's (one scan point each:
    a Prony branch opened, a quartic bulk term, an inclusion's sphere, Darcy flow, the
    springs), on a load-unload history."""
    P = BASES[law]
    hist = ramp_history(5e-3, 2e-3, frames=7, unload=True)
    model = fm.model(law, P, compliant_bottom=True)
    full = fm.element_params(law, P)
    eps = 1e-6
    dirs = [model.with_params({**full, n: full[n] * 10 ** eps}) for n in P]
    names = list(P)
    for e in available_effects(law):
        scans = e.scan_points(fm)
        for scan in scans[:: max(1, len(scans) // 2)][:2]:
            dirs.append(e.direction(model, full, eps, scan, fm))
            names.append(e.name)
    assert {"inclusion", "punch_friction", "bottom_slip"} <= set(names)
    assert ("poroelastic" in names) == (law != "BR")     # (Darcy flow: through an elastic or SR skeleton)
    values = hist.value if control == "displacement" else solve_history(
        fm.model(law, P, compliant_bottom=True), hist.time, hist.value, "displacement").force
    opts = NewtonOptions(rtol=1e-10)
    runs = []
    for linearized in (False, True):
        for d in dirs:
            if hasattr(d, "start"):
                d.start()
        sens = Sensitivity(dirs, eps, linearized=linearized)
        runs.append(solve_history(model, hist.time, values, control, opts, sensitivity=sens))
        assert (sens.batch is not None) == linearized
    ref, lin = runs
    floor = {k: np.abs(getattr(ref, k)).max() for k in ("du", "ddepth", "dforce")}
    errors = {}
    for i, name in enumerate(names):
        for key in ("du", "ddepth", "dforce"):
            a, b = getattr(ref, key)[:, i], getattr(lin, key)[:, i]
            # the generic step's finite differences are exact to about eps relative, and
            # their rounding error is a fixed fraction of the largest direction's (BR's D2 =
            # 1000, whose motion is 1e-7 of C1's: 3.7e-4 of its own, 1e-9 of C1's; with the
            # symmetric factorization 1.1e-9 of C1's under force control)
            scale = max(np.abs(a).max(), 3e-5 * floor[key])
            if scale == 0:
                assert np.abs(b).max() == 0, name
                continue
            errors[name, key] = np.abs(a - b).max() / scale
    # measured: 1e-9 to 5e-7 (the springs, D1, k1), D2 of BR 3.7e-4 of its own scale
    assert max(errors.values()) < 1e-4, {k: f"{v:.1e}" for k, v in errors.items()}
