"""Exports read back by their own readers (OpenCV) or parsed and checked number for number.

Beyond equal numbers, each format is checked for meaning: a board corner projected with the
exported parameters by the format's own conventions lands where dualcal projects it.
"""

from __future__ import annotations

import ast
import json
import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from dualcal.files import io
from dualcal.synthetic import synth
from dualcal.geometry.camera import project_points
from dualcal.errors import InputError
from dualcal.files.export import (FORMATS, _yaml_float, colmap_cameras_txt, export_files, kalibr_yaml,
                                  mrcal_cameramodel, mrcal_paths, write_export)
from dualcal.geometry.rotation import rotation_from_rotvec

yaml = pytest.importorskip("yaml", reason="pyyaml (test extra) parses the Kalibr export")


@pytest.fixture(scope="module")
def rig():
    """A three-camera rig (wide reference, tele, ultra) with exact synthetic truth."""
    truth = synth.make_truth("triple", views=4, seed=3, scale=0.25)
    return synth.truth_rig_model(truth)


@pytest.fixture
def calib_json(rig, tmp_path):
    path = tmp_path / "calib.json"
    io.save_rig(path, rig)
    return path


def _board_in(rig, name, view="IMG_01"):
    """(N, 3) board corners in camera ``name``'s frame and in the reference frame, and dualcal's pixels."""
    X = rig.board.object_points_mm()
    X_ref = rig.camera_poses[rig.reference][view].apply(X)
    uv = project_points(rig.cameras[name], rig.camera_poses[name][view].apply(X))
    return X_ref, uv


def test_camera_order_puts_the_reference_first(rig):
    assert rig.camera_order() == ["wide", "tele", "ultra"]


# ---------------------------------------------------------------------------- OpenCV


