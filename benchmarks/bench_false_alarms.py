"""Checks that know their false-alarm rate and name what they blame: ``rig_rigid``, ``focus`` and ``loop_closure``
on synthetic rigs and the real sets.

``rig_rigid`` judges each instant against a robust core of the others (its tie cost from its own relative poses
against the relations the core tells), ``focus`` each photo's focal scale against a robust core of its camera's
other photos and each camera's photos split in two, ``loop_closure`` each pair of cameras' relative poses against
the rig; each at a stated false-alarm rate of 1 % per calibration (:data:`dualcal.estimation.checks.FALSE_ALARM_RATE`),
split over its tests by Sidak. This measures it, and how often each names what is wrong.

* **Noise.** Synthetic rigs (``dualcal.synthetic.synth`` presets ``stereo``, ``note8``, ``triple``; 13 instants;
  the paper's lens, k1 k2) with corner noise as real photos have it: white noise of 0.1 px per coordinate plus,
  per photo, a smooth warp of its own (shift, scale, shear and bend, each coefficient 0.03 px over the half image;
  independent between the cameras, as blur or rolling shutter make it). ``--varying``: every photo's noise also
  scaled by ``exp(N(0, 0.35))``. Calibrated with the lens models asked (default k1k2), outliers kept
  (``drop_outliers=False``, so that the checks see every photo).
* **rig_rigid.** Synchronised: a false alarm is a calibration whose test names an instant (the stated rate), and
  the share whose check fails. Then 1, 2 and 3 instants (the 7th, 3rd, 11th) of the first non-reference camera
  shot 0.5 mm and 1.5 arcmin off the rig (random directions; a handheld shot some 20-30 ms late): the share where
  every one is named, and where some good instant is named with them.
* **focus.** Synchronised: the share that fail. Then 1, 2 and 3 photos of the first non-reference camera (same
  instants) with a focal length 1 % longer (a refocus): every one's instant named as refocused, and with its camera
  (of two cameras of one instant, the one whose focal scale is further off with every camera alone: on the VGA rig
  a photo's own focal length is too weak to tell them apart reliably), or a good instant named. And a
  **lens split**: the reference camera's photos alone (rig mode ``none``), every other one through a lens of a
  focal length 10, 20 or 30 % longer and other distortion (two lenses of one image size merged into one camera):
  the share where ``focus`` fails.
* **loop_closure** (``triple``): synchronised and rigid, the ultra-wide seeing the board in only 4 of the 13
  instants (so ultra-wide pairs share 4): the share that fail; then the ultra-wide knocked (10 arcmin, 0.2 mm)
  after the 6th instant, seeing all 13: the share that fail naming it.
* **Real sets** (``../shared/data``, detected once): the stereo sample (``left*.jpg``/``right*.jpg``, 9x6, a rigid
  rig, reference left) under the models and ``auto``: ``rig_rigid``'s named instants with their F and p, and
  ``focus``; the single-camera sets (huawei-y5-2017 7x9, bouguet-calib-example 12x13) and caliscope's four webcams
  (``xy_CHARUCO.csv``, rig mode ``none``): ``focus``, and how many photos it did not judge.

Every share is printed with its 95 % Wilson interval, beside the stated 1 %; and, over the synchronised rigs, the
share of the instants' (photos') statistics beyond the 1e-3 quantile of Student's t of the core's ``n - 1``
degrees of freedom and of half of them (which the checks take: ``T_DOF_SHARE``).

Run from the repository root::

    .venv/bin/python benchmarks/bench_false_alarms.py [--seeds 100] [--base-seed 5000] [--quick] [--varying]
        [--presets stereo note8 triple] [--models k1k2 ...] [--warp 0.03] [--no-real] [--no-synthetic]

``--quick``: 12 seeds, the stereo preset and the triple's loop (a few minutes). The default (100 seeds, three
presets, k1k2) takes about an hour on one core.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.checks import FALSE_ALARM_RATE, SHIFT_SIGMAS, T_DOF_SHARE
from dualcal.estimation.distributions import f_sf
from dualcal.geometry.board import Board
from dualcal.geometry.camera import project_points
from dualcal.geometry.model import CameraCorners, CornerSet, Pose
from dualcal.geometry.rotation import rotation_from_opk
from dualcal.progress import collect_warnings
from dualcal.synthetic import synth

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
WHITE_PX = 0.1
WARP_PX = 0.03
VARYING_SIGMA = 0.35
DESYNC_MM, DESYNC_ARCMIN = 0.5, 1.5
REFOCUS = 0.01
SPLITS = (0.1, 0.2, 0.3)
BAD_INSTANTS = (6, 2, 10)          # the 7th, 3rd and 11th instants


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """The 95 % Wilson score interval of a share ``k / n``."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def photo_noise(truth, seed: int, varying: bool) -> CornerSet:
    """Exact corners plus white noise and a smooth warp of each photo's own (module docstring)."""
    rng = np.random.default_rng(seed)
    cams = {}
    for name, views in synth.true_corners(truth).items():
        W, H = truth.cameras[name].image_size
        out = {}
        for v, uv in views.items():
            scale = math.exp(rng.normal(0.0, VARYING_SIGMA)) if varying else 1.0
            q = (uv - [W / 2, H / 2]) / (max(W, H) / 2)
            basis = np.stack([np.ones(len(q)), q[:, 0], q[:, 1], q[:, 0] ** 2, q[:, 1] ** 2, q[:, 0] * q[:, 1]], 1)
            warp = basis @ rng.normal(0.0, WARP_PX, (2, 6)).T
            out[v] = uv + scale * (warp + rng.normal(0.0, WHITE_PX, uv.shape))
        cams[name] = CameraCorners(truth.cameras[name].image_size, out)
    return CornerSet(truth.board, cams)


