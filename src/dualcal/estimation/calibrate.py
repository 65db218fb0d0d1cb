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
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from .adjust import COVARIANCE_KINDS, Problem, Solution, adjust, cost, initial_state
from ..geometry.board import SHAPE_TERMS
from ..geometry.camera import DEFAULT_LENS_MODEL, DISTORTION_NAMES, FISHEYE_MODELS, INTRINSIC_NAMES, LENS_MODELS
from .checks import REFOCUS_SHARE, design_effect, focal_scale_fits, focus_drift, rig_rigid, run_checks, tie_costs
from .covariance import JointCovariance, intrinsic_name
from .distributions import f_quantile
from .duplicates import describe_duplicates, merge_duplicate_instants
from ..errors import EstimationError, InputError
from .loop_closure import loop_closure
from .lm import NEAR_START, LMOptions
from ..geometry.model import CornerSet, Pose, RigModel, RigRelation, choose_reference, observed_mask
from ..progress import warn
from .rig_relations import parameter_covariance, rig_relation, shared_views
from ..geometry.scale import relative_sigma, with_scale
from ..geometry.zhang import MIN_HOMOGRAPHY_CORNERS, initial_camera, spans_a_plane

MIN_VIEWS = 3
BOARD_SHAPES = ("auto", "flat", "fit")
#: The board's shape is kept where its coefficients differ from zero at this significance level.
SHAPE_SIGNIFICANCE = 0.01


def unusable_reason(uv: np.ndarray, xy_board: np.ndarray) -> str | None:
    """Why a photo's measured corners cannot determine a homography (None if they can): fewer than
    :data:`dualcal.geometry.zhang.MIN_HOMOGRAPHY_CORNERS`, or all on one line."""
    seen = observed_mask(uv)
    if seen.sum() >= MIN_HOMOGRAPHY_CORNERS and spans_a_plane(xy_board[seen]):
        return None
    return (f"its {int(seen.sum())} measured corner(s) "
            f"{'lie on one line' if seen.sum() >= MIN_HOMOGRAPHY_CORNERS else 'are too few'}; "
            f"a photo needs at least {MIN_HOMOGRAPHY_CORNERS} corners, not all on one line")


def usable_photos(corners: CornerSet, names: list[str], xy_board: np.ndarray,
                  quiet: bool = False) -> list[tuple[int, str, np.ndarray]]:
    """``(camera index, view, (N, 2) corners)`` of every photo whose measured corners determine a
    homography (:func:`unusable_reason`). Every other photo where the board was found is skipped
    with a warning naming it (unless ``quiet``: a calibration already said so)."""
    blocks = []
    for c, name in enumerate(names):
        for v, uv in sorted(corners.cameras[name].found().items()):
            reason = unusable_reason(uv, xy_board)
            if reason:
                if not quiet:
                    warn(f"{name}/{v} skipped: {reason}")
                continue
            blocks.append((c, v, uv))
    return blocks


def _check_enough_views(blocks, names) -> None:
    for c, name in enumerate(names):
        n = sum(1 for cam, _, _ in blocks if cam == c)
        if n < MIN_VIEWS:
            raise EstimationError(f"camera {name!r} has {n} usable view(s); at least {MIN_VIEWS} are needed "
                                  "(take more photos, or check that the board is found in them)")


def _block_poses(sol: Solution) -> dict[tuple[int, str], Pose]:
    """Board-to-camera pose of every observed (camera, view)."""
    p = sol.problem
    return {(c, v): sol.state.photo_pose(p, c, p.view_index[v]) for c, v, _ in p.blocks}


def _starting_values(sol: Solution):
    """Per-camera intrinsics and board-to-camera poses of a solution, to start another adjustment."""
    bp = _block_poses(sol)
    n = len(sol.problem.cameras)
    cams = [sol.state.camera(sol.problem, c) for c in range(n)]
    poses = [{v: bp[(c, v)] for cc, v, _ in sol.problem.blocks if cc == c and (c, v) in bp} for c in range(n)]
    return cams, poses


@dataclass(frozen=True)
class Setup:
    """What every adjustment of one calibration shares: the board's corners ``X_board`` (N, 3), the
    camera names and image sizes, the reference's index, the skew model, the rig mode and the lens
    model of every camera (one name, or one per camera)."""

    X_board: np.ndarray
    names: list[str]
    sizes: list[tuple[int, int]]
    reference: int
    skew: bool
    mode: str
    model: str | tuple[str, ...] = DEFAULT_LENS_MODEL

    def solve(self, blocks, start: "Solution | None" = None, mode: str | None = None,
              board_shape: bool = False) -> "Solution":
        """:func:`solve` with these settings (``mode`` overrides the rig mode)."""
        return solve(self.X_board, self.names, self.sizes, blocks, self.reference, self.skew, mode or self.mode,
                     start, board_shape, self.model)


