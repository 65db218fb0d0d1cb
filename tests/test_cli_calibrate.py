"""`dualcal calibrate` and `dualcal synth`: results, and one clear line with exit code 2 on bad input."""

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from schema_check import assert_valid
from dualcal.files.io import load_rig, save_corners
from dualcal.synthetic.synth import make_truth, noisy_corner_set


@pytest.fixture
def synth_dir(tmp_path, run_cli):
    out = tmp_path / "set"
    res = run_cli("synth", out, "--preset", "note8", "--views", "8", "--seed", "4", "--no-photos")
    assert res.code == 0, res.err
    return out


def _assert_one_line_error(res, pattern):
    assert res.code == 2, (res.code, res.err)
    assert len(res.err_lines) == 1, res.err
    assert "Traceback" not in res.err
    assert pattern in res.err, res.err


def test_synth_then_calibrate_recovers_the_truth(synth_dir, run_cli):
    res = run_cli("calibrate", synth_dir / "corners.json", "-o", synth_dir / "calib.json")
    assert res.code == 0, res.err
    for text in ("alpha = fx", "Model 1 (skew = 0)", "Model 2 (skew free)", "D (mm)", "d_kappa"):
        assert text in res.out
    rig, truth = load_rig(synth_dir / "calib.json"), load_rig(synth_dir / "truth.json")
    for name in ("wide", "tele"):
        assert abs(rig.cameras[name].fx - truth.cameras[name].fx) < 4 * rig.camera_sigma[name]["fx"]
    assert rig.rig["tele"].baseline_mm == pytest.approx(truth.rig["tele"].baseline_mm, abs=0.1)
    assert rig.skew is False and rig.rig_mode == "rigid"


