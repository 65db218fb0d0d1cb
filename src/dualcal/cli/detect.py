"""``dualcal detect`` and ``dualcal pick``, and the dataset options other commands share.

``calibrate`` accepts a dataset as its INPUT with the same flags: decorate it with
:func:`dataset_options` and call :func:`corners_from_dataset` with its keyword arguments.
"""

from __future__ import annotations

import functools

import click

from ..board import Board
from ..dataset import open_dataset
from ..detect import detect_dataset, detect_photo, load_hints, pick_hints, save_hints
from ..errors import InputError
from ..io import save_corners
from ..model import CornerSet
from . import cli
from .common import board_from_flags, board_options, default_jobs

DATASET_OPTION_NAMES = ("cameras", "pair_by", "time_tolerance_s", "reference", "jobs", "hints_path",
                        "overlays_dir")


def dataset_options(f):
    """Click options that say how to read a dataset: ``--camera``, ``--pair-by``, ``--time-tolerance``,
    ``--reference``, ``--jobs``, ``--hints``, ``--overlays`` (keyword names: :data:`DATASET_OPTION_NAMES`)."""
    options = [
        click.option("--camera", "cameras", multiple=True, metavar="NAME=GLOB",
                     help="A camera and its photos, e.g. --camera left='data/left*.jpg' (repeatable); "
                          "photos are paired by the text the wildcard matched."),
        click.option("--pair-by", "pair_by", type=click.Choice(["stem", "time"]), default="stem",
                     show_default=True, help="Pair photos of the same instant by file stem or EXIF capture time."),
        click.option("--time-tolerance", "time_tolerance_s", type=float, default=2.0, show_default=True,
                     metavar="SECONDS", help="Largest capture-time difference within a pair (--pair-by time)."),
        click.option("--reference", "reference", metavar="NAME", default=None,
                     help="Reference camera (default: 'wide' if present, else the first name)."),
        click.option("--jobs", "jobs", type=int, default=None, metavar="N",
                     help="Photos processed in parallel (default: all cores)."),
        click.option("--hints", "hints_path", type=click.Path(dir_okay=False), default=None,
                     help="Four clicked corners per photo (from 'dualcal pick') for photos where "
                          "automatic detection fails."),
        click.option("--overlays", "overlays_dir", type=click.Path(file_okay=False), default=None,
                     help="Write small JPEGs with the detected corners numbered into this folder."),
    ]

    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        return f(*args, **kwargs)

    for option in reversed(options):
        wrapper = option(wrapper)
    return wrapper


def corners_from_dataset(dataset_path, board: Board, cameras=(), pair_by: str = "stem",
                         time_tolerance_s: float = 2.0, reference: str | None = None,
                         jobs: int | None = None, hints_path=None, overlays_dir=None) -> CornerSet:
    """Open a dataset and detect its corners (what ``detect`` does before writing corners.json)."""
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs {jobs}: must be at least 1")
    dataset = open_dataset(dataset_path, cameras, pair_by=pair_by, reference=reference,
                           time_tolerance_s=time_tolerance_s)
    hints = load_hints(hints_path) if hints_path else None
    return detect_dataset(dataset, board, jobs=jobs or default_jobs(), hints=hints, overlays_dir=overlays_dir)


@cli.command("detect")
@click.argument("dataset", type=click.Path(), required=False)
@board_options(required=True)
@dataset_options
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="corners.json to write.")
def detect_command(dataset, board_spec, square_mm, output, **opts):
    """Find the chessboard corners in every photo of DATASET and write corners.json.

    DATASET is a folder with one subfolder of photos per camera (or a folder of photos: one
    camera); or give the cameras one by one with --camera NAME=GLOB.
    """
    board = board_from_flags(board_spec, square_mm)
    corners = corners_from_dataset(dataset, board, **opts)
    save_corners(output, corners)
    found = {c: sum(v is not None for v in cc.views.values()) for c, cc in corners.cameras.items()}
    summary = ", ".join(f"{c} {n}/{len(corners.cameras[c].views)}" for c, n in found.items())
    click.echo(f"board found in: {summary} photos; wrote {output}", err=True)


@cli.command("pick")
@click.argument("dataset", type=click.Path(), required=False)
@board_options(required=True)
@click.option("--camera", "cameras", multiple=True, metavar="NAME=GLOB", help="As for 'dualcal detect'.")
@click.option("--pair-by", "pair_by", type=click.Choice(["stem", "time"]), default="stem", show_default=True)
@click.option("--all", "all_photos", is_flag=True, help="Ask for every photo, not only where detection fails.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="hints.json to write.")
def pick_command(dataset, board_spec, square_mm, cameras, pair_by, all_photos, output):
    """Click the four outer inner-corners of the board in photos where automatic detection fails.

    For each photo click corner 0, corner cols-1 (end of the first row), corner N-1 and corner
    N-cols (start of the last row); Enter accepts, Backspace undoes, Esc skips, q quits. The
    result is a hints file for 'dualcal detect --hints'. Needs a display.
    """
    from ..detect.manual import display_available

    if not display_available():
        raise InputError("dualcal pick needs a display and OpenCV with GUI support "
                         "(no DISPLAY, or opencv-python-headless is installed)")
    board = board_from_flags(board_spec, square_mm)
    ds = open_dataset(dataset, cameras, pair_by=pair_by)
    todo = {}
    for cam, photos in ds.cameras.items():
        for view, photo in photos.items():
            if all_photos or detect_photo(photo.path, board).uv is None:
                todo.setdefault(cam, {})[view] = photo.path
    if not todo:
        click.echo("the board was found automatically in every photo: no hints needed", err=True)
        return
    save_hints(output, pick_hints(todo))
    click.echo(f"wrote {output}", err=True)
