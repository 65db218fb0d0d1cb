"""Focus as part of the lens, estimated: where each photo focused, whether a lens breathes, and a camera at any focus.

The model is :mod:`dualcal.geometry.focus`'s: a thin lens at the EXIF focal length ``f`` whose focal lengths grow by
``b f / (d - f)`` as it focuses at ``d``, ``b`` a breathing coefficient per camera. Its pieces here:

* :func:`photo_focus`: each calibration photo's focus, from its metadata where corners.json's camera ``meta`` holds
  it (``focus_m``, ``{view: m}``, read at detection from the Apple MakerNote or EXIF ``SubjectDistance``:
  :func:`dualcal.files.photos.read_focus`), else the board's distance along the camera's axis in it (autofocus
  focuses on the board); each camera's reference focus ``d0`` is its photos' median. A camera is a candidate
  where its EXIF focal length is known and its photos' focus spans more than :data:`MIN_FOCUS_SPAN`.
* :func:`with_breathing`, a stage of the calibration (:mod:`dualcal.estimation.calibrate`): the candidates' ``b``
  estimated with the rest and kept where they differ from 0 beyond the photos' noise (:func:`breathing_test`: the
  test of the board's shape, :mod:`dualcal.estimation.board_shape`, one coefficient per camera). A lens whose focus
  the photos do not show is not modelled: its calibration holds at the focus it was made at.
* :func:`camera_at_focus` and :func:`covariance_at_focus`: a camera at another focus, for measuring with new photos. The
  focal lengths at ``d`` are ``g(d) fx0``; their covariance follows from ``fx0``'s and ``b``'s by ``J C J^T``
  (``d fx / d fx0 = g``, ``d fx / d b = fx0 dg/db``), so the sigma grows with ``|dg/db|``, which grows with
  ``|1/(d - f) - 1/(d0 - f)|``: the further from the calibration's focus, the larger. Outside the calibration
  photos' focus range a warning says it is an extrapolation. :func:`covariance_at_focus` also gives every camera whose
  photos shift with the stabiliser (:mod:`dualcal.estimation.ois`) its spread in its principal point's variance:
  a new photo's principal point is uncertain by ``sigma_ois``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .adjust import Solution
from .board_shape import SHAPE_FULL_TEST, SHAPE_SIGNIFICANCE
from .covariance import KINDS, JointCovariance, breathing_name, intrinsic_name
from .distributions import f_quantile
from .fitting import Setup
from ..geometry.focus import PhotoFocus
from ..geometry.focus import camera_at_focus as _at_focus
from ..geometry.model import CornerSet, RigModel
from ..geometry.camera import CameraModel
from ..progress import warn

__all__ = ["MIN_FOCUS_SPAN", "breathing_test", "camera_at_focus", "covariance_at_focus", "photo_focus",
           "rig_at_focus", "with_breathing"]

#: A camera's photos show its breathing only where their focus spans more than this share (farthest over nearest,
#: less 1): photos all focused alike (focus locked) say nothing of it.
MIN_FOCUS_SPAN = 0.05


def photo_focus(corners: CornerSet, sol: Solution) -> PhotoFocus | None:
    """Each photo of ``sol`` focused (module docstring): from its camera's ``meta["focus_m"]`` where stated, else
    the board centre's depth in the camera (``sol``'s pose of the photo). Cameras without an EXIF focal length
    (``meta["exif"]["focal_length_mm"]``) are left out; None where none is left."""
    p = sol.problem
    centre = p.X_board.mean(axis=0)
    focal, reference, focus, source = {}, {}, {}, {}
    for c, name in enumerate(p.cameras):
        f_mm = corners.cameras[name].focal_length_mm
        if f_mm is None:
            continue
        stated = corners.cameras[name].meta.get("focus_m") or {}
        for cc, v, _ in p.blocks:
            if cc != c:
                continue
            d = stated.get(v)
            if isinstance(d, (int, float)) and np.isfinite(d) and 1000.0 * d > 2.0 * f_mm:
                focus[name, v], source[name, v] = 1000.0 * float(d), "metadata"
            else:
                focus[name, v] = float(sol.photo_poses[c, v].apply(centre[None])[0, 2])
                source[name, v] = "board"
        focal[name] = f_mm
        reference[name] = float(np.median([d for (n, _), d in focus.items() if n == name]))
    return PhotoFocus(focal, reference, focus, source) if focal else None


def _spans(focus: PhotoFocus, name: str) -> bool:
    seen = [d for (n, _), d in focus.focus_mm.items() if n == name]
    return max(seen) > (1.0 + MIN_FOCUS_SPAN) * min(seen)


#: The name of the breathing test (calib.json ``adjustment.lens_motion.breathing.test``).
BREATHING_TEST = ("Hotelling's test of the cameras' breathing coefficients together, against their covariance "
                  f"(significance {SHAPE_SIGNIFICANCE:g})")


def breathing_test(sol: Solution, one_step: bool = False) -> dict:
    """Whether the breathing coefficients of ``sol`` differ from 0 beyond the photos' noise.

    As :func:`dualcal.estimation.board_shape.board_shape_test` judges the board's shape: the ``p`` coefficients ``b``
    at the linearised minimum, ``T2 = b^T C^-1 b`` against ``p (G - 1) / (G - p) F(p, G - p)`` at
    :data:`dualcal.estimation.board_shape.SHAPE_SIGNIFICANCE` (``G`` instants), ``C`` their covariance clustered by
    instant or the textbook one, whichever gives the smaller ``T2`` (the larger uncertainty, as every sigma dualcal
    reports is the larger of the two). The cameras are judged together: in a rig they share their photos' poses,
    so one lens's breathing left out would bend another's coefficient. Returns ``{"t2", "limit", "significant",
    "estimate", "cameras": {camera: {"breathing", "sigma"}}}`` (``limit`` None and not significant with too few
    instants, ``G <= p + 1``).
    """
    p, lay = sol.problem, sol.problem.layout
    cols = np.array([lay.breathing[c][0] for c in sorted(lay.breathing)])
    b = sol.state.breathing[sorted(lay.breathing)] + sol.factorization.step()[cols]
    covs = [sol.covariance(cols, kind) for kind in KINDS]
    sigma = np.sqrt(np.max([np.diag(C) for C in covs], axis=0))
    doc = {"estimate": "one-step" if one_step else "adjusted",
           "cameras": {p.cameras[c]: {"breathing": float(x), "sigma": float(s)}
                       for c, x, s in zip(sorted(lay.breathing), b, sigma)}}
    k, G = len(cols), len(p.views)
    if G <= k + 1:
        return {**doc, "t2": None, "limit": None, "significant": False}
    t2 = min(float(b @ np.linalg.lstsq(C, b, rcond=None)[0]) for C in covs)
    limit = float(k * (G - 1) / (G - k) * f_quantile(k, G - k, 1.0 - SHAPE_SIGNIFICANCE))
    return {**doc, "t2": t2, "limit": limit, "significant": bool(t2 > limit)}


def with_breathing(setup: Setup, flat: Solution, focus: PhotoFocus | None) -> tuple[Setup, dict | None]:
    """``setup`` with the breathing of its cameras where the photos show it (module docstring), from ``flat`` (a
    solution of ``setup``), and the record of the test (calib.json ``adjustment.lens_motion.breathing``; None
    where no camera could be judged: no focal length, or a focus that does not move).

    The test is made first at the one-step estimate from ``flat`` and, where its ``T2`` is above
    :data:`dualcal.estimation.board_shape.SHAPE_FULL_TEST` of its limit, at the full adjustment. Every camera judged
    is modelled where the test is significant.
    """
    candidates = tuple(n for n in setup.names if focus is not None and n in focus.focal_mm and _spans(focus, n))
    if not candidates:
        return setup, None
    trial = replace(setup, focus=focus, breathing=candidates)
    blocks, shape = flat.problem.blocks, flat.problem.board_shape
    test = breathing_test(trial.linearised(flat, shape), one_step=True)
    if test["limit"] is not None and test["t2"] > SHAPE_FULL_TEST * test["limit"]:
        test = breathing_test(trial.solve(blocks, flat, board_shape=shape))
    sources = {n: {s: sum(1 for (cam, _), x in focus.source.items() if cam == n and x == s)
                   for s in ("metadata", "board")} for n in candidates}
    record = {"test": BREATHING_TEST, **test, "focus_from": sources}
    return (trial if test["significant"] else setup), record


# ---------------------------------------------------------------------------- a camera at another focus


def camera_at_focus(rig: RigModel, camera_name: str, focus_m: float | None) -> CameraModel:
    """Camera ``camera_name`` of ``rig`` as it is in a photo focused at ``focus_m`` metres: its focal lengths at
    that focus where the calibration models its focus (:mod:`dualcal.geometry.focus`); the calibration's camera
    where it does not, or where the focus is not known (None). A focus outside the calibration photos' range is an
    extrapolation, and a warning says so."""
    model = rig.focus_models.get(camera_name)
    if model is None or focus_m is None:
        return rig.cameras[camera_name]
    if model.outside(focus_m):
        lo, hi = model.focus_range_m
        warn(f"camera {camera_name!r}: focus {focus_m:.2f} m is outside its calibration photos' {lo:.2f}-{hi:.2f} m: "
             "its focal length there is extrapolated by the focus model, and its sigma grows with the distance "
             "(calibrate with the board nearer or farther too, to measure there)")
    return _at_focus(rig.cameras[camera_name], model, focus_m)


def covariance_at_focus(rig: RigModel, focus_m: dict[str, float | None]) -> dict | None:
    """``rig``'s joint covariance (calib.json's ``covariance``) for photos focused at ``focus_m`` ``{camera: m or
    None}`` (module docstring): the intrinsics of each camera whose focus is modelled carried to that focus, and the
    stabiliser's spread of every camera whose photos shift added to its principal point's variance. ``rig``'s own
    where neither applies (or it has none)."""
    moved = {c: rig.focus_models[c] for c, d in focus_m.items() if d is not None and c in rig.focus_models}
    shifting = {c: s for c, s in rig.ois_sigma_px.items() if s > 0}
    if rig.covariance is None or not (moved or shifting):
        return rig.covariance
    cov = JointCovariance.from_dict(rig.covariance)
    where = {n: i for i, n in enumerate(cov.parameters)}
    J = np.eye(len(where))
    for c, model in moved.items():
        g, dg = float(model.scale(focus_m[c])), float(model.scale_per_breathing(focus_m[c]))
        for n in ("fx", "fy", "skew"):
            i = where.get(intrinsic_name(c, n))
            if i is not None:
                J[i, i] = g
                if breathing_name(c) in where:
                    J[i, where[breathing_name(c)]] = getattr(rig.cameras[c], n) * dg
    added = np.zeros(len(where))
    for c, s in shifting.items():
        for n in ("cx", "cy"):
            if intrinsic_name(c, n) in where:
                added[where[intrinsic_name(c, n)]] = s * s
    matrices = {k: J @ np.asarray(cov.matrices[k]) @ J.T + np.diag(added) for k in KINDS}
    return JointCovariance(cov.parameters, matrices).to_dict()


def rig_at_focus(rig: RigModel, focus_m: dict[str, float | None]) -> RigModel:
    """``rig`` as in photos focused at ``focus_m`` ``{camera: m or None}``: the cameras :func:`camera_at_focus`, the
    covariance :func:`covariance_at_focus` (for a rectification or an undistortion of those photos)."""
    return replace(rig, cameras={c: camera_at_focus(rig, c, focus_m.get(c)) for c in rig.cameras},
                   covariance=covariance_at_focus(rig, focus_m))
