"""Rectification (dualcal.files.rectify) and the undistort command: round trips, straight lines,
agreement with OpenCV, bands, output matrices, EXIF, and the errors users can cause."""

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from dualcal.geometry.camera import (CameraModel, check_invertible_in_image, distort_points, normalized_from_pixel,
                                     pixel_from_normalized, project_points, undistort_points)
from dualcal.errors import InputError, NotInvertibleError
from dualcal.files.io import save_rig
from dualcal.files.dataset import open_image, read_exif
from dualcal.files.rectify import (KEEP_MODES, _pixels, _undistort_task, rectified_camera, rectify_map, undistort_file,
                                   undistort_image)
from dualcal.synthetic.synth import PRESETS, make_truth, scale_camera, truth_rig_model

ALL_CAMERAS = {f"{preset}-{name}": cam for preset, p in PRESETS.items() for name, cam in p["cameras"].items()}
STEREO_LEFT = PRESETS["stereo"]["cameras"]["left"]                       # 640 x 480, strong barrel
WIDE_QUARTER = scale_camera(PRESETS["note8"]["cameras"]["wide"], 0.25)    # 756 x 1008, k1 > 0, k2 < 0
FOLDING = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.5, 0.0)


def _pixel_grid(cam: CameraModel, step: float) -> np.ndarray:
    """(N, 2) pixels covering the whole image, outer pixel edges included."""
    w, h = cam.image_size
    u = np.append(np.arange(-0.5, w - 0.5, step), w - 0.5)
    v = np.append(np.arange(-0.5, h - 0.5, step), h - 0.5)
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def _smooth_texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 3.0)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


# ---------------------------------------------------------------------------- points


@pytest.mark.parametrize("name", sorted(ALL_CAMERAS))
def test_points_round_trip_over_the_whole_image(name):
    cam = ALL_CAMERAS[name]
    uv = _pixel_grid(cam, step=max(cam.image_size) / 400)
    ideal = undistort_points(cam, uv)
    assert np.max(np.abs(ideal - uv)) > 1.0                 # the model does distort
    assert np.max(np.abs(distort_points(cam, ideal) - uv)) < 1e-6


def test_model_that_folds_over_inside_the_image_is_refused():
    with pytest.raises(NotInvertibleError, match="folds over"):
        check_invertible_in_image(FOLDING)
    with pytest.raises(NotInvertibleError, match="folds over"):
        rectified_camera(FOLDING, "same")
    with pytest.raises(NotInvertibleError, match="not invertible"):
        undistort_points(FOLDING, np.array([[0.0, 0.0]]))
    undistort_points(FOLDING, np.array([[320.0, 240.0], [400.0, 300.0]]))   # fine near the centre


def test_keep_same_works_for_a_lens_that_folds_only_in_the_corners():
    """k1 = -0.12 at fx = 300 on 640 x 480: the model folds at normalised radius 1.11, beyond the
    middle of every edge (1.07) but inside the corners (1.33). The camera's own matrix still
    rectifies the photo (the output's rays never reach the fold; the folded corner pixels of the
    source are simply not used); the modes that trace the whole border, and points in those
    corners, are refused."""
    cam = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.12, 0.0)
    new_cam = rectified_camera(cam, "same")
    assert new_cam == cam.with_distortion(0.0, 0.0)
    out = undistort_image(np.full((480, 640), 200, np.uint8), cam, new_cam, interpolation=cv2.INTER_NEAREST)
    map_x, map_y = rectify_map(cam, new_cam, 0, 480)
    inside = (map_x >= 0) & (map_x <= 639) & (map_y >= 0) & (map_y <= 479)
    assert inside.mean() > 0.9 and np.all(out[inside] == 200) and np.all(out[~inside] == 0)
    for keep in ("all", "valid"):
        with pytest.raises(NotInvertibleError, match="folds over inside the image"):
            rectified_camera(cam, keep)
    with pytest.raises(NotInvertibleError, match="not invertible beyond"):
        undistort_points(cam, np.array([[0.0, 0.0]]))
    with pytest.raises(NotInvertibleError, match="folds over at the middle of an image edge"):
        rectified_camera(FOLDING, "same")


