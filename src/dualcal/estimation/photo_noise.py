"""Each photo's own noise: a variance component per photo, and the weight it gives the photo in the adjustment.

A blurred photo (the board 5-20 px out of focus) has noisier corners than a sharp one (0.2-1 px against
0.03-0.1 px). Counted alike, it pulls the result as hard as a sharp photo, and against the sharp photos' noise
its corners look like outliers. So every photo's noise is estimated from its own residuals, with every camera
adjusted alone (the photo's own pose free: what is measured is its corners' noise, not how well the rig ties
them), and the adjustment weighs each photo by it (:mod:`dualcal.estimation.adjust`, ``weights``):

* the variance component of photo ``b``: ``s_b^2 = sum |e_k|^2 / nu_b`` over its corners within the outlier
  limit, of its rough residuals ``e_k``: the residuals less their smooth part, a cubic in the board's
  coordinates (:func:`rough_residuals`). What is smooth over a board (its pose, a bent board, a lens term the model
  lacks, a shot out of sync) is no corner noise: a blurred photo's corners scatter about it, and its misfit is
  for the board's shape, the lens model and the checks to find. ``nu_b`` degrees of freedom: its ``2 n_b``
  coordinates less the ten smooth terms of each and what the adjustment fitted of them (:func:`rough_residuals`);
* shrunk toward its camera's level where it has few corners, by empirical Bayes on the log scale (a
  random-effects model, as DerSimonian & Laird 1986 estimate it): ``y_b = ln s_b^2`` less its bias is about
  normal with variance ``v_b = psi'(nu_b / 2)`` (about ``2 / nu_b``); the camera's photos' true levels scatter by
  ``tau^2``, estimated by the method of moments from how far Cochran's ``Q = sum (y_b - mean)^2 / v_b`` exceeds
  what photos alike give (its chi-square quantile at :data:`ALIKE_LEVEL`: 0 unless the photos differ beyond
  chance); each photo's level is ``mu + tau^2 / (tau^2 + v_b) (y_b - mu)`` (``mu`` the camera's random-effects
  mean): its own estimate where the photos differ and it has many corners, its camera's where they are alike
  or it has few; never below :data:`SHARPEST_SHARE` of its camera's level. The cameras' levels are shrunk toward
  the rig's mean alike, so that cameras of the same noise share one level;
* its weight ``w_b = sigma_ref^2 / sigma_b^2``, with ``sigma_ref^2 = sum nu_b / sum (nu_b / sigma_b^2)`` over
  every photo, so that ``s0`` stays in pixels (the noise of a photo of weight 1) and, on photos all alike, every
  weight is 1 and the adjustment is the unweighted one.

A corner is then an outlier where its rough residual is far above its own photo's noise
(:mod:`dualcal.estimation.outliers`), and a blurred photo keeps its corners. A photo whose median residual
exceeds :data:`GROSS_SHARE` of its squares' size in the image is no noisy measurement of the board but another
numbering or another board (:attr:`PhotoNoise.gross`): it is left out. What a photo's noise costs is its share
of the information it would give as sharp as its camera's sharpest photo, ``(sigma_sharp / sigma_b)^2``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .adjust import Solution, photo_jacobians
from .distributions import chi2_quantile

__all__ = ["ALIKE_LEVEL", "GROSS_SHARE", "MEDIAN_LENGTH", "SHARPEST_SHARE", "PhotoNoise", "photo_noise",
           "photo_weights", "rough_residuals"]

#: The median length of a 2-D residual of independent equal errors, in units of their sigma: ``sqrt(2 ln 2)``.
MEDIAN_LENGTH = float(np.sqrt(2.0 * np.log(2.0)))
#: A photo's median residual (px) beyond this share of its squares' size in the image (px) is no corner noise:
#: a blurred corner is off by a few hundredths of a square (defocus of 20 px on squares of 100 px: about 1 px), a
#: corner numbered as another by a whole square.
GROSS_SHARE = 0.1
#: Smooth terms per image coordinate taken out of a photo's residuals before its noise is measured: a cubic in the
#: board's coordinates (its pose's six unknowns are among them, to first order). A quadratic left a lens term the
#: model lacks in the photos near a wide's edge (phone3, k3 = 0.2: 2-7 x the corner noise), which then weighed
#: them down and hid the term from the comparison of lens models; the cubic leaves under 1.2 x.
SMOOTH_TERMS = 10
#: Noise below this (px) is numerical: exact synthetic corners.
NOISE_FLOOR_PX = 1e-6
#: No photo's noise is taken below this share of its camera's level: blur makes a photo noisier, nothing makes it
#: much sharper than its camera focuses, and a smaller estimate is an artefact (exact corners planted in a set, a
#: few corners that fit by chance) that would let one photo outweigh its camera's others by orders of magnitude.
SHARPEST_SHARE = 1.0 / 3.0
#: Photos (cameras) count as of one noise level unless their estimates scatter beyond what one level gives
#: at this quantile of Cochran's Q: on photos alike, 99 % of calibrations weigh every photo alike (weight 1).
ALIKE_LEVEL = 0.99


@dataclass(frozen=True)
class PhotoNoise:
    """Every photo's noise (module docstring), by ``(camera, view)``: ``noise_px`` its level ``sigma_b`` (px per
    coordinate) shrunk toward its camera's, ``raw_px`` its own estimate ``s_b``, ``dof`` its ``nu_b``;
    ``camera_px`` each camera's level (shrunk toward the rig's) and ``spread`` its ``tau`` (the scatter of its
    photos' log-variances; 0: photos alike), ``camera_spread`` that of the cameras' levels; ``reference_px``
    ``sigma_ref``; ``gross`` the photos whose median residual exceeds :data:`GROSS_SHARE` of their squares, the
    worst first (not in the others); ``lengths_px`` (n_blocks, N) the rough residuals' lengths (px) of the
    photos of the solution it was estimated from, in its blocks' order (NaN where not measured)."""

    noise_px: dict[tuple[str, str], float]
    raw_px: dict[tuple[str, str], float]
    dof: dict[tuple[str, str], float]
    camera_px: dict[str, float]
    spread: dict[str, float]
    camera_spread: float
    reference_px: float
    gross: list[tuple[str, str]]
    lengths_px: np.ndarray | None = None

    def weights(self) -> dict[tuple[str, str], float] | None:
        """``{(camera, view): w_b}`` (module docstring); None where every photo is of one level (every weight 1)."""
        if len(set(self.noise_px.values())) <= 1:
            return None
        return {k: (self.reference_px / s) ** 2 for k, s in self.noise_px.items()}

    def information_share(self) -> dict[tuple[str, str], float]:
        """``{(camera, view): (sigma_sharp / sigma_b)^2}``: the share of the information each photo gives of what
        it would give as sharp as its camera's sharpest photo."""
        sharp = {}
        for (camera, _), s in self.noise_px.items():
            sharp[camera] = min(sharp.get(camera, np.inf), s)
        return {k: (sharp[k[0]] / s) ** 2 for k, s in self.noise_px.items()}

    def to_dict(self, photos_kept=None) -> dict:
        """calib.json's ``adjustment.photo_noise``: ``reference_px``, ``camera_spread``, per camera ``camera_px`` and
        ``spread``, and per photo ``photos.<camera>.<view>`` ``{"noise_px", "raw_px", "dof", "weight",
        "information_share"}`` (of the ``(camera, view)`` in ``photos_kept``, default all; ``dof`` rounded to the
        integer the file's contract has)."""
        weights, share = self.weights() or dict.fromkeys(self.noise_px, 1.0), self.information_share()
        photos: dict[str, dict[str, dict]] = {}
        for (camera, view), s in sorted(self.noise_px.items()):
            if photos_kept is not None and (camera, view) not in photos_kept:
                continue
            photos.setdefault(camera, {})[view] = {
                "noise_px": s, "raw_px": self.raw_px[camera, view], "dof": round(self.dof[camera, view]),
                "weight": weights[camera, view], "information_share": share[camera, view]}
        return {"reference_px": self.reference_px, "camera_px": dict(self.camera_px), "spread": dict(self.spread),
                "camera_spread": self.camera_spread, "photos": photos}


def photo_weights(adjustment: Mapping) -> dict[tuple[str, str], float] | None:
    """The photos' weights a calibration recorded (``adjustment.photo_noise``, :meth:`PhotoNoise.to_dict`), None
    for an unweighted one."""
    doc = adjustment.get("photo_noise")
    if not doc:
        return None
    return {(camera, view): float(d["weight"]) for camera, views in doc["photos"].items() for view, d in views.items()}


def _log_variance_moments(nu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of ``ln(chi^2_nu / nu)``, ``psi(nu/2) - ln(nu/2)`` and ``psi'(nu/2)``, by their
    asymptotic series in ``x = nu / 2`` (to 1 % at ``nu = 2``, far closer above)."""
    x = nu / 2.0
    return -1.0 / (2 * x) - 1.0 / (12 * x * x), 1.0 / x + 1.0 / (2 * x * x) + 1.0 / (6 * x ** 3)


def _square_sizes_px(X_board: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(B,) each photo's median image distance (px) between corners that are neighbours on the board, both
    measured, of its corners ``uv`` (B, N, 2); inf where there are none."""
    d = np.linalg.norm(X_board[:, None, :] - X_board[None, :, :], axis=2)
    step = np.min(d[d > 0])
    i, j = np.nonzero(np.triu(np.abs(d - step) < 1e-6 * step))
    lengths = np.linalg.norm(uv[:, i] - uv[:, j], axis=2)
    seen = np.isfinite(lengths).any(axis=1)
    out = np.full(len(uv), np.inf)
    out[seen] = np.nanmedian(lengths[seen], axis=1)
    return out


def _smooth_basis(X_board: np.ndarray) -> np.ndarray:
    """(N, :data:`SMOOTH_TERMS`) the smooth functions of the board's corners that a photo's residuals are
    taken less: a cubic in their coordinates (centred, scaled to [-1, 1]); a photo of fewer corners takes the
    first of them (:func:`_terms`)."""
    xy = X_board[:, :2] - X_board[:, :2].mean(axis=0)
    x, y = (xy / max(float(np.max(np.abs(xy))), 1e-300)).T
    return np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3])


