"""The seed paper's validation (section 3.1, Tables 1 and 2), end to end with the CLI.

1. `liverinv synthesize config/studies/table1_truth.yaml`: poroelastic truth on the fine
   mesh, 100 warped volumes, indenter record;
2. `liverinv track` on the coarse (inverse) mesh;
3. `liverinv fit` of the biphasic law (PE, Table 1 seeds) and the SR law (Table 2 seeds),
   by Nelder-Mead and by least squares, each with a checkpoint;
4. prints the recovered parameters, Phi components, forward solves and wall time per fit.

    python benchmarks/validate_tables.py --out results/validation [--methods least-squares]
        [--laws PE SR] [--max-evaluations N]
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path

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
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    bundle, truth, flow = out / "bundle.h5", out / "truth.nc", out / "flow.nc"
    if not bundle.exists():
        print(f"synthesize: {sh('liverinv', 'synthesize', ROOT / 'config/studies/table1_truth.yaml', '--out', bundle, '--truth-out', truth):.0f} s")
    if not flow.exists():
        print(f"track: {sh('liverinv', 'track', bundle, '--mesh', COARSE, '--out', flow):.0f} s")
    import xarray as xr
    for law in args.laws:
        for method in args.methods:
            for i, seed in enumerate(SEEDS[law], 1):
                fit = out / f"fit_{law}_{method}_seed{i}.nc"
                cmd = ["liverinv", "fit", "--bundle", bundle, "--flow", flow, "--mesh", COARSE,
                       "--law", law, "--method", method, "--checkpoint", out / f"ckpt_{law}_{method}_{i}",
                       "--out", fit] + [f"--start={k}={v}" for k, v in seed.items()]
                if args.max_evaluations:
                    cmd += ["--max-evaluations", args.max_evaluations]
                wall = sh(*cmd) if not fit.exists() else float("nan")
                with xr.open_dataset(fit, engine="h5netcdf") as ds:
                    best = ", ".join(f"{p}={v:.4g}" for p, v in zip(ds.param.values, ds.best.values))
                    print(f"{law} {method} seed {i}: {best}; Phi {float(ds.phi):.3e} (vol {float(ds.phi_vol):.3e}, "
                          f"ind {float(ds.phi_ind):.3e}); {ds.attrs['n_solves']} solves; {wall:.0f} s", flush=True)


if __name__ == "__main__":
    main()
