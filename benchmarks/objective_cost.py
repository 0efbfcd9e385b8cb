"""Cost of one forward solve under the paper's objective (force-driven, Eqs. 4-5) and the
noise-aware likelihood (depth-driven, seen through the tracker), plain and with the
sensitivities along every free parameter, at given parameters.

    python benchmarks/objective_cost.py --bundle B.h5 --flow F.nc \
        --mesh ../shared/benchmark/cylinder_coarse.msh --law elastic \
        --param C1=200 --param C2=5000 --param D1=1.5e-3
"""

import argparse
import time

import xarray as xr

from liverinv.commands import parse_assignments
from liverinv.imaging.observation import tracking_observation
from liverinv.forward import ForwardModel
from liverinv.identify.noise import noise_model
from liverinv.identify.objective import Measurements, Objective
from liverinv.identify.optimize import Fit
from liverinv.imaging.bundle import open_bundle


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--flow", required=True)
    ap.add_argument("--mesh", required=True)
    ap.add_argument("--law", required=True)
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--repeat", type=int, default=2, help="best of this many solves")
    args = ap.parse_args()
    params = parse_assignments(args.param, "--param")
    flow = xr.open_dataset(args.flow, engine="h5netcdf").load()
    fm = ForwardModel(args.mesh)
    with open_bundle(args.bundle) as b:
        ind = b.indenter
        t0 = time.perf_counter()
        observation = tracking_observation(b, flow, fm.mesh, fm.mesh)
        t_obs = time.perf_counter() - t0
        data = Measurements.from_flow(flow, ind.time_s, ind.displacement_m, ind.force_N)
        noise = noise_model(ind, flow)
    print(f"observation operator build: {t_obs:.1f} s")
    for name, obj in (("paper, at the nodes", Objective(fm, args.law, data)),
                      ("likelihood, through the tracker",
                       Objective(fm, args.law, data, observation=observation, noise=noise))):
        fit = Fit(obj, params)
        x = fit.to_x([params[k] for k in fit.names])
        plain, sens = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            obj(params)
            plain.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            fit.solve_with_jacobian(x)
            sens.append(time.perf_counter() - t0)
        print(f"{name}: {len(obj.t_drive)} driving times; plain solve {min(plain):.2f} s, "
              f"with {len(fit.names)} sensitivities {min(sens):.2f} s")


if __name__ == "__main__":
    main()
