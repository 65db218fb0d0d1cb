"""End-to-end calibration against synthetic truth: recovery, honest sigmas, outlier photos.

Tolerances: with exact corners every mode recovers the truth to numerical precision; with
noise, errors must stay within 4 reported sigmas (and sigmas must be honest: the Monte Carlo
tests check that error / sigma has a spread between 0.8 and 1.25).
"""

import dataclasses
import json

import cv2
import numpy as np
import pytest

from dualcal.geometry.board import sag_mm, shaped_points_mm
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import INTRINSIC_NAMES, project_points
from dualcal.errors import EstimationError, InputError
from dualcal.geometry.model import CameraCorners, CornerSet, Pose
from dualcal.geometry.rotation import rotation_from_rotvec
from dualcal.synthetic.synth import make_truth, noisy_corner_set


def _intrinsic_errors(rig, truth):
    return {name: rig.cameras[name].as_vector() - truth.cameras[name].as_vector() for name in truth.cameras}


@pytest.mark.parametrize("preset,mode,skew", [(p, m, k) for p in ("note8", "stereo", "triple")
                                               for m in ("rigid", "paper", "none") for k in (False, True)])
def test_exact_corners_give_the_exact_rig(preset, mode, skew):
    truth = make_truth(preset, 10, seed=11)
    rig = calibrate_rig(noisy_corner_set(truth, 0.0), skew=skew, rig_mode=mode)
    for name, err in _intrinsic_errors(rig, truth).items():
        tolerance = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-7, 1e-6, 1e-7, 1e-7, 1e-6, 1e-6])   # ..., p1, p2, k3, k4
        scale = tolerance * np.maximum(1, np.abs(truth.cameras[name].as_vector()))
        assert np.all(np.abs(err) < scale), (name, err)
    for name, rel in rig.rig.items():
        np.testing.assert_allclose(rel.pose.t_mm, truth.rig[name].t_mm, atol=1e-5)
        np.testing.assert_allclose(rel.pose.R, truth.rig[name].R, atol=1e-8)
    assert rig.rms_px < 1e-6
    assert not rig.dropped_views


@pytest.mark.parametrize("preset,mode", [("note8", "rigid"), ("note8", "paper"), ("stereo", "rigid"),
                                         ("stereo", "none"), ("triple", "rigid")])
def test_noisy_corners_recover_truth_within_4_sigma(preset, mode):
    truth = make_truth(preset, 13, seed=7)
    rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=8), rig_mode=mode)
    for name, err in _intrinsic_errors(rig, truth).items():
        sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
        free = sig > 0
        assert np.all(np.abs(err[free]) < 4 * sig[free]), (name, err, sig)
        assert abs(err[0]) < 0.005 * truth.cameras[name].fx          # focal length within 0.5 %
    for name, rel in rig.rig.items():
        true = truth.rig[name]
        assert abs(rel.baseline_mm - np.linalg.norm(true.t_mm)) < 4 * rel.sigma_baseline_mm
        assert np.all(np.abs(rel.pose.opk_arcmin - true.opk_arcmin) < 4 * rel.sigma_opk_arcmin)
    assert rig.adjustment["s0_px"] == pytest.approx(0.2, rel=0.1)


_CATEGORY = {"fx": "focal length", "fy": "focal length", "cx": "principal point", "cy": "principal point",
             "k1": "k1", "k2": "k2"}


def _add_z(z, rig, truth):
    """Append error / sigma of every parameter of ``rig`` to ``z[which][kind]``, for ``which`` of
    ``sigma`` (calib.json's) and ``sigma_formal``."""
    for name, cam in rig.cameras.items():
        for p, kind in _CATEGORY.items():
            err = getattr(cam, p) - getattr(truth.cameras[name], p)
            z["sigma"].setdefault(kind, []).append(err / rig.camera_sigma[name][p])
            z["sigma_formal"].setdefault(kind, []).append(err / rig.camera_sigma_formal[name][p])
    for name, rel in rig.rig.items():
        true, formal = truth.rig[name], rel.sigma_formal
        err_D = rel.baseline_mm - np.linalg.norm(true.t_mm)
        err_opk = rel.pose.opk_arcmin - true.opk_arcmin
        z["sigma"].setdefault("baseline", []).append(err_D / rel.sigma_baseline_mm)
        z["sigma_formal"].setdefault("baseline", []).append(err_D / formal["baseline_mm"])
        z["sigma"].setdefault("angles", []).extend(err_opk / rel.sigma_opk_arcmin)
        z["sigma_formal"].setdefault("angles", []).extend(err_opk / formal["opk_arcmin"])


