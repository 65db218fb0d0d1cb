"""A circle grid's centres modelled as the centres of the circles' images (the outline model).

A detector measures the centre of each circle's image (its outline's); the adjustment
(:mod:`dualcal.estimation.adjust`) models the projection of a point. The two differ by the
perspective bias of :mod:`dualcal.geometry.circles` (a few tenths of a pixel for a tilted board
and circles of a few mm), which a calibration from projected centres absorbs into its focal
length and poses. This stage removes it without a solver of its own: given any solver
``solve(blocks, start) -> Solution`` and a first solution, it

1. computes, from the current solution's cameras and poses, each circle's offset
   ``o = circle_image_centre - projected centre`` (:func:`outline_offsets`);
2. solves again, started from the current solution, with each observed centre moved by
   ``-o`` (:func:`corrected_blocks`), so that the point model of the moved centre is the
   outline model of the observed one: ``uv - o(theta) - P(theta) = uv - C(theta)``;
3. repeats until no offset changes by more than ``tol_px`` (1e-4 px).

What it converges to. At its fixed point ``theta*`` the residuals are those of the outline
model, ``r = uv - C(theta*)``, and the solver's normal equations hold with the point model's
Jacobian: ``J_P^T r = 0``. The outline model's least-squares solution has ``(J_P + J_o)^T r = 0``,
where ``J_o``, the offsets' derivative, is small against ``J_P`` (the offsets are a few tenths of a
pixel and change slowly with the parameters): the two coincide where the data fit exactly, and
otherwise differ by ``(J^T J)^-1 J_o^T r``, a small share of the parameters' sigma (measured in
``tests/test_circles.py`` against a direct least-squares fit of the outline model). Each iteration
shrinks the change of the offsets by about ``|J_o| / |J_P|``: two or three solves, each from a near
start.

The board is taken as flat (a board shape estimated by the solver is ignored in the offsets).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry.board import Board
from ..geometry.circles import circle_centre_offset_px
from .adjust import Solution

__all__ = ["CircleCentreFit", "outline_offsets", "corrected_blocks", "fit_circle_outlines", "OFFSET_TOLERANCE_PX"]

#: The fixed point is reached when no circle's offset changes by more than this between two solves.
OFFSET_TOLERANCE_PX = 1e-4


@dataclass(frozen=True)
class CircleCentreFit:
    """Result of :func:`fit_circle_outlines`.

    ``solution``: the last solve, over ``blocks`` (the observed centres moved by the offsets of the
    solution before it); ``offsets_px`` ``{(camera, view): (N, 2)}`` the offsets of ``solution`` itself;
    ``iterations`` the solves made after the first solution; ``change_px`` the largest change of an
    offset in the last of them; ``converged`` whether it is below the tolerance.
    """

    solution: Solution
    blocks: list
    offsets_px: dict
    iterations: int
    change_px: float
    converged: bool


def outline_offsets(sol: Solution, board: Board) -> dict[tuple[int, str], np.ndarray]:
    """``{(camera, view): (N, 2)}`` pixels: for every photo of ``sol``, each circle's image centre minus its
    projected centre (:func:`dualcal.geometry.circles.circle_centre_offset_px`) under ``sol``'s camera and pose."""
    if not board.is_circle_grid:
        raise InputError(f"{board.describe()}: its points are not circles (the outline model is for circle grids)")
    centres = board.object_points_mm()
    poses = sol.photo_poses
    cams = {c: sol.state.camera(sol.problem, c) for c in range(len(sol.problem.cameras))}
    return {(c, v): circle_centre_offset_px(cams[c], poses[(c, v)], centres, 0.5 * board.circle_diameter_mm)
            for c, v, _ in sol.problem.blocks}


def corrected_blocks(blocks, offsets_px: dict) -> list:
    """``(camera, view, uv - offset)`` of every block ``(camera, view, uv)``: the observed centres moved
    so that a point model of them is the outline model of the observed ones (NaN rows stay NaN)."""
    return [(c, v, np.asarray(uv, float) - offsets_px[(c, v)]) for c, v, uv in blocks]


def fit_circle_outlines(solve: Callable, blocks, first: Solution, board: Board,
                        tol_px: float = OFFSET_TOLERANCE_PX, max_iterations: int = 10) -> CircleCentreFit:
    """The outline model's solution of a circle grid's observed centres, by the fixed point of the module
    docstring.

    Parameters
    ----------
    solve : callable
        ``solve(blocks, start) -> Solution``: the calibration's solver (e.g. ``Setup.solve`` of
        :mod:`dualcal.estimation.fitting`), started from ``start``.
    blocks : list of (int, str, (N, 2) ndarray)
        ``(camera, view, uv)``: the observed centres (pixels, NaN rows where not measured), as detected.
    first : Solution
        ``solve``'s solution of ``blocks`` as they are (the point model): the start.
    board : Board
        the circle grid (its ``circle_diameter_mm`` the circles' diameter).
    tol_px : float
        stop when no offset changes by more than this (pixels).
    max_iterations : int
        solves at most.

    Returns
    -------
    CircleCentreFit
    """
    sol = first
    offsets = outline_offsets(sol, board)
    change, moved = np.inf, list(blocks)
    for iteration in range(1, max_iterations + 1):
        moved = corrected_blocks(blocks, offsets)
        sol = solve(moved, sol)
        new = outline_offsets(sol, board)
        change = max(float(np.nanmax(np.abs(new[k] - offsets[k]), initial=0.0)) for k in new)
        offsets = new
        if change < tol_px:
            return CircleCentreFit(sol, moved, offsets, iteration, change, True)
    return CircleCentreFit(sol, moved, offsets, max_iterations, change, False)
