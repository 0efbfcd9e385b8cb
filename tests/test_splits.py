"""The misfit splits of the diagnosis: every split's shares sum to 1, local gradients are exact
for linear fields, and planted residual fields land in the part that holds them."""

from types import SimpleNamespace

import numpy as np
import pytest

from liverinv.diagnose.splits import local_gradients, misfit_splits


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(3)
    return rng.uniform([-0.04, -0.04, 0.0], [0.04, 0.04, 0.03], (600, 3))


def test_local_gradients_are_exact_for_linear_fields(cloud):
    L = np.array([[1.0, 2.0, -0.5], [0.3, -1.0, 0.0], [0.2, 0.1, 4.0]])
    f = cloud @ L.T + np.array([1.0, -2.0, 0.5])
    nb, op = local_gradients(cloud)
    G = np.einsum("njk,nki->nij", op, f[nb])
    assert np.abs(G - L).max() < 1e-9 * np.abs(L).max()
    # a point left out (weight 0) does not enter its neighbours' fits
    w = np.ones(len(cloud)); w[0] = 0.0
    f2 = f.copy(); f2[0] += 1e3
    nb, op = local_gradients(cloud, w)
    G = np.einsum("njk,nki->nij", op, f2[nb])
    assert np.abs(G[1:] - L).max() < 1e-8 * np.abs(L).max()


def _objective(X, v_of, c, t0, t1, depth_rate):
    """What misfit_splits reads of an Objective: data, sizes, the drive and the velocities."""
    K, N = v_of.shape[:2]
    t = np.linspace(t0[0], t1[-1], 200)
    d = np.cumsum(np.r_[0.0, depth_rate(0.5 * (t[1:] + t[:-1])) * np.diff(t)])
    data = SimpleNamespace(X=X, c_of=c, t0=t0, t1=t1)
    return SimpleNamespace(data=data, K=K, N=N, v_of=v_of, t_drive=t, d_drive=d, forward=None)


def test_planted_residuals_land_in_their_parts(cloud):
    """A residual that is a pure dilatation is all volumetric, a pure shear all deviatoric;
    a residual where the model's strain rate is high falls in the high bin; the time split
    finds loading, a hold and unloading from the indenter's rate; every split sums to 1."""
    K, N = 9, len(cloud)
    t0 = np.arange(K) * 1.0
    t1 = t0 + 1.0
    rate = lambda t: np.where(t < 3, 1e-3, np.where(t < 6, 0.0, -1e-3))
    c = np.ones((K, N, 3))
    X = cloud
    # the model's velocity: a stretch whose rate grows with |x| (d v_x / d x = 2e-2 |x|)
    v_fem = np.zeros((K, N, 3))
    v_fem[..., 0] = 1e-2 * (X[:, 0] * np.abs(X[:, 0]))[None]
    for planted, expect in ((np.eye(3), "volumetric"), (np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0.0]]), "deviatoric")):
        v_of = v_fem + 1e-4 * (X @ planted.T)[None]
        obj = _objective(X, v_of, c, t0, t1, rate)
        res = (v_of - v_fem).ravel()
        s = misfit_splits(obj, res, v_fem)
        assert s["gradient"][expect] == pytest.approx(1.0, abs=1e-9)
        assert set(s["time"]) == {"loading", "hold", "unloading"}
        for parts in s.values():
            assert sum(parts.values()) == pytest.approx(1.0, rel=1e-12)
    # a residual only where |x| is large, i.e. where the model deforms fast
    v_of = v_fem.copy()
    v_of[:, np.abs(X[:, 0]) > 0.03, 2] += 1e-4
    obj = _objective(X, v_of, c, t0, t1, rate)
    s = misfit_splits(obj, (v_of - v_fem).ravel(), v_fem)
    assert s["strain_rate"]["high"] > 0.9 and s["strain_rate"]["low"] < 0.01
    assert "strain_rate" not in misfit_splits(obj, (v_of - v_fem).ravel())     # needs the model's motion
