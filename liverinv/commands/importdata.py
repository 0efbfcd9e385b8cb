"""`liverinv import`: a measurement bundle from a lab's files (volumes, frame times, indenter
record, geometry)."""

from __future__ import annotations

from pathlib import Path


def register(sub):
    p = sub.add_parser("import", help="build a measurement bundle from NRRD/MetaImage/NIfTI/DICOM volumes and CSVs",
                       description=__doc__ + " Volume coordinates (mm in these formats) are taken as mesh "
                       "coordinates unless --transform is given.")
    p.add_argument("--volumes", nargs="+", required=True, type=Path, metavar="FILE",
                   help="one 3D file per frame in frame order (.nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz), "
                        "or one 4D file, or a DICOM folder (one series per frame)")
    p.add_argument("--frame-times", required=True, type=Path, metavar="CSV", help="columns frame,time_s")
    p.add_argument("--indenter", required=True, type=Path, metavar="CSV",
                   help="columns time_s,displacement_m,force_N (or displacement_mm)")
    p.add_argument("--geometry", required=True, type=Path, metavar="YAML",
                   help="tissue_height_m, tissue_radius_m, indenter_radius_m, indenter_axis_m [x, y] (mesh optional)")
    p.add_argument("--transform", type=Path, metavar="YAML",
                   help="rigid map file -> mesh coordinates: rotation (3x3), translation_m (3)")
    p.add_argument("--force-noise", type=float, default=0.0, metavar="N",
                   help="force sensor noise RMS (default 0: estimated from the record by fit)")
    p.add_argument("--displacement-noise", type=float, default=0.0, metavar="M",
                   help="displacement sensor noise RMS in m (default 0: estimated)")
    p.add_argument("--out", required=True, type=Path, help="bundle to write (.h5)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UserError
    from ..imaging.importing import import_bundle

    for name in ("force_noise", "displacement_noise"):
        v = getattr(args, name)
        if not v >= 0:
            raise UserError(f"--{name.replace('_', '-')} is {v:g}; a noise level is >= 0")
    if not args.out.parent.exists():
        raise UserError(f"{args.out.parent}: output folder does not exist")
    s = import_bundle(args.volumes, args.frame_times, args.indenter, args.geometry, args.out, args.transform,
                      args.force_noise, args.displacement_noise)
    sp = ", ".join(f"{1e3 * v:.4g}" for v in s["spacing_m"])
    print(f"wrote {args.out}: {s['frames']} volumes of {s['shape']} voxels ({sp} mm, {s['dtype']}), "
          f"{s['samples']} indenter samples (displacement in {s['unit']})")
    return 0
