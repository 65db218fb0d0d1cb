"""A fleet of devices: one calibration per device as a task of a Dask cluster, resumable, one table.

``ROOT`` holds one folder per device: a folder with a ``corners.json`` (calibrated as it is), or a
dataset of photos (``ROOT/<device>/<camera>/*.jpg``, detected first). Every device is calibrated
by :func:`calibrate_device`, in a task of a ``dask.distributed`` cluster, with the same
:class:`BatchOptions`, and writes into ``OUTDIR/<device>/``:

* ``calib.json`` (and ``eval.json`` unless evaluation is off), atomically;
* ``batch.json`` last: the options and the input files (path, size, modification time) the result
  came from, the device's row of the fleet table and the warnings its calibration gave.

A re-run skips a device whose ``batch.json`` records the same options and the same input files as
now (so its outputs are newer than its inputs) and reuses its row; a device whose inputs or
options changed is done again. A device that fails with a reason dualcal gives (unreadable input,
too few views, ...) is a row ``failed: <reason>``, recorded like a success, so that a re-run does
not repeat it while nothing changed. A worker that dies is replaced and its device tried again by
Dask (up to ``distributed.scheduler.allowed-failures`` times, then the device fails saying so);
such failures, and unexpected errors, are not recorded, so a re-run tries again. An interrupted
run leaves every finished device intact: each file is written atomically, and a task removes the
device's old ``batch.json`` first and writes the new one last.

:func:`fleet_row` turns a calib.json (and eval.json) into one flat row; :func:`fleet_table`
collects the rows, :func:`write_fleet_tables` writes ``fleet.csv`` and ``fleet.parquet``. The
columns are in the README, section "Fleets".
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import re
import logging
import signal
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__
from .geometry.board import Board
from .estimation.calibrate import calibrate_rig
from .errors import DualcalError, InputError, OutputError
from .files.io import (make_output_folder, read_json, rig_to_dict, write_bytes_atomic, write_json_atomic,
                       write_text_atomic)
from .progress import collect_warnings, progress_bar
from .workflow import DETECTION_OPTIONS, calibrate_corners, evaluate_calibration, read_corners

CALIB_NAME, EVAL_NAME, RECORD_NAME = "calib.json", "eval.json", "batch.json"
TABLE_NAMES = ("fleet.csv", "fleet.parquet")
PAGE_NAME = "fleet.html"
#: The names in OUTDIR that are the fleet's own: no device may be named so.
FLEET_FILE_NAMES = (*TABLE_NAMES, PAGE_NAME)
#: Leading columns of the fleet table; the others follow in calib.json's order.
LEADING_COLUMNS = ("device", "status", "input", "seconds", "warnings")


# ---------------------------------------------------------------------------- devices and options


@dataclass(frozen=True)
class Device:
    """One device of the fleet: ``folder`` (absolute) holds a ``corners.json`` or photos."""

    name: str
    folder: Path

    @property
    def kind(self) -> str:
        """``"corners"`` when the folder has a corners.json (it is used as it is), else ``"photos"``."""
        return "corners" if (self.folder / "corners.json").is_file() else "photos"

    def input_files(self) -> list[Path]:
        """The files the device's result depends on: its corners.json, or every file of its folder."""
        if self.kind == "corners":
            return [self.folder / "corners.json"]
        return sorted(p for p in self.folder.rglob("*")
                      if p.is_file() and not any(part.startswith(".") for part in p.relative_to(self.folder).parts))


