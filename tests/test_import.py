"""`liverinv import`: volumes written with SimpleITK in each supported format (NRRD, MetaImage,
NIfTI, a DICOM series per frame, one 4D NRRD) and CSVs, imported back into a bundle that must
match the original voxel for voxel, with its spacing, orientation and times."""

import numpy as np
import pytest

sitk = pytest.importorskip("SimpleITK")

from liverinv.cli import main  # noqa: E402
from liverinv.imaging.bundle import open_bundle  # noqa: E402

SHAPE = (12, 9, 16)                       # lateral, elevational, axial
SPACING_MM = (0.5, 0.6, 0.3)
ORIGIN_MM = (-3.0, 2.0, 10.0)
ROT_Z90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # columns: image axes
TIMES = np.array([0.0, 0.04, 0.08, 0.125])


def frames(rng):
    return [rng.integers(0, 65535, SHAPE, dtype=np.uint16) for _ in TIMES]


def image(vol, direction=ROT_Z90):
    img = sitk.GetImageFromArray(vol.transpose(2, 1, 0))   # ITK index (x, y, z) = (lat, elev, axial)
    img.SetSpacing(SPACING_MM)
    img.SetOrigin(ORIGIN_MM)
    img.SetDirection(tuple(np.asarray(direction).ravel()))
    return img


def write_dicom_series(folder, vol, number):
    """One frame as a DICOM series of axial slices (tags as a scanner writes them)."""
    img = image(vol)
    w = sitk.ImageFileWriter()
    w.KeepOriginalImageUIDOn()
    uid = f"1.2.826.0.1.3680043.2.1125.{number + 1}.{np.random.default_rng(number).integers(1e9)}"
    D = np.asarray(img.GetDirection()).reshape(3, 3)
    for z in range(img.GetDepth()):
        s = img[:, :, z]
        pos = img.TransformIndexToPhysicalPoint((0, 0, z))
        for tag, value in {"0008|0060": "US", "0020|000e": uid, "0020|0011": str(number + 1),
                           "0020|0013": str(z + 1), "0020|0032": "\\".join(f"{p:.6f}" for p in pos),
                           "0020|0037": "\\".join(f"{v:.6f}" for v in (*D[:, 0], *D[:, 1])),
                           "0018|0050": f"{SPACING_MM[2]:.6f}", "0028|0030": f"{SPACING_MM[1]:.6f}\\{SPACING_MM[0]:.6f}",
                           "0008|0018": f"{uid}.{z + 1}"}.items():
            s.SetMetaData(tag, value)
        w.SetFileName(str(folder / f"f{number:02d}_{z:03d}.dcm"))
        w.Execute(s)


@pytest.fixture
def lab_files(tmp_path):
    t = np.arange(0, 0.2, 0.01)
    (tmp_path / "indenter.csv").write_text("time_s,displacement_mm,force_N\n" + "\n".join(
        f"{a:.4f},{2.0 * a:.6f},{0.5 * a:.6f}" for a in t))
    (tmp_path / "frames.csv").write_text("frame,time_s\n" + "\n".join(f"{k},{v}" for k, v in enumerate(TIMES)))
    (tmp_path / "geometry.yaml").write_text("tissue_height_m: 0.0303\ntissue_radius_m: 0.05\n"
                                            "indenter_radius_m: 0.006\nindenter_axis_m: [0.0, 0.0]\n")
    return tmp_path


def run_import(files, volumes, out, *extra):
    return main(["import", "--volumes", *map(str, volumes), "--frame-times", str(files / "frames.csv"),
                 "--indenter", str(files / "indenter.csv"), "--geometry", str(files / "geometry.yaml"),
                 "--out", str(out), *extra])


def check_bundle(out, vols):
    with open_bundle(out, check_all_frames=True) as b:
        assert b.grid.shape == SHAPE
        np.testing.assert_allclose(b.grid.spacing_m, np.array(SPACING_MM) * 1e-3, rtol=1e-6)
        np.testing.assert_allclose(b.grid.origin_m, np.array(ORIGIN_MM) * 1e-3, atol=1e-9)
        np.testing.assert_allclose(b.grid.R, ROT_Z90, atol=1e-6)
        np.testing.assert_allclose(b.time_s, TIMES)
        stored = b._file["volumes/data"][...]
        for k, v in enumerate(vols):
            np.testing.assert_array_equal(stored[k], v)          # voxel for voxel
        np.testing.assert_allclose(b.indenter.displacement_m[-1], 2.0 * 0.19 * 1e-3)
        assert b.geometry["indenter_radius_m"] == 0.006


@pytest.mark.parametrize("suffix", [".nrrd", ".mha", ".nii.gz"])
def test_import_of_one_3d_file_per_frame_matches_voxel_for_voxel(lab_files, rng, suffix):
    vols = frames(rng)
    paths = []
    for k, v in enumerate(vols):
        paths.append(lab_files / f"frame{k}{suffix}")
        sitk.WriteImage(image(v), str(paths[-1]))
    assert run_import(lab_files, paths, lab_files / "b.h5") == 0
    check_bundle(lab_files / "b.h5", vols)


