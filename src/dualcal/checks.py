"""Checks of a calibration: whether, and how far, to trust it.

Each check is ``{"ok": bool, "message": "...", ...}`` (calib.json's ``checks``, the contract), with
a message in plain words that says what is wrong and what would help:

``converged``      the adjustment reached its optimum.
``photos``         enough instants for sigmas that come from how the photos disagree.
``fit``            every camera's RMS (2-D, per corner) near what corner detection achieves.
``rig_rigid``      the photos of every instant fit one rigid relative pose of the cameras, judged
                   against the photo-level noise (an unsynchronised pair, a lens that moved).
``focus``          no photo whose own focal length is off by many sigma (the phone refocused).
``determination``  every parameter determined well enough (focal length, principal point,
                   distortion as far out as corners were measured, baseline, angles).
``lens_model``     residuals that do not grow towards the image's edge (the lens model lacks terms).
``scale_plausible`` where EXIF shows a phone's small sensor (focal length in mm and its 35 mm equivalent):
                   the board's distance and the lenses' spacing are a phone's (:func:`scale_plausibility`).
                   Every length scales with the board's square size, which only the user knows; a wrong
                   one passes every other check. Without those EXIF facts there is nothing to judge it by,
                   so there is no such check and :func:`scale_note` says that the scale rests on the square
                   (a check that always passes would only add to "all checks pass").

*Photo-level noise.* Corner errors within one photo are correlated on real photos, so a test
against white corner noise (``s0``) would fail every real rig. The checks measure noise in units of
``kappa^2 s0^2``, where the design effect ``kappa^2`` of a camera is how much more its photos
disagree than white noise allows: the median ratio of the clustered to the formal variance of
its intrinsics, never below 1 (:func:`design_effect`).
"""

from __future__ import annotations

import numpy as np

from .adjust import Solution, photo_rows
from .model import RigModel

__all__ = ["design_effect", "rig_rigid", "focus_drift", "determination", "fit_quality", "photo_count",
           "lens_model_fit", "convergence", "scale_plausibility", "scale_note", "run_checks", "verdict",
           "failed_checks"]

#: Fewer instants than this give unreliable sigmas (they come from the instants' scatter).
MIN_INSTANTS = 8
#: A camera's RMS (2-D, per corner) above this is far beyond what corner detection achieves.
FIT_RMS_LIMIT_PX = 1.0
#: False-alarm rate of the rigidity test, for all instants together and (Bonferroni) per instant.
RIGID_FALSE_ALARM = 1e-3
#: The instants together, or one instant, fail only where they also fit this many times worse than
#: the photo-level noise allows per degree of freedom. That noise is estimated from the intrinsics'
#: scatter, and the poses see more of an error that is smooth across one photo than the intrinsics do
#: (a shift of 0.02 px common to one photo's corners, independent between the cameras, already fits a
#: rigid rig 2-3 x worse than white noise of 0.05 px allows; the renders of ``make demo`` 1.6 x), while
#: a shot out of sync or a lens that moved fits tens to hundreds of times worse.
RIGID_RATIO = 10.0
#: A photo's own focal length this many sigma from the others' is a refocus.
FOCUS_SIGMAS = 5.0
#: Noise below this (px) is numerical: exact synthetic corners are judged against it instead.
NOISE_FLOOR_PX = 1e-6
#: Thresholds of ``determination``.
MAX_FOCAL_REL = 0.01               # sigma of fx, fy relative to the value
MAX_CENTRE_REL = 0.01              # sigma of cx, cy relative to the image width, height
MAX_DISTORTION_PX = 0.5            # sigma of the radial distortion at the outermost corner measured
MAX_BASELINE_REL = 0.02            # sigma of the baseline relative to it
MAX_ANGLE_ARCMIN = 30.0            # sigma of omega, phi, kappa
#: ``scale_plausible``: a sensor whose diagonal (from EXIF: 43.27 mm x focal length / its 35 mm
#: equivalent) is below this is a phone's (1/1.3" is 12 mm, a 1" type 16 mm), whose lenses sit this
#: far apart (mm) ...
PHONE_SENSOR_DIAGONAL_MM = 20.0
PHONE_BASELINE_MM = (5.0, 40.0)
#: ... and whose board is held this far away (mm; the median over the instants, from the reference camera).
PHONE_BOARD_DISTANCE_MM = (150.0, 5000.0)
#: The diagonal of the 35 mm film frame, mm (what a "35 mm equivalent" focal length refers to).
FILM_DIAGONAL_MM = 43.27

