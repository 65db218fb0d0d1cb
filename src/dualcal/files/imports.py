"""Import what peers hand you (``dualcal import``), and read every file ``calibrate --intrinsics`` takes.

=========  ===========================================  ==============================  ==========================
format     file(s)                                      cameras named                   writes
=========  ===========================================  ==============================  ==========================
caliscope  a session folder: ``charuco.toml``,          ``cam_N`` after ``cam_id``      corners.json, and
           ``calibration/{extrinsic|intrinsic}/CHARUCO/                                 intrinsics.json from
           xy_CHARUCO.csv`` (or the csv beside the                                      ``camera_array.toml``
           toml), ``camera_array.toml`` (optional)
opencv     a ``cv2.FileStorage`` YAML, JSON or XML      the map's key; a file of one    intrinsics.json
           (``camera_matrix``/``distortion_coeffici-    camera by its stem; ``M1``,
           ents``, ``cameraMatrix``/``distCoeffs``,     ``M2``: ``cam1``, ``cam2``
           ``M1``/``D1``, ``K``/``D``, dualcal's export)
kalibr     a camchain YAML                              the rostopic's first part       intrinsics.json
                                                        (``/wide/image_raw``), else
                                                        ``camN``
mrcal      ``.cameramodel`` files, one per camera       the file's stem                 intrinsics.json
colmap     ``cameras.txt``                              as dualcal's export names       intrinsics.json
                                                        them, else ``cameraID``
=========  ===========================================  ==============================  ==========================

A peer's lens becomes a dualcal lens model (:data:`dualcal.geometry.camera.LENS_MODELS`) term for term, or is
refused: OpenCV's ``distCoeffs`` (4, 5, 8, 12 or 14 of them; Kalibr's ``radtan``, mrcal's ``LENSMODEL_OPENCV*``,
COLMAP's ``OPENCV``/``FULL_OPENCV`` are the same coefficients) take the smallest radial-tangential model that
holds every coefficient that is not zero (or has a sigma): a coefficient written as exactly 0 was not estimated.
The rational, thin-prism and tilt terms that dualcal has no model for must be 0. A fisheye
(``cv2.fisheye``'s four coefficients, Kalibr's ``equidistant``, COLMAP's ``OPENCV_FISHEYE``) is ``kb4``.
dualcal's own export names its model (``lens_model``), which is then taken as it is.

Every format dualcal exports (:mod:`dualcal.files.export`) reads back to the same parameters, and its poses
(``X_cam = R X_ref + T``) back to the same rig. No peer's format but OpenCV's interactive calibration states
an uncertainty (``cameraMatrix_std_dev``, ``dist_coeffs_std_dev``): its cameras are priors with those
(textbook) sigmas; every other imported camera is held fixed. A calib.json given to ``--intrinsics`` is a prior
with its own sigmas and its covariance's correlations.

caliscope places ChArUco corner ``k = r * cols + c`` at ``((c + 1) s, (r + 1) s)`` (metres), OpenCV's
frame; dualcal's board frame is the same shifted by one square (:mod:`dualcal.geometry.board`), so the ids are
taken as they are; each row's ``obj_loc`` is checked against them. An intrinsic session's ``sync_index``
is no moment shared by the cameras (each filmed the board alone): its cameras say so in corners.json
(``imported.instants_shared: false``), and :func:`dualcal.workflow.calibrate_corners` then calibrates every
camera alone.
"""

from __future__ import annotations

import ast
import csv
import io
import math
import re
import tokenize
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.board import DICTIONARIES, Board, dictionary_name, smallest_dictionary
from ..geometry.camera import FISHEYE_MODELS, LENS_MODELS, CameraModel, intrinsic_names
from ..geometry.model import CameraCorners, CornerSet, KnownIntrinsics, Pose, RigModel
from ..geometry.rotation import rotation_from_rotvec
from ..progress import warn
from .io import (check_output_file, json_kind, load_intrinsics, make_output_folder, read_json, save_corners,
                 save_intrinsics)

__all__ = ["CALISCOPE_SESSIONS", "FORMATS", "Imported", "import_files", "known_from_rig", "python_literal",
           "read_known_intrinsics", "write_imported"]

#: The formats ``dualcal import`` reads.
FORMATS = ("caliscope", "opencv", "kalibr", "mrcal", "colmap")
#: Which of a caliscope session's recordings to import: ``auto`` takes the extrinsic one where there is one.
CALISCOPE_SESSIONS = ("auto", "intrinsic", "extrinsic")

_MM_PER_M = 1000.0
_CM_PER_INCH = 1 / 0.393701       # caliscope's own conversion (``INCHES_PER_CM = 0.393701``), which its boards use


@dataclass
class Imported:
    """What a peer's files hold, in dualcal's terms.

    ``cameras``: each camera's intrinsics (:class:`~dualcal.geometry.model.KnownIntrinsics`); ``poses``: the
    cameras' poses where the source has them, ``X_cam = R X_frame + t_mm`` with ``frame`` naming ``X_frame``
    (a camera, or the source's world); ``corners``: a caliscope session's corners, with ``session`` its
    recordings (``intrinsic`` or ``extrinsic``).
    """

    format: str
    paths: list[str]
    cameras: dict[str, KnownIntrinsics] = field(default_factory=dict)
    poses: dict[str, Pose] = field(default_factory=dict)
    frame: str | None = None
    corners: CornerSet | None = None
    session: str | None = None


# ---------------------------------------------------------------------------- a peer's lens as dualcal's

#: The radial-tangential coefficients of OpenCV's ``distCoeffs``, in its order, then those dualcal has no model
#: for: rational ``k4 k5 k6``, thin prism ``s1 .. s4``, tilt ``tau_x tau_y`` (4, 5, 8, 12 or 14 in all).
_OPENCV_TERMS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
_OPENCV_COUNTS = (0, 4, 5, 8, 12, 14)
_RADTAN_MODELS = [m for m in LENS_MODELS if m not in FISHEYE_MODELS]


