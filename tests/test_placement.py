"""`liverinv check`: the placement check refuses data that cannot be tracked, with one line."""

import meshio
import numpy as np
import pytest

from conftest import COARSE
from liverinv.cli import main
from liverinv.imaging.bundle import Indenter, write_bundle
from liverinv.imaging.grid import ImageGrid


def bundle(path, rng, constant=False, shift=(0.0, 0.0, 0.0)):
    grid = ImageGrid((40, 24, 60), (0.5e-3, 0.5e-3, 0.3e-3), np.array([-10e-3, -6e-3, 12e-3]) + shift)
    base = rng.random(grid.shape)
    vols = [np.full(grid.shape, 0.5) if constant else np.roll(base, k, axis=2) * 0.9 for k in range(3)]
    t = np.linspace(0, 1, 20)
    write_bundle(path, vols, grid, [0.0, 0.1, 0.2], Indenter(t, 1e-3 * t, 0.1 * t),
                 {"tissue_height_m": 0.0303, "tissue_radius_m": 0.05, "indenter_radius_m": 0.006,
                  "indenter_axis_m": [0.0, 0.0]})
    return path


def test_a_placed_mesh_passes_and_draws_its_picture(tmp_path, rng, capsys):
    b = bundle(tmp_path / "b.h5", rng)
    assert main(["check", str(b), "--mesh", str(COARSE), "--picture", str(tmp_path / "p.png")]) == 0
    out = capsys.readouterr()
    assert "can be tracked" in out.out and (tmp_path / "p.png").stat().st_size > 20_000
    # rolled by one voxel per frame along the axial axis: the motion estimate says about 1
    assert "warning: the frames move by about" in out.err or "frame-to-frame motion: about" in out.out


@pytest.mark.parametrize("case, words", [
    ("shifted", "no mesh node lies inside the field of view"),
    ("mm", "a unit mismatch?"),
    ("constant", "no texture"),
])
def test_data_that_cannot_be_tracked_is_refused_with_one_line(tmp_path, rng, capsys, case, words):
    mesh = COARSE
    if case == "mm":
        m = meshio.read(COARSE)
        m.points = m.points * 1e3
        mesh = tmp_path / "mm.msh"
        meshio.write(mesh, m, file_format="gmsh22")
    b = bundle(tmp_path / "b.h5", rng, constant=case == "constant", shift=(1.0, 0, 0) if case == "shifted" else (0, 0, 0))
    assert main(["check", str(b), "--mesh", str(mesh)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len([e for e in err if "error" in e]) == 1 and words in err[-1], err
    # track refuses it too, before any tracking, and writes nothing
    assert main(["track", str(b), "--mesh", str(mesh), "--out", str(tmp_path / "f.nc")]) == 2
    assert words in capsys.readouterr().err and not (tmp_path / "f.nc").exists()
