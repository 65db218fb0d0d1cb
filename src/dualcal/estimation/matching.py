"""One tap, every photo: the point tapped in one photo found in another photo of the same instant, along
its epipolar line, to a fraction of a pixel, with its own sigma, or said to be unmatched.

A point tapped at pixel ``uv_a`` of camera ``a`` lies on the ray of that pixel; seen from camera ``b``
of the rig (``X_b = R X_a + t``, calib.json) the ray is the epipolar line, curved by ``b``'s lens.
The search runs on a **local rectification about the tapped ray** (:func:`match_frame`): one
orientation for both cameras, its x axis along the baseline (from ``a``'s perspective centre to
``b``'s), its z axis the tapped ray's direction made perpendicular to the baseline, so that the
plane through both centres and the ray is the plane ``y = 0``. Both photos are resampled as ideal
pinhole images of one focal length ``f`` (the coarser camera's: a tele is reduced to a wide's scale,
Gaussian-smoothed first against aliasing by ``0.5 sqrt(s^2 + 1)`` of its pixels, ``s`` its scale over the
grid's); a surface point at depth ``Z`` along the rectified axis appears at ``(x, y)`` in ``a`` and
``(x - d, y)`` in ``b``, the disparity ``d = f B / Z`` (``B`` the baseline). A patch of ``a`` about the tap
is then the patch of ``b`` at ``x - d`` wherever the surface is near fronto-parallel to the rectified axis:
a search in one dimension, ``d`` from 0 (infinity) to ``f B / min_distance_mm``.

**Search** (:func:`match_point`). Zero-mean normalised cross-correlation (ZNCC) of a Gaussian-weighted
window (:data:`HALF_WINDOW`) at every whole disparity, the best over a few disparity slopes (:data:`SLOPES`:
the window stretched and sheared as a slanted plane would be). A match must be unique along the line:
the best peak's score ``q1`` and the best other peak's ``q2`` (a local maximum separated from the best by
a dip of :data:`DIP` in score) must satisfy ``1 - q1 <= AMBIGUITY (1 - q2)`` and ``q1 - q2 >= MIN_GAP``
(a repeated pattern has a second peak nearly as good). Where the window alone is ambiguous (a chessboard
corner repeats two squares away), the search moves up a scale: the window covers twice the scene (the
grid's focal length halved, the same window in samples), up to a third of the photo's shorter side (a
larger window holds more of the scene at other depths than of the point's surroundings), until the
peak is unique; it is then followed down to the finest scale within :data:`FOLLOW_SAMPLES` samples
(coarse-to-fine: the context decides which peak, the fine scale where). No unique peak at any scale:
``repeated pattern``; a best score below :data:`MIN_SCORE`: ``no match`` (occluded, or the point looks
different in the other photo).

**Sub-pixel.** At the finest scale the disparity is refined by Gauss-Newton (Lucas-Kanade along the
line) on the window's weighted squared difference ``sum w (g T + o + beta lap(T) - S(x + s . p))^2``: the
tapped patch ``T`` with a gain ``g``, an offset ``o`` and what differs of the two photos' blur (to first
order a Gaussian blur of variance ``v`` adds ``v / 2`` times the Laplacian; the blur found lacking is
then added to the sharper photo and the fit repeated), against ``b``'s patch ``S`` resampled at the shifted
positions, ``s`` the disparity's slopes along and across the line at window position ``p`` (a plane is
exactly an affine disparity in a rectified pair). The slopes come from two fits: the window's own
(free: right where the window has texture throughout, poor where it holds only a corner's two edges)
and a window four times as large (right on a plane of sparse texture, wrong where it crosses an
object's edge); the shift is the mean of the two shifts, and half their difference enters its sigma.

**Sigma.** The shift is linear in the residuals, ``dx = c . r`` (``c`` the Gauss-Newton row of the shift);
each residual is ``g`` times ``a``'s noise minus ``b``'s, each *resampled*: a sample is a Gaussian-smoothed,
bilinearly interpolated combination ``L`` of source pixels (separable, so ``L L^T`` is the elementwise
product of two small Gram matrices). With white noise of variance ``sigma^2`` per source pixel, the
residuals' covariance is ``sigma^2 C``, ``C = g^2 L_a L_a^T + L_b L_b^T``, and::

    var(dx) = sigma^2 c C c^T,    sigma^2 = sum w r^2 / tr(W P C P^T)

``P`` the fit's residual-maker (``sigma^2`` is estimated from the residuals themselves against what they
are expected to be, so whatever the two patches do not share, JPEG, a surface not quite planar, counts
as noise, and the smoothing's correlation of neighbouring samples is kept). It is taken no smaller than
the clustered estimate (the window in 3 x 3 blocks, each block's residuals one draw), and a slope taken
from the larger window adds its own uncertainty through the shift's sensitivity to it. The search runs on the
calibration's epipolar line, itself uncertain across: were it off by ``dy``, ``b``'s samples would differ by
``g_y dy`` and the shift by ``c . g_y dy`` (:attr:`Match.epipolar_coupling`: large where the texture slants
across the line, zero for texture square to it); ``epipolar_sigma_px`` (the measurement takes it from the
calibration's covariance) enters the sigma that way (:meth:`Match.widened`). Checked on renders: the matched
pixel's error over its sigma has a spread of 1.0-1.1 against the true geometry, 0.86 against a calibrated one
(tests/test_match.py, benchmarks/bench_match.py). A tap whose window has no texture along the line (its
predicted sigma above :data:`MAX_SIGMA_PX` before matching, or its match's after: a blank wall, an edge along
the line) is ``texture-less``.

The matched pixel is the tapped pixel's surface point as ``b`` sees it, so a tap's error moves the
match with it: :attr:`Match.tap_jacobian` is ``d uv_b / d uv_a`` over the surface the match found (its
disparity and slopes), which the measurement uses to keep the tap's error out of the disparity
(:mod:`dualcal.estimation.measurement`).

Everything here is a pure function of arrays: photos as (H, W) grey arrays in their stored frame
(pixel ``(i, j)`` at ``(u=j, v=i)``), cameras as :class:`~dualcal.geometry.camera.CameraModel`, the
relative pose as :class:`~dualcal.geometry.model.Pose` (``X_b = R X_a + t``, mm).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..geometry.camera import CameraModel, in_frame, pixel_rays, project_points
from ..geometry.model import Pose

__all__ = ["HALF_WINDOW", "MIN_DISTANCE_MM", "Match", "MatchFrame", "epipolar_curve", "match_frame",
           "match_point"]

#: Half-width of the matching window, grid samples (the window is 2 h + 1 square, Gaussian-weighted).
HALF_WINDOW = 8
#: Nearest surface searched by default, mm from the tapped camera (a phone focuses down to about 0.1 m).
MIN_DISTANCE_MM = 100.0
#: Smallest ZNCC of a match at the finest scale.
MIN_SCORE = 0.6
#: A second peak makes the match ambiguous when ``1 - best > AMBIGUITY (1 - second)``.
AMBIGUITY = 0.5
#: ... or when the second peak's score is within this of the best's (near-perfect scores of a repeated pattern).
MIN_GAP = 0.1
#: A local maximum counts as another peak when the score dips by this much between it and the best.
DIP = 0.1
#: Disparity slopes tried in the search, as window samples the window's edge moves (the same along and across).
SLOPES = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
#: Coarsest scale tried: the window then spans ``(2 h + 1) 2^MAX_LEVEL`` samples of the finest grid.
MAX_LEVEL = 5
#: Largest sigma of a match along the line, px of the finest grid (beyond: texture-less).
MAX_SIGMA_PX = 0.5
#: Disparities searched beyond infinity (negative), px of the finest grid: the calibration's error.
NEGATIVE_MARGIN_PX = 4.0
#: Share of a window that must fall inside the other photo.
MIN_INSIDE = 0.8
#: Samples each side followed from a coarse scale to the next finer one.
FOLLOW_SAMPLES = 3
_GN_ITERATIONS = 12
_BLUR_PASSES = 4
_CLUSTERS = 3
_SLOPE_LEVEL = 2


@dataclass(frozen=True)
class MatchFrame:
    """The local rectification of cameras ``a`` (tapped) and ``b`` about one tapped ray (module docstring).

    ``rotation_a``, ``rotation_b`` (3, 3): rectified direction = ``rotation @`` camera-frame direction;
    ``baseline_mm``: distance between the two perspective centres (``b``'s at ``(B, 0, 0)`` in the
    rectified frame of ``a``'s centre); ``f_px``: the finest grid's focal length; ``x_tap``: the tap's
    rectified ``x`` (its ``y`` is 0), px of that grid.
    """

    rotation_a: np.ndarray
    rotation_b: np.ndarray
    baseline_mm: float
    f_px: float
    x_tap: float

    def disparity_px(self, depth_mm: np.ndarray) -> np.ndarray:
        """``f B / Z``: the disparity of a point at rectified depth ``depth_mm``."""
        return self.f_px * self.baseline_mm / np.asarray(depth_mm, float)


@dataclass(frozen=True)
class Match:
    """Where a tapped point is in the other photo, or why it is not found.

    ``ok``: found; ``reason``: why not (``"off the image"``, ``"texture-less"``, ``"repeated pattern"``,
    ``"no match"``), None when found. For a match: ``uv`` (2,) its pixel in ``b`` (stored frame,
    distorted); ``sigma_px`` its 1-sigma along the epipolar line, px of ``b``; ``direction`` (2,) the
    line's unit direction at ``uv`` in ``b``'s pixels (the match is exact across it: ``covariance`` (2, 2) is
    ``sigma_px^2 direction direction^T``); ``score`` the ZNCC at the match, ``second_score`` the best
    other peak's (None: none); ``level`` the scale that made it unique (0: the finest); ``depth_mm`` the
    rectified depth; ``tap_jacobian`` (2, 2) ``d uv / d uv_a`` over the surface found (its depth and slant);
    ``photometric_sigma_px`` the sigma of the match on the line as given, ``epipolar_coupling`` how far it moves along
    the line per px the line is off across (``sigma_px`` holds both, :meth:`widened`).
    """

    ok: bool
    reason: str | None = None
    uv: np.ndarray | None = None
    sigma_px: float | None = None
    direction: np.ndarray | None = None
    score: float | None = None
    second_score: float | None = None
    level: int | None = None
    depth_mm: float | None = None
    tap_jacobian: np.ndarray | None = None
    photometric_sigma_px: float | None = None
    epipolar_coupling: float | None = None

    def widened(self, epipolar_sigma_px: float) -> "Match":
        """The match with ``sigma_px`` from its photometric sigma and an epipolar line off across by
        ``epipolar_sigma_px`` (1-sigma, px of ``b``): ``sqrt(s_photo^2 + (coupling e)^2)``."""
        if not self.ok:
            return self
        return replace(self, sigma_px=float(np.hypot(self.photometric_sigma_px,
                                                     self.epipolar_coupling * epipolar_sigma_px)))

    @property
    def covariance(self) -> np.ndarray:
        """(2, 2) the match's covariance in ``b``'s pixels: along the line only."""
        return self.sigma_px ** 2 * np.outer(self.direction, self.direction)


def match_frame(cam_a: CameraModel, cam_b: CameraModel, pose_ab: Pose, uv_a) -> MatchFrame:
    """The local rectification about the ray of pixel ``uv_a`` (module docstring).

    Parameters
    ----------
    cam_a, cam_b : CameraModel
        The tapped camera and the other one.
    pose_ab : Pose
        ``X_b = R X_a + t_mm``.
    uv_a : (2,) array_like
        The tapped pixel in ``a``.

    Returns
    -------
    MatchFrame

    Raises
    ------
    ValueError
        The cameras share their centre, or the ray runs along the baseline.
    """
    centre_b = pose_ab.center_mm                                   # b's centre in a's frame
    baseline = float(np.linalg.norm(centre_b))
    if baseline <= 0:
        raise ValueError("the two cameras share their perspective centre: nothing to match along")
    x_axis = centre_b / baseline
    ray = pixel_rays(cam_a, np.asarray(uv_a, float))[0]
    ray = ray / np.linalg.norm(ray)
    z_axis = ray - (ray @ x_axis) * x_axis
    if np.linalg.norm(z_axis) < 1e-6:
        raise ValueError("the tapped ray runs along the baseline: no epipolar line")
    z_axis /= np.linalg.norm(z_axis)
    M = np.vstack([x_axis, np.cross(z_axis, x_axis), z_axis])
    f = float(min(cam_a.fx, cam_a.fy, cam_b.fx, cam_b.fy))
    rect = M @ ray
    return MatchFrame(M, M @ pose_ab.R.T, baseline, f, float(f * rect[0] / rect[2]))


def _pixels(cam: CameraModel, rotation: np.ndarray, f_px: float, x: np.ndarray, y: np.ndarray):
    """Rectified grid points ``(x, y)`` (px of focal ``f_px``) -> the camera's pixels, and whether it sees them."""
    rays = np.stack([x / f_px, y / f_px, np.ones(np.broadcast(x, y).shape)], axis=-1).reshape(-1, 3) @ rotation
    seen = in_frame(cam, rays)
    uv = project_points(cam, np.where(seen[:, None], rays, [0.0, 0.0, 1.0]))
    shape = np.broadcast(x, y).shape
    return uv.reshape(*shape, 2), seen.reshape(shape)


def _smoothing_px(cam: CameraModel, f_grid: float) -> float:
    """Gaussian sigma (source px) before resampling a photo of ``cam`` at focal ``f_grid``: ``0.5 sqrt(s^2 + 1)``,
    ``s`` the source's pixels per grid sample (module docstring; also above 1:1, against interpolation bias)."""
    s = min(cam.fx, cam.fy) / f_grid
    return 0.5 * float(np.sqrt(s * s + 1.0))


@dataclass(frozen=True)
class _Samples:
    """A photo resampled on rectified grid points: ``values`` (shape of the points), ``inside``, and what the
    sigma needs: the source pixels ``uv`` and the smoothing ``sigma_px``, the crop's origin ``origin``."""

    values: np.ndarray
    inside: np.ndarray
    uv: np.ndarray
    sigma_px: float
    crop: np.ndarray
    origin: tuple[int, int]


def _resample(image: np.ndarray, cam: CameraModel, rotation: np.ndarray, f0: float, level: int,
              x: np.ndarray, y: np.ndarray, extra_var: float = 0.0) -> _Samples:
    """``image`` of ``cam`` at rectified points ``(x, y)`` (px of the finest grid ``f0``), smoothed for scale
    ``level`` (:func:`_smoothing_px`) and by a Gaussian of variance ``extra_var`` more (finest-grid px^2),
    bilinear; only the crop around them is smoothed."""
    uv, seen = _pixels(cam, rotation, f0, x, y)
    s = min(cam.fx, cam.fy) / f0
    sigma = float(np.sqrt(_smoothing_px(cam, f0 / 2 ** level) ** 2 + extra_var * s * s))
    h, w = image.shape
    pad = int(np.ceil(4 * sigma)) + 2
    used = uv[seen]
    if len(used) == 0:
        return _Samples(np.zeros(x.shape), np.zeros(x.shape, bool), uv, sigma, np.zeros((1, 1)), (0, 0))
    u0, v0 = (np.floor(used.min(axis=0)).astype(int) - pad).clip(0)
    u1, v1 = np.minimum(np.ceil(used.max(axis=0)).astype(int) + pad + 1, [w, h])
    crop = cv2.GaussianBlur(np.ascontiguousarray(image[v0:v1, u0:u1], np.float32), (0, 0), sigma,
                            borderType=cv2.BORDER_REFLECT)
    map_u = (uv[..., 0] - u0).astype(np.float32)
    map_v = (uv[..., 1] - v0).astype(np.float32)
    values = cv2.remap(crop, map_u.reshape(-1, map_u.shape[-1]), map_v.reshape(-1, map_v.shape[-1]), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).astype(float).reshape(x.shape)
    return _Samples(values, seen, uv, sigma, crop, (int(u0), int(v0)))


def _window_weights(half: int) -> np.ndarray:
    """(2h+1, 2h+1) Gaussian weights of sigma h / 2."""
    k = np.arange(-half, half + 1)
    g = np.exp(-0.5 * (k / (0.5 * half)) ** 2)
    return np.outer(g, g)


def zncc_along(template: np.ndarray, template_inside: np.ndarray, strip: np.ndarray, strip_inside: np.ndarray,
               weights: np.ndarray) -> np.ndarray:
    """Weighted zero-mean normalised cross-correlation of ``template`` (m, w) at every shift along ``strip`` (m, W).

    Parameters
    ----------
    template, strip : ndarray
        The two patches, the strip at least as wide as the template.
    template_inside, strip_inside : ndarray of bool
        Which samples lie inside their photo (the others are left out of the sums).
    weights : (m, w) ndarray
        The window's weights.

    Returns
    -------
    (W - w + 1,) ndarray
        The score at each shift (the template's column 0 on the strip's column k), NaN where less than
        :data:`MIN_INSIDE` of the window's weight is inside both photos or a patch is flat.
    """
    windows = np.lib.stride_tricks.sliding_window_view(strip, template.shape)[0]          # (n, m, w)
    inside = np.lib.stride_tricks.sliding_window_view(strip_inside, template.shape)[0]
    m = weights * template_inside * inside
    total = m.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        mt = np.einsum("nij,ij->n", m, template) / total
        ms = np.einsum("nij,nij->n", m, windows) / total
        t = template[None] - mt[:, None, None]
        s = windows - ms[:, None, None]
        cov = np.einsum("nij,nij,nij->n", m, t, s)
        score = cov / np.sqrt(np.einsum("nij,nij,nij->n", m, t, t) * np.einsum("nij,nij,nij->n", m, s, s))
    score[total < MIN_INSIDE * weights.sum()] = np.nan
    return score


def _peaks(score: np.ndarray) -> tuple[int, float | None]:
    """The best shift, and the best other peak's score (a local maximum separated from the best by a dip of
    :data:`DIP`); None when there is none."""
    best = int(np.nanargmax(score))
    s = np.where(np.isfinite(score), score, -1.0)
    local = np.flatnonzero((s[1:-1] >= s[:-2]) & (s[1:-1] >= s[2:])) + 1
    second = None
    for k in local:
        if k == best:
            continue
        between = s[min(k, best): max(k, best) + 1]
        if s[k] - between.min() >= DIP and (second is None or s[k] > second):
            second = float(s[k])
    return best, second


def _parabola(score: np.ndarray, k: int) -> float:
    """Sub-sample offset of the peak at ``k`` from the parabola through its two neighbours (0 at an end)."""
    if k <= 0 or k >= len(score) - 1 or not np.all(np.isfinite(score[k - 1:k + 2])):
        return 0.0
    a, b, c = score[k - 1:k + 2]
    den = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) if den < 0 else 0.0