def solve(X_board, names, sizes, blocks, reference: int, skew: bool, mode: str,
          start: Solution | None = None, board_shape: bool = False,
          model: str | tuple[str, ...] = DEFAULT_LENS_MODEL) -> Solution:
    """Initialise and adjust one rig (no outlier handling). ``blocks``: (camera, view, uv) triples;
    ``model``: the lens model (:data:`dualcal.geometry.camera.LENS_MODELS`) of every camera, or one per camera.

    Starting values come from Zhang's closed form per camera, or from ``start``, an earlier
    solution over the same photos (or a superset of them: photos it did not see start from
    Zhang's), whose board shape is kept as the start too. The paper's model starts from the
    better (lower cost) of the rigid solution (every instant's baseline direction the same) and
    the cameras-alone solution (each instant's own relative pose): the first is the nearer when
    the rig is rigid, the second when the direction moves between instants. With
    ``board_shape`` the board's out-of-plane shape is estimated too.
    """
    _check_enough_views(blocks, names)
    models = (model,) * len(names) if isinstance(model, str) else tuple(model)
    if mode == "paper" and start is None:
        start = solve(X_board, names, sizes, blocks, reference, skew, "none", board_shape=board_shape, model=model)
    shape = start.state.board_shape_mm if start is not None else None
    if start is not None:
        cams, poses = _starting_values(start)
        views = {v for _, v, _ in blocks}
        poses = [{v: pose for v, pose in per.items() if v in views} for per in poses]
        missing = [(c, v) for c, v, _ in blocks if v not in poses[c]]
        if missing:
            zhang = {c: initial_camera(X_board[:, :2], {v: uv for cc, v, uv in blocks if cc == c}, sizes[c], skew,
                                       models[c])[1]
                     for c in {c for c, _ in missing}}
            for c, v in missing:
                poses[c][v] = zhang[c][v]
    else:
        cams, poses = [], []
        for c, size in enumerate(sizes):
            cam, p = initial_camera(X_board[:, :2], {v: uv for cc, v, uv in blocks if cc == c}, size, skew,
                                    models[c])
            cams.append(cam)
            poses.append(p)
    first_mode = "rigid" if mode == "paper" else mode
    problem = Problem(X_board, list(names), list(sizes), blocks, first_mode, skew, reference, board_shape, models)
    sol = adjust(problem, initial_state(problem, cams, poses, shape), LMOptions() if start is None else NEAR_START)
    if mode != "paper":
        return sol
    problem = Problem(X_board, list(names), list(sizes), blocks, "paper", skew, reference, board_shape, models)
    starts = [initial_state(problem, *_starting_values(s), s.state.board_shape_mm) for s in (sol, start)]
    return adjust(problem, min(starts, key=lambda state: cost(problem, state)), NEAR_START)


def pair_solutions(setup: Setup, sol: Solution, alone: Solution, x: int, y: int) -> tuple[Solution, Solution, int]:
    """Cameras ``x`` and ``y`` of ``sol`` as a rigid two-camera rig (``x`` its reference) and alone, from
    the instants both saw there, started from ``sol``'s values (the tied pair) and ``alone``'s (the
    cameras alone: where the pair's photos are all those ``alone`` had, it is already their solution)."""
    cams, poses = _starting_values(sol)
    views = set(poses[x]) & set(poses[y])
    blocks = [(int(c == y), v, uv) for c, v, uv in sol.problem.blocks if c in (x, y) and v in views]
    model = setup.model if isinstance(setup.model, str) else (setup.model[x], setup.model[y])
    pair = replace(setup, names=[setup.names[x], setup.names[y]], sizes=[setup.sizes[x], setup.sizes[y]],
                   reference=0, mode="rigid", model=model)
    _check_enough_views(blocks, pair.names)

    def adjusted(mode: str, start: Solution) -> Solution:
        problem = Problem(pair.X_board, pair.names, pair.sizes, blocks, mode, pair.skew, 0, False, pair.model)
        start_cams, start_poses = _starting_values(start)
        return adjust(problem, initial_state(problem, [start_cams[x], start_cams[y]],
                                             [{v: p for v, p in start_poses[c].items() if v in views} for c in (x, y)]),
                      NEAR_START)

    return adjusted("rigid", sol), adjusted("none", alone), len(views)


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


