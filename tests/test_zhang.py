"""Closed-form initialisation (paper sections 1.3-1.6) against exact synthetic data."""

import dataclasses

import numpy as np
import pytest

from dualcal.camera import project_points
from dualcal.errors import EstimationError
from dualcal.rotation import rotation_from_opk
from dualcal.model import Pose
from dualcal.synth import make_truth, true_corners
from dualcal.zhang import (apply_homography, estimate_homography, extrinsics_from_homography, initial_camera,
                           intrinsics_from_homographies, radial_distortion_linear)


def _pinhole_views(truth, name, skew=0.0):
    cam = dataclasses.replace(truth.cameras[name], k1=0.0, k2=0.0, skew=skew)
    X = truth.board.object_points_mm()
    views = {v: project_points(cam, truth.camera_pose(name, v).apply(X)) for v in truth.view_poses}
    return cam, X[:, :2], views


def test_homography_maps_board_to_pixels_exactly():
    truth = make_truth("note8", 3, seed=1)
    cam, xy, views = _pinhole_views(truth, "wide")
    uv = views["IMG_01"]
    H = estimate_homography(xy, uv)
    assert np.max(np.abs(apply_homography(H, xy) - uv)) < 1e-8
    assert H[2, 2] == 1.0


@pytest.mark.parametrize("preset,name", [("note8", "wide"), ("note8", "tele"), ("stereo", "left")])
@pytest.mark.parametrize("skew", [False, True])
def test_zhang_closed_form_recovers_pinhole_intrinsics(preset, name, skew):
    truth = make_truth(preset, 8, seed=2)
    cam, xy, views = _pinhole_views(truth, name, skew=4.0 if skew else 0.0)
    Hs = [estimate_homography(xy, views[v]) for v in sorted(views)]
    est = intrinsics_from_homographies(Hs, cam.image_size, skew=skew)
    np.testing.assert_allclose(est.as_vector()[:5], cam.as_vector()[:5], rtol=1e-7, atol=1e-5)


def test_extrinsics_from_homography_recover_pose():
    truth = make_truth("note8", 4, seed=3)
    cam, xy, views = _pinhole_views(truth, "tele")
    for v, uv in views.items():
        pose = extrinsics_from_homography(cam.K, estimate_homography(xy, uv))
        true = truth.camera_pose("tele", v)
        np.testing.assert_allclose(pose.R, true.R, atol=1e-9)
        np.testing.assert_allclose(pose.t_mm, true.t_mm, atol=1e-6)


def test_linear_k1_k2_exact_with_true_intrinsics_and_poses():
    truth = make_truth("stereo", 6, seed=4)
    cam = truth.cameras["left"]
    obs = true_corners(truth)["left"]
    keys = sorted(obs)
    k1, k2 = radial_distortion_linear(cam.with_distortion(0, 0), [truth.camera_pose("left", v) for v in keys],
                                      truth.board.object_points_mm()[:, :2], [obs[v] for v in keys])
    assert k1 == pytest.approx(cam.k1, abs=1e-9) and k2 == pytest.approx(cam.k2, abs=1e-9)


def test_initial_camera_is_close_enough_to_start_the_adjustment():
    truth = make_truth("note8", 13, seed=0)
    obs = true_corners(truth)["wide"]
    cam, poses = initial_camera(truth.board.object_points_mm()[:, :2], obs, truth.cameras["wide"].image_size)
    assert abs(cam.fx / truth.cameras["wide"].fx - 1) < 0.02
    assert set(poses) == set(obs)


def test_parallel_views_are_degenerate():
    truth = make_truth("note8", 1, seed=5)
    cam, xy, _ = _pinhole_views(truth, "wide")
    base = truth.view_poses["IMG_01"]
    X = np.column_stack([xy, np.zeros(len(xy))])
    Hs = []
    for k in range(5):   # same orientation, board only shifted and turned about its normal
        R = base.R @ rotation_from_opk([0.0, 0.0, 0.2 * k])
        uv = project_points(cam, Pose(R, base.t_mm + [10.0 * k, -5.0 * k, 20.0 * k]).apply(X))
        Hs.append(estimate_homography(xy, uv))
    with pytest.raises(EstimationError, match="parallel"):
        intrinsics_from_homographies(Hs, cam.image_size, skew=False)
