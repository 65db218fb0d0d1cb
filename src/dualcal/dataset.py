"""Finding the cameras and photos of a dataset and pairing photos of the same instant.

A dataset (CONTRACT.md, "Input") is either

* a folder with one subfolder of photos per camera (``DATASET/wide/*.jpg``, ``DATASET/tele/*.jpg``;
  any names), or a folder that holds only photos: one camera named after the folder; or
* cameras given one by one as ``NAME=GLOB`` (``left=data/left*.jpg``).

Photos of the same instant share a *view key*: the file stem, or for a glob the part(s) that
its wildcards matched (``left*.jpg`` and ``right*.jpg`` pair ``left01`` with ``right01`` as
``01``), or, with ``pair_by="time"``, the reference camera's stem of the photo taken within
``time_tolerance_s`` of it (EXIF capture time).

Pixels are used as stored: the EXIF orientation tag is reported in the metadata, never applied.
Only headers are read here; decoding is :func:`read_gray`'s job.
"""

from __future__ import annotations

import glob as globmod
import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from .errors import InputError
from .model import choose_reference
from .progress import warn

try:  # HEIC/HEIF through pillow-heif
    from pillow_heif import register_heif_opener

    register_heif_opener()
except ImportError:  # pragma: no cover - pillow-heif is a dependency; HEIC is then unreadable
    pass

__all__ = ["PHOTO_SUFFIXES", "Dataset", "Photo", "open_dataset", "parse_camera_spec", "read_gray",
           "read_exif"]

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".heic", ".heif")

# EXIF tags (TIFF/EXIF 2.3)
_ORIENTATION, _MAKE, _MODEL, _EXIF_IFD = 0x0112, 0x010F, 0x0110, 0x8769
_DATETIME, _DATETIME_ORIGINAL, _SUBSEC_ORIGINAL = 0x0132, 0x9003, 0x9291
_FOCAL_LENGTH, _FOCAL_35MM = 0x920A, 0xA405


@dataclass
class Photo:
    """One photo file: its path, stored pixel size ``(W, H)`` and EXIF facts (see :func:`read_exif`)."""

    path: Path
    size: tuple[int, int]
    exif: dict


@dataclass
class Dataset:
    """Cameras and their photos, keyed by view: ``cameras[name][view] -> Photo``.

    ``skipped`` lists ``(path, reason)`` of files that looked like photos but could not be read.
    """

    cameras: dict[str, dict[str, Photo]]
    reference: str
    source: str
    skipped: list[tuple[Path, str]] = field(default_factory=list)

    def image_size(self, camera: str) -> tuple[int, int]:
        return next(iter(self.cameras[camera].values())).size

    def meta(self, camera: str) -> dict:
        """corners.json ``meta`` of a camera: photo paths, EXIF make/model/focal, orientation."""
        photos = self.cameras[camera]
        first = next(iter(photos.values())).exif
        exif = {k: first[k] for k in ("make", "model", "focal_length_mm", "focal_length_35mm_mm")
                if first.get(k) is not None}
        orientation = {v: p.exif.get("orientation") for v, p in photos.items()
                       if p.exif.get("orientation") not in (None, 1)}
        meta = {"photos": {v: str(p.path) for v, p in photos.items()}, "exif": exif}
        if orientation:
            # Reported, never applied: coordinates are in the stored pixel frame.
            meta["exif_orientation"] = orientation
        return meta

    def photo_count(self) -> int:
        return sum(len(v) for v in self.cameras.values())


# ---------------------------------------------------------------------------- reading

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
    make, model = exif.get(_MAKE), exif.get(_MODEL)
    f35 = sub.get(_FOCAL_35MM)
    return {
        "make": make.strip("\x00 ") if isinstance(make, str) else None,
        "model": model.strip("\x00 ") if isinstance(model, str) else None,
        "focal_length_mm": _rational(sub.get(_FOCAL_LENGTH)),
        "focal_length_35mm_mm": _rational(f35) if f35 else None,
        "orientation": int(exif[_ORIENTATION]) if _ORIENTATION in exif else None,
        "taken": taken,
    }


