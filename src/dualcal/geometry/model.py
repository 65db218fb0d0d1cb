"""Data classes for what flows between the stages: corners in, a calibrated rig out.

Conventions (README, "Conventions"): board to camera ``X_cam = R @ X_board + t_mm``; a
non-reference camera ``c`` of a rig sees ``X_c = R_c @ X_ref + t_c``. Poses are plain numpy
arrays; the classes only group them and never hide state.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .board import Board, sag_mm, shaped_points_mm
from .camera import CameraModel, intrinsic_names, project_points
from .focus import FocusModel, camera_at_focus
from .rotation import ARCMIN_PER_RAD, nearest_rotation, opk_from_rotation, rotation_angle_deg


#: calib.json's top-level ``model`` when the cameras' lens models differ.
MIXED_LENS_MODELS = "mixed"


@dataclass
class Pose:
    """A rigid transform ``X_to = R @ X_from + t_mm``."""

    R: np.ndarray
    t_mm: np.ndarray

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Transform (N, 3) points."""
        return np.asarray(X) @ self.R.T + self.t_mm

    def compose(self, first: "Pose") -> "Pose":
        """``self after first``: ``X -> self.apply(first.apply(X))``."""
        return Pose(self.R @ first.R, self.R @ first.t_mm + self.t_mm)

    def inverse(self) -> "Pose":
        """The pose the other way: ``X_from = R^T X_to - R^T t_mm``."""
        return Pose(self.R.T, -self.R.T @ self.t_mm)

    @property
    def center_mm(self) -> np.ndarray:
        """Perspective centre in the 'from' frame: ``-R^T t`` (paper eq. 11)."""
        return -self.R.T @ self.t_mm

    @property
    def opk_arcmin(self) -> np.ndarray:
        """(3,) omega, phi, kappa of ``R = Rz(kappa) Ry(phi) Rx(omega)``, minutes of arc."""
        return opk_from_rotation(self.R) * ARCMIN_PER_RAD

    def to_dict(self) -> dict:
        """``{"R": 3 x 3 list, "t_mm": 3 list}``, as calib.json holds a pose."""
        return {"R": self.R.tolist(), "t_mm": self.t_mm.tolist()}


def stacked(poses) -> tuple[np.ndarray, np.ndarray]:
    """The rotations (n, 3, 3) and translations (n, 3), mm, of ``poses`` as stacks (batched pose algebra)."""
    return np.array([p.R for p in poses]), np.array([p.t_mm for p in poses])


def mean_pose(poses: list[Pose]) -> Pose:
    """Chordal mean of the rotations (nearest rotation to their sum) and mean of the translations."""
    return Pose(nearest_rotation(np.sum([p.R for p in poses], axis=0)), np.mean([p.t_mm for p in poses], axis=0))


#: :func:`consensus_pose` leaves out poses turned by more than this from the medoid (degrees) ...
CONSENSUS_ANGLE_DEG = 5.0
#: ... or moved from it by more than this many times the poses' median distance from it (and 1 mm).
CONSENSUS_SPREAD = 5.0


def consensus_pose(poses: list[Pose]) -> Pose:
    """:func:`mean_pose` of the poses that agree: the medoid (least summed rotation angle to the others) and those
    within :data:`CONSENSUS_ANGLE_DEG` and :data:`CONSENSUS_SPREAD` median distances of it. Where every pose
    agrees, exactly their mean. A start for a rig's relative pose that one gross instant (a board numbered the
    other way round in one photo, seen from behind) does not throw off."""
    R, t = stacked(poses)
    angle = rotation_angle_deg(R[:, None], R[None, :])                  # between each two
    medoid = int(np.argmin(angle.sum(axis=1)))
    moved = np.linalg.norm(t - t[medoid], axis=1)
    agree = (angle[medoid] <= CONSENSUS_ANGLE_DEG) & (moved <= max(CONSENSUS_SPREAD * np.median(moved), 1.0))
    return mean_pose(poses if agree.all() else [p for p, ok in zip(poses, agree) if ok])


def observed_mask(uv_px: np.ndarray) -> np.ndarray:
    """(N,) True for the corners of a view that were measured (rows that are not NaN)."""
    return np.all(np.isfinite(np.asarray(uv_px, float)), axis=-1)