def board_shape_test(sol: Solution) -> dict:
    """Whether the board's shape estimated in ``sol`` differs from flat beyond the photos' noise.

    Hotelling's test of the three shape coefficients against the covariance clustered by instant
    (so that noise correlated within photos does not pass for a bent board): with ``G`` instants,
    ``T2 = w^T Cov^-1 w`` is compared with ``p (G-1) / (G-p) F(p, G-p)`` at
    :data:`SHAPE_SIGNIFICANCE`. Returns ``{"t2", "limit", "significant", "coefficients_mm",
    "sigma_mm"}``; with too few instants to judge (``G <= p + 1``) ``limit`` is None and the shape
    is not significant.
    """
    cols = sol.problem.layout.board_shape
    w = sol.state.board_shape_mm
    cov = sol.covariance(cols, "clustered")
    p, G = len(cols), len(sol.problem.views)
    doc = {"coefficients_mm": dict(zip(SHAPE_TERMS, map(float, w))),
           "sigma_mm": dict(zip(SHAPE_TERMS, map(float, np.sqrt(np.maximum(np.diag(cov), 0.0)))))}
    if G <= p + 1:
        return {**doc, "t2": None, "limit": None, "significant": False}
    t2 = float(w @ np.linalg.lstsq(cov, w, rcond=None)[0])
    limit = float(p * (G - 1) / (G - p) * f_quantile(p, G - p, 1.0 - SHAPE_SIGNIFICANCE))
    return {**doc, "t2": t2, "limit": limit, "significant": bool(t2 > limit)}


#: ``model="auto"``: every camera's lens model chosen by its held-out instants (:mod:`dualcal.estimation.model_selection`).
AUTO_MODEL = "auto"


def lens_models_for(model: str | Mapping[str, str], names: list[str]) -> tuple[str, ...]:
    """One lens model per camera of ``names`` from a model name (every camera) or a mapping
    ``{camera: model}`` (cameras not named get the mapping's ``"*"``, else
    :data:`dualcal.geometry.camera.DEFAULT_LENS_MODEL`).

    Raises
    ------
    InputError
        An unknown model name, or a mapping naming a camera that is not there.
    """
    if isinstance(model, str):
        model = dict.fromkeys(names, model)
    model = dict(model)
    default = model.pop("*", DEFAULT_LENS_MODEL)
    unknown_cameras = sorted(set(model) - set(names))
    if unknown_cameras:
        raise InputError(f"lens model given for camera {unknown_cameras[0]!r}, which is not one of the rig's "
                         f"({', '.join(names)})")
    for m in [default, *model.values()]:
        if m not in LENS_MODELS:
            raise InputError(f"lens model {m!r} is unknown (choose from {', '.join(LENS_MODELS)}, or {AUTO_MODEL})")
    return tuple(model.get(n, default) for n in names)


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
        each camera's chosen by its held-out instants (:func:`dualcal.estimation.model_selection.calibrate_auto`,
        which records the comparison in ``adjustment["lens_models"]``)

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
        from .model_selection import calibrate_auto
        rig = calibrate_auto(corners, calibrate=_calibrate_distinct, **options)
    else:
        rig = _calibrate_distinct(corners, model=model, **options)
    if duplicates:
        rig.adjustment["duplicates"] = duplicates
    return rig


def _calibrate_distinct(corners: CornerSet, skew: bool, rig_mode: str, reference: str | None, drop_outliers: bool,
                        outlier_factor: float, board_shape: str, model: str | Mapping[str, str]) -> RigModel:
    """:func:`calibrate_rig` with given lens models, of corners whose duplicate instants are merged."""
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
    alone, blocks = _adjust_dropping_outliers(replace(setup, mode="none"), blocks, factor, dropped, dropped_corners)
    sol = alone
    if rig_mode != "none":
        sol, rig_blocks = _adjust_dropping_outliers(setup, blocks, factor, dropped, dropped_corners, alone)
        if rig_blocks is not blocks:      # the rig dropped photos or corners: the same photos alone
            alone = setup.solve(rig_blocks, sol, mode="none")
    flat = sol
    shape_test = None
    if board_shape != "flat":
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
        loop = loop_closure(names, ref, lambda x, y: pair_solutions(setup, flat, alone, x, y),
                            lambda tied, alone: rig_rigid(tied, alone, None if kappa2 is None else {0: kappa2}))
        if loop is not None:
            rig.checks["loop_closure"] = loop
    return rig


