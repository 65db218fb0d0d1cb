"""``dualcal evaluate`` (the paper's Tables 5 and 6) and ``dualcal undistort`` (section 1.8)."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, default_jobs, echo, table_console


def _case_photos(name: str, doc: dict) -> str:
    """What a case intersects, from its first pair: 'wide+tele, one instant' or 'wide, two instants'."""
    cams = next(p["cameras"] for p in doc["per_pair"] if p["case"] == name)
    return f"{cams[0]}+{cams[1]}, one instant" if cams[0] != cams[1] else f"{cams[0]}, two instants"


def evaluation_table(doc: dict, n_corners: int):
    """The eval.json document as a rich table like the paper's Tables 5 and 6."""
    from rich.table import Table

    kind = "hold-out: each view resected with a calibration that left it out" if doc.get("holdout") \
        else "photos oriented by the calibration's own poses"
    table = Table(title=f"Stereo intersection of the {n_corners} board corners: RMSE in mm", caption=kind)
    table.add_column("Case")
    table.add_column("Photos")
    for axis in "XYZ":
        table.add_column(f"RMSE {axis}", justify="right")
    table.add_column("Pairs", justify="right")
    for name, case in doc["cases"].items():
        table.add_row(name, _case_photos(name, doc), *(f"{x:.3f}" for x in case["rmse_mm"]), str(case["pairs"]))
    return table


def pose_free_table(doc: dict):
    """eval.json's pose-free length check as a rich table (None where it has none)."""
    from rich.table import Table

    if not doc.get("pose_free"):
        return None
    table = Table(title="Pose-free length check (length errors, mm)",
                  caption="corner-to-corner distances intersected with the rig alone: no board pose absorbs an error")
    for col in ("Case", "RMS", "Largest", "Lengths", "Instants"):
        table.add_column(col, justify="left" if col == "Case" else "right")
    for name, case in doc["pose_free"].items():
        table.add_row(name, f"{case['rms_mm']:.3f}", f"{case['max_mm']:.3f}", str(case["lengths"]),
                      str(case["instants"]))
    return table


@cli.command("evaluate")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="eval.json to write.")
@click.option("--holdout", is_flag=True,
              help="Leave each view out of the calibration in turn and orient it by space resection "
                   "(an honest check; recalibrates once per view, with the calibration's settings and "
                   "without the photos it dropped).")
def evaluate_command(calib: Path, output: Path, holdout: bool) -> None:
    """Check a calibration by stereo intersection of the board corners (paper Tables 5, 6).

    Every corner is intersected from two photos and compared with the board: the reference
    and another camera at the same instant (case "dual"), and each camera at two instants
    (one case per camera). Then the pose-free length check: every dual instant's corners
    intersected with the rig alone, no board pose, and all corner-to-corner distances compared
    with the board's (RMS and largest error). Prints RMSE X, Y, Z in mm per case and writes eval.json, with the
    fingerprint of the calibration it checked ("calibration_fingerprint"), so that 'dualcal
    report' can refuse an eval.json of another calibration.
    """
    from ..files.io import check_output_file, write_json_atomic
    from ..workflow import evaluate_calibration, read_calibration

    check_output_file(output)
    rig = read_calibration(calib)
    doc = evaluate_calibration(rig, holdout=holdout)
    write_json_atomic(output, doc)
    console = table_console()
    console.print(evaluation_table(doc, rig.board.n_corners))
    pose_free = pose_free_table(doc)
    if pose_free is not None:
        console.print(pose_free)


@cli.command("undistort")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--camera", "camera_name", required=True, metavar="NAME",
              help="The camera of calib.json that took the photos.")
@click.option("-o", "--output", "out_dir", required=True, metavar="OUTDIR",
              type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if its parent exists); photos keep their names.")
@click.option("--keep", type=LazyChoice("dualcal.files.rectify:KEEP_MODES"), default="same", show_default=True,
              help="Camera matrix of the output: the calibrated one (same), one that keeps every "
                   "source pixel (all), or one with no empty border (valid).")
@click.option("--jobs", type=click.IntRange(min=1), default=None,
              help="Photos undistorted in parallel (default: all cores).")
def undistort_command(calib: Path, images: tuple[Path, ...], camera_name: str, out_dir: Path, keep: str,
                      jobs: int | None) -> None:
    """Remove lens distortion from photos (paper section 1.8), keeping their EXIF.

    Only the lens distortion is removed: each photo keeps its camera's orientation, so this is
    not a stereo rectification (for a pair whose corresponding points share a row, use 'dualcal
    rectify'). Writes OUTDIR/<photo name> for each photo and OUTDIR/<NAME>.rectified.json, the
    pinhole camera (k1 = k2 = 0) of the undistorted photos. Where the calibration models the camera's
    focus, each photo is taken with its camera at the focus its metadata states.
    """
    from ..estimation.focus_model import camera_at_focus
    from ..files.io import load_rig, write_json_atomic
    from ..files.photos import read_focus
    from ..files.rectify import (check_same_rectified_camera, rectified_camera, rectified_camera_doc,
                                 rectified_json_path, undistort_files)

    rig = load_rig(calib)
    if camera_name not in rig.cameras:
        raise InputError(f"--camera {camera_name!r} is not in {calib} (cameras: {', '.join(rig.cameras)})")
    cam = rig.cameras[camera_name]
    new_cam = rectified_camera(cam, keep)
    doc_path = rectified_json_path(out_dir, camera_name)
    check_same_rectified_camera(doc_path, new_cam)
    written = undistort_files(images, out_dir, cam, new_cam, jobs=jobs or default_jobs(),
                              camera_of=lambda path: camera_at_focus(rig, camera_name, read_focus(path).focus_m))
    if not written:
        raise InputError(f"none of the {len(images)} photos could be rectified (see the warnings above)")
    write_json_atomic(doc_path, rectified_camera_doc(camera_name, keep, calib, new_cam))
    echo(f"{len(written)} of {len(images)} photos undistorted into {out_dir} "
         f"(fx={new_cam.fx:.2f} fy={new_cam.fy:.2f} cx={new_cam.cx:.2f} cy={new_cam.cy:.2f}, "
         f"k1=k2=0: {camera_name}.rectified.json)")
