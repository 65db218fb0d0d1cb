"""Sub-pixel corners at full resolution, in small windows only (paper section 1.2, last step).

Two steps per corner, both touching only a window around it:

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
   window does not. A corner whose fit does not converge inside its window keeps the step-1
   value.

Pixel ``(row i, col j)`` has its centre at ``(u=j, v=i)``.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["refine_corners", "fit_saddles", "window_half_size"]


def window_half_size(spacing_px: np.ndarray, lo: int = 3, hi: int = 24) -> np.ndarray:
    """Half-size of the refinement window for corners ``spacing_px`` apart: about a third of it.

    A window must not reach the next corner; a third of the spacing leaves room for a start
    off by a few pixels. Larger windows see more of the four edges (more precise, and on
    boards whose squares do not quite meet, a better-defined crossing), up to ``hi``.
    """
    return np.clip(np.floor(0.34 * np.asarray(spacing_px, float)), lo, hi).astype(int)


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
    _, E1E2, _ = _model(p, qx, qy)
    A = np.stack(np.broadcast_arrays(1.0, qx[None, :], qy[None, :], E1E2), axis=-1)  # (K, P, 4)
    At = np.swapaxes(A, 1, 2)
    p[:, 5:9] = np.linalg.solve((At @ A).astype(float) + 1e-9 * np.eye(4),
                                (At @ z[..., None]).astype(float))[..., 0]

    ok = valid.copy()
    lam = np.full(K, 1e-3)
    cost = _cost(p, qx, qy, z)
    for _ in range(iterations):
        J, res = _jacobian(p, qx, qy, z)
        Jt = np.swapaxes(J, 1, 2)
        JtJ = (Jt @ J).astype(float)
        Jtr = (Jt @ res[..., None])[..., 0].astype(float)
        D = np.einsum("kii->ki", JtJ) + 1e-12
        step = np.linalg.solve(JtJ + lam[:, None, None] * D[:, :, None] * np.eye(9),
                               -Jtr[..., None])[..., 0]
        trial = p + step
        new_cost = _cost(trial, qx, qy, z)
        better = new_cost < cost
        p[better], cost[better] = trial[better], new_cost[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
        if np.all((np.max(np.abs(step[:, :2]), axis=1) < 1e-4) | (lam > 1e4)):
            break
    rms = np.sqrt(cost / max(1, z.shape[1]))
    inside = np.all(np.abs(p[:, :2]) < 0.5 * half, axis=1) & (p[:, 4] > 0.2) & (p[:, 4] < half)
    ok &= inside & np.all(np.isfinite(p), axis=1)
    return centres + p[:, :2], ok, rms


def _model(p, qx, qy):
    p = p.astype(np.float32)          # pixel-scale arithmetic: float32 is ample and twice as fast
    c, s = np.cos(p[:, 2:4]), np.sin(p[:, 2:4])                # (K, 2)
    dx = qx[None, :] - p[:, 0:1]
    dy = qy[None, :] - p[:, 1:2]
    t1 = c[:, 0:1] * dx + s[:, 0:1] * dy
    t2 = c[:, 1:2] * dx + s[:, 1:2] * dy
    k = 1.0 / p[:, 4:5]
    E1, E2 = np.tanh(t1 * k), np.tanh(t2 * k)
    return (E1, E2), E1 * E2, (t1, t2, dx, dy, c, s)


def _predict(p, qx, qy):
    _, E1E2, _ = _model(p, qx, qy)
    p = p.astype(np.float32)
    return p[:, 5:6] + p[:, 6:7] * qx + p[:, 7:8] * qy + p[:, 8:9] * E1E2


def _cost(p, qx, qy, z):
    r = _predict(p, qx, qy) - z
    cost = np.sum(r * r, axis=1, dtype=np.float64)
    return np.where(np.isfinite(cost), cost, np.inf)


def _jacobian(p, qx, qy, z):
    (E1, E2), E1E2, (t1, t2, dx, dy, c, s) = _model(p, qx, qy)
    p = p.astype(np.float32)
    w = p[:, 4:5]
    a = p[:, 8:9]
    g1 = (1.0 - E1 * E1) / w           # dE/dt of E = tanh(t / w)
    g2 = (1.0 - E2 * E2) / w
    G1, G2 = g1 * E2, E1 * g2
    J = np.empty(t1.shape + (9,), np.float32)
    J[..., 0] = -a * (G1 * c[:, 0:1] + G2 * c[:, 1:2])
    J[..., 1] = -a * (G1 * s[:, 0:1] + G2 * s[:, 1:2])
    J[..., 2] = a * G1 * (-s[:, 0:1] * dx + c[:, 0:1] * dy)
    J[..., 3] = a * G2 * (-s[:, 1:2] * dx + c[:, 1:2] * dy)
    J[..., 4] = -a * (G1 * t1 + G2 * t2) / w
    J[..., 5] = 1.0
    J[..., 6] = qx[None, :]
    J[..., 7] = qy[None, :]
    J[..., 8] = E1E2
    res = p[:, 5:6] + p[:, 6:7] * qx + p[:, 7:8] * qy + a * E1E2 - z
    return J, res


def refine_corners(img: np.ndarray, uv: np.ndarray, grid_shape: tuple[int, int],
                   wide_start: bool = False) -> np.ndarray:
    """Refine grid corners at full resolution, each in its own small window.

    Parameters
    ----------
    img : (H, W) uint8 full-resolution image.
    uv : (rows*cols, 2) coarse corners in row-major grid order (any of the grid's orders).
    grid_shape : ``(rows, cols)`` of ``uv``.
    wide_start : start with a window of nearly half the corner spacing, for starting points
        that may be off by many pixels (corners predicted from four clicks).

    Returns
    -------
    (N, 2) refined corners, pixels, in the order of ``uv``.
    """
    rows, cols = grid_shape
    g = np.asarray(uv, float).reshape(rows, cols, 2)
    along_c = np.gradient(g, axis=1)                       # (rows, cols, 2) between neighbours
    along_r = np.gradient(g, axis=0)
    spacing = np.minimum(np.linalg.norm(along_c, axis=2), np.linalg.norm(along_r, axis=2)).ravel()
    start = g.reshape(-1, 2)
    if wide_start:
        start = _subpix(img, start, int(np.clip(0.45 * spacing.min(), 3, 80)))
    half = int(np.min(window_half_size(spacing)))
    first = _subpix(img, start, min(half, 11))
    dirs = np.stack([along_c.reshape(-1, 2), along_r.reshape(-1, 2)], axis=1)
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    fit, ok, _ = fit_saddles(img, first, dirs, half)
    return np.where(ok[:, None], fit, first)
