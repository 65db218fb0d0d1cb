"""The fleet: one Dask task per device on a local cluster of 2 worker processes, against known truth.

The synthetic fleet (:mod:`dualcal.synthetic.synth_fleet`): 12 units of the note8 rig given as corners.json,
each with its own true intrinsics and rig; one triple-camera unit; one unit given as rendered
photos; and two that must fail (a truncated corners.json, a unit with 2 views). The cluster and
the first run over the fleet (during which a worker process is killed) are made once per module.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from schema_check import assert_valid
from dualcal import batch
from dualcal.files.io import load_rig, rig_to_dict, save_corners
from dualcal.pages.report import fleet
from dualcal.synthetic.synth import noisy_corner_set, truth_rig_model
from dualcal.synthetic.synth_fleet import device_truth, write_device_photos, write_fleet

distributed = pytest.importorskip("dask.distributed")

Z_LIMIT = 4.0
BOARD = {"cols": 8, "rows": 5, "square_mm": 30.0}
# the truth's lens model for every camera (not auto, which may give a wide lens kb4): parameters compared one to one
OPTIONS = batch.BatchOptions(board=batch.Board(8, 5, 30.0), calibrate={"model": "k1k2"})
FAILING = {"broken": "malformed or truncated JSON", "few-views": "has 2 usable view(s); at least 3 are needed"}


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster, distributed.Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def fleet_root(tmp_path_factory):
    """ROOT of the synthetic fleet and the truth of every device that can be calibrated."""
    root = tmp_path_factory.mktemp("fleet") / "root"
    truths = write_fleet(root, n_devices=12, views=8, seed=100)
    truths["triple-unit"] = device_truth("triple", views=8, seed=200)
    (root / "triple-unit").mkdir()
    save_corners(root / "triple-unit" / "corners.json", noisy_corner_set(truths["triple-unit"], 0.1, seed=200))
    truths["photos-unit"] = device_truth("note8", views=5, seed=300, scale=0.25)
    write_device_photos(root / "photos-unit", truths["photos-unit"], seed=300)
    (root / "broken").mkdir()
    (root / "broken" / "corners.json").write_text('{"board": {"cols": 8, "rows": 5, "squ')
    (root / "few-views").mkdir()
    save_corners(root / "few-views" / "corners.json", noisy_corner_set(device_truth("note8", 2, seed=400), 0.1))
    return root, truths


@pytest.fixture(scope="module")
def first_run(client, fleet_root, tmp_path_factory):
    """Every device calibrated once; after the first result, a worker that is busy is killed."""
    root, _ = fleet_root
    out = tmp_path_factory.mktemp("out")
    devices = batch.find_devices(root)
    workers_before = set(client.scheduler_info()["workers"])
    killed = None
    results = []
    for result in batch.calibrate_fleet(devices, out, OPTIONS, client=client, progress=False):
        results.append(result)
        if killed is None:
            busy = {addr: keys for addr, keys in client.processing().items() if keys}
            addr = next(iter(busy))
            pid = client.run(os.getpid, workers=[addr])[addr]
            os.kill(pid, signal.SIGKILL)
            killed = {"address": addr, "tasks": len(busy[addr])}
    client.wait_for_workers(2, timeout=60)
    workers_after = set(client.scheduler_info()["workers"])
    return {"out": out, "results": results, "devices": devices, "killed": killed,
            "workers": (workers_before, workers_after)}


def _truth_row(truth) -> dict:
    return batch.fleet_row(rig_to_dict(truth_rig_model(truth)))


# ---------------------------------------------------------------------------- the first run


def test_every_calibrated_device_is_within_4_sigma_of_its_truth(first_run, fleet_root):
    _, truths = fleet_root
    rows = {r.device: r.row for r in first_run["results"]}
    assert {d for d, row in rows.items() if row["status"] == "ok"} == set(truths)
    table = batch.fleet_table(first_run["results"])
    parameters = fleet.estimated_parameters(table)
    for device, truth in truths.items():
        row, expected = rows[device], _truth_row(truth)
        compared = [p for p in parameters if p.column in expected and p.column in row]
        # 2 cameras x (fx fy cx cy k1 k2) + baseline, 3 angles, 3 translations; 3 cameras: 18 + 14
        assert len(compared) == (32 if device == "triple-unit" else 19)
        z = {p.column: (row[p.column] - expected[p.column]) / row[p.sigma] for p in compared}
        worst = max(z, key=lambda c: abs(z[c]))
        assert abs(z[worst]) < Z_LIMIT, f"{device} {worst}: {z[worst]:+.2f} sigma from its truth"


def test_the_devices_differ_from_each_other_by_far_more_than_their_sigmas(first_run):
    """The fleet's units really differ (the test would not tell a per-device result from a copy)."""
    table = fleet.succeeded(batch.fleet_table(first_run["results"]))
    note8 = table[table["device"].str.startswith("unit-")]
    for column, sigma in (("wide.fx", "wide.sigma.fx"), ("tele.fy", "tele.sigma.fy"),
                          ("rig.tele.opk_arcmin.kappa", "rig.tele.sigma.opk_arcmin.kappa")):
        assert note8[column].std() > 3 * note8[sigma].median()


