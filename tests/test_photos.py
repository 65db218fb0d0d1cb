"""Reading a photo's pixels (:func:`dualcal.files.photos.read_gray`): JPEGs through libjpeg-turbo's simplejpeg,
pixel for pixel what OpenCV decodes, in the stored frame; what it cannot read falls back to OpenCV."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from dualcal.files.photos import decode_jpeg_gray, read_gray
from dualcal.synthetic.render import render_view
from dualcal.synthetic.synth import make_truth


@pytest.fixture(scope="module")
def render() -> np.ndarray:
    """A small photo-like render of a board (grey, with the room's clutter and sensor noise)."""
    truth = make_truth("note8", views=1, seed=3, scale=0.15)
    view = next(iter(truth.view_poses))
    return render_view(truth.cameras["wide"], truth.camera_pose("wide", view), truth.board, np.random.default_rng(3))


def _opencv_gray(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)


def _jpeg(img, **save) -> bytes:
    buf = io.BytesIO()
    (img if isinstance(img, Image.Image) else Image.fromarray(img)).save(buf, "JPEG", **save)
    return buf.getvalue()


def _colour(gray: np.ndarray) -> np.ndarray:
    g = gray.astype(int)
    return np.clip(np.stack([g + 12, g, g - 9], axis=-1), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("kind", ["grey", "colour 4:2:0", "colour 4:4:4", "progressive", "restart markers", "CMYK"])
def test_a_jpeg_is_decoded_to_opencvs_pixels_exactly(tmp_path, render, kind):
    img = {"grey": render, "CMYK": Image.fromarray(_colour(render)).convert("CMYK")}.get(kind, _colour(render))
    save = {"colour 4:4:4": {"subsampling": 0}, "progressive": {"progressive": True},
            "restart markers": {"restart_marker_blocks": 4}}.get(kind, {})
    data = _jpeg(img, quality=90, **save)
    path = tmp_path / "IMG_01.jpg"
    path.write_bytes(data)
    gray = read_gray(path)
    assert gray.shape == render.shape and gray.dtype == np.uint8 and gray.flags.c_contiguous
    np.testing.assert_array_equal(gray, _opencv_gray(data))
    np.testing.assert_array_equal(decode_jpeg_gray(data), gray)


def test_the_exif_orientation_is_never_applied(tmp_path, render):
    exif = Image.Exif()
    exif[0x0112] = 6                                   # "turn 90 degrees clockwise to view"
    data = _jpeg(render, quality=90, exif=exif.tobytes())
    (tmp_path / "IMG_01.jpg").write_bytes(data)
    gray = read_gray(tmp_path / "IMG_01.jpg")
    assert gray.shape == render.shape                  # stored frame: H x W as stored, not turned
    np.testing.assert_array_equal(gray, _opencv_gray(data))


def test_a_jpeg_libjpeg_turbo_is_strict_about_falls_back_to_opencv(tmp_path, render):
    """Corrupt entropy-coded data that libjpeg recovers from with a warning: simplejpeg refuses it, OpenCV decodes
    what it can, as dualcal always did."""
    good = _jpeg(render, quality=90)
    middle = (good.find(b"\xff\xda") + len(good)) // 2
    corrupt = good[:middle] + b"\xff\xd3" + good[middle:]           # a restart marker where none belongs
    assert decode_jpeg_gray(corrupt) is None
    (tmp_path / "IMG_01.jpg").write_bytes(corrupt)
    expected = _opencv_gray(corrupt)
    assert expected is not None
    np.testing.assert_array_equal(read_gray(tmp_path / "IMG_01.jpg"), expected)
