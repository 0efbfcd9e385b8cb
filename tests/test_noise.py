"""The noise-aware objective: noise levels from the records, smoothing, the cluster-robust
covariance, and identification under the seed paper's indenter noise (3.9 um, 13 mN RMS at
100 Hz) with planted tracking noise."""

import numpy as np
import pytest

from conftest import SIGMA_D, SIGMA_F, SIGMA_TRACK, noisy_measurements
from liverinv.forward import ForwardModel
from liverinv.identify.noise import (FORCE_MODEL_ERROR, NoiseModel, kinks, piecewise_quadratic, reversals, smooth_record,
                                    tracking_noise, white_noise_rms)
from liverinv.identify.objective import Measurements, Objective
from liverinv.identify.optimize import Fit
from liverinv.identify.uncertainty import cluster_robust, gauss_newton
from liverinv.loading import LoadHistory, ramp_history

TRUTH = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
START = dict(C1=140.0, C2=6500.0, D1=1.05e-3)     # 30 % off


def _triangle(t, depth=6e-3, rate=2e-3):
    return np.minimum(rate * t, 2 * depth - rate * t)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_level_of_a_record_with_a_reversal(seed):
    """Planted white noise on a load-unload depth and a quadratic force (the reversal is a
    kink): the second-difference estimate is within 10 % of the planted level."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 6.0, 0.01)
    d = _triangle(t)
    assert white_noise_rms(d + SIGMA_D * rng.standard_normal(t.size)) == pytest.approx(SIGMA_D, rel=0.1)
    f = 2.4e4 * d ** 2
    assert white_noise_rms(f + SIGMA_F * rng.standard_normal(t.size)) == pytest.approx(SIGMA_F, rel=0.1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_smoothing_split_at_the_reversal_keeps_the_kink(seed):
    """GCV splines on each side of the detected reversal: measured 0.07-0.11 sigma RMS and at
    most 0.28 sigma from the planted triangle (one spline over the kink: 0.47 and 4-6)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 6.0, 0.01)
    d = _triangle(t)
    y = d + SIGMA_D * rng.standard_normal(t.size)
    breaks = reversals(t, y, SIGMA_D)
    np.testing.assert_allclose(breaks, [3.0], atol=0.011)
    err = smooth_record(t, y, SIGMA_D, breaks)(t) - d
    assert np.sqrt(np.mean(err ** 2)) < 0.2 * SIGMA_D
    assert np.abs(err).max() < 0.6 * SIGMA_D
    assert smooth_record(t, y, 0.0)(t[5]) == y[5]       # no noise: the samples themselves


