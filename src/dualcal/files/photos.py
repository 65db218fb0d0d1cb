"""Reading photos: their stored pixels and the facts of their EXIF header.

Every photo dualcal reads is opened here, by :func:`read_exif` (header only), :func:`read_gray`
(detection) and :func:`open_image` (rectification, undistortion), so all formats and their errors
are handled in one place: JPEG, PNG and TIFF through OpenCV or Pillow, HEIC through pillow-heif,
RAW (DNG) through rawpy (LibRaw).

Pixels are used as stored: the EXIF orientation tag is reported, never applied (the sensor does
not turn when the phone does), so every coordinate is in the stored frame. A DNG is read as the
sensor recorded it: the active area of the raw frame (DNG ``ActiveArea``) pixel for pixel, its
orientation tag reported like EXIF's, and no lens correction (LibRaw applies none of the DNG's
opcode lists, where a phone keeps its warp). Its pixel ``(i, j)`` is LibRaw's visible pixel
``(i, j)``: the active area's, except that LibRaw moves an odd origin of it to the next even row or
column (it keeps the frame on the colour filter's period), which then drops that first row or
column. Every photo of a camera has the same area, so this only shifts the frame's origin.
A phone's JPEG of the same shot is another frame (its DNG ``DefaultCrop``, resampled, the lens
corrected): calibrate the DNGs or the JPEGs of a camera, not a mix.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import struct
import sys
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError

if TYPE_CHECKING:
    import rawpy

# pillow-heif (HEIC) and rawpy (DNG) are imported on the first file that needs them
# (:func:`_pillow_open`, :func:`_open_raw`): together they take about 50 ms to import, which a
# folder of JPEGs need not pay.

# Pillow refuses an image of more than 2 * MAX_IMAGE_PIXELS as a decompression bomb (179 MP by
# default), but phones make 200 MP photos: allow up to 512 MP (detection bounds the memory they
# take, jobs_within_memory).
if Image.MAX_IMAGE_PIXELS is not None:
    Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS, 256_000_000)

__all__ = ["PHOTO_MEMORY_BYTES", "PHOTO_SUFFIXES", "RAW_SUFFIXES", "FocusFacts", "Photo", "apple_maker_note",
           "decode_bytes_per_pixel", "jobs_within_memory", "open_image", "output_suffix", "read_exif", "read_focus",
           "read_gray", "source_format"]

RAW_SUFFIXES = (".dng",)
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".heic", ".heif", *RAW_SUFFIXES)
# What the photos being read and detected at once may hold together (the interpreter and the
# libraries take about 0.1 GB more): the default jobs of detection keep a folder of 48-200 MP
# photos under 1.5 GB (:func:`jobs_within_memory`).
PHOTO_MEMORY_BYTES = 1.2e9
_FORMATS = {".jpg": "jpeg", ".jpeg": "jpeg", ".png": "png", ".tif": "tiff", ".tiff": "tiff", ".heic": "heic",
            ".heif": "heic", ".dng": "dng"}

# EXIF tags (TIFF/EXIF 2.3)
_ORIENTATION, _MAKE, _MODEL, _EXIF_IFD = 0x0112, 0x010F, 0x0110, 0x8769
_DATETIME, _DATETIME_ORIGINAL, _SUBSEC_ORIGINAL = 0x0132, 0x9003, 0x9291
_FOCAL_LENGTH, _FOCAL_35MM, _LENS_MODEL = 0x920A, 0xA405, 0xA434
_FOCAL_PLANE_X_RESOLUTION, _FOCAL_PLANE_UNIT = 0xA20E, 0xA210
#: Millimetres per unit of EXIF ``FocalPlaneResolutionUnit`` (2 inch, 3 cm; 4 mm and 5 um as some writers use).
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


@dataclass
class Photo:
    """One photo file: its path, stored pixel size ``(W, H)`` and EXIF facts (see :func:`read_exif`)."""

    path: Path
    size: tuple[int, int]
    exif: dict


def _rational(x) -> float | None:
    try:
        value = float(x)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return value if np.isfinite(value) else None


def _exif_from_image(img: Image.Image) -> dict:
    exif = img.getexif()
    sub = exif.get_ifd(_EXIF_IFD) if exif else {}
    stamp = sub.get(_DATETIME_ORIGINAL) or exif.get(_DATETIME)
    taken = None
    if isinstance(stamp, str):
        try:
            taken = datetime.strptime(stamp.strip("\x00 "), "%Y:%m:%d %H:%M:%S")
            subsec = str(sub.get(_SUBSEC_ORIGINAL, "")).strip("\x00 ")
            if subsec.isdigit():
                taken += timedelta(seconds=int(subsec) / 10 ** len(subsec))
        except ValueError:
            taken = None
    make, model, lens = exif.get(_MAKE), exif.get(_MODEL), sub.get(_LENS_MODEL)
    f35 = sub.get(_FOCAL_35MM)
    plane_res, plane_unit = _rational(sub.get(_FOCAL_PLANE_X_RESOLUTION)), sub.get(_FOCAL_PLANE_UNIT, 2)
    px_per_mm = plane_res / _FOCAL_PLANE_UNIT_MM[plane_unit] if plane_res and plane_unit in _FOCAL_PLANE_UNIT_MM \
        else None
    orientation = exif.get(_ORIENTATION)
    if img.format == "HEIF":   # pillow-heif set the tag to 1 and kept the file's value aside
        orientation = img.info.get("original_orientation") or orientation
    return {
        "make": make.strip("\x00 ") if isinstance(make, str) else None,
        "model": model.strip("\x00 ") if isinstance(model, str) else None,
        "lens_model": lens.strip("\x00 ") or None if isinstance(lens, str) else None,
        "focal_length_mm": _rational(sub.get(_FOCAL_LENGTH)),
        "focal_length_35mm_mm": _rational(f35) if f35 else None,
        "focal_plane_px_per_mm": px_per_mm,
        "orientation": int(orientation) if orientation is not None else None,
        "taken": taken,
    }


# What Pillow and pillow-heif raise for a file that is not a readable image (pillow-heif
# documents ValueError, EOFError, SyntaxError, RuntimeError and OSError; Pillow refuses
# absurdly large images with DecompressionBombError).
# rawpy raises LibRawError (and its subclasses) for a file LibRaw cannot open or unpack.
_UNREADABLE = (OSError, SyntaxError, ValueError, EOFError, RuntimeError, Image.DecompressionBombError)


def _unreadable() -> tuple[type[Exception], ...]:
    """:data:`_UNREADABLE`, and rawpy's ``LibRawError`` once a raw file was opened (rawpy imported)."""
    raw = sys.modules.get("rawpy")
    return _UNREADABLE + ((raw.LibRawError,) if raw is not None else ())


