"""One tap, every photo: points tapped in one photo and found in the other (``dualcal.estimation.matching``), against
the same points tapped by hand in every photo, and against OpenCV's way of finding them.

Every point is tapped with an error of ``--tap`` px (2: a finger on a phone's screen) per coordinate.

**Renders** (``note8`` wide + tele at ``--scale``, 11 mm baseline): the rig calibrated from noisy board corners
(0.3 px), then photos of textured boxes (``dualcal.synthetic.render_object``) at 0.3-2 m, 12 points on each box's
faces. *One tap*: each point tapped in the wide, found in the tele. *By hand*: tapped in both photos. Printed: the
share found, the matched pixel's error against the render's truth and its z (error over its sigma, along the
line, its sigma as measure.json gives it, the calibration's epipolar uncertainty in it), the lengths' RMS
error both ways and their ratio, z of the one-tap lengths (independent pairs: each
point in one length), with the taps' own uncertainty given as pixel_sigma.

**The real stereo set** (``../shared/data/opencv-samples-stereo``, 640 x 480, 100 mm baseline): for each pair
held out, the rig calibrated from the other twelve (rigid, k1 k2, left the reference); the board's detected
corners are the object: each tapped in the left photo (its detected corner plus the tap's error) and found in
the right, or tapped by hand in both. The truth of a match: where the board's plane puts the tapped pixel in
the right photo (the homography between the undistorted corners of both photos); of a length: the board's
geometry (30 mm squares). Interior corners repeat along the line (the board's squares): a corner the
context cannot tell from its neighbours is unmatched ("repeated pattern"), never matched to another. With a
100 mm baseline, taps by hand in both photos put a point's depth within a few mm, and lengths across the line of
sight are set by each tap's own error (one tap has one, by hand the two average): the ratio is printed for the
lengths that run in depth and for the others apart.

**OpenCV's way** on the same taps: ``cv2.stereoRectify`` with the calibration, ``initUndistortRectifyMap`` and
``remap`` of both photos (``alpha = 1``: with 0, OpenCV zooms into a wide + tele pair's overlap, to 50000 px of focal length), ``matchTemplate`` (``TM_CCOEFF_NORMED``, the same 17 x 17 window) along the rectified
row, parabolic sub-pixel; its matched pixel's RMS error (gross misses, beyond 5 px, counted apart) and the
ratio of times per point.

Run from the repository root::

    .venv/bin/python benchmarks/bench_match.py           # renders at 0.25 and the whole real set: 2-4 minutes
    .venv/bin/python benchmarks/bench_match.py --quick   # fewer boxes and pairs
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.matching import HALF_WINDOW
from dualcal.estimation.measurement import measure
from dualcal.geometry.camera import pixel_rays, project_points, undistort_points, distort_points
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_opk
from dualcal.synthetic.render_object import TexturedBox, render_object
from dualcal.synthetic.synth import make_truth, noisy_corner_set

STEREO = Path(__file__).resolve().parents[2] / "shared" / "data" / "opencv-samples-stereo"


def quiet(function, *args, **kwargs):
    with contextlib.redirect_stderr(io.StringIO()):
        return function(*args, **kwargs)


def measure_all(rig, points: dict, *photos) -> dict:
    """:func:`measure`, points by hand whose rays do not meet (2 px of disparity on an 11 mm baseline at 2 m puts a
    point behind the cameras) left out: what a person does when told which point fails."""
    from dualcal.errors import EstimationError

    points = {**points, "points": dict(points["points"])}
    while True:
        try:
            return quiet(measure, rig, points, *photos)
        except EstimationError as exc:
            name = str(exc).split("'")[1]
            del points["points"][name]
            points["lengths"] = [p for p in points["lengths"] if name not in p]


def rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


# ---------------------------------------------------------------------------- OpenCV's way


class OpenCVMatcher:
    """Rectify the pair with OpenCV (stereoRectify, initUndistortRectifyMap, remap) and find a tap along its row
    with matchTemplate (TM_CCOEFF_NORMED) and a parabola; the match mapped back to the second photo's pixels."""

    def __init__(self, rig, a: str, b: str, image_a, image_b):
        ca, cb = rig.cameras[a], rig.cameras[b]
        pose = rig.pose_from_reference(b).compose(rig.pose_from_reference(a).inverse())
        size = tuple(ca.image_size)
        R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(ca.K, np.array(ca.distortion), cb.K, np.array(cb.distortion), size,
                                                   pose.R, pose.t_mm.reshape(3, 1), alpha=1)
        self.cams, self.R, self.P = (ca, cb), (R1, R2), (P1, P2)
        self.vertical = abs(P2[1, 3]) > abs(P2[0, 3])
        self.rect = []
        for cam, R, P, image in zip(self.cams, self.R, self.P, (image_a, image_b)):
            m1, m2 = cv2.initUndistortRectifyMap(cam.K, np.array(cam.distortion), R, P, size, cv2.CV_32FC1)
            rect = cv2.remap(image, m1, m2, cv2.INTER_LINEAR)
            self.rect.append(rect.T.copy() if self.vertical else rect)

    def _to_rect(self, k, uv):
        p = cv2.undistortPoints(np.float64(uv).reshape(1, 1, 2), self.cams[k].K, np.array(self.cams[k].distortion),
                                R=self.R[k], P=self.P[k]).reshape(2)
        return p[::-1] if self.vertical else p

    def match(self, uv_a):
        x, y = self._to_rect(0, uv_a)
        h = HALF_WINDOW
        xi, yi = int(round(x)), int(round(y))
        A, B = self.rect
        if not (h <= yi < A.shape[0] - h and h <= xi < A.shape[1] - h):
            return None
        template = A[yi - h:yi + h + 1, xi - h:xi + h + 1]
        strip = B[yi - h:yi + h + 1, :]
        score = cv2.matchTemplate(strip, template, cv2.TM_CCOEFF_NORMED)[0]
        k = int(np.argmax(score))
        if 0 < k < len(score) - 1:
            a, b, c = score[k - 1:k + 2]
            k = k + (0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0)
        xr = k + h + (x - xi)                        # the template's centre, with the tap's own sub-pixel part
        p = np.array([y, xr] if self.vertical else [xr, y])
        # back to the second photo's distorted pixels: rectified -> normalised (P2, R2) -> its lens
        cam, R, P = self.cams[1], self.R[1], self.P[1]
        ray = R.T @ np.linalg.solve(P[:, :3], np.array([p[0], p[1], 1.0]))
        return project_points(cam, ray[None])[0]


