"""The seed paper's validation (section 3.1, Tables 1 and 2), end to end with the CLI.

1. `liverinv synthesize config/studies/table1_truth.yaml`: poroelastic truth on the fine
   mesh, 100 warped volumes, indenter record;
2. `liverinv track` on the coarse (inverse) mesh;
3. `liverinv fit` of the biphasic law (PE, Table 1 seeds) and the SR law (Table 2 seeds),
   by Nelder-Mead and by least squares, each with a checkpoint;
4. writes OUT/tables.md (recovered parameters with their start values and, for PE, the
   error against the truth; Phi components; RMS figures; forward solves and solve time per
   fit; least-squares solves to reach the Nelder-Mead optimum) and the convergence figures
   OUT/convergence_<law>_<method>.png (the paper's Figs. 5-6).

Finished fits are read back; an interrupted fit resumes from its checkpoint.

    python benchmarks/validate_tables.py --out results/validation [--methods least-squares]
        [--laws PE SR] [--seeds 1 3] [--max-evaluations N] [--model-mesh medium]
        [--design-points 16 --polish 1] [--observation tracker] [--jacobian fd]

`--model-mesh` runs the forward model on another mesh than the coarse tracking mesh (a path,
or a `liverinv.meshgen` preset name generated into OUT); `--design-points N` adds the
multi-start stage to least squares (`liverinv fit --design-points`); `--observation
tracker` compares the model through the tracker's windows (`liverinv fit --observation`).
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
COARSE = ROOT.parent / "shared" / "benchmark" / "cylinder_coarse.msh"

SEEDS = {  # Table 1 and Table 2 start points
    "PE": [dict(C1=150, C2=4000, D1=2e-4, kappa=1e-8), dict(C1=300, C2=6000, D1=5e-3, kappa=5e-7),
           dict(C1=200, C2=5000, D1=1.5e-3, kappa=1e-7)],
    "SR": [dict(C1=200, C2=5000, D1=1.5e-3, g1=0.4, tau_g1=0.1),
           dict(C1=500, C2=1000, D1=1e-4, g1=0.6, tau_g1=0.5),
           dict(C1=50, C2=6000, D1=5e-5, g1=0.2, tau_g1=0.01)],
}


def sh(*args):
    t = time.perf_counter()
    subprocess.run([str(a) for a in args], check=True)
    return time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "validation")
    ap.add_argument("--laws", nargs="+", default=["PE", "SR"])
    ap.add_argument("--methods", nargs="+", default=["least-squares", "nelder-mead"])
    ap.add_argument("--max-evaluations", type=int, default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="seed numbers (1-3), default all")
    ap.add_argument("--exact-motion", action="store_true",
                    help="fit the exact truth motion (fine-mesh truth sampled at the coarse nodes, "
                         "the tracked confidence as weights) instead of the tracked motion: "
                         "separates the inverse mesh's bias from the tracking error")
    ap.add_argument("--model-mesh", default=None,
                    help="forward-model mesh: a path or a liverinv.meshgen preset (e.g. medium)")
    ap.add_argument("--design-points", type=int, default=0, help="least squares: multi-start design points")
    ap.add_argument("--polish", type=int, default=2, help="least squares: design points polished")
    ap.add_argument("--probe-evaluations", type=int, default=10,
                    help="least squares multi-start: residual evaluations of each run before the best is continued")
    ap.add_argument("--jacobian", choices=["sensitivity", "fd"], default="sensitivity",
                    help="least squares: Jacobian from the solve's sensitivities (default) or finite differences")
    ap.add_argument("--observation", choices=["nodes", "tracker"], default="nodes",
                    help="compare the model at the tracked nodes (the paper) or through the tracker's windows")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    model_mesh = model_mesh_path(args.model_mesh, out) if args.model_mesh else None
    bundle, truth, flow = out / "bundle.h5", out / "truth.nc", out / "flow.nc"
    if not bundle.exists():
        print(f"synthesize: {sh('liverinv', 'synthesize', ROOT / 'config/studies/table1_truth.yaml', '--out', bundle, '--truth-out', truth):.0f} s")
    if not flow.exists():
        print(f"track: {sh('liverinv', 'track', bundle, '--mesh', COARSE, '--out', flow):.0f} s")
    import xarray as xr

    from liverinv.plots import plot_fits
    if args.exact_motion:
        flow = exact_flow(truth, flow, out / "flow_exact.nc")
    rows, fits = [], {}
    for law in args.laws:
        for method in args.methods:
            for i, seed in enumerate(SEEDS[law], 1):
                if args.seeds and i not in args.seeds:
                    continue
                tag = f"{law}_{method}{'_exact' if args.exact_motion else ''}"
                if model_mesh:
                    tag += f"_{Path(model_mesh).stem}"
                if args.design_points and method == "least-squares":
                    tag += f"_ds{args.design_points}p{args.polish}e{args.probe_evaluations}"
                if args.observation == "tracker":
                    tag += "_obs"
                if method == "least-squares" and args.jacobian == "fd":
                    tag += "_fd"
                fit = out / f"fit_{tag}_seed{i}.nc"
                cmd = ["liverinv", "fit", "--bundle", bundle, "--flow", flow, "--mesh", COARSE,
                       "--law", law, "--method", method, "--checkpoint", out / f"ckpt_{tag}_{i}",
                       "--out", fit] + [f"--start={k}={v}" for k, v in seed.items()]
                if method == "least-squares":
                    cmd += ["--jacobian", args.jacobian]
                if args.max_evaluations:
                    cmd += ["--max-evaluations", args.max_evaluations]
                if model_mesh:
                    cmd += ["--model-mesh", model_mesh]
                if args.observation != "nodes":
                    cmd += ["--observation", args.observation]
                if args.design_points and method == "least-squares":
                    cmd += ["--design-points", args.design_points, "--polish", args.polish,
                            "--probe-evaluations", args.probe_evaluations]
                if not fit.exists():
                    print(f"{fit.name}: {sh(*cmd):.0f} s wall", flush=True)
                with xr.open_dataset(fit, engine="h5netcdf") as ds:
                    ds = ds.load()
                fits[(law, method, i)] = fit
                rows.append(summary_row(law, method, i, seed, ds))
                print(rows[-1], flush=True)
    table = tables(rows, fits)
    (out / "tables.md").write_text(table)
    print(table)
    for law in args.laws:
        for method in args.methods:
            paths = [fits[k] for k in sorted(fits) if k[:2] == (law, method)]
            if paths:
                plot_fits(paths, out / f"convergence_{law}_{method}.png",
                          truth=TRUTH if law == "PE" else None,
                          labels=[f"{law} {method} seed {k[2]}" for k in sorted(fits) if k[:2] == (law, method)])


TRUTH = dict(C1=200.0, C2=5000.0, D1=1.5e-3, kappa=1e-7)


def model_mesh_path(name, folder):
    """A mesh file, or a `liverinv.meshgen` preset generated once into folder/model_<name>.msh."""
    from liverinv.meshgen import PRESETS, generate_indentation_mesh
    if Path(name).exists():
        return Path(name)
    if name not in PRESETS:
        raise SystemExit(f"--model-mesh {name}: neither a file nor a preset ({', '.join(PRESETS)})")
    path = Path(folder) / f"model_{name}.msh"
    if not path.exists():
        generate_indentation_mesh(path, **PRESETS[name])
    return path


def exact_flow(truth, flow, out):
    """The tracked flow file with u_of replaced by the truth's frame-to-frame motion at the
    inverse mesh's nodes (the truth run may be on another mesh)."""
    import xarray as xr

    from liverinv.fem.probe import Probe
    from liverinv.fileio import write_netcdf
    if out.exists():
        return out
    tr = xr.load_dataset(truth, engine="h5netcdf")
    fl = xr.load_dataset(flow, engine="h5netcdf")
    probe = Probe(tr.X.values, tr.cells.values, fl.X.values)
    t = np.concatenate([fl.time_start.values[:1], fl.time_end.values])
    U = probe(tr.u.interp(time=t).values)
    fl["u_of"] = (fl.u_of.dims, U[1:] - U[:-1], fl.u_of.attrs)
    fl.attrs["note"] = f"u_of replaced by the exact motion of {truth} (validate_tables --exact-motion)"
    write_netcdf(fl, out)
    return out


