"""Solves started from a nearby solution (`solve_history`'s `guide`), as the diagnosis starts
its solves from the fit's: the same solution as unguided, and the objective's memory of its
last solves that provides the guide."""

import numpy as np
import pytest

from liverinv.fem.solver import solve_history
from liverinv.forward import ForwardModel
from liverinv.identify.objective import Measurements, Objective
from liverinv.loading import ramp_history

SR = dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.5)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    return ForwardModel(generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004))


@pytest.fixture(scope="module")
def history():
    return ramp_history(4e-3, 2e-3, frames=13, unload=True)


@pytest.mark.parametrize("control", ["displacement", "force"])
def test_a_solve_guided_by_its_own_solution_starts_converged(tiny, history, control):
    """Guided by its own solution a solve makes no iteration and returns that solution."""
    values = history.value if control == "displacement" else \
        solve_history(tiny.model("SR", SR), history.time, history.value, "displacement").force
    h = solve_history(tiny.model("SR", SR), history.time, values, control)
    again = solve_history(tiny.model("SR", SR), history.time, values, control, guide=h.u.reshape(len(h.u), -1))
    assert h.iterations.sum() > 2 * len(h.time) and again.iterations.sum() == 0
    assert np.abs(again.u - h.u).max() <= 1e-12 * np.abs(h.u).max()
    assert np.array_equal(again.depth, h.depth)


@pytest.mark.parametrize("law, params, contact", [
    ("SR+punch_friction", dict(SR, k_punch=1e12), {}),         # a bonded punch: the friction secant
    ("SR+bottom_slip", dict(SR, c_bottom=1e-2), {}),           # a sliding bottom: the slip secant
    ("PSR", dict(SR, kappa=3e-9), {}),                          # Darcy flow: pressures are not in the guide
])
def test_a_guided_solve_of_another_model_is_its_unguided_solution(tiny, history, law, params, contact):
    """The diagnosis's secants, guided by the fitted law's solution, end where they end
    unguided (both to the solver's tolerance; measured on the tiny mesh: displacements within
    2.8e-7 to 9.4e-6 of the largest, the sliding bottom's the farthest, forces within 1.4e-6)."""
    base = solve_history(tiny.model("SR", SR), history.time, history.value, "displacement")
    plain = solve_history(tiny.model(law, params), history.time, history.value, "displacement")
    guided = solve_history(tiny.model(law, params), history.time, history.value, "displacement",
                           guide=base.u.reshape(len(base.u), -1))
    assert np.abs(plain.u - base.u).max() > 0.01 * np.abs(base.u).max()      # far from the guide
    assert np.abs(guided.u - plain.u).max() <= 3e-5 * np.abs(plain.u).max()
    assert np.abs(guided.force - plain.force).max() <= 1e-5 * np.abs(plain.force).max()


def test_a_guide_of_the_wrong_shape_is_refused(tiny, history):
    with pytest.raises(ValueError, match="one displacement vector per time"):
        solve_history(tiny.model("SR", SR), history.time, history.value, "displacement",
                      guide=np.zeros((len(history.time) - 1, 3 * tiny.mesh.n_nodes)))


def test_the_objective_remembers_its_last_solves(tiny, history):
    """`Objective.solution` holds the nodal histories of the last `REMEMBERED` parameter sets
    solved by calling the objective (fixed parameters merged), and no other."""
    run = tiny.run("SR", SR, history)
    obj = Objective(tiny, "SR", Measurements.from_run(run), fixed={"tau_g1": SR["tau_g1"]})
    free = {k: v for k, v in SR.items() if k != "tau_g1"}
    ev = obj(free)
    u = obj.solution(free)
    assert u.shape == (len(obj.t_drive), 3 * tiny.mesh.n_nodes)
    # (driven by the run's force: the run's displacements to the solver's tolerance)
    assert ev.ok and np.abs(u.reshape(-1, tiny.mesh.n_nodes, 3) - run.u.values).max() <= 1e-4 * np.abs(run.u.values).max()
    assert obj.solution(dict(free, C1=201.0)) is None
    others = [dict(free, C1=200.0 + i) for i in range(1, obj.REMEMBERED + 1)]
    for p in others:
        obj(p)
    assert obj.solution(free) is None and all(obj.solution(p) is not None for p in others)
    # a model built and solved apart (the diagnosis's secants) is not remembered
    obj.evaluate_model(free, tiny.model("SR", SR))
    assert obj.solution(free) is None
