"""Stereo rectification (dualcal.files.stereo) and `dualcal rectify`: rows (columns) of corresponding points
agree, OpenCV's conventions hold, maps and points agree, real rendered photos line up."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from schema_check import assert_valid
from dualcal.files.detect import detect_photo
from dualcal.errors import EstimationError, InputError
from dualcal.files.io import save_rig
from dualcal.geometry.model import Pose
from dualcal.files.rectify import rectify_map
from dualcal.synthetic.render import render_view
from dualcal.files.stereo import rectify_points, stereo_rectify
from dualcal.synthetic.synth import make_truth, true_corners, truth_rig_model

# (preset, first camera, second camera, vertical): a horizontal stereo rig, the note8 wide + tele
# (baseline along the columns), and ultra-wide + tele of the triple rig (focal lengths 1700 and 6100 px)
PAIRS = [("stereo", "left", "right", False), ("note8", "wide", "tele", True), ("triple", "ultra", "tele", True),
         ("stereo5", "left", "right", False)]   # and the stereo pair with OpenCV's five-coefficient lenses


@pytest.fixture(scope="module", params=PAIRS, ids=[f"{p}-{a}-{b}" for p, a, b, _ in PAIRS])
def pair(request):
    preset, first, second, vertical = request.param
    truth = make_truth(preset, views=6, seed=1)
    return truth, truth_rig_model(truth), first, second, vertical


def _opencv(rig, first, second, alpha):
    c1, c2 = rig.cameras[first], rig.cameras[second]
    pose = rig.pose_from_reference(second).compose(rig.pose_from_reference(first).inverse())
    d = [np.array(c.distortion) for c in (c1, c2)]
    return cv2.stereoRectify(c1.K, d[0], c2.K, d[1], c1.image_size, pose.R, pose.t_mm.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY,
                             alpha=alpha)


@pytest.mark.parametrize("keep", ["valid", "all"])
def test_corresponding_true_corners_share_a_row_or_column(pair, keep):
    """True corners of every view, seen by both cameras, rectified: same row (column) to 1e-6 px."""
    truth, rig, first, second, vertical = pair
    rect = stereo_rectify(rig, first, second, keep)
    assert rect.vertical is vertical
    corners = true_corners(truth)
    worst = 0.0
    for view in truth.view_poses:
        a = rectify_points(rect, first, rig.cameras[first], corners[first][view])
        b = rectify_points(rect, second, rig.cameras[second], corners[second][view])
        worst = max(worst, float(np.max(np.abs(a[:, 0 if vertical else 1] - b[:, 0 if vertical else 1]))))
        disparity = (a - b)[:, 1 if vertical else 0]
        assert np.all(disparity > 0) or np.all(disparity < 0)       # one side of infinity, as it must
    assert worst < 1e-6


def test_rotations_and_projections_are_opencvs(pair):
    """R1 R2 exactly as cv2.stereoRectify; P2's baseline term and Q's -1/T as OpenCV's."""
    _, rig, first, second, vertical = pair
    rect = stereo_rectify(rig, first, second)
    R1, R2, P1, P2, Q, _, _ = _opencv(rig, first, second, alpha=0)
    np.testing.assert_allclose(rect.R1, R1, atol=1e-9)
    np.testing.assert_allclose(rect.R2, R2, atol=1e-9)
    axis = 1 if vertical else 0
    assert rect.P2[axis, 3] / rect.P2[0, 0] == pytest.approx(P2[axis, 3] / P2[0, 0], rel=1e-9)
    assert rect.Q[3, 2] == pytest.approx(Q[3, 2], rel=1e-9)
    assert rect.P2[1 - axis, 3] == 0 and rect.P2[2, 3] == 0
    np.testing.assert_array_equal(rect.P1[:, :3], rect.P2[:, :3])     # one camera matrix for both


