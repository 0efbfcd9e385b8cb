"""Balancing the likelihood's blocks by what their residuals show.

The noise levels of the likelihood objective are set before the fit: the indenter's from
the sensor, the tracking's from the flow with a floor. Tracking errors are correlated in
space and time, so the volumetric block holds far fewer independent pieces of information
than residuals, and a systematic tracking error (the same on every speckle seed) then
outweighs the force record. `balanced_fit` fits once, measures each block's inflation at the
optimum (`uncertainty.block_inflation`: residual variance times the design effect of the
correlation within 12 mm node blocks and 0.25 s record chunks), rescales that block's noise
level by its square root (the force's never below the sensor's) and continues from the
optimum when a level moved by more than `tol`.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from .optimize import Fit
from .uncertainty import block_inflation

__all__ = ["balanced_fit"]

log = logging.getLogger(__name__)


def balanced_fit(objective, start, run, checkpoint=None, progress=None, tol=0.25, binding=None, shared=()):
    """`run(fit, x0)` (an optimizer of `Fit`, from the start when x0 is None) with the
    objective's noise levels, then once more from its optimum with the balanced levels.

    Returns (fit, result) of the last stage; `result["stages"]` lists the noise levels and
    solve counts of each stage. `shared` checkpoints (fits from other starts) serve the first
    stage only: the balanced levels depend on the start."""
    fit = Fit(objective, start, checkpoint=checkpoint, progress=progress, binding=binding, shared=shared)
    result = run(fit, None)
    if objective.noise is None or result["best"] is None:
        return fit, result
    best = result["best"]
    x = np.asarray(best["x"])
    J = best.get("jacobian")
    if J is None:
        J, _ = fit.fd_jacobian(x, purpose="balance", fd_purpose="balance")
    r = best["residual"]
    groups = objective.residual_groups()
    n_vol = objective.v_of.size
    lam_vol = block_inflation(J, r, groups, slice(0, n_vol))
    lam_ind = block_inflation(J, r, groups, slice(n_vol, None))
    noise = objective.noise
    balanced = replace(noise, tracking_m=noise.tracking_m * np.sqrt(lam_vol),
                       force_N=noise.force_N * np.sqrt(max(lam_ind, 1.0)),
                       sources={**noise.sources, "balance": f"inflation vol {lam_vol:.3g}, ind {lam_ind:.3g}"})
    stage1 = dict(tracking_m=noise.tracking_m, force_N=noise.force_N, n_solves=result["n_solves"],
                  inflation_vol=lam_vol, inflation_ind=lam_ind)
    log.info("block inflation at the first optimum: volumetric %.3g, indenter %.3g", lam_vol, lam_ind)
    moved = (abs(np.sqrt(lam_vol) - 1) > tol) or (np.sqrt(max(lam_ind, 1.0)) - 1 > tol)
    if not moved:
        result["stages"] = [stage1]
        return fit, result
    fit2 = Fit(objective.with_noise(balanced), start, checkpoint=checkpoint, progress=progress, tag="balanced",
               binding=binding)
    _carry_over(fit, fit2, n_vol, noise.tracking_m / balanced.tracking_m, noise.force_N / balanced.force_N)
    result2 = run(fit2, x)
    result2["message"] = (f"{result2['message']} (balanced: tracking noise x{np.sqrt(lam_vol):.3g}, force "
                          f"noise x{np.sqrt(max(lam_ind, 1.0)):.3g}, after {result['n_solves']} solves)")
    result2["stages"] = [stage1, dict(tracking_m=balanced.tracking_m, force_N=balanced.force_N,
                                      n_solves=result2["n_solves"] - result["n_solves"])]
    return fit2, result2


def _carry_over(fit, fit2, n_vol, a_vol, a_ind):
    """The first stage's solves in the second stage's units: the blocks only scale, so every
    residual, Jacobian and Phi is rescaled exactly and none is solved again."""
    for rec in fit.history:
        if tuple(rec["key"]) in fit2._used:
            continue
        new = dict(rec)
        if rec["ok"] and rec["residual"] is not None:
            scale = np.ones(len(rec["residual"]))
            scale[:n_vol], scale[n_vol:] = a_vol, a_ind
            new["residual"] = rec["residual"] * scale
            new["jacobian"] = None if rec.get("jacobian") is None else rec["jacobian"] * scale[:, None]
            new["phi_vol"], new["phi_ind"] = rec["phi_vol"] * a_vol ** 2, rec["phi_ind"] * a_ind ** 2
            new["phi"] = new["phi_vol"] + new["phi_ind"]
        fit2._cache[tuple(rec["key"])] = new
        fit2._used.add(tuple(rec["key"]))
        fit2.history.append(new)
