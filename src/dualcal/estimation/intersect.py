"""Space intersection: the 3-D point seen by two or more oriented photos (paper section 2).

The paper checks a calibration by a stereo-pair intersection of the board corners (Tables 5
and 6). Here it is done in two steps, both vectorised over all points at once:

1. :func:`intersect_rays`, the linear least-squares point: each photo gives a ray from its
   perspective centre ``C_i`` along ``d_i = R_i^T (x_i, y_i, 1)`` (the undistorted normalised
   observation, paper eqs. 24-27, turned into the common frame); the point minimising the sum
   of squared perpendicular distances solves ``sum_i P_i X = sum_i P_i C_i`` with the projector
   ``P_i = I - d_i d_i^T``. It is solved for ``X - mean(C_i)``, so the 3 x 3 systems do not
   carry the large common offset of the centres.
2. :func:`triangulate` refines that point by Gauss-Newton on the collinearity equations (the
   pixel residuals of every photo through the full camera model). Perpendicular distances in
   mm weigh a near camera more than a far one and a wide camera as much as a tele that
   resolves angles twice as finely; pixel residuals weigh each photo by what it measures, so
   with equal isotropic pixel noise this is the maximum-likelihood point (the photogrammetric
   space intersection).

Conventions: poses map the common frame (here the board frame) to the camera,
``X_cam = R @ X + t_mm`` (README, "Conventions"); points are (N, 3) in mm.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.camera import CameraModel, ideal_normalized_from_pixel, project_with_jacobians
from ..errors import EstimationError
from ..geometry.model import Pose

_PARALLEL_EIGENVALUE = 1e-12   # smallest eigenvalue of sum_i P_i below which rays count as parallel


def viewing_rays(cam: CameraModel, pose: Pose, uv_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays of observed pixels in the pose's 'from' frame.

    Parameters
    ----------
    cam : the camera that took the photo.
    pose : its pose, common frame -> camera.
    uv_px : (N, 2) observed (distorted) pixels.

    Returns
    -------
    centre_mm : (3,) perspective centre ``-R^T t`` (paper eq. 11).
    directions : (N, 3) unit vectors ``R^T (x, y, 1) / |(x, y, 1)|``.
    """
    xy = ideal_normalized_from_pixel(cam, uv_px)
    d_cam = np.column_stack([xy, np.ones(len(xy))])
    d = d_cam @ pose.R                        # rows R^T d_cam
    return pose.center_mm, d / np.linalg.norm(d, axis=1, keepdims=True)


def intersect_rays(centres_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Least-squares intersection of M >= 2 rays for each of N points.

    Parameters
    ----------
    centres_mm : (M, 3) ray origins, or (M, N, 3) one origin per ray and point.
    directions : (M, N, 3) unit directions.

    Returns
    -------
    (N, 3) points minimising the sum of squared perpendicular distances to their M rays.

    Raises
    ------
    EstimationError
        Fewer than two rays, or (nearly) parallel rays for some point.
    """
    d = np.asarray(directions, dtype=float)
    if d.ndim != 3 or d.shape[0] < 2:
        raise EstimationError("an intersection needs at least two rays per point")
    C = np.asarray(centres_mm, dtype=float)
    C = np.broadcast_to(C[:, None, :] if C.ndim == 2 else C, d.shape)
    origin = C.mean(axis=0)                                                  # (N, 3)
    P = np.eye(3) - d[..., :, None] * d[..., None, :]                       # (M, N, 3, 3)
    A = P.sum(axis=0)
    b = np.einsum("mnij,mnj->ni", P, C - origin)
    smallest = np.linalg.eigvalsh(A)[:, 0]
    if np.any(smallest < _PARALLEL_EIGENVALUE):
        raise EstimationError(f"{int(np.sum(smallest < _PARALLEL_EIGENVALUE))} point(s) seen along parallel "
                              "rays: the photos give no intersection (same position, or no base)")
    return origin + np.linalg.solve(A, b[..., None])[..., 0]


def triangulate(cameras: Sequence[CameraModel], poses: Sequence[Pose], uv_px: Sequence[np.ndarray],
                max_iter: int = 20, tol_mm: float = 1e-9) -> np.ndarray:
    """Space intersection of N points observed in M >= 2 oriented photos.

    The linear point of :func:`intersect_rays` refined by Gauss-Newton on the pixel residuals
    ``project(cam_i, R_i X + t_i) - uv_i`` of all photos (module docstring).

    Parameters
    ----------
    cameras, poses, uv_px
        per photo its camera, its pose (common frame -> camera) and its
        (N, 2) observed pixels of the same N points (all measured: no NaN rows).
    max_iter, tol_mm
        Gauss-Newton stops when no point moves more than ``tol_mm``.

    Returns
    -------
    (N, 3) ndarray
        The points in the common frame, mm.

    Raises
    ------
    EstimationError
        An unmeasured (NaN) point, parallel rays, a point behind a camera, or no convergence.
    """
    if not all(np.all(np.isfinite(uv)) for uv in uv_px):
        raise EstimationError("space intersection needs every point measured in every photo: select the "
                              "points all photos saw (unmeasured corners are NaN rows)")
    rays = [viewing_rays(c, p, uv) for c, p, uv in zip(cameras, poses, uv_px, strict=True)]
    X = intersect_rays(np.array([c for c, _ in rays]), np.array([d for _, d in rays]))
    for _ in range(max_iter):
        N = np.zeros((len(X), 3, 3))
        g = np.zeros((len(X), 3))
        for cam, pose, uv in zip(cameras, poses, uv_px, strict=True):
            X_cam = pose.apply(X)
            if np.any(X_cam[:, 2] <= 0):
                raise EstimationError("an intersected point lies behind a camera: the photos' poses disagree")
            uv_hat, J_X, _ = project_with_jacobians(cam, X_cam)
            J = J_X @ pose.R                                                 # (N, 2, 3)
            N += np.einsum("nki,nkj->nij", J, J)
            g += np.einsum("nki,nk->ni", J, uv_hat - uv)
        step = np.linalg.solve(N, -g[..., None])[..., 0]
        X = X + step
        if np.max(np.abs(step)) <= tol_mm:
            return X
    raise EstimationError(f"space intersection did not converge in {max_iter} Gauss-Newton steps")
