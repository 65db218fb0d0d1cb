"""How far apart two cameras' clips are in time, from the board's motion that both see.

Two streams that one app starts are not frame-aligned: a few frames of start-up delay and a fraction of
a frame between the sensors. The offset ``d`` of camera ``c`` is the reference's clock time (seconds from
the reference's first frame) at which ``c``'s first frame was exposed (CONTRACT.md, "Video"), so ``c``'s
frame at its own time ``t`` shows the board as the reference saw it at ``t + d``. It is found in two steps,
on the board tracked in every frame (no file is read here):

1. **Coarse**, by cross-correlating the board's image speed. Each frame's speed is the RMS motion of its
   corners since the frame before, in board diagonals per second (so a tele and a wide, which see the
   board at different scales, give the same curve); a frame without the board counts as moving fast (the
   board blurred or carried out of view). The lag where the two curves' normalised cross-correlation
   peaks, searched in quarter frames, is the start.
2. **Refined**, from the rig's rigidity. With each camera's lens adjusted on a few of its tracked frames
   (:func:`rough_camera`) and the board's pose in every frame (space
   resection), camera ``c``'s frame at ``t`` must show the board where the reference's pose at ``t + d``,
   interpolated through its three frames nearest that moment (a parabola: the board accelerates),
   carried by the rig's relative pose ``T``, puts it. ``d`` and ``T`` are adjusted together
   (Gauss-Newton on the pixel residuals of every corner of every frame where both saw the board), frames
   that do not fit dropped (3 x the median misfit). Only frames where the board moves inform ``d``; the
   still ones fix ``T``.

The sigma of ``d`` is the largest of :data:`FLOOR_FRAMES` of a frame, the textbook one and the one clustered
by the board's motions from one hold to the next (the sandwich of :mod:`dualcal.estimation.uncertainty`'s idea, here for one parameter, with
the small-sample factor ``G / (G - 1)``): the frames of one motion share the errors of its poses, its blur
and the lens model's error where it passes, so their residuals are not independent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import EstimationError
from ..geometry.board import Board
from ..geometry.camera import CameraModel, ideal_normalized_from_pixel, project_points
from ..geometry.rotation import nearest_rotation, rotation_from_rotvec, rotvec_from_rotation
from ..geometry.zhang import initial_camera
from ..progress import collect_warnings

__all__ = ["TimeOffset", "board_speed", "coarse_offset", "estimate_offsets", "refine_offset"]

#: The coarse search spans at most this many seconds either way (and at most 40 % of the shorter clip).
MAX_LAG_S = 3.0
#: Speeds above this (board diagonals per second) count as this: the curve's shape is in its pauses.
SPEED_CAP = 1.0
#: The coarse peak must reach this correlation, else the clips are not matched.
MIN_CORRELATION = 0.3
#: Frames both cameras saw the board in, at least, for the refinement.
MIN_FRAMES = 10
#: Tracked frames the lens of :func:`rough_camera` is adjusted on, per camera (spread over the clip).
ZHANG_VIEWS = 25
#: The sigma is at least this share of a frame: what the residuals cannot show, the interpolation between
#: the reference's frames and the lens's own error, left the offset up to 0.002 frames off on exact
#: synthetic tracks (a rolling shutter, whose rows are exposed at different times, adds more: 0.3 ms
#: of 15 ms readout where the board sat in other rows of the two images).
FLOOR_FRAMES = 0.005


@dataclass
class TimeOffset:
    """A camera's offset from the reference: ``offset_s`` (module docstring) and its 1-sigma, the coarse
    start and its peak correlation, and how many of its frames the refinement used."""

    offset_s: float
    sigma_s: float
    coarse_s: float
    correlation: float
    frames: int


def board_speed(times_s: np.ndarray, uv_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The board's image speed between consecutive frames (module docstring, step 1).

    Parameters
    ----------
    times_s : (F,) frame times.
    uv_px : (F, N, 2) corners, NaN rows where the board was not found.

    Returns
    -------
    t_s : (F - 1,) the middle of each frame interval; speed : (F - 1,) board diagonals per second,
    NaN where either frame lacks the board.
    """
    d = np.sqrt(np.mean(np.sum(np.diff(uv_px, axis=0) ** 2, axis=2), axis=1))
    diag = np.linalg.norm(uv_px[:, -1] - uv_px[:, 0], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = d / diag[1:] / np.diff(times_s)
    return 0.5 * (times_s[1:] + times_s[:-1]), speed


def _speed_signal(times_s, uv_px):
    t, s = board_speed(times_s, uv_px)
    return t, np.where(np.isfinite(s), np.minimum(s, SPEED_CAP), SPEED_CAP) / SPEED_CAP


def coarse_offset(ref: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray],
                  fps: float) -> tuple[float, float]:
    """The lag (s) that best lines the other camera's speed curve up with the reference's, and the
    correlation there (module docstring, step 1). ``ref``, ``other``: ``(times_s, uv_px)`` of each."""
    tr, sr = _speed_signal(*ref)
    to, so = _speed_signal(*other)
    span = min(tr[-1] - tr[0], to[-1] - to[0]) if len(tr) > 1 and len(to) > 1 else 0.0
    limit = min(MAX_LAG_S, 0.4 * span)
    best = (0.0, -np.inf)
    for lag in np.arange(-limit, limit + 1e-9, 0.25 / fps):
        t = to + lag
        inside = (t >= tr[0]) & (t <= tr[-1])
        if inside.sum() < MIN_FRAMES:
            continue
        a = np.interp(t[inside], tr, sr)
        b = so[inside]
        a, b = a - a.mean(), b - b.mean()
        denom = np.sqrt(np.sum(a * a) * np.sum(b * b))
        r = float(np.sum(a * b) / denom) if denom > 0 else -np.inf
        if r > best[1]:
            best = (float(lag), r)
    return best


