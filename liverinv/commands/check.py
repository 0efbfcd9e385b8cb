"""`liverinv check`: can this mesh be tracked in this bundle? Nodes in view, texture, motion
scale, and a picture of the mesh over the first volume with the punch drawn."""

from __future__ import annotations

import sys
from pathlib import Path


def register(sub):
    p = sub.add_parser("check", help="check a bundle and a tracking mesh before tracking", description=__doc__)
    p.add_argument("bundle", type=Path, help="measurement bundle (.h5)")
    p.add_argument("--mesh", type=Path, required=True, help="tracking mesh (gmsh tet10, m)")
    p.add_argument("--picture", type=Path, default=None, help="PNG of the mesh over orthogonal slices")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UserError
    from ..imaging.bundle import open_bundle
    from ..imaging.placement import check_placement, placement_picture
    from .track import read_tracking_mesh

    points, _ = read_tracking_mesh(args.mesh)
    with open_bundle(args.bundle) as b:
        rep = check_placement(b, points)
        if args.picture is not None:
            placement_picture(b, points, args.picture)
    for line in rep.lines():
        print(line)
    for w in rep.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if rep.problems:
        raise UserError(rep.problems[0])
    print(f"{args.bundle} can be tracked on {args.mesh}" + (f"; picture {args.picture}" if args.picture else ""))
    return 0
