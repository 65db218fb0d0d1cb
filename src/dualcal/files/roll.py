"""A phone's camera roll: one folder of photos of several lenses, split into cameras and instants.

A phone's stock camera app saves one lens per shot, so a phone's rear cameras are calibrated from a
tripod: at each board position every lens shoots in turn, a few seconds apart, then the board is
moved (CONTRACT.md, "A phone's camera roll"). What the user then has is one folder, every lens
mixed, in shooting order. This module turns it into a dataset, in two steps: the cameras from the
photos' headers (before detection, so that a command that needs only the cameras, such as choosing
a board, never waits for the rest), then, once the boards are detected, the instants.

* **cameras by EXIF** (:func:`split_cameras`): photos are grouped by the lens their EXIF names
  (``LensModel``, the focal length in mm and its 35 mm equivalent: an iPhone's "2x" is its main lens
  cropped, with another equivalent focal length), and by image size (a lens shooting at two resolutions
  is two cameras, as its focal length in pixels differs). A camera is named by its 35 mm-equivalent
  focal length (:func:`camera_class`): ``ultra`` below 20 mm, ``wide`` 20-35 mm, ``tele`` above; a
  second of a class is ``wide2``, ``tele2``, ... in order of focal length. The equivalent focal length
  is EXIF ``FocalLengthIn35mmFilm``, else derived from the focal length in mm and the sensor's size
  (``FocalPlaneXResolution``); where neither is known the cameras are named by rank of focal length,
  with a warning.
* **a photo stored turned** (:func:`turned_photos`): a photo of the same lens whose size is the other
  photos' transposed (1536 x 2048 among 2048 x 1536) is left out with a warning, not taken for a camera.
* **cameras by what the photos show** (:func:`cameras_from_boards`), where the photos carry no EXIF (a
  phone's browser strips it on upload): by image size, then by the focal length each photo's board gives
  alone (:mod:`dualcal.geometry.one_view`), grouped around the values many photos share. A board seen nearly
  square-on gives a focal length that fits more than one camera; two more clues decide then, over the roll
  in shooting order at once (the most likely labelling of a chain): successive photos of one position by two
  lenses look alike but for the ratio of their focal lengths (:func:`looks_alike`), and each lens bends the
  board as it does (its division model, fitted to the photos told so far: an ultra-wide's board near the
  image's edge fits no other lens). A photo still unclear is left out, saying so. Named by the same rule,
  from the focal length found.
* **instants** (:func:`split_roll`): the photos in shooting order (capture time, else file name) are
  split into board positions by every clue the roll gives: the board's image and pose, the capture
  times, the lens order (:mod:`dualcal.files.roll_positions`), each decision with its margin (log-odds);
  a split is refused only where the clues disagree. A **retake** (two photos of one camera at one
  position) keeps the later (a retake is taken because the first was not right); a photo without the
  board is left out, saying so.

Every decision is kept in :attr:`CameraRoll.record`, corners.json's top-level ``roll``: which clues told
the cameras (``clues.cameras``: ``EXIF lens``, ``image size``, ``focal length from the board``) and the
instants (``clues.instants``: ``capture time``, ``order``, ``board image``, ``board pose``, ``lens
order``), each camera's facts, each instant's photos and margin, what was left out and why.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry.camera import equivalent_focal_35mm, focal_px_from_35mm
from ..geometry.model import observed_mask
from ..geometry.one_view import OneView, board_pixels, common_division, division_misfits, one_view, spread_px
from .photos import Photo
from .roll_positions import CERTAIN, MIN_MARGIN, SAME_IMAGE, Shot, image_change, split_positions

__all__ = ["CameraRoll", "camera_class", "cameras_from_boards", "equivalent_focal_mm", "has_lens_exif",
           "is_camera_roll", "looks_alike", "shooting_order", "split_cameras", "split_roll", "turned_photos"]

#: The spread of one lens's focal lengths from single views beyond their measured noise: the principal
#: point off the centre and the division model's misfit of the real lens (natural log).
FOCAL_MODEL_SIGMA = 0.08
#: What the model leaves out grows as the board faces the camera: a board tilted by ``t`` adds this over
#: ``tan(t)`` to the spread of its log focal length (a board 5 degrees from square-on: 0.34).
TILT_SIGMA = 0.03
#: Two groups of focal lengths closer than this ratio are one camera (a phone's lenses differ by 1.5 or more).
SAME_FOCAL_RATIO = 1.3
#: A photo takes a camera where the odds for it are at least this (99:1).
SURE_ODDS = 99.0
#: Two photos of one position by two lenses look alike (:func:`looks_alike`): the board's shapes agree within
#: this share of its size, and its shift (the small rotation between the lenses, their parallax) within this
#: angle (radians; 6 degrees).
ALIKE_SHAPE, ALIKE_SHIFT_RAD = 0.08, 0.1
#: The log-odds two successive photos that look alike give their labels (one position).
ALIKE_LOG_ODDS = 6.0


@dataclass
class CameraRoll:
    """A camera roll split into ``cameras[name][view key] -> Photo`` and the record of every decision."""

    cameras: dict[str, dict[str, Photo]]
    record: dict = field(default_factory=dict)


def has_lens_exif(photo: Photo) -> bool:
    """Whether a photo's EXIF says which lens took it (``LensModel`` or a focal length)."""
    e = photo.exif
    return any(e.get(k) for k in ("lens_model", "focal_length_mm", "focal_length_35mm_mm"))


