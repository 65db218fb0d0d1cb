"""The camera model: pinhole with skew and a lens model (paper eqs. 1, 13, 24-28), or a fisheye.

Conventions (README, "Conventions"):

* Camera frame: x right, y down, z forward; a point ``X_cam`` projects to normalised
  coordinates ``x = X/Z, y = Y/Z``.
* Lens distortion, OpenCV's model term for term (so that exports are exact), ``r2 = x^2 + y^2``::

      xd = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
      yd = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y

  The paper's model (eq. 13; eq. 25 corrected) is the lens model ``k1k2``: ``p1 = p2 = k3 = 0``,
  and with those zero every function here computes exactly what it computed before the other
  coefficients existed. :data:`LENS_MODELS` names the models; a :class:`CameraModel` says which
  one it is, and its coefficients outside that model are zero.
* The fisheye lens model ``kb4`` is OpenCV's ``cv2.fisheye`` (Kannala-Brandt, equidistant), with
  ``r = sqrt(x^2 + y^2)``, ``theta = atan(r)`` (the ray's angle from the axis)::

      theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
      xd = x theta_d / r,  yd = y theta_d / r

  Its ``k1 .. k4`` have that meaning (not the radial polynomial's). A fisheye projects rays at and
  beyond 90 degrees too (``theta = atan2(sqrt(X^2 + Y^2), Z)``); undistortion to the normalised
  plane exists only below 90 degrees. The functions on a :class:`CameraModel` (:func:`distort`,
  :func:`undistort`, :func:`lens_jacobian`, :func:`fold_radius`, ...) dispatch on the model's
  family; those on bare coefficients are the family's own.
* Pixels: ``u = fx xd + skew yd + cx``, ``v = fy yd + cy``; pixel ``(row i, col j)`` has its
  centre at ``(u=j, v=i)``. ``fx, fy, skew, cx, cy`` are the paper's alpha, beta, gamma, u0, v0.

Arrays of points are ``(N, 2)`` (pixels or normalised) or ``(N, 3)`` (camera frame, mm).
Functions on normalised coordinates take the coefficients in OpenCV's order,
``(k1, k2, p1=0, p2=0, k3=0)``, so ``f(xy, *cam.distortion)`` applies a camera's lens.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import NotInvertibleError

#: Lens coefficients in OpenCV's order (its ``distCoeffs``), then the fisheye's k4 (``cv2.fisheye``: k1 k2 k3 k4).
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4")
INTRINSIC_NAMES = ("fx", "fy", "skew", "cx", "cy") + DISTORTION_NAMES

#: Lens models by name; each name lists its coefficients. ``k1k2`` is the paper's (the default),
#: ``k1k2p1p2k3`` OpenCV's five-coefficient model, ``kb4`` OpenCV's fisheye (module docstring).
LENS_MODELS = {
    "k1k2": ("k1", "k2"),
    "k1k2k3": ("k1", "k2", "k3"),
    "k1k2p1p2": ("k1", "k2", "p1", "p2"),
    "k1k2p1p2k3": ("k1", "k2", "p1", "p2", "k3"),
    "kb4": ("k1", "k2", "k3", "k4"),
}
DEFAULT_LENS_MODEL = "k1k2"

#: The diagonal of a 35 mm film frame (36 x 24 mm): what a "35 mm-equivalent" focal length refers to.
FULL_FRAME_DIAGONAL_MM = float(np.hypot(36.0, 24.0))


def focal_px_from_35mm(image_size: tuple[int, int], f35_mm: float) -> float:
    """A camera's focal length in pixels from its 35 mm-equivalent focal length (EXIF
    ``FocalLengthIn35mmFilm``): the image diagonal is to the pixels what 43.27 mm is to the film."""
    return float(f35_mm) * float(np.hypot(*image_size)) / FULL_FRAME_DIAGONAL_MM


def equivalent_focal_35mm(image_size: tuple[int, int], f_px: float) -> float:
    """The 35 mm-equivalent focal length (mm) of a focal length in pixels (inverse of :func:`focal_px_from_35mm`)."""
    return float(f_px) * FULL_FRAME_DIAGONAL_MM / float(np.hypot(*image_size))
#: The lens models of the fisheye family (equidistant, ``theta_d`` a polynomial in the angle).
FISHEYE_MODELS = frozenset({"kb4"})


def intrinsic_names(model: str = DEFAULT_LENS_MODEL) -> tuple[str, ...]:
    """The intrinsics of a camera of lens model ``model``: ``fx fy skew cx cy`` and its coefficients."""
    return INTRINSIC_NAMES[:5] + LENS_MODELS[model]


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera. ``image_size`` is ``(width, height)`` in pixels; ``model`` is its
    lens model (a key of :data:`LENS_MODELS`), whose coefficients it may have; the others are 0.

    Raises
    ------
    ValueError
        An unknown ``model``, or a non-zero coefficient the model does not have.
    """

    image_size: tuple[int, int]
    fx: float
    fy: float
    skew: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    model: str = DEFAULT_LENS_MODEL

    def __post_init__(self):
        if self.model not in LENS_MODELS:
            raise ValueError(f"lens model {self.model!r} is unknown (choose from {', '.join(LENS_MODELS)})")
        foreign = [n for n in DISTORTION_NAMES if n not in LENS_MODELS[self.model] and getattr(self, n) != 0.0]
        if foreign:
            raise ValueError(f"lens model {self.model} has no {', '.join(foreign)}")

    @property
    def K(self) -> np.ndarray:
        """The paper's matrix A: ``[[fx, skew, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fisheye(self) -> bool:
        """Whether the lens model is a fisheye (:data:`FISHEYE_MODELS`)."""
        return self.model in FISHEYE_MODELS

    @property
    def distortion(self) -> tuple[float, ...]:
        """OpenCV's ``distCoeffs`` of this lens: ``(k1, k2, p1, p2, k3)``, or for a fisheye
        ``cv2.fisheye``'s ``D``, ``(k1, k2, k3, k4)``."""
        if self.fisheye:
            return self.k1, self.k2, self.k3, self.k4
        return self.k1, self.k2, self.p1, self.p2, self.k3

    @property
    def radial(self) -> tuple[float, float, float]:
        """``(k1, k2, k3)``: the radial part of a radial-tangential lens."""
        return self.k1, self.k2, self.k3

    @property
    def tangential(self) -> bool:
        """Whether the lens has tangential terms (``p1`` or ``p2`` not zero)."""
        return self.p1 != 0.0 or self.p2 != 0.0

    def as_vector(self) -> np.ndarray:
        """``[fx, fy, skew, cx, cy, k1, k2, p1, p2, k3, k4]`` (order of :data:`INTRINSIC_NAMES`)."""
        return np.array([getattr(self, n) for n in INTRINSIC_NAMES], dtype=float)

    @classmethod
    def from_vector(cls, image_size, vec, model: str = DEFAULT_LENS_MODEL) -> "CameraModel":
        """The camera of :meth:`as_vector` ``vec`` (a shorter one leaves the last coefficients 0)."""
        return cls(tuple(int(s) for s in image_size), *(float(x) for x in vec), model=model)

    def with_distortion(self, k1: float, k2: float, p1: float = 0.0, p2: float = 0.0,
                        k3: float = 0.0, k4: float = 0.0) -> "CameraModel":
        """The same camera and lens model with other coefficients (those not given are 0)."""
        return replace(self, k1=float(k1), k2=float(k2), p1=float(p1), p2=float(p2), k3=float(k3), k4=float(k4))

    def pinhole(self) -> "CameraModel":
        """The same matrix A without lens distortion (lens model ``k1k2``, every coefficient 0)."""
        return replace(self, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0, k4=0.0, model=DEFAULT_LENS_MODEL)


