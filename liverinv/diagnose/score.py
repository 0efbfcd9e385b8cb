"""Which effect is missing, from the fit alone: score tests at the effects' null values.

One forward solve of the fitted law at its optimum gives the residual r and, by direct
differentiation, its derivatives along the fitted parameters (X) and along every candidate
effect's amplitude at every scanned value (z). For each candidate:

* z is made orthogonal to X (the fitted parameters would absorb the rest of it);
* the predicted drop of Phi is ``(z'r)^2 / z'z`` and the one-step estimate of the amplitude
  ``-z'r / z'z`` (Gauss-Newton from the null); an estimate against the physical sign
  (a negative relaxation amplitude) predicts no drop;
* the statistic ``t = -sign z'r / sqrt(V)`` uses the cluster-robust variance of the score
  ``V = sum_g (sum_{i in g} z_i r_i)^2`` over the fit's residual groups (12 mm node blocks with
  all their frames, 0.25 s indenter chunks), because tracking errors and the model mesh's
  discretization error are correlated in space and time; the one-sided p-value ``1 - Phi(t)``
  is multiplied by the number of scanned values (Bonferroni over the scan);
* an effect is recommended when its p-value is below `alpha` and its predicted drop is at
  least `min_drop` of Phi_vol; the best of those (largest predicted drop) is the
  recommendation. Under a level stricter than `ALPHA` (warped volumes) the strict level says
  whether an effect is missing and the nominal one which: once an effect passes the strict
  level, the recommendation is the largest predicted drop among the effects that pass `ALPHA`
  (`recommend`).

A boundary effect saturates far from its null: a spring on the footprint goes from frictionless
to bonded between about 1e6 and 1e9 Pa/m, and its first-order score at the null sees little of
the bonded punch (on the imaged SR-with-bonded-punch case it predicted 3.8 % where the refit
removed 38.5 %, and the quartic bulk term ranked first). Such an effect (`Effect.far`: punch friction, bottom slip) is
also tested by the secant to its full size, one nonlinear solve of the fitted law with the
punch bonded or the bottom sliding: z = r_full - r, its amplitude theta the fraction of the full
effect, a second point of the effect's scan. The one-step parameter follows from the effect's
saturation, fraction = a / (a + a_half), with a_half from the tangent and the secant (their
projection). On that case the secant predicts 38.8 % (ranked first), on partial friction
(k_punch 1e7 Pa/m) 10.0 % for an actual 11 %.

Darcy flow is far from linear in 1/kappa: at kappa 1e-8 m^4/(N s) the consolidation time of
the footprint is about the test's, while its first-order score at the drained null sees flow
that follows the rate of volume change at once. Behind SR with kappa 1e-8 hidden, the score
predicted 2.6 % where the PSR refit removed 26 %, and bulk relaxation (whose scanned relaxation
time can take the consolidation time) ranked first at 17 %. So Darcy flow is also tested by
secants (`Effect.secant_scan`): one biphasic solve of the fitted skeleton at each of
`effects.KAPPA_SECANTS` (kappa 3e-9 and 3e-8), each a point of its scan, the estimate the
best point's kappa. On that case the best secant predicts 27 % and ranks first; behind elastic
with bulk relaxation hidden, bulk relaxation stays first (5.5 % against 3.2 %).
"""

from __future__ import annotations

import json
import logging
import time as _time
from dataclasses import replace

import numpy as np
from scipy import stats
from threadpoolctl import threadpool_limits

from ..parallel import beside
from .effects import CATALOG, INCLUSION_DEPTHS_M, INCLUSION_RADII_M, available_effects, sphere_allowed

__all__ = ["diagnose", "confirm_by_tracker_response", "refine_inclusion", "ALPHA", "MIN_DROP"]

log = logging.getLogger(__name__)

ALPHA = 0.01        # family-wise level of the scan-corrected one-sided test
SECANT = "secant_to"   # a scan point that is the secant to the effect's full size (`Effect.far`)
FULL = "full_size"     # ... and it stands for the full size (`Effect.far` or its fallback)
MIN_DROP = 0.01     # an effect must be predicted to remove this fraction of Phi_vol
#: under a level stricter than ALPHA (warped volumes), an effect predicted to remove this fraction
#: of Phi_vol needs only ALPHA: along any effect the tracker's systematic error explained at most
#: 2.6 % of Phi_vol on the recorded warped nulls and last steps (`passes`)
STRONG_DROP = 0.05
EPS = 1e-6          # step of the sensitivity directions
#: Newton tolerance of the secant solves (the objective's own is 1e-6): their residual's change
#: from the fit's is then within 2e-4 to 1.1e-3 of the tight solve's and its predicted drop within
#: 0.15 %, in 32-50 % fewer iterations (the four secants of the warped elastic null of seed 19
#: and of the warped neo-Hookean null of seed 15)
SECANT_RTOL = 1e-4


