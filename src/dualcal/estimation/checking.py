"""The checks stage of a calibration: every check of its result, each bad photo or instant named alone.

:func:`calibration_checks` runs every check of :mod:`dualcal.estimation.checks` on a calibration's final solution,
with ``focus`` and ``rig_rigid`` made by :func:`attribution_checks` (which names each refocused photo and each
instant that does not fit the rig alone, by taking the worst out and judging the others again), and in a rig of
three cameras or more the ``loop_closure`` check (:mod:`dualcal.estimation.loop_closure`) of its pairs.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .adjust import Solution
from .checks import (focal_scale_fits, focal_scale_sigmas, focus_drift, relation_shift_sigma, rig_rigid, run_checks,
                     tie_costs)
from ..errors import EstimationError
from .fitting import Setup, pair_solutions
from .loop_closure import loop_closure
from ..geometry.model import RigModel


def calibration_checks(setup: Setup, rig: RigModel, sol: Solution, flat: Solution, alone: Solution) -> dict:
    """Every check of ``rig`` (calib.json's ``checks``): ``sol`` its final solution, ``flat`` the same rig mode
    with a flat board and ``alone`` every camera alone, over the same photos; ``setup`` the calibration's."""
    checks = run_checks(rig, sol, flat, alone,
                        attribution=partial(attribution_checks, setup) if setup.mode != "none" else None)
    if setup.mode != "none":
        kappa2 = checks.get("rig_rigid", {}).get("design_effect")       # the rig's photo-level noise
        loop = loop_closure(setup.names, setup.reference, lambda x, y: pair_solutions(setup, flat, alone, x, y),
                            lambda tied, alone: rig_rigid(tied, alone, None if kappa2 is None else {0: kappa2}))
        if loop is not None:
            checks["loop_closure"] = loop
    return checks


def attribution_checks(setup: Setup, tied: Solution, alone: Solution, kappa2) -> tuple[dict, dict | None]:
    """The ``focus`` and ``rig_rigid`` checks (:mod:`dualcal.estimation.checks`) with every bad photo or instant named alone.

    A refocused photo or a desynchronised instant pulls the intrinsics and the shared relative pose, so
    the others fit worse too, and the statistics of one fit flag good photos beside the bad one. So the
    worst is named, taken out, and the others are judged by a fit without it (tied and alone solved
    again), until none is flagged, or a quarter of the instants are named (then the rig itself is not
    rigid or the focus drifts, and the last statistics say so). Refocused photos come first: a focal
    change that explains most of its instant's misfit (:func:`dualcal.estimation.checks.focus_drift`), the photo of
    the instant whose own focal scale is furthest off with its own pose (the alone fit; the tied fit
    cannot tell which camera of an instant refocused). Then the instants (:func:`dualcal.estimation.checks.rig_rigid`).
    """
    limit = max(1, len(tied.problem.views) // 4)
    blocks = list(tied.problem.blocks)
    named_photos: list[dict] = []
    while True:
        focus = focus_drift(tied, kappa2, tie_costs(tied, alone), named_photos)
        new = [f for f in focus["flagged"][len(named_photos):] if f["cause"] == "refocus"]
        if not new or len(named_photos) >= limit:
            break
        view = new[0]["view"]
        c = _refocused_camera(alone, view, kappa2)
        name = setup.names[c] if c is not None else new[0]["camera"]
        named_photos.append(next((f for f in focus["flagged"] if (f["camera"], f["view"]) == (name, view)),
                                 {**new[0], "camera": name}) | {"cause": "refocus"})
        c = setup.names.index(name)
        blocks = [b for b in blocks if (b[0], b[1]) != (c, view)]
        try:
            tied, alone = setup.solve(blocks, tied), setup.solve(blocks, alone, mode="none")
        except EstimationError:
            break
    doc = rig_rigid(tied, alone, kappa2)
    named: dict[str, dict] = {}
    while doc is not None and doc["flagged"][len(named):] and len(named) < limit:
        worst = doc["flagged"][len(named)]
        named[worst] = {"statistic": doc["instants"][worst], **doc["instant_f"][worst]}
        blocks = [b for b in blocks if b[1] != worst]
        try:
            before, (tied, alone) = tied, (setup.solve(blocks, tied), setup.solve(blocks, alone, mode="none"))
        except EstimationError:
            break
        named[worst]["shift_sigma"] = relation_shift_sigma(before, tied)      # what it alone moves
        shifts = [t["shift_sigma"] for t in named.values()]
        doc = rig_rigid(tied, alone, kappa2, named=named, shift_sigma=None if None in shifts else max(shifts))
    return focus, doc


def _refocused_camera(alone: Solution, view: str, kappa2) -> int | None:
    """Of the photos of ``view``, the camera whose own focal scale is furthest off with its own pose
    (:func:`dualcal.estimation.checks.focal_scale_fits` on the cameras-alone solution), in photo-level sigmas."""
    fits = focal_scale_fits(alone, {view})
    if not fits:
        return None
    z = [abs(focal_scale_sigmas(f, kappa2, alone.s0_px)) for f in fits]
    return fits[int(np.argmax(z))]["camera"]
