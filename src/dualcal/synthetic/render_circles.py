"""The circles of a circle grid in a rendered photo, box-filtered exactly.

:func:`dualcal.synthetic.render.render_view` draws a circle grid (``Board.pattern`` ``"circles"`` or
``"acircles"``) with :func:`circle_darkness` in place of the chessboard's squares: dark filled circles
of diameter ``circle_mm`` centred on the board's points, on white paper. As for the squares, each
pixel's value is the exact mean of the board's reflectance over the pixel's footprint, an
axis-aligned box in board millimetres centred on the pixel's board point (so the filter is
point-symmetric and moves no centre): the area of a box cut by a disc, in closed form.

Area of a box and a disc. For the disc of radius ``r`` at the origin let ``G(x, y)`` (``x, y >= 0``)
be the area of its part in ``[0, x] x [0, y]``: with ``x, y`` clipped to ``[0, r]`` and
``x_c = min(x, sqrt(r^2 - y^2))`` (where the circle leaves the height ``y``),
``G = y x_c + I(x) - I(x_c)``, ``I(u) = (u sqrt(r^2 - u^2) + r^2 asin(u / r)) / 2`` the area under the
circle's arc. Extended as an odd function of each coordinate, ``S(x, y) = sgn(x) sgn(y) G(|x|, |y|)``
is an antiderivative of the disc's indicator in both coordinates, so the box ``[x0, x1] x [y0, y1]``
holds ``S(x1, y1) - S(x0, y1) - S(x1, y0) + S(x0, y0)`` of it.
"""

from __future__ import annotations

import numpy as np

from ..geometry.board import Board

__all__ = ["box_disc_area", "circle_darkness"]


def _arc_area(u: np.ndarray, r: float) -> np.ndarray:
    """``I(u)``: the area under the arc ``sqrt(r^2 - t^2)`` for ``t`` in ``[0, u]``, ``0 <= u <= r``."""
    return 0.5 * (u * np.sqrt(np.maximum(r * r - u * u, 0.0)) + r * r * np.arcsin(np.clip(u / r, -1.0, 1.0)))


def _corner_area(x: np.ndarray, y: np.ndarray, r: float) -> np.ndarray:
    """``S(x, y)``: the signed area of the disc of radius ``r`` at the origin between the axes and ``(x, y)``."""
    ax, ay = np.minimum(np.abs(x), r), np.minimum(np.abs(y), r)
    xc = np.minimum(ax, np.sqrt(np.maximum(r * r - ay * ay, 0.0)))
    return np.sign(x) * np.sign(y) * (ay * xc + _arc_area(ax, r) - _arc_area(xc, r))


def box_disc_area(x0, x1, y0, y1, r: float) -> np.ndarray:
    """Area (mm^2) of the boxes ``[x0, x1] x [y0, y1]`` (arrays, ``x0 <= x1``, ``y0 <= y1``, mm, relative to the
    disc's centre) inside the disc of radius ``r`` mm (module docstring)."""
    return (_corner_area(x1, y1, r) - _corner_area(x0, y1, r) - _corner_area(x1, y0, r)
            + _corner_area(x0, y0, r))


def circle_darkness(board: Board, X: np.ndarray, Y: np.ndarray, hX: np.ndarray, hY: np.ndarray) -> np.ndarray:
    """Share (0..1) of each pixel's footprint, the box ``[X - hX, X + hX] x [Y - hY, Y + hY]`` mm, that a
    circle of the grid covers.

    Parameters
    ----------
    board : Board
        a circle grid (``pattern`` ``"circles"`` or ``"acircles"``).
    X, Y : ndarray
        board points of the pixels' centres, mm (any shape).
    hX, hY : ndarray
        half-widths of the footprints, mm (the shape of ``X``); below the circles' spacing minus their radius,
        so that a footprint meets only circles of the two rows and two columns around it.
    """
    s, r = board.square_mm, 0.5 * board.circle_diameter_mm
    pitch = 2.0 * s if board.pattern == "acircles" else s         # along a row
    covered = np.zeros(np.shape(X))
    r0 = np.floor(Y / s).astype(int)
    for row in (r0, r0 + 1):
        shift = (row % 2) * s if board.pattern == "acircles" else 0.0
        c0 = np.floor((X - shift) / pitch).astype(int)
        for col in (c0, c0 + 1):
            on_board = (row >= 0) & (row < board.rows) & (col >= 0) & (col < board.cols)
            dx, dy = X - (shift + col * pitch), Y - row * s
            near = on_board & (np.abs(dx) < r + hX) & (np.abs(dy) < r + hY)
            if near.any():
                covered[near] += box_disc_area(dx[near] - hX[near], dx[near] + hX[near],
                                               dy[near] - hY[near], dy[near] + hY[near], r)
    return np.clip(covered / (4.0 * hX * hY), 0.0, 1.0)
