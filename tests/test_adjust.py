"""The joint adjustment (dualcal.estimation.adjust): exact Jacobians on partial views in every rig mode, the
paper's model as the constrained form it replaces, sigma propagation, the per-instant pieces of
the reduced system, and optimality against an independent solver."""

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

from dualcal.estimation.adjust import OisPrior, Problem, cost, initial_state, instant_rows, linearise, residuals
from dualcal.estimation.rig_relations import rig_relation
from dualcal.estimation.fitting import solve, usable_photos
from dualcal.geometry.camera import CameraModel, project_points
from dualcal.geometry.focus import PhotoFocus
from dualcal.geometry.model import Pose, choose_reference
from dualcal.geometry.poses import relative_pose
from dualcal.geometry.rotation import opk_from_rotation, rotation_from_opk, rotation_from_rotvec, rotvec_from_rotation
from dualcal.synthetic.synth import make_truth, noisy_corner_set


def _corners(preset, views, seed, noise, missing=0.3, absent=()):
    """A synthetic corner set with a share ``missing`` of the corners not measured (NaN) and the
    photos ``absent`` ((camera, view) pairs) not taken."""
    truth = make_truth(preset, views, seed=seed)
    corners = noisy_corner_set(truth, noise, seed=seed + 1)
    rng = np.random.default_rng(seed + 2)
    for name, cc in corners.cameras.items():
        for v, uv in cc.views.items():
            uv[rng.random(len(uv)) < missing] = np.nan
            if (name, v) in absent:
                cc.views[v] = None
    return truth, corners


def _setup(corners, mode="rigid", skew=False):
    """The arguments of :func:`dualcal.estimation.fitting.solve` for ``corners``."""
    names = sorted(corners.cameras)
    X = corners.board.object_points_mm()
    sizes = [corners.cameras[n].image_size for n in names]
    return X, names, sizes, usable_photos(corners, names, X[:, :2]), names.index(choose_reference(names)), skew, mode


def _truth_state(problem, truth, wiggle=0.0, seed=0):
    """The true state in ``problem``'s layout, moved by a random step of size ``wiggle`` (so that
    the residuals are not zero and the paper's directions differ between instants)."""
    cams = [truth.cameras[n] for n in problem.cameras]
    poses = [{v: truth.camera_pose(n, v) for v in truth.view_poses} for n in problem.cameras]
    state = initial_state(problem, cams, poses)
    rng = np.random.default_rng(seed)
    h = rng.normal(0, wiggle, problem.layout.n_global + problem.layout.local_used.size)
    h[problem.layout.n_global:] *= problem.layout.local_used.ravel()
    h[problem.layout.n_global:] *= 1e-2                  # poses: radians and mm
    return state.updated(problem.layout, h)


def _used(problem):
    return np.concatenate([np.ones(problem.layout.n_global, bool), problem.layout.local_used.ravel()])


def _flat_residuals(problem, state):
    r = residuals(problem, state)
    return r[np.isfinite(r[..., 0])].ravel()


def _numeric_jacobian(problem, state, step=1e-6):
    n = len(_used(problem))
    J = np.zeros((len(_flat_residuals(problem, state)), n))
    for j in np.flatnonzero(_used(problem)):
        e = np.zeros(n)
        e[j] = step
        J[:, j] = (_flat_residuals(problem, state.updated(problem.layout, e))
                   - _flat_residuals(problem, state.updated(problem.layout, -e))) / (2 * step)
    return J


def _dense(ne):
    """The whole normal matrix and gradient from the per-instant pieces (flat numbering)."""
    G, (V, L) = ne.n_global, ne.local_used.shape
    N = np.zeros((G + V * L, G + V * L))
    N[:G, :G] = ne.gg.sum(axis=0)
    for v in range(V):
        s = slice(G + v * L, G + (v + 1) * L)
        N[:G, s], N[s, :G], N[s, s] = ne.gl[v], ne.gl[v].T, ne.ll[v]
    return N, ne.gradient()


PARTIAL_CASES = [("stereo", "rigid", (), False), ("triple", "rigid", (("wide", "IMG_02"),), True),
                 ("triple", "paper", (("wide", "IMG_02"), ("ultra", "IMG_01")), True),
                 ("note8", "none", (("tele", "IMG_03"),), False), ("note8", "none", (), True)]


