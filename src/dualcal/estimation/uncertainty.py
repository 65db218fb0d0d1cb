"""Uncertainty that holds on real photos: the covariance clustered by instant, and the error on instants left out.

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

The same leverage gives the error on an instant the calibration did not see (a leave-one-instant-out
cross-validation, which compares lens models): for a linear model, leaving cluster ``c`` out and
fitting its own unknowns (its board poses) to it again leaves it the residuals ``(I - H_cc)^-1 r_c``
(the grouped form of the PRESS residuals), exactly, with no new adjustment.

*In the space of the global unknowns.* Neither needs the cluster's rows. Cluster ``c``'s own unknowns
(those of its instant alone) are eliminated: with its normal-equation pieces ``N_gg,c``, ``N_gl,c``,
``N_ll,c`` and gradients ``g_g,c``, ``g_l,c`` (:class:`dualcal.estimation.normal_equations.NormalEquations`),
its reduced information is ``S_c = N_gg,c - N_gl,c N_ll,c^-1 N_lg,c`` and its reduced score
``b_c = g_g,c - N_gl,c N_ll,c^-1 g_l,c``, ``S = sum_c S_c`` is the reduced camera system, and the rows
``J~_c = J_g,c - J_l,c N_ll,c^-1 N_lg,c`` are those of the globals with the cluster's own unknowns fitted
out. ``H_cc`` is the projector on the own unknowns' columns (eigenvalue 1: the directions a cluster
determines alone, which carry no residual at the optimum and are left out) plus ``J~_c S^-1 J~_c^T``,
whose non-zero eigenvalues ``1 - mu`` are those of ``S_c`` against ``S``: with ``S^-1 = T^T T``
(a Cholesky factor of ``S`` scaled to a unit diagonal, for its precision), ``mu`` and ``U`` are the
eigenvalues and eigenvectors of ``T K_c T^T``, where ``K_c = sum_{d != c} S_d`` is what the other
clusters know (summed without ``c``, so that ``mu`` near 0, an instant that alone determines something,
keeps its digits). Then, with ``q_c = U^T T b_c``, since ``J~^T f(J~ S^-1 J~^T) = T^-1 f(T S_c T^T) T J~^T``:

* the cluster's CR2 shift of the globals, ``N^-1 J_c^T W_c r_c = T^T U mu^-1/2 q_c`` (0 where
  ``mu <= 1e-9``: determined by the cluster alone), and of a local unknown its combination of globals;
* the globals without the cluster, moved by ``z_c = (S - S_c)^-1 b_c = T^T U q_c / mu`` (none where some
  ``mu <= 1e-6``: the others do not determine everything the cluster touches), and its held-out
  residuals ``r_c + J~_c z_c``, whose sum of squares over any of its photos is a quadratic form in the
  photo's own normal-equation pieces (:func:`held_out_squares`).

One eigen-decomposition of size ``G`` per instant, batched, where the rows would need one QR of the
instant's ``2 N`` rows by their columns each.

*A prior* on some globals (known intrinsics, :mod:`dualcal.estimation.adjust`) belongs to no instant: its
information is in ``S`` and in what every instant's others know (``K_c``), and its own part of the score has a
known variance, ``R R^T`` (:attr:`dualcal.estimation.normal_equations.NormalEquations.prior_meat_root`), whose
shift ``S^-1 R`` the clustered covariance adds to the instants' (``prior``), so that the prior's uncertainty is
in every sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .normal_equations import Factorization, NormalEquations

__all__ = ["InstantLeverage", "held_out_squares", "instant_leverage"]

_SELF_DETERMINED = 1e-9    # 1 - eigenvalue below which a direction is fixed by its cluster alone
_HELD_OUT_OWN = 1e-6       # the same, for asking whether the other clusters determine a direction


@dataclass(frozen=True)
class InstantLeverage:
    """Every instant's leverage on the global unknowns (module docstring), for ``V`` instants, ``G`` globals.

    ``shifts`` (G, V): each instant's CR2 shift of the globals (its leverage-adjusted score through
    ``N^-1``); their outer products summed, with those of ``prior`` (G, q), a prior's shift (none: q = 0), are
    the clustered covariance of the globals. ``held_out`` (V, G): the globals' change when the instant is left
    out, a row of NaN where the others cannot do without it.
    """

    shifts: np.ndarray
    held_out: np.ndarray
    prior: np.ndarray


def _sums_without_each(S_c: np.ndarray) -> np.ndarray:
    """(V, G, G): ``sum_{d != c} S_d`` for every ``c``, summed, not subtracted from the total."""
    zero = np.zeros((1,) + S_c.shape[1:])
    before = np.concatenate([zero, np.cumsum(S_c, axis=0)[:-1]])
    after = np.concatenate([np.cumsum(S_c[::-1], axis=0)[::-1][1:], zero])
    return before + after


def instant_leverage(factorization: Factorization, ne: NormalEquations | None = None) -> InstantLeverage:
    """:class:`InstantLeverage` from the factorization of the undamped normal equations at the optimum
    (``mu = 0``), whose locals are each instant's own unknowns; the gradients those of ``ne`` (default:
    the factorization's own; :meth:`NormalEquations.moved` gives those of the linearised minimum)."""
    W = factorization.W
    ne = factorization.ne if ne is None else ne
    S_c = ne.gg - factorization.gl @ W                                                       # (V, G, G)
    b = ne.grad_g - np.einsum("vgl,vl->vg", factorization.gl, np.einsum("vij,vj->vi", factorization.ll_inv,
                                                                          ne.grad_l))
    prior = np.zeros(S_c.shape[1:]) if ne.prior_gg is None else ne.prior_gg
    S = S_c.sum(axis=0) + prior
    d = 1.0 / np.sqrt(np.diag(S))
    T = np.linalg.inv(np.linalg.cholesky(S * d[:, None] * d[None, :])) * d[None, :]        # S^-1 = T^T T
    mu, U = np.linalg.eigh(T @ (_sums_without_each(S_c) + prior) @ T.T)
    q = np.einsum("vgk,vg->vk", U, b @ T.T)                                                  # U^T T b
    keep = mu > _SELF_DETERMINED
    shifts = T.T @ np.einsum("vgk,vk->gv", U, np.where(keep, q / np.sqrt(np.where(keep, mu, 1.0)), 0.0))
    known = np.all(mu > _HELD_OUT_OWN, axis=1)
    held = np.einsum("vgk,vk->vg", U, q / np.where(known[:, None], mu, 1.0)) @ T
    root = np.zeros((len(S), 0)) if ne.prior_meat_root is None else ne.prior_meat_root
    return InstantLeverage(shifts, np.where(known[:, None], held, np.nan), T.T @ (T @ root))