def test_photo_names_with_brackets_are_printed_as_they_are(synth_dir, run_cli):
    """The tables read no markup: a photo named ``IMG_02 [edited]`` (a phone's copy) is printed whole, and one with
    ``[/x]`` in its name does not stop the command (rich took ``[edited]`` for a style, and ``[/x]`` for a closing
    tag it could not match)."""
    doc = json.loads((synth_dir / "corners.json").read_text())
    for cam in doc["cameras"].values():
        views = cam["views"]
        first, second = sorted(views)[:2]
        views[f"{first} [edited]"], views[f"{second} [/x]"] = views.pop(first), views.pop(second)
    (synth_dir / "renamed.json").write_text(json.dumps(doc))
    res = run_cli("calibrate", synth_dir / "renamed.json", "-o", synth_dir / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err
    assert " [edited] " in res.out and " [/x] " in res.out


@pytest.mark.parametrize("flags,mode,skew", [(["--rig", "paper", "--skew"], "paper", True),
                                             (["--rig", "none"], "none", False)])
def test_calibrate_modes_are_recorded(synth_dir, run_cli, flags, mode, skew):
    res = run_cli("calibrate", synth_dir / "corners.json", "-o", synth_dir / "c.json", "--no-compare-models", *flags)
    assert res.code == 0, res.err
    doc = assert_valid(synth_dir / "c.json")
    assert doc["rig_mode"] == mode and doc["skew"] is skew


def test_calibrate_model_flag_fits_opencvs_lens_and_records_it(tmp_path, run_cli):
    """`dualcal synth --preset stereo5` (OpenCV's five-coefficient lenses), then `calibrate --model
    k1k2p1p2k3`: calib.json names the model, has p1 p2 k3 with their sigmas, and the table shows them."""
    out = tmp_path / "set"
    assert run_cli("synth", out, "--preset", "stereo5", "--views", "8", "--seed", "2", "--noise", "0.1",
                   "--no-photos").code == 0
    res = run_cli("calibrate", out / "corners.json", "-o", out / "calib.json", "--model", "k1k2p1p2k3",
                  "--no-compare-models")
    assert res.code == 0, res.err
    assert "lens model k1k2p1p2k3" in res.out and "lens distortion" in res.out
    doc = assert_valid(out / "calib.json")
    assert doc["model"] == "k1k2p1p2k3" and doc["adjustment"]["options"]["model"] == "k1k2p1p2k3"
    truth = load_rig(out / "truth.json")
    assert truth.model == "k1k2p1p2k3"
    for name, entry in doc["cameras"].items():
        for p in ("p1", "p2", "k3"):
            assert abs(entry[p] - getattr(truth.cameras[name], p)) < 4 * entry["sigma"][p], (name, p)
        assert f"{entry['p1']:.5f}" in res.out


def test_calibrate_compares_the_lens_models_and_records_the_comparison(tmp_path, run_cli):
    """Every lens model on the same corners: a table, one recommendation in calib.json and in the
    line below the table (with the command to use it where it is not the model used)."""
    out = tmp_path / "set"
    assert run_cli("synth", out, "--preset", "stereo5", "--views", "8", "--seed", "2", "--noise", "0.1",
                   "--no-photos").code == 0
    res = run_cli("calibrate", out / "corners.json", "-o", out / "calib.json", "--no-compare-models", "--model", "k1k2")
    assert res.code == 0, res.err
    scores = assert_valid(out / "calib.json")["adjustment"]["lens_models"]
    assert [s["model"] for s in scores] == ["k1k2", "k1k2k3", "k1k2p1p2", "k1k2p1p2k3"]
    (best,) = [s for s in scores if s["recommended"]]
    assert min(s["worse_se"] for s in scores) == 0 and best["worse_se"] <= 2
    assert all(s["worse_se"] > 2 for s in scores if s["coefficients"] < best["coefficients"])
    assert "Lens models: RMS (px)" in res.out
    advice = next(line for line in res.out.splitlines() if line.startswith("lens model "))
    if best["model"] == "k1k2":
        assert advice.startswith("lens model k1k2: no richer model")
    else:
        assert f"--model {best['model']}" in advice
    res = run_cli("calibrate", out / "corners.json", "-o", out / "c2.json", "--no-compare-models", "--no-compare-lens",
                  "--model", "k1k2")
    assert res.code == 0 and "lens_models" not in json.loads((out / "c2.json").read_text())["adjustment"]
    assert "Lens models" not in res.out


def test_an_unknown_lens_model_is_refused_by_the_flag(synth_dir, run_cli):
    res = run_cli("calibrate", synth_dir / "corners.json", "-o", synth_dir / "c.json", "--model", "fisheye")
    assert res.code == 2 and "Invalid value for '--model'" in res.err and "k1k2p1p2k3" in res.err


def test_board_flag_that_disagrees_with_the_file(synth_dir, run_cli):
    res = run_cli("calibrate", synth_dir / "corners.json", "--board", "9x6", "--square", "30", "-o", synth_dir / "c.json")
    _assert_one_line_error(res, "board 9x6 disagrees")


@pytest.mark.parametrize("content,pattern", [("{\"board\": {\"cols\": 8,", "truncated"), ("not json", "malformed"),
                                             ("", "malformed")])
def test_malformed_or_truncated_corners(tmp_path, run_cli, content, pattern):
    p = tmp_path / "corners.json"
    p.write_text(content)
    _assert_one_line_error(run_cli("calibrate", p, "-o", tmp_path / "c.json"), pattern)


def test_fewer_than_three_usable_views(tmp_path, run_cli):
    cs = noisy_corner_set(make_truth("note8", 4, seed=1), 0.1)
    for v in ("IMG_01", "IMG_02"):
        cs.cameras["wide"].views[v] = None
    save_corners(tmp_path / "corners.json", cs)
    _assert_one_line_error(run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "c.json"),
                           "at least 3 are needed")


def test_degenerate_parallel_views(tmp_path, run_cli):
    truth = make_truth("note8", 1, seed=2)
    base = truth.view_poses["IMG_01"]
    from dualcal.geometry.model import Pose
    for k in range(2, 6):
        truth.view_poses[f"IMG_{k:02d}"] = Pose(base.R.copy(), base.t_mm + [8.0 * k, -4.0 * k, 15.0 * k])
    save_corners(tmp_path / "corners.json", noisy_corner_set(truth, 0.05))
    _assert_one_line_error(run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "c.json"), "parallel")


def test_calib_json_given_where_corners_are_expected(synth_dir, run_cli):
    _assert_one_line_error(run_cli("calibrate", synth_dir / "truth.json", "-o", synth_dir / "c.json"),
                           "this is a calib.json, expected a corners.json")


def test_missing_input_and_missing_output_folder(synth_dir, run_cli, tmp_path):
    _assert_one_line_error(run_cli("calibrate", tmp_path / "nothing.json", "-o", tmp_path / "c.json"),
                           "no such file")
    _assert_one_line_error(run_cli("calibrate", synth_dir / "corners.json", "-o", tmp_path / "no" / "c.json"),
                           "does not exist")


@pytest.mark.parametrize("args,pattern", [(["--board", "8x", "--square", "30"], "--board '8x' is malformed"),
                                          (["--board", "8x5", "--square", "-3"], "--square -3.0")])
