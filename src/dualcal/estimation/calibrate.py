"""From corners to a calibrated rig: initialisation, joint adjustment, outliers, board shape, checks.

:func:`calibrate_rig` is the whole of the paper's sections 1.3 to 1.7 for any number of cameras:
Zhang's closed form per camera (:mod:`dualcal.geometry.zhang`), the rig's relative poses from the views
the cameras share, then the joint adjustment (:mod:`dualcal.estimation.adjust`) in the chosen rig mode.
Each photo contributes the corners it measured; one whose corners cannot fix a homography (fewer
than 4, or all on one line) is skipped with a warning.

Outliers are single corners: one whose residual is far above the typical residual of its camera
is left out (``dropped_corners``), and a photo is dropped only when most of its corners are
outliers (a moved board, a wrong numbering), each with a recorded reason; they are looked for
first with every camera alone, so that a bad photo shows in its own camera's residuals, then in
the rig. The board's shape (sag, bend, twist: :data:`dualcal.geometry.board.SHAPE_TERMS`) is estimated
where the photos show it beyond their noise. Every sigma comes twice: clustered by instant (it
holds on real photos) and the textbook one; :mod:`dualcal.estimation.checks` then says how far to trust the
result. A final adjustment that did not converge is said so, on stderr and in calib.json.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import partial

import numpy as np

from .adjust import Solution
from .checks import (REFOCUS_SHARE, design_effect, focal_scale_fits, focal_scale_sigmas, focus_drift,
                     relation_shift_sigma, rig_rigid, run_checks, tie_costs)
from .distributions import f_quantile
from .duplicates import describe_duplicates, merge_duplicate_instants
from ..errors import EstimationError, InputError
from .fitting import (AUTO_MODEL, MIN_VIEWS, Setup, lens_models_for, pair_solutions, rig_model_from_solution,
                      unusable_reason, usable_photos)
from .loop_closure import loop_closure
from .model_selection import choose_lens_models, preferred_lens_models
from ..geometry.board import SHAPE_TERMS
from ..geometry.camera import DEFAULT_LENS_MODEL
from ..geometry.model import CornerSet, RigModel, choose_reference
from ..progress import warn

BOARD_SHAPES = ("auto", "flat", "fit")
#: The board's shape is kept where its coefficients differ from zero at this significance level.
SHAPE_SIGNIFICANCE = 0.01
#: The shape is tested first at its one-step estimate from the flat board's solution; where that test's
#: ``T^2`` exceeds this share of its limit, the shape is adjusted in full and the test made there, so
#: that a decision near the limit is the full adjustment's.
SHAPE_FULL_TEST = 0.5


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


def _adjust_dropping_outliers(setup: Setup, blocks, factor, dropped, dropped_corners, start=None):
    """Solve, drop outlier photos and then outlier corners while there are any, solve again;
    returns ``(solution, blocks)``.

    In a tied rig a bad photo pulls the shared pose and so spreads its error over every photo of
    that instant; of the photos of the flagged instant whose corners are mostly outliers, the one
    whose removal fits best is dropped, and only if the fit then really improves. Corners are
    dropped a round at a time (at most :data:`MAX_CORNER_ROUNDS`), as the limit is recomputed.
    """
    s = setup
    names = s.names
    sol = s.solve(blocks, start)
    rounds = 0
    alone_share = {}
    if factor and s.mode != "none" and start is not None:
        alone_share = dict(zip([(c, v) for c, v, _ in start.problem.blocks], outlier_shares(start, factor)[0]))
    while factor:
        shares, limits = outlier_shares(sol, factor)
        out = find_outlier(shares, limits)
        if out is not None:
            b, share, limit = out
            view = blocks[b][1]
            instant = _instant_misfit(s, sol, start, blocks, view, alone_share)
            if instant is not None:
                if instant == "instant":
                    kept = _without_instant(s, sol, start, blocks, view, dropped)
                    if kept is None:
                        return sol, blocks
                    sol, blocks = kept
                    continue
                candidates = instant                      # the refocused photo(s) of the instant
            else:
                candidates = [b] if s.mode == "none" else [i for i, blk in enumerate(blocks) if blk[1] == view]
            candidates = [i for i in candidates if _views_left(blocks, blocks[i][0]) > MIN_VIEWS]
            if s.mode != "none" and instant is None:
                candidates = [i for i in candidates if shares[i] > MOST_CORNERS]
            if not candidates:
                warn(f"{names[blocks[b][0]]}/{view}: {share:.0%} of its corners are outliers (limit {limit:.3g} px) "
                     f"but it cannot be dropped: only {MIN_VIEWS} views left for {names[blocks[b][0]]!r}")
                return sol, blocks
            # a fresh start: the solution with the bad photo in it may be far off
            trials = [(s.solve(blocks[:i] + blocks[i + 1:]), i) for i in candidates]
            best, i = min(trials, key=lambda t: t[0].s0_px)
            if best.s0_px >= sol.s0_px:
                warn(f"{names[blocks[b][0]]}/{view}: {share:.0%} of its corners are outliers (limit {limit:.3g} px) "
                     "but dropping the photo does not improve the fit: kept")
                return sol, blocks
            c, rms_i = blocks[i][0], sol.block_rms_px[i]
            if instant is not None:
                reason = (f"it fits {names[c]!r} alone, but tied to the rig only with a focal length of its own: the "
                          f"phone refocused or zoomed between the shots of {view} (photo RMS {rms_i:.3g} px in rig mode "
                          f"{s.mode}; without it s0 falls from {sol.s0_px:.3g} to {best.s0_px:.3g} px); lock focus")
            else:
                reason = (f"{share:.0%} of its corners are outliers (residual above {limit:.3g} px, {factor:g} x the "
                          f"median of {names[c]!r}; photo RMS {rms_i:.3g} px) in rig mode {s.mode}; without it s0 "
                          f"falls from {sol.s0_px:.3g} to {best.s0_px:.3g} px (moved board, wrong corner order, blur, "
                          "or another zoom/focus setting?)")
            warn(f"dropping {names[c]}/{view}: {reason}")
            dropped.append({"camera": names[c], "view": view, "rms_px": rms_i, "reason": reason})
            sol, blocks = best, blocks[:i] + blocks[i + 1:]
            continue
        bad, limit = corner_outliers(sol, factor)
        if not bad.any() or rounds >= MAX_CORNER_ROUNDS:
            return sol, blocks
        rounds += 1
        blocks = _without_corners(setup, sol, blocks, bad, limit, dropped, dropped_corners)
        sol = s.solve(blocks, sol)
    return sol, blocks


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


def _without_instant(setup: Setup, sol: Solution, alone: Solution, blocks, view: str, dropped):
    """``(solution, blocks)`` without every photo of ``view`` (an instant whose photos fit their cameras
    alone but not the rig), each recorded in ``dropped`` with the reason; None where that leaves a camera
    too few views or does not improve the fit (a warning says so)."""
    names = setup.names
    instant = [i for i, blk in enumerate(blocks) if blk[1] == view]
    rest = [blk for i, blk in enumerate(blocks) if i not in instant]
    short = [names[blocks[i][0]] for i in instant if _views_left(rest, blocks[i][0]) < MIN_VIEWS]
    if short:
        warn(f"instant {view} does not fit the rig, but it cannot be dropped: only {MIN_VIEWS} views left for "
             f"{short[0]!r}")
        return None
    best = setup.solve(rest)
    if best.s0_px >= sol.s0_px:
        return None
    alone_rms = {(c, v): r for (c, v, _), r in zip(alone.problem.blocks, alone.block_rms_px)}
    cams = [names[blocks[i][0]] for i in instant]
    fits = ", ".join(f"{names[blocks[i][0]]} {alone_rms.get((blocks[i][0], view), float('nan')):.3g} px" for i in instant)
    tied = ", ".join(f"{names[blocks[i][0]]} {sol.block_rms_px[i]:.3g} px" for i in instant)
    reason = (f"instant {view}: its photos fit their cameras alone (RMS {fits}) but not one relative pose of the rig "
              f"(RMS {tied} in rig mode {setup.mode}; without the instant s0 falls from {sol.s0_px:.3g} to "
              f"{best.s0_px:.3g} px): the cameras' shots disagree (not taken at the same instant, or a lens or the "
              "board moved between them)")
    warn(f"dropping {' and '.join(f'{c}/{view}' for c in cams)}: {reason}")
    for i in instant:
        dropped.append({"camera": names[blocks[i][0]], "view": view, "rms_px": sol.block_rms_px[i], "reason": reason,
                        "instant": True})
    return best, rest


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


def board_shape_test(sol: Solution, one_step: bool = False) -> dict:
    """Whether the board's shape estimated in ``sol`` differs from flat beyond the photos' noise.

    Hotelling's test of the three shape coefficients against the covariance clustered by instant
    (so that noise correlated within photos does not pass for a bent board): with ``G`` instants,
    ``T2 = w^T Cov^-1 w`` is compared with ``p (G-1) / (G-p) F(p, G-p)`` at
    :data:`SHAPE_SIGNIFICANCE`. Returns ``{"t2", "limit", "significant", "coefficients_mm",
    "sigma_mm", "estimate"}`` (``estimate``: ``"adjusted"``, or ``"one-step"`` where ``sol`` is a flat board's
    solution linearised with the shape free); with too few instants to judge (``G <= p + 1``) ``limit`` is
    None and the shape is not significant. ``w`` and its covariance are those of the linearised minimum (``sol`` moved by its
    Gauss-Newton step): of the adjusted shape, or from a flat board's solution linearised with the shape
    free (:func:`dualcal.estimation.adjust.linearised_at`), the one-step estimate (Wald's test at the
    one-step estimator, which differs from the adjusted one's by terms of second order in the shape).
    """
    cols = sol.problem.layout.board_shape
    w = sol.state.board_shape_mm + sol.factorization.step()[cols]                # at the linearised minimum
    cov = sol.covariance(cols, "clustered")
    p, G = len(cols), len(sol.problem.views)
    doc = {"coefficients_mm": dict(zip(SHAPE_TERMS, map(float, w))),
           "sigma_mm": dict(zip(SHAPE_TERMS, map(float, np.sqrt(np.maximum(np.diag(cov), 0.0))))),
           "estimate": "one-step" if one_step else "adjusted"}
    if G <= p + 1:
        return {**doc, "t2": None, "limit": None, "significant": False}
    t2 = float(w @ np.linalg.lstsq(cov, w, rcond=None)[0])
    limit = float(p * (G - 1) / (G - p) * f_quantile(p, G - p, 1.0 - SHAPE_SIGNIFICANCE))
    return {**doc, "t2": t2, "limit": limit, "significant": bool(t2 > limit)}


def calibrate_rig(corners: CornerSet, skew: bool = False, rig_mode: str = "rigid",
                  reference: str | None = None, drop_outliers: bool = True,
                  outlier_factor: float = 6.0, board_shape: str = "auto",
                  model: str | Mapping[str, str] = DEFAULT_LENS_MODEL) -> RigModel:
    """Calibrate every camera of a rig and the rig itself from chessboard corners.

    Parameters
    ----------
    corners : CornerSet
        the detected corners (corners.json content). Instants that repeat another's view (a copied
        photo, a burst: :mod:`dualcal.estimation.duplicates`) count once, with a warning; calib.json records them
        (``adjustment.duplicates``, and ``duplicates`` in each camera's entry of its corners).
    skew : bool
        False fixes skew = 0 (the paper's Model 1), True estimates it (Model 2)
    rig_mode : str
        ``rigid``, ``paper`` or ``none`` (see :mod:`dualcal.estimation.adjust`)
    reference : str or None
        name of the reference camera (default: the one recorded in ``corners``, else ``wide``,
        else the first name)
    drop_outliers : bool
        leave out corners whose residual exceeds ``outlier_factor`` x the median of
        their camera (:func:`outlier_limit_px`), and photos where most corners are outliers.
        Outliers are looked for first with every camera adjusted alone (so that a bad photo shows
        in its own camera's residuals, not spread over the rig), then in ``rig_mode`` (which
        also reveals a board moved between the shots of one instant).
    board_shape : str
        ``auto`` estimates the board's out-of-plane shape and keeps it where the photos
        show it beyond their noise (:func:`board_shape_test`), ``fit`` always keeps it, ``flat``
        takes the board as flat.
    model : str or Mapping[str, str]
        the lens model of every camera, a key of :data:`dualcal.geometry.camera.LENS_MODELS`:
        ``k1k2`` (the paper's), ``k1k2k3``, ``k1k2p1p2``, ``k1k2p1p2k3`` (OpenCV's five coefficients) or
        ``kb4`` (OpenCV's fisheye); or ``{camera: model}`` (cameras not named: ``k1k2``); or ``"auto"``:
        each camera's chosen by its held-out instants (:func:`_calibrate_auto`, which records the comparison in
        ``adjustment["lens_models"]``)

    Returns
    -------
    RigModel
        calib.json's content: every camera's intrinsics and lens, the rig, the board's poses, every value's
        1-sigma (``sigma``, and the textbook ``sigma_formal``), the joint covariance and the checks.

    Raises
    ------
    InputError
        An unknown lens model or board shape option.
    EstimationError
        Fewer than 3 usable views for a camera, degenerate views, no shared view in a rig.
    """
    if board_shape not in BOARD_SHAPES:
        raise InputError(f"--board-shape {board_shape!r} is unknown (choose from {', '.join(BOARD_SHAPES)})")
    corners, duplicates = merge_duplicate_instants(corners)
    if duplicates:
        warn(describe_duplicates(duplicates))
    options = dict(skew=skew, rig_mode=rig_mode, reference=reference, drop_outliers=drop_outliers,
                   outlier_factor=outlier_factor, board_shape=board_shape)
    if isinstance(model, str) and model == AUTO_MODEL:
        rig = _calibrate_auto(corners, **options)
    else:
        rig = _calibrate_distinct(corners, model=model, **options)[0]
    if duplicates:
        rig.adjustment["duplicates"] = duplicates
    return rig


def _calibrate_auto(corners: CornerSet, **options) -> RigModel:
    """:func:`calibrate_rig` with every camera's lens model chosen by its held-out instants
    (:mod:`dualcal.estimation.model_selection`): a calibration with every camera's preferred model, the
    comparison of the models on its corners, and a calibration with the models chosen where they differ.
    ``adjustment["lens_models"]`` holds the comparison, ``adjustment["lens_models_chosen"]`` ``{camera: model}``."""
    candidates, preferred = preferred_lens_models(corners, options["skew"])
    base, alone = _calibrate_distinct(corners, model=preferred, **options)
    chosen, comparison = choose_lens_models(base, candidates, preferred, alone)
    final = base if chosen == preferred else _calibrate_distinct(corners, model=chosen, start=alone, **options)[0]
    final.adjustment["lens_models"] = comparison
    final.adjustment["lens_models_chosen"] = chosen
    return final


def _calibrate_distinct(corners: CornerSet, skew: bool, rig_mode: str, reference: str | None, drop_outliers: bool,
                        outlier_factor: float, board_shape: str, model: str | Mapping[str, str],
                        start: Solution | None = None) -> tuple[RigModel, Solution]:
    """:func:`calibrate_rig` with given lens models, of corners whose duplicate instants are merged, and its
    solution with every camera alone (flat board) over the photos it kept. The cameras alone start from
    Zhang's closed form, or from ``start``, such a solution with other lens models."""
    names = sorted(corners.cameras)
    models = lens_models_for(model, names)
    ref = names.index(choose_reference(names, reference if reference is not None else corners.reference))
    sizes = [corners.cameras[n].image_size for n in names]
    X = corners.board.object_points_mm()
    blocks = usable_photos(corners, names, X[:, :2])
    dropped: list[dict] = []
    dropped_corners: list[dict] = []
    factor = outlier_factor if drop_outliers else None
    setup = Setup(X, names, sizes, ref, skew, rig_mode, models)
    alone, blocks = _adjust_dropping_outliers(replace(setup, mode="none"), blocks, factor, dropped, dropped_corners,
                                              start)
    sol = alone
    if rig_mode != "none":
        sol, rig_blocks = _adjust_dropping_outliers(setup, blocks, factor, dropped, dropped_corners, alone)
        if rig_blocks is not blocks:      # the rig dropped photos or corners: the same photos alone
            alone = setup.solve(rig_blocks, sol, mode="none")
    flat = sol
    shape_test = None
    if board_shape == "auto":            # the one-step estimate first: the full adjustment only near the limit
        shape_test = board_shape_test(setup.linearised(sol, board_shape=True), one_step=True)
        if shape_test["limit"] is not None and shape_test["t2"] > SHAPE_FULL_TEST * shape_test["limit"]:
            shape_test = None
    if board_shape != "flat" and shape_test is None:
        shaped = setup.solve(sol.problem.blocks, sol, board_shape=True)
        shape_test = board_shape_test(shaped)
        if board_shape == "fit" or shape_test["significant"]:
            sol = shaped
    if not sol.converged:
        warn(f"the adjustment (rig mode {rig_mode}, {'Model 2' if skew else 'Model 1'}) did not converge: "
             f"{sol.termination}; the results and their sigmas are not those of the best fit")
    rig = rig_model_from_solution(sol, corners, dropped, dropped_corners)
    rig.adjustment["options"] = {"drop_outliers": bool(drop_outliers), "outlier_factor": float(outlier_factor),
                                 "board_shape": board_shape,
                                 "model": models[0] if len(set(models)) == 1 else dict(zip(names, models))}
    if shape_test is not None:
        rig.adjustment["board_shape_test"] = shape_test
    rig.checks = run_checks(rig, sol, flat, alone,
                            attribution=partial(attribution_checks, setup) if rig_mode != "none" else None)
    if rig_mode != "none":
        kappa2 = rig.checks.get("rig_rigid", {}).get("design_effect")       # the rig's photo-level noise
        loop = loop_closure(flat, alone, kappa2)
        if loop is not None:
            rig.checks["loop_closure"] = loop
    return rig, alone


def attribution_checks(setup: Setup, tied: Solution, alone: Solution, kappa2) -> tuple[dict, dict | None]:
    """The ``focus`` and ``rig_rigid`` checks (:func:`dualcal.estimation.checks.focus_and_rigidity`), every
    refocused photo and every instant that does not fit the rig named at once by tests against a robust core of
    the others; both solutions adjusted again once without what they name, to see how far it moves the rig."""
    from .checks import focus_and_rigidity

    return focus_and_rigidity(tied, alone, kappa2, refit=lambda blocks: (setup.solve(blocks, tied),
                                                                         setup.solve(blocks, alone, mode="none")))


def _refocused_camera(alone: Solution, view: str, kappa2) -> int | None:
    """Of the photos of ``view``, the camera whose own focal scale is furthest off with its own pose
    (:func:`dualcal.estimation.checks.refocused_camera`)."""
    from .checks import refocused_camera

    return refocused_camera(alone, view, kappa2)