def held_out_squares(factorization: Factorization, held_out: np.ndarray, ne: NormalEquations | None = None
                     ) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Each photo's held-out sum of squares ``|r + J~ z|^2`` (px^2), ``z`` its instant's row of
    ``held_out`` (:attr:`InstantLeverage.held_out`): ``(camera, blocks (P,), squares (P,))`` per camera's
    photos (:attr:`dualcal.estimation.normal_equations.NormalEquations.photos`), NaN where the instant
    cannot be left out. The photos' pieces are those of ``ne`` (default: the factorization's own).

    With ``y = N_ll^-1 N_lg z`` (the instant's own unknowns fitted again) and the photo's pieces, the sum
    is ``r^T r + 2 (g_g^T z - g_l^T y) + z^T N_gg z - 2 z^T N_gl y + y^T N_ll y``.
    """
    y = np.einsum("vlg,vg->vl", factorization.W, np.nan_to_num(held_out))
    out = []
    for ph in (factorization.ne if ne is None else ne).photos:
        z = held_out[ph.views][:, ph.global_columns]
        yl = y[ph.views][:, ph.local_slots]
        squares = (ph.squares + 2 * (np.einsum("pi,pi->p", ph.grad_g, z) - np.einsum("pi,pi->p", ph.grad_l, yl))
                   + np.einsum("pi,pij,pj->p", z, ph.gg, z) - 2 * np.einsum("pi,pij,pj->p", z, ph.gl, yl)
                   + np.einsum("pi,pij,pj->p", yl, ph.ll, yl))
        out.append((ph.camera, ph.blocks, squares))
    return out
