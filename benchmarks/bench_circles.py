"""Circle grids: the perspective bias of circle centres, OpenCV against dualcal, on 12 MP renders with known truth.

One camera of 4000 x 3000 pixels (fx = fy = 3200 px, k1 = 0.06, k2 = -0.15), an asymmetric grid acircles:4x11 of
20 mm spacing and ``--circle`` mm circles (default 12: large circles as on OpenCV's printed
``acircles_pattern.png``, where the bias shows most), rendered with :func:`dualcal.synthetic.render.render_view` (exact
box-filtering, blur 1.2 px, noise 1.2 %). Per band of tilts (0-15, 15-30, 30-45, 45-60 degrees off frontal;
``--views`` photos each, the board filling 35-65 % of the frame, seeds 2000+: held out, the tests use others):

* every photo's centres by OpenCV's ``findCirclesGrid`` at full size (its default blob detector with the largest blob
  raised to 1e6 px^2, as a 12 MP photo needs; its clustering variant where the plain one fails) and by dualcal
  (:func:`dualcal.files.detect.circles.detect_circles`); photos each found; centre RMS against the truth, the centre of
  each circle's image (:func:`dualcal.geometry.circles.outline_centroid_px`), and against the projected centre (what a
  point model takes it for: the bias);
* the focal length each gives against the truth: OpenCV's ``calibrateCamera`` on OpenCV's centres (k1, k2 only, no
  tangential terms: the truth's lens model), dualcal's adjustment on dualcal's centres as points (the point model),
  and with the outline model (:func:`dualcal.estimation.circle_centres.fit_circle_outlines`).

Figures for synthetic renders, not for real photos. Run::

    PYTHONPATH=src python benchmarks/bench_circles.py [--views 8] [--circle 12]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal.estimation.circle_centres import fit_circle_outlines
from dualcal.estimation.fitting import Setup
from dualcal.files.detect.circles import detect_circles
from dualcal.geometry.board import Board
from dualcal.geometry.camera import CameraModel, project_points
from dualcal.geometry.circles import outline_centroid_px
from dualcal.geometry.model import Pose
from dualcal.synthetic.render import render_view

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_circles import opencv_centres  # noqa: E402  (OpenCV as the tests run it)

CAMERA = CameraModel((4000, 3000), 3200.0, 3200.0, 0.0, 1990.0, 1510.0, 0.06, -0.15)
BANDS = ((0, 15), (15, 30), (30, 45), (45, 60))


def look_at(centre_mm, target_mm, roll) -> Pose:
    z = target_mm - centre_mm
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    R = np.vstack([c * x + s * y, -s * x + c * y, z])
    return Pose(R, -R @ centre_mm)


def poses_in_band(board: Board, band, views: int, seed: int) -> list[Pose]:
    """Board poses ``band`` degrees off frontal, the whole pattern in the frame, filling 35-65 % of it."""
    rng = np.random.default_rng(seed)
    x0, x1, y0, y1 = board.pattern_extent_mm()
    corners = np.array([[x0, y0, 0], [x1, y0, 0], [x0, y1, 0], [x1, y1, 0]], float)
    middle = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    extent = np.hypot(x1 - x0, y1 - y0)
    out = []
    while len(out) < views:
        tilt, azim = np.radians(rng.uniform(*band)), rng.uniform(0, 2 * np.pi)
        dist = CAMERA.fx * extent / (rng.uniform(0.35, 0.65) * max(CAMERA.image_size))
        direction = -np.array([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)])
        target = middle + np.append(rng.uniform(-0.1, 0.1, 2) * [x1 - x0, y1 - y0], 0.0)
        pose = look_at(target + dist * direction, target, rng.uniform(-np.pi, np.pi))
        uv = project_points(CAMERA, pose.apply(corners))
        if np.all(uv > 20) and np.all(uv < np.array(CAMERA.image_size) - 21):
            out.append(pose)
    return out


def matched(uv, truth):
    """``uv`` reordered to the truth's points (nearest neighbour: OpenCV's numbering may start elsewhere)."""
    d = np.hypot(*(uv[:, None] - truth[None]).transpose(2, 0, 1))
    return uv[np.argmin(d, axis=0)]


def rms(a, b) -> float:
    return float(np.sqrt(np.nanmean(np.sum((a - b) ** 2, axis=1))))


def opencv_fx(board, views) -> float:
    X = board.object_points_mm().astype(np.float32)
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    _, K, *_ = cv2.calibrateCamera([X] * len(views), [v.astype(np.float32) for v in views], CAMERA.image_size,
                                   None, None, flags=flags)
    return float(K[0, 0])


def dualcal_fx(board, views) -> tuple[float, float, int]:
    setup = Setup(board.object_points_mm(), ["cam"], [CAMERA.image_size], 0, False, "none", "k1k2")
    blocks = [(0, f"IMG_{i:02d}", uv) for i, uv in enumerate(views)]
    first = setup.solve(blocks)
    fit = fit_circle_outlines(lambda b, start: setup.solve(b, start), blocks, first, board)
    return (first.state.camera(first.problem, 0).fx, fit.solution.state.camera(fit.solution.problem, 0).fx,
            fit.iterations)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--circle", type=float, default=12.0)
    args = ap.parse_args()
    board = Board.circle_grid("acircles", 4, 11, 20.0, args.circle)
    print(f"{board.describe(sizes=True)}; camera {CAMERA.image_size[0]}x{CAMERA.image_size[1]}, fx {CAMERA.fx:g} px; "
          f"{args.views} renders per band (synthetic)")
    print(f"{'tilt deg':>9} {'found cv/ours':>13} {'bias px':>8} {'rms cv':>8} {'rms ours':>8} "
          f"{'t cv s':>7} {'t ours s':>8} {'fx err cv':>10} {'points':>8} {'outline':>8} {'solves':>6}")
    X = board.object_points_mm()
    for i, band in enumerate(BANDS):
        mine, theirs, bias, err_cv, err_ours, t_cv, t_ours = [], [], [], [], [], [], []
        for k, pose in enumerate(poses_in_band(board, band, args.views, 2000 + 100 * i)):
            img = render_view(CAMERA, pose, board, np.random.default_rng([2000 + i, k]))
            truth = outline_centroid_px(CAMERA, pose, X, 0.5 * board.circle_mm)
            projected = project_points(CAMERA, pose.apply(X))
            bias.append(rms(truth, projected))
            # taking turns: OpenCV first on even photos, dualcal first on odd ones
            runs = {}
            for who in (("cv", "ours") if k % 2 == 0 else ("ours", "cv")):
                t = time.perf_counter()
                if who == "cv":
                    runs[who] = opencv_centres(img, board)
                else:
                    try:
                        runs[who] = detect_circles(img, board)[0]
                    except Exception:                                   # not found: counted
                        runs[who] = None
                (t_cv if who == "cv" else t_ours).append(time.perf_counter() - t)
            if runs["cv"] is not None:
                theirs.append(matched(runs["cv"], truth))
                err_cv.append(rms(theirs[-1], truth))
            if runs["ours"] is not None:
                mine.append(runs["ours"])
                err_ours.append(rms(mine[-1], truth))
        fx_cv = opencv_fx(board, theirs) - CAMERA.fx if len(theirs) >= 3 else float("nan")
        fx_point, fx_outline, solves = dualcal_fx(board, mine) if len(mine) >= 3 else (np.nan, np.nan, 0)
        print(f"{band[0]:>4}-{band[1]:<4} {len(theirs):>6}/{len(mine):<6} {np.mean(bias):8.3f} "
              f"{np.sqrt(np.mean(np.square(err_cv))):8.4f} {np.sqrt(np.mean(np.square(err_ours))):8.4f} "
              f"{np.median(t_cv):7.2f} {np.median(t_ours):8.2f} {fx_cv:+10.3f} {fx_point - CAMERA.fx:+8.3f} "
              f"{fx_outline - CAMERA.fx:+8.3f} {solves:>6}")
    print("bias px: RMS of (image centre - projected centre); rms: centres vs the image centres; fx err: px vs truth "
          "(cv: OpenCV's calibrateCamera on its centres; points: dualcal on its centres as points; outline: with the "
          "bias corrected)")


if __name__ == "__main__":
    main()
