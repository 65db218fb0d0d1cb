"""Whether the cameras of a rig of three or more, taken two at a time, tell the rig's story: the ``loop_closure``
check, from the joint solution and the solution with every camera alone (no pair adjusted again).

The joint adjustment of a rigid rig has one relative pose per camera (reference -> camera), so the relation
between two other cameras B and C is ``T_BC = T_C T_B^-1`` and every loop closes by construction: comparing the
joint solution with itself tests nothing. What can be tested is whether each pair's own photos agree with it.
With every camera alone each photo has its own board pose, so every instant that two cameras ``x`` and ``y``
both saw shows their relative pose (:func:`dualcal.estimation.instant_poses.relation_deviation`): its deviation
``d_v`` (rotation increment rad, translation mm) from the joint relation ``T_xy`` (from the reference's
relations, reported as calib.json has them), with the covariance of all of them together from the
cameras-alone solution's inverse normal matrix (their intrinsics' shared error included) in units of the
photo-level noise ``kappa^2 s0^2`` (the design effect, as ``rig_rigid`` takes it). For each pair sharing
:data:`MIN_PAIR_INSTANTS` instants or more:

* its **scatter**: the deviations about their own weighted mean, ``S = (D - A e)^T Cov^-1 (D - A e)``, a
  chi-square of ``6 (n - 1)`` degrees of freedom for a rigid pair; ``ratio = S / (6 (n - 1))`` against
  ``F(6 (n - 1), G - 1)`` (the photo-level noise comes from the scatter of ``G`` instants). It is taken over the
  pair's **robust core** of instants (:mod:`dualcal.estimation.robust_tests`: each instant's own chi-square, its
  cube root against the others', as ``rig_rigid`` judges its instants): a board small and far in a photo has a pose
  whose error is far from Gaussian (two minima, a curved valley), and a few such instants, each 5-50 x its
  linearised covariance, made every pair of a synthetic caliscope session fail (18 of 20 sessions) on a rigid rig.
  The instants apart from the core fail the pair only where leaving them out moves its mean by more than
  :data:`dualcal.estimation.checks.SHIFT_SIGMAS` of its sigma (as ``rig_rigid``'s instants). A camera that moved
  between instants (knocked, a lens with stabilisation) fails every pair it belongs to and passes the others,
  which names it (the camera common to the pairs that fail);
* its **closure** (pairs of two non-reference cameras B and C: the loop reference -> B -> C): the mean ``e``
  of the pair's own relative poses against the joint relation, ``T^2 = e^T (Cov_e + Cov_BC)^-1 e`` with the
  mean's covariance and the joint relation's (the adjustment's, formal, in the same noise), against
  ``6 F(6, G - 1)``; the two are taken as independent, which is exact for instants the reference did not see
  and cautious for those it saw (there the pair's mean moves with the joint relation).

Every test at the check's false-alarm rate (:data:`dualcal.estimation.checks.FALSE_ALARM_RATE`, split over
the tests by Sidak), as the other checks. A pair sharing fewer instants is not judged, and said so.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from .adjust import Solution
from .checks import FALSE_ALARM_RATE, SHIFT_SIGMAS, T_DOF_SHARE, design_effect
from .distributions import f_quantile, f_sf, sidak
from ..geometry.model import Pose, stacked
from .instant_poses import pose_columns, relation_deviation
from .rig_relations import rig_linearisation
from .robust_tests import cube_root_spread, robust_core
from ..geometry.rotation import ARCMIN_PER_RAD

__all__ = ["MIN_PAIR_INSTANTS", "LOOP_TEST", "loop_closure"]

#: A pair of cameras that shares fewer instants is not judged: its relative poses from so few photos say too
#: little about their scatter (each one's error is correlated within its photos, which the noise of their
#: corners does not show).
MIN_PAIR_INSTANTS = 3

#: An instant whose relative pose (with every camera alone) is known to worse than this (its largest rotation
#: sigma, degrees) is not judged: a board small or far in a photo has a pose whose error is far from Gaussian (two
#: minima, a curved valley), which the linear test takes for a misfit. On synthetic caliscope sessions (four webcams
#: 2 m from a 12-corner board that spans 50-90 px; poses to 1.4-4.4 degrees) every pair through such instants
#: scattered 2-9 x their linearised covariance on a rigid rig, and the check failed 17 times in 20; a board that
#: fills a good part of the frame gives poses to hundredths of a degree.
MAX_ROTATION_SIGMA_DEG = 1.0

#: The name of ``loop_closure``'s test (calib.json ``checks.loop_closure.test``).
LOOP_TEST = ("F test of each pair of cameras' relative poses instant by instant about their mean, and of that mean "
             "against the rig's relation (loops through the reference), against the photo-level noise (Sidak over "
             "the tests)")


def _relation(sol: Solution, c: int):
    """Camera ``c``'s relation to the reference as a pose (identity for the reference), and its Jacobian (6, k)
    (rotation increment, translation) by the flat columns (k,)."""
    if c == sol.problem.reference:
        return Pose(np.eye(3), np.zeros(3)), np.zeros((6, 0)), np.zeros(0, int)
    lin = rig_linearisation(sol, c)
    return Pose(lin.R, lin.t), np.vstack([lin.J_rot, lin.J_t]), lin.columns


def _joint_relation(tied: Solution, x: int, y: int, kappa2: float):
    """The joint relation of ``y`` to ``x`` (``R``, ``t``) and its covariance (6, 6) in photo-level noise."""
    (P_x, J_x, cols_x), (P_y, J_y, cols_y) = _relation(tied, x), _relation(tied, y)
    _, J = relation_deviation(P_x.R, P_x.t_mm, P_y.R, P_y.t_mm, np.eye(3), np.zeros(3))
    cols = np.unique(np.concatenate([cols_x, cols_y]))
    L = np.zeros((12, len(cols)))
    L[:6, np.searchsorted(cols, cols_x)] = J_x
    L[6:, np.searchsorted(cols, cols_y)] = J_y
    cov = kappa2 * (J @ L) @ tied.covariance(cols, "formal") @ (J @ L).T if len(cols) else np.zeros((6, 6))
    R = P_y.R @ P_x.R.T
    return R, P_y.t_mm - R @ P_x.t_mm, cov


def _scatter(D: np.ndarray, cov: np.ndarray, keep: np.ndarray):
    """The weighted mean ``e`` (6,) of the deviations ``D`` (n, 6) of the instants ``keep`` (n,) bool, with their
    joint covariance ``cov`` (6n, 6n), its covariance, and their scatter about it (a chi-square of ``6 (k - 1)``
    degrees of freedom for ``k`` instants kept)."""
    rows = np.repeat(keep, 6)
    d = D[keep].ravel()
    A = np.tile(np.eye(6), (int(keep.sum()), 1))
    WA_Wd = np.linalg.solve(cov[np.ix_(rows, rows)], np.column_stack([A, d]))     # cov^-1 [A d]
    WA, Wd = WA_Wd[:, :6], WA_Wd[:, 6]
    cov_e = np.linalg.inv(A.T @ WA)
    e = cov_e @ (A.T @ Wd)
    return e, cov_e, float((d - A @ e) @ (Wd - WA @ e))


def _deviations(tied: Solution, alone: Solution, x: int, y: int, views: list[str], kappa2: float):
    """A pair's relative pose at each of ``views`` (with every camera alone) as its deviation from the joint
    relation: ``(D (n, 6), cov4 (n, 6, n, 6), cov_J (6, 6))``, the deviations (rotation increment rad,
    translation mm), their joint covariance and the joint relation's, all in photo-level noise."""
    R_J, t_J, cov_J = _joint_relation(tied, x, y, kappa2)
    poses = alone.photo_poses
    n = len(views)
    D, J = relation_deviation(*stacked([poses[(x, v)] for v in views]), *stacked([poses[(y, v)] for v in views]),
                              R_J, t_J)
    columns = np.concatenate([np.concatenate([pose_columns(alone, v, x), pose_columns(alone, v, y)]) for v in views])
    C = alone.covariance(columns, "formal").reshape(n, 12, n * 12)
    JC = np.swapaxes((J @ C).reshape(n, 6, n, 12), 0, 2)                      # (b, i, a, k): J block-diagonal
    JCJ = (JC.reshape(n, 6 * n, 12) @ np.swapaxes(J, 1, 2)).reshape(n, 6, n, 6)     # (b, i, a, l)
    return D, kappa2 * np.transpose(JCJ, (2, 1, 0, 3)), cov_J


