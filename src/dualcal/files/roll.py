"""A phone's camera roll: one folder of photos of several lenses, split into cameras and instants.

A phone's stock camera app saves one lens per shot, so a phone's rear cameras are calibrated from a
tripod: at each board position every lens shoots in turn, a few seconds apart, then the board is
moved (CONTRACT.md, "A phone's camera roll"). What the user then has is one folder, every lens
mixed, in shooting order. This module turns it into a dataset:

* **cameras** (:func:`split_cameras`): photos are grouped by the lens their EXIF names
  (``LensModel``; where it is missing, the focal length in mm), and by image size (a lens shooting
  at two resolutions is two cameras, as its focal length in pixels differs). A camera is named by
  its 35 mm-equivalent focal length (:func:`camera_class`): ``ultra`` below 20 mm, ``wide`` 20-35 mm,
  ``tele`` above; a second of a class is ``wide2``, ``tele2``, ... in order of focal length. The
  equivalent focal length is EXIF ``FocalLengthIn35mmFilm``, else derived from the focal length in
  mm and the sensor's size (``FocalPlaneXResolution``); where neither is known the cameras are named
  by rank of focal length, with a warning.
* **instants** (:func:`split_instants`): photos are ordered by capture time; the gaps between the
  lenses of one position are much shorter than the gaps between positions (the board is moved), so
  the gaps fall in two groups, and the split is the widest break between them on a log scale
  (:func:`instant_gap`). It is found from the data, or given (``instant_gap_s``).
* **retakes**: two photos of one camera in one instant; the later is kept (a retake is taken because
  the first was not right), and the other is left out, saying so.

Every decision is kept in :attr:`CameraRoll.record`, corners.json's top-level ``roll``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np

from ..geometry.camera import equivalent_focal_35mm
from ..errors import InputError
from .photos import Photo

__all__ = ["CameraRoll", "camera_class", "equivalent_focal_mm", "instant_gap", "is_camera_roll", "open_camera_roll",
           "split_cameras", "split_instants", "with_detection"]

#: The smallest ratio between the gaps of two board positions and of two lenses of one position that
#: counts as a break between them (below it the capture times do not tell the positions apart).
MIN_GAP_RATIO = 2.5


@dataclass
class CameraRoll:
    """A camera roll split into ``cameras[name][view key] -> Photo`` and the record of every decision."""

    cameras: dict[str, dict[str, Photo]]
    record: dict = field(default_factory=dict)


def lens_key(photo: Photo) -> tuple:
    """What tells a roll's cameras apart: the device, its lens (``LensModel``, else the focal length in
    mm and the 35 mm equivalent) and the image size."""
    e = photo.exif
    lens = e.get("lens_model") or (e.get("focal_length_mm"), e.get("focal_length_35mm_mm"))
    return e.get("make"), e.get("model"), lens, tuple(photo.size)


def equivalent_focal_mm(photo: Photo) -> float | None:
    """The 35 mm-equivalent focal length of a photo: EXIF ``FocalLengthIn35mmFilm``, else the focal
    length in mm scaled by the ratio of the full-frame diagonal to the sensor's (from the focal plane
    resolution), else None."""
    e = photo.exif
    if e.get("focal_length_35mm_mm"):
        return float(e["focal_length_35mm_mm"])
    f_mm, px_per_mm = e.get("focal_length_mm"), e.get("focal_plane_px_per_mm")
    if f_mm and px_per_mm:
        return equivalent_focal_35mm(photo.size, float(f_mm) * px_per_mm)      # the focal length in pixels
    return None


def camera_class(f35_mm: float) -> str:
    """``ultra`` (below 20 mm equivalent), ``wide`` (20-35 mm) or ``tele`` (above 35 mm)."""
    return "ultra" if f35_mm < 20.0 else "wide" if f35_mm <= 35.0 else "tele"


def is_camera_roll(photos: list[Photo]) -> bool:
    """True when the photos of one folder come from more than one camera (:func:`lens_key`)."""
    return len({lens_key(p) for p in photos}) > 1


def split_cameras(photos: list[Photo]) -> tuple[dict[str, list[Photo]], dict[str, dict], list[str]]:
    """The photos of a roll by camera name (module docstring), each camera's facts, and warnings."""
    groups: dict[tuple, list[Photo]] = {}
    for p in photos:
        groups.setdefault(lens_key(p), []).append(p)
    warnings = []
    f35 = {}
    for key, members in groups.items():
        values = [v for v in (equivalent_focal_mm(p) for p in members) if v]
        f35[key] = float(np.median(values)) if values else None
    known = all(v is not None for v in f35.values())
    if known:
        order = sorted(groups, key=lambda k: f35[k])
        classes = [camera_class(f35[k]) for k in order]
    else:
        def focal(k):
            mm = [p.exif.get("focal_length_mm") for p in groups[k] if p.exif.get("focal_length_mm")]
            return float(np.median(mm)) if mm else math.inf
        order = sorted(groups, key=focal)
        classes = (["ultra", "wide", "tele"] if len(order) >= 3 else ["wide", "tele"])[:len(order)]
        classes += ["tele"] * (len(order) - len(classes))
        warnings.append("the photos' EXIF gives no 35 mm-equivalent focal length, so their cameras are named by "
                        f"rank of focal length ({', '.join(classes)}); check them in the table")
    names, seen = {}, {}
    for key, cls in zip(order, classes):
        seen[cls] = seen.get(cls, 0) + 1
        names[key] = cls if seen[cls] == 1 else f"{cls}{seen[cls]}"
    cameras = {names[k]: sorted(groups[k], key=_time) for k in order}
    facts = {}
    for k in order:
        first = groups[k][0].exif
        facts[names[k]] = {"lens_model": first.get("lens_model"), "focal_length_mm": first.get("focal_length_mm"),
                           "focal_length_35mm_mm": f35[k], "image_size": list(groups[k][0].size),
                           "make": first.get("make"), "model": first.get("model"), "photos": len(groups[k])}
    return cameras, facts, warnings


