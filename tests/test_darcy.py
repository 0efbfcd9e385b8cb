"""The first-order Darcy direction at the drained limit (fem/darcy.py) against the biphasic
model's own sensitivity along 1/kappa at a large permeability, on the same mesh and rule."""

import numpy as np
import pytest

from liverinv.fem.biphasic import Biphasic
from liverinv.fem.darcy import DrainedDarcy
from liverinv.fem.sensitivity import Sensitivity
from liverinv.fem.solver import solve_history
from liverinv.forward import ForwardModel
from liverinv.loading import ramp_history

SKELETONS = {"elastic": dict(C1=200.0, C2=5000.0, D1=1.5e-3),
             "SR": dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.5)}
SCALE = 1e7          # the amplitude a of 1/kappa = SCALE a (as the catalog's poroelastic effect)
KAPPA = 1e-2         # a drained biphasic model: 1/kappa = 100 (a = 1e-5)


@pytest.fixture(scope="module")
def fm(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    return ForwardModel(generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004))


@pytest.mark.parametrize("control", ["displacement", "force"])
@pytest.mark.parametrize("skeleton", sorted(SKELETONS))
def test_drained_darcy_direction_is_the_biphasic_sensitivity(fm, skeleton, control):
    """du/da and the indenter's change at every frame of a load-unload history. Measured on
    the tiny mesh (displacement control): 1.5e-4 of the largest value; the difference grows
    as 1/kappa of the reference (5e-4 at kappa 1e-3, 5e-3 at 1e-4: its second-order term).
    The reference's variant steps 1/kappa by 1e-2 only: its finite difference in kappa is
    exact to 1e-2 kappa (with a = 1e-6, 1/kappa 100 -> 110, it was 10 % off)."""
    law = "elastic" if skeleton == "elastic" else "SR"
    P = SKELETONS[skeleton]
    hist = ramp_history(5e-3, 2e-3, frames=9, unload=True)
    values = hist.value if control == "displacement" else solve_history(
        fm.model(law, P), hist.time, hist.value, "displacement").force
    full = fm.element_params(law, P)
    bp = Biphasic(fm.space, dict(full, kappa=KAPPA), drained=fm.drained)
    eps = 1e-9
    var = bp.with_params(dict(full, kappa=1.0 / (1.0 / KAPPA + SCALE * eps)))
    ref = solve_history(bp, hist.time, values, control, sensitivity=Sensitivity([var], eps))
    eps = 1e-6
    solid = fm.model(law, P)
    h = solve_history(solid, hist.time, values, control,
                      sensitivity=Sensitivity([DrainedDarcy(fm.space, fm.drained, SCALE)], eps))
    du_ref, du = ref.du[:, 0], h.du[:, 0]
    assert np.abs(du_ref).max() > 1e-6                      # a real effect: m per unit amplitude
    assert np.abs(du - du_ref).max() < 1e-3 * np.abs(du_ref).max()
    if control == "force":
        dd_ref = ref.ddepth[:, 0]
        assert np.abs(h.ddepth[:, 0] - dd_ref).max() < 1e-3 * np.abs(dd_ref).max()
    else:
        df_ref = ref.dforce[:, 0]
        assert np.abs(h.dforce[:, 0] - df_ref).max() < 1e-3 * np.abs(df_ref).max()
