"""Gather a study's fit files into one xarray Dataset over (law, seed, method, param)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from ..fileio import provenance
from ..identify.compare import group_misfit
from ..laws import PARAMS
from .spec import FitJob, WorkflowStudy

__all__ = ["gather_fits", "fit_flags", "load_dataset", "STATUS"]

STATUS = ("ok", "flagged", "failed")


def fit_flags(ds: xr.Dataset) -> list[str]:
    """The fit file's own warnings (bound, undetermined, indenter residual, failed solves), one per line."""
    return [w for w in ds.attrs.get("warnings", "").split("\n") if w]


def load_dataset(path) -> xr.Dataset:
    """A fit file or gathered fits, loaded whole; UserError naming a missing file."""
    from ..errors import UserError
    if not Path(path).is_file():
        raise UserError(f"{path}: file not found")
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()


def gather_fits(study: WorkflowStudy, paths: dict[FitJob, Path]) -> xr.Dataset:
    """One Dataset of every fit of `study`: best, start and truth per parameter, the misfit
    components, costs, status ('ok', 'flagged' with the reasons in `flags`, or 'failed' with
    the error) and the evaluation histories (NaN-padded to the longest)."""
    laws, seeds, methods = study.laws, study.seeds, study.methods
    names = [p for p in PARAMS if any(p in _law_params(study, law) for law in laws)]
    shape = (len(laws), len(seeds), len(methods))
    idx = {p: i for i, p in enumerate(names)}
    best = np.full(shape + (len(names),), np.nan)
    start, rel_sd = best.copy(), best.copy()
    at_bound = np.zeros(best.shape, bool)
    scalars = {k: np.full(shape, np.nan) for k in
               ("phi", "phi_vol", "phi_ind", "phi_common", "phi_vol_common", "phi_ind_common", "rms_depth",
                "rms_axial", "rms_force", "n_solves", "search_solves", "solve_time_s", "cond")}
    status = np.full(shape, "failed", dtype=object)
    flags = np.full(shape, "", dtype=object)
    message = np.full(shape, "", dtype=object)
    histories = {}
    clusters = {}          # (i, j, k) -> (labels, misfit per cluster at the common levels, field cluster mask)
    phi_units = "1"
    for job, path in paths.items():
        i, j, k = laws.index(job.law), seeds.index(job.seed), methods.index(job.method)
        ds = load_dataset(path)
        for p, v in study.start(job.law, job.seed).items():
            start[i, j, k, idx[p]] = v
        if ds.attrs.get("status") == "failed" or "best" not in ds:
            status[i, j, k] = "failed"
            message[i, j, k] = ds.attrs.get("error", "no result")
            continue
        phi_units = ds.phi.attrs.get("units", phi_units)
        for p, b, sd, ab in zip(ds.param.values, ds.best.values, ds.rel_sd.values, ds.at_bound.values):
            best[i, j, k, idx[str(p)]] = b
            rel_sd[i, j, k, idx[str(p)]] = sd
            at_bound[i, j, k, idx[str(p)]] = bool(ab)
        for key in ("phi", "phi_vol", "phi_ind", "rms_depth", "rms_axial", "rms_force"):
            scalars[key][i, j, k] = float(ds[key])
        for key in ("phi", "phi_vol", "phi_ind"):
            scalars[key + "_common"][i, j, k] = float(ds[key + "_common"] if key + "_common" in ds else ds[key])
        if "residual_group" in ds:
            clusters[(i, j, k)] = _cluster_misfit(ds)
        n = int(ds.attrs["n_solves"])
        # a search on merged frame pairs (identify.search) is part of the fit's cost
        scalars["search_solves"][i, j, k] = int(ds.attrs.get("search_solves", 0))
        scalars["n_solves"][i, j, k] = n + scalars["search_solves"][i, j, k]
        scalars["solve_time_s"][i, j, k] = (float(ds.history_wall_s.values.sum())
                                            + float(ds.attrs.get("search_solve_time_s", 0.0)))
        scalars["cond"][i, j, k] = float(ds.attrs.get("cond", np.nan))
        message[i, j, k] = str(ds.attrs.get("message", ""))
        f = fit_flags(ds)
        flags[i, j, k] = "; ".join(f)
        status[i, j, k] = "flagged" if f else "ok"
        P = np.full((ds.sizes["evaluation"], len(names)), np.nan)
        for p in ds.param.values:
            P[:, idx[str(p)]] = ds.history_params.sel(param=p).values
        histories[(i, j, k)] = (ds.history_phi.values, ds.history_phi_vol.values, ds.history_phi_ind.values,
                                ds.history_wall_s.values, P)
    # seeds of one law and method that disagree
    tol = study.agree_tol
    spread = np.full((len(laws), len(methods), len(names)), np.nan)
    for i in range(len(laws)):
        for k in range(len(methods)):
            ok = status[i, :, k] != "failed"
            if ok.sum() < 2:
                continue
            b = best[i, ok, k]
            spread[i, k] = (np.nanmax(b, 0) - np.nanmin(b, 0)) / np.abs(np.nanmedian(b, 0))
            bad = [names[q] for q in range(len(names)) if spread[i, k, q] > tol]
            if bad:
                for j in np.nonzero(ok)[0]:
                    flags[i, j, k] = "; ".join(filter(None, [flags[i, j, k], f"seeds disagree on {', '.join(bad)} "
                                                             f"(spread over {100 * tol:g} %)"]))
                    status[i, j, k] = "flagged"
    n_ev = max([len(h[0]) for h in histories.values()], default=0)
    H = {key: np.full(shape + (n_ev,), np.nan) for key in ("phi", "phi_vol", "phi_ind", "wall_s")}
    HP = np.full(shape + (n_ev, len(names)), np.nan)
    for (i, j, k), (phi, pv, pi, wall, P) in histories.items():
        n = len(phi)
        H["phi"][i, j, k, :n], H["phi_vol"][i, j, k, :n], H["phi_ind"][i, j, k, :n] = phi, pv, pi
        H["wall_s"][i, j, k, :n] = wall
        HP[i, j, k, :n] = P
    truth = study.truth_params()
    dims = ("law", "seed", "method")
    cluster_vars = _cluster_vars(clusters, shape, dims, phi_units)
    units = {"phi": phi_units, "phi_vol": phi_units, "phi_ind": phi_units, "phi_common": phi_units,
             "phi_vol_common": phi_units, "phi_ind_common": phi_units, "rms_depth": "m", "rms_axial": "m",
             "rms_force": "N", "n_solves": "1", "search_solves": "1", "solve_time_s": "s", "cond": "1"}
    out = xr.Dataset(
        data_vars=dict(
            best=(dims + ("param",), best, {"long_name": "identified parameter (SI)"}),
            start=(dims + ("param",), start, {"long_name": "start value (SI)"}),
            truth=(("param",), np.array([truth.get(p, np.nan) for p in names], float),
                   {"long_name": "truth (synthetic data), NaN where unknown"}),
            rel_sd=(dims + ("param",), rel_sd, {"long_name": "relative standard deviation"}),
            at_bound=(dims + ("param",), at_bound),
            param_unit=(("param",), [PARAMS[p].unit for p in names]),
            seed_spread=(("law", "method", "param"), spread,
                         {"long_name": "(max - min) / median of the seeds' best values"}),
            status=(dims, status.astype(str), {"long_name": "ok | flagged (see flags) | failed (see message)"}),
            flags=(dims, flags.astype(str)),
            message=(dims, message.astype(str)),
            **{k: (dims, v, {"units": units[k]}) for k, v in scalars.items()},
            history_phi=(dims + ("evaluation",), H["phi"], {"units": phi_units}),
            history_phi_vol=(dims + ("evaluation",), H["phi_vol"], {"units": phi_units}),
            history_phi_ind=(dims + ("evaluation",), H["phi_ind"], {"units": phi_units}),
            history_wall_s=(dims + ("evaluation",), H["wall_s"], {"units": "s"}),
            history_params=(dims + ("evaluation", "param"), HP),
            **cluster_vars,
        ),
        coords=dict(law=laws, seed=seeds, method=methods, param=names),
    )
    out.attrs = provenance(study=study.name, study_file=str(study.path), study_sha256=study.sha256,
                           objective=study.spec["fit"].get("objective", "likelihood"),
                           fit_files=[str(paths[j]) for j in paths],
                           paper=study.spec.get("paper", {}))
    return out


