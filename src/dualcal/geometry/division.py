"""The one-parameter division model of a lens (Fitzgibbon's), fitted to a board's homographies: the starts of a
calibration and of a photo alone, before any lens is known.

Lens distortion bends the board's lines, and a homography takes the bend for perspective, which the closed forms
read as a focal length. So the homographies are fitted to corners undistorted by
``u = c + (u_d - c) / (1 + lam r_d^2)``, ``c`` the image centre and ``r_d`` the distance from it in half-diagonals,
with ``lam`` chosen to minimise their misfit: one view's own (:func:`division_homography`), or that of several
views of one camera together (:func:`common_division`), where the views whose board lies near the image's edge fix
it for those near its centre.
"""

from __future__ import annotations

import numpy as np

from .homography import estimate_homographies
from .model import observed_mask

__all__ = ["DIVISION_GRID", "DIVISION_PARABOLAS", "DIVISION_VIEWS", "LAMBDA_RANGE", "LAMBDA_SIGNIFICANCE",
           "centre_and_scale", "common_division", "division_homography", "division_misfits", "undistort_division"]

#: The division model's coefficient is searched in this range (per squared half-diagonal); ``1 + lam r^2``
#: stays positive over the image.
LAMBDA_RANGE = (-0.9, 0.6)
#: A division model is used where it lowers the homography's squared residuals by more than this many times their
#: variance per coordinate (a chi-square of one degree of freedom at five sigma).
LAMBDA_SIGNIFICANCE = 25.0


def centre_and_scale(image_size) -> tuple[np.ndarray, float]:
    """The division model's centre ``c`` (2,), the image's, and its unit of distance, the half-diagonal (pixels)."""
    w, h = image_size
    return np.array([(w - 1) / 2.0, (h - 1) / 2.0]), 0.5 * float(np.hypot(w, h))


def undistort_division(uv: np.ndarray, lam: float, image_size) -> np.ndarray:
    """(N, 2) pixels undistorted by the division model ``u = c + (u_d - c) / (1 + lam r_d^2)`` (module docstring)."""
    c, s = centre_and_scale(image_size)
    d = np.asarray(uv, float) - c
    return c + d / (1.0 + lam * np.sum(d * d, axis=-1, keepdims=True) / s**2)


def division_misfits(xy: np.ndarray, uv: np.ndarray, lams: np.ndarray, image_size):
    """The homographies of one view's corners ``uv`` (N, 2) undistorted with each of ``lams`` (L,), (L, 3, 3), and
    their misfits (L,) in distorted pixels (the RMS length of a corner's residual: :func:`_division_fits`)."""
    Hs, squares = _division_fits(xy, uv[None], np.ones((1, len(uv)), bool), lams, image_size)
    return Hs[:, 0], np.sqrt(squares[:, 0] / len(uv))


def division_homography(xy_board: np.ndarray, uv: np.ndarray, image_size) -> tuple[np.ndarray, float, float]:
    """The homography of a view's corners undistorted by the division model that fits them best.

    Parameters
    ----------
    xy_board : (N, 2) board points, mm.
    uv : (N, 2) their pixels (all measured).
    image_size : (W, H).

    Returns
    -------
    ``(H, lam, misfit_px)``: see :class:`dualcal.geometry.one_view.OneView`. ``lam`` is found on a grid over
    :data:`LAMBDA_RANGE`, then on two finer grids around the best point (to 0.2 % of the range); it is kept only
    where it lowers the squared residuals by more than :data:`LAMBDA_SIGNIFICANCE` times their variance (a small
    board near the centre does not fix it, and a wrong one turns the board's pose), else 0.
    """
    lo, hi = LAMBDA_RANGE
    for _ in range(3):
        grid = np.linspace(lo, hi, 11)
        Hs, misfit = division_misfits(xy_board, uv, grid, image_size)
        i = int(np.argmin(misfit))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    (H0,), (m0,) = division_misfits(xy_board, uv, np.zeros(1), image_size)
    variance = max(misfit[i], 1e-3) ** 2 / 2.0                # per coordinate
    if len(uv) * (m0**2 - misfit[i] ** 2) < LAMBDA_SIGNIFICANCE * variance:
        return H0, 0.0, float(m0)
    return Hs[i], float(grid[i]), float(misfit[i])


