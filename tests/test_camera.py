"""Camera model: projection, exact Jacobians, distortion both ways (paper eqs. 13, 24-28)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cv2

from dataclasses import replace

from dualcal.geometry.camera import (INTRINSIC_NAMES, LENS_MODELS, CameraModel, check_invertible_in_image,
                                     distort_normalized, distort_points, fisheye_max_angle, fold_radius,
                                     ideal_normalized_from_pixel, intrinsic_names, max_distorted_radius,
                                     max_monotonic_radius, normalized_from_pixel, pixel_from_normalized, project_points,
                                     project_with_jacobians, ray_directions, undistort, undistort_normalized,
                                     undistort_points, undistort_radius)
from dualcal.errors import NotInvertibleError
from dualcal.synthetic.synth import PRESETS

CAM = CameraModel((3024, 4032), 3127.2, 3136.0, 2.5, 1453.7, 2021.1, 0.08, -0.20)
#: OpenCV's five-coefficient lens (and skew) on the same sensor
CAM5 = CameraModel((3024, 4032), 3127.2, 3136.0, 2.5, 1453.7, 2021.1, 0.08, -0.20, 0.0021, -0.0013, 0.15,
                   model="k1k2p1p2k3")


def test_projection_follows_the_contract_formula():
    X = np.array([[100.0, -50.0, 600.0]])
    x, y = 100 / 600, -50 / 600
    r2 = x * x + y * y
    f = 1 + CAM.k1 * r2 + CAM.k2 * r2 * r2
    expected = [CAM.fx * x * f + CAM.skew * y * f + CAM.cx, CAM.fy * y * f + CAM.cy]
    np.testing.assert_allclose(project_points(CAM, X)[0], expected, rtol=0, atol=1e-9)


def _assert_jacobians_are_differences(cam, X, model, absent, h_mm, atol_X, atol_K):
    """project_with_jacobians' J_X and J_K against central differences: by the point (steps of ``h_mm``)
    and by every intrinsic in ``model``'s family (steps of 1e-6 relative); the ``absent`` columns zero."""
    _, J_X, J_K = project_with_jacobians(cam, X)
    for i in range(3):
        d = np.zeros(3)
        d[i] = h_mm
        num = (project_points(cam, X + d) - project_points(cam, X - d)) / (2 * h_mm)
        np.testing.assert_allclose(J_X[:, :, i], num, rtol=1e-6, atol=atol_X)
    vec = cam.as_vector()
    for i, name in enumerate(INTRINSIC_NAMES):
        if name in absent:
            assert not J_K[:, :, i].any()
            continue
        step = 1e-6 * max(1.0, abs(vec[i]))
        plus, minus = vec.copy(), vec.copy()
        plus[i] += step
        minus[i] -= step
        num = (project_points(CameraModel.from_vector(cam.image_size, plus, model), X)
               - project_points(CameraModel.from_vector(cam.image_size, minus, model), X)) / (2 * step)
        np.testing.assert_allclose(J_K[:, :, i], num, rtol=1e-5, atol=atol_K)


