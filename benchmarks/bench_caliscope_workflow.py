"""A caliscope user's workflow over many seeds (issue 39): ``import caliscope`` of a session, then the rig calibrated
with the session's intrinsics held (``calibrate --intrinsics``).

Sessions of :func:`dualcal.synthetic.synth_caliscope.make_caliscope_truth` (synthetic, known truth: four webcams of
1280 x 720 on an arc 2 m from the capture volume, caliscope's 12-corner ChArUco board, 57 moments, 0.3 px of corner
noise), written in caliscope's layout (``camera_array.toml`` with the true intrinsics), read back by
:func:`dualcal.files.imports.read_caliscope` and calibrated by :func:`dualcal.estimation.calibrate.calibrate_rig`
with the imported intrinsics, as the CLI does. Printed: over the seeds, each camera's error / sigma of its
translation (mm) and angles (omega-phi-kappa, arcmin) against the truth (their mean and spread; target spread
0.7-1.4), and how often each check fails (every check states a false-alarm rate of 1 % per calibration, or a fixed
limit).

    .venv/bin/python benchmarks/bench_caliscope_workflow.py [--seeds 20] [--noise 0.3]
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.files.imports import read_caliscope
from dualcal.progress import collect_warnings
from dualcal.synthetic.synth_caliscope import make_caliscope_truth, write_caliscope_session


def one_session(seed: int, noise_px: float, folder: Path) -> tuple[list[float], list[str]]:
    """The z values (error / sigma) of every camera's t and omega-phi-kappa, and the checks that failed."""
    truth = write_caliscope_session(folder, make_caliscope_truth(seed=seed), noise_px=noise_px, seed=seed)
    imported = read_caliscope(folder)
    with collect_warnings():
        rig = calibrate_rig(imported.corners, known_intrinsics=imported.cameras, model="auto")
    z = []
    for name, pose in truth.rig.items():
        got = rig.rig[name]
        z += list((got.pose.t_mm - pose.t_mm) / got.sigma_t_mm)
        z += list((got.pose.opk_arcmin - pose.opk_arcmin) / got.sigma_opk_arcmin)
    return z, [name for name, check in rig.checks.items() if not check.get("ok", True)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--noise", type=float, default=0.3, help="corner noise, px per coordinate")
    args = parser.parse_args(argv)
    zs, failed = [], Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            z, bad = one_session(seed, args.noise, Path(tmp) / f"s{seed}")
            zs.append(z)
            failed.update(bad)
            print(f"seed {seed:2d}: |z| largest {np.max(np.abs(z)):.2f}; checks failing: {', '.join(bad) or 'none'}")
    z = np.concatenate(zs)
    print(f"\n{args.seeds} sessions, {len(z)} values (t and omega-phi-kappa of cam_1..cam_3): z mean {z.mean():+.2f}, "
          f"spread {z.std():.2f} (target 0.7-1.4), largest |z| {np.abs(z).max():.2f}")
    for name, count in sorted(failed.items()):
        print(f"check {name} failed in {count} of {args.seeds}")
    if not failed:
        print("no check failed in any session")
    return 0 if 0.7 <= z.std() <= 1.4 else 1


if __name__ == "__main__":
    raise SystemExit(main())