@dataclass
class CameraCorners:
    """Detected corners of one camera: ``views[key]`` is (N, 2) pixels, or None if not found.

    Inside a view, a corner that could not be measured (or was rejected) is a row of NaN: the
    array keeps its length and order, so row k is always corner k (corners.json writes such a
    corner as ``null``, see the contract). ``meta`` holds extra per-camera information carried
    through corners.json (photo paths, EXIF make, model and focal length, ...); keys are written
    as they are.
    """

    image_size: tuple[int, int]
    views: dict[str, np.ndarray | None]
    meta: dict = field(default_factory=dict)

    @property
    def focal_length_mm(self) -> float | None:
        """The lens's focal length its photos' EXIF gives, mm (``meta["exif"]["focal_length_mm"]``); None without."""
        f = (self.meta.get("exif") or {}).get("focal_length_mm")
        return float(f) if isinstance(f, (int, float)) and f > 0 else None

    def found(self) -> dict[str, np.ndarray]:
        """The views where the board was found (at least one corner measured)."""
        return {k: v for k, v in self.views.items() if v is not None and observed_mask(v).any()}


@dataclass
class CornerSet:
    """The content of a corners.json: a board and each camera's corners per view key; ``roll`` is the
    record of a camera roll's split into cameras and instants (:mod:`dualcal.files.roll`), or None."""

    board: Board
    cameras: dict[str, CameraCorners]
    reference: str | None = None     # the reference camera chosen at detection, if one was given
    roll: dict | None = None

    def cameras_alone(self) -> list[str]:
        """The cameras whose view keys name no moment shared with the other cameras: each filmed the board on its
        own (an imported caliscope intrinsic session: ``meta["imported"]["instants_shared"]`` false)."""
        return [name for name, cam in self.cameras.items()
                if (cam.meta.get("imported") or {}).get("instants_shared") is False]

    def with_views(self, keep: Callable[[str, str], bool]) -> "CornerSet":
        """The same corners with only the photos for which ``keep(camera, view)`` is true."""
        cams = {name: CameraCorners(c.image_size, {v: uv for v, uv in c.views.items() if keep(name, v)}, c.meta)
                for name, c in self.cameras.items()}
        return replace(self, cameras=cams)


#: How a camera's known intrinsics enter its calibration (:class:`KnownIntrinsics`).
INTRINSICS_USES = ("prior", "fixed")


