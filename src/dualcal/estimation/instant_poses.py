"""Each instant's relative poses of the cameras, from the solution with every camera alone: what one instant
says of the rig, to judge it against the others (``rig_rigid``) and the pairs of cameras against the rig
(``loop_closure``), without adjusting the rig again.

With every camera alone (rig mode ``none``) each photo has its own board pose ``X_c = R_c X_board + t_c``, so
instant ``v`` shows camera ``y``'s pose relative to camera ``x``: ``R = R_y R_x^T``, ``t = t_y - R t_x``. Its
deviation from a relation ``(R_J, t_J)`` is ``d = (rotvec(R R_J^T), t - t_J)`` (rad, mm; the rotation as a left
increment, as the adjustment moves rotations), and to first order in the two photos' pose increments
``(a_x, b_x, a_y, b_y)`` (rotation, translation)::

    d_rot = a_y - R a_x,    d_t = b_y - R b_x + [R t_x]x (a_y - R a_x)

so its covariance is ``J C J^T``, ``C`` the two photos' pose covariance from the cameras-alone solution
(white corner noise: ``s0^2`` times the inverse normal matrix, :meth:`dualcal.estimation.adjust.Solution.covariance`).
In the paper's model (rig mode ``paper``) the baseline's direction is free in every instant, so only the
rotation and the baseline's length deviate: ``d = (rotvec(R R_J^T), |t| - D)``, 4 per camera.

Tying an instant's photos to relations ``theta`` costs, to first order and with the intrinsics held,
``(z - theta)^T Cov^-1 (z - theta)``: its tie cost. The relations that the instants ``S`` tell together are the
weighted mean of theirs (:func:`relations_of`); an instant judged against the others gets the cost of its
deviation from their mean, with that mean's own covariance added (:func:`deleted_costs`), whichever bad instants
are outside ``S``: nearly a chi-square of ``k`` degrees of freedom (6 per tied camera, 4 in the paper's model) in
units of the white noise, for an instant like the others (the intrinsics' error, which the covariance given them
leaves out, moves each instant's relative pose its own way and adds some: on a VGA stereo rig of 30 instants
with white noise they averaged 1.46 ``k`` (tests/test_instant_poses.py); noise correlated within the photos adds
more, and the checks take the scale from the instants' own scatter).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .adjust import Solution
from .normal_equations import PhotoNormals
from ..geometry.model import stacked
from ..geometry.rotation import cross_matrix, rotvec_from_rotation

__all__ = ["InstantRelations", "best_fitting_half", "deleted_costs", "fit_costs", "focal_column", "focal_responses",
           "instant_relations", "pose_columns", "refocus_explained", "relation_deviation", "relations_of"]


def pose_columns(sol: Solution, view: str, c: int) -> np.ndarray:
    """The flat columns (6,) of camera ``c``'s own board pose in instant ``view`` of a cameras-alone solution."""
    lay = sol.problem.layout
    return lay.local_columns(sol.problem.view_index[view], lay.pose[c])


