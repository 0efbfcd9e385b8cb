"""Benchmark of the forward engine on the canonical indentation problem.

Prints, for the coarse and fine benchmark meshes: wall time, nonlinear iterations,
assembly / factorization / back-substitution time and F at 4.6 mm and 9.2 mm for
  - elastic, displacement control, 46 + 46 steps (reference: felupe 0.1985 / 0.8460 N,
    FEBio 4-point rule 0.198546 / 0.846028 N on the coarse mesh),
  - SR (C1 200, C2 5000, D1 1.5e-3, g1 0.4, tau_g1 0.06), force control over 100 frames,
    driven by the force of its own displacement-controlled load/unload,
and, with --felupe, felupe on the same mesh and steps, timed side by side.

    python benchmarks/bench_forward.py [--meshes coarse fine] [--felupe] [--solver full]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from liverinv.fem.solver import NewtonOptions
from liverinv.forward import ForwardModel, force_history_of
from liverinv.loading import ramp_history

BENCH = Path(__file__).resolve().parents[1].parent / "shared" / "benchmark"
ELASTIC = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
SR = dict(C1=200.0, C2=5000.0, D1=1.5e-3, g1=0.4, tau_g1=0.06)


def f_at(ds, depth):
    """F on the loading branch at a depth (interpolated if no frame hits it)."""
    d, F = ds.indenter_depth.values, ds.indenter_force.values
    k = int(np.argmax(d))
    return float(np.interp(depth, d[: k + 1], F[: k + 1]))


def row(name, mesh, ds, wall):
    import json
    t = json.loads(ds.attrs["solver"])
    print(f"{name:<34} {mesh:<7} {wall:7.2f} {int(ds.newton_iterations.sum()):6d} "
          f"{t['tangents']:5d} {t['residuals']:6d} {t['assembly_s']:7.2f} {t['factor_s']:7.2f} "
          f"{t['solve_s']:7.2f} {f_at(ds, 4.6e-3):9.6f} {f_at(ds, 9.2e-3):9.6f}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["coarse", "fine"])
    ap.add_argument("--felupe", action="store_true", help="also run felupe side by side (coarse)")
    ap.add_argument("--solver", default="bfgs", choices=["bfgs", "full"])
    ap.add_argument("--linear-solver", default=None, choices=["pardiso", "superlu"])
    args = ap.parse_args(argv)
    opts = NewtonOptions(method=args.solver, solver=args.linear_solver)
    print(f"{'case':<34} {'mesh':<7} {'wall_s':>7} {'iters':>6} {'tang':>5} {'resid':>6} "
          f"{'asm_s':>7} {'fact_s':>7} {'solv_s':>7} {'F4.6mm_N':>9} {'F9.2mm_N':>9}")
    for name in args.meshes:
        fm = ForwardModel(BENCH / f"cylinder_{name}.msh")
        hist = ramp_history(9.2e-3, 2e-3, steps=46, unload=True)
        t0 = time.perf_counter()
        ds = fm.run("elastic", ELASTIC, hist, opts)
        row("elastic disp 46+46", name, ds, time.perf_counter() - t0)
        hist100 = ramp_history(9.2e-3, 2e-3, frames=101, unload=True)
        t0 = time.perf_counter()
        ds_d = fm.run("SR", SR, hist100, opts)
        row("SR disp 100 frames", name, ds_d, time.perf_counter() - t0)
        t0 = time.perf_counter()
        ds_f = fm.run("SR", SR, force_history_of(ds_d), opts)
        row("SR force 100 frames", name, ds_f, time.perf_counter() - t0)
        err = np.abs(ds_f.indenter_depth.values - ds_d.indenter_depth.values).max()
        print(f"    force control reproduces the depth history to {err:.2e} m")
    if args.felupe:
        sys.path.insert(0, str(Path(__file__).parent))
        from felupe_reference import run_felupe
        out = run_felupe(BENCH / "cylinder_coarse.msh", **ELASTIC, steps=46, unload=True)
        print(f"{'felupe elastic disp 46+46':<34} {'coarse':<7} {out['wall_time_s']:7.2f} "
              f"{out['newton_iterations']:6d} {'':>5} {'':>6} {'':>7} {'':>7} {'':>7} "
              f"{out['force_4p6mm']:9.6f} {out['force_9p2mm']:9.6f}")


if __name__ == "__main__":
    main()
