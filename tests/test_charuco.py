"""ChArUco boards: rendered markers, detection against OpenCV's and the truth, misread ids, the
dictionary and layout found from photos, calibration from partial views.

Tolerances: a corner is right when it is within 0.3 px of the truth (a wrong id puts it a square,
tens of pixels, away); dualcal's corner RMS must not exceed OpenCV's ``CharucoDetector`` on the
same photos; calibrated parameters must lie within 4 of their stated sigmas.
"""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from dualcal.geometry.board import Board
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import INTRINSIC_NAMES, CameraModel, project_points
from dualcal.files.detect import detect_photo
from dualcal.geometry.grid import validate_grid
from dualcal.files.detect.charuco import check_markers, detect_charuco, opencv_board, resolve_board
from dualcal.errors import DetectionError
from dualcal.estimation.evaluation import evaluate
from dualcal.files.io import load_corners, load_rig
from dualcal.geometry.model import Pose, observed_mask
from dualcal.synthetic.render import render_view, write_photo_set
from dualcal.synthetic.synth import make_truth, noisy_corner_set, true_corners, truth_rig_model

BOARD = Board.charuco_board((11, 8), 25.0, 18.0, "DICT_5X5_100")


def _err_px(uv, truth_uv):
    return np.linalg.norm(np.asarray(uv) - truth_uv, axis=1)


def _rms(err):
    return float(np.sqrt(np.mean(np.square(err))))