def _spreads(z):
    return {which: {k: float(np.std(v, ddof=1)) for k, v in kinds.items()} for which, kinds in z.items()}


def _z_spreads(preset, mode, skew, draws, noise_px=0.2):
    """Spread (standard deviation) of error / sigma over noise draws, per kind of parameter, for
    ``sigma`` and ``sigma_formal``."""
    truth = make_truth(preset, 13, seed=5)
    z = {"sigma": {}, "sigma_formal": {}}
    for k in range(draws):
        rig = calibrate_rig(noisy_corner_set(truth, noise_px, seed=100 + k), skew=skew, rig_mode=mode,
                            drop_outliers=False)
        _add_z(z, rig, truth)
    return _spreads(z)


@pytest.mark.parametrize("preset,mode,skew,draws", [("note8", "rigid", False, 60), ("note8", "paper", False, 30),
                                                    ("stereo", "none", True, 30)])
def test_monte_carlo_sigmas_are_honest(preset, mode, skew, draws):
    """White corner noise: both calib.json's sigma and the textbook sigma_formal are honest."""
    for which, spreads in _z_spreads(preset, mode, skew, draws).items():
        assert set(spreads) == {"focal length", "principal point", "k1", "k2", "baseline", "angles"}
        bad = {k: round(v, 2) for k, v in spreads.items() if not 0.8 <= v <= 1.25}
        assert not bad, f"{which}: spread of error/sigma outside [0.8, 1.25]: {bad}"


def test_sigma_holds_where_the_errors_of_a_photo_are_correlated():
    """Each photo seen through its own slightly different camera (focal length +-0.03 %, principal
    point +-0.4 px, k1 +-0.002: refocus, a lens that shifts, what a model lacks) on top of 0.1 px
    white noise: the errors within a photo are correlated. 40 draws of a 13-instant stereo rig:
    calib.json's sigma stays honest (spread 0.75-1.3) while the textbook sigma_formal is too small
    (spread above 1.5 for every kind)."""
    truth = make_truth("stereo", 13, seed=5)
    X = truth.board.object_points_mm()
    z = {"sigma": {}, "sigma_formal": {}}
    for k in range(40):
        rng = np.random.default_rng(500 + k)
        cams = {}
        for name, cam in truth.cameras.items():
            views = {}
            for v in truth.view_poses:
                scale = 1 + rng.normal(0, 3e-4)
                photo_cam = dataclasses.replace(cam, fx=cam.fx * scale, fy=cam.fy * scale, cx=cam.cx + rng.normal(0, 0.4),
                                                cy=cam.cy + rng.normal(0, 0.4), k1=cam.k1 + rng.normal(0, 0.002))
                views[v] = project_points(photo_cam, truth.camera_pose(name, v).apply(X)) + rng.normal(0, 0.1, X[:, :2].shape)
            cams[name] = CameraCorners(cam.image_size, views)
        _add_z(z, calibrate_rig(CornerSet(truth.board, cams), drop_outliers=False, board_shape="flat"), truth)
    spreads = _spreads(z)
    honest = {k: round(v, 2) for k, v in spreads["sigma"].items() if not 0.75 <= v <= 1.3}
    assert not honest, f"sigma: spread of error/sigma outside [0.75, 1.3]: {honest}"
    optimistic = {k: round(v, 2) for k, v in spreads["sigma_formal"].items() if not v > 1.5}
    assert not optimistic, f"sigma_formal should be too small here: {optimistic}"


