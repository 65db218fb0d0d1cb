"""Space intersection (dualcal.estimation.intersect): exact rays, least-squares optimality, degenerate cases."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from dualcal.geometry.camera import CameraModel, project_points
from dualcal.errors import EstimationError
from dualcal.estimation.intersect import intersect_rays, triangulate, viewing_rays
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_rotvec
from dualcal.synthetic.synth import make_truth

WIDE = CameraModel((3024, 4032), 3127.2, 3136.0, 0.0, 1453.7, 2021.1, 0.08, -0.20)
TELE = CameraModel((3024, 4032), 6058.7, 6076.3, 2.5, 1373.1, 1971.9, -0.12, 0.80)


def _looking_at_origin(centre_mm, roll_rad: float) -> Pose:
    """Board -> camera pose of a camera at ``centre_mm`` looking at the origin."""
    z = -np.asarray(centre_mm, float) / np.linalg.norm(centre_mm)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = rotation_from_rotvec([0.0, 0.0, roll_rad]) @ np.vstack([x, np.cross(z, x), z])
    return Pose(R, -R @ np.asarray(centre_mm, float))


@pytest.fixture
def scene():
    rng = np.random.default_rng(3)
    X = rng.uniform(-150, 150, (60, 3))
    poses = [_looking_at_origin([-300, 40, -900], 0.3), _looking_at_origin([250, -60, -1000], -0.2),
             _looking_at_origin([30, 280, -800], 1.0)]
    cams = [WIDE, TELE, WIDE]
    uv = [project_points(c, p.apply(X)) for c, p in zip(cams, poses)]
    return X, cams, poses, uv


def test_viewing_rays_pass_through_the_points(scene):
    X, cams, poses, uv = scene
    for cam, pose, obs in zip(cams, poses, uv):
        centre, d = viewing_rays(cam, pose, obs)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        to_point = X - centre
        perpendicular = to_point - np.sum(to_point * d, axis=1, keepdims=True) * d
        assert np.max(np.linalg.norm(perpendicular, axis=1)) < 1e-9


@pytest.mark.parametrize("n_photos", [2, 3])
def test_exact_observations_give_the_points(scene, n_photos):
    X, cams, poses, uv = scene
    rays = [viewing_rays(c, p, o) for c, p, o in zip(cams[:n_photos], poses[:n_photos], uv[:n_photos])]
    linear = intersect_rays(np.array([c for c, _ in rays]), np.array([d for _, d in rays]))
    np.testing.assert_allclose(linear, X, atol=1e-8)
    np.testing.assert_allclose(triangulate(cams[:n_photos], poses[:n_photos], uv[:n_photos]), X, atol=1e-8)


def test_linear_point_minimises_perpendicular_distances():
    rng = np.random.default_rng(5)
    centres = rng.normal(0, 100, (4, 3))
    directions = rng.normal(0, 1, (4, 25, 3)) + np.array([0, 0, 3.0])
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    X = intersect_rays(centres, directions)

    def perpendicular(p, n):
        v = p - centres
        d = directions[:, n]
        return (v - np.sum(v * d, axis=1, keepdims=True) * d).ravel()

    for n in range(25):
        # optimality: the gradient sum_i P_i (X - C_i) of half the cost vanishes ...
        gradient = perpendicular(X[n], n).reshape(4, 3).sum(axis=0)
        assert np.linalg.norm(gradient) < 1e-9
        # ... and an independent minimiser finds the same point
        best = least_squares(perpendicular, X[n] + 10.0, args=(n,), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        np.testing.assert_allclose(X[n], best, atol=1e-4)


def test_refined_point_minimises_pixel_residuals(scene):
    X, cams, poses, uv = scene
    rng = np.random.default_rng(8)
    noisy = [o + rng.normal(0, 0.5, o.shape) for o in uv]
    refined = triangulate(cams, poses, noisy)
    rays = [viewing_rays(c, p, o) for c, p, o in zip(cams, poses, noisy)]
    linear = intersect_rays(np.array([c for c, _ in rays]), np.array([d for _, d in rays]))
    assert np.max(np.abs(refined - linear)) > 1e-3      # the refinement does move the points

    def reprojection(p, n):
        return np.concatenate([project_points(c, q.apply(p[None]))[0] - o[n]
                               for c, q, o in zip(cams, poses, noisy)])

    for n in range(0, len(X), 7):
        best = least_squares(reprojection, linear[n], args=(n,), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        np.testing.assert_allclose(refined[n], best, atol=1e-6)


def test_parallel_rays_raise():
    d = np.tile([[[0.0, 0.0, 1.0]]], (2, 3, 1))
    with pytest.raises(EstimationError, match="parallel"):
        intersect_rays(np.array([[0.0, 0, 0], [10.0, 0, 0]]), d)


def test_one_photo_raises(scene):
    X, cams, poses, uv = scene
    with pytest.raises(EstimationError, match="two rays"):
        triangulate(cams[:1], poses[:1], uv[:1])


def test_point_behind_a_camera_raises(scene):
    X, cams, poses, uv = scene
    # Camera 1 turned by 180 degrees about its y axis: its rays through the points reflected in
    # its centre lie on the same lines, so the lines meet at X, which is behind that camera.
    turned = Pose(rotation_from_rotvec([0.0, np.pi, 0.0]) @ poses[1].R,
                  rotation_from_rotvec([0.0, np.pi, 0.0]) @ poses[1].t_mm)
    reflected = 2.0 * poses[1].center_mm - X
    uv_turned = project_points(cams[1], turned.apply(reflected))
    with pytest.raises(EstimationError, match="behind"):
        triangulate([cams[0], cams[1]], [poses[0], turned], [uv[0], uv_turned])


def test_synthetic_rig_corners_are_recovered():
    truth = make_truth("note8", views=2, seed=4)
    X = truth.board.object_points_mm()
    cams = [truth.cameras["wide"], truth.cameras["tele"]]
    poses = [truth.camera_pose("wide", "IMG_01"), truth.camera_pose("tele", "IMG_01")]
    uv = [project_points(c, p.apply(X)) for c, p in zip(cams, poses)]
    np.testing.assert_allclose(triangulate(cams, poses, uv), X, atol=1e-6)


def test_unmeasured_points_are_refused(scene):
    X, cams, poses, uv = scene
    partial = uv[1].copy()
    partial[3] = np.nan
    with pytest.raises(EstimationError, match="select the points all photos saw"):
        triangulate(cams[:2], poses[:2], [uv[0], partial])
