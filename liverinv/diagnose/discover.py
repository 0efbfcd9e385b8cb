"""Add the missing effect and watch the error fall: base fit, diagnose, add the recommended
effect (warm-started from the fit and the effect's one-step estimate), refit, until nothing is
recommended.

Every step is fitted with the same noise levels (those of the base fit after its balance
stage), so its Phi, Phi_vol and Phi_ind fall on one scale from step to step. A nested-model
test accompanies each addition: the likelihood-ratio statistic Phi_before - Phi_after against
chi^2 with the added free parameters, and AIC/BIC differences (Phi is -2 log L up to a constant).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy import stats

from ..identify.balance import balanced_fit
from ..identify.optimize import Fit
from ..laws import PARAMS, get_law
from .effects import law_with
from .score import diagnose

__all__ = ["discover", "fit_law"]

log = logging.getLogger(__name__)


def _needs_multistart(law):
    return bool({"g1", "k1"} & set(get_law(law).free))


def fit_law(objective, start, design_points=None, max_evaluations=100, balance=False, progress=None):
    """Least squares of `objective.law` from `start` (with the multi-start stage for laws with
    relaxation terms, which have several minima); balanced first if asked. (fit, result)."""
    n_design = (8 if _needs_multistart(objective.law) else 0) if design_points is None else design_points

    def run(fit, x0):
        if x0 is not None:
            return fit.least_squares(max_evaluations=max_evaluations, x0=x0)
        if n_design > 0:
            return fit.multistart(n_design, 1, max_evaluations=max_evaluations, probe_evaluations=6)
        return fit.least_squares(max_evaluations=max_evaluations)

    if balance:
        return balanced_fit(objective, start, run, progress=progress)
    fit = Fit(objective, start, progress=progress)
    return fit, run(fit, None)


def _clip_start(law, p):
    out = {}
    for k in get_law(law).free:
        if k in p:
            lo, hi = PARAMS[k].lower, PARAMS[k].upper
            v = float(p[k])
            out[k] = min(max(v, lo + 1e-6 * (hi - lo) if PARAMS[k].scale == "linear" else max(lo, 1e-12) * 1.01),
                         hi - 1e-3 * (hi - lo) if PARAMS[k].scale == "linear" else hi / 1.01)
    return out


def discover(objective_for, base_law, start=None, max_steps=3, progress=None) -> dict:
    """`objective_for(law, fixed, noise)` builds the objective of a law on the data (noise None:
    the data's own levels); `progress(rec)` is called after every forward solve of the fits.
    Returns the steps (law, added effect, fit and diagnosis figures)."""
    obj = objective_for(base_law, {}, None)
    law = get_law(base_law)
    start = {k: v for k, v in (start or law.defaults).items() if k in law.free}
    fit, res = fit_law(obj, start, balance=obj.noise is not None, progress=progress)
    noise = fit.obj.noise
    obj = fit.obj
    steps = []
    current_law, fixed, added = base_law, {}, []
    params = res["best"]["params"]
    rec = res["best"]
    stopped = f"reached --max-steps {max_steps}"
    for step in range(max_steps + 1):
        d = diagnose(obj, params, fit.names, fit.log_scale, rec["phi_vol"])
        steps.append(dict(step=step, law=current_law, fixed=dict(fixed), added=added[-1] if added and step else "",
                          params={**params, **fixed}, phi=rec["phi"], phi_vol=rec["phi_vol"], phi_ind=rec["phi_ind"],
                          n_free=len(fit.names), n_solves=len(fit.history), diagnosis=d,
                          n_residuals=int(obj.n_residuals)))
        if d["recommended"] == "none":
            stopped = "no candidate effect is worth its parameters (nothing recommended)"
            break
        if step == max_steps:
            break
        effect = d["recommended"]
        row = next(r for r in d["rows"] if r["effect"] == effect)
        added.append(effect)
        new_law, new_fixed = law_with(base_law, added)
        guess = {**params, **{k: v for k, v in fixed.items()}, **row["estimate"]}
        guess = {k: v for k, v in guess.items() if k not in new_fixed}
        guess = _clip_start(new_law, {**get_law(new_law).defaults, **guess})
        obj = objective_for(new_law, new_fixed, noise)
        fit, res = fit_law(obj, guess, design_points=0, progress=progress)
        if res["best"] is None:
            stopped = f"the refit with {effect} failed"
            break
        rec, params = res["best"], res["best"]["params"]
        current_law, fixed = new_law, new_fixed
        prev = steps[-1]
        dof = len(fit.names) - prev["n_free"]
        lr = prev["phi"] - rec["phi"]
        n = obj.n_residuals
        steps[-1]["next"] = dict(lr=lr, dof=dof, p_lr=float(stats.chi2.sf(max(lr, 0.0), max(dof, 1))),
                                 d_aic=-lr + 2 * dof, d_bic=-lr + dof * np.log(n),
                                 actual_drop_vol=(prev["phi_vol"] - rec["phi_vol"]) / prev["phi_vol"],
                                 predicted_drop_vol=row["predicted_drop"])
    return dict(steps=steps, stopped_because=stopped, noise=noise.to_json() if noise is not None else "")
