"""All JSON in and out of dualcal, and atomic writes (formats: the contract, README).

Loaders validate and raise :class:`~dualcal.errors.InputError` with a message that names the
file and the fix; nothing here ever returns half-read data. Every output goes through
:func:`write_bytes_atomic`: a temporary file in the destination folder, checked to the last byte
on the disk, then ``os.replace``, so an interrupted run or a full disk never leaves half a file
and never destroys an earlier result (a full disk is an :class:`~dualcal.errors.OutputError`).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import math
import os
import re
import tempfile
from json.encoder import encode_basestring_ascii
from pathlib import Path

import numpy as np

from .. import __version__
from ..geometry.board import SHAPE_TERMS, Board
from ..geometry.camera import (DEFAULT_LENS_MODEL, DISTORTION_NAMES, LENS_MODELS, CameraModel, intrinsic_names,
                               max_distorted_radius, normalized_from_pixel)
from ..errors import InputError, OutputError
from ..geometry.focus import FocusModel
from ..geometry.model import (MIXED_LENS_MODELS, CameraCorners, CornerSet, KnownIntrinsics, Pose, RigModel,
                              RigRelation, rig_residuals, rms_px)
from ..parallel import raise_if_cancelled
from ..progress import warn
from .schemas import validate

# ---------------------------------------------------------------------------- atomic writes


#: Marks the temporary files of dualcal's writes: ``.<name>.dualcal-tmp-<pid>-<random><suffix>``.
#: One that a killed run left behind (its process gone) is removed by the next write into that folder.
TEMP_MARK = ".dualcal-tmp-"
_TEMP_NAME = re.compile(r"^\..*\.dualcal-tmp-(\d+)-[^/]*$")
#: errno values that mean "the disk (or the quota) is full".
_FULL = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EFBIG}


def _write_failure(exc: OSError, where) -> OutputError:
    """The one-line error of a failed write: a full disk said as such, else the system's reason."""
    if exc.errno in _FULL:
        return OutputError(f"{where}: the disk is full ({exc.strerror}): free some space; nothing was replaced")
    if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        return OutputError(f"{where}: cannot write there ({exc.strerror}): choose another output")
    return OutputError(f"{where}: cannot be written ({exc.strerror or exc})")


def _process_gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:         # it exists (another user's): not ours to judge
        return False
    return False


def clean_stale_temporaries(folder) -> list[Path]:
    """Remove the temporary files (:data:`TEMP_MARK`) that runs killed meanwhile left in ``folder``.

    Only files whose writing process is gone are removed, so a concurrent writer's file stays.
    Returns the paths removed."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _TEMP_NAME.match(entry.name)
        if match and entry.is_file(follow_symlinks=False) and _process_gone(int(match.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


_cleaned: set[str] = set()


def _clean_once(folder) -> None:
    """:func:`clean_stale_temporaries` the first time this process writes into ``folder``."""
    key = os.path.abspath(folder)
    if key not in _cleaned:
        _cleaned.add(key)
        clean_stale_temporaries(folder)


def _probe_writable(folder: Path) -> None:
    """Raise :class:`OutputError` unless a file can really be created in ``folder`` (a read-only
    mount or folder is found here, before any long work); stale temporaries are cleaned on the way."""
    _clean_once(folder)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".probe{TEMP_MARK}{os.getpid()}-", dir=folder)
    except OSError as exc:
        raise _write_failure(exc, f"output folder {str(folder)!r}") from None
    os.close(fd)
    os.unlink(tmp)


def _output_path(path) -> tuple[Path, Path]:
    """``path`` and its folder, after checking that the folder exists and ``path`` is no folder."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"output folder {str(parent)!r} does not exist: create it first or choose another -o")
    if path.is_dir():
        raise InputError(f"output {str(path)!r} is a folder: give a file name")
    return path, parent


def check_output_file(path) -> Path:
    """Raise :class:`InputError` unless ``path`` can be written as a file: its folder exists, is
    writable (else :class:`OutputError`), and ``path`` is not itself a folder. Commands call this
    first, before any long work."""
    path, parent = _output_path(path)
    _probe_writable(parent)
    return path


def make_output_folder(path) -> Path:
    """Create the output folder ``path`` unless it exists (its parent must exist already), and
    check that it is writable (:class:`OutputError` otherwise).

    The rule of every dualcal output: dualcal creates at most the last folder of a path, so a
    mistyped path fails at once with :class:`InputError` instead of growing a tree of folders.
    """
    path = Path(path)
    if not path.is_dir():
        if not path.parent.is_dir():
            raise InputError(f"output folder {str(path)!r}: its parent does not exist (create it first)")
        try:
            path.mkdir()
        except OSError as exc:
            if exc.errno in _FULL | {errno.EROFS}:
                raise _write_failure(exc, f"output folder {str(path)!r}") from None
            raise InputError(f"output folder {str(path)!r} cannot be created ({exc.strerror or exc})") from None
    _probe_writable(path)
    return path


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()    # read once: setting it later, even briefly, would race with other threads


