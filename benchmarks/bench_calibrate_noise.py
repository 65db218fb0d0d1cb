"""Photos weighed by their own noise (issue 38): the weighted calibration against the unweighted one, same run.

1. Synthetic rigs with known truth (``stereo``, ``note8``, ``triple``; ``make_truth`` seeds 5000+, which the tests
   do not use): half the photos 5-10 x noisier than the others (0.25-0.5 px against 0.05), ``--draws`` draws per
   rig. Per preset: the RMS error of every parameter (intrinsics, baseline, angles) weighted over unweighted, their
   geometric mean and the worst (target: each < 1), and the spread of error / sigma of the weighted calibration
   (target 0.7-1.4). Then white corner noise on every photo (0.2 px): how far the weighting moves any parameter,
   in its sigma (target < 0.05), and the share of calibrations in which every photo is weighed alike.
2. The shared real sets (``../shared/data``; corners detected here): every camera's noise level and the scatter of
   its photos', the held-out error (px, 2-D per corner) weighted and not, how far the weighting moves each
   parameter (in sigmas: the largest and the median), and the split-half test of the sigmas
   (:mod:`dualcal.estimation.validation`, ``--splits`` splits; target 0.7-1.5) of both.
3. The real stereo rig's measured lengths, each instant left out in turn: calibrated on the others (``k1k2``), the
   left-out instant's board corners measured (corner 0 to every corner, and between the four outer ones), z =
   (measured - true) / sigma, mean and sd, under the four combinations of the weighting and the outlier rounds
   (``drop_outliers``), so that what moves the mean z shows (issue 38: -0.07 to -0.22 on four real stereo heads).

Run from the repository root::

    .venv/bin/python benchmarks/bench_calibrate_noise.py               # about 5 minutes
    .venv/bin/python benchmarks/bench_calibrate_noise.py --draws 4 --splits 10   # a quick look
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_photo_noise import _blurred_corners, _errors  # noqa: E402

from dualcal.estimation.calibrate import calibrate_rig  # noqa: E402
from dualcal.estimation.measurement import measure  # noqa: E402
from dualcal.estimation.validation import pooled_spread, split_half_z  # noqa: E402
from dualcal.files.dataset import open_dataset  # noqa: E402
from dualcal.files.detect import detect_dataset  # noqa: E402
from dualcal.geometry.board import Board  # noqa: E402
from dualcal.progress import collect_warnings  # noqa: E402
from dualcal.synthetic.synth import make_truth, noisy_corner_set  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SETS = {
    "opencv-samples-stereo": (["left=left*.jpg", "right=right*.jpg"], Board(9, 6, 30.0)),
    "bouguet-calib-example": (["cam=Image*.tif"], Board(12, 13, 30.0)),
    "huawei-y5-2017": ([], Board(7, 9, 30.0)),
}


def quiet(f, *args, **kwargs):
    with collect_warnings(), contextlib.redirect_stderr(io.StringIO()):
        return f(*args, **kwargs)


def synthetic(draws: int) -> None:
    print(f"1. synthetic rigs, half the photos 5-10 x noisier (0.25-0.5 px against 0.05), {draws} draws each")
    print(f"{'preset':8s} {'RMS error weighted / unweighted':>34s} {'worst':>7s} {'z spread':>9s}   "
          f"white noise: {'largest move':>12s} {'all alike':>10s}")
    for k, preset in enumerate(("stereo", "note8", "triple")):
        truth = make_truth(preset, 14, seed=5000 + k)
        w, u, z, moved, alike = [], [], [], [], 0
        for d in range(draws):
            corners, _ = _blurred_corners(truth, 0.05, (0.25, 0.5), 0.5, seed=6000 + 100 * k + d)
            rig = quiet(calibrate_rig, corners, model="k1k2")
            e, s = _errors(rig, truth)
            w.append(e)
            z.append(e / s)
            u.append(_errors(quiet(calibrate_rig, corners, model="k1k2", weigh_photos=False), truth)[0])
            white = noisy_corner_set(truth, 0.2, seed=7000 + 100 * k + d)
            a, b = (_errors(quiet(calibrate_rig, white, model="k1k2", weigh_photos=x), truth) for x in (True, False))
            moved.append(float(np.max(np.abs(a[0] - b[0]) / b[1])))
            alike += bool(np.all(np.abs(a[0] - b[0]) <= 1e-6 * b[1]))
        ratio = np.sqrt(np.mean(np.square(w), axis=0) / np.mean(np.square(u), axis=0))
        print(f"{preset:8s} {np.exp(np.mean(np.log(ratio))):34.2f} {ratio.max():7.2f} "
              f"{np.sqrt(np.mean(np.square(z))):9.2f}   {'':13s}{max(moved):12.3f} {alike:>5d} of {draws}")


def largest_moves(a, b) -> tuple[float, float]:
    """The largest and the median ``|a - b| / sigma_b`` over every intrinsic and rig value."""
    moves = []
    for name, cam in b.cameras.items():
        for p, s in b.camera_sigma[name].items():
            if s > 0:
                moves.append(abs(getattr(a.cameras[name], p) - getattr(cam, p)) / s)
    for name, rel in b.rig.items():
        r = a.rig[name]
        moves += list(np.abs(r.pose.t_mm - rel.pose.t_mm) / rel.sigma_t_mm)
        moves += list(np.abs(r.pose.opk_arcmin - rel.pose.opk_arcmin) / rel.sigma_opk_arcmin)
    return max(moves), float(np.median(moves))


def real(splits: int) -> dict:
    print(f"\n2. the real sets: each photo's noise, held-out error, the weighting's moves, split-half z ({splits} splits)")
    kinds = ("f", "c", "k", "baseline", "angles")
    found = {}
    for name, (globs, board) in SETS.items():
        if not (DATA / name).is_dir():
            print(f"{name}: not found at {DATA / name}")
            continue
        corners = quiet(detect_dataset, open_dataset(DATA / name, globs), board, progress=False)
        found[name] = corners
        rig, plain = (quiet(calibrate_rig, corners, weigh_photos=x) for x in (True, False))
        pn = rig.adjustment["photo_noise"]
        levels = ", ".join(f"{c} {pn['camera_px'][c]:.3f} px (photos' spread x{np.exp(pn['spread'][c] / 2):.2f}, "
                           f"weights {min(d['weight'] for d in pn['photos'][c].values()):.2f}-"
                           f"{max(d['weight'] for d in pn['photos'][c].values()):.2f})" for c in pn["camera_px"])
        most, median = largest_moves(rig, plain)
        print(f"{name}: {levels}")
        print(f"    held-out error {rig.adjustment['held_out_rms_px']:.4f} px weighted, "
              f"{plain.adjustment['held_out_rms_px']:.4f} unweighted; the weighting moves the parameters by "
              f"{most:.2f} sigma at most (median {median:.2f}); dropped photos {len(rig.dropped_views)} / "
              f"{len(plain.dropped_views)}, corners {len(rig.dropped_corners)} / {len(plain.dropped_corners)}")
        t0 = time.perf_counter()
        for label, weigh in (("weighted", True), ("unweighted", False)):
            spread = pooled_spread(quiet(split_half_z, corners, splits, 0,
                                         partial(calibrate_rig, weigh_photos=weigh))["sigma"])
            print(f"    split-half z {label:10s} " + " ".join(f"{k} {spread[k]:.2f}" for k in kinds if k in spread))
        print(f"    ({time.perf_counter() - t0:.0f} s)")
    return found


def stereo_lengths(corners) -> None:
    print("\n3. the real stereo rig's lengths, each instant left out and measured (mean z, sd; 0 and 1 are right)")
    board = corners.board
    X = board.object_points_mm()
    n, c = board.n_corners, board.cols
    outer = [0, c - 1, n - c, n - 1]
    pairs = [(0, k) for k in range(1, n)] + [(a, b) for i, a in enumerate(outer) for b in outer[i + 1:] if a != 0]
    true = np.array([np.linalg.norm(X[a] - X[b]) for a, b in pairs])
    views = sorted(set(corners.cameras["left"].found()) & set(corners.cameras["right"].found()))
    pixel_sigma = np.median(list(quiet(calibrate_rig, corners, model="k1k2", weigh_photos=False)
                                 .camera_rms_px.values())) / np.sqrt(2)
    for weigh in (True, False):
        for drop in (True, False):
            z = []
            for v in views:
                rig = quiet(calibrate_rig, corners.with_views(lambda _, w: w != v), model="k1k2", weigh_photos=weigh,
                            drop_outliers=drop)
                held = {cam: corners.cameras[cam].views[v] for cam in ("left", "right")}
                seen = np.all([np.isfinite(uv).all(axis=1) for uv in held.values()], axis=0)
                both = [i for i, (a, b) in enumerate(pairs) if seen[a] and seen[b]]
                doc = quiet(measure, rig, {"points": {f"c{k}": {cam: held[cam][k].tolist() for cam in held}
                                                      for k in np.flatnonzero(seen)},
                                           "lengths": [[f"c{pairs[i][0]}", f"c{pairs[i][1]}"] for i in both],
                                           "pixel_sigma": float(pixel_sigma)})
                got = np.array([L["length_mm"] for L in doc["lengths"]])
                z.extend((got - true[both]) / np.array([L["sigma_mm"] for L in doc["lengths"]]))
            z = np.array(z)
            print(f"    weighted {'yes' if weigh else 'no ':3s}  outlier rounds {'yes' if drop else 'no ':3s}  "
                  f"mean z {z.mean():+.3f}  sd {z.std():.3f}  ({len(z)} lengths, {len(views)} instants)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=12, help="draws per synthetic rig")
    ap.add_argument("--splits", type=int, default=30, help="split-half splits per real set")
    args = ap.parse_args()
    if args.draws:                         # --draws 0: the real sets alone
        synthetic(args.draws)
    found = real(args.splits)
    if "opencv-samples-stereo" in found:
        stereo_lengths(found["opencv-samples-stereo"])


if __name__ == "__main__":
    main()