@dataclass(frozen=True, eq=False)
class KnownIntrinsics:
    """A camera's intrinsics known before its calibration (``dualcal calibrate --intrinsics FILE``).

    ``camera`` is the lens model and its values. ``use`` says how they enter the calibration: ``"prior"``, each
    value observed with its 1-sigma ``sigma`` (``{name: sigma}``, names of
    :func:`~dualcal.geometry.camera.intrinsic_names` of the model), or jointly with ``covariance`` ((k, k), over
    the names ``parameters``) where the source has one; ``"fixed"``, held at these values (a source without any
    uncertainty). In a prior given by ``sigma`` alone, the values with a sigma above 0 are its ``parameters``,
    with a diagonal ``covariance`` (set here); a free intrinsic of the model outside ``parameters`` is estimated
    from the photos alone. ``source`` names the file they came from. ``mode`` and ``names`` are ``use`` and
    ``parameters`` as the adjustment reads them (:mod:`dualcal.estimation.adjust`). ``photos`` ``{view: (N, 2)}``
    are the corners the source calibrated the camera from, where it says (a calib.json): a prior from the same
    photos would count their information twice.

    Raises
    ------
    ValueError
        An unknown ``use``, a prior without a sigma or covariance, a fixed camera with one, a sigma or a
        covariance's name that is not an intrinsic of the lens model, or a covariance of the wrong shape.
    """

    camera: CameraModel
    use: str = "fixed"
    sigma: dict[str, float] = field(default_factory=dict)
    parameters: tuple[str, ...] = ()
    covariance: np.ndarray | None = None
    source: str = ""
    photos: dict[str, np.ndarray] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        if self.use not in INTRINSICS_USES:
            raise ValueError(f"use {self.use!r} is not one of {', '.join(INTRINSICS_USES)}")
        uncertain = bool(self.sigma) or self.covariance is not None
        if uncertain != (self.use == "prior"):
            raise ValueError("a prior needs a sigma or a covariance, and only a prior has one")
        names = intrinsic_names(self.camera.model)
        foreign = [n for n in (*self.sigma, *self.parameters) if n not in names]
        if foreign:
            raise ValueError(f"{', '.join(foreign)}: not intrinsics of lens model {self.camera.model}")
        if self.use == "prior" and self.covariance is None:           # independent sigmas: a diagonal covariance
            given = tuple(n for n in names if self.sigma.get(n, 0.0) > 0)
            if not given:
                raise ValueError("a prior needs a sigma above 0")
            object.__setattr__(self, "parameters", given)
            object.__setattr__(self, "covariance", np.diag([self.sigma[n] ** 2 for n in given]))
        k = len(self.parameters)
        if (self.covariance is None) != (k == 0) or (k and np.shape(self.covariance) != (k, k)):
            raise ValueError(f"covariance of shape {np.shape(self.covariance)} for {k} parameters")

    def photos_in(self, views: Mapping[str, np.ndarray | None], tol_px: float = 0.01) -> list[str]:
        """The views of ``views`` (a camera's corners, ``{view: (N, 2) or None}``) that are photos the source
        calibrated this camera from: the same view with the same corners (within ``tol_px``)."""
        same = []
        for v, uv in views.items():
            old = self.photos.get(v)
            if uv is None or old is None or np.shape(old) != np.shape(uv):
                continue
            a, b = np.asarray(uv, float), np.asarray(old, float)
            seen = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
            if seen.any() and np.max(np.abs(a[seen] - b[seen])) <= tol_px:
                same.append(v)
        return same

    @property
    def mode(self) -> str:
        """``"prior"`` or ``"fixed"`` (``use``)."""
        return self.use

    @property
    def names(self) -> tuple[str, ...]:
        """The intrinsics the prior's ``covariance`` is over (``parameters``; none when fixed)."""
        return self.parameters

    def to_dict(self) -> dict:
        """``{"mode", "image_size", "model", "values": {intrinsic: value}, "names", "covariance", "source"}`` (JSON),
        as calib.json's ``adjustment.known_intrinsics`` records each camera."""
        return {"mode": self.use, "image_size": list(self.camera.image_size), "model": self.camera.model,
                "values": {n: float(getattr(self.camera, n)) for n in intrinsic_names(self.camera.model)},
                "names": list(self.parameters),
                "covariance": None if self.covariance is None else np.asarray(self.covariance, float).tolist(),
                "source": self.source}

    @classmethod
    def from_dict(cls, doc: dict) -> "KnownIntrinsics":
        """The record :meth:`to_dict` wrote."""
        camera = CameraModel(tuple(doc["image_size"]), model=doc["model"], **doc["values"])
        if doc.get("covariance") is None:
            return cls(camera, source=doc.get("source", ""))
        return cls(camera, "prior", parameters=tuple(doc["names"]), covariance=np.asarray(doc["covariance"], float),
                   source=doc.get("source", ""))


def choose_reference(names, override: str | None = None) -> str:
    """The reference camera: ``override``, else ``wide`` if present, else the first sorted name."""
    names = sorted(names)
    if override is not None:
        if override not in names:
            from ..errors import InputError
            raise InputError(f"--reference {override!r} is not a camera here (cameras: {', '.join(names)})")
        return override
    return "wide" if "wide" in names else names[0]


@dataclass
class RigRelation:
    """Pose of a non-reference camera relative to the reference, with 1-sigma uncertainties.

    ``sigma_*`` are the sigmas that hold on real photos (as ``RigModel.camera_sigma``); ``sigma_formal``
    the textbook ones, ``{"t_mm": (3,), "baseline_mm": float, "opk_arcmin": (3,)}`` (empty when
    unknown).
    """

    pose: Pose
    sigma_t_mm: np.ndarray
    sigma_baseline_mm: float
    sigma_opk_arcmin: np.ndarray
    sigma_formal: dict = field(default_factory=dict)

    @property
    def baseline_mm(self) -> float:
        """Distance between the perspective centres: ``|t_c|``."""
        return float(np.linalg.norm(self.pose.t_mm))


