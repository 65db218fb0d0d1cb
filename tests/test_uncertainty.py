"""The clustered (CR2) covariance on linear models with known truth.

A linear model with clusters like a calibration's instants: global parameters shared by every
cluster (like the intrinsics) and one local parameter per cluster (like its board pose).
"""

import numpy as np
import pytest

from dualcal.estimation.uncertainty import (ClusterRows, cluster_scores, clustered_covariance, held_out_residuals,
                                            leverage_adjusted_residuals)

G, M, P = 10, 30, 3          # clusters, rows per cluster, global parameters


def _design(rng):
    """Rows of each cluster: global regressors (M, P) and a local intercept column."""
    return [rng.normal(size=(M, P)) + rng.normal(size=P) for _ in range(G)]


def _fit(X_blocks, y_blocks):
    """Least squares of the whole problem; returns the estimate, N^-1, clusters and s0^2."""
    n = P + G
    J = np.zeros((G * M, n))
    for c, Xc in enumerate(X_blocks):
        J[c * M:(c + 1) * M, :P] = Xc
        J[c * M:(c + 1) * M, P + c] = 1.0
    y = np.concatenate(y_blocks)
    N_inv = np.linalg.inv(J.T @ J)
    beta = N_inv @ J.T @ y
    r = J @ beta - y
    clusters = [ClusterRows(np.r_[np.arange(P), P + c], J[c * M:(c + 1) * M][:, np.r_[np.arange(P), P + c]],
                            r[c * M:(c + 1) * M]) for c in range(G)]
    return beta, N_inv, clusters, float(r @ r) / (len(y) - n)


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
        beta, N_inv, clusters, s0sq = _fit(X_blocks, y_blocks)
        est.append(beta[:P] - truth)
        var_formal.append(np.diag(N_inv)[:P] * s0sq)
        block = lambda cols: N_inv[np.ix_(cols, cols)]          # noqa: E731
        var_cr2.append(np.diag(clustered_covariance(cluster_scores(clusters, block), block, np.arange(P))))
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


def test_self_determined_directions_are_projected_out():
    """A cluster that alone determines a parameter (leverage 1 there) gives no score along it."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=5)
    J = np.column_stack([np.ones(5), x - x.mean()])
    M = np.diag([1 / 5.0, 0.01])                      # the intercept's leverage is 1
    r = rng.normal(size=5)
    r -= r.mean()                                      # optimum: no residual along the intercept
    adj = leverage_adjusted_residuals(J, r, M)
    assert np.all(np.isfinite(adj))
    assert abs(adj.sum()) < 1e-9
    with pytest.raises(ValueError):
        leverage_adjusted_residuals(J, r[:4], M)


def test_held_out_residuals_are_those_of_the_fit_without_the_cluster():
    """Linear model: ``(I - H)^-1 r`` is exactly the residual of a cluster predicted by the fit of the
    others, its own intercept fitted to it again; a cluster without which the others cannot
    determine a parameter has none."""
    rng = np.random.default_rng(4)
    X_blocks = _design(rng)
    y_blocks = [Xc @ np.array([1.0, -2.0, 0.5]) + rng.normal() + rng.normal(0, 0.3, M) for Xc in X_blocks]
    _, N_inv, clusters, _ = _fit(X_blocks, y_blocks)
    block = lambda cols: N_inv[np.ix_(cols, cols)]          # noqa: E731
    for c in (0, 7):
        others = [i for i in range(G) if i != c]
        J = np.zeros(((G - 1) * M, P + G - 1))
        for k, i in enumerate(others):
            J[k * M:(k + 1) * M, :P] = X_blocks[i]
            J[k * M:(k + 1) * M, P + k] = 1.0
        beta = np.linalg.lstsq(J, np.concatenate([y_blocks[i] for i in others]), rcond=None)[0]
        pred = X_blocks[c] @ beta[:P]
        expected = pred - np.mean(pred - y_blocks[c]) - y_blocks[c]        # its intercept refitted
        cl = clusters[c]
        np.testing.assert_allclose(held_out_residuals(cl.J, cl.r, block(cl.columns), 1), expected, atol=1e-10)
    J = np.column_stack([np.ones(5), np.arange(5.0)])       # the only cluster to see the slope
    r = rng.normal(size=5)
    assert held_out_residuals(J, r - r.mean(), np.linalg.inv(J.T @ J), 1) is None
