"""The chessboard target: geometry and corner numbering (paper section 1.2).

Conventions (see README, "Conventions"):

* ``cols x rows`` counts **inner** corners; a board of 9 x 6 squares is ``8x5``.
* Inner corner ``k = r*cols + c`` sits at ``(X, Y, Z) = (c*s, r*s, 0)`` mm in the board frame.
* Squares are indexed by the board coordinates of their lower corner: square ``(a, b)``
  covers ``X in [a*s, (a+1)*s]``, ``Y in [b*s, (b+1)*s]`` for ``a = -1 .. cols-1`` and
  ``b = -1 .. rows-1``. Square ``(-1, -1)``, diagonally outside corner 0, is black, so a square
  is black exactly when ``a + b`` is even.
* Z points into the board, away from the camera; a camera looking at the printed side sits
  at negative Z.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .errors import InputError

_SPEC = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


@dataclass(frozen=True)
class Board:
    """A planar chessboard with ``cols x rows`` inner corners of pitch ``square_mm``."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self):
        if self.cols < 2 or self.rows < 2:
            raise InputError(f"board {self.cols}x{self.rows}: needs at least 2x2 inner corners")
        if not (self.square_mm > 0 and np.isfinite(self.square_mm)):
            raise InputError(f"square size {self.square_mm} mm: must be a positive number")

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def is_symmetric(self) -> bool:
        """True when the board looks the same turned by 180 degrees (``cols + rows`` even)."""
        return (self.cols + self.rows) % 2 == 0

    def object_points_mm(self) -> np.ndarray:
        """(N, 3) board-frame coordinates of the inner corners, in corner order ``k = r*cols + c``."""
        r, c = np.divmod(np.arange(self.n_corners), self.cols)
        return np.column_stack([c * self.square_mm, r * self.square_mm, np.zeros(self.n_corners)])

    def spec(self) -> str:
        return f"{self.cols}x{self.rows}"

    def to_dict(self) -> dict:
        return {"cols": self.cols, "rows": self.rows, "square_mm": float(self.square_mm)}

    @classmethod
    def from_dict(cls, d: dict) -> "Board":
        try:
            cols, rows = d["cols"], d["rows"]
            if not all(isinstance(n, int) and not isinstance(n, bool) for n in (cols, rows)):
                raise TypeError("cols and rows must be whole numbers")
            return cls(cols, rows, float(d["square_mm"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"board entry {d!r} is malformed: needs cols, rows, square_mm") from exc


def parse_board_spec(spec: str) -> tuple[int, int]:
    """``"8x5"`` -> ``(8, 5)``; raises :class:`InputError` with the expected form otherwise."""
    m = _SPEC.match(str(spec))
    if not m:
        raise InputError(f"--board {spec!r} is malformed: give inner corners as COLSxROWS, e.g. 8x5")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 2 or rows < 2:
        raise InputError(f"--board {spec!r}: needs at least 2x2 inner corners")
    return cols, rows


def is_black_square(a, b):
    """True where square ``(a, b)`` (indexed as in the module docstring) is black."""
    return (np.asarray(a) + np.asarray(b)) % 2 == 0


# ---------------------------------------------------------------------------- the board's shape

SHAPE_TERMS = ("xx", "yy", "xy")
"""The out-of-plane shape of a real board: ``Z = w_xx x'^2 + w_yy y'^2 + w_xy x' y'`` (mm), with
``x', y'`` the board coordinates scaled to [-1, 1] over the corners. A printed board glued on
card or foam sags, bends along one axis or twists; these are the low-order shapes it takes (a
plane itself is absorbed by every photo's pose). Each coefficient is the height, in mm, that its
term reaches at the edge (``xx``, ``yy``) or the corner (``xy``) of the corner grid."""


def shape_basis(xy_mm: np.ndarray) -> np.ndarray:
    """(N, 3) values of the :data:`SHAPE_TERMS` at board points ``xy_mm`` (N, 2), scaled to [-1, 1]
    over the points' own extent (pass all of a board's corners)."""
    xy = np.asarray(xy_mm, float)[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    s = (xy - 0.5 * (lo + hi)) / np.maximum(0.5 * (hi - lo), 1e-12)
    return np.column_stack([s[:, 0] ** 2, s[:, 1] ** 2, s[:, 0] * s[:, 1]])


def shaped_points_mm(X_board: np.ndarray, shape_mm: np.ndarray | None) -> np.ndarray:
    """Board points (N, 3) moved out of plane by the shape coefficients ``shape_mm`` (3,) (None: flat)."""
    X = np.array(X_board, float)
    if shape_mm is not None:
        X[:, 2] = X[:, 2] + shape_basis(X) @ np.asarray(shape_mm, float)
    return X


def sag_mm(X_board: np.ndarray, shape_mm: np.ndarray | None) -> float:
    """Largest distance of the shaped board's corners from their best-fitting plane, mm."""
    if shape_mm is None:
        return 0.0
    Z = shape_basis(X_board) @ np.asarray(shape_mm, float)
    A = np.column_stack([np.asarray(X_board, float)[:, :2], np.ones(len(Z))])
    return float(np.max(np.abs(Z - A @ np.linalg.lstsq(A, Z, rcond=None)[0])))
