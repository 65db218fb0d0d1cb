"""Coarse chessboard search on a reduced image (paper section 1.2, first step).

The photo is area-averaged to 1/2, 1/4 or 1/8 size so that its long side is about 1000-1600
pixels, and OpenCV's detectors find the grid there: the classic ``findChessboardCorners``
(fast on a small image), then, if that fails, ``findChessboardCornersSB`` (Duda & Frese
2018, more robust to blur and noise) and its exhaustive mode. Their corners are accurate to
about a reduced pixel, enough to start the full-resolution refinement, whose window is wider.

Why not JPEG's reduced decode (``cv2.IMREAD_REDUCED_GRAYSCALE_4``)? Huffman decoding, which
DCT scaling does not shorten, is most of a decode: measured on 12 MP renders a 1/4 decode
costs 18 ms against 33 ms for a full one (and on an 8 MP phone photo 111 ms against 118 ms),
while area-averaging the full image costs 2-5 ms. The full image is needed for the refinement
anyway, so one full decode plus :func:`reduce_image` is the cheaper way for every photo that
shows a board.
"""

from __future__ import annotations

import cv2
import numpy as np

from ...parallel import raise_if_cancelled
from ...geometry.grid import local_spacing_px, neighbour_residuals_px

__all__ = ["reduction_factor", "reduce_image", "find_grid", "find_partial_grid", "to_full_resolution"]

_ATTEMPTS = (
    ("classic", cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK),
    ("sb", cv2.CALIB_CB_NORMALIZE_IMAGE),
    ("sb", cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE),
)


def reduction_factor(image_size: tuple[int, int], min_long_side: int = 1000) -> int:
    """Largest of 8, 4, 2, 1 that keeps the long side of the reduced image >= ``min_long_side``."""
    long_side = max(image_size)
    for f in (8, 4, 2):
        if long_side / f >= min_long_side:
            return f
    return 1


def reduce_image(gray: np.ndarray, factor: int) -> np.ndarray:
    """Average ``factor x factor`` blocks; pixel centres map as in :func:`to_full_resolution`."""
    if factor == 1:
        return gray
    h, w = gray.shape[0] // factor, gray.shape[1] // factor
    return cv2.resize(gray[: h * factor, : w * factor], (w, h), interpolation=cv2.INTER_AREA)


def find_grid(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """Inner corners of a ``cols x rows`` board in ``gray``, as a (rows, cols, 2) grid, or None.

    The grid is in the detector's own order (row-major, ``cols`` corners per row); which end
    is corner 0 is decided later by :mod:`dualcal.files.detect.order`. Each attempt can take a second
    on a large image: an interrupted pool (:func:`dualcal.parallel.raise_if_cancelled`) stops between them.
    """
    for kind, flags in _ATTEMPTS:
        raise_if_cancelled()
        if kind == "sb":
            found, corners = cv2.findChessboardCornersSB(gray, (cols, rows), flags=flags)
        else:
            found, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=flags)
        if found and corners is not None and len(corners) == cols * rows:
            return corners.reshape(rows, cols, 2).astype(float)
    return None


def find_partial_grid(gray: np.ndarray, min_size: int = 3) -> np.ndarray | None:
    """The largest chessboard grid ``findChessboardCornersSB`` can grow in ``gray``, any size.

    Where glare washes out a square, or a shadow or blur hides part of the board, the whole
    board is not found, but the part on one side of the damage is (``CALIB_CB_LARGER`` with a
    ``min_size x min_size`` pattern), less the rows and columns at its edge that disagree with
    the rest. Returns a (r, c, 2) grid in the detector's order, or None;
    which part of the board it is, is for :func:`dualcal.files.detect.order.place_partial_grid` to say.
    """
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_LARGER
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(gray, (min_size, min_size), flags)
    if not found or corners is None or meta is None:
        return None
    rows, cols = meta.shape[:2]
    if len(corners) != rows * cols:
        return None
    return _trim_to_consistent(corners.reshape(rows, cols, 2).astype(float), min_size)


def _trim_to_consistent(part: np.ndarray, min_size: int, tolerance: float = 0.08) -> np.ndarray | None:
    """Drop border rows and columns of a grid until every corner is within ``tolerance`` of its
    spacing from its neighbours' prediction (the detector's grid can run on past the damage
    into the background at its edge); None when less than ``min_size x min_size`` is left."""
    while min(part.shape[:2]) >= min_size:
        flat = part.reshape(-1, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            bad = neighbour_residuals_px(flat, part.shape[:2]) / local_spacing_px(flat, part.shape[:2])
        # not finite: a corner on top of its neighbour (every corner of a 3 x 3 grid or more
        # has the 8 neighbours a prediction needs)
        bad = np.where(np.isfinite(bad), bad, 1.0).reshape(part.shape[:2])
        if bad.max() <= tolerance:
            return part
        sides = {"top": bad[0].sum(), "bottom": bad[-1].sum(), "left": bad[:, 0].sum(), "right": bad[:, -1].sum()}
        worst = max(sides, key=sides.get)
        part = {"top": part[1:], "bottom": part[:-1], "left": part[:, 1:], "right": part[:, :-1]}[worst]
    return None


def to_full_resolution(uv_reduced: np.ndarray, factor: int) -> np.ndarray:
    """Reduced-image pixels -> full-resolution pixels (pixel centres: ``f (u + 0.5) - 0.5``)."""
    return (np.asarray(uv_reduced, float) + 0.5) * factor - 0.5
