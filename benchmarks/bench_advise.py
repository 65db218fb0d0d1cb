"""Advised photos against photos drawn like the first ones (synthetic rigs with known truth).

For each preset and seed: 5 photos drawn by :func:`dualcal.synthetic.synth.make_truth` (the whole board in
every camera, 0.2 px corner noise) are calibrated; then

* **advised**: 6 times over, ``dualcal.estimation.advise`` is asked for the next pose, the photo is taken at
  it (exact corners of the true rig plus the same noise, in the cameras it says see the board,
  :func:`dualcal.synthetic.synth.photographed`) and the rig is calibrated again, as a user would follow it;
* **random**: the same 5 photos and the next 6 that ``make_truth`` draws.

Printed: the ratio advised / random of the key sigmas (focal lengths, principal points, k1,
baseline, angles; the honest ``sigma`` of calib.json), geometric mean over the parameters then
averaged over the seeds (target <= 0.7); the largest |error| / sigma of those parameters in the
advised calibrations (target <= 4); the number of photos, from the 5, until every camera's fx and
fy sigma and the baseline's are at most ``--goal`` x their values at 5 photos, advised (with those
goals as ``--target``) against random (in steps of 3; target ratio <= 0.6); and the
prediction-vs-actual check: the key sigmas predicted for the first advised photo against those of
the calibration that includes it (geometric mean of actual / predicted, target within 10 %).

Run from the repository root::

    .venv/bin/python benchmarks/bench_advise.py                    # 3 seeds x 3-4 rigs, 1-3 minutes
    .venv/bin/python benchmarks/bench_advise.py --presets note8 --seeds 5
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


def geomean_ratio(a: dict, b: dict) -> float:
    return float(np.exp(np.mean([np.log(a[n][1] / b[n][1]) for n in a])))


def first_views(corners: CornerSet, n: int) -> CornerSet:
    keep = sorted(next(iter(corners.cameras.values())).views)[:n]
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


def run(preset: str, seed: int, goal: float):
    truth = synth.make_truth(preset, views=MAX_PHOTOS, seed=seed)
    all_corners = synth.noisy_corner_set(truth, NOISE_PX, seed=seed)
    start = first_views(all_corners, START)
    rig5 = calibrate_rig(start)
    rng = np.random.default_rng(seed + 1000)
    predicted = []
    advised, _ = follow_advice(truth, start, rig5, rng, MORE, predicted=predicted)
    random = calibrate_rig(first_views(all_corners, START + MORE))
    a, r = key_values(advised, truth), key_values(random, truth)
    worst_z = max(abs(e - t) / s for e, s, t in a.values())
    names = [n for n in a if n in predicted[0][0][0]]
    pred_ratio = [float(np.exp(np.mean([np.log(act[n] / pred[n]) for n in names]))) for pred, act in predicted[0]]
    # photos to the goal
    goals = goals_of(rig5, goal)
    _, n_adv = follow_advice(truth, start, rig5, np.random.default_rng(seed + 2000), MAX_PHOTOS - START, goals)
    n_rand = None
    for n in range(START + 3, MAX_PHOTOS + 1, 3):
        if met(calibrate_rig(first_views(all_corners, n)), goals):
            n_rand = n - START
            break
    return geomean_ratio(a, r), worst_z, pred_ratio, n_adv, n_rand


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=[p for p in ("note8", "triple", "stereo", "phone3")
                                                      if p in synth.PRESETS])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--goal", type=float, default=0.4, help="goal: sigma at most this x its value at 5 photos")
    args = ap.parse_args()
    print(f"{'rig':8} {'seed':>4} {'advised/random':>14} {'max |err|/sigma':>15} {'actual/predicted':>16} {'textbook':>8} "
          f"{'photos to goal: advised':>23} {'random':>7} {'ratio':>6}")
    for preset in args.presets:
        rows = []
        t0 = time.perf_counter()
        for seed in range(args.seeds):
            ratio, z, pred, n_adv, n_rand = run(preset, seed, args.goal)
            rows.append((ratio, z, pred, n_adv, n_rand))
            rr = f"{n_adv / n_rand:.2f}" if n_rand else "-"
            print(f"{preset:8} {seed:>4} {ratio:>14.3f} {z:>15.2f} {pred[0]:>16.3f} {pred[1]:>8.3f} {n_adv:>23} "
                  f"{n_rand if n_rand else f'>{MAX_PHOTOS - START}':>7} {rr:>6}")
        ratios = np.array([r[0] for r in rows])
        counts = [(r[3], r[4] if r[4] else MAX_PHOTOS - START) for r in rows]
        print(f"{preset:8} {'mean':>4} {ratios.mean():>14.3f} {max(r[1] for r in rows):>15.2f} "
              f"{np.mean([r[2][0] for r in rows]):>16.3f} {np.mean([r[2][1] for r in rows]):>8.3f} "
              f"{sum(c[0] for c in counts):>23} "
              f"{sum(c[1] for c in counts):>7} {sum(c[0] for c in counts) / sum(c[1] for c in counts):>6.2f}"
              f"   ({time.perf_counter() - t0:.0f} s)")
    print("targets: advised/random <= 0.7, max |err|/sigma <= 4, actual/predicted within 0.9-1.1, photos ratio <= 0.6")


if __name__ == "__main__":
    main()