def relation_deviation(R_x: np.ndarray, t_x: np.ndarray, R_y: np.ndarray, t_y: np.ndarray, R_J: np.ndarray,
                       t_J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The deviation ``d`` (..., 6) of the relative pose of board poses ``(R_x, t_x)`` -> ``(R_y, t_y)`` (stacks
    (..., 3, 3) and (..., 3) of the instants) from ``(R_J, t_J)`` and its Jacobian (..., 6, 12) by the two poses'
    increments ``(a_x, b_x, a_y, b_y)`` (module docstring)."""
    R = R_y @ np.swapaxes(R_x, -1, -2)
    Rt_x = np.einsum("...ij,...j->...i", R, t_x)
    K = cross_matrix(Rt_x)
    J = np.zeros(R.shape[:-2] + (6, 12))
    J[..., :3, :3], J[..., :3, 6:9] = -R, np.eye(3)
    J[..., 3:, :3], J[..., 3:, 3:6], J[..., 3:, 6:9], J[..., 3:, 9:] = -K @ R, -R, K, np.eye(3)
    return np.concatenate([rotvec_from_rotation(R @ np.swapaxes(R_J, -1, -2)), t_y - Rt_x - t_J], axis=-1), J


@dataclass(frozen=True)
class InstantRelations:
    """Every instant's deviations from the joint relations of its tied cameras (module docstring).

    ``views`` (n,) the instants where the reference and another camera have photos; per instant ``cameras``
    its tied cameras' indices, ``z`` (k,) the deviations (``k = per`` times their number), ``cov`` (k, k) their
    covariance in px^2 of white corner noise (``s0^2`` included), ``weight`` its inverse, and ``jacobian``
    (k, 6 (m + 1)) the deviations' by the pose increments of the instant's photos (the reference's first, then the
    tied cameras'). ``per`` is 6 (``rigid``) or 4 (``paper``), ``n_cameras`` the rig's cameras."""

    views: list[str]
    cameras: list[list[int]]
    z: list[np.ndarray]
    cov: list[np.ndarray]
    per: int
    n_cameras: int
    weight: list[np.ndarray]
    jacobian: list[np.ndarray]

    def only(self, keep) -> "InstantRelations":
        """The instants where ``keep`` (n,) is true."""
        pick = [i for i, k in enumerate(keep) if k]
        return replace(self, **{name: [getattr(self, name)[i] for i in pick]
                                for name in ("views", "cameras", "z", "cov", "weight", "jacobian")})

    @property
    def dofs(self) -> np.ndarray:
        """(n,) each instant's degrees of freedom."""
        return np.array([len(z) for z in self.z])

    def columns(self, i: int) -> np.ndarray:
        """Where instant ``i``'s deviations sit in the stacked relations (``per`` per camera)."""
        return np.concatenate([np.arange(self.per * c, self.per * (c + 1)) for c in self.cameras[i]])

    def information(self, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The information matrix and score of the stacked relations (``per`` per camera) from the instants
        ``members`` (n,) bool."""
        size = self.per * self.n_cameras
        info, score = np.zeros((size, size)), np.zeros(size)
        for i in np.flatnonzero(members):
            cols = self.columns(i)
            info[np.ix_(cols, cols)] += self.weight[i]
            score[cols] += self.weight[i] @ self.z[i]
        return info, score


def instant_relations(tied: Solution, alone: Solution) -> InstantRelations:
    """Every instant's relative poses from ``alone`` (every camera alone) against the relations of ``tied``
    (rig mode ``rigid`` or ``paper``, over the same photos), with their covariance given the intrinsics (each
    photo's pose block of the inverse normal matrix: the tie cost holds the intrinsics too)."""
    p = tied.problem
    ref, per = p.reference, 6 if p.mode == "rigid" else 4
    poses, ll_inv, s02 = alone.photo_poses, alone.factorization.ll_inv, alone.s0_px ** 2
    lay = alone.problem.layout
    tied_cams = {view: [c for c in range(len(p.cameras)) if c != ref and (c, view) in poses]
                 for view in alone.problem.views if (ref, view) in poses}
    tied_cams = {view: cams for view, cams in tied_cams.items() if cams}
    pairs = [(view, c) for view, cams in tied_cams.items() for c in cams]
    if not pairs:
        return InstantRelations([], [], [], [], per, len(p.cameras), [], [])
    d, Jd = relation_deviation(*stacked([poses[ref, view] for view, _ in pairs]),          # every pair at once
                               *stacked([poses[c, view] for view, c in pairs]),
                               np.array([tied.state.rig_R[c] for _, c in pairs]),
                               np.array([tied.state.rig_t[c] if per == 6 else np.zeros(3) for _, c in pairs]))
    if per == 4:                                   # the paper's model: the baseline's length alone
        length = np.linalg.norm(d[:, 3:], axis=1)
        u = d[:, 3:] / length[:, None]
        d = np.column_stack([d[:, :3], length - np.array([tied.state.baseline_mm[c] for _, c in pairs])])
        Jd = np.concatenate([Jd[:, :3], np.einsum("pi,pij->pj", u, Jd[:, 3:])[:, None]], axis=1)
    views, cameras, zs, covs, jacobians = [], [], [], [], []
    first = 0
    for view, cams in tied_cams.items():
        vi = alone.problem.view_index[view]
        slots = np.concatenate([lay.pose[ref]] + [lay.pose[c] for c in cams])
        C = s02 * ll_inv[vi][np.ix_(slots, slots)]
        J = np.zeros((per * len(cams), 6 * (len(cams) + 1)))
        for i in range(len(cams)):
            rows = slice(per * i, per * (i + 1))
            J[rows, :6], J[rows, 6 * (i + 1):6 * (i + 2)] = Jd[first + i, :, :6], Jd[first + i, :, 6:]
        views.append(view)
        cameras.append(cams)
        zs.append(d[first:first + len(cams)].ravel())
        covs.append(J @ C @ J.T)
        jacobians.append(J)
        first += len(cams)
    return InstantRelations(views, cameras, zs, covs, per, len(p.cameras), [np.linalg.inv(c) for c in covs],
                            jacobians)


def _solved(info: np.ndarray, score: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The relations and their covariance on the entries ``known`` (bool) that some instant informs."""
    cov = np.linalg.inv(info[np.ix_(known, known)])
    theta = np.zeros(len(score))
    theta[known] = cov @ score[known]
    return theta, cov


def _shown(rel: InstantRelations, members: np.ndarray) -> np.ndarray:
    """(per * n_cameras,) bool: the entries of the cameras some instant of ``members`` shows."""
    counts = np.zeros(rel.n_cameras, int)
    for i in np.flatnonzero(members):
        counts[rel.cameras[i]] += 1
    return np.repeat(counts > 0, rel.per)


def relations_of(rel: InstantRelations, members: np.ndarray) -> np.ndarray:
    """The relations (stacked, ``per`` per camera; 0 where no member shows the camera) that the instants
    ``members`` (n,) bool tell together: the weighted mean of theirs."""
    return _solved(*rel.information(members), _shown(rel, members))[0]


def deleted_costs(rel: InstantRelations, core: np.ndarray) -> np.ndarray:
    """(n,) every instant's tie cost (px^2 of white noise) against the relations of the instants ``core`` (n,)
    bool without it: ``(z - theta)^T (Cov + Cov_theta)^-1 (z - theta)`` (module docstring); inf where the core
    without it shows not every camera of the instant."""
    info, score = rel.information(core)
    if len({tuple(c) for c in rel.cameras}) == 1:            # every instant of the same cameras: all at once
        return _deleted_costs_alike(rel, core, info, score)
    out = np.empty(len(rel.views))
    for i, z in enumerate(rel.z):
        cols = rel.columns(i)
        M, b, members = info, score, core
        if core[i]:                                  # the core without it: its information and score taken away
            M, b, members = info.copy(), score.copy(), core.copy()
            M[np.ix_(cols, cols)] -= rel.weight[i]
            b[cols] -= rel.weight[i] @ z
            members[i] = False
        known = _shown(rel, members)
        if not known[cols].all():
            out[i] = np.inf
            continue
        theta, cov = _solved(M, b, known)
        at = np.searchsorted(np.flatnonzero(known), cols)
        d = z - theta[cols]
        out[i] = float(d @ np.linalg.solve(rel.cov[i] + cov[np.ix_(at, at)], d))
    return out


def _deleted_costs_alike(rel: InstantRelations, core: np.ndarray, info: np.ndarray, score: np.ndarray) -> np.ndarray:
    """:func:`deleted_costs` where every instant shows the same cameras: their relations' information and score
    less each core instant's own, solved for all instants at once."""
    cols = rel.columns(0)
    if core.sum() < 2:
        return np.full(len(rel.views), np.inf)
    W, z = np.array(rel.weight), np.array(rel.z)                               # (n, k, k), (n, k)
    own = core[:, None, None]
    M = info[np.ix_(cols, cols)][None] - np.where(own, W, 0.0)
    b = score[cols][None] - np.where(own[..., 0], np.einsum("nkl,nl->nk", W, z), 0.0)
    cov = np.linalg.inv(M)
    d = z - np.einsum("nkl,nl->nk", cov, b)
    return np.einsum("nk,nk->n", d, np.linalg.solve(np.array(rel.cov) + cov, d[..., None])[..., 0])


def focal_column(sol: Solution, ph: PhotoNormals) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The focal column ``j = fx J_fx + fy J_fy`` (the camera's focal lengths scaled together) of the photos ``ph``
    of one camera (their pieces of ``sol``'s normal equations, at its state) against their own unknowns and
    residuals: ``J_l^T j`` (P, kl), ``j^T j`` (P,) and ``j^T r`` (P,); None where the camera's intrinsics are held
    fixed (known), whose focal length the photos do not move."""
    lay, c = sol.problem.layout, ph.camera
    if len(lay.intrinsics[c]) < 2:
        return None
    fx, fy = sol.state.intrinsics[c, :2]
    i, j = (int(np.flatnonzero(ph.global_columns == k)[0]) for k in lay.intrinsics[c][:2])   # free where any is
    return (fx * ph.gl[:, i] + fy * ph.gl[:, j],
            fx * fx * ph.gg[:, i, i] + 2 * fx * fy * ph.gg[:, i, j] + fy * fy * ph.gg[:, j, j],
            fx * ph.grad_g[:, i] + fy * ph.grad_g[:, j])


def focal_responses(alone: Solution, views) -> dict[tuple[int, str], np.ndarray]:
    """How each photo's own pose in ``alone`` (every camera alone) moves per unit of focal change of that photo
    alone, for the photos of ``views``: ``{(camera, view): (6,)}`` (rotation increment, translation; zero for a
    camera whose intrinsics are held fixed). A photo
    taken at a focal length ``1 + s`` times its camera's has the residuals ``-s J_s`` at its true pose
    (``J_s = fx dr/dfx + fy dr/dfy``), which its pose takes up as far as it can: ``s (J_p^T J_p)^-1 J_p^T J_s``
    (the board nearer, and turned where the board is tilted), from the photo's pieces of the normal equations
    (:func:`focal_column`)."""
    p, lay = alone.problem, alone.problem.layout
    out = {}
    for ph in alone.factorization.ne.photos:
        c = ph.camera
        column = focal_column(alone, ph)
        pose = [int(np.flatnonzero(ph.local_slots == slot)[0]) for slot in lay.pose[c]]   # among the photos' own
        for k, v in enumerate(ph.views):
            view = p.views[v]
            if view in views:
                out[(c, view)] = np.zeros(6) if column is None else np.linalg.solve(
                    ph.ll[k][np.ix_(pose, pose)], column[0][k][pose])
    return out


def refocus_explained(rel: InstantRelations, i: int, core: np.ndarray, responses: dict, reference: int
                      ) -> dict[int, tuple[float, float]]:
    """How far a focal change of each of instant ``i``'s photos explains the instant's deviation from the
    relations of the instants ``core`` (n,) bool without it: ``{camera: (share, s)}``, ``share`` the part of the
    instant's tie cost the focal change ``s`` of that photo takes away (the least-squares fit of ``s`` along the
    deviation its pose's response makes, :func:`focal_responses`, in the deviation's metric). Of two cameras
    the relative pose alone cannot tell which refocused (one longer, or the other shorter, look alike)."""
    others = core.copy()
    others[i] = False
    d = rel.z[i] - relations_of(rel, others)[rel.columns(i)]
    W, J = rel.weight[i], rel.jacobian[i]
    cams = [reference] + rel.cameras[i]
    U = np.column_stack([J[:, 6 * j:6 * j + 6] @ responses[(c, rel.views[i])] for j, c in enumerate(cams)])
    g, h = U.T @ W @ d, np.einsum("kj,kl,lj->j", U, W, U)
    total = max(float(d @ W @ d), 1e-300)
    return {c: (float(g[j] * g[j] / h[j] / total), float(g[j] / h[j])) for j, c in enumerate(cams) if h[j] > 0}


def fit_costs(rel: InstantRelations, members: np.ndarray) -> np.ndarray:
    """(n,) every instant's tie cost (px^2 of white noise) against the relations the instants ``members`` (n,)
    bool tell together, itself among them or not (no deletion: for the relations of many instants)."""
    theta = relations_of(rel, members)
    return np.array([(z - theta[rel.columns(i)]) @ rel.weight[i] @ (z - theta[rel.columns(i)])
                     for i, z in enumerate(rel.z)])


def best_fitting_half(rel: InstantRelations, max_rounds: int = 20) -> np.ndarray:
    """(n,) bool: the ``n // 2 + 1`` instants whose tie costs per degree of freedom against their own relations
    are the least, found by concentration steps from every instant (as in least trimmed squares: the half that
    fits best gives the relations, and the half that fits those best is taken again until it stays): a start
    that bad instants, while they are fewer than half, cannot move."""
    n = len(rel.views)
    half = np.ones(n, bool)
    for _ in range(max_rounds):
        new = np.zeros(n, bool)
        new[np.argsort(fit_costs(rel, half) / rel.dofs, kind="stable")[:n // 2 + 1]] = True
        if (new == half).all():
            break
        half = new
    return half
