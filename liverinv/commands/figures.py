"""`liverinv figures`: a study's figures from its files. With `--convergence LAW --out PNG`:
Phi and every parameter of LAW's fits against forward solves; otherwise any of `--indenter`
(indenter histories of data and the best fit of each law), `--velocities` (vertical nodal
velocity histories, tracked and modelled) and `--fields` (ParaView fields of the best law)."""

from __future__ import annotations

from pathlib import Path


def register(sub):
    p = sub.add_parser("figures", help="a study's figures from its gathered fits and data", description=__doc__)
    p.add_argument("fits", type=Path, help="gathered fits (liverinv gather)")
    p.add_argument("--convergence", metavar="LAW", help="the convergence figure of this law, to --out")
    p.add_argument("--out", type=Path, help="figure file of --convergence")
    p.add_argument("--fits-dir", type=Path, help="folder of the fit files (LAW_SEED_METHOD.nc)")
    p.add_argument("--bundle", type=Path)
    p.add_argument("--flow", type=Path)
    p.add_argument("--mesh", type=Path, help="tracking mesh")
    p.add_argument("--nodes", type=int, default=4, help="nodes whose velocity histories are drawn")
    p.add_argument("--slice-y", type=float, default=0.0, help="m; the nodes are taken near this plane")
    p.add_argument("--indenter", type=Path, help="indenter figure to write")
    p.add_argument("--velocities", type=Path, help="nodal velocity figure to write")
    p.add_argument("--fields", type=Path, help="ParaView fields to write (.pvd with its _frames/ folder of VTU files)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UserError
    from ..pipeline import figures as F
    from ..pipeline.gather import load_dataset

    ds = load_dataset(args.fits)
    if args.convergence:
        if args.out is None:
            raise UserError("--convergence needs --out")
        if args.convergence not in ds.law.values:
            raise UserError(f"{args.fits} has no law {args.convergence!r}; it has {list(ds.law.values)}")
        F.plot_convergence(ds, args.convergence, args.out)
        print(f"wrote {args.out}")
        return 0
    if not (args.indenter or args.velocities or args.fields):
        raise UserError("nothing to draw: give --convergence LAW, or --indenter/--velocities/--fields")
    need = {"--fits-dir": args.fits_dir, "--flow": args.flow}
    if args.indenter:
        need["--bundle"] = args.bundle
    if args.fields:
        need["--mesh"] = args.mesh
    missing = [k for k, v in need.items() if v is None]
    if missing:
        raise UserError(f"these figures need {', '.join(missing)}")
    for p in (args.bundle, args.flow, args.mesh):
        if p is not None and not p.is_file():
            raise UserError(f"{p}: file not found")
    best = F.best_fits(ds)
    if not best:
        raise UserError(f"every fit in {args.fits} failed: nothing to draw")
    files = {f"{law} (seed {s}, {m})": args.fits_dir / f"{law}_{s}_{m}.nc" for law, (s, m) in best.items()}
    if args.indenter:
        F.plot_indenter(args.bundle, files, args.indenter)
    if args.velocities:
        F.plot_velocities(args.flow, files, args.velocities, args.nodes, args.slice_y)
    if args.fields:
        law = min(best, key=lambda k: float(ds.phi_common.sel({"law": k, "seed": best[k][0], "method": best[k][1]})))
        s, m = best[law]
        F.write_fields(args.flow, args.fits_dir / f"{law}_{s}_{m}.nc", args.mesh, args.fields)
    print("wrote " + ", ".join(str(p) for p in (args.indenter, args.velocities, args.fields) if p))
    return 0
