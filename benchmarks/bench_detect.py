"""Chessboard detection: dualcal against OpenCV on 12 MP photo-like renders with known truth.

Renders 13 views of the ``note8`` wide + tele rig (26 photos of 3024 x 4032) into a temporary
folder, then per camera (photo set):

* dualcal as shipped: :func:`dualcal.detect.detect_dataset` over the set with its default of
  all cores (wall time, process start-up included);
* dualcal in one process, one photo after the other (:func:`dualcal.detect.detect_photo`);
* OpenCV as a user would run it, one photo after the other: ``cv2.imread`` at full
  resolution, ``findChessboardCorners`` on the full image, then ``cornerSubPix``
  (11 x 11 window, 30 iterations, eps 0.001);
* the floor: one full-resolution ``cv2.imread`` per photo.

It prints wall times, the ratios dualcal / OpenCV (target <= 0.5, for dualcal as shipped) and
the corner RMS error against the truth (dualcal's must be <= 0.03 px; OpenCV's corners are
matched to the truth by nearest neighbour, since its order differs). Exit code 1 if a target
is missed.

    .venv/bin/python benchmarks/bench_detect.py [--views 13] [--seed 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal.dataset import open_dataset
from dualcal.detect import detect_dataset, detect_photo
from dualcal.render import write_photo_set
from dualcal.synth import make_truth, true_corners


def _rms(uv, truth):
    return float(np.sqrt(np.mean(np.sum((uv - truth) ** 2, axis=1))))


def _opencv(path: Path, cols: int, rows: int):
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(img, (cols, rows),
                                               cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    return cv2.cornerSubPix(img, corners, (11, 11), (-1, -1), crit).reshape(-1, 2).astype(float)


def _nearest_order(uv, truth):
    d = np.linalg.norm(uv[:, None, :] - truth[None, :, :], axis=2)
    return truth[np.argmin(d, axis=1)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=13)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, default=None, help="render into this folder and keep it")
    args = ap.parse_args(argv)

    truth = make_truth("note8", views=args.views, seed=args.seed)
    tc = true_corners(truth)
    root = args.keep or Path(tempfile.mkdtemp(prefix="dualcal-bench-"))
    t0 = time.perf_counter()
    paths = write_photo_set(truth, root, seed=args.seed)
    print(f"rendered {sum(len(v) for v in paths.values())} photos of "
          f"{'x'.join(map(str, truth.cameras['wide'].image_size))} in {time.perf_counter() - t0:.1f} s ({root})",
          file=sys.stderr)

    b = truth.board
    header = (f"{'set':5} {'photos':>6} {'dualcal s':>9} {'1 proc s':>9} {'OpenCV s':>9} {'decode s':>9} "
              f"{'ratio':>6} {'1 proc':>7} {'dualcal RMS px':>15} {'OpenCV RMS px':>14} {'found d/o':>9}")
    print(header)
    print("-" * len(header))
    ok = True
    for cam, views in paths.items():
        t = time.perf_counter()
        shipped = detect_dataset(open_dataset(root / cam), b, progress=False)
        t_ship = time.perf_counter() - t
        t_d = t_o = t_dec = 0.0
        err_d, err_o, found_o = [], [], 0
        for view, path in views.items():
            t = time.perf_counter()
            cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            t_dec += time.perf_counter() - t

            t = time.perf_counter()
            res = detect_photo(path, b)
            t_d += time.perf_counter() - t
            assert res.uv is None or np.allclose(res.uv, shipped.cameras[cam].views[view])

            t = time.perf_counter()
            uv = _opencv(path, b.cols, b.rows)
            t_o += time.perf_counter() - t
            if uv is not None:
                found_o += 1
                err_o.append(uv - _nearest_order(uv, tc[cam][view]))
        found = shipped.cameras[cam].found()
        err_d = [uv - tc[cam][v] for v, uv in found.items()]
        n = len(views)
        rms_d = _rms(np.concatenate(err_d), 0.0) if err_d else float("nan")
        rms_o = _rms(np.concatenate(err_o), 0.0) if err_o else float("nan")
        ratio, ratio_1 = t_ship / t_o, t_d / t_o
        print(f"{cam:5} {n:6d} {t_ship:9.2f} {t_d:9.2f} {t_o:9.2f} {t_dec:9.2f} {ratio:6.2f} {ratio_1:7.2f} "
              f"{rms_d:15.4f} {rms_o:14.4f} {len(found):>4}/{found_o:<4}")
        ok &= ratio <= 0.5 and rms_d <= 0.03 and len(found) == n
    print(f"dualcal = detect_dataset with all {os.cpu_count()} cores; 1 proc = the same, one photo after "
          "the other in one process; ratio = dualcal / OpenCV")
    print("targets (ratio <= 0.5, dualcal RMS <= 0.03 px, every board found):", "met" if ok else "MISSED")
    if args.keep is None:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
