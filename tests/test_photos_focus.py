"""Where a photo focused, read from its metadata (dualcal.files.photos.read_focus).

The EXIF and MakerNote bytes are built here by hand, as a phone writes them: an Apple MakerNote is
``"Apple iOS\\0"``, a version, the byte order at byte 12 and a TIFF IFD at byte 14 whose offsets count
from the MakerNote's first byte (exiftool's Apple table gives the tags: 0x000c FocusDistanceRange
rational64s[2], 0x002f FocusPosition int32s, 0x0007 AFStable int32s, 0x0038 AFMeasuredDepth int32s,
0x003d AFConfidence int32s, 0x0008 AccelerationVector rational64s[3]).
"""

import struct

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin

from dualcal.errors import InputError
from dualcal.files.photos import apple_maker_note, read_focus

SRATIONAL, SLONG = 10, 9


def apple_note(entries: list[tuple[int, int, tuple]], order: str = ">") -> bytes:
    """An Apple MakerNote holding ``entries`` ``(tag, TIFF type, values)`` (signed rationals as (num, den) pairs),
    values that do not fit in 4 bytes stored after the IFD at offsets from the note's start."""
    header = b"Apple iOS\0" + b"\x00\x01" + (b"MM" if order == ">" else b"II")
    ifd_size = 2 + 12 * len(entries) + 4
    data_at = len(header) + ifd_size
    ifd, data = struct.pack(order + "H", len(entries)), b""
    for tag, kind, values in entries:
        if kind == SRATIONAL:
            payload = b"".join(struct.pack(order + "ii", *v) for v in values)
        else:
            payload = b"".join(struct.pack(order + "i", v) for v in values)
        if len(payload) <= 4:
            ifd += struct.pack(order + "HHI", tag, kind, len(values)) + payload.ljust(4, b"\0")
        else:
            ifd += struct.pack(order + "HHII", tag, kind, len(values), data_at + len(data))
            data += payload
    return header + ifd + b"\0\0\0\0" + data


IPHONE_NOTE = [(0x0007, SLONG, (1,)), (0x0008, SRATIONAL, ((-12, 1000), (-985, 1000), (118, 1000))),
               (0x000C, SRATIONAL, ((66, 100), (68, 100))), (0x002F, SLONG, (143,)), (0x0038, SLONG, (655,)),
               (0x003D, SLONG, (97,))]


def jpeg_with(path, subject_distance=None, maker_note=None, distance_range=None):
    """A small JPEG whose EXIF IFD holds the given tags (as Pillow writes them: rationals, SHORT, UNDEFINED)."""
    exif = Image.Exif()
    exif[0x010F] = "Apple"
    sub = exif.get_ifd(0x8769)
    if subject_distance is not None:
        sub[0x9206] = TiffImagePlugin.IFDRational(*subject_distance)
    if distance_range is not None:
        sub[0xA40C] = distance_range
    if maker_note is not None:
        sub[0x927C] = maker_note
    Image.new("L", (32, 24), 128).save(path, "JPEG", exif=exif.tobytes())
    return path


@pytest.mark.parametrize("order", [">", "<"])
def test_an_iphone_maker_note_gives_its_focus_distance_range_and_position(tmp_path, order):
    facts = read_focus(jpeg_with(tmp_path / "IMG_0001.JPG", maker_note=apple_note(IPHONE_NOTE, order)))
    assert facts.apple["FocusDistanceRange"] == pytest.approx((0.66, 0.68))
    assert facts.apple["FocusPosition"] == 143 and facts.apple["AFStable"] == 1
    assert facts.apple["AFMeasuredDepth"] == 655 and facts.apple["AFConfidence"] == 97
    assert facts.apple["AccelerationVector"] == pytest.approx((-0.012, -0.985, 0.118))
    assert facts.focus_m == pytest.approx(0.67) and facts.source == "Apple FocusDistanceRange"


def test_exif_subject_distance_is_the_focus_without_a_maker_note(tmp_path):
    facts = read_focus(jpeg_with(tmp_path / "a.jpg", subject_distance=(1250, 1000), distance_range=2))
    assert facts.subject_distance_m == pytest.approx(1.25) and facts.subject_distance_range == "close view"
    assert facts.apple == {} and facts.focus_m == pytest.approx(1.25) and facts.source == "EXIF SubjectDistance"


def test_the_maker_note_wins_over_subject_distance_and_infinity_is_no_focus(tmp_path):
    both = read_focus(jpeg_with(tmp_path / "b.jpg", subject_distance=(2, 1), maker_note=apple_note(IPHONE_NOTE)))
    assert both.focus_m == pytest.approx(0.67)
    far = read_focus(jpeg_with(tmp_path / "c.jpg", subject_distance=(0xFFFFFFFF, 1)))
    assert far.subject_distance_m == np.inf and far.focus_m is None
    unknown = read_focus(jpeg_with(tmp_path / "d.jpg", subject_distance=(0, 1)))
    assert unknown.subject_distance_m is None and unknown.focus_m is None


def test_a_photo_without_focus_tags_gives_none(tmp_path):
    plain = tmp_path / "plain.png"
    Image.new("L", (16, 16)).save(plain)
    facts = read_focus(plain)
    assert facts.focus_m is None and facts.source is None and facts.apple == {}
    other = read_focus(jpeg_with(tmp_path / "other.jpg", maker_note=b"Nikon\0\x02\x10\0\0MM\0*\0\0\0\x08\0\0"))
    assert other.apple == {} and other.focus_m is None


def test_a_dng_keeps_subject_distance_in_ifd0(tmp_path):
    """TIFF/EP (and so a DNG) may carry SubjectDistance in IFD 0 itself; a DNG's metadata is read as a TIFF's."""
    path = tmp_path / "raw.dng"
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[0x9206] = TiffImagePlugin.IFDRational(45, 100)
    Image.new("L", (16, 16)).save(path, "TIFF", tiffinfo=info)
    assert read_focus(path).focus_m == pytest.approx(0.45)


def test_malformed_maker_notes_are_ignored_and_unreadable_files_refused(tmp_path):
    note = apple_note(IPHONE_NOTE)
    assert apple_maker_note(note[:20]) == {}                 # the IFD cut short
    cut = apple_maker_note(note[:-10])                       # FocusDistanceRange's values, stored last, cut off
    assert "FocusDistanceRange" not in cut and cut["FocusPosition"] == 143
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(b"not a photo")
    with pytest.raises(InputError, match="not a readable image"):
        read_focus(broken)