def lens_key(photo: Photo) -> tuple:
    """What tells a roll's cameras apart by EXIF, but for the image size: the device and its lens
    (``LensModel``, the focal length in mm and its 35 mm equivalent)."""
    e = photo.exif
    return e.get("make"), e.get("model"), e.get("lens_model"), e.get("focal_length_mm"), e.get("focal_length_35mm_mm")


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


def _natural_key(name: str) -> list:
    """``IMG_9.JPG`` before ``IMG_10.JPG``: the digits of a name compared as numbers."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def shooting_order(photos: list[Photo]) -> tuple[list[Photo], bool]:
    """The photos in shooting order, and whether that order is by capture time: by EXIF capture time (then
    name) where every photo has one, else by file name (numbers in it compared as numbers)."""
    timed = bool(photos) and all(p.exif.get("taken") is not None for p in photos)
    if timed:
        return sorted(photos, key=lambda p: (p.exif["taken"], _natural_key(p.path.name))), True
    return sorted(photos, key=lambda p: _natural_key(p.path.name)), False


def turned_photos(photos: list[Photo], where: str = "") -> tuple[list[Photo], dict]:
    """The photos less those stored turned, and ``{path: why}`` of those.

    Of the photos of one lens (:func:`lens_key`; photos without EXIF are one group), those whose size is
    the transpose of a size more of them have are turned (their pixels are the camera's turned by 90
    degrees: another camera to the adjustment).

    Raises
    ------
    InputError
        As many photos of one lens have a size as its transpose: which are turned is unknown (``where``
        names the folder).
    """
    groups: dict[tuple, list[Photo]] = {}
    for p in photos:
        groups.setdefault(lens_key(p), []).append(p)
    turned = {}
    for members in groups.values():
        count: dict[tuple[int, int], int] = {}
        for p in members:
            count[tuple(p.size)] = count.get(tuple(p.size), 0) + 1
        for p in members:
            w, h = p.size
            if w != h and count.get((h, w), 0) > count[(w, h)]:
                turned[p.path] = (f"stored turned: {w}x{h}, where {count[(h, w)]} other photo(s) of the same camera "
                                  f"are {h}x{w}")
            elif w != h and count.get((h, w), 0) == count[(w, h)]:
                raise InputError(f"{where or p.path.parent}: photos of one camera differ in size, {count[(w, h)]} "
                                 f"{w}x{h} and as many {h}x{w}: one of the two sizes is stored turned; leave those "
                                 "out, or put each camera's photos in its own folder")
    return [p for p in photos if p.path not in turned], turned


def is_camera_roll(photos: list[Photo]) -> bool:
    """True when the photos of one folder come from more than one camera by their EXIF (lens and size)."""
    return len({(lens_key(p), tuple(p.size)) for p in photos}) > 1


def _names(f35: dict, known: bool) -> tuple[dict, list[str]]:
    """Camera names by 35 mm-equivalent focal length (module docstring) for keys with ``f35[key]`` (or, where
    not ``known``, in the order of the keys, by rank), and the warnings to give."""
    if known:
        order = sorted(f35, key=lambda k: f35[k])
        classes = [camera_class(f35[k]) for k in order]
        warnings = []
    else:
        order = list(f35)
        classes = (["ultra", "wide", "tele"] if len(order) >= 3 else ["wide", "tele"])[:len(order)]
        classes += ["tele"] * (len(order) - len(classes))
        warnings = ["the photos' EXIF gives no 35 mm-equivalent focal length, so their cameras are named by "
                    f"rank of focal length ({', '.join(classes)}); check them in the table"]
    names, seen = {}, {}
    for key, cls in zip(order, classes):
        seen[cls] = seen.get(cls, 0) + 1
        names[key] = cls if seen[cls] == 1 else f"{cls}{seen[cls]}"
    return names, warnings


def split_cameras(photos: list[Photo]) -> tuple[dict[str, list[Photo]], dict[str, dict], list[str]]:
    """The photos of a roll by camera name from their EXIF (module docstring), each camera's facts, and warnings."""
    groups: dict[tuple, list[Photo]] = {}
    for p in photos:
        groups.setdefault((lens_key(p), tuple(p.size)), []).append(p)
    f35 = {}
    for key, members in groups.items():
        values = [v for v in (equivalent_focal_mm(p) for p in members) if v]
        f35[key] = float(np.median(values)) if values else None
    known = all(v is not None for v in f35.values())
    if not known:
        def focal(k):
            mm = [p.exif.get("focal_length_mm") for p in groups[k] if p.exif.get("focal_length_mm")]
            return float(np.median(mm)) if mm else math.inf
        f35 = {k: f35[k] for k in sorted(groups, key=focal)}
    names, warnings = _names(f35, known)
    order = list(names)
    cameras = {names[k]: shooting_order(groups[k])[0] for k in order}
    facts = {}
    for k in order:
        first = groups[k][0].exif
        facts[names[k]] = {"lens_model": first.get("lens_model"), "focal_length_mm": first.get("focal_length_mm"),
                           "focal_length_35mm_mm": f35[k], "image_size": list(groups[k][0].size),
                           "make": first.get("make"), "model": first.get("model"), "photos": len(groups[k]),
                           "told_by": "EXIF lens"}
    return cameras, facts, warnings


