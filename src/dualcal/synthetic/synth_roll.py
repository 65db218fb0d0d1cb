"""A synthetic camera roll: a rig's photos as a phone's camera app leaves them in one folder.

:func:`write_camera_roll` renders every camera and view of a synthetic rig (:func:`dualcal.synthetic.render.write_photo_set`)
and lays the photos out as a tripod session does (CONTRACT.md, "A phone's camera roll"): one flat folder,
``IMG_0101.JPG``, ``IMG_0102.JPG``, ... in shooting order; at each board position every lens shoots in turn,
a few seconds apart (widest first), then the board is moved (tens of seconds). Each photo carries the EXIF a
phone writes: ``Make``, ``Model``, ``LensModel``, ``FocalLength``, ``FocalLengthIn35mmFilm``,
``DateTimeOriginal`` and ``SubSecTimeOriginal``, inserted into the JPEG without re-encoding it. The roll also
holds what real ones do: a retake (one position's reference photo shot twice), a photo without the board,
an ``.AAE`` sidecar file and a ``.MOV`` Live Photo clip.

How the session is shot is a :class:`Shooting`: the gaps between lenses and between positions, a lens switch
that takes longer, stray photos between or after the positions, lenses that miss a position. Its script
(:func:`shooting_script`: which photo, when) is what tests of the roll's split use without rendering.
:func:`strip_exif` does to a roll what a phone's browser does to the photos it uploads: JPEGs re-encoded
without EXIF.

The 35 mm-equivalent focal length of a camera is ``fx * 43.27 mm / image diagonal (px)``, its focal
length in mm that divided by a phone sensor's typical crop factor (:data:`CROP_FACTOR`).
"""

from __future__ import annotations

import io
import struct
import tempfile
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
from PIL import Image, TiffImagePlugin

from ..files.io import encode_jpeg, write_bytes_atomic
from ..files.photos import Photo
from ..geometry.camera import equivalent_focal_35mm
from ..files.roll import camera_class
from .synth import make_truth, true_corners

__all__ = ["CROP_FACTOR", "ScriptedShot", "Shooting", "equivalent_focal_of", "roll_without_exif", "shared_size_rig",
           "shooting_script", "strip_exif", "write_camera_roll"]

#: A phone sensor's crop factor by camera class (an iPhone's ultra-wide 2.2 mm is 13 mm equivalent, its
#: main camera 6.9 mm 24 mm, its tele 9 mm 77 mm): it sets only EXIF's focal length in mm.
CROP_FACTOR = {"ultra": 6.0, "wide": 3.5, "tele": 8.5}
_START = datetime(2026, 11, 30, 10, 0, 0)


def equivalent_focal_of(cam) -> float:
    """The 35 mm-equivalent focal length (mm) of a :class:`~dualcal.geometry.camera.CameraModel`."""
    return equivalent_focal_35mm(cam.image_size, cam.fx)


