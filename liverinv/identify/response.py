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

__all__ = ["tracker_error", "with_corrected_data", "continue_on_tracker_response"]


def tracker_error(objective: Objective, params: dict, bundle, flow, tracking_mesh, predicted_by=None) -> np.ndarray:
    """(K, N, 3) m: the tracker's response to the model's motion at `params` minus the
    observation operator's prediction of it, frame pair by frame pair. With `predicted_by`
    (the same law and data on another model mesh, usually the tracking mesh, where `objective`
    is on a finer one), the prediction is that objective's: the error then holds the tracker's
    error and the coarser mesh's discretization error together."""
    from ..imaging.response import tracker_response

    if objective.data.u_of.shape[0] != flow.sizes["frame"]:
        raise ValueError("the objective's frame pairs are not the flow's (merged pairs?)")
    u = _motion(objective, params)
    d = objective.data
    at_frames = objective.model_motion(objective.t_drive, u)[1]           # linear in time, as the objective
    response = tracker_response(bundle, flow, tracking_mesh, objective.forward.mesh,
                                at_frames(np.concatenate([d.t0[:1], d.t1])))
    if predicted_by is not None:
        objective, u = predicted_by, _motion(predicted_by, params)
    predicted = objective.model_motion(objective.t_drive, objective.at_data_nodes(u))[0] * (d.t1 - d.t0)[:, None, None]
    return response - predicted


def _motion(objective: Objective, params: dict) -> np.ndarray:
    """The model's nodal motion (time, node, 3) at `params` over the objective's drive."""
    model = objective.forward.model(objective.law, {**params, **objective.fixed})
    return np.asarray(solve_history(model, objective.t_drive, objective.f_drive, objective.control, objective.options).u)


def with_corrected_data(objective: Objective, error: np.ndarray) -> Objective:
    """The same objective on the tracked motion less the tracker's error `error` (K, N, 3)."""
    return objective.with_measurements(dataclasses.replace(objective.data, u_of=objective.data.u_of - error))


def continue_on_tracker_response(objective: Objective, fit, result: dict, bundle_path, flow_path, mesh_path, *,
                                 jacobian: str = "sensitivity", max_evaluations: int = 100, checkpoint=None,
                                 progress=None, binding=None):
    """The least-squares fit `fit` (with its `result`) continued from its optimum on the tracked
    motion less the tracker's error there, from `objective`'s own noise levels and then, for the
    likelihood, with the balance stage on the corrected motion (balanced on the uncorrected
    motion, the field's noise level had absorbed the operator's error: 3-4x on the Table 1 setup,
    against 0.18x after the correction). Returns (fit, result, record of the first stage)."""
    import xarray as xr

    from ..imaging.bundle import open_bundle
    from ..mesh import read_mesh
    from .balance import balanced_fit
    from .optimize import Fit

    if objective.observation is None:
        raise ValueError("the tracker response corrects the tracking observation operator; "
                         "this objective compares the motion at the nodes (use observation 'tracker')")
    first = result["best"]
    params = {k: first["params"][k] for k in fit.names}
    with open_bundle(bundle_path) as b:
        err = tracker_error(fit.obj, params, b, xr.load_dataset(flow_path, engine="h5netcdf"),
                            read_mesh(mesh_path, required=()))
    corrected = with_corrected_data(objective, err)
    stage_binding = {**(binding or {}), "tracker_response_from": params, "stage": "balanced on the corrected motion"}

    def run(f, x0):
        return f.least_squares(max_evaluations=max_evaluations, x0=x0, jacobian=jacobian)
    if corrected.noise is not None:
        fit2, result2 = balanced_fit(corrected, params, run, checkpoint=checkpoint, progress=progress,
                                     binding=stage_binding)
    else:
        fit2 = Fit(corrected, params, checkpoint=checkpoint, progress=progress, binding=stage_binding)
        result2 = run(fit2, None)
    record = dict(first_stage={k: float(v) for k, v in params.items()}, first_stage_phi=float(first["phi"]),
                  first_stage_solves=len(fit.history), error_rms_m=float(np.sqrt(np.mean(err ** 2))))
    return fit2, result2, record
