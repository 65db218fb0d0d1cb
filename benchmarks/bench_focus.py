"""Focus as part of the lens, and the stabiliser's shift: lengths measured at another focus than the calibration's.

A phone whose lenses breathe with focus (``fx(d) = fx_inf (1 + b f / (d - f))``, ``--breathing`` b, the EXIF focal
lengths of ``note8``: wide 4.3 mm, tele 6 mm) and whose stabiliser shifts every photo's principal point (``--ois``
px per coordinate, each camera and photo its own draw), as ``dualcal.synthetic.synth`` makes it
(``make_truth(breathing=, ois_px=)``). For each of ``--seeds`` draws:

* the calibration: ``--views`` instants of a board of 15 mm squares at 0.45-0.75 m (``fill``), each photo focused
  on the board (its focus in corners.json's meta, as detection reads it from the photo's EXIF and Apple MakerNote),
  corners with ``--noise`` px, calibrated twice: as today (``calibrate_rig(lens_motion=False)``: no focus model,
  no shifts) and with the lens's motion modelled where the photos show it (the default);
* the measurement instants (held out): ``--instants`` per distance, at 0.3 m and 2 m from the wide, each a tilted
  square of 4 points (a third of its distance across) photographed by both cameras focused on it (breathing at
  that focus, a new stabiliser draw), every point tapped in both photos with ``--tap`` px of error per coordinate
  (``pixel_sigma``); each photo's focus given from its metadata (``measure(focus_metadata_m=)``); the 6 lengths
  between the 4 points measured against their truth.

Printed: what the calibration found (each camera's breathing coefficient against the truth, the stabiliser's spread,
whether rig_rigid and focus pass) and per distance the lengths' z = (measured - true) / sigma, mean and sd (target
with the model: |mean z| <= 0.3, sd 0.7-1.4), with their RMS error in % of the length, today's and the model's;
then the same on a phone whose lenses hold still (``--breathing 0 --ois 0``), where no model may be chosen (the
results as today's: ``benchmarks/bench_calibrate_regression.py`` checks that to 1e-6 sigma on its 39 cases) and the
time of a calibration with the tests against one without them (the same run, taking turns, median).
All figures are of synthetic corners (exact truth), not of real photos.

Run from the repository root::

    .venv/bin/python benchmarks/bench_focus.py              # 10 seeds, about 2 minutes
    .venv/bin/python benchmarks/bench_focus.py --seeds 3    # a quick look
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

import numpy as np

from dualcal.errors import EstimationError
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.measurement import measure
from dualcal.geometry.board import Board
from dualcal.geometry.camera import project_points
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_opk
from dualcal.synthetic.synth import make_truth, noisy_corner_set
from dualcal.synthetic.synth_focus import FOCAL_MM, photo_lenses

DISTANCES_MM = (300.0, 2000.0)
#: The board of 15 mm squares fills this share of the tele's frame: 0.45-0.75 m from the wide.
FILL = (0.49, 0.81)


def quiet(function, *args, **kwargs):
    with contextlib.redirect_stderr(io.StringIO()):
        return function(*args, **kwargs)


def measured(rig, points: dict, focus_m: dict) -> dict:
    """:func:`measure`, a point whose rays do not meet (a tap's error at 2 m on an 11 mm baseline can put it behind
    the cameras) left out with its lengths, as a person told which point fails would."""
    while True:
        try:
            return quiet(measure, rig, points, focus_metadata_m=focus_m)
        except EstimationError as exc:
            name = str(exc).split("'")[1]
            points = {**points, "points": {k: v for k, v in points["points"].items() if k != name},
                      "lengths": [p for p in points["lengths"] if name not in p]}


def phone_corners(truth, noise_px: float, seed: int):
    """The calibration's corners as detection gives them from a phone's photos: each camera's EXIF focal length and
    each photo's focus in its meta (``noisy_corner_set`` writes them for lenses that breathe or shift; for still
    lenses, each photo focused on the board's centre)."""
    corners = noisy_corner_set(truth, noise_px, seed=seed)
    if truth.photo_lenses is None:
        centre = truth.board.object_points_mm().mean(axis=0)
        for name, cc in corners.cameras.items():
            cc.meta = {"exif": {"focal_length_mm": FOCAL_MM["note8"][name]},
                       "focus_m": {v: truth.camera_pose(name, v).apply(centre[None])[0, 2] / 1000 for v in cc.views}}
    return corners


