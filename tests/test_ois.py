"""The stabiliser's shift of every photo (dualcal.estimation.ois): its spread recovered from the instants, the rig
check passing a stabilised rig whose shots are synchronised, no shift where the lenses hold still, and a new photo's
principal point as uncertain as the spread in every measurement."""

import numpy as np
import pytest

from calib_regression import synthetic_corners
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.covariance import JointCovariance, intrinsic_name
from dualcal.estimation.focus_model import covariance_at_focus
from dualcal.files.io import load_rig, save_rig
from dualcal.progress import collect_warnings
from dualcal.synthetic.synth import make_truth, noisy_corner_set

OIS_PX = 1.0


@pytest.fixture(scope="module")
def stabilised():
    """A wide + tele phone whose stabiliser moves every photo's principal point by 1 px per coordinate (6 MP, 14
    synchronised instants, corners 0.1 px): calibrated with the shifts modelled, and as before (no lens motion)."""
    truth = make_truth("note8", views=14, seed=61, scale=0.5, ois_px=OIS_PX)
    corners = noisy_corner_set(truth, 0.1, seed=1)
    with collect_warnings():
        return truth, calibrate_rig(corners, model="k1k2"), calibrate_rig(corners, model="k1k2", lens_motion=False)


def test_the_stabilisers_spread_is_recovered(stabilised):
    """In a rig the shifts show as the relative angle between the cameras moving from instant to instant by
    ``delta_w / f_w - delta_t / f_t``: the spread of that angle the estimated spreads give is within 30 % of the
    truth's (each camera's alone is told from its pose only by the lens's perspective and distortion, weakly for
    a tele); the rig's angles are within 3 sigma of the truth, each photo's shift is estimated, and calib.json keeps
    them."""
    truth, rig, _ = stabilised
    assert rig.adjustment["lens_motion"]["ois"]["significant"]
    fw, ft = truth.cameras["wide"].fx, truth.cameras["tele"].fx
    angle = np.hypot(rig.ois_sigma_px["wide"] / fw, rig.ois_sigma_px["tele"] / ft)
    assert 0.7 < angle / (OIS_PX * np.hypot(1 / fw, 1 / ft)) < 1.4
    relation = rig.rig["tele"]
    assert np.all(np.abs(relation.pose.opk_arcmin - truth.rig["tele"].opk_arcmin) < 3 * relation.sigma_opk_arcmin)
    assert set(rig.ois_shift_px) == {name for name, s in rig.ois_sigma_px.items() if s > 0}
    assert all(len(per) == 14 for per in rig.ois_shift_px.values())


def test_rig_rigid_passes_a_stabilised_rig_whose_shots_are_synchronised(stabilised):
    """Without the shifts the instants do not fit one relative pose (rig_rigid fails, instants are dropped); with
    them every instant is kept and the check passes, its instants together near 1 x the photo-level noise."""
    _, rig, plain = stabilised
    assert not plain.checks["rig_rigid"]["ok"]
    assert rig.checks["rig_rigid"]["ok"] and not rig.dropped_views
    assert 0.3 < rig.checks["rig_rigid"]["ratio"] < 2.0


def _with_exif(corners, focal_mm=4.3):
    """``corners`` whose cameras' EXIF gives a focal length (their photos may be stabilised)."""
    for cc in corners.cameras.values():
        cc.meta = {"exif": {"focal_length_mm": focal_mm}}
    return corners


@pytest.mark.parametrize("preset", ["note8", "triple"])
def test_no_shift_where_the_lenses_hold_still(preset):
    """A rig whose principal points stay put (its photos' EXIF gives a focal length: they may be stabilised): the
    test does not find shifts, every camera's spread is 0, and the calibration is the one without the lens's
    motion, to the last digit."""
    corners = _with_exif(noisy_corner_set(make_truth(preset, views=12, seed=62, scale=0.25), 0.2, seed=2))
    with collect_warnings():
        rig = calibrate_rig(corners, model="k1k2")
        plain = calibrate_rig(corners, model="k1k2", lens_motion=False)
    test = rig.adjustment["lens_motion"]["ois"]
    assert not test["significant"] and test["statistic"] < test["limit"]
    assert rig.ois_sigma_px == dict.fromkeys(rig.cameras, 0.0) and not rig.ois_shift_px
    assert rig.cameras == plain.cameras
    assert np.array_equal(rig.covariance["clustered"], plain.covariance["clustered"])


def test_a_new_photos_principal_point_is_as_uncertain_as_the_spread(stabilised, tmp_path):
    """calib.json's ois_sigma_px and each photo's shift read back; a measurement's covariance gives each shifting
    camera's cx and cy the spread's variance on top of the calibration's, and nothing else."""
    _, rig, _ = stabilised
    save_rig(tmp_path / "calib.json", rig)
    back = load_rig(tmp_path / "calib.json")
    assert back.ois_sigma_px == rig.ois_sigma_px
    assert all(np.array_equal(back.ois_shift_px[c][v], s) for c, per in rig.ois_shift_px.items() for v, s in per.items())
    before, after = JointCovariance.from_dict(back.covariance), JointCovariance.from_dict(covariance_at_focus(back, {}))
    added = np.zeros(len(before.parameters))
    for camera, spread in back.ois_sigma_px.items():
        for n in ("cx", "cy"):
            added[before.index([intrinsic_name(camera, n)])] = spread ** 2
    for kind in ("clustered", "formal"):
        np.testing.assert_allclose(after.matrices[kind], before.matrices[kind] + np.diag(added), rtol=0, atol=1e-12)


def test_a_desynchronised_instant_is_not_taken_for_a_stabiliser():
    """One instant whose second camera shot 0.5 mm and 1.5 arcmin off the rig (the regression harness's planted
    desync) pulls the rig's relative pose, so that every instant seems shifted; the test leaves it out (it fits far
    worse than the others), finds no shift in the rest, and rig_rigid names it, as without the test."""
    corners = _with_exif(synthetic_corners("triple", 12, 5, 0.1, "desync"))
    with collect_warnings():
        rig = calibrate_rig(corners, model="k1k2")
    test = rig.adjustment["lens_motion"]["ois"]
    assert test["left_out"] == ["IMG_07"] and not test["significant"]
    assert not rig.checks["rig_rigid"]["ok"] and rig.checks["rig_rigid"]["flagged"] == ["IMG_07"]


def test_cameras_without_a_focal_length_in_exif_are_not_judged():
    """A webcam rig (no EXIF) whose every instant is jittered like OIS would shift it: its lenses are taken to hold
    still, no stabiliser is looked for, and the calibration is the one without the lens's motion; only the cameras
    whose EXIF gives a focal length are judged."""
    truth = make_truth("note8", views=14, seed=61, scale=0.5, ois_px=OIS_PX)
    corners = noisy_corner_set(truth, 0.1, seed=1)
    for cc in corners.cameras.values():
        cc.meta = {}
    with collect_warnings():
        rig = calibrate_rig(corners, model="k1k2")
        plain = calibrate_rig(corners, model="k1k2", lens_motion=False)
    assert "lens_motion" not in rig.adjustment and not rig.ois_sigma_px and rig.cameras == plain.cameras
    corners.cameras["tele"].meta = {"exif": {"focal_length_mm": 6.0}}
    with collect_warnings():
        rig = calibrate_rig(corners, model="k1k2")
    assert rig.adjustment["lens_motion"]["ois"]["cameras"] == ["tele"] and set(rig.ois_sigma_px) == {"tele"}
