"""`liverinv fit`: identify a law's parameters from a measurement bundle and its tracked flow."""

from __future__ import annotations

import json
import sys
from pathlib import Path


from ..cli import UserError
from . import INCLUSIONS_HELP, inclusions_arg, parse_assignments


def _positive_int(text):
    import argparse
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{v} is not >= 1")
    return v


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
    p.add_argument("--max-evaluations", type=_positive_int, default=None,
                   help="Nelder-Mead: forward solves; least squares: residual evaluations per run")
    p.add_argument("--design-points", type=int, default=0, metavar="N",
                   help="least squares with a global stage (laws with several minima, e.g. SR): short "
                        "runs from the start and from the --polish best of N Sobol design points over the "
                        "parameters' search ranges, then the best run continued to convergence")
    p.add_argument("--polish", type=int, default=2, help="design points polished by least squares")
    p.add_argument("--probe-evaluations", type=int, default=10,
                   help="residual evaluations of each least-squares run before the best is continued")
    p.add_argument("--search-pairs", type=int, default=None, metavar="N",
                   help="with --design-points, a record of more than N frame pairs (default 30) is "
                        "searched on pairs merged pairs // N at a time (about 1/m of the cost per solve), then "
                        "fitted on all frames from the search's best; 0: search on all frames")
    p.add_argument("--jacobian", choices=["sensitivity", "fd"], default="sensitivity",
                   help="least squares: the Jacobian from the forward solve's parameter sensitivities "
                        "(one solve per evaluation; default) or forward differences (1 + n solves)")
    p.add_argument("--checkpoint", help="folder for the evaluation log; an interrupted fit resumes from it")
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5], default=2)
    p.add_argument("--inclusions", metavar="JSON|FILE", help=INCLUSIONS_HELP)
    p.add_argument("--out", required=True, help="fit file (netCDF)")
    p.add_argument("--shared-checkpoint", action="append", default=[], metavar="DIR",
                   help="checkpoint folder of a fit of the same data, law and options from another start "
                        "(repeatable): its solves are read back instead of solved again, e.g. the design stage "
                        "of --design-points, which every start shares; a folder of other inputs is ignored "
                        "with a warning, and none is written")
    p.add_argument("--fresh-checkpoint", action="store_true",
                   help="if --checkpoint holds solves of other inputs, set it aside (renamed *.stale-N) and start anew")
    p.add_argument("--indenter-only", action="store_true",
                   help="fit the indenter record alone when the flow has too few confident nodes for a "
                        "volumetric term (otherwise refused)")
    p.add_argument("--tracker-response", action="store_true",
                   help="after the fit, render the bundle's first volume warped by the fitted model's motion, "
                        "track it with the flow's options, take the difference from the observation operator's "
                        "prediction as the tracker's error and continue the fit on the tracked motion less that "
                        "error (needs --observation tracker; one more solve plus rendering and tracking, ~5 min "
                        "for 100 paper-size volumes)")
    p.add_argument("--keep-going", action="store_true",
                   help="if the fit fails, write a fit file that records the failure (status 'failed', the "
                        "error) and exit 0, so that a workflow's other fits go on and its table says so")
    p.set_defaults(func=run)


class FitFailed(UserError):
    """No forward solve succeeded; the fit file with status 'failed' is written."""


def run(args) -> int:
    if not args.keep_going:
        return _run(args)
    try:
        return _run(args)
    except FitFailed as e:
        print(f"liverinv fit: {e}", file=sys.stderr)
        return 0
    except Exception as e:   # recorded, not raised: one failed seed must not stop a study
        msg = str(e) if isinstance(e, UserError) else f"{type(e).__name__}: {e}"
        _write_failed(args, msg)
        print(f"liverinv fit: failed ({msg}); recorded in {args.out}", file=sys.stderr)
        return 0


def _write_failed(args, msg, history=None):
    import xarray as xr

    from ..fileio import provenance, write_netcdf
    ds = xr.Dataset(attrs=provenance(status="failed", error=msg, law=args.law, method=args.method,
                                     start=args.start, fixed=args.fixed))
    if history:
        ds["history_message"] = ("evaluation", [str(r.get("message", "")) for r in history])
        ds["history_wall_s"] = ("evaluation", [float(r["wall_s"]) for r in history], {"units": "s"})
    write_netcdf(ds, args.out)


def _binding(args, law, fixed, noise, flow_path):
    """What the checkpoint's solves depend on: the data and meshes (hashes), law and options."""
    from ..fileio import data_sha256, file_sha256
    # the data's content, not the files' bytes: a rerun that tracks the same motion again
    # writes other run times into the flow file, and its logged solves still hold
    return dict(bundle=data_sha256(args.bundle), flow=data_sha256(flow_path, attrs=("options", "stride", "window")),
                mesh=file_sha256(args.mesh),
                model_mesh=file_sha256(args.model_mesh) if args.model_mesh else "",
                law=law, fixed=fixed, objective=args.objective, observation=args.observation,
                quadrature_order=args.quadrature_order, noise=noise.to_json() if noise is not None else "",
                indenter_only=bool(args.indenter_only), inclusions=args.inclusions or "")


