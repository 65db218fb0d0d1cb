"""``dualcal calibrate`` and ``dualcal synth``."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, board_from_flags, board_options, check_board_agrees, default_jobs, stdout_console
from .detect import corners_from_dataset, dataset_options


def _load_input(path: str, flags, dataset_opts):
    """corners.json as it is (less the views ``--exclude`` leaves out), or a dataset through detection
    with the board ``flags`` (:func:`~dualcal.cli.common.board_from_flags`)."""
    from ..dataset import exclude_views
    from ..io import load_corners
    from ..progress import warn

    if path is not None and Path(path).is_file() and dataset_opts.get("cameras"):
        raise InputError(f"{path} is a file, but --camera takes photos from globs: give a dataset folder "
                         "(or no INPUT) with --camera, or the corners.json alone")
    if path is None or Path(path).is_dir() or dataset_opts.get("cameras"):
        if flags is None:
            raise InputError("a dataset needs --board (COLSxROWS, or charuco:SXxSY with --marker MM) and --square MM")
        return corners_from_dataset(path, flags, **dataset_opts)
    if not Path(path).exists():
        raise InputError(f"{path}: no such file or folder (give a corners.json or a dataset folder)")
    ignored = [flag for key, flag in (("jobs", "--jobs"), ("hints_path", "--hints"), ("overlays_dir", "--overlays"))
               if dataset_opts.get(key)]
    if ignored:
        warn(f"{', '.join(ignored)} only apply to a dataset; {path} is a corners.json, so they are ignored")
    corners = load_corners(path)
    check_board_agrees(flags, corners.board, str(path))
    return exclude_views(corners, dataset_opts.get("exclude", ()))


@cli.command("calibrate")
@click.argument("input_path", metavar="INPUT", type=click.Path(), required=False)
@board_options(required=False)
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="calib.json to write.")
@click.option("--skew", is_flag=True, help="Estimate skew (the paper's Model 2); default skew = 0 (Model 1).")
@click.option("--rig", "rig_mode", type=LazyChoice("dualcal.adjust:RIG_MODES"), default="rigid", show_default=True,
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
@click.option("--model", "model", type=LazyChoice("dualcal.camera:LENS_MODELS"), default="k1k2", show_default=True,
              help="Lens model: k1k2 (the paper's, two radial terms), k1k2k3 (three), k1k2p1p2 (two radial and "
                   "two tangential), k1k2p1p2k3 (OpenCV's five coefficients).")
@click.option("--compare-models/--no-compare-models", default=True, show_default=True,
              help="Also solve the other skew model and print both side by side, as the paper's tables do.")
@click.option("--compare-lens/--no-compare-lens", "compare_lens", default=True, show_default=True,
              help="Also calibrate with every other lens model, compare them by their error on instants left "
                   "out of the calibration, and recommend one (recorded in calib.json).")
@dataset_options
def calibrate_command(input_path, board_spec, square_mm, marker_mm, dictionary, output, skew, rig_mode,
                      drop_outliers, outlier_factor, board_shape, model, compare_models, compare_lens,
                      **dataset_opts):
    """Calibrate every camera and the rig from INPUT and write calib.json.

    INPUT is a corners.json (from 'dualcal detect', also one edited by hand: views removed,
    corners set to null) or a dataset folder, in which case the corners are detected first (same
    options as 'dualcal detect'). Prints a table of every photo (RMS per camera, kept, dropped
    or left out and why), then the parameters with their 1-sigma (the paper's Tables 2-4), the
    lens models compared by their error on instants left out, and the checks' verdict.
    """
    from dataclasses import asdict

    from ..board import SHAPE_TERMS
    from ..calibrate import calibrate_rig
    from ..checks import failed_checks, verdict
    from ..errors import EstimationError
    from ..io import check_output_file, save_rig
    from ..model_selection import compare_lens_models
    from ..progress import warn
    from ..tables import lens_model_advice, lens_model_table, photo_table, result_tables

    if input_path is None and not dataset_opts.get("cameras"):
        raise click.UsageError("give INPUT (a corners.json or a dataset folder) or --camera NAME=GLOB")
    if not outlier_factor > 1:
        raise InputError(f"--outlier-factor {outlier_factor}: must be greater than 1")
    check_output_file(output)
    corners = _load_input(input_path, board_from_flags(board_spec, square_mm, marker_mm, dictionary), dataset_opts)
    kwargs = dict(rig_mode=rig_mode, reference=dataset_opts.get("reference"), drop_outliers=drop_outliers,
                  outlier_factor=outlier_factor, board_shape=board_shape, model=model)
    rig = calibrate_rig(corners, skew=skew, **kwargs)
    lens_scores = None
    if compare_lens:
        try:
            lens_scores = compare_lens_models(rig)
            rig.adjustment["lens_models"] = [asdict(s) for s in lens_scores]
        except EstimationError as exc:
            warn(f"the lens models could not be compared: {exc}")
    save_rig(output, rig)
    models = [rig]
    if compare_models:
        try:
            other = calibrate_rig(corners, skew=not skew, **kwargs)
            models = [other, rig] if skew else [rig, other]
        except EstimationError as exc:
            warn(f"the other skew model could not be solved for comparison: {exc}")
    console = stdout_console()
    console.print(photo_table(rig))
    for table in result_tables(models):
        console.print(table)
    if rig.board_shape_mm is not None:
        console.print(f"board shape estimated: sag {rig.board_sag_mm():.2f} mm "
                      f"({', '.join(f'{t} {w:+.2f} mm' for t, w in zip(SHAPE_TERMS, rig.board_shape_mm))})")
    console.print(f"RMS reprojection error (2-D, per corner) {rig.rms_px:.3f} px, s0 (per coordinate) "
                  f"{rig.adjustment['s0_px']:.3f} px, rig mode {rig.rig_mode}, lens model {rig.model}; written {output}")
    if lens_scores:
        console.print(lens_model_table(lens_scores, rig.model))
        console.print(lens_model_advice(lens_scores, rig.model))
    console.print(verdict(rig.checks))
    for name in failed_checks(rig.checks):
        console.print(f"  {name}: {rig.checks[name]['message']}")


def _coverage(text: str | None, board) -> tuple[float, float] | None:
    """``--coverage LO:HI`` as a pair (None: the whole board in every camera)."""
    charuco = board is not None and board.charuco is not None
    if text is None:
        return (0.3, 1.0) if charuco else None
    if not charuco:
        raise InputError("--coverage needs a ChArUco board (--board charuco:SXxSY): a chessboard must be seen whole")
    lo, sep, hi = text.partition(":")
    try:
        pair = (float(lo), float(hi if sep else lo))
    except ValueError:
        raise InputError(f"--coverage {text!r}: give LO:HI, two shares of the board, e.g. 0.3:1") from None
    if not 0 < pair[0] <= pair[1] <= 1:
        raise InputError(f"--coverage {text!r}: needs 0 < LO <= HI <= 1")
    return pair


@cli.command("synth")
@click.argument("outdir", type=click.Path(file_okay=False))
@click.option("--preset", type=LazyChoice("dualcal.synth:PRESETS"), default="note8", show_default=True,
              help="The rig: note8 (wide + tele, 12 MP), stereo (640x480 pair), triple (wide + tele + ultra), "
                   "stereo5 (the 640x480 pair with OpenCV's five-coefficient lenses, k1 k2 p1 p2 k3).")
@click.option("--views", type=int, default=13, show_default=True, help="Number of board poses.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of poses, noise and photos.")
@click.option("--scale", type=float, default=1.0, show_default=True,
              help="Resample the sensors (0.25 gives small, fast photos).")
@click.option("--noise", "noise_px", type=float, default=0.1, show_default=True,
              help="Gaussian noise (px, per coordinate) added to the true corners in corners.json.")
@click.option("--photos/--no-photos", default=True, show_default=True, help="Render photo-like JPEGs.")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Photos rendered in parallel (default: all cores).")
@board_options(required=False, dictionary_default="the smallest DICT_5X5 that holds the markers")
@click.option("--coverage", metavar="LO:HI", default=None,
              help="Share of the board's corners the narrowest camera sees, drawn per view from LO to HI "
                   "(ChArUco boards; default 0.3:1 for them, the whole board for a chessboard).")
@click.option("--marks", type=click.Choice(["code", "dots", "logo", "text"]), default=None,
              help="Print marks in the chessboard's white squares: a binary code in each (as ECoCheck), a dot in "
                   "each, a logo in two, or a serial number along the first row.")
def synth_command(outdir, preset, views, seed, scale, noise_px, photos, jobs, board_spec, square_mm, marker_mm,
                  dictionary, coverage, marks):
    """Write a synthetic rig with known truth to OUTDIR.

    \b
    OUTDIR/corners.json        true corners plus --noise (input of 'dualcal calibrate')
    OUTDIR/truth.json          the true calibration, in calib.json format
    OUTDIR/photos/<cam>/*.jpg  photo-like renders of the board (a dataset for 'dualcal detect')

    --board replaces the preset's board. With a ChArUco board (--board charuco:11x8 --square 25
    --marker 18) the narrowest camera (the tele) sees only part of the board in most views
    (--coverage), and corners.json has null for the corners a photo does not show.
    """
    from .. import synth
    from ..board import with_default_markers
    from ..io import make_output_folder, rig_to_dict, save_corners, write_json_atomic

    if not 0 < scale <= 4:
        raise InputError(f"--scale {scale}: must be in (0, 4]")
    if noise_px < 0:
        raise InputError(f"--noise {noise_px}: must be >= 0")
    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary)
    board = with_default_markers(board) if board is not None else None
    if marks is not None and board is not None and board.charuco is not None:
        raise InputError("--marks is for chessboards: a ChArUco board has its markers in its white squares")
    share = _coverage(coverage, board)
    out = make_output_folder(outdir)
    truth = synth.make_truth(preset, views, seed, scale, board=board, coverage=share)
    corners = synth.noisy_corner_set(truth, noise_px, seed)
    save_corners(out / "corners.json", corners)
    write_json_atomic(out / "truth.json", rig_to_dict(synth.truth_rig_model(truth, corners)))
    if photos:
        from ..render import write_photo_set
        write_photo_set(truth, make_output_folder(out / "photos"), seed=seed, jobs=jobs or default_jobs(), marks=marks)
    n = len(truth.view_poses) * len(truth.cameras)
    click.echo(f"{preset}: {len(truth.cameras)} cameras x {len(truth.view_poses)} views "
               f"({n} {'photos' if photos else 'corner sets'}) written to {out}")