@functools.cache
def _heif_plugin():
    """pillow-heif, its HEIF opener registered with Pillow (None where it is not installed)."""
    try:
        import pillow_heif
    except ImportError:  # pragma: no cover - pillow-heif is a dependency; HEIC is then unreadable
        return None
    pillow_heif.register_heif_opener()
    return pillow_heif


def _pillow_open(fp) -> Image.Image:
    """``Image.open(fp)``; a file Pillow does not know is tried again with the HEIF opener registered."""
    try:
        return Image.open(fp)
    except UnidentifiedImageError:
        if "HEIF" in Image.OPEN or _heif_plugin() is None:
            raise
        if hasattr(fp, "seek"):
            fp.seek(0)
        return Image.open(fp)


def _detail(exc: Exception) -> str:
    """An exception's message; LibRaw's come as bytes (``b'Input/output error'``)."""
    arg = exc.args[0] if len(exc.args) == 1 else None
    return arg.decode(errors="replace") if isinstance(arg, bytes) else str(exc)


@contextlib.contextmanager
def _reading(path):
    """Turn the errors of opening or decoding ``path`` into one clear :class:`InputError`."""
    try:
        yield
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except _unreadable() as exc:
        raise InputError(f"{path}: not a readable image ({_detail(exc)})") from None


