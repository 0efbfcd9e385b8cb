"""`liverinv gather`: a workflow study's fit files into one Dataset (fits.nc)."""

from __future__ import annotations

from pathlib import Path


def register(sub):
    p = sub.add_parser("gather", help="gather a study's fit files into one xarray Dataset", description=__doc__)
    p.add_argument("study", type=Path, help="workflow study (YAML)")
    p.add_argument("--fits-dir", type=Path, required=True, help="folder of the fit files, named LAW_SEED_METHOD.nc")
    p.add_argument("--name", help="study name (default: the file's stem)")
    p.add_argument("--out", type=Path, required=True, help="gathered fits (netCDF)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UserError
    from ..fileio import write_netcdf
    from ..pipeline.gather import gather_fits
    from ..pipeline.spec import load_workflow_study
    from ..study import StudyError

    try:
        study = load_workflow_study(args.study, args.name)
    except StudyError as e:
        raise UserError(str(e)) from None
    paths = {job: args.fits_dir / f"{job.tag}.nc" for job in study.fit_jobs()}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise UserError(f"fit files missing: {', '.join(missing)}")
    ds = gather_fits(study, paths)
    write_netcdf(ds, args.out)
    counts = {s: int((ds.status == s).sum()) for s in ("ok", "flagged", "failed")}
    print(f"wrote {args.out}: {ds.sizes['law']} laws x {ds.sizes['seed']} seeds x {ds.sizes['method']} methods; "
          + ", ".join(f"{v} {k}" for k, v in counts.items()))
    return 0
