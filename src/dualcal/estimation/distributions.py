"""The F and chi-square distributions' quantiles, for the tests a calibration runs (Hotelling's T^2)
and the consistency of a measured point's rays (:mod:`dualcal.estimation.measurement`).

The board-shape test (:func:`dualcal.estimation.board_shape.board_shape_test`) and the loop check
(:mod:`dualcal.estimation.loop_closure`) compare a statistic with a quantile of ``F(d1, d2)``. scipy has it
(``scipy.special.fdtri``), but importing any of scipy costs about 0.3 s, longer than OpenCV takes
to calibrate a 13-instant rig, and nothing else on the calibration's path needs scipy: so the
quantile is computed here, from the regularised incomplete beta function
``I_x(a, b)`` (``P(F <= f) = I_x(d1/2, d2/2)`` with ``x = d1 f / (d1 f + d2)``), by its continued
fraction (DLMF 8.17.22, evaluated by the modified Lentz method), inverted by Newton's steps in ``x``;
the chi-square quantile from the regularised incomplete gamma function likewise (DLMF 8.7.1 and
8.9.2). The tests check both against scipy.
"""

from __future__ import annotations

import math

_TINY = 1e-300
_EPS = 1e-15


def _continued_fraction(terms) -> float:
    """``a1 / (b1 + a2 / (b2 + ...))`` for the pairs ``(a_n, b_n)`` of ``terms``, by the modified Lentz
    method, to a relative ``_EPS``."""
    f = c = _TINY
    d = 0.0
    for a, b in terms:
        d = b + a * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = b + a / c
        c = c if abs(c) > _TINY else _TINY
        f *= c * d
        if abs(c * d - 1.0) < _EPS:
            break
    return f


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of ``I_x(a, b)`` (DLMF 8.17.22), for ``x < (a + 1) / (a + b + 2)``:
    ``1 / (1 + d_1 / (1 + d_2 / (1 + ...)))``."""
    def terms():
        yield 1.0, 1.0
        yield -(a + b) * x / (a + 1.0), 1.0                                                # d_1
        for m in range(1, 1000):
            yield m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)), 1.0                   # d_2m
            yield -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)), 1.0        # d_2m+1
    return _continued_fraction(terms())


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
    """The ``q`` quantile of the F distribution with ``(d1, d2)`` degrees of freedom (``scipy.special.fdtri``):
    ``I_x(d1/2, d2/2) = q`` with ``x = d1 f / (d1 f + d2)``, or for an upper quantile (``q > 1/2``, the tests'
    limits) its tail ``I_y(d2/2, d1/2) = 1 - q`` with ``y = 1 - x``, so that a quantile far out is solved where
    its probability is small and held to its relative precision."""
    if not (d1 > 0 and d2 > 0 and 0.0 < q < 1.0):
        raise ValueError(f"F quantile: need d1, d2 > 0 and 0 < q < 1 (got {d1}, {d2}, {q})")
    if q <= 0.5:
        x = _beta_quantile(0.5 * d1, 0.5 * d2, q)
        return d2 * x / (d1 * (1.0 - x))
    y = _beta_quantile(0.5 * d2, 0.5 * d1, 1.0 - q)
    return d2 * (1.0 - y) / (d1 * y)


def _beta_quantile(a: float, b: float, p: float) -> float:
    """The ``x`` where ``I_x(a, b) = p``, by Newton's steps in a bracket (:func:`_bisect`) from where the
    function's leading term ``x^a / (a B(a, b))`` reaches ``p`` (near for a small ``p``)."""
    log_beta = math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)

    def density(x):                                     # d I_x(a, b) / dx
        return math.exp((a - 1.0) * math.log(x) + (b - 1.0) * math.log1p(-x) - log_beta) if 0.0 < x < 1.0 else 0.0
    start = math.exp((math.log(p * a) + log_beta) / a)
    return _bisect(lambda x: regularized_beta(a, b, x), p, 0.0, 1.0, 1e-13, density, start if start < 1.0 else None)


