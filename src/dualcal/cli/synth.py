"""``dualcal synth``: a synthetic rig with known truth, for the demo, the tests and trying dualcal out."""

from __future__ import annotations

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, board_from_flags, board_options, default_jobs, echo


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
@click.option("--preset", type=LazyChoice("dualcal.synthetic.synth:PRESETS"), default="note8", show_default=True,
              help="The rig: note8 (wide + tele, 12 MP), stereo (640x480 pair), triple (wide + tele + ultra), "
                   "stereo5 (the 640x480 pair with OpenCV's five-coefficient lenses, k1 k2 p1 p2 k3), phone3 "
                   "(wide + 3x tele + a 145-degree fisheye ultra-wide, kb4).")
@click.option("--views", type=int, default=13, show_default=True, help="Number of board poses.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of poses, noise and photos.")
@click.option("--scale", type=float, default=1.0, show_default=True,
              help="Resample the sensors (0.25 gives small, fast photos).")
@click.option("--noise", "noise_px", type=float, default=0.1, show_default=True,
              help="Gaussian noise (px, per coordinate) added to the true corners in corners.json.")
@click.option("--photos/--no-photos", default=True, show_default=True, help="Render photo-like JPEGs.")
@click.option("--roll", is_flag=True,
              help="Write the photos as a phone's camera roll instead: one folder OUTDIR/roll, every lens mixed in "
                   "shooting order with EXIF, a retake, a photo without the board and sidecar files.")
@click.option("--video", is_flag=True,
              help="Write clips instead: OUTDIR/clips/<camera>.mp4 (H.264), the board carried by hand and held still "
                   "--views times, every other camera starting --offset-frames after the reference.")
@click.option("--fps", type=float, default=30.0, show_default=True, help="With --video: the clips' frame rate.")
@click.option("--offset-frames", type=float, default=3.4, show_default=True,
              help="With --video: how many frames after the reference the other cameras start (a fraction too).")
@click.option("--readout-ms", type=float, default=0.0, show_default=True,
              help="With --video: a rolling shutter's readout time, top row to bottom row (0: global shutter).")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Photos rendered in parallel (default: all cores).")
@board_options(required=False, dictionary_default="the smallest DICT_5X5 that holds the markers")
@click.option("--coverage", metavar="LO:HI", default=None,
              help="Share of the board's corners the narrowest camera sees, drawn per view from LO to HI "
                   "(ChArUco boards; default 0.3:1 for them, the whole board for a chessboard).")
@click.option("--breathing", type=click.FloatRange(min=0.0), default=0.0, show_default=True, metavar="B",
              help="The lenses breathe with focus: fx(d) = fx_inf (1 + B f / (d - f)), f the EXIF focal length "
                   "(1: a thin lens), each photo focused on the board; its focus written into its EXIF "
                   "(SubjectDistance, an Apple-style MakerNote's FocusDistanceRange).")
@click.option("--ois", "ois_px", type=click.FloatRange(min=0.0), default=0.0, show_default=True, metavar="PX",
              help="Each photo's principal point moved by optical image stabilisation: a normal draw of PX px per "
                   "coordinate, independent per camera and photo.")
@click.option("--object-photos", is_flag=True,
              help="Also write measurement photos of a textured box at 0.3 m and 2 m (OUTDIR/measure/<distance>mm/"
                   "<camera>.jpg, the same lenses, focused on it); truth.json's measure_photos has the box's corners.")
@click.option("--marks", type=LazyChoice("dualcal.synthetic.render_marks:MARK_KINDS"), default=None,
              help="Print marks in the chessboard's white squares: a binary code in each (as ECoCheck), a dot in "
                   "each, a logo in two, or a serial number along the first row.")
