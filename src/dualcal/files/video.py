"""Video clips as input: decoded once, the board tracked in every frame, the still moments measured.

A clip stands where a camera's folder of photos would (CONTRACT.md, "Input", "Video"): ``clips/wide.mp4``
(the stem names the camera) or ``--camera NAME=FILE.mp4``. This module is the files layer's part:

1. :func:`read_frames` decodes a clip with PyAV (FFmpeg: H.264, HEVC, ...; the ``video`` extra), one
   frame in memory at a time, each with its time from the clip's first frame (its presentation
   timestamp). The phone's rotation metadata is reported (``rotation_deg``), never applied: like a
   photo's EXIF orientation (the sensor does not turn when the phone does), every coordinate is in the
   stored frame.
2. :func:`track_clip` follows the board through every frame on a reduced image (OpenCV's classic
   detector where it was not in the frame before, else Lucas-Kanade optical flow from that frame; a
   sub-pixel fit there), in the contract's corner order (the squares' colours,
   :mod:`dualcal.files.detect.order`). Where it barely moved since the frame before, the pixels that the
   refinement of its corners reads are kept (:class:`CornerWindows`: a window around each corner, not the
   frame), so that the frames chosen at the end are measured as a photo's corners are measured
   (:func:`dualcal.files.detect.refine.refine_corners`, then the grid's checks,
   :func:`dualcal.geometry.grid.validate_grid`) with memory that does not grow with the frame size.
3. :func:`video_corners` turns the clips of a rig into a :class:`~dualcal.geometry.model.CornerSet`: each
   camera's offset from the reference (:mod:`dualcal.estimation.time_offset`), its moments of the board held
   still and the ones chosen (:mod:`dualcal.estimation.moments`), every camera's view of a moment being its
   frame nearest that moment, keyed ``f`` and the reference's frame index (``f000123``). What was read,
   found still and chosen, and why the rest was not, is said on stderr and kept in corners.json
   (each camera's ``video``).
"""

from __future__ import annotations

import glob as globmod
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..errors import DetectionError, InputError
from ..extras import require
from ..geometry.board import Board
from ..geometry.grid import validate_grid
from ..geometry.model import CameraCorners, CornerSet, choose_reference
from ..parallel import interruptible_map
from ..progress import progress_bar, warn
from .detect.coarse import reduce_image, to_full_resolution
from .detect.order import check_colours, order_grid, square_colours
from .detect.refine import refine_corners, window_half_size
from .detect.symmetry import align_symmetric_numbering

__all__ = ["VIDEO_SUFFIXES", "ClipInfo", "ClipTrack", "find_clips", "is_video", "probe_clip", "read_frames",
           "track_clip", "video_corners"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".3gp", ".mts")

#: The reduced image the board is searched in (where it was not in the frame before) has its long side at
#: least this (px).
SEARCH_LONG_SIDE_PX = 640
#: Where the board was lost and not found again, it is searched for in every this many frames only (a
#: search costs tens of milliseconds; the board is mostly moving fast or out of view then).
SEARCH_EVERY = 3
#: The board is followed on a frame reduced so that its squares keep at least this many pixels.
FOLLOW_SQUARE_PX = 8
#: Lucas-Kanade's window and pyramid levels (on the reduced frame).
FLOW_WINDOW = (11, 11)
FLOW_LEVELS = 2
#: A frame is measured at full resolution when its corners moved less than this since the frame before
#: (full-resolution px per frame, RMS over the corners; the coarse corners' own noise is well below it).
MEASURE_BELOW_PX = 2.0
#: The windows kept around each corner reach this far (px) beyond the refinement's own window
#: (:func:`dualcal.files.detect.refine.window_half_size`): its fit may move the corner a little.
WINDOW_MARGIN_PX = 4


def _reduction(at_most: float) -> int:
    """The largest reduction factor :func:`~dualcal.files.detect.coarse.reduce_image` makes exactly (a power of
    two: it halves the image) that is at most ``at_most``, and 1 below 2. A factor that is no power of two
    (3: 1920 px / 640) was halved once and scaled back by 3, every corner 1.5 x too far from the origin."""
    return 1 << max(0, int(np.floor(np.log2(max(at_most, 1.0)))))


