"""Geometry of a detected grid of corners: local spacing, leave-one-out prediction, checks.

Pure functions over (N, 2) arrays of pixels in the contract's corner order (corner
``k = r*cols + c``), where a corner that was not measured is a NaN row
(:func:`dualcal.geometry.model.observed_mask`). Nothing here reads an image, so the checks are tested
on stored real grids (``tests/data``).

The check of a corner is its distance from where its neighbours put it
(:func:`neighbour_predictions`): a homography fitted to the measured corners around it (it left
out), with a quadratic correction for the bending by the lens, maps its board position into
the image. Over two squares that follows perspective exactly and lens distortion to within
its third-order change, so exact corners sit within a few hundredths of a pixel of their
predictions (``tests/test_detect.py``); what a real photo adds is its corner noise (0.1-0.3 px
on the real sets) and its board's own departures from a true grid, while a corner measured on
the wrong feature, or pulled by glare or a smudge, stands out by more.
"""

from __future__ import annotations

import functools

import numpy as np

from .board import Board
from .model import observed_mask

__all__ = ["local_spacing_px", "neighbour_predictions", "predict_from_neighbours", "neighbour_residuals_px",
           "typical_residual_px", "outlier_limit_px", "corner_noise_px", "worst_outlier", "min_corners", "validate_grid"]

#: An accepted corner lies within ``OUTLIER_TIMES`` the typical neighbour residual around it
#: (:func:`typical_residual_px`: the larger of its neighbours' median and the photo's) of its neighbours'
#: prediction (:func:`outlier_limit_px`): about 6 standard deviations of the photo's own corner noise (the median
#: of a 2-D residual's length is 1.18 of its per-coordinate deviation), so that only a corner on the wrong
#: feature, or pulled by glare or a smudge by many times the noise, is left out. The scale is the photo's own,
#: whatever its noise: a defocused photo's corners are noisier, not wrong, and how much each photo's noise costs
#: is the adjustment's to weigh. The typical residual is local because what the prediction cannot follow of a
#: board that is not flat (a sheet curled on a table) is shared by the corners around, and raises their limit
#: with them, where the rest of the board is flat: on steep 960 x 720 renders of a sheet whose far end curls up
#: by 10 mm, 23 of 2592 exact corners (0.05 px of noise) were off a limit of 4 x the photo's median, none with the
#: local one. What such a board's corners keep of its shape is the adjustment's to judge.
OUTLIER_TIMES = 5.0
#: ... but never below this share of the corner's spacing: on a sharp photo the noise is a few hundredths of a
#: pixel, below what the prediction itself cannot follow of a lens's bending and a sheet's curl near the board's
#: edge (on the steep 960 x 720 renders of curled sheets: exact corners up to 1.2 % of a square off their
#: prediction, 0.36 px), and a corner within 2 % of a square of its neighbours' prediction is on the right
#: feature: one on the wrong feature is off by a good part of a square. Whether it is as precise as the others
#: is for the adjustment to judge.
OUTLIER_FLOOR_SHARE = 0.02
#: Fewest measured neighbours for which :func:`predict_from_neighbours` fits a cubic, not a quadratic,
#: to what the homography leaves (its 10 coefficients with 4 to spare).
CUBIC_NEIGHBOURS = 14
#: The gain (:func:`predict_from_neighbours`) of an inner corner's prediction from its full
#: 5 x 5 patch; a corner whose prediction carries more noise (the board's edge, 0.65-0.8, and
#: its four corners, about 2) gets a limit larger by sqrt(1 + gain^2) / sqrt(1 + INNER_GAIN^2).
INNER_GAIN = 0.43


