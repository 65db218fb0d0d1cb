"""Detection of one photo and of a whole dataset (paper section 1.2).

Per photo (:func:`detect_photo`), one photo in memory at a time (a ChArUco board goes through
:func:`.charuco.measure_charuco` instead: its markers number the corners):

1. decode the photo once, reduce it to 1/2-1/8 size and find the grid there (:mod:`.coarse`),
   or, where that fails and the user clicked four corners, predict the grid from them
   (:mod:`.manual`); failing that, take the largest part of the board the detector found and
   place it on the board by the colours of the squares around it (glare on a square, a
   shadow, the frame's edge); a photo that shows no part of a board is given up on there;
2. sample the squares: they must alternate like a chessboard, the outer ring too, and the
   board must not continue beyond it (:mod:`.order`); put the corners in the contract's order;
3. refine each corner at full resolution in a window fitted to its own squares (where the photo is
   too blurred for that, by the window's point symmetry), check it against the homography of its
   neighbours, with the photo's own corner noise as the scale, and refine it again from there if it
   disagrees; a corner that still disagrees by many times the noise is a NaN row (``null`` in
   corners.json), not a lost photo (:func:`.refine.measure_grid`); the photo's blur and corner noise are
   measured (:func:`photo_quality`) and written in the camera's ``meta["photo_quality"]``;
4. check the grid as a whole (:func:`.grid.validate_grid`): enough corners left (6 of a board OpenCV
   found whole, more than half of one placed from a part), no fold, no corner off its neighbours'
   prediction. A grid that fails is reported as not found.

:func:`detect_dataset` runs that over every photo of a :class:`~dualcal.files.dataset.Dataset` in
parallel threads and gathers a :class:`~dualcal.geometry.model.CornerSet`; for a ChArUco board whose
dictionary (or layout) is not given it first finds them from the photos
(:func:`.charuco.resolve_board`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ...geometry.board import DICTIONARIES, Board, dictionary_family
from ..dataset import Dataset, unpaired_cameras
from ..photos import jobs_within_memory, read_gray
from ...errors import DetectionError, InputError
from ..io import make_output_folder, write_jpeg_atomic
from ...geometry.model import CameraCorners, CornerSet
from ...parallel import interruptible_map
from ...progress import progress_bar, warn
from .charuco import measure_charuco, resolve_board
from .circles import detect_circles
from .coarse import (classic_grid, consistent_part, largest_grid, reduce_image, reduction_factor, sb_grid,
                     shows_a_chessboard, to_full_resolution)
from ...geometry.grid import corner_noise_px, local_spacing_px, validate_grid
from .manual import grid_from_hints
from .order import (PartialBoard, check_colours, filled_grid, looks_like_part_of_a_board, order_grid, place_partial_grid,
                    square_colours)
from .refine import measure_grid
from .symmetry import align_symmetric_numbering

__all__ = ["PhotoResult", "photo_quality", "detect_photo", "detect_dataset", "likely_boards", "locate_board", "suggest_board"]


@dataclass
class PhotoResult:
    """Outcome for one photo: ``uv`` (N, 2) pixels in corner order, or None with a ``reason``.

    ``failed_check`` names the check that a grid of the board's size, found in the photo, failed
    (``"colours"``: its squares are not those of the board; ``"corners"``: the refined corners
    are not a board's grid); it is ``""`` where no such grid was found. ``partial``: only part of
    a chessboard is in view (a plain chessboard must be seen whole). ``mirrored``: the board is
    printed with its other diagonal black (:func:`.order.order_grid`). ``blur_px`` and
    ``corner_noise_px``: how blurred the photo is and how noisy its corners are
    (:func:`photo_quality`), NaN where not measured.
    """

    uv: np.ndarray | None
    image_size: tuple[int, int] | None = None
    reason: str = ""
    symmetric: bool = False
    manual: bool = False
    failed_check: str = ""
    partial: bool = False
    mirrored: bool = False
    blur_px: float = float("nan")
    corner_noise_px: float = float("nan")


def photo_quality(uv: np.ndarray, board: Board, edge_width_px: float) -> dict[str, float]:
    """How blurred a photo is and how noisy its corners are: ``{"blur_px", "corner_noise_px"}``.

    ``blur_px``: the width of the squares' edges, the median over the corners of the corner fit's ``w``
    (:func:`.refine.fit_saddles`; about 1.2 x the standard deviation of a Gaussian blur, 0.7 x the radius of
    a defocused lens's disc up to about 10 px, beyond which the fit's window no longer holds the edges and it
    only grows). ``corner_noise_px``: the standard deviation of one
    coordinate of a corner, from the photo's own corners (:func:`dualcal.geometry.grid.corner_noise_px`).
    """
    return {"blur_px": float(edge_width_px), "corner_noise_px": corner_noise_px(uv, (board.rows, board.cols))}


class _CheckFailed(DetectionError):
    """A grid of the board's size was found but failed the check ``check``."""

    def __init__(self, check: str, message: str):
        super().__init__(message)
        self.check = check


#: Squares (corner spacing, reduced pixels) below which a part of a board found on the reduced image, but
#: not the board, is searched for again at twice the resolution (OpenCV's detectors need about 10 pixels a
#: square, and a steep view makes one side of the squares short).
SMALL_SQUARE_PX = 16.0


def locate_board(full: np.ndarray, board: Board, partial: bool = True):
    """Where the board is in a photo: ``(small, factor, grid, placed)``.

    ``small`` is the reduced image searched (:func:`.coarse.reduce_image` by ``factor``), ``grid`` the
    board's (rows, cols, 2) inner corners in full-resolution pixels, in the detector's order, ``placed``
    whether it was extended from a part of the board found (:func:`.order.place_partial_grid`; only where
    ``partial``).

    What a photo without the whole board costs matters as much as what a photo with it does: a phone's
    camera roll has many (the tele sees part of a board placed for the ultra-wide's edges, or none). So,
    on the reduced image: OpenCV's classic detector (milliseconds where the board is in view); then the
    largest chessboard grid SB can grow (:func:`.coarse.largest_grid`): where there is none, the photo is
    given up on there; its corners that agree with each other (:func:`.coarse.consistent_part`) are
    placed on the board by the squares' colours (the whole board, or a board cut by the frame, which
    raises :class:`.order.PartialBoard` where it cannot be numbered); where they cannot be, or none
    agree, OpenCV's SB detector is asked for the whole board (its growth from 3 x 3 corners can stop
    short of a board it finds when asked for the board's size), if what was grown may be part of the
    board in full view (:func:`.order.looks_like_part_of_a_board`: not stripes of a carpet, not a
    board cut by the frame); where OpenCV's quick look sees a board (:func:`.coarse.shows_a_chessboard`),
    SB is asked too, but only its normalised attempt: stripes fool the quick look, and both attempts cost
    real photos of a striped carpet 1.06 x SB's own time, against 0.83-0.90 x for the first alone (every
    board of the real sets found this way was found by the first).
    Only a grid whose squares are below :data:`SMALL_SQUARE_PX` sends the search to twice the
    resolution (at full resolution: SB on OpenCV's upsampled image). Measured on 3 MP photos without
    the whole board, taking turns on one thread each (``benchmarks/bench_detect.py``, a loaded machine):
    0.4-0.9 of the time of OpenCV's ``findChessboardCornersSB`` alone on the same photos, per kind
    (a board cut by the frame or absent; synthetic, and real photos cropped), where the search at both
    resolutions took several times SB's.

    Raises
    ------
    DetectionError
        (or :class:`.order.PartialBoard`) when the board is not found.
    """
    size = full.shape[::-1]
    f = reduction_factor(size)
    while True:
        small = reduce_image(full, f)
        grid = classic_grid(small, board.cols, board.rows)
        if grid is not None:
            return small, f, to_full_resolution(grid, f), False
        unplaced = DetectionError(f"no {board.spec()} chessboard found")
        grown = largest_grid(small)
        if grown is None:
            raise unplaced
        # where no part agrees (a 3 x 3 grid's corners predict each other poorly), what was grown is
        # placed as it is: the colours of the squares judge it, and the measured corners again
        part = consistent_part(grown)
        seen = grown if part is None else part
        seen_px = to_full_resolution(seen, f)
        if partial:
            try:
                return small, f, place_partial_grid(seen_px, small, f, board), True
            except PartialBoard:
                raise
            except DetectionError as exc:
                unplaced = exc
        # SB's growth can stop short of a board it finds whole when asked for it: ask it, where what it
        # grew may be part of the board in full view, or (its normalised attempt alone: stripes of a carpet
        # fool the quick look) where the classic detector's quick look saw a board
        grid = None
        if looks_like_part_of_a_board(seen_px, small, f, board):
            grid = sb_grid(small, board.cols, board.rows)
        elif shows_a_chessboard(small, board.cols, board.rows):
            grid = sb_grid(small, board.cols, board.rows, exhaustive=False)
        if grid is not None:
            return small, f, to_full_resolution(grid, f), False
        if np.median(local_spacing_px(seen.reshape(-1, 2), seen.shape[:2])) >= SMALL_SQUARE_PX:
            raise unplaced
        if f > 1 and max(size) / f < 2000:
            f //= 2
            continue
        grid = sb_grid(small, board.cols, board.rows, upsampled=True)
        if grid is None:
            raise unplaced
        return small, f, to_full_resolution(grid, f), False


def detect_photo(path, board: Board, hint_uv: np.ndarray | None = None,
                 overlay_path: Path | None = None) -> PhotoResult:
    """Find, order, refine and check the chessboard corners of one photo.

    Parameters
    ----------
    path
        photo file (JPEG, PNG, TIFF, HEIC).
    board : Board
        the expected board; a board of another size is not accepted. A ChArUco board whose
        dictionary or layout is not given gets them from this photo.
    hint_uv : ndarray or None
        (4, 2) clicked corners 0, cols-1, N-1, N-cols (manual mode), used when the
        automatic search fails (chessboards only).
    overlay_path : Path or None
        where to write a small JPEG with the corners and their numbers drawn.

    Returns
    -------
    PhotoResult
        ``uv is None`` with a one-line ``reason`` when the photo cannot be read or the board is not
        found or fails its checks. A failure that one photo can cause in OpenCV, the file system or
        Pillow (``cv2.error``, ``OSError``, ``ValueError``) is reported the same way, so one odd photo
        never stops a dataset; any other exception is a bug and propagates.
    """
    try:
        full = read_gray(path)
        size = (full.shape[1], full.shape[0])
        if board.pattern != "chessboard":
            uv, symmetric = detect_circles(full, board)          # circle grids (.circles)
            if overlay_path is not None:
                f = reduction_factor(size)
                write_overlay(overlay_path, reduce_image(full, f), uv, f)
            return PhotoResult(uv, size, symmetric=symmetric)
        if board.charuco is not None:
            # a dataset settles the dictionary and layout first (detect_dataset); one photo alone tells its own
            uv, width = measure_charuco(full, board if board.charuco.resolved else resolve_board(board, [full]))
            if overlay_path is not None:
                f = reduction_factor(size)
                write_overlay(overlay_path, reduce_image(full, f), uv, f)
            return PhotoResult(uv, size, **photo_quality(uv, board, width))
        manual = False
        try:
            # clicked corners stand in for a board not found whole: no part of it is placed then
            small, f, grid, placed = locate_board(full, board, partial=hint_uv is None)
        except DetectionError:
            if hint_uv is None:
                raise
            f = reduction_factor(size)
            small, grid, placed, manual = reduce_image(full, f), grid_from_hints(hint_uv, board), False, True
        colours = square_colours(small, grid, f)
        try:
            check_colours(colours, board.cols, board.rows)
        except DetectionError as exc:
            raise _CheckFailed("colours", str(exc)) from None
        # clicked grids too: whichever end the user started from, the contract's order
        coarse, symmetric, mirrored = order_grid(grid, colours, board)
        uv, width = measure_grid(full, coarse, (board.rows, board.cols), wide_start=manual)
        # a board OpenCV found whole keeps what its checks leave of it (more than half of a placed or clicked one)
        reason = validate_grid(uv, board, whole=not (placed or manual))
        if reason:
            raise _CheckFailed("corners", reason)
        if placed:
            # extended from a part by its perspective: the squares around the measured corners must
            # still be those of exactly this board (a curled sheet bends the extension)
            try:
                check_colours(square_colours(small, filled_grid(uv, coarse, board), f), board.cols, board.rows)
            except DetectionError as exc:
                raise _CheckFailed("colours", f"a part of the board was found but not placed on it ({exc})") from None
        if overlay_path is not None:
            write_overlay(overlay_path, small, uv, f)
        return PhotoResult(uv, size, symmetric=symmetric, manual=manual, mirrored=mirrored,
                           **photo_quality(uv, board, width))
    except (DetectionError, InputError) as exc:
        return PhotoResult(None, None, reason=str(exc).replace(f"{path}: ", ""),
                           failed_check=getattr(exc, "check", ""), partial=isinstance(exc, PartialBoard))
    except (cv2.error, OSError, ValueError) as exc:
        return PhotoResult(None, None, reason=f"{type(exc).__name__}: {' '.join(str(exc).split())}")


def write_overlay(path: Path, small: np.ndarray, uv: np.ndarray, factor: int, max_side: int = 1200) -> None:
    """A small JPEG of the photo with every measured corner marked and numbered (corner 0 in red).

    ``path``'s folder must exist (see :func:`prepare_overlay_folders`).
    """
    scale = min(1.0, max_side / max(small.shape)) / factor
    img = cv2.cvtColor(cv2.resize(small, None, fx=scale * factor, fy=scale * factor,
                                  interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2BGR)
    pts = (uv + 0.5) * scale - 0.5
    for k, (u, v) in enumerate(pts):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        colour = (0, 0, 255) if k == 0 else (0, 200, 0)
        p = (int(round(u)), int(round(v)))
        cv2.circle(img, p, 4 if k else 7, colour, 2)
        cv2.putText(img, str(k), (p[0] + 5, p[1] - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)
    write_jpeg_atomic(path, img, 85)


def prepare_overlay_folders(overlays_dir, cameras) -> dict[str, Path]:
    """``{camera: overlays_dir/camera}``, created; ``overlays_dir`` itself only if its parent exists."""
    root = make_output_folder(overlays_dir)
    return {cam: make_output_folder(root / cam) for cam in cameras}


def warn_unpaired_cameras(dataset: Dataset) -> None:
    """One warning per camera that shares no view key with the reference: nothing pairs it."""
    ref_keys = set(dataset.cameras[dataset.reference])
    for cam in unpaired_cameras(dataset):
        photos = dataset.cameras[cam]
        warn(f"camera {cam!r} shares no view with the reference {dataset.reference!r} (e.g. "
             f"{next(iter(photos))!r} vs {next(iter(ref_keys))!r}): name photos of one instant alike "
             "(same stem, or what the --camera globs' wildcards match) or use --pair-by time")


def likely_boards(board: Board) -> list[Board]:
    """The ``--board`` a user most likely meant when ``board`` is not found: squares counted
    instead of inner corners (``cols-1 x rows-1``), the counts swapped, or both."""
    if board.charuco is not None or board.pattern == "points":
        return []                     # its markers say which board it is: none is mistaken for another
    if board.is_circle_grid:          # circles counted along the other side
        return [replace(board, cols=board.rows, rows=board.cols)] if board.cols != board.rows else []
    c, r, s = board.cols, board.rows, board.square_mm
    sizes = [(c - 1, r - 1), (r, c), (r - 1, c - 1)]
    return [Board(a, b, s) for a, b in dict.fromkeys(sizes) if min(a, b) >= 2 and (a, b) != (c, r)]


def board_found_instead(paths, board: Board) -> tuple[Board | None, int]:
    """Of :func:`likely_boards`, the first found in most of ``paths``, and in how many (``(None, 0)``: none)."""
    paths = list(paths)
    best, best_found = None, 0
    for other in likely_boards(board):
        found = sum(detect_photo(p, other).uv is not None for p in paths)
        if found > best_found:
            best, best_found = other, found
        if best_found == len(paths):        # none can be found in more
            break
    return best, best_found


def suggest_board(paths, board: Board, tries: int = 3) -> str:
    """A sentence naming the ``--board`` under which the board is found in ``paths`` (the first
    ``tries`` of them), or "" when none of :func:`likely_boards` is."""
    paths = list(paths)[:tries]
    best, found = board_found_instead(paths, board)
    return "" if best is None else _found_as(best, found, len(paths))


def _found_as(other: Board, found: int, tried: int) -> str:
    return (f"the board is found as --board {other.spec()} in {found} of {tried} photo(s) tried "
            f"(--board counts inner corners, COLSxROWS)")


#: When none of the first this many photos shows a grid of ``--board``'s size and every one shows one of
#: :func:`likely_boards`, detection stops there: ``--board`` is wrong, and searching each photo for a board
#: that is not in it takes seconds (a minute for 26 photos of 12 MP).
EARLY_CHECK_PHOTOS = 3


def _stop_if_another_board(tasks, results: list[PhotoResult], board: Board, source, total: int) -> None:
    """Raise :class:`InputError` naming the board of :data:`EARLY_CHECK_PHOTOS` photos that all show
    another board than ``board`` (no grid of ``board``'s size found, no clicked corners)."""
    if any(r.uv is not None or r.failed_check for r in results) or any(hint is not None for _, _, hint, _ in tasks):
        return
    paths = [path for path, *_ in tasks]
    other, found = board_found_instead(paths, board)
    if other is not None and found == len(paths):
        raise InputError(f"no {board.describe()} found in the first {len(paths)} photos of {source}: "
                         f"{_found_as(other, found, len(paths))}; the other {total - len(paths)} photos were not "
                         "searched")


def find_board_markers(dataset: Dataset, board: Board) -> Board:
    """A ChArUco board with the dictionary and layout its photos show (:func:`.charuco.resolve_board`),
    from the first photos of the reference camera, then of the others; says in a warning what it found."""
    order = [dataset.reference] + [c for c in dataset.cameras if c != dataset.reference]
    paths = [photo.path for cam in order for photo in dataset.cameras[cam].values()]

    def images():
        for path in paths:
            try:
                yield read_gray(path)
            except InputError:
                continue

    try:
        found = resolve_board(board, images())
    except DetectionError as exc:
        raise InputError(f"{dataset.source}: {exc}: check --board, --square, --marker (or give --dictionary)") from None
    ch = found.charuco
    same = [d for d in dictionary_family(ch.dictionary) if DICTIONARIES[d][1] > DICTIONARIES[ch.dictionary][1]]
    notes = []
    if board.charuco.dictionary is None:
        notes.append(f"dictionary {ch.dictionary}" + (f" (a board made with {', '.join(same)} is the same board)"
                                                      if same else ""))
    if board.charuco.legacy is None and ch.squares[1] % 2 == 0:
        notes.append("OpenCV's legacy layout (OpenCV < 4.6)" if ch.legacy else "OpenCV's current layout")
    warn(f"{found.spec()}: found from the photos: {'; '.join(notes)}")
    return found


def detect_dataset(dataset: Dataset, board: Board, jobs: int | None = None,
                   hints: dict[str, dict[str, np.ndarray]] | None = None,
                   overlays_dir=None, progress: bool = True, detect=None) -> CornerSet:
    """Detect the board in every photo of a dataset.

    Parameters
    ----------
    dataset : Dataset
        from :func:`dualcal.files.dataset.open_dataset`.
    board : Board
        the chessboard (``--board``, ``--square``).
    jobs : int or None
        photos processed at once, in threads; each holds one photo (default: all cores, fewer
        where the photos are so large that the memory they take would pass 1.2 GB,
        :func:`dualcal.files.photos.jobs_within_memory`).
    hints : dict[str, dict[str, ndarray]] or None
        ``{camera: {view: (4, 2)}}`` clicked corners (manual mode) for photos where the
        automatic search fails (see :mod:`dualcal.files.detect.manual`).
    overlays_dir
        write ``overlays_dir/<camera>/<view>.jpg`` with the detected corners drawn
        (``overlays_dir`` is created if its parent exists).
    progress : bool
        draw a progress bar on stderr.
    detect : callable or None
        ``detect(path, board, hint_uv, overlay_path) -> PhotoResult``, called from several threads at once in
        place of :func:`detect_photo` for each photo (the app's, which remembers the photos it detected as they
        were uploaded); everything else, dataset-wide, is done here as without it.

    Returns
    -------
    CornerSet
        Every camera's corners per view; a view is None where no board was found (each such photo is
        named in a warning).

    Raises
    ------
    InputError
        When no photo of the dataset yields the board, or ``overlays_dir``'s parent is missing.
    """
    hints = hints or {}
    unknown = [f"{c}/{v}" for c, vs in hints.items() for v in vs
               if c not in dataset.cameras or v not in dataset.cameras[c]]
    if unknown:
        warn(f"hints for photos not in the dataset are ignored: {', '.join(sorted(unknown))}")
    if hints and board.charuco is not None:
        warn(f"hints are for chessboards; {board.describe()} numbers its corners by its markers: hints ignored")
        hints = {}
    warn_unpaired_cameras(dataset)
    if board.charuco is not None and not board.charuco.resolved:
        board = find_board_markers(dataset, board)
    overlay_dirs = {} if overlays_dir is None else prepare_overlay_folders(overlays_dir, dataset.cameras)
    tasks, keys = [], []
    for cam, photos in dataset.cameras.items():
        for view, photo in photos.items():
            overlay = overlay_dirs[cam] / f"{view}.jpg" if overlay_dirs else None
            tasks.append((photo.path, board, hints.get(cam, {}).get(view), overlay))
            keys.append((cam, view))
    every_photo = [photo for cam in dataset.cameras.values() for photo in cam.values()]
    jobs = max(1, min(jobs or jobs_within_memory(every_photo), len(tasks)))
    results: list[PhotoResult] = []
    with progress_bar("detecting corners", len(tasks), enabled=progress) as advance:
        # threads, not processes: decoding, OpenCV's detectors and numpy's array loops release
        # the GIL, and threads start at once, share the board and need no picklable state;
        # a Ctrl-C cancels the photos not yet started (dualcal.parallel)
        for r in interruptible_map(lambda task: (detect or detect_photo)(*task), tasks, jobs):
            results.append(r)
            advance()
            if len(results) == EARLY_CHECK_PHOTOS < len(tasks):
                _stop_if_another_board(tasks[:len(results)], results, board, dataset.source, len(tasks))

    views: dict[str, dict[str, np.ndarray | None]] = {c: {} for c in dataset.cameras}
    symmetric = 0
    mirrored = sum(r.uv is not None and r.mirrored for r in results)
    board_mirrored = 2 * mirrored > sum(r.uv is not None for r in results)
    for i, ((cam, view), res) in enumerate(zip(keys, results)):
        if res.uv is not None and res.image_size != dataset.image_size(cam):
            res = PhotoResult(None, reason=f"decoded as {res.image_size}, its header and the camera's "
                                           f"other photos say {dataset.image_size(cam)}")
        elif res.uv is not None and res.mirrored != board_mirrored:
            # one printed board: its colours number every photo alike; a photo that disagrees
            # misjudged its squares' colours
            res = PhotoResult(None, reason="its squares' colours number the board as the mirror image of the "
                                           "board in most photos", failed_check="colours")
        results[i] = res
    for (cam, view), (path, *_), res in zip(keys, tasks, results):
        views[cam][view] = res.uv
        if res.uv is None:
            warn(f"{path}: skipped: {res.reason}")
        symmetric += res.symmetric
    found = sum(v is not None for vs in views.values() for v in vs.values())
    if 2 * found < len(tasks):
        # another --board only where no grid of this size was found at all: a board found that
        # failed a later check is this board (its transposed size would not fix the check)
        missed = [path for (path, *_), res in zip(tasks, results) if res.uv is None and not res.failed_check]
        failed = "; ".join(f"in {n} photo(s) a {board.spec()} grid was found but failed the {check} check"
                           for check, n in Counter(r.failed_check for r in results if r.failed_check).most_common())
        suggestion = suggest_board(missed, board)
        if found == 0:
            check = ("check --board (circles, circles:COLSxROWS or acircles:COLSxROWS)" if board.is_circle_grid
                     else "check --board (inner corners, COLSxROWS)" if board.charuco is None
                     else "check --board (squares, charuco:SXxSY), --square, --marker and --dictionary")
            raise InputError(f"no {board.describe()} found in any photo of {dataset.source} "
                             f"({len(tasks)} photos): " + ": ".join(filter(None, [failed, suggestion or check])))
        hint = "; ".join(filter(None, [suggestion, failed]))
        if hint:
            warn(f"{board.spec()} found in only {found} of {len(tasks)} photos: {hint}")
    cameras = {}
    for cam in dataset.cameras:
        meta = dataset.meta(cam)
        manual = sorted(v for (c, v), r in zip(keys, results) if c == cam and r.manual)
        if manual:
            meta["manual_views"] = manual
        partial = sorted(v for (c, v), r in zip(keys, results) if c == cam and r.partial)
        if partial:
            meta["partial_views"] = partial
        quality = {v: {"blur_px": round(r.blur_px, 3), "corner_noise_px": round(r.corner_noise_px, 4)}
                   for (c, v), r in zip(keys, results) if c == cam and r.uv is not None
                   and np.isfinite(r.blur_px) and np.isfinite(r.corner_noise_px)}
        if quality:
            meta["photo_quality"] = dict(sorted(quality.items()))
        cameras[cam] = CameraCorners(dataset.image_size(cam), views[cam], meta)
        if all(v is None for v in views[cam].values()):
            warn(f"camera {cam!r}: the board was found in none of its photos")
    corners = CornerSet(board, cameras)
    if symmetric:
        how = "the candidate nearest the image's top-left"
        if len(cameras) > 1:
            corners, turned = align_symmetric_numbering(corners, dataset.reference)
            how += (f" in camera {dataset.reference!r}, and in the other cameras the numbering that fits the rig's "
                    f"relative pose ({turned} photo(s) renumbered)")
        warn(f"board {board.spec()} looks the same turned by 180 degrees: in {symmetric} photo(s) corner 0 was "
             f"taken as {how}")
    return corners