# ---------------------------------------------------------------------------- cameras from the boards

def _log_focal_modes(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The log focal lengths that groups of photos share: the modes of the photos' densities (each a normal
    of its spread), those closer than :data:`SAME_FOCAL_RATIO` merged, refined by expectation-maximisation,
    and kept where they hold at least 1.5 photos and a fifth as many as the largest."""
    grid = np.arange(x.min() - 0.5, x.max() + 0.5, 0.01)
    density = np.sum(np.exp(-0.5 * ((grid[:, None] - x) / s) ** 2) / s, axis=1)
    peaks = [i for i in range(1, len(grid) - 1) if density[i] >= density[i - 1] and density[i] > density[i + 1]]
    modes: list[float] = []
    for i in sorted(peaks, key=lambda i: -density[i]):
        if all(abs(grid[i] - m) >= np.log(SAME_FOCAL_RATIO) for m in modes):
            modes.append(float(grid[i]))
    mu = np.array(sorted(modes) or [float(np.median(x))])
    for _ in range(10):
        r = _responsibilities(x, s, mu)
        mass = r.sum(axis=0)
        keep = mass >= max(1.5, 0.2 * mass.max())
        mu, r = mu[keep], r[:, keep]
        mu = np.sum(r * x[:, None] / s[:, None] ** 2, axis=0) / np.sum(r / s[:, None] ** 2, axis=0)
    return mu


def _responsibilities(x: np.ndarray, s: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """(n, m) probability of each photo's log focal length ``x`` (spread ``s``) under each mode ``mu``."""
    z = -0.5 * ((x[:, None] - mu[None, :]) / s[:, None]) ** 2
    z -= z.max(axis=1, keepdims=True)
    p = np.exp(z)
    return p / p.sum(axis=1, keepdims=True)