def radial_factor(r2: np.ndarray, k1: float, k2: float, k3: float = 0.0) -> np.ndarray:
    """``1 + k1 r^2 + k2 r^4 + k3 r^6`` for squared radii ``r2``."""
    if k3 == 0.0:
        return 1.0 + r2 * (k1 + k2 * r2)
    return 1.0 + r2 * (k1 + r2 * (k2 + k3 * r2))


def _radial_slope(r2: np.ndarray, k1: float, k2: float, k3: float = 0.0) -> np.ndarray:
    """``d rd / dr = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6`` of ``rd = r (1 + k1 r^2 + k2 r^4 + k3 r^6)``."""
    return radial_factor(r2, 3.0 * k1, 5.0 * k2, 7.0 * k3)


def tangential_shift(x: np.ndarray, y: np.ndarray, p1: float, p2: float) -> tuple[np.ndarray, np.ndarray]:
    """The tangential terms ``(2 p1 x y + p2 (r2 + 2 x^2), p1 (r2 + 2 y^2) + 2 p2 x y)`` at ideal ``x, y``."""
    r2 = x * x + y * y
    return 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y


def _distorted_with_jacobian(x: np.ndarray, y: np.ndarray, k1: float, k2: float, p1: float, p2: float,
                             k3: float):
    """``xd, yd`` of ideal ``x, y`` (the module's model) and the Jacobian ``d(xd, yd) / d(x, y)`` as
    ``(a, b, d)``: ``[[a, b], [b, d]]`` (it is symmetric). Also returns ``r2``."""
    r2 = x * x + y * y
    f = radial_factor(r2, k1, k2, k3)
    g = 2.0 * (k1 + 2.0 * k2 * r2) if k3 == 0.0 else 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # 2 df/dr2
    xd, yd = x * f, y * f
    a, b, d = f + x * x * g, x * y * g, f + y * y * g
    if p1 != 0.0 or p2 != 0.0:
        tx, ty = tangential_shift(x, y, p1, p2)
        xd, yd = xd + tx, yd + ty
        a = a + 2.0 * p1 * y + 6.0 * p2 * x
        b = b + 2.0 * p1 * x + 2.0 * p2 * y
        d = d + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, (a, b, d), r2


def distort_normalized(xy: np.ndarray, k1: float, k2: float, p1: float = 0.0, p2: float = 0.0,
                       k3: float = 0.0) -> np.ndarray:
    """Ideal normalised coordinates (N, 2) -> distorted ones (the module's model; paper eq. 13)."""
    xy = np.asarray(xy, dtype=float)
    r2 = np.sum(xy * xy, axis=-1, keepdims=True)
    out = xy * radial_factor(r2, k1, k2, k3)
    if p1 == 0.0 and p2 == 0.0:
        return out
    return out + np.stack(tangential_shift(xy[..., 0], xy[..., 1], p1, p2), axis=-1)


def _quadratic_roots(a: float, b: float, c: float) -> list[float]:
    """Real roots of ``a s^2 + b s + c`` (numerically stable; a vanishing ``a`` leaves the linear root)."""
    if a == 0.0:
        return [-c / b] if b != 0.0 else []
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return []
    q = -0.5 * (b + np.copysign(np.sqrt(disc), b))
    with np.errstate(over="ignore", divide="ignore"):   # q / a is +-inf for a vanishing a: no root there
        return [q / a, c / q] if q != 0.0 else []


#: Squared radii searched for the fold of a radial model with k3: up to r = 1e30, beyond any lens.
_S_MAX = 1e60


