"""Photos to a calibrated rig, end to end: ``dualcal calibrate photos/`` against OpenCV's pipeline.

The input is what ``dualcal synth DIR --preset note8 --views 13`` writes: 26 JPEG photos of 12 MP (3024 x 4032),
wide + tele, an 8x5 board of 30 mm squares, with known truth (synthetic figures). Each side is a fresh process,
start-up and imports included, the commands taking turns run by run (median of ``--runs`` after one warm-up), so
that a shared machine's drift weighs on each alike:

* dualcal: ``dualcal calibrate PHOTOS --board 8x5 --square 30`` (detection on all cores, then its defaults:
  lens models compared, sigmas, checks);
* OpenCV, as a careful user writes it: per photo ``cv2.imread`` (grey), a copy reduced to a long side of about
  1000 pixels (``INTER_AREA``), the classic ``findChessboardCorners`` on it (adaptive threshold, normalised, fast
  check), ``cornerSubPix`` (11 x 11) at full size; then ``calibrateCamera`` per camera (k1 k2) and
  ``stereoCalibrate`` of the tele with the wide (``CALIB_USE_INTRINSIC_GUESS``); one photo after another.

Also timed, for the breakdown: ``dualcal --version`` (start-up), ``dualcal detect`` alone, ``dualcal calibrate
corners.json`` alone, and in this process the decoding alone of the 26 photos (one thread, CPU time): OpenCV's
``cv2.imread`` and dualcal's ``read_gray`` (libjpeg-turbo through simplejpeg, the same pixels), which both pipelines
must do at full size (the refinement, dualcal's and OpenCV's, wants full-resolution pixels; decoding a reduced copy
first, or a region, still decodes every Huffman code before it, which is most of a decode: see
``bench_detect.py``'s decoding lines) and which is therefore the floor under both. Printed: the wall and CPU times,
the ratios dualcal / OpenCV (target <= 1.0 wall, issue 41), and each result's errors against the truth (fx, cx, k1
of both cameras, the baseline).

    .venv/bin/python benchmarks/bench_end_to_end.py [--runs 3] [--photos DIR] [--keep DIR]

``--photos DIR``: a folder ``dualcal synth`` wrote (its ``photos/`` and ``truth.json``), rendered once and kept
with ``--keep``; rendering takes about a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from dualcal.files.photos import read_gray

OPENCV_PIPELINE = r"""
import json, os, sys
import cv2, numpy as np
root, cols, rows, square, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
cams = sorted(os.listdir(root))
obj = np.zeros((cols * rows, 3), np.float32)
obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
pts, size = {}, {}
for cam in cams:
    pts[cam] = {}
    for name in sorted(os.listdir(os.path.join(root, cam))):
        img = cv2.imread(os.path.join(root, cam, name), cv2.IMREAD_GRAYSCALE)
        f = max(1, max(img.shape) // 1000)
        small = cv2.resize(img, (img.shape[1] // f, img.shape[0] // f), interpolation=cv2.INTER_AREA)
        found, c = cv2.findChessboardCorners(small, (cols, rows), flags=flags)
        if not found:
            continue
        c = cv2.cornerSubPix(img, (c + 0.5) * f - 0.5, (11, 11), (-1, -1), crit)
        pts[cam][name] = c
        size[cam] = img.shape[::-1]
k1k2 = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
model = {}
for cam in cams:
    views = list(pts[cam].values())
    _, K, d, _, _ = cv2.calibrateCamera([obj] * len(views), views, size[cam], None, None, flags=k1k2)
    model[cam] = (K, d)
ref = "wide" if "wide" in cams else cams[0]
result = {"cameras": {c: {"fx": m[0][0, 0], "cx": m[0][0, 2], "k1": m[1].ravel()[0]} for c, m in model.items()}}
for cam in cams:
    if cam != ref:
        common = sorted(set(pts[ref]) & set(pts[cam]))
        r = cv2.stereoCalibrate([obj] * len(common), [pts[ref][k] for k in common], [pts[cam][k] for k in common],
                                *model[ref], *model[cam], size[ref], flags=cv2.CALIB_USE_INTRINSIC_GUESS | k1k2)
        result["baseline_mm"] = float(np.linalg.norm(r[6]))
json.dump(result, open(out, "w"), default=float)
"""


def median_times(commands: dict[str, list[str]], runs: int) -> dict[str, tuple[float, float]]:
    """Median wall time and median CPU time (user + system, the process and its threads) of each command, the
    commands taking turns, after one warm-up round."""
    times = {name: [] for name in commands}
    for i in range(runs + 1):
        for name, cmd in commands.items():
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wall = time.perf_counter() - t
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if i:
                times[name].append((wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime))
    return {name: (statistics.median(w for w, _ in t), statistics.median(c for _, c in t)) for name, t in times.items()}


def errors(result: dict, truth: dict) -> dict[str, float]:
    """Errors against the truth of fx, cx and k1 of every camera and of the baseline."""
    out = {}
    for cam, t in truth["cameras"].items():
        for key in ("fx", "cx", "k1"):
            out[f"{cam} {key}"] = result["cameras"][cam][key] - t[key]
    out["baseline mm"] = result["baseline_mm"] - next(iter(truth["rig"].values()))["baseline_mm"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--photos", type=Path, default=None, help="a folder 'dualcal synth' wrote (photos/, truth.json)")
    ap.add_argument("--keep", type=Path, default=None, help="render into this folder and keep it")
    args = ap.parse_args(argv)
    dualcal = str(Path(sys.executable).with_name("dualcal"))
    root = args.photos or args.keep or Path(tempfile.mkdtemp(prefix="dualcal-e2e-"))
    work = Path(tempfile.mkdtemp(prefix="dualcal-e2e-out-"))
    try:
        if args.photos is None:
            print("rendering 26 photos of 12 MP ...", file=sys.stderr)
            subprocess.run([dualcal, "synth", str(root), "--preset", "note8", "--views", "13"], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        photos = root / "photos"
        board = ["--board", "8x5", "--square", "30"]
        subprocess.run([dualcal, "detect", str(photos), *board, "-o", str(work / "corners.json")], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        commands = {
            "dualcal calibrate photos/": [dualcal, "calibrate", str(photos), *board, "-o", str(work / "calib.json")],
            "OpenCV pipeline": [sys.executable, "-c", OPENCV_PIPELINE, str(photos), "8", "5", "30",
                                str(work / "opencv.json")],
            "dualcal --version": [dualcal, "--version"],
            "dualcal detect": [dualcal, "detect", str(photos), *board, "-o", str(work / "corners2.json")],
            "dualcal calibrate corners.json": [dualcal, "calibrate", str(work / "corners.json"), "-o",
                                               str(work / "calib2.json")],
        }
        t = median_times(commands, args.runs)
        cv2.setNumThreads(1)
        files = sorted(photos.glob("*/*.jpg"))
        decode = {"OpenCV imread": [], "dualcal read_gray": []}
        for _ in range(args.runs):
            for name, read in (("OpenCV imread", lambda p: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)),
                               ("dualcal read_gray", read_gray)):
                start = time.process_time()
                for path in files:
                    read(path)
                decode[name].append(time.process_time() - start)
        decode = {name: statistics.median(t) for name, t in decode.items()}
        truth = json.loads((root / "truth.json").read_text())
        calib = json.loads((work / "calib.json").read_text())
        ours = errors({"cameras": calib["cameras"], "baseline_mm": calib["rig"]["tele"]["baseline_mm"]}, truth)
        theirs = errors(json.loads((work / "opencv.json").read_text()), truth)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        if args.photos is None and args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    ours_s, theirs_s = t["dualcal calibrate photos/"], t["OpenCV pipeline"]
    ratio = ours_s[0] / theirs_s[0]
    print(f"26 photos of 12 MP, wide + tele; processes taking turns, median of {args.runs} runs "
          f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f})")
    print(f"  {'':32} {'wall s':>7} {'CPU s':>7}")
    for name, (wall, cpu) in t.items():
        print(f"  {name:32} {wall:7.2f} {cpu:7.2f}")
    for name, seconds in decode.items():
        print(f"  {'decoding alone: ' + name:32} {'':7} {seconds:7.2f}   (the 26 JPEGs, one thread, in this process)")
    print(f"ratio dualcal / OpenCV end to end: {ratio:.2f} wall (target <= 1.0), {ours_s[1] / theirs_s[1]:.2f} CPU")
    cores = os.cpu_count() or 1
    floor = t["dualcal --version"][0] + decode["dualcal read_gray"] / cores
    print(f"floor under dualcal: start-up + its decoding spread over {cores} cores = {floor:.2f} s = "
          f"{floor / theirs_s[0]:.2f} x OpenCV's pipeline, before any detection or calibration (on idle cores)")
    print(f"{'error vs truth':14} {'dualcal':>10} {'OpenCV':>10}")
    for key in ours:
        print(f"{key:14} {ours[key]:10.4f} {theirs[key]:10.4f}")
    return 0 if ratio <= 1.0 else 1


if __name__ == "__main__":
    sys.exit(main())
