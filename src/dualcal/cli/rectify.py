"""``dualcal rectify``: a stereo-rectified pair of photos, OpenCV's R1 R2 P1 P2 Q, an epipolar check."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import LazyChoice, echo

EPIPOLAR_IMAGE = "epipolar.jpg"


def _pair(specs: tuple[str, str]) -> dict[str, Path]:
    """``("wide=a.jpg", "tele=b.jpg")`` -> ``{"wide": Path("a.jpg"), "tele": Path("b.jpg")}``."""
    from ..files.dataset import parse_camera_spec

    pair = {}
    for spec in specs:
        name, image = parse_camera_spec(spec)
        if name in pair:
            raise InputError(f"--pair names camera {name!r} twice: give one photo of each of two cameras")
        pair[name] = Path(image)
    return pair


@cli.command("rectify")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--pair", "pair_specs", nargs=2, required=True, metavar="NAME=IMAGE NAME2=IMAGE2",
              help="The two photos, one of each camera, taken at one instant; the first is OpenCV's camera 1.")
@click.option("-o", "--output", "out_dir", required=True, metavar="OUTDIR",
              type=click.Path(file_okay=False, path_type=Path), help="Output folder (created if its parent exists).")
@click.option("--keep", type=LazyChoice("dualcal.files.stereo:KEEP_REGIONS"), default="valid", show_default=True,
              help="valid: the region both photos fill, no empty border (OpenCV alpha=0); all: every pixel "
                   "of both photos (alpha=1).")
def rectify_command(calib: Path, pair_specs: tuple[str, str], out_dir: Path, keep: str) -> None:
    """Stereo-rectify a pair of photos of two cameras of the rig (OpenCV's stereoRectify).

    Both photos are turned into one ideal camera (no distortion, square pixels, the smaller focal
    length of the two, so a tele photo is reduced to the wide's scale) seen from each camera's
    perspective centre, so that corresponding points lie on the same row, or on the same column
    for a vertical baseline (like a phone's wide + tele above each other). Where the calibration models a
    camera's focus, its photo is taken with its camera at the focus its metadata states.

    \b
    OUTDIR/<NAME>-<stem>.<ext>  the two rectified photos (EXIF kept)
    OUTDIR/rectify.json         R1 R2 P1 P2 Q (OpenCV's conventions), camera names, output size
    OUTDIR/epipolar.jpg         both photos side by side (stacked for a vertical rig) with lines
                                along which corresponding points must lie
    """
    import numpy as np

    from ..estimation.focus_model import rig_at_focus
    from ..files.photos import open_image, output_suffix, read_focus
    from ..files.io import (calibration_fingerprint, check_output_file, load_rig, make_output_folder, write_jpeg_atomic,
                            write_json_atomic)
    from ..files.stereo import epipolar_check_image, rectify_pair_files, stereo_rectify

    photos = _pair(pair_specs)
    rig = rig_at_focus(load_rig(calib), {name: read_focus(path).focus_m for name, path in photos.items()})
    first, second = photos
    rect = stereo_rectify(rig, first, second, keep)
    out = make_output_folder(out_dir)
    doc_path, check_path = out / "rectify.json", out / EPIPOLAR_IMAGE
    for path in (doc_path, check_path):
        check_output_file(path)
    for name, photo in photos.items():
        if (out / f"{name}-{photo.stem}{output_suffix(photo)}").resolve() == photo.resolve():
            raise InputError(f"{photo}: the output would overwrite the original photo; choose another -o")
    written = rectify_pair_files(rig, rect, photos, out)
    images = []
    for name in rect.names:
        with open_image(written[name]) as img:
            images.append(np.asarray(img.convert("RGB")))
    check = epipolar_check_image(images, rect.vertical)
    write_jpeg_atomic(check_path, np.ascontiguousarray(check[..., ::-1]), 90)
    write_json_atomic(doc_path, {**rect.to_dict(), "calibration": str(calib),
                                 "calibration_fingerprint": calibration_fingerprint(rig),
                                 "photos": {n: {"source": str(photos[n]), "rectified": written[n].name}
                                            for n in rect.names},
                                 "epipolar_check": EPIPOLAR_IMAGE})
    w, h = rect.image_size
    layout = "same column (vertical rig)" if rect.vertical else "same row (horizontal rig)"
    echo(f"rectified {first} + {second} to {w}x{h} px, f = {rect.camera.fx:.2f} px, baseline "
         f"{abs(rect.baseline_mm):.3f} mm, corresponding points on the {layout}: wrote "
         f"{', '.join(written[n].name for n in rect.names)}, rectify.json and {EPIPOLAR_IMAGE} in {out}")
