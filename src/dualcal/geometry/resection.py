"""Space resection: the pose of a photo (or of a rig at one instant) from known board points.

The inverse problem of :mod:`dualcal.estimation.intersect`: the cameras are calibrated and the board's
geometry is known, the board-to-camera pose is sought. It orients the photos that a calibration
did not see (the hold-out check of :mod:`dualcal.estimation.evaluation`). Corners that were not measured
(NaN rows, :func:`dualcal.geometry.model.observed_mask`) are left out; each camera may have seen other
corners.

Conventions (README, "Conventions"): ``X_cam = R @ X_board + t_mm``; a rig camera ``i`` sees
``X_i = rig[i] (X_ref)``.
"""

from __future__ import annotations

import numpy as np

from .camera import CameraModel, ideal_normalized_from_pixel, project_with_jacobians
from ..errors import EstimationError
from .model import Pose, observed_mask
from .rotation import cross_matrix, rotation_from_rotvec

MIN_RESECTION_CORNERS = 4      # IPPE's start needs four points of the plane


def fixes_homography(xy_board: np.ndarray) -> bool:
    """Whether (N, 2) board points fix a homography: four of them with no three on one line.

    Points that span a plane may still not: four corners on a row of the board and one off it leave a
    homography free along the row (each row's image fixes only the row's own projective map), as a partial
    ChArUco view often has them. The test is exact, on the board's own coordinates: the DLT of the points
    onto themselves has a null space of one dimension (the identity) where they fix a homography, and the
    points ``H0 X`` of any other view have the same null space moved by ``H0``.
    """
    xy = np.asarray(xy_board, float)
    if len(xy) < MIN_RESECTION_CORNERS:
        return False
    xy = (xy - xy.mean(axis=0)) / max(float(np.abs(xy - xy.mean(axis=0)).max()), 1e-300)
    one, zero = np.ones((len(xy), 1)), np.zeros((len(xy), 3))
    p = np.column_stack([xy, one])
    A = np.vstack([np.hstack([p, zero, -xy[:, :1] * p]), np.hstack([zero, p, -xy[:, 1:] * p])])
    s = np.linalg.svd(A, compute_uv=False)
    return bool(s[7] > 1e-9 * s[0])


def planar_pose(X_board: np.ndarray, cam: CameraModel, uv_px: np.ndarray) -> Pose:
    """Board -> camera pose from the measured corners of one photo of the planar board: IPPE on
    undistorted normalised corners (exact for exact corners), or SQPnP where the corners fix no
    homography (:func:`fixes_homography`: IPPE's start is one) or IPPE finds no pose. A board whose shape
    was estimated (corners off the plane Z = 0) gets the pose of its flat approximation, a start for
    :func:`resect`.

    Raises
    ------
    EstimationError
        Fewer than :data:`MIN_RESECTION_CORNERS` measured corners, or no solution.
    """
    seen = observed_mask(uv_px)
    if seen.sum() < MIN_RESECTION_CORNERS:
        raise EstimationError(f"space resection needs at least {MIN_RESECTION_CORNERS} measured corners "
                              f"({int(seen.sum())} given)")
    xy = ideal_normalized_from_pixel(cam, uv_px[seen]).astype(np.float64)
    flat = np.column_stack([X_board[seen, :2], np.zeros(int(seen.sum()))]).astype(np.float64)
    import cv2          # imported here: the calibration's other steps do not need OpenCV

    ok = False
    if fixes_homography(flat[:, :2]):
        ok, rvec, tvec = cv2.solvePnP(flat, xy, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(flat, xy, np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise EstimationError("space resection: no initial pose (degenerate corners?)")
    return Pose(rotation_from_rotvec(rvec.ravel()), tvec.ravel())


def resect(X_board: np.ndarray, cameras: list[CameraModel], rig: list[Pose], uv_px: list[np.ndarray],
           max_iter: int = 30, tol: float = 1e-12) -> Pose:
    """Space resection of one instant of a rig: the board -> reference pose.

    Minimises the pixel residuals of every camera's measured corners by Gauss-Newton, the rig
    being fixed: camera ``i`` sees ``X_i = rig[i] (pose X_board)``. One camera alone is the case
    ``rig = [identity]``. The start comes by :func:`planar_pose` from the camera with the most
    measured corners. The update is ``R <- exp([w]x) R, t <- exp([w]x) t + dt``, so
    ``d X_ref = -[X_ref]x w + dt``.

    Parameters
    ----------
    X_board : (N, 3) board corners, mm (Z = 0 for a flat board).
    cameras, rig, uv_px : per camera its model, its pose relative to the reference camera
        (reference -> camera) and its (N, 2) observed corners (NaN rows: not measured).

    Returns
    -------
    Pose mapping the board to the reference camera.

    Raises
    ------
    EstimationError
        Too few or degenerate corners, or no convergence.
    """
    seen = [observed_mask(uv) for uv in uv_px]
    first = int(np.argmax([s.sum() for s in seen]))
    pose = rig[first].inverse().compose(planar_pose(X_board, cameras[first], uv_px[first]))
    for _ in range(max_iter):
        J, r = [], []
        for cam, rel, uv, s in zip(cameras, rig, uv_px, seen, strict=True):
            X_ref = pose.apply(X_board[s])
            d_Xref = np.concatenate([-cross_matrix(X_ref), np.broadcast_to(np.eye(3), X_ref.shape + (3,))], axis=2)
            uv_hat, J_X, _ = project_with_jacobians(cam, rel.apply(X_ref))
            J.append((J_X @ rel.R @ d_Xref).reshape(-1, 6))
            r.append((uv_hat - uv[s]).ravel())
        J, r = np.vstack(J), np.concatenate(r)
        step, _, rank, _ = np.linalg.lstsq(J, -r, rcond=None)
        if rank < 6:
            raise EstimationError("space resection is degenerate (corners on a line?)")
        pose = Pose(rotation_from_rotvec(step[:3]), step[3:]).compose(pose)
        if np.max(np.abs(step)) <= tol * max(1.0, np.linalg.norm(pose.t_mm)):
            return pose
    raise EstimationError(f"space resection did not converge in {max_iter} Gauss-Newton steps")