def _write_all(fd: int, data: bytes) -> None:
    """``os.write`` until every byte is written; a write that writes nothing is a full disk."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        if n <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view = view[n:]


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, checked to the last byte.

    Every dualcal output goes through here: a temporary file beside ``path`` (named with
    :data:`TEMP_MARK`, so a later run cleans it if this one is killed), written, flushed to the
    disk (``fsync``), its size on the disk compared with ``len(data)``, then renamed over
    ``path``. On any failure the temporary file is removed and ``path`` is left as it was; a
    failed write (a full disk, a short write) raises :class:`OutputError`, a Ctrl-C meanwhile
    commits nothing (:func:`dualcal.parallel.raise_if_cancelled`).
    """
    path, folder = _output_path(path)
    _clean_once(folder)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:100]}{TEMP_MARK}{os.getpid()}-",
                                   suffix=path.suffix or ".tmp", dir=folder)
    except OSError as exc:
        raise _write_failure(exc, f"output folder {str(folder)!r}") from None
    try:
        try:
            _write_all(fd, data)
            os.fsync(fd)
            size = os.fstat(fd).st_size
        except OSError as exc:
            raise _write_failure(exc, path) from None
        finally:
            os.close(fd)
        if size != len(data):
            raise OutputError(f"{path}: {size} of {len(data)} bytes written (a full disk?); nothing was replaced")
        raise_if_cancelled()               # interrupted meanwhile: commit nothing
        os.chmod(tmp, 0o666 & ~_UMASK)     # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path, doc: dict) -> None:
    write_text_atomic(path, dumps_indented(doc) + "\n")


def dumps_indented(doc) -> str:
    """``json.dumps(doc, indent=1, allow_nan=False)``, the same text, in about two thirds of its time: a list of
    numbers, or of ``null`` and lists of numbers (a view's corners), is written in one pass rather than by
    json's pure-Python encoder (the one it uses whenever it indents), value by value."""
    out: list[str] = []
    put = out.append

    def number(x: float) -> str:
        finite((x,))
        return float.__repr__(x)

    def finite(values) -> None:
        if not all(map(math.isfinite, values)):
            bad = next(x for x in values if not math.isfinite(x))
            raise ValueError(f"Out of range float values are not JSON compliant: {bad!r}")

    def encode(o, level: int) -> None:
        if isinstance(o, str):
            put(encode_basestring_ascii(o))
        elif o is None or o is True or o is False:
            put("null" if o is None else "true" if o else "false")
        elif isinstance(o, int):
            put(int.__repr__(o))
        elif isinstance(o, float):
            put(number(o))
        elif isinstance(o, (list, tuple, dict)):
            if not o:
                put("{}" if isinstance(o, dict) else "[]")
                return
            inner, end = "\n" + " " * (level + 1), "\n" + " " * level
            if isinstance(o, dict):
                put("{")
                for i, (key, value) in enumerate(o.items()):
                    put(("" if i == 0 else ",") + inner + encode_basestring_ascii(_json_key(key)) + ": ")
                    encode(value, level + 1)
                put(end + "}")
            elif all(type(x) is float for x in o):
                finite(o)
                put("[" + inner + ("," + inner).join(map(float.__repr__, o)) + end + "]")
            elif all(x is None or (type(x) is list and x and all(type(y) is float for y in x)) for x in o):
                deeper, close = inner + " ", inner + "]"
                pair = "[" + deeper + "%r," + deeper + "%r" + close         # %r of a float is its repr
                finite([y for x in o if x is not None for y in x])
                put("[" + inner + ("," + inner).join("null" if x is None else pair % (x[0], x[1]) if len(x) == 2 else
                                                     "[" + deeper + ("," + deeper).join(map(float.__repr__, x)) + close
                                                     for x in o) + end + "]")
            else:
                put("[")
                for i, x in enumerate(o):
                    put(("" if i == 0 else ",") + inner)
                    encode(x, level + 1)
                put(end + "]")
        else:
            raise TypeError(f"Object of type {o.__class__.__name__} is not JSON serializable")

    encode(doc, 0)
    return "".join(out)


def _json_key(key) -> str:
    """A dict key as json writes it (a number or a constant as its JSON text)."""
    if isinstance(key, str):
        return key
    if key is None or isinstance(key, bool):
        return json.dumps(key)
    if isinstance(key, float):
        return float.__repr__(key)
    if isinstance(key, int):
        return int.__repr__(key)
    raise TypeError(f"keys must be str, int, float, bool or None, not {key.__class__.__name__}")


def encode_jpeg(bgr: np.ndarray, quality: int) -> bytes:
    """An 8-bit BGR (or grey) image as JPEG bytes (OpenCV's encoder)."""
    import cv2

    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OutputError(f"JPEG encoding of a {bgr.shape} image failed")
    return buf.tobytes()


def write_jpeg_atomic(path, bgr: np.ndarray, quality: int = 90) -> None:
    """Encode an 8-bit BGR image as JPEG and write it atomically, checked to the last byte."""
    write_bytes_atomic(path, encode_jpeg(bgr, quality))


# ---------------------------------------------------------------------------- reading


def read_json(path) -> dict:
    """Parse a JSON file; missing, unreadable or truncated files raise :class:`InputError`."""
    path = Path(path)
    try:
        exists = path.exists()
    except OSError as exc:                      # e.g. a name too long for the file system
        raise InputError(f"{str(path)[:80]}: cannot be read ({exc.strerror or exc})") from None
    if not exists:
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a JSON file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (expected JSON)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: malformed or truncated JSON ({exc.msg} at line {exc.lineno})") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply to be a dualcal file") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object at the top level")
    return doc


