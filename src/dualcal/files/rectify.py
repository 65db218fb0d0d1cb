"""Undistorted ("rectified") photos: the paper's section 1.8, eqs. 24-29.

The rectified image is an ideal pinhole image, ``I'(u, v) = I(u~, v~)`` (eq. 29): for every
output pixel ``(u, v)`` the distorted source position ``(u~, v~)`` follows from the forward
model, so no equation has to be solved per pixel:

* ``(x, y) = A'^-1 (u, v, 1)`` with the output matrix ``A'`` (eq. 28 inverted),
* ``(x~, y~) = (x, y) (1 + k1 r^2 + k2 r^4)`` (eq. 13; eq. 25 corrected), or the camera's full
  lens model (:mod:`dualcal.geometry.camera`: ``k3`` and the tangential ``p1, p2``, or the fisheye ``kb4``),
* ``(u~, v~) = A (x~, y~, 1)`` with the camera's matrix ``A`` (eq. 24 inverted),

then the source is resampled there with ``cv2.remap``. Points go the other way with
Newton-Raphson on the radial polynomial (eqs. 25-27), and 2-D Newton on the full model where it
has tangential terms: :func:`dualcal.geometry.camera.undistort_points`.

The output matrix ``A'`` is chosen by ``keep`` (see :func:`rectified_camera`): the camera's own
``A`` (``"same"``), one that keeps every source pixel (``"all"``) or one that shows only valid
pixels (``"valid"``). The output has the size of the input; pixel centres follow the contract
(pixel ``(row i, col j)`` is at ``(u=j, v=i)``). Maps are computed and applied in horizontal
bands of ``band_rows`` rows, so memory beyond the two images stays bounded for any image size.
Files keep their EXIF block (and ICC profile): the stored pixel frame does not change, so an
orientation tag stays true.
"""

from __future__ import annotations

import io
import os
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, JpegImagePlugin

from ..geometry.camera import (CameraModel, check_invertible_in_image, distort, fold_radius, intrinsic_names,
                               normalized_from_pixel, pixel_from_normalized, radial_factor, tangential_shift,
                               undistort_points)
from .photos import open_image, output_suffix, read_exif
from ..errors import InputError
from .io import make_output_folder, read_json, write_bytes_atomic
from ..parallel import interruptible_map, raise_if_cancelled
from ..progress import progress_bar, warn

KEEP_MODES = ("same", "all", "valid")
DEFAULT_BAND_ROWS = 64
JPEG_QUALITY = 95         # also the quality of HEIC outputs
_BORDER_SAMPLES = 256     # samples per image edge when tracing the rectified border
_REMAP_MARGIN_ROWS = 4    # source rows kept around a band's footprint (interpolation support)


# ---------------------------------------------------------------------------- the output camera


def _border_pixels(image_size: tuple[int, int], n: int = _BORDER_SAMPLES) -> dict[str, np.ndarray]:
    """(n, 2) pixel centres along each edge of an image: ``left, right, top, bottom``."""
    w, h = image_size
    us, vs = np.linspace(0.0, w - 1.0, n), np.linspace(0.0, h - 1.0, n)
    return {"left": np.column_stack([np.zeros(n), vs]),
            "right": np.column_stack([np.full(n, w - 1.0), vs]),
            "top": np.column_stack([us, np.zeros(n)]),
            "bottom": np.column_stack([us, np.full(n, h - 1.0)])}