def _bisect(cdf, q: float, lo: float, hi: float, rtol: float, density=None, start: float | None = None) -> float:
    """The ``x`` in ``[lo, hi]`` where the increasing ``cdf`` reaches ``q``, to ``rtol``: by bisection from the
    middle, or with the ``density`` (the cdf's derivative) by Newton's steps from ``start`` (default: the middle)
    kept inside the shrinking bracket (a step that would leave it bisects instead), a few evaluations where
    bisection needs fifty."""
    x = 0.5 * (lo + hi) if start is None else start
    for _ in range(200):
        c = cdf(x)
        lo, hi = (x, hi) if c < q else (lo, x)
        slope = density(x) if density is not None else 0.0
        newton = x - (c - q) / slope if slope > 0.0 else None
        if newton is not None and lo <= newton <= hi:
            if abs(newton - x) <= rtol * abs(newton):
                return newton
            x = newton
        else:
            x = 0.5 * (lo + hi)
        if hi - lo <= rtol * hi:
            break
    return 0.5 * (lo + hi)


def regularized_gamma(a: float, x: float) -> float:
    """``P(a, x)``, the regularised lower incomplete gamma function, for ``a > 0``, ``x >= 0``: its series
    (DLMF 8.7.1) below ``x = a + 1``, else one minus the continued fraction of ``Q(a, x)`` (DLMF 8.9.2,
    modified Lentz)."""
    if x <= 0.0:
        return 0.0
    log_front = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        for n in range(1, 10000):
            term *= x / (a + n)
            total += term
            if abs(term) < _EPS * abs(total):
                break
        return math.exp(log_front) * total

    def terms():                    # Q(a, x) / front = 1 / (x + 1 - a - 1 (1 - a) / (x + 3 - a - ...))
        yield 1.0, x + 1.0 - a
        for n in range(1, 10000):
            yield -n * (n - a), x + 1.0 - a + 2.0 * n
    return 1.0 - math.exp(log_front) * _continued_fraction(terms())


def chi2_quantile(dof: float, q: float) -> float:
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom
    (``scipy.special.chdtri(dof, 1 - q)``): ``P(dof / 2, x / 2) = q`` solved by bisection in ``x``."""
    if not (dof > 0 and 0.0 < q < 1.0):
        raise ValueError(f"chi-square quantile: need dof > 0 and 0 < q < 1 (got {dof}, {q})")
    a = 0.5 * dof
    lo, hi = 0.0, max(1.0, dof)
    while regularized_gamma(a, 0.5 * hi) < q:     # P increases in x: bracket the quantile
        lo, hi = hi, 2.0 * hi
    return _bisect(lambda x: regularized_gamma(a, 0.5 * x), q, lo, hi, 1e-15)


def f_sf(f: float, d1: float, d2: float) -> float:
    """``P(F > f)`` for the F distribution with ``(d1, d2)`` degrees of freedom (``scipy.special.fdtrc``):
    ``I_y(d2/2, d1/2)`` with ``y = d2 / (d2 + d1 f)``, the p-value of an observed ``f`` (1 for ``f <= 0``,
    0 for ``f = inf``)."""
    if not (d1 > 0 and d2 > 0):
        raise ValueError(f"F tail: need d1, d2 > 0 (got {d1}, {d2})")
    if f <= 0.0:
        return 1.0
    if math.isinf(f):
        return 0.0
    return regularized_beta(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f))


def sidak(rate: float, tests: int) -> float:
    """The rate of each of ``tests`` independent tests that makes their family's false-alarm rate ``rate``
    (Sidak: ``1 - (1 - rate)^(1/tests)``, a little above Bonferroni's ``rate / tests``). Whatever the tests'
    dependence, the family's rate is at most ``tests`` times this (Boole), ``-log(1 - rate)``: ``rate`` to within
    ``rate^2 / 2``."""
    if not (0.0 < rate < 1.0 and tests >= 1):
        raise ValueError(f"Sidak: need 0 < rate < 1 and tests >= 1 (got {rate}, {tests})")
    return -math.expm1(math.log1p(-rate) / tests)
