"""``dualcal calibrate``."""

from __future__ import annotations

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, board_from_flags, board_options, square_sigma_option, table_console
from .detect import dataset_options, read_corners_from_flags


@cli.command("calibrate")
@click.argument("input_path", metavar="INPUT", type=click.Path(), required=False)
@board_options(required=False)
@square_sigma_option
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="calib.json to write.")
@click.option("--skew", is_flag=True, help="Estimate skew (the paper's Model 2); default skew = 0 (Model 1).")
@click.option("--rig", "rig_mode", type=LazyChoice("dualcal.estimation.adjust:RIG_MODES"), default="rigid", show_default=True,
              help="rigid: one relative pose per camera; paper: per-view poses with the paper's "
                   "constraints (equal baseline and angles); none: each camera alone.")
@click.option("--drop-outliers/--keep-outliers", default=True, show_default=True,
              help="Leave out corners whose residuals are far out of line (and photos where most corners are), "
                   "and re-adjust.")
@click.option("--outlier-factor", type=float, default=6.0, show_default=True,
              help="A corner is an outlier when its residual exceeds this many times the median residual of "
                   "its camera; a photo, when most of its corners are.")
@click.option("--board-shape", "board_shape", type=click.Choice(["auto", "flat", "fit"]), default="auto",
              show_default=True,
              help="auto: estimate the board's sag, bend and twist and keep them where the photos show them "
                   "beyond their noise; fit: always keep them; flat: take the board as flat.")
@click.option("--model", "model", multiple=True, metavar="[CAMERA=]NAME", default=("auto",), show_default=True,
              help="Lens model: k1k2 (the paper's, two radial terms), k1k2k3 (three), k1k2p1p2 (two radial and "
                   "two tangential), k1k2p1p2k3 (OpenCV's five coefficients), kb4 (OpenCV's fisheye), or auto "
                   "(each camera's chosen by its error on instants left out). NAME for every camera, CAMERA=NAME "
                   "(repeatable) for one; cameras not named get the NAME given alone, else k1k2.")
@click.option("--compare-models/--no-compare-models", default=True, show_default=True,
              help="Also solve the other skew model and print both side by side, as the paper's tables do.")
@click.option("--compare-lens/--no-compare-lens", "compare_lens", default=True, show_default=True,
              help="With a --model NAME: also calibrate with every other lens model, compare them by their error "
                   "on instants left out of the calibration, and recommend one (recorded in calib.json). --model "
                   "auto always compares them, camera by camera.")
@click.option("--intrinsics", "intrinsics", multiple=True, metavar="FILE", type=click.Path(),
              help="Known intrinsics (repeatable): a calib.json, an intrinsics.json ('dualcal import' writes them), "
                   "or a peer's file (OpenCV .yml, Kalibr camchain, mrcal .cameramodel, COLMAP cameras.txt). Each "
                   "camera it names takes its lens model and intrinsics from it: a prior with the file's sigma "
                   "where it has one, else held fixed; the other cameras are calibrated as always.")