def _first_positive_root(c1: float, c2: float, c3: float) -> float:
    """Smallest positive root of ``P(s) = 1 + c1 s + c2 s^2 + c3 s^3`` (``inf`` if none).

    ``P(0) = 1``. Without ``c3`` the quadratic formula. With it, ``P`` is monotonic between the
    roots of ``P'`` (a quadratic), so the first of those pieces on which ``P`` reaches 0 brackets
    the root (:func:`_bracketed_root`); that holds for any ``c3``, also one so small that the
    cubic's third root is astronomically far away (roots beyond :data:`_S_MAX` count as none).
    """
    if c3 == 0.0:
        return min([s for s in _quadratic_roots(c2, c1, 1.0) if s > 0.0], default=float("inf"))

    def P(s):
        return 1.0 + s * (c1 + s * (c2 + c3 * s))

    def dP(s):
        return c1 + s * (2.0 * c2 + 3.0 * c3 * s)

    a = 0.0
    for b in sorted(s for s in _quadratic_roots(3.0 * c3, 2.0 * c2, c1) if 0.0 < s < _S_MAX) + [_S_MAX]:
        if P(b) <= 0.0:
            return _bracketed_root(P, dP, a, b)
        a = b
    return float("inf")


def _bracketed_root(P, dP, a: float, b: float) -> float:
    """The root of ``P`` in ``[a, b]``, where ``P`` is monotonic, ``P(a) > 0 >= P(b)``: Newton's steps,
    a bisection (geometric where the bracket spans decades) wherever a step would leave the bracket,
    which shrinks at every step, until it is a few rounding errors wide. (Written out rather than
    scipy's ``brentq``: importing scipy takes a third of a second, for one scalar root.)"""
    x = b
    for _ in range(1000):           # from b = 1e60 Newton shrinks a cubic's tail by 2/3 a step: 350 at most
        p = P(x)
        if p == 0.0:
            return x
        if p > 0.0:
            a = x
        else:
            b = x
        if b - a <= 4.0 * np.finfo(float).eps * b:
            break
        slope = dP(x)
        with np.errstate(over="ignore"):            # a slope near 0 sends the step far out: a bisection then
            step = x - p / slope if slope != 0.0 else np.nan
        if a < step < b:
            x = step
        else:
            x = np.sqrt(a * b) if a > 0.0 and b > 1e3 * a else 0.5 * (a + b)
    return float(b)


def max_monotonic_radius(k1: float, k2: float, k3: float = 0.0) -> float:
    """Largest undistorted radius up to which ``rd = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` is increasing.

    ``d rd / dr = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6``; its first positive root in ``r^2`` bounds the
    region where the radial part of the lens has a unique inverse. Returns ``inf`` when there is none.
    """
    s = _first_positive_root(3.0 * k1, 5.0 * k2, 7.0 * k3)
    return float(np.sqrt(s)) if np.isfinite(s) else float("inf")


def max_distorted_radius(k1: float, k2: float, k3: float = 0.0) -> float:
    """Largest distorted normalised radius the radial model reaches before it folds over (``inf`` if
    never): ``rd`` at :func:`max_monotonic_radius`. Undistortion is unique only below it."""
    r_max = max_monotonic_radius(k1, k2, k3)
    return float(r_max * radial_factor(r_max**2, k1, k2, k3)) if np.isfinite(r_max) else float("inf")


def _monotonic_bracket(rd: np.ndarray, k1: float, k2: float, k3: float) -> tuple[np.ndarray, np.ndarray]:
    """``[lo, hi]`` enclosing the root of ``r (1 + k1 r^2 + k2 r^4 + k3 r^6) = rd`` on the monotonic branch.

    The branch is ``0 <= r <= max_monotonic_radius``; where that is infinite, ``hi`` doubles from
    ``rd`` until the model passes ``rd``.
    """
    lo = np.zeros_like(rd)
    r_max = max_monotonic_radius(k1, k2, k3)
    if np.isfinite(r_max):
        return lo, np.full_like(rd, r_max)
    hi = np.maximum(rd, 1e-300)
    for _ in range(2100):                       # 2^2100 exceeds any float: the loop always ends
        short = hi * radial_factor(hi * hi, k1, k2, k3) < rd
        if not short.any():
            break
        hi = np.where(short, 2.0 * hi, hi)
    return lo, hi


def undistort_radius(rd: np.ndarray, k1: float, k2: float, max_iter: int = 200, k3: float = 0.0):
    """Solve ``rd = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` for ``r`` on the monotonic branch (paper eq. 25,
    typo corrected): Newton's method safeguarded by bisection.

    The root is kept in a bracket ``[lo, hi]`` of the branch ``0 <= r <= max_monotonic_radius``
    (where the model increases, so the root there is unique), which every evaluation narrows; a
    Newton step that would leave the bracket is replaced by its midpoint. Newton starts from the
    first-order inverse ``rd / (1 + k1 rd^2 + ...)`` (a few steps reach machine precision away
    from the fold) and stops on the residual, ``|r (1 + k1 r^2 + ...) - rd| <= 4 eps rd``, or on a
    bracket one rounding unit wide. Radii ``rd`` beyond :func:`max_distorted_radius` have no root
    on the branch: the caller must refuse them (:func:`undistort_normalized` does). NaN stays NaN.

    Returns ``(r, converged)``; ``converged`` is False if some radius did not settle in ``max_iter``
    evaluations.
    """
    rd = np.asarray(rd, dtype=float)
    out = np.full(rd.shape, np.nan)
    idx = np.flatnonzero(np.isfinite(rd))               # the radii still being solved for
    target = rd.ravel()[idx]
    lo, hi = _monotonic_bracket(target, k1, k2, k3)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = target / radial_factor(target * target, k1, k2, k3)
    r = np.where((r >= lo) & (r <= hi), r, 0.5 * (lo + hi))
    tol = 4.0 * np.finfo(float).eps * np.maximum(target, np.finfo(float).tiny)
    for _ in range(max_iter):
        r2 = r * r
        f = r * radial_factor(r2, k1, k2, k3) - target
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
            newton = r - f / _radial_slope(r2, k1, k2, k3)
        r = np.where(done, r, np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi)))
    out.flat[idx] = r
    return out, False