@dataclass(frozen=True)
class _Search:
    best_x: float            # rectified x in b of the best peak (finest-grid px)
    score: float
    second: float | None
    unique: bool


def _search(frame: MatchFrame, a: tuple, b: tuple, level: int, x_lo: float, x_hi: float,
            half: int) -> _Search | None:
    """ZNCC at scale ``level`` for every ``x`` of ``b`` in ``[x_lo, x_hi]`` (finest-grid px), the best over the
    disparity slopes of :data:`SLOPES` (the tapped window stretched and sheared as a slanted plane would be,
    so that a large window on a slanted surface still finds its own place); None when no window lies inside
    both photos."""
    step = 2.0 ** level
    k = np.arange(-half, half + 1) * step
    n = int(np.floor((x_hi - x_lo) / step)) + 1
    if n < 1:
        return None
    across, along = np.meshgrid(k, k, indexing="ij")
    slopes = SLOPES / half
    s1, s2 = (g.ravel()[:, None, None] for g in np.meshgrid(slopes, slopes, indexing="ij"))
    tx = frame.x_tap + (along[None] - s2 * across[None]) / (1.0 + s1)
    T = _resample(*a, frame.rotation_a, frame.f_px, level, tx, np.broadcast_to(across, tx.shape))
    xs = x_lo + (np.arange(n + 2 * half) - half) * step
    sy, sx = np.meshgrid(k, xs, indexing="ij")
    S = _resample(*b, frame.rotation_b, frame.f_px, level, sx, sy)
    weights = _window_weights(half)
    scores = np.array([zncc_along(T.values[i], T.inside[i], S.values, S.inside, weights) for i in range(len(tx))])
    if not np.any(np.isfinite(scores)):
        return None
    with np.errstate(invalid="ignore"):
        score = np.nanmax(np.where(np.isfinite(scores), scores, -np.inf), axis=0)
    score[~np.isfinite(score)] = np.nan
    best, second = _peaks(score)
    q = float(score[best])
    unique = second is None or ((1.0 - q) <= AMBIGUITY * (1.0 - second) and q - second >= MIN_GAP)
    return _Search(x_lo + (best + _parabola(score, best)) * step, q, second, unique)


