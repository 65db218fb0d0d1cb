"""Fleet benchmark: devices per second of ``dualcal batch`` on 1 and 2 Dask workers, same run.

A synthetic fleet (:func:`dualcal.synthetic.synth_fleet.write_fleet`: note8 units given as corners.json,
``--views`` views each, seed 1000 and up, which the tests do not use) is calibrated

* by the peer: a plain loop in this process over the devices, each ``load_corners``,
  ``calibrate_rig``, ``save_rig``, ``evaluate`` and writing eval.json (the work of one task);
* by :func:`dualcal.batch.calibrate_fleet` on a ``LocalCluster`` of 1 and of 2 worker processes,
  (a) warm: the cluster already started and dualcal imported in its workers, (b) cold: starting
  and closing the cluster (and the workers' imports) included;
  then the table and the page (``fleet_table``, ``write_fleet_tables``, ``render_fleet``);
* again, with every device up to date (the second run: no cluster, rows from batch.json), whose
  time is compared with the cold first run;
* by the command itself, ``dualcal batch ROOT -o OUT --workers 2``, first and second run, in a
  new process each (Python start-up and imports included).

Wall times (``time.perf_counter``) on a shared machine are noisy: read the ratios. Dask workers run
one thread each (the nanny sets ``OMP_NUM_THREADS=1`` and the like); for a like-for-like peer run
the benchmark as ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_batch.py``.

Run from the repository root::

    .venv/bin/python benchmarks/bench_batch.py                  # 24 devices, 8 views
    .venv/bin/python benchmarks/bench_batch.py --devices 48 --views 13
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dask.distributed import Client, LocalCluster

from dualcal import batch
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.evaluation import evaluate
from dualcal.files.io import load_corners, save_rig, write_json_atomic
from dualcal.pages.report.fleet import render_fleet
from dualcal.synthetic.synth_fleet import write_fleet

OPTIONS = batch.BatchOptions()


def peer_loop(devices, out: Path) -> None:
    for device in devices:
        rig = calibrate_rig(load_corners(device.folder / "corners.json"))
        folder = out / device.name
        folder.mkdir()
        save_rig(folder / "calib.json", rig)
        write_json_atomic(folder / "eval.json", evaluate(rig, progress=False))


def fleet_outputs(devices, out: Path, **cluster) -> list:
    """One batch run as the command does it: the devices, then the tables and the page."""
    results = list(batch.calibrate_fleet(devices, out, OPTIONS, progress=False, **cluster))
    table = batch.fleet_table(results)
    batch.write_fleet_tables(out, table)
    (out / "fleet.html").write_text(render_fleet(table), encoding="utf-8")
    return results


def timed(f, *args, **kwargs) -> tuple[float, object]:
    t0 = time.perf_counter()
    value = f(*args, **kwargs)
    return time.perf_counter() - t0, value


def fresh(base: Path, name: str) -> Path:
    path = base / name
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir()
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=24, help="devices in the fleet (default 24)")
    parser.add_argument("--views", type=int, default=8, help="views per device (default 8)")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        base = Path(tmp)
        root = base / "root"
        write_fleet(root, n_devices=args.devices, views=args.views, seed=1000)
        devices = batch.find_devices(root)
        n = len(devices)
        print(f"fleet: {n} note8 devices x {args.views} views x 2 cameras x 40 corners; "
              f"load average {os.getloadavg()[0]:.2f}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '-')}")

        rows = []
        t_peer, _ = timed(peer_loop, devices, fresh(base, "peer"))
        rows.append(("peer: calibrate_rig loop, 1 process", t_peer))
        cold = {}
        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                              silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
                client.run(importlib.import_module, "dualcal.batch")     # workers up, dualcal imported
                t_warm, results = timed(fleet_outputs, devices, fresh(base, f"warm{workers}"), client=client)
                assert sum(r.ok for r in results) == n, [r.row["status"] for r in results if not r.ok]
            rows.append((f"batch, {workers} worker(s), cluster running", t_warm))
            out = fresh(base, f"cold{workers}")
            cold[workers], _ = timed(fleet_outputs, devices, out, workers=workers)
            rows.append((f"batch, {workers} worker(s), cluster start and close included", cold[workers]))
        t_again, again = timed(fleet_outputs, devices, base / "cold2")
        assert all(r.skipped for r in again)
        rows.append(("second run, all up to date (no cluster)", t_again))

        print(f"\n{'run':<58} {'seconds':>8} {'devices/s':>10} {'vs peer':>8}")
        for label, seconds in rows:
            print(f"{label:<58} {seconds:8.2f} {n / seconds:10.1f} {t_peer / seconds:7.2f}x")
        print(f"\nsecond run / first run (2 workers, cold): {t_again / cold[2]:.1%} (target < 20 %)")

        cli_out = base / "cli"
        cmd = [sys.executable, "-m", "dualcal", "batch", str(root), "-o", str(cli_out), "--workers", "2"]
        t_cli1, first = timed(subprocess.run, cmd, capture_output=True, text=True)
        t_cli2, second = timed(subprocess.run, cmd, capture_output=True, text=True)
        assert first.returncode == second.returncode == 0, first.stderr + second.stderr
        print(f"command 'dualcal batch --workers 2': first run {t_cli1:.2f} s, second run {t_cli2:.2f} s "
              f"({t_cli2 / t_cli1:.1%}; both include Python start-up and imports)")


if __name__ == "__main__":
    main()