#: ``lens_model``: RMS of the outermost third of a camera's corners (by their distance from the
#: principal point) over that of the innermost third, beyond which the model misses terms.
EDGE_RATIO = 2.0


def design_effect(sol: Solution) -> dict[int, float]:
    """Per camera index: median over its free intrinsics of clustered / formal variance, at least 1."""
    out = {}
    for c in range(len(sol.problem.cameras)):
        clustered, formal = sol.intrinsic_sigma(c, "clustered"), sol.intrinsic_sigma(c, "formal")
        out[c] = max(1.0, float(np.median([(clustered[n] / s) ** 2 for n, s in formal.items() if s > 0])))
    return out


def _block_costs(sol: Solution) -> np.ndarray:
    return np.nansum(sol.residuals ** 2, axis=(1, 2))


def rig_rigid(tied: Solution, alone: Solution, kappa2: dict[int, float] | None = None) -> dict | None:
    """Whether every instant's photos fit one rigid relative pose (None for a rig of one camera or
    mode ``none``).

    Both solutions must be over the same photos: ``tied`` in rig mode ``rigid`` or ``paper``,
    ``alone`` with every camera alone. The extra cost of tying instant ``v``, in units of the
    photo-level noise ``kappa^2 s0^2`` of the cameras alone, is ``T_v``; for a rigid rig it is
    chi-square with ``6`` (rigid; ``4`` for the paper's model, whose baseline direction is free) degrees
    of freedom per tied camera of the instant, ``T = sum T_v`` with as many less one instant's worth
    per tied camera. The check fails where ``T`` or any ``T_v`` is beyond its chi-square quantile at
    :data:`RIGID_FALSE_ALARM` (per instant, divided by the number of instants), and it or that
    instant also fits :data:`RIGID_RATIO` times worse than the noise per degree of freedom.
    """
    from scipy.stats import chi2

    p = tied.problem
    if p.mode == "none" or len(p.cameras) < 2:
        return None
    kappa2 = max((design_effect(alone) if kappa2 is None else kappa2).values())
    noise = max(kappa2 * alone.s0_px ** 2, NOISE_FLOOR_PX ** 2)
    extra = _block_costs(tied) - _block_costs(alone)
    per = 6 if p.mode == "rigid" else 4
    stats, dofs = {}, {}
    for v, view in enumerate(p.views):
        blocks = [b for b, (c, vv, _) in enumerate(p.blocks) if vv == view]
        cams = {p.blocks[b][0] for b in blocks}
        k = per * len(cams - {p.reference}) if p.reference in cams else 0
        if k:
            stats[view] = float(extra[blocks].sum() / noise)
            dofs[view] = k
    tied_cams = [c for c in range(len(p.cameras)) if c != p.reference and any(
        p.blocks[b][0] == c for b in range(len(p.blocks)))]
    dof = sum(dofs.values()) - per * len(tied_cams)
    if dof <= 0 or not stats:
        return None
    total = float(sum(stats.values()))
    limit_total = float(chi2.ppf(1.0 - RIGID_FALSE_ALARM, dof))
    limits = {v: float(chi2.ppf(1.0 - RIGID_FALSE_ALARM / len(stats), k)) for v, k in dofs.items()}
    flagged = sorted((v for v in stats if stats[v] > max(limits[v], RIGID_RATIO * dofs[v])),
                     key=lambda v: -stats[v])
    ratio = total / dof
    ok = total <= max(limit_total, RIGID_RATIO * dof) and not flagged
    doc = {"ok": ok, "ratio": ratio, "limit_ratio": max(limit_total / dof, RIGID_RATIO), "design_effect": kappa2,
           "instants": {v: round(t, 3) for v, t in stats.items()}, "flagged": flagged}
    if ok:
        doc["message"] = (f"the photos of every instant fit one rigid relative pose ({ratio:.2f} x the photo-level "
                          f"noise on average, limit {max(limit_total / dof, RIGID_RATIO):.3g})")
    elif flagged:
        worst = ", ".join(f"{v} ({stats[v] / dofs[v]:.0f} x)" for v in flagged[:5])
        doc["message"] = (f"the photos of {len(flagged)} instant(s) do not fit the rig's relative pose: {worst} the "
                          "photo-level noise: shots not taken at the same instant, a lens that moved (stabiliser, "
                          "focus) or a board that moved between the cameras' shots; drop them with --exclude or "
                          "shoot them again")
    else:
        doc["message"] = (f"the instants fit one rigid relative pose {ratio:.1f} x worse than the photo-level noise "
                          f"allows (limit {RIGID_RATIO:.3g}): the cameras' shots are not synchronised, or the "
                          "rig is not rigid; its baseline and angles hold only on average")
    return doc


