"""Which lens model the photos support: the error on instants the calibration did not see.

A lens model with more coefficients always fits the photos it was calibrated on better; the fair
question is whether it also predicts photos it did not see. For every instant ``v``, the
calibration without ``v`` predicts where ``v``'s corners lie once ``v``'s own board pose is fitted
again; the residuals of that prediction are the held-out residuals (a leave-one-instant-out
cross-validation). dualcal computes them from the full adjustment alone, linearised:
``e_v = (I - H_vv)^-1 r_v`` with ``H_vv`` the instant's block of the hat matrix
(:func:`dualcal.estimation.uncertainty.held_out_residuals`; exact for a linear model, one small
eigen-decomposition per instant, no re-adjustment). calib.json records them in ``adjustment``:
``held_out_rms_px`` (2-D, per corner) and ``held_out_per_instant``.

:func:`compare_lens_models` adjusts the same corners with every lens model (those the calibration
used: its outliers stay out, so every model is scored on the same corners; each adjustment starts
from the calibration's values, :func:`dualcal.estimation.fitting.refit`, and stops within 0.05 sigma of its
minimum, :data:`dualcal.estimation.lm.COMPARISON_LM`) and compares the models instant by instant: ``d_v = SS_v(model) -
SS_v(best)``, the held-out sum of squares (px^2) of instant ``v`` minus that of the model with the
least held-out error; its mean over the instants in units of its standard error says how many
standard errors the model is worse than the best. The recommendation is
the model with the fewest coefficients that is within :data:`RECOMMEND_WITHIN_SE` standard errors of
the best: a richer model must earn its coefficients by predicting the unseen instants clearly
better.

``calibrate_rig(model="auto")`` (:func:`preferred_lens_models`, :func:`choose_lens_models`: two stages of the
calibration, :mod:`dualcal.estimation.calibrate`) makes that choice
for every camera, from its own corners' held-out residuals (calib.json ``adjustment.held_out_per_camera``).
The candidates of a camera are the radial-tangential models, and the fisheye ``kb4`` too where the camera's field
of view makes one plausible: Zhang's closed form (no lens) puts the image's corner more than
:data:`FISHEYE_HALF_DIAGONAL_DEG` from the axis (a phone's main camera: about 40, its ultra-wide:
55-60 and more). For such a camera ``kb4`` is also the preferred model, as ``k1k2`` is for the
others: a polynomial in the pinhole radius must then predict clearly better to be chosen (the paired
test over instants is weak when, as here, the difference lies in the few instants that put the board
near the image's edge). A first calibration gives each camera its preferred model and finds the
outliers; then one adjustment per lens model, on the corners the first used and started from its
values (:func:`dualcal.estimation.fitting.refit`), with every camera alone (rig mode ``none``, so that no
camera's lens changes another's held-out error through the shared poses), gives that model to every
camera it is a candidate of (the others keep their preferred model): one solve per model scores
every camera. Each camera then gets the model of the rule above among its candidates, and the rig is
calibrated once more with them."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..geometry.camera import DEFAULT_LENS_MODEL, FISHEYE_MODELS, LENS_MODELS, CameraModel, image_corner_radius
from ..errors import EstimationError
from .adjust import Solution
from .checks import EDGE_RATIO
from .fitting import Setup, refit
from .held_out import camera_piece, fit_summary, joint_fit
from ..geometry.model import RigModel
from ..geometry.zhang import closed_form_camera
from ..progress import warn
from .lm import COMPARISON_LM

__all__ = ["FISHEYE_HALF_DIAGONAL_DEG", "LensModelScore", "RECOMMEND_WITHIN_SE", "choose_lens_models",
           "compare_lens_models", "lens_model_candidates", "score_lens_models"]

#: A camera whose image corner lies more than this far from its axis (Zhang's closed form, no lens)
#: has the fisheye ``kb4`` among its candidate lens models.
FISHEYE_HALF_DIAGONAL_DEG = 50.0

#: A model within this many standard errors of the best held-out error counts as good as the best.
RECOMMEND_WITHIN_SE = 2.0


@dataclass(frozen=True)
class LensModelScore:
    """One lens model's fit and held-out error (px, 2-D per corner) on the compared instants;
    ``worse_se`` how many standard errors of the paired per-instant difference its held-out error
    exceeds the best model's (0 for the best)."""

    model: str
    coefficients: int
    fit_rms_px: float
    held_out_rms_px: float
    worse_se: float
    recommended: bool


def rig_fit(rig: RigModel) -> dict:
    """A calibration's fit and held-out errors as :func:`score_lens_models` takes them (the keys of
    :func:`dualcal.estimation.held_out.fit_summary`)."""
    return {"rms_px": rig.rms_px, "camera_rms_px": rig.camera_rms_px,
            **{k: rig.adjustment[k] for k in ("held_out_per_instant", "held_out_per_camera")}}