def _division_fits(xy: np.ndarray, uvs: np.ndarray, seen: np.ndarray, lams: np.ndarray, image_size):
    """For each of ``lams`` (L,), every view's homography of its corners (``uvs`` (V, N, 2), ``seen`` (V, N))
    undistorted by it, (L, V, 3, 3), and its squared residuals summed over its corners, scaled back to its distorted
    pixels by the model's magnification of its board, (L, V): the L x V homographies in one batch."""
    L, (V, N) = len(lams), seen.shape
    c, s = centre_and_scale(image_size)
    d = np.where(seen[..., None], uvs, c) - c                                              # (V, N, 2)
    pts = c + d / (1.0 + lams[:, None, None, None] * np.sum(d * d, axis=-1, keepdims=True) / s**2)   # (L, V, N, 2)
    on = np.broadcast_to(seen, (L, V, N))
    Hs = np.array(estimate_homographies(xy, pts.reshape(L * V, N, 2), on.reshape(L * V, N), refine=False))
    q = np.einsum("kij,nj->kni", Hs, np.column_stack([xy, np.ones(len(xy))])).reshape(L, V, N, 3)
    residual = np.where(on, np.sum((q[..., :2] / q[..., 2:] - pts) ** 2, axis=-1), 0.0)
    n = seen.sum(axis=1)

    def spread(p):
        mean = np.where(on[..., None], p, 0.0).sum(axis=-2) / n[:, None]
        return np.sqrt(np.where(on, np.sum((p - mean[..., None, :]) ** 2, axis=-1), 0.0).sum(axis=-1))

    magnification = spread(pts) / spread(np.broadcast_to(d, pts.shape))            # (L, V)
    return Hs.reshape(L, V, 3, 3), residual.sum(axis=-1) / magnification**2


#: :func:`common_division` looks at this many views at most: those whose corners reach furthest from the image's
#: centre, where a lens bends the board's image most (its cost grows with the views, the division model's fit does
#: not: a calibration's start is all it gives; on the synthetic presets and the real sets, 12 views give ``lam``
#: within 0.012 of 20 views', in 60 % of the time).
DIVISION_VIEWS = 12
#: :func:`common_division` evaluates this many ``lam`` evenly over :data:`LAMBDA_RANGE` (a step of 0.3, 0 among
#: them: a lens without distortion gets none), then refines the best by :data:`DIVISION_PARABOLAS` steps of
#: successive parabolic interpolation (the vertex of the parabola through the best point and its neighbours), where
#: the summed squares are smooth: on the synthetic presets and the real sets, ``lam`` within 0.0016 of an 11-point
#: grid's, in two thirds of the time.
DIVISION_GRID = 6
DIVISION_PARABOLAS = 3


def common_division(xy_board: np.ndarray, uvs, image_size) -> float:
    """The division model's ``lam`` that fits the homographies of several views of one camera best together
    (their summed squared residuals: the best of a grid, refined by :data:`DIVISION_PARABOLAS` parabolas): the
    views whose board lies near the image's edge fix it for those near its centre. ``uvs``: (N, 2) pixels per
    view, NaN rows for corners not measured; without any view, 0. Of more than :data:`DIVISION_VIEWS` views,
    those whose corners reach furthest from the image's centre."""
    if len(uvs) == 0:
        return 0.0
    xy_board = np.asarray(xy_board, float)
    uvs = np.asarray(uvs, float).reshape(-1, len(xy_board), 2)
    if len(uvs) > DIVISION_VIEWS:          # those whose corners reach furthest from the centre fix lam
        centre = 0.5 * (np.asarray(image_size, float) - 1.0)
        reach = np.nanmax(np.linalg.norm(uvs - centre, axis=2), axis=1)
        uvs = uvs[np.sort(np.argsort(-np.nan_to_num(reach, nan=-1.0), kind="stable")[:DIVISION_VIEWS])]
    seen = observed_mask(uvs)
    grid = np.linspace(*LAMBDA_RANGE, DIVISION_GRID)
    def summed_squares(lams):
        return _division_fits(xy_board, uvs, seen, lams, image_size)[1].sum(axis=1)

    cost = summed_squares(grid)
    i = int(np.argmin(cost))
    if i in (0, len(grid) - 1):              # at the range's end
        return float(grid[i])
    bracket = [(grid[j], cost[j]) for j in (i - 1, i, i + 1)]
    for _ in range(DIVISION_PARABOLAS):
        (a, fa), (b, fb), (c, fc) = bracket
        curvature = (b - a) * (fb - fc) - (b - c) * (fb - fa)
        if not curvature < 0:                # flat, or not a minimum's shape: the grid's best stands
            break
        x = b - 0.5 * ((b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)) / curvature
        if not a < x < c or x == b:
            break
        (fx,) = summed_squares(np.array([x]))
        if fx < fb:                          # x the new best, between b and the bracket's end on its side
            bracket = [(a, fa), (x, fx), (b, fb)] if x < b else [(b, fb), (x, fx), (c, fc)]
        else:                                # b still the best: the bracket closes in from x's side
            bracket = [(x, fx), (b, fb), (c, fc)] if x < b else [(a, fa), (b, fb), (x, fx)]
    return float(bracket[1][0])