def _rotation_sigma_deg(cov4: np.ndarray) -> np.ndarray:
    """(n,) each instant's largest rotation sigma of its relative pose (degrees), from ``cov4``."""
    blocks = np.einsum("aiaj->aij", cov4)[:, :3, :3]
    return np.degrees(np.sqrt(np.maximum(np.linalg.eigvalsh(blocks)[:, -1], 0.0)))


def _pair(D: np.ndarray, cov4: np.ndarray, cov_J: np.ndarray, rate: float) -> dict:
    """A pair's deviations ``D`` (n, 6) with their covariance ``cov4`` (:func:`_deviations`): the instants of its
    robust core (``core`` (n,) bool: each instant's own chi-square, its cube root against the others',
    :mod:`dualcal.estimation.robust_tests`, as ``rig_rigid`` judges its instants, at ``rate``), their scatter ``S``
    about their mean, the mean ``e`` and its covariance with the joint relation's ``cov_J``, and ``shift``: how far
    the instants outside the core move the mean, the largest change of a component over its sigma from the core."""
    n = len(D)
    cov = cov4.reshape(6 * n, 6 * n)
    own = np.einsum("ai,ai->a", D, np.linalg.solve(np.einsum("aiaj->aij", cov4), D[..., None])[..., 0])  # 6 dof each
    r = cube_root_spread(np.full(n, 6.0))
    core = robust_core(np.cbrt(own / 6.0), r, rate, T_DOF_SHARE)
    e, cov_e, scatter = _scatter(D, cov, core)
    shift = 0.0
    if not core.all():
        e_all = _scatter(D, cov, np.ones(n, bool))[0]
        shift = float(np.max(np.abs(e_all - e) / np.sqrt(np.maximum(np.diag(cov_e), 1e-300))))
    return {"scatter": scatter, "e": e, "cov_e": cov_e + cov_J, "core": core, "shift": shift}