def json_kind(doc: dict) -> str:
    """'calib', 'eval', 'corners' or 'unknown' for a parsed document."""
    if "dualcal_version" in doc and "rig" in doc:
        return "calib"
    if "cases" in doc:
        return "eval"
    if "cameras" in doc and "board" in doc:
        return "corners"
    if "points" in doc:
        return "measure" if "frame" in doc else "points"
    if "cameras" in doc:
        return "intrinsics"
    return "unknown"


_KIND_NAMES = {"calib": "a calib.json", "eval": "an eval.json", "corners": "a corners.json",
               "points": "a points.json", "measure": "a measure.json", "intrinsics": "an intrinsics.json",
               "unknown": "not a dualcal file"}


def _expect_kind(path, doc: dict, kind: str) -> None:
    got = json_kind(doc)
    if got != kind:
        raise InputError(f"{path}: this is {_KIND_NAMES[got]}, expected {_KIND_NAMES[kind]}")


def _finite_array(value, shape_tail, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected numbers") from None
    if arr.ndim != len(shape_tail) or any(s is not None and a != s for a, s in zip(arr.shape, shape_tail)):
        raise InputError(f"{what}: expected shape {shape_tail}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: contains NaN or infinite values")
    return arr


def _corner_array(value, n_corners: int, what: str) -> np.ndarray:
    """A view's corners: a list of ``n_corners`` entries ``[u, v]`` or ``null`` (not measured),
    as an (n_corners, 2) array with NaN rows for the ``null`` ones."""
    if not isinstance(value, list) or len(value) != n_corners:
        got = f"{len(value)} entries" if isinstance(value, list) else type(value).__name__
        raise InputError(f"{what}: expected a list of {n_corners} corners ([u, v] or null), got {got}")
    missing = [v is None for v in value]
    if all(missing):
        raise InputError(f"{what}: every corner is null (write null for the whole view instead)")
    arr = np.full((n_corners, 2), np.nan)
    arr[~np.array(missing)] = _finite_array([v for v in value if v is not None], (None, 2), what)
    return arr


def _image_size(value, what: str) -> tuple[int, int]:
    arr = _finite_array(value, (2,), f"{what} image_size")
    if np.any(arr <= 0) or np.any(arr != np.round(arr)):
        raise InputError(f"{what} image_size {value!r}: expected two positive integers [W, H]")
    return int(arr[0]), int(arr[1])


def board_from_dict(entry, source: str) -> Board:
    """The board entry of a corners.json or calib.json (a chessboard, or a ChArUco board with its
    ``charuco`` entry, see the contract), validated; the error names ``source``."""
    try:
        return Board.from_dict(entry if isinstance(entry, dict) else {})
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def corners_from_dict(doc: dict, source: str = "corners.json") -> CornerSet:
    """Validate a corners.json document and build a :class:`CornerSet`."""
    board = board_from_dict(doc.get("board"), source)
    cams = doc.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise InputError(f"{source}: 'cameras' must be a non-empty object")
    cameras = {}
    for name, entry in cams.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("views"), dict):
            raise InputError(f"{source}: camera {name!r} needs 'image_size' and a 'views' object")
        size = _image_size(entry.get("image_size"), f"{source}: camera {name!r}")
        views = {}
        for key, pts in entry["views"].items():
            if pts is None:
                views[str(key)] = None
                continue
            views[str(key)] = _corner_array(pts, board.n_corners,
                                            f"{source}: camera {name!r} view {key!r} "
                                            f"(board {board.spec()} has {board.n_corners} corners)")
        meta = {k: v for k, v in entry.items() if k not in ("image_size", "views")}
        cameras[str(name)] = CameraCorners(size, views, meta)
    reference = doc.get("reference")
    if reference is not None and reference not in cameras:
        raise InputError(f"{source}: reference {reference!r} is not one of the cameras {sorted(cameras)}")
    roll = doc.get("roll")
    if roll is not None and not isinstance(roll, dict):
        raise InputError(f"{source}: 'roll' must be an object (the camera roll's record)")
    return CornerSet(board, cameras, reference, roll)


def _corner_list(uv: np.ndarray | None):
    """A view's corners for corners.json: ``[u, v]`` per corner rounded to 5 decimals, ``null`` for NaN rows.

    Corners read from a corners.json are rounded already (``np.round`` leaves every one as it is exactly when
    Python's ``round`` does): their values are taken as they are, without rounding each number again."""
    if uv is None:
        return None
    uv = np.asarray(uv, float)
    ok = np.isfinite(uv).all(axis=1)
    if np.array_equal(np.round(uv[ok], 5), uv[ok]):
        return [p if good else None for p, good in zip(uv.tolist(), ok.tolist())]
    return [[round(u, 5), round(v, 5)] if good else None for (u, v), good in zip(uv.tolist(), ok.tolist())]


def corners_to_dict(cs: CornerSet) -> dict:
    cams = {}
    for name, cam in cs.cameras.items():
        cams[name] = {"image_size": list(cam.image_size),
                      "views": {k: _corner_list(v) for k, v in cam.views.items()},
                      **cam.meta}
    doc = {"board": cs.board.to_dict(), "cameras": cams}
    if cs.reference is not None:
        doc["reference"] = cs.reference
    if cs.roll is not None:
        doc["roll"] = cs.roll
    return doc


def _load(path, kind: str) -> dict:
    """Read a JSON file that must be of ``kind`` and valid against its schema (:mod:`dualcal.files.schemas`)."""
    doc = read_json(path)
    _expect_kind(path, doc, kind)
    validate(doc, kind, str(path))
    return doc