def find_devices(root, exclude: Iterable = ()) -> list[Device]:
    """The device folders of ``root`` (its sub-folders, hidden ones and ``exclude`` left out), by name.

    Raises
    ------
    InputError
        ``root`` is not a folder, or holds no device folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: no such folder (give a folder with one sub-folder per device)")
    left_out = {Path(p).resolve() for p in exclude}
    devices = [Device(p.name, p.resolve()) for p in sorted(root.iterdir())
               if p.is_dir() and not p.name.startswith(".") and p.resolve() not in left_out]
    clashing = [d.name for d in devices if d.name.lower() in FLEET_FILE_NAMES]
    if clashing:
        raise InputError(f"{root / clashing[0]}: a device may not be named like the fleet's own files "
                         f"({', '.join(FLEET_FILE_NAMES)}): rename the folder or leave it out")
    if not devices:
        raise InputError(f"{root}: holds no device folder (one sub-folder per device, each with a "
                         "corners.json or the photos of a dataset)")
    return devices


def input_snapshot(device: Device) -> dict[str, list[int]]:
    """``{path relative to the device folder: [size, modification time in ns]}`` of its input files."""
    out = {}
    for path in device.input_files():
        st = path.stat()
        out[path.relative_to(device.folder).as_posix()] = [st.st_size, st.st_mtime_ns]
    return out


#: Keyword arguments of the workflow that are the device's own (its input) or only show progress.
_NOT_RECORDED = {"source", "board", "corners", "progress", *DETECTION_OPTIONS}


def _with_defaults(function, kwargs: dict) -> dict:
    """``kwargs`` with the defaults of ``function``'s other keyword arguments."""
    defaults = {name: p.default for name, p in inspect.signature(function).parameters.items()
                if p.default is not inspect.Parameter.empty}
    return {**defaults, **kwargs}


