"""ChArUco boards: dualcal against OpenCV's ``CharucoDetector`` and calibration, on renders with known truth.

Each set is a ``note8`` wide + tele rig (12 MP at ``--scale 1``) looking at an 11x8 ChArUco board
(25 mm squares, 18 mm markers, DICT_5X5_100) from ``--views`` poses in which the tele sees 30 to
100 % of the board and the wide at least 80 % (``dualcal.synthetic.synth.make_truth(coverage=(0.3, 1))``),
rendered as ``dualcal synth`` renders photos. Every third photo is rendered once more with two
pairs of markers drawn with each other's codes (planted misread ids; those copies are only
detected, not calibrated). Seeds 2000+ (held out: the tests use others).

1. **Detection**, every photo, same image for both:

   * dualcal: :func:`dualcal.files.detect.detect_photo` (markers on a reduced image, ids checked against
     the board's geometry, corners refined at full resolution);
   * OpenCV: ``cv2.aruco.CharucoDetector(board).detectBoard`` on the full image (its defaults:
     local homographies from the markers, ``cornerSubPix``).

   Printed: photos with a board, corners found, corners OpenCV found that dualcal did not, wrong
   corners (more than 1 px from the truth: a wrong id or a wrong feature), corner RMS vs the truth
   over all each found and over the corners both found, and the time per photo; for the copies
   with misread ids, the photos with a board and the wrong corners.

2. **Calibration** of the rig from each detector's corners:

   * dualcal: :func:`dualcal.calibrate_rig` (rigid, Model 1) on dualcal's corners;
   * OpenCV: ``cv2.calibrateCamera`` per camera (k1 k2 only: ``CALIB_FIX_K3 |
     CALIB_ZERO_TANGENT_DIST``), each view with the object points of the ids it found, then
     ``cv2.stereoCalibrate`` (``CALIB_USE_INTRINSIC_GUESS``) on the ids both cameras saw at each
     instant (stereoCalibrate needs the same object points in both cameras of a pair), on
     OpenCV's corners;
   * and, to tell the detector from the solver, each solver on the other's corners.

   Printed: the RMS error vs truth over the sets of every parameter (focal lengths, principal
   points, k1, k2 of both cameras; baseline, the three angles), per pipeline, the ratio
   dualcal / OpenCV and its geometric mean over the parameters (a single parameter's ratio over
   a few sets scatters by tens of percent either way).

Exit code 1 if a target is missed: dualcal finds every corner OpenCV finds, no wrong corner, a
corner RMS at most OpenCV's, and a geometric mean of the error ratios at most 1.

    .venv/bin/python benchmarks/bench_charuco.py [--sets 4] [--views 8] [--scale 1.0] [--seed 2000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal import calibrate_rig
from dualcal.geometry.board import Board
from dualcal.geometry.camera import CameraModel
from dualcal.files.detect import detect_photo
from dualcal.files.detect.charuco import opencv_board
from dualcal.geometry.model import CameraCorners, CornerSet, Pose, observed_mask
from dualcal.synthetic.render import photo_seed, render_view
from dualcal.synthetic.synth import make_truth, true_corners
from dualcal.geometry.homography import spans_a_plane

BOARD = Board.charuco_board((11, 8), 25.0, 18.0, "DICT_5X5_100")
SWAPS = [(5, 30), (30, 5), (17, 18), (18, 17)]
CV_K1K2 = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
WRONG_PX = 1.0


def _rms(e) -> float:
    e = np.concatenate(e) if isinstance(e, list) else np.asarray(e)
    return float(np.sqrt(np.mean(np.square(e)))) if len(e) else float("nan")


def opencv_detect(gray: np.ndarray) -> np.ndarray:
    """OpenCV's ChArUco corners in dualcal's layout: (N, 2), NaN rows for the corners not found."""
    corners, ids, _, _ = cv2.aruco.CharucoDetector(opencv_board(BOARD)).detectBoard(gray)
    out = np.full((BOARD.n_corners, 2), np.nan)
    if ids is not None:
        out[ids.ravel()] = corners.reshape(-1, 2)
    return out


def _usable(uv: np.ndarray | None) -> bool:
    if uv is None:
        return False
    seen = observed_mask(uv)
    return seen.sum() >= 6 and spans_a_plane(BOARD.object_points_mm()[seen, :2])


def render_set(truth, root: Path, seed: int, misread: bool = False) -> dict[str, dict[str, Path]]:
    """Every photo of the set (``misread``: only every third, with :data:`SWAPS` planted)."""
    paths = {}
    for ci, (cam, model) in enumerate(truth.cameras.items()):
        (root / cam).mkdir(parents=True, exist_ok=True)
        paths[cam] = {}
        for vi, view in enumerate(truth.view_poses):
            if misread and (ci + vi) % 3:
                continue
            img = render_view(model, truth.camera_pose(cam, view), BOARD, photo_seed(seed, ci, vi),
                              swapped_markers=SWAPS if misread else ())
            path = root / cam / f"{view}.jpg"
            cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 92])
            paths[cam][view] = path
    return paths


def detection(truth, paths, stats):
    """Both detectors on every photo; returns each one's corner set."""
    tc = true_corners(truth)
    sets = {"dualcal": {}, "OpenCV": {}}
    for cam, views in paths.items():
        for m in sets:
            sets[m][cam] = {}
        for view, path in views.items():
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            t0 = time.perf_counter()
            res = detect_photo(path, BOARD)
            t1 = time.perf_counter()
            theirs = opencv_detect(gray)
            t2 = time.perf_counter()
            ours = res.uv if res.uv is not None else np.full((BOARD.n_corners, 2), np.nan)
            stats["time"]["dualcal"].append(t1 - t0)
            stats["time"]["OpenCV"].append(t2 - t1)
            truth_uv = tc[cam][view]
            for m, uv in (("dualcal", ours), ("OpenCV", theirs)):
                seen = observed_mask(uv)
                err = np.linalg.norm(uv[seen] - truth_uv[seen], axis=1)
                stats["photos"][m] += int(seen.any())
                stats["corners"][m] += int(seen.sum())
                stats["wrong"][m] += int(np.sum(~(err <= WRONG_PX)))
                stats["err"][m].append(err[err <= WRONG_PX])
                sets[m][cam][view] = uv if _usable(uv) else None
            both = observed_mask(ours) & observed_mask(theirs)
            stats["missed"] += int(np.sum(observed_mask(theirs) & ~observed_mask(ours)))
            for m, uv in (("dualcal", ours), ("OpenCV", theirs)):
                stats["common"][m].append(np.linalg.norm(uv[both] - truth_uv[both], axis=1))
            stats["total"] += 1
    return {m: CornerSet(BOARD, {cam: CameraCorners(truth.cameras[cam].image_size, views)
                                 for cam, views in per.items()}) for m, per in sets.items()}


