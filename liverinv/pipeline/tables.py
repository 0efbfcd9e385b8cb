"""A study's tables from its gathered fits (`fits.nc`), in the paper's layout: recovered value
with the start in parentheses, the error against the truth where known, Phi, Phi_ind, Phi_vol,
and a status column that keeps a flagged or failed fit from passing as a clean number. The
tables hold only what the data and the code determine, so a rerun reproduces them digit for
digit; the solve times are in `fits.nc` (`solve_time_s`) and the workflow's benchmark files."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import xarray as xr

from ..identify.compare import WORSE_Z, paired_misfit_test

__all__ = ["fit_table", "markdown_table", "ranking", "ranking_table"]


def _law_params(ds, law):
    return [str(p) for p in ds.param.values if np.isfinite(ds.start.sel(law=law, param=p).values).any()]


def fit_table(ds: xr.Dataset) -> pd.DataFrame:
    """One row per fit (law, method, seed): numbers only, for a CSV."""
    rows = []
    for law in ds.law.values:
        params = _law_params(ds, law)
        for method in ds.method.values:
            for seed in ds.seed.values:
                f = ds.sel({"law": law, "seed": seed, "method": method})
                row = dict(law=str(law), method=str(method), seed=str(seed), status=str(f.status.values),
                           flags=str(f.flags.values), message=str(f.message.values))
                for p in params:
                    b, t = float(f.best.sel(param=p)), float(ds.truth.sel(param=p))
                    row[p] = b
                    row[f"{p}_start"] = float(f.start.sel(param=p))
                    row[f"{p}_rel_sd"] = float(f.rel_sd.sel(param=p))
                    row[f"{p}_error"] = b / t - 1 if np.isfinite(t) and t != 0 else np.nan
                for k in ("phi", "phi_ind", "phi_vol", "phi_common", "phi_ind_common", "phi_vol_common", "rms_depth", "rms_axial", "rms_force", "n_solves"):
                    row[k] = float(f[k])
                rows.append(row)
    return pd.DataFrame(rows)


def _g(v, fmt=".4g"):
    return "-" if not np.isfinite(v) else format(v, fmt)


def markdown_table(ds: xr.Dataset, rank: pd.DataFrame | None = None) -> str:
    """The paper's layout per law; flags below each table; then `rank` (by default `ranking(ds)`)."""
    df = fit_table(ds)
    units = dict(zip([str(p) for p in ds.param.values], [str(u) for u in ds.param_unit.values]))
    phi_u = ds.phi.attrs.get("units", "")
    out = [f"# Study `{ds.attrs.get('study', '')}`: fits\n",
           f"Objective: {ds.attrs.get('objective', '')} (Phi {'dimensionless' if phi_u == '1' else 'in ' + phi_u}). Each cell: recovered value "
           "(start), and the error against the truth where it is known. Status `flagged` or `failed` "
           "means the number is not to be used as it stands; the reasons follow each table.\n"]
    for law in ds.law.values:
        params = _law_params(ds, law)
        sub = df[df.law == law]
        head = ["method", "seed"] + [f"{p} ({units[p]})" for p in params] + ["Phi", "Phi_ind", "Phi_vol", "solves",
                                                                              "status"]
        out += [f"\n## {law}\n", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        notes = []
        for _, r in sub.iterrows():
            cells = [r.method, r.seed]
            for p in params:
                c = f"{_g(r[p])} ({_g(r[p + '_start'])})"
                if np.isfinite(r[p + "_error"]):
                    c += f" {100 * r[p + '_error']:+.1f} %"
                cells.append(c)
            cells += [_g(r.phi), _g(r.phi_ind), _g(r.phi_vol), _g(r.n_solves, ".0f"),
                      f"**{r.status}**" if r.status != "ok" else "ok"]
            out.append("| " + " | ".join(str(c) for c in cells) + " |")
            if r.status == "flagged":
                notes.append(f"- {r.method} seed {r.seed}: {r['flags']}")
            elif r.status == "failed":
                notes.append(f"- {r.method} seed {r.seed}: failed: {r.message}")
        if notes:
            out += ["", "Flags:", *notes]
    rk = ranking(ds) if rank is None else rank
    if rk is not None:
        out += ["\n## Ranking of the laws by Phi (best fit of each law, at the common noise levels; "
                "`phi_vol_rank`: the order by Phi_vol)\n",
                _plain_markdown(rk)]
        if "z" in rk:
            out += ["", f"z_vol, z_ind, z: each law against the first-ranked one, the paired test of their misfits "
                        f"per residual cluster (12 mm node cubes with all their frames, 0.25 s of the indenter "
                        f"record; cluster-robust, `liverinv.identify.compare`); positive: worse. `clearly_worse` "
                        f"names the parts where z > {WORSE_Z:.2f} (one-sided p < 0.01): worse by more than "
                        f"the data's own error explains. Between nested laws only indicative."]
    out += ["", f"Provenance: study file sha256 {ds.attrs.get('study_sha256', '?')[:16]}..., liverinv "
                f"{ds.attrs.get('liverinv_version', '?')}, git {ds.attrs.get('git_revision', '?')}."]
    return "\n".join(out) + "\n"


def ranking(ds: xr.Dataset) -> pd.DataFrame | None:
    """The laws ordered by their best Phi (over seeds and methods, fits not failed) at the
    common noise levels (the balance stage's levels are each fit's own), set beside the
    paper's values where the study gives them; None with a single law.

    Phi, not its part Phi_vol: Phi is the likelihood every fit minimizes, and a law can buy a
    lower Phi_vol with a worse force record (the Table 3 surrogate: BR's Phi_vol 0.3 % below
    SR's, its Phi_ind 50 % above). The paper's Phi was almost all Phi_vol (Phi_ind 0.6 % of
    it), so its order by Phi and by Phi_vol is the same; here the force record's noise weight
    makes Phi_ind a real part of Phi. `phi_vol_rank` gives the order by Phi_vol beside it.

    Where the fits carry their misfit per residual cluster (`phi_cluster_common`), each law
    is also tested against the first-ranked one by the paired, cluster-robust test of
    `identify.compare` on Phi_vol, Phi_ind and Phi (`z_vol`, `z_ind`, `z`; positive: worse),
    and `clearly_worse` names the parts in which it is worse at the one-sided 1 % level."""
    if ds.sizes["law"] < 2:
        return None
    paper = json.loads(ds.attrs.get("paper", "{}") or "{}")
    rows, chosen = [], {}
    for law in ds.law.values:
        f = ds.sel(law=law)
        ok = (f.status != "failed").values
        pv = np.where(ok, f.phi_common.values, np.nan)
        if not np.isfinite(pv).any():
            rows.append(dict(law=str(law), phi_vol=np.nan, phi_ind=np.nan, phi=np.nan, status="failed"))
            continue
        j, k = np.unravel_index(np.nanargmin(pv), pv.shape)
        g = f.isel({"seed": j, "method": k})
        chosen[str(law)] = g
        rows.append(dict(law=str(law), phi_vol=float(g.phi_vol_common), phi_ind=float(g.phi_ind_common),
                         phi=float(g.phi_common),
                         status=str(g.status.values)))
    df = pd.DataFrame(rows).sort_values("phi", na_position="last", kind="stable").reset_index(drop=True)
    df.insert(1, "rank", np.arange(1, len(df) + 1))
    df["phi_vs_best"] = df.phi / df.phi.min()
    df["phi_vol_vs_best"] = df.phi_vol / df.phi_vol.min()
    df["phi_vol_rank"] = df.phi_vol.rank(method="first", na_option="bottom").astype(int)
    if "phi_cluster_common" in ds:
        _versus_first(df, chosen, ds.cluster_is_field.values.astype(bool))
    if paper:
        pp = {law: v.get("phi", v.get("phi_vol", np.nan)) for law, v in paper.items()}
        order = sorted((v, law) for law, v in pp.items() if np.isfinite(v))
        prank = {law: r + 1 for r, (_, law) in enumerate(order)}
        df["paper_phi"] = [pp.get(law, np.nan) for law in df.law]
        df["paper_phi_vol"] = [paper.get(law, {}).get("phi_vol", np.nan) for law in df.law]
        df["paper_rank"] = [prank.get(law, np.nan) for law in df.law]
    return df


def ranking_table(ds: xr.Dataset, rank: pd.DataFrame | None = None) -> pd.DataFrame:
    """`rank` (by default `ranking(ds)`), or for a study of one law its row with a note that
    there is nothing to rank (the workflow's ranking.csv exists for every study)."""
    rk = ranking(ds) if rank is None else rank
    if rk is None:
        rk = pd.DataFrame(dict(law=[str(v) for v in ds.law.values], rank=1,
                               note="the study fits one law: nothing to rank"))
    return rk


def _versus_first(df: pd.DataFrame, chosen: dict, field: np.ndarray) -> None:
    """Add to the ranking `df` the paired test of each law's chosen fit against the first
    row's (z_vol, z_ind, z) and `clearly_worse`, the parts where z > WORSE_Z."""
    parts = {"z_vol": ("Phi_vol", field), "z_ind": ("Phi_ind", ~field), "z": ("Phi", np.ones_like(field))}
    first = chosen.get(str(df.law.iloc[0]))
    for key, (_, mask) in parts.items():
        df[key] = [paired_misfit_test(chosen[law].phi_cluster_common.values[mask],
                                      first.phi_cluster_common.values[mask])["z"]
                   if i > 0 and first is not None and law in chosen
                   and np.isfinite(chosen[law].phi_cluster_common.values[mask]).all() else np.nan
                   for i, law in enumerate(df.law)]
    df["clearly_worse"] = [", ".join(label for key, (label, _) in parts.items() if r[key] > WORSE_Z)
                           or ("-" if i == 0 or not np.isfinite(r["z"]) else "no")
                           for i, (_, r) in enumerate(df.iterrows())]


def _plain_markdown(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(_g(v) if isinstance(v, float) else str(v) for v in r) + " |")
    return "\n".join(lines)
