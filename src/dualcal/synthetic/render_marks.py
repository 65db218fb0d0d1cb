"""Marks printed in a chessboard's white squares, for the photo-like renders of :mod:`dualcal.synthetic.render`.

Boards that labs print often carry something in their white squares: a small binary code in every
one (BoofCV's ECoCheck), dots (fiducials, PuzzleBoard's coded dots), a vendor's logo, a serial
number. A detector must still find, number and refine such a board, so the renders can draw them:

``code``  a 4 x 4 binary code in every white square, 0.55 of its side (as ECoCheck), a different random code in each;
``dots``  a dark disc of 0.3 of the side in every white square;
``logo``  a large ring-and-bar logo in the two white squares nearest the board's centre, 0.7 of the side;
``text``  a serial number in small print along the white squares of the board's first row of squares.

Each mark is a raster of cells (black or white), drawn exactly box-filtered by the summed-area
tables of :mod:`dualcal.synthetic.render_charuco` (the ChArUco markers' machinery: a mark is to a white
square what a marker is), and stays well inside its square (at least 0.15 of the side from its
edges), so no mark touches a corner: the corners' positions are those of the plain board.
"""

from __future__ import annotations

import numpy as np

from ..geometry.board import Board
from .render_charuco import MarkerTexture

__all__ = ["MARK_KINDS", "marks_texture"]

#: The kinds of marks :func:`marks_texture` draws.
MARK_KINDS = ("code", "dots", "logo", "text")


def _white_squares(board: Board, inverted: bool) -> np.ndarray:
    """(M, 2) white squares ``(a, b)`` of a plain chessboard (``inverted``: the other squares), in reading order."""
    b, a = np.divmod(np.arange((board.cols + 1) * (board.rows + 1)), board.cols + 1)
    a, b = a - 1, b - 1
    white = (a + b) % 2 == (0 if inverted else 1)
    return np.column_stack([a[white], b[white]])


def _disc(cells: int) -> np.ndarray:
    """A filled disc on a ``cells x cells`` raster (1 = dark)."""
    c = (np.arange(cells) + 0.5) / cells - 0.5
    return (np.hypot(*np.meshgrid(c, c)) <= 0.5).astype(float)


def _logo(cells: int) -> np.ndarray:
    """A ring with a bar through it, as a vendor's logo (1 = dark)."""
    c = (np.arange(cells) + 0.5) / cells - 0.5
    x, y = np.meshgrid(c, c)
    r = np.hypot(x, y)
    return (((r <= 0.5) & (r >= 0.3)) | ((np.abs(y) <= 0.08) & (np.abs(x) <= 0.5))).astype(float)


def _text(cells: int, label: str) -> np.ndarray:
    """``label`` in small print on a ``cells x cells`` raster (1 = dark), a line across the middle."""
    import cv2

    img = np.zeros((cells, cells), np.uint8)
    scale = cv2.getFontScaleFromHeight(cv2.FONT_HERSHEY_PLAIN, cells // 4, 1)
    (w, h), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_PLAIN, scale, 1)
    cv2.putText(img, label, ((cells - w) // 2, (cells + h) // 2), cv2.FONT_HERSHEY_PLAIN, scale, 255, 1)
    return (img > 127).astype(float)


def marks_texture(board: Board, kind: str, seed: int = 0, inverted: bool = False) -> MarkerTexture:
    """The marks of ``kind`` (one of :data:`MARK_KINDS`) in the white squares of a plain chessboard.

    ``seed`` draws the codes of ``code``; ``inverted``: the board's other squares are the white ones. Returns a :class:`~dualcal.synthetic.render_charuco.MarkerTexture`
    for :func:`~dualcal.synthetic.render_charuco.marker_darkness` (no mark: ``marker_at`` -1).
    """
    if board.charuco is not None:
        raise ValueError("marks are for plain chessboards; a ChArUco board has its markers")
    if kind not in MARK_KINDS:
        raise ValueError(f"marks={kind!r}; expected one of {', '.join(MARK_KINDS)}")
    squares = _white_squares(board, inverted)
    if kind == "code":
        rng = np.random.default_rng(seed)
        side, rasters = 0.55, [np.kron(rng.integers(0, 2, (4, 4)), np.ones((2, 2))).astype(float)
                              for _ in squares]
    elif kind == "dots":
        side, rasters = 0.3, [_disc(24)] * len(squares)
    elif kind == "logo":
        centre = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2])
        squares = squares[np.argsort(np.hypot(*(squares - centre).T), kind="stable")[:2]]
        side, rasters = 0.7, [_logo(32)] * len(squares)
    else:
        squares = squares[squares[:, 1] == -1]
        side = 0.7
        rasters = [_text(48, f"SN{seed % 1000:03d}-{i}") for i in range(len(squares))]
    dark = np.stack(rasters)
    cells = dark.shape[1]
    sat = np.zeros((len(dark), cells + 1, cells + 1))
    sat[:, 1:, 1:] = dark.cumsum(axis=1).cumsum(axis=2)
    marker_at = -np.ones((board.rows + 1, board.cols + 1), int)
    marker_at[squares[:, 1] + 1, squares[:, 0] + 1] = np.arange(len(squares))
    s = board.square_mm
    return MarkerTexture(sat, marker_at, side * s / cells, 0.5 * (1.0 - side) * s, s)