@dataclass
class RigModel:
    """A calibrated rig: the content of calib.json.

    ``camera_poses[cam][view]`` is the board-to-camera pose of every camera in every view it
    saw; ``views[view]`` (the contract's ``views``) is the reference camera's.

    ``camera_sigma`` holds the 1-sigmas that hold on real photos (the larger of the one from the
    covariance clustered by instant, :mod:`dualcal.estimation.uncertainty`, and the textbook one),
    ``camera_sigma_formal`` the textbook ones. Where the
    board's shape was estimated, ``board_shape_mm`` (3,) holds its coefficients
    (:data:`dualcal.geometry.board.SHAPE_TERMS`) and ``board_shape_sigma_mm`` their sigmas; None for a flat
    board. ``dropped_corners`` lists the single corners the calibration left out
    (``{"camera", "view", "corner", "residual_px"}``), ``checks`` the named checks of the result
    (:mod:`dualcal.estimation.checks`), ``covariance`` the joint covariance of the calibrated parameters
    (``{"parameters": [names], "clustered": (k, k), "formal": (k, k)}``) or None.

    The lens's motion (:mod:`dualcal.geometry.focus`, :mod:`dualcal.estimation.ois`): ``focus_models`` ``{camera:
    FocusModel}`` of the cameras whose focus is modelled (their ``cameras`` entry is at the model's ``focus_m``),
    ``photo_focus_m`` ``{camera: {view: m}}`` where each of their calibration photos focused, ``ois_sigma_px``
    ``{camera: px}`` the spread of the stabiliser's shift of the principal point from photo to photo (0: none seen;
    cameras not judged are not named) and ``ois_shift_px`` ``{camera: {view: (2,)}}`` each calibration photo's
    shift. :meth:`photo_camera` is a calibration photo's own camera.
    """

    board: Board
    reference: str
    skew: bool
    rig_mode: str
    cameras: dict[str, CameraModel]
    camera_sigma: dict[str, dict[str, float]]
    camera_rms_px: dict[str, float]
    rig: dict[str, RigRelation]
    camera_poses: dict[str, dict[str, Pose]]
    view_rms_px: dict[str, dict[str, float]]
    rms_px: float
    corners: CornerSet
    adjustment: dict = field(default_factory=dict)
    dropped_views: list[dict] = field(default_factory=list)
    camera_sigma_formal: dict[str, dict[str, float]] = field(default_factory=dict)
    board_shape_mm: np.ndarray | None = None
    board_shape_sigma_mm: np.ndarray | None = None
    dropped_corners: list[dict] = field(default_factory=list)
    checks: dict = field(default_factory=dict)
    covariance: dict | None = None
    focus_models: dict[str, FocusModel] = field(default_factory=dict)
    photo_focus_m: dict[str, dict[str, float]] = field(default_factory=dict)
    ois_sigma_px: dict[str, float] = field(default_factory=dict)
    ois_shift_px: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    def photo_camera(self, name: str, view: str) -> CameraModel:
        """Camera ``name`` as it took its calibration photo of ``view``: at that photo's focus where its focus is
        modelled, its principal point moved by that photo's stabiliser shift where it has one; else ``cameras[name]``."""
        cam = self.cameras[name]
        focus = self.photo_focus_m.get(name, {}).get(view)
        if name in self.focus_models and focus is not None:
            cam = camera_at_focus(cam, self.focus_models[name], focus)
        shift = self.ois_shift_px.get(name, {}).get(view)
        if shift is not None:
            cam = replace(cam, cx=cam.cx + float(shift[0]), cy=cam.cy + float(shift[1]))
        return cam

    @property
    def model(self) -> str:
        """The cameras' common lens model (calib.json's ``model``), or ``"mixed"`` (:attr:`models`)."""
        models = set(self.models.values())
        return models.pop() if len(models) == 1 else MIXED_LENS_MODELS

    @property
    def models(self) -> dict[str, str]:
        """``{camera: its lens model}`` (calib.json's ``cameras.<name>.model``)."""
        return {name: cam.model for name, cam in self.cameras.items()}

    def calibration_options(self) -> dict:
        """The options the calibration ran with (``adjustment["options"]``: ``drop_outliers``,
        ``outlier_factor``, ``board_shape``, ``model``: :func:`dualcal.estimation.calibrate.calibrate_rig`'s keyword
        arguments); files written before one was recorded get its default."""
        return {"drop_outliers": True, "outlier_factor": 6.0, "board_shape": "auto",
                "model": self.model if self.model != MIXED_LENS_MODELS else self.models,
                **self.adjustment.get("options", {})}

    def board_points_mm(self) -> np.ndarray:
        """(N, 3) the board's corners as calibrated: flat, or shaped by ``board_shape_mm``."""
        return shaped_points_mm(self.board.object_points_mm(), self.board_shape_mm)

    def board_sag_mm(self) -> float | None:
        """How far the calibrated board's corners are off a plane (:func:`dualcal.geometry.board.sag_mm`); None
        where its shape was not estimated."""
        if self.board_shape_mm is None:
            return None
        return sag_mm(self.board.object_points_mm(), self.board_shape_mm)

    def used_corners(self) -> CornerSet:
        """The corners the calibration used: ``corners`` without the photos it dropped
        (``dropped_views``; an entry without a camera drops the view in every camera) and with the
        single corners it dropped (``dropped_corners``) set to NaN."""
        views_out = {(d.get("camera"), d.get("view")) for d in self.dropped_views}
        corners_out: dict[tuple[str, str], list[int]] = {}
        for d in self.dropped_corners:
            corners_out.setdefault((d["camera"], d["view"]), []).append(int(d["corner"]))
        cams = {}
        for name, cc in self.corners.cameras.items():
            views = {}
            for v, uv in cc.views.items():
                if (name, v) in views_out or (None, v) in views_out:
                    continue
                if uv is not None and (name, v) in corners_out:
                    uv = np.array(uv, float)
                    uv[corners_out[(name, v)]] = np.nan
                views[v] = uv
            cams[name] = CameraCorners(cc.image_size, views, cc.meta)
        return replace(self.corners, cameras=cams)

    def camera_order(self) -> list[str]:
        """Camera names, the reference first, then the others in calib.json's order."""
        return [self.reference] + [name for name in self.cameras if name != self.reference]

    def pose_from_reference(self, name: str) -> Pose:
        """``X_cam = R X_ref + t_mm`` for camera ``name`` (identity for the reference camera)."""
        if name == self.reference:
            return Pose(np.eye(3), np.zeros(3))
        return self.rig[name].pose

    def reference_poses(self) -> dict[str, Pose]:
        """Board-to-reference-camera pose per view (derived through the rig where needed)."""
        out = dict(self.camera_poses.get(self.reference, {}))
        for cam, rel in self.rig.items():
            for view, pose in self.camera_poses.get(cam, {}).items():
                if view not in out:
                    out[view] = rel.pose.inverse().compose(pose)
        return dict(sorted(out.items()))

    def board_distances_mm(self) -> np.ndarray:
        """(views,) distance of the board's centre from the reference camera in every view, mm."""
        centre = self.board.object_points_mm().mean(axis=0)
        return np.array([np.linalg.norm(p.apply(centre[None])[0]) for p in self.reference_poses().values()])


