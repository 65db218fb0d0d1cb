"""RAW (DNG) photos (dualcal.files.photos): read as the sensor recorded them, detected, calibrated.

The DNGs are written by ``tests/dngfile.py`` (pidng): a render of the board with known truth,
mosaicked to a Bayer frame, so every test knows what each sensor pixel holds.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import cv2
import numpy as np
import pytest
import rawpy
from dngfile import write_dng, write_linear_dng

from dualcal.geometry.board import Board
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.files.dataset import open_dataset
from dualcal.files.detect import detect_dataset, detect_photo
from dualcal.errors import InputError
from dualcal.files.photos import (PHOTO_SUFFIXES, Photo, jobs_within_memory, open_image, read_exif, read_gray,
                                  source_format)
from dualcal.files.rectify import undistort_files
from dualcal.synthetic.render import photo_seed, render_view, write_photo_set
from dualcal.files.io import load_rig, save_rig
from dualcal.pages.report import render_report
from dualcal.pages.report.html import source_formats
from dualcal.files.stereo import rectify_pair_files, stereo_rectify
from dualcal.synthetic.synth import make_truth, true_corners, truth_rig_model


def _smooth_image(shape=(48, 64), seed=0) -> np.ndarray:
    """A smooth random grey image: a demosaicked copy of it is close to it pixel for pixel."""
    noise = np.random.default_rng(seed).uniform(0, 255, shape).astype(np.float32)
    img = cv2.GaussianBlur(noise, (0, 0), 2.5)
    img = (img - img.min()) / (img.max() - img.min()) * 200 + 30
    return np.rint(img).astype(np.uint8)


def _shift_error(a: np.ndarray, b: np.ndarray, dy: int, dx: int) -> float:
    """Mean |a - b shifted by (dy, dx)| over their common interior."""
    h, w = a.shape
    m = 3
    return float(np.abs(a[m:h - m, m:w - m].astype(float)
                        - b[m + dy:h - m + dy, m + dx:w - m + dx].astype(float)).mean())


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_dng_pixel_ij_is_sensor_pixel_ij_of_the_active_area(tmp_path, pattern):
    gray = _smooth_image()
    path = write_dng(tmp_path / "a.dng", gray, pattern=pattern, margin=(4, 6, 2, 2), orientation=6)
    out = read_gray(path)
    assert out.shape == gray.shape and out.dtype == np.uint8
    # the round trip (mosaic, white balance, demosaic, tone) gives the image back where it is smooth ...
    assert _shift_error(gray, out, 0, 0) < 1.5
    # ... and one pixel off it would not: the frame is neither shifted nor turned (orientation 6 not applied)
    assert min(_shift_error(gray, out, dy, dx) for dy, dx in ((0, 1), (1, 0), (1, 1), (0, -1), (-1, 0))) > 4
    with rawpy.imread(str(path)) as raw:
        assert (raw.sizes.width, raw.sizes.height) == (gray.shape[1], gray.shape[0])
        assert raw.postprocess(user_flip=0, half_size=False).shape[:2] == gray.shape
    with open_image(path) as img:                      # LibRaw's development: the same frame
        assert img.size == (gray.shape[1], gray.shape[0]) and img.format == "TIFF"
        developed = np.asarray(img.convert("L"))
    assert _shift_error(cv2.equalizeHist(developed), cv2.equalizeHist(out), 0, 0) < 8
    assert read_exif(path)[0] == (gray.shape[1], gray.shape[0])


def test_a_linear_dng_is_read_through_libraws_development_pixel_for_pixel(tmp_path):
    gray = _smooth_image(seed=2)
    out = read_gray(write_linear_dng(tmp_path / "linear.dng", gray))
    assert out.shape == gray.shape
    # another tone curve (LibRaw's BT.709 and colour matrix), the same pixels
    a, b = cv2.equalizeHist(gray), cv2.equalizeHist(out)
    assert _shift_error(a, b, 0, 0) < 4 < min(_shift_error(a, b, dy, dx) for dy, dx in ((0, 1), (1, 0), (1, 1)))


def test_an_odd_active_area_origin_is_moved_to_the_filters_period(tmp_path):
    """LibRaw keeps the frame on the 2 x 2 pattern: an active area starting at row 3, column 5
    is read from row 4, column 6, one row and column fewer (as photos.py documents)."""
    gray = _smooth_image(seed=1)
    path = write_dng(tmp_path / "odd.dng", gray, margin=(3, 5, 1, 2))
    out = read_gray(path)
    assert out.shape == (gray.shape[0] - 1, gray.shape[1] - 1)
    assert read_exif(path)[0] == (gray.shape[1] - 1, gray.shape[0] - 1)
    assert _shift_error(gray[1:, 1:], out, 0, 0) < 1.5


def test_read_exif_of_a_dng_gives_its_size_and_exif_facts(tmp_path):
    taken = datetime(2026, 11, 30, 14, 5, 9)
    path = write_dng(tmp_path / "IMG_0001.dng", _smooth_image(), make="Apple", model="iPhone 15 Pro",
                     orientation=8, taken=taken, focal_length_mm=6.86, focal_length_35mm_mm=24,
                     lens_model="iPhone 15 Pro back triple camera 6.86mm f/1.78")
    size, exif = read_exif(path)
    assert size == (64, 48)
    expected = {"make": "Apple", "model": "iPhone 15 Pro",
                "lens_model": "iPhone 15 Pro back triple camera 6.86mm f/1.78", "focal_length_mm": 6.86, "focal_length_35mm_mm": 24.0, "orientation": 8, "taken": taken}
    assert {k: exif.get(k) for k in expected} == expected
    assert ".dng" in PHOTO_SUFFIXES and source_format(path) == "dng" and source_format("a.JPG") == "jpeg"


@pytest.mark.parametrize("content", [b"", b"II*\x00" + bytes(100), b"not a raw file at all" * 50])
def test_an_unreadable_dng_is_one_clear_input_error(tmp_path, content):
    path = tmp_path / "bad.dng"
    path.write_bytes(content)
    for read in (read_gray, read_exif, open_image):
        with pytest.raises(InputError, match="bad.dng"):
            read(path)
    with pytest.raises(InputError, match="no such file"):
        read_gray(tmp_path / "missing.dng")


def test_a_truncated_dng_is_not_read_as_a_photo(tmp_path):
    path = write_dng(tmp_path / "cut.dng", _smooth_image((200, 300)))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    res = detect_photo(path, Board(8, 5, 30.0))
    assert res.uv is None and res.reason, res


def _render_set(truth, root: Path, seed: int) -> None:
    """The photo set of ``truth`` as JPEGs (``root/jpeg``) and, from the very same renders, as DNGs
    (``root/dng``): the two differ only by what a phone's processing would change."""
    write_photo_set(truth, root / "jpeg", seed=seed, progress=False)
    for ci, (name, cam) in enumerate(truth.cameras.items()):
        (root / "dng" / name).mkdir(parents=True)
        for vi, view in enumerate(truth.view_poses):
            img = render_view(cam, truth.camera_pose(name, view), truth.board, photo_seed(seed, ci, vi))
            write_dng(root / "dng" / name / f"{view}.dng", img, margin=(8, 8, 0, 0))