def _grid(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return np.asarray(uv, float).reshape(shape[0], shape[1], 2)


def local_spacing_px(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N,) distance from each corner to its nearest measured grid neighbour (of the eight), pixels.

    This bounds the window a corner may be refined in without seeing another corner. NaN for a
    corner that is not measured or has no measured neighbour.
    """
    g = _grid(uv, shape)
    R, C = shape
    pad = np.full((R + 2, C + 2, 2), np.nan)
    pad[1:-1, 1:-1] = g
    best = np.full((R, C), np.inf)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                d = np.linalg.norm(pad[1 + dr:R + 1 + dr, 1 + dc:C + 1 + dc] - g, axis=2)
                best = np.fmin(best, d)
    best[~np.isfinite(best)] = np.nan
    return best.ravel()


def _neighbourhoods(shape: tuple[int, int]):
    """(N, M) indices of each corner's neighbours and their (N, M, 2) offsets ``(dc, dr)``.

    A corner's neighbours are the other corners within two rows and columns (a 5 x 5 patch,
    cut at the board's edge: ``M = 24``, indices -1 outside the board).
    """
    R, C = shape
    offs = np.array([(dc, dr) for dr in range(-2, 3) for dc in range(-2, 3) if dr or dc])
    r, c = np.divmod(np.arange(R * C), C)
    rr, cc = r[:, None] + offs[None, :, 1], c[:, None] + offs[None, :, 0]
    inside = (rr >= 0) & (rr < R) & (cc >= 0) & (cc < C)
    idx = np.where(inside, rr * C + cc, -1)
    return idx, np.broadcast_to(offs, idx.shape + (2,)).astype(float)


def neighbour_predictions(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N, 2) position of every corner predicted from its neighbours, leaving itself out.

    See :func:`predict_from_neighbours`, which also says how sensitive each prediction is.
    """
    return predict_from_neighbours(uv, shape)[0]


def predict_from_neighbours(uv: np.ndarray, shape: tuple[int, int]):
    """Leave-one-out predictions of every corner and their sensitivity to the neighbours' errors.

    Parameters
    ----------
    uv : (N, 2) corners in grid order (row-major, ``shape[1]`` per row); NaN rows are unmeasured.
    shape : ``(rows, cols)``.

    Returns
    -------
    pred : (N, 2) predictions, NaN where a corner has fewer than 8 measured neighbours within
        two rows and columns.
    gain : (N,) how much of a neighbour's error reaches the prediction: the root sum of squares
        of the weights of the neighbours in a quadratic fit (about 0.4 for an inner corner, 2-3
        for a corner of the board, whose prediction is an extrapolation).

    Notes
    -----
    The neighbours are the measured corners of the 5 x 5 patch around the corner (cut at the
    board's edge). A homography from their board offsets ``(dc, dr)`` to the image is fitted by
    the direct linear transform (on coordinates centred on their mean and scaled by their
    spread); a polynomial in ``(dc, dr)`` is then fitted to what the homography leaves, and both
    are evaluated at offset ``(0, 0)``. The homography follows perspective exactly; the
    polynomial takes up the bending of the grid lines by the lens, which over two squares of a
    640 x 480 photo with k1 = -0.29 leaves the true corners of the real stereo set 0.5-0.8 px off
    a homography alone, and by a board that is not flat (a sheet of paper curled on a table). It is
    cubic where at least :data:`CUBIC_NEIGHBOURS` neighbours are measured, else quadratic: at an
    inner corner whose patch is symmetric the cubic terms cancel, but near the board's edge, where
    the patch is cut, they do not (measured on exact corners of 960 x 720 renders 50-70 degrees off
    frontal through k1 = -0.29: the largest residual near the edge 0.18 px with a quadratic, 0.04 with
    a cubic; 0.23 and 0.07 on a sheet whose edges rise 10 mm over 200 mm).

    Memoised on the values: a photo's detection asks it of the same corners to drop outliers, to check the grid
    and to measure the photo's noise. The arrays returned are shared, and read-only.
    """
    uv = np.ascontiguousarray(uv, float)
    return _predicted(uv.tobytes(), len(uv), tuple(int(n) for n in shape))


@functools.lru_cache(maxsize=64)
def _predicted(uv_bytes: bytes, n: int, shape: tuple[int, int]):
    """:func:`predict_from_neighbours` of corners given by their bytes (hashable, so that it can be memoised)."""
    uv = np.frombuffer(uv_bytes).reshape(n, 2)
    use = observed_mask(uv)
    idx, offs = _neighbourhoods(shape)
    valid = (idx >= 0) & use[np.maximum(idx, 0)]
    enough = valid.sum(axis=1) >= 8
    pts = np.where(valid[..., None], uv[np.maximum(idx, 0)], 0.0)          # (N, M, 2)
    w = valid.astype(float)
    n = np.maximum(w.sum(axis=1), 1.0)
    mean = (pts * w[..., None]).sum(axis=1) / n[:, None]
    spread = np.sqrt((((pts - mean[:, None]) ** 2).sum(axis=2) * w).sum(axis=1) / n) + 1e-12
    p = (pts - mean[:, None]) / spread[:, None, None]
    x, y = offs[..., 0], offs[..., 1]
    u, v = p[..., 0], p[..., 1]
    z, o = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([x, y, o, z, z, z, -u * x, -u * y, -u], axis=-1)
    rows_v = np.stack([z, z, z, x, y, o, -v * x, -v * y, -v], axis=-1)
    A = np.concatenate([rows_u, rows_v], axis=1) * np.concatenate([w, w], axis=1)[..., None]
    # the null vector of A: eigenvector of the smallest eigenvalue of A^T A (coordinates are
    # normalised, so the 9 x 9 normal matrix is well conditioned; far cheaper than an SVD of A)
    _, vecs = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)
    h = vecs[:, :, 0]                                                         # (N, 9)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = h[:, None, 6] * x + h[:, None, 7] * y + h[:, None, 8]
        fitted = np.stack([(h[:, None, 0] * x + h[:, None, 1] * y + h[:, None, 2]) / den,
                           (h[:, None, 3] * x + h[:, None, 4] * y + h[:, None, 5]) / den], axis=-1)
        at_zero = np.stack([h[:, 2], h[:, 5]], axis=1) / h[:, 8:9]
    left = np.where(valid[..., None], p - fitted, 0.0)                       # (N, M, 2)
    cubic = (valid.sum(axis=1) >= CUBIC_NEIGHBOURS).astype(float)[:, None]
    Q = np.stack([o, x, y, x * x, x * y, y * y] + [t * cubic for t in (x**3, x * x * y, x * y * y, y**3)],
                 axis=-1) * w[..., None]                                     # (N, M, 10)
    with np.errstate(invalid="ignore"):
        Qt = np.swapaxes(Q, 1, 2)
        Qinv = np.linalg.solve(Qt @ Q + 1e-9 * np.eye(10), Qt)              # (N, 10, M)
        coef = Qinv @ left                                                   # (N, 10, 2)
    with np.errstate(invalid="ignore"):      # corners with too few neighbours: NaN below
        pred = (at_zero + coef[:, 0, :]) * spread[:, None] + mean
    pred[~enough | ~np.all(np.isfinite(pred), axis=1)] = np.nan
    gain = np.sqrt(np.sum(Qinv[:, 0, :] ** 2, axis=1))
    pred.setflags(write=False)
    gain.setflags(write=False)
    return pred, gain


