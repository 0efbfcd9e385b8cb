"""`liverinv discover`: fit a base law, diagnose it, add the recommended effect, refit, until
nothing is recommended; writes DISCOVERY.nc (one step per added effect)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from . import INCLUSIONS_HELP


def register(sub):
    p = sub.add_parser("discover", help="base fit, then diagnose / add / refit until nothing is missing",
                       description=__doc__)
    p.add_argument("--bundle", type=Path, required=True)
    p.add_argument("--flow", type=Path, required=True)
    p.add_argument("--mesh", type=Path, required=True, help="tracking mesh")
    p.add_argument("--law", required=True, help="base law")
    p.add_argument("--model-mesh", type=Path, help="mesh of the forward model for every step (default: --mesh)")
    p.add_argument("--final-mesh", default="auto", metavar="auto|none|MESH",
                   help="refit the last step's law on this finer model mesh, warm-started, for its parameters "
                        "(auto, the default: the tracking cylinder meshed with the medium preset, written beside "
                        "--out, unless --mesh is as fine or --model-mesh is given; none: the tracking mesh's)")
    p.add_argument("--observation", choices=["nodes", "tracker"])
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5], default=2)
    p.add_argument("--start", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--fixed", action="append", default=[], metavar="NAME=VALUE",
                   help="held fixed in the base law and every later law that has it, unless the added "
                        "effect is made of it (e.g. C2=0: a neo-Hookean base, as the law NH) (repeatable)")
    p.add_argument("--max-steps", type=int, default=3)
    p.add_argument("--inclusions", metavar="JSON|FILE", help="known inclusions of the base model; " + INCLUSIONS_HELP)
    p.add_argument("--out", type=Path, required=True, help="DISCOVERY.nc")
    p.add_argument("--figures", type=Path, help="folder for the discovery figure")
    p.set_defaults(func=run)


def run(args) -> int:
    from dataclasses import replace

    from ..cli import UserError
    from ..diagnose.discover import Z_WITHDRAW, discover
    from ..diagnose.effects import KAPPA_SECANTS
    from ..diagnose.files import discovery_dataset, imaging_calibration, tracker_error_for
    from ..fileio import write_netcdf
    from ..identify.setup import objective_from_files
    from ..laws import LawError, get_law
    from . import inclusions_arg, parse_assignments

    try:
        get_law(args.law)
    except LawError as e:
        raise UserError(str(e)) from None
    if args.max_steps < 0:
        raise UserError("--max-steps must be >= 0")
    start = {**get_law(args.law).defaults, **parse_assignments(args.start, "--start")}
    fixed = parse_assignments(args.fixed, "--fixed")
    try:
        get_law(args.law).resolve({**{k: v for k, v in start.items() if k not in fixed}, **fixed})
    except LawError as e:
        raise UserError(str(e)) from None
    inclusions = inclusions_arg(args.inclusions)

    def objective_on(model_mesh):
        def objective_for(law, fixed, noise):
            obj, _ = objective_from_files(args.bundle, args.flow, args.mesh, law, fixed, model_mesh, "likelihood",
                                          args.observation, None if noise is None else noise.force_N,
                                          None if noise is None else noise.depth_m,
                                          None if noise is None else noise.tracking_m, args.quadrature_order,
                                          inclusions=inclusions)
            if noise is not None:
                obj = obj.with_noise(replace(obj.noise, sources=noise.sources))
            return obj
        return objective_for

    final_mesh, final_note = final_model_mesh(args)
    calibration = imaging_calibration(args.bundle)

    from tqdm import tqdm
    bar = tqdm(desc=f"discover from {args.law}", unit="solve", disable=None)
    try:
        out = discover(objective_on(args.model_mesh), args.law, start, args.max_steps,
                       progress=lambda rec: bar.update(1), fixed=fixed,
                       final_objective_for=objective_on(final_mesh) if final_mesh else None,
                       alpha=calibration["alpha"],
                       tracker_error=tracker_error_for(args.bundle, args.flow, args.mesh)
                       if calibration["correct_final"] else None,
                       confirm_inclusions=calibration["confirm_geometric"])
    except ValueError as e:
        raise UserError(str(e)) from None
    finally:
        bar.close()
    ds = discovery_dataset(out, base_law=args.law, bundle=str(args.bundle), flow=str(args.flow), mesh=str(args.mesh),
                           model_mesh=str(args.model_mesh or args.mesh),
                           defaults="likelihood objective; multi-start (8 design points) for laws with relaxation; "
                                    "noise levels of the base fit after its balance stage for every step; "
                                    "scans and thresholds of liverinv.diagnose.score "
                                    f"(p < {calibration['alpha']:g} after the scan's "
                                    "Bonferroni correction and a predicted drop >= 1 % of Phi_vol; punch friction "
                                    "and bottom slip also by the secant to bonded / sliding, Darcy flow by secants "
                                    f"to kappa {' and '.join(f'{k:g}' for k in KAPPA_SECANTS)}); when several "
                                    "effects pass, the best 3 and their rivals are refitted for 8 solves each, from "
                                    "the second step also in place of an earlier addition's rival, and the lowest Phi "
                                    "is added (liverinv.diagnose.discover.N_TRIALS, TRIAL_EVALUATIONS); an inclusion's "
                                    "sphere is refined on a 2.5 mm grid first"
                                    + ("; on these warped volumes every effect that passes (and a significant "
                                       "sphere) must also pass on the tracked motion "
                                       "less the tracker's response to the fitted model on the finer mesh, then "
                                       "on the tracking mesh (liverinv.diagnose.score.confirm_by_tracker_response)"
                                       if calibration["confirm_geometric"] else "")
                                    + "; an addition whose refit lowers Phi by "
                                    "less than 1 % of Phi_vol is not kept; a record of more than 61 frames is "
                                    "searched (multi-start, trials) on frame pairs merged pairs // 30 at a time "
                                    "and every reported fit finished on all frames "
                                    "(liverinv.identify.search.SEARCH_PAIRS); the last step's law refitted on a "
                                    "finer model mesh (--final-mesh auto: the tracking cylinder with the medium "
                                    "preset), whose parameters are the last step's params"
                                    + ("; on these warped volumes the last step's law is then refitted on the "
                                       "tracked motion less the tracker's response to its fit, on the tracking and "
                                       "the finer mesh, the lower Phi taken and balanced from the data's own noise "
                                       "levels (liverinv.diagnose.discover.corrected_final_fit): its parameters are "
                                       "the last step's params" if calibration["correct_final"] else "")
                                    + "; the last addition is withdrawn (and the step before it fitted again) when "
                                    "the last refit (on the corrected motion, else on the finer mesh) puts its "
                                    f"amplitude within {Z_WITHDRAW:g} SD of its null "
                                    "(liverinv.diagnose.discover.unresolved_addition)",
                           inclusions=json.dumps([i.to_json() for i in inclusions]), fixed=json.dumps(fixed),
                           final_model_mesh=str(final_mesh or ""), final_model_mesh_note=final_note,
                           caveat=calibration["caveat"], alpha=calibration["alpha"])
    write_netcdf(ds, args.out)
    if args.figures:
        from ..diagnose.figures import plot_discovery
        plot_discovery(ds, args.figures / "discovery.png")
    for s in range(ds.sizes["step"]):
        print(f"step {s}: {ds.law.values[s]}{' + ' + ds.added.values[s] if ds.added.values[s] else ''}: "
              f"Phi_vol {float(ds.phi_vol[s]):.4g}, Phi_ind {float(ds.phi_ind[s]):.4g}")
        value, sd = json.loads(str(ds.params_tracking_mesh.values[s])), json.loads(str(ds.param_sd.values[s]))
        if final_mesh and s == ds.sizes["step"] - 1:     # its SDs are the final fit's, printed below
            print("    " + ", ".join(f"{k} {value[k]:.4g}" for k in sd) + " (on the tracking mesh; SDs below)")
        else:
            print("    " + ", ".join(f"{k} {value[k]:.4g} +- {v:.2g}" for k, v in sd.items()))
        for w in filter(None, str(ds.warnings.values[s]).split("\n")):
            print(f"warning: step {s} ({ds.law.values[s]}): {w}", file=sys.stderr)
    response = json.loads(ds.attrs.get("tracker_response") or "{}")
    if final_mesh:
        print(f"final fit on {final_mesh} ({final_note}): Phi {ds.attrs['final_phi']:.5g} (tracking mesh "
              f"{float(ds.phi[-1]):.5g}) in {ds.attrs['final_n_solves']} solves; "
              + ("; its Phi is not comparable on warped volumes, see below" if response.get("mesh") else
                 "; its parameters:" if ds.attrs["final_kept"] else "; not kept, the tracking mesh's parameters:"))
    else:
        print(f"no final fit on a finer mesh: {final_note}")
    if response.get("mesh"):
        print(f"refitted on the tracked motion less the tracker's response to the fit (warped volumes; error RMS "
              f"{1e6 * response['error_rms_m'][response['mesh']]:.3g} um), on the {response['mesh']} (its Phi the lower "
              f"there), in {response['n_solves']} solves ({response['wall_s']:.0f} s); the reported parameters:")
    if final_mesh or response.get("mesh"):
        value, sd = json.loads(str(ds.params.values[-1])), json.loads(str(ds.param_sd.values[-1]))
        model = json.loads(str(ds.param_sd_model.values[-1]))
        print("    " + ", ".join(f"{k} {value[k]:.4g} +- {v:.2g}" for k, v in sd.items()))
        if model:
            print("    the spread of the other fits of this law (model mesh, tracker correction) about it: "
                  + ", ".join(f"{k} {v:.2g}" for k, v in model.items()) + " (param_sd_model; param_sd_total "
                  "combines both)")
    if ds.attrs["caveat"]:
        print(f"warning: {ds.attrs['caveat']}", file=sys.stderr)
    print(f"wrote {args.out}: {ds.attrs['stopped_because']}")
    return 0


def final_model_mesh(args):
    """(mesh path or None, what was decided) for the final fit of `--final-mesh`."""
    from ..cli import UserError
    from ..mesh import MeshError, read_mesh
    from ..meshgen import refined_model_mesh

    if args.final_mesh == "none":
        return None, "--final-mesh none"
    if args.model_mesh:
        return None, "every step ran on --model-mesh"
    if args.final_mesh != "auto":
        path = Path(args.final_mesh)
        try:
            read_mesh(path)
        except MeshError as e:
            raise UserError(f"--final-mesh: {e}") from None
        return path, "given by --final-mesh"
    try:
        tracking = read_mesh(args.mesh)
    except MeshError as e:
        raise UserError(str(e)) from None
    return refined_model_mesh(tracking, args.out.with_name(args.out.stem + "_model_mesh.msh"))
