"""Lens models on the real stereo set: fit RMS and parameters per model, against Bouguet and OpenCV.

The real set is ``../shared/data/opencv-samples-stereo`` (Bouguet's stereo example 5, 13 pairs of
640x480 photos, 9x6 inner corners of 30 mm; its SOURCE.md lists the references). Corners are
detected once by dualcal; then, on exactly those corners,

* dualcal ``calibrate_rig(corners, rig_mode="rigid", reference="left", model=M)`` for every lens
  model ``M`` (the joint adjustment of both cameras and the rig, as Bouguet's stereo optimisation);
* OpenCV ``cv2.calibrateCamera`` per camera with the flags of the same model (``CALIB_FIX_K3``,
  ``CALIB_ZERO_TANGENT_DIST`` where the model lacks them), then ``cv2.stereoCalibrate`` with
  ``CALIB_USE_INTRINSIC_GUESS`` and the same flags: the same maximum-likelihood problem, solved by
  another program.

Printed per model: the fit (RMS of the 2-D residual per corner, per camera and overall; s0, the
a-posteriori sigma of one coordinate), every camera's parameters with dualcal's 1-sigma, OpenCV's
on the same corners, and Bouguet's published joint stereo result (``kc = [k1 k2 p1 p2 k3]``, k3
fixed at 0, his uncertainties about 3 sigma, from 14 pairs where OpenCV's copy has 13; his cc
as published: whether his pixels are 0- or 1-based is not verified, SOURCE.md). The RMS says which model the data favour as a fit; it always falls as
coefficients are added, so compare the fall with what noise alone gives: for ``q`` more unknowns
in ``n`` observations, s0 would fall by about a factor ``sqrt((n - p) / (n - p - q))`` if they
explained nothing. (Cross-validation is the honest comparison; this is the fit only.)

Run from the repository root::

    .venv/bin/python benchmarks/bench_lens_models.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from dualcal.board import Board
from dualcal.calibrate import calibrate_rig
from dualcal.camera import LENS_MODELS
from dualcal.dataset import open_dataset
from dualcal.detect import detect_dataset

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "opencv-samples-stereo"

#: Bouguet's joint stereo optimisation (SOURCE.md): fc, cc (as published), kc = k1 k2 p1 p2 k3.
BOUGUET = {"left": {"fx": 533.52331, "fy": 533.52699, "cx": 341.60376, "cy": 235.19287,
                    "k1": -0.28838, "k2": 0.09714, "p1": 0.00109, "p2": -0.00030, "k3": 0.0},
           "right": {"fx": 536.81377, "fy": 536.47649, "cx": 326.28657, "cy": 250.10121,
                     "k1": -0.28943, "k2": 0.10690, "p1": -0.00059, "p2": 0.00014, "k3": 0.0}}
PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def _opencv_flags(model: str) -> int:
    names = LENS_MODELS[model]
    flags = 0 if "k3" in names else cv2.CALIB_FIX_K3
    return flags if "p1" in names else flags | cv2.CALIB_ZERO_TANGENT_DIST


def opencv_rig(corners, model: str) -> tuple[dict, dict]:
    """OpenCV on the same corners: per camera calibrateCamera, then stereoCalibrate (left, right).
    Returns ``{camera: {param: value}}`` and the stereo solution's RMS (px)."""
    X = corners.board.object_points_mm().astype(np.float32)
    left, right = corners.cameras["left"], corners.cameras["right"]
    views = sorted(v for v in left.views if left.views[v] is not None and right.views.get(v) is not None)
    img = {n: [corners.cameras[n].views[v].astype(np.float32) for v in views] for n in ("left", "right")}
    flags = _opencv_flags(model)
    K, D = {}, {}
    for n in ("left", "right"):
        _, K[n], D[n], _, _ = cv2.calibrateCamera([X] * len(views), img[n], left.image_size, None, None, flags=flags)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        [X] * len(views), img["left"], img["right"], K["left"], D["left"], K["right"], D["right"], left.image_size,
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    out = {}
    for n, Km, Dm in (("left", K1, D1), ("right", K2, D2)):
        d = Dm.ravel()
        out[n] = {"fx": Km[0, 0], "fy": Km[1, 1], "cx": Km[0, 2], "cy": Km[1, 2],
                  "k1": d[0], "k2": d[1], "p1": d[2], "p2": d[3], "k3": d[4]}
    return out, float(rms)             # sqrt(sum of du^2 + dv^2 / corners): a 2-D RMS per corner


def main() -> int:
    if not DATA.is_dir():
        print(f"real data set not present at {DATA}")
        return 0
    ds = open_dataset(DATA, ["left=left*.jpg", "right=right*.jpg"])
    corners = detect_dataset(ds, Board(9, 6, 30.0), jobs=2, progress=False)
    models = list(LENS_MODELS)
    fits = {m: calibrate_rig(corners, rig_mode="rigid", reference="left", model=m, drop_outliers=False)
            for m in models}
    print(f"opencv-samples-stereo, {len(corners.cameras['left'].views)} pairs, rig mode rigid, reference left\n")
    print(f"{'model':<12} {'unknowns':>8} {'RMS left':>9} {'RMS right':>9} {'RMS':>7} {'s0 (px)':>8} "
          f"{'noise-only s0':>13} {'OpenCV RMS':>10} {'converged':>9}")
    base = fits["k1k2"]
    for m in models:
        rig, adj = fits[m], fits[m].adjustment
        n, p0, p = adj["n_observations"], base.adjustment["n_parameters"], adj["n_parameters"]
        noise_only = base.adjustment["s0_px"] * np.sqrt((n - p0) / (n - p))
        _, cv_rms = opencv_rig(corners, m)
        print(f"{m:<12} {p:>8} {rig.camera_rms_px['left']:>9.4f} {rig.camera_rms_px['right']:>9.4f} "
              f"{rig.rms_px:>7.4f} {adj['s0_px']:>8.4f} {noise_only:>13.4f} {cv_rms:>10.4f} "
              f"{str(adj['converged']):>9}")
    print("\nRMS: of the 2-D residual per corner (px); s0: sigma of one coordinate (px); noise-only s0: what\n"
          "k1k2's s0 would become with the extra unknowns explaining nothing; OpenCV RMS: stereoCalibrate's\n"
          "(a 2-D RMS per corner too) on the same corners with the same model.\n")
    cv = {m: opencv_rig(corners, m)[0] for m in models}
    for cam in ("left", "right"):
        print(f"camera {cam}: per model dualcal's value +- 1 sigma, then OpenCV's on the same corners; "
              "Bouguet's joint stereo result (his sigmas are about 3x)")
        print(f"{'':>10}" + "".join(f"{m:>24}" for m in models) + f"{'Bouguet':>12}")
        for prm in PARAMS:
            digits = 5 if prm in LENS_MODELS["k1k2p1p2k3"] else 2
            row = f"{prm:>4} dualcal"[:10].ljust(10)
            for m in models:
                value, sigma = getattr(fits[m].cameras[cam], prm), fits[m].camera_sigma[cam][prm]
                row += f"{value:.{digits}f} +- {sigma:.{digits}f}".rjust(24) if sigma > 0 else "-".rjust(24)
            print(row + f"{BOUGUET[cam][prm]:>12.{digits}f}")
            print(f"{'  OpenCV':<10}" + "".join(f"{cv[m][cam][prm]:>24.{digits}f}" for m in models))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
