"""``dualcal calibrate``'s speed where a user feels it, beside OpenCV's, in one run (issue 32).

1. **The defaults as a process, from 50 instants up.** What a user waits for: the whole command, start-up and
   imports included, on a synthetic corners.json of 50 and 100 instants of two cameras (``note8``), three
   (``triple``) and four (``bench_calibrate.QUAD_PRESET``: wide, tele, ultra-wide and a macro camera, a
   10 x 10 board). Each side is timed as a fresh process (median of ``--runs`` runs after one warm-up, the
   commands taking turns run by run, so that a shared machine's drift weighs on each alike):

   * dualcal, its defaults (``--model auto``: every camera's lens model chosen by held-out instants, the
     other skew model beside it, the board-shape test, covariances, held-out errors, checks, calib.json
     written and the tables printed);
   * OpenCV: a Python process that reads the same corners.json and runs ``cv2.calibrateCamera`` per
     camera (k1 k2) and ``cv2.stereoCalibrate`` of every other camera with the reference
     (``CALIB_USE_INTRINSIC_GUESS``), which gives no sigma, no check and no model choice, and writes nothing;
   * the floor under dualcal's time: a process that imports every module the default command imported, in
     its order, and does nothing else (``imports alone``).

   Beside the wall times, each side's CPU seconds (user and system, median): on a machine busy with other
   work the wall time of both waits for a core, and the CPU time is what each side itself costs.
   Target: dualcal / OpenCV at most 1.0, and at 50 instants of two to four cameras at most 1.25 (issue 41). ``--growth`` adds 13 and 200 instants and the paper's case alone
   (``--model k1k2 --no-compare-models --no-compare-lens``).

2. **A recalibration in process** (what the app does after a photo is left out: the corners in memory,
   one instant left out, calibrated again with the defaults, the other skew model included, as the
   command computes them; nothing read or written): median wall seconds over ``--runs`` instants left
   out, on 13 and 20 instants of the three synthetic rigs and on the three shared real sets (corners
   detected here, once). Target: under 1 s (wall; the CPU seconds beside it, which other work on a shared
   machine inflates less). OpenCV's in-process calibration of the same corners beside it.

3. **The real sets against the defaults of an earlier revision** (``--baseline``, default ``8ffbcf9``, the
   main branch before issue 32's speed work, exported from git and run in a process of its own on the
   same corners): the lens models chosen, the checks passed, and the largest ``|delta| / sigma`` of any
   parameter (intrinsics, rig, board shape) of the calibration and of the other skew model. Target: the
   same models, no check that passed then fails now, every parameter within 0.05 sigma. A check that failed
   then and passes now is listed, not failed: issue 33 changed ``rig_rigid``'s test after that revision,
   and the real stereo sample's instants, which it flagged, now pass it, as that issue asks.

dualcal's sources are byte-compiled first, as an installed package's are (this machine sets
``PYTHONDONTWRITEBYTECODE``, which would otherwise make every run compile them again).

    .venv/bin/python benchmarks/bench_calibrate_process.py              # the three parts (~2 min)
    .venv/bin/python benchmarks/bench_calibrate_process.py --growth     # and 13 and 200 instants, the paper's case (~4 min)
    .venv/bin/python benchmarks/bench_calibrate_process.py --quick      # one run each, note8 only
    .venv/bin/python benchmarks/bench_calibrate_process.py --processes  # part 1 alone, at 50 instants
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
#: The real sets: folder, cameras (NAME=GLOB; none: the folder is one camera), board (inner corners), square mm.
REAL_SETS = {"stereo": ("opencv-samples-stereo", ["left=left*.jpg", "right=right*.jpg"], (9, 6), 25.0),
             "bouguet": ("bouguet-calib-example", ["cam=Image*.tif"], (12, 13), 30.0),
             "huawei": ("huawei-y5-2017", [], (7, 9), 30.0)}
PROCESS_TARGET = 1.0
#: Issue 41's target at 50 instants (two to four cameras), where start-up and imports weigh most.
FIFTY_INSTANTS_TARGET = 1.25
RECALIBRATION_TARGET_S = 1.0
BASELINE_TARGET_SIGMA = 0.05


# ----------------------------------------------------------------------------- what a calibration gives


def defaults(corners):
    """What ``dualcal calibrate`` computes with its defaults: the calibration and the other skew model."""
    from dualcal.workflow import calibrate_corners, other_skew_model

    rig = calibrate_corners(corners)
    return rig, other_skew_model(rig)


def summary(rig, other) -> dict:
    """The lens models chosen, the checks, and every parameter with its sigma (of both skew models)."""
    def values(r):
        out = {}
        for n, cam in r.cameras.items():
            out.update({f"{n}.{k}": (float(getattr(cam, k)), float(s)) for k, s in r.camera_sigma[n].items() if s > 0})
        for n, rel in r.rig.items():
            out[f"{n}.baseline_mm"] = (float(rel.baseline_mm), float(rel.sigma_baseline_mm))
            out.update({f"{n}.{a}": (float(x), float(s)) for a, x, s in zip(("omega", "phi", "kappa"), rel.pose.opk_arcmin,
                                                                              rel.sigma_opk_arcmin)})
            out.update({f"{n}.t_{a}": (float(x), float(s)) for a, x, s in zip("xyz", rel.pose.t_mm, rel.sigma_t_mm)})
        if r.board_shape_mm is not None:
            out.update({f"board.shape_{i}": (float(w), float(s))
                        for i, (w, s) in enumerate(zip(r.board_shape_mm, r.board_shape_sigma_mm))})
        return out
    return {"models": rig.adjustment.get("lens_models_chosen"), "checks": {k: bool(c["ok"]) for k, c in rig.checks.items()},
            "values": values(rig), "other": values(other)}


def dump(out: str, paths: list[str]) -> None:
    """``--dump``: :func:`summary` of the defaults on each corners.json, to ``out`` (run with an earlier
    revision's sources first on ``PYTHONPATH``)."""
    import logging

    from dualcal.files.io import load_corners

    logging.disable(logging.WARNING)
    Path(out).write_text(json.dumps({p: summary(*defaults(load_corners(p))) for p in paths}))


def largest_change(old: dict, new: dict) -> tuple[float, str]:
    """The largest ``|new - old| / sigma_old`` over the parameters both have, and its name."""
    worst = (0.0, "")
    for kind in ("values", "other"):
        for key, (x, s) in old[kind].items():
            if key in new[kind] and s > 0:
                worst = max(worst, (abs(new[kind][key][0] - x) / s, f"{kind}:{key}"))
    return worst


# ----------------------------------------------------------------------------- 1. as processes


def part_processes(cases, runs: int, growth: bool) -> list[list]:
    from bench_calibrate import compile_sources, process_times

    compile_sources()
    rows = []
    print(f"\n1. The defaults as processes (median of {runs} run(s) after a warm-up, taking turns; "
          "OPENBLAS_NUM_THREADS=1)")
    head = (f"{'rig':8} {'instants':>8} {'dualcal':>9} {'OpenCV':>8} {'dualcal/OpenCV':>15} {'imports alone':>14}"
            f" {'CPU s: dualcal':>15} {'OpenCV':>7} {'ratio':>6}")
    print(head + (f" {'paper case':>11} {'paper/OpenCV':>13}" if growth else ""))
    with tempfile.TemporaryDirectory() as tmp:
        for preset, views in cases:
            t = process_times(preset, views, runs if views < 200 else 1, Path(tmp), paper=growth)
            ratio = t["default"] / t["opencv"]
            line = (f"{preset:8} {views:8d} {t['default']:8.2f}s {t['opencv']:7.2f}s {ratio:15.2f} "
                    f"{t['imports']:13.2f}s {t['default cpu']:14.2f}s {t['opencv cpu']:6.2f}s "
                    f"{t['default cpu'] / t['opencv cpu']:6.2f}")
            if growth:
                line += f" {t['paper']:10.2f}s {t['paper'] / t['opencv']:13.2f}"
            print(line, flush=True)
            if views >= 50:
                target = FIFTY_INSTANTS_TARGET if views == 50 else PROCESS_TARGET
                rows.append([f"defaults as a process, {preset} {views} instants: dualcal / OpenCV "
                             f"({t['default']:.2f} s / {t['opencv']:.2f} s)", f"{ratio:.2f}",
                             f"<= {target:g}", "PASS" if ratio <= target else "FAIL"])
    print(f"(cameras: note8 2, triple 3, quad 4; load average {os.getloadavg()[0]:.1f})")
    return rows


# ----------------------------------------------------------------------------- 2. in process


def real_corners(folder: Path) -> dict[str, Path]:
    """The real sets' corners, detected here once, as corners.json files in ``folder``."""
    out = {}
    for name, (sub, cameras, (cols, rows), square) in REAL_SETS.items():
        if not (DATA / sub).is_dir():
            print(f"real set {sub} not present under {DATA}: skipped")
            continue
        path = folder / f"{name}.json"
        args = [str(DATA / sub)] if not cameras else [arg for c in cameras for arg in
                                                       ("--camera", c.split("=")[0] + "=" + str(DATA / sub / c.split("=")[1]))]
        subprocess.run([sys.executable, "-m", "dualcal", "detect", *args, "--board", f"{cols}x{rows}", "--square",
                        str(square), "-o", str(path)], check=True, capture_output=True)
        out[name] = path
    return out


def recalibration_seconds(corners, runs: int) -> tuple[float, float, float]:
    """Median wall seconds of :func:`defaults` with one instant left out (a different one each run), its CPU
    seconds (which other work on a shared machine inflates less), and OpenCV's wall seconds on the same
    corners (:func:`bench_calibrate.opencv_calibrate`)."""
    from dataclasses import replace

    from bench_calibrate import opencv_calibrate
    from dualcal.geometry.model import CornerSet, choose_reference

    views = sorted({v for cc in corners.cameras.values() for v in cc.found()})
    ours, cpu, theirs = [], [], []
    reference = choose_reference(sorted(corners.cameras), corners.reference)
    defaults(corners)                                            # warm-up (caches, first imports)
    for k in range(runs):
        left_out = views[(k * 7) % len(views)]
        fewer = CornerSet(corners.board, {n: replace(cc, views={v: uv for v, uv in cc.views.items() if v != left_out})
                                          for n, cc in corners.cameras.items()}, corners.reference)
        t0, c0 = time.perf_counter(), time.process_time()
        defaults(fewer)
        ours.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        t0 = time.perf_counter()
        opencv_calibrate(fewer, reference)
        theirs.append(time.perf_counter() - t0)
    return statistics.median(ours), statistics.median(cpu), statistics.median(theirs)


def part_recalibration(presets, runs: int, real: dict[str, Path]) -> list[list]:
    import logging

    from bench_calibrate import float32_corner_set, quad_truth
    from dualcal.files.io import load_corners
    from dualcal.synthetic import synth

    logging.disable(logging.WARNING)
    print(f"\n2. A recalibration in process: one instant left out, the defaults again (median of {runs} "
          "instants left out; wall seconds)")
    print(f"{'corners':22} {'instants':>8} {'dualcal':>9} {'(CPU)':>8} {'OpenCV':>8} {'target':>8}")
    rows, worst = [], 0.0
    cases = [(f"{p} (synthetic)", views, lambda p=p, v=views: float32_corner_set(
        quad_truth(v, seed=7) if p == "quad" else synth.make_truth(p, v, seed=7), 0.1, seed=8))
             for p in presets for views in (13, 20)]
    cases += [(f"{name} (real)", None, lambda path=path: load_corners(path)) for name, path in real.items()]
    for label, views, make in cases:
        corners = make()
        n = len({v for cc in corners.cameras.values() for v in cc.found()})
        t, t_cpu, t_cv = recalibration_seconds(corners, runs)
        worst = max(worst, t)
        print(f"{label:22} {n:8d} {t:8.3f}s {t_cpu:7.3f}s {t_cv:7.3f}s "
              f"{'PASS' if t < RECALIBRATION_TARGET_S else 'FAIL':>8}", flush=True)
    rows.append(["recalibration in process, 13-20 instants: slowest (s)", f"{worst:.3f}",
                 f"< {RECALIBRATION_TARGET_S:g}", "PASS" if worst < RECALIBRATION_TARGET_S else "FAIL"])
    print(f"(load average {os.getloadavg()[0]:.1f})")
    return rows


# ----------------------------------------------------------------------------- 3. against the old defaults


def part_baseline(real: dict[str, Path], revision: str) -> list[list]:
    import logging

    from dualcal.files.io import load_corners

    logging.disable(logging.WARNING)
    print(f"\n3. The real sets against the defaults of revision {revision}")
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", revision, "src"], check=True, capture_output=True)
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        old_json = Path(tmp) / "old.json"
        env = {**os.environ, "PYTHONPATH": str(Path(tmp) / "src"), "OPENBLAS_NUM_THREADS": "1"}
        subprocess.run([sys.executable, __file__, "--dump", str(old_json), *map(str, real.values())], check=True,
                       env=env)
        old = json.loads(old_json.read_text())
    print(f"{'set':10} {'models (old -> new)':44} {'checks':>8} {'max |delta|/sigma':>18}  parameter")
    rows, same_models, worst_all, lost, gained = [], True, 0.0, [], []
    for name, path in real.items():
        new = summary(*defaults(load_corners(path)))
        before = old[str(path)]
        worst, key = largest_change(before, new)
        models = before["models"] == new["models"]
        checks = before["checks"] == new["checks"]
        same_models &= models
        worst_all = max(worst_all, worst)
        lost += [f"{name} {c}" for c, ok in before["checks"].items() if ok and not new["checks"].get(c, True)]
        gained += [f"{name} {c}" for c, ok in before["checks"].items() if not ok and new["checks"].get(c, False)]
        print(f"{name:10} {str(new['models']) + ('' if models else ' (was ' + str(before['models']) + ')'):44} "
              f"{'same' if checks else 'DIFFER':>8} {worst:18.2g}  {key}")
        if not checks:
            print(f"{'':10} checks before {before['checks']}, now {new['checks']}")
    rows.append([f"real sets vs {revision}: same models", "yes" if same_models else "no", "yes",
                 "PASS" if same_models else "FAIL"])
    # a check that failed before and passes now is a change of the check itself (rig_rigid's test of issue 33
    # passes on the real stereo sample, as that issue asks), not of the calibration: listed, not a failure
    rows.append([f"real sets vs {revision}: checks passed before and failed now"
                 + (f" (failed before, pass now: {', '.join(gained)})" if gained else ""),
                 ", ".join(lost) or "none", "none", "FAIL" if lost else "PASS"])
    rows.append([f"real sets vs {revision}: max |delta| / sigma", f"{worst_all:.2g}", f"<= {BASELINE_TARGET_SIGMA:g}",
                 "PASS" if worst_all <= BASELINE_TARGET_SIGMA else "FAIL"])
    return rows


# ----------------------------------------------------------------------------- main


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one run each, note8 only, no baseline")
    parser.add_argument("--growth", action="store_true", help="also 13 and 200 instants and the paper's case")
    parser.add_argument("--processes", action="store_true", help="part 1 alone, at 50 instants")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--baseline", default="8ffbcf9", help="git revision whose defaults the real sets are held "
                                                               "against (default: main before issue 32's speed work)")
    parser.add_argument("--dump", nargs="+", metavar=("OUT", "CORNERS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.dump:
        dump(args.dump[0], args.dump[1:])
        return
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_calibrate import print_table

    runs = 1 if args.quick else args.runs
    presets = ("note8",) if args.quick else ("note8", "triple", "quad")
    sizes = (13, 50, 100, 200) if args.growth else (50,) if args.processes else (50, 100)
    t0 = time.perf_counter()
    rows = part_processes([(p, v) for p in presets for v in sizes], runs, args.growth)
    if args.processes:
        print_table("Summary", ["target", "value", "goal", "verdict"], rows)
        return
    with tempfile.TemporaryDirectory() as tmp:
        real = real_corners(Path(tmp))
        rows += part_recalibration(presets, runs, real)
        if not args.quick and real:
            rows += part_baseline(real, args.baseline)
    print_table("Summary", ["target", "value", "goal", "verdict"], rows)
    print(f"\ntotal benchmark time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
