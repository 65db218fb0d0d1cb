"""Rotations (omega-phi-kappa convention) and board geometry."""

import numpy as np
import pytest

from dualcal.geometry.board import Board, is_black_square, parse_board_spec
from dualcal.errors import InputError
from dualcal.geometry.rotation import (cross_matrix, nearest_rotation, opk_from_rotation, rotation_from_opk,
                                       rotation_from_rotvec, rotvec_from_rotation)


def _Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_opk_is_rz_ry_rx_and_round_trips():
    opk = np.array([0.1, -0.25, 1.2])
    R = rotation_from_opk(opk)
    np.testing.assert_allclose(R, _Rz(opk[2]) @ _Ry(opk[1]) @ _Rx(opk[0]), atol=1e-15)
    np.testing.assert_allclose(opk_from_rotation(R), opk, atol=1e-14)


def test_rotvec_round_trip_and_cross_matrix():
    w = np.array([0.3, -0.2, 0.9])
    np.testing.assert_allclose(rotvec_from_rotation(rotation_from_rotvec(w)), w, atol=1e-14)
    v = np.array([1.0, 2.0, -3.0])
    np.testing.assert_allclose(cross_matrix(w) @ v, np.cross(w, v), atol=1e-15)


def test_rotvec_and_opk_agree_with_scipy_at_every_angle():
    """dualcal's own Rodrigues formulas (scipy's Rotation costs a third of a second to import) against
    scipy's, from 0 (and 1e-9 rad) to pi, one-by-one and stacked: to 1e-14."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    axes = rng.normal(size=(500, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-9, 1e-5, 1e-4, 2e-4, np.pi - 1e-6], rng.uniform(0, np.pi, 494)])
    v = axes * angles[:, None]
    R = rotation_from_rotvec(v)
    assert np.abs(R - Rotation.from_rotvec(v).as_matrix()).max() < 1e-14
    assert np.abs(rotation_from_rotvec(v[7]) - R[7]).max() == 0.0
    back = rotvec_from_rotation(R)
    assert np.abs(rotation_from_rotvec(back) - R).max() < 1e-14
    assert np.abs(back - Rotation.from_matrix(R).as_rotvec()).max() < 1e-9
    opk = rng.uniform(-1.5, 1.5, 3)
    assert np.abs(rotation_from_opk(opk) - Rotation.from_euler("ZYX", opk[::-1]).as_matrix()).max() < 1e-15


def test_nearest_rotation_recovers_a_perturbed_rotation():
    R = rotation_from_opk([0.2, 0.1, -0.4])
    Rn = nearest_rotation(R + 1e-3 * np.random.default_rng(0).normal(size=(3, 3)))
    np.testing.assert_allclose(Rn @ Rn.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rn) == pytest.approx(1.0)
    assert np.max(np.abs(Rn - R)) < 3e-3


def test_board_corner_numbering_and_colours():
    b = Board(8, 5, 30.0)
    X = b.object_points_mm()
    assert X.shape == (40, 3)
    np.testing.assert_array_equal(X[9], [30.0, 30.0, 0.0])       # k = r*cols + c with r=1, c=1
    np.testing.assert_array_equal(X[39], [210.0, 120.0, 0.0])
    assert is_black_square(-1, -1) and not is_black_square(0, -1)
    assert not b.is_symmetric and Board(7, 9, 30).is_symmetric


@pytest.mark.parametrize("spec", ["8", "8x", "ax5", "8x5x3", "1x5", ""])
def test_malformed_board_spec(spec):
    with pytest.raises(InputError, match="--board"):
        parse_board_spec(spec)


def test_board_rejects_bad_square():
    with pytest.raises(InputError, match="square"):
        Board(8, 5, -1.0)