def test_a_bent_board_is_found_and_costs_little():
    """A board bent by about 1 mm (sag, bend and twist): its shape is estimated (auto), the sag
    recovered within 20 % in every draw, and the errors of the intrinsics and the rig stay within
    1.3 x those of the same rig with a flat board (RMS over 10 draws with the same noise)."""
    truth = make_truth("note8", 13, seed=5)
    X = truth.board.object_points_mm()
    shape = np.array([0.9, -0.6, 0.6])
    bent = shaped_points_mm(X, shape)
    true_sag = sag_mm(X, shape)
    assert 0.8 < true_sag < 1.5
    err = {"flat": [], "bent": []}
    for k in range(10):
        rng = np.random.default_rng(700 + k)
        noise = {n: {v: rng.normal(0, 0.2, X[:, :2].shape) for v in truth.view_poses} for n in truth.cameras}
        for which, points in (("flat", X), ("bent", bent)):
            cams = {n: CameraCorners(cam.image_size, {v: project_points(cam, truth.camera_pose(n, v).apply(points))
                                                      + noise[n][v] for v in truth.view_poses})
                    for n, cam in truth.cameras.items()}
            rig = calibrate_rig(CornerSet(truth.board, cams))
            if which == "bent":
                assert rig.board_shape_mm is not None
                assert abs(sag_mm(X, rig.board_shape_mm) - true_sag) < 0.2 * true_sag
            intr = np.concatenate([(rig.cameras[n].as_vector() - truth.cameras[n].as_vector())[[0, 1, 3, 4, 5, 6]]
                                   / np.array([1, 1, 1, 1, 1e-3, 1e-2]) for n in sorted(truth.cameras)])
            rel = rig.rig["tele"]
            err[which].append(np.concatenate([intr, [rel.baseline_mm - np.linalg.norm(truth.rig["tele"].t_mm)],
                                              rel.pose.opk_arcmin - truth.rig["tele"].opk_arcmin]))
    rms = {w: np.sqrt(np.mean(np.square(e), axis=0)) for w, e in err.items()}
    ratio = rms["bent"] / rms["flat"]
    assert np.all(ratio < 1.3), np.round(ratio, 2)


def test_the_shape_test_at_the_one_step_estimate_is_that_of_the_adjusted_shape():
    """The board-shape test is made first at the one-step (linearised) estimate from the flat board's
    solution; the shape is adjusted in full only where that T^2 exceeds half its limit
    (``board_shape.SHAPE_FULL_TEST``). On boards bent from not at all to twice what the photos show (13 note8
    instants, 0.2 px), the one-step T^2 is within 3 % of the adjusted shape's, so that no decision can differ
    (it would take a factor of 2), and calibrate_rig decides as the full test does."""
    from dualcal.estimation.board_shape import board_shape_test
    from dualcal.estimation.fitting import Setup, usable_photos

    truth = make_truth("note8", 13, seed=5)
    X = truth.board.object_points_mm()
    rng = np.random.default_rng(41)
    decisions = set()
    for scale in (0.0, 0.04, 0.08, 0.3):
        points = shaped_points_mm(X, scale * np.array([0.9, -0.6, 0.6]))
        cams = {n: CameraCorners(cam.image_size, {v: project_points(cam, truth.camera_pose(n, v).apply(points))
                                                  + rng.normal(0, 0.2, X[:, :2].shape) for v in truth.view_poses})
                for n, cam in truth.cameras.items()}
        corners = CornerSet(truth.board, cams)
        names = sorted(cams)
        setup = Setup(X, names, [cams[n].image_size for n in names], names.index("wide"), False, "rigid",
                      ("k1k2", "k1k2"))
        blocks = usable_photos(corners, names, X[:, :2])
        flat = setup.solve(blocks, setup.solve(blocks, mode="none"))
        one_step = board_shape_test(setup.linearised(flat, board_shape=True), one_step=True)
        full = board_shape_test(setup.solve(blocks, flat, board_shape=True))
        assert one_step["t2"] == pytest.approx(full["t2"], rel=0.03), scale
        rig = calibrate_rig(corners, model="k1k2", drop_outliers=False)
        test = rig.adjustment["board_shape_test"]
        assert test["significant"] == full["significant"], scale
        assert test["estimate"] == ("adjusted" if one_step["t2"] > 0.5 * one_step["limit"] else "one-step")
        decisions.add(full["significant"])
    assert decisions == {False, True}


