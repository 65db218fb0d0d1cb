"""Lens models on the real photo sets: fit RMS and parameters per model, against OpenCV and the references.

For each lens model ``M`` of :data:`dualcal.geometry.camera.LENS_MODELS` (``k1k2``, ``k1k2k3``, ``k1k2p1p2``,
``k1k2p1p2k3``), on corners detected once by dualcal:

* dualcal ``calibrate_rig(corners, model=M, drop_outliers=False)``: on the stereo set
  ``../shared/data/opencv-samples-stereo`` (Bouguet's stereo example 5, 13 pairs of 640x480
  photos, 9x6 inner corners of 30 mm) the rigid rig with reference ``left`` (both cameras and the
  rig adjusted together, as in Bouguet's stereo optimisation); on the single-camera sets
  ``bouguet-calib-example`` (20 photos, 12x13 corners, strong distortion) and ``huawei-y5-2017`` (20
  photos, 7x9 corners, a home-made board) the camera alone;
* OpenCV, the same maximum-likelihood problem solved by another program, on the same corners
  (rounded to float32, which OpenCV takes: below 1e-4 px): ``cv2.calibrateCamera`` per camera with
  the flags of the model (``CALIB_FIX_K3``, ``CALIB_ZERO_TANGENT_DIST`` where it lacks them), for the
  stereo set then ``cv2.stereoCalibrate`` with ``CALIB_USE_INTRINSIC_GUESS`` and the same flags.

Printed per set and model: the fit (RMS of the 2-D residual per corner, dualcal's and OpenCV's; s0,
the a-posteriori sigma of one coordinate) and the lens coefficients with dualcal's 1-sigma; for the
stereo set also every camera's parameters beside OpenCV's and Bouguet's published joint stereo
result (``kc = [k1 k2 p1 p2 k3]``, k3 fixed at 0, his uncertainties about 3 sigma, from 14 pairs
where OpenCV's copy has 13; his cc as published: whether his pixels are 0- or 1-based is not
verified, SOURCE.md). The fit always improves as coefficients are added; compare the fall of s0
with what noise alone gives: with ``q`` more unknowns in ``n`` observations, s0 would become
``s0 sqrt((n - p) / (n - p - q))`` if they explained nothing ("noise-only s0"). This compares fits
only; held-out photos are the fair comparison.

Run from the repository root::

    .venv/bin/python benchmarks/bench_lens_models.py [--sets stereo bouguet huawei]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from dualcal.geometry.board import Board
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import LENS_MODELS
from dualcal.files.dataset import open_dataset
from dualcal.files.detect import detect_dataset

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
#: set name -> (folder, cameras given as NAME=GLOB (none: the folder is one camera), board)
SETS = {"stereo": ("opencv-samples-stereo", ["left=left*.jpg", "right=right*.jpg"], Board(9, 6, 30.0)),
        "bouguet": ("bouguet-calib-example", ["camera=Image*.tif"], Board(12, 13, 30.0)),
        "huawei": ("huawei-y5-2017", (), Board(7, 9, 30.0))}

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


def _parameters(K: np.ndarray, D: np.ndarray) -> dict[str, float]:
    d = D.ravel()
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
            "k1": d[0], "k2": d[1], "p1": d[2], "p2": d[3], "k3": d[4]}


def opencv_fit(corners, model: str) -> tuple[dict, float]:
    """OpenCV on the same corners: calibrateCamera per camera, then stereoCalibrate for two cameras.
    Returns ``{camera: {param: value}}`` and the RMS, ``sqrt(sum(du^2 + dv^2) / corners)`` (px)."""
    X = corners.board.object_points_mm().astype(np.float32)
    names = sorted(corners.cameras)
    views = sorted(set.intersection(*(set(corners.cameras[n].found()) for n in names)))
    img = {n: [corners.cameras[n].views[v].astype(np.float32) for v in views] for n in names}
    size = corners.cameras[names[0]].image_size
    flags = _opencv_flags(model)
    fits = {n: cv2.calibrateCamera([X] * len(views), img[n], size, None, None, flags=flags) for n in names}
    if len(names) == 1:
        rms, K, D, *_ = fits[names[0]]
        return {names[0]: _parameters(K, D)}, float(rms)
    a, b = names
    rms, K1, D1, K2, D2, *_ = cv2.stereoCalibrate(
        [X] * len(views), img[a], img[b], fits[a][1], fits[a][2], fits[b][1], fits[b][2], size,
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    return {a: _parameters(K1, D1), b: _parameters(K2, D2)}, float(rms)


def _value_sigma(value: float, sigma: float, digits: int) -> str:
    return f"{value:.{digits}f} +- {sigma:.{digits}f}" if sigma > 0 else "-"


def compare(name: str) -> None:
    folder, cameras, board = SETS[name]
    if not (DATA / folder).is_dir():
        print(f"{folder}: not present at {DATA / folder}\n")
        return
    corners = detect_dataset(open_dataset(DATA / folder, cameras), board, jobs=2, progress=False)
    stereo = len(corners.cameras) == 2
    kwargs = dict(rig_mode="rigid", reference="left") if stereo else dict(rig_mode="none")
    fits = {m: calibrate_rig(corners, model=m, drop_outliers=False, **kwargs) for m in LENS_MODELS}
    cv = {m: opencv_fit(corners, m) for m in LENS_MODELS}
    base = fits["k1k2"].adjustment
    print(f"{folder}: {', '.join(f'{n} {len(c.found())} photos' for n, c in corners.cameras.items())}, "
          f"rig mode {kwargs['rig_mode']}")
    print(f"{'model':<12} {'unknowns':>8} {'RMS':>7} {'OpenCV RMS':>10} {'s0 (px)':>8} {'noise-only s0':>13}  "
          "lens coefficients +- 1 sigma")
    for m, rig in fits.items():
        adj = rig.adjustment
        n = adj["n_observations"]
        noise_only = base["s0_px"] * np.sqrt((n - base["n_parameters"]) / (n - adj["n_parameters"]))
        lens = "; ".join(f"{cam}: " + ", ".join(
            f"{p} {_value_sigma(getattr(rig.cameras[cam], p), rig.camera_sigma[cam][p], 5)}" for p in LENS_MODELS[m])
            for cam in rig.cameras)
        print(f"{m:<12} {adj['n_parameters']:>8} {rig.rms_px:>7.4f} {cv[m][1]:>10.4f} {adj['s0_px']:>8.4f} "
              f"{noise_only:>13.4f}  {lens}{'' if adj['converged'] else '  (NOT CONVERGED)'}")
    print()
    if not stereo:
        return
    for cam in ("left", "right"):
        print(f"camera {cam}: per model dualcal's value +- 1 sigma, then OpenCV's on the same corners; "
              "Bouguet's joint stereo result (his sigmas are about 3x)")
        print(f"{'':>10}" + "".join(f"{m:>24}" for m in LENS_MODELS) + f"{'Bouguet':>12}")
        for prm in PARAMS:
            digits = 5 if prm in LENS_MODELS["k1k2p1p2k3"] else 2
            print(f"{prm:<10}" + "".join(_value_sigma(getattr(fits[m].cameras[cam], prm),
                                                      fits[m].camera_sigma[cam][prm], digits).rjust(24)
                                         for m in LENS_MODELS) + f"{BOUGUET[cam][prm]:>12.{digits}f}")
            print(f"{'  OpenCV':<10}" + "".join(f"{cv[m][0][cam][prm]:>24.{digits}f}" for m in LENS_MODELS))
        print()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", nargs="+", choices=list(SETS), default=list(SETS), help="real sets to compare")
    for name in parser.parse_args().sets:
        compare(name)
    print("RMS: of the 2-D residual per corner (px), dualcal's and OpenCV's with the same model on the same "
          "corners; s0: sigma of one coordinate (px); noise-only s0: what k1k2's s0 would become if the extra "
          "unknowns explained nothing.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