def shared_size_rig(focal_px: dict[str, float], fisheye: tuple[str, ...] = ("ultra",),
                    image_size: tuple[int, int] = (2016, 1512)) -> dict:
    """A rig whose lenses all take photos of one size, as :func:`dualcal.synthetic.synth.make_truth` takes it.

    The roll a phone's browser uploads (HEIC turned JPEG, EXIF gone) may hold two or three lenses at one size:
    an ultra-wide whose processing leaves it a fisheye (about 1130 px) beside a wide (about 1340 px) at
    2016 x 1512, say. ``focal_px``: each camera's focal length, the reference first (name them as
    :func:`dualcal.files.roll.camera_class` would, ``wide`` the reference); the cameras in ``fisheye`` are a
    ``kb4`` fisheye (nearly equidistant: a strong barrel), the others mild ``k1k2`` lenses. Each principal
    point is 0.5-1 % from the centre; the lenses sit 10-25 mm apart, turned by up to 40 arcmin. Where a
    fisheye is the widest, 30 % of the views are near its image's edge (the board 25-40 degrees off its axis).
    """
    from ..geometry.board import Board
    from ..geometry.camera import CameraModel
    from ..geometry.model import Pose
    from ..geometry.rotation import ARCMIN_PER_RAD, rotation_from_opk

    w, h = image_size
    cameras, rig = {}, {}
    for i, (name, f) in enumerate(focal_px.items()):
        cx, cy = (w - 1) / 2 + (0.006, -0.004, 0.008)[i % 3] * w, (h - 1) / 2 + (0.005, 0.008, -0.006)[i % 3] * h
        if name in fisheye:
            cameras[name] = CameraModel((w, h), f, f * 0.9995, 0.0, cx, cy, 0.02, -0.004, k3=0.001, k4=-0.0002,
                                        model="kb4")
        else:
            cameras[name] = CameraModel((w, h), f, f * 1.0005, 0.0, cx, cy, (0.05, -0.06, 0.03)[i % 3],
                                        (-0.12, 0.2, -0.05)[i % 3])
        if i:
            opk = np.array([(-20.0, 15.0, -30.0), (10.0, -25.0, 40.0)][i % 2]) / ARCMIN_PER_RAD
            rig[name] = Pose(rotation_from_opk(opk), np.array([0.4, (12.0, -22.0)[i % 2], -0.3]))
    widest = min(focal_px, key=focal_px.get)
    edge = [dict(camera=widest, share=0.3, fill=(0.25, 0.45), angle_deg=(25.0, 40.0))] if widest in fisheye else []
    return dict(board=Board(8, 5, 30.0), cameras=cameras, rig=rig, fill=(0.45, 0.85), edge=edge)


def _exif_bytes(cam, taken: datetime, device: str) -> bytes:
    """The APP1 payload (``Exif\\0\\0`` + TIFF) of a photo of ``cam`` taken at ``taken``."""
    f35 = equivalent_focal_of(cam)
    f_mm = f35 / CROP_FACTOR[camera_class(f35)]
    exif = Image.Exif()
    exif[0x010F] = "dualcal"                       # Make
    exif[0x0110] = device                          # Model
    exif[0x0112] = 1                               # Orientation
    sub = exif.get_ifd(0x8769)
    sub[0x9003] = taken.strftime("%Y:%m:%d %H:%M:%S")            # DateTimeOriginal
    sub[0x9291] = f"{taken.microsecond // 1000:03d}"              # SubSecTimeOriginal
    sub[0x920A] = TiffImagePlugin.IFDRational(round(f_mm * 1000), 1000)   # FocalLength
    sub[0xA405] = int(round(f35))                                  # FocalLengthIn35mmFilm
    sub[0xA434] = f"{device} back camera {f_mm:.2f}mm f/1.8"      # LensModel
    return exif.tobytes()


def _reencoded(jpeg: bytes, quality: int) -> bytes:
    """A JPEG decoded and encoded again by Pillow at ``quality``, without EXIF (no ``exif=``: Pillow writes none)."""
    out = io.BytesIO()
    with Image.open(io.BytesIO(jpeg)) as img:
        img.save(out, "JPEG", quality=quality)
    return out.getvalue()