@pytest.mark.parametrize("cam", [CAM, CAM5], ids=["k1k2", "k1k2p1p2k3"])
def test_jacobians_match_central_differences(cam):
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-200, 200, 20), rng.uniform(-300, 300, 20), rng.uniform(400, 900, 20)])
    assert project_with_jacobians(cam, X)[2].shape == (20, 2, len(INTRINSIC_NAMES))
    # every coefficient, also those the model lacks; k4, the fisheye's alone, has no column
    _assert_jacobians_are_differences(cam, X, "k1k2p1p2k3", absent=("k4",), h_mm=1e-4, atol_X=1e-7, atol_K=1e-6)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_projection_and_jacobians_agree_with_opencv(seed):
    """cv2.projectPoints of random cameras with OpenCV's five coefficients (no skew: OpenCV has
    none): the same pixels, and its Jacobian with respect to the translation (at R = I, t = 0: d uv
    / d X_cam), f, c and the distortion coefficients is dualcal's."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(300, 6000)
    k = (rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01),
         rng.uniform(-0.3, 0.3))
    cam = CameraModel((4000, 3000), f, f * rng.uniform(0.98, 1.02), 0.0, rng.uniform(1800, 2200),
                      rng.uniform(1300, 1700), *k, model="k1k2p1p2k3")
    X = np.column_stack([rng.uniform(-0.5, 0.5, (30, 2)), np.ones(30)]) * rng.uniform(300, 3000, (30, 1))
    uv, J_X, J_K = project_with_jacobians(cam, X)
    uv_cv, J_cv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, np.array(cam.distortion))
    scale = np.maximum(1.0, np.abs(J_K))
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2), rtol=0, atol=1e-8)
    np.testing.assert_allclose(project_points(cam, X), uv, rtol=0, atol=1e-9)
    J_cv = J_cv.reshape(-1, 2, 15)                 # rvec, tvec, (fx, fy), (cx, cy), (k1, k2, p1, p2, k3)
    np.testing.assert_allclose(J_X, J_cv[:, :, 3:6], rtol=1e-9, atol=1e-9)
    columns = [INTRINSIC_NAMES.index(n) for n in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")]
    np.testing.assert_allclose(J_K[:, :, columns] / scale[:, :, columns], J_cv[:, :, 6:] / scale[:, :, columns],
                               rtol=0, atol=1e-9)


def test_the_paper_model_is_the_lens_model_k1k2():
    """Lens models list their coefficients; a camera's coefficients outside its model are zero."""
    assert LENS_MODELS["k1k2"] == ("k1", "k2") and LENS_MODELS["k1k2p1p2k3"] == ("k1", "k2", "p1", "p2", "k3")
    assert intrinsic_names() == ("fx", "fy", "skew", "cx", "cy", "k1", "k2")
    assert CAM.model == "k1k2" and (CAM.p1, CAM.p2, CAM.k3) == (0.0, 0.0, 0.0)
    assert CAM5.distortion == (0.08, -0.20, 0.0021, -0.0013, 0.15)
    with pytest.raises(ValueError, match="lens model k1k2 has no p1, k3"):
        CameraModel((640, 480), 500.0, 500.0, 0.0, 320.0, 240.0, 0.1, 0.0, p1=0.001, k3=0.2)
    with pytest.raises(ValueError, match="lens model 'fisheye' is unknown"):
        CameraModel((640, 480), 500.0, 500.0, 0.0, 320.0, 240.0, model="fisheye")


def test_pixel_and_normalized_are_inverse_with_skew():
    uv = np.array([[0.0, 0.0], [3023.0, 4031.0], [1500.5, 17.25]])
    np.testing.assert_allclose(pixel_from_normalized(CAM, normalized_from_pixel(CAM, uv)), uv, atol=1e-9)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_undistort_points_round_trip_over_whole_image(preset):   # stereo5: tangential lenses
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


def _radial_slope(r, k1, k2, k3=0.0):
    """d rd / dr of rd = r (1 + k1 r^2 + k2 r^4 + k3 r^6)."""
    return 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6


@settings(max_examples=400, deadline=None)
@given(k1=st.floats(-1.0, 1.0), k2=st.floats(-1.0, 1.5), k3=st.floats(-1.0, 1.0), p1=st.floats(-0.02, 0.02),
       p2=st.floats(-0.02, 0.02), s=st.floats(0.0, 0.95), angle=st.floats(0, 2 * np.pi))
def test_undistort_inverts_the_full_model_on_its_invertible_range(k1, k2, k3, p1, p2, s, angle):
    """OpenCV's model, tangential terms up to 0.02 (ten times a real lens'): undistort(distort(x)) = x
    within 95 % of the radial part's fold (at most radius 1, 45 degrees off axis) where the radial
    slope d rd / dr is at least 0.25, i.e. well away from the fold, where the tangential terms
    cannot fold the image. The distorted point is matched to the rounding of the residual test,
    the ideal one to that over the Jacobian's smallest singular value."""
    r = s * min(max_monotonic_radius(k1, k2, k3), 1.0)
    if _radial_slope(r, k1, k2, k3) < 0.25:
        return
    xy = r * np.array([[np.cos(angle), np.sin(angle)]])
    xy_d = distort_normalized(xy, k1, k2, p1, p2, k3)
    back = undistort_normalized(xy_d, k1, k2, p1, p2, k3)
    tol = 16 * np.finfo(float).eps * max(1.0, float(np.abs(xy_d).max()))
    np.testing.assert_allclose(distort_normalized(back, k1, k2, p1, p2, k3), xy_d, rtol=0, atol=tol)
    cam = CameraModel((2, 2), 1.0, 1.0, 0.0, 0.0, 0.0, k1, k2, p1, p2, k3, model="k1k2p1p2k3")
    _, J_X, _ = project_with_jacobians(cam, np.array([[*xy[0], 1.0]]))
    sigma_min = np.linalg.svd(J_X[0, :, :2], compute_uv=False)[-1]
    np.testing.assert_allclose(back, xy, rtol=0, atol=4 * tol / sigma_min)


