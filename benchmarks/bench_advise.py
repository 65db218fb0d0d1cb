"""Advised photos against photos drawn like the first ones (synthetic rigs with known truth).

For each preset, seed and start: the rig and 60 board poses drawn by :func:`dualcal.synthetic.synth.make_truth`
(the whole board in every camera, 0.2 px corner noise); start ``j`` is its photos ``11 j`` to ``11 j + 4``
(5 photos), which are calibrated; then

* **advised**: 6 times over, ``dualcal.estimation.advise`` is asked for the next pose, the photo is taken at
  it (exact corners of the true rig plus the same noise, in the cameras it says see the board,
  :func:`dualcal.synthetic.synth.photographed`) and the rig is calibrated again, as a user would follow it;
* **random**: the same 5 photos and the next 6 that ``make_truth`` drew.

Printed, per preset:

* **every key sigma's ratio advised / random** (each camera's fx, fy, cx, cy, k1; each rig camera's baseline,
  omega, phi, kappa; the honest ``sigma`` of calib.json): its geometric mean over the seeds and starts, and
  its worst (largest) run with the run's seed/start; PASS when the geometric mean is at most 1.0, i.e. no
  camera's parameter is left worse off than random photos leave it;
* **the geometric mean over every key sigma** of those ratios: PASS at most 0.5;
* per run: that geometric mean, the largest |error| / sigma of the key parameters in the advised calibration
  (target <= 4), the prediction-vs-actual check (the key sigmas predicted for the first advised photo against
  those of the calibration that includes it, geometric mean of actual / predicted, honest and textbook;
  target within 10 %), and, for start 0 only, the photos from the 5 until every camera's fx and fy sigma and
  the baseline's are at most ``--goal`` x their values at 5 photos, advised (with those goals as
  ``--target``) against random (in steps of 3; target ratio <= 0.6).

Run from the repository root::

    .venv/bin/python benchmarks/bench_advise.py                  # 8 seeds x 2 starts x 3 rigs, about 8 min on 2 cores
    .venv/bin/python benchmarks/bench_advise.py --quick          # 2 seeds x 1 start of note8, no photos-to-goal: under a minute
    .venv/bin/python benchmarks/bench_advise.py --presets triple --seeds 4 --starts 1 --no-goal
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dualcal.estimation import advise as A
from dualcal.synthetic import synth
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.model import CornerSet
from dualcal.geometry.rotation import ARCMIN_PER_RAD, opk_from_rotation

NOISE_PX = 0.2
START, MORE, MAX_PHOTOS = 5, 6, 60
#: targets: every key sigma's ratio (geometric mean over runs), their geometric mean
EACH_MAX, GEOMEAN_MAX = 1.0, 0.5


def key_values(rig, truth=None):
    """``{name: (estimate, sigma, true)}`` of the key parameters of a calibration."""
    out = {}
    for name, cam in rig.cameras.items():
        for n in ("fx", "fy", "cx", "cy", "k1"):
            out[f"{name}.{n}"] = (getattr(cam, n), rig.camera_sigma[name][n],
                                  getattr(truth.cameras[name], n) if truth else np.nan)
    for name, rel in rig.rig.items():
        out[f"{name}.baseline_mm"] = (rel.baseline_mm, rel.sigma_baseline_mm,
                                      np.linalg.norm(truth.rig[name].t_mm) if truth else np.nan)
        opk = opk_from_rotation(rel.pose.R) * ARCMIN_PER_RAD
        true = opk_from_rotation(truth.rig[name].R) * ARCMIN_PER_RAD if truth else [np.nan] * 3
        for i, a in enumerate(("omega", "phi", "kappa")):
            out[f"{name}.{a}_arcmin"] = (opk[i], rel.sigma_opk_arcmin[i], true[i])
    return out


def views_of(corners: CornerSet, first: int, n: int) -> CornerSet:
    """The photos ``first`` to ``first + n - 1`` in the order ``make_truth`` drew them."""
    keep = sorted(next(iter(corners.cameras.values())).views)[first:first + n]
    return corners.with_views(lambda cam, view: view in keep)


def follow_advice(truth, corners, rig, rng, count, goals=None, predicted=None):
    """Take ``count`` advised photos one after another (or until ``goals`` are met); returns the last
    calibration, the photos taken and, in ``predicted``, (predicted key sigmas, actual) of the first."""
    for i in range(count):
        prior = A.prior_from_rig(rig)
        advice = A.advise(prior, count=1, goals=goals, seed=i)
        if goals and advice.done:
            return rig, i
        pose = advice.poses[0]
        corners = synth.photographed(truth, corners, f"ADV_{i:02d}", pose.pose, pose.cameras, NOISE_PX, rng)
        rig = calibrate_rig(corners)
        if predicted is not None and i == 0:
            seen = {n: A.seen_corners(prior, n, pose.pose) for n in pose.cameras}
            G = A.target_gradients(prior)
            formal = A.sigmas(A.updated_covariance(prior.covariance, A.instant_information(prior, pose.pose, seen)), G)
            actual = A.prior_from_rig(rig)
            predicted.append(((pose.predicted_sigma, A.honest_sigmas(actual)), (formal, A.sigmas(actual.covariance, G))))
    return rig, count


def goals_of(rig, factor: float) -> dict[str, float]:
    goals = {f"{n}.{p}": factor * rig.camera_sigma[n][p] for n in rig.cameras for p in ("fx", "fy")}
    goals.update({f"{n}.baseline_mm": factor * rel.sigma_baseline_mm for n, rel in rig.rig.items()})
    return goals


def met(rig, goals) -> bool:
    now = {f"{n}.{p}": rig.camera_sigma[n][p] for n in rig.cameras for p in ("fx", "fy")}
    now.update({f"{n}.baseline_mm": rel.sigma_baseline_mm for n, rel in rig.rig.items()})
    return all(now[k] <= s for k, s in goals.items())


def run(preset: str, seed: int, start: int, goal: float | None, truth=None, all_corners=None):
    """One run: ``({key: advised / random}, max |err|/sigma, (honest, textbook) actual/predicted,
    photos to the goal advised, random)``."""
    first = start * (START + MORE)
    begin = views_of(all_corners, first, START)
    rig5 = calibrate_rig(begin)
    rng = np.random.default_rng(seed + 1000 + 100 * start)
    predicted = []
    advised, _ = follow_advice(truth, begin, rig5, rng, MORE, predicted=predicted)
    random = calibrate_rig(views_of(all_corners, first, START + MORE))
    a, r = key_values(advised, truth), key_values(random, truth)
    ratios = {n: a[n][1] / r[n][1] for n in a}
    worst_z = max(abs(e - t) / s for e, s, t in a.values())
    names = [n for n in a if n in predicted[0][0][0]]
    pred_ratio = [float(np.exp(np.mean([np.log(act[n] / pred[n]) for n in names]))) for pred, act in predicted[0]]
    n_adv = n_rand = None
    if goal is not None:
        goals = goals_of(rig5, goal)
        _, n_adv = follow_advice(truth, begin, rig5, np.random.default_rng(seed + 2000), MAX_PHOTOS - START, goals)
        for n in range(START + 3, MAX_PHOTOS - first + 1, 3):
            if met(calibrate_rig(views_of(all_corners, first, n)), goals):
                n_rand = n - START
                break
    return ratios, worst_z, pred_ratio, n_adv, n_rand


def geomean(x) -> float:
    return float(np.exp(np.mean(np.log(x))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=[p for p in ("note8", "triple", "stereo") if p in synth.PRESETS])
    ap.add_argument("--seeds", type=int, default=8, help="rigs and poses drawn per preset (seeds 0..N-1)")
    ap.add_argument("--starts", type=int, default=2, help="starting sets of 5 photos per seed")
    ap.add_argument("--goal", type=float, default=0.4, help="goal: sigma at most this x its value at 5 photos")
    ap.add_argument("--no-goal", action="store_true", help="skip the photos-to-goal count (the slow part)")
    ap.add_argument("--quick", action="store_true", help="note8, 2 seeds, 1 start, no photos-to-goal: about a minute")
    args = ap.parse_args()
    if args.quick:
        args.presets, args.seeds, args.starts, args.no_goal = ["note8"], 2, 1, True
    verdicts = []
    for preset in args.presets:
        t0 = time.perf_counter()
        print(f"\n{preset}: {args.seeds} seeds x {args.starts} starts of {START} photos, {MORE} more photos each")
        print(f"{'seed/start':>10} {'geomean advised/random':>22} {'max |err|/sigma':>15} {'actual/predicted':>16} "
              f"{'textbook':>8} {'photos to goal: advised':>23} {'random':>7}")
        rows = []
        for seed in range(args.seeds):
            truth = synth.make_truth(preset, views=MAX_PHOTOS, seed=seed)
            all_corners = synth.noisy_corner_set(truth, NOISE_PX, seed=seed)
            for start in range(args.starts):
                goal = None if args.no_goal or start else args.goal
                ratios, z, pred, n_adv, n_rand = run(preset, seed, start, goal, truth, all_corners)
                rows.append((f"{seed}/{start}", ratios, z, pred, n_adv, n_rand))
                adv = "-" if n_adv is None else n_adv
                rnd = "-" if goal is None else (n_rand if n_rand else f">{MAX_PHOTOS - START}")
                print(f"{seed:>8}/{start} {geomean(list(ratios.values())):>22.3f} {z:>15.2f} {pred[0]:>16.3f} "
                      f"{pred[1]:>8.3f} {adv:>23} {rnd:>7}", flush=True)
        names = list(rows[0][1])
        print(f"{'key sigma':22} {'advised/random':>14} {'worst run':>9} {'(seed/start)':>12}")
        each = {}
        for n in names:
            r = np.array([row[1][n] for row in rows])
            each[n] = geomean(r)
            w = int(np.argmax(r))
            ok = each[n] <= EACH_MAX
            verdicts.append(ok)
            print(f"{n:22} {each[n]:>14.3f} {r[w]:>9.3f} {rows[w][0]:>12}  {'PASS' if ok else 'FAIL'} (<= {EACH_MAX})")
        g = geomean(list(each.values()))
        verdicts.append(g <= GEOMEAN_MAX)
        goal_rows = [(row[4], row[5] or MAX_PHOTOS - START) for row in rows if row[4] is not None]
        print(f"{'geometric mean':22} {g:>14.3f} {'':>9} {'':>12}  {'PASS' if g <= GEOMEAN_MAX else 'FAIL'} "
              f"(<= {GEOMEAN_MAX})")
        print(f"{preset}: max |err|/sigma {max(row[2] for row in rows):.2f} (<= 4); actual/predicted honest "
              f"{np.mean([row[3][0] for row in rows]):.3f}, textbook {np.mean([row[3][1] for row in rows]):.3f} "
              f"(0.9-1.1)" + (f"; photos to goal advised / random {sum(a for a, _ in goal_rows)} / "
                              f"{sum(b for _, b in goal_rows)} (<= 0.6)" if goal_rows else "")
              + f"   ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"\n{'PASS' if all(verdicts) else 'FAIL'}: every key sigma advised/random <= {EACH_MAX} and their geometric "
          f"mean <= {GEOMEAN_MAX} on every preset")


if __name__ == "__main__":
    main()
