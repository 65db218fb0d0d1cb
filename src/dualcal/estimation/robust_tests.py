"""Values judged against a robust estimate of the others' scatter, so that two or three bad ones cannot hide each
other (masking): the statistics under ``rig_rigid`` and ``focus`` (:mod:`dualcal.estimation.checks`).

The checks have values ``x_i`` (one per instant or photo) that share one location and one unknown scale,
each with its own known relative spread ``r_i``::

    x_i = mu + tau r_i eps_i,    eps_i ~ N(0, 1)

(``rig_rigid``: the cube root of each instant's tie statistic, :func:`cube_root_spread`; ``focus``: each photo's
focal scale with its own sigma). Each value is judged against others (:func:`core_tests`): with their weighted
mean ``mu`` and spread ``tau`` (weights ``r^-2``), ``t_i = (x_i - mu) / (tau sqrt(r_i^2 + 1 / sum r_j^-2))`` is
Student's ``t`` with ``n - 1`` degrees of freedom for ``n`` others (the externally studentised residual; a share
``dof_share`` of them where the values scatter as a mixture, with longer tails than one normal). The textbook
test takes every other value, and fails where several are off: each bad one widens the others' spread and moves
their mean, so none stands out. Here the others are a **core** (:func:`robust_core`): the values each of which
passes its test against the rest of the core at the test's own rate, found from a start that no bad value can
move while they are fewer than half (the weighted median and the median absolute deviation of the values, which
may depend on the core: an instant's statistic against the rig's relations the core tells). Every value outside
the core fails its test and every value inside passes, so where nothing is wrong the core is every value (but
at the tests' own rate) and the tests are the textbook ones, with their false-alarm rate.

A lens split (two lenses merged into one camera) defeats any test of one value against the others: half the
photos are off, in two groups. :func:`split_test` judges the best split of the sorted values into two groups
against the same values' splits by chance.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .distributions import f_quantile, f_sf

__all__ = ["CoreTest", "core_tests", "cube_root_spread", "robust_core", "split_test", "t_limit"]

#: MAD of a normal over its standard deviation.
_MAD_NORMAL = 0.6744897501960817
_MAX_ROUNDS = 20


def cube_root_spread(dofs) -> np.ndarray:
    """The relative spread ``r`` (k,) of the cube roots of chi-square statistics of ``dofs`` (k,) degrees of freedom
    each over its degrees of freedom (Wilson and Hilferty, 1931: ``(chi^2_k / k)^(1/3)`` is nearly normal, of
    variance ``2 / (9 k)``; with fewer effective degrees of freedom, as noise correlated within a photo leaves, all
    spreads grow by one factor, which ``tau`` takes)."""
    return np.sqrt(2.0 / (9.0 * np.asarray(dofs, float)))


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cum, 0.5 * cum[-1])])


@functools.lru_cache(maxsize=256)
def t_limit(dof: float, rate: float, two_sided: bool) -> float:
    """The ``t`` that Student's t of ``dof`` degrees of freedom exceeds (in absolute value, ``two_sided``) with
    probability ``rate`` (a quantile costs a millisecond, and the tests of one core share a few)."""
    return math.sqrt(f_quantile(1, dof, 1.0 - (rate if two_sided else 2.0 * rate)))


@dataclass(frozen=True)
class CoreTest:
    """One value judged against others: ``t`` its externally studentised residual, ``dof`` Student's degrees of
    freedom, ``p`` the p-value (one-sided, upward, or two-sided), ``mu`` the others' location and ``spread`` the
    standard deviation of the value's difference from it (``t = (x - mu) / spread``)."""

    t: float
    dof: float
    p: float
    mu: float
    spread: float

    def limit(self, rate: float, two_sided: bool) -> float:
        """The ``t`` a value of this test reaches at p-value ``rate``."""
        return t_limit(self.dof, rate, two_sided)


