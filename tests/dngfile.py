"""Writing DNG files for the tests: a rendered board mosaicked to a Bayer raw frame, or linear (pidng).

A render (:func:`dualcal.synthetic.render.render_view`) is an 8-bit grey photo of a grey board: its value
``g`` is taken back to linear light ``(g / 255) ** 2.2`` and each pixel of the colour filter
array records it through its channel's gain (a neutral scene seen by a sensor whose red and blue
are less sensitive than its green), on a 12-bit scale above a black level. The DNG says so
(``AsShotNeutral`` = the gains), so a raw developer's white balance undoes them. Pixel ``(i, j)``
of the render is sensor pixel ``(i, j)`` of the DNG's active area, inside a masked margin.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np
from pidng.core import RAW2DNG, DNGTags, Tag
from pidng.dng import Type, dngIFD, dngTag

CHANNEL = {"R": 0, "G": 1, "B": 2}
GAINS = {"R": 0.55, "G": 1.0, "B": 0.7}


def mosaic(gray: np.ndarray, pattern: str = "RGGB", black: int = 64, white: int = 4095,
           margin: tuple[int, int, int, int] = (0, 0, 0, 0)) -> np.ndarray:
    """The raw frame (uint16) of a grey image under a 2 x 2 ``pattern``, with ``margin`` masked
    (black) rows and columns (top, left, bottom, right) around it."""
    linear = (np.asarray(gray, float) / 255.0) ** 2.2
    gain = np.array([GAINS[c] for c in pattern]).reshape(2, 2)
    h, w = linear.shape
    raw = black + linear * gain[np.arange(h)[:, None] % 2, np.arange(w)[None, :] % 2] * (white - black)
    top, left, bottom, right = margin
    frame = np.full((h + top + bottom, w + left + right), black, np.uint16)
    frame[top:top + h, left:left + w] = np.rint(raw).astype(np.uint16)
    return frame


def write_dng(path, gray: np.ndarray, *, pattern: str = "RGGB", black: int = 64, white: int = 4095,
              margin: tuple[int, int, int, int] = (0, 0, 0, 0), orientation: int = 1, make: str = "dualcal",
              model: str = "synthetic phone", taken: datetime | None = None, focal_length_mm: float | None = None,
              focal_length_35mm_mm: int | None = None, lens_model: str | None = None) -> Path:
    """Write ``gray`` (a render, (H, W) uint8) as a Bayer DNG whose active area is ``gray``'s pixels.

    ``pattern`` is the active area's: its top-left pixel is ``pattern[0]`` (the DNG specification
    puts the origin of ``CFAPattern`` at the ``ActiveArea``'s)."""
    top, left, bottom, right = margin
    frame = mosaic(gray, pattern, black, white, margin)
    tags = DNGTags()
    for tag, value in ((Tag.ImageWidth, frame.shape[1]), (Tag.ImageLength, frame.shape[0]),
                       (Tag.TileWidth, frame.shape[1]), (Tag.TileLength, frame.shape[0]),
                       (Tag.Orientation, orientation), (Tag.PhotometricInterpretation, 32803),
                       (Tag.SamplesPerPixel, 1), (Tag.BitsPerSample, 16), (Tag.CFARepeatPatternDim, [2, 2]),
                       (Tag.CFAPattern, [CHANNEL[c] for c in pattern]),
                       (Tag.BlackLevel, black), (Tag.WhiteLevel, white),
                       (Tag.ActiveArea, [top, left, top + gray.shape[0], left + gray.shape[1]]),
                       (Tag.ColorMatrix1, [[1, 1], [0, 1], [0, 1], [0, 1], [1, 1], [0, 1], [0, 1], [0, 1], [1, 1]]),
                       (Tag.CalibrationIlluminant1, 21),
                       (Tag.AsShotNeutral, [[int(GAINS[c] * 1000), 1000] for c in "RGB"]),
                       (Tag.Make, make), (Tag.Model, model), (Tag.UniqueCameraModel, f"{make} {model}")):
        tags.set(tag, value)
    exif = dngIFD()
    if taken is not None:
        exif.tags.append(dngTag(Tag.DateTimeOriginal, taken.strftime("%Y:%m:%d %H:%M:%S")))
    if focal_length_mm is not None:
        exif.tags.append(dngTag(Tag.FocalLength, [[int(round(focal_length_mm * 100)), 100]]))
    if focal_length_35mm_mm is not None:
        exif.tags.append(dngTag(Tag.FocalLengthIn35mmFilm, [int(focal_length_35mm_mm)]))
    if lens_model is not None:
        exif.tags.append(dngTag(Tag.EXIFPhotoLensModel, lens_model))
    if exif.tags:
        # pidng 4.0.9's IFD-typed tag fails on Python 3 (it mixes str and bytes): a LONG tag that
        # carries the sub-IFD is what it would write
        pointer = dngTag((Tag.EXIF_IFD[0], Type.Long), [0])
        pointer.subIFD = exif
        tags.__tags__[Tag.EXIF_IFD] = pointer
    writer = RAW2DNG()
    writer.options(tags, path="", compress=False)
    path = Path(path)
    path.write_bytes(bytes(writer.convert(frame)))
    return path


def write_linear_dng(path, gray: np.ndarray, white: int = 4095) -> Path:
    """Write ``gray`` as a linear DNG (``LinearRaw``: three samples a pixel, already demosaiced, as
    Apple's ProRAW is), its linear light on a 12-bit scale."""
    linear = np.rint((np.asarray(gray, float) / 255.0) ** 2.2 * white).astype(np.uint16)
    h, w = linear.shape
    tags = DNGTags()
    for tag, value in ((Tag.ImageWidth, w), (Tag.ImageLength, h), (Tag.TileWidth, w), (Tag.TileLength, h),
                       (Tag.PhotometricInterpretation, 34892), (Tag.SamplesPerPixel, 3),
                       (Tag.BitsPerSample, [16, 16, 16]), (Tag.BlackLevel, 0), (Tag.WhiteLevel, white),
                       (Tag.ColorMatrix1, [[1, 1], [0, 1], [0, 1], [0, 1], [1, 1], [0, 1], [0, 1], [0, 1], [1, 1]]),
                       (Tag.CalibrationIlluminant1, 21), (Tag.AsShotNeutral, [[1, 1], [1, 1], [1, 1]]),
                       (Tag.Make, "dualcal"), (Tag.Model, "linear phone"), (Tag.UniqueCameraModel, "dualcal linear")):
        tags.set(tag, value)
    writer = RAW2DNG()
    writer.options(tags, path="", compress=False)
    path = Path(path)
    path.write_bytes(bytes(writer.convert(np.repeat(linear, 3, axis=1))))
    return path
