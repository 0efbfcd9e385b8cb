"""Linearized parameter bias of a model mesh: how far the optimum moves from the truth when
data simulated on one mesh are fitted with the forward model on another.

At the true parameters x_t, with the residual vector r(x_t) (nonzero only through the model
mesh's discretization, and through tracking error if the flow is tracked) and its
forward-difference Jacobian J, one Gauss-Newton step from the truth,

    dx = -(J^T W J)^-1 J^T W r(x_t),

predicts the bias of the fitted normalized parameters (log10 for moduli and permeability),
for the paper's objective (W = I) and for variants: without the indenter term, and with the
nodes within a distance of the punch rim left out. Costs 1 + n_params forward solves.

    python benchmarks/mesh_bias.py --flow results/validation/flow_exact.nc \
        --bundle results/validation/bundle.h5 [--model-mesh medium]

Measured (Table 1 truth on cylinder_fine.msh, exact motion at the coarse nodes) against the
full least-squares fit of the same data on the coarse mesh: predicted C1 -3.35 %, C2 -0.14 %,
D1 +10.05 %, kappa +0.63 %; fitted -3.1 %, -0.2 %, +10.3 %, +0.9 %.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
COARSE = ROOT.parent / "shared" / "benchmark" / "cylinder_coarse.msh"
TRUTH = dict(C1=200.0, C2=5000.0, D1=1.5e-3, kappa=1e-7)
A_PUNCH, H = 0.006, 0.0303


def linear_bias(J, r, rows=None):
    """Percent change of each parameter predicted by one Gauss-Newton step from the truth
    over the selected residual rows (log-scaled parameters)."""
    rows = np.ones(len(r), bool) if rows is None else rows
    dx = -np.linalg.lstsq(J[rows], r[rows], rcond=None)[0]
    return 100 * (10 ** dx - 1)


def main(argv=None):
    import xarray as xr

    from liverinv.forward import ForwardModel
    from liverinv.identify.objective import Measurements, Objective
    from liverinv.identify.optimize import Fit
    from liverinv.imaging.bundle import open_bundle
    from exact_motion import model_mesh_path

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flow", type=Path, required=True, help="flow file (tracked, or benchmarks/exact_motion.py)")
    ap.add_argument("--bundle", type=Path, required=True, help="bundle with the indenter record")
    ap.add_argument("--model-mesh", default=str(COARSE), help="a mesh file or a liverinv.meshgen preset")
    ap.add_argument("--law", default="PE")
    ap.add_argument("--truth", nargs="+", default=[f"{k}={v}" for k, v in TRUTH.items()], metavar="NAME=VALUE")
    args = ap.parse_args(argv)
    truth = {k: float(v) for k, v in (s.split("=") for s in args.truth)}
    mesh = model_mesh_path(args.model_mesh, Path(args.flow).parent)
    with open_bundle(args.bundle) as b:
        ind = b.indenter
        t_ind, depth, force = ind.time_s, ind.displacement_m, ind.force_N
    flow = xr.load_dataset(args.flow, engine="h5netcdf")
    obj = Objective(ForwardModel(mesh), args.law, Measurements.from_flow(flow, t_ind, depth, force))
    fit = Fit(obj, truth)
    J, r = fit.fd_jacobian(fit.to_x(list(truth.values())))
    n_vol = obj.v_of.size
    X = flow.X.values
    dist = np.hypot(np.hypot(X[:, 0], X[:, 1]) - A_PUNCH, X[:, 2] - H)
    node_of_row = np.tile(np.repeat(np.arange(obj.N), 3), obj.K)
    print(f"model mesh {mesh}: {obj.forward.mesh.n_nodes} nodes; at the truth Phi_vol {r[:n_vol] @ r[:n_vol]:.3e}, "
          f"Phi_ind {r[n_vol:] @ r[n_vol:]:.3e}")
    print("predicted bias (%): " + ", ".join(fit.names))
    vol = np.arange(len(r)) < n_vol
    print(f"  paper objective        {np.round(linear_bias(J, r), 2)}")
    print(f"  without indenter term  {np.round(linear_bias(J, r, vol), 2)}")
    print(f"  indenter term only     {np.round(linear_bias(J, r, ~vol), 2)}")
    for cut in (0.004, 0.008):
        rows = ~vol.copy()
        rows[:n_vol] = dist[node_of_row] > cut
        print(f"  nodes > {1e3 * cut:.0f} mm from rim  {np.round(linear_bias(J, r, rows), 2)}")


if __name__ == "__main__":
    main()
