"""Write a calibrated rig in the formats other tools read (``dualcal export``).

=========  ==================================  ===========================  ===========
format     file(s)                             rig pose                     lengths
=========  ==================================  ===========================  ===========
opencv     one FileStorage YAML                ``X_cam = R X_ref + T``      millimetres
kalibr     one camchain YAML (cam0, cam1, ..)  ``T_cn_cnm1``: previous cam  metres
colmap     one ``cameras.txt``                 none (intrinsics only)       –
mrcal      one ``.cameramodel`` per camera     ``rt_cam_ref``               metres
=========  ==================================  ===========================  ===========

Cameras are numbered from the reference camera (cam0 / camera id 1), then the others in the
order of calib.json. Every format writes the lens model it is given, in OpenCV's
radial-tangential model, which is exactly dualcal's (:mod:`dualcal.geometry.camera`), the coefficients a
lens model lacks being 0:

==========  ==========================  ======================  =====================  ===================
lens model  opencv ``D``                kalibr ``radtan``       colmap                 mrcal
==========  ==========================  ======================  =====================  ===================
k1k2        k1 k2 0 0 0                 k1 k2 0 0               OPENCV                 LENSMODEL_OPENCV4
k1k2p1p2    k1 k2 p1 p2 0               k1 k2 p1 p2             OPENCV                 LENSMODEL_OPENCV4
k1k2k3      k1 k2 0 0 k3                refused (no k3)         FULL_OPENCV            LENSMODEL_OPENCV5
k1k2p1p2k3  k1 k2 p1 p2 k3              refused (no k3)         FULL_OPENCV            LENSMODEL_OPENCV5
kb4         k1 k2 k3 k4 (cv2.fisheye)   ``equidistant``         OPENCV_FISHEYE         refused (no such)
==========  ==========================  ======================  =====================  ===================

The fisheye ``kb4`` is OpenCV's ``cv2.fisheye`` model term for term: its ``D`` (1x4) is what
``cv2.fisheye.projectPoints`` takes, Kalibr's ``pinhole`` + ``equidistant`` (``pinhole-equi``) and
COLMAP's ``OPENCV_FISHEYE`` are the same model; mrcal has no Kannala-Brandt model, so a rig with one
is refused there.

(COLMAP's OPENCV is ``k1 k2 p1 p2``, its FULL_OPENCV ``k1 k2 p1 p2 k3 k4 k5 k6``, here with
``k4 = k5 = k6 = 0``; mrcal's OPENCV4 and OPENCV5 are OpenCV's first four and five.) None of
the formats has a skew term: a non-zero ``skew`` (the paper's gamma, Model 2) is dropped, with a
warning. Pixel convention: OpenCV, Kalibr and mrcal centre pixel ``(row i, col j)`` at
``(j, i)`` like dualcal; COLMAP centres it at ``(j + 0.5, i + 0.5)``, so its principal point
is shifted by half a pixel.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from .. import __version__
from ..geometry.camera import LENS_MODELS, CameraModel
from ..errors import InputError
from .io import check_output_file, write_text_atomic
from ..geometry.model import RigModel
from ..progress import warn
from ..geometry.rotation import rotvec_from_rotation

FORMATS = ("opencv", "kalibr", "colmap", "mrcal")

_MM_PER_M = 1000.0


def skewed_cameras(rig: RigModel) -> dict[str, float]:
    """Cameras whose skew (px) is not zero, which the export formats cannot represent."""
    return {name: cam.skew for name, cam in rig.cameras.items() if cam.skew != 0.0}


def _has_k3(cam: CameraModel) -> bool:
    """Whether the camera's lens has the radial-tangential ``k3`` (which a four-coefficient format cannot
    hold; a fisheye's k3 is a term of its own model)."""
    return not cam.fisheye and "k3" in LENS_MODELS[cam.model]