def refit(rig: RigModel, model: str | Mapping[str, str] | None = None, skew: bool | None = None,
          rig_mode: str | None = None, options: LMOptions = NEAR_START) -> Solution:
    """The corners ``rig`` used (:meth:`RigModel.used_corners`), adjusted again with another lens model,
    skew model or rig mode (None: ``rig``'s), started from ``rig``'s values.

    No outliers are looked for and the board keeps ``rig``'s treatment (its shape estimated again where
    ``rig`` kept one): the same corners, so that the solutions compare. A lens model of ``rig``'s family
    starts from ``rig``'s coefficients (a new coefficient at 0, a dropped one let go); one of another
    family (a fisheye for a radial lens, or back) from Zhang's closed form with ``rig``'s poses.
    This is what comparing lens or skew models costs: one adjustment from a near start, where a full
    calibration (closed form, outliers alone and tied, the board-shape test) takes several. ``options``:
    the adjustment's tolerances (a comparison needs fewer digits than a result).
    """
    corners = rig.used_corners()
    names = sorted(corners.cameras)
    models = lens_models_for(rig.models if model is None else model, names)
    skew = rig.skew if skew is None else skew
    X = corners.board.object_points_mm()
    blocks = usable_photos(corners, names, X[:, :2], quiet=True)
    _check_enough_views(blocks, names)
    sizes = [corners.cameras[n].image_size for n in names]
    poses = [dict(rig.camera_poses[n]) for n in names]
    cams = []
    for c, n in enumerate(names):
        cam = rig.cameras[n]
        if (models[c] in FISHEYE_MODELS) == cam.fisheye:
            cams.append(replace(cam, model=models[c], skew=cam.skew if skew else 0.0,
                                **{k: 0.0 for k in DISTORTION_NAMES if k not in LENS_MODELS[models[c]]}))
        else:
            cams.append(initial_camera(X[:, :2], {v: uv for cc, v, uv in blocks if cc == c}, sizes[c], skew,
                                       models[c])[0])
    ref = names.index(rig.reference)
    problem = Problem(X, names, sizes, blocks, rig_mode or rig.rig_mode, skew, ref, rig.board_shape_mm is not None,
                      models)
    return adjust(problem, initial_state(problem, cams, poses, rig.board_shape_mm), options)


def fit_summary(sol: Solution) -> dict:
    """What comparing models needs of a solution: ``rms_px`` (2-D, per corner), ``camera_rms_px``
    ``{camera: px}`` and the held-out errors of :func:`held_out_error`."""
    sq = np.sum(sol.residuals ** 2, axis=2)
    cams = np.array([c for c, _, _ in sol.problem.blocks])
    return {"rms_px": float(np.sqrt(np.nanmean(sq))),
            "camera_rms_px": {name: float(np.sqrt(np.nanmean(sq[cams == c])))
                              for c, name in enumerate(sol.problem.cameras)},
            **held_out_error(sol)}


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
    named: dict[str, float] = {}
    while doc is not None and doc["flagged"][len(named):] and len(named) < limit:
        worst = doc["flagged"][len(named)]
        named[worst] = doc["instants"][worst]
        blocks = [b for b in blocks if b[1] != worst]
        try:
            tied, alone = setup.solve(blocks, tied), setup.solve(blocks, alone, mode="none")
        except EstimationError:
            break
        doc = rig_rigid(tied, alone, kappa2, named=named)
    return focus, doc


def _refocused_camera(alone: Solution, view: str, kappa2) -> int | None:
    """Of the photos of ``view``, the camera whose own focal scale is furthest off with its own pose
    (:func:`dualcal.estimation.checks.focal_scale_fits` on the cameras-alone solution), in photo-level sigmas."""
    fits = focal_scale_fits(alone, {view})
    if not fits:
        return None
    z = [abs(f["s"]) / np.sqrt(max(kappa2[f["camera"]] * alone.s0_px ** 2, 1e-12) * f["var_s"]) for f in fits]
    return fits[int(np.argmax(z))]["camera"]


