"""The calibration targets: chessboards and ChArUco boards, geometry and corner numbering (paper section 1.2).

Conventions (see README, "Conventions"):

* ``cols x rows`` counts **inner** corners; a board of 9 x 6 squares is ``8x5``.
* Inner corner ``k = r*cols + c`` sits at ``(X, Y, Z) = (c*s, r*s, 0)`` mm in the board frame.
* Squares are indexed by the board coordinates of their lower corner: square ``(a, b)``
  covers ``X in [a*s, (a+1)*s]``, ``Y in [b*s, (b+1)*s]`` for ``a = -1 .. cols-1`` and
  ``b = -1 .. rows-1``. Square ``(-1, -1)``, diagonally outside corner 0, is black, so a square
  is black exactly when ``a + b`` is even.
* Z points into the board, away from the camera; a camera looking at the printed side sits
  at negative Z.

A **ChArUco board** (``Board.charuco`` set, :class:`Charuco`) is a chessboard of
``SX x SY`` squares (so ``cols = SX - 1``, ``rows = SY - 1``) with an ArUco marker in every
white square. Its corners are numbered as OpenCV numbers ChArUco corners: OpenCV's corner
``k`` of ``cv2.aruco.CharucoBoard((SX, SY), s, m, dictionary)`` sits at ``((c+1)*s, (r+1)*s)``
in OpenCV's frame, whose origin is the board's outer corner, so dualcal's frame is OpenCV's
shifted by one square along X and Y; the axes are the same (X along the printed rows, Y down
the printed board, Z into it). Markers fill the white squares in reading order (top row
first, left to right), marker ``i`` having the dictionary's id ``i``.

The layout is OpenCV's current one (OpenCV >= 4.6, ``setLegacyPattern(False)``): the top-left
square, ``(-1, -1)``, is black for every board, as on dualcal's chessboards. OpenCV's legacy
pattern (``legacy=True``, boards made by OpenCV before 4.6 and by some vendors) differs only
when ``SY`` is even: then its top-left square is white and the colours and markers are those
of the other squares. A board whose markers number its corners has no 180-degree ambiguity.

A **circle grid** (``pattern`` ``"circles"`` or ``"acircles"``, CONTRACT.md "circle grids") counts
circles, not squares: ``cols x rows`` as OpenCV's ``findCirclesGrid`` counts them, ``square_mm`` the
distance between neighbouring centres, ``circle_mm`` the diameter of a (dark, filled) circle. Point
``k = r*cols + c`` is the centre of a circle at ``(c*s, r*s, 0)`` (symmetric grid) or
``((2c + r % 2) * s, r*s, 0)`` (asymmetric grid: every other row shifted by one spacing, the rows
``2s`` apart along X). Without a given diameter a circle is :data:`DEFAULT_CIRCLE_SHARE` of the
spacing, as OpenCV's pattern generator (``gen_pattern.py``, radius = spacing / 5) prints it.

A **target given by its points** (``pattern`` ``"points"``, ``points_mm``; corners.json's
``board.points_mm``) is any planar layout: point ``k`` at ``points_mm[k]`` (mm, ``Z = 0``). Its
``cols`` is the number of points and ``rows`` 1 (one row of points: a count, not a grid); its
``square_mm`` is the spacing its scale tolerance refers to (by default the median distance of a
point to its nearest neighbour). It cannot be detected in photos: its points come from corners.json.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError

_SPEC = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")
_CHARUCO_SPEC = re.compile(r"^\s*charuco\s*:\s*(\d+)\s*[xX]\s*(\d+)\s*$", re.IGNORECASE)
_CIRCLES_SPEC = re.compile(r"^\s*(a?circles)\s*:\s*(\d+)\s*[xX]\s*(\d+)\s*$", re.IGNORECASE)

#: The kinds of target: a chessboard (a ChArUco board too: ``Board.charuco`` set), OpenCV's symmetric and
#: asymmetric circle grids, and a target given by its points.
PATTERNS = ("chessboard", "circles", "acircles", "points")

#: A circle's diameter as a share of the centres' spacing where none is given: OpenCV's ``gen_pattern.py``
#: prints circles of radius ``spacing / 5`` (its default ``--radius_rate 5``).
DEFAULT_CIRCLE_SHARE = 0.4

#: OpenCV's predefined ArUco dictionaries (``cv2.aruco.DICT_*``): name -> (bits per side,
#: number of markers). Within a family ``DICT_NxN_*`` the smaller dictionaries are the first
#: markers of the larger ones, so a board made with one is read the same with any larger one.
DICTIONARIES = {
    **{f"DICT_{n}X{n}_{k}": (n, k) for n in (4, 5, 6, 7) for k in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": (5, 1024),
    "DICT_APRILTAG_16h5": (4, 30),
    "DICT_APRILTAG_25h9": (5, 35),
    "DICT_APRILTAG_36h10": (6, 2320),
    "DICT_APRILTAG_36h11": (6, 587),
    "DICT_ARUCO_MIP_36h12": (6, 250),
}


def dictionary_name(name: str) -> str:
    """OpenCV's spelling of a predefined dictionary name (any case, ``DICT_`` optional)."""
    key = str(name).strip().upper()
    key = key if key.startswith("DICT_") else "DICT_" + key
    for known in DICTIONARIES:
        if known.upper() == key:
            return known
    raise InputError(f"dictionary {name!r} is not one of OpenCV's predefined ArUco dictionaries "
                     f"({', '.join(DICTIONARIES)})")


