"""Which board to print for a rig: squares and size from the cameras' fields of view.

A rig whose cameras' focal lengths differ by 3-6x (a phone's ultra-wide, wide and tele) is calibrated
from photos in which the narrowest camera (the tele) sees the whole board, so the board must stand
far enough for the tele: there it fills at most :data:`TELE_FILL` of the tele's shorter image side.
At that distance the widest camera (the ultra-wide) sees each square at

    ``q_px = f_wide_px * s / d = TELE_FILL * short_tele_px * f_wide_px / (f_tele_px * n)``

pixels, for ``n`` squares along the board's longer side of squares of ``s`` mm, at distance ``d``:
independent of the square size. So the number of squares is bounded by how finely the widest camera
must resolve them (:data:`MIN_SQUARE_PX`, for sub-pixel corners), and the square size by the paper:
the largest whole millimetre that fits. The board has ``cols + rows`` odd (an even and an odd number
of squares), so that its corner 0 is never ambiguous (CONTRACT.md, "Geometry conventions"). Focal
lengths in pixels come from the 35 mm equivalent, ``f_px = f35 * diagonal_px / 43.27 mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..geometry.board import Board
from ..geometry.camera import focal_px_from_35mm
from ..errors import InputError

__all__ = ["BoardChoice", "MIN_SQUARE_PX", "TELE_FILL", "fitting_choice", "suggest_board"]

#: Share of the narrowest camera's shorter image side the board's longer side may fill.
TELE_FILL = 0.7
#: The smallest square, in the widest camera's pixels, whose corners are found to a few hundredths of a px.
MIN_SQUARE_PX = 14.0
#: Squares along the board's longer side: at most (more corners add little, and cost time), at least.
MAX_SQUARES, MIN_SQUARES = 14, 6
#: The margin a printer needs and the board's quiet zone, per side, mm.
PAGE_MARGIN_MM = 15.0


@dataclass(frozen=True)
class BoardChoice:
    """A board for a rig (:func:`suggest_board`): the board, the distance to hold it at (mm) from the
    cameras, and the size of its squares in each camera's pixels there."""

    board: Board
    distance_mm: float
    square_px: dict[str, float]
    narrowest: str
    widest: str

    def describe(self) -> str:
        cols, rows = self.board.cols + 1, self.board.rows + 1
        px = ", ".join(f"{name} {q:.0f} px" for name, q in self.square_px.items())
        return (f"a chessboard of {cols} x {rows} squares of {self.board.square_mm:g} mm (--board "
                f"{self.board.spec()} --square {self.board.square_mm:g}), held about {self.distance_mm / 1000:.2f} m "
                f"from the phone: there the {self.narrowest} sees it whole ({TELE_FILL:.0%} of its shorter side) "
                f"and a square is {px}")


def suggest_board(cameras: dict[str, tuple[tuple[int, int], float]], paper_mm: tuple[float, float]) -> BoardChoice:
    """The board to print on a page of ``paper_mm`` for cameras ``{name: (image size (W, H), f35 mm)}``.

    Raises
    ------
    InputError
        No camera, or the widest camera cannot resolve :data:`MIN_SQUARE_PX` squares of even the
        smallest board where the narrowest sees it whole (focal lengths too far apart for one board).
    """
    if not cameras:
        raise InputError("no camera to choose a board for")
    f = {name: focal_px_from_35mm(size, f35) for name, (size, f35) in cameras.items()}
    narrow, wide = max(f, key=f.get), min(f, key=f.get)
    short_narrow = min(cameras[narrow][0])
    n_max = math.floor(TELE_FILL * short_narrow * f[wide] / (f[narrow] * MIN_SQUARE_PX))
    if n_max < MIN_SQUARES:
        raise InputError(f"the {wide}'s focal length is {f[narrow] / f[wide]:.1f} x shorter than the {narrow}'s: where "
                         f"the {narrow} sees a board whole, the {wide} cannot resolve {MIN_SQUARES} squares across it; "
                         "calibrate the two with separate boards or distances")
    n = min(MAX_SQUARES, n_max)
    w, h = sorted(paper_mm, reverse=True)
    page_w, page_h = w - 2 * PAGE_MARGIN_MM, h - 2 * PAGE_MARGIN_MM - 24.0      # 24 mm: the spec and scale bar
    m = max(MIN_SQUARES - 1, round(n * page_h / page_w))
    if (n + m) % 2 == 0:
        m -= 1
    s = math.floor(min(page_w / n, page_h / m))
    distance = f[narrow] * n * s / (TELE_FILL * short_narrow)
    board = Board(n - 1, m - 1, float(s))
    return BoardChoice(board, distance, {name: f[name] * s / distance for name in sorted(f, key=f.get)},
                       narrow, wide)


def fitting_choice(cameras: dict[str, tuple[tuple[int, int], float]], paper: str) -> BoardChoice:
    """:func:`suggest_board` for a paper of :data:`dualcal.files.boardprint.PAPERS`, its squares made smaller by
    whole millimetres until the page (:func:`dualcal.files.boardprint.page_layout`) holds the board."""
    from dataclasses import replace

    from .boardprint import PAPERS, page_layout

    if paper not in PAPERS:
        raise InputError(f"paper {paper!r}: choose one of {', '.join(PAPERS)}")
    choice = suggest_board(cameras, PAPERS[paper])
    while True:
        try:
            page_layout(choice.board, paper)
            return choice
        except InputError:
            if choice.board.square_mm <= 5:
                raise
        s = choice.board.square_mm - 1.0
        scale = s / choice.board.square_mm
        choice = replace(choice, board=replace(choice.board, square_mm=s), distance_mm=choice.distance_mm * scale)
