"""Where a circle of the board appears: the centre of its image, not the image of its centre.

Under perspective the image of a circle is an ellipse whose centre is not the projection of the
circle's centre: the near half of the circle is imaged larger than the far half, so the ellipse's
centre moves away from the projected centre, towards the near side, by an amount that grows with
the board's tilt and with the square of the circle's size. A detector measures the ellipse's centre
(its outline's, or its area's: the same for an ellipse), so a calibration that models the projected
centre is biased. Here the model is the outline's.

Closed form (the dualcal geometry; projective conics as in Hartley & Zisserman, ch. 2 and 8). In the
board plane the circle of centre ``m = (X0, Y0)`` and radius ``rho`` is the conic
``C = [[I, -m], [-m^T, m^T m - rho^2]]``, whose dual (its inverse up to scale) is
``C* = [[m m^T - rho^2 I, m], [m^T, 1]]``. The board-to-normalised-image homography of a pose is
``H = [r1 r2 t]`` (paper eq. 2 without ``A``); the circle's image is the conic ``C' = H^-T C H^-1``,
whose dual is ``H C* H^T``. An ellipse's centre is the pole of the line at infinity ``l = (0, 0, 1)``:
``x_c ~ C'^-1 l = H C* H^T l = H C* h`` with ``h`` the third row of ``H``. Written out,

    x_c ~ w * H (m, 1) - rho^2 * H (h1, h2, 0),    w = h1 X0 + h2 Y0 + h3

(``H (m, 1)`` is the circle's centre in the camera's frame and ``w`` its depth). The second term is
the bias: zero for a board parallel to the image (``h1 = h2 = 0``) or a point (``rho = 0``).

The lens's distortion then maps the ellipse: :func:`circle_image_centre` takes the ray through
``x_c`` through the camera's full projection, which is exact for the distortion's linear part over
the circle's small image (an affine map keeps an ellipse's centre) and leaves the curvature of the
distortion across the circle (second order in the circle's image size) unmodelled; the tests and
``benchmarks/bench_circles.py`` measure what that leaves.
"""

from __future__ import annotations

import numpy as np

from .camera import CameraModel, project_points
from .model import Pose

__all__ = ["circle_image_centre_rays", "circle_image_centre", "circle_centre_offset_px", "outline_centroid_px"]


def circle_image_centre_rays(pose: Pose, centres_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """Rays through the centres of the circles' images in the ideal (undistorted) camera.

    Parameters
    ----------
    pose : Pose
        board-to-camera pose (``X_cam = R X_board + t``).
    centres_mm : (N, 2) or (N, 3) ndarray
        the circles' centres in the board frame, mm, on the board's plane (a third column must be 0).
    radius_mm : float
        the circles' radius, mm.

    Returns
    -------
    (N, 3) ndarray
        Camera-frame directions (x, y, z) of the ellipses' centres, ``x_c ~ w H (m, 1) - rho^2 H (h1, h2, 0)``
        (module docstring), scaled so that ``z`` is the circle centre's depth where the bias is zero.
    """
    m = np.asarray(centres_mm, float)[:, :2]
    H = np.column_stack([pose.R[:, 0], pose.R[:, 1], pose.t_mm])
    p = m @ H[:, :2].T + H[:, 2]                   # H (m, 1): each centre in the camera frame
    w = p[:, 2]                                    # = h1 X0 + h2 Y0 + h3
    q = H[:, :2] @ H[2, :2]                        # H (h1, h2, 0)
    return p - (radius_mm ** 2 / w)[:, None] * q[None, :]     # (w p - rho^2 q) / w


def circle_image_centre(cam: CameraModel, pose: Pose, centres_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """(N, 2) pixels of the centres of the circles' images (their outlines' centres), as a detector that
    fits each circle's outline measures them: :func:`circle_image_centre_rays` through ``cam``'s full
    projection (distortion to first order over each circle, module docstring).

    Parameters
    ----------
    cam : CameraModel
        the camera and its lens.
    pose : Pose
        board-to-camera pose.
    centres_mm : (N, 2) or (N, 3) ndarray
        circle centres in the board frame, mm (``Z = 0``).
    radius_mm : float
        circle radius, mm.
    """
    return project_points(cam, circle_image_centre_rays(pose, centres_mm, radius_mm))


def circle_centre_offset_px(cam: CameraModel, pose: Pose, centres_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """(N, 2) pixels: the centre of each circle's image minus the projection of its centre, the
    perspective bias a model of projected centres leaves (module docstring)."""
    m = np.asarray(centres_mm, float)[:, :2]
    X = pose.apply(np.column_stack([m, np.zeros(len(m))]))
    return circle_image_centre(cam, pose, m, radius_mm) - project_points(cam, X)


def outline_centroid_px(cam: CameraModel, pose: Pose, centres_mm: np.ndarray, radius_mm: float,
                        samples: int = 256) -> np.ndarray:
    """(N, 2) pixels: the centroid of the area inside each circle's outline as the camera images it, distortion
    and all, from ``samples`` points of the outline (the polygon's centroid, shoelace formula).

    The reference :func:`circle_image_centre` is checked against: the same for a pinhole camera (an ellipse's
    area centroid is its centre), and, with distortion, what a detector that takes the centroid of a circle's
    image measures. ``samples`` points evenly spaced in angle on the circle make a polygon whose centroid is the
    ellipse's centre exactly where the image is an ellipse (an affine image of a regular polygon).
    """
    m = np.asarray(centres_mm, float)[:, :2]
    angle = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    ring = radius_mm * np.column_stack([np.cos(angle), np.sin(angle)])
    out = np.empty((len(m), 2))
    for i, c in enumerate(m):
        xy = c + ring
        p = project_points(cam, pose.apply(np.column_stack([xy, np.zeros(samples)])))
        q = np.roll(p, -1, axis=0)
        cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
        out[i] = np.sum((p + q) * cross[:, None], axis=0) / (3.0 * np.sum(cross))
    return out