def dictionary_family(name: str) -> list[str]:
    """The dictionaries that begin with the same markers as ``name``, smallest first."""
    m = re.fullmatch(r"DICT_(\d)X\d_\d+", name)
    if not m:
        return [name]
    return [f"DICT_{m.group(1)}X{m.group(1)}_{k}" for k in (50, 100, 250, 1000)]


def smallest_dictionary(name: str, n_markers: int) -> str:
    """The smallest dictionary of ``name``'s family that holds ``n_markers`` markers."""
    return next(d for d in dictionary_family(name) + [name] if DICTIONARIES[d][1] >= n_markers)


@dataclass(frozen=True)
class Charuco:
    """The markers of a ChArUco board (see the module docstring).

    ``squares = (SX, SY)`` counts squares; ``marker_mm`` is the side of a marker (its black
    border included). ``dictionary`` is OpenCV's name of the markers' dictionary and ``legacy``
    whether the board has OpenCV's legacy layout; either may be None while it is still to be
    found from the photos (:mod:`dualcal.files.detect.charuco`); files always hold both.
    """

    squares: tuple[int, int]
    marker_mm: float
    dictionary: str | None = None
    legacy: bool | None = False

    def __post_init__(self):
        sx, sy = self.squares
        if sy % 2 == 1 and self.legacy is not False:
            object.__setattr__(self, "legacy", False)      # the two layouts are the same board
        if self.dictionary is not None:
            object.__setattr__(self, "dictionary", dictionary_name(self.dictionary))

    @property
    def n_markers(self) -> int:
        return self.squares[0] * self.squares[1] // 2

    @property
    def resolved(self) -> bool:
        """True when the dictionary and the layout are known."""
        return self.dictionary is not None and self.legacy is not None


