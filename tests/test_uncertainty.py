"""The clustered (CR2) covariance and the held-out errors on linear models with known truth.

A linear model with clusters like a calibration's instants: global parameters shared by every
cluster (like the intrinsics) and one local parameter per cluster (like its board pose), given to
:mod:`dualcal.estimation.uncertainty` as a calibration gives it: normal equations kept cluster by cluster.
"""

import numpy as np
import pytest

from dualcal.estimation.normal_equations import Factorization, NormalEquations, PhotoNormals
from dualcal.estimation.uncertainty import held_out_squares, instant_leverage

G, M, P = 10, 30, 3          # clusters, rows per cluster, global parameters


def _design(rng):
    """Rows of each cluster: global regressors (M, P) and a local intercept column."""
    return [rng.normal(size=(M, P)) + rng.normal(size=P) for _ in range(G)]


def _fit(X_blocks, y_blocks):
    """Least squares of the whole problem: the estimate, ``N^-1``, ``s0^2`` and the factorization of
    its normal equations kept cluster by cluster (each cluster one photo)."""
    n = P + G
    J = np.zeros((G * M, n))
    for c, Xc in enumerate(X_blocks):
        J[c * M:(c + 1) * M, :P] = Xc
        J[c * M:(c + 1) * M, P + c] = 1.0
    y = np.concatenate(y_blocks)
    N_inv = np.linalg.inv(J.T @ J)
    beta = N_inv @ J.T @ y
    r = (J @ beta - y).reshape(G, M)                        # predicted - observed, as the adjustment's
    X = np.array(X_blocks)
    gg, gl, ll = X.transpose(0, 2, 1) @ X, X.sum(axis=1)[:, :, None], np.full((G, 1, 1), float(M))
    grad_g, grad_l = np.einsum("cmp,cm->cp", X, r), r.sum(axis=1)[:, None]
    photo = PhotoNormals(0, np.arange(G), np.arange(G), np.arange(P), np.array([0]), gg, gl, ll, grad_g, grad_l,
                         np.sum(r ** 2, axis=1), np.full(G, M))
    ne = NormalEquations(gg, gl, ll, grad_g, grad_l, np.ones((G, 1), bool), photos=[photo])
    return beta, N_inv, Factorization(ne, 0.0), float(np.sum(r ** 2)) / (len(y) - n)


def _draws(correlated: bool, n_draws: int, seed: int):
    rng = np.random.default_rng(seed)
    X_blocks = _design(rng)
    truth = np.array([1.0, -2.0, 0.5])
    est, var_formal, var_cr2 = [], [], []
    for _ in range(n_draws):
        y_blocks = []
        for Xc in X_blocks:
            e = rng.normal(0.0, 0.3, M)
            if correlated:                    # a per-cluster error along the regressors (like a bent board)
                e = e + Xc @ rng.normal(0.0, 0.2, P)
            y_blocks.append(Xc @ truth + rng.normal() + e)
        beta, N_inv, factorization, s0sq = _fit(X_blocks, y_blocks)
        shifts = instant_leverage(factorization).shifts
        est.append(beta[:P] - truth)
        var_formal.append(np.diag(N_inv)[:P] * s0sq)
        var_cr2.append(np.sum(shifts ** 2, axis=1))
    return np.array(est), np.array(var_formal), np.array(var_cr2)


def test_cr2_is_unbiased_for_independent_equal_errors():
    """E[CR2] = sigma^2 N^-1 exactly for a linear model with white noise: the mean over draws agrees."""
    err, var_formal, var_cr2 = _draws(correlated=False, n_draws=400, seed=1)
    ratio = var_cr2.mean(axis=0) / var_formal.mean(axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.08)
    z = err / np.sqrt(var_cr2)
    assert np.all((0.85 < z.std(axis=0)) & (z.std(axis=0) < 1.2)), z.std(axis=0)


def test_cr2_stays_honest_where_the_textbook_sigma_does_not():
    """Errors shared within a cluster: the formal z spread is far above 1, the clustered one is about 1."""
    err, var_formal, var_cr2 = _draws(correlated=True, n_draws=300, seed=2)
    z_cr2 = (err / np.sqrt(var_cr2)).std(axis=0)
    z_formal = (err / np.sqrt(var_formal)).std(axis=0)
    assert np.all((0.8 < z_cr2) & (z_cr2 < 1.25)), z_cr2
    assert np.all(z_formal > 1.8), z_formal