def _orthogonal(X, Z):
    if X.shape[1] == 0:
        return Z
    Q, _ = np.linalg.qr(X)
    return Z - Q @ (Q.T @ Z)


def diagnose(objective, params: dict, fitted: list, log_scale, phi_vol: float | None, effects=None,
             alpha=ALPHA, min_drop=MIN_DROP, scans=None) -> dict:
    """Score tests of the candidate `effects` (default: every available effect the law lacks)
    for the fit `params` of `objective.law` (`fitted`: the names that were identified,
    `log_scale`: their normalization). Returns a dict with `rows` (one per effect, ranked by
    predicted drop), `recommended` (an effect name or 'none') and what was done. `phi_vol`: the
    measure of the predicted drops, the fit's Phi_vol (None: the diagnosis solve's own). `scans`
    maps an effect to its own scan points (e.g. a finer sphere grid, `refine_inclusion`)."""
    t0 = _time.perf_counter()
    law = objective.law
    fm = objective.forward
    cands = [CATALOG[e] for e in effects] if effects else available_effects(law, objective.fixed)
    cands = [e for e in cands if e.name not in _held_already(fm)]
    base = {**params, **objective.fixed}
    # testing bottom slip needs the bottom's tangential dofs free (a spring, bonded at c_bottom = 0)
    model = fm.model(law, base, compliant_bottom=any(e.name == "bottom_slip" for e in cands))
    full = fm.element_params(law, base)
    dirs = []
    for name, ls in zip(fitted, log_scale):
        p = dict(full)
        p[name] = full[name] * 10 ** EPS if ls else full[name] + EPS
        dirs.append(model.with_params(p))
    cols = []
    for e in cands:
        for scan in (scans or {}).get(e.name) or e.scan_points(fm):
            dirs.append(e.direction(model, full, EPS, scan, fm))
            cols.append((e, scan))
    # effects that saturate far from their null (a bonded punch, a sliding bottom) also by the
    # secant to their full size: one solve each, its residual's change a column like the others
    # and effects far from linear in their amplitude (Darcy flow) by secants at a scan of it.
    # They are solved in a second, forked process while this one makes the sensitivity step,
    # with one thread each in MKL and OpenBLAS; those the second has not started when the step
    # is done are solved here (`parallel.beside`). In a second thread instead (the GIL is held
    # by the assembly's Python), the pair took as long as one after the other (the warped
    # elastic null of seed 34: 10.5-11.0 s overlapped, 4.95 + 5.15 s one after the other).
    jobs = [(e, a) for e in cands for a in e.secant_points()]
    # every solve starts from the fitted law's own solution where the fit left it (one of its last
    # solves): on the warped nulls of seeds 44 and 47 (31 frames) the diagnosis then took 4.1-4.5
    # plain solves' time against 4.6-5.2, its predicted drops equal to 4 digits (docs/diagnosis.md,
    # session 40)
    guide = objective.solution(params)
    log.info("diagnosis of %s: solves start from %s", objective.law,
             "the fit's solution" if guide is not None else "rest (the fit's solution is not the objective's)")

    def sensitivity_step():
        ev = objective.evaluate_model(dict(params), model, dirs, EPS, guide=guide)
        if not ev.ok:      # (no more secants are started)
            raise ValueError(f"the forward solve at the fit's optimum failed: {ev.message}")
        return ev
    with threadpool_limits(limits=1 if jobs else None):
        ev, solved = beside(sensitivity_step,
                            lambda i: _secant_solve(objective, params, model, full, fm, *jobs[i], guide=guide), len(jobs))
    r, J = ev.residual, ev.jacobian
    if phi_vol is None:
        phi_vol = float(ev.phi_vol)
    k = len(fitted)
    n_solves = 1
    secants, changes = [], []
    for (e, a), (far, a_try, n) in zip(jobs, solved):
        n_solves += n
        if not far.ok:
            continue
        changes.append(far.residual - r)
        cols.append((e, {SECANT: a_try, FULL: a == e.far}))
        if e not in secants:
            secants.append(e)
    if changes:
        J = np.column_stack([J, *changes])
    Z = _orthogonal(J[:, :k], J[:, k:])
    groups = objective.residual_groups()
    s = Z.T @ r
    zz = np.einsum("ij,ij->j", Z, Z)
    _, g_idx = np.unique(groups, return_inverse=True)
    V = _cluster_variance(Z, r, g_idx)
    # a localized direction (an inclusion) lives in one or two groups, where the residual holds
    # the effect itself: the cluster-robust variance is then about the score squared (t ~ 1).
    # Its variance is instead the pooled one, sigma^2 D z'z, with the design effect D of the
    # residual's correlation within the groups measured on the fitted directions X (spread
    # over all groups). (The heteroscedastic form D sum z_i^2 r_i^2 was tried: on the quick
    # study's null data it gave p 7e-36 to a 3.5 mm sphere under the punch, against 1.5e-4.)
    geo = np.array([c[0].geometric for c in cols], bool)
    if geo.any():
        V[geo] = _design_effect(J[:, :k], r, g_idx) * float(r @ r / r.size) * zz[geo]
    n_vol = objective.v_of.size
    rows = []
    for e in cands:
        idx = [i for i, (ee, _) in enumerate(cols) if ee is e]
        best = None
        for i in idx:
            theta = -s[i] / zz[i] if zz[i] > 0 else 0.0
            physical = e.physical(theta)
            drop = s[i] ** 2 / zz[i] if (zz[i] > 0 and physical) else 0.0
            # one-sided in the physical direction; two-sided (|t|, p doubled) for either sign
            t = ((abs(s[i]) if e.sign == 0 else -np.sign(e.sign) * s[i]) / np.sqrt(V[i])) if V[i] > 0 else 0.0
            cand = dict(i=i, theta=theta, physical=physical, drop=drop, t=t, scan=cols[i][1])
            if cols[i][1].get(FULL):
                # theta is the fraction of the full effect; the amplitude from the effect's
                # saturation, its half-size amplitude from the tangent (at the null) and the secant
                tan = next(j for j in idx if SECANT not in cols[j][1])
                half = float(Z[:, i] @ Z[:, tan] / zz[tan]) if zz[tan] > 0 else np.nan
                cand["theta"] = e.saturating_amplitude(theta, half, cols[i][1][SECANT]) if physical else theta
            elif SECANT in cols[i][1]:
                # a point of the secant scan: the amplitude is the point's (theta, the fraction of
                # its change that fits, is not an amplitude of a response this far from linear)
                cand["theta"] = cols[i][1][SECANT] if physical else theta
            if best is None or cand["drop"] > best["drop"] or (cand["drop"] == best["drop"] == 0 and t > best["t"]):
                best = cand
        p_raw = float(min(1.0, stats.norm.sf(best["t"]) * (2.0 if e.sign == 0 else 1.0)))
        p_adj = float(min(1.0, p_raw * len(idx)))
        rows.append(dict(effect=e.name, description=e.description,
                         predicted_drop=float(best["drop"] / phi_vol) if phi_vol > 0 else 0.0,
                         predicted_drop_phi=float(best["drop"]), p_value=p_adj, p_value_raw=p_raw,
                         statistic=float(best["t"]), physical=bool(best["physical"]), n_scan=len(idx),
                         amplitude=float(best["theta"]), amplitude_unit=e.unit,
                         estimate=e.estimate(best["theta"], {k: v for k, v in best["scan"].items() if k not in (SECANT, FULL)})
                         if best["physical"] else {}, secant=SECANT in best["scan"],
                         where=_where(objective, Z[:, best["i"]], n_vol)))
    rows.sort(key=lambda row: (-row["predicted_drop"], row["p_value"]))
    eligible = [row["effect"] for row in rows if passes(row, alpha, min_drop)]
    not_tested = {e.name: e.why_not for e in CATALOG.values() if not e.available}
    from .splits import misfit_splits
    return dict(rows=rows, splits=misfit_splits(objective, r, ev.v_fem),
                recommended=recommend(rows, eligible, alpha, min_drop),
                uncertainty=fitted_uncertainty(objective, params, fitted, log_scale, J[:, :k], r, groups),
                eligible=eligible, alpha=alpha, min_drop=min_drop,
                significant=[row["effect"] for row in rows if row["p_value"] < alpha and row["physical"]],
                residual_check=float(np.sqrt(np.mean(r ** 2))), phi=float(ev.phi), phi_vol=float(ev.phi_vol),
                phi_ind=float(ev.phi_ind), not_tested=not_tested, n_directions=len(cols) + k, n_solves=n_solves,
                wall_s=_time.perf_counter() - t0,
                scan="relaxation times over " + ", ".join(f"{v:g}" for v in
                                                            CATALOG["shear_relaxation"].scanned["tau_g1"])
                     + " s; inclusion spheres of radius " + ", ".join(f"{1e3 * v:g}" for v in INCLUSION_RADII_M)
                     + " mm centred on and 5 mm beside the punch axis, " + ", ".join(
                         f"{1e3 * v:g}" for v in INCLUSION_DEPTHS_M) + " mm deep; " + "".join(
                         f"{e.name} at its null and by the secant to " + ", ".join(
                             f"{e.amplitude} = {a:g} {e.unit}" for a in e.secant_points())
                         + f" ({len(e.secant_points())} solve{'s' if len(e.secant_points()) > 1 else ''}); "
                         for e in secants) + "p-values Bonferroni over each effect's scan")