@pytest.mark.parametrize("mode", ["rigid", "paper", "none"])
def test_exact_corners_give_the_exact_lens_of_every_coefficient(mode):
    """OpenCV's five-coefficient lens (synth preset stereo5: k3 = 0.238, p1 = 0.0018 on the left)
    comes back exactly: corners to 1e-6 px, every coefficient to 1e-8 (where the corners fit to 1e-11 px, the
    adjustment's last step is that far from zero: where it stops there depends on its start)."""
    truth = make_truth("stereo5", 10, seed=11)
    rig = calibrate_rig(noisy_corner_set(truth, 0.0), rig_mode=mode, model="k1k2p1p2k3")
    assert rig.model == "k1k2p1p2k3" and rig.rms_px < 1e-6
    for name, cam in rig.cameras.items():
        true = truth.cameras[name]
        np.testing.assert_allclose(cam.distortion, true.distortion, rtol=0, atol=1e-8)
        np.testing.assert_allclose(cam.as_vector()[:5], true.as_vector()[:5], rtol=1e-8, atol=1e-6)
    for name, rel in rig.rig.items():
        np.testing.assert_allclose(rel.pose.t_mm, truth.rig[name].t_mm, atol=1e-6)


def test_noisy_corners_recover_a_tangential_lens_within_4_sigma():
    truth = make_truth("stereo5", 13, seed=7)
    rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=8), model="k1k2p1p2k3")
    for name, err in _intrinsic_errors(rig, truth).items():
        sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
        free = sig > 0
        assert free.sum() == 9                          # all but skew
        assert np.all(np.abs(err[free]) < 4 * sig[free]), (name, err, sig)
    assert rig.adjustment["s0_px"] == pytest.approx(0.2, rel=0.1)


def test_monte_carlo_sigmas_of_the_tangential_terms_are_honest():
    """30 noise draws on stereo5 in OpenCV's model: error / sigma of p1, p2 (and k3) spreads by 0.8-1.25."""
    truth = make_truth("stereo5", 13, seed=5)
    z = {"p1": [], "p2": [], "k3": []}
    for k in range(30):
        rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=300 + k), model="k1k2p1p2k3", drop_outliers=False)
        for name, cam in rig.cameras.items():
            for p in z:
                z[p].append((getattr(cam, p) - getattr(truth.cameras[name], p)) / rig.camera_sigma[name][p])
    spreads = {p: round(float(np.std(v, ddof=1)), 2) for p, v in z.items()}
    assert all(0.8 <= s <= 1.25 for s in spreads.values()), spreads


def test_an_unknown_lens_model_is_an_input_error():
    with pytest.raises(InputError, match="lens model .fisheye. is unknown \\(choose from k1k2, k1k2k3, k1k2p1p2"):
        calibrate_rig(noisy_corner_set(make_truth("stereo", 4, seed=0), 0.0), model="fisheye")


def _plant(corners, truth, camera, view, uv):
    corners.cameras[camera].views[view] = uv
    return corners


@pytest.mark.parametrize("kind", ["shuffled", "focal+3%"])
def test_a_planted_bad_photo_is_dropped_and_the_result_unharmed(kind):
    truth = make_truth("note8", 13, seed=1)
    clean = calibrate_rig(noisy_corner_set(truth, 0.1, seed=2))
    corners = noisy_corner_set(truth, 0.1, seed=2)
    view = "IMG_05"
    if kind == "shuffled":
        cam = "wide"
        uv = corners.cameras[cam].views[view][np.random.default_rng(3).permutation(40)]
    else:
        cam = "tele"
        t = truth.cameras[cam]
        zoomed = dataclasses.replace(t, fx=1.03 * t.fx, fy=1.03 * t.fy)
        uv = project_points(zoomed, truth.camera_pose(cam, view).apply(truth.board.object_points_mm()))
    rig = calibrate_rig(_plant(corners, truth, cam, view, uv))
    assert [(d["camera"], d["view"]) for d in rig.dropped_views] == [(cam, view)]
    assert "RMS" in rig.dropped_views[0]["reason"]
    for name in truth.cameras:
        err = rig.cameras[name].as_vector() - truth.cameras[name].as_vector()
        sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
        clean_err = clean.cameras[name].as_vector() - truth.cameras[name].as_vector()
        free = sig > 0
        assert np.all(np.abs(err[free]) < 4 * sig[free])
        assert np.all(np.abs(err[free]) <= np.abs(clean_err[free]) + 1.5 * sig[free])


