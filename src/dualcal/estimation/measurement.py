"""Measuring with a calibrated rig: 3-D points and lengths from one instant, each with an honest sigma.

A point is given by its pixels in two or more cameras of the rig, in photos taken at one instant
(points.json, contract "measure"). It is intersected in the reference camera's frame with the
rig alone: camera ``c`` sees ``X_c = R_c X + t_c`` (:meth:`dualcal.geometry.model.RigModel.pose_from_reference`),
by :func:`dualcal.estimation.intersect.triangulate` (least squares on the pixel residuals, paper section 2).

Uncertainty, to first order. The point minimises the pixel residuals
``r(X, theta, uv) = project(cam_i, R_i X + t_i) - uv_i`` of its photos; at the minimum
``J^T r = 0`` with ``J = dr/dX`` (2m x 3), so measured pixels moved by ``duv`` and calibrated
parameters moved by ``dtheta`` move the point by::

    dX = A (duv - J_theta dtheta),    A = (J^T J)^-1 J^T.

``theta`` are the parameters of calib.json's joint covariance (``covariance``, built by
:func:`dualcal.estimation.rig_relations.parameter_covariance`) of the cameras the point was seen by: their free
intrinsics (``J_theta`` from :func:`dualcal.geometry.camera.project_with_jacobians`, so any lens model),
and for a non-reference camera its rotation's left increment ``d`` (``R_c <- exp([d]x) R_c``, so
``d(R_c X)/dd = -[R_c X]x``) and its translation ``t_c``. Every point of one measurement shares
``theta``, so their errors are correlated; the joint covariance of the P points (3P x 3P) is::

    Cov = blockdiag(A_p S_p A_p^T) + B Cov_theta B^T,    B = [-A_p J_theta,p]  (3P x k),

with ``S_p`` the pixel noise (``pixel_sigma^2`` per coordinate, independent between photos). A
length ``L = |X_a - X_b|`` has ``sigma_L^2 = g^T Cov g``, ``g = (e, -e)``, ``e`` the unit vector
from b to a: the correlations are kept, so an error of the rig's scale shows in full in a length,
while a shift of both ends alike cancels.

Which covariance of ``theta``: calib.json holds two, ``clustered`` by instant and ``formal``
(:mod:`dualcal.estimation.uncertainty`). As for every sigma dualcal reports, each value's sigma is the larger
of the two propagated ones: for a coordinate the larger variance, for a length the larger
``sigma_L``, each computed within one covariance with all its correlations (taking the larger per
coordinate first and combining those would not be a covariance, and would lose the correlations
that make a length more certain than its ends).

Pixel noise: ``pixel_sigma`` of points.json (px per coordinate; one number, or one per camera);
by default each camera's own noise in its calibration, ``rms_px / sqrt(2)`` (per coordinate, from
the 2-D RMS) times ``sqrt(observations / redundancy)`` (the residuals of a fit are smaller than its
errors): :func:`calibration_pixel_sigma`. That is the noise of a detected corner; pixels placed
by hand are less precise, and should say so.

Matched points (:mod:`dualcal.estimation.matching`). With the instant's photos, a point given in one
camera only (a tap) is found in the others; its pixels' errors are then correlated: a tap's error
``delta`` (``pixel_sigma`` of that camera) moves the matched pixel with it (``K delta``, ``K`` the match's
``tap_jacobian``), and the match adds its own error along the epipolar line (``M``, its ``sigma_px``), so
the pixels ``(uv_a, uv_b, ...)`` have the covariance ``S = T s^2 T^T + blockdiag(0, M_b, ...)``,
``T = (I, K_b, ...)``: the tap moves the point along the surface, not in depth. Wherever ``S`` appears
below it is this matrix (diagonal for points given by hand in every camera). The match is made on the
calibration's epipolar line, which is itself uncertain across (by :func:`_epipolar_sigma_px`, from the
calibration's covariance): a line off by ``D`` moves a match along it by its ``epipolar_coupling`` times ``D``
(how the texture there slants), which its ``sigma_px`` includes (:meth:`Match.widened`), taken as independent
of the calibration's other effects on the point.

Focus. Each photo's camera is :func:`dualcal.estimation.focus_model.camera_at_focus` at that photo's focus
distance: the focus its metadata states, else the distance of the points it measured (``focus_from``
``"metadata"``, ``"points"``), where the calibration models focus (:func:`focus_modelled`); otherwise the
calibration's own camera (``"calibration"``, ``focus_m`` the median distance of the board in its calibration
photos). The covariance of
``theta`` is then that of the intrinsics at that focus (the focus model's uncertainty grows away from the
calibration's focus), and, where the calibration saw the stabiliser shift its photos, a new photo's principal
point is uncertain by the spread it found (``ois_sigma_px``): :func:`dualcal.estimation.focus_model.covariance_at_focus`.

When the linear model stops describing a length, its sigma means little, and the length is
flagged (``meaningless`` in measure.json, a warning on stderr saying what would help): its sigma
above :data:`MAX_RELATIVE_SIGMA` of it; an end point whose depth is uncertain by more than
:data:`MAX_DEPTH_SHARE` of its distance (the intersection is then far from linear: depth goes as
1 / parallax); or end points so uncertain across the line (mostly in depth) that the length comes
out long on average by more than :data:`MAX_BIAS_SHARE` of its sigma (to second order a length
errs by ``+tr(P Cov_ab) / 2L``, ``P = I - e e^T``, ``Cov_ab`` the covariance of ``X_a - X_b``).
A point whose pixels disagree beyond what their noise and the calibration's uncertainty allow is
flagged too (``consistent``: its residuals' chi-square, against their covariance
``(I - J A)(S + J_theta Cov_theta J_theta^T)(I - J A)^T``, beyond the :data:`RESIDUAL_PROBABILITY`
quantile with ``2m - 3`` degrees of freedom): not the same point in every photo, or photos not of one
instant. Near the rig, the calibration's part dominates: a relative pose uncertain by 0.1 mm moves a
point at 0.4 m by a pixel in the tele.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..geometry.camera import INTRINSIC_NAMES, CameraModel, project_with_jacobians
from .covariance import JointCovariance, intrinsic_name, rig_name
from .distributions import chi2_quantile
from ..errors import EstimationError, InputError
from .focus_model import camera_at_focus, covariance_at_focus
from .intersect import triangulate
from .matching import MIN_DISTANCE_MM, Match, match_point
from ..geometry.model import RigModel
from ..progress import track, warn
from ..geometry.rotation import cross_matrix
from ..geometry.scale import relative_sigma, with_scale_in_measurement

#: A length is flagged when its sigma is above this share of it.
MAX_RELATIVE_SIGMA = 0.10
#: ... or when an end point's depth sigma is above this share of its distance from the reference camera.
MAX_DEPTH_SHARE = 0.10
#: ... or when its second-order bias (end points uncertain across the line) is above this share of its sigma.
MAX_BIAS_SHARE = 0.25
#: A point's pixels disagree when their residual is beyond this quantile of chi-square.
RESIDUAL_PROBABILITY = 0.999

COVARIANCE_KINDS = ("clustered", "formal")


def calibration_pixel_sigma(rig: RigModel) -> dict[str, float]:
    """Each camera's noise of one pixel coordinate in its calibration, px (module docstring)."""
    adj = rig.adjustment
    n, redundancy = adj.get("n_observations"), adj.get("redundancy")
    factor = np.sqrt(n / redundancy) if n and redundancy else 1.0
    return {name: float(rms / np.sqrt(2.0) * factor) for name, rms in rig.camera_rms_px.items()}


