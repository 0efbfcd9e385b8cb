"""`liverinv track`: nodal Lucas-Kanade motion of a measurement bundle at mesh nodes."""

from __future__ import annotations

import sys

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers):
    p = subparsers.add_parser(
        "track", help="track the bundle's volume sequence at the nodes of a mesh",
        description="Frame-to-frame nodal motion (u_of) and confidence (c_of) by the modified "
                    "Lucas-Kanade of the paper's Appendix; writes a flow Dataset (netCDF).")
    p.add_argument("bundle", type=Path, help="measurement bundle (.h5)")
    p.add_argument("--mesh", type=Path, required=True, help="tracking mesh (gmsh tet10)")
    p.add_argument("--out", type=Path, required=True, help="flow file to write (.nc)")
    p.add_argument("--iterations", type=int, default=8,
                   help="warp-and-re-solve iterations of the Appendix's per-node translation (8; "
                        "fewer leave a lag behind changes of speed)")
    p.add_argument("--interpolated-iterations", type=int, default=0,
                   help="then iterations with the interpolated motion as the model (0; 1 "
                        "halves the error on noise-free warped data, hurts with noise)")
    p.add_argument("--window", choices=["subtet", "element"], default="subtet",
                   help="node neighbourhood weights: sub-tet hats (default) or, for corner "
                        "nodes, the linear shape function of every element around it")
    p.add_argument("--tol-vox", type=float, default=1e-5,
                   help="stop refining when the largest correction is below this (voxels)")
    p.add_argument("--stride", type=int, nargs=3, default=(2, 2, 1), metavar=("L", "E", "A"),
                   help="use every n-th voxel along lateral, elevational, axial (2 2 1)")
    p.add_argument("--confidence", choices=["sum", "mean"], default="sum",
                   help="Eq. A.4 sum (paper) or weighted mean of |gradient|")
    p.add_argument("--frames", type=int, default=None, help="track only the first N volumes")
    p.add_argument("--picture", type=Path, default=None,
                   help="also draw a slice with the mesh and the tracked motion (PNG)")
    p.add_argument("--picture-frame", type=int, default=None,
                   help="frame pair to draw (default: the one with the largest motion)")
    p.set_defaults(func=run)


def read_tracking_mesh(path: Path):
    """(points, cells) of a tet10 mesh; UserError naming the file if unusable."""
    from ..cli import UserError
    try:
        from ..mesh import MeshError, read_mesh
    except ImportError:  # forward engine not present: plain meshio
        from ..imaging.weights import mesh_arrays
        if not path.is_file():
            raise UserError(f"{path}: mesh file not found") from None
        try:
            return mesh_arrays(str(path))
        except Exception as e:
            raise UserError(f"{path}: cannot read tetra10 cells ({e})") from None
    try:
        m = read_mesh(path, required=())
    except MeshError as e:
        raise UserError(str(e)) from None
    return m.points, m.cells


def run(args) -> int:
    from ..cli import UserError
    from ..fileio import check_writable, file_sha256, provenance, write_netcdf
    from ..imaging.bundle import open_bundle
    from ..imaging.flow import track_bundle
    from ..imaging.tracking import TrackOptions

    for out in (args.out, args.picture):  # before tracking: a folder we cannot write fails now
        if out is not None:
            check_writable(out)
    points, cells = read_tracking_mesh(args.mesh)
    if args.iterations < 1 or min(args.stride) < 1 or args.interpolated_iterations < 0:
        raise UserError("--iterations and --stride must be >= 1, --interpolated-iterations >= 0")
    opts = TrackOptions(max_iterations=args.iterations, tol_vox=args.tol_vox,
                        confidence=args.confidence,
                        interpolated_iterations=args.interpolated_iterations)
    with open_bundle(args.bundle) as b:
        if b.n_frames < 2:
            raise UserError(f"{args.bundle}: /volumes/data holds {b.n_frames} volume; tracking needs 2")
        from ..imaging.placement import check_placement
        rep = check_placement(b, points)
        if rep.problems:
            raise UserError(rep.problems[0] + " (liverinv check draws the placement)")
        for w in rep.warnings:
            print(f"warning: {w}", file=sys.stderr)
        from tqdm import tqdm
        with tqdm(desc="track", unit="pair", disable=None) as bar:
            def progress(k, n):
                bar.total = n
                bar.update(1)
            ds = track_bundle(b, points, cells, opts, stride=tuple(args.stride), frames=args.frames,
                              window=args.window, progress=progress)
        ds.attrs.update(provenance(bundle=str(args.bundle), bundle_sha256=file_sha256(args.bundle),
                                   mesh=str(args.mesh), mesh_sha256=file_sha256(args.mesh)))
        write_netcdf(ds, args.out)
        if args.picture is not None:
            from ..imaging.plotting import flow_picture
            flow_picture(b, ds, cells, args.picture, pair=args.picture_frame)
    print(f"wrote {args.out}: {ds.sizes['frame']} frame pairs, {ds.sizes['node']} nodes, "
          f"{ds.attrs['tracking_seconds']:.1f} s wall tracking "
          f"(+{ds.attrs['weights_seconds']:.1f} s weights; {ds.attrs['cpu_seconds']:.1f} s CPU in all)")
    return 0