def _plain(value):
    """A JSON-like value with tuples turned into lists (as it reads back from batch.json)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


@dataclass(frozen=True)
class BatchOptions:
    """What applies to every device of a batch.

    ``calibrate`` holds keyword arguments of :func:`dualcal.workflow.calibrate_corners` (those of
    :func:`dualcal.estimation.calibrate.calibrate_rig`: ``skew``, ``rig_mode``, ``reference``, ``drop_outliers``,
    ``outlier_factor``, ...; and ``compare_lens``), ``dataset`` those of :func:`dualcal.workflow.read_corners`
    (``cameras`` with globs relative to each device folder, ``pair_by``, ``square_sigma_mm``, ...).
    ``board`` is needed for photos and, where given, must agree with every corners.json. ``evaluate``
    writes eval.json (:func:`dualcal.workflow.evaluate_calibration`, with ``holdout``). Every device
    goes through the workflow a single ``calibrate`` and ``evaluate`` take, so it gets the same files.
    """

    board: Board | None = None
    calibrate: dict = field(default_factory=dict)
    dataset: dict = field(default_factory=dict)
    evaluate: bool = True
    holdout: bool = False

    def record(self, kind: str) -> dict:
        """The options a device of ``kind`` depends on, as they take effect (defaults filled in), as
        batch.json records them."""
        doc = {"dualcal_version": __version__, "board": self.board.to_dict() if self.board else None,
               "calibrate": {"compare_lens": True, **_with_defaults(calibrate_rig, self.calibrate)},
               "evaluate": self.evaluate, "holdout": self.holdout}
        dataset = _with_defaults(read_corners, self.dataset)
        doc["dataset"] = dataset if kind == "photos" else {"square_sigma_mm": dataset["square_sigma_mm"]}
        return _plain({key: {k: v for k, v in value.items() if k not in _NOT_RECORDED} if isinstance(value, dict)
                       and key in ("calibrate", "dataset") else value for key, value in doc.items()})

    def check(self, devices: list[Device]) -> None:
        """Raise :class:`InputError` for options that cannot apply to these devices."""
        globs = [spec[1] if isinstance(spec, (tuple, list)) else str(spec).partition("=")[2]
                 for spec in self.dataset.get("cameras", ())]
        absolute = [glob for glob in globs if Path(glob).is_absolute()]
        if absolute:
            raise InputError(f"--camera glob {absolute[0]}: in a batch a glob is relative to each device folder "
                             "(e.g. --camera left='left*.jpg'), so that every device uses its own photos")
        photos = [d.name for d in devices if d.kind == "photos"]
        if photos and self.board is None:
            raise InputError(f"device(s) {', '.join(photos[:3])}{' ...' if len(photos) > 3 else ''} have photos "
                             "and no corners.json: give --board COLSxROWS and --square MM")


# ---------------------------------------------------------------------------- the table row


#: Labels of the entries of fixed-length lists in calib.json and eval.json.
_LIST_LABELS = {"t_mm": ("x", "y", "z"), "rmse_mm": ("x", "y", "z"), "opk_arcmin": ("omega", "phi", "kappa"),
                "image_size": ("w", "h")}
#: Parts of calib.json that are per view or per corner, not per device (and rotation matrices,
#: whose angles are in ``opk_arcmin``).
_NOT_IN_ROW = {"views", "corners", "camera_poses", "dropped_views", "R", "per_pair", "held_out_per_instant",
               "held_out_per_camera", "covariance", "dropped_corners"}
#: Objects keyed by view under these names (a check's statistic per instant) are left out too.
_PER_VIEW_OBJECTS = {"instants"}


def _flatten(value, name: str, out: dict) -> None:
    """Scalars of a JSON value into ``out`` under dotted names (``tele.sigma.fx``)."""
    key = name.rpartition(".")[2]
    if isinstance(value, dict):
        for k, v in value.items():
            if k not in _NOT_IN_ROW and not (k in _PER_VIEW_OBJECTS and isinstance(v, dict)):
                _flatten(v, f"{name}.{k}", out)
    elif isinstance(value, list):
        if value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            labels = _LIST_LABELS.get(key)
            if labels is None or len(labels) != len(value):
                labels = range(len(value))
            for label, v in zip(labels, value):
                out[f"{name}.{label}"] = v
    elif value is None or isinstance(value, (bool, int, float, str)):
        out[name] = value


def fleet_row(calib: dict, evaluation: dict | None = None) -> dict:
    """One device's row of the fleet table from its calib.json (and eval.json) documents.

    Every scalar of calib.json outside the per-view parts, under its keys joined by dots: each
    camera's entries under its name (``wide.fx``, ``wide.sigma.fx``, ``wide.image_size.w``),
    each rig relation under ``rig.<camera>`` (``rig.tele.baseline_mm``,
    ``rig.tele.sigma.opk_arcmin.omega``), the others under their own (``rms_px``,
    ``adjustment.s0_px``, ``checks.rig_rigid.ok``); lists of three are split into ``x y z`` or
    ``omega phi kappa``. Added: ``<camera>.views`` (views in the adjustment), ``dropped_views``
    (how many), ``checks.ok`` (every check passed, where calib.json has checks) and the eval.json
    cases as ``eval.<case>.rmse_mm.x`` ...
    """
    row: dict = {}
    for key, value in calib.items():
        if key == "cameras":
            for name, entry in value.items():
                _flatten(entry, name, row)
                row[f"{name}.views"] = len(calib.get("camera_poses", {}).get(name, {}))
        elif key == "rig":
            for name, entry in value.items():
                _flatten(entry, f"rig.{name}", row)
        elif key not in _NOT_IN_ROW:
            _flatten(value, key, row)
    row["dropped_views"] = len(calib.get("dropped_views", []))
    checks = calib.get("checks")
    if isinstance(checks, dict) and checks:
        row["checks.ok"] = all(bool(c.get("ok", True)) for c in checks.values() if isinstance(c, dict))
    if evaluation is not None:
        _flatten(evaluation.get("cases", {}), "eval", row)
        row["eval.holdout"] = bool(evaluation.get("holdout", False))
    return row


# ---------------------------------------------------------------------------- one device


@dataclass
class DeviceResult:
    """What became of one device: its table ``row`` (with ``status``), the warnings its calibration
    gave, and whether it was ``skipped`` (up to date from an earlier run)."""

    device: str
    row: dict
    warnings: list[str] = field(default_factory=list)
    skipped: bool = False

    @property
    def ok(self) -> bool:
        return self.row.get("status") == "ok"


def _failed(device: Device, reason: str, seconds: float | None = None) -> dict:
    return {"device": device.name, "status": f"failed: {reason}", "input": device.kind, "seconds": seconds}


def _device_corners(device: Device, options: BatchOptions):
    source = device.folder / "corners.json" if device.kind == "corners" else device.folder
    return read_corners(source, options.board, jobs=1, progress=False, **options.dataset)


def calibrate_device(device: Device, out_folder, options: BatchOptions, snapshot: dict) -> DeviceResult:
    """Calibrate one device and write its outputs to ``out_folder`` (the task of one device).

    ``snapshot`` is :func:`input_snapshot` of the device, taken before the task started; it is
    recorded in batch.json. The library's warnings are collected (:func:`dualcal.progress.collect_warnings`)
    and returned (exact with one thread per worker process, as :func:`dask_client` starts them; on a
    cluster whose workers run several threads, a warning may land with another device). A
    :class:`~dualcal.errors.DualcalError` becomes a recorded ``failed: <reason>`` row; any other
    exception is a row too, not recorded.
    """
    out_folder = Path(out_folder)       # made once there is something to write: no empty folder if interrupted
    # An earlier record goes first: until the new one is written, the outputs are not up to date.
    (out_folder / RECORD_NAME).unlink(missing_ok=True)
    start = time.perf_counter()
    record = True
    with collect_warnings() as warnings:
        try:
            rig = calibrate_corners(_device_corners(device, options), **options.calibrate)
            calib = rig_to_dict(rig)
            write_json_atomic(make_output_folder(out_folder) / CALIB_NAME, calib)
            evaluation = None
            if options.evaluate:
                evaluation = evaluate_calibration(rig, holdout=options.holdout, progress=False)
                write_json_atomic(out_folder / EVAL_NAME, evaluation)
            else:       # an eval.json of an earlier calibration would not be of this one
                (out_folder / EVAL_NAME).unlink(missing_ok=True)
            row = {"device": device.name, "status": "ok", "input": device.kind,
                   "seconds": time.perf_counter() - start, **fleet_row(calib, evaluation)}
        except OutputError as exc:   # a full disk is not the device's fault: tried again next run
            row = _failed(device, str(exc), time.perf_counter() - start)
            record = False
        except DualcalError as exc:
            row = _failed(device, str(exc), time.perf_counter() - start)
        except Exception as exc:  # a bug, not the device's input: one row, and tried again next run
            row = _failed(device, f"internal error: {type(exc).__name__}: {exc}", time.perf_counter() - start)
            record = False
    row["warnings"] = len(warnings)
    if record:
        write_json_atomic(make_output_folder(out_folder) / RECORD_NAME, {
            "device": device.name, "options": options.record(device.kind), "inputs": snapshot,
            "row": row, "warnings": warnings})
    return DeviceResult(device.name, row, warnings)


def recorded_result(device: Device, out_folder, options: BatchOptions, snapshot: dict) -> DeviceResult | None:
    """The device's earlier result when it is up to date, else None.

    Up to date: ``out_folder/batch.json`` records the same options and input files as now, and,
    for a success, calib.json (and eval.json where evaluated) are there.
    """
    out_folder = Path(out_folder)
    try:
        doc = read_json(out_folder / RECORD_NAME)
    except InputError:
        return None
    if doc.get("options") != options.record(device.kind) or doc.get("inputs") != snapshot:
        return None
    row = doc.get("row")
    if not isinstance(row, dict) or row.get("device") != device.name:
        return None
    if row.get("status") == "ok":
        needed = [CALIB_NAME] + ([EVAL_NAME] if options.evaluate else [])
        if not all((out_folder / name).is_file() for name in needed):
            return None
    return DeviceResult(device.name, row, list(doc.get("warnings", [])), skipped=True)


# ---------------------------------------------------------------------------- the fleet


class _InterruptNoise(logging.Filter):
    """Drops the traceback distributed can log on Ctrl-C: when the interrupt comes before a call
    of the client has started in its event loop, the callback that cancels it reads a variable
    not yet set (a ``NameError`` in ``distributed.utils.sync``, logged by tornado); the interrupt
    itself is handled as any other."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (isinstance(exc, NameError) and "'future'" in str(exc))


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``dask.distributed.Client``: of the cluster at ``scheduler``, or of a new ``LocalCluster``
    of ``workers`` processes with one thread each (closed on exit)."""
    log, noise = logging.getLogger("tornado.application"), _InterruptNoise()
    log.addFilter(noise)
    try:
        with _dask_client(workers, scheduler) as client:
            yield client
    finally:
        log.removeFilter(noise)


@contextlib.contextmanager
def _dask_client(workers: int | None, scheduler: str | None):
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"--scheduler {scheduler}: no Dask scheduler answers there ({exc})") from None
        with client:
            yield client
        return
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.register_plugin(_sigint_ignoring_plugin())
        yield client


def _sigint_ignoring_plugin():
    """A worker plugin that makes each worker of the local cluster (restarted ones too) ignore SIGINT.

    Ctrl-C in a terminal reaches every process of its group: the client alone handles it (it
    cancels the devices not yet done and closes the cluster), instead of every worker dying with
    a traceback. Defined here so that ``dask.distributed`` is imported only when a cluster is.
    """
    from dask.distributed import WorkerPlugin

    class IgnoreSigint(WorkerPlugin):
        name = "dualcal-ignore-sigint"

        def setup(self, worker):
            signal.signal(signal.SIGINT, signal.SIG_IGN)     # runs in the worker's main thread

    return IgnoreSigint()


def _result_of(future, device: Device) -> DeviceResult:
    """The task's result, or a failed row for a task Dask gave up on (its workers kept dying)."""
    from dask.distributed import KilledWorker

    if future.status == "finished":
        return future.result()
    exc = future.exception()
    if isinstance(exc, KilledWorker):
        reason = ("the worker process died every time it calibrated this device (out of memory? a crash "
                  "in a library?); tried on several workers")
    elif isinstance(exc, DualcalError):
        reason = str(exc)
    else:
        reason = f"internal error: {type(exc).__name__}: {exc}"
    return DeviceResult(device.name, {**_failed(device, reason), "warnings": 0})


