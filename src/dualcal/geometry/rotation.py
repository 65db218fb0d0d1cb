"""Rotations: rotation vectors, omega-phi-kappa, nearest rotation (paper sections 1.5, 1.7).

Convention: ``R_c = Rz(kappa) @ Ry(phi) @ Rx(omega)`` with right-handed (active) elementary
rotations, e.g. ``Rx(w) = [[1, 0, 0], [0, cos w, -sin w], [0, sin w, cos w]]``. Angles are in
radians unless a name says otherwise (``opk_arcmin``).
"""

from __future__ import annotations

import numpy as np

ARCMIN_PER_RAD = 180.0 * 60.0 / np.pi


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
    """Rodrigues: (3,) or (N, 3) rotation vectors (radians) -> (3, 3) or (N, 3, 3);
    ``R = I + sin(t) [u]x + (1 - cos(t)) [u]x^2`` for ``rotvec = t u``, written with
    ``sin(t) / t`` and ``(1 - cos(t)) / t^2`` (their series below 1e-4 rad) so that it holds at ``t = 0``."""
    v = np.asarray(rotvec, dtype=float)
    t2 = np.sum(v * v, axis=-1)[..., None, None]
    t = np.sqrt(t2)
    small = t < 1e-4
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
        b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / t2)
    K = cross_matrix(v)
    return np.eye(3) + a * K + b * (K @ K)


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_rotvec` (angle in [0, pi]); works on (..., 3, 3).

    Through the unit quaternion ``(w, x, y, z)`` of ``R``, each from the largest of ``1 + tr R`` and
    ``1 + 2 R_ii - tr R`` (so that no division is by a small number), with ``w >= 0``; then
    ``rotvec = 2 atan2(|xyz|, w) xyz / |xyz|``.
    """
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.diagonal(R, axis1=-2, axis2=-1)
    four = np.stack([1.0 + tr, 1.0 + 2.0 * d[..., 0] - tr, 1.0 + 2.0 * d[..., 1] - tr,
                     1.0 + 2.0 * d[..., 2] - tr], axis=-1)            # 4 w^2, 4 x^2, 4 y^2, 4 z^2
    k = np.argmax(four, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(four, k[..., None], -1)[..., 0], 1e-300))     # 2 |q_k|
    # 4 q_k q_j for every j, from the off-diagonal sums and differences of R
    wx, wy, wz = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    xy, xz, yz = R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2]
    rows = np.stack([np.stack([four[..., 0], wx, wy, wz], -1), np.stack([wx, four[..., 1], xy, xz], -1),
                     np.stack([wy, xy, four[..., 2], yz], -1), np.stack([wz, xz, yz, four[..., 3]], -1)], -2)
    q = np.take_along_axis(rows, k[..., None, None], -2)[..., 0, :] / (2.0 * s[..., None])
    q = np.where(q[..., :1] < 0, -q, q)
    xyz = q[..., 1:]
    n = np.linalg.norm(xyz, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(n < 1e-12, 2.0 / np.maximum(q[..., 0], 1e-300), 2.0 * np.arctan2(n, q[..., 0]) / n)
    return xyz * scale[..., None]


def rotation_angle_deg(R: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """The angle (degrees) of the rotation between ``R`` and ``Q`` (that of ``R^T Q``), for stacks (..., 3, 3)
    that broadcast against each other: ``arccos((tr(R^T Q) - 1) / 2)``."""
    tr = np.einsum("...ij,...ij->...", R, Q)
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to ``M`` (3, 3), or to each of a stack (..., 3, 3), in the Frobenius norm (SVD;
    the sign fix keeps det = +1)."""
    U, _, Vt = np.linalg.svd(M)
    U[..., :, 2] *= np.sign(np.linalg.det(U @ Vt))[..., None]
    return U @ Vt


def rotation_from_opk(opk_rad) -> np.ndarray:
    """``[omega, phi, kappa]`` (radians) -> ``Rz(kappa) @ Ry(phi) @ Rx(omega)`` (module docstring)."""
    omega, phi, kappa = np.asarray(opk_rad, dtype=float)
    (cw, sw), (cp, sp), (ck, sk) = ((np.cos(a), np.sin(a)) for a in (omega, phi, kappa))
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cw, -sw], [0.0, sw, cw]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[ck, -sk, 0.0], [sk, ck, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


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