# ---------------------------------------------------------------------------- OpenCV's calibration

def _points(uv: np.ndarray, mask: np.ndarray):
    X = BOARD.object_points_mm().astype(np.float32)
    return X[mask], uv[mask].astype(np.float32)


def opencv_calibration(corners: CornerSet, reference: str = "wide"):
    """calibrateCamera per camera on the ids each view found, then stereoCalibrate on the ids both saw."""
    per = {}
    for name, cc in corners.cameras.items():
        views = cc.found()
        obj, img = zip(*(_points(uv, observed_mask(uv)) for _, uv in sorted(views.items())))
        _, K, d, _, _ = cv2.calibrateCamera(list(obj), list(img), cc.image_size, None, None, flags=CV_K1K2)
        per[name] = (K, d)
    other = next(n for n in corners.cameras if n != reference)
    ref_views, views = corners.cameras[reference].found(), corners.cameras[other].found()
    obj, img1, img2 = [], [], []
    for v in sorted(set(ref_views) & set(views)):
        both = observed_mask(ref_views[v]) & observed_mask(views[v])
        if both.sum() < 6 or not spans_a_plane(BOARD.object_points_mm()[both, :2]):
            continue
        o, a = _points(ref_views[v], both)
        obj.append(o)
        img1.append(a)
        img2.append(_points(views[v], both)[1])
    start = [a.copy() for cam in (reference, other) for a in per[cam]]
    out = cv2.stereoCalibrate(obj, img1, img2, *start, corners.cameras[reference].image_size,
                              flags=CV_K1K2 | cv2.CALIB_USE_INTRINSIC_GUESS)
    _, K1, d1, K2, d2, R, T = out[:7]
    cams = {reference: _camera(corners.cameras[reference].image_size, K1, d1),
            other: _camera(corners.cameras[other].image_size, K2, d2)}
    return cams, {other: Pose(R, T.ravel())}


def _camera(size, K, d) -> CameraModel:
    d = d.ravel()
    return CameraModel(tuple(size), K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2], d[0], d[1])


def dualcal_calibration(corners: CornerSet):
    rig = calibrate_rig(corners)
    return rig.cameras, {n: r.pose for n, r in rig.rig.items()}


