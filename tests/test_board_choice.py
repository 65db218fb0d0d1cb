"""Choosing the board for a rig's fields of view (dualcal.files.board_choice)."""

import math

import pytest

from dualcal.files.board_choice import MIN_SQUARE_PX, TELE_FILL, fitting_choice, suggest_board
from dualcal.geometry.camera import focal_px_from_35mm as focal_px
from dualcal.files.boardprint import PAPERS, page_layout
from dualcal.errors import InputError

IPHONE = {"ultra": ((4032, 3024), 13.0), "wide": ((4032, 3024), 24.0), "tele": ((4032, 3024), 77.0)}


@pytest.mark.parametrize("paper", ["A4", "A3"])
def test_the_tele_sees_the_board_whole_where_the_ultra_wide_resolves_its_squares(paper):
    choice = fitting_choice(IPHONE, paper)
    board = choice.board
    page_layout(board, paper)                                     # it fits the page (raises otherwise)
    assert (board.cols + board.rows) % 2 == 1                     # corner 0 is never ambiguous
    long_mm = (max(board.cols, board.rows) + 1) * board.square_mm
    tele_px = focal_px(*IPHONE["tele"]) * long_mm / choice.distance_mm
    assert tele_px <= TELE_FILL * 3024 + 1e-6
    assert choice.square_px["ultra"] >= MIN_SQUARE_PX
    assert choice.narrowest == "tele" and choice.widest == "ultra"
    assert 0.3e3 < choice.distance_mm < 3e3


def test_a_larger_paper_gives_larger_squares_held_further_away():
    a4, a3 = fitting_choice(IPHONE, "A4"), fitting_choice(IPHONE, "A3")
    assert a3.board.square_mm > a4.board.square_mm and a3.distance_mm > a4.distance_mm
    # the squares' size in pixels does not depend on the paper (module docstring)
    assert a3.square_px["ultra"] == pytest.approx(a4.square_px["ultra"], rel=0.1)


def test_focal_lengths_too_far_apart_for_one_board_are_refused():
    with pytest.raises(InputError, match="cannot resolve"):
        suggest_board({"ultra": ((1000, 750), 13.0), "tele": ((1000, 750), 240.0)}, PAPERS["A4"])


def test_focal_px_from_the_35mm_equivalent():
    assert focal_px((4032, 3024), 24.0) == pytest.approx(24.0 * 5040 / math.hypot(36, 24))