def _terms(n: np.ndarray) -> np.ndarray:
    """The smooth terms of photos of ``n`` corners: the cubic's :data:`SMOOTH_TERMS`, an affine field (3) for
    fewer than 2.5 times as many corners, the mean (1) for fewer than 6."""
    return np.where(n >= 2.5 * SMOOTH_TERMS, SMOOTH_TERMS, np.where(n >= 6, 3, 1))


def _less_smooth(r: np.ndarray, use: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``r`` (B, N, 2) less their smooth part fitted by least squares to the corners ``use`` (B, N) of
    each photo, and each photo's number of smooth terms (B,)."""
    k = _terms(use.sum(axis=1))
    fitted = np.zeros_like(r)
    r0 = np.where(use[..., None], r, 0.0)
    for terms in np.unique(k):
        photos = np.flatnonzero(k == terms)
        A = basis[:, :terms]
        weighted = A.T * use[photos].astype(float)[:, None, :]              # (B, terms, N)
        coef = np.linalg.solve(weighted @ A + 1e-12 * np.eye(terms), weighted @ r0[photos])
        fitted[photos] = A @ coef
    return r - fitted, k


def rough_residuals(sol: Solution, factor: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every photo's residuals less their smooth part (module docstring), ``(n_blocks, N, 2)`` px (NaN where not
    measured), each photo's degrees of freedom ``nu_b`` and its corners within ``factor`` x the median length of
    its rough residuals (all with ``factor`` None), ``(n_blocks, N)`` bool.

    The smooth part is a cubic in the corners' board positions per image coordinate, fitted by least
    squares twice: to every measured corner, then (with ``factor``) to those within ``factor`` x the median
    length of the first fit's rough residuals, so that a gross corner error does not move it (a photo of fewer
    corners gets fewer terms: an affine field, or its mean). ``nu_b`` is ``tr((I - P)(I - H))`` over the ``2 n``
    coordinates of the second fit's ``n`` corners, ``P`` the projection on the smooth terms and ``H`` the photo's
    block of the adjustment's hat matrix (its pose, its share of the intrinsics): what part of white noise its
    rough residuals keep. The pose's unknowns lie in the smooth terms' span only as far as the photo's
    perspective is affine (a narrow lens's more than a wide one's): counting them out twice, or not, would make
    cameras of one noise level look different.

    Kept with ``sol`` (:attr:`dualcal.estimation.adjust.Solution.derived`), read-only: a stage asks for the rough
    residuals of the cameras alone to weigh their photos, and the next stage for the same ones to judge the rig's."""
    key = ("rough_residuals", factor)
    if key not in sol.derived:
        sol.derived[key] = _rough_residuals(sol, factor)
        for a in sol.derived[key]:
            a.setflags(write=False)
    return sol.derived[key]


