"""From corners to a calibrated rig: initialisation, joint adjustment, outlier views.

:func:`calibrate_rig` is the whole of the paper's sections 1.3 to 1.7 for any number of cameras:
Zhang's closed form per camera (:mod:`dualcal.zhang`), the rig's relative poses from the views
the cameras share, then the joint adjustment (:mod:`dualcal.adjust`) in the chosen rig mode.
Each photo contributes the corners it measured; one whose corners cannot fix a homography (fewer
than 4, or all on one line) is skipped with a warning. Photos whose residuals are far out of line
with the others are dropped one at a time, each with a recorded reason, and the adjustment is
repeated. A final adjustment that did not converge is said so, on stderr and in calib.json.
"""

from __future__ import annotations

import numpy as np

from .adjust import Problem, Solution, adjust, cost, initial_state, rig_relation, shared_views
from .camera import DEFAULT_LENS_MODEL, LENS_MODELS
from .errors import EstimationError, InputError
from .model import CornerSet, Pose, RigModel, RigRelation, choose_reference, observed_mask
from .progress import warn
from .zhang import MIN_HOMOGRAPHY_CORNERS, initial_camera, spans_a_plane

MIN_VIEWS = 3


def usable_photos(corners: CornerSet, names: list[str], xy_board: np.ndarray) -> list[tuple[int, str, np.ndarray]]:
    """``(camera index, view, (N, 2) corners)`` of every photo whose measured corners determine a
    homography: at least :data:`dualcal.zhang.MIN_HOMOGRAPHY_CORNERS`, not all on one line. Every
    other photo where the board was found is skipped with a warning naming it."""
    blocks = []
    for c, name in enumerate(names):
        for v, uv in sorted(corners.cameras[name].found().items()):
            seen = observed_mask(uv)
            if seen.sum() < MIN_HOMOGRAPHY_CORNERS or not spans_a_plane(xy_board[seen]):
                warn(f"{name}/{v} skipped: its {int(seen.sum())} measured corner(s) "
                     f"{'lie on one line' if seen.sum() >= MIN_HOMOGRAPHY_CORNERS else 'are too few'}; "
                     f"a photo needs at least {MIN_HOMOGRAPHY_CORNERS} corners, not all on one line")
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
    poses = [{v: bp[(c, v)] for cc, v, _ in sol.problem.blocks if cc == c} for c in range(n)]
    return cams, poses


def solve(X_board, names, sizes, blocks, reference: int, skew: bool, mode: str,
          start: Solution | None = None, model: str = DEFAULT_LENS_MODEL) -> Solution:
    """Initialise and adjust one rig (no outlier handling). ``blocks``: (camera, view, uv) triples;
    ``model``: the lens model of every camera (:data:`dualcal.camera.LENS_MODELS`).

    Starting values come from Zhang's closed form per camera, or from ``start``, an earlier
    solution over the same photos with every camera alone (rig mode ``none``). The paper's model
    starts from the better (lower cost) of the rigid solution (every instant's baseline direction
    the same) and the cameras-alone solution (each instant's own relative pose): the first is
    the nearer when the rig is rigid, the second when the direction moves between instants.
    """
    _check_enough_views(blocks, names)
    if mode == "paper" and start is None:
        start = solve(X_board, names, sizes, blocks, reference, skew, "none", model=model)
    if start is not None:
        cams, poses = _starting_values(start)
    else:
        cams, poses = [], []
        for c, size in enumerate(sizes):
            cam, p = initial_camera(X_board[:, :2], {v: uv for cc, v, uv in blocks if cc == c}, size, skew, model)
            cams.append(cam)
            poses.append(p)
    first_mode = "rigid" if mode == "paper" else mode
    problem = Problem(X_board, list(names), list(sizes), blocks, first_mode, skew, reference, model)
    sol = adjust(problem, initial_state(problem, cams, poses))
    if mode != "paper":
        return sol
    problem = Problem(X_board, list(names), list(sizes), blocks, "paper", skew, reference, model)
    starts = [initial_state(problem, *_starting_values(s)) for s in (sol, start)]
    return adjust(problem, min(starts, key=lambda state: cost(problem, state)))


