"""How far the tracker's motion is from the truth on synthetic data: the tracked frame-pair
motion against the truth's motion seen through the tracker's observation operator (what
`--observation tracker` compares the model with) and against the truth's nodal motion, as
a confidence-weighted gain (regression slope of tracked on reference, 1 = no bias) and RMS
error, by region (under the punch, rim, far field) and by component. Not a workflow job: a
diagnostic of the tracking and of the observation operator.

    python benchmarks/tracker_gain.py --bundle B.h5 --flow F.nc --truth T.nc \
        --mesh ../shared/benchmark/cylinder_coarse.msh

T.nc is the truth run of the bundle (`liverinv synthesize STUDY --truth-only --truth-out T.nc`,
on the truth's own mesh); --mesh is the mesh the flow was tracked on.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

PUNCH_RADIUS_M = 6e-3


def references(bundle, flow, truth, mesh):
    """(tracked, observed truth, nodal truth, confidence): (frames, nodes, 3) arrays."""
    import xarray as xr

    from liverinv.fem.probe import Probe
    from liverinv.imaging.bundle import open_bundle
    from liverinv.imaging.observation import tracking_observation
    from liverinv.mesh import TetMesh, read_mesh

    fl = xr.load_dataset(flow, engine="h5netcdf")
    tr = xr.load_dataset(truth, engine="h5netcdf")
    truth_mesh = TetMesh(tr.X.values, tr.cells.values)
    O = tracking_observation(open_bundle(bundle), fl, read_mesh(mesh, required=()), truth_mesh)
    t = np.concatenate([fl.time_start.values[:1], fl.time_end.values])
    U = tr.u.interp(time=t).values
    observed = O(U[1:] - U[:-1])
    Un = Probe(tr.X.values, tr.cells.values, fl.X.values)(U)
    return fl.u_of.values, observed, Un[1:] - Un[:-1], fl.c_of.values, fl.X.values


def gain_table(u, ref, c, X):
    """Rows (region, component, gain, rms_m): the confidence-weighted slope of u on ref."""
    r = np.hypot(X[:, 0], X[:, 1])
    a = PUNCH_RADIUS_M
    regions = {"all": np.ones_like(r, bool), "under the punch": r < a, "rim (a-2a)": (r >= a) & (r < 2 * a),
               "far field": r >= 2 * a}
    rows = []
    for name, m in regions.items():
        for k, comp in enumerate(("x", "y", "z", "all")):
            sl = slice(None) if comp == "all" else slice(k, k + 1)
            w = c[:, m][..., sl]
            uu, rr = u[:, m][..., sl], ref[:, m][..., sl]
            rows.append((name, comp, float((w * uu * rr).sum() / (w * rr * rr).sum()),
                         float(np.sqrt((w * (uu - rr) ** 2).sum() / w.sum()))))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--flow", type=Path, required=True)
    ap.add_argument("--truth", type=Path, required=True, help="the bundle's truth run")
    ap.add_argument("--mesh", type=Path, required=True, help="the mesh the flow was tracked on")
    args = ap.parse_args(argv)
    u, observed, nodal, c, X = references(args.bundle, args.flow, args.truth, args.mesh)
    print("| region | component | gain vs observed truth | RMS error (um) | gain vs nodal truth | RMS error (um) |")
    print("|---|---|---|---|---|---|")
    for (reg, comp, g_o, e_o), (_, _, g_n, e_n) in zip(gain_table(u, observed, c, X), gain_table(u, nodal, c, X)):
        print(f"| {reg} | {comp} | {g_o:.3f} | {1e6 * e_o:.1f} | {g_n:.3f} | {1e6 * e_n:.1f} |")


if __name__ == "__main__":
    main()
