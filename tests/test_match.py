"""One tap found in the other photo (dualcal.estimation.matching), on renders with known truth.

The truth of a tap: the surface point its pixel's ray meets (a textured box, :mod:`dualcal.synthetic.render_object`,
or the board's plane), projected into the other camera. Each test taps with 2 px of error, as a finger does, so
the window is never centred on a feature.
"""

import numpy as np
import pytest

from dualcal.estimation.matching import epipolar_curve, match_frame, match_point
from dualcal.geometry.camera import pixel_rays, project_points
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_opk
from dualcal.synthetic.render import render_view
from dualcal.synthetic.render_object import TexturedBox, render_object
from dualcal.synthetic.synth import PRESETS, make_truth, scale_camera

TAP_PX = 2.0
IDENTITY = Pose(np.eye(3), np.zeros(3))


@pytest.fixture(scope="module")
def note8_box():
    """The note8 rig at a quarter of its size (756 x 1008), a textured box 0.4 m away, both photos rendered."""
    cams = {n: scale_camera(c, 0.25) for n, c in PRESETS["note8"]["cameras"].items()}
    poses = {"wide": IDENTITY, "tele": PRESETS["note8"]["rig"]["tele"]}
    box = TexturedBox(Pose(rotation_from_opk(np.radians([20.0, -30.0, 10.0])), np.array([0.0, 0.0, 400.0])),
                      (120.0, 80.0, 60.0), seed=1)
    images = {n: render_object(cams[n], poses[n], box, np.random.default_rng(i)) for i, n in enumerate(cams)}
    return cams, poses, box, images


def _true_match(cams, poses, box, tapped, other, uv):
    """Where the surface point under pixel ``uv`` of ``tapped`` appears in ``other``."""
    ray = poses[tapped].R.T @ pixel_rays(cams[tapped], np.asarray(uv)[None])[0]
    X = box.surface_point(poses[tapped].center_mm, ray)
    return project_points(cams[other], poses[other].apply(X[None]))[0]


@pytest.mark.parametrize("tapped,other", [("wide", "tele"), ("tele", "wide")])
def test_taps_on_a_textured_box_are_found_with_sigmas_that_hold(note8_box, tapped, other):
    """40 taps on the box's faces (2 px off the point meant): every match within 5 sigma of the truth, the errors
    over their sigmas with sd 0.7-1.4 and mean within +-0.4; the matches a few tenths of a pixel good."""
    cams, poses, box, images = note8_box
    pose_ab = poses[other].compose(poses[tapped].inverse())
    rng = np.random.default_rng(3)
    z, err = [], []
    while len(z) < 40:
        X = box.pose.apply(rng.uniform(-0.4, 0.4, 3) * np.array(box.size_mm))
        uv = project_points(cams[tapped], poses[tapped].apply(X[None]))[0] + rng.normal(0.0, TAP_PX, 2)
        truth = _true_match(cams, poses, box, tapped, other, uv)
        w, h = cams[other].image_size
        if not (30 < truth[0] < w - 30 and 30 < truth[1] < h - 30):
            continue
        m = match_point(images[tapped], cams[tapped], images[other], cams[other], pose_ab, uv)
        if not m.ok:
            assert m.reason in ("texture-less", "no match"), m.reason
            continue
        e = m.uv - truth
        assert abs(e @ [-m.direction[1], m.direction[0]]) < 0.05        # on the epipolar line (exact calibration)
        z.append(e @ m.direction / m.sigma_px)
        err.append(e @ m.direction)
    z = np.array(z)
    summary = f"z sd {z.std():.2f} mean {z.mean():+.2f}, errors rms {np.sqrt(np.mean(np.square(err))):.3f} px"
    print(summary)
    assert np.all(np.abs(z) < 5) and 0.7 <= z.std() <= 1.4 and abs(z.mean()) <= 0.4, summary
    assert np.sqrt(np.mean(np.square(err))) < 0.4, summary


def test_the_match_follows_the_tap_as_its_jacobian_says(note8_box):
    """Moving the tap by a pixel moves the match by the tap Jacobian (over the face's own slant), to 0.1 px."""
    cams, poses, box, images = note8_box
    pose_ab = poses["tele"].compose(poses["wide"].inverse())
    uv = project_points(cams["wide"], box.pose.apply(np.array([[10.0, 5.0, -30.0]])))[0]
    m0 = match_point(images["wide"], cams["wide"], images["tele"], cams["tele"], pose_ab, uv)
    assert m0.ok
    for step in ([1.5, 0.0], [0.0, 1.5]):
        m1 = match_point(images["wide"], cams["wide"], images["tele"], cams["tele"], pose_ab, uv + step)
        assert m1.ok
        assert np.linalg.norm((m1.uv - m0.uv) - m0.tap_jacobian @ step) < 0.1


