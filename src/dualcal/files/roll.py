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
  phone's browser strips it on upload): by image size, then by the lens each photo's board shows alone, its
  focal length and how it bends the board (:func:`dualcal.geometry.one_view.view_lens`), grouped with a
  stated margin (:mod:`dualcal.files.roll_lenses`: two photos are of one lens where they differ by less than
  a few sigma of their difference, two lenses are told apart where their means differ by more; lenses too
  close to tell are refused, saying what to do). Lenses so close that their photos' focal lengths look like
  one lens's still show in the roll: successive photos of one position scaled by the same ratio again and
  again (:func:`scale_step`); they are split by that ratio, or refused where even it cannot tell which photo is
  which. A board seen nearly square-on gives a focal length that fits
  more than one camera; the photos beside it decide then, over the roll in shooting order at once (the most
  likely labelling of a chain): successive photos of one position by two lenses look alike but for the ratio
  of their focal lengths (:func:`looks_alike`). A photo still unclear is left out, saying so. Named by the same
  rule, from the focal length found.
* **instants** (:func:`split_roll`): the photos in shooting order (capture time, else file name) are
  split into board positions by every clue the roll gives: the board's image and pose, the capture
  times, the lens order (:mod:`dualcal.files.roll_positions`), each decision with its margin (log-odds);
  a split is refused only where the clues disagree. A **retake** (two photos of one camera at one
  position) keeps the later (a retake is taken because the first was not right); a photo without the
  board is left out, saying so.

