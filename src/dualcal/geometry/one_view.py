"""What one photo of a planar board tells on its own: its camera's focal length and the board's pose.

A camera roll whose photos carry no EXIF (:mod:`dualcal.files.roll`) is told apart into cameras by what each
photo shows, before any camera is calibrated. One view of a board fixes a homography (8 numbers); a
camera with square pixels, no skew and its principal point at the image centre has one unknown left,
its focal length, which Zhang's two constraints on the view (paper section 1.4, eqs. 9-10) then give:
with ``B = K^-T K^-1 = diag(1/f^2, 1/f^2, 1)`` in pixels centred on the image,

    h1^T B h2 = 0,        h1^T B h1 = h2^T B h2,

two equations, linear in ``1/f^2``, solved by least squares (:func:`focal_from_homography`). The principal
point of a phone's camera lies within a few percent of the centre, which moves ``f`` far less than the
factor of 1.5-3 between its lenses.

Lens distortion bends the board's lines and biases that focal length (an ultra-wide's by half), so the
homography is fitted to corners undistorted by the one-parameter division model (Fitzgibbon's),
``u = c + (u_d - c) / (1 + lam r_d^2)`` with ``c`` the image centre and ``r_d`` the distance from it in
half-diagonals, ``lam`` chosen to minimise the homography's misfit (:func:`division_homography`).

The focal length of one view is as good as the board's perspective is strong: a board seen square-on
gives none. Its spread is measured, not modelled: the same computation on four interleaved quarters of
the corners (:func:`one_view`, ``f_log_sigma``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import EstimationError
from .model import Pose, observed_mask
from .zhang import (MIN_HOMOGRAPHY_CORNERS, apply_homography, common_focal, estimate_homographies,
                    extrinsics_from_homography)

__all__ = ["OneView", "board_pixels", "board_pose", "spread_px", "common_division", "division_homography", "division_misfits",
           "focal_from_homography", "one_view", "undistort_division"]

#: The division model's coefficient is searched in this range (per squared half-diagonal); ``1 + lam r^2``
#: stays positive over the image.
LAMBDA_RANGE = (-0.9, 0.6)
#: A division model is used where it lowers the homography's squared residuals by more than this many times their
#: variance per coordinate (a chi-square of one degree of freedom at five sigma).
LAMBDA_SIGNIFICANCE = 25.0
#: The spread of one view's log focal length never counts as less than this (the principal point is not
#: exactly at the centre, and the division model is not the lens).
MIN_F_LOG_SIGMA = 0.03


@dataclass(frozen=True)
class OneView:
    """One photo's board, alone.

    ``H`` (3, 3) maps board ``(X, Y)`` mm to pixels undistorted by the division model with ``lam``
    (:func:`undistort_division`); ``H_quarters`` (4, 3, 3) the same from each interleaved quarter of the
    corners (NaN where one cannot be had), whose spread measures what the view fixes; ``misfit_px`` is the
    RMS of the homography's residuals (in the photo's pixels); ``f_px`` the focal length the view gives
    (NaN where it gives none) and ``f_log_sigma`` the spread of its natural logarithm (inf where unknown);
    ``tilt_deg`` the angle between the board's normal and the optical axis with that focal length (NaN without
    one: the less the tilt, the more the focal length suffers from what the model leaves out, the principal
    point off the centre and the lens); ``image_size`` is ``(W, H)``.
    """

    H: np.ndarray
    H_quarters: np.ndarray
    lam: float
    misfit_px: float
    f_px: float
    f_log_sigma: float
    tilt_deg: float
    image_size: tuple[int, int]


def board_pixels(view: OneView, xy_board: np.ndarray) -> np.ndarray:
    """(N, 2) where ``view``'s homography puts the board points ``xy_board`` (N, 2) mm: pixels undistorted by
    its division model."""
    return apply_homography(view.H, xy_board)


def spread_px(points: np.ndarray) -> float:
    """The size of a set of (N, 2) image points: the RMS distance of the points from their centre."""
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def _centre_and_scale(image_size) -> tuple[np.ndarray, float]:
    w, h = image_size
    return np.array([(w - 1) / 2.0, (h - 1) / 2.0]), 0.5 * float(np.hypot(w, h))


def undistort_division(uv: np.ndarray, lam: float, image_size) -> np.ndarray:
    """(N, 2) pixels undistorted by the division model ``u = c + (u_d - c) / (1 + lam r_d^2)`` (module docstring)."""
    c, s = _centre_and_scale(image_size)
    d = np.asarray(uv, float) - c
    return c + d / (1.0 + lam * np.sum(d * d, axis=-1, keepdims=True) / s**2)


def _misfits(xy: np.ndarray, uv: np.ndarray, lams: np.ndarray, image_size):
    """The homographies of ``uv`` undistorted with each of ``lams``, and their misfits in distorted pixels."""
    c, s = _centre_and_scale(image_size)
    d = uv - c
    pts = c + d / (1.0 + lams[:, None, None] * np.sum(d * d, axis=1)[None, :, None] / s**2)      # (L, N, 2)
    Hs = np.array(estimate_homographies(xy, pts, np.ones(pts.shape[:2], bool), refine=False))
    q = np.einsum("lij,nj->lni", Hs, np.column_stack([xy, np.ones(len(xy))]))
    residual = np.sum((q[..., :2] / q[..., 2:] - pts) ** 2, axis=2)
    # residuals in undistorted pixels, scaled back by the model's magnification of the board
    spread = np.sqrt(np.sum((pts - pts.mean(axis=1, keepdims=True)) ** 2, axis=(1, 2)))
    magnification = spread / np.linalg.norm(uv - uv.mean(axis=0))
    return Hs, np.sqrt(residual.mean(axis=1)) / magnification


def division_homography(xy_board: np.ndarray, uv: np.ndarray, image_size) -> tuple[np.ndarray, float, float]:
    """The homography of a view's corners undistorted by the division model that fits them best.

    Parameters
    ----------
    xy_board : (N, 2) board points, mm.
    uv : (N, 2) their pixels (all measured).
    image_size : (W, H).

    Returns
    -------
    ``(H, lam, misfit_px)``: see :class:`OneView`. ``lam`` is found on a grid over :data:`LAMBDA_RANGE`, then on
    two finer grids around the best point (to 0.2 % of the range); it is kept only where it lowers the squared
    residuals by more than :data:`LAMBDA_SIGNIFICANCE` times their variance (a small board near the centre
    does not fix it, and a wrong one turns the board's pose), else 0.
    """
    lo, hi = LAMBDA_RANGE
    for _ in range(3):
        grid = np.linspace(lo, hi, 11)
        Hs, misfit = _misfits(xy_board, uv, grid, image_size)
        i = int(np.argmin(misfit))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    (H0,), (m0,) = _misfits(xy_board, uv, np.zeros(1), image_size)
    variance = max(misfit[i], 1e-3) ** 2 / 2.0                # per coordinate
    if len(uv) * (m0**2 - misfit[i] ** 2) < LAMBDA_SIGNIFICANCE * variance:
        return H0, 0.0, float(m0)
    return Hs[i], float(grid[i]), float(misfit[i])


def _summed_squares(xy: np.ndarray, uvs: np.ndarray, seen: np.ndarray, lam: float, image_size) -> float:
    """The squared residuals of every view's homography (``uvs`` (V, N, 2), ``seen`` (V, N)) with the corners
    undistorted by ``lam``, summed, each view's scaled back to its distorted pixels."""
    pts = np.where(seen[..., None], undistort_division(np.where(seen[..., None], uvs, 0.0), lam, image_size), 0.0)
    Hs = np.array(estimate_homographies(xy, pts, seen, refine=False))
    q = np.einsum("vij,nj->vni", Hs, np.column_stack([xy, np.ones(len(xy))]))
    residual = np.where(seen, np.sum((q[..., :2] / q[..., 2:] - pts) ** 2, axis=2), 0.0)
    n = seen.sum(axis=1)

    def spread(p):
        mean = np.where(seen[..., None], p, 0.0).sum(axis=1) / n[:, None]
        return np.sqrt(np.where(seen, np.sum((p - mean[:, None]) ** 2, axis=2), 0.0).sum(axis=1))

    magnification = spread(pts) / spread(np.where(seen[..., None], uvs, 0.0))
    return float(np.sum(residual.sum(axis=1) / magnification**2))


def division_misfits(xy_board: np.ndarray, uv: np.ndarray, image_size, lams) -> np.ndarray:
    """(L,) the misfit (RMS, the photo's pixels) of a view's homography with its measured corners (``uv``, NaN rows
    for the others) undistorted by each of ``lams``: how well each lens's bend fits the view."""
    seen = observed_mask(uv)
    return _misfits(np.asarray(xy_board, float)[seen], np.asarray(uv, float)[seen], np.asarray(lams, float),
                    image_size)[1]


def common_division(xy_board: np.ndarray, uvs, image_size) -> float:
    """The division model's ``lam`` that fits the homographies of several views of one camera best together
    (their summed squared residuals; grids refined as in :func:`division_homography`): the views whose board
    lies near the image's edge fix it for those near its centre. ``uvs``: (N, 2) pixels per view, NaN rows
    for corners not measured; without any view, 0."""
    if len(uvs) == 0:
        return 0.0
    uvs = np.asarray(uvs, float).reshape(-1, len(xy_board), 2)
    seen = observed_mask(uvs)
    lo, hi = LAMBDA_RANGE
    for _ in range(3):
        grid = np.linspace(lo, hi, 11)
        cost = [_summed_squares(xy_board, uvs, seen, lam, image_size) for lam in grid]
        i = int(np.argmin(cost))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    return float(grid[i])


def focal_from_homography(H: np.ndarray, image_size) -> float:
    """The focal length (pixels) that one view's homography gives a camera with square pixels, no skew
    and its principal point at the image centre (module docstring; :func:`dualcal.geometry.zhang.common_focal`
    of the one view), or NaN where it gives none (a board seen square-on, or noise that makes ``1/f^2``
    negative)."""
    return common_focal([H], image_size)


def one_view(xy_board: np.ndarray, uv: np.ndarray, image_size, lam: float | None = None) -> OneView | None:
    """What one photo's detected board tells alone (:class:`OneView`), or None with fewer than 8 corners.

    ``lam``: the division model's coefficient, where it is known (:func:`common_division`); else the view's own
    (:func:`division_homography`).

    ``f_log_sigma`` is the standard deviation of the log focal lengths of four interleaved quarters of the
    corners (every other column of every other row: each a quarter as many corners, so their spread is
    twice the whole's), at least :data:`MIN_F_LOG_SIGMA`.
    """
    seen = observed_mask(uv)
    if seen.sum() < 2 * MIN_HOMOGRAPHY_CORNERS:
        return None
    xy, pts = np.asarray(xy_board, float)[seen], np.asarray(uv, float)[seen]
    try:
        if lam is None:
            H, lam, misfit = division_homography(xy, pts, image_size)
        else:
            (H,), (misfit,) = _misfits(xy, pts, np.array([lam]), image_size)
    except EstimationError:
        return None
    f = focal_from_homography(H, image_size)
    undistorted = undistort_division(pts, lam, image_size)
    # the quarters: every other column of every other row, so that each spans the board
    col = np.unique(np.round(xy[:, 0], 6), return_inverse=True)[1]
    row = np.unique(np.round(xy[:, 1], 6), return_inverse=True)[1]
    quarter = col % 2 + 2 * (row % 2)
    parts = quarter[None, :] == np.arange(4)[:, None]
    try:
        Hq = np.array(estimate_homographies(xy, np.broadcast_to(undistorted, (4, *undistorted.shape)), parts,
                                            refine=False))
        logs = np.log([focal_from_homography(H, image_size) for H in Hq])
    except EstimationError:
        Hq, logs = np.full((4, 3, 3), np.nan), np.full(4, np.nan)
    sigma = np.inf if not np.isfinite(f) or not np.all(np.isfinite(logs)) else max(np.std(logs) / 2, MIN_F_LOG_SIGMA)
    view = OneView(H, Hq, lam, misfit, float(f), float(sigma), float("nan"), tuple(int(v) for v in image_size))
    if np.isfinite(f):
        tilt = np.degrees(np.arccos(min(1.0, abs(board_pose(view, f).R[2, 2]))))
        view = replace(view, tilt_deg=float(tilt))
    return view


def board_pose(view: OneView, f_px: float, H: np.ndarray | None = None) -> Pose:
    """The board-to-camera pose of a view for a camera of focal length ``f_px`` with its principal point at
    the image centre (paper section 1.5 on the view's homography, or on ``H``, one of its quarters')."""
    c, _ = _centre_and_scale(view.image_size)
    K = np.array([[f_px, 0.0, c[0]], [0.0, f_px, c[1]], [0.0, 0.0, 1.0]])
    return extrinsics_from_homography(K, view.H if H is None else H)