def _safe_name(name: str) -> str:
    """``name`` with characters other than letters, digits, ``_`` and ``-`` replaced by ``_``."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", name) or "camera"


def _opencv_key(name: str) -> str:
    """A FileStorage key for camera ``name``: :func:`_safe_name`, starting with a letter or ``_``."""
    key = _safe_name(name)
    return key if re.match(r"[A-Za-z_]", key) else f"_{key}"


def _distinct(names: list[str], spell: Callable[[str], object], what: str) -> dict:
    """``{name: spell(name)}`` for the cameras ``names``; two cameras spelled alike raise :class:`InputError`.

    ``spell`` makes a camera name safe for a format (a file name, a key), which can map two
    names to one (``wide 1`` and ``wide_1`` both give the mrcal file ``wide_1.cameramodel``).
    """
    out, owner = {}, {}
    for name in names:
        spelled = out[name] = spell(name)
        if spelled in owner:
            raise InputError(f"cameras {owner[spelled]!r} and {name!r} would both be written as {what} "
                             f"'{spelled}': rename one of them when detecting the corners (--camera NAME=GLOB) "
                             "and calibrate again")
        owner[spelled] = name
    return out


def _unrelated_cameras(rig: RigModel) -> list[str]:
    """Non-reference cameras without a pose relative to the reference (rig mode ``none``)."""
    return [name for name in rig.cameras if name != rig.reference and name not in rig.rig]


# ---------------------------------------------------------------------------- OpenCV


def opencv_yaml(rig: RigModel) -> str:
    """OpenCV FileStorage YAML of the rig, readable with ``cv2.FileStorage``.

    Top level: ``reference`` (name), ``cameras`` (sequence of names, reference first), then a
    map per camera (key: the name, characters other than letters, digits, ``-`` and ``_``
    replaced by ``_``, and ``_`` put in front of a leading digit) holding
    ``image_width``, ``image_height`` (px), ``K`` (3x3, px), ``D`` (1x5: k1, k2, p1, p2, k3, zero
    where the lens model lacks them; for the fisheye ``kb4`` 1x4, ``cv2.fisheye``'s k1, k2, k3, k4),
    ``lens_model`` (dualcal's name of it) and,
    for every camera with a pose relative to the reference, ``R`` (3x3) and ``T`` (3x1, mm)
    such that ``X_cam = R X_ref + T`` (what ``cv2.stereoCalibrate`` returns). Each other camera
    also carries the stereo rectification of the pair (reference = camera 1, this camera =
    camera 2) that ``dualcal rectify`` computes with ``--keep valid``
    (:func:`dualcal.files.stereo.stereo_rectify`): ``R1``, ``R2``, ``P1``, ``P2``, ``Q`` (what
    ``cv2.stereoRectify`` returns) and ``rectified_width``, ``rectified_height``.
    """
    from ..errors import EstimationError
    from .stereo import stereo_rectify

    keys = _distinct(rig.camera_order(), _opencv_key, "the OpenCV key")
    fs = cv2.FileStorage(".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.writeComment(f"dualcal {__version__} rig calibration. K in pixels (skew dropped), "
                    "D = (k1, k2, p1, p2, k3), or cv2.fisheye's (k1, k2, k3, k4) where lens_model is kb4; "
                    "X_cam = R X_ref + T with T in millimetres.")
    fs.write("reference", rig.reference)
    fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
    for name in rig.camera_order():
        fs.write("", name)
    fs.endWriteStruct()
    for name in rig.camera_order():
        cam = rig.cameras[name]
        fs.startWriteStruct(keys[name], cv2.FileNode_MAP)
        fs.write("image_width", int(cam.image_size[0]))
        fs.write("image_height", int(cam.image_size[1]))
        fs.write("K", np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]]))
        fs.write("D", np.array(cam.distortion).reshape(1, -1))
        fs.write("lens_model", cam.model)
        if name == rig.reference or name in rig.rig:
            pose = rig.pose_from_reference(name)
            fs.write("R", pose.R)
            fs.write("T", pose.t_mm.reshape(3, 1))
        if name in rig.rig:
            try:
                rect = stereo_rectify(rig, rig.reference, name)
            except EstimationError as exc:       # a folding lens, no overlap: the pair has no rectification
                warn(f"no stereo rectification of {rig.reference} + {name} in the export: {exc}")
            else:
                for key in ("R1", "R2", "P1", "P2", "Q"):
                    fs.write(key, getattr(rect, key))
                fs.write("rectified_width", int(rect.image_size[0]))
                fs.write("rectified_height", int(rect.image_size[1]))
        fs.endWriteStruct()
    return fs.releaseAndGetString()


# ---------------------------------------------------------------------------- Kalibr


def _yaml_float(x: float) -> str:
    """A float PyYAML (YAML 1.1) reads back as a float: ``1e-05`` would be a string there."""
    s = repr(float(x))
    if "e" in s:
        mantissa, exponent = s.split("e")
        if "." not in mantissa:
            mantissa += ".0"
        if exponent[0] not in "+-":
            exponent = "+" + exponent
        s = f"{mantissa}e{exponent}"
    return s


def _yaml_list(values) -> str:
    return "[" + ", ".join(_yaml_float(v) for v in values) + "]"


def kalibr_yaml(rig: RigModel) -> str:
    """Kalibr camchain YAML: ``cam0`` (the reference), ``cam1``, ... .

    Each camera: ``camera_model: pinhole``, ``intrinsics: [fu, fv, pu, pv]`` (px),
    ``distortion_model: radtan``, ``distortion_coeffs: [k1, k2, p1, p2]`` (``p1 = p2 = 0`` for
    the paper's ``k1k2``), or for the fisheye ``kb4`` ``distortion_model: equidistant`` with
    ``[k1, k2, k3, k4]`` (Kalibr's ``pinhole-equi``),
    ``resolution: [w, h]``, ``rostopic``, ``cam_overlaps`` (every other camera: all saw the same
    board) and, from cam1 on, ``T_cn_cnm1``: the 4x4 transform taking camera n-1 coordinates to
    camera n coordinates, translation in metres.

    Raises
    ------
    InputError
        For a lens model with ``k3``, which radtan does not have.
    """
    order = rig.camera_order()
    with_k3 = [name for name in order if _has_k3(rig.cameras[name])]
    if with_k3:
        raise InputError(f"kalibr's radtan model has no k3, which the lens model {rig.cameras[with_k3[0]].model} "
                         f"of {', '.join(with_k3)} has: export to opencv, colmap or mrcal, which hold it, or "
                         "calibrate with --model k1k2p1p2")
    topics = _distinct(order, lambda name: f"/{_safe_name(name).replace('-', '_')}/image_raw", "the rostopic")
    lines = [f"# dualcal {__version__} rig calibration: "
             + ", ".join(f"cam{i} = {name}" for i, name in enumerate(order))
             + "; T_cn_cnm1 in metres, skew dropped"]
    previous = None
    for i, name in enumerate(order):
        cam = rig.cameras[name]
        pose = rig.pose_from_reference(name)
        lines.append(f"cam{i}:")
        if previous is not None:
            # cam n from cam n-1: X_n = R_n X_ref + t_n, X_ref = R_m^T (X_m - t_m).
            rel = pose.compose(previous.inverse())
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = rel.R, rel.t_mm / _MM_PER_M
            lines.append("  T_cn_cnm1:")
            lines += [f"  - {_yaml_list(row)}" for row in T]
        overlaps = ", ".join(str(j) for j in range(len(order)) if j != i)
        lines += [f"  cam_overlaps: [{overlaps}]",
                  "  camera_model: pinhole",
                  f"  distortion_coeffs: {_yaml_list(cam.distortion if cam.fisheye else cam.distortion[:4])}",
                  f"  distortion_model: {'equidistant' if cam.fisheye else 'radtan'}",
                  f"  intrinsics: {_yaml_list([cam.fx, cam.fy, cam.cx, cam.cy])}",
                  f"  resolution: [{cam.image_size[0]}, {cam.image_size[1]}]",
                  f"  rostopic: {topics[name]}"]
        previous = pose
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- COLMAP


def colmap_cameras_txt(rig: RigModel) -> str:
    """COLMAP ``cameras.txt``: one camera per rig camera, ids 1, 2, ... .

    ``CAMERA_ID OPENCV WIDTH HEIGHT fx fy cx cy k1 k2 p1 p2``, or for a lens model with ``k3``
    ``CAMERA_ID FULL_OPENCV WIDTH HEIGHT fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6`` (``k4 = k5 = k6 =
    0``), or for the fisheye ``kb4`` ``CAMERA_ID OPENCV_FISHEYE WIDTH HEIGHT fx fy cx cy k1 k2 k3 k4``,
    with ``cx, cy`` moved by +0.5 px to COLMAP's pixel convention (centre of the top-left pixel at
    (0.5, 0.5)).
    """
    order = rig.camera_order()
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(order)}",
             f"# dualcal {__version__}: " + ", ".join(f"{i} = {n}" for i, n in enumerate(order, 1))
             + "; principal point in COLMAP's convention (dualcal's + 0.5 px), skew dropped"]
    for i, name in enumerate(order, 1):
        cam = rig.cameras[name]
        params = [cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5, cam.k1, cam.k2, cam.p1, cam.p2]
        model = "OPENCV"
        if cam.fisheye:
            params, model = params[:4] + list(cam.distortion), "OPENCV_FISHEYE"
        elif _has_k3(cam):
            params, model = params + [cam.k3, 0.0, 0.0, 0.0], "FULL_OPENCV"
        lines.append(f"{i} {model} {cam.image_size[0]} {cam.image_size[1]} "
                     + " ".join(repr(float(p)) for p in params))
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- mrcal


def mrcal_cameramodel(rig: RigModel, name: str) -> str:
    """mrcal ``.cameramodel`` text of camera ``name`` (a Python-literal dict with comments).

    ``lensmodel: LENSMODEL_OPENCV4`` with ``intrinsics = [fx, fy, cx, cy, k1, k2, p1, p2]``
    (px), or for a lens model with ``k3`` ``LENSMODEL_OPENCV5`` with ``[..., p2, k3]``;
    ``extrinsics = rt_cam_ref = [rx, ry, rz, tx, ty, tz]``: rotation vector (radians) and
    translation (metres) taking reference camera coordinates to this camera's, and
    ``imagersize = [w, h]``. The reference camera has zero extrinsics.
    """
    cam = rig.cameras[name]
    pose = rig.pose_from_reference(name)
    rt = np.concatenate([rotvec_from_rotation(pose.R), pose.t_mm / _MM_PER_M])
    intrinsics = [cam.fx, cam.fy, cam.cx, cam.cy, *cam.distortion[:4]]
    lensmodel = "LENSMODEL_OPENCV4"
    if _has_k3(cam):
        intrinsics, lensmodel = intrinsics + [cam.k3], "LENSMODEL_OPENCV5"

    def literal(values):
        return "[ " + " ".join(f"{float(v)!r}," for v in values) + " ]"

    return "\n".join([
        f"# dualcal {__version__}: camera {name!r} of a rig calibrated with reference {rig.reference!r}",
        "# extrinsics translation in metres; skew dropped",
        "{",
        f"    'lensmodel':  '{lensmodel}',",
        "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....",
        f"    'intrinsics': {literal(intrinsics)},",
        "    # extrinsics are rt_fromref",
        f"    'extrinsics': {literal(rt)},",
        f"    'imagersize': [ {cam.image_size[0]}, {cam.image_size[1]} ],",
        "}",
        "",
    ])


def mrcal_paths(rig: RigModel, output: str | Path) -> dict[str, Path]:
    """File per camera: ``OUTPUT/NAME.cameramodel`` if OUTPUT is a folder, else ``OUTPUT-NAME.cameramodel``.

    A ``.cameramodel`` suffix on a stem is dropped first (``-o rig.cameramodel`` gives
    ``rig-wide.cameramodel``, ``rig-tele.cameramodel``). A string ending in ``/`` must name an
    existing folder.

    Raises
    ------
    InputError
        For a missing folder, or two cameras whose names give the same file.
    """
    if str(output).endswith(("/", os.sep)) and not Path(output).is_dir():
        raise InputError(f"output folder {str(output)!r} does not exist: create it first or give a file stem")
    output = Path(output)
    if output.is_dir():
        folder, prefix = output, ""
    else:
        stem = output.with_suffix("") if output.suffix == ".cameramodel" else output
        folder, prefix = stem.parent, f"{stem.name}-"
    return _distinct(rig.camera_order(), lambda name: folder / f"{prefix}{_safe_name(name)}.cameramodel",
                     "the file")


# ---------------------------------------------------------------------------- files


def export_files(rig: RigModel, fmt: str, output: str | Path) -> dict[Path, str]:
    """The files of format ``fmt`` (one of :data:`FORMATS`) for ``output``, as ``{path: text}``.

    Raises
    ------
    InputError
        for an unknown format, two cameras whose names the format would spell alike, in kalibr
        and mrcal (which place every camera relative to the reference), a rig whose cameras
        have no relative pose (rig mode ``none``), in kalibr a radial lens model with ``k3``, or in
        mrcal a fisheye.
    """
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r} is unknown (choose from {', '.join(FORMATS)})")
    unrelated = _unrelated_cameras(rig)
    if fmt in ("kalibr", "mrcal") and unrelated:
        raise InputError(f"camera(s) {', '.join(unrelated)} have no pose relative to {rig.reference} "
                         f"(rig mode {rig.rig_mode!r}), which {fmt} needs: calibrate with --rig rigid or paper")
    fisheyes = [name for name, cam in rig.cameras.items() if cam.fisheye]
    if fmt == "mrcal" and fisheyes:
        raise InputError(f"mrcal has no Kannala-Brandt fisheye, the lens model of {', '.join(fisheyes)}: export to "
                         "opencv (cv2.fisheye), kalibr (pinhole-equi) or colmap (OPENCV_FISHEYE), which have it")
    if fmt == "mrcal":
        return {path: mrcal_cameramodel(rig, name) for name, path in mrcal_paths(rig, output).items()}
    text = {"opencv": opencv_yaml, "kalibr": kalibr_yaml, "colmap": colmap_cameras_txt}[fmt](rig)
    return {Path(output): text}


def write_export(rig: RigModel, fmt: str, output: str | Path) -> list[Path]:
    """Write :func:`export_files` atomically; warn once if a non-zero skew had to be dropped.

    Every path is checked (:func:`dualcal.files.io.check_output_file`) before any file is written.

    Parameters
    ----------
    rig : RigModel
        The calibration.
    fmt : str
        ``opencv``, ``kalibr``, ``colmap`` or ``mrcal`` (:data:`FORMATS`).
    output : str or Path
        The file to write; for ``mrcal`` a folder (one ``NAME.cameramodel`` per camera) or a stem.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    InputError
        An unknown format, or a lens model the format cannot hold (the message names those that can).
    OutputError
        A file cannot be written; nothing was replaced.
    """
    files = export_files(rig, fmt, output)
    for path in files:
        check_output_file(path)
    skewed = skewed_cameras(rig)
    if skewed:
        warn(f"{fmt} has no skew term: dropped skew "
             + ", ".join(f"{n} = {s:.4g} px" for n, s in skewed.items())
             + " (calibrate without --skew for an exact export)")
    for path, text in files.items():
        write_text_atomic(path, text)
    return list(files)


__all__ = ["FORMATS", "colmap_cameras_txt", "export_files", "kalibr_yaml",
           "mrcal_cameramodel", "mrcal_paths", "opencv_yaml", "skewed_cameras",
           "write_export"]