def _noise_gram(s: _Samples) -> np.ndarray:
    """``L L^T`` (n, n): the covariance of a photo's n samples ``s`` for white noise of unit variance per source
    pixel, ``L`` the smoothing then the bilinear interpolation that made them (module docstring).

    Both are separable, so a sample's row of ``L`` is the outer product of one row and one column factor
    (the smoothing kernel's rows at its two neighbouring pixels, mixed by its bilinear weights) and ``L L^T``
    is the elementwise product of the two factors' Gram matrices.
    """
    h, w = s.crop.shape
    r = int(np.ceil(4 * s.sigma_px))
    kernel = cv2.getGaussianKernel(2 * r + 1, s.sigma_px).ravel()

    def factor(coord: np.ndarray, size: int) -> np.ndarray:
        blur = np.zeros((size, size))
        for d, value in zip(range(-r, r + 1), kernel):       # row i: the kernel centred on pixel i
            i = np.arange(max(0, -d), min(size, size - d))
            blur[i, i + d] = value
        lo = np.floor(coord).astype(int)
        f = (coord - lo)[:, None]
        return (1 - f) * blur[np.clip(lo, 0, size - 1)] + f * blur[np.clip(lo + 1, 0, size - 1)]

    rows = factor(s.uv[..., 1].ravel() - s.origin[1], h)
    cols = factor(s.uv[..., 0].ravel() - s.origin[0], w)
    return (rows @ rows.T) * (cols @ cols.T)