def _secant_solve(objective, params, model, full, fm, e, a, guide=None):
    """The fitted law's solve with the effect `e` at amplitude `a` (`Effect.secant_model`), or
    at its fallbacks where the full size does not solve (`Effect.far_fallback`): (evaluation,
    the amplitude solved, solves made); from the fitted law's solution `guide` if given."""
    tries = [a, *e.far_fallback] if a == e.far else [a]
    for n, a_try in enumerate(tries, 1):
        far = objective.evaluate_model(dict(params), e.secant_model(model, full, a_try, fm),
                                       options=replace(objective.options, rtol=SECANT_RTOL), guide=guide)
        if far.ok:
            break
        log.warning("the %s model at %s = %g %s did not solve (%s): %s", e.name, e.amplitude, a_try, e.unit,
                    far.message[:200], f"trying {tries[n]:g}" if n < len(tries) else "not tested there")
    return far, a_try, n


def best_rows(rows) -> dict:
    """Each effect's best diagnosis row (its best scan point): the first of its rows, which are
    in rank order."""
    best = {}
    for r in rows:
        best.setdefault(r["effect"], r)
    return best


def passes(row, alpha=ALPHA, min_drop=MIN_DROP) -> bool:
    """Is the diagnosis `row` worth adding: physical, predicted to remove `min_drop` of Phi_vol
    and significant at `alpha`; or, under a level stricter than `ALPHA` (warped volumes), at
    `ALPHA` with a predicted drop of `STRONG_DROP`. The strict level is there because the
    tracker's error on warped volumes is systematic and passed the nominal level on every warped
    null, but along no effect did it explain more than 2.6 % of Phi_vol (elastic nulls, speckle
    seeds 6-10: 1.4-2.6 % at p 0.003-0.009; SR null seed 13: 1.6 % at p 0.004; the last steps of
    six warped discoveries: at most 2.2 %, p 6e-4). A bonded punch beside bulk relaxation (warped
    Darcy flow + bonded punch, seed 13) was predicted at 11.5 %, p 2.6e-4, and was missed."""
    if not row["physical"] or row["predicted_drop"] < min_drop:
        return False
    return row["p_value"] < alpha or (alpha < ALPHA and row["p_value"] < ALPHA and row["predicted_drop"] >= STRONG_DROP)


