"""Frame pairs merged for a search on a long record (Measurements.every, Objective.every)."""

import numpy as np
import pytest

from conftest import SIGMA_D, SIGMA_F, SIGMA_TRACK, noisy_measurements
from liverinv.forward import ForwardModel
from liverinv.identify.noise import NoiseModel
from liverinv.identify.objective import Objective
from liverinv.loading import ramp_history

E = dict(C1=200.0, C2=5000.0, D1=1.5e-3)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    fm = ForwardModel(generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004))
    return fm, fm.run("elastic", E, ramp_history(4e-3, 2e-3, frames=17, unload=True))


def test_merged_pairs_sum_the_motion_and_carry_its_variance(tiny_run):
    fm, run = tiny_run
    data = noisy_measurements(run, 0)                   # 8 pairs
    merged = data.every(3)                             # pairs 0-2, 3-5, 6-7
    assert np.allclose(merged.t0, data.t0[[0, 3, 6]]) and np.allclose(merged.t1, data.t1[[2, 5, 7]])
    assert np.allclose(merged.u_of[2], data.u_of[6] + data.u_of[7])
    # m / sum(1/c): with sigma sqrt(m), the variance of the sum sigma^2 sum(1/c_i)
    assert np.allclose(merged.c_of[1], 3.0 / (1 / data.c_of[3] + 1 / data.c_of[4] + 1 / data.c_of[5]))
    c = data.c_of.copy()
    c[4, 0, 0] = 0.0
    assert data.__class__(**{**vars(data), "c_of": c}).every(3).c_of[1, 0, 0] == 0.0
    assert data.every(1) is data
    gap = data.__class__(**{**vars(data), "t0": data.t0 + np.r_[0.0, 1e-3 * np.ones(7)]})
    with pytest.raises(ValueError, match="merged"):
        gap.every(2)


def test_merged_objective_compares_summed_model_motion_with_summed_tracking(tiny_run):
    """An elastic model has no history: on merged pairs its motion is the full objective's
    summed over each block, and so is the volumetric residual (with sigma sqrt(m))."""
    fm, run = tiny_run
    data = noisy_measurements(run, 1)
    obj = Objective(fm, "elastic", data, noise=NoiseModel(SIGMA_F, SIGMA_D, SIGMA_TRACK, {}))
    sub = obj.every(2)
    assert sub.K == 4 and sub.noise.tracking_m == pytest.approx(SIGMA_TRACK * np.sqrt(2))
    p = dict(C1=180.0, C2=6000.0, D1=1e-3)
    full, merged = obj(p), sub(p)
    u_fem = full.v_fem * (data.t1 - data.t0)[:, None, None]
    summed = u_fem.reshape(4, 2, *u_fem.shape[1:]).sum(axis=1)
    expect = np.sqrt(sub.data.c_of) * (summed - sub.data.u_of) / (SIGMA_TRACK * np.sqrt(2))
    n_vol = sub.v_of.size
    assert np.abs(expect).max() > 1.0                  # a real misfit, off the truth
    got = merged.residual[:n_vol].reshape(expect.shape)
    # r = w (u_OF - u_FEM); measured 5e-6 of the largest (the solver's tolerance: the merged
    # objective steps the model twice as far)
    assert np.abs(got + expect).max() < 1e-4 * np.abs(expect).max()