def _heif_undo(img: Image.Image) -> list[Image.Transpose]:
    """Transposes that take a decoded HEIF image back to its stored (coded) pixel frame.

    libheif applies the ``irot`` (anticlockwise quarter turns) and ``imir`` (mirror about
    axis 0: top-bottom, 1: left-right) properties while decoding, in the file's order, and
    pillow-heif then resets the EXIF orientation to 1. They are undone here in reverse order,
    so a HEIC photo is seen like a JPEG: stored pixels, orientation reported, never applied.
    A ``clap`` crop, applied before them, cannot be undone and is kept (it is the same for
    every photo of a camera). pillow-heif keeps the list only on its image handle, which it
    drops once the pixels are loaded: call this before ``load()``.
    """
    if img.format != "HEIF":
        return []
    try:  # private: pillow-heif has no public accessor for the transformations
        steps = img._heif_file[img.tell()]._c_image.transformations
    except (AttributeError, TypeError, IndexError):
        version = getattr(_heif_plugin(), "__version__", "?")
        raise InputError(f"{img.filename}: pillow-heif {version} does not report the HEIF rotation, so the "
                         "photo cannot be read in its stored frame (dualcal is tested with pillow-heif 1.8)") from None
    quarter_turns = {90: Image.Transpose.ROTATE_270, 180: Image.Transpose.ROTATE_180,
                     270: Image.Transpose.ROTATE_90}
    undo = []
    for kind, *args in reversed(steps):
        if kind == "irot" and args[0] % 360:
            undo.append(quarter_turns[args[0] % 360])
        elif kind == "imir":
            undo.append(Image.Transpose.FLIP_TOP_BOTTOM if args[0] == 0 else Image.Transpose.FLIP_LEFT_RIGHT)
    return undo


def _stored_size(img: Image.Image, undo: list[Image.Transpose]) -> tuple[int, int]:
    turns = sum(op in (Image.Transpose.ROTATE_90, Image.Transpose.ROTATE_270) for op in undo)
    return (int(img.height), int(img.width)) if turns % 2 else (int(img.width), int(img.height))


# ---------------------------------------------------------------------------- where a photo focused

# EXIF 2.3: SubjectDistance (RATIONAL, m; 0 unknown, 0xFFFFFFFF/1 infinity), SubjectDistanceRange (SHORT),
# MakerNote (UNDEFINED)
_SUBJECT_DISTANCE, _SUBJECT_DISTANCE_RANGE, _MAKER_NOTE = 0x9206, 0xA40C, 0x927C
#: EXIF SubjectDistanceRange's values.
SUBJECT_DISTANCE_RANGES = {0: "unknown", 1: "macro", 2: "close view", 3: "distant view"}
#: Apple's MakerNote: this prefix, then (at byte 12) the byte order of the TIFF IFD that starts at byte 14, its
#: offsets counted from the MakerNote's first byte (the layout of exiftool's Apple table and MakerNotes.pm).
_APPLE_PREFIX, _APPLE_IFD_START = b"Apple iOS\0", 14
#: The Apple tags read, by exiftool's names: tag -> (name, how many values).
_APPLE_TAGS = {0x0007: ("AFStable", 1), 0x0008: ("AccelerationVector", 3), 0x000C: ("FocusDistanceRange", 2),
               0x002F: ("FocusPosition", 1), 0x0038: ("AFMeasuredDepth", 1), 0x003D: ("AFConfidence", 1)}
# TIFF field types -> (struct code, bytes); a rational is two of them
_TIFF_TYPES = {1: ("B", 1), 3: ("H", 2), 4: ("I", 4), 5: ("I", 4), 6: ("b", 1), 8: ("h", 2), 9: ("i", 4),
               10: ("i", 4), 11: ("f", 4), 12: ("d", 8)}


@dataclass(frozen=True)
class FocusFacts:
    """Where a photo focused, as its metadata says (:func:`read_focus`).

    ``subject_distance_m``: EXIF ``SubjectDistance`` (None: absent or 0, "unknown"; ``inf``: infinity);
    ``subject_distance_range``: EXIF ``SubjectDistanceRange`` as its name (:data:`SUBJECT_DISTANCE_RANGES`);
    ``apple``: the Apple MakerNote's tags of :data:`_APPLE_TAGS` by exiftool's names (``FocusDistanceRange``
    a pair of metres, ``AccelerationVector`` three values in g, the others integers), empty without one.
    """

    subject_distance_m: float | None = None
    subject_distance_range: str | None = None
    apple: dict = field(default_factory=dict)

    @property
    def focus_m(self) -> float | None:
        """The focus distance, m: the middle of Apple's ``FocusDistanceRange`` (the autofocus's own estimate), else
        EXIF ``SubjectDistance``; None when neither states one (infinity is not a distance to model)."""
        lo_hi = self.apple.get("FocusDistanceRange")
        if lo_hi and all(np.isfinite(lo_hi)) and min(lo_hi) > 0:
            return float(sum(lo_hi) / 2)
        d = self.subject_distance_m
        return d if d is not None and np.isfinite(d) else None

    @property
    def source(self) -> str | None:
        """Which tag :attr:`focus_m` comes from (``"Apple FocusDistanceRange"``, ``"EXIF SubjectDistance"``)."""
        if self.focus_m is None:
            return None
        lo_hi = self.apple.get("FocusDistanceRange")
        return "Apple FocusDistanceRange" if lo_hi and min(lo_hi) > 0 else "EXIF SubjectDistance"


