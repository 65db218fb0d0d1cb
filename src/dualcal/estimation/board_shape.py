"""The board's shape: estimated where the photos show it beyond their noise (sag, bend, twist).

A printed board is rarely flat to a tenth of a millimetre; :data:`dualcal.geometry.board.SHAPE_TERMS` give its
out-of-plane shape three coefficients, which the adjustment estimates with the rest
(:mod:`dualcal.estimation.adjust`, ``board_shape``). :func:`board_shape_test` says whether they differ from
zero beyond the photos' noise, and :func:`with_board_shape` is the calibration's stage
(:mod:`dualcal.estimation.calibrate`) that keeps the shape where they do (``board_shape="auto"``), always
(``"fit"``) or never (``"flat"``).
"""

from __future__ import annotations

import numpy as np

from .adjust import Solution
from .distributions import f_quantile
from .fitting import Setup
from ..geometry.board import SHAPE_TERMS

BOARD_SHAPES = ("auto", "flat", "fit")
#: The board's shape is kept where its coefficients differ from zero at this significance level.
SHAPE_SIGNIFICANCE = 0.01
#: The shape is tested first at its one-step estimate from the flat board's solution; where that test's
#: ``T^2`` exceeds this share of its limit, the shape is adjusted in full and the test made there, so
#: that a decision near the limit is the full adjustment's.
SHAPE_FULL_TEST = 0.5


def with_board_shape(setup: Setup, flat: Solution, board_shape: str) -> tuple[Solution, dict | None]:
    """``flat`` (a solution with a flat board) with the board's shape estimated where ``board_shape`` says so,
    and the shape's test (:func:`board_shape_test`; None for ``"flat"``). ``"auto"`` tests the one-step estimate
    first and adjusts the shape in full only near the test's limit (:data:`SHAPE_FULL_TEST`); the shape is
    kept where the test finds it significant (always with ``"fit"``)."""
    shape_test = None
    if board_shape == "auto":            # the one-step estimate first: the full adjustment only near the limit
        shape_test = board_shape_test(setup.linearised(flat, board_shape=True), one_step=True)
        if shape_test["limit"] is not None and shape_test["t2"] > SHAPE_FULL_TEST * shape_test["limit"]:
            shape_test = None
    if board_shape != "flat" and shape_test is None:
        shaped = setup.solve(flat.problem.blocks, flat, board_shape=True)
        shape_test = board_shape_test(shaped)
        if board_shape == "fit" or shape_test["significant"]:
            return shaped, shape_test
    return flat, shape_test


def board_shape_test(sol: Solution, one_step: bool = False) -> dict:
    """Whether the board's shape estimated in ``sol`` differs from flat beyond the photos' noise.

    Hotelling's test of the three shape coefficients against the covariance clustered by instant
    (so that noise correlated within photos does not pass for a bent board): with ``G`` instants,
    ``T2 = w^T Cov^-1 w`` is compared with ``p (G-1) / (G-p) F(p, G-p)`` at
    :data:`SHAPE_SIGNIFICANCE`. Returns ``{"t2", "limit", "significant", "coefficients_mm",
    "sigma_mm", "estimate"}`` (``estimate``: ``"adjusted"``, or ``"one-step"`` where ``sol`` is a flat board's
    solution linearised with the shape free); with too few instants to judge (``G <= p + 1``) ``limit`` is
    None and the shape is not significant. ``w`` and its covariance are those of the linearised minimum (``sol`` moved by its
    Gauss-Newton step): of the adjusted shape, or from a flat board's solution linearised with the shape
    free (:func:`dualcal.estimation.adjust.linearised_at`), the one-step estimate (Wald's test at the
    one-step estimator, which differs from the adjusted one's by terms of second order in the shape).
    """
    cols = sol.problem.layout.board_shape
    w = sol.state.board_shape_mm + sol.factorization.step()[cols]                # at the linearised minimum
    cov = sol.covariance(cols, "clustered")
    p, G = len(cols), len(sol.problem.views)
    doc = {"coefficients_mm": dict(zip(SHAPE_TERMS, map(float, w))),
           "sigma_mm": dict(zip(SHAPE_TERMS, map(float, np.sqrt(np.maximum(np.diag(cov), 0.0))))),
           "estimate": "one-step" if one_step else "adjusted"}
    if G <= p + 1:
        return {**doc, "t2": None, "limit": None, "significant": False}
    t2 = float(w @ np.linalg.lstsq(cov, w, rcond=None)[0])
    limit = float(p * (G - 1) / (G - p) * f_quantile(p, G - p, 1.0 - SHAPE_SIGNIFICANCE))
    return {**doc, "t2": t2, "limit": limit, "significant": bool(t2 > limit)}
