"""From corners to a calibrated rig: the calibration as a pipeline of stages.

:func:`calibrate_rig` is the whole of the paper's sections 1.3 to 1.7 for any number of cameras, and reads as
the list of its stages. Each stage is a function of the previous one's result and calls nothing above it; every
adjustment in them is the one solver (:class:`dualcal.estimation.fitting.Setup`: ``solve`` from Zhang's closed
form or from an earlier solution), its stages as switches (the rig mode, the lens models, the board's shape, the
photos' weights, the cameras whose intrinsics are known):

1. :func:`photos_to_calibrate`: instants that repeat another's view merged (:mod:`dualcal.estimation.duplicates`),
   the photos whose corners can fix a homography (the others skipped with a warning naming them), the rig's
   cameras, its reference and those whose intrinsics are known (:class:`Photos`);
2. :func:`lens_models`: each camera's lens model, given, or (``model="auto"``) its candidates from Zhang's
   closed form and the one it starts with (:class:`LensModels`);
3. :func:`cameras_alone`: every camera from Zhang's closed form (:mod:`dualcal.geometry.zhang`; a known camera
   from its intrinsics), adjusted alone, each photo's noise estimated and the photos weighed by it
   (:mod:`dualcal.estimation.photo_noise`), its outliers left out (:mod:`dualcal.estimation.outliers`), so that a
   bad photo shows in its own camera's residuals (:class:`Fit`); :func:`circle_outlines`: a circle grid's centres
   as the centres of the circles' outlines' images, not the images of their centres (the perspective bias,
   :mod:`dualcal.estimation.circle_centres`);
4. :func:`rig_tied`: the rig from the cameras' relative poses, adjusted in its rig mode, its outliers left out
   (which also reveals a board moved, or a lens refocused, between the shots of one instant);
   :func:`lens_motion`: the lens's motion where the photos show it: each photo's principal point shifted by the
   stabiliser (:mod:`dualcal.estimation.ois`), its focal lengths with its focus
   (:mod:`dualcal.estimation.focus_model`); each chosen runs stages 3-4 again with it, from the cameras alone;
5. :func:`board_shape`: the board's shape where the photos show it (:mod:`dualcal.estimation.board_shape`);
6. :func:`lens_choice` (``model="auto"``): every camera's lens model chosen by its held-out instants
   (:mod:`dualcal.estimation.model_selection`); where one changes, stages 3-5 again with the chosen models,
   started from the cameras alone;
7. :func:`calibration`: the covariance, clustered by instant and textbook, of every value calib.json reports,
   and the :class:`~dualcal.geometry.model.RigModel` (a final adjustment that did not converge is said so);
8. :func:`dualcal.estimation.checking.calibration_checks`: every check of the result, each photo or instant
   to blame named.

A new term of the adjustment (a prior, a focus model, a weight per photo) is one switch of
:class:`~dualcal.estimation.fitting.Setup`, set by the stage that knows it, and one piece of the problem's definition
in :mod:`dualcal.estimation.adjust`: every later stage's adjustment then has it. The photos' weights are set in
stage 3, the known intrinsics in stage 1 from :func:`calibrate_rig`'s ``known_intrinsics``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .adjust import Solution
from .board_shape import BOARD_SHAPES, with_board_shape
from .checking import calibration_checks
from .circle_centres import fit_circle_outlines
from .duplicates import describe_duplicates, merge_duplicate_instants
from ..errors import InputError
from .focus_model import photo_focus, with_breathing
from .ois import may_stabilise, ois_spread, with_ois
from .fitting import (AUTO_MODEL, Setup, known_intrinsics_record, lens_models_for, rig_model_from_solution,
                      usable_photos)
from .model_selection import choose_lens_models, preferred_lens_models
from .outliers import adjust_dropping_outliers
from .photo_noise import PhotoNoise
from ..geometry.camera import DEFAULT_LENS_MODEL
from ..geometry.model import CornerSet, KnownIntrinsics, RigModel, choose_reference
from ..geometry.rotation import rotation_angle_deg
from ..progress import collect_warnings, warn

__all__ = ["BOARD_SHAPES", "Fit", "LensModels", "Photos", "Settings", "calibrate_rig"]


@dataclass(frozen=True)
class Settings:
    """The options of a calibration (:func:`calibrate_rig`'s keywords but the lens model)."""

    skew: bool = False
    rig_mode: str = "rigid"
    reference: str | None = None
    drop_outliers: bool = True
    outlier_factor: float = 6.0
    board_shape: str = "auto"
    weigh_photos: bool = True
    lens_motion: bool = True

    @property
    def factor(self) -> float | None:
        """The outlier rule's factor (:func:`dualcal.estimation.outliers.outlier_limit_px`), None where no outliers
        are looked for."""
        return self.outlier_factor if self.drop_outliers else None


@dataclass(frozen=True)
class Photos:
    """Stage 1: the corners calibrated (``corners``, duplicate instants merged, ``duplicates`` their records), the
    photos used, ``blocks`` ``(camera index, view, (N, 2) px)``, and ``setup``, the rig's cameras and the solver's
    switches (the lens models are the next stage's)."""

    corners: CornerSet
    duplicates: list[dict]
    blocks: list[tuple[int, str, np.ndarray]]
    setup: Setup


@dataclass(frozen=True)
class LensModels:
    """Stage 2: each camera's lens model to adjust with (``models``, in the order of the cameras), and with
    ``model="auto"`` the ``candidates`` ``{camera: models}`` and the ``preferred`` ``{camera: model}`` of every
    camera whose intrinsics are not known (None where the models were given)."""

    models: tuple[str, ...]
    candidates: dict[str, tuple[str, ...]] | None = None
    preferred: dict[str, str] | None = None


@dataclass(frozen=True)
class Fit:
    """Stages 3-5: the adjusted rig. ``setup`` the solver's switches (with the lens models and the photos'
    weights), ``blocks`` the photos kept, ``alone`` every camera alone over them (flat board), ``flat`` the rig tied
    in its mode (``alone`` in mode ``none``), ``solution`` the final one (``flat``, or with the board's shape),
    ``shape_test`` the board-shape test (:func:`dualcal.estimation.board_shape.board_shape_test`; None where not
    made), the photos and corners left out, each with its reason, ``noise`` each photo's
    (:class:`dualcal.estimation.photo_noise.PhotoNoise`; None where the photos are not weighed by it), and
    ``lens_motion`` the tests of the lens's motion (:func:`lens_motion`; None before them)."""

    setup: Setup
    blocks: list[tuple[int, str, np.ndarray]]
    alone: Solution
    flat: Solution
    solution: Solution
    shape_test: dict | None = None
    dropped: list[dict] = field(default_factory=list)
    dropped_corners: list[dict] = field(default_factory=list)
    noise: PhotoNoise | None = None
    lens_motion: dict | None = None
    circle_centres: dict | None = None


def photos_to_calibrate(corners: CornerSet, settings: Settings,
                        known: Mapping[str, KnownIntrinsics] | None = None) -> Photos:
    """Stage 1 (module docstring); ``known``: the cameras whose intrinsics are known (:func:`calibrate_rig`).

    Raises
    ------
    InputError
        Known intrinsics of a camera that is not in ``corners``, or of another image size.
    """
    corners, duplicates = merge_duplicate_instants(corners)
    if duplicates:
        warn(describe_duplicates(duplicates))
    names = sorted(corners.cameras)
    for name, k in (known or {}).items():
        if name not in corners.cameras:
            raise InputError(f"known intrinsics of camera {name!r}, which is not one of the corners' "
                             f"({', '.join(names)})")
        if tuple(k.camera.image_size) != tuple(corners.cameras[name].image_size):
            raise InputError(f"known intrinsics of camera {name!r} are for images of {k.camera.image_size}, its "
                             f"photos are {corners.cameras[name].image_size}: another camera or another resolution")
        again = k.photos_in(corners.cameras[name].views) if k.mode == "prior" else []
        if again:
            warn(f"camera {name}: {len(again)} of its photos ({', '.join(again[:3])}{', ...' if len(again) > 3 else ''}) "
                 f"are photos {k.source or 'its known intrinsics'} was calibrated from: their information counts "
                 "twice, in the prior and in the photos, and its sigmas come out too small; give the rig's step only "
                 "the joint instants, or calibrate these photos without --intrinsics")
    reference = settings.reference if settings.reference is not None else corners.reference
    X = corners.board.object_points_mm()
    setup = Setup(X, names, [corners.cameras[n].image_size for n in names],
                  names.index(choose_reference(names, reference)), settings.skew, settings.rig_mode,
                  known=dict(known) if known else None)
    return Photos(corners, duplicates, usable_photos(corners, names, X[:, :2]), setup)


def lens_models(photos: Photos, model: str | Mapping[str, str]) -> LensModels:
    """Stage 2 (module docstring): ``model`` for every camera, ``{camera: model}``, or ``"auto"``: each camera's
    candidates and preferred model (:func:`dualcal.estimation.model_selection.preferred_lens_models`); a camera
    whose intrinsics are known has their lens model."""
    setup = photos.setup
    known = {n: k.camera.model for n, k in (setup.known or {}).items()}
    if isinstance(model, str) and model == AUTO_MODEL:
        candidates, preferred = preferred_lens_models(setup, photos.blocks)
        return LensModels(lens_models_for({**preferred, **known}, setup.names), candidates, preferred)
    given = lens_models_for(model, setup.names)
    return LensModels(tuple(known.get(n, m) for n, m in zip(setup.names, given)))


def cameras_alone(photos: Photos, models: tuple[str, ...], settings: Settings, start: Solution | None = None) -> Fit:
    """Stage 3 (module docstring): every camera adjusted alone from Zhang's closed form, or from ``start`` (such
    a solution with other lens models), its outliers left out; with ``settings.weigh_photos`` each photo's noise
    estimated and the photos weighed by it (:mod:`dualcal.estimation.photo_noise`)."""
    setup = replace(photos.setup, model=models)
    dropped: list[dict] = []
    dropped_corners: list[dict] = []
    alone, blocks, noise, solved = adjust_dropping_outliers(replace(setup, mode="none"), photos.blocks,
                                                            settings.factor, dropped, dropped_corners, start,
                                                            weigh=settings.weigh_photos)
    setup = replace(solved, mode=setup.mode)
    return Fit(setup, blocks, alone, alone, alone, None, dropped, dropped_corners, noise)


def circle_outlines(photos: Photos, fit: Fit) -> Fit:
    """Stage 3's second part (module docstring), for a circle grid only: each circle's centre as measured taken as
    the centre of its outline's image, not the image of its centre (:mod:`dualcal.estimation.circle_centres`: the
    perspective bias removed by moving each observed centre by its offset under the cameras alone, to the fixed
    point). The later stages adjust the moved centres; ``circle_centres`` records the offsets."""
    board = photos.corners.board
    if not board.is_circle_grid:
        return fit
    outlines = fit_circle_outlines(lambda blocks, start: fit.setup.solve(blocks, start, mode="none"), fit.blocks,
                                   fit.alone, board)
    largest = max(float(np.nanmax(np.linalg.norm(o, axis=1), initial=0.0)) for o in outlines.offsets_px.values())
    record = {"model": "outline", "largest_offset_px": largest, "solves": outlines.iterations,
              "change_px": outlines.change_px, "converged": outlines.converged}
    alone = outlines.solution
    return replace(fit, blocks=outlines.blocks, alone=alone, flat=alone, solution=alone, circle_centres=record)


#: A photo whose pose with its camera alone is turned by more than this from the rig's (degrees) may sit in the
#: other minimum of a small or distant board's pose (a planar target seen nearly square-on or from far has two
#: poses that fit its corners almost equally, turned tens of degrees apart); the cameras alone are then solved
#: again from the rig's poses, so that each photo's pose is the minimum nearest the rig's and the checks compare
#: like with like. A rigid rig's photos agree to minutes of arc; a weak photo's pose to a degree or two.
AMBIGUOUS_POSE_DEG = 10.0


def _turned_from_rig(alone: Solution, tied: Solution) -> float:
    """The largest angle (degrees) between a photo's pose with its camera alone and in the rig."""
    rig = tied.photo_poses
    both = [k for k in alone.photo_poses if k in rig]
    if not both:
        return 0.0
    return float(np.max(rotation_angle_deg(np.array([alone.photo_poses[k].R for k in both]),
                                           np.array([rig[k].R for k in both]))))


def rig_tied(fit: Fit, factor: float | None) -> Fit:
    """Stage 4 (module docstring): the rig in its mode, started from the cameras alone, its outliers (against
    each photo's noise with every camera alone) left out; the cameras alone solved again, from the rig's poses,
    over the photos it kept where it left out more, or where a photo's pose alone is turned far from the rig's
    (:data:`AMBIGUOUS_POSE_DEG`)."""
    if fit.setup.mode == "none":
        return fit
    dropped, dropped_corners = list(fit.dropped), list(fit.dropped_corners)
    tied, blocks, _, _ = adjust_dropping_outliers(fit.setup, fit.blocks, factor, dropped, dropped_corners,
                                                  fit.alone, fit.noise)
    alone = fit.alone
    if blocks is not fit.blocks or _turned_from_rig(fit.alone, tied) > AMBIGUOUS_POSE_DEG:
        alone = fit.setup.solve(blocks, tied, mode="none")
    return replace(fit, blocks=blocks, alone=alone, flat=tied, solution=tied, dropped=dropped,
                   dropped_corners=dropped_corners)


def lens_motion(photos: Photos, alone: Fit, fit: Fit, said: list[str], factor: float | None) -> Fit:
    """Stage 4's second part (module docstring): from ``fit`` (stage 4's rig) whether its photos shift with the
    stabiliser (:func:`dualcal.estimation.ois.with_ois`, the spreads by :func:`dualcal.estimation.ois.ois_spread`;
    a rig tied only, the cameras whose EXIF gives a focal length), then whether each camera's lens breathes with its
    focus (:func:`dualcal.estimation.focus_model.with_breathing`; each photo's focus from its metadata, else its
    board's distance). Each term chosen runs stages 3 (its cameras alone, from ``alone``, stage 3's) and 4 again with it,
    so that the outliers are judged with it (a stabilised rig's instants do not fit one relative pose without it)
    and the next test is made on what it leaves; what stage 4 said before (``said``) is said where neither is
    chosen. ``lens_motion`` records the tests (calib.json ``adjustment.lens_motion``)."""
    def again(setup: Setup) -> Fit:
        cameras = setup.solve(alone.blocks, alone.alone, mode="none")
        return rig_tied(replace(alone, setup=setup, alone=cameras, flat=cameras, solution=cameras), factor)

    first, record = fit, {}
    setup, record["ois"] = with_ois(fit.setup, fit.flat, fit.alone, may_stabilise(photos.corners))
    if setup is not fit.setup:      # the spreads from the instants its prior keeps, but those that fit far worse
        tied = again(setup).flat
        if record["ois"]["left_out"]:
            tied = setup.solve([b for b in tied.problem.blocks if b[1] not in record["ois"]["left_out"]], tied)
        setup, spread = ois_spread(setup, tied)
        record["ois"].update(spread)
        fit = again(setup)
    setup, record["breathing"] = with_breathing(fit.setup, fit.flat, photo_focus(photos.corners, fit.alone))
    if setup is not fit.setup:
        fit = again(setup)
    if fit is first:
        for message in said:
            warn(message)
    return replace(fit, lens_motion={k: v for k, v in record.items() if v is not None})


def board_shape(fit: Fit, option: str) -> Fit:
    """Stage 5 (module docstring): the board's shape as ``option`` says
    (:func:`dualcal.estimation.board_shape.with_board_shape`)."""
    solution, shape_test = with_board_shape(fit.setup, fit.flat, option)
    return replace(fit, solution=solution, shape_test=shape_test)


def adjusted(photos: Photos, models: tuple[str, ...], settings: Settings, start: Solution | None = None) -> Fit:
    """Stages 3 to 5 with the lens ``models``."""
    alone = circle_outlines(photos, cameras_alone(photos, models, settings, start))   # 3
    if not settings.lens_motion:
        return board_shape(rig_tied(alone, settings.factor), settings.board_shape)     # 4, 5
    with collect_warnings() as said:
        fit = rig_tied(alone, settings.factor)                            # 4
    fit = lens_motion(photos, alone, fit, said, settings.factor)          # 4: focus, stabiliser
    return board_shape(fit, settings.board_shape)                         # 5


def lens_choice(fit: Fit, lenses: LensModels) -> tuple[tuple[str, ...], list[dict]]:
    """Stage 6 (module docstring): every camera's lens model chosen by its held-out instants, from ``fit`` with
    every camera's preferred model, and the comparison as calib.json keeps it (``adjustment["lens_models"]``)."""
    chosen, comparison = choose_lens_models(fit.solution, fit.alone, lenses.candidates, lenses.preferred)
    return tuple(chosen.get(n, m) for n, m in zip(fit.setup.names, fit.setup.models)), comparison


def calibration(photos: Photos, fit: Fit, settings: Settings) -> RigModel:
    """Stage 7 (module docstring): ``fit``'s final solution with the covariance of every value it reports, as
    calib.json holds it (:func:`dualcal.estimation.fitting.rig_model_from_solution`)."""
    sol, setup = fit.solution, fit.setup
    if not sol.converged:
        warn(f"the adjustment (rig mode {setup.mode}, {'Model 2' if setup.skew else 'Model 1'}) did not converge: "
             f"{sol.termination}; the results and their sigmas are not those of the best fit")
    rig = rig_model_from_solution(sol, photos.corners, fit.dropped, fit.dropped_corners)
    models = setup.model
    rig.adjustment["options"] = {"drop_outliers": bool(settings.drop_outliers),
                                 "outlier_factor": float(settings.outlier_factor), "board_shape": settings.board_shape,
                                 "model": models[0] if len(set(models)) == 1 else dict(zip(setup.names, models)),
                                 "weigh_photos": bool(settings.weigh_photos), "lens_motion": bool(settings.lens_motion)}
    if fit.shape_test is not None:
        rig.adjustment["board_shape_test"] = fit.shape_test
    if fit.noise is not None:
        kept = {(setup.names[c], v) for c, v, _ in sol.problem.blocks}
        rig.adjustment["photo_noise"] = fit.noise.to_dict(kept)
    if setup.known:
        rig.adjustment["known_intrinsics"] = known_intrinsics_record(setup)
    if fit.circle_centres is not None:
        rig.adjustment["circle_centres"] = fit.circle_centres
    if fit.lens_motion:
        rig.adjustment["lens_motion"] = fit.lens_motion
        if "ois" in fit.lens_motion:                  # the cameras judged: 0 where the photos show no shift
            rig.ois_sigma_px = {**dict.fromkeys(fit.lens_motion["ois"]["cameras"], 0.0), **rig.ois_sigma_px}
    return rig


def calibrate_rig(corners: CornerSet, skew: bool = False, rig_mode: str = "rigid",
                  reference: str | None = None, drop_outliers: bool = True,
                  outlier_factor: float = 6.0, board_shape: str = "auto",
                  model: str | Mapping[str, str] = DEFAULT_LENS_MODEL, weigh_photos: bool = True,
                  known_intrinsics: Mapping[str, KnownIntrinsics] | None = None, lens_motion: bool = True) -> RigModel:
    """Calibrate every camera of a rig and the rig itself from chessboard corners (the stages: module docstring).

    Parameters
    ----------
    corners : CornerSet
        the detected corners (corners.json content). Instants that repeat another's view (a copied
        photo, a burst: :mod:`dualcal.estimation.duplicates`) count once, with a warning; calib.json records them
        (``adjustment.duplicates``, and ``duplicates`` in each camera's entry of its corners).
    skew : bool
        False fixes skew = 0 (the paper's Model 1), True estimates it (Model 2)
    rig_mode : str
        ``rigid``, ``paper`` or ``none`` (see :mod:`dualcal.estimation.adjust`)
    reference : str or None
        name of the reference camera (default: the one recorded in ``corners``, else ``wide``,
        else the first name)
    drop_outliers : bool
        leave out corners whose residual exceeds ``outlier_factor`` x the median of
        their camera (:func:`dualcal.estimation.outliers.outlier_limit_px`), and photos where most corners are
        outliers. Outliers are looked for first with every camera adjusted alone (so that a bad photo shows
        in its own camera's residuals, not spread over the rig), then in ``rig_mode`` (which
        also reveals a board moved between the shots of one instant).
    board_shape : str
        ``auto`` estimates the board's out-of-plane shape and keeps it where the photos
        show it beyond their noise (:func:`dualcal.estimation.board_shape.board_shape_test`), ``fit`` always keeps
        it, ``flat`` takes the board as flat.
    model : str or Mapping[str, str]
        the lens model of every camera, a key of :data:`dualcal.geometry.camera.LENS_MODELS`:
        ``k1k2`` (the paper's), ``k1k2k3``, ``k1k2p1p2``, ``k1k2p1p2k3`` (OpenCV's five coefficients) or
        ``kb4`` (OpenCV's fisheye); or ``{camera: model}`` (cameras not named: ``k1k2``); or ``"auto"``:
        each camera's chosen by its held-out instants (:func:`lens_choice`, which records the comparison in
        ``adjustment["lens_models"]`` and the choice in ``adjustment["lens_models_chosen"]``)
    weigh_photos : bool
        estimate each photo's own noise from its residuals with every camera alone, weigh the photos by it in
        every adjustment and judge each photo's corners against it (:mod:`dualcal.estimation.photo_noise`;
        ``adjustment["photo_noise"]`` records it); False: every photo alike, corners judged against their
        camera's median residual
    known_intrinsics : Mapping[str, KnownIntrinsics] or None
        ``{camera: KnownIntrinsics}``: cameras whose lens model and intrinsics are known (an earlier calibration
        of each camera from its own photos, a peer's file). Each takes its lens model from it, and its
        intrinsics as a prior of its covariance (``mode`` ``prior``; every sigma then holds their uncertainty
        too), or held fixed (``fixed``: no covariance); Zhang's closed form is not needed for it (its photos'
        poses by space resection), and one photo of it suffices. The check ``intrinsics_prior`` says whether its
        photos agree with what was known (a lens that changed is named). ``adjustment["known_intrinsics"]``
        records them.
    lens_motion : bool
        find whether each camera's focal lengths change with its focus, and whether a hand-held phone's
        stabiliser shifts each photo's principal point, and model them where the photos show it (:func:`lens_motion`;
        ``adjustment["lens_motion"]`` records the tests); False: neither, as a lens that holds still (a camera
        whose corners.json gives no EXIF focal length is not focus-modelled either way).

    Returns
    -------
    RigModel
        calib.json's content: every camera's intrinsics and lens, the rig, the board's poses, every value's
        1-sigma (``sigma``, and the textbook ``sigma_formal``), the joint covariance and the checks.

    Raises
    ------
    InputError
        An unknown lens model or board shape option, known intrinsics of a camera that is not there.
    EstimationError
        Fewer than 3 usable views for a camera, degenerate views, no shared view in a rig.
    """
    if board_shape not in BOARD_SHAPES:
        raise InputError(f"--board-shape {board_shape!r} is unknown (choose from {', '.join(BOARD_SHAPES)})")
    settings = Settings(skew, rig_mode, reference, drop_outliers, outlier_factor, board_shape, weigh_photos,
                        lens_motion)
    photos = photos_to_calibrate(corners, settings, known_intrinsics)                    # 1
    lenses = lens_models(photos, model)                                                  # 2
    fit = adjusted(photos, lenses.models, settings)                                      # 3, 4, 5
    comparison = None
    if lenses.candidates is not None:
        chosen, comparison = lens_choice(fit, lenses)                                    # 6
        if chosen != lenses.models:
            fit = adjusted(photos, chosen, settings, start=fit.alone)                    # 3, 4, 5 again
    rig = calibration(photos, fit, settings)                                             # 7
    rig.checks = calibration_checks(fit.setup, rig, fit.solution, fit.flat, fit.alone)   # 8
    if comparison is not None:
        rig.adjustment["lens_models"] = comparison
        rig.adjustment["lens_models_chosen"] = dict(zip(fit.setup.names, fit.setup.model))
    if photos.duplicates:
        rig.adjustment["duplicates"] = photos.duplicates
    return rig