def calibrate_fleet(devices: list[Device], out_dir, options: BatchOptions, *, client=None,
                    workers: int | None = None, scheduler: str | None = None,
                    progress: bool = True) -> Iterator[DeviceResult]:
    """Calibrate every device, each in a Dask task; yield each result as it comes.

    Devices that are up to date (:func:`recorded_result`) come first, without a cluster; the
    others are submitted to ``client``, else to a cluster of :func:`dask_client` (started only
    when there is work). Device folders and ``out_dir`` must be seen at the same paths by every
    worker. Closing the iterator early (or Ctrl-C) cancels the devices not yet done.

    Parameters
    ----------
    devices : from :func:`find_devices`.
    out_dir : existing folder; device ``d`` writes into ``out_dir/d``.
    options : what applies to every device.
    client : a ``dask.distributed.Client`` to use (and leave open).
    workers, scheduler : for :func:`dask_client` when no ``client`` is given (a local cluster gets
        at most one worker per device to do).
    progress : a progress bar over the devices on stderr.

    Raises
    ------
    InputError
        Options that cannot apply (:meth:`BatchOptions.check`), an unreachable scheduler.
    """
    from .extras import require

    require("fleet")
    options.check(devices)
    out_dir = Path(out_dir).resolve()
    todo = []
    for device in devices:
        snapshot = input_snapshot(device)
        done = recorded_result(device, out_dir / device.name, options, snapshot)
        if done is not None:
            yield done
        else:
            todo.append((device, snapshot))
    if not todo:
        return
    from dask.distributed import as_completed

    if client is not None:
        own = contextlib.nullcontext(client)
    else:       # no more local workers than devices to do
        own = dask_client(min(workers, len(todo)) if workers else None, scheduler)
    with own as client, progress_bar("calibrating devices", len(todo), enabled=progress) as advance:
        futures = {client.submit(calibrate_device, device, out_dir / device.name, options, snapshot,
                                 pure=False): device
                   for device, snapshot in todo}
        try:
            for future in as_completed(futures):
                result = _result_of(future, futures.pop(future))
                # released at once: a result held by a worker that dies later would be computed again
                future.release()
                yield result
                advance()
        finally:
            client.cancel(list(futures))


