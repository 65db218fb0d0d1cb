"""Checks of a calibration: whether, and how far, to trust it.

Each check is ``{"ok": bool, "message": "...", ...}`` (calib.json's ``checks``, the contract), with
a message in plain words that says what is wrong and what would help:

``converged``      the adjustment reached its optimum.
``photos``         enough instants for sigmas that come from how the photos disagree.
``fit``            every camera's RMS (2-D, per corner) near what corner detection achieves.
``rig_rigid``      the photos of every instant fit one rigid relative pose of the cameras: each instant
                   judged against the other instants' scatter (an F test), the instants together against
                   the photo-level noise (an unsynchronised pair, a lens that moved).
``focus``          no photo whose own focal length is off against the scatter of its camera's other
                   photos (a Student t test: the phone refocused).
``determination``  every parameter determined well enough (focal length, principal point,
                   distortion as far out as corners were measured, baseline, angles).
``lens_model``     residuals that do not grow towards the image's edge (the lens model lacks terms).
``scale_plausible`` where EXIF shows a phone's small sensor (focal length in mm and its 35 mm equivalent):
                   the board's distance and the lenses' spacing are a phone's (:func:`scale_plausibility`).
                   Every length scales with the board's square size, which only the user knows; a wrong
                   one passes every other check. Without those EXIF facts there is nothing to judge it by,
                   so there is no such check and :func:`scale_note` says that the scale rests on the square
                   (a check that always passes would only add to "all checks pass").

*False alarms.* ``rig_rigid`` and ``focus`` take their limits from the distribution of their statistic
on a synchronised rig with a fixed focus, at :data:`FALSE_ALARM_RATE` per calibration, split over their
tests; the statistic of one instant (photo) is judged against the scatter of the others, so that the
calibration's own noise, lens-model error included, sets the limit. Each gives ``test`` (its name),
``statistic`` (the worst instant's or photo's), ``limit`` (that test's) and ``false_alarm_rate``.
``benchmarks/bench_false_alarms.py`` measures the rates. The other checks have fixed limits: physical
ones (what corner detection achieves, a sigma too large to use), said in their entries.

*Photo-level noise.* Corner errors within one photo are correlated on real photos, so a test
against white corner noise (``s0``) would fail every real rig. The checks measure noise in units of
``kappa^2 s0^2``, where the design effect ``kappa^2`` of a camera is how much more its photos
disagree than white noise allows: the median ratio of the clustered to the formal variance of
its intrinsics, never below 1 (:func:`design_effect`).
"""

from __future__ import annotations

import numpy as np

from .adjust import Solution, photo_rows
from .distributions import f_quantile, f_sf, sidak
from .rig_relations import rig_relation
from ..errors import EstimationError
from ..geometry.camera import FULL_FRAME_DIAGONAL_MM
from ..geometry.model import RigModel
from ..geometry.rotation import ARCMIN_PER_RAD, opk_from_rotation

__all__ = ["design_effect", "rig_rigid", "rigidity_statistics", "focus_drift", "focal_scale_fits", "tie_costs",
           "determination", "fit_quality", "photo_count", "lens_model_fit", "convergence", "scale_plausibility",
           "scale_note", "run_checks", "verdict", "relation_shift_sigma", "check_limits", "instant_f_tests",
           "focal_t_tests", "focal_scale_sigmas", "dof_share", "failed_checks"]

#: Fewer instants than this give unreliable sigmas (they come from the instants' scatter).
MIN_INSTANTS = 8
#: A camera's RMS (2-D, per corner) above this is far beyond what corner detection achieves.
FIT_RMS_LIMIT_PX = 1.0
#: The false-alarm rate of each check with a statistical limit (``rig_rigid``, ``focus``), per calibration:
#: on a synchronised rig with a fixed focus, one calibration in a hundred fails the check by chance. It is
#: split over the check's tests (one per instant, or per photo) by :func:`dualcal.estimation.distributions.sidak`.
FALSE_ALARM_RATE = 0.01
#: ... where that focal change takes away at least this share of its instant's extra cost of being tied
#: to the rig (a desynchronised shot also pulls the focal lengths, but explains little of its misfit so).
REFOCUS_SHARE = 0.6
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

#: ``lens_model``: RMS of the outermost third of a camera's corners (by their distance from the
#: principal point) over that of the innermost third, beyond which the model misses terms.
EDGE_RATIO = 2.0


def design_effect(sol: Solution) -> dict[int, float]:
    """Per camera index: median over its free intrinsics of clustered / formal variance, at least 1."""
    out = {}
    for c in range(len(sol.problem.cameras)):
        clustered, formal = sol.intrinsic_sigma(c, "clustered"), sol.intrinsic_sigma(c, "formal")
        ratios = [(clustered[n] / s) ** 2 for n, s in formal.items() if s > 0]
        out[c] = max(1.0, float(np.median(ratios))) if ratios else 1.0          # none free: intrinsics held fixed
    return out