def _replaced(truth, corners: CornerSet, name: str, views, pose_of, camera_of) -> CornerSet:
    """``corners`` with camera ``name``'s photos of ``views`` moved from where ``truth`` puts them to where
    ``pose_of(view)`` (board to camera) and ``camera_of(view)`` put them (their noise kept)."""
    X = truth.board.object_points_mm()
    exact = synth.true_corners(truth)[name]
    cams = dict(corners.cameras)
    moved = {v: corners.cameras[name].views[v] + project_points(camera_of(v), pose_of(v).apply(X)) - exact[v]
             for v in views}
    cams[name] = CameraCorners(cams[name].image_size, {**cams[name].views, **moved}, cams[name].meta)
    return CornerSet(corners.board, cams, corners.reference)


def desynchronised(truth, corners: CornerSet, seed: int, views) -> CornerSet:
    """``corners`` with the instants ``views`` of the first non-reference camera shot off the rig by
    :data:`DESYNC_MM` and :data:`DESYNC_ARCMIN` in random directions (their noise as the others')."""
    rng = np.random.default_rng(seed + 1000)
    name = next(n for n in sorted(truth.cameras) if n != truth.reference)
    rig = truth.rig[name]
    poses = {}
    for v in views:
        d, a = (x / np.linalg.norm(x) for x in rng.normal(size=(2, 3)))
        R = rotation_from_opk(a * DESYNC_ARCMIN * np.pi / (180 * 60))
        poses[v] = Pose(R @ rig.R, R @ rig.t_mm + DESYNC_MM * d).compose(truth.view_poses[v])
    cam = truth.cameras[name]
    return _replaced(truth, corners, name, views, poses.get, lambda v: cam)


def refocused(truth, corners: CornerSet, views) -> tuple[CornerSet, str]:
    """``corners`` with the first non-reference camera's photos of ``views`` taken at a focal length
    :data:`REFOCUS` longer, and that camera's name."""
    name = next(n for n in sorted(truth.cameras) if n != truth.reference)
    cam = truth.cameras[name]
    zoomed = replace(cam, fx=cam.fx * (1 + REFOCUS), fy=cam.fy * (1 + REFOCUS))
    return _replaced(truth, corners, name, views, lambda v: truth.camera_pose(name, v), lambda v: zoomed), name