def instant_points(distance: float, rng: np.random.Generator) -> np.ndarray:
    """(4, 3) corners of a square a third of ``distance`` across, ``distance`` mm ahead of the wide, turned by
    up to 30 degrees (reference frame, mm)."""
    R = rotation_from_opk(np.radians(rng.uniform(-30.0, 30.0, 3)))
    half = distance / 6.0
    square = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
    centre = np.array([rng.uniform(-0.05, 0.05) * distance, rng.uniform(-0.05, 0.05) * distance, distance])
    return square @ R.T + centre


def lengths_z(rig, truth, breathing: float, ois_px: float, instants: int, tap_px: float,
              rng: np.random.Generator) -> dict[float, tuple[list, list]]:
    """``{distance: (z, relative error)}`` of the lengths of ``instants`` held-out instants at each distance."""
    out = {}
    focal = FOCAL_MM["note8"]
    for distance in DISTANCES_MM:
        zs, errors = [], []
        for _ in range(instants):
            X = instant_points(distance, rng)
            poses = {n: Pose(np.eye(3), np.zeros(3)) if n == truth.reference else truth.rig[n] for n in truth.cameras}
            depth = {n: float(poses[n].apply(X.mean(axis=0)[None])[0, 2]) for n in truth.cameras}
            lenses = photo_lenses(truth.cameras, focal, depth, breathing, ois_px, rng)
            points = {f"P{k}": {} for k in range(len(X))}
            for n, lens in lenses.items():
                uv = project_points(lens.camera, poses[n].apply(X)) + rng.normal(0.0, tap_px, (len(X), 2))
                for k, p in enumerate(uv):
                    points[f"P{k}"][n] = p.tolist()
            pairs = [[f"P{a}", f"P{b}"] for a in range(len(X)) for b in range(a + 1, len(X))]
            doc = measured(rig, {"points": points, "lengths": pairs, "pixel_sigma": tap_px},
                           {n: lens.focus_mm / 1000.0 for n, lens in lenses.items()})
            for length in doc["lengths"]:
                a, b = int(length["from"][1:]), int(length["to"][1:])
                true = float(np.linalg.norm(X[a] - X[b]))
                zs.append((length["length_mm"] - true) / length["sigma_mm"])
                errors.append((length["length_mm"] - true) / true)
        out[distance] = (zs, errors)
    return out