def _pixel_sigmas(rig: RigModel, given) -> tuple[dict[str, float], str]:
    """``pixel_sigma`` per camera and where it comes from: ``points.json`` or ``calibration``."""
    own = calibration_pixel_sigma(rig)
    if given is None:
        missing = [c for c, s in own.items() if not np.isfinite(s)]
        if missing:
            raise InputError(f"calib.json states no rms_px for camera {missing[0]!r}: give pixel_sigma (px) in "
                             "points.json")
        return own, "calibration"
    if isinstance(given, dict):
        return {**own, **given}, "points.json"
    return dict.fromkeys(own, float(given)), "points.json"


def _covariances(rig: RigModel) -> tuple[dict[str, int], dict[str, np.ndarray]]:
    """calib.json's joint covariance (:class:`dualcal.estimation.covariance.JointCovariance`): index of every
    parameter name and ``{kind: (k, k)}``."""
    cov = JointCovariance.from_dict(rig.covariance)
    return {name: i for i, name in enumerate(cov.parameters)}, {k: cov.matrices[k] for k in COVARIANCE_KINDS}


@dataclass(frozen=True)
class IntersectedPoint:
    """One point intersected from its photos (module docstring).

    ``xyz_mm`` (3,) in the reference camera's frame; ``cameras`` the m photos' cameras;
    ``A`` (3, 2m) its sensitivity to their pixels, ``B`` (3, k) to the calibration's parameters
    (``dX = A duv + B dtheta``); ``residual_px`` (m, 2) of each photo; ``J_theta`` (2m, k) the
    residuals' derivative with respect to the parameters and ``annihilator`` (2m, 2m) ``I - J A``, which
    turns errors of pixels and parameters into residuals (``r = -(I - J A)(duv - J_theta dtheta)``).
    """

    xyz_mm: np.ndarray
    cameras: tuple[str, ...]
    A: np.ndarray
    B: np.ndarray
    residual_px: np.ndarray
    J_theta: np.ndarray
    annihilator: np.ndarray