def _log_focal_spread(view: OneView) -> float:
    """The spread of the log focal length a view gives: its measured spread, :data:`FOCAL_MODEL_SIGMA` and
    :data:`TILT_SIGMA` over the tangent of the board's tilt, together (inf where it gives none)."""
    if not (np.isfinite(view.f_px) and np.isfinite(view.f_log_sigma) and view.tilt_deg > 0):
        return np.inf
    return float(np.sqrt(view.f_log_sigma**2 + FOCAL_MODEL_SIGMA**2 + (TILT_SIGMA / np.tan(np.radians(view.tilt_deg))) ** 2))


def _camera_log_odds(view: OneView, modes: np.ndarray) -> np.ndarray:
    """(m,) the log-probability that a photo is of each camera (``modes``: their log focal lengths) by the focal
    length its board gives (equal where it gives none)."""
    spread = _log_focal_spread(view)
    if not np.isfinite(spread):
        return np.full(len(modes), -np.log(len(modes)))
    return np.log(np.maximum(_responsibilities(np.array([np.log(view.f_px)]), np.array([spread]), modes)[0], 1e-300))


def looks_alike(a: OneView, b: OneView, ratio: float, f_px: float, xy_board: np.ndarray,
                symmetric: bool = False) -> bool:
    """Whether photo ``b``'s board, scaled about the image centre by ``ratio`` (``a``'s camera's focal length,
    ``f_px``, to ``b``'s), is ``a``'s: two lenses of a phone at one board position (their axes nearly parallel,
    their centres a few mm apart) see the board alike but for the scale, and for a shift by the small rotation
    between them and their parallax. The shapes must agree within :data:`ALIKE_SHAPE` of the board's size in
    ``a``, the shift within :data:`ALIKE_SHIFT_RAD` of ``f_px``."""
    pa = board_pixels(a, xy_board)
    centre = (np.asarray(a.image_size, float) - 1.0) / 2.0
    pb = centre + ratio * (board_pixels(b, xy_board) - centre)
    size = spread_px(pa)
    for other in ([pb, pb[::-1]] if symmetric else [pb]):
        shift = pa.mean(axis=0) - other.mean(axis=0)
        shape = np.sqrt(np.mean(np.sum((pa - other - shift) ** 2, axis=1)))
        if shape <= ALIKE_SHAPE * size and np.linalg.norm(shift) <= ALIKE_SHIFT_RAD * f_px:
            return True
    return False


