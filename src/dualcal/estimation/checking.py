"""The checks stage of a calibration: every check of its result, every bad photo or instant named.

:func:`calibration_checks` runs every check of :mod:`dualcal.estimation.checks` on a calibration's final solution,
with ``focus`` and ``rig_rigid`` made by :func:`attribution_checks` (which names every refocused photo and every
instant that does not fit the rig at once, each judged against a robust core of the others), in a rig of three
cameras or more the ``loop_closure`` check (:mod:`dualcal.estimation.loop_closure`) of its pairs from the joint and
the cameras-alone solutions, and where some cameras' intrinsics were known the ``intrinsics_prior`` check
(:func:`intrinsics_prior`).
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np

from .adjust import Solution
from .checks import FALSE_ALARM_RATE, MAX_FOCAL_REL, design_effect, focus_and_rigidity, run_checks
from .distributions import chi2_quantile, regularized_gamma, sidak
from ..errors import EstimationError
from .fitting import Setup
from ..geometry.camera import INTRINSIC_NAMES
from .loop_closure import loop_closure
from ..geometry.model import KnownIntrinsics, RigModel


def calibration_checks(setup: Setup, rig: RigModel, sol: Solution, flat: Solution, alone: Solution) -> dict:
    """Every check of ``rig`` (calib.json's ``checks``): ``sol`` its final solution, ``flat`` the same rig mode
    with a flat board and ``alone`` every camera alone, over the same photos; ``setup`` the calibration's."""
    checks = run_checks(rig, sol, flat, alone,
                        attribution=partial(attribution_checks, setup) if setup.mode != "none" else None)
    if setup.mode != "none":
        kappa2 = checks.get("rig_rigid", {}).get("design_effect")       # the rig's photo-level noise
        loop = loop_closure(flat, alone, kappa2)
        if loop is not None:
            checks["loop_closure"] = loop
    if setup.known:
        checks["intrinsics_prior"] = intrinsics_prior(setup, sol)
    return checks


#: The name of ``intrinsics_prior``'s test (calib.json ``checks.intrinsics_prior.test``).
PRIOR_TEST = ("chi-square test of each known camera's intrinsics from its photos alone against the known ones "
              "(Sidak over the cameras)")


def _photos_covariance(alone: Solution, names) -> tuple[list[str], np.ndarray]:
    """Of the intrinsics ``names``, those ``alone`` (one camera, from its photos alone) estimates, and their
    covariance in photo-level noise (the textbook one times the camera's design effect)."""
    lay = alone.problem.layout
    free = [str(n) for n in np.array(INTRINSIC_NAMES)[lay.free_intrinsics[0]]]
    names = [n for n in names if n in free]
    columns = lay.intrinsics[0][[free.index(n) for n in names]]
    return names, design_effect(alone)[0] * alone.covariance(columns, "formal")


def _against_known(alone: Solution, known: KnownIntrinsics, rate: float) -> dict:
    """One camera's test of :func:`intrinsics_prior`: ``alone`` its solution from its own photos alone."""
    names, C = _photos_covariance(alone, known.names or INTRINSIC_NAMES)
    d = np.array([getattr(alone.state.camera(alone.problem, 0), n) - getattr(known.camera, n) for n in names])
    if known.covariance is not None:
        at = [known.names.index(n) for n in names]
        C = C + np.asarray(known.covariance, float)[np.ix_(at, at)]
    t2 = float(d @ np.linalg.lstsq(C, d, rcond=None)[0])
    return {"t2": t2, "dof": len(names), "limit": chi2_quantile(len(names), 1.0 - rate),
            "p_value": 1.0 - regularized_gamma(0.5 * len(names), 0.5 * t2),
            "shift_sigma": {n: float(x / np.sqrt(C[i, i])) for i, (n, x) in enumerate(zip(names, d))}}


def _focal_sigma_rel(alone: Solution) -> float:
    """The 1-sigma of ``alone``'s (one camera) focal length fx relative to it, in photo-level noise (0 where fx is
    not estimated)."""
    names, C = _photos_covariance(alone, ["fx"])
    if not names:
        return 0.0
    return float(np.sqrt(max(C[0, 0], 0.0))) / alone.state.camera(alone.problem, 0).fx


def intrinsics_prior(setup: Setup, sol: Solution, rate: float = FALSE_ALARM_RATE) -> dict:
    """The ``intrinsics_prior`` check: whether each camera's photos agree with its known intrinsics.

    Each known camera is calibrated again from its own photos alone (its own pose in each, no rig: the other
    cameras cannot lend it their errors), started from ``sol``; the difference ``d`` of the intrinsics its known
    ones name (a fixed camera: all of its model's free ones) from the known values, with the covariance ``C`` of
    the photos' estimate (the textbook one in photo-level noise, times the camera's design effect, as the other
    checks judge: :func:`dualcal.estimation.checks.design_effect`; the clustered one is of too few instants here,
    often fewer than the intrinsics) plus the known covariance, gives ``T^2 = d^T C^-1 d``, about chi-square with
    as many degrees of freedom as intrinsics where the lens is the one known; the rate ``rate`` per calibration
    is split over the cameras by Sidak. A camera whose photos alone do not determine its intrinsics (a board small
    in every frame), or its focal length to :data:`dualcal.estimation.checks.MAX_FOCAL_REL` (what ``determination``
    asks of a result), is not judged: such photos cannot tell a refocus (about 1 %) from their noise, and the
    linear test of intrinsics they determine so weakly does not hold (on a synthetic session of four webcams whose
    board spans 50-90 px, focal lengths to 3-5 %, it failed with the true intrinsics held). A lens that changed (refocused, another zoom, a lens swapped) fails and is
    named, with the intrinsics that moved most in their sigmas.

    Returns ``{"ok", "message", "test", "statistic", "limit", "false_alarm_rate", "camera_rate", "worst",
    "flagged", "cameras": {camera: {"t2", "dof", "limit", "p_value", "shift_sigma": {intrinsic: sigmas}} or
    {"judged": False, "reason"}}}``.
    """
    each = sidak(rate, len(setup.known))
    cameras, flagged = {}, []
    for name, known in sorted(setup.known.items()):
        c = setup.names.index(name)
        own = replace(setup, names=[name], sizes=[setup.sizes[c]], reference=0, mode="none",
                      model=(setup.models[c],), known=None)
        try:
            alone = own.solve([(0, v, uv) for cc, v, uv in sol.problem.blocks if cc == c], sol,
                              board_shape=sol.problem.board_shape)
        except EstimationError as exc:
            cameras[name] = {"judged": False, "reason": f"its photos alone do not determine its intrinsics ({exc})"}
            continue
        weak = _focal_sigma_rel(alone)
        if weak > MAX_FOCAL_REL:
            cameras[name] = {"judged": False, "reason": f"its photos alone determine its focal length only to "
                                                        f"+-{100 * weak:.1f} % (more than {100 * MAX_FOCAL_REL:g} %)"}
            continue
        cameras[name] = _against_known(alone, known, each)
        if cameras[name]["t2"] > cameras[name]["limit"]:
            flagged.append(name)
    judged = {n: t for n, t in cameras.items() if "t2" in t}
    worst = max(judged, key=lambda n: judged[n]["t2"] / judged[n]["limit"], default=None)
    doc = {"test": PRIOR_TEST, "false_alarm_rate": rate, "camera_rate": each, "worst": worst,
           "statistic": judged[worst]["t2"] if worst else None, "limit": judged[worst]["limit"] if worst else None,
           "flagged": flagged, "cameras": cameras, "ok": not flagged}
    rate_words = f"false-alarm rate {100 * rate:g} % per calibration"
    if flagged:
        words = "; ".join(f"{n}: T^2 = {cameras[n]['t2']:.1f} (limit {cameras[n]['limit']:.1f}), "
                          + ", ".join(f"{k} {v:+.1f} sigma" for k, v in sorted(
                              cameras[n]["shift_sigma"].items(), key=lambda kv: -abs(kv[1]))[:3]) for n in flagged)
        doc["message"] = (f"the photos of {', '.join(flagged)} disagree with the intrinsics known for "
                          f"{'it' if len(flagged) == 1 else 'them'} ({words}): the lens changed since (refocused, "
                          f"another zoom, a lens or case moved), or the known intrinsics are another camera's; "
                          f"calibrate {'it' if len(flagged) == 1 else 'them'} again from its own photos ({rate_words})")
    elif worst:
        doc["message"] = (f"the photos agree with the known intrinsics: the worst, {worst}, T^2 = "
                          f"{judged[worst]['t2']:.1f} (limit {judged[worst]['limit']:.1f}; {rate_words})")
    else:
        doc["message"] = ("no known camera's photos determine its intrinsics alone: the known ones are taken as they "
                          "are, unchecked")
    not_judged = [n for n, t in cameras.items() if not t.get("judged", True)]
    if not_judged and (flagged or worst):
        doc["message"] += f"; not judged: {', '.join(not_judged)} (its photos alone do not determine its intrinsics)"
    return doc


def attribution_checks(setup: Setup, tied: Solution, alone: Solution, kappa2) -> tuple[dict, dict | None]:
    """The ``focus`` and ``rig_rigid`` checks (:func:`dualcal.estimation.checks.focus_and_rigidity`), every
    refocused photo and every instant that does not fit the rig named at once by tests against a robust core of
    the others; both solutions adjusted again once without what they name, to see how far it moves the rig."""
    return focus_and_rigidity(tied, alone, kappa2, refit=lambda blocks: (setup.solve(blocks, tied),
                                                                         setup.solve(blocks, alone, mode="none")))

