"""Measuring on held-out instants: do the sigmas of ``dualcal.measure`` hold for photos the calibration never saw?

For each preset (``note8`` wide + tele, 11 mm baseline; ``stereo``, 100 mm) and each of ``--draws``
noise draws: a rig with ``--views`` calibration instants plus ``--held-out`` more (``make_truth``
seeds 3000+, unlike the tests'), corner noise ``--noise`` px on every photo. The rig is calibrated
on the first instants only (rigid rig, k1 k2, flat board); then every held-out instant's board
corners, as both cameras measured them, are the "points" of ``dualcal.measure`` (pixel_sigma =
the noise), and the lengths from corner 0 to every other corner, and between the board's four
outer corners, are measured. Their truth is the board's geometry; the points' truth is the
board's corners in the reference camera's frame.

Printed per preset: the number of lengths and coordinates, z = (measured - true) / sigma (mean,
sd; target sd 0.8-1.25, mean within +-0.2), the share of lengths flagged as not meaningful and
z of the lengths not flagged (a selection on a noisy flag: indicative only), the RMS length error in % of the length, and for the peer the same lengths from OpenCV
(``cv2.stereoCalibrate`` with k1 k2 on the same calibration corners, ``cv2.undistortPoints`` +
``cv2.triangulatePoints``; OpenCV gives no sigma) with the ratio of the RMS errors.

Run from the repository root::

    .venv/bin/python benchmarks/bench_measure.py            # 30 draws per preset, about a minute
    .venv/bin/python benchmarks/bench_measure.py --draws 5  # a quick look

It ends with the cost of one measure of 300, 1,000 and 3,000 points (as many lengths): linear in the points.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

import cv2
import numpy as np

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.measurement import measure
from dualcal.geometry.model import CameraCorners, CornerSet
from dualcal.synthetic.synth import make_truth, noisy_corner_set

PRESETS = ("note8", "stereo")


def split(corners: CornerSet, views: list[str]) -> CornerSet:
    """``corners`` restricted to the instants ``views``."""
    return CornerSet(corners.board, {c: CameraCorners(cc.image_size, {v: cc.views[v] for v in views})
                                     for c, cc in corners.cameras.items()})


def requested_lengths(board) -> list[tuple[int, int]]:
    """Corner 0 to every other corner, and the six between the four outer corners."""
    n, c = board.n_corners, board.cols
    outer = [0, c - 1, n - c, n - 1]
    return [(0, k) for k in range(1, n)] + [(a, b) for i, a in enumerate(outer) for b in outer[i + 1:] if a != 0]


def opencv_lengths(calib: CornerSet, held: dict[str, np.ndarray], pairs, ref: str, other: str) -> np.ndarray:
    """The same lengths from OpenCV: stereoCalibrate (k1 k2) on the calibration corners, then triangulatePoints."""
    X = calib.board.object_points_mm().astype(np.float32)
    views = sorted(calib.cameras[ref].views)
    obj = [X for _ in views]
    uv = {c: [calib.cameras[c].views[v].astype(np.float32) for v in views] for c in (ref, other)}
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    size = tuple(calib.cameras[ref].image_size)
    K, D = {}, {}
    for c in (ref, other):
        _, K[c], D[c], _, _ = cv2.calibrateCamera(obj, uv[c], tuple(calib.cameras[c].image_size), None, None, flags=flags)
    _, K[ref], D[ref], K[other], D[other], R, T, _, _ = cv2.stereoCalibrate(
        obj, uv[ref], uv[other], K[ref], D[ref], K[other], D[other], size, flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS)
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R, T.reshape(3, 1)])
    n1 = cv2.undistortPoints(held[ref].reshape(-1, 1, 2), K[ref], D[ref]).reshape(-1, 2)
    n2 = cv2.undistortPoints(held[other].reshape(-1, 1, 2), K[other], D[other]).reshape(-1, 2)
    Xh = cv2.triangulatePoints(P1, P2, n1.T, n2.T)
    pts = (Xh[:3] / Xh[3]).T
    return np.array([np.linalg.norm(pts[a] - pts[b]) for a, b in pairs])


def run(preset: str, draws: int, views: int, held_out: int, noise: float) -> dict:
    z_len, z_pt, flagged, rel_err, rel_err_cv = [], [], [], [], []
    for d in range(draws):
        truth = make_truth(preset, views=views + held_out, seed=3000 + d)
        ref, other = truth.reference, next(c for c in truth.cameras if c != truth.reference)
        corners = noisy_corner_set(truth, noise, seed=4000 + d)
        keys = sorted(truth.view_poses)
        calib_set = split(corners, keys[:views])
        rig = calibrate_rig(calib_set, board_shape="flat")
        board_mm = truth.board.object_points_mm()
        pairs = requested_lengths(truth.board)
        true_len = np.array([np.linalg.norm(board_mm[a] - board_mm[b]) for a, b in pairs])
        for v in keys[views:]:
            held = {c: corners.cameras[c].views[v] for c in (ref, other)}
            points = {"points": {f"c{k}": {c: held[c][k].tolist() for c in (ref, other)} for k in range(len(board_mm))},
                      "lengths": [[f"c{a}", f"c{b}"] for a, b in pairs], "pixel_sigma": noise}
            with contextlib.redirect_stderr(io.StringIO()):
                doc = measure(rig, points)
            got = np.array([L["length_mm"] for L in doc["lengths"]])
            z_len.extend((got - true_len) / np.array([L["sigma_mm"] for L in doc["lengths"]]))
            flagged.extend(L["meaningless"] for L in doc["lengths"])
            rel_err.extend((got - true_len) / true_len)
            X_ref = truth.view_poses[v].apply(board_mm)
            for k in range(len(board_mm)):
                p = doc["points"][f"c{k}"]
                z_pt.extend((np.array(p["xyz_mm"]) - X_ref[k]) / np.array(p["sigma_mm"]))
            rel_err_cv.extend((opencv_lengths(calib_set, held, pairs, ref, other) - true_len) / true_len)
    z_len, z_pt, flagged = np.array(z_len), np.array(z_pt), np.array(flagged)
    kept = z_len[~flagged]
    return {"lengths": len(z_len), "z_len": (z_len.mean(), z_len.std()), "coordinates": len(z_pt),
            "z_kept": (kept.mean(), kept.std()) if len(kept) else (np.nan, np.nan),
            "z_pt": (z_pt.mean(), z_pt.std()), "flagged": float(np.mean(flagged)),
            "rms_pct": 100 * float(np.sqrt(np.mean(np.square(rel_err)))),
            "rms_pct_cv": 100 * float(np.sqrt(np.mean(np.square(rel_err_cv))))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=30, help="noise draws (one rig each) per preset")
    parser.add_argument("--views", type=int, default=8, help="calibration instants")
    parser.add_argument("--held-out", type=int, default=4, help="held-out instants measured")
    parser.add_argument("--noise", type=float, default=0.3, help="corner noise, px per coordinate")
    args = parser.parse_args()
    print(f"{args.draws} draws per preset; calibrated on {args.views} instants, measured on {args.held_out} held-out "
          f"instants; corner noise {args.noise} px\n")
    print(f"{'preset':8s} {'lengths':>8s} {'z mean':>7s} {'z sd':>6s} {'coords':>7s} {'z mean':>7s} {'z sd':>6s} "
          f"{'flagged':>8s} {'z mean':>7s} {'z sd':>6s} {'RMS %':>7s} {'OpenCV %':>9s} {'ratio':>6s} {'time s':>7s}")
    for preset in PRESETS:
        t0 = time.perf_counter()
        r = run(preset, args.draws, args.views, args.held_out, args.noise)
        print(f"{preset:8s} {r['lengths']:8d} {r['z_len'][0]:+7.3f} {r['z_len'][1]:6.3f} {r['coordinates']:7d} "
              f"{r['z_pt'][0]:+7.3f} {r['z_pt'][1]:6.3f} {100 * r['flagged']:7.1f}% {r['z_kept'][0]:+7.3f} "
              f"{r['z_kept'][1]:6.3f} {r['rms_pct']:7.3f} "
              f"{r['rms_pct_cv']:9.3f} {r['rms_pct'] / r['rms_pct_cv']:6.3f} {time.perf_counter() - t0:7.1f}")


def cost(counts=(300, 1000, 3000)) -> None:
    """Seconds of one ``measure`` of P points (every instant's board corners of a calibrated note8 rig, repeated)
    with P lengths (each point to the next): linear in P."""
    truth = make_truth("note8", views=8, seed=1)
    rig = calibrate_rig(noisy_corner_set(truth, 0.3, seed=0), board_shape="flat")
    corners = noisy_corner_set(truth, 0.3, seed=1)
    seen = [{c: corners.cameras[c].views[v][k].tolist() for c in truth.cameras}
            for v in corners.cameras[truth.reference].views for k in range(truth.board.n_corners)]
    print(f"\ncost of one measure (note8 rig): {'points':>7s} {'lengths':>8s} {'seconds':>8s} {'us / point':>11s}")
    for n in counts:
        points = {f"P{i}": seen[i % len(seen)] for i in range(n)}
        names = list(points)
        doc = {"points": points, "lengths": [[a, b] for a, b in zip(names, names[1:] + names[:1])],
               "pixel_sigma": 0.3}
        t0 = time.perf_counter()
        with contextlib.redirect_stderr(io.StringIO()):
            measure(rig, doc)
        dt = time.perf_counter() - t0
        print(f"{'':35s}{n:7d} {n:8d} {dt:8.2f} {1e6 * dt / n:11.0f}")


if __name__ == "__main__":
    main()
    cost()
