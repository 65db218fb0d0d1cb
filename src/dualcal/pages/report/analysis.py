"""The numbers behind the report, computed from a calibrated rig alone (no plotting here).

Everything is recomputed from what calib.json carries (intrinsics, every camera's board pose
in every view, the detected corners), never stored twice:

* :func:`rig_residuals`: observed minus projected corners, per camera and view (pixels);
* :func:`rms_px`, :func:`outlier_views`: per-view RMS and the views out of line: those whose RMS
  is above the limit at which the calibration takes a corner for an outlier
  (:func:`dualcal.estimation.outliers.outlier_limit_px`), so that most of their corners are;
* :func:`coverage_counts`, :func:`coverage_hints`: where on each sensor the board was seen,
  and plain-words warnings where it was not;
* :func:`distortion_curve`, :func:`displacement_map`: the size of the radial distortion of
  the model (paper eq. 13; with ``k3`` where the lens model has it) over the radius, and of the
  whole lens distortion (tangential terms included) over the image;
* :func:`rig_camera_frames`: where the cameras of the rig sit in the reference camera frame;
* :func:`format_value_sigma`: a value and its 1-sigma, rounded to the sigma's precision;
* :func:`camera_findings`: all of the above for each camera of a rig, with plain-words hints.

Conventions (README, "Conventions"): pixel ``(row i, col j)`` has its centre at ``(u=j, v=i)``;
residual = observed - projected; RMS is over points, ``sqrt(mean(du^2 + dv^2))``.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import cv2
import numpy as np
from matplotlib.path import Path as MplPath

from ...estimation.outliers import outlier_limit_px
from ...geometry.camera import (LENS_MODELS, CameraModel, distorted_radius, fold_distorted_radius, image_corner_radius,
                                max_monotonic_radius, normalized_from_pixel, undistort_normalized,
                                undistort_points, undistorted_radius)
from ...errors import NotInvertibleError
from ...geometry.model import Pose, RigModel, ViewResiduals, observed_mask, rig_residuals, rms_px  # noqa: F401 (re-exported)

#: Coverage hints: the outer ring of the image, as a share of the half-diagonal.
OUTER_RING = 0.2
#: Coverage hints: the image is split into this many cells per side to find empty regions.
REGION_GRID = 3
#: Coverage hints: warn when the boards covered less than this share of the image area.
MIN_AREA_SHARE = 0.5
#: Coverage maps use square cells of this share of the image's long side.
COVERAGE_CELL_SHARE = 1 / 48

_REGION_NAMES = {(0, 0): "top-left", (0, 1): "top", (0, 2): "top-right",
                 (1, 0): "left", (1, 1): "centre", (1, 2): "right",
                 (2, 0): "bottom-left", (2, 1): "bottom", (2, 2): "bottom-right"}


def view_outlier_limit_px(residuals: dict[str, ViewResiduals], factor: float) -> float:
    """RMS above which a view of one camera is out of line (px): the calibration's limit for one
    corner, :func:`dualcal.estimation.outliers.outlier_limit_px` of the median length of the camera's corner
    residuals and ``factor``; NaN without views."""
    lengths = [np.linalg.norm(r.residual_px, axis=1) for r in residuals.values()]
    if not lengths or not sum(len(x) for x in lengths):
        return math.nan
    return outlier_limit_px(float(np.median(np.concatenate(lengths))), factor)


def outlier_views(residuals: dict[str, ViewResiduals], factor: float) -> list[str]:
    """Views of one camera whose RMS exceeds :func:`view_outlier_limit_px` (sorted keys)."""
    limit = view_outlier_limit_px(residuals, factor)
    return sorted(v for v, r in residuals.items() if r.rms_px > limit)


# ---------------------------------------------------------------------------- coverage


def coverage_counts(image_size: tuple[int, int], boards_uv_px: list[np.ndarray],
                    cell_px: float) -> np.ndarray:
    """How many views' boards cover each cell of a grid over the image.

    Parameters
    ----------
    image_size : (W, H) pixels
    boards_uv_px : list of (N, 2) corner arrays, one per view; each board is taken as the convex
        hull of its corners
    cell_px : side of one grid cell in pixels

    Returns
    -------
    (rows, cols) int array: for cell ``[i, j]``, the number of boards whose hull holds the cell's
    centre ``(u, v) = ((j + 1/2) c - 1/2, (i + 1/2) c - 1/2)``, ``c = cell_px`` (the grid starts at
    the image's edge, half a pixel before pixel centre 0).
    """
    w, h = image_size
    cols, rows = max(1, math.ceil(w / cell_px)), max(1, math.ceil(h / cell_px))
    uu, vv = np.meshgrid((np.arange(cols) + 0.5) * cell_px - 0.5, (np.arange(rows) + 0.5) * cell_px - 0.5)
    centres = np.column_stack([uu.ravel(), vv.ravel()])
    counts = np.zeros(rows * cols, np.int32)
    for uv in boards_uv_px:
        hull = cv2.convexHull(np.asarray(uv, np.float32)).reshape(-1, 2)
        counts += MplPath(hull).contains_points(centres)
    return counts.reshape(rows, cols)


def relative_radius(image_size: tuple[int, int], uv_px: np.ndarray) -> np.ndarray:
    """Distance of pixels (N, 2) from the image centre, as a share of the half-diagonal."""
    w, h = image_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    return np.linalg.norm(np.asarray(uv_px, float) - centre, axis=-1) / (0.5 * math.hypot(w, h))


def coverage_hints(camera_name: str, image_size: tuple[int, int], boards_uv_px: list[np.ndarray],
                   area_share: float) -> list[str]:
    """Plain-words warnings where the corners of ``camera_name`` leave parts of the image empty.

    ``area_share`` is the share of the image that at least one board covered (from
    :func:`coverage_counts`). Returns an empty list when coverage is good.
    """
    if not boards_uv_px:
        return [f"no corners of the {camera_name} camera were used: nothing is known about its image"]
    uv = np.vstack(boards_uv_px)
    hints = []
    reach = float(relative_radius(image_size, uv).max())
    if reach < 1.0 - OUTER_RING:
        hints.append(f"no corners in the outer {OUTER_RING:.0%} of the {camera_name} image "
                     f"(they reach {reach:.0%} of the way from the centre to the corners): "
                     "distortion there is extrapolated")
    w, h = image_size
    j = np.clip((uv[:, 0] + 0.5) * REGION_GRID // w, 0, REGION_GRID - 1).astype(int)
    i = np.clip((uv[:, 1] + 0.5) * REGION_GRID // h, 0, REGION_GRID - 1).astype(int)
    seen = set(zip(i.tolist(), j.tolist()))
    empty = [name for cell, name in _REGION_NAMES.items() if cell not in seen]
    filled = [name for cell, name in _REGION_NAMES.items() if cell in seen]
    if empty:
        where = (f"no corners in the {', '.join(empty)}" if len(empty) <= len(filled)
                 else f"corners only in the {', '.join(filled)}")
        hints.append(f"{where} of the {camera_name} image ({REGION_GRID}x{REGION_GRID} regions): "
                     "take photos with the board in the empty regions")
    if area_share < MIN_AREA_SHARE:
        hints.append(f"the boards covered only {area_share:.0%} of the {camera_name} image: "
                     "fill more of the frame, near the edges and corners")
    return hints


# ---------------------------------------------------------------------------- distortion


@dataclass(frozen=True)
class DistortionCurve:
    """Radial displacement of the model along the radius, in pixels.

    ``radius_px`` is the distorted (observed) distance from the principal point, ``shift_px``
    the distorted minus the ideal radius there, both scaled by ``f = sqrt(fx fy)``.
    ``corner_radius_px`` is where the farthest image corner lies; ``fold_radius_px`` where the
    model stops being monotonic (undistortion not unique beyond), or None if it never does
    inside the image.
    """

    radius_px: np.ndarray
    shift_px: np.ndarray
    corner_radius_px: float
    fold_radius_px: float | None


def _mean_focal_px(camera: CameraModel) -> float:
    return math.sqrt(camera.fx * camera.fy)


def distortion_curve(camera: CameraModel, samples: int = 200) -> DistortionCurve:
    """Radial displacement ``rd - r`` (paper eq. 13) from the centre out to the image corner.

    Of the radial part of the lens (``k1, k2, k3``): tangential terms (``p1, p2``) move points
    across the radius too, so they have no curve along it (:func:`displacement_map` shows them).
    Of a fisheye, ``r`` is the pinhole radius ``tan(theta)`` of the same ray, and the curve ends
    where the image's corner is, or short of 90 degrees.
    """
    f = _mean_focal_px(camera)
    rd_corner = image_corner_radius(camera)
    rd_fold = fold_distorted_radius(camera)
    fold = rd_fold < rd_corner
    if camera.fisheye:          # its "fold" may be 90 degrees from the axis, where tan(theta) is infinite
        r_end = float(undistorted_radius(camera, np.array([min(rd_corner, rd_fold * (1 - 1e-9))]))[0])
    elif fold:
        r_end = max_monotonic_radius(*camera.radial)
    else:
        r_end = float(undistort_normalized(np.array([[rd_corner, 0.0]]), *camera.radial[:2], k3=camera.k3)[0, 0])
    r = np.linspace(0.0, r_end, samples)
    rd = distorted_radius(camera, r)
    return DistortionCurve(rd * f, (rd - r) * f, rd_corner * f, rd_fold * f if fold else None)


def displacement_px(camera: CameraModel, uv_px: np.ndarray) -> np.ndarray:
    """Length in pixels of the distortion at observed pixels (N, 2): ``|uv - ideal(uv)|``.

    NaN where undistortion is not unique (beyond the model's fold, :func:`max_distorted_radius`).
    The full lens model, tangential terms included.
    """
    uv_px = np.asarray(uv_px, float)
    out = np.full(len(uv_px), np.nan)
    rd = np.linalg.norm(normalized_from_pixel(camera, uv_px), axis=-1)
    ok = rd < fold_distorted_radius(camera)
    with contextlib.suppress(NotInvertibleError):   # Newton failed right at the fold: leave the map blank
        out[ok] = np.linalg.norm(uv_px[ok] - undistort_points(camera, uv_px[ok]), axis=-1)
    return out


def displacement_map(camera: CameraModel, cells: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`displacement_px` on a grid over the image, about ``cells`` samples on the long side.

    Returns ``u`` (cols,), ``v`` (rows,) pixel coordinates and the (rows, cols) displacement.
    """
    w, h = camera.image_size
    step = max(w, h) / cells
    u = np.linspace(-0.5, w - 0.5, max(2, round(w / step) + 1))
    v = np.linspace(-0.5, h - 0.5, max(2, round(h / step) + 1))
    uu, vv = np.meshgrid(u, v)
    d = displacement_px(camera, np.column_stack([uu.ravel(), vv.ravel()]))
    return u, v, d.reshape(uu.shape)


def corner_reach_px(camera: CameraModel, uv_px: np.ndarray) -> float:
    """Farthest observed corner (N, 2) from the principal point, in :class:`DistortionCurve` units."""
    if len(uv_px) == 0:
        return math.nan
    rd = np.linalg.norm(normalized_from_pixel(camera, uv_px), axis=1)
    return float(rd.max() * _mean_focal_px(camera))


# ---------------------------------------------------------------------------- rig geometry


def rig_camera_frames(rig: RigModel) -> dict[str, Pose]:
    """Pose of every camera of the rig as ``X_ref = R X_cam + t`` (reference camera frame, mm).

    The reference camera is the identity; cameras without a relation to it (rig mode ``none``)
    are left out. ``t`` is the camera's perspective centre in the reference frame.
    """
    frames = {rig.reference: Pose(np.eye(3), np.zeros(3))}
    for name, rel in rig.rig.items():
        frames[name] = rel.pose.inverse()
    return frames


# ---------------------------------------------------------------------------- formatting


def format_value_sigma(value: float, sigma: float, sigma_digits: int = 2,
                       fallback_digits: int = 6) -> tuple[str, str]:
    """Strings for a value and its 1-sigma, the value rounded to the sigma's last digit.

    ``sigma`` gets ``sigma_digits`` significant digits. A sigma of exactly 0 means the value
    was held fixed (``"fixed"``); a missing (NaN) sigma gives ``"–"``. Without a usable sigma
    the value is written with ``fallback_digits`` significant digits.

    Examples
    --------
    >>> format_value_sigma(3127.2083, 12.894)
    ('3127', '13')
    >>> format_value_sigma(-0.01834, 0.0431)
    ('-0.018', '0.043')
    >>> format_value_sigma(0.0, 0.0)
    ('0', 'fixed')
    """
    value, sigma = float(value), float(sigma)
    if not math.isfinite(value):
        return "–", "–"
    if not math.isfinite(sigma) or sigma < 0:
        return f"{value:.{fallback_digits}g}", "–"
    if sigma == 0:
        return f"{value:.{fallback_digits}g}", "fixed"
    decimals = max(0, sigma_digits - 1 - math.floor(math.log10(sigma)))
    # Rounding can carry the sigma to one more digit (0.096 -> 0.10): recompute once.
    if float(f"{sigma:.{decimals}f}") >= 10 ** (sigma_digits - decimals):
        decimals = max(0, decimals - 1)
    text = f"{value:.{decimals}f}"
    if float(text) == 0:
        text = text.lstrip("-")
    return text, f"{sigma:.{decimals}f}"


# ---------------------------------------------------------------------------- per camera


@dataclass
class CameraFindings:
    """What the report shows about one camera of a rig.

    ``residuals[view]`` and ``view_rms_px[view]`` for every view with corners and a pose;
    ``rms_px`` over all of them; ``outliers``, the views above ``outlier_limit_px``
    (:func:`view_outlier_limit_px`); ``coverage`` counts
    (:func:`coverage_counts`) on cells of ``coverage_cell_px``; the distortion ``curve`` and
    ``reach_px``, the farthest observed corner on it; ``hints``: plain-words warnings.
    """

    residuals: dict[str, ViewResiduals]
    view_rms_px: dict[str, float]
    rms_px: float
    outlier_limit_px: float
    outliers: list[str]
    coverage: np.ndarray
    coverage_cell_px: float
    curve: DistortionCurve
    reach_px: float
    hints: list[str]

    @property
    def boards_uv_px(self) -> list[np.ndarray]:
        """Observed corners (N, 2) of every view with residuals."""
        return [r.uv_px for r in self.residuals.values()]


def camera_findings(rig: RigModel) -> dict[str, CameraFindings]:
    """:class:`CameraFindings` of every camera of ``rig`` (in the order of ``rig.cameras``).

    Outliers are judged as the calibration judged them, with its recorded ``outlier_factor``
    (:meth:`dualcal.geometry.model.RigModel.calibration_options`).
    """
    residuals = rig_residuals(rig)
    factor = float(rig.calibration_options()["outlier_factor"])
    out = {}
    for name, camera in rig.cameras.items():
        res = residuals[name]
        boards = [r.uv_px for r in res.values()]
        view_rms = {v: r.rms_px for v, r in res.items()}
        limit = view_outlier_limit_px(res, factor)
        outliers = outlier_views(res, factor)
        cell = max(camera.image_size) * COVERAGE_CELL_SHARE
        counts = coverage_counts(camera.image_size, boards, cell)
        curve = distortion_curve(camera)
        hints = coverage_hints(name, camera.image_size, boards, float(np.mean(counts > 0)))
        if outliers:
            many = len(outliers) > 1
            hints.append(f"{name}: view{'s' if many else ''} {', '.join(outliers)} "
                         f"{'have' if many else 'has'} an RMS above the camera's outlier limit of "
                         f"{limit:.3g} px: check {'them' if many else 'it'} for blur, a moved board or a "
                         "wrong detection")
        if curve.fold_radius_px is not None:
            hints.append(f"{name}: the distortion model folds over inside the image (beyond "
                         f"{curve.fold_radius_px:.0f} px from the principal point): "
                         f"{', '.join(LENS_MODELS[camera.model])} are not usable out there")
        all_uv = np.vstack(boards) if boards else np.empty((0, 2))
        all_res = np.vstack([r.residual_px for r in res.values()]) if res else np.empty((0, 2))
        out[name] = CameraFindings(res, view_rms, rms_px(all_res), limit, outliers, counts, cell,
                                   curve, corner_reach_px(camera, all_uv), hints)
    return out
