"""The camera model: pinhole with skew and two radial terms (paper eqs. 1, 13, 24-28).

Conventions (README, "Conventions"):

* Camera frame: x right, y down, z forward; a point ``X_cam`` projects to normalised
  coordinates ``x = X/Z, y = Y/Z``.
* Radial distortion (paper eq. 13; eq. 25 corrected): ``r2 = x^2 + y^2``,
  ``xd = x (1 + k1 r2 + k2 r2^2)``, likewise ``yd``.
* Pixels: ``u = fx xd + skew yd + cx``, ``v = fy yd + cy``; pixel ``(row i, col j)`` has its
  centre at ``(u=j, v=i)``. ``fx, fy, skew, cx, cy`` are the paper's alpha, beta, gamma, u0, v0.

Arrays of points are ``(N, 2)`` (pixels or normalised) or ``(N, 3)`` (camera frame, mm).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import NotInvertibleError

INTRINSIC_NAMES = ("fx", "fy", "skew", "cx", "cy", "k1", "k2")


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera. ``image_size`` is ``(width, height)`` in pixels."""

    image_size: tuple[int, int]
    fx: float
    fy: float
    skew: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0

    @property
    def K(self) -> np.ndarray:
        """The paper's matrix A: ``[[fx, skew, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def as_vector(self) -> np.ndarray:
        """``[fx, fy, skew, cx, cy, k1, k2]`` (order of :data:`INTRINSIC_NAMES`)."""
        return np.array([getattr(self, n) for n in INTRINSIC_NAMES], dtype=float)

    @classmethod
    def from_vector(cls, image_size, vec) -> "CameraModel":
        return cls(tuple(int(s) for s in image_size), *(float(x) for x in vec))

    def with_distortion(self, k1: float, k2: float) -> "CameraModel":
        return replace(self, k1=float(k1), k2=float(k2))


def radial_factor(r2: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """``1 + k1 r^2 + k2 r^4`` for squared radii ``r2``."""
    return 1.0 + r2 * (k1 + k2 * r2)


def distort_normalized(xy: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """Ideal normalised coordinates (N, 2) -> distorted ones (paper eq. 13 model)."""
    xy = np.asarray(xy, dtype=float)
    r2 = np.sum(xy * xy, axis=-1, keepdims=True)
    return xy * radial_factor(r2, k1, k2)


def max_monotonic_radius(k1: float, k2: float) -> float:
    """Largest undistorted radius up to which ``rd = r (1 + k1 r^2 + k2 r^4)`` is increasing.

    ``d rd / dr = 1 + 3 k1 r^2 + 5 k2 r^4``; its first positive root in ``r^2`` bounds the
    region where undistortion is unique. Returns ``inf`` when there is none.
    """
    a, b = 5.0 * k2, 3.0 * k1                   # a s^2 + b s + 1 = 0 in s = r^2
    if a == 0.0:
        roots = [-1.0 / b] if b != 0.0 else []
    else:
        disc = b * b - 4.0 * a
        if disc < 0.0:
            roots = []
        else:                                    # the numerically stable pair of roots
            q = -0.5 * (b + np.copysign(np.sqrt(disc), b))
            with np.errstate(over="ignore"):     # q / a is +-inf for a vanishing k2: no root there
                roots = [q / a, 1.0 / q] if q != 0.0 else []
    positive = [s for s in roots if s > 0.0]
    return float(np.sqrt(min(positive))) if positive else float("inf")


def max_distorted_radius(k1: float, k2: float) -> float:
    """Largest distorted normalised radius the model reaches before it folds over (``inf`` if never):
    ``rd`` at :func:`max_monotonic_radius`. Undistortion is unique only below it."""
    r_max = max_monotonic_radius(k1, k2)
    return float(r_max * radial_factor(r_max**2, k1, k2)) if np.isfinite(r_max) else float("inf")


def _monotonic_bracket(rd: np.ndarray, k1: float, k2: float) -> tuple[np.ndarray, np.ndarray]:
    """``[lo, hi]`` enclosing the root of ``r (1 + k1 r^2 + k2 r^4) = rd`` on the monotonic branch.

    The branch is ``0 <= r <= max_monotonic_radius``; where that is infinite, ``hi`` doubles from
    ``rd`` until the model passes ``rd``.
    """
    lo = np.zeros_like(rd)
    r_max = max_monotonic_radius(k1, k2)
    if np.isfinite(r_max):
        return lo, np.full_like(rd, r_max)
    hi = np.maximum(rd, 1e-300)
    for _ in range(2100):                       # 2^2100 exceeds any float: the loop always ends
        short = hi * radial_factor(hi * hi, k1, k2) < rd
        if not short.any():
            break
        hi = np.where(short, 2.0 * hi, hi)
    return lo, hi


def undistort_radius(rd: np.ndarray, k1: float, k2: float, max_iter: int = 200):
    """Solve ``rd = r (1 + k1 r^2 + k2 r^4)`` for ``r`` on the monotonic branch (paper eq. 25, typo
    corrected): Newton's method safeguarded by bisection.

    The root is kept in a bracket ``[lo, hi]`` of the branch ``0 <= r <= max_monotonic_radius``
    (where the model increases, so the root there is unique), which every evaluation narrows; a
    Newton step that would leave the bracket is replaced by its midpoint. Newton starts from the
    first-order inverse ``rd / (1 + k1 rd^2 + k2 rd^4)`` (a few steps reach machine precision away
    from the fold) and stops on the residual, ``|r (1 + k1 r^2 + k2 r^4) - rd| <= 4 eps rd``, or on a
    bracket one rounding unit wide. Radii ``rd`` beyond :func:`max_distorted_radius` have no root
    on the branch: the caller must refuse them (:func:`undistort_normalized` does). NaN stays NaN.

    Returns ``(r, converged)``; ``converged`` is False if some radius did not settle in ``max_iter``
    evaluations.
    """
    rd = np.asarray(rd, dtype=float)
    out = np.full(rd.shape, np.nan)
    idx = np.flatnonzero(np.isfinite(rd))               # the radii still being solved for
    target = rd.ravel()[idx]
    lo, hi = _monotonic_bracket(target, k1, k2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = target / radial_factor(target * target, k1, k2)
    r = np.where((r >= lo) & (r <= hi), r, 0.5 * (lo + hi))
    tol = 4.0 * np.finfo(float).eps * np.maximum(target, np.finfo(float).tiny)
    for _ in range(max_iter):
        r2 = r * r
        f = r * radial_factor(r2, k1, k2) - target
        done = (np.abs(f) <= tol) | (hi - lo <= 2.0 * np.finfo(float).eps * hi)
        if done.all():
            out.flat[idx] = r
            return out, True
        if 2 * done.sum() >= done.size:                 # drop the settled radii (not every time: it costs)
            out.flat[idx[done]] = r[done]
            keep = ~done
            idx, target, tol, lo, hi, r, r2, f, done = (a[keep] for a in (idx, target, tol, lo, hi, r, r2, f, done))
        lo, hi = np.where(f < 0, r, lo), np.where(f > 0, r, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = r - f / (1.0 + r2 * (3.0 * k1 + 5.0 * k2 * r2))
        r = np.where(done, r, np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi)))
    out.flat[idx] = r
    return out, False


def undistort_normalized(xy_d: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) -> ideal ones (paper eqs. 24-27).

    Finds the undistorted radius on the monotonic branch with :func:`undistort_radius`, then
    scales ``(xd, yd)`` by ``r / rd`` (eqs. 26, 27). NaN rows (corners not measured) stay NaN.

    Raises
    ------
    NotInvertibleError
        Where a radius lies beyond the fold of the model (:func:`max_distorted_radius`), where the
        distorted image of the monotonic branch ends, or if the root does not settle.
    """
    xy_d = np.asarray(xy_d, dtype=float)
    rd = np.hypot(xy_d[..., 0], xy_d[..., 1])
    rd_max = max_distorted_radius(k1, k2)
    if np.any(rd > rd_max):
        raise NotInvertibleError(
            f"distortion k1={k1:.4g}, k2={k2:.4g} is not invertible beyond normalised "
            f"radius {rd_max:.4g}, where the model folds over (asked for {np.nanmax(rd):.4g})")
    r, converged = undistort_radius(rd, k1, k2)
    if not converged:
        raise NotInvertibleError("undistortion did not converge (radius too close to the fold of the model)")
    scale = np.divide(r, rd, out=np.ones_like(rd), where=rd > 0)
    return xy_d * scale[..., None]