# ---------------------------------------------------------------------------- residuals of a calibration


@dataclass(frozen=True)
class ViewResiduals:
    """Measured corners of one camera in one view: ``uv_px`` observed (M, 2), ``residual_px`` (M, 2).

    Corners that were not measured (NaN rows, :func:`dualcal.geometry.model.observed_mask`) are not in them.
    """

    uv_px: np.ndarray
    residual_px: np.ndarray

    @property
    def rms_px(self) -> float:
        return rms_px(self.residual_px)


def rms_px(residual_px: np.ndarray) -> float:
    """Root mean square length of (N, 2) residual vectors, ``sqrt(mean(du^2 + dv^2))``."""
    residual_px = np.asarray(residual_px, float).reshape(-1, 2)
    if len(residual_px) == 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum(residual_px**2, axis=1))))


def rig_residuals(rig: RigModel) -> dict[str, dict[str, ViewResiduals]]:
    """Residuals ``[camera][view]`` of every view that has both detected corners and a pose.

    Views without a pose (not found, or dropped by the calibration) are left out; views are
    in sorted key order; corners not measured (NaN rows) or dropped by the calibration are left
    out of each view; the board is the one calibrated (:meth:`RigModel.board_points_mm`), each photo's camera its
    own (:meth:`RigModel.photo_camera`: its focus, its stabiliser's shift).
    """
    X_board = rig.board_points_mm()
    used = rig.used_corners()
    out: dict[str, dict[str, ViewResiduals]] = {}
    for name in rig.cameras:
        found = used.cameras[name].found() if name in used.cameras else {}
        poses = rig.camera_poses.get(name, {})
        views = {}
        for view in sorted(set(found) & set(poses)):
            measured = observed_mask(found[view])
            uv = np.asarray(found[view], float)[measured]
            uv_model = project_points(rig.photo_camera(name, view), poses[view].apply(X_board[measured]))
            views[view] = ViewResiduals(uv, uv - uv_model)
        out[name] = views
    return out