@settings(max_examples=200, deadline=None)
@given(k1=st.floats(-1.0, 1.0), k2=st.floats(-1.0, 1.0), k3=st.floats(-1.0, 1.0))
def test_max_monotonic_radius_with_k3_is_the_first_root_of_the_slope(k1, k2, k3):
    """The radial part r (1 + k1 r^2 + k2 r^4 + k3 r^6) increases up to the radius, where its slope
    vanishes (inf: everywhere up to 10 here)."""
    r_max = max_monotonic_radius(k1, k2, k3)
    if r_max < 1e6:                                # (beyond, the terms overflow)
        terms = 1 + 3 * abs(k1) * r_max**2 + 5 * abs(k2) * r_max**4 + 7 * abs(k3) * r_max**6
        assert abs(_radial_slope(r_max, k1, k2, k3)) <= 1e-9 * terms
    r = np.linspace(0.0, min(r_max, 10.0), 2001)[:-1]
    assert np.all(_radial_slope(r, k1, k2, k3) > 0)
    assert max_monotonic_radius(k1, k2, 0.0) == max_monotonic_radius(k1, k2)


def test_a_tangential_lens_that_folds_is_a_named_error():
    """p1 = 0.3 (150 times a real lens'): the tangential terms fold the image where y < -0.56
    (the Jacobian's determinant (1 + 2 p1 y)(1 + 6 p1 y) - 4 p1^2 x^2 changes sign) although the
    radial part is the identity; the image check says so. A point no ideal point reaches from the
    radial start is a named error too."""
    folding = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, p1=0.3, model="k1k2p1p2")
    with pytest.raises(NotInvertibleError, match="p1=0.3 folds over inside the image: its tangential terms"):
        check_invertible_in_image(folding)
    with pytest.raises(NotInvertibleError, match="did not converge"):
        undistort_normalized(np.array([[0.0, -2.0]]), *folding.distortion)
    inside = CameraModel((640, 480), 800.0, 800.0, 0.0, 320.0, 240.0, p1=0.3, model="k1k2p1p2")  # |y| <= 0.3
    check_invertible_in_image(inside)
    check_invertible_in_image(CAM5)
    # and a radial fold inside the image is still found first, with the coefficients named
    radial = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.6, 0.0, 0.001, 0.0, 0.0, model="k1k2p1p2k3")
    with pytest.raises(NotInvertibleError, match="k1=-0.6, k2=0 folds over inside the image: radius not monotonic"):
        check_invertible_in_image(radial)


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


@pytest.mark.parametrize("cam", [CAM, CAM5], ids=["k1k2", "k1k2p1p2k3"])
def test_unmeasured_points_stay_unmeasured(cam):
    xy = np.array([[0.1, 0.2], [np.nan, np.nan], [-0.3, 0.05]])
    back = undistort_normalized(distort_normalized(xy, *cam.distortion), *cam.distortion)
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
    from dualcal.geometry.camera import ideal_normalized_from_pixel
    from dualcal.geometry.model import Pose
    from dualcal.geometry.rotation import rotation_from_rotvec
    Xc = Pose(rotation_from_rotvec(np.array(rotvec)), np.array(t)).apply(np.array([[X[0], X[1], 0.0]]))
    xy = Xc[:, :2] / Xc[:, 2:]
    if Xc[0, 2] <= 0 or np.hypot(*xy[0]) >= 0.99 * max_monotonic_radius(CAM.k1, CAM.k2):
        return
    uv = project_points(CAM, Xc)
    np.testing.assert_allclose(ideal_normalized_from_pixel(CAM, uv), xy, atol=1e-10)


