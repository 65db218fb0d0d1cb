"""A synthetic caliscope session with known truth: what a caliscope user hands dualcal, made from a rig.

:func:`make_caliscope_truth` draws a rig as caliscope's own extrinsic test session has one: four webcams of
1280 x 720 around a capture volume about 2 m across, looking in at it from an arc, and its ChArUco board of
4 x 5 squares (54 mm, 12 inner corners) carried through the volume, small in every frame (a tenth of its
width), each moment seen by three or four of the cameras, some of its corners out of a frame. The reference
camera ``cam_0`` is caliscope's world.

:func:`write_caliscope_session` writes it in caliscope's layout (``dualcal import caliscope`` reads it):
``charuco.toml``, ``camera_array.toml`` (the true intrinsics, OpenCV's five coefficients, and each camera's
pose, world to camera, a rotation vector and metres), ``calibration/extrinsic/CHARUCO/xy_CHARUCO.csv`` (every
moment's corners with Gaussian noise, one ``sync_index`` one moment for every camera) and, with
``intrinsic_frames``, ``calibration/intrinsic/CHARUCO/xy_CHARUCO.csv``: each camera filming the board alone,
near it and filling its frame, ``sync_index`` counting that camera's own frames (no moment shared).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..files.io import make_output_folder, write_text_atomic
from ..geometry.board import Board
from ..geometry.camera import CameraModel, in_frame
from ..geometry.model import Pose
from ..geometry.rotation import rotation_from_rotvec, rotvec_from_rotation
from .synth import SynthTruth, _look_at_pose, seen_pixels

__all__ = ["CALISCOPE_BOARD", "make_caliscope_truth", "write_caliscope_session"]

#: caliscope's test board: ChArUco 4 x 5 squares of 54 mm, markers 0.75 of the square, DICT_4X4_50.
CALISCOPE_BOARD = Board.charuco_board((4, 5), 54.0, 40.5, "DICT_4X4_50")
#: Four webcams of 1280 x 720 with OpenCV's five coefficients, as caliscope calibrates them.
_WEBCAMS = [
    CameraModel((1280, 720), 903.5, 907.8, 0.0, 618.3, 394.2, -0.332, 0.046, -0.0041, 0.0038, 0.066,
                model="k1k2p1p2k3"),
    CameraModel((1280, 720), 921.2, 920.4, 0.0, 652.9, 351.6, -0.118, 0.091, 0.0012, -0.0007, -0.041,
                model="k1k2p1p2k3"),
    CameraModel((1280, 720), 884.7, 886.1, 0.0, 633.0, 366.8, -0.254, 0.102, -0.0009, 0.0021, -0.013,
                model="k1k2p1p2k3"),
    CameraModel((1280, 720), 949.0, 947.3, 0.0, 641.4, 372.5, 0.031, -0.145, 0.0017, 0.0005, 0.112,
                model="k1k2p1p2k3"),
]
#: A camera sees the board where its line of sight meets the board's face at less than this from the normal.
MAX_OBLIQUITY_DEG = 70.0
_MIN_CORNERS = 4
_FPS = 30.0


def _sees(cam: CameraModel, pose: Pose, board: Board) -> np.ndarray:
    """(N,) the corners ``cam`` finds with the board at board-to-camera ``pose``: its printed face turned to the
    camera within :data:`MAX_OBLIQUITY_DEG`, the corner inside the frame."""
    X = pose.apply(board.object_points_mm())
    centre = X.mean(axis=0)
    facing = pose.R[:, 2] @ centre / np.linalg.norm(centre)          # board's Z points away from a camera facing it
    if facing < np.cos(np.radians(MAX_OBLIQUITY_DEG)):
        return np.zeros(len(X), bool)
    return in_frame(cam, X)


def make_caliscope_truth(cameras: int = 4, moments: int = 57, seed: int = 0, radius_mm: float = 2000.0,
                         spread_mm: float = 500.0) -> SynthTruth:
    """A rig of webcams around a capture volume and the board's pose at every moment (module docstring).

    Parameters
    ----------
    cameras : int
        2 to 4 webcams, ``cam_0`` .. , on an arc of 120 degrees at ``radius_mm`` from the volume's centre,
        0.1-0.4 m above or below it, each looking at the centre.
    moments : int
        Board poses kept: each seen by at least three cameras (both, for two), with at least four corners in each.
    seed : int
        Seed of the rig's heights and the board's poses.
    radius_mm, spread_mm : float
        The cameras' distance from the volume's centre, and how far from it (along each axis) the board goes.

    Returns
    -------
    SynthTruth
        ``cam_0`` the reference; view keys the moments' ``sync_index``, zero-padded to four digits (as
        ``dualcal import caliscope`` keys them).

    Raises
    ------
    InputError
        Fewer than 2 or more than 4 cameras.
    """
    if not 2 <= cameras <= len(_WEBCAMS):
        raise InputError(f"a synthetic caliscope session has 2 to {len(_WEBCAMS)} cameras, not {cameras}")
    rng = np.random.default_rng(seed)
    names = [f"cam_{i}" for i in range(cameras)]
    centre = np.array([0.0, 0.0, radius_mm])       # the volume's centre in a frame W of the room
    positions, world = {}, {}
    for name, azimuth in zip(names, np.radians(np.linspace(-60.0, 60.0, cameras))):
        height = rng.choice([-1, 1]) * rng.uniform(100.0, 400.0)
        positions[name] = centre + radius_mm * np.array([np.sin(azimuth), 0.0, -np.cos(azimuth)]) + [0, height, 0]
        world[name] = _look_at_pose(positions[name], centre, rng.uniform(-0.05, 0.05))     # W to camera
    reference = world[names[0]]
    rig = {n: world[n].compose(reference.inverse()) for n in names[1:]}
    truth = SynthTruth(CALISCOPE_BOARD, dict(zip(names, _WEBCAMS)), names[0], rig, {})
    middle = truth.board.object_points_mm().mean(axis=0)
    while len(truth.view_poses) < moments:
        # the board's centre somewhere in the volume, its face turned to within 35 degrees of one camera
        at = centre + rng.uniform(-spread_mm, spread_mm, 3) * [1.0, 0.6, 1.0]
        facing = _tilted(positions[names[rng.integers(cameras)]] - at, rng)
        pose = reference.compose(Pose(R := _board_axes(-facing, rng), at - R @ middle))   # board to cam_0
        seen = [n for n, cam in truth.cameras.items()
                if _sees(cam, truth.seen_by(n, pose), truth.board).sum() >= _MIN_CORNERS]
        if len(seen) >= min(3, cameras):
            truth.view_poses[f"{len(truth.view_poses):04d}"] = pose
    return truth


def _board_axes(z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A rotation whose third column is the unit vector ``z`` (the board's normal, into the board), turned about
    it by a random roll: the board's axes in the frame ``z`` is given in."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    roll = rng.uniform(-np.pi, np.pi)
    x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
    return np.column_stack([x, y, z])


def _tilted(direction: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``direction`` as a unit vector, turned by up to 35 degrees about a random axis."""
    d = direction / np.linalg.norm(direction)
    axis = np.cross(d, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    return rotation_from_rotvec(np.radians(rng.uniform(0.0, 35.0)) * axis) @ d


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def _toml(tables: dict[str, dict]) -> str:
    """TOML text of ``{table name (or "" for the top level): {key: value}}``."""
    lines = []
    for table, entries in tables.items():
        if table:
            lines += ["", f"[{table}]"]
        lines += [f"{key} = {_toml_value(value)}" for key, value in entries.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


_HEADER = ("sync_index,cam_id,frame_index,frame_time,object_id,keypoint_id,img_loc_x,img_loc_y,"
           "obj_loc_x,obj_loc_y,obj_loc_z")


def _csv_rows(sync: int, cam_id: int, uv: np.ndarray, board: Board) -> list[str]:
    """caliscope's rows of one camera's corners at ``sync`` (NaN rows: not found); object points in metres
    in caliscope's (OpenCV's) board frame, one square off dualcal's."""
    s_m = board.square_mm / 1000.0
    rows = []
    for k in np.flatnonzero(np.isfinite(uv[:, 0])):
        r, c = divmod(int(k), board.cols)
        rows.append(f"{sync},{cam_id},{sync},{sync / _FPS:.6f},0,{k},{uv[k, 0]:.6f},{uv[k, 1]:.6f},"
                    f"{(c + 1) * s_m:.6f},{(r + 1) * s_m:.6f},")
    return rows


def _intrinsic_poses(cam: CameraModel, board: Board, frames: int, rng: np.random.Generator) -> list[Pose]:
    """Board-to-camera poses of a camera filming the board alone: near it (filling 25-55 % of the frame's
    width), tilted 10-45 degrees, anywhere in the frame, with at least half its corners in it."""
    X = board.object_points_mm()
    middle = X.mean(axis=0)
    width = (board.cols + 1) * board.square_mm
    poses = []
    while len(poses) < frames:
        distance = cam.fx * width / (rng.uniform(0.25, 0.55) * cam.image_size[0])
        uv = rng.uniform([0.15, 0.15], [0.85, 0.85]) * cam.image_size
        at = np.array([(uv[0] - cam.cx) / cam.fx, (uv[1] - cam.cy) / cam.fy, 1.0]) * distance
        axis = np.array([np.cos(phi := rng.uniform(0, 2 * np.pi)), np.sin(phi), 0.0])
        R = rotation_from_rotvec(np.radians(rng.uniform(10.0, 45.0)) * axis) @ rotation_from_rotvec(
            [0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        pose = Pose(R, at - R @ middle)
        if _sees(cam, pose, board).mean() >= 0.5:
            poses.append(pose)
    return poses


def write_caliscope_session(folder, truth: SynthTruth | None = None, *, noise_px: float = 0.3, seed: int = 0,
                            camera_array: bool = True, intrinsic_frames: int = 0) -> SynthTruth:
    """Write a caliscope session of ``truth`` (default: :func:`make_caliscope_truth`) into ``folder``.

    Parameters
    ----------
    folder : str or Path
        The session folder (created if its parent exists).
    truth : SynthTruth, optional
        The rig and the board's moments; cameras named ``cam_N``, its board a ChArUco board.
    noise_px : float
        Gaussian noise of every corner, px per coordinate.
    seed : int
        Seed of the noise (and of the intrinsic recordings).
    camera_array : bool
        Write ``camera_array.toml`` with the true intrinsics and poses.
    intrinsic_frames : int
        Also write each camera's own recording of this many frames (``calibration/intrinsic``).

    Returns
    -------
    SynthTruth
        The truth written.
    """
    truth = truth if truth is not None else make_caliscope_truth(seed=seed)
    folder = make_output_folder(folder)
    rng = np.random.default_rng(seed)
    board = truth.board
    write_text_atomic(folder / "charuco.toml", _toml({"": {
        "columns": board.charuco.squares[0], "rows": board.charuco.squares[1], "board_height": 11.0,
        "board_width": 8.5, "dictionary": board.charuco.dictionary, "units": "inch",
        "aruco_scale": board.charuco.marker_mm / board.square_mm, "square_size_override_cm": board.square_mm / 10.0,
        "inverted": False, "legacy_pattern": bool(board.charuco.legacy)}}))
    if camera_array:
        tables = {}
        for name, cam in truth.cameras.items():
            pose = truth.rig.get(name, Pose(np.eye(3), np.zeros(3)))
            tables[f"cameras.{name.removeprefix('cam_')}"] = {
                "cam_id": int(name.removeprefix("cam_")), "size": list(cam.image_size), "rotation_count": 0,
                "error": float(noise_px * np.sqrt(2.0)), "matrix": cam.K.tolist(), "distortions": list(cam.distortion),
                "translation": (pose.t_mm / 1000.0).tolist(), "rotation": rotvec_from_rotation(pose.R).tolist(),
                "grid_count": 30, "fisheye": cam.fisheye}
        write_text_atomic(folder / "camera_array.toml", _toml(tables))
    X = board.object_points_mm()
    rows = [_HEADER]
    for view, board_pose in truth.view_poses.items():
        for name, cam in truth.cameras.items():
            pose = truth.seen_by(name, board_pose)
            uv = np.where(_sees(cam, pose, board)[:, None], seen_pixels(cam, pose, X), np.nan)
            if np.isfinite(uv[:, 0]).sum() >= _MIN_CORNERS:
                rows += _csv_rows(int(view), int(name.removeprefix("cam_")), uv + rng.normal(0, noise_px, uv.shape),
                                  board)
    _write_csv(folder, "extrinsic", rows)
    if intrinsic_frames:
        rows = [_HEADER]
        for name, cam in truth.cameras.items():
            for frame, pose in enumerate(_intrinsic_poses(cam, board, intrinsic_frames, rng)):
                uv = np.where(_sees(cam, pose, board)[:, None], seen_pixels(cam, pose, X), np.nan)
                rows += _csv_rows(frame, int(name.removeprefix("cam_")), uv + rng.normal(0, noise_px, uv.shape), board)
        _write_csv(folder, "intrinsic", rows)
    return truth


def _write_csv(folder: Path, session: str, rows: list[str]) -> None:
    where = folder / "calibration" / session / "CHARUCO"
    where.mkdir(parents=True, exist_ok=True)
    write_text_atomic(where / "xy_CHARUCO.csv", "\n".join(rows) + "\n")
