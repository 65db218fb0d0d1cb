"""Outliers: single corners far off their photo's fit, and photos (or instants) that do not fit at all.

A corner is an outlier when its residual is far above the typical residual of its camera
(:func:`outlier_limit_px`); it is left out (``dropped_corners``). A photo is dropped only when most of its
corners are outliers (:data:`MOST_CORNERS`: a moved board, a wrong numbering), and only where that really
improves the fit, with a recorded reason; in a tied rig, an instant whose photos fit their cameras alone but not
the rig is dropped whole (the cameras' shots disagree), or the photo whose own focal length explains the misfit
(a refocus). :func:`adjust_dropping_outliers` is the stage of the calibration (:mod:`dualcal.estimation.calibrate`)
that does this with every camera alone first, so that a bad photo shows in its own camera's residuals, then with
the rig tied.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .adjust import Solution
from .checking import _refocused_camera
from .checks import REFOCUS_SHARE, design_effect, focal_scale_fits
from .fitting import MIN_VIEWS, Setup, unusable_reason
from ..progress import warn

OUTLIER_FLOOR_PX = 0.05
#: A photo is dropped when more than this share of its corners are outliers.
MOST_CORNERS = 0.5


def outlier_limit_px(camera_median_px: float, factor: float) -> float:
    """Residual above which a corner is an outlier: ``factor`` x the median length of its camera's
    corner residuals (cameras differ in noise), but never below :data:`OUTLIER_FLOOR_PX`. For
    independent equal errors the median length is 1.18 sigma, so the default factor 6 puts the
    limit at 7 sigma: corner errors on real photos have long tails (a board's own defects, blur),
    and only gross errors (a corner on the wrong feature) are meant; on the real sets a limit of
    4 medians took out corners whose error the photos share, and the sigmas of k suffered. The
    report uses it too."""
    return max(factor * camera_median_px, OUTLIER_FLOOR_PX)


def corner_outliers(sol: Solution, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Which measured corners are outliers: ``(B, N)`` bool, and each photo's limit (B,) px."""
    length = np.linalg.norm(sol.residuals, axis=2)                       # (B, N), NaN where not measured
    cams = np.array([c for c, _, _ in sol.problem.blocks])
    limit = np.empty(len(cams))
    for c in np.unique(cams):
        limit[cams == c] = outlier_limit_px(float(np.nanmedian(length[cams == c])), factor)
    with np.errstate(invalid="ignore"):
        return length > limit[:, None], limit


def outlier_shares(sol: Solution, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Each photo's share of outlier corners (B,) and its limit (B,) px (:func:`corner_outliers`)."""
    out, limit = corner_outliers(sol, factor)
    return out.sum(axis=1) / np.maximum(np.isfinite(sol.residuals[..., 0]).sum(axis=1), 1), limit


def find_outlier(shares: np.ndarray, limits: np.ndarray):
    """The photo with the largest share of outlier corners (:func:`outlier_shares`), if more than
    :data:`MOST_CORNERS` of them are, as ``(block, share, limit_px)``; else None."""
    worst = int(np.argmax(shares))
    if shares[worst] <= MOST_CORNERS:
        return None
    return worst, float(shares[worst]), float(limits[worst])


def _views_left(blocks, c: int) -> int:
    return sum(1 for blk in blocks if blk[0] == c)


MAX_CORNER_ROUNDS = 5


@dataclass(frozen=True)
class _Round:
    """What one round of :func:`adjust_dropping_outliers` adjusts: each of ``trials`` (lists of photos, the one
    that fits best is kept) from ``start``; with ``improve``, kept only where it fits better than the solution
    before (else ``kept``, a warning, is said where given); ``record(before, after, trial)`` records and says
    what was left out."""

    trials: list[list]
    start: Solution | None = None
    improve: bool = False
    kept: str | None = None
    record: Callable[[Solution, Solution, int], None] | None = None


def adjust_dropping_outliers(setup: Setup, blocks, factor, dropped, dropped_corners, start=None):
    """Solve, drop outlier photos and then outlier corners while there are any, solve again;
    returns ``(solution, blocks)``.

    Each round decides what to leave out of the current solution (:func:`_next_round`) and adjusts the
    photos without it, the one adjustment of the stage: a photo, an instant or a refocused photo from a
    fresh start (the solution with the bad photo in it may be far off), kept only where the fit then really
    improves; outlier corners from the solution, a round at a time (at most :data:`MAX_CORNER_ROUNDS`), as
    the limit is recomputed. In a tied rig a bad photo pulls the shared pose and so spreads its error over
    every photo of that instant; of the photos of the flagged instant whose corners are mostly outliers,
    the one whose removal fits best is dropped.
    """
    alone_share = {}
    if factor and setup.mode != "none" and start is not None:
        alone_share = dict(zip([(c, v) for c, v, _ in start.problem.blocks], outlier_shares(start, factor)[0]))
    sol, corner_rounds = None, 0
    step: _Round | None = _Round([blocks], start)
    while step is not None:
        trials = [setup.solve(trial, step.start) for trial in step.trials]
        best = min(range(len(trials)), key=lambda i: trials[i].s0_px)
        if step.improve and trials[best].s0_px >= sol.s0_px:
            if step.kept:
                warn(step.kept)
            break
        if step.record is not None:
            step.record(sol, trials[best], best)
        sol, blocks = trials[best], step.trials[best]
        if not factor:
            break
        step = _next_round(setup, sol, blocks, start, factor, alone_share, dropped, dropped_corners,
                           corner_rounds < MAX_CORNER_ROUNDS)
        corner_rounds += step is not None and not step.improve
    return sol, blocks


def _next_round(setup: Setup, sol: Solution, blocks, alone: Solution | None, factor: float, alone_share: dict,
                dropped: list, dropped_corners: list, corners_too: bool) -> _Round | None:
    """What to leave out of ``sol`` next (:func:`adjust_dropping_outliers`): the photo (or the instant, or the
    refocused photo of an instant) most of whose corners are outliers; else, where ``corners_too``, the outlier
    corners; None where there is nothing to leave out, or it cannot be (a warning says why)."""
    names = setup.names
    shares, limits = outlier_shares(sol, factor)
    out = find_outlier(shares, limits)
    if out is None:
        bad, limit = corner_outliers(sol, factor)
        if not bad.any() or not corners_too:
            return None
        return _Round([_without_corners(setup, sol, blocks, bad, limit, dropped, dropped_corners)], sol)
    b, share, limit = out
    view = blocks[b][1]
    instant = _instant_misfit(setup, sol, alone, blocks, view, alone_share)
    if instant == "instant":
        return _without_instant(setup, alone, blocks, view, dropped)
    if instant is not None:
        candidates = instant                      # the refocused photo(s) of the instant
    else:
        candidates = [b] if setup.mode == "none" else [i for i, blk in enumerate(blocks) if blk[1] == view]
    candidates = [i for i in candidates if _views_left(blocks, blocks[i][0]) > MIN_VIEWS]
    if setup.mode != "none" and instant is None:
        candidates = [i for i in candidates if shares[i] > MOST_CORNERS]
    photo = f"{names[blocks[b][0]]}/{view}: {share:.0%} of its corners are outliers (limit {limit:.3g} px)"
    if not candidates:
        warn(f"{photo} but it cannot be dropped: only {MIN_VIEWS} views left for {names[blocks[b][0]]!r}")
        return None

    def record(before: Solution, after: Solution, trial: int):
        i = candidates[trial]
        c, rms_i = blocks[i][0], before.block_rms_px[i]
        if instant is not None:
            reason = (f"it fits {names[c]!r} alone, but tied to the rig only with a focal length of its own: the "
                      f"phone refocused or zoomed between the shots of {view} (photo RMS {rms_i:.3g} px in rig mode "
                      f"{setup.mode}; without it s0 falls from {before.s0_px:.3g} to {after.s0_px:.3g} px); lock focus")
        else:
            reason = (f"{share:.0%} of its corners are outliers (residual above {limit:.3g} px, {factor:g} x the "
                      f"median of {names[c]!r}; photo RMS {rms_i:.3g} px) in rig mode {setup.mode}; without it s0 "
                      f"falls from {before.s0_px:.3g} to {after.s0_px:.3g} px (moved board, wrong corner order, blur, "
                      "or another zoom/focus setting?)")
        warn(f"dropping {names[c]}/{view}: {reason}")
        dropped.append({"camera": names[c], "view": view, "rms_px": rms_i, "reason": reason})

    return _Round([blocks[:i] + blocks[i + 1:] for i in candidates], improve=True,
                  kept=f"{photo} but dropping the photo does not improve the fit: kept", record=record)


def _instant_misfit(setup: Setup, sol: Solution, alone: Solution | None, blocks, view: str, alone_share: dict):
    """Why the photos of ``view`` do not fit the rig when every one of them fits its camera alone
    (``alone_share``: each photo's share of outlier corners with every camera alone): ``"instant"``
    when the cameras' shots disagree, or the blocks of the photo(s) whose own focal length explains
    the misfit (a refocus, :data:`dualcal.estimation.checks.REFOCUS_SHARE`); None when a photo is an outlier
    alone (a bad photo, judged photo by photo) or the instant has one camera."""
    instant = [i for i, blk in enumerate(blocks) if blk[1] == view]
    if alone is None or len({blocks[i][0] for i in instant}) < 2:
        return None
    if any(alone_share.get((blocks[i][0], view), 1.0) > MOST_CORNERS for i in instant):
        return None
    alone_cost = {(c, v): float(np.nansum(r ** 2)) for (c, v, _), r in zip(alone.problem.blocks, alone.residuals)}
    tie = sum(float(np.nansum(sol.residuals[i] ** 2)) - alone_cost.get((blocks[i][0], view), 0.0) for i in instant)
    if not any(tie > 0 and f["explained_px2"] >= REFOCUS_SHARE * tie for f in focal_scale_fits(sol, {view})):
        return "instant"
    c = _refocused_camera(alone, view, design_effect(alone))
    return [i for i in instant if blocks[i][0] == c] or "instant"


def _without_instant(setup: Setup, alone: Solution, blocks, view: str, dropped) -> _Round | None:
    """The round without every photo of ``view`` (an instant whose photos fit their cameras alone but not the
    rig), each recorded in ``dropped`` with the reason where that improves the fit; None where that leaves a
    camera too few views (a warning says so)."""
    names = setup.names
    instant = [i for i, blk in enumerate(blocks) if blk[1] == view]
    rest = [blk for i, blk in enumerate(blocks) if i not in instant]
    short = [names[blocks[i][0]] for i in instant if _views_left(rest, blocks[i][0]) < MIN_VIEWS]
    if short:
        warn(f"instant {view} does not fit the rig, but it cannot be dropped: only {MIN_VIEWS} views left for "
             f"{short[0]!r}")
        return None

    def record(before: Solution, after: Solution, _trial: int):
        alone_rms = {(c, v): r for (c, v, _), r in zip(alone.problem.blocks, alone.block_rms_px)}
        cams = [names[blocks[i][0]] for i in instant]
        fits = ", ".join(f"{names[blocks[i][0]]} {alone_rms.get((blocks[i][0], view), float('nan')):.3g} px"
                         for i in instant)
        tied = ", ".join(f"{names[blocks[i][0]]} {before.block_rms_px[i]:.3g} px" for i in instant)
        reason = (f"instant {view}: its photos fit their cameras alone (RMS {fits}) but not one relative pose of the "
                  f"rig (RMS {tied} in rig mode {setup.mode}; without the instant s0 falls from {before.s0_px:.3g} to "
                  f"{after.s0_px:.3g} px): the cameras' shots disagree (not taken at the same instant, or a lens or "
                  "the board moved between them)")
        warn(f"dropping {' and '.join(f'{c}/{view}' for c in cams)}: {reason}")
        for i in instant:
            dropped.append({"camera": names[blocks[i][0]], "view": view, "rms_px": before.block_rms_px[i],
                            "reason": reason, "instant": True})

    return _Round([rest], improve=True, record=record)


def _without_corners(setup: Setup, sol: Solution, blocks, bad, limit, dropped, dropped_corners):
    """``blocks`` with the outlier corners ``bad`` (B, N) set to NaN, each recorded; a photo left
    unable to fix a homography is dropped, with the reason."""
    out = []
    length = np.linalg.norm(sol.residuals, axis=2)
    for b, (c, v, uv) in enumerate(blocks):
        if not bad[b].any():
            out.append((c, v, uv))
            continue
        for k in np.flatnonzero(bad[b]):
            dropped_corners.append({"camera": setup.names[c], "view": v, "corner": int(k),
                                    "residual_px": float(length[b, k]), "limit_px": float(limit[b])})
        uv = np.array(uv, float)
        uv[bad[b]] = np.nan
        reason = unusable_reason(uv, setup.X_board[:, :2])
        if reason and _views_left(out, c) + _views_left(blocks[b + 1:], c) >= MIN_VIEWS:
            reason = f"without its {int(bad[b].sum())} outlier corner(s) {reason}"
            warn(f"dropping {setup.names[c]}/{v}: {reason}")
            dropped.append({"camera": setup.names[c], "view": v, "rms_px": sol.block_rms_px[b], "reason": reason})
            continue
        out.append((c, v, uv if reason is None else blocks[b][2]))
    return out
