"""Synthetic truth for lenses that breathe with focus and shift with optical image stabilisation (OIS).

**Breathing.** A phone lens focuses by moving: at focus distance ``d`` (mm, object to lens) a thin lens of focal
length ``f`` (mm, the EXIF focal length) sits ``f d / (d - f)`` from the sensor, so its principal distance grows
by ``f / (d - f)`` over its value at infinity. A real lens is not thin; a coefficient ``b`` scales that growth::

    fx(d) = fx_inf (1 + b f / (d - f)),    fy(d) = fy_inf (1 + b f / (d - f))

(``b = 1``: the thin lens, +0.9 % at 0.5 m for ``f`` = 4.3 mm). The principal point and the lens's distortion in
normalised coordinates stay as they are. The preset's ``fx, fy`` are the values at infinity. Each photo is focused
where its subject is: a board photo at the board centre's depth along that camera's axis, a measurement photo at
the object's.

**OIS.** Each photo's principal point is moved by its own shift ``(du, dv)``, drawn independently per camera and
per photo from a normal distribution of ``ois_px`` px per coordinate (px of the photo as written): the lens module
moved sideways to hold the image still.

Each photo's focus is written into its EXIF (``SubjectDistance``, m) and into an Apple-style MakerNote
(``FocusDistanceRange``, the focus +-1.5 %, as iPhones write it; :func:`dualcal.files.photos.apple_maker_note` reads
it), with the EXIF focal length; the truth file records every photo's focus, shift and camera
(:func:`photos_truth_doc`). :func:`write_object_photos` renders measurement photos of a textured box
(:mod:`dualcal.synthetic.render_object`) at given distances with the same lenses.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image, TiffImagePlugin

from ..files.io import write_bytes_atomic
from ..geometry.camera import CameraModel
from ..geometry.model import Pose
from ..geometry.rotation import rotation_from_opk
from ..parallel import interruptible_map
from ..progress import progress_bar

__all__ = ["FOCAL_MM", "PhotoLens", "breathing_camera", "face_points", "focal_lengths_mm", "focus_exif", "lens_doc",
           "photo_lenses", "photos_truth_doc", "write_focus_photo_set", "write_object_photos"]

#: The EXIF focal length of each preset's cameras, mm (a phone's wide 4.3 mm at 1.4 um pixels, ...). A camera not
#: named here: its focal length in px times 1.4 um.
FOCAL_MM = {"note8": {"wide": 4.3, "tele": 6.0}, "triple": {"wide": 4.25, "tele": 6.0, "ultra": 2.2},
            "phone3": {"wide": 5.7, "ultra": 1.55, "tele": 9.0}}
_PITCH_MM = 0.0014
#: Half-width of the FocusDistanceRange written, as a share of the focus distance.
RANGE_SHARE = 0.015


def breathing_camera(cam: CameraModel, focal_mm: float, breathing: float, focus_mm: float) -> CameraModel:
    """``cam`` (its ``fx, fy`` at infinity) focused at ``focus_mm``: ``fx (1 + b f / (d - f))`` (module docstring)."""
    if not focus_mm > focal_mm:
        raise ValueError(f"a lens of {focal_mm:g} mm cannot focus at {focus_mm:g} mm")
    grow = 1.0 + breathing * focal_mm / (focus_mm - focal_mm)
    return replace(cam, fx=cam.fx * grow, fy=cam.fy * grow)


@dataclass(frozen=True)
class PhotoLens:
    """One photo's lens: its ``camera`` (breathing and shift applied), ``focus_mm``, ``shift_px`` (2,), ``focal_mm``."""

    camera: CameraModel
    focus_mm: float
    shift_px: tuple[float, float]
    focal_mm: float


def focal_lengths_mm(preset: str, cameras: dict[str, CameraModel], scale: float = 1.0) -> dict[str, float]:
    """Each camera's EXIF focal length, mm (:data:`FOCAL_MM`, else its focal length in px times 1.4 um at full size)."""
    known = FOCAL_MM.get(preset, {})
    return {n: known.get(n, c.fx / scale * _PITCH_MM) for n, c in cameras.items()}


