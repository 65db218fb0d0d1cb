"""The work of a project, as it runs in a worker process (:mod:`.jobs` starts it; nothing here touches
the server).

* :func:`detect_upload`: one uploaded photo: its corners (through :class:`RememberedDetection`, the same
  :func:`dualcal.files.detect.detect_photo` a command calls, remembered on disk) and its thumbnail; its
  preview for the screen when it is first asked for (:func:`write_screen_preview`).
* :func:`run_job`: bring a project's files up to a version: exactly what

      cd PROJECT && dualcal detect photos BOARD-FLAGS -o corners.json       (every photo; kept, see below)
      dualcal calibrate corners.json [--exclude ...] -o calib.json            (corners.json: those used)
      dualcal evaluate calib.json -o eval.json && dualcal advise calib.json -o advise.json
      dualcal export calib.json --format F -o exports/...

  compute (:mod:`dualcal.workflow`: every dataset-level step, the camera roll's split, identical files,
  a ChArUco board's dictionary, as the commands run them), with each photo's detection taken from
  where its upload left it, and every photo's corners kept for the next change of the photos used
  (:func:`_every_photos_corners`). It tells the server each step done through ``conn``.
* :func:`make_report`: ``dualcal report calib.json --eval eval.json -o report.html``, when it is asked for.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from ..errors import DualcalError
from ..files.detect.pipeline import PhotoResult, detect_photo
from ..files.io import read_json, write_json_atomic
from ..progress import collect_warnings
from .store import EXPORTS, Project, Settings, exclude_pattern
from .summary import advice_summary, calibration_summary, split_warnings

__all__ = ["CALIBRATE_OPTIONS", "RememberedDetection", "detect_upload", "make_report", "run_job",
           "write_screen_preview"]

#: ``dualcal calibrate``'s defaults, as :func:`dualcal.workflow.calibrate_corners` keywords (the app has no
#: flags for them; the test of the app's calib.json against the command's holds them equal).
CALIBRATE_OPTIONS = dict(skew=False, compare_lens=True, rig_mode="rigid", reference=None, drop_outliers=True,
                         outlier_factor=6.0, board_shape="auto", model="auto")
THUMB_PX, SCREEN_PX = 360, 1600


def _board_key(board) -> dict:
    doc = board.to_dict()
    doc.pop("square_sigma_mm", None)
    if board.charuco is not None:
        doc["charuco"]["legacy"] = board.charuco.legacy
    return doc


class RememberedDetection:
    """:func:`~dualcal.files.detect.detect_photo`, each result kept in ``cache_dir`` under the photo's name,
    size and modification time and the board, so that a photo is detected once (when it is uploaded)
    however often the dataset is read again. Thread-safe (each result is one file written atomically)."""

    def __init__(self, cache_dir: Path, photos_dir: Path):
        self.cache_dir, self.photos_dir = Path(cache_dir), Path(photos_dir)

    def _file(self, path, board) -> Path:
        stat = os.stat(path)
        name = os.path.relpath(os.path.abspath(path), os.path.abspath(self.photos_dir))
        key = json.dumps([name, stat.st_size, stat.st_mtime_ns, _board_key(board)], sort_keys=True)
        return self.cache_dir / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.json"

    def known(self, path, board) -> PhotoResult | None:
        try:
            doc = read_json(self._file(path, board))
        except Exception:        # absent or unreadable: detected again
            return None
        uv = None if doc["uv"] is None else np.array([[np.nan, np.nan] if p is None else p for p in doc["uv"]], float)
        return PhotoResult(uv, tuple(doc["image_size"]) if doc["image_size"] else None, doc["reason"], doc["symmetric"],
                           doc["manual"], doc["failed_check"], doc["partial"], doc["mirrored"])

    def __call__(self, path, board, hint_uv=None, overlay_path=None) -> PhotoResult:
        if hint_uv is not None or overlay_path is not None:
            return detect_photo(path, board, hint_uv, overlay_path)
        result = self.known(path, board)
        if result is None:
            result = detect_photo(path, board)
            uv = None if result.uv is None else [None if not np.all(np.isfinite(p)) else [float(p[0]), float(p[1])]
                                                 for p in result.uv]
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            write_json_atomic(self._file(path, board), {
                "uv": uv, "image_size": list(result.image_size) if result.image_size else None, "reason": result.reason,
                "symmetric": result.symmetric, "manual": result.manual, "failed_check": result.failed_check,
                "partial": result.partial, "mirrored": result.mirrored})
        return result


def _detector(project: Project) -> RememberedDetection:
    return RememberedDetection(project.app_file("detections"), project.photos_dir)


def _reduced(path: Path, long_side: int) -> np.ndarray:
    """The photo in its stored frame as BGR, its long side about ``long_side`` (JPEG decoded reduced)."""
    import cv2

    from ..files.photos import open_image, read_exif

    if path.suffix.lower() in (".heic", ".heif", ".dng"):
        with open_image(path) as img:
            rgb = img.convert("RGB")
            rgb.thumbnail((long_side, long_side))
            return cv2.cvtColor(np.asarray(rgb), cv2.COLOR_RGB2BGR)
    (w, h), _ = read_exif(path)
    factor = next(f for f in (8, 4, 2, 1) if max(w, h) / f >= long_side or f == 1)
    flag = {8: cv2.IMREAD_REDUCED_COLOR_8, 4: cv2.IMREAD_REDUCED_COLOR_4, 2: cv2.IMREAD_REDUCED_COLOR_2,
            1: cv2.IMREAD_COLOR}[factor]
    img = cv2.imread(str(path), flag | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise ValueError("cannot be decoded")
    scale = min(1.0, long_side / max(img.shape[:2]))
    return cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else img


def _write_thumbnail(project: Project, photo: str, uv, image_size) -> None:
    """``thumbs``: the photo small (decoded reduced), the detected corners drawn."""
    import cv2

    from ..files.io import write_jpeg_atomic

    thumb = _reduced(project.photos_dir / photo, THUMB_PX)
    if uv is not None and image_size:
        s = thumb.shape[1] / image_size[0]
        for k, (u, v) in enumerate(np.asarray(uv)):
            if np.isfinite(u) and np.isfinite(v):
                cv2.circle(thumb, (int(round((u + 0.5) * s - 0.5)), int(round((v + 0.5) * s - 0.5))),
                           4 if k == 0 else 2, (40, 40, 230) if k == 0 else (60, 200, 60), -1, cv2.LINE_AA)
    out = project.preview("thumbs", photo)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_jpeg_atomic(out, thumb, 85)


def write_screen_preview(project: Project, photo: str) -> Path:
    """``screen``: the photo for measuring on a screen (its long side about :data:`SCREEN_PX`), made when it is
    first asked for: most photos are never opened, and making it with every upload's detection would hold the
    verdict back (it costs two thirds of a 12 MP photo's detection)."""
    from ..files.io import write_jpeg_atomic

    out = project.preview("screen", photo)
    if not out.is_file():
        screen = _reduced(project.photos_dir / photo, SCREEN_PX)
        out.parent.mkdir(parents=True, exist_ok=True)
        write_jpeg_atomic(out, screen, 85)
    return out


def detect_upload(folder: str, photo: str, board) -> dict:
    """Detect one uploaded photo (remembered for :func:`run_job`) and write its thumbnail.

    Returns ``{"photo", "found", "reason", "image_size"}``.
    """
    project = Project(Path(folder))
    path = project.photos_dir / photo
    result = _detector(project)(path, board)
    try:
        _write_thumbnail(project, photo, result.uv, result.image_size)
    except Exception as exc:              # a photo that cannot be shown is still one the dataset may read
        reason = result.reason or f"cannot be shown ({type(exc).__name__})"
        return {"photo": photo, "found": result.uv is not None, "reason": reason, "image_size": None}
    return {"photo": photo, "found": result.uv is not None, "reason": result.reason,
            "image_size": list(result.image_size) if result.image_size else None}


def _results(project: Project, **changes) -> dict:
    doc = project.read_app_json("results.json") or {"version": -1, "files": {}}
    doc.update(changes)
    write_json_atomic(project.app_file("results.json"), doc)
    return doc


def _file_done(project: Project, name: str, version: int, conn) -> None:
    doc = project.read_app_json("results.json") or {"version": -1, "files": {}}
    doc["files"][name] = version
    write_json_atomic(project.app_file("results.json"), doc)
    if conn is not None:
        conn.send(("file", name))


def _locked(project: Project):
    """The folder's job lock: one job (or report) in a folder at a time, even one a killed server left behind."""
    import fcntl

    project.app_dir.mkdir(exist_ok=True)
    lock = open(project.app_file("job.lock"), "w")
    fcntl.flock(lock, fcntl.LOCK_EX)
    return lock


def run_job(folder: str, version: int, settings: dict, left_out: list[str], conn=None, recompute: bool = True) -> None:
    """Bring the project's files to ``version`` (module docstring); on an error a user can cause, results.json
    says it (``error``) and the files of the last complete calibration stay as they were.

    ``recompute`` False takes the calib.json there as it is (a folder the commands made, opened the first time):
    only what the page shows is made from it, and the files missing beside it.
    """
    project = Project(Path(folder))
    os.chdir(project.folder)          # a process of its own: corners.json names photos/..., as the commands do
    with _locked(project), collect_warnings() as warnings:
        try:
            _calibrate(project, version, Settings(**settings), left_out, conn, warnings, recompute)
        except DualcalError as exc:
            _results(project, version=version, error=str(exc), warnings=list(warnings))
            if conn is not None:
                conn.send(("error", str(exc)))
            return
    if conn is not None:
        conn.send(("done", version))


def _every_photos_corners(project: Project, settings: Settings, warnings: list[str]):
    """The corners of every photo of the project, none left out, as ``dualcal detect photos`` writes them in
    corners.json (the camera roll split, each photo's detection as its upload left it): read once for a set of
    photos and a board, and kept (``.dualcal-app/corners-all.json``, with the warnings of that read, which are
    said again), so that leaving a photo out, or using it again, calibrates at once from them, as ``dualcal
    calibrate corners.json --exclude PHOTO`` does (reading the photos' headers, the files' contents for copies
    and the roll's split again took a third of that wait on a 62-photo roll)."""
    from .. import __version__
    from ..files.io import corners_from_dict, corners_to_dict
    from ..workflow import read_corners

    stats = {name: os.stat(project.photos_dir / name) for name in project.photo_names()}
    key = {"dualcal": __version__, "board": settings.to_dict(),
           "photos": [[name, st.st_size, st.st_mtime_ns] for name, st in stats.items()]}
    kept = project.read_app_json("corners-all.json")
    if kept and kept.get("key") == key:
        warnings.extend(kept["warnings"])
        return corners_from_dict(kept["corners"], "corners-all.json")
    before = len(warnings)
    doc = corners_to_dict(read_corners("photos", settings.make_board(), square_sigma_mm=settings.square_sigma_mm,
                                       detect=_detector(project), progress=False))
    write_json_atomic(project.app_file("corners-all.json"), {"key": key, "warnings": list(warnings[before:]),
                                                             "corners": doc})
    return corners_from_dict(doc, "corners-all.json")         # as corners.json holds them, the first time too


def _calibrate(project: Project, version: int, settings: Settings, left_out, conn, warnings, recompute) -> None:
    from ..estimation.advise import advice_to_dict, advise, prior_from_rig
    from ..files.dataset import exclude_views
    from ..files.io import rig_to_dict, save_corners, save_rig, write_text_atomic
    from ..workflow import calibrate_corners, evaluate_calibration, read_calibration

    present = set(project.photo_names())
    fresh = recompute and bool(present)
    if fresh:
        patterns = [exclude_pattern(p) for p in sorted(set(left_out) & present)]
        corners = exclude_views(_every_photos_corners(project, settings, warnings), patterns)
        save_corners("corners.json", corners)
        _file_done(project, "corners.json", version, conn)
        rig = calibrate_corners(corners, **CALIBRATE_OPTIONS)
        save_rig("calib.json", rig)
    else:                                   # a calib.json the commands made, taken as it is
        rig = read_calibration("calib.json")
    summary = calibration_summary(rig, rig_to_dict(rig), version)
    summary["warnings"], summary["photos_left_out"] = split_warnings(list(warnings), sorted(present))
    write_json_atomic(project.app_file("summary.json"), summary)
    _results(project, version=version, error=None, warnings=list(warnings))
    _file_done(project, "calib.json", version, conn)
    if conn is not None:
        conn.send(("calibrated", version))

    if fresh or not Path("eval.json").exists():
        write_json_atomic("eval.json", evaluate_calibration(rig, progress=False))
    _file_done(project, "eval.json", version, conn)
    advice = advise(prior_from_rig(rig), 5, {}, seed=0)
    advice_doc = advice_to_dict(advice)
    if fresh or not Path("advise.json").exists():
        from ..pages.report.advice import render_advice_page
        write_json_atomic("advise.json", advice_doc)
        write_text_atomic("advise.html", render_advice_page(advice, {n: c.image_size for n, c in rig.cameras.items()}))
    _file_done(project, "advise.json", version, conn)
    previous = project.read_app_json("predicted.json")
    if previous and previous.get("instants", 0) >= len(rig.reference_poses()):
        previous = None            # a prediction is for a calibration with more photos than that one had
    summary["advice"] = advice_summary(advice_doc, previous, advice.current_sigma)
    write_json_atomic(project.app_file("summary.json"), summary)
    if advice.poses:
        write_json_atomic(project.app_file("predicted.json"), {
            "version": version, "instants": len(rig.reference_poses()), "predicted_sigma": advice.poses[0].predicted_sigma})
    _file_done(project, "summary.json", version, conn)

    from ..files.export import write_export
    (project.folder / "exports" / EXPORTS["mrcal"]).mkdir(parents=True, exist_ok=True)
    for fmt, name in EXPORTS.items():
        try:
            write_export(rig, fmt, f"exports/{name}" + ("/" if fmt == "mrcal" else ""))
        except DualcalError as exc:
            warnings.append(f"export {fmt}: {exc}")
    _file_done(project, "exports", version, conn)
    summary["warnings"], summary["photos_left_out"] = split_warnings(list(warnings), sorted(present))
    write_json_atomic(project.app_file("summary.json"), summary)
    _results(project, version=version, error=None, warnings=list(warnings), complete=version)


def make_report(folder: str) -> dict:
    """report.html of the calib.json there (and its eval.json, where it belongs to it), as ``dualcal report
    calib.json --eval eval.json`` writes it: made when it is asked for, since it is the slowest file (its
    figures: two thirds of a recalibration's time on a small set) and the one least needed while photos are
    added and left out. Returns results.json."""
    from ..errors import InputError
    from ..files.io import check_evaluation_belongs, load_evaluation, write_text_atomic
    from ..pages.report import render_report
    from ..workflow import read_calibration

    project = Project(Path(folder))
    with _locked(project):
        version = (project.read_app_json("results.json") or {}).get("files", {}).get("calib.json", -1)
        rig = read_calibration(project.folder / "calib.json")
        try:
            evaluation = load_evaluation(project.folder / "eval.json")
            check_evaluation_belongs(rig, evaluation, "calib.json", "eval.json")
        except InputError:
            evaluation = None
        write_text_atomic(project.folder / "report.html", render_report(rig, evaluation, progress=False))
        _file_done(project, "report.html", version, None)
    return project.read_app_json("results.json")