@pytest.mark.parametrize("name", sorted(ALL_CAMERAS))
def test_projected_3d_line_is_straight_after_undistortion(name):
    cam = ALL_CAMERAS[name]
    w, h = cam.image_size
    # A 3-D line from near the top-left corner at 1 m to near the bottom-left corner at 1.6 m.
    ends_px = np.array([[0.04 * w, 0.03 * h], [0.10 * w, 0.97 * h]])
    ends_xy = normalized_from_pixel(cam, ends_px)
    ends = np.column_stack([ends_xy, np.ones(2)]) * np.array([[1000.0], [1600.0]])
    X = ends[0] + np.linspace(0, 1, 400)[:, None] * (ends[1] - ends[0])
    uv = project_points(cam, X)
    uv = uv[(uv[:, 0] > -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < h - 0.5)]
    assert len(uv) > 200

    def straightness(pts):
        centred = pts - pts.mean(axis=0)
        normal = np.linalg.svd(centred)[2][1]
        return np.max(np.abs(centred @ normal))

    assert straightness(uv) > 0.5                          # curved as photographed
    assert straightness(undistort_points(cam, uv)) < 0.05  # straight once undistorted


# ---------------------------------------------------------------------------- images


def _line_photo(cam: CameraModel, p0, p1, sigma_px: float = 2.0) -> np.ndarray:
    """Float image of a thin straight line (ideal pixels p0 -> p1) as the distorting lens shows it."""
    w, h = cam.image_size
    uu, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    ideal = undistort_points(cam, np.column_stack([uu.ravel(), vv.ravel()]))
    normal = np.array([p1[1] - p0[1], p0[0] - p1[0]]) / np.hypot(*(p1 - p0))
    distance = (ideal - p0) @ normal
    return np.exp(-0.5 * (distance / sigma_px) ** 2).reshape(h, w).astype(np.float32)


