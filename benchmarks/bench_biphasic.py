"""Benchmark of the biphasic (poroelastic) forward model on the canonical indentation problem.

The poroelastic truth case of the benchmark table (C1 200, C2 5000, D1 1.5e-3, kappa 1e-7),
displacement-controlled load/unload 0 -> 9.2 mm -> 0 at 2 mm/s. Prints per mesh and case:
wall time, nonlinear iterations, tangents, assembly / factorization / back-substitution
time, F at 4.6 mm (loading), 9.2 mm and 4.6 mm (unloading), the peak fluid load fraction on
loading. Cases (biphasic laws run on FEBio's 8-point tet10 rule, see `ForwardModel.biphasic_space`):
  - 100 frames (dt 0.092 s): the run inside the Table 1 fits (coarse) and the truth (fine);
  - 200 frames (half the step): time-step convergence;
  - with --febio: 46 + 46 steps (dt 0.1 s) against the FEBio 4 reference (Taylor-Hood,
    8-point rule) 0.220266 / 0.929160 / 0.175165 N (coarse mesh).

    OMP_NUM_THREADS=1 python benchmarks/bench_biphasic.py [--meshes coarse fine] [--febio]
        [--solver bfgs|full] [--frames 101 201] [--order coarse=2 fine=2]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from liverinv.fem.solver import NewtonOptions
from liverinv.forward import ForwardModel
from liverinv.loading import ramp_history

BENCH = Path(__file__).resolve().parents[1].parent / "shared" / "benchmark"
PE = dict(C1=200.0, C2=5000.0, D1=1.5e-3, kappa=1e-7)
FEBIO_TH = (0.220266, 0.929160, 0.175165)


def forces(ds):
    """F at 4.6 mm loading, 9.2 mm, 4.6 mm unloading (interpolated between frames)."""
    d, F = ds.indenter_depth.values, ds.indenter_force.values
    k = int(np.argmax(d))
    up = float(np.interp(4.6e-3, d[: k + 1], F[: k + 1]))
    down = float(np.interp(4.6e-3, d[k:][::-1], F[k:][::-1]))
    return up, float(F[k]), down


def row(name, mesh, ds, wall):
    t = json.loads(ds.attrs["solver"])
    d = ds.indenter_depth.values
    k = int(np.argmax(d))
    ff = ds.fluid_load_fraction.values[1: k + 1]
    f46, f92, f46u = forces(ds)
    print(f"{name:<30} {mesh:<7} {wall:7.2f} {int(ds.newton_iterations.sum()):6d} {t['tangents']:5d} "
          f"{t['assembly_s']:6.2f} {t['factor_s']:6.2f} {t['solve_s']:6.2f} "
          f"{f46:9.6f} {f92:9.6f} {f46u:9.6f} {np.nanmax(ff):7.4f}", flush=True)
    return np.array([f46, f92, f46u])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["coarse", "fine"])
    ap.add_argument("--frames", nargs="+", type=int, default=[101, 201])
    ap.add_argument("--order", nargs="+", default=["coarse=2", "fine=2"],
                    help="quadrature order per mesh, NAME=ORDER (2 or 3: biphasic laws use FEBio's "
                         "8-point rule; 4: 11 points, 5: 14 points)")
    ap.add_argument("--febio", action="store_true", help="FEBio 8-point rule, dt 0.1 s (coarse)")
    ap.add_argument("--solver", default="bfgs", choices=["bfgs", "full"])
    ap.add_argument("--linear-solver", default=None, choices=["pardiso", "superlu"])
    args = ap.parse_args(argv)
    opts = NewtonOptions(method=args.solver, solver=args.linear_solver)
    print(f"{'case':<30} {'mesh':<7} {'wall_s':>7} {'iters':>6} {'tang':>5} {'asm_s':>6} "
          f"{'fact_s':>6} {'solv_s':>6} {'F4.6_N':>9} {'F9.2_N':>9} {'F4.6u_N':>9} {'ff_max':>7}")
    orders = dict(item.split("=") for item in args.order)
    for name in args.meshes:
        order = int(orders.get(name, 2))
        fm = ForwardModel(BENCH / f"cylinder_{name}.msh", quadrature_order=order)
        ref = None
        for frames in args.frames:
            hist = ramp_history(9.2e-3, 2e-3, frames=frames, unload=True)
            t0 = time.perf_counter()
            ds = fm.run("PE", PE, hist, opts)
            f = row(f"PE disp {frames - 1} frames, {ds.attrs['quadrature_points']}-pt", name, ds, time.perf_counter() - t0)
            if ref is not None:
                print(f"    halving the step changes F by {np.array2string(100 * (f / ref - 1), precision=3)} %")
            ref = f
        if args.febio and name == "coarse":
            hist = ramp_history(9.2e-3, 2e-3, steps=46, unload=True)
            t0 = time.perf_counter()
            ds = fm.run("PE", PE, hist, opts)
            f = row(f"PE disp 46+46, {ds.attrs['quadrature_points']}-pt", name, ds, time.perf_counter() - t0)
            print(f"    vs FEBio 4 (Taylor-Hood, dt 0.1 s): {np.array2string(100 * (f / FEBIO_TH - 1), precision=4)} %")


if __name__ == "__main__":
    main()