def recommend(rows, eligible, alpha=ALPHA, min_drop=MIN_DROP, vetoed=()) -> str:
    """The effect to add, or 'none': the first of `eligible` (those that pass `alpha` with a
    drop of `min_drop`, in rank order), but under a level stricter than `ALPHA` the largest
    predicted drop among the physical, not vetoed rows that pass `ALPHA` with that drop. The
    strict level keeps the null data silent (0 of 4 warped nulls passed it); once an effect
    passes it, the nominal level picks which. On warped strain-stiffening data (neo-Hookean
    base, speckle seeds 13 and 14) strain stiffening was predicted to remove 82 % of Phi_vol at p
    1.6-1.9e-4, a 3.5 mm sphere 61 % at p 1e-67: the sphere was recommended, yet refitted (the
    trials of `discover`, seed 14) strain stiffening removed 96 % of Phi_vol and the sphere 28 %.
    The cluster-robust test is conservative for an effect that acts everywhere. Predicted drops
    that differ by less than `min_drop` (the least drop worth an effect) do not choose: the
    strict level's candidate stays (warped Darcy flow with a bonded punch, seed 13: the quartic
    bulk term at p 4e-4 and bulk relaxation at p 7e-7 were both predicted at 22.4 %; refitted,
    bulk relaxation reached Phi 452, the quartic term 481)."""
    if not eligible:
        return "none"
    if alpha < ALPHA:
        best = best_rows(rows)
        nominal = [r["effect"] for r in rows if passes(r, ALPHA, min_drop) and r["effect"] not in vetoed]
        if nominal and best[nominal[0]]["predicted_drop"] - best[eligible[0]]["predicted_drop"] >= min_drop:
            return nominal[0]
    return eligible[0]