def test_keep_outliers_keeps_every_photo():
    """A board moved by 25 px between the shots of one instant: kept, and it shows in the RMS."""
    truth = make_truth("note8", 8, seed=1)
    corners = noisy_corner_set(truth, 0.1, seed=2)
    corners.cameras["tele"].views["IMG_03"] += [25.0, -15.0]
    rig = calibrate_rig(corners, drop_outliers=False)
    assert not rig.dropped_views and rig.view_rms_px["IMG_03"]["tele"] > 3 and rig.rms_px > 1


def test_fewer_than_three_views_is_a_clear_error():
    truth = make_truth("note8", 5, seed=1)
    corners = noisy_corner_set(truth, 0.1)
    for v in ("IMG_01", "IMG_02", "IMG_03"):
        corners.cameras["tele"].views[v] = None
    with pytest.raises(EstimationError, match="'tele' has 2 usable view"):
        calibrate_rig(corners)


def test_cameras_without_a_shared_instant_cannot_form_a_rig():
    truth = make_truth("stereo", 8, seed=1)
    corners = noisy_corner_set(truth, 0.1)
    for i, v in enumerate(sorted(corners.cameras["left"].views)):
        corners.cameras["left" if i % 2 else "right"].views[v] = None
    with pytest.raises(EstimationError, match="shares no view"):
        calibrate_rig(corners)
    rig = calibrate_rig(corners, rig_mode="none")
    assert rig.rig == {}                   # each camera alone still calibrates
    for name, cam in rig.cameras.items():
        assert abs(cam.fx - truth.cameras[name].fx) < 4 * rig.camera_sigma[name]["fx"]


def test_reference_camera_and_poses():
    truth = make_truth("triple", 6, seed=2)
    rig = calibrate_rig(noisy_corner_set(truth, 0.0), reference="tele")
    assert rig.reference == "tele" and set(rig.rig) == {"wide", "ultra"}
    expected = truth.rig["tele"].inverse()                 # tele -> wide
    np.testing.assert_allclose(rig.rig["wide"].pose.t_mm, expected.t_mm, atol=1e-5)
    for view, pose in rig.reference_poses().items():
        np.testing.assert_allclose(pose.t_mm, truth.camera_pose("tele", view).t_mm, atol=1e-5)


def test_paper_mode_holds_one_baseline_even_with_few_noisy_views():
    """The paper's model holds D exactly equal in every instant: with few noisy views its D stays
    with the truth (the constrained solver it replaced reported 12.95 mm here, with |t| between
    11.5 and 13.1 mm across the views it claimed equal)."""
    truth = make_truth("note8", 8, seed=0)
    corners = noisy_corner_set(truth, 0.3, seed=1)
    for cam in corners.cameras.values():
        del cam.views["IMG_05"]
    rel = calibrate_rig(corners, rig_mode="paper").rig["tele"]
    assert abs(rel.baseline_mm - np.linalg.norm(truth.rig["tele"].t_mm)) < 3 * rel.sigma_baseline_mm


def test_paper_mode_fits_a_baseline_whose_direction_moves_between_instants():
    """A tele whose centre moves on a sphere around the wide's between shots (its baseline turned
    by 15 degrees, differently in each instant, its length kept) is the paper's model exactly:
    it recovers D and fits to the noise, where the rigid model cannot."""
    truth = make_truth("note8", 13, seed=2)
    corners = noisy_corner_set(truth, 0.1, seed=3)
    rng = np.random.default_rng(4)
    X = truth.board.object_points_mm()
    t = truth.rig["tele"].t_mm
    for v, ref_pose in truth.view_poses.items():
        axis = np.cross(t, rng.normal(size=3))
        turned = rotation_from_rotvec(np.radians(15.0) * axis / np.linalg.norm(axis)) @ t
        moved = Pose(truth.rig["tele"].R, turned).compose(ref_pose)
        corners.cameras["tele"].views[v] += project_points(truth.cameras["tele"], moved.apply(X)) \
            - project_points(truth.cameras["tele"], truth.camera_pose("tele", v).apply(X))
    paper = calibrate_rig(corners, rig_mode="paper", drop_outliers=False)
    rigid = calibrate_rig(corners, rig_mode="rigid", drop_outliers=False)
    rel = paper.rig["tele"]
    assert abs(rel.baseline_mm - np.linalg.norm(t)) < 4 * rel.sigma_baseline_mm
    assert paper.adjustment["s0_px"] == pytest.approx(0.1, rel=0.1)
    assert rigid.adjustment["s0_px"] > 10 * paper.adjustment["s0_px"]


