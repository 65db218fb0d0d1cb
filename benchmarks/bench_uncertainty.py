"""Honest sigmas on real photos: the split-half test on the shared real sets.

For each real set of ``../shared/data`` (corners detected here by ``dualcal.detect_dataset``):
calibrate two disjoint random halves of the instants with the project's defaults, ``--splits``
times, and pool ``z = (p_A - p_B) / sqrt(s_A^2 + s_B^2)`` per kind of parameter
(:mod:`dualcal.estimation.validation`): ``sqrt(mean(z^2))`` is about 1 for honest sigmas, larger for sigmas
that are too small. Printed for dualcal's ``sigma`` (clustered by instant, never below the
textbook value) and ``sigma_formal`` (the textbook one, what OpenCV's ``calibrateCameraExtended``,
MATLAB and Bouguet report), side by side; the target for ``sigma`` is 0.7-1.5 for every kind.

For comparison the same splits are run with OpenCV's ``calibrateCameraExtended`` (k1 k2, one
camera at a time: its ``stdDeviationsIntrinsics``; OpenCV gives no sigma for a stereo rig's R, T).

Run from the repository root::

    .venv/bin/python benchmarks/bench_uncertainty.py                 # 100 splits per set, about 2 minutes
    .venv/bin/python benchmarks/bench_uncertainty.py --splits 20     # the issue's minimum, noisier

With 10-20 instants per set the splits are far from independent, so the pooled figure is itself
noisy: 20 splits move it by about +-0.3 from one seed to the next, 100 splits by less.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal.geometry.board import Board
from dualcal.files.dataset import open_dataset
from dualcal.files.detect import detect_dataset
from dualcal.geometry.model import observed_mask
from dualcal.estimation.validation import GROUPS, instants_of, pooled_spread, split_half_z

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SETS = {
    "opencv-samples-stereo": (["left=left*.jpg", "right=right*.jpg"], Board(9, 6, 30.0)),
    "bouguet-calib-example": (["cam=Image*.tif"], Board(12, 13, 30.0)),
    "huawei-y5-2017": ([], Board(7, 9, 30.0)),
}


def opencv_split_half(corners, splits: int, seed: int) -> dict[str, list[float]]:
    """The same split-half test with ``cv2.calibrateCameraExtended``'s intrinsic sigmas (k1 k2,
    fix k3 and tangential), every camera alone, on the corners every half's photos measured."""
    keys = instants_of(corners)
    rng = np.random.default_rng(seed)
    X = corners.board.object_points_mm().astype(np.float32)
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    z: dict[str, list[float]] = {}
    for _ in range(splits):
        order = rng.permutation(keys)
        half = len(keys) // 2
        results = []
        for part in (order[:half], order[half:]):
            per_cam = {}
            for name, cc in corners.cameras.items():
                views = [cc.views[k] for k in part if cc.views.get(k) is not None]
                obj = [X[observed_mask(uv)] for uv in views]
                img = [uv[observed_mask(uv)].astype(np.float32) for uv in views]
                out = cv2.calibrateCameraExtended(obj, img, cc.image_size, None, None, flags=flags)
                K, D, std = out[1], out[2], out[5].ravel()
                per_cam[name] = {"fx": (K[0, 0], std[0]), "fy": (K[1, 1], std[1]), "cx": (K[0, 2], std[2]),
                                 "cy": (K[1, 2], std[3]), "k1": (D.ravel()[0], std[4]), "k2": (D.ravel()[1], std[5])}
            results.append(per_cam)
        for name in corners.cameras:
            for group, params in GROUPS.items():
                for p in params:
                    (va, sa), (vb, sb) = results[0][name][p], results[1][name][p]
                    z.setdefault(group, []).append((va - vb) / np.hypot(sa, sb))
    return z


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splits", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    kinds = ("f", "c", "k", "baseline", "angles")
    print(f"split-half test, {args.splits} random splits per set: sqrt(mean z^2) per kind (honest: about 1; "
          "target for sigma 0.7-1.5)\n")
    print(f"{'set':24s} {'sigmas':22s} " + " ".join(f"{k:>9s}" for k in kinds) + "   time")
    for name, (globs, board) in SETS.items():
        folder = DATA / name
        if not folder.is_dir():
            print(f"{name:24s} (not found at {folder})")
            continue
        ds = open_dataset(folder, globs)
        corners = detect_dataset(ds, board, progress=False)
        t0 = time.perf_counter()
        z = split_half_z(corners, args.splits, args.seed)
        elapsed = time.perf_counter() - t0
        rows = [("dualcal sigma", pooled_spread(z["sigma"])), ("dualcal sigma_formal", pooled_spread(z["sigma_formal"])),
                ("OpenCV calibrateCamera", pooled_spread(opencv_split_half(corners, args.splits, args.seed)))]
        for i, (label, spread) in enumerate(rows):
            cells = " ".join(f"{spread[k]:9.2f}" if k in spread else f"{'-':>9s}" for k in kinds)
            print(f"{name if i == 0 else '':24s} {label:22s} {cells}" + (f"   {elapsed:.0f} s" if i == 0 else ""))
    print("\nOpenCV: calibrateCameraExtended per camera (k1 k2), its stdDeviationsIntrinsics; no sigma for a rig.")


if __name__ == "__main__":
    main()
