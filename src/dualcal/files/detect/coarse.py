"""Coarse chessboard search on a reduced image (paper section 1.2, first step).

The photo is area-averaged to 1/2, 1/4 or 1/8 size so that its long side is about 1000-1600
pixels, and OpenCV's detectors find the grid there: the classic ``findChessboardCorners``
(:func:`classic_grid`, milliseconds on a small image that shows the board), ``findChessboardCornersSB``
(Duda & Frese 2018, robust to blur and noise; :func:`sb_grid`), and the largest chessboard grid SB can
grow from any 3 x 3 corners (:func:`largest_grid`, :func:`consistent_part`): the part of a board in view where the frame
cuts it or glare or a shadow hides a square. Their corners are accurate to about a reduced pixel,
enough to start the full-resolution refinement, whose window is wider. The order in which they are
tried, and when to give up, is :func:`dualcal.files.detect.pipeline.locate_board`'s.

Why not decode a reduced copy (JPEG's DCT scaling), and then only the regions around the corners at full size?
Huffman decoding, which neither shortens, is most of a decode: libjpeg-turbo's 1/8 decode (every Huffman code, no
inverse DCT) takes 0.42 of OpenCV's full ``imread`` on 12 MP renders and 0.92 on the real progressive 8 MP phone
photos, where :func:`dualcal.files.photos.read_gray`'s full decode (libjpeg-turbo through simplejpeg) takes 0.73 and
1.0 (``benchmarks/bench_detect.py``, CPU time, one thread). A region of a JPEG without restart markers can only be
decoded after every Huffman code before it, so a reduced decode plus the regions costs more than one full decode for
every photo that shows a board; area-averaging the full image costs 1-2 ms. Only the DCT coefficients, read once,
would give both for the price of the Huffman decoding, and no maintained binding reads them quickly (jpeglib and
pyjpegio took 2-3 x a full decode).
"""

from __future__ import annotations

import cv2
import numpy as np

from ...parallel import raise_if_cancelled
from ...geometry.grid import local_spacing_px, neighbour_residuals_px

__all__ = ["reduction_factor", "reduce_image", "classic_grid", "shows_a_chessboard", "sb_grid", "find_grid",
           "largest_grid", "consistent_part", "to_full_resolution", "board_window", "in_window"]

_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
_SB_ATTEMPTS = (cv2.CALIB_CB_NORMALIZE_IMAGE, cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)


def reduction_factor(image_size: tuple[int, int], min_long_side: int = 1000) -> int:
    """Largest of 8, 4, 2, 1 that keeps the long side of the reduced image >= ``min_long_side``."""
    long_side = max(image_size)
    for f in (8, 4, 2):
        if long_side / f >= min_long_side:
            return f
    return 1


def reduce_image(gray: np.ndarray, factor: int) -> np.ndarray:
    """Average ``factor x factor`` blocks (``factor`` 1, 2, 4 or 8); pixel centres map as in
    :func:`to_full_resolution`.

    By halving the image ``log2(factor)`` times (OpenCV's vectorised 2 x 2 average: 2.3 ms for a 12 MP
    photo to 1/4, against 8.6 ms for one 4 x 4 average), which is the same average but for the rounding
    of the intermediate images to whole grey levels.
    """
    h, w = gray.shape[0] // factor, gray.shape[1] // factor
    small = gray[: h * factor, : w * factor]
    while factor > 1:
        factor //= 2
        small = cv2.resize(small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA)
    return small


#: OpenCV's SB detector draws from OpenCV's random number generator (one per thread), so what it finds in
#: a photo depended on what that thread had drawn before (a board found in one run and missed in the next):
#: the generator is seeded with this before each of its calls, and a photo's detection is the same every time.
SB_SEED = 20241202


def _grid(found: bool, corners, cols: int, rows: int) -> np.ndarray | None:
    if found and corners is not None and len(corners) == cols * rows:
        return corners.reshape(rows, cols, 2).astype(float)
    return None


