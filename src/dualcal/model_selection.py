"""Which lens model the photos support: the error on instants the calibration did not see.

A lens model with more coefficients always fits the photos it was calibrated on better; the fair
question is whether it also predicts photos it did not see. For every instant ``v``, the
calibration without ``v`` predicts where ``v``'s corners lie once ``v``'s own board pose is fitted
again; the residuals of that prediction are the held-out residuals (a leave-one-instant-out
cross-validation). dualcal computes them from the full adjustment alone, linearised:
``e_v = (I - H_vv)^-1 r_v`` with ``H_vv`` the instant's block of the hat matrix
(:func:`dualcal.uncertainty.held_out_residuals`; exact for a linear model, one small
eigen-decomposition per instant, no re-adjustment). calib.json records them in ``adjustment``:
``held_out_rms_px`` (2-D, per corner) and ``held_out_per_instant``.

:func:`compare_lens_models` calibrates the same corners with every lens model (those the
calibration used: its outliers stay out, so every model is scored on the same corners) and
compares the models instant by instant: ``d_v = SS_v(model) - SS_v(best)``, the held-out sum of
squares (px^2) of instant ``v`` minus that of the model with the least held-out error; its mean
over the instants in units of its standard error says how many standard errors the model is
worse than the best. The recommendation is the model with the fewest coefficients that is within
:data:`RECOMMEND_WITHIN_SE` standard errors of the best: a richer model must earn its
coefficients by predicting the unseen instants clearly better.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .camera import LENS_MODELS
from .errors import EstimationError
from .model import RigModel
from .progress import warn

__all__ = ["LensModelScore", "RECOMMEND_WITHIN_SE", "compare_lens_models", "score_lens_models"]

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


def _squares(rig: RigModel, views: list[str]) -> np.ndarray:
    per = rig.adjustment["held_out_per_instant"]
    return np.array([per[v]["rms_px"] ** 2 * per[v]["corners"] for v in views])


def score_lens_models(rigs: dict[str, RigModel]) -> list[LensModelScore]:
    """Score calibrations of the same corners by different lens models (module docstring).

    Parameters
    ----------
    rigs : ``{model: calibration}``, each with ``adjustment["held_out_per_instant"]``.

    Returns
    -------
    One score per model, fewest coefficients first; exactly one is ``recommended``.

    Raises
    ------
    EstimationError
        No rigs, or fewer than 3 instants that every calibration could leave out.
    """
    if not rigs:
        raise EstimationError("no lens model to compare")
    views = sorted(set.intersection(*(set(r.adjustment["held_out_per_instant"]) for r in rigs.values())))
    if len(views) < 3:
        raise EstimationError(f"{len(views)} instant(s) can be left out by every model: a comparison needs 3")
    corners = {m: {v: r.adjustment["held_out_per_instant"][v]["corners"] for v in views} for m, r in rigs.items()}
    if any(c != next(iter(corners.values())) for c in corners.values()):
        raise EstimationError("the calibrations compared did not use the same corners")
    n_corners = sum(next(iter(corners.values())).values())
    squares = {m: _squares(r, views) for m, r in rigs.items()}
    best = min(squares, key=lambda m: squares[m].sum())
    order = sorted(rigs, key=lambda m: (len(LENS_MODELS[m]), m))
    worse = {}
    for m in order:
        d = squares[m] - squares[best]
        se = np.std(d, ddof=1) / np.sqrt(len(d))
        worse[m] = float(np.mean(d) / se) if se > 0 else 0.0
    chosen = next(m for m in order if worse[m] <= RECOMMEND_WITHIN_SE)
    return [LensModelScore(m, len(LENS_MODELS[m]), rigs[m].rms_px, float(np.sqrt(squares[m].sum() / n_corners)),
                           worse[m], m == chosen) for m in order]


def compare_lens_models(rig: RigModel, models=tuple(LENS_MODELS),
                        calibrate: Callable[..., RigModel] | None = None) -> list[LensModelScore]:
    """Calibrate the corners ``rig`` used with every lens model of ``models`` and score them.

    Every calibration has ``rig``'s settings (skew, rig mode, reference, board shape), with the
    corners and photos ``rig`` used (:meth:`RigModel.used_corners`) and outliers not looked for
    again, so that every model is judged on the same corners; ``rig`` itself stands for its own
    model. A model whose calibration fails is left out with a warning.
    """
    if calibrate is None:
        from .calibrate import calibrate_rig as calibrate
    corners = rig.used_corners()
    options = {**rig.calibration_options(), "drop_outliers": False}
    rigs = {rig.model: rig}
    for model in models:
        if model in rigs:
            continue
        try:
            rigs[model] = calibrate(corners, skew=rig.skew, rig_mode=rig.rig_mode, reference=rig.reference,
                                    **{**options, "model": model})
        except EstimationError as exc:
            warn(f"lens model {model} could not be calibrated for the comparison: {exc}")
    return score_lens_models(rigs)
