"""The joint least-squares adjustment of all cameras and views (paper section 1.7).

Minimises the pixel reprojection error of every measured corner in every photo of every camera
(eqs. 16-19) over the intrinsics of each camera (:data:`dualcal.geometry.camera.INTRINSIC_NAMES`, those
left free) and the poses, by Levenberg-Marquardt (:mod:`dualcal.estimation.lm`) on normal equations kept per
instant (:mod:`dualcal.estimation.normal_equations`). A photo's corners that were not measured (NaN rows)
simply have no residual, so two cameras of one instant may see different corners. Three ways to
tie the cameras together (``mode``):

``rigid``  per instant one board-to-reference pose; per extra camera one relative pose
           ``X_c = R_c X_ref + t_c``: the rig is rigid by construction.
``paper``  the paper's model (eqs. 20-23: baseline D and the three relative angles equal in every
           instant), as a parametrisation rather than as constraints: per extra camera one
           relative rotation ``R_c`` and one baseline length ``D_c`` shared by all instants, and
           per instant its own unit direction ``u_v`` of the baseline (2 unknowns), so
           ``X_c = R_c X_ref + D_c u_v``. In an instant the reference did not see, ``u_v`` stays
           at its starting value (the model says nothing about it there).
``none``   every camera alone: each photo its own board pose.

Unknowns are *global* (intrinsics; ``R_c, t_c`` or ``R_c, D_c``) or *local* to one instant (its
board pose, or each camera's in mode ``none``; the directions ``u_v``). :class:`Layout` says where
each sits in the flat parameter vector. Rotations are updated by left increments and directions
on the sphere (:mod:`dualcal.geometry.poses`), so covariances are those of the increments. Every
Jacobian is analytic.

With ``board_shape`` the board is not taken as flat: three global unknowns, shared by every
photo, give its out-of-plane shape (:data:`dualcal.geometry.board.SHAPE_TERMS`: sag, bend, twist), so the
corners sit at ``X + Z(X) e_z``.

With ``known`` intrinsics (:class:`dualcal.geometry.model.KnownIntrinsics`) a camera's intrinsics are held fixed
(no columns), or, in mode ``prior``, taken as a prior: rows ``sqrt(P) (theta - theta_0)`` on the named free
intrinsics, ``P = scale^2 C_0^-1`` with ``C_0`` the prior's covariance and ``scale`` (``prior_scale_px``) the
noise of a photo of weight 1, so that the prior weighs against the corners in the cost's own units (a prior's
intrinsics are held like ``fixed`` ones until ``scale`` is known). The prior's information enters the globals'
block of the normal equations whole (it belongs to no instant), and the covariance clustered by instant adds
its known variance, ``scale^2 P`` (:mod:`dualcal.estimation.uncertainty`), so that every sigma holds the
intrinsics' uncertainty too.

With ``weights`` each photo's squared residuals count with its own weight ``w_b``: the cost is
``F = sum_b w_b |r_b|^2``, each photo's residual rows and Jacobian rows scaled by ``sqrt(w_b)`` (weighted
least squares). :mod:`dualcal.estimation.photo_noise` sets ``w_b = sigma_ref^2 / sigma_b^2`` from every photo's
own noise ``sigma_b``, so that ``s0`` stays in pixels (the noise of a photo of weight 1) and a blurred photo
counts for what its corners are worth. ``residuals`` stay pixels, unweighted.

With ``focus`` (:class:`dualcal.geometry.focus.PhotoFocus`, each photo's focus) and ``breathing`` (the cameras
whose lens breathes), each of those cameras has one more global unknown, its breathing coefficient ``b``
(:mod:`dualcal.geometry.focus`): its photo focused at ``d`` sees the camera's intrinsics (given at the reference
focus ``d0``) with ``fx``, ``fy`` and ``skew`` times ``g(d) = (1 + b f/(d - f)) / (1 + b f/(d0 - f))``, so a pixel
``uv`` of the camera at ``d0`` is at ``c + g (uv - c)`` (``c`` the principal point) in that photo.

With ``ois`` (:class:`OisPrior`, optical image stabilisation) each photo of a camera it names has its own
principal-point shift ``delta`` (2, px), a local unknown of its instant added to every pixel of the photo, with a
prior of spread ``sigma_c`` per coordinate (a random effect): rows ``scale delta / sigma_c`` in the cost, ``scale``
(``OisPrior.scale_px``) the noise of a photo of weight 1 that the prior weighs against, in the cost's own units
(:mod:`dualcal.estimation.ois` takes the photo-level noise). The prior's information belongs to the shift's instant (its block of the normal equations), and
every photo's part of the cost (:meth:`Solution.block_costs`) holds its shift's prior, so that what an instant costs
tied to the rig is what its shots cost under the stabiliser's spread. :mod:`dualcal.estimation.ois` estimates
``sigma_c``.

To add a group of global parameters: give it columns in :func:`_build_layout`, a field in
:class:`State` updated in :meth:`State.updated`, and its Jacobian piece in
:func:`_jacobian_pieces`, where ``J_X`` (d residual / d camera-frame point) and the rotations are
at hand (d residual / d board point is ``J_X R_c R_v``).

Two covariances of the unknowns (``kind``): ``formal``, the textbook ``N^-1 s0^2`` with
``s0^2 = v^T v / redundancy``, and ``clustered``, from how the instants disagree with each other
(:mod:`dualcal.estimation.uncertainty`), which holds where the corner errors of one photo are correlated
(real photos). Derived values (baseline, omega-phi-kappa) get theirs by propagation, ``J Cov J^T``
(:mod:`dualcal.estimation.rig_relations`, which also builds the joint covariance calib.json keeps).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..geometry.board import SHAPE_TERMS, shape_basis, shaped_points_mm
from ..geometry.focus import PhotoFocus, focal_scale, focal_scale_per_breathing
from ..geometry.camera import (DEFAULT_LENS_MODEL, INTRINSIC_NAMES, LENS_MODELS, CameraModel, intrinsic_names,
                               project_points, project_with_jacobians)
from ..errors import EstimationError, InputError
from .lm import LMOptions, levenberg_marquardt
from ..geometry.model import KnownIntrinsics, Pose, consensus_pose, observed_mask
from .normal_equations import Factorization, NormalEquations, PhotoNormals
from ..geometry.poses import moved_on_sphere, relative_pose, rotated, tangent_basis
from .uncertainty import InstantLeverage, held_out_squares, instant_leverage

RIG_MODES = ("rigid", "paper", "none")
COVARIANCE_KINDS = ("clustered", "formal")


# ----------------------------------------------------------------------------- what is observed


@dataclass(frozen=True)
class OisPrior:
    """The stabiliser's shift of every photo as a random effect (module docstring): ``sigma_px`` ``{camera:
    spread, px per coordinate}`` of the cameras whose photos shift, ``scale_px`` the noise of a photo of weight 1 the
    prior weighs against."""

    sigma_px: Mapping[str, float]
    scale_px: float

    def information(self, camera: str) -> float:
        """``(scale / sigma)^2``: the prior's information per shift coordinate in the cost's units."""
        return (self.scale_px / self.sigma_px[camera]) ** 2


@dataclass(frozen=True)
class CameraBatch:
    """All photos of one camera: ``blocks`` (B,) indices into ``Problem.blocks``, ``views`` (B,)
    instant indices, ``uv_px`` (B, N, 2) corners (NaN rows unmeasured), ``observed`` (B, N), ``sqrt_weight``
    (B,) the square root of each photo's weight (None: every weight 1), ``focus_mm`` (B,) each photo's focus where
    the camera's lens breathes (None otherwise)."""

    camera: int
    blocks: np.ndarray
    views: np.ndarray
    uv_px: np.ndarray
    observed: np.ndarray
    sqrt_weight: np.ndarray | None = None
    focus_mm: np.ndarray | None = None