def rectified_camera(cam: CameraModel, keep: str = "same") -> CameraModel:
    """The pinhole camera (no lens distortion, :meth:`~dualcal.geometry.camera.CameraModel.pinhole`) of the
    rectified image, same size as ``cam``'s.

    Parameters
    ----------
    cam : CameraModel
        the calibrated camera.
    keep : str
        ``"same"``: the camera's own matrix ``A`` (a distorted pixel and its rectified
        position describe the same ray through the same ``A``); ``"all"``: every source pixel
        stays inside the output (a black border appears where the source has no pixels);
        ``"valid"``: every output pixel has a source pixel (no border, the rim is cut).
        ``"all"`` and ``"valid"`` trace the source's outer pixel centres through the model,
        keep ``fx / fy`` of the camera, set skew to 0 and centre the traced border.

    Returns
    -------
    CameraModel
        A camera without lens distortion, of ``cam``'s image size.

    Raises
    ------
    InputError
        Unknown ``keep``.
    NotInvertibleError
        The distortion folds over inside the image, so the rectified image is not defined;
        with ``"same"`` only a fold that reaches the middle of an image edge is refused (one in
        the corners costs those corners, which :func:`rectify_map` masks).
    """
    if keep not in KEEP_MODES:
        raise InputError(f"--keep {keep!r} is unknown (choose from {', '.join(KEEP_MODES)})")
    check_invertible_in_image(cam, corners_may_fold=keep == "same")
    if keep == "same":
        return cam.pinhole()
    # Trace the image border into ideal normalised coordinates (eqs. 24-27).
    edges = {name: normalized_from_pixel(cam.pinhole(), undistort_points(cam, uv))
             for name, uv in _border_pixels(cam.image_size).items()}
    if keep == "all":
        xy = np.vstack(list(edges.values()))
        (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
    else:  # the largest box inside the traced border: innermost point of each edge
        x0, x1 = edges["left"][:, 0].max(), edges["right"][:, 0].min()
        y0, y1 = edges["top"][:, 1].max(), edges["bottom"][:, 1].min()
    # Map the box onto the output's outer pixel centres, keeping the camera's fx / fy.
    w, h = cam.image_size
    aspect = cam.fx / cam.fy
    fit = (min if keep == "all" else max)((w - 1) / (aspect * (x1 - x0)), (h - 1) / (y1 - y0))
    fx, fy = float(aspect * fit), float(fit)
    return replace(cam.pinhole(), fx=fx, fy=fy, skew=0.0, cx=float((w - 1) / 2 - fx * (x0 + x1) / 2),
                   cy=float((h - 1) / 2 - fy * (y0 + y1) / 2))


# ---------------------------------------------------------------------------- maps and images


def rectify_map(cam: CameraModel, new_cam: CameraModel, row0: int, row1: int,
                R: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distorted source position of every output pixel in rows ``row0 .. row1 - 1``.

    The forward model of eqs. 24-29 (module docstring). Without ``R`` it is evaluated
    separably: ``y`` depends on the row only, so the band costs a handful of (B, W) array
    operations. ``R`` (3, 3) turns the output camera against ``cam``, ``X_out = R X_cam`` (a
    stereo rectification, :mod:`dualcal.files.stereo`): each output ray is turned back into ``cam``'s
    frame first. Output pixels whose ideal radius lies beyond the model's monotonic range
    would fold back onto other source pixels, and rays behind the camera have no source; they
    get the position ``(-1e6, -1e6)``, which remaps to the border value.

    Returns
    -------
    map_x, map_y : (row1 - row0, W) float32 source ``u~, v~`` in pixels, as ``cv2.remap`` takes.
    """
    w = new_cam.image_size[0]
    y = ((np.arange(row0, row1, dtype=float) - new_cam.cy) / new_cam.fy)[:, None]            # (B, 1)
    x = ((np.arange(w, dtype=float) - new_cam.cx)[None, :] - new_cam.skew * y) / new_cam.fx  # (B, W)
    behind = None
    if R is not None:
        (a, b, c), (d, e, f_), (g, h, i) = np.asarray(R, float).T    # rows of R^T: ray in cam's frame
        z = g * x + h * y + i
        behind = z <= 0
        x, y = (a * x + b * y + c) / z, (d * x + e * y + f_) / z
    r2 = x * x + y * y                                                                        # (B, W)
    if cam.fisheye:                  # no separable shortcut: the whole ideal point through the lens
        uv = pixel_from_normalized(cam, distort(cam, np.stack(np.broadcast_arrays(x, y), axis=-1)))
        map_x, map_y = uv[..., 0], uv[..., 1]
    else:
        map_x, map_y = _radial_tangential_map(cam, x, y, r2)
    r_max = fold_radius(cam)
    invalid = r2 > r_max * r_max if np.isfinite(r_max) else np.zeros(map_x.shape, bool)
    if behind is not None:
        invalid |= behind
    map_x[invalid] = map_y[invalid] = -1e6
    return map_x.astype(np.float32), map_y.astype(np.float32)


def _radial_tangential_map(cam: CameraModel, x: np.ndarray, y: np.ndarray, r2: np.ndarray):
    """Source pixels ``(u~, v~)`` of ideal ``x, y`` through a radial-tangential lens (eq. 13)."""
    f = radial_factor(r2, *cam.radial)
    yd = y * f
    if cam.tangential:
        tx, ty = tangential_shift(x, y, cam.p1, cam.p2)
        yd = yd + ty
        map_x = cam.fx * (x * f + tx) + cam.skew * yd + cam.cx
    else:
        map_x = (cam.fx * f) * x + cam.skew * yd + cam.cx
    return map_x, cam.fy * yd + cam.cy


def undistort_image(image: np.ndarray, cam: CameraModel, new_cam: CameraModel | None = None,
                    band_rows: int = DEFAULT_BAND_ROWS, interpolation: int = cv2.INTER_LINEAR,
                    R: np.ndarray | None = None) -> np.ndarray:
    """The rectified image ``I'(u, v) = I(u~, v~)`` (paper eq. 29), computed in bands.

    Parameters
    ----------
    image : ndarray
        (H, W) or (H, W, C) array (uint8, uint16 or float32; C <= 4) taken by ``cam``.
    cam : CameraModel
        the calibrated camera; ``cam.image_size`` must be ``(W, H)``.
    new_cam : CameraModel or None
        pinhole camera of the output (default: :func:`rectified_camera` ``(cam, "same")``);
        its ``image_size`` is the output's.
    band_rows : int
        rows per band; the result does not depend on it.
    interpolation : int
        a ``cv2.INTER_*`` flag.
    R : ndarray or None
        (3, 3) rotation of the output camera, ``X_out = R X_cam`` (see :func:`rectify_map`).

    Returns
    -------
    (H', W'[, C]) ndarray
        Of the input's dtype, ``(W', H') = new_cam.image_size``; pixels with no source are 0.

    Raises
    ------
    InputError
        The image does not have the camera's size.
    """
    h, w = image.shape[:2]
    if (w, h) != tuple(cam.image_size):
        raise InputError(f"image is {w}x{h} px but the camera was calibrated at "
                         f"{cam.image_size[0]}x{cam.image_size[1]} px")
    new_cam = new_cam if new_cam is not None else rectified_camera(cam, "same")
    band_rows = max(1, int(band_rows))
    w_out, h_out = new_cam.image_size
    out = np.zeros((h_out, w_out) + image.shape[2:], image.dtype)
    for row0 in range(0, h_out, band_rows):
        raise_if_cancelled()
        row1 = min(h_out, row0 + band_rows)
        map_x, map_y = rectify_map(cam, new_cam, row0, row1, R)
        # Only the source rows this band reaches (plus the interpolation support) are passed on;
        # the offset is an integer, so the float32 map stays exact and the result band-independent.
        inside = map_y[(map_y > -_REMAP_MARGIN_ROWS) & (map_y < h - 1 + _REMAP_MARGIN_ROWS)]
        if inside.size == 0:
            continue
        src0 = max(0, int(np.floor(inside.min())) - _REMAP_MARGIN_ROWS)
        src1 = min(h, int(np.ceil(inside.max())) + _REMAP_MARGIN_ROWS + 1)
        map_y -= np.float32(src0)
        out[row0:row1] = cv2.remap(image[src0:src1], map_x, map_y, interpolation,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out


# ---------------------------------------------------------------------------- photo files


def _check_size(path: Path, size: tuple[int, int], cam: CameraModel) -> None:
    if tuple(size) != tuple(cam.image_size):
        raise InputError(f"{path}: image is {size[0]}x{size[1]} px but the camera was calibrated at "
                         f"{cam.image_size[0]}x{cam.image_size[1]} px (a photo of another camera?)")


# Pillow modes resampled as they are: 8-bit bands, 16-bit grey (any byte order), 32-bit int and float.
_KEPT_MODES = ("L", "LA", "RGB", "RGBA", "CMYK", "YCbCr", "I;16", "I;16L", "I;16B", "I;16N", "I", "F")


def _pixels(img: Image.Image) -> tuple[np.ndarray, str]:
    """Pixel array ``cv2.remap`` can resample at the image's full depth, and the mode to write back.

    16-bit grey stays 16-bit (in native byte order); 32-bit integers are resampled as float64
    (exact); palettes become RGB(A), bilevel images grey, other modes RGB(A).
    """
    if img.mode not in _KEPT_MODES:
        alpha = "A" in img.getbands() or "transparency" in img.info
        img = img.convert("L" if img.mode == "1" else "RGBA" if alpha else "RGB")
    pixels = np.asarray(img)
    if img.mode == "I":
        pixels = pixels.astype(np.float64)
    return pixels.astype(pixels.dtype.newbyteorder("=")), img.mode


def _image_from(pixels: np.ndarray, mode: str) -> Image.Image:
    """The inverse of :func:`_pixels`."""
    if mode == "I":
        return Image.fromarray(np.rint(pixels).astype(np.int32))
    if pixels.dtype == np.uint8:      # 8-bit bands: RGBA and CMYK look alike, so say which
        return Image.fromarray(pixels, mode=mode)
    return Image.fromarray(pixels)    # 16-bit grey and float: the array's type sets the mode


def undistort_file(src, dst, cam: CameraModel, new_cam: CameraModel | None = None,
                   band_rows: int = DEFAULT_BAND_ROWS, R: np.ndarray | None = None,
                   blur_sigma_px: float = 0.0) -> Path:
    """Rectify one photo file into ``dst`` (written atomically), keeping EXIF and ICC profile.

    The output format is the input's (JPEG at quality 95 with the source's chroma
    subsampling; HEIC at quality 95, in its stored frame with its EXIF orientation; 16-bit
    grey stays 16-bit; a DNG is developed to an 8-bit sRGB TIFF, :func:`~dualcal.files.photos.open_image`).
    ``R`` turns the output camera (:func:`undistort_image`); ``blur_sigma_px`` > 0 smooths the
    source first (a Gaussian of that sigma), against aliasing where the output has fewer pixels
    per ray than the source. Returns ``dst``. Raises
    :class:`InputError` for an unreadable file or a wrong image size.
    """
    src, dst = Path(src), Path(dst)
    img = open_image(src)
    _check_size(src, img.size, cam)
    fmt = img.format or "PNG"
    options = {k: img.info[k] for k in ("exif", "icc_profile", "dpi") if img.info.get(k)}
    if fmt in ("JPEG", "HEIF"):
        options["quality"] = JPEG_QUALITY
    if fmt == "JPEG":
        sampling = JpegImagePlugin.get_sampling(img)
        if sampling >= 0:
            options["subsampling"] = sampling
    pixels, mode = _pixels(img)
    img.close()
    if blur_sigma_px > 0:
        pixels = cv2.GaussianBlur(pixels, (0, 0), blur_sigma_px)
    out = _image_from(undistort_image(pixels, cam, new_cam, band_rows, R=R), mode)
    encoded = io.BytesIO()       # encoded in memory, so the write is checked to the last byte
    out.save(encoded, format=fmt, **options)
    write_bytes_atomic(dst, encoded.getvalue())
    return dst


def _undistort_task(task) -> str | None:
    """Worker: rectify one file; a failure the photo can cause comes back as a message naming it.

    Beyond :class:`InputError`, OpenCV, the file system and Pillow's encoders can fail on one
    photo (an odd pixel format, a full disk): that photo is skipped, the others go on. Any other
    exception is a bug and is not caught.
    """
    src, dst, cam, new_cam, band_rows = task
    try:
        undistort_file(src, dst, cam, new_cam, band_rows)
    except InputError as exc:
        return str(exc)
    except (cv2.error, OSError, ValueError) as exc:
        return f"{src}: {type(exc).__name__}: {' '.join(str(exc).split())}"
    return None


def output_paths(sources, out_dir) -> list[Path]:
    """``out_dir/<file name>`` for each source (a DNG's as ``.tif``, :func:`~dualcal.files.photos.output_suffix`);
    :class:`InputError` on clashes or overwriting a source."""
    out_dir = make_output_folder(out_dir)
    dests, seen = [], {}
    for src in map(Path, sources):
        dst = out_dir / (src.stem + output_suffix(src))
        if dst.name in seen:
            raise InputError(f"{src} and {seen[dst.name]} would both be written to {dst}: "
                             "rectify them into different folders")
        if dst.exists() and src.exists() and dst.samefile(src):
            raise InputError(f"{dst}: the output would overwrite the original photo; choose another -o")
        seen[dst.name] = src
        dests.append(dst)
    return dests


def readable_photos(sources, cam: CameraModel) -> list[Path]:
    """The sources whose header can be read, each checked to have ``cam``'s size.

    An unreadable file is skipped with a warning naming it; a photo of another size raises
    :class:`InputError` (it was taken by another camera or at another resolution).
    """
    readable = []
    for src in map(Path, sources):
        try:
            size, _ = read_exif(src)
        except InputError as exc:
            warn(f"skipped: {exc}")
            continue
        _check_size(src, size, cam)
        readable.append(src)
    return readable


def rectified_json_path(out_dir, camera_name: str) -> Path:
    """``OUTDIR/NAME.rectified.json``: the pinhole camera of the photos rectified into ``OUTDIR``."""
    return Path(out_dir) / f"{camera_name}.rectified.json"


def rectified_camera_doc(camera_name: str, keep: str, calibration, new_cam: CameraModel) -> dict:
    """The content of ``NAME.rectified.json``: where the camera came from and its intrinsics
    (``fx fy skew cx cy k1 k2``, the lens coefficients 0)."""
    return {"camera": camera_name, "keep": keep, "calibration": str(calibration),
            "image_size": list(new_cam.image_size), **{k: getattr(new_cam, k) for k in intrinsic_names()}}


def check_same_rectified_camera(doc_path, new_cam: CameraModel) -> None:
    """Refuse to add photos to a folder whose ``NAME.rectified.json`` names another camera.

    Photos rectified with another ``--keep`` or another calibration would lie beside the new
    ones while the file describes only the last run. Raises :class:`InputError` then (or when
    the file is not a rectified-camera document); a folder without the file is fine.
    """
    doc_path = Path(doc_path)
    if not doc_path.exists():
        return
    doc = read_json(doc_path)
    try:
        old = CameraModel.from_vector(doc["image_size"], [doc[k] for k in intrinsic_names()])
        same = old.image_size == new_cam.image_size and np.allclose(old.as_vector(), new_cam.as_vector(),
                                                                     rtol=1e-9, atol=1e-12)
    except (KeyError, TypeError, ValueError):
        same = False
    if not same:
        raise InputError(f"{doc_path.parent} already holds photos rectified to another camera "
                         f"({doc_path.name}, keep={doc.get('keep')!r}): rectify into another folder (-o)")


def undistort_files(sources, out_dir, cam: CameraModel, new_cam: CameraModel | None = None,
                    jobs: int | None = None, band_rows: int = DEFAULT_BAND_ROWS,
                    progress: bool = True, camera_of=None) -> list[Path]:
    """Rectify photos of one camera into ``out_dir`` (same file names), in parallel.

    Parameters
    ----------
    sources : photo paths, all taken by ``cam`` at its calibrated size.
    out_dir : output folder; created if its parent exists.
    cam : the calibrated camera.
    new_cam : pinhole camera of the output (default: :func:`rectified_camera` ``(cam, "same")``).
    jobs : worker threads (default: all cores); 1 works in the calling thread.
    band_rows : rows per band (a worker needs about ``64 * band_rows * W`` bytes beyond the
        two images).
    progress : draw a progress bar on stderr.
    camera_of : None, or ``camera_of(path) -> CameraModel``: each photo's own camera (``cam`` at the photo's focus,
        :func:`dualcal.estimation.focus_model.camera_at_focus`), undistorted into the one ``new_cam``.

    Returns
    -------
    Paths of the rectified photos. A photo that cannot be read is skipped with a warning naming it.

    Raises
    ------
    InputError
        A photo of the wrong size, an output folder whose parent is missing, two photos of the
        same name, or an output that would overwrite its source.
    NotInvertibleError
        The camera's distortion folds over inside the image (checked by :func:`rectified_camera`).
    """
    new_cam = new_cam if new_cam is not None else rectified_camera(cam, "same")
    sources = readable_photos(sources, cam)
    created = not Path(out_dir).exists()
    dests = output_paths(sources, out_dir)
    try:
        written = _undistort_all(sources, dests, camera_of or (lambda _: cam), new_cam, jobs, band_rows, progress)
    finally:
        if created and not any(Path(out_dir).iterdir()):     # nothing came of it: no new empty folder
            Path(out_dir).rmdir()
    return written


def _undistort_all(sources, dests, camera_of, new_cam, jobs, band_rows, progress) -> list[Path]:
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(dests)))
    tasks = [(s, d, camera_of(s), new_cam, band_rows) for s, d in zip(sources, dests, strict=True)]
    written = []
    with progress_bar("undistorting photos", len(tasks), enabled=progress) as advance:
        # threads (dualcal.parallel): decoding, remapping and encoding release the GIL, and a
        # Ctrl-C stops every worker at its next band
        for task, problem in zip(tasks, interruptible_map(_undistort_task, tasks, jobs), strict=True):
            if problem is None:
                written.append(task[1])
            else:
                warn(f"skipped: {problem}")
            advance()
    return written
