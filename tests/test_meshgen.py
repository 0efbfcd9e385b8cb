"""Tests of the gmsh indentation mesh generator (coarse sizes, a few seconds in all)."""

import numpy as np
import pytest

meshio = pytest.importorskip("meshio")
pytest.importorskip("gmsh")

from liverinv.meshgen import (  # noqa: E402
    PRESETS,
    generate_indentation_mesh,
    main,
    summarize_mesh,
    tet10_volumes,
)

R, H, A = 0.05, 0.0303, 0.006
SIZES = {"h_far": 0.02, "h_rim": 0.004}


@pytest.fixture(scope="module")
def mesh_path(tmp_path_factory):
    return generate_indentation_mesh(tmp_path_factory.mktemp("mesh") / "cyl.msh",
                                     R=R, H=H, a=A, **SIZES)


@pytest.fixture(scope="module")
def summary(mesh_path):
    return summarize_mesh(mesh_path)


def test_only_tetra10_volume_cells_and_named_groups(mesh_path):
    m = meshio.read(mesh_path)
    assert {c.type for c in m.cells} == {"tetra10", "triangle6"}
    assert set(m.field_data) == {"tissue", "bottom", "side", "top_free", "footprint"}
    assert m.field_data["tissue"][1] == 3
    assert all(m.field_data[n][1] == 2 for n in ("bottom", "side", "top_free", "footprint"))
    assert set(m.cell_sets_dict["tissue"]) == {"tetra10"}
    for name in ("bottom", "side", "top_free", "footprint"):
        assert len(m.cell_sets_dict[name]["triangle6"]) > 0, name
    # every node belongs to a tetrahedron (no orphan geometry nodes)
    assert np.unique(m.get_cells_type("tetra10")).size == len(m.points)


def test_volume_is_the_cylinder(mesh_path, summary):
    exact = np.pi * R**2 * H
    assert abs(summary["volume"] - exact) / exact < 1e-4  # measured ~3e-5
    # straight-sided (corner-node) tets miss the curved side by more than 1e-3: the
    # tolerance above needs the mid-side nodes to sit on the circle
    m = meshio.read(mesh_path)
    c, p = m.get_cells_type("tetra10"), m.points
    v_lin = np.einsum("ij,ij->i", np.cross(p[c[:, 1]] - p[c[:, 0]], p[c[:, 2]] - p[c[:, 0]]),
                      p[c[:, 3]] - p[c[:, 0]]) / 6
    assert (v_lin > 0).all()
    assert abs(v_lin.sum() - exact) / exact > 1e-3
    assert (tet10_volumes(p, c) > 0).all()


def test_footprint_is_the_punch_disk(mesh_path, summary):
    p = meshio.read(mesh_path).points
    nodes = summary["nodes_footprint"]
    r = np.hypot(p[nodes, 0], p[nodes, 1])
    assert (r <= A + 1e-9).all()
    assert np.allclose(p[nodes, 2], H, rtol=0, atol=1e-12)
    assert np.sum(np.isclose(r, A, rtol=0, atol=1e-9)) >= 8  # the rim is a mesh edge
    assert abs(summary["area_footprint"] - np.pi * A**2) / (np.pi * A**2) < 1e-3
    # the annulus around it starts at the same rim
    free = summary["nodes_top_free"]
    r_free = np.hypot(p[free, 0], p[free, 1])
    assert r_free.min() == pytest.approx(A, abs=1e-9)
    assert np.allclose(p[free, 2], H, rtol=0, atol=1e-12)
    assert summary["area_top_free"] == pytest.approx(np.pi * (R**2 - A**2), rel=1e-3)


def test_bottom_and_side(mesh_path, summary):
    p = meshio.read(mesh_path).points
    assert np.allclose(p[summary["nodes_bottom"], 2], 0.0, atol=1e-12)
    r = np.hypot(*p[summary["nodes_side"], :2].T)
    assert np.allclose(r, R, rtol=1e-9)
    assert summary["area_bottom"] == pytest.approx(np.pi * R**2, rel=1e-3)
    assert summary["area_side"] == pytest.approx(2 * np.pi * R * H, rel=1e-3)