def _parameter_rows(rig: RigModel, name: str, X_cam: np.ndarray, J_X: np.ndarray, J_K: np.ndarray,
                    index: dict[str, int]) -> np.ndarray:
    """(P, 2, k) derivative of P photos' residuals in camera ``name`` (points ``X_cam`` (P, 3), their
    Jacobians ``J_X`` (P, 2, 3) and ``J_K`` (P, 2, 10)) with respect to the covariance's parameters."""
    rows = np.zeros((len(X_cam), 2, len(index)))
    for i, n in enumerate(INTRINSIC_NAMES):
        key = intrinsic_name(name, n)
        if key in index:
            rows[:, :, index[key]] = J_K[:, :, i]
    if name == rig.reference:
        return rows
    keys = [rig_name(name, what, axis) for what in ("rotation_rad", "t_mm") for axis in "xyz"]
    if not all(k in index for k in keys):
        raise InputError(f"calib.json's covariance has no rig relation of camera {name!r}: it cannot measure")
    R_X = X_cam - rig.pose_from_reference(name).t_mm              # R_c X
    d_rotation = -np.einsum("pkj,pji->pki", J_X, cross_matrix(R_X))
    for k, column in zip(keys, np.concatenate([d_rotation, J_X], axis=2).transpose(2, 0, 1)):
        rows[:, :, index[k]] = column
    return rows


def intersect_points(rig: RigModel, uv_px: dict[str, dict[str, np.ndarray]], index: dict[str, int],
                     failed: dict[str, str] | None = None) -> dict[str, IntersectedPoint]:
    """Intersect and linearise points ``{name: {camera: (2,) uv}}`` (module docstring), those seen by the
    same cameras together (one triangulation and one projection per camera for all of them).

    ``index`` maps the names of calib.json's covariance parameters to their positions. A point whose rays do not
    meet raises :class:`EstimationError`, or with ``failed`` is left out and named there with the reason.
    """
    groups: dict[tuple[str, ...], list[str]] = {}
    for name, seen in uv_px.items():
        groups.setdefault(tuple(seen), []).append(name)
    out = {}
    for names, members in groups.items():
        cams = [rig.cameras[c] for c in names]
        poses = [rig.pose_from_reference(c) for c in names]
        uv = [np.array([np.asarray(uv_px[m][c], float) for m in members]) for c in names]    # per camera (P, 2)
        try:
            X = triangulate(cams, poses, uv)
        except EstimationError as exc:
            if len(members) > 1:                   # name the point whose rays fail
                for m in members:
                    out.update(intersect_points(rig, {m: uv_px[m]}, index, failed))
            elif failed is not None:
                failed[members[0]] = str(exc)
            else:
                raise EstimationError(f"point {members[0]!r}: {exc}") from None
            continue
        J, J_theta, res = [], [], []
        for name, cam, pose, uv_c in zip(names, cams, poses, uv):
            X_cam = pose.apply(X)
            uv_hat, J_X, J_K = project_with_jacobians(cam, X_cam)
            J.append(J_X @ pose.R)
            J_theta.append(_parameter_rows(rig, name, X_cam, J_X, J_K, index))
            res.append(uv_hat - uv_c)
        J, J_theta = np.concatenate(J, axis=1), np.concatenate(J_theta, axis=1)     # (P, 2m, 3), (P, 2m, k)
        A = np.linalg.solve(np.einsum("pki,pkj->pij", J, J), J.transpose(0, 2, 1))  # (P, 3, 2m)
        B = -A @ J_theta
        annihilator = np.eye(J.shape[1]) - J @ A
        res = np.stack(res, axis=1)                                                 # (P, m, 2)
        for i, m in enumerate(members):
            out[m] = IntersectedPoint(X[i], names, A[i], B[i], res[i], J_theta[i], annihilator[i])
    return {name: out[name] for name in uv_px if name in out}


def intersect_point(rig: RigModel, uv_px: dict[str, np.ndarray], index: dict[str, int]) -> IntersectedPoint:
    """Intersect one point from its pixels ``{camera: (2,) uv}`` and linearise it (:func:`intersect_points`)."""
    return intersect_points(rig, {"point": uv_px}, index)["point"]


def _residual_chi2(p: IntersectedPoint, pixel_cov: np.ndarray, cov_theta: dict[str, np.ndarray]) -> float:
    """The point's residuals against what its pixels' covariance ``pixel_cov`` (2m, 2m) and the calibration's
    uncertainty allow.

    ``Cov(r) = (I - J A) (S + J_theta C J_theta^T) (I - J A)^T`` (rank ``2m - 3``), for each covariance
    ``C`` of calib.json; the smaller chi-square of the two (the larger uncertainty) is returned.
    """
    r = p.residual_px.ravel()
    chis = []
    for C in cov_theta.values():
        cov_r = p.annihilator @ (pixel_cov + p.J_theta @ C @ p.J_theta.T) @ p.annihilator.T
        chis.append(float(r @ np.linalg.pinv(cov_r, rcond=1e-10, hermitian=True) @ r))
    return min(chis)