@dataclass(frozen=True)
class _Fit:
    """A shift fitted at one scale: ``x`` (finest-grid px), the blur variance ``a`` still lacks (negative: ``b``),
    the disparity's ``slopes`` (2,) along and across the line; ``sigma_x`` and the slopes' covariance (2, 2),
    ``slopes_cov``, and the shift's ``coupling`` to an epipolar line off across, computed when asked
    (``uncertainty()`` gives them): for the last of the blur passes only."""

    x: float
    blur_variance: float
    slopes: np.ndarray
    uncertainty: Callable[[], tuple[float, np.ndarray, float]]

    @functools.cached_property
    def _sigmas(self) -> tuple[float, np.ndarray]:
        return self.uncertainty()

    @property
    def sigma_x(self) -> float:
        return self._sigmas[0]

    @property
    def slopes_cov(self) -> np.ndarray:
        return self._sigmas[1]

    @property
    def coupling(self) -> float:
        """How far the shift moves along the line when the line is off by one (finest-grid) px across it."""
        return self._sigmas[2]


def _refine(frame: MatchFrame, a: tuple, b: tuple, x0: float, half: int):
    """The shift at the finest scale from ``x0`` and its sigma, finest-grid px, the disparity's slopes and the shift's
    coupling to the line's error across (module docstring); None when it does not settle.

    Two estimates of the disparity's slopes (the plane of the surface): the window's own (free in its fit: right
    where the window has texture everywhere, wrong where it holds a corner's two edges and no more) and a
    window four times as large (right on a plane with sparse texture, wrong where it crosses an object's edge).
    The shift is their mean; its sigma is their mean variance and half their difference, in quadrature: two
    estimates that disagree say so in the sigma.
    """
    local = _equalised(frame, a, b, x0, half, 0)
    coarse = _equalised(frame, a, b, x0, half, _SLOPE_LEVEL)
    wide = None if coarse is None else _equalised(frame, a, b, coarse.x, half, 0, coarse.slopes, coarse.slopes_cov)
    if local is None or wide is None:
        fine = local or wide
        return None if fine is None else (fine.x, fine.sigma_x, fine.slopes, fine.coupling)
    d = local.x - wide.x
    return (0.5 * (local.x + wide.x), float(np.sqrt(0.5 * (local.sigma_x ** 2 + wide.sigma_x ** 2) + 0.25 * d * d)),
            0.5 * (local.slopes + wide.slopes), 0.5 * (local.coupling + wide.coupling))


