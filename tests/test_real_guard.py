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

import pytest

import realsets
from test_real_data import bouguet_corners, huawei_corners, stereo_corners  # noqa: F401 (fixtures, detected once)

PINNED = json.loads((Path(__file__).parent / "data" / "real_sets.json").read_text())
FIXTURES = {"opencv-samples-stereo": "stereo_corners", "huawei-y5-2017": "huawei_corners",
            "bouguet-calib-example": "bouguet_corners"}


@pytest.mark.parametrize("real", [r for r in realsets.REAL_SETS if r.name in FIXTURES], ids=lambda r: r.name)
def test_real_set_keeps_its_boards_parameters_and_verdict(real, request, computed_once):
    if not real.folder.is_dir():
        pytest.skip(f"real data set {real.name} is not present at {real.folder}")
    corners = request.getfixturevalue(FIXTURES[real.name])
    row = computed_once(f"guard-{real.name}", lambda: realsets.summarise(corners, realsets.calibrate(real, corners)))
    pinned = PINNED["sets"][real.name]
    assert realsets.differences(pinned["row"], row, PINNED["share_of_sigma"]) == []
    for name, found in pinned["opencv_boards"].items():
        assert row["cameras"][name]["boards"] >= max(found.values()), f"{name}: fewer boards than OpenCV finds"
