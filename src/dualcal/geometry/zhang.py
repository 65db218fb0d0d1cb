"""Closed-form initial calibration of one camera (paper sections 1.3 to 1.6).

* Homographies (section 1.3, eq. 3): :mod:`dualcal.geometry.homography`; of corners undistorted by a division
  model, :mod:`dualcal.geometry.division`.
* :func:`intrinsics_from_homographies`: Zhang's constraints (eqs. 4-10) solved by SVD, and
  Burger's closed-form formulas for alpha, beta, gamma, u0, v0 (section 1.4). With skew fixed
  to 0 (the paper's Model 1) the unknown ``b2`` is removed, which imposes ``b2 = 0`` exactly.
* :func:`extrinsics_from_homography`: lambda, r1, r2, t, r3 = r1 x r2, then the nearest rotation
  (section 1.5, eq. 11).
* :func:`radial_distortion_linear`: linear least squares for k1, k2 (section 1.6, eqs. 13-15), and
  for the other coefficients of a lens model (eq. 15 extended).
* A fisheye (lens model ``kb4``) is beyond a homography of its pixels: :func:`initial_fisheye_camera`
  runs the steps above on its corners undistorted by a division model, then fits its own lens's coefficients.
* Weak views, as peers' sessions have them (4-12 corners of a board a tenth of the frame wide, near
  square-on): :func:`perspective_z` tests that the views show perspective beyond their corners' noise (else
  they fix no focal length); :func:`common_focal` is the constrained closed form (square pixels, the principal
  point at the image centre: one focal length from eqs. 9-10 of every view), which :func:`initial_camera` starts
  from where the views fix its focal length better than Zhang's (:func:`homography_covariances`: how well each
  view fixes its homography).

Board points are the board's ``(X, Y)`` in mm (Z = 0); image points are pixels ``(u, v)``. A
view may have corners that were not measured (NaN rows, :func:`dualcal.geometry.model.observed_mask`):
each view uses the corners it has, at least :data:`MIN_HOMOGRAPHY_CORNERS` not on one line.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from .camera import (DEFAULT_LENS_MODEL, FISHEYE_MODELS, LENS_MODELS, CameraModel, fold_distorted_radius,
                     normalized_from_pixel)
from .division import common_division, undistort_division
from .homography import MIN_HOMOGRAPHY_CORNERS, estimate_homographies, homography_covariances
from ..errors import EstimationError
from .model import Pose, observed_mask
from .resection import fixes_homography, planar_pose
from .rotation import nearest_rotation
from ..progress import warn


def _v_row(H: np.ndarray, i: int, j: int) -> np.ndarray:
    """Zhang's ``v_ij`` (paper eqs. 9, 10) for columns ``i, j`` of ``H`` (3, 3), or of each of a stack
    (..., 3, 3); b = [B11 B12 B22 B13 B23 B33]."""
    hi, hj = H[..., :, i], H[..., :, j]
    return np.stack([hi[..., 0] * hj[..., 0], hi[..., 0] * hj[..., 1] + hi[..., 1] * hj[..., 0], hi[..., 1] * hj[..., 1],
                     hi[..., 2] * hj[..., 0] + hi[..., 0] * hj[..., 2], hi[..., 2] * hj[..., 1] + hi[..., 1] * hj[..., 2],
                     hi[..., 2] * hj[..., 2]], axis=-1)


def intrinsics_from_homographies(homographies, image_size, skew: bool = False, weights=None) -> CameraModel:
    """Zhang's closed form with Burger's formulas (paper section 1.4); no distortion.

    Parameters
    ----------
    homographies : sequence of (3, 3) board-to-pixel homographies: at least 2 with ``skew=False``
        (4 equations for the 4 degrees of freedom of ``B`` up to scale), 3 with ``skew=True`` (5)
    image_size : (W, H), used to condition the system (pixels are centred and scaled first)
    skew : False fixes gamma = 0 (Model 1), True estimates it (Model 2)
    weights : one per homography (default 1): each view's two equations are multiplied by it
        (a view of weight 0 is left out)

    Raises
    ------
    EstimationError
        If the views do not determine the intrinsics (e.g. all boards parallel to each other).
    """
    w, h = image_size
    s = 0.5 * (w + h)
    # Condition: work in centred, scaled pixels (an upper-triangular similarity keeps A upper triangular).
    Nrm = np.array([[1.0 / s, 0.0, -0.5 * (w - 1) / s], [0.0, 1.0 / s, -0.5 * (h - 1) / s], [0.0, 0.0, 1.0]])
    weights = np.ones(len(homographies)) if weights is None else np.asarray(weights, float)
    if len(weights) != len(homographies):
        raise ValueError(f"{len(weights)} weights for {len(homographies)} homographies")
    Hn = Nrm @ np.asarray(homographies, float).reshape(-1, 3, 3)[weights > 0]
    Hn = Hn / np.linalg.norm(Hn[:, :, :2], axis=(1, 2))[:, None, None]
    w = weights[weights > 0, None]
    V = np.stack([w * _v_row(Hn, 0, 1), w * (_v_row(Hn, 0, 0) - _v_row(Hn, 1, 1))], axis=1).reshape(-1, 6)
    free = [i for i in range(6) if skew or i != 1]
    V = V[:, free]                                  # b2 = 0  <=>  gamma = 0
    n = len(free)                                   # unknowns of b; b is found up to scale
    views_needed = int(np.ceil((n - 1) / 2))
    if len(V) < n - 1:
        model = "with skew free (Model 2)" if skew else "with skew = 0 (Model 1)"
        raise EstimationError(f"Zhang's closed form {model} needs at least {views_needed} views "
                              f"({len(V) // 2} given)")
    # b spans the null space of V: the last right singular vector of the *full* decomposition where V has
    # fewer rows than unknowns (a reduced SVD does not contain it then); else the reduced one has it, at less cost.
    _, sv, Vt = np.linalg.svd(V, full_matrices=len(V) < n)
    sv = np.concatenate([sv, np.zeros(n - len(sv))])
    if sv[-2] < 1e-6 * sv[0]:
        raise EstimationError("the views do not determine the intrinsics: the board poses are (nearly) "
                              "parallel to each other; take photos with the board tilted in different directions")
    b = np.zeros(6)
    b[free] = Vt[-1]
    if b[0] < 0:                                    # B = A^-T A^-1 up to scale: make it positive
        b = -b
    b1, b2, b3, b4, b5, b6 = b
    # Burger's formulas (paper section 1.4).
    wB = b1 * b3 * b6 - b2**2 * b6 - b1 * b5**2 + 2 * b2 * b4 * b5 - b3 * b4**2
    d = b1 * b3 - b2**2
    if d <= 0 or wB <= 0:
        raise EstimationError("Zhang's closed form gave no valid camera (B is not positive definite): the "
                              "board poses are too alike (e.g. all parallel) or the corners too noisy; take photos "
                              "with the board tilted in different directions")
    alpha = np.sqrt(wB / (d * b1))
    beta = np.sqrt(b1 * wB / d**2)
    # B12 = -gamma / (alpha^2 beta): the minus sign is missing in the paper's print of this formula.
    gamma = -b2 * np.sqrt(wB / (d**2 * b1))
    u0 = (b2 * b5 - b3 * b4) / d
    v0 = (b2 * b4 - b1 * b5) / d
    A = np.linalg.inv(Nrm) @ np.array([[alpha, gamma, u0], [0.0, beta, v0], [0.0, 0.0, 1.0]])
    return CameraModel(tuple(image_size), A[0, 0], A[1, 1], A[0, 1], A[0, 2], A[1, 2])


#: The views' perspective must stand this far above their corners' noise (a standard normal deviate: one-sided,
#: 0.1 %) for the photos to fix a focal length (:func:`perspective_z`).
PERSPECTIVE_SIGNIFICANCE = 3.09


def perspective_z(Hs, covariances, variance_px2: float) -> float:
    """How far the views' perspective stands above their corners' noise, as a standard normal deviate.

    A board's image fixes a focal length only through its perspective: the third row ``(h31, h32)`` of its
    homography (``H[2, 2] = 1``), which is zero where the board is seen square-on (anywhere in the frame) or
    so far away that its image is an affine map of it, and the focal length then trades with the distance.
    With each view's ``(h31, h32)`` of covariance ``variance_px2 * covariances[v][6:8, 6:8]``
    (:func:`homography_covariances`), ``chi^2 = sum_v p_v^T C_v^-1 p_v`` has ``2 V`` degrees of freedom where
    no view has any perspective; it is returned as the standard normal deviate of the same tail
    (Wilson-Hilferty), +inf for exact corners and NaN where the variance is unknown.

    Parameters
    ----------
    Hs : (V, 3, 3) the views' homographies.
    covariances, variance_px2 : :func:`homography_covariances` of the views.
    """
    Hs = np.asarray(Hs, float).reshape(-1, 3, 3)
    if not np.isfinite(variance_px2):
        return float("nan")
    if variance_px2 == 0:
        return float("inf")
    p = Hs[:, 2, :2] / Hs[:, 2, 2:3]
    chi2 = float(np.einsum("vi,vij,vj->", p, np.linalg.inv(variance_px2 * covariances[:, 6:8, 6:8]), p))
    k = 2 * len(Hs)
    return float(((chi2 / k) ** (1 / 3) - (1 - 2 / (9 * k))) / np.sqrt(2 / (9 * k)))


def _centred_scaled(image_size) -> tuple[np.ndarray, float]:
    """The similarity (3, 3) from pixels to pixels centred on the image and scaled by its half-diagonal, and
    that half-diagonal."""
    w, h = image_size
    s = 0.5 * float(np.hypot(w, h))
    return np.array([[1.0 / s, 0.0, -0.5 * (w - 1) / s], [0.0, 1.0 / s, -0.5 * (h - 1) / s], [0.0, 0.0, 1.0]]), s


def focal_equations(Hs, image_size) -> tuple[np.ndarray, np.ndarray]:
    """Zhang's two equations of each view (paper eqs. 9-10) for a camera with square pixels, no skew and its
    principal point at the image centre (the constrained closed form).

    With ``B = diag(1/f^2, 1/f^2, 1)`` in pixels centred on the image and scaled by its half-diagonal ``s``,
    ``h1^T B h2 = 0`` and ``h1^T B h1 - h2^T B h2 = 0`` are linear in ``x = (s / f)^2``: ``a x + b = 0``.

    Parameters
    ----------
    Hs : (V, 3, 3) board-to-pixel homographies.
    image_size : (W, H).

    Returns
    -------
    ``(a, b)``, each (V, 2), every view's homography scaled so that its 2 x 2 part has unit norm.
    """
    N, _ = _centred_scaled(image_size)
    M = N @ np.asarray(Hs, float).reshape(-1, 3, 3)
    M = M / np.linalg.norm(M[:, :2, :2], axis=(1, 2))[:, None, None]
    m1, m2 = M[:, :, 0], M[:, :, 1]
    a = np.stack([m1[:, 0] * m2[:, 0] + m1[:, 1] * m2[:, 1],
                  m1[:, 0] ** 2 + m1[:, 1] ** 2 - m2[:, 0] ** 2 - m2[:, 1] ** 2], axis=1)
    b = np.stack([m1[:, 2] * m2[:, 2], m1[:, 2] ** 2 - m2[:, 2] ** 2], axis=1)
    return a, b


#: Views whose :func:`focal_equations` have ``sum a^2`` below the square of this are a similarity of the board
#: (seen square-on: each homography's columns orthogonal and of equal length to within this), which tells no
#: focal length.
SQUARE_ON = 1e-9


def common_focal(Hs, image_size, weights=None) -> float:
    """One focal length (px) from every view together, for a camera with square pixels, no skew and its
    principal point at the image centre: :func:`focal_equations` solved for ``x`` by least squares, each view's
    two equations multiplied by its weight (default 1). NaN where there is none: every board seen square-on
    (:data:`SQUARE_ON`), or noise that makes ``x`` negative.
    """
    a, b = focal_equations(Hs, image_size)
    w2 = (np.ones(len(a)) if weights is None else np.asarray(weights, float))[:, None] ** 2
    information = float(np.sum(w2 * a * a))
    x = -float(np.sum(w2 * a * b)) / information if information >= SQUARE_ON**2 else 0.0
    return _centred_scaled(image_size)[1] / np.sqrt(x) if x > 0 else float("nan")


def extrinsics_from_homography(K: np.ndarray, H: np.ndarray) -> Pose:
    """Board-to-camera pose from a homography (paper section 1.5).

    ``lambda = 1 / |A^-1 h1|``, ``r1 = lambda A^-1 h1``, ``r2 = lambda A^-1 h2``,
    ``t = lambda A^-1 h3``, ``r3 = r1 x r2``, then the nearest rotation. The sign of lambda is
    chosen so that the board lies in front of the camera (t_z > 0).
    """
    return extrinsics_from_homographies(K, [H])[0]


def extrinsics_from_homographies(K: np.ndarray, Hs) -> list[Pose]:
    """:func:`extrinsics_from_homography` of every homography ``Hs`` (V, 3, 3), in one batch."""
    a = np.linalg.inv(K) @ np.asarray(Hs, float)                                  # columns a1, a2, a3
    lam = 2.0 / (np.linalg.norm(a[:, :, 0], axis=1) + np.linalg.norm(a[:, :, 1], axis=1))
    lam = np.where(a[:, 2, 2] < 0, -lam, lam)
    r1, r2, t = (lam[:, None] * a[:, :, i] for i in range(3))
    Rs = nearest_rotation(np.stack([r1, r2, np.cross(r1, r2)], axis=-1))
    return [Pose(R, tt) for R, tt in zip(Rs, t)]


_RADIAL_POWER = {"k1": 1, "k2": 2, "k3": 3}     # coefficient of r^(2 n)


def radial_distortion_linear(cam: CameraModel, poses, xy_board: np.ndarray, observed,
                             model: str = DEFAULT_LENS_MODEL) -> tuple[float, ...]:
    """The lens coefficients of ``model`` by linear least squares (paper eqs. 13-15, extended).

    For each point, ``(u~ - u, v~ - v) = A' (xd - x, yd - y)`` where ``(u, v)`` is the ideal
    (distortion-free) projection of normalised ``(x, y)``, ``(u~, v~)`` the observed pixel and
    ``A' = [[fx, skew], [0, fy]]``. In the paper's model (eq. 14) that is
    ``(u - u0, v - v0) (k1 r^2 + k2 r^4)``, ``u - u0`` including the skew term ``fx x + gamma y``.
    This extends eq. 15 to the other coefficients of :mod:`dualcal.geometry.camera`'s model, which are
    linear too given the ideal projections: ``k3`` adds the column of ``r^6``, ``p1`` the column
    ``A' (2 x y, r^2 + 2 y^2)`` and ``p2`` the column ``A' (r^2 + 2 x^2, 2 x y)``. Rows of
    ``observed`` that are NaN (corners not measured) are left out.

    Returns the coefficients in the order of :data:`dualcal.geometry.camera.LENS_MODELS` ``[model]``
    (``k1, k2`` for the paper's model).
    """
    names = LENS_MODELS[model]
    X = np.column_stack([xy_board, np.zeros(len(xy_board))])
    D_rows, d_rows = [], []
    for pose, uv_obs in zip(poses, observed):
        seen = observed_mask(uv_obs)
        uv_obs = uv_obs[seen]
        Xc = pose.apply(X[seen])
        x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
        r2 = x * x + y * y
        du = cam.fx * x + cam.skew * y
        dv = cam.fy * y
        u, v = du + cam.cx, dv + cam.cy
        tangential = {"p1": (2 * x * y, r2 + 2 * y * y), "p2": (r2 + 2 * x * x, 2 * x * y)}   # d(xd, yd) / dp
        cols_u, cols_v = [], []
        for n in names:
            if n in tangential:
                sx, sy = tangential[n]
                cols_u.append(cam.fx * sx + cam.skew * sy)
                cols_v.append(cam.fy * sy)
            else:                                # k1, k2, k3: (u - u0, v - v0) r^2, r^4, r^6
                cu, cv = du, dv
                for _ in range(_RADIAL_POWER[n]):
                    cu, cv = cu * r2, cv * r2
                cols_u.append(cu)
                cols_v.append(cv)
        D_rows += [np.column_stack(cols_u), np.column_stack(cols_v)]
        d_rows += [uv_obs[:, 0] - u, uv_obs[:, 1] - v]
    D = np.vstack(D_rows)
    d = np.concatenate(d_rows)
    k, *_ = np.linalg.lstsq(D, d, rcond=None)                     # eq. 15
    return tuple(float(c) for c in k)


def initial_camera(xy_board: np.ndarray, views: dict, image_size, skew: bool = False,
                   model: str = DEFAULT_LENS_MODEL, name: str | None = None):
    """Zhang's full initialisation of one camera: intrinsics, the lens (k1 k2, or the coefficients
    of lens ``model``) and one pose per view.

    ``views[k]`` is (N, 2), NaN rows for corners not measured; every view needs at least
    :data:`MIN_HOMOGRAPHY_CORNERS` corners not on one line (``dualcal.estimation.calibrate`` skips the others).
    Returns ``(CameraModel, {view: Pose})``: homographies (section 1.3; the normalised DLT's, not refined on
    the pixel error: a start, which the adjustment refines, and the closed form that :func:`closed_form_camera`
    gives, computed once), closed-form intrinsics (1.4), one pose per view (1.5), then the lens by linear least
    squares (1.6). The closed form
    weighs each view by its homography's redundancy (``sqrt(2 n - 8)`` for n corners: one of 4
    corners has none, and no say; unweighted, a single such view of a narrow lens that sees
    small parts of the board was seen to make fx 790 px for a true 6059).

    Weak views as peers record them (a small board, 4-12 corners, a partial ChArUco view, near square-on):
    the homographies are of the corners undistorted by a division model, and the camera is Zhang's or the
    constrained one (:func:`_closed_form_intrinsics`). Where a fallback changes the start, a warning naming
    ``name`` (the camera; else its image size) says so: a view whose corners fix no homography
    (:func:`dualcal.geometry.resection.fixes_homography`: four on a row and one off it) is left out of the
    closed form; where Zhang's closed form gives no camera (``B`` not positive definite), the constrained one
    starts (:func:`common_focal`). A pose with a corner behind the camera, or of a view without a homography,
    comes by space resection (:func:`dualcal.geometry.resection.planar_pose`: IPPE, or SQPnP where IPPE
    cannot). A start the adjustment could not move from is avoided: linear coefficients whose radial part folds
    over where the corners are become 0. These are the starting values of the joint adjustment, which refines
    all of them together.

    Raises
    ------
    EstimationError
        Where the photos fix no camera: no view fixes a homography, their boards' perspective is within their
        corners' noise (:func:`perspective_z`), or neither closed form gives a camera.
    """
    if model in FISHEYE_MODELS:
        return initial_fisheye_camera(xy_board, views, image_size, skew, model, name)
    keys = sorted(views)
    seen = [observed_mask(views[k]) for k in keys]
    start = _closed_form(xy_board, [views[k] for k in keys], seen, image_size, skew, name)
    coefficients = radial_distortion_linear(start.camera, start.poses, xy_board, [views[k] for k in keys], model)
    cam = replace(start.camera, model=model, **dict(zip(LENS_MODELS[model], coefficients)))
    cam = _admissible_distortion(cam, [views[k][m] for k, m in zip(keys, seen)])
    _warn_fallbacks(start, keys, image_size, name)
    return cam, dict(zip(keys, start.poses))


def closed_form_camera(xy_board: np.ndarray, views: dict, image_size, skew: bool = False,
                       name: str | None = None) -> CameraModel:
    """Zhang's closed-form intrinsics alone (sections 1.3-1.4; no lens): from the DLT's homographies,
    not refined, which is enough to judge a lens's field of view (with :func:`initial_camera`'s fallbacks,
    unsaid)."""
    uvs = [views[k] for k in sorted(views)]
    return _closed_form_intrinsics(xy_board, uvs, [observed_mask(uv) for uv in uvs], image_size, skew, name)[0]


@dataclass(frozen=True)
class _ClosedForm:
    """What :func:`_closed_form` found: the camera (no lens), one pose per view, one homography per view (None
    where its corners fix none) and, where the constrained closed form stood in for Zhang's, why and what it
    gave (else None)."""

    camera: CameraModel
    poses: list[Pose]
    homographies: tuple[np.ndarray | None, ...]
    fallback: str | None


def _subject(name: str | None, image_size, views: int) -> str:
    """The camera a message is about: its name, else its image size and number of photos."""
    return name if name else f"the camera of {image_size[0]} x {image_size[1]} px ({views} photos)"


def _warn_fallbacks(start: _ClosedForm, keys: list[str], image_size, name: str | None) -> None:
    """One warning per fallback :func:`_closed_form` took (:func:`initial_camera`)."""
    who = _subject(name, image_size, len(keys))
    if start.fallback:
        warn(f"{who}: {start.fallback}")
    without = [k for k, H in zip(keys, start.homographies) if H is None]
    if without:
        shown = ", ".join(without[:4]) + (f" and {len(without) - 4} more" if len(without) > 4 else "")
        warn(f"{who}: {len(without)} photo(s) ({shown}) fix no homography (no four of their corners without three "
             "on one line): left out of the closed form, their start poses from their corners by PnP (SQPnP)")


#: The jackknife of the closed form's focal length leaves out one of at most this many groups of views at a time
#: (every ``JACKKNIFE_GROUPS``-th view together): one view at a time up to that many views, so that its cost stops
#: growing with the square of the views.
JACKKNIFE_GROUPS = 20


def _jackknife_log_sigma(estimate, views: int) -> float:
    """The jackknife's sigma of ``log(estimate(keep))`` (``keep``: (V,) bool) over the ``views`` left out one at a
    time, or with more than :data:`JACKKNIFE_GROUPS` views, one interleaved group at a time (the delete-a-group
    jackknife): how well the views fix what ``estimate`` gives (inf where it gives nothing without one of them)."""
    groups = min(views, JACKKNIFE_GROUPS)
    member = np.arange(views) % groups
    logs = []
    for i in range(groups):
        keep = member != i
        try:
            logs.append(np.log(estimate(keep)))
        except EstimationError:
            return float("inf")
    logs = np.array(logs)
    if not np.all(np.isfinite(logs)):
        return float("inf")
    return float(np.sqrt((groups - 1) / groups * np.sum((logs - logs.mean()) ** 2)))


def _closed_form(xy_board: np.ndarray, uvs: list[np.ndarray], seen: list[np.ndarray], image_size, skew: bool,
                 name: str | None = None) -> _ClosedForm:
    """Homographies, the closed form (:func:`_closed_form_intrinsics`) and one pose per view, no lens (sections
    1.3-1.5, with :func:`initial_camera`'s fallbacks): a view without a homography, or whose pose puts a corner
    behind the camera (from a poor closed form), is resected."""
    cam, Hs, fallback = _closed_form_intrinsics(xy_board, uvs, seen, image_size, skew, name)
    X = np.column_stack([xy_board, np.zeros(len(xy_board))])
    with_H = [i for i, H in enumerate(Hs) if H is not None]
    poses: list[Pose | None] = [None] * len(uvs)
    for i, pose in zip(with_H, extrinsics_from_homographies(cam.K, [Hs[i] for i in with_H])):
        poses[i] = pose
    poses = [pose if pose is not None and np.all(pose.apply(X[m])[:, 2] > 0) else planar_pose(X, cam, uv)
             for uv, m, pose in zip(uvs, seen, poses)]
    return _ClosedForm(cam, poses, Hs, fallback)


def _closed_form_intrinsics(xy_board: np.ndarray, uvs: list[np.ndarray], seen: list[np.ndarray], image_size,
                            skew: bool, name: str | None = None):
    """Homographies (the normalised DLT's, not refined: a start) and the closed form (sections 1.3-1.4) of the views
    whose corners fix a homography: ``(camera, homographies, fallback)``, the homographies one per view (None where
    its corners fix none), ``fallback`` as :class:`_ClosedForm`'s.

    The homographies are of the corners undistorted by the division model that fits every
    view's homography best (:func:`dualcal.geometry.division.common_division`): a lens bends the image of a board
    near the frame's edge, and its homography takes the bend for perspective, which the closed forms read as a
    focal length (sessions of caliscope's webcams, k1 down to -0.33 at 1280 x 720, the board a tenth of the frame:
    the starts' median error of fx 22 % without it, 12 % with it). The camera is then a pinhole start of the
    undistorted pixels, whose lens section 1.6 estimates.

    Of Zhang's camera and the constrained one (square pixels, the principal point at the image centre, one focal
    length: :func:`common_focal`), the camera is the one whose focal length the views fix better: the smaller
    jackknife sigma over the views (:func:`_jackknife_log_sigma`). Tilted boards that fill the frame fix
    Zhang's four unknowns (and its focal length is then the nearer); small boards with few corners, seen near
    square-on, leave its ``B`` to the noise (not positive definite, or a focal length far too short: half the
    truth and less at 1.2 px of noise on caliscope's webcams), where the constrained one, with three unknowns
    less, holds.

    Memoised on the values (a calibration asks it of each camera's photos for its lens models' candidates and for
    its start; the homographies it returns are shared: a tuple of read-only arrays).

    Raises
    ------
    EstimationError
        No view fixes a homography, the views' perspective is within their corners' noise (:func:`perspective_z`:
        the photos fix no focal length), or neither closed form gives a camera.
    """
    xy = np.ascontiguousarray(xy_board, float)
    uv = np.ascontiguousarray(np.reshape(np.asarray(uvs, float), (len(uvs), len(xy), 2)))
    on = np.ascontiguousarray(np.reshape(np.asarray(seen, bool), (len(seen), len(xy))))
    return _memoised_intrinsics(xy.tobytes(), len(xy), uv.tobytes(), on.tobytes(), tuple(int(s) for s in image_size),
                                bool(skew), name)


#: Up to this many closed forms are memoised: a calibration's cameras', each asked for twice or more.
_MEMOISED_CLOSED_FORMS = 64


@functools.lru_cache(maxsize=_MEMOISED_CLOSED_FORMS)
def _memoised_intrinsics(xy_bytes: bytes, n: int, uv_bytes: bytes, seen_bytes: bytes, image_size, skew: bool,
                         name: str | None):
    """:func:`_closed_form_intrinsics` of arrays given by their bytes (hashable, so that it can be memoised)."""
    xy_board = np.frombuffer(xy_bytes).reshape(n, 2)
    uvs = np.frombuffer(uv_bytes).reshape(-1, n, 2)
    seen = np.frombuffer(seen_bytes, bool).reshape(-1, n)
    who = _subject(name, image_size, len(uvs))
    fixes: dict[bytes, bool] = {}                   # views that see the same corners share the answer
    for m in seen:
        if m.tobytes() not in fixes:
            fixes[m.tobytes()] = fixes_homography(xy_board[m])
    fixing = [i for i, m in enumerate(seen) if fixes[m.tobytes()]]
    if not fixing:
        raise EstimationError(f"{who}: no photo's corners fix a homography (at least four corners, no three of "
                              "them on one line); take photos where more of the board is seen")
    f_uvs, f_seen = np.array([uvs[i] for i in fixing], float), np.array([seen[i] for i in fixing])
    lam = common_division(xy_board, f_uvs, image_size)
    f_uvs = np.where(f_seen[..., None], undistort_division(np.nan_to_num(f_uvs), lam, image_size), np.nan)
    fixed = np.array(estimate_homographies(xy_board, f_uvs, f_seen, refine=False))
    z = perspective_z(fixed, *homography_covariances(fixed, xy_board, f_uvs, f_seen))
    if z < PERSPECTIVE_SIGNIFICANCE:
        raise EstimationError(f"{who}: its photos fix no focal length: their boards' perspective is within their "
                              f"corners' noise (z = {z:.1f}, {PERSPECTIVE_SIGNIFICANCE:g} needed), the boards seen "
                              "square-on or too small; take photos with the board tilted 30-50 degrees in "
                              "different directions")
    # A homography of n corners has 2n - 8 redundant equations; one of 4 corners fits them
    # exactly, noise and all, and would pull the closed form as hard as one of 40.
    weights = np.sqrt(2.0 * f_seen.sum(axis=1) - 2 * MIN_HOMOGRAPHY_CORNERS)
    if not weights.any():                       # no view has more corners than its homography needs: alike
        weights = np.ones(len(fixed))
    starts, spread, failed = _closed_forms(fixed, weights, image_size, skew)
    if not starts:
        raise EstimationError(f"{who}: {failed}: the board poses are too alike or the corners too noisy; take "
                              "photos with the board tilted 30-50 degrees in different directions")
    chosen = min(starts, key=lambda kind: (spread[kind], kind != "zhang"))
    if _normals_spread_deg(starts[chosen], fixed) < PARALLEL_DEG:
        raise EstimationError(f"{who}: its boards are all parallel to each other (their normals within "
                              f"{PARALLEL_DEG:g} degree), which fixes no principal point; take photos with the board "
                              "tilted 30-50 degrees in different directions")
    fallback = None
    if failed:
        sure = f" (+-{100 * spread[chosen]:.2g} % by the jackknife)" if np.isfinite(spread[chosen]) else ""
        fallback = (f"{failed} from {len(fixed)} photos; it starts from square pixels, the principal point at the "
                    f"image centre and one focal length from every photo together, f = {starts[chosen].fx:.0f} px"
                    f"{sure}, which the adjustment then refines with the rest")
    Hs: list[np.ndarray | None] = [None] * len(uvs)
    fixed.setflags(write=False)                 # shared by the memo's callers
    for i, H in zip(fixing, fixed):
        Hs[i] = H
    return starts[chosen], tuple(Hs), fallback


def _closed_forms(Hs: np.ndarray, weights: np.ndarray, image_size, skew: bool):
    """Zhang's camera and the constrained one from the homographies ``Hs`` (V, 3, 3) weighed by ``weights`` (V,):
    ``(starts, spread, failed)``, the cameras each closed form gives (``{"zhang": ..., "constrained": ...}``), the
    jackknife sigma of each one's log focal length, and what made Zhang's fail (its error's first clause;
    its advice, after the colon, is not a fallback's) or None."""
    def zhang(keep):
        return intrinsics_from_homographies(Hs[keep], image_size, skew, weights[keep])

    def constrained_f(keep):
        return common_focal(Hs[keep], image_size, weights[keep])

    every = np.ones(len(Hs), bool)
    starts, spread, failed = {}, {}, None
    f_px = constrained_f(every)
    if np.isfinite(f_px):
        w, h = image_size
        starts["constrained"] = CameraModel(tuple(image_size), f_px, f_px, 0.0, 0.5 * (w - 1), 0.5 * (h - 1))
        spread["constrained"] = _jackknife_log_sigma(constrained_f, len(Hs))
    try:
        starts["zhang"] = zhang(every)
        spread["zhang"] = _jackknife_log_sigma(lambda keep: _mean_focal(zhang(keep)), len(Hs))
    except EstimationError as exc:
        failed = str(exc).split(":")[0]
    return starts, spread, failed


#: Boards whose normals all lie within this (RMS, degrees) of their mean are parallel: Zhang's degenerate case, where
#: the views fix a focal length only given the principal point, which no start can give the adjustment.
PARALLEL_DEG = 1.0


def _normals_spread_deg(cam: CameraModel, Hs: np.ndarray) -> float:
    """The RMS angle (degrees) of the boards' normals from their mean, their poses from ``Hs`` with ``cam``."""
    normals = np.array([pose.R[:, 2] for pose in extrinsics_from_homographies(cam.K, Hs)])
    mean = normals.mean(axis=0)
    cosines = np.clip(normals @ (mean / np.linalg.norm(mean)), -1.0, 1.0)
    return float(np.degrees(np.sqrt(np.mean(np.arccos(cosines) ** 2))))


def _mean_focal(cam: CameraModel) -> float:
    return float(np.sqrt(cam.fx * cam.fy))


def initial_fisheye_camera(xy_board: np.ndarray, views: dict, image_size, skew: bool = False, model: str = "kb4",
                           name: str | None = None):
    """Zhang's initialisation for a fisheye (``kb4``), which may see 120 degrees and more.

    A plane's fisheye image is not a homography of it, but the corners undistorted by the division model that fits
    every view's homography best (:func:`_closed_form_intrinsics`) nearly are one: A and the poses are the closed
    form's of those, as :func:`initial_camera`'s (computed once for both, and for the lens models' candidates).
    Then the linear least squares of section 1.6 for ``k1 .. k4``: given the poses,
    ``(u~, v~) - (u, v) = A' (x theta / r) sum_j k_j theta^(2 j)`` with ``(u, v)`` the equidistant projection.
    Where those coefficients fold over inside the radius the corners reach, the fisheye starts without them.
    Returns ``(CameraModel, {view: Pose})``.

    On phone3's ultra-wide (145 degrees on the diagonal) f starts within 0.2 % of the truth, the principal point
    within 0.6 % of f and the corners within 0.1 % of f. On equidistant fisheyes that see 220-290 degrees on the
    diagonal (f 1300-1000 px on 3024 x 4032) f starts 10-50 % off (it trades off with ``k1 .. k4``), the corners
    still within 1.5 % of f, and the adjustment reaches the same minimum as from the search this start replaced
    (``k1`` by fixed points of the closed form on the rays' pinhole image), which took 5-10 times as long and
    started f up to 4.6 times the truth on the same views.
    """
    keys = sorted(views)
    uvs = [np.asarray(views[k], float) for k in keys]
    seen = [observed_mask(uv) for uv in uvs]
    start = _closed_form(xy_board, uvs, seen, image_size, skew, name)
    guess = replace(start.camera, model=model)
    coefficients = _fisheye_linear(guess, start.poses, xy_board, uvs)
    cam = guess.with_distortion(coefficients[0], coefficients[1], k3=coefficients[2], k4=coefficients[3])
    reach = max(np.max(np.linalg.norm(normalized_from_pixel(cam, uv[m]), axis=1)) for uv, m in zip(uvs, seen))
    _warn_fallbacks(start, keys, image_size, name)
    return (cam if reach < fold_distorted_radius(cam) else guess), dict(zip(keys, start.poses))


def _fisheye_linear(cam: CameraModel, poses, xy_board: np.ndarray, observed) -> np.ndarray:
    """``k1 .. k4`` of a fisheye by linear least squares given A and the poses (eq. 15's idea)."""
    X = np.column_stack([xy_board, np.zeros(len(xy_board))])
    D_rows, d_rows = [], []
    for pose, uv_obs in zip(poses, observed):
        m = observed_mask(uv_obs)
        Xc = pose.apply(X[m])
        rho = np.hypot(Xc[:, 0], Xc[:, 1])
        theta = np.arctan2(rho, Xc[:, 2])
        ex, ey = (np.divide(Xc[:, i], rho, out=np.zeros_like(rho), where=rho > 0) * theta for i in (0, 1))
        du, dv = cam.fx * ex + cam.skew * ey, cam.fy * ey
        powers = np.column_stack([theta ** (2 * j) for j in range(1, 5)])
        D_rows += [du[:, None] * powers, dv[:, None] * powers]
        d_rows += [uv_obs[m, 0] - (du + cam.cx), uv_obs[m, 1] - (dv + cam.cy)]
    k, *_ = np.linalg.lstsq(np.vstack(D_rows), np.concatenate(d_rows), rcond=None)
    return k


def _admissible_distortion(cam: CameraModel, observed: list[np.ndarray]) -> CameraModel:
    """``cam``, or ``cam`` without distortion if its radial part folds over inside the radius that
    the measured corners reach (a linear estimate from a poor closed form; the adjustment cannot
    start from a lens that is not invertible where the corners are)."""
    rd = max(np.max(np.linalg.norm(normalized_from_pixel(cam, uv), axis=1)) for uv in observed)
    return cam if rd < fold_distorted_radius(cam) else cam.with_distortion(0.0, 0.0)