def _with_exif(jpeg: bytes, payload: bytes) -> bytes:
    """A JPEG with an APP1 EXIF segment inserted after its SOI marker (the image data untouched)."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG")
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


@dataclass(frozen=True)
class Shooting:
    """How a tripod session is shot (times in seconds, drawn uniformly from each range).

    ``lens_gap_s``: between two lenses of one position; ``position_gap_s``: before each position (the board
    moved); ``slow_switch_s``: one lens switch (the middle position's last) takes this long instead; ``retake``:
    the reference camera's photo of a middle position that shows the board is shot twice; ``stray_after``: a
    photo without the board (the floor) is shot this long after these positions (index; -1 the last);
    ``missed``: ``(camera, position index)`` photos not shot (a lens that missed a position).
    """

    lens_gap_s: tuple[float, float] = (2.0, 6.0)
    position_gap_s: tuple[float, float] = (25.0, 90.0)
    slow_switch_s: float | None = None
    retake: bool = True
    stray_after: tuple[int, ...] = (1,)
    stray_gap_s: tuple[float, float] = (25.0, 90.0)
    missed: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True)
class ScriptedShot:
    """One photo of a session: its file name, camera and view (None for a stray photo), when it was taken."""

    name: str
    camera: str | None
    view: str | None
    taken: datetime


def shooting_script(truth, shooting: Shooting = Shooting(), seed: int = 0, first_number: int = 101) -> list[ScriptedShot]:
    """The photos of a session of ``truth`` (:class:`~dualcal.synthetic.synth.SynthTruth`) in shooting order:
    the lenses widest first at each position (:class:`Shooting` says the rest)."""
    from .synth import true_corners

    rng = np.random.default_rng([int(seed), 2024])
    order = sorted(truth.cameras, key=lambda name: equivalent_focal_of(truth.cameras[name]))
    views = list(truth.view_poses)
    corners = true_corners(truth)
    shown = [v for v in views if np.isfinite(corners[truth.reference][v]).all()]
    retake_view = shown[len(shown) // 2] if shooting.retake and shown else None
    slow = views[len(views) // 2] if shooting.slow_switch_s is not None else None
    stray = {len(views) - 1 if i < 0 else i for i in shooting.stray_after}
    missed = set(shooting.missed)
    script, taken, number = [], _START, first_number

    def shoot(camera, view):
        nonlocal number
        script.append(ScriptedShot(f"IMG_{number:04d}.JPG", camera, view, taken))
        number += 1

    for vi, view in enumerate(views):
        names = [n for n in order if (n, vi) not in missed]
        for ci, name in enumerate(names):
            if ci == 0:
                gap = rng.uniform(*shooting.position_gap_s)
            elif view == slow and ci == len(names) - 1:
                gap = shooting.slow_switch_s
            else:
                gap = rng.uniform(*shooting.lens_gap_s)
            taken += timedelta(seconds=float(gap))
            shoot(name, view)
            if view == retake_view and name == truth.reference:
                taken += timedelta(seconds=float(rng.uniform(1.5, 3.0)))
                shoot(name, view)
        if vi in stray:                        # the floor, between two positions or after the last
            taken += timedelta(seconds=float(rng.uniform(*shooting.stray_gap_s)))
            shoot(None, None)
    return script


def roll_without_exif(focal_px: dict[str, float], fisheye: tuple[str, ...], seed: int, views: int = 12,
                  noise_px: float = 0.1):
    """A tripod session (:func:`shooting_script`) of a rig whose lenses share one size (:func:`shared_size_rig`),
    as a browser uploads it, without EXIF, and without rendering: ``(truth, photos, uv, true_camera)``, the photos'
    headers (:class:`dualcal.files.photos.Photo`, no metadata), their corners by path (the truth's with ``noise_px``
    of noise; None where the photo shows no whole board) and each photo's true camera by file name (None: no
    board)."""
    truth = make_truth(shared_size_rig(focal_px, fisheye), views=views, seed=seed, scale=0.25)
    rng = np.random.default_rng(seed)
    corners = true_corners(truth)
    photos, uv, true_camera = [], {}, {}
    for s in shooting_script(truth, Shooting(), seed):
        cam = truth.cameras[s.camera or truth.reference]
        photos.append(Photo(Path("/roll") / s.name, tuple(cam.image_size), {}))
        seen = s.camera is not None and np.isfinite(corners[s.camera][s.view]).all()
        uv[photos[-1].path] = (corners[s.camera][s.view] + rng.normal(0, noise_px, corners[s.camera][s.view].shape)
                               if seen else None)
        true_camera[s.name] = s.camera
    return truth, photos, uv, true_camera


def write_camera_roll(truth, folder, seed: int = 0, device: str = "synthetic phone", first_number: int = 101,
                      shooting: Shooting = Shooting(), sidecars: bool = True, jobs: int | None = None,
                      progress: bool = True, **render_kwargs) -> dict:
    """Write the photos of ``truth`` (:class:`~dualcal.synthetic.synth.SynthTruth`) as one camera-roll folder,
    shot as ``shooting`` says (``render_kwargs``: :func:`dualcal.synthetic.render.write_photo_set`'s, e.g. ``marks``).

    Parameters
    ----------
    truth : SynthTruth
        The synthetic rig (:func:`dualcal.synthetic.synth.make_truth`).
    folder : str or Path
        The camera roll's folder (created).
    seed : int
        Seed of the photos and of the times between the shots.
    device : str
        The EXIF model of the phone.
    first_number : int
        The number of the first photo, ``IMG_0101.JPG``.
    shooting : Shooting
        How the session is shot: the times between the shots, retakes, stray photos.
    sidecars : bool
        Add an ``.AAE`` and a ``.MOV`` file, as a phone's export does.
    jobs : int or None
        Photos rendered at once (default: all cores).
    progress : bool
        Draw a progress bar on stderr.
    **render_kwargs
        Passed on to :func:`dualcal.synthetic.render.write_photo_set`.

    Returns
    -------
    dict
        The roll as it was shot: ``{"photos": {file name: (camera, view)}, "retake": (first, second),
        "stray": [file names], "sidecars": [file names]}`` (camera None for the photos without the board).
    """
    from .render import write_photo_set

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([int(seed), 2025])
    script = shooting_script(truth, shooting, seed, first_number)
    shot = {"photos": {s.name: (s.camera, s.view) for s in script}, "retake": None,
            "stray": [s.name for s in script if s.camera is None], "sidecars": []}
    with tempfile.TemporaryDirectory(dir=folder.parent) as tmp:
        rendered = write_photo_set(truth, tmp, seed=seed, jobs=jobs, progress=progress, **render_kwargs)
        cam = truth.cameras[truth.reference]
        for before, s in zip([None] + script, script):
            if s.camera is not None:
                data, exif_cam = rendered[s.camera][s.view].read_bytes(), truth.cameras[s.camera]
                if before is not None and (before.camera, before.view) == (s.camera, s.view):
                    shot["retake"] = (before.name, s.name)
                    # a retake is another exposure, never the same file: encoded again, a little differently
                    data = _reencoded(data, 90)
            else:
                w, h = cam.image_size
                pixels = (rng.normal(120, 25, (h // 8, w // 8)).clip(0, 255)).astype(np.uint8)
                floor = np.asarray(Image.fromarray(pixels).resize((w, h), Image.BILINEAR))
                data, exif_cam = encode_jpeg(floor, 85), cam
            write_bytes_atomic(folder / s.name, _with_exif(data, _exif_bytes(exif_cam, s.taken, device)))
        if sidecars:
            names = sorted(shot["photos"])
            aae, mov = Path(names[0]).with_suffix(".AAE").name, Path(names[1]).with_suffix(".MOV").name
            write_bytes_atomic(folder / aae,
                               b'<?xml version="1.0" encoding="UTF-8"?>\n<plist version="1.0"><dict/></plist>\n')
            write_bytes_atomic(folder / mov, b"\x00\x00\x00\x14ftypqt  \x00\x00\x00\x00qt  ")
            shot["sidecars"] = [aae, mov]
    return shot


def strip_exif(folder, out_folder, quality: int = 92) -> list[Path]:
    """Re-encode the JPEGs of ``folder`` into ``out_folder`` without EXIF (Pillow), as a phone's browser
    uploads them; other files are not copied. Returns the written paths."""
    out_folder = Path(out_folder)
    out_folder.mkdir(parents=True, exist_ok=True)
    written = []
    for path in sorted(Path(folder).iterdir()):
        if path.suffix.lower() in (".jpg", ".jpeg"):
            write_bytes_atomic(out_folder / path.name, _reencoded(path.read_bytes(), quality))
            written.append(out_folder / path.name)
    return written
