"""Space resection of one photo (dualcal.geometry.resection): which corners fix a homography, and the planar pose
from partial views as peers' ChArUco sessions have them (the rig resection is tested in test_evaluation.py)."""

import itertools

import numpy as np
import pytest
from scipy.optimize import least_squares

from dualcal.errors import EstimationError
from dualcal.geometry.camera import CameraModel, project_points
from dualcal.geometry.model import Pose
from dualcal.geometry.resection import fixes_homography, planar_pose, resect
from dualcal.geometry.rotation import rotation_from_rotvec, rotvec_from_rotation
from dualcal.synthetic.synth import seen_pixels
from dualcal.synthetic.synth_caliscope import CALISCOPE_BOARD

#: caliscope's 12-corner board (3 x 4 inner corners, 54 mm) and one of its webcams (1280 x 720, OpenCV's lens).
X_BOARD = CALISCOPE_BOARD.object_points_mm()
WEBCAM = CameraModel((1280, 720), 884.7, 886.1, 0.0, 633.0, 366.8, -0.254, 0.102, -0.0009, 0.0021, -0.013,
                     model="k1k2p1p2k3")


def _no_three_on_a_line(xy: np.ndarray) -> bool:
    """The definition, by brute force: four of the points with no three of them on one line."""
    def collinear(a, b, c):
        return abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) < 1e-9
    return any(not any(collinear(*three) for three in itertools.combinations(four, 3))
               for four in itertools.combinations(xy, 4))


def test_corners_fix_a_homography_where_four_have_no_three_on_a_line():
    """Every subset of 4, 5 or 6 of the board's 12 corners: the DLT's null space says what the definition says (four
    on a row and one off it span a plane, yet fix no homography)."""
    xy = X_BOARD[:, :2]
    checked = 0
    for n in (4, 5, 6):
        for subset in itertools.combinations(range(len(xy)), n):
            assert fixes_homography(xy[list(subset)]) == _no_three_on_a_line(xy[list(subset)]), subset
            checked += 1
    assert checked == 495 + 792 + 924
    assert not fixes_homography(xy[[1, 4, 7, 10, 11]])            # caliscope's cam_2, photos 0035 and 0036
    assert fixes_homography(xy[[0, 3, 7, 10, 11]]) and not fixes_homography(xy[:3])


def _tilted_pose(tilt_deg: float, distance_mm: float, seed: int) -> Pose:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis[2] = 0.0
    R = rotation_from_rotvec(np.radians(tilt_deg) * axis / np.linalg.norm(axis))
    return Pose(R, np.array([rng.uniform(-300, 300), rng.uniform(-150, 150), distance_mm]) - R @ X_BOARD.mean(axis=0))


@pytest.mark.parametrize("corners", [[1, 4, 7, 10, 11], [0, 3, 6, 9, 10], [2, 5, 8, 11, 10], [0, 1, 2, 4],
                                     [3, 4, 5, 7], [0, 1, 4, 5], list(range(12))])
def test_a_partial_view_gets_its_exact_pose(corners):
    """Exact corners of partial views, the board a tenth of the frame: those that fix no homography (four on a row and
    one off it, three on a row and one off it), where IPPE finds no pose, by SQPnP; the others by IPPE."""
    for seed, tilt in enumerate((0.0, 25.0, 50.0)):
        truth = _tilted_pose(tilt, 1800.0, seed)
        uv = np.full((len(X_BOARD), 2), np.nan)
        uv[corners] = seen_pixels(WEBCAM, truth, X_BOARD)[corners]
        pose = planar_pose(X_BOARD, WEBCAM, uv)
        np.testing.assert_allclose(pose.R, truth.R, atol=1e-6)
        np.testing.assert_allclose(pose.t_mm, truth.t_mm, atol=1e-3)


def test_a_partial_view_with_noise_starts_the_resection_in_the_basin_of_its_best_pose():
    """0.3 px of noise on caliscope's cam_2 case (five corners, four on one column, the board a tenth of the frame):
    the pose SQPnP gives, refined by Gauss-Newton (:func:`resect`), is the least-squares pose found from the truth."""
    rng = np.random.default_rng(3)
    for seed in range(10):
        truth = _tilted_pose(30.0, 1500.0, seed)
        uv = np.full((len(X_BOARD), 2), np.nan)
        uv[[1, 4, 7, 10, 11]] = seen_pixels(WEBCAM, truth, X_BOARD)[[1, 4, 7, 10, 11]] + rng.normal(0, 0.3, (5, 2))
        seen = np.isfinite(uv[:, 0])

        def residuals(p):
            return (project_points(WEBCAM, Pose(rotation_from_rotvec(p[:3]), p[3:]).apply(X_BOARD[seen]))
                    - uv[seen]).ravel()

        best = least_squares(residuals, np.concatenate([rotvec_from_rotation(truth.R), truth.t_mm]),
                             xtol=1e-15, ftol=1e-15, gtol=1e-15).x
        pose = resect(X_BOARD, [WEBCAM], [Pose(np.eye(3), np.zeros(3))], [uv])
        np.testing.assert_allclose(rotvec_from_rotation(pose.R), best[:3], atol=1e-7)
        np.testing.assert_allclose(pose.t_mm, best[3:], atol=1e-4 * np.linalg.norm(best[3:]))


def test_fewer_than_four_corners_are_refused():
    uv = np.full((len(X_BOARD), 2), np.nan)
    uv[[0, 4, 8]] = seen_pixels(WEBCAM, _tilted_pose(20.0, 1500.0, 0), X_BOARD)[[0, 4, 8]]
    with pytest.raises(EstimationError, match=r"at least 4 measured corners \(3 given\)"):
        planar_pose(X_BOARD, WEBCAM, uv)
