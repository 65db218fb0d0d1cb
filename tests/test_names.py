"""Names that are data (issue 24, finding 5, and the batch leftovers of finding 7): formula-looking device names
made inert in fleet.csv, control characters kept off the terminal, the pick page's data unable to end its script,
device names that are the fleet's own files refused, no empty device folder after an interruption."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from rich.table import Table

from dualcal.synthetic import synth
from dualcal.batch import (BatchOptions, Device, calibrate_device, csv_safe_cell, find_devices, input_snapshot,
                           write_fleet_tables)
from dualcal.cli.common import table_console
from dualcal.errors import InputError
from dualcal.files.io import save_corners
from dualcal.progress import warn
from dualcal.pages.report.pick import render_pick_page, script_json
from dualcal.terminal import printable

HOSTILE = ["=HYPERLINK(\"http://x\",\"y\")", "+cmd|' /C calc'!A0", "-2+3", "@SUM(A1)", "\tx", "\rx"]


@pytest.mark.parametrize("name", HOSTILE)
def test_formula_looking_text_is_made_inert(name):
    assert csv_safe_cell(name) == "'" + name


@pytest.mark.parametrize("value", [-0.145, "-0.145", "+3", 0, "ok", "failed: too few views", None])
def test_numbers_and_plain_text_stay_as_they_are(value):
    assert csv_safe_cell(value) == value


def test_fleet_csv_quotes_formula_device_names_and_keeps_numbers(tmp_path):
    table = pd.DataFrame({"device": HOSTILE[:4], "status": ["ok"] * 4, "wide.k1": [-0.145, 0.1, -2.0, 3.5]})
    csv_path, parquet_path = write_fleet_tables(tmp_path, table)
    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["device"] for r in rows] == ["'" + n for n in HOSTILE[:4]]
    assert [r["wide.k1"] for r in rows] == ["-0.145", "0.1", "-2.0", "3.5"]
    assert list(pd.read_parquet(parquet_path)["device"]) == HOSTILE[:4]     # the data itself is not changed


@pytest.mark.parametrize("name", ["fleet.csv", "fleet.parquet", "fleet.html", "FLEET.CSV"])
def test_a_device_named_like_the_fleets_own_files_is_refused(tmp_path, name):
    (tmp_path / "unit-1").mkdir()
    (tmp_path / name).mkdir()
    with pytest.raises(InputError, match="named like the fleet's own files"):
        find_devices(tmp_path)


def test_control_characters_never_reach_the_terminal(capsys):
    name = "IMG\x1b[2J\x1b]0;pwned\x07_01\x9b"
    assert printable(name) == "IMG[2J]0;pwned_01"
    warn(f"photo {name} [bold]x[/bold] skipped")
    table = Table()
    table.add_column("view")
    table.add_row(name)
    table_console().print(table)
    out, err = capsys.readouterr()
    assert not re.search(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]", out + err)
    assert "IMG[2J]0;pwned_01" in out and "[bold]x[/bold]" in err          # shown, not run, not markup


def test_the_cli_error_line_holds_no_control_character(tmp_path, run_cli):
    res = run_cli("evaluate", tmp_path / "no\x1b[31msuch.json", "-o", tmp_path / "e.json")
    assert res.code == 2 and "\x1b" not in res.err and "no[31msuch.json" in res.err


def test_script_json_cannot_end_its_script():
    value = [{"file": "a</script><!--<script>&b.png"}]
    text = str(script_json(value))
    assert "<" not in text and ">" not in text and json.loads(text) == value


def test_the_pick_page_keeps_a_hostile_file_name_inside_its_data(tmp_path):
    truth = synth.make_truth("stereo", views=3, seed=0)
    rig = synth.truth_rig_model(truth)
    photos = {}
    for name in ("left", "right"):
        w, h = rig.cameras[name].image_size
        photos[name] = tmp_path / f"{name}<!--<script>.png"      # (no "/" in a file name)
        Image.fromarray(np.zeros((h, w), np.uint8)).save(photos[name])
    page = render_pick_page(rig, photos, max_px=64)
    data = re.search(r'<script type="application/json" id="photos-data">(.*?)</script>', page, re.S).group(1)
    assert [p["file"] for p in json.loads(data)] == [p.name for p in photos.values()]
    # the page's own scripts are all there is: a name adds no <script> and ends none
    assert page.count("<script") == page.count("</script>") == 2


def test_an_interrupted_device_leaves_no_empty_folder(tmp_path, monkeypatch):
    truth = synth.make_truth("stereo", views=4, seed=0)
    device = tmp_path / "in" / "unit-1"
    device.mkdir(parents=True)
    save_corners(device / "corners.json", synth.noisy_corner_set(truth, 0.1, seed=0))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr("dualcal.batch.calibrate_corners", interrupted)
    dev = Device("unit-1", device)
    with pytest.raises(KeyboardInterrupt):
        calibrate_device(dev, tmp_path / "out" / "unit-1", BatchOptions(evaluate=False), input_snapshot(dev))
    assert not (tmp_path / "out" / "unit-1").exists()


def test_a_device_with_a_bad_json_input_is_recorded_not_retried(tmp_path):
    """Finding 7: a corners.json with NaN (or a wrong type) was an internal error, tried again on every run."""
    device = tmp_path / "in" / "unit-1"
    device.mkdir(parents=True)
    truth = synth.make_truth("stereo", views=4, seed=0)
    save_corners(device / "corners.json", synth.noisy_corner_set(truth, 0.1, seed=0))
    doc = json.loads((device / "corners.json").read_text())
    doc["board"]["square_mm"] = float("nan")
    (device / "corners.json").write_text(json.dumps(doc))
    dev = Device("unit-1", device)
    (tmp_path / "out").mkdir()
    result = calibrate_device(dev, tmp_path / "out" / "unit-1", BatchOptions(evaluate=False), input_snapshot(dev))
    assert result.row["status"].startswith("failed: ") and "board.square_mm is NaN" in result.row["status"]
    recorded = json.loads((tmp_path / "out" / "unit-1" / "batch.json").read_text())
    assert recorded["row"]["status"] == result.row["status"]