def load_corners(path) -> CornerSet:
    """Read a corners.json, checked against its schema and beyond it (every number finite, views of the
    board's size).

    Parameters
    ----------
    path : str or Path
        The corners.json to read.

    Returns
    -------
    CornerSet
        The board and every camera's corners per view (``None`` for a photo without the board).

    Raises
    ------
    InputError
        A missing or unreadable file, or one that breaks a rule (the message names the key).
    """
    return corners_from_dict(_load(path, "corners"), str(path))


def save_corners(path, cs: CornerSet) -> None:
    """Write ``cs`` as corners.json, atomically (a temporary file beside it, checked, then renamed).

    Parameters
    ----------
    path : str or Path
        The file to write; its folder must exist.
    cs : CornerSet
        The corners to write.

    Raises
    ------
    OutputError
        The file cannot be written (a full disk, a read-only folder); nothing was replaced.
    """
    write_json_atomic(path, corners_to_dict(cs))


# ---------------------------------------------------------------------------- calib.json


def _pose_from_dict(d: dict, what: str) -> Pose:
    R = _finite_array(d.get("R"), (3, 3), f"{what} R")
    t = _finite_array(d.get("t_mm"), (3,), f"{what} t_mm")
    return Pose(R, t)


def rig_to_dict(rig: RigModel) -> dict:
    """The calib.json document of a :class:`RigModel` (contract keys first, extensions after)."""
    cameras = {}
    for name, cam in rig.cameras.items():
        names = intrinsic_names(cam.model)        # the model's coefficients only (k1k2: the keys of old files)
        entry = {"image_size": list(cam.image_size), "model": cam.model}
        entry.update({n: float(getattr(cam, n)) for n in names})
        entry["sigma"] = {n: float(s) for n, s in rig.camera_sigma[name].items() if n in names}
        if name in rig.camera_sigma_formal:
            entry["sigma_formal"] = {n: float(s) for n, s in rig.camera_sigma_formal[name].items() if n in names}
        entry["rms_px"] = float(rig.camera_rms_px[name])
        if name in rig.focus_models:
            entry["focus_m"] = rig.focus_models[name].focus_m
            entry["focus_model"] = rig.focus_models[name].to_dict()
        if name in rig.ois_sigma_px:
            entry["ois_sigma_px"] = float(rig.ois_sigma_px[name])
        cameras[name] = entry
    rig_doc = {}
    for name, rel in rig.rig.items():
        rig_doc[name] = {**rel.pose.to_dict(), "baseline_mm": rel.baseline_mm,
                         "opk_arcmin": rel.pose.opk_arcmin.tolist(),
                         "sigma": _rig_sigma_doc(rel.sigma_t_mm, rel.sigma_baseline_mm, rel.sigma_opk_arcmin)}
        if rel.sigma_formal:
            f = rel.sigma_formal
            rig_doc[name]["sigma_formal"] = _rig_sigma_doc(f["t_mm"], f["baseline_mm"], f["opk_arcmin"])
    views = {}
    noise = (rig.adjustment.get("photo_noise") or {}).get("photos", {})
    for view, pose in rig.reference_poses().items():
        views[view] = {**pose.to_dict(), "rms_px": rig.view_rms_px.get(view, {})}
        if noise:
            views[view]["noise_px"] = {cam: noise[cam][view]["noise_px"] for cam in noise if view in noise[cam]}
        focus = {cam: float(per[view]) for cam, per in rig.photo_focus_m.items() if view in per}
        if focus:
            views[view]["focus_m"] = focus
        shifts = {cam: [float(x) for x in per[view]] for cam, per in rig.ois_shift_px.items() if view in per}
        if shifts:
            views[view]["ois_shift_px"] = shifts
    board = rig.board.to_dict()
    if rig.board_shape_mm is not None:
        board["sag_mm"] = rig.board_sag_mm()
        board["shape_mm"] = dict(zip(SHAPE_TERMS, map(float, rig.board_shape_mm)))
        board["shape_sigma_mm"] = dict(zip(SHAPE_TERMS, map(float, rig.board_shape_sigma_mm)))
    doc = {
        "dualcal_version": __version__,
        "board": board,
        "reference": rig.reference,
        "skew": bool(rig.skew),
        "rig_mode": rig.rig_mode,
        "model": rig.model,
        "cameras": cameras,
        "rig": rig_doc,
        "views": views,
        "rms_px": float(rig.rms_px),
        "corners": corners_to_dict(rig.corners),
        "camera_poses": {cam: {v: p.to_dict() for v, p in poses.items()}
                         for cam, poses in rig.camera_poses.items()},
        "adjustment": rig.adjustment,
        "dropped_views": rig.dropped_views,
        "dropped_corners": rig.dropped_corners,
        "checks": rig.checks,
        "checks_sha256": checks_digest(rig.checks),
    }
    if rig.covariance is not None:
        doc["covariance"] = rig.covariance
    known = (rig.adjustment.get("known_intrinsics") or {}).get("cameras")
    if known:
        doc["intrinsics_given"] = {name: entry["mode"] for name, entry in sorted(known.items())}
    video = video_record(rig.corners)
    if video is not None:
        doc["video"] = video
    return doc


