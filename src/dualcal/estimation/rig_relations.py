"""The rig's relative poses from an adjustment, and the joint covariance of what a calibration reports.

For every non-reference camera ``c`` the rig's relation ``X_c = R X_ref + t`` (CONTRACT.md, "Rig") as
each rig mode holds it (:mod:`dualcal.estimation.adjust`): ``rigid`` one relative pose, ``paper`` one rotation and
baseline length with a direction per instant (reported along their mean), ``none`` each instant's own
relative pose (reported as their mean). :func:`rig_linearisation` gives the relation and its Jacobian
by the adjustment's flat parameters; :func:`rig_relation` the relation with the sigmas of its
translation, baseline and omega-phi-kappa; :func:`parameter_covariance` the joint covariance of every
camera's intrinsics and every rig relation (named as :mod:`dualcal.estimation.covariance` says), which calib.json
keeps and measure, advise and the checks read.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .adjust import COVARIANCE_KINDS, Problem, Solution
from ..geometry.board import SHAPE_TERMS
from ..geometry.camera import INTRINSIC_NAMES
from .covariance import breathing_name, intrinsic_name, rig_name
from ..errors import EstimationError
from ..geometry.model import Pose, mean_pose
from ..geometry.poses import opk_jacobian, relative_pose, tangent_basis
from ..progress import warn
from ..geometry.rotation import ARCMIN_PER_RAD, cross_matrix, opk_from_rotation

__all__ = ["RigLinearisation", "parameter_covariance", "rig_linearisation", "rig_relation", "shared_views"]

NEAR_GIMBAL_DEG = 5.0    # |phi| within this of 90 degrees: omega and kappa are ill-defined


def shared_views(problem: Problem, c: int) -> list[str]:
    """Views seen by both the reference and camera ``c``."""
    both = problem.seen(c) & problem.seen(problem.reference)
    return [v for v, ok in zip(problem.views, both) if ok]


@dataclass(frozen=True)
class RigLinearisation:
    """The reference-to-camera pose ``R``, ``t`` (mm) reported for a camera and its first-order
    dependence on the flat parameters ``columns`` (k,): ``J_t`` (3, k), ``J_D`` (k,) of the baseline
    length, ``J_rot`` (3, k) of the rotation's left increment."""

    R: np.ndarray
    t: np.ndarray
    J_t: np.ndarray
    J_D: np.ndarray
    J_rot: np.ndarray
    columns: np.ndarray


def rig_linearisation(sol: Solution, c: int) -> RigLinearisation:
    """The rig relation of camera ``c`` as :func:`rig_relation` reports it, linearised.

    ``rigid``: the adjusted ``R_c, t_c``. ``paper``: ``R_c``, and ``t`` of length ``D_c`` along the
    mean of the instants' directions (D's sigma is that of the parameter itself). ``none``: the
    mean of the instants' relative poses (to first order).
    """
    p, st, lay = sol.problem, sol.state, sol.problem.layout
    if p.mode != "rigid":
        views = np.flatnonzero(p.seen(c) & p.seen(p.reference))
        if not len(views):
            raise EstimationError(f"camera {p.cameras[c]!r} shares no view with the reference "
                                  f"{p.cameras[p.reference]!r}: the rig cannot be determined")
    if p.mode == "rigid":
        R, t = st.rig_R[c], st.rig_t[c]
        cols = np.concatenate([lay.rig_rotation[c], lay.rig_translation[c]])
        J_rot, J_t = np.eye(3, 6), np.eye(3, 6, 3)
    elif p.mode == "paper":
        R, D = st.rig_R[c], st.baseline_mm[c]
        u, B = st.direction[views, c], tangent_basis(st.direction[views, c])
        m = u.sum(axis=0)
        m_hat = m / np.linalg.norm(m)
        t = D * m_hat
        cols = np.concatenate([lay.rig_rotation[c], lay.baseline[c],
                               *[lay.local_columns(v, lay.direction[c]) for v in views]])
        J_rot = np.eye(3, len(cols))
        # t = D m / |m|: d t = m_hat dD + D (I - m_hat m_hat^T) / |m| B_v d delta_v
        J_t = np.concatenate([np.zeros((3, 3)), m_hat[:, None],
                              *(D * (np.eye(3) - np.outer(m_hat, m_hat)) / np.linalg.norm(m) @ B)], axis=1)
    else:
        R, t, J_rot, J_t, cols = _mean_relative_pose(sol, c, views)
    if p.mode == "paper":
        J_D = np.sign(D) * np.eye(1, len(cols), 3)[0]
    else:
        J_D = (t / np.linalg.norm(t)) @ J_t
    return RigLinearisation(np.array(R, float), np.array(t, float), J_t, J_D, J_rot, cols)


