"""What one photo of a board tells alone (dualcal.geometry.one_view): the focal length, the lens's bend, the pose;
its lens with its sigmas (view_lens), honest where the principal point is known, which its camera's photos tell."""

import numpy as np
import pytest

from dualcal.geometry.division import common_division, undistort_division
from dualcal.geometry.homography import estimate_homography
from dualcal.geometry.one_view import PRINCIPAL_POINT_SIGMA, board_pose, focal_from_homography, one_view, view_lens
from dualcal.synthetic import synth


@pytest.fixture(scope="module")
def views():
    """True corners (0.1 px of noise) of every camera of the three-lens presets: a kb4 fisheye ultra-wide, a
    wide and a tele (phone3) and three mild lenses (triple), with the boards' tilts."""
    rng = np.random.default_rng(0)
    out = []
    for preset in ("phone3", "triple"):
        truth = synth.make_truth(preset, views=10, seed=1, scale=0.25)
        xy = truth.board.object_points_mm()[:, :2]
        for cam, per_view in synth.true_corners(truth).items():
            for view, uv in per_view.items():
                if np.isfinite(uv).all():
                    tilt = np.degrees(np.arccos(abs(truth.camera_pose(cam, view).R[2, 2])))
                    noisy = uv + rng.normal(0, 0.1, uv.shape)
                    out.append((preset, cam, truth.cameras[cam], xy, noisy, tilt, truth.camera_pose(cam, view),
                                one_view(xy, noisy, truth.cameras[cam].image_size)))
    return out


def test_the_focal_length_of_a_pinhole_view_is_exact():
    f, size = 1200.0, (1600, 1200)
    K = np.array([[f, 0, 799.5], [0, f, 599.5], [0, 0, 1]])
    R = synth._look_at_pose(np.array([300.0, -200.0, -900.0]), np.zeros(3), 0.3).R
    t = -R @ np.array([300.0, -200.0, -900.0])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    assert focal_from_homography(H, size) == pytest.approx(f, rel=1e-9)
    H_square_on = K @ np.column_stack([[1, 0, 0], [0, 1, 0], [0, 0, 900.0]])
    assert np.isnan(focal_from_homography(H_square_on, size))        # a board seen square-on gives none


def test_one_view_gives_the_focal_length_within_its_spread_where_the_board_is_tilted(views):
    """At least 20 degrees of tilt: every camera's focal length within 15 % (the fisheye's too, through the
    division model), and within 3 of its spreads (the measured one and 8 % for the model) for nine in ten."""
    errors, z = [], []
    for preset, name, cam, xy, uv, tilt, _, v in views:
        if tilt >= 20:
            e = np.log(v.f_px / cam.fx)
            errors.append(abs(e))
            z.append(abs(e) / np.hypot(v.f_log_sigma, 0.08))
    assert len(errors) > 20 and max(errors) < 0.15, max(errors)
    assert np.mean(np.array(z) < 3) > 0.9


def test_the_division_model_straightens_a_fisheye(views):
    fisheye = [(xy, uv) for preset, name, cam, xy, uv, *_ in views if preset == "phone3" and name == "ultra"]
    size = next(cam.image_size for preset, name, cam, *_ in views if name == "ultra")
    lam = common_division(fisheye[0][0], [uv for _, uv in fisheye], size)
    assert -0.9 < lam < -0.2                                       # a kb4 at 120 degrees bends a lot
    bent = [one_view(xy, uv, size, 0.0).misfit_px for xy, uv in fisheye]
    straight = [one_view(xy, uv, size, lam).misfit_px for xy, uv in fisheye]
    worst = int(np.argmax(bent))                                  # the board nearest the fisheye's edge
    assert straight[worst] < 0.5 * bent[worst] and np.median(straight) <= np.median(bent)
    uv = np.array([[10.0, 20.0], [700.0, 900.0]])
    np.testing.assert_allclose(undistort_division(uv, 0.0, size), uv)


