"""Calibrating a rig from two clips: dualcal beside what an OpenCV user does, against the truth.

Renders a synthetic rig's two clips (``dualcal.synthetic.synth_video``: the board carried by hand and held
still ``--holds`` times, motion blur, H.264 .mp4, the second camera starting ``--offset-frames`` after the
first) and calibrates them three ways:

* **dualcal**: ``read_corners`` (the board tracked, the offset estimated, the held moments chosen and
  measured) and ``calibrate_corners``, as ``dualcal calibrate clips/`` does;
* **OpenCV user**: every 10th frame of each clip, ``findChessboardCorners`` + ``cornerSubPix`` (OpenCV's
  tutorial, with a 11 x 11 window where the tutorial has 23 x 23: that one straddles these squares of
  about 20 px and makes OpenCV's fx 75-95 px wrong; the benchmark gives OpenCV its best), ``calibrateCamera``
  per camera, the frames paired by index, ``stereoCalibrate`` (intrinsics fixed);
* **OpenCV, true offset**: the same, with the second clip's frames paired with the reference's by the true
  whole-frame offset (what is left is the sub-frame part: 0.4 of a frame, 13 ms at 30 fps, by default).

It prints each one's errors against the truth (the rig's translation in mm and rotation in arcmin, each
camera's fx and cx) and its time, and dualcal's ratios to the OpenCV user: rig error and time. Then dualcal's
offset against the truth and the split-half spread of its sigmas over held moments
(:func:`dualcal.estimation.validation.split_half_z` with the moments as the unit).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dualcal.estimation.validation import moments_of, pooled_spread, split_half_z
from dualcal.geometry.rotation import rotvec_from_rotation
from dualcal.synthetic.synth_video import make_video_truth, write_clips
from dualcal.workflow import calibrate_corners, read_corners

ARCMIN = 180 * 60 / np.pi


def opencv_user(clips: dict[str, Path], board, shift: int = 0, step: int = 10):
    """OpenCV's tutorial on clips: every ``step``-th frame of the reference, the other clip's frame ``shift``
    frames earlier (0: by index), ``findChessboardCorners`` + ``cornerSubPix``, ``calibrateCamera`` each,
    ``stereoCalibrate`` on the pairs. Returns ``(K, dist)`` per camera and the rig's ``(R, T)``."""
    names = list(clips)
    pattern = (board.cols, board.rows)
    objp = board.object_points_mm().astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    found, size = {}, {}
    for k, name in enumerate(names):
        wanted = lambda i: i % step == 0 if k == 0 else (i + shift) % step == 0  # noqa: E731
        cap = cv2.VideoCapture(str(clips[name]))
        found[name] = {}
        i = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if wanted(i):
                gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                size[name] = gray.shape[::-1]
                hit, corners = cv2.findChessboardCorners(gray, pattern, None)
                if hit:
                    found[name][i + (shift if k else 0)] = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)
            i += 1
        cap.release()
    cams = {}
    for name in names:
        views = list(found[name].values())
        _, K, dist, _, _ = cv2.calibrateCamera([objp] * len(views), views, size[name], None, None)
        cams[name] = (K, dist)
    a, b = names
    common = sorted(set(found[a]) & set(found[b]))
    (Ka, da), (Kb, db) = cams[a], cams[b]
    out = cv2.stereoCalibrate([objp] * len(common), [found[a][i] for i in common], [found[b][i] for i in common],
                              Ka, da, Kb, db, size[a], flags=cv2.CALIB_FIX_INTRINSIC)
    return cams, (out[5], out[6].ravel()), len(common)