def test_a_noisier_camera_keeps_its_photos():
    """Outliers are judged against each photo's own noise: a camera whose corners are simply
    noisier (here 4x) is not an outlier."""
    truth = make_truth("triple", 13, seed=3)
    corners = noisy_corner_set(truth, 0.1, seed=4)
    rng = np.random.default_rng(5)
    for v, uv in corners.cameras["ultra"].views.items():
        corners.cameras["ultra"].views[v] = uv + rng.normal(0, 0.4, uv.shape)
    rig = calibrate_rig(corners)
    assert rig.dropped_views == []
    assert len(rig.dropped_corners) == 0                     # of 1560: the limit is ~7 sigma of each camera
    assert rig.adjustment["options"] == {"drop_outliers": True, "outlier_factor": 6.0, "board_shape": "auto",
                                         "model": "k1k2", "weigh_photos": True}


def _partial_views(corners, rng, missing=0.3, tele_window=0.25):
    """Take a share ``missing`` of every photo's corners out (NaN), and let the tele see only the
    corners inside the central ``tele_window`` of its image (a narrower field of view)."""
    for name, cc in corners.cameras.items():
        w, h = cc.image_size
        lo, hi = (1 - tele_window) / 2, (1 + tele_window) / 2
        for uv in cc.views.values():
            uv[rng.random(len(uv)) < missing] = np.nan
            if name == "tele":
                outside = (uv[:, 0] < lo * w) | (uv[:, 0] > hi * w) | (uv[:, 1] < lo * h) | (uv[:, 1] > hi * h)
                uv[outside] = np.nan
    return corners


@pytest.mark.parametrize("mode", ["rigid", "paper", "none"])
def test_partial_views_recover_the_truth_within_the_sigmas(mode):
    """30 % of the corners of every photo missing at random, and a tele that sees only the middle
    quarter of its frame's width and height (about half the board): every parameter within 4 sigma of the
    truth in every draw, and error / sigma spread like a unit normal (0.75-1.3 over the draws)."""
    truth = make_truth("note8", 13, seed=9)
    rng = np.random.default_rng(10)
    z, seen = [], []
    for k in range(8):
        corners = _partial_views(noisy_corner_set(truth, 0.2, seed=300 + k), rng)
        seen.append(np.mean([np.isfinite(uv[:, 0]).mean() for uv in corners.cameras["tele"].views.values()]))
        rig = calibrate_rig(corners, rig_mode=mode, drop_outliers=False)
        for name, err in _intrinsic_errors(rig, truth).items():
            sig = np.array([rig.camera_sigma[name][p] for p in INTRINSIC_NAMES])
            free = sig > 0
            assert np.all(np.abs(err[free]) < 4 * sig[free]), (name, err, sig)
            z.extend(err[free] / sig[free])
        for name, rel in rig.rig.items():
            true = truth.rig[name]
            z.append((rel.baseline_mm - np.linalg.norm(true.t_mm)) / rel.sigma_baseline_mm)
            z.extend((rel.pose.opk_arcmin - true.opk_arcmin) / rel.sigma_opk_arcmin)
            assert np.all(np.abs(z[-4:]) < 4)
    assert 0.2 < np.mean(seen) < 0.5                     # the tele measured a third of its corners
    assert 0.75 <= np.std(z, ddof=1) <= 1.3


def test_photos_with_too_few_corners_are_skipped_naming_them(capsys):
    truth = make_truth("note8", 6, seed=3)
    corners = noisy_corner_set(truth, 0.1, seed=4)
    corners.cameras["tele"].views["IMG_02"][3:] = np.nan                 # 3 corners left
    corners.cameras["wide"].views["IMG_04"][8:] = np.nan                 # the first row only: one line
    rig = calibrate_rig(corners)
    err = capsys.readouterr().err
    assert "tele/IMG_02 skipped: its 3 measured corner(s) are too few" in err
    assert "wide/IMG_04 skipped: its 8 measured corner(s) lie on one line" in err
    assert "IMG_02" not in rig.camera_poses["tele"] and "IMG_04" not in rig.camera_poses["wide"]
    assert "IMG_04" in rig.camera_poses["tele"] and set(rig.reference_poses()) == set(truth.view_poses)


