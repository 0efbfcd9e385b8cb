"""`liverinv diagnose`: which physical effect is missing from a fit (score tests at each
candidate effect's null value, from one forward solve with sensitivities)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def register(sub):
    p = sub.add_parser("diagnose", help="rank the physical effects missing from a fitted law", description=__doc__)
    p.add_argument("--fit", type=Path, required=True, help="fit file (liverinv fit)")
    p.add_argument("--bundle", type=Path, required=True)
    p.add_argument("--flow", type=Path, required=True)
    p.add_argument("--mesh", type=Path, required=True, help="tracking mesh")
    p.add_argument("--model-mesh", type=Path, help="forward-model mesh (default: the fit's)")
    p.add_argument("--observation", choices=["nodes", "tracker"], help="default: the fit's")
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5], default=2)
    p.add_argument("--effects", nargs="+", help="candidates (default: every available effect the law lacks)")
    p.add_argument("--out", type=Path, required=True, help="DIAG.nc")
    p.add_argument("--figures", type=Path, help="folder for the diagnosis figure")
    p.set_defaults(func=run)


def objective_of_fit(fit, bundle, flow, mesh, model_mesh=None, observation=None, quadrature_order=2):
    """The objective a fit file was fitted with (its law, fixed values, objective, noise levels
    after the balance stage, observation, model mesh), and the fit's best parameters."""
    from ..cli import UserError
    from ..identify.setup import objective_from_files
    import xarray as xr
    if not Path(fit).is_file():
        raise UserError(f"{fit}: fit file not found")
    with xr.open_dataset(fit, engine="h5netcdf") as ds:
        ds = ds.load()
    if ds.attrs.get("status") == "failed" or "best" not in ds:
        raise UserError(f"{fit}: the fit failed ({ds.attrs.get('error', 'no result')}): nothing to diagnose")
    law = ds.attrs["law"]
    fixed = json.loads(ds.attrs.get("fixed") or "{}")
    noise = json.loads(ds.attrs["noise"]) if ds.attrs.get("noise") else None
    mm = model_mesh or (ds.attrs.get("model_mesh") if ds.attrs.get("model_mesh") not in (None, "", str(mesh)) else None)
    obj, _ = objective_from_files(bundle, flow, mesh, law, fixed, mm, ds.attrs.get("objective", "likelihood"),
                                  observation or ds.attrs.get("observation") or None,
                                  noise and noise["force_N"], noise and noise["depth_m"], noise and noise["tracking_m"],
                                  quadrature_order, inclusions=json.loads(ds.attrs.get("inclusions") or "[]"))
    params = {str(k): float(v) for k, v in zip(ds.param.values, ds.best.values)}
    return obj, params, ds


def finer_objective(args, obj):
    """A function returning the fit's objective on a finer model mesh (the medium preset of
    the model's cylinder, written beside --out, as `discover --final-mesh auto`), for the
    inclusion check on warped volumes (`score.tracker_and_mesh_error`); the function raises
    ValueError (and the check takes the tracking mesh's own response) when the model mesh is
    not a cylinder or is already at least as fine."""
    from ..meshgen import refined_model_mesh

    path = args.out.with_name(args.out.stem + "_model_mesh.msh")

    def finer():
        made, note = refined_model_mesh(obj.forward.mesh, path)
        if made is None:
            raise ValueError(note)
        return objective_of_fit(args.fit, args.bundle, args.flow, args.mesh, made, args.observation,
                                args.quadrature_order)[0]
    return finer


def run(args) -> int:
    from ..cli import UserError
    from ..diagnose.files import diagnosis_dataset, explain, imaging_calibration, tracker_error_for
    from ..diagnose.score import confirm_by_tracker_response, diagnose
    from ..diagnose.splits import SPLIT_MEANING
    from ..fileio import write_netcdf
    from ..laws import PARAMS

    obj, params, ds = objective_of_fit(args.fit, args.bundle, args.flow, args.mesh, args.model_mesh,
                                       args.observation, args.quadrature_order)
    names = list(params)
    calibration = imaging_calibration(args.bundle)
    try:
        log_scale = [PARAMS[n].scale == "log" for n in names]
        d = diagnose(obj, params, names, log_scale, float(ds.phi_vol), args.effects, alpha=calibration["alpha"])
        if calibration["confirm_geometric"]:
            d = confirm_by_tracker_response(d, obj, params, names, log_scale,
                                            tracker_error_for(args.bundle, args.flow, args.mesh),
                                            alpha=calibration["alpha"], finer=finer_objective(args, obj))
    except (ValueError, KeyError) as e:
        raise UserError(str(e)) from None
    caveat = calibration["caveat"]
    out = diagnosis_dataset(d, fit=str(args.fit), base_law=obj.law, fit_phi_vol=float(ds.phi_vol), caveat=caveat)
    write_netcdf(out, args.out)
    if args.figures:
        from ..diagnose.figures import plot_diagnosis
        plot_diagnosis(out, args.figures / "diagnosis.png")
    for split, parts in d.get("splits", {}).items():
        print(f"{SPLIT_MEANING.get(split, 'Phi_vol')} by {split}: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in parts.items()))
    print(explain(d))
    if caveat:
        print(f"warning: {caveat}", file=sys.stderr)
    print(f"wrote {args.out}: recommended {d['recommended']} ({d['wall_s']:.1f} s, {d['n_directions']} directions "
          f"in one solve); not tested: {', '.join(d['not_tested'])}")
    return 0
