"""Pose algebra for the adjustment: increments, relative poses, unit directions, angle Jacobians.

Conventions (README, "Conventions"): a pose maps ``X_to = R @ X_from + t_mm``; a non-reference
camera ``c`` sees ``X_c = R_c @ X_ref + t_c``. The adjustment never works on angles: a rotation is
updated by a left increment, ``R <- exp([d]x) R`` (``d`` a rotation vector, radians), so its
covariance is that of ``d``, and there is no singularity anywhere. omega-phi-kappa are derived
for display only (:func:`opk_jacobian` carries a covariance over to them; it is singular at
``phi = +-90 deg``).

A unit vector ``u`` (the direction of a baseline) is updated on the sphere by a 2-vector
``delta`` along an orthonormal basis ``B(u)`` of its tangent plane (:func:`tangent_basis`):
``u <- cos|delta| u + sin|delta| B delta / |delta|``, whose derivative at ``delta = 0`` is ``B``.

All functions work on stacks: (..., 3, 3) rotations, (..., 3) vectors.
"""

from __future__ import annotations

import numpy as np

from .model import Pose
from .rotation import rotation_from_rotvec


def relative_pose(ref: Pose, cam: Pose) -> Pose:
    """Reference-to-camera pose from both board-to-camera poses of one instant."""
    return cam.compose(ref.inverse())


def rotated(R: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``exp([d]x) @ R`` for (..., 3, 3) rotations and (..., 3) rotation vectors (radians)."""
    d = np.asarray(d, float)
    return (rotation_from_rotvec(d.reshape(-1, 3)).reshape(d.shape[:-1] + (3, 3))) @ R


def tangent_basis(u: np.ndarray) -> np.ndarray:
    """(..., 3, 2) orthonormal basis ``[b1, b2]`` of the plane orthogonal to unit vectors ``u``.

    ``b1`` is ``u`` crossed with the coordinate axis least aligned with it, so the basis is a
    smooth function of ``u`` away from the switch between axes; ``(b1, b2, u)`` is right-handed.
    """
    u = np.asarray(u, float)
    axis = np.eye(3)[np.argmin(np.abs(u), axis=-1)]
    b1 = np.cross(u, axis)
    b1 /= np.linalg.norm(b1, axis=-1, keepdims=True)
    b2 = np.cross(u, b1)
    return np.stack([b1, b2], axis=-1)


def moved_on_sphere(u: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Unit vectors ``u`` (..., 3) moved by tangent increments ``delta`` (..., 2) (module docstring)."""
    step = np.einsum("...ij,...j->...i", tangent_basis(u), delta)
    angle = np.linalg.norm(delta, axis=-1, keepdims=True)
    sinc = np.sinc(angle / np.pi)                       # sin(angle) / angle, 1 at 0
    moved = np.cos(angle) * u + sinc * step
    return moved / np.linalg.norm(moved, axis=-1, keepdims=True)


def opk_jacobian(opk_rad: np.ndarray) -> np.ndarray:
    """(3, 3) derivative of ``[omega, phi, kappa]`` with respect to a left rotation increment.

    With ``R = Rz(kappa) Ry(phi) Rx(omega)`` the increment ``d`` of ``exp([d]x) R`` is
    ``d = M [d_omega, d_phi, d_kappa]`` with ``M = [Rz Ry e_x, Rz e_y, e_z]`` (the three rotation
    axes in the frame they act in), so the Jacobian is ``M^-1``. ``det M = cos(phi)``: omega and
    kappa are undefined at ``phi = +-90 deg``, and their rows grow like ``1 / cos(phi)`` near it.
    """
    _, phi, kappa = opk_rad
    ck, sk, cp, sp = np.cos(kappa), np.sin(kappa), np.cos(phi), np.sin(phi)
    # M^-1 in closed form (M = [[ck cp, -sk, 0], [sk cp, ck, 0], [-sp, 0, 1]])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.array([[ck / cp, sk / cp, 0.0], [-sk, ck, 0.0], [ck * sp / cp, sk * sp / cp, 1.0]])
