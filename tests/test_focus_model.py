"""Focus as part of the lens (dualcal.geometry.focus, dualcal.estimation.focus_model): the thin lens with a breathing
coefficient, each photo's focus, the coefficient recovered within its sigma where the photos span distances, no
model where the lenses do not breathe, and a camera at another focus whose sigma grows with the extrapolation."""

from dataclasses import replace

import numpy as np
import pytest

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.covariance import JointCovariance, intrinsic_name
from dualcal.estimation.focus_model import camera_at_focus, covariance_at_focus, photo_focus
from dualcal.files.io import load_rig, save_rig
from dualcal.geometry.board import Board
from dualcal.estimation.fitting import refit
from dualcal.geometry.focus import FocusModel, focal_scale, focal_scale_per_breathing
from dualcal.geometry.focus import camera_at_focus as lens_at_focus
from dualcal.progress import collect_warnings
from dualcal.synthetic.synth import make_truth, noisy_corner_set
from dualcal.synthetic.synth_focus import FOCAL_MM

#: A board of 15 mm squares filling 0.3-0.9 of the tele's frame: photos focused from 0.36 to 1.04 m.
SPANNING = dict(views=14, scale=0.5, board=Board(8, 5, 15.0), fill=(0.3, 0.9))


def test_the_focal_scale_is_the_thin_lens_image_distance():
    """b = 1: the principal distance is the thin lens's image distance f d / (d - f) (Gauss's lens equation), so
    g(d) is its ratio at two focus distances; dg/db is g's derivative; fx, fy and skew scale, the principal point
    and the lens do not."""
    f, d, d0 = 4.3, 300.0, 600.0
    assert focal_scale(d, f, 1.0, d0) == pytest.approx((f * d / (d - f)) / (f * d0 / (d0 - f)), rel=1e-14)
    assert focal_scale(d0, f, 1.7, d0) == 1.0
    step = 1e-6
    numeric = (focal_scale(d, f, 1.3 + step, d0) - focal_scale(d, f, 1.3 - step, d0)) / (2 * step)
    assert focal_scale_per_breathing(d, f, 1.3, d0) == pytest.approx(numeric, rel=1e-7)
    cam = make_truth("note8", 1, seed=0).cameras["wide"]
    cam = replace(cam, skew=2.0)
    at = lens_at_focus(cam, FocusModel(f, d0 / 1000, 1.0, (0.5, 0.7)), d / 1000)
    g = focal_scale(d, f, 1.0, d0)
    assert (at.fx, at.fy, at.skew) == pytest.approx((cam.fx * g, cam.fy * g, cam.skew * g), rel=1e-14)
    assert (at.cx, at.cy, at.k1, at.k2) == (cam.cx, cam.cy, cam.k1, cam.k2)


def _with_focus_meta(corners, truth):
    """``corners`` with each camera's meta as detection writes it for photos whose lenses hold still: the EXIF focal
    length and each photo's focus (the board centre's depth)."""
    centre = truth.board.object_points_mm().mean(axis=0)
    for name, cc in corners.cameras.items():
        cc.meta = {"exif": {"focal_length_mm": FOCAL_MM["note8"][name]},
                   "focus_m": {v: truth.camera_pose(name, v).apply(centre[None])[0, 2] / 1000 for v in cc.views}}
    return corners


@pytest.fixture(scope="module")
def breathing():
    """A phone whose lenses breathe (b = 2) calibrated from photos focused from 0.36 to 1.04 m."""
    truth = make_truth("note8", seed=41, breathing=2.0, **SPANNING)
    return truth, calibrate_rig(noisy_corner_set(truth, 0.05, seed=1), model="k1k2")


def test_breathing_is_recovered_within_its_sigma(breathing):
    """Both lenses' breathing coefficients within 2.5 of their sigmas of the truth, and each camera's fx at its
    reference focus (its photos' median) within 2.5 sigma of the true fx there; the focus check does not flag the
    photos whose focal change the model explains."""
    truth, rig = breathing
    assert set(rig.focus_models) == {"wide", "tele"}
    assert rig.adjustment["lens_motion"]["breathing"]["significant"]
    for name, model in rig.focus_models.items():
        f = FOCAL_MM["note8"][name]
        assert model.focal_length_mm == f and model.breathing_sigma > 0
        assert abs(model.breathing - 2.0) < 2.5 * model.breathing_sigma
        true_fx = truth.cameras[name].fx * (1 + 2.0 * f / (1000 * model.focus_m - f))
        assert abs(rig.cameras[name].fx - true_fx) < 2.5 * rig.camera_sigma[name]["fx"]
        assert model.focus_range_m[0] < 0.4 and model.focus_range_m[1] > 0.95
    assert rig.checks["focus"]["ok"]
    assert rig.adjustment["lens_motion"]["breathing"]["focus_from"]["wide"] == {"metadata": 14, "board": 0}


def test_no_focus_model_where_the_lenses_do_not_breathe():
    """The same photos of lenses that hold still (their focus stated in every photo's metadata): the test does not
    choose the model, and the calibration is the one without it, to the last digit."""
    truth = make_truth("note8", seed=41, **SPANNING)
    corners = _with_focus_meta(noisy_corner_set(truth, 0.05, seed=1), truth)
    rig = calibrate_rig(corners, model="k1k2")
    test = rig.adjustment["lens_motion"]["breathing"]
    assert not test["significant"] and test["t2"] < test["limit"] and not rig.focus_models
    plain = calibrate_rig(corners, model="k1k2", lens_motion=False)
    assert rig.cameras == plain.cameras
    assert np.array_equal(rig.covariance["clustered"], plain.covariance["clustered"])