def test_the_pose_of_one_view_is_near_the_truth(views):
    for preset, name, cam, xy, uv, tilt, pose, _ in views:
        if preset == "triple" and name == "tele":
            v = one_view(xy, uv, cam.image_size, 0.0)
            R = board_pose(v, cam.fx).R
            angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ pose.R) - 1) / 2, -1, 1)))
            assert angle < 3.0, (tilt, angle)


def test_a_view_with_too_few_corners_tells_nothing():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    assert one_view(xy, xy * 100 + 50, (640, 480)) is None
    H = estimate_homography(xy, xy * 100 + 50)
    assert np.isnan(focal_from_homography(H, (640, 480)))


@pytest.fixture(scope="module")
def shared_size_views():
    """A fisheye ultra-wide (1130 px) and a wide (1340 px) of one size, 2016 x 1512 at a quarter, 16 positions,
    0.1 px of noise: each photo's lens (view_lens) with its truth."""
    from dualcal.synthetic.synth_roll import shared_size_rig

    truth = synth.make_truth(shared_size_rig({"wide": 1340.0, "ultra": 1130.0}), views=16, seed=5, scale=0.25)
    xy = truth.board.object_points_mm()[:, :2]
    rng = np.random.default_rng(5)
    return {name: (truth.cameras[name], [view_lens(xy, uv + rng.normal(0, 0.1, uv.shape), truth.cameras[name].image_size)
                                         for uv in per.values() if np.isfinite(uv).all()])
            for name, per in synth.true_corners(truth).items()}


def _true_pp(cam):
    """A camera's principal point as view_lens's offset from the image centre, in half-diagonals."""
    return (np.array([cam.cx, cam.cy]) - (np.asarray(cam.image_size) - 1) / 2) / (0.5 * np.hypot(*cam.image_size))


def test_one_views_lens_is_honest_where_the_principal_point_is_known(shared_size_views):
    """Given its camera's true principal point, each photo's ln f lies within its sigma of the truth as a normal
    would (the z-scores' RMS 0.5-1.3, none beyond 4), and its bend tells the fisheye (lam about -0.4) from the
    wide (about 0) by many of its sigmas."""
    for name, (cam, views) in shared_size_views.items():
        z = []
        for v in views:
            (ln_f, lam), cov = v.given(_true_pp(cam), np.zeros((2, 2)))
            z.append((ln_f - np.log(cam.fx)) / np.sqrt(cov[0, 0]))
            lam_sigma = np.sqrt(cov[1, 1])
            if name == "ultra" and lam_sigma < 0.1:                  # a board that reaches where the lens bends
                assert lam < -0.25, (lam, lam_sigma)
            elif name == "wide":
                assert abs(lam) < 0.15 + 3 * lam_sigma, (lam, lam_sigma)
        rms = float(np.sqrt(np.mean(np.square(z))))
        assert 0.5 < rms < 1.3 and np.max(np.abs(z)) < 4, (name, rms, z)


def test_the_photos_of_one_lens_tell_its_principal_point_together(shared_size_views):
    """Each lens's photos together put its principal point within 3 of its sigmas of the truth, surer than the prior;
    a photo's focal length at that point is surer than at the prior's (the prior's 2 % of the half-diagonal is most
    of one photo's uncertainty)."""
    from dualcal.files.roll_lenses import _prior, shared_principal_point

    for name, (cam, views) in shared_size_views.items():
        pp, cov = shared_principal_point(views, np.arange(len(views)))
        sigma = np.sqrt(np.diag(cov))
        assert np.all(np.abs(pp - _true_pp(cam)) < 3 * sigma) and np.all(sigma < 0.5 * PRINCIPAL_POINT_SIGMA), \
            (name, pp, _true_pp(cam), sigma)
        sharper = [v.given(pp, cov)[1][0, 0] < v.given(*_prior())[1][0, 0] for v in views]
        assert np.mean(sharper) > 0.9
