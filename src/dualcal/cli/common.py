"""Options and small helpers shared by the commands."""

from __future__ import annotations

import os

import click

from ..board import Board, parse_board_spec
from ..errors import InputError


def board_options(required: bool):
    """``--board COLSxROWS`` and ``--square MM``; optional where the input file names the board."""
    def decorate(f):
        f = click.option("--square", "square_mm", type=float, metavar="MM", required=required,
                         help="Side of one square in millimetres.")(f)
        return click.option("--board", "board_spec", metavar="COLSxROWS", required=required,
                            help="Inner corners of the chessboard, e.g. 8x5 for a board of 9 x 6 squares.")(f)
    return decorate


def board_from_flags(board_spec: str | None, square_mm: float | None) -> Board | None:
    """A :class:`Board` from the flags, or None when neither is given."""
    if board_spec is None and square_mm is None:
        return None
    if board_spec is None or square_mm is None:
        raise InputError("give both --board COLSxROWS and --square MM")
    if not square_mm > 0:
        raise InputError(f"--square {square_mm}: must be a positive length in millimetres")
    cols, rows = parse_board_spec(board_spec)
    return Board(cols, rows, float(square_mm))


def check_board_agrees(flags: Board | None, from_file: Board, source: str) -> Board:
    """The file's board, after checking that the flags (if any) say the same."""
    if flags is not None and (flags.cols, flags.rows) != (from_file.cols, from_file.rows):
        raise InputError(f"--board {flags.spec()} disagrees with {source}, which has "
                         f"{from_file.spec()}: drop --board or use the matching file")
    if flags is not None and abs(flags.square_mm - from_file.square_mm) > 1e-9 * from_file.square_mm:
        raise InputError(f"--square {flags.square_mm:g} disagrees with {source}, which has "
                         f"{from_file.square_mm:g} mm")
    return from_file


def default_jobs() -> int:
    return max(1, os.cpu_count() or 1)