def _rms_px(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def is_video(path) -> bool:
    """A video file by its name (:data:`VIDEO_SUFFIXES`)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES and not Path(path).name.startswith(".")


def find_clips(source=None, cameras=()) -> dict[str, Path] | None:
    """The clips of an input, ``{camera: path}``, or None when the input holds no video.

    A folder whose files are clips (``clips/wide.mp4``, ``clips/tele.mov``: each stem a camera), or cameras
    given as ``NAME=FILE.mp4`` (every ``--camera`` a clip). A folder that also holds photos or camera folders
    is a dataset of photos (a phone's camera roll keeps its Live Photos as ``.MOV`` beside the photos; the
    dataset skips them with a warning); clips mixed with globs of photos are refused.
    """
    if cameras:
        specs = [c.partition("=")[::2] if isinstance(c, str) else tuple(c) for c in cameras]
        clips = {n.strip(): p.strip() for n, p in specs}
        videos = {n for n, p in clips.items() if is_video(p)}
        if not videos:
            return None
        if len(videos) < len(clips):
            raise InputError(f"--camera: {', '.join(sorted(videos))} are clips and {', '.join(sorted(set(clips) - videos))} "
                             "photos: give every camera as a clip, or every camera as photos")
        base = Path(source) if source is not None else None
        out = {}
        for name, pattern in clips.items():
            full = pattern if base is None or Path(pattern).is_absolute() else str(base / pattern)
            matched = sorted(globmod.glob(full))
            if len(matched) != 1 or not Path(matched[0]).is_file():
                raise InputError(f"--camera {name}={pattern}: " + ("no such clip" if not matched else
                                 f"matches {len(matched)} files; give one clip per camera"))
            out[name] = Path(matched[0])
        return out
    if source is None or not Path(source).is_dir():
        return None
    entries = sorted(p for p in Path(source).iterdir() if not p.name.startswith("."))
    clips = [p for p in entries if p.is_file() and is_video(p)]
    if not clips:
        return None
    from .photos import PHOTO_SUFFIXES

    if any(p.is_dir() or p.suffix.lower() in PHOTO_SUFFIXES for p in entries):
        return None          # photos (a camera roll's Live Photos are .MOV beside them): the clips are not used
    names = {}
    for p in clips:
        if p.stem in names:
            raise InputError(f"{names[p.stem]} and {p} name the same camera {p.stem!r}: rename or remove one")
        names[p.stem] = p
    return names


# ---------------------------------------------------------------------------- decoding


@dataclass
class ClipInfo:
    """What a clip's header says: its stored frame size ``(W, H)``, frame rate, frame count (an estimate
    where the container does not say), codec, the rotation a player applies (degrees; reported only) and
    its duration (s)."""

    path: Path
    size: tuple[int, int]
    fps: float
    frames: int
    codec: str
    rotation_deg: int
    duration_s: float

    def to_dict(self) -> dict:
        return {"file": str(self.path), "image_size": list(self.size), "fps": self.fps, "codec": self.codec,
                "rotation_deg": self.rotation_deg, "duration_s": self.duration_s}


def _open(path):
    require("video")
    import av

    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError) as exc:
        raise InputError(f"{path}: not a readable video ({' '.join(str(exc).split())})") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: holds no video stream")
    return container


def _rotation(stream, first_frame=None) -> int:
    """The display rotation of a stream (degrees, counter-clockwise as FFmpeg says it), 0 if none."""
    angle = None
    if first_frame is not None:
        angle = getattr(first_frame, "rotation", None)
    if not angle:
        angle = (stream.metadata or {}).get("rotate")
    try:
        return int(round(float(angle or 0))) % 360
    except ValueError:
        return 0


def probe_clip(path) -> ClipInfo:
    """The :class:`ClipInfo` of a clip (its first frame decoded for the rotation).

    Raises
    ------
    InputError
        Not a video, no video stream, the ``video`` extra not installed.
    """
    with _open(path) as container:
        import av               # (after _open: it says in one line which extra installs it)

        stream = container.streams.video[0]
        rate = stream.average_rate or stream.guessed_rate or 30
        duration = float(stream.duration * stream.time_base) if stream.duration else (
            container.duration / 1e6 if container.duration else 0.0)
        try:
            first = next(container.decode(stream))
        except (StopIteration, av.error.FFmpegError):
            raise InputError(f"{path}: no frame could be decoded") from None
        frames = stream.frames or int(round(duration * float(rate)))
        return ClipInfo(Path(path), (first.width, first.height), float(rate), frames, stream.codec_context.name,
                        _rotation(stream, first), duration)


#: Limited-range ("TV") luma 16-235 to full-range grey 0-255.
_FULL_RANGE = np.clip(np.rint((np.arange(256) - 16) * (255 / 219)), 0, 255).astype(np.uint8)


def _gray(frame, full_range: bool) -> np.ndarray:
    """The luma of a decoded frame as (H, W) uint8: the Y plane itself for the usual 8-bit YUV formats, with
    ``full_range`` stretched from 16-235 where the clip is limited-range (as phones record; corners do not
    care: the detectors and the refinement's fit take any gain and offset of the grey levels)."""
    if frame.format.name not in ("yuv420p", "yuvj420p", "nv12", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p"):
        return frame.to_ndarray(format="gray")
    plane = frame.planes[0]
    luma = np.frombuffer(plane, np.uint8).reshape(plane.height, plane.line_size)[:, :plane.width]
    full = frame.format.name.startswith("yuvj") or getattr(frame, "color_range", 0) == 2     # 2: JPEG range
    return luma if full or not full_range else cv2.LUT(luma, _FULL_RANGE)


def read_frames(path, full_range: bool = True):
    """Decode a clip: yields ``(index, t_s, gray)`` per frame, ``t_s`` seconds from its first frame (from
    the presentation timestamps, so a variable frame rate is followed), ``gray`` (H, W) uint8 in the stored
    frame (``full_range``: grey levels 0-255, else the luma as stored, :func:`_gray`). One frame at a time; a
    frame FFmpeg cannot decode ends the clip there with a warning."""
    with _open(path) as container:
        import av

        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        t0 = None
        index = 0
        try:
            for frame in container.decode(stream):
                t = float(frame.pts * stream.time_base) if frame.pts is not None else index / float(
                    stream.average_rate or 30)
                t0 = t if t0 is None else t0
                yield index, t - t0, _gray(frame, full_range)
                index += 1
        except av.error.FFmpegError as exc:
            warn(f"{path}: decoding stopped at frame {index} ({' '.join(str(exc).split())})")


# ---------------------------------------------------------------------------- tracking


@dataclass
class CornerWindows:
    """The pixels of one frame that the refinement of its corners reads: a square window around each
    coarse corner (``start`` (N, 2), full-resolution px), ``patches`` (N, n, n) uint8 whose top-left
    pixels are ``origin`` (N, 2) [col, row]. A frame held still keeps these instead of the whole frame, so
    the frames chosen at the end are measured as photos are (:meth:`measure`) with memory that does not
    grow with the frame size."""

    start: np.ndarray
    origin: np.ndarray
    patches: np.ndarray

    @classmethod
    def cut(cls, gray: np.ndarray, uv: np.ndarray, grid_shape: tuple[int, int]) -> "CornerWindows":
        grid = uv.reshape(*grid_shape, 2)
        # the refinement's windows follow each corner's nearest neighbour, never farther than the farthest
        # neighbour along a row or column: windows of that size hold them all
        reach = max(np.linalg.norm(np.diff(grid, axis=0), axis=2).max(), np.linalg.norm(np.diff(grid, axis=1), axis=2).max())
        half = int(window_half_size(reach)) + WINDOW_MARGIN_PX
        H, W = gray.shape
        n = 2 * half + 1
        origin = np.clip(np.rint(uv).astype(int) - half, 0, [W - n, H - n])
        patches = np.lib.stride_tricks.sliding_window_view(gray, (n, n))[origin[:, 1], origin[:, 0]]
        return cls(uv, origin, patches)

    def measure(self, image_size: tuple[int, int], board: Board) -> np.ndarray:
        """(N, 2) the corners refined at full resolution as a photo's are
        (:func:`dualcal.files.detect.refine.refine_corners`); NaN rows where a fit failed."""
        W, H = image_size
        canvas = np.zeros((H, W), np.uint8)
        n = self.patches.shape[1]
        for (c, r), patch in zip(self.origin, self.patches):
            canvas[r:r + n, c:c + n] = patch
        uv, ok = refine_corners(canvas, self.start, (board.rows, board.cols))
        uv[~ok] = np.nan
        return uv


@dataclass
class ClipTrack:
    """The board through one clip.

    ``times_s`` (F,) each frame's time from the clip's first; ``coarse_px`` (F, N, 2) the board's corners
    found on the reduced frame (full-resolution pixels, the contract's order; NaN rows where it was not
    found); ``windows`` ``{frame: CornerWindows}`` in the frames where the board barely moved
    (:data:`MEASURE_BELOW_PX`), to measure those chosen; ``rejected`` counts frames by why they were not.
    """

    info: ClipInfo
    times_s: np.ndarray
    coarse_px: np.ndarray
    windows: dict[int, CornerWindows] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)

    @property
    def frames_read(self) -> int:
        return len(self.times_s)

    @property
    def frames_found(self) -> int:
        return int(np.isfinite(self.coarse_px[:, 0, 0]).sum())


_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.01)
#: The board is followed within this share of its extent in the image around where it was (the rest of the
#: frame is not looked at: a board that moved farther is found afresh).
FOLLOW_REACH = 0.3
#: A grid followed from the frame before is kept while every corner is within this share of its spacing
#: from its neighbours' prediction (else the board is searched afresh).
FOLLOW_TOLERANCE = 0.15