def photo_lenses(cameras: dict[str, CameraModel], focal_mm: dict[str, float], focus_mm: dict[str, float],
                 breathing: float, ois_px: float, rng: np.random.Generator) -> dict[str, PhotoLens]:
    """Each camera's lens in one photo focused at ``focus_mm[camera]``, shifted by a draw of ``ois_px`` per coordinate."""
    out = {}
    for name, cam in cameras.items():
        shift = rng.normal(0.0, ois_px, 2) if ois_px > 0 else np.zeros(2)
        lens = breathing_camera(cam, focal_mm[name], breathing, focus_mm[name]) if breathing else cam
        out[name] = PhotoLens(replace(lens, cx=lens.cx + shift[0], cy=lens.cy + shift[1]), float(focus_mm[name]),
                              (float(shift[0]), float(shift[1])), float(focal_mm[name]))
    return out


def _apple_note(focus_m: float) -> bytes:
    """An Apple MakerNote (big-endian) holding ``FocusDistanceRange`` (0x000c, two signed rationals): the focus
    +-:data:`RANGE_SHARE`, in mm over 1000."""
    lo, hi = (round(focus_m * 1000 * (1 + s * RANGE_SHARE)) for s in (-1, 1))
    header = b"Apple iOS\0\x00\x01MM"
    data_at = len(header) + 2 + 12 + 4
    return (header + struct.pack(">HHHII", 1, 0x000C, 10, 2, data_at) + b"\0\0\0\0"
            + struct.pack(">iiii", lo, 1000, hi, 1000))


def focus_exif(lens: PhotoLens, model: str = "synthetic phone") -> bytes:
    """The EXIF block (``Exif\\0\\0`` + TIFF) of a photo taken with ``lens``: make, model, focal length,
    ``SubjectDistance`` and the Apple-style MakerNote's ``FocusDistanceRange`` (module docstring)."""
    exif = Image.Exif()
    exif[0x010F] = "dualcal"
    exif[0x0110] = model
    sub = exif.get_ifd(0x8769)
    sub[0x920A] = TiffImagePlugin.IFDRational(round(lens.focal_mm * 1000), 1000)      # FocalLength
    sub[0x9206] = TiffImagePlugin.IFDRational(round(lens.focus_mm), 1000)             # SubjectDistance, m
    sub[0x927C] = _apple_note(lens.focus_mm / 1000.0)                                 # MakerNote
    return exif.tobytes()


def _write_jpeg(path: Path, gray: np.ndarray, exif: bytes, quality: int) -> None:
    buf = io.BytesIO()
    Image.fromarray(gray).save(buf, "JPEG", quality=quality, exif=exif)
    write_bytes_atomic(path, buf.getvalue())


def lens_doc(lens: PhotoLens) -> dict:
    """A photo's lens as truth.json records it."""
    c = lens.camera
    return {"focus_m": lens.focus_mm / 1000.0, "ois_shift_px": list(lens.shift_px), "focal_length_mm": lens.focal_mm,
            "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy}


def photos_truth_doc(truth) -> dict:
    """truth.json's ``photos``: ``{view: {camera: {"focus_m", "ois_shift_px", "focal_length_mm", "fx", "fy", "cx",
    "cy"}}}``, every photo's lens as it took that photo (:class:`~dualcal.synthetic.synth.SynthTruth`'s
    ``photo_lenses``)."""
    return {view: {cam: lens_doc(lens) for cam, lens in lenses.items()} for view, lenses in truth.photo_lenses.items()}


def _render_board(task) -> str:
    from .render import photo_seed, render_view

    lens, pose, board, key, path, quality, model = task
    _write_jpeg(path, render_view(lens.camera, pose, board, photo_seed(*key)), focus_exif(lens, model), quality)
    return str(path)


def write_focus_photo_set(truth, photo_dir, seed: int = 0, jobs: int | None = None, quality: int = 92,
                          progress: bool = True) -> dict[str, dict[str, Path]]:
    """:func:`dualcal.synthetic.render.write_photo_set` for a truth whose lenses breathe or shift: each photo rendered
    with its own lens (``truth.photo_lenses``) and its focus in its EXIF (:func:`focus_exif`).

    Returns ``{camera: {view: path}}``.
    """
    photo_dir = Path(photo_dir)
    tasks, paths = [], {}
    for ci, name in enumerate(truth.cameras):
        (photo_dir / name).mkdir(parents=True, exist_ok=True)
        paths[name] = {}
        for vi, view in enumerate(truth.view_poses):
            paths[name][view] = photo_dir / name / f"{view}.jpg"
            tasks.append((truth.photo_lenses[view][name], truth.camera_pose(name, view), truth.board, (seed, ci, vi),
                          paths[name][view], quality, "synthetic phone"))
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(tasks)))
    with progress_bar("rendering photos", len(tasks), enabled=progress) as advance:
        for _ in interruptible_map(_render_board, tasks, jobs):
            advance()
    return paths


