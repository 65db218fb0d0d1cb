"""Synthetic rigs with known truth: the test bed of dualcal.

A :class:`SynthTruth` is a rig (intrinsics of every camera, the pose of every camera relative
to the reference) and a set of board poses chosen so that the whole board is seen by every
camera, or, with ``coverage`` (for ChArUco boards), so that the narrowest camera sees only
part of it. From it come exact corners (:func:`true_corners`; a corner outside a camera's
frame is a NaN row), noisy corner sets (:func:`noisy_corner_set`) and, in
:mod:`dualcal.synthetic.render`, photo-like images.

Presets
-------
``note8``   wide + tele of a Samsung Galaxy Note 8 class phone (12 MP portrait, 11 mm baseline,
            the paper's set-up: 8x5 inner corners of 30 mm)
``stereo``  a 640x480 stereo rig with a 100 mm baseline (like OpenCV's stereo sample)
``triple``  wide + tele + ultra-wide (three cameras, 12 MP portrait)
``stereo5`` the ``stereo`` rig with OpenCV's five-coefficient lens model (``k1k2p1p2k3``): left as
            OpenCV's own calibration of its stereo sample's left camera (``left_intrinsics.yml``:
            k3 = 0.238, p1 = 0.0018), right as Bouguet's joint stereo result (p1 = -0.0006, k3 = 0)
``phone3``  a three-lens phone shot in RAW (12 MP portrait each): ``wide`` (26 mm equivalent,
            ``k1k2p1p2k3``, modest), ``ultra`` a fisheye (``kb4``, about 125 x 105 degrees, 145
            on the diagonal; 12 mm from the wide) and ``tele`` (3x, ``k1k2``; 22 mm from the wide
            on the other side). Most views are seen whole by every camera (the tele the
            narrowest); in the others (``edge``: 30 % for the ultra-wide, 20 % for the wide) the
            board is near one camera, off its axis (35-62 degrees for the ultra-wide, 20-32 for the
            wide) so that its corners reach that image's edges, and the cameras that do not see all
            of it miss that instant (their corners are NaN, the view None).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry.board import Board
from ..geometry.circles import circle_centre_offset_px
from ..geometry.camera import INTRINSIC_NAMES, CameraModel, fold_radius, in_frame, project_points
from ..errors import EstimationError, InputError
from ..geometry.model import CameraCorners, CornerSet, Pose, RigModel, RigRelation
from ..geometry.rotation import ARCMIN_PER_RAD, rotation_from_opk, rotation_from_rotvec

_W, _H = 3024, 4032

#: On partial views (``coverage``), the share of the board's corners every camera but the
#: narrowest sees at least: the wide of a phone sees nearly all of a board held close to the tele.
OTHERS_COVERAGE = 0.8


def _opk(arcmin):
    return rotation_from_opk(np.asarray(arcmin, float) / ARCMIN_PER_RAD)


PRESETS = {
    "note8": dict(
        board=Board(8, 5, 30.0),
        cameras={
            "wide": CameraModel((_W, _H), 3127.2, 3136.0, 0.0, 1453.7, 2021.1, 0.08, -0.20),
            "tele": CameraModel((_W, _H), 6058.7, 6076.3, 0.0, 1373.1, 1971.9, -0.12, 0.80),
        },
        rig={"tele": Pose(_opk([0.36, 0.65, -1.92]), np.array([0.35, -11.0, 0.25]))},
        fill=(0.45, 0.85),
    ),
    "stereo": dict(
        board=Board(9, 6, 30.0),
        cameras={
            "left": CameraModel((640, 480), 533.5, 533.5, 0.0, 341.6, 235.2, -0.288, 0.097),
            "right": CameraModel((640, 480), 536.8, 536.5, 0.0, 326.3, 250.1, -0.289, 0.107),
        },
        rig={"right": Pose(rotation_from_opk([0.00669, 0.00452, -0.00350]),
                           np.array([-99.80, 1.12, 0.05]))},
        fill=(0.35, 0.6),
    ),
    "triple": dict(
        board=Board(8, 5, 30.0),
        cameras={
            "wide": CameraModel((_W, _H), 3100.0, 3100.0, 0.0, 1510.0, 2010.0, 0.06, -0.15),
            "tele": CameraModel((_W, _H), 6100.0, 6100.0, 0.0, 1500.0, 2030.0, -0.10, 0.60),
            "ultra": CameraModel((_W, _H), 1700.0, 1700.0, 0.0, 1515.0, 2000.0, -0.05, 0.02),
        },
        rig={"tele": Pose(_opk([1.0, -2.0, 3.0]), np.array([0.2, -10.0, 0.3])),
             "ultra": Pose(_opk([-3.0, 1.5, -2.0]), np.array([0.4, 12.0, -0.5]))},
        fill=(0.45, 0.85),
    ),
}
PRESETS["phone3"] = dict(
    board=Board(8, 5, 30.0),
    cameras={
        "wide": CameraModel((_W, _H), 2905.0, 2903.0, 0.0, 1515.0, 2008.0, 0.065, -0.2, 0.0, 0.0, 0.2,
                            model="k1k2p1p2k3"),
        "ultra": CameraModel((_W, _H), 1450.0, 1449.0, 0.0, 1508.0, 2022.0, 0.2, 0.02, k3=-0.005, k4=0.001,
                             model="kb4"),
        "tele": CameraModel((_W, _H), 8700.0, 8695.0, 0.0, 1498.0, 2030.0, -0.08, 0.5),
    },
    rig={"ultra": Pose(_opk([-20.0, 15.0, -30.0]), np.array([0.4, 12.0, -0.3])),
         "tele": Pose(_opk([10.0, -25.0, 40.0]), np.array([-0.3, -22.0, 0.5]))},
    fill=(0.45, 0.85),
    edge=[dict(camera="ultra", share=0.3, fill=(0.25, 0.45), angle_deg=(35.0, 62.0)),
          dict(camera="wide", share=0.2, fill=(0.3, 0.5), angle_deg=(20.0, 32.0))],
)
PRESETS["stereo5"] = dict(
    PRESETS["stereo"],
    cameras={
        "left": CameraModel((640, 480), 535.9157, 535.9157, 0.0, 342.2832, 235.5708, -0.26637, -0.03859,
                            0.00178, -0.00028, 0.23839, model="k1k2p1p2k3"),
        "right": CameraModel((640, 480), 536.81377, 536.47649, 0.0, 326.28657, 250.10121, -0.28943, 0.10690,
                             -0.00059, 0.00014, 0.0, model="k1k2p1p2k3"),
    },
)


@dataclass
class SynthTruth:
    """A rig and board poses with known truth.

    ``rig[cam]`` maps reference-camera coordinates to camera ``cam`` (the reference maps to
    itself and is not listed); ``view_poses[view]`` maps board to reference camera. ``photo_lenses``
    (``{view: {cam: PhotoLens}}``, :mod:`dualcal.synthetic.synth_focus`) holds each photo's own lens where the
    lenses breathe with focus or shift with OIS (``cameras`` then hold their values at infinity, unshifted);
    None: every photo is taken with ``cameras``.
    """

    board: Board
    cameras: dict[str, CameraModel]
    reference: str
    rig: dict[str, Pose]
    view_poses: dict[str, Pose]
    photo_lenses: dict | None = None

    def photo_camera(self, cam: str, view: str) -> CameraModel:
        """The camera as it took ``cam``'s photo of ``view``: focused on the board and shifted by OIS where its lens
        breathes or shifts (``photo_lenses[view][cam]``, :mod:`dualcal.synthetic.synth_focus`), else ``cameras[cam]``."""
        return self.cameras[cam] if self.photo_lenses is None else self.photo_lenses[view][cam].camera

    def camera_pose(self, cam: str, view: str) -> Pose:
        """Board-to-camera pose of ``cam`` in ``view``."""
        return self.seen_by(cam, self.view_poses[view])

    def seen_by(self, cam: str, board_pose: Pose) -> Pose:
        """Board-to-camera pose of ``cam`` when the board is at ``board_pose`` (board to reference camera)."""
        return board_pose if cam == self.reference else self.rig[cam].compose(board_pose)


def scale_camera(cam: CameraModel, scale: float) -> CameraModel:
    """The same lens on a sensor resampled by ``scale`` (pixel centres kept consistent)."""
    w, h = cam.image_size
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return replace(cam, image_size=size, fx=cam.fx * scale, fy=cam.fy * scale, skew=cam.skew * scale,
                   cx=(cam.cx + 0.5) * scale - 0.5, cy=(cam.cy + 0.5) * scale - 0.5)


def _outline_mm(board: Board) -> np.ndarray:
    """(4, 3) corners of the board's printed pattern (:meth:`Board.pattern_extent_mm`: a chessboard's outer ring
    of squares), first and last diagonally opposite."""
    x0, x1, y0, y1 = board.pattern_extent_mm()
    return np.array([[x0, y0, 0], [x1, y0, 0], [x0, y1, 0], [x1, y1, 0]], float)


def _look_at_pose(center: np.ndarray, target: np.ndarray, roll: float) -> Pose:
    """Board-to-camera pose of a camera at ``center`` looking at ``target`` (board frame)."""
    z = target - center
    z /= np.linalg.norm(z)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    R = np.vstack([x, y, z])
    return Pose(R, -R @ center)


def _all_visible(cams: dict[str, CameraModel], poses: dict[str, Pose], X: np.ndarray,
                 margin: float) -> bool:
    for name, cam in cams.items():
        Xc = poses[name].apply(X)
        if np.any(Xc[:, 2] <= 0) or np.any(np.hypot(Xc[:, 0], Xc[:, 1]) >= fold_radius(cam) * Xc[:, 2]):
            return False
        uv = project_points(cam, Xc)
        w, h = cam.image_size
        m = margin * min(w, h)
        if np.any(uv < m) or np.any(uv[:, 0] > w - 1 - m) or np.any(uv[:, 1] > h - 1 - m):
            return False
    return True


def make_truth(preset: str | dict = "note8", views: int = 13, seed: int = 0, scale: float = 1.0,
               max_tilt_deg: float = 40.0, min_tilt_deg: float = 5.0,
               fill: tuple[float, float] | None = None, board: Board | None = None,
               coverage: tuple[float, float] | None = None, breathing: float = 0.0, ois_px: float = 0.0,
               focal_mm: dict[str, float] | None = None) -> SynthTruth:
    """Draw a rig from ``preset`` and ``views`` board poses seen whole by every camera.

    Poses look at a random point of the board from a tilt of ``min_tilt_deg`` to
    ``max_tilt_deg`` degrees (steep views: e.g. 45 to 65), with a random roll, at a distance
    where the board fills a random share, drawn from ``fill`` (default: the preset's), of the
    narrowest camera's frame (a small share: small squares). ``board`` replaces the preset's
    board. The outer ring of squares stays inside every image too.

    ``coverage = (lo, hi)``: partial views, for boards whose markers number the corners
    (ChArUco). The narrowest camera sees between ``lo`` and ``hi`` of the board's inner corners
    (inside its frame, :func:`in_frame`), looking at a random point of the whole board from
    nearer (the board fills up to ``1.1 / sqrt(lo)`` of its frame); every other camera sees at
    least :data:`OTHERS_COVERAGE` of them.

    Parameters
    ----------
    preset : str or dict
        The rig: ``note8`` (wide + tele, 12 MP), ``stereo`` (a 640x480 pair), ``triple`` (wide + tele +
        ultra-wide), ``phone3`` (wide + 3x tele + a fisheye ultra-wide), ``stereo5`` (the pair with OpenCV's
        five-coefficient lenses); or a rig of one's own, as :data:`PRESETS` holds one (``board``, ``cameras``
        with the reference first, ``rig``, ``fill``, and ``edge`` where some views are near a camera's edge).
    views : int
        Number of board poses.
    seed : int
        Seed of the poses.
    scale : float
        Resample every sensor by this factor (0.25: small, fast photos).
    max_tilt_deg, min_tilt_deg : float
        The range of the board's tilt from facing the camera.
    fill : tuple of float or None
        The range of the share of the narrowest camera's frame the board fills.
    board : Board or None
        Another board than the preset's.
    coverage : tuple of float or None
        Partial views of a ChArUco board, as above.
    breathing : float
        The lenses breathe with focus (:mod:`dualcal.synthetic.synth_focus`): ``fx(d) = fx_inf (1 + b f / (d - f))``
        with this ``b`` (0: they do not), each photo focused on the board's centre; the preset's ``fx, fy`` are
        then the values at infinity.
    ois_px : float
        Each photo's principal point moved by OIS, a normal draw of this many px per coordinate, independent per
        camera and photo (0: none). Drawn from a generator of its own: the poses are those without it.
    focal_mm : dict or None
        Each camera's focal length, mm, for the breathing (default: the preset's,
        :func:`dualcal.synthetic.synth_focus.focal_lengths_mm`).

    Returns
    -------
    SynthTruth
        The board, the cameras, the rig and the board's pose in every view.

    Raises
    ------
    InputError
        An unknown preset, or fewer than one view.
    EstimationError
        No poses could be placed as asked.
    """
    if isinstance(preset, str) and preset not in PRESETS:
        raise InputError(f"--preset {preset!r} is unknown (choose from {', '.join(PRESETS)})")
    if views < 1:
        raise InputError("--views must be at least 1")
    p = PRESETS[preset] if isinstance(preset, str) else preset
    board = board or p["board"]
    cameras = {n: scale_camera(c, scale) for n, c in p["cameras"].items()}
    reference = next(iter(cameras))
    rig = {n: Pose(q.R.copy(), q.t_mm.copy()) for n, q in p["rig"].items()}
    rng = np.random.default_rng(seed)

    s = board.square_mm
    outline = _outline_mm(board)
    X = np.vstack([board.object_points_mm(), outline])
    centre = np.append(0.5 * (outline[0, :2] + outline[3, :2]), 0.0)
    extent = float(np.linalg.norm(outline[3] - outline[0]))
    narrowest = max(cameras, key=lambda n: cameras[n].fx / min(cameras[n].image_size))
    fmin, fmax = fill or p["fill"]
    if coverage is not None:
        lo, hi = coverage
        if not 0 < lo <= hi <= 1:
            raise InputError(f"coverage {lo:g}-{hi:g}: needs 0 < lo <= hi <= 1")
        fmax = max(fmax, 1.1 / np.sqrt(lo))
    reach = 0.15 if coverage is None else 0.45
    # the last views of each kind of edge view (a preset's "edge"), in the order given
    edge_of_view = [] if coverage is not None else [e for e in p.get("edge", []) for _ in range(round(views * e["share"]))]
    edge_of_view = [None] * (views - len(edge_of_view)) + edge_of_view

    view_poses = {}
    attempts = 0
    aim = None
    while len(view_poses) < views:
        attempts += 1
        if attempts > 20000 * views:
            seen = "the whole board in every camera" if coverage is None else f"coverage {lo:g}-{hi:g}"
            raise EstimationError(f"could not place {views} views for preset {preset!r} with {seen}")
        if coverage is not None and aim is None:
            aim = rng.uniform(lo, hi)        # a share drawn per view, so that small ones are not rare
        tilt = np.radians(rng.uniform(min_tilt_deg, max_tilt_deg))
        azim = rng.uniform(0, 2 * np.pi)
        fill = rng.uniform(fmin, fmax)
        dist = cameras[narrowest].fx * extent / (fill * min(cameras[narrowest].image_size))
        direction = -np.array([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)])
        target = centre + np.array([rng.uniform(-reach, reach) * board.cols * s,
                                    rng.uniform(-reach, reach) * board.rows * s, 0.0])
        roll = rng.uniform(-np.pi, np.pi)
        edge = edge_of_view[len(view_poses)]
        if edge is not None:
            poses = _edge_view_poses(cameras, rig, reference, edge, extent, target, direction, roll, rng)
            if _all_visible({edge["camera"]: cameras[edge["camera"]]}, poses, X, margin=0.01):
                view_poses[f"IMG_{len(view_poses) + 1:02d}"] = poses[reference]
            continue
        ref_pose = _look_at_pose(target + dist * direction, target, roll)
        poses = {reference: ref_pose, **{n: q.compose(ref_pose) for n, q in rig.items()}}
        if coverage is None:
            ok = _all_visible(cameras, poses, X, margin=0.01)
        else:
            share = {n: in_frame(c, poses[n].apply(X[:board.n_corners])).mean() for n, c in cameras.items()}
            ok = (lo <= share[narrowest] <= hi and abs(share[narrowest] - aim) <= 0.1
                  and all(share[n] >= OTHERS_COVERAGE for n in cameras if n != narrowest))
        if ok:
            view_poses[f"IMG_{len(view_poses) + 1:02d}"] = ref_pose
            aim = None
    truth = SynthTruth(board, cameras, reference, rig, view_poses)
    if breathing or ois_px:
        truth = _with_photo_lenses(truth, preset, scale, breathing, ois_px, focal_mm, seed)
    return truth


def _with_photo_lenses(truth: SynthTruth, preset: str, scale: float, breathing: float, ois_px: float,
                       focal_mm: dict[str, float] | None, seed: int) -> SynthTruth:
    """``truth`` with every photo's own lens: focused on the board's centre, shifted by OIS
    (:func:`dualcal.synthetic.synth_focus.photo_lenses`)."""
    from .synth_focus import focal_lengths_mm, photo_lenses

    if breathing < 0 or ois_px < 0:
        raise InputError(f"breathing {breathing:g} and ois_px {ois_px:g} must be >= 0")
    focal = focal_mm or focal_lengths_mm(preset, truth.cameras, scale)
    rng = np.random.default_rng([int(seed), 0x015])
    centre = truth.board.object_points_mm().mean(axis=0)
    lenses = {}
    for view in truth.view_poses:
        depth = {n: float(truth.camera_pose(n, view).apply(centre[None])[0, 2]) for n in truth.cameras}
        lenses[view] = photo_lenses(truth.cameras, focal, depth, breathing, ois_px, rng)
    return replace(truth, photo_lenses=lenses)


def _edge_view_poses(cameras, rig, reference, edge, extent, target, direction, roll, rng) -> dict[str, Pose]:
    """Board-to-camera poses of a view near ``edge["camera"]``'s image edge: the board seen from
    ``direction`` at a distance where it fills ``edge["fill"]`` of that camera's frame, the camera
    then turned so that the board's centre lies ``edge["angle_deg"]`` off its axis."""
    name = edge["camera"]
    cam = cameras[name]
    dist = cam.fx * extent / (rng.uniform(*edge["fill"]) * min(cam.image_size))
    look = _look_at_pose(target + dist * direction, target, roll)
    angle, azimuth = np.radians(rng.uniform(*edge["angle_deg"])), rng.uniform(0, 2 * np.pi)
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    turn = Pose(rotation_from_rotvec(angle * axis), np.zeros(3))
    own = turn.compose(look)
    ref_pose = own if name == reference else rig[name].inverse().compose(own)
    return {reference: ref_pose, **{n: q.compose(ref_pose) for n, q in rig.items()}}