def video_record(cs: CornerSet) -> dict | None:
    """calib.json's ``video`` (CONTRACT.md, "Video") from the clips' records in each camera's corners
    (:mod:`dualcal.files.video`), or None when the corners are not from clips."""
    clips = {name: cam.meta["video"] for name, cam in cs.cameras.items() if isinstance(cam.meta.get("video"), dict)}
    if not clips:
        return None
    offset = {n: r["offset_s"] for n, r in clips.items() if "offset_s" in r}
    sigma = {n: r["offset_sigma_s"] for n, r in clips.items() if "offset_sigma_s" in r}
    keys = ("frames_read", "board_found", "still", "moments", "chosen", "not_used")
    return {"offset_s": offset, "offset_sigma_s": sigma, "unmatched": sorted(set(clips) - set(offset)),
            "frames": {n: {k: r[k] for k in keys if k in r} for n, r in clips.items()}}


def checks_digest(checks: dict) -> str:
    """sha256 of calib.json's ``checks`` as canonical JSON: stored beside them as ``checks_sha256``, so
    that checks edited by hand are found and refused (:func:`rig_from_dict`), never trusted."""
    text = json.dumps(checks, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def _trusted_checks(doc: dict, source: str) -> dict:
    """calib.json's ``checks`` if they are as the calibration wrote them (``checks_sha256``); checks
    without their digest (a file written by hand or by an older dualcal) are dropped with a warning."""
    checks = doc.get("checks") or {}
    stored = doc.get("checks_sha256")
    if stored is None:
        if checks:
            warn(f"{source}: its checks carry no checks_sha256 (written by hand or by an older dualcal): "
                 "they are not used; calibrate again to have them")
        return {}
    if stored != checks_digest(checks):
        raise InputError(f"{source}: its checks were edited after the calibration computed them "
                         "(checks_sha256 does not match): calibrate again rather than edit them")
    return dict(checks)


def _rig_sigma_doc(t_mm, baseline_mm, opk_arcmin) -> dict:
    return {"baseline_mm": float(baseline_mm), "opk_arcmin": np.asarray(opk_arcmin, float).tolist(),
            "t_mm": np.asarray(t_mm, float).tolist()}


def _rig_sigma(d: dict) -> tuple[np.ndarray, float, np.ndarray]:
    return (np.asarray(d.get("t_mm", [np.nan] * 3), float), float(d.get("baseline_mm", np.nan)),
            np.asarray(d.get("opk_arcmin", [np.nan] * 3), float))


def rig_from_dict(doc: dict, source: str = "calib.json") -> RigModel:
    """Validate a calib.json document and build a :class:`RigModel`."""
    try:
        corners = corners_from_dict(doc["corners"], f"{source} corners")
        board = board_from_dict(doc["board"], source)
        common = _lens_model(doc, source)
        cameras, sigma, sigma_formal, rms = {}, {}, {}, {}
        for name, e in doc["cameras"].items():
            size = _image_size(e["image_size"], f"{source}: camera {name!r}")
            model = _camera_lens_model(e, common, f"{source}: camera {name!r}")
            _check_lens_keys(e, model, f"{source}: camera {name!r}")
            cameras[name] = CameraModel(size, **{n: float(e[n]) for n in intrinsic_names(model)}, model=model)
            sigma[name] = {k: float(v) for k, v in e.get("sigma", {}).items()}
            # coefficients outside the model are fixed at 0: sigma 0, as the adjustment gives them
            sigma[name].update({n: 0.0 for n in DISTORTION_NAMES if n not in LENS_MODELS[model]})
            if "sigma_formal" in e:
                sigma_formal[name] = {k: float(v) for k, v in e["sigma_formal"].items()}
                sigma_formal[name].update({n: 0.0 for n in DISTORTION_NAMES if n not in LENS_MODELS[model]})
            rms[name] = float(e.get("rms_px", float("nan")))
        rig = {}
        for name, e in doc["rig"].items():
            formal = dict(zip(("t_mm", "baseline_mm", "opk_arcmin"), _rig_sigma(e["sigma_formal"]))) \
                if "sigma_formal" in e else {}
            rig[name] = RigRelation(_pose_from_dict(e, f"{source}: rig {name!r}"), *_rig_sigma(e.get("sigma", {})),
                                    formal)
        reference = str(doc["reference"])
        if "camera_poses" in doc:
            poses = {cam: {v: _pose_from_dict(p, f"{source}: {cam} {v}") for v, p in d.items()}
                     for cam, d in doc["camera_poses"].items()}
        else:  # a minimal calib.json: derive every camera's pose from the reference's
            ref = {v: _pose_from_dict(p, f"{source}: view {v}") for v, p in doc["views"].items()}
            poses = {reference: ref}
            for name, rel in rig.items():
                poses[name] = {v: rel.pose.compose(p) for v, p in ref.items()}
        view_rms = {v: {c: float(x) for c, x in (p.get("rms_px") or {}).items()}
                    for v, p in doc.get("views", {}).items()}
        focus_models = {name: FocusModel.from_dict(e["focus_model"], e["focus_m"])
                        for name, e in doc["cameras"].items() if "focus_model" in e}
        photo_focus = {name: {v: float(p["focus_m"][name]) for v, p in doc.get("views", {}).items()
                              if name in (p.get("focus_m") or {})} for name in focus_models}
        ois_sigma = {name: float(e["ois_sigma_px"]) for name, e in doc["cameras"].items() if "ois_sigma_px" in e}
        ois_shift = {name: {v: np.asarray(p["ois_shift_px"][name], float) for v, p in doc.get("views", {}).items()
                            if name in (p.get("ois_shift_px") or {})} for name in ois_sigma}
        shape = doc["board"].get("shape_mm")
        shape_sigma = doc["board"].get("shape_sigma_mm", {})
        model = RigModel(board, reference, bool(doc.get("skew", False)), str(doc.get("rig_mode", "rigid")),
                         cameras, sigma, rms, rig, poses, view_rms, float(doc.get("rms_px", np.nan)),
                         corners, doc.get("adjustment", {}), doc.get("dropped_views", []), sigma_formal,
                         None if shape is None else np.array([float(shape[t]) for t in SHAPE_TERMS]),
                         None if shape is None else np.array([float(shape_sigma.get(t, np.nan)) for t in SHAPE_TERMS]),
                         list(doc.get("dropped_corners", [])), _trusted_checks(doc, source), doc.get("covariance"),
                         focus_models, photo_focus, ois_sigma, {n: d for n, d in ois_shift.items() if d})
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise InputError(f"{source}: malformed calib.json ({type(exc).__name__}: {exc})") from None
    _check_consistent(model, source)
    return model


def _lens_model(doc: dict, source: str) -> str:
    """calib.json's ``model``: a lens model or ``mixed``; a file without one (written before lens models)
    is the paper's ``k1k2``."""
    model = doc.get("model", DEFAULT_LENS_MODEL)
    if model not in LENS_MODELS and model != MIXED_LENS_MODELS:
        raise InputError(f"{source}: lens model {model!r} is unknown (dualcal knows {', '.join(LENS_MODELS)})")
    return model


def _camera_lens_model(entry: dict, common: str, what: str) -> str:
    """A camera's ``model``, else the file's common one (files written before cameras had their own)."""
    model = entry.get("model", common)
    if model not in LENS_MODELS:
        raise InputError(f"{what}: lens model {model!r} is unknown (dualcal knows {', '.join(LENS_MODELS)})")
    if common != MIXED_LENS_MODELS and model != common:
        raise InputError(f"{what} has lens model {model}, the file's 'model' says {common} (or 'mixed')")
    return model


def _check_lens_keys(entry: dict, model: str, what: str,
                     named_by: str = "calib.json 'model'; a file without one is k1k2") -> None:
    """Raise :class:`InputError` unless a camera entry has exactly the lens coefficients of ``model`` (which
    ``named_by`` says where the file names)."""
    missing = [n for n in LENS_MODELS[model] if n not in entry]
    if missing:
        raise InputError(f"{what} lacks {', '.join(missing)} of its lens model {model} ({named_by})")
    foreign = [n for n in DISTORTION_NAMES if n in entry and n not in LENS_MODELS[model]]
    if foreign:
        raise InputError(f"{what} has {', '.join(foreign)}, which its lens model {model} does not have ({named_by})")


def _lens_fold_problem(cam: CameraModel, corners: CameraCorners | None) -> str | None:
    """Why the lens cannot be what was calibrated, or None: its radial distortion folds over (stops
    growing with the radius) inside the region its own corners span, where the calibration measured it.
    (A fitted polynomial may fold beyond its data, in the image's corners: undistort refuses that itself.)"""
    rd_max = max_distorted_radius(*cam.radial)
    seen = [uv[np.isfinite(uv).all(axis=1)] for uv in (corners.views.values() if corners else ()) if uv is not None]
    if not seen or not np.isfinite(rd_max):
        return None
    rd_seen = float(np.max(np.linalg.norm(normalized_from_pixel(cam, np.vstack(seen)), axis=1)))
    if rd_seen > rd_max:
        return (f"its lens distortion {tuple(round(float(k), 4) for k in cam.radial)} folds over at normalised "
                f"radius {rd_max:.3g}, inside the {rd_seen:.3g} its own corners reach: not a lens")
    return None


def _is_rotation(R: np.ndarray) -> bool:
    return np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0


def _check_consistent(rig: RigModel, source: str) -> None:
    """Cross-checks of a calib.json that its parts agree (names, board, rotations, focal lengths)."""
    names = set(rig.cameras)
    problems = []
    if rig.reference not in names:
        problems.append(f"reference {rig.reference!r} is not one of the cameras {sorted(names)}")
    if not set(rig.rig) <= names - {rig.reference}:
        problems.append(f"rig entries {sorted(rig.rig)} must be cameras other than the reference")
    if set(rig.corners.cameras) != names:
        problems.append(f"its corners are of cameras {sorted(rig.corners.cameras)}, its intrinsics of {sorted(names)}")
    if rig.board != rig.corners.board:
        problems.append("'board' and 'corners.board' differ")
    bad_f = [n for n, cam in rig.cameras.items() if not (cam.fx > 0 and cam.fy > 0)]
    if bad_f:
        problems.append(f"focal lengths must be positive (cameras {bad_f})")
    problems += [f"camera {name!r}: {p}" for name, cam in rig.cameras.items() if name not in bad_f
                 for p in [_lens_fold_problem(cam, rig.corners.cameras.get(name))] if p]
    poses = [rel.pose for rel in rig.rig.values()] + [p for d in rig.camera_poses.values() for p in d.values()]
    if not all(_is_rotation(p.R) for p in poses):
        problems.append("a rotation matrix R is not orthonormal with determinant +1")
    if problems:
        raise InputError(f"{source}: inconsistent calib.json: {'; '.join(problems)}")


def load_rig(path) -> RigModel:
    """Read a calib.json, checked against its schema and beyond it (finite numbers, rotations that are
    rotations, a lens that does not fold over inside its corners, the checks as the calibration wrote them).

    Parameters
    ----------
    path : str or Path
        The calib.json to read.

    Returns
    -------
    RigModel
        The calibration, with the corners it was computed from.

    Raises
    ------
    InputError
        A missing or unreadable file, or one that breaks a rule (the message names the key).
    """
    return rig_from_dict(_load(path, "calib"), str(path))


def save_rig(path, rig: RigModel) -> None:
    """Write ``rig`` as calib.json, atomically (a temporary file beside it, checked, then renamed).

    Parameters
    ----------
    path : str or Path
        The file to write; its folder must exist.
    rig : RigModel
        The calibration to write.

    Raises
    ------
    OutputError
        The file cannot be written (a full disk, a read-only folder); nothing was replaced.
    """
    write_json_atomic(path, rig_to_dict(rig))


def load_evaluation(path) -> dict:
    return _load(path, "eval")


# ---------------------------------------------------------------------------- intrinsics.json (calibrate --intrinsics)


def intrinsics_to_dict(cameras: dict[str, KnownIntrinsics], poses: dict[str, Pose] | None = None,
                       frame: str | None = None, source: dict | None = None) -> dict:
    """The intrinsics.json document of known intrinsics (its schema: ``dualcal schema intrinsics``).

    Parameters
    ----------
    cameras : dict of str to KnownIntrinsics
        Each camera's lens model and values, with their sigma or covariance where known.
    poses : dict of str to Pose, optional
        Cameras' poses in the source, ``X_cam = R X_frame + t_mm`` (written as each camera's ``extrinsics``).
    frame : str, optional
        What ``X_frame`` is (a camera's name, or the source's world).
    source : dict, optional
        What was imported (``{"format": ..., "paths": [...]}``).

    Returns
    -------
    dict
        The document, contract keys first.
    """
    doc: dict = {"dualcal_version": __version__}
    if source is not None:
        doc["source"] = source
    doc["cameras"] = {}
    for name, known in cameras.items():
        cam = known.camera
        entry = {"model": cam.model, "image_size": list(cam.image_size),
                 **{n: float(getattr(cam, n)) for n in intrinsic_names(cam.model)}}
        if known.sigma:
            entry["sigma"] = {n: float(v) for n, v in known.sigma.items()}
        if known.covariance is not None:
            entry["covariance"] = {"parameters": list(known.parameters),
                                   "matrix": np.asarray(known.covariance, float).tolist()}
        if poses and name in poses:
            entry["extrinsics"] = {"frame": frame or "", **poses[name].to_dict()}
        doc["cameras"][name] = entry
    return doc


def _known_covariance(entry: dict, names: tuple[str, ...], what: str) -> tuple[tuple[str, ...], np.ndarray | None]:
    """A camera entry's ``covariance`` as ``(parameters, (k, k) matrix)``, checked: intrinsics of its lens model,
    symmetric, positive semi-definite."""
    cov = entry.get("covariance")
    if cov is None:
        return (), None
    parameters = tuple(cov["parameters"])
    foreign = [n for n in parameters if n not in names]
    if foreign or len(set(parameters)) != len(parameters):
        raise InputError(f"{what} covariance: its parameters must be distinct intrinsics of its lens model "
                         f"({', '.join(names)}), not {', '.join(foreign) or 'repeated'}")
    k = len(parameters)
    matrix = _finite_array(cov["matrix"], (k, k), f"{what} covariance matrix ({k} parameters)")
    scale = max(float(np.max(np.abs(np.diag(matrix)))), np.finfo(float).tiny)
    if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=1e-12 * scale) \
            or np.min(np.linalg.eigvalsh(0.5 * (matrix + matrix.T))) < -1e-9 * scale:
        raise InputError(f"{what} covariance matrix is not symmetric positive semi-definite: not a covariance")
    return parameters, matrix