def _chain_labels(views: list[OneView], unary: np.ndarray, modes: np.ndarray, xy_board: np.ndarray,
                  symmetric: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The camera of each photo of one size (in shooting order) that explains best both what each photo says
    alone (``unary`` (n, m): log-likelihoods of the cameras, whose log focal lengths are ``modes``) and how
    successive photos look alike (:func:`looks_alike`: one position, two cameras; or a retake): the most likely
    labelling of a chain (Viterbi), with each photo's margin (the log-odds of its label against the next best,
    from the max-marginals)."""
    n, m = len(views), len(modes)
    pair = np.zeros((max(n - 1, 0), m, m))                                       # (i-1, i) bonus
    for i in range(1, n):
        for a in range(m):
            for b in range(m):
                if a == b:
                    alike = image_change(views[i], views[i - 1], xy_board, symmetric) <= SAME_IMAGE
                else:
                    alike = looks_alike(views[i], views[i - 1], float(np.exp(modes[a] - modes[b])),
                                        float(np.exp(modes[a])), xy_board, symmetric)
                pair[i - 1, b, a] = ALIKE_LOG_ODDS if alike else 0.0
    forward = np.zeros((n, m))
    forward[0] = unary[0]
    for i in range(1, n):
        forward[i] = unary[i] + np.max(forward[i - 1][:, None] + pair[i - 1], axis=0)
    backward = np.zeros((n, m))
    for i in range(n - 2, -1, -1):
        backward[i] = np.max(pair[i] + (unary[i + 1] + backward[i + 1])[None, :], axis=1)
    marginal = forward + backward
    best = np.sort(marginal, axis=1)
    return np.argmax(marginal, axis=1), best[:, -1] - (best[:, -2] if m > 1 else -np.inf)


def _lens_log_odds(uv: np.ndarray, size, lams: np.ndarray, xy_board: np.ndarray) -> np.ndarray:
    """(m,) the log-likelihood of a photo's corners under each camera's lens (``lams``: their division models),
    from the misfits of its homography with each (chi-square with the corners' noise from the best, at least
    0.05 px; at most 20 against). A board near the image's centre fits every lens alike; one near an
    ultra-wide's edge only its own."""
    seen = observed_mask(uv)
    misfit = division_misfits(xy_board, uv, size, lams)
    variance = max(misfit.min(), 0.05) ** 2 / 2.0                      # per coordinate
    return np.maximum(-seen.sum() * (misfit**2 - misfit.min() ** 2) / (2.0 * variance), -20.0)


def cameras_from_boards(photos: list[Photo], corners_uv: dict, xy_board: np.ndarray, symmetric: bool = False):
    """The cameras of photos without EXIF, from what they show (module docstring).

    Parameters
    ----------
    photos : the roll's photos.
    corners_uv : ``{path: (N, 2) pixels or None}``, each photo's detected corners (NaN rows where not measured).
    xy_board : (N, 2) the board's corners, mm.
    symmetric : the board looks the same turned by 180 degrees (its photos may be numbered either way round).

    Returns
    -------
    ``(cameras, facts, warnings, left_out)``: the photos by camera name, each camera's facts (``told_by``,
    ``focal_length_board_px``, ``focal_length_35mm_mm``, ``image_size``, ``photos``), the warnings to give,
    and ``{file name: reason}`` of the photos no camera could be told for.
    """
    order, _ = shooting_order(photos)
    views = {p.path: None if corners_uv.get(p.path) is None else one_view(xy_board, corners_uv[p.path], p.size)
             for p in photos}
    groups: dict = {}
    left_out = {p.path.name: "no board found, and without EXIF its camera is unknown"
                for p in order if views.get(p.path) is None}
    mu: dict = {}
    for size in sorted({tuple(p.size) for p in photos}):
        shown = [p for p in order if tuple(p.size) == size and views.get(p.path) is not None]
        spread = np.array([_log_focal_spread(views[p.path]) for p in shown])
        sure = np.isfinite(spread)
        if not sure.any():
            for p in shown:
                left_out[p.path.name] = "its board gives no focal length, and without EXIF its camera is unknown"
            continue
        modes = _log_focal_modes(np.log([views[p.path].f_px for p, ok in zip(shown, sure) if ok]), spread[sure])
        chain = [views[p.path] for p in shown]
        unary = np.array([_camera_log_odds(v, modes) for v in chain])
        labels, margins = _chain_labels(chain, unary, modes, xy_board, symmetric)
        if len(modes) > 1:
            # each lens's distortion, from the photos told so far, tells the others: an ultra-wide's board near
            # the image's edge is bent as no other lens bends it
            lams = np.array([common_division(xy_board, [corners_uv[p.path] for p, k, m in zip(shown, labels, margins)
                                                        if k == c and m >= np.log(SURE_ODDS)], size)
                             for c in range(len(modes))])
            unary += np.array([_lens_log_odds(corners_uv[p.path], size, lams, xy_board) for p in shown])
            labels, margins = _chain_labels(chain, unary, modes, xy_board, symmetric)
        for p, k, margin in zip(shown, labels, margins):
            if margin >= np.log(SURE_ODDS):
                groups.setdefault((size, int(k)), []).append(p)
                mu[(size, int(k))] = modes[k]
            else:
                left_out[p.path.name] = ("its camera is unclear: the focal length its board gives fits more than one "
                                         "camera (a board seen nearly square-on), and neither photo beside it tells")
    f35 = {k: equivalent_focal_35mm(k[0], math.exp(mu[k])) for k in groups}
    names, warnings = _names(f35, True)
    cameras = {names[k]: groups[k] for k in names}
    facts = {names[k]: {"told_by": "focal length from the board", "focal_length_board_px": round(math.exp(mu[k]), 1),
                        "focal_length_35mm_mm": round(f35[k], 1), "image_size": list(k[0]), "photos": len(groups[k]),
                        "lens_model": None, "focal_length_mm": None, "make": None, "model": None}
             for k in names}
    return cameras, facts, warnings, left_out