def classic_grid(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """OpenCV's classic detector (adaptive threshold, normalised, fast check): the inner corners of a
    ``cols x rows`` board as a (rows, cols, 2) grid in the detector's own order (row-major, ``cols``
    corners per row; which end is corner 0 is decided later by :mod:`dualcal.files.detect.order`), or None."""
    raise_if_cancelled()
    return _grid(*cv2.findChessboardCorners(gray, (cols, rows), flags=_CLASSIC_FLAGS), cols, rows)


def shows_a_chessboard(gray: np.ndarray, cols: int, rows: int) -> bool:
    """OpenCV's quick look for a ``cols x rows`` chessboard (``checkChessboard``, the classic detector's fast
    check: dark and light quads at a few thresholds; 3-30 ms on a reduced photo)."""
    raise_if_cancelled()
    return bool(cv2.checkChessboard(gray, (cols, rows)))


def sb_grid(gray: np.ndarray, cols: int, rows: int, upsampled: bool = False,
            exhaustive: bool = True) -> np.ndarray | None:
    """``findChessboardCornersSB`` for a ``cols x rows`` board, as :func:`classic_grid` returns it: normalised,
    then (``exhaustive``) exhaustive; ``upsampled``: exhaustive on the image upsampled by OpenCV
    (``CALIB_CB_ACCURACY``), for squares of a few pixels. Each attempt can take a second on a large image: an
    interrupted pool (:func:`dualcal.parallel.raise_if_cancelled`) stops between them."""
    attempts = ((_SB_ATTEMPTS[1] | cv2.CALIB_CB_ACCURACY,) if upsampled else
                _SB_ATTEMPTS if exhaustive else _SB_ATTEMPTS[:1])
    for flags in attempts:
        raise_if_cancelled()
        cv2.setRNGSeed(SB_SEED)
        grid = _grid(*cv2.findChessboardCornersSB(gray, (cols, rows), flags=flags), cols, rows)
        if grid is not None:
            return grid
    return None


def find_grid(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """Inner corners of a ``cols x rows`` board in ``gray``, as a (rows, cols, 2) grid, or None:
    :func:`classic_grid`, then :func:`sb_grid`."""
    grid = classic_grid(gray, cols, rows)
    return grid if grid is not None else sb_grid(gray, cols, rows)


def largest_grid(gray: np.ndarray, min_size: int = 3) -> np.ndarray | None:
    """The largest chessboard grid ``findChessboardCornersSB`` can grow in ``gray``, any size, as it is.

    ``CALIB_CB_LARGER`` with a ``min_size x min_size`` pattern, exhaustive. Returns a (r, c, 2) grid in
    the detector's order, or None.
    """
    raise_if_cancelled()
    flags = _SB_ATTEMPTS[1] | cv2.CALIB_CB_LARGER
    cv2.setRNGSeed(SB_SEED)
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(gray, (min_size, min_size), flags)
    if not found or corners is None or meta is None:
        return None
    rows, cols = meta.shape[:2]
    if len(corners) != rows * cols:
        return None
    return corners.reshape(rows, cols, 2).astype(float)


def consistent_part(part: np.ndarray, min_size: int = 3, tolerance: float = 0.08) -> np.ndarray | None:
    """A grid of :func:`largest_grid` less the rows and columns at its edge that disagree with the rest.

    Where glare washes out a square, or a shadow or blur hides part of the board, the whole board is
    not found, but the part on one side of the damage is, and the detector's grid can run on past the
    damage into the background at its edge. Border rows and columns are dropped, the worst first, until
    every corner is within ``tolerance`` of its spacing from its neighbours' prediction; None when less
    than ``min_size x min_size`` is left. Which part of the board the rest is, is for
    :func:`dualcal.files.detect.order.place_partial_grid` to say.
    """
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


def board_window(part_px: np.ndarray, cols: int, rows: int, shape: tuple[int, int], factor: int) -> tuple[slice, slice]:
    """Where a ``cols x rows`` board of which ``part_px`` is a part can lie in an image reduced by ``factor``.

    ``part_px``: a (r, c, 2) grid of the board's corners, full-resolution pixels; ``shape``: the reduced image's
    (H, W). The part's bounding box widened on every side by twice the board's longer side and its outer ring
    (``2 * max(cols, rows) + 4``) in the part's own squares, whatever their place on the board and however
    steep the view (a square on a board's far side is rarely half of one on its near side), as the (rows, cols)
    slices of the reduced image. A detector asked for the board there sees the board, and no more than it of
    the room's clutter, where each of its corners may cost it time (:func:`in_window`)."""
    flat = part_px.reshape(-1, 2)
    spacing = float(np.nanmedian(local_spacing_px(flat, part_px.shape[:2])))
    reach = (2 * max(cols, rows) + 4) * spacing
    if not np.isfinite(reach):
        return slice(0, shape[0]), slice(0, shape[1])
    lo = np.floor((np.nanmin(flat, axis=0) - reach + 0.5) / factor - 0.5).astype(int)
    hi = np.ceil((np.nanmax(flat, axis=0) + reach + 0.5) / factor - 0.5).astype(int) + 1
    lo = np.clip(lo, 0, [shape[1], shape[0]])
    hi = np.clip(hi, 0, [shape[1], shape[0]])
    return slice(lo[1], hi[1]), slice(lo[0], hi[0])


def in_window(find, gray: np.ndarray, window: tuple[slice, slice], *args, **kwargs) -> np.ndarray | None:
    """``find(gray[window], *args, **kwargs)`` (a detector of this module), its grid in ``gray``'s pixels."""
    rows, cols = window
    grid = find(np.ascontiguousarray(gray[rows, cols]), *args, **kwargs)
    return None if grid is None else grid + [cols.start, rows.start]