@dataclass(frozen=True)
class Board:
    """A planar target: a chessboard of ``cols x rows`` inner corners of pitch ``square_mm``, a ChArUco
    board when ``charuco`` is given (:meth:`charuco_board` builds one from its squares), a circle grid
    (``pattern`` ``"circles"`` or ``"acircles"``, circles of diameter ``circle_mm``, None for the default:
    :attr:`circle_diameter_mm`; :meth:`circle_grid`)
    or a target given by its points (``pattern`` ``"points"``, :meth:`from_points`); see the module
    docstring for each one's layout.

    ``square_sigma_mm`` is the 1-sigma of the printed square's size (a board printed at home is true
    to a few tenths of a percent): every length dualcal derives scales with the square, so it enters
    their sigmas fully correlated (:mod:`dualcal.geometry.scale`). It is a tolerance, not a property of the
    pattern: :meth:`matches` ignores it.
    """

    cols: int
    rows: int
    square_mm: float
    charuco: Charuco | None = None
    square_sigma_mm: float = 0.0
    pattern: str = "chessboard"
    circle_mm: float | None = None
    points_mm: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self):
        if self.pattern not in PATTERNS:
            raise InputError(f"board pattern {self.pattern!r} is unknown: expected one of {', '.join(PATTERNS)}")
        if self.pattern == "points":
            self._check_points()
        elif self.cols < 2 or self.rows < 2:
            what = "circles" if self.is_circle_grid else "inner corners"
            raise InputError(f"board {self.cols}x{self.rows}: needs at least 2x2 {what}")
        if not (self.square_mm > 0 and np.isfinite(self.square_mm)):
            raise InputError(f"square size {self.square_mm} mm: must be a positive number")
        if not (self.square_sigma_mm >= 0 and np.isfinite(self.square_sigma_mm)):
            raise InputError(f"square size sigma {self.square_sigma_mm} mm: must be a length >= 0")
        if self.square_sigma_mm > 0.1 * self.square_mm:
            raise InputError(f"square size sigma {self.square_sigma_mm:g} mm is more than a tenth of the square "
                             f"({self.square_mm:g} mm): measure the printed board (e.g. 10 squares with a ruler)")
        if self.is_circle_grid:
            self._check_circles()
        elif self.circle_mm is not None:
            raise InputError(f"a circle diameter ({self.circle_mm:g} mm) describes a circle grid, not a "
                             f"{self.pattern}")
        ch = self.charuco
        if ch is None:
            return
        if self.pattern != "chessboard":
            raise InputError(f"a ChArUco board is a chessboard with markers, not a {self.pattern} target")
        if tuple(ch.squares) != (self.cols + 1, self.rows + 1):
            raise InputError(f"ChArUco board of {ch.squares[0]}x{ch.squares[1]} squares has "
                             f"{ch.squares[0] - 1}x{ch.squares[1] - 1} inner corners, not {self.cols}x{self.rows}")
        if not (0 < ch.marker_mm < self.square_mm and np.isfinite(ch.marker_mm)):
            raise InputError(f"marker size {ch.marker_mm} mm: must be positive and smaller than the square "
                             f"({self.square_mm:g} mm)")
        if ch.dictionary is not None and DICTIONARIES[ch.dictionary][1] < ch.n_markers:
            raise InputError(f"dictionary {ch.dictionary} holds {DICTIONARIES[ch.dictionary][1]} markers; a ChArUco "
                             f"board of {ch.squares[0]}x{ch.squares[1]} squares needs {ch.n_markers}")

    def _check_circles(self) -> None:
        # neighbouring circles must not touch: centres s apart (symmetric), s*sqrt(2) (asymmetric)
        d = self.circle_diameter_mm
        if not (0 < d < self.circle_gap_mm and np.isfinite(d)):
            raise InputError(f"circle diameter {d:g} mm: must be positive and smaller than the distance "
                             f"between neighbouring circles ({self.circle_gap_mm:g} mm)")

    @property
    def circle_diameter_mm(self) -> float:
        """A circle grid's circle diameter, mm: ``circle_mm``, or where that is not given (None)
        :data:`DEFAULT_CIRCLE_SHARE` of the spacing."""
        return float(self.circle_mm) if self.circle_mm is not None else DEFAULT_CIRCLE_SHARE * float(self.square_mm)

    @property
    def circle_gap_mm(self) -> float:
        """Distance from a circle grid's centre to its nearest other centre, mm (the spacing; the diagonal
        ``s sqrt(2)`` on an asymmetric grid)."""
        return self.square_mm * (np.sqrt(2.0) if self.pattern == "acircles" else 1.0)

    def _check_points(self) -> None:
        pts = np.asarray(self.points_mm if self.points_mm is not None else [], float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 4 or not np.all(np.isfinite(pts)):
            raise InputError("a target given by its points needs at least 4 points [x, y] in mm")
        if (self.cols, self.rows) != (len(pts), 1):
            raise InputError(f"a target of {len(pts)} points has cols {len(pts)} and rows 1, "
                             f"not {self.cols}x{self.rows}")
        centred = pts - pts.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[1] <= 1e-9 * max(sv[0], 1e-300):
            raise InputError(f"the target's {len(pts)} points lie on one line: a calibration needs a planar layout")
        if len(np.unique(np.round(pts, 9), axis=0)) < len(pts):
            raise InputError("the target's points repeat a point: each point must be at its own place")

    @classmethod
    def circle_grid(cls, pattern: str, cols: int, rows: int, spacing_mm: float, circle_mm: float | None = None,
                    square_sigma_mm: float = 0.0) -> "Board":
        """A circle grid (``pattern`` ``"circles"`` or ``"acircles"``) of ``cols x rows`` circles,
        ``spacing_mm`` between neighbouring centres, circles of diameter ``circle_mm`` (None:
        :data:`DEFAULT_CIRCLE_SHARE` of the spacing)."""
        if pattern not in ("circles", "acircles"):
            raise InputError(f"circle grid pattern {pattern!r}: expected circles or acircles")
        return cls(int(cols), int(rows), float(spacing_mm), square_sigma_mm=float(square_sigma_mm), pattern=pattern,
                   circle_mm=None if circle_mm is None else float(circle_mm))

    @classmethod
    def from_points(cls, points_mm, square_mm: float | None = None, square_sigma_mm: float = 0.0) -> "Board":
        """A target given by its points: ``points_mm`` (N, 2) or (N, 3) with ``Z = 0``, mm, any planar layout.
        ``square_mm``: the spacing its scale tolerance refers to (None: the median distance of a point to
        its nearest neighbour)."""
        pts = np.asarray(points_mm, float)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise InputError(f"the target's points: expected a list of [x, y] or [x, y, 0] in mm, got shape "
                             f"{pts.shape}")
        if pts.shape[1] == 3 and np.any(pts[:, 2] != 0):
            raise InputError("the target's points must lie in its plane: give [x, y] or [x, y, 0] (Z = 0)")
        pts = pts[:, :2]
        if square_mm is None and len(pts) >= 2 and np.all(np.isfinite(pts)):
            d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
            np.fill_diagonal(d, np.inf)
            square_mm = float(np.median(d.min(axis=1)))
        return cls(len(pts), 1, float(square_mm) if square_mm is not None else 1.0,
                   square_sigma_mm=float(square_sigma_mm), pattern="points",
                   points_mm=tuple(tuple(map(float, p)) for p in pts))

    @classmethod
    def charuco_board(cls, squares: tuple[int, int], square_mm: float, marker_mm: float,
                      dictionary: str | None = None, legacy: bool | None = False) -> "Board":
        """A ChArUco board of ``squares = (SX, SY)`` squares (``SX-1 x SY-1`` inner corners)."""
        sx, sy = (int(n) for n in squares)
        if sx < 3 or sy < 3:
            raise InputError(f"ChArUco board {sx}x{sy}: needs at least 3x3 squares")
        return cls(sx - 1, sy - 1, float(square_mm), Charuco((sx, sy), float(marker_mm), dictionary, legacy))

    @property
    def n_corners(self) -> int:
        """Number of inner corners, ``cols * rows``."""
        return self.cols * self.rows

    @property
    def is_circle_grid(self) -> bool:
        """True for a symmetric or asymmetric circle grid."""
        return self.pattern in ("circles", "acircles")

    @property
    def is_symmetric(self) -> bool:
        """True when the board looks the same turned by 180 degrees about its centre: a chessboard with
        ``cols + rows`` even, every symmetric circle grid, an asymmetric one with ``rows`` even; never a
        ChArUco board (its markers number the corners) nor a target given by its points (not detected).
        Turned, point ``k`` falls on point ``N-1-k``."""
        if self.pattern == "circles":
            return True
        if self.pattern == "acircles":
            return self.rows % 2 == 0
        return self.pattern == "chessboard" and self.charuco is None and (self.cols + self.rows) % 2 == 0

    def object_points_mm(self) -> np.ndarray:
        """(N, 3) board-frame coordinates of the points in order ``k = r*cols + c``: inner corners,
        circle centres (see the module docstring) or the points of a target given by them."""
        if self.pattern == "points":
            xy = np.asarray(self.points_mm, float)
            return np.column_stack([xy, np.zeros(len(xy))])
        r, c = np.divmod(np.arange(self.n_corners), self.cols)
        x = 2 * c + r % 2 if self.pattern == "acircles" else c
        return np.column_stack([x * self.square_mm, r * self.square_mm, np.zeros(self.n_corners)])

    def pattern_extent_mm(self) -> tuple[float, float, float, float]:
        """``(x0, x1, y0, y1)`` mm: the printed pattern's area in the board frame, without its margin: a
        chessboard's squares (the outer ring included), a circle grid's circles with half a spacing
        around them, a target's points with one spacing around them."""
        s = self.square_mm
        if self.pattern == "chessboard":
            return -s, self.cols * s, -s, self.rows * s
        xy = self.object_points_mm()[:, :2]
        pad = 0.5 * (s + self.circle_diameter_mm) if self.is_circle_grid else s
        (x0, y0), (x1, y1) = xy.min(axis=0) - pad, xy.max(axis=0) + pad
        return float(x0), float(x1), float(y0), float(y1)

    def spec(self) -> str:
        """``"8x5"`` (inner corners) for a chessboard, ``"charuco:11x8"`` (squares) for a ChArUco board,
        ``"circles:4x11"`` / ``"acircles:4x11"`` (circles) for a circle grid, ``"points:N"`` for a target
        given by its ``N`` points."""
        if self.charuco is not None:
            return "charuco:{}x{}".format(*self.charuco.squares)
        if self.pattern == "points":
            return f"points:{self.n_corners}"
        if self.is_circle_grid:
            return f"{self.pattern}:{self.cols}x{self.rows}"
        return f"{self.cols}x{self.rows}"

    def describe(self, sizes: bool = False) -> str:
        """The board in words, for messages: ``"8x5 chessboard"``, ``"ChArUco board charuco:11x8 (DICT_5X5_50)"``,
        ``"acircles:4x11 asymmetric circle grid"``, ``"target of 40 points"``; with ``sizes``, its square
        (and marker, or spacing and circle) size too."""
        if self.pattern == "points":
            return f"target of {self.n_corners} points" + (f" ({self.square_mm:g} mm apart)" if sizes else "")
        if self.is_circle_grid:
            kind = "symmetric" if self.pattern == "circles" else "asymmetric"
            sized = f" of {self.square_mm:g} mm spacing and {self.circle_diameter_mm:g} mm circles" if sizes else ""
            return f"{self.spec()} {kind} circle grid{sized}"
        if self.charuco is None:
            text = f"{self.spec()} chessboard"
        else:
            text = f"ChArUco board {self.spec()}" + (f" ({self.charuco.dictionary})" if self.charuco.dictionary else "")
        if sizes:
            text += f" of {self.square_mm:g} mm squares"
            text += f" and {self.charuco.marker_mm:g} mm markers" if self.charuco is not None else ""
        return text

    def black_parity(self) -> int:
        """Square ``(a, b)`` is black where ``(a + b) % 2`` equals this (0, except on OpenCV's legacy
        ChArUco layout with an even number of rows of squares)."""
        return int(bool(self.charuco is not None and self.charuco.legacy))

    def marker_squares(self) -> np.ndarray:
        """(M, 2) square ``(a, b)`` of ChArUco marker ``i`` (row ``i``): the white squares in reading order."""
        if self.charuco is None:
            return np.empty((0, 2), int)
        b, a = np.divmod(np.arange((self.cols + 1) * (self.rows + 1)), self.cols + 1)
        a, b = a - 1, b - 1
        white = (a + b) % 2 != self.black_parity()
        return np.column_stack([a[white], b[white]])

    def marker_corners_mm(self) -> np.ndarray:
        """(M, 4, 3) board-frame corners of every marker, in OpenCV's order (top-left, top-right,
        bottom-right, bottom-left of the printed board: increasing X first, Y down)."""
        sq = self.marker_squares().astype(float)
        s, m = self.square_mm, self.charuco.marker_mm
        lo = sq * s + 0.5 * (s - m)
        offs = np.array([[0, 0], [m, 0], [m, m], [0, m]], float)
        xy = lo[:, None, :] + offs[None]
        return np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], axis=2)

    def corner_markers(self) -> np.ndarray:
        """(N, 2) ids of the markers in the two white squares touching each inner corner."""
        index = -np.ones((self.rows + 1, self.cols + 1), int)
        sq = self.marker_squares()
        index[sq[:, 1] + 1, sq[:, 0] + 1] = np.arange(len(sq))
        r, c = np.divmod(np.arange(self.n_corners), self.cols)
        around = np.stack([index[r, c], index[r, c + 1], index[r + 1, c], index[r + 1, c + 1]], axis=1)
        return np.sort(around, axis=1)[:, 2:]

    def matches(self, other: "Board") -> bool:
        """True when ``other`` is this board; a ChArUco board's dictionary and layout, and a circle grid's
        diameter, are compared only where this one gives them (a board from the command line may leave them
        to the photos, or to the file); ``square_sigma_mm`` is not compared."""
        if self.is_circle_grid and self.circle_mm is None:         # the diameter not given: any
            return replace(self, square_sigma_mm=0.0) == replace(other, square_sigma_mm=0.0, circle_mm=None)
        if self.charuco is None or other.charuco is None:
            return replace(self, square_sigma_mm=0.0) == replace(other, square_sigma_mm=0.0)
        mine, theirs = self.charuco, other.charuco
        return (replace(self, charuco=None, square_sigma_mm=0.0) == replace(other, charuco=None, square_sigma_mm=0.0)
                and (mine.squares, mine.marker_mm) == (theirs.squares, theirs.marker_mm)
                and mine.dictionary in (None, theirs.dictionary) and mine.legacy in (None, theirs.legacy))

    def to_dict(self) -> dict:
        """The board entry of corners.json and calib.json (the contract's keys)."""
        if self.pattern == "points":
            doc = {"points_mm": [list(p) for p in self.points_mm], "square_mm": float(self.square_mm)}
        else:
            doc = {"cols": self.cols, "rows": self.rows, "square_mm": float(self.square_mm)}
        if self.is_circle_grid:
            doc.update(pattern=self.pattern, circle_mm=self.circle_diameter_mm)
        if self.square_sigma_mm:
            doc["square_sigma_mm"] = float(self.square_sigma_mm)
        ch = self.charuco
        if ch is not None:
            doc["charuco"] = {"squares": list(ch.squares), "marker_mm": float(ch.marker_mm),
                              "dictionary": ch.dictionary}
            if ch.legacy is not False:
                doc["charuco"]["legacy"] = ch.legacy
        return doc

    @classmethod
    def from_dict(cls, d: dict) -> "Board":
        """The board of a corners.json or calib.json entry, validated (:class:`InputError` says what is wrong)."""
        sigma = d.get("square_sigma_mm", 0.0)
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)):
            raise InputError(f"board entry's square_sigma_mm {sigma!r}: expected a length in millimetres")
        pattern = d.get("pattern", "points" if "points_mm" in d else "chessboard")
        if pattern == "points" or "points_mm" in d:
            return cls._points_from_dict(d, float(sigma))
        try:
            cols, rows = d["cols"], d["rows"]
            if not all(_whole(n) for n in (cols, rows)):
                raise TypeError("cols and rows must be whole numbers")
            board = cls(cols, rows, float(d["square_mm"]), square_sigma_mm=float(sigma))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"board entry {d!r} is malformed: needs cols, rows, square_mm") from exc
        if pattern in ("circles", "acircles"):
            circle = d.get("circle_mm")
            if circle is not None and (isinstance(circle, bool) or not isinstance(circle, (int, float))):
                raise InputError(f"board entry's circle_mm {circle!r}: expected the circles' diameter in millimetres")
            if "charuco" in d:
                raise InputError("board entry: a circle grid has no charuco entry")
            return cls.circle_grid(pattern, cols, rows, board.square_mm, circle, board.square_sigma_mm)
        if pattern != "chessboard":
            raise InputError(f"board entry's pattern {pattern!r}: expected circles or acircles (or none: a chessboard)")
        if "charuco" not in d:
            return board
        ch = d["charuco"]
        form = ('"charuco": {"squares": [SX, SY], "marker_mm": MM, "dictionary": "DICT_..."} '
                '(and "legacy": true for OpenCV\'s legacy layout)')
        if not isinstance(ch, dict) or set(ch) - {"squares", "marker_mm", "dictionary", "legacy"}:
            raise InputError(f"board entry's charuco {ch!r} is malformed: expected {form}")
        squares, marker, name, legacy = (ch.get(k) for k in ("squares", "marker_mm", "dictionary", "legacy"))
        if not (isinstance(squares, list) and len(squares) == 2 and all(_whole(n) for n in squares)):
            raise InputError(f"board entry's charuco squares {squares!r}: expected [SX, SY], two whole numbers")
        if isinstance(marker, bool) or not isinstance(marker, (int, float)):
            raise InputError(f"board entry's charuco marker_mm {marker!r}: expected a length in millimetres")
        if not isinstance(name, str):
            raise InputError(f"board entry's charuco dictionary {name!r}: expected the name of an OpenCV dictionary, "
                             "e.g. \"DICT_5X5_100\"")
        if legacy is not None and not isinstance(legacy, bool):
            raise InputError(f"board entry's charuco legacy {legacy!r}: expected true or false")
        return replace(board, charuco=Charuco(tuple(squares), float(marker), name, bool(legacy)))

    @classmethod
    def _points_from_dict(cls, d: dict, sigma: float) -> "Board":
        """The target of a board entry with ``points_mm`` (see :meth:`from_points`)."""
        points, square = d.get("points_mm"), d.get("square_mm")
        if not (isinstance(points, list) and all(isinstance(p, list) and len(p) in (2, 3) and
                                                 all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in p)
                                                 for p in points)):
            raise InputError("board entry's points_mm: expected a list of [x, y] or [x, y, 0] in millimetres")
        if d.get("pattern", "points") != "points" or "charuco" in d:
            raise InputError("board entry: points_mm gives the target by its points; it has no other pattern")
        if square is not None and (isinstance(square, bool) or not isinstance(square, (int, float))):
            raise InputError(f"board entry's square_mm {square!r}: expected a length in millimetres")
        if len({len(p) for p in points}) > 1:
            raise InputError("board entry's points_mm: give every point as [x, y], or every point as [x, y, 0]")
        board = cls.from_points(points, None if square is None else float(square), sigma)
        for key in ("cols", "rows"):
            if key in d and d[key] != getattr(board, key):
                raise InputError(f"board entry's {key} {d[key]!r} disagrees with its {board.n_corners} points_mm "
                                 f"(a target of points has cols {board.cols}, rows 1)")
        return board


