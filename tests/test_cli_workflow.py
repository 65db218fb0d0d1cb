"""Iterating on a calibration from the command line: datasets refused with one clear line, --exclude,
the per-photo table, a corners.json edited by hand, and files that belong to another calibration."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from schema_check import assert_valid
from dualcal.files.io import calibration_fingerprint, load_corners, load_rig, save_corners, save_rig
from dualcal.synthetic.synth import make_truth, noisy_corner_set, truth_rig_model


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """A rendered note8 photo set: photos/wide/IMG_01..06.jpg, photos/tele/IMG_01..06.jpg."""
    from dualcal.cli import main

    out = tmp_path_factory.mktemp("workflow") / "set"
    with pytest.raises(SystemExit):
        main(["synth", str(out), "--views", "6", "--scale", "0.25", "--seed", "2"])
    return out / "photos"


def _one_line(res, code=2):
    assert res.code == code, (res.code, res.err)
    assert len(res.err_lines) == 1 and "Traceback" not in res.err, res.err
    return res.err_lines[0]


# ---------------------------------------------------------------------------- datasets refused


def _dataset_with(tmp_path, photos, case):
    d = tmp_path / "ds"
    shutil.copytree(photos, d)
    if case == "empty camera folder":
        for p in (d / "tele").iterdir():
            p.unlink()
    elif case == "nothing pairs":
        for p in (d / "tele").iterdir():
            p.rename(p.with_name("TELE" + p.name[3:]))
    elif case == "photos and subfolders":
        shutil.copy(d / "wide" / "IMG_01.jpg", d / "screenshot.jpg")
    return d


@pytest.mark.parametrize("command", ["detect", "calibrate"])
@pytest.mark.parametrize("case, words", [
    ("empty camera folder", ["camera folder", "/tele", "holds no photos", "move it out"]),
    ("nothing pairs", ["camera 'tele' pairs with", "'wide'", "'TELE_01' vs 'IMG_01'", "--pair-by time"]),
    ("photos and subfolders", ["holds photos (screenshot.jpg, ...) and also subfolders with photos (tele, wide)",
                               "its own subfolder"]),
])
def test_a_dataset_that_cannot_be_calibrated_is_refused_in_one_line(photos, tmp_path, run_cli, command, case, words):
    d = _dataset_with(tmp_path, photos, case)
    out = tmp_path / ("corners.json" if command == "detect" else "calib.json")
    line = _one_line(run_cli(command, d, "--board", "8x5", "--square", "30", "-o", out))
    for w in words:
        assert w in line, line
    assert str(d) in line
    assert not out.exists()


# ---------------------------------------------------------------------------- --exclude and the photo table


def test_exclude_on_detect_leaves_photos_out_and_records_them(photos, tmp_path, run_cli):
    out = tmp_path / "corners.json"
    res = run_cli("detect", photos, "--board", "8x5", "--square", "30", "-o", out,
                  "--exclude", "IMG_02", "--exclude", "tele/IMG_05", "--exclude", "IMG_04.jpg")
    assert res.code == 0, res.err
    assert "; 5 left out by --exclude; wrote" in res.err
    corners = load_corners(out)
    assert sorted(corners.cameras["wide"].views) == ["IMG_01", "IMG_03", "IMG_05", "IMG_06"]
    assert sorted(corners.cameras["tele"].views) == ["IMG_01", "IMG_03", "IMG_06"]
    assert sorted(corners.cameras["tele"].meta["excluded"]) == ["IMG_02", "IMG_04", "IMG_05"]
    assert corners.cameras["tele"].meta["excluded"]["IMG_05"].endswith("tele/IMG_05.jpg")


def test_exclude_that_matches_nothing_is_a_warning_and_one_that_empties_a_camera_an_error(photos, tmp_path, run_cli):
    res = run_cli("detect", photos, "--board", "8x5", "--square", "30", "-o", tmp_path / "c.json",
                  "--exclude", "IMG_99")
    assert res.code == 0 and "--exclude 'IMG_99' matches no photo" in res.err
    line = _one_line(run_cli("detect", photos, "--board", "8x5", "--square", "30", "-o", tmp_path / "c.json",
                             "--exclude", "tele/*"))
    assert "leaves camera 'tele' without photos" in line


@pytest.fixture(scope="module")
def corners_json(tmp_path_factory):
    d = tmp_path_factory.mktemp("corners")
    save_corners(d / "corners.json", noisy_corner_set(make_truth("note8", 8, seed=4), 0.1, seed=4))
    return d / "corners.json"


def test_calibrate_prints_every_photo_and_exclude_works_on_a_corners_json(corners_json, tmp_path, run_cli):
    out = tmp_path / "calib.json"
    res = run_cli("calibrate", corners_json, "-o", out, "--no-compare-models", "--exclude", "tele/IMG_03")
    assert res.code == 0, res.err
    rows = {line.split()[0]: line.split() for line in res.out.splitlines() if line.strip().startswith("IMG_")}
    assert sorted(rows) == [f"IMG_0{i}" for i in range(1, 9)]
    assert rows["IMG_01"][-1] == "kept" and float(rows["IMG_01"][1]) < 0.5
    assert "tele: left out by --exclude" in " ".join(rows["IMG_03"])
    assert "Photos: 15 of 16 kept" in res.out
    rig = load_rig(out)
    assert "IMG_03" not in rig.camera_poses["tele"] and "IMG_03" in rig.camera_poses["wide"]
    assert rig.corners.cameras["tele"].meta["excluded"] == {"IMG_03": None}


def test_the_photo_table_says_why_a_photo_was_dropped_or_not_found(corners_json, tmp_path, run_cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    cs = load_corners(corners_json)
    # another numbering (each row's corners in the other order): a gross misfit, dropped; 3 px of noise on every
    # corner of another photo (a blurred one) is kept, weighed by its own noise
    cs.cameras["wide"].views["IMG_05"] = cs.cameras["wide"].views["IMG_05"].reshape(5, 8, 2)[:, ::-1].reshape(40, 2)
    cs.cameras["tele"].views["IMG_06"] = cs.cameras["tele"].views["IMG_06"] + np.random.default_rng(0).normal(
        0, 3.0, (40, 2))
    cs.cameras["tele"].views["IMG_07"] = None
    save_corners(tmp_path / "corners.json", cs)
    res = run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err
    table = res.out[res.out.index("Photos:"):]
    row5 = next(line for line in table.splitlines() if line.strip().startswith("IMG_05"))
    assert "dropped: instant IMG_05: its photos fit their cameras alone" in row5
    assert float(row5.split()[1]) > 2
    row6 = next(line for line in table.splitlines() if line.strip().startswith("IMG_06"))
    assert row6.split()[-1] == "kept"
    noise = json.loads((tmp_path / "calib.json").read_text())["adjustment"]["photo_noise"]["photos"]["tele"]["IMG_06"]
    assert 2.0 < noise["noise_px"] < 4.5 and noise["weight"] < 0.01
    row7 = next(line for line in table.splitlines() if line.strip().startswith("IMG_07"))
    assert "tele: board not found" in row7 and row7.split()[2] == "-"


def test_the_photo_table_shows_each_photos_blur_and_noise_and_notes_the_blurred_ones(corners_json, tmp_path, run_cli,
                                                                                      monkeypatch):
    """corners.json's ``photo_quality`` (as detection measures it): a blur / noise column per camera, and a note on
    the photo whose edges are over twice as wide as its camera's typical photo's."""
    monkeypatch.setenv("COLUMNS", "220")
    cs = load_corners(corners_json)
    for cam, cc in cs.cameras.items():
        cc.meta["photo_quality"] = {v: {"blur_px": 6.2 if (cam, v) == ("wide", "IMG_05") else 1.5,
                                        "corner_noise_px": 0.3 if (cam, v) == ("wide", "IMG_05") else 0.1}
                                    for v in cc.views}
    save_corners(tmp_path / "corners.json", cs)
    assert load_corners(tmp_path / "corners.json").cameras["wide"].meta["photo_quality"]["IMG_05"]["blur_px"] == 6.2
    res = run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err
    table = res.out[res.out.index("Photos:"):]
    assert "wide blur / noise" in table and "tele blur / noise" in table
    rows = {line.split()[0]: line for line in table.splitlines() if line.strip().startswith("IMG_")}
    assert "6.2 / 0.300" in rows["IMG_05"] and "wide: blurred (edges 6.2 px wide, corner noise 0.30 px)" in rows["IMG_05"]
    assert "blurred" not in rows["IMG_04"] and "1.5 / 0.100" in rows["IMG_04"]


def test_a_corners_json_edited_by_hand_keeps_working(corners_json, tmp_path, run_cli):
    """Views deleted from one camera, a view set to null: calibrate as usual."""
    doc = json.loads(corners_json.read_text())
    del doc["cameras"]["tele"]["views"]["IMG_02"]
    doc["cameras"]["wide"]["views"]["IMG_06"] = None
    (tmp_path / "corners.json").write_text(json.dumps(doc))
    res = run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err
    assert_valid(tmp_path / "calib.json")
    rig = load_rig(tmp_path / "calib.json")
    assert sorted(rig.camera_poses["tele"]) == [f"IMG_0{i}" for i in (1, 3, 4, 5, 6, 7, 8)]
    assert "IMG_06" not in rig.camera_poses["wide"]


def test_a_corners_json_with_null_corners_keeps_working(corners_json, tmp_path, run_cli):
    doc = json.loads(corners_json.read_text())
    for k in (0, 7, 20):
        doc["cameras"]["tele"]["views"]["IMG_02"][k] = None
    (tmp_path / "corners.json").write_text(json.dumps(doc))
    res = run_cli("calibrate", tmp_path / "corners.json", "-o", tmp_path / "calib.json", "--no-compare-models")
    assert res.code == 0, res.err


# ---------------------------------------------------------------------------- files of another calibration


@pytest.fixture(scope="module")
def two_calibrations(tmp_path_factory, corners_json):
    from dualcal.estimation.calibrate import calibrate_rig

    d = tmp_path_factory.mktemp("two")
    save_rig(d / "a.json", calibrate_rig(load_corners(corners_json)))
    other = noisy_corner_set(make_truth("note8", 8, seed=9), 0.1, seed=9)
    save_rig(d / "b.json", calibrate_rig(other))
    return d


def test_evaluate_writes_the_fingerprint_and_report_refuses_another_calibrations_eval(two_calibrations, run_cli):
    d = two_calibrations
    assert run_cli("evaluate", d / "a.json", "-o", d / "eval-a.json").code == 0
    doc = json.loads((d / "eval-a.json").read_text())
    assert doc["calibration_fingerprint"] == calibration_fingerprint(load_rig(d / "a.json"))
    assert run_cli("report", d / "a.json", "--eval", d / "eval-a.json", "-o", d / "r.html").code == 0
    (d / "r2.html").write_text("earlier")
    line = _one_line(run_cli("report", d / "b.json", "--eval", d / "eval-a.json", "-o", d / "r2.html"))
    assert "eval-a.json was computed from another calibration than" in line and "dualcal evaluate" in line
    assert (d / "r2.html").read_text() == "earlier"


def test_an_eval_json_without_fingerprint_must_name_the_calibrations_cameras(two_calibrations, tmp_path, run_cli):
    d = two_calibrations
    cases = {"cases": {"dual": {"rmse_mm": [1, 2, 3], "pairs": 2}, "left": {"rmse_mm": [1, 2, 3], "pairs": 2}}}
    (tmp_path / "eval.json").write_text(json.dumps(cases))
    line = _one_line(run_cli("report", d / "a.json", "--eval", tmp_path / "eval.json", "-o", tmp_path / "r.html"))
    assert "names cameras left that" in line


def test_the_fingerprint_ignores_formatting_and_follows_the_numbers(two_calibrations, tmp_path):
    d = two_calibrations
    rig = load_rig(d / "a.json")
    doc = json.loads((d / "a.json").read_text())
    doc["dualcal_version"] = "9.9"
    (tmp_path / "a.json").write_text(json.dumps(doc, indent=4))
    assert calibration_fingerprint(load_rig(tmp_path / "a.json")) == calibration_fingerprint(rig)
    doc["cameras"]["tele"]["fx"] += 1e-9
    (tmp_path / "a.json").write_text(json.dumps(doc))
    assert calibration_fingerprint(load_rig(tmp_path / "a.json")) != calibration_fingerprint(rig)


@pytest.mark.parametrize("command", ["evaluate", "report"])
def test_a_calib_json_whose_corners_belong_to_another_calibration_is_refused(two_calibrations, tmp_path, run_cli,
                                                                             command):
    d = two_calibrations
    a, b = (json.loads((d / f"{n}.json").read_text()) for n in "ab")
    a["corners"] = b["corners"]
    (tmp_path / "mixed.json").write_text(json.dumps(a))
    line = _one_line(run_cli(command, tmp_path / "mixed.json", "-o", tmp_path / "out"))
    assert "the corners it carries do not fit its calibration" in line


def test_truth_with_noisy_corners_is_not_refused(tmp_path, run_cli):
    truth = make_truth("note8", 5, seed=1)
    save_rig(tmp_path / "truth.json", truth_rig_model(truth, noisy_corner_set(truth, 0.3, seed=1)))
    assert run_cli("evaluate", tmp_path / "truth.json", "-o", tmp_path / "eval.json").code == 0
    assert_valid(tmp_path / "truth.json")
    assert_valid(tmp_path / "eval.json")


@pytest.mark.parametrize("width", [40, 80, 200])
def test_the_tables_given_their_measured_widths_render_the_same_text(corners_json, tmp_path, width):
    """The commands' tables give rich the widths of their unwrapped columns (it then need not measure every cell
    again): the text is the same as rich's own measuring gives, on narrow terminals too, with a photo name of wide
    characters and a control character in it."""
    import io

    from dualcal.cli.common import table_console
    from dualcal.cli.tables import checks_table, photo_table
    from dualcal.workflow import calibrate_corners

    cs = load_corners(corners_json)
    cs.cameras["wide"].views["写真\x07_01"] = cs.cameras["wide"].views.pop("IMG_01")
    cs.cameras["tele"].views["写真\x07_01"] = cs.cameras["tele"].views.pop("IMG_01")
    rig = calibrate_corners(cs)

    def text(table, measured):
        if not measured:
            for column in table.columns:
                column.width = None
        console = table_console()
        console.file, console.width = io.StringIO(), width
        console.print(table)
        return console.file.getvalue()

    for build in (photo_table, checks_table):
        assert any(c.width is not None for c in build(rig).columns)
        assert text(build(rig), True) == text(build(rig), False)
