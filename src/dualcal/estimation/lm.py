"""Levenberg-Marquardt on block normal equations, with a convergence test that can be trusted.

The cost is ``F = r^T r`` (pixels squared). Each iteration solves ``(H + mu D) h = -g`` with
``g = J^T r``, ``D = diag N`` (Marquardt's scaling, so ``mu`` has no units) and ``H`` the
Gauss-Newton matrix ``N = J^T J`` plus the exact second-order terms a curved model supplies
(:class:`dualcal.estimation.normal_equations.NormalEquations`), or ``N`` alone where those make the system
indefinite. Then only the residuals at ``x + h`` are evaluated (the Jacobian is computed again
only for an accepted step). A trial whose cost is not finite (e.g. a corner at ``Z <= 0``,
behind its camera) is rejected. The damping follows the gain ratio ``rho = (F - F(x + h)) / (F - L(h))`` of the actual
to the predicted decrease (Nielsen 1999; Madsen, Nielsen & Tingleff 2004, alg. 3.16): on
``rho > 0`` the step is taken and ``mu <- mu max(1/3, 1 - (2 rho - 1)^3)``, else
``mu <- mu nu, nu <- 2 nu``. With ``(H + mu D) h = -g`` the decrease that the quadratic model
``L(h) = F + 2 g^T h + h^T H h`` predicts is ``F - L(h) = -g^T h + mu h^T D h``.

It stops on the first of these tests (``s0 = sqrt(F / redundancy)``, never taken below
``floor_px``, the level of rounding in the pixel coordinates; ``mu`` starts at ``mu0``):

* gradient: ``max_j |g_j| / sqrt(N_jj F) <= gtol`` (the residuals are orthogonal to every
  Jacobian column; the infinity norm of the gradient, scaled so that it has no units);
* step: ``sqrt(h^T N h) / s0 <= xtol``: the step moves the estimate by less than ``xtol`` of its
  standard deviation (the Mahalanobis length of the step in the covariance ``s0^2 N^-1``);
* function: actual and predicted relative decrease of ``F`` both ``<= ftol``;
* the iteration limit, or the damping limit (no step lowers the cost).

``mu0`` is where the damping starts: 1e-6 (:class:`LMOptions`) from a start far from the minimum
(Zhang's closed form), 1e-9 (:data:`NEAR_START`) from an earlier solution. With Marquardt's scaling
the normal matrix has a unit diagonal, and its smallest eigenvalues belong to the parameters the
photos determine together, not one by one: about 2e-6 for a 12 MP phone's wide and tele (``synth
--preset note8``), 4e-5 to 2e-4 on the real sets. A damping of that order shortens the step along
those directions by a good part of itself in every iteration, and the convergence turns linear
(the steps shrank about tenfold an iteration where Gauss-Newton's shrink a hundredfold and more):
the eight solves of a note8 calibration (with ``--model auto`` and the other skew model) took 39
iterations from 1e-6 and take 31 with the near starts' 1e-9. From a far start the damping is
needed, and a small ``mu0`` only adds rejected trials.

None of these is believed alone: when one fires, an undamped solve (the one the covariance needs
anyway) checks that the Gauss-Newton step ``h0 = -N^-1 g`` from the estimate has a Mahalanobis
length ``sqrt(g^T N^-1 g) / s0 <= verify_sigma``, i.e. that no parameter nor any function of them is
further than ``verify_sigma`` standard deviations from the minimum of the linearised problem;
otherwise the iterations go on. A small step caused by heavy damping therefore never passes for
convergence, and ``converged`` is False only when the iteration or damping limit ends the run
short of that.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .normal_equations import Factorization, NormalEquations


@dataclass(frozen=True)
class LMOptions:
    """Tolerances of :func:`levenberg_marquardt` (module docstring)."""

    max_iter: int = 100
    gtol: float = 1e-10
    xtol: float = 1e-3
    ftol: float = 1e-12
    verify_sigma: float = 1e-3
    floor_px: float = 1e-6
    mu0: float = 1e-6
    mu_max: float = 1e20


#: The tolerances for a start from an earlier solution (module docstring: ``mu0``).
NEAR_START = LMOptions(mu0=1e-9)

#: Where a comparison's adjustments stop (the lens models compared, the loop check's pairs of cameras):
#: within 0.05 sigma of their minimum, not the 1e-3 of a result. What they compare is taken at the
#: linearised minimum (:meth:`dualcal.estimation.adjust.Solution.held_out_squares`, the pairs' relations),
#: so where within 0.05 sigma a solve stopped moves it only to second order: on the three real sets
#: ``worse_se`` moved by at most 7e-4 SE (the choice is at 2) and the same models were chosen.
COMPARISON_LM = replace(NEAR_START, xtol=0.05, verify_sigma=0.05)


@dataclass
class LMResult:
    """The estimate and why the solver stopped.

    ``factorization`` is that of the undamped normal equations at ``x`` (for the covariance);
    ``distance_sigma`` the Mahalanobis length of the remaining Gauss-Newton step (module docstring).
    """

    x: Any
    cost: float
    factorization: Factorization
    iterations: int
    converged: bool
    termination: str
    distance_sigma: float


def levenberg_marquardt(x: Any, linearise: Callable[[Any], tuple[float, NormalEquations]],
                        cost: Callable[[Any], float], update: Callable[[Any, np.ndarray], Any],
                        redundancy: int, options: LMOptions = LMOptions()) -> LMResult:
    """Minimise ``F = r^T r`` from ``x`` (module docstring).

    Parameters
    ----------
    x : the starting estimate (any object; only ``update`` looks inside it).
    linearise : ``x -> (F, NormalEquations)`` at ``x``.
    cost : ``x -> F``, residuals only; ``inf`` where ``x`` is not admissible.
    update : ``(x, h) -> x + h`` for a flat step ``h`` (numbering of :mod:`dualcal.estimation.normal_equations`).
    redundancy : observations minus unknowns, for ``s0``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the undamped normal matrix at the end is not positive definite (the data do not
        determine every parameter).
    """
    o = options
    F, ne = linearise(x)
    mu, nu, it = o.mu0, 2.0, 0
    checked = None                  # (ne, distance, factorization) of the last undamped check
    stop = _gradient_test(ne, F, o) or _near_minimum(o)
    while True:
        if stop is not None:        # a test says "done": believe it only if the undamped step agrees
            try:
                checked = _check(ne, F, redundancy, o)
                if checked[1] <= o.verify_sigma:
                    break
            except np.linalg.LinAlgError:            # not determined here: go on
                pass
            stop = None
        if it >= o.max_iter:
            stop = f"iteration limit {o.max_iter} reached"
            break
        if mu > o.mu_max:
            stop = "no step lowers the cost (damping limit)"
            break
        it += 1
        scale = max(np.sqrt(F / redundancy), o.floor_px)
        g, d = ne.gradient(), ne.diagonal()
        try:
            try:
                h = ne.factor(mu, second_order=True).step()
            except np.linalg.LinAlgError:          # the second-order terms make it indefinite here
                h = ne.factor(mu).step()
        except np.linalg.LinAlgError:
            mu, nu = mu * nu, 2.0 * nu
            continue
        predicted = float(-g @ h + mu * (h @ (d * h)))
        small_step = np.sqrt(ne.metric(h)) <= o.xtol * scale
        trial = update(x, h)
        F_trial = cost(trial)
        rho = (F - F_trial) / predicted if predicted > 0 and np.isfinite(F_trial) else -np.inf
        if rho > 0:
            F_old, x = F, trial
            F, ne = linearise(x)
            mu, nu = mu * max(1 / 3, 1 - (2 * rho - 1) ** 3), 2.0
            if small_step:
                stop = f"step below {o.xtol:g} sigma"
            elif F_old - F <= o.ftol * F_old and predicted <= o.ftol * F_old:
                stop = f"relative cost change below {o.ftol:g}"
            else:
                stop = _gradient_test(ne, F, o) or _near_minimum(o)
        else:
            mu, nu = mu * nu, 2.0 * nu
            if small_step:                          # at the rounding level of the cost
                stop = f"step below {o.xtol:g} sigma"
    if checked is None or checked[0] is not ne:
        checked = _check(ne, F, redundancy, o)
    _, distance, factorization = checked
    converged = bool(distance <= o.verify_sigma)
    if not converged:
        stop += f"; the estimate is still {distance:.2g} sigma from the minimum"
    return LMResult(x, float(F), factorization, it, converged, stop, float(distance))


def _near_minimum(o: LMOptions) -> str:
    """The test that every start and every accepted step gets: the undamped check itself (a factorization,
    no new residuals), so that a start already at its minimum, or a step that lands there, ends the run
    without another linearisation to find it out."""
    return f"Gauss-Newton step below {o.verify_sigma:g} sigma"


def _gradient_test(ne: NormalEquations, F: float, o: LMOptions) -> str | None:
    """The scaled gradient test (module docstring), or None."""
    g, d = ne.gradient(), ne.diagonal()
    if F == 0.0 or np.max(np.abs(g) / np.sqrt(d * F)) <= o.gtol:
        return f"gradient below {o.gtol:g}"
    return None


def _check(ne: NormalEquations, F: float, redundancy: int, o: LMOptions):
    """``(ne, distance, factorization)``: the Mahalanobis length of the undamped Gauss-Newton step
    from the estimate of ``ne``, in units of ``s0`` (module docstring)."""
    factorization = ne.factor(0.0)
    scale = max(np.sqrt(F / redundancy), o.floor_px)
    return ne, np.sqrt(max(float(-ne.gradient() @ factorization.step()), 0.0)) / scale, factorization
