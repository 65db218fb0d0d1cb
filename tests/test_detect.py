"""Chessboard detection on photo-like renders with known truth: accuracy, order, self-checks."""

import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dualcal.board import Board
from dualcal.camera import project_points
from dualcal.cli import main
from dualcal.dataset import open_dataset
from dualcal.detect import detect_dataset, detect_photo, grid_from_hints, grid_smoothness_px, save_hints
from dualcal.detect.coarse import reduce_image, reduction_factor, to_full_resolution
from dualcal.errors import InputError
from dualcal.io import load_corners
from dualcal.model import Pose
from dualcal.render import render_view, write_photo_set
from dualcal.rotation import rotation_from_opk
from dualcal.synth import make_truth, true_corners


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((np.asarray(a) - b) ** 2, axis=1))))


def _truth_with_board(board: Board, views: int, seed: int, scale: float = 0.25):
    """A note8-like rig looking at ``board`` turned about the optical axis by ``k * 360 / views``
    degrees in view ``k``, keeping only views where the whole board is seen."""
    truth = replace(make_truth("note8", views=views, seed=seed, scale=scale), board=board)
    s = board.square_mm
    outline = np.array([[a, b, 0.0] for a in (-1.6 * s, (board.cols + 0.6) * s)
                        for b in (-1.6 * s, (board.rows + 0.6) * s)])
    keep = {}
    for k, (view, pose) in enumerate(truth.view_poses.items()):
        roll = Pose(rotation_from_opk([0.0, 0.0, 2 * np.pi * k / views]), np.zeros(3))
        pose = roll.compose(pose)
        truth.view_poses[view] = pose
        ok = True
        for cam, model in truth.cameras.items():
            uv = project_points(model, truth.camera_pose(cam, view).apply(outline))
            w, h = model.image_size
            ok &= bool(np.all((uv > 2) & (uv < [w - 3, h - 3])))
        if ok:
            keep[view] = pose
    return replace(truth, view_poses=keep)


def _render(truth, cam, view, path: Path, **kw):
    import cv2

    img = render_view(truth.cameras[cam], truth.camera_pose(cam, view), truth.board,
                      np.random.default_rng(zlib.crc32(f"{cam}/{view}".encode())), **kw)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 92])
    return path


def _expected_order(uv_true: np.ndarray, board: Board) -> np.ndarray:
    """The contract's order: the truth, or for a symmetric board the 180-degree turn nearest the top-left."""
    if not board.is_symmetric:
        return uv_true
    turned = uv_true[::-1]
    return uv_true if np.hypot(*uv_true[0]) <= np.hypot(*turned[0]) else turned


@pytest.mark.slow
def test_full_resolution_12mp_corners_within_three_hundredths_of_a_pixel(tmp_path):
    truth = make_truth("note8", views=1, seed=11)
    paths = write_photo_set(truth, tmp_path, seed=1, jobs=1, progress=False)
    tc = true_corners(truth)
    for cam in ("wide", "tele"):
        res = detect_photo(paths[cam]["IMG_01"], truth.board)
        assert res.uv is not None, res.reason
        assert res.image_size == (3024, 4032)
        assert _rms(res.uv, tc[cam]["IMG_01"]) <= 0.03


@pytest.mark.parametrize("board", [Board(8, 5, 30.0), Board(7, 5, 30.0), Board(6, 4, 30.0), Board(5, 5, 30.0)],
                         ids=lambda b: b.spec())
