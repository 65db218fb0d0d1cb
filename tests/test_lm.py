"""Levenberg-Marquardt (dualcal.estimation.lm) on a small separable problem with a known optimum.

The model: instant ``v`` measures ``y_vi = a_v exp(-b t_i) + c`` plus noise; ``b`` and ``c`` are
global, each ``a_v`` local. scipy's least_squares gives the reference optimum.
"""

import numpy as np
import pytest
from scipy.optimize import least_squares

from dualcal.estimation.lm import LMOptions, levenberg_marquardt
from dualcal.estimation.normal_equations import NormalEquations

T = np.linspace(0.0, 4.0, 15)
V = 5


def _data(seed=0, noise=0.01):
    rng = np.random.default_rng(seed)
    a = rng.uniform(1.0, 3.0, V)
    return a[:, None] * np.exp(-0.7 * T) + 0.2 + rng.normal(0, noise, (V, len(T)))


def _residuals(x, y):
    b, c, a = x[0], x[1], x[2:]
    return a[:, None] * np.exp(-b * T) + c - y


def _linearise(x, y):
    b, a = x[0], x[2:]
    r = _residuals(x, y)
    e = np.exp(-b * T)
    ne = NormalEquations.zeros(2, np.ones((V, 1), bool))
    for v in range(V):
        Jg = np.column_stack([-a[v] * T * e, np.ones_like(T)])
        Jl = e[:, None]
        ne.gg[v], ne.gl[v], ne.ll[v] = Jg.T @ Jg, Jg.T @ Jl, Jl.T @ Jl
        ne.grad_g[v], ne.grad_l[v] = Jg.T @ r[v], Jl.T @ r[v]
    return float(np.sum(r * r)), ne


def _solve(x0, y, **options):
    return levenberg_marquardt(x0, lambda x: _linearise(x, y), lambda x: float(np.sum(_residuals(x, y) ** 2)),
                               lambda x, h: x + h, y.size - len(x0), LMOptions(**options))


def test_finds_the_least_squares_optimum_and_says_it_converged():
    y = _data()
    x0 = np.concatenate([[2.0, 0.0], np.ones(V)])
    res = _solve(x0, y)
    best = least_squares(lambda x: _residuals(x, y).ravel(), x0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    assert res.converged and res.distance_sigma < 1e-3
    F, ne = _linearise(best, y)                               # it stops within 1e-3 sigma of the minimum
    d = res.x - best
    assert np.sqrt(ne.metric(d) / (F / (y.size - len(x0)))) < 1e-3 * (1 + 1e-6)
    assert res.iterations < 20


def test_an_iteration_limit_is_reported_as_not_converged():
    y = _data()
    res = _solve(np.concatenate([[2.0, 0.0], np.ones(V)]), y, max_iter=2)
    assert not res.converged and res.iterations == 2
    assert res.termination.startswith("iteration limit 2 reached; the estimate is still")


def test_a_stopping_test_is_believed_only_when_the_undamped_step_agrees():
    """A step tolerance so loose that every step meets it does not end the run early: the
    undamped Gauss-Newton check sends the solver on, to the same optimum."""
    y = _data()
    x0 = np.concatenate([[2.0, 0.0], np.ones(V)])
    res, strict = _solve(x0, y, xtol=1e6), _solve(x0, y)
    assert res.converged and res.iterations > 1
    np.testing.assert_allclose(res.x, strict.x, rtol=1e-4, atol=1e-6)   # both within 1e-3 sigma of the minimum


def test_inadmissible_trials_are_rejected():
    """A cost of inf (in the adjustment: a corner behind its camera) rejects the trial; the
    solver goes on with more damping and still converges."""
    y = _data()
    x0 = np.concatenate([[2.0, 0.0], np.ones(V)])
    calls = {"inf": 0}

    def cost(x):
        if calls["inf"] < 3:                           # the first three trials are refused
            calls["inf"] += 1
            return np.inf
        return float(np.sum(_residuals(x, y) ** 2))

    res = levenberg_marquardt(x0, lambda x: _linearise(x, y), cost, lambda x, h: x + h, y.size - len(x0))
    assert calls["inf"] == 3 and res.converged
    assert res.x[0] == pytest.approx(0.7, abs=0.01)


def test_exact_data_converge_at_the_rounding_level():
    y = _data(noise=0.0)
    res = _solve(np.concatenate([[2.0, 0.0], np.ones(V)]), y)
    assert res.converged and res.cost < 1e-18      # residuals of 1e-10: below the 1e-6 px floor's 1e-3
    assert res.x[0] == pytest.approx(0.7, abs=1e-10)
