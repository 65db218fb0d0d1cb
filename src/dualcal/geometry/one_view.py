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
homography is fitted to corners undistorted by the one-parameter division model (Fitzgibbon's,
:mod:`dualcal.geometry.division`), its ``lam`` chosen to minimise the homography's misfit
(:func:`dualcal.geometry.division.division_homography`).

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
from .division import LAMBDA_RANGE, centre_and_scale, division_homography, division_misfits, undistort_division
from .homography import MIN_HOMOGRAPHY_CORNERS, apply_homography, estimate_homographies
from .model import Pose, observed_mask
from .zhang import common_focal, extrinsics_from_homography

__all__ = ["LENS_PARAMETERS", "OneView", "ViewLens", "board_pixels", "board_pose", "spread_px", "focal_from_homography",
           "one_view", "view_lens"]

#: The spread of one view's log focal length never counts as less than this (the principal point is not
#: exactly at the centre, and the division model is not the lens).
MIN_F_LOG_SIGMA = 0.03


@dataclass(frozen=True)
class OneView:
    """One photo's board, alone.

    ``H`` (3, 3) maps board ``(X, Y)`` mm to pixels undistorted by the division model with ``lam``
    (:func:`dualcal.geometry.division.undistort_division`); ``H_quarters`` (4, 3, 3) the same from each
    interleaved quarter of the corners (NaN where one cannot be had), whose spread measures what the view fixes;
    ``misfit_px`` is the
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


def focal_from_homography(H: np.ndarray, image_size) -> float:
    """The focal length (pixels) that one view's homography gives a camera with square pixels, no skew
    and its principal point at the image centre (module docstring; :func:`dualcal.geometry.zhang.common_focal`
    of the one view), or NaN where it gives none (a board seen square-on, or noise that makes ``1/f^2``
    negative)."""
    return common_focal([H], image_size)


def one_view(xy_board: np.ndarray, uv: np.ndarray, image_size, lam: float | None = None) -> OneView | None:
    """What one photo's detected board tells alone (:class:`OneView`), or None with fewer than 8 corners.

    ``lam``: the division model's coefficient, where it is known (:func:`dualcal.geometry.division.common_division`);
    else the view's own (:func:`dualcal.geometry.division.division_homography`).

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
            (H,), (misfit,) = division_misfits(xy, pts, np.array([lam]), image_size)
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
    c, _ = centre_and_scale(view.image_size)
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
    c, s = centre_and_scale(image_size)
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
