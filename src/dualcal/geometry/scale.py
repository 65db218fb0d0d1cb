"""The board's scale: the tolerance of the printed squares in every length dualcal gives.

Every length a calibration yields rests on the square size: were the squares ``(1 + e)`` times the size
given, every board coordinate, board pose translation, the rig's ``t_mm`` and baseline, and every
point measured with the rig would be ``(1 + e)`` times larger, while no pixel, angle or intrinsic
would change. A board printed at home is true to a few tenths of a percent, so ``e`` is a random
error with ``sigma_e = square_sigma_mm / square_mm`` (:attr:`dualcal.geometry.board.Board.square_sigma_mm`),
the same for all lengths: fully correlated. Its part of a length ``L``'s variance is ``(sigma_e L)^2``,
and of a point ``X`` (in the reference camera's frame, whose origin the scale keeps) ``sigma_e^2 X X^T``;
so a length-like sigma is ``sqrt(sigma^2 + (sigma_e L)^2)`` (:func:`with_scale`). Differences of lengths
(an error common to both) and ratios are untouched by it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["relative_sigma", "scale_share", "with_scale", "with_scale_in_measurement"]


def relative_sigma(board) -> float:
    """``sigma_e``: the relative 1-sigma of the board's scale (0 when the squares are taken as exact)."""
    return float(board.square_sigma_mm) / float(board.square_mm)


def with_scale(sigma, value, rel: float):
    """``sqrt(sigma^2 + (rel value)^2)``: a length-like sigma with the board's scale added (elementwise)."""
    return np.sqrt(np.square(sigma) + np.square(rel * np.asarray(value, float)))


def scale_share(sigma_total, value, rel: float):
    """The share of ``sigma_total``'s variance that the board's scale makes (0 where ``sigma_total`` is 0)."""
    total = np.square(np.asarray(sigma_total, float))
    part = np.square(rel * np.asarray(value, float))
    return np.divide(part, total, out=np.zeros_like(total), where=total > 0)


def with_scale_in_measurement(doc: dict, rel: float) -> dict:
    """A measure.json document (:func:`dualcal.estimation.measurement.measure`) with the board's scale in every sigma.

    Points: ``sigma_mm`` per coordinate and ``depth_sigma_mm`` (along the line of sight: the distance
    scales); lengths: ``sigma_mm``, ``sigma_percent``. Each gains ``sigma_scale_mm``, the scale's part
    (0 for exact squares), so that a reader sees how much of the sigma it is.
    """
    points = {}
    for name, p in doc["points"].items():
        xyz = np.asarray(p["xyz_mm"], float)
        points[name] = {**p, "sigma_mm": with_scale(p["sigma_mm"], xyz, rel).tolist(),
                        "depth_sigma_mm": float(with_scale(p["depth_sigma_mm"], p["distance_mm"], rel)),
                        "sigma_scale_mm": (rel * np.abs(xyz)).tolist()}
    lengths = []
    for entry in doc["lengths"]:
        sigma = float(with_scale(entry["sigma_mm"], entry["length_mm"], rel))
        lengths.append({**entry, "sigma_mm": sigma, "sigma_percent": 100.0 * sigma / entry["length_mm"],
                        "sigma_scale_mm": rel * entry["length_mm"]})
    return {**doc, "points": points, "lengths": lengths, "square_sigma_relative": rel}