def fleet_table(results: Iterable[DeviceResult]):
    """The fleet table (a ``pandas.DataFrame``), one row per device in name order.

    Columns: :data:`LEADING_COLUMNS`, then every other column in the order of the first row that
    has it (calib.json's order); a device lacks what it did not produce (missing values).
    """
    import pandas as pd     # here, not at the top: the workers, which import this module, never need it

    rows = sorted((r.row for r in results), key=lambda row: row["device"])
    columns = list(LEADING_COLUMNS)
    seen = set(columns)
    for row in rows:
        for key in row:
            if key not in seen:
                seen.add(key)
                columns.append(key)
    return pd.DataFrame.from_records(rows, columns=columns)


#: What a spreadsheet takes for the start of a formula (OWASP, "CSV Injection").
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def csv_safe_cell(value):
    """A text cell made inert as OWASP says: one that begins with ``= + - @``, a tab or a CR is prefixed
    with ``'`` (a spreadsheet shows it as text, never runs it). Numbers, and text that is a number
    (``-0.145``), stay as they are."""
    if not isinstance(value, str) or not value.startswith(FORMULA_STARTS):
        return value
    try:
        float(value)
        return value
    except ValueError:
        return "'" + value


def csv_safe(table):
    """The fleet table with every text cell made inert (:func:`csv_safe_cell`), for ``fleet.csv``."""
    text = table.select_dtypes(include=["object", "string"]).columns
    return table.assign(**{c: table[c].map(csv_safe_cell) for c in text})


