"""The paper's manual mode (section 1.2): four clicked corners, the rest by homography.

For each photo the user gives the four outer inner-corners of the grid, in the order corner 0,
corner ``cols-1``, corner ``N-1``, corner ``N-cols`` (``N = cols*rows``). They define the
board-to-image homography (paper eq. 3); since a homography keeps cross ratios, it predicts
every other node of the grid, and the predictions are then checked, put in the contract's
order and refined like automatic ones (:mod:`dualcal.detect.pipeline`). A hints file is JSON
``{camera: {view: [[u, v] x 4]}}``.

:func:`pick_hints` is the interactive part (``dualcal pick``): a window shows each photo and
the user clicks the four corners.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..board import Board
from ..errors import InputError
from ..io import read_json, write_json_atomic

__all__ = ["load_hints", "save_hints", "grid_from_hints", "hint_board_points", "pick_hints",
           "display_available"]


def hint_board_points(board: Board) -> np.ndarray:
    """Board grid indices ``(c, r)`` of the four hinted corners, in hint order (4, 2)."""
    C, R = board.cols - 1, board.rows - 1
    return np.array([[0, 0], [C, 0], [C, R], [0, R]], float)


def grid_from_hints(hint_uv: np.ndarray, board: Board) -> np.ndarray:
    """Predict all corners from the four hinted ones.

    Parameters
    ----------
    hint_uv : (4, 2) pixels of corners 0, cols-1, N-1, N-cols.
    board : the chessboard.

    Returns
    -------
    (rows, cols, 2) predicted corners, pixels, in the grid order the clicks define.
    """
    hint_uv = np.asarray(hint_uv, float)
    H = cv2.getPerspectiveTransform(hint_board_points(board).astype(np.float32),
                                    hint_uv.astype(np.float32))
    c, r = np.meshgrid(np.arange(board.cols), np.arange(board.rows))
    pts = np.stack([c, r], -1).reshape(-1, 1, 2).astype(np.float64)
    return cv2.perspectiveTransform(pts, H).reshape(board.rows, board.cols, 2)


def load_hints(path) -> dict[str, dict[str, np.ndarray]]:
    """Read and validate a hints JSON file: ``{camera: {view: (4, 2) array}}``."""
    doc = read_json(path)
    out: dict[str, dict[str, np.ndarray]] = {}
    for cam, views in doc.items():
        if not isinstance(views, dict):
            raise InputError(f"{path}: camera {cam!r} must map view names to four [u, v] points")
        for view, pts in views.items():
            try:
                arr = np.asarray(pts, float)
            except (TypeError, ValueError):
                arr = np.zeros(0)
            if arr.shape != (4, 2) or not np.all(np.isfinite(arr)):
                raise InputError(f"{path}: {cam}/{view}: expected four [u, v] points "
                                 "(corner 0, cols-1, N-1, N-cols)")
            out.setdefault(str(cam), {})[str(view)] = arr
    return out


def save_hints(path, hints: dict[str, dict[str, np.ndarray]]) -> None:
    write_json_atomic(path, {c: {v: np.asarray(p, float).round(2).tolist() for v, p in views.items()}
                             for c, views in hints.items()})


def display_available() -> bool:
    """True when an interactive window can be opened (a display and a GUI-enabled OpenCV)."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    info = cv2.getBuildInformation()
    gui = next((line for line in info.splitlines() if line.strip().startswith("GUI:")), "")
    return bool(gui.split(":", 1)[-1].strip()) and "NONE" not in gui.upper()


_PROMPTS = ("corner 0", "corner cols-1 (end of the first row)", "corner N-1 (opposite corner 0)",
            "corner N-cols (start of the last row)")


def _click_four(window: str, image: np.ndarray, scale: float, title: str):
    """Show ``image`` and collect four left clicks; returns (4, 2) full-resolution pixels or None."""
    clicks: list[tuple[float, float]] = []

    def on_mouse(event, x, y, _flags, _param):
        if event == cv2.EVENT_LBUTTONDOWN and len(clicks) < 4:
            clicks.append(((x + 0.5) / scale - 0.5, (y + 0.5) / scale - 0.5))

    cv2.setMouseCallback(window, on_mouse)
    while True:
        shown = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        for k, (u, v) in enumerate(clicks):
            p = (int(round((u + 0.5) * scale - 0.5)), int(round((v + 0.5) * scale - 0.5)))
            cv2.circle(shown, p, 6, (0, 0, 255), 2)
            cv2.putText(shown, str(k), (p[0] + 8, p[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 255), 2)
        msg = (f"{title}: click {_PROMPTS[len(clicks)]}" if len(clicks) < 4
               else f"{title}: Enter to accept, Backspace to undo")
        cv2.setWindowTitle(window, msg)
        cv2.imshow(window, shown)
        key = cv2.waitKey(30) & 0xFF
        if key in (8, 127) and clicks:
            clicks.pop()
        elif key in (13, 10) and len(clicks) == 4:
            return np.array(clicks)
        elif key in (27, ord("s")):          # Esc or s: skip this photo
            return None
        elif key == ord("q"):
            raise KeyboardInterrupt


def pick_hints(photos: dict[str, dict[str, Path]], max_side: int = 1400) -> dict[str, dict[str, np.ndarray]]:
    """Let the user click the four outer inner-corners of each photo (Esc skips, q quits).

    Parameters
    ----------
    photos : ``{camera: {view: path}}`` of the photos that need hints.
    max_side : long side of the window, pixels (the photo is shown reduced).
    """
    from ..dataset import read_gray

    if not display_available():
        raise InputError("dualcal pick needs a display and OpenCV with GUI support "
                         "(no DISPLAY, or opencv-python-headless is installed)")
    window = "dualcal pick"
    cv2.namedWindow(window, cv2.WINDOW_AUTOSIZE)
    out: dict[str, dict[str, np.ndarray]] = {}
    try:
        for cam, views in photos.items():
            for view, path in views.items():
                full = read_gray(path)
                scale = min(1.0, max_side / max(full.shape))
                shown = cv2.resize(full, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                pts = _click_four(window, shown, scale, f"{cam}/{view}")
                if pts is not None:
                    out.setdefault(cam, {})[view] = pts
    finally:
        cv2.destroyWindow(window)
    return out
