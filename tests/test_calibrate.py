"""End-to-end calibration against synthetic truth: recovery, honest sigmas, outlier photos.

Tolerances: with exact corners every mode recovers the truth to numerical precision; with
noise, errors must stay within 4 reported sigmas (and sigmas must be honest: the Monte Carlo
tests check that error / sigma has a spread between 0.8 and 1.25).
"""

import dataclasses

import numpy as np
import pytest

from dualcal.calibrate import calibrate_rig
from dualcal.camera import INTRINSIC_NAMES, project_points
from dualcal.errors import EstimationError
from dualcal.synth import make_truth, noisy_corner_set


def _intrinsic_errors(rig, truth):
    return {name: rig.cameras[name].as_vector() - truth.cameras[name].as_vector() for name in truth.cameras}


@pytest.mark.parametrize("preset,mode,skew", [(p, m, k) for p in ("note8", "stereo", "triple")
                                               for m in ("rigid", "paper", "none") for k in (False, True)])
def test_exact_corners_give_the_exact_rig(preset, mode, skew):
    truth = make_truth(preset, 10, seed=11)
    rig = calibrate_rig(noisy_corner_set(truth, 0.0), skew=skew, rig_mode=mode)
    for name, err in _intrinsic_errors(rig, truth).items():
        scale = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-7, 1e-6]) * np.maximum(1, np.abs(truth.cameras[name].as_vector()))
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


def _z_spreads(preset, mode, skew, draws, noise_px=0.2):
    """Spread (standard deviation) of error / sigma over noise draws, per kind of parameter."""
    truth = make_truth(preset, 13, seed=5)
    z = {}
    for k in range(draws):
        rig = calibrate_rig(noisy_corner_set(truth, noise_px, seed=100 + k), skew=skew, rig_mode=mode,
                            drop_outliers=False)
        for name, cam in rig.cameras.items():
            for p, kind in _CATEGORY.items():
                err = getattr(cam, p) - getattr(truth.cameras[name], p)
                z.setdefault(kind, []).append(err / rig.camera_sigma[name][p])
        for name, rel in rig.rig.items():
            true = truth.rig[name]
            z.setdefault("baseline", []).append(
                (rel.baseline_mm - np.linalg.norm(true.t_mm)) / rel.sigma_baseline_mm)
            z.setdefault("angles", []).extend((rel.pose.opk_arcmin - true.opk_arcmin) / rel.sigma_opk_arcmin)
    return {k: float(np.std(v, ddof=1)) for k, v in z.items()}


@pytest.mark.parametrize("preset,mode,skew,draws", [("note8", "rigid", False, 60), ("note8", "paper", False, 30),
                                                    ("stereo", "none", True, 30)])
def test_monte_carlo_sigmas_are_honest(preset, mode, skew, draws):
    spreads = _z_spreads(preset, mode, skew, draws)
    assert set(spreads) == {"focal length", "principal point", "k1", "k2", "baseline", "angles"}
    bad = {k: round(v, 2) for k, v in spreads.items() if not 0.8 <= v <= 1.25}
    assert not bad, f"spread of error/sigma outside [0.8, 1.25]: {bad}"


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
    truth = make_truth("note8", 8, seed=1)
    corners = noisy_corner_set(truth, 0.1, seed=2)
    corners.cameras["wide"].views["IMG_03"] = corners.cameras["wide"].views["IMG_03"][::-1].copy()
    rig = calibrate_rig(corners, drop_outliers=False)
    assert not rig.dropped_views and rig.rms_px > 10


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


def test_paper_mode_warns_when_its_baseline_drifts_from_the_rigid_one(capsys):
    """The paper's constraints leave each view's baseline direction free: with few noisy views
    D can drift; dualcal says so rather than reporting it silently."""
    truth = make_truth("note8", 8, seed=0)
    corners = noisy_corner_set(truth, 0.3, seed=1)
    for cam in corners.cameras.values():
        del cam.views["IMG_05"]
    rig = calibrate_rig(corners, rig_mode="paper")
    err = capsys.readouterr().err
    drift = abs(rig.rig["tele"].baseline_mm - np.linalg.norm(truth.rig["tele"].t_mm))
    assert drift > 1.0 and "prefer --rig rigid" in err


def test_a_noisier_camera_keeps_its_photos():
    """Outliers are judged against each camera's own median: a camera whose corners are simply
    noisier (here 4x) is not an outlier."""
    truth = make_truth("triple", 13, seed=3)
    corners = noisy_corner_set(truth, 0.1, seed=4)
    rng = np.random.default_rng(5)
    for v, uv in corners.cameras["ultra"].views.items():
        corners.cameras["ultra"].views[v] = uv + rng.normal(0, 0.4, uv.shape)
    rig = calibrate_rig(corners)
    assert rig.dropped_views == []
    assert rig.adjustment["options"] == {"drop_outliers": True, "outlier_factor": 3.0}