def _studentised(x: np.ndarray, r: np.ndarray, core: np.ndarray, dof_share: float):
    """Every value's ``(t, dof, mu, spread)`` against the core without it, as arrays (NaN where fewer than three
    others remain or the value is not finite)."""
    w = np.where(core, 1.0 / np.square(r), 0.0)
    xs = np.where(core, x, 0.0)
    own = core.astype(float)
    n = core.sum() - own                               # the others, each value's own taken away
    W = w.sum() - w
    S1 = (w * xs).sum() - w * xs
    S2 = (w * xs * xs).sum() - w * xs * xs
    with np.errstate(divide="ignore", invalid="ignore"):
        mu = S1 / W
        tau = np.sqrt(np.maximum(S2 - S1 * mu, 0.0) / (n - 1))
        spread = np.maximum(tau, 1e-300) * np.sqrt(r ** 2 + 1.0 / W)
        t = (x - mu) / spread
    bad = (n < 3) | ~np.isfinite(x)
    return np.where(bad, np.nan, t), dof_share * (n - 1), mu, spread


def core_tests(x: np.ndarray, r: np.ndarray, core: np.ndarray, two_sided: bool,
               dof_share: float = 1.0) -> list[CoreTest | None]:
    """Every value ``x_i`` against the core without it (module docstring), by Student's t of ``dof_share`` of its
    degrees of freedom; None where fewer than three others remain or the value is not finite. ``two_sided`` False
    judges only values above the others (a worse fit)."""
    x, r, core = np.asarray(x, float), np.asarray(r, float), np.asarray(core, bool)
    t, dof, mu, spread = _studentised(x, r, core, dof_share)
    out = []
    for i in range(len(x)):
        if np.isnan(t[i]):
            out.append(None)
            continue
        tail = f_sf(t[i] * t[i], 1, dof[i])               # P(|T| > |t|) for Student's t
        p = tail if two_sided else (0.5 * tail if t[i] > 0 else 1.0 - 0.5 * tail)
        out.append(CoreTest(float(t[i]), float(dof[i]), float(p), float(mu[i]), float(spread[i])))
    return out


def robust_core(values, r: np.ndarray, rate: float, dof_share: float = 1.0,
                start: np.ndarray | None = None) -> np.ndarray:
    """The core (n,) bool: the values each of which passes its test against the rest of the core at ``rate``
    (:func:`core_tests`, two-sided, with ``dof_share``; module docstring): a value far below the others leaves
    it too, so that it does not widen their spread, though only a value above them may fail a one-sided test.

    Parameters
    ----------
    values : (n,) array, or a callable ``core -> (n,) array``: values that depend on the core (each instant's
        statistic against the rig's relations fitted to the core) are computed again for every core tried.
    r : (n,) the values' relative spreads.
    rate, dof_share : the tests'.
    start : (n,) bool or None: the core whose values the start takes (None: every value). The start keeps the
        values within the tests' limit of the values' weighted median, in units of their median absolute
        deviation, which bad values cannot move while they are fewer than half.

    Returns
    -------
    (n,) bool: the last core, its values' tests against it all passing (or, after 20 rounds or before a core of
    fewer than four, the last one tried). A value that is not finite is never in it.
    """
    compute = values if callable(values) else (lambda core: values)
    r = np.asarray(r, float)
    n = len(r)
    if n < 4:                                        # too few to judge any against the others
        return np.ones(n, bool)
    x = np.asarray(compute(np.ones(n, bool) if start is None else np.asarray(start, bool)), float)
    mu = _weighted_median(x, 1.0 / r ** 2)
    tau = float(np.median(np.abs(x - mu) / r)) / _MAD_NORMAL
    if not 0 < tau < np.inf:
        return np.isfinite(x)
    core = np.abs(x - mu) <= t_limit(max(dof_share * (n - 2), 1.0), rate, True) * tau * r
    for _ in range(_MAX_ROUNDS):
        x = np.asarray(compute(core), float)
        t, dof, _, _ = _studentised(x, r, core, dof_share)
        limits = np.array([t_limit(float(d), rate, True) if d > 0 else np.inf for d in dof])
        new = np.abs(t) <= limits                       # NaN (cannot be judged) is not in it
        if new.sum() < 4 or (new == core).all():
            break
        core = new
    return core


#: The least number of values in either group of :func:`split_test`.
MIN_SPLIT_GROUP = 3
#: Draws of the split statistic under the null hypothesis (fixed seed, so that a calibration is repeatable).
SPLIT_DRAWS = 4000


