"""The paper's stereo-intersection check (dualcal.estimation.evaluation) and ``dualcal evaluate``."""

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import project_points
from dualcal.errors import EstimationError, InputError
from dualcal.estimation.evaluation import corner_length_errors, evaluate, pose_free_check, resect_view, stereo_cases
from dualcal.files.io import load_evaluation, save_rig
from dualcal.geometry.model import Pose, observed_mask
from dualcal.geometry.resection import resect
from dualcal.geometry.rotation import rotation_from_rotvec, rotvec_from_rotation
from dualcal.synthetic.synth import make_truth, noisy_corner_set, true_corners, truth_rig_model

IDENTITY = Pose(np.eye(3), np.zeros(3))
FLOOR_FACTOR = 1.25


# ---------------------------------------------------------------------------- resection


def test_resection_recovers_exact_poses():
    truth = make_truth("note8", views=3, seed=2)
    X = truth.board.object_points_mm()
    uv = true_corners(truth)
    cases = [(["wide"], [IDENTITY], "wide"), (["tele"], [IDENTITY], "tele"),
             (["wide", "tele"], [IDENTITY, truth.rig["tele"]], "wide"),
             (["tele"], [truth.rig["tele"]], "wide")]          # tele alone, through the rig
    for view in truth.view_poses:
        for cams, rig, pose_of in cases:
            pose = resect(X, [truth.cameras[c] for c in cams], rig, [uv[c][view] for c in cams])
            expected = truth.camera_pose(pose_of, view)
            np.testing.assert_allclose(pose.R, expected.R, atol=1e-10)
            np.testing.assert_allclose(pose.t_mm, expected.t_mm, atol=1e-7)