def summary_row(law, method, i, seed, ds):
    n = ds.sizes["evaluation"]
    solves = int(ds.attrs["n_solves"])
    wall = float(ds.history_wall_s.values[:solves].sum())
    best = {p: float(v) for p, v in zip(ds.param.values, ds.best.values)}
    return dict(law=law, method=method, seed=i, start=seed, best=best, phi=float(ds.phi),
                phi_vol=float(ds.phi_vol), phi_ind=float(ds.phi_ind), rms_depth=float(ds.rms_depth),
                rms_axial=float(ds.rms_axial), solves=solves, evaluations=n, wall_s=wall,
                phi_history=ds.history_phi.values[:solves].copy(),
                wall_history=ds.history_wall_s.values[:solves].copy())


def tables(rows, fits):
    """Markdown: one row per fit (recovered parameters, errors against the truth for PE,
    misfit, forward solves, solve time) and the least-squares vs Nelder-Mead cost."""
    lines = []
    for law in dict.fromkeys(r["law"] for r in rows):
        names = list(rows[[r["law"] for r in rows].index(law)]["best"])
        lines += [f"\n### {law}\n", "| method | seed | " + " | ".join(names)
                  + " | Phi | Phi_vol | Phi_ind | RMS depth (mm) | RMS axial (mm) | solves | solve time (s) |",
                  "|---" * (len(names) + 9) + "|"]
        for r in (r for r in rows if r["law"] == law):
            cells = []
            for k in names:
                v = r["best"][k]
                cell = f"{v:.4g} ({r['start'][k]:.3g})"
                if law == "PE":
                    cell += f" {100 * (v / TRUTH[k] - 1):+.1f}%"
                cells.append(cell)
            lines.append(f"| {r['method']} | {r['seed']} | " + " | ".join(cells)
                         + f" | {r['phi']:.4e} | {r['phi_vol']:.4e} | {r['phi_ind']:.3e} | {1e3 * r['rms_depth']:.3f}"
                         f" | {1e3 * r['rms_axial']:.3f} | {r['solves']} | {r['wall_s']:.0f} |")
    cmp = []
    for r in rows:
        if r["method"] != "least-squares":
            continue
        nm = [q for q in rows if q["method"] == "nelder-mead" and q["law"] == r["law"] and q["seed"] == r["seed"]]
        if not nm:
            continue
        target = 1.01 * nm[0]["phi"]
        reached = np.nonzero(r["phi_history"] <= target)[0]
        n_ls = int(reached[0]) + 1 if reached.size else None
        t_ls = f"{r['wall_history'][:n_ls].sum():.0f}" if n_ls else "-"
        cmp.append(f"| {r['law']} | {r['seed']} | {nm[0]['phi']:.4e} | {nm[0]['solves']} | "
                   f"{n_ls if n_ls else 'not reached'} | {r['solves']} | "
                   + (f"{nm[0]['solves'] / n_ls:.1f}x |" if n_ls else "- |")
                   + f" {nm[0]['wall_s']:.0f} | {t_ls} |")
    if cmp:
        lines += ["\n### Least squares vs Nelder-Mead\n",
                  "| law | seed | NM optimum Phi | NM solves | LS solves to within 1 % of it | LS solves in all | ratio "
                  "| NM solve time (s) | LS solve time to within 1 % (s) |",
                  "|---|---|---|---|---|---|---|---|---|"] + cmp
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
