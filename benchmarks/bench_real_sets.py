"""The real sets of ../shared/data as one table: boards found by dualcal and by OpenCV, parameters, verdict.

For every set of ``tests/realsets.py``: the photos, the boards dualcal finds against OpenCV's classic detector and its
SB detector (full resolution), the corners the calibration kept, each camera's lens model and parameters with their
sigmas, the rig's baseline and angles, the checks that fail; then what moved against the pinned table of the guard
(``tests/data/real_sets.json``, tests/test_real_guard.py), in sigmas.

    .venv/bin/python benchmarks/bench_real_sets.py          # the table and what moved (a few minutes: OpenCV's SB)
    .venv/bin/python benchmarks/bench_real_sets.py --pin    # ... and pin the table for the guard
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import realsets  # noqa: E402

PINNED = ROOT / "tests" / "data" / "real_sets.json"
#: The guard fails a parameter that moves by more than this share of its pinned sigma.
SHARE_OF_SIGMA = 0.25


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pin", action="store_true", help="write the table to tests/data/real_sets.json for the guard")
    args = ap.parse_args()
    pinned = json.loads(PINNED.read_text()) if PINNED.exists() else {"sets": {}}
    table = {}
    for real in realsets.REAL_SETS:
        if not real.folder.is_dir():
            print(f"{real.name}: not present at {real.folder}: skipped")
            continue
        corners = realsets.detect(real)
        row = realsets.summarise(corners, realsets.calibrate(real, corners))
        opencv = {cam: realsets.opencv_boards_found(paths, real.board) for cam, paths in real.photo_paths().items()}
        table[real.name] = {"row": row, "opencv_boards": opencv}
        print(f"\n## {real.name}")
        print("| camera | photos | boards dualcal | OpenCV classic | OpenCV SB | corners kept | model | "
              + " | ".join(realsets.CAMERA_KEYS) + " |")
        print("|" + " --- |" * (7 + len(realsets.CAMERA_KEYS)))
        for name, cam in row["cameras"].items():
            cv = opencv.get(name, {"classic": "-", "sb": "-"})
            values = " | ".join(f"{v:.5g} +- {s:.2g}" if s is not None else f"{v:.5g}"
                                for v, s in (cam[k] for k in realsets.CAMERA_KEYS))
            print(f"| {name} | {cam['photos']} | {cam['boards']} | {cv['classic']} | {cv['sb']} | {cam['corners']} | "
                  f"{cam['model']} | {values} |")
        for name, rel in row["rig"].items():
            opk = ", ".join(f"{a:.2f} +- {s:.2f}" for a, s in rel["opk_arcmin"])
            print(f"rig {name}: baseline {rel['baseline_mm'][0]:.3f} +- {rel['baseline_mm'][1]:.3f} mm, "
                  f"omega-phi-kappa [{opk}] arcmin")
        print(f"checks that fail: {', '.join(row['failed_checks']) or 'none'}")
        was = pinned["sets"].get(real.name)
        if was is not None:
            moved = realsets.differences(was["row"], row, SHARE_OF_SIGMA)
            print("against the pinned table: " + ("nothing moved" if not moved else "; ".join(moved)))
    if args.pin:
        PINNED.write_text(json.dumps({"share_of_sigma": SHARE_OF_SIGMA, "sets": table}, indent=1) + "\n")
        print(f"\npinned: {PINNED}")


if __name__ == "__main__":
    main()