def _split_f(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every row of ``x`` (m, n) sorted (``order`` (m, n)), and the ``F`` of each of its splits into the lowest
    ``j + 1`` and the rest, ``j`` from ``MIN_SPLIT_GROUP - 1`` (m, n + 1 - 2 MIN_SPLIT_GROUP), weights ``w`` (n,)
    (see :func:`split_test`)."""
    order = np.argsort(x, axis=1)
    xs, ws = np.take_along_axis(x, order, axis=1), w[order]
    n = x.shape[1]
    cw, cx, cxx = np.cumsum(ws, axis=1), np.cumsum(ws * xs, axis=1), np.cumsum(ws * xs * xs, axis=1)
    j = np.arange(MIN_SPLIT_GROUP - 1, n - MIN_SPLIT_GROUP)
    wa, xa, xxa = cw[:, j], cx[:, j], cxx[:, j]
    wb, xb, xxb = cw[:, -1:] - wa, cx[:, -1:] - xa, cxx[:, -1:] - xxa
    within = (xxa - xa * xa / wa) + (xxb - xb * xb / wb)
    between = (xa / wa - xb / wb) ** 2 * wa * wb / (wa + wb)
    return order, between / np.maximum(within, 1e-300) * (n - 2)


def split_test(x: np.ndarray, r: np.ndarray, rate: float, dof_share: float = 1.0,
               least_change: float = 0.0) -> dict | None:
    """Whether values ``x`` (n,) of relative spreads ``r`` (n,) fall into two groups of different locations.

    For every split of the sorted values into a lower and an upper group of at least :data:`MIN_SPLIT_GROUP`,
    ``F = between / (within / (n - 2))`` (weighted by ``r^-2``: the squared difference of the groups' means over
    its variance against the groups' own scatter); the statistic is the largest. Sorting makes it far larger
    than ``F(1, n - 2)`` on values of one location, so its distribution is drawn: :data:`SPLIT_DRAWS` sets of
    values ``r_i eps_i`` (fixed seed; the unknown scale cancels; ``eps`` Student's t of ``dof_share (n - 2)``
    degrees of freedom, normal for ``dof_share`` 1, as :func:`core_tests` takes them), the limit its
    ``1 - rate`` quantile (for a ``rate`` below ``1 / SPLIT_DRAWS`` the draws' largest, a limit a little low).

    Returns ``{"f", "limit", "p", "change", "lower": (n,) bool, "failed"}``: the lower group of the best split,
    ``change`` the upper group's weighted mean less the lower's, ``p`` the share of draws at or beyond ``f`` (at
    least ``1 / SPLIT_DRAWS``); ``failed`` where ``f`` exceeds its limit and ``change`` exceeds ``least_change``
    (a split too small to matter is not drawn for: ``limit`` and ``p`` None). None for fewer than
    ``2 MIN_SPLIT_GROUP`` values.
    """
    x, r = np.asarray(x, float), np.asarray(r, float)
    n = len(x)
    if n < 2 * MIN_SPLIT_GROUP:
        return None
    w = 1.0 / r ** 2
    order, f_splits = _split_f(x[None, :], w)
    best = int(np.argmax(f_splits[0]))
    lower = np.zeros(n, bool)
    lower[order[0, :best + MIN_SPLIT_GROUP]] = True
    change = float(np.average(x[~lower], weights=w[~lower]) - np.average(x[lower], weights=w[lower]))
    out = {"f": float(f_splits[0, best]), "limit": None, "p": None, "change": change, "lower": lower,
           "failed": False}
    if change <= least_change:
        return out
    rng = np.random.default_rng(0)
    eps = rng.standard_normal((SPLIT_DRAWS, n)) if dof_share >= 1 else rng.standard_t(dof_share * (n - 2),
                                                                                       (SPLIT_DRAWS, n))
    null = np.sort(np.max(_split_f(eps * r, w)[1], axis=1))
    out["limit"] = float(null[min(int(math.floor((1.0 - rate) * SPLIT_DRAWS)), SPLIT_DRAWS - 1)])
    out["p"] = max(float(np.mean(null >= out["f"])), 1.0 / SPLIT_DRAWS)
    out["failed"] = out["f"] > out["limit"]
    return out
