"""Corner order and colour checks: the contract's numbering from a detected grid.

Corner 0 is the inner corner whose diagonally-outside square of the outer ring is black and
from which X (along ``cols``) and Y (along ``rows``) make a right-handed frame with Z pointing
into the board, away from the camera (CONTRACT.md, "Geometry conventions"). In the image
(``u`` right, ``v`` down, camera ``z`` forward) that frame is right-handed exactly when
``cross(dX, dY) > 0``. When ``cols + rows`` is even the board is 180-degree symmetric and
colour cannot tell the two candidates apart: corner 0 is then the candidate nearest the
image's top-left.

The same square samples also check the detection: the inner squares and the outer ring must
alternate like a chessboard, and the squares one further out must not (else the photo shows a
larger board than the one asked for, and the detector found only part of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ...geometry.board import Board
from ...geometry.grid import predict_from_neighbours
from ...errors import DetectionError

__all__ = ["PartialBoard", "SquareColours", "square_colours", "check_colours", "filled_grid", "looks_like_part_of_a_board",
           "order_grid", "place_partial_grid", "right_handed"]


#: Samples per square along each side (:func:`square_colours`).
_SAMPLES = 7


class PartialBoard(DetectionError):
    """Only part of a plain chessboard is in the photo: its corners cannot be numbered."""


@dataclass
class SquareColours:
    """Median grey of board squares; ``values[b + 2, a + 2]`` for square ``(a, b)``, NaN if unseen.

    Squares ``a = -2 .. cols``, ``b = -2 .. rows`` in the grid's own index frame: the inner
    squares, the outer ring (``a`` or ``b`` = -1 or cols-1/rows-1) and one ring beyond.
    ``even_is_dark`` tells whether squares with ``a + b`` even are the dark ones.
    """

    values: np.ndarray
    even_is_dark: bool
    contrast: float


def _extend_line(p: np.ndarray, n: int = 2) -> np.ndarray:
    """Extend points along axis 0 by ``n`` at each end, quadratically (lens bending included).

    With three points ``p0, p1, p2`` the parabola through them gives ``p(-1) = 3p0 - 3p1 + p2``
    and ``p(-2) = 6p0 - 8p1 + 3p2`` (Lagrange); with two, a straight line.
    """
    if len(p) >= 3:
        head = [3 * p[0] - 3 * p[1] + p[2], 6 * p[0] - 8 * p[1] + 3 * p[2]]
        tail = [3 * p[-1] - 3 * p[-2] + p[-3], 6 * p[-1] - 8 * p[-2] + 3 * p[-3]]
    else:
        head = [2 * p[0] - p[1], 3 * p[0] - 2 * p[1]]
        tail = [2 * p[-1] - p[-2], 3 * p[-1] - 2 * p[-2]]
    return np.concatenate([np.stack(head[:n][::-1]), p, np.stack(tail[:n])])


def extended_grid(grid: np.ndarray) -> np.ndarray:
    """(rows+4, cols+4, 2): the grid with two rings of corners extrapolated around it."""
    g = np.stack([_extend_line(row) for row in grid])               # along each row
    return np.stack([_extend_line(col) for col in np.swapaxes(g, 0, 1)], axis=1)


def square_colours(gray: np.ndarray, grid_px: np.ndarray, factor: int = 1) -> SquareColours:
    """Sample the mean grey of the squares around a detected grid.

    Parameters
    ----------
    gray : image to sample (e.g. the reduced image of the coarse search).
    grid_px : (rows, cols, 2) corners, full-resolution pixels.
    factor : reduction of ``gray`` relative to full resolution.

    Each square is sampled at 7 x 7 points interpolated bilinearly between its four corners;
    corners outside the grid are extrapolated along the grid lines (:func:`extended_grid`).
    Inner squares are sampled over the middle 80 % of their side and valued by the samples'
    median, so that marks printed in a white square (a code, dots, a logo, text: less than half
    its area) or glare on a dark one do not change its colour; squares outside the grid in the
    half nearer to the grid, since many boards print the outer ring narrower than a full square.
    """
    R, C = grid_px.shape[:2]
    ext = extended_grid(np.asarray(grid_px, float))

    n = _SAMPLES

    def spans(m):     # (m + 3, n) sample fractions across squares -2 .. m of a line of m corners
        k = np.arange(-2, m + 1)[:, None]
        lo = np.where(k < 0, 0.55, 0.1)
        return lo + (np.where(k < 0, 0.9, np.where(k >= m - 1, 0.45, 0.9)) - lo) * np.linspace(0, 1, n)

    fs = spans(C)[None, :, None, :, None]          # across columns: (1, C+3, 1, n, 1)
    ft = spans(R)[:, None, :, None, None]          # across rows:    (R+3, 1, n, 1, 1)
    p00, p01 = ext[:-1, :-1, None, None], ext[:-1, 1:, None, None]
    p10, p11 = ext[1:, :-1, None, None], ext[1:, 1:, None, None]
    pts = (1 - ft) * ((1 - fs) * p00 + fs * p01) + ft * ((1 - fs) * p10 + fs * p11)   # (R+3, C+3, n, n, 2)
    pts = ((pts + 0.5) / factor - 0.5).reshape(R + 3, C + 3, n * n, 2)
    h, w = gray.shape
    inside = np.all((pts >= 0) & (pts <= [w - 1, h - 1]), axis=(2, 3))
    flat = pts.reshape(-1, 1, 2).astype(np.float32)
    samples = cv2.remap(gray, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR).reshape(R + 3, C + 3, n * n)
    # the median of most of the square, not its mean: a code, dots, a logo or text printed in a
    # white square (up to nearly half of the area sampled), or glare on a dark one, leave it alone
    values = np.where(inside, np.median(samples, axis=2), np.nan)
    inner = values[2:R + 1, 2:C + 1]
    a, b = np.meshgrid(np.arange(C - 1), np.arange(R - 1))
    even = (a + b) % 2 == 0
    # medians, not means: a glare spot on a dark square or a shadow over a few light ones must
    # not decide which squares are the dark ones
    diff = np.nanmedian(inner[~even]) - np.nanmedian(inner[even])
    return SquareColours(values, bool(diff > 0), float(abs(diff)))


def _neighbour_mean(values: np.ndarray) -> np.ndarray:
    """Mean of the (up to) four edge-neighbours of every square, NaN-aware."""
    pad = np.pad(values, 1, constant_values=np.nan)
    stack = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    n = np.sum(np.isfinite(stack), axis=0)
    total = np.nansum(stack, axis=0)
    return np.where(n > 0, total / np.maximum(n, 1), np.nan)


#: :func:`check_colours`' limits: a square's least contrast with its neighbours (grey levels) for its colour to
#: count, and the largest share of the inner squares (at least one) whose colour may disagree with the board's.
MIN_CONTRAST = 8.0
MAX_ODD_SHARE = 0.1


def _alternation(col: SquareColours, cols: int, rows: int, min_contrast: float, max_odd_share: float):
    """The inner squares' part of :func:`check_colours` (raises :class:`DetectionError`); returns the square
    indices, which are dark, the sign expected of each against its neighbours, the inner and ring masks and
    each square's local contrast (about +1 as a chessboard predicts)."""
    if not col.contrast >= min_contrast:
        raise DetectionError(f"squares show too little contrast ({col.contrast:.1f} grey levels)")
    a, b = np.meshgrid(np.arange(-2, cols + 1), np.arange(-2, rows + 1))
    dark = ((a + b) % 2 == 0) == col.even_is_dark
    sign = np.where(dark, -1.0, 1.0)                     # expected side of the neighbours
    inner = (a >= 0) & (a <= cols - 2) & (b >= 0) & (b <= rows - 2)
    ring = ((a == -1) | (a == cols - 1) | (b == -1) | (b == rows - 1)) & ~(
        (a < -1) | (b < -1) | (a > cols - 1) | (b > rows - 1))
    board_part = np.where(inner | ring, col.values, np.nan)
    local = (board_part - _neighbour_mean(board_part)) * sign / col.contrast   # about +1 as predicted
    seen = inner & np.isfinite(local)
    odd = int(np.sum(local[seen] < 0.2))
    if odd > max(1, int(max_odd_share * seen.sum())):
        raise DetectionError(f"the squares between the corners do not alternate like a chessboard "
                             f"({odd} of {int(seen.sum())} do not)")
    return a, b, dark, sign, inner, ring, local


