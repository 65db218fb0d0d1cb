"""Checks of a calibration: whether, and how far, to trust it.

Each check is ``{"ok": bool, "message": "...", ...}`` (calib.json's ``checks``, the contract), with
a message in plain words that says what is wrong and what would help:

``converged``      the adjustment reached its optimum.
``photos``         enough instants for sigmas that come from how the photos disagree.
``fit``            every camera's RMS (2-D, per corner) near what corner detection achieves.
``rig_rigid``      the photos of every instant fit one rigid relative pose of the cameras: each instant judged
                   against a robust core of the other instants (two or three bad ones cannot hide each other),
                   the instants together against the photo-level noise (an unsynchronised pair, a lens that moved).
``focus``          no photo whose own focal length is off against a robust core of its camera's other photos (the
                   phone refocused), and no camera whose photos have two focal lengths (two lenses taken for one).
``determination``  every parameter determined well enough (focal length, principal point,
                   distortion as far out as corners were measured, baseline, angles).
``lens_model``     residuals that do not grow towards the image's edge (the lens model lacks terms).
``scale_plausible`` where EXIF shows a phone's small sensor (focal length in mm and its 35 mm equivalent):
                   the board's distance and the lenses' spacing are a phone's (:func:`scale_plausibility`).
                   Every length scales with the board's square size, which only the user knows; a wrong
                   one passes every other check. Without those EXIF facts there is nothing to judge it by,
                   so there is no such check and :func:`scale_note` says that the scale rests on the square
                   (a check that always passes would only add to "all checks pass").

*False alarms.* ``rig_rigid``, ``focus`` (and ``loop_closure``, :mod:`dualcal.estimation.loop_closure`) take
their limits from the distribution of their statistic on a synchronised rig with a fixed focus, at
:data:`FALSE_ALARM_RATE` per calibration, split over their tests; the statistic of one instant (photo) is judged
against the scatter of a core of the others (:mod:`dualcal.estimation.robust_tests`), so that the calibration's own
noise, lens-model error included, sets the limit, and bad instants do not. Each gives ``test`` (its name),
``statistic`` (the worst instant's or photo's), ``limit`` (that test's) and ``false_alarm_rate``.
``benchmarks/bench_false_alarms.py`` measures the rates. The other checks have fixed limits: physical ones (what
corner detection achieves, a sigma too large to use), said in their entries.

*Photo-level noise.* Corner errors within one photo are correlated on real photos, so a test
against white corner noise (``s0``) would fail every real rig. The checks measure noise in units of
``kappa^2 s0^2``, where the design effect ``kappa^2`` of a camera is how much more its photos
disagree than white noise allows: the median ratio of the clustered to the formal variance of
its intrinsics, never below 1 (:func:`design_effect`).
"""

from __future__ import annotations

import numpy as np

from .adjust import Solution
from .distributions import f_quantile, sidak
from .instant_poses import (InstantRelations, best_fitting_half, deleted_costs, focal_column, focal_responses,
                            instant_relations, refocus_explained)
from .rig_relations import rig_relation
from ..errors import EstimationError
from .robust_tests import MIN_SPLIT_GROUP, CoreTest, core_tests, cube_root_spread, robust_core, split_test
from ..geometry.camera import FULL_FRAME_DIAGONAL_MM
from ..geometry.model import RigModel
from ..geometry.rotation import ARCMIN_PER_RAD, opk_from_rotation

__all__ = ["design_effect", "rig_rigid", "rigidity_statistics", "focus_drift", "focal_scale_fits", "tie_costs",
           "determination", "fit_quality", "photo_count", "lens_model_fit", "convergence", "scale_plausibility",
           "scale_note", "run_checks", "verdict", "relation_shift_sigma", "check_limits", "instant_tests",
           "focal_scale_sigmas", "failed_checks", "focus_and_rigidity", "refocused_camera"]

#: Fewer instants than this give unreliable sigmas (they come from the instants' scatter).
MIN_INSTANTS = 8
#: A camera's RMS (2-D, per corner) above this is far beyond what corner detection achieves.
FIT_RMS_LIMIT_PX = 1.0
#: The false-alarm rate of each check with a statistical limit (``rig_rigid``, ``focus``, ``loop_closure``), per
#: calibration: on a synchronised rig with a fixed focus, one calibration in a hundred fails the check by chance.
#: It is split over the check's tests (one per instant, photo or pair) by
#: :func:`dualcal.estimation.distributions.sidak`.
FALSE_ALARM_RATE = 0.01
#: A photo's focal change is a refocus (``focus``) where it takes away at least this share of its instant's extra
#: cost of being tied to the rig (a desynchronised shot also pulls the focal lengths, but explains little of its
#: misfit so).
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
    """Each photo's ``|r|^2`` (px^2), with its stabiliser shift's prior where it has one (what the shift costs:
    :meth:`dualcal.estimation.adjust.Solution.ois_costs_px2`)."""
    return np.nansum(sol.residuals ** 2, axis=(1, 2)) + sol.ois_costs_px2()


