"""Small-strain punch stiffness F/d of indentation meshes (elastic benchmark law, one 1 µm
displacement step): how stiff each mesh's punch rim makes it, against the converged
axisymmetric reference 18.32 N/m (../shared/benchmark/README.md).

    python benchmarks/punch_stiffness.py [--meshes coarse fine medium PATH ...]

Measured: coarse 19.937, medium 19.209, fine 19.070 N/m.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1].parent / "shared" / "benchmark"
REFERENCE = 18.32  # N/m


def stiffness(mesh, depth=1e-6):
    from liverinv.fem.solver import solve_history
    from liverinv.forward import ForwardModel
    fm = ForwardModel(mesh)
    h = solve_history(fm.model("elastic", dict(C1=200.0, C2=5000.0, D1=1.5e-3)),
                      np.array([0.0, 1.0]), np.array([0.0, depth]), "displacement")
    return fm.mesh.n_nodes, float(h.force[-1] / depth)


def main(argv=None):
    from liverinv.meshgen import PRESETS, generate_indentation_mesh
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="+", default=["coarse", "medium", "fine"],
                    help="benchmark mesh (coarse, fine), meshgen preset (medium) or path")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp())
    for name in args.meshes:
        path = BENCH / f"cylinder_{name}.msh"
        if not path.exists():
            path = Path(name)
        if not path.exists():
            if name not in PRESETS:
                ap.error(f"{name}: neither a benchmark mesh, a preset nor a file")
            path = generate_indentation_mesh(tmp / f"{name}.msh", **PRESETS[name])
        n, k = stiffness(path)
        print(f"{name:8s} {n:6d} nodes  F/d = {k:.3f} N/m  ({100 * (k / REFERENCE - 1):+.1f} % vs converged {REFERENCE})")


if __name__ == "__main__":
    main()
