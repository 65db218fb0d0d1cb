"""``dualcal batch``: calibrate a fleet of devices on a Dask cluster (a shell over :mod:`dualcal.batch`).

The options of ``calibrate`` that apply to every device are ``calibrate``'s own option objects:
those whose names are keyword arguments of :func:`~dualcal.workflow.calibrate_corners` (those of
:func:`~dualcal.estimation.calibrate.calibrate_rig`) or :func:`~dualcal.workflow.read_corners`, and the board. Dask and pandas are imported only when
the command runs.
"""

from __future__ import annotations

import inspect
from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .calibrate import calibrate_command, model_flags
from .common import BOARD_OPTION_NAMES, board_from_flags, default_jobs, echo

# calibrate's options that do not apply per device: its input and output, and what only the
# terminal shows or only a single dataset's detection uses. Every other option of calibrate is
# one of calibrate_corners' or read_corners' (the command sorts them when it runs), so a new
# calibration option reaches batch without a change here. The library is imported only then,
# to keep the CLI's start-up light. Known intrinsics (--intrinsics) are a device's own, not the fleet's.
_NOT_PER_DEVICE = {"input_path", "output", "compare_models", "jobs", "hints_path", "overlays_dir", "intrinsics"}
_PER_DEVICE = [p for p in calibrate_command.params if p.name not in _NOT_PER_DEVICE]


@cli.command("batch")
@click.argument("root", type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if its parent exists): OUTDIR/<device>/calib.json, fleet.csv, "
                   "fleet.parquet, fleet.html.")
@click.option("--workers", type=click.IntRange(min=1), default=None, metavar="N",
              help="Worker processes of the local Dask cluster (default: all cores).")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 (ROOT and OUTDIR at the same "
                   "paths on every worker).")
@click.option("--baseline", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="An earlier fleet.parquet: fleet.html shows each device's drift against it.")
@click.option("--flag-sigmas", type=float, default=5.0, show_default=True, metavar="K",
              help="fleet.html lists devices more than K of their own sigmas from the fleet (or their baseline).")
@click.option("--evaluate/--no-evaluate", "run_evaluate", default=True, show_default=True,
              help="Write eval.json per device (the stereo-intersection check, as 'dualcal evaluate').")
@click.option("--holdout", is_flag=True, help="Evaluate with hold-out (as 'dualcal evaluate --holdout').")
def batch_command(root, out_dir, workers, scheduler, baseline, flag_sigmas, run_evaluate, holdout, **per_device):
    """Calibrate every device of ROOT, one Dask task per device, and tabulate the fleet.

    \b
    ROOT/<device>/corners.json            a device as corners (from 'dualcal detect'), or
    ROOT/<device>/<camera>/*.jpg          a device as photos (a dataset, as for 'calibrate').
    \b
    OUTDIR/<device>/calib.json, eval.json  each device's results, written atomically
    OUTDIR/fleet.csv, fleet.parquet        one row per device: status, parameters and sigmas
    OUTDIR/fleet.html                      the spread over the fleet, odd devices, drift
    \b
    The options of 'calibrate' below apply to every device (a --camera glob is relative to each
    device folder). A re-run skips the devices whose outputs are newer than their inputs and
    were made with the same options. Exit code 0 when every device was calibrated, 1 when
    some failed (their rows say why), 2 on bad usage.
    """
    from ..extras import require

    require("fleet")
    require("report")
    from ..batch import (PAGE_NAME, TABLE_NAMES, BatchOptions, calibrate_fleet, find_devices, fleet_inputs_digest,
                         fleet_outputs_current, fleet_table, read_fleet_table, write_fleet_tables)
    from ..estimation.calibrate import calibrate_rig
    from ..files.io import make_output_folder, write_text_atomic
    from ..progress import warn
    from ..workflow import DETECTION_OPTIONS, read_corners

    calibrate_kwargs = (set(inspect.signature(calibrate_rig).parameters) - {"corners"}) | {"compare_lens"}
    dataset_kwargs = set(inspect.signature(read_corners).parameters) - {"source", "board", "progress",
                                                                        *DETECTION_OPTIONS}

    if scheduler is not None and workers is not None:
        raise InputError("--workers sets up a local cluster; with --scheduler the cluster's own workers run")
    if per_device.get("outlier_factor") is not None and not per_device["outlier_factor"] > 1:
        raise InputError(f"--outlier-factor {per_device['outlier_factor']}: must be greater than 1")
    if not flag_sigmas > 0:
        raise InputError(f"--flag-sigmas {flag_sigmas}: must be positive")
    per_device["model"] = model_flags(per_device.get("model", ()))
    earlier = read_fleet_table(baseline) if baseline is not None else None
    devices = find_devices(root, exclude=[out_dir])
    out_dir = make_output_folder(out_dir)
    options = BatchOptions(
        board=board_from_flags(*(per_device.pop(name) for name in BOARD_OPTION_NAMES)),
        calibrate={k: v for k, v in per_device.items() if k in calibrate_kwargs},
        dataset={k: v for k, v in per_device.items() if k in dataset_kwargs},
        evaluate=run_evaluate, holdout=holdout)
    results = []
    for result in calibrate_fleet(devices, out_dir, options, workers=workers or default_jobs(),
                                  scheduler=scheduler):
        results.append(result)
        if not result.skipped:
            for line in result.warnings:
                warn(f"{result.device}: {line}")
    written = [out_dir / name for name in TABLE_NAMES]
    digest = fleet_inputs_digest(results, baseline, flag_sigmas)
    current = fleet_outputs_current(out_dir, digest)
    if not current:      # else the tables and the page are those of these very rows: nothing to write
        from ..pages.report.fleet import render_fleet

        table = fleet_table(results)
        written = write_fleet_tables(out_dir, table)
        write_text_atomic(out_dir / PAGE_NAME, render_fleet(table, earlier, flag_sigmas, inputs_digest=digest))
    failed = sorted((r for r in results if not r.ok), key=lambda r: r.device)
    for r in failed:
        echo(f"dualcal: {r.device}: {r.row['status']}", err=True)
    skipped = sum(r.skipped for r in results)
    echo(f"{len(results)} device{'s' if len(results) != 1 else ''}: {len(results) - len(failed)} ok, {len(failed)} failed"
         f"{f' ({skipped} up to date from an earlier run)' if skipped else ''}; "
         f"{'up to date' if current else 'wrote'} {', '.join(str(p) for p in written)}, {out_dir / PAGE_NAME}",
         err=True)
    if failed:
        raise SystemExit(1)


batch_command.params.extend(_PER_DEVICE)
