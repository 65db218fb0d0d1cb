"""Every user error of every command: exit code 2, one line on stderr naming the problem, no traceback."""

import numpy as np
import pytest
from PIL import Image

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.files.io import save_corners, save_rig
from dualcal.synthetic.synth import make_truth, noisy_corner_set


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("errors")
    corners = noisy_corner_set(make_truth("stereo", 5, seed=2), 0.1, seed=2)
    save_corners(d / "corners.json", corners)
    save_rig(d / "calib.json", calibrate_rig(corners))
    (d / "truncated.json").write_text((d / "calib.json").read_text()[:500])
    (d / "empty").mkdir()
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(d / "photo.png")
    return d


CASES = {
    "missing folder": (["detect", "{d}/nowhere", "--board", "9x6", "--square", "30", "-o", "{d}/c.json"],
                       "no such file or folder"),
    "empty folder": (["detect", "{d}/empty", "--board", "9x6", "--square", "30", "-o", "{d}/c.json"], "no photos"),
    "unknown camera": (["undistort", "{d}/calib.json", "--camera", "tele", "{d}/photo.png", "-o", "{d}/rect"],
                       "tele"),
    "malformed --board": (["detect", "{d}/empty", "--board", "9by6", "--square", "30", "-o", "{d}/c.json"],
                          "--board '9by6' is malformed"),
    "non-positive --square": (["detect", "{d}/empty", "--board", "9x6", "--square", "0", "-o", "{d}/c.json"],
                              "--square"),
    "truncated calib.json": (["evaluate", "{d}/truncated.json", "-o", "{d}/e.json"], "truncated"),
    "board disagrees": (["calibrate", "{d}/corners.json", "--board", "8x5", "--square", "30", "-o", "{d}/x.json"],
                        "disagrees"),
    "calib.json as corners": (["calibrate", "{d}/calib.json", "-o", "{d}/x.json"], "expected a corners.json"),
    "corners.json as calib": (["evaluate", "{d}/corners.json", "-o", "{d}/e.json"], "expected a calib.json"),
    "corners.json to report": (["report", "{d}/corners.json", "-o", "{d}/r.html"], "expected a calib.json"),
    "corners.json to export": (["export", "{d}/corners.json", "--format", "opencv", "-o", "{d}/r.yml"],
                               "expected a calib.json"),
    "missing output folder (calibrate)": (["calibrate", "{d}/corners.json", "-o", "{d}/no/x.json"], "does not exist"),
    "missing output folder (evaluate)": (["evaluate", "{d}/calib.json", "-o", "{d}/no/e.json"], "does not exist"),
    "missing output folder (report)": (["report", "{d}/calib.json", "-o", "{d}/no/r.html"], "does not exist"),
    "missing output folder (export)": (["export", "{d}/calib.json", "--format", "colmap", "-o", "{d}/no/c.txt"],
                                       "does not exist"),
    "missing input file": (["report", "{d}/nothing.json", "-o", "{d}/r.html"], "no such file"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_user_error_is_one_clear_line_with_exit_code_2(files, run_cli, case):
    args, pattern = CASES[case]
    res = run_cli(*[a.format(d=files) for a in args])
    assert res.code == 2, (res.code, res.err)
    assert "Traceback" not in res.err
    assert len(res.err_lines) == 1, res.err
    assert pattern in res.err, res.err
