"""The printable board: a PDF at true scale, or a PNG at a stated resolution.

The page shows the board that a command line describes (:mod:`dualcal.geometry.board`) and, in the
margin under it, its specification (the command line that reads it back), a scale bar with
millimetre ticks to check the print with a ruler, and the board's axes from corner 0. Every
black area (the squares and, on a ChArUco board, the black cells of the markers, whose codes
come from ``cv2.aruco.generateImageMarker``) is one filled path of rectangles in millimetres
(a circle grid's circles: one path of circles, matplotlib's eight Bezier arcs each, within 4e-6
of the radius), so the PDF is vector art that a printer draws at its own resolution, and a PNG rasterised by
matplotlib's Agg has exact area coverage at every edge (no seams between touching cells).

Page coordinates are millimetres from the page's top-left corner, y down. Print the PDF at
100 % ("actual size", not "fit to page") and measure the scale bar.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.board import Board, with_default_markers
from ..errors import InputError
from .io import write_bytes_atomic

__all__ = ["PAPERS", "PageLayout", "page_layout", "write_board"]

MM_PER_INCH = 25.4

#: Paper sizes, (width, height) in mm, portrait.
PAPERS = {"A4": (210.0, 297.0), "A3": (297.0, 420.0), "A2": (420.0, 594.0), "A1": (594.0, 841.0),
          "A0": (841.0, 1189.0), "letter": (215.9, 279.4), "legal": (215.9, 355.6)}

#: Room under the board for the specification and the scale bar, mm.
TEXT_MM = 24.0


@dataclass(frozen=True)
class PageLayout:
    """Where the board sits on the page, mm: ``origin_mm`` is corner 0 (``X = Y = 0`` of the board
    frame) from the page's top-left, the board's X along the page's x and its Y down the page."""

    page_mm: tuple[float, float]
    origin_mm: tuple[float, float]
    board: Board

    @property
    def board_mm(self) -> tuple[float, float]:
        """Width and height of the printed pattern (:meth:`Board.pattern_extent_mm`: a chessboard's ``cols + 1`` by
        ``rows + 1`` squares), mm."""
        x0, x1, y0, y1 = self.board.pattern_extent_mm()
        return x1 - x0, y1 - y0


def _quiet_zone_mm(board: Board) -> float:
    """White margin around the squares: detectors want one, 10 mm or half a square at least."""
    return max(10.0, 0.5 * board.square_mm)


def page_layout(board: Board, paper: str = "auto", dpi: float | None = None) -> PageLayout:
    """The page of ``board``: ``paper`` is a key of :data:`PAPERS` (either orientation, whichever
    holds the board), ``"fit"`` (the board, its quiet zone and the text, nothing more) or
    ``"auto"`` (the smallest A size that holds it, else ``fit``). With ``dpi`` the page is cut to
    a whole number of pixels (so that a pixel is exactly ``25.4 / dpi`` mm).

    Raises
    ------
    InputError
        When the board does not fit on the paper asked for.
    """
    if board.pattern == "points":
        raise InputError(f"{board.describe()}: a target given by its points is printed by whoever made it, "
                         "not by dualcal")
    x0, x1, y0, y1 = board.pattern_extent_mm()
    w, h = x1 - x0, y1 - y0
    q = _quiet_zone_mm(board)
    need = (w + 2 * q, h + 2 * q + TEXT_MM)
    if paper not in PAPERS and paper not in ("auto", "fit"):
        raise InputError(f"--paper {paper!r}: choose auto, fit or one of {', '.join(PAPERS)}")
    if paper == "fit":
        page = need
    else:
        names = ["A4", "A3", "A2", "A1", "A0"] if paper == "auto" else [paper]
        page = None
        for name in names:
            for size in (PAPERS[name], PAPERS[name][::-1]):
                if size[0] >= need[0] and size[1] >= need[1]:
                    page = size
                    break
            if page:
                break
        if page is None:
            if paper != "auto":
                raise InputError(f"{board.spec()} with {board.square_mm:g} mm squares needs {need[0]:.0f} x "
                                 f"{need[1]:.0f} mm: it does not fit on {paper} (try --paper fit or a larger one)")
            page = need
    if dpi is not None:
        page = tuple(np.floor(np.asarray(page) * dpi / MM_PER_INCH) * MM_PER_INCH / dpi)
    left = 0.5 * (page[0] - w)
    top = 0.5 * (page[1] - TEXT_MM - h)
    return PageLayout((float(page[0]), float(page[1])), (left - x0, top - y0), board)