def seen_pixels(cam: CameraModel, pose: Pose, X_board: np.ndarray) -> np.ndarray:
    """(N, 2) exact pixels of the board points ``X_board`` that ``cam`` at board-to-camera ``pose`` sees
    (:func:`in_frame`), NaN rows for the others."""
    Xc = pose.apply(X_board)
    seen = in_frame(cam, Xc)
    uv = project_points(cam, np.where(seen[:, None], Xc, 1.0))
    uv[~seen] = np.nan
    return uv


def true_corners(truth: SynthTruth) -> dict[str, dict[str, np.ndarray]]:
    """Exact pixel positions ``[cam][view] -> (N, 2)`` of every inner corner (a circle grid's: the centre of each
    circle's image, :func:`dualcal.geometry.circles.circle_image_centre`); NaN rows for the
    corners a camera does not see (:func:`in_frame`: only on partial views). A chessboard (no
    markers to number a part of it) that a camera does not see whole, with its outer squares, is
    all NaN: the camera missed that instant."""
    X = truth.board.object_points_mm()
    outline = _outline_mm(truth.board)
    out = {}
    for cam in truth.cameras:
        out[cam] = {}
        for v in truth.view_poses:
            model = truth.photo_camera(cam, v)
            pose = truth.camera_pose(cam, v)
            missed = truth.board.charuco is None and not _all_visible({cam: model}, {cam: pose},
                                                                      np.vstack([X, outline]), margin=0.0)
            out[cam][v] = np.full((len(X), 2), np.nan) if missed else seen_pixels(model, pose, X)
            if truth.board.is_circle_grid:      # a circle's centre as measured: its image's (geometry.circles)
                out[cam][v] += circle_centre_offset_px(model, pose, X, 0.5 * truth.board.circle_diameter_mm)
    return out


