"""One rig fitted to its corners: the solving core under every stage of a calibration, comparison and check.

What the stages of a calibration (:mod:`dualcal.estimation.calibrate`), the comparison of lens models
(:mod:`dualcal.estimation.model_selection`) and the checks share: which photos can be used
(:func:`usable_photos`), the one adjustment of a rig from Zhang's closed form or from an earlier solution
(:class:`Setup`, its switches: the rig mode, the lens models, the board's shape; :func:`solve`), a
calibration's or a solution's corners adjusted again with another lens, skew or rig model, or some of its
cameras alone (:func:`refit`, the one entry point of the comparison of lens models), two cameras of a rig as a
rig of their own (:func:`pair_solutions`), and a solution packaged with its covariance as the
:class:`~dualcal.geometry.model.RigModel` that calib.json holds (:func:`rig_model_from_solution`).
No outliers are looked for here and nothing is decided: those are the calibration's stages.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from .adjust import COVARIANCE_KINDS, OisPrior, Problem, Solution, adjust, cost, initial_state, linearised_at
from ..geometry.board import SHAPE_TERMS
from ..geometry.camera import (DEFAULT_LENS_MODEL, DISTORTION_NAMES, FISHEYE_MODELS, INTRINSIC_NAMES, LENS_MODELS,
                               CameraModel)
from .covariance import JointCovariance, breathing_name, intrinsic_name
from ..errors import EstimationError, InputError
from .held_out import fit_summary
from .photo_noise import photo_weights
from .lm import COMPARISON_LM, NEAR_START, LMOptions
from ..geometry.focus import PhotoFocus
from ..geometry.model import CornerSet, KnownIntrinsics, Pose, RigModel, RigRelation, observed_mask
from ..progress import warn
from .rig_relations import parameter_covariance, rig_relation, shared_views
from ..geometry.scale import relative_sigma, with_scale
from ..geometry.resection import planar_pose
from ..geometry.homography import MIN_HOMOGRAPHY_CORNERS, spans_a_plane
from ..geometry.zhang import initial_camera

MIN_VIEWS = 3


def unusable_reason(uv: np.ndarray, xy_board: np.ndarray) -> str | None:
    """Why a photo's measured corners cannot determine a homography (None if they can): fewer than
    :data:`dualcal.geometry.homography.MIN_HOMOGRAPHY_CORNERS`, or all on one line."""
    seen = observed_mask(uv)
    if seen.sum() >= MIN_HOMOGRAPHY_CORNERS and spans_a_plane(xy_board[seen]):
        return None
    return (f"its {int(seen.sum())} measured corner(s) "
            f"{'lie on one line' if seen.sum() >= MIN_HOMOGRAPHY_CORNERS else 'are too few'}; "
            f"a photo needs at least {MIN_HOMOGRAPHY_CORNERS} corners, not all on one line")


def usable_photos(corners: CornerSet, names: list[str], xy_board: np.ndarray,
                  quiet: bool = False) -> list[tuple[int, str, np.ndarray]]:
    """``(camera index, view, (N, 2) corners)`` of every photo whose measured corners determine a
    homography (:func:`unusable_reason`). Every other photo where the board was found is skipped
    with a warning naming it (unless ``quiet``: a calibration already said so). Photos that measured the same
    corners share the verdict."""
    blocks, verdicts = [], {}
    for c, name in enumerate(names):
        for v, uv in sorted(corners.cameras[name].found().items()):
            seen = observed_mask(uv).tobytes()
            if seen not in verdicts:
                verdicts[seen] = unusable_reason(uv, xy_board)
            reason = verdicts[seen]
            if reason:
                if not quiet:
                    warn(f"{name}/{v} skipped: {reason}")
                continue
            blocks.append((c, v, uv))
    return blocks


def _check_enough_views(blocks, names, known=None) -> None:
    for c, name in enumerate(names):
        n = sum(1 for cam, _, _ in blocks if cam == c)
        if n < (1 if name in (known or {}) else MIN_VIEWS):
            raise EstimationError(f"camera {name!r} has {n} usable view(s); at least {MIN_VIEWS} are needed "
                                  "(take more photos, or check that the board is found in them)")


def _starting_values(sol: Solution, names=None):
    """Per-camera intrinsics and board-to-camera poses of a solution, to start another adjustment: of every
    camera, or of the cameras ``names`` (some of the solution's), in that order."""
    bp = sol.photo_poses
    cameras = range(len(sol.problem.cameras)) if names is None else [sol.problem.cameras.index(n) for n in names]
    cams = [sol.state.camera(sol.problem, c) for c in cameras]
    poses = [{v: bp[(c, v)] for cc, v, _ in sol.problem.blocks if cc == c and (c, v) in bp} for c in cameras]
    return cams, poses


def _lens_motion_start(sol: Solution) -> dict:
    """A solution's breathing coefficients ``{camera: b}`` and photos' shifts ``{(camera, view): (2,)}``, as
    :func:`dualcal.estimation.adjust.initial_state`'s keywords: the start of another adjustment."""
    p, lay = sol.problem, sol.problem.layout
    shifts = {(p.cameras[c], v): sol.state.ois_px[p.view_index[v], c] for c, v, _ in p.blocks if c in lay.ois}
    return {"breathing": {p.cameras[c]: float(sol.state.breathing[c]) for c in lay.breathing}, "ois_px": shifts}


@dataclass(frozen=True)
class Setup:
    """What every adjustment of one calibration shares, the switches of its one solver: the board's corners
    ``X_board`` (N, 3), the camera names and image sizes, the reference's index, the skew model, the rig mode,
    the lens model of every camera (one name, or one per camera), each photo's weight ``weights``
    ``{(camera, view): w}`` (:mod:`dualcal.estimation.photo_noise`; None: all 1), and the cameras whose
    intrinsics are ``known`` ``{camera: KnownIntrinsics}``, as a prior of scale ``prior_scale_px`` (the noise of
    a photo of weight 1; None: held until it is known) or fixed; the lens's motion: each photo's ``focus``
    (:class:`dualcal.geometry.focus.PhotoFocus`) and the cameras whose lens ``breathing`` with it is estimated
    (:mod:`dualcal.estimation.focus_model`), the stabiliser's shift of each photo, ``ois``
    (:class:`dualcal.estimation.adjust.OisPrior`, :mod:`dualcal.estimation.ois`). :meth:`problem` makes the
    :class:`dualcal.estimation.adjust.Problem` of every adjustment from them."""

    X_board: np.ndarray
    names: list[str]
    sizes: list[tuple[int, int]]
    reference: int
    skew: bool
    mode: str
    model: str | tuple[str, ...] = DEFAULT_LENS_MODEL
    weights: Mapping[tuple[str, str], float] | None = None
    known: Mapping[str, KnownIntrinsics] | None = None
    prior_scale_px: float | None = None
    focus: PhotoFocus | None = None
    breathing: tuple[str, ...] = ()
    ois: OisPrior | None = None

    @property
    def models(self) -> tuple[str, ...]:
        """One lens model per camera."""
        return (self.model,) * len(self.names) if isinstance(self.model, str) else tuple(self.model)

    def problem(self, blocks, mode: str | None = None, board_shape: bool = False) -> Problem:
        """The adjustment's problem of ``blocks`` with these switches (``mode`` overrides the rig mode)."""
        return Problem(self.X_board, list(self.names), list(self.sizes), blocks, mode or self.mode, self.skew,
                       self.reference, board_shape, self.models, self.weights, self.known, self.prior_scale_px,
                       self.focus, tuple(n for n in self.breathing if n in self.names), self.ois)

    def closed_form(self, c: int, views: dict):
        """Camera ``c``'s start from the photos ``views`` ``{view: uv}``: Zhang's closed form
        (:func:`dualcal.geometry.zhang.initial_camera`), or, for a camera whose intrinsics are known, those and
        each photo's pose by space resection (:func:`dualcal.geometry.resection.planar_pose`): ``(camera,
        {view: Pose})``."""
        known = (self.known or {}).get(self.names[c])
        if known is None:
            return initial_camera(self.X_board[:, :2], views, self.sizes[c], self.skew, self.models[c])
        return known.camera, {v: planar_pose(self.X_board, known.camera, uv) for v, uv in views.items()}

    def solve(self, blocks, start: "Solution | None" = None, mode: str | None = None,
              board_shape: bool = False) -> "Solution":
        """Initialise and adjust one rig (no outlier handling). ``blocks``: (camera, view, uv) triples; ``mode``
        overrides the rig mode.

        Starting values come from Zhang's closed form per camera, or from ``start``, an earlier
        solution over the same photos (or a superset of them: photos it did not see start from
        Zhang's; of these cameras or more), whose board shape is kept as the start too; a camera of
        another lens model there starts from its values as :func:`refit` converts them. The paper's model
        starts from the better (lower cost) of the rigid solution (every instant's baseline direction the same) and
        the cameras-alone solution (each instant's own relative pose): the first is the nearer when
        the rig is rigid, the second when the direction moves between instants. With
        ``board_shape`` the board's out-of-plane shape is estimated too.
        """
        mode = mode or self.mode
        X_board, skew, models = self.X_board, self.skew, self.models
        _check_enough_views(blocks, self.names, self.known)
        if mode == "paper" and start is None:
            start = self.solve(blocks, mode="none", board_shape=board_shape)
        shape = start.state.board_shape_mm if start is not None else None
        if start is not None:
            cams, poses = _starting_values(start, self.names)
            cams = [cam if cam.model == models[c] else
                    _start_camera(cam, models[c], skew, X_board, {v: uv for cc, v, uv in blocks if cc == c})
                    for c, cam in enumerate(cams)]
            views = {v for _, v, _ in blocks}
            poses = [{v: pose for v, pose in per.items() if v in views} for per in poses]
            missing = [(c, v) for c, v, _ in blocks if v not in poses[c]]
            if missing:
                zhang = {c: self.closed_form(c, {v: uv for cc, v, uv in blocks if cc == c})[1]
                         for c in {c for c, _ in missing}}
                for c, v in missing:
                    poses[c][v] = zhang[c][v]
        else:
            cams, poses = map(list, zip(*(self.closed_form(c, {v: uv for cc, v, uv in blocks if cc == c})
                                          for c in range(len(self.names)))))
        problem = self.problem(blocks, "rigid" if mode == "paper" else mode, board_shape)
        motion = _lens_motion_start(start) if start is not None else {}
        sol = adjust(problem, initial_state(problem, cams, poses, shape, **motion),
                     LMOptions() if start is None else NEAR_START)
        if mode != "paper":
            return sol
        problem = self.problem(blocks, "paper", board_shape)
        starts = [initial_state(problem, *_starting_values(s, self.names), s.state.board_shape_mm,
                                **_lens_motion_start(s)) for s in (sol, start)]
        return adjust(problem, min(starts, key=lambda state: cost(problem, state)), NEAR_START)

    def linearised(self, sol: "Solution", board_shape: bool) -> "Solution":
        """``sol``'s photos and state linearised (:func:`dualcal.estimation.adjust.linearised_at`), the board's
        shape free or not."""
        return linearised_at(self.problem(sol.problem.blocks, sol.problem.mode, board_shape), sol.state)


def solve(X_board, names, sizes, blocks, reference: int, skew: bool, mode: str,
          start: Solution | None = None, board_shape: bool = False,
          model: str | tuple[str, ...] = DEFAULT_LENS_MODEL) -> Solution:
    """:meth:`Setup.solve` of a setup of these arguments (every photo of weight 1)."""
    return Setup(X_board, names, sizes, reference, skew, mode, model).solve(blocks, start, board_shape=board_shape)


def pair_solutions(setup: Setup, sol: Solution, alone: Solution, x: int, y: int) -> tuple[Solution, Solution, int]:
    """Cameras ``x`` and ``y`` of ``sol`` as a rigid two-camera rig (``x`` its reference) and alone, from
    the instants both saw there, started from ``sol``'s values (the tied pair) and ``alone``'s (the
    cameras alone: where the pair's photos are all those ``alone`` had, it is already their solution),
    each adjusted to a comparison's tolerance (:data:`dualcal.estimation.lm.COMPARISON_LM`)."""
    cams, poses = _starting_values(sol)
    views = set(poses[x]) & set(poses[y])
    blocks = [(int(c == y), v, uv) for c, v, uv in sol.problem.blocks if c in (x, y) and v in views]
    pair = replace(setup, names=[setup.names[x], setup.names[y]], sizes=[setup.sizes[x], setup.sizes[y]],
                   reference=0, mode="rigid", model=(setup.models[x], setup.models[y]))
    _check_enough_views(blocks, pair.names, pair.known)

    def adjusted(mode: str, start: Solution) -> Solution:
        problem = pair.problem(blocks, mode)
        start_cams, start_poses = _starting_values(start, pair.names)
        return adjust(problem, initial_state(problem, start_cams, [{v: p for v, p in per.items() if v in views}
                                                                   for per in start_poses],
                                             **_lens_motion_start(start)), COMPARISON_LM)

    return adjusted("rigid", sol), adjusted("none", alone), len(views)


#: ``model="auto"``: every camera's lens model chosen by its held-out instants
#: (:mod:`dualcal.estimation.model_selection`).
AUTO_MODEL = "auto"


def lens_models_for(model: str | Mapping[str, str], names: list[str]) -> tuple[str, ...]:
    """One lens model per camera of ``names`` from a model name (every camera) or a mapping
    ``{camera: model}`` (cameras not named get the mapping's ``"*"``, else
    :data:`dualcal.geometry.camera.DEFAULT_LENS_MODEL`).

    Raises
    ------
    InputError
        An unknown model name, or a mapping naming a camera that is not there.
    """
    if isinstance(model, str):
        model = dict.fromkeys(names, model)
    model = dict(model)
    default = model.pop("*", DEFAULT_LENS_MODEL)
    unknown_cameras = sorted(set(model) - set(names))
    if unknown_cameras:
        raise InputError(f"lens model given for camera {unknown_cameras[0]!r}, which is not one of the rig's "
                         f"({', '.join(names)})")
    for m in [default, *model.values()]:
        if m not in LENS_MODELS:
            raise InputError(f"lens model {m!r} is unknown (choose from {', '.join(LENS_MODELS)}, or {AUTO_MODEL})")
    return tuple(model.get(n, default) for n in names)


def refit(source: RigModel | Solution, model: str | Mapping[str, str] | None = None, skew: bool | None = None,
          rig_mode: str | None = None, options: LMOptions = NEAR_START, cameras=None) -> Solution:
    """The corners ``source`` used, adjusted again with another lens model, skew model or rig mode (None:
    ``source``'s), started from ``source``'s values; those of the ``cameras`` named alone, where given (then
    the first named is the reference, unless ``source``'s is among them).

    ``source`` is a calibration (its corners without those it left out, :meth:`RigModel.used_corners`) or a
    solution (its photos). No outliers are looked for and the board keeps ``source``'s treatment (its shape
    estimated again where ``source`` estimated one): the same corners, so that the solutions compare. A lens
    model of ``source``'s family starts from its coefficients (a new coefficient at 0, a dropped one let go);
    one of another family (a fisheye for a radial lens, or back) from Zhang's closed form with ``source``'s
    poses. This is what comparing lens or skew models costs: one adjustment from a near start, where a full
    calibration (closed form, outliers alone and tied, the board-shape test) takes several. ``options``: the
    adjustment's tolerances (a comparison needs fewer digits than a result).
    """
    start = _Values.of(source)
    names = sorted(start.names if cameras is None else cameras)
    requested = start.models if model is None else dict.fromkeys(names, model) if isinstance(model, str) else model
    model = {**requested, **{n: start.models[n] for n in start.known or ()}}      # a known camera keeps its lens
    models = lens_models_for({k: m for k, m in model.items() if k in names or k == "*"}, names)
    skew = start.skew if skew is None else skew
    setup = Setup(start.X_board, names, [start.sizes[n] for n in names],
                  names.index(start.reference) if start.reference in names else 0, skew, rig_mode or start.mode,
                  models, start.weights, start.known, start.prior_scale_px, start.focus, start.breathing, start.ois)
    blocks = [(names.index(n), v, uv) for n, v, uv in start.photos if n in names]
    _check_enough_views(blocks, names, start.known)
    cams = [_start_camera(start.cameras[n], models[c], skew, setup.X_board,
                          {v: uv for cc, v, uv in blocks if cc == c}) for c, n in enumerate(names)]
    problem = setup.problem(blocks, board_shape=start.board_shape_mm is not None)
    return adjust(problem, initial_state(problem, cams, [dict(start.poses[n]) for n in names], start.board_shape_mm,
                                         start.breathing_values, start.ois_px), options)


@dataclass(frozen=True)
class _Values:
    """What :func:`refit` starts from, by camera name: a calibration's or a solution's photos ``(camera, view,
    uv)``, cameras, board-to-camera poses, image sizes and lens models, its board's shape (None: flat), its
    reference, skew model, rig mode, photos' weights, the cameras whose intrinsics were known (with the
    prior's scale), and the lens's motion: each photo's focus, the cameras whose lens breathes and their
    coefficients, the stabiliser's prior and each photo's shift."""

    X_board: np.ndarray
    names: list[str]
    photos: list[tuple[str, str, np.ndarray]]
    cameras: dict[str, CameraModel]
    poses: dict[str, dict[str, Pose]]
    sizes: dict[str, tuple[int, int]]
    models: dict[str, str]
    board_shape_mm: np.ndarray | None
    reference: str
    skew: bool
    mode: str
    weights: Mapping[tuple[str, str], float] | None
    known: Mapping[str, KnownIntrinsics] | None
    prior_scale_px: float | None
    focus: PhotoFocus | None = None
    breathing: tuple[str, ...] = ()
    ois: OisPrior | None = None
    breathing_values: dict | None = None
    ois_px: dict | None = None

    @classmethod
    def of(cls, source: RigModel | Solution) -> "_Values":
        if isinstance(source, Solution):
            p = source.problem
            poses = {n: {} for n in p.cameras}
            for (c, v), pose in source.photo_poses.items():
                poses[p.cameras[c]][v] = pose
            motion = _lens_motion_start(source)
            return cls(p.X_board, list(p.cameras), [(p.cameras[c], v, uv) for c, v, uv in p.blocks],
                       {n: source.state.camera(p, c) for c, n in enumerate(p.cameras)}, poses,
                       dict(zip(p.cameras, p.image_sizes)), dict(zip(p.cameras, p.models)),
                       source.state.board_shape_mm if p.board_shape else None, p.cameras[p.reference], p.skew, p.mode,
                       p.weights, p.known, p.prior_scale_px, p.focus, p.breathing, p.ois, motion["breathing"],
                       motion["ois_px"])
        corners = source.used_corners()
        X = corners.board.object_points_mm()
        names = sorted(corners.cameras)
        photos = [(names[c], v, uv) for c, v, uv in usable_photos(corners, names, X[:, :2], quiet=True)]
        return cls(X, names, photos, source.cameras, source.camera_poses,
                   {n: corners.cameras[n].image_size for n in names}, source.models, source.board_shape_mm,
                   source.reference, source.skew, source.rig_mode, photo_weights(source.adjustment),
                   *known_intrinsics_of(source.adjustment), *lens_motion_of(source))


def _start_camera(cam: CameraModel, model: str, skew: bool, X_board: np.ndarray, views: dict) -> CameraModel:
    """``cam`` as the start of an adjustment with lens ``model``: ``cam``'s coefficients where ``model`` is
    of its family (a new coefficient at 0, a dropped one let go), else Zhang's closed form of ``views``."""
    if (model in FISHEYE_MODELS) == cam.fisheye:
        return replace(cam, model=model, skew=cam.skew if skew else 0.0,
                       **{k: 0.0 for k in DISTORTION_NAMES if k not in LENS_MODELS[model]})
    return initial_camera(X_board[:, :2], views, cam.image_size, skew, model)[0]


def rig_model_from_solution(sol: Solution, corners: CornerSet, dropped: list[dict],
                            dropped_corners: list[dict] = ()) -> RigModel:
    """Package an adjustment result as the :class:`RigModel` written to calib.json (no checks)."""
    p, st = sol.problem, sol.state
    names = p.cameras
    cams = {name: st.camera(p, c) for c, name in enumerate(names)}
    fit = fit_summary(sol)
    names_cov, covs = parameter_covariance(sol, COVARIANCE_KINDS)
    sd = {kind: dict(zip(names_cov, np.sqrt(np.maximum(np.diag(cov), 0.0)))) for kind, cov in covs.items()}
    sigma_formal = {name: {n: sd["formal"].get(intrinsic_name(name, n), 0.0) for n in INTRINSIC_NAMES}
                    for name in names}
    sigma = {name: {n: max(sd["clustered"].get(intrinsic_name(name, n), 0.0), s)
                    for n, s in sigma_formal[name].items()} for name in names}
    view_rms: dict[str, dict[str, float]] = {}
    for b, (c, v, _) in enumerate(p.blocks):
        view_rms.setdefault(v, {})[names[c]] = sol.block_rms_px[b]
    poses: dict[str, dict[str, Pose]] = {name: {} for name in names}
    for (c, v), pose in sorted(sol.photo_poses.items(), key=lambda kv: kv[0][1]):
        poses[names[c]][v] = pose
    rig = {}
    for c, name in enumerate(names):
        if c == p.reference:
            continue
        if p.mode == "none" and not shared_views(p, c):
            warn(f"camera {name!r} shares no view with {names[p.reference]!r}: no rig relation for it")
            continue
        pose, *clustered = rig_relation(sol, c, "clustered")
        _, *formal = rig_relation(sol, c, "formal", warn_gimbal=False)
        sigma_t, sigma_d, sigma_opk = (np.maximum(a, b) for a, b in zip(clustered, formal))
        rel = relative_sigma(corners.board)          # the printed squares' tolerance: every length scales
        rig[name] = RigRelation(pose, with_scale(sigma_t, pose.t_mm, rel),
                                float(with_scale(sigma_d, np.linalg.norm(pose.t_mm), rel)), sigma_opk,
                                dict(zip(("t_mm", "baseline_mm", "opk_arcmin"), formal)))
    adjustment = {"s0_px": sol.s0_px, "redundancy": sol.redundancy, "iterations": sol.iterations,
                  "converged": sol.converged, "termination": sol.termination,
                  "n_observations": p.n_observations, "n_parameters": p.n_parameters,
                  **{k: fit[k] for k in ("held_out_rms_px", "held_out_per_instant", "held_out_per_camera")}}
    shape = shape_sigma = None
    if p.board_shape:
        shape = st.board_shape_mm.copy()
        shape_sigma = np.array([max(sd[kind][f"board.shape_mm.{t}"] for kind in COVARIANCE_KINDS) for t in SHAPE_TERMS])
    covariance = JointCovariance(tuple(names_cov), covs).to_dict()
    rig_model = RigModel(corners.board, names[p.reference], p.skew, p.mode, cams, sigma, fit["camera_rms_px"], rig,
                         poses, dict(sorted(view_rms.items())), fit["rms_px"], corners, adjustment, dropped,
                         sigma_formal, shape, shape_sigma, list(dropped_corners), {}, covariance)
    return _with_lens_motion(rig_model, sol, sd)


def _with_lens_motion(rig: RigModel, sol: Solution, sd: dict[str, dict[str, float]]) -> RigModel:
    """``rig`` with the lens's motion ``sol`` estimated (:class:`RigModel`'s ``focus_models``, ``photo_focus_m``,
    ``ois_sigma_px``, ``ois_shift_px``); ``sd`` the reported parameters' sigmas by covariance kind."""
    p, st, lay = sol.problem, sol.state, sol.problem.layout
    for c in lay.breathing:
        name = p.cameras[c]
        views = [v for cc, v, _ in p.blocks if cc == c]
        formal = sd["formal"][breathing_name(name)]
        rig.focus_models[name] = p.focus.model(name, st.breathing[c], views,
                                               max(sd["clustered"][breathing_name(name)], formal), formal)
        rig.photo_focus_m[name] = {v: p.focus.focus_mm[name, v] / 1000.0 for v in views}
    if p.ois is not None:
        rig.ois_sigma_px = {name: float(s) for name, s in p.ois.sigma_px.items() if name in p.cameras}
        for c in lay.ois:
            rig.ois_shift_px[p.cameras[c]] = {v: st.ois_px[p.view_index[v], c].copy() for cc, v, _ in p.blocks
                                             if cc == c}
    return rig


def known_intrinsics_record(setup: Setup) -> dict | None:
    """calib.json's ``adjustment.known_intrinsics`` of a calibration whose ``setup`` had cameras of known
    intrinsics: ``{"prior_scale_px", "cameras": {camera: KnownIntrinsics.to_dict()}}``; None for none."""
    if not setup.known:
        return None
    return {"prior_scale_px": setup.prior_scale_px,
            "cameras": {name: known.to_dict() for name, known in sorted(setup.known.items())}}


def lens_motion_of(rig: RigModel) -> tuple:
    """What a calibration's lens motion was (:func:`_with_lens_motion`), as :class:`Setup`'s switches and a start:
    ``(focus, breathing, ois, {camera: b}, {(camera, view): shift})`` (None and empty where it has none)."""
    focus = None
    if rig.focus_models:
        focus = PhotoFocus({n: m.focal_length_mm for n, m in rig.focus_models.items()},
                           {n: m.focus_m * 1000.0 for n, m in rig.focus_models.items()},
                           {(n, v): d * 1000.0 for n in rig.focus_models for v, d in rig.photo_focus_m[n].items()}, {})
    spread = {n: s for n, s in rig.ois_sigma_px.items() if s > 0}
    scale = ((rig.adjustment.get("lens_motion") or {}).get("ois") or {}).get("scale_px")
    ois = OisPrior(spread, scale) if spread and scale else None
    shifts = {(n, v): np.asarray(d, float) for n, per in rig.ois_shift_px.items() for v, d in per.items()}
    return focus, tuple(rig.focus_models), ois, {n: m.breathing for n, m in rig.focus_models.items()}, shifts


def known_intrinsics_of(adjustment: Mapping) -> tuple[dict[str, KnownIntrinsics] | None, float | None]:
    """The known intrinsics and the prior's scale a calibration recorded (:func:`known_intrinsics_record`)."""
    doc = adjustment.get("known_intrinsics")
    if not doc:
        return None, None
    return {name: KnownIntrinsics.from_dict(d) for name, d in doc["cameras"].items()}, doc["prior_scale_px"]