# ---------------------------------------------------------------------------- instants

def _camera_focal_px(photos: list[Photo], facts: dict, views: dict) -> float:
    """A camera's focal length in pixels for the board's poses: EXIF's 35 mm equivalent, else the board's
    (the median of its photos'), else the image's long side."""
    size = tuple(photos[0].size)
    if facts.get("told_by") == "EXIF lens" and facts.get("focal_length_35mm_mm"):
        return focal_px_from_35mm(size, facts["focal_length_35mm_mm"])
    f = [views[p.path].f_px for p in photos if views.get(p.path) is not None and np.isfinite(views[p.path].f_px)]
    return float(np.median(f)) if f else float(max(size))


def _camera_views(cameras: dict[str, list[Photo]], corners_uv: dict, xy_board: np.ndarray) -> dict:
    """``{path: OneView or None}`` of every photo, with its camera's division model (fitted to all its photos
    together, :func:`dualcal.geometry.one_view.common_division`)."""
    views = {}
    for photos in cameras.values():
        shown = [p for p in photos if corners_uv.get(p.path) is not None]
        lam = common_division(xy_board, [corners_uv[p.path] for p in shown], photos[0].size) if shown else 0.0
        for p in photos:
            uv = corners_uv.get(p.path)
            views[p.path] = None if uv is None else one_view(xy_board, uv, p.size, lam)
    return views


def _sureness(margin: float) -> str:
    """A margin (log-odds) in words: ``certain`` (no split could decide otherwise), ``sure`` (odds above
    400:1), ``likely`` (above 7:1), ``unsure``."""
    return "certain" if margin >= CERTAIN else "sure" if margin >= 6.0 else "likely" if margin >= MIN_MARGIN \
        else "unsure"