@dataclass(frozen=True)
class Layout:
    """Where each unknown sits: global columns, and local slots within an instant's block.

    Global (indices into the first ``n_global`` entries of the flat vector):
    ``intrinsics[c]`` the free intrinsics of camera ``c`` (``free_intrinsics[c]``, a (K,) mask
    over :data:`INTRINSIC_NAMES`); ``rig_rotation[c]`` (3) of each tied camera; ``rig_translation[c]``
    (3, rigid) or ``baseline[c]`` (1, paper); ``board_shape`` (3, or none) the board's shape
    coefficients; ``breathing[c]`` (1) of each camera whose lens breathes. Local (0 .. ``n_local``): ``pose[k]``
    (6: rotation increment, then translation) of pose slot ``k`` (slot 0 is the reference's board pose; in mode
    ``none`` slot ``c`` is camera ``c``'s); ``direction[c]`` (2, paper); ``ois[c]`` (2) the principal-point shift
    of camera ``c``'s photo of the instant, where it has one. ``local_used`` (V, L) marks the slots each instant has.
    """

    free_intrinsics: np.ndarray
    intrinsics: dict[int, np.ndarray]
    rig_rotation: dict[int, np.ndarray]
    rig_translation: dict[int, np.ndarray]
    baseline: dict[int, np.ndarray]
    board_shape: np.ndarray
    n_global: int
    pose: dict[int, np.ndarray]
    direction: dict[int, np.ndarray]
    n_local: int
    local_used: np.ndarray
    breathing: dict[int, np.ndarray] = field(default_factory=dict)
    ois: dict[int, np.ndarray] = field(default_factory=dict)

    def local_columns(self, view: int, slots: np.ndarray) -> np.ndarray:
        """Flat indices of local ``slots`` of instant ``view``."""
        return self.n_global + view * self.n_local + np.asarray(slots)


@dataclass
class Problem:
    """What is observed: every camera's corners in every view it saw, and how the rig is tied.

    ``blocks`` is a list of ``(camera index, view key, (N, 2) pixels)``, one per photo; row k is
    corner k of ``X_board`` (N, 3); unmeasured corners are NaN rows. ``model`` is the lens model
    (:data:`dualcal.geometry.camera.LENS_MODELS`) of every camera, or a sequence of one per camera; its
    coefficients are free, the others stay 0. ``models`` is the sequence, one per camera. ``weights``
    ``{(camera name, view): w}`` weighs each photo's squared residuals (module docstring; a photo not named,
    or no mapping: 1); ``block_weights`` (n_blocks,) is each block's. ``known`` ``{camera name:
    KnownIntrinsics}`` holds cameras' intrinsics fixed or as a prior of scale ``prior_scale_px`` (module
    docstring); ``priors`` lists the priors in force (:class:`Prior`). ``focus`` (each photo's focus) and
    ``breathing`` (camera names) free the breathing coefficient of those cameras, ``ois`` gives the photos of
    the cameras it names their own principal-point shift (module docstring).
    """

    X_board: np.ndarray
    cameras: list[str]
    image_sizes: list[tuple[int, int]]
    blocks: list[tuple[int, str, np.ndarray]]
    mode: str = "rigid"
    skew: bool = False
    reference: int = 0
    board_shape: bool = False
    model: str | tuple[str, ...] = DEFAULT_LENS_MODEL
    weights: Mapping[tuple[str, str], float] | None = None
    known: Mapping[str, KnownIntrinsics] | None = None
    prior_scale_px: float | None = None
    focus: PhotoFocus | None = None
    breathing: tuple[str, ...] = ()
    ois: OisPrior | None = None

    def __post_init__(self):
        if self.mode not in RIG_MODES:
            raise InputError(f"rig mode {self.mode!r} is unknown (choose from {', '.join(RIG_MODES)})")
        self.models = (self.model,) * len(self.cameras) if isinstance(self.model, str) else tuple(self.model)
        unknown = [m for m in self.models if m not in LENS_MODELS]
        if unknown or len(self.models) != len(self.cameras):
            raise InputError(f"lens model {unknown[0] if unknown else self.model!r} is unknown or not one per "
                             f"camera (choose from {', '.join(LENS_MODELS)})")
        self.views = sorted({v for _, v, _ in self.blocks})
        self.view_index = {v: i for i, v in enumerate(self.views)}
        weights = self.weights or {}
        self.block_weights = np.array([float(weights.get((self.cameras[c], v), 1.0)) for c, v, _ in self.blocks])
        self.batches = []
        for c in range(len(self.cameras)):
            idx = np.array([b for b, (cc, _, _) in enumerate(self.blocks) if cc == c], int)
            if len(idx):
                uv = np.array([self.blocks[b][2] for b in idx], float)
                focus = (np.array([self.focus.focus_mm[self.cameras[c], self.blocks[b][1]] for b in idx], float)
                         if self.breathes(c) else None)
                self.batches.append(CameraBatch(c, idx, np.array([self.view_index[self.blocks[b][1]] for b in idx]),
                                                uv, observed_mask(uv),
                                                np.sqrt(self.block_weights[idx]) if self.weights else None, focus))
        self.shape_basis = shape_basis(self.X_board)          # (N, 3), used when board_shape
        self.layout = _build_layout(self)
        self.priors = _priors(self)

    def breathes(self, c: int) -> bool:
        """Whether camera ``c``'s breathing coefficient is an unknown."""
        return self.focus is not None and self.cameras[c] in self.breathing

    def shifts(self, c: int) -> bool:
        """Whether camera ``c``'s photos have their own principal-point shift (OIS)."""
        return self.ois is not None and self.cameras[c] in self.ois.sigma_px

    def tied(self, c: int) -> bool:
        """Whether camera ``c`` is tied to the reference by a relative pose."""
        return self.mode != "none" and c != self.reference

    def pose_slot(self, c: int) -> int:
        """The local pose slot camera ``c``'s photos hang on."""
        return c if self.mode == "none" else 0

    @property
    def n_observations(self) -> int:
        return 2 * int(sum(b.observed.sum() for b in self.batches))

    @property
    def n_parameters(self) -> int:
        return self.layout.n_global + int(self.layout.local_used.sum())

    def held(self, c: int) -> bool:
        """Whether camera ``c``'s intrinsics are held at their known values (``fixed``, or a prior whose scale
        is not known yet)."""
        known = (self.known or {}).get(self.cameras[c])
        return known is not None and (known.mode == "fixed" or self.prior_scale_px is None)

    def seen(self, c: int) -> np.ndarray:
        """(V,) bool: the instants camera ``c`` saw."""
        out = np.zeros(len(self.views), bool)
        for b in self.batches:
            if b.camera == c:
                out[b.views] = True
        return out