def test_every_board_found_in_the_contract_order_at_any_roll(tmp_path, board):
    truth = _truth_with_board(board, views=16, seed=board.cols * 10 + board.rows)
    assert len(truth.view_poses) >= 6
    tc = true_corners(truth)
    rolls = []
    for view in truth.view_poses:
        for cam in truth.cameras:
            res = detect_photo(_render(truth, cam, view, tmp_path / cam / f"{view}.jpg"), board)
            assert res.uv is not None, f"{cam}/{view}: {res.reason}"
            assert res.symmetric == board.is_symmetric
            assert _rms(res.uv, _expected_order(tc[cam][view], board)) < 0.05, f"{cam}/{view}"
            d = tc[cam][view][1] - tc[cam][view][0]
            rolls.append(np.degrees(np.arctan2(d[1], d[0])))
    # the poses turn the board through all four quadrants
    assert len({int((r + 180) // 90) for r in rolls}) == 4


def test_a_board_of_another_size_is_not_accepted(tmp_path):
    truth = make_truth("note8", views=2, seed=4, scale=0.25)
    for view in truth.view_poses:
        path = _render(truth, "wide", view, tmp_path / f"{view}.jpg")
        assert detect_photo(path, Board(8, 5, 30)).uv is not None
        for other in (Board(7, 4, 30), Board(7, 5, 30), Board(8, 4, 30), Board(9, 5, 30)):
            res = detect_photo(path, other)
            assert res.uv is None, f"{view} accepted as {other.spec()}"
            assert res.reason


def test_manual_mode_predicts_the_grid_from_four_clicks(tmp_path, monkeypatch):
    truth = make_truth("note8", views=1, seed=6, scale=0.5)
    uv_true = true_corners(truth)["tele"]["IMG_01"]
    path = _render(truth, "tele", "IMG_01", tmp_path / "t.jpg")
    b = truth.board
    clicks = uv_true[[0, b.cols - 1, b.n_corners - 1, b.n_corners - b.cols]]
    clicks = clicks + np.random.default_rng(0).uniform(-2.5, 2.5, clicks.shape)
    predicted = grid_from_hints(clicks, b).reshape(-1, 2)
    assert np.max(np.linalg.norm(predicted - uv_true, axis=1)) < 15
    # force the automatic search to fail, so that the hints are used
    monkeypatch.setattr("dualcal.detect.pipeline.find_grid", lambda *a, **k: None)
    assert detect_photo(path, b).uv is None
    res = detect_photo(path, b, hint_uv=clicks)
    assert res.manual and res.uv is not None
    assert _rms(res.uv, uv_true) <= 0.03
    # clicked from the opposite corner: still put in the contract's order
    turned = detect_photo(path, b, hint_uv=clicks[[2, 3, 0, 1]])
    assert turned.manual and _rms(turned.uv, uv_true) <= 0.03


def test_reduced_image_keeps_pixel_centres():
    ramp = np.tile(np.arange(256, dtype=np.uint8), (64, 1))
    small = reduce_image(ramp, 4)
    assert small.shape == (16, 64)
    # reduced pixel 10 averages full pixels 40..43, whose centre is 41.5 = 4 (10 + 0.5) - 0.5
    assert abs(float(small[5, 10]) - 41.5) <= 0.5
    assert to_full_resolution(np.array([[10.0, 5.0]]), 4).tolist() == [[41.5, 21.5]]
    assert reduction_factor((3024, 4032)) == 4 and reduction_factor((2448, 3264)) == 2
    assert reduction_factor((640, 480)) == 1


def test_grid_smoothness_flags_a_misplaced_corner():
    truth = make_truth("note8", views=1, seed=1, scale=0.25)
    g = true_corners(truth)["wide"]["IMG_01"].reshape(5, 8, 2).copy()
    spacing = np.linalg.norm(g[0, 1] - g[0, 0])
    assert grid_smoothness_px(g) < 0.02 * spacing
    g[2, 3] += 0.3 * spacing
    assert grid_smoothness_px(g) > 0.15 * spacing


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("set")
    truth = make_truth("note8", views=3, seed=8, scale=0.25)
    write_photo_set(truth, root / "photos", seed=2, jobs=1, progress=False)
    return truth, root / "photos"


def test_dataset_detection_skips_bad_photos_with_a_warning_naming_each(small_set, tmp_path, capsys):
    truth, photos = small_set
    cam = tmp_path / "ds" / "wide"
    cam.mkdir(parents=True)
    for v in ("IMG_01", "IMG_02"):
        (cam / f"{v}.jpg").write_bytes((photos / "wide" / f"{v}.jpg").read_bytes())
    data = (photos / "wide" / "IMG_03.jpg").read_bytes()
    (cam / "truncated.jpg").write_bytes(data[: len(data) // 2])
    (cam / "notimage.jpg").write_text("hello")
    import cv2

    cv2.imwrite(str(cam / "blank.jpg"), np.full((1008, 756), 128, np.uint8))
    other = replace(truth, board=Board(6, 4, 30.0))
    _render(other, "wide", "IMG_01", cam / "otherboard.jpg")

    corners = detect_dataset(open_dataset(tmp_path / "ds"), truth.board, jobs=2, progress=False)
    err = capsys.readouterr().err
    views = corners.cameras["wide"].views
    tc = true_corners(truth)["wide"]
    for v in ("IMG_01", "IMG_02"):
        assert _rms(views[v], tc[v]) < 0.05
    for bad in ("truncated", "blank", "otherboard"):
        assert views[bad] is None
        assert f"{bad}.jpg" in err
    assert "notimage" not in views and "notimage.jpg" in err
    assert corners.cameras["wide"].image_size == (756, 1008)


def test_dataset_with_nothing_usable_is_an_input_error(small_set, tmp_path):
    _, photos = small_set
    with pytest.raises(InputError, match="no 9x6 chessboard found"):
        detect_dataset(open_dataset(photos), Board(9, 6, 30.0), jobs=1, progress=False)


def test_detect_command_writes_corners_json_and_overlays(small_set, tmp_path):
    truth, photos = small_set
    out, overlays = tmp_path / "corners.json", tmp_path / "ov"
    with pytest.raises(SystemExit) as exc:
        main(["detect", str(photos), "--board", "8x5", "--square", "30", "-o", str(out),
              "--jobs", "1", "--overlays", str(overlays)])
    assert exc.value.code == 0
    cs = load_corners(out)
    assert cs.board == truth.board and sorted(cs.cameras) == ["tele", "wide"]
    tc = true_corners(truth)
    for cam, cc in cs.cameras.items():
        assert cc.image_size == truth.cameras[cam].image_size
        assert set(cc.meta["photos"]) == set(truth.view_poses)
        for v, uv in cc.views.items():
            assert _rms(uv, tc[cam][v]) < 0.05
            assert (overlays / cam / f"{v}.jpg").is_file()


def test_detect_command_uses_hints_and_rejects_bad_usage(small_set, tmp_path, capsys):
    _, photos = small_set
    hints = tmp_path / "hints.json"
    save_hints(hints, {"wide": {"IMG_01": np.zeros((4, 2))}})
    with pytest.raises(SystemExit) as exc:
        main(["detect", str(photos), "--board", "8x5", "--square", "30", "-o", str(tmp_path / "c.json"),
              "--jobs", "1", "--hints", str(hints)])
    assert exc.value.code == 0                 # automatic detection works: the hints are not needed
    for args, message in [(["--board", "8by5", "--square", "30"], "malformed"),
                          (["--board", "8x5", "--square", "30", "--camera", "x"], "NAME=GLOB")]:
        with pytest.raises(SystemExit) as exc:
            main(["detect", str(photos), *args, "-o", str(tmp_path / "c.json")])
        assert exc.value.code == 2
        assert message in capsys.readouterr().err


def test_pick_without_a_display_exits_2_with_one_line(small_set, tmp_path, monkeypatch, capsys):
    _, photos = small_set
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(SystemExit) as exc:
        main(["pick", str(photos), "--board", "8x5", "--square", "30", "-o", str(tmp_path / "h.json")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "display" in err[0]