def score_lens_models(fits: dict[str, dict], camera: str | None = None,
                      first: str | None = None) -> list[LensModelScore]:
    """Score fits of the same corners by different lens models (module docstring).

    Parameters
    ----------
    fits : ``{model: fit}``, each with ``held_out_per_instant`` and ``rms_px`` (and
        ``held_out_per_camera``, ``camera_rms_px`` for a ``camera``): :func:`dualcal.estimation.held_out.fit_summary`
        of a solution, or :func:`rig_fit` of a calibration.
    camera : score one camera's corners only (its fit RMS, its held-out errors), else the whole rig's.
    first : a model preferred to all others (a fisheye's ``kb4``): it comes first in the order in which
        the first model within :data:`RECOMMEND_WITHIN_SE` of the best is recommended.

    Returns
    -------
    One score per model, ``first`` first, then fewest coefficients first; exactly one is ``recommended``.

    Raises
    ------
    EstimationError
        No fits, or fewer than 3 instants that every model could leave out.
    """
    if not fits:
        raise EstimationError("no lens model to compare")
    held = {m: f["held_out_per_instant"] if camera is None else f["held_out_per_camera"][camera]
            for m, f in fits.items()}
    views = sorted(set.intersection(*(set(h) for h in held.values())))
    unscored = sorted(set.union(*(set(h) for h in held.values())) - set(views))
    if unscored:            # an instant a model cannot predict without it determines some of its terms alone
        why = ", ".join(f"{v} ({', '.join(m for m, h in held.items() if v not in h)})" for v in unscored[:6])
        warn(f"lens models{f' of {camera}' if camera else ''} compared on the {len(views)} instants every one can "
             f"predict without them; {len(unscored)} left out, which the model(s) named cannot predict without "
             f"them (they alone determine some of its terms): {why}")
    if len(views) < 3:
        raise EstimationError(f"{len(views)} instant(s) can be left out by every model: a comparison needs 3")
    corners = {m: {v: h[v]["corners"] for v in views} for m, h in held.items()}
    if any(c != next(iter(corners.values())) for c in corners.values()):
        raise EstimationError("the calibrations compared did not use the same corners")
    n_corners = sum(next(iter(corners.values())).values())
    squares = {m: np.array([h[v]["rms_px"] ** 2 * h[v]["corners"] for v in views]) for m, h in held.items()}
    best = min(squares, key=lambda m: squares[m].sum())
    order = sorted(fits, key=lambda m: (m != first, len(LENS_MODELS[m]), m))
    worse = {}
    for m in order:
        d = squares[m] - squares[best]
        se = np.std(d, ddof=1) / np.sqrt(len(d))
        worse[m] = float(np.mean(d) / se) if se > 0 else 0.0
    chosen = next(m for m in order if worse[m] <= RECOMMEND_WITHIN_SE)
    fit = {m: f["rms_px"] if camera is None else f["camera_rms_px"][camera] for m, f in fits.items()}
    return [LensModelScore(m, len(LENS_MODELS[m]), fit[m], float(np.sqrt(squares[m].sum() / n_corners)),
                           worse[m], m == chosen) for m in order]


def _refits(rig: RigModel, mappings: dict[str, object], rig_mode: str | None = None) -> dict[str, dict]:
    """:func:`dualcal.estimation.held_out.fit_summary` of ``rig``'s corners refitted with each lens model mapping
    ``{name: model or {camera: model}}`` (:func:`dualcal.estimation.fitting.refit`); one that cannot be solved
    is left out with a warning."""
    solved = {name: _compared(f"lens model {name}", rig, mapping, rig_mode) for name, mapping in mappings.items()}
    return {name: fit_summary(sol) for name, sol in solved.items() if sol is not None}


def _compared(what: str, source, model, rig_mode: str | None, cameras=None) -> Solution | None:
    """``source`` adjusted again with lens ``model`` to a comparison's tolerance
    (:func:`dualcal.estimation.fitting.refit`, :data:`dualcal.estimation.lm.COMPARISON_LM`); None, with a
    warning naming ``what``, where that cannot be solved."""
    try:
        return refit(source, model=model, rig_mode=rig_mode, options=COMPARISON_LM, cameras=cameras)
    except EstimationError as exc:
        warn(f"{what} could not be calibrated for the comparison: {exc}")
        return None


def compare_lens_models(rig: RigModel, models=tuple(m for m in LENS_MODELS if m not in FISHEYE_MODELS)
                        ) -> list[LensModelScore]:
    """Score every lens model of ``models`` on the corners ``rig`` used (:meth:`RigModel.used_corners`):
    each is adjusted from ``rig``'s values in ``rig``'s settings (skew, rig mode, reference, board shape),
    without looking for outliers again (:func:`dualcal.estimation.fitting.refit`), so that every model is judged
    on the same corners; ``rig`` itself stands for its own model."""
    fits = {rig.model: rig_fit(rig)} if rig.model in LENS_MODELS else {}
    fits.update(_refits(rig, {m: m for m in models if m not in fits}))
    return score_lens_models(fits)