def synth_command(outdir, preset, views, seed, scale, noise_px, photos, roll, video, fps, offset_frames, readout_ms,
                  jobs, board_spec, square_mm, marker_mm, dictionary, circle_mm, coverage, breathing, ois_px,
                  object_photos, marks):
    """Write a synthetic rig with known truth to OUTDIR.

    \b
    OUTDIR/corners.json        true corners plus --noise (input of 'dualcal calibrate')
    OUTDIR/truth.json          the true calibration, in calib.json format
    OUTDIR/photos/<cam>/*.jpg  photo-like renders of the board (a dataset for 'dualcal detect')
    OUTDIR/roll/IMG_*.JPG      with --roll: the same photos as a phone's camera roll
    OUTDIR/clips/<cam>.mp4     with --video: clips instead (truth.json's "video" has the true offsets)
    OUTDIR/measure/...         with --object-photos: photos of a textured box at 0.3 m and 2 m

    With --breathing or --ois every photo has its own lens, recorded in truth.json's "photos"
    (focus, shift, fx, fy, cx, cy per photo; "cameras" then hold the values at infinity).

    --board replaces the preset's board. With a ChArUco board (--board charuco:11x8 --square 25
    --marker 18) the narrowest camera (the tele) sees only part of the board in most views
    (--coverage), and corners.json has null for the corners a photo does not show.
    """
    from ..synthetic import synth
    from ..geometry.board import with_default_markers
    from ..files.io import make_output_folder, rig_to_dict, save_corners, write_json_atomic

    if not 0 < scale <= 4:
        raise InputError(f"--scale {scale}: must be in (0, 4]")
    if noise_px < 0:
        raise InputError(f"--noise {noise_px}: must be >= 0")
    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary, circle_mm)
    board = with_default_markers(board) if board is not None else None
    if marks is not None and board is not None and board.charuco is not None:
        raise InputError("--marks is for chessboards: a ChArUco board has its markers in its white squares")
    share = _coverage(coverage, board)
    own_lenses = breathing > 0 or ois_px > 0
    if own_lenses and (roll or video or marks or (board is not None and board.charuco is not None)):
        raise InputError("--breathing and --ois write a chessboard's photo set (OUTDIR/photos), not with --roll, "
                         "--video, --marks or a ChArUco board")
    if video:
        return _synth_video(outdir, preset, views, seed, scale, fps, offset_frames, readout_ms, board, marks or roll)
    out = make_output_folder(outdir)
    truth = synth.make_truth(preset, views, seed, scale, board=board, coverage=share, breathing=breathing,
                             ois_px=ois_px)
    corners = synth.noisy_corner_set(truth, noise_px, seed)
    save_corners(out / "corners.json", corners)
    doc = rig_to_dict(synth.truth_rig_model(truth, corners))
    if own_lenses or object_photos:
        from ..synthetic import synth_focus
        if own_lenses:
            doc["photos"] = synth_focus.photos_truth_doc(truth)
        if object_photos:
            doc["measure_photos"] = synth_focus.write_object_photos(
                truth, make_output_folder(out / "measure"), seed=seed, breathing=breathing, ois_px=ois_px,
                focal_mm=synth_focus.focal_lengths_mm(preset, truth.cameras, scale))
    write_json_atomic(out / "truth.json", doc)
    if own_lenses and photos:
        from ..synthetic.synth_focus import write_focus_photo_set
        write_focus_photo_set(truth, make_output_folder(out / "photos"), seed=seed, jobs=jobs or default_jobs())
    elif roll:
        from ..synthetic.synth_roll import write_camera_roll
        write_camera_roll(truth, make_output_folder(out / "roll"), seed=seed, jobs=jobs or default_jobs(), marks=marks)
    elif photos:
        from ..synthetic.render import write_photo_set
        write_photo_set(truth, make_output_folder(out / "photos"), seed=seed, jobs=jobs or default_jobs(), marks=marks)
    n = len(truth.view_poses) * len(truth.cameras)
    echo(f"{preset}: {len(truth.cameras)} cameras x {len(truth.view_poses)} views "
         f"({n} {'photos' if photos or roll else 'corner sets'}{' in a camera roll' if roll else ''}) written to {out}")


def _synth_video(outdir, preset, holds, seed, scale, fps, offset_frames, readout_ms, board, other) -> None:
    """``synth --video``: the clips, truth.json with the true offsets (its ``video``) and the held instants."""
    from ..files.io import make_output_folder, rig_to_dict, write_json_atomic
    from ..synthetic import synth
    from ..synthetic.synth_video import make_video_truth, video_truth_doc, write_clips

    if other:
        raise InputError("--video writes clips of a chessboard: --roll and --marks do not apply to it")
    if board is not None and board.charuco is not None:
        raise InputError("--video needs a chessboard (a ChArUco board is not tracked in clips)")
    if holds < 3:
        raise InputError("--video needs --views 3 or more (the times the board is held still)")
    if not 1 <= fps <= 240:
        raise InputError(f"--fps {fps}: must be within 1-240")
    if readout_ms < 0:
        raise InputError(f"--readout-ms {readout_ms}: must be >= 0")
    truth = make_video_truth(preset, holds, seed, scale, fps=fps, offset_frames=offset_frames,
                             readout_s=readout_ms / 1000, board=board)
    odd = [n for n, c in truth.truth.cameras.items() if c.image_size[0] % 2 or c.image_size[1] % 2]
    if odd:
        raise InputError(f"--scale {scale}: camera {odd[0]!r} would be {truth.truth.cameras[odd[0]].image_size}, "
                         "and H.264 needs even sizes: choose another --scale")
    out = make_output_folder(outdir)
    doc = rig_to_dict(synth.truth_rig_model(truth.truth))
    write_json_atomic(out / "truth.json", {**doc, "video": video_truth_doc(truth)})
    write_clips(truth, make_output_folder(out / "clips"), seed=seed)
    echo(f"{preset}: {len(truth.truth.cameras)} clips of {truth.duration_s:.1f} s at {fps:g} fps, the board held "
         f"{holds} times, written to {out / 'clips'}")