def tracker_and_mesh_error(tracker_error, objective, params: dict, finer=None):
    """The error the inclusion check (`confirm_by_tracker_response`) takes from the tracked
    motion, and which mesh's response it is ("finer mesh" or "tracking mesh"): with `finer` (a
    function returning the same law's objective on a finer model mesh), the tracker's response
    to the finer mesh's motion less `objective`'s prediction, so the tracker's error and the
    tracking mesh's discretization error together; `objective`'s own response without it, or
    where the finer model does not solve. The warped neo-Hookean nulls' softer sphere under the
    punch is the coarse mesh's: seed 14, p 9e-27 on the tracked motion, 8.6e-25 less the coarse
    mesh's response, 1 less the medium mesh's."""
    if finer is not None:
        try:
            return tracker_error(finer(), params, predicted_by=objective), "finer mesh"
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as e:
            log.warning("the tracker's response to the finer mesh's motion failed (%s): the tracking mesh's "
                        "own response is used", e)
    return tracker_error(objective, params), "tracking mesh"


def checked_by_tracker_response(d: dict) -> list:
    """The effects of the diagnosis `d` that `confirm_by_tracker_response` tests again: every
    effect that passes its test, and each geometric effect (an inclusion) that is significant.
    Until session 39 an effect predicted to remove `STRONG_DROP` or more was not checked: on the
    warped nulls of 31 volumes the tracker's error had explained at most 2.6 % of Phi_vol along
    any effect (`passes`). On the warped elastic null of 100 volumes with `synthesize`'s
    noise-free record (speckle seed 50) punch friction passed at 8.9 % (p 0.0033) and the
    quartic bulk term at 8.85 % (p 2.9e-4), unchecked; the trials added the quartic term, whose
    fit on the corrected motion kept it at 4.3 SD. Checked, friction passes on the finer mesh's
    response (p 8e-6) but not on the tracking mesh's (p 0.56), the quartic term not on the finer
    mesh's (p 0.0019, 1.1 %), and nothing is recommended. A true effect stays in the corrected
    motion whatever its size (the response is the model's, not the data's); on the recorded
    true effects of warped data the check passed them all (docs/diagnosis.md, session 39)."""
    return [e for e in dict.fromkeys(d["eligible"] + d["significant"]) if CATALOG[e].geometric or e in d["eligible"]]