def _coefficients_text(k1: float, k2: float, p1: float = 0.0, p2: float = 0.0, k3: float = 0.0,
                       k4: float = 0.0) -> str:
    """``k1=.., k2=..`` and the other coefficients where they are not zero, for messages."""
    values = dict(zip(DISTORTION_NAMES, (k1, k2, p1, p2, k3, k4)))
    return ", ".join(f"{n}={v:.4g}" for n, v in values.items() if n in ("k1", "k2") or v != 0.0)


def _radial_inverse(xy_r: np.ndarray, k1: float, k2: float, k3: float) -> np.ndarray:
    """Ideal points whose radial distortion alone gives ``xy_r`` (N, 2) (eqs. 25-27): the radius from
    :func:`undistort_radius`, the direction kept. A radius beyond the fold is taken at the fold."""
    rd = np.hypot(xy_r[..., 0], xy_r[..., 1])
    r, converged = undistort_radius(np.minimum(rd, max_distorted_radius(k1, k2, k3)), k1, k2, k3=k3)
    if not converged:
        raise NotInvertibleError("undistortion did not converge (radius too close to the fold of the model)")
    return xy_r * np.divide(r, rd, out=np.ones_like(rd), where=rd > 0)[..., None]


#: Newton on the full model stops when the residual is this many rounding units (of 1 or the radius).
_NEWTON_TOL_EPS = 16.0
_NEWTON_MAX_ITER = 50
_START_ITERATIONS = 3          # fixed-point steps x <- radial inverse(xd - tangential shift(x)) before Newton


def _undistort_tangential(xy_d: np.ndarray, k1: float, k2: float, p1: float, p2: float, k3: float) -> np.ndarray:
    """Ideal points (N, 2) that distort onto ``xy_d`` (N, 2) under the full model; NaN rows stay NaN.

    Start: the radial inverse of ``xd`` less the tangential shift of the current estimate, a few
    times (the shift taken first at ``xd`` itself). Then 2-D Newton on the full model, each step
    halved while it would leave the radial part's monotonic branch, stopped on the residual,
    ``max |distort(x) - xd| <= 16 eps max(|xd|, 1)``.

    Raises
    ------
    NotInvertibleError
        Where Newton does not settle, or settles where the Jacobian's determinant is not positive
        (the tangential terms fold the image there).
    """
    idx = np.flatnonzero(np.all(np.isfinite(xy_d), axis=-1))
    target = xy_d[idx]
    xy = target
    for _ in range(_START_ITERATIONS):
        xy = _radial_inverse(target - np.column_stack(tangential_shift(xy[:, 0], xy[:, 1], p1, p2)), k1, k2, k3)
    x, y = xy[:, 0], xy[:, 1]
    tx, ty = target[:, 0], target[:, 1]
    r2_max = max_monotonic_radius(k1, k2, k3) ** 2
    tol = _NEWTON_TOL_EPS * np.finfo(float).eps * np.maximum(np.maximum(np.abs(tx), np.abs(ty)), 1.0)
    for _ in range(_NEWTON_MAX_ITER):
        xd, yd, (a, b, d), _ = _distorted_with_jacobian(x, y, k1, k2, p1, p2, k3)
        fx, fy = xd - tx, yd - ty
        det = a * d - b * b
        done = np.maximum(np.abs(fx), np.abs(fy)) <= tol
        if done.all():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            sx, sy = np.where(done, 0.0, (d * fx - b * fy) / det), np.where(done, 0.0, (a * fy - b * fx) / det)
        for _ in range(60):                     # stay on the branch where the radial part increases
            outside = (x - sx) ** 2 + (y - sy) ** 2 > r2_max
            if not outside.any():
                break
            sx, sy = np.where(outside, 0.5 * sx, sx), np.where(outside, 0.5 * sy, sy)
        x, y = x - sx, y - sy
    else:
        raise NotInvertibleError(f"undistortion with {_coefficients_text(k1, k2, p1, p2, k3)} did not converge "
                                 "(a point too close to where the model folds over)")
    if not np.all(det > 0):
        raise NotInvertibleError(f"distortion {_coefficients_text(k1, k2, p1, p2, k3)} folds over where asked: "
                                 "the tangential terms fold the image there, so undistortion is not unique")
    out = np.full(xy_d.shape, np.nan)
    out[idx, 0], out[idx, 1] = x, y
    return out