def _block_costs(sol: Solution) -> np.ndarray:
    return np.nansum(sol.residuals ** 2, axis=(1, 2))


def rigidity_statistics(tied: Solution, alone: Solution, kappa2: dict[int, float] | None = None):
    """Per instant, the extra cost of tying its photos to one relative pose, in units of the photo-level
    noise, its degrees of freedom and its leverage; and the noise ``kappa^2 s0^2`` (px^2). None for a rig
    of one camera or mode ``none``. See :func:`rig_rigid`.

    Returns ``{"stats": {view: T_v}, "dofs": {view: k_v}, "leverage": {view: h_v}, "dof", "design_effect",
    "noise_px2"}``: ``k_v`` is 6 per tied camera of the instant (4 in the paper's model, whose baseline
    direction is free), ``dof`` their sum less the shared relative poses' own (6 or 4 per tied camera), and
    ``h_v`` the share of the shared poses that the instant determines, ``1 / n_c`` for a camera tied in
    ``n_c`` instants, averaged over the instant's tied cameras (equal information per instant).
    """
    p = tied.problem
    if p.mode == "none" or len(p.cameras) < 2:
        return None
    kappa2 = max((design_effect(alone) if kappa2 is None else kappa2).values())
    noise = max(kappa2 * alone.s0_px ** 2, NOISE_FLOOR_PX ** 2)
    per = 6 if p.mode == "rigid" else 4
    cams_of: dict[str, set] = {}
    for c, v, _ in p.blocks:
        cams_of.setdefault(v, set()).add(c)
    tied_in = {v: (cams - {p.reference}) if p.reference in cams else set() for v, cams in cams_of.items()}
    n_tied = {c: sum(c in t for t in tied_in.values()) for c in range(len(p.cameras))}
    stats, dofs, leverage = {}, {}, {}
    for view, extra in tie_costs(tied, alone).items():
        if tied_in.get(view):
            stats[view], dofs[view] = max(float(extra / noise), 0.0), per * len(tied_in[view])
            leverage[view] = float(np.mean([1.0 / n_tied[c] for c in tied_in[view]]))
    tied_cams = {c for c, _, _ in p.blocks if c != p.reference}
    dof = sum(dofs.values()) - per * len(tied_cams)
    if dof <= 0 or not stats:
        return None
    return {"stats": stats, "dofs": dofs, "leverage": leverage, "dof": dof, "design_effect": kappa2,
            "noise_px2": noise, "own_noise": own_noise(alone, stats)}


def own_noise(alone: Solution, views) -> dict[str, float]:
    """Per instant of ``views``, the noise of its photos relative to all photos': the mean square residual
    of its photos with every camera alone (over their coordinates less six per photo, its own pose) over
    ``s0^2``. Sharper photos have less, blurred ones more; their poses, and so the instant's tie cost,
    scatter likewise."""
    ss: dict[str, float] = {}
    n: dict[str, int] = {}
    for (c, v, _), r in zip(alone.problem.blocks, alone.residuals):
        ss[v] = ss.get(v, 0.0) + float(np.nansum(r ** 2))
        n[v] = n.get(v, 0) + int(np.isfinite(r).sum()) - 6
    s02 = max(alone.s0_px ** 2, NOISE_FLOOR_PX ** 2)
    return {v: max(ss[v] / max(n[v], 1), NOISE_FLOOR_PX ** 2) / s02 for v in views if v in ss}


#: The least share of an instant's degrees of freedom that :func:`instant_f_tests` gives its noise: one in
#: six (a rigid pose's own six, moved by one smooth error of each photo).
MIN_DOF_SHARE = 1.0 / 6.0


def dof_share(values: list[float], dofs: list[int]) -> float:
    """The share ``e`` of their degrees of freedom that tie costs ``T_u`` scatter with (Satterthwaite).

    ``T_u / (k_u (1 - h_u))`` (``values``, each of ``k_u`` degrees of freedom, ``dofs``) have one mean
    ``sigma^2``; with white noise on the corners ``T_u`` is ``sigma^2 chi^2(k_u)``, of variance ``2 / k_u``
    relative to its mean squared. Noise correlated within the photos (a smooth error of each photo, the
    lens model's error where the board lies) moves the poses along fewer directions, and the tie costs
    scatter as with ``e k_u`` degrees of freedom, ``e < 1``: ``e = 2 m^2 (n - 1) / sum k_u (y_u - m)^2`` by
    the moments of the ``n`` values ``y_u`` (mean ``m``), between :data:`MIN_DOF_SHARE` and 1.
    """
    y, k = np.asarray(values, float), np.asarray(dofs, float)
    if len(y) < 3:
        return 1.0
    m = float(np.mean(y))
    spread = float(np.sum(k * (y - m) ** 2))
    if m <= 0 or spread <= 0:
        return 1.0
    return float(np.clip(2.0 * m * m * (len(y) - 1) / spread, MIN_DOF_SHARE, 1.0))