def face_points(box, share: float = 0.3) -> np.ndarray:
    """(4, 3) points on the face of ``box`` that looks most squarely at the reference camera, ``share`` of its
    sides from its centre each way (in its plane, reference frame, mm): points to tap and measure between."""
    R, centre, half = box.pose.R, box.pose.t_mm, np.asarray(box.size_mm, float) / 2
    toward = -centre / np.linalg.norm(centre)
    axis = int(np.argmax(np.abs(R.T @ toward)))
    normal = R[:, axis] * np.sign(R[:, axis] @ toward)
    a, b = [k for k in range(3) if k != axis]
    offsets = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    return np.array([centre + normal * half[axis] + 2 * share * (i * half[a] * R[:, a] + j * half[b] * R[:, b])
                     for i, j in offsets])


def write_object_photos(truth, folder, distances_mm=(300.0, 2000.0), seed: int = 0, breathing: float = 0.0,
                        ois_px: float = 0.0, focal_mm: dict[str, float] | None = None, quality: int = 92) -> dict:
    """Measurement photos of a textured box (:class:`~dualcal.synthetic.render_object.TexturedBox`, edges 0.3, 0.22
    and 0.15 of its distance, turned 20-35 degrees) at each of ``distances_mm`` from the reference camera, every
    camera of ``truth`` focused on it (breathing ``breathing``, its own OIS shift of ``ois_px``): written as
    ``folder/<distance>mm/<camera>.jpg`` with their focus in EXIF.

    Returns
    -------
    dict
        truth.json's ``measure_photos``: ``{"<distance>mm": {"box": {"R", "t_mm", "size_mm"}, "corners_mm": (8, 3)
        in the reference camera's frame, "face_points_mm": (4, 3) (:func:`face_points`), "photos": {camera:
        {"file", lens...}}}}``.
    """
    from .render_object import TexturedBox, render_object

    folder = Path(folder)
    focal = focal_mm or {n: c.fx * _PITCH_MM for n, c in truth.cameras.items()}
    rng = np.random.default_rng([int(seed), 0x0B7EC7])
    out = {}
    for k, distance in enumerate(distances_mm):
        angles = rng.uniform(20.0, 35.0, 3) * rng.choice([-1.0, 1.0], 3)
        pose = Pose(rotation_from_opk(np.radians(angles)), np.array([0.0, 0.0, float(distance)]))
        box = TexturedBox(pose, (0.3 * distance, 0.22 * distance, 0.15 * distance), seed=int(seed) * 10 + k)
        depth = {n: float(truth.seen_by(n, pose).t_mm[2]) for n in truth.cameras}
        lenses = photo_lenses(truth.cameras, focal, depth, breathing, ois_px, rng)
        sub = folder / f"{distance:g}mm"
        sub.mkdir(parents=True, exist_ok=True)
        photos = {}
        for ci, (name, lens) in enumerate(lenses.items()):
            to_camera = truth.rig[name] if name != truth.reference else Pose(np.eye(3), np.zeros(3))
            gray = render_object(lens.camera, to_camera, box, np.random.default_rng([int(seed), k, ci]))
            _write_jpeg(sub / f"{name}.jpg", gray, focus_exif(lens), quality)
            photos[name] = {"file": f"{sub.name}/{name}.jpg", **lens_doc(lens)}
        out[sub.name] = {"box": {"R": pose.R.tolist(), "t_mm": pose.t_mm.tolist(), "size_mm": list(box.size_mm)},
                         "corners_mm": box.corners_mm().tolist(), "face_points_mm": face_points(box).tolist(),
                         "photos": photos}
    return out
