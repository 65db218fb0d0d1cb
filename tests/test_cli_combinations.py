"""Issue 33: no internal error on any combination of ``calibrate``'s options.

Every combination of ``--rig`` (rigid, paper, none) x ``--skew`` (on, off) x ``--model`` (auto, one model for
every camera, one per camera) x ``--board-shape`` (auto, flat, fit) x ``--keep-outliers`` (on, off), 108 in
all, runs in-process (``dualcal.cli.main``) on each of the three shared real sets
(``tests/test_real_data.py::test_every_combination_of_options_on_a_real_set``, on the corners that module
detects once), and ends either in exit code 0 with ``adjustment.converged`` true and the options it was given
recorded in calib.json, or in exit code 2 with one line on stderr (an input the combination cannot solve);
never in exit code 1 (an internal error). On one camera the rig modes have no rig to tie: every one
calibrates the camera alone.

All 108 on each synthetic preset do not fit the suite's time as well: here a covering design runs, 13
combinations in which every pair of values of any two options occurs (:data:`ALL_PAIRS`), on ``note8``
(wide + tele), ``triple`` (a fisheye ultra-wide beside them) and ``stereo5`` (OpenCV's five-coefficient
lenses), one fixed seed each.
"""

import itertools
import json
from pathlib import Path

import pytest

from dualcal.files.io import save_corners
from dualcal.synthetic.synth import make_truth, noisy_corner_set

RIGS = ("rigid", "paper", "none")
SKEWS = (False, True)
MODELS = ("auto", "one", "per-camera")
SHAPES = ("auto", "flat", "fit")
OUTLIERS = (False, True)                     # --keep-outliers
#: A covering array of strength 2 for the levels 3, 2, 3, 3, 2 (indices into the tuples above): every pair of
#: values of any two options occurs in one of these 13 rows (checked by test_the_covering_design_covers_every_pair).
ALL_PAIRS = [(0, 0, 0, 0, 0), (0, 1, 1, 1, 1), (0, 0, 2, 2, 1), (1, 1, 0, 1, 0), (1, 0, 1, 2, 1), (1, 1, 2, 0, 0),
             (2, 0, 0, 2, 0), (2, 1, 1, 0, 1), (2, 0, 2, 1, 0), (0, 1, 0, 2, 1), (1, 0, 0, 0, 1), (2, 1, 2, 2, 1),
             (0, 0, 1, 0, 0)]
#: The lens models given: one for every camera, and one per camera (mixed: radial, OpenCV's five, fisheye).
ONE_MODEL = "k1k2p1p2"
PER_CAMERA = ("k1k2k3", "k1k2p1p2k3", "kb4")


def _flags(names, rig, skew, model, shape, keep_outliers) -> list[str]:
    flags = ["--rig", rig, "--board-shape", shape]
    flags += ["--skew"] if skew else []
    flags += ["--keep-outliers"] if keep_outliers else []
    if model == "one":
        flags += ["--model", ONE_MODEL]
    elif model == "per-camera":
        for name, lens in zip(names, itertools.cycle(PER_CAMERA)):
            flags += ["--model", f"{name}={lens}"]
    return flags


def run_every(run_cli, corners_path: Path, out: Path, names: list[str], combinations) -> dict[str, int]:
    """Run each combination; return how many ended in exit 0 and in exit 2 (one line each)."""
    ends = {"solved": 0, "refused": 0}
    for rig, skew, model, shape, keep in combinations:
        flags = _flags(names, rig, skew, model, shape, keep)
        res = run_cli("calibrate", corners_path, "-o", out, *flags)
        assert res.code in (0, 2), f"{' '.join(flags)}: exit {res.code}: {res.err.strip()[-300:]}"
        if res.code == 2:
            lines = [line for line in res.err.splitlines() if line.startswith("dualcal: error:")]
            assert len(lines) == 1 and "Traceback" not in res.err, f"{' '.join(flags)}: {res.err}"
            ends["refused"] += 1
            continue
        doc = json.loads(out.read_text())
        options = doc["adjustment"]["options"]
        assert doc["adjustment"]["converged"] is True, f"{' '.join(flags)}: {doc['adjustment']['termination']}"
        assert (doc["rig_mode"], doc["skew"], options["board_shape"], options["drop_outliers"]) == (rig, skew, shape,
                                                                                                    not keep), flags
        if model == "one":
            assert doc["model"] == ONE_MODEL, flags
        elif model == "per-camera":
            assert [doc["cameras"][n]["model"] for n in names] == [m for _, m in zip(names, itertools.cycle(PER_CAMERA))]
        else:
            assert set(doc["adjustment"]["lens_models_chosen"]) == set(names)
        assert ("board_shape_test" in doc["adjustment"]) == (shape != "flat"), flags
        if shape != "auto":
            assert ("shape_mm" in doc["board"]) == (shape == "fit"), flags
        ends["solved"] += 1
    return ends


def every_combination():
    """All 108 combinations of the five options' values (the order of :func:`run_every`'s arguments)."""
    return itertools.product(RIGS, SKEWS, MODELS, SHAPES, OUTLIERS)


@pytest.mark.parametrize("preset", ["note8", "triple", "stereo5"])
def test_a_covering_design_of_options_on_a_synthetic_rig(preset, run_cli, tmp_path):
    """The 13 combinations of :data:`ALL_PAIRS` on one synthetic rig (8 instants, 0.2 px, seed 3): each solved or
    refused in one line, none an internal error; on these rigs of two and three cameras every one is solved."""
    corners = noisy_corner_set(make_truth(preset, 8, seed=3), 0.2, seed=4)
    save_corners(tmp_path / "corners.json", corners)
    ends = run_every(run_cli, tmp_path / "corners.json", tmp_path / "calib.json", sorted(corners.cameras),
                      [tuple(levels[i] for levels, i in zip((RIGS, SKEWS, MODELS, SHAPES, OUTLIERS), row))
                       for row in ALL_PAIRS])
    assert ends == {"solved": len(ALL_PAIRS), "refused": 0}


def test_the_covering_design_covers_every_pair():
    """Every pair of values of any two of the five options occurs in some row of :data:`ALL_PAIRS`."""
    sizes = [len(levels) for levels in (RIGS, SKEWS, MODELS, SHAPES, OUTLIERS)]
    for a, b in itertools.combinations(range(5), 2):
        seen = {(row[a], row[b]) for row in ALL_PAIRS}
        assert seen == set(itertools.product(range(sizes[a]), range(sizes[b]))), (a, b)
