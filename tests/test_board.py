"""Boards: ChArUco geometry against OpenCV's, the board entry of the files, the printed board read back."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from dualcal.geometry.board import DICTIONARIES, Board, board_from_spec, dictionary_name, with_default_markers
from dualcal.files.boardprint import page_layout, write_board
from dualcal.files.detect import detect_photo
from dualcal.files.detect.charuco import aruco_dictionary, opencv_board
from dualcal.errors import InputError
from dualcal.files.io import corners_from_dict, corners_to_dict, load_corners
from dualcal.geometry.model import CameraCorners, CornerSet

CONTRACT_ENTRY = {"cols": 10, "rows": 7, "square_mm": 25.0,
                  "charuco": {"squares": [11, 8], "marker_mm": 18.0, "dictionary": "DICT_5X5_100"}}


@pytest.mark.parametrize("squares", [(11, 8), (11, 7), (6, 5), (5, 4)])
@pytest.mark.parametrize("legacy", [False, True])
def test_charuco_corners_and_markers_are_opencvs_shifted_by_one_square(squares, legacy):
    board = Board.charuco_board(squares, 20.0, 14.0, "DICT_4X4_50", legacy)
    cb = opencv_board(board)
    s = np.array([20.0, 20.0, 0.0])
    np.testing.assert_allclose(board.object_points_mm(), cb.getChessboardCorners() - s, atol=1e-5)
    np.testing.assert_array_equal(cb.getIds().ravel(), np.arange(board.charuco.n_markers))
    np.testing.assert_allclose(board.marker_corners_mm(), np.asarray(cb.getObjPoints()) - s, atol=1e-5)
    # square (-1, -1) is black on OpenCV's current layout, on the legacy one only for an odd SY
    assert (board.black_parity() == 1) == (legacy and squares[1] % 2 == 0)
    # every inner corner touches exactly two marker squares
    assert np.all(board.corner_markers() >= 0)


def test_dictionary_table_is_opencvs():
    for name, (bits, n) in DICTIONARIES.items():
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        assert (d.markerSize, len(d.bytesList)) == (bits, n), name
    assert dictionary_name("dict_apriltag_36H11") == "DICT_APRILTAG_36h11"
    assert dictionary_name("5x5_100") == "DICT_5X5_100"
    cut = aruco_dictionary("DICT_APRILTAG_36h10", 44)
    assert len(cut.bytesList) == 44 and cut.maxCorrectionBits == aruco_dictionary("DICT_APRILTAG_36h10").maxCorrectionBits


def test_contract_board_entry_round_trips_and_chessboards_are_unchanged():
    board = Board.from_dict(CONTRACT_ENTRY)
    assert board.charuco.squares == (11, 8) and board.n_corners == 70 and not board.is_symmetric
    assert board.to_dict() == CONTRACT_ENTRY and board.spec() == "charuco:11x8"
    legacy = replace(board, charuco=replace(board.charuco, legacy=True))
    assert Board.from_dict(legacy.to_dict()) == legacy and legacy.to_dict()["charuco"]["legacy"] is True
    chess = Board(8, 5, 30.0)
    assert chess.to_dict() == {"cols": 8, "rows": 5, "square_mm": 30.0} and chess.spec() == "8x5"
    assert board_from_spec("8x5", 30) == chess
    # an odd number of rows has one layout
    assert Board.charuco_board((11, 7), 25, 18, "DICT_5X5_50", legacy=None).charuco.legacy is False


@pytest.mark.parametrize("change, message", [
    ({"squares": [11]}, "squares"),
    ({"squares": [12, 8]}, "12x8 squares has 11x7 inner corners, not 10x7"),
    ({"marker_mm": 25.0}, "smaller than the square"),
    ({"marker_mm": "18"}, "marker_mm"),
    ({"dictionary": "DICT_5X5_9"}, "not one of OpenCV's predefined"),
    ({"dictionary": "DICT_APRILTAG_16h5"}, "holds 30 markers; a ChArUco board of 11x8 squares needs 44"),
    ({"dictionary": None}, "dictionary"),
    ({"legacy": "yes"}, "legacy"),
    ({"extra": 1}, "malformed"),
])
def test_malformed_charuco_entries_are_refused_naming_the_file(tmp_path, change, message):
    entry = {**CONTRACT_ENTRY, "charuco": {**CONTRACT_ENTRY["charuco"], **change}}
    path = tmp_path / "corners.json"
    path.write_text(json.dumps({"board": entry, "cameras": {"wide": {"image_size": [640, 480], "views": {}}}}))
    with pytest.raises(InputError, match=message) as exc:
        load_corners(path)
    assert str(path) in str(exc.value)


def test_corners_json_with_a_charuco_board_and_null_corners_round_trips():
    board = Board.from_dict(CONTRACT_ENTRY)
    uv = np.full((70, 2), np.nan)
    uv[10:20] = np.arange(20.0).reshape(10, 2)
    cs = CornerSet(board, {"tele": CameraCorners((3024, 4032), {"IMG_01": uv, "IMG_02": None})})
    doc = corners_to_dict(cs)
    assert doc["board"] == CONTRACT_ENTRY and doc["cameras"]["tele"]["views"]["IMG_01"][0] is None
    back = corners_from_dict(json.loads(json.dumps(doc)))
    assert back.board == board
    np.testing.assert_array_equal(back.cameras["tele"].views["IMG_01"], uv)


@pytest.mark.parametrize("args, message", [
    (("charuco:11x8", 25.0), "--marker MM"),
    (("charuco:11x8", 25.0, 30.0), "smaller than the square"),
    (("charuco:11", 25.0, 18.0), "charuco:SXxSY"),
    (("charuco:2x8", 25.0, 18.0), "at least 3x3 squares"),
    (("8x5", 30.0, 18.0), "--marker and --dictionary describe a ChArUco board"),
    (("charuco:11x8", 25.0, 18.0, "DICT_4X4_999"), "not one of OpenCV's predefined"),
    (("charuco:11x8", -1.0, 18.0), "--square"),
])
def test_board_flags_are_checked(args, message):
    with pytest.raises(InputError, match=message):
        board_from_spec(*args)


def test_flags_leave_the_dictionary_and_layout_to_the_photos_and_match_the_files_board():
    given = board_from_spec("charuco:11x8", 25, 18)
    assert given.charuco.dictionary is None and given.charuco.legacy is None
    found = Board.from_dict(CONTRACT_ENTRY)
    assert given.matches(found) and not found.matches(replace(found, square_mm=24.0))
    assert not board_from_spec("charuco:11x8", 25, 18, "DICT_4X4_50").matches(found)
    drawn = with_default_markers(given)
    assert drawn.charuco.dictionary == "DICT_5X5_50" and drawn.charuco.legacy is False


# ---------------------------------------------------------------------------- the printed board


def _expected_px(layout, dpi):
    """Where corner k is on a page rendered at ``dpi`` (per axis): pixel centres at (j, i), mm * dpi / 25.4."""
    xy_mm = np.asarray(layout.origin_mm) + layout.board.object_points_mm()[:, :2]
    return xy_mm * np.asarray(dpi) / 25.4 - 0.5


@pytest.mark.parametrize("spec, square, marker", [("charuco:11x8", 25.0, 18.0), ("8x5", 30.0, None)])
def test_printed_png_is_read_back_at_true_scale_by_opencv_and_dualcal(tmp_path, spec, square, marker):
    dpi = 100.0
    path = tmp_path / "board.png"
    layout = write_board(board_from_spec(spec, square, marker), path, dpi=dpi)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img.shape[::-1] == tuple(round(x * dpi / 25.4) for x in layout.page_mm)
    # as a camera sees the print: slightly blurred (a perfectly sharp edge is no photo)
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), cv2.GaussianBlur(img, (0, 0), 1.0))
    blurred = cv2.imread(str(photo), cv2.IMREAD_GRAYSCALE)
    expected = _expected_px(layout, dpi)
    board = layout.board
    res = detect_photo(photo, board)
    assert res.uv is not None, res.reason
    np.testing.assert_allclose(res.uv, expected, atol=0.05)        # 0.013 mm at 100 dpi
    if board.charuco is not None:
        corners, ids, _, _ = cv2.aruco.CharucoDetector(opencv_board(board)).detectBoard(blurred)
        assert len(ids) == board.n_corners
        np.testing.assert_allclose(corners.reshape(-1, 2), expected[ids.ravel()], atol=0.1)
    else:
        found, corners = cv2.findChessboardCorners(blurred, (board.cols, board.rows))
        assert found
        np.testing.assert_allclose(corners.reshape(-1, 2), expected, atol=0.3)


def test_printed_pdf_has_the_page_size_and_is_read_back_at_true_scale(tmp_path):
    pdfium = pytest.importorskip("pypdfium2", reason="pypdfium2 (test extra) renders the PDF back")
    path = tmp_path / "board.pdf"
    layout = write_board(board_from_spec("charuco:7x5", 30.0, 22.0, "DICT_6X6_50"), path)
    page = pdfium.PdfDocument(str(path))[0]
    np.testing.assert_allclose(np.asarray(page.get_size()) * 25.4 / 72.0, (297.0, 210.0), atol=0.01)  # A4
    dpi = 120.0
    img = page.render(scale=dpi / 72.0, grayscale=True).to_numpy()
    photo = tmp_path / "pdf.png"
    cv2.imwrite(str(photo), cv2.GaussianBlur(np.ascontiguousarray(img[..., 0] if img.ndim == 3 else img), (0, 0), 1.0))
    res = detect_photo(photo, layout.board)
    assert res.uv is not None, res.reason
    # PDFium rounds the bitmap to whole pixels: its scale is the bitmap's size over the page's
    scale = np.asarray(img.shape[1::-1]) / (np.asarray(layout.page_mm) / 25.4)
    np.testing.assert_allclose(scale, dpi, rtol=2e-3)
    np.testing.assert_allclose(res.uv, _expected_px(layout, scale), atol=0.05)


def test_page_sizes_and_refusals():
    board = board_from_spec("charuco:11x8", 25.0, 18.0)
    assert page_layout(board).page_mm == (420.0, 297.0)                 # A3: A4 is too small
    assert page_layout(board, "fit").page_mm[0] == pytest.approx(275.0 + 2 * 12.5)
    with pytest.raises(InputError, match="does not fit on A4"):
        page_layout(board, "A4")
    with pytest.raises(InputError, match="--paper 'B5'"):
        page_layout(board, "B5")


def test_board_command_writes_the_file_and_refuses_bad_usage(tmp_path, run_cli):
    code, _, err = run_cli("board", "charuco:5x4", "--square", "30", "--marker", "20", "-o", tmp_path / "b.pdf")
    assert code == 0 and (tmp_path / "b.pdf").read_bytes()[:5] == b"%PDF-" and "DICT_5X5_50" in err
    code, _, err = run_cli("board", "--board", "8x5", "--square", "30", "-o", tmp_path / "c.png", "--dpi", "50")
    assert code == 0 and cv2.imread(str(tmp_path / "c.png")) is not None
    for args, message in [(("charuco:5x4", "--square", "30", "--marker", "20", "-o", tmp_path / "b.png"), "--dpi"),
                          (("charuco:5x4", "--square", "30", "--marker", "20", "-o", tmp_path / "b.svg"), ".pdf"),
                          (("8x5", "--board", "7x5", "--square", "30", "-o", tmp_path / "d.pdf"), "given twice"),
                          (("8x5", "-o", tmp_path / "d.pdf"), "--square")]:
        code, _, err = run_cli("board", *args)
        assert code == 2 and message in err and len([ln for ln in err.splitlines() if ln.strip()]) == 1, err
    assert not (tmp_path / "d.pdf").exists()
