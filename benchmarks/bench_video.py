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


#: Clips as phones record them (``--size``): note8's wide and tele in video (VIDEO_PRESETS), at phones' bit rates.
SIZES = {"1080p": ("phone-1080p", 17.0), "4k": ("phone-4k", 50.0)}
CODECS = {"h264": "libx264", "hevc": "libx265"}


def transcode(master: Path, out: Path, codec: str, bitrate_mbps: float | None) -> None:
    """``master`` (a clip rendered once at constant quality) encoded again as a phone would (``encode_clip``)."""
    from dualcal.files.io import write_bytes_atomic
    from dualcal.files.video import probe_clip, read_frames
    from dualcal.synthetic.synth_video import encode_clip

    info = probe_clip(master)
    write_bytes_atomic(out, encode_clip((g for _, _, g in read_frames(master)), info.size, info.fps, codec=codec,
                                        bitrate_mbps=bitrate_mbps))


def clips_for(args, preset: str, bitrate_mbps: float | None):
    """The synthetic recording of ``preset`` and its clips in ``--codec`` at ``bitrate_mbps`` (None: constant
    quality), transcoded from clips rendered once; with ``--keep``, all of them kept for the next run."""
    video = make_video_truth(preset, args.holds, args.seed, args.scale, offset_frames=args.offset_frames,
                             readout_s=args.readout_ms / 1000, away=args.away)
    recording = Path(args.keep or tempfile.mkdtemp()) / (f"{preset}-x{args.scale:g}-h{args.holds}-s{args.seed}"
                                                         f"-o{args.offset_frames:g}-r{args.readout_ms:g}-a{args.away}")
    master = recording / "master"
    names = list(video.truth.cameras)
    if not all((master / f"{n}.mp4").exists() for n in names):
        master.mkdir(parents=True, exist_ok=True)
        write_clips(video, master, seed=args.seed, progress=True)
    folder = recording / f"{args.codec}-{f'{bitrate_mbps:g}mbps' if bitrate_mbps else 'crf18'}"
    folder.mkdir(exist_ok=True)
    clips = {n: folder / f"{n}.mp4" for n in names}
    for n, path in clips.items():
        if not path.exists():
            transcode(master / f"{n}.mp4", path, CODECS[args.codec], bitrate_mbps)
    return video, folder, clips


def compare(args, preset: str, bitrate_mbps: float | None) -> dict:
    """One recording calibrated three ways (module docstring); prints the table and returns the ratios."""
    video, folder, clips = clips_for(args, preset, bitrate_mbps)
    truth = video.truth
    ref, other = list(truth.cameras)
    fps = video.fps[other]
    W, H = truth.cameras[ref].image_size
    print(f"\n{preset} ({W}x{H}, {args.codec}): {video.duration_s:.1f} s at {fps:g} fps, board held {args.holds} "
          f"times (and {args.away} times out of view), '{other}' starts {args.offset_frames:g} frames after "
          f"'{ref}'; clips in {folder} "
          f"({sum(p.stat().st_size for p in clips.values()) * 8 / 1e6 / video.duration_s / len(clips):.0f} Mbit/s each)")

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
    t_user, t_dualcal = np.median(wall["opencv"]), np.median(wall["dualcal"])
    ratios = np.array(wall["dualcal"]) / np.array(wall["opencv"])          # turn by turn
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
          f"time {t_dualcal / t_user:.2f} x (median of {args.rounds} turns each; turn by turn "
          f"{', '.join(f'{r:.2f}' for r in ratios)}; CPU time {np.median(cpu['dualcal']) / np.median(cpu['opencv']):.2f} x: "
          f"{np.median(cpu['dualcal']):.1f} s vs {np.median(cpu['opencv']):.1f} s)")
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
    return {"time": t_dualcal / t_user, "t error": te_d / te_u, "R error": re_d / re_u}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", nargs="+", choices=list(SIZES), default=None,
                        help="clips as phones record them: note8's wide and tele filmed in 1080p or 4K "
                             "(dualcal.synthetic.synth_video.VIDEO_PRESETS); several: one comparison each")
    parser.add_argument("--preset", default="stereo", help="the rig, where no --size is given")
    parser.add_argument("--codec", choices=list(CODECS), default="h264")
    parser.add_argument("--mbps", type=float, default=None,
                        help="the clips' bit rate (default: a phone's with --size, 17 in 1080p and 50 in 4K; "
                             "else constant quality, crf 18)")
    parser.add_argument("--holds", type=int, default=18)
    parser.add_argument("--away", type=int, default=0,
                        help="times the board is carried out of every camera's view between holds (make_video_truth)")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--offset-frames", type=float, default=3.4)
    parser.add_argument("--readout-ms", type=float, default=0.0)
    parser.add_argument("--splits", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3, help="turns each pipeline is timed (the median counts)")
    parser.add_argument("--keep", default=None,
                        help="keep the clips in a folder of this one per recording, and reuse them in the next run")
    args = parser.parse_args()

    runs = [(SIZES[s][0], args.mbps or SIZES[s][1]) for s in args.size] if args.size else [(args.preset, args.mbps)]
    ratios = {p: compare(args, p, mbps) for p, mbps in runs}
    print("\n" + "\n".join(f"{p}: dualcal / OpenCV's pipeline: time {r['time']:.2f} x, rig error "
                            f"{r['t error']:.3f} x (translation), {r['R error']:.3f} x (rotation)"
                            for p, r in ratios.items()))


if __name__ == "__main__":
    main()
