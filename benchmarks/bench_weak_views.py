"""Weak views as peers record them: every webcam session calibrated alone, dualcal beside OpenCV in the same run.

Sessions of tests/peer_sessions.py (synthetic, known truth): one of caliscope's four webcams (1280 x 720, OpenCV's five
coefficients, k1 from -0.33 to +0.03), its 12-corner ChArUco board 5-15 % of the frame wide, anywhere in it (4-12
corners seen), tilted 0-40 degrees, 20-50 views, 0.3 px of noise. For each: dualcal's start (``initial_camera``: its fx
against the truth), its calibration (``--rig none``, the true lens model): calibrated or not, converged or not, fx
against the truth in per cent and in its sigmas; OpenCV's ``calibrateCamera`` with the same lens model on the same
corners (its own start, ``initIntrinsicParams2D``). Then sessions whose boards are all seen square-on near the middle
of the frame (no perspective: no focal length): how many dualcal refuses in one line, and OpenCV's fx.

    .venv/bin/python benchmarks/bench_weak_views.py              # 40 sessions and 20 square-on ones (about 2 min)
    .venv/bin/python benchmarks/bench_weak_views.py --seeds 60
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from peer_sessions import WEBCAMS, peer_session, square_on_session  # noqa: E402

from dualcal.errors import EstimationError  # noqa: E402
from dualcal.geometry.model import observed_mask  # noqa: E402
from dualcal.geometry.homography import MIN_HOMOGRAPHY_CORNERS, spans_a_plane  # noqa: E402
from dualcal.geometry.zhang import initial_camera  # noqa: E402
from dualcal.progress import collect_warnings  # noqa: E402
from dualcal.synthetic.synth import noisy_corner_set  # noqa: E402
from dualcal.workflow import calibrate_corners  # noqa: E402

NOISE_PX = 0.3
MODEL = "k1k2p1p2k3"


def _usable(corners, xy) -> dict:
    return {k: uv for k, uv in corners.found().items()
            if observed_mask(uv).sum() >= MIN_HOMOGRAPHY_CORNERS and spans_a_plane(xy[observed_mask(uv)])}


def _opencv_fx(views: dict, X, image_size) -> float:
    """OpenCV's ``calibrateCamera`` (five coefficients, its own start) on the views' corners; NaN where it fails."""
    import cv2

    objects = [X[observed_mask(uv)].astype(np.float32) for uv in views.values()]
    images = [uv[observed_mask(uv)].astype(np.float32) for uv in views.values()]
    try:
        _, K, *_ = cv2.calibrateCamera(objects, images, tuple(image_size), None, None)
    except cv2.error:
        return float("nan")
    return float(K[0, 0])


def _dualcal(corners, cam):
    """``(start fx, fx, sigma fx, outcome)``: outcome ``ok``, ``not converged`` or the error."""
    xy = corners.board.object_points_mm()[:, :2]
    with collect_warnings():
        try:
            start = initial_camera(xy, _usable(corners.cameras["cam"], xy), cam.image_size)[0].fx
        except (EstimationError, np.linalg.LinAlgError):
            start = float("nan")
        try:
            rig = calibrate_corners(corners, rig_mode="none", model=MODEL, compare_lens=False)
        except (EstimationError, np.linalg.LinAlgError) as exc:       # the second: a traceback, before this closed form
            return start, float("nan"), float("nan"), str(exc)
    outcome = "ok" if rig.adjustment["converged"] else "not converged"
    return start, rig.cameras["cam"].fx, rig.camera_sigma["cam"]["fx"], outcome


def _summary(name: str, errors: list[float], z: list[float], done: int, total: int, verb: str = "calibrated") -> str:
    e = np.abs(np.array(errors, float))
    e = e[np.isfinite(e)]
    line = f"{name}: {verb} {done} of {total}"
    if len(e):
        line += f"; |fx error| median {100 * np.median(e):.1f} %, max {100 * np.max(e):.1f} %"
    if z:
        line += f"; |fx - truth| > 3 sigma: {int(np.sum(np.abs(z) > 3))}"
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40, help="peer-like sessions (default 40)")
    ap.add_argument("--square-on", type=int, default=20, help="sessions of boards all seen square-on (default 20)")
    args = ap.parse_args()
    print("| seed | views | lens k1 | start fx % | dualcal fx % | z | outcome | OpenCV fx % |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    starts, ours, z, theirs, converged, calibrated, opencv_ok = [], [], [], [], 0, 0, 0
    for seed in range(args.seeds):
        cam = WEBCAMS[seed % len(WEBCAMS)]
        truth = peer_session(cam, 20 + seed % 31, seed)
        corners = noisy_corner_set(truth, NOISE_PX, seed)
        start, fx, sigma, outcome = _dualcal(corners, cam)
        xy = truth.board.object_points_mm()
        f_cv = _opencv_fx(_usable(corners.cameras["cam"], xy[:, :2]), xy, cam.image_size)
        starts.append(start / cam.fx - 1)
        theirs.append(f_cv / cam.fx - 1)
        opencv_ok += bool(np.isfinite(f_cv))
        if np.isfinite(fx):
            calibrated += 1
            converged += outcome == "ok"
            ours.append(fx / cam.fx - 1)
            z.append((fx - cam.fx) / sigma)
        print(f"| {seed} | {len(truth.view_poses)} | {cam.k1:+.3f} | {100 * starts[-1]:+.1f} | "
              f"{100 * (fx / cam.fx - 1):+.1f} | {(fx - cam.fx) / sigma:+.1f} | {outcome[:60]} | {100 * theirs[-1]:+.1f} |")
    print()
    print(_summary("dualcal's start", starts, [], int(np.isfinite(starts).sum()), args.seeds, "started"))
    print(_summary("dualcal", ours, z, calibrated, args.seeds) + f"; converged {converged}")
    print(_summary("OpenCV calibrateCamera", theirs, [], opencv_ok, args.seeds))
    refused, cv_square = 0, []
    for seed in range(args.square_on):
        cam = WEBCAMS[2]
        corners = noisy_corner_set(square_on_session(cam, seed), NOISE_PX, seed)
        *_, outcome = _dualcal(corners, cam)
        refused += "fix no focal length" in outcome
        xy = corners.board.object_points_mm()
        cv_square.append(_opencv_fx(_usable(corners.cameras["cam"], xy[:, :2]), xy, cam.image_size) / cam.fx - 1)
    e = np.abs(np.array(cv_square))
    print(f"\nboards all square-on ({args.square_on} sessions): dualcal refuses {refused} in one line; OpenCV returns an "
          f"fx in {int(np.isfinite(e).sum())}, |fx error| median {100 * np.nanmedian(e):.0f} %")


if __name__ == "__main__":
    main()