def lens_split(truth, corners: CornerSet, longer: float) -> CornerSet:
    """The reference camera alone, every other photo of it through a lens ``longer`` (share) longer in focal length
    with half its k1 (two lenses of one image size merged into one camera)."""
    name = truth.reference
    cam = truth.cameras[name]
    other = replace(cam, fx=cam.fx * (1 + longer), fy=cam.fy * (1 + longer), k1=0.5 * cam.k1)
    views = list(truth.view_poses)[1::2]
    alone = CornerSet(corners.board, {name: corners.cameras[name]}, name)
    return _replaced(truth, alone, name, views, lambda v: truth.camera_pose(name, v), lambda v: other)


def _checks(corners: CornerSet, model: str, **options) -> dict:
    with collect_warnings():
        return calibrate_rig(corners, model=model, drop_outliers=False, **options).checks


def synthetic(presets, models, seeds, base, varying) -> None:
    """Every synthetic row (module docstring), printed as it is done."""
    for preset in presets:
        for model in models:
            c: dict[str, int] = {}
            t0 = time.perf_counter()

            def count(key, yes):
                c[key] = c.get(key, 0) + bool(yes)

            for i in range(seeds):
                seed = base + i
                truth = synth.make_truth(preset, 13, seed=seed)
                corners = photo_noise(truth, seed, varying)
                views = list(truth.view_poses)
                checks = _checks(corners, model)
                tails(c, checks)
                count("rigid names", checks["rig_rigid"]["flagged"])
                count("rigid fails", not checks["rig_rigid"]["ok"])
                count("focus fails", not checks["focus"]["ok"])
                for k in (1, 2, 3):
                    bad = [views[j] for j in BAD_INSTANTS[:k]]
                    rigid = _checks(desynchronised(truth, corners, seed, bad), model)["rig_rigid"]
                    count(f"desync {k} named", set(bad) <= set(rigid["flagged"]))
                    count(f"desync {k} good named", set(rigid["flagged"]) - set(bad))
                    photos, name = refocused(truth, corners, bad)
                    focus = _checks(photos, model)["focus"]
                    named = {(f["camera"], f["view"]) for f in focus["flagged"] if f["cause"] == "refocus"}
                    count(f"refocus {k} named", set(bad) <= {v for _, v in named})
                    count(f"refocus {k} photo named", {(name, v) for v in bad} <= named)
                    count(f"refocus {k} good named", {v for _, v in named} - set(bad))
                for longer in SPLITS:
                    split = _checks(lens_split(truth, corners, longer), model, rig_mode="none")["focus"]
                    count(f"split {longer:g} fails", not split["ok"])
                if preset == "triple":
                    loop_rows(c, count, truth, corners, views, model)
            print_row(preset, model, seeds, c, time.perf_counter() - t0)
            sys.stdout.flush()


def tails(c: dict, checks: dict) -> None:
    """Count the synchronised rig's instant (photo) statistics beyond the 1e-3 quantile of Student's t of the core's
    ``n - 1`` degrees of freedom and of half of them (what the checks take, ``checks.T_DOF_SHARE``)."""
    for key, tests, two_sided in (("rigid", checks["rig_rigid"]["instant_f"].values(), False),
                                  ("focus", checks["focus"]["photo_t"].values(), True)):
        for t in tests:
            tail = f_sf(t["t"] ** 2, 1, t["dof"] / T_DOF_SHARE)             # P(|T| > |t|), Student's t(n - 1)
            full = tail if two_sided else (0.5 * tail if t["t"] > 0 else 1.0)
            c[f"{key} tests"] = c.get(f"{key} tests", 0) + 1
            c[f"{key} beyond full"] = c.get(f"{key} beyond full", 0) + (full < 1e-3)
            c[f"{key} beyond half"] = c.get(f"{key} beyond half", 0) + (t["p"] < 1e-3)


def loop_rows(c, count, truth, corners: CornerSet, views, model: str) -> None:
    """``loop_closure`` on a triple rig: the ultra-wide in 4 instants (synchronised), then knocked."""
    few = CornerSet(corners.board, {**corners.cameras, "ultra": CameraCorners(
        corners.cameras["ultra"].image_size, {v: (uv if v in views[::4] else None)
                                              for v, uv in corners.cameras["ultra"].views.items()})}, corners.reference)
    loop = _checks(few, model).get("loop_closure")
    count("loop few fails", loop is None or not loop["ok"])
    rig = truth.rig["ultra"]
    knocked = Pose(rotation_from_opk(np.radians([10 / 60, 0, 0])) @ rig.R, rig.t_mm + [0.2, 0, 0])
    moved = _replaced(truth, corners, "ultra", views[6:], lambda v: knocked.compose(truth.view_poses[v]),
                      lambda v: truth.cameras["ultra"])
    loop = _checks(moved, model)["loop_closure"]
    count("loop knocked named", not loop["ok"] and "camera ultra in each" in loop["message"])


