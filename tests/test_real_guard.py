"""The guard for real photos: every real set's boards, parameters and verdict pinned in one table.

``tests/data/real_sets.json`` holds, for every set of ``../shared/data`` (:data:`realsets.REAL_SETS`), the row of
:func:`realsets.summarise` as the code gave it when it was pinned, and how many boards OpenCV's detectors find in its
photos. A change fails this test where it loses a board, finds fewer boards than OpenCV, changes a camera's lens model,
moves a parameter (intrinsics, baseline, angles) by more than ``share_of_sigma`` of its pinned sigma, or makes a check
fail that passed. A change that means to move them pins the table again, and says why in its commit:
``.venv/bin/python benchmarks/bench_real_sets.py --pin`` (it prints the table and what moved).
"""

import json
from pathlib import Path

import numpy as np
import pytest

import realsets
from dualcal.progress import collect_warnings
from dualcal.workflow import calibrate_corners
from test_real_data import bouguet_corners, huawei_corners, stereo_corners  # noqa: F401 (fixtures, detected once)

PINNED = json.loads((Path(__file__).parent / "data" / "real_sets.json").read_text())
FIXTURES = {"opencv-samples-stereo": "stereo_corners", "huawei-y5-2017": "huawei_corners",
            "bouguet-calib-example": "bouguet_corners", "caliscope-prerecorded": "caliscope_corners"}
CALISCOPE = next(r for r in realsets.REAL_SETS if r.name == "caliscope-prerecorded")


def _calibrated(real, corners, computed_once):
    """The set calibrated as ``dualcal calibrate`` does (:func:`realsets.calibrate`), once for the whole run."""
    return computed_once(f"calibrated-{real.name}", lambda: realsets.calibrate(real, corners))


@pytest.fixture(scope="module")
def caliscope_corners(computed_once):
    """caliscope's intrinsic session (four webcams, its corners of a 12-corner ChArUco board), imported."""
    if not CALISCOPE.folder.is_dir():
        pytest.skip(f"real data set {CALISCOPE.name} is not present at {CALISCOPE.folder}")
    return computed_once("caliscope-corners", lambda: realsets.detect(CALISCOPE))


@pytest.mark.parametrize("real", [r for r in realsets.REAL_SETS if r.name in FIXTURES], ids=lambda r: r.name)
def test_real_set_keeps_its_boards_parameters_and_verdict(real, request, computed_once):
    if not real.folder.is_dir():
        pytest.skip(f"real data set {real.name} is not present at {real.folder}")
    corners = request.getfixturevalue(FIXTURES[real.name])
    row = realsets.summarise(corners, _calibrated(real, corners, computed_once))
    pinned = PINNED["sets"][real.name]
    assert realsets.differences(pinned["row"], row, PINNED["share_of_sigma"]) == []
    for name, found in pinned["opencv_boards"].items():
        assert row["cameras"][name]["boards"] >= max(found.values()), f"{name}: fewer boards than OpenCV finds"


def _fx(corners) -> dict:
    """Each camera's ``(fx, sigma_fx)``, calibrated as the guard does (``--rig none``)."""
    with collect_warnings():
        rig = calibrate_corners(corners, **CALISCOPE.options)
    return {name: (cam.fx, rig.camera_sigma[name]["fx"]) for name, cam in rig.cameras.items()}


def test_every_caliscope_webcam_calibrates_as_caliscopes_own_test_asks_and_its_halves_agree(caliscope_corners,
                                                                                            computed_once):
    """The four webcams of caliscope's intrinsic session (4-12 corners per frame, its inner corners a tenth of the
    frame wide; cam_2 once failed in the closed form on frames whose corners fix no homography) each calibrate
    alone: what caliscope's own test asserts of cam_0 (0.3 W < fx < 5 W, cx and cy within 0.3-0.7 of the image,
    0 < RMS < 2 px), and its frames split in two (even and odd ``sync_index``) calibrated apart give focal lengths
    within 3 of their combined sigmas."""
    rig = _calibrated(CALISCOPE, caliscope_corners, computed_once)
    assert sorted(rig.cameras) == ["cam_0", "cam_1", "cam_2", "cam_3"]
    w, h = 1280, 720
    for name, cam in rig.cameras.items():
        assert 0.3 * w < cam.fx < 5 * w, name
        assert 0.3 * w < cam.cx < 0.7 * w and 0.3 * h < cam.cy < 0.7 * h, name
        assert 0 < rig.camera_rms_px[name] < 2, name
    halves = [_fx(caliscope_corners.with_views(lambda cam, view: int(view) % 2 == parity)) for parity in (0, 1)]
    for name in rig.cameras:
        (f0, s0), (f1, s1) = halves[0][name], halves[1][name]
        assert abs(f0 - f1) < 3 * np.hypot(s0, s1), name
