"""Options and small helpers shared by the commands.

Nothing here imports numpy, OpenCV, scipy or matplotlib: the command modules are imported to
register their commands on every start (``dualcal --version`` too), and import the library only
inside the command functions.
"""

from __future__ import annotations

import importlib
import os

import click

from ..errors import InputError
from ..terminal import printable


class LazyChoice(click.Choice):
    """A :class:`click.Choice` whose choices are a library constant, imported when first needed.

    ``LazyChoice("dualcal.estimation.adjust:RIG_MODES")`` shows and checks the values of
    ``dualcal.estimation.adjust.RIG_MODES`` without importing that module when the command is only listed.
    """

    def __init__(self, source: str):
        self._source = source
        super().__init__(())

    @property
    def choices(self):
        module, name = self._source.split(":")
        return tuple(getattr(importlib.import_module(module), name))

    @choices.setter
    def choices(self, _value):   # click's __init__ assigns the (empty) tuple it was given
        pass


#: The keyword names of :func:`board_options` (what a command hands to :func:`board_from_flags`).
BOARD_OPTION_NAMES = ("board_spec", "square_mm", "marker_mm", "dictionary", "circle_mm")


def square_sigma_option(f):
    """``--square-sigma MM``: the tolerance of the printed squares (keyword ``square_sigma_mm``, None when
    not given: then a corners.json keeps the tolerance it records)."""
    return click.option("--square-sigma", "square_sigma_mm", type=float, metavar="MM", default=None,
                        help="1-sigma of the printed square's size (e.g. 0.05 for a board printed at home and "
                             "measured with a ruler); it enters the sigma of every length: the baseline, t_mm, "
                             "measured points and lengths (default: 0, the squares are exact).")(f)


def board_options(required: bool, dictionary_default: str = "found from the photos"):
    """``--board``, ``--square MM`` and, for a ChArUco board, ``--marker MM`` and ``--dictionary NAME``, for a
    circle grid ``--circle MM``; ``--board`` and ``--square`` optional where the input file names the board.
    ``dictionary_default`` says in the help what a ChArUco board without ``--dictionary`` gets."""
    def decorate(f):
        f = click.option("--circle", "circle_mm", type=float, metavar="MM", default=None,
                         help="Circle grids: diameter of one circle in millimetres (default: 0.4 of --square, as "
                              "OpenCV's gen_pattern.py prints them).")(f)
        f = click.option("--dictionary", "dictionary", metavar="NAME", default=None,
                         help="ChArUco boards: OpenCV's name of the markers' dictionary, e.g. DICT_5X5_100 "
                              f"(default: {dictionary_default}).")(f)
        f = click.option("--marker", "marker_mm", type=float, metavar="MM", default=None,
                         help="ChArUco boards: side of one marker in millimetres.")(f)
        f = click.option("--square", "square_mm", type=float, metavar="MM", required=required,
                         help="Side of one square in millimetres (a circle grid: the distance between "
                              "neighbouring centres).")(f)
        return click.option("--board", "board_spec", metavar="COLSxROWS|charuco:SXxSY|acircles:COLSxROWS",
                            required=required,
                            help="Inner corners of the chessboard, e.g. 8x5 for a board of 9 x 6 squares; the "
                                 "squares of a ChArUco board, e.g. charuco:11x8 (with --marker); or the circles of "
                                 "a symmetric or asymmetric circle grid, circles:COLSxROWS or acircles:COLSxROWS "
                                 "(OpenCV's count, e.g. acircles:4x11).")(f)
    return decorate


def exclude_option(f):
    """``--exclude PATTERN`` (repeatable): photos left out, see :func:`dualcal.files.dataset.is_excluded`."""
    return click.option("--exclude", "exclude", multiple=True, metavar="PATTERN",
                        help="Leave out the photos that match this glob (repeatable). It is matched "
                             "against the view key (IMG_03: every camera's photo of that instant), the "
                             "file name (IMG_03.jpg) and CAMERA/KEY (tele/IMG_03: that camera's photo "
                             "only).")(f)


def board_from_flags(board_spec: str | None, square_mm: float | None, marker_mm: float | None = None,
                     dictionary: str | None = None, circle_mm: float | None = None):
    """A :class:`~dualcal.geometry.board.Board` from the flags (:func:`dualcal.geometry.board.board_from_spec`), or None
    when none is given."""
    if board_spec is None and square_mm is None:
        if circle_mm is not None:
            raise InputError("--circle describes a circle grid: give --board acircles:COLSxROWS (or circles:) "
                             "and --square MM too")
        if marker_mm is not None or dictionary is not None:
            raise InputError("--marker and --dictionary describe a ChArUco board: give --board charuco:SXxSY "
                             "and --square MM too")
        return None
    if board_spec is None or square_mm is None:
        raise InputError("give both --board (COLSxROWS, or charuco:SXxSY) and --square MM")
    from ..geometry.board import board_from_spec
    return board_from_spec(board_spec, square_mm, marker_mm, dictionary, circle_mm=circle_mm)


def default_jobs() -> int:
    return max(1, os.cpu_count() or 1)


def table_console(stderr: bool = False):
    """A rich console on stdout (or ``stderr``) for the commands' tables and lines: it never wraps a plain line
    (paths stay whole for copying), prints no control character (:class:`dualcal.progress.SafeConsole`) and reads
    no markup or emoji codes in what it prints: a photo named ``IMG_01 [edited].jpg`` is printed as it is named
    (rich took ``[edited]`` for a style and dropped it, and a name with ``[/x]`` stopped the command), and the
    tables render a tenth faster."""
    from ..progress import SafeConsole
    return SafeConsole(stderr=stderr, soft_wrap=True, highlight=False, markup=False, emoji=False)


def echo(text: str = "", err: bool = False, nl: bool = True) -> None:
    """``click.echo`` of a line that may hold names: control characters stripped (:func:`dualcal.terminal.printable`)."""
    click.echo(printable(text), err=err, nl=nl)
