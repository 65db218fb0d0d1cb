"""Sub-pixel corners at full resolution, in small windows only (paper section 1.2, last step).

Each corner has its own window, 0.4 of the distance to its nearest neighbour (on a tilted
board the squares of one photo range from a few to many tens of pixels). Two steps per
corner, both touching only that window:

1. ``cv2.cornerSubPix`` (gradient orthogonality, Förstner / Bouguet) from the coarse position:
   a wide basin of convergence, accurate to a few hundredths of a pixel.
2. :func:`fit_saddles`: a least-squares fit of a blurred ideal corner to the window's pixels,
   all corners at once (batched Levenberg-Marquardt). The model is two straight edges through the
   corner ``c`` with unit normals ``n1, n2`` (angles ``theta1, theta2``), a blurred step of
   width ``w`` across each edge and a linear light gradient::

       I(p) = m + g . (p - p0) + a * E(n1 . (p - c)) * E(n2 . (p - c)),
       E(t) = tanh(t / w)

   ``tanh`` stands in for the Gaussian-blurred step ``erf``: like it, it is odd, so any
   mismatch of the edge profile is symmetric about the corner and cannot move it, and it is
   forty times cheaper to evaluate.

   It uses every pixel's value rather than only gradient directions, so with sensor noise it
   is more precise than step 1. Where the printed squares do not quite meet (home-made
   boards), it returns the crossing of the four edges, which gradient orthogonality in a small
   window does not. A corner whose fit does not converge inside its window is reported as
   failed.
3. Where a photo's edges are blurred over much of its windows (a defocused lens), one crossing of
   two edges is no model of a window that its neighbours' blur reaches into: every corner is then
   measured by its window's point symmetry (:func:`symmetry_centres`), which any point-symmetric
   blur keeps. A corner whose fit failed in a sharper photo gets the symmetry's centre as its best
   estimate.

:func:`measure_grid` then checks every corner against its neighbours (:mod:`.grid`), with the
photo's own corner noise as the scale, refines again from the neighbours' prediction where it
disagrees, and makes a NaN row only of a corner many times the noise off.

Pixel ``(row i, col j)`` has its centre at ``(u=j, v=i)``.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from ...geometry.grid import (OUTLIER_FLOOR_SHARE, local_spacing_px, outlier_limit_px, predict_from_neighbours,
                              typical_residual_px, worst_outlier)

__all__ = ["refine_corners", "fit_saddles", "symmetry_centres", "window_half_size", "drop_outliers", "measure_grid"]


#: :func:`fit_saddles` fits again without the pixels off its first fit by more than this many robust
#: sigmas (at least 1 grey level) and this share of the corner's half-contrast, where they are more
#: than this share of the window's.
OUTLIER_MADS = 4.0
OUTLIER_CONTRAST = 1.0
OUTLIER_SHARE = 0.01
#: :func:`fit_saddles` stops a corner's steps once one moves it by less than this (px). Gauss-Newton converges
#: quadratically here: on 12 MP renders the steps go about 1e-2, 1e-4, 1e-6 px, so the step after one below
#: this is below 1e-5 px, far under a corner's noise (a few hundredths of a pixel).
SETTLED_PX = 1e-3


def window_half_size(spacing_px: np.ndarray, lo: int = 3, hi: int = 24) -> np.ndarray:
    """Half-size of the refinement window of a corner ``spacing_px`` from its nearest neighbour.

    A window must not reach the next corner; 0.4 of the distance to the nearest of the eight
    neighbours (diagonals included, so a sheared grid is covered) leaves room for a start off
    by a few pixels. Larger windows see more of the four edges (more precise, and on
    boards whose squares do not quite meet, a better-defined crossing), up to ``hi``.
    """
    return np.clip(np.floor(0.4 * np.asarray(spacing_px, float)), lo, hi).astype(int)


def _subpix(img: np.ndarray, uv: np.ndarray, half: int) -> np.ndarray:
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 60, 1e-3)
    pts = np.ascontiguousarray(uv, np.float32).reshape(-1, 1, 2)
    return cv2.cornerSubPix(img, pts, (int(half), int(half)), (-1, -1), crit).reshape(-1, 2).astype(float)


def _windows(img: np.ndarray, centres: np.ndarray, half: int):
    """(K, n, n) float32 windows around integer ``centres`` (K, 2); ``valid`` where fully inside."""
    H, W = img.shape
    n = 2 * half + 1
    cu, cv = centres[:, 0], centres[:, 1]
    valid = (cu - half >= 0) & (cv - half >= 0) & (cu + half < W) & (cv + half < H)
    out = np.zeros((len(centres), n, n), np.float32)
    for k in np.flatnonzero(valid):
        out[k] = img[cv[k] - half: cv[k] + half + 1, cu[k] - half: cu[k] + half + 1]
    return out, valid


def fit_saddles(img: np.ndarray, uv: np.ndarray, edge_dirs: np.ndarray, half: int,
                iterations: int = 12):
    """Fit the blurred-corner model of the module docstring around every corner.

    Parameters
    ----------
    img : (H, W) uint8 or float image.
    uv : (K, 2) starting corner positions, pixels.
    edge_dirs : (K, 2, 2) unit directions of the two grid lines through each corner (along
        the board's rows and columns); only their angles are used, as a start.
    half : window half-size; the fit uses the pixels within a disc of this radius.
    iterations : at most this many Levenberg-Marquardt steps.

    Returns
    -------
    uv_fit : (K, 2) fitted corners.
    ok : (K,) True where the fit converged inside its window.
    rms : (K,) residual RMS of the fit, in grey levels (the image's units).
    width_px : (K,) the fitted edge width ``w`` (the blur across an edge, pixels: about 1.2 x a Gaussian
        blur's standard deviation); NaN where the window is not inside the image.
    """
    uv = np.asarray(uv, float)
    K = len(uv)
    centres = np.rint(uv).astype(int)
    win, valid = _windows(img, centres, half)
    r = np.arange(-half, half + 1, dtype=np.float32)
    qy, qx = np.meshgrid(r, r, indexing="ij")
    disc = (qx * qx + qy * qy <= (half + 0.5) ** 2).ravel()
    qx, qy = qx.ravel()[disc], qy.ravel()[disc]           # offsets from the window centre
    z = win.reshape(K, -1)[:, disc]                        # (K, P) observations

    # parameters: cu, cv (relative to the window centre), theta1, theta2, w, m, gx, gy, a
    normals = np.stack([-edge_dirs[:, :, 1], edge_dirs[:, :, 0]], axis=-1)   # (K, 2, 2)
    p = np.zeros((K, 9))
    p[:, 0:2] = uv - centres
    p[:, 2] = np.arctan2(normals[:, 0, 1], normals[:, 0, 0])
    p[:, 3] = np.arctan2(normals[:, 1, 1], normals[:, 1, 0])
    p[:, 4] = 1.5
    # linear start for the photometric terms (m, g, a) given the geometry
    E1, E2 = _model(p, qx, qy)[:2]
    At = np.empty((K, 4, len(qx)), np.float32)             # (K, 4, P): the terms' columns, one row each
    At[:, 0], At[:, 1], At[:, 2] = 1.0, qx, qy
    np.multiply(E1, E2, out=At[:, 3])
    p[:, 5:9] = np.linalg.solve((At @ np.swapaxes(At, 1, 2)).astype(float) + 1e-9 * np.eye(4),
                                (At @ z[..., None]).astype(float))[..., 0]

    ok = valid.copy()
    cost, model = _lm(p, qx, qy, z, None, np.arange(K), iterations)
    # marks printed in a white square (a code, a dot, text) or a glare spot inside the window are
    # no part of the corner model: where more than OUTLIER_SHARE of a window's pixels are off the
    # fit by over OUTLIER_MADS robust sigmas and OUTLIER_CONTRAST of the corner's half-contrast a (a
    # dark mark on white is off by about 2a; a real edge's profile, which tanh only approximates, by
    # far less), the fit is done again without them
    res = _predict(p, model, qx, qy) - z
    sample = res[:, ::3]                   # a robust scale needs no more pixels than a third of a window's
    mad = 1.4826 * np.median(np.abs(sample - np.median(sample, axis=1, keepdims=True)), axis=1, keepdims=True)
    keep = np.abs(res) <= np.maximum(OUTLIER_MADS * np.maximum(mad, 1.0), OUTLIER_CONTRAST * np.abs(p[:, 8:9]))
    again = np.flatnonzero(valid & (np.mean(~keep, axis=1) > OUTLIER_SHARE))
    if len(again):
        wt = keep[again].astype(np.float32)
        sub = p[again]
        cost_again = _lm(sub, qx, qy, z[again], wt, np.arange(len(again)), iterations)[0]
        p[again] = sub
        cost[again] = cost_again * keep.shape[1] / np.maximum(wt.sum(axis=1), 1.0)
    rms = np.sqrt(cost / max(1, z.shape[1]))
    inside = np.all(np.abs(p[:, :2]) < 0.5 * half, axis=1) & (p[:, 4] > 0.2) & (p[:, 4] < half)
    ok &= inside & np.all(np.isfinite(p), axis=1)
    return centres + p[:, :2], ok, rms, np.where(valid & np.isfinite(p[:, 4]), np.abs(p[:, 4]), np.nan)


def symmetry_centres(img: np.ndarray, uv: np.ndarray, half: int, iterations: int = 20):
    """Refine corners to the centre of their window's point symmetry (the fallback of :func:`refine_corners`).

    A chessboard seen in an affine view is point-symmetric about each of its corners (the squares on one side
    are the squares on the other, turned by 180 degrees), and so is its image blurred by any point-symmetric
    spread (a Gaussian, a defocused lens's disc) over any width: where the blur spreads over much of a square,
    and the corner model of :func:`fit_saddles` (one crossing of two edges in its window) no longer holds, the
    corner is still the point ``c`` about which the window is symmetric. Gauss-Newton on

        E(c) = sum_d (I(c + d) - I(c - d))^2

    over the offsets ``d`` of half a disc of radius ``half`` (each pair once), ``I`` and its gradient
    interpolated bilinearly. Perspective leaves a second-order asymmetry; measured on 1280 x 960 renders with
    squares of 26 px and a defocus disc of 10 px radius: 0.03 px RMS against the truth, where the corner fit
    wandered off by pixels and ``cornerSubPix`` was 0.9 px off.

    Parameters
    ----------
    img : (H, W) uint8 or float image.
    uv : (K, 2) starting corners, pixels (within about the blur's width of the corner).
    half : radius of the window, pixels.
    iterations : at most this many Gauss-Newton steps (each at most a pixel per coordinate).

    Returns
    -------
    uv : (K, 2) refined corners.
    ok : (K,) True where the window lies inside the image and the centre stayed within ``half / 2`` of its start.
    """
    uv = np.asarray(uv, float)
    m = half + half // 2 + 2                                 # the patch holds c +- d wherever c may go
    n = 2 * m + 1
    r = np.arange(-half, half + 1, dtype=np.float32)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    pair = (dx * dx + dy * dy <= (half + 0.5) ** 2) & ((dy > 0) | ((dy == 0) & (dx > 0)))
    dx, dy = dx[pair], dy[pair]
    centres = np.rint(uv).astype(int)
    patches, valid = _windows(img, centres, m)
    gy, gx = np.gradient(patches, axis=(1, 2))

    def sample(rows, x, y):
        x0 = np.clip(np.floor(x).astype(int), 0, n - 2)
        y0 = np.clip(np.floor(y).astype(int), 0, n - 2)
        fx, fy = x - x0, y - y0
        return [(a[rows, y0, x0] * (1 - fx) + a[rows, y0, x0 + 1] * fx) * (1 - fy)
                + (a[rows, y0 + 1, x0] * (1 - fx) + a[rows, y0 + 1, x0 + 1] * fx) * fy for a in (patches, gx, gy)]

    start = (uv - centres + m).astype(np.float32)            # corners in patch coordinates
    c = start.copy()
    active = np.flatnonzero(valid)
    for _ in range(iterations):
        if len(active) == 0:
            break
        cu, cv = c[active, :1], c[active, 1:]
        Ip, gxp, gyp = sample(active[:, None], cu + dx, cv + dy)
        Im, gxm, gym = sample(active[:, None], cu - dx, cv - dy)
        e, Ju, Jv = Ip - Im, gxp - gxm, gyp - gym
        a, b, d = (Ju * Ju).sum(1), (Ju * Jv).sum(1), (Jv * Jv).sum(1)
        gu, gv = (Ju * e).sum(1), (Jv * e).sum(1)
        det = a * d - b * b
        det = np.where(np.abs(det) > 1e-12, det, np.inf)
        step = np.clip(np.stack([-(d * gu - b * gv) / det, -(a * gv - b * gu) / det], axis=1), -1.0, 1.0)
        c[active] += step
        active = active[np.max(np.abs(step), axis=1) >= 1e-3]
    ok = valid & np.all(np.isfinite(c), axis=1) & np.all(np.abs(c - start) < 0.5 * half, axis=1)
    return c - m + centres, ok


def _lm(p, qx, qy, z, wt, active, iterations):
    """Levenberg-Marquardt on the corners ``active`` of ``p`` (K, 9), in place; ``wt`` (K, P) 0/1 pixel
    weights or None; a corner is done once its step moves it by less than :data:`SETTLED_PX`. Returns the (K,)
    costs and :func:`_model`'s pieces at the final ``p``. The model evaluated at a trial that is kept is the one
    the next step's Jacobian is taken at (:func:`_model` once a step, not twice)."""
    lam = np.full(len(p), 1e-3)
    model = list(_model(p, qx, qy))
    cost = _cost(p, model, qx, qy, z, wt)
    eye = np.eye(9)
    for _ in range(iterations):
        if len(active) == len(p):       # every corner still moving: the arrays as they are, not copies
            pa, za, wa, ma = p.copy(), z, wt, model
        else:
            pa, za = p[active], z[active]
            wa = None if wt is None else wt[active]
            ma = [m[active] for m in model]
        Jt, res = _jacobian(pa, ma, qx, qy, za)
        if wa is not None:
            Jt *= wa[:, None, :]
            res *= wa
        JtJ = (Jt @ np.swapaxes(Jt, 1, 2)).astype(float)
        Jtr = (Jt @ res[..., None])[..., 0].astype(float)
        D = np.einsum("kii->ki", JtJ) + 1e-12
        la = lam[active]
        step = np.linalg.solve(JtJ + la[:, None, None] * D[:, :, None] * eye, -Jtr[..., None])[..., 0]
        trial = pa + step
        trial_model = _model(trial, qx, qy)
        new_cost = _cost(trial, trial_model, qx, qy, za, wa)
        better = new_cost < cost[active]
        kept = active[better]
        p[kept], cost[kept] = trial[better], new_cost[better]
        for m, t in zip(model, trial_model):
            m[kept] = t[better]
        lam[active] = np.where(better, la * 0.3, la * 10.0)
        done = better & (np.max(np.abs(step[:, :2]), axis=1) < SETTLED_PX) | (lam[active] > 1e4)
        active = active[~done]
        if len(active) == 0:
            break
    return cost, model


def _model(p, qx, qy):
    """The pieces of the model at ``p`` (K, 9): ``(E1, E2, t1, t2, dx, dy)`` (K, P) and ``(c, s)`` (K, 2),
    the cosines and sines of the edges' normals."""
    p = p.astype(np.float32)          # pixel-scale arithmetic: float32 is ample and twice as fast
    c, s = np.cos(p[:, 2:4]), np.sin(p[:, 2:4])                # (K, 2)
    dx = qx[None, :] - p[:, 0:1]
    dy = qy[None, :] - p[:, 1:2]
    t1 = c[:, 0:1] * dx + s[:, 0:1] * dy
    t2 = c[:, 1:2] * dx + s[:, 1:2] * dy
    k = 1.0 / p[:, 4:5]
    return np.tanh(t1 * k), np.tanh(t2 * k), t1, t2, dx, dy, c, s


def _predict(p, model, qx, qy):
    E1, E2 = model[:2]
    p = p.astype(np.float32)
    return p[:, 5:6] + p[:, 6:7] * qx + p[:, 7:8] * qy + p[:, 8:9] * (E1 * E2)


def _cost(p, model, qx, qy, z, wt=None):
    r = _predict(p, model, qx, qy) - z
    if wt is not None:
        r = r * wt
    cost = np.sum(r * r, axis=1, dtype=np.float64)
    return np.where(np.isfinite(cost), cost, np.inf)


def _jacobian(p, model, qx, qy, z):
    """``(Jt, res)``: the transposed Jacobian (K, 9, P) of the model (:func:`_model`'s pieces ``model`` at
    ``p`` (K, 9)) by its parameters (one contiguous row of pixels per parameter, which the products
    ``Jt Jt^T`` and ``Jt res`` want) and the residuals (K, P) against ``z``."""
    E1, E2, t1, t2, dx, dy, c, s = model
    E1E2 = E1 * E2
    p = p.astype(np.float32)
    w = p[:, 4:5]
    a = p[:, 8:9]
    aG1 = a * (1.0 - E1 * E1) / w * E2           # a dE1/dt1 E2, with dE/dt = (1 - E^2) / w for E = tanh(t / w)
    aG2 = a * E1 * (1.0 - E2 * E2) / w
    Jt = np.empty((len(p), 9, t1.shape[1]), np.float32)
    Jt[:, 0] = -(aG1 * c[:, 0:1] + aG2 * c[:, 1:2])
    Jt[:, 1] = -(aG1 * s[:, 0:1] + aG2 * s[:, 1:2])
    Jt[:, 2] = aG1 * (-s[:, 0:1] * dx + c[:, 0:1] * dy)
    Jt[:, 3] = aG2 * (-s[:, 1:2] * dx + c[:, 1:2] * dy)
    Jt[:, 4] = -(aG1 * t1 + aG2 * t2) / w
    Jt[:, 5] = 1.0
    Jt[:, 6] = qx[None, :]
    Jt[:, 7] = qy[None, :]
    Jt[:, 8] = E1E2
    res = p[:, 5:6] + p[:, 6:7] * qx + p[:, 7:8] * qy + a * E1E2 - z
    return Jt, res


def _groups(half: np.ndarray):
    """Indices of the corners sharing each window half-size (windows are batched per size)."""
    for h in np.unique(half):
        yield int(h), np.flatnonzero(half == h)


def refine_corners(img: np.ndarray, uv: np.ndarray, grid_shape: tuple[int, int],
                   spacing_px: np.ndarray | None = None, wide_start: bool = False,
                   only: np.ndarray | None = None):
    """Refine grid corners at full resolution, each in a window fitted to its own squares.

    Parameters
    ----------
    img : (H, W) uint8 full-resolution image.
    uv : (rows*cols, 2) starting corners in row-major grid order (any of the grid's orders);
        NaN rows are left alone.
    grid_shape : ``(rows, cols)`` of ``uv``.
    spacing_px : (rows*cols,) distance from each corner to its nearest neighbour, which sets its
        window (:func:`window_half_size`); default: measured on ``uv``
        (:func:`~dualcal.geometry.grid.local_spacing_px`).
    wide_start : first pull every corner in with a window of nearly half its spacing, for
        starting points that may be off by many pixels (corners predicted from four clicks).
    only : (N,) bool, refine only these corners (the others are returned as they are, not ok);
        all others still set the grid's directions.

    Returns
    -------
    uv : (N, 2) refined corners, pixels, in the order of ``uv``.
    ok : (N,) True where the corner was measured in its window: by the blurred-corner fit
        (:func:`fit_saddles`), or where the photo is too blurred for it (:data:`BLURRED_WIDTH_SHARE`), by the
        window's point symmetry (:func:`symmetry_centres`); elsewhere ``uv`` holds the best estimate there is
        (the symmetry's centre, or the ``cornerSubPix`` result), which the caller should not trust as it is.
    """
    refined = refine_measured(img, uv, grid_shape, spacing_px, wide_start, only)
    return refined.uv, refined.ok


#: Where the fitted edge widths ``w`` of a photo's corners pass this share of their windows' half-size (the
#: median over the photo), the blur spreads over so much of the windows that the corner model of
#: :func:`fit_saddles` (a single crossing of two edges) stops holding, and the photo's corners are measured by
#: their windows' point symmetry instead (:func:`symmetry_centres`); so is a corner whose fit fails. Measured on
#: 1280 x 960 renders defocused by discs of 0-10 px radius, the RMS error against the truth of the corner fit and
#: the symmetry: 0.010 and 0.011 px in focus, 0.013-0.024 and 0.017-0.018 px at 0.2-0.25, 0.022-0.030 and
#: 0.015-0.017 px at 0.25-0.3, 0.032-0.039 and 0.018-0.026 px at 0.3-0.4, 0.10-1.1 and 0.024-0.04 px beyond. The
#: switch is at 0.3, not where the symmetry starts to be better: the small windows of sharp low-resolution photos
#: reach 0.2-0.26, and there a photo and its copy developed otherwise (a DNG and its JPEG) would fall on either
#: side of it and be measured by two methods whose results differ by a hundredth of a pixel.
BLURRED_WIDTH_SHARE = 0.3


class RefinedCorners(NamedTuple):
    """What :func:`refine_measured` found: ``uv`` (N, 2) and ``ok`` (N,) as :func:`refine_corners` returns them,
    ``tried`` (N,) the corners that were refined (inside the image, with a window), ``width_px`` (N,) each
    corner's fitted edge width (:func:`fit_saddles`; NaN where not fitted), ``blurred`` whether they were measured
    by their windows' symmetry (:data:`BLURRED_WIDTH_SHARE`)."""

    uv: np.ndarray
    ok: np.ndarray
    tried: np.ndarray
    width_px: np.ndarray
    blurred: bool


def refine_measured(img: np.ndarray, uv: np.ndarray, grid_shape: tuple[int, int],
                    spacing_px: np.ndarray | None = None, wide_start: bool = False,
                    only: np.ndarray | None = None, blurred: bool | None = None) -> RefinedCorners:
    """:func:`refine_corners`, with which corners were tried and what their fits measured of the photo's blur.

    ``blurred``: measure the corners by their windows' symmetry, or not; None: where the corners' own edge widths
    say so (:data:`BLURRED_WIDTH_SHARE`). A few corners refined again (``only``) take the photo's decision: the
    corners that failed are no sample of its blur."""
    rows, cols = grid_shape
    start = np.array(uv, float).reshape(rows * cols, 2)
    spacing = local_spacing_px(start, grid_shape) if spacing_px is None else np.asarray(spacing_px, float)
    todo = np.isfinite(spacing) & np.all(np.isfinite(start), axis=1)
    if only is not None:
        todo &= np.asarray(only, bool)
    # a corner outside the image (a board cut off by the frame) cannot be measured; one near its edge, in a
    # window that the edge cuts
    H, W = img.shape
    room = np.floor(np.min(np.column_stack([start, [W - 1, H - 1] - start]), axis=1))
    todo &= np.isfinite(room) & (room > 3)
    half = np.where(todo, np.minimum(window_half_size(np.where(todo, spacing, 0.0)), np.where(todo, room, 0) - 1), 0)
    if wide_start:
        wide = np.clip(np.floor(0.45 * np.where(todo, spacing, 0.0)), 3, 80).astype(int)
        for h, k in _groups(wide[todo]):
            k = np.flatnonzero(todo)[k]
            start[k] = _subpix(img, start[k], h)
    g = start.reshape(rows, cols, 2)
    dirs = np.stack([_grid_direction(g, axis=1), _grid_direction(g, axis=0)], axis=1)
    out = start.copy()
    good = np.zeros(len(start), bool)
    width = np.full(len(start), np.nan)
    first = start.copy()
    for h, k in _groups(half[todo]):
        k = np.flatnonzero(todo)[k]
        first[k] = _subpix(img, start[k], h)
        out[k], good[k], _, width[k] = fit_saddles(img, first[k], dirs[k], h)
    out = np.where(good[:, None], out, first)
    # a photo whose edges are blurred over much of the corners' windows is measured by the windows' symmetry; in a
    # sharper photo a corner whose fit failed gets its symmetry's centre as its best estimate, but not as measured
    if blurred is None:
        share = width[todo] / np.maximum(half[todo], 1)
        blurred = bool(np.isfinite(share).any() and np.nanmedian(share) > BLURRED_WIDTH_SHARE)
    redo = todo & (~good | blurred)
    for h, k in _groups(half[redo]):
        k = np.flatnonzero(redo)[k]
        # cornerSubPix's gradients cross neighbouring squares' blur too: start from it only where it stayed
        # near the start
        near = np.linalg.norm(first[k] - start[k], axis=1) < 0.25 * h
        sym, sym_ok = symmetry_centres(img, np.where(near[:, None], first[k], start[k]), h)
        out[k] = np.where(sym_ok[:, None], sym, first[k])
        good[k] = sym_ok & blurred
    ok = todo & good & (np.linalg.norm(out - start, axis=1) < np.maximum(half, 1))
    return RefinedCorners(out, ok, todo, width, blurred)


def _grid_direction(g: np.ndarray, axis: int) -> np.ndarray:
    """(N, 2) unit direction of the grid line through each corner along ``axis`` (NaN-tolerant)."""
    fwd = np.diff(g, axis=axis)
    pad = [(0, 0)] * 3
    pad[axis] = (1, 0)
    back_d = np.pad(fwd, pad, constant_values=np.nan)
    pad[axis] = (0, 1)
    fwd_d = np.pad(fwd, pad, constant_values=np.nan)
    d = np.where(np.isfinite(fwd_d), fwd_d, 0.0) + np.where(np.isfinite(back_d), back_d, 0.0)
    d = d.reshape(-1, 2)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    fallback = np.array([1.0, 0.0]) if axis == 1 else np.array([0.0, 1.0])
    return np.where(n > 0, d / np.where(n > 0, n, 1.0), fallback)


def drop_outliers(uv: np.ndarray, grid_shape: tuple[int, int], spacing_px: np.ndarray,
                  judged: np.ndarray | None = None, floor_share: float = OUTLIER_FLOOR_SHARE) -> np.ndarray:
    """``uv`` with the corners that disagree with their neighbours set to NaN, worst first.

    The worst corner (:func:`~dualcal.geometry.grid.worst_outlier`) goes first and the residuals
    are computed again, so that one bad corner does not take with it its neighbours, whose
    predictions it spoiled. What is left passes :func:`~dualcal.geometry.grid.validate_grid`'s
    residual check. ``judged``: only these corners may be dropped (default: all); ``floor_share``: the limit's
    floor (:func:`~dualcal.geometry.grid.outlier_limit_px`).
    """
    uv = np.array(uv, float)
    while (worst := worst_outlier(uv, grid_shape, spacing_px, judged=judged, floor_share=floor_share)) is not None:
        uv[worst[0]] = np.nan
    return uv


#: Rounds of second chances in :func:`measure_grid`: a corner lost next to others lost has no prediction until they
#: are back.
RETRY_ROUNDS = 2


class MeasuredGrid(NamedTuple):
    """:func:`measure_grid`'s result: ``uv`` (N, 2) the corners, NaN rows for the corners left out;
    ``edge_width_px`` the photo's blur, the median fitted edge width of its corners (:func:`fit_saddles`'s ``w``,
    about 1.2 x a Gaussian blur's standard deviation; NaN where none was fitted)."""

    uv: np.ndarray
    edge_width_px: float


def measure_grid(img: np.ndarray, coarse_uv: np.ndarray, grid_shape: tuple[int, int],
                 wide_start: bool = False) -> MeasuredGrid:
    """Sub-pixel corners of a whole grid, each checked against its neighbours.

    1. A coarse corner further than 0.15 of its spacing from its neighbours' prediction (the
       classic detector's corners at the border of a tilted board can be 5-13 px off) starts
       from that prediction instead.
    2. Every corner is refined in its own window (:func:`refine_corners`); of those measured, every
       corner further than :func:`~dualcal.geometry.grid.outlier_limit_px` (many times the photo's own
       corner noise) from its neighbours' prediction is dropped, worst first (:func:`drop_outliers`).
    3. Each dropped corner gets a second chance: refined again from where its remaining
       neighbours put it, and kept if its fit converges there within the limit (in
       :data:`RETRY_ROUNDS`, for corners whose neighbours come back in the first).
    4. A corner whose refinement failed and did not come back keeps the best estimate there is (the
       symmetry's centre or ``cornerSubPix``'s, or where that ran off, its start) where it is within
       many times the photo's own noise of its neighbours' prediction.

    Parameters
    ----------
    img : (H, W) uint8 full-resolution image.
    coarse_uv : (N, 2) starting corners in grid order.
    grid_shape : ``(rows, cols)``.
    wide_start : see :func:`refine_corners`.

    Returns
    -------
    MeasuredGrid
        the corners (NaN rows for those left out, and for those outside the image) and the photo's blur.
    """
    coarse = np.asarray(coarse_uv, float)
    spacing = local_spacing_px(coarse, grid_shape)
    pred, _ = predict_from_neighbours(coarse, grid_shape)
    far = np.linalg.norm(coarse - pred, axis=1) > 0.15 * spacing
    start = np.where(far[:, None], pred, coarse)
    refined = refine_measured(img, start, grid_shape, spacing, wide_start=wide_start)
    uv = drop_outliers(np.where(refined.ok[:, None], refined.uv, np.nan), grid_shape, spacing)
    retried = np.zeros(len(uv), bool)
    for _ in range(RETRY_ROUNDS):
        if not (refined.tried & ~retried & ~np.all(np.isfinite(uv), axis=1)).any():     # none to retry
            break
        pred, gain = predict_from_neighbours(uv, grid_shape)
        retry = refined.tried & ~retried & ~np.all(np.isfinite(uv), axis=1) & np.all(np.isfinite(pred), axis=1)
        if not retry.any():
            break
        retried |= retry
        again, ok, *_ = refine_measured(img, np.where(retry[:, None], pred, uv), grid_shape, spacing, only=retry,
                                        blurred=refined.blurred)
        typical = typical_residual_px(np.linalg.norm(uv - pred, axis=1), grid_shape)
        keep = retry & ok & (np.linalg.norm(again - pred, axis=1) <= outlier_limit_px(spacing, typical, gain))
        uv[keep] = again[keep]
        uv = drop_outliers(uv, grid_shape, spacing)
    # a corner whose refinement failed twice keeps its best estimate (cornerSubPix's, or where that ran off, its
    # start) where the measured corners around it can judge it and it is within many times the photo's own
    # noise of their prediction (the floor for what the prediction cannot follow is for measured corners)
    rough = refined.tried & ~refined.ok & ~np.all(np.isfinite(uv), axis=1)
    if rough.any():
        half = window_half_size(np.where(rough, spacing, 0.0))
        ran_off = np.linalg.norm(refined.uv - start, axis=1) >= 0.5 * half
        uv[rough] = np.where(ran_off[:, None], start, refined.uv)[rough]
        unjudged = rough & ~np.all(np.isfinite(predict_from_neighbours(uv, grid_shape)[0]), axis=1)
        uv[unjudged] = np.nan
        uv = drop_outliers(uv, grid_shape, spacing, judged=rough, floor_share=0.0)
    return MeasuredGrid(uv, photo_edge_width_px(refined.width_px))


def photo_edge_width_px(width_px: np.ndarray) -> float:
    """A photo's blur: the median of its corners' fitted edge widths ``width_px`` (NaN ones left out; NaN if none)."""
    widths = np.asarray(width_px, float)
    widths = widths[np.isfinite(widths)]
    return float(np.median(widths)) if len(widths) else float("nan")
