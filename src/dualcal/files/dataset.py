"""Finding the cameras and photos of a dataset and pairing photos of the same instant.

A dataset (CONTRACT.md, "Input") is either

* a folder with one subfolder of photos per camera (``DATASET/wide/*.jpg``, ``DATASET/tele/*.jpg``;
  any names), or a folder that holds only photos: one camera named after the folder, or, when its
  photos' EXIF shows several cameras, a phone's camera roll split into cameras and instants by
  :mod:`dualcal.files.roll`; or
* cameras given one by one as ``NAME=GLOB`` (``left=data/left*.jpg``).

Photos of the same instant share a *view key*: the file stem, or for a glob the part(s) that
its wildcards matched (``left*.jpg`` and ``right*.jpg`` pair ``left01`` with ``right01`` as
``01``), or, with ``pair_by="time"``, the reference camera's stem of the photo taken within
``time_tolerance_s`` of it (EXIF capture time).

A camera roll is split in two steps: its cameras by EXIF when it is opened (:func:`open_dataset`), its
instants once its boards are detected (:func:`split_roll_dataset`), which needs the boards' poses. A folder
of photos without EXIF is one camera when it is opened, and may turn out a camera roll when its boards are
detected: the focal lengths they give tell its cameras apart (:func:`dualcal.files.roll.cameras_from_boards`).
A photo stored turned (its size its camera's other photos' transposed) is left out with a warning.

Photos can be left out by ``exclude`` patterns (:func:`is_excluded`). A dataset that cannot be
calibrated as it stands is refused with one clear error: a camera folder without photos, a folder
holding photos and subfolders with photos; and ``detect`` and ``calibrate`` refuse cameras whose photos
pair with none of the reference camera's (:func:`check_pairs`). Photos are read by
:mod:`dualcal.files.photos`.
"""

from __future__ import annotations

import fnmatch
import glob as globmod
import hashlib
import os
import re
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import InputError
from ..geometry.model import CameraCorners, CornerSet, choose_reference
from .photos import PHOTO_SUFFIXES, Photo, open_image, read_exif, read_gray, source_format
from ..progress import warn
from .roll import has_lens_exif, is_camera_roll, split_cameras, turned_photos

__all__ = ["PHOTO_SUFFIXES", "Dataset", "Photo", "check_pairs", "exclude_views", "is_excluded", "open_dataset",
           "open_image", "parse_camera_spec", "read_exif", "read_gray", "split_roll_dataset"]

@dataclass
class Dataset:
    """Cameras and their photos, keyed by view: ``cameras[name][view] -> Photo``.

    ``skipped`` lists ``(path, reason)`` of files that looked like photos but could not be read, or were
    stored turned; ``excluded[name][view]`` the photos left out by ``exclude`` patterns; ``roll`` is the
    record of a camera roll's split into cameras and instants (:mod:`dualcal.files.roll`; corners.json's
    ``roll``), or None; ``identical[name][path]`` the files left out as copies of another (the kept one).

    ``roll_options`` is not None while a folder of photos awaits its split after detection
    (:func:`split_roll_dataset`): a camera roll, whose ``cameras`` are then its EXIF cameras with their
    photos keyed by file stem, or photos without EXIF (one camera, or one per image size), whose cameras
    only their boards tell. It holds what the split takes (``exclude``, ``instant_gap_s``, ``reference``).
    """

    cameras: dict[str, dict[str, Photo]]
    reference: str
    source: str
    skipped: list[tuple[Path, str]] = field(default_factory=list)
    excluded: dict[str, dict[str, Path]] = field(default_factory=dict)
    roll: dict | None = None
    identical: dict[str, dict[str, Path]] = field(default_factory=dict)
    roll_options: dict | None = None

    @property
    def split_pending(self) -> bool:
        """Whether the photos await their split into cameras and instants (:func:`split_roll_dataset`)."""
        return self.roll_options is not None

    def image_size(self, camera: str) -> tuple[int, int]:
        return next(iter(self.cameras[camera].values())).size

    def meta(self, camera: str) -> dict:
        """corners.json ``meta`` of a camera: photo paths, EXIF make/model/focal, orientation, the
        kind of its photo files (``source_format``: ``"jpeg"``, ``"dng"``, ..., comma-separated if
        mixed), and the photos left out by ``exclude`` (``excluded``: view -> path)."""
        photos = self.cameras[camera]
        first = next(iter(photos.values())).exif
        exif = {k: first[k] for k in ("make", "model", "focal_length_mm", "focal_length_35mm_mm")
                if first.get(k) is not None}
        orientation = {v: p.exif.get("orientation") for v, p in photos.items()
                       if p.exif.get("orientation") not in (None, 1)}
        meta = {"photos": {v: str(p.path) for v, p in photos.items()}, "exif": exif,
                "source_format": ",".join(sorted({source_format(p.path) for p in photos.values()}))}
        if orientation:
            # Reported, never applied: coordinates are in the stored pixel frame.
            meta["exif_orientation"] = orientation
        if self.excluded.get(camera):
            meta["excluded"] = {v: str(p) for v, p in self.excluded[camera].items()}
        if self.identical.get(camera):
            meta["identical_files"] = {str(p): str(kept) for p, kept in self.identical[camera].items()}
        return meta

    def photo_count(self) -> int:
        return sum(len(v) for v in self.cameras.values())


