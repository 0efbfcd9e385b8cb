"""Parameter errors of discoveries against their truth: the reported fit (the last step),
the uncorrected fit on the final (medium) mesh and the tracking mesh's fit, side by side.

Reads DISCOVERY.nc files written by `benchmarks/hidden_effects.py`, each with its truth study
(`<tag>.yaml`) beside it, and prints each fit's relative errors and their summary over all
files (median, mean, largest absolute error; of all parameters and of the added effects' only).

    python benchmarks/discovery_errors.py DIR/*_warp_s3?_disc.nc
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import yaml

BASE = ("C1", "C2", "D1")


def errors(disc: Path) -> dict[str, dict[str, float]]:
    """{fit: {param: relative error in %}} for the reported, final-mesh and tracking-mesh fits,
    over the parameters the last step fitted (those with a standard deviation: a law's
    held values, such as BR's D2, are left out) that the truth gives a non-zero value."""
    import xarray as xr
    ds = xr.load_dataset(disc, engine="h5netcdf")
    truth = yaml.safe_load(Path(str(disc).replace("_disc.nc", ".yaml")).read_text())["params"]
    fits = {"reported": json.loads(ds.params.values[-1]),
            "final mesh, uncorrected": json.loads(ds.attrs.get("final_params", "{}")),
            "tracking mesh": json.loads(ds.params_tracking_mesh.values[-1])}
    fitted = json.loads(ds.param_sd_total.values[-1])
    return {name: {k: 100.0 * (v / truth[k] - 1.0) for k, v in p.items() if truth.get(k) and k in fitted}
            for name, p in fits.items() if p}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("discoveries", nargs="+", type=Path)
    args = ap.parse_args(argv)
    pooled: dict[str, list[tuple[str, float]]] = {}
    for disc in args.discoveries:
        print(disc.name)
        for name, e in errors(disc).items():
            pooled.setdefault(name, []).extend(e.items())
            print(f"  {name:24s} " + ", ".join(f"{k} {v:+.1f}" for k, v in e.items()))
    print("| fit | parameters | median | mean | largest | added effects': median, mean |")
    print("|---|---|---|---|---|---|")
    for name, kv in pooled.items():
        a = np.abs([v for _, v in kv])
        h = np.abs([v for k, v in kv if k not in BASE])
        print(f"| {name} | {a.size} | {np.median(a):.1f} % | {a.mean():.1f} % | {a.max():.1f} % | "
              f"{np.median(h):.1f}, {h.mean():.1f} % |")


if __name__ == "__main__":
    main()
