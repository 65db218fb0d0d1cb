"""Whether the pairwise relative poses of a rig of three or more cameras close their loops.

The joint adjustment of a rigid rig has one relative pose per camera (reference -> camera), so
the relation between two other cameras B and C is ``T_BC = T_C T_B^-1`` and every loop closes by
construction: comparing the joint solution with itself tests nothing. What can be tested is
whether the cameras, taken two at a time, tell the same story. Every pair ``(X, Y)`` is
calibrated alone as a rigid two-camera rig, from the instants both saw (intrinsics free, X its
reference), and for every loop ``ref -> B -> C`` the composed pairwise relations are compared
with the direct one:

* the misclosure ``R_e = R_BC R_rB R_rC^T`` (as its rotation vector, arcmin) and
  ``t_e = R_BC t_rB + t_BC - t_rC`` (mm), in C's frame;
* its covariance clustered by instant: each instant's shift of every pair's relation (its adjusted
  score through the pair's inverse normal matrix, the terms of the pair's ``clustered`` covariance,
  :meth:`dualcal.estimation.adjust.Solution.instant_shifts`) is carried to the misclosure to first order in the
  left increments ``R <- exp([d]x) R`` (``d_e = d_BC + R_BC d_rB - d_rC``, ``dt_e = -[R_BC t_rB]x d_BC
  + R_BC dt_rB + dt_BC - dt_rC``), summed over the pairs instant by instant, and ``Cov = sum_v s_v s_v^T``
  over the ``n`` instants. The pairs share photos (each camera's are in two pairs), so their errors are
  correlated; summing per instant keeps that (taking the pairs as independent overstated the sigma
  about ten-fold on synthetic rigs);
* Hotelling's ``T^2 = e^T Cov^-1 e``, failing beyond ``6 (n-1) / (n-6) F(6, n-6)`` at
  :data:`LOOP_FALSE_ALARM` (Bonferroni over the loops): the covariance is estimated from ``n``
  instants. A loop needs more than 6 instants.

A loop of averages can close although a camera moved: with every instant seen by all three, the
pairs with the moved camera average the same two poses. So each pair's own rigidity is judged too,
by :func:`dualcal.estimation.checks.rig_rigid` on the pair's rigid and cameras-alone solutions: a camera
knocked between instants fails the pairs it belongs to and passes the others, which names it.
The check passes when every pair is rigid and every loop closes.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from .adjust import Solution
from .distributions import f_quantile
from ..errors import EstimationError
from ..geometry.poses import rotated
from .rig_relations import rig_linearisation
from ..geometry.rotation import ARCMIN_PER_RAD, cross_matrix, rotvec_from_rotation

__all__ = ["LOOP_FALSE_ALARM", "loop_closure"]

#: False-alarm rate of the loop test, over all loops together.
LOOP_FALSE_ALARM = 1e-3


def _pair_relation(sol: Solution):
    """Camera 1's rigid relation to camera 0 in a two-camera solution at its linearised minimum (moved by the
    remaining Gauss-Newton step, so that where the solve stopped matters only to second order): R, t and
    each instant's shift of (rotation increment rad, t mm), ``{view: (6,)}``."""
    lin = rig_linearisation(sol, 1)
    J = np.vstack([lin.J_rot, lin.J_t])
    step = J @ sol.factorization.step()[lin.columns]
    return rotated(lin.R, step[:3]), lin.t + step[3:], {v: J @ d for v, d in sol.instant_shifts(lin.columns).items()}


def _misclosure(rB, rC, BC):
    """Misclosure (rotation vector rad, t mm) of ref -> B -> C against ref -> C, and each instant's shift of it."""
    (R_rB, t_rB, d_rB), (R_rC, t_rC, d_rC), (R_BC, t_BC, d_BC) = rB, rC, BC
    e = np.concatenate([rotvec_from_rotation(R_BC @ R_rB @ R_rC.T), R_BC @ t_rB + t_BC - t_rC])
    J_BC = np.block([[np.eye(3), np.zeros((3, 3))], [-cross_matrix(R_BC @ t_rB), np.eye(3)]])
    J_rB = np.block([[R_BC, np.zeros((3, 3))], [np.zeros((3, 3)), R_BC]])
    views = set(d_rB) | set(d_rC) | set(d_BC)
    zero = np.zeros(6)
    shifts = np.array([J_BC @ d_BC.get(v, zero) + J_rB @ d_rB.get(v, zero) - d_rC.get(v, zero)
                       for v in sorted(views)])
    return e, shifts