OUTLIER_FLOOR_PX = 0.05


def outlier_limit_px(camera_median_px: float, factor: float) -> float:
    """RMS above which a photo is out of line: ``factor`` x the median photo RMS of its own camera
    (cameras differ in noise), but never below :data:`OUTLIER_FLOOR_PX`. The report uses it too."""
    return max(factor * camera_median_px, OUTLIER_FLOOR_PX)


def find_outlier(sol: Solution, factor: float):
    """The photo furthest above its camera's outlier limit, as ``(block, rms, limit)``, or None."""
    rms = np.asarray(sol.block_rms_px)
    cams = np.array([c for c, _, _ in sol.problem.blocks])
    limit = np.empty_like(rms)
    for c in np.unique(cams):
        limit[cams == c] = outlier_limit_px(float(np.median(rms[cams == c])), factor)
    worst = int(np.argmax(rms / limit))
    if rms[worst] <= limit[worst]:
        return None
    return worst, float(rms[worst]), float(limit[worst])


def _views_left(blocks, c: int) -> int:
    return sum(1 for blk in blocks if blk[0] == c)


def _adjust_dropping_outliers(X, names, sizes, blocks, ref, skew, mode, factor, dropped, start=None,
                              model: str = DEFAULT_LENS_MODEL):
    """Solve, drop the worst photo while one is out of line, solve again; returns (solution, blocks).

    In a tied rig a bad photo pulls the shared pose and so spreads its error over every photo of
    that instant; of the photos of the flagged instant that are themselves out of line, the one
    whose removal fits best is dropped, and only if the fit then really improves.
    """
    sol = solve(X, names, sizes, blocks, ref, skew, mode, start, model)
    while True:
        out = find_outlier(sol, factor) if factor else None
        if out is None:
            return sol, blocks
        b, rms, limit = out
        view = blocks[b][1]
        if mode == "none":
            candidates = [b]
        else:
            cams = np.array([blk[0] for blk in blocks])
            rms_all = np.asarray(sol.block_rms_px)
            candidates = [i for i, blk in enumerate(blocks) if blk[1] == view and rms_all[i] > outlier_limit_px(
                float(np.median(rms_all[cams == blk[0]])), factor)]
        candidates = [i for i in candidates if _views_left(blocks, blocks[i][0]) > MIN_VIEWS]
        if not candidates:
            warn(f"{names[blocks[b][0]]}/{view} is out of line (RMS {rms:.3g} px, limit {limit:.3g} px) "
                 f"but cannot be dropped: only {MIN_VIEWS} views left for {names[blocks[b][0]]!r}")
            return sol, blocks
        trials = [(solve(X, names, sizes, blocks[:i] + blocks[i + 1:], ref, skew, mode, model=model), i)
                  for i in candidates]
        best, i = min(trials, key=lambda t: t[0].s0_px)
        if best.s0_px >= sol.s0_px:
            warn(f"{names[blocks[b][0]]}/{view} is out of line (RMS {rms:.3g} px, limit {limit:.3g} px) "
                 "but dropping it does not improve the fit: kept")
            return sol, blocks
        c, rms_i = blocks[i][0], sol.block_rms_px[i]
        reason = (f"reprojection RMS {rms_i:.3g} px above the limit {limit:.3g} px ({factor:g} x the median "
                  f"of {names[c]!r}) in rig mode {mode}; without it s0 falls from {sol.s0_px:.3g} to "
                  f"{best.s0_px:.3g} px (moved board, wrong corner order, blur, or another zoom/focus setting?)")
        warn(f"dropping {names[c]}/{view}: {reason}")
        dropped.append({"camera": names[c], "view": view, "rms_px": rms_i, "reason": reason})
        sol, blocks = best, blocks[:i] + blocks[i + 1:]