def _take(counter: list[int], n: int) -> np.ndarray:
    start = counter[0]
    counter[0] += int(n)
    return np.arange(start, counter[0])


def _build_layout(p: Problem) -> Layout:
    C, V = len(p.cameras), len(p.views)
    # skew per --skew; the lens coefficients of the model (the others stay at 0)
    free = np.array([[n in intrinsic_names(m) for n in INTRINSIC_NAMES] for m in p.models]).reshape(C, -1)
    if not p.skew:
        free[:, INTRINSIC_NAMES.index("skew")] = False
    for c in range(C):
        if p.held(c):
            free[c] = False
    g = [0]
    intrinsics = {c: _take(g, free[c].sum()) for c in range(C)}
    tied = [c for c in range(C) if p.tied(c)]
    rig_rotation = {c: _take(g, 3) for c in tied}
    rig_translation = {c: _take(g, 3) for c in tied} if p.mode == "rigid" else {}
    baseline = {c: _take(g, 1) for c in tied} if p.mode == "paper" else {}
    board_shape = _take(g, len(SHAPE_TERMS) if p.board_shape else 0)
    breathing = {c: _take(g, 1) for c in range(C) if p.breathes(c)}
    loc = [0]
    pose = {k: _take(loc, 6) for k in (range(C) if p.mode == "none" else [0])}
    direction = {c: _take(loc, 2) for c in tied} if p.mode == "paper" else {}
    ois = {c: _take(loc, 2) for c in range(C) if p.shifts(c)}
    used = np.zeros((V, loc[0]), bool)
    for b in p.batches:
        used[np.ix_(b.views, pose[p.pose_slot(b.camera)])] = True
        if b.camera in ois:
            used[np.ix_(b.views, ois[b.camera])] = True
    for c, slots in direction.items():
        used[np.ix_(p.seen(c) & p.seen(p.reference), slots)] = True
    return Layout(free, intrinsics, rig_rotation, rig_translation, baseline, board_shape, g[0], pose, direction,
                  loc[0], used, breathing, ois)


@dataclass(frozen=True)
class Prior:
    """A prior on camera ``camera``'s intrinsics ``names`` (those of its known ones that are free): their known
    values ``theta0`` (p,), their global columns ``columns`` (p,) and ``root`` (p, p), ``root^T root = P`` its
    information in the cost's units (module docstring)."""

    camera: int
    names: tuple[str, ...]
    theta0: np.ndarray
    columns: np.ndarray
    root: np.ndarray

    def residual(self, state: "State") -> np.ndarray:
        """(p,) the prior's rows ``root (theta - theta0)``."""
        index = [INTRINSIC_NAMES.index(n) for n in self.names]
        return self.root @ (state.intrinsics[self.camera, index] - self.theta0)


def _priors(p: Problem) -> list[Prior]:
    """The priors in force: every known camera of mode ``prior`` once ``prior_scale_px`` is known."""
    out = []
    for c, name in enumerate(p.cameras):
        known = (p.known or {}).get(name)
        if known is None or p.held(c):
            continue
        lay = p.layout
        free = [str(n) for n in np.array(INTRINSIC_NAMES)[lay.free_intrinsics[c]]]
        names = tuple(n for n in known.names if n in free)
        if not names:
            continue
        at = [known.names.index(n) for n in names]
        information = np.linalg.inv(np.asarray(known.covariance, float))[np.ix_(at, at)]     # given the others
        root = p.prior_scale_px * np.linalg.cholesky(information).T
        out.append(Prior(c, names, np.array([getattr(known.camera, n) for n in names], float),
                         lay.intrinsics[c][[free.index(n) for n in names]], root))
    return out


# ----------------------------------------------------------------------------- the unknowns