def focus_drift(sol: Solution, kappa2: dict[int, float]) -> dict:
    """Photos whose own focal length is off.

    Each photo's focal scale (``fx``, ``fy`` times ``1 + s``) is fitted with its instant's own
    unknowns (the board pose; in a rig it is held by the instant's other photos too, so a tele that
    refocused shows against the wide) and every other parameter held, linearised at the solution
    ``sol``; ``s`` against its sigma in photo-level noise (``kappa2[c]`` for camera ``c``) is flagged
    beyond :data:`FOCUS_SIGMAS`.
    """
    p, lay = sol.problem, sol.problem.layout
    by_instant: dict[str, list] = {}
    for pr in photo_rows(p, sol.state):
        by_instant.setdefault(p.blocks[pr.block][1], []).append(pr)
    flagged = []
    for view, rows in by_instant.items():
        local = np.unique(np.concatenate([pr.columns[pr.columns >= lay.n_global] for pr in rows]))
        m = sum(len(pr.r) for pr in rows)
        J_local, r = np.zeros((m, len(local))), np.concatenate([pr.r for pr in rows])
        row = 0
        for pr in rows:
            own = pr.columns >= lay.n_global
            J_local[row:row + len(pr.r), np.searchsorted(local, pr.columns[own])] = pr.J[:, own]
            row += len(pr.r)
        row = 0
        for pr in rows:
            c = p.blocks[pr.block][0]
            col = {int(k): i for i, k in enumerate(pr.columns)}
            fx_col, fy_col = lay.intrinsics[c][:2]                 # fx and fy are always free
            cam = sol.state.intrinsics[c]
            J_scale = np.zeros(m)
            J_scale[row:row + len(pr.r)] = cam[0] * pr.J[:, col[fx_col]] + cam[1] * pr.J[:, col[fy_col]]
            row += len(pr.r)
            A = np.column_stack([J_local, J_scale])
            try:
                inv = np.linalg.inv(A.T @ A)
            except np.linalg.LinAlgError:
                continue
            s = -(inv @ (A.T @ r))[-1]
            z = s / np.sqrt(max(kappa2[c] * sol.s0_px ** 2, NOISE_FLOOR_PX ** 2) * inv[-1, -1])
            if abs(z) > FOCUS_SIGMAS:
                flagged.append({"camera": p.cameras[c], "view": view, "focal_change": float(s), "sigmas": float(z)})
    flagged.sort(key=lambda f: -abs(f["sigmas"]))
    if not flagged:
        return {"ok": True, "flagged": [], "message": f"no photo's own focal length is off by more than "
                                                      f"{FOCUS_SIGMAS:g} sigma"}
    worst = ", ".join(f"{f['camera']}/{f['view']} ({100 * f['focal_change']:+.2f} %, {abs(f['sigmas']):.0f} sigma)"
                      for f in flagged[:4])
    return {"ok": False, "flagged": flagged,
            "message": f"{len(flagged)} photo(s) have a focal length of their own: {worst}: the phone refocused or "
                       "zoomed between shots; lock focus (AF/AE lock) and shoot again, or leave them out with --exclude"}