def _alternates(grid_px: np.ndarray, gray: np.ndarray, factor: int) -> bool:
    """Whether the squares between the corners of a (r, c, 2) grid alternate like a chessboard's."""
    r, c = grid_px.shape[:2]
    try:
        _alternation(square_colours(gray, grid_px, factor), c, r, MIN_CONTRAST, MAX_ODD_SHARE)
    except DetectionError:
        return False
    return True


def looks_like_part_of_a_board(grid_px: np.ndarray, gray: np.ndarray, factor: int, board: Board) -> bool:
    """Whether a (r, c, 2) grid found by a detector (full-resolution pixels) may be part of ``board`` in full
    view: the squares between its corners alternate like a chessboard's (:func:`check_colours`' inner
    squares), and some placement of it on the board (:func:`place_partial_grid`'s) keeps every inner corner
    at least half a square inside the image, where the outer ring of squares, a square wide, must be seen.
    A grid on other stripes or checks (a carpet, tiles), or a board cut by the frame, is no such part: no
    detector asked for the whole board will find it there."""
    if not _alternates(grid_px, gray, factor):
        return False
    size = np.array(gray.shape[::-1]) * factor
    step = float(np.median(np.linalg.norm(np.diff(grid_px, axis=1), axis=2)))
    return any(np.all(np.isfinite(grid)) and np.all((grid >= 0.5 * step) & (grid <= size - 1 - 0.5 * step))
               for grid in _placements(grid_px, board))


