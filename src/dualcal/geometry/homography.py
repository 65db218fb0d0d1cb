"""Homographies of a planar board's views (paper section 1.3, eq. 3): ``[u, v, 1] ~ H [X, Y, 1]``.

* :func:`estimate_homographies`: the normalised direct linear transform (Hartley's normalisation) of many views in
  one batch, then (``refine``) Gauss-Newton on the pixel reprojection error;
* :func:`homography_covariances`: how well each view fixes its homography, and the corners' noise from their
  residuals.

Board points are the board's ``(X, Y)`` in mm (Z = 0); image points are pixels ``(u, v)``. A view may have corners
that were not measured (NaN rows, :func:`dualcal.geometry.model.observed_mask`): each view uses the corners it has,
at least :data:`MIN_HOMOGRAPHY_CORNERS` not on one line.
"""

from __future__ import annotations

import numpy as np

from ..errors import EstimationError

__all__ = ["MIN_HOMOGRAPHY_CORNERS", "apply_homography", "estimate_homographies", "estimate_homography",
           "homography_covariances", "spans_a_plane"]

MIN_HOMOGRAPHY_CORNERS = 4      # a homography has 8 unknowns; each corner gives 2 equations


def spans_a_plane(xy_board: np.ndarray) -> bool:
    """Whether (N, 2) board points are not all on one line (so that they fix a homography)."""
    centred = np.asarray(xy_board, float) - np.mean(xy_board, axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return len(s) == 2 and s[1] > 1e-9 * s[0]


def _normalising_transforms(pts: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(V, 3, 3) similarities moving each view's points ``pts[v][seen[v]]`` ((V, N, 2), (V, N)) to zero
    mean and mean distance sqrt(2) (Hartley's normalisation)."""
    n = seen.sum(axis=1)
    mean = np.where(seen[..., None], pts, 0.0).sum(axis=1) / n[:, None]
    distance = np.linalg.norm(np.where(seen[..., None], pts - mean[:, None], 0.0), axis=2)     # 0 where unseen
    scale = np.sqrt(2.0) / np.maximum(distance.sum(axis=1) / n, 1e-12)
    T = np.zeros((len(pts), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = scale
    T[:, :2, 2] = -scale[:, None] * mean
    T[:, 2, 2] = 1.0
    return T


def apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map (N, 2) points through a 3x3 homography."""
    p = xy @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:3]


def _homographies_dlt(xy_board: np.ndarray, uvs: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(V, 3, 3) normalised DLTs of the views ``uvs`` (V, N, 2) over their corners ``seen`` (V, N), in
    one batch: an unseen corner's two rows of the DLT matrix are zero, which leaves its singular
    vectors those of the seen corners' rows alone."""
    V = len(uvs)
    board = np.broadcast_to(xy_board, uvs.shape)
    Tb, Ti = _normalising_transforms(board, seen), _normalising_transforms(uvs, seen)
    b = np.where(seen[..., None], board @ np.swapaxes(Tb[:, :2, :2], 1, 2) + Tb[:, None, :2, 2], 0.0)
    i = np.where(seen[..., None], uvs @ np.swapaxes(Ti[:, :2, :2], 1, 2) + Ti[:, None, :2, 2], 0.0)
    on = seen.astype(float)
    A = np.zeros((V, 2 * uvs.shape[1], 9))
    A[:, 0::2, 0:2], A[:, 0::2, 2] = b, on
    A[:, 0::2, 6:8] = -i[..., :1] * b
    A[:, 0::2, 8] = -i[..., 0]
    A[:, 1::2, 3:5], A[:, 1::2, 5] = b, on
    A[:, 1::2, 6:8] = -i[..., 1:2] * b
    A[:, 1::2, 8] = -i[..., 1]
    _, s, Vt = np.linalg.svd(np.linalg.qr(A, mode="r"))             # A's singular values and vectors, from its R
    if np.any(s[:, -2] < 1e-9 * s[:, 0]):
        raise EstimationError("homography is degenerate: board points are (nearly) collinear")
    H = np.linalg.inv(Ti) @ Vt[:, -1].reshape(V, 3, 3) @ Tb
    return H / H[:, 2:3, 2:3]


def estimate_homographies(xy_board: np.ndarray, uvs, seen, refine: bool = True) -> list[np.ndarray]:
    """:func:`estimate_homography` of each view ``uvs[v]`` (N, 2) over its corners ``seen[v]`` (N,),
    the DLTs solved in one batch."""
    xy_board = np.asarray(xy_board, float)
    uvs = np.asarray(uvs, float).reshape(-1, len(xy_board), 2)
    seen = np.asarray(seen, bool).reshape(len(uvs), len(xy_board))
    if np.any(seen.sum(axis=1) < MIN_HOMOGRAPHY_CORNERS):
        raise EstimationError(f"a homography needs at least {MIN_HOMOGRAPHY_CORNERS} points")
    Hs = _homographies_dlt(xy_board, uvs, seen)
    return list(_refine_homographies(Hs, xy_board, uvs, seen) if refine else Hs)


def estimate_homography(xy_board: np.ndarray, uv: np.ndarray, refine: bool = True) -> np.ndarray:
    """Homography ``H`` with ``[u, v, 1] ~ H [X, Y, 1]`` (paper eq. 3), ``H[2, 2] = 1``.

    Normalised DLT, then (``refine``) Gauss-Newton on the pixel reprojection error.
    """
    uv = np.asarray(uv, float)
    return estimate_homographies(xy_board, [uv], [np.ones(len(uv), bool)], refine)[0]


def _homography_projection(h: np.ndarray, xy_board: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (V, N, 2) of the board points ``xy_board`` (N, 2) through homographies ``h`` (V, 8) (``H``'s
    first eight entries row by row, ``H[2, 2] = 1``), and their Jacobians (V, N, 2, 8) with respect to ``h``."""
    X, Y = xy_board[:, 0], xy_board[:, 1]
    w = h[:, 6, None] * X + h[:, 7, None] * Y + 1.0
    p = np.stack([h[:, 0, None] * X + h[:, 1, None] * Y + h[:, 2, None],
                  h[:, 3, None] * X + h[:, 4, None] * Y + h[:, 5, None]], axis=-1) / w[..., None]
    J = np.zeros(p.shape + (8,))
    J[:, :, 0, 0], J[:, :, 0, 1], J[:, :, 0, 2] = X / w, Y / w, 1.0 / w
    J[:, :, 1, 3:6] = J[:, :, 0, 0:3]
    J[:, :, :, 6] = -p * (X / w)[..., None]
    J[:, :, :, 7] = -p * (Y / w)[..., None]
    return p, J


def _refine_homographies(Hs: np.ndarray, xy_board: np.ndarray, uvs: np.ndarray, seen: np.ndarray,
                         max_iter: int = 20) -> np.ndarray:
    """Gauss-Newton on the pixel reprojection error of every view from its DLT's ``H`` ((V, 3, 3); views
    ``uvs`` (V, N, 2) over their corners ``seen`` (V, N)), all views in one batch. Each start is close, so
    no damping is needed: a view whose step does not lower its error stops there, as does one whose step
    is below 1e-12 of its parameters."""
    on = seen[..., None].astype(float)
    uv = np.where(seen[..., None], uvs, 0.0)

    def residuals(h, views):
        return ((_homography_projection(h, xy_board)[0] - uv[views]) * on[views]).reshape(len(views), -1)

    h = (Hs.reshape(-1, 9)[:, :8] / Hs[:, 2, 2, None]).copy()
    r = residuals(h, np.arange(len(h)))
    cost = np.einsum("vi,vi->v", r, r)
    active = np.arange(len(h))
    for _ in range(max_iter):
        if not len(active):
            break
        ha = h[active]
        J = _homography_projection(ha, xy_board)[1]
        Q, R = np.linalg.qr((J * on[active][..., None]).reshape(len(active), -1, 8))
        step = np.linalg.solve(R, -np.einsum("vmk,vm->vk", Q, r[active])[..., None])[..., 0]
        trial = ha + step
        r_trial = residuals(trial, active)
        cost_trial = np.einsum("vi,vi->v", r_trial, r_trial)
        better = cost_trial < cost[active]
        done = active[better]
        h[done], r[done], cost[done] = trial[better], r_trial[better], cost_trial[better]
        small = np.max(np.abs(step) / (np.abs(trial) + 1e-12), axis=1) < 1e-12
        active = active[better & ~small]
    return np.concatenate([h, np.ones((len(h), 1))], axis=1).reshape(-1, 3, 3)


def homography_covariances(Hs, xy_board: np.ndarray, uvs, seen) -> tuple[np.ndarray, float]:
    """How well each view fixes its homography: the covariance of ``H``'s first eight entries (``H[2, 2] = 1``)
    per unit variance of a corner's coordinates, ``(J^T J)^-1`` with ``J`` the Jacobian of the corners'
    pixels, and the corners' variance (px^2 per coordinate) pooled over the views from the homographies'
    residuals: their squares over their ``2 n - 8`` degrees of freedom (NaN where no view has any).

    Parameters
    ----------
    Hs : (V, 3, 3) the views' homographies.
    xy_board : (N, 2) board points, mm.
    uvs, seen : (V, N, 2) the views' pixels and (V, N) which of them were measured.

    Returns
    -------
    ``(covariances (V, 8, 8), variance_px2)``.
    """
    Hs = np.asarray(Hs, float)
    seen = np.asarray(seen, bool)
    h = Hs.reshape(-1, 9)[:, :8] / Hs[:, 2, 2, None]
    p, J = _homography_projection(h, xy_board)
    J = (J * seen[..., None, None]).reshape(len(h), -1, 8)
    residual = np.where(seen[..., None], p - np.where(seen[..., None], uvs, 0.0), 0.0)
    dof = int(np.sum(2 * seen.sum(axis=1) - 8))
    variance = float(np.sum(residual**2) / dof) if dof > 0 else float("nan")
    return np.linalg.inv(np.swapaxes(J, 1, 2) @ J), variance