def _black_path(layout: PageLayout):
    """One matplotlib path of every black area, page mm: a circle grid's circles, or the closed rectangles of
    :func:`_black_rectangles`, all turning the same way (its fill is their union)."""
    from matplotlib.path import Path as MplPath

    board, (ox, oy) = layout.board, layout.origin_mm
    if board.is_circle_grid:
        centres = board.object_points_mm()[:, :2] + (ox, oy)
        return MplPath.make_compound_path(*(MplPath.circle(tuple(c), 0.5 * board.circle_diameter_mm) for c in centres))
    r = _black_rectangles(layout)
    verts = np.stack([r[:, [0, 1]], r[:, [2, 1]], r[:, [2, 3]], r[:, [0, 3]], r[:, [0, 1]]], axis=1)
    codes = np.tile([MplPath.MOVETO] + [MplPath.LINETO] * 3 + [MplPath.CLOSEPOLY], len(r))
    return MplPath(verts.reshape(-1, 2), codes)


def _black_rectangles(layout: PageLayout) -> np.ndarray:
    """(K, 4) ``x0, y0, x1, y1`` page mm of every black area: squares, then marker cells."""
    board, (ox, oy), s = layout.board, layout.origin_mm, layout.board.square_mm
    b, a = np.divmod(np.arange((board.cols + 1) * (board.rows + 1)), board.cols + 1)
    a, b = a - 1, b - 1
    black = (a + b) % 2 == board.black_parity()
    x0, y0 = ox + a[black] * s, oy + b[black] * s
    rects = [np.column_stack([x0, y0, x0 + s, y0 + s])]
    if board.charuco is not None:
        import cv2

        ch = board.charuco
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ch.dictionary))
        cells = dictionary.markerSize + 2
        cell = ch.marker_mm / cells
        for i, (x, y) in enumerate(board.marker_corners_mm()[:, 0, :2]):
            rr, cc = np.nonzero(cv2.aruco.generateImageMarker(dictionary, i, cells, borderBits=1) == 0)
            cx, cy = ox + x + cc * cell, oy + y + rr * cell
            rects.append(np.column_stack([cx, cy, cx + cell, cy + cell]))
    return np.vstack(rects)


def _spec_lines(board: Board) -> list[str]:
    """What the page says about itself: the command line that reads the board, and its geometry."""
    s = board.square_mm
    if board.is_circle_grid:
        kind = "symmetric" if board.pattern == "circles" else "asymmetric"
        return [f"--board {board.spec()} --square {s:g} --circle {board.circle_diameter_mm:g}",
                f"{kind} circle grid of {board.cols} x {board.rows} circles of {board.circle_diameter_mm:g} mm, "
                f"{s:g} mm apart "
                "(OpenCV's count and order); point 0 at the top left"]
    if board.charuco is None:
        return [f"--board {board.spec()} --square {s:g}",
                f"chessboard of {board.cols + 1} x {board.rows + 1} squares of {s:g} mm: {board.cols} x {board.rows} "
                "inner corners; corner 0 at the top left"]
    ch = board.charuco
    layout = "OpenCV's legacy layout" if ch.legacy else "OpenCV's layout (>= 4.6)"
    return [f"--board {board.spec()} --square {s:g} --marker {ch.marker_mm:g} --dictionary {ch.dictionary}",
            f"ChArUco board of {ch.squares[0]} x {ch.squares[1]} squares of {s:g} mm, markers {ch.marker_mm:g} mm, "
            f"{ch.dictionary}, {layout}: {board.cols} x {board.rows} inner corners numbered as OpenCV numbers them"]