def _run(args) -> int:
    from tqdm import tqdm

    from ..fileio import file_sha256, write_netcdf
    from ..identify.fitfile import fit_dataset
    from ..identify.setup import objective_from_files
    from ..laws import LawError, get_law
    from ..mesh import MeshError

    start, fixed = parse_assignments(args.start, "--start"), parse_assignments(args.fixed, "--fixed")
    try:
        law = get_law(args.law)
        start = {**{k: v for k, v in law.defaults.items() if k in law.free and k not in fixed}, **start}
        law.resolve({**start, **fixed})
        obj, args.observation = objective_from_files(
            args.bundle, args.flow, args.mesh, args.law, fixed, args.model_mesh, args.objective, args.observation,
            args.noise_force, args.noise_depth, args.noise_tracking, args.quadrature_order, args.indenter_only,
            inclusions_arg(args.inclusions))
        noise = obj.noise
        binding = _binding(args, args.law, fixed, noise, args.flow)
        if args.checkpoint and args.fresh_checkpoint:
            _set_aside_if_stale(Path(args.checkpoint), binding)
    except (LawError, MeshError, ValueError, KeyError, OSError) as e:
        raise UserError(str(e)) from None
    bar = tqdm(desc=f"fit {args.law}", unit="solve", disable=None)
    best = [float("inf")]

    def progress(rec):
        if rec["ok"]:
            best[0] = min(best[0], rec["phi"])
        bar.update(1)
        bar.set_postfix(phi=f"{best[0]:.3e}", refresh=False)

    from ..identify.optimize import CheckpointMismatch
    from ..identify.response import continue_on_tracker_response
    try:
        fit, result, jac = _optimize(args, obj, start, progress, binding)
    except (CheckpointMismatch, ValueError) as e:
        bar.close()
        raise UserError(str(e)) from None
    response = {}
    if args.tracker_response and result["best"] is not None:
        try:
            if args.observation != "tracker":
                raise ValueError("--tracker-response needs --observation tracker (the operator it corrects)")
            fit, result, response = continue_on_tracker_response(
                obj, fit, result, args.bundle, args.flow, args.mesh, jacobian=args.jacobian,
                max_evaluations=args.max_evaluations or 100, progress=progress, binding=binding,
                checkpoint=str(Path(args.checkpoint) / "tracker-response") if args.checkpoint else None)
            jac = result.get("jacobian")
        except (CheckpointMismatch, ValueError) as e:
            bar.close()
            raise UserError(str(e)) from None
    bar.close()
    if result["best"] is None:
        errors = [r.get("message", "") for r in fit.history if r.get("message")]
        msg = (f"no forward solve succeeded in {len(fit.history)} solves (first error: "
               f"{errors[0][:200] if errors else 'none reported'})")
        _write_failed(args, msg, fit.history)
        raise FitFailed(f"{msg}; wrote status 'failed' to {args.out}")
    ds = fit_dataset(fit, result, jac, attrs=dict(bundle=str(args.bundle), flow=str(args.flow),
                                                   mesh=str(args.mesh), mesh_sha256=file_sha256(args.mesh),
                                                   model_mesh=str(args.model_mesh or args.mesh),
                                                   observation=args.observation,
                                                   stages=json.dumps(result.get("stages", [])),
                                                   jacobian=args.jacobian if args.method == "least-squares" else "",
                                                   indenter_only=int(args.indenter_only),
                                                   inclusions=json.dumps([i.to_json() for i in obj.forward.inclusions]),
                                                   tracker_response=json.dumps(response),
                                                   shared_solves=int(result.get("n_shared", 0))
                                                   + int((result.get("search") or {}).get("n_shared", 0)),
                                                   model_mesh_sha256=file_sha256(args.model_mesh or args.mesh)))
    write_netcdf(ds, args.out)
    best_p = ", ".join(f"{k}={v:.4g}" for k, v in zip(ds.param.values, ds.best.values))
    n_total = int(ds.attrs["n_solves"]) + int(ds.attrs["search_solves"])
    print(f"wrote {args.out}: {best_p}; Phi = {float(ds.phi):.4g} (vol {float(ds.phi_vol):.4g}, "
          f"ind {float(ds.phi_ind):.4g}) after {n_total} forward solves"
          + (f" ({ds.attrs['search_solves']} of the search on merged frame pairs)" if ds.attrs["search_solves"] else "")
          + (f", {ds.attrs['shared_solves']} of them read from a shared checkpoint" if ds.attrs["shared_solves"] else ""))
    for line in filter(None, ds.attrs["warnings"].split("\n")):
        print(f"warning: {line}", file=sys.stderr)
    return 0


def _set_aside_if_stale(ckpt: Path, binding):
    import json as _json
    f = ckpt / "binding.json"
    if not ckpt.exists():
        return
    try:
        same = f.exists() and _json.loads(f.read_text()) == _json.loads(_json.dumps(binding))
    except ValueError:
        same = False
    if same or not any(ckpt.iterdir()):
        return
    k = 1
    while ckpt.with_name(f"{ckpt.name}.stale-{k}").exists():
        k += 1
    ckpt.rename(ckpt.with_name(f"{ckpt.name}.stale-{k}"))
    print(f"liverinv fit: checkpoint {ckpt} held solves of other inputs; moved to {ckpt.name}.stale-{k}",
          file=sys.stderr)


def _optimize(args, obj, start, progress, binding):
    from ..identify.optimize import Fit
    if args.method == "nelder-mead":
        fit = Fit(obj, start, checkpoint=args.checkpoint, progress=progress, binding=binding,
                  shared=args.shared_checkpoint)
        result = fit.nelder_mead(max_evaluations=args.max_evaluations or 400)
        jac = None
    else:
        from ..identify.search import least_squares_fit
        fit, result = least_squares_fit(obj, start, design_points=args.design_points, polish=args.polish,
                                        max_evaluations=args.max_evaluations or 100,
                                        probe_evaluations=args.probe_evaluations, jacobian=args.jacobian,
                                        search_pairs=args.search_pairs, checkpoint=args.checkpoint,
                                        progress=progress, binding=binding, shared=args.shared_checkpoint)
        jac = result.get("jacobian")
    return fit, result, jac
