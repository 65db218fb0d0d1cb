"""The real photo sets of ``../shared/data`` as one table: boards found, each camera's parameters, the verdict.

What the guard (tests/test_real_guard.py) pins and what ``benchmarks/bench_real_sets.py`` prints. Each set is
detected (or imported) and calibrated as ``dualcal calibrate`` does with its defaults (:func:`dualcal.workflow.calibrate_corners`),
and summarised by :func:`summarise`: per camera the photos, the boards found, the corners kept, every intrinsic with its
sigma; per non-reference camera the baseline and angles with their sigmas; the checks that fail.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dualcal.geometry.board import Board

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

#: The parameters of each camera the table holds (those every lens model has).
CAMERA_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2")


@dataclass(frozen=True)
class RealSet:
    """One folder of ``../shared/data``: how it is opened, its board and how ``dualcal calibrate`` is run on it.

    ``cameras`` are ``--camera NAME=GLOB`` specs (relative to the folder; empty: the folder is one camera),
    ``options`` the options of :func:`dualcal.workflow.calibrate_corners`. A set of a peer's corners, not photos, has
    no board here (its files name it) and ``imported`` the format :func:`dualcal.files.imports.import_files` reads it
    in, with ``import_options``."""

    name: str
    board: Board | None
    cameras: tuple[str, ...] = ()
    options: dict = field(default_factory=dict)
    imported: str | None = None
    import_options: dict = field(default_factory=dict)

    @property
    def folder(self) -> Path:
        return DATA / self.name

    def photo_paths(self) -> dict[str, list[Path]]:
        """``{camera: [photo, ...]}`` of a set of photos (empty for a set of corners)."""
        if self.board is None:
            return {}
        if not self.cameras:
            return {self.name: sorted(p for p in self.folder.iterdir() if p.suffix.lower() in (".jpg", ".tif"))}
        return {spec.split("=")[0]: sorted(self.folder.glob(spec.split("=")[1])) for spec in self.cameras}


REAL_SETS = (
    RealSet("opencv-samples-stereo", Board(9, 6, 30.0), ("left=left*.jpg", "right=right*.jpg")),
    RealSet("huawei-y5-2017", Board(7, 9, 30.0)),
    RealSet("bouguet-calib-example", Board(12, 13, 30.0), ("cam=Image*.tif",)),
    # caliscope's intrinsic session: each webcam filmed the board alone, so every camera is calibrated alone
    RealSet("caliscope-prerecorded", None, options={"rig_mode": "none"}, imported="caliscope",
            import_options={"image_size": {"*": (1280, 720)}}),
)


def detect(real: RealSet):
    """The set's corners, detected as ``dualcal detect`` does (two threads, no progress bar), or imported as
    ``dualcal import`` does."""
    from dualcal.files.dataset import open_dataset
    from dualcal.files.detect import detect_dataset
    from dualcal.files.imports import import_files

    if real.imported:
        return import_files(real.imported, [real.folder], **real.import_options).corners

    specs = [f"{spec.split('=')[0]}={real.folder}/{spec.split('=')[1]}" for spec in real.cameras]
    dataset = open_dataset(None, specs) if specs else open_dataset(real.folder)
    return detect_dataset(dataset, real.board, jobs=2, progress=False)


def calibrate(real: RealSet, corners):
    """The set calibrated as ``dualcal calibrate`` does with its defaults (and the set's own options)."""
    from dualcal.workflow import calibrate_corners

    return calibrate_corners(corners, **real.options)


def _number(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def summarise(corners, rig) -> dict:
    """The set's row of the table: ``{"cameras": {name: {...}}, "rig": {name: {...}}, "failed_checks": [...]}``.

    Per camera: ``photos``, ``boards`` (found), ``corners`` (kept by the calibration), ``model``, and each of
    :data:`CAMERA_KEYS` as ``[value, sigma]``; per non-reference camera ``baseline_mm`` and ``opk_arcmin`` with their
    sigmas (none between cameras that each filmed the board alone); ``failed_checks`` the names of the checks that
    fail (the verdict)."""
    used = rig.used_corners()
    cameras = {}
    for name, cam in rig.cameras.items():
        views = corners.cameras[name].views
        kept = sum(int(np.isfinite(uv[:, 0]).sum()) for uv in used.cameras[name].found().values())
        sigma = rig.camera_sigma[name]
        cameras[name] = {"photos": len(views), "boards": sum(uv is not None for uv in views.values()),
                         "corners": kept, "model": cam.model,
                         **{k: [float(getattr(cam, k)), _number(sigma.get(k))] for k in CAMERA_KEYS}}
    # cameras that each filmed the board alone (caliscope's intrinsic session) share no moment: no relation to pin
    alone = {name for name, c in corners.cameras.items() if (c.meta.get("imported") or {}).get("instants_shared") is False}
    relations = {name: {"baseline_mm": [float(rel.baseline_mm), float(rel.sigma_baseline_mm)],
                        "opk_arcmin": [[float(a), float(s)] for a, s in zip(rel.pose.opk_arcmin, rel.sigma_opk_arcmin)]}
                 for name, rel in rig.rig.items() if not {name, rig.reference} & alone}
    failed = sorted(k for k, c in rig.checks.items() if not c.get("ok", True))
    return {"cameras": cameras, "rig": relations, "failed_checks": failed}


def opencv_boards_found(paths: list[Path], board: Board) -> dict[str, int]:
    """How many of ``paths`` OpenCV's detectors find ``board`` in, at full resolution: the classic
    ``findChessboardCorners`` (adaptive threshold, normalised) and ``findChessboardCornersSB`` (exhaustive)."""
    import cv2

    size = (board.cols, board.rows)
    classic = sb = 0
    for path in paths:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        classic += bool(cv2.findChessboardCorners(gray, size, flags=flags)[0])
        sb += bool(cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)[0])
    return {"classic": classic, "sb": sb}


def differences(pinned: dict, now: dict, share: float) -> list[str]:
    """What moved from the ``pinned`` row to ``now``: a board or corners lost, a lens model changed, a parameter moved by
    more than ``share`` of its pinned sigma, a check that passed and fails now (one line each; empty: nothing)."""
    out = []
    for name, was in pinned["cameras"].items():
        cam = now["cameras"].get(name)
        if cam is None:
            out.append(f"camera {name} is gone")
            continue
        if cam["boards"] < was["boards"]:
            out.append(f"{name}: {cam['boards']} boards found, {was['boards']} before")
        if cam["model"] != was["model"]:
            out.append(f"{name}: lens model {cam['model']}, {was['model']} before")
            continue
        for k in CAMERA_KEYS:
            (v0, s0), (v1, _) = was[k], cam[k]
            if s0 and abs(v1 - v0) > share * s0:
                out.append(f"{name}.{k}: {v1:.6g}, {v0:.6g} +- {s0:.3g} before ({abs(v1 - v0) / s0:.2f} sigma)")
    for name, was in pinned["rig"].items():
        rel = now["rig"].get(name)
        if rel is None:
            out.append(f"rig relation {name} is gone")
            continue
        pairs = [("baseline_mm", was["baseline_mm"], rel["baseline_mm"])] + [
            (f"opk_arcmin[{i}]", a, b) for i, (a, b) in enumerate(zip(was["opk_arcmin"], rel["opk_arcmin"]))]
        for key, (v0, s0), (v1, _) in pairs:
            if s0 and abs(v1 - v0) > share * s0:
                out.append(f"{name}.{key}: {v1:.6g}, {v0:.6g} +- {s0:.3g} before ({abs(v1 - v0) / s0:.2f} sigma)")
    newly = sorted(set(now["failed_checks"]) - set(pinned["failed_checks"]))
    if newly:
        out.append(f"checks that passed fail now: {', '.join(newly)}")
    return out