def _equalised(frame: MatchFrame, a: tuple, b: tuple, x0: float, half: int, level: int, slopes=None,
               slopes_cov=None) -> _Fit | None:
    """:func:`_fit_shift` with the photos' blur made equal first: the blur one lacks added to it and fitted again
    until what is left is negligible."""
    extra = 0.0                       # variance of the blur added to a (> 0) or to b (< 0), finest-grid px^2
    for _ in range(_BLUR_PASSES):
        fit = _fit_shift(frame, a, b, x0, half, level, max(extra, 0.0), max(-extra, 0.0), slopes, slopes_cov)
        if fit is None:
            return None
        extra += fit.blur_variance
        if abs(fit.blur_variance) < 0.05 * 4 ** level:
            break
    return fit


def _fit_shift(frame: MatchFrame, a: tuple, b: tuple, x0: float, half: int, level: int, extra_a: float,
               extra_b: float, slopes=None, slopes_cov=None) -> _Fit | None:
    """Gauss-Newton at scale ``level`` from ``x0`` (module docstring): the disparity at the tap, its slopes along
    and across the line (a plane not fronto-parallel stretches and shears the window along the line; or given,
    ``slopes`` with covariance ``slopes_cov``), gain, offset, and what is left of the photos' difference of blur
    (to first order a Gaussian blur of variance ``v`` adds ``v / 2`` times the Laplacian), with ``extra_a``,
    ``extra_b`` of blur variance (finest-grid px^2) added to each photo first.

    None when the shift does not settle within a sample and a half of ``x0``, or the window leaves ``b``.
    """
    step = 2.0 ** level
    k = np.arange(-half - 1, half + 2) * step
    ty, tx = np.meshgrid(k, frame.x_tap + k, indexing="ij")
    T_big = _resample(*a, frame.rotation_a, frame.f_px, level, tx, ty, extra_a)
    inner = (slice(1, -1), slice(1, -1))
    Tv = T_big.values
    lap = Tv[:-2, 1:-1] + Tv[2:, 1:-1] + Tv[1:-1, :-2] + Tv[1:-1, 2:] - 4 * Tv[inner]     # per sample^2
    T = _Samples(Tv[inner], T_big.inside[inner], T_big.uv[inner], T_big.sigma_px, T_big.crop, T_big.origin)
    k = k[1:-1]
    n = len(k)
    w = _window_weights(half) * T.inside
    W = w.ravel()
    along, across = np.meshgrid(k, k)                 # finest-grid px (rows: across the line; columns: along it)
    free = slopes is None
    slope = np.zeros(2) if free else np.asarray(slopes, float)
    x, photometric = x0, np.array([1.0, 0.0, 0.0])    # gain, offset, blur
    for _ in range(_GN_ITERATIONS):
        shift = x + slope[0] * along + slope[1] * across         # (n, n) rectified x of b's samples
        sx = np.concatenate([along + shift - 0.5 * step, along + shift, along + shift + 0.5 * step], axis=1)
        S_all = _resample(*b, frame.rotation_b, frame.f_px, level, sx, np.tile(across, 3), extra_b)
        S_minus, S, S_plus = (S_all.values[:, i * n:(i + 1) * n] for i in range(3))
        if not np.all(S_all.inside[:, n:2 * n][w > 0]):
            return None
        g = (S_plus - S_minus) / step                            # dS/dx, per finest-grid px
        columns = [-g] + ([-g * along, -g * across] if free else []) + [T.values, np.ones_like(g), lap]
        J = np.stack(columns, axis=-1).reshape(-1, len(columns))
        r = (photometric[0] * T.values + photometric[1] + photometric[2] * lap - S).ravel()
        N = J.T @ (J * W[:, None])
        delta = -np.linalg.solve(N, J.T @ (W * r))
        x += delta[0]
        if free:
            slope = slope + delta[1:3]
        photometric = photometric + delta[-3:]
        if abs(x - x0) > 1.5 * min(step, 2.0) or np.max(np.abs(slope)) > 0.5:
            return None
        if abs(delta[0]) < 1e-4:
            break
    S_at = _Samples(S, S_all.inside[:, n:2 * n], S_all.uv[:, n:2 * n], S_all.sigma_px, S_all.crop, S_all.origin)
    r = (photometric[0] * T.values + photometric[1] + photometric[2] * lap - S).ravel()

    def uncertainty() -> tuple[float, np.ndarray, float]:
        # the sigma (module docstring): C, the residuals' covariance for unit noise per source pixel; the noise's
        # variance from the residuals against their expectation tr(W P C P^T), P = I - J G with G = N^-1 J^T W (the
        # diagonal of P C P^T without forming it: diag C - 2 diag(J G C) + diag(J G C G^T J^T)); the shift's from
        # G's first row, and given slopes' uncertainty through the shift's sensitivity to them
        C = photometric[0] ** 2 * _noise_gram(T) + _noise_gram(S_at)
        G = np.linalg.solve(N, (J * W[:, None]).T)
        GC = G @ C
        diagonal = np.diag(C) - 2 * np.einsum("kj,jk->k", J, GC) + np.einsum("kj,jl,kl->k", J, GC @ G.T, J)
        noise_var = float(np.sum(W * r * r)) / float(np.sum(W * diagonal))
        var_x = noise_var * float(GC[0] @ G[0])
        # clustered: each block of the window's residuals taken as one draw, whatever their correlation inside
        contribution = (G[0] * r).reshape(n, n)
        edges = np.linspace(0, n, _CLUSTERS + 1).astype(int)[:-1]
        blocks = np.add.reduceat(np.add.reduceat(contribution, edges, axis=0), edges, axis=1)
        var_x = max(var_x, float(np.sum(blocks ** 2)) * blocks.size / (blocks.size - 1))
        # the line itself off by dy across: b's samples then differ by g_y dy, which moves the shift by G_0 . g_y
        shift_px = x + slope[0] * along + slope[1] * across + along
        rows = _resample(*b, frame.rotation_b, frame.f_px, level, np.concatenate([shift_px, shift_px], axis=1),
                         np.concatenate([across - 0.5 * step, across + 0.5 * step], axis=1), extra_b).values
        coupling = float(G[0] @ ((rows[:, n:] - rows[:, :n]) / step).ravel())
        if free:
            return float(np.sqrt(var_x)), noise_var * (GC[1:3] @ G[1:3].T), coupling
        sensitivity = np.array([G[0] @ (g * along).ravel(), G[0] @ (g * across).ravel()])
        return (float(np.sqrt(var_x + sensitivity @ slopes_cov @ sensitivity)), np.asarray(slopes_cov, float),
                coupling)

    return _Fit(float(x), float(2.0 * photometric[2] / photometric[0]) * step ** 2, slope, uncertainty)