def parameter_errors(cameras, rig, truth) -> dict[str, float]:
    out = {}
    for name, cam in cameras.items():
        true = truth.cameras[name]
        for p in ("fx", "fy", "cx", "cy", "k1", "k2"):
            out[f"{name}.{p}"] = getattr(cam, p) - getattr(true, p)
    for name, pose in rig.items():
        true = truth.rig[name]
        out[f"{name}.baseline_mm"] = np.linalg.norm(pose.t_mm) - np.linalg.norm(true.t_mm)
        for axis, e in zip(("omega", "phi", "kappa"), pose.opk_arcmin - true.opk_arcmin):
            out[f"{name}.{axis}_arcmin"] = e
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", type=int, default=4)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=2000)
    args = ap.parse_args(argv)

    def new_stats():
        st = {k: {"dualcal": 0, "OpenCV": 0} for k in ("photos", "corners", "wrong")}
        st.update(err={"dualcal": [], "OpenCV": []}, common={"dualcal": [], "OpenCV": []},
                  time={"dualcal": [], "OpenCV": []}, missed=0, total=0)
        return st

    stats, misread = new_stats(), new_stats()
    pipelines = {"dualcal": ("dualcal", dualcal_calibration), "OpenCV": ("OpenCV", opencv_calibration),
                 "dualcal solver, OpenCV corners": ("OpenCV", dualcal_calibration),
                 "OpenCV solver, dualcal corners": ("dualcal", opencv_calibration)}
    errors = {p: [] for p in pipelines}
    shares = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.sets):
            seed = args.seed + k
            truth = make_truth("note8", views=args.views, seed=seed, scale=args.scale, board=BOARD, coverage=(0.3, 1.0))
            shares += [float(observed_mask(uv).mean()) for uv in true_corners(truth)["tele"].values()]
            corner_sets = detection(truth, render_set(truth, Path(tmp) / f"set{k}", seed), stats)
            detection(truth, render_set(truth, Path(tmp) / f"misread{k}", seed, misread=True), misread)
            for name, (detector, solve) in pipelines.items():
                errors[name].append(parameter_errors(*solve(corner_sets[detector]), truth))
            print(f"set {k + 1}/{args.sets} (seed {seed}) done", flush=True)

    n = stats["total"]
    print(f"\n{args.sets} sets x {args.views} views x 2 cameras = {n} photos at scale {args.scale:g}; the tele saw "
          f"{min(shares):.0%}-{max(shares):.0%} of the board (median {np.median(shares):.0%})\n")
    print(f"{'detection':34s} {'dualcal':>12s} {'OpenCV':>12s}")
    print(f"{'photos with a board':34s} {stats['photos']['dualcal']:>12d} {stats['photos']['OpenCV']:>12d}   of {n}")
    print(f"{'corners found':34s} {stats['corners']['dualcal']:>12d} {stats['corners']['OpenCV']:>12d}")
    print(f"{'corners OpenCV found, dualcal not':34s} {stats['missed']:>12d}")
    print(f"{'wrong corners (> 1 px off)':34s} {stats['wrong']['dualcal']:>12d} {stats['wrong']['OpenCV']:>12d}")
    rms = {m: _rms(stats["err"][m]) for m in ("dualcal", "OpenCV")}
    common = {m: _rms(stats["common"][m]) for m in ("dualcal", "OpenCV")}
    print(f"{'corner RMS vs truth (px)':34s} {rms['dualcal']:>12.4f} {rms['OpenCV']:>12.4f}")
    print(f"{'  on the corners both found':34s} {common['dualcal']:>12.4f} {common['OpenCV']:>12.4f}")
    print(f"{'time per photo (s, median)':34s} {np.median(stats['time']['dualcal']):>12.3f} "
          f"{np.median(stats['time']['OpenCV']):>12.3f}")
    m = misread
    print(f"{'with 2 pairs of markers swapped:':34s}")
    print(f"{'  photos with a board':34s} {m['photos']['dualcal']:>12d} {m['photos']['OpenCV']:>12d}   of {m['total']}")
    print(f"{'  corners found':34s} {m['corners']['dualcal']:>12d} {m['corners']['OpenCV']:>12d}")
    print(f"{'  wrong corners (> 1 px off)':34s} {m['wrong']['dualcal']:>12d} {m['wrong']['OpenCV']:>12d}")

    names = list(errors["dualcal"][0])
    table = {p: {q: float(np.sqrt(np.mean([e[q] ** 2 for e in errs]))) for q in names} for p, errs in errors.items()}
    print(f"\ncalibration: RMS error vs truth over {args.sets} set(s)")
    print(f"{'parameter':22s}" + "".join(f"{p:>18s}" for p in ("dualcal", "OpenCV", "dualcal on cv pts",
                                                              "OpenCV on dc pts")) + f"{'dualcal/OpenCV':>16s}")
    ratios = []
    for q in names:
        ratios.append(table["dualcal"][q] / table["OpenCV"][q])
        print(f"{q:22s}" + "".join(f"{table[p][q]:>18.5g}" for p in pipelines) + f"{ratios[-1]:>16.3f}")
    mean_ratio = float(np.exp(np.mean(np.log(ratios))))
    print(f"{'geometric mean':22s}" + " " * 18 * len(pipelines) + f"{mean_ratio:>16.3f}")

    failed = []
    if stats["missed"]:
        failed.append(f"{stats['missed']} corners found by OpenCV only")
    if stats["wrong"]["dualcal"] or misread["wrong"]["dualcal"]:
        failed.append(f"{stats['wrong']['dualcal'] + misread['wrong']['dualcal']} wrong corners")
    if rms["dualcal"] > rms["OpenCV"]:
        failed.append("corner RMS above OpenCV's")
    if mean_ratio > 1.0:
        failed.append(f"errors {mean_ratio:.2f} x OpenCV's (geometric mean)")
    print("\n" + ("targets met" if not failed else "targets missed: " + "; ".join(failed)))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