#: The dictionary family a ChArUco board is drawn or printed with when none is given.
DEFAULT_FAMILY = "DICT_5X5_1000"


def with_default_markers(board: Board) -> Board:
    """A ChArUco board with every choice made, to draw or print it: the dictionary where it is not
    given (the smallest 5x5 one that holds its markers) and OpenCV's current layout where the
    layout is not. A chessboard is returned as it is."""
    ch = board.charuco
    if ch is None or ch.resolved:
        return board
    name = ch.dictionary or smallest_dictionary(DEFAULT_FAMILY, ch.n_markers)
    return replace(board, charuco=replace(ch, dictionary=name, legacy=bool(ch.legacy)))


def _whole(n) -> bool:
    return isinstance(n, int) and not isinstance(n, bool)


def parse_board_spec(spec: str) -> tuple[int, int]:
    """``"8x5"`` -> ``(8, 5)``; raises :class:`InputError` with the expected form otherwise."""
    m = _SPEC.match(str(spec))
    if not m:
        raise InputError(f"--board {spec!r} is malformed: give inner corners as COLSxROWS, e.g. 8x5, "
                         "the squares of a ChArUco board as charuco:SXxSY, e.g. charuco:11x8, or a circle grid's "
                         "circles as circles:COLSxROWS or acircles:COLSxROWS")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 2 or rows < 2:
        raise InputError(f"--board {spec!r}: needs at least 2x2 inner corners")
    return cols, rows


