"""Rotations: rotation vectors, omega-phi-kappa, nearest rotation (paper sections 1.5, 1.7).

Convention: ``R_c = Rz(kappa) @ Ry(phi) @ Rx(omega)`` with right-handed (active) elementary
rotations, e.g. ``Rx(w) = [[1, 0, 0], [0, cos w, -sin w], [0, sin w, cos w]]``. Angles are in
radians unless a name says otherwise (``opk_arcmin``).
"""

from __future__ import annotations

import numpy as np

ARCMIN_PER_RAD = 180.0 * 60.0 / np.pi


def _rotation():
    """scipy's ``Rotation``, imported on first use: importing this module (and with it
    ``dualcal.model`` and ``dualcal.detect``) must not pull in scipy, so commands start fast."""
    from scipy.spatial.transform import Rotation

    return Rotation


def cross_matrix(v: np.ndarray) -> np.ndarray:
    """``[v]x`` such that ``cross_matrix(v) @ w == np.cross(v, w)``; works on (..., 3) stacks."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (3,) or (N, 3) rotation vectors (radians) -> (3, 3) or (N, 3, 3)."""
    return _rotation().from_rotvec(rotvec).as_matrix()


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_rotvec`."""
    return _rotation().from_matrix(R).as_rotvec()


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to ``M`` in the Frobenius norm (SVD; the sign fix keeps det = +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_from_opk(opk_rad) -> np.ndarray:
    """``[omega, phi, kappa]`` (radians) -> ``Rz(kappa) @ Ry(phi) @ Rx(omega)``."""
    omega, phi, kappa = np.asarray(opk_rad, dtype=float)
    return _rotation().from_euler("ZYX", [kappa, phi, omega]).as_matrix()


def opk_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_opk`: ``[omega, phi, kappa]`` in radians; works on (..., 3, 3).

    From ``R = Rz(kappa) Ry(phi) Rx(omega)``: ``R[2,1] = cos(phi) sin(omega)``,
    ``R[2,2] = cos(phi) cos(omega)``, ``R[2,0] = -sin(phi)``, ``R[1,0] = sin(kappa) cos(phi)``,
    ``R[0,0] = cos(kappa) cos(phi)``.
    """
    R = np.asarray(R, dtype=float)
    omega = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    phi = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    kappa = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([omega, phi, kappa], axis=-1)
