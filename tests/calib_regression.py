"""A calibration's results as numbers to compare, and the comparison: the regression harness of the pipeline.

:func:`summary` takes from a :class:`~dualcal.geometry.model.RigModel` every value calib.json reports with a
sigma (each camera's intrinsics, each rig relation's translation, baseline and angles, the board's shape), the
sigmas (``sigma`` and ``sigma_formal``), the joint covariance, the fit (s0, RMS, held-out errors), the photos
and corners left out, the lens models chosen and compared, and every check's ``ok`` and what it names.
:func:`differences` compares two summaries: a value moved by more than ``tol_sigma`` of its sigma, a sigma or
a fit figure changed by more than ``tol_sigma`` of itself, a covariance entry by more than ``tol_sigma`` of
``sqrt(C_ii C_jj)``, or anything else that differs (a check's verdict, a photo left out, a model chosen) is
one line each.

The cases (:data:`SYNTHETIC_CASES`; the real sets in ``benchmarks/bench_calibrate_regression.py``) are
corner sets with known recipes (a synth preset, its seeds and noise, and what is planted in them) and the
options of :func:`dualcal.calibrate_rig`. ``tests/test_calibrate_regression.py`` holds a few of them, and the
real stereo rig's corners, against references made with main's code (``tests/data/calibrate_regression.json``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dualcal.geometry.camera import INTRINSIC_NAMES, project_points
from dualcal.geometry.model import CameraCorners, CornerSet, Pose, RigModel
from dualcal.geometry.rotation import rotation_from_opk
from dualcal.synthetic import synth

#: The comparison's tolerance: a value within this share of its sigma, a sigma within this share of itself.
TOL_SIGMA = 1e-6


# ----------------------------------------------------------------------------- the cases


def planted(corners: CornerSet, truth: synth.SynthTruth, plant: str | None, seed: int) -> CornerSet:
    """``corners`` with one kind of trouble planted (None: as they are): ``outliers`` (a corner in every
    third photo off by 3-6 px, one photo's corners shuffled), ``desync`` (one instant's second camera shot
    0.5 mm and 1.5 arcmin off the rig), ``refocus`` (one photo of the second camera with a focal length 0.5 %
    longer), ``moved`` (one instant's board moved by 25 px in its second camera)."""
    if plant is None:
        return corners
    rng = np.random.default_rng(seed + 500)
    names = sorted(truth.cameras, key=lambda n: n != truth.reference)
    second, views = names[1], list(truth.view_poses)
    view = views[len(views) // 2]
    cams = {n: CameraCorners(c.image_size, {v: None if uv is None else np.array(uv, float)
                                            for v, uv in c.views.items()}, c.meta)
            for n, c in corners.cameras.items()}
    X = truth.board.object_points_mm()
    if plant == "outliers":
        for n, cc in cams.items():
            for i, v in enumerate(sorted(cc.views)):
                if i % 3 == 0:
                    k = rng.integers(len(X))
                    cc.views[v][k] += rng.choice([-1, 1], 2) * rng.uniform(3, 6, 2)
        cams[second].views[view] = cams[second].views[view][rng.permutation(len(X))]
    elif plant in ("desync", "refocus"):
        cam, pose = truth.cameras[second], truth.camera_pose(second, view)
        if plant == "refocus":
            cam = replace(cam, fx=cam.fx * 1.005, fy=cam.fy * 1.005)
        else:
            d, a = (u / np.linalg.norm(u) for u in rng.normal(size=(2, 3)))
            R, rel = rotation_from_opk(a * 1.5 * np.pi / (180 * 60)), truth.rig[second]
            pose = Pose(R @ rel.R, R @ rel.t_mm + 0.5 * d).compose(truth.view_poses[view])
        cams[second].views[view] = project_points(cam, pose.apply(X)) + rng.normal(0, 0.05, (len(X), 2))
    elif plant == "moved":
        cams[second].views[view] = cams[second].views[view] + np.array([25.0, 0.0])
    else:
        raise ValueError(f"unknown plant {plant!r}")
    return CornerSet(corners.board, cams)


def synthetic_corners(preset: str, views: int, seed: int, noise_px: float, plant: str | None = None,
                      truth=None) -> CornerSet:
    """The corners of a synthetic case: ``preset``'s rig (or ``truth(views, seed)``), noise of ``noise_px``
    (seed ``seed + 1``) and the trouble ``plant`` (:func:`planted`)."""
    truth = synth.make_truth(preset, views, seed=seed) if truth is None else truth(views, seed)
    return planted(synth.noisy_corner_set(truth, noise_px, seed=seed + 1), truth, plant, seed)


def _case(preset, views, seed, noise_px, plant=None, **options) -> dict:
    name = "-".join([preset, str(views), *(f"{k}={v}" for k, v in options.items()), *([plant] if plant else [])])
    return {"name": name, "preset": preset, "views": views, "seed": seed, "noise_px": noise_px, "plant": plant,
            "options": options}


#: Every synthetic preset under the lens models (auto, fixed), the rig modes and both skew models, and the
#: troubles the outlier rounds, the attribution of the checks and the board-shape test exist for.
SYNTHETIC_CASES = [
    *(_case(p, 12, 1, 0.1, model=m, rig_mode=r, skew=s)
      for p in ("stereo", "note8", "triple")
      for m, r, s in (("auto", "rigid", False), ("auto", "paper", False), ("auto", "none", False),
                      ("k1k2", "rigid", True), ("k1k2", "paper", True), ("k1k2", "none", False))),
    _case("phone3", 12, 2, 0.1, model="auto", rig_mode="rigid", skew=False),
    _case("stereo", 12, 3, 0.1, "outliers", model="auto", rig_mode="rigid", skew=False),
    _case("note8", 13, 5, 0.05, "outliers", model="k1k2", rig_mode="none", skew=False),
    _case("note8", 13, 0, 0.05, "desync", model="k1k2", rig_mode="rigid", skew=False),
    _case("note8", 13, 1, 0.05, "refocus", model="k1k2", rig_mode="rigid", skew=False),
    _case("triple", 12, 5, 0.1, "desync", model="auto", rig_mode="rigid", skew=False),
    _case("stereo", 12, 6, 0.1, "moved", model="k1k2", rig_mode="paper", skew=False),
    _case("note8", 12, 7, 0.1, model="k1k2", rig_mode="rigid", skew=False, board_shape="fit"),
    _case("stereo", 12, 8, 0.1, model="k1k2", rig_mode="rigid", skew=False, drop_outliers=False),
]


# ----------------------------------------------------------------------------- what is compared


def _floats(values) -> list[float]:
    return [float(x) for x in np.ravel(values)]


def summary(rig: RigModel) -> dict:
    """Every number and decision of ``rig`` that the comparison looks at (module docstring), as JSON."""
    values, sigma, formal = {}, {}, {}
    for name, cam in rig.cameras.items():
        for p in INTRINSIC_NAMES:
            key = f"{name}.{p}"
            values[key] = float(getattr(cam, p))
            sigma[key] = float(rig.camera_sigma[name][p])
            formal[key] = float(rig.camera_sigma_formal[name][p])
    for name, rel in rig.rig.items():
        for what, v, s, f in (("t_mm", rel.pose.t_mm, rel.sigma_t_mm, rel.sigma_formal.get("t_mm")),
                              ("opk_arcmin", rel.pose.opk_arcmin, rel.sigma_opk_arcmin,
                               rel.sigma_formal.get("opk_arcmin")),
                              ("baseline_mm", [rel.baseline_mm], [rel.sigma_baseline_mm],
                               [rel.sigma_formal.get("baseline_mm")])):
            for i, (vi, si, fi) in enumerate(zip(_floats(v), _floats(s), np.ravel(f))):
                key = f"{name}.rig.{what}.{i}"
                values[key], sigma[key], formal[key] = vi, si, float(fi)
    if rig.board_shape_mm is not None:
        for i, (v, s) in enumerate(zip(rig.board_shape_mm, rig.board_shape_sigma_mm)):
            values[f"board.shape.{i}"], sigma[f"board.shape.{i}"] = float(v), float(s)
    adj = rig.adjustment
    fit = {"s0_px": adj["s0_px"], "rms_px": rig.rms_px, "held_out_rms_px": adj.get("held_out_rms_px"),
           **{f"rms_px.{n}": r for n, r in rig.camera_rms_px.items()}}
    for entry in adj.get("lens_models", []):
        for n, d in entry["per_camera"].items():
            if d.get("candidate"):
                fit[f"lens_models.{entry['model']}.{n}.held_out_rms_px"] = d["held_out_rms_px"]
    checks = {}
    for name, c in rig.checks.items():
        flagged = c.get("flagged", c.get("problems", []))
        checks[name] = {"ok": bool(c.get("ok", True)),
                        "flagged": sorted(f if isinstance(f, str) else f"{f['camera']}/{f['view']}" for f in flagged)}
        if name == "loop_closure":
            checks[name]["pairs"] = {k: bool(p["ok"]) for k, p in c.get("pairs", {}).items()}
    cov = rig.covariance or {}
    return {"values": values, "sigma": sigma, "sigma_formal": formal,
            "fit": {k: None if v is None else float(v) for k, v in fit.items()},
            "covariance": {"parameters": cov.get("parameters", []), "clustered": cov.get("clustered", []),
                           "formal": cov.get("formal", [])},
            "dropped_views": sorted(f"{d.get('camera')}/{d['view']}" for d in rig.dropped_views),
            "dropped_corners": sorted(f"{d['camera']}/{d['view']}/{d['corner']}" for d in rig.dropped_corners),
            "lens_models_chosen": adj.get("lens_models_chosen"), "board_shape": rig.board_shape_mm is not None,
            "checks": checks}


def differences(ref: dict, new: dict, tol_sigma: float = TOL_SIGMA) -> list[str]:
    """Every way ``new`` differs from ``ref`` (two :func:`summary`'s) beyond ``tol_sigma`` (module docstring)."""
    if "error" in ref or "error" in new:
        return [] if ref.get("error") == new.get("error") else [f"error: {ref.get('error')} -> {new.get('error')}"]
    out = []
    for key in ("dropped_views", "dropped_corners", "lens_models_chosen", "board_shape"):
        if ref[key] != new[key]:
            out.append(f"{key}: {ref[key]} -> {new[key]}")
    for name in ref["checks"].keys() | new["checks"].keys():
        if ref["checks"].get(name) != new["checks"].get(name):
            out.append(f"check {name}: {ref['checks'].get(name)} -> {new['checks'].get(name)}")
    if set(ref["values"]) != set(new["values"]):
        out.append(f"parameters: {sorted(set(ref['values']) ^ set(new['values']))}")
    for key in ref["values"].keys() & new["values"].keys():
        s = ref["sigma"][key]
        d = abs(new["values"][key] - ref["values"][key])
        if d > tol_sigma * s or (s == 0 and d > 1e-12 * max(1.0, abs(ref["values"][key]))):
            out.append(f"{key}: {ref['values'][key]!r} -> {new['values'][key]!r} ({d / s if s else np.inf:.3g} sigma)")
        for kind in ("sigma", "sigma_formal"):
            a, b = ref[kind].get(key), new[kind].get(key)
            if a is not None and b is not None and abs(b - a) > tol_sigma * abs(a) + 1e-300:
                out.append(f"{kind} of {key}: {a!r} -> {b!r} ({abs(b - a) / abs(a) if a else np.inf:.3g} of itself)")
    for key in ref["fit"].keys() | new["fit"].keys():
        a, b = ref["fit"].get(key), new["fit"].get(key)
        if (a is None) != (b is None) or (a is not None and abs(b - a) > tol_sigma * abs(a)):
            out.append(f"fit {key}: {a!r} -> {b!r}")
    rc, nc = ref.get("covariance"), new.get("covariance")
    if rc is None or nc is None:
        return out
    if rc["parameters"] != nc["parameters"]:
        out.append(f"covariance parameters: {rc['parameters']} -> {nc['parameters']}")
    else:
        for kind in ("clustered", "formal"):
            a, b = np.asarray(rc[kind], float), np.asarray(nc[kind], float)
            if a.size:
                scale = np.sqrt(np.outer(np.diag(a), np.diag(a))) + 1e-300
                worst = float(np.max(np.abs(b - a) / scale))
                if worst > tol_sigma:
                    out.append(f"covariance {kind}: an entry moved by {worst:.3g} of sqrt(C_ii C_jj)")
    return out


def largest_shift_sigma(ref: dict, new: dict) -> float:
    """The largest ``|new - ref| / sigma`` over the parameters both have (0 where none moved)."""
    return max((abs(new["values"][k] - ref["values"][k]) / ref["sigma"][k]
                for k in ref["values"].keys() & new["values"].keys() if ref["sigma"][k] > 0), default=0.0)
