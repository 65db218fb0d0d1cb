"""The stabiliser's shift of every photo (optical image stabilisation, OIS) as a random effect of the adjustment.

A hand-held phone's stabiliser moves each lens sideways for every shot, so each photo's principal point is shifted
by its own ``delta`` (px), the wide's and the tele's independently. With every camera alone a shift is nearly a
turn of the camera (``delta / f`` rad), taken up by the photo's pose; tied in a rig it is not: the relative angle
between the cameras seen in one instant moves by about ``delta / f`` (3 px at ``f`` = 6000 px: 1.7 arcmin), more
than the rig's angles' sigma, and the rig seems not rigid. :mod:`dualcal.estimation.adjust` (``ois``) gives each
photo its shift, with a prior ``delta ~ N(0, sigma_c^2)`` per coordinate for camera ``c``: a random effect, whose
spread ``sigma_c`` is estimated here, from how the instants disagree.

**Whether the photos show one** (:func:`ois_test`), for the cameras that may have a stabiliser (:func:`may_stabilise`:
those whose EXIF gives a focal length; in data without EXIF a shift is not told from a desynchronised shot's
jitter, which ``rig_rigid`` is to name). From the rig tied without shifts (its outliers left out), every
photo's shift is estimated in one Gauss-Newton step with a prior too weak to matter (``sigma`` :data:`FREE_SPREAD`
times the noise: the shifts as fixed effects, kept apart from the pose only where the data tell them apart).
Each instant's chi-square ``q_v = delta_v^T Cov(delta_v)^-1 delta_v`` (the cost its shifts take away, in units of
the noise) has ``k_v`` degrees of freedom under no stabiliser, ``k_v`` its shifts' share of the redundancy
(Foerstner's ``r``, below; nearly 2 per photo). An instant whose ``q_v`` is far beyond the others' is one whose
shots disagree (a desynchronised shot: ``rig_rigid``'s to name), and is left out of the test. In units of the
photo-level noise (``kappa^2 s0^2``, the design effect of :func:`dualcal.estimation.checks.design_effect`, as
``rig_rigid`` measures it) ``sum q_v / (kappa^2 sum k_v)`` is compared with ``F(sum k_v, G - 1)`` at
:data:`dualcal.estimation.checks.FALSE_ALARM_RATE`. A rig whose shots are synchronised and whose lenses do not
shift passes, and keeps the calibration it had (no shift modelled).

**Its spread** (:func:`ois_spread`): variance components, the iteration of Foerstner (1979, "Ein Verfahren zur
Schaetzung von Varianz- und Kovarianzkomponenten"; Koch, *Parameter Estimation and Hypothesis Testing in Linear
Models*, variance components), which converges to the REML estimate: with the photos' shifts ``delta_i`` estimated under the prior
of spread ``sigma_c``, and ``r_c = sum_i (1 - p_c [N^-1]_ii)`` the redundancy of the prior's rows of camera ``c``
(``p_c = (scale / sigma_c)^2`` their weight, ``N`` the normal matrix), the new spread is
``sigma_c^2 = sum_i delta_i^2 / r_c``, until they settle. The noise ``scale`` the prior is weighed against is the
photo-level noise of a photo of weight 1, ``kappa s0`` (the cameras alone): a photo's corner errors that move
together (blur, a board not flat, the lens model's misfit) would otherwise pass for a shift of its own. A camera
whose shifts the data cannot tell from its pose (``r_c`` below 1), or whose spread falls below :data:`MIN_SPREAD`
of the noise, is given none (0).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .adjust import OisPrior, Solution
from .checks import FALSE_ALARM_RATE, T_DOF_SHARE, design_effect
from .distributions import f_quantile, sidak
from .robust_tests import core_tests, cube_root_spread, robust_core
from ..errors import EstimationError
from .fitting import Setup
from ..geometry.model import CornerSet

__all__ = ["FREE_SPREAD", "MIN_SPREAD", "may_stabilise", "ois_spread", "ois_test", "with_ois"]

#: The spread of the prior under which the test estimates every shift, in units of the noise: far beyond any
#: stabiliser's, so that the shifts are fixed effects wherever the data determine them.
FREE_SPREAD = 100.0
#: A camera whose shifts' spread falls below this share of the noise of a photo of weight 1 is given none.
MIN_SPREAD = 0.05
#: The iteration of the spreads stops when none changes by more than this share of its standard error
#: (``sigma_c / sqrt(2 r_c)``: a spread from ``r_c`` degrees of freedom), or after :data:`MAX_ROUNDS`.
SPREAD_TOLERANCE = 0.1
MAX_ROUNDS = 30

#: The name of the test (calib.json ``adjustment.lens_motion.ois.test``).
OIS_TEST = ("F test of the photos' principal-point shifts (their joint chi-square over its degrees of freedom) "
            "against the photo-level noise")


def _shift_columns(sol: Solution, camera: int) -> np.ndarray:
    """The flat columns of camera ``camera``'s photos' shifts in ``sol``, instant by instant (u, v)."""
    lay = sol.problem.layout
    slots = lay.ois[camera]
    return np.concatenate([lay.local_columns(v, slots) for v in np.flatnonzero(lay.local_used[:, slots[0]])])


def _redundancy_shares(sol: Solution) -> dict[int, float]:
    """``{camera: r_c}``: the redundancy of each camera's shifts' prior rows, ``sum (1 - p_c [N^-1]_ii)``."""
    p = sol.problem
    return {c: float(np.sum(1.0 - p.ois.information(p.cameras[c]) * np.diag(
        sol.factorization.inverse_block(_shift_columns(sol, c))))) for c in p.layout.ois}


def _free_shifts(setup: Setup, tied: Solution, scale: float, cameras) -> Solution:
    """``tied`` (a rig without shifts) linearised with every photo of ``cameras`` shifted, free under a prior too
    weak to matter (:data:`FREE_SPREAD` times ``scale``)."""
    free = replace(setup, ois=OisPrior(dict.fromkeys(cameras, FREE_SPREAD * scale), scale))
    return free.linearised(tied, tied.problem.board_shape)


def _instant_scores(tied: Solution, free: Solution, scale: float) -> tuple[dict[str, float], dict[str, float]]:
    """Each instant's score test of its photos' shifts, the others' held at none: ``{view: q_v}`` (in units of
    ``scale``) and ``{view: k_v}`` its degrees of freedom. With the instant's shifts' gradient ``g`` and their
    information given everything ``tied`` estimates, ``I = N_dd - N_dt N_tt^-1 N_td`` (``N_tt^-1`` ``tied``'s,
    over the globals and the instant's own unknowns), ``q_v = g^T (I + P)^-1 g`` and ``k_v = tr((I + P)^-1 I)``
    (``P`` the weak prior)."""
    lay, lay0, ne = free.problem.layout, tied.problem.layout, free.factorization.ne
    G = lay.n_global
    q, k = {}, {}
    for v, view in enumerate(free.problem.views):
        shifts = np.concatenate([slots for slots in lay.ois.values() if lay.local_used[v, slots[0]]])
        own = np.flatnonzero(lay0.local_used[v])
        cross = np.hstack([ne.gl[v][:, shifts].T, ne.ll[v][np.ix_(shifts, own)]])
        inverse = tied.factorization.inverse_block(np.concatenate([np.arange(G), lay0.local_columns(v, own)]))
        prior = np.eye(len(shifts)) / FREE_SPREAD ** 2
        information = ne.ll[v][np.ix_(shifts, shifts)] - prior - cross @ inverse @ cross.T
        g = ne.grad_l[v][shifts]
        q[view] = float(g @ np.linalg.solve(information + prior, g)) / scale ** 2
        k[view] = float(np.trace(np.linalg.solve(information + prior, information)))
    return q, k


def _joint_statistic(free: Solution, scale: float) -> tuple[float, float, dict[str, float]]:
    """Every photo's shift estimated at once: their joint chi-square ``Q`` (in units of ``scale``), its degrees of
    freedom (the shifts' prior rows' redundancy) and each camera's shifts' RMS, px."""
    p, lay, step = free.problem, free.problem.layout, free.factorization.step()
    cols = np.concatenate([_shift_columns(free, c) for c in lay.ois])
    inverse = free.factorization.inverse_block(cols)
    q = float(step[cols] @ np.linalg.solve(inverse, step[cols])) / scale ** 2
    dof = float(np.sum(1.0 - np.diag(inverse) / FREE_SPREAD ** 2))
    return q, dof, {p.cameras[c]: float(np.sqrt(np.mean(step[_shift_columns(free, c)] ** 2))) for c in lay.ois}


def may_stabilise(corners: CornerSet) -> tuple[str, ...]:
    """The cameras whose photos may carry a stabiliser's shift: those whose EXIF gives a focal length (corners.json's
    ``meta["exif"]["focal_length_mm"]``: a phone's, a compact's or a stabilised lens's photos). A camera without
    (a webcam, a machine-vision camera, photos whose EXIF was stripped) is taken as one whose lens holds still: its
    rig's instants that do not fit one relative pose are ``rig_rigid``'s to judge, not a stabiliser's to explain."""
    return tuple(name for name, cc in corners.cameras.items() if cc.focal_length_mm is not None)


def _worst_instant(q: dict[str, float], k: dict[str, float], rate: float) -> str | None:
    """The instant whose score ``q_v`` (chi-square of ``k_v`` degrees of freedom) fits worst among those that fail
    their test against a robust core of the others at ``rate`` (:mod:`dualcal.estimation.robust_tests`: the cube
    roots of ``q_v / k_v``, as ``rig_rigid`` judges its tie costs), or None where none fails."""
    views = list(q)
    dofs = np.array([max(k[v], 1e-9) for v in views])
    x = np.cbrt(np.array([q[v] for v in views]) / dofs)
    r = cube_root_spread(dofs)
    tests = core_tests(x, r, robust_core(x, r, rate, T_DOF_SHARE), False, T_DOF_SHARE)
    failing = [(t.t, v) for v, t in zip(views, tests) if t is not None and t.p < rate]
    return max(failing)[1] if failing else None


def ois_test(setup: Setup, tied: Solution, alone: Solution, cameras=None,
             rate: float = FALSE_ALARM_RATE) -> dict | None:
    """Whether the photos of ``tied`` (a rig without shifts; ``alone`` every camera alone over the same photos) show
    the stabiliser's shifts in the ``cameras`` named (default: all); None for a rig of one camera or mode ``none``,
    or where no camera of it is named.

    A stabiliser shifts every photo; an instant whose shots disagree (not synchronised, the board moved) is one
    instant, and pulls the rig's relative pose, so that the others seem shifted too. So, as ``rig_rigid`` names
    them (:func:`_worst_instant`: each instant's ``q_v`` against a robust core of the others, the rate split over
    the instants), the worst instant that fits far worse than the others is left out and the others
    judged from a fit without it, until none is (at most a quarter of the instants): those are the rig check's to
    judge, and the stabiliser's spread is estimated without them.

    Returns ``{"test", "cameras" (those judged), "statistic" (Q / (kappa^2 k)), "limit", "dof" (k), "design_effect"
    (kappa^2), "significant", "false_alarm_rate", "left_out": [views], "spread_px": {camera: the shifts' RMS, px}}``
    (the spreads' start: above them, as the shifts' estimates hold their noise too).
    """
    p = tied.problem
    cameras = [n for n in p.cameras if cameras is None or n in cameras]
    if p.mode == "none" or len(p.cameras) < 2 or not cameras:
        return None
    scale = max(alone.s0_px, 1e-9)       # the noise: tied without shifts, the rig's misfit would count in it
    each = sidak(rate, len(p.views) + 1)
    left_out = []
    try:
        while True:
            free = _free_shifts(setup, tied, scale, cameras)
            q, k = _instant_scores(tied, free, scale)
            worst = _worst_instant(q, k, each)
            if worst is None or len(left_out) >= len(p.views) // 4:
                break
            left_out.append(worst)
            tied = setup.solve([b for b in tied.problem.blocks if b[1] != worst], tied, board_shape=p.board_shape)
        statistic, dof, rms = _joint_statistic(free, scale)
    except (np.linalg.LinAlgError, EstimationError):
        return None
    kappa2 = max(design_effect(alone).values())
    limit = f_quantile(dof, max(len(tied.problem.views) - 1, 1), 1.0 - rate)
    ratio = statistic / (kappa2 * dof)
    return {"test": OIS_TEST, "cameras": cameras, "statistic": ratio, "limit": limit, "dof": dof,
            "design_effect": kappa2, "significant": bool(ratio > limit), "false_alarm_rate": rate,
            "left_out": left_out, "spread_px": rms}


def ois_spread(setup: Setup, tied: Solution) -> tuple[Setup, dict]:
    """Each camera's spread of the stabiliser's shifts by variance components (module docstring), from ``tied`` (a
    rig adjusted under ``setup``'s prior, the spreads' start): ``setup`` with the prior (none where no camera keeps
    a spread) and the record ``{"sigma_px": {camera: px}, "scale_px", "redundancy": {camera: r_c}, "rounds",
    "settled"}``."""
    blocks, shape = tied.problem.blocks, tied.problem.board_shape
    sigma, scale = dict(setup.ois.sigma_px), setup.ois.scale_px
    sol, shares, settled, rounds = tied, {}, False, 0
    while sigma and not settled and rounds < MAX_ROUNDS:
        rounds += 1
        trial = replace(setup, ois=OisPrior(dict(sigma), scale))
        try:
            sol = trial.solve(blocks, sol, board_shape=shape)
        except EstimationError:
            break
        p = sol.problem
        shares = {p.cameras[c]: r for c, r in _redundancy_shares(sol).items()}
        new = {}
        for c in p.layout.ois:
            name = p.cameras[c]
            squares = sum(float(np.sum(sol.state.ois_px[p.view_index[v], c] ** 2)) for cc, v, _ in p.blocks if cc == c)
            if shares[name] >= 1.0:
                new[name] = np.sqrt(squares / shares[name])
        kept = {n: s for n, s in new.items() if s >= MIN_SPREAD * scale}
        settled = set(kept) == set(sigma) and all(
            abs(kept[n] - sigma[n]) <= SPREAD_TOLERANCE * kept[n] / np.sqrt(2.0 * shares[n]) for n in kept)
        sigma = kept
    record = {"sigma_px": {n: float(sigma.get(n, 0.0)) for n in setup.names}, "scale_px": scale,
              "redundancy": shares, "rounds": rounds, "settled": settled}
    return replace(setup, ois=OisPrior(dict(sigma), scale) if sigma else None), record


def with_ois(setup: Setup, tied: Solution, alone: Solution, cameras=None) -> tuple[Setup, dict | None]:
    """``setup`` with the stabiliser's shifts of the ``cameras`` named (default: all; :func:`may_stabilise`) where the
    photos show them (:func:`ois_test`), their spreads at their start (the shifts' RMS, above the spreads:
    :func:`ois_spread` estimates them from a fit under this prior, without the instants the test left out), and the
    test's record (calib.json ``adjustment.lens_motion.ois``; None where not judged)."""
    test = ois_test(setup, tied, alone, cameras)
    if test is None or not test["significant"]:
        return setup, test
    scale = float(np.sqrt(test["design_effect"])) * alone.s0_px
    return replace(setup, ois=OisPrior({n: max(s, 2 * MIN_SPREAD * scale) for n, s in test["spread_px"].items()},
                                       scale)), test