def run(args, breathing: float, ois_px: float) -> None:
    print(f"\nbreathing b = {breathing:g}, stabiliser {ois_px:g} px per coordinate; {args.views} instants at "
          f"0.45-0.75 m, corners {args.noise:g} px, taps {args.tap:g} px, {args.seeds} seeds")
    found = {"today": {d: ([], []) for d in DISTANCES_MM}, "model": {d: ([], []) for d in DISTANCES_MM}}
    rows, times = [], {"today": [], "model": []}
    for seed in range(args.seeds):
        truth = make_truth("note8", views=args.views, seed=5000 + seed, scale=args.scale, board=Board(8, 5, 15.0),
                           fill=FILL, max_tilt_deg=50.0, breathing=breathing, ois_px=ois_px)
        corners = phone_corners(truth, args.noise, seed)
        rigs = {}
        for kind in ("today", "model") if seed % 2 else ("model", "today"):        # taking turns
            t0 = time.perf_counter()
            rigs[kind] = quiet(calibrate_rig, corners, model="k1k2", lens_motion=kind == "model")
            times[kind].append(time.perf_counter() - t0)
        rig = rigs["model"]
        rows.append({"b": {n: (m.breathing, m.breathing_sigma) for n, m in rig.focus_models.items()},
                     "ois": dict(rig.ois_sigma_px),
                     "checks": {k: rig.checks[k]["ok"] for k in ("rig_rigid", "focus") if k in rig.checks},
                     "today_checks": {k: rigs["today"].checks[k]["ok"] for k in ("rig_rigid", "focus")
                                      if k in rigs["today"].checks}})
        for kind in found:
            rng = np.random.default_rng([seed, 77])                     # the same instants and taps for both
            for d, (z, e) in lengths_z(rigs[kind], truth, breathing, ois_px, args.instants, args.tap, rng).items():
                found[kind][d][0].extend(z)
                found[kind][d][1].extend(e)
    chosen = {n: sum(n in r["b"] for r in rows) for n in ("wide", "tele")}
    print(f"  breathing modelled: wide in {chosen['wide']}/{len(rows)}, tele in {chosen['tele']}/{len(rows)} "
          "calibrations")
    for n in ("wide", "tele"):
        got = [r["b"][n] for r in rows if n in r["b"]]
        if got:
            b, s = np.array(got).T
            print(f"    {n}: b = {np.mean(b):.2f} (truth {breathing:g}), its sigma {np.mean(s):.2f}, "
                  f"z = (b - truth) / sigma: mean {np.mean((b - breathing) / s):+.2f}, sd {np.std((b - breathing) / s):.2f}")
    with_ois = sum(any(s > 0 for s in r["ois"].values()) for r in rows)
    print(f"  stabiliser modelled in {with_ois}/{len(rows)} calibrations", end="")
    if with_ois:
        spread = {n: np.mean([r["ois"][n] for r in rows if r["ois"].get(n, 0) > 0] or [0.0]) for n in ("wide", "tele")}
        angle = [np.hypot(r["ois"].get("wide", 0) / truth.cameras["wide"].fx, r["ois"].get("tele", 0) /
                          truth.cameras["tele"].fx) for r in rows]
        true_angle = ois_px * np.hypot(1 / truth.cameras["wide"].fx, 1 / truth.cameras["tele"].fx)
        print(f": spread wide {spread['wide']:.2f} px, tele {spread['tele']:.2f} px (truth {ois_px:g} each); the "
              f"relative angle's spread it implies {np.mean(angle) * 3437.75:.2f} arcmin (truth {true_angle * 3437.75:.2f})")
    else:
        print()
    for kind, key in (("today", "today_checks"), ("model", "checks")):
        passed = {k: sum(r[key].get(k, True) for r in rows) for k in ("rig_rigid", "focus")}
        print(f"  {kind:>5}: rig_rigid passes {passed['rig_rigid']}/{len(rows)}, focus {passed['focus']}/{len(rows)}")
    print(f"  {'distance':>10} {'':>6} {'lengths':>8} {'mean z':>8} {'sd z':>7} {'RMS error %':>12}")
    for d in DISTANCES_MM:
        for kind in found:
            z, e = (np.array(x) for x in found[kind][d])
            print(f"  {d / 1000:>8.1f} m {kind:>6} {len(z):>8} {np.mean(z):>+8.2f} {np.std(z):>7.2f} "
                  f"{100 * np.sqrt(np.mean(e ** 2)):>12.3f}")
    ratio = np.median(np.array(times["model"]) / np.array(times["today"]))
    print(f"  calibration time, median: with the tests {np.median(times['model']):.2f} s, without "
          f"{np.median(times['today']):.2f} s (median of each set's ratio {ratio:.2f})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--scale", type=float, default=1.0, help="sensor scale of the 12 MP preset")
    ap.add_argument("--noise", type=float, default=0.3, help="corner noise, px per coordinate")
    ap.add_argument("--breathing", type=float, default=1.5)
    ap.add_argument("--ois", type=float, default=2.0, help="the stabiliser's spread, px per coordinate")
    ap.add_argument("--tap", type=float, default=0.5, help="the taps' error, px per coordinate")
    ap.add_argument("--instants", type=int, default=5, help="held-out instants per distance and seed")
    args = ap.parse_args(argv)
    run(args, args.breathing, args.ois)
    run(args, 0.0, 0.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