def _radtan_values(coefficients, what: str) -> dict[str, float]:
    """``{k1, k2, p1, p2, k3}`` of OpenCV's ``distCoeffs``; its terms beyond those must be 0."""
    c = [float(x) for x in np.ravel(coefficients)]
    if len(c) not in _OPENCV_COUNTS:
        raise InputError(f"{what}: {len(c)} distortion coefficients; OpenCV's model has 4, 5, 8, 12 or 14")
    c += [0.0] * (5 - len(c)) if len(c) < 5 else []
    extra = {n: x for n, x in zip(_OPENCV_TERMS[5:], c[5:]) if x != 0.0}
    if extra:
        raise InputError(f"{what}: its lens has {', '.join(f'{n} = {x:.4g}' for n, x in extra.items())}, a model "
                         f"dualcal does not have (its models: {', '.join(LENS_MODELS)}): calibrate that camera "
                         "with dualcal instead")
    return dict(zip(_OPENCV_TERMS[:5], c[:5]))


def _smallest_radtan_model(needed: set[str]) -> str:
    """The radial-tangential lens model with the fewest coefficients that holds every one of ``needed``."""
    return min((m for m in _RADTAN_MODELS if needed <= set(LENS_MODELS[m])), key=lambda m: len(LENS_MODELS[m]))


def _camera(image_size, K, coefficients, what: str, *, fisheye: bool = False, model: str | None = None,
            sigma: dict[str, float] | None = None) -> CameraModel:
    """The camera of a camera matrix ``K`` (3 x 3) and OpenCV's distortion ``coefficients`` (``cv2.fisheye``'s
    four where ``fisheye``), in the lens model ``model`` where the source names it (dualcal's export), else
    the smallest that holds them (module docstring)."""
    K = np.asarray(K, float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or np.any(K[[1, 2, 2], [0, 0, 1]] != 0.0) \
            or not abs(K[2, 2] - 1.0) < 1e-12 or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"{what}: {np.round(K, 6).tolist()} is not a camera matrix [[fx, skew, cx], [0, fy, cy], "
                         "[0, 0, 1]] with fx, fy > 0")
    if fisheye or model in FISHEYE_MODELS:
        c = np.ravel(coefficients).astype(float)
        if len(c) != 4:
            raise InputError(f"{what}: a fisheye (cv2.fisheye) has 4 distortion coefficients, not {len(c)}")
        values, model = dict(zip(LENS_MODELS["kb4"], c)), "kb4"
    else:
        values = _radtan_values(coefficients, what)
        if model is None:
            needed = {n for n, x in values.items() if x != 0.0 or (sigma or {}).get(n, 0.0) > 0.0}
            model = _smallest_radtan_model(needed)
        elif model not in LENS_MODELS:
            raise InputError(f"{what}: lens model {model!r} is unknown (dualcal knows {', '.join(LENS_MODELS)})")
        foreign = {n: x for n, x in values.items() if n not in LENS_MODELS[model] and x != 0.0}
        if foreign:
            raise InputError(f"{what}: its lens model {model} has no {', '.join(foreign)}, which the file gives")
        values = {n: x for n, x in values.items() if n in LENS_MODELS[model]}
    return CameraModel(image_size, float(K[0, 0]), float(K[1, 1]), float(K[0, 1]), float(K[0, 2]), float(K[1, 2]),
                       **values, model=model)


def _known(camera: CameraModel, source: str, sigma: dict[str, float] | None = None) -> KnownIntrinsics:
    """A camera held fixed, or a prior where ``sigma`` gives the 1-sigma of some of its intrinsics."""
    names = intrinsic_names(camera.model)
    sigma = {n: float(s) for n, s in (sigma or {}).items() if n in names and math.isfinite(s)}
    return KnownIntrinsics(camera, "prior" if sigma else "fixed", sigma, source=source)


def _size(value, what: str) -> tuple[int, int]:
    w, h = (float(x) for x in np.ravel(value))
    if not (w > 0 and h > 0 and w == round(w) and h == round(h)):
        raise InputError(f"{what}: image size {w:g} x {h:g} is not two positive whole numbers")
    return int(w), int(h)


# ---------------------------------------------------------------------------- OpenCV FileStorage

_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "camMat", "M", "K")
_DISTORTION_KEYS = ("distortion_coefficients", "distCoeffs", "dist_coeffs", "D")
_CAMERA_KEY = re.compile(rf"^({'|'.join(_MATRIX_KEYS)})(\d*)$")


def _node_array(node) -> np.ndarray | None:
    """A FileStorage node as an array: an ``!!opencv-matrix``, a map of ``rows``, ``cols``, ``data`` (ROS's
    camera_info), a sequence of numbers, or a number; None where it is none of these."""
    if node is None or node.empty() or node.isNone():
        return None
    if node.isMap() and not node.getNode("data").empty():
        data = _node_array(node.getNode("data"))
        rows, cols = node.getNode("rows").real(), node.getNode("cols").real()
        return data.reshape(int(rows), int(cols)) if data is not None and rows and cols else data
    if node.isSeq():
        values = [node.at(i) for i in range(node.size())]
        if all(v.isReal() or v.isInt() for v in values):
            return np.array([v.real() for v in values])
        return None
    if node.isReal() or node.isInt():
        return np.array(node.real())
    mat = node.mat()
    return None if mat is None else np.asarray(mat, float)