def instant_f_tests(stats: dict[str, float], dofs: dict[str, int], leverage: dict[str, float], dof: int,
                    rate: float) -> dict[str, dict]:
    """Each instant's tie cost against the other instants' scatter: an F test per instant at ``rate``.

    With the instants' tie costs ``T_v`` (:func:`rigidity_statistics`, any unit: it cancels) summing to
    ``S`` over ``dof`` degrees of freedom, instant ``v`` left out of the shared relative poses would cost
    ``Q_v = T_v / (1 - h_v)`` (its deleted, or predicted, tie cost, exact for equal leverage ``h_v``), and
    the others ``S - Q_v`` over ``dof - k_v``. On a synchronised rig whose instants share one noise
    level, ``F_v = (Q_v / k_v) / ((S - Q_v) / (dof - k_v))`` follows ``F(k_v, dof - k_v)`` for white noise
    (the externally studentised outlier test): whatever that level is, lens-model error and noise
    correlated within the photos included, it comes from the others. Correlated noise scatters the tie
    costs as with fewer degrees of freedom: both are taken times the others' share ``e``
    (:func:`dof_share`, of the others alone, so that the instant judged does not widen its own limit),
    ``F(e k_v, e (dof - k_v))``. Returns ``{view: {"f", "d1", "d2", "p"}}`` for the instants that can be
    judged (``dof - k_v > 0``); an instant fails where ``p < rate``, and those, and the one of the smallest
    ``p``, also have ``"limit"``, the F quantile at ``1 - rate`` (``f > limit`` where ``p < rate``).
    """
    total = sum(stats.values())
    scaled = {v: t / (dofs[v] * max(1.0 - leverage[v], 1e-9)) for v, t in stats.items()}
    out = {}
    for v, t in stats.items():
        d1, d2 = dofs[v], dof - dofs[v]
        if d2 <= 0:
            continue
        others = [u for u in stats if u != v]
        e = dof_share([scaled[u] for u in others], [dofs[u] for u in others])
        q = t / max(1.0 - leverage[v], 1e-9)
        rest = max(total - q, 1e-12 * total, 1e-300)            # JSON has no inf: a huge F instead
        f = (q / d1) / (rest / d2)
        out[v] = {"f": f, "d1": e * d1, "d2": e * d2, "p": f_sf(f, e * d1, e * d2)}
    worst = min(out, key=lambda v: out[v]["p"], default=None)
    for v, t in out.items():            # a quantile costs a millisecond: only where it is shown
        if t["p"] < rate or v == worst:
            t["limit"] = f_quantile(t["d1"], t["d2"], 1.0 - rate)
    return out


#: Instants that ``rig_rigid`` names (they fit worse than the others at its false-alarm rate) fail it only
#: where leaving one out moves some value of the rig's relations (t, baseline, omega-phi-kappa) by more than
#: this many of its sigmas without it: a misfit that moves no result beyond twice its uncertainty (a
#: difference of no significance at 95 %) is worth naming, not a verdict of "use with care". Synthetic VGA
#: stereo rig of 13 instants (tests/test_checks.py): one instant's camera 0.5 mm and 0.025 degrees off
#: moves it 0.7 sigma, 1 mm and 0.05 degrees 1.3 sigma, a lens knocked by 3 mm far more; a 0.5 mm, 1.5
#: arcmin desynchronised shot moves a 12 MP rig's by many sigma. OpenCV's stereo sample: its instants 08 and
#: 03 (the board moved a little between the shots), 1.3-1.7.
SHIFT_SIGMAS = 2.0


