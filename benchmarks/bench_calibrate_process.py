"""``dualcal calibrate corners.json`` as a process against OpenCV's calibration path as a process.

What a user waits for: the whole command, start-up and imports included. On the same synthetic
corners.json, each side is timed as a fresh process (median of ``--runs`` runs after one warm-up, the
four commands taking turns run by run, so that a shared machine's drift weighs on each alike):

* dualcal, its defaults (``--model auto``: every camera's lens model chosen by held-out instants, the
  other skew model beside it, the board-shape test, covariances, held-out errors, checks);
* dualcal, the paper's case alone (``--model k1k2 --no-compare-models --no-compare-lens``: one lens
  model, one skew model, still with the board-shape test, sigmas, held-out errors and checks);
* OpenCV: a Python process that reads the same corners.json and runs ``cv2.calibrateCamera`` per
  camera (k1 k2) and ``cv2.stereoCalibrate`` of every other camera with the reference
  (``CALIB_USE_INTRINSIC_GUESS``), which gives no sigma, no check and no model choice;
* the floor under dualcal's time: a process that imports every module the default command imported, in
  its order, and does nothing else (``imports alone``). What lies between it and the command is the work.

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
import tempfile
from pathlib import Path

from bench_calibrate import compile_sources, process_times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="13 instants of note8 only")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    cases = [("note8", 13)] if args.quick else [(p, v) for p in ("note8", "triple", "quad") for v in (13, 50, 200)]
    compile_sources()
    print(f"{'rig':8} {'instants':>8} {'dualcal default':>16} {'paper case':>11} {'OpenCV':>8} "
          f"{'default/OpenCV':>15} {'paper/OpenCV':>13} {'imports alone':>14} {'imports/OpenCV':>15}")
    with tempfile.TemporaryDirectory() as tmp:
        for preset, views in cases:
            t = process_times(preset, views, args.runs if views < 200 else 1, Path(tmp))
            print(f"{preset:8} {views:8d} {t['default']:15.2f}s {t['paper']:10.2f}s {t['opencv']:7.2f}s "
                  f"{t['default'] / t['opencv']:15.2f} {t['paper'] / t['opencv']:13.2f} {t['imports']:13.2f}s "
                  f"{t['imports'] / t['opencv']:15.2f}", flush=True)
    print(f"(processes taking turns, median of {args.runs} runs after a warm-up, 1 run at 200 instants; cameras: note8 2, "
          f"triple 3, quad 4; load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