def _predicted_sigma(frame: MatchFrame, a: tuple, half: int) -> float:
    """The sigma a match of the tapped window could reach along the line, px of the finest grid (inf: its
    gradients along the line are mostly noise): the tapped photo's noise ``sigma`` per pixel (Immerkaer's
    Laplacian difference, its median over the window's pixels) in both photos, a smoothed sample's variance
    ``v = sigma^2 / (4 pi s^2)`` (``s`` the smoothing, source px), and the window's gradient energy along the
    line less what noise alone gives it (``2 v (1 - rho)``, ``rho`` the smoothed noise's correlation one
    sample apart): large where the window has no texture along the line (a blank wall, an edge along it)."""
    k = np.arange(-half, half + 1, dtype=float)
    ty, tx = np.meshgrid(k, frame.x_tap + np.concatenate([k - 0.5, k + 0.5]), indexing="ij")
    T = _resample(*a, frame.rotation_a, frame.f_px, 0, tx, ty)
    n = len(k)
    g = T.values[:, n:] - T.values[:, :n]
    w = _window_weights(half)
    h, wd = T.crop.shape
    lap = cv2.filter2D(a[0][T.origin[1]:T.origin[1] + h, T.origin[0]:T.origin[0] + wd].astype(np.float32), -1,
                       np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32))
    noise = float(np.median(np.abs(lap[1:-1, 1:-1]))) * 1.4826 / 6.0 if lap.size > 9 else 1.0
    noise = max(noise, 0.5)                                  # 8-bit quantisation: never below half a level
    smoothing = max(T.sigma_px, 0.5)
    step_src = min(a[1].fx, a[1].fy) / frame.f_px            # source px per grid sample
    v = noise ** 2 / (4 * np.pi * smoothing ** 2)
    noise_energy = 2 * v * (1 - np.exp(-step_src ** 2 / (4 * smoothing ** 2))) * w.sum()
    energy = float(np.sum(w * g ** 2))
    if energy <= 2 * noise_energy:
        return float("inf")
    return float(np.sqrt(2 * v * np.sum(w ** 2 * g ** 2)) / (energy - noise_energy))