def lens_model_grid(adjustment: dict) -> tuple[list[str], list[tuple[str, list[dict | None]]]]:
    """``--model auto``'s comparison as a grid (what its tables show): the models (calib.json
    ``adjustment["lens_models"]``), and per camera one cell per model, ``{"held_out_rms_px", "worse_se",
    "chosen"}``, or None where the model is no candidate of the camera."""
    entries, chosen = adjustment["lens_models"], adjustment["lens_models_chosen"]
    rows = []
    for name, model in chosen.items():
        cells = [e["per_camera"].get(name, {"candidate": False}) for e in entries]
        rows.append((name, [{"held_out_rms_px": d["held_out_rms_px"], "worse_se": d["worse_se"],
                             "chosen": e["model"] == model} if d["candidate"] else None
                            for e, d in zip(entries, cells)]))
    return [e["model"] for e in entries], rows


def _camera_entry(score: LensModelScore | None) -> dict:
    """calib.json's ``per_camera`` entry of one model for one camera (``candidate`` False: not scored)."""
    if score is None:
        return {"candidate": False}
    return {"candidate": True, **{k: v for k, v in asdict(score).items() if k not in ("model", "coefficients")}}


def lens_model_candidates(cam: CameraModel) -> tuple[str, ...]:
    """The lens models ``calibrate_rig(model="auto")`` tries for a camera whose closed-form intrinsics are
    ``cam`` (its matrix A): the radial-tangential ones, and the fisheyes where the image's corner lies
    more than :data:`FISHEYE_HALF_DIAGONAL_DEG` from the axis through a pinhole of that A."""
    wide = np.degrees(np.arctan(image_corner_radius(cam.pinhole()))) > FISHEYE_HALF_DIAGONAL_DEG
    return tuple(m for m in LENS_MODELS if wide or m not in FISHEYE_MODELS)


def preferred_lens_models(setup: Setup, blocks) -> tuple[dict[str, tuple[str, ...]], dict[str, str]]:
    """Every camera's candidate lens models (:func:`lens_model_candidates`, from Zhang's closed form of its
    usable photos ``blocks``, ``(camera index, view, uv)``) and its preferred one: the fisheye ``kb4`` where it
    is a candidate, else :data:`dualcal.geometry.camera.DEFAULT_LENS_MODEL`; a camera whose intrinsics are
    known (``setup.known``) has none.

    Raises
    ------
    EstimationError
        A camera with fewer than 3 usable photos.
    """
    xy = setup.X_board[:, :2]
    candidates = {}
    for c, name in enumerate(setup.names):
        if name in (setup.known or {}):                  # its lens model is known
            continue
        views = {v: uv for cc, v, uv in blocks if cc == c}
        if len(views) < 3:
            raise EstimationError(f"camera {name!r} has {len(views)} usable view(s); at least 3 are needed")
        candidates[name] = lens_model_candidates(closed_form_camera(xy, views, setup.sizes[c], setup.skew))
    preferred = {n: next((m for m in c if m in FISHEYE_MODELS), DEFAULT_LENS_MODEL) for n, c in candidates.items()}
    return candidates, preferred


def choose_lens_models(sol: Solution, alone: Solution, candidates: dict[str, tuple[str, ...]],
                       preferred: dict[str, str]) -> tuple[dict[str, str], list[dict]]:
    """Every camera's lens model chosen by its held-out instants (module docstring), from ``sol``, a
    calibration's final solution with every camera's ``preferred`` model (:func:`preferred_lens_models`), and
    ``alone``, its solution with every camera alone (flat board) over the same photos.

    Returns ``{camera: model}`` and the comparison as calib.json keeps it (``adjustment["lens_models"]``):
    one entry per model (the whole rig's scores, every camera alone; for a model that is not every camera's
    candidate, the others keep their preferred model), each with ``per_camera``
    ``{camera: {"candidate", "fit_rms_px", "held_out_rms_px", "worse_se", "recommended"}}``.
    """
    names = sorted(candidates)
    mappings = {m: {n: m if m in candidates[n] else preferred[n] for n in names}
                for m in LENS_MODELS if any(m in c for c in candidates.values())}
    fits = _camera_fits(sol, alone, candidates, preferred, mappings)
    per_camera, chosen = {}, dict(preferred)
    for n in names:
        try:
            scores = score_lens_models({m: f for m, f in fits.items() if m in candidates[n]}, n, first=preferred[n])
        except EstimationError as exc:
            warn(f"the lens models of {n!r} could not be compared ({exc}): it keeps {preferred[n]}")
            continue
        per_camera[n] = {s.model: s for s in scores}
        chosen[n] = _edge_consistent(n, next(s.model for s in scores if s.recommended), scores, fits)
    try:
        overall = {s.model: asdict(s) for s in score_lens_models(fits)}
    except EstimationError:         # no model, or too few instants: the per-camera entries say it
        overall = {}
    return chosen, [{**overall.get(m, {"model": m, "coefficients": len(LENS_MODELS[m])}),
                     "per_camera": {n: _camera_entry(per_camera.get(n, {}).get(m)) for n in names}} for m in fits]