def _opencv_camera(node, suffix: str, name: str, path: Path, image_size) -> KnownIntrinsics | None:
    """The camera whose matrix and distortion are keys of the map ``node`` (``M`` + ``suffix``, ``D`` + ``suffix``,
    ...: :data:`_MATRIX_KEYS`, :data:`_DISTORTION_KEYS`), or None where it holds none."""
    def get(key):
        return _node_array(node.getNode(key))

    def text(key):
        n = node.getNode(key)
        return n.string() if n.isString() else None

    K = next((a for a in (get(k + suffix) for k in _MATRIX_KEYS) if a is not None and a.size == 9), None)
    if K is None:
        return None
    what = f"{path}: camera {name!r}"
    D = next((a for a in (get(k + suffix) for k in _DISTORTION_KEYS) if a is not None), np.zeros(0))
    lens_model = text("lens_model")                                 # dualcal's export names it
    flag = get("fisheye_model")                                     # OpenCV's calibration tutorial
    fisheye = (lens_model in FISHEYE_MODELS or (flag is not None and flag != 0)
               or (text("distortion_model") or "").lower() in ("equidistant", "fisheye")     # ROS camera_info
               or (lens_model is None and get("K" + suffix) is not None and np.size(D) == 4))  # cv2.fisheye's K, D
    width, height = get("image_width"), get("image_height")
    found = np.array([width, height]) if width is not None and height is not None else next(
        (a for a in (get(k) for k in ("cameraResolution", "image_size", "imageSize", "resolution"))
         if a is not None and a.size == 2), None)
    size = _given_size(None if found is None else _size(found, what), image_size, name, what)
    sigma = {}
    std_K, std_D = get("cameraMatrix_std_dev"), get("dist_coeffs_std_dev")    # OpenCV's interactive calibration
    if std_K is not None and std_K.size >= 4:
        sigma.update(zip(("fx", "fy", "cx", "cy"), std_K.ravel()[:4]))
        if sigma["fx"] == 0.0 and sigma["fy"] > 0.0:
            # a fixed aspect ratio: fx follows fy, so OpenCV gives it no sigma of its own (fx = ratio * fy)
            sigma["fx"] = sigma["fy"] * K.flat[0] / K.flat[4]
    if std_D is not None:
        sigma.update(zip(LENS_MODELS["kb4"] if fisheye else _OPENCV_TERMS[:5], std_D.ravel()))
    camera = _camera(size, K.reshape(3, 3), D, what, fisheye=fisheye, model=lens_model, sigma=sigma)
    return _known(camera, str(path), sigma)


def _given_size(found, image_size: dict | None, name: str, what: str) -> tuple[int, int]:
    """A camera's image size: the file's (``found``), else the one given for it (or for every camera, ``"*"``)."""
    given = (image_size or {}).get(name, (image_size or {}).get("*"))
    if found is not None and given is not None and tuple(given) != tuple(found):
        raise InputError(f"{what}: the image size given, {given[0]} x {given[1]}, is not the file's "
                         f"{found[0]} x {found[1]}")
    if found is None and given is None:
        raise InputError(f"{what}: the file does not give the image size: give it (--image-size WxH)")
    return tuple(int(x) for x in (found if found is not None else given))


def read_opencv(path: Path, image_size: dict | None = None) -> Imported:
    """The cameras of an OpenCV FileStorage file (YAML, JSON or XML; module docstring).

    Top-level keys ``M``/``K``/``camera_matrix``/``cameraMatrix``/``camMat`` with ``D``/``distCoeffs``/
    ``dist_coeffs``/``distortion_coefficients`` are one camera, named after the file; with a number after them
    (``M1``, ``D1``, ``M2``, ``D2``), one camera per number, ``cam1``, ``cam2``; a top-level map holding them is
    a camera named by its key (dualcal's export: the camera's name, and its ``R``, ``T``, mm, as poses from
    the reference). The image size is ``image_width``/``image_height``, ``cameraResolution`` or ``image_size``,
    else ``image_size[name]`` (or ``["*"]``).
    """
    import cv2

    from .export import _opencv_key

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as exc:
        # OpenCV says "... in function '<path>(<line>): <what>'": keep the line and what
        where = re.search(r"\((\d+)\): ([^']*)'?\s*$", str(exc.__cause__ or exc))
        raise InputError(f"{path}: not an OpenCV FileStorage file (YAML, JSON or XML)"
                         + (f": line {where.group(1)}: {where.group(2)}" if where else "")) from None
    if not opened:
        raise InputError(f"{path}: not an OpenCV FileStorage file (YAML, JSON or XML)")
    try:
        root, listed, reference = fs.root(), fs.getNode("cameras"), fs.getNode("reference")
        exported = listed.isSeq() and reference.isString()          # dualcal's export: names, poses in mm
        names_by_key = {_opencv_key(n): n for n in (listed.at(i).string() for i in range(listed.size()))} \
            if exported else {}
        cameras, poses = {}, {}
        for key in root.keys():
            node = fs.getNode(key)
            known = _opencv_camera(node, "", names_by_key.get(key, key), path, image_size) if node.isMap() else None
            if known is not None:
                name = names_by_key.get(key, key)
                cameras[name] = known
                R, T = _node_array(node.getNode("R")), _node_array(node.getNode("T"))
                if exported and R is not None and T is not None:
                    poses[name] = Pose(R.reshape(3, 3), T.reshape(3))
                continue
            m = _CAMERA_KEY.match(key)
            name = (f"cam{m.group(2)}" if m.group(2) else path.stem) if m else None
            if m and name not in cameras:
                known = _opencv_camera(root, m.group(2), name, path, image_size)
                if known is not None:
                    cameras[name] = known
        frame = reference.string() if exported and poses else None
    finally:
        fs.release()
    if not cameras:
        raise InputError(f"{path}: no camera matrix with its distortion coefficients found (looked for "
                         "camera_matrix/distortion_coefficients, cameraMatrix/distCoeffs, M1/D1, K/D)")
    return Imported("opencv", [str(path)], cameras, poses, frame)