def _cluster_misfit(ds):
    """A fit file's misfit per residual cluster at the common noise levels (its field rows
    scaled by phi_vol_common / phi_vol, its indenter rows likewise), and which clusters are
    of the field."""
    labels = ds.residual_group.values
    r = ds.residual.values
    n_vol = ds.v_fem.size
    scale = np.ones(r.size)
    for key, rows in (("phi_vol", slice(0, n_vol)), ("phi_ind", slice(n_vol, None))):
        own = float(ds[key])
        common = float(ds[key + "_common"]) if key + "_common" in ds else own
        scale[rows] = common / own if own > 0 else 1.0
    G = int(labels.max()) + 1
    field = np.bincount(labels[:n_vol], minlength=G) > 0
    return labels, group_misfit(r, labels, G, scale), field


def _cluster_vars(clusters, shape, dims, phi_units) -> dict:
    """`phi_cluster_common` (dims, cluster) and `cluster_is_field` (cluster) when every fit
    with them has the same clusters (the same data and residual layout); else nothing."""
    if not clusters:
        return {}
    labels0, _, field = next(iter(clusters.values()))
    if any(lab.shape != labels0.shape or not np.array_equal(lab, labels0) for lab, _, _ in clusters.values()):
        return {}
    out = np.full(shape + (field.size,), np.nan)
    for (i, j, k), (_, phi, _) in clusters.items():
        out[i, j, k] = phi
    return dict(
        phi_cluster_common=(dims + ("cluster",), out, {
            "units": phi_units, "long_name": "misfit per residual cluster (12 mm node cube with all its "
            "frames, or 0.25 s of the indenter record) at the common noise levels: sums to phi_common"}),
        cluster_is_field=(("cluster",), field, {"long_name": "the cluster holds field (tracked motion) rows"}))


def _law_params(study, law):
    from ..laws import get_law
    return [p for p in get_law(law).free if p not in study.fixed(law)]