def intrinsics_from_dict(doc: dict, source: str = "intrinsics.json") -> dict[str, KnownIntrinsics]:
    """Validate an intrinsics.json document and build each camera's :class:`KnownIntrinsics` (a prior where the
    camera has ``sigma`` or ``covariance``, else fixed).

    Raises
    ------
    InputError
        An unknown lens model, coefficients that are not exactly the model's, a sigma or covariance of names
        that are not its intrinsics, a matrix that is not a covariance.
    """
    out = {}
    for name, e in doc["cameras"].items():
        what = f"{source}: camera {name!r}"
        model = e["model"]
        if model not in LENS_MODELS:
            raise InputError(f"{what}: lens model {model!r} is unknown (dualcal knows {', '.join(LENS_MODELS)})")
        _check_lens_keys(e, model, what, "its 'model'")
        names = intrinsic_names(model)
        sigma = {k: float(v) for k, v in e.get("sigma", {}).items()}
        foreign = [k for k in sigma if k not in names]
        if foreign:
            raise InputError(f"{what}: sigma of {', '.join(foreign)}, which are not intrinsics of its lens model "
                             f"{model} ({', '.join(names)})")
        parameters, covariance = _known_covariance(e, names, what)
        camera = CameraModel(_image_size(e["image_size"], what), float(e["fx"]), float(e["fy"]),
                             float(e.get("skew", 0.0)), float(e["cx"]), float(e["cy"]),
                             **{n: float(e[n]) for n in LENS_MODELS[model]}, model=model)
        prior = bool(sigma) or covariance is not None
        out[str(name)] = KnownIntrinsics(camera, "prior" if prior else "fixed", sigma, parameters, covariance,
                                         source)
    return out