def undistort_normalized(xy_d: np.ndarray, k1: float, k2: float, p1: float = 0.0, p2: float = 0.0,
                         k3: float = 0.0) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) -> ideal ones (paper eqs. 24-27, the module's model).

    Finds the undistorted radius of the radial part on its monotonic branch with
    :func:`undistort_radius`, and scales ``(xd, yd)`` by ``r / rd`` (eqs. 26, 27). Where ``p1`` or
    ``p2`` is not zero, that radial solution (of ``xd`` less its tangential shift) starts 2-D
    Newton on the full model, stopped on the residual (:func:`_undistort_tangential`). NaN rows
    (corners not measured) stay NaN.

    Raises
    ------
    NotInvertibleError
        Radial lens: where a radius lies beyond the fold of the model (:func:`max_distorted_radius`)
        or the root does not settle. Tangential lens: where Newton does not settle on the radial
        part's monotonic branch with a positive Jacobian (the full model folds there).
    """
    xy_d = np.asarray(xy_d, dtype=float)
    if p1 != 0.0 or p2 != 0.0:
        return _undistort_tangential(xy_d.reshape(-1, 2), k1, k2, p1, p2, k3).reshape(xy_d.shape)
    rd = np.hypot(xy_d[..., 0], xy_d[..., 1])
    rd_max = max_distorted_radius(k1, k2, k3)
    if np.any(rd > rd_max):
        raise NotInvertibleError(
            f"distortion {_coefficients_text(k1, k2, k3=k3)} is not invertible beyond normalised "
            f"radius {rd_max:.4g}, where the model folds over (asked for {np.nanmax(rd):.4g})")
    return _radial_inverse(xy_d, k1, k2, k3)


# ----------------------------------------------------------------------------- the fisheye (kb4)


def _theta_factor(t2: np.ndarray, k1: float, k2: float, k3: float, k4: float) -> np.ndarray:
    """``1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8`` for squared angles ``t2``: ``theta_d / theta``."""
    return 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))


def _theta_slope(t2: np.ndarray, k1: float, k2: float, k3: float, k4: float) -> np.ndarray:
    """``d theta_d / d theta = 1 + 3 k1 t^2 + 5 k2 t^4 + 7 k3 t^6 + 9 k4 t^8``."""
    return _theta_factor(t2, 3.0 * k1, 5.0 * k2, 7.0 * k3, 9.0 * k4)


def fisheye_max_angle(k1: float, k2: float, k3: float = 0.0, k4: float = 0.0) -> float:
    """Largest angle from the axis (rad, at most pi) up to which ``theta_d(theta)`` increases: the
    first positive root of ``d theta_d / d theta`` (a quartic in ``theta^2``), else pi."""
    roots = np.roots([9.0 * k4, 7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])      # np.roots drops leading zeros
    s = [r.real for r in roots if abs(r.imag) <= 1e-12 * max(abs(r), 1.0) and r.real > 0.0]
    return float(min(np.sqrt(min(s)), np.pi)) if s else float(np.pi)


def _theta_over_r(theta: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``theta / r`` (1 on the axis)."""
    return np.divide(theta, r, out=np.ones_like(r), where=r > 0)


def fisheye_distort(xy: np.ndarray, k1: float, k2: float, k3: float = 0.0, k4: float = 0.0) -> np.ndarray:
    """Ideal normalised coordinates (N, 2) -> distorted ones of the ``kb4`` fisheye (module docstring)."""
    xy = np.asarray(xy, dtype=float)
    r = np.hypot(xy[..., 0], xy[..., 1])[..., None]
    theta = np.arctan(r)
    return xy * _theta_over_r(theta, r) * _theta_factor(theta * theta, k1, k2, k3, k4)


def _fisheye_with_jacobian(x: np.ndarray, y: np.ndarray, k1: float, k2: float, k3: float, k4: float):
    """``xd, yd``, ``d(xd, yd) / d(x, y)`` as ``(a, b, d)`` (symmetric) and ``{coefficient: (dxd,
    dyd)}`` of the fisheye. With ``s = theta_d / r``: ``dxd/dx = s + x^2 g``, ``dxd/dy = x y g``,
    ``g = s'(r) / r = (theta_d'(theta) / (1 + r^2) - s) / r^2`` (its limit ``2 (k1 - 1/3)`` on the
    axis); ``d xd / d k_j = x (theta / r) theta^(2j)``."""
    r2 = x * x + y * y
    r = np.sqrt(r2)
    theta = np.arctan(r)
    t2 = theta * theta
    q = _theta_over_r(theta, r)
    s = q * _theta_factor(t2, k1, k2, k3, k4)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(r2 > 0, (_theta_slope(t2, k1, k2, k3, k4) / (1.0 + r2) - s) / r2, 2.0 * (k1 - 1.0 / 3.0))
    xq, yq = x * q, y * q
    powers = {"k1": t2, "k2": t2 * t2, "k3": t2 * t2 * t2, "k4": t2 ** 4}
    return x * s, y * s, (s + x * x * g, x * y * g, s + y * y * g), {n: (xq * w, yq * w) for n, w in powers.items()}


def _fisheye_angle(theta_d: np.ndarray, k: tuple, theta_max: float, max_iter: int = 100) -> np.ndarray:
    """Solve ``theta (1 + k1 theta^2 + ...) = theta_d`` on ``[0, theta_max]`` (where it increases):
    Newton safeguarded by bisection from ``theta = theta_d``, stopped on ``4 eps`` of the residual."""
    lo, hi = np.zeros_like(theta_d), np.full_like(theta_d, theta_max)
    t = np.clip(theta_d, lo, hi)
    tol = 4.0 * np.finfo(float).eps * np.maximum(theta_d, np.finfo(float).tiny)
    for _ in range(max_iter):
        f = t * _theta_factor(t * t, *k) - theta_d
        if np.all((np.abs(f) <= tol) | (hi - lo <= 2.0 * np.finfo(float).eps * hi)):
            return t
        lo, hi = np.where(f < 0, t, lo), np.where(f > 0, t, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = t - f / _theta_slope(t * t, *k)
        t = np.where(np.abs(f) <= tol, t, np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi)))
    raise NotInvertibleError("fisheye undistortion did not converge (an angle too close to the fold of the model)")