def test_refining_the_rim_adds_nodes(tmp_path, summary):
    finer = generate_indentation_mesh(tmp_path / "finer.msh", R=R, H=H, a=A,
                                      h_far=SIZES["h_far"], h_rim=SIZES["h_rim"] / 2)
    s = summarize_mesh(finer)
    assert s["n_nodes"] > summary["n_nodes"]
    assert s["n_footprint"] > summary["n_footprint"]


def test_footprint_size_option(tmp_path, summary):
    path = generate_indentation_mesh(tmp_path / "fp.msh", R=R, H=H, a=A, h_footprint=0.0015,
                                     **SIZES)
    assert summarize_mesh(path)["n_footprint"] > summary["n_footprint"]


def test_first_order_mesh(tmp_path):
    path = generate_indentation_mesh(tmp_path / "lin.msh", order=1, **SIZES)
    m = meshio.read(path)
    assert {c.type for c in m.cells} == {"tetra", "triangle"}


@pytest.mark.parametrize("kwargs, name", [
    ({"a": 0.05}, "a"),
    ({"R": -1.0}, "R"),
    ({"H": 0.0}, "H"),
    ({"h_far": 0.0}, "h_far"),
    ({"h_rim": -0.001}, "h_rim"),
    ({"h_rim": 0.05, "h_far": 0.02}, "h_rim"),
    ({"h_footprint": 0.0}, "h_footprint"),
    ({"order": 3}, "order"),
])
def test_bad_arguments_raise(tmp_path, kwargs, name):
    out = tmp_path / "bad.msh"
    with pytest.raises(ValueError, match=rf"^{name} "):
        generate_indentation_mesh(out, **{**SIZES, **kwargs})
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no temp file left behind


def test_cli_writes_mesh(tmp_path, capsys):
    out = tmp_path / "cli.msh"
    assert main([str(out), "--h-far", "0.02", "--h-rim", "0.004"]) == 0
    assert out.exists() and "tetra10" in capsys.readouterr().out
    assert out.read_text().startswith("$MeshFormat\n4.1 0 8")
    assert [p.name for p in tmp_path.iterdir()] == ["cli.msh"]


def test_refined_model_mesh_is_the_tracking_cylinder_with_the_medium_preset(tmp_path):
    """discover's final model mesh: read back from a generated cylinder (R 40 mm, H 25 mm,
    a 5 mm), the same cylinder and footprint with the medium preset's sizes scaled by a / 6 mm;
    refused, with the reason, for a mesh as fine and for one that is not such a cylinder."""
    from dataclasses import replace

    from liverinv.mesh import read_mesh
    from liverinv.meshgen import cylinder_of, refined_model_mesh
    tracking = read_mesh(generate_indentation_mesh(tmp_path / "t.msh", R=0.04, H=0.025, a=0.005,
                                                   **PRESETS["tiny"]))
    dims, _ = cylinder_of(tracking)
    assert dims == pytest.approx((0.04, 0.025, 0.005), rel=1e-9)
    path, note = refined_model_mesh(tracking, tmp_path / "m.msh")
    s = summarize_mesh(path)
    assert s["volume"] == pytest.approx(np.pi * 0.04 ** 2 * 0.025, rel=2e-3)
    assert s["area_footprint"] == pytest.approx(np.pi * 0.005 ** 2, rel=2e-3)
    assert s["n_tetra10"] > 3 * tracking.n_elements and "medium preset" in note
    # the same sizes the second time: the same mesh (gmsh meshes a 1e-17 change of a size anew)
    again, _ = refined_model_mesh(tracking, tmp_path / "m2.msh")
    assert (tmp_path / "m.msh").read_bytes() == again.read_bytes()
    fine = read_mesh(path)
    assert refined_model_mesh(fine, tmp_path / "m3.msh")[0] is None and not (tmp_path / "m3.msh").exists()
    squashed = replace(tracking, points=tracking.points * [1.0, 0.7, 1.0])
    none, why = refined_model_mesh(squashed, tmp_path / "m4.msh")
    assert none is None and "not a cylinder" in why