def check_colours(col: SquareColours, cols: int, rows: int, min_contrast: float = MIN_CONTRAST,
                  max_odd_share: float = MAX_ODD_SHARE) -> None:
    """Raise :class:`DetectionError` unless the squares look like exactly a ``cols x rows`` board.

    Each square is compared with its four neighbours (local contrast, so a shadow across the
    board or uneven light does not matter): it must be darker than them where the chessboard
    has a dark square and lighter where it has a light one. Up to ``max_odd_share`` of the inner
    squares (at least one) may disagree, for glare on a dark square or a smudge; the outer ring
    must agree in 80 % of its squares, and the squares one further out must not continue the
    pattern (else the photo shows a larger board and the detector found part of it).
    """
    a, b, dark, sign, inner, ring, local = _alternation(col, cols, rows, min_contrast, max_odd_share)
    seen = ring & np.isfinite(local)
    if seen.sum() < 4 or np.mean(local[seen] > 0.2) < 0.8:
        raise DetectionError("the outer ring of squares does not continue the chessboard "
                             "(a different board, or the board is cut off)")
    mid = 0.5 * (np.nanmedian(col.values[inner & dark]) + np.nanmedian(col.values[inner & ~dark]))
    score = (col.values - mid) * sign / (0.5 * col.contrast)     # +1: as a chessboard predicts
    sides = {"left": (a == -2) & (b >= 0) & (b <= rows - 2), "right": (a == cols) & (b >= 0) & (b <= rows - 2),
             "top": (b == -2) & (a >= 0) & (a <= cols - 2), "bottom": (b == rows) & (a >= 0) & (a <= cols - 2)}
    for name, side in sides.items():
        s = score[side]
        s = s[np.isfinite(s)]
        if len(s) >= 2 and np.mean(s) > 0.5:
            raise DetectionError(f"the chessboard continues beyond its outer ring ({name} side of the grid): "
                                 f"the board is larger than {cols}x{rows} inner corners")