def _rough_residuals(sol: Solution, factor: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rough_residuals`, computed."""
    r = sol.residuals
    seen = np.isfinite(r[..., 0])
    basis = _smooth_basis(sol.problem.X_board)

    def within(rough):
        if factor is None:
            return seen
        length = np.linalg.norm(rough, axis=2)
        median = np.nanmedian(np.where(seen, length, np.nan), axis=1)
        with np.errstate(invalid="ignore"):
            return seen & (length <= factor * np.maximum(median, NOISE_FLOOR_PX)[:, None])

    rough, _ = _less_smooth(r, seen, basis)
    fit = within(rough)
    if (fit != seen).any():
        rough, _ = _less_smooth(r, fit, basis)
    return rough, _degrees_of_freedom(sol, fit, basis), within(rough)


def _degrees_of_freedom(sol: Solution, fit: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(n_blocks,) ``tr((I - P)(I - H))`` of every photo over its corners ``fit`` (:func:`rough_residuals`).

    With ``H = J C J^T`` (``J`` the photo's rows of those corners, ``C`` its columns' block of the inverse normal
    matrix) and ``P = A (A^T A)^-1 A^T`` the projection on its smooth terms ``A`` (the same for ``u`` and ``v``),
    the trace is ``2 m - 2 t - <C, J^T J - sum_c (A^T J_c)^T (A^T A)^-1 A^T J_c>`` (``m`` corners, ``t`` terms,
    ``c`` the ``u`` rows and the ``v`` rows): no ``2m x 2m`` matrix, and the photos of one shape in one batch."""
    n, terms = fit.sum(axis=1), _terms(fit.sum(axis=1))
    nu = np.empty(len(fit))
    for photos, columns, J_all in photo_jacobians(sol.problem, sol.state):
        k = columns.shape[1]
        for t in set(terms[photos].tolist()):
            of_t = terms[photos] == t
            blocks = photos[of_t]
            on = fit[blocks].astype(float)
            J = J_all[of_t] * on[..., None, None]                   # corner by corner, u then v
            A = basis[None, :, :t] * on[..., None]
            AtA = np.swapaxes(A, 1, 2) @ A + 1e-12 * np.eye(t)
            AtJ = np.swapaxes((np.swapaxes(A, 1, 2) @ J.reshape(len(blocks), -1, 2 * k)).reshape(-1, t, 2, k), 1, 2)
            smooth = (np.swapaxes(AtJ.reshape(len(blocks), 2 * t, k), 1, 2)
                      @ np.linalg.solve(AtA[:, None], AtJ).reshape(len(blocks), 2 * t, k))     # summed over u, v
            J = J.reshape(len(blocks), -1, k)
            C = sol.factorization.inverse_blocks(columns[of_t])
            nu[blocks] = 2 * n[blocks] - 2 * t - np.sum(C * (np.swapaxes(J, 1, 2) @ J - smooth), axis=(1, 2))
    return np.maximum(nu, 1.0)


def photo_noise(sol: Solution, factor: float | None) -> PhotoNoise:
    """Every photo's noise from ``sol``, a solution with every camera alone (module docstring): from its rough
    residuals (:func:`rough_residuals`) within ``factor`` x their median length (in noise: :data:`MEDIAN_LENGTH`
    sigma; None: all of them)."""
    p = sol.problem
    rough, nu, inliers = rough_residuals(sol, factor)
    squares = np.where(inliers, np.sum(np.nan_to_num(rough) ** 2, axis=2), 0.0).sum(axis=1)
    misfit = np.nanmedian(np.linalg.norm(sol.residuals, axis=2), axis=1) / _square_sizes_px(
        p.X_board, np.array([uv for _, _, uv in p.blocks], float))
    raw, dof, gross = {}, {}, {}
    for b, (c, view, _) in enumerate(p.blocks):
        key = (p.cameras[c], view)
        if misfit[b] > GROSS_SHARE:
            gross[key] = float(misfit[b])
            continue
        raw[key] = max(float(np.sqrt(squares[b] / nu[b])), NOISE_FLOOR_PX)
        dof[key] = float(nu[b])
    cameras = [n for n in p.cameras if any(k[0] == n for k in raw)]
    photos = {n: [k for k in raw if k[0] == n] for n in cameras}
    y, v = {}, {}
    for keys in photos.values():
        bias, var = _log_variance_moments(np.array([dof[k] for k in keys], float))
        y.update(zip(keys, np.log([raw[k] ** 2 for k in keys]) - bias))
        v.update(zip(keys, var))
    within = {n: _random_effects(np.array([y[k] for k in keys]), np.array([v[k] for k in keys]))
              for n, keys in photos.items()}
    mu_c, se2_c = np.array([within[n][0] for n in cameras]), np.array([within[n][2] for n in cameras])
    mu, tau2_cameras, _ = _random_effects(mu_c, se2_c)
    level_c = dict(zip(cameras, mu + tau2_cameras / (tau2_cameras + se2_c) * (mu_c - mu)))
    noise = {}
    for n, keys in photos.items():
        tau2 = within[n][1]
        floor = SHARPEST_SHARE * np.exp(level_c[n] / 2.0)
        noise.update({k: max(float(np.exp((level_c[n] + tau2 / (tau2 + v[k]) * (y[k] - level_c[n])) / 2.0)), floor)
                      for k in keys})
    camera_px = {n: float(np.exp(level / 2.0)) for n, level in level_c.items()}
    spread = {n: float(np.sqrt(within[n][1])) for n in cameras}
    reference = float(np.sqrt(sum(dof[k] for k in noise) / sum(dof[k] / s ** 2 for k, s in noise.items()))) \
        if noise else 1.0
    return PhotoNoise(noise, raw, dof, camera_px, spread, float(np.sqrt(tau2_cameras)), reference,
                      sorted(gross, key=gross.get, reverse=True), np.linalg.norm(rough, axis=2))


@lru_cache(maxsize=None)
def _alike_limit(dof: int) -> float:
    """Cochran's Q of ``dof + 1`` estimates of one level at :data:`ALIKE_LEVEL` (the chi-square quantile)."""
    return chi2_quantile(dof, ALIKE_LEVEL)


def _random_effects(y: np.ndarray, v: np.ndarray) -> tuple[float, float, float]:
    """The random-effects mean ``mu`` of estimates ``y`` (k,) of variances ``v`` (k,), the variance ``tau^2`` of
    their true values (the excess of Cochran's ``Q`` over its chi-square quantile at :data:`ALIKE_LEVEL`, by the
    method of moments; 0 for one estimate) and the variance of ``mu``."""
    u = 1.0 / v
    tau2 = 0.0
    if len(y) > 1:
        q = float(np.sum(u * (y - np.sum(u * y) / np.sum(u)) ** 2))
        tau2 = max(0.0, (q - _alike_limit(len(y) - 1)) / (np.sum(u) - np.sum(u * u) / np.sum(u)))
    u_random = 1.0 / (v + tau2)
    return float(np.sum(u_random * y) / np.sum(u_random)), tau2, float(1.0 / np.sum(u_random))