def _sandwich_of_rows(X_blocks, y_blocks, beta, N_inv, c):
    """Cluster ``c``'s CR2 shift of the globals from its rows: ``N^-1 J_c^T (I - H_cc)^-1/2 r_c``, the
    directions it determines alone (leverage 1) left out."""
    cols = np.r_[np.arange(P), P + c]
    Jc = np.column_stack([X_blocks[c], np.ones(M)])
    rc = Jc @ beta[cols] - y_blocks[c]
    lam, U = np.linalg.eigh(Jc @ N_inv[np.ix_(cols, cols)] @ Jc.T)
    f = np.where(1 - lam > 1e-9, 1 / np.sqrt(np.maximum(1 - lam, 1e-300)), 0.0)
    return (N_inv[:, cols] @ (Jc.T @ (U @ (f * (U.T @ rc)))))[:P]


def test_cr2_equals_the_sandwich_of_the_rows():
    """The shifts from the normal equations are those of the rows (:func:`_sandwich_of_rows`)."""
    rng = np.random.default_rng(5)
    X_blocks = _design(rng)
    y_blocks = [Xc @ np.array([1.0, -2.0, 0.5]) + rng.normal() + rng.normal(0, 0.3, M) for Xc in X_blocks]
    beta, N_inv, factorization, _ = _fit(X_blocks, y_blocks)
    shifts = instant_leverage(factorization).shifts
    for c in (0, 4):
        np.testing.assert_allclose(shifts[:, c], _sandwich_of_rows(X_blocks, y_blocks, beta, N_inv, c), rtol=1e-9,
                                   atol=1e-12)


def test_held_out_errors_are_those_of_the_fit_without_the_cluster():
    """Linear model: the globals without a cluster and the cluster's sum of squares as that fit predicts it,
    its own intercept fitted to it again, are exactly those of the fit of the others."""
    rng = np.random.default_rng(4)
    X_blocks = _design(rng)
    y_blocks = [Xc @ np.array([1.0, -2.0, 0.5]) + rng.normal() + rng.normal(0, 0.3, M) for Xc in X_blocks]
    beta, _, factorization, _ = _fit(X_blocks, y_blocks)
    held = instant_leverage(factorization).held_out
    (_, blocks, squares), = held_out_squares(factorization, held)
    for c in (0, 7):
        others = [i for i in range(G) if i != c]
        J = np.zeros(((G - 1) * M, P + G - 1))
        for k, i in enumerate(others):
            J[k * M:(k + 1) * M, :P] = X_blocks[i]
            J[k * M:(k + 1) * M, P + k] = 1.0
        beta_c = np.linalg.lstsq(J, np.concatenate([y_blocks[i] for i in others]), rcond=None)[0]
        pred = X_blocks[c] @ beta_c[:P]
        expected = pred - np.mean(pred - y_blocks[c]) - y_blocks[c]        # its intercept refitted
        np.testing.assert_allclose(held[c], beta_c[:P] - beta[:P], rtol=1e-9, atol=1e-12)
        assert squares[list(blocks).index(c)] == pytest.approx(np.sum(expected ** 2), rel=1e-9)


def test_a_parameter_one_cluster_alone_determines():
    """A global that one cluster alone sees: that cluster cannot be left out (NaN), and its CR2 shift leaves
    the direction it determines alone out, as the rows' sandwich does."""
    rng = np.random.default_rng(3)
    X_blocks = _design(rng)
    for Xc in X_blocks[1:]:
        Xc[:, 2] = 0.0                                 # the third regressor: in cluster 0 alone
    y_blocks = [Xc @ np.array([1.0, -2.0, 0.5]) + rng.normal() + rng.normal(0, 0.3, M) for Xc in X_blocks]
    beta, N_inv, factorization, _ = _fit(X_blocks, y_blocks)
    lev = instant_leverage(factorization)
    assert np.all(np.isnan(lev.held_out[0])) and np.all(np.isfinite(lev.held_out[1:]))
    for c in (0, 1):
        np.testing.assert_allclose(lev.shifts[:, c], _sandwich_of_rows(X_blocks, y_blocks, beta, N_inv, c),
                                   rtol=1e-6, atol=1e-9 * np.abs(lev.shifts).max())