def test_malformed_board_flags(synth_dir, run_cli, args, pattern):
    _assert_one_line_error(run_cli("calibrate", synth_dir / "corners.json", *args, "-o", synth_dir / "c.json"),
                           pattern)


def test_unknown_flag_value_is_a_usage_error(synth_dir, run_cli):
    res = run_cli("calibrate", synth_dir / "corners.json", "--rig", "bogus", "-o", synth_dir / "c.json")
    assert res.code == 2 and "Traceback" not in res.err


def test_killed_mid_write_leaves_the_old_output_intact(synth_dir):
    """SIGKILL a real calibration while it is writing calib.json: the earlier file survives whole."""
    out = synth_dir / "calib.json"
    out.write_text('{"earlier": "result"}\n')
    child = textwrap.dedent(f"""
        import sys, time, dualcal.files.io as io
        real_fsync = io.os.fsync
        def slow_fsync(fd):
            print("writing", flush=True)
            time.sleep(60)
        io.os.fsync = slow_fsync
        from dualcal.cli import main
        main(["calibrate", {str(synth_dir / "corners.json")!r}, "-o", {str(out)!r}, "--no-compare-models"])
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert out.read_text() == '{"earlier": "result"}\n'


def test_synth_writes_truth_and_noisy_corners(synth_dir):
    corners = assert_valid(synth_dir / "corners.json")
    truth = load_rig(synth_dir / "truth.json")
    assert set(corners["cameras"]) == {"wide", "tele"}
    assert corners["cameras"]["wide"]["image_size"] == [3024, 4032]
    uv = np.array(corners["cameras"]["tele"]["views"]["IMG_01"])
    from dualcal.geometry.camera import project_points
    exact = project_points(truth.cameras["tele"],
                           truth.camera_poses["tele"]["IMG_01"].apply(truth.board.object_points_mm()))
    assert 0.05 < np.std(uv - exact) < 0.15          # --noise 0.1 px by default


def test_synth_bad_values(tmp_path, run_cli):
    _assert_one_line_error(run_cli("synth", tmp_path / "x", "--scale", "0"), "--scale")
    _assert_one_line_error(run_cli("synth", tmp_path / "a" / "b"), "does not exist")


def test_calibrate_chooses_each_cameras_lens_model_by_default_and_prints_the_choice(tmp_path, run_cli):
    """``--model auto`` (the default): calib.json names every camera's model and records the
    comparison per camera; the table shows each camera's held-out RMS per model, the chosen starred."""
    out = tmp_path / "set"
    assert run_cli("synth", out, "--preset", "stereo5", "--views", "8", "--seed", "2", "--noise", "0.1",
                   "--no-photos").code == 0
    res = run_cli("calibrate", out / "corners.json", "-o", out / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err
    doc = json.loads((out / "calib.json").read_text())
    chosen = doc["adjustment"]["lens_models_chosen"]
    assert set(chosen) == {"left", "right"} and all(doc["cameras"][n]["model"] == m for n, m in chosen.items())
    assert doc["model"] == (chosen["left"] if len(set(chosen.values())) == 1 else "mixed")
    assert [e["model"] for e in doc["adjustment"]["lens_models"]] == ["k1k2", "k1k2k3", "k1k2p1p2", "k1k2p1p2k3"]
    assert "Lens model of each camera (--model auto)" in res.out
    row = next(line for line in res.out.splitlines() if line.strip().startswith("left"))
    assert row.count("*") == 1


def test_model_flags_name_one_camera_or_every_camera(tmp_path, run_cli):
    out = tmp_path / "set"
    assert run_cli("synth", out, "--preset", "stereo5", "--views", "6", "--seed", "2", "--no-photos").code == 0
    res = run_cli("calibrate", out / "corners.json", "-o", out / "c.json", "--no-compare-models",
                  "--model", "k1k2p1p2", "--model", "right=k1k2")
    assert res.code == 0, res.err
    doc = json.loads((out / "c.json").read_text())
    assert (doc["model"], doc["cameras"]["left"]["model"], doc["cameras"]["right"]["model"]) == \
        ("mixed", "k1k2p1p2", "k1k2")
    res = run_cli("calibrate", out / "corners.json", "-o", out / "c.json", "--model", "middle=k1k2")
    _assert_one_line_error(res, "lens model given for camera 'middle', which is not one of the rig's (left, right)")
    res = run_cli("calibrate", out / "corners.json", "-o", out / "c.json", "--model", "auto", "--model", "left=kb4")
    _assert_one_line_error(res, "--model auto chooses every camera's model: it cannot be combined with CAMERA=NAME")
