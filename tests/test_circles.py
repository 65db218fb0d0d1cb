"""Circle grids and targets given by their points: layout, the circles' image centres, detection on renders,
the outline model's fixed point, calibrations from a target's points, the files."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from dualcal.errors import InputError
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.circle_centres import fit_circle_outlines, outline_offsets
from dualcal.estimation.fitting import Setup
from dualcal.estimation.rig_relations import parameter_covariance
from dualcal.files.detect.circles import detect_circles
from dualcal.files.io import load_corners, save_corners
from dualcal.geometry.board import Board, board_from_spec
from dualcal.geometry.camera import CameraModel, project_points
from dualcal.geometry.circles import circle_centre_offset_px, circle_image_centre, outline_centroid_px
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_rotvec
from dualcal.synthetic.render import render_view
from dualcal.synthetic.synth import make_truth, noisy_corner_set, scale_camera
from dualcal.workflow import check_board

ACIRCLES = Board.circle_grid("acircles", 4, 11, 20.0, 10.0)
CAMERA_12MP = CameraModel((4000, 3000), 3200.0, 3200.0, 0.0, 1990.0, 1510.0, 0.06, -0.15)


def _pose(rotvec_deg, t_mm) -> Pose:
    return Pose(rotation_from_rotvec(np.radians(rotvec_deg)), np.asarray(t_mm, float))


# ------------------------------------------------------------------------------------------------- layout

def test_layout_is_opencvs():
    """OpenCV's sample (calibration.cpp) puts asymmetric point (i row, j column) at ((2j + i % 2) s, i s, 0),
    symmetric ones at (j s, i s, 0), in row-major order."""
    X = board_from_spec("acircles:4x11", 15.0).object_points_mm()
    assert X.shape == (44, 3)
    np.testing.assert_array_equal(X[:6, :2], [[0, 0], [30, 0], [60, 0], [90, 0], [15, 15], [45, 15]])
    np.testing.assert_array_equal(X[-1, :2], [(2 * 3 + 10 % 2) * 15, 10 * 15])
    S = board_from_spec("circles:7x5", 25.0, circle_mm=12).object_points_mm()
    np.testing.assert_array_equal(S[8, :2], [25, 25])
    assert board_from_spec("circles:7x5", 25.0).circle_diameter_mm == pytest.approx(10.0)      # gen_pattern's default
    assert ACIRCLES.is_symmetric is False and Board.circle_grid("acircles", 4, 10, 20.0).is_symmetric
    with pytest.raises(InputError, match="smaller than the distance"):
        board_from_spec("circles:7x5", 25.0, circle_mm=25.0)
    with pytest.raises(InputError, match="--circle describes a circle grid"):
        board_from_spec("8x5", 25.0, circle_mm=5.0)


# ------------------------------------------------------------------------------- the circles' image centres

def test_image_centre_is_the_outlines_centre():
    """The closed form against the centroid of the projected outline, 256 points: exact for a pinhole camera (an
    ellipse); with a lens, the distortion's curvature over a circle is what the closed form leaves out."""
    centres = ACIRCLES.object_points_mm()
    pose = _pose([48, 12, 4], [-70, -110, 520])
    pinhole = CameraModel((4000, 3000), 3200.0, 3200.0, 0.0, 1990.0, 1510.0)
    offset = circle_centre_offset_px(pinhole, pose, centres, 5.0)
    assert np.max(np.hypot(*offset.T)) > 0.15                      # the bias is there to be modelled
    exact = outline_centroid_px(pinhole, pose, centres, 5.0)
    np.testing.assert_allclose(circle_image_centre(pinhole, pose, centres, 5.0), exact, atol=1e-5)
    # a fronto-parallel board: no bias at all
    np.testing.assert_allclose(circle_centre_offset_px(pinhole, _pose([0, 0, 30], [0, 0, 500]), centres, 5.0), 0,
                               atol=1e-9)
    lens = outline_centroid_px(CAMERA_12MP, pose, centres, 5.0) - circle_image_centre(CAMERA_12MP, pose, centres, 5.0)
    assert np.max(np.hypot(*lens.T)) < 0.05 * np.max(np.hypot(*offset.T))