def rig_errors(R, t, truth_pose) -> tuple[float, float]:
    """Translation error (mm) and rotation error (arcmin) of a rig's relative pose."""
    return (float(np.linalg.norm(np.asarray(t) - truth_pose.t_mm)),
            float(np.linalg.norm(rotvec_from_rotation(np.asarray(R) @ truth_pose.R.T)) * ARCMIN))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="stereo")
    parser.add_argument("--holds", type=int, default=18)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--offset-frames", type=float, default=3.4)
    parser.add_argument("--readout-ms", type=float, default=0.0)
    parser.add_argument("--splits", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=2, help="turns each pipeline is timed (the best counts)")
    parser.add_argument("--keep", default=None, help="write the clips here (default: a temporary folder)")
    args = parser.parse_args()

    video = make_video_truth(args.preset, args.holds, args.seed, args.scale, offset_frames=args.offset_frames,
                             readout_s=args.readout_ms / 1000)
    truth = video.truth
    folder = Path(args.keep or tempfile.mkdtemp())
    folder.mkdir(parents=True, exist_ok=True)
    clips = {n: folder / f"{n}.mp4" for n in truth.cameras}
    if not (args.keep and all(p.exists() for p in clips.values())):      # (--keep: clips of a run before reused)
        clips = write_clips(video, folder, seed=args.seed, progress=False)
    ref, other = list(truth.cameras)
    fps = video.fps[other]
    print(f"{args.preset} x{args.scale:g}: {video.duration_s:.1f} s at {fps:g} fps, board held {args.holds} times, "
          f"'{other}' starts {args.offset_frames:g} frames after '{ref}'; clips in {folder}")

    wall = {"opencv": [], "dualcal": []}
    cpu = {"opencv": [], "dualcal": []}
    for _ in range(args.rounds):                 # the two take turns: the machine's speed drifts
        for who in ("opencv", "dualcal"):
            t0, c0 = time.perf_counter(), time.process_time()
            if who == "opencv":
                user = opencv_user(clips, truth.board)
            else:
                corners = read_corners(str(folder), truth.board, progress=False)
                rig = calibrate_corners(corners)
            wall[who].append(time.perf_counter() - t0)
            cpu[who].append(time.process_time() - c0)
    t_user, t_dualcal = min(wall["opencv"]), min(wall["dualcal"])
    told = opencv_user(clips, truth.board, shift=int(np.floor(video.offset_s[other] * fps)))

    rows = []
    for label, cams, (R, t), pairs, seconds in (("OpenCV user (pairs by index)", *user[:2], user[2], t_user),
                                                 ("OpenCV told the whole-frame offset", *told[:2], told[2], None)):
        rows.append((label, *rig_errors(R, t, truth.rig[other]),
                     {n: (cams[n][0][0, 0] - truth.cameras[n].fx, cams[n][0][0, 2] - truth.cameras[n].cx)
                      for n in truth.cameras}, pairs, seconds))
    rel = rig.rig[other]
    rows.append(("dualcal", *rig_errors(rel.pose.R, rel.pose.t_mm, truth.rig[other]),
                 {n: (c.fx - truth.cameras[n].fx, c.cx - truth.cameras[n].cx) for n, c in rig.cameras.items()},
                 len(rig.reference_poses()), t_dualcal))
    print(f"\n{'':36s} {'t err mm':>9s} {'R err arcmin':>12s} " + " ".join(f"{n + ' fx/cx err px':>22s}" for n in truth.cameras)
          + f" {'pairs':>6s} {'time s':>7s}")
    for label, te, re, intr, pairs, seconds in rows:
        print(f"{label:36s} {te:9.3f} {re:12.3f} " + " ".join(f"{dx:+10.3f} {dc:+10.3f}" for dx, dc in intr.values())
              + f" {pairs:6d} {seconds if seconds is not None else float('nan'):7.2f}")
    (_, te_u, re_u, *_), (_, te_t, re_t, *_), (_, te_d, re_d, *_) = rows
    print(f"\ndualcal / OpenCV user: rig translation error {te_d / te_u:.3f} x, rotation error {re_d / re_u:.3f} x, "
          f"time {t_dualcal / t_user:.2f} x (best of {args.rounds} turns each; CPU time "
          f"{min(cpu['dualcal']) / min(cpu['opencv']):.2f} x: {min(cpu['dualcal']):.1f} s vs {min(cpu['opencv']):.1f} s)")
    print(f"dualcal / OpenCV told the whole-frame offset: translation error {te_d / te_t:.3f} x, "
          f"rotation error {re_d / re_t:.3f} x")

    sigma = rel.sigma_t_mm
    print(f"dualcal rig t_mm error / sigma: {np.round((rel.pose.t_mm - truth.rig[other].t_mm) / sigma, 2)}; "
          f"opk error / sigma: {np.round((rel.pose.opk_arcmin - truth.rig[other].opk_arcmin) / rel.sigma_opk_arcmin, 2)}")
    worst = max(abs(getattr(c, p) - getattr(truth.cameras[n], p)) / rig.camera_sigma[n][p]
                for n, c in rig.cameras.items() for p in ("fx", "fy", "cx", "cy", "k1", "k2"))
    print(f"dualcal intrinsics: largest |error| / sigma {worst:.2f}")
    record = corners.cameras[other].meta["video"]
    err = record["offset_s"] - video.offset_s[other]
    print(f"offset: {record['offset_s'] * 1000:.3f} ms +- {record['offset_sigma_s'] * 1000:.3f} (true "
          f"{video.offset_s[other] * 1000:.3f}): error {err * 1000:+.3f} ms = {err / record['offset_sigma_s']:+.2f} sigma")
    if args.splits:
        from dualcal.estimation.calibrate import calibrate_rig

        z = split_half_z(corners, splits=args.splits, groups=moments_of(corners), model="k1k2", calibrate=calibrate_rig)
        spread = pooled_spread(z["sigma"])
        print(f"split-half z spread over moments ({args.splits} splits, {len(rig.reference_poses())} moments): "
              + ", ".join(f"{g} {v:.2f}" for g, v in spread.items()))


if __name__ == "__main__":
    main()