def test_the_epipolar_curve_passes_through_the_true_point(note8_box):
    cams, poses, box, _ = note8_box
    pose_ab = poses["tele"].compose(poses["wide"].inverse())
    X = box.pose.apply(np.array([[0.0, 0.0, -30.0]]))[0]
    uv = project_points(cams["wide"], X[None])[0]
    curve = epipolar_curve(cams["wide"], cams["tele"], pose_ab, uv, [np.linalg.norm(X), 1e5])
    assert np.allclose(curve[0], project_points(cams["tele"], pose_ab.apply(X[None]))[0], atol=1e-6)
    frame = match_frame(cams["wide"], cams["tele"], pose_ab, uv)
    assert frame.baseline_mm == pytest.approx(np.linalg.norm(pose_ab.t_mm))
    assert frame.disparity_px(np.inf) == 0


def test_a_board_corner_of_a_stereo_pair_is_found_and_repeated_squares_never_confuse_it():
    """A 640 x 480 pair with a 100 mm baseline: the board's inner corners repeat every two squares along the
    line, so a window alone cannot tell them apart; the match is then made unique at a coarser scale or the
    point is left unmatched ("repeated pattern"), never matched to the wrong corner."""
    truth = make_truth("stereo", views=3, seed=3)
    rng = np.random.default_rng(1)
    z, found = [], 0
    for vi, view in enumerate(truth.view_poses):
        images = {c: render_view(truth.cameras[c], truth.camera_pose(c, view), truth.board,
                                 np.random.default_rng([vi, i])) for i, c in enumerate(truth.cameras)}
        board_pose = truth.view_poses[view]
        normal, point = board_pose.R[:, 2], board_pose.t_mm
        for k in rng.choice(truth.board.n_corners, 12, replace=False):
            X = board_pose.apply(truth.board.object_points_mm()[k][None])[0]
            uv = project_points(truth.cameras["left"], X[None])[0] + rng.normal(0.0, TAP_PX, 2)
            d = pixel_rays(truth.cameras["left"], uv[None])[0]
            S = (point @ normal) / (d @ normal) * d
            true_uv = project_points(truth.cameras["right"], truth.rig["right"].apply(S[None]))[0]
            m = match_point(images["left"], truth.cameras["left"], images["right"], truth.cameras["right"],
                            truth.rig["right"], uv)
            if not m.ok:
                assert m.reason == "repeated pattern", m.reason
                continue
            found += 1
            z.append((m.uv - true_uv) @ m.direction / m.sigma_px)
            assert np.linalg.norm(m.uv - true_uv) < 1.0                 # never another corner
    z = np.array(z)
    assert found >= 24 and 0.6 <= z.std() <= 1.5, (found, z.std())


def _flat(size, seed=0):
    """A blank grey photo (sensor noise only) of ``size`` (W, H)."""
    return np.clip(128 + np.random.default_rng(seed).normal(0.0, 1.0, size[::-1]), 0, 255).astype(np.uint8)


def _stripes(size, period_px):
    """Stripes of ``period_px`` across the note8's epipolar lines (its baseline is vertical: the lines are columns)."""
    rows = 128 + 90 * np.sign(np.sin(2 * np.pi * np.arange(size[1]) / period_px))
    return np.repeat(rows[:, None], size[0], axis=1).astype(np.uint8)


def test_a_point_that_cannot_be_matched_says_why():
    """Texture-less (a blank wall), a repeated pattern (stripes across the epipolar line, at every scale), a tap
    whose line leaves the other photo."""
    cams = {n: scale_camera(c, 0.25) for n, c in PRESETS["note8"]["cameras"].items()}
    pose_ab = PRESETS["note8"]["rig"]["tele"]
    wide, tele = cams["wide"].image_size, cams["tele"].image_size
    centre = np.array([wide[0] / 2, wide[1] / 2])
    blank = match_point(_flat(wide), cams["wide"], _flat(tele, 1), cams["tele"], pose_ab, centre)
    assert not blank.ok and blank.reason == "texture-less"
    repeated = match_point(_stripes(wide, 40.0), cams["wide"], _stripes(tele, 77.5), cams["tele"], pose_ab, centre)
    assert not repeated.ok and repeated.reason == "repeated pattern"
    outside = match_point(_flat(wide), cams["wide"], _flat(tele), cams["tele"], pose_ab, [-5.0, 10.0])
    assert not outside.ok and outside.reason == "off the image"
