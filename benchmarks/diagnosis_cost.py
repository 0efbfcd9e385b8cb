"""The cost of one diagnosis in forward solves: on a discover run's data and base fit, time one
plain solve of the fitted law (the faster of two, after one untimed) and one `diagnose` (all candidates, scans
included), from the fit's solution as in `discover` and without it.

    python benchmarks/diagnosis_cost.py --dir /work/runs/null --tag null_s1 \
        --mesh ../shared/benchmark/cylinder_coarse.msh
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main(argv=None):
    import numpy as np
    import xarray as xr

    from liverinv.diagnose.files import discovery_objective
    from liverinv.diagnose.score import diagnose
    from liverinv.laws import PARAMS, get_law

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, required=True, help="the directory of benchmarks/hidden_effects.py")
    ap.add_argument("--tag", required=True, help="CASE_sSEED")
    ap.add_argument("--mesh", required=True)
    args = ap.parse_args(argv)
    d = args.dir
    ds = xr.load_dataset(d / f"{args.tag}_disc.nc", engine="h5netcdf")
    # the base fit on the tracking mesh (`params` holds the final fit's on a finer mesh when the
    # base law is the last step)
    fits = ds.params_tracking_mesh if "params_tracking_mesh" in ds else ds.params
    law, params = str(ds.law.values[0]), json.loads(fits.values[0])
    obj = discovery_objective(ds, bundle=d / f"{args.tag}.h5", flow=d / f"{args.tag}_flow.nc", mesh=args.mesh)
    names = [k for k in params if k in get_law(law).free]
    p = {k: params[k] for k in names}
    ev = obj(p)          # (the first solve also smooths the indenter record: not timed)
    t_solve = np.inf
    for _ in range(2):
        t = time.perf_counter()
        ev = obj(p)
        t_solve = min(t_solve, time.perf_counter() - t)
    # as in `discover`, the fit's last solve (the optimum's) is the objective's latest: the
    # diagnosis's solves start from it; then without it ("cold")
    for cold in (False, True):
        if cold:
            obj._solved.clear()
        t = time.perf_counter()
        out = diagnose(obj, p, names, [PARAMS[n].scale == "log" for n in names], float(ev.phi_vol))
        t_diag = time.perf_counter() - t
        print(f"{args.tag} ({law}, {'cold' if cold else 'from the fit'}): plain solve {t_solve:.2f} s, diagnosis "
              f"{t_diag:.2f} s = {t_diag / t_solve:.2f} solves ({out['n_solves']} solves with sensitivities); "
              f"recommended {out['recommended']}")


if __name__ == "__main__":
    main()