def _edge_consistent(camera: str, recommended: str, scores: list[LensModelScore], fits: dict[str, dict]) -> str:
    """The model chosen for ``camera``: the ``recommended`` one, unless its residuals grow towards the image's edge
    (its RMS of the outermost third of the corners over the innermost's above
    :data:`dualcal.estimation.checks.EDGE_RATIO`, the ``lens_model`` check's limit) where a candidate's do not and
    predict the unseen instants better: then the one of those with the fewest coefficients. The paired test over
    instants is weak where the difference lies in the few instants that reach the image's edge (8 instants, a lens
    with k3: 1.9 standard errors for a model with 1.9 times the held-out RMS); a model the ``lens_model`` check
    would fail is not chosen over one it passes."""
    ratio = {s.model: fits[s.model].get("camera_edge_ratio", {}).get(camera, float("nan")) for s in scores}
    held = {s.model: s.held_out_rms_px for s in scores}
    if not ratio[recommended] > EDGE_RATIO:
        return recommended
    better = [s.model for s in scores if ratio[s.model] <= EDGE_RATIO and held[s.model] < held[recommended]]
    return better[0] if better else recommended


def _camera_fits(sol: Solution, alone: Solution, candidates, preferred,
                 mappings: dict[str, dict[str, str]]) -> dict[str, dict]:
    """``{model: fit}`` (:func:`dualcal.estimation.held_out.fit_summary`'s keys) of ``sol``'s photos with every
    camera alone and the lens models of each mapping ``{model: {camera: model}}``, each adjusted by
    :func:`dualcal.estimation.fitting.refit`.

    With every camera alone and a flat board no camera's fit depends on another's: each camera is adjusted
    alone once per candidate model (its preferred one is ``alone``'s; every other from the solution of the
    camera's richest model nested in it that has been solved, or from Zhang's closed form for another family),
    and a mapping's fit is put together from its cameras' (an instant is left out of every camera where one
    camera cannot do without it, as in one adjustment of them all). A board whose shape ``sol`` estimated ties
    the cameras together: one adjustment of them all per distinct mapping, from ``sol``. One that cannot be
    solved is left out with a warning."""
    shaped = sol.problem.board_shape

    def piece(n: str, mapping: dict[str, str]):
        """Which solution's part camera ``n`` takes in ``mapping``'s fit."""
        return n, tuple(sorted(mapping.items())) if shaped else mapping[n]

    if shaped:
        requests = [(None, key) for key in sorted({tuple(sorted(mp.items())) for mp in mappings.values()})]
        solved = {}
    else:               # fewest coefficients first: each model starts from the richest one nested in it
        requests = [((n,), m) for n in sorted(candidates)
                    for m in sorted(candidates[n], key=lambda m: len(LENS_MODELS[m])) if m != preferred[n]]
        solved = {((n,), preferred[n]): alone for n in candidates}
    for cameras, model in requests:
        start = sol if cameras is None else _nested_start(solved, cameras[0], model, preferred)
        what = f"lens models {dict(model)}" if cameras is None else f"lens model {model} of {cameras[0]!r}"
        solved[cameras, model] = _compared(what, start, dict(model) if cameras is None else model, "none", cameras)
    pieces = {(n, model): camera_piece(s, c) for (cameras, model), s in solved.items() if s is not None
              for c, n in enumerate(s.problem.cameras) if cameras is None or n in cameras}
    return {m: joint_fit({n: pieces[piece(n, mp)] for n in mp}) for m, mp in mappings.items()
            if all(piece(n, mp) in pieces for n in mp)}


def _nested_start(solved: dict, n: str, model: str, preferred: dict[str, str]) -> Solution:
    """The solution camera ``n``'s ``model`` starts from: that of its richest model nested in ``model`` solved
    so far (:func:`_camera_fits`), else its preferred model's."""
    nested = [k for (cams, k), s in solved.items() if cams == (n,) and s is not None
              and (k in FISHEYE_MODELS) == (model in FISHEYE_MODELS) and set(LENS_MODELS[k]) <= set(LENS_MODELS[model])]
    return solved[(n,), max(nested, key=lambda k: len(LENS_MODELS[k])) if nested else preferred[n]]