def test_each_photo_focuses_where_its_metadata_says_else_on_the_board(breathing):
    """photo_focus: a photo's stated focus where its camera's meta has one, else the board centre's depth in the
    camera; a camera without an EXIF focal length is left out."""
    truth, _ = breathing
    corners = noisy_corner_set(truth, 0.0)
    solution = refit(calibrate_rig(corners, model="k1k2", lens_motion=False), rig_mode="none")   # the boards' poses
    del corners.cameras["wide"].meta["focus_m"]["IMG_01"]
    del corners.cameras["tele"].meta["exif"]
    focus = photo_focus(corners, solution)
    assert set(focus.focal_mm) == {"wide"}
    assert focus.source["wide", "IMG_01"] == "board" and focus.source["wide", "IMG_02"] == "metadata"
    centre = truth.board.object_points_mm().mean(axis=0)
    wide = solution.problem.cameras.index("wide")
    assert focus.focus_mm["wide", "IMG_01"] == solution.photo_poses[wide, "IMG_01"].apply(centre[None])[0, 2]
    depth = truth.camera_pose("wide", "IMG_01").apply(centre[None])[0, 2]      # its fx off by the breathing
    assert focus.focus_mm["wide", "IMG_01"] == pytest.approx(depth, rel=0.01)
    assert focus.focus_mm["wide", "IMG_02"] == pytest.approx(truth.photo_lenses["IMG_02"]["wide"].focus_mm, rel=1e-12)
    assert focus.reference_mm["wide"] == pytest.approx(np.median(list(focus.focus_mm.values())))


def test_a_camera_at_another_focus_is_less_certain_the_further_it_is_extrapolated(breathing, tmp_path):
    """calib.json keeps the model (focus_m, focus_model, each photo's focus; read back whole); a camera at its
    reference focus is the calibration's, with its covariance; elsewhere its fx is the model's, and beyond the
    photos' focus range fx's sigma grows the further it is extrapolated (in 1/d), nearer and farther; outside the
    range a warning says so."""
    truth, rig = breathing
    save_rig(tmp_path / "calib.json", rig)
    back = load_rig(tmp_path / "calib.json")
    assert back.focus_models == rig.focus_models and back.photo_focus_m == rig.photo_focus_m
    model = back.focus_models["tele"]
    assert camera_at_focus(back, "tele", model.focus_m) == back.cameras["tele"]
    assert camera_at_focus(back, "tele", None) == back.cameras["tele"]

    def fx_sigma(focus_m):
        cov = JointCovariance.from_dict(covariance_at_focus(back, {"tele": focus_m}))
        return max(np.sqrt(cov.block([intrinsic_name("tele", "fx")], kind)[0, 0]) for kind in ("clustered", "formal"))

    own = fx_sigma(None)
    assert fx_sigma(model.focus_m) == pytest.approx(own, rel=1e-9)
    lo, hi = model.focus_range_m
    nearer, farther = [fx_sigma(d) for d in (lo, 0.3, 0.25, 0.2)], [fx_sigma(d) for d in (hi, 2.0, 5.0, 100.0)]
    assert np.all(np.diff(nearer) > 0) and np.all(np.diff(farther) > 0)
    assert nearer[-1] > 3 * own and farther[-1] > 2 * own
    sigmas = nearer
    with collect_warnings() as said:
        near = camera_at_focus(back, "tele", 0.2)
    assert len(said) == 1 and "outside its calibration photos'" in said[0] and "extrapolated" in said[0]
    true_ratio = (1 + 2.0 * 6.0 / (200.0 - 6.0)) / (1 + 2.0 * 6.0 / (1000 * model.focus_m - 6.0))
    assert near.fx / back.cameras["tele"].fx == pytest.approx(true_ratio, abs=3 * sigmas[-1] / near.fx)
    with collect_warnings() as said:
        camera_at_focus(back, "tele", 0.6)
    assert not said


def test_export_writes_a_camera_at_the_focus_asked(breathing, tmp_path, run_cli):
    """``dualcal export --focus tele=0.3``: that camera's focal lengths at 0.3 m (the model's), the other at its
    calibration's focus; a malformed --focus is one line and exit 2."""
    _, rig = breathing
    save_rig(tmp_path / "calib.json", rig)
    res = run_cli("export", tmp_path / "calib.json", "--format", "colmap", "--focus", "tele=0.3", "-o",
                  tmp_path / "cameras.txt")
    assert res.code == 0, res.err
    rows = {line.split()[0]: [float(x) for x in line.split()[4:8]]
            for line in (tmp_path / "cameras.txt").read_text().splitlines() if line and not line.startswith("#")}
    tele, wide = sorted(rows, key=lambda k: rows[k][0])[::-1]
    g = rig.focus_models["tele"].scale(0.3)
    assert rows[tele][:2] == pytest.approx([rig.cameras["tele"].fx * g, rig.cameras["tele"].fy * g], rel=1e-9)
    assert rows[wide][:2] == pytest.approx([rig.cameras["wide"].fx, rig.cameras["wide"].fy], rel=1e-9)
    res = run_cli("export", tmp_path / "calib.json", "--format", "colmap", "--focus", "tele", "-o",
                  tmp_path / "other.txt")
    assert res.code == 2 and len(res.err_lines) == 1 and "CAMERA=METRES" in res.err