def test_rms_and_redundancy_count_only_measured_corners():
    truth = make_truth("stereo", 6, seed=5)
    corners = noisy_corner_set(truth, 0.2, seed=6)
    corners.cameras["right"].views["IMG_03"][:20] = np.nan
    rig = calibrate_rig(corners, drop_outliers=False)
    n_obs = 2 * (2 * 6 * 54 - 20)
    assert rig.adjustment["n_observations"] == n_obs
    assert rig.adjustment["redundancy"] == n_obs - rig.adjustment["n_parameters"]
    assert rig.adjustment["converged"] is True and rig.adjustment["termination"]
    assert all(np.isfinite(r) for v in rig.view_rms_px.values() for r in v.values())
    assert rig.rms_px == pytest.approx(0.2 * np.sqrt(2), rel=0.15)


@pytest.mark.not_converged
def test_a_solve_that_does_not_converge_says_so(tmp_path, run_cli, monkeypatch):
    """An adjustment cut at 2 iterations: calib.json records converged false and why, and the
    command warns (exit code 0: the result is written, but marked)."""
    from dualcal.estimation import adjust as adjust_module
    from dualcal.files.io import save_corners
    from dualcal.estimation.lm import LMOptions

    def two_iterations(problem, state, options=None):
        return adjust_module.adjust(problem, state, LMOptions(max_iter=2))
    monkeypatch.setattr("dualcal.estimation.fitting.adjust", two_iterations)
    save_corners(tmp_path / "corners.json", noisy_corner_set(make_truth("note8", 6, seed=3), 0.2, seed=4))
    res = run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "calib.json", "--no-compare-models",
                  "--keep-outliers")
    assert res.code == 0
    assert "the adjustment (rig mode rigid, Model 1) did not converge: iteration limit 2 reached" in res.err
    adjustment = json.loads((tmp_path / "calib.json").read_text())["adjustment"]
    assert adjustment["converged"] is False and adjustment["termination"].startswith("iteration limit 2 reached")
    assert adjustment["iterations"] == 2


# ----------------------------------------------------------------------------- the fisheye kb4


def _fisheye_pair(views=12, seed=5):
    """phone3's wide (its truth has k3, no tangential terms) and its fisheye ultra-wide (kb4)."""
    truth = make_truth("phone3", views, seed=seed)
    return dataclasses.replace(truth, cameras={n: truth.cameras[n] for n in ("wide", "ultra")},
                               rig={"ultra": truth.rig["ultra"]})


def test_a_fisheye_calibrates_as_cv2_fisheye_calibrate_does():
    """The same noisy corners of phone3's ultra-wide (145 degrees on the diagonal) through
    cv2.fisheye.calibrate and dualcal (kb4, one camera, flat board): the same camera, to 1e-3 of its
    sigma (both minimise the same pixel error; dualcal stops within 1e-3 sigma of the minimum, OpenCV is
    run to 1e-14), near the truth within 4 sigma."""
    truth = make_truth("phone3", 12, seed=3)
    corners = noisy_corner_set(truth, 0.1, seed=4)
    one = CornerSet(corners.board, {"ultra": corners.cameras["ultra"]})
    rig = calibrate_rig(one, model="kb4", board_shape="flat", drop_outliers=False)
    cam, sigma = rig.cameras["ultra"], rig.camera_sigma["ultra"]
    X = corners.board.object_points_mm().reshape(1, -1, 3)
    views = [uv for uv in one.cameras["ultra"].views.values() if uv is not None]
    rms, K, D, _, _ = cv2.fisheye.calibrate(
        [X] * len(views), [uv.reshape(1, -1, 2) for uv in views], cam.image_size,
        np.array([[1500.0, 0, 1511.5], [0, 1500.0, 2015.5], [0, 0, 1]]), np.zeros((4, 1)),
        flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-14))
    theirs = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"), (K[0, 0], K[1, 1], K[0, 2], K[1, 2], *D.ravel())))
    for p, value in theirs.items():
        assert abs(getattr(cam, p) - value) < 1e-3 * sigma[p], p
        assert abs(getattr(cam, p) - getattr(truth.cameras["ultra"], p)) < 4 * sigma[p], p
    assert rms == pytest.approx(rig.rms_px, rel=1e-6)                 # both of the 2-D residual per corner