def _length_note(rig, a, b, points, length, sigma, pixel_share, depth, bias, pixel_sigma):
    """Why a length is not meaningful and what would help (None where it is); ``pixel_share`` is the pixel
    noise's share of its variance."""
    reasons = []
    if sigma > MAX_RELATIVE_SIGMA * length:
        reasons.append(f"its sigma is {100 * sigma / length:.0f} % of it")
    for p in (a, b):
        d, s = np.linalg.norm(points[p].xyz_mm), depth[p]
        if s > MAX_DEPTH_SHARE * d:
            reasons.append(f"the depth of {p} is uncertain by {100 * s / d:.0f} % of its distance ({d:.0f} mm)")
    if bias > MAX_BIAS_SHARE * sigma:
        reasons.append(f"its end points are so uncertain across the line (in depth: {a} +-{depth[a]:.3g} mm, "
                       f"{b} +-{depth[b]:.3g} mm) that it comes out long by about {bias:.3g} mm on average, "
                       f"{bias / sigma:.1f} of its sigma")
    if not reasons:
        return None
    far = max((a, b), key=lambda p: np.linalg.norm(points[p].xyz_mm))
    used = sorted(set(points[a].cameras) | set(points[b].cameras), key=rig.camera_order().index)
    centres = [rig.pose_from_reference(c).center_mm for c in used]
    base = max(np.linalg.norm(p - q) for i, p in enumerate(centres) for q in centres[i + 1:])
    helps = [f"get closer ({far} is {np.linalg.norm(points[far].xyz_mm):.0f} mm away)",
             f"a pair of cameras with a longer baseline ({'+'.join(used)}: {base:.1f} mm)"]
    if pixel_share >= 0.5:
        px = ", ".join(f"{c} {pixel_sigma[c]:.2g}" for c in used)
        helps.append(f"pixels placed more precisely (pixel_sigma {px} px: {100 * pixel_share:.0f} % of "
                     "the variance)")
    else:
        helps.append(f"more instants in the calibration ({100 * (1 - pixel_share):.0f} % of the variance "
                     "is the calibration's)")
    return (f"length {a}-{b} = {length:.1f} +- {sigma:.2g} mm is not meaningful: {'; '.join(reasons)}. "
            f"What would help: {', '.join(helps)}")