def test_dng_corners_agree_with_the_truth(tmp_path):
    truth = make_truth("note8", views=1, seed=21, scale=0.5)
    tc = true_corners(truth)
    view = next(iter(truth.view_poses))
    for ci, (name, cam) in enumerate(truth.cameras.items()):
        img = render_view(cam, truth.camera_pose(name, view), truth.board, photo_seed(21, ci, 0))
        res = detect_photo(write_dng(tmp_path / f"{name}.dng", img, pattern="GRBG"), truth.board)
        assert res.image_size == cam.image_size
        err = res.uv - tc[name][view]
        assert np.all(np.isfinite(err))
        assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.02      # px, at 1512 x 2016
        assert np.abs(err.mean(axis=0)).max() < 0.005                 # no shift of the frame


@pytest.mark.slow
def test_a_dng_set_and_its_jpeg_set_calibrate_to_the_same_camera_within_their_sigmas(tmp_path):
    truth = make_truth("note8", views=8, seed=4, scale=0.25)
    _render_set(truth, tmp_path, seed=4)
    rigs = {}
    for kind in ("jpeg", "dng"):
        corners = detect_dataset(open_dataset(tmp_path / kind), truth.board, progress=False)
        assert all(cc.meta["source_format"] == kind for cc in corners.cameras.values())
        assert all(uv is not None for cc in corners.cameras.values() for uv in cc.views.values())
        rigs[kind] = calibrate_rig(corners)
    jpeg, dng = rigs["jpeg"], rigs["dng"]
    for name, cam in truth.cameras.items():
        for p in ("fx", "fy", "cx", "cy", "k1", "k2"):
            sigma = min(jpeg.camera_sigma[name][p], dng.camera_sigma[name][p])
            a, b, true = getattr(jpeg.cameras[name], p), getattr(dng.cameras[name], p), getattr(cam, p)
            assert abs(a - b) < sigma, (name, p, a, b, sigma)
            assert abs(b - true) < 4 * dng.camera_sigma[name][p], (name, p, b, true)
    sigma_d = max(jpeg.rig["tele"].sigma_baseline_mm, dng.rig["tele"].sigma_baseline_mm)
    assert abs(jpeg.rig["tele"].baseline_mm - dng.rig["tele"].baseline_mm) < sigma_d
    save_rig(tmp_path / "calib.json", dng)                # what the photos were is kept in calib.json's corners
    page = render_report(load_rig(tmp_path / "calib.json"))
    assert "RAW (DNG): the sensor" in page and "JPEG: the phone" not in page
    assert source_formats(jpeg, ["wide", "tele"]) == {"wide": "JPEG: the phone's processed photo",
                                                      "tele": "JPEG: the phone's processed photo"}
    pair = {name: tmp_path / "dng" / name / "IMG_02.dng" for name in ("wide", "tele")}
    exact = truth_rig_model(truth)                        # (this set's estimate folds over at the wide's corner)
    written = rectify_pair_files(exact, stereo_rectify(exact, "wide", "tele"), pair, tmp_path)
    assert sorted(p.name for p in written.values()) == ["tele-IMG_02.tif", "wide-IMG_02.tif"]
    # a DNG undistorted is developed to an 8-bit sRGB TIFF of the same size, named .tif
    src = tmp_path / "dng" / "tele" / "IMG_01.dng"
    [out] = undistort_files([src], tmp_path / "undistorted", dng.cameras["tele"], progress=False)
    assert out.name == "IMG_01.tif"
    with open_image(out) as img:
        assert img.size == truth.cameras["tele"].image_size and img.mode == "RGB" and img.format == "TIFF"


def test_default_jobs_keep_the_photos_in_memory_together_under_the_limit():
    def photos(w, h, suffix, n=4):
        return [Photo(Path(f"p{i}{suffix}"), (w, h), {}) for i in range(n)]

    assert jobs_within_memory(photos(8064, 6048, ".jpg"), cores=8) == 8            # 0.12 GB each
    assert jobs_within_memory(photos(8064, 6048, ".dng"), cores=8) == 5            # 0.22 GB each
    assert jobs_within_memory(photos(16320, 12240, ".dng"), cores=8) == 1          # 200 MP: 0.9 GB
    assert jobs_within_memory(photos(16320, 12240, ".jpg") + photos(4032, 3024, ".jpg"), cores=8) == 2
    assert jobs_within_memory(photos(4032, 3024, ".jpg"), cores=2) == 2
    assert jobs_within_memory([], cores=3) == 3