def rigidity_statistics(tied: Solution, alone: Solution, kappa2: dict[int, float] | None = None):
    """Per instant, the extra cost of tying its photos to one relative pose in units of the photo-level noise,
    and its degrees of freedom; the noise ``kappa^2 s0^2`` (px^2). None for a rig of one camera or mode ``none``.
    See :func:`rig_rigid`.

    Returns ``{"stats": {view: T_v}, "dofs": {view: k_v}, "dof", "design_effect", "noise_px2", "own_noise"}``:
    ``k_v`` is 6 per tied camera of the instant (4 in the paper's model, whose baseline direction is free),
    ``dof`` their sum less the shared relative poses' own (6 or 4 per tied camera), ``own_noise`` each
    instant's photos' noise relative to all photos' (:func:`own_noise`).
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
    stats, dofs = {}, {}
    for view, extra in tie_costs(tied, alone).items():
        if tied_in.get(view):
            stats[view], dofs[view] = max(float(extra / noise), 0.0), per * len(tied_in[view])
    tied_cams = {c for c, _, _ in p.blocks if c != p.reference}
    dof = sum(dofs.values()) - per * len(tied_cams)
    if dof <= 0 or not stats:
        return None
    return {"stats": stats, "dofs": dofs, "dof": dof, "design_effect": kappa2, "noise_px2": noise,
            "own_noise": own_noise(alone, stats)}


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


#: The share of its ``n - 1`` degrees of freedom that the Student ``t`` judging one instant (photo) against the
#: core of the others has (``rig_rigid``, ``focus``). With noise correlated within the photos (a board not quite
#: flat, blur, lens terms the model lacks) the instants differ in how far it moves their poses and focal scales,
#: so their statistics scatter as a mixture, with longer tails than one normal and a core spread less sure than
#: its count says. Half the degrees of freedom holds the stated rate where all would not: on synthetic rigs with
#: a smooth warp of each photo's own (``benchmarks/bench_false_alarms.py``; VGA stereo and 12 MP wide + tele and
#: triple, 13 and 30 instants, 100-400 seeds each), the share of synchronised rigs' instant statistics beyond
#: ``t(n - 1)``'s quantile at 1e-3 was 1.5-3.7e-3 (the photos' focal scales 0.8-3.5e-3), beyond
#: ``t((n - 1) / 2)``'s 0.3-1.1e-3 (0-0.8e-3).
T_DOF_SHARE = 0.5


def instant_tests(rel: InstantRelations, own: dict[str, float], rate: float) -> tuple[np.ndarray, np.ndarray,
                                                                                    list[CoreTest | None]]:
    """Each instant of ``rel`` against a robust core of the others (``rig_rigid``), each test at ``rate``.

    An instant's statistic is its tie cost against the relations the core without it tells
    (:func:`dualcal.estimation.instant_poses.deleted_costs`), over its degrees of freedom and its photos' own
    noise (``own``, :func:`own_noise`); its cube root ``x`` is nearly normal, of spread ``r``
    (:func:`dualcal.estimation.robust_tests.cube_root_spread`). The core (:func:`dualcal.estimation.robust_tests.robust_core`)
    starts from the half of the instants that fit best (:func:`dualcal.estimation.instant_poses.best_fitting_half`),
    so that bad instants neither pull the relations the others are judged by nor widen their scatter.
    Returns ``(x, core, tests)`` over ``rel.views``, each test one-sided (a worse fit), by Student's t of
    :data:`T_DOF_SHARE` of its degrees of freedom.
    """
    dofs = rel.dofs
    scale = np.array([own.get(v, 1.0) for v in rel.views]) * dofs
    r = cube_root_spread(dofs)
    computed: dict[bytes, np.ndarray] = {}

    def values(core: np.ndarray) -> np.ndarray:
        key = core.tobytes()
        if key not in computed:
            computed[key] = np.cbrt(deleted_costs(rel, core) / scale)
        return computed[key]

    core = robust_core(values, r, rate, T_DOF_SHARE, best_fitting_half(rel) if len(rel.views) >= 4 else None)
    x = values(core)
    return x, core, core_tests(x, r, core, False, T_DOF_SHARE)


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
RIGID_TEST = ("Student t test of each instant's tie cost against a robust core of the other instants' (Sidak over "
              "the instants); F test of the instants together against the photo-level noise")


def rig_rigid(tied: Solution, alone: Solution, kappa2: dict[int, float] | None = None,
              refocused=(), rate: float = FALSE_ALARM_RATE, refit=None) -> dict | None:
    """Whether every instant's photos fit one rigid relative pose (None for a rig of one camera or mode ``none``),
    at the false-alarm rate ``rate`` per calibration.

    Both solutions must be over the same photos: ``tied`` in rig mode ``rigid`` or ``paper``, ``alone`` with
    every camera alone. Two tests, the rate split over them by Sidak (``G`` instants judged: ``G + 1`` tests):

    * each instant against a robust core of the others (:func:`instant_tests`): its tie cost against the
      relations the core without it tells, from each instant's own relative poses
      (:mod:`dualcal.estimation.instant_poses`), in its own photos' noise (:func:`own_noise`: a blurred instant's
      poses scatter more, a sharp one's less), judged against the core's scatter of the same, so that two or
      three bad instants neither pull the relations nor widen the scatter the others are judged by; an instant
      out of sync, or whose lens moved, fails;
    * the instants together (their tie costs, :func:`rigidity_statistics`; where instants are named, those of
      the others without them): ``ratio = sum T_v / dof`` against
      ``F(dof, G - 1)`` (the photo-level noise is estimated from the intrinsics' scatter over the ``G``
      instants, :func:`design_effect`, so about ``G - 1`` degrees of freedom): every instant out of sync, or a
      rig that is not rigid, fails.

    ``refocused`` are photos ``(camera, view)`` with a focal length of their own (``focus``): a refocus explains
    their instants' misfit, which are not judged here. An instant that fails, whose deviation from the core's
    relations one of its photos' focal change explains for :data:`REFOCUS_SHARE` of its tie cost or more
    (:func:`dualcal.estimation.instant_poses.refocus_explained`), is a refocus too (``refocused``: ``{"camera",
    "view", "focal_change", "explained_share", "f", "f_limit", "p"}``), not named here: ``focus`` names it, where
    the refocused photos pulled the camera's focal length so far that none stood out among its photos.
    ``refit(blocks) -> (tied, alone)`` adjusts both solutions
    again over other photos: where instants are named or photos refocused, once without them, for the instants
    together without their pull; named instants fail the check only where leaving them out moves the rig's
    relations by more than :data:`SHIFT_SIGMAS` of their sigma without them (:func:`relation_shift_sigma`): a
    smaller misfit is named in the message and kept. Without ``refit``, or where it fails, a named instant fails
    the check.

    The document: ``ok``, ``message``, ``test``, ``statistic`` (the worst instant's, a named one first: its tie
    cost per degree of freedom over the core's typical one), ``limit`` (that ratio at its test's limit),
    ``p_value``, ``false_alarm_rate`` (``rate``, per calibration), ``instant_rate`` (each test's), ``instants``
    ``{view: T_v}``, ``instant_f`` ``{view: {"f", "t", "dof", "p"}}`` (the ratio, its t, Student's degrees of
    freedom and p-value; ``"limit"`` for the named and the worst: an instant fails where ``p < instant_rate``),
    ``core_instants`` (how many the core holds), ``flagged``, ``refocused``, ``ratio`` and ``limit_ratio`` (the
    instants together), ``design_effect``, ``explained_by_refocus``, ``shift_sigma``, ``shift_limit_sigma``.
    """
    found = rigidity_statistics(tied, alone, kappa2)
    if found is None:
        return None
    kappa2s = design_effect(alone) if kappa2 is None else kappa2
    stats, dofs, dof, kappa2 = found["stats"], found["dofs"], found["dof"], found["design_effect"]
    explained = {v for _, v in refocused}
    rel = instant_relations(tied, alone)
    rel = rel.only([v in stats and v not in explained for v in rel.views])
    each = sidak(rate, len(rel.views) + 1)
    x, core, tests = instant_tests(rel, found["own_noise"], each)
    judged = {v: (t, x[i]) for i, (v, t) in enumerate(zip(rel.views, tests)) if t is not None}
    named = sorted((v for v, (t, _) in judged.items() if t.p < each), key=lambda v: judged[v][0].p)
    found_refocused = []
    responses = focal_responses(alone, set(named)) if named else {}
    for v in named:                     # an instant whose misfit one photo's focal change explains: a refocus
        shares = refocus_explained(rel, rel.views.index(v), core, responses, tied.problem.reference)
        if not shares:                  # no camera of it can refocus (every one's intrinsics held fixed)
            continue
        c = max(shares, key=lambda c: shares[c][0])
        if shares[c][0] >= REFOCUS_SHARE:
            picked = refocused_camera(alone, v, kappa2s)        # of cameras alike, the one further off alone
            c = picked if picked in shares and shares[picked][0] >= REFOCUS_SHARE else c
            found_refocused.append({"camera": tied.problem.cameras[c], "view": v, "focal_change": shares[c][1],
                                    "explained_share": shares[c][0]})
    explained |= {f["view"] for f in found_refocused}
    refocused = [*refocused, *((f["camera"], f["view"]) for f in found_refocused)]
    flagged = [v for v in named if v not in explained]
    worst = flagged[0] if flagged else min((v for v in judged if v not in explained), key=lambda v: judged[v][0].p,
                                           default=None)
    instant_f = {}
    for v, (t, xv) in judged.items():
        typical = max(t.mu, 1e-300)
        entry = {"f": round(float((xv / typical) ** 3), 4), "t": round(t.t, 3), "dof": t.dof, "p": t.p}
        if v in named or v == worst:       # a quantile costs a millisecond: only where it is shown
            at_limit = t.mu + t.limit(each, False) * t.spread
            entry["limit"] = round(float((at_limit / typical) ** 3), 4)
        instant_f[v] = entry
    for f in found_refocused:
        f.update(f=instant_f[f["view"]]["f"], f_limit=instant_f[f["view"]]["limit"], p=instant_f[f["view"]]["p"])
    views = len(rel.views)
    after = _without(refit, tied, flagged, refocused)
    dof_kept = dof - sum(dofs[v] for v in stats if v not in rel.views or v in flagged or v in explained)
    costs = stats
    if after is not None:               # the tie costs of the others without the pull of those left out
        tie, apart = _view_costs(after[0]), _view_costs(after[1])
        costs = {v: max((tie[v] - apart[v]) / found["noise_px2"], 0.0) for v in tie if v in stats}
    ratio = sum(costs[v] for v in rel.views if v not in flagged and v not in explained) / dof_kept if dof_kept > 0 \
        else 0.0
    limit_ratio = f_quantile(max(dof_kept, 1), max(views - 1, 1), 1.0 - each)
    shift_sigma = relation_shift_sigma(tied, after[0]) if after is not None and flagged else None
    harmless = bool(flagged) and shift_sigma is not None and shift_sigma <= SHIFT_SIGMAS
    ok = ratio <= limit_ratio and (not flagged or harmless)
    top = instant_f.get(worst, {})
    doc = {"ok": ok, "test": RIGID_TEST, "false_alarm_rate": rate, "instant_rate": each,
           "statistic": top.get("f"), "limit": top.get("limit"), "p_value": top.get("p"), "worst": worst,
           "ratio": ratio, "limit_ratio": limit_ratio, "design_effect": kappa2,
           "instants": {v: round(t, 3) for v, t in stats.items()}, "instant_f": instant_f,
           "core_instants": int(core.sum()), "flagged": flagged, "refocused": found_refocused,
           "explained_by_refocus": sorted(v for v in explained if v in stats),
           "shift_sigma": shift_sigma, "shift_limit_sigma": SHIFT_SIGMAS}
    doc["message"] = _rigid_message(doc, rate)
    return doc


def _view_costs(sol: Solution) -> dict[str, float]:
    """Per instant, its photos' squared residuals (px^2)."""
    out: dict[str, float] = {}
    for (_, view, _), cost in zip(sol.problem.blocks, _block_costs(sol)):
        out[view] = out.get(view, 0.0) + float(cost)
    return out


def _without(refit, tied: Solution, views, photos) -> tuple[Solution, Solution] | None:
    """Both solutions adjusted again (``refit``) without the instants ``views`` and the photos ``(camera, view)``;
    None without any, without ``refit``, or where they cannot be."""
    names = tied.problem.cameras
    blocks = [b for b in tied.problem.blocks if b[1] not in views and (names[b[0]], b[1]) not in set(photos)]
    if len(blocks) == len(tied.problem.blocks) or refit is None:
        return None
    try:
        return refit(blocks)
    except EstimationError:
        return None


def _rigid_message(doc: dict, rate: float) -> str:
    """``rig_rigid``'s message (:func:`rig_rigid`'s document)."""
    flagged, fs, rate_words = doc["flagged"], doc["instant_f"], f"false-alarm rate {100 * rate:g} % per calibration"
    one = len(flagged) == 1
    named = ", ".join(f"{v} (F = {fs[v]['f']:.1f} x the others' tie cost, limit {fs[v]['limit']:.2f}, "
                      f"p = {fs[v]['p']:.2g})" for v in flagged[:5]) + (f" and {len(flagged) - 5} more"
                                                                        if len(flagged) > 5 else "")
    together = f"the instants together {doc['ratio']:.2f} x the photo-level noise (limit {doc['limit_ratio']:.2f}"
    if doc["ok"] and flagged:
        return (f"the photos of every instant fit one rigid relative pose but for {named}, which fit worse than the "
                f"other instants ({rate_words}); leaving {'it' if one else 'them'} out moves the "
                f"baseline and angles by {doc['shift_sigma']:.2f} sigma at most (limit {SHIFT_SIGMAS:g}): a small "
                "misfit (the board moved a little between the shots, a shot a little late) that changes no result "
                "beyond twice its sigma; kept (--exclude them to compare)")
    if doc["ok"]:
        worst = doc["worst"]
        words = (f"the worst, {worst}, F = {fs[worst]['f']:.2f} x the others' tie cost against their scatter (limit "
                 f"{fs[worst]['limit']:.2f}); ") if worst else ""
        return f"the photos of every instant fit one rigid relative pose: {words}{together}; {rate_words})"
    if flagged:
        moved = (f"; leaving them out moves the baseline and angles by up to {doc['shift_sigma']:.1f} sigma"
                 if doc["shift_sigma"] is not None else "")
        rest = f"; without them, {together})" if doc["ratio"] > doc["limit_ratio"] else ""
        return (f"the photos of {len(flagged)} instant(s) do not fit the rig's relative pose: {named} against the "
                f"other instants' scatter{moved}{rest}: the cameras' shots of {'that instant' if one else 'those instants'} "
                "disagree (not taken at the same instant, a lens that moved, or a board that moved between the shots); "
                f"drop them with --exclude or shoot them again ({rate_words})")
    return (f"the instants fit one rigid relative pose {doc['ratio']:.1f} x worse than the photo-level noise allows "
            f"(limit {doc['limit_ratio']:.2f}; {rate_words}): the cameras' shots are not synchronised, or the rig is "
            "not rigid; its baseline and angles hold only on average")


def focal_scale_fits(sol: Solution, views=None) -> list[dict]:
    """Each photo's own focal scale, fitted with its instant's own unknowns, linearised at ``sol``.

    For every photo of the instants ``views`` (default: all), ``fx`` and ``fy`` times ``1 + s`` are
    fitted together with the instant's own unknowns (the board pose; in a rig it is held by the
    instant's other photos too, so a tele that refocused shows against the wide) and every other
    parameter held. Returns ``{"block", "camera" (index), "view", "s", "var_s" (per unit residual
    variance), "explained_px2"}`` per photo, instant by instant: ``explained_px2`` is how much of the instant's
    squared residuals the focal scale takes away.

    From the photos' own pieces of the normal equations at ``sol`` (no Jacobian computed again): with ``N`` the
    instant's own unknowns' ``J^T J`` summed over its photos and ``g`` their ``J^T r``, ``b``, ``c``, ``d`` the
    photo's ``J^T j``, ``j^T j``, ``j^T r`` of its column ``j = fx J_fx + fy J_fy``, the fit's last unknown is
    ``s = -(d - b^T N^-1 g) / S`` of variance ``1 / S``, ``S = c - b^T N^-1 b`` (the Schur complement).
    """
    p, lay = sol.problem, sol.problem.layout
    n_local = lay.local_used.shape[1]
    N = np.zeros((len(p.views), n_local, n_local))
    g = np.zeros((len(p.views), n_local))
    for ph in sol.factorization.ne.photos:       # one photo per instant in a camera: no index repeats
        N[ph.views[:, None, None], ph.local_slots[None, :, None], ph.local_slots[None, None, :]] += ph.ll
        g[ph.views[:, None], ph.local_slots] += ph.grad_l
    unused = ~lay.local_used
    N[unused[:, :, None] & np.eye(n_local, dtype=bool)] = 1.0            # an unused slot: a unit of its own
    wanted = None if views is None else {p.view_index[v] for v in views if v in p.view_index}
    fits = []
    for ph in sol.factorization.ne.photos:
        column = focal_column(sol, ph)
        if column is None:                                     # intrinsics held fixed (known): not judged here
            continue
        jl, cc, d = column
        b = np.zeros((len(ph.views), n_local))
        b[:, ph.local_slots] = jl
        for k, (block, v) in enumerate(zip(ph.blocks, ph.views)):
            if wanted is not None and v not in wanted:
                continue
            try:
                x = np.linalg.solve(N[v], np.column_stack([b[k], g[v]]))
            except np.linalg.LinAlgError:
                continue
            schur = cc[k] - b[k] @ x[:, 0]
            if not schur > 0:
                continue
            step = (d[k] - b[k] @ x[:, 1]) / schur
            fits.append({"block": int(block), "camera": ph.camera, "view": p.views[v], "s": float(-step),
                         "var_s": float(1.0 / schur), "explained_px2": float(step * step * schur)})
    first: dict[str, int] = {}                                 # instant by instant, in the order of the blocks
    for block, (_, v, _) in enumerate(p.blocks):
        first.setdefault(v, block)
    return sorted(fits, key=lambda f: (first[f["view"]], f["block"]))


def tie_costs(tied: Solution, alone: Solution) -> dict[str, float]:
    """Per instant, how much more its photos cost (px^2) tied to the rig than with every camera alone."""
    extra = _block_costs(tied) - _block_costs(alone)
    out: dict[str, float] = {}
    for b, (_, view, _) in enumerate(tied.problem.blocks):
        out[view] = out.get(view, 0.0) + float(extra[b])
    return out


def focal_scale_sigmas(fit: dict, kappa2: dict[int, float], s0_px: float) -> float:
    """A photo's own focal scale (a :func:`focal_scale_fits` entry) in units of its sigma in photo-level noise
    (``kappa2[c] s0^2`` for its camera ``c``)."""
    return fit["s"] / np.sqrt(max(kappa2[fit["camera"]] * s0_px ** 2, NOISE_FLOOR_PX ** 2) * fit["var_s"])


#: ``focus`` judges no photo whose own corners fix its focal length no better than this (1 sigma of its focal
#: scale from its corners' noise, ``s0``): few corners, or a board small or square-on in the frame. Such a photo
#: can show no refocus a phone makes (0.1-3 % of the focal length), and at its test's limit (20-25 %) the focal
#: scale, one linearised step from the calibration's focal length, no longer holds (caliscope's 12-corner webcam
#: session: a photo with 7 corners, +-27 %, gave +150 %).
MAX_FOCAL_SCALE_SIGMA = 0.05

#: The name of ``focus``'s test (calib.json ``checks.focus.test``).
FOCUS_TEST = ("Student t test of each photo's focal scale against a robust core of its camera's other photos (Sidak "
              "over the photos); the best split of each camera's photos into two groups of focal lengths against the "
              "splits of chance (Sidak over the cameras)")


def focus_drift(sol: Solution, kappa2: dict[int, float], tie_cost_px2: dict[str, float] | None = None,
                alone: Solution | None = None, rate: float = FALSE_ALARM_RATE, found_by_rig=()) -> dict:
    """Photos whose own focal length is off (the phone refocused or zoomed between shots), and cameras whose
    photos have two focal lengths (two lenses merged into one camera).

    Each photo's own focal scale ``s`` (:func:`focal_scale_fits`), with its sigma from its corners' noise (the
    photo-level noise of its camera, ``kappa2[c]``, is one factor for all of them, which the test takes from their
    own scatter: a camera of two lenses would inflate it), is judged against a robust core of its camera's other photos
    (:mod:`dualcal.estimation.robust_tests`: two or three refocused photos cannot hide each other), two-sided, by
    Student's t of :data:`T_DOF_SHARE` of the core's degrees of freedom; a photo whose sigma exceeds
    :data:`MAX_FOCAL_SCALE_SIGMA` is not judged (``not_judged``). Each camera's judged photos that do not fail
    are also split into two groups of focal lengths (:func:`dualcal.estimation.robust_tests.split_test`): a camera of
    two lenses fails, where its groups' focal lengths differ by more than :data:`SHIFT_SIGMAS` of the camera's
    focal length's sigma (relative, the larger of the clustered and the formal: a difference that no result shows
    beyond its uncertainty is no second lens). The rate ``rate`` per calibration is split by Sidak over the
    photos (half of it where a camera has photos enough to split, the other half over those cameras).

    In a rig, an instant whose cameras' shots disagree (a desynchronised shot, a lens that moved) also pulls the
    focal lengths of its photos, but a focal change explains only a small part of its misfit, where a refocus
    explains most of it: with ``tie_cost_px2`` (:func:`tie_costs`), a photo that fails is a refocus only where
    its focal scale takes away at least :data:`REFOCUS_SHARE` of its instant's extra cost of being tied to the rig;
    the others are left to ``rig_rigid`` (``flagged`` lists them with ``"cause": "rig"``). A refocused photo pulls
    the photos of its instant with it (they share the board's pose): of an instant's photos that fail, the one
    whose own focal scale is furthest off with every camera alone (``alone``, :func:`refocused_camera`) is named.
    ``found_by_rig`` are refocused photos ``rig_rigid`` found (its ``refocused``), named too.

    The document: ``ok``, ``message``, ``flagged`` (``{"camera", "view", "focal_change", "sigmas", "t", "dof", "p",
    "limit", "explained_share", "cause"}``, cause ``refocus``, ``rig`` or ``split``), ``test``, ``statistic`` (the
    largest ``|t|``, a refocused photo's first; or a split camera's ``F``), ``limit``, ``p_value``, ``worst``,
    ``false_alarm_rate`` (``rate``), ``photo_rate`` and ``split_rate`` (each test's), ``photo_t``
    ``{"camera/view": {"t", "dof", "p"}}`` (every judged photo's test), ``not_judged`` (``{"camera",
    "view", "sigma"}``), ``not_judged_limit`` (:data:`MAX_FOCAL_SCALE_SIGMA`), ``splits`` ``{camera: {"f", "limit",
    "p", "lower", "upper", "focal_change", "sigma_focal", "failed"}}`` (every camera tested: its groups' photos, the
    difference of their focal scales and the camera's relative focal sigma).
    """
    names = sol.problem.cameras
    fits = focal_scale_fits(sol)
    for fit in fits:
        fit["sigma"] = float(np.sqrt(max(sol.s0_px, NOISE_FLOOR_PX) ** 2 * fit["var_s"]))
    weak = [f for f in fits if not f["sigma"] <= MAX_FOCAL_SCALE_SIGMA]
    by_camera: dict[int, list] = {}
    for fit in fits:
        if fit["sigma"] <= MAX_FOCAL_SCALE_SIGMA:
            by_camera.setdefault(fit["camera"], []).append(fit)
    splittable = [c for c, g in by_camera.items() if len(g) >= 2 * MIN_SPLIT_GROUP]
    judged = sum(len(g) for g in by_camera.values())
    each = sidak(rate / 2 if splittable else rate, max(judged, 1))
    split_each = sidak(rate / 2, len(splittable)) if splittable else None
    flagged, splits, tested = [], {}, {}
    for c, group in by_camera.items():
        s, sd = np.array([f["s"] for f in group]), np.array([f["sigma"] for f in group])
        tests = core_tests(s, sd, robust_core(s, sd, each, T_DOF_SHARE), True, T_DOF_SHARE)
        rest = []
        for fit, test in zip(group, tests):
            if test is None:
                continue
            tie = (tie_cost_px2 or {}).get(fit["view"])
            share = fit["explained_px2"] / tie if tie and tie > 0 else None
            tested[(names[c], fit["view"])] = entry = {
                "camera": names[c], "view": fit["view"], "focal_change": fit["s"] - test.mu,
                "sigmas": float(fit["s"] / fit["sigma"]), "t": abs(test.t), "dof": test.dof, "p": test.p,
                "limit": test.limit(each, True),
                "explained_share": share, "cause": "refocus" if share is None or share >= REFOCUS_SHARE else "rig"}
            if test.p < each:
                flagged.append(entry)
            else:
                rest.append(fit)
        if c in splittable and len(rest) >= 2 * MIN_SPLIT_GROUP:
            cam = sol.state.intrinsics[c]
            sigma = max(sol.intrinsic_sigma(c, kind)[k] / v for kind in ("clustered", "formal")
                        for k, v in (("fx", cam[0]), ("fy", cam[1])))
            splits[names[c]] = sp = _split(rest, split_each, SHIFT_SIGMAS * sigma)
            sp["sigma_focal"] = sigma
            if sp["failed"]:
                small = sp["lower"] if len(sp["lower"]) <= len(sp["upper"]) else sp["upper"]
                sign = 1.0 if small is sp["upper"] else -1.0
                flagged += [{**tested[(names[c], view)], "focal_change": sign * sp["focal_change"], "t": None,
                             "p": sp["p"], "limit": sp["limit"], "explained_share": None, "cause": "split"}
                            for view in small]
    if alone is not None and sol.problem.mode != "none":
        flagged = _one_per_instant(flagged, tested, alone, kappa2)
    flagged += [{**f, "sigmas": None, "t": None, "dof": None, "limit": None, "cause": "refocus"} for f in found_by_rig]
    flagged.sort(key=lambda f: (f["cause"] != "refocus", f["t"] is None, -(f["t"] or 0.0)))
    return _focus_document(flagged, splits, list(tested.values()), weak, names, each, split_each, rate)


def _split(fits: list[dict], rate: float, least_change: float) -> dict:
    """One camera's photos (:func:`focal_scale_fits` entries with their ``sigma``) split into two groups of focal
    lengths (:func:`dualcal.estimation.robust_tests.split_test`): ``{"f", "limit", "p", "failed", "focal_change",
    "lower", "upper"}``, the difference of the groups' weighted mean focal scales and their photos."""
    found = split_test(np.array([f["s"] for f in fits]), np.array([f["sigma"] for f in fits]), rate, T_DOF_SHARE,
                       least_change)
    low = found["lower"]
    return {"f": found["f"], "limit": found["limit"], "p": found["p"], "failed": found["failed"],
            "focal_change": found["change"], "lower": [f["view"] for f, x in zip(fits, low) if x],
            "upper": [f["view"] for f, x in zip(fits, low) if not x]}


def refocused_camera(alone: Solution, view: str, kappa2) -> int | None:
    """Of the photos of ``view``, the camera whose own focal scale is furthest off with its own pose
    (:func:`focal_scale_fits` on the cameras-alone solution), in photo-level sigmas."""
    fits = focal_scale_fits(alone, {view})
    if not fits:
        return None
    z = [abs(focal_scale_sigmas(f, kappa2, alone.s0_px)) for f in fits]
    return fits[int(np.argmax(z))]["camera"]


def _one_per_instant(flagged: list[dict], tested: dict, alone: Solution, kappa2) -> list[dict]:
    """Of every instant with a refocused photo, the photo :func:`refocused_camera` picks (a refocus pulls the other
    photos of its instant with it: they share the board's pose in the rig), from ``tested`` ``{(camera, view):
    entry}``; the others of the instant are no longer named."""
    names = alone.problem.cameras
    picked = {}
    for f in flagged:
        if f["cause"] == "refocus" and f["view"] not in picked:
            c = refocused_camera(alone, f["view"], kappa2)
            picked[f["view"]] = tested.get((names[c], f["view"])) if c is not None else None
    out = [f for f in flagged if f["cause"] != "refocus" or picked[f["view"]] is None]
    return out + [{**entry, "cause": "refocus"} for entry in picked.values() if entry is not None]


def _focus_document(flagged, splits, tested, weak, names, each, split_each, rate) -> dict:
    """``focus``'s document and message (:func:`focus_drift`)."""
    refocused = [f for f in flagged if f["cause"] == "refocus"]
    split = {n: sp for n, sp in splits.items() if sp["failed"]}
    worst = max(tested, key=lambda f: f["t"], default=None)
    doc = {"test": FOCUS_TEST, "false_alarm_rate": rate, "photo_rate": each, "split_rate": split_each,
           "photo_t": {f"{f['camera']}/{f['view']}": {"t": round(f["t"], 3), "dof": f["dof"], "p": f["p"]}
                       for f in tested},
           "flagged": flagged, "splits": splits, "not_judged_limit": MAX_FOCAL_SCALE_SIGMA,
           "not_judged": [{"camera": names[f["camera"]], "view": f["view"], "sigma": f["sigma"]} for f in weak]}
    if refocused:
        top = refocused[0]
        doc.update(statistic=top["t"] if top["t"] is not None else top["f"],
                   limit=top["limit"] if top["t"] is not None else top["f_limit"], p_value=top["p"],
                   worst=f"{top['camera']}/{top['view']}")
    elif split:
        name, sp = next(iter(split.items()))
        doc.update(statistic=sp["f"], limit=sp["limit"], p_value=sp["p"], worst=f"{name} (two focal lengths)")
    elif worst is not None:
        doc.update(statistic=worst["t"], limit=worst["limit"], p_value=worst["p"],
                   worst=f"{worst['camera']}/{worst['view']}")
    else:
        doc.update(statistic=None, limit=None, p_value=None, worst=None)
    rate_words = f"false-alarm rate {100 * rate:g} % per calibration"
    sigmas = [f["sigma"] for f in weak]
    unjudged = (f"; {len(weak)} photo(s) not judged: their own corners fix the focal length only to "
                f"+-{100 * min(sigmas):.0f}-{100 * max(sigmas):.0f} % (more than {100 * MAX_FOCAL_SCALE_SIGMA:g} %: "
                "few corners, or the board small or square-on)") if weak else ""
    problems = []
    if refocused:
        problems.append(f"{len(refocused)} photo(s) have a focal length of their own: " + ", ".join(
            f"{f['camera']}/{f['view']} ({100 * f['focal_change']:+.2f} %, " + (
                f"|t| = {f['t']:.1f}, limit {f['limit']:.2f})" if f["t"] is not None else
                f"its instant F = {f['f']:.1f} x the others' tie cost, limit {f['f_limit']:.2f}, "
                f"{100 * f['explained_share']:.0f} % of it the focal change's)")
            for f in refocused[:4]) + (f" and {len(refocused) - 4} more" if len(refocused) > 4 else "")
            + ": the phone refocused or zoomed between shots (or the photos are another lens's)")
    for name, sp in split.items():
        problems.append(f"the photos of {name} have two focal lengths, {100 * sp['focal_change']:.1f} % apart "
                        f"({len(sp['lower'])} and {len(sp['upper'])} photos; split F = {sp['f']:.0f}, limit "
                        f"{sp['limit']:.0f}): two lenses taken for one camera, or the focus changed between two "
                        "series")
    if problems:
        doc["ok"] = False
        doc["message"] = ("; ".join(problems) + ": lock focus (AF/AE lock) and shoot again, leave them out with "
                          f"--exclude, or give each lens its own camera ({rate_words}){unjudged}")
        return doc
    doc["ok"] = True
    rest = (f" (the focal lengths of {len(flagged)} photo(s) of instants that do not fit the rig move too, as a pose "
            "error pulls them: see rig_rigid)") if flagged else ""
    stat = (f"the worst, {doc['worst']}, |t| = {doc['statistic']:.2f} against its camera's other photos (limit "
            f"{doc['limit']:.2f}; {rate_words})") if worst is not None else "too few photos per camera to judge"
    doc["message"] = f"no photo's own focal length is off: {stat}{rest}{unjudged}"
    return doc


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
    """Parameters known too poorly to use, in plain words with what would help (thresholds above); the rig's
    relations only where the rig was calibrated (not in rig mode ``none``: each camera from its own photos)."""
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
    for name, rel in (rig.rig.items() if rig.rig_mode != "none" else ()):     # --rig none calibrates no rig
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


def camera_edge_ratio(sol: Solution, c: int, per_view: bool = True) -> tuple[float, list[str]]:
    """Camera ``c``'s RMS residual of its outermost third of corners (by their distance from the principal point)
    over that of its innermost third (NaN with too few corners), and (``per_view``) the views where that ratio of
    their own corners exceeds :data:`EDGE_RATIO`."""
    p = sol.problem
    cam = sol.state.camera(p, c)
    blocks = [b for b, (cc, _, _) in enumerate(p.blocks) if cc == c]
    if not blocks:
        return float("nan"), []
    uv = np.array([p.blocks[b][2] for b in blocks], float)
    length = np.linalg.norm(sol.residuals[blocks], axis=2)                   # NaN where not measured
    rho = np.where(np.isfinite(length), np.hypot(uv[..., 0] - cam.cx, uv[..., 1] - cam.cy), np.nan)
    ratio = float(_edge_ratios(rho.reshape(1, -1), length.reshape(1, -1))[0])
    if not per_view:
        return ratio, []
    over = _edge_ratios(rho, length) > EDGE_RATIO
    return ratio, [f"{p.cameras[c]}/{p.blocks[b][1]}" for b, o in zip(blocks, over) if o]


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


def _edge_ratios(rho: np.ndarray, length: np.ndarray, min_points: int = 10) -> np.ndarray:
    """For each row of ``rho`` and ``length`` (V, N; NaN where not measured), the RMS of the residual lengths of
    the outermost third of its corners (by ``rho``) over that of the innermost third: (V,), NaN with fewer than
    ``min_points`` in a third. The thirds' bounds are :func:`numpy.quantile`'s (its linear interpolation), all rows
    in one batch."""
    n = np.isfinite(rho).sum(axis=1)
    ordered = np.sort(rho, axis=1)                                     # NaN last
    bounds = []
    for q in (1 / 3, 2 / 3):
        at = (np.maximum(n, 1) - 1) * q
        below = np.floor(at).astype(int)
        a = np.take_along_axis(ordered, below[:, None], 1)[:, 0]
        b = np.take_along_axis(ordered, np.minimum(below + 1, np.maximum(n - 1, 0))[:, None], 1)[:, 0]
        t = at - below
        bounds.append(np.where(t >= 0.5, b - (b - a) * (1 - t), a + (b - a) * t))      # numpy's _lerp
    squares = np.where(np.isfinite(rho), length ** 2, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        inner = rho <= bounds[0][:, None]
        outer = rho >= bounds[1][:, None]
        rms_in = np.sqrt(np.sum(np.where(inner, squares, 0.0), axis=1) / inner.sum(axis=1))
        rms_out = np.sqrt(np.sum(np.where(outer, squares, 0.0), axis=1) / outer.sum(axis=1))
        ratio = rms_out / np.maximum(rms_in, 1e-12)
    return np.where(n >= 3 * min_points, ratio, np.nan)


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


def focus_and_rigidity(tied: Solution, alone: Solution, kappa2, refit=None) -> tuple[dict, dict | None]:
    """``focus`` and ``rig_rigid`` from one pair of solutions, each naming every photo or instant to blame at once
    (tests against a robust core of the others): the refocused photos first, whose instants ``rig_rigid`` then
    does not judge (a refocus explains their misfit). ``refit``: see :func:`rig_rigid`."""
    tie = tie_costs(tied, alone) if tied.problem.mode != "none" else None
    focus = focus_drift(tied, kappa2, tie, alone)
    refocused = [(f["camera"], f["view"]) for f in focus["flagged"] if f["cause"] == "refocus"]
    rigid = rig_rigid(tied, alone, kappa2, refocused, refit=refit)
    if rigid is not None and rigid["refocused"]:          # refocused photos that hid each other from focus's test
        focus = focus_drift(tied, kappa2, tie, alone, found_by_rig=rigid["refocused"])
    return focus, rigid


def run_checks(rig: RigModel, sol: Solution, tied_flat: Solution, alone: Solution, attribution=None) -> dict:
    """Every check of a calibration: ``rig`` and its final solution ``sol``; ``tied_flat`` the same
    rig mode with a flat board and ``alone`` every camera alone, over the same photos (for
    ``rig_rigid`` and ``focus``). ``attribution(tied, alone, kappa2) -> (focus, rig_rigid)`` makes those
    two (default: :func:`focus_and_rigidity`)."""
    checks = {"converged": convergence(sol), "photos": photo_count(rig), "fit": fit_quality(rig)}
    kappa2 = design_effect(alone)
    focus, rigid = (attribution or focus_and_rigidity)(tied_flat, alone, kappa2)
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