@pytest.mark.parametrize("squares, legacy", [((11, 8), False), ((11, 8), True), ((9, 7), False)])
def test_rendered_markers_are_opencvs_board_exactly(squares, legacy):
    """A frontal view at 4 px per mm (5x5 markers: exactly 4 px per cell) is OpenCV's own image."""
    board = Board.charuco_board(squares, 20.0, 14.0, "DICT_5X5_250", legacy)
    cam = CameraModel((squares[0] * 80 + 40, squares[1] * 80 + 40), 1000.0, 1000.0, 0.0, 99.5, 99.5, 0.0, 0.0)
    img = render_view(cam, Pose(np.eye(3), np.array([0.0, 0.0, 250.0])), board, blur_px=0.0, noise=0.0,
                      vignetting=0.0, uneven_light=0.0, clutter=0, white=1.0, black=0.0)
    ref = opencv_board(board).generateImage((squares[0] * 80, squares[1] * 80), marginSize=0, borderBits=1)
    np.testing.assert_array_equal(img[20:20 + ref.shape[0], 20:20 + ref.shape[1]], ref)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A note8 rig at 0.35 scale, 6 views, the tele seeing 30-100 % of an 11x8 ChArUco board."""
    truth = make_truth("note8", views=6, seed=21, scale=0.35, board=BOARD, coverage=(0.3, 1.0))
    root = tmp_path_factory.mktemp("charuco")
    write_photo_set(truth, root / "photos", seed=21, progress=False)
    return truth, root


def test_corners_found_wherever_opencv_finds_them_with_the_right_ids_and_smaller_errors(rendered):
    truth, root = rendered
    tc = true_corners(truth)
    ours, theirs, shares = [], [], []
    detector = cv2.aruco.CharucoDetector(opencv_board(BOARD))
    for cam in truth.cameras:
        for view in truth.view_poses:
            path = root / "photos" / cam / f"{view}.jpg"
            res = detect_photo(path, BOARD)
            assert res.uv is not None, res.reason
            seen = observed_mask(res.uv)
            err = _err_px(res.uv[seen], tc[cam][view][seen])
            assert err.max() < 0.3, (cam, view, np.flatnonzero(seen)[err >= 0.3])     # no wrong id
            corners, ids, _, _ = detector.detectBoard(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
            ids = ids.ravel()
            assert set(ids) <= set(np.flatnonzero(seen)), (cam, view, sorted(set(ids) - set(np.flatnonzero(seen))))
            ours.append(err)
            theirs.append(_err_px(corners.reshape(-1, 2), tc[cam][view][ids]))
            if cam == "tele":
                shares.append(seen.mean())
    assert min(shares) < 0.6 and max(shares) > 0.9            # partial views and whole ones
    assert _rms(np.concatenate(ours)) <= _rms(np.concatenate(theirs))


def test_misread_ids_never_become_wrong_corners(rendered):
    """Markers drawn with each other's codes (a misread to the detector) are dropped by their
    neighbours' homography; OpenCV's own detector gives up on the whole board."""
    truth, _ = rendered
    view = next(iter(truth.view_poses))
    uv_true = true_corners(truth)["wide"][view]
    swapped = [(5, 30), (30, 5), (17, 18), (18, 17)]        # 17 and 18 are two squares apart
    img = render_view(truth.cameras["wide"], truth.camera_pose("wide", view), BOARD, np.random.default_rng(3),
                      swapped_markers=swapped)
    uv = detect_charuco(img, BOARD)
    seen = observed_mask(uv)
    assert seen.sum() >= 60 and _err_px(uv[seen], uv_true[seen]).max() < 0.3
    # the check itself, on exact marker corners with ids permuted
    pose, cam = truth.camera_pose("wide", view), truth.cameras["wide"]
    markers = project_points(cam, pose.apply(BOARD.marker_corners_mm().reshape(-1, 3))).reshape(-1, 4, 2)
    ids = np.arange(len(markers))
    ids[[3, 20, 21, 40]] = [20, 3, 40, 21]
    kept = check_markers(markers, ids, BOARD)
    assert not kept[[3, 20, 21, 40]].any() and kept.sum() >= len(ids) - 8


def test_too_few_or_collinear_corners_are_not_a_board():
    uv = np.full((BOARD.n_corners, 2), np.nan)
    uv[:5] = np.column_stack([np.arange(5) * 50.0, np.zeros(5)])
    assert "at least 6 needed: for a homography with redundancy" in validate_grid(uv, BOARD)
    uv[:8] = np.column_stack([np.arange(8) * 50.0, np.zeros(8)])
    assert "lie on one line" in validate_grid(uv, BOARD)


@pytest.mark.parametrize("squares, dictionary, legacy", [((11, 8), "DICT_4X4_50", True),
                                                         ((9, 7), "DICT_6X6_250", False),
                                                         ((8, 6), "DICT_APRILTAG_36h11", False)])
def test_dictionary_and_layout_are_found_from_the_photos(squares, dictionary, legacy):
    board = Board.charuco_board(squares, 25.0, 18.0, dictionary, legacy)
    truth = make_truth("note8", views=2, seed=4, scale=0.3, board=board)
    imgs = [render_view(truth.cameras["wide"], truth.camera_pose("wide", v), board, np.random.default_rng(k))
            for k, v in enumerate(truth.view_poses)]
    found = resolve_board(Board.charuco_board(squares, 25.0, 18.0, None, None), iter(imgs))
    # the smallest dictionary of the family that holds the markers: the same board
    expect = {"DICT_6X6_250": "DICT_6X6_50"}.get(dictionary, dictionary)
    assert (found.charuco.dictionary, found.charuco.legacy) == (expect, legacy)
    uv = detect_charuco(imgs[0], found)
    np.testing.assert_allclose(uv[observed_mask(uv)], true_corners(truth)["wide"]["IMG_01"][observed_mask(uv)],
                               atol=0.3)
    if squares[1] % 2 == 0:
        # a photo that shows the ends of the rows refutes the other layout instead of renumbering
        other = replace(found, charuco=replace(found.charuco, legacy=not legacy))
        with pytest.raises(DetectionError, match="laid out as on OpenCV's"):
            detect_charuco(imgs[0], other)
    with pytest.raises(DetectionError, match="no marker of"):
        detect_charuco(imgs[0], replace(found, charuco=replace(found.charuco, dictionary="DICT_7X7_50")))


def test_partial_views_recover_the_truth_within_the_sigmas():
    """Noisy corners of a rig whose tele sees 30-100 % of the board (and the wide 80-100 %)."""
    truth = make_truth("note8", views=13, seed=31, board=BOARD, coverage=(0.3, 1.0))
    tele_share = [observed_mask(uv).mean() for uv in true_corners(truth)["tele"].values()]
    assert min(tele_share) < 0.45
    z = []
    for k in range(6):
        rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=40 + k), drop_outliers=False)
        for name, cam in rig.cameras.items():
            err = cam.as_vector() - truth.cameras[name].as_vector()
            sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
            z.extend(err[sig > 0] / sig[sig > 0])
        rel, true = rig.rig["tele"], truth.rig["tele"]
        z.append((rel.baseline_mm - np.linalg.norm(true.t_mm)) / rel.sigma_baseline_mm)
        z.extend((rel.pose.opk_arcmin - true.opk_arcmin) / rel.sigma_opk_arcmin)
    z = np.asarray(z)
    assert np.abs(z).max() < 4.0 and 0.7 < np.std(z) < 1.3, (np.abs(z).max(), np.std(z))


@pytest.mark.slow
def test_rendered_partial_views_detect_calibrate_evaluate_report_and_export(rendered, tmp_path, run_cli):
    """The commands end to end on the rendered rig, the dictionary left to the photos."""
    truth, root = rendered
    corners_json, calib = tmp_path / "corners.json", tmp_path / "calib.json"
    code, _, err = run_cli("detect", root / "photos", "--board", "charuco:11x8", "--square", "25", "--marker", "18",
                           "-o", corners_json)
    assert code == 0, err
    assert "dictionary DICT_5X5_50" in err
    doc = json.loads(corners_json.read_text())
    assert doc["board"]["charuco"] == {"squares": [11, 8], "marker_mm": 18.0, "dictionary": "DICT_5X5_50"}
    assert any(None in v for v in doc["cameras"]["tele"]["views"].values())     # partial views: null corners
    code, _, err = run_cli("calibrate", corners_json, "-o", calib, "--no-compare-models")
    assert code == 0, err
    rig = load_rig(calib)
    for name, cam in rig.cameras.items():
        err_v = cam.as_vector() - truth.cameras[name].as_vector()
        sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
        assert np.all(np.abs(err_v[sig > 0]) < 4 * sig[sig > 0]), (name, err_v / np.where(sig > 0, sig, 1))
    rel = rig.rig["tele"]
    assert abs(rel.baseline_mm - np.linalg.norm(truth.rig["tele"].t_mm)) < 4 * rel.sigma_baseline_mm
    # the board flags must agree with the file's board: the marker size is checked too
    code, _, err = run_cli("calibrate", corners_json, "--board", "charuco:11x8", "--square", "25", "--marker", "17",
                           "-o", tmp_path / "x.json")
    assert code == 2 and "marker 17 mm disagrees" in err
    evaluation = tmp_path / "eval.json"
    assert run_cli("evaluate", calib, "-o", evaluation).code == 0
    cases = json.loads(evaluation.read_text())["cases"]
    # the 3-D check on the corners both photos saw, against the floor the true rig gives on them
    floor = evaluate(truth_rig_model(truth, rig.corners), progress=False)["cases"]
    assert cases["dual"]["pairs"] == floor["dual"]["pairs"] == len(truth.view_poses)
    for case in ("dual", "wide", "tele"):
        assert np.all(np.asarray(cases[case]["rmse_mm"]) < 1.2 * np.asarray(floor[case]["rmse_mm"]) + 0.01), case
    assert run_cli("report", calib, "--eval", evaluation, "-o", tmp_path / "report.html").code == 0
    html = (tmp_path / "report.html").read_text()
    assert "ChArUco charuco:11x8, DICT_5X5_50, markers 18 mm" in html
    for fmt in ("opencv", "kalibr", "colmap", "mrcal"):
        assert run_cli("export", calib, "--format", fmt, "-o", tmp_path / f"rig.{fmt}").code == 0


def test_commands_that_cannot_use_a_charuco_board_say_so(tmp_path, run_cli):
    code, _, err = run_cli("pick", tmp_path, "--board", "charuco:11x8", "--square", "25", "--marker", "18",
                           "-o", tmp_path / "h.json")
    assert code == 2 and "pick is for chessboards" in err
    code, _, err = run_cli("synth", tmp_path / "s", "--coverage", "0.3:1", "--no-photos")
    assert code == 2 and "--coverage needs a ChArUco board" in err
    code, _, err = run_cli("detect", tmp_path, "--board", "charuco:11x8", "--square", "25", "-o", tmp_path / "c.json")
    assert code == 2 and "--marker MM" in err


def test_synth_writes_partial_charuco_views(tmp_path, run_cli):
    code, _, err = run_cli("synth", tmp_path / "s", "--board", "charuco:11x8", "--square", "25", "--marker", "18",
                           "--views", "6", "--no-photos", "--coverage", "0.3:0.6")
    assert code == 0, err
    corners = load_corners(tmp_path / "s" / "corners.json")
    assert corners.board.charuco.dictionary == "DICT_5X5_50"
    shares = [observed_mask(uv).mean() for uv in corners.cameras["tele"].views.values()]
    assert all(0.3 <= s <= 0.6 for s in shares)
    assert all(observed_mask(uv).mean() >= 0.8 for uv in corners.cameras["wide"].views.values())
