"""Time the tracker's response (`imaging.response.tracker_response`) to one motion: the bundle's
first volume warped (or its scatterers moved) by the flow's own accumulated motion, tracked
again on the tracking mesh. Prints the wall time and, with --save, writes the response so that
two versions of the code can be compared array for array.

    python benchmarks/response_time.py --bundle B.h5 --flow F.nc --mesh cylinder_coarse.msh [--save R.npy]
"""

import argparse
import time

import numpy as np
import xarray as xr

from liverinv.imaging.bundle import open_bundle
from liverinv.imaging.response import tracker_response
from liverinv.mesh import read_mesh


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--flow", required=True)
    ap.add_argument("--mesh", required=True, help="the tracking mesh (the flow's)")
    ap.add_argument("--save", help="write the response (K, N, 3) m here (.npy)")
    args = ap.parse_args(argv)
    flow = xr.load_dataset(args.flow, engine="h5netcdf")
    mesh = read_mesh(args.mesh, required=())
    u = np.concatenate([np.zeros((1,) + flow.u_of.shape[1:]), np.cumsum(flow.u_of.values, axis=0)])
    with open_bundle(args.bundle) as b:
        t0 = time.perf_counter()
        r = tracker_response(b, flow, mesh, mesh, u)
        wall = time.perf_counter() - t0
    print(f"tracker response: {flow.sizes['frame']} frame pairs, {mesh.n_nodes} nodes, {wall:.1f} s")
    if args.save:
        np.save(args.save, r)


if __name__ == "__main__":
    main()