def loop_closure(tied: Solution, alone: Solution, kappa2: float | None = None,
                 rate: float = FALSE_ALARM_RATE) -> dict | None:
    """The ``loop_closure`` check (module docstring) of a rig; None for fewer than three cameras or rig mode
    ``none``.

    Parameters
    ----------
    tied : the joint solution (rig mode ``rigid`` or ``paper``, a flat board), over the same photos as ``alone``.
    alone : every camera alone (rig mode ``none``).
    kappa2 : the photo-level noise over the white noise (default: the largest of ``alone``'s cameras' design
        effects, :func:`dualcal.estimation.checks.design_effect`).
    rate : the false-alarm rate per calibration.

    Returns
    -------
    ``{"ok", "message", "test", "statistic", "limit", "p_value", "false_alarm_rate", "test_rate", "worst",
    "pairs": {"X-Y": {"ok", "views", "judged", "ratio", "limit_ratio", "p", "core_instants", "apart" (the instants
    apart from the core), "shift_sigma", "shift_limit_sigma"}} (a pair not judged: ``"message"`` instead of the
    statistics), "loops": {"r-B-C": {"ok", "t2",
    "limit", "p", "instants", "rotation_arcmin": [3], "t_mm": [3], "sigma_rotation_arcmin": [3], "sigma_t_mm":
    [3]}}, "not_judged": ["X-Y", ...]}`` (the misclosure in C's frame), ``statistic`` and ``limit`` of the test
    of the smallest p-value (a pair's ratio or a loop's ``T^2``).
    """
    p = tied.problem
    names, ref = p.cameras, p.reference
    if len(names) < 3 or p.mode == "none":
        return None
    kappa2 = max(design_effect(alone).values()) if kappa2 is None else kappa2
    G = len(alone.problem.views)
    photos = alone.photo_poses
    shared = {}
    for x, y in combinations(range(len(names)), 2):
        x, y = (y, x) if y == ref else (x, y)
        shared[(x, y)] = [v for v in alone.problem.views if (x, v) in photos and (y, v) in photos]
    firm, weak = {}, {}
    for (x, y), views in shared.items():         # instants whose poses the linear test can judge
        if len(views) >= MIN_PAIR_INSTANTS:
            D, cov4, cov_J = _deviations(tied, alone, x, y, views, kappa2)
            keep = _rotation_sigma_deg(cov4) <= MAX_ROTATION_SIGMA_DEG
            weak[(x, y)] = int((~keep).sum())
            if keep.sum() >= MIN_PAIR_INSTANTS:
                firm[(x, y)] = ([v for v, k in zip(views, keep) if k], D[keep], cov4[keep][:, :, keep], cov_J)
    n_tests = len(firm) + sum(ref not in k for k in firm)
    each = sidak(rate, max(n_tests, 1))
    pairs, loops, tests = {}, {}, []
    for (x, y), views in shared.items():
        key = f"{names[x]}-{names[y]}"
        if (x, y) not in firm:
            why = (f"fewer than {MIN_PAIR_INSTANTS} shared instants" if len(views) < MIN_PAIR_INSTANTS else
                   f"fewer than {MIN_PAIR_INSTANTS} shared instants whose relative pose is known to "
                   f"{MAX_ROTATION_SIGMA_DEG:g} degree ({weak[(x, y)]} of {len(views)} are not: boards small or far)")
            pairs[key] = {"ok": True, "judged": False, "views": len(views), "message": f"not judged: {why}"}
            continue
        views, D, cov4, cov_J = firm[(x, y)]
        fit = _pair(D, cov4, cov_J, sidak(each, len(views)))
        kept = int(fit["core"].sum())
        dof = 6 * (kept - 1)
        ratio = fit["scatter"] / dof
        p_pair = f_sf(ratio, dof, max(G - 1, 1))
        limit = f_quantile(dof, max(G - 1, 1), 1.0 - each)
        apart = [v for v, k in zip(views, fit["core"]) if not k]
        moved = fit["shift"] > SHIFT_SIGMAS
        pairs[key] = {"ok": bool(ratio <= limit and not moved), "judged": True, "views": len(views), "ratio": ratio,
                      "limit_ratio": limit, "p": p_pair, "core_instants": kept, "apart": apart,
                      "shift_sigma": fit["shift"], "shift_limit_sigma": SHIFT_SIGMAS}
        tests.append((p_pair, f"pair {key}", ratio, limit))
        if ref in (x, y):
            continue
        e, cov_e = fit["e"], fit["cov_e"]
        t2 = float(e @ np.linalg.solve(cov_e, e))
        p_loop = f_sf(t2 / 6, 6, max(G - 1, 1))
        limit = 6 * f_quantile(6, max(G - 1, 1), 1.0 - each)
        sd = np.sqrt(np.maximum(np.diag(cov_e), 0.0))
        loop = f"{names[ref]}-{names[x]}-{names[y]}"
        loops[loop] = {"ok": t2 <= limit, "t2": t2, "limit": limit, "p": p_loop, "instants": len(views),
                       "rotation_arcmin": (e[:3] * ARCMIN_PER_RAD).tolist(), "t_mm": e[3:].tolist(),
                       "sigma_rotation_arcmin": (sd[:3] * ARCMIN_PER_RAD).tolist(), "sigma_t_mm": sd[3:].tolist()}
        tests.append((p_loop, f"loop {loop}", t2, limit))
    return _document(pairs, loops, tests, rate, each)