def board_from_spec(spec: str, square_mm: float, marker_mm: float | None = None,
                    dictionary: str | None = None, square_sigma_mm: float = 0.0,
                    circle_mm: float | None = None) -> Board:
    """The board of ``--board SPEC --square MM [--marker MM] [--dictionary NAME] [--square-sigma MM]
    [--circle MM]``.

    ``SPEC`` is ``COLSxROWS`` (a chessboard's inner corners), ``charuco:SXxSY`` (a ChArUco
    board's squares, which needs ``marker_mm``; without ``dictionary`` it is found from the
    photos, and so is the layout when ``SY`` is even), or ``circles:COLSxROWS`` /
    ``acircles:COLSxROWS`` (a symmetric or asymmetric circle grid's circles, ``square_mm`` the
    centres' spacing and ``circle_mm`` the circles' diameter, by default
    :data:`DEFAULT_CIRCLE_SHARE` of the spacing).
    """
    if not (square_mm is not None and square_mm > 0):
        raise InputError(f"--square {square_mm}: must be a positive length in millimetres")
    circles = _CIRCLES_SPEC.match(str(spec))
    if circle_mm is not None and circles is None:
        raise InputError("--circle describes a circle grid: give --board circles:COLSxROWS or acircles:COLSxROWS")
    if circles is not None:
        if marker_mm is not None or dictionary is not None:
            raise InputError("--marker and --dictionary describe a ChArUco board, not a circle grid")
        if circle_mm is not None and not circle_mm > 0:
            raise InputError(f"--circle {circle_mm}: must be a positive length in millimetres")
        return Board.circle_grid(circles.group(1).lower(), int(circles.group(2)), int(circles.group(3)),
                                 square_mm, circle_mm, square_sigma_mm)
    if str(spec).strip().lower().split(":")[0] in ("circles", "acircles"):
        raise InputError(f"--board {spec!r} is malformed: give a circle grid's circles as circles:COLSxROWS or "
                         "acircles:COLSxROWS, e.g. acircles:4x11")
    m = _CHARUCO_SPEC.match(str(spec))
    if m is None:
        if str(spec).strip().lower().startswith("charuco"):
            raise InputError(f"--board {spec!r} is malformed: give a ChArUco board's squares as charuco:SXxSY, "
                             "e.g. charuco:11x8")
        if marker_mm is not None or dictionary is not None:
            raise InputError("--marker and --dictionary describe a ChArUco board: give --board charuco:SXxSY")
        cols, rows = parse_board_spec(spec)
        return Board(cols, rows, float(square_mm), square_sigma_mm=float(square_sigma_mm))
    if marker_mm is None:
        raise InputError(f"--board {spec} is a ChArUco board: give the side of its markers with --marker MM")
    if not marker_mm > 0:
        raise InputError(f"--marker {marker_mm}: must be a positive length in millimetres")
    board = Board.charuco_board((int(m.group(1)), int(m.group(2))), square_mm, marker_mm, dictionary, legacy=None)
    return replace(board, square_sigma_mm=float(square_sigma_mm))