def test_a_failing_device_is_a_row_with_its_reason(first_run):
    rows = {r.device: r.row for r in first_run["results"]}
    for device, reason in FAILING.items():
        assert rows[device]["status"].startswith("failed: ") and reason in rows[device]["status"]
        assert not (first_run["out"] / device / "calib.json").exists()
        recorded = json.loads((first_run["out"] / device / "batch.json").read_text())
        assert recorded["row"]["status"] == rows[device]["status"]


def test_the_run_survives_a_killed_worker(first_run):
    """The killed worker had tasks; Dask started a new worker and every device still has its row."""
    killed = first_run["killed"]
    before, after = first_run["workers"]
    assert killed["tasks"] >= 1
    assert killed["address"] not in after and len(after) == 2 and after != before
    assert sorted(r.device for r in first_run["results"]) == [d.name for d in first_run["devices"]]
    assert sum(r.ok for r in first_run["results"]) == len(first_run["devices"]) - len(FAILING)


def test_outputs_of_a_device_are_its_calibration(first_run, fleet_root):
    out = first_run["out"]
    rig = load_rig(out / "photos-unit" / "calib.json")
    assert rig.dropped_views == [] and set(rig.cameras) == {"wide", "tele"}
    assert set(assert_valid(out / "photos-unit" / "eval.json")["cases"]) == {"dual", "wide", "tele"}
    row = next(r.row for r in first_run["results"] if r.device == "photos-unit")
    assert row["input"] == "photos" and row["wide.fx"] == rig.cameras["wide"].fx
    assert row["wide.views"] == 5 and row["board.cols"] == 8


# ---------------------------------------------------------------------------- resuming


