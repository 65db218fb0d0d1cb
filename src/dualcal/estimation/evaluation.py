"""The paper's 3-D check: stereo intersection of the board corners (section 2, Tables 5, 6).

Every board corner that both photos of a pair measured is intersected from them
(:func:`dualcal.estimation.intersect.triangulate`) and compared with the board's known geometry (its shape as
calibrated, :meth:`dualcal.geometry.model.RigModel.board_points_mm`: flat, or bent where the calibration
estimated that), in the board frame, as RMSE per axis. The cases:

* ``dual``: the reference camera and another camera at the same instant (paper case 1), for
  every view both saw. With more than two cameras, ``dual`` pairs the reference with the first
  other camera and ``dual:<camera>`` with each further one.
* ``<camera>``: one camera at two instants (paper cases 2 and 3), for every pair of views. The
  board is the same physical object in both, so both rays live in the board frame.

Orientation of the photos:

* by default the calibration's own poses (as in the paper: the check uses the photos the
  calibration was fitted to);
* ``holdout=True``: each view is left out of the calibration in turn, and its photos are then
  oriented by space resection (:func:`dualcal.geometry.resection.resect`) with the intrinsics and rig that calibration
  found, so no ray comes from a calibration that saw its photo. A pair of two instants takes
  each photo from its own fold. Each fold repeats the full calibration: its settings (skew,
  rig mode, reference, outlier options) and its photos, those it dropped left out.

The pose-free length check (in the spirit of VDI/VDE 2634's length measurement error): in
Tables 5/6 every photo is oriented on the very corners it then checks, so the poses absorb much of
a calibration's error (a focal length 1 % off moves the board 1 % farther, and its corners stay
where they were seen). :func:`pose_free_check` uses no board pose at all: every dual instant's
corners are intersected with the rig alone (the reference camera and another one at the same
instant, ``X_c = R_c X_ref + t_c``), and every corner-to-corner distance is compared with the
board's (:meth:`RigModel.board_points_mm`). Nothing can absorb a wrong focal length, principal
point or relative pose there; a scale error shows in full. With ``holdout`` each instant is
intersected with the calibration that left it out.

eval.json (contract): ``{"cases": {name: {"rmse_mm": [x, y, z], "pairs": N}}}``; added keys:
``points`` per case (corners intersected), ``per_pair`` (each pair's cameras, views and
RMSE), ``holdout``, and the pose-free check: ``pose_free`` ``{case: {"rms_mm", "max_mm",
"lengths", "instants"}}`` (the dual cases: errors of all corner-to-corner lengths, mm) and
``pose_free_per_instant`` (``[{"case", "cameras", "view", "rms_mm", "max_mm", "lengths"}]``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .adjust import RIG_MODES
from ..geometry.camera import CameraModel
from ..errors import EstimationError, InputError
from .intersect import triangulate
from ..geometry.model import CornerSet, Pose, RigModel, observed_mask
from ..progress import progress_bar, warn
from ..geometry.resection import resect

_IDENTITY = Pose(np.eye(3), np.zeros(3))


@dataclass(frozen=True)
class OrientedPhoto:
    """A photo ready for intersection: its camera, pose (board -> camera) and observed corners."""

    camera: CameraModel
    pose: Pose
    uv_px: np.ndarray


# ---------------------------------------------------------------------------- orienting photos


def fitted_photos(rig: RigModel) -> dict[str, dict[str, OrientedPhoto]]:
    """Every photo with the pose the calibration fitted to it, its own camera (:meth:`RigModel.photo_camera`: its
    focus, its stabiliser's shift) and the corners it used: ``[camera][view]``."""
    out = {}
    used = rig.used_corners()
    for cam in rig.cameras:
        corners = used.cameras[cam].found()
        out[cam] = {v: OrientedPhoto(rig.photo_camera(cam, v), pose, corners[v])
                    for v, pose in rig.camera_poses.get(cam, {}).items() if v in corners}
    return out


def resect_view(calib: RigModel, view: str, corners: CornerSet) -> dict[str, OrientedPhoto]:
    """Orient the photos of one view with a calibration: ``{camera: photo}``.

    When the calibration treats the cameras as a rig (rig mode ``rigid`` or ``paper``) they are
    resected together, one board pose for the whole rig, so the rig's relative pose is part of
    what the check tests; in rig mode ``none`` each camera is resected on its own.
    """
    X = calib.board_points_mm()
    photos = {c: cc.found().get(view) for c, cc in corners.cameras.items() if c in calib.cameras}
    seen = {c: uv for c, uv in photos.items() if uv is not None}
    tied = [c for c in seen if calib.rig_mode != "none" and (c == calib.reference or c in calib.rig)]
    groups = ([tied] if tied else []) + [[c] for c in seen if c not in tied]
    out = {}
    for group in groups:
        rel = {c: _IDENTITY if c == calib.reference or len(group) == 1 else calib.rig[c].pose for c in group}
        pose = resect(X, [calib.cameras[c] for c in group], [rel[c] for c in group], [seen[c] for c in group])
        for c in group:
            out[c] = OrientedPhoto(calib.cameras[c], rel[c].compose(pose), seen[c])
    return out


def holdout_photos(rig: RigModel, progress: bool = True,
                   folds: dict[str, RigModel] | None = None) -> dict[str, dict[str, OrientedPhoto]]:
    """Every photo oriented by a calibration that did not see its view (leave one view out).

    Calls :func:`dualcal.estimation.calibrate.calibrate_rig` once per view, as the full calibration was
    run: with the photos and corners it used (:meth:`RigModel.used_corners`) of all other views and its
    settings (skew, rig mode, reference, :meth:`RigModel.calibration_options`: outliers, board shape, lens
    model); then :func:`resect_view` orients the view's used photos. Only views the full calibration
    kept are evaluated. ``folds``, where given, receives each view's calibration (``folds[view]``).
    """
    from .calibrate import calibrate_rig   # the adjustment is only needed here

    if rig.rig_mode not in RIG_MODES:
        raise InputError(f"--holdout recalibrates, which needs a rig mode of {', '.join(RIG_MODES)} "
                         f"(this calibration has {rig.rig_mode!r})")
    options = rig.calibration_options()
    corners = rig.used_corners()
    views = sorted({v for poses in rig.camera_poses.values() for v in poses})
    out: dict[str, dict[str, OrientedPhoto]] = {cam: {} for cam in rig.cameras}
    with progress_bar("hold-out folds", len(views), enabled=progress) as advance:
        for view in views:
            try:
                calib = calibrate_rig(corners.with_views(lambda _, v: v != view), skew=rig.skew,
                                      rig_mode=rig.rig_mode, reference=rig.reference, **options)
            except EstimationError as exc:
                raise EstimationError(f"hold-out calibration without view {view!r} failed: {exc}") from None
            if folds is not None:
                folds[view] = calib
            kept = {c for c, poses in rig.camera_poses.items() if view in poses}
            for cam, photo in resect_view(calib, view, corners).items():
                if cam in kept:
                    out[cam][view] = photo
            advance()
    return out


# ---------------------------------------------------------------------------- the three cases


def case_pairs(photos: dict[str, dict[str, OrientedPhoto]], reference: str) -> dict[str, list[tuple]]:
    """The pairs of each case: ``{case: [((cam_a, view_a), (cam_b, view_b)), ...]}``.

    Order: the dual cases (reference with each other camera, in ``photos`` order), then one
    case per camera (reference first). Cases without a pair are left out.
    """
    others = [c for c in photos if c != reference]
    cases = {}
    if reference in photos:
        for i, cam in enumerate(others):
            shared = sorted(set(photos[reference]) & set(photos[cam]))
            cases["dual" if i == 0 else f"dual:{cam}"] = [((reference, v), (cam, v)) for v in shared]
    for cam in ([reference] if reference in photos else []) + others:
        cases[cam] = [((cam, a), (cam, b)) for a, b in itertools.combinations(sorted(photos[cam]), 2)]
    return {name: pairs for name, pairs in cases.items() if pairs}


def pair_errors(X_board: np.ndarray, a: OrientedPhoto, b: OrientedPhoto) -> np.ndarray:
    """(n, 3) intersected corners minus their board coordinates ``X_board`` (N, 3), mm (board frame),
    for the n corners both photos measured (in corner order).

    Raises
    ------
    EstimationError
        No corner seen in both photos, or a degenerate intersection.
    """
    both = observed_mask(a.uv_px) & observed_mask(b.uv_px)
    if not both.any():
        raise EstimationError("the two photos measured no corner in common")
    X = triangulate([a.camera, b.camera], [a.pose, b.pose], [a.uv_px[both], b.uv_px[both]])
    return X - X_board[both]


def _rmse(err: np.ndarray) -> list[float]:
    return np.sqrt(np.mean(err**2, axis=0)).tolist()


def stereo_cases(X_board: np.ndarray, photos: dict[str, dict[str, OrientedPhoto]], reference: str) -> dict:
    """Intersect every pair of every case against the board's corners ``X_board`` (N, 3): the
    eval.json document (without ``holdout``)."""
    cases, per_pair = {}, []
    for name, pairs in case_pairs(photos, reference).items():
        errors = []
        for (ca, va), (cb, vb) in pairs:
            try:
                err = pair_errors(X_board, photos[ca][va], photos[cb][vb])
            except EstimationError as exc:
                warn(f"case {name}: pair {ca}/{va} + {cb}/{vb} left out: {exc}")
                continue
            errors.append(err)
            per_pair.append({"case": name, "cameras": [ca, cb], "views": [va, vb], "rmse_mm": _rmse(err)})
        if errors:
            all_err = np.vstack(errors)
            cases[name] = {"rmse_mm": _rmse(all_err), "pairs": len(errors), "points": len(all_err)}
    return {"cases": cases, "per_pair": per_pair}


# ---------------------------------------------------------------------------- the pose-free length check


def corner_length_errors(calib: RigModel, cam: str, uv_ref: np.ndarray, uv_cam: np.ndarray,
                         X_board: np.ndarray) -> np.ndarray:
    """Errors (mm) of every corner-to-corner length of one dual instant, intersected with the rig alone.

    The corners both photos measured (the reference camera's ``uv_ref`` and camera ``cam``'s
    ``uv_cam``, (N, 2) with NaN rows) are intersected in the reference camera's frame with
    ``calib``'s intrinsics and relative pose, no board pose; each of the ``n (n - 1) / 2`` distances
    between them minus the same distance of the board's corners ``X_board`` (N, 3).

    Raises
    ------
    EstimationError
        Fewer than two corners in common, or a degenerate intersection.
    """
    if cam not in calib.rig:
        raise EstimationError(f"the calibration has no relative pose of camera {cam!r}")
    both = observed_mask(uv_ref) & observed_mask(uv_cam)
    if both.sum() < 2:
        raise EstimationError(f"the two photos measured {int(both.sum())} corner(s) in common, a length needs two")
    X = triangulate([calib.cameras[calib.reference], calib.cameras[cam]],
                    [_IDENTITY, calib.pose_from_reference(cam)], [uv_ref[both], uv_cam[both]])
    i, j = np.triu_indices(int(both.sum()), 1)
    B = X_board[both]
    return np.linalg.norm(X[i] - X[j], axis=1) - np.linalg.norm(B[i] - B[j], axis=1)


def pose_free_check(rig: RigModel, folds: dict[str, RigModel] | None = None) -> dict:
    """The pose-free length check of every dual instant (module docstring).

    Parameters
    ----------
    rig : the calibration; its used corners (:meth:`RigModel.used_corners`) of the views it kept
        in both cameras are intersected.
    folds : ``{view: calibration}`` to intersect each view with (the hold-out calibrations that
        left it out); default ``rig`` for every view.

    Returns
    -------
    ``{"pose_free": {case: {"rms_mm", "max_mm", "lengths", "instants"}}, "pose_free_per_instant":
    [{"case", "cameras", "view", "rms_mm", "max_mm", "lengths"}]}``; cases are named as in
    :func:`case_pairs` (``dual``, ``dual:<camera>``). An instant that cannot be intersected is
    left out with a warning.
    """
    X_board = rig.board_points_mm()
    used = rig.used_corners().cameras
    ref = rig.reference
    views = {c: {v for v in rig.camera_poses.get(c, {}) if used[c].views.get(v) is not None} for c in rig.cameras}
    cases, per_instant = {}, []
    for i, cam in enumerate(c for c in rig.cameras if c != ref and c in rig.rig):
        name = "dual" if i == 0 else f"dual:{cam}"
        errors = []
        for v in sorted(views[ref] & views[cam]):
            calib = folds[v] if folds is not None else rig
            try:
                err = corner_length_errors(calib, cam, used[ref].views[v], used[cam].views[v], X_board)
            except EstimationError as exc:
                warn(f"pose-free check {name}: instant {v} left out: {exc}")
                continue
            errors.append(err)
            per_instant.append({"case": name, "cameras": [ref, cam], "view": v, **_length_summary(err)})
        if errors:
            cases[name] = {**_length_summary(np.concatenate(errors)), "instants": len(errors)}
    return {"pose_free": cases, "pose_free_per_instant": per_instant}


def _length_summary(err: np.ndarray) -> dict:
    return {"rms_mm": float(np.sqrt(np.mean(err**2))), "max_mm": float(np.max(np.abs(err))), "lengths": len(err)}


def evaluate(rig: RigModel, holdout: bool = False, progress: bool = True) -> dict:
    """The paper's stereo-intersection check of a calibration (module docstring).

    Parameters
    ----------
    rig : RigModel
        a calibration (calib.json content).
    holdout : bool
        orient each view by resection with a calibration that left it out.
    progress : bool
        progress bar over the hold-out folds on stderr.

    Returns
    -------
    dict
        The eval.json document: ``{"cases": {name: {"rmse_mm": [x, y, z], "pairs": N,
        "points": n}}, "per_pair": [...], "holdout": bool}`` and the pose-free check
        (:func:`pose_free_check`: ``pose_free``, ``pose_free_per_instant``). A pair whose
        intersection is degenerate (parallel rays: two photos from one spot) is left out with a
        warning.

    Raises
    ------
    InputError
        A camera named like a case of another kind (``dual`` or ``dual:...``); ``holdout``
        for a calibration of a rig mode :func:`dualcal.estimation.calibrate.calibrate_rig` does not run.
    EstimationError
        No case has a pair, or a hold-out calibration fails.
    """
    clash = [c for c in rig.cameras if c == "dual" or c.startswith("dual:")]
    if clash:
        raise InputError(f"camera {clash[0]!r} takes the name of the evaluation case of two cameras "
                         "('dual', 'dual:<camera>'): give it another name when detecting the corners "
                         "(--camera NAME=GLOB) and calibrate again")
    folds = {} if holdout else None
    photos = holdout_photos(rig, progress, folds) if holdout else fitted_photos(rig)
    doc = stereo_cases(rig.board_points_mm(), photos, rig.reference)
    if not doc["cases"]:
        raise EstimationError("nothing to intersect: no camera has two oriented photos and no view has two cameras")
    doc["holdout"] = bool(holdout)
    return {**doc, **pose_free_check(rig, folds)}
