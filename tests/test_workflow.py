"""The one workflow (dualcal.workflow): the same input gives the same files whichever way it comes in."""

import json

import numpy as np
import pytest

from dualcal.synthetic import synth
from dualcal import workflow
from dualcal.batch import BatchOptions, Device, calibrate_device, input_snapshot
from dualcal.geometry.board import Board
from dualcal.errors import InputError
from dualcal.files.io import rig_to_dict, save_corners
from dualcal.progress import collect_warnings, warn


@pytest.fixture(scope="module")
def device(tmp_path_factory):
    """A device folder with a synthetic corners.json (stereo rig, 8 instants)."""
    folder = tmp_path_factory.mktemp("fleet") / "phone-a"
    folder.mkdir()
    truth = synth.make_truth("stereo", 8, seed=3)
    save_corners(folder / "corners.json", synth.noisy_corner_set(truth, 0.1, seed=3))
    return folder


def _same(a, b, path="") -> None:
    """``a`` and ``b`` have the same keys and the same values (floats to 1e-9 relative)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, sorted(set(a) ^ set(b)))
        for key in a:
            _same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert isinstance(b, (int, float)) and np.isclose(a, b, rtol=1e-9, atol=1e-12), (path, a, b)
    else:
        assert a == b, (path, a, b)


def test_cli_batch_and_api_write_the_same_calibration_and_evaluation(device, tmp_path, run_cli):
    corners_path = device / "corners.json"
    # the command line
    assert run_cli("calibrate", corners_path, "-o", tmp_path / "calib.json", "--no-compare-models").code == 0
    assert run_cli("evaluate", tmp_path / "calib.json", "-o", tmp_path / "eval.json").code == 0
    cli_calib = json.loads((tmp_path / "calib.json").read_text())
    cli_eval = json.loads((tmp_path / "eval.json").read_text())
    # a fleet of one device (the task batch runs on each worker)
    out = tmp_path / "phone-a"
    dev = Device("phone-a", device)
    result = calibrate_device(dev, out, BatchOptions(), input_snapshot(dev))
    assert result.ok, result.row
    # the Python API
    rig = workflow.calibrate_corners(workflow.read_corners(corners_path))
    api_calib = json.loads(json.dumps(rig_to_dict(rig)))
    api_eval = json.loads(json.dumps(workflow.evaluate_calibration(rig, progress=False)))

    assert "lens_models" in cli_calib["adjustment"] and "calibration_fingerprint" in cli_eval
    for calib, evaluation in ((json.loads((out / "calib.json").read_text()), json.loads((out / "eval.json").read_text())),
                              (api_calib, api_eval)):
        _same(cli_calib, calib)
        _same(cli_eval, evaluation)


def test_a_board_that_disagrees_with_the_corners_file_is_refused_naming_what_differs(device):
    found = workflow.read_corners(device / "corners.json").board
    other = f"{found.cols + 1}x{found.rows}"
    with pytest.raises(InputError, match=f"board {other} disagrees with .*corners.json, which has {found.spec()}"):
        workflow.read_corners(device / "corners.json", Board(found.cols + 1, found.rows, found.square_mm))
    with pytest.raises(InputError, match=f"square 31 mm disagrees with .*which has {found.square_mm:g} mm"):
        workflow.read_corners(device / "corners.json", Board(found.cols, found.rows, 31.0))


def test_the_square_tolerance_is_recorded_with_the_board(device):
    corners = workflow.read_corners(device / "corners.json", square_sigma_mm=0.05)
    assert corners.board.square_sigma_mm == 0.05
    assert corners.board.to_dict()["square_sigma_mm"] == 0.05
    assert workflow.read_corners(device / "corners.json").board.square_sigma_mm == 0.0


def test_detection_options_on_a_corners_file_are_a_warning(device):
    with collect_warnings() as warnings:
        workflow.read_corners(device / "corners.json", jobs=3)
    assert len(warnings) == 1 and "detection options (jobs) do not apply" in warnings[0]


def test_library_errors_name_no_command_line_flag(device, tmp_path):
    with pytest.raises(InputError) as err:
        workflow.read_corners(tmp_path)           # photos (none here) without a board
    assert "--" not in str(err.value)
    with pytest.raises(InputError) as err:
        workflow.read_corners(device / "corners.json", cameras=["a=*.jpg"])
    assert "--" not in str(err.value)


def test_warnings_are_collected_instead_of_printed(capsys):
    with collect_warnings() as warnings:
        warn("one [bold]thing[/]")
    assert warnings == ["one [bold]thing[/]"] and capsys.readouterr().err == ""
    warn("two [x]")
    assert capsys.readouterr().err.strip() == "dualcal: warning: two [x]"