def fisheye_max_distorted_radius(k1: float, k2: float, k3: float = 0.0, k4: float = 0.0) -> float:
    """Largest distorted normalised radius ``theta_d`` with a unique ray below 90 degrees (the image of
    the fold of ``theta_d(theta)``, or of 90 degrees if that comes first): undistortion's limit."""
    t = min(fisheye_max_angle(k1, k2, k3, k4), np.pi / 2)
    return float(t * _theta_factor(t * t, k1, k2, k3, k4))


def fisheye_undistort(xy_d: np.ndarray, k1: float, k2: float, k3: float = 0.0, k4: float = 0.0) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) of the ``kb4`` fisheye -> ideal ones (``x = X/Z``).

    ``theta`` from ``theta_d = |xd|`` on the increasing branch of ``theta_d(theta)`` (bracketed
    Newton), then ``r = tan(theta)`` along the same direction. NaN rows stay NaN.

    Raises
    ------
    NotInvertibleError
        A radius beyond :func:`fisheye_max_distorted_radius`: past the model's fold, or a ray at or
        beyond 90 degrees from the axis, which has no point on the normalised plane.
    """
    xy_d = np.asarray(xy_d, dtype=float)
    theta_d = np.hypot(xy_d[..., 0], xy_d[..., 1])
    limit = fisheye_max_distorted_radius(k1, k2, k3, k4)
    if np.any(theta_d >= limit):
        raise NotInvertibleError(
            f"fisheye {_coefficients_text(k1, k2, k3=k3, k4=k4)} has no ray below 90 degrees, or no unique "
            f"one, beyond normalised radius {limit:.4g} (asked for {np.nanmax(theta_d):.4g})")
    ok = np.isfinite(theta_d)
    theta = np.full_like(theta_d, np.nan)
    theta[ok] = _fisheye_angle(theta_d[ok], (k1, k2, k3, k4), min(fisheye_max_angle(k1, k2, k3, k4), np.pi / 2))
    scale = np.divide(np.tan(theta), theta_d, out=np.ones_like(theta_d), where=theta_d > 0)
    return xy_d * scale[..., None]


# ----------------------------------------------------------------------------- a camera's lens, either family


def distort(cam: CameraModel, xy: np.ndarray) -> np.ndarray:
    """Ideal normalised coordinates (N, 2) -> distorted ones by ``cam``'s lens."""
    if cam.fisheye:
        return fisheye_distort(xy, *cam.distortion)
    return distort_normalized(xy, *cam.distortion)


def undistort(cam: CameraModel, xy_d: np.ndarray) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) -> ideal ones by ``cam``'s lens (:func:`undistort_normalized`,
    :func:`fisheye_undistort`); raises :class:`NotInvertibleError` where that is not unique."""
    if cam.fisheye:
        return fisheye_undistort(xy_d, *cam.distortion)
    return undistort_normalized(xy_d, *cam.distortion)


def lens_jacobian(cam: CameraModel, x: np.ndarray, y: np.ndarray):
    """``xd, yd`` of ideal ``x, y``, ``d(xd, yd) / d(x, y)`` as ``(a, b, d)`` (``[[a, b], [b, d]]``) and
    ``{coefficient: (d xd, d yd)}`` for every coefficient of ``cam``'s lens family."""
    if cam.fisheye:
        return _fisheye_with_jacobian(x, y, *cam.distortion)
    xd, yd, jac, r2 = _distorted_with_jacobian(x, y, *cam.distortion)
    r4 = r2 * r2
    xy2 = 2.0 * x * y
    return xd, yd, jac, {"k1": (x * r2, y * r2), "k2": (x * r4, y * r4), "k3": (x * r4 * r2, y * r4 * r2),
                         "p1": (xy2, r2 + 2.0 * y * y), "p2": (r2 + 2.0 * x * x, xy2)}


def ray_directions(cam: CameraModel, xy_d: np.ndarray) -> np.ndarray:
    """Distorted normalised coordinates (..., 2) -> the directions (..., 3) of their rays: ``(x, y, 1)``
    of the ideal point, or for a fisheye ``(sin theta e, cos theta)`` (``e`` the unit direction in
    the image), which reaches 90 degrees and beyond up to the model's fold. Raises
    :class:`NotInvertibleError` beyond the fold (:func:`undistort`)."""
    xy_d = np.asarray(xy_d, dtype=float)
    if not cam.fisheye:
        xy = undistort(cam, xy_d)
        return np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1)
    theta_d = np.hypot(xy_d[..., 0], xy_d[..., 1])
    theta_max = fisheye_max_angle(*cam.distortion)
    limit = theta_max * _theta_factor(theta_max**2, *cam.distortion)
    if np.any(theta_d > limit):
        raise NotInvertibleError(f"fisheye {_coefficients_text(cam.k1, cam.k2, k3=cam.k3, k4=cam.k4)} folds over "
                                 f"beyond normalised radius {limit:.4g} (asked for {np.nanmax(theta_d):.4g})")
    theta = np.full_like(theta_d, np.nan)
    ok = np.isfinite(theta_d)
    theta[ok] = _fisheye_angle(theta_d[ok], cam.distortion, theta_max)
    e = xy_d * np.divide(1.0, theta_d, out=np.zeros_like(theta_d), where=theta_d > 0)[..., None]
    return np.concatenate([e * np.sin(theta)[..., None], np.cos(theta)[..., None]], axis=-1)


def fold_radius(cam: CameraModel) -> float:
    """Largest ideal normalised radius up to which ``cam``'s lens is monotonic (``inf`` if never
    folds): :func:`max_monotonic_radius` of the radial part, or ``tan`` of the fisheye's
    :func:`fisheye_max_angle` (``inf`` when that is 90 degrees or more)."""
    if cam.fisheye:
        t = fisheye_max_angle(*cam.distortion)
        return float(np.tan(t)) if t < np.pi / 2 else float("inf")
    return max_monotonic_radius(*cam.radial)