def _covariance(rig: RigModel, names: list[str]) -> np.ndarray | None:
    if not rig.covariance:
        return None
    index = {n: i for i, n in enumerate(rig.covariance["parameters"])}
    if not all(n in index for n in names):
        return None
    idx = [index[n] for n in names]
    return np.asarray(rig.covariance["clustered"])[np.ix_(idx, idx)]


def determination(rig: RigModel) -> dict:
    """Parameters known too poorly to use, in plain words with what would help (thresholds above)."""
    problems = []
    used = rig.used_corners()
    for name, cam in rig.cameras.items():
        sig = rig.camera_sigma[name]
        w, h = cam.image_size
        for key in ("fx", "fy"):
            rel = sig.get(key, 0.0) / getattr(cam, key)
            if rel > MAX_FOCAL_REL:
                problems.append(f"{name} {key} known only to +-{100 * rel:.1f} %: add photos with the board tilted "
                                "30-50 degrees in different directions")
        for key, size in (("cx", w), ("cy", h)):
            if sig.get(key, 0.0) > MAX_CENTRE_REL * size:
                problems.append(f"{name} {key} known only to +-{sig[key]:.0f} px: add photos with the board tilted "
                                "and in every part of the frame")
        # the radial distortion where the data reach: beyond the outermost corner it is extrapolated
        uv = np.vstack([uv for uv in used.cameras[name].found().values()] or [np.zeros((0, 2))])
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        terms = [k for k in ("k1", "k2", "k3") if sig.get(k, 0.0) > 0]
        cov = _covariance(rig, [f"{name}.{k}" for k in terms])
        if cov is not None and terms and len(uv):
            r = float(np.max(np.hypot((uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy)))
            g = 0.5 * (cam.fx + cam.fy) * r * np.array([r ** (2 * (i + 1)) for i in range(len(terms))])
            s = float(np.sqrt(max(g @ cov @ g, 0.0)))
            if s > MAX_DISTORTION_PX:
                problems.append(f"{name} distortion known only to +-{s:.1f} px at the outermost corner measured: "
                                "add photos with the board near the corners and edges of the frame")
    for name, rel in rig.rig.items():
        D = rel.baseline_mm
        if D > 0 and rel.sigma_baseline_mm > MAX_BASELINE_REL * D:
            problems.append(f"{name} baseline known only to +-{100 * rel.sigma_baseline_mm / D:.1f} %: add instants "
                            "with the board tilted, at several distances")
        if np.max(rel.sigma_opk_arcmin) > MAX_ANGLE_ARCMIN:
            problems.append(f"{name} relative angles known only to +-{np.max(rel.sigma_opk_arcmin):.0f} arcmin: add "
                            "instants with the board tilted in different directions")
    if not problems:
        return {"ok": True, "problems": [], "message": "every parameter is well determined"}
    return {"ok": False, "problems": problems, "message": "; ".join(problems)}


def fit_quality(rig: RigModel) -> dict:
    """Every camera's RMS (2-D, per corner) below :data:`FIT_RMS_LIMIT_PX`."""
    bad = {n: r for n, r in rig.camera_rms_px.items() if r > FIT_RMS_LIMIT_PX}
    if not bad:
        return {"ok": True, "message": "every camera fits its corners to "
                                       f"{max(rig.camera_rms_px.values()):.3g} px RMS (2-D, per corner) or better"}
    worst = ", ".join(f"{n} {r:.2f} px" for n, r in bad.items())
    return {"ok": False, "message": f"RMS (2-D, per corner) {worst}, far above what corner detection achieves on sharp "
                                    "photos (0.02-0.3 px): a board that is not flat or not printed true, blurred or "
                                    "moving photos, or corners found wrongly; the sigmas account for it, but check "
                                    "the board and the photos"}


def photo_count(rig: RigModel) -> dict:
    """At least :data:`MIN_INSTANTS` instants."""
    n = len({v for poses in rig.camera_poses.values() for v in poses})
    if n >= MIN_INSTANTS:
        return {"ok": True, "instants": n, "message": f"{n} instants"}
    return {"ok": False, "instants": n,
            "message": f"only {n} instants: 10-20, the board tilted 30-50 degrees in different directions and "
                       "reaching the corners of the frame, give parameters and sigmas you can rely on (the sigmas "
                       "come from how the photos disagree with each other)"}


def lens_model_fit(sol: Solution) -> dict:
    """Residuals that grow towards the image's edge: a model problem, reported, never a reason to drop."""
    p = sol.problem
    bad, views = [], []
    for c, name in enumerate(p.cameras):
        cam = sol.state.camera(p, c)
        w, h = cam.image_size
        rho_all, len_all = [], []
        for b, (cc, view, uv) in enumerate(p.blocks):
            if cc != c:
                continue
            length = np.linalg.norm(sol.residuals[b], axis=1)
            seen = np.isfinite(length)
            rho = np.hypot(uv[seen, 0] - cam.cx, uv[seen, 1] - cam.cy)
            rho_all.append(rho)
            len_all.append(length[seen])
            if _edge_ratio(rho, length[seen]) > EDGE_RATIO:
                views.append(f"{name}/{view}")
        ratio = _edge_ratio(np.concatenate(rho_all), np.concatenate(len_all)) if rho_all else np.nan
        if ratio > EDGE_RATIO:
            bad.append(f"{name} ({ratio:.1f} x)")
    if not bad:
        return {"ok": True, "views": views, "message": "residuals do not grow towards the image's edge"}
    return {"ok": False, "views": views,
            "message": f"residuals at the image's edge are far larger than at its centre: {', '.join(bad)}: the lens "
                       "model misses terms; try --model with more coefficients (k1k2p1p2k3), and see the report's "
                       "residual plots"}


def _edge_ratio(rho: np.ndarray, length: np.ndarray, min_points: int = 10) -> float:
    """RMS of the residual lengths of the outermost third of the corners (by ``rho``) over that of the
    innermost third (NaN with fewer than ``min_points`` in a third)."""
    if len(rho) < 3 * min_points:
        return float("nan")
    lo, hi = np.quantile(rho, [1 / 3, 2 / 3])
    inner, outer = length[rho <= lo], length[rho >= hi]
    return float(np.sqrt(np.mean(outer ** 2)) / max(np.sqrt(np.mean(inner ** 2)), 1e-12))


def convergence(sol: Solution) -> dict:
    if sol.converged:
        return {"ok": True, "message": f"the adjustment converged in {sol.iterations} iterations"}
    return {"ok": False, "message": f"the adjustment did not converge ({sol.termination}): the results and their sigmas "
                                    "are not those of the best fit"}


def _sensor_diagonals_mm(rig: RigModel) -> dict[str, float]:
    """Each camera's sensor diagonal from its corners' EXIF facts (``meta["exif"]``), where they are given."""
    out = {}
    for name, cam in rig.corners.cameras.items():
        exif = cam.meta.get("exif") or {}
        f_mm, f35_mm = exif.get("focal_length_mm"), exif.get("focal_length_35mm_mm")
        if isinstance(f_mm, (int, float)) and isinstance(f35_mm, (int, float)) and f_mm > 0 and f35_mm > 0:
            out[name] = FILM_DIAGONAL_MM * f_mm / f35_mm
    return out


def scale_plausibility(rig: RigModel) -> dict | None:
    """The ``scale_plausible`` check (module docstring), or None where no camera's EXIF shows a phone's sensor.

    Returns ``{"ok", "message", "sensor_diagonal_mm": {camera: mm}, "board_distance_mm": median over the
    instants, "baseline_mm": {camera: mm}}``.
    """
    diagonals = _sensor_diagonals_mm(rig)
    if not diagonals or max(diagonals.values()) >= PHONE_SENSOR_DIAGONAL_MM:
        return None
    centre = rig.board.object_points_mm().mean(axis=0)
    distance = float(np.median([np.linalg.norm(p.R @ centre + p.t_mm) for p in rig.reference_poses().values()]))
    baselines = {name: float(rel.baseline_mm) for name, rel in rig.rig.items()}
    problems = []
    lo, hi = PHONE_BOARD_DISTANCE_MM
    if not lo <= distance <= hi:
        problems.append(f"the board is {distance:.0f} mm from the {rig.reference} camera, where a phone's board is "
                        f"held {lo / 1000:g}-{hi / 1000:g} m away")
    lo, hi = PHONE_BASELINE_MM
    odd = {n: b for n, b in baselines.items() if not lo <= b <= hi}
    if odd:
        problems.append(f"the lenses are {', '.join(f'{n} {b:.1f} mm' for n, b in odd.items())} apart, where a "
                        f"phone's are {lo:g}-{hi:g} mm")
    doc = {"sensor_diagonal_mm": diagonals, "board_distance_mm": distance, "baseline_mm": baselines}
    sensors = ", ".join(f"{n} {d:.1f} mm" for n, d in diagonals.items())
    if problems:
        return {"ok": False, **doc,
                "message": f"{'; '.join(problems)} (a phone's sensor by EXIF: diagonal {sensors}): is the board's "
                           f"square really {rig.board.square_mm:g} mm? Every length scales with it"}
    return {"ok": True, **doc,
            "message": f"the board's distance ({distance:.0f} mm) and the lenses' spacing are a phone's (sensor "
                       f"diagonal by EXIF {sensors}), as a square of {rig.board.square_mm:g} mm makes them"}


def scale_note(rig: RigModel) -> str:
    """One line for a calibration without the ``scale_plausible`` check: what its lengths rest on."""
    return (f"the scale (every length in mm) rests on the board's square of {rig.board.square_mm:g} mm alone: "
            "the photos' EXIF has no focal length and 35 mm equivalent of a phone's lens to judge it by")


def run_checks(rig: RigModel, sol: Solution, tied_flat: Solution, alone: Solution) -> dict:
    """Every check of a calibration: ``rig`` and its final solution ``sol``; ``tied_flat`` the same
    rig mode with a flat board and ``alone`` every camera alone, over the same photos (for
    ``rig_rigid`` and ``focus``)."""
    checks = {"converged": convergence(sol), "photos": photo_count(rig), "fit": fit_quality(rig)}
    kappa2 = design_effect(alone)
    rigid = rig_rigid(tied_flat, alone, kappa2)
    if rigid is not None:
        checks["rig_rigid"] = rigid
    checks["focus"] = focus_drift(tied_flat, kappa2)
    checks["determination"] = determination(rig)
    checks["lens_model"] = lens_model_fit(sol)
    scale = scale_plausibility(rig)
    if scale is not None:
        checks["scale_plausible"] = scale
    return checks


def failed_checks(checks: dict) -> list[str]:
    return [name for name, c in checks.items() if not c.get("ok", True)]


def verdict(checks: dict) -> str:
    """One line: whether to trust the calibration, naming the checks that fail."""
    if not checks:
        return "verdict: no checks were run"
    failed = failed_checks(checks)
    if not failed:
        return f"verdict: all {len(checks)} checks pass: the results and their sigmas hold for these photos"
    return f"verdict: use with care: {len(failed)} of {len(checks)} checks fail ({', '.join(failed)})"
