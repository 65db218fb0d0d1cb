"""The calibration gives the results it gave: a few synthetic sets and the real stereo rig against references.

The references (``tests/data/calibrate_regression.json``) were made by ``benchmarks/bench_calibrate_regression.py
test-data`` on main's code before the calibration was rewritten as a pipeline of stages; that script compares
many more cases (every preset, lens model, rig mode and skew model, the real sets). Here: the stereo pair with
``--model auto``, the 12 MP wide + tele in the paper's model with skew, the three-lens rig (a fisheye among
them) alone, planted outliers, a desynchronised instant (dropped whole, and one named by ``rig_rigid`` and
``loop_closure``), and the real stereo rig's corners as detected then (rounded to 0.001 px). Every parameter and
sigma within 1e-6 of its sigma, every check's verdict and what it names, the photos and corners left out and the
lens models chosen the same (:func:`calib_regression.differences`), with every photo alike (``weigh_photos=False``,
the calibration the references were made by). With the photos weighed by their own noise (the default, issue 38),
the synthetic sets of white corner noise keep every parameter within 0.05 of its sigma.
"""

import json
from pathlib import Path

import pytest

from calib_regression import differences, largest_shift_sigma, summary, synthetic_corners
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.files.io import corners_from_dict
from dualcal.progress import collect_warnings

REFERENCES = json.loads((Path(__file__).parent / "data" / "calibrate_regression.json").read_text())


def _calibrated(case: dict, **options) -> dict:
    if "real" in case:
        corners = corners_from_dict(REFERENCES["corners"][case["real"]])
    else:
        corners = synthetic_corners(case["preset"], case["views"], case["seed"], case["noise_px"], case["plant"])
    with collect_warnings():
        new = summary(calibrate_rig(corners, **case["options"], **options))
    del new["covariance"]
    return new


@pytest.mark.parametrize("name", sorted(REFERENCES["cases"]))
def test_the_calibration_gives_the_results_it_gave(name):
    ref = REFERENCES["cases"][name]
    diff = differences(ref["summary"], _calibrated(ref["case"], weigh_photos=False))
    assert not diff, "\n".join(diff)


@pytest.mark.parametrize("name", sorted(n for n, r in REFERENCES["cases"].items()
                                        if "real" not in r["case"] and r["case"]["plant"] is None))
def test_photos_alike_weighed_by_their_noise_give_the_same_results(name):
    ref = REFERENCES["cases"][name]
    assert largest_shift_sigma(ref["summary"], _calibrated(ref["case"])) < 0.05