# ---------------------------------------------------------------------------------------------- detection

def _rms(a, b) -> float:
    return float(np.sqrt(np.nanmean(np.sum((a - b) ** 2, axis=1))))


def opencv_centres(img, board):
    """OpenCV's findCirclesGrid at full size, as a user sets it: its default blob detector but for the largest blob
    (5000 px^2 by default: a 12 MP photo's circles are larger); the clustering variant where the plain one fails."""
    params = cv2.SimpleBlobDetector_Params()
    params.maxArea = 1e6
    kind = cv2.CALIB_CB_ASYMMETRIC_GRID if board.pattern == "acircles" else cv2.CALIB_CB_SYMMETRIC_GRID
    for flags in (kind, kind | cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(img, (board.cols, board.rows), flags=flags,
                                             blobDetector=cv2.SimpleBlobDetector_create(params))
        if found:
            return centres.reshape(-1, 2).astype(float)
    return None


@pytest.mark.parametrize("scale, board, pose", [
    (0.5, ACIRCLES, _pose([35, -20, 80], [-60, -120, 420])),                                # 3 MP
    (1.0, ACIRCLES, _pose([-10, 50, -30], [-70, -100, 560])),                              # 12 MP
    (0.5, Board.circle_grid("circles", 7, 5, 25.0), _pose([30, 25, 170], [60, 40, 560])),  # symmetric, 3 MP
])
def test_detection_beats_opencv(scale, board, pose):
    """Every centre found, numbered as the contract says, closer to the true centre of its image (the outline's
    area centroid) than OpenCV's findCirclesGrid at full size on the same render."""
    cam = scale_camera(CAMERA_12MP, scale)
    img = render_view(cam, pose, board, np.random.default_rng(3))
    truth = outline_centroid_px(cam, pose, board.object_points_mm(), 0.5 * board.circle_diameter_mm)
    uv, ambiguous = detect_circles(img, board)
    assert ambiguous == board.is_symmetric
    if ambiguous and _rms(uv, truth) > 1:                           # the other of the two numberings
        uv = uv[::-1]
    assert np.isfinite(uv).all()
    theirs = opencv_centres(img, board)
    assert theirs is not None
    theirs = theirs[np.argmin(np.hypot(*(theirs[:, None] - truth[None]).transpose(2, 0, 1)), axis=0)]
    ours_px, opencv_px = _rms(uv, truth), _rms(theirs, truth)
    assert ours_px < opencv_px and ours_px < 0.05, (ours_px, opencv_px)


def test_a_target_of_points_is_not_detected():
    board = Board.from_points([[0, 0], [50, 0], [0, 40], [60, 50], [20, 10]])
    with pytest.raises(InputError, match="cannot be detected"):
        detect_circles(np.zeros((100, 100), np.uint8), board)


# ---------------------------------------------------------------------------------------- the outline model

def _outline_blocks(truth, board, noise_px, seed):
    rng = np.random.default_rng(seed)
    cam = truth.cameras["left"]
    X = board.object_points_mm()
    return [(0, v, circle_image_centre(cam, truth.camera_pose("left", v), X, 0.5 * board.circle_diameter_mm)
             + rng.normal(0.0, noise_px, (len(X), 2))) for v in truth.view_poses]


def test_fixed_point_removes_the_bias():
    """Centres measured as the circles' image centres (no noise): the point model's focal length is biased by the
    perspective offsets; the fixed point recovers the true one to what its 1e-4 px tolerance leaves."""
    board = Board.circle_grid("acircles", 4, 11, 20.0, 13.0)
    truth = make_truth("stereo", views=10, seed=4, board=board, min_tilt_deg=35, max_tilt_deg=60)
    cam = truth.cameras["left"]
    blocks = _outline_blocks(truth, board, 0.0, 0)
    setup = Setup(board.object_points_mm(), ["left"], [cam.image_size], 0, False, "none", "k1k2")
    first = setup.solve(blocks)
    fit = fit_circle_outlines(lambda b, start: setup.solve(b, start), blocks, first, board)
    assert fit.converged and fit.iterations <= 4 and fit.change_px < 1e-4
    fx_point = first.state.camera(first.problem, 0).fx
    fx_outline = fit.solution.state.camera(fit.solution.problem, 0).fx
    assert abs(fx_point - cam.fx) > 0.05                        # biased: 0.1 px here (0.02 %)
    assert abs(fx_outline - cam.fx) < 0.005 and fit.solution.s0_px < 1e-4
    # its offsets are those of its own solution
    again = outline_offsets(fit.solution, board)
    assert max(np.max(np.abs(again[k] - fit.offsets_px[k])) for k in again) == 0.0


def test_fixed_point_is_the_outline_models_least_squares():
    """With noise the fixed point (the point model's normal equations at the outline residuals) and the outline
    model's own least-squares solution (scipy on its residuals, from there) agree to a small share of the sigma."""
    least_squares = pytest.importorskip("scipy.optimize").least_squares
    board = Board.circle_grid("acircles", 4, 11, 20.0, 13.0)
    truth = make_truth("stereo", views=8, seed=5, board=board, min_tilt_deg=35, max_tilt_deg=60)
    cam0 = truth.cameras["left"]
    blocks = _outline_blocks(truth, board, 0.1, 1)
    setup = Setup(board.object_points_mm(), ["left"], [cam0.image_size], 0, False, "none", "k1k2")
    fit = fit_circle_outlines(lambda b, start: setup.solve(b, start), blocks, setup.solve(blocks), board)
    sol = fit.solution
    cam = sol.state.camera(sol.problem, 0)
    views = [v for _, v, _ in blocks]
    X = board.object_points_mm()

    def unpack(p):
        c = CameraModel(cam.image_size, p[0], p[1], 0.0, p[2], p[3], p[4], p[5], model="k1k2")
        return c, [Pose(rotation_from_rotvec(p[6 + 6 * i: 9 + 6 * i]), p[9 + 6 * i: 12 + 6 * i])
                   for i in range(len(views))]

    def residuals(p):
        c, poses = unpack(p)
        return np.concatenate([(circle_image_centre(c, q, X, 0.5 * board.circle_diameter_mm) - uv).ravel()
                               for q, (_, _, uv) in zip(poses, blocks)])

    start = [cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.k2]
    for v in views:
        pose = sol.photo_poses[(0, v)]
        start += list(cv2.Rodrigues(pose.R)[0].ravel()) + list(pose.t_mm)
    best = least_squares(residuals, np.array(start), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    names, covs = parameter_covariance(sol, ("formal",))
    sigma_fx = float(np.sqrt(covs["formal"][names.index("left.fx"), names.index("left.fx")]))
    assert abs(best.x[0] - cam.fx) < 0.002 * sigma_fx, (best.x[0] - cam.fx, sigma_fx)     # 1e-4 sigma here


def test_calibrate_rig_removes_the_bias_of_a_circle_grid():
    """Through the pipeline: a stereo rig's circle centres measured as the circles' image centres (noise-free).
    As a circle grid its focal lengths come back to 0.01 px (the outline stage of calibrate_rig, recorded in
    ``adjustment.circle_centres``); the same centres given as a target's points (the point model) are biased."""
    board = Board.circle_grid("acircles", 4, 11, 20.0, 13.0)
    truth = make_truth("stereo", views=10, seed=4, board=board, min_tilt_deg=35, max_tilt_deg=60)
    corners = noisy_corner_set(truth, 0.0)
    rig = calibrate_rig(corners, rig_mode="rigid", lens_motion=False)
    record = rig.adjustment["circle_centres"]
    assert record["converged"] and record["largest_offset_px"] > 0.05
    points = replace(corners, board=Board.from_points(board.object_points_mm(), square_mm=board.square_mm))
    as_points = calibrate_rig(points, rig_mode="rigid", lens_motion=False)
    assert "circle_centres" not in as_points.adjustment
    for name, cam in truth.cameras.items():
        assert abs(rig.cameras[name].fx - cam.fx) < 0.01, name
        assert abs(as_points.cameras[name].fx - cam.fx) > 0.05, name


# ---------------------------------------------------------------------------------- targets given by points

def test_a_target_given_by_its_points_calibrates(tmp_path):
    """A planar layout of 40 scattered points (no grid): Zhang's closed form and the adjustment need only planar
    points; the rig comes back within its sigmas of the truth, through corners.json."""
    rng = np.random.default_rng(2)
    board = Board.from_points(rng.uniform([0, 0], [240, 160], (40, 2)))
    truth = make_truth("stereo", views=12, seed=3, board=board)
    save_corners(tmp_path / "corners.json", noisy_corner_set(truth, 0.1, seed=1))
    corners = load_corners(tmp_path / "corners.json")
    assert corners.board == board and corners.board.spec() == "points:40"
    rig = calibrate_rig(corners, rig_mode="rigid")
    for name, cam in truth.cameras.items():
        for key in ("fx", "fy", "cx", "cy"):
            err = getattr(rig.cameras[name], key) - getattr(cam, key)
            assert abs(err) < 4 * rig.camera_sigma[name][key], (name, key, err, rig.camera_sigma[name][key])
    t_true = truth.rig["right"].t_mm
    assert np.all(np.abs(rig.rig["right"].pose.t_mm - t_true) < 4 * rig.rig["right"].sigma_t_mm + 1e-9)


def test_board_entries_round_trip(tmp_path):
    """corners.json keeps a circle grid's pattern and circle diameter and a target's points; bad entries say why."""
    for board in (ACIRCLES, Board.circle_grid("circles", 7, 5, 25.0, square_sigma_mm=0.05),
                  Board.from_points([[0, 0, 0], [50, 0, 0], [0, 40, 0], [60, 50, 0]], square_mm=10.0)):
        assert board.matches(Board.from_dict(board.to_dict()))
        assert Board.from_dict(board.to_dict()).to_dict() == board.to_dict()
    truth = make_truth("stereo", views=3, seed=1, board=ACIRCLES)
    save_corners(tmp_path / "c.json", noisy_corner_set(truth, 0.0))
    loaded = load_corners(tmp_path / "c.json")
    assert loaded.board == ACIRCLES and loaded.board.circle_mm == 10.0
    # a board given without --circle is the file's, whatever its diameter; with another one it is not
    assert check_board(board_from_spec("acircles:4x11", 20.0), loaded.board, "c.json") == loaded.board
    with pytest.raises(InputError, match="disagrees with c.json"):
        check_board(board_from_spec("acircles:4x11", 20.0, circle_mm=8.0), loaded.board, "c.json")
    for entry, message in (({"points_mm": [[0, 0], [1, 0], [2, 0], [3, 0]]}, "one line"),
                           ({"points_mm": [[0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}, "its plane"),
                           ({"cols": 4, "rows": 11, "square_mm": 20, "pattern": "hexagons"}, "pattern"),
                           ({"cols": 4, "rows": 11, "square_mm": 20, "pattern": "acircles", "circle_mm": "8"},
                            "circle_mm")):
        with pytest.raises(InputError, match=message):
            Board.from_dict(entry)


def test_printed_circles_at_true_scale(tmp_path):
    """The PNG of `dualcal board acircles:4x11` at 100 dpi: each circle's centroid where the layout puts the board's
    point, and its area that of a circle of the given diameter (to a pixel's share)."""
    pytest.importorskip("matplotlib")
    from dualcal.files.boardprint import write_board

    dpi = 100.0
    layout = write_board(ACIRCLES, tmp_path / "b.png", dpi=dpi)
    img = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    px = dpi / 25.4
    expected = (ACIRCLES.object_points_mm()[:, :2] + layout.origin_mm) * px - 0.5
    dark = 1.0 - img.astype(float) / 255.0
    r = int(np.ceil(0.5 * ACIRCLES.circle_mm * px)) + 2
    for u, v in expected:
        u0, v0 = int(round(u)), int(round(v))
        win = dark[v0 - r: v0 + r + 1, u0 - r: u0 + r + 1]
        vv, uu = np.mgrid[v0 - r: v0 + r + 1, u0 - r: u0 + r + 1]
        centroid = np.array([np.sum(win * uu), np.sum(win * vv)]) / win.sum()
        assert np.hypot(*(centroid - (u, v))) < 0.05
        assert win.sum() == pytest.approx(np.pi / 4 * (ACIRCLES.circle_mm * px) ** 2, rel=0.01)