def test_q_reprojects_disparity_to_the_point(pair):
    """(u, v, disparity) through Q gives the corner's position in rectified camera 1, mm."""
    truth, rig, first, second, vertical = pair
    rect = stereo_rectify(rig, first, second)
    view = next(iter(truth.view_poses))
    X1 = truth_rig_model(truth).camera_poses[first][view].apply(truth.board.object_points_mm())
    corners = true_corners(truth)
    a = rectify_points(rect, first, rig.cameras[first], corners[first][view])
    b = rectify_points(rect, second, rig.cameras[second], corners[second][view])
    d = (a - b)[:, 1 if vertical else 0]
    hom = np.column_stack([a, d, np.ones(len(d))]) @ rect.Q.T
    np.testing.assert_allclose(hom[:, :3] / hom[:, 3:], X1 @ rect.R1.T, rtol=1e-7, atol=1e-6)


def test_maps_follow_the_points_and_opencvs_maps(pair):
    """The remap table at a rectified corner points at the distorted corner; OpenCV's map agrees."""
    truth, rig, first, second, _ = pair
    rect = stereo_rectify(rig, first, second, "all")
    view = next(iter(truth.view_poses))
    for name in (first, second):
        cam = rig.cameras[name]
        uv = true_corners(truth)[name][view]
        r = rectify_points(rect, name, cam, uv)
        map_x, map_y = rectify_map(cam, rect.camera, 0, rect.image_size[1], rect.rotation(name))
        sample = np.column_stack([cv2.remap(m, r[:, 0:1].astype(np.float32), r[:, 1:2].astype(np.float32),
                                            cv2.INTER_LINEAR).ravel() for m in (map_x, map_y)])
        assert np.max(np.abs(sample - uv)) < 0.02 * max(1.0, cam.fx / rect.camera.fx)
        cv_x, cv_y = cv2.initUndistortRectifyMap(cam.K, np.array(cam.distortion), rect.rotation(name),
                                                 rect.P1[:, :3], rect.image_size, cv2.CV_32FC1)
        inside = (map_x > 0) & (map_x < cam.image_size[0] - 1) & (map_y > 0) & (map_y < cam.image_size[1] - 1)
        assert inside.mean() > 0.05
        assert np.max(np.abs(cv_x - map_x)[inside]) < 0.05 and np.max(np.abs(cv_y - map_y)[inside]) < 0.05


def test_the_common_camera_keeps_the_smaller_focal_length_and_the_regions_nest(pair):
    _, rig, first, second, _ = pair
    valid, every = stereo_rectify(rig, first, second, "valid"), stereo_rectify(rig, first, second, "all")
    f = min(min(c.fx, c.fy) for c in (rig.cameras[first], rig.cameras[second]))
    assert valid.camera.fx == valid.camera.fy == every.camera.fx == f
    assert valid.camera.skew == 0 and valid.camera.k1 == valid.camera.k2 == 0
    assert valid.image_size[0] < every.image_size[0] and valid.image_size[1] < every.image_size[1]


def test_nan_corners_stay_nan(pair):
    truth, rig, first, _, _ = pair
    rect = stereo_rectify(rig, first, pair[3])
    uv = true_corners(truth)[first][next(iter(truth.view_poses))].copy()
    uv[[2, 5]] = np.nan
    out = rectify_points(rect, first, rig.cameras[first], uv)
    assert np.isnan(out[[2, 5]]).all() and np.isfinite(np.delete(out, [2, 5], axis=0)).all()


def test_pairs_that_cannot_be_rectified_are_refused():
    truth = make_truth("stereo", views=3, seed=0)
    rig = truth_rig_model(truth)
    with pytest.raises(InputError, match="twice"):
        stereo_rectify(rig, "left", "left")
    with pytest.raises(InputError, match="not in the calibration"):
        stereo_rectify(rig, "left", "tele")
    with pytest.raises(InputError, match="--keep"):
        stereo_rectify(rig, "left", "right", "some")
    rig.rig.pop("right")
    with pytest.raises(InputError, match="no pose relative"):
        stereo_rectify(rig, "left", "right")
    turned = truth_rig_model(truth)
    turned.rig["right"].pose = Pose(np.diag([-1.0, 1.0, -1.0]), np.array([-100.0, 0.0, 0.0]))   # looks backwards
    with pytest.raises(EstimationError):
        stereo_rectify(turned, "left", "right")


# ---------------------------------------------------------------------------- the command on rendered photos


