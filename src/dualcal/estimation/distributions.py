"""The F distribution's quantile, for the tests a calibration runs (Hotelling's T^2).

The board-shape test (:func:`dualcal.estimation.calibrate.board_shape_test`) and the loop check
(:mod:`dualcal.estimation.loop_closure`) compare a statistic with a quantile of ``F(d1, d2)``. scipy has it
(``scipy.special.fdtri``), but importing any of scipy costs about 0.3 s, longer than OpenCV takes
to calibrate a 13-instant rig, and nothing else on the calibration's path needs scipy: so the
quantile is computed here, from the regularised incomplete beta function
``I_x(a, b)`` (``P(F <= f) = I_x(d1/2, d2/2)`` with ``x = d1 f / (d1 f + d2)``), by its continued
fraction (DLMF 8.17.22, evaluated by the modified Lentz method), inverted by bisection in ``x``.
The tests check it against scipy to 1e-10.
"""

from __future__ import annotations

import math

_TINY = 1e-300
_EPS = 1e-15


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of ``I_x(a, b)`` (DLMF 8.17.22), for ``x < (a + 1) / (a + b + 2)``."""
    f = c = 1.0
    d = 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    f = d
    for m in range(1, 1000):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),                    # d_2m
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):         # d_2m+1
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + num / c
            c = c if abs(c) > _TINY else _TINY
            f *= c * d
        if abs(c * d - 1.0) < _EPS:
            break
    return f


def regularized_beta(a: float, b: float, x: float) -> float:
    """``I_x(a, b)``, the regularised incomplete beta function, for ``a, b > 0`` and ``0 <= x <= 1``."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (a * math.log(x) + b * math.log1p(-x) + math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_fraction(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_fraction(b, a, 1.0 - x) / b


def f_quantile(d1: float, d2: float, q: float) -> float:
    """The ``q`` quantile of the F distribution with ``(d1, d2)`` degrees of freedom (``scipy.special.fdtri``)."""
    if not (d1 > 0 and d2 > 0 and 0.0 < q < 1.0):
        raise ValueError(f"F quantile: need d1, d2 > 0 and 0 < q < 1 (got {d1}, {d2}, {q})")
    a, b = 0.5 * d1, 0.5 * d2
    lo, hi = 0.0, 1.0
    for _ in range(200):                 # bisection in x = d1 f / (d1 f + d2): I_x is increasing in x
        mid = 0.5 * (lo + hi)
        if regularized_beta(a, b, mid) < q:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-16 * hi:
            break
    x = 0.5 * (lo + hi)
    return d2 * x / (d1 * (1.0 - x))
