"""``dualcal report`` (the HTML report) and ``dualcal export`` (other tools' formats)."""

from __future__ import annotations

from pathlib import Path

import click

from . import cli
from .common import LazyChoice, echo


@cli.command("report")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="report.html to write.")
@click.option("--eval", "eval_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="An eval.json of this calibration (one of another calibration is refused): adds "
                   "the evaluation table (paper Tables 5, 6).")
def report_command(calib: Path, output: Path, eval_path: Path | None) -> None:
    """Write a self-contained HTML report of a calibration.

    One file with no external link: the parameters with 1-sigma (paper Tables 2-4), residual
    vectors and histograms, per-view RMS with outliers, sensor coverage with hints, the
    distortion curve and map, a 3-D view of the board poses and the rig, and the evaluation
    (paper Tables 5, 6) when --eval is given.
    """
    from ..files.io import check_evaluation_belongs, check_output_file, load_evaluation, write_text_atomic
    from ..pages.report import render_report
    from ..workflow import read_calibration

    check_output_file(output)  # fail before rendering, not after
    rig = read_calibration(calib)
    evaluation = None
    if eval_path is not None:
        evaluation = load_evaluation(eval_path)
        check_evaluation_belongs(rig, evaluation, str(calib), str(eval_path))
    html = render_report(rig, evaluation, progress=True)
    write_text_atomic(output, html)
    echo(f"report written to {output} ({len(html.encode()) / 1e6:.1f} MB)")


@cli.command("export")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", required=True, type=LazyChoice("dualcal.files.export:FORMATS"),
              help="opencv: FileStorage YAML (K, D, R, T in mm); kalibr: camchain YAML (metres); "
                   "colmap: cameras.txt (OPENCV model); mrcal: one .cameramodel per camera (metres).")
@click.option("-o", "--output", required=True, type=click.Path(),  # a str: keeps a trailing "/"
              help="File to write. For mrcal: a folder (gets NAME.cameramodel per camera) or a "
                   "stem (gets STEM-NAME.cameramodel).")
@click.option("--focus", "focus_specs", multiple=True, metavar="CAMERA=METRES",
              help="Export the camera as focused at that distance, where the calibration models its focus "
                   "(calib.json focus_model; repeatable). Default: the focus it was calibrated at (focus_m).")
def export_command(calib: Path, fmt: str, output: str, focus_specs: tuple[str, ...]) -> None:
    """Write a calibration in OpenCV, Kalibr, COLMAP or mrcal format.

    \b
    opencv  cv2.FileStorage YAML: per camera K, D = (k1, k2, p1, p2, k3), image size,
            and R, T with X_cam = R X_ref + T (T in millimetres); per other camera
            the stereo rectification with the reference, R1 R2 P1 P2 Q (as 'dualcal
            rectify' computes it)
    kalibr  camchain YAML: cam0 (reference), cam1, ...; pinhole + radtan
            (k1 k2 p1 p2: a lens model with k3 is refused), T_cn_cnm1 in metres
    colmap  cameras.txt, one OPENCV camera per rig camera (FULL_OPENCV for a lens
            model with k3; principal point + 0.5 px, COLMAP's pixel convention)
    mrcal   LENSMODEL_OPENCV4 .cameramodel files (OPENCV5 for a lens model with k3),
            extrinsics rt_cam_ref (reference camera frame, metres)

    Each format gets the lens model of the calibration (--model of 'dualcal calibrate'),
    with zeros for the coefficients it lacks. None of these formats has a skew term: a
    non-zero skew is dropped with a warning. A camera whose focus the calibration models is
    written at its calibration's focus, or at the one --focus gives.
    """
    from ..errors import InputError
    from ..estimation.focus_model import rig_at_focus
    from ..files.export import write_export
    from ..files.io import load_rig

    rig = load_rig(calib)
    focus = {}
    for spec in focus_specs:
        name, _, metres = spec.partition("=")
        try:
            focus[name] = float(metres)
        except ValueError:
            raise InputError(f"--focus {spec!r}: expected CAMERA=METRES, e.g. tele=0.3") from None
        if name not in rig.cameras or not focus[name] > 0:
            raise InputError(f"--focus {spec!r}: expected a camera of {calib} ({', '.join(rig.cameras)}) and a "
                             "distance above 0 m")
    for path in write_export(rig_at_focus(rig, focus) if focus else rig, fmt, output):
        echo(f"wrote {path}")