def write_fleet_tables(out_dir, table) -> list[Path]:
    """Write ``out_dir/fleet.csv`` and ``out_dir/fleet.parquet`` atomically; returns their paths."""
    csv_path, parquet_path = (Path(out_dir) / name for name in TABLE_NAMES)
    write_text_atomic(csv_path, csv_safe(table).to_csv(index=False))
    write_bytes_atomic(parquet_path, table.to_parquet(index=False))
    return [csv_path, parquet_path]


def fleet_inputs_digest(results: Iterable[DeviceResult], baseline=None, flag_sigmas: float = 5.0) -> str:
    """A sha256 of everything the fleet tables and page are made from: every device's row, the
    bytes of the ``baseline`` fleet.parquet (a path, or None), ``flag_sigmas`` and dualcal's version."""
    rows = sorted((r.row for r in results), key=lambda row: row["device"])
    h = hashlib.sha256(json.dumps(rows, sort_keys=True, default=repr).encode())
    h.update(b"" if baseline is None else Path(baseline).read_bytes())
    h.update(f"{flag_sigmas!r} {__version__}".encode())
    return h.hexdigest()


_INPUTS_META = re.compile(rb'<meta name="dualcal-fleet-inputs" content="([0-9a-f]{64})">')


def fleet_outputs_current(out_dir, digest: str) -> bool:
    """True when ``out_dir`` holds fleet.csv, fleet.parquet and a fleet.html made from ``digest``
    (:func:`fleet_inputs_digest`, recorded in the page's head), so that nothing need be written again."""
    out_dir = Path(out_dir)
    page = out_dir / PAGE_NAME
    if not (page.is_file() and all((out_dir / name).is_file() for name in TABLE_NAMES)):
        return False
    with page.open("rb") as f:
        found = _INPUTS_META.search(f.read(4096))
    return found is not None and found.group(1).decode() == digest


def read_fleet_table(path):
    """An earlier ``fleet.parquet`` (e.g. ``--baseline``), checked to have ``device`` and ``status``."""
    import pandas as pd
    import pyarrow

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file (give the fleet.parquet of an earlier 'dualcal batch')")
    try:
        table = pd.read_parquet(path)
    except (OSError, pyarrow.ArrowException, ValueError) as exc:
        raise InputError(f"{path}: not a readable parquet file ({exc})") from None
    missing = [c for c in ("device", "status") if c not in table.columns]
    if missing:
        raise InputError(f"{path}: has no column {missing[0]!r}: not a fleet.parquet of 'dualcal batch'")
    return table