def _line_centroids(img: np.ndarray, p0, p1, half: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: the row, the intensity centroid in a window around the ideal line, the ideal u."""
    h, w = img.shape
    rows, found, expected = [], [], []
    for v in range(h):
        u_line = p0[0] + (p1[0] - p0[0]) * (v - p0[1]) / (p1[1] - p0[1])
        lo, hi = int(round(u_line)) - half, int(round(u_line)) + half + 1
        if lo >= 0 and hi <= w:
            seg = img[v, lo:hi].astype(float)
            rows.append(v)
            found.append(np.sum(seg * np.arange(lo, hi)) / np.sum(seg))
            expected.append(u_line)
    return np.array(rows), np.array(found), np.array(expected)


@pytest.mark.parametrize("cam", [STEREO_LEFT, WIDE_QUARTER], ids=["stereo-left", "note8-wide-quarter"])
def test_rendered_line_is_straight_after_rectification(cam):
    w, h = cam.image_size
    p0, p1 = np.array([0.06 * w, 0.0]), np.array([0.12 * w, h - 1.0])
    photo = _line_photo(cam, p0, p1)
    rows, u_photo, _ = _line_centroids(photo, p0, p1, half=25)
    fit = np.polyval(np.polyfit(rows, u_photo, 1), rows)
    assert np.max(np.abs(u_photo - fit)) > 0.7                        # bent in the photo

    rectified = undistort_image(photo, cam)
    rows, u_found, u_line = _line_centroids(rectified, p0, p1, half=9)
    map_x, map_y = rectify_map(cam, rectified_camera(cam), 0, h)
    cols = np.round(u_found).astype(int)
    inside = (map_x[rows, cols] > 12) & (map_y[rows, cols] > 12) & (map_y[rows, cols] < h - 13)
    assert inside.sum() > 0.9 * h
    assert np.max(np.abs(u_found - u_line)[inside]) < 0.05             # straight, and where it belongs


@pytest.mark.parametrize("cam", [STEREO_LEFT, PRESETS["stereo5"]["cameras"]["left"]], ids=["k1k2", "k1k2p1p2k3"])
@pytest.mark.parametrize("keep", KEEP_MODES)
def test_maps_and_images_agree_with_opencv(keep, cam):
    new_cam = rectified_camera(cam, keep)
    dist = np.array(cam.distortion)                 # OpenCV's five coefficients
    cv_x, cv_y = cv2.initUndistortRectifyMap(cam.K, dist, None, new_cam.K, cam.image_size, cv2.CV_32FC1)
    map_x, map_y = rectify_map(cam, new_cam, 0, cam.image_size[1])
    assert max(np.max(np.abs(map_x - cv_x)), np.max(np.abs(map_y - cv_y))) < 1e-3
    img = _smooth_texture(480, 640)
    diff = np.abs(undistort_image(img, cam, new_cam).astype(int) - cv2.undistort(img, cam.K, dist, None, new_cam.K))
    assert diff.mean() < 0.2


@pytest.mark.parametrize("band_rows", [1, 7, 100])
@pytest.mark.parametrize("keep,interpolation", [("same", cv2.INTER_LINEAR), ("all", cv2.INTER_LINEAR),
                                                ("valid", cv2.INTER_CUBIC)])
def test_bands_give_the_same_image_as_one_piece(band_rows, keep, interpolation):
    cam = STEREO_LEFT
    new_cam = rectified_camera(cam, keep)
    img = (np.random.default_rng(1).random((480, 640, 3)) * 255).astype(np.uint8)
    whole = undistort_image(img, cam, new_cam, band_rows=480, interpolation=interpolation)
    banded = undistort_image(img, cam, new_cam, band_rows=band_rows, interpolation=interpolation)
    np.testing.assert_array_equal(banded, whole)


@pytest.mark.parametrize("name", sorted(ALL_CAMERAS))
def test_keep_valid_shows_only_source_pixels(name):
    cam = ALL_CAMERAS[name]
    w, h = cam.image_size
    new_cam = rectified_camera(cam, "valid")
    assert new_cam.fx / new_cam.fy == pytest.approx(cam.fx / cam.fy)
    map_x, map_y = rectify_map(cam, new_cam, 0, h)
    margins = np.array([map_x.min(), w - 1 - map_x.max(), map_y.min(), h - 1 - map_y.max()])
    assert np.all(margins > -0.01)                 # every output pixel has a source pixel
    assert margins.min() < 0.5                     # and the box is as large as it can be


@pytest.mark.parametrize("name", sorted(ALL_CAMERAS))
def test_keep_all_shows_every_source_pixel(name):
    cam = ALL_CAMERAS[name]
    w, h = cam.image_size
    new_cam = rectified_camera(cam, "all")
    uv = np.clip(_pixel_grid(cam, step=max(w, h) / 200), 0.0, [w - 1.0, h - 1.0])   # centres, border included
    ideal = normalized_from_pixel(cam.with_distortion(0, 0), undistort_points(cam, uv))
    out = pixel_from_normalized(new_cam, ideal)
    margins = np.array([out[:, 0].min(), w - 1 - out[:, 0].max(), out[:, 1].min(), h - 1 - out[:, 1].max()])
    assert np.all(margins > -0.01)
    assert margins.min() < 0.5


def test_wrong_image_size_is_refused():
    with pytest.raises(InputError, match="640x480"):
        undistort_image(np.zeros((100, 100), np.uint8), STEREO_LEFT)


# ---------------------------------------------------------------------------- files


def _jpeg_with_exif(path, cam=STEREO_LEFT, seed=0):
    w, h = cam.image_size
    exif = Image.Exif()
    exif[0x010F] = "dualcal-test-make"      # Make
    exif[0x0110] = "model X"                # Model
    exif[0x0112] = 6                        # Orientation: reported, never applied
    exif[0x0132] = "2024:05:06 07:08:09"    # DateTime
    Image.fromarray(_smooth_texture(h, w, seed=seed)).save(path, quality=92, exif=exif.tobytes())
    return path


def test_exif_is_kept(tmp_path):
    src = _jpeg_with_exif(tmp_path / "IMG_01.jpg")
    dst = undistort_file(src, tmp_path / "out.jpg", STEREO_LEFT)
    with Image.open(src) as a, Image.open(dst) as b:
        assert b.format == "JPEG" and b.size == a.size
        assert b.info["exif"] == a.info["exif"]
        assert b.getexif()[0x010F] == "dualcal-test-make" and b.getexif()[0x0112] == 6
        rectified, original = np.asarray(b).astype(int), np.asarray(a)
    expected = undistort_image(original, STEREO_LEFT)
    # the pixels are the rectified ones, up to JPEG coding
    assert np.abs(rectified - expected).mean() < 0.2 * np.abs(original.astype(int) - expected).mean()


def test_real_phone_photo_keeps_its_exif(shared_data, tmp_path):
    """An 8 MP Huawei photo with the reference calibration of its folder (MATLAB, 1-based centre)."""
    src = shared_data / "huawei-y5-2017" / "IMG_20210417_010329.jpg"
    if not src.exists():
        pytest.skip(f"{src} is missing")
    cam = CameraModel((2448, 3264), 2700.1129, 2704.0118, 0.0, 1178.3009, 1587.6612, 0.0926, -0.2114)
    dst = undistort_file(src, tmp_path / src.name, cam, rectified_camera(cam, "valid"))
    with Image.open(src) as a, Image.open(dst) as b:
        assert b.size == a.size and b.format == "JPEG"
        assert b.info["exif"] == a.info["exif"] and b.getexif()[0x010F].startswith("HUAWEI")


def test_png_round_trip_is_exact(tmp_path):
    img = _smooth_texture(480, 640)[..., 1].copy()
    Image.fromarray(img).save(tmp_path / "a.png")
    undistort_file(tmp_path / "a.png", tmp_path / "b.png", STEREO_LEFT)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "b.png")), undistort_image(img, STEREO_LEFT))


def test_16_bit_png_round_trip_keeps_16_bits(tmp_path):
    img = (_smooth_texture(480, 640)[..., 0].astype(np.uint16) * 257 + 3).astype(np.uint16)   # up to 65538 - 3
    Image.fromarray(img).save(tmp_path / "a.png")
    undistort_file(tmp_path / "a.png", tmp_path / "b.png", STEREO_LEFT)
    with Image.open(tmp_path / "b.png") as out:
        assert out.mode == "I;16"
        rectified = np.asarray(out)
    np.testing.assert_array_equal(rectified, undistort_image(img, STEREO_LEFT))
    assert rectified.max() > 255


@pytest.mark.parametrize("mode, order", [("I;16", "<"), ("I;16B", ">"), ("I;16L", "<")])
def test_16_bit_modes_stay_16_bit_in_native_byte_order(mode, order):
    values = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    pixels, _ = _pixels(Image.frombytes(mode, (4, 3), values.astype(f"{order}u2").tobytes()))
    assert pixels.dtype == np.dtype(np.uint16)          # native order: OpenCV can resample it
    np.testing.assert_array_equal(pixels, values)


def test_rotated_heic_is_rectified_in_its_stored_frame_and_keeps_its_orientation(tmp_path):
    pytest.importorskip("pillow_heif").register_heif_opener()      # for Pillow to write HEIC here
    cam = scale_camera(STEREO_LEFT, 0.25)                # 160 x 120
    stored = _smooth_texture(120, 160)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(stored).save(tmp_path / "a.heic", format="HEIF", exif=exif.tobytes(), quality=-1, chroma=444)
    undistort_file(tmp_path / "a.heic", tmp_path / "b.heic", cam)
    size, facts = read_exif(tmp_path / "b.heic")
    assert size == (160, 120) and facts["orientation"] == 6
    with open_image(tmp_path / "b.heic") as out:
        rectified = np.asarray(out.convert("RGB")).astype(int)
    error = np.abs(rectified - undistort_image(stored, cam)).mean()
    assert error < 0.2 * np.abs(rectified - stored).mean()       # rectified, in the stored frame


def test_a_photo_that_breaks_a_library_is_skipped_but_a_bug_is_not_hidden(tmp_path, monkeypatch):
    task = (tmp_path / "left01.jpg", tmp_path / "out.jpg", STEREO_LEFT, STEREO_LEFT, 64)
    for error in (cv2.error("bad depth"), OSError(28, "No space left on device"), ValueError("bad mode")):
        def fail(*args, error=error):
            raise error
        monkeypatch.setattr("dualcal.files.rectify.undistort_file", fail)
        message = _undistort_task(task)
        assert message.startswith(f"{tmp_path / 'left01.jpg'}: ") and type(error).__name__ in message

    def bug(*args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr("dualcal.files.rectify.undistort_file", bug)
    with pytest.raises(ZeroDivisionError):
        _undistort_task(task)


# ---------------------------------------------------------------------------- the command



@pytest.fixture
def stereo_calib(tmp_path):
    path = tmp_path / "calib.json"
    save_rig(path, truth_rig_model(make_truth("stereo", views=3, seed=0)))
    return path


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_undistort_command(tmp_path, stereo_calib, run_cli, jobs):
    photos = [_jpeg_with_exif(tmp_path / f"left{i:02d}.jpg", seed=i) for i in range(3)]
    broken = tmp_path / "left99.jpg"
    broken.write_bytes(b"not a jpeg at all")
    out_dir = tmp_path / "rectified"
    res = run_cli("undistort", stereo_calib, "--camera", "left", *photos, broken, "-o", out_dir,
                  "--keep", "valid", "--jobs", jobs)
    assert res.code == 0, res.err
    assert sorted(p.name for p in out_dir.glob("*.jpg")) == [p.name for p in photos]
    assert "left99.jpg" in res.err and "skipped" in res.err
    assert "3 of 4 photos" in res.out
    doc = json.loads((out_dir / "left.rectified.json").read_text())
    expected = rectified_camera(STEREO_LEFT, "valid")
    assert doc["k1"] == 0 and doc["fx"] == pytest.approx(expected.fx) and doc["cx"] == pytest.approx(expected.cx)
    with Image.open(out_dir / "left01.jpg") as img:
        assert img.getexif()[0x010F] == "dualcal-test-make"


def test_undistort_command_errors(tmp_path, stereo_calib, run_cli):
    photo = _jpeg_with_exif(tmp_path / "left01.jpg")
    res = run_cli("undistort", stereo_calib, "--camera", "tele", photo, "-o", tmp_path / "o")
    assert res.code == 2 and "'tele' is not in" in res.err and "left, right" in res.err

    Image.new("L", (320, 240)).save(tmp_path / "small.jpg")
    res = run_cli("undistort", stereo_calib, "--camera", "left", tmp_path / "small.jpg",
                  "-o", tmp_path / "o")
    assert res.code == 2 and "small.jpg" in res.err and "320x240" in res.err and "640x480" in res.err

    res = run_cli("undistort", stereo_calib, "--camera", "left", photo, "-o", tmp_path / "no" / "o")
    assert res.code == 2 and "parent does not exist" in res.err

    res = run_cli("undistort", stereo_calib, "--camera", "left", photo, "-o", tmp_path)
    assert res.code == 2 and "overwrite the original" in res.err

    res = run_cli("undistort", stereo_calib, "--camera", "left", "--keep", "some", photo,
                  "-o", tmp_path / "o")
    assert res.code == 2 and "--keep" in res.err

    rig = truth_rig_model(make_truth("stereo", views=3, seed=0))
    rig.cameras["left"] = FOLDING
    save_rig(tmp_path / "folding.json", rig)
    res = run_cli("undistort", tmp_path / "folding.json", "--camera", "left", photo,
                  "-o", tmp_path / "o")
    assert res.code == 2 and "folds over" in res.err


def test_undistort_refuses_to_mix_output_cameras_in_one_folder(tmp_path, stereo_calib, run_cli):
    photo = _jpeg_with_exif(tmp_path / "left01.jpg")
    out = tmp_path / "rectified"
    args = ("undistort", stereo_calib, "--camera", "left", photo, "-o", out, "--jobs", "1")
    assert run_cli(*args, "--keep", "valid").code == 0
    assert run_cli(*args, "--keep", "valid").code == 0          # the same camera again: fine
    res = run_cli(*args, "--keep", "all")
    assert res.code == 2 and len(res.err_lines) == 1
    assert "another camera" in res.err and "keep='valid'" in res.err and "another folder" in res.err
    assert json.loads((out / "left.rectified.json").read_text())["keep"] == "valid"
    assert run_cli(*args[:-2], "-o", tmp_path / "other", "--keep", "all").code == 0