@pytest.fixture(scope="module")
def rendered_note8(tmp_path_factory):
    d = tmp_path_factory.mktemp("rectify")
    truth = make_truth("note8", views=2, seed=5, scale=0.25)
    save_rig(d / "calib.json", truth_rig_model(truth))
    view = next(iter(truth.view_poses))
    for name, cam in truth.cameras.items():
        img = render_view(cam, truth.camera_pose(name, view), truth.board, np.random.default_rng(3))
        cv2.imwrite(str(d / f"{name}.png"), img)
    return d, truth


def test_rectify_command_lines_up_detected_corners_of_rendered_photos(rendered_note8, run_cli, tmp_path):
    """wide + tele rendered photos, rectified: their detected corners share a column to 0.1 px."""
    d, truth = rendered_note8
    res = run_cli("rectify", d / "calib.json", "--pair", f"wide={d / 'wide.png'}", f"tele={d / 'tele.png'}",
                  "-o", tmp_path, "--keep", "all")
    assert res.code == 0, res.err
    doc = assert_valid(tmp_path / "rectify.json")
    assert doc["cameras"] == ["wide", "tele"] and doc["layout"] == "vertical"
    assert set(doc) >= {"R1", "R2", "P1", "P2", "Q", "image_size", "calibration_fingerprint"}
    w, h = doc["image_size"]
    uv = {}
    for name in ("wide", "tele"):
        found = detect_photo(tmp_path / f"{name}-{name}.png", truth.board)
        assert found.uv is not None, found.reason
        assert found.image_size == (w, h)
        uv[name] = found.uv
    assert np.max(np.abs(uv["wide"][:, 0] - uv["tele"][:, 0])) < 0.1
    check = cv2.imread(str(tmp_path / "epipolar.jpg"))
    assert check.shape[:2] == (2 * h, w) or max(check.shape) == 2400     # stacked: a vertical rig


def test_rectify_command_errors_are_one_line(rendered_note8, run_cli, tmp_path):
    d, _ = rendered_note8
    for pair, message in [((f"wide={d / 'wide.png'}", f"wide={d / 'tele.png'}"), "twice"),
                          ((f"wide={d / 'wide.png'}", f"ultra={d / 'tele.png'}"), "'ultra' is not in"),
                          ((f"wide={d / 'wide.png'}", f"tele={d / 'wide.png'}x"), "no such file"),
                          ((f"wide={d / 'tele.png'}", "nonsense"), "NAME=GLOB")]:
        res = run_cli("rectify", d / "calib.json", "--pair", *pair, "-o", tmp_path / "out")
        assert res.code == 2 and len(res.err_lines) == 1, res.err
        assert message in res.err, res.err


def test_a_fisheye_pair_rectifies_and_maps_like_cv2_fisheye():
    """phone3's wide + kb4 ultra-wide (a vertical rig, 12 mm): true corners rectified share a column,
    and the ultra-wide's remap table is cv2.fisheye.initUndistortRectifyMap's."""
    truth = make_truth("phone3", views=6, seed=1)
    rig = truth_rig_model(truth)
    rect = stereo_rectify(rig, "wide", "ultra", "valid")
    assert rect.vertical
    corners = true_corners(truth)
    for view in [v for v in truth.view_poses if not np.isnan(corners["wide"][v]).all()]:    # instants both saw
        a = rectify_points(rect, "wide", rig.cameras["wide"], corners["wide"][view])
        b = rectify_points(rect, "ultra", rig.cameras["ultra"], corners["ultra"][view])
        assert np.nanmax(np.abs(a[:, 0] - b[:, 0])) < 1e-6
    cam = rig.cameras["ultra"]
    map_x, map_y = rectify_map(cam, rect.camera, 0, rect.image_size[1], rect.rotation("ultra"))
    cv_x, cv_y = cv2.fisheye.initUndistortRectifyMap(cam.K, np.array(cam.distortion).reshape(4, 1),
                                                     rect.rotation("ultra"), rect.P1[:, :3], rect.image_size,
                                                     cv2.CV_32FC1)
    inside = (map_x > 0) & (map_x < cam.image_size[0] - 1) & (map_y > 0) & (map_y < cam.image_size[1] - 1)
    assert inside.mean() > 0.9
    assert np.max(np.abs(cv_x - map_x)[inside]) < 0.05 and np.max(np.abs(cv_y - map_y)[inside]) < 0.05