def _pair_words(key: str, pair: dict) -> str:
    """Why a pair fails, in words: its core's scatter, and the instants apart from the core that move it."""
    words = f"{key} ({pair['ratio']:.1f} x the noise, limit {pair['limit_ratio']:.2f}"
    if pair["shift_sigma"] > pair["shift_limit_sigma"]:
        shown = ", ".join(pair["apart"][:6]) + (" ..." if len(pair["apart"]) > 6 else "")
        words += (f"; {len(pair['apart'])} instant(s) apart from the others, {shown}, move its relation by "
                  f"{pair['shift_sigma']:.1f} sigma")
    return words + ")"


def _document(pairs: dict, loops: dict, tests: list, rate: float, each: float) -> dict:
    """``loop_closure``'s document and message (:func:`loop_closure`)."""
    not_judged = [k for k, pr in pairs.items() if not pr["judged"]]
    bad_pairs = [k for k, pr in pairs.items() if not pr["ok"]]
    bad_loops = [k for k, lp in loops.items() if not lp["ok"]]
    worst = min(tests, default=None, key=lambda t: t[0])
    doc = {"ok": not bad_pairs and not bad_loops, "test": LOOP_TEST, "false_alarm_rate": rate, "test_rate": each,
           "statistic": worst[2] if worst else None, "limit": worst[3] if worst else None,
           "p_value": worst[0] if worst else None, "worst": worst[1] if worst else None,
           "pairs": pairs, "loops": loops, "not_judged": not_judged}
    rate_words = f"false-alarm rate {100 * rate:g} % per calibration"
    skipped = "".join(f"; pair {k} ({pairs[k]['views']}) {pairs[k]['message']}" for k in not_judged)
    if not tests:
        doc["message"] = (f"no pair of cameras shares {MIN_PAIR_INSTANTS} instants or more whose relative pose the "
                          f"test can judge: the cameras' pairwise relative poses cannot be checked{skipped}")
    elif doc["ok"]:
        doc["message"] = (f"the cameras' pairwise relative poses agree with the rig: {len(tests) - len(loops)} pair(s) "
                          f"scatter as their photos' noise allows and {len(loops)} loop(s) close (the worst, "
                          f"{worst[1]}, {worst[2]:.2f} against a limit of {worst[3]:.2f}; {rate_words}){skipped}")
    else:
        parts = []
        if bad_pairs:
            cams = [set(k.split("-")) for k in bad_pairs]
            common = set.intersection(*cams) if len(cams) > 1 else set()
            words = ", ".join(_pair_words(k, pairs[k]) for k in bad_pairs)
            moved = f" (camera {', '.join(sorted(common))} in each: it moved between instants?)" if common else ""
            parts.append(f"the pair(s) {words} do not fit one rigid relation{moved}")
        for k in bad_loops:
            lp = loops[k]
            parts.append(f"loop {k} misses by {np.linalg.norm(lp['rotation_arcmin']):.2f}' and "
                         f"{np.linalg.norm(lp['t_mm']):.3f} mm (T^2 {lp['t2']:.1f}, limit {lp['limit']:.1f})")
        doc["message"] = ("; ".join(parts) + ": the rig's relative poses do not hold for every instant "
                          f"({rate_words}); find the instants with rig_rigid, drop them with --exclude or shoot "
                          f"again{skipped}")
    return doc