# ---------------------------------------------------------------------------- renders


def renders(scale: float, distances, points_per_box: int, tap: float, seed: int = 0) -> dict:
    truth = make_truth("note8", views=12, seed=2, scale=scale)
    rig = calibrate_rig(noisy_corner_set(truth, 0.3, seed=5), board_shape="flat")
    to_cam = {"wide": Pose(np.eye(3), np.zeros(3)), "tele": truth.rig["tele"]}
    rng = np.random.default_rng(seed)
    out = {"z_pixel": [], "err_pixel": [], "err_one": [], "err_hand": [], "z_len": [], "tried": 0, "found": 0,
           "reasons": {}, "cv_err": [], "cv_gross": 0, "t_one": 0.0, "t_cv": 0.0, "n_cv": 0}
    for k, distance in enumerate(distances):
        pose = Pose(rotation_from_opk(np.radians(rng.uniform(-30, 30, 3))), np.array([0.0, 0.0, distance]))
        box = TexturedBox(pose, (0.4 * distance, 0.3 * distance, 0.2 * distance), seed=100 + k)
        images = {c: render_object(truth.cameras[c], to_cam[c], box, np.random.default_rng([seed, k, i]))
                  for i, c in enumerate(truth.cameras)}
        X, uv = [], {c: [] for c in truth.cameras}
        while len(X) < points_per_box:
            P = box.pose.apply(rng.uniform(-0.42, 0.42, 3) * np.array(box.size_mm))
            S = box.surface_point(np.zeros(3), P / np.linalg.norm(P))
            seen = {c: project_points(truth.cameras[c], to_cam[c].apply(S[None]))[0] for c in truth.cameras}
            if all(30 < s[0] < truth.cameras[c].image_size[0] - 30 and 30 < s[1] < truth.cameras[c].image_size[1] - 30
                   for c, s in seen.items()):
                X.append(S)
                for c in uv:
                    uv[c].append(seen[c])
        X = np.array(X)
        taps = [uv["wide"][i] + rng.normal(0, tap, 2) for i in range(len(X))]
        hand = [{c: uv[c][i] + rng.normal(0, tap, 2) for c in uv} for i in range(len(X))]
        cv_matcher = OpenCVMatcher(rig, "wide", "tele", images["wide"], images["tele"])
        truths = []
        for t in taps:                                   # the tapped pixel's surface point, as the tele sees it
            S = box.surface_point(np.zeros(3), pixel_rays(truth.cameras["wide"], t[None])[0])
            truths.append(project_points(truth.cameras["tele"], to_cam["tele"].apply(S[None]))[0])
            t0 = time.perf_counter()
            cv = cv_matcher.match(t)
            out["t_cv"] += time.perf_counter() - t0
            out["n_cv"] += 1
            _score_opencv(out, cv, truths[-1])
        names = [f"P{i}" for i in range(len(X))]
        lengths = [[a, b] for i, a in enumerate(names) for b in names[i + 1:]]
        t0 = time.perf_counter()
        one = measure_all(rig, {"points": {n: {"wide": taps[i].tolist()} for i, n in enumerate(names)},
                                "lengths": lengths, "pixel_sigma": tap}, images)
        out["t_one"] += time.perf_counter() - t0
        _score_matches(out, one, {n: truths[i] for i, n in enumerate(names)}, "tele")
        by_hand = measure_all(rig, {"points": {n: {c: v.tolist() for c, v in hand[i].items()}
                                               for i, n in enumerate(names)}, "lengths": lengths, "pixel_sigma": tap})
        _compare(out, one, by_hand, lambda a, b: np.linalg.norm(X[int(a[1:])] - X[int(b[1:])]), names)
    return out