def test_a_second_run_skips_every_device_without_a_cluster(first_run):
    """Nothing changed: every device comes from its batch.json; no scheduler is even contacted."""
    out = first_run["out"]
    mtimes = {p: p.stat().st_mtime_ns for p in out.glob("*/*.json")}
    again = list(batch.calibrate_fleet(first_run["devices"], out, OPTIONS, scheduler="tcp://127.0.0.1:9",
                                       progress=False))
    assert all(r.skipped for r in again) and len(again) == len(first_run["devices"])
    first = {r.device: r.row for r in first_run["results"]}
    assert {r.device: r.row for r in again} == first
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/*.json")} == mtimes


def test_changed_inputs_or_options_redo_the_device(first_run, client):
    out, devices = first_run["out"], first_run["devices"]
    unit = next(d for d in devices if d.name == "unit-003")
    snapshot = batch.input_snapshot(unit)
    assert batch.recorded_result(unit, out / unit.name, OPTIONS, snapshot) is not None
    assert batch.recorded_result(unit, out / unit.name, replace(OPTIONS, calibrate={"skew": True}), snapshot) is None
    assert batch.recorded_result(unit, out / unit.name, replace(OPTIONS, evaluate=False), snapshot) is None
    # photos devices depend on the dataset options too, corners devices do not
    photos = next(d for d in devices if d.name == "photos-unit")
    other_pairing = replace(OPTIONS, dataset={"pair_by": "time"})
    assert batch.recorded_result(unit, out / unit.name, other_pairing, snapshot) is not None
    assert batch.recorded_result(photos, out / photos.name, other_pairing, batch.input_snapshot(photos)) is None

    corners = unit.folder / "corners.json"
    st = corners.stat()
    os.utime(corners, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    again = list(batch.calibrate_fleet(devices, out, OPTIONS, client=client, progress=False))
    assert [r.device for r in again if not r.skipped] == ["unit-003"]
    assert next(r for r in again if r.device == "unit-003").ok

    # without evaluation the device is done again, and its eval.json (of the earlier run) removed
    [result] = batch.calibrate_fleet([unit], out, replace(OPTIONS, evaluate=False), client=client, progress=False)
    assert result.ok and not result.skipped and "eval.dual.pairs" not in result.row
    assert not (out / unit.name / "eval.json").exists() and (out / unit.name / "calib.json").is_file()


def test_a_missing_output_redoes_the_device(first_run):
    out = first_run["out"]
    unit = next(d for d in first_run["devices"] if d.name == "unit-007")
    snapshot = batch.input_snapshot(unit)
    eval_json = out / unit.name / "eval.json"
    saved = eval_json.read_bytes()
    eval_json.unlink()
    try:
        assert batch.recorded_result(unit, out / unit.name, OPTIONS, snapshot) is None
        assert batch.recorded_result(unit, out / unit.name, replace(OPTIONS, evaluate=False), snapshot) is None
    finally:
        eval_json.write_bytes(saved)
    assert batch.recorded_result(unit, out / unit.name, OPTIONS, snapshot) is not None


# ---------------------------------------------------------------------------- the table


def test_fleet_parquet_reads_back_with_the_documented_columns(first_run, tmp_path):
    table = batch.fleet_table(first_run["results"])
    csv_path, parquet_path = batch.write_fleet_tables(tmp_path, table)
    back = pd.read_parquet(parquet_path)
    arrow = pq.read_table(parquet_path)
    assert list(back.columns) == list(table.columns) == arrow.column_names
    assert list(back.columns[:5]) == ["device", "status", "input", "seconds", "warnings"]
    documented = ["wide.fx", "wide.fy", "wide.skew", "wide.cx", "wide.cy", "wide.k1", "wide.k2", "wide.rms_px",
                  "wide.views", "wide.image_size.w", "wide.image_size.h", "wide.sigma.fx", "wide.sigma.k2",
                  "tele.fx", "tele.sigma.cy", "ultra.fx", "ultra.sigma.fx",
                  "rig.tele.baseline_mm", "rig.tele.sigma.baseline_mm", "rig.tele.opk_arcmin.omega",
                  "rig.tele.sigma.opk_arcmin.kappa", "rig.tele.t_mm.x", "rig.tele.sigma.t_mm.z",
                  "rig.ultra.baseline_mm", "rms_px", "reference", "rig_mode", "skew", "board.square_mm",
                  "adjustment.s0_px", "adjustment.redundancy", "dropped_views", "dualcal_version",
                  "eval.dual.rmse_mm.x", "eval.dual.pairs", "eval.wide.rmse_mm.z", "eval.holdout"]
    assert [c for c in documented if c not in back.columns] == []
    assert not any(c.endswith(".R") or ".R." in c for c in back.columns)
    assert list(back["device"]) == sorted(back["device"])
    by_device = back.set_index("device")
    calib = assert_valid(first_run["out"] / "unit-005" / "calib.json")
    assert by_device.loc["unit-005", "tele.sigma.fx"] == calib["cameras"]["tele"]["sigma"]["fx"]
    assert by_device.loc["unit-005", "rig.tele.opk_arcmin.phi"] == calib["rig"]["tele"]["opk_arcmin"][1]
    assert by_device.loc["broken", "status"].startswith("failed: ") and pd.isna(by_device.loc["broken", "wide.fx"])
    assert pd.isna(by_device.loc["unit-005", "ultra.fx"]) and by_device.loc["triple-unit", "ultra.fx"] > 0
    from_csv = pd.read_csv(csv_path)
    np.testing.assert_allclose(from_csv["wide.fx"], back["wide.fx"], rtol=1e-12)
    assert list(from_csv["status"]) == list(back["status"])


def test_fleet_row_takes_whatever_calib_json_holds():
    """Keys that later lens models and checks add become columns without knowing them here; what
    is per instant (held-out errors, a check's statistic per instant) or a matrix is not."""
    calib = {"dualcal_version": "9", "board": {**BOARD, "sag_mm": 0.2}, "reference": "wide", "model": "k1k2p1p2k3",
             "cameras": {"wide": {"image_size": [400, 300], "fx": 1.0, "p1": 0.001, "k3": 0.3,
                                  "sigma": {"fx": 0.1, "p1": 1e-4}, "sigma_formal": {"fx": 0.05}}},
             "rig": {"tele": {"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t_mm": [1.0, 2.0, 3.0], "baseline_mm": 3.7,
                              "opk_arcmin": [1.0, 2.0, 3.0], "sigma": {"opk_arcmin": [0.1, 0.2, 0.3]}}},
             "views": {"IMG_01": {"R": [], "t_mm": [0, 0, 1]}}, "corners": {"board": BOARD},
             "camera_poses": {"wide": {"IMG_01": {}, "IMG_02": {}}}, "dropped_views": [{"view": "IMG_03"}],
             "adjustment": {"converged": True, "termination": "gradient", "options": {"drop_outliers": True},
                            "held_out_rms_px": 0.2, "held_out_per_instant": {"IMG_01": {"rms_px": 0.2, "corners": 40}}},
             "covariance": {"parameters": ["wide.fx"], "clustered": [[0.01]], "formal": [[0.0025]]},
             "checks": {"rig_rigid": {"ok": False, "message": "moved", "chi2": 40.0, "instants": {"IMG_01": 40.0}},
                        "photos": {"ok": True, "instants": 1}, "flat": {"ok": True}}}
    row = batch.fleet_row(calib, {"cases": {"dual": {"rmse_mm": [1, 2, 3], "pairs": 4}}, "per_pair": [{}]})
    assert row == {
        "dualcal_version": "9", "board.cols": 8, "board.rows": 5, "board.square_mm": 30.0, "board.sag_mm": 0.2,
        "reference": "wide", "model": "k1k2p1p2k3",
        "wide.image_size.w": 400, "wide.image_size.h": 300, "wide.fx": 1.0, "wide.p1": 0.001, "wide.k3": 0.3,
        "wide.sigma.fx": 0.1, "wide.sigma.p1": 1e-4, "wide.sigma_formal.fx": 0.05, "wide.views": 2,
        "rig.tele.t_mm.x": 1.0, "rig.tele.t_mm.y": 2.0, "rig.tele.t_mm.z": 3.0, "rig.tele.baseline_mm": 3.7,
        "rig.tele.opk_arcmin.omega": 1.0, "rig.tele.opk_arcmin.phi": 2.0, "rig.tele.opk_arcmin.kappa": 3.0,
        "rig.tele.sigma.opk_arcmin.omega": 0.1, "rig.tele.sigma.opk_arcmin.phi": 0.2,
        "rig.tele.sigma.opk_arcmin.kappa": 0.3,
        "adjustment.converged": True, "adjustment.termination": "gradient", "adjustment.options.drop_outliers": True,
        "adjustment.held_out_rms_px": 0.2,
        "checks.rig_rigid.ok": False, "checks.rig_rigid.message": "moved", "checks.rig_rigid.chi2": 40.0,
        "checks.photos.ok": True, "checks.photos.instants": 1,
        "checks.flat.ok": True, "dropped_views": 1, "checks.ok": False,
        "eval.dual.rmse_mm.x": 1, "eval.dual.rmse_mm.y": 2, "eval.dual.rmse_mm.z": 3, "eval.dual.pairs": 4,
        "eval.holdout": False}


def test_a_task_dask_gave_up_on_is_a_failed_row():
    """A device on which every worker died (KilledWorker) fails with that reason, like any other row."""
    class GaveUp:
        status = "error"

        def exception(self):
            return distributed.KilledWorker("calibrate_device-1", "tcp://127.0.0.1:1", 3)

    row = batch._result_of(GaveUp(), batch.Device("unit-x", Path("/nowhere"))).row
    assert row["device"] == "unit-x" and row["status"].startswith("failed: the worker process died every time")


def test_finding_devices(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "a").mkdir()
    (tmp_path / ".hidden").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "b" / "corners.json").write_text("{}")
    devices = batch.find_devices(tmp_path, exclude=[tmp_path / "out"])
    assert [(d.name, d.kind) for d in devices] == [("a", "photos"), ("b", "corners")]
    with pytest.raises(batch.InputError, match="holds no device folder"):
        batch.find_devices(tmp_path / "a")
    with pytest.raises(batch.InputError, match="--board COLSxROWS and --square MM"):
        batch.BatchOptions().check(devices)
    with pytest.raises(batch.InputError, match="relative to each device folder"):
        batch.BatchOptions(batch.Board(8, 5, 30.0), dataset={"cameras": ("left=/data/*.jpg",)}).check(devices)


# ---------------------------------------------------------------------------- fleet.html


def _small_table(values, sigmas, devices=None) -> pd.DataFrame:
    devices = devices or [f"d{i}" for i in range(len(values))]
    return pd.DataFrame({"device": devices, "status": ["ok"] * len(values), "wide.fx": values,
                         "wide.sigma.fx": sigmas, "wide.skew": 0.0, "wide.sigma.skew": 0.0, "rms_px": 0.1})


def test_deviation_and_drift_in_sigmas():
    table = _small_table([1.0, 2.0, 3.0, 10.0], [1.0, 1.0, 0.5, 1.0])
    params = fleet.estimated_parameters(table)
    assert [(p.column, p.sigma, p.group, p.name, p.unit) for p in params] == [
        ("wide.fx", "wide.sigma.fx", "wide", "fx", "px")]          # skew: fixed everywhere, left out
    z = fleet.deviation_sigmas(table, params)
    np.testing.assert_allclose(z["wide.fx"], [-1.5, -0.5, 1.0, 7.5])
    assert fleet.robust_spread(np.array([1.0, 2.0, 3.0, 10.0])) == pytest.approx(1.4826)
    before = _small_table([1.0, 2.0, 2.0, 10.0], [1.0, 1.0, 0.5, 1.0], ["d0", "d1", "d2", "gone"])
    dz, delta = fleet.drift_sigmas(table, before, params)
    assert list(dz.index) == ["d0", "d1", "d2"]
    np.testing.assert_allclose(dz["wide.fx"], [0.0, 0.0, 1.0 / np.hypot(0.5, 0.5)])
    np.testing.assert_allclose(delta["wide.fx"], [0.0, 0.0, 1.0])


def test_fleet_page_lists_failures_odd_devices_and_drift(first_run):
    table = batch.fleet_table(first_run["results"])
    by_device = table.set_index("device")
    baseline = table.copy()
    unit = baseline["device"] == "unit-005"
    sigma = by_device.loc["unit-005", "wide.sigma.fx"]
    baseline.loc[unit, "wide.fx"] = by_device.loc["unit-005", "wide.fx"] - 10 * sigma
    baseline.loc[baseline["device"] == "unit-012", "device"] = "unit-099"
    page = fleet.render_fleet(table, baseline, flag_sigmas=5.0)

    failed = page[page.index('id="table-failed"'):page.index("</table>", page.index('id="table-failed"'))]
    for device, reason in FAILING.items():
        assert f"<td class=\"l\">{device}</td>" in failed and reason in failed
    flagged = page[page.index('id="table-flagged"'):page.index("</table>", page.index('id="table-flagged"'))]
    assert '<td class="l">photos-unit</td>' in flagged     # a quarter-size sensor: unlike every other unit
    spread = page[page.index('id="table-spread"'):page.index("</table>", page.index('id="table-spread"'))]
    assert spread.count("<tr>") == 1 + len(fleet.estimated_parameters(table)) + len(fleet.quality_parameters(table))
    drift = page[page.index('id="table-drift"'):page.index("</table>", page.index('id="table-drift"'))]
    first_drift_row = drift[drift.index("<tbody>"):].split("</tr>")[0]
    assert '<td class="l">unit-005</td>' in first_drift_row and "wide.fx" in first_drift_row
    assert f"{10 / np.hypot(1, 1):+.1f}" in first_drift_row
    assert "New: unit-012." in page and "Not in this run: unit-099." in page
    assert page.count("<svg") == len(fleet._groups(fleet.estimated_parameters(table))) + 1
    assert "http://" not in page.replace("http://www.w3.org", "") and "<script" not in page


def test_fleet_page_names_the_checks_that_failed():
    table = _small_table([1.0, 2.0, 3.0], [1.0, 1.0, 1.0])
    table["checks.rig_rigid.ok"] = [True, False, True]
    table["checks.flat.ok"] = [True, False, False]
    page = fleet.render_fleet(table)
    checks = page[page.index('id="table-checks"'):page.index("</table>", page.index('id="table-checks"'))]
    assert checks.count("<tr>") == 3
    assert '<td class="l">d1</td><td class="l">rig_rigid, flat</td>' in checks
    assert '<td class="l">d2</td><td class="l">flat</td>' in checks


def test_fleet_page_of_a_fleet_where_everything_failed():
    table = pd.DataFrame({"device": ["a"], "status": ["failed: no photos"], "input": ["photos"]})
    page = fleet.render_fleet(table)
    assert "No device was calibrated." in page and "no photos" in page and "<svg" not in page


# ---------------------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("small") / "root"
    write_fleet(root, n_devices=2, views=6, seed=500)
    return root


def test_cli_batch_on_a_cluster(run_cli, client, small_fleet, tmp_path):
    out = tmp_path / "out"
    res = run_cli("batch", small_fleet, "-o", out, "--scheduler", client.scheduler.address, "--no-evaluate")
    assert res.code == 0, res.err
    assert res.err_lines[-1].startswith("2 devices: 2 ok, 0 failed; wrote ")
    assert {p.name for p in out.iterdir()} == {"unit-001", "unit-002", "fleet.csv", "fleet.parquet", "fleet.html"}
    assert not (out / "unit-001" / "eval.json").exists() and (out / "unit-001" / "calib.json").is_file()

    # nothing changed: the tables and the page are not written again; another --flag-sigmas rewrites the page
    outputs = [out / name for name in ("fleet.csv", "fleet.parquet", "fleet.html")]
    before = [p.stat().st_mtime_ns for p in outputs]
    res = run_cli("batch", small_fleet, "-o", out, "--scheduler", client.scheduler.address, "--no-evaluate")
    assert res.code == 0 and res.err_lines[-1].startswith("2 devices: 2 ok, 0 failed (2 up to date from an earlier "
                                                          "run); up to date ")
    assert [p.stat().st_mtime_ns for p in outputs] == before
    res = run_cli("batch", small_fleet, "-o", out, "--scheduler", client.scheduler.address, "--no-evaluate",
                  "--flag-sigmas", "3")
    assert res.code == 0 and "; wrote " in res.err_lines[-1]
    assert (out / "fleet.html").stat().st_mtime_ns != before[2]

    (small_fleet / "unit-003").mkdir()
    (small_fleet / "unit-003" / "corners.json").write_text("[]")
    try:
        res = run_cli("batch", small_fleet, "-o", out, "--scheduler", client.scheduler.address, "--no-evaluate",
                      "--baseline", out / "fleet.parquet")
    finally:
        (small_fleet / "unit-003" / "corners.json").unlink()
        (small_fleet / "unit-003").rmdir()
    assert res.code == 1
    assert res.err_lines[-2:-1] == [f"dualcal: unit-003: failed: {small_fleet / 'unit-003' / 'corners.json'}: "
                                    "expected a JSON object at the top level"]
    assert res.err_lines[-1].startswith("3 devices: 2 ok, 1 failed (2 up to date from an earlier run); wrote ")
    assert "Drift against the baseline" in (out / "fleet.html").read_text()


@pytest.mark.parametrize("args, message", [
    (["{root}/nowhere", "-o", "{tmp}/o"], "no such folder"),
    (["{root}", "-o", "{tmp}/o", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"], "--workers sets up"),
    (["{root}", "-o", "{tmp}/o", "--baseline", "{root}/unit-001/corners.json"], "not a readable parquet file"),
    (["{root}", "-o", "{tmp}/o", "--outlier-factor", "0.5"], "--outlier-factor 0.5: must be greater than 1"),
    (["{root}", "-o", "{tmp}/a/b"], "its parent does not exist"),
    (["{root}", "-o", "{tmp}/o", "--camera", "wide=/abs/*.jpg"], "relative to each device folder"),
])
def test_cli_batch_usage_errors_are_one_line(run_cli, small_fleet, tmp_path, args, message):
    res = run_cli("batch", *(a.format(root=small_fleet, tmp=tmp_path) for a in args))
    assert res.code == 2 and len(res.err_lines) == 1 and message in res.err_lines[0], res.err


def test_cli_batch_photos_need_a_board(run_cli, tmp_path):
    (tmp_path / "root" / "unit" / "wide").mkdir(parents=True)
    res = run_cli("batch", tmp_path / "root", "-o", tmp_path / "o")
    assert res.code == 2 and res.err_lines == [
        "dualcal: error: device(s) unit have photos and no corners.json: give --board COLSxROWS and --square MM "
        "(see docs/checks.md#inputerror)"]


def test_cli_batch_help_lists_the_options_of_calibrate(run_cli):
    res = run_cli("batch", "--help")
    assert res.code == 0
    for flag in ("--workers", "--scheduler", "--baseline", "--board", "--square", "--skew", "--rig",
                 "--keep-outliers", "--outlier-factor", "--camera", "--pair-by", "--reference"):
        assert flag in res.out
    assert "--overlays" not in res.out and "--compare-models" not in res.out


def test_cli_batch_takes_calibrates_lens_model(run_cli, client, small_fleet, tmp_path):
    """--model is one of calibrate's options, so every device gets it: calib.json and the fleet table
    name the model and carry its coefficients."""
    assert "--model" in run_cli("batch", "--help").out
    res = run_cli("batch", small_fleet, "-o", tmp_path / "out", "--scheduler", client.scheduler.address,
                  "--no-evaluate", "--model", "k1k2p1p2")
    assert res.code == 0, res.err
    table = pd.read_parquet(tmp_path / "out" / "fleet.parquet")
    assert list(table["model"]) == ["k1k2p1p2"] * 2
    assert table[["wide.p1", "tele.p2", "wide.sigma.p1"]].notna().all().all() and "wide.k3" not in table
    assert json.loads((tmp_path / "out" / "unit-001" / "calib.json").read_text())["model"] == "k1k2p1p2"


def test_cli_batch_on_a_real_stereo_rig_agrees_with_bouguet(run_cli, client, shared_data, tmp_path):
    """OpenCV's stereo sample as a device of photos (a link into shared/data): Bouguet's reference
    values within the tolerances of tests/test_real_data.py."""
    (tmp_path / "root").mkdir()
    (tmp_path / "root" / "opencv-stereo").symlink_to(shared_data / "opencv-samples-stereo")
    res = run_cli("batch", tmp_path / "root", "-o", tmp_path / "out", "--scheduler", client.scheduler.address,
                  "--board", "9x6", "--square", "30", "--camera", "left=left*.jpg", "--camera", "right=right*.jpg",
                  "--reference", "left")
    assert res.code == 0, res.err
    row = pd.read_parquet(tmp_path / "out" / "fleet.parquet").iloc[0]
    assert row["input"] == "photos" and row["reference"] == "left" and row["left.views"] == row["right.views"] == 13
    np.testing.assert_allclose([row["right.fx"], row["right.fy"]], [536.81377, 536.47649], atol=2.0)
    np.testing.assert_allclose([row["right.cx"], row["right.cy"]], [326.28657, 250.10121], atol=3.0)
    np.testing.assert_allclose([row[f"rig.right.t_mm.{a}"] for a in "xyz"], [-99.80198, 1.12443, 0.05041], atol=1.0)


@pytest.mark.slow
def test_ctrl_c_leaves_finished_devices_intact(fleet_root, tmp_path):
    """SIGINT to the whole process group, as a terminal sends it: one line, exit 130, finished devices
    whole and skipped by the next run."""
    root, _ = fleet_root
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "dualcal", "batch", str(root), "-o", str(out), "--workers", "2", "--holdout",
           "--board", "8x5", "--square", "30", "--model", "k1k2"]        # OPTIONS: calibrate_rig's default model
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while len(list(out.glob("*/batch.json"))) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err
    assert [line for line in err.splitlines() if line.strip()][-1] == "dualcal: interrupted"
    done = sorted(p.parent.name for p in out.glob("*/batch.json"))
    assert 2 <= len(done) < len(batch.find_devices(root))
    assert not (out / "fleet.parquet").exists()
    options = replace(OPTIONS, holdout=True)
    for device in batch.find_devices(root):
        result = batch.recorded_result(device, out / device.name, options, batch.input_snapshot(device))
        assert (result is not None) == (device.name in done)
        if result is not None and result.ok:
            assert load_rig(out / device.name / "calib.json").cameras