def confirm_by_tracker_response(d: dict, objective, params: dict, fitted: list, log_scale, tracker_error,
                                alpha=ALPHA, min_drop=MIN_DROP, finer=None) -> dict:
    """The diagnosis `d` with each effect of `checked_by_tracker_response` (an inclusion that
    passes its test or is significant, a small effect that passes) tested again on the tracked
    motion less the tracker's own error at the fit, and dropped (`vetoed`) when it does not pass
    there.

    `finer`: a function returning the fitted law's objective on a finer model mesh, whose
    motion the tracker's response is then taken to (`tracker_and_mesh_error`; the tracker
    check's `response_mesh` says which mesh's was used); an effect that passes there must pass
    on the tracking mesh's own response too. Data made on the tracking mesh itself (as a user of
    `synthesize` may make them) have none of the finer mesh's difference from it, and that
    response puts the difference into the corrected motion: on the warped elastic null of seed
    43 with its truth on the coarse benchmark mesh, a 2.1x stiffer 3.5 mm sphere beside the
    punch passed at p 5e-137 (14.8 % of the corrected Phi_vol) on the finer (medium) mesh's
    response and was added; the final fit, on the tracking mesh, withdrew it.
    `tracker_error(objective, params)`: the tracker's response to the fitted model's motion
    less the observation operator's prediction of it (`identify.response.tracker_error`: the
    first volume warped by the model's motion and tracked with the flow's options). That error
    is the model's, not the data's: an effect in the tissue stays in the corrected motion, a
    pattern of the tracker's leaves it. Made for warped volumes, where the response is the data's
    own physics: on warped Darcy-flow data (speckle seed 11) the PE fit's diagnosis passed a 3.3x
    stiffer 3.5 mm sphere 6 mm under the punch (predicted drop 3.6 %, p 1e-8) that is not in the
    truth (refitted, its Phi_vol went below the truth's own: 34.7 against 39.3); on the corrected
    motion it had p 0.0057. A true 10x sphere passed both (p 1e-22, then 1e-17). The check costs
    the response (one plain solve, the warp and the tracking of every volume: 43 s for 100
    volumes on the coarse benchmark mesh, session 41) and one solve with the effect's directions
    per effect checked."""
    geo = checked_by_tracker_response(d)
    if not geo or d["recommended"] == "none":
        return d
    from ..identify.response import with_corrected_data
    t0 = _time.perf_counter()
    error, response_mesh = tracker_and_mesh_error(tracker_error, objective, params, finer)
    n_solves = 1

    def test(e, corrected, where):
        # measured against the corrected Phi_vol, the check's own solve's
        again = diagnose(corrected, params, fitted, log_scale, None, effects=[e], alpha=alpha, min_drop=min_drop)
        row = again["rows"][0]
        return dict(p_value=row["p_value"], predicted_drop=row["predicted_drop"], estimate=row["estimate"],
                    passes=again["recommended"] == e, response_mesh=where, phi_vol_corrected=again["phi_vol"])
    corrected = with_corrected_data(objective, error)
    check = {e: test(e, corrected, response_mesh) for e in geo}
    n_solves += len(geo)
    passed = [e for e in geo if check[e]["passes"]]
    if passed and response_mesh == "finer mesh":
        # data made on the tracking mesh itself have none of the finer mesh's difference from it,
        # and the finer mesh's response puts that difference in the corrected motion (the coarse
        # mesh is stiffer at the punch rim): an effect must pass on the tracking mesh's response too
        corrected = with_corrected_data(objective, tracker_error(objective, params))
        n_solves += 1 + len(passed)
        for e in passed:
            again = test(e, corrected, "tracking mesh")
            check[e] = dict(check[e], passes=again["passes"], tracking_mesh=again)
        response_mesh = "finer mesh, then tracking mesh"
    vetoed = {}
    for e, c in check.items():
        if not c["passes"]:
            c = c.get("tracking_mesh", c)
            vetoed[e] = (f"not on the tracked motion less the tracker's own error at the fit ({c['response_mesh']}'s "
                         f"response; p = {c['p_value']:.2g}, predicted drop {100 * c['predicted_drop']:.1f} % "
                         "there): taken for the tracker's (or, with a finer mesh's response, the tracking mesh's)")
    eligible = [e for e in d["eligible"] if e not in vetoed]
    return dict(d, eligible=eligible, significant=[e for e in d["significant"] if e not in vetoed],
                recommended=recommend(d["rows"], eligible, alpha, min_drop, vetoed), vetoed=vetoed,
                tracker_check=dict(effects=check, phi_vol_corrected=check[geo[-1]]["phi_vol_corrected"],
                                   wall_s=_time.perf_counter() - t0, response_mesh=response_mesh),
                n_solves=d["n_solves"] + n_solves,     # the responses' solves, the checks
                wall_s=d["wall_s"] + _time.perf_counter() - t0)


