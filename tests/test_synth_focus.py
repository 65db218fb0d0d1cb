"""Synthetic lenses that breathe with focus and shift with OIS (dualcal.synthetic.synth_focus), and their photos."""

import json

import numpy as np
import pytest

from dualcal.files.photos import read_focus
from dualcal.synthetic.synth import make_truth, true_corners
from dualcal.synthetic.synth_focus import FOCAL_MM, RANGE_SHARE, breathing_camera
from dualcal.geometry.camera import project_points


def test_each_photo_is_focused_on_the_board_and_shifted_by_its_own_draw():
    """fx(d) = fx_inf (1 + b f / (d - f)) at the board centre's depth in that photo's camera; the principal point
    moved by a draw of the stated spread, per camera and photo; the corners are the photo's own camera's."""
    plain = make_truth("note8", views=12, seed=4, scale=0.25)
    truth = make_truth("note8", views=12, seed=4, scale=0.25, breathing=1.5, ois_px=2.0)
    assert plain.photo_lenses is None
    assert all(np.allclose(truth.view_poses[v].R, plain.view_poses[v].R) for v in plain.view_poses)  # the same poses
    centre = truth.board.object_points_mm().mean(axis=0)
    shifts = []
    corners = true_corners(truth)
    for view, lenses in truth.photo_lenses.items():
        for cam, lens in lenses.items():
            depth = truth.camera_pose(cam, view).apply(centre[None])[0, 2]
            f = FOCAL_MM["note8"][cam]
            grow = 1 + 1.5 * f / (depth - f)
            nominal = truth.cameras[cam]
            assert lens.focus_mm == pytest.approx(depth) and lens.focal_mm == f
            assert lens.camera.fx == pytest.approx(nominal.fx * grow) and lens.camera.fy == pytest.approx(nominal.fy * grow)
            assert (lens.camera.cx - nominal.cx, lens.camera.cy - nominal.cy) == pytest.approx(lens.shift_px)
            shifts.append(lens.shift_px)
            X = truth.camera_pose(cam, view).apply(truth.board.object_points_mm())
            seen = np.isfinite(corners[cam][view][:, 0])
            assert np.allclose(corners[cam][view][seen], project_points(lens.camera, X[seen]), atol=1e-9)
    shifts = np.array(shifts)
    assert 1.4 < shifts.std() < 2.6 and np.all(np.abs(shifts.mean(axis=0)) < 1.0)
    # 0.3 m with the tele (6 mm): +2 % for a thin lens
    tele = truth.cameras["tele"]
    assert breathing_camera(tele, 6.0, 1.0, 300.0).fx / tele.fx == pytest.approx(300.0 / 294.0)


def test_synth_writes_each_photos_focus_into_its_exif_and_the_truth(tmp_path, run_cli):
    """``dualcal synth --breathing --ois --object-photos``: truth.json's photos and measure_photos; every photo's
    EXIF states its focus (SubjectDistance, and the Apple-style MakerNote's FocusDistanceRange +-1.5 %)."""
    res = run_cli("synth", tmp_path / "s", "--views", "2", "--scale", "0.1", "--breathing", "1", "--ois", "1.5",
                  "--object-photos", "--jobs", "2")
    assert res.code == 0, res.err
    doc = json.loads((tmp_path / "s" / "truth.json").read_text())
    assert set(doc["photos"]) == {"IMG_01", "IMG_02"} and set(doc["measure_photos"]) == {"300mm", "2000mm"}
    for view, lenses in doc["photos"].items():
        for cam, lens in lenses.items():
            facts = read_focus(tmp_path / "s" / "photos" / cam / f"{view}.jpg")
            assert facts.subject_distance_m == pytest.approx(lens["focus_m"], abs=1e-3)
            lo, hi = facts.apple["FocusDistanceRange"]
            assert lo == pytest.approx(lens["focus_m"] * (1 - RANGE_SHARE), abs=1e-3) and lo < lens["focus_m"] < hi
    near = doc["measure_photos"]["300mm"]
    for cam, photo in near["photos"].items():
        assert read_focus(tmp_path / "s" / "measure" / photo["file"]).focus_m == pytest.approx(photo["focus_m"], rel=0.01)
        assert 0.2 < photo["focus_m"] < 0.4
    box = near["box"]
    R, t, half = np.array(box["R"]), np.array(box["t_mm"]), np.array(box["size_mm"]) / 2
    local = (np.array(near["face_points_mm"]) - t) @ R                 # the box's frame: on one face
    assert np.any(np.all(np.isclose(np.abs(local), half, atol=1e-9), axis=0))
    res = run_cli("synth", tmp_path / "r", "--views", "2", "--scale", "0.1", "--breathing", "1", "--roll")
    assert res.code == 2 and "--breathing and --ois write a chessboard's photo set" in res.err
