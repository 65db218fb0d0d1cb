"""Detection on the real photo sets in shared/data, and the calibrations against their references.

References (each folder's SOURCE.md):

* opencv-samples-stereo (Bouguet's stereo example 5, 9x6 inner corners of 30 mm): the joint
  stereo optimisation gives left fc = [533.52, 533.53], cc = [341.60, 235.19], right
  fc = [536.81, 536.48], cc = [326.29, 250.10], T = [-99.80, 1.12, 0.05] mm (X_right = R X_left + T).
* huawei-y5-2017 (7x9 inner corners of 30 mm, a 180-degree symmetric board): MATLAB's
  fx = 2700.11 +- 2.82, fy = 2704.01 +- 2.65 (1 sigma), principal point [1179.30, 1588.66]
  in MATLAB's 1-based pixels.
"""

from pathlib import Path

import numpy as np
import pytest

from dualcal.board import Board
from dualcal.dataset import open_dataset
from dualcal.detect import detect_dataset

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
STEREO = DATA / "opencv-samples-stereo"
HUAWEI = DATA / "huawei-y5-2017"


def _need(folder: Path):
    if not folder.is_dir():
        pytest.skip(f"real data set {folder.name} is not present at {folder}")


@pytest.fixture(scope="module")
def stereo_corners():
    _need(STEREO)
    ds = open_dataset(STEREO, ["left=left*.jpg", "right=right*.jpg"])
    return detect_dataset(ds, Board(9, 6, 30.0), jobs=2, progress=False)


@pytest.fixture(scope="module")
def huawei_corners():
    _need(HUAWEI)
    return detect_dataset(open_dataset(HUAWEI), Board(7, 9, 30.0), jobs=2, progress=False)


def test_stereo_globs_pair_however_they_are_spelled(monkeypatch):
    _need(STEREO)
    plain = open_dataset(STEREO, ["left=left*.jpg", "right=right*.jpg"])
    monkeypatch.chdir(STEREO)
    dotted = open_dataset(None, ["left=./left*.jpg", "right=./right*.jpg"])
    assert list(dotted.cameras["left"]) == list(dotted.cameras["right"]) == list(plain.cameras["left"])
    assert len(plain.cameras["left"]) == 13 and "01" in plain.cameras["left"]


def test_every_stereo_board_found_in_the_same_order_in_both_cameras(stereo_corners):
    left, right = stereo_corners.cameras["left"], stereo_corners.cameras["right"]
    assert len(left.views) == len(right.views) == 13
    assert all(v is not None for v in [*left.views.values(), *right.views.values()])
    # the rig only shifts the image sideways: corner k is at about the same row in both photos
    for key in left.views:
        dv = right.views[key][:, 1] - left.views[key][:, 1]
        assert np.ptp(dv) < 25, key


def test_every_huawei_board_found(huawei_corners):
    (cam,) = huawei_corners.cameras.values()
    assert len(cam.views) == 20 and all(v is not None for v in cam.views.values())
    assert cam.image_size == (2448, 3264)
    assert cam.meta["exif"]["model"] == "MYA-U29"


def test_stereo_calibration_agrees_with_bouguet(stereo_corners):
    calibrate = pytest.importorskip("dualcal.calibrate")
    rig = calibrate.calibrate_rig(stereo_corners, rig_mode="rigid", reference="left")
    ref = {"left": ([533.52331, 533.52699], [341.60376, 235.19287]),
           "right": ([536.81377, 536.47649], [326.28657, 250.10121])}
    for name, (fc, cc) in ref.items():
        cam = rig.cameras[name]
        np.testing.assert_allclose([cam.fx, cam.fy], fc, atol=2.0)
        np.testing.assert_allclose([cam.cx, cam.cy], cc, atol=3.0)
    np.testing.assert_allclose(rig.rig["right"].pose.t_mm, [-99.80198, 1.12443, 0.05041], atol=1.0)


def test_stereo_tangential_terms_agree_with_bouguet(stereo_corners):
    """Bouguet estimated kc = [k1 k2 p1 p2] (k3 fixed at 0): dualcal's k1k2p1p2 on the same photos (13
    of his 14 pairs) finds the tangential terms he published, within 4e-4 (0.2 px at the image
    corner); p1 is well determined (>= 5 sigma from 0, his sign), and the fit improves by more than
    the four extra unknowns could explain as noise."""
    calibrate = pytest.importorskip("dualcal.calibrate")
    k1k2 = calibrate.calibrate_rig(stereo_corners, rig_mode="rigid", reference="left")
    rig = calibrate.calibrate_rig(stereo_corners, rig_mode="rigid", reference="left", model="k1k2p1p2")
    bouguet = {"left": (0.00109, -0.00030), "right": (-0.00059, 0.00014)}
    for name, (p1, p2) in bouguet.items():
        cam, sigma = rig.cameras[name], rig.camera_sigma[name]
        assert abs(cam.p1 - p1) < 4e-4 and abs(cam.p2 - p2) < 4e-4, (name, cam.p1, cam.p2)
        assert np.sign(cam.p1) == np.sign(p1) and abs(cam.p1) > 5 * sigma["p1"]
    n, p0, p = rig.adjustment["n_observations"], k1k2.adjustment["n_parameters"], rig.adjustment["n_parameters"]
    noise_only = k1k2.adjustment["s0_px"] * np.sqrt((n - p0) / (n - p))
    assert rig.adjustment["s0_px"] < 0.98 * noise_only


def test_huawei_calibration_agrees_with_matlab(huawei_corners):
    calibrate = pytest.importorskip("dualcal.calibrate")
    rig = calibrate.calibrate_rig(huawei_corners, rig_mode="none")
    (cam,) = rig.cameras.values()
    assert abs(cam.fx - 2700.1129) <= 3 * 2.8244
    assert abs(cam.fy - 2704.0118) <= 3 * 2.6479
    # MATLAB's principal point is 1-based: subtract 1 for dualcal's pixel-centre convention
    assert abs(cam.cx - (1179.3009 - 1)) <= 3 * 1.8586
    assert abs(cam.cy - (1588.6612 - 1)) <= 3 * 1.4667