@pytest.mark.slow
def test_monte_carlo_sigmas_of_a_fisheye_rig_are_honest():
    """16 noise draws of phone3's wide (k1k2k3) + fisheye ultra-wide (kb4), rigid rig, 0.05 px:
    error / sigma of the intrinsics (kb4's k1 .. k4 too) and of the rig spreads by 0.8-1.25
    (benchmarks/bench_fisheye_sigma.py runs more draws, and at 0.2 px, where kb4's four correlated
    coefficients are less linear)."""
    truth = _fisheye_pair()
    z = {}
    for k in range(16):
        rig = calibrate_rig(noisy_corner_set(truth, 0.05, seed=500 + k), model={"wide": "k1k2k3", "ultra": "kb4"},
                            drop_outliers=False, board_shape="flat")
        for name, cam in rig.cameras.items():
            for p in ("fx", "fy", "cx", "cy", *(("k1", "k2", "k3", "k4") if cam.fisheye else ("k1", "k2"))):
                kind = f"{'fisheye' if cam.fisheye else 'wide'} {p}"
                z.setdefault(kind, []).append((getattr(cam, p) - getattr(truth.cameras[name], p))
                                              / rig.camera_sigma[name][p])
        rel, true = rig.rig["ultra"], truth.rig["ultra"]
        z.setdefault("baseline", []).append((rel.baseline_mm - np.linalg.norm(true.t_mm)) / rel.sigma_baseline_mm)
        z.setdefault("angles", []).extend((rel.pose.opk_arcmin - true.opk_arcmin) / rel.sigma_opk_arcmin)
    pooled = {"intrinsics": [x for k, v in z.items() if k not in ("baseline", "angles") for x in v],
              "rig": z["baseline"] + z["angles"]}
    spreads = {k: round(float(np.std(v, ddof=1)), 2) for k, v in pooled.items()}
    assert all(0.8 <= s <= 1.25 for s in spreads.values()), spreads


# ----------------------------------------------------------------------------- refit


def test_a_refit_is_the_full_calibration_of_the_other_model():
    """Issue 23: comparing models by one adjustment from the calibration's values (``refit``) gives what a
    full calibration of that model on the same corners gives (outliers not looked for), to 1e-3 of a
    sigma: for a richer lens model, for the other skew model and for the cameras alone."""
    from dualcal.estimation.fitting import refit
    from dualcal.geometry.camera import intrinsic_names

    corners = noisy_corner_set(make_truth("note8", 10, seed=5), 0.15, seed=6)
    rig = calibrate_rig(corners, model="k1k2")
    for change in (dict(model="k1k2p1p2"), dict(skew=True), dict(rig_mode="none")):
        full = calibrate_rig(corners, **{"model": "k1k2", "drop_outliers": False, **change})
        sol = refit(rig, **change)
        assert sol.converged and sol.problem.mode == full.rig_mode and sol.problem.skew == full.skew
        for c, name in enumerate(sol.problem.cameras):
            cam, want, sigma = sol.state.camera(sol.problem, c), full.cameras[name], full.camera_sigma[name]
            assert cam.model == want.model
            for p in intrinsic_names(cam.model):
                if sigma[p] > 0:
                    assert abs(getattr(cam, p) - getattr(want, p)) < 1e-3 * sigma[p], (change, name, p)


def test_a_start_from_a_solution_needs_fewer_iterations_with_little_damping():
    """A 12 MP phone's normal matrix, scaled to a unit diagonal, has eigenvalues near 2e-6: the far
    start's damping of 1e-6 made every refit converge linearly. From a solution the damping starts at
    ``NEAR_START``'s 1e-9 (:mod:`dualcal.estimation.lm`): fewer iterations, to the same minimum."""
    from dualcal.estimation.fitting import refit
    from dualcal.estimation.lm import LMOptions

    corners = noisy_corner_set(make_truth("note8", 10, seed=5), 0.15, seed=6)
    rig = calibrate_rig(corners, model="k1k2")
    for change in (dict(model="k1k2p1p2"), dict(model="k1k2k3"), dict(skew=True), dict(rig_mode="none")):
        near, far = refit(rig, **change), refit(rig, **change, options=LMOptions())
        assert near.converged and near.iterations < far.iterations, change
        assert near.s0_px == pytest.approx(far.s0_px, rel=1e-9)