def split_roll(cameras: dict[str, list[Photo]], facts: dict[str, dict], corners_uv: dict, xy_board: np.ndarray,
               folder: str, instant_gap_s: float | None = None, left_out: dict[str, str] | None = None,
               camera_clues: tuple[str, ...] = ("EXIF lens", "image size"),
               symmetric: bool = False) -> tuple[CameraRoll, list[str]]:
    """Split a roll's photos, by camera, into instants (module docstring).

    Parameters
    ----------
    cameras : the photos of each camera (:func:`split_cameras` or :func:`cameras_from_boards`).
    facts : each camera's facts, as those give them.
    corners_uv : ``{path: (N, 2) pixels or None}``, each photo's detected corners (NaN rows where not measured).
    xy_board : (N, 2) the board's corners, mm.
    folder : the roll's folder (for the record and the messages).
    instant_gap_s : a capture-time gap that decides alone: photos further apart are two board positions.
    left_out : ``{file name: reason}`` of photos already left out (turned, copies, no camera).
    camera_clues : what told the cameras apart, for the record.
    symmetric : the board looks the same turned by 180 degrees (its photos may be numbered either way round).

    Returns
    -------
    ``(roll, warnings)``: a :class:`CameraRoll` keyed by view (the stem of an instant's first photo) and the
    warnings to give (retakes, photos without the board, unsure decisions; not those of ``left_out``).

    Raises
    ------
    InputError
        No photo shows the board, or the clues disagree on where a board position ends (the message
        names the photos and what each clue says).
    """
    left_out = dict(left_out or {})
    said = set(left_out)                              # left out before, and said so there
    views = _camera_views(cameras, corners_uv, xy_board)
    camera_of = {p.path: name for name, photos in cameras.items() for p in photos}
    order, timed = shooting_order([p for photos in cameras.values() for p in photos])
    for p in order:
        if views.get(p.path) is None:
            left_out[p.path.name] = f"no board found ({camera_of[p.path]})"
    shown = [p for p in order if views.get(p.path) is not None]
    if not shown:
        raise InputError(f"{folder}: the board was found in none of the camera roll's photos")
    focal = {name: _camera_focal_px(photos, facts[name], views) for name, photos in cameras.items()}
    t0 = shown[0].exif.get("taken")
    shots = [Shot(camera_of[p.path], views[p.path], (p.exif["taken"] - t0).total_seconds() if timed else None)
             for p in shown]
    split = split_positions(shots, xy_board, focal, instant_gap_s, symmetric)
    disagree = split.disagreeing_gaps()
    if disagree:
        k = disagree[0]
        a, b = shown[k - 1], shown[k]
        t, board = split.time_log_odds[k - 1], split.board_log_odds[k - 1]
        gap = (b.exif["taken"] - a.exif["taken"]).total_seconds()         # (only capture times disagree)
        raise InputError(
            f"{folder}: the clues disagree on whether {a.path.name} ({camera_of[a.path]}) and {b.path.name} "
            f"({camera_of[b.path]}) are one board position: the capture times say "
            f"{'yes' if t > 0 else 'no'} (a gap of {gap:.1f} s), the boards {'yes' if board > 0 else 'no'}; give "
            "the largest gap between the lenses of one position (instant gap, in seconds), or leave one of them out")
    warnings = []
    for k in split.unsure_gaps():
        warnings.append(f"{shown[k - 1].path.name} and {shown[k].path.name}: unsure whether one board position "
                        f"or two (margin {split.margins[k - 1]:.1f}, log-odds): check the instants")
    by_camera: dict[str, dict[str, Photo]] = {name: {} for name in cameras}
    record_instants = {}
    for r, run in enumerate(split.runs):
        photos = [shown[i] for i in run]
        key = photos[0].path.stem
        chosen: dict[str, Photo] = {}
        for p in photos:                  # in shooting order: a retake replaces the earlier photo
            name = camera_of[p.path]
            if name in chosen:
                left_out[chosen[name].path.name] = (f"retake: {p.path.name} of the same camera ({name}) at the "
                                                    "same board position is kept (the later)")
            chosen[name] = p
        for name, p in chosen.items():
            by_camera[name][key] = p
        margin = split.run_margin(r)
        record_instants[key] = {"taken": photos[0].exif["taken"].isoformat() if timed else None,
                                "photos": {name: p.path.name for name, p in chosen.items()},
                                "margin": round(margin, 1), "sure": _sureness(margin)}
    warnings += [f"{name}: left out ({reason})" for name, reason in left_out.items() if name not in said]
    margins = [v["margin"] for v in record_instants.values()]
    record = {"folder": folder, "instant_gap_s": split.gap_s, "instant_gap_found": instant_gap_s is None,
              "cameras": facts,
              "instants": record_instants, "left_out": left_out,
              "order": "capture time" if timed else "file name",
              "clues": {"cameras": list(camera_clues), "instants": split.clues},
              "split_margin": min(margins), "split_sure": _sureness(min(margins))}
    return CameraRoll({n: v for n, v in by_camera.items() if v}, record), warnings
