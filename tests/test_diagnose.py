"""The diagnosis: effects at their null reproduce the fitted model; score tests find a
planted shear or bulk relaxation behind an elastic fit and stay silent on elastic data."""

import numpy as np
import pytest

from conftest import SIGMA_D, SIGMA_F, SIGMA_TRACK, noisy_measurements
from liverinv.diagnose.effects import CATALOG, available_effects, law_with
from liverinv.diagnose.score import diagnose
from liverinv.forward import ForwardModel
from liverinv.identify.noise import NoiseModel
from liverinv.identify.objective import Measurements, Objective
from liverinv.identify.optimize import Fit
from liverinv.loading import ramp_history

E = dict(C1=200.0, C2=5000.0, D1=1.5e-3)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    path = generate_indentation_mesh(tmp_path_factory.mktemp("mesh") / "tiny.msh", h_far=0.03, h_rim=0.004)
    return ForwardModel(path)


@pytest.mark.parametrize("effect", [e for e in CATALOG if CATALOG[e].available and e != "strain_stiffening"])
def test_every_effect_at_its_null_reproduces_the_base_model(tiny, effect):
    """The law that carries the effect, with the effect's parameters at the null, gives the
    base law's residual (elastic base) to solver tolerance."""
    run = tiny.run("elastic", E, ramp_history(2e-3, 2e-3, frames=9, unload=True))
    data = Measurements.from_run(run)
    off = dict(E, C1=180.0)                   # away from the data: a residual of order one
    base = Objective(tiny, "elastic", data)(off)
    law, fixed = law_with("elastic", [effect])
    e = CATALOG[effect]
    null = {"g1": 0.0, "k1": 0.0, "D2": 1e3, "tau_g1": 0.3, "tau_k1": 0.3, "k_punch": 0.0, "c_bottom": 0.0}
    ext = Objective(tiny, law, data, fixed=fixed)({**off, **{k: null[k] for k in e.needs}})
    assert e.applies_to("elastic") and not e.applies_to(law, ())
    assert np.abs(ext.residual - base.residual).max() <= 1e-6 * np.abs(base.residual).max() + 1e-12


@pytest.mark.parametrize("truth_law, truth, contact, expected", [
    ("SR", dict(E, g1=0.3, tau_g1=0.5), {}, "shear_relaxation"),
    pytest.param("BR", dict(E, D2=1e3, k1=0.5, tau_k1=0.3), {}, "bulk_relaxation", marks=pytest.mark.slow),
    ("elastic", E, {"support": "sliding"}, "bottom_slip"),
    ("elastic", E, {}, "none"),
])
def test_planted_effect_is_found_and_null_data_stay_silent(tiny, truth_law, truth, contact, expected):
    truth_model = ForwardModel(tiny.mesh, **contact) if contact else tiny
    run = truth_model.run(truth_law, truth, ramp_history(4e-3, 2e-3, frames=17, unload=True))
    obj = Objective(tiny, "elastic", noisy_measurements(run, 0), noise=NoiseModel(SIGMA_F, SIGMA_D, SIGMA_TRACK, {}))
    fit = Fit(obj, dict(C1=150.0, C2=6000.0, D1=1e-3))
    out = fit.least_squares()
    d = diagnose(obj, out["params"], fit.names, fit.log_scale, out["best"]["phi_vol"])
    # the null solve of the diagnosis is the fit's optimum again (its bottom is a spring of
    # compliance C_BONDED, for the slip direction: the fixed bottom to about 1e-8 in Phi)
    assert d["phi"] == pytest.approx(out["best"]["phi"], rel=1e-6)
    assert d["recommended"] == expected, d["rows"]
    assert set(d["splits"]) == {"region", "depth", "time", "component"}
    for parts in d["splits"].values():
        assert sum(parts.values()) == pytest.approx(1.0, rel=1e-9)
    assert {r["effect"] for r in d["rows"]} == {e.name for e in available_effects("elastic")}
    assert set(d["not_tested"]) == {"poroelastic", "inclusion"}
    if expected != "none":
        top = d["rows"][0]
        assert top["effect"] == expected and top["predicted_drop"] > 0.3 and top["p_value"] < 1e-3
        if expected != "bottom_slip":
            amp = "g1" if expected == "shear_relaxation" else "k1"
            assert 0.5 * truth[amp] < top["estimate"][amp] < 2 * truth[amp]
    else:
        assert all(r["p_value"] > 0.01 or r["predicted_drop"] < 0.01 or not r["physical"] for r in d["rows"])