# ---------------------------------------------------------------------------- Kalibr


def read_kalibr(path: Path) -> Imported:
    """The cameras of a Kalibr camchain YAML (``cam0``, ``cam1``, ...: ``camera_model: pinhole``,
    ``distortion_model`` ``radtan``, ``equidistant`` or ``none``, ``intrinsics: [fu, fv, pu, pv]``,
    ``distortion_coeffs``, ``resolution``), and the chain's poses from ``cam0`` composed of ``T_cn_cnm1``
    (metres, as mm). Each camera is named by the first part of its ``rostopic`` (``/wide/image_raw``: ``wide``;
    dualcal's export writes the camera's name there, a ``-`` as ``_``) where those are distinct, else by its key."""
    from ..extras import require

    require("kalibr")
    import yaml

    text = _read_text(path)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not a YAML file ({str(exc).splitlines()[0][:100]})") from None
    keys = sorted((k for k in (doc or {}) if re.fullmatch(r"cam\d+", str(k))), key=lambda k: int(k[3:])) \
        if isinstance(doc, dict) else []
    if not keys:
        raise InputError(f"{path}: no cam0, cam1, ... of a Kalibr camchain in it")
    topics = [str(doc[k].get("rostopic", "") if isinstance(doc[k], dict) else "").strip("/").split("/")[0]
              for k in keys]
    names = topics if all(topics) and len(set(topics)) == len(topics) else keys
    cameras, poses = {}, {}
    pose = Pose(np.eye(3), np.zeros(3))
    for i, (key, name) in enumerate(zip(keys, names)):
        e, what = doc[key], f"{path}: {key}"
        try:
            if e.get("camera_model", "pinhole") != "pinhole":
                raise InputError(f"{what}: camera model {e['camera_model']!r}: dualcal has the pinhole one only "
                                 f"(its lens models: {', '.join(LENS_MODELS)})")
            distortion = e.get("distortion_model", "none")
            if distortion not in ("radtan", "equidistant", "none"):
                raise InputError(f"{what}: distortion model {distortion!r} is none of dualcal's (radtan, equidistant "
                                 "or none)")
            fu, fv, pu, pv = (float(x) for x in e["intrinsics"])
            coefficients = [float(x) for x in e.get("distortion_coeffs", [])] if distortion != "none" else []
            K = [[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]]
            camera = _camera(_size(e["resolution"], what), K, coefficients, what,
                             fisheye=distortion == "equidistant")
            if i:
                T = np.asarray(e["T_cn_cnm1"], float)
                pose = Pose(T[:3, :3], T[:3, 3] * _MM_PER_M).compose(pose)
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            raise InputError(f"{what}: malformed camchain entry ({type(exc).__name__}: {exc})") from None
        cameras[name] = _known(camera, str(path))
        poses[name] = pose
    return Imported("kalibr", [str(path)], cameras, poses, names[0])


# ---------------------------------------------------------------------------- mrcal

#: mrcal's lens models dualcal has, and how many distortion coefficients follow fx, fy, cx, cy.
_MRCAL_MODELS = {"LENSMODEL_PINHOLE": 0, "LENSMODEL_OPENCV4": 4, "LENSMODEL_OPENCV5": 5, "LENSMODEL_OPENCV8": 8,
                 "LENSMODEL_OPENCV12": 12}


def python_literal(text: str, what: str):
    """The Python literal ``text`` holds, its comments stripped (by Python's own tokenizer: a ``#`` inside a
    string stays)."""
    try:
        tokens = [t for t in tokenize.generate_tokens(io.StringIO(text).readline) if t.type != tokenize.COMMENT]
        return ast.literal_eval(tokenize.untokenize(tokens))
    except (tokenize.TokenError, SyntaxError, ValueError, MemoryError, RecursionError) as exc:
        raise InputError(f"{what}: not a Python literal, as a .cameramodel is ({type(exc).__name__})") from None


