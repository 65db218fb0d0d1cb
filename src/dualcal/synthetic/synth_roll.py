"""A synthetic camera roll: a rig's photos as a phone's camera app leaves them in one folder.

:func:`write_camera_roll` renders every camera and view of a synthetic rig (:func:`dualcal.synthetic.render.write_photo_set`)
and lays the photos out as a tripod session does (CONTRACT.md, "A phone's camera roll"): one flat folder,
``IMG_0101.JPG``, ``IMG_0102.JPG``, ... in shooting order; at each board position every lens shoots in turn,
a few seconds apart (widest first), then the board is moved (tens of seconds). Each photo carries the EXIF a
phone writes: ``Make``, ``Model``, ``LensModel``, ``FocalLength``, ``FocalLengthIn35mmFilm``,
``DateTimeOriginal`` and ``SubSecTimeOriginal``, inserted into the JPEG without re-encoding it. The roll also
holds what real ones do: a retake (one position's reference photo shot twice), a photo without the board,
an ``.AAE`` sidecar file and a ``.MOV`` Live Photo clip.

The 35 mm-equivalent focal length of a camera is ``fx * 43.27 mm / image diagonal (px)``, its focal
length in mm that divided by a phone sensor's typical crop factor (:data:`CROP_FACTOR`).
"""

from __future__ import annotations

import struct
import tempfile
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
from PIL import Image, TiffImagePlugin

from ..files.io import encode_jpeg, write_bytes_atomic
from ..geometry.camera import equivalent_focal_35mm
from ..files.roll import camera_class

__all__ = ["CROP_FACTOR", "equivalent_focal_of", "write_camera_roll"]

#: A phone sensor's crop factor by camera class (an iPhone's ultra-wide 2.2 mm is 13 mm equivalent, its
#: main camera 6.9 mm 24 mm, its tele 9 mm 77 mm): it sets only EXIF's focal length in mm.
CROP_FACTOR = {"ultra": 6.0, "wide": 3.5, "tele": 8.5}
_START = datetime(2026, 11, 30, 10, 0, 0)


def equivalent_focal_of(cam) -> float:
    """The 35 mm-equivalent focal length (mm) of a :class:`~dualcal.geometry.camera.CameraModel`."""
    return equivalent_focal_35mm(cam.image_size, cam.fx)


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


def _with_exif(jpeg: bytes, payload: bytes) -> bytes:
    """A JPEG with an APP1 EXIF segment inserted after its SOI marker (the image data untouched)."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG")
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def write_camera_roll(truth, folder, seed: int = 0, device: str = "synthetic phone", first_number: int = 101,
                      retake: bool = True, stray_photo: bool = True, sidecars: bool = True, jobs: int | None = None,
                      progress: bool = True, **render_kwargs) -> dict:
    """Write the photos of ``truth`` (:class:`~dualcal.synthetic.synth.SynthTruth`) as one camera-roll folder
    (``render_kwargs``: :func:`dualcal.synthetic.render.write_photo_set`'s, e.g. ``marks``).

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
    retake, stray_photo, sidecars : bool
        Add a retake of one photo, a photo without the board, and an ``.AAE`` and a ``.MOV`` file.
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
        "stray": file name, "sidecars": [file names]}`` (camera None for the photo without the board).
    """
    from .render import write_photo_set

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([int(seed), 2024])
    order = sorted(truth.cameras, key=lambda name: equivalent_focal_of(truth.cameras[name]))
    views = list(truth.view_poses)
    shot = {"photos": {}, "retake": None, "stray": None, "sidecars": []}
    with tempfile.TemporaryDirectory(dir=folder.parent) as tmp:
        rendered = write_photo_set(truth, tmp, seed=seed, jobs=jobs, progress=progress, **render_kwargs)
        number, taken = first_number, _START

        def put(data: bytes, cam, what) -> str:
            nonlocal number
            name = f"IMG_{number:04d}.JPG"
            write_bytes_atomic(folder / name, _with_exif(data, _exif_bytes(cam, taken, device)))
            shot["photos"][name] = what
            number += 1
            return name

        retake_view = views[len(views) // 2] if retake else None
        for vi, view in enumerate(views):
            for ci, cam_name in enumerate(order):
                taken += timedelta(seconds=float(rng.uniform(2.0, 6.0)) if ci else float(rng.uniform(25.0, 90.0)))
                data = rendered[cam_name][view].read_bytes()
                name = put(data, truth.cameras[cam_name], (cam_name, view))
                if view == retake_view and cam_name == truth.reference:
                    taken += timedelta(seconds=float(rng.uniform(1.5, 3.0)))
                    shot["retake"] = (name, put(data, truth.cameras[cam_name], (cam_name, view)))
            if stray_photo and vi == 1:                 # the floor, between two positions
                taken += timedelta(seconds=float(rng.uniform(25.0, 90.0)))
                cam = truth.cameras[truth.reference]
                w, h = cam.image_size
                pixels = (rng.normal(120, 25, (h // 8, w // 8)).clip(0, 255)).astype(np.uint8)
                floor = np.asarray(Image.fromarray(pixels).resize((w, h), Image.BILINEAR))
                shot["stray"] = put(encode_jpeg(floor, 85), cam, (None, None))
        if sidecars:
            names = sorted(shot["photos"])
            aae, mov = Path(names[0]).with_suffix(".AAE").name, Path(names[1]).with_suffix(".MOV").name
            write_bytes_atomic(folder / aae,
                               b'<?xml version="1.0" encoding="UTF-8"?>\n<plist version="1.0"><dict/></plist>\n')
            write_bytes_atomic(folder / mov, b"\x00\x00\x00\x14ftypqt  \x00\x00\x00\x00qt  ")
            shot["sidecars"] = [aae, mov]
    return shot