def calibrate_rig(corners: CornerSet, skew: bool = False, rig_mode: str = "rigid",
                  reference: str | None = None, drop_outliers: bool = True,
                  outlier_factor: float = 3.0, model: str = DEFAULT_LENS_MODEL) -> RigModel:
    """Calibrate every camera of a rig and the rig itself from chessboard corners.

    Parameters
    ----------
    corners : the detected corners (corners.json content)
    skew : False fixes skew = 0 (the paper's Model 1), True estimates it (Model 2)
    rig_mode : ``rigid``, ``paper`` or ``none`` (see :mod:`dualcal.adjust`)
    reference : name of the reference camera (default: the one recorded in ``corners``, else ``wide``,
        else the first name)
    drop_outliers : drop photos whose RMS exceeds ``outlier_factor`` x the median, one at a time.
        Outliers are looked for first with every camera adjusted alone (so that a bad photo shows
        in its own camera's residuals, not spread over the rig), then in ``rig_mode`` (which
        also reveals a board moved between the shots of one instant).
    model : the lens model of every camera, a key of :data:`dualcal.camera.LENS_MODELS`:
        ``k1k2`` (the paper's), ``k1k2k3``, ``k1k2p1p2`` or ``k1k2p1p2k3`` (OpenCV's five coefficients)

    Raises
    ------
    InputError
        An unknown lens model.
    EstimationError
        Fewer than 3 usable views for a camera, degenerate views, no shared view in a rig.
    """
    if model not in LENS_MODELS:
        raise InputError(f"--model {model!r} is unknown (choose from {', '.join(LENS_MODELS)})")
    names = sorted(corners.cameras)
    ref = names.index(choose_reference(names, reference if reference is not None else corners.reference))
    sizes = [corners.cameras[n].image_size for n in names]
    X = corners.board.object_points_mm()
    blocks = usable_photos(corners, names, X[:, :2])
    dropped: list[dict] = []
    factor = outlier_factor if drop_outliers else None
    alone = None
    if factor and rig_mode != "none":
        alone, blocks = _adjust_dropping_outliers(X, names, sizes, blocks, ref, skew, "none", factor, dropped,
                                                  model=model)
    sol, _ = _adjust_dropping_outliers(X, names, sizes, blocks, ref, skew, rig_mode, factor, dropped, alone, model)
    if not sol.converged:
        warn(f"the adjustment (rig mode {rig_mode}, {'Model 2' if skew else 'Model 1'}) did not converge: "
             f"{sol.termination}; the results and their sigmas are not those of the best fit")
    rig = rig_model_from_solution(sol, corners, dropped)
    rig.adjustment["options"] = {"drop_outliers": bool(drop_outliers), "outlier_factor": float(outlier_factor),
                                 "model": model}
    return rig


def rig_model_from_solution(sol: Solution, corners: CornerSet, dropped: list[dict]) -> RigModel:
    """Package an adjustment result as the :class:`RigModel` written to calib.json."""
    p, st = sol.problem, sol.state
    names = p.cameras
    sq = np.sum(sol.residuals ** 2, axis=2)                 # (B, N) squared px, NaN where not measured
    cams = {name: st.camera(p, c) for c, name in enumerate(names)}
    sigma = {name: sol.intrinsic_sigma(c) for c, name in enumerate(names)}
    cam_rms = {}
    for c, name in enumerate(names):
        mask = [cc == c for cc, _, _ in p.blocks]
        cam_rms[name] = float(np.sqrt(np.nanmean(sq[mask])))
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
        rig[name] = RigRelation(*rig_relation(sol, c))
    adjustment = {"s0_px": sol.s0_px, "redundancy": sol.redundancy, "iterations": sol.iterations,
                  "converged": sol.converged, "termination": sol.termination,
                  "n_observations": p.n_observations, "n_parameters": p.n_parameters}
    return RigModel(corners.board, names[p.reference], p.skew, p.mode, cams, sigma, cam_rms, rig, poses,
                    dict(sorted(view_rms.items())), float(np.sqrt(np.nanmean(sq))), corners, adjustment, dropped)