def read_mrcal(paths: list[Path]) -> Imported:
    """The cameras of mrcal ``.cameramodel`` files (``lensmodel``, ``intrinsics = [fx, fy, cx, cy, ...]``,
    ``imagersize``, ``extrinsics = rt_cam_ref``: a rotation vector and a translation, metres, as mm), one per
    file, each named by the file's stem. The poses' frame is the camera whose extrinsics are zero, where
    exactly one is (dualcal's export: the reference)."""
    cameras, poses = {}, {}
    for path in paths:
        what = f"{path}"
        doc = python_literal(_read_text(path), what)
        if not isinstance(doc, dict) or "lensmodel" not in doc or "intrinsics" not in doc:
            raise InputError(f"{what}: not an mrcal .cameramodel (a dict with lensmodel and intrinsics)")
        lensmodel = str(doc["lensmodel"])
        if lensmodel not in _MRCAL_MODELS:
            raise InputError(f"{what}: mrcal's {lensmodel} is none of dualcal's lens models (it reads "
                             f"{', '.join(_MRCAL_MODELS)})")
        try:
            values = [float(x) for x in doc["intrinsics"]]
            if len(values) != 4 + _MRCAL_MODELS[lensmodel]:
                raise ValueError(f"{len(values)} intrinsics for {lensmodel}")
            fx, fy, cx, cy = values[:4]
            camera = _camera(_size(doc["imagersize"], what), [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                             values[4:], what)
            rt = np.asarray(doc.get("extrinsics", np.zeros(6)), float).reshape(6)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{what}: malformed .cameramodel ({type(exc).__name__}: {exc})") from None
        name = path.stem
        if name in cameras:
            raise InputError(f"{what}: a second camera named {name!r} (each file's stem names its camera)")
        cameras[name] = _known(camera, str(path))
        poses[name] = Pose(rotation_from_rotvec(rt[:3]), rt[3:] * _MM_PER_M)
    at_origin = [n for n, p in poses.items() if np.all(p.R == np.eye(3)) and np.all(p.t_mm == 0.0)]
    frame = at_origin[0] if len(at_origin) == 1 else "mrcal reference"
    return Imported("mrcal", [str(p) for p in paths], cameras, poses, frame)


# ---------------------------------------------------------------------------- COLMAP

#: COLMAP's camera models dualcal has: their parameters after WIDTH HEIGHT, in dualcal's names (``f`` is fx = fy).
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
_DUALCAL_COLMAP_NAMES = re.compile(r"^# dualcal [^:]*: (.*?); principal point")


def read_colmap(path: Path) -> Imported:
    """The cameras of a COLMAP ``cameras.txt`` (``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...``; the models of
    :data:`_COLMAP_MODELS`), the principal point moved by -0.5 px from COLMAP's pixel convention to dualcal's.
    Cameras are named as dualcal's export lists them (``# dualcal ...: 1 = wide, 2 = tele; ...``), else
    ``camera<ID>``."""
    lines = _read_text(path).splitlines()
    listed = {}
    for line in lines:
        m = _DUALCAL_COLMAP_NAMES.match(line)
        if m:
            listed = dict(re.findall(r"(\d+) = (.*?)(?=, \d+ = |$)", m.group(1)))
    cameras = {}
    for number, line in enumerate(lines, 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        what = f"{path}: line {number}"
        if len(words) < 4:
            raise InputError(f"{what}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...")
        ident, model = words[0], words[1]
        if model not in _COLMAP_MODELS:
            raise InputError(f"{what}: COLMAP's {model} is none of dualcal's lens models (it reads "
                             f"{', '.join(_COLMAP_MODELS)})")
        try:
            values = dict(zip(_COLMAP_MODELS[model], (float(x) for x in words[4:])))
            if len(words) - 4 != len(_COLMAP_MODELS[model]):
                raise ValueError(f"{len(words) - 4} parameters for {model}")
            size = _size([float(words[2]), float(words[3])], what)
        except ValueError as exc:
            raise InputError(f"{what}: malformed ({exc})") from None
        fx, fy = values.get("fx", values.get("f")), values.get("fy", values.get("f"))
        K = [[fx, 0.0, values["cx"] - 0.5], [0.0, fy, values["cy"] - 0.5], [0.0, 0.0, 1.0]]
        fisheye = model == "OPENCV_FISHEYE"
        terms = LENS_MODELS["kb4"] if fisheye else _OPENCV_TERMS[:8]
        coefficients = [values.get(n, 0.0) for n in terms]
        name = listed.get(ident, f"camera{ident}")
        cameras[name] = _known(_camera(size, K, coefficients, what, fisheye=fisheye), str(path))
    if not cameras:
        raise InputError(f"{path}: no camera in it (COLMAP's cameras.txt: CAMERA_ID MODEL WIDTH HEIGHT PARAMS...)")
    return Imported("colmap", [str(path)], cameras)


# ---------------------------------------------------------------------------- caliscope

_CSV = "xy_CHARUCO.csv"


def _caliscope_csv(folder: Path, session: str) -> tuple[Path, str]:
    """The session's corners file and which recordings it holds (``intrinsic`` or ``extrinsic``)."""
    laid_out = {s: folder / "calibration" / s / "CHARUCO" / _CSV for s in ("extrinsic", "intrinsic")}
    for s in (("extrinsic", "intrinsic") if session == "auto" else (session,)):
        if laid_out[s].is_file():
            return laid_out[s], s
    if (folder / _CSV).is_file():
        # the folder does not say: intrinsic, where nothing is assumed shared by the cameras, unless told
        return folder / _CSV, "intrinsic" if session == "auto" else session
    where = " or ".join(str(p.relative_to(folder)) for s, p in laid_out.items() if session in ("auto", s))
    raise InputError(f"{folder}: no {where} (nor {_CSV} beside its charuco.toml): not a caliscope session with "
                     "ChArUco corners")


def _toml(path: Path) -> dict:
    try:
        return tomllib.loads(_read_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: malformed TOML ({exc})") from None


def caliscope_board(doc: dict, source: str) -> tuple[Board, bool]:
    """The ChArUco board of a caliscope ``charuco.toml`` and whether it is printed colour-inverted.

    ``columns`` x ``rows`` squares; the square ``square_size_override_cm`` where given, else the largest that
    fits ``board_height`` x ``board_width`` (in ``units``, ``inch`` or ``cm``), as caliscope sizes it; the
    marker ``aruco_scale`` of the square; ``legacy_pattern`` OpenCV's legacy layout; a dictionary too small for
    the board's markers is taken in its family's size that holds them, as caliscope does.
    """
    try:
        cols, rows = int(doc["columns"]), int(doc["rows"])
        square_cm = doc.get("square_size_override_cm") or doc.get("square_size_overide_cm")
        if not square_cm:
            scale = _CM_PER_INCH if doc.get("units", "inch") == "inch" else 1.0
            square_cm = min(float(doc["board_height"]) * scale / rows, float(doc["board_width"]) * scale / cols)
        square_mm = 10.0 * float(square_cm)
        marker_mm = square_mm * float(doc.get("aruco_scale", 0.75))
        name = dictionary_name(doc.get("dictionary", "DICT_4X4_50"))
        n_markers = cols * rows // 2
        if DICTIONARIES[name][1] < n_markers:
            name = smallest_dictionary(name, n_markers)
        board = Board.charuco_board((cols, rows), square_mm, marker_mm, name, bool(doc.get("legacy_pattern", False)))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{source}: not a caliscope ChArUco board ({type(exc).__name__}: {exc}): needs columns, "
                         "rows and square_size_override_cm (or board_height and board_width)") from None
    return board, bool(doc.get("inverted", False))


def _caliscope_cameras(doc: dict, source: str) -> tuple[dict[str, KnownIntrinsics], dict[str, Pose],
                                                         dict[str, tuple[int, int]]]:
    """A ``camera_array.toml``'s cameras (``[cameras.N]``: ``size``, ``matrix``, ``distortions``, ``fisheye``,
    ``rotation`` as a rotation vector or 3 x 3, ``translation`` in metres, world to camera), their poses in
    caliscope's world, and every camera's image size (a camera without intrinsics yet has one too)."""
    entries = doc.get("cameras") or {k.removeprefix("cam_"): v for k, v in doc.items() if re.fullmatch(r"cam_\d+", k)}
    cameras, poses, sizes = {}, {}, {}
    for key, e in sorted(entries.items(), key=lambda kv: int(kv[0]) if str(kv[0]).isdigit() else -1):
        name, what = f"cam_{key}", f"{source}: camera {key}"
        try:
            if "size" in e:
                sizes[name] = _size(e["size"], what)
            if e.get("matrix") in (None, "null"):
                warn(f"{what} has no intrinsics yet: left out of intrinsics.json")
                continue
            camera = _camera(sizes[name], e["matrix"], e.get("distortions") or [], what,
                             fisheye=bool(e.get("fisheye", False)))
            rotation, translation = e.get("rotation"), e.get("translation")
            if rotation not in (None, "null") and translation not in (None, "null"):
                R = np.asarray(rotation, float)
                R = rotation_from_rotvec(R.reshape(3)) if R.size == 3 else R.reshape(3, 3)
                poses[name] = Pose(R, np.asarray(translation, float).reshape(3) * _MM_PER_M)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{what}: malformed camera ({type(exc).__name__}: {exc})") from None
        cameras[name] = _known(camera, source)
    return cameras, poses, sizes


def _column(header: list[str], names: tuple[str, ...], source: str) -> int:
    for n in names:
        if n in header:
            return header.index(n)
    raise InputError(f"{source}: no column {' or '.join(names)} (caliscope's columns: sync_index, cam_id, "
                     "keypoint_id, img_loc_x, img_loc_y, obj_loc_x, obj_loc_y, ...)")


def caliscope_corners(path: Path, board: Board) -> dict[str, dict[int, np.ndarray]]:
    """The corners of a caliscope ``xy_CHARUCO.csv``: ``{cam_N: {sync_index: (n_corners, 2) px}}``, NaN rows for
    the corners not found; each row's ``obj_loc`` (metres, where given) is checked against its corner's place on
    ``board`` in caliscope's frame, ``((c + 1) s, (r + 1) s)``."""
    source = str(path)
    rows = list(csv.reader(io.StringIO(_read_text(path))))
    if not rows:
        raise InputError(f"{source}: empty")
    header = [h.strip() for h in rows[0]]
    at = {k: _column(header, names, source) for k, names in (
        ("sync", ("sync_index",)), ("cam", ("cam_id", "port")), ("id", ("keypoint_id", "point_id")),
        ("u", ("img_loc_x",)), ("v", ("img_loc_y",)))}
    obj = [header.index(n) if n in header else None for n in ("obj_loc_x", "obj_loc_y")]
    s_m = board.square_mm / _MM_PER_M
    out: dict[str, dict[int, np.ndarray]] = {}
    for number, row in enumerate(rows[1:], 2):
        if not row:
            continue
        try:
            sync, cam, k = int(row[at["sync"]]), int(row[at["cam"]]), int(row[at["id"]])
            u, v = float(row[at["u"]]), float(row[at["v"]])
            xy = [float(row[i]) if i is not None and row[i].strip() else math.nan for i in obj]
        except (ValueError, IndexError):
            raise InputError(f"{source}: line {number}: malformed ({','.join(row)[:80]})") from None
        if not 0 <= k < board.n_corners:
            raise InputError(f"{source}: line {number}: corner {k} is not one of the {board.n_corners} of the "
                             f"board {board.describe(sizes=True)} its charuco.toml describes")
        r, c = divmod(k, board.cols)
        expected = np.array([(c + 1) * s_m, (r + 1) * s_m])
        if np.any(np.abs(np.array(xy) - expected) > 1e-6 + 1e-4 * np.abs(expected)):    # NaN (not given) passes
            raise InputError(f"{source}: line {number}: corner {k} at ({xy[0]:.6g}, {xy[1]:.6g}) m, where the board "
                             f"of its charuco.toml has it at ({expected[0]:.6g}, {expected[1]:.6g}) m: the "
                             "charuco.toml is not the board of these corners")
        if not (math.isfinite(u) and math.isfinite(v)):
            raise InputError(f"{source}: line {number}: the corner's pixel ({u}, {v}) is not finite")
        view = out.setdefault(f"cam_{cam}", {}).setdefault(sync, np.full((board.n_corners, 2), np.nan))
        if np.isfinite(view[k, 0]):
            raise InputError(f"{source}: line {number}: corner {k} of cam_{cam} at sync_index {sync} a second time")
        view[k] = u, v
    if not out:
        raise InputError(f"{source}: no corners in it")
    return out


def read_caliscope(folder: Path, session: str = "auto", image_size: dict | None = None) -> Imported:
    """A caliscope session folder (module docstring): its corners as a :class:`CornerSet` (cameras ``cam_N``,
    instants the ``sync_index``, zero-padded), and its ``camera_array.toml``'s cameras where it has one.

    Parameters
    ----------
    folder : Path
        The session: ``charuco.toml``, ``calibration/{extrinsic|intrinsic}/CHARUCO/xy_CHARUCO.csv`` (or
        ``xy_CHARUCO.csv`` beside the toml), ``camera_array.toml`` (optional).
    session : str
        ``auto`` (the extrinsic recordings where there are some, else the intrinsic ones; a csv beside the toml
        is taken as intrinsic), ``intrinsic`` or ``extrinsic``.
    image_size : dict, optional
        ``{camera: (W, H)}`` or ``{"*": (W, H)}``, for cameras that ``camera_array.toml`` does not give.

    Returns
    -------
    Imported
        Its corners, session, and cameras with their poses in caliscope's world.

    Raises
    ------
    InputError
        A missing file, a malformed one, corners that are not of the board, an image size not known or that
        the corners overflow.
    """
    if session not in CALISCOPE_SESSIONS:
        raise InputError(f"session {session!r} is not one of {', '.join(CALISCOPE_SESSIONS)}")
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder (a caliscope session is a folder with its charuco.toml)")
    if not (folder / "charuco.toml").is_file():
        raise InputError(f"{folder}: no charuco.toml, which describes a caliscope session's board")
    board, inverted = caliscope_board(_toml(folder / "charuco.toml"), str(folder / "charuco.toml"))
    csv_path, session = _caliscope_csv(folder, session)
    array_path = folder / "camera_array.toml"
    cameras, poses, sizes = (_caliscope_cameras(_toml(array_path), str(array_path)) if array_path.is_file()
                             else ({}, {}, {}))
    found = caliscope_corners(csv_path, board)
    width = max(4, len(str(max(max(v) for v in found.values()))))
    corner_cameras = {}
    for name in sorted(found, key=lambda n: int(n[4:])):
        what = f"{csv_path}: {name}"
        if name not in sizes and name not in (image_size or {}) and "*" not in (image_size or {}):
            raise InputError(f"{what}: the image size is not in the csv, and {array_path} "
                             f"{'does not give it' if array_path.is_file() else 'is not there'}: give it "
                             "(--image-size WxH, e.g. 1280x720)")
        size = _given_size(sizes.get(name), image_size, name, what)
        views = {f"{sync:0{width}d}": uv for sync, uv in sorted(found[name].items())}
        _check_inside(views, size, what)
        meta = {"imported": {"format": "caliscope", "session": session, "instants_shared": session == "extrinsic",
                             "cam_id": int(name[4:]), "board_inverted": inverted}}
        corner_cameras[name] = CameraCorners(size, views, meta)
    return Imported("caliscope", [str(folder)], cameras, poses, "caliscope world" if poses else None,
                    CornerSet(board, corner_cameras), session)


def _check_inside(views: dict[str, np.ndarray], size: tuple[int, int], what: str) -> None:
    """Raise :class:`InputError` when a corner lies outside the image of ``size`` (a wrong image size)."""
    uv = np.vstack(list(views.values()))
    uv = uv[np.isfinite(uv[:, 0])]
    w, h = size
    outside = (uv[:, 0] < -0.5) | (uv[:, 0] > w - 0.5) | (uv[:, 1] < -0.5) | (uv[:, 1] > h - 0.5)
    if outside.any():
        u, v = uv[outside][0]
        raise InputError(f"{what}: a corner at ({u:.1f}, {v:.1f}) px lies outside its {w} x {h} image: the image "
                         "size is not that of these corners")


# ---------------------------------------------------------------------------- import, write, read back


def _read_text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, expected a file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def _renamed(imported: Imported, rename: dict[str, str]) -> Imported:
    """``imported`` with cameras renamed ``{old: new}``."""
    names = set(imported.cameras) | set(imported.corners.cameras if imported.corners else ())
    unknown = sorted(set(rename) - names)
    if unknown:
        raise InputError(f"no camera {', '.join(map(repr, unknown))} to rename (cameras: {', '.join(sorted(names))})")
    new = [rename.get(n, n) for n in names]
    if len(set(new)) != len(new):
        raise InputError(f"renaming {rename} gives two cameras one name")

    def keyed(d):
        return {rename.get(k, k): v for k, v in d.items()}

    corners = imported.corners
    if corners is not None:
        corners = replace(corners, cameras=keyed(corners.cameras))
    return replace(imported, cameras=keyed(imported.cameras), poses=keyed(imported.poses),
                   frame=rename.get(imported.frame, imported.frame), corners=corners)


def import_files(fmt: str, paths, *, image_size: dict | None = None, session: str = "auto",
                 rename: dict[str, str] | None = None) -> Imported:
    """Read a peer's calibration or session (module docstring) in dualcal's terms.

    Parameters
    ----------
    fmt : str
        One of :data:`FORMATS`.
    paths : list of str or Path
        The session folder (caliscope), the file (opencv, kalibr, colmap), or the files (mrcal, one per camera).
    image_size : dict, optional
        ``{camera: (W, H)}`` or ``{"*": (W, H)}``: the image size of cameras the files do not give it for.
    session : str
        caliscope: ``auto``, ``intrinsic`` or ``extrinsic`` (:func:`read_caliscope`).
    rename : dict, optional
        ``{name: new name}`` of cameras.

    Returns
    -------
    Imported
        The cameras' intrinsics (held fixed, or a prior where the file gives sigmas), their poses where the
        files give them, a caliscope session's corners.

    Raises
    ------
    InputError
        An unknown format, a missing or malformed file, a lens model dualcal does not have, an image size not
        known.
    """
    if fmt not in FORMATS:
        raise InputError(f"format {fmt!r} is unknown (dualcal imports {', '.join(FORMATS)})")
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError(f"no {fmt} file given")
    for path in paths:
        if not path.exists():
            raise InputError(f"{path}: no such file or folder")
    if fmt != "mrcal" and len(paths) > 1:
        raise InputError(f"{fmt}: one {'session folder' if fmt == 'caliscope' else 'file'} at a time "
                         f"({len(paths)} given); only mrcal takes several, one per camera")
    if fmt != "caliscope" and paths[0].is_dir():
        raise InputError(f"{paths[0]}: a folder; {fmt} imports a file")
    if fmt == "caliscope":
        imported = read_caliscope(paths[0], session, image_size)
    elif fmt == "opencv":
        imported = read_opencv(paths[0], image_size)
    elif fmt == "kalibr":
        imported = read_kalibr(paths[0])
    elif fmt == "mrcal":
        imported = read_mrcal(paths)
    else:
        imported = read_colmap(paths[0])
    return _renamed(imported, rename) if rename else imported


def write_imported(imported: Imported, folder) -> list[Path]:
    """Write ``folder/corners.json`` (a caliscope session's corners) and ``folder/intrinsics.json`` (the cameras'
    intrinsics, their poses as ``extrinsics``), atomically; ``folder`` is created if its parent exists.

    Parameters
    ----------
    imported : Imported
        What :func:`import_files` read.
    folder : str or Path
        The folder to write into.

    Returns
    -------
    list of Path
        The files written.
    """
    folder = make_output_folder(folder)
    files = []
    if imported.corners is not None:
        files.append((check_output_file(folder / "corners.json"), lambda p: save_corners(p, imported.corners)))
    if imported.cameras:
        source = {"format": imported.format, "paths": imported.paths}
        files.append((check_output_file(folder / "intrinsics.json"),
                      lambda p: save_intrinsics(p, imported.cameras, imported.poses, imported.frame, source)))
    for path, write in files:
        write(path)
    return [path for path, _ in files]


def known_from_rig(rig: RigModel, source: str) -> dict[str, KnownIntrinsics]:
    """Each camera of a calibration as a prior: its intrinsics with their 1-sigma (calib.json's ``sigma``, the
    one that holds on real photos) and, where calib.json has the joint covariance, the correlations of the
    camera's intrinsics (its clustered covariance's block, scaled to those sigmas), and the corners it calibrated
    the camera from (``photos``). The correlations between cameras are not kept."""
    from ..estimation.covariance import JointCovariance

    covariance = JointCovariance.from_dict(rig.covariance, source) if rig.covariance else None
    used = rig.used_corners().cameras if rig.corners is not None else {}
    out = {}
    for name, cam in rig.cameras.items():
        names = intrinsic_names(cam.model)
        sigma = {n: float(s) for n, s in rig.camera_sigma.get(name, {}).items() if n in names and math.isfinite(s)}
        parameters, matrix = (), None
        free = [n for n in names if covariance is not None and covariance.has([f"{name}.{n}"]) and sigma.get(n, 0) > 0]
        if free:
            block = covariance.block([f"{name}.{n}" for n in free], "clustered")
            d = np.sqrt(np.clip(np.diag(block), np.finfo(float).tiny, None))
            s = np.array([sigma[n] for n in free])
            parameters, matrix = tuple(free), block / np.outer(d, d) * np.outer(s, s)
        use = "prior" if sigma or matrix is not None else "fixed"
        photos = {v: np.asarray(uv, float) for v, uv in used[name].views.items() if uv is not None} if name in used else {}
        out[name] = KnownIntrinsics(cam, use, sigma, parameters, matrix, source, photos)
    return out


def _format_of(path: Path) -> str:
    """The format of a file of known intrinsics: ``dualcal`` (a calib.json or intrinsics.json), or one of
    :data:`FORMATS` but caliscope, by its suffix and content."""
    suffix = path.suffix.lower()
    if suffix == ".cameramodel":
        return "mrcal"
    if suffix == ".txt":
        return "colmap"
    text = _read_text(path)
    if text.lstrip().startswith(("%YAML", "<?xml")) or "!!opencv-matrix" in text:
        return "opencv"
    if suffix == ".json":
        return "dualcal" if json_kind(read_json(path)) in ("calib", "intrinsics") else "opencv"
    if suffix in (".yml", ".yaml", ".xml"):
        return "kalibr" if re.search(r"^cam\d+\s*:", text, re.M) else "opencv"
    if "lensmodel" in text and text.lstrip().startswith(("{", "#")):
        return "mrcal"
    raise InputError(f"{path}: cannot tell its format (a calib.json, an intrinsics.json, OpenCV's .yml/.json/.xml, "
                     "a Kalibr camchain .yaml, an mrcal .cameramodel or COLMAP's cameras.txt)")


def read_known_intrinsics(path) -> dict[str, KnownIntrinsics]:
    """Every camera's known intrinsics in a file ``calibrate --intrinsics`` takes.

    A calib.json (each camera a prior with its sigmas, :func:`known_from_rig`), an intrinsics.json (as it says:
    :func:`dualcal.files.io.load_intrinsics`), or a peer's file read directly (:func:`import_files`: OpenCV's
    ``.yml``/``.json``/``.xml``, a Kalibr camchain ``.yaml``, an mrcal ``.cameramodel``, COLMAP's
    ``cameras.txt``), told apart by suffix and content.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict of str to KnownIntrinsics
        By camera name.

    Raises
    ------
    InputError
        A missing file, a folder (a caliscope session is imported first), a format it cannot tell, and every
        refusal of the readers.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder; give a file of intrinsics (a caliscope session: 'dualcal import "
                         "caliscope' it first, then give its intrinsics.json)")
    if not path.exists():
        raise InputError(f"{path}: no such file")
    fmt = _format_of(path)
    if fmt == "dualcal":
        doc = read_json(path)
        if json_kind(doc) == "intrinsics":
            return load_intrinsics(path)
        from .io import load_rig
        return known_from_rig(load_rig(path), str(path))
    return import_files(fmt, [path]).cameras
