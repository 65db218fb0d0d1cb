"""Photo-like renders: exact geometry, correct anti-aliasing, bounded-memory bands, photo sets."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from dualcal.geometry.board import Board
from dualcal.geometry.camera import project_points
from dualcal.files.detect.refine import fit_saddles, symmetry_centres
from dualcal.geometry.board import shaped_points_mm
from dualcal.synthetic.render import (PhoneProcessing, _box_mean, _square_wave_integral, board_coordinates, board_height_mm,
                                     defocus_kernel, render_view,
                                     shaped_corners_mm, write_photo_set)
from dualcal.synthetic.synth import make_truth, true_corners


def _grid_directions(uv: np.ndarray, board: Board) -> np.ndarray:
    """(N, 2, 2) unit directions of the grid's rows and columns at every corner (what fit_saddles starts from)."""
    g = uv.reshape(board.rows, board.cols, 2)
    dirs = np.stack([np.gradient(g, axis=1).reshape(-1, 2), np.gradient(g, axis=0).reshape(-1, 2)], 1)
    return dirs / np.linalg.norm(dirs, axis=2, keepdims=True)


def _fit_from_near(img: np.ndarray, uv_true: np.ndarray, board: Board, half: int):
    """``(fit, ok)`` of fit_saddles on ``img`` started 0.3 px (per coordinate, a fixed draw) off the true corners."""
    start = uv_true + np.random.default_rng(2).normal(0, 0.3, uv_true.shape)
    fit, ok, *_ = fit_saddles(img, start, _grid_directions(uv_true, board), half=half)
    return fit, ok


@pytest.fixture(scope="module")
def truth():
    return make_truth("note8", views=2, seed=3, scale=0.5)


def test_box_filtered_square_wave_matches_brute_force_average():
    s, lo, hi = 30.0, -30.0, 240.0
    rng = np.random.default_rng(0)
    x = rng.uniform(-60, 280, 200)
    h = rng.uniform(0.05, 20.0, 200)
    analytic = _box_mean(lambda t: _square_wave_integral(t, s), x, h, lo, hi)
    t = np.linspace(-1, 1, 20001)[None, :] * h[:, None] + x[:, None]
    sq = np.where(np.floor(t / s) % 2 == 0, 1.0, -1.0) * ((t >= lo) & (t <= hi))
    np.testing.assert_allclose(analytic, sq.mean(axis=1), atol=2e-3)


def test_pixels_map_back_to_the_board_points_they_see(truth):
    cam, pose = truth.cameras["tele"], truth.camera_pose("tele", "IMG_01")
    Xb = truth.board.object_points_mm()
    uv = project_points(cam, pose.apply(Xb))
    X, Y, front = board_coordinates(cam, pose, uv[:, 0], uv[:, 1])
    # one (u, v) pair per corner lies on the diagonal of the (B, W) grid
    np.testing.assert_allclose(np.diag(X), Xb[:, 0], atol=1e-9)
    np.testing.assert_allclose(np.diag(Y), Xb[:, 1], atol=1e-9)
    assert np.all(np.diag(front))


@pytest.mark.parametrize("cam_name", ["wide", "tele"])
def test_rendered_corners_sit_exactly_where_the_model_projects_them(truth, cam_name):
    """Renderer bias: a noise-free render, fitted with a large window, gives the truth to < 0.005 px."""
    cam, pose = truth.cameras[cam_name], truth.camera_pose(cam_name, "IMG_02")
    img = render_view(cam, pose, truth.board, np.random.default_rng(1), noise=0.0)
    uv_true = true_corners(truth)[cam_name]["IMG_02"]
    fit, ok = _fit_from_near(img, uv_true, truth.board, half=12)
    assert ok.all()
    err = fit - uv_true
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.005
    assert np.all(np.abs(err.mean(axis=0)) < 0.002)


def test_a_lens_with_tangential_terms_renders_its_corners_where_the_model_projects_them():
    """The stereo pair with OpenCV's five-coefficient lenses (p1 = 0.0018, k3 = 0.238 on the left)."""
    truth = make_truth("stereo5", views=1, seed=3)
    for name, cam in truth.cameras.items():
        pose = truth.camera_pose(name, "IMG_01")
        img = render_view(cam, pose, truth.board, np.random.default_rng(1), noise=0.0)
        uv_true = true_corners(truth)[name]["IMG_01"]
        fit, ok = _fit_from_near(img, uv_true, truth.board, half=8)
        assert ok.all()
        assert np.sqrt(np.mean(np.sum((fit - uv_true) ** 2, axis=1))) < 0.01


