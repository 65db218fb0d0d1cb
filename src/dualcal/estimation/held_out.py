"""A solution's fit and its error on instants it did not see: what comparing lens models scores.

For every instant ``v``, the calibration without ``v`` predicts where ``v``'s corners lie once ``v``'s own
board pose is fitted again; the residuals of that prediction are the held-out residuals (a
leave-one-instant-out cross-validation), found from the full adjustment alone, linearised
(:meth:`dualcal.estimation.adjust.Solution.held_out_squares`, :mod:`dualcal.estimation.uncertainty`).
calib.json records them in ``adjustment`` (``held_out_rms_px``, ``held_out_per_instant``,
``held_out_per_camera``), and :mod:`dualcal.estimation.model_selection` scores lens models by them.
"""

from __future__ import annotations

import numpy as np

from .adjust import Solution
from .checks import camera_edge_ratio

__all__ = ["camera_piece", "fit_summary", "held_out_error", "held_out_summary", "joint_fit"]


def fit_summary(sol: Solution) -> dict:
    """What comparing models needs of a solution: ``rms_px`` (2-D, per corner), ``camera_rms_px``
    ``{camera: px}`` and the held-out errors of :func:`held_out_error`."""
    sq = np.sum(sol.residuals ** 2, axis=2)
    cams = np.array([c for c, _, _ in sol.problem.blocks])
    return {"rms_px": float(np.sqrt(np.nanmean(sq))),
            "camera_rms_px": {name: float(np.sqrt(np.nanmean(sq[cams == c])))
                              for c, name in enumerate(sol.problem.cameras)},
            **held_out_error(sol)}


def held_out_error(sol: Solution) -> dict:
    """The error on instants the calibration did not see (:meth:`Solution.held_out_squares`), as
    :func:`held_out_summary` gives it."""
    names = sol.problem.cameras
    return held_out_summary({view: None if photos is None else {names[c]: sq for c, sq in sorted(photos.items())}
                             for view, photos in sol.held_out_squares().items()}, names)


def held_out_summary(squares: dict[str, dict[str, tuple[float, int]] | None], names) -> dict:
    """From each instant's held-out ``{camera: (px^2, corners)}`` (None: it cannot be left out):
    ``held_out_rms_px``, the RMS length of the 2-D held-out residual per corner over the instants
    that can be left out, ``held_out_per_instant`` ``{view: {"rms_px", "corners"}}`` and the same of
    each camera of ``names``' own corners, ``held_out_per_camera`` ``{camera: {view: {"rms_px", "corners"}}}``."""
    per_instant, per_camera = {}, {name: {} for name in names}
    for view, photos in squares.items():
        if photos is None:
            continue
        for name, (sq, n) in photos.items():
            per_camera[name][view] = {"rms_px": float(np.sqrt(max(sq, 0.0) / n)), "corners": n}
        sq, n = (sum(x) for x in zip(*photos.values()))
        per_instant[view] = {"rms_px": float(np.sqrt(max(sq, 0.0) / n)), "corners": n}
    total = sum(d["rms_px"] ** 2 * d["corners"] for d in per_instant.values())
    corners = sum(d["corners"] for d in per_instant.values())
    return {"held_out_rms_px": float(np.sqrt(total / corners)) if corners else None,
            "held_out_per_instant": per_instant, "held_out_per_camera": per_camera}


def camera_piece(sol: Solution, c: int) -> dict:
    """Camera ``c``'s part of a fit: its corners' sum of squares (px^2) and count, and per instant its
    held-out ``(px^2, corners)`` (:meth:`dualcal.estimation.adjust.Solution.held_out_squares`), None where the
    instant cannot be left out."""
    sq = np.sum(sol.residuals ** 2, axis=2)[[b for b, (cc, _, _) in enumerate(sol.problem.blocks) if cc == c]]
    held = {v: None if photos is None else photos[c] for v, photos in sol.held_out_squares().items()
            if photos is None or c in photos}
    return {"squares": float(np.nansum(sq)), "corners": int(np.isfinite(sq).sum()), "held_out": held,
            "edge_ratio": camera_edge_ratio(sol, c, per_view=False)[0]}


def joint_fit(pieces: dict[str, dict]) -> dict:
    """The fit of cameras alone, ``{camera: piece}`` (:func:`camera_piece`), as
    :func:`fit_summary` gives that of one adjustment of them all (an instant that one camera cannot do without
    is left out of all)."""
    views = sorted({v for p in pieces.values() for v in p["held_out"]})
    squares = {v: None if any(p["held_out"].get(v, ()) is None for p in pieces.values()) else
               {n: p["held_out"][v] for n, p in pieces.items() if v in p["held_out"]} for v in views}
    return {"rms_px": float(np.sqrt(sum(p["squares"] for p in pieces.values())
                                    / sum(p["corners"] for p in pieces.values()))),
            "camera_rms_px": {n: float(np.sqrt(p["squares"] / p["corners"])) for n, p in pieces.items()},
            "camera_edge_ratio": {n: p["edge_ratio"] for n, p in pieces.items()},
            **held_out_summary(squares, list(pieces))}
