"""``dualcal import``: a peer's session or calibration as dualcal's corners.json and intrinsics.json."""

from __future__ import annotations

import re
from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, echo

_SIZE = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


def image_size_flags(values: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    """``--image-size`` values (``WxH`` for every camera, ``CAMERA=WxH`` for one) as ``{camera or "*": (W, H)}``."""
    out = {}
    for value in values:
        name, _, size = value.rpartition("=")
        m = _SIZE.match(size)
        if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
            raise click.BadParameter(f"{value!r}: give WxH in pixels (e.g. 1280x720), or CAMERA=WxH",
                                     param_hint="'--image-size'")
        key = name.strip() or "*"
        if key in out:
            raise InputError(f"--image-size {value}: {'every camera' if key == '*' else key} has a size already")
        out[key] = int(m.group(1)), int(m.group(2))
    return out


def rename_flags(values: tuple[str, ...]) -> dict[str, str]:
    """``--rename NAME=NEW`` values as ``{name: new}``."""
    out = {}
    for value in values:
        old, _, new = value.partition("=")
        if not old.strip() or not new.strip():
            raise click.BadParameter(f"{value!r}: give NAME=NEW, e.g. cam_0=wide", param_hint="'--rename'")
        out[old.strip()] = new.strip()
    return out


@cli.command("import")
@click.argument("fmt", metavar="FORMAT", type=LazyChoice("dualcal.files.imports:FORMATS"))
@click.argument("paths", metavar="PATH...", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write corners.json and intrinsics.json into (created if its parent exists).")
@click.option("--image-size", "image_sizes", multiple=True, metavar="[CAMERA=]WxH",
              help="The image size of cameras whose files do not give it (a caliscope session without "
                   "camera_array.toml, OpenCV's stereo intrinsics.yml): WxH for every camera, CAMERA=WxH for one "
                   "(repeatable).")
@click.option("--session", type=LazyChoice("dualcal.files.imports:CALISCOPE_SESSIONS"), default="auto",
              show_default=True,
              help="caliscope: the recordings to import. auto: the extrinsic ones where the session has them, else "
                   "the intrinsic ones (a csv beside charuco.toml is taken as intrinsic); intrinsic: each camera "
                   "filmed the board alone (its sync_index is no moment the cameras share); extrinsic: every "
                   "sync_index is one moment for every camera.")
@click.option("--rename", "renames", multiple=True, metavar="NAME=NEW",
              help="Name a camera otherwise, e.g. cam_0=wide (repeatable): calibrate --intrinsics matches cameras "
                   "by name.")
def import_command(fmt: str, paths: tuple[Path, ...], output: Path, image_sizes, session: str, renames) -> None:
    """Import a peer's session or calibration: write corners.json and intrinsics.json.

    \b
    caliscope  a session folder (charuco.toml, calibration/extrinsic|intrinsic/
               CHARUCO/xy_CHARUCO.csv, camera_array.toml): corners.json, cameras
               cam_N, instants by sync_index; intrinsics.json from camera_array.toml
    opencv     a cv2.FileStorage YAML, JSON or XML (camera_matrix/distortion_
               coefficients, cameraMatrix/distCoeffs, M1/D1/M2/D2, K/D, dualcal's
               export): intrinsics.json
    kalibr     a camchain YAML (pinhole, radtan or equidistant): intrinsics.json
    mrcal      .cameramodel files, one per camera (LENSMODEL_OPENCV4/5/8/12,
               PINHOLE), named by their stem: intrinsics.json
    colmap     cameras.txt (PINHOLE, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE):
               intrinsics.json

    Each lens becomes one of dualcal's lens models, coefficient for coefficient; a lens
    dualcal has no model for is refused. intrinsics.json is what 'dualcal calibrate
    --intrinsics' takes: a camera with the sigmas of its source (OpenCV's interactive
    calibration) enters as a prior, every other one held fixed; the cameras' poses
    are kept as their 'extrinsics'.
    """
    from ..files.imports import import_files, write_imported

    if session != "auto" and fmt != "caliscope":
        raise InputError(f"--session {session} is for caliscope sessions, not {fmt} files")
    imported = import_files(fmt, paths, image_size=image_size_flags(image_sizes), session=session,
                            rename=rename_flags(renames))
    if imported.corners is not None:
        for line in corner_lines(imported):
            echo(line)
    for name, known in imported.cameras.items():
        cam = known.camera
        how = "a prior (sigma of " + ", ".join(known.sigma) + ")" if known.use == "prior" else "held fixed"
        pose = f", its pose from {imported.frame}" if name in imported.poses and imported.frame else ""
        echo(f"{name}: {cam.model}, {cam.image_size[0]} x {cam.image_size[1]}, fx {cam.fx:.2f} fy {cam.fy:.2f} "
             f"cx {cam.cx:.2f} cy {cam.cy:.2f}, {how}{pose}")
    for path in write_imported(imported, output):
        echo(f"wrote {path}")


def corner_lines(imported) -> list[str]:
    """What an imported session's corners hold: cameras, frames, instants, corners; and what its recordings mean
    for the rig."""
    import numpy as np

    cameras = imported.corners.cameras
    counts = ", ".join(f"{name} {len(cam.views)}" for name, cam in cameras.items())
    instants = {view for cam in cameras.values() for view in cam.views}
    corners = sum(int(np.isfinite(uv[:, 0]).sum()) for cam in cameras.values() for uv in cam.views.values())
    lines = [f"corners: {len(cameras)} cameras (frames: {counts}), {len(instants)} instants, {corners} corners, "
             f"board {imported.corners.board.describe(sizes=True)}"]
    if imported.session == "intrinsic":
        lines.append("caliscope's intrinsic recordings: each camera filmed the board alone, so an instant is no "
                     "moment the cameras share; calibrate will take every lens alone (rig mode none)")
    return lines