def test_import_of_one_4d_file(lab_files, rng):
    vols = frames(rng)
    img4 = sitk.JoinSeries([image(v) for v in vols])
    img4.SetDirection(tuple(np.block([[ROT_Z90, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]).ravel()))
    img4.SetOrigin((*ORIGIN_MM, 0.0))
    sitk.WriteImage(img4, str(lab_files / "seq.nrrd"))
    assert run_import(lab_files, [lab_files / "seq.nrrd"], lab_files / "b.h5") == 0
    check_bundle(lab_files / "b.h5", vols)


def test_import_of_a_dicom_folder_one_series_per_frame(lab_files, rng):
    vols = frames(rng)
    folder = lab_files / "dicom"
    folder.mkdir()
    for k in (2, 0, 3, 1):                              # written out of order on purpose
        write_dicom_series(folder, vols[k], k)
    assert run_import(lab_files, [folder], lab_files / "b.h5") == 0
    check_bundle(lab_files / "b.h5", vols)


def test_a_rigid_transform_moves_the_grid(lab_files, rng):
    vols = frames(rng)
    paths = [lab_files / f"f{k}.mha" for k in range(len(vols))]
    for p, v in zip(paths, vols):
        sitk.WriteImage(image(v, np.eye(3)), str(p))
    (lab_files / "T.yaml").write_text("rotation: [[0, -1, 0], [1, 0, 0], [0, 0, 1]]\ntranslation_m: [0.001, 0, -0.01]\n")
    assert run_import(lab_files, paths, lab_files / "b.h5", "--transform", str(lab_files / "T.yaml")) == 0
    with open_bundle(lab_files / "b.h5") as b:
        np.testing.assert_allclose(b.grid.R, ROT_Z90, atol=1e-12)
        np.testing.assert_allclose(b.grid.origin_m, ROT_Z90 @ (np.array(ORIGIN_MM) * 1e-3) + [0.001, 0, -0.01])


@pytest.mark.parametrize("change, words", [
    (lambda d: (d / "frames.csv").write_text("frame,time_s\n0,0\n1,0.04\n2,0.04\n3,0.1\n"), "not strictly increasing"),
    (lambda d: (d / "frames.csv").write_text("frame,time_s\n0,0\n1,0.04\n"), "expected one row for each of the 4 volumes"),
    (lambda d: (d / "frames.csv").write_text("frame,t\n0,0\n1,0.04\n2,0.08\n3,0.1\n"), "missing column(s) ['time_s']"),
    (lambda d: (d / "indenter.csv").write_text("time_s,displacement_m,force_N\n0,1,0\n0.1,2,0\n0.2,3,0\n0.3,4,0\n"),
     "name it displacement_mm"),
    (lambda d: (d / "indenter.csv").write_text("time_s,depth,force_N\n0,1,0\n"), "missing column(s)"),
    (lambda d: (d / "indenter.csv").write_text("time_s,displacement_mm,force_N\n0,0,0\n0.1,x,0\n0.2,1,0\n0.3,1,0\n"),
     "not numbers"),
    (lambda d: (d / "geometry.yaml").write_text("tissue_height_m: 30.3\ntissue_radius_m: 0.05\nindenter_radius_m: 0.006\n"
                                                "indenter_axis_m: [0, 0]\n"), "is it in mm"),
    (lambda d: (d / "geometry.yaml").write_text("tissue_height: 0.03\n"), "unknown key(s) ['tissue_height']"),
    (lambda d: (d / "frames.csv").write_text("frame,time_s\n0,0\n1,0.1\n2,0.2\n3,0.5\n"), "outside the indenter record"),
])
def test_bad_lab_files_are_one_line_and_leave_nothing(lab_files, rng, capsys, change, words):
    vols = frames(rng)
    paths = [lab_files / f"f{k}.nrrd" for k in range(len(vols))]
    for p, v in zip(paths, vols):
        sitk.WriteImage(image(v), str(p))
    change(lab_files)
    assert run_import(lab_files, paths, lab_files / "b.h5") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err
    assert not list(lab_files.glob("*.h5")) and not list(lab_files.glob(".*part"))


def test_volumes_that_do_not_share_a_grid_are_refused(lab_files, rng, capsys):
    vols = frames(rng)
    paths = [lab_files / f"f{k}.nrrd" for k in range(len(vols))]
    for p, v in zip(paths, vols):
        sitk.WriteImage(image(v), str(p))
    odd = image(vols[2])
    odd.SetSpacing((0.5, 0.5, 0.3))
    sitk.WriteImage(odd, str(paths[2]))
    assert run_import(lab_files, paths, lab_files / "b.h5") == 2
    assert "every frame must share one grid" in capsys.readouterr().err
    (lab_files / "junk.nrrd").write_text("not an image")
    assert run_import(lab_files, [lab_files / "junk.nrrd"], lab_files / "b.h5") == 2
    assert "not a readable volume" in capsys.readouterr().err
