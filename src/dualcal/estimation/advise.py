"""Which photo next: board poses that shrink a calibration's honest uncertainty the most.

The calibration's covariance ``C`` of its global parameters (every camera's intrinsics, the rig's
relative rotations and translations, the board's shape; calib.json ``covariance``) says how well
each is known. A new instant (one photo per camera that sees the board) at board pose ``P`` adds
the information of its corners,

    I(P) = A_g^T (I - A_l (A_l^T A_l)^-1 A_l^T) A_g / sigma^2,

with ``A_g``, ``A_l`` the exact Jacobians (:func:`dualcal.geometry.camera.project_with_jacobians`) of its
predicted corners with respect to the global parameters and to the instant's own pose, a nuisance
eliminated by the Schur complement (the projection), in the normal equations' units. The covariance
once it is taken is ``(C^-1 + I(P))^-1`` in closed form (no re-solve), and the next pose is chosen
assuming this one was taken (greedy).

Honest noise. A new corner's noise is its camera's level in the terms of the textbook covariance
``C = s0^2 N^-1`` that the update works on: ``s0``, the calibration's a-posteriori sigma of a corner of a
photo of weight 1, times the camera's noise over the reference noise where the calibration weighs each photo
by its own noise (:mod:`dualcal.estimation.photo_noise`; :func:`photo_noise_px` for its own photos). On
real photos the errors of one photo's corners are correlated, and the calibration measured by how much: for
each target the
ratio ``kappa`` of its honest sigma (the larger of the clustered-by-instant and the textbook one,
:mod:`dualcal.estimation.uncertainty`, as calib.json reports it) to its textbook one. A new photo brings the
same photo-level noise, so its information enters with noise ``kappa s0`` for that target: the
honest sigma after is ``kappa`` times the textbook one after. (On synthetic sets of 5 photos this
predicts the honest key sigmas of the calibration that includes the photo to within 10 % on average
over draws, where weighting the whole update by one camera-wide factor was 18-30 % off: the clustered
part is a per-parameter quantity.)

Targets are linear functions ``g^T theta`` of the parameters, their sigma ``sqrt(g^T C g)``:
every intrinsic, ``<camera>.distortion_edge_px`` (the lens's displacement at the image corner
farthest from the principal point, along the radius: what the distortion terms together do where
the image needs them most), ``<camera>.baseline_mm`` and ``<camera>.omega_arcmin`` /
``phi_arcmin`` / ``kappa_arcmin`` of the rig. The default objective is the geometric mean of the
key targets' sigmas relative to their current values (focal lengths, principal points, edge
distortion, baseline, angles), first within each camera, then over the cameras, so a camera with
few targets is not forgotten; with goals (``--target NAME=SIGMA``) it is how far the sigmas are
above their goals (geometric mean of ``max(sigma / goal, 1)``).

No camera left behind. A geometric mean lets a large gain on some parameters pay for leaving another
where it was, and a greedy choice made one photo at a time remembers nothing: a photo seen by the wide
alone that halves its principal point's sigma wins over one that shrinks every sigma a little, again
and again, and the tele's principal point and the rig's angles fall behind what as many ordinary photos
would have given them. So without goals the poses are ranked by the objective plus :data:`LAG_WEIGHT`
times the lag of the key target that lags most, ``max(log(sigma / due), 0)``, where a target's due after
``s`` advised photos is :data:`DUE_FACTOR` times its sigma after ``s`` more photos like the calibration's
own: its ``n`` instants' information is ``C^-1``, so ``s`` more like them make it ``C^-1 (n + s) / n`` and
every sigma ``sqrt(n / (n + s))`` of what it is now (:func:`_dues`; for a plan, which has no photos, the
average candidate every camera sees, :func:`random_information`). Each advised photo must so shrink
every key sigma at least as much as an ordinary photo would (5 % more), where one pose can; among those
the objective decides. The gain reported is the objective's alone, and ``done`` says that no pose would
shrink the objective by :data:`STOP_GAIN`.

Candidates are poses a person can hold (:func:`holdable`): the board in front of the reference
camera, its centre within 0.67-1.5 times the distance range the calibration's photos span, at most
60 degrees from facing that camera. Each is aimed at one camera: along the ray of a pixel (half of them
near the image's centre), tilted and turned at random, and placed where that camera sees the whole board
nearest (:func:`_nearest_whole_mm`), or farther (:func:`candidate_poses`). A narrow camera's principal
point and lens show in views that fill its frame, tilted: drawn at random distances, the tele of a
wide + 2.8 x tele rig saw 2 of its 114 candidates fill 80 % of its frame and none tilted 40 degrees or
more (35 and 7 of 263 placed so), and the advice followed with whole-board photos left its principal
point behind random photos (``tests/test_advise.py``).

Which cameras see a pose: those that would detect the board in it (:func:`seen_corners`). A plain
chessboard only whole, its outline inside the frame by a margin (:func:`frame_margin_px`: where the
calibration knows the lens too little to say where the outline falls, or where a board held
:data:`HOLD_SHARE` of its distance off would leave the frame: three times as far across a 3 x tele's
frame as across the wide's); a ChArUco board in part (:data:`CHARUCO_SHARE` of its corners); either only
with every square at least :data:`MIN_SQUARE_PX` long in the image and at most :data:`MAX_VIEW_DEG` from
facing the camera (:func:`detectable`). A camera counted where it would not find the board is
information the calibration never gets.

Lens-model agnostic: the cameras are projected only through ``project_with_jacobians`` and their
coefficients are those calib.json's covariance names.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.board import Board, shape_basis, shaped_points_mm
from ..geometry.camera import (INTRINSIC_NAMES, CameraModel, focal_px_from_35mm, in_frame, pixel_rays,
                               project_points, project_with_jacobians, radial_lens_gradient)
from .covariance import JointCovariance, intrinsic_name, rig_name
from ..errors import InputError
from ..geometry.model import Pose, RigModel
from ..geometry.poses import opk_jacobian, tangent_basis
from ..geometry.rotation import ARCMIN_PER_RAD, cross_matrix, opk_from_rotation, rotation_from_rotvec
from ..geometry.scale import relative_sigma, with_scale

#: The distance range of holdable poses, as factors of the range the calibration's photos span.
DISTANCE_FACTORS = (0.67, 1.5)
#: The largest angle between the board's normal and its line of sight to the reference camera.
MAX_TILT_DEG = 60.0
#: A camera sees a ChArUco board when it sees at least this share of its corners (and 6 of them).
CHARUCO_SHARE = 0.5
MIN_CHARUCO_CORNERS = 6
#: A chessboard's outer squares stay this share of the frame's shorter side inside it, or twice the
#: sigma of where they fall as far as the lens is known, up to MAX_FRAME_MARGIN: a board held a little
#: off, or a lens a little different from the calibration's estimate, still shows it whole.
FRAME_MARGIN = 0.03
MAX_FRAME_MARGIN = 0.10
#: How far from an advised pose a person may hold the board, across the line of sight, as a share of its
#: distance (1.5 cm at 1 m): the frame's margin keeps the whole board in view of a camera even so.
HOLD_SHARE = 0.015
#: ``done`` without goals: the best next photo shrinks the objective by less than this share.
STOP_GAIN = 0.02
#: Candidate poses drawn per camera.
CANDIDATES_PER_CAMERA = 250
#: Of them, the share centred near the middle of that camera's image (the others anywhere in its central 80 %),
#: and the share placed farther than where it sees the whole board nearest.
CENTRED_SHARE = 0.5
FARTHER_SHARE = 0.5
#: Steps of the bisection for that distance (its log range halved each time: 2^-10 of it, under 0.1 %).
BISECTIONS = 10
#: A detector finds a chessboard's corners where every square is at least this long in the image (OpenCV's
#: detectors need about 10 pixels a square, :mod:`dualcal.files.detect.pipeline`; 12 leaves room for a lens
#: known only so well at the image's edge, whose squares there may be 8 % smaller than predicted after 5
#: photos of the 640 x 480 pair) and the board is at most :data:`MAX_VIEW_DEG` from facing the camera.
MIN_SQUARE_PX = 12.0
MAX_VIEW_DEG = 70.0
#: The default ranking's weight of the most-lagging key target's lag (module docstring): how much of the
#: objective's log a pose may give up per log of lag; 0: the objective alone. (``benchmarks/bench_advise.py``
#: on seeds 100-105 of its five rigs, key sigmas advised / random, their geometric mean and the largest, the
#: tele's kappa angle on every rig but the pair: 0: 0.23-0.30, 0.79-0.87; 4: 0.23-0.30, 0.67-0.76.)
LAG_WEIGHT = 4.0
#: A key target's due is this share of its sigma after as many photos like the calibration's own (5 % to
#: spare: the honest sigma after a few photos scatters about its prediction).
DUE_FACTOR = 0.95
#: The key targets of the default objective, per camera.
KEY_INTRINSICS = ("fx", "fy", "cx", "cy")
RIG_TARGETS = ("baseline_mm", "omega_arcmin", "phi_arcmin", "kappa_arcmin")


@dataclass(frozen=True)
class Prior:
    """What the advice starts from: a rig's nominal values and the covariance of its parameters.

    ``parameters`` (k,) are named as calib.json's ``covariance.parameters``; ``covariance`` (k, k) is
    the textbook one, ``clustered`` the one clustered by instant (None: none measured, as for a
    plan); ``noise_px[camera]`` the sigma of a new corner coordinate in the textbook covariance's
    terms; ``distance_mm`` the (lo, hi) range of the distances of holdable poses; ``instants`` how many
    instants the covariance is the information of (None: a plan's, known before any photo).
    """

    board: Board
    reference: str
    cameras: dict[str, CameraModel]
    rig: dict[str, Pose]
    board_shape_mm: np.ndarray | None
    parameters: list[str]
    covariance: np.ndarray
    clustered: np.ndarray | None
    noise_px: dict[str, float]
    distance_mm: tuple[float, float]
    rig_mode: str = "rigid"
    instants: int | None = None

    def board_points_mm(self) -> np.ndarray:
        """(N, 3) the board's corners as calibrated (flat, or shaped by ``board_shape_mm``)."""
        return shaped_points_mm(self.board.object_points_mm(), self.board_shape_mm)

    def camera_pose(self, name: str, board_pose: Pose) -> Pose:
        """Board-to-camera pose of ``name`` for the board at ``board_pose`` (reference frame)."""
        return board_pose if name == self.reference else self.rig[name].compose(board_pose)


@dataclass
class AdvisedPose:
    """One advised pose: ``pose`` (board to reference camera), the ``cameras`` that see it, the sigmas
    once it (and every pose before it) is taken, the share by which it shrinks the objective, the
    board's centre in the reference camera's frame, and
    for every camera the board's outline in its frame (``outline_px[camera]``, (M, 2) px, or None
    where the board is partly behind it)."""

    pose: Pose
    cameras: list[str]
    predicted_sigma: dict[str, float]
    gain: float
    centre_mm: np.ndarray
    outline_px: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def distance_mm(self) -> float:
        """Distance of the board's centre from the reference camera."""
        return float(np.linalg.norm(self.centre_mm))

    @property
    def tilt_deg(self) -> float:
        """How far the board's front turns away from facing the reference camera (:func:`tilt_deg`)."""
        return tilt_deg(self.pose.R, self.centre_mm)


@dataclass
class Advice:
    """The result of :func:`advise`: the sigmas now, the poses best first, ``done`` and the goals."""

    frame: str
    current_sigma: dict[str, float]
    poses: list[AdvisedPose]
    done: bool
    goals: dict[str, float]
    next_gain: float


# ---------------------------------------------------------------------------- the starting point


def photo_distance_range(rig: RigModel) -> tuple[float, float]:
    """(lo, hi) distances of the board's centre from the reference camera over the calibration's photos, mm."""
    d = rig.board_distances_mm()
    if not len(d):
        raise InputError("the calibration has no photo with a board pose: nothing to advise from")
    return float(d.min()), float(d.max())


def prior_from_rig(rig: RigModel) -> Prior:
    """The :class:`Prior` of a calibration: its values, both covariances and its ``s0``.

    Parameters
    ----------
    rig : RigModel
        A calibration (calib.json), with its joint covariance.

    Returns
    -------
    Prior
        Where the calibration stands, for :func:`advise`.

    Raises
    ------
    InputError
        The calibration holds no covariance (written before dualcal stored it), a covariance that is
        not positive definite, or no ``s0``.
    """
    cov = JointCovariance.from_dict(rig.covariance)
    s0 = rig.adjustment.get("s0_px")
    if not s0 or not np.isfinite(s0):
        raise InputError("this calib.json has no a-posteriori sigma (adjustment.s0_px): calibrate again")
    formal = cov.matrices["formal"]
    try:
        np.linalg.cholesky(formal)
    except np.linalg.LinAlgError:
        raise InputError("this calib.json's covariance is not positive definite: some parameter is not "
                         "determined by its photos (see its 'determination' check)") from None
    lo, hi = photo_distance_range(rig)
    noise = rig.adjustment.get("photo_noise")          # a new photo's corners: as noisy as its camera's photos
    level = {n: float(s0) * (noise["camera_px"][n] / noise["reference_px"] if noise else 1.0) for n in rig.cameras}
    return Prior(rig.board, rig.reference, dict(rig.cameras), {n: r.pose for n, r in rig.rig.items()},
                 None if rig.board_shape_mm is None else np.asarray(rig.board_shape_mm, float),
                 list(cov.parameters), formal, cov.matrices["clustered"], level,
                 (DISTANCE_FACTORS[0] * lo, DISTANCE_FACTORS[1] * hi), rig.rig_mode,
                 len({view for poses in rig.camera_poses.values() for view in poses}))


def photo_noise_px(rig: RigModel) -> dict[tuple[str, str], float]:
    """``{(camera, view): px}`` each photo's corner noise in the textbook covariance's terms: ``s0 / sqrt(w_b)``
    for its weight ``w_b`` in the adjustment (calib.json's ``adjustment.photo_noise``, each photo weighed by its
    own noise), ``s0`` for every photo of a calibration that weighs them alike."""
    s0 = float(rig.adjustment["s0_px"])
    photos = (rig.adjustment.get("photo_noise") or {}).get("photos", {})
    return {(camera, view): s0 / np.sqrt(photos.get(camera, {}).get(view, {}).get("weight", 1.0))
            for camera, poses in rig.camera_poses.items() for view in poses}


#: A plan's prior: 1-sigma of what is known before any photo (relative focal length, principal point
#: as a share of the image, lens coefficients, rig angles in radians and translation in mm).
PLAN_PRIOR = {"focal": 0.05, "centre": 0.03, "lens": 0.1, "rotation_rad": 0.02, "t_mm": 3.0}
#: A plan's noise of a corner coordinate, px (a detector on real photos, with the photo-level part).
PLAN_NOISE_PX = 0.3
#: A plan's distances: where the board spans these shares of a camera's shorter side.
PLAN_FILL = (0.85, 0.3)


def nominal_camera(image_size: tuple[int, int], focal_35mm: float) -> CameraModel:
    """A camera from its image size and 35 mm-equivalent focal length (square pixels, centred, no lens)."""
    w, h = image_size
    f = focal_px_from_35mm((w, h), focal_35mm)
    return CameraModel((int(w), int(h)), f, f, 0.0, (w - 1) / 2, (h - 1) / 2, 0.0, 0.0)


def nominal_prior(cameras: dict[str, CameraModel], board: Board, reference: str,
                  rig: dict[str, Pose], noise_px: float = PLAN_NOISE_PX) -> Prior:
    """A :class:`Prior` before any photo: nominal ``cameras`` and ``rig`` (reference to camera),
    independent sigmas from :data:`PLAN_PRIOR`, distances where the board spans :data:`PLAN_FILL`
    of the cameras' frames (the nearest of the widest camera to the farthest of the narrowest).

    Parameters
    ----------
    cameras : dict[str, CameraModel]
        Nominal cameras (:func:`nominal_camera`).
    board : Board
        The board to be photographed.
    reference : str
        The reference camera.
    rig : dict[str, Pose]
        Each other camera's nominal pose relative to the reference.
    noise_px : float
        The corner noise assumed, pixels per coordinate.

    Returns
    -------
    Prior
        Where a calibration would start, for :func:`advise`."""
    names, sd = [], []
    for name, cam in cameras.items():
        w, h = cam.image_size
        for n in ("fx", "fy", "cx", "cy", "k1", "k2"):
            names.append(intrinsic_name(name, n))
            sd.append({"fx": PLAN_PRIOR["focal"] * cam.fx, "fy": PLAN_PRIOR["focal"] * cam.fy,
                       "cx": PLAN_PRIOR["centre"] * w, "cy": PLAN_PRIOR["centre"] * h}.get(n, PLAN_PRIOR["lens"]))
    for name in rig:
        for what in ("rotation_rad", "t_mm"):
            for a in "xyz":
                names.append(rig_name(name, what, a))
                sd.append(PLAN_PRIOR[what])
    s = board.square_mm
    extent = float(np.hypot((board.cols + 1) * s, (board.rows + 1) * s))
    dist = [[cam.fx * extent / (fill * min(cam.image_size)) for fill in PLAN_FILL] for cam in cameras.values()]
    return Prior(board, reference, dict(cameras), dict(rig), None, names, np.diag(np.square(sd)), None,
                 dict.fromkeys(cameras, float(noise_px)), (min(d[0] for d in dist), max(d[1] for d in dist)))


# ---------------------------------------------------------------------------- targets


def edge_point(cam: CameraModel) -> np.ndarray:
    """The camera-frame ray (3,) of the image corner farthest from the principal point."""
    w, h = cam.image_size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    return pixel_rays(cam, corners[np.argmax(np.linalg.norm(corners - [cam.cx, cam.cy], axis=1))])[0]


def target_gradients(prior: Prior) -> dict[str, np.ndarray]:
    """Every target as a gradient ``g`` (k,) over the prior's parameters: ``sigma = sqrt(g^T C g)``.

    Keys: every parameter that is an intrinsic (``wide.fx``, ...), ``<camera>.distortion_edge_px``,
    and for every rig camera ``baseline_mm`` and ``omega_arcmin``, ``phi_arcmin``, ``kappa_arcmin``.
    """
    index = {n: i for i, n in enumerate(prior.parameters)}
    k = len(prior.parameters)
    out = {}
    for n in prior.parameters:
        if n.count(".") == 1 and not n.startswith("board."):
            g = np.zeros(k)
            g[index[n]] = 1.0
            out[n] = g
    for name, cam in prior.cameras.items():
        lens = [n for n in INTRINSIC_NAMES[5:] if intrinsic_name(name, n) in index]
        if lens:
            g = np.zeros(k)
            g[[index[intrinsic_name(name, n)] for n in lens]] = radial_lens_gradient(cam, edge_point(cam), lens)
            out[f"{name}.distortion_edge_px"] = g
    for name, pose in prior.rig.items():
        rot = [index.get(rig_name(name, "rotation_rad", a)) for a in "xyz"]
        tr = [index.get(rig_name(name, "t_mm", a)) for a in "xyz"]
        if None in rot or None in tr:
            continue
        g = np.zeros(k)
        g[tr] = pose.t_mm / np.linalg.norm(pose.t_mm)
        out[f"{name}.baseline_mm"] = g
        J_opk = opk_jacobian(opk_from_rotation(pose.R)) * ARCMIN_PER_RAD
        for row, angle in zip(J_opk, ("omega", "phi", "kappa")):
            g = np.zeros(k)
            g[rot] = row
            out[f"{name}.{angle}_arcmin"] = g
    return out


def key_targets(names) -> dict[str, list[str]]:
    """The default objective's targets among target ``names``, grouped by camera (module docstring)."""
    groups: dict[str, list[str]] = {}
    for name in names:
        cam, what = name.split(".", 1)
        if what in KEY_INTRINSICS or what in RIG_TARGETS or what == "distortion_edge_px":
            groups.setdefault(cam, []).append(name)
    return groups


def sigmas(covariance: np.ndarray, gradients: dict[str, np.ndarray]) -> dict[str, float]:
    """``{target: sqrt(g^T C g)}`` for one covariance (k, k)."""
    return {n: float(np.sqrt(max(g @ covariance @ g, 0.0))) for n, g in gradients.items()}


def photo_factors(prior: Prior, gradients: dict[str, np.ndarray]) -> dict[str, float]:
    """Each target's ``kappa``: its honest sigma over its textbook one (at least 1; module docstring)."""
    formal = sigmas(prior.covariance, gradients)
    if prior.clustered is None:
        return dict.fromkeys(gradients, 1.0)
    clustered = sigmas(prior.clustered, gradients)
    return {n: max(1.0, clustered[n] / formal[n]) if formal[n] > 0 else 1.0 for n in gradients}


def honest_sigmas(prior: Prior, covariance: np.ndarray | None = None) -> dict[str, float]:
    """Every target's honest sigma for a textbook ``covariance`` (default: the prior's own, which gives
    the sigmas calib.json reports). A baseline's includes the printed squares' tolerance
    (:mod:`dualcal.geometry.scale`), which no photo shrinks."""
    gradients = target_gradients(prior)
    return _honest(prior, prior.covariance if covariance is None else covariance, gradients,
                   photo_factors(prior, gradients))


def _honest(prior: Prior, covariance: np.ndarray, gradients: dict, kappa: dict) -> dict[str, float]:
    """:func:`honest_sigmas` from the targets' ``gradients`` and photo factors ``kappa``, computed once."""
    out = {n: kappa[n] * s for n, s in sigmas(covariance, gradients).items()}
    rel = relative_sigma(prior.board)
    for name, pose in prior.rig.items():
        key = f"{name}.baseline_mm"
        if rel and key in out:
            out[key] = float(with_scale(out[key], np.linalg.norm(pose.t_mm), rel))
    return out


# ---------------------------------------------------------------------------- candidates


def tilt_deg(R: np.ndarray, centre_mm: np.ndarray) -> float:
    """Angle between the board's normal (its +Z, into the board: away from a camera that sees its
    front) and the line of sight from the camera to its centre ``centre_mm`` (camera frame), degrees;
    above 90 the camera sees the board's back."""
    return float(_tilts_deg(R[None], np.asarray(centre_mm, float)[None])[0])


def _tilts_deg(R: np.ndarray, centres_mm: np.ndarray) -> np.ndarray:
    """:func:`tilt_deg` of stacks: rotations (n, 3, 3), centres (n, 3) -> (n,)."""
    cos = np.einsum("ni,ni->n", R[:, :, 2], centres_mm) / np.linalg.norm(centres_mm, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _applied(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(n, m, 3) the points ``X`` (m, 3) under each of the poses ``R`` (n, 3, 3), ``t`` (n, 3)."""
    return np.einsum("nij,mj->nmi", R, X) + t[:, None]


def _holdable(prior: Prior, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n,) :func:`holdable` for the board-to-reference poses ``R`` (n, 3, 3), ``t`` (n, 3)."""
    X = _applied(R, t, prior.board.object_points_mm())
    centres = X.mean(axis=1)
    d = np.linalg.norm(centres, axis=1)
    lo, hi = prior.distance_mm
    return (np.all(X[:, :, 2] > 0, axis=1) & (d >= lo * (1 - 1e-9)) & (d <= hi * (1 + 1e-9))
            & (_tilts_deg(R, centres) <= MAX_TILT_DEG + 1e-9))


def holdable(prior: Prior, pose: Pose) -> bool:
    """Whether a person can hold the board at ``pose`` (board to reference camera): every corner in
    front of the camera, its centre's distance within ``prior.distance_mm``, its front at most
    :data:`MAX_TILT_DEG` from facing the camera."""
    return bool(_holdable(prior, pose.R[None], pose.t_mm[None])[0])


def inside_frame(prior: Prior, name: str, X_cam: np.ndarray) -> np.ndarray:
    """(N,) True for camera-frame points (N, 3) that camera ``name`` sees (:func:`~dualcal.geometry.camera.in_frame`)
    at least their :func:`frame_margin_px` inside its image's edges."""
    cam = prior.cameras[name]
    seen = in_frame(cam, X_cam)
    uv, _, J_K = project_with_jacobians(cam, np.where(seen[:, None], X_cam, [0.0, 0.0, 1.0]))
    m = frame_margin_px(prior, name, J_K)[:, None]
    return seen & np.all((uv >= m) & (uv <= np.array(cam.image_size) - 1 - m), axis=1)


def square_corners_mm(board: Board) -> np.ndarray:
    """(rows + 2, cols + 2, 3) the corners of every square of the board (its inner corners and the outline one
    square beyond them), in the board's frame."""
    s = board.square_mm
    x, y = np.meshgrid(np.arange(-1, board.cols + 1) * s, np.arange(-1, board.rows + 1) * s)
    return np.stack([x, y, np.zeros_like(x)], axis=-1)


def detectable(cam: CameraModel, board: Board, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n,) whether a detector finds the board in camera ``cam`` at the board-to-camera poses ``R`` (n, 3, 3),
    ``t`` (n, 3), as far as its view goes: seen at most :data:`MAX_VIEW_DEG` from facing the camera, and every
    square it sees (both ends of a side in the frame) at least :data:`MIN_SQUARE_PX` long in the image (a
    steep view's short sides and the far squares too)."""
    grid = _applied(R, t, square_corners_mm(board).reshape(-1, 3))                  # (n, G, 3)
    seen = in_frame(cam, grid.reshape(-1, 3))
    uv = np.full((seen.size, 2), np.nan)
    uv[seen] = project_points(cam, grid.reshape(-1, 3)[seen])
    uv = uv.reshape(len(R), board.rows + 2, board.cols + 2, 2)
    sides = np.concatenate([np.linalg.norm(np.diff(uv, axis=k), axis=-1).reshape(len(R), -1) for k in (1, 2)], axis=1)
    shortest = np.min(np.where(np.isfinite(sides), sides, np.inf), axis=1)
    return (_tilts_deg(R, grid.mean(axis=1)) <= MAX_VIEW_DEG) & np.isfinite(shortest) & (shortest >= MIN_SQUARE_PX)


def _seen(prior: Prior, name: str, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the board-to-reference poses ``R`` (n, 3, 3), ``t`` (n, 3): the corners camera ``name`` measures
    (n, N) bool and whether it detects the board at all (n,) (:func:`seen_corners`)."""
    board, cam = prior.board, prior.cameras[name]
    if name != prior.reference:
        rel = prior.rig[name]
        R, t = rel.R @ R, t @ rel.R.T + rel.t_mm
    seen = in_frame(cam, _applied(R, t, prior.board_points_mm()).reshape(-1, 3)).reshape(len(R), -1)
    found = detectable(cam, board, R, t)
    if board.charuco is not None:
        return seen, found & (seen.sum(axis=1) >= max(MIN_CHARUCO_CORNERS, CHARUCO_SHARE * seen.shape[1]))
    outline = _applied(R, t, board_outline_mm(board))
    whole = inside_frame(prior, name, outline.reshape(-1, 3)).reshape(len(R), -1).all(axis=1)
    return seen, found & seen.all(axis=1) & whole


def seen_corners(prior: Prior, name: str, board_pose: Pose) -> np.ndarray | None:
    """(N,) bool, the corners camera ``name`` measures at ``board_pose``, or None where it would not detect
    the board (:func:`detectable`; a chessboard: unless every corner is seen and the outer squares stay inside
    the frame by their margin, :func:`inside_frame`; ChArUco: enough corners)."""
    seen, found = _seen(prior, name, board_pose.R[None], board_pose.t_mm[None])
    return seen[0] if found[0] else None


def frame_margin_px(prior: Prior, name: str, J_K: np.ndarray) -> np.ndarray:
    """(M,) how far inside camera ``name``'s frame points of the board's outline must fall, px, given the
    Jacobians ``J_K`` (M, 2, 11) of their images on the intrinsics: twice the largest sigma of where each
    falls, as far as the calibration knows the lens, or how far the board's image moves when it is held
    :data:`HOLD_SHARE` of its distance off (that share of the focal length: three times as far across a 3 x
    tele's frame as across the wide's), whichever is larger, within :data:`FRAME_MARGIN` and
    :data:`MAX_FRAME_MARGIN` of the frame's shorter side."""
    cam = prior.cameras[name]
    index = {n: i for i, n in enumerate(prior.parameters)}
    used = [(j, index[intrinsic_name(name, n)]) for j, n in enumerate(INTRINSIC_NAMES)
            if intrinsic_name(name, n) in index]
    J = J_K[:, :, [j for j, _ in used]]
    cols = [i for _, i in used]
    var = np.zeros(len(J_K))
    for C in (prior.covariance, prior.clustered):
        if C is not None:
            var = np.maximum(var, np.einsum("mai,ij,maj->ma", J, C[np.ix_(cols, cols)], J).max(axis=1))
    short = min(cam.image_size)
    return np.clip(np.maximum(2.0 * np.sqrt(var), HOLD_SHARE * max(cam.fx, cam.fy)), FRAME_MARGIN * short,
                   MAX_FRAME_MARGIN * short)


def board_outline_mm(board: Board, samples: int = 8) -> np.ndarray:
    """(4 samples, 3) points around the board's outer squares (one square beyond the corner grid)."""
    s = board.square_mm
    x0, y0, x1, y1 = -s, -s, board.cols * s, board.rows * s
    t = np.linspace(0.0, 1.0, samples, endpoint=False)[:, None]
    edges = [np.hstack([x0 + (x1 - x0) * t, np.full_like(t, y0)]), np.hstack([np.full_like(t, x1), y0 + (y1 - y0) * t]),
             np.hstack([x1 - (x1 - x0) * t, np.full_like(t, y1)]), np.hstack([np.full_like(t, x0), y1 - (y1 - y0) * t])]
    xy = np.vstack(edges)
    return np.column_stack([xy, np.zeros(len(xy))])


def outline_px(prior: Prior, name: str, board_pose: Pose) -> np.ndarray | None:
    """(M, 2) the board's outline (:func:`board_outline_mm`) in camera ``name``'s frame, pixels
    (through its lens); None where part of it is behind the camera."""
    X = prior.camera_pose(name, board_pose).apply(board_outline_mm(prior.board))
    if np.any(X[:, 2] <= 0):
        return None
    return project_with_jacobians(prior.cameras[name], X)[0]


def _facing_rotations(view_dir: np.ndarray, tilt_rad: np.ndarray, azimuth_rad: np.ndarray,
                      roll_rad: np.ndarray) -> np.ndarray:
    """(n, 3, 3) board-to-camera rotations whose board normal (+Z, away from the camera) is ``view_dir``
    (n, 3) tilted by ``tilt_rad`` (n,) about an axis at ``azimuth_rad`` (n,) around it, with the board
    turned by ``roll_rad`` (n,)."""
    z = view_dir / np.linalg.norm(view_dir, axis=1, keepdims=True)
    B = tangent_basis(z)                                        # (n, 3, 2) two axes perpendicular to z
    axis = np.einsum("nij,nj->ni", B, np.column_stack([np.cos(azimuth_rad), np.sin(azimuth_rad)]))
    normal = np.einsum("nij,nj->ni", rotation_from_rotvec(tilt_rad[:, None] * axis), z)
    x = B[:, :, 0] - normal * np.einsum("ni,ni->n", normal, B[:, :, 0])[:, None]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(normal, x)
    c, s = np.cos(roll_rad)[:, None], np.sin(roll_rad)[:, None]
    return np.stack([c * x + s * y, -s * x + c * y, normal], axis=-1)


def _on_rays(origin: np.ndarray, rays: np.ndarray, distance_mm: np.ndarray) -> np.ndarray:
    """(n, 3) the points on the unit ``rays`` (n, 3) from ``origin`` (3,) (reference frame) at ``distance_mm``
    (n,) from the reference camera."""
    b = rays @ origin
    s = -b + np.sqrt(np.maximum(b * b - origin @ origin + distance_mm ** 2, 0.0))
    return origin + s[:, None] * rays


def _nearest_whole_mm(prior: Prior, aimed: str, rays: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(n,) the nearest distance from the reference camera, within ``prior.distance_mm``, at which camera
    ``aimed`` sees the whole board (its outline inside the frame by its margin, :func:`inside_frame`) with
    its centre on the rays (n, 3) (reference frame, from ``aimed``) and rotations ``R`` (n, 3, 3); NaN where
    it does not even at the far end. By bisection on the log distance (the board's image shrinks towards
    its centre as it moves away)."""
    rel = prior.camera_pose(aimed, Pose(np.eye(3), np.zeros(3)))          # reference to the aimed camera
    origin = rel.inverse().t_mm
    offsets = board_outline_mm(prior.board) - prior.board.object_points_mm().mean(axis=0)

    def whole(log_d):
        X = _applied(R, _on_rays(origin, rays, np.exp(log_d)), offsets)
        return inside_frame(prior, aimed, rel.apply(X.reshape(-1, 3))).reshape(len(R), -1).all(axis=1)

    lo, hi = np.log(prior.distance_mm)
    near, far = np.full(len(R), lo), np.full(len(R), hi)
    for _ in range(BISECTIONS):
        mid = 0.5 * (near + far)
        ok = whole(mid)
        far, near = np.where(ok, mid, far), np.where(ok, near, mid)
    far = np.where(whole(np.full(len(R), lo)), lo, far)
    return np.where(whole(np.full(len(R), hi)), np.exp(far), np.nan)


def candidate_poses(prior: Prior, per_camera: int = CANDIDATES_PER_CAMERA, seed: int = 0):
    """Holdable board poses, ``[(pose, {camera: seen corners (N,) bool})]``, aimed at each camera in turn.

    Each is drawn along the ray of a random pixel of the aimed camera (:data:`CENTRED_SHARE` of them near
    the image's centre, where the board can fill the frame), tilted up to :data:`MAX_TILT_DEG`
    from facing it in a random direction and turned at random, then placed where that camera sees the whole
    board nearest (:func:`_nearest_whole_mm`: the board fills its frame as far as the tilt and the pixel
    let it, where a lens's principal point and distortion show most), or, for :data:`FARTHER_SHARE` of
    them, log-uniformly between there and the far end of ``prior.distance_mm`` (for a ChArUco board, seen
    in part, between the near end and the far end); kept when holdable and the aimed camera detects the
    board there (:func:`seen_corners`). Every camera that does is listed.
    """
    rng = np.random.default_rng(seed)
    centre_b = prior.board.object_points_mm().mean(axis=0)
    lo, hi = prior.distance_mm
    out = []
    for aimed, cam in prior.cameras.items():
        to_ref = prior.camera_pose(aimed, Pose(np.eye(3), np.zeros(3))).inverse()
        w, h = cam.image_size
        spread = np.where(rng.uniform(size=(per_camera, 1)) < CENTRED_SHARE, 0.1, 0.4)
        pixels = np.array([w, h]) * (0.5 + spread * rng.uniform(-1.0, 1.0, (per_camera, 2)))
        rays = pixel_rays(cam, pixels) @ to_ref.R.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        R = _facing_rotations(rays, np.radians(rng.uniform(0.0, MAX_TILT_DEG, per_camera)),
                              rng.uniform(0, 2 * np.pi, per_camera), rng.uniform(-np.pi, np.pi, per_camera))
        partial = prior.board.charuco is not None
        near = np.full(per_camera, lo) if partial else _nearest_whole_mm(prior, aimed, rays, R)
        farther = rng.uniform(size=per_camera) < (1.0 if partial else FARTHER_SHARE)
        d = np.where(farther, near * (hi / near) ** rng.uniform(size=per_camera), near)
        keep = np.isfinite(d)
        R, t = R[keep], _on_rays(to_ref.t_mm, rays[keep], d[keep]) - R[keep] @ centre_b
        keep = _holdable(prior, R, t)
        R, t = R[keep], t[keep]
        seen = {n: _seen(prior, n, R, t) for n in prior.cameras}
        for i in np.flatnonzero(seen[aimed][1]):
            out.append((Pose(R[i], t[i]), {n: m[i] for n, (m, found) in seen.items() if found[i]}))
    return out


# ---------------------------------------------------------------------------- information of an instant


def instant_information(prior: Prior, pose: Pose, seen: dict[str, np.ndarray],
                        noise_px: dict[str, float] | None = None) -> np.ndarray:
    """(k, k) information a new instant at ``pose`` adds on the prior's parameters (module docstring).

    ``seen[camera]`` (N,) bool: the corners each camera measures, with noise ``noise_px[camera]`` (default
    ``prior.noise_px``: a new photo's, its camera's level; :func:`photo_noise_px` gives a calibration's own
    photos' noise). The instant's board pose (left
    rotation increment and translation of the reference camera's pose) is eliminated; so are, in
    rig mode ``paper``, each camera's baseline direction in this instant and, in mode ``none``,
    each camera's own pose (the rig's parameters then get no information from it).
    """
    index = {n: i for i, n in enumerate(prior.parameters)}
    k = len(prior.parameters)
    X_b = prior.board_points_mm()
    basis = shape_basis(prior.board.object_points_mm())
    blocks_g, blocks_l = [], []
    own_poses = prior.rig_mode == "none"
    names = list(seen)
    n_local = 6 * (len(names) if own_poses else 1) + (2 * len(names) if prior.rig_mode == "paper" else 0)
    for c, name in enumerate(names):
        m = seen[name]
        X_ref = pose.apply(X_b[m])
        rel = prior.camera_pose(name, Pose(np.eye(3), np.zeros(3)))     # reference to this camera
        X_c = rel.apply(X_ref)
        _, J_X, J_K = project_with_jacobians(prior.cameras[name], X_c)
        n = len(X_c)
        Ag = np.zeros((n, 2, k))
        Al = np.zeros((n, 2, n_local))
        for j, par in enumerate(INTRINSIC_NAMES):
            if intrinsic_name(name, par) in index:
                Ag[:, :, index[intrinsic_name(name, par)]] = J_K[:, :, j]
        J_ref = J_X @ rel.R                                          # d uv / d X_ref, (n, 2, 3)
        if name in prior.rig and not own_poses and rig_name(name, "t_mm", "x") in index:
            rot = [index[rig_name(name, "rotation_rad", a)] for a in "xyz"]
            tr = [index[rig_name(name, "t_mm", a)] for a in "xyz"]
            Ag[:, :, rot] = J_X @ -cross_matrix(X_c - rel.t_mm)    # R <- exp([d]x) R
            Ag[:, :, tr] = J_X
        for j, term in enumerate(("xx", "yy", "xy")):
            if f"board.shape_mm.{term}" in index:
                Ag[:, :, index[f"board.shape_mm.{term}"]] = (J_ref @ pose.R[:, 2]) * basis[m, j][:, None]
        p0 = 6 * c if own_poses else 0
        Al[:, :, p0:p0 + 3] = J_ref @ -cross_matrix(X_ref - pose.t_mm)   # board pose, left increment
        Al[:, :, p0 + 3:p0 + 6] = J_ref
        if prior.rig_mode == "paper" and name in prior.rig:
            q = n_local - 2 * len(names) + 2 * c
            # this instant's own baseline direction (t = D u_v): two tangent increments of u_v
            Al[:, :, q:q + 2] = J_X @ tangent_basis(rel.t_mm[None] / np.linalg.norm(rel.t_mm))[0]
        w = 1.0 / (prior.noise_px if noise_px is None else noise_px)[name]
        blocks_g.append(w * Ag.reshape(-1, k))
        blocks_l.append(w * Al.reshape(-1, n_local))
    A_g, A_l = np.vstack(blocks_g), np.vstack(blocks_l)
    A_l = A_l[:, np.any(A_l != 0, axis=0)]
    Q, _ = np.linalg.qr(A_l)
    A_perp = A_g - Q @ (Q.T @ A_g)                                   # the Schur complement's factor
    return A_perp.T @ A_perp


def updated_covariance(covariance: np.ndarray, information: np.ndarray) -> np.ndarray:
    """``(C^-1 + I)^-1``, computed in the scale of ``C``'s sigmas (for conditioning);
    ``information`` may be (k, k) or a stack (m, k, k)."""
    sd = np.sqrt(np.diag(covariance))
    corr = covariance / np.outer(sd, sd)
    scaled = information * np.outer(sd, sd)
    out = np.linalg.inv(np.linalg.inv(corr) + scaled)
    return out * np.outer(sd, sd)


# ---------------------------------------------------------------------------- the advice


def parse_goals(goals: dict[str, float], gradients: dict[str, np.ndarray]) -> dict[str, float]:
    """Check ``goals`` (``{target: sigma}``) against the targets there are; InputError names the unknown."""
    unknown = [n for n in goals if n not in gradients]
    if unknown:
        raise InputError(f"target {unknown[0]!r} is not one this calibration has (it has e.g. "
                         f"{', '.join(list(gradients)[:6])}, ...)")
    bad = [n for n, s in goals.items() if not (np.isfinite(s) and s > 0)]
    if bad:
        raise InputError(f"target {bad[0]}={goals[bad[0]]!r}: a goal sigma must be a positive number")
    return dict(goals)


def _objective(sig: np.ndarray, reference: np.ndarray, groups: list[np.ndarray], hinge: bool) -> np.ndarray:
    """Mean log of ``sig / reference`` (m, t) over targets, per group then over groups: (m,)."""
    ratio = np.log(sig / reference)
    if hinge:
        ratio = np.maximum(ratio, 0.0)
    return np.mean([ratio[:, g].mean(axis=1) for g in groups], axis=0)


def random_information(info: np.ndarray, candidates) -> np.ndarray:
    """(k, k) the information of an average photo drawn like a user's: the mean over the candidates
    that every camera sees (all candidates where none is)."""
    n_cams = max(len(seen) for _, seen in candidates)
    every = [i for i, (_, seen) in enumerate(candidates) if len(seen) == n_cams]
    return info[every].mean(axis=0)


def _dues(prior: Prior, G: np.ndarray, C: np.ndarray, info: np.ndarray, candidates, count: int) -> list[np.ndarray]:
    """Each key target's due after 1 .. ``count`` advised photos, ``[(t,)]`` (module docstring): the textbook
    sigma ``sqrt(g^T C g)`` of each row of ``G`` (t, k) after as many photos like the calibration's own
    (``C n / (n + s)`` for its ``n`` instants), or, for a plan, like the average candidate every camera sees
    (:func:`random_information`; ``info`` (m, k, k) the candidates'), times :data:`DUE_FACTOR`."""
    if prior.instants:
        now = np.sqrt(np.einsum("tk,kl,tl->t", G, C, G))
        return [DUE_FACTOR * now * np.sqrt(prior.instants / (prior.instants + s)) for s in range(1, count + 1)]
    mean_info = random_information(info, candidates)
    return [DUE_FACTOR * np.sqrt(np.maximum(np.einsum("tk,kl,tl->t", G, updated_covariance(C, s * mean_info), G),
                                            1e-300)) for s in range(1, count + 1)]


def _lag(sig: np.ndarray, due: np.ndarray) -> np.ndarray:
    """How far the most-lagging target is behind what it is due, ``max(log(sig / due), 0)`` (m,)."""
    return np.maximum(np.log(sig / due).max(axis=1), 0.0)


def advise(prior: Prior, count: int = 5, goals: dict[str, float] | None = None,
           candidates=None, seed: int = 0) -> Advice:
    """The ``count`` poses that shrink the objective the most, chosen greedily (module docstring).

    Parameters
    ----------
    prior : Prior
        where the calibration stands (:func:`prior_from_rig`, or a nominal one for a plan)
    count : int
        how many poses
    goals : dict[str, float] or None
        ``{target: sigma}``; default: the key targets relative to their current sigmas
    candidates
        ``[(pose, seen)]`` to choose from (default :func:`candidate_poses`)
    seed : int
        Seed of the candidate poses drawn.

    Returns
    -------
    Advice
        The poses, best first, each with the sigmas predicted once it and those before it are taken,
        and whether the goals are met (advise.json's content, :func:`advice_to_dict`).

    Raises
    ------
    InputError
        A goal names no target; no candidate pose is holdable.
    """
    if count < 1:
        raise InputError("count must be at least 1")
    gradients = target_gradients(prior)
    goals = parse_goals(goals or {}, gradients)
    kappa = photo_factors(prior, gradients)
    current = _honest(prior, prior.covariance, gradients, kappa)
    if goals:
        names = list(goals)
        groups = [np.arange(len(names))]
        reference = np.array([goals[n] for n in names])
    else:
        by_camera = key_targets(gradients)
        names = [n for g in by_camera.values() for n in g]
        pos = {n: i for i, n in enumerate(names)}
        groups = [np.array([pos[n] for n in g]) for g in by_camera.values()]
        reference = np.array([max(current[n], 1e-300) for n in names])
    G = np.array([kappa[n] * gradients[n] for n in names])         # (t, k): honest sigma = sqrt(g^T C g)
    candidates = candidate_poses(prior, seed=seed) if candidates is None else candidates
    if not candidates:
        raise InputError("no holdable board pose is seen whole by any camera (is the board larger than "
                         "every camera's view at the distances of the photos?)")
    info = np.array([instant_information(prior, pose, seen) for pose, seen in candidates])
    centre_b = prior.board.object_points_mm().mean(axis=0)
    C = prior.covariance
    score_now = _objective(np.sqrt(np.einsum("tk,kl,tl->t", G, C, G))[None], reference, groups, bool(goals))[0]
    if not goals and LAG_WEIGHT > 0:
        due = _dues(prior, G, C, info, candidates, count)
    chosen, first_gain = [], None
    for step in range(count):
        if goals and score_now <= 0.0:                               # every goal met: no more photos
            first_gain = 0.0 if first_gain is None else first_gain
            break
        Cs = updated_covariance(C, info)                             # (m, k, k)
        sig = np.sqrt(np.maximum(np.einsum("tk,mkl,tl->mt", G, Cs, G), 0.0))
        score = _objective(sig, reference, groups, bool(goals))
        rank = score if goals or LAG_WEIGHT <= 0 else score + LAG_WEIGHT * _lag(sig, due[step])
        best = int(np.argmin(rank))
        gain = float(1.0 - np.exp(score[best] - score_now))
        # done: no pose would shrink the objective by STOP_GAIN (the lag term aside)
        first_gain = float(1.0 - np.exp(score.min() - score_now)) if first_gain is None else first_gain
        C, score_now = Cs[best], float(score[best])
        pose, seen = candidates[best]
        outline = {n: outline_px(prior, n, pose) for n in prior.cameras}
        chosen.append(AdvisedPose(pose, [n for n in prior.cameras if n in seen], _honest(prior, C, gradients, kappa),
                                  gain, pose.apply(centre_b[None])[0], outline))
    done = (all(current[n] <= s for n, s in goals.items()) if goals else first_gain < STOP_GAIN)
    return Advice(prior.reference, current, chosen, bool(done), goals, float(first_gain))


# ---------------------------------------------------------------------------- words and JSON


def describe(pose: AdvisedPose) -> str:
    """The pose in words: distance, and which side of the board (as the reference camera's image shows
    it: top, bottom, left, right) is farther away.

    Parameters
    ----------
    pose : AdvisedPose
        One of :attr:`Advice.poses`.

    Returns
    -------
    str
        E.g. ``64 cm from the camera, tilted 35 degrees, its top side farther away``."""
    normal = pose.pose.R[:, 2]
    view = pose.centre_mm / pose.distance_mm
    tilt = pose.tilt_deg
    # the normal's component across the line of sight: where the board's far side is
    across = normal - view * (normal @ view)
    parts = [f"{pose.distance_mm / 10:.0f} cm from the camera"]
    if tilt < 8:
        parts.append("facing the camera")
    else:
        # a normal (away from the camera) that leans to +y belongs to a board whose -y (top) side is farther
        horiz = "left" if across[0] > 0 else "right"
        vert = "top" if across[1] > 0 else "bottom"
        side = horiz if abs(across[0]) >= abs(across[1]) else vert
        parts.append(f"tilted {tilt:.0f} degrees, its {side} side farther away")
    return ", ".join(parts)


def advice_to_dict(advice: Advice) -> dict:
    """advise.json (contract, "advise"; the keys beyond it are added ones)."""
    return {
        "frame": advice.frame,
        "current_sigma": advice.current_sigma,
        "poses": [{**p.pose.to_dict(), "cameras": p.cameras, "predicted_sigma": p.predicted_sigma,
                   "gain": p.gain, "distance_mm": p.distance_mm, "tilt_deg": p.tilt_deg,
                   "description": describe(p),
                   "outline_px": {n: None if o is None else np.asarray(o, float).tolist()
                                  for n, o in p.outline_px.items()}}
                  for p in advice.poses],
        "done": advice.done,
        "goals": advice.goals,
        "next_gain": advice.next_gain,
        "stop_gain": STOP_GAIN,
    }
