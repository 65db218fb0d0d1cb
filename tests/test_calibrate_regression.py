"""The calibration gives the results it gave: a few synthetic sets and the real stereo rig against references.

The references (``tests/data/calibrate_regression.json``) were made by ``benchmarks/bench_calibrate_regression.py
test-data`` on main's code before the calibration was rewritten as a pipeline of stages; that script compares
many more cases (every preset, lens model, rig mode and skew model, the real sets). Here: the stereo pair with
``--model auto``, the 12 MP wide + tele in the paper's model with skew, the three-lens rig (a fisheye among
them) alone, planted outliers, a desynchronised instant (dropped whole, and one named by ``rig_rigid`` and
``loop_closure``), and the real stereo rig's corners as detected then (rounded to 0.001 px). Every parameter and
sigma within 1e-6 of its sigma, every check's verdict and what it names, the photos and corners left out and the
lens models chosen the same (:func:`calib_regression.differences`).
"""

import json
from pathlib import Path

import pytest

from calib_regression import differences, summary, synthetic_corners
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.files.io import corners_from_dict
from dualcal.progress import collect_warnings

REFERENCES = json.loads((Path(__file__).parent / "data" / "calibrate_regression.json").read_text())


@pytest.mark.parametrize("name", sorted(REFERENCES["cases"]))
def test_the_calibration_gives_the_results_it_gave(name):
    ref = REFERENCES["cases"][name]
    case = ref["case"]
    if "real" in case:
        corners = corners_from_dict(REFERENCES["corners"][case["real"]])
    else:
        corners = synthetic_corners(case["preset"], case["views"], case["seed"], case["noise_px"], case["plant"])
    with collect_warnings():
        new = summary(calibrate_rig(corners, **case["options"]))
    del new["covariance"]
    diff = differences(ref["summary"], new)
    assert not diff, "\n".join(diff)
