"""Known intrinsics as priors (issue 39): the staged calibration of a rig over many seeds.

Every camera of a synthetic rig (``note8``, ``stereo``; ``make_truth`` seeds 8000+, which the tests do not use) is
calibrated from 12 instants of its own, then the rig from ``J`` joint instants (5 and 10) with those intrinsics as
priors (``calibrate_rig(known_intrinsics=...)``). Printed per rig and ``J``:

* the spread of error / sigma of the rig's translation and angles over the seeds (target 0.7-1.4), and of the
  intrinsics (the priors as the photos moved them);
* the share of calibrations whose ``intrinsics_prior`` check fails, with its 95 % Wilson interval (stated rate:
  1 % per calibration; the lenses did not change);
* the share that names the tele (or the right camera) when its focal length changed by 0.5, 1 and 2 % between
  its own photos and the rig's.

Run from the repository root::

    .venv/bin/python benchmarks/bench_calibrate_known.py              # 40 seeds, a few minutes
    .venv/bin/python benchmarks/bench_calibrate_known.py --seeds 10   # a quick look
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_known_intrinsics import _rig_z, known_of, only  # noqa: E402

from dualcal.estimation.calibrate import calibrate_rig  # noqa: E402
from dualcal.progress import collect_warnings  # noqa: E402
from dualcal.synthetic.synth import make_truth, noisy_corner_set  # noqa: E402


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson interval of a share ``k / n``."""
    p = k / n
    centre, half = (p + z * z / (2 * n)) / (1 + z * z / n), z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (
        1 + z * z / n)
    return max(centre - half, 0.0), min(centre + half, 1.0)


def staged(preset: str, seed: int, joint: int, focal_change: float = 0.0):
    """Each camera from 12 instants of its own, then the rig from ``joint`` instants with them as priors, the
    second camera's focal length changed by ``focal_change`` in between: ``(truth, rig)``."""
    truth = make_truth(preset, joint, seed=seed)
    known = {}
    with collect_warnings():
        for k, name in enumerate(sorted(truth.cameras)):
            own = make_truth(preset, 12, seed=seed + 100 + k)
            known[name] = known_of(calibrate_rig(only(noisy_corner_set(own, 0.1, seed=seed + 200 + k), [name]),
                                                 model="k1k2"), name)
        changed = [n for n in truth.cameras if n != truth.reference][0]
        cam = truth.cameras[changed]
        truth.cameras[changed] = replace(cam, fx=cam.fx * (1 + focal_change), fy=cam.fy * (1 + focal_change))
        rig = calibrate_rig(noisy_corner_set(truth, 0.1, seed=seed + 300), known_intrinsics=known)
    return truth, rig, changed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=40)
    args = ap.parse_args()
    print(f"staged calibration, {args.seeds} seeds per case: each camera from 12 instants of its own, then the rig "
          "from J joint instants with them as priors\n")
    print(f"{'rig':7s} {'J':>3s} {'rig z spread':>13s} {'intrinsics z':>13s} {'false alarms':>13s} {'95 % interval':>15s}"
          f"   named when the focal length changed by 0.5 / 1 / 2 %   time")
    for p, preset in enumerate(("note8", "stereo")):
        for joint in (5, 10):
            t0 = time.perf_counter()
            rig_z, intr_z, alarms = [], [], 0
            named = {0.005: 0, 0.01: 0, 0.02: 0}
            for s in range(args.seeds):
                seed = 8000 + 1000 * p + 10 * s
                truth, rig, changed = staged(preset, seed, joint)
                rig_z.append(_rig_z(rig, truth))
                intr_z += [(getattr(c, q) - getattr(truth.cameras[n], q)) / rig.camera_sigma[n][q]
                           for n, c in rig.cameras.items() for q in ("fx", "fy", "cx", "cy", "k1", "k2")]
                alarms += not rig.checks["intrinsics_prior"]["ok"]
                for change in named:
                    check = staged(preset, seed, joint, change)[1].checks["intrinsics_prior"]
                    named[change] += check["flagged"] == [changed]
            lo, hi = wilson(alarms, args.seeds)
            z = np.concatenate(rig_z)
            print(f"{preset:7s} {joint:3d} {np.sqrt(np.mean(z ** 2)):13.2f} {np.sqrt(np.mean(np.square(intr_z))):13.2f} "
                  f"{100 * alarms / args.seeds:12.1f}% {100 * lo:6.1f}-{100 * hi:5.1f} %   "
                  + " / ".join(f"{100 * k / args.seeds:5.0f} %" for k in named.values())
                  + f"   {time.perf_counter() - t0:5.0f} s")


if __name__ == "__main__":
    main()
