"""Outliers: single corners far off their photo's fit, and photos (or instants) that do not fit at all.

A corner is an outlier when its residual is far above its photo's own noise (:func:`outlier_limit_px` of
:data:`dualcal.estimation.photo_noise.MEDIAN_LENGTH` times the photo's noise, estimated with every camera alone:
:mod:`dualcal.estimation.photo_noise`), so that a blurred photo keeps its corners; it is left out
(``dropped_corners``). (Without the photos weighed by their noise, the limit is that of the typical residual of
the photo's camera.) A photo is dropped only for a gross misfit: its median residual beyond a tenth of its squares
(another numbering, another board), or most of its corners outliers against its own noise (:data:`MOST_CORNERS`: a board
moved between the shots of an instant), and only where that really improves the fit, with a recorded reason; in
a tied rig, an instant whose photos fit their cameras alone but not the rig is dropped whole (the cameras' shots
disagree), or the photo whose own focal length explains the misfit (a refocus).
:func:`adjust_dropping_outliers` is the stage of the calibration (:mod:`dualcal.estimation.calibrate`) that does
this with every camera alone first, so that a bad photo shows in its own camera's residuals and each photo's
noise is its own corners', then with the rig tied.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .adjust import Solution
from .checks import REFOCUS_SHARE, design_effect, focal_scale_fits, refocused_camera
from .fitting import MIN_VIEWS, Setup, unusable_reason
from .photo_noise import MEDIAN_LENGTH, PhotoNoise, photo_noise, rough_residuals
from ..progress import warn

OUTLIER_FLOOR_PX = 0.05
#: A photo is dropped when more than this share of its corners are outliers.
MOST_CORNERS = 0.5


def outlier_limit_px(median_px: float, factor: float) -> float:
    """Residual above which a corner is an outlier: ``factor`` x the median length of a corner residual
    (``median_px``: its photo's in its own noise, :data:`dualcal.estimation.photo_noise.MEDIAN_LENGTH` sigma; or
    its camera's), but never below :data:`OUTLIER_FLOOR_PX`. For independent equal errors the median length is
    1.18 sigma, so the default factor 6 puts the limit at 7 sigma: corner errors on real photos have long tails
    (a board's own defects, blur), and only gross errors (a corner on the wrong feature) are meant; on the real
    sets a limit of 4 medians took out corners whose error the photos share, and the sigmas of k suffered. The
    report uses it too."""
    return max(factor * median_px, OUTLIER_FLOOR_PX)


def corner_outliers(sol: Solution, factor: float, noise: PhotoNoise | None = None,
                    lengths: np.ndarray | None = None):
    """Which measured corners are outliers: ``(B, N)`` bool, each photo's limit (B,) px and the residual lengths
    judged (B, N) px: ``lengths`` (with every camera alone, the rough residuals':
    :func:`dualcal.estimation.photo_noise.rough_residuals`), or the residuals', against its own ``noise``
    (:func:`dualcal.estimation.photo_noise.photo_noise`), or, without it (or for a photo it has not), against its
    camera's median residual."""
    p = sol.problem
    length = np.linalg.norm(sol.residuals, axis=2) if lengths is None else lengths          # (B, N), NaN
    cams = np.array([c for c, _, _ in p.blocks])
    limit = np.empty(len(cams))
    for c in np.unique(cams):
        limit[cams == c] = outlier_limit_px(float(np.nanmedian(length[cams == c])), factor)
    if noise is not None:
        for b, (c, v, _) in enumerate(p.blocks):
            if (p.cameras[c], v) in noise.noise_px:
                limit[b] = outlier_limit_px(MEDIAN_LENGTH * noise.noise_px[p.cameras[c], v], factor)
    with np.errstate(invalid="ignore"):
        return length > limit[:, None], limit, length


def outlier_shares(sol: Solution, factor: float, noise: PhotoNoise | None = None,
                   lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each photo's share of outlier corners (B,) and its limit (B,) px (:func:`corner_outliers`)."""
    out, limit, _ = corner_outliers(sol, factor, noise, lengths)
    return out.sum(axis=1) / np.maximum(np.isfinite(sol.residuals[..., 0]).sum(axis=1), 1), limit


def find_outlier(shares: np.ndarray, limits: np.ndarray, misfit: np.ndarray | None = None):
    """The photo with the largest share of outlier corners (:func:`outlier_shares`), if more than
    :data:`MOST_CORNERS` of them are, as ``(block, share, limit_px)``; else None. Of photos with the same share
    (a tied rig pulled far off by one instant can make every photo's corners outliers against their own noise),
    the one of the largest ``misfit`` (B,), its RMS over its limit."""
    worst = int(np.lexsort((np.zeros(len(shares)) if misfit is None else misfit, shares))[-1])
    if shares[worst] <= MOST_CORNERS:
        return None
    return worst, float(shares[worst]), float(limits[worst])


def _views_left(blocks, c: int) -> int:
    return sum(1 for blk in blocks if blk[0] == c)


MAX_CORNER_ROUNDS = 5
#: Each photo's noise (with ``weigh``) is estimated again from every solution, and the photos weighed by it
#: again, until no weight changes by more than this share (at most :data:`MAX_REWEIGHTS` times).
REWEIGHT_TOLERANCE = 1e-3
MAX_REWEIGHTS = 10


@dataclass(frozen=True)
class _Round:
    """What one round of :func:`adjust_dropping_outliers` adjusts (``kind``: ``start``, ``photo``, ``instant``,
    ``gross``, ``corners``, ``reweight`` or ``prior``): each of ``trials`` (lists of photos, the one that fits best
    is kept) from ``start``, with the solver's switches ``setup`` (None: as before: a ``reweight`` round weighs the
    photos by their noise, ``noise``, and gives a prior on known intrinsics its scale, as a ``prior`` round
    does); with ``improve``, kept only where it fits better than the solution before (else ``kept``, a warning,
    is said where given); ``record(before, after, trial)`` records and says what was left out."""

    kind: str
    trials: list[list]
    start: Solution | None = None
    setup: Setup | None = None
    noise: PhotoNoise | None = None
    improve: bool = False
    kept: str | None = None
    record: Callable[[Solution, Solution, int], None] | None = None


def adjust_dropping_outliers(setup: Setup, blocks, factor, dropped, dropped_corners, start=None,
                             noise: PhotoNoise | None = None, weigh: bool = False):
    """Solve, drop outlier photos and then outlier corners while there are any, solve again;
    returns ``(solution, blocks, noise, setup)``.

    Each round decides what to leave out of the current solution (:func:`_next_round`) and adjusts the
    photos without it, the one adjustment of the stage: a photo, an instant or a refocused photo from a
    fresh start (the solution with the bad photo in it may be far off), kept only where the fit then really
    improves; outlier corners from the solution, a round at a time (at most :data:`MAX_CORNER_ROUNDS`), as
    the limit is recomputed. In a tied rig a bad photo pulls the shared pose and so spreads its error over
    every photo of that instant; of the photos of the flagged instant whose corners are mostly outliers,
    the one whose removal fits best is dropped.

    With ``weigh`` (every camera alone, ``setup.mode`` ``none``) each photo's noise is estimated from every
    solution (:func:`dualcal.estimation.photo_noise.photo_noise`), its corners judged against it, and the photos
    weighed by it and adjusted again until the weights settle (:data:`REWEIGHT_TOLERANCE`); the ``noise``
    returned is the one whose weights the solution has, with the ``setup`` of its switches (the weights, and
    the scale of a prior on known intrinsics, which they hold until the first solution's noise gives it; without
    ``weigh``, its ``s0``). With ``noise`` (the cameras alone's, ``setup``'s weights from it) in a tied rig, a
    photo is judged against it, and no single corner: a corner that fits its photo's own pose but not the rig's
    is no corner error but its instant's misfit (a shot out of sync, a board moved), which the photo or the
    instant is dropped for, or ``rig_rigid`` names. Without either, the corners are judged against their camera's
    median residual.
    """
    alone_share = {}
    if factor and setup.mode != "none" and start is not None:
        rough = None if noise is None else np.linalg.norm(rough_residuals(start, factor)[0], axis=2)
        alone_share = dict(zip([(c, v) for c, v, _ in start.problem.blocks],
                               outlier_shares(start, factor, noise, rough)[0]))
    sol, corner_rounds, reweights, weighed = None, 0, 0, noise
    step: _Round | None = _Round("start", [blocks], start)
    while step is not None:
        if step.setup is not None:
            setup, weighed = step.setup, step.noise or weighed
        trials = [setup.solve(trial, step.start) for trial in step.trials]
        best = min(range(len(trials)), key=lambda i: trials[i].s0_px)
        if step.improve and trials[best].s0_px >= sol.s0_px:
            if step.kept:
                warn(step.kept)
            break
        if step.record is not None:
            step.record(sol, trials[best], best)
        sol, blocks = trials[best], step.trials[best]
        if weigh:
            noise = photo_noise(sol, factor)
        step = _next_round(setup, sol, blocks, start, factor, alone_share, dropped, dropped_corners,
                           corner_rounds < MAX_CORNER_ROUNDS and (noise is None or setup.mode == "none"), noise,
                           weigh and reweights < MAX_REWEIGHTS)
        corner_rounds += step is not None and step.kind == "corners"
        reweights += step is not None and step.kind == "reweight"
    if weigh and weighed is None:          # the first weights were 1 within the tolerance: the solution's own
        weighed, setup = noise, replace(setup, weights=noise.weights())
    return sol, blocks, weighed, setup


def _settled(setup: Setup, noise: PhotoNoise) -> bool:
    """Whether the photos' weights of ``noise`` are ``setup``'s, within :data:`REWEIGHT_TOLERANCE`."""
    old, new = setup.weights or {}, noise.weights() or {}
    return all(abs(new.get(k, 1.0) / old.get(k, 1.0) - 1.0) <= REWEIGHT_TOLERANCE for k in old.keys() | new.keys())


def _next_round(setup: Setup, sol: Solution, blocks, alone: Solution | None, factor: float | None, alone_share: dict,
                dropped: list, dropped_corners: list, corners_too: bool, noise: PhotoNoise | None,
                reweigh: bool) -> _Round | None:
    """What to do next with ``sol`` (:func:`adjust_dropping_outliers`): leave out a photo of a gross misfit
    (:attr:`dualcal.estimation.photo_noise.PhotoNoise.gross`), else the photo (or the instant, or the refocused
    photo of an instant) most of whose corners are outliers against ``noise``, else, where ``corners_too``, the
    outlier corners; else, where ``reweigh``, weigh the photos by ``noise`` where their weights have not
    settled; give a prior on known intrinsics its scale where it has none yet. None where there is nothing to do,
    or what should be left out cannot be (a warning says why)."""
    if factor:
        leave_out = _leave_out(setup, sol, blocks, alone, factor, alone_share, dropped, dropped_corners, corners_too,
                               noise)
        if leave_out is not None:
            return leave_out
    if reweigh and not _settled(setup, noise):
        return _Round("reweight", [blocks], sol, replace(setup, weights=noise.weights(), prior_scale_px=(
            noise.reference_px if setup.known else None)), noise)
    if any(k.mode == "prior" for k in (setup.known or {}).values()) and setup.prior_scale_px is None:
        return _Round("prior", [blocks], sol, replace(setup, weights=None if noise is None else noise.weights(),
                                                      prior_scale_px=sol.s0_px), noise)
    return None


def _leave_out(setup: Setup, sol: Solution, blocks, alone: Solution | None, factor: float, alone_share: dict,
               dropped: list, dropped_corners: list, corners_too: bool, noise: PhotoNoise | None) -> _Round | None:
    """The round that leaves out what :func:`_next_round` says, or None."""
    names = setup.names
    lengths = noise.lengths_px if noise is not None and setup.mode == "none" else None   # with every camera alone
    index = {(names[c], v): i for i, (c, v, _) in enumerate(blocks)}
    gross = [index[k] for k in (noise.gross if noise is not None else ())
             if k in index and _views_left(blocks, blocks[index[k]][0]) > MIN_VIEWS]
    if gross:                            # the worst first: it may have pulled the others' fit off
        return _without_gross(setup, blocks, gross[0], dropped)
    shares, limits = outlier_shares(sol, factor, noise, lengths)
    out = find_outlier(shares, limits, np.asarray(sol.block_rms_px) / np.maximum(limits, 1e-12))
    if out is None:
        bad, limit, length = corner_outliers(sol, factor, noise, lengths)
        if not bad.any() or not corners_too:
            return None
        return _Round("corners", [_without_corners(setup, sol, blocks, bad, limit, length, dropped, dropped_corners)],
                      sol)
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
    median = ("the median its photo's own noise gives" if noise is not None else
              f"the median of {names[blocks[b][0]]!r}")

    def record(before: Solution, after: Solution, trial: int):
        i = candidates[trial]
        c, rms_i = blocks[i][0], before.block_rms_px[i]
        if instant is not None:
            reason = (f"it fits {names[c]!r} alone, but tied to the rig only with a focal length of its own: the "
                      f"phone refocused or zoomed between the shots of {view} (photo RMS {rms_i:.3g} px in rig mode "
                      f"{setup.mode}; without it s0 falls from {before.s0_px:.3g} to {after.s0_px:.3g} px); lock focus")
        else:
            reason = (f"{share:.0%} of its corners are outliers (residual above {limit:.3g} px, {factor:g} x "
                      f"{median}; photo RMS {rms_i:.3g} px) in rig mode {setup.mode}; without it s0 "
                      f"falls from {before.s0_px:.3g} to {after.s0_px:.3g} px (moved board, wrong corner order, blur, "
                      "or another zoom/focus setting?)")
        warn(f"dropping {names[c]}/{view}: {reason}")
        dropped.append({"camera": names[c], "view": view, "rms_px": rms_i, "reason": reason})

    return _Round("photo", [blocks[:i] + blocks[i + 1:] for i in candidates], improve=True,
                  kept=f"{photo} but dropping the photo does not improve the fit: kept", record=record)


def _without_gross(setup: Setup, blocks, b: int, dropped: list) -> _Round:
    """The round without photo ``b``, a gross misfit (:attr:`dualcal.estimation.photo_noise.PhotoNoise.gross`)."""
    c, view, _ = blocks[b]

    def record(before: Solution, after: Solution, _trial: int):
        reason = (f"its corners are off its own fit by {before.block_rms_px[b]:.3g} px RMS, more than a tenth of its "
                  f"squares in the photo: no noise of a corner detection, but another numbering of the board (turned "
                  f"or mirrored), another board, or corners found wrongly; without it s0 is {after.s0_px:.3g} px")
        warn(f"dropping {setup.names[c]}/{view}: {reason}")
        dropped.append({"camera": setup.names[c], "view": view, "rms_px": before.block_rms_px[b], "reason": reason})

    return _Round("gross", [blocks[:b] + blocks[b + 1:]], record=record)


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
    alone_cost = dict(zip([(c, v) for c, v, _ in alone.problem.blocks], alone.block_costs()))
    tied_cost = sol.block_costs()
    tie = sum(float(tied_cost[i]) - alone_cost.get((blocks[i][0], view), 0.0) for i in instant)
    if not any(tie > 0 and f["explained_px2"] >= REFOCUS_SHARE * tie for f in focal_scale_fits(sol, {view})):
        return "instant"
    c = refocused_camera(alone, view, design_effect(alone))
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

    return _Round("instant", [rest], improve=True, record=record)


def _without_corners(setup: Setup, sol: Solution, blocks, bad, limit, length, dropped, dropped_corners):
    """``blocks`` with the outlier corners ``bad`` (B, N) set to NaN, each recorded with its residual ``length``
    and its photo's ``limit`` (px); a photo left unable to fix a homography is dropped, with the reason."""
    out = []
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