def place_partial_grid(part_px: np.ndarray, gray: np.ndarray, factor: int, board: Board) -> np.ndarray:
    """The whole board's (rows, cols, 2) grid from a part of it found by the detector.

    Every placement of the part (either way round) inside the board is extended to the whole
    board through the homography of the part and sampled (:func:`square_colours`); the one
    whose squares look like exactly the board (:func:`check_colours`: its outer ring continues
    the chessboard, the squares beyond do not) is returned. The extended corners are a start
    only, off by up to a few pixels where the lens bends the grid; the refinement takes them
    from there. A placement that runs off the image (a board cut off by the frame) is judged on
    the squares in view, where the board is not 180-degree symmetric (``cols + rows`` odd: its
    colours then fix its numbering) and more than half of its corners are in the image; the
    corners outside it are NaN after refinement. Placements that run off the image are judged
    for symmetric boards too, so that a wrong placement inside the image is not taken for the only
    one: a symmetric board whose one fitting placement runs off the image is refused.

    Raises
    ------
    PartialBoard
        When the part's squares alternate like a chessboard's, no placement fits, the part reaches to
        within 1.5 of its squares of the image's edge and some placement runs off the image: the board is
        cut off by the frame.
    DetectionError
        When no placement, or more than one, fits.
    """
    R, C = board.rows, board.cols
    if part_px.shape[:2] in ((R, C), (C, R)):        # the whole board: the detector's own corners
        return part_px if part_px.shape[:2] == (R, C) else np.swapaxes(part_px, 0, 1)
    if not _alternates(part_px, gray, factor):         # stripes of a carpet, a grid of tiles
        raise DetectionError(f"no {board.spec()} chessboard found")
    h, w = gray.shape
    size = np.array([w, h]) * factor
    fits, off_image = [], False
    for grid in _placements(part_px, board):
        inside = np.all((grid >= 0) & (grid <= size - 1), axis=2)
        if not inside.all():
            off_image = True
            # a board cut off by the frame, judged on the squares in view where most of it is
            if 2 * inside.sum() <= R * C or not np.all(np.isfinite(grid)):
                continue
        try:
            check_colours(square_colours(gray, grid, factor), C, R)
        except DetectionError:
            continue
        fits.append((grid, bool(inside.all())))
    cut = any(not whole for _, whole in fits)
    if (not fits and off_image) or (cut and (board.is_symmetric or len(fits) > 1)):
        step = np.median(np.linalg.norm(np.diff(part_px, axis=1), axis=2))
        if cut or np.any(part_px < 1.5 * step) or np.any(part_px > size - 1 - 1.5 * step):
            r, c = part_px.shape[:2]
            how = ("a chessboard with cols + rows even must be seen whole: it looks the same turned by 180 degrees"
                   if board.is_symmetric else "too little of it, or of its edges, is in view to number its corners")
            raise PartialBoard(f"only part of the {board.spec()} chessboard is in the photo ({c}x{r} corners "
                               f"at the frame's edge): {how} (a ChArUco board may be seen in part)")
    if len(fits) != 1:
        raise DetectionError(f"no {board.spec()} chessboard found" + (
            " (a part of one was, but not where it lies on the board)" if fits else ""))
    return fits[0][0]


def _placements(part_px: np.ndarray, board: Board):
    """Every placement of a (r, c, 2) part (either way round) inside the board, as the (rows, cols, 2) grid
    of the whole board it extends to (:func:`_extension`). Where the part has more rows or columns than the
    board (SB's grid run on into the board's margin), each run of the board's rows or columns of it."""
    R, C = board.rows, board.cols
    for grid in (part_px, np.swapaxes(part_px, 0, 1)):
        for i in range(max(grid.shape[0] - R, 0) + 1):
            for j in range(max(grid.shape[1] - C, 0) + 1):
                part = grid[i:i + R, j:j + C]
                r, c = part.shape[:2]
                extend = _extension(part) if r * c >= 9 else None
                if extend is None:
                    continue
                for i0 in range(R - r + 1):
                    for j0 in range(C - c + 1):
                        J, I = np.meshgrid(np.arange(C) - j0, np.arange(R) - i0)
                        yield extend(J, I)


def _extension(part: np.ndarray):
    """A function ``(J, I) -> (..., 2)`` pixels of grid position ``(column J, row I)`` of a (r, c, 2) part of a
    board, or None: the part's homography, and where the part is at least 4 x 4 a quadratic in ``(J, I)``
    fitted to what the homography leaves of it (the bending of the grid by the lens and by a board that is
    not flat, a curled sheet: over a few squares, the homography alone puts the corners beyond the part
    several pixels off, enough to sample the wrong squares)."""
    r, c = part.shape[:2]
    jj, ii = np.meshgrid(np.arange(c, dtype=float), np.arange(r, dtype=float))
    src = np.column_stack([jj.ravel(), ii.ravel()])
    H, _ = cv2.findHomography(src.astype(np.float32), part.reshape(-1, 2).astype(np.float32), 0)
    if H is None:
        return None

    def homography(J, I):
        q = np.stack([J, I, np.ones_like(J)], axis=-1) @ H.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return q[..., :2] / q[..., 2:]

    if min(r, c) < 4:
        return homography

    def basis(J, I):
        J, I = np.asarray(J, float), np.asarray(I, float)
        return np.stack([np.ones_like(J), J, I, J * J, J * I, I * I], axis=-1)

    coef = np.linalg.lstsq(basis(src[:, 0], src[:, 1]), part.reshape(-1, 2) - homography(src[:, 0], src[:, 1]),
                           rcond=None)[0]
    return lambda J, I: homography(J, I) + basis(J, I) @ coef