def relation_shift_sigma(before: Solution, after: Solution) -> float | None:
    """How far the rig's relations move from ``before`` to ``after`` (the same rig mode, some instants left
    out): the largest ``|change| / sigma`` over every non-reference camera's translation (mm), baseline and
    omega-phi-kappa, each sigma ``after``'s, the larger of the clustered and the formal (as calib.json
    reports it): the uncertainty without the instants left out, which their own misfit would inflate.
    None where no camera's relation is in both."""
    p, q = before.problem, after.problem

    def relation(sol: Solution, c: int, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(t_mm, baseline, opk_arcmin) and their sigmas of ``kind``."""
        pose, s_t, s_d, s_opk = rig_relation(sol, c, kind, warn_gimbal=False)
        value = np.concatenate([pose.t_mm, [np.linalg.norm(pose.t_mm)], opk_from_rotation(pose.R) * ARCMIN_PER_RAD])
        return value, np.concatenate([s_t, [s_d], s_opk])

    worst = None
    for c, name in enumerate(p.cameras):
        if c == p.reference or name not in q.cameras:
            continue
        try:
            was, _ = relation(before, c, "formal")
            now, formal = relation(after, q.cameras.index(name), "formal")
            _, clustered = relation(after, q.cameras.index(name), "clustered")
        except EstimationError:
            continue
        change = now - was
        change[4:] = (change[4:] + 180 * 60) % (360 * 60) - 180 * 60          # angles across +-180 degrees
        shift = float(np.max(np.abs(change) / np.maximum(np.maximum(formal, clustered), 1e-300)))
        worst = shift if worst is None else max(worst, shift)
    return worst


#: The name of ``rig_rigid``'s test (calib.json ``checks.rig_rigid.test``).
RIGID_TEST = ("F test of each instant's tie cost against the other instants' (Sidak over the instants); "
              "F test of the instants together against the photo-level noise")


def rig_rigid(tied: Solution, alone: Solution, kappa2: dict[int, float] | None = None,
              explained=(), named: dict[str, dict] | None = None, rate: float = FALSE_ALARM_RATE,
              shift_sigma: float | None = None) -> dict | None:
    """Whether every instant's photos fit one rigid relative pose (None for a rig of one camera or
    mode ``none``), at the false-alarm rate ``rate`` per calibration.

    Both solutions must be over the same photos: ``tied`` in rig mode ``rigid`` or ``paper``,
    ``alone`` with every camera alone. The extra cost of tying instant ``v`` in units of the photo-level
    noise ``kappa^2 s0^2`` of the cameras alone is ``T_v`` (:func:`rigidity_statistics`), with ``k_v``
    degrees of freedom. Two tests, the rate split over them by Sidak (``G`` instants: ``G + 1`` tests):

    * each instant against the others (:func:`instant_f_tests`), its tie cost taken in its own photos'
      noise (:func:`own_noise`: a blurred instant's poses scatter more, a sharp one's less): an instant out
      of sync, or whose lens moved, fails;
    * the instants together: ``ratio = sum T_v / dof`` against ``F(dof, G - 1)`` (the photo-level noise is
      estimated from the intrinsics' scatter over the ``G`` instants, :func:`design_effect`, so about
      ``G - 1`` degrees of freedom): every instant out of sync, or a rig that is not rigid, fails.

    ``explained`` are instants whose misfit a refocused photo explains (``focus``): they are not judged
    here. ``named`` are instants already found not to fit (:func:`dualcal.estimation.checking.attribution_checks`
    takes the worst out and judges the others without it, so that a bad instant, which pulls the shared
    pose, does not make the good ones look bad): ``{view: its test}`` as it was, flagged first.
    ``shift_sigma`` is how far leaving a named instant out moves the rig's relations, the largest over the
    named ones, each taken out of the fit without those named before it (:func:`relation_shift_sigma`):
    named instants that each move them by at most :data:`SHIFT_SIGMAS` do not fail the check (they fit
    worse than the others, but the misfit of none changes a result beyond its uncertainty, which the
    instants' scatter already holds); the message names them.

    The document: ``ok``, ``message``, ``test``, ``statistic`` (the worst instant's F, or a named one's),
    ``limit`` (its F quantile), ``p_value``, ``false_alarm_rate`` (``rate``, per calibration),
    ``instant_rate`` (each test's), ``instants`` ``{view: T_v}``, ``instant_f`` ``{view: {"f", "p"}}`` (and
    ``"limit"`` for the flagged and the worst; an instant fails where ``p < instant_rate``), ``flagged``,
    ``ratio`` and ``limit_ratio`` (the instants together), ``design_effect``, ``explained_by_refocus``.
    """
    found = rigidity_statistics(tied, alone, kappa2)
    if found is None:
        return None
    stats, dofs, dof, kappa2 = found["stats"], found["dofs"], found["dof"], found["design_effect"]
    named = named or {}
    judged = {v: t for v, t in stats.items() if v not in explained}
    dof -= sum(dofs[v] for v in stats if v not in judged)
    views = len(judged) + len(named)
    each = sidak(rate, views + 1)
    own = found["own_noise"]                  # each instant in its own photos' noise (sharp or blurred)
    tests = instant_f_tests({v: t / own.get(v, 1.0) for v, t in judged.items()}, dofs, found["leverage"], dof,
                            each) if dof > 0 else {}
    flagged = list(named) + sorted((v for v, t in tests.items() if t["p"] < each), key=lambda v: tests[v]["p"])
    ratio = float(sum(judged.values())) / dof if judged and dof > 0 else 0.0
    limit_ratio = f_quantile(max(dof, 1), max(views - 1, 1), 1.0 - each)
    harmless = (bool(flagged) and set(flagged) == set(named) and shift_sigma is not None
                and shift_sigma <= SHIFT_SIGMAS)
    ok = ratio <= limit_ratio and (not flagged or harmless)
    all_tests = {**{v: {k: t[k] for k in ("f", "p", "limit") if k in t} for v, t in tests.items()},
                 **{v: {k: t[k] for k in ("f", "p", "limit") if k in t} for v, t in named.items()}}
    worst = flagged[0] if flagged else (min(tests, key=lambda v: tests[v]["p"]) if tests else None)
    doc = {"ok": ok, "test": RIGID_TEST, "false_alarm_rate": rate, "instant_rate": each,
           "statistic": all_tests[worst]["f"] if worst else None,
           "limit": all_tests[worst]["limit"] if worst else None,
           "p_value": all_tests[worst]["p"] if worst else None, "worst": worst,
           "ratio": ratio, "limit_ratio": limit_ratio, "design_effect": kappa2,
           "instants": {v: round(t, 3) for v, t in {**stats, **{v: t["statistic"] for v, t in named.items()}}.items()},
           "instant_f": {v: {k: round(x, 4) if k != "p" else x for k, x in t.items()} for v, t in all_tests.items()},
           "flagged": flagged, "explained_by_refocus": sorted(v for v in explained if v in stats),
           "shift_sigma": shift_sigma, "shift_limit_sigma": SHIFT_SIGMAS}
    rate_words = f"false-alarm rate {100 * rate:g} % per calibration"
    if ok and flagged:
        words = ", ".join(f"{v} (F = {all_tests[v]['f']:.1f}, p = {all_tests[v]['p']:.2g})" for v in flagged[:5])
        doc["message"] = (f"the photos of every instant fit one rigid relative pose but for {words}, which fit worse "
                          f"than the other instants ({rate_words}); leaving {'it' if len(flagged) == 1 else 'them'} "
                          f"out one at a time moves the baseline and angles by {shift_sigma:.2f} sigma at most (limit "
                          f"{SHIFT_SIGMAS:g}): a small misfit (the board moved a little between the shots, a shot a "
                          "little late) that changes no result beyond twice its sigma; kept (--exclude them to compare)")
    elif ok:
        worst_words = (f"the worst, {worst}, F = {all_tests[worst]['f']:.2f} against the others' scatter (limit "
                       f"{all_tests[worst]['limit']:.2f}); ") if worst else ""
        doc["message"] = (f"the photos of every instant fit one rigid relative pose: {worst_words}the instants together "
                          f"{ratio:.2f} x the photo-level noise (limit {limit_ratio:.2f}; {rate_words})")
    elif flagged:
        words = ", ".join(f"{v} (F = {all_tests[v]['f']:.1f}, limit {all_tests[v]['limit']:.2f}, p = "
                          f"{all_tests[v]['p']:.2g})" for v in flagged[:5])
        moved = (f"; leaving them out one at a time moves the baseline and angles by up to {shift_sigma:.1f} sigma"
                 if shift_sigma is not None else "")
        doc["message"] = (f"the photos of {len(flagged)} instant(s) do not fit the rig's relative pose: {words} against "
                          f"the other instants' scatter{moved}, the others fit: the cameras' shots of "
                          f"{'that instant' if len(flagged) == 1 else 'those instants'} disagree (not taken at the same "
                          "instant, a lens that moved, or a board that moved between the shots); drop them with "
                          f"--exclude or shoot them again ({rate_words})")
    else:
        doc["message"] = (f"the instants fit one rigid relative pose {ratio:.1f} x worse than the photo-level noise "
                          f"allows (limit {limit_ratio:.2f}; {rate_words}): the cameras' shots are not synchronised, "
                          "or the rig is not rigid; its baseline and angles hold only on average")
    return doc


def focal_scale_fits(sol: Solution, views=None) -> list[dict]:
    """Each photo's own focal scale, fitted with its instant's own unknowns, linearised at ``sol``.

    For every photo of the instants ``views`` (default: all), ``fx`` and ``fy`` times ``1 + s`` are
    fitted together with the instant's own unknowns (the board pose; in a rig it is held by the
    instant's other photos too, so a tele that refocused shows against the wide) and every other
    parameter held. Returns ``{"block", "camera" (index), "view", "s", "var_s" (per unit residual
    variance), "explained_px2"}`` per photo: ``explained_px2`` is how much of the instant's squared
    residuals the focal scale takes away.
    """
    p, lay = sol.problem, sol.problem.layout
    by_instant: dict[str, list] = {}
    for pr in photo_rows(p, sol.state):
        view = p.blocks[pr.block][1]
        if views is None or view in views:
            by_instant.setdefault(view, []).append(pr)
    fits = []
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
            if len(lay.intrinsics[c]) < 2:                         # intrinsics held fixed (known): not judged here
                row += len(pr.r)
                continue
            col = {int(k): i for i, k in enumerate(pr.columns)}
            fx_col, fy_col = lay.intrinsics[c][:2]                 # fx and fy are free where any intrinsic is
            cam = sol.state.intrinsics[c]
            J_scale = np.zeros(m)
            J_scale[row:row + len(pr.r)] = cam[0] * pr.J[:, col[fx_col]] + cam[1] * pr.J[:, col[fy_col]]
            row += len(pr.r)
            A = np.column_stack([J_local, J_scale])
            try:
                inv = np.linalg.inv(A.T @ A)
            except np.linalg.LinAlgError:
                continue
            step = inv @ (A.T @ r)
            fits.append({"block": pr.block, "camera": c, "view": view, "s": float(-step[-1]),
                         "var_s": float(inv[-1, -1]), "explained_px2": float(step[-1] ** 2 / inv[-1, -1])})
    return fits


def tie_costs(tied: Solution, alone: Solution) -> dict[str, float]:
    """Per instant, how much more its photos cost (px^2) tied to the rig than with every camera alone."""
    extra = _block_costs(tied) - _block_costs(alone)
    out: dict[str, float] = {}
    for b, (_, view, _) in enumerate(tied.problem.blocks):
        out[view] = out.get(view, 0.0) + float(extra[b])
    return out


def focal_t_tests(z: list[float], rate: float) -> list[dict]:
    """Each of one camera's photos' focal scales against the scatter of the others: a Student t test at ``rate``
    (two-sided).

    ``z`` are the photos' focal scales in units of their own sigma up to one unknown factor (the
    photo-level noise; it cancels). The camera's focal length is fitted to them all, so each is a residual
    of a mean (leverage ``h = 1 / n`` for ``n`` photos); photo ``i`` left out leaves the others
    ``SS - z_i^2 / (1 - h)`` over ``n - 2`` degrees of freedom, and ``t_i = z_i / sqrt((1 - h) (SS - z_i^2 /
    (1 - h)) / (n - 2))`` follows Student's ``t(n - 2)`` for a camera whose focus stayed (the externally
    studentised residual). Returns per photo ``{"t", "dof", "p", "limit"}`` (``limit`` the t quantile at
    ``1 - rate / 2``); empty below 3 photos.
    """
    n = len(z)
    if n < 3:
        return []
    h, dof = 1.0 / n, n - 2
    ss = float(np.sum(np.square(z)))
    limit = float(np.sqrt(f_quantile(1, dof, 1.0 - rate)))
    out = []
    for zi in z:
        rest = max(ss - zi ** 2 / (1.0 - h), 1e-12 * ss, 1e-300)   # JSON has no inf: a huge t instead
        t = abs(zi) / np.sqrt((1.0 - h) * rest / dof)
        out.append({"t": float(t), "dof": dof, "p": f_sf(t * t, 1, dof), "limit": limit})
    return out


def focal_scale_sigmas(fit: dict, kappa2: dict[int, float], s0_px: float) -> float:
    """A photo's own focal scale (a :func:`focal_scale_fits` entry) in units of its sigma in photo-level noise
    (``kappa2[c] s0^2`` for its camera ``c``)."""
    return fit["s"] / np.sqrt(max(kappa2[fit["camera"]] * s0_px ** 2, NOISE_FLOOR_PX ** 2) * fit["var_s"])


#: The name of ``focus``'s test (calib.json ``checks.focus.test``).
FOCUS_TEST = "Student t test of each photo's focal scale against its camera's other photos (Sidak over the photos)"


def focus_drift(sol: Solution, kappa2: dict[int, float], tie_cost_px2: dict[str, float] | None = None,
                named: list[dict] = (), rate: float = FALSE_ALARM_RATE) -> dict:
    """Photos whose own focal length is off: the phone refocused or zoomed between shots.

    A photo's own focal scale ``s`` (:func:`focal_scale_fits`) in units of its sigma in photo-level noise
    (``sigmas``, ``kappa2[c]`` for camera ``c``) is judged against the other photos of its camera
    (:func:`focal_t_tests`), the false-alarm rate ``rate`` per calibration split over the photos by Sidak.
    In a rig, an instant whose cameras' shots disagree (a desynchronised shot, a lens that moved) also
    pulls the focal lengths of its photos, but a focal change explains only a small part of its misfit,
    where a refocus explains most of it: with ``tie_cost_px2`` (:func:`tie_costs`), a candidate is a
    refocus only where its focal scale takes away at least :data:`REFOCUS_SHARE` of its instant's extra
    cost of being tied to the rig; the others are left to ``rig_rigid`` (``flagged`` lists them with
    ``"cause": "rig"``). ``named`` are refocused photos already found
    (:func:`dualcal.estimation.checking.attribution_checks` takes each out and judges the others without it):
    they are flagged first, as they were found.

    The document: ``ok``, ``message``, ``flagged``, ``test``, ``statistic`` (the largest ``|t|``, or a named
    photo's), ``limit``, ``p_value``, ``false_alarm_rate`` (``rate``), ``photo_rate`` (each test's).
    """
    fits = focal_scale_fits(sol)
    each = sidak(rate, len(fits) + len(named)) if fits or named else rate
    by_camera: dict[int, list] = {}
    for fit in fits:
        c = fit["camera"]
        fit["z"] = focal_scale_sigmas(fit, kappa2, sol.s0_px)
        by_camera.setdefault(c, []).append(fit)
    for group in by_camera.values():
        for fit, test in zip(group, focal_t_tests([f["z"] for f in group], each)):
            fit["test"] = test
    flagged = list(named)
    worst = max((f for f in fits if "test" in f), key=lambda f: f["test"]["t"], default=None)
    for fit in fits:
        test = fit.get("test")
        if test is None or test["t"] <= test["limit"]:
            continue
        view = fit["view"]
        tie = (tie_cost_px2 or {}).get(view)
        share = fit["explained_px2"] / tie if tie and tie > 0 else None
        cause = "refocus" if share is None or share >= REFOCUS_SHARE else "rig"
        flagged.append({"camera": sol.problem.cameras[fit["camera"]], "view": view, "focal_change": fit["s"],
                        "sigmas": float(fit["z"]), "t": test["t"], "p": test["p"], "limit": test["limit"],
                        "explained_share": share, "cause": cause})
    flagged[len(named):] = sorted(flagged[len(named):], key=lambda f: -f["t"])
    refocused = [f for f in flagged if f["cause"] == "refocus"]
    top = refocused[0] if refocused else None
    doc = {"test": FOCUS_TEST, "false_alarm_rate": rate, "photo_rate": each,
           "statistic": top["t"] if top else (worst["test"]["t"] if worst else None),
           "limit": top["limit"] if top else (worst["test"]["limit"] if worst else None),
           "p_value": top["p"] if top else (worst["test"]["p"] if worst else None),
           "worst": (f"{top['camera']}/{top['view']}" if top else
                     f"{sol.problem.cameras[worst['camera']]}/{worst['view']}" if worst else None)}
    rate_words = f"false-alarm rate {100 * rate:g} % per calibration"
    if not refocused:
        rest = (f" (the focal lengths of {len(flagged)} photo(s) of instants that do not fit the rig move too, as a "
                "pose error pulls them: see rig_rigid)") if flagged else ""
        stat = (f"the worst, {doc['worst']}, |t| = {doc['statistic']:.2f} against its camera's other photos (limit "
                f"{doc['limit']:.2f}; {rate_words})") if worst else "too few photos per camera to judge"
        return {"ok": True, "flagged": flagged, **doc,
                "message": f"no photo's own focal length is off: {stat}{rest}"}
    words = ", ".join(f"{f['camera']}/{f['view']} ({100 * f['focal_change']:+.2f} %, |t| = {f['t']:.1f}, limit "
                      f"{f['limit']:.2f})" for f in refocused[:4])
    return {"ok": False, "flagged": flagged, **doc,
            "message": f"{len(refocused)} photo(s) have a focal length of their own: {words}: the phone refocused or "
                       "zoomed between shots; lock focus (AF/AE lock) and shoot again, or leave them out with --exclude "
                       f"({rate_words})"}


def _edge_distortion_sigma(rig: RigModel, name: str, uv: np.ndarray) -> float | None:
    """The sigma (px, radial, the larger of the covariance kinds) of camera ``name``'s lens distortion at
    the measured corner ``uv`` (N, 2) farthest from the principal point; None without a covariance of its
    lens coefficients (:func:`dualcal.geometry.camera.radial_lens_gradient`: every lens model)."""
    from ..geometry.camera import LENS_MODELS, pixel_rays, radial_lens_gradient
    from .covariance import JointCovariance, intrinsic_name

    cam = rig.cameras[name]
    terms = [k for k in LENS_MODELS[cam.model] if rig.camera_sigma[name].get(k, 0.0) > 0]
    names = [intrinsic_name(name, k) for k in terms]
    if not terms or not len(uv) or not rig.covariance:
        return None
    cov = JointCovariance.from_dict(rig.covariance)
    if not cov.has(names):
        return None
    rays = pixel_rays(cam, uv)
    far = int(np.argmax(np.hypot(rays[:, 0], rays[:, 1])))
    return cov.derived_sigma(names, radial_lens_gradient(cam, rays[far], terms))


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
        # the distortion where the data reach: beyond the outermost corner it is extrapolated
        uv = np.vstack([uv for uv in used.cameras[name].found().values()] or [np.zeros((0, 2))])
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        s = _edge_distortion_sigma(rig, name, uv)
        if s is not None:
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
    fixed = {"test": "physical limit: the largest camera RMS (px, 2-D per corner) against what corner detection "
                     "achieves", "statistic": max(rig.camera_rms_px.values(), default=0.0), "limit": FIT_RMS_LIMIT_PX,
             "false_alarm_rate": None}
    if not bad:
        return {"ok": True, **fixed, "message": "every camera fits its corners to "
                                       f"{max(rig.camera_rms_px.values()):.3g} px RMS (2-D, per corner) or better"}
    worst = ", ".join(f"{n} {r:.2f} px" for n, r in bad.items())
    return {"ok": False, **fixed, "message": f"RMS (2-D, per corner) {worst}, far above what corner detection achieves on sharp "
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


def camera_edge_ratio(sol: Solution, c: int) -> tuple[float, list[str]]:
    """Camera ``c``'s RMS residual of its outermost third of corners (by their distance from the principal point)
    over that of its innermost third (NaN with too few corners), and the views where that ratio of their own
    corners exceeds :data:`EDGE_RATIO`."""
    p = sol.problem
    cam = sol.state.camera(p, c)
    rho_all, len_all, views = [], [], []
    for b, (cc, view, uv) in enumerate(p.blocks):
        if cc != c:
            continue
        length = np.linalg.norm(sol.residuals[b], axis=1)
        seen = np.isfinite(length)
        rho = np.hypot(uv[seen, 0] - cam.cx, uv[seen, 1] - cam.cy)
        rho_all.append(rho)
        len_all.append(length[seen])
        if _edge_ratio(rho, length[seen]) > EDGE_RATIO:
            views.append(f"{p.cameras[c]}/{view}")
    ratio = _edge_ratio(np.concatenate(rho_all), np.concatenate(len_all)) if rho_all else float("nan")
    return ratio, views


def lens_model_fit(sol: Solution) -> dict:
    """Residuals that grow towards the image's edge: a model problem, reported, never a reason to drop."""
    p = sol.problem
    bad, views, ratios = [], [], []
    for c, name in enumerate(p.cameras):
        ratio, edge_views = camera_edge_ratio(sol, c)
        views += edge_views
        if np.isfinite(ratio):
            ratios.append(float(ratio))
        if ratio > EDGE_RATIO:
            bad.append(f"{name} ({ratio:.1f} x)")
    fixed = {"test": "fixed limit: the largest camera's RMS of its outermost third of corners over its innermost "
                     "third", "statistic": max(ratios, default=None), "limit": EDGE_RATIO, "false_alarm_rate": None}
    if not bad:
        return {"ok": True, "views": views, **fixed, "message": "residuals do not grow towards the image's edge"}
    return {"ok": False, "views": views, **fixed,
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
            out[name] = FULL_FRAME_DIAGONAL_MM * f_mm / f35_mm
    return out


def scale_plausibility(rig: RigModel) -> dict | None:
    """The ``scale_plausible`` check (module docstring), or None where no camera's EXIF shows a phone's sensor.

    Returns ``{"ok", "message", "sensor_diagonal_mm": {camera: mm}, "board_distance_mm": median over the
    instants, "baseline_mm": {camera: mm}}``.
    """
    diagonals = _sensor_diagonals_mm(rig)
    if not diagonals or max(diagonals.values()) >= PHONE_SENSOR_DIAGONAL_MM:
        return None
    distance = float(np.median(rig.board_distances_mm()))
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


def _attribution(tied: Solution, alone: Solution, kappa2) -> tuple[dict, dict | None]:
    """``focus`` and ``rig_rigid`` from one pair of solutions (no photo or instant taken out)."""
    focus = focus_drift(tied, kappa2, tie_costs(tied, alone) if tied.problem.mode != "none" else None)
    explained = {f["view"] for f in focus["flagged"] if f["cause"] == "refocus"}
    return focus, rig_rigid(tied, alone, kappa2, explained)


def run_checks(rig: RigModel, sol: Solution, tied_flat: Solution, alone: Solution, attribution=None) -> dict:
    """Every check of a calibration: ``rig`` and its final solution ``sol``; ``tied_flat`` the same
    rig mode with a flat board and ``alone`` every camera alone, over the same photos (for
    ``rig_rigid`` and ``focus``). ``attribution(tied, alone, kappa2) -> (focus, rig_rigid)`` makes those
    two (default: from these solutions alone; :func:`dualcal.estimation.checking.attribution_checks` names each
    refocused photo and each instant that does not fit the rig alone)."""
    checks = {"converged": convergence(sol), "photos": photo_count(rig), "fit": fit_quality(rig)}
    kappa2 = design_effect(alone)
    focus, rigid = (attribution or _attribution)(tied_flat, alone, kappa2)
    if rigid is not None:
        checks["rig_rigid"] = rigid
    checks["focus"] = focus
    checks["determination"] = determination(rig)
    checks["lens_model"] = lens_model_fit(sol)
    scale = scale_plausibility(rig)
    if scale is not None:
        checks["scale_plausible"] = scale
    return checks


def check_limits(check: dict) -> dict[str, str]:
    """A check's test, statistic, limit and false-alarm rate as text for a table (``""`` where it has none;
    the rate ``"fixed"`` for a check whose limit is fixed, not statistical)."""
    def number(x):
        return "" if x is None else f"{x:.3g}"
    stat, limit = check.get("statistic"), check.get("limit")
    rate = check.get("false_alarm_rate")
    if "test" not in check:
        return {"test": "", "statistic": "", "limit": "", "rate": ""}
    worst = f" ({check['worst']})" if check.get("worst") else ""
    return {"test": check["test"], "statistic": number(stat) + (worst if stat is not None else ""),
            "limit": number(limit), "rate": "fixed" if rate is None else f"{100 * rate:g} % per calibration"}


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