@pytest.mark.parametrize("preset,mode,absent,board_shape", PARTIAL_CASES)
def test_jacobian_rows_of_every_instant_match_central_differences(preset, mode, absent, board_shape):
    """Partial views (30 % of the corners missing, whole photos absent, in paper mode an instant
    without the reference), with and without the board's shape: each instant's Jacobian rows, and
    the normal equations assembled from them, are those of the residuals' central differences."""
    truth, corners = _corners(preset, 4, seed=3, noise=0.1, absent=absent)
    args = _setup(corners, mode)
    problem = Problem(*args[:4], mode=mode, reference=args[4], board_shape=board_shape)
    state = _truth_state(problem, truth, wiggle=1e-3)
    J = _numeric_jacobian(problem, state)
    r = _flat_residuals(problem, state)
    counts = [2 * int(np.isfinite(uv[:, 0]).sum()) for _, _, uv in problem.blocks]
    starts = np.concatenate([[0], np.cumsum(counts)])
    N_rows, g_rows = np.zeros((J.shape[1],) * 2), np.zeros(J.shape[1])
    for inst in instant_rows(problem, state):
        rows = np.concatenate([np.arange(starts[b], starts[b + 1]) for b, (_, v, _) in enumerate(problem.blocks)
                               if v == inst.view])
        block = J[rows]
        np.testing.assert_allclose(inst.J, block[:, inst.columns], rtol=1e-5, atol=1e-5 * np.abs(block).max())
        others = np.delete(block, inst.columns, axis=1)
        assert np.abs(others).max() <= 1e-6 * np.abs(block).max()
        np.testing.assert_allclose(inst.r, r[rows], atol=1e-12)
        N_rows[np.ix_(inst.columns, inst.columns)] += inst.J.T @ inst.J
        g_rows[inst.columns] += inst.J.T @ inst.r
    F, ne = linearise(problem, state)
    N, g = _dense(ne)
    used = _used(problem)
    np.testing.assert_allclose(N[np.ix_(used, used)], N_rows[np.ix_(used, used)], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(g[used], g_rows[used], rtol=1e-9, atol=1e-9)
    assert F == pytest.approx(r @ r, rel=1e-12) and cost(problem, state) == pytest.approx(F, rel=1e-12)


@pytest.mark.parametrize("preset,mode,absent,board_shape", PARTIAL_CASES[1:])
def test_the_instants_leverage_from_the_normal_equations_is_that_of_their_rows(preset, mode, absent, board_shape):
    """Each instant's CR2 shift of the globals and its held-out sums of squares per photo, found from the normal
    equations kept photo by photo (:mod:`dualcal.estimation.uncertainty`), are those of its Jacobian rows: the
    eigen-decomposition of its hat block ``H = J N^-1 J^T`` (the directions of leverage 1, its own poses, left
    out of the score and kept in the held-out residuals ``(I - H)^-1 r``), ``r`` the residuals at the linearised
    minimum (plus ``J`` times the remaining Gauss-Newton step)."""
    truth, corners = _corners(preset, 9, seed=5, noise=0.2, absent=absent)
    X, names, sizes, blocks, ref, skew, _ = _setup(corners, mode)
    sol = solve(X, names, sizes, blocks, ref, skew, mode, board_shape=board_shape)
    G, inverse = sol.problem.layout.n_global, sol.factorization.inverse_block
    held, step = sol.held_out_squares(), sol.factorization.step()
    for inst in instant_rows(sol.problem, sol.state):
        r = inst.r + inst.J @ step[inst.columns]
        Q, R = np.linalg.qr(inst.J)
        lam, V = np.linalg.eigh(R @ inverse(inst.columns) @ R.T)
        U, own = Q @ V, 1 - lam <= 1e-9
        w = U @ (np.where(own, 0.0, 1 / np.sqrt(np.where(own, 1.0, 1 - lam))) * (U.T @ r))
        both = inverse(np.concatenate([np.arange(G), inst.columns]))
        np.testing.assert_allclose(sol.instant_shifts(np.arange(G))[inst.view], both[:G, G:] @ (inst.J.T @ w),
                                   rtol=1e-6, atol=1e-9 * np.abs(both[:G, G:] @ (inst.J.T @ w)).max())
        e = r + U @ (np.where(own, 0.0, lam / np.where(own, 1.0, 1 - lam)) * (U.T @ r))
        for c, (squares, n) in held[inst.view].items():
            mine = inst.row_cameras == c
            assert 2 * n == mine.sum() and squares == pytest.approx(float(e[mine] @ e[mine]), rel=1e-7)


def _relative_values(problem, state):
    """``[D, omega, phi, kappa]`` of every instant the reference and the other camera of a
    two-camera rig share, from each camera's own pose (mode ``none``): the quantities of the
    paper's constraints (eqs. 20-23)."""
    ref, other, out = problem.reference, 1 - problem.reference, []
    for v in np.flatnonzero(problem.seen(ref) & problem.seen(other)):
        rel = relative_pose(Pose(state.pose_R[v, ref], state.pose_t[v, ref]),
                            Pose(state.pose_R[v, other], state.pose_t[v, other]))
        out.append(np.concatenate([[np.linalg.norm(rel.t_mm)], opk_from_rotation(rel.R)]))
    return np.array(out)


def test_the_paper_parametrisation_solves_the_constrained_form():
    """The paper's model as a parametrisation and as constraints on every camera's own poses
    (``D_q = D_1`` and equal angles, q = 2..m, Lagrange multipliers) have the same solution and
    the same covariance: at the parametrised solution the constraints hold, the gradient of the
    cost over the free poses is a combination of the constraints' gradients (the KKT
    conditions), and the constrained covariance ``N^-1 - N^-1 C^T (C N^-1 C^T)^-1 C N^-1`` gives
    D and the intrinsics the sigmas the parametrisation reports."""
    truth, corners = _corners("note8", 6, seed=5, noise=0.2, missing=0.2)
    args = _setup(corners, "paper")
    sol = solve(*args)
    p = sol.problem
    free = Problem(*args[:4], mode="none", reference=args[4])
    cams = [sol.state.camera(p, c) for c in range(2)]
    poses = [{v: sol.photo_poses[c, v] for cc, v, _ in p.blocks if cc == c} for c in range(2)]
    x = initial_state(free, cams, poses)
    F, ne = linearise(free, x)
    assert F == pytest.approx(sol.s0_px ** 2 * sol.redundancy, rel=1e-12)
    values = _relative_values(free, x)
    np.testing.assert_allclose(values - values[0], 0.0, atol=1e-9)          # the constraints hold

    def constraints(state):
        vals = _relative_values(free, state)
        return (vals[1:] - vals[0]).ravel()
    used = _used(free)
    C = np.zeros((len(constraints(x)), len(used)))
    for j in np.flatnonzero(used):
        e = np.zeros(len(used))
        e[j] = 1e-6
        C[:, j] = (constraints(x.updated(free.layout, e)) - constraints(x.updated(free.layout, -e))) / 2e-6
    N, g = _dense(ne)
    N, g, C = N[np.ix_(used, used)], g[used], C[:, used]
    lam = np.linalg.lstsq(C.T, g, rcond=None)[0]
    assert np.linalg.norm(g - C.T @ lam) < 1e-6 * np.linalg.norm(g)       # KKT
    assert sol.redundancy == free.n_observations - free.n_parameters + len(C)
    Ni = np.linalg.inv(N)
    Q = sol.s0_px ** 2 * (Ni - Ni @ C.T @ np.linalg.solve(C @ Ni @ C.T, C @ Ni))
    J_D = np.zeros(len(used))          # D = |t| of the first shared instant, by central differences
    for k, j in enumerate(np.flatnonzero(used)):
        e = np.zeros(len(used))
        e[j] = 1e-6
        J_D[k] = (_relative_values(free, x.updated(free.layout, e))[0, 0]
                  - _relative_values(free, x.updated(free.layout, -e))[0, 0]) / 2e-6
    assert np.sqrt(J_D @ Q @ J_D) == pytest.approx(rig_relation(sol, 1 - p.reference)[2], rel=1e-4)
    for c in range(2):
        cols = free.layout.intrinsics[c]
        np.testing.assert_allclose(np.sqrt(np.diag(Q)[cols]),
                                   [s for s in sol.intrinsic_sigma(c).values() if s > 0], rtol=1e-4)


@pytest.mark.parametrize("mode,rtol", [("rigid", 1e-5), ("paper", 1e-5), ("none", 2e-2)])
def test_rig_sigmas_are_the_propagated_covariance(mode, rtol):
    """t, D and omega-phi-kappa of every tied camera: their sigmas are ``J Cov J^T`` with ``J`` by
    central differences of what :func:`rig_relation` reports (mode ``none``: its first-order
    mean of rotations, hence the looser tolerance)."""
    truth, corners = _corners("triple", 5, seed=6, noise=0.2, missing=0.2)
    sol = solve(*_setup(corners, mode))
    p = sol.problem
    cols = np.flatnonzero(_used(p))
    cov = sol.covariance(cols)
    for c in (c for c in range(3) if c != p.reference):
        def values(state):
            pose = rig_relation(dataclasses.replace(sol, state=state), c)[0]
            return np.concatenate([pose.t_mm, [np.linalg.norm(pose.t_mm)], pose.opk_arcmin])
        J = np.zeros((7, len(cols)))
        for k, j in enumerate(cols):
            e = np.zeros(len(_used(p)))
            e[j] = 1e-7
            J[:, k] = (values(sol.state.updated(p.layout, e)) - values(sol.state.updated(p.layout, -e))) / 2e-7
        expected = np.sqrt(np.diag(J @ cov @ J.T))
        _, sigma_t, sigma_D, sigma_opk = rig_relation(sol, c)
        np.testing.assert_allclose(np.concatenate([sigma_t, [sigma_D], sigma_opk]), expected, rtol=rtol)


def test_the_rigid_solution_is_the_optimum_of_an_independent_model():
    """The same photos (30 % of the corners missing) fitted by scipy's least_squares on a model
    written here from the contract's formulas, started away from dualcal's solution: it comes
    back to it."""
    truth, corners = _corners("stereo", 5, seed=8, noise=0.2, missing=0.3)
    args = _setup(corners, "rigid")
    sol = solve(*args)
    p, st = sol.problem, sol.state
    X, V = p.X_board, len(p.views)

    def unpack(x):
        intr = x[:12].reshape(2, 6)
        cams = [CameraModel(p.image_sizes[c], *intr[c, :2], 0.0, *intr[c, 2:]) for c in range(2)]
        rig = Pose(rotation_from_rotvec(x[12:15]), x[15:18])
        views = [Pose(rotation_from_rotvec(x[18 + 6 * v:21 + 6 * v]), x[21 + 6 * v:24 + 6 * v]) for v in range(V)]
        return cams, rig, views

    def res(x):
        cams, rig, views = unpack(x)
        out = []
        for c, view, uv in p.blocks:
            pose = views[p.view_index[view]]
            if c != p.reference:
                pose = rig.compose(pose)
            seen = np.isfinite(uv[:, 0])
            out.append((project_points(cams[c], pose.apply(X[seen])) - uv[seen]).ravel())
        return np.concatenate(out)

    tied = 1 - p.reference
    x0 = np.concatenate([np.delete(st.intrinsics[c][:7], 2) for c in range(2)]     # k1k2: p1 p2 k3 stay 0
                        + [rotvec_from_rotation(st.rig_R[tied]), st.rig_t[tied]]
                        + [np.concatenate([rotvec_from_rotation(st.pose_R[v, 0]), st.pose_t[v, 0]]) for v in range(V)])
    assert res(x0) @ res(x0) == pytest.approx(sol.s0_px ** 2 * sol.redundancy, rel=1e-12)
    start = x0 + np.random.default_rng(0).normal(0, 1e-3, len(x0)) * np.maximum(1, np.abs(x0)) * 1e-2
    fit = least_squares(res, start, xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale="jac")
    assert 2 * fit.cost == pytest.approx(res(x0) @ res(x0), rel=1e-9)
    sigma = np.array([s for c in range(2) for s in sol.intrinsic_sigma(c).values() if s > 0])
    assert np.abs((fit.x[:12] - x0[:12]) / sigma).max() < 1e-3


def test_a_corner_behind_a_camera_makes_a_state_inadmissible():
    truth, corners = _corners("stereo", 3, seed=1, noise=0.0, missing=0.0)
    args = _setup(corners)
    p = Problem(*args[:4], mode="rigid", reference=args[4])
    state = _truth_state(p, truth)
    assert cost(p, state) < 1e-18
    state.pose_t[0, 0] *= -1                                 # instant 0's board behind the cameras
    assert cost(p, state) == np.inf


def test_omega_phi_kappa_near_the_gimbal_lock_warn(capsys):
    truth, corners = _corners("stereo", 4, seed=2, noise=0.1, missing=0.0)
    sol = solve(*_setup(corners))
    state = dataclasses.replace(sol.state, rig_R=sol.state.rig_R.copy())
    state.rig_R[1] = rotation_from_opk(np.radians([0.1, 88.0, 0.2]))
    rig_relation(dataclasses.replace(sol, state=state), 1)
    assert "phi = 88.0 degrees, near the omega-phi-kappa singularity" in capsys.readouterr().err
    rig_relation(sol, 1)
    assert "singularity" not in capsys.readouterr().err


@pytest.mark.parametrize("mode", ["rigid", "paper", "none"])
def test_the_lens_motion_terms_have_exact_jacobians_and_their_priors_rows(mode):
    """Lenses that breathe with focus (a coefficient per camera) and photos shifted by the stabiliser (a random
    effect per photo): the Jacobian rows are those of the residuals' central differences, and the normal equations
    are the rows' plus the shifts' prior ``(scale / sigma)^2`` on each shift, its gradient and its cost."""
    truth = make_truth("note8", 4, seed=3, breathing=1.5, ois_px=1.0)
    corners = noisy_corner_set(truth, 0.1, seed=4)
    args = _setup(corners, mode)
    focus = PhotoFocus({"wide": 4.3, "tele": 6.0}, {"wide": 550.0, "tele": 560.0},
                       {(n, v): truth.photo_lenses[v][n].focus_mm for n in args[1] for v in truth.view_poses}, {})
    ois = OisPrior({"wide": 1.5, "tele": 0.8}, 0.2)
    problem = Problem(*args[:4], mode=mode, reference=args[4], board_shape=True, focus=focus,
                      breathing=("tele", "wide"), ois=ois)
    rng = np.random.default_rng(5)
    state = _truth_state(problem, truth, wiggle=1e-3)
    state.breathing[:] = [1.2, 0.7]
    state.ois_px[:] = rng.normal(0.0, 1.0, state.ois_px.shape)
    J, r = _numeric_jacobian(problem, state), _flat_residuals(problem, state)
    counts = [2 * int(np.isfinite(uv[:, 0]).sum()) for _, _, uv in problem.blocks]
    starts = np.concatenate([[0], np.cumsum(counts)])
    lay, used = problem.layout, _used(problem)
    for inst in instant_rows(problem, state):
        rows = np.concatenate([np.arange(starts[b], starts[b + 1]) for b, (_, v, _) in enumerate(problem.blocks)
                               if v == inst.view])
        np.testing.assert_allclose(inst.J, J[rows][:, inst.columns], rtol=1e-5, atol=1e-5 * np.abs(J[rows]).max())
    prior = np.zeros(len(used))
    shifts = np.zeros(len(used))
    for c, slots in lay.ois.items():
        for v in np.flatnonzero(lay.local_used[:, slots[0]]):
            prior[lay.local_columns(v, slots)] = ois.information(problem.cameras[c])
            shifts[lay.local_columns(v, slots)] = state.ois_px[v, c]
    assert np.count_nonzero(prior) == 2 * len(problem.blocks)
    F, ne = linearise(problem, state)
    N, g = _dense(ne)
    np.testing.assert_allclose(N[np.ix_(used, used)], (J.T @ J + np.diag(prior))[np.ix_(used, used)], rtol=1e-6,
                               atol=1e-6 * np.abs(N).max())
    np.testing.assert_allclose(g[used], (J.T @ r + prior * shifts)[used], rtol=1e-6, atol=1e-6 * np.abs(g).max())
    assert F == pytest.approx(r @ r + shifts @ (prior * shifts), rel=1e-12) and cost(problem, state) == pytest.approx(F)


@pytest.mark.parametrize("mode", ["rigid", "paper", "none"])
def test_a_solutions_residuals_are_those_at_its_state(mode):
    """A solution keeps the residuals its last normal equations were built from (not computed again): they are
    :func:`residuals` at its state, NaN where a corner was not measured, unweighted where the photos are weighed and
    the lens moves (breathing, the stabiliser's shifts)."""
    truth = make_truth("note8", 5, seed=6, breathing=1.5, ois_px=1.0)
    corners = noisy_corner_set(truth, 0.2, seed=7)
    uv = corners.cameras["tele"].views["IMG_02"]
    uv[:7] = np.nan
    args = _setup(corners, mode)
    focus = PhotoFocus({"wide": 4.3, "tele": 6.0}, {"wide": 550.0, "tele": 560.0},
                       {(n, v): truth.photo_lenses[v][n].focus_mm for n in args[1] for v in truth.view_poses}, {})
    weights = {(n, v): 0.5 + 0.1 * i for i, (n, v) in enumerate((n, v) for n in args[1] for v in truth.view_poses)}
    problem = Problem(*args[:4], mode=mode, reference=args[4], focus=focus, breathing=("tele",),
                      ois=OisPrior({"wide": 1.5, "tele": 0.8}, 0.2), weights=weights)
    from dualcal.estimation.adjust import adjust
    sol = adjust(problem, _truth_state(problem, truth, wiggle=1e-3))
    expected = residuals(problem, sol.state)
    assert np.array_equal(np.isnan(sol.residuals), np.isnan(expected)) and np.isnan(sol.residuals).any()
    np.testing.assert_allclose(sol.residuals, expected, rtol=0, atol=1e-12)