def _score_matches(out, doc, truths: dict, camera: str) -> None:
    """The matches of a measurement (their sigma as measure.json gives it, the calibration's epipolar uncertainty
    in it) against the truth of each tapped pixel: the error along the line and its z."""
    for name, true_b in truths.items():
        out["tried"] += 1
        m = doc["points"].get(name, {}).get("matched", {}).get(camera)
        if m is None:
            for why in doc["unmatched"].get(name, {}).values():
                out["reasons"][why] = out["reasons"].get(why, 0) + 1
            continue
        out["found"] += 1
        out["err_pixel"].append(float((np.array(m["uv"]) - true_b) @ m["direction"]))
        out["z_pixel"].append(out["err_pixel"][-1] / m["sigma_px"])


def _score_opencv(out, cv, true_b) -> None:
    """OpenCV's matched pixel against the truth: its error, or a gross miss beyond 5 px."""
    if cv is None:
        return
    e = float(np.linalg.norm(cv - true_b))
    if e < 5:
        out["cv_err"].append(e)
    else:
        out["cv_gross"] += 1


def _compare(out, one, by_hand, true_length, names):
    """Lengths both ways on the same pairs, and z of the one-tap lengths of disjoint pairs."""
    found = {(L["from"], L["to"]): L for L in one["lengths"]}
    xyz = {n: np.asarray(p["xyz_mm"]) for n, p in one["points"].items()}
    for L in by_hand["lengths"]:
        key = (L["from"], L["to"])
        if key in found:
            out["err_hand"].append(L["length_mm"] - true_length(*key))
            out["err_one"].append(found[key]["length_mm"] - true_length(*key))
            a, b = xyz[key[0]], xyz[key[1]]                # how much of the length runs along the line of sight
            out.setdefault("depth_share", []).append(abs((a - b) @ (a + b)) / (np.linalg.norm(a - b)
                                                                              * np.linalg.norm(a + b)))
    for i in range(0, len(names) - 1, 2):
        L = found.get((names[i], names[i + 1]))
        if L is not None:
            out["z_len"].append((L["length_mm"] - true_length(names[i], names[i + 1])) / L["sigma_mm"])


# ---------------------------------------------------------------------------- the real stereo set


def real_stereo(tap: float, pairs: int | None, seed: int = 0) -> dict | None:
    from dualcal.files.dataset import open_dataset
    from dualcal.files.detect import detect_dataset
    from dualcal.files.photos import read_gray
    from dualcal.geometry.board import Board

    if not STEREO.is_dir():
        return None
    corners = detect_dataset(open_dataset(STEREO, ["left=left*.jpg", "right=right*.jpg"]), Board(9, 6, 30.0),
                             jobs=2, progress=False)
    board = corners.board.object_points_mm()
    views = sorted(corners.cameras["left"].views)[:pairs]
    rng = np.random.default_rng(seed)
    out = {"z_pixel": [], "err_pixel": [], "err_one": [], "err_hand": [], "z_len": [], "tried": 0, "found": 0,
           "reasons": {}, "cv_err": [], "cv_gross": 0, "t_one": 0.0, "t_cv": 0.0, "n_cv": 0}
    for v in views:
        rig = quiet(calibrate_rig, corners.with_views(lambda c, w, v=v: w != v), rig_mode="rigid", reference="left")
        L, R = (read_gray(STEREO / f"{c}{v}.jpg") for c in ("left", "right"))
        uvL, uvR = (np.asarray(corners.cameras[c].views[v], float) for c in ("left", "right"))
        ok = np.flatnonzero(np.all(np.isfinite(uvL), 1) & np.all(np.isfinite(uvR), 1))
        cams = [rig.cameras["left"], rig.cameras["right"]]
        H, _ = cv2.findHomography(undistort_points(cams[0], uvL[ok]), undistort_points(cams[1], uvR[ok]), 0)

        def plane_match(uv):
            p = H @ np.append(undistort_points(cams[0], uv[None])[0], 1.0)
            return distort_points(cams[1], (p[:2] / p[2])[None])[0]

        pose = rig.pose_from_reference("right")
        cv_matcher = OpenCVMatcher(rig, "left", "right", L, R)
        taps = {int(k): uvL[k] + rng.normal(0, tap, 2) for k in ok}
        truths = {f"c{k}": plane_match(t) for k, t in taps.items()}
        for k, t in taps.items():
            t0 = time.perf_counter()
            cv = cv_matcher.match(t)
            out["t_cv"] += time.perf_counter() - t0
            out["n_cv"] += 1
            _score_opencv(out, cv, truths[f"c{k}"])
        order = rng.permutation(list(taps))
        names = [f"c{k}" for k in order]
        lengths = [[a, b] for i, a in enumerate(names) for b in names[i + 1:]]
        t0 = time.perf_counter()
        one = measure_all(rig, {"points": {f"c{k}": {"left": taps[k].tolist()} for k in order},
                                "lengths": lengths, "pixel_sigma": tap}, {"left": L, "right": R})
        out["t_one"] += time.perf_counter() - t0
        _score_matches(out, one, truths, "right")
        hand = measure_all(rig, {"points": {f"c{k}": {"left": taps[k].tolist(),
                                                      "right": (uvR[k] + rng.normal(0, tap, 2)).tolist()}
                                            for k in order}, "lengths": lengths, "pixel_sigma": tap})
        _compare(out, one, hand, lambda a, b: np.linalg.norm(board[int(a[1:])] - board[int(b[1:])]), names)
    return out


