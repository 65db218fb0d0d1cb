"""Camera model: projection, exact Jacobians, distortion both ways (paper eqs. 13, 24-28)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualcal.camera import (CameraModel, check_invertible_in_image, distort_normalized, distort_points,
                            max_distorted_radius, max_monotonic_radius, normalized_from_pixel, pixel_from_normalized,
                            project_points, project_with_jacobians, undistort_normalized, undistort_points,
                            undistort_radius)
from dualcal.errors import NotInvertibleError
from dualcal.synth import PRESETS

CAM = CameraModel((3024, 4032), 3127.2, 3136.0, 2.5, 1453.7, 2021.1, 0.08, -0.20)


def test_projection_follows_the_contract_formula():
    X = np.array([[100.0, -50.0, 600.0]])
    x, y = 100 / 600, -50 / 600
    r2 = x * x + y * y
    f = 1 + CAM.k1 * r2 + CAM.k2 * r2 * r2
    expected = [CAM.fx * x * f + CAM.skew * y * f + CAM.cx, CAM.fy * y * f + CAM.cy]
    np.testing.assert_allclose(project_points(CAM, X)[0], expected, rtol=0, atol=1e-9)


def test_jacobians_match_central_differences():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-200, 200, 20), rng.uniform(-300, 300, 20), rng.uniform(400, 900, 20)])
    _, J_X, J_K = project_with_jacobians(CAM, X)
    h = 1e-4
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        num = (project_points(CAM, X + d) - project_points(CAM, X - d)) / (2 * h)
        np.testing.assert_allclose(J_X[:, :, i], num, rtol=1e-6, atol=1e-7)
    vec = CAM.as_vector()
    for i in range(7):
        step = 1e-6 * max(1.0, abs(vec[i]))
        plus, minus = vec.copy(), vec.copy()
        plus[i] += step
        minus[i] -= step
        num = (project_points(CameraModel.from_vector(CAM.image_size, plus), X)
               - project_points(CameraModel.from_vector(CAM.image_size, minus), X)) / (2 * step)
        np.testing.assert_allclose(J_K[:, :, i], num, rtol=1e-5, atol=1e-6)


def test_pixel_and_normalized_are_inverse_with_skew():
    uv = np.array([[0.0, 0.0], [3023.0, 4031.0], [1500.5, 17.25]])
    np.testing.assert_allclose(pixel_from_normalized(CAM, normalized_from_pixel(CAM, uv)), uv, atol=1e-9)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_undistort_points_round_trip_over_whole_image(preset):
    for cam in PRESETS[preset]["cameras"].values():
        w, h = cam.image_size
        u, v = np.meshgrid(np.linspace(-0.5, w - 0.5, 41), np.linspace(-0.5, h - 0.5, 41))
        uv = np.column_stack([u.ravel(), v.ravel()])
        back = distort_points(cam, undistort_points(cam, uv))
        assert np.max(np.abs(back - uv)) < 1e-6


@settings(max_examples=300, deadline=None)
@given(k1=st.floats(-1.0, 1.0), k2=st.floats(-1.0, 1.5), s=st.floats(0.0, 0.999), angle=st.floats(0, 2 * np.pi))
def test_undistort_inverts_distort_on_the_monotonic_branch(k1, k2, s, angle):
    """undistort(distort(x)) = x for every radius up to the fold (or up to 3 where there is none).
    Near the fold the inverse is ill-conditioned (d rd / dr -> 0), so the tolerance on x is the
    rounding of rd divided by that slope; the distorted point itself is matched to rounding."""
    r_max = max_monotonic_radius(k1, k2)
    r = s * min(r_max, 3.0)
    xy = r * np.array([[np.cos(angle), np.sin(angle)]])
    xy_d = distort_normalized(xy, k1, k2)
    back = undistort_normalized(xy_d, k1, k2)
    rd = float(np.hypot(*xy_d[0]))
    np.testing.assert_allclose(distort_normalized(back, k1, k2), xy_d, rtol=0, atol=1e-14 * max(1.0, rd))
    slope = 1 + 3 * k1 * r**2 + 5 * k2 * r**4
    np.testing.assert_allclose(back, xy, rtol=0, atol=1e-14 * max(1.0, rd) / slope)


@settings(max_examples=100, deadline=None)
@given(k1=st.floats(-1.0, 1.0), k2=st.floats(-1.0, 1.0), beyond=st.floats(1e-9, 1.0))
def test_past_the_fold_is_a_named_error(k1, k2, beyond):
    rd_max = max_distorted_radius(k1, k2)
    if not np.isfinite(rd_max):
        return
    with pytest.raises(NotInvertibleError, match="folds over"):
        undistort_normalized(np.array([[0.0, rd_max * (1 + beyond)]]), k1, k2)


def test_undistortion_takes_the_root_before_the_fold():
    """k1 = 0.6, k2 = -0.6: rd = 0.99 has two roots, 0.9155 (before the fold at r = 0.975) and
    1.030 (after it, where the model folds back); Newton from the first-order start alone lands
    on the second."""
    k1, k2 = 0.6, -0.6
    r, converged = undistort_radius(np.array([0.99]), k1, k2)
    assert converged and r[0] < max_monotonic_radius(k1, k2)
    assert r[0] == pytest.approx(0.9155, abs=1e-4)
    assert r[0] * (1 + k1 * r[0] ** 2 + k2 * r[0] ** 4) == pytest.approx(0.99, abs=1e-15)
    # right at the fold the slope vanishes; the bracket still converges on the residual
    rd_max = max_distorted_radius(k1, k2)
    r, converged = undistort_radius(np.array([rd_max, 0.5 * rd_max, 0.0]), k1, k2)
    assert converged and r[0] == pytest.approx(max_monotonic_radius(k1, k2), rel=1e-7) and r[2] == 0.0


def test_unmeasured_points_stay_unmeasured():
    xy = np.array([[0.1, 0.2], [np.nan, np.nan], [-0.3, 0.05]])
    back = undistort_normalized(distort_normalized(xy, CAM.k1, CAM.k2), CAM.k1, CAM.k2)
    assert np.isnan(back[1]).all()
    np.testing.assert_allclose(back[[0, 2]], xy[[0, 2]], atol=1e-14)


def test_max_monotonic_radius_is_where_the_derivative_vanishes():
    k1, k2 = -0.35, 0.05
    r = max_monotonic_radius(k1, k2)
    assert abs(1 + 3 * k1 * r**2 + 5 * k2 * r**4) < 1e-12
    assert max_monotonic_radius(0.1, 0.2) == np.inf


def test_folding_distortion_inside_the_image_is_a_clear_error():
    folding = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.6, 0.0)
    with pytest.raises(NotInvertibleError, match="not monotonic"):
        check_invertible_in_image(folding)
    check_invertible_in_image(CAM)


@settings(max_examples=200, deadline=None)
@given(rotvec=st.tuples(*[st.floats(-0.8, 0.8)] * 3), t=st.tuples(st.floats(-100, 100), st.floats(-100, 100),
                                                                 st.floats(300, 1500)),
       X=st.tuples(st.floats(-150, 150), st.floats(-150, 150)))
def test_projection_of_random_poses_back_projects_onto_the_ray(rotvec, t, X):
    """Any board point in front of the camera projects to a pixel whose ray passes through it."""
    from dualcal.camera import ideal_normalized_from_pixel
    from dualcal.model import Pose
    from dualcal.rotation import rotation_from_rotvec
    Xc = Pose(rotation_from_rotvec(np.array(rotvec)), np.array(t)).apply(np.array([[X[0], X[1], 0.0]]))
    xy = Xc[:, :2] / Xc[:, 2:]
    if Xc[0, 2] <= 0 or np.hypot(*xy[0]) >= 0.99 * max_monotonic_radius(CAM.k1, CAM.k2):
        return
    uv = project_points(CAM, Xc)
    np.testing.assert_allclose(ideal_normalized_from_pixel(CAM, uv), xy, atol=1e-10)
