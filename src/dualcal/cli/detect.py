"""``dualcal detect`` (photos to corners.json) and ``dualcal pick`` (the paper's manual mode).

:func:`dataset_options` adds the options that read a dataset; ``calibrate`` takes the same ones
and passes them to :func:`dualcal.workflow.read_corners` (:func:`read_corners_from_flags`).
``pick`` takes the same :func:`dataset_selection_options`, so its hints have the view keys
``detect`` and ``calibrate`` use.
"""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import board_from_flags, board_options, echo, exclude_option, square_sigma_option, table_console

DATASET_OPTION_NAMES = ("cameras", "pair_by", "time_tolerance_s", "instant_gap_s", "reference", "exclude", "jobs",
                        "hints_path", "overlays_dir")

_SELECTION_OPTIONS = [
    click.option("--camera", "cameras", multiple=True, metavar="NAME=GLOB",
                 help="A camera and its photos, e.g. --camera left='data/left*.jpg' (repeatable); "
                      "photos are paired by the text the wildcard matched."),
    click.option("--pair-by", "pair_by", type=click.Choice(["stem", "time"]), default="stem",
                 show_default=True, help="Pair photos of the same instant by file stem or EXIF capture time."),
    click.option("--time-tolerance", "time_tolerance_s", type=float, default=2.0, show_default=True,
                 metavar="SECONDS", help="Largest capture-time difference within a pair (--pair-by time)."),
    click.option("--instant-gap", "instant_gap_s", type=float, default=None, metavar="SECONDS",
                 help="A camera roll (one folder, every lens mixed): photos taken up to this apart may be one board "
                      "position, further apart never (default: the roll's own clues decide: the lens sequence, the "
                      "boards' images and poses, the capture times)."),
    click.option("--reference", "reference", metavar="NAME", default=None,
                 help="Reference camera (default: 'wide' if present, else the first name)."),
    exclude_option,
]

_DETECTION_OPTIONS = [
    click.option("--jobs", "jobs", type=click.IntRange(min=1), default=None, metavar="N",
                 help="Photos processed in parallel (default: all cores, fewer for photos so large that they would "
                      "take more than 1.2 GB together)."),
    click.option("--hints", "hints_path", type=click.Path(dir_okay=False), default=None,
                 help="Four clicked corners per photo (from 'dualcal pick') for photos where "
                      "automatic detection fails."),
    click.option("--overlays", "overlays_dir", type=click.Path(file_okay=False), default=None,
                 help="Write small JPEGs with the detected corners numbered into this folder "
                      "(created if its parent exists)."),
]


def dataset_selection_options(f):
    """Click options that find and pair a dataset's photos: ``--camera``, ``--pair-by``,
    ``--time-tolerance``, ``--reference``, ``--exclude`` (keyword names as
    :func:`~dualcal.files.dataset.open_dataset`'s)."""
    for option in reversed(_SELECTION_OPTIONS):
        f = option(f)
    return f


def dataset_options(f):
    """:func:`dataset_selection_options` plus ``--jobs``, ``--hints``, ``--overlays`` (keyword names:
    :data:`DATASET_OPTION_NAMES`): how to read a dataset and detect its corners."""
    for option in reversed(_SELECTION_OPTIONS + _DETECTION_OPTIONS):
        f = option(f)
    return f


def read_corners_from_flags(input_path, board, square_sigma_mm, dataset_opts: dict):
    """:func:`dualcal.workflow.read_corners` of a command's INPUT, board flags and :func:`dataset_options`."""
    from ..workflow import read_corners

    return read_corners(input_path, board, square_sigma_mm=square_sigma_mm, **dataset_opts)