@pytest.mark.parametrize("seed", [0, 1])
def test_a_long_record_is_smoothed_from_its_bin_means(seed, monkeypatch):
    """A curved 1 kHz ramp (4000 samples) is smoothed from 1000 bin means (scipy's GCV is a
    Python loop over the samples): its error against the planted curve, in depth and in rate,
    is that of the spline of every sample to within 5 % (measured: the same to 3 digits)."""
    from liverinv.identify import noise
    rng = np.random.default_rng(seed)
    t = np.arange(0, 4.0, 1e-3)

    def curve(tq):
        return 2e-3 * tq - 1e-4 * tq ** 2 + 2e-5 * np.sin(3 * tq)
    y = curve(t) + SIGMA_D * rng.standard_normal(t.size)
    tq = np.linspace(0, 4.0, 3001)
    smooth = smooth_record.__wrapped__        # not the memo of the last records
    binned = smooth(t, y, SIGMA_D)
    assert noise._binned(t, y)[0].size == noise.SPLINE_BINS
    monkeypatch.setattr(noise, "SPLINE_BINS", 10 ** 9)
    every = smooth(t, y, SIGMA_D)
    assert np.abs(every(tq) - binned(tq)).max() > 1e-3 * SIGMA_D      # two splines
    err_binned, err_every = binned(tq) - curve(tq), every(tq) - curve(tq)
    assert np.sqrt(np.mean(err_binned ** 2)) < 1.05 * np.sqrt(np.mean(err_every ** 2))
    assert np.sqrt(np.mean(err_every ** 2)) < 0.15 * SIGMA_D        # (it is smoothed at all)
    rate_binned = np.gradient(binned(tq), tq) - np.gradient(curve(tq), tq)
    rate_every = np.gradient(every(tq), tq) - np.gradient(curve(tq), tq)
    assert np.sqrt(np.mean(rate_binned ** 2)) < 1.05 * np.sqrt(np.mean(rate_every ** 2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kinks_of_a_hold_are_breaks(seed):
    """A 6 mm ramp, 2 s hold and unload with the paper's depth noise: the reversals alone put
    one break at the noise's extremum on the hold and left the drive depth 17 um and 12 % of
    the ramp's rate off where the hold starts and ends (session 31, the seed-33 hold data);
    the kinks are the hold's two ends within 0.011 s, and the pieces' splines stay within
    0.3 sigma of the planted record. A smooth turn (a cosine) gives its reversals and no
    other break; a rest before a ramp and a change of rate are kinks too."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 8.0, 0.01)
    d = np.interp(t, [0, 3, 5, 8], [0, 6e-3, 6e-3, 0])
    y = d + SIGMA_D * rng.standard_normal(t.size)
    breaks = kinks(t, y, SIGMA_D)
    np.testing.assert_allclose(breaks, [3.0, 5.0], atol=0.011)
    assert np.abs(smooth_record(t, y, SIGMA_D, breaks)(t) - d).max() < 0.3 * SIGMA_D
    assert np.abs(smooth_record(t, y, SIGMA_D, reversals(t, y, SIGMA_D))(t) - d).max() > 1.5 * SIGMA_D
    cosine = 3e-3 * (1 - np.cos(np.pi * t / 2)) + SIGMA_D * rng.standard_normal(t.size)
    np.testing.assert_allclose(kinks(t, cosine, SIGMA_D), [2.0, 4.0, 6.0], atol=0.011)
    rates = np.interp(t, [0, 1, 3, 4, 8], [0, 0, 2e-3, 6e-3, 0]) + SIGMA_D * rng.standard_normal(t.size)
    np.testing.assert_allclose(kinks(t, rates, SIGMA_D), [1.0, 3.0, 4.0], atol=0.011)


def test_piecewise_quadratic_interpolation_is_exact_for_quadratics_on_each_side():
    t = np.arange(0, 6.0, 0.01)
    nodes = np.unique(np.r_[np.linspace(0, 6, 13), 3.0])
    F = lambda s: 2.4e4 * _triangle(s) ** 2
    W = piecewise_quadratic(nodes, t, [3.0])
    assert np.abs(W @ F(nodes) - F(t)).max() < 1e-12
    assert np.abs(np.interp(t, nodes, F(nodes)) - F(t)).max() > 5e-3   # linear: 6 mN off


def test_tracking_noise_from_the_flow_follows_confidence():
    """Smooth nodal motion plus white noise of RMS s / sqrt(c): the estimate at c = 1 is
    within 10 % of s."""
    rng = np.random.default_rng(4)
    K, N = 40, 300
    t = np.linspace(0, 4, K + 1)
    amp = rng.uniform(0, 1e-3, (N, 3))
    U = np.sin(0.8 * t)[:, None, None] * amp
    c = rng.uniform(0.1, 1.0, (K, N, 3))
    u = np.diff(U, axis=0) + 3e-6 / np.sqrt(c) * rng.standard_normal((K, N, 3))
    est, source = tracking_noise(u, c, np.diff(t))
    assert est == pytest.approx(3e-6, rel=0.1) and "estimated" in source
    floor, source = tracking_noise(np.diff(U, axis=0), c, np.diff(t), grid_spacing_m=[5e-4, 5e-4, 3e-4])
    assert floor == pytest.approx(0.02 * 3e-4) and "floor" in source


def test_cluster_robust_covariance_covers_correlated_errors():
    """Linear regression with errors shared within groups (as tracking errors are within a
    node's neighbourhood): over 400 replicates the sandwich SD is within 15 % of the spread
    of the estimates, while the independent-residual SD is more than 2x too small."""
    rng = np.random.default_rng(5)
    G, per = 60, 40
    groups = np.repeat(np.arange(G), per)
    X = np.column_stack([np.ones(G * per), rng.normal(size=G * per) + np.repeat(rng.normal(size=G), per)])
    est, sd_robust, sd_naive = [], [], []
    for _ in range(400):
        e = np.repeat(rng.normal(size=G), per) + 0.3 * rng.normal(size=G * per)
        b, *_ = np.linalg.lstsq(X, e, rcond=None)
        r = e - X @ b
        cov, n_groups = cluster_robust(-X, r, groups)
        naive = gauss_newton(-X, r, 10, np.array([False, False]))["rel_sd"]
        est.append(b)
        sd_robust.append(np.sqrt(np.diag(cov)))
        sd_naive.append(naive)
    spread = np.std(est, axis=0)
    assert n_groups == G
    np.testing.assert_allclose(np.mean(sd_robust, axis=0), spread, rtol=0.15)
    assert np.all(np.mean(sd_naive, axis=0) < 0.5 * spread)


@pytest.fixture(scope="module")
def noisy_case(tmp_path_factory):
    """Elastic truth on a tiny mesh, 4 mm at 2 mm/s with unloading; the indenter record at
    100 Hz with the paper's noise, and the exact nodal motion of 16 frame pairs with planted
    tracking noise of RMS 2 um / sqrt(c)."""
    from liverinv.meshgen import generate_indentation_mesh
    path = generate_indentation_mesh(tmp_path_factory.mktemp("mesh") / "tiny.msh", h_far=0.03, h_rim=0.004)
    fm = ForwardModel(path)
    run = fm.run("elastic", TRUTH, ramp_history(4e-3, 2e-3, frames=33, unload=True))
    return fm, run


def test_paper_noise_recovered_by_the_likelihood_with_honest_uncertainty(noisy_case):
    """Five noise seeds: every fit from 30 % off within 5 % of the truth on every parameter,
    and the truth within two reported (cluster-robust) standard deviations in at least 4 of
    5 seeds for every parameter."""
    from liverinv.identify.fitfile import fit_dataset
    fm, run = noisy_case
    noise = NoiseModel(SIGMA_F, SIGMA_D, SIGMA_TRACK, {})
    z = []
    for seed in range(5):
        fit = Fit(Objective(fm, "elastic", noisy_measurements(run, seed), noise=noise), START)
        out = fit.least_squares()
        for k, v in TRUTH.items():
            assert out["params"][k] == pytest.approx(v, rel=0.05), (seed, k, out["params"])
        ds = fit_dataset(fit, out, out["jacobian"])
        assert ds.attrs["objective"] == "likelihood" and "cluster-robust" in ds.attrs["covariance"]
        assert float(ds.phi_ind) / int(ds.n_ind) == pytest.approx(1.0, abs=0.2)   # white, as planted
        sd = np.sqrt(np.diag(ds.cov_x.values))
        x_true = fit.to_x([TRUTH[k] for k in fit.names])
        z.append((fit.to_x(ds.best.values) - x_true) / sd)
    covered = (np.abs(np.array(z)) < 2).sum(axis=0)
    assert np.all(covered >= 4), np.array(z)


def test_paper_objective_is_unchanged_and_its_indenter_term_is_force_noise(noisy_case):
    """The paper's Phi stays available and exact (zero at the truth on clean data); with the
    indenter noise its indenter term at the truth is the driven depth's jitter (measured 8.7x
    its field term), while the likelihood's indenter share stays below half."""
    fm, run = noisy_case
    clean = Objective(fm, "elastic", Measurements.from_run(run))
    assert clean.control == "force" and clean(TRUTH).phi < 1e-12
    noisy = noisy_measurements(run, 0)
    paper = Objective(fm, "elastic", noisy)(TRUTH)
    assert paper.phi_ind > 5 * paper.phi_vol
    lik = Objective(fm, "elastic", noisy, noise=NoiseModel(SIGMA_F, SIGMA_D, SIGMA_TRACK, {}))(TRUTH)
    assert lik.phi_ind / lik.phi < 0.5


def test_block_inflation_measures_variance_and_correlation():
    """A block whose residuals are twice as noisy as claimed inflates by 4; one whose errors
    are shared by groups of 20 rows by about the design effect 1 + (20 - 1) rho."""
    from liverinv.identify.uncertainty import block_inflation
    rng = np.random.default_rng(6)
    n, G = 4000, 200
    J = rng.normal(size=(n, 2))
    groups = np.repeat(np.arange(G), n // G)
    lam = [block_inflation(J, 2.0 * rng.normal(size=n), groups, slice(None)) for _ in range(50)]
    assert np.mean(lam) == pytest.approx(4.0, rel=0.1)
    # shared error: rho = 0.5 within groups of 20, regressors shared too (as neighbouring
    # nodes move alike): design effect 1 + 19 * 0.5 = 10.5
    Jg = np.repeat(rng.normal(size=(G, 2)), n // G, axis=0)
    lam = [block_inflation(Jg, np.sqrt(0.5) * (np.repeat(rng.normal(size=G), n // G) + rng.normal(size=n)),
                           groups, slice(None)) for _ in range(50)]
    assert np.mean(lam) == pytest.approx(10.5, rel=0.15)


def test_a_noise_free_force_record_is_compared_no_closer_than_the_model_can_match_it():
    """`synthesize`'s default record is noise-free. Its force level is 1 % of the force range
    (the model's own error), not the second differences' estimate (about 1e-17 N); a depth
    record keeps 1e-4 of its range; a bundle's paper-level 13 mN stays; a given level is taken
    as it is. (With 1e-4 of the range for the force, the warped elastic null of seed 38 got three
    false additions: docs/diagnosis.md, session 33.)"""
    from liverinv.identify.noise import noise_model
    from liverinv.imaging.bundle import Indenter
    t = np.arange(0.0, 6.0 + 1e-9, 0.01)
    depth = np.interp(t, [0.0, 3.0, 6.0], [0.0, 6e-3, 0.0])
    force = 0.35 * (depth / 6e-3) ** 1.5
    clean = noise_model(Indenter(t, depth, force), None, tracking_m=1e-6)
    assert FORCE_MODEL_ERROR == 0.01
    assert clean.force_N == pytest.approx(3.5e-3)
    assert clean.depth_m == pytest.approx(6e-7)
    assert "floor 0.01 of the range" in clean.sources["force_N"]
    noisy = noise_model(Indenter(t, depth, force, SIGMA_D, SIGMA_F), None, tracking_m=1e-6)
    assert (noisy.force_N, noisy.depth_m) == (SIGMA_F, SIGMA_D)
    assert noisy.sources["force_N"] == "bundle"
    assert noise_model(Indenter(t, depth, force), None, force_N=1e-4, tracking_m=1e-6).force_N == 1e-4


def test_a_creep_record_breaks_at_the_ends_of_the_force_hold(noisy_case):
    """A force-controlled creep test (what a lab's indenter under force feedback records): SR
    truth (g1 0.4, tau_g1 0.5 s) on the tiny mesh, the force ramped to 0.15 N in 2 s, held 3 s,
    unloaded in 2 s, so the depth creeps 0.29 mm while the force is held. The depth record's
    kinks are the ends of the hold within one indenter sample (measured within 0.0065 s), and
    the smoothed drive is within 0.35 sigma RMS of the truth's depth on three noise seeds
    (measured 0.21-0.27 sigma)."""
    fm, _ = noisy_case
    t = np.round(np.arange(0.0, 7.0 + 1e-9, 0.1), 10)
    force = LoadHistory("force", t, np.interp(t, [0.0, 2.0, 5.0, 7.0], [0.0, 0.15, 0.15, 0.0]))
    run = fm.run("SR", dict(TRUTH, g1=0.4, tau_g1=0.5), force)
    depth = run.indenter_depth.values
    assert depth[50] - depth[20] == pytest.approx(2.9e-4, rel=0.05)       # it creeps
    t_ind = np.arange(0.0, 7.0 + 1e-9, 0.01)
    planted = np.interp(t_ind, run.time.values, depth)
    for seed in range(3):
        y = planted + SIGMA_D * np.random.default_rng(seed).standard_normal(t_ind.size)
        breaks = kinks(t_ind, y, SIGMA_D)
        np.testing.assert_allclose(breaks, [2.0, 5.0], atol=0.01)
        err = smooth_record(t_ind, y, SIGMA_D, breaks)(t_ind) - planted
        assert np.sqrt(np.mean(err ** 2)) < 0.35 * SIGMA_D, seed


def test_relaxation_fitted_through_a_hold(noisy_case):
    """SR truth (g1 0.4, tau_g1 0.3 s) on the tiny mesh, 4 mm at 2 mm/s, 1 s hold, unload,
    the paper's indenter noise: the drive breaks at the hold's two ends (frame times), and the
    least-squares fit from 20 % off recovers every parameter within 5 % on two noise seeds
    (measured 0.3-2.8 %). With the reversals alone as breaks (one at the noise's extremum on
    the hold, 2.96 s) the same fits ended at C1 +10-12 %, C2 +13-16 %, g1 +18 %, tau_g1 -27 %
    (session 31, /tmp/s31/t/hold_fit.py)."""
    fm, _ = noisy_case
    truth = dict(TRUTH, g1=0.4, tau_g1=0.3)
    run = fm.run("SR", truth, ramp_history(4e-3, 2e-3, frames=31, unload=True, hold=1.0))
    start = {k: v * (1.2 if i % 2 else 0.8) for i, (k, v) in enumerate(truth.items())}
    noise = NoiseModel(SIGMA_F, SIGMA_D, SIGMA_TRACK, {})
    for seed in range(2):
        obj = Objective(fm, "SR", noisy_measurements(run, seed), noise=noise)
        np.testing.assert_array_equal(obj.breaks, [2.0, 3.0])
        out = Fit(obj, start).least_squares()
        for k, v in truth.items():
            assert out["params"][k] == pytest.approx(v, rel=0.05), (seed, k, out["params"])
