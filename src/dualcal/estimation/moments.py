"""Which frames of a clip to calibrate from: the board held still, and among those the moments that add most.

Most frames of a calibration clip show the board moving: blurred, and (with a rolling shutter, or a
residual offset between two cameras' clocks) with corners where no single pose puts them. Frames taken
where it is held still escape all three. And neighbouring frames say nearly the same thing: a moment
counts once however many of its frames are used (:mod:`dualcal.estimation.duplicates`: the instants of
one moment are one).

1. **Still frames.** A camera's frame is still when its measured corners moved less than
   :data:`STILL_PX` per frame (RMS over the corners, full-resolution pixels) both since the frame
   before and until the frame after. A run of at least :data:`MIN_RUN` such frames is a hold.
2. **Moments.** On the reference's clock (each camera's offset added), the holds of the cameras that
   overlap are one moment; its time is the middle of their common part (of the longest hold where
   they do not overlap), snapped to the reference's frame nearest it, and each camera's view of it is its
   frame nearest that time, where that frame is still (else the camera has no view of it). A camera
   whose clock is not matched (no offset) has moments of its own.
3. **The choice.** Greedily, the moment whose corners shrink the key sigmas most (the information
   measure of :mod:`dualcal.estimation.advise`: a new instant's information, its pose eliminated, on a
   nominal prior of the lenses and the rig from Zhang's closed form), until :data:`MAX_INSTANTS` are
   chosen or the next adds less than :data:`MIN_GAIN`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import EstimationError
from ..geometry.board import Board
from ..geometry.model import mean_pose, observed_mask
from ..geometry.resection import planar_pose
from ..geometry.zhang import initial_camera

__all__ = ["MAX_INSTANTS", "MomentChoice", "choose_moments", "still_runs"]

#: Image motion below which a frame is still, full-resolution px per frame (RMS over the corners).
STILL_PX = 0.5
#: Frames a hold needs, at least.
MIN_RUN = 3
#: Moments chosen at most (a 30 s clip with the board held 15-40 times gives all of its holds).
MAX_INSTANTS = 40
#: A moment that shrinks the key sigmas (geometric mean) by less than this share is not chosen.
MIN_GAIN = 0.002


@dataclass
class MomentChoice:
    """The moments chosen: ``frames[camera][view key] -> frame index``; ``moment_of[view key]`` the moment's
    number (the holds in time order); per camera the count of ``still_frames`` and ``moment_count`` (the
    moments it saw) and ``not_used`` (why frames or moments were not chosen: counts by reason)."""

    frames: dict[str, dict[str, int]]
    moment_of: dict[str, int]
    still_frames: dict[str, int]
    moment_count: dict[str, int]
    not_used: dict[str, dict[str, int]] = field(default_factory=dict)


def still_runs(measured: dict[int, np.ndarray], still_px: float = STILL_PX,
               min_run: int = MIN_RUN) -> tuple[list[np.ndarray], dict[int, float]]:
    """Runs (each an array of consecutive frame indices) of still frames, and each measured frame's motion
    (px per frame, RMS over the corners seen in both frames: the larger of before and after; inf where a
    neighbour was not measured)."""
    if not measured:
        return [], {}
    frames = np.array(sorted(measured))
    span = np.full((frames[-1] - frames[0] + 3,) + measured[frames[0]].shape, np.nan)   # a NaN frame each side
    span[frames - frames[0] + 1] = [measured[j] for j in frames]
    with np.errstate(invalid="ignore"):
        d2 = np.sum(np.diff(span, axis=0) ** 2, axis=2)                  # (frames + 1, N): j-1 -> j at row j
        seen = np.isfinite(d2)
        step = np.sqrt(np.where(seen, d2, 0.0).sum(axis=1) / seen.sum(axis=1))
    step[~seen.any(axis=1)] = np.inf
    rows = frames - frames[0] + 1
    moving = np.maximum(step[rows - 1], step[rows])                    # since the frame before, until the next
    motion = dict(zip(frames.tolist(), moving.tolist()))
    still = frames[moving < still_px]
    runs = np.split(still, np.flatnonzero(np.diff(still) > 1) + 1) if len(still) else []
    return [r for r in runs if len(r) >= min_run], motion


def _moments(holds: dict[str, list[tuple[float, float]]]) -> list[dict[str, tuple[float, float, int]]]:
    """Groups of overlapping holds ``(start_s, end_s)`` across cameras (time order): ``{camera: (start_s,
    end_s, index of the hold)}`` (a camera's longest where two of its holds fall in one group)."""
    events = sorted((a, b, name, k) for name, hs in holds.items() for k, (a, b) in enumerate(hs))
    groups, end = [], -np.inf
    for a, b, name, k in events:
        if a > end:
            groups.append({})
        g = groups[-1]
        if name not in g or b - a > g[name][1] - g[name][0]:
            g[name] = (a, b, k)
        end = max(end, b)
    return groups


def _moment_time(group: dict[str, tuple[float, float, int]]) -> float:
    a = max(h[0] for h in group.values())
    b = min(h[1] for h in group.values())
    if a <= b:
        return 0.5 * (a + b)
    longest = max(group.values(), key=lambda h: h[1] - h[0])
    return 0.5 * (longest[0] + longest[1])


def _nominal_prior(candidates, board: Board, sizes, reference: str):
    """The advice's nominal prior on the cameras and the rig that ``candidates`` (``{camera: uv}`` each) show,
    and each candidate's board pose in the reference's frame with the corners each camera saw."""
    from .advise import nominal_prior

    xy = board.object_points_mm()[:, :2]
    X = board.object_points_mm()
    names = sorted({n for c in candidates for n in c}, key=lambda n: (n != reference, n))
    cams = {}
    for n in names:
        views = {str(i): c[n] for i, c in enumerate(candidates) if n in c}
        if len(views) < 3:
            raise EstimationError(f"camera {n!r} holds the board still in fewer than 3 moments")
        cams[n] = initial_camera(xy, views, sizes[n])[0]
    poses = [{n: planar_pose(X, cams[n], uv) for n, uv in c.items()} for c in candidates]
    rig = {}
    for n in names[1:]:
        rel = [p[n].compose(p[reference].inverse()) for p in poses if n in p and reference in p]
        if not rel:
            raise EstimationError(f"camera {n!r} never holds the board still at a moment the reference does")
        rig[n] = mean_pose(rel)
    prior = nominal_prior(cams, board, reference, rig)
    board_poses = [p[reference] if reference in p else next(rig[n].inverse().compose(p[n]) for n in p)
                   for p in poses]
    return prior, [(bp, {n: observed_mask(uv) for n, uv in c.items()}) for bp, c in zip(board_poses, candidates)]


def rank_by_information(candidates, board: Board, sizes, reference: str, count: int) -> list[int]:
    """Indices of up to ``count`` of ``candidates`` (``{camera: (N, 2) corners}`` each), the one that shrinks
    the key sigmas most first, each given those before it (module docstring, step 3)."""
    from .advise import _objective, instant_information, key_targets, target_gradients, updated_covariance

    prior, cands = _nominal_prior(candidates, board, sizes, reference)
    gradients = target_gradients(prior)
    by_camera = key_targets(gradients)
    names = [n for g in by_camera.values() for n in g]
    pos = {n: i for i, n in enumerate(names)}
    groups = [np.array([pos[n] for n in g]) for g in by_camera.values()]
    G = np.array([gradients[n] for n in names])
    C = prior.covariance
    ref = np.sqrt(np.einsum("tk,kl,tl->t", G, C, G))
    info = np.array([instant_information(prior, pose, seen) for pose, seen in cands])
    score_now = _objective(ref[None], ref, groups, False)[0]
    left, chosen = list(range(len(cands))), []
    while left and len(chosen) < count:
        Cs = updated_covariance(C, info[left])
        score = _objective(np.sqrt(np.maximum(np.einsum("tk,mkl,tl->mt", G, Cs, G), 0.0)), ref, groups, False)
        best = int(np.argmin(score))
        if len(chosen) >= 3 and 1.0 - np.exp(score[best] - score_now) < MIN_GAIN:
            break
        chosen.append(left.pop(best))
        C, score_now = Cs[best], float(score[best])
    return chosen


def choose_moments(tracks: dict[str, tuple[np.ndarray, dict[int, np.ndarray]]], board: Board, reference: str,
                   offsets: dict[str, float | None], sizes: dict[str, tuple[int, int]],
                   max_instants: int = MAX_INSTANTS, still_px: float = STILL_PX) -> MomentChoice:
    """The moments to calibrate from (module docstring).

    Parameters
    ----------
    tracks : ``{camera: (times_s (F,), corners {frame: (N, 2)})}``: each frame's time from its clip's first,
        and the board's corners as tracked in the frames that can be chosen (where it barely moved).
    reference : the reference camera; its clock is the common one.
    offsets : each camera's offset (s, :mod:`dualcal.estimation.time_offset`), None where its clock is not matched.
    sizes : each camera's image size.
    """
    times_ref = tracks[reference][0]
    fps_ref = 1.0 / float(np.median(np.diff(times_ref))) if len(times_ref) > 1 else 30.0
    runs, holds, still = {}, {}, {}
    for name, (times, measured) in tracks.items():
        runs[name], _ = still_runs(measured, still_px)
        still[name] = int(sum(len(r) for r in runs[name]))
        off = offsets.get(name)
        holds[name] = [(times[r[0]] + (off or 0.0), times[r[-1]] + (off or 0.0)) for r in runs[name]]
    matched = {n for n in tracks if n == reference or offsets.get(n) is not None}
    groups = [(g, True) for g in _moments({n: holds[n] for n in matched})]
    groups += [({n: (*h, k)}, False) for n in tracks if n not in matched for k, h in enumerate(holds[n])]
    candidates, keys = [], []
    for g, on_reference_clock in groups:
        t = _moment_time(g)
        views = {}
        if reference in g:                   # the moment is the reference's frame nearest it
            run = runs[reference][g[reference][2]]
            t = float(times_ref[run[np.argmin(np.abs(times_ref[run] - t))]])
        for name, (_, _, k) in g.items():
            times = tracks[name][0]
            run = runs[name][k]
            gap = np.abs(times[run] + (offsets.get(name) or 0.0) - t)
            # its frame nearest the moment, where it held the board still then (not before or after)
            if gap.min() <= 0.5 * np.median(np.diff(times)) + 1e-6:
                views[name] = int(run[np.argmin(gap)])
        if not views:
            continue
        if on_reference_clock:
            i = int(np.argmin(np.abs(times_ref - t))) if times_ref[0] <= t <= times_ref[-1] else int(round(t * fps_ref))
            key = f"f{i:06d}"
        else:
            (name, j), = views.items()
            key = f"{name}:f{j:06d}"
        candidates.append({n: tracks[n][1][j] for n, j in views.items()})
        keys.append((key, views, {n: len(runs[n][k]) for n, (_, _, k) in g.items() if n in views}))
    count = {n: sum(n in c for c in candidates) for n in tracks}
    if len(candidates) > 3:
        try:
            order = rank_by_information(candidates, board, sizes, reference, max_instants)
        except (EstimationError, np.linalg.LinAlgError):        # no prior to rank by: the first ones
            order = list(range(min(len(candidates), max_instants)))
    else:
        order = list(range(len(candidates)))
    frames = {n: {} for n in tracks}
    moment_of = {}
    little = dict.fromkeys(tracks, 0)
    for m, (key, views, held) in enumerate(keys):
        if m not in order:
            for n, length in held.items():
                little[n] += length
            continue
        moment_of[key] = m
        for n, j in views.items():
            frames[n][key] = j
    not_used = {n: {"held, another frame of its moment chosen": still[n] - little[n] - len(frames[n]),
                    "held, its moment adds little": little[n]} for n in tracks}
    return MomentChoice(frames, moment_of, still, count, not_used)