def epipolar_curve(cam_a: CameraModel, cam_b: CameraModel, pose_ab: Pose, uv_a, distances_mm) -> np.ndarray:
    """Where the ray of ``uv_a`` appears in ``b``, at the given distances along it from ``a``'s centre.

    Parameters
    ----------
    cam_a, cam_b : CameraModel
    pose_ab : Pose
        ``X_b = R X_a + t_mm``.
    uv_a : (2,) array_like
        The tapped pixel.
    distances_mm : (N,) array_like
        Distances along the ray, mm.

    Returns
    -------
    (N, 2) ndarray
        ``b``'s pixels (distorted), NaN rows where ``b`` does not see the point.
    """
    ray = pixel_rays(cam_a, np.asarray(uv_a, float))[0]
    X = np.asarray(distances_mm, float)[:, None] * (ray / np.linalg.norm(ray))
    X_b = pose_ab.apply(X)
    seen = in_frame(cam_b, X_b)
    uv = project_points(cam_b, np.where(seen[:, None], X_b, [0.0, 0.0, 1.0]))
    uv[~seen] = np.nan
    return uv


def _tap_jacobian(frame: MatchFrame, cam_a: CameraModel, cam_b: CameraModel, uv_a: np.ndarray, x_b: float,
                  slopes: np.ndarray, step_px: float = 0.25) -> np.ndarray:
    """``d uv_b / d uv_a``: where the match moves when the tap does, over the surface the match found (its
    rectified disparity at the tap and its ``slopes`` along and across the line)."""
    def to_b(uv):
        ray = pixel_rays(cam_a, uv)[0] @ frame.rotation_a.T
        dx, y = frame.f_px * ray[0] / ray[2] - frame.x_tap, frame.f_px * ray[1] / ray[2]
        x = x_b + (1.0 + slopes[0]) * dx + slopes[1] * y
        return _pixels(cam_b, frame.rotation_b, frame.f_px, np.array([x]), np.array([y]))[0][0]

    J = np.empty((2, 2))
    for i in range(2):
        e = np.zeros(2)
        e[i] = step_px
        J[:, i] = (to_b(uv_a + e) - to_b(uv_a - e)) / (2 * step_px)
    return J


