"""Finding cameras and photos, pairing views, EXIF metadata, and clear errors."""

import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from dualcal.files.dataset import open_dataset, open_image, read_exif, read_gray
from dualcal.files.io import make_output_folder
from dualcal.errors import InputError


def _photo(path, size=(64, 48), taken=None, orientation=None, make=None, fmt=None, value=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = np.full((size[1], size[0]), value, np.uint8)
    code = zlib.crc32(str(path).encode())   # every photo its own content (identical files count once): the
    for k in range(min(size[0] // 8, 8)):   # top 8x8 blocks grey levels from the path's checksum
        pixels[:8, 8 * k:8 * k + 8] = ((code >> (4 * k)) & 15) * 16
    img = Image.fromarray(pixels)
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    if make is not None:
        exif[0x010F], exif[0x0110] = make
    if taken is not None or make is not None:
        sub = exif.get_ifd(0x8769)
        if taken is not None:
            sub[0x9003] = taken
        if make is not None:
            sub[0x920A], sub[0xA405] = 4.25, 26
    img.save(path, format=fmt, exif=exif.tobytes())
    return path


def test_one_subfolder_per_camera_pairs_by_stem(tmp_path):
    for cam in ("wide", "tele"):
        for v in ("IMG_01", "IMG_02"):
            _photo(tmp_path / cam / f"{v}.jpg", size=(64, 48) if cam == "wide" else (32, 48))
    ds = open_dataset(tmp_path)
    assert sorted(ds.cameras) == ["tele", "wide"] and ds.reference == "wide"
    assert list(ds.cameras["tele"]) == ["IMG_01", "IMG_02"]
    assert ds.image_size("wide") == (64, 48) and ds.image_size("tele") == (32, 48)
    assert open_dataset(tmp_path, reference="tele").reference == "tele"


def test_a_folder_of_photos_is_one_camera_named_after_it(tmp_path):
    for v in ("a", "b", "c"):
        _photo(tmp_path / "phone" / f"{v}.png", fmt="PNG")
    ds = open_dataset(tmp_path / "phone")
    assert list(ds.cameras) == ["phone"] and list(ds.cameras["phone"]) == ["a", "b", "c"]


def test_camera_globs_pair_by_the_wildcard_text(tmp_path):
    for v in ("01", "02", "11"):
        _photo(tmp_path / f"left{v}.jpg")
        _photo(tmp_path / f"right{v}.jpg")
    ds = open_dataset(tmp_path, ["left=left*.jpg", "right=right*"])
    assert list(ds.cameras["left"]) == ["01", "02", "11"] == list(ds.cameras["right"])
    assert ds.reference == "left"
    ds = open_dataset(None, [("r", str(tmp_path / "right?1.jpg"))])
    assert list(ds.cameras["r"]) == ["0", "1"]


@pytest.mark.parametrize("prefix", ["./", "", "sub/../"])
def test_globs_spelled_with_dot_slash_pair_like_plain_ones(tmp_path, monkeypatch, prefix):
    (tmp_path / "sub").mkdir()
    for v in ("01", "02"):
        _photo(tmp_path / f"left{v}.jpg")
        _photo(tmp_path / f"right{v}.jpg")
    monkeypatch.chdir(tmp_path)
    ds = open_dataset(None, [f"left={prefix}left*.jpg", f"right={prefix}right*.jpg"])
    assert list(ds.cameras["left"]) == ["01", "02"] == list(ds.cameras["right"])


def test_two_photos_with_one_stem_are_an_error_naming_both(tmp_path):
    _photo(tmp_path / "cam" / "IMG_01.jpg")
    _photo(tmp_path / "cam" / "IMG_01.JPG")
    with pytest.raises(InputError, match=r"IMG_01\.JPG.*IMG_01\.jpg|IMG_01\.jpg.*IMG_01\.JPG"):
        open_dataset(tmp_path / "cam")
    with pytest.raises(InputError, match="same name 'IMG_01'"):
        open_dataset(tmp_path, ["cam=cam/IMG_*"], pair_by="time")


def test_a_folder_that_cannot_be_listed_is_an_input_error(tmp_path, monkeypatch):
    _photo(tmp_path / "wide" / "a.jpg")
    listing = Path.iterdir

    def refuse(self):
        if self.name == "wide":
            raise PermissionError(13, "Permission denied")
        return listing(self)

    monkeypatch.setattr(Path, "iterdir", refuse)
    with pytest.raises(InputError, match="'.*wide' cannot be listed \\(Permission denied\\)"):
        open_dataset(tmp_path)


def test_output_folders_are_created_only_below_an_existing_folder(tmp_path):
    assert make_output_folder(tmp_path / "new").is_dir()
    assert make_output_folder(tmp_path / "new") == tmp_path / "new"        # existing: fine
    with pytest.raises(InputError, match="parent does not exist"):
        make_output_folder(tmp_path / "missing" / "new")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="cannot be created"):
        make_output_folder(tmp_path / "file")


def test_pair_by_exif_time_uses_the_reference_stems(tmp_path):
    _photo(tmp_path / "wide" / "W1.jpg", taken="2024:05:01 10:00:00")
    _photo(tmp_path / "wide" / "W2.jpg", taken="2024:05:01 10:00:30")
    _photo(tmp_path / "tele" / "T7.jpg", taken="2024:05:01 10:00:31")
    _photo(tmp_path / "tele" / "T8.jpg", taken="2024:05:01 10:00:01")
    _photo(tmp_path / "tele" / "T9.jpg", taken="2024:05:01 11:00:00")
    ds = open_dataset(tmp_path, pair_by="time", time_tolerance_s=2)
    tele = {k: p.path.name for k, p in ds.cameras["tele"].items()}
    assert tele == {"W1": "T8.jpg", "W2": "T7.jpg", "tele:T9": "T9.jpg"}


def test_exif_is_reported_and_orientation_never_applied(tmp_path):
    path = _photo(tmp_path / "cam" / "x.jpg", size=(40, 30), orientation=6, make=("Acme", "Phone 1"),
                  taken="2024:01:02 03:04:05")
    size, exif = read_exif(path)
    assert size == (40, 30)
    assert exif["orientation"] == 6 and exif["make"] == "Acme" and exif["model"] == "Phone 1"
    assert exif["focal_length_mm"] == pytest.approx(4.25) and exif["focal_length_35mm_mm"] == 26
    assert read_gray(path).shape == (30, 40)           # stored frame, not turned
    meta = open_dataset(tmp_path / "cam").meta("cam")
    assert meta["exif_orientation"] == {"x": 6}
    assert meta["exif"]["model"] == "Phone 1" and meta["photos"] == {"x": str(path)}


def test_heic_photos_are_read(tmp_path):
    pytest.importorskip("pillow_heif").register_heif_opener()      # for Pillow to write HEIC here
    path = tmp_path / "cam" / "a.heic"
    path.parent.mkdir()
    Image.fromarray(np.full((48, 64, 3), 200, np.uint8)).save(path, format="HEIF")
    ds = open_dataset(tmp_path / "cam")
    assert ds.image_size("cam") == (64, 48)
    assert read_gray(path).shape == (48, 64)


def _rotated_heic(path, orientation: int) -> np.ndarray:
    """A lossless HEIC whose stored pixels are returned; pillow-heif writes irot/imir for the tag."""
    pytest.importorskip("pillow_heif").register_heif_opener()      # for Pillow to write HEIC here
    stored = np.zeros((48, 64), np.uint8)
    stored[:8, :16] = 250                      # marks the stored frame's top-left
    stored[40:, 56:] = 120
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored).convert("RGB").save(path, format="HEIF", exif=exif.tobytes(), quality=-1,
                                                chroma=444)
    return stored


@pytest.mark.parametrize("orientation", [1, 2, 3, 4, 5, 6, 7, 8])
def test_heic_is_read_in_its_stored_frame_with_its_orientation_reported(tmp_path, orientation):
    path = tmp_path / "cam" / "a.heic"
    path.parent.mkdir()
    stored = _rotated_heic(path, orientation)
    with Image.open(path) as img:              # pillow-heif alone turns it for display
        assert img.size == ((48, 64) if orientation >= 5 else (64, 48))
    size, exif = read_exif(path)
    assert size == (64, 48)
    assert exif["orientation"] == orientation
    np.testing.assert_allclose(read_gray(path), stored, atol=2)
    with open_image(path) as img:
        assert img.format == "HEIF" and img.size == (64, 48)
        if orientation != 1:                   # the tag travels with the pixels it describes
            assert img.getexif()[0x0112] == orientation
    ds = open_dataset(tmp_path / "cam")
    assert ds.image_size("cam") == (64, 48)
    assert ds.meta("cam").get("exif_orientation", {}).get("a") == (None if orientation == 1 else orientation)


@pytest.mark.parametrize("setup, message", [
    (lambda d: None, "does not exist"),
    (lambda d: d.mkdir(), "holds no photos"),
    (lambda d: (_photo(d / "a.jpg", size=(64, 48)), _photo(d / "b.jpg", size=(48, 64))), "differ in size"),
])
def test_bad_datasets_raise_one_clear_error(tmp_path, setup, message):
    d = tmp_path / "ds"
    setup(d)
    with pytest.raises(InputError, match=message):
        open_dataset(d)


def test_bad_camera_options_raise_clear_errors(tmp_path):
    _photo(tmp_path / "a1.jpg")
    with pytest.raises(InputError, match="matches no photo"):
        open_dataset(tmp_path, ["b=b*.jpg"])
    with pytest.raises(InputError, match="NAME=GLOB"):
        open_dataset(tmp_path, ["nonsense"])
    with pytest.raises(InputError, match="not a camera"):
        open_dataset(tmp_path, ["a=a*.jpg"], reference="tele")
    with pytest.raises(InputError, match="no EXIF capture time"):
        _photo(tmp_path / "c1.jpg")
        open_dataset(tmp_path, ["a=a*.jpg", "c=c*.jpg"], pair_by="time")


def test_truncated_and_corrupt_photos_raise_input_errors(tmp_path):
    good = _photo(tmp_path / "good.jpg", value=90)
    assert read_gray(good).shape == (48, 64)
    data = good.read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) - 40])
    with pytest.raises(InputError, match="truncated"):
        read_gray(tmp_path / "cut.jpg")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(InputError, match="cannot be decoded"):
        read_gray(tmp_path / "junk.png")


