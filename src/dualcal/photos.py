"""Reading photos: their stored pixels and the facts of their EXIF header.

Every photo dualcal reads is opened here, by :func:`read_exif` (header only), :func:`read_gray`
(detection) and :func:`open_image` (rectification, undistortion), so all formats and their errors
are handled in one place: JPEG, PNG and TIFF through OpenCV or Pillow, HEIC through pillow-heif.

Pixels are used as stored: the EXIF orientation tag is reported, never applied (the sensor does
not turn when the phone does), so every coordinate is in the stored frame.
"""

from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from .errors import InputError

try:  # HEIC/HEIF through pillow-heif
    import pillow_heif

    pillow_heif.register_heif_opener()
except ImportError:  # pragma: no cover - pillow-heif is a dependency; HEIC is then unreadable
    pillow_heif = None

__all__ = ["PHOTO_SUFFIXES", "Photo", "open_image", "read_exif", "read_gray"]

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".heic", ".heif")

# EXIF tags (TIFF/EXIF 2.3)
_ORIENTATION, _MAKE, _MODEL, _EXIF_IFD = 0x0112, 0x010F, 0x0110, 0x8769
_DATETIME, _DATETIME_ORIGINAL, _SUBSEC_ORIGINAL = 0x0132, 0x9003, 0x9291
_FOCAL_LENGTH, _FOCAL_35MM, _LENS_MODEL = 0x920A, 0xA405, 0xA434


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
    orientation = exif.get(_ORIENTATION)
    if img.format == "HEIF":   # pillow-heif set the tag to 1 and kept the file's value aside
        orientation = img.info.get("original_orientation") or orientation
    return {
        "make": make.strip("\x00 ") if isinstance(make, str) else None,
        "model": model.strip("\x00 ") if isinstance(model, str) else None,
        "lens_model": lens.strip("\x00 ") or None if isinstance(lens, str) else None,
        "focal_length_mm": _rational(sub.get(_FOCAL_LENGTH)),
        "focal_length_35mm_mm": _rational(f35) if f35 else None,
        "orientation": int(orientation) if orientation is not None else None,
        "taken": taken,
    }


# What Pillow and pillow-heif raise for a file that is not a readable image (pillow-heif
# documents ValueError, EOFError, SyntaxError, RuntimeError and OSError; Pillow refuses
# absurdly large images with DecompressionBombError).
_UNREADABLE = (OSError, SyntaxError, ValueError, EOFError, RuntimeError, Image.DecompressionBombError)


@contextlib.contextmanager
def _reading(path):
    """Turn the errors of opening or decoding ``path`` into one clear :class:`InputError`."""
    try:
        yield
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except _UNREADABLE as exc:
        raise InputError(f"{path}: not a readable image ({exc})") from None


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
        version = getattr(pillow_heif, "__version__", "?")
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


def read_exif(path) -> tuple[tuple[int, int], dict]:
    """Stored pixel size ``(W, H)`` and EXIF facts of a photo, from its header only.

    The facts are ``make``, ``model``, ``lens_model`` (EXIF ``LensModel``), ``focal_length_mm``,
    ``focal_length_35mm_mm``, ``orientation`` (the EXIF tag, 1-8, or None; never applied) and
    ``taken`` (capture time, a ``datetime`` or None). Raises :class:`InputError` for a file that is not a readable image.
    """
    with _reading(path), Image.open(path) as img:
        return _stored_size(img, _heif_undo(img)), _exif_from_image(img)


def open_image(path) -> Image.Image:
    """Decode a photo with Pillow in its stored pixel frame (HEIC too, see :func:`_heif_undo`).

    The image keeps its ``format`` and ``info`` (EXIF with the file's orientation tag, ICC
    profile), so it can be written back in kind. Raises :class:`InputError` for a file that is
    not a readable image.
    """
    with _reading(path):
        img = Image.open(path)
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
    after the EOI (maker trailers) does not matter.
    """
    return data.rfind(b"\xff\xd9") > data.rfind(b"\xff\xda") > 0


def read_gray(path) -> np.ndarray:
    """Decode a photo at full resolution as 8-bit grey, in its stored pixel frame.

    The EXIF orientation is not applied. JPEG, PNG and TIFF go through OpenCV, HEIC through
    :func:`open_image`. A truncated or corrupt file raises :class:`InputError`.
    """
    path = Path(path)
    if path.suffix.lower() in (".heic", ".heif"):
        with open_image(path) as img:
            return np.asarray(img.convert("L"))
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        with Image.open(io.BytesIO(data)) as header:
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
