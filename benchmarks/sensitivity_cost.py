"""Cost of the least-squares Jacobian: one objective evaluation without and with the
solve's parameter sensitivities, against the forward-difference Jacobian it replaces
(1 + n plain solves), on the Table 1 data (a bundle and its tracked flow).

    python benchmarks/sensitivity_cost.py --bundle results/validation_v2/bundle.h5 \\
        --flow results/validation_v2/flow.nc [--law PE] [--model-mesh M] [--observation tracker]

Prints the wall time of each kind of evaluation and the relative difference between the
sensitivity Jacobian and central differences of plain solves (step 1e-4 in normalized
parameters). Measured (coarse mesh, PE, 99 steps, quiet machine): plain solve 9.5 s, with 4
sensitivities 20.7 s (2.2x), forward-difference Jacobian 47 s; agreement 2e-5 to 4e-4.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1].parent / "shared" / "benchmark"
START = {"PE": dict(C1=200.0, C2=5000.0, D1=1.5e-3, kappa=1e-7),
         "SR": dict(C1=250.0, C2=7700.0, D1=1.55e-3, g1=0.34, tau_g1=0.33),
         "SBR": dict(C1=250.0, C2=7700.0, D1=1.55e-3, g1=0.34, tau_g1=0.33, D2=1000.0, k1=0.3, tau_k1=0.5)}


def main(argv=None):
    import xarray as xr

    from liverinv.imaging.observation import tracking_observation
    from liverinv.forward import ForwardModel
    from liverinv.identify.objective import Measurements, Objective
    from liverinv.identify.optimize import Fit
    from liverinv.imaging.bundle import open_bundle

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--flow", type=Path, required=True)
    ap.add_argument("--mesh", type=Path, default=BENCH / "cylinder_coarse.msh")
    ap.add_argument("--model-mesh", type=Path, default=None)
    ap.add_argument("--law", default="PE", choices=sorted(START))
    ap.add_argument("--observation", default="nodes", choices=["nodes", "tracker"])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)
    flow = xr.load_dataset(args.flow, engine="h5netcdf")
    fm = ForwardModel(args.model_mesh or args.mesh)
    with open_bundle(args.bundle) as b:
        ind = b.indenter
        obs = tracking_observation(b, flow, args.mesh, fm.mesh) if args.observation == "tracker" else None
        meas = Measurements.from_flow(flow, ind.time_s, ind.displacement_m, ind.force_N)
    obj = Objective(fm, args.law, meas, observation=obs)
    fit = Fit(obj, START[args.law])
    x = fit.to_x(list(START[args.law].values()))
    n = len(x)
    plain, sens = [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        obj(fit.params_of(x))
        plain.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        directions = [fit.params_of(x + fit.sens_step * e) for e in np.eye(n)]
        ev = obj(fit.params_of(x), directions=directions, eps=fit.sens_step)
        sens.append(time.perf_counter() - t0)
    # central differences of plain solves (a residual of the sensitivity solve differs from
    # the plain one by the solver tolerance along another iteration path, ~2e-4 relative)
    h = 1e-4
    pairs = [(obj(fit.params_of(x + h * e)), obj(fit.params_of(x - h * e))) for e in np.eye(n)]
    if all(p.ok and m.ok for p, m in pairs):
        J_fd = np.column_stack([(p.residual - m.residual) / (2 * h) for p, m in pairs])
        err = np.linalg.norm(ev.jacobian - J_fd, axis=0) / np.linalg.norm(J_fd, axis=0)
    else:
        err = [np.nan if p.ok and m.ok else np.inf for p, m in pairs]   # inf: a solve of the check failed
    print(f"{args.law} on {fm.mesh.n_nodes} nodes, {len(obj.t_drive) - 1} steps, observation {args.observation}")
    print(f"plain solve: {min(plain):.1f} s; solve with {n} sensitivities: {min(sens):.1f} s "
          f"({min(sens) / min(plain):.2f}x); forward-difference Jacobian: {(1 + n) * min(plain):.1f} s")
    print("relative difference to central differences per parameter: "
          + ", ".join(f"{k} {e:.1e}" for k, e in zip(fit.names, err)))


if __name__ == "__main__":
    main()