def test_unreadable_files_are_skipped_with_a_warning(tmp_path, capsys):
    _photo(tmp_path / "cam" / "good.jpg")
    (tmp_path / "cam" / "bad.jpg").write_text("not an image")
    ds = open_dataset(tmp_path / "cam")
    assert list(ds.cameras["cam"]) == ["good"]
    assert "bad.jpg" in capsys.readouterr().err


def test_a_subfolder_without_photos_beside_photos_is_ignored(tmp_path):
    """Like the real huawei-y5-2017 set: photos and a reference/ folder holding only notes."""
    _photo(tmp_path / "phone" / "a.jpg")
    (tmp_path / "phone" / "reference").mkdir()
    (tmp_path / "phone" / "reference" / "README.md").write_text("notes")
    assert list(open_dataset(tmp_path / "phone").cameras) == ["phone"]


@pytest.mark.parametrize("setup, message", [
    (lambda d: (_photo(d / "wide" / "a.jpg"), (d / "tele").mkdir()), "camera folder .*tele.* holds no photos"),
    (lambda d: (_photo(d / "wide" / "a.jpg"), _photo(d / "shot.png")), "holds photos .* subfolders with photos"),
])
def test_datasets_that_would_lose_photos_or_a_camera_are_refused(tmp_path, setup, message):
    d = tmp_path / "ds"
    d.mkdir()
    setup(d)
    with pytest.raises(InputError, match=message):
        open_dataset(d)