def fitted_uncertainty(objective, params, fitted, log_scale, J, r, groups) -> dict:
    """The fitted parameters' standard deviations (SI) and relative ones, and whether the data
    determine them, from the diagnosis solve's own sensitivities `J` (columns: the fitted
    parameters in the fit's normalization, log10 for log-scaled ones): the Gauss-Newton
    covariance of the fit file (`identify.uncertainty`), cluster-robust over `groups` for the
    likelihood, at no extra solve."""
    from ..identify.uncertainty import gauss_newton
    unc = gauss_newton(J, r, objective.M, np.asarray(log_scale, bool),
                       groups=groups if getattr(objective, "noise", None) is not None else None)
    value = np.array([float(params[n]) for n in fitted])
    sd_x = np.sqrt(np.clip(np.diag(unc["cov_x"]), 0, None))
    sd = np.where(log_scale, np.abs(value) * np.log(10.0) * sd_x, sd_x)
    return dict(sd={n: float(v) for n, v in zip(fitted, sd)},
                rel_sd={n: float(v) for n, v in zip(fitted, unc["rel_sd"])},
                determined={n: bool(v) for n, v in zip(fitted, unc["determined"])}, cond=float(unc["cond"]))


def refine_inclusion(objective, params, fitted, log_scale, phi_vol, estimate, step=2.5e-3) -> dict:
    """The inclusion's sphere on a grid 2.5 mm finer around the scan's best (27 centres, radii
    0.8 and 1 times its radius), from one more solve: the estimate of the best of them. (Its
    p-value is not reported: the refinement selects on the coarse scan's result.)"""
    c, r = np.asarray(estimate["inclusion_center_m"]), float(estimate["inclusion_radius_m"])
    grid = [{"center_m": list(c + step * np.array([i, j, k])), "radius_m": rr}
            for rr in (0.8 * r, r) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]
    # the coarse scan's rules hold here too: moved 2.5 mm up, a sphere under the punch reached the
    # top face (warped PSR data, seed 7: a 7x stiffer sphere 0 mm below the footprint was added)
    grid = [g for g in grid if sphere_allowed(objective.forward.mesh, g)]
    if not grid:
        return estimate
    d = diagnose(objective, params, fitted, log_scale, phi_vol, effects=["inclusion"], scans={"inclusion": grid})
    return d["rows"][0]["estimate"] or estimate


def _cluster_variance(Z, r, g_idx):
    """The cluster-robust variance of each column's score z'r: sum over the residual groups
    g of (z_g' r_g)^2."""
    G = np.zeros((g_idx.max() + 1, Z.shape[1]))
    np.add.at(G, g_idx, Z * r[:, None])
    return np.einsum("gj,gj->j", G, G)


def _design_effect(X, r, g_idx) -> float:
    """The cluster-robust variance of the scores of the fitted directions X over the variance
    they would have with independent residuals, sum_g (X_g' r_g)^2 / (sigma^2 X'X), averaged
    over them (at least 1)."""
    if X.shape[1] == 0:
        return 1.0
    ratio = _cluster_variance(X, r, g_idx) / (float(r @ r / r.size) * np.einsum("ij,ij->j", X, X))
    return float(max(1.0, np.mean(ratio)))


def _held_already(fm) -> set:
    """Boundary effects the model's own contact already has in full."""
    return ({"punch_friction"} if fm.punch == "bonded" else set()) | ({"bottom_slip"} if fm.support != "fixed" else set())


def _where(objective, z, n_vol):
    """Where in space and time the effect changes the motion: its squared sensitivity's
    shares by region (under the punch, rim, far field) and by time window (loading,
    unloading), in plain words."""
    d = objective.data
    K, N = objective.K, objective.N
    zv = z[:n_vol].reshape(K, N, 3) ** 2
    total = zv.sum()
    if total <= 0:
        return "acts on the indenter record only"
    X = objective.forward.mesh.points if d.X is None else np.asarray(d.X)
    r = np.hypot(X[:, 0], X[:, 1])
    a = 0.006
    region = {"under the punch": r < a, "near the rim": (r >= a) & (r < 2 * a), "far field": r >= 2 * a}
    tm = 0.5 * (d.t0 + d.t1)
    t_rev = objective.t_drive[np.argmax(objective.d_drive)] if hasattr(objective, "d_drive") else tm.max()
    window = {"loading": tm <= t_rev, "unloading": tm > t_rev}
    by_region = {k: float(zv[:, m].sum() / total) for k, m in region.items()}
    by_time = {k: float(zv[m].sum() / total) for k, m in window.items()}
    r_top = max(by_region, key=by_region.get)
    t_top = max(by_time, key=by_time.get)
    return (f"{100 * by_region[r_top]:.0f} % {r_top}, {100 * by_time[t_top]:.0f} % in the {t_top} "
            f"({json.dumps({**{k: round(v, 3) for k, v in by_region.items()}, **{k: round(v, 3) for k, v in by_time.items()}})})")