def filled_grid(uv: np.ndarray, coarse_uv: np.ndarray, board: Board) -> np.ndarray:
    """(rows, cols, 2) corners: the measured ``uv`` (N, 2, NaN rows unmeasured), each unmeasured corner where
    its measured neighbours put it (:func:`~dualcal.geometry.grid.predict_from_neighbours`, repeated as the
    filled corners give others enough neighbours), else at its ``coarse_uv`` start."""
    shape = (board.rows, board.cols)
    g = np.array(uv, float)
    while True:
        missing = ~np.all(np.isfinite(g), axis=1)
        if not missing.any():
            break
        pred = predict_from_neighbours(g, shape)[0]
        fill = missing & np.all(np.isfinite(pred), axis=1)
        if not fill.any():
            break
        g[fill] = pred[fill]
    g = np.where(np.all(np.isfinite(g), axis=1)[:, None], g, coarse_uv)
    return g.reshape(board.rows, board.cols, 2)


def right_handed(grid: np.ndarray) -> bool:
    """True when (X along axis 1, Y along axis 0) of a (rows, cols, 2) pixel grid has Z away from the camera."""
    dX = grid[:-1, 1:] - grid[:-1, :-1]
    dY = grid[1:, :-1] - grid[:-1, :-1]
    return float(np.sum(dX[..., 0] * dY[..., 1] - dX[..., 1] * dY[..., 0])) > 0


def _candidates(square: bool):
    """Index transforms that keep a grid's shape: identity, half turn and the two flips, and
    for a square grid the same after a transpose."""
    flips = [lambda g: g, lambda g: g[::-1, ::-1], lambda g: g[:, ::-1], lambda g: g[::-1, :]]
    return flips + ([lambda g, f=f: f(np.swapaxes(g, 0, 1)) for f in flips] if square else [])


def order_grid(grid_px: np.ndarray, colours: SquareColours, board: Board):
    """Put a detected (rows, cols, 2) grid into the contract's corner order.

    Corner 0 is an inner corner whose diagonally-outside square is black, with X along ``cols``
    and Y along ``rows``. When ``cols + rows`` is even, one diagonal of the board has black
    squares at its ends and the other white ones; on most boards (dualcal's, OpenCV's) it is the
    diagonal where the frame is right-handed with Z into the board. Boards printed the other way
    (BoofCV's ECoCheck, a chessboard of 14 x 10 squares whose top-left square is white) have no
    such corner: they are numbered from a black end with the frame right-handed with Z towards
    the camera (``mirrored``), which is as rigid a board frame as the other (the board is flat in
    it, Z = 0), the same in every photo of that board.

    Returns
    -------
    uv : (rows*cols, 2) corners, corner ``k = r*cols + c``.
    ambiguous : True when the board is 180-degree symmetric and the corner nearest the
        image's top-left was taken as corner 0.
    mirrored : True when the board's frame has Z towards the camera (see above).
    """
    R, C = grid_px.shape[:2]
    if (R, C) != (board.rows, board.cols):
        raise DetectionError(f"grid of {C}x{R} corners, expected {board.cols}x{board.rows}")
    idx = np.stack(np.meshgrid(np.arange(C), np.arange(R)), -1)          # idx[r, c] = (c, r)
    fits = {True: [], False: []}
    for f in _candidates(R == C):
        g, i = f(grid_px), f(idx)
        # square (-1, -1) of the candidate has the colour of its square (0, 0): the cell
        # between its corners [0,0], [0,1], [1,0], [1,1], whose lowest index-frame corner is:
        a0, b0 = np.min(i[:2, :2].reshape(-1, 2), axis=0)
        if ((a0 + b0) % 2 == 0) == colours.even_is_dark:
            fits[right_handed(g)].append(g)
    mirrored = not fits[True]
    keep = fits[not mirrored]
    if not keep:
        raise DetectionError("no corner ordering is consistent with the board's colours")
    ambiguous = len(keep) > 1
    if ambiguous:
        keep.sort(key=lambda g: float(np.hypot(*g[0, 0])))
    return keep[0].reshape(-1, 2), ambiguous, mirrored