def test_exclude_leaves_photos_out_and_lists_them(tmp_path):
    for cam in ("wide", "tele"):
        for k in (1, 2, 3):
            _photo(tmp_path / cam / f"IMG_0{k}.jpg")
    ds = open_dataset(tmp_path, exclude=["IMG_02", "tele/IMG_03"])
    assert sorted(ds.cameras["wide"]) == ["IMG_01", "IMG_03"] and sorted(ds.cameras["tele"]) == ["IMG_01"]
    assert sorted(ds.excluded["tele"]) == ["IMG_02", "IMG_03"]
    assert ds.meta("tele")["excluded"]["IMG_03"].endswith("IMG_03.jpg")


def test_a_photo_stored_turned_is_left_out_with_a_warning_not_taken_for_a_camera(tmp_path, capsys):
    """Issue 33: one phone's photos, one stored turned (its size the others' transposed), in a folder of photos
    and in a camera's folder: that photo is left out, saying it is turned; the rest is one camera."""
    for folder in (tmp_path / "phone", tmp_path / "set" / "wide"):
        for k in range(4):
            _photo(folder / f"IMG_0{k}.jpg", make=("Nokia", "N9"))
        _photo(folder / "IMG_09.jpg", size=(48, 64), make=("Nokia", "N9"))
    for path, name in ((tmp_path / "phone", "phone"), (tmp_path / "set", "wide")):
        ds = open_dataset(path)
        assert list(ds.cameras) == [name] and sorted(ds.cameras[name]) == [f"IMG_0{k}" for k in range(4)]
        assert not ds.split_pending and ds.skipped[0][0].name == "IMG_09.jpg"
        assert "IMG_09.jpg: left out (stored turned: 48x64, where 4 other photo(s) of the same camera are 64x48)" \
            in capsys.readouterr().err


def test_a_folder_of_photos_without_exif_awaits_its_boards_to_tell_its_cameras(tmp_path):
    """Photos as a phone's browser uploads them: one camera per image size until the boards tell them apart
    (dualcal.files.roll.cameras_from_boards); nothing is refused for its sizes."""
    for k in range(3):
        _photo(tmp_path / "upload" / f"image{k}.jpg")
        _photo(tmp_path / "upload" / f"image{k + 3}.jpg", size=(40, 30))
    ds = open_dataset(tmp_path / "upload", exclude=["image1"])
    assert ds.split_pending and ds.roll is None and ds.roll_options["exclude"] == ("image1",)
    assert {n: sorted(v) for n, v in ds.cameras.items()} == {"40x30": ["image3", "image4", "image5"],
                                                              "64x48": ["image0", "image1", "image2"]}