# ----------------------------------------------------------------------------- the fisheye kb4

#: A 145-degree (diagonal) fisheye on a 12 MP sensor, OpenCV's cv2.fisheye coefficients.
FISH = CameraModel((3024, 4032), 1450.0, 1449.0, 0.0, 1508.0, 2022.0, 0.2, 0.02, k3=-0.005, k4=0.001, model="kb4")


def _rays(rng, n, max_deg):
    """``n`` camera-frame points (N, 3) in random directions up to ``max_deg`` from the axis."""
    theta, phi = np.radians(rng.uniform(0, max_deg, n)), rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]) \
        * rng.uniform(100, 5000, n)[:, None]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_kb4_projects_like_cv2_fisheye(seed):
    """cv2.fisheye.projectPoints of random fisheyes (skew as OpenCV's alpha = skew / fx), 500 points up
    to 60 degrees from the axis: the same pixels to 1e-9 px."""
    rng = np.random.default_rng(seed)
    fx = rng.uniform(300, 3000)
    cam = CameraModel((4000, 3000), fx, fx * rng.uniform(0.98, 1.02), rng.uniform(-2, 2), rng.uniform(1900, 2100),
                      rng.uniform(1400, 1600), *rng.uniform(-0.05, 0.05, 2), k3=rng.uniform(-0.01, 0.01),
                      k4=rng.uniform(-0.002, 0.002), model="kb4")
    X = _rays(rng, 500, 60.0)
    ours = project_points(cam, X)
    theirs, _ = cv2.fisheye.projectPoints(X.reshape(1, -1, 3), np.zeros(3), np.zeros(3), cam.K * [[1, 0, 1], [0, 1, 1],
                                          [0, 0, 1]], np.array(cam.distortion).reshape(4, 1), alpha=cam.skew / cam.fx)
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), rtol=0, atol=1e-9)
    np.testing.assert_allclose(project_with_jacobians(cam, X)[0], ours, rtol=0, atol=1e-9)


def test_kb4_jacobians_match_central_differences():
    rng = np.random.default_rng(1)
    cam = replace(FISH, skew=1.5)
    X = np.vstack([_rays(rng, 30, 70.0), [[0.0, 0.0, 800.0], [1e-9, 0.0, 800.0]]])     # the axis too
    # p1, p2, the radial-tangential lens's alone, have no column in a fisheye
    _assert_jacobians_are_differences(cam, X, "kb4", absent=("p1", "p2"), h_mm=1e-3, atol_X=1e-6, atol_K=1e-5)


def test_kb4_undistorts_like_cv2_fisheye_and_round_trips():
    """Over the whole image; OpenCV's undistortPoints clamps theta_d at pi / 2 (the image's corners
    here reach 1.74), so it is compared inside that radius."""
    w, h = FISH.image_size
    uv = np.stack(np.meshgrid(np.linspace(0, w - 1, 40), np.linspace(0, h - 1, 50)), axis=-1).reshape(-1, 2)
    ours = ideal_normalized_from_pixel(FISH, uv)
    theirs = cv2.fisheye.undistortPoints(uv.reshape(1, -1, 2), FISH.K, np.array(FISH.distortion).reshape(4, 1))
    inside = np.hypot(*normalized_from_pixel(FISH, uv).T) < np.pi / 2
    assert inside.mean() > 0.9
    np.testing.assert_allclose(ours[inside], theirs.reshape(-1, 2)[inside], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(distort_points(FISH, undistort_points(FISH, uv)), uv, rtol=0, atol=1e-8)


def test_kb4_sees_at_and_beyond_90_degrees_but_does_not_undistort_there():
    """Rays at 90 and 100 degrees project (on the atan2 angle) and come back as rays; they have no
    point on the normalised plane, so undistortion refuses them, and an image that reaches them
    is not invertible."""
    X = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -np.tan(np.radians(10))], [0.3, 0.4, 0.0]])
    uv = project_points(FISH, X)
    theta = np.radians([90.0, 100.0, 90.0])
    rd = theta * (1 + FISH.k1 * theta**2 + FISH.k2 * theta**4 + FISH.k3 * theta**6 + FISH.k4 * theta**8)
    np.testing.assert_allclose(np.hypot(*(normalized_from_pixel(FISH, uv)).T), rd, rtol=1e-12)
    rays = ray_directions(FISH, normalized_from_pixel(FISH, uv))
    np.testing.assert_allclose(rays, X / np.linalg.norm(X, axis=1)[:, None], atol=1e-12)
    with pytest.raises(NotInvertibleError, match="90 degrees"):
        undistort(FISH, normalized_from_pixel(FISH, uv[:1]))
    check_invertible_in_image(FISH)                               # 73 degrees at the image's corners
    with pytest.raises(NotInvertibleError, match="90 degrees from its axis, inside the image"):
        check_invertible_in_image(replace(FISH, fx=1000.0, fy=1000.0))