def load_intrinsics(path) -> dict[str, KnownIntrinsics]:
    """Read an intrinsics.json (``dualcal import`` writes them; ``calibrate --intrinsics`` takes them), checked
    against its schema and beyond it.

    Parameters
    ----------
    path : str or Path
        The intrinsics.json to read.

    Returns
    -------
    dict of str to KnownIntrinsics
        Each camera's known intrinsics, a prior where the file gives a sigma or covariance, else fixed.

    Raises
    ------
    InputError
        A missing or unreadable file, or one that breaks a rule (the message names the key).
    """
    return intrinsics_from_dict(_load(path, "intrinsics"), str(path))


def save_intrinsics(path, cameras: dict[str, KnownIntrinsics], poses: dict[str, Pose] | None = None,
                    frame: str | None = None, source: dict | None = None) -> None:
    """Write an intrinsics.json (:func:`intrinsics_to_dict`) atomically.

    Parameters
    ----------
    path : str or Path
        The file to write; its folder must exist.
    cameras, poses, frame, source
        As :func:`intrinsics_to_dict`.

    Raises
    ------
    OutputError
        The file cannot be written (a full disk, a read-only folder); nothing was replaced.
    """
    write_json_atomic(path, intrinsics_to_dict(cameras, poses, frame, source))