@dataset_options
def calibrate_command(input_path, board_spec, square_mm, marker_mm, dictionary, circle_mm, square_sigma_mm, output,
                      skew, rig_mode, drop_outliers, outlier_factor, board_shape, model, compare_models, compare_lens,
                      intrinsics, **dataset_opts):
    """Calibrate every camera and the rig from INPUT and write calib.json.

    INPUT is a corners.json (from 'dualcal detect', also one edited by hand: views removed,
    corners set to null) or a dataset folder, in which case the corners are detected first (same
    options as 'dualcal detect'). Prints a table of every photo (RMS per camera, kept, dropped
    or left out and why), then the parameters with their 1-sigma (the paper's Tables 2-4), the
    lens models compared by their error on instants left out, and the checks' verdict.
    """
    from ..geometry.board import SHAPE_TERMS
    from ..estimation.checks import failed_checks, scale_note, verdict
    from ..errors import EstimationError
    from ..files.io import check_output_file, save_rig
    from ..messages import CHECKS, page_of
    from ..progress import warn
    from .tables import (checks_table, lens_model_advice, lens_model_choice_table, lens_model_table, photo_table,
                                lens_motion_lines, result_tables, roll_tables, video_lines)
    from ..workflow import (calibrate_corners, known_intrinsics_for, lens_scores, other_skew_model,
                            read_intrinsics)

    if input_path is None and not dataset_opts.get("cameras"):
        raise click.UsageError("give INPUT (a corners.json or a dataset folder) or --camera NAME=GLOB")
    if not outlier_factor > 1:
        raise InputError(f"--outlier-factor {outlier_factor}: must be greater than 1")
    check_output_file(output)
    model = model_flags(model)
    known = read_intrinsics(intrinsics)               # before the photos are detected: a bad file fails at once
    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary, circle_mm)
    corners = read_corners_from_flags(input_path, board, square_sigma_mm, dataset_opts)
    kwargs = dict(rig_mode=rig_mode, reference=dataset_opts.get("reference"), drop_outliers=drop_outliers,
                  outlier_factor=outlier_factor, board_shape=board_shape, model=model,
                  known_intrinsics=known_intrinsics_for(corners, known))
    rig = calibrate_corners(corners, skew=skew, compare_lens=compare_lens, **kwargs)
    scores = lens_scores(rig)
    save_rig(output, rig)
    models = [rig]
    if compare_models:
        try:
            other = other_skew_model(rig)
            models = [other, rig] if skew else [rig, other]
        except EstimationError as exc:
            warn(f"the other skew model could not be solved for comparison: {exc}")
    console = table_console()
    for table in roll_tables(corners.roll) if corners.roll else ():
        console.print(table)
    for line in video_lines(corners):
        console.print(line)
    console.print(photo_table(rig))
    for table in result_tables(models):
        console.print(table)
    if rig.board_shape_mm is not None:
        console.print(f"board shape estimated: sag {rig.board_sag_mm():.2f} mm "
                      f"({', '.join(f'{t} {w:+.2f} mm' for t, w in zip(SHAPE_TERMS, rig.board_shape_mm))})")
    for line in lens_motion_lines(rig):
        console.print(line)
    console.print(f"RMS reprojection error (2-D, per corner) {rig.rms_px:.3f} px, s0 (per coordinate) "
                  f"{rig.adjustment['s0_px']:.3f} px, rig mode {rig.rig_mode}, lens model {rig.model}; written {output}")
    if scores:
        console.print(lens_model_table(scores, rig.model))
        console.print(lens_model_advice(scores, rig.model))
    if "lens_models_chosen" in rig.adjustment and rig.adjustment.get("lens_models"):  # none: every lens given
        console.print(lens_model_choice_table(rig.adjustment))
    console.print(checks_table(rig))
    console.print(verdict(rig.checks))
    for name in failed_checks(rig.checks):
        page = f" (see {page_of(name)})" if name in CHECKS else ""
        console.print(f"  {name}: {rig.checks[name]['message']}{page}")
    if "scale_plausible" not in rig.checks:
        console.print(f"  note: {scale_note(rig)}; check --square")


def model_flags(values: tuple[str, ...]):
    """``--model`` values as ``calibrate_rig``'s ``model``: ``"auto"``, one name, or ``{camera: name}``
    (with the name given alone, if any, under the key ``"*"`` for the cameras not named)."""
    from ..geometry.camera import LENS_MODELS

    if not values:
        return "auto"
    alone = [v for v in values if "=" not in v]
    named = dict(v.split("=", 1) for v in values if "=" in v)
    for name in alone + list(named.values()):
        if name not in (*LENS_MODELS, "auto"):
            raise click.BadParameter(f"{name!r} is not one of {', '.join((*LENS_MODELS, 'auto'))}",
                                     param_hint="'--model'")
    if len(alone) > 1:
        raise InputError(f"--model {' '.join(alone)}: give one NAME for every camera, and CAMERA=NAME for others")
    if "auto" in alone + list(named.values()) and (named or len(alone) != 1):
        raise InputError("--model auto chooses every camera's model: it cannot be combined with CAMERA=NAME")
    if not named:
        return alone[0]
    return {**({"*": alone[0]} if alone else {}), **named}