def is_black_square(a, b):
    """True where square ``(a, b)`` (indexed as in the module docstring) is black on a chessboard."""
    return (np.asarray(a) + np.asarray(b)) % 2 == 0


# ---------------------------------------------------------------------------- the board's shape

SHAPE_TERMS = ("xx", "yy", "xy")
"""The out-of-plane shape of a real board: ``Z = w_xx x'^2 + w_yy y'^2 + w_xy x' y'`` (mm), with
``x', y'`` the board coordinates scaled to [-1, 1] over the corners. A printed board glued on
card or foam sags, bends along one axis or twists; these are the low-order shapes it takes (a
plane itself is absorbed by every photo's pose). Each coefficient is the height, in mm, that its
term reaches at the edge (``xx``, ``yy``) or the corner (``xy``) of the corner grid."""


def shape_basis(xy_mm: np.ndarray, extent_mm=None) -> np.ndarray:
    """(N, 3) values of the :data:`SHAPE_TERMS` at board points ``xy_mm`` (N, 2), scaled to [-1, 1]
    over the points' own extent (pass all of a board's corners), or over ``extent_mm``, ``(lo, hi)`` (2,)
    each (the corners' extent, for points beyond them)."""
    xy = np.asarray(xy_mm, float)[:, :2]
    lo, hi = (xy.min(axis=0), xy.max(axis=0)) if extent_mm is None else (np.asarray(e, float) for e in extent_mm)
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