def test_opencv_export_reads_back_in_opencv(rig, tmp_path):
    path = tmp_path / "rig.yml"
    assert write_export(rig, "opencv", path) == [path]
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("reference").string() == "wide"
    seq = fs.getNode("cameras")
    assert [seq.at(i).string() for i in range(seq.size())] == ["wide", "tele", "ultra"]
    for name, cam in rig.cameras.items():
        node = fs.getNode(name)
        size = (int(node.getNode("image_width").real()), int(node.getNode("image_height").real()))
        assert size == cam.image_size
        np.testing.assert_array_equal(node.getNode("K").mat(),
                                      [[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
        np.testing.assert_array_equal(node.getNode("D").mat(), [[cam.k1, cam.k2, 0, 0, 0]])
        R, T = node.getNode("R").mat(), node.getNode("T").mat()
        if name == rig.reference:
            np.testing.assert_array_equal(R, np.eye(3))
            np.testing.assert_array_equal(T, np.zeros((3, 1)))
        else:
            np.testing.assert_array_equal(R, rig.rig[name].pose.R)
            np.testing.assert_array_equal(T.ravel(), rig.rig[name].pose.t_mm)


def test_opencv_export_projects_like_dualcal(rig, tmp_path):
    """cv2.projectPoints with the exported K, D, R, T (X_cam = R X_ref + T) reproduces dualcal."""
    path = tmp_path / "rig.yml"
    write_export(rig, "opencv", path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    for name in ("tele", "ultra"):
        node = fs.getNode(name)
        X_ref, uv = _board_in(rig, name)
        rvec, _ = cv2.Rodrigues(node.getNode("R").mat())
        uv_cv, _ = cv2.projectPoints(X_ref, rvec, node.getNode("T").mat(), node.getNode("K").mat(),
                                     node.getNode("D").mat())
        np.testing.assert_allclose(uv_cv.reshape(-1, 2), uv, atol=1e-6)


def test_opencv_keys_for_awkward_camera_names(rig, tmp_path):
    """Camera names are kept in ``cameras``; map keys are valid FileStorage keys."""
    renamed = replace(rig, cameras={"2x tele": rig.cameras["tele"], "wide": rig.cameras["wide"]},
                      rig={"2x tele": rig.rig["tele"]})
    path = tmp_path / "rig.yml"
    write_export(renamed, "opencv", path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("cameras").at(1).string() == "2x tele"
    np.testing.assert_array_equal(fs.getNode("_2x_tele").getNode("T").mat().ravel(), rig.rig["tele"].pose.t_mm)


def test_opencv_export_without_rig_relation_has_no_pose(rig, tmp_path):
    alone = replace(rig, rig={}, rig_mode="none")
    path = tmp_path / "alone.yml"
    write_export(alone, "opencv", path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("tele").getNode("R").empty()
    assert not fs.getNode("wide").getNode("R").empty()


# ---------------------------------------------------------------------------- Kalibr


def test_kalibr_export_parses_number_for_number(rig):
    doc = yaml.safe_load(kalibr_yaml(rig))
    assert list(doc) == ["cam0", "cam1", "cam2"]
    for i, name in enumerate(rig.camera_order()):
        cam, entry = rig.cameras[name], doc[f"cam{i}"]
        assert entry["camera_model"] == "pinhole"
        assert entry["distortion_model"] == "radtan"
        assert entry["intrinsics"] == [cam.fx, cam.fy, cam.cx, cam.cy]
        assert entry["distortion_coeffs"] == [cam.k1, cam.k2, 0.0, 0.0]
        assert entry["resolution"] == list(cam.image_size)
        assert entry["rostopic"] == f"/{name}/image_raw"
        assert entry["cam_overlaps"] == [j for j in range(3) if j != i]
        assert ("T_cn_cnm1" in entry) == (i > 0)


def test_kalibr_chain_composes_to_the_rig_in_metres(rig):
    """T_c2_c0 = T_c2_c1 T_c1_c0 must equal the rig's ultra pose, translation in metres."""
    doc = yaml.safe_load(kalibr_yaml(rig))
    T10 = np.array(doc["cam1"]["T_cn_cnm1"])
    T21 = np.array(doc["cam2"]["T_cn_cnm1"])
    assert T10.dtype == float and T21.dtype == float
    for T, name in ((T10, "tele"), (T21 @ T10, "ultra")):
        pose = rig.rig[name].pose
        np.testing.assert_allclose(T[:3, :3], pose.R, atol=1e-12)
        np.testing.assert_allclose(T[:3, 3] * 1000.0, pose.t_mm, atol=1e-9)
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


@pytest.mark.parametrize("x", [1e-05, -2e-07, 1.5e-12, 3e20, 0.0, -0.25, 6058.651])
def test_yaml_floats_stay_floats_in_pyyaml(x):
    """PyYAML reads ``1e-05`` as a string; the export's spelling must come back as the same float."""
    value = yaml.safe_load(f"v: {_yaml_float(x)}")["v"]
    assert isinstance(value, float) and value == x


# ---------------------------------------------------------------------------- COLMAP


def test_colmap_cameras_txt(rig):
    lines = colmap_cameras_txt(rig).splitlines()
    assert lines[:3] == ["# Camera list with one line of data per camera:",
                         "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                         "# Number of cameras: 3"]
    data = [ln.split() for ln in lines if not ln.startswith("#")]
    assert [row[0] for row in data] == ["1", "2", "3"]
    for row, name in zip(data, rig.camera_order()):
        cam = rig.cameras[name]
        assert row[1] == "OPENCV"
        assert (int(row[2]), int(row[3])) == cam.image_size
        params = [float(p) for p in row[4:]]
        assert params == [cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5, cam.k1, cam.k2, 0.0, 0.0]


def test_colmap_opencv_model_projects_like_dualcal_half_a_pixel_apart(rig):
    """COLMAP's OPENCV model on the exported parameters lands 0.5 px right and down of dualcal."""
    row = [ln for ln in colmap_cameras_txt(rig).splitlines() if ln.startswith("2 ")][0].split()
    fx, fy, cx, cy, k1, k2, p1, p2 = (float(p) for p in row[4:])
    X = rig.camera_poses["tele"]["IMG_02"].apply(rig.board.object_points_mm())
    _, uv = _board_in(rig, "tele", "IMG_02")
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    radial = k1 * r2 + k2 * r2 * r2
    xd = x + x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y + y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    np.testing.assert_allclose(np.column_stack([fx * xd + cx, fy * yd + cy]), uv + 0.5, atol=1e-6)


# ---------------------------------------------------------------------------- mrcal


def _parse_cameramodel(text: str) -> dict:
    """mrcal's .cameramodel: a Python literal dict with ``#`` comments."""
    return ast.literal_eval(re.sub(r"#[^\n]*", "", text))


def test_mrcal_cameramodel_parses_number_for_number(rig):
    for name in rig.camera_order():
        cam = rig.cameras[name]
        doc = _parse_cameramodel(mrcal_cameramodel(rig, name))
        assert set(doc) == {"lensmodel", "intrinsics", "extrinsics", "imagersize"}
        assert doc["lensmodel"] == "LENSMODEL_OPENCV4"
        assert doc["intrinsics"] == [cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.k2, 0.0, 0.0]
        assert doc["imagersize"] == list(cam.image_size)
        rt = np.array(doc["extrinsics"])
        if name == rig.reference:
            np.testing.assert_array_equal(rt, np.zeros(6))
        else:
            pose = rig.rig[name].pose
            np.testing.assert_allclose(rotation_from_rotvec(rt[:3]), pose.R, atol=1e-12)
            np.testing.assert_allclose(rt[3:] * 1000.0, pose.t_mm, atol=1e-9)


def test_mrcal_files_in_a_folder_or_by_stem(rig, tmp_path):
    folder = tmp_path / "models"
    folder.mkdir()
    assert mrcal_paths(rig, folder) == {n: folder / f"{n}.cameramodel" for n in ("wide", "tele", "ultra")}
    assert mrcal_paths(rig, tmp_path / "rig.cameramodel") == {
        n: tmp_path / f"rig-{n}.cameramodel" for n in ("wide", "tele", "ultra")}
    written = write_export(rig, "mrcal", tmp_path / "rig")
    assert sorted(p.name for p in written) == ["rig-tele.cameramodel", "rig-ultra.cameramodel",
                                               "rig-wide.cameramodel"]
    assert _parse_cameramodel(written[0].read_text())["lensmodel"] == "LENSMODEL_OPENCV4"
    with pytest.raises(InputError, match="does not exist"):
        mrcal_paths(rig, f"{tmp_path}/missing/")


# ---------------------------------------------------------------------------- all formats


@pytest.mark.parametrize("fmt", ["kalibr", "mrcal"])
def test_formats_that_place_cameras_refuse_a_rig_without_relations(rig, tmp_path, fmt):
    alone = replace(rig, rig={}, rig_mode="none")
    with pytest.raises(InputError, match="no pose relative to wide"):
        export_files(alone, fmt, tmp_path / "out")


def test_unknown_format_is_an_input_error(rig, tmp_path):
    with pytest.raises(InputError, match="choose from opencv, kalibr, colmap, mrcal"):
        export_files(rig, "matlab", tmp_path / "out")


@pytest.mark.parametrize("fmt", FORMATS)
def test_nonzero_skew_is_dropped_with_one_warning(rig, tmp_path, capsys, fmt):
    skewed = replace(rig, cameras={**rig.cameras, "tele": replace(rig.cameras["tele"], skew=0.75)})
    write_export(skewed, fmt, tmp_path / "out")
    err = capsys.readouterr().err
    assert err.count("warning") == 1
    assert "tele = 0.75 px" in err and "no skew term" in err


def _renamed(rig, reference: str, other: str):
    """The wide + tele part of ``rig`` with its cameras renamed."""
    return replace(rig, cameras={reference: rig.cameras["wide"], other: rig.cameras["tele"]}, reference=reference,
                   rig={other: rig.rig["tele"]})


@pytest.mark.parametrize("fmt, what", [("opencv", "the OpenCV key 'wide_1'"),
                                       ("kalibr", "the rostopic '/wide_1/image_raw'"),
                                       ("mrcal", "the file '{tmp}/rig-wide_1.cameramodel'")])
def test_cameras_spelled_alike_are_refused(rig, tmp_path, fmt, what):
    """``wide 1`` and ``wide_1`` are distinct cameras but one key or file name after escaping."""
    alike = _renamed(rig, "wide 1", "wide_1")
    message = f"cameras 'wide 1' and 'wide_1' would both be written as {what.replace('{tmp}', str(tmp_path))}"
    with pytest.raises(InputError, match=re.escape(message)):
        write_export(alike, fmt, tmp_path / "rig")
    assert list(tmp_path.iterdir()) == []
    assert write_export(alike, "colmap", tmp_path / "cameras.txt")   # numbered cameras: no clash


def test_kalibr_topics_of_cameras_differing_in_dash_and_underscore_clash(rig):
    alike = _renamed(rig, "wide-1", "wide_1")
    with pytest.raises(InputError, match="'wide-1' and 'wide_1' would both be written as the rostopic"):
        kalibr_yaml(alike)
    files = sorted(mrcal_paths(alike, "rig").values())
    assert files == [Path("rig-wide-1.cameramodel"), Path("rig-wide_1.cameramodel")]       # '-' is kept


@pytest.mark.parametrize("fmt", ["opencv", "kalibr", "colmap"])
def test_single_file_formats_refuse_a_folder(rig, tmp_path, fmt):
    with pytest.raises(InputError, match="is a folder: give a file name"):
        write_export(rig, fmt, tmp_path)


def test_mrcal_checks_every_file_before_writing_any(rig, tmp_path):
    (tmp_path / "rig-ultra.cameramodel").mkdir()
    with pytest.raises(InputError, match="rig-ultra.cameramodel' is a folder"):
        write_export(rig, "mrcal", tmp_path / "rig")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig-ultra.cameramodel"]


def test_zero_skew_exports_without_warning(rig, tmp_path, capsys):
    write_export(rig, "colmap", tmp_path / "cameras.txt")
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------------------- CLI



def test_cli_export_writes_the_file(calib_json, tmp_path, run_cli):
    out = tmp_path / "cameras.txt"
    code, stdout, _ = run_cli("export", str(calib_json), "--format", "colmap", "-o", str(out))
    assert code == 0 and f"wrote {out}" in stdout
    assert out.read_text().startswith("# Camera list with one line of data per camera:")


@pytest.mark.parametrize("args, message", [
    (["--format", "matlab"], "Invalid value for '--format'"),
    (["--format", "opencv", "-o", "{tmp}/no/such/folder/rig.yml"], "output folder"),
    (["--format", "mrcal", "-o", "{tmp}/models/"], "output folder"),
    (["--format", "kalibr", "-o", "{tmp}"], "is a folder: give a file name"),
])
def test_cli_export_errors_are_one_line(calib_json, tmp_path, run_cli, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if "-o" not in args:
        args += ["-o", str(tmp_path / "x.yml")]
    code, _, err = run_cli("export", str(calib_json), *args)
    assert code == 2 and message in err
    assert "Traceback" not in err


def test_cli_export_refuses_a_corners_json(rig, tmp_path, run_cli):
    corners = tmp_path / "corners.json"
    io.save_corners(corners, rig.corners)
    code, _, err = run_cli("export", str(corners), "--format", "opencv", "-o", str(tmp_path / "x.yml"))
    assert code == 2
    assert "this is a corners.json, expected a calib.json" in err
    assert len(err.strip().splitlines()) == 1


def test_opencv_export_carries_the_stereo_rectification_of_dualcal_rectify(calib_json, rig, tmp_path, run_cli):
    """Per other camera, R1 R2 P1 P2 Q exactly as `dualcal rectify` writes them for (reference, camera)."""
    assert run_cli("export", calib_json, "--format", "opencv", "-o", tmp_path / "rig.yml").code == 0
    fs = cv2.FileStorage(str(tmp_path / "rig.yml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("wide").getNode("R1").empty()
    for name in ("tele", "ultra"):
        photos = []
        for cam in ("wide", name):
            w, h = rig.cameras[cam].image_size
            cv2.imwrite(str(tmp_path / f"{cam}.png"), np.full((h, w), 128, np.uint8))
            photos.append(f"{cam}={tmp_path / f'{cam}.png'}")
        res = run_cli("rectify", calib_json, "--pair", *photos, "-o", tmp_path / name)
        assert res.code == 0, res.err
        doc = json.loads((tmp_path / name / "rectify.json").read_text())
        node = fs.getNode(name)
        for key in ("R1", "R2", "P1", "P2", "Q"):
            np.testing.assert_array_equal(node.getNode(key).mat(), doc[key])
        assert [int(node.getNode(k).real()) for k in ("rectified_width", "rectified_height")] == doc["image_size"]


# ---------------------------------------------------------------------------- lens models


@pytest.fixture(scope="module")
def rig5():
    """The stereo pair with OpenCV's five-coefficient lenses (synth preset stereo5: k3, p1, p2 not zero)."""
    return synth.truth_rig_model(synth.make_truth("stereo5", views=3, seed=2))


@pytest.fixture(scope="module")
def rig4(rig5):
    """The same pair in the model k1k2p1p2 (k3 dropped)."""
    return replace(rig5, cameras={n: replace(c, k3=0.0, model="k1k2p1p2") for n, c in rig5.cameras.items()})


def _camera_frame_points(rig, name, view="IMG_02"):
    X = rig.camera_poses[name][view].apply(rig.board.object_points_mm())
    return X, project_points(rig.cameras[name], X)


@pytest.mark.parametrize("which", ["rig4", "rig5"])
def test_opencv_export_writes_all_five_coefficients_and_projects_like_dualcal(which, request, tmp_path):
    rig = request.getfixturevalue(which)
    write_export(rig, "opencv", tmp_path / "rig.yml")
    fs = cv2.FileStorage(str(tmp_path / "rig.yml"), cv2.FILE_STORAGE_READ)
    for name, cam in rig.cameras.items():
        node = fs.getNode(name)
        np.testing.assert_array_equal(node.getNode("D").mat(), [cam.distortion])
        assert node.getNode("lens_model").string() == cam.model
        X, uv = _camera_frame_points(rig, name)
        uv_cv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), node.getNode("K").mat(), node.getNode("D").mat())
        np.testing.assert_allclose(uv_cv.reshape(-1, 2), uv, atol=1e-6)


def test_kalibr_radtan_holds_p1_p2_and_refuses_k3(rig4, rig5):
    doc = yaml.safe_load(kalibr_yaml(rig4))
    for i, name in enumerate(rig4.camera_order()):
        cam = rig4.cameras[name]
        assert doc[f"cam{i}"]["distortion_coeffs"] == [cam.k1, cam.k2, cam.p1, cam.p2]
    with pytest.raises(InputError, match="kalibr's radtan model has no k3, which the lens model k1k2p1p2k3 of "
                                         "left, right has: export to opencv, colmap or mrcal"):
        kalibr_yaml(rig5)


def _colmap_rows(rig):
    rows = [ln.split() for ln in colmap_cameras_txt(rig).splitlines() if not ln.startswith("#")]
    return dict(zip(rig.camera_order(), rows))


@pytest.mark.parametrize("which, colmap_model, n_params", [("rig4", "OPENCV", 8), ("rig5", "FULL_OPENCV", 12)])
def test_colmap_model_of_each_lens_model_projects_like_dualcal_half_a_pixel_apart(which, colmap_model, n_params,
                                                                                 request):
    """COLMAP's OPENCV (k1 k2 p1 p2) and FULL_OPENCV (k1 k2 p1 p2 k3 k4 k5 k6, a rational radial
    factor) by their own formulas, on the exported numbers."""
    rig = request.getfixturevalue(which)
    for name, row in _colmap_rows(rig).items():
        assert row[1] == colmap_model and len(row) == 4 + n_params
        p = [float(v) for v in row[4:]] + [0.0] * (12 - n_params)
        fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 = p
        assert p[4:9] == list(rig.cameras[name].distortion) and p[9:] == [0.0, 0.0, 0.0]
        X, uv = _camera_frame_points(rig, name)
        x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
        r2 = x * x + y * y
        radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
        np.testing.assert_allclose(np.column_stack([fx * xd + cx, fy * yd + cy]), uv + 0.5, atol=1e-6)


@pytest.mark.parametrize("which, lensmodel", [("rig4", "LENSMODEL_OPENCV4"), ("rig5", "LENSMODEL_OPENCV5")])
def test_mrcal_lensmodel_of_each_lens_model(which, lensmodel, request):
    rig = request.getfixturevalue(which)
    for name in rig.camera_order():
        cam = rig.cameras[name]
        doc = _parse_cameramodel(mrcal_cameramodel(rig, name))
        assert doc["lensmodel"] == lensmodel
        n = 4 if lensmodel.endswith("4") else 5
        assert doc["intrinsics"] == [cam.fx, cam.fy, cam.cx, cam.cy, *cam.distortion[:n]]


def test_cli_kalibr_export_of_a_k3_model_is_one_line(rig5, tmp_path, run_cli):
    io.save_rig(tmp_path / "calib.json", rig5)
    res = run_cli("export", tmp_path / "calib.json", "--format", "kalibr", "-o", tmp_path / "camchain.yaml")
    assert res.code == 2 and len(res.err_lines) == 1 and "radtan model has no k3" in res.err
    assert not (tmp_path / "camchain.yaml").exists()


# ----------------------------------------------------------------------------- the fisheye kb4


@pytest.fixture(scope="module")
def rig3():
    """phone3's exact truth: a kb4 ultra-wide beside radial-tangential wide and tele."""
    return synth.truth_rig_model(synth.make_truth("phone3", views=3, seed=2, scale=0.25))


def test_opencv_export_of_a_fisheye_reprojects_with_cv2_fisheye(rig3, tmp_path):
    """Read back with cv2.FileStorage: D is cv2.fisheye's 1x4 for the kb4 camera (1x5 for the others),
    and cv2.fisheye.projectPoints with K and D puts the board's corners where dualcal does."""
    write_export(rig3, "opencv", tmp_path / "rig.yml")
    fs = cv2.FileStorage(str(tmp_path / "rig.yml"), cv2.FILE_STORAGE_READ)
    for name, cam in rig3.cameras.items():
        node = fs.getNode(name)
        D = node.getNode("D").mat()
        assert node.getNode("lens_model").string() == cam.model and D.shape == ((1, 4) if cam.fisheye else (1, 5))
        X, uv = _camera_frame_points(rig3, name, "IMG_01")
        project = cv2.fisheye.projectPoints if cam.fisheye else cv2.projectPoints
        uv_cv, _ = project(X.reshape(1, -1, 3), np.zeros(3), np.zeros(3), node.getNode("K").mat(), D)
        np.testing.assert_allclose(uv_cv.reshape(-1, 2), uv, atol=1e-6)
    assert rig3.cameras["ultra"].fisheye


def test_kalibr_and_colmap_hold_the_fisheye_as_their_equidistant_models(rig3):
    """Kalibr's pinhole-equi (``distortion_model: equidistant``) and COLMAP's OPENCV_FISHEYE, by their
    own formulas (COLMAP's principal point half a pixel off), project like dualcal."""
    order = rig3.camera_order()
    radtan = replace(rig3, cameras={**rig3.cameras, "wide": replace(rig3.cameras["wide"], k3=0.0, model="k1k2p1p2")})
    doc = yaml.safe_load(kalibr_yaml(radtan))
    cam = rig3.cameras["ultra"]
    entry = doc[f"cam{order.index('ultra')}"]
    assert (entry["camera_model"], entry["distortion_model"]) == ("pinhole", "equidistant")
    assert entry["distortion_coeffs"] == [cam.k1, cam.k2, cam.k3, cam.k4]
    assert doc[f"cam{order.index('wide')}"]["distortion_model"] == "radtan"
    row = _colmap_rows(rig3)["ultra"]
    assert row[1] == "OPENCV_FISHEYE" and len(row) == 12
    fx, fy, cx, cy, k1, k2, k3, k4 = (float(v) for v in row[4:])
    X, uv = _camera_frame_points(rig3, "ultra", "IMG_01")
    r = np.hypot(X[:, 0], X[:, 1]) / X[:, 2]
    theta = np.arctan(r)
    scale = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8) / r
    xd, yd = X[:, 0] / X[:, 2] * scale, X[:, 1] / X[:, 2] * scale
    np.testing.assert_allclose(np.column_stack([fx * xd + cx, fy * yd + cy]), uv + 0.5, atol=1e-6)


def test_mrcal_refuses_a_fisheye_naming_the_formats_that_hold_it(rig3, tmp_path, run_cli):
    with pytest.raises(InputError, match="mrcal has no Kannala-Brandt fisheye, the lens model of ultra: export to "
                                         "opencv \\(cv2.fisheye\\), kalibr \\(pinhole-equi\\) or colmap"):
        export_files(rig3, "mrcal", tmp_path)
    io.save_rig(tmp_path / "calib.json", rig3)
    res = run_cli("export", tmp_path / "calib.json", "--format", "mrcal", "-o", tmp_path / "m")
    assert res.code == 2 and len(res.err.strip().splitlines()) == 1 and "OPENCV_FISHEYE" in res.err