def _edge_curl(board: Board, lift_mm: float):
    """A sheet flat on a table but for its last 40 % along X, which curls up to ``lift_mm`` at its far edge."""
    x0, x1 = 0.6 * (board.cols - 1) * board.square_mm, (board.cols - 1) * board.square_mm
    return lambda X, Y: lift_mm * (np.clip(X - x0, 0.0, None) / (x1 - x0)) ** 2


@pytest.mark.parametrize("shape", ["model", "edge"])
def test_a_curled_sheet_renders_its_corners_where_the_model_projects_them(shape):
    """A board that is not flat, seen 55-65 degrees off frontal at 960 x 720: every pixel sees the surface point
    that projects back to it, and a noise-free render's corners are the shaped corners' projections (to the
    0.01-0.02 px the blurred-corner fit reaches in windows of 5 px on flat boards too)."""
    board = Board(9, 6, 25.0)
    truth = make_truth("stereo", views=1, seed=2, scale=1.5, min_tilt_deg=55, max_tilt_deg=65, board=board)
    cam, pose = truth.cameras["left"], truth.camera_pose("left", "IMG_01")
    shape_mm = np.array([6.0, -4.0, 2.0]) if shape == "model" else _edge_curl(board, 12.0)
    X = shaped_corners_mm(board, shape_mm)
    if shape == "model":
        np.testing.assert_allclose(X, shaped_points_mm(board.object_points_mm(), shape_mm), atol=1e-12)
    else:
        assert X[:, 2].max() == pytest.approx(12.0) and X[:, 2].min() == 0.0
    u, v = np.arange(0.0, 960.0, 11.3), np.arange(0.0, 720.0, 9.7)
    Xs, Ys, front = board_coordinates(cam, pose, u, v, board, shape_mm)
    seen = pose.apply(np.stack([Xs, Ys, board_height_mm(board, Xs, Ys, shape_mm)], axis=-1)[front])
    uu, vv = np.meshgrid(u, v)
    assert front.mean() > 0.3
    np.testing.assert_allclose(project_points(cam, seen), np.stack([uu, vv], axis=-1)[front], atol=1e-6)
    img = render_view(cam, pose, board, np.random.default_rng(1), noise=0.0, blur_px=0.6, shape_mm=shape_mm)
    uv_true = project_points(cam, pose.apply(X))
    flat = project_points(cam, pose.apply(board.object_points_mm()))
    assert np.max(np.linalg.norm(uv_true - flat, axis=1)) > 3.0          # the shape moves corners by pixels
    fit, ok = _fit_from_near(img, uv_true, board, half=5)
    assert ok.all()
    assert np.sqrt(np.mean(np.sum((fit - uv_true) ** 2, axis=1))) < 0.02


def test_bands_do_not_change_the_image(truth):
    cam, pose = truth.cameras["wide"], truth.camera_pose("wide", "IMG_01")
    small = replace(cam, image_size=(cam.image_size[0], 700))
    a = render_view(small, pose, truth.board, np.random.default_rng(0), noise=0.0, band_rows=37)
    b = render_view(small, pose, truth.board, np.random.default_rng(0), noise=0.0, band_rows=4096)
    np.testing.assert_array_equal(a, b)


def test_render_shows_a_dark_square_outside_corner_zero_and_white_margin(truth):
    cam, pose = truth.cameras["tele"], truth.camera_pose("tele", "IMG_01")
    img = render_view(cam, pose, truth.board, np.random.default_rng(0), noise=0.0, blur_px=0.0)
    s = truth.board.square_mm
    pts = np.array([[-0.5 * s, -0.5 * s, 0], [0.5 * s, -0.5 * s, 0], [-1.4 * s, 2.5 * s, 0]])
    u, v = np.rint(project_points(cam, pose.apply(pts))).astype(int).T
    dark, light, margin = img[v, u]
    assert dark < 60 < 120 < light and margin > 120


def test_write_photo_set_writes_every_photo_and_does_not_depend_on_jobs(tmp_path):
    truth = make_truth("stereo", views=2, seed=1, scale=0.5)
    one = write_photo_set(truth, tmp_path / "a", seed=5, jobs=1, progress=False)
    two = write_photo_set(truth, tmp_path / "b", seed=5, jobs=2, progress=False)
    assert set(one) == {"left", "right"} and set(one["left"]) == {"IMG_01", "IMG_02"}
    for cam in one:
        for view, path in one[cam].items():
            assert path == tmp_path / "a" / cam / f"{view}.jpg"
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            assert img.shape == (truth.cameras[cam].image_size[1], truth.cameras[cam].image_size[0])
            assert path.read_bytes() == two[cam][view].read_bytes()
    assert not list((tmp_path / "a").rglob(".*"))       # no temporary files left behind


def test_another_board_size_renders_with_its_own_layout():
    truth = make_truth("stereo", views=1, seed=2)
    board = Board(5, 3, 30.0)
    img = render_view(truth.cameras["left"], truth.view_poses["IMG_01"], board, noise=0.0)
    found, corners = cv2.findChessboardCornersSB(img, (5, 3))
    assert found