def _figure(layout: PageLayout, dpi: float):
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch

    W, H = layout.page_mm
    fig = Figure(figsize=(W / MM_PER_INCH, H / MM_PER_INCH), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    ax.set_axis_off()
    ax.add_patch(PathPatch(_black_path(layout), facecolor="black", edgecolor="none", lw=0,
                           snap=False))          # Agg would move rectilinear edges to whole pixels

    board, (ox, oy) = layout.board, layout.origin_mm
    x0, _, y0, _ = board.pattern_extent_mm()
    bw, bh = layout.board_mm
    left, top = ox + x0, oy + y0
    bottom = top + bh
    pt = 72.0 / MM_PER_INCH                                      # points per mm
    text = dict(fontsize=3.2 * pt, color="black", va="top", ha="left", family="DejaVu Sans")
    lines = _spec_lines(board)
    y = bottom + _quiet_zone_mm(board) * 0.6
    ax.text(left, y, "dualcal board " + lines[0], fontweight="bold", **text)
    ax.text(left, y + 4.5, lines[1], **text)
    ax.text(left, y + 8.5, "Print at 100 % (actual size, not fit to page); the bar must measure its length:",
            **text)
    bar = 100.0 if bw >= 100.0 else 50.0 if bw >= 50.0 else 10.0 * np.floor(bw / 10.0)
    yb = y + 14.0
    ax.add_patch(_rect(left, yb, bar, 1.0))
    for t in np.arange(0.0, bar + 1e-9, 10.0 if bar >= 20 else 1.0):
        ax.plot([left + t, left + t], [yb, yb + (3.0 if t % 50 == 0 else 2.0)], color="black", lw=0.25 * pt)
    ax.text(left + bar + 2.0, yb - 0.8, f"{bar:g} mm", **text)
    # the board's axes from corner 0, in the quiet zone above the squares
    q = 0.45 * _quiet_zone_mm(board)
    arrow = dict(arrowstyle="-|>", color="black", lw=0.25 * pt, mutation_scale=6)
    ax.annotate("", (ox + 12.0, top - q), (ox, top - q), arrowprops=arrow)
    ax.text(ox + 13.0, top - q - 1.6, "X", **text)
    ax.annotate("", (left - q, oy + 12.0), (left - q, oy), arrowprops=arrow)
    ax.text(left - q - 1.2, oy + 13.0, "Y", **text)
    return fig


def _rect(x, y, w, h):
    from matplotlib.patches import Rectangle
    return Rectangle((x, y), w, h, facecolor="black", edgecolor="none", lw=0)


def write_board(board: Board, path, paper: str = "auto", dpi: float | None = None) -> PageLayout:
    """Write the printable board to ``path``: a PDF (vector, true scale) or a PNG at ``dpi``.

    Parameters
    ----------
    board : the board (a ChArUco board without a dictionary or layout gets the defaults of
        :func:`dualcal.geometry.board.with_default_markers`).
    path : ``*.pdf`` or ``*.png`` (written atomically).
    paper : see :func:`page_layout`.
    dpi : pixels per inch of a PNG (required for one; a PDF has none).

    Returns
    -------
    The :class:`PageLayout` drawn (where corner 0 is on the page).
    """
    from ..extras import require

    require("report")
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".pdf", ".png"):
        raise InputError(f"{path}: give a .pdf (true scale) or a .png (with --dpi) file name")
    if kind == ".png" and not (dpi and dpi > 0):
        raise InputError("a PNG needs --dpi (pixels per inch at which it is printed), e.g. --dpi 300")
    board = with_default_markers(board)
    layout = page_layout(board, paper, dpi if kind == ".png" else None)
    fig = _figure(layout, dpi or 72.0)
    meta = {"Title": f"dualcal board {_spec_lines(board)[0]}"} if kind == ".pdf" else {}
    encoded = io.BytesIO()       # in memory, so the write is checked to the last byte
    fig.savefig(encoded, format=kind[1:], dpi=dpi or 72.0, metadata=meta)
    write_bytes_atomic(path, encoded.getvalue())
    return layout
