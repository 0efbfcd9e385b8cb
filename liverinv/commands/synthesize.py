"""`liverinv synthesize`: truth simulation + synthetic 3D ultrasound -> measurement bundle."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers):
    p = subparsers.add_parser(
        "synthesize", help="simulate a study and render its 3D ultrasound measurement bundle",
        description="Run the study's truth simulation, render the ultrasound volume sequence "
                    "(imaging: section of the study) and write the measurement bundle (HDF5).")
    p.add_argument("study", type=Path, help="study config (YAML)")
    p.add_argument("--out", type=Path, required=True, help="bundle to write (.h5)")
    p.add_argument("--truth-out", type=Path, default=None,
                   help="also keep the truth simulation (forward-run Dataset, netCDF)")
    p.set_defaults(func=run)


def load_study(path: Path) -> dict:
    import yaml
    from ..cli import UserError
    if not path.is_file():
        raise UserError(f"{path}: study file not found")
    try:
        study = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise UserError(f"{path}: not valid YAML ({e})".replace("\n", " ")) from None
    if not isinstance(study, dict):
        raise UserError(f"{path}: a study is a mapping of keys (mesh, law, params, loading, imaging)")
    return study


def repo_base(path: Path) -> Path:
    """Relative paths in a study are relative to the repository root (the parent of
    config/), or to the study's directory when it is not inside config/studies."""
    path = path.resolve()
    if path.parent.name == "studies" and path.parent.parent.name == "config":
        return path.parent.parent.parent
    return path.parent


def run(args) -> int:
    from ..imaging.synth import synthesize
    study = load_study(args.study)
    synthesize(study, repo_base(args.study), args.out, args.truth_out, source=str(args.study))
    print(f"wrote {args.out}" + (f" and {args.truth_out}" if args.truth_out else ""))
    return 0
