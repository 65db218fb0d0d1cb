"""The stabiliser's shift of every photo (optical image stabilisation, OIS) as a random effect of the adjustment.

A hand-held phone's stabiliser moves each lens sideways for every shot, so each photo's principal point is shifted
by its own ``delta`` (px), the wide's and the tele's independently. With every camera alone a shift is nearly a
turn of the camera (``delta / f`` rad), taken up by the photo's pose; tied in a rig it is not: the relative angle
between the cameras seen in one instant moves by about ``delta / f`` (3 px at ``f`` = 6000 px: 1.7 arcmin), more
than the rig's angles' sigma, and the rig seems not rigid. :mod:`dualcal.estimation.adjust` (``ois``) gives each
photo its shift, with a prior ``delta ~ N(0, sigma_c^2)`` per coordinate for camera ``c``: a random effect, whose
spread ``sigma_c`` is estimated here, from how the instants disagree.

**Whether the photos show one** (:func:`ois_test`). From the rig tied without shifts (its outliers left out), every
photo's shift is estimated in one Gauss-Newton step with a prior too weak to matter (``sigma`` :data:`FREE_SPREAD`
times the noise: the shifts as fixed effects, kept apart from the pose only where the data tell them apart).
Their joint chi-square ``Q = delta^T Cov(delta)^-1 delta`` (the cost they take away, in units of the noise) has
``k`` degrees of freedom under no stabiliser, ``k`` the shifts' share of the redundancy (Foerstner's ``r``, below;
nearly 2 per photo); in units of the photo-level noise (``kappa^2 s0^2``, the design effect of
:func:`dualcal.estimation.checks.design_effect`, as ``rig_rigid`` measures it) ``Q / (kappa^2 k)`` is compared with
``F(k, G - 1)`` at :data:`dualcal.estimation.checks.FALSE_ALARM_RATE`. A rig whose shots are synchronised and whose
lenses do not shift passes, and keeps the calibration it had (no shift modelled).

**Its spread** (:func:`ois_spread`): variance components, the iteration of Foerstner (1979, "Ein Verfahren zur
Schaetzung von Varianz- und Kovarianzkomponenten"; Koch, *Parameter Estimation and Hypothesis Testing in Linear
Models*, 3.6), which converges to the REML estimate: with the photos' shifts ``delta_i`` estimated under the prior
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
from .checks import FALSE_ALARM_RATE, design_effect
from .distributions import f_quantile
from ..errors import EstimationError
from .fitting import Setup

__all__ = ["FREE_SPREAD", "MIN_SPREAD", "ois_spread", "ois_test", "with_ois"]

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


def ois_test(setup: Setup, tied: Solution, alone: Solution, rate: float = FALSE_ALARM_RATE) -> dict | None:
    """Whether the photos of ``tied`` (a rig without shifts; ``alone`` every camera alone over the same photos) show
    the stabiliser's shifts (module docstring); None for a rig of one camera or mode ``none``.

    Returns ``{"test", "statistic" (Q / (kappa^2 k)), "limit", "dof" (k), "design_effect" (kappa^2), "significant",
    "false_alarm_rate", "spread_px": {camera: the shifts' RMS, px}}`` (the spreads' start: above them, as the
    shifts' estimates hold their noise too).
    """
    p = tied.problem
    if p.mode == "none" or len(p.cameras) < 2:
        return None
    scale = max(alone.s0_px, 1e-9)       # the noise: tied without shifts, the rig's misfit would count in it
    free = replace(setup, ois=OisPrior(dict.fromkeys(p.cameras, FREE_SPREAD * scale), scale))
    lin = free.linearised(tied, p.board_shape)
    step = lin.factorization.step()
    cols = np.concatenate([_shift_columns(lin, c) for c in lin.problem.layout.ois])
    inverse = lin.factorization.inverse_block(cols)
    delta = step[cols]
    try:
        q = float(delta @ np.linalg.solve(inverse, delta)) / scale ** 2
    except np.linalg.LinAlgError:
        return None
    shares = _redundancy_shares(lin)
    dof = float(sum(shares.values()))
    kappa2 = max(design_effect(alone).values())
    views = len(p.views)
    limit = f_quantile(dof, max(views - 1, 1), 1.0 - rate)
    ratio = q / (kappa2 * dof)
    spread = {p.cameras[c]: float(np.sqrt(np.mean(step[_shift_columns(lin, c)] ** 2))) for c in lin.problem.layout.ois}
    return {"test": OIS_TEST, "statistic": ratio, "limit": limit, "dof": dof, "design_effect": kappa2,
            "significant": bool(ratio > limit), "false_alarm_rate": rate, "spread_px": spread}


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


def with_ois(setup: Setup, tied: Solution, alone: Solution) -> tuple[Setup, dict | None]:
    """``setup`` with the stabiliser's shifts where the photos show them (:func:`ois_test`), their spreads at their
    start (the shifts' RMS, above the spreads: :func:`ois_spread` estimates them from a fit under this prior), and
    the test's record (calib.json ``adjustment.lens_motion.ois``; None where not judged)."""
    test = ois_test(setup, tied, alone)
    if test is None or not test["significant"]:
        return setup, test
    scale = float(np.sqrt(test["design_effect"])) * alone.s0_px
    return replace(setup, ois=OisPrior({n: max(s, 2 * MIN_SPREAD * scale) for n, s in test["spread_px"].items()},
                                       scale)), test
