"""Each instant's relative poses from the cameras-alone solution (dualcal.estimation.instant_poses): their
deviation's Jacobian, an instant's tie cost against the others as a chi-square, and a refocus told by the pose."""

import dataclasses

import numpy as np
import pytest

from dualcal.estimation import calibrate, checking
from dualcal.estimation.instant_poses import (deleted_costs, focal_responses, instant_relations, refocus_explained,
                                              relation_deviation, relations_of)
from dualcal.geometry.camera import project_points
from dualcal.geometry.model import CameraCorners, CornerSet, Pose
from dualcal.geometry.poses import rotated
from dualcal.geometry.rotation import rotation_from_rotvec
from dualcal.synthetic.synth import make_truth, noisy_corner_set


def _solutions(monkeypatch, corners):
    """The rig's solution (flat board) and the cameras-alone one that its checks see."""
    seen = {}

    def spy(rig, sol, tied, alone, attribution=None):
        seen.update(tied=tied, alone=alone)
        return {}

    monkeypatch.setattr(checking, "run_checks", spy)
    monkeypatch.setattr(checking, "loop_closure", lambda *args: None)
    calibrate.calibrate_rig(corners, drop_outliers=False, board_shape="flat")
    return seen["tied"], seen["alone"]


def test_the_deviation_jacobian_is_the_finite_difference():
    """Two board poses and a relation some arcminutes and tenths of a millimetre from theirs (the deviation is small,
    where its Jacobian is taken): the Jacobian by the poses' increments is the finite difference's."""
    rng = np.random.default_rng(0)
    P_x = Pose(rotation_from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 100, 3) + [0, 0, 600])
    P_y = Pose(rotation_from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 100, 3) + [0, 0, 600])
    R = P_y.R @ P_x.R.T
    R_J, t_J = rotation_from_rotvec(rng.normal(0, 1e-3, 3)) @ R, P_y.t_mm - R @ P_x.t_mm + rng.normal(0, 0.3, 3)
    d0, J = relation_deviation(P_x.R, P_x.t_mm, P_y.R, P_y.t_mm, R_J, t_J)
    step = 1e-6
    for k in range(12):
        h = np.zeros(12)
        h[k] = step
        moved = [Pose(rotated(P.R, h[6 * i:6 * i + 3]), P.t_mm + h[6 * i + 3:6 * i + 6]) for i, P in enumerate((P_x, P_y))]
        d1, _ = relation_deviation(moved[0].R, moved[0].t_mm, moved[1].R, moved[1].t_mm, R_J, t_J)
        np.testing.assert_allclose((d1 - d0) / step, J[:, k], rtol=0, atol=2e-3 * max(1.0, np.abs(J[:, k]).max()))


def test_the_deviations_of_a_stack_of_instants_are_each_instants():
    """Instants stacked give each instant's deviation and Jacobian, as one at a time (the loop check's batch)."""
    rng = np.random.default_rng(1)
    Rs = rotation_from_rotvec(rng.normal(0, 0.3, (2, 5, 3)))
    ts = rng.normal(0, 100, (2, 5, 3)) + [0, 0, 600]
    R_J, t_J = rotation_from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 50, 3)
    D, J = relation_deviation(Rs[0], ts[0], Rs[1], ts[1], R_J, t_J)
    assert D.shape == (5, 6) and J.shape == (5, 6, 12)
    for i in range(5):
        d, Ji = relation_deviation(Rs[0, i], ts[0, i], Rs[1, i], ts[1, i], R_J, t_J)
        np.testing.assert_allclose(D[i], d, rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[i], Ji, rtol=0, atol=1e-12)


def test_an_instants_tie_cost_against_the_others_is_near_a_chi_square(monkeypatch):
    """White corner noise of 0.1 px on a stereo rig of 30 instants: each instant's tie cost against the others
    (their relations, less it, with their own covariance) over its 6 degrees of freedom averages a little above 1
    (1 with the intrinsics exact: the cameras-alone solution's error in them moves each instant's relative pose
    its own way, beyond the photos' pose covariance; the checks take the scale from the instants' scatter), and an
    instant outside a core is judged against all of the core's relations, with their covariance."""
    truth = make_truth("stereo", 30, seed=11)
    tied, alone = _solutions(monkeypatch, noisy_corner_set(truth, 0.1, seed=11))
    rel = instant_relations(tied, alone)
    costs = deleted_costs(rel, np.ones(len(rel.views), bool))
    assert rel.dofs.tolist() == [6] * 30
    assert 1.0 - 3 * np.sqrt(2 / (6 * 30)) < np.mean(costs / 6) < 2.0
    core = np.ones(30, bool)
    core[[3, 7]] = False
    i = 3                                         # outside the core: judged against all of it
    d = rel.z[i] - relations_of(rel, core)[rel.columns(i)]
    info, _ = rel.information(core)
    cols = rel.columns(i)
    expected = d @ np.linalg.solve(rel.cov[i] + np.linalg.inv(info[np.ix_(cols, cols)]), d)
    assert deleted_costs(rel, core)[i] == pytest.approx(expected, rel=1e-9)


def test_a_refocused_photo_is_told_by_its_instants_relative_pose(monkeypatch):
    """The tele's photo of one instant taken 0.5 % longer: with every camera alone its pose takes the focal change
    up (nearer, and turned), so its instant's relative pose moves along that response: a focal change of the tele
    of +0.5 % (or one of the wide of -0.5 %: the relative pose cannot tell them apart) explains all of it."""
    truth = make_truth("note8", 13, seed=2)
    corners = noisy_corner_set(truth, 0.05, seed=2)
    tele = truth.cameras["tele"]
    zoomed = dataclasses.replace(tele, fx=1.005 * tele.fx, fy=1.005 * tele.fy)
    X = truth.board.object_points_mm()
    views = dict(corners.cameras["tele"].views)
    views["IMG_07"] = project_points(zoomed, truth.camera_pose("tele", "IMG_07").apply(X)) \
        + np.random.default_rng(2).normal(0, 0.05, (len(X), 2))
    corners = CornerSet(corners.board, {**corners.cameras, "tele": CameraCorners(tele.image_size, views)})
    tied, alone = _solutions(monkeypatch, corners)
    rel = instant_relations(tied, alone)
    core = np.array([v != "IMG_07" for v in rel.views])
    shares = refocus_explained(rel, rel.views.index("IMG_07"), core, focal_responses(alone, {"IMG_07"}),
                               tied.problem.reference)
    wide, tele_ = (shares[tied.problem.cameras.index(n)] for n in ("wide", "tele"))
    assert tele_[0] > 0.95 and tele_[1] == pytest.approx(0.005, abs=0.0008)
    assert wide[0] > 0.95 and wide[1] == pytest.approx(-0.005, abs=0.0008)
