"""Least-squares fits with the multi-start stage searched on merged frame pairs.

A law with relaxation terms has several minima, so its fit starts with a global stage
(`Fit.multistart`: a capped run from the start, Phi at the design points, capped runs from the
best of them). On a long record that stage is most of the cost. When the record has more than
`search_pairs` frame pairs, the stage runs on the pairs merged m = pairs // search_pairs at a
time (`Objective.every`: motion summed, tracking noise times sqrt(m); the forward model takes
about 1/m of the time), and least squares on all frames continues from its best point; the
likelihood's balance stage then runs as usual (`balance.balanced_fit`). The search's solves
are logged in the same checkpoint (tag ``merged-M``), so an interrupted fit replays them, and
reported apart (`result["search"]`), since their Phi is on the merged pairs' scale.
"""

from __future__ import annotations

import time

import numpy as np

from .balance import balanced_fit
from .optimize import Fit

__all__ = ["SEARCH_PAIRS", "merge_factor", "least_squares_fit"]

SEARCH_PAIRS = 30          # longer records are searched on merged frame pairs


def merge_factor(objective, search_pairs=SEARCH_PAIRS) -> int:
    """How many frame pairs the search merges into one (1: none)."""
    return max(1, objective.K // int(search_pairs)) if search_pairs else 1


def least_squares_fit(objective, start, *, design_points=0, polish=2, max_evaluations=100,
                      probe_evaluations=10, jacobian="sensitivity", search_pairs=SEARCH_PAIRS, balance=True,
                      checkpoint=None, progress=None, binding=None, shared=()):
    """Bounded least squares of `objective.law` from `start`: with the multi-start stage when
    `design_points` > 0 (on merged frame pairs for a long record, see the module doc), then
    balanced when the objective is a likelihood and `balance`. `shared`: checkpoint folders of
    fits of the same inputs from other starts, whose solves are read back (`Fit`). Returns
    (fit, result) of the last stage; ``result["search"]`` describes a merged search (None
    without one)."""
    search_pairs = SEARCH_PAIRS if search_pairs is None else search_pairs
    if search_pairs < 0:
        raise ValueError(f"search_pairs must be 0 (no merged search) or positive, not {search_pairs}")
    m = merge_factor(objective, search_pairs) if design_points > 0 else 1
    search = {}

    def run(fit, x0):
        if x0 is not None:      # the balanced stage, from the first optimum
            return fit.least_squares(max_evaluations=max_evaluations, x0=x0, jacobian=jacobian)
        if design_points <= 0:
            return fit.least_squares(max_evaluations=max_evaluations, jacobian=jacobian)
        if m == 1:
            return fit.multistart(design_points, polish, max_evaluations=max_evaluations,
                                  probe_evaluations=probe_evaluations, jacobian=jacobian)
        t0 = time.perf_counter()
        merged = Fit(objective.every(m), fit.start, checkpoint=checkpoint, progress=progress,
                     tag=f"merged-{m}", binding=binding, shared=shared)
        res = merged.multistart(design_points, polish, max_evaluations=max_evaluations,
                                probe_evaluations=probe_evaluations, jacobian=jacobian)
        best = res["best"]
        search.update(frame_pairs_merged=m, n_solves=len(merged.history),
                      n_shared=sum(1 for r in merged.history if r.get("shared_from")),
                      n_failed=sum(not r["ok"] for r in merged.history),
                      solve_time_s=float(sum(r["wall_s"] for r in merged.history)),
                      wall_s=time.perf_counter() - t0, phi=None if best is None else float(best["phi"]),
                      params=None if best is None else {k: float(v) for k, v in best["params"].items()})
        x1 = None if best is None else np.asarray(best["x"])
        fit.follow(merged)
        out = fit.least_squares(max_evaluations=max_evaluations, x0=x1, jacobian=jacobian)
        out["method"] = "least-squares multistart"
        out["message"] = (f"multi-start on frame pairs merged {m} at a time ({len(merged.history)} solves: "
                          f"{res['message']}), then least squares on all frames: {out['message']}")
        return out

    if balance and objective.noise is not None:
        fit, result = balanced_fit(objective, start, run, checkpoint=checkpoint, progress=progress, binding=binding,
                                   shared=shared)
    else:
        fit = Fit(objective, start, checkpoint=checkpoint, progress=progress, binding=binding, shared=shared)
        result = run(fit, None)
    result["search"] = search or None
    return fit, result