# ---------------------------------------------------------------------------- files that belong together

#: The calib.json keys that define a calibration (what is hashed by :func:`calibration_fingerprint`).
FINGERPRINT_KEYS = ("board", "reference", "skew", "rig_mode", "cameras", "rig", "camera_poses", "corners")


def calibration_fingerprint(rig: RigModel) -> str:
    """``"sha256:<hex>"`` of the content of calib.json that defines the calibration.

    The keys :data:`FINGERPRINT_KEYS` of :func:`rig_to_dict`, as canonical JSON (sorted keys, no
    spaces), so the fingerprint does not change when a file is saved again, re-indented or
    written by another dualcal version, and changes with any number of the calibration.
    """
    doc = rig_to_dict(rig)
    text = json.dumps({k: doc[k] for k in FINGERPRINT_KEYS}, sort_keys=True, separators=(",", ":"),
                      allow_nan=False)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def check_evaluation_belongs(rig: RigModel, evaluation: dict, calib_source: str, eval_source: str) -> None:
    """Raise :class:`InputError` unless ``evaluation`` (an eval.json) was computed from ``rig``.

    Compared by :func:`calibration_fingerprint` (eval.json's ``calibration_fingerprint``); an
    eval.json without one (written by hand or by an older dualcal) must at least name only
    cameras of the calibration in its cases.
    """
    stored = evaluation.get("calibration_fingerprint")
    rerun = f"run 'dualcal evaluate {calib_source} -o {eval_source}' again"
    if stored is not None:
        own = calibration_fingerprint(rig)
        if stored != own:
            raise InputError(f"{eval_source} was computed from another calibration than {calib_source} "
                             f"(fingerprint {str(stored)[7:19]}, {calib_source} has {own[7:19]}): {rerun}")
        return
    named = {c for p in evaluation.get("per_pair", []) for c in p.get("cameras", ())}
    named |= {case.split(":", 1)[-1] for case in evaluation.get("cases", {}) if case != "dual"}  # "dual:ultra"
    names = set(rig.cameras)
    foreign = sorted(named - names)
    if foreign:
        raise InputError(f"{eval_source} names cameras {', '.join(foreign)} that {calib_source} does not have "
                         f"(cameras: {', '.join(sorted(names))}): {rerun}")


def check_corners_fit(rig: RigModel, source: str, slack_px: float = 1.0) -> None:
    """Raise :class:`InputError` when the corners calib.json carries do not fit its calibration.

    Each camera's RMS reprojection error over the views it has poses for is recomputed and must
    not exceed ``3 x rms_px + slack_px`` of the ``rms_px`` calib.json states: a calib.json assembled from
    parts of two calibrations (or whose corners were replaced) fails by many pixels. Cameras
    without a stated ``rms_px`` are not checked.
    """
    for name, views in rig_residuals(rig).items():
        stated = rig.camera_rms_px.get(name, np.nan)
        if not np.isfinite(stated) or not views:
            continue
        rms = rms_px(np.vstack([r.residual_px for r in views.values()]))
        if not rms <= 3 * stated + slack_px:
            raise InputError(f"{source}: the corners it carries do not fit its calibration (camera {name!r}: "
                             f"RMS {rms:.3g} px, the file says {stated:.3g} px): it was edited or assembled from "
                             "different calibrations; calibrate again")


# ---------------------------------------------------------------------------- points.json (dualcal measure)


def load_points(path, single_camera: bool = False) -> dict:
    """Read and validate a points.json (:func:`dualcal.estimation.measurement.points_from_dict`; ``single_camera``:
    points may be given in one camera, to be found in the instant's photos)."""
    from ..estimation.measurement import points_from_dict

    return points_from_dict(_load(path, "points"), str(path), single_camera)
