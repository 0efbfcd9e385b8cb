"""The tracked motion corrected by the tracker's response to the fitted model's own motion.

At a fit's parameters p, `imaging.response.tracker_response` renders the bundle's first volume
warped by the model's displacement and tracks it: R(p). The objective's observation operator
predicts O(p) for the same motion. Their difference e = R(p) - O(p) is the operator's error at
that motion. Since the objective compares the data u_OF with O(.), subtracting e from the data
is the same as adding it to the operator: at p the observation is then the tracker itself, and
to first order near p (e changes slowly with the parameters). The fit is then continued from p
on the corrected data.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ..fem.solver import solve_history
from .objective import Objective

log = logging.getLogger(__name__)

__all__ = ["tracker_error", "with_corrected_data"]


def tracker_error(objective: Objective, params: dict, bundle, flow, tracking_mesh) -> np.ndarray:
    """(K, N, 3) m: the tracker's response to the model's motion at `params` minus the
    observation operator's prediction of it, frame pair by frame pair."""
    from ..imaging.response import tracker_response

    if objective.data.u_of.shape[0] != flow.sizes["frame"]:
        raise ValueError("the objective's frame pairs are not the flow's (merged pairs?)")
    model = objective.forward.model(objective.law, {**params, **objective.fixed})
    h = solve_history(model, objective.t_drive, objective.f_drive, objective.control, objective.options)
    d = objective.data
    u = np.asarray(h.u)
    at_frames = objective.model_motion(objective.t_drive, u)[1]           # linear in time, as the objective
    response = tracker_response(bundle, flow, tracking_mesh, objective.forward.mesh,
                                at_frames(np.concatenate([d.t0[:1], d.t1])))
    predicted = objective.model_motion(objective.t_drive, objective.at_data_nodes(u))[0] * (d.t1 - d.t0)[:, None, None]
    return response - predicted


def with_corrected_data(objective: Objective, error: np.ndarray) -> Objective:
    """The same objective on the tracked motion less the tracker's error `error` (K, N, 3)."""
    data = dataclasses.replace(objective.data, u_of=objective.data.u_of - error)
    return Objective(objective.forward, objective.law, data, objective.fixed, objective.options,
                     objective.confidence_floor, objective.outside_tol, objective.observation, objective.noise)
