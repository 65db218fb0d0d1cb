"""Pose algebra (dualcal.geometry.poses): increments, directions on the sphere, the omega-phi-kappa Jacobian."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualcal.geometry.model import Pose
from dualcal.geometry.poses import moved_on_sphere, opk_jacobian, relative_pose, rotated, tangent_basis
from dualcal.geometry.rotation import opk_from_rotation, rotation_from_opk, rotation_from_rotvec

unit_vectors = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1).map(
    lambda v: np.array(v) / np.linalg.norm(v))


@settings(max_examples=100, deadline=None)
@given(u=unit_vectors)
def test_tangent_basis_is_orthonormal_right_handed_and_orthogonal_to_u(u):
    B = tangent_basis(u)
    np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(u @ B, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(B[:, 0], B[:, 1]), u, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(u=unit_vectors, delta=st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)))
def test_moving_on_the_sphere_turns_by_the_length_of_the_increment(u, delta):
    delta = np.array(delta)
    moved = moved_on_sphere(u, delta)
    assert np.linalg.norm(moved) == pytest.approx(1.0, abs=1e-12)
    assert np.arccos(np.clip(moved @ u, -1, 1)) == pytest.approx(np.linalg.norm(delta), abs=1e-7)


def test_sphere_increment_has_the_basis_as_derivative_and_minus_u_as_curvature():
    u = np.array([0.3, -0.9, 0.2])
    u /= np.linalg.norm(u)
    B, h = tangent_basis(u), 1e-4
    for a in range(2):
        e = np.eye(2)[a] * h
        plus, minus = moved_on_sphere(u, e), moved_on_sphere(u, -e)
        np.testing.assert_allclose((plus - minus) / (2 * h), B[:, a], atol=1e-8)
        np.testing.assert_allclose((plus - 2 * u + minus) / h**2, -u, atol=1e-5)   # used by the paper's Hessian


def test_rotated_is_a_left_increment_on_stacks():
    R = np.stack([rotation_from_rotvec([0.1, 0.2, -0.3]), np.eye(3)])
    d = np.array([[0.01, -0.02, 0.03], [0.0, 0.0, 0.5]])
    out = rotated(R, d)
    for k in range(2):
        np.testing.assert_allclose(out[k], rotation_from_rotvec(d[k]) @ R[k], atol=1e-15)


@pytest.mark.parametrize("opk_deg", [(1.0, 2.0, -3.0), (40.0, -70.0, 120.0), (-10.0, 85.0, 5.0)])
def test_opk_jacobian_matches_central_differences(opk_deg):
    R = rotation_from_opk(np.radians(opk_deg))
    J, h = opk_jacobian(opk_from_rotation(R)), 1e-6
    for i in range(3):
        d = np.eye(3)[i] * h
        num = (opk_from_rotation(rotated(R, d)) - opk_from_rotation(rotated(R, -d))) / (2 * h)
        np.testing.assert_allclose(J[:, i], num, atol=1e-6 / np.cos(np.radians(opk_deg[1])))


def test_opk_jacobian_blows_up_for_omega_and_kappa_at_the_gimbal_lock():
    J = opk_jacobian(np.array([0.1, np.pi / 2, 0.2]))
    assert np.abs(J[[0, 2], :2]).min() > 1e12 and np.abs(J[1]).max() <= 1.0


def test_relative_pose_maps_reference_to_camera():
    ref = Pose(rotation_from_rotvec([0.2, -0.1, 0.05]), np.array([10.0, -20.0, 500.0]))
    rel = Pose(rotation_from_rotvec([0.01, 0.02, -0.03]), np.array([0.3, -11.0, 0.2]))
    X = np.random.default_rng(0).normal(0, 100, (5, 3))
    found = relative_pose(ref, rel.compose(ref))
    np.testing.assert_allclose(found.apply(ref.apply(X)), rel.apply(ref.apply(X)), atol=1e-9)


def test_the_consensus_pose_is_the_mean_where_every_pose_agrees_and_leaves_a_turned_one_out():
    from dualcal.geometry.model import Pose, consensus_pose, mean_pose
    from dualcal.geometry.rotation import rotation_from_rotvec

    rng = np.random.default_rng(0)
    poses = [Pose(rotation_from_rotvec(0.01 * rng.standard_normal(3)), np.array([100.0, 0, 0]) + rng.standard_normal(3))
             for _ in range(9)]
    assert np.array_equal(consensus_pose(poses).R, mean_pose(poses).R)
    turned = poses + [Pose(rotation_from_rotvec(np.array([0.0, np.pi, 0.0])), np.array([-100.0, 0, 0]))]
    kept, mean_of_all = consensus_pose(turned), mean_pose(turned)
    assert np.allclose(kept.R, mean_pose(poses).R) and np.allclose(kept.t_mm, mean_pose(poses).t_mm)
    assert np.linalg.norm(mean_of_all.t_mm - mean_pose(poses).t_mm) > 10.0      # the turned pose pulls the plain mean


def test_rotation_angle_deg_is_the_angle_of_the_relative_rotation_and_broadcasts():
    from dualcal.geometry.rotation import rotation_angle_deg, rotation_from_rotvec

    rng = np.random.default_rng(3)
    R = np.array([rotation_from_rotvec(rng.normal(0, 1, 3)) for _ in range(4)])
    turn = np.radians([0.5, 10.0, 90.0, 170.0])
    axis = rng.normal(0, 1, (4, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    Q = np.array([r @ rotation_from_rotvec(a * t) for r, a, t in zip(R, axis, turn)])
    assert np.allclose(rotation_angle_deg(R, Q), np.degrees(turn), atol=1e-5)
    outer = rotation_angle_deg(R[:, None], Q[None, :])
    assert outer.shape == (4, 4) and np.allclose(np.diag(outer), np.degrees(turn), atol=1e-5)