def test_glare_saturates_its_spot_and_a_shadow_dims_its_side(truth):
    cam, pose = truth.cameras["tele"], truth.camera_pose("tele", "IMG_01")
    W, H = cam.image_size
    plain = render_view(cam, pose, truth.board, np.random.default_rng(0), noise=0.0).astype(float)
    spot = (W / 3, H / 3, 20.0, 1.5)
    glared = render_view(cam, pose, truth.board, np.random.default_rng(0), noise=0.0, glare=[spot]).astype(float)
    u, v = int(spot[0]), int(spot[1])
    assert glared[v, u] == 255 and np.array_equal(glared[:, -50:], plain[:, -50:])
    # the line through the image centre with normal +u: the right half is dimmed by 60 %
    shaded = render_view(cam, pose, truth.board, np.random.default_rng(0), noise=0.0,
                         shadow=(0.0, 0.0, 0.6, 5.0)).astype(float)
    left, right = slice(0, W // 2 - 40), slice(W // 2 + 40, W)
    np.testing.assert_allclose(shaded[:, left], plain[:, left], atol=1.0)
    bright = plain[:, right] > 40
    np.testing.assert_allclose(shaded[:, right][bright] / plain[:, right][bright], 0.4, atol=0.03)


def test_a_planted_corner_is_drawn_where_it_was_moved_and_the_others_stay(truth):
    cam, pose = truth.cameras["wide"], truth.camera_pose("wide", "IMG_02")
    b = truth.board
    uv_true = true_corners(truth)["wide"]["IMG_02"]
    k, shift_mm = 19, np.array([2.0, -1.0])
    img = render_view(cam, pose, b, np.random.default_rng(1), noise=0.0, outliers=[(k, *shift_mm)])
    dirs = _grid_directions(uv_true, b)
    X = b.object_points_mm()
    moved = project_points(cam, pose.apply(X[k:k + 1] + [*shift_mm, 0.0]))
    start = uv_true.copy()
    start[k] = moved
    fit, ok, *_ = fit_saddles(img, start, dirs, half=6)
    assert ok[k] and np.linalg.norm(fit[k] - moved) < 0.05
    others = np.arange(b.n_corners) != k
    assert np.max(np.linalg.norm(fit[others] - uv_true[others], axis=1)) < 0.02


def test_a_fisheye_renders_its_corners_where_the_model_projects_them():
    """phone3's kb4 ultra-wide at half resolution, a view near its edge (the board 35-62 degrees off
    the axis) and one in the middle: every pixel's ray is the fisheye's (beyond 90 degrees too)."""
    truth = make_truth("phone3", views=10, seed=3, scale=0.5)
    cam = truth.cameras["ultra"]
    for view in ("IMG_01", "IMG_06"):                 # IMG_06: the first near the ultra-wide's edge
        img = render_view(cam, truth.camera_pose("ultra", view), truth.board, np.random.default_rng(1), noise=0.0)
        uv_true = true_corners(truth)["ultra"][view]
        fit, ok = _fit_from_near(img, uv_true, truth.board, half=6)
        assert ok.all()
        assert np.sqrt(np.mean(np.sum((fit - uv_true) ** 2, axis=1))) < 0.02


def test_defocus_is_a_disc_that_blurs_corners_without_moving_them(truth):
    """The defocus kernel is a disc of the given radius (its area, its support); a defocused, phone-processed
    noise-free render keeps its corners where the model projects them: the window's point symmetry finds them
    within 0.04 px RMS (what perspective leaves of asymmetry; 0.005 px in focus) though the disc is a fifth of a
    square wide."""
    k = defocus_kernel(6.0)
    assert k.shape == (13, 13) and k.sum() == pytest.approx(1.0, abs=1e-6)
    assert np.count_nonzero(k > 0.5 * k.max()) == pytest.approx(np.pi * 36, rel=0.05)
    cam, pose = truth.cameras["tele"], truth.camera_pose("tele", "IMG_01")
    uv_true = true_corners(truth)["tele"]["IMG_01"]
    img = render_view(cam, pose, truth.board, np.random.default_rng(1), noise=0.0, defocus_px=12.0,
                      processing=PhoneProcessing(quality=None))
    sharp = render_view(cam, pose, truth.board, np.random.default_rng(1), noise=0.0)
    assert np.abs(img.astype(int) - sharp).max() > 60                  # the squares' edges are spread out
    fit, ok = symmetry_centres(img, uv_true + np.random.default_rng(2).normal(0, 0.5, uv_true.shape), 10)
    assert ok.all()
    assert np.sqrt(np.mean(np.sum((fit - uv_true) ** 2, axis=1))) < 0.04
