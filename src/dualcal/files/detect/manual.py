"""The paper's manual mode (section 1.2): four clicked corners, the rest by homography.

For each photo the user gives the four outer inner-corners of the grid, in the order corner 0,
corner ``cols-1``, corner ``N-1``, corner ``N-cols`` (``N = cols*rows``). They define the
board-to-image homography (paper eq. 3); since a homography keeps cross ratios, it predicts
every other node of the grid, and the predictions are then checked, put in the contract's
order and refined like automatic ones (:mod:`dualcal.files.detect.pipeline`). A hints file is JSON
``{camera: {view: [[u, v] x 4]}}``.

:func:`pick_hints` is the interactive part (``dualcal pick``): a matplotlib window shows each
photo, reduced, and the user clicks the four corners (the toolbar zooms in for precision). The
clicking itself is :class:`CornerClicks`, plain state driven by the window's events.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import cv2
import numpy as np

from ...geometry.board import Board
from ...errors import InputError
from ..io import read_json, write_json_atomic
from ...progress import warn
from .coarse import reduce_image, to_full_resolution

__all__ = ["CornerClicks", "connect_clicks", "display_problem", "grid_from_hints", "hint_board_points",
           "load_hints", "pick_hints", "save_hints"]


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


def display_problem() -> str | None:
    """Why ``dualcal pick`` cannot open a window here, in one line; None when it can.

    It needs a display (``DISPLAY`` or ``WAYLAND_DISPLAY`` on Linux and other X11 systems) and
    an interactive matplotlib backend (matplotlib falls back to the non-interactive Agg when
    no GUI toolkit is installed).
    """
    if sys.platform not in ("darwin", "win32") and not (os.environ.get("DISPLAY")
                                                        or os.environ.get("WAYLAND_DISPLAY")):
        return "dualcal pick needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set"
    import matplotlib
    from matplotlib.backends import BackendFilter, backend_registry

    backend = matplotlib.get_backend()
    if backend.lower() in backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE):
        return (f"dualcal pick needs an interactive matplotlib backend, and {backend!r} cannot open windows "
                "(install a GUI toolkit such as tkinter, or set MPLBACKEND, e.g. MPLBACKEND=TkAgg)")
    return None


_PROMPTS = ("corner 0", "corner cols-1 (end of the first row)", "corner N-1 (opposite corner 0)",
            "corner N-cols (start of the last row)")
_LABELS = ("0", "cols-1", "N-1", "N-cols")


class CornerClicks:
    """Clicking the four hinted corners of one photo: the state, without any window.

    A matplotlib figure feeds it mouse presses and keys (:func:`connect_clicks`): a left click
    adds the next corner, a right click or Backspace takes the last one back, Enter accepts
    four, Esc skips the photo, q stops asking. Points are in the shown image's pixels.
    """

    def __init__(self) -> None:
        self.points: list[tuple[float, float]] = []
        self.outcome: str | None = None          # "accept", "skip" or "quit" once decided

    def press(self, button: int, x: float | None, y: float | None) -> None:
        if self.outcome is not None:
            return
        if button == 1 and x is not None and y is not None and len(self.points) < 4:
            self.points.append((float(x), float(y)))
        elif button == 3 and self.points:
            self.points.pop()

    def key(self, key: str | None) -> None:
        if self.outcome is not None:
            return
        if key == "enter" and len(self.points) == 4:
            self.outcome = "accept"
        elif key == "backspace" and self.points:
            self.points.pop()
        elif key == "escape":
            self.outcome = "skip"
        elif key == "q":
            self.outcome = "quit"

    def prompt(self) -> str:
        if len(self.points) < 4:
            return f"click {_PROMPTS[len(self.points)]}\nright click: undo, Esc: skip this photo, q: stop"
        return "Enter: accept these four corners\nright click or Backspace: undo, Esc: skip, q: stop"


def connect_clicks(fig, ax, clicks: CornerClicks, title: str) -> list[int]:
    """Route ``fig``'s mouse and key events into ``clicks``, redrawing marks and instructions.

    Clicks while the toolbar zooms or pans are the user's navigation, not corners. Once
    ``clicks.outcome`` is decided (or the window is closed: "quit") the figure's event loop
    is stopped. Returns the connection ids.
    """
    marks, = ax.plot([], [], "o", mfc="none", mec="red", ms=12, mew=2)
    labels = [ax.annotate("", (0, 0), xytext=(8, -8), textcoords="offset points", color="red",
                          fontsize=12, fontweight="bold") for _ in range(4)]

    def redraw():
        pts = np.array(clicks.points).reshape(-1, 2)
        marks.set_data(pts[:, 0], pts[:, 1])
        for k, label in enumerate(labels):
            label.set_visible(k < len(pts))
            if k < len(pts):
                label.set_text(_LABELS[k])
                label.xy = tuple(pts[k])
        ax.set_title(f"{title}: {clicks.prompt()}", fontsize=10)
        fig.canvas.draw_idle()
        if clicks.outcome is not None:
            fig.canvas.stop_event_loop()

    def on_press(event):
        toolbar = getattr(fig.canvas, "toolbar", None)
        if event.inaxes is ax and not (toolbar is not None and toolbar.mode):
            clicks.press(int(event.button), event.xdata, event.ydata)
            redraw()

    def on_key(event):
        clicks.key(event.key)
        redraw()

    def on_close(_event):
        if clicks.outcome is None:
            clicks.outcome = "quit"
        fig.canvas.stop_event_loop()

    redraw()
    return [fig.canvas.mpl_connect("button_press_event", on_press),
            fig.canvas.mpl_connect("key_press_event", on_key),
            fig.canvas.mpl_connect("close_event", on_close)]


def pick_hints(photos: dict[str, dict[str, Path]], max_side: int = 1400) -> dict[str, dict[str, np.ndarray]]:
    """Let the user click the four outer inner-corners of each photo in a matplotlib window.

    Parameters
    ----------
    photos : ``{camera: {view: path}}`` of the photos that need hints.
    max_side : the photo is shown reduced by a whole factor to at most about this long side.

    Returns
    -------
    ``{camera: {view: (4, 2)}}`` full-resolution pixels of the photos clicked and accepted;
    skipped photos are left out, and after q (or closing the window) the rest too.

    Raises
    ------
    InputError
        No display or no interactive matplotlib backend (see :func:`display_problem`).
    """
    from ...extras import require

    require("report")
    problem = display_problem()
    if problem:
        raise InputError(problem)
    import matplotlib.pyplot as plt

    from ..photos import read_gray

    out: dict[str, dict[str, np.ndarray]] = {}
    # q and Backspace are matplotlib's shortcuts for closing and going back a view; here they are ours
    ours = ("q", "backspace")
    keymaps = {name: [k for k in plt.rcParams[name] if k not in ours] for name in ("keymap.quit", "keymap.back")}
    with plt.rc_context(keymaps):
        fig, ax = plt.subplots(figsize=(10, 8))
        plt.show(block=False)
        try:
            for cam, views in photos.items():
                for view, path in views.items():
                    try:
                        full = read_gray(path)
                    except InputError as exc:
                        warn(f"skipped: {exc}")
                        continue
                    factor = max(1, int(np.ceil(max(full.shape) / max_side)))
                    ax.clear()
                    ax.imshow(reduce_image(full, factor), cmap="gray", interpolation="nearest")
                    ax.set_axis_off()
                    clicks = CornerClicks()
                    ids = connect_clicks(fig, ax, clicks, f"{cam}/{view}")
                    fig.canvas.start_event_loop(timeout=0)
                    for cid in ids:
                        fig.canvas.mpl_disconnect(cid)
                    if clicks.outcome == "accept":
                        out.setdefault(cam, {})[view] = to_full_resolution(clicks.points, factor)
                    elif clicks.outcome == "quit":
                        return out
        finally:
            plt.close(fig)
    return out