def _found_board(small: np.ndarray, factor: int, board: Board) -> np.ndarray | None:
    """(N, 2) the board's corners found afresh on a reduced frame (full-resolution px, contract order), or None."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(small, (board.cols, board.rows), flags=flags)
    if not found or corners is None or len(corners) != board.n_corners:
        return None
    corners = cv2.cornerSubPix(small, corners.reshape(-1, 1, 2), (3, 3), (-1, -1), _SUBPIX)
    grid = to_full_resolution(corners.reshape(board.rows, board.cols, 2).astype(float), factor)
    colours = square_colours(small, grid, factor)
    try:
        check_colours(colours, board.cols, board.rows)
    except DetectionError:
        return None
    ordered, _, _ = order_grid(grid, colours, board)
    return ordered.reshape(-1, 2)


def _followed_board(before: np.ndarray, small: np.ndarray, uv: np.ndarray, factor: int,
                    board: Board) -> np.ndarray | None:
    """The corners ``uv`` of the frame before (full-resolution px) followed into this frame by pyramidal
    Lucas-Kanade optical flow, then fitted to the sub-pixel, on the two frames reduced by ``factor``
    (``before``, ``small``) and cut to the board's surroundings (:data:`FOLLOW_REACH`); None when a corner
    is lost or the grid no longer looks like one (:data:`FOLLOW_TOLERANCE`)."""
    h, w = small.shape
    start = (uv + 0.5) / factor - 0.5
    lo, hi = start.min(axis=0), start.max(axis=0)
    reach = FOLLOW_REACH * float(np.max(hi - lo)) + 8
    x0, y0 = np.maximum(lo - reach, 0).astype(int)
    x1, y1 = np.minimum(hi + reach + 1, [w, h]).astype(int)
    if x1 - x0 < 16 or y1 - y0 < 16:
        return None
    a, b = (np.ascontiguousarray(img[y0:y1, x0:x1]) for img in (before, small))
    origin = np.array([x0, y0], float)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(a, b, (start - origin).astype(np.float32).reshape(-1, 1, 2), None,
                                                winSize=FLOW_WINDOW, maxLevel=FLOW_LEVELS)
    if moved is None or not status.all():
        return None
    if np.any(moved < 2) or np.any(moved[..., 0] > b.shape[1] - 3) or np.any(moved[..., 1] > b.shape[0] - 3):
        return None
    moved = cv2.cornerSubPix(b, moved, (3, 3), (-1, -1), _SUBPIX)
    out = to_full_resolution(moved.reshape(-1, 2).astype(float) + origin, factor)
    return out if _grid_like(out.reshape(board.rows, board.cols, 2)) else None


def _grid_like(grid: np.ndarray) -> bool:
    """Whether a (rows, cols, 2) grid still looks like a board's: along every row and column each corner is
    within :data:`FOLLOW_TOLERANCE` of the spacing from the middle of its two neighbours (a board's image
    bends that little between neighbouring corners; a corner that slid to the next one does not)."""
    step = np.diff(grid, axis=1)
    spacing2 = float(np.mean(np.sum(step * step, axis=2)))
    bend_r = grid[:, 2:] - 2 * grid[:, 1:-1] + grid[:, :-2]
    bend_c = grid[2:] - 2 * grid[1:-1] + grid[:-2]
    worst = max(float(np.max(np.sum(bend_r * bend_r, axis=2))), float(np.max(np.sum(bend_c * bend_c, axis=2))))
    return spacing2 > 0 and worst <= (2 * FOLLOW_TOLERANCE) ** 2 * spacing2


def track_clip(path, board: Board, progress: bool = True, name: str | None = None, advance=None,
               info: ClipInfo | None = None) -> ClipTrack:
    """Decode ``path`` once and follow the board through it (module docstring, step 2): found afresh where
    it was not in the frame before, else followed (:func:`_followed_board`); the windows of its corners kept
    where it moved less than :data:`MEASURE_BELOW_PX` since the frame before. ``advance(n=1)``: called once
    per frame (a shared progress bar); without it, the clip's own bar (``progress``). ``info``: the clip's
    :func:`probe_clip`, where it was read already.

    Raises
    ------
    InputError
        The clip cannot be read (:func:`probe_clip`), or a ChArUco board (not tracked in clips).
    """
    if board.charuco is not None:
        raise InputError(f"{path}: clips are read with a chessboard; a ChArUco board is not tracked in video yet")
    info = info or probe_clip(path)
    W, H = info.size
    search = _reduction(max(W, H) / SEARCH_LONG_SIDE_PX)
    factor = search                           # of the frame the board is followed in, set by its squares
    times, coarse = [], []
    windows: dict[int, CornerWindows] = {}
    rejected = {"board not found": 0}
    previous, before, searched = None, None, -SEARCH_EVERY
    with progress_bar(f"reading {name or Path(path).name}", info.frames,
                      enabled=progress and advance is None) as own:
        advance = advance or own
        for index, t, gray in read_frames(path, full_range=False):
            if gray.shape != (H, W):
                raise InputError(f"{path}: frame {index} is {gray.shape[1]}x{gray.shape[0]}, the first {W}x{H}")
            times.append(t)
            small = np.ascontiguousarray(reduce_image(gray, factor))
            uv = None if previous is None else _followed_board(before, small, previous, factor, board)
            if uv is None and (previous is not None or index - searched >= SEARCH_EVERY):
                # where it was lost while followed, its squares' size says how far the frame can be reduced
                reduced = max(search, factor // 2) if previous is not None else search
                searched = index
                uv = _found_board(np.ascontiguousarray(reduce_image(gray, reduced)), reduced, board)
                if uv is not None:
                    grid = uv.reshape(board.rows, board.cols, 2)
                    square = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
                    renewed = _reduction(min(square / FOLLOW_SQUARE_PX, 4 * search))
                    if renewed != factor:
                        factor, small = renewed, np.ascontiguousarray(reduce_image(gray, renewed))
            if uv is None:
                rejected["board not found"] += 1
                coarse.append(np.full((board.n_corners, 2), np.nan))
            else:
                coarse.append(uv)
                if previous is not None and _rms_px(uv, previous) < MEASURE_BELOW_PX:
                    windows[index] = CornerWindows.cut(gray, uv, (board.rows, board.cols))
            previous, before = uv, small
            advance()
    if not times:
        raise InputError(f"{path}: no frame could be decoded")
    return ClipTrack(info, np.asarray(times), np.asarray(coarse), windows, rejected)


# ---------------------------------------------------------------------------- a rig's clips


def video_corners(clips: dict[str, Path], board: Board, reference: str | None = None, progress: bool = True,
                  max_instants: int | None = None) -> CornerSet:
    """The corners of a rig's clips (module docstring, step 3).

    Parameters
    ----------
    clips : ``{camera: path}`` (:func:`find_clips`).
    board : the chessboard.
    reference : the reference camera (default: ``wide`` if there is one, else the first name).
    max_instants : at most this many moments are chosen (default
        :data:`dualcal.estimation.moments.MAX_INSTANTS`).

    Raises
    ------
    InputError
        A clip that cannot be read, or in which the board is never measured held still.
    """
    from ..estimation import moments as moments_mod
    from ..estimation.time_offset import estimate_offsets

    ref = choose_reference(clips, reference)
    infos = {name: probe_clip(path) for name, path in clips.items()}
    with progress_bar("reading clips", sum(i.frames for i in infos.values()), enabled=progress) as advance:
        # one thread per clip: decoding, OpenCV and most of numpy release the GIL
        found = interruptible_map(lambda item: track_clip(item[1], board, name=item[0], advance=advance,
                                                          info=infos[item[0]]),
                                  list(clips.items()), max(1, min(len(clips), os.cpu_count() or 1)))
        tracks = dict(zip(clips, found))
    for name, tr in tracks.items():
        if not tr.windows:
            raise InputError(f"{clips[name]}: the board ({board.spec()}) was never found held still in its "
                             f"{tr.frames_read} frames (found in {tr.frames_found}): hold it still for a moment "
                             "at each position, and check --board (inner corners, COLSxROWS)")
    offsets = estimate_offsets({n: (t.times_s, t.coarse_px, t.info.size) for n, t in tracks.items()}, board, ref)
    for name, off in offsets.items():
        if name != ref and off is None:
            warn(f"camera {name!r}: the board is never seen moving by it and by {ref!r} at once, so its clock "
                 f"cannot be matched to {ref!r}'s: its lens is calibrated alone")
    choice = moments_mod.choose_moments({n: (t.times_s, {j: t.coarse_px[j] for j in t.windows})
                                         for n, t in tracks.items()}, board, ref,
                                        {n: (o.offset_s if o is not None else None) for n, o in offsets.items()},
                                        {n: t.info.size for n, t in tracks.items()},
                                        max_instants=max_instants or moments_mod.MAX_INSTANTS)
    cameras = {}
    for name, tr in tracks.items():
        views = {}
        for key, j in choice.frames[name].items():
            uv = tr.windows[j].measure(tr.info.size, board)
            reason = validate_grid(uv, board)
            if reason:
                warn(f"{clips[name]}: frame {j} ({key}) skipped: {reason}")
            views[key] = None if reason else uv
        record = {**tr.info.to_dict(), "frames_read": tr.frames_read, "board_found": tr.frames_found,
                  "still": choice.still_frames[name],
                  "moments": choice.moment_count[name], "chosen": sum(v is not None for v in views.values()),
                  "frame_of_view": dict(choice.frames[name]),
                  "moment_of_view": {k: choice.moment_of[k] for k in views},
                  "not_used": {**tr.rejected, "board moving": tr.frames_found - choice.still_frames[name],
                               **choice.not_used[name]}}
        if offsets.get(name) is not None:
            record["offset_s"] = offsets[name].offset_s
            record["offset_sigma_s"] = offsets[name].sigma_s
        if tr.info.rotation_deg:
            warn(f"{clips[name]}: the clip says to turn it by {tr.info.rotation_deg} degrees for display; the "
                 "frames are used as stored (the sensor does not turn when the phone does)")
        cameras[name] = CameraCorners(tr.info.size, views, {"video": record})
    corners = CornerSet(board, cameras, ref)
    if board.is_symmetric and len(cameras) > 1:
        # each frame numbered by the top-left rule (as photos are): every other camera's views renumbered to
        # fit the rig, as detection does (dualcal.files.detect.symmetry)
        corners, turned = align_symmetric_numbering(corners, ref)
        warn(f"board {board.spec()} looks the same turned by 180 degrees: corner 0 taken as the candidate nearest "
             f"the image's top-left in {ref!r} and as fits the rig in the other cameras ({turned} view(s) "
             "renumbered); a board with an odd COLS+ROWS has no such doubt")
    return corners