def match_point(image_a: np.ndarray, cam_a: CameraModel, image_b: np.ndarray, cam_b: CameraModel, pose_ab: Pose,
                uv_a, min_distance_mm: float = MIN_DISTANCE_MM, half: int = HALF_WINDOW,
                epipolar_sigma_px: float = 0.0) -> Match:
    """Find the point tapped at ``uv_a`` in photo ``a`` in photo ``b`` of the same instant (module docstring).

    Parameters
    ----------
    image_a, image_b : (H, W) ndarray
        The two photos, grey, in their stored frames.
    cam_a, cam_b : CameraModel
        Their cameras (calibrated at those sizes).
    pose_ab : Pose
        ``X_b = R X_a + t_mm``.
    uv_a : (2,) array_like
        The tapped pixel in ``a``.
    min_distance_mm : float
        The nearest surface searched, mm from ``a``'s centre along the rectified axis.
    half : int
        Half-width of the window, samples.
    epipolar_sigma_px : float
        How far off across itself the calibration's epipolar line may be at the match, 1-sigma, px of ``b``: the
        match moves along the line by its ``epipolar_coupling`` times that, which its ``sigma_px`` includes
        (:meth:`Match.widened` adds it later).

    Returns
    -------
    Match
        The matched pixel, its sigma along the epipolar line and its score, or the reason it is unmatched.
    """
    uv_a = np.asarray(uv_a, float)
    w, h = cam_a.image_size
    if not (0 <= uv_a[0] <= w - 1 and 0 <= uv_a[1] <= h - 1):
        return Match(False, "off the image")
    frame = match_frame(cam_a, cam_b, pose_ab, uv_a)
    a, b = (image_a, cam_a), (image_b, cam_b)
    x_lo = frame.x_tap - float(frame.disparity_px(min_distance_mm))
    x_hi = frame.x_tap + NEGATIVE_MARGIN_PX
    found = _search(frame, a, b, 0, x_lo, x_hi, half)
    if found is None:
        return Match(False, "off the image")
    if _predicted_sigma(frame, a, half) > MAX_SIGMA_PX:
        return Match(False, "texture-less")
    level = 0
    # the window at the coarsest scale spans at most a third of the smaller photo's shorter side (beyond, it holds
    # more of the scene at other depths than of the point's surroundings)
    shortest = min(min(cam.image_size) * frame.f_px / min(cam.fx, cam.fy) for cam in (cam_a, cam_b))
    top = min(MAX_LEVEL, int(np.floor(np.log2(shortest / (3 * (2 * half + 1))))))
    while not found.unique and found.score >= MIN_SCORE and level < top:
        coarser = _search(frame, a, b, level + 1, x_lo, x_hi, half)
        if coarser is None:
            break
        level, found = level + 1, coarser
    if found.score < MIN_SCORE:
        return Match(False, "no match", score=found.score, second_score=found.second)
    if not found.unique:
        return Match(False, "repeated pattern", score=found.score, second_score=found.second)
    second = found.second if level == 0 else None
    for finer in range(level - 1, -1, -1):            # follow the peak down to the finest scale
        reach = FOLLOW_SAMPLES * 2.0 ** (finer + 1)
        found = _search(frame, a, b, finer, found.best_x - reach, found.best_x + reach, half)
        if found is None or found.score < MIN_SCORE:
            return Match(False, "no match", score=None if found is None else found.score)
    refined = _refine(frame, a, b, found.best_x, half)
    if refined is None:
        return Match(False, "no match", score=found.score)
    x_b, sigma_x, slopes, coupling = refined
    if sigma_x > MAX_SIGMA_PX:
        return Match(False, "texture-less", score=found.score)
    uv_b = _pixels(cam_b, frame.rotation_b, frame.f_px, np.array([x_b - 0.5, x_b, x_b + 0.5, x_b, x_b]),
                   np.array([0.0, 0.0, 0.0, -0.5, 0.5]))[0]
    along, across = uv_b[2] - uv_b[0], uv_b[4] - uv_b[3]            # d uv_b / d x and d uv_b / d y, per grid px
    scale_along, scale_across = float(np.linalg.norm(along)), float(np.linalg.norm(across))
    disparity = frame.x_tap - x_b
    depth = frame.f_px * frame.baseline_mm / disparity if disparity > 0 else np.inf
    # in b's px: the match's own sigma, and its move along per px of the line's error across
    coupling_px = coupling * scale_along / scale_across
    sigma_px = float(np.hypot(sigma_x * scale_along, coupling_px * epipolar_sigma_px))
    return Match(True, None, uv_b[1], sigma_px, along / scale_along, found.score, second, level, float(depth),
                 _tap_jacobian(frame, cam_a, cam_b, uv_a, x_b, slopes), float(sigma_x * scale_along), coupling_px)
