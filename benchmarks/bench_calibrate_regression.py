"""The calibration's regression harness: every result of a revision recorded, and compared with another's.

A change meant to leave the calibration's results as they are (a new shape of the code, a faster path) is
checked by recording the results of one revision and comparing those of another on the same inputs:

* the synthetic presets (``tests/calib_regression.py``'s :data:`SYNTHETIC_CASES`: ``stereo``, ``note8``,
  ``triple``, ``phone3`` under ``--model auto`` and fixed, rig modes ``rigid``, ``paper`` and ``none``, skew
  on and off, the board's shape ``auto`` and ``fit``, with outliers, a desynchronised instant, a refocused
  photo and a moved board planted), and the four-camera rig of ``bench_calibrate.py`` (``quad``);
* the shared real sets: ``opencv-samples-stereo`` as a rig, ``bouguet-calib-example`` and ``huawei-y5-2017``
  alone (their corners detected here, or read from ``--corners DIR`` where an earlier run saved them, so that a
  change of the detection does not pass for one of the calibration).

Every parameter and sigma is compared (within ``--tol`` of its sigma; default 1e-6), with the joint
covariance, the fit, the photos and corners left out, the lens models chosen and every check's verdict and
what it names (``tests/calib_regression.py``'s :func:`differences`). Each case's time is printed beside the
reference's (noisy on a shared machine: a hint, not a measurement).

Run from the repository root::

    .venv/bin/python benchmarks/bench_calibrate_regression.py record /tmp/before.json   # on the old revision
    .venv/bin/python benchmarks/bench_calibrate_regression.py compare /tmp/before.json  # on the new one
    .venv/bin/python benchmarks/bench_calibrate_regression.py test-data                 # the suite's references

``test-data`` writes ``tests/data/calibrate_regression.json``: the few cases ``tests/test_calibrate_regression.py``
compares in every run of the suite (a few seconds), with the real stereo rig's corners (rounded to 0.001 px), so
that the test needs neither the photos nor the detection. Run it only on main's code: its references are what the
calibration must keep giving.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from calib_regression import (SYNTHETIC_CASES, _case, differences, largest_shift_sigma, summary,  # noqa: E402
                              synthetic_corners)

from dualcal.errors import DualcalError  # noqa: E402
from dualcal.estimation.calibrate import calibrate_rig  # noqa: E402
from dualcal.files.io import corners_from_dict, corners_to_dict, load_corners, save_corners  # noqa: E402
from dualcal.geometry.board import Board  # noqa: E402
from dualcal.progress import collect_warnings  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
TEST_DATA = ROOT / "tests" / "data" / "calibrate_regression.json"

#: The real sets: ``{name: (folder, patterns or None, board)}`` as tests/test_real_data.py detects them.
REAL_SETS = {
    "stereo": ("opencv-samples-stereo", ["left=left*.jpg", "right=right*.jpg"], Board(9, 6, 30.0)),
    "bouguet": ("bouguet-calib-example", ["cam={folder}/Image*.tif"], Board(12, 13, 30.0)),
    "huawei": ("huawei-y5-2017", None, Board(7, 9, 30.0)),
}
REAL_CASES = [
    *({"name": f"real-stereo-{m}-{r}{'-skew' if s else ''}", "real": "stereo",
       "options": {"model": m, "rig_mode": r, "skew": s}}
      for m, r, s in (("auto", "rigid", False), ("k1k2", "paper", False), ("auto", "none", False),
                      ("k1k2", "rigid", True), ("k1k2p1p2k3", "rigid", False))),
    *({"name": f"real-{n}-{m}{'-skew' if s else ''}", "real": n, "options": {"model": m, "skew": s}}
      for n in ("bouguet", "huawei") for m, s in (("auto", False), ("k1k2", True))),
]
QUAD_CASES = [{**_case("quad", 12, 7, 0.1, model=m, rig_mode=r, skew=False), "quad": True}
              for m, r in (("auto", "rigid"), ("k1k2", "paper"), ("k1k2", "none"))]
#: The cases the suite compares (tests/test_calibrate_regression.py): a few seconds in all.
TEST_CASES = ("stereo-12-model=auto-rig_mode=rigid-skew=False", "note8-12-model=k1k2-rig_mode=paper-skew=True",
              "triple-12-model=auto-rig_mode=none-skew=False",
              "stereo-12-model=auto-rig_mode=rigid-skew=False-outliers",
              "note8-13-model=k1k2-rig_mode=rigid-skew=False-desync",
              "triple-12-model=auto-rig_mode=rigid-skew=False-desync", "real-stereo-auto-rigid")


def real_corners(name: str, cache: Path | None):
    """The corners of real set ``name``: from ``cache/<name>.json`` where there, else detected (and saved there)."""
    if cache is not None and (cache / f"{name}.json").exists():
        return load_corners(cache / f"{name}.json")
    from dualcal.files.dataset import open_dataset
    from dualcal.files.detect import detect_dataset

    folder, patterns, board = REAL_SETS[name]
    absolute = patterns is not None and any("{folder}" in p for p in patterns)
    if absolute:
        patterns = [p.format(folder=DATA / folder) for p in patterns]
    dataset = open_dataset(None if absolute else DATA / folder, *([patterns] if patterns else []))
    corners = detect_dataset(dataset, board, jobs=2, progress=False)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        save_corners(cache / f"{name}.json", corners)
    return corners


def case_corners(case: dict, cache: Path | None):
    if "real" in case:
        return real_corners(case["real"], cache)
    truth = None
    if case.get("quad"):
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from bench_calibrate import quad_truth as truth
    return synthetic_corners(case["preset"], case["views"], case["seed"], case["noise_px"], case["plant"], truth)


def run(cases, cache: Path | None, extra: dict | None = None) -> dict:
    out = {}
    for case in cases:
        corners = case_corners(case, cache)
        t0 = time.perf_counter()
        try:
            with collect_warnings():
                result = summary(calibrate_rig(corners, **case["options"], **(extra or {})))
        except DualcalError as exc:             # a refusal is a result too
            result = {"error": str(exc)}
        out[case["name"]] = {"case": case, "seconds": time.perf_counter() - t0, "summary": result}
        print(f"{case['name']:<70} {out[case['name']]['seconds']:6.2f} s", flush=True)
    return out


def all_cases(quick: bool) -> list[dict]:
    real = [c for c in REAL_CASES if (DATA / REAL_SETS[c["real"]][0]).is_dir()]
    cases = SYNTHETIC_CASES + QUAD_CASES + real
    return [c for c in cases if c["name"] in TEST_CASES] if quick else cases


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("action", choices=("record", "compare", "test-data"))
    ap.add_argument("file", nargs="?", type=Path, help="the record to write or to compare with")
    ap.add_argument("--corners", type=Path, default=Path("/tmp/dualcal-regression-corners"),
                    help="where the real sets' corners are kept between runs")
    ap.add_argument("--quick", action="store_true", help="only the suite's cases")
    ap.add_argument("--tol", type=float, default=1e-6, help="tolerance, in sigmas (default 1e-6)")
    ap.add_argument("--unweighted", action="store_true",
                    help="calibrate with weigh_photos=False (every photo alike: the calibration before issue 38)")
    args = ap.parse_args(argv)
    if args.action == "test-data":
        cases = [c for c in SYNTHETIC_CASES + REAL_CASES if c["name"] in TEST_CASES]
        unweighted = {"weigh_photos": False}          # as the test compares them: every photo alike
        results = run(cases, args.corners, unweighted)
        doc = {"about": "References of tests/test_calibrate_regression.py, made by "
                        "benchmarks/bench_calibrate_regression.py test-data on main's code; the real stereo rig's "
                        "corners rounded to 0.001 px",
               "corners": {"stereo": _rounded(corners_to_dict(real_corners("stereo", args.corners)))},
               "cases": {name: {"case": r["case"], "summary": r["summary"]} for name, r in results.items()}}
        stored = corners_from_dict(doc["corners"]["stereo"])
        for r in doc["cases"].values():
            if r["case"].get("real") == "stereo":         # the references are those of the rounded corners
                with collect_warnings():
                    r["summary"] = summary(calibrate_rig(stored, **r["case"]["options"], **unweighted))
            del r["summary"]["covariance"]                # the sigmas stand for it here: the file stays small
        TEST_DATA.write_text(json.dumps(doc, separators=(",", ":")) + "\n")
        print(f"wrote {TEST_DATA} ({TEST_DATA.stat().st_size // 1024} KB)")
        return 0
    if args.file is None:
        ap.error("record and compare need a file")
    if args.action == "record":
        results = run(all_cases(args.quick), args.corners)
        args.file.write_text(json.dumps(results))
        print(f"recorded {len(results)} calibrations in {args.file}")
        return 0
    ref = json.loads(args.file.read_text())
    results = run([r["case"] for r in ref.values() if not args.quick or r["case"]["name"] in TEST_CASES],
                  args.corners, {"weigh_photos": False} if args.unweighted else None)
    failed = 0
    print(f"\n{'case':<70} {'old s':>7} {'new s':>7} {'moved':>8}  differences beyond {args.tol:g} sigma")
    for name, r in results.items():
        diff = differences(ref[name]["summary"], r["summary"], args.tol)
        failed += bool(diff)
        moved = largest_shift_sigma(ref[name]["summary"], r["summary"]) if "values" in r["summary"] else 0.0
        print(f"{name:<70} {ref[name]['seconds']:7.2f} {r['seconds']:7.2f} {moved:8.2g}  {len(diff) or 'none'}")
        for line in diff[:12]:
            print(f"    {line}")
    total_old = sum(ref[n]["seconds"] for n in results)
    total_new = sum(r["seconds"] for r in results.values())
    print(f"\n{len(results) - failed} of {len(results)} calibrations the same; time {total_new:.1f} s against "
          f"{total_old:.1f} s recorded ({total_new / total_old:.2f} x; not taken in turns: a hint only)")
    return 1 if failed else 0


def _rounded(doc):
    """``doc`` with every float rounded to 0.001 (the stored corners)."""
    if isinstance(doc, float):
        return round(doc, 3)
    if isinstance(doc, list):
        return [_rounded(x) for x in doc]
    if isinstance(doc, dict):
        return {k: _rounded(v) for k, v in doc.items()}
    return doc


if __name__ == "__main__":
    raise SystemExit(main())
