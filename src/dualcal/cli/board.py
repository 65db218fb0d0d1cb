"""``dualcal board``: the printable board that a command line describes (a shell over :mod:`dualcal.files.boardprint`)."""

from __future__ import annotations

import click

from ..errors import InputError
from . import cli
from .common import board_from_flags, board_options, echo


@cli.command("board")
@click.argument("spec", metavar="[COLSxROWS|charuco:SXxSY|acircles:COLSxROWS]", required=False)
@board_options(required=False, dictionary_default="the smallest DICT_5X5 that holds the markers")
@click.option("--paper", default="auto", show_default=True, metavar="NAME",
              help="A4, A3, A2, A1, A0, letter, legal (either orientation), fit (the board and its margins) "
                   "or auto (the smallest A size that holds the board).")
@click.option("--dpi", type=float, default=None, metavar="DPI", help="Pixels per inch of a PNG (required for one).")
@click.option("--for", "for_photos", type=click.Path(exists=True), default=None, metavar="PHOTOS",
              help="Suggest the board for the cameras of these photos (a camera roll or a dataset: their EXIF "
                   "focal lengths): the tele must see it whole where the ultra-wide still resolves its squares.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="board.pdf or board.png to write.")
def board_command(spec, board_spec, square_mm, marker_mm, dictionary, circle_mm, paper, dpi, for_photos, output):
    """Write the board to print: a PDF at true scale, or a PNG at --dpi.

    \b
    dualcal board charuco:11x8 --square 25 --marker 18 -o board.pdf
    dualcal board --board 8x5 --square 30 -o chessboard.png --dpi 300
    dualcal board acircles:4x11 --square 20 --circle 12 -o circles.pdf

    The board is given as the first argument or with --board, as for the other commands: a
    chessboard's inner corners (8x5 prints 9 x 6 squares), a ChArUco board's squares, or a circle
    grid's circles (circles:COLSxROWS or acircles:COLSxROWS, OpenCV's count). A ChArUco
    board without --dictionary uses the smallest DICT_5X5 dictionary that holds its markers, in
    OpenCV's current layout. The margin names the options that read the board back, and a scale
    bar checks the print: print at 100 % (actual size).

    With --for PHOTOS (a few test shots of every lens, or a camera roll) and no board, the board is
    chosen for those cameras and the paper (default A4): how many squares, how large, and how far
    from the phone to hold it.
    """
    from ..files.boardprint import write_board
    from ..files.io import check_output_file

    if spec is not None and board_spec is not None and spec != board_spec:
        raise InputError(f"the board is given twice ({spec} and --board {board_spec}): give it once")
    if for_photos is not None:
        if (spec or board_spec) is not None:
            raise InputError("--for chooses the board for the photos' cameras: give it without a board")
        check_output_file(output)
        board, paper = _board_for(for_photos, paper)
    elif (spec or board_spec) is None:
        raise click.UsageError("give the board: COLSxROWS or charuco:SXxSY (or --board), with --square MM, "
                               "or --for PHOTOS to have it chosen")
    else:
        check_output_file(output)
        board = board_from_flags(spec or board_spec, square_mm, marker_mm, dictionary, circle_mm)
    layout = write_board(board, output, paper=paper, dpi=dpi)
    w, h = layout.page_mm
    sizes = (f"circles of {board.circle_diameter_mm:g} mm, {board.square_mm:g} mm apart" if board.is_circle_grid
             else f"squares of {board.square_mm:g} mm")
    echo(f"{layout.board.describe()}, {sizes}, on a {w:.0f} x {h:.0f} mm page: wrote {output} (print at 100 %)",
         err=True)


def _board_for(photos, paper: str):
    """The board :func:`dualcal.files.board_choice.suggest_board` chooses for the cameras of ``photos``, printed
    to stderr with where to hold it; and the paper it is for (``auto`` is A4)."""
    from ..files.board_choice import fitting_choice
    from ..files.dataset import open_dataset
    from ..files.roll import equivalent_focal_mm

    dataset = open_dataset(photos)
    cameras = {}
    for name, views in dataset.cameras.items():
        photo = next(iter(views.values()))
        f35 = equivalent_focal_mm(photo)
        if f35 is None:
            raise InputError(f"{photo.path}: its EXIF gives no 35 mm-equivalent focal length, so its field of view "
                             "is unknown: choose the board yourself (COLSxROWS --square MM)")
        cameras[name] = (photo.size, f35)
    paper = "A4" if paper == "auto" else paper
    choice = fitting_choice(cameras, paper)
    echo(f"for {', '.join(cameras)}: {choice.describe()}", err=True)
    return choice.board, paper