def _share(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return f"{100 * k / n:5.1f} % [{100 * lo:4.1f}, {100 * hi:4.1f}]"


def print_header(quick: bool) -> None:
    print(f"stated false-alarm rate: {100 * FALSE_ALARM_RATE:g} % per calibration and check; each share with its 95 % "
          "Wilson interval")
    print("rig_rigid 'names' = its test names an instant (the stated rate); 'fails' = the check fails (named instants "
          f"that move the rig by more than {SHIFT_SIGMAS:g} sigma); 'k named' = every one of k bad instants (photos) "
          "named; 'good named' = a good one named with them")


def print_row(preset: str, model: str, n: int, c: dict, seconds: float) -> None:
    print(f"\n{preset} ({model}), {n} seeds, {seconds:.0f} s")
    rows = [("synchronised, fixed focus", [("rig_rigid names", "rigid names"), ("rig_rigid fails", "rigid fails"),
                                           ("focus fails", "focus fails")])]
    rows += [(f"{k} desynchronised instant(s)", [("all named", f"desync {k} named"),
                                                 ("a good one named", f"desync {k} good named")]) for k in (1, 2, 3)]
    rows += [(f"{k} refocused photo(s) (+{100 * REFOCUS:g} %)", [("all named", f"refocus {k} named"),
                                                                 ("with their camera", f"refocus {k} photo named"),
                                                                 ("a good one named", f"refocus {k} good named")])
             for k in (1, 2, 3)]
    rows += [("lens split (rig mode none)", [(f"+{100 * s:g} %: focus fails", f"split {s:g} fails") for s in SPLITS])]
    if "loop few fails" in c:
        rows += [("loop_closure (triple)", [("ultra in 4 instants: fails", "loop few fails"),
                                            ("ultra knocked: named", "loop knocked named")])]
    for title, cells in rows:
        print(f"  {title:36s} " + "   ".join(f"{label} {_share(c.get(key, 0), n)}" for label, key in cells))
    for key, what in (("rigid", "instants (rig_rigid)"), ("focus", "photos (focus)")):
        m = c.get(f"{key} tests", 0)
        if m:
            print(f"  synchronised {what}: of {m} tests, beyond the 1e-3 quantile of t(n - 1) "
                  f"{1000 * c[f'{key} beyond full'] / m:.2f}e-3, of t((n - 1) / 2) {1000 * c[f'{key} beyond half'] / m:.2f}e-3")


def caliscope_corners(path: Path) -> CornerSet:
    """caliscope's intrinsic session (``xy_CHARUCO.csv``, its SOURCE.md): four webcams, 1280 x 720, a ChArUco board
    of 4 x 5 squares of 54 mm (12 inner corners, keypoint ``k = r * 3 + c``); each sync index one photo."""
    board = Board.charuco_board((4, 5), 54.0, 40.5, "DICT_4X4_1000")
    views: dict[str, dict[str, np.ndarray]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            photo = views.setdefault(f"cam_{row['cam_id']}", {}).setdefault(
                f"{int(row['sync_index']):03d}", np.full((board.n_corners, 2), np.nan))
            photo[int(row["keypoint_id"])] = float(row["img_loc_x"]), float(row["img_loc_y"])
    return CornerSet(board, {c: CameraCorners((1280, 720), v) for c, v in views.items()})


def _focus_line(label: str, focus: dict) -> str:
    stat = f"|t| {focus['statistic']:.2f} (limit {focus['limit']:.2f})" if focus["statistic"] is not None else "-"
    return (f"{label:11s} focus ok {str(focus['ok']):5s} worst {focus['worst']} {stat}; not judged "
            f"{len(focus['not_judged'])}; flagged {[(f['camera'], f['view'], f['cause']) for f in focus['flagged']]}")


def real_sets(models) -> None:
    """The real sets (module docstring); each skipped where ../shared/data lacks it."""
    from dualcal.files.dataset import open_dataset
    from dualcal.files.detect import detect_dataset

    stereo, huawei, bouguet, cali = (DATA / n for n in ("opencv-samples-stereo", "huawei-y5-2017",
                                                        "bouguet-calib-example", "caliscope-prerecorded"))
    if stereo.is_dir():
        corners = detect_dataset(open_dataset(stereo, ["left=left*.jpg", "right=right*.jpg"]), Board(9, 6, 30.0),
                                 jobs=1, progress=False)
        print("\nopencv-samples-stereo (9x6, rigid, reference left): rig_rigid and focus")
        for model in (*models, "auto"):
            rig = calibrate_rig(corners, reference="left", model=model)
            check = rig.checks["rig_rigid"]
            fs = check["instant_f"]
            named = ", ".join(f"{v} (F {fs[v]['f']:.1f}, limit {fs[v]['limit']:.1f}, p {fs[v]['p']:.1g})"
                              for v in check["flagged"]) or "-"
            print(f"{model:11s} rig_rigid ok {str(check['ok']):5s} named {named}; shift {check['shift_sigma']}; "
                  f"worst other p {min((t['p'] for v, t in fs.items() if v not in check['flagged']), default=1):.2g}; "
                  f"together {check['ratio']:.2f} (limit {check['limit_ratio']:.2f})")
            print(_focus_line("", rig.checks["focus"]))
    else:
        print(f"\n{stereo} absent: no real stereo set")
    for folder, cams, board in ((huawei, (), Board(7, 9, 30.0)), (bouguet, ["cam=Image*.tif"], Board(12, 13, 30.0))):
        if not folder.is_dir():
            print(f"\n{folder} absent")
            continue
        ds = open_dataset(folder, list(cams)) if cams else open_dataset(folder)
        corners = detect_dataset(ds, board, jobs=1, progress=False)
        print(f"\n{folder.name} (single camera): focus")
        for model in (*models, "auto"):
            with collect_warnings():
                print(_focus_line(model, calibrate_rig(corners, model=model).checks["focus"]))
    if (cali / "xy_CHARUCO.csv").is_file():
        print("\ncaliscope-prerecorded (four webcams, 12-corner ChArUco, rig mode none): focus")
        for model in (*models, "auto"):
            with collect_warnings():
                print(_focus_line(model, calibrate_rig(caliscope_corners(cali / "xy_CHARUCO.csv"), rig_mode="none",
                                                       model=model).checks["focus"]))
    else:
        print(f"\n{cali} absent")


def main() -> None:
    global WARP_PX  # noqa: PLW0603 (the noise of this run)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--base-seed", type=int, default=5000)
    ap.add_argument("--presets", nargs="+", default=["stereo", "note8", "triple"])
    ap.add_argument("--models", nargs="+", default=["k1k2"])
    ap.add_argument("--warp", type=float, default=0.03, help="px of each photo's smooth warp (0: white noise only)")
    ap.add_argument("--varying", action="store_true", help="each photo's noise scaled by exp(N(0, 0.35))")
    ap.add_argument("--quick", action="store_true", help="12 seeds, the stereo and triple presets")
    ap.add_argument("--no-real", action="store_true", help="leave out the real sets")
    ap.add_argument("--no-synthetic", action="store_true", help="only the real sets")
    args = ap.parse_args()
    WARP_PX = args.warp
    if args.quick:
        args.seeds, args.presets = 12, ["stereo", "triple"]
    if not args.no_synthetic:
        print(f"noise: white {WHITE_PX} px + a smooth warp of {WARP_PX} px per photo"
              f"{f', each photo scaled by exp(N(0, {VARYING_SIGMA}))' if args.varying else ''}; desync {DESYNC_MM} mm / "
              f"{DESYNC_ARCMIN} arcmin; refocus +{100 * REFOCUS:g} %; 13 instants; base seed {args.base_seed}")
        print_header(args.quick)
        synthetic(args.presets, args.models, args.seeds, args.base_seed, args.varying)
    if not args.no_real:
        real_sets(args.models)


if __name__ == "__main__":
    main()