def test_the_traceback_distributed_logs_on_an_early_ctrl_c_is_dropped():
    """distributed's sync() cancels a call not yet started by reading an unset variable, and tornado
    logs the NameError with a traceback (seen once in 25 Ctrl-C runs); only that record is dropped."""
    def cancel():
        if future is not None:       # noqa: F821 - distributed's bug, reproduced
            pass
        future = None                # noqa: F841

    try:
        cancel()
    except NameError:
        record = logging.LogRecord("tornado.application", logging.ERROR, "ioloop.py", 1, "Exception in callback",
                                   None, sys.exc_info())
    other = logging.LogRecord("tornado.application", logging.ERROR, "ioloop.py", 1, "Exception in callback",
                              None, (ValueError, ValueError("x"), None))
    noise = batch._InterruptNoise()
    assert not noise.filter(record) and noise.filter(other)


def test_every_option_batch_takes_from_calibrate_reaches_the_library():
    """Each of calibrate's options that batch applies per device is a keyword of calibrate_rig (or
    calibrate_corners' compare_lens) or read_corners, or a board flag: the command sorts them by those names."""
    import inspect

    from dualcal.estimation.calibrate import calibrate_rig
    from dualcal.cli.batch import _PER_DEVICE
    from dualcal.cli.common import BOARD_OPTION_NAMES
    from dualcal.workflow import read_corners

    known = (set(inspect.signature(calibrate_rig).parameters) | set(inspect.signature(read_corners).parameters)
             | {"compare_lens"})
    assert {p.name for p in _PER_DEVICE} - known - set(BOARD_OPTION_NAMES) == set()