def apple_maker_note(data: bytes) -> dict:
    """The tags of :data:`_APPLE_TAGS` in an Apple MakerNote (EXIF tag 0x927C's bytes; module constants say the
    layout), by exiftool's names; empty for another maker's note or a malformed one."""
    if not isinstance(data, bytes) or not data.startswith(_APPLE_PREFIX) or len(data) < _APPLE_IFD_START + 2:
        return {}
    order = "<" if data[12:14] == b"II" else ">"
    try:
        (count,) = struct.unpack_from(order + "H", data, _APPLE_IFD_START)
        out = {}
        for i in range(count):
            tag, kind, n, value = struct.unpack_from(order + "HHI4s", data, _APPLE_IFD_START + 2 + 12 * i)
            if tag not in _APPLE_TAGS or kind not in _TIFF_TYPES:
                continue
            name, wanted = _APPLE_TAGS[tag]
            code, size = _TIFF_TYPES[kind]
            items = n * (2 if kind in (5, 10) else 1)
            raw = value if items * size <= 4 else data[struct.unpack(order + "I", value)[0]:][:items * size]
            if len(raw) < items * size:
                continue                                        # its values lie beyond the note's end
            numbers = struct.unpack(order + code * items, raw[:items * size])
            if kind in (5, 10):
                numbers = tuple(p / q if q else float("nan") for p, q in zip(numbers[::2], numbers[1::2]))
            if len(numbers) >= wanted:
                out[name] = numbers[0] if wanted == 1 else tuple(float(x) for x in numbers[:wanted])
        return out
    except struct.error:
        return {}


def _focus_from_exif(exif: Image.Exif) -> FocusFacts:
    sub = exif.get_ifd(_EXIF_IFD) if exif else {}
    tags = {**dict(exif or {}), **dict(sub)}           # a DNG (TIFF/EP) may keep them in IFD 0
    distance = tags.get(_SUBJECT_DISTANCE)
    d = _rational(distance)
    if d is not None and getattr(distance, "numerator", None) == 0xFFFFFFFF:
        d = float("inf")
    code = tags.get(_SUBJECT_DISTANCE_RANGE)
    return FocusFacts(d if d else None, SUBJECT_DISTANCE_RANGES.get(code) if isinstance(code, int) else None,
                      apple_maker_note(tags.get(_MAKER_NOTE)))


def read_focus(path) -> FocusFacts:
    """Where a photo focused, from its metadata only (:class:`FocusFacts`): EXIF ``SubjectDistance`` and
    ``SubjectDistanceRange`` (JPEG, HEIC, DNG), and an iPhone's Apple MakerNote (``FocusDistanceRange``,
    ``FocusPosition``, ``AFStable``, ...). A photo without them gives empty facts (``focus_m`` None).

    Android's Camera2 focus distance (``LENS_FOCUS_DISTANCE``, dioptres) has no EXIF tag of its own: it is read
    where the camera app wrote it as ``SubjectDistance``.

    Parameters
    ----------
    path : str or Path
        The photo (JPEG, PNG, TIFF, HEIC or DNG); only its header is read.

    Returns
    -------
    FocusFacts
        What its metadata says; ``focus_m`` is the distance to use (None: none stated).

    Raises
    ------
    InputError
        Not a readable image.
    """
    if _is_raw(path):
        with _reading(path), open(path, "rb") as fp:
            return _focus_from_exif(_TiffTags(fp).getexif())
    with _reading(path), _pillow_open(path) as img:
        return _focus_from_exif(img.getexif())


def read_exif(path) -> tuple[tuple[int, int], dict]:
    """Stored pixel size ``(W, H)`` and EXIF facts of a photo, from its header only.

    The facts are ``make``, ``model``, ``lens_model`` (EXIF ``LensModel``), ``focal_length_mm``,
    ``focal_length_35mm_mm``, ``focal_plane_px_per_mm`` (the sensor's pixels per mm, from EXIF
    ``FocalPlaneXResolution``), ``orientation`` (the EXIF tag, 1-8, or None; never applied) and
    ``taken`` (capture time, a ``datetime`` or None). Raises :class:`InputError` for a file that is not a readable image.

    For a DNG the size is its raw frame's active area (what :func:`read_gray` returns).
    """
    if _is_raw(path):
        return _raw_exif(path)
    with _reading(path), _pillow_open(path) as img:
        return _stored_size(img, _heif_undo(img)), _exif_from_image(img)