def held_out_error(sol: Solution) -> dict:
    """The error on instants the calibration did not see (:meth:`Solution.held_out_residuals`):
    ``held_out_rms_px``, the RMS length of the 2-D held-out residual per corner over the instants
    that can be left out, ``held_out_per_instant`` ``{view: {"rms_px", "corners"}}`` and the same of
    each camera's own corners, ``held_out_per_camera`` ``{camera: {view: {"rms_px", "corners"}}}``."""
    per_instant, per_camera = {}, {name: {} for name in sol.problem.cameras}
    row_cameras = {ir.view: ir.row_cameras for ir in sol.instant_rows}
    for view, e in sol.held_out_residuals().items():
        if e is None:
            continue
        per_instant[view] = {"rms_px": float(np.sqrt(2 * np.mean(e ** 2))), "corners": len(e) // 2}
        for c in np.unique(row_cameras[view]):
            ec = e[row_cameras[view] == c]
            per_camera[sol.problem.cameras[c]][view] = {"rms_px": float(np.sqrt(2 * np.mean(ec ** 2))),
                                                        "corners": len(ec) // 2}
    squares = sum(d["rms_px"] ** 2 * d["corners"] for d in per_instant.values())
    corners = sum(d["corners"] for d in per_instant.values())
    return {"held_out_rms_px": float(np.sqrt(squares / corners)) if corners else None,
            "held_out_per_instant": per_instant, "held_out_per_camera": per_camera}


def rig_model_from_solution(sol: Solution, corners: CornerSet, dropped: list[dict],
                            dropped_corners: list[dict] = ()) -> RigModel:
    """Package an adjustment result as the :class:`RigModel` written to calib.json (no checks)."""
    p, st = sol.problem, sol.state
    names = p.cameras
    cams = {name: st.camera(p, c) for c, name in enumerate(names)}
    names_cov, covs = parameter_covariance(sol, COVARIANCE_KINDS)
    sd = {kind: dict(zip(names_cov, np.sqrt(np.maximum(np.diag(cov), 0.0)))) for kind, cov in covs.items()}
    sigma_formal = {name: {n: sd["formal"].get(intrinsic_name(name, n), 0.0) for n in INTRINSIC_NAMES}
                    for name in names}
    sigma = {name: {n: max(sd["clustered"].get(intrinsic_name(name, n), 0.0), s)
                    for n, s in sigma_formal[name].items()} for name in names}
    fit = fit_summary(sol)
    view_rms: dict[str, dict[str, float]] = {}
    for b, (c, v, _) in enumerate(p.blocks):
        view_rms.setdefault(v, {})[names[c]] = sol.block_rms_px[b]
    poses: dict[str, dict[str, Pose]] = {name: {} for name in names}
    for (c, v), pose in sorted(_block_poses(sol).items(), key=lambda kv: kv[0][1]):
        poses[names[c]][v] = pose
    rig = {}
    for c, name in enumerate(names):
        if c == p.reference:
            continue
        if p.mode == "none" and not shared_views(p, c):
            warn(f"camera {name!r} shares no view with {names[p.reference]!r}: no rig relation for it")
            continue
        pose, *clustered = rig_relation(sol, c, "clustered")
        _, *formal = rig_relation(sol, c, "formal", warn_gimbal=False)
        sigma_t, sigma_d, sigma_opk = (np.maximum(a, b) for a, b in zip(clustered, formal))
        rel = relative_sigma(corners.board)          # the printed squares' tolerance: every length scales
        rig[name] = RigRelation(pose, with_scale(sigma_t, pose.t_mm, rel),
                                float(with_scale(sigma_d, np.linalg.norm(pose.t_mm), rel)), sigma_opk,
                                dict(zip(("t_mm", "baseline_mm", "opk_arcmin"), formal)))
    adjustment = {"s0_px": sol.s0_px, "redundancy": sol.redundancy, "iterations": sol.iterations,
                  "converged": sol.converged, "termination": sol.termination,
                  "n_observations": p.n_observations, "n_parameters": p.n_parameters,
                  **{k: fit[k] for k in ("held_out_rms_px", "held_out_per_instant", "held_out_per_camera")}}
    shape = shape_sigma = None
    if p.board_shape:
        shape = st.board_shape_mm.copy()
        shape_sigma = np.array([max(sd[kind][f"board.shape_mm.{t}"] for kind in COVARIANCE_KINDS) for t in SHAPE_TERMS])
    covariance = JointCovariance(tuple(names_cov), covs).to_dict()
    return RigModel(corners.board, names[p.reference], p.skew, p.mode, cams, sigma, fit["camera_rms_px"], rig, poses,
                    dict(sorted(view_rms.items())), fit["rms_px"], corners, adjustment, dropped,
                    sigma_formal, shape, shape_sigma, list(dropped_corners), {}, covariance)
