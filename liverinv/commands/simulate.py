"""`liverinv simulate`: one forward simulation from a study YAML or from flags."""

from __future__ import annotations

import logging
from pathlib import Path

from ..cli import UserError
from . import parse_assignments

log = logging.getLogger(__name__)


def register(sub):
    p = sub.add_parser("simulate", help="run one forward simulation of the indentation test",
                       description=__doc__)
    p.add_argument("study", nargs="?", help="study YAML (flags below override its keys)")
    p.add_argument("--mesh", help="tet10 mesh file (groups bottom, side, top_free, footprint)")
    p.add_argument("--law", help="constitutive law: NH, elastic, SR, SR_low, SR_high, BR, SBR, ...")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="material parameter in SI units (repeatable)")
    p.add_argument("--control", choices=["displacement", "force"])
    p.add_argument("--depth", type=float, help="peak punch depth, m")
    p.add_argument("--rate", type=float, help="punch speed, m/s")
    p.add_argument("--steps", type=int, help="steps per ramp")
    p.add_argument("--frames", type=int, help="equally spaced frames over the whole history")
    p.add_argument("--unload", action=__import__("argparse").BooleanOptionalAction, default=None,
                   help="ramp back to zero after the peak (default: yes)")
    p.add_argument("--hold", type=float, help="hold at peak depth, s")
    p.add_argument("--force-history", help="CSV with columns time_s, force_N (force control)")
    p.add_argument("--punch", choices=["frictionless", "bonded"])
    p.add_argument("--support", choices=["fixed", "sliding"])
    p.add_argument("--solver", choices=["bfgs", "full"], help="nonlinear solver strategy")
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5],
                   help="tetrahedron rule degree (2: 4 points, default; 5: 14 points)")
    p.add_argument("--out", required=True, help="output run file (netCDF)")
    p.set_defaults(func=run)


def _study_from_args(args) -> tuple[dict, Path]:
    from ..study import load_study
    if args.study:
        study, base = load_study(args.study)
        if args.mesh:
            study["mesh"] = str(Path(args.mesh).resolve())
        else:
            study["mesh"] = str((base / study["mesh"]).resolve()) if "mesh" in study else None
    else:
        study, base = {"loading": {}}, Path(".")
        study["mesh"] = args.mesh
    if args.law:
        study["law"] = args.law
    study["params"] = {**study.get("params", {}), **parse_assignments(args.param, "--param")}
    loading = dict(study.get("loading", {}))
    for key in ("control", "depth", "rate", "steps", "frames", "unload", "hold"):
        v = getattr(args, key)
        if v is not None:
            loading[key] = v
    if args.steps is not None:
        loading.pop("frames", None)
    if args.frames is not None:
        loading.pop("steps", None)
    if args.force_history:
        loading["force_history"] = str(Path(args.force_history).resolve())
        loading["control"] = "force"
    loading.setdefault("control", "displacement")
    if loading["control"] == "displacement" or not loading.get("force_history"):
        loading.setdefault("depth", 9.2e-3)
        loading.setdefault("rate", 2e-3)
        if "frames" not in loading:
            loading.setdefault("steps", 46)
    study["loading"] = loading
    contact = dict(study.get("contact", {}))
    if args.punch:
        contact["punch"] = args.punch
    if args.support:
        contact["support"] = args.support
    study["contact"] = contact
    if args.solver:
        study.setdefault("solver", {})["method"] = args.solver
    if args.quadrature_order:
        study.setdefault("solver", {})["quadrature_order"] = args.quadrature_order
    if not study.get("mesh"):
        raise UserError("no mesh: give --mesh PATH or a study with a mesh key")
    if not study.get("law"):
        raise UserError("no law: give --law NAME or a study with a law key")
    return study, base


def run(args) -> int:
    from ..fem.solver import ConvergenceError
    from ..fileio import write_netcdf
    from ..laws import LawError, get_law
    from ..mesh import MeshError
    from ..study import StudyError, simulate_study

    try:
        study, base = _study_from_args(args)
        get_law(study["law"]).resolve(study["params"])  # fail before any work
        ds = simulate_study(study, base)
    except (LawError, MeshError, StudyError, ValueError) as e:
        raise UserError(str(e)) from None
    except ConvergenceError as e:
        raise UserError(f"the simulation did not converge: {e}") from None
    write_netcdf(ds, args.out)
    t = ds.attrs.get("solver", "")
    print(f"wrote {args.out}: {ds.sizes['time']} frames, peak depth {ds.indenter_depth.max().item()*1e3:.3f} mm, "
          f"peak force {ds.indenter_force.max().item():.4f} N")
    log.info("solver: %s", t)
    return 0