def open_image(path) -> Image.Image:
    """Decode a photo with Pillow in its stored pixel frame (HEIC too, see :func:`_heif_undo`).

    The image keeps its ``format`` and ``info`` (EXIF with the file's orientation tag, ICC
    profile), so it can be written back in kind. A DNG is developed (:func:`_developed_image`) to
    an 8-bit sRGB image of format TIFF (written with :func:`output_suffix`'s ``.tif``). Raises
    :class:`InputError` for a file that is not a readable image.
    """
    if _is_raw(path):
        return _developed_image(path)
    with _reading(path):
        img = _pillow_open(path)
        try:
            check_plausible_photo(path, img.size, os.path.getsize(path))
            undo = _heif_undo(img)
            img.load()
        except BaseException:
            img.close()
            raise
    if img.format != "HEIF":
        return img
    stored = img
    for op in undo:
        stored = stored.transpose(op)
    stored.format = img.format
    orientation = img.info.get("original_orientation")
    if orientation:                     # put back the tag pillow-heif reset: it is true of the stored frame
        exif = img.getexif()
        exif[_ORIENTATION] = orientation
        stored.info["exif"] = exif.tobytes()
    if stored is not img:
        img.close()
    return stored


#: Largest image read, pixels: five times a 200 MP phone photo.
MAX_PIXELS = 1_000_000_000
#: Beyond :data:`PLAUSIBLE_PIXELS`, a photo (sensor noise, texture) needs at least one byte per this many
#: pixels: JPEG keeps 0.5-4 bits a pixel, a PNG of a photo about 8. Only a drawing compresses further.
MAX_PIXELS_PER_BYTE = 200
PLAUSIBLE_PIXELS = 16_000_000


def check_plausible_photo(path, size: tuple[int, int], file_bytes: int) -> None:
    """Raise :class:`InputError` when a header's size ``(W, H)`` cannot be a photo's, before it is decoded:
    beyond :data:`MAX_PIXELS`, or beyond :data:`PLAUSIBLE_PIXELS` with more than :data:`MAX_PIXELS_PER_BYTE`
    pixels per byte of the file (a 190 KB PNG of 13000 x 13000). A large photo is not refused for its size."""
    w, h = size
    pixels = w * h
    if pixels > MAX_PIXELS or (pixels > PLAUSIBLE_PIXELS and pixels > MAX_PIXELS_PER_BYTE * max(file_bytes, 1)):
        raise InputError(f"{path}: its header says {w} x {h} px ({pixels / 1e6:.0f} MP) in {file_bytes / 1e3:.0f} KB, "
                         "which no photo is: not decoded")


def _jpeg_complete(data: bytes) -> bool:
    """True when the last scan of a JPEG is closed by an end-of-image marker.

    Inside entropy-coded data every 0xFF byte is stuffed, so neither SOS (FF DA) nor EOI
    (FF D9) can occur there: a file cut short has no EOI after its last SOS. Data appended
    after the EOI (maker trailers) does not matter. (Searched from both ends: a baseline JPEG's one
    SOS is near its start, and a backward search for it would read the whole file.)
    """
    eoi = data.rfind(b"\xff\xd9")
    return eoi > 0 and data.find(b"\xff\xda", eoi) < 0 and data.find(b"\xff\xda", 0, eoi) > 0


