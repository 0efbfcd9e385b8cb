"""`liverinv fit`: identify a law's parameters from a measurement bundle and its tracked flow."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ..cli import UserError
from . import parse_assignments


def register(sub):
    p = sub.add_parser("fit", help="identify material parameters (Nelder-Mead or least squares)",
                       description=__doc__)
    p.add_argument("--bundle", required=True, help="measurement bundle (HDF5) with the indenter record")
    p.add_argument("--flow", required=True, help="tracked nodal motion (liverinv track)")
    p.add_argument("--mesh", required=True, help="the mesh the flow was tracked on")
    p.add_argument("--model-mesh", help="mesh of the forward model, if not --mesh (e.g. one refined at "
                   "the punch rim); its displacement is interpolated at the tracked nodes")
    p.add_argument("--observation", choices=["nodes", "tracker"], default=None,
                   help="compare the model's motion at the tracked nodes (the paper; default of --objective "
                        "paper), or as the tracker would report it (default of --objective likelihood): "
                        "window-averaged with the first volume's gradients, which removes the tracker's "
                        "averaging bias where the motion is peaked (needs the flow's tracking options; "
                        "~15 s to build)")
    p.add_argument("--objective", choices=["likelihood", "paper"], default="likelihood",
                   help="likelihood (default): the model driven by the smoothed measured depth, the force "
                        "and the tracked motion each weighted by its noise level; paper: Eqs. 4-5, driven by "
                        "the raw measured force (exact on noise-free data, biased by sensor noise)")
    p.add_argument("--noise-force", type=float, metavar="N", help="force noise RMS (default: the bundle's, "
                   "else estimated from the record)")
    p.add_argument("--noise-depth", type=float, metavar="M", help="depth noise RMS in m (default: as --noise-force)")
    p.add_argument("--noise-tracking", type=float, metavar="M", help="frame-pair tracking error at confidence "
                   "1, in m (default: estimated from the flow, floored)")
    p.add_argument("--law", required=True)
    p.add_argument("--start", action="append", default=[], metavar="NAME=VALUE", help="start value (repeatable)")
    p.add_argument("--fixed", action="append", default=[], metavar="NAME=VALUE", help="held fixed (repeatable)")
    p.add_argument("--method", choices=["nelder-mead", "least-squares"], default="least-squares")
    p.add_argument("--max-evaluations", type=int, default=None,
                   help="Nelder-Mead: forward solves; least squares: residual evaluations per run")
    p.add_argument("--design-points", type=int, default=0, metavar="N",
                   help="least squares with a global stage (laws with several minima, e.g. SR): short "
                        "runs from the start and from the --polish best of N Sobol design points over the "
                        "parameters' search ranges, then the best run continued to convergence")
    p.add_argument("--polish", type=int, default=2, help="design points polished by least squares")
    p.add_argument("--probe-evaluations", type=int, default=10,
                   help="residual evaluations of each least-squares run before the best is continued")
    p.add_argument("--jacobian", choices=["sensitivity", "fd"], default="sensitivity",
                   help="least squares: the Jacobian from the forward solve's parameter sensitivities "
                        "(one solve per evaluation; default) or forward differences (1 + n solves)")
    p.add_argument("--checkpoint", help="folder for the evaluation log; an interrupted fit resumes from it")
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5], default=2)
    p.add_argument("--out", required=True, help="fit file (netCDF)")
    p.add_argument("--keep-going", action="store_true",
                   help="if the fit fails, write a fit file that records the failure (status 'failed', the "
                        "error) and exit 0, so that a workflow's other fits go on and its table says so")
    p.set_defaults(func=run)


def run(args) -> int:
    if not args.keep_going:
        return _run(args)
    try:
        return _run(args)
    except Exception as e:   # recorded, not raised: one failed seed must not stop a study
        from ..fileio import provenance, write_netcdf
        import xarray as xr
        msg = str(e) if isinstance(e, UserError) else f"{type(e).__name__}: {e}"
        write_netcdf(xr.Dataset(attrs=provenance(status="failed", error=msg, law=args.law, method=args.method,
                                                 start=args.start, fixed=args.fixed)), args.out)
        print(f"liverinv fit: failed ({msg}); recorded in {args.out}", file=sys.stderr)
        return 0


def _run(args) -> int:
    import xarray as xr
    from tqdm import tqdm

    from ..fileio import file_sha256, write_netcdf
    from ..forward import ForwardModel
    from ..identify.fitfile import fit_dataset
    from ..identify.objective import Measurements, Objective
    from ..identify.optimize import Fit
    from ..imaging.bundle import open_bundle
    from ..imaging.observation import tracking_observation
    from ..laws import LawError, get_law
    from ..mesh import MeshError

    start, fixed = parse_assignments(args.start, "--start"), parse_assignments(args.fixed, "--fixed")
    if args.observation is None:
        args.observation = "tracker" if args.objective == "likelihood" else "nodes"
    try:
        law = get_law(args.law)
        start = {**{k: v for k, v in law.defaults.items() if k in law.free and k not in fixed}, **start}
        law.resolve({**start, **fixed})
        for path, what in ((args.bundle, "bundle"), (args.flow, "flow")):
            if not Path(path).is_file():
                raise UserError(f"{path}: {what} file not found")
        with xr.open_dataset(args.flow, engine="h5netcdf") as flow:
            flow = flow.load()
        fm = ForwardModel(args.model_mesh or args.mesh, quadrature_order=args.quadrature_order)
        if not args.model_mesh and flow.sizes.get("node") != fm.mesh.n_nodes:
            raise UserError(f"{args.flow} has {flow.sizes.get('node')} nodes, {args.mesh} "
                            f"{fm.mesh.n_nodes}: was it tracked on this mesh?")
        with open_bundle(args.bundle) as b:
            ind = b.indenter
            t_ind, depth, force = ind.time_s, ind.displacement_m, ind.force_N
            observation = None
            if args.observation == "tracker":
                tracking_mesh = args.mesh if args.model_mesh else fm.mesh   # read once if the same
                observation = tracking_observation(b, flow, tracking_mesh, fm.mesh)
            noise = None
            if args.objective == "likelihood":
                from ..identify.noise import noise_model
                noise = noise_model(ind, flow, args.noise_force, args.noise_depth, args.noise_tracking)
        obj = Objective(fm, args.law, Measurements.from_flow(flow, t_ind, depth, force), fixed=fixed,
                        observation=observation, noise=noise)
    except (LawError, MeshError, ValueError, KeyError, OSError) as e:
        raise UserError(str(e)) from None
    bar = tqdm(desc=f"fit {args.law}", unit="solve", disable=None)
    best = [float("inf")]

    def progress(rec):
        if rec["ok"]:
            best[0] = min(best[0], rec["phi"])
        bar.update(1)
        bar.set_postfix(phi=f"{best[0]:.3e}", refresh=False)

    if args.method == "nelder-mead":
        fit = Fit(obj, start, checkpoint=args.checkpoint, progress=progress)
        result = fit.nelder_mead(max_evaluations=args.max_evaluations or 400)
        jac = None
    else:
        from ..identify.balance import balanced_fit
        n_max = args.max_evaluations or 100

        def run_least_squares(fit, x0):
            if x0 is not None:      # the balanced stage, from the first optimum
                return fit.least_squares(max_evaluations=n_max, x0=x0, jacobian=args.jacobian)
            if args.design_points > 0:
                return fit.multistart(args.design_points, args.polish, max_evaluations=n_max,
                                      probe_evaluations=args.probe_evaluations, jacobian=args.jacobian)
            return fit.least_squares(max_evaluations=n_max, jacobian=args.jacobian)

        fit, result = balanced_fit(obj, start, run_least_squares, checkpoint=args.checkpoint, progress=progress)
        jac = result.get("jacobian")
    bar.close()
    ds = fit_dataset(fit, result, jac, attrs=dict(bundle=str(args.bundle), flow=str(args.flow),
                                                   mesh=str(args.mesh), mesh_sha256=file_sha256(args.mesh),
                                                   model_mesh=str(args.model_mesh or args.mesh),
                                                   observation=args.observation,
                                                   stages=json.dumps(result.get("stages", [])),
                                                   jacobian=args.jacobian if args.method == "least-squares" else "",
                                                   model_mesh_sha256=file_sha256(args.model_mesh or args.mesh)))
    write_netcdf(ds, args.out)
    best_p = ", ".join(f"{k}={v:.4g}" for k, v in zip(ds.param.values, ds.best.values))
    print(f"wrote {args.out}: {best_p}; Phi = {float(ds.phi):.4g} (vol {float(ds.phi_vol):.4g}, "
          f"ind {float(ds.phi_ind):.4g}) after {ds.attrs['n_solves']} forward solves")
    for line in filter(None, ds.attrs["warnings"].split("\n")):
        print(f"warning: {line}", file=sys.stderr)
    return 0