@dataclass
class State:
    """The unknowns (conventions: README).

    intrinsics : (C, K) per camera, in the order of :data:`INTRINSIC_NAMES`.
    pose_R, pose_t : (V, P, 3, 3), (V, P, 3) board-to-camera pose of each pose slot per instant.
    rig_R : (C, 3, 3) reference-to-camera rotation (identity where the camera is not tied).
    rig_t : (C, 3) reference-to-camera translation, mm (mode ``rigid``).
    baseline_mm : (C,) the paper's D (mode ``paper``).
    direction : (V, C, 3) unit direction of the baseline per instant (mode ``paper``).
    board_shape_mm : (3,) the board's shape coefficients (:data:`dualcal.geometry.board.SHAPE_TERMS`; zero
        for a flat board).
    breathing : (C,) each camera's breathing coefficient (zero where its lens does not breathe).
    ois_px : (V, C, 2) each photo's principal-point shift, px (zero where its camera's photos do not shift).
    """

    intrinsics: np.ndarray
    pose_R: np.ndarray
    pose_t: np.ndarray
    rig_R: np.ndarray
    rig_t: np.ndarray
    baseline_mm: np.ndarray
    direction: np.ndarray
    board_shape_mm: np.ndarray = field(default_factory=lambda: np.zeros(len(SHAPE_TERMS)))
    breathing: np.ndarray | None = None
    ois_px: np.ndarray | None = None

    def __post_init__(self):
        C, V = len(self.intrinsics), len(self.pose_R)
        if self.breathing is None:
            self.breathing = np.zeros(C)
        if self.ois_px is None:
            self.ois_px = np.zeros((V, C, 2))

    def updated(self, layout: Layout, h: np.ndarray) -> "State":
        """The state moved by a flat step ``h`` (numbering of :mod:`dualcal.estimation.normal_equations`)."""
        h_g, h_l = h[:layout.n_global], h[layout.n_global:].reshape(len(self.pose_R), layout.n_local)
        intr = self.intrinsics.copy()
        for c, cols in layout.intrinsics.items():
            intr[c, layout.free_intrinsics[c]] += h_g[cols]
        rig_R, rig_t, D = self.rig_R.copy(), self.rig_t.copy(), self.baseline_mm.copy()
        for c, cols in layout.rig_rotation.items():
            rig_R[c] = rotated(rig_R[c], h_g[cols])
        for c, cols in layout.rig_translation.items():
            rig_t[c] += h_g[cols]
        for c, cols in layout.baseline.items():
            D[c] += h_g[cols[0]]
        shape = self.board_shape_mm + h_g[layout.board_shape] if len(layout.board_shape) else self.board_shape_mm
        pose_R, pose_t, direction = self.pose_R.copy(), self.pose_t.copy(), self.direction.copy()
        for k, slots in layout.pose.items():
            pose_R[:, k] = rotated(pose_R[:, k], h_l[:, slots[:3]])
            pose_t[:, k] += h_l[:, slots[3:]]
        for c, slots in layout.direction.items():
            direction[:, c] = moved_on_sphere(direction[:, c], h_l[:, slots])
        breathing, ois = self.breathing.copy(), self.ois_px.copy()
        for c, cols in layout.breathing.items():
            breathing[c] += h_g[cols[0]]
        for c, slots in layout.ois.items():
            ois[:, c] += h_l[:, slots]
        return State(intr, pose_R, pose_t, rig_R, rig_t, D, direction, shape, breathing, ois)

    def camera(self, problem: Problem, c: int) -> CameraModel:
        return CameraModel.from_vector(problem.image_sizes[c], self.intrinsics[c], problem.models[c])

    def relative_t(self, problem: Problem, c: int, views: np.ndarray) -> np.ndarray:
        """(B, 3) reference-to-camera ``c`` translation in the given instants (tied cameras)."""
        if problem.mode == "rigid":
            return np.broadcast_to(self.rig_t[c], (len(views), 3))
        return self.baseline_mm[c] * self.direction[views, c]

    def photo_poses(self, problem: Problem, c: int, views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Board-to-camera ``c`` poses in the instants ``views`` (B,): ``R`` (B, 3, 3), ``t`` (B, 3) mm."""
        k = problem.pose_slot(c)
        R, t = self.pose_R[views, k], self.pose_t[views, k]
        if not problem.tied(c):
            return R.copy(), t.copy()
        return self.rig_R[c] @ R, t @ self.rig_R[c].T + self.relative_t(problem, c, views)


def initial_state(problem: Problem, cameras: list[CameraModel], poses: list[dict[str, Pose]],
                  board_shape_mm: np.ndarray | None = None, breathing: Mapping[str, float] | None = None,
                  ois_px: Mapping[tuple[str, str], np.ndarray] | None = None) -> State:
    """Starting values in the problem's layout from every camera's own estimates.

    ``cameras[c]`` is a CameraModel, ``poses[c][view]`` a board-to-camera Pose (e.g. from Zhang's
    closed form, or from an earlier adjustment). A tied camera's relative pose starts at the mean
    of its relative poses over the instants it shares with the reference that agree (:func:`~dualcal.geometry.model.consensus_pose`; in mode ``paper``:
    ``D`` at the mean baseline length, each instant's direction at its own). The board's shape
    starts at ``board_shape_mm`` (default flat), each breathing coefficient at ``breathing[camera]`` and each
    photo's shift at ``ois_px[(camera, view)]`` (default 0; only where the problem has them). Poses of views the
    problem does not have (an earlier solution's, of photos dropped since) are ignored.
    """
    C, V, ref = len(cameras), len(problem.views), problem.reference
    rig_R, rig_t = np.tile(np.eye(3), (C, 1, 1)), np.zeros((C, 3))
    D, direction = np.zeros(C), np.zeros((V, C, 3))
    for c in range(C):
        if not problem.tied(c):
            continue
        shared = [v for v in poses[c] if v in poses[ref] and v in problem.view_index]
        if not shared:
            raise EstimationError(f"camera {problem.cameras[c]!r} shares no view with the reference camera "
                                  f"{problem.cameras[ref]!r}: photos of the same instant are needed")
        rels = {v: relative_pose(poses[ref][v], poses[c][v]) for v in shared}
        mean = consensus_pose(list(rels.values()))         # one gross instant does not throw the start off
        rig_R[c], rig_t[c] = mean.R, mean.t_mm
        D[c] = np.mean([np.linalg.norm(rel.t_mm) for rel in rels.values()])
        direction[:, c] = mean.t_mm / np.linalg.norm(mean.t_mm)
        for v, rel in rels.items():
            direction[problem.view_index[v], c] = rel.t_mm / np.linalg.norm(rel.t_mm)
    slots = C if problem.mode == "none" else 1
    pose_R, pose_t = np.tile(np.eye(3), (V, slots, 1, 1)), np.zeros((V, slots, 3))
    shape = np.zeros(len(SHAPE_TERMS)) if board_shape_mm is None else np.array(board_shape_mm, float)
    state = State(np.array([cam.as_vector() for cam in cameras]), pose_R, pose_t, rig_R, rig_t, D, direction, shape)
    for i, v in enumerate(problem.views):
        if problem.mode == "none":
            for c in range(C):
                if v in poses[c]:
                    pose_R[i, c], pose_t[i, c] = poses[c][v].R, poses[c][v].t_mm
            continue
        c = ref if v in poses[ref] else next(c for c in range(C) if v in poses[c])
        pose = poses[c][v]
        if c != ref:     # seen only by other cameras: through the rig
            rel = Pose(rig_R[c], state.relative_t(problem, c, np.array([i]))[0])
            pose = rel.inverse().compose(pose)
        pose_R[i, 0], pose_t[i, 0] = pose.R, pose.t_mm
    for c in problem.layout.breathing:
        state.breathing[c] = (breathing or {}).get(problem.cameras[c], 0.0)
    for c in problem.layout.ois:
        for (name, view), shift in (ois_px or {}).items():
            if name == problem.cameras[c] and view in problem.view_index:
                state.ois_px[problem.view_index[view], c] = shift
    return state


# ----------------------------------------------------------------------------- residuals and Jacobians


def _camera_points(problem: Problem, state: State, batch: CameraBatch):
    """``W = R_v X`` (B, N, 3), the camera-frame points ``X_c`` (B, N, 3) and the relative
    translation (B, 3) (None for an untied camera)."""
    k = problem.pose_slot(batch.camera)
    X = shaped_points_mm(problem.X_board, state.board_shape_mm) if problem.board_shape else problem.X_board
    W = X @ np.swapaxes(state.pose_R[batch.views, k], 1, 2)                                  # (B, N, 3)
    Y = W + state.pose_t[batch.views, k][:, None, :]
    if not problem.tied(batch.camera):
        return W, Y, None
    rel_t = state.relative_t(problem, batch.camera, batch.views)
    return W, Y @ state.rig_R[batch.camera].T + rel_t[:, None, :], rel_t


def _focal_scales(problem: Problem, state: State, batch: CameraBatch) -> tuple[np.ndarray, np.ndarray]:
    """Each photo's focal scale ``g`` (B,) and ``dg/db`` (B,) of a camera whose lens breathes (module docstring)."""
    name, c = problem.cameras[batch.camera], batch.camera
    args = (problem.focus.focal_mm[name], state.breathing[c], problem.focus.reference_mm[name])
    return focal_scale(batch.focus_mm, *args), focal_scale_per_breathing(batch.focus_mm, *args)


def _in_photos(problem: Problem, state: State, batch: CameraBatch, uv: np.ndarray) -> np.ndarray:
    """``uv`` (B, N, 2), pixels of camera ``batch.camera`` at its reference focus and unshifted, as its photos see
    them: scaled about the principal point by each photo's focal scale where the lens breathes, moved by each
    photo's shift where it has one (module docstring)."""
    c = batch.camera
    if problem.breathes(c):
        centre = state.intrinsics[c, 3:5]
        uv = centre + _focal_scales(problem, state, batch)[0][:, None, None] * (uv - centre)
    if problem.shifts(c):
        uv = uv + state.ois_px[batch.views, c][:, None, :]
    return uv


def _predicted(problem: Problem, state: State, batch: CameraBatch, Xc: np.ndarray) -> np.ndarray:
    """(B, N, 2) the pixels of the camera-frame points ``Xc`` (B, N, 3) in each photo of ``batch``."""
    with np.errstate(divide="ignore", invalid="ignore"):      # unmeasured corners may sit anywhere
        uv = project_points(state.camera(problem, batch.camera), Xc.reshape(-1, 3)).reshape(Xc.shape[:2] + (2,))
    return _in_photos(problem, state, batch, uv)


def corners_behind(problem: Problem, state: State) -> int:
    """How many measured corners lie at ``Z <= 0``, behind their camera."""
    return sum(int(np.sum(_camera_points(problem, state, b)[1][b.observed][:, 2] <= 0)) for b in problem.batches)


def cost(problem: Problem, state: State, allowed_behind: int = 0) -> float:
    """``sum_b w_b |r_b|^2`` over the measured corners, residuals only; ``inf`` if more than ``allowed_behind``
    of them lie at ``Z <= 0`` (a projection from behind the camera is a mirror image, not a fit)."""
    total, behind = 0.0, 0
    for batch in problem.batches:
        Xc = _camera_points(problem, state, batch)[1]
        behind += int(np.sum(Xc[batch.observed][:, 2] <= 0))
        if behind > allowed_behind:
            return np.inf
        if problem.breathes(batch.camera) or problem.shifts(batch.camera):
            uv = _predicted(problem, state, batch, Xc)[batch.observed]
        else:                                     # the observed corners only
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = project_points(state.camera(problem, batch.camera), Xc[batch.observed])
        squares = np.sum((uv - batch.uv_px[batch.observed]) ** 2, axis=1)
        if batch.sqrt_weight is not None:
            squares = squares * np.broadcast_to(batch.sqrt_weight[:, None] ** 2, batch.observed.shape)[batch.observed]
        total += float(np.sum(squares))
    total += sum(float(np.sum(prior.residual(state) ** 2)) for prior in problem.priors)
    total += float(np.sum(ois_costs(problem, state)))
    return total if np.isfinite(total) else np.inf


def ois_costs(problem: Problem, state: State) -> np.ndarray:
    """(n_blocks,) each photo's shift's part of the cost, ``(scale / sigma)^2 |delta|^2`` (module docstring; 0 for a
    photo without a shift)."""
    out = np.zeros(len(problem.blocks))
    for batch in problem.batches:
        if problem.shifts(batch.camera):
            shift = state.ois_px[batch.views, batch.camera]
            out[batch.blocks] = problem.ois.information(problem.cameras[batch.camera]) * np.sum(shift ** 2, axis=1)
    return out


def residuals(problem: Problem, state: State) -> np.ndarray:
    """(n_blocks, N, 2) predicted - observed pixels, NaN where a corner was not measured."""
    out = np.full((len(problem.blocks), len(problem.X_board), 2), np.nan)
    for batch in problem.batches:
        uv = _predicted(problem, state, batch, _camera_points(problem, state, batch)[1])
        out[batch.blocks] = np.where(batch.observed[..., None], uv - batch.uv_px, np.nan)
    return out


def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``a x b`` along the last axis, written into ``out`` (numpy's ``cross`` moves axes and copies)."""
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _columns(problem: Problem, c: int) -> tuple[np.ndarray, np.ndarray]:
    """The global columns and the local slots that camera ``c``'s photos touch, in the order of
    :func:`_jacobian`."""
    lay = problem.layout
    glob = [lay.intrinsics[c]]
    loc = [lay.pose[problem.pose_slot(c)]]
    if problem.tied(c):
        glob += [lay.rig_rotation[c], lay.rig_translation[c] if problem.mode == "rigid" else lay.baseline[c]]
        if problem.mode == "paper":
            loc.append(lay.direction[c])
    glob.append(lay.board_shape)
    if c in lay.breathing:
        glob.append(lay.breathing[c])
    if c in lay.ois:
        loc.append(lay.ois[c])
    return np.concatenate(glob), np.concatenate(loc)


def _jacobian(problem: Problem, state: State, batch: CameraBatch, W, Xc, rel_t, J_X, J_K, n_global: int,
              d_breathing=None):
    """d residual / d unknowns of one camera's photos, (B, N, 2, k): the global columns of
    :func:`_columns` (the first ``n_global``), then its local slots; the rows of unmeasured corners zero.
    ``J_X``, ``J_K`` are those of the photos' pixels (each photo's focal scale in them), ``d_breathing`` (B, N, 2)
    d pixel / d b where the lens breathes."""
    lay, c = problem.layout, batch.camera
    J = np.empty(J_X.shape[:3] + (n_global + len(_columns(problem, c)[1]),))
    free = np.flatnonzero(lay.free_intrinsics[c])
    k = len(free)
    J[..., :k] = np.take(J_K, free, axis=-1)          # by indices: a boolean mask on the last axis is slower
    M = J_X                                                              # d res / d (R_v X + t_v)
    if problem.tied(c):
        M = J_X @ state.rig_R[c]
        _cross((Xc - rel_t[:, None, :])[:, :, None, :], J_X, J[..., k:k + 3])          # -J_X [p]x
        k += 3
        if problem.mode == "rigid":
            J[..., k:k + 3] = J_X
            k += 3
        else:
            u = state.direction[batch.views, c]
            J[..., k] = (J_X @ u[:, None, :, None])[..., 0]
            k += 1
    if problem.board_shape:       # d X_board / d w = basis e_z, seen through R_v: its third column
        normal = state.pose_R[batch.views, problem.pose_slot(c)][:, :, 2]                # (B, 3)
        along = (M @ normal[:, None, :, None])[..., 0]                                     # (B, N, 2)
        J[..., k:k + 3] = along[..., None] * problem.shape_basis[None, :, None, :]
        k += 3
    if d_breathing is not None:
        J[..., k] = d_breathing
        k += 1
    _cross(W[:, :, None, :], M, J[..., k:k + 3])                                          # -M [W]x
    J[..., k + 3:k + 6] = M
    k += 6
    if problem.mode == "paper" and problem.tied(c):
        u = state.direction[batch.views, c]
        free = lay.local_used[batch.views][:, lay.direction[c][0]]
        J[..., k:k + 2] = (state.baseline_mm[c] * free)[:, None, None, None] * (J_X @ tangent_basis(u)[:, None])
        k += 2
    if problem.shifts(c):                                   # d pixel / d shift: the identity
        J[..., k:k + 2] = np.eye(2)
    J[~batch.observed] = 0.0
    return J


def _linearised_batches(problem: Problem, state: State):
    """Per camera: ``(batch, r (B, 2N), J (B, 2N, k_g + k_l), global columns (k_g,), local slots (k_l,), raw (B,
    2N))``, the Jacobian's global columns first; the rows of unmeasured corners zero; each photo's rows of ``r`` and
    ``J`` scaled by the square root of its weight, ``raw`` its residuals unscaled."""
    for batch in problem.batches:
        W, Xc, rel_t = _camera_points(problem, state, batch)
        B, n = batch.observed.shape
        with np.errstate(divide="ignore", invalid="ignore"):      # unmeasured corners may sit anywhere
            uv, J_X, J_K = project_with_jacobians(state.camera(problem, batch.camera), Xc.reshape(-1, 3))
        uv, J_X, J_K = uv.reshape(B, n, 2), J_X.reshape(B, n, 2, 3), J_K.reshape(B, n, 2, -1)
        d_breathing = None
        if problem.breathes(batch.camera):        # c + g (uv - c): the lengths on the sensor scale, c does not
            g, dg = _focal_scales(problem, state, batch)
            from_centre = uv - state.intrinsics[batch.camera, 3:5]
            d_breathing = dg[:, None, None] * from_centre
            J_X = g[:, None, None, None] * J_X
            J_K = J_K.copy()
            J_K[..., :3] *= g[:, None, None, None]
            J_K[..., 5:] *= g[:, None, None, None]
        uv = _in_photos(problem, state, batch, uv)
        r = np.where(batch.observed[:, :, None], uv - batch.uv_px, 0.0).reshape(B, 2 * n)
        cols_g, slots_l = _columns(problem, batch.camera)
        J = _jacobian(problem, state, batch, W, Xc, rel_t, J_X, J_K, len(cols_g), d_breathing).reshape(B, 2 * n, -1)
        raw = r
        if batch.sqrt_weight is not None:
            r = r * batch.sqrt_weight[:, None]
            J *= batch.sqrt_weight[:, None, None]
        yield batch, r, J, cols_g, slots_l, raw


def linearise(problem: Problem, state: State) -> tuple[float, NormalEquations]:
    """``F`` (the weighted ``r^T r``) and the normal equations, assembled photo by photo from dense (2N, k)
    pieces."""
    lay = problem.layout
    ne = NormalEquations.zeros(lay.n_global, lay.local_used)
    total = 0.0
    for batch, r, J, cg, sl, raw in _linearised_batches(problem, state):
        squares = np.sum(r * r, axis=1)
        total += float(squares.sum())
        v = batch.views[:, None, None]              # one photo per instant in a camera: no index repeats
        kg = len(cg)
        JtJ = np.swapaxes(J, 1, 2) @ J
        gg, gl, ll = JtJ[:, :kg, :kg], JtJ[:, :kg, kg:], JtJ[:, kg:, kg:]
        grad = (r[:, None, :] @ J)[:, 0]
        g_g, g_l = grad[:, :kg], grad[:, kg:]
        ne.gg[v, cg[:, None], cg[None, :]] += gg
        ne.gl[v, cg[:, None], sl[None, :]] += gl
        ne.ll[v, sl[:, None], sl[None, :]] += ll
        ne.grad_g[batch.views[:, None], cg] += g_g
        ne.grad_l[batch.views[:, None], sl] += g_l
        ne.photos.append(PhotoNormals(batch.camera, batch.blocks, batch.views, cg, sl, gg, gl, ll, g_g, g_l, squares,
                                      batch.observed.sum(axis=1), raw))
        if problem.mode == "paper" and problem.tied(batch.camera):
            _add_sphere_curvature(problem, state, ne, batch, g_g[:, cg == lay.baseline[batch.camera][0]][:, 0],
                                  g_l[:, np.isin(sl, lay.direction[batch.camera])])
    for c, slots in lay.ois.items():                 # each shift's prior: its instant's own rows
        views = lay.local_used[:, slots[0]]
        information = problem.ois.information(problem.cameras[c])
        shift = state.ois_px[views, c]
        total += information * float(np.sum(shift ** 2))
        ne.ll[np.ix_(views, slots, slots)] += information * np.eye(2)
        ne.grad_l[np.ix_(views, slots)] += information * shift
    if problem.priors:
        ne.prior_gg, ne.prior_grad = np.zeros((lay.n_global, lay.n_global)), np.zeros(lay.n_global)
        roots = []
        for prior in problem.priors:
            r = prior.residual(state)
            total += float(r @ r)
            ne.prior_gg[np.ix_(prior.columns, prior.columns)] += prior.root.T @ prior.root
            ne.prior_grad[prior.columns] += prior.root.T @ r
            roots.append(np.zeros((lay.n_global, len(r))))
            roots[-1][prior.columns] = problem.prior_scale_px * prior.root.T
        ne.prior_meat_root = np.hstack(roots)
    return total, ne


def _add_sphere_curvature(problem: Problem, state: State, ne: NormalEquations, batch: CameraBatch,
                          g_D: np.ndarray, g_dir: np.ndarray) -> None:
    """Add the exact second-order terms ``sum r d2r`` that the paper's baseline ``D u_v`` brings in.

    The constraint ``|t_v| = D`` is curved: where an instant's baseline depth is poorly determined
    its direction moves far, and Gauss-Newton alone then converges only linearly. On the sphere
    ``u(delta) = u + B delta - |delta|^2 u / 2 + ...``, so ``d2 X_c / d delta^2 = -D u I`` and
    ``d2 X_c / dD d delta = B``; through the projection (whose own curvature Gauss-Newton neglects
    as usual) these give ``H_delta,delta = -D g_D I`` and ``H_D,delta = g_delta / D`` with the
    photo's gradients ``g_D = sum r^T J_X u`` and ``g_delta = D sum r^T J_X B``. ``g_D`` (B,) and
    ``g_dir`` (B, 2) are those gradients of each photo of ``batch``.
    """
    lay, c = problem.layout, batch.camera
    if ne.curvature_ll is None:
        ne.curvature_ll, ne.curvature_gl = np.zeros_like(ne.ll), np.zeros_like(ne.gl)
    D, dirs = state.baseline_mm[c], lay.direction[c]
    free = lay.local_used[batch.views, dirs[0]]
    ne.curvature_ll[batch.views[:, None], dirs, dirs] += (-D * g_D * free)[:, None]
    ne.curvature_gl[batch.views[:, None], lay.baseline[c][0], dirs] += g_dir * free[:, None] / D


@dataclass(frozen=True)
class PhotoRows:
    """The Jacobian rows of one photo's measured corners: ``J`` (m, k) over the flat parameter
    indices ``columns`` (k,), residuals ``r`` (m,) (predicted - observed, px; corner by corner, u
    then v), both scaled by the square root of the photo's weight; ``block`` is the photo's index in
    ``Problem.blocks``."""

    block: int
    columns: np.ndarray
    J: np.ndarray
    r: np.ndarray


def photo_rows(problem: Problem, state: State) -> list[PhotoRows]:
    """The Jacobian rows of every photo's measured corners, in the order of ``problem.blocks``."""
    lay = problem.layout
    out = []
    for batch, r, J, cg, sl, _ in _linearised_batches(problem, state):
        rows = np.repeat(batch.observed, 2, axis=1)
        for i, (b, v) in enumerate(zip(batch.blocks, batch.views)):
            used = np.concatenate([np.ones(len(cg), bool), lay.local_used[v, sl]])
            out.append(PhotoRows(int(b), np.concatenate([cg, lay.local_columns(v, sl[used[len(cg):]])]),
                                 J[i][rows[i]][:, used], r[i][rows[i]]))
    return sorted(out, key=lambda pr: pr.block)


def photo_jacobians(problem: Problem, state: State):
    """The photos' Jacobians as batches of dense arrays: per camera and set of local slots its photos use,
    ``(blocks (B,), columns (B, k), J (B, N, 2, k))``, each photo's rows of its corners (u then v; zero where a
    corner was not measured) over the flat parameter indices ``columns``, scaled by the square root of its weight:
    :func:`photo_rows`'s, without picking each photo's measured rows one by one."""
    lay = problem.layout
    for batch, _, J, cg, sl, _ in _linearised_batches(problem, state):
        patterns, which = np.unique(lay.local_used[batch.views][:, sl], axis=0, return_inverse=True)
        for i, pattern in enumerate(patterns):
            photos = np.flatnonzero(which.ravel() == i)
            keep = np.concatenate([np.ones(len(cg), bool), pattern])
            columns = np.hstack([np.broadcast_to(cg, (len(photos), len(cg))),
                                 lay.local_columns(batch.views[photos][:, None], sl[pattern][None, :])])
            J_photos = J if len(patterns) == 1 else J[photos]
            J_photos = J_photos if keep.all() else J_photos[:, :, keep]
            yield batch.blocks[photos], columns, J_photos.reshape(len(photos), -1, 2, int(keep.sum()))


@dataclass(frozen=True)
class InstantRows:
    """The Jacobian rows of one instant's measured corners: ``J`` (m, k) over the flat parameter
    indices ``columns`` (k,), residuals ``r`` (m,) (predicted - observed, px); ``row_cameras`` (m,) the
    camera index of each row."""

    view: str
    columns: np.ndarray
    J: np.ndarray
    r: np.ndarray
    row_cameras: np.ndarray | None = None


def instant_rows(problem: Problem, state: State) -> list[InstantRows]:
    """The Jacobian rows of every instant's measured corners, in the order of ``problem.views``
    (within an instant: camera by camera, corner by corner, u then v)."""
    parts = defaultdict(list)
    for pr in photo_rows(problem, state):
        parts[problem.view_index[problem.blocks[pr.block][1]]].append(pr)
    out = []
    for v, pieces in sorted(parts.items()):
        pieces.sort(key=lambda pr: problem.blocks[pr.block][0])
        columns = np.unique(np.concatenate([pr.columns for pr in pieces]))
        J = np.zeros((sum(len(pr.r) for pr in pieces), len(columns)))
        row = 0
        for pr in pieces:
            J[row:row + len(pr.r), np.searchsorted(columns, pr.columns)] = pr.J
            row += len(pr.r)
        out.append(InstantRows(problem.views[v], columns, J, np.concatenate([pr.r for pr in pieces]),
                               np.concatenate([np.full(len(pr.r), problem.blocks[pr.block][0]) for pr in pieces])))
    return out


# ----------------------------------------------------------------------------- the solution


@dataclass
class Solution:
    """Result of :func:`adjust`: the state, the fit and the factorized normal equations.

    ``residuals`` is (n_blocks, N, 2), pixels (unweighted), NaN where a corner was not measured;
    ``block_rms_px`` the RMS length of each photo's 2-D residuals over its measured corners. A solution does not
    change once :func:`adjust` returns it: ``derived`` holds what the stages above compute from it and ask for more
    than once (:func:`dualcal.estimation.photo_noise.rough_residuals`, :meth:`held_out_squares`), by key, as the
    cached properties below do.
    """

    problem: Problem
    state: State
    residuals: np.ndarray
    s0_px: float
    redundancy: int
    iterations: int
    converged: bool
    termination: str
    factorization: Factorization
    block_rms_px: list[float] = field(default_factory=list)
    derived: dict = field(default_factory=dict, repr=False, compare=False)

    def covariance(self, columns, kind: str = "formal") -> np.ndarray:
        """The covariance of the flat parameters ``columns`` (mm, rad, px...): ``formal``
        ``s0^2 N^-1``, or ``clustered`` by instant (module docstring)."""
        if kind == "formal":
            return self.s0_px ** 2 * self.factorization.inverse_block(columns)
        if kind != "clustered":
            raise ValueError(f"covariance kind {kind!r} is not one of {COVARIANCE_KINDS}")
        shifts = np.hstack([self._shifts(columns),
                            self.factorization.global_combination(columns) @ self._leverage.prior])
        return shifts @ shifts.T

    def instant_shifts(self, columns) -> dict[str, np.ndarray]:
        """``{view: (k,)}``: each instant's shift of the flat parameters ``columns`` (its adjusted score
        through ``N^-1``), whose outer products sum to the ``clustered`` covariance."""
        return dict(zip(self.problem.views, self._shifts(columns).T))

    def _shifts(self, columns) -> np.ndarray:
        """(k, V): every instant's shift of the flat parameters ``columns``
        (:func:`dualcal.estimation.uncertainty.instant_leverage`)."""
        return self.factorization.global_combination(columns) @ self._leverage.shifts

    @cached_property
    def _at_minimum(self) -> NormalEquations:
        """The normal equations with the gradients of the linearised minimum: the residuals plus the Jacobian
        times the remaining Gauss-Newton step, so that where within its tolerance the solver stopped does not
        move the sigmas and the held-out errors to first order."""
        return self.factorization.ne.moved(self.factorization.step())

    @cached_property
    def _leverage(self) -> InstantLeverage:
        return instant_leverage(self.factorization, self._at_minimum)

    def intrinsic_sigma(self, c: int, kind: str = "formal") -> dict[str, float]:
        """1-sigma of every intrinsic of camera ``c`` (0 for a fixed one), of covariance ``kind``."""
        lay = self.problem.layout
        sig = dict.fromkeys(INTRINSIC_NAMES, 0.0)
        cols = lay.intrinsics[c]
        values = np.sqrt(np.maximum(np.diag(self.covariance(cols, kind)), 0.0))
        for name, s in zip(np.array(INTRINSIC_NAMES)[lay.free_intrinsics[c]], values):
            sig[str(name)] = float(s)
        return sig

    def block_costs(self) -> np.ndarray:
        """(n_blocks,) each photo's part of the cost: ``w_b |r_b|^2`` (px^2 of a photo of weight 1), and its shift's
        prior where it has one (:func:`ois_costs`)."""
        return (self.problem.block_weights * np.nansum(self.residuals ** 2, axis=(1, 2))
                + ois_costs(self.problem, self.state))

    def ois_costs_px2(self) -> np.ndarray:
        """(n_blocks,) each photo's shift's prior in the photo's own pixels (its part of the cost over its
        weight): what the stabiliser's shift adds to ``|r_b|^2`` (0 for a photo without a shift)."""
        return ois_costs(self.problem, self.state) / self.problem.block_weights

    @cached_property
    def photo_poses(self) -> dict[tuple[int, str], Pose]:
        """The board-to-camera pose of every photo, ``{(camera, view): Pose}``."""
        p, out = self.problem, {}
        for batch in p.batches:
            for b, R, t in zip(batch.blocks, *self.state.photo_poses(p, batch.camera, batch.views)):
                out[p.blocks[b][0], p.blocks[b][1]] = Pose(R, t)
        return out

    def held_out_squares(self) -> dict[str, dict[int, tuple[float, int]] | None]:
        """``{view: {camera: (px^2, corners)}}``: the sum of squares of each photo's residuals as the
        adjustment without its instant predicts them, the instant's own poses fitted to it again, and how
        many corners it has (a linearised leave-one-instant-out, :mod:`dualcal.estimation.uncertainty`);
        None for an instant the others cannot do without (the only one to show some parameter). Computed once
        (:attr:`derived`); the same dict each time, not to be changed."""
        if "held_out_squares" not in self.derived:
            self.derived["held_out_squares"] = self._held_out_squares()
        return self.derived["held_out_squares"]

    def _held_out_squares(self) -> dict[str, dict[int, tuple[float, int]] | None]:
        p = self.problem
        out: dict[str, dict[int, tuple[float, int]] | None] = {v: {} for v in p.views}
        counts = {b: int(n) for ph in self.factorization.ne.photos for b, n in zip(ph.blocks, ph.corners)}
        for c, blocks, squares in held_out_squares(self.factorization, self._leverage.held_out, self._at_minimum):
            for b, sq in zip(blocks, squares / p.block_weights[blocks]):           # weighted squares: px^2
                view = p.blocks[b][1]
                if out[view] is not None:
                    out[view] = None if np.isnan(sq) else {**out[view], c: (float(sq), counts[b])}
        return out


def linearised_at(problem: Problem, state: State) -> Solution:
    """The adjustment linearised at ``state`` and not iterated (``iterations`` 0): its residuals and the
    factorization of its normal equations there, whose Gauss-Newton step ``factorization.step()`` gives the
    one-step estimate and whose covariances are those of that estimate (the linearised minimum).

    Raises
    ------
    EstimationError
        Fewer observations than unknowns, or a singular normal matrix.
    """
    redundancy = _redundancy(problem)
    F, ne = linearise(problem, state)
    with _determined():
        factorization = ne.factor(0.0)
    return _solution(problem, state, F, redundancy, 0, False, "linearised, not adjusted", factorization)


def adjust(problem: Problem, state: State, options: LMOptions = LMOptions()) -> Solution:
    """Levenberg-Marquardt from ``state`` (:func:`dualcal.estimation.lm.levenberg_marquardt`).

    Raises
    ------
    EstimationError
        Fewer observations than unknowns, or a singular normal matrix (the data do not determine
        the parameters).
    """
    redundancy = _redundancy(problem)
    with _determined():
        behind = corners_behind(problem, state)       # a poor start may have some: none may be added
        res = levenberg_marquardt(state, lambda s: linearise(problem, s), lambda s: cost(problem, s, behind),
                                  lambda s, h: s.updated(problem.layout, h), redundancy, options)
    return _solution(problem, res.x, res.cost, redundancy, res.iterations, res.converged, res.termination,
                     res.factorization)


def _redundancy(problem: Problem) -> int:
    shift_rows = sum(int(problem.layout.local_used[:, slots].sum()) for slots in problem.layout.ois.values())
    redundancy = (problem.n_observations + sum(len(prior.names) for prior in problem.priors) + shift_rows
                  - problem.n_parameters)
    if redundancy <= 0:
        raise EstimationError(f"not enough observations: redundancy {redundancy} (more views needed)")
    return redundancy


@contextmanager
def _determined():
    """A singular normal matrix as the :class:`EstimationError` a user can act on."""
    try:
        yield
    except np.linalg.LinAlgError:
        raise EstimationError("the normal equations are singular: the photos do not determine every "
                              "parameter (too few views, or views all alike)") from None


def _solution(problem: Problem, state: State, F: float, redundancy: int, iterations: int, converged: bool,
              termination: str, factorization: Factorization) -> Solution:
    """The :class:`Solution` at ``state``, whose residuals are those the normal equations of ``factorization``
    (linearised at ``state``) were built from."""
    r = np.full((len(problem.blocks), len(problem.X_board), 2), np.nan)
    for batch, ph in zip(problem.batches, factorization.ne.photos):
        r[batch.blocks] = np.where(batch.observed[..., None], ph.residuals.reshape(len(batch.blocks), -1, 2), np.nan)
    return Solution(problem, state, r, float(np.sqrt(F / redundancy)), redundancy, iterations, converged,
                    termination, factorization, np.sqrt(np.nanmean(np.sum(r ** 2, axis=2), axis=1)).tolist())