def read_gray(path) -> np.ndarray:
    """Decode a photo at full resolution as 8-bit grey, in its stored pixel frame.

    The EXIF orientation is not applied. JPEG, PNG and TIFF go through OpenCV, HEIC through
    :func:`open_image`, DNG through :func:`_raw_gray`. A truncated or corrupt file raises :class:`InputError`.
    """
    path = Path(path)
    if _is_raw(path):
        return _raw_gray(path)
    if path.suffix.lower() in (".heic", ".heif"):
        with open_image(path) as img:
            return np.asarray(img.convert("L"))
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        with _pillow_open(io.BytesIO(data)) as header:
            size = header.size
    except Image.DecompressionBombError as exc:
        raise InputError(f"{path}: {exc}: not decoded") from None
    except _UNREADABLE:         # OpenCV has the last word on what it can decode
        size = (0, 0)
    check_plausible_photo(path, size, len(data))
    if data.startswith(b"\xff\xd8") and not _jpeg_complete(data):     # a JPEG by its content, whatever its name
        raise InputError(f"{path}: truncated or corrupt JPEG (no end-of-image marker after its last scan)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise InputError(f"{path}: cannot be decoded as an image")
    return img


# ---------------------------------------------------------------------------- formats

def _is_raw(path) -> bool:
    return Path(path).suffix.lower() in RAW_SUFFIXES


def source_format(path) -> str:
    """``"jpeg"``, ``"png"``, ``"tiff"``, ``"heic"`` or ``"dng"``: the kind of photo file ``path`` is."""
    suffix = Path(path).suffix.lower()
    return _FORMATS.get(suffix, suffix.lstrip("."))


def output_suffix(path) -> str:
    """The file suffix of a photo written from ``path`` by :func:`open_image` (a DNG's is ``.tif``)."""
    return ".tif" if _is_raw(path) else Path(path).suffix


def decode_bytes_per_pixel(path) -> float:
    """Peak memory of :func:`read_gray` and of detecting the board in its image, bytes per pixel.

    Measured (48 MP, 2 photos at once): a JPEG about 2.5 (its file, the grey image, the reduced
    copies), a DNG about 4.5 (LibRaw's raw frame, 2 bytes a pixel, and :func:`_bayer_gray`'s 2),
    a HEIC about 5 (estimated, not measured: pillow-heif decodes to RGB first).
    """
    return {"dng": 4.5, "heic": 5.0}.get(source_format(path), 2.5)


def jobs_within_memory(photos, memory_bytes: float = PHOTO_MEMORY_BYTES, cores: int | None = None) -> int:
    """How many of ``photos`` (:class:`Photo`) to read and detect at once: all cores (``cores``,
    default ``os.cpu_count()``), but no more than keep the largest of them, that many at a time,
    within ``memory_bytes`` (:func:`decode_bytes_per_pixel`); at least 1. A 48 MP JPEG takes
    about 0.12 GB, so 8 cores run 8 of them; a 200 MP DNG 0.9 GB, so one runs at a time."""
    cores = max(1, cores or os.cpu_count() or 1)
    largest = max((p.size[0] * p.size[1] * decode_bytes_per_pixel(p.path) for p in photos), default=0.0)
    return max(1, min(cores, int(memory_bytes // largest) if largest else cores))


# ---------------------------------------------------------------------------- RAW (DNG)

# LibRaw's development for open_image: full size (half_size off), no turn (user_flip=0: the
# stored frame), the camera's white balance, no auto-brightening (a fixed exposure: a photo's
# tone does not depend on its content), BT.709 gamma; none of these moves a pixel.
_DEVELOP = {"half_size": False, "user_flip": 0, "use_camera_wb": True, "no_auto_bright": True,
            "output_bps": 8}


def _developed(raw: rawpy.RawPy) -> np.ndarray:
    """``raw`` developed by LibRaw: :data:`_DEVELOP`, AHD demosaicing."""
    import rawpy

    return raw.postprocess(**_DEVELOP, demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD)


def _open_raw(path) -> rawpy.RawPy:
    """LibRaw's handle of a raw file (metadata read; pixels unpacked on first use)."""
    import rawpy

    Path(path).stat()                        # a missing file: FileNotFoundError, which LibRaw calls an I/O error
    return rawpy.imread(str(path))


class _TiffTags:
    """The tags of a TIFF that Pillow cannot decode (a DNG: IFD 0 and its EXIF IFD, read from
    ``fp`` as Pillow's TIFF reader does), as :func:`_exif_from_image` reads an image."""

    format, info = "DNG", {}

    def __init__(self, fp):
        self._exif = Image.Exif()
        self._exif.load_from_fp(fp)

    def getexif(self) -> Image.Exif:
        return self._exif


def _raw_exif(path) -> tuple[tuple[int, int], dict]:
    """Active-area size and EXIF facts of a DNG: LibRaw's sizes and the DNG's tags (header only;
    no pixel is decoded)."""
    with _reading(path):
        with _open_raw(path) as raw:
            size = (int(raw.sizes.width), int(raw.sizes.height))
        with open(path, "rb") as fp:
            return size, _exif_from_image(_TiffTags(fp))


def _check_visible(path, image: np.ndarray, raw) -> np.ndarray:
    visible = (int(raw.sizes.height), int(raw.sizes.width))
    if image.shape[:2] != visible:
        raise InputError(f"{path}: LibRaw develops this raw frame to {image.shape[1]}x{image.shape[0]}, not its "
                         f"{visible[1]}x{visible[0]} sensor pixels (a sensor of non-square pixels?): it cannot "
                         "be read pixel for pixel")
    return image


def _is_bayer(raw) -> bool:
    """A raw frame of one sample a pixel under a 2 x 2 red, green, blue colour filter array."""
    import rawpy

    pattern = raw.raw_pattern
    return (raw.raw_type == rawpy.RawType.Flat and pattern is not None and pattern.shape == (2, 2)
            and sorted(raw.color_desc.decode()[c] for c in pattern.flat) == ["B", "G", "G", "R"])


def _bayer_gray(raw) -> np.ndarray:
    """Grey of a Bayer raw frame: each site's black level off, the camera's white balance and a
    1/2.2 power (as a photo is encoded) in one table per site of the 2 x 2 pattern, to 8 bits; then
    OpenCV's bilinear demosaicing straight to grey (``COLOR_Bayer....2GRAY``).

    Output pixel ``(i, j)`` is sensor pixel ``(i, j)`` of LibRaw's visible area. The tone curve is
    monotonic and the demosaicing symmetric, so neither moves a corner. Besides LibRaw's frame
    (2 bytes a pixel) it needs 2 bytes a pixel, where LibRaw's own development needs 16.
    """
    cfa = raw.raw_image_visible                          # (H, W) uint16, a view of LibRaw's frame
    pattern = raw.raw_pattern                            # colour index at (row % 2, col % 2)
    desc = raw.color_desc.decode()
    wb = np.asarray(raw.camera_whitebalance, float)
    if wb[3] == 0 and desc[3] == "G":                    # LibRaw: 0 for the second green is the first's
        wb[3] = wb[1]
    if not np.all(wb[pattern] > 0):                      # no white balance recorded
        wb = np.ones(4)
    wb = wb / wb[pattern].min()
    black = np.asarray(raw.black_level_per_channel, float)
    level = np.arange(65536, dtype=float)
    mosaic = np.empty(cfa.shape, np.uint8)
    for y in range(2):
        for x in range(2):
            c = pattern[y, x]
            linear = np.clip((level - black[c]) * wb[c] / max(float(raw.white_level) - black[c], 1.0), 0.0, 1.0)
            table = np.rint(255.0 * linear ** (1 / 2.2)).astype(np.uint8)
            mosaic[y::2, x::2] = table[cfa[y::2, x::2]]
    code = getattr(cv2, f"COLOR_Bayer{''.join(desc[c] for c in pattern.flat)}2GRAY")
    return cv2.cvtColor(mosaic, code)


def _raw_gray(path) -> np.ndarray:
    """A DNG as 8-bit grey, pixel for pixel of its active area: :func:`_bayer_gray` for a Bayer
    frame, else (a linear DNG, already demosaiced, or another filter array) LibRaw's development."""
    with _reading(path), _open_raw(path) as raw:
        if _is_bayer(raw):
            gray = _bayer_gray(raw)
        else:
            gray = cv2.cvtColor(_developed(raw), cv2.COLOR_RGB2GRAY)
        return _check_visible(path, gray, raw)


def _developed_image(path) -> Image.Image:
    """A DNG developed by LibRaw (:func:`_developed`: 8-bit sRGB, the camera's white balance, no
    auto-brightening, AHD demosaicing) as a Pillow image of format TIFF in the raw frame's own
    orientation, with the DNG's EXIF (its make, model, orientation tag, and EXIF IFD) in ``info``."""
    with _reading(path):
        with _open_raw(path) as raw:
            rgb = _check_visible(path, _developed(raw), raw)
        with open(path, "rb") as fp:
            dng = _TiffTags(fp).getexif()
            exif = Image.Exif()
            for tag in (_MAKE, _MODEL, _ORIENTATION, _DATETIME):
                if dng.get(tag) is not None:
                    exif[tag] = dng[tag]
            sub = dict(dng.get_ifd(_EXIF_IFD))
    if sub:
        exif[_EXIF_IFD] = sub
    img = Image.fromarray(rgb)
    img.format = "TIFF"
    img.info["exif"] = exif.tobytes()
    return img