def pixel_from_normalized(cam: CameraModel, xy_d: np.ndarray) -> np.ndarray:
    """Distorted normalised (N, 2) -> pixels (N, 2) through the matrix A (paper eq. 28)."""
    xy_d = np.asarray(xy_d, dtype=float)
    u = cam.fx * xy_d[..., 0] + cam.skew * xy_d[..., 1] + cam.cx
    v = cam.fy * xy_d[..., 1] + cam.cy
    return np.stack([u, v], axis=-1)


def normalized_from_pixel(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalised (N, 2) through A^-1 (paper eq. 24)."""
    uv = np.asarray(uv, dtype=float)
    y = (uv[..., 1] - cam.cy) / cam.fy
    x = (uv[..., 0] - cam.cx - cam.skew * y) / cam.fx
    return np.stack([x, y], axis=-1)


def project_points(cam: CameraModel, X_cam: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) -> distorted pixels (N, 2)."""
    X_cam = np.asarray(X_cam, dtype=float)
    xy = X_cam[..., :2] / X_cam[..., 2:3]
    return pixel_from_normalized(cam, distort_normalized(xy, cam.k1, cam.k2))


def project_with_jacobians(cam: CameraModel, X_cam: np.ndarray):
    """Projection and its exact derivatives.

    Returns
    -------
    uv : (N, 2) pixels
    d_uv_d_X : (N, 2, 3) derivative with respect to the camera-frame point
    d_uv_d_intrinsics : (N, 2, 7) derivative with respect to ``[fx, fy, skew, cx, cy, k1, k2]``
    """
    X_cam = np.asarray(X_cam, dtype=float)
    X, Y, Z = X_cam[:, 0], X_cam[:, 1], X_cam[:, 2]
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    r2 = x * x + y * y
    f = radial_factor(r2, cam.k1, cam.k2)
    xd, yd = x * f, y * f
    u = cam.fx * xd + cam.skew * yd + cam.cx
    v = cam.fy * yd + cam.cy

    g = 2.0 * (cam.k1 + 2.0 * cam.k2 * r2)      # d f / d r2 times 2
    dxd_dx, dxd_dy = f + x * x * g, x * y * g
    dyd_dx, dyd_dy = dxd_dy, f + y * y * g
    du_dx = cam.fx * dxd_dx + cam.skew * dyd_dx
    du_dy = cam.fx * dxd_dy + cam.skew * dyd_dy
    dv_dx, dv_dy = cam.fy * dyd_dx, cam.fy * dyd_dy

    n = len(X)
    J_X = np.empty((n, 2, 3))
    J_X[:, 0, 0] = du_dx * iz
    J_X[:, 0, 1] = du_dy * iz
    J_X[:, 0, 2] = -(du_dx * x + du_dy * y) * iz
    J_X[:, 1, 0] = dv_dx * iz
    J_X[:, 1, 1] = dv_dy * iz
    J_X[:, 1, 2] = -(dv_dx * x + dv_dy * y) * iz

    J_K = np.zeros((n, 2, 7))
    J_K[:, 0, 0] = xd
    J_K[:, 0, 2] = yd
    J_K[:, 0, 3] = 1.0
    J_K[:, 1, 1] = yd
    J_K[:, 1, 4] = 1.0
    pu = cam.fx * x + cam.skew * y
    pv = cam.fy * y
    J_K[:, 0, 5], J_K[:, 0, 6] = pu * r2, pu * r2 * r2
    J_K[:, 1, 5], J_K[:, 1, 6] = pv * r2, pv * r2 * r2
    return np.stack([u, v], axis=-1), J_X, J_K


def ideal_normalized_from_pixel(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Observed (distorted) pixels -> ideal normalised coordinates ``(X/Z, Y/Z)`` of their rays."""
    return undistort_normalized(normalized_from_pixel(cam, uv), cam.k1, cam.k2)


def undistort_points(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Observed (distorted) pixels -> ideal pinhole pixels of the same matrix A."""
    return pixel_from_normalized(cam, ideal_normalized_from_pixel(cam, uv))


def distort_points(cam: CameraModel, uv_ideal: np.ndarray) -> np.ndarray:
    """Ideal pinhole pixels -> observed (distorted) pixels; inverse of :func:`undistort_points`."""
    xy = normalized_from_pixel(cam, uv_ideal)
    return pixel_from_normalized(cam, distort_normalized(xy, cam.k1, cam.k2))


def image_corner_radius(cam: CameraModel) -> float:
    """Largest distorted normalised radius reached inside the image (at its corners)."""
    w, h = cam.image_size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    return float(np.max(np.linalg.norm(normalized_from_pixel(cam, corners), axis=1)))


def check_invertible_in_image(cam: CameraModel, corners_may_fold: bool = False) -> None:
    """Raise :class:`NotInvertibleError` if undistortion is not unique somewhere in the image.

    With ``corners_may_fold`` a fold is accepted where it lies beyond the middle of every image
    edge, i.e. where it cuts off only the image's corners (a forward remap masks those pixels).
    """
    rd_max = max_distorted_radius(cam.k1, cam.k2)
    w, h = cam.image_size
    edge_middles = np.array([[-0.5, (h - 1) / 2], [w - 0.5, (h - 1) / 2], [(w - 1) / 2, -0.5], [(w - 1) / 2, h - 0.5]])
    rd_img = float(np.max(np.linalg.norm(normalized_from_pixel(cam, edge_middles), axis=1))) if corners_may_fold \
        else image_corner_radius(cam)
    if rd_img > rd_max:
        where = "at the middle of an image edge" if corners_may_fold else "inside the image"
        raise NotInvertibleError(
            f"distortion k1={cam.k1:.4g}, k2={cam.k2:.4g} folds over {where}: "
            f"radius not monotonic beyond normalised {rd_max:.4g}, image reaches {rd_img:.4g}")
