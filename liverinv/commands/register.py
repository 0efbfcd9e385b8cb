"""`liverinv register`: the registered (mechanically regularized) displacement field of a
tracked flow, with regularization springs (seed paper Eqs. 1-3)."""

from __future__ import annotations

from pathlib import Path

from ..cli import UserError
from . import parse_assignments


def register(sub):
    p = sub.add_parser("register", help="registered displacement field from tracked motion (springs, Eqs. 1-3)",
                       description=__doc__)
    p.add_argument("--bundle", required=True, help="measurement bundle (HDF5) with the indenter record")
    p.add_argument("--flow", required=True, help="tracked nodal motion (liverinv track)")
    p.add_argument("--mesh", required=True, help="mesh the flow was tracked on")
    p.add_argument("--law", required=True)
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="material parameter in SI units (repeatable; others: the law's defaults)")
    p.add_argument("--beta", type=float, default=None,
                   help="regularization coefficient of Eq. 2, k = beta K c (default 1: a fully confident "
                        "spring as stiff as its node; liverinv.identify.register.DEFAULT_BETA)")
    p.add_argument("--quadrature-order", type=int, choices=[2, 3, 4, 5], default=2)
    p.add_argument("--out", required=True, help="registration file (netCDF)")
    p.set_defaults(func=run)


def run(args) -> int:
    import xarray as xr

    from ..fem.solver import ConvergenceError
    from ..fileio import file_sha256, write_netcdf
    from ..forward import ForwardModel
    from ..identify.register import DEFAULT_BETA, register_flow, registration_dataset
    from ..imaging.bundle import open_bundle
    from ..laws import LawError, get_law
    from ..mesh import MeshError

    params = parse_assignments(args.param, "--param")
    beta = DEFAULT_BETA if args.beta is None else args.beta
    try:
        law = get_law(args.law)
        resolved = law.resolve(params)
        if not 0 < beta < float("inf"):
            raise UserError(f"--beta must be a positive number (got {beta})")
        for path, what in ((args.bundle, "bundle"), (args.flow, "flow")):
            if not Path(path).is_file():
                raise UserError(f"{path}: {what} file not found")
        with open_bundle(args.bundle) as b:
            ind = b.indenter
            t_ind, depth = ind.time_s, ind.displacement_m
        with xr.open_dataset(args.flow, engine="h5netcdf") as flow:
            flow = flow.load()
        fm = ForwardModel(args.mesh, quadrature_order=args.quadrature_order)
        reg = register_flow(fm, args.law, params, flow, t_ind, depth, beta=beta)
    except (LawError, MeshError, ValueError, KeyError, OSError) as e:
        raise UserError(str(e)) from None
    except ConvergenceError as e:
        raise UserError(f"the registration did not converge: {e}") from None
    ds = registration_dataset(reg, fm.mesh, args.law, {k: resolved[k] for k in law.free} | dict(law.fixed),
                              attrs=dict(bundle=str(args.bundle), flow=str(args.flow), mesh=str(args.mesh),
                                         mesh_sha256=file_sha256(args.mesh),
                                         quadrature_points=int((fm.biphasic_space() if law.biphasic else fm.space).nq)))
    write_netcdf(ds, args.out)
    print(f"wrote {args.out}: {ds.sizes['time']} frames, beta {reg.beta:g}, Phi = {reg.phi_total:.3e} m^2 "
          f"(Eq. 3), {reg.timing['wall_s']:.1f} s")
    return 0
