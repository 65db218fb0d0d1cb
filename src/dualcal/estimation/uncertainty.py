"""Uncertainty that holds on real photos: the covariance clustered by instant.

The adjustment's textbook covariance ``s0^2 N^-1`` (``sigma_formal``) assumes that every corner's
error is independent of every other's. On real photos it is not: a board that is not flat or not
printed true, a lens term the model lacks, blur or a refocus move all corners of one photo
together, so the photos disagree with each other more than white corner noise allows, and the
textbook sigmas are several times too small.

``sigma`` therefore comes from how the instants disagree with each other: the cluster-robust
("sandwich") covariance with the photos of one instant as a cluster,

    Cov = N^-1 (sum_c  J_c^T  W_c r_c r_c^T W_c  J_c) N^-1,

with ``J_c``, ``r_c`` the Jacobian rows and residuals of cluster ``c`` and ``N = J^T J``. With
8-30 instants the plain sandwich (``W_c = I``) is too small, because every cluster's residuals
were fitted by the same parameters and so are smaller than its errors; the bias-reduced
linearisation of Bell & McCaffrey (2002, "CR2") undoes that with ``W_c = (I - H_cc)^-1/2``, where
``H_cc = J_c N^-1 J_c^T`` is the cluster's block of the hat matrix. For a linear model with
independent, equal errors CR2 is exactly unbiased, so on white corner noise ``sigma`` and
``sigma_formal`` agree; with errors correlated within photos, ``sigma`` stays honest where
``sigma_formal`` does not (tests/test_uncertainty.py checks both by Monte Carlo).

The sigma dualcal reports (``sigma`` in calib.json) is the larger of this one and the textbook
one, for every parameter and derived value: with 8-30 instants the clustered variance of a value
that few instants inform is itself uncertain (its Bell-McCaffrey degrees of freedom are 4-9 on
the synthetic rigs of the tests), and it cannot see the noise of what one instant determines
alone (its own poses, in the paper's model the per-instant baseline direction); the textbook
value is the floor there. On white noise the two agree to within that uncertainty, so the
larger one is honest too (error / sigma spreads 0.84-1.03 over the tests' Monte Carlo draws).

``H_cc`` has the rank of the cluster's columns (its instant's poses and the global parameters it
touches), so its eigen-decomposition is taken in that small space: with ``J_c = Q R`` (thin QR),
``H_cc = Q (R M R^T) Q^T`` where ``M`` is ``N^-1`` restricted to the cluster's columns. Directions
that the cluster alone determines (its own board pose: eigenvalue 1) carry no residual at the
optimum and are left out.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

__all__ = ["ClusterRows", "cluster_scores", "clustered_covariance", "held_out_residuals", "leverage_adjusted_residuals"]

_SELF_DETERMINED = 1e-9    # 1 - eigenvalue below which a direction is fixed by its cluster alone
_HELD_OUT_OWN = 1e-6       # the same, for asking whether the other clusters determine a direction


@dataclass(frozen=True)
class ClusterRows:
    """The rows of one cluster (one instant): ``J`` (m, k) over parameter ``columns`` (k,), residuals ``r`` (m,)."""

    columns: np.ndarray
    J: np.ndarray
    r: np.ndarray


def _hat_eigen(J: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``lam`` and row-space eigenvectors ``U`` of the cluster's hat block ``H = J M J^T``."""
    Q, R = np.linalg.qr(J)
    lam, V = np.linalg.eigh(R @ M @ R.T)
    return lam, Q @ V


def leverage_adjusted_residuals(J: np.ndarray, r: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``(I - H)^-1/2 r`` with ``H = J M J^T`` (Bell & McCaffrey's CR2 adjustment).

    Parameters
    ----------
    J : (m, k) the cluster's Jacobian rows over its k columns.
    r : (m,) its residuals.
    M : (k, k) the inverse normal matrix restricted to those columns.
    """
    lam, U = _hat_eigen(J, M)
    keep = 1.0 - lam > _SELF_DETERMINED
    factor = np.where(keep, 1.0 / np.sqrt(np.where(keep, 1.0 - lam, 1.0)), 0.0) - 1.0
    # r + U (f - 1) U^T r: (I - H)^-1/2 on the span of J, identity outside it; the self-determined
    # directions (f = 0) are projected out, their residual is zero at the optimum anyway
    return r + U @ (factor * (U.T @ r))


def held_out_residuals(J: np.ndarray, r: np.ndarray, M: np.ndarray, n_own: int) -> np.ndarray | None:
    """The cluster's residuals as the fit without it predicts them: ``(I - H)^-1 r``, or None.

    For a linear least-squares problem this is exact: leaving the cluster out moves the shared
    parameters so that its residuals become ``(I - H)^-1 r`` once its ``n_own`` own columns (the
    parameters no other cluster has, e.g. its board poses) are fitted to it again (the grouped form
    of the PRESS residuals). At the optimum ``r`` has no component along those own columns, the
    directions where ``H`` has eigenvalue 1, so they are left as they are. ``None`` when more than
    ``n_own`` eigenvalues are 1: without the cluster the others do not determine everything it
    touches, and no prediction exists. Arguments as :func:`leverage_adjusted_residuals`.
    """
    lam, U = _hat_eigen(J, M)
    own = 1.0 - lam <= _HELD_OUT_OWN
    if own.sum() > n_own:
        return None
    factor = np.where(own, 1.0, 1.0 / np.where(own, 1.0, 1.0 - lam)) - 1.0
    return r + U @ (factor * (U.T @ r))


def cluster_scores(clusters: Iterable[ClusterRows], inverse_block: Callable[[np.ndarray], np.ndarray]):
    """Each cluster's leverage-adjusted score ``J_c^T (I - H_cc)^-1/2 r_c``, as ``(columns, score)``.

    Parameters
    ----------
    clusters : the rows of every cluster (instant): objects with ``columns``, ``J`` and ``r`` like
        :class:`ClusterRows` (e.g. :class:`dualcal.estimation.adjust.InstantRows`); together all rows of the problem.
    inverse_block : ``columns -> N^-1[columns, columns]``, the unscaled inverse normal matrix (no ``s0^2``).
    """
    out = []
    for cl in clusters:
        cols = np.asarray(cl.columns)
        out.append((cols, cl.J.T @ leverage_adjusted_residuals(cl.J, cl.r, inverse_block(cols))))
    return out


def cluster_shifts(scores, inverse_block: Callable[[np.ndarray], np.ndarray], columns) -> np.ndarray:
    """(k, clusters): each cluster's shift ``N^-1 s_c`` of the parameters ``columns`` (k,), from its
    adjusted score ``s_c`` (:func:`cluster_scores`)."""
    columns = np.asarray(columns, int)
    k = len(columns)
    shifts = np.zeros((k, len(scores)))
    for i, (cols, s) in enumerate(scores):
        both = inverse_block(np.concatenate([columns, cols]))
        shifts[:, i] = both[:k, k:] @ s
    return shifts


def clustered_covariance(scores, inverse_block: Callable[[np.ndarray], np.ndarray], columns) -> np.ndarray:
    """The CR2 cluster-robust covariance (module docstring) of the parameters ``columns`` (k,).

    ``Cov = sum_c (N^-1 s_c)(N^-1 s_c)^T`` over the clusters' adjusted scores ``s_c``
    (:func:`cluster_scores`, :func:`cluster_shifts`), restricted to ``columns``: a (k, k) matrix in
    the units of the residuals squared (pixels^2) times those of ``N^-1``.
    """
    shifts = cluster_shifts(scores, inverse_block, columns)
    return shifts @ shifts.T