def test_rig_resection_minimises_the_pixel_residuals():
    truth = make_truth("note8", views=1, seed=5)
    X = truth.board.object_points_mm()
    noisy = noisy_corner_set(truth, 0.5, seed=3)
    cams = [truth.cameras["wide"], truth.cameras["tele"]]
    rig = [IDENTITY, truth.rig["tele"]]
    uv = [noisy.cameras["wide"].views["IMG_01"], noisy.cameras["tele"].views["IMG_01"]]
    pose = resect(X, cams, rig, uv)

    def residuals(p):
        board_to_ref = Pose(rotation_from_rotvec(p[:3]), p[3:])
        return np.concatenate([(project_points(c, q.compose(board_to_ref).apply(X)) - o).ravel()
                               for c, q, o in zip(cams, rig, uv)])

    start = truth.view_poses["IMG_01"]
    best = least_squares(residuals, np.concatenate([rotvec_from_rotation(start.R), start.t_mm]),
                         xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(rotvec_from_rotation(pose.R), best[:3], atol=1e-9)
    np.testing.assert_allclose(pose.t_mm, best[3:], atol=1e-6)


def test_resect_view_ties_the_rig_cameras():
    truth = make_truth("triple", views=2, seed=1)
    rig = truth_rig_model(truth)
    photos = resect_view(rig, "IMG_02", rig.corners)
    assert sorted(photos) == ["tele", "ultra", "wide"]
    for cam, photo in photos.items():
        np.testing.assert_allclose(photo.pose.R, truth.camera_pose(cam, "IMG_02").R, atol=1e-10)
        np.testing.assert_allclose(photo.pose.t_mm, truth.camera_pose(cam, "IMG_02").t_mm, atol=1e-7)


def test_resection_uses_the_corners_each_camera_measured():
    """Exact corners, 40 % of each photo's missing (the two cameras miss different ones), and a
    tele that saw only 3: the rig resection still returns the exact pose."""
    truth = make_truth("note8", views=2, seed=4)
    X = truth.board.object_points_mm()
    uv = true_corners(truth)
    rng = np.random.default_rng(0)
    wide, tele = uv["wide"]["IMG_02"].copy(), uv["tele"]["IMG_02"].copy()
    wide[rng.random(len(wide)) < 0.4] = np.nan
    tele[3:] = np.nan
    pose = resect(X, [truth.cameras["wide"], truth.cameras["tele"]], [IDENTITY, truth.rig["tele"]], [wide, tele])
    np.testing.assert_allclose(pose.t_mm, truth.view_poses["IMG_02"].t_mm, atol=1e-7)
    with pytest.raises(EstimationError, match="at least 4 measured corners"):
        resect(X, [truth.cameras["tele"]], [IDENTITY], [tele])


# ---------------------------------------------------------------------------- the cases


def test_exact_corners_intersect_exactly_and_the_document_follows_the_contract():
    truth = make_truth("note8", views=13, seed=0)
    doc = evaluate(truth_rig_model(truth), progress=False)
    assert list(doc["cases"]) == ["dual", "wide", "tele"]
    assert doc["holdout"] is False
    for name, case in doc["cases"].items():
        assert case["pairs"] == (13 if name == "dual" else 78)
        assert case["points"] == 40 * case["pairs"]
        assert len(case["rmse_mm"]) == 3 and max(case["rmse_mm"]) < 1e-6
    assert len(doc["per_pair"]) == 13 + 2 * 78
    first = doc["per_pair"][0]
    assert first["case"] == "dual" and first["cameras"] == ["wide", "tele"] and first["views"] == ["IMG_01"] * 2
    json.dumps(doc, allow_nan=False)                       # serialisable as it is


def test_noise_propagates_into_the_rmse():
    truth = make_truth("stereo", views=6, seed=0)
    small = evaluate(truth_rig_model(truth, noisy_corner_set(truth, 0.01, seed=2)))
    large = evaluate(truth_rig_model(truth, noisy_corner_set(truth, 0.04, seed=2)))
    for name in small["cases"]:
        ratio = np.array(large["cases"][name]["rmse_mm"]) / small["cases"][name]["rmse_mm"]
        np.testing.assert_allclose(ratio, 4.0, rtol=0.02)  # intersection is linear in small noise


def test_three_cameras_name_the_dual_cases():
    truth = make_truth("triple", views=4, seed=0)
    doc = evaluate(truth_rig_model(truth))
    assert list(doc["cases"]) == ["dual", "dual:ultra", "wide", "tele", "ultra"]
    assert {tuple(p["cameras"]) for p in doc["per_pair"] if p["case"] == "dual:ultra"} == {("wide", "ultra")}


def test_views_without_a_pose_are_left_out():
    truth = make_truth("note8", views=5, seed=0)
    rig = truth_rig_model(truth)
    del rig.camera_poses["tele"]["IMG_03"]                 # e.g. dropped by the calibration
    doc = evaluate(rig)
    assert doc["cases"]["dual"]["pairs"] == 4
    assert doc["cases"]["wide"]["pairs"] == 10 and doc["cases"]["tele"]["pairs"] == 6


def test_pairs_intersect_the_corners_both_photos_measured(capsys):
    truth = make_truth("stereo", views=3, seed=0)
    rig = truth_rig_model(truth)
    rng = np.random.default_rng(1)
    for cam in rig.corners.cameras.values():
        for uv in cam.views.values():
            uv[rng.random(len(uv)) < 0.3] = np.nan
    right, left = rig.corners.cameras["right"].views["IMG_02"], rig.corners.cameras["left"].views["IMG_02"]
    right[:2], right[2:] = true_corners(truth)["right"]["IMG_02"][:2], np.nan
    left[:2] = np.nan                                                 # no corner in common there
    doc = evaluate(rig)
    views = rig.corners.cameras
    both = [observed_mask(views["left"].views[v]) & observed_mask(views["right"].views[v]) for v in ("IMG_01", "IMG_03")]
    assert doc["cases"]["dual"]["pairs"] == 2 and doc["cases"]["dual"]["points"] == sum(m.sum() for m in both)
    assert max(doc["cases"]["dual"]["rmse_mm"]) < 1e-6
    assert "left/IMG_02 + right/IMG_02 left out: the two photos measured no corner in common" in capsys.readouterr().err


def test_partial_views_through_calibration_and_hold_out():
    """Corners missing at random (25 %): calibrate and evaluate, fitted and held out, stay near
    the floor that the true calibration gives on the same corners."""
    truth = make_truth("stereo", views=8, seed=0)
    noisy = noisy_corner_set(truth, 0.15, seed=1)
    rng = np.random.default_rng(2)
    for cam in noisy.cameras.values():
        for uv in cam.views.values():
            uv[rng.random(len(uv)) < 0.25] = np.nan
    floor = evaluate(truth_rig_model(truth, noisy))
    rig = calibrate_rig(noisy)
    _assert_within_floor(evaluate(rig), floor)
    _assert_within_floor(evaluate(rig, holdout=True, progress=False), floor)


def test_nothing_to_intersect_raises():
    truth = make_truth("stereo", views=1, seed=0)
    rig = truth_rig_model(truth)
    rig.camera_poses["right"] = {}
    with pytest.raises(EstimationError, match="nothing to intersect"):
        evaluate(rig)


def test_a_pair_without_base_is_left_out_with_a_warning(capsys):
    truth = make_truth("stereo", views=3, seed=0)
    rig = truth_rig_model(truth)
    left = rig.corners.cameras["left"].views
    left["IMG_02"] = left["IMG_01"].copy()                 # the same photo twice: parallel rays
    rig.camera_poses["left"]["IMG_02"] = rig.camera_poses["left"]["IMG_01"]
    doc = evaluate(rig)
    assert doc["cases"]["left"]["pairs"] == 2 and doc["cases"]["right"]["pairs"] == 3
    assert "left/IMG_01 + left/IMG_02 left out" in capsys.readouterr().err


def test_holdout_needs_a_calibration():
    with pytest.raises(InputError, match="rig mode"):
        evaluate(truth_rig_model(make_truth("stereo", views=4, seed=0)), holdout=True)


def test_a_camera_named_like_a_case_is_refused():
    rig = truth_rig_model(make_truth("triple", views=3, seed=0))
    for name in ("dual", "dual:x"):
        renamed = replace(rig, cameras={(name if c == "tele" else c): m for c, m in rig.cameras.items()})
        with pytest.raises(InputError, match=f"camera '{name}' takes the name of the evaluation case"):
            evaluate(renamed)


@pytest.mark.parametrize("options, expected", [
    (None, {"drop_outliers": True, "outlier_factor": 6.0, "board_shape": "auto"}),   # written before options were recorded
    ({"drop_outliers": False, "outlier_factor": 4.5, "board_shape": "flat"},
     {"drop_outliers": False, "outlier_factor": 4.5, "board_shape": "flat"}),
])
def test_holdout_folds_repeat_the_calibration(monkeypatch, options, expected):
    """Each fold gets the calibration's options and its photos minus the held-out view; photos it
    dropped are in no fold and in no resection. The folds return the exact truth here, so the
    resected photos intersect exactly unless a dropped photo (its board moved by 20 px) pulls them."""
    truth = make_truth("note8", views=5, seed=0)
    corners = noisy_corner_set(truth, 0.0)
    corners.cameras["tele"].views["IMG_03"] = corners.cameras["tele"].views["IMG_03"] + 20.0
    rig = replace(truth_rig_model(truth, corners), rig_mode="rigid", skew=False,
                  adjustment={} if options is None else {"options": options},
                  dropped_views=[{"camera": "tele", "view": "IMG_03", "rms_px": 28.3, "reason": "moved board"}])
    del rig.camera_poses["tele"]["IMG_03"]
    folds = []

    def fold(fold_corners, **kwargs):
        folds.append(({(c, v) for c, cc in fold_corners.cameras.items() for v in cc.found()}, kwargs))
        return truth_rig_model(truth)

    monkeypatch.setattr("dualcal.estimation.calibrate.calibrate_rig", fold)
    doc = evaluate(rig, holdout=True, progress=False)
    views = sorted(truth.view_poses)
    assert len(folds) == len(views)
    for held_out, (photos, kwargs) in zip(views, folds):
        assert kwargs == {"skew": False, "rig_mode": "rigid", "reference": "wide", "model": "k1k2", **expected}
        assert photos == {(c, v) for c in ("wide", "tele") for v in views if v != held_out} - {("tele", "IMG_03")}
    assert doc["cases"]["dual"]["pairs"] == 4 and doc["cases"]["tele"]["pairs"] == 6
    assert doc["cases"]["wide"]["pairs"] == 10 and max(doc["cases"]["wide"]["rmse_mm"]) < 1e-6


# ---------------------------------------------------------------------------- against the floor


def _floor_and_calibration(preset: str, views: int, noise_px: float):
    truth = make_truth(preset, views=views, seed=0)
    noisy = noisy_corner_set(truth, noise_px, seed=1)
    floor = evaluate(truth_rig_model(truth, noisy))
    return floor, noisy


def _assert_within_floor(doc, floor, factor=FLOOR_FACTOR):
    assert list(doc["cases"]) == list(floor["cases"])
    for name, case in doc["cases"].items():
        assert case["pairs"] == floor["cases"][name]["pairs"]
        assert np.all(np.array(case["rmse_mm"]) <= factor * np.array(floor["cases"][name]["rmse_mm"])), name


@pytest.mark.parametrize("preset,noise_px", [("note8", 0.3), ("stereo", 0.15)])
def test_calibrated_rig_is_within_the_floor(preset, noise_px):
    floor, noisy = _floor_and_calibration(preset, 13, noise_px)
    _assert_within_floor(evaluate(calibrate_rig(noisy)), floor)


@pytest.mark.parametrize("preset,noise_px", [("note8", 0.3), ("stereo", 0.15)])
def test_holdout_is_within_the_floor(preset, noise_px):
    floor, noisy = _floor_and_calibration(preset, 8, noise_px)
    doc = evaluate(calibrate_rig(noisy), holdout=True, progress=False)
    assert doc["holdout"] is True
    _assert_within_floor(doc, floor)


def test_holdout_names_the_fold_that_cannot_be_calibrated():
    truth = make_truth("stereo", views=3, seed=0)
    rig = calibrate_rig(noisy_corner_set(truth, 0.1, seed=1))
    with pytest.raises(EstimationError, match="without view 'IMG_01' failed: .*at least 3"):
        evaluate(rig, holdout=True, progress=False)


def test_holdout_without_a_rig_resects_each_camera_alone():
    """Rig mode ``none``: each camera is calibrated and resected on its own, so only the
    single-camera cases can reach the floor; the dual case still has all its pairs."""
    floor, noisy = _floor_and_calibration("note8", 8, 0.3)
    doc = evaluate(calibrate_rig(noisy, rig_mode="none"), holdout=True, progress=False)
    assert doc["cases"]["dual"]["pairs"] == 8
    del doc["cases"]["dual"], floor["cases"]["dual"]
    _assert_within_floor(doc, floor)


# ---------------------------------------------------------------------------- the command



# ---------------------------------------------------------------------------- the pose-free length check


def test_pose_free_check_is_exact_on_exact_corners_and_counts_every_length():
    truth = make_truth("triple", views=3, seed=0)
    doc = pose_free_check(truth_rig_model(truth))
    assert list(doc["pose_free"]) == ["dual", "dual:ultra"]
    n = truth.board.n_corners
    for case in doc["pose_free"].values():
        assert case["rms_mm"] < 1e-6 and case["max_mm"] < 1e-6
        assert case["lengths"] == 3 * n * (n - 1) // 2 and case["instants"] == 3
    assert [(e["case"], e["cameras"], e["view"]) for e in doc["pose_free_per_instant"]][:2] == [
        ("dual", ["wide", "tele"], "IMG_01"), ("dual", ["wide", "tele"], "IMG_02")]


def test_pose_free_lengths_use_the_corners_both_photos_measured():
    truth = make_truth("note8", views=1, seed=0)
    rig = truth_rig_model(truth, noisy_corner_set(truth, 0.0))
    uv = true_corners(truth)
    wide, tele = uv["wide"]["IMG_01"].copy(), uv["tele"]["IMG_01"].copy()
    wide[[0, 5]], tele[[7]] = np.nan, np.nan
    err = corner_length_errors(rig, "tele", wide, tele, rig.board_points_mm())
    assert len(err) == 37 * 36 // 2 and np.abs(err).max() < 1e-6
    tele[2:] = np.nan
    with pytest.raises(EstimationError, match="1 corner"):
        corner_length_errors(rig, "tele", wide, tele, rig.board_points_mm())


def _paper_tables(rig):
    """The paper's Tables 5/6: every photo oriented alone on the corners it then checks (space resection)."""
    alone, used = replace(rig, rig_mode="none"), rig.used_corners()
    photos = {c: {} for c in rig.cameras}
    for view in rig.reference_poses():
        for cam, photo in resect_view(alone, view, used).items():
            photos[cam][view] = photo
    cases = stereo_cases(rig.board_points_mm(), photos, rig.reference)["cases"]
    return {name: float(np.linalg.norm(case["rmse_mm"])) for name, case in cases.items()}


def test_pose_free_check_catches_a_focal_length_1_percent_off_where_tables_5_6_barely_move(tmp_path):
    """The tele's fx, fy scaled by 1.01 in calib.json: the paper's Tables 5/6 (each photo oriented on its own
    corners) move by under 3 %, the pose-free check's RMS length error grows more than 4-fold."""
    truth = make_truth("note8", views=8, seed=0)
    rig = calibrate_rig(noisy_corner_set(truth, 0.3, seed=0))
    save_rig(tmp_path / "calib.json", rig)
    doc = json.loads((tmp_path / "calib.json").read_text())
    for key in ("fx", "fy"):
        doc["cameras"]["tele"][key] *= 1.01
    (tmp_path / "off.json").write_text(json.dumps(doc))
    from dualcal.files.io import load_rig
    off = load_rig(tmp_path / "off.json")
    before, after = _paper_tables(rig), _paper_tables(off)
    assert list(before) == ["dual", "wide", "tele"]
    for name in before:
        assert after[name] == pytest.approx(before[name], rel=0.03), name
    rms_before = pose_free_check(rig)["pose_free"]["dual"]["rms_mm"]
    rms_after = pose_free_check(off)["pose_free"]["dual"]["rms_mm"]
    assert rms_after > 4 * rms_before, (rms_before, rms_after)


def test_evaluate_command(tmp_path, run_cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")            # rich wraps nothing: one row per case
    truth = make_truth("note8", views=4, seed=0)
    save_rig(tmp_path / "calib.json", truth_rig_model(truth, noisy_corner_set(truth, 0.2, seed=0)))
    res = run_cli("evaluate", tmp_path / "calib.json", "-o", tmp_path / "eval.json")
    assert res.code == 0, res.err
    doc = load_evaluation(tmp_path / "eval.json")
    tables, pose_free = res.out.split("Pose-free length check")
    rows = [line for line in tables.splitlines() if line.startswith("│")]
    assert [r.split("│")[1].strip() for r in rows] == ["dual", "wide", "tele"]
    for row, case in zip(rows, doc["cases"].values()):
        assert [float(x) for x in row.split("│")[3:6]] == pytest.approx(case["rmse_mm"], abs=6e-4)
    rows = [line.split("│")[1:-1] for line in pose_free.splitlines() if line.startswith("│")]
    assert [r[0].strip() for r in rows] == ["dual"]
    case = doc["pose_free"]["dual"]
    assert [float(x) for x in rows[0][1:3]] == pytest.approx([case["rms_mm"], case["max_mm"]], abs=6e-4)
    assert int(rows[0][3]) == case["lengths"] == 4 * 40 * 39 // 2 and int(rows[0][4]) == case["instants"] == 4


def test_evaluate_command_errors(tmp_path, run_cli):
    res = run_cli("evaluate", tmp_path / "missing.json", "-o", tmp_path / "eval.json")
    assert res.code == 2 and "missing.json: no such file" in res.err
    save_rig(tmp_path / "calib.json", truth_rig_model(make_truth("stereo", views=3, seed=0)))
    res = run_cli("evaluate", tmp_path / "calib.json", "-o", tmp_path / "no" / "eval.json")
    assert res.code == 2 and "does not exist" in res.err
    res = run_cli("evaluate", tmp_path / "calib.json", "-o", tmp_path / "eval.json", "--holdout")
    assert res.code == 2 and "rig mode" in res.err
    assert not (tmp_path / "eval.json").exists()
