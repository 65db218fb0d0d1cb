"""``dualcal calibrate corners.json`` as a process against OpenCV's calibration path as a process.

What a user waits for: the whole command, start-up and imports included. On the same synthetic
corners.json, each side is timed as a fresh process (median of ``--runs`` runs after one warm-up):

* dualcal, its defaults (``--model auto``: every camera's lens model chosen by held-out instants, the
  other skew model beside it, the board-shape test, covariances, held-out errors, checks);
* dualcal, the paper's case alone (``--model k1k2 --no-compare-models --no-compare-lens``: one lens
  model, one skew model, still with the board-shape test, sigmas, held-out errors and checks);
* OpenCV: a Python process that reads the same corners.json and runs ``cv2.calibrateCamera`` per
  camera (k1 k2) and ``cv2.stereoCalibrate`` of every other camera with the reference
  (``CALIB_USE_INTRINSIC_GUESS``), which gives no sigma, no check and no model choice.

Then how the time grows: 13, 50 and 200 instants of two cameras (``note8``), three (``triple``) and
four (``bench_calibrate.QUAD_PRESET``: wide, tele, ultra-wide and a macro camera, a 10 x 10 board).
dualcal's sources are byte-compiled first, as an installed package's are (this machine sets
``PYTHONDONTWRITEBYTECODE``, which would otherwise make every run compile them again).

    .venv/bin/python benchmarks/bench_calibrate_process.py            # the table and the growth (~10 min)
    .venv/bin/python benchmarks/bench_calibrate_process.py --quick    # 13 instants of note8 only
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DUALCAL = [sys.executable, "-m", "dualcal"]

OPENCV = r"""
import json, sys
import cv2, numpy as np
doc = json.load(open(sys.argv[1]))
b = doc["board"]
obj = np.array([[c * b["square_mm"], r * b["square_mm"], 0] for r in range(b["rows"]) for c in range(b["cols"])],
               np.float32)
cams = doc["cameras"]
names = sorted(cams)
ref = "wide" if "wide" in names else names[0]
flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
K, D = {}, {}
for n in names:
    views = [np.array(v, np.float32) for v in cams[n]["views"].values() if v is not None]
    _, K[n], D[n], _, _ = cv2.calibrateCamera([obj] * len(views), views, tuple(cams[n]["image_size"]), None, None,
                                              flags=flags)
for n in names:
    if n == ref:
        continue
    keys = [k for k in cams[ref]["views"] if cams[ref]["views"][k] is not None and cams[n]["views"].get(k) is not None]
    a = [np.array(cams[ref]["views"][k], np.float32) for k in keys]
    c = [np.array(cams[n]["views"][k], np.float32) for k in keys]
    cv2.stereoCalibrate([obj] * len(keys), a, c, K[ref], D[ref], K[n], D[n], tuple(cams[ref]["image_size"]),
                        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS)
"""


def _time(cmd: list[str], runs: int) -> float:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    subprocess.run(cmd, check=True, capture_output=True, env=env)          # warm-up (file caches)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def write_corners(preset: str, views: int, folder: Path) -> Path:
    """A synthetic corners.json of ``views`` instants of ``preset`` (``quad``: bench_calibrate's 4 cameras)."""
    data = folder / f"{preset}-{views}"
    if preset == "quad":
        from bench_calibrate import float32_corner_set, quad_truth
        from dualcal.files.io import save_corners

        data.mkdir(parents=True)
        save_corners(data / "corners.json", float32_corner_set(quad_truth(views, seed=7), 0.1, seed=8))
    else:
        subprocess.run(DUALCAL + ["synth", str(data), "--preset", preset, "--views", str(views), "--no-photos",
                                  "--noise", "0.1"], check=True, capture_output=True)
    return data / "corners.json"


def measure(preset: str, views: int, runs: int, folder: Path) -> dict[str, float]:
    corners = write_corners(preset, views, folder)
    out = corners.parent / "calib.json"
    script = folder / "opencv_calibrate.py"
    script.write_text(OPENCV)
    return {"default": _time(DUALCAL + ["calibrate", str(corners), "-o", str(out)], runs),
            "paper": _time(DUALCAL + ["calibrate", str(corners), "-o", str(out), "--model", "k1k2",
                                      "--no-compare-models", "--no-compare-lens"], runs),
            "opencv": _time([sys.executable, str(script), str(corners)], runs)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="13 instants of note8 only")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    cases = [("note8", 13)] if args.quick else [(p, v) for p in ("note8", "triple", "quad") for v in (13, 50, 200)]
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "src" / "dualcal")], check=True)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    print(f"{'rig':8} {'instants':>8} {'dualcal default':>16} {'paper case':>11} {'OpenCV':>8} "
          f"{'default/OpenCV':>15} {'paper/OpenCV':>13}")
    with tempfile.TemporaryDirectory() as tmp:
        for preset, views in cases:
            t = measure(preset, views, args.runs if views < 200 else 1, Path(tmp))
            print(f"{preset:8} {views:8d} {t['default']:15.2f}s {t['paper']:10.2f}s {t['opencv']:7.2f}s "
                  f"{t['default'] / t['opencv']:15.2f} {t['paper'] / t['opencv']:13.2f}", flush=True)
    print(f"(processes, median of {args.runs} runs after a warm-up, 1 run at 200 instants; cameras: note8 2, "
          f"triple 3, quad 4; load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
