"""The fit file: an xarray Dataset with the evaluation history, the best parameters, the
misfit components, residuals and model velocities at the optimum, uncertainty, provenance."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from ..fileio import provenance
from ..laws import PARAMS, reading_notes
from .optimize import Fit
from .uncertainty import gauss_newton

__all__ = ["fit_dataset", "fit_warnings"]

INDENTER_EXCESS = 2.0   # warn when the indenter residual's RMS exceeds its noise level this much
FAILED_SHARE = 0.1      # warn when at least this share of the forward solves (and 2) did not converge


def fit_dataset(fit: Fit, result: dict, jacobian=None, attrs=None) -> xr.Dataset:
    names = fit.names
    hist = [r for r in fit.history]
    n = len(hist)
    P = np.array([[r["params"][k] for k in names] for r in hist]) if n else np.zeros((0, len(names)))
    best = result["best"]
    x_best = np.asarray(best["x"]) if best else result["x"]
    # the optimum once more: residuals and velocities (with sensitivities where the fit used
    # them: the same solve as the recorded one, and the Jacobian at the optimum itself)
    if fit._sensitive and best is not None and best.get("jacobian") is not None:
        ev, steps = fit.solve_with_jacobian(x_best)
        jacobian = ev.jacobian * np.sign(steps)
    else:
        ev = fit.obj(fit.params_of(x_best))
    if jacobian is None:
        jacobian, _ = fit.fd_jacobian(x_best, purpose="uncertainty", fd_purpose="uncertainty")
    noise = getattr(fit.obj, "noise", None)
    labels = fit.obj.residual_groups()          # also kept: laws are compared on them (pipeline.compare)
    if labels.size != ev.residual.size:
        raise RuntimeError(f"{labels.size} residual groups for {ev.residual.size} residuals")
    groups = labels if noise is not None else None
    unc = gauss_newton(jacobian, ev.residual, fit.obj.M, fit.log_scale, groups=groups)
    units = [PARAMS[k].unit for k in names]
    # the misfit at the first stage's noise levels (the sensor's and the flow's estimate, the
    # same for every law on the same data): the balanced levels are each fit's own
    a_vol = a_ind = 1.0
    stages = result.get("stages") or []
    if len(stages) == 2:
        a_vol = stages[1]["tracking_m"] / stages[0]["tracking_m"]
        a_ind = stages[1]["force_N"] / stages[0]["force_N"]
    common = {"long_name": "misfit at the first stage's noise levels: comparable between laws on the same data"}
    phi_units = "1" if noise is not None else "m^2/s^2"
    search = result.get("search") or {}     # a multi-start stage on merged frame pairs (identify.search)
    ds = xr.Dataset(
        data_vars=dict(
            best=("param", [ev.params[k] for k in names], {"long_name": "identified parameters (SI)"}),
            start=("param", [fit.start[k] for k in names]),
            param_unit=("param", units),
            history_params=(("evaluation", "param"), P),
            history_phi=("evaluation", [r["phi"] for r in hist], {"units": phi_units}),
            history_phi_vol=("evaluation", [r["phi_vol"] for r in hist], {"units": phi_units}),
            history_phi_ind=("evaluation", [r["phi_ind"] for r in hist], {"units": phi_units}),
            history_ok=("evaluation", np.array([bool(r["ok"]) for r in hist])),
            history_wall_s=("evaluation", [r["wall_s"] for r in hist], {"units": "s"}),
            history_purpose=("evaluation", [r["purpose"] for r in hist]),
            phi=((), ev.phi, {"units": phi_units}),
            phi_vol=((), ev.phi_vol, {"units": phi_units}),
            phi_ind=((), ev.phi_ind, {"units": phi_units}),
            phi_vol_common=((), ev.phi_vol * a_vol ** 2, {"units": phi_units, **common}),
            phi_ind_common=((), ev.phi_ind * a_ind ** 2, {"units": phi_units, **common}),
            phi_common=((), ev.phi_vol * a_vol ** 2 + ev.phi_ind * a_ind ** 2, {"units": phi_units, **common}),
            rms_depth=((), ev.rms_depth, {"units": "m", "long_name": "RMS indenter displacement error"}),
            rms_axial=((), ev.rms_axial, {"units": "m", "long_name": "RMS axial nodal displacement error"}),
            rms_force=((), getattr(ev, "rms_force", np.nan), {"units": "N", "long_name": "RMS indenter force error"}),
            n_vol=((), int(np.count_nonzero(fit.obj._w_vol)), {"long_name": "volumetric residuals that carry data"}),
            n_ind=((), int(fit.obj.M), {"long_name": "indenter residuals"}),
            at_bound=("param", fit.at_bound(x_best)),
            residual=("residual_index", ev.residual),
            residual_group=("residual_index", np.unique(labels, return_inverse=True)[1].ravel().astype(np.int32),
                            {"long_name": "cluster of the residual row: a 12 mm cube of tracked nodes with all "
                                          "its frames, or 0.25 s of the indenter record (Objective.residual_groups)"}),
            model_time=("drive", ev.model_time, {"units": "s", "long_name": "driving times of the model"}),
            model_depth=("drive", ev.model_depth, {"units": "m", "long_name": "model indenter depth at the optimum"}),
            model_force=("drive", ev.model_force, {"units": "N", "long_name": "model indenter force at the optimum"}),
            v_fem=(("frame", "node", "component"), ev.v_fem, {"units": "m/s", "long_name": "model nodal velocity at the optimum"}),
            cov_x=(("param", "param2"), unc["cov_x"], {"long_name": "covariance of normalized parameters (log10 for log-scaled)"}),
            corr=(("param", "param2"), unc["corr"]),
            rel_sd=("param", unc["rel_sd"], {"long_name": "relative standard deviation, all data"}),
            rel_sd_indenter_only=("param", unc["rel_sd_indenter_only"], {"long_name": "relative standard deviation, indenter data only"}),
            determined=("param", unc["determined"]),
            determined_by_indenter=("param", unc["determined_by_indenter"]),
        ),
        coords=dict(param=names, param2=names, component=["x", "y", "z"]),
    )
    ds.attrs = provenance(law=fit.obj.law, method=result["method"], message=result["message"],
                          fixed=fit.obj.fixed, n_solves=int(result["n_solves"]),
                          cond=float(unc["cond"]), cond_indenter_only=float(unc["cond_indenter_only"]),
                          objective="likelihood" if noise is not None else "paper",
                          noise=noise.to_json() if noise is not None else "",
                          covariance=(f"cluster-robust over {unc['n_groups']} groups" if groups is not None
                                      else "Gauss-Newton, independent residuals"),
                          search=json.dumps(search),
                          search_solves=int(search.get("n_solves", 0)),
                          search_solve_time_s=float(search.get("solve_time_s", 0.0)),
                          **(attrs or {}))
    ds.attrs["warnings"] = "\n".join(fit_warnings(ds))
    return ds


def parameter_warnings(bound, loose) -> list[str]:
    """The warnings of parameters `bound` (names at a bound of their range) and `loose` ((name,
    relative SD) the data do not determine), with how to read those that have a note
    (`laws.reading_notes`: a bonded punch, a sliding bottom, a sphere's contrast)."""
    out = [f"ended at a bound: {', '.join(bound)}"] if bound else []
    if loose:
        out.append("not determined by the data: " + ", ".join(f"{n} (relative SD {sd:.2g})" for n, sd in loose))
    return out + reading_notes([*bound, *(n for n, _ in loose)])


def fit_warnings(ds) -> list[str]:
    """What a user must know before trusting a fit: parameters at a bound, parameters the
    data do not determine, an indenter residual far above its noise level, many forward solves
    that did not converge (the search's on merged frame pairs included)."""
    names = [str(p) for p in ds.param.values]
    out = parameter_warnings([n for n, b in zip(names, ds.at_bound.values) if b],
                             [(n, sd) for n, sd, ok in zip(names, ds.rel_sd.values, ds.determined.values) if not ok])
    if ds.attrs.get("objective") == "likelihood" and int(ds.n_ind) > 0:
        sigma = json.loads(ds.attrs["noise"])["force_N"]
        ratio = float(ds.rms_force) / sigma
        if ratio > INDENTER_EXCESS:
            out.append(f"indenter force residual RMS {float(ds.rms_force):.3g} N is {ratio:.1f} x its noise "
                       f"level {sigma:.3g} N: the law does not explain the force record")
    search = json.loads(ds.attrs.get("search") or "{}") or {}
    failed = int(np.count_nonzero(~ds.history_ok.values)) + int(search.get("n_failed", 0))
    total = int(ds.sizes.get("evaluation", 0)) + int(search.get("n_solves", 0))
    if failed >= 2 and failed >= FAILED_SHARE * total:
        out.append(f"{failed} of {total} forward solves did not converge (counted as a penalty, so the search "
                   "skipped those parameter sets): soft or nearly incompressible laws converge with the "
                   "14-point rule, --quadrature-order 5")
    return out
