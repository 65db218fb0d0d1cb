"""The markers of a ChArUco board, box-filtered exactly, for the photo-like renders of :mod:`dualcal.synthetic.render`.

:mod:`dualcal.synthetic.render` draws the squares of every board analytically; on a ChArUco board this
module adds the ArUco markers in its white squares (layout: :mod:`dualcal.geometry.board`). Each
marker's cells come from OpenCV (``cv2.aruco.generateImageMarker`` at one pixel per cell,
with a one-cell black border), so the renders carry exactly the codes OpenCV's detector
reads. A marker is piecewise constant on its cells, so the integral of its darkness over any
axis-aligned box is the summed-area table of its cells interpolated bilinearly at the box's
corners: the box filter of a pixel's footprint is exact, as it is for the squares. A
footprint that reaches beyond its square (half a footprint wider than the white margin
between marker and square, i.e. squares of a few pixels) sees only the marker of the square
its centre is in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.board import Board

__all__ = ["MarkerTexture", "marker_texture", "marker_darkness"]


@dataclass(frozen=True)
class MarkerTexture:
    """Summed-area tables of every marker's darkness (1 on black cells), with its placement.

    ``sat[i, y, x]`` is the number of black cells of marker ``i`` in rows ``< y`` and columns
    ``< x``; ``marker_at[b + 1, a + 1]`` is the id of the marker in square ``(a, b)`` (-1 for a
    black square); a marker's cells are ``cell_mm`` wide and start ``margin_mm`` inside its square.
    """

    sat: np.ndarray
    marker_at: np.ndarray
    cell_mm: float
    margin_mm: float
    square_mm: float


def marker_texture(board: Board, swapped=()) -> MarkerTexture:
    """The :class:`MarkerTexture` of a ChArUco board whose dictionary is known.

    ``swapped``: pairs ``(i, j)``, marker ``i`` drawn with the code of id ``j`` (a misprinted or,
    to a detector, misread marker: the tests plant them).
    """
    import cv2

    ch = board.charuco
    if ch is None or ch.dictionary is None:
        raise ValueError("a ChArUco board with a known dictionary is needed to draw its markers")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ch.dictionary))
    bits = dictionary.markerSize
    cells = bits + 2
    code = dict(enumerate(range(ch.n_markers)))
    code.update({int(i): int(j) for i, j in swapped})
    dark = np.stack([1.0 - cv2.aruco.generateImageMarker(dictionary, code[i], cells, borderBits=1) / 255.0
                     for i in range(ch.n_markers)])
    sat = np.zeros((ch.n_markers, cells + 1, cells + 1))
    sat[:, 1:, 1:] = dark.cumsum(axis=1).cumsum(axis=2)
    marker_at = -np.ones((board.rows + 1, board.cols + 1), int)
    sq = board.marker_squares()
    marker_at[sq[:, 1] + 1, sq[:, 0] + 1] = np.arange(len(sq))
    return MarkerTexture(sat, marker_at, ch.marker_mm / cells, 0.5 * (board.square_mm - ch.marker_mm),
                         board.square_mm)


def _bilinear(sat: np.ndarray, ids: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``sat[ids]`` interpolated bilinearly at cell coordinates ``(x, y)``, clipped to the marker."""
    n = sat.shape[1] - 1
    x, y = np.clip(x, 0.0, n), np.clip(y, 0.0, n)
    x0 = np.minimum(np.floor(x).astype(int), n - 1)
    y0 = np.minimum(np.floor(y).astype(int), n - 1)
    fx, fy = x - x0, y - y0
    flat = sat.reshape(-1)
    base = ids * (n + 1) ** 2 + y0 * (n + 1) + x0
    s00, s01 = flat[base], flat[base + 1]
    s10, s11 = flat[base + n + 1], flat[base + n + 2]
    return (s00 * (1 - fx) + s01 * fx) * (1 - fy) + (s10 * (1 - fx) + s11 * fx) * fy


def marker_darkness(tex: MarkerTexture, X: np.ndarray, Y: np.ndarray, hX: np.ndarray, hY: np.ndarray) -> np.ndarray:
    """Share of the box ``[X - hX, X + hX] x [Y - hY, Y + hY]`` (board mm) covered by black marker cells."""
    s = tex.square_mm
    a = np.floor(X / s).astype(int)
    b = np.floor(Y / s).astype(int)
    rows, cols = tex.marker_at.shape
    inside = (a >= -1) & (a < cols - 1) & (b >= -1) & (b < rows - 1)
    ids = np.where(inside, tex.marker_at[np.clip(b + 1, 0, rows - 1), np.clip(a + 1, 0, cols - 1)], -1)
    out = np.zeros(np.shape(X))
    on = ids >= 0
    if not on.any():
        return out
    c = tex.cell_mm
    x = (X[on] - a[on] * s - tex.margin_mm) / c
    y = (Y[on] - b[on] * s - tex.margin_mm) / c
    hx, hy = hX[on] / c, hY[on] / c
    i = ids[on]
    area = (_bilinear(tex.sat, i, x + hx, y + hy) - _bilinear(tex.sat, i, x - hx, y + hy)
            - _bilinear(tex.sat, i, x + hx, y - hy) + _bilinear(tex.sat, i, x - hx, y - hy))
    out[on] = area / (4.0 * hx * hy)
    return out
