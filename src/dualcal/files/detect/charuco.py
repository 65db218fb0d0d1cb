"""ChArUco corners: markers and ids from OpenCV, sub-pixel corners by dualcal, ids checked by geometry.

A ChArUco board (:mod:`dualcal.geometry.board`) is a chessboard with an ArUco marker in every white
square; the markers' ids say which part of the board a photo shows, so a photo may show any
part of it. Per photo (:func:`detect_charuco`):

1. **Markers** and their ids on a reduced image (1/2-1/8 size, as for chessboards; at twice the
   resolution when the markers found there are small or few), by OpenCV's ``cv2.aruco``
   marker detector (what ``CharucoDetector`` runs first), with the dictionary cut to the board's
   markers. OpenCV's own interpolation of the corners is not used: it would trust every id.
2. **Ids checked against the board's geometry** (:func:`check_markers`): each marker's four
   corners are predicted by the homography of the other markers around it on the board (those
   within :data:`NEIGHBOUR_RADIUS_SQUARES` squares), leaving it out; the worst marker further
   than :data:`MARKER_TOLERANCE` of its own side from its prediction is dropped and the others
   judged again, until every marker left agrees with its neighbours. A misread id puts a marker
   at least one square diagonal (1.4 squares, two marker sides) from where its neighbours say,
   so it cannot pass; a marker without a neighbour cannot be judged and is dropped too. So a
   misread id never reaches the corners.
3. **Corners**: every inner corner touching a marker that passed is predicted by the
   homography of the markers around it (:func:`predict_corners`), then refined at full
   resolution by :func:`dualcal.files.detect.refine.refine_corners` (``cornerSubPix``, then the
   blurred-corner fit) in a window that stays clear of the markers: a marker starts
   ``(s - m) / 2`` from its square's edges, so around a corner a square window of that half-width
   (in pixels, as the local homography maps it, less the blur) holds only the four squares'
   edges, which is the model the fit assumes. A corner whose fit fails or lands further than
   :data:`CORNER_TOLERANCE` of its spacing from its markers' prediction is left out; then,
   where a corner has enough measured neighbours and its squares are small enough for their
   homography to follow the lens (:data:`GRID_CHECK_SPACING`), the chessboard check of
   :mod:`dualcal.geometry.grid` (leave-one-out homography of its neighbours) drops what disagrees.
4. **The view as a whole** (:func:`dualcal.geometry.grid.validate_grid`): at least
   :data:`dualcal.geometry.grid.MIN_CHARUCO_CORNERS` corners, not on one line, no fold.

The dictionary and, for an even number of rows of squares, the layout (OpenCV's current one or
its legacy one, :mod:`dualcal.geometry.board`) are found from the photos when the board does not say
(:func:`resolve_board`): the family of dictionaries and the layout whose markers agree with the
board's geometry in the most markers, over as many photos as it takes to tell the layouts apart
(they differ only at the ends of the rows of markers). A photo that fits the other layout better
than the board's is refused (:func:`detect_charuco`); one that shows no end of a row fits both,
so the layout must come from the dataset (or the file).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ...geometry.board import DICTIONARIES, Board, dictionary_family, smallest_dictionary
from ...errors import DetectionError
from .coarse import reduce_image, reduction_factor, to_full_resolution
from ...geometry.grid import local_spacing_px, validate_grid
from .refine import MeasuredGrid, drop_outliers, photo_edge_width_px, refine_measured, window_half_size

__all__ = ["opencv_board", "detect_markers", "check_markers", "agreeing_markers", "predict_corners",
           "detect_charuco", "measure_charuco", "marker_scores", "resolve_board"]

#: Markers whose centres lie within this many squares of a marker's centre (on the board) are
#: its neighbours: the 8 around it (diagonals at 1.41 squares, in line at 2).
NEIGHBOUR_RADIUS_SQUARES = 2.1
#: A marker is accepted when its corners lie within this share of its side from where its
#: neighbours put them (a misread id is off by two sides or more).
MARKER_TOLERANCE = 0.25
#: A refined corner must lie within this share of its spacing from its markers' prediction.
CORNER_TOLERANCE = 0.1
#: The chessboard check of a corner against its neighbours (:func:`dualcal.geometry.grid.worst_outlier`)
#: applies where its spacing is at most this share of the image's long side: there the
#: neighbours of exact corners predict them to within 0.1 px through a phone's lens, beyond it
#: (squares of 3-12 % of the frame) the lens bends a 5 x 5 patch by 0.3-5 px.
GRID_CHECK_SPACING = 0.025
#: Markers with fewer pixels per cell than this (on the reduced image; a marker of ``n x n`` bits
#: has ``n + 2`` cells a side, its border included) are looked for again at twice the resolution:
#: on renders OpenCV's decoder finds every marker from about 2 pixels per cell, and starts to
#: miss some below.
MIN_PX_PER_CELL = 3.5
#: Pixels of blur kept between a corner's refinement window and the markers.
BLUR_MARGIN_PX = 1.5


def aruco_dictionary(name: str, n_markers: int | None = None):
    """OpenCV's predefined dictionary ``name`` (a key of :data:`dualcal.geometry.board.DICTIONARIES`), cut to
    its first ``n_markers`` markers when given.

    A board uses only the first markers of its dictionary, and the cut dictionary reads them
    alike (its markers are as far apart as before, and it keeps the same error correction), but
    its decoder compares each candidate with ``n_markers`` codes instead of up to 2320: 0.05 s
    instead of 0.4-2.8 s on a 1000 x 750 image.
    """
    full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    if n_markers is None or n_markers >= len(full.bytesList):
        return full
    return cv2.aruco.Dictionary(full.bytesList[:n_markers], full.markerSize, full.maxCorrectionBits)


def opencv_board(board: Board):
    """The ``cv2.aruco.CharucoBoard`` of a ChArUco board whose dictionary and layout are known."""
    ch = board.charuco
    cb = cv2.aruco.CharucoBoard(tuple(ch.squares), board.square_mm, ch.marker_mm, aruco_dictionary(ch.dictionary))
    cb.setLegacyPattern(bool(ch.legacy))
    return cb


def detect_markers(gray: np.ndarray, board: Board, dictionary: str | None = None):
    """ArUco markers of the board's dictionary (or ``dictionary``) in ``gray``.

    Returns ``(uv, ids)``: (M, 4, 2) corners of each marker in ``gray``'s pixels (OpenCV's
    order) and (M,) ids, only ids the board has, each once (an id seen twice is dropped).
    """
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary or board.charuco.dictionary,
                                                        board.charuco.n_markers), _detector_parameters())
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return np.empty((0, 4, 2)), np.empty(0, int)
    uv = np.asarray(corners, float).reshape(-1, 4, 2)
    ids = np.asarray(ids).ravel().astype(int)
    values, counts = np.unique(ids, return_counts=True)
    keep = (ids < board.charuco.n_markers) & np.isin(ids, values[counts == 1])
    return uv[keep], ids[keep]


def _detector_parameters():
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return params


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """Least-squares homography (N >= 4 points, normalised DLT by OpenCV), or None if degenerate."""
    if len(src) < 4:
        return None
    H, _ = cv2.findHomography(np.asarray(src, np.float64), np.asarray(dst, np.float64), 0)
    return H if H is not None and np.all(np.isfinite(H)) else None


def _apply(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[:, :2] / p[:, 2:3]


def _marker_errors(uv: np.ndarray, ids: np.ndarray, board_xy: np.ndarray, centres: np.ndarray,
                   radius_mm: float, alive: np.ndarray) -> np.ndarray:
    """Leave-one-out error of every live marker, in units of its side (inf: no neighbour)."""
    err = np.full(len(ids), np.inf)
    for j in np.flatnonzero(alive):
        d = np.linalg.norm(centres[ids] - centres[ids[j]], axis=1)
        nb = alive & (d <= radius_mm) & (np.arange(len(ids)) != j)
        if not nb.any():
            continue
        H = _homography(board_xy[ids[nb]].reshape(-1, 2), uv[nb].reshape(-1, 2))
        if H is None:
            continue
        side = np.mean(np.linalg.norm(uv[j] - np.roll(uv[j], 1, axis=0), axis=1))
        err[j] = np.max(np.linalg.norm(_apply(H, board_xy[ids[j]]) - uv[j], axis=1)) / side
    return err


def _marker_geometry(board: Board, legacy: bool | None):
    """Board-frame marker corners (M, 4, 2), their centres and the neighbour radius, mm, on the
    board's layout or on ``legacy``'s."""
    if legacy is not None:
        board = replace(board, charuco=replace(board.charuco, legacy=legacy))
    board_xy = board.marker_corners_mm()[:, :, :2]
    return board_xy, board_xy.mean(axis=1), NEIGHBOUR_RADIUS_SQUARES * board.square_mm


def check_markers(uv: np.ndarray, ids: np.ndarray, board: Board, legacy: bool | None = None) -> np.ndarray:
    """(M,) True for the markers whose ids agree with the board's geometry (module docstring, step 2).

    Parameters
    ----------
    uv : (M, 4, 2) marker corners, pixels; ids : (M,) their ids.
    board : the ChArUco board; ``legacy`` overrides its layout (to test the other one).
    """
    geometry = _marker_geometry(board, legacy)
    alive = np.ones(len(ids), bool)
    while alive.any():
        err = _marker_errors(uv, ids, *geometry, alive)
        bad = alive & ~(err <= MARKER_TOLERANCE)
        if not bad.any():
            break
        finite = bad & np.isfinite(err)
        # the worst judged marker first (it spoils its neighbours' predictions); markers no
        # neighbour can judge go once every judged one agrees
        alive[np.argmax(np.where(finite, err, -1.0)) if finite.any() else bad] = False
    return alive


def agreeing_markers(uv: np.ndarray, ids: np.ndarray, board: Board, legacy: bool | None = None) -> int:
    """How many markers agree with their neighbours at once (one pass of :func:`check_markers`,
    nothing dropped): a quick score of a dictionary or layout, high only for the right one."""
    err = _marker_errors(uv, ids, *_marker_geometry(board, legacy), np.ones(len(ids), bool))
    return int(np.sum(err <= MARKER_TOLERANCE))


def predict_corners(uv: np.ndarray, ids: np.ndarray, board: Board):
    """Every inner corner as the markers around it put it, and how much room its refinement has.

    Parameters
    ----------
    uv : (M, 4, 2) corners of markers that passed :func:`check_markers`, pixels; ids : (M,).
    board : the ChArUco board.

    Returns
    -------
    pred : (N, 2) predicted corners, from the homography of the markers within
        :data:`NEIGHBOUR_RADIUS_SQUARES` squares of the corner; NaN where there are none.
    touching : (N,) True for the corners of a square whose marker is among ``ids``: the ones
        to measure.
    clear_px : (N,) half-width of the square around each corner that holds no marker, pixels
        (the image of ``(s - m) / 2`` at the corner), NaN where ``pred`` is.
    """
    X = board.object_points_mm()[:, :2]
    board_xy = board.marker_corners_mm()[:, :, :2]
    centres = board_xy.mean(axis=1)
    radius = NEIGHBOUR_RADIUS_SQUARES * board.square_mm
    e = 0.5 * (board.square_mm - board.charuco.marker_mm)
    pred = np.full((len(X), 2), np.nan)
    clear = np.full(len(X), np.nan)
    diag = np.array([[e, e], [-e, e], [e, -e], [-e, -e]])
    for k, xy in enumerate(X):
        near = np.linalg.norm(centres[ids] - xy, axis=1) <= radius
        H = _homography(board_xy[ids[near]].reshape(-1, 2), uv[near].reshape(-1, 2)) if near.any() else None
        if H is None:
            continue
        p = _apply(H, np.vstack([xy, xy + diag]))
        pred[k] = p[0]
        # the image of the marker-free square (s - m)/2 around the corner: half its diagonals
        clear[k] = np.min(np.linalg.norm(p[1:] - p[0], axis=1)) / np.sqrt(2.0)
    touching = np.isin(board.corner_markers(), ids).any(axis=1)
    return pred, touching & np.all(np.isfinite(pred), axis=1), clear


def _find_markers(full: np.ndarray, board: Board):
    """Markers of the board found on a reduced image, at twice its resolution (and so on) while
    they are small there (:data:`MIN_PX_PER_CELL`) or fewer than 4; returns ``(uv, ids)`` of the
    pass that found most, in full-resolution pixels."""
    f = reduction_factor(full.shape[::-1])
    cells = DICTIONARIES[board.charuco.dictionary][0] + 2
    best = (np.empty((0, 4, 2)), np.empty(0, int))
    while True:
        uv, ids = detect_markers(reduce_image(full, f), board)
        if len(ids) > len(best[1]):
            best = (to_full_resolution(uv, f), ids)
        side = np.median(np.linalg.norm(uv - np.roll(uv, 1, axis=1), axis=2)) if len(ids) else 0.0
        if f == 1 or (len(ids) >= 4 and side >= MIN_PX_PER_CELL * cells):
            return best
        f //= 2


def _layouts(board: Board) -> tuple[bool, ...]:
    """The layouts a board of this many rows can have (one when ``SY`` is odd: they are the same)."""
    return (False, True) if board.charuco.squares[1] % 2 == 0 else (False,)


def detect_charuco(full: np.ndarray, board: Board) -> np.ndarray:
    """The inner corners of a ChArUco board in a full-resolution photo (module docstring).

    Parameters
    ----------
    full : (H, W) uint8 grey photo.
    board : a ChArUco board whose dictionary and layout are known (:func:`resolve_board`).

    Returns
    -------
    (N, 2) corners in the board's order, pixels; NaN rows for the corners not measured.

    Raises
    ------
    DetectionError
        With a one-line reason when the photo does not show enough of the board.
    """
    return measure_charuco(full, board).uv


def measure_charuco(full: np.ndarray, board: Board) -> MeasuredGrid:
    """:func:`detect_charuco`'s corners, and the photo's blur (:class:`.refine.MeasuredGrid`)."""
    uv, ids = _find_markers(full, board)
    if len(ids) == 0:
        raise DetectionError(f"no marker of {board.describe()} found")
    if len(_layouts(board)) == 2:
        # the two layouts number the markers one square apart but for those at the ends of the
        # rows, which only the right layout fits: more markers fitting the other one refute this
        own, other = (agreeing_markers(uv, ids, board, legacy) for legacy in (board.charuco.legacy,
                                                                               not board.charuco.legacy))
        if other > own:
            which = "OpenCV's current layout" if board.charuco.legacy else "OpenCV's legacy layout (OpenCV < 4.6)"
            raise DetectionError(f"the markers are laid out as on {which}, not as {board.describe()} says")
    ok = check_markers(uv, ids, board)
    if not ok.any():
        raise DetectionError(f"none of the {len(ids)} markers found agrees with the board's geometry "
                             "(a marker needs a neighbouring one to be checked)")
    uv, ids = uv[ok], ids[ok]
    pred, todo, clear = predict_corners(uv, ids, board)
    shape = (board.rows, board.cols)
    spacing = local_spacing_px(pred, shape)
    # the refinement window is 0.4 of the spacing it is given: give it the marker-free room
    room = np.minimum(spacing, (clear - BLUR_MARGIN_PX) / 0.4)
    half = window_half_size(np.where(np.isfinite(room), room, 0.0))
    H, W = full.shape
    todo &= np.isfinite(room) & np.all((pred >= half[:, None] + 1) & (pred <= np.array([W, H]) - half[:, None] - 2),
                                       axis=1)
    refined = refine_measured(full, pred, shape, np.where(todo, room, np.nan), only=todo)
    good = todo & refined.ok & (np.linalg.norm(refined.uv - pred, axis=1) <= CORNER_TOLERANCE * spacing)
    out = np.where(good[:, None], refined.uv, np.nan)
    # the neighbours' prediction is exact to a few hundredths of a pixel only over small squares
    judged = spacing <= GRID_CHECK_SPACING * max(W, H)
    out = drop_outliers(out, shape, spacing, judged=judged)
    reason = validate_grid(out, board, judged=judged)
    if reason:
        raise DetectionError(reason)
    return MeasuredGrid(out, photo_edge_width_px(refined.width_px[good]))


# ---------------------------------------------------------------------------- the board's dictionary

#: Agreeing markers (summed over the photos looked at) that settle a board's dictionary.
SETTLED_MARKERS = 8
#: On a board with an even number of rows of squares, the two layouts number the same markers
#: one square apart except the markers at the ends of the rows (a photo that shows none of them
#: fits both): the layout is settled when one fits this many more markers than the other.
LAYOUT_MARGIN = 2


def _family_heads() -> list[str]:
    """One dictionary per family: the others begin with the same markers."""
    return list(dict.fromkeys(dictionary_family(name)[-1] for name in DICTIONARIES))


def marker_scores(gray: np.ndarray, board: Board) -> dict[tuple[str, bool], int]:
    """How many markers of one (reduced) image agree with the board's geometry, per candidate
    ``(dictionary, legacy)``: every family of OpenCV's dictionaries (named by its smallest member
    that holds the board's markers) or the board's own dictionary, and every layout it can have."""
    ch = board.charuco
    names = [ch.dictionary] if ch.dictionary else [smallest_dictionary(h, ch.n_markers) for h in _family_heads()
                                                   if DICTIONARIES[h][1] >= ch.n_markers]
    layouts = _layouts(board) if ch.legacy is None else (ch.legacy,)
    scores = {}
    for name in names:
        uv, ids = detect_markers(gray, board, name)
        for legacy in layouts:
            scores[name, legacy] = agreeing_markers(uv, ids, board, legacy) if len(ids) else 0
    return scores


def resolve_board(board: Board, images) -> Board:
    """``board`` with its dictionary and layout found from ``images`` where it does not give them.

    Every photo's markers are scored (:func:`marker_scores`) and the scores summed, until the
    best candidate has :data:`SETTLED_MARKERS` and, where the layout is open, beats the other
    layout by :data:`LAYOUT_MARGIN`.

    Parameters
    ----------
    board : a ChArUco board, ``charuco.dictionary`` and/or ``charuco.legacy`` None.
    images : an iterable of (H, W) uint8 grey photos, read only as far as needed.

    Raises
    ------
    DetectionError
        When no photo shows a marker of any dictionary that fits the board, or the photos cannot
        tell the two layouts apart (none shows the end of a row of markers).
    """
    ch = board.charuco
    if ch.resolved:
        return board
    total: dict[tuple[str, bool], int] = {}
    for gray in images:
        for key, n in marker_scores(reduce_image(gray, reduction_factor(gray.shape[::-1])), board).items():
            total[key] = total.get(key, 0) + n
        if _settled(total, ch.legacy is None and len(_layouts(board)) == 2):
            break
    best = max(total, key=total.get, default=None)
    if best is None or total[best] == 0:
        raise DetectionError(f"no marker of any of OpenCV's dictionaries fits {board.describe()} "
                             f"({ch.squares[0]}x{ch.squares[1]} squares of {board.square_mm:g} mm)")
    if ch.legacy is None and len(_layouts(board)) == 2 and total[best] - total[best[0], not best[1]] < LAYOUT_MARGIN:
        raise DetectionError("the photos do not tell OpenCV's current ChArUco layout from its legacy one (for an "
                             "even number of rows of squares they differ only at the ends of the rows): add a "
                             "photo that shows the whole board")
    return replace(board, charuco=replace(ch, dictionary=best[0], legacy=best[1]))


def _settled(total: dict, layout_open: bool) -> bool:
    best = max(total, key=total.get, default=None)
    if best is None or total[best] < SETTLED_MARKERS:
        return False
    return not layout_open or total[best] - total.get((best[0], not best[1]), 0) >= LAYOUT_MARGIN
