"""The joint least-squares adjustment of all cameras and views (paper section 1.7).

Minimises the pixel reprojection error of every corner in every photo of every camera
(eqs. 16-19) over the intrinsics ``[fx, fy, skew, cx, cy, k1, k2]`` of each camera and the
poses, by Levenberg-Marquardt on the normal equations (block-sparse Jacobian). Three ways to
tie the cameras together (``mode``):

``rigid``  one board-to-reference pose per view and one reference-to-camera pose per extra
           camera: the rig is rigid by construction (6 relative unknowns per camera).
``paper``  every camera its own pose in every view, plus the paper's constraints (eqs. 20-23)
           that the baseline D and the three relative angles are the same in every view:
           4 (m - 1) equations per extra camera, solved as constrained least squares with
           Lagrange multipliers, ``[[N, C^T], [C, 0]] [dx, k] = [-g, -c]`` (Mikhail &
           Ackermann, ch. 9).
``none``   every camera alone (no tie at all).

Poses are updated multiplicatively, ``R <- exp([d]x) R``, ``t <- t + dt``; the covariance of
a pose is that of ``(d, dt)``. Sigma of every parameter is ``sqrt(diag(Q) s0^2)`` with ``Q`` the
(constrained) inverse normal matrix and ``s0^2 = v^T v / redundancy`` the a-posteriori variance
factor; derived values (baseline, omega-phi-kappa) get theirs by propagation, ``J Q J^T s0^2``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .camera import INTRINSIC_NAMES, CameraModel, project_with_jacobians
from .errors import EstimationError
from .model import Pose, mean_pose
from .rotation import (ARCMIN_PER_RAD, opk_from_rotation, rotation_from_rotvec,
                       rotvec_from_rotation)

RIG_MODES = ("rigid", "paper", "none")
_SKEW = INTRINSIC_NAMES.index("skew")


@dataclass
class Problem:
    """What is observed: every camera's corners in every view it saw.

    ``blocks`` is a list of ``(camera index, view key, (N, 2) observed pixels)``; the corners are
    those of ``X_board`` (N, 3) in the same order.
    """

    X_board: np.ndarray
    cameras: list[str]
    image_sizes: list[tuple[int, int]]
    blocks: list[tuple[int, str, np.ndarray]]
    mode: str = "rigid"
    skew: bool = False
    reference: int = 0

    def __post_init__(self):
        if self.mode not in RIG_MODES:
            raise EstimationError(f"--rig {self.mode!r} is unknown (choose from {', '.join(RIG_MODES)})")
        self.views = sorted({v for _, v, _ in self.blocks})
        if self.mode == "rigid":
            self.slots = [("view", v) for v in self.views] + \
                [("rig", c) for c in range(len(self.cameras)) if c != self.reference]
        else:
            self.slots = [("pose", (c, v)) for c, v, _ in self.blocks]
        self.slot_index = {s: i for i, s in enumerate(self.slots)}
        self.free_intrinsics = [i for i in range(7) if self.skew or i != _SKEW]
        self.n_intr = len(self.free_intrinsics)
        self.n_params = self.n_intr * len(self.cameras) + 6 * len(self.slots)
        # Per-view pose slots never share a residual with each other: their part of the normal
        # matrix is block diagonal (6x6), which the solver eliminates first (see _BlockSolver).
        local = [i for i, (kind, _) in enumerate(self.slots) if kind != "rig"]
        self.local_columns = np.array([self.pose_columns(i) for i in local]).reshape(-1, 6)
        is_local = np.zeros(self.n_params, bool)
        is_local[self.local_columns.ravel()] = True
        self.global_columns = np.flatnonzero(~is_local)

    def block_slots(self, b: int) -> tuple[int, int]:
        """(pose slot, rig slot or -1) of block ``b``."""
        c, v, _ = self.blocks[b]
        if self.mode == "rigid":
            rig = -1 if c == self.reference else self.slot_index[("rig", c)]
            return self.slot_index[("view", v)], rig
        return self.slot_index[("pose", (c, v))], -1

    def intr_columns(self, c: int) -> np.ndarray:
        return self.n_intr * c + np.arange(self.n_intr)

    def pose_columns(self, slot: int) -> np.ndarray:
        return self.n_intr * len(self.cameras) + 6 * slot + np.arange(6)


@dataclass
class State:
    """The unknowns: intrinsics (C, 7) and pose slots ``R`` (P, 3, 3), ``t`` (P, 3)."""

    intr: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def updated(self, problem: Problem, dx: np.ndarray) -> "State":
        n = problem.n_intr * len(problem.cameras)
        intr = self.intr.copy()
        intr[:, problem.free_intrinsics] += dx[:n].reshape(len(problem.cameras), problem.n_intr)
        d = dx[n:].reshape(-1, 6)
        return State(intr, rotation_from_rotvec(d[:, :3]) @ self.R, self.t + d[:, 3:])

    def camera(self, problem: Problem, c: int) -> CameraModel:
        return CameraModel.from_vector(problem.image_sizes[c], self.intr[c])

    def pose(self, slot: int) -> Pose:
        return Pose(self.R[slot].copy(), self.t[slot].copy())


def residuals_and_normal_equations(problem: Problem, state: State, with_normal: bool = True):
    """Residuals ``predicted - observed`` (2 per corner, block by block), and the normal matrix
    ``N = J^T J`` (dense, n_params^2) and gradient ``J^T r``.

    The Jacobian is never stored whole: the rows of one photo depend only on its camera's
    intrinsics and one or two pose slots, so each photo's dense (2N, k) piece is multiplied out
    on its own and added into ``N`` at its columns.
    """
    X = problem.X_board
    n = len(X)
    res = np.empty(2 * n * len(problem.blocks))
    N = np.zeros((problem.n_params, problem.n_params)) if with_normal else None
    grad = np.zeros(problem.n_params) if with_normal else None
    by_cam: dict[int, list[int]] = {}
    for b, (c, _, _) in enumerate(problem.blocks):
        by_cam.setdefault(c, []).append(b)
    for c, bl in by_cam.items():
        bl = np.array(bl)
        B = len(bl)
        slots = np.array([problem.block_slots(b) for b in bl])
        Rs, ts = state.R[slots[:, 0]], state.t[slots[:, 0]]
        W = np.einsum("bij,nj->bni", Rs, X)                        # R_v X  (B, N, 3)
        Y = W + ts[:, None, :]
        has_rig = slots[0, 1] >= 0
        if has_rig:
            Rr, tr = state.R[slots[:, 1]], state.t[slots[:, 1]]
            Xc = np.einsum("bij,bnj->bni", Rr, Y) + tr[:, None, :]
        else:
            Xc = Y
        uv, J_X, J_K = project_with_jacobians(state.camera(problem, c), Xc.reshape(-1, 3))
        obs = np.concatenate([problem.blocks[b][2] for b in bl])
        r_b = (uv - obs).reshape(B, 2 * n)
        res.reshape(len(problem.blocks), 2 * n)[bl] = r_b
        if not with_normal:
            continue
        J_X = J_X.reshape(B, n, 2, 3)
        M = J_X @ Rr[:, None] if has_rig else J_X                              # d res / d Y
        parts = [J_K[:, :, problem.free_intrinsics].reshape(B, n, 2, -1),
                 -np.cross(M, W[:, :, None, :]), M]                            # intrinsics, pose slot
        cols = [np.broadcast_to(problem.intr_columns(c), (B, problem.n_intr)),
                np.array([problem.pose_columns(s) for s in slots[:, 0]])]
        if has_rig:                                                            # the rig's slot
            parts += [-np.cross(J_X, (Xc - tr[:, None, :])[:, :, None, :]), J_X]
            cols.append(np.array([problem.pose_columns(s) for s in slots[:, 1]]))
        Jb = np.concatenate(parts, axis=-1).reshape(B, 2 * n, -1)             # (B, 2N, k)
        cb = np.concatenate(cols, axis=1)                                      # (B, k)
        JbT = np.swapaxes(Jb, 1, 2)
        np.add.at(N, (cb[:, :, None], cb[:, None, :]), JbT @ Jb)
        np.add.at(grad, cb, (JbT @ r_b[:, :, None])[:, :, 0])
    return res, N, grad


# ----------------------------------------------------------------------------- the paper's constraints


def relative_pose(ref: Pose, cam: Pose) -> Pose:
    """Reference-to-camera pose from both board-to-camera poses of one view."""
    return cam.compose(ref.inverse())


def _wrap_angles(a: np.ndarray, angles: slice) -> np.ndarray:
    """``a`` with the entries ``angles`` (radians) folded into (-pi, pi]."""
    a = np.array(a, dtype=float)
    a[..., angles] = (a[..., angles] + np.pi) % (2 * np.pi) - np.pi
    return a


def _perturbed(R: np.ndarray, t: np.ndarray, i: int, step: float):
    """``(R, t)`` stacks with increment ``i`` (0-2 rotation, 3-5 translation) set to ``step``."""
    d = np.zeros(6)
    d[i] = step
    return rotation_from_rotvec(d[:3]) @ R, t + d[3:]


def _numeric_jacobian(f, slots: list[int], state: State, angles: slice, step: float = 1e-6) -> np.ndarray:
    """Central differences of ``f(state)`` with respect to the 6 increments of each pose slot;
    the entries ``angles`` of ``f`` are angles, whose differences are folded into (-pi, pi]."""
    f0 = f(state)
    J = np.zeros((len(f0), 6 * len(slots)))
    for k, s in enumerate(slots):
        for i in range(6):
            vals = []
            for sign in (1.0, -1.0):
                R, t = state.R.copy(), state.t.copy()
                R[s], t[s] = _perturbed(R[s], t[s], i, sign * step)
                vals.append(f(State(state.intr, R, t)))
            J[:, 6 * k + i] = _wrap_angles(vals[0] - vals[1], angles) / (2 * step)
    return J


_OPK = slice(1, 4)     # the angles in d_opk's [D, omega, phi, kappa]


def d_opk(R_ref, t_ref, R_cam, t_cam) -> np.ndarray:
    """``[D, omega, phi, kappa]`` of the relative pose of each view (paper eqs. 20-23).

    ``D = |C_cam - C_ref| = |t_rel|``; the angles are those of ``R_rel = R_cam R_ref^T``.
    Works on stacks: (P, 3, 3) rotations, (P, 3) translations -> (P, 4).
    """
    R = R_cam @ np.swapaxes(R_ref, -1, -2)
    t = t_cam - np.einsum("...ij,...j->...i", R, t_ref)
    return np.concatenate([np.linalg.norm(t, axis=-1)[..., None], opk_from_rotation(R)], axis=-1)


def _d_opk_jacobian(R_ref, t_ref, R_cam, t_cam, step: float = 1e-6) -> np.ndarray:
    """(P, 4, 12) derivatives of :func:`d_opk` by central differences: 6 increments of the
    reference pose, then 6 of the camera pose."""
    J = np.zeros((len(R_ref), 4, 12))
    for i in range(6):
        up, down = _perturbed(R_ref, t_ref, i, step), _perturbed(R_ref, t_ref, i, -step)
        J[:, :, i] = _wrap_angles(d_opk(*up, R_cam, t_cam) - d_opk(*down, R_cam, t_cam), _OPK) / (2 * step)
        up, down = _perturbed(R_cam, t_cam, i, step), _perturbed(R_cam, t_cam, i, -step)
        J[:, :, 6 + i] = _wrap_angles(d_opk(R_ref, t_ref, *up) - d_opk(R_ref, t_ref, *down), _OPK) / (2 * step)
    return J


def shared_views(problem: Problem, c: int) -> list[str]:
    """Views seen by both the reference and camera ``c`` (in the order used by the constraints)."""
    seen = {}
    for cam, v, _ in problem.blocks:
        seen.setdefault(v, set()).add(cam)
    return [v for v in problem.views if {problem.reference, c} <= seen.get(v, set())]


def paper_constraints(problem: Problem, state: State, with_jacobian: bool = True):
    """The paper's constraints (eqs. 20-23) ``D_q - D_1 = 0``, ``d_omega_q - d_omega_1 = 0``,
    ``d_phi_q - d_phi_1 = 0``, ``d_kappa_q - d_kappa_1 = 0`` for every extra camera and every
    shared view ``q = 2..m``: values ``g`` (K,) and Jacobian ``C`` (K, n_params) or None."""
    g_all, C_all = [], []
    for c in range(len(problem.cameras)):
        if c == problem.reference:
            continue
        views = shared_views(problem, c)
        if len(views) < 2:
            continue
        ref_slots = np.array([problem.slot_index[("pose", (problem.reference, v))] for v in views])
        cam_slots = np.array([problem.slot_index[("pose", (c, v))] for v in views])
        args = (state.R[ref_slots], state.t[ref_slots], state.R[cam_slots], state.t[cam_slots])
        f = d_opk(*args)
        g_all.append(_wrap_angles(f[1:] - f[0], _OPK).ravel())
        if not with_jacobian:
            continue
        J = _d_opk_jacobian(*args)
        C = np.zeros((len(views) - 1, 4, problem.n_params))
        for q in range(1, len(views)):
            for slot, Jq, sign in ((ref_slots[q], J[q, :, :6], 1), (cam_slots[q], J[q, :, 6:], 1),
                                   (ref_slots[0], J[0, :, :6], -1), (cam_slots[0], J[0, :, 6:], -1)):
                C[q - 1][:, problem.pose_columns(slot)] += sign * Jq
        C_all.append(C.reshape(-1, problem.n_params))
    if not g_all:
        return np.zeros(0), (np.zeros((0, problem.n_params)) if with_jacobian else None)
    return np.concatenate(g_all), (np.vstack(C_all) if with_jacobian else None)


# ----------------------------------------------------------------------------- the solver


@dataclass
class Solution:
    """Result of :func:`adjust`: the state, its covariance and the fit statistics."""

    problem: Problem
    state: State
    covariance: np.ndarray          # s0^2 Q, (n_params, n_params)
    residuals: np.ndarray           # predicted - observed, (2 N B,)
    s0_px: float
    redundancy: int
    iterations: int
    n_constraints: int
    block_rms_px: list[float] = field(default_factory=list)
    rigid_start: "Solution | None" = None   # paper mode: the rigid solution it started from

    def intrinsic_sigma(self, c: int) -> dict[str, float]:
        p = self.problem
        sig = dict.fromkeys(INTRINSIC_NAMES, 0.0)
        diag = np.sqrt(np.maximum(np.diag(self.covariance)[p.intr_columns(c)], 0.0))
        for i, s in zip(p.free_intrinsics, diag):
            sig[INTRINSIC_NAMES[i]] = float(s)
        return sig

    def propagate(self, f, slots: list[int], angles: slice) -> tuple[np.ndarray, np.ndarray]:
        """Value of ``f(state)`` and its covariance ``J Cov J^T`` through the given pose slots."""
        J = _numeric_jacobian(f, slots, self.state, angles)
        idx = np.concatenate([self.problem.pose_columns(s) for s in slots])
        return f(self.state), J @ self.covariance[np.ix_(idx, idx)] @ J.T


class _BlockSolver:
    """Solves ``A x = b`` for the damped normal matrix by eliminating the pose blocks first.

    The unknowns split into global ones (intrinsics, the rig's relative poses) and per-view pose
    slots whose 6x6 blocks of ``A`` are independent of each other. With ``W = A_ll^-1 A_lg`` the
    reduced system is ``S = A_gg - A_gl W`` (a few dozen unknowns), so the cost grows linearly,
    not cubically, with the number of photos (the classical reduced camera system).
    """

    def __init__(self, A: np.ndarray, problem: Problem):
        g, L = problem.global_columns, problem.local_columns
        self.g, self.l = g, L.ravel()
        blocks = A[L[:, :, None], L[:, None, :]]                               # (k, 6, 6)
        self.blocks_inv = np.linalg.inv(np.linalg.cholesky(blocks))          # raises if not definite
        self.blocks_inv = np.swapaxes(self.blocks_inv, -1, -2) @ self.blocks_inv
        self.A_gl = A[np.ix_(g, self.l)]
        self.W = self._block_solve(self.A_gl.T)
        self.cho = scipy.linalg.cho_factor(A[np.ix_(g, g)] - self.A_gl @ self.W)

    def _block_solve(self, b_l: np.ndarray) -> np.ndarray:
        k = len(self.blocks_inv)
        return (self.blocks_inv @ b_l.reshape(k, 6, -1)).reshape(b_l.shape)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``A^-1 b`` for a vector (n,) or a matrix (n, m)."""
        y_l = self._block_solve(b[self.l])
        x = np.empty_like(b, dtype=float)
        x[self.g] = scipy.linalg.cho_solve(self.cho, b[self.g] - self.A_gl @ y_l)
        x[self.l] = y_l - self.W @ x[self.g]
        return x


class _KKTSolver:
    """Solves ``A dx = -grad`` subject to ``C dx = -g`` (Lagrange multipliers, Mikhail & Ackermann
    ch. 9) by the Schur complement: ``dx = y - A^-1 C^T k``, ``A y = -grad``,
    ``(C A^-1 C^T) k = C y + g``. Also gives the minimum-norm (in the A metric) correction that
    restores ``C dx = -g`` alone, used as a second-order correction after a nonlinear step."""

    def __init__(self, A: np.ndarray, problem: Problem, C: np.ndarray | None):
        self.A = _BlockSolver(A, problem)
        self.C = C
        if C is not None and len(C):
            self.AiCt = self.A.solve(C.T)
            self.S = C @ self.AiCt

    def step(self, grad: np.ndarray, g: np.ndarray) -> np.ndarray:
        y = self.A.solve(-grad)
        if len(g) == 0:
            return y
        return y - self.AiCt @ np.linalg.solve(self.S, self.C @ y + g)

    def correction(self, g: np.ndarray) -> np.ndarray:
        return -self.AiCt @ np.linalg.solve(self.S, g)


def adjust(problem: Problem, state: State, max_iter: int = 100, tol: float = 1e-10) -> Solution:
    """Levenberg-Marquardt on the normal equations (with the paper's constraints in ``paper`` mode).

    In ``paper`` mode every trial step is followed by up to three second-order corrections that
    bring the (nonlinear) constraints back to zero before the step is judged by its cost.

    Raises
    ------
    EstimationError
        If the normal matrix is singular (the data do not determine the parameters).
    """
    constrained = problem.mode == "paper"
    r, Nmat, grad = residuals_and_normal_equations(problem, state)
    g, C = paper_constraints(problem, state) if constrained else (np.zeros(0), None)
    cost = r @ r
    lam = 1e-4
    it = 0
    for it in range(1, max_iter + 1):
        diag = np.maximum(np.diag(Nmat), 1e-12)
        improved = False
        while lam < 1e12:
            try:
                solver = _KKTSolver(Nmat + lam * np.diag(diag), problem, C)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = state.updated(problem, solver.step(grad, g))
            if constrained:
                for _ in range(3):
                    g_t = paper_constraints(problem, trial, with_jacobian=False)[0]
                    if np.max(np.abs(g_t)) < 1e-12:
                        break
                    trial = trial.updated(problem, solver.correction(g_t))
            r_new = residuals_and_normal_equations(problem, trial, with_normal=False)[0]
            cost_new = r_new @ r_new
            if np.isfinite(cost_new) and cost_new <= cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        rel_change = (cost - cost_new) / max(cost, 1e-300)
        state, cost = trial, cost_new
        r, Nmat, grad = residuals_and_normal_equations(problem, state)
        if constrained:
            g, C = paper_constraints(problem, state)
        lam = max(lam / 10, 1e-12)
        if rel_change < tol:
            break

    try:
        Q = _BlockSolver(Nmat, problem).solve(np.eye(len(Nmat)))
    except np.linalg.LinAlgError:
        raise EstimationError("the normal equations are singular: the photos do not determine every "
                              "parameter (too few views, or views all alike)") from None
    n_con = len(g)
    if n_con:
        QC = Q @ C.T
        Q = Q - QC @ np.linalg.solve(C @ QC, QC.T)
    redundancy = len(r) - problem.n_params + n_con
    if redundancy <= 0:
        raise EstimationError(f"not enough observations: redundancy {redundancy} (more views needed)")
    s0sq = float(r @ r) / redundancy
    n = len(problem.X_board)
    block_rms = np.sqrt(np.mean(r.reshape(len(problem.blocks), n, 2) ** 2, axis=(1, 2)) * 2)
    return Solution(problem, state, Q * s0sq, r, float(np.sqrt(s0sq)), redundancy, it, n_con,
                    block_rms.tolist())


# ----------------------------------------------------------------------------- the rig's relative poses


def rig_relation(sol: Solution, c: int):
    """Reference-to-camera ``c`` pose and 1-sigma of ``t_mm``, baseline D and opk (arcmin).

    ``rigid``: the adjusted relative pose itself. ``paper``: D and the angles (equal in every view
    by the constraints) from the first shared view, ``t`` of length D along the mean direction over
    the views. ``none``: the mean of the per-view relative poses. Sigmas by propagation of the
    adjustment's covariance.
    """
    p = sol.problem
    if p.mode == "rigid":
        slot = p.slot_index[("rig", c)]
        slots = [slot]

        def f(s):
            return _rig_values(s.pose(slot))
    else:
        views = shared_views(p, c)
        if not views:
            raise EstimationError(f"camera {p.cameras[c]!r} shares no view with the reference "
                                  f"{p.cameras[p.reference]!r}: the rig cannot be determined")
        pairs = [(p.slot_index[("pose", (p.reference, v))], p.slot_index[("pose", (c, v))]) for v in views]
        slots = [s for pair in pairs for s in pair]

        def f(s):
            rels = [relative_pose(s.pose(a), s.pose(b)) for a, b in pairs]
            t_mean = np.mean([q.t_mm for q in rels], axis=0)
            if p.mode == "paper":
                # D and the angles are equal in every view; only the direction of t is free.
                D = np.linalg.norm(rels[0].t_mm)
                return _rig_values(Pose(rels[0].R, D * t_mean / np.linalg.norm(t_mean)))
            return _rig_values(mean_pose(rels))
    values, cov = sol.propagate(f, slots, angles=slice(4, 10))   # opk and rotation vector
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    pose = _pose_from_values(values)
    return pose, sigma[0:3], float(sigma[3]), sigma[4:7] * ARCMIN_PER_RAD


def _rig_values(pose: Pose) -> np.ndarray:
    """``[t (3), D, omega, phi, kappa]`` plus the rotation vector, for propagation."""
    return np.concatenate([pose.t_mm, [np.linalg.norm(pose.t_mm)], opk_from_rotation(pose.R),
                           rotvec_from_rotation(pose.R)])


def _pose_from_values(values: np.ndarray) -> Pose:
    return Pose(rotation_from_rotvec(values[7:10]), values[0:3].copy())