def loop_closure(names: list[str], ref: int, pair_solutions, rig_rigid) -> dict | None:
    """The ``loop_closure`` check (module docstring) of a rig; None for fewer than three cameras.

    Parameters
    ----------
    names : the cameras; ``ref`` the index of the reference.
    pair_solutions : ``(x, y) -> (tied, alone, instants)``, cameras ``x`` and ``y`` as a rigid two-camera
        rig (``x`` its reference) and alone, over the instants both saw
        (:func:`dualcal.estimation.fitting.pair_solutions`); raises :class:`EstimationError` when they cannot be.
    rig_rigid : ``(tied, alone) -> dict | None``, :func:`dualcal.estimation.checks.rig_rigid` of a pair (the
        calibration passes the rig's design effect, so that every pair is judged against the same noise).

    Returns
    -------
    ``{"ok", "message", "pairs": {"X-Y": {"ok", "ratio", "views"}}, "loops": {"r-B-C": {"ok", "t2",
    "limit", "instants", "rotation_arcmin": [3], "t_mm": [3], "sigma_rotation_arcmin": [3], "sigma_t_mm": [3]}}}``
    (misclosure in C's frame; sigmas from the clustered covariance).
    """
    if len(names) < 3:
        return None
    pairs, relations = {}, {}
    for x, y in combinations(range(len(names)), 2):
        if y == ref:
            x, y = y, x
        key = f"{names[x]}-{names[y]}"
        try:
            tied, alone, views = pair_solutions(x, y)
        except EstimationError as exc:
            pairs[key] = {"ok": False, "views": 0, "message": str(exc)}
            continue
        rigid = rig_rigid(tied, alone) or {"ok": True, "ratio": 0.0}
        pairs[key] = {"ok": bool(rigid["ok"]), "ratio": float(rigid["ratio"]), "views": views}
        relations[(x, y)] = _pair_relation(tied)
    others = [c for c in range(len(names)) if c != ref]
    loops = {}
    triples = [(b, c) for b, c in combinations(others, 2) if {(ref, b), (ref, c), (b, c)} <= set(relations)]
    alpha = LOOP_FALSE_ALARM / max(1, len(triples))
    for b, c in triples:
        e, shifts = _misclosure(relations[(ref, b)], relations[(ref, c)], relations[(b, c)])
        n = len(shifts)
        if n <= 6:
            continue
        cov = shifts.T @ shifts
        stat = float(e @ np.linalg.lstsq(cov, e, rcond=None)[0])
        limit = float(6 * (n - 1) / (n - 6) * f_quantile(6, n - 6, 1.0 - alpha))       # Hotelling's T^2
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        loops[f"{names[ref]}-{names[b]}-{names[c]}"] = {
            "ok": stat <= limit, "t2": stat, "limit": limit, "instants": n,
            "rotation_arcmin": (e[:3] * ARCMIN_PER_RAD).tolist(), "t_mm": e[3:].tolist(),
            "sigma_rotation_arcmin": (sd[:3] * ARCMIN_PER_RAD).tolist(), "sigma_t_mm": sd[3:].tolist()}
    bad_pairs = [k for k, p in pairs.items() if not p["ok"]]
    bad_loops = [k for k, lp in loops.items() if not lp["ok"]]
    doc = {"ok": not bad_pairs and not bad_loops and bool(loops), "pairs": pairs, "loops": loops}
    if not loops:
        doc["message"] = ("no loop of three cameras can be checked: some pair of cameras shares too few "
                          "instants to be calibrated alone, or the three pairs' instants are 6 or fewer")
    elif doc["ok"]:
        worst = max(loops.values(), key=lambda lp: lp["t2"])
        doc["message"] = (f"the cameras' pairwise relative poses agree: every pair fits one rigid relation and "
                          f"{len(loops)} loop(s) close within their sigmas (largest T^2 {worst['t2']:.1f}, "
                          f"limit {worst['limit']:.1f})")
    else:
        parts = []
        if bad_pairs:
            cams = [set(k.split("-")) for k in bad_pairs]
            common = set.intersection(*cams) if len(cams) > 1 else set()
            parts.append(f"the pair(s) {', '.join(bad_pairs)} do not fit one rigid relation"
                         + (f" (camera {', '.join(sorted(common))} in each: it moved between instants?)" if common else ""))
        for k in bad_loops:
            lp = loops[k]
            parts.append(f"loop {k} misses by {np.linalg.norm(lp['rotation_arcmin']):.2f}' and "
                         f"{np.linalg.norm(lp['t_mm']):.3f} mm (T^2 {lp['t2']:.0f}, limit {lp['limit']:.1f})")
        doc["message"] = ("; ".join(parts) + ": the rig's relative poses do not hold for every instant; "
                          "find the instants with rig_rigid, drop them with --exclude or shoot again")
    return doc
