"""Normal equations in the block structure of the reduced camera system, kept per instant.

The unknowns of the adjustment split into ``G`` *global* parameters, shared by many photos
(intrinsics, the rig's relative pose, later the board's shape), and for each of ``V`` instants
(view keys) ``L`` *local* parameters that only the photos of that instant see (the board pose,
the per-instant baseline direction of the paper's model). Every residual belongs to one instant,
so ``N = J^T J`` is an arrow matrix::

    N = [[ sum_v Ngg_v,  Ngl_1,  Ngl_2, ...],
         [ Nlg_1,        Nll_1,  0,     ...],
         [ Nlg_2,        0,      Nll_2, ...], ...]

and :class:`NormalEquations` keeps exactly those pieces, instant by instant (and, where they are
assembled from photos, each photo's own part: :class:`PhotoNormals`, from which the error an instant's
photos would have if the fit had not seen them is found without their rows). A prior on some globals (known
intrinsics) belongs to no instant: its information ``prior_gg`` (G, G) and gradient ``prior_grad`` (G,) are
added to the globals' block whole.
The damped system ``(N + mu D) h = -g`` (``D = diag N``, Marquardt's scaling) is solved by
eliminating the locals first (:class:`Factorization`): with ``W_v = A_ll,v^-1 A_lg,v`` the reduced
matrix ``S = A_gg - sum_v A_gl,v W_v`` has only ``G`` rows, so the cost grows linearly with the
number of instants. The same factorization at ``mu = 0`` gives every block of ``N^-1`` that a
covariance needs, without forming ``N^-1`` whole.

Parameters are numbered in one flat vector: the ``G`` globals, then instant ``v``'s locals at
``G + v L + j``. An instant may use fewer than ``L`` locals (``local_used``); the unused slots
have no Jacobian column, are held at zero step and never enter a covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class PhotoNormals:
    """Each photo's own part of the normal equations, for the photos of one camera (``P`` photos):
    ``views`` (P,) their instants, ``global_columns`` (kg,) and ``local_slots`` (kl,) where their pieces
    sit, ``gg`` (P, kg, kg), ``gl`` (P, kg, kl), ``ll`` (P, kl, kl), ``grad_g`` (P, kg), ``grad_l`` (P, kl),
    ``squares`` (P,) ``r^T r`` and ``corners`` (P,) how many corners each measured; ``residuals`` (P, 2N) each photo's
    residuals (predicted - observed, px, u then v corner by corner, 0 where not measured; not scaled by its weight)
    where the equations were built, None where they were moved (:meth:`NormalEquations.moved`)."""

    camera: int
    blocks: np.ndarray
    views: np.ndarray
    global_columns: np.ndarray
    local_slots: np.ndarray
    gg: np.ndarray
    gl: np.ndarray
    ll: np.ndarray
    grad_g: np.ndarray
    grad_l: np.ndarray
    squares: np.ndarray
    corners: np.ndarray
    residuals: np.ndarray | None = None


@dataclass
class NormalEquations:
    """``J^T J`` and ``J^T r`` (``r`` = predicted - observed) per instant (module docstring).

    Attributes
    ----------
    gg : (V, G, G) each instant's part of the global-global block.
    gl : (V, G, L) global-local blocks.
    ll : (V, L, L) local-local blocks.
    grad_g : (V, G) each instant's part of the global gradient.
    grad_l : (V, L) local gradients.
    local_used : (V, L) bool, which local slots are parameters in each instant.
    curvature_gl, curvature_ll : None, or (V, G, L) and (V, L, L) second-order terms
        ``sum r d2r / dp dq`` of the Hessian that a curved model adds to ``J^T J`` (used for the
        steps with ``second_order=True``, never for a covariance).
    photos : each camera's photos' own parts (:class:`PhotoNormals`), where they were kept.
    prior_gg, prior_grad : None, or (G, G) and (G,) a prior's information and gradient (module docstring).
    prior_meat_root : None, or (G, q): ``R R^T`` is the variance of the prior's part of the gradient, which the
        covariance clustered by instant adds (:mod:`dualcal.estimation.uncertainty`).
    """

    gg: np.ndarray
    gl: np.ndarray
    ll: np.ndarray
    grad_g: np.ndarray
    grad_l: np.ndarray
    local_used: np.ndarray
    curvature_gl: np.ndarray | None = None
    curvature_ll: np.ndarray | None = None
    photos: list[PhotoNormals] = field(default_factory=list)
    prior_gg: np.ndarray | None = None
    prior_grad: np.ndarray | None = None
    prior_meat_root: np.ndarray | None = None

    @classmethod
    def zeros(cls, n_global: int, local_used: np.ndarray) -> "NormalEquations":
        V, L = local_used.shape
        return cls(np.zeros((V, n_global, n_global)), np.zeros((V, n_global, L)), np.zeros((V, L, L)),
                   np.zeros((V, n_global)), np.zeros((V, L)), local_used)

    @property
    def n_global(self) -> int:
        return self.gg.shape[1]

    def moved(self, h: np.ndarray) -> "NormalEquations":
        """The same matrices with the gradients (and each photo's gradients and ``r^T r``) of the linearised
        residuals ``r + J h`` after a flat step ``h``: at ``h = -N^-1 g``, those of the linearised minimum."""
        G, (V, L) = self.n_global, self.ll.shape[:2]
        h_g, h_l = h[:G], h[G:].reshape(V, L)
        photos = []
        for ph in self.photos:
            hg, hl = h_g[ph.global_columns], h_l[ph.views][:, ph.local_slots]
            grad_g = ph.grad_g + ph.gg @ hg + np.einsum("pij,pj->pi", ph.gl, hl)
            grad_l = ph.grad_l + np.einsum("pji,pj->pi", ph.gl, np.broadcast_to(hg, ph.grad_g.shape)) + np.einsum(
                "pij,pj->pi", ph.ll, hl)
            squares = ph.squares + np.einsum("pi,pi->p", ph.grad_g + grad_g, np.broadcast_to(hg, grad_g.shape)) + \
                np.einsum("pi,pi->p", ph.grad_l + grad_l, hl)
            photos.append(replace(ph, grad_g=grad_g, grad_l=grad_l, squares=squares, residuals=None))
        return replace(self, grad_g=self.grad_g + self.gg @ h_g + np.einsum("vgl,vl->vg", self.gl, h_l),
                       grad_l=self.grad_l + np.einsum("vgl,g->vl", self.gl, h_g) + np.einsum("vij,vj->vi", self.ll, h_l),
                       photos=photos,
                       prior_grad=None if self.prior_grad is None else self.prior_grad + self.prior_gg @ h_g)

    def global_block(self) -> np.ndarray:
        """(G, G) the globals' block of ``N``: every instant's, and the prior's."""
        gg = self.gg.sum(axis=0)
        return gg if self.prior_gg is None else gg + self.prior_gg

    def gradient(self) -> np.ndarray:
        """``J^T r`` as one flat vector (module docstring)."""
        g = self.grad_g.sum(axis=0)
        return np.concatenate([g if self.prior_grad is None else g + self.prior_grad, self.grad_l.ravel()])

    def diagonal(self) -> np.ndarray:
        """``diag N`` as one flat vector; 1 for unused local slots (so it can divide)."""
        d_l = np.where(self.local_used, np.diagonal(self.ll, axis1=1, axis2=2), 1.0)
        return np.concatenate([np.diag(self.global_block()), d_l.ravel()])

    def metric(self, h: np.ndarray) -> float:
        """``h^T N h`` for a flat vector ``h`` (the squared change of the residuals ``J h``)."""
        G, (V, L) = self.n_global, self.ll.shape[:2]
        h_g, h_l = h[:G], h[G:].reshape(V, L)
        return float(h_g @ self.global_block() @ h_g + 2.0 * np.einsum("g,vgl,vl->", h_g, self.gl, h_l)
                     + np.einsum("vi,vij,vj->", h_l, self.ll, h_l))

    def factor(self, mu: float = 0.0, second_order: bool = False) -> "Factorization":
        """Factorization of ``N + mu diag(N)`` (with ``second_order``: plus the curvature terms);
        raises ``numpy.linalg.LinAlgError`` if it is not positive definite."""
        return Factorization(self, mu, second_order)


class Factorization:
    """``A = N + mu diag(N)`` (+ curvature terms) with the locals eliminated (module docstring)."""

    def __init__(self, ne: NormalEquations, mu: float, second_order: bool = False):
        self.ne = ne
        d_l = np.diagonal(ne.ll, axis1=1, axis2=2)
        # unused slots get 1 on the diagonal: decoupled (their Jacobian columns are zero) and invertible
        A_ll = ne.ll + _diag_embed(np.where(ne.local_used, mu * d_l, 1.0))
        gl = ne.gl
        if second_order and ne.curvature_ll is not None:
            A_ll = A_ll + ne.curvature_ll
            gl = gl + ne.curvature_gl
        self.gl = gl
        chol = np.linalg.cholesky(A_ll)                              # raises if not positive definite
        chol_inv = np.linalg.inv(chol)
        self.ll_inv = np.swapaxes(chol_inv, 1, 2) @ chol_inv         # (V, L, L)
        self.W = self.ll_inv @ np.swapaxes(gl, 1, 2)               # (V, L, G)
        A_gg = ne.global_block()
        A_gg = A_gg + mu * np.diag(np.diag(A_gg))
        self.S = A_gg - np.einsum("vgl,vlh->gh", gl, self.W)
        self.chol_S = np.linalg.cholesky(self.S)                     # raises LinAlgError too
        self._S_inv = None

    def step(self) -> np.ndarray:
        """The flat step ``h`` solving ``A h = -g``."""
        ne = self.ne
        y_l = -np.einsum("vij,vj->vi", self.ll_inv, ne.grad_l)
        h_g = self._solve_S(-ne.gradient()[:ne.n_global] - np.einsum("vgl,vl->g", self.gl, y_l))
        h_l = y_l - self.W @ h_g
        return np.concatenate([h_g, np.where(ne.local_used, h_l, 0.0).ravel()])

    def global_inverse(self) -> np.ndarray:
        """(G, G) ``S^-1``: at ``mu = 0`` the global block of ``N^-1`` (computed once)."""
        if self._S_inv is None:
            self._S_inv = self._solve_S(np.eye(len(self.S)))
        return self._S_inv

    def _solve_S(self, b: np.ndarray) -> np.ndarray:
        """``S^-1 b`` from ``S = C C^T`` (two triangular systems; numpy's general solver, as scipy's
        triangular one costs a third of a second to import for systems of a few dozen unknowns)."""
        return np.linalg.solve(self.chol_S.T, np.linalg.solve(self.chol_S, b))

    def global_combination(self, columns: np.ndarray) -> np.ndarray:
        """(..., k, G): each flat parameter of ``columns`` (..., k) as the combination of globals through which a
        step of the globals moves it once the locals are fitted again: ``e_g`` for a global, ``-W_v[j]`` for
        local ``j`` of instant ``v``."""
        columns = np.asarray(columns, int)
        G, L = self.ne.n_global, self.ne.ll.shape[1]
        is_local = columns >= G
        v, j = np.divmod(columns - G, L)
        E = np.zeros(columns.shape + (G,))
        E[(*np.nonzero(~is_local), columns[~is_local])] = 1.0
        E[is_local] = -self.W[v[is_local], j[is_local]]
        return E

    def inverse_block(self, columns: np.ndarray) -> np.ndarray:
        """``A^-1`` restricted to the flat parameter indices ``columns`` (k,), as a (k, k) matrix.

        ``(A^-1)_gg = S^-1``, ``(A^-1)_lg,v = -W_v S^-1`` and
        ``(A^-1)_ll,vw = [v = w] A_ll,v^-1 + W_v S^-1 W_w^T``.
        """
        columns = np.asarray(columns, int)
        G, L = self.ne.n_global, self.ne.ll.shape[1]
        E = self.global_combination(columns)
        out = E @ self.global_inverse() @ E.T
        v, j = np.divmod(columns - G, L)
        loc = np.flatnonzero(columns >= G)
        for instant in np.unique(v[loc]):                   # the locals' own blocks, instant by instant
            at = loc[v[loc] == instant]
            out[np.ix_(at, at)] += self.ll_inv[instant][np.ix_(j[at], j[at])]
        return out

    def inverse_blocks(self, columns: np.ndarray) -> np.ndarray:
        """:meth:`inverse_block` of each row of ``columns`` (B, k), (B, k, k) in one batch (rows of few columns:
        a photo's)."""
        columns = np.asarray(columns, int)
        G, L = self.ne.n_global, self.ne.ll.shape[1]
        E = self.global_combination(columns)
        out = E @ self.global_inverse() @ np.swapaxes(E, 1, 2)
        is_local = columns >= G
        v, j = np.divmod(np.where(is_local, columns - G, 0), L)
        same = is_local[:, :, None] & is_local[:, None, :] & (v[:, :, None] == v[:, None, :])
        return out + np.where(same, self.ll_inv[v[:, :, None], j[:, :, None], j[:, None, :]], 0.0)


def _diag_embed(d: np.ndarray) -> np.ndarray:
    """(..., n) -> (..., n, n) diagonal matrices."""
    out = np.zeros(d.shape + d.shape[-1:])
    idx = np.arange(d.shape[-1])
    out[..., idx, idx] = d
    return out