def test_kb4_fold_is_the_first_root_of_the_slope():
    k = (-0.3, 0.02, 0.0, 0.0)
    t = fisheye_max_angle(*k)
    slope = lambda s: 1 + 3 * k[0] * s**2 + 5 * k[1] * s**4  # noqa: E731
    assert abs(slope(t)) < 1e-12 and slope(0.99 * t) > 0
    cam = replace(FISH, k1=k[0], k2=k[1], k3=0.0, k4=0.0)
    assert fold_radius(cam) == pytest.approx(np.tan(t))
    with pytest.raises(NotInvertibleError):
        check_invertible_in_image(cam)
    assert fisheye_max_angle(0.0, 0.0) == np.pi                   # equidistant: no fold before 180 degrees


def test_the_radial_lens_gradient_is_the_outward_motion_per_coefficient():
    """Against central differences, in a radial-tangential model and in the fisheye one."""
    from dualcal.geometry.camera import radial_lens_gradient

    X = np.array([0.4, -0.3, 1.0])
    for cam in (CameraModel((4000, 3000), 3000.0, 3001.0, 0.0, 2010.0, 1490.0, 0.05, -0.1, 0.001, -0.002, 0.02,
                            model="k1k2p1p2k3"),
                CameraModel((4000, 3000), 1500.0, 1500.0, 0.0, 2000.0, 1500.0, 0.1, 0.01, k3=-0.003, k4=0.001, model="kb4")):
        names = LENS_MODELS[cam.model]
        outward = project_points(cam, X[None])[0] - [cam.cx, cam.cy]
        outward /= np.linalg.norm(outward)
        h = 1e-6
        numeric = [outward @ (project_points(replace(cam, **{n: getattr(cam, n) + h}), X[None])[0]
                              - project_points(replace(cam, **{n: getattr(cam, n) - h}), X[None])[0]) / (2 * h)
                   for n in names]
        assert np.allclose(radial_lens_gradient(cam, X, names), numeric, rtol=1e-6, atol=1e-6)


def test_the_fold_of_a_cubic_lens_is_brents_root():
    """The first root of the slope of a k1 k2 k3 lens, found without scipy, is scipy's brentq root on the
    same bracket to a few rounding errors, down to a k3 so small that the cubic's other roots are 1e15
    times further out."""
    from scipy.optimize import brentq

    from dualcal.geometry.camera import _first_positive_root

    rng = np.random.default_rng(3)
    for k1, k2, k3 in [(-0.3, 0.1, -1e-40), (-1.0, 0.0, 1e-12), (0.0, 0.0, -1e-30),
                       *zip(rng.uniform(-1, 1, 300), rng.uniform(-1, 1, 300),
                            rng.choice([-1, 1], 300) * 10.0 ** rng.uniform(-30, 0, 300))]:
        c1, c2, c3 = 3 * k1, 5 * k2, 7 * k3
        s = _first_positive_root(c1, c2, c3)
        if np.isfinite(s):
            P = lambda x: 1 + x * (c1 + x * (c2 + c3 * x))          # noqa: E731
            ref = brentq(P, 0.999 * s, 1.001 * s, xtol=1e-300, rtol=4 * np.finfo(float).eps)
            assert abs(s - ref) <= 1e-14 * ref