def _time(photo: Photo) -> datetime:
    return photo.exif["taken"]


def instant_gap(gaps_s: np.ndarray) -> float | None:
    """The capture-time gap that splits board positions (module docstring), or None where the gaps
    show no break of at least :data:`MIN_GAP_RATIO` between two groups.

    The sorted gaps are split where the ratio of one to the next is largest (the largest step of
    their logarithms); the threshold is the geometric mean of the two gaps at the step. Gaps under
    0.1 s count as 0.1 s (a burst), so that a near-zero gap does not make a false break.
    """
    g = np.sort(np.maximum(np.asarray(gaps_s, float), 0.1))
    if len(g) < 2:
        return None
    ratios = g[1:] / g[:-1]
    i = int(np.argmax(ratios))
    if ratios[i] < MIN_GAP_RATIO:
        return None
    return float(np.sqrt(g[i] * g[i + 1]))


def split_instants(cameras: dict[str, list[Photo]], gap_s: float | None = None):
    """Group a roll's photos into instants by capture time.

    Returns ``(instants, gap_s, found)``: each instant a list of ``(camera, photo)`` in shooting order,
    the gap used, and whether it was found from the data (False: given).

    Raises
    ------
    InputError
        The capture times show no break between board positions and no gap is given.
    """
    shots = sorted(((p.exif["taken"], name, p) for name, photos in cameras.items() for p in photos),
                   key=lambda s: (s[0], str(s[2].path)))
    times = np.array([(t - shots[0][0]).total_seconds() for t, _, _ in shots])
    gaps = np.diff(times)
    found = gap_s is None
    if found:
        gap_s = instant_gap(gaps)
        if gap_s is None:
            if len(shots) <= len(cameras):       # one position only: every photo is one instant
                gap_s = math.inf
            else:
                spread = f"{gaps.min():.1f}-{gaps.max():.1f} s" if len(gaps) else "none"
                raise InputError(f"the capture times of the camera roll show no break between board positions "
                                 f"(gaps {spread}): give the largest gap between the lenses of one position "
                                 "(instant gap, in seconds)")
    instants, current = [], [shots[0][1:]]
    for gap, shot in zip(gaps, shots[1:]):
        if gap > gap_s:
            instants.append(current)
            current = []
        current.append(shot[1:])
    instants.append(current)
    return instants, float(gap_s), found


def open_camera_roll(photos: list[Photo], folder: str, instant_gap_s: float | None = None):
    """Split the photos of a camera-roll folder into cameras and instants (module docstring).

    Returns ``(roll, warnings)``: a :class:`CameraRoll` keyed by view (the stem of an instant's first
    photo) and the warnings to give (retakes, photos without a capture time, names by rank).

    Raises
    ------
    InputError
        No photo has a capture time, or the times show no break between positions (see
        :func:`split_instants`).
    """
    timed = [p for p in photos if p.exif.get("taken") is not None]
    untimed = [p for p in photos if p.exif.get("taken") is None]
    if not timed:
        sizes = sorted({p.size for p in photos})
        what = (f"its photos differ in size ({', '.join(f'{w}x{h}' for w, h in sizes)})" if len(sizes) > 1
                else "its photos come from several lenses")
        raise InputError(f"{folder}: {what} but have no EXIF capture time, so they cannot be grouped into board "
                         "positions as a camera roll: put each camera's photos in its own subfolder")
    left_out = {p.path.name: "no EXIF capture time, so its board position is unknown" for p in untimed}
    by_camera, facts, warnings = split_cameras(timed)
    instants, gap_s, found = split_instants(by_camera, instant_gap_s)
    cameras: dict[str, dict[str, Photo]] = {name: {} for name in by_camera}
    record_instants = {}
    for shots in instants:
        key = shots[0][1].path.stem
        chosen: dict[str, Photo] = {}
        for name, photo in shots:        # in shooting order: a retake replaces the earlier photo
            if name in chosen:
                left_out[chosen[name].path.name] = f"retake: {photo.path.name} of the same camera ({name}) at the " \
                                                   "same board position is kept (the later)"
            chosen[name] = photo
        for name, photo in chosen.items():
            cameras[name][key] = photo
        record_instants[key] = {"taken": shots[0][1].exif["taken"].isoformat(),
                                "photos": {name: photo.path.name for name, photo in chosen.items()}}
    for name, reason in left_out.items():
        warnings.append(f"{name}: left out ({reason})")
    record = {"folder": folder, "instant_gap_s": gap_s if math.isfinite(gap_s) else None,
              "instant_gap_found": found, "cameras": facts, "instants": record_instants, "left_out": left_out}
    return CameraRoll({n: v for n, v in cameras.items() if v}, record), warnings


def with_detection(record: dict, corners) -> dict:
    """The roll's record with the photos in which detection found no board added to ``left_out``
    (``corners`` is the :class:`~dualcal.geometry.model.CornerSet` detected from the roll)."""
    left_out = dict(record.get("left_out", {}))
    for key, instant in record.get("instants", {}).items():
        for name, file_name in instant["photos"].items():
            cam = corners.cameras.get(name)
            if cam is not None and key in cam.views and cam.views[key] is None:
                left_out[file_name] = f"no board found ({name}, instant {key})"
    return {**record, "left_out": left_out}
