"""Photos that are not what they say (issue 24, findings 6 and 7): a header that no photo has is refused before
decoding, a PNG named .jpg is decoded by its content, a broken symbolic link is skipped with a warning."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from dualcal.files.dataset import open_dataset
from dualcal.errors import InputError
from dualcal.files.photos import check_plausible_photo, open_image, read_gray


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _png_claiming(path, width: int, height: int, size_bytes: int):
    """A PNG whose header says ``width x height`` (8-bit grey) in a file of about ``size_bytes``."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    body = zlib.compress(b"\0" * 1000)
    pad = _chunk(b"tEXt", b"pad\0" + b"x" * max(0, size_bytes - 200))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + pad + _chunk(b"IDAT", body) + _chunk(b"IEND", b""))
    return path


def test_a_header_that_no_photo_has_is_refused_before_decoding(tmp_path):
    """The finding: a 190 KB PNG of 13000 x 13000 took 26 s and 1.3 GB before anything was said."""
    bomb = _png_claiming(tmp_path / "IMG_01.png", 13000, 13000, 190_000)
    for read in (read_gray, open_image):
        with pytest.raises(InputError, match=r"13000 x 13000 px \(169 MP\) in 190 KB, which no photo is"):
            read(bomb)


def test_a_large_photo_is_not_refused_for_its_size():
    check_plausible_photo("a 200 MP photo", (16320, 12240), 25_000_000)      # 200 MP in 25 MB: a photo
    check_plausible_photo("a small drawing", (2000, 1500), 3_000)            # small: never judged by its bytes
    with pytest.raises(InputError, match="which no photo is"):
        check_plausible_photo("x", (40000, 40000), 10**10)                   # 1.6 GP: beyond any phone


def test_a_png_named_jpg_is_decoded_by_its_content(tmp_path):
    img = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    Image.fromarray(img).save(tmp_path / "IMG_01.jpg", format="PNG")
    np.testing.assert_array_equal(read_gray(tmp_path / "IMG_01.jpg"), img)
    data = (tmp_path / "IMG_01.jpg").read_bytes()
    Image.fromarray(img).save(tmp_path / "cut.jpg", format="JPEG")
    (tmp_path / "cut.jpg").write_bytes((tmp_path / "cut.jpg").read_bytes()[:-100])
    with pytest.raises(InputError, match="truncated or corrupt JPEG"):     # a real JPEG cut short still is one
        read_gray(tmp_path / "cut.jpg")
    assert data.startswith(b"\x89PNG")


def test_a_broken_symlink_is_skipped_with_a_warning_naming_it(tmp_path, capsys):
    cam = tmp_path / "set" / "wide"
    cam.mkdir(parents=True)
    Image.new("L", (64, 48)).save(cam / "IMG_01.jpg")
    (cam / "IMG_02.jpg").symlink_to(tmp_path / "gone.jpg")
    ds = open_dataset(tmp_path / "set")
    assert [photo.path.name for photo in ds.cameras["wide"].values()] == ["IMG_01.jpg"]
    err = capsys.readouterr().err
    assert "IMG_02.jpg is a broken symbolic link" in err and "gone.jpg" in err