def rig_relation(sol: Solution, c: int, kind: str = "formal", warn_gimbal: bool = True):
    """Reference-to-camera ``c`` pose and 1-sigma of ``t_mm``, baseline D and opk (arcmin), from
    the covariance ``kind`` (``formal`` or ``clustered``, :meth:`Solution.covariance`).

    The pose is that of :func:`rig_linearisation`. Sigmas propagate the covariance of the rotation
    increment, then of omega-phi-kappa through :func:`dualcal.geometry.poses.opk_jacobian`; near
    ``phi = +-90 deg`` a warning (``warn_gimbal``) says that omega and kappa are then ill-defined.
    """
    p = sol.problem
    lin = rig_linearisation(sol, c)
    R, t = lin.R, lin.t
    J = np.vstack([lin.J_t, lin.J_D, lin.J_rot])
    cov = J @ sol.covariance(lin.columns, kind) @ J.T
    opk = opk_from_rotation(R)
    if warn_gimbal and abs(abs(np.degrees(opk[1])) - 90.0) < NEAR_GIMBAL_DEG:
        warn(f"camera {p.cameras[c]!r}: phi = {np.degrees(opk[1]):.1f} degrees, near the omega-phi-kappa "
             "singularity at +-90: omega and kappa (and their sigmas) are ill-defined there; the rotation "
             "itself (R in calib.json) is as well determined as ever")
    J_opk = opk_jacobian(opk)
    sigma_opk = np.sqrt(np.maximum(np.diag(J_opk @ cov[4:7, 4:7] @ J_opk.T), 0.0)) * ARCMIN_PER_RAD
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return Pose(R.copy(), t.copy()), sigma[0:3], float(sigma[3]), sigma_opk


def parameter_covariance(sol: Solution, kinds=COVARIANCE_KINDS) -> tuple[list[str], dict[str, np.ndarray]]:
    """The joint covariance of what a calibration reports, for each covariance kind.

    Parameters (named as :mod:`dualcal.estimation.covariance` says), in order: every camera's free intrinsics
    (``"<camera>.<name>"``); for every camera
    with a rig relation its rotation's left increment (``"<camera>.rig.rotation_rad.x"``, ``.y``,
    ``.z``: ``R <- exp([d]x) R``) and its translation (``"<camera>.rig.t_mm.x"``, ...), as
    :func:`rig_linearisation` reports them; the board's shape coefficients
    (``"board.shape_mm.xx"``, ...) where estimated; every breathing coefficient (``"<camera>.breathing"``).
    Returns the names and ``{kind: (k, k)}``, the
    correlations kept (e.g. for the uncertainty of a measurement with the rig).
    """
    p, lay = sol.problem, sol.problem.layout
    names, rows = [], []                 # each reported parameter as a combination of flat columns
    for c, name in enumerate(p.cameras):
        for col, n in zip(lay.intrinsics[c], np.array(INTRINSIC_NAMES)[lay.free_intrinsics[c]]):
            names.append(intrinsic_name(name, n))
            rows.append({col: 1.0})
    for c, name in enumerate(p.cameras):
        if c == p.reference or (p.mode == "none" and not (p.seen(c) & p.seen(p.reference)).any()):
            continue
        lin = rig_linearisation(sol, c)
        for what, J in (("rotation_rad", lin.J_rot), ("t_mm", lin.J_t)):
            for axis, row in zip("xyz", J):
                names.append(rig_name(name, what, axis))
                rows.append(dict(zip(lin.columns.tolist(), row)))
    for col, term in zip(lay.board_shape, SHAPE_TERMS):
        names.append(f"board.shape_mm.{term}")
        rows.append({col: 1.0})
    for c, cols in lay.breathing.items():
        names.append(breathing_name(p.cameras[c]))
        rows.append({cols[0]: 1.0})
    columns = np.array(sorted({col for row in rows for col in row}), int)
    index = {col: i for i, col in enumerate(columns)}
    J = np.zeros((len(rows), len(columns)))
    for i, row in enumerate(rows):
        for col, value in row.items():
            J[i, index[col]] += value
    return names, {kind: J @ sol.covariance(columns, kind) @ J.T for kind in kinds}


def _mean_relative_pose(sol: Solution, c: int, views: np.ndarray):
    """Mode ``none``: the mean of the instants' relative poses and its first-order Jacobian.

    Per instant ``R_rel = R_c R_ref^T`` and ``t_rel = t_c - R_rel t_ref``. With left increments
    ``(e, f)`` of the reference's board pose and ``(a, b)`` of camera ``c``'s:
    ``d theta_rel = a - R_rel e`` and ``d t_rel = -R_rel [t_ref]x e - R_rel f + [R_rel t_ref]x a + b``.
    The mean of the rotations moves by the mean of the increments (exact where they agree).
    Returns ``R, t, J_rot (3, k), J_t (3, k)`` and the k flat columns.
    """
    p, st, lay = sol.problem, sol.state, sol.problem.layout
    ref, n = p.reference, len(views)
    rels, J_rot, J_t, cols = [], [], [], []
    for v in views:
        R_ref, t_ref = st.pose_R[v, ref], st.pose_t[v, ref]
        rel = relative_pose(Pose(R_ref, t_ref), Pose(st.pose_R[v, c], st.pose_t[v, c]))
        rels.append(rel)
        Rr = rel.R
        # reference increments (e rotation, f translation), then camera increments (a, b)
        J_rot.append(np.hstack([-Rr, np.zeros((3, 3)), np.eye(3), np.zeros((3, 3))]) / n)
        J_t.append(np.hstack([-Rr @ cross_matrix(t_ref), -Rr, cross_matrix(Rr @ t_ref), np.eye(3)]) / n)
        cols += [lay.local_columns(v, lay.pose[ref]), lay.local_columns(v, lay.pose[c])]
    mean = mean_pose(rels)
    return mean.R, mean.t_mm, np.hstack(J_rot), np.hstack(J_t), np.concatenate(cols)