def noisy_corner_set(truth: SynthTruth, noise_px: float, seed: int = 0) -> CornerSet:
    """Exact corners plus isotropic Gaussian noise of ``noise_px`` per coordinate.

    Parameters
    ----------
    truth : SynthTruth
        The synthetic rig (:func:`make_truth`).
    noise_px : float
        Standard deviation of the noise, pixels per coordinate (0: the exact corners).
    seed : int
        Seed of the noise.

    Returns
    -------
    CornerSet
        Every camera's corners in every view, as detection would give them (a view a camera misses is None).
    """
    rng = np.random.default_rng(seed)
    cams = {}
    for cam, views in true_corners(truth).items():
        noisy = {v: uv + rng.normal(0.0, noise_px, uv.shape) for v, uv in views.items()}
        noisy = {v: None if np.isnan(uv).all() else uv for v, uv in noisy.items()}
        cams[cam] = CameraCorners(truth.cameras[cam].image_size, noisy)
    return CornerSet(truth.board, cams)


def truth_rig_model(truth: SynthTruth, corners: CornerSet | None = None) -> RigModel:
    """The truth as a :class:`RigModel` (zero sigmas), e.g. to write truth.json or to evaluate.

    Parameters
    ----------
    truth : SynthTruth
        The synthetic rig (:func:`make_truth`).
    corners : CornerSet or None
        The corners the model carries (default: the exact ones).

    Returns
    -------
    RigModel
        The true cameras, rig and poses, in calib.json's form.
    """
    corners = corners if corners is not None else noisy_corner_set(truth, 0.0)
    zero3 = np.zeros(3)
    rig = {n: RigRelation(p, zero3, 0.0, zero3) for n, p in truth.rig.items()}
    poses = {cam: {v: truth.camera_pose(cam, v) for v in truth.view_poses} for cam in truth.cameras}
    return RigModel(truth.board, truth.reference, True, "truth", dict(truth.cameras),
                    {c: dict.fromkeys(INTRINSIC_NAMES, 0.0) for c in truth.cameras},
                    {c: 0.0 for c in truth.cameras}, rig, poses,
                    {v: {c: 0.0 for c in truth.cameras} for v in truth.view_poses}, 0.0, corners)


def photographed(truth: SynthTruth, corners: CornerSet, view: str, board_pose: Pose, cameras,
                 noise_px: float, rng: np.random.Generator) -> CornerSet:
    """``corners`` with one more instant ``view``: the board at ``board_pose`` (board to reference
    camera) as ``cameras`` photograph it, exact corners plus isotropic noise of ``noise_px``;
    a corner a camera does not see (:func:`in_frame`) is NaN, a photo that shows none None.
    (Following advice in a simulator.)"""
    X = truth.board.object_points_mm()
    cams = {}
    for name, cc in corners.cameras.items():
        views = dict(cc.views)
        if name in cameras:
            uv = seen_pixels(truth.cameras[name], truth.seen_by(name, board_pose), X)
            uv = uv + rng.normal(0.0, noise_px, uv.shape)
            views[view] = uv if np.isfinite(uv[:, 0]).any() else None
        cams[name] = CameraCorners(cc.image_size, views, cc.meta)
    return CornerSet(corners.board, cams, corners.reference)