def neighbour_residuals_px(uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N,) distance of each corner from its neighbours' prediction (NaN where it cannot be judged)."""
    return np.linalg.norm(np.asarray(uv, float) - neighbour_predictions(uv, shape), axis=1)


def typical_residual_px(residual_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N,) the typical neighbour residual around each corner: the larger of the median residual of its
    neighbours within two rows and columns (itself left out; at least 4 of them judged) and the photo's
    median. ``residual_px`` (N,): each corner's distance from its neighbours' prediction, NaN where it
    cannot be judged."""
    res = np.asarray(residual_px, float)
    finite = np.isfinite(res)
    if not finite.any():
        return np.zeros(len(res))
    idx, _ = _neighbourhoods(shape)
    around = np.where(idx >= 0, res[np.maximum(idx, 0)], np.nan)
    enough = np.sum(np.isfinite(around), axis=1) >= 4
    local = np.full(len(res), -np.inf)
    if enough.any():
        local[enough] = np.nanmedian(around[enough], axis=1)
    return np.maximum(local, float(np.median(res[finite])))


def outlier_limit_px(spacing_px: np.ndarray, typical_px, gain=INNER_GAIN,
                     floor_share: float = OUTLIER_FLOOR_SHARE) -> np.ndarray:
    """Largest accepted neighbour residual of corners ``spacing_px`` from their nearest neighbour.

    ``typical_px`` is the typical neighbour residual around each corner (:func:`typical_residual_px`:
    the corner noise and what the prediction cannot follow of the board's shape), ``gain`` that of
    each corner's prediction; see :data:`OUTLIER_TIMES`, :data:`OUTLIER_FLOOR_SHARE` (``floor_share``) and
    :data:`INNER_GAIN` for the rule.
    """
    noise = np.sqrt((1.0 + np.asarray(gain, float) ** 2) / (1.0 + INNER_GAIN**2))
    return (np.maximum(OUTLIER_TIMES * np.asarray(typical_px, float), floor_share * np.asarray(spacing_px, float))
            * np.maximum(noise, 1.0))


#: The median length of a 2-D residual whose coordinates are independent with standard deviation 1 (the
#: Rayleigh distribution's median, sqrt(2 ln 2)).
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))


def corner_noise_px(uv: np.ndarray, shape: tuple[int, int]) -> float:
    """A photo's corner noise: the standard deviation of one coordinate of a corner, pixels, estimated robustly
    from the photo itself, NaN where no corner can be judged.

    Each corner's distance from its neighbours' prediction (:func:`predict_from_neighbours`) carries its own
    noise and, through the prediction, its neighbours' (``1 + gain^2`` times the variance); divided by that, the
    median over the photo's corners is :data:`RAYLEIGH_MEDIAN` standard deviations. The median ignores a few
    corners on the wrong feature, but what the prediction cannot follow of the board's shape counts as noise.
    """
    uv = np.asarray(uv, float)
    pred, gain = predict_from_neighbours(uv, shape)
    scaled = np.linalg.norm(uv - pred, axis=1) / np.sqrt(1.0 + gain**2)
    scaled = scaled[np.isfinite(scaled)]
    return float(np.median(scaled) / RAYLEIGH_MEDIAN) if len(scaled) else float("nan")


def worst_outlier(uv: np.ndarray, shape: tuple[int, int], spacing_px: np.ndarray | None = None,
                  candidates: int = 8, judged: np.ndarray | None = None, floor_share: float = OUTLIER_FLOOR_SHARE):
    """The corner to reject first, or None when every corner that can be judged is within its limit.

    Parameters
    ----------
    uv : (N, 2) corners in grid order, NaN rows unmeasured.
    shape : ``(rows, cols)``.
    spacing_px : (N,) spacing that sets each corner's limit; default :func:`local_spacing_px` of ``uv``.
    candidates : how many of the corners over the photo's limit are tried (see below).
    judged : (N,) bool, the corners that may be judged (default: all); the others still predict
        their neighbours.
    floor_share : the limit's floor, a share of the spacing (:func:`outlier_limit_px`).

    Returns
    -------
    ``(k, residual_px)`` or None.

    Notes
    -----
    One bad corner also spoils the predictions of its neighbours: it raises their residuals, and with them
    the typical residual around itself (:func:`typical_residual_px`), by which it would hide; and it can
    push the extrapolated prediction of a board corner next to it further than its own residual. So the
    corners over the limit the photo's median residual sets (which no corner can raise) are candidates, the
    ``candidates`` of them whose residual is largest for the noise their prediction carries (residual /
    sqrt(1 + gain^2), :func:`predict_from_neighbours`) first: each is left out in turn, its own limit is set
    by the typical residual around it without it, and of those over that limit, the one whose absence
    leaves the others closest to their predictions (least sum of squared residual / limit) is the corner to
    reject.
    """
    uv = np.asarray(uv, float)
    pred, gain = predict_from_neighbours(uv, shape)
    res = np.linalg.norm(uv - pred, axis=1)
    finite = np.isfinite(res)           # every corner with a prediction sets the scale, whether it may be judged or not
    if not finite.any():
        return None
    if spacing_px is None:
        spacing_px = local_spacing_px(uv, shape)
    over = finite & (res > outlier_limit_px(spacing_px, np.median(res[finite]), gain, floor_share))
    if judged is not None:
        over &= np.asarray(judged, bool)
    if not over.any():
        return None
    z = np.where(over, res / np.sqrt(1.0 + gain**2), -np.inf)
    best = None
    for k in np.argsort(-z)[: min(candidates, int(over.sum()))]:
        without = uv.copy()
        without[k] = np.nan
        others = np.linalg.norm(without - neighbour_predictions(without, shape), axis=1)
        limit = outlier_limit_px(spacing_px, typical_residual_px(others, shape), gain, floor_share)
        if res[k] <= limit[k]:
            continue
        r = others / limit
        left_over = float(np.sum(np.where(np.isfinite(r), r * r, 0.0)))
        if best is None or left_over < best[0]:
            best = (left_over, int(k))
    return None if best is None else (best[1], float(res[best[1]]))


#: Fewest corners of a ChArUco photo (:func:`min_corners`).
MIN_CHARUCO_CORNERS = 6


def min_corners(board: Board, whole: bool = False) -> int:
    """Fewest measured corners for a photo to be kept: at least 6, and more than half of a chessboard that was
    not found whole.

    At least 6, so that the photo's homography (8 unknowns) has redundancy: 12 equations, 4 more than the
    unknowns, enough for a wrong corner to show in the fit and to be told from the others. A chessboard that
    OpenCV's detector found whole (``whole``: every corner in order, its squares' colours checked) needs no
    more: the corners a photo lost at its checks are its outliers, and a blurred photo's noisier corners are
    kept, not lost. A board placed from a part of it, or predicted from four clicks, needs more than half of
    its corners, so that the photo still shows most of the board and its extent still constrains the pose. A
    ChArUco photo may show any part of its board (the markers number the corners, and every corner was checked
    against them), so it needs only those :data:`MIN_CHARUCO_CORNERS`, not on one line.
    """
    if board.charuco is not None or whole:
        return MIN_CHARUCO_CORNERS
    return max(MIN_CHARUCO_CORNERS, board.n_corners // 2 + 1)


def validate_grid(uv: np.ndarray, board: Board, judged: np.ndarray | None = None, whole: bool = False) -> str | None:
    """Why a detected grid is not a ``board`` seen by a camera, or None when it is.

    Parameters
    ----------
    uv : (N, 2) corners in the contract's order, NaN rows where a corner was rejected.
    board : the board.
    judged : (N,) bool, the corners to check against their neighbours (default: all).
    whole : the grid was found whole by OpenCV's detector (:func:`min_corners`).

    Returns
    -------
    A one-line reason, or None. Checked: the number of measured corners
    (:func:`min_corners`), not all on one line; every grid cell with four measured corners is a convex quadrilateral
    turning the same way as the others (no fold, no crossed rows); every measured corner that
    can be judged sits within :func:`outlier_limit_px` of its neighbours' prediction
    (:func:`worst_outlier`).
    """
    uv = np.asarray(uv, float)
    if uv.shape != (board.n_corners, 2):
        return f"{len(uv)} corners, expected {board.n_corners}"
    shape = (board.rows, board.cols)
    seen = observed_mask(uv)
    need = min_corners(board, whole)
    if seen.sum() < need:
        why = "more than half of the board" if need > MIN_CHARUCO_CORNERS else "for a homography with redundancy"
        return (f"only {int(seen.sum())} of {board.n_corners} corners passed their checks "
                f"(at least {need} needed: {why})")
    r, c = np.divmod(np.flatnonzero(seen), board.cols)
    if min(np.linalg.matrix_rank(np.column_stack([r - r.mean(), c - c.mean()])), 2) < 2:
        return f"its {int(seen.sum())} corners lie on one line of the board (a homography needs them to span it)"
    g = _grid(uv, shape)
    quad = np.stack([g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]], axis=2)     # (R-1, C-1, 4, 2)
    edge = np.roll(quad, -1, axis=2) - quad
    turn = edge[..., 0] * np.roll(edge, -1, axis=2)[..., 1] - edge[..., 1] * np.roll(edge, -1, axis=2)[..., 0]
    full = np.all(np.isfinite(turn), axis=2)
    if full.any():
        signs = np.sign(turn[full])
        majority = np.sign(np.sum(signs))
        if majority == 0 or np.any(signs != majority):
            r, c = np.argwhere(full)[np.flatnonzero(np.any(signs != majority, axis=1))[0]]
            return f"the grid folds over itself at the cell of corner {r * board.cols + c}"
    worst = worst_outlier(uv, shape, judged=judged)
    if worst is not None:
        return f"corner {worst[0]} is {worst[1]:.2f} px from where its neighbours put it"
    return None