def report(title: str, r: dict) -> None:
    z_px, z_len = np.asarray(r["z_pixel"]), np.asarray(r["z_len"])
    ratio = rms(r["err_one"]) / rms(r["err_hand"])
    print(f"\n{title}")
    print(f"  taps found in the other photo: {r['found']} of {r['tried']} ({100 * r['found'] / r['tried']:.0f} %); "
          f"not found: {r['reasons'] or 'none'}")
    print(f"  matched pixel: error {rms(r['err_pixel']):.3f} px rms along the line, z = error / sigma: "
          f"sd {z_px.std():.2f}, mean {z_px.mean():+.2f}   (target sd 0.7-1.4)")
    print(f"  OpenCV's way (stereoRectify + matchTemplate): error {rms(r['cv_err']):.3f} px rms, "
          f"{r['cv_gross']} gross (> 5 px) of {r['n_cv']}; time per point: dualcal's measure (matching, sigmas, "
          f"lengths) {1000 * r['t_one'] / max(r['tried'], 1):.0f} ms, OpenCV's matchTemplate on its rectified pair "
          f"{1000 * r['t_cv'] / max(r['n_cv'], 1):.1f} ms")
    print(f"  lengths ({len(r['err_one'])}): one tap {rms(r['err_one']):.2f} mm rms, by hand in every photo "
          f"{rms(r['err_hand']):.2f} mm rms: ratio {ratio:.3f}   (target <= 0.3)")
    deep = np.asarray(r["depth_share"]) >= 0.3
    if deep.any():
        print(f"  of them running in depth (at least 0.3 of the length along the line of sight, {deep.sum()}): one "
              f"tap {rms(np.asarray(r['err_one'])[deep]):.2f} mm rms, by hand {rms(np.asarray(r['err_hand'])[deep]):.2f}"
              f" mm: ratio {rms(np.asarray(r['err_one'])[deep]) / rms(np.asarray(r['err_hand'])[deep]):.3f}; across "
              f"it: ratio {rms(np.asarray(r['err_one'])[~deep]) / rms(np.asarray(r['err_hand'])[~deep]):.3f}")
    print(f"  one-tap lengths, z over {len(z_len)} independent ones: sd {z_len.std():.2f}, mean {z_len.mean():+.2f}"
          f"   (target sd 0.7-1.4)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tap", type=float, default=2.0, help="tap error, px per coordinate")
    parser.add_argument("--scale", type=float, default=0.25, help="the renders' scale of the note8 rig")
    parser.add_argument("--quick", action="store_true", help="three boxes and four real pairs")
    args = parser.parse_args()
    distances = (300.0, 600.0, 1200.0) if args.quick else (300.0, 450.0, 600.0, 800.0, 1200.0, 2000.0)
    t = time.time()
    report(f"Renders: note8 at {args.scale:g} (11 mm baseline), textured boxes at "
           f"{', '.join(f'{d / 1000:g}' for d in distances)} m, taps {args.tap:g} px",
           renders(args.scale, distances, 12, args.tap))
    real = real_stereo(args.tap, 4 if args.quick else None)
    if real is None:
        print(f"\nthe real stereo set is not at {STEREO}: skipped")
    else:
        report(f"Real: opencv-samples-stereo (100 mm baseline), each pair held out, its board corners tapped "
               f"{args.tap:g} px off in the left photo", real)
    print(f"\n({time.time() - t:.0f} s)")


if __name__ == "__main__":
    main()
