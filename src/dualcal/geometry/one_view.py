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

To tell a roll's lenses apart, :func:`view_lens` then adjusts the view's corners for its pose, its focal length,
the division model's coefficient and the principal point (a prior holds it near the centre), and keeps what the
corners say of those four as a normal (:class:`ViewLens`): the focal length's uncertainty then comes from the
photo itself, and several photos of one lens can tell their principal point together (:meth:`ViewLens.given`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import EstimationError
from .model import Pose, observed_mask
from .zhang import (MIN_HOMOGRAPHY_CORNERS, apply_homography, common_focal, estimate_homographies,
                    extrinsics_from_homography)

__all__ = ["LENS_PARAMETERS", "OneView", "ViewLens", "board_pixels", "board_pose", "spread_px", "common_division",
           "division_homography", "focal_from_homography", "one_view", "undistort_division", "view_lens"]

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


def _summed_squares(xy: np.ndarray, uvs: np.ndarray, seen: np.ndarray, lams: np.ndarray, image_size) -> np.ndarray:
    """For each of ``lams`` (L,), the squared residuals of every view's homography (``uvs`` (V, N, 2), ``seen``
    (V, N)) with the corners undistorted by it, summed, each view's scaled back to its distorted pixels: (L,), the
    L x V homographies in one batch."""
    L, (V, N) = len(lams), seen.shape
    c, s = _centre_and_scale(image_size)
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
    return np.sum(residual.sum(axis=-1) / magnification**2, axis=1)


#: :func:`common_division` looks at this many views at most: those whose corners reach furthest from the image's
#: centre, where a lens bends the board's image most (its cost grows with the views, the division model's fit does
#: not: a calibration's start is all it gives).
DIVISION_VIEWS = 20
#: :func:`common_division` refines its grid's best ``lam`` by this many steps of successive parabolic interpolation
#: (the vertex of the parabola through the best point and its neighbours), where the summed squares are smooth.
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
    grid = np.linspace(*LAMBDA_RANGE, 11)
    cost = _summed_squares(xy_board, uvs, seen, grid, image_size)
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
        (fx,) = _summed_squares(xy_board, uvs, seen, np.array([x]), image_size)
        if fx < fb:                          # x the new best, between b and the bracket's end on its side
            bracket = [(a, fa), (x, fx), (b, fb)] if x < b else [(b, fb), (x, fx), (c, fc)]
        else:                                # b still the best: the bracket closes in from x's side
            bracket = [(x, fx), (b, fb), (c, fc)] if x < b else [(a, fa), (b, fb), (x, fx)]
    return float(bracket[1][0])


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
    Hq = np.full((4, 3, 3), np.nan)
    for k in range(4):                 # each on its own: a board seen in part may leave a quarter too few corners
        try:
            Hq[k] = estimate_homographies(xy, undistorted[None], (quarter == k)[None], refine=False)[0]
        except EstimationError:
            pass
    with np.errstate(invalid="ignore"):
        logs = np.log([focal_from_homography(H, image_size) if np.all(np.isfinite(H)) else np.nan for H in Hq])
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


# ---------------------------------------------------------------------------- one view's lens, with its sigmas

#: The principal point of a phone's camera lies this far from the image centre (1-sigma, a share of the
#: half-diagonal) before its photos say where: the prior of one view's lens (phones' own calibrations put it
#: within about 1 % of the width).
PRINCIPAL_POINT_SIGMA = 0.02
#: The corners' noise never counts as less than this (pixels): synthetic corners can be nearly exact.
MIN_NOISE_PX = 0.02
#: One view's focal length is searched between these multiples of the half-diagonal.
FOCAL_RANGE = (0.1, 30.0)
#: The lens's parameters of one view, in this order: ``ln f`` (f in pixels), the division model's ``lam`` (per
#: squared half-diagonal, about the principal point), the principal point's offset from the image centre (x, y, in
#: half-diagonals).
LENS_PARAMETERS = ("ln_f", "lam", "pp_x", "pp_y")


@dataclass(frozen=True)
class ViewLens:
    """One photo's lens, from its board alone (:func:`view_lens`), as a normal distribution of
    :data:`LENS_PARAMETERS`: ``information`` (4, 4) is what the photo's corners say (the board's pose eliminated;
    no prior), ``estimate`` (4,) the estimate with the principal point's prior (:data:`PRINCIPAL_POINT_SIGMA`
    about the centre). ``rms_px``: the fit's residual RMS; ``corners``: the corners used; ``image_size`` (W, H).

    ``f_px``, ``lam`` and :meth:`given` the principal point: what the photo says of its lens where the principal
    point is known (its camera's, from several photos) to within a covariance.
    """

    estimate: np.ndarray
    information: np.ndarray
    rms_px: float
    corners: int
    image_size: tuple[int, int]
    tilt_deg: float = float("nan")

    @property
    def f_px(self) -> float:
        return float(np.exp(self.estimate[0]))

    @property
    def lam(self) -> float:
        return float(self.estimate[1])

    def canonical(self) -> tuple[np.ndarray, np.ndarray]:
        """``(information, information @ the estimate without the prior)``: the photo's corners' word on the lens
        as a normal's canonical form, which adds over photos (the estimate's prior taken out)."""
        prior = np.diag([0.0, 0.0, 1.0, 1.0]) / PRINCIPAL_POINT_SIGMA**2
        return self.information, (self.information + prior) @ self.estimate

    def given(self, pp: np.ndarray, pp_covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(features, covariance)``: ``(ln f, lam)`` (2,) and their covariance (2, 2) from this photo, where the
        principal point's offset is ``pp`` (2, half-diagonals) with ``pp_covariance`` (2, 2): the normal of
        ``(ln f, lam)`` conditioned on it, the principal point's uncertainty carried through."""
        info, eta = self.canonical()
        # a weak prior on ln f and lam keeps a board seen square-on (which fixes neither) invertible
        A = info[:2, :2] + np.diag([1e-4, 1e-2])
        B = info[:2, 2:]
        cov = np.linalg.inv(A)
        mean = cov @ (eta[:2] - B @ np.asarray(pp, float))
        G = cov @ B
        return mean, cov + G @ np.asarray(pp_covariance, float) @ G.T


def _division_pixels(params: np.ndarray, R0: np.ndarray, X: np.ndarray, c: np.ndarray, s: float) -> np.ndarray:
    """(P, N, 2) pixels of the board points ``X`` (N, 3) for each row of ``params`` (P, 10): a rotation vector
    applied after ``R0`` (3), ``t_mm`` (3), then :data:`LENS_PARAMETERS`, through the division model about the
    principal point (an undistorted radius ``r_u`` to a distorted ``r_d = 2 r_u / (1 + sqrt(1 - 4 lam r_u^2))``,
    both in half-diagonals ``s``)."""
    from .rotation import rotation_from_rotvec

    R = rotation_from_rotvec(params[:, :3]) @ R0                                    # (P, 3, 3)
    Xc = np.einsum("pij,nj->pni", R, X) + params[:, None, 3:6]
    ru = np.exp(params[:, 6])[:, None, None] * (Xc[..., :2] / Xc[..., 2:3]) / s    # (P, N, 2), half-diagonals
    r2 = np.sum(ru * ru, axis=-1, keepdims=True)
    lam = params[:, 7][:, None, None]
    factor = 2.0 / (1.0 + np.sqrt(np.maximum(1.0 - 4.0 * lam * r2, 0.0)))
    return c + s * (params[:, None, 8:10] + factor * ru)


def view_lens(xy_board: np.ndarray, uv: np.ndarray, image_size, start: OneView | None = None) -> ViewLens | None:
    """One photo's lens from its board alone: focal length, radial distortion and principal point, with what the
    photo fixes of each.

    The photo's corners are adjusted (Levenberg-Marquardt) for the board's pose and :data:`LENS_PARAMETERS`
    (square pixels, no skew) under a prior that holds the principal point within :data:`PRINCIPAL_POINT_SIGMA` of
    the image centre; the corners' noise is the misfit of the view's homography (at least :data:`MIN_NOISE_PX`).
    The information of the lens's parameters is that of the corners with the pose eliminated (the Schur
    complement of the normal matrix, whitened by the noise): a board seen square-on fixes no focal length, one
    near the centre no distortion, and one photo the principal point only along one line.

    Parameters
    ----------
    xy_board : (N, 2) board points, mm.
    uv : (N, 2) their pixels, NaN rows where not measured.
    image_size : (W, H).
    start : the view's :func:`one_view` (computed where not given).

    Returns
    -------
    ViewLens or None
        None with fewer than 8 measured corners, or where the view tells nothing (its homography fails).
    """
    seen = observed_mask(uv)
    start = start if start is not None else one_view(xy_board, uv, image_size)
    if start is None or seen.sum() < 2 * MIN_HOMOGRAPHY_CORNERS:
        return None
    c, s = _centre_and_scale(image_size)
    X = np.column_stack([np.asarray(xy_board, float)[seen], np.zeros(int(seen.sum()))])
    measured = np.asarray(uv, float)[seen]
    log_f_range = np.log(np.array(FOCAL_RANGE) * s)
    f0 = float(np.exp(np.clip(np.log(start.f_px), *log_f_range))) if np.isfinite(start.f_px) else s
    pose = board_pose(start, f0)
    params = np.concatenate([np.zeros(3), pose.t_mm, [np.log(f0), start.lam, 0.0, 0.0]])
    # the corners' noise: the misfit of the view's homography with the division model about the centre (the same
    # lens with the principal point at the centre, 9 unknowns)
    noise = max(start.misfit_px * np.sqrt(2 * len(X) / max(2 * len(X) - 9, 1)), MIN_NOISE_PX)
    steps = 1e-6 * np.where(np.arange(10) < 3, 1.0, np.where(np.arange(10) < 6, 1.0 + np.abs(params), 1.0))

    def whitened(p):                       # (P, 2N + 2): the corners' residuals, then the principal point's prior
        r = (_division_pixels(p, pose.R, X, c, s) - measured).reshape(len(p), -1) / noise
        return np.concatenate([r, p[:, 8:10] / PRINCIPAL_POINT_SIGMA], axis=1)

    def jacobian(p):                       # central differences, every parameter at once
        trial = np.repeat(p[None], 20, axis=0)
        trial[np.arange(10), np.arange(10)] += steps
        trial[10 + np.arange(10), np.arange(10)] -= steps
        r = whitened(trial)
        return ((r[:10] - r[10:]) / (2.0 * steps[:, None])).T

    r = whitened(params[None])[0]
    mu = 1e-3
    for _ in range(50):
        J = jacobian(params)
        A, g, cost = J.T @ J, J.T @ r, r @ r
        while mu <= 1e8:
            trial = params + np.linalg.solve(A + mu * np.diag(np.diag(A) + 1e-12), -g)
            trial[6] = np.clip(trial[6], *log_f_range)
            trial[7] = np.clip(trial[7], *LAMBDA_RANGE)
            r_trial = whitened(trial[None])[0]
            if r_trial @ r_trial <= cost:
                mu = max(mu / 3.0, 1e-9)
                break
            mu *= 4.0
        if mu > 1e8:
            break
        params, r = trial, r_trial
        if cost - r @ r <= 1e-10 * (1.0 + cost):
            break
    J = jacobian(params)[:2 * len(X)]                                    # the corners' rows, without the prior
    A = J.T @ J
    try:
        information = A[6:, 6:] - A[6:, :6] @ np.linalg.solve(A[:6, :6], A[:6, 6:])
    except np.linalg.LinAlgError:
        return None
    rms = float(np.sqrt(np.mean(r[:2 * len(X)] ** 2))) * noise
    from .rotation import rotation_from_rotvec

    tilt = float(np.degrees(np.arccos(min(1.0, abs((rotation_from_rotvec(params[:3]) @ pose.R)[2, 2])))))
    return ViewLens(params[6:].copy(), information, rms, len(X), tuple(int(v) for v in image_size), tilt)