def _finite_uv(value, what: str) -> np.ndarray:
    """A pixel ``[u, v]``: two finite numbers."""
    try:
        uv = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected numbers") from None
    if uv.shape != (2,):
        raise InputError(f"{what}: expected shape (2,), got {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise InputError(f"{what}: contains NaN or infinite values")
    return uv


def _positive_px(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise InputError(f"{what}: expected a positive number of pixels, got {value!r}")
    return float(value)


def points_from_dict(doc: dict, source: str = "points.json", single_camera: bool = False) -> dict:
    """Validate a points.json document (contract, "measure"); with ``single_camera`` (the instant's photos are
    given) a point may be given in one camera only, to be matched in the others.

    Returns ``{"points": {name: {camera: (2,) uv_px}}, "lengths": [(from, to), ...], "pixel_sigma":
    None | px | {camera: px}}``. ``pixel_sigma`` may be one number (px per coordinate, every camera)
    or, as dualcal adds, one per camera. Which cameras exist is checked against the calibration by
    :func:`dualcal.estimation.measurement.measure`.
    """
    points = doc.get("points")
    if not isinstance(points, dict) or not points:
        raise InputError(f"{source}: 'points' must be a non-empty object: {{\"A\": {{\"wide\": [u, v], "
                         "\"tele\": [u, v]}, ...}")
    out = {}
    for name, seen in points.items():
        if not isinstance(seen, dict):
            raise InputError(f"{source}: point {name!r} must be an object of camera names to pixels [u, v]")
        if len(seen) < (1 if single_camera else 2):
            raise InputError(f"{source}: point {name!r} is given in {len(seen)} camera(s) "
                             f"({', '.join(seen) or 'none'}); a point needs its pixels in two or more cameras "
                             "of one instant (or, with the photos of that instant, in one)")
        out[str(name)] = {str(cam): _finite_uv(uv, f"{source}: point {name!r} in camera {cam!r}")
                          for cam, uv in seen.items()}
    lengths = doc.get("lengths", [])
    if not isinstance(lengths, (list, tuple)):
        raise InputError(f"{source}: 'lengths' must be a list of pairs of point names, e.g. [[\"A\", \"B\"]]")
    pairs = []
    for pair in lengths:
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(isinstance(p, str) for p in pair)):
            raise InputError(f"{source}: length {pair!r}: expected a pair of point names, e.g. [\"A\", \"B\"]")
        unknown = [p for p in pair if p not in out]
        if unknown:
            raise InputError(f"{source}: length {pair!r} names point {unknown[0]!r}, which is not in 'points'")
        if pair[0] == pair[1]:
            raise InputError(f"{source}: length {pair!r} joins a point to itself")
        pairs.append((pair[0], pair[1]))
    sigma = doc.get("pixel_sigma")
    if isinstance(sigma, dict):
        sigma = {str(cam): _positive_px(s, f"{source}: pixel_sigma of camera {cam!r}") for cam, s in sigma.items()}
    elif sigma is not None:
        sigma = _positive_px(sigma, f"{source}: pixel_sigma")
    return {"points": out, "lengths": pairs, "pixel_sigma": sigma}


# ---------------------------------------------------------------------------- focus


def focus_modelled(rig: RigModel, camera_name: str) -> bool:
    """Whether the calibration models camera ``camera_name``'s intrinsics as a function of the focus distance
    (calib.json's ``cameras.<name>.focus_model``, contract "measure with the photos";
    :mod:`dualcal.estimation.focus_model`). A camera it does not model is measured with the calibration's own
    camera (``focus_from`` ``"calibration"``)."""
    return camera_name in rig.focus_models


def calibration_focus_m(rig: RigModel, camera_name: str) -> float | None:
    """The focus distance the calibration's camera stands for, m: its focus model's reference focus where it has
    one, else the median distance of the board's centre from camera ``camera_name`` along its axis in its
    calibration photos (autofocus focused there); None without poses."""
    if camera_name in rig.focus_models:
        return rig.focus_models[camera_name].focus_m
    poses = rig.camera_poses.get(camera_name) or {}
    if not poses:
        if camera_name == rig.reference or camera_name not in rig.rig:
            return None
        rel = rig.rig[camera_name].pose
        poses = {v: rel.compose(p) for v, p in rig.reference_poses().items()}
    centre = rig.board.object_points_mm().mean(axis=0)
    return float(np.median([p.apply(centre[None])[0, 2] for p in poses.values()]) / 1000.0)


def _focus(rig: RigModel, cameras, focus_metadata: dict, distances_m: dict) -> dict:
    """``{camera: {"focus_m", "focus_from", "focus_metadata_m"}}`` (module docstring, "Focus")."""
    out = {}
    for c in cameras:
        stated = focus_metadata.get(c)
        if focus_modelled(rig, c) and stated is not None:
            focus, source = stated, "metadata"
        elif focus_modelled(rig, c) and distances_m.get(c) is not None:
            focus, source = distances_m[c], "points"
        else:
            focus, source = calibration_focus_m(rig, c), "calibration"
        out[c] = {"focus_m": focus, "focus_from": source, "focus_metadata_m": stated}
    return out


# ---------------------------------------------------------------------------- matching


def _check_photos(rig: RigModel, photos: dict) -> None:
    for c, image in photos.items():
        if c not in rig.cameras:
            raise InputError(f"photo of camera {c!r}: it is not in the calibration (cameras: "
                             f"{', '.join(rig.camera_order())})")
        h, w = np.shape(image)[:2]
        if (w, h) != tuple(rig.cameras[c].image_size):
            W, H = rig.cameras[c].image_size
            raise InputError(f"the photo of camera {c!r} is {w}x{h} px, but the camera was calibrated at {W}x{H} px: "
                             "give that camera's photo as it was stored (not resized or turned)")


def match_taps(rig: RigModel, taps: dict[str, dict[str, np.ndarray]], photos: dict[str, np.ndarray],
               min_distance_mm: float = MIN_DISTANCE_MM) -> dict[str, dict[str, Match]]:
    """Each point given in one camera found in the instant's other photos (:func:`dualcal.estimation.matching.match_point`).

    Parameters
    ----------
    rig : RigModel
        The calibration (its cameras as the photos were taken:
        :func:`dualcal.estimation.focus_model.camera_at_focus`).
    taps : dict
        ``{point: {camera: (2,) uv}}``, each point in one camera.
    photos : dict
        ``{camera: (H, W) grey image}`` of one instant, stored frame.
    min_distance_mm : float
        The nearest surface searched.

    Returns
    -------
    dict
        ``{point: {other camera: Match}}`` for every other camera with a photo and a pose in the rig.
    """
    out = {}
    for name, seen in track(taps.items(), "matching the points", len(taps)):
        (a, uv), = seen.items()
        if a not in photos:
            raise InputError(f"point {name!r} is given in camera {a!r} only, and there is no photo of {a!r} to find it "
                             f"in the others: give that camera's photo of the instant")
        pose_a = rig.pose_from_reference(a)
        others = [b for b in rig.camera_order() if b != a and b in photos and (b == rig.reference or b in rig.rig)]
        if not others:
            raise InputError(f"point {name!r} is given in camera {a!r} only, and there is no photo of another camera "
                             f"of the rig to find it in: give another camera's photo of the instant")
        out[name] = {}
        for b in others:
            pose_ab = rig.pose_from_reference(b).compose(pose_a.inverse())
            out[name][b] = match_point(photos[a], rig.cameras[a], photos[b], rig.cameras[b], pose_ab, uv,
                                       min_distance_mm)
    return out


def _pixel_covariance(cameras: tuple[str, ...], sigma_px: dict[str, float], matches: dict[str, Match] | None):
    """(2m, 2m) covariance of a point's pixels in ``cameras`` (module docstring, "Matched points"): independent
    ``sigma_px`` per coordinate for pixels given by hand; for a tap (``cameras[0]``) and its ``matches``, the tap's
    error carried into every match by its ``tap_jacobian``, plus the match's own along its epipolar line."""
    if not matches:
        return np.diag(np.repeat([sigma_px[c] ** 2 for c in cameras], 2))
    T = np.vstack([np.eye(2)] + [matches[c].tap_jacobian for c in cameras[1:]])
    S = sigma_px[cameras[0]] ** 2 * T @ T.T
    for i, c in enumerate(cameras[1:], start=1):
        S[2 * i:2 * i + 2, 2 * i:2 * i + 2] += matches[c].covariance
    return S


def _epipolar_sigma_px(p: IntersectedPoint, camera: str, m: Match, cov_theta: dict[str, np.ndarray]) -> float:
    """How far off across itself the calibration's epipolar line may be at the match of point ``p`` in ``camera``,
    1-sigma, px (the larger of calib.json's two covariances).

    A misclosure ``D`` across the line in that camera (a pixel off by ``D n``, ``n`` the unit normal to the line)
    leaves the residual ``P n D`` (``P`` the point's ``annihilator``, a projector), so ``D = u . r`` with
    ``u = P n / |P n|^2``; the calibration's part of the residuals has covariance ``P J_theta C J_theta^T P^T``.
    """
    i = p.cameras.index(camera)
    normal = np.zeros(2 * len(p.cameras))
    normal[2 * i:2 * i + 2] = [-m.direction[1], m.direction[0]]
    Pn = p.annihilator @ normal
    u = p.annihilator.T @ (Pn / (Pn @ Pn))
    return float(np.sqrt(max(u @ p.J_theta @ C @ p.J_theta.T @ u for C in cov_theta.values())))


def match_to_dict(m: Match) -> dict:
    """A match as measure.json's ``matched`` holds it: ``uv``, ``sigma_px``, ``score``, ``second_score``, ``direction``."""
    return {"uv": m.uv.tolist(), "sigma_px": m.sigma_px, "score": m.score, "second_score": m.second_score,
            "direction": m.direction.tolist()}


# ---------------------------------------------------------------------------- measuring


def measure(rig: RigModel, points: dict, photos: dict[str, np.ndarray] | None = None,
            focus_metadata_m: dict[str, float | None] | None = None,
            min_distance_mm: float = MIN_DISTANCE_MM) -> dict:
    """Points and lengths measured with a calibrated rig, each with its 1-sigma (module docstring).

    Parameters
    ----------
    rig : RigModel
        the calibration (calib.json content), with its joint covariance.
    points : dict
        a points.json document (contract, "measure"): ``{"points": {name: {camera: [u, v]}},
        "lengths": [[from, to], ...], "pixel_sigma": px}`` (``lengths`` and ``pixel_sigma``
        optional; ``pixel_sigma`` may also be ``{camera: px}``). Pixels are in the stored frame of
        photos of one instant.
    photos : dict or None
        ``{camera: (H, W) grey image}``: the instant's photos (contract, "measure with the photos"). A point
        given in one camera only is then found in the others (:func:`match_taps`); one that cannot be is
        listed in ``unmatched`` and no length uses it.
    focus_metadata_m : dict or None
        ``{camera: focus distance, m}`` that each photo's metadata states (None: not stated).
    min_distance_mm : float
        The nearest surface a match is searched at.

    Returns
    -------
    dict
        The measure.json document: ``{"frame": reference camera, "points": {name: {"xyz_mm", "sigma_mm",
        "cameras", "distance_mm", "depth_sigma_mm", "residual_px", "consistent", "matched"?}}, "lengths":
        [{"from", "to", "length_mm", "sigma_mm", "sigma_percent", "sigma_pixels_mm", "sigma_calibration_mm",
        "bias_mm", "meaningless", "warning"}], "unmatched": {name: {camera: reason}}, "cameras": {camera:
        {"focus_m", "focus_from", "focus_metadata_m"}}, "pixel_sigma": {camera: px}, "pixel_sigma_source"}``.
        ``depth_sigma_mm`` is the sigma along the line of sight from the reference camera, ``bias_mm``
        a length's second-order bias, ``sigma_pixels_mm`` and ``sigma_calibration_mm`` the parts of its
        sigma from the pixels and the calibration, ``sigma_scale_mm`` (points and lengths) the part from
        the tolerance of the printed squares (:mod:`dualcal.geometry.scale`), which every sigma includes.
        A matched point's ``matched`` is ``{camera: {"uv", "sigma_px", "score", "second_score",
        "direction"}}``: the pixel found, its sigma along the epipolar line (``direction``, the line's unit
        vector there), the ZNCC there and at the best other peak.

    Raises
    ------
    InputError
        A malformed points document, a camera the rig does not have, a calibration without its
        joint covariance, a photo not of its camera's size, a tap without its camera's photo.
    EstimationError
        A point whose rays do not intersect (parallel, or behind a camera).
    """
    photos = photos or {}
    spec = points_from_dict(points, "points", single_camera=bool(photos))
    for name, seen in spec["points"].items():
        unknown = [c for c in seen if c not in rig.cameras]
        if unknown:
            raise InputError(f"point {name!r}: camera {unknown[0]!r} is not in the calibration "
                             f"(cameras: {', '.join(rig.camera_order())})")
        loose = [c for c in seen if c != rig.reference and c not in rig.rig]
        if loose:
            raise InputError(f"point {name!r}: the calibration has no relative pose of camera {loose[0]!r} to "
                             f"{rig.reference!r} (calibrated alone, rig mode {rig.rig_mode!r}): it cannot measure with it")
    _check_photos(rig, photos)
    pixel_sigma, source = _pixel_sigmas(rig, spec["pixel_sigma"])
    cameras = [c for c in rig.camera_order() if c in photos or any(c in seen for seen in spec["points"].values())]
    focus = _focus(rig, cameras, focus_metadata_m or {}, {})
    doc = _measure_at(rig, spec, photos, focus, pixel_sigma, min_distance_mm)
    if any(focus_modelled(rig, c) and f["focus_from"] == "calibration" for c, f in focus.items()):
        # a camera whose focus is modelled but not stated: again at the distance of the points it measured
        focus = _focus(rig, cameras, focus_metadata_m or {}, _distances_m(rig, doc))
        doc = _measure_at(rig, spec, photos, focus, pixel_sigma, min_distance_mm)
    doc.update(cameras=focus, pixel_sigma={c: pixel_sigma[c] for c in rig.camera_order()}, pixel_sigma_source=source)
    return with_scale_in_measurement(doc, relative_sigma(rig.board))


def _distances_m(rig: RigModel, doc: dict) -> dict[str, float]:
    """Each camera's median distance (along its axis, m) of the points it measured in ``doc``."""
    out = {}
    for c in rig.camera_order():
        z = [rig.pose_from_reference(c).apply(np.asarray(p["xyz_mm"])[None])[0, 2]
             for p in doc["points"].values() if c in p["cameras"]]
        if z:
            out[c] = float(np.median(z) / 1000.0)
    return out


def _measure_at(rig: RigModel, spec: dict, photos: dict, focus: dict, pixel_sigma: dict,
                min_distance_mm: float) -> dict:
    """:func:`measure` with each photo's camera at its ``focus``
    (:func:`dualcal.estimation.focus_model.camera_at_focus`), and the calibration's covariance there
    (:func:`dualcal.estimation.focus_model.covariance_at_focus`: the focus model's, the stabiliser's)."""
    rig = replace(rig, cameras={c: camera_at_focus(rig, c, focus[c]["focus_m"]) if c in focus else cam
                                for c, cam in rig.cameras.items()},
                  covariance=covariance_at_focus(rig, {c: f["focus_m"] for c, f in focus.items()}))
    taps = {n: seen for n, seen in spec["points"].items() if len(seen) == 1}
    found = match_taps(rig, taps, photos, min_distance_mm)
    uv_px, matched, unmatched = {}, {}, {}
    for name, seen in spec["points"].items():
        uv_px[name] = dict(seen)
        if name not in found:
            continue
        matched[name] = {c: m for c, m in found[name].items() if m.ok}
        missed = {c: m.reason for c, m in found[name].items() if not m.ok}
        if missed:
            unmatched[name] = missed
        uv_px[name].update({c: m.uv for c, m in matched[name].items()})
        if len(uv_px[name]) < 2:
            warn(f"point {name}: not found in the other photos ({'; '.join(f'{c}: {r}' for c, r in missed.items())}): "
                 "it is not measured (tap it in another photo too, or pick a point with texture around it)")
            del uv_px[name]
    failed = {}
    doc = _measured(rig, spec, uv_px, matched, pixel_sigma, failed)
    for name, reason in failed.items():
        unmatched[name] = {c: f"its rays do not meet in front of the cameras ({reason})" for c in matched[name]}
        warn(f"point {name}: its match does not meet its tap's ray in front of the cameras: it is not measured")
    for name, m in matched.items():
        if name in doc["points"] and m:
            doc["points"][name]["matched"] = {c: match_to_dict(x) for c, x in m.items()}
    doc["unmatched"] = unmatched
    return doc


def _measured(rig: RigModel, spec: dict, uv_px: dict, matched: dict, pixel_sigma: dict,
              failed: dict[str, str]) -> dict:
    """The points ``uv_px`` ``{name: {camera: uv}}`` intersected and the lengths between them (module docstring); a
    matched point whose rays do not meet (a match at or beyond infinity) is left out and named in ``failed``."""
    index, cov_theta = _covariances(rig)
    given = {n: uv for n, uv in uv_px.items() if n not in matched}
    found = {**intersect_points(rig, given, index),
             **intersect_points(rig, {n: uv for n, uv in uv_px.items() if n in matched}, index, failed)}
    found = {n: found[n] for n in uv_px if n in found}
    names = list(found)
    for n in names:
        for c, m in (matched.get(n) or {}).items():
            matched[n][c] = m.widened(_epipolar_sigma_px(found[n], c, m, cov_theta))
    pixel_cov = {n: _pixel_covariance(found[n].cameras, pixel_sigma, matched.get(n)) for n in names}
    # Every part is a fixed-size block (module docstring): a point's 3 x 3 pixel part A S A^T, and the
    # calibration's part through B (3 x k), so the cost grows linearly with the points and the lengths.
    pixels = {n: found[n].A @ pixel_cov[n] @ found[n].A.T for n in names}

    doc_points, depth, chi2_limit = {}, {}, {}
    for n in names:
        p = found[n]
        blocks = [pixels[n] + p.B @ C @ p.B.T for C in cov_theta.values()]
        distance = float(np.linalg.norm(p.xyz_mm))
        ray = p.xyz_mm / distance
        var = np.max([np.diag(block) for block in blocks], axis=0)
        depth[n] = float(np.sqrt(max(ray @ block @ ray for block in blocks)))
        dof = 2 * len(p.cameras) - 3
        if dof not in chi2_limit:
            chi2_limit[dof] = chi2_quantile(dof, RESIDUAL_PROBABILITY)
        consistent = bool(_residual_chi2(p, pixel_cov[n], cov_theta) <= chi2_limit[dof])
        doc_points[n] = {"xyz_mm": p.xyz_mm.tolist(), "sigma_mm": np.sqrt(var).tolist(), "cameras": list(p.cameras),
                         "distance_mm": distance, "depth_sigma_mm": depth[n],
                         "residual_px": {c: float(np.linalg.norm(r)) for c, r in zip(p.cameras, p.residual_px)},
                         "consistent": consistent}
        if not consistent:
            warn(f"point {n}: its pixels disagree by "
                 f"{', '.join(f'{c} {np.linalg.norm(r):.2g} px' for c, r in zip(p.cameras, p.residual_px))}, "
                 "far beyond their noise (pixel_sigma) and the calibration's uncertainty: not the same point in "
                 "every photo (a mis-click?), or photos not taken at one instant")

    lengths, unmeasured = [], []
    for a, b in spec["lengths"]:
        missing = [p for p in (a, b) if p not in found]
        if missing:
            unmeasured.append({"from": a, "to": b, "reason": f"point {missing[0]} is not measured (unmatched)"})
            warn(f"length {a}-{b} is not measured: point {missing[0]} was not found in the other photos")
            continue
        d = found[a].xyz_mm - found[b].xyz_mm
        length = float(np.linalg.norm(d))
        e = d / length
        # X_a - X_b moves by A_a duv_a - A_b duv_b + (B_a - B_b) dtheta: its covariance, per kind
        pixel_part, dB = pixels[a] + pixels[b], found[a].B - found[b].B
        diff_cov = {kind: pixel_part + dB @ C @ dB.T for kind, C in cov_theta.items()}
        kind = max(COVARIANCE_KINDS, key=lambda k: e @ diff_cov[k] @ e)
        sigma = float(np.sqrt(e @ diff_cov[kind] @ e))
        var_pixels = float(e @ pixel_part @ e)
        across = np.eye(3) - np.outer(e, e)
        bias = float(np.trace(across @ diff_cov[kind]) / (2.0 * length))
        note = _length_note(rig, a, b, found, length, sigma, var_pixels / sigma ** 2, depth, bias, pixel_sigma)
        if note:
            warn(note)
        lengths.append({"from": a, "to": b, "length_mm": length, "sigma_mm": sigma,
                        "sigma_percent": 100.0 * sigma / length, "sigma_pixels_mm": float(np.sqrt(var_pixels)),
                        "sigma_calibration_mm": float(np.sqrt(max(e @ dB @ cov_theta[kind] @ dB.T @ e, 0.0))),
                        "bias_mm": bias, "meaningless": note is not None, "warning": note})
    return {"frame": rig.reference, "points": doc_points, "lengths": lengths, "unmeasured_lengths": unmeasured}
