"""The fit file: an xarray Dataset with the evaluation history, the best parameters, the
misfit components, residuals and model velocities at the optimum, uncertainty, provenance."""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..fileio import provenance
from ..laws import PARAMS
from .optimize import Fit
from .uncertainty import gauss_newton

__all__ = ["fit_dataset"]


def fit_dataset(fit: Fit, result: dict, jacobian=None, attrs=None) -> xr.Dataset:
    names = fit.names
    hist = [r for r in fit.history]
    n = len(hist)
    P = np.array([[r["params"][k] for k in names] for r in hist]) if n else np.zeros((0, len(names)))
    best = result["best"]
    x_best = np.asarray(best["x"]) if best else result["x"]
    ev = fit.obj(fit.params_of(x_best))  # the optimum once more: residuals and velocities
    if jacobian is None:
        jacobian, _ = fit.fd_jacobian(x_best, purpose="uncertainty", fd_purpose="uncertainty")
    unc = gauss_newton(jacobian, ev.residual, fit.obj.M, fit.log_scale)
    units = [PARAMS[k].unit for k in names]
    ds = xr.Dataset(
        data_vars=dict(
            best=("param", [ev.params[k] for k in names], {"long_name": "identified parameters (SI)"}),
            start=("param", [fit.start[k] for k in names]),
            param_unit=("param", units),
            history_params=(("evaluation", "param"), P),
            history_phi=("evaluation", [r["phi"] for r in hist], {"units": "m^2/s^2"}),
            history_phi_vol=("evaluation", [r["phi_vol"] for r in hist], {"units": "m^2/s^2"}),
            history_phi_ind=("evaluation", [r["phi_ind"] for r in hist], {"units": "m^2/s^2"}),
            history_ok=("evaluation", np.array([bool(r["ok"]) for r in hist])),
            history_wall_s=("evaluation", [r["wall_s"] for r in hist], {"units": "s"}),
            history_purpose=("evaluation", [r["purpose"] for r in hist]),
            phi=((), ev.phi, {"units": "m^2/s^2"}),
            phi_vol=((), ev.phi_vol, {"units": "m^2/s^2"}),
            phi_ind=((), ev.phi_ind, {"units": "m^2/s^2"}),
            rms_depth=((), ev.rms_depth, {"units": "m", "long_name": "RMS indenter displacement error"}),
            rms_axial=((), ev.rms_axial, {"units": "m", "long_name": "RMS axial nodal displacement error"}),
            residual=("residual_index", ev.residual),
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
                          **(attrs or {}))
    return ds