@cli.command("detect")
@click.argument("dataset", type=click.Path(), required=False)
@board_options(required=True)
@square_sigma_option
@dataset_options
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="corners.json to write.")
def detect_command(dataset, board_spec, square_mm, marker_mm, dictionary, circle_mm, square_sigma_mm, output, **opts):
    """Find the board's corners in every photo of DATASET and write corners.json.

    DATASET is a folder with one subfolder of photos per camera (or a folder of photos: one
    camera); or give the cameras one by one with --camera NAME=GLOB. A --reference given here
    is written into corners.json (top-level "reference"), so 'dualcal calibrate' uses it too.
    A ChArUco board (--board charuco:SXxSY --marker MM) may be seen in part: the corners a photo
    does not show are null; without --dictionary, the dictionary is found from the photos.
    """
    from ..files.io import check_output_file, save_corners

    check_output_file(output)
    if dataset is not None and Path(dataset).is_file():
        raise InputError(f"{dataset} is a file: detect reads photos (a dataset folder, or --camera NAME=GLOB)")
    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary, circle_mm)
    corners = read_corners_from_flags(dataset, board, square_sigma_mm, opts)
    save_corners(output, corners)
    if corners.roll:
        from .tables import roll_tables

        console = table_console(stderr=True)
        for table in roll_tables(corners.roll):
            console.print(table)
    from .tables import video_lines

    for line in video_lines(corners):
        echo(line, err=True)
    found = {c: sum(v is not None for v in cc.views.values()) for c, cc in corners.cameras.items()}
    summary = ", ".join(f"{c} {n}/{len(corners.cameras[c].views)}" for c, n in found.items())
    excluded = sum(len(cc.meta.get("excluded", {})) for cc in corners.cameras.values())
    left_out = f"; {excluded} left out by --exclude" if excluded else ""
    partial = sum(len(cc.meta.get("partial_views", [])) for cc in corners.cameras.values())
    if partial:
        left_out += (f"; {partial} show only part of the board, where its corners cannot be numbered "
                     "(see the warnings)")
    echo(f"board found in: {summary} photos{left_out}; wrote {output}", err=True)


def display_problem():
    """Why no window can be opened here, or None (:func:`dualcal.files.detect.display_problem`)."""
    from ..files.detect import display_problem as problem
    return problem()


def pick_hints(todo):
    """The clicking session (:func:`dualcal.files.detect.pick_hints`)."""
    from ..files.detect import pick_hints as pick
    return pick(todo)


@cli.command("pick")
@click.argument("dataset", type=click.Path(), required=False)
@board_options(required=True)
@dataset_selection_options
@click.option("--all", "all_photos", is_flag=True, help="Ask for every photo, not only where detection fails.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="hints.json to write.")
def pick_command(dataset, board_spec, square_mm, marker_mm, dictionary, circle_mm, all_photos, output, **selection):
    """Click the four outer inner-corners of the board in photos where automatic detection fails.

    For each photo click corner 0, corner cols-1 (end of the first row), corner N-1 and corner
    N-cols (start of the last row); right click or Backspace undoes, Enter accepts, Esc skips
    the photo, q stops (the hints so far are kept); the toolbar zooms in. The result is a
    hints file for 'dualcal detect --hints' with the same dataset options. Needs a display.
    """
    from ..files.dataset import open_dataset
    from ..files.detect import detect_photo, save_hints
    from ..files.io import check_output_file
    from ..progress import track

    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary, circle_mm)
    if board.charuco is not None:
        raise InputError(f"pick is for chessboards: {board.describe()} numbers its corners by its markers, "
                         "so a photo that shows part of it needs no clicks")
    problem = display_problem()
    if problem:
        raise InputError(problem)
    check_output_file(output)
    ds = open_dataset(dataset, **selection)
    photos = [(cam, view, photo.path) for cam, views in ds.cameras.items() for view, photo in views.items()]
    todo: dict[str, dict] = {}
    for cam, view, path in track(photos, "looking for boards", enabled=not all_photos):
        if all_photos or detect_photo(path, board).uv is None:
            todo.setdefault(cam, {})[view] = path
    if not todo:
        echo("the board was found automatically in every photo: no hints needed", err=True)
        return
    hints = pick_hints(todo)
    if not hints:
        echo("no photo was clicked: nothing written", err=True)
        return
    save_hints(output, hints)
    echo(f"hints for {sum(len(v) for v in hints.values())} photo(s): wrote {output}", err=True)