def rough_camera(uv_px: np.ndarray, board: Board, image_size) -> CameraModel:
    """A camera's lens from :data:`ZHANG_VIEWS` of its tracked frames (spread over the clip): Zhang's closed
    form, then adjusted alone (k1, k2; :func:`dualcal.estimation.calibrate.calibrate_rig`). The closed form
    alone left the offset 0.3 ms off on synthetic tracks, the adjusted lens 0.03 ms."""
    from ..geometry.model import CameraCorners, CornerSet
    from .calibrate import calibrate_rig

    found = np.flatnonzero(np.isfinite(uv_px[:, :, 0]).all(axis=1))
    if len(found) < 3:
        raise EstimationError("the board was found in fewer than 3 frames")
    pick = found[np.unique(np.linspace(0, len(found) - 1, min(len(found), ZHANG_VIEWS)).round().astype(int))]
    views = {f"{j}": uv_px[j] for j in pick}
    try:
        corners = CornerSet(board, {"camera": CameraCorners(tuple(image_size), views)})
        with collect_warnings():
            return calibrate_rig(corners, rig_mode="none", board_shape="flat", drop_outliers=False).cameras["camera"]
    except EstimationError:
        return initial_camera(board.object_points_mm()[:, :2], views, image_size)[0]


def frame_poses(cam: CameraModel, uv_px: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation (F, 3, 3), translation (F, 3) and validity (F,) of the board's pose in every frame where the
    whole board was tracked (space resection by IPPE on the undistorted corners, as
    :func:`dualcal.geometry.resection.planar_pose`, every frame's corners undistorted at once)."""
    import cv2

    F = len(uv_px)
    R, t, ok = np.tile(np.eye(3), (F, 1, 1)), np.zeros((F, 3)), np.zeros(F, bool)
    whole = np.flatnonzero(np.isfinite(uv_px[:, :, 0]).all(axis=1))
    if not len(whole):
        return R, t, ok
    xy = ideal_normalized_from_pixel(cam, uv_px[whole].reshape(-1, 2)).reshape(len(whole), -1, 2)
    flat = np.column_stack([board.object_points_mm()[:, :2], np.zeros(board.n_corners)])
    rvecs = np.zeros((F, 3))
    for j, pts in zip(whole, xy):
        found, rvec, tvec = cv2.solvePnP(flat, pts, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
        if found:
            rvecs[j], t[j], ok[j] = rvec.ravel(), tvec.ravel(), True
    R[ok] = rotation_from_rotvec(rvecs[ok])
    return R, t, ok


def _interpolated(times_s, R, t, ok, at_s):
    """The reference's pose at times ``at_s``, by the parabola through its three frames nearest each
    (rotations as rotation vectors relative to the middle frame's, which stay small); valid only where the
    three have a pose and are evenly spaced (no frame dropped between them)."""
    m = np.clip(np.searchsorted(times_s, at_s - 0.5 * np.median(np.diff(times_s))), 1, len(times_s) - 2)
    t0, t1, t2 = times_s[m - 1], times_s[m], times_s[m + 1]
    typical = np.median(np.diff(times_s))
    valid = (ok[m - 1] & ok[m] & ok[m + 1] & (np.abs(at_s - t1) <= 0.75 * typical)
             & (t2 - t0 < 2.5 * typical))
    # Lagrange weights of the three frames at at_s
    w0 = (at_s - t1) * (at_s - t2) / ((t0 - t1) * (t0 - t2))
    w1 = (at_s - t0) * (at_s - t2) / ((t1 - t0) * (t1 - t2))
    w2 = (at_s - t0) * (at_s - t1) / ((t2 - t0) * (t2 - t1))
    Rm_T = np.swapaxes(R[m], 1, 2)
    v = (w0[:, None] * rotvec_from_rotation(R[m - 1] @ Rm_T) + w2[:, None] * rotvec_from_rotation(R[m + 1] @ Rm_T))
    Ri = rotation_from_rotvec(v) @ R[m]
    ti = w0[:, None] * t[m - 1] + w1[:, None] * t[m] + w2[:, None] * t[m + 1]
    return Ri, ti, valid


def _residuals(params, ref, other, cam, X, frames):
    """Pixel residuals (n, N*2) of the other camera's ``frames`` for offset ``params[0]`` and the rig's
    relative pose ``exp(params[1:4]) R0``, ``t0 + params[4:7]`` (``(R0, t0) = cam[1]``), NaN where the
    reference has no pose at that moment."""
    (times_r, R_r, t_r, ok_r), (times_o, uv_o), (R0, t0) = ref, other, cam[1]
    d = params[0]
    Rig = rotation_from_rotvec(params[1:4]) @ R0
    tig = t0 + params[4:7]
    Ri, ti, valid = _interpolated(times_r, R_r, t_r, ok_r, times_o[frames] + d)
    Xr = np.einsum("fij,nj->fni", Ri, X) + ti[:, None, :]
    Xc = Xr @ Rig.T + tig
    uv = project_points(cam[0], Xc.reshape(-1, 3)).reshape(len(frames), -1, 2)
    r = (uv - uv_o[frames]).reshape(len(frames), -1)
    r[~valid] = np.nan
    return r


def _motions(frames: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """Cluster numbers of ``frames``: one per motion of the board from one hold to the next (a new one
    after every frame where it is still, moving less than a pixel, or after a frame it was not seen in)."""
    moved = np.full(len(uv_px), np.inf)
    moved[1:] = np.sqrt(np.mean(np.sum(np.diff(uv_px, axis=0) ** 2, axis=2), axis=1))
    calm = ~(moved > 1.0)                                              # still, or not seen (NaN)
    starts = np.cumsum(calm[:-1] & ~calm[1:])                          # motions begun up to each frame
    return np.r_[0, starts][frames]


def refine_offset(ref, other, cam_other: CameraModel, board: Board, start_s: float,
                  iterations: int = 12) -> tuple[float, float, int]:
    """Offset (s), its sigma (s) and the frames used (module docstring, step 2).

    ``ref``: the reference's ``(times_s, R (F, 3, 3), t (F, 3), ok (F,))`` board poses; ``other``: the other
    camera's ``(times_s, uv_px (F, N, 2), R, t, ok)``.

    Raises
    ------
    EstimationError
        Fewer than :data:`MIN_FRAMES` frames where both cameras saw the board at one moment.
    """
    times_o, uv_o, R_o, t_o, ok_o = other
    X = board.object_points_mm()
    frames = np.flatnonzero(ok_o & np.isfinite(uv_o[:, :, 0]).all(axis=1))
    Ri, ti, valid = _interpolated(*ref, times_o[frames] + start_s)
    frames, Ri, ti = frames[valid], Ri[valid], ti[valid]
    if len(frames) < MIN_FRAMES:
        raise EstimationError(f"the board was seen by both cameras at once in only {len(frames)} frames")
    # the rig's relative pose: the mean of each frame's (other camera's pose) o (reference's pose)^-1
    rel_R = R_o[frames] @ np.swapaxes(Ri, 1, 2)
    R0 = nearest_rotation(rel_R.sum(axis=0))
    t0 = np.median(t_o[frames] - np.einsum("ij,fj->fi", R0, ti), axis=0)
    base = (cam_other, (R0, t0))
    steps = np.array([1e-4, 1e-5, 1e-5, 1e-5, 1e-3, 1e-3, 1e-3])

    def rows(params, which):
        """Residuals (n, 2N) and their Jacobian (n, 2N, 7) of the frames ``which`` that can be compared."""
        r = _residuals(params, ref, (times_o, uv_o), base, X, which)
        J = np.stack([(_residuals(params + np.eye(7)[k] * steps[k], ref, (times_o, uv_o), base, X, which) - r)
                      / steps[k] for k in range(7)], axis=-1)
        fin = np.isfinite(r).all(axis=1) & np.isfinite(J).all(axis=(1, 2))
        return r[fin], J[fin], which[fin]

    params = np.array([start_s, 0, 0, 0, 0, 0, 0], float)
    used = frames
    for it in range(iterations):
        r, J, used = rows(params, used)
        if it == 2:                                  # once near: frames that do not fit are dropped
            rms = np.sqrt(np.mean(r ** 2, axis=1))
            fit = rms <= 3 * np.median(rms)
            r, J, used = r[fit], J[fit], used[fit]
        Jf = J.reshape(-1, 7)
        delta = np.linalg.lstsq(Jf.T @ Jf, -Jf.T @ r.reshape(-1), rcond=None)[0]
        params = params + delta
        if abs(delta[0]) < 1e-7 and it >= 3:
            break
    r, J, used = rows(params, used)
    if len(used) < MIN_FRAMES:
        raise EstimationError(f"the board was seen by both cameras at once in only {len(used)} frames")
    Jf = J.reshape(-1, 7)
    Ninv = np.linalg.inv(Jf.T @ Jf)
    # each frame's pose (6 unknowns of the reference's) is fitted too: take them off the redundancy
    redundancy = max(r.size - 7 - 6 * len(r), 1)
    formal = np.sqrt(float(np.sum(r ** 2)) / redundancy * Ninv[0, 0])
    scores = np.einsum("fmi,fm->fi", J, r)                             # per frame
    clusters = _motions(used, uv_o)
    G = len(np.unique(clusters))
    meat = sum(np.outer(g, g) for g in (scores[clusters == k].sum(axis=0) for k in np.unique(clusters)))
    clustered = np.sqrt(G / max(G - 1, 1) * (Ninv @ meat @ Ninv)[0, 0])
    floor = FLOOR_FRAMES * float(np.median(np.diff(times_o)))
    return float(params[0]), float(max(formal, clustered, floor)), int(len(used))


def estimate_offsets(tracks: dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int]]], board: Board,
                     reference: str) -> dict[str, TimeOffset | None]:
    """Every camera's offset from the reference (None where the board is never seen moving by both).

    ``tracks[camera] = (times_s (F,), uv_px (F, N, 2), image_size)``: the board tracked in every frame.
    The reference's own offset is 0.
    """
    times_r, uv_r, size_r = tracks[reference]
    fps = 1.0 / float(np.median(np.diff(times_r))) if len(times_r) > 1 else 30.0
    out: dict[str, TimeOffset | None] = {reference: TimeOffset(0.0, 0.0, 0.0, 1.0, len(times_r))}
    ref_poses = None
    for name, (times_o, uv_o, size_o) in tracks.items():
        if name == reference:
            continue
        lag, corr = coarse_offset((times_r, uv_r), (times_o, uv_o), fps)
        if not corr >= MIN_CORRELATION:
            out[name] = None
            continue
        try:
            if ref_poses is None:
                ref_poses = (times_r, *frame_poses(rough_camera(uv_r, board, size_r), uv_r, board))
            cam_o = rough_camera(uv_o, board, size_o)
            offset, sigma, used = refine_offset(ref_poses, (times_o, uv_o, *frame_poses(cam_o, uv_o, board)),
                                                cam_o, board, lag)
        except EstimationError:
            out[name] = None
            continue
        out[name] = TimeOffset(offset, sigma, lag, corr, used)
    return out