def fold_distorted_radius(cam: CameraModel) -> float:
    """Largest distorted normalised radius that undistorts uniquely (:func:`max_distorted_radius`,
    :func:`fisheye_max_distorted_radius`; the radial part of a radial-tangential lens)."""
    if cam.fisheye:
        return fisheye_max_distorted_radius(*cam.distortion)
    return max_distorted_radius(*cam.radial)


def distorted_radius(cam: CameraModel, r: np.ndarray) -> np.ndarray:
    """The distorted normalised radius of ideal radii ``r`` (the radial part of the lens)."""
    r = np.asarray(r, dtype=float)
    if cam.fisheye:
        theta = np.arctan(r)
        return theta * _theta_factor(theta * theta, *cam.distortion)
    return r * radial_factor(r * r, *cam.radial)


def undistorted_radius(cam: CameraModel, rd: np.ndarray) -> np.ndarray:
    """Inverse of :func:`distorted_radius` on the monotonic branch (radii beyond the fold are NaN)."""
    rd = np.asarray(rd, dtype=float)
    ok = rd < fold_distorted_radius(cam)
    out = np.full(rd.shape, np.nan)
    out[ok] = undistort(cam, np.column_stack([rd[ok], np.zeros(int(ok.sum()))]))[:, 0]
    return out


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
    """Camera-frame points (N, 3) -> distorted pixels (N, 2). A fisheye projects points at and behind
    90 degrees from the axis too (the angle ``atan2(sqrt(X^2 + Y^2), Z)``); a pinhole lens divides by Z.

    Parameters
    ----------
    cam : CameraModel
        The camera and its lens (the projection of the Conventions).
    X_cam : (N, 3) ndarray
        Points in the camera's frame, mm (x right, y down, z forward).

    Returns
    -------
    (N, 2) ndarray
        Their pixels ``(u, v)``, as the camera observes them (distorted)."""
    X_cam = np.asarray(X_cam, dtype=float)
    if not cam.fisheye:
        xy = X_cam[..., :2] / X_cam[..., 2:3]
        return pixel_from_normalized(cam, distort_normalized(xy, *cam.distortion))
    rho = np.hypot(X_cam[..., 0], X_cam[..., 1])[..., None]
    theta = np.arctan2(rho, X_cam[..., 2:3])
    direction = np.divide(X_cam[..., :2], rho, out=np.zeros_like(X_cam[..., :2]), where=rho > 0)
    return pixel_from_normalized(cam, direction * theta * _theta_factor(theta * theta, *cam.distortion))


def project_with_jacobians(cam: CameraModel, X_cam: np.ndarray):
    """Projection and its exact derivatives (points in front of the camera, ``Z > 0``).

    Returns
    -------
    uv : (N, 2) pixels
    d_uv_d_X : (N, 2, 3) derivative with respect to the camera-frame point
    d_uv_d_intrinsics : (N, 2, 11) derivative with respect to the intrinsics in the order of
        :data:`INTRINSIC_NAMES`, ``[fx, fy, skew, cx, cy, k1, k2, p1, p2, k3, k4]`` (every lens
        coefficient of the camera's lens family, whichever its model has; the others' columns 0)
    """
    X_cam = np.asarray(X_cam, dtype=float)
    X, Y, Z = X_cam[:, 0], X_cam[:, 1], X_cam[:, 2]
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    xd, yd, (dxd_dx, dxd_dy, dyd_dy), d_coefficients = lens_jacobian(cam, x, y)
    dyd_dx = dxd_dy
    u = cam.fx * xd + cam.skew * yd + cam.cx
    v = cam.fy * yd + cam.cy

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

    J_K = np.zeros((n, 2, len(INTRINSIC_NAMES)))
    J_K[:, 0, 0] = xd
    J_K[:, 0, 2] = yd
    J_K[:, 0, 3] = 1.0
    J_K[:, 1, 1] = yd
    J_K[:, 1, 4] = 1.0
    for name, (dxd, dyd) in d_coefficients.items():
        i = INTRINSIC_NAMES.index(name)
        J_K[:, 0, i] = cam.fx * dxd + cam.skew * dyd
        J_K[:, 1, i] = cam.fy * dyd
    return np.stack([u, v], axis=-1), J_X, J_K


def radial_lens_gradient(cam: CameraModel, X_cam: np.ndarray, names) -> np.ndarray:
    """How the image of the camera-frame point ``X_cam`` (3,) moves outward (along the line from the
    principal point) per unit of each lens coefficient ``names``: (len(names),) px per unit. With a
    covariance of the coefficients it gives the sigma of the lens's displacement there, in any lens model."""
    uv, _, J_K = project_with_jacobians(cam, np.asarray(X_cam, float).reshape(1, 3))
    outward = uv[0] - [cam.cx, cam.cy]
    outward = outward / max(np.linalg.norm(outward), 1e-12)
    return outward @ J_K[0][:, [INTRINSIC_NAMES.index(n) for n in names]]