Every decision is kept in :attr:`CameraRoll.record`, corners.json's top-level ``roll``: which clues told
the cameras (``clues.cameras``: ``EXIF lens``, ``image size``, ``focal length from the board``) and the
instants (``clues.instants``: ``capture time``, ``order``, ``board image``, ``board pose``, ``lens
order``), each camera's facts, each instant's photos and margin, what was left out and why; where the boards
told the cameras, how far apart the closest two lenses of one size are (``cameras_separation_sigma``, in sigma
of their difference) and how sure that is (``cameras_sure``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from ..geometry.camera import equivalent_focal_35mm, focal_px_from_35mm
from ..geometry.model import observed_mask
from ..geometry.division import common_division
from ..geometry.one_view import OneView, board_pixels, one_view, spread_px, view_lens
from .photos import Photo
from .roll_lenses import MIN_LENS_PHOTOS, SPLIT_SIGMA, LensSplit, find_lenses, lens_of, log_likelihoods, separations
from .roll_positions import CERTAIN, MIN_MARGIN, SAME_IMAGE, Shot, image_change, split_positions

__all__ = ["CameraRoll", "camera_class", "cameras_from_boards", "equivalent_focal_mm", "has_lens_exif",
           "is_camera_roll", "looks_alike", "scale_step", "shooting_order", "split_cameras", "split_roll",
           "turned_photos"]

#: A photo takes a camera where the odds for it are at least this (99:1).
SURE_ODDS = 99.0
#: A photo fits the lens it is told to where its point (``ln f``, the division model's coefficient) lies within
#: this Mahalanobis distance squared of the lens's mean (a chi-square of 2 degrees of freedom at 1e-4).
FITS_LENS_CHI2 = 18.42
#: Two photos of one position by two lenses look alike (:func:`looks_alike`): the board's shapes agree within
#: this share of its size, and its shift (the small rotation between the lenses, their parallax) within this
#: angle (radians; 6 degrees).
ALIKE_SHAPE, ALIKE_SHIFT_RAD = 0.08, 0.1
#: The log-odds two successive photos that look alike give their labels (one position).
ALIKE_LOG_ODDS = 6.0
#: Two successive photos of one lens that show one position scaled by more than this (``|ln r|``: a refocus moves
#: a phone's focal length by 1.5 % at most) are two lenses' photos, where :data:`LENS_STEP_PAIRS` pairs show the
#: same ratio within :data:`LENS_STEP_TOLERANCE` (a board moved towards the camera gives a ratio of its own).
MIN_LENS_STEP, LENS_STEP_PAIRS, LENS_STEP_TOLERANCE = 0.02, 3, 0.01


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


def scale_step(a: OneView, b: OneView, f_px: float, xy_board: np.ndarray, symmetric: bool = False) -> float | None:
    """``ln r`` where photo ``b``'s board scaled by ``r`` about the image centre is ``a``'s (:func:`looks_alike`): one
    board position shot by two lenses whose focal lengths differ by ``r`` (``r`` by least squares, the shift
    free), or None where the boards are not alike (another position)."""
    pa, pb = board_pixels(a, xy_board), board_pixels(b, xy_board)
    for other in ([pb, pb[::-1]] if symmetric else [pb]):
        da, db = pa - pa.mean(axis=0), other - other.mean(axis=0)
        r = float(np.sum(da * db) / np.sum(db * db))
        if r > 0 and looks_alike(a, b if other is pb else _turned(b), r, f_px, xy_board):
            return float(np.log(r))
    return None


def _turned(view: OneView) -> OneView:
    """A view of a board that looks the same turned by 180 degrees, numbered the other way round."""
    turn = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    return replace(view, H=view.H @ turn)


def _two_lenses_in_one(chain: list[OneView], labels: np.ndarray, lenses: list, xy_board: np.ndarray,
                       symmetric: bool) -> list[tuple[int, int, float]]:
    """The successive photos ``(i - 1, i)`` given one lens that show one board position scaled by the same ratio
    ``ln r`` (beyond a refocus, :data:`MIN_LENS_STEP`) as at least :data:`LENS_STEP_PAIRS` - 1 other such pairs
    (within :data:`LENS_STEP_TOLERANCE`): two lenses whose photos' focal lengths could not tell them apart, whose
    photos of one position tell them so (none where no ratio repeats)."""
    steps = []
    for i in range(1, len(chain)):
        if labels[i] == labels[i - 1]:
            step = scale_step(chain[i - 1], chain[i], lenses[labels[i]].f_px, xy_board, symmetric)
            if step is not None and abs(step) >= MIN_LENS_STEP:
                steps.append((i - 1, i, step))
    best: list[tuple[int, int, float]] = []
    for _, _, step in steps:
        near = [s for s in steps if abs(abs(s[2]) - abs(step)) <= LENS_STEP_TOLERANCE]
        best = near if len(near) > len(best) else best
    return best if len(best) >= LENS_STEP_PAIRS else []


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


def _sureness_of_split(sigma: float) -> str:
    """Two lenses' separation (:func:`dualcal.files.roll_lenses.find_lenses`) in words: ``certain`` (twice the
    margin or more), ``sure`` (the margin or more), ``unsure`` (refused)."""
    return "certain" if sigma >= 2 * SPLIT_SIGMA else "sure" if sigma >= SPLIT_SIGMA else "unsure"


def _not_told(folder: str, size, split: LensSplit, views: list) -> InputError:
    """The refusal of a roll whose lenses of one size cannot be told apart (:attr:`LensSplit.told`): two lenses
    closer than :data:`dualcal.files.roll_lenses.SPLIT_SIGMA`, or photos that scatter more than one lens's without a
    gap."""
    where = f"{folder + ': ' if folder else ''}the photos of {size[0]}x{size[1]} px without EXIF"
    if split.unresolved:
        i, j = min(split.unresolved, key=lambda ij: split.separation_sigma[ij])
        a, b = split.lenses[i], split.lenses[j]
        what = (f"show two groups of focal lengths, {a.f_px:.0f} +- {a.f_sigma_px:.0f} px ({len(a.members)} photos) "
                f"and {b.f_px:.0f} +- {b.f_sigma_px:.0f} px ({len(b.members)}), only {split.separation_sigma[i, j]:.1f} "
                f"sigma apart (at least {SPLIT_SIGMA:g} tell two lenses apart)")
    else:
        group = max(split.spread, key=len)
        f = sorted(views[i].f_px for i in group)
        what = (f"show focal lengths from {f[0]:.0f} to {f[-1]:.0f} px ({len(group)} photos) that scatter more than "
                "one lens's photos do, but in no groups apart (lenses too close to tell, or one lens that moved "
                "between the photos)")
    return InputError(f"{where} {what}: which lens took which photo cannot be told; keep the EXIF (export the "
                      "originals from the phone, not through a browser), or put each camera's photos in a folder of "
                      "its own (a dataset folder with one subfolder per camera)")


def _split_by_steps(views: list, split: LensSplit, labels: np.ndarray, steps: list, chain: list,
                    xy_board: np.ndarray, symmetric: bool) -> LensSplit | None:
    """One lens found that is two (:func:`_two_lenses_in_one`) split by the ratio its photos of one position show:
    two lenses ``ln r`` apart about its mean, each photo told by its focal length and by the photos beside it
    (:func:`_chain_labels`), then each lens from its photos. Their separation is the ratio's, in sigma of its mean
    over the pairs (its spread at least 0.2 %). None where the photos do not fall into two lenses of at least
    :data:`dualcal.files.roll_lenses.MIN_LENS_PHOTOS` photos with every pair on its two sides."""
    k = int(labels[steps[0][1]])
    log_r = np.array([abs(step) for _, _, step in steps])
    delta = float(np.median(log_r))
    half = np.array([delta / 2.0, 0.0])
    lens = split.lenses[k]
    pseudo = split.lenses[:k] + [replace(lens, mean=lens.mean - half), replace(lens, mean=lens.mean + half)] \
        + split.lenses[k + 1:]
    unary, _ = log_likelihoods(views, pseudo)
    new, margins = _chain_labels(chain, unary, np.array([q.mean[0] for q in pseudo]), xy_board, symmetric)
    sure = margins >= np.log(SURE_ODDS)
    members = [np.flatnonzero((new == j) & sure) for j in (k, k + 1)]
    # a step is ln(f of the first / f of the second): the first is the longer lens where it is positive
    sides = [(new[i] == k + (step > 0), new[j] == k + (step < 0)) for i, j, step in steps]
    if min(len(m) for m in members) < MIN_LENS_PHOTOS or not all(a and b for a, b in sides):
        return None
    lenses = split.lenses[:k] + [lens_of(views, m) for m in members] + split.lenses[k + 1:]
    sep = separations(lenses)
    sep[k, k + 1] = sep[k + 1, k] = delta / (max(float(np.std(log_r)), 0.002) / np.sqrt(len(log_r)))
    return LensSplit(lenses, sep, [], split.stray, [], (k, k + 1))


def _two_in_one(folder: str, size, pairs: list) -> InputError:
    """The refusal of a roll where one lens found is two (:func:`_two_lenses_in_one`) and their photos could not be
    told apart even by their photos of one position (:func:`_split_by_steps`)."""
    named = ", ".join(f"{a.path.name} and {b.path.name}" for a, b, _ in pairs[:3])
    ratio = float(np.exp(np.median([abs(step) for _, _, step in pairs])))
    return InputError(
        f"{folder + ': ' if folder else ''}the photos of {size[0]}x{size[1]} px without EXIF show one lens by their "
        f"focal lengths, but {len(pairs)} pairs of successive photos ({named}) show one board position {ratio:.3f} "
        "times larger in the second: two lenses too close to tell which took which photo; keep the EXIF (export the "
        "originals from the phone, not through a browser), or put each camera's photos in a folder of its own (a "
        "dataset folder with one subfolder per camera)")


def cameras_from_boards(photos: list[Photo], corners_uv: dict, xy_board: np.ndarray, symmetric: bool = False,
                        folder: str = ""):
    """The cameras of photos without EXIF, from what they show (module docstring).

    Parameters
    ----------
    photos : the roll's photos.
    corners_uv : ``{path: (N, 2) pixels or None}``, each photo's detected corners (NaN rows where not measured).
    xy_board : (N, 2) the board's corners, mm.
    symmetric : the board looks the same turned by 180 degrees (its photos may be numbered either way round).
    folder : the roll's folder, for the messages.

    Returns
    -------
    ``(cameras, facts, warnings, left_out)``: the photos by camera name, each camera's facts (``told_by``,
    ``focal_length_board_px`` and its ``focal_length_board_sigma_px``, ``distortion_board`` (the division model's
    coefficient) and its ``distortion_board_sigma``, the ``nearest_lens`` of its image size and the
    ``separation_sigma`` from it (None where it is alone) and how ``sure`` that is, ``focal_length_35mm_mm``,
    ``image_size``, ``photos``), the warnings to give, and ``{file name: reason}`` of the photos no camera could
    be told for.

    Raises
    ------
    InputError
        Two lenses of one image size whose photos' focal lengths and distortions are too close to tell which
        photo is which (:data:`dualcal.files.roll_lenses.SPLIT_SIGMA`, or photos that scatter more than one lens's
        without a gap), or one lens found whose successive photos show one position scaled by a ratio again and
        again (:data:`LENS_STEP_PAIRS`) but that ratio cannot split.
    """
    order, _ = shooting_order(photos)
    views = {p.path: None if corners_uv.get(p.path) is None else one_view(xy_board, corners_uv[p.path], p.size)
             for p in photos}
    groups: dict = {}
    left_out = {p.path.name: "no board found, and without EXIF its camera is unknown"
                for p in order if views.get(p.path) is None}
    found: dict = {}
    for size in sorted({tuple(p.size) for p in photos}):
        shown = [p for p in order if tuple(p.size) == size and views.get(p.path) is not None]
        if not shown:
            continue
        lenses = [view_lens(xy_board, corners_uv[p.path], size, views[p.path]) for p in shown]
        split = find_lenses(lenses)
        if not split.told:
            raise _not_told(folder, size, split, lenses)
        if not split.lenses:
            for p in shown:
                left_out[p.path.name] = "its board gives no focal length, and without EXIF its camera is unknown"
            continue
        unary, d2 = log_likelihoods(lenses, split.lenses)
        log_f = np.array([lens.mean[0] for lens in split.lenses])
        chain = [views[p.path] for p in shown]
        labels, margins = _chain_labels(chain, unary, log_f, xy_board, symmetric)
        steps = _two_lenses_in_one(chain, labels, split.lenses, xy_board, symmetric)
        if steps:
            split = _split_by_steps(lenses, split, labels, steps, chain, xy_board, symmetric)
            if split is None:
                raise _two_in_one(folder, size, [(shown[i], shown[j], step) for i, j, step in steps])
            unary, d2 = log_likelihoods(lenses, split.lenses)
            log_f = np.array([lens.mean[0] for lens in split.lenses])
            labels, margins = _chain_labels(chain, unary, log_f, xy_board, symmetric)
        for i, (p, k, margin) in enumerate(zip(shown, labels, margins)):
            fits = not np.isfinite(d2[i, k]) or d2[i, k] <= FITS_LENS_CHI2
            if margin >= np.log(SURE_ODDS) and fits:
                groups.setdefault((size, int(k)), []).append(p)
                found[(size, int(k))] = (split, int(k))
            elif not fits:
                left_out[p.path.name] = (f"its board's focal length ({lenses[i].f_px:.0f} px) and distortion fit "
                                         "none of the lenses the other photos of its size show")
            else:
                left_out[p.path.name] = ("its camera is unclear: the focal length its board gives fits more than one "
                                         "camera (a board seen nearly square-on), and neither photo beside it tells")
    f35 = {key: equivalent_focal_35mm(key[0], split.lenses[k].f_px) for key, (split, k) in found.items()}
    names, warnings = _names(f35, True)
    cameras = {names[key]: groups[key] for key in names}
    facts = {}
    for key, (split, k) in found.items():
        lens, apart = split.lenses[k], split.separation_sigma[k]
        nearest = [(key[0], j) for j in np.argsort(apart) if np.isfinite(apart[j]) and (key[0], j) in names][:1]
        told = "focal length from the board" + (", its scale at one position" if k in split.by_ratio else "")
        facts[names[key]] = {
            "told_by": told, "focal_length_board_px": round(lens.f_px, 1),
            "focal_length_board_sigma_px": round(lens.f_sigma_px, 1), "distortion_board": round(lens.lam, 4),
            "distortion_board_sigma": round(lens.lam_sigma, 4),
            "nearest_lens": names[nearest[0]] if nearest else None,
            "separation_sigma": round(float(apart[nearest[0][1]]), 1) if nearest else None,
            "sure": _sureness_of_split(float(apart[nearest[0][1]])) if nearest else "certain",
            "focal_length_35mm_mm": round(f35[key], 1), "image_size": list(key[0]), "photos": len(groups[key]),
            "lens_model": None, "focal_length_mm": None, "make": None, "model": None}
    facts = {name: facts[name] for name in cameras}
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
    together, :func:`dualcal.geometry.division.common_division`)."""
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
    apart = [c["separation_sigma"] for c in facts.values() if c.get("separation_sigma") is not None]
    if "focal length from the board" in camera_clues:       # how sure the cameras are, where the boards told them
        record["cameras_separation_sigma"] = min(apart) if apart else None
        record["cameras_sure"] = _sureness_of_split(min(apart)) if apart else "certain"
    return CameraRoll({n: v for n, v in by_camera.items() if v}, record), warnings