def read_exif(path) -> tuple[tuple[int, int], dict]:
    """Stored pixel size ``(W, H)`` and EXIF facts of a photo, from its header only.

    The facts are ``make``, ``model``, ``focal_length_mm``, ``focal_length_35mm_mm``,
    ``orientation`` (the EXIF tag, 1-8, or None; never applied) and ``taken`` (capture time,
    a ``datetime`` or None). Raises :class:`InputError` for a file that is not a readable image.
    """
    try:
        with Image.open(path) as img:
            return (int(img.width), int(img.height)), _exif_from_image(img)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise InputError(f"{path}: not a readable image ({exc})") from None


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
    pillow-heif. A truncated or corrupt file raises :class:`InputError`.
    """
    path = Path(path)
    if path.suffix.lower() in (".heic", ".heif"):
        try:
            with Image.open(path) as img:
                return np.asarray(img.convert("L"))
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
            raise InputError(f"{path}: cannot be decoded ({exc})") from None
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    if path.suffix.lower() in (".jpg", ".jpeg") and not _jpeg_complete(data):
        raise InputError(f"{path}: truncated or corrupt JPEG (no end-of-image marker after its last scan)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise InputError(f"{path}: cannot be decoded as an image")
    return img


# ---------------------------------------------------------------------------- finding photos

def _is_photo(p: Path) -> bool:
    return p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES and not p.name.startswith(".")


def parse_camera_spec(spec: str) -> tuple[str, str]:
    """``"left=data/left*.jpg"`` -> ``("left", "data/left*.jpg")``."""
    name, sep, pattern = str(spec).partition("=")
    name = name.strip()
    if not sep or not name or not pattern.strip():
        raise InputError(f"--camera {spec!r} is malformed: give NAME=GLOB, e.g. --camera left='data/left*.jpg'")
    return name, pattern.strip()


def _glob_regex(pattern: str) -> re.Pattern:
    """A regex matching what ``glob`` matches for ``pattern``, with one group per wildcard."""
    out, i = [], 0
    while i < len(pattern):
        ch = pattern[i]
        j = pattern.find("]", i + 2) if ch == "[" else -1
        if ch == "*":
            out.append("(.*)")
        elif ch == "?":
            out.append("(.)")
        elif j > 0:
            out.append("(" + pattern[i:j + 1].replace("[!", "[^", 1) + ")")
            i = j
        else:
            out.append(re.escape(ch))
        i += 1
    return re.compile("".join(out) + r"\Z", re.DOTALL)


def _glob_keys(name: str, pattern: str, paths: list[Path]) -> dict[str, Path]:
    """View key of each file matched by ``pattern``: the text its wildcards matched.

    ``left*.jpg`` keys ``left01.jpg`` as ``01``; several wildcards are joined with ``_``; a
    wildcard that ran over the suffix (``left*``) does not keep it; a pattern without
    wildcards keys its file by stem.
    """
    regex = _glob_regex(pattern)
    keys: dict[str, Path] = {}
    for p in paths:
        m = regex.match(str(p))
        key = "_".join(g for g in (m.groups() if m else ()) if g) or p.stem
        if p.suffix and key.endswith(p.suffix):
            key = key[: -len(p.suffix)] or p.stem
        if key in keys:
            raise InputError(f"--camera {name}={pattern}: {keys[key]} and {p} get the same view key "
                             f"{key!r}; make the wildcard cover the part that tells photos apart")
        keys[key] = p
    return keys


def _camera_folders(root: Path) -> dict[str, list[Path]]:
    if not root.exists():
        raise InputError(f"dataset folder {str(root)!r} does not exist")
    if not root.is_dir():
        raise InputError(f"{str(root)!r} is not a folder: give a dataset folder, or cameras with --camera NAME=GLOB")
    subdirs = sorted(d for d in root.iterdir() if d.is_dir() and not d.name.startswith("."))
    cams = {d.name: sorted(p for p in d.iterdir() if _is_photo(p)) for d in subdirs}
    cams = {n: ps for n, ps in cams.items() if ps}
    if cams:
        return cams
    photos = sorted(p for p in root.iterdir() if _is_photo(p))
    if not photos:
        raise InputError(f"dataset folder {str(root)!r} holds no photos "
                         f"({', '.join(PHOTO_SUFFIXES)}) nor camera subfolders with photos")
    return {root.resolve().name: photos}


def _read_headers(name: str, files: dict[str, Path], skipped: list) -> dict[str, Photo]:
    photos = {}
    for key, path in sorted(files.items()):
        try:
            size, exif = read_exif(path)
        except InputError as exc:
            warn(f"skipping {path}: {str(exc).split(': ', 1)[-1]}")
            skipped.append((path, str(exc)))
            continue
        photos[key] = Photo(path, size, exif)
    sizes = {p.size for p in photos.values()}
    if len(sizes) > 1:
        listing = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
        raise InputError(f"camera {name!r}: photos differ in size ({listing}); a camera's photos must all "
                         "have one size (put each camera's photos in its own folder or glob)")
    return photos


def _pair_by_time(cams: dict[str, dict[str, Photo]], reference: str, tolerance_s: float):
    """Re-key every camera's photos with the reference camera's key of the same instant."""
    def stamp(photo: Photo, cam: str):
        if photo.exif.get("taken") is None:
            raise InputError(f"--pair-by time: {photo.path} (camera {cam!r}) has no EXIF capture time; "
                             "pair by file name instead (--pair-by stem)")
        return photo.exif["taken"]

    ref_times = {k: stamp(p, reference) for k, p in cams[reference].items()}
    out = {reference: cams[reference]}
    for name, photos in cams.items():
        if name == reference:
            continue
        # greedy one-to-one matching, closest pairs first
        cand = sorted((abs((stamp(p, name) - t).total_seconds()), k, rk)
                      for k, p in photos.items() for rk, t in ref_times.items())
        used_k, used_rk, keyed = set(), set(), {}
        for dt, k, rk in cand:
            if dt <= tolerance_s and k not in used_k and rk not in used_rk:
                used_k.add(k)
                used_rk.add(rk)
                keyed[rk] = photos[k]
        for k, p in photos.items():
            if k not in used_k:
                warn(f"{p.path}: no photo of camera {reference!r} within {tolerance_s:g} s; "
                     "used for this camera alone")
                keyed[f"{name}:{k}"] = p
        out[name] = dict(sorted(keyed.items()))
    return out


def open_dataset(path=None, cameras=(), pair_by: str = "stem", reference: str | None = None,
                 time_tolerance_s: float = 2.0) -> Dataset:
    """Find the cameras and photos of a dataset and key them by view.

    Parameters
    ----------
    path : dataset folder (see the module docstring), or None when ``cameras`` are given.
    cameras : ``NAME=GLOB`` strings or ``(name, glob)`` pairs; they take precedence over ``path``
        (a relative glob is taken relative to ``path`` when given, else to the working folder).
    pair_by : ``"stem"`` (file stem, or the glob's wildcard text) or ``"time"`` (EXIF capture time).
    reference : the reference camera (default: ``wide`` if present, else the first sorted name);
        with ``pair_by="time"`` its stems are the view keys.
    time_tolerance_s : largest capture-time difference of two photos of the same instant.

    Raises
    ------
    InputError
        Missing or empty folder, a glob matching no photo, an unknown reference camera, a camera
        whose photos differ in size, no readable photo.
    """
    if pair_by not in ("stem", "time"):
        raise InputError(f"--pair-by {pair_by!r}: choose stem or time")
    specs = [parse_camera_spec(c) if isinstance(c, str) else tuple(c) for c in cameras]
    files: dict[str, dict[str, Path]] = {}
    if specs:
        base = Path(path) if path is not None else None
        if base is not None and not base.is_dir():
            raise InputError(f"dataset folder {str(base)!r} does not exist")
        for name, pattern in specs:
            if name in files:
                raise InputError(f"--camera {name!r} is given twice")
            full = pattern if base is None or Path(pattern).is_absolute() else str(base / pattern)
            matched = sorted(Path(p) for p in globmod.glob(full) if _is_photo(Path(p)))
            if not matched:
                raise InputError(f"--camera {name}={pattern}: matches no photo")
            files[name] = _glob_keys(name, full, matched) if pair_by == "stem" else {p.stem: p for p in matched}
        source = str(path) if path is not None else ", ".join(f"{n}={g}" for n, g in specs)
    else:
        if path is None:
            raise InputError("give a dataset folder or cameras with --camera NAME=GLOB")
        files = {n: {p.stem: p for p in ps} for n, ps in _camera_folders(Path(path)).items()}
        source = str(path)

    skipped: list = []
    cams = {n: _read_headers(n, f, skipped) for n, f in sorted(files.items())}
    empty = [n for n, ps in cams.items() if not ps]
    if empty:
        raise InputError(f"camera {empty[0]!r} has no readable photo")
    ref = choose_reference(cams, reference)
    if pair_by == "time":
        cams = _pair_by_time(cams, ref, time_tolerance_s)
    return Dataset(cams, ref, source, skipped)