# ---------------------------------------------------------------------------- finding photos

def _is_photo(p: Path) -> bool:
    """A photo file by its name; a broken symbolic link with a photo's name is skipped with a warning naming it."""
    if p.suffix.lower() not in PHOTO_SUFFIXES or p.name.startswith("."):
        return False
    if p.is_symlink() and not p.exists():
        warn(f"skipped: {p} is a broken symbolic link (to {os.readlink(p)})")
        return False
    return p.is_file()


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
    wildcards keys its file by stem. Pattern and paths are compared normalised
    (``./left*.jpg`` matches ``left01.jpg``), as ``pathlib`` and ``glob`` spell them differently.
    """
    regex = _glob_regex(os.path.normpath(pattern))
    keys: dict[str, Path] = {}
    for p in paths:
        m = regex.match(os.path.normpath(p))
        key = "_".join(g for g in (m.groups() if m else ()) if g) or p.stem
        if p.suffix and key.endswith(p.suffix):
            key = key[: -len(p.suffix)] or p.stem
        if key in keys:
            raise InputError(f"--camera {name}={pattern}: {keys[key]} and {p} get the same view key "
                             f"{key!r}; make the wildcard cover the part that tells photos apart")
        keys[key] = p
    return keys


def _list_folder(folder: Path) -> list[Path]:
    try:
        return sorted(folder.iterdir())
    except OSError as exc:
        raise InputError(f"folder {str(folder)!r} cannot be listed ({exc.strerror or exc})") from None


def _warn_not_photos(folder: Path, entries: list[Path]) -> None:
    """One warning naming the files of a photo folder that are not photos (a camera roll's ``.AAE``
    edits and ``.MOV`` Live Photos, notes): they are skipped."""
    others = [p.name for p in entries if p.is_file() and not p.name.startswith(".") and not _is_photo(p)]
    if others:
        listing = ", ".join(others[:4]) + (f" and {len(others) - 4} more" if len(others) > 4 else "")
        warn(f"{folder}: skipping {len(others)} file(s) that are not photos ({listing})")


def _camera_folders(root: Path) -> tuple[dict[str, list[Path]], bool]:
    """Photos per camera of a dataset folder: one subfolder per camera, or photos only (one camera,
    or a camera roll: :mod:`dualcal.files.roll`), and whether the folder holds its photos itself.

    A folder holding photos and subfolders with photos, or (in a folder of camera subfolders) a
    subfolder without photos, is refused: either would silently leave photos or a camera out of
    the calibration. Beside photos, a subfolder without photos (notes, a README) is ignored; files
    that are not photos are named in a warning.
    """
    if not root.exists():
        raise InputError(f"dataset folder {str(root)!r} does not exist")
    if not root.is_dir():
        raise InputError(f"{str(root)!r} is not a folder: give a dataset folder, or cameras with --camera NAME=GLOB")
    entries = _list_folder(root)
    subdirs = [d for d in entries if d.is_dir() and not d.name.startswith(".")]
    photos = [p for p in entries if _is_photo(p)]
    cams = {d.name: [p for p in _list_folder(d) if _is_photo(p)] for d in subdirs}
    with_photos = [n for n, ps in cams.items() if ps]
    if photos and with_photos:
        raise InputError(f"dataset folder {str(root)!r} holds photos ({photos[0].name}, ...) and also subfolders "
                         f"with photos ({', '.join(with_photos[:3])}): put each camera's photos in its own "
                         "subfolder, or move the subfolders out (or give the cameras with --camera NAME=GLOB)")
    if photos:
        _warn_not_photos(root, entries)
        return {root.resolve().name: photos}, True
    if not with_photos:
        raise InputError(f"dataset folder {str(root)!r} holds no photos "
                         f"({', '.join(PHOTO_SUFFIXES)}) nor camera subfolders with photos")
    empty = [n for n, ps in cams.items() if not ps]
    if empty:
        raise InputError(f"camera folder {str(root / empty[0])!r} holds no photos ({', '.join(PHOTO_SUFFIXES)}): "
                         f"put that camera's photos in it, or move it out of {str(root)!r}")
    for name in cams:
        _warn_not_photos(root / name, _list_folder(root / name))
    return cams, False


def is_excluded(patterns, camera: str, view: str, file_name: str | None = None) -> bool:
    """Whether a photo matches one of the ``--exclude`` glob patterns.

    A pattern (:func:`fnmatch.fnmatchcase`) is matched against the view key (``IMG_03``: the
    photos of every camera at that instant), the file name (``IMG_03.jpg``) and ``CAMERA/KEY``
    (``tele/IMG_03``: that camera's photo only).
    """
    names = [view, f"{camera}/{view}"] + ([file_name] if file_name else [])
    return any(fnmatch.fnmatchcase(name, pattern) for pattern in patterns for name in names)


def _excluded_keys(files: dict[str, dict[str, str | None]], patterns) -> dict[str, list[str]]:
    """The keys that ``patterns`` leave out of each camera, from ``files[camera][key] -> file name``.

    A pattern that matches nothing is a warning; one that leaves a camera without photos an error.
    """
    out: dict[str, list[str]] = {}
    used = set()
    for name, keyed in files.items():
        for key, file_name in keyed.items():
            hits = {p for p in patterns if is_excluded([p], name, key, file_name)}
            used |= hits
            if hits:
                out.setdefault(name, []).append(key)
        if len(out.get(name, ())) == len(keyed):
            raise InputError(f"--exclude {' '.join(patterns)} leaves camera {name!r} without photos")
    for pattern in patterns:
        if pattern not in used:
            warn(f"--exclude {pattern!r} matches no photo (it is matched against view keys such as "
                 f"{next(iter(next(iter(files.values()))))!r}, file names and CAMERA/KEY)")
    return out


def exclude_views(corners: CornerSet, patterns) -> CornerSet:
    """``corners`` less the views that ``patterns`` leave out (:func:`is_excluded`).

    The file name is taken from the camera's ``photos`` (corners.json), where it is known. The views
    left out are added to each camera's ``excluded`` (view -> photo path or None).
    """
    if not patterns:
        return corners
    photos = {name: cam.meta.get("photos", {}) for name, cam in corners.cameras.items()}
    keys = _excluded_keys({name: {v: Path(photos[name][v]).name if v in photos[name] else None for v in cam.views}
                           for name, cam in corners.cameras.items()}, patterns)
    cameras = {}
    for name, cam in corners.cameras.items():
        out = {v: photos[name].get(v) for v in keys.get(name, ())}
        meta = {**cam.meta, "excluded": {**cam.meta.get("excluded", {}), **out}} if out else cam.meta
        cameras[name] = CameraCorners(cam.image_size, {v: uv for v, uv in cam.views.items() if v not in out}, meta)
    return replace(corners, cameras=cameras)


def unpaired_cameras(dataset: Dataset) -> list[str]:
    """The cameras none of whose photos pairs with one of the reference camera's (no view key in common);
    none while a camera roll awaits its split (its instants pair them)."""
    if dataset.split_pending:
        return []
    ref_keys = set(dataset.cameras[dataset.reference])
    return [name for name, photos in dataset.cameras.items()
            if name != dataset.reference and not ref_keys & set(photos)]


def check_pairs(dataset: Dataset, pair_by: str = "stem") -> None:
    """Raise :class:`InputError` when some camera's photos pair with none of the reference camera's.

    A rig cannot be calibrated then (``detect`` and ``calibrate`` refuse such a dataset; the
    library's :func:`open_dataset` accepts it, for cameras to be used alone).
    """
    ref_keys = set(dataset.cameras[dataset.reference])
    for name in unpaired_cameras(dataset):
        photos = dataset.cameras[name]
        how = ("none was taken within --time-tolerance of one of the reference camera's" if pair_by == "time"
               else f"e.g. {min(photos)!r} vs {min(ref_keys)!r}")
        raise InputError(f"{dataset.source}: no photo of camera {name!r} pairs with one of the reference camera "
                         f"{dataset.reference!r} ({how}): name the photos of one instant alike (same stem, or what "
                         "the --camera globs' wildcards match), pair them with --pair-by time, or calibrate each "
                         "camera on its own")


def _key_by_stem(name: str, paths: list[Path]) -> dict[str, Path]:
    """``{stem: path}``; two photos with one stem (``IMG_01.jpg``, ``IMG_01.JPG``) are an error."""
    keys: dict[str, Path] = {}
    for p in paths:
        if p.stem in keys:
            raise InputError(f"camera {name!r}: {keys[p.stem]} and {p} have the same name {p.stem!r}, so "
                             "they would be one view; rename or remove one of them")
        keys[p.stem] = p
    return keys


def _read_photos(files: dict[str, Path], skipped: list) -> dict[str, Photo]:
    """The headers of ``files`` (key -> path); an unreadable file is skipped with a warning and
    listed in ``skipped``."""
    photos = {}
    for key, path in sorted(files.items()):
        try:
            size, exif = read_exif(path)
        except InputError as exc:
            warn(f"skipping {path}: {str(exc).split(': ', 1)[-1]}")
            skipped.append((path, str(exc)))
            continue
        photos[key] = Photo(path, size, exif)
    return photos


def _read_headers(name: str, files: dict[str, Path], skipped: list,
                  read: dict[str, Photo] | None = None) -> dict[str, Photo]:
    """:func:`_read_photos` of one camera, whose photos must have one size (``read``: headers already
    read, by key, which are taken as they are)."""
    photos = {k: read[k] for k in files} if read is not None else _read_photos(files, skipped)
    photos = _without_turned(photos, skipped, f"camera {name!r}")
    sizes = {p.size for p in photos.values()}
    if len(sizes) > 1:
        listing = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
        raise InputError(f"camera {name!r}: photos differ in size ({listing}); a camera's photos must all "
                         "have one size (put each camera's photos in its own folder or glob)")
    return photos


def _without_turned(photos: dict[str, Photo], skipped: list, where: str) -> dict[str, Photo]:
    """``photos`` (key -> Photo) less those stored turned (:func:`dualcal.files.roll.turned_photos`), each named
    in a warning and added to ``skipped``."""
    _, turned = turned_photos(list(photos.values()), where)
    for path, why in turned.items():
        warn(f"{path}: left out ({why})")
        skipped.append((path, why))
    return {k: p for k, p in photos.items() if p.path not in turned}


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


def duplicate_files(paths) -> list[list[Path]]:
    """Groups (two or more, each in the given order) of files with identical content: by size, then sha256."""
    by_size = defaultdict(list)
    for p in map(Path, paths):
        by_size[p.stat().st_size].append(p)
    groups = []
    for same_size in by_size.values():
        if len(same_size) < 2:
            continue
        by_hash = defaultdict(list)
        for p in same_size:
            digest = hashlib.sha256()
            with open(p, "rb") as fh:
                for chunk in iter(lambda: fh.read(1 << 20), b""):
                    digest.update(chunk)
            by_hash[digest.hexdigest()].append(p)
        groups += [g for g in by_hash.values() if len(g) > 1]
    order = {p: i for i, p in enumerate(map(Path, paths))}
    return sorted(groups, key=lambda g: order[g[0]])


def _without_copies(files: dict[str, Path]) -> dict[Path, Path]:
    """Remove from ``files`` (key -> path) every file whose content is that of an earlier one (a photo
    copied, exported twice): it would count as an instant of its own, and the sigmas, which come from
    how the instants disagree, would shrink. Returns ``{removed path: kept path}``, each said in a warning."""
    removed = {}
    for kept, *copies in duplicate_files(sorted(files.values())):
        for copy in copies:
            removed[copy] = kept
        warn(f"{', '.join(p.name for p in copies)}: the same file as {kept.name}: counted once")
    for key in [k for k, p in files.items() if p in removed]:
        del files[key]
    return removed


def _open_roll(photos: list[Photo], name: str, source: str, options: dict, skipped,
               identical: dict[Path, Path]) -> Dataset:
    """A folder of photos that awaits its split after detection (:attr:`Dataset.roll_options`): a camera roll by
    EXIF (:func:`dualcal.files.roll.split_cameras`), or photos without EXIF as one camera ``name`` (one per
    image size, ``WxH``, where they differ). ``identical`` are the files left out as copies."""
    record = None
    if all(has_lens_exif(p) for p in photos):
        by_camera, facts, notes = split_cameras(photos)
        for note in notes:
            warn(note)
        record = {"folder": source, "cameras": facts}
    else:
        sizes = sorted({p.size for p in photos})
        by_camera = {name if len(sizes) == 1 else f"{w}x{h}": [p for p in photos if p.size == (w, h)]
                     for w, h in sizes}
    cams = {n: {p.path.stem: p for p in ps} for n, ps in by_camera.items()}
    # photos without EXIF are named for now: a reference is checked against the cameras their boards tell
    return Dataset(cams, choose_reference(cams, options["reference"] if record is not None else None), source,
                   skipped, {}, record, _copies_by_camera(cams, identical), roll_options=options)


def _copies_by_camera(cameras: dict[str, dict[str, Photo]], identical: dict[Path, Path]) -> dict:
    """``identical`` ``{copy left out: the file kept}`` as :attr:`Dataset.identical` holds it, by the camera whose
    photo the kept file is (copies of a file no camera holds are dropped)."""
    names = {p.path: n for n, photos in cameras.items() for p in photos.values()}
    copies: dict = {}
    for p, kept in identical.items():
        if kept in names:
            copies.setdefault(names[kept], {})[p] = kept
    return copies


def split_roll_dataset(dataset: Dataset, corners: CornerSet) -> tuple[Dataset, CornerSet]:
    """Split a folder of photos that awaited its detected boards (:attr:`Dataset.split_pending`) into cameras
    and instants (:func:`dualcal.files.roll.split_roll`; photos without EXIF: their cameras first, by
    :func:`dualcal.files.roll.cameras_from_boards`), less what ``exclude`` leaves out (matched against the
    instants' view keys, the file names and CAMERA/KEY).

    Parameters
    ----------
    dataset : from :func:`open_dataset`, with ``split_pending``.
    corners : its detected corners (:func:`dualcal.files.detect.detect_dataset`), keyed as ``dataset``.

    Returns
    -------
    The dataset and its corners keyed by camera and instant, with the roll's record (corners.json ``roll``);
    photos without EXIF that show one camera are returned as they are (one camera keyed by file stem).

    Raises
    ------
    InputError
        What :func:`dualcal.files.roll.split_roll` and ``exclude`` refuse.
    """
    from .roll import cameras_from_boards, split_roll

    options = dataset.roll_options
    xy_board = corners.board.object_points_mm()[:, :2]
    detected = {}                                   # photo path -> (camera, key) of the detection
    corners_uv = {}
    for cam, photos in dataset.cameras.items():
        for key, photo in photos.items():
            detected[photo.path] = (cam, key)
            corners_uv[photo.path] = corners.cameras[cam].views.get(key)
    photos = [p for ps in dataset.cameras.values() for p in ps.values()]
    left_out = {p.name: why for p, why in dataset.skipped}
    identical = {p: kept for d in dataset.identical.values() for p, kept in d.items()}
    left_out.update({p.name: f"the same file as {kept.name}" for p, kept in identical.items()})
    symmetric = corners.board.is_symmetric and corners.board.charuco is None
    if dataset.roll is None:
        by_camera, facts, notes, unknown = cameras_from_boards(photos, corners_uv, xy_board, symmetric, dataset.source)
        if len(dataset.cameras) == 1 and len(by_camera) <= 1:        # one camera, as the folder was opened
            one = replace(dataset, reference=choose_reference(dataset.cameras, options["reference"]), roll_options=None)
            _exclude(one, options["exclude"])
            return one, _regrouped(one, corners, detected, None)
        for note in notes + [f"{name}: left out ({why})" for name, why in unknown.items()]:
            warn(note)
        left_out.update(unknown)
        clues = ("image size", "focal length from the board")
    else:
        by_camera = {name: list(ps.values()) for name, ps in dataset.cameras.items()}
        facts, clues = dataset.roll["cameras"], ("EXIF lens", "image size")
    roll, notes = split_roll(by_camera, facts, corners_uv, xy_board, dataset.source, options["instant_gap_s"], left_out,
                             clues, symmetric=symmetric)
    for note in notes:
        warn(note)
    split = Dataset(roll.cameras, choose_reference(roll.cameras, options["reference"]), dataset.source,
                    dataset.skipped, {}, roll.record, _copies_by_camera(roll.cameras, identical))
    _exclude(split, options["exclude"])
    out = _regrouped(split, corners, detected, roll.record)
    if symmetric and len(out.cameras) > 1:
        from .detect.symmetry import align_symmetric_numbering

        out, turned = align_symmetric_numbering(out, split.reference)
        if turned:
            warn(f"board {corners.board.spec()} looks the same turned by 180 degrees: {turned} photo(s) of the "
                 f"roll renumbered to fit the rig's relative pose to camera {split.reference!r}")
    return split, out


def _exclude(dataset: Dataset, patterns) -> None:
    """Leave out of ``dataset`` the photos ``patterns`` match (:func:`is_excluded`), listing them in ``excluded``."""
    if patterns:
        keys = _excluded_keys({n: {k: p.path.name for k, p in v.items()} for n, v in dataset.cameras.items()},
                              patterns)
        dataset.excluded.update({n: {k: dataset.cameras[n].pop(k).path for k in ks} for n, ks in keys.items()})


def _regrouped(dataset: Dataset, corners: CornerSet, detected: dict[Path, tuple[str, str]], roll) -> CornerSet:
    """The corners of ``dataset``'s cameras and views, taken from ``corners`` by photo (``detected``: each photo's
    camera and key there), with ``dataset``'s meta (and the manual and partial views the detection marked, and each
    photo's quality it measured)."""
    cameras = {}
    for name, photos in dataset.cameras.items():
        meta = dataset.meta(name)
        for flag in ("manual_views", "partial_views"):
            keys = sorted(k for k, p in photos.items()
                          if detected[p.path][1] in corners.cameras[detected[p.path][0]].meta.get(flag, ()))
            if keys:
                meta[flag] = keys
        quality = {k: q for k, p in photos.items() if (q := corners.cameras[detected[p.path][0]].meta
                                                       .get("photo_quality", {}).get(detected[p.path][1]))}
        if quality:
            meta["photo_quality"] = dict(sorted(quality.items()))
        uv = {k: corners.cameras[detected[p.path][0]].views[detected[p.path][1]] for k, p in photos.items()}
        cameras[name] = CameraCorners(dataset.image_size(name), uv, meta)
    return replace(corners, cameras=cameras, roll=roll)


def open_dataset(path=None, cameras=(), pair_by: str = "stem", reference: str | None = None,
                 time_tolerance_s: float = 2.0, exclude=(), instant_gap_s: float | None = None) -> Dataset:
    """Find the cameras and photos of a dataset and key them by view.

    Parameters
    ----------
    path
        dataset folder (see the module docstring), or None when ``cameras`` are given.
    cameras
        ``NAME=GLOB`` strings or ``(name, glob)`` pairs; they take precedence over ``path``
        (a relative glob is taken relative to ``path`` when given, else to the working folder).
    pair_by : str
        ``"stem"`` (file stem, or the glob's wildcard text) or ``"time"`` (EXIF capture time).
    reference : str or None
        the reference camera (default: ``wide`` if present, else the first sorted name);
        with ``pair_by="time"`` its stems are the view keys.
    time_tolerance_s : float
        largest capture-time difference of two photos of the same instant.
    instant_gap_s : float or None
        a camera roll (a folder of photos of several cameras, :mod:`dualcal.files.roll`): photos
        taken less than this apart are one board position, further apart two (default: found from every clue
        of the roll); taken by :func:`split_roll_dataset`.
    exclude
        glob patterns of photos to leave out (:func:`is_excluded`; with ``pair_by="time"``
        the view key is the photo's own stem); they are listed in :attr:`Dataset.excluded`. For a folder of
        photos that awaits its split (:attr:`Dataset.split_pending`), :func:`split_roll_dataset` applies them.

    Returns
    -------
    Dataset
        Every camera's photos keyed by view (instant), and what was left out and why.

    Raises
    ------
    InputError
        Missing or empty folder, a camera folder without photos, a folder holding both photos and
        subfolders, a glob matching no photo, an unknown reference camera, a camera whose photos
        differ in size, no readable photo (see also :func:`check_pairs`).
    """
    if pair_by not in ("stem", "time"):
        raise InputError(f"--pair-by {pair_by!r}: choose stem or time")
    specs = [parse_camera_spec(c) if isinstance(c, str) else tuple(c) for c in cameras]
    files: dict[str, dict[str, Path]] = {}
    flat = False
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
            files[name] = _glob_keys(name, full, matched) if pair_by == "stem" else _key_by_stem(name, matched)
        source = str(path) if path is not None else ", ".join(f"{n}={g}" for n, g in specs)
    else:
        if path is None:
            raise InputError("give a dataset folder or cameras with --camera NAME=GLOB")
        folders, flat = _camera_folders(Path(path))
        files = {n: _key_by_stem(n, ps) for n, ps in folders.items()}
        source = str(path)
    identical = {n: _without_copies(f) for n, f in files.items()}
    skipped: list = []
    read: dict[str, dict[str, Photo]] = {}
    if flat:                                # a folder of photos: one camera, or a camera roll
        (name, keyed), = files.items()
        read[name] = _without_turned(_read_photos(keyed, skipped), skipped, source)
        photos = list(read[name].values())
        if photos and (is_camera_roll(photos) or not all(has_lens_exif(p) for p in photos)):
            options = {"exclude": tuple(exclude), "instant_gap_s": instant_gap_s, "reference": reference}
            return _open_roll(photos, name, source, options, skipped, identical[name])
        files = {name: {k: p for k, p in keyed.items() if k in read[name]}}
    excluded = {}
    if exclude:
        keys = _excluded_keys({n: {k: p.name for k, p in f.items()} for n, f in files.items()}, exclude)
        excluded = {n: {k: files[n].pop(k) for k in ks} for n, ks in keys.items()}
    cams = {n: _read_headers(n, f, skipped, read.get(n)) for n, f in sorted(files.items())}
    empty = [n for n, ps in cams.items() if not ps]
    if empty:
        raise InputError(f"camera {empty[0]!r} has no readable photo")
    ref = choose_reference(cams, reference)
    if pair_by == "time":
        cams = _pair_by_time(cams, ref, time_tolerance_s)
    return Dataset(cams, ref, source, skipped, excluded, identical={n: d for n, d in identical.items() if d})