def ideal_normalized_from_pixel(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Observed (distorted) pixels -> ideal normalised coordinates ``(X/Z, Y/Z)`` of their rays."""
    return undistort(cam, normalized_from_pixel(cam, uv))


def undistort_points(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Observed (distorted) pixels -> ideal pinhole pixels of the same matrix A.

    Parameters
    ----------
    cam : CameraModel
        The camera and its lens.
    uv : (N, 2) ndarray
        Pixels as the camera observed them.

    Returns
    -------
    (N, 2) ndarray
        Where a lens without distortion, of the same ``fx, fy, skew, cx, cy``, would have put them.

    Raises
    ------
    NotInvertibleError
        A pixel where the lens model folds over (no single ray).
    """
    return pixel_from_normalized(cam, ideal_normalized_from_pixel(cam, uv))


def distort_points(cam: CameraModel, uv_ideal: np.ndarray) -> np.ndarray:
    """Ideal pinhole pixels -> observed (distorted) pixels; inverse of :func:`undistort_points`.

    Parameters
    ----------
    cam : CameraModel
        The camera and its lens.
    uv_ideal : (N, 2) ndarray
        Pixels of a lens without distortion, of the same ``fx, fy, skew, cx, cy``.

    Returns
    -------
    (N, 2) ndarray
        Where the camera observes them.
    """
    return pixel_from_normalized(cam, distort(cam, normalized_from_pixel(cam, uv_ideal)))


def image_corner_radius(cam: CameraModel) -> float:
    """Largest distorted normalised radius reached inside the image (at its corners)."""
    w, h = cam.image_size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    return float(np.max(np.linalg.norm(normalized_from_pixel(cam, corners), axis=1)))


def _folds_tangentially(cam: CameraModel, rd_img: float, samples: int = 129) -> bool:
    """Whether the full model folds (its Jacobian's determinant is not positive) at an ideal point
    whose distorted image lies inside the image and within normalised radius ``rd_img``.

    Samples a square grid of ideal points out to the radius whose radial distortion reaches
    ``rd_img`` (10 % beyond, for the tangential shift), at most to the radial part's fold.
    """
    k1, k2, k3 = cam.radial
    rd_max = max_distorted_radius(k1, k2, k3)
    r_out = float(undistort_radius(np.array([min(1.1 * rd_img, rd_max)]), k1, k2, k3=k3)[0][0])
    t = np.linspace(-r_out, r_out, samples)
    x, y = (a.ravel() for a in np.meshgrid(t, t))
    xd, yd, (a, b, d), r2 = _distorted_with_jacobian(x, y, *cam.distortion)
    uv = pixel_from_normalized(cam, np.column_stack([xd, yd]))
    w, h = cam.image_size
    seen = ((r2 <= r_out * r_out) & (np.hypot(xd, yd) <= rd_img) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
    return bool(np.any(a[seen] * d[seen] - b[seen] ** 2 <= 0))


def check_invertible_in_image(cam: CameraModel, corners_may_fold: bool = False) -> None:
    """Raise :class:`NotInvertibleError` if undistortion is not unique somewhere in the image.

    With ``corners_may_fold`` a fold is accepted where it lies beyond the middle of every image
    edge, i.e. where it cuts off only the image's corners (a forward remap masks those pixels).
    The radial part is checked exactly (its fold radius, :func:`max_distorted_radius`); for a lens
    with tangential terms the determinant of the full model's Jacobian must also be positive on a
    dense grid of the ideal points that the image shows. A fisheye must not fold inside the image,
    nor show rays at 90 degrees or more from its axis (they have no undistorted point).
    """
    rd_max = fold_distorted_radius(cam)
    w, h = cam.image_size
    edge_middles = np.array([[-0.5, (h - 1) / 2], [w - 0.5, (h - 1) / 2], [(w - 1) / 2, -0.5], [(w - 1) / 2, h - 0.5]])
    rd_img = float(np.max(np.linalg.norm(normalized_from_pixel(cam, edge_middles), axis=1))) if corners_may_fold \
        else image_corner_radius(cam)
    where = "at the middle of an image edge" if corners_may_fold else "inside the image"
    if rd_img > rd_max:
        if cam.fisheye:
            raise NotInvertibleError(
                f"fisheye {_coefficients_text(cam.k1, cam.k2, k3=cam.k3, k4=cam.k4)} folds over, or sees "
                f"90 degrees from its axis, {where}: beyond normalised {rd_max:.4g}, image reaches {rd_img:.4g}")
        raise NotInvertibleError(
            f"distortion {_coefficients_text(cam.k1, cam.k2, k3=cam.k3)} folds over {where}: "
            f"radius not monotonic beyond normalised {rd_max:.4g}, image reaches {rd_img:.4g}")
    if cam.tangential and _folds_tangentially(cam, rd_img):
        raise NotInvertibleError(f"distortion {_coefficients_text(*cam.distortion)} folds over {where}: its "
                                 "tangential terms fold the image there, so undistortion is not unique")


def in_frame(cam: CameraModel, X_cam: np.ndarray) -> np.ndarray:
    """(N,) True for camera-frame points (N, 3) that ``cam`` sees: in front of it, short of the
    lens's fold (:func:`~dualcal.geometry.camera.fold_radius`) and projected inside the image."""
    X_cam = np.asarray(X_cam, float)
    front = X_cam[:, 2] > 0
    xy = X_cam[:, :2] / np.where(front, X_cam[:, 2], 1.0)[:, None]
    uv = project_points(cam, np.where(front[:, None], X_cam, 1.0))
    w, h = cam.image_size
    inside = np.all((uv >= 0) & (uv <= [w - 1, h - 1]), axis=1)
    return front & (np.hypot(xy[:, 0], xy[:, 1]) < fold_radius(cam)) & inside


def pixel_rays(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """The camera-frame rays ``(x, y, 1)`` (n, 3) of pixels ``uv`` (n, 2), through the lens; where the
    lens cannot be undone there (a poorly determined one may fold inside the image), the pinhole rays."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    try:
        xy = ideal_normalized_from_pixel(cam, uv)
    except NotInvertibleError:
        xy = None
    if xy is None or not np.all(np.isfinite(xy)):
        xy = normalized_from_pixel(cam, uv)
    return np.column_stack([xy, np.ones(len(xy))])
