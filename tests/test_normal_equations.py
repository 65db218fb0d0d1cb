"""Block normal equations (dualcal.estimation.normal_equations) against the same algebra on dense matrices."""

import numpy as np
import pytest

from dualcal.estimation.normal_equations import NormalEquations

G, V, L = 5, 4, 3


@pytest.fixture
def problem():
    """A random arrow-structured J (rows of instant v touch the globals and v's locals); instant 2
    has only 2 of its 3 local slots. Returns the pieces, the dense J, r and the used mask."""
    rng = np.random.default_rng(1)
    used = np.ones((V, L), bool)
    used[2, 1] = False
    rows = 12
    J = np.zeros((V * rows, G + V * L))
    for v in range(V):
        J[v * rows:(v + 1) * rows, :G] = rng.normal(size=(rows, G))
        J[v * rows:(v + 1) * rows, G + v * L:G + (v + 1) * L] = rng.normal(size=(rows, L)) * used[v]
    r = rng.normal(size=V * rows)
    ne = NormalEquations.zeros(G, used)
    for v in range(V):
        Jg, Jl, rv = J[v * rows:(v + 1) * rows, :G], J[v * rows:(v + 1) * rows, G + v * L:G + (v + 1) * L], \
            r[v * rows:(v + 1) * rows]
        ne.gg[v], ne.gl[v], ne.ll[v] = Jg.T @ Jg, Jg.T @ Jl, Jl.T @ Jl
        ne.grad_g[v], ne.grad_l[v] = Jg.T @ rv, Jl.T @ rv
    keep = np.concatenate([np.ones(G, bool), used.ravel()])
    return ne, J, r, keep


def test_damped_step_solves_the_dense_system(problem):
    ne, J, r, keep = problem
    N, g = J.T @ J, J.T @ r
    for mu in (0.0, 1e-3, 10.0):
        A = (N + mu * np.diag(np.diag(N)))[np.ix_(keep, keep)]
        h = ne.factor(mu).step()
        np.testing.assert_allclose(h[keep], np.linalg.solve(A, -g[keep]), rtol=1e-10, atol=1e-12)
        assert np.all(h[~keep] == 0)
        assert ne.metric(h) == pytest.approx(h @ N @ h, rel=1e-12)
    np.testing.assert_allclose(ne.gradient(), g, atol=1e-12)
    np.testing.assert_allclose(ne.diagonal()[keep], np.diag(N)[keep])


def test_inverse_blocks_are_those_of_the_dense_inverse(problem):
    ne, J, r, keep = problem
    cols = np.flatnonzero(keep)
    Q = np.linalg.inv((J.T @ J)[np.ix_(keep, keep)])
    pick = np.array([0, 3, G, G + 2, G + 2 * L, G + 3 * L + 1])       # globals, locals of 3 instants
    where = np.searchsorted(cols, pick)
    np.testing.assert_allclose(ne.factor().inverse_block(pick), Q[np.ix_(where, where)], rtol=1e-9, atol=1e-12)
    # in a batch, a row of columns per photo: the globals and one instant's locals (any order)
    rows = np.array([[0, 3, G, G + 2], [G + 3 * L + 2, 1, G + 3 * L, 4], [2, 0, G + L + 1, G + L]])
    batch = ne.factor().inverse_blocks(rows)
    for row, block in zip(rows, batch):
        where = np.searchsorted(cols, row)
        np.testing.assert_allclose(block, Q[np.ix_(where, where)], rtol=1e-9, atol=1e-12)


def test_second_order_terms_enter_the_steps_only_when_asked(problem):
    ne, J, r, keep = problem
    rng = np.random.default_rng(2)
    C_ll = np.zeros((V, L, L))
    C_gl = np.zeros((V, G, L))
    for v in range(V):
        a = rng.normal(size=(L, L)) * 0.1
        C_ll[v] = (a + a.T) * np.outer(ne.local_used[v], ne.local_used[v])
        C_gl[v] = rng.normal(size=(G, L)) * 0.1 * ne.local_used[v]
    ne.curvature_ll, ne.curvature_gl = C_ll, C_gl
    H = J.T @ J
    for v in range(V):
        s = slice(G + v * L, G + (v + 1) * L)
        H[s, s] += C_ll[v]
        H[:G, s] += C_gl[v]
        H[s, :G] += C_gl[v].T
    g = J.T @ r
    h = ne.factor(0.0, second_order=True).step()
    np.testing.assert_allclose(h[keep], np.linalg.solve(H[np.ix_(keep, keep)], -g[keep]), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ne.factor().step()[keep], np.linalg.solve((J.T @ J)[np.ix_(keep, keep)], -g[keep]),
                               rtol=1e-9, atol=1e-12)
