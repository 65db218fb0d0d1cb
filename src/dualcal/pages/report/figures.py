"""The report's figures: matplotlib ``Figure`` objects, rendered to inline SVG.

Each ``*_figure`` function takes the numbers of :mod:`dualcal.pages.report.analysis` and returns a
:class:`matplotlib.figure.Figure` built without pyplot (no global figure registry, Agg/SVG
canvases only). :func:`figure_svg` turns one into an ``<svg>`` element ready to inline in
HTML: no XML prologue, no external reference, ids salted per figure so that several SVGs can
share one page, and the same input always gives the same bytes.

Image axes follow the pixel convention of the README: ``u`` to the right, ``v`` down, pixel
``(row i, col j)`` centred at ``(u=j, v=i)``.
"""

from __future__ import annotations

import io
import math
import re
import textwrap

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from ...geometry.board import Board
from ...geometry.camera import CameraModel, normalized_from_pixel
from ...geometry.model import Pose
from .analysis import DistortionCurve, ViewResiduals, rms_px

#: Style shared by all figures (applied only while a figure is built and saved).
STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.titleweight": "bold",
    "axes.grid": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "svg.fonttype": "none",
    "image.cmap": "viridis",
}

#: One colour per camera, in the order the rig lists them.
CAMERA_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")
_OUTLIER_COLOUR = "#d62728"


def camera_colour(index: int) -> str:
    return CAMERA_COLOURS[index % len(CAMERA_COLOURS)]


def style():
    """Context manager applying :data:`STYLE`."""
    return matplotlib.rc_context(STYLE)


def figure_svg(fig: Figure, salt: str) -> str:
    """The figure as an inline ``<svg>`` element that scales with its container.

    ``salt`` (e.g. the figure's HTML id) makes the SVG's internal ids unique on the page.
    """
    buf = io.StringIO()
    with matplotlib.rc_context({**STYLE, "svg.hashsalt": salt}):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None, "Format": None,
                                                 "Type": None})
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    # matplotlib's default-stroke <style> would apply to the whole page: the page's CSS has it.
    text = re.sub(r"<style[^>]*>.*?</style>", "", text, count=1, flags=re.S)
    # Group ids (figure_1, axes_1, ...) repeat in every figure; keep only the referenced ones.
    referenced = set(re.findall(r'url\(#([^)]+)\)|href="#([^"]+)"', text))
    referenced = {a or b for a, b in referenced}
    text = re.sub(r'\sid="([^"]+)"', lambda m: m.group(0) if m.group(1) in referenced else "", text)
    # Inline SVG in HTML needs no namespace declarations (the HTML parser supplies them), and a
    # fixed width/height would stop it from following the page width; the viewBox keeps the
    # shape and max-width keeps it from growing beyond its drawn size (pt -> CSS px: 4/3).
    head_end = text.index(">")
    width_pt = float(re.search(r'\swidth="([\d.]+)pt"', text[:head_end]).group(1))
    head = re.sub(r'\s(?:width|height|xmlns(?::\w+)?)="[^"]*"', "", text[:head_end])
    return (head + f' style="max-width: {width_pt * 4 / 3:.0f}px" preserveAspectRatio="xMidYMid meet"'
            + text[head_end:])


def _image_axes_figure(image_size: tuple[int, int], long_side_in: float = 5.2,
                       extra_width_in: float = 1.1) -> tuple[Figure, object]:
    """A figure with one axes shaped like the image (plus room for a colour bar)."""
    w, h = image_size
    scale = long_side_in / max(w, h)
    fig = Figure(figsize=(w * scale + extra_width_in, h * scale + 0.8), layout="constrained")
    ax = fig.add_subplot()
    # Pixel axes over the image: u right, v down, equal scale, the sensor outline drawn.
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.add_patch(Rectangle((-0.5, -0.5), w, h, fill=False, lw=0.8, ec="0.3"))
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    for side in ("top", "right"):
        ax.spines[side].set_visible(True)
    return fig, ax


def wrap_text(text: str, width: int) -> str:
    """``text`` broken into lines of at most ``width`` characters (long names too), for titles and labels."""
    return "\n".join(textwrap.wrap(text, width, break_long_words=True, break_on_hyphens=False)) or text


def set_title(ax, text: str) -> None:
    """A left-aligned axes title, wrapped to the width of its figure so that it is never cut off."""
    width_in = ax.figure.get_figwidth() * ax.get_position().width
    ax.set_title(wrap_text(text, max(16, int(width_in * 72 / (STYLE["axes.titlesize"] * 0.62)))), loc="left")


def _nice_length(x: float) -> float:
    """The 1, 2 or 5 times a power of ten nearest below ``x``."""
    if not x > 0:
        return 1.0
    p = 10 ** math.floor(math.log10(x))
    return max(m * p for m in (1, 2, 5) if m * p <= x)


# ---------------------------------------------------------------------------- residuals


def residual_quiver_figure(name: str, image_size: tuple[int, int],
                           residuals: dict[str, ViewResiduals]) -> Figure:
    """Residual vectors drawn at their corners over the image, magnified, with a scale bar."""
    fig, ax = _image_axes_figure(image_size)
    if not residuals:
        set_title(ax, f"{name}: no residuals")
        return fig
    uv = np.vstack([r.uv_px for r in residuals.values()])
    res = np.vstack([r.residual_px for r in residuals.values()])
    length = np.hypot(res[:, 0], res[:, 1])
    # Draw the 95th-percentile residual as 4 % of the image's long side.
    p95 = float(np.percentile(length, 95)) or 1.0
    gain = 0.04 * max(image_size) / p95
    q = ax.quiver(uv[:, 0], uv[:, 1], res[:, 0], res[:, 1], length, angles="xy", scale_units="xy",
                  scale=1.0 / gain, width=0.004, cmap="plasma")
    key = _nice_length(2 * p95)
    ax.quiverkey(q, 0.80, 1.025, key, f"{key:g} px", labelpos="W", coordinates="axes",
                 color="0.1", fontproperties={"size": 8})
    fig.colorbar(q, ax=ax, shrink=0.6, label="|residual| (px)")
    set_title(ax, f"{name}: residuals × {gain:,.0f}")
    return fig


def residual_histogram_figure(name: str, residuals: dict[str, ViewResiduals]) -> Figure:
    """Histograms of the u and v residual components with the normal curve of the same sigma."""
    fig = Figure(figsize=(5.2, 3.4), layout="constrained")
    ax = fig.add_subplot()
    if not residuals:
        set_title(ax, f"{name}: no residuals")
        return fig
    res = np.vstack([r.residual_px for r in residuals.values()])
    sd = res.std(axis=0)
    half = max(4.0 * float(sd.max()), float(np.abs(res).max()) * 1.02, 1e-6)
    bins = np.linspace(-half, half, 41)
    x = np.linspace(-half, half, 300)
    width = bins[1] - bins[0]
    for k, (label, colour) in enumerate((("du", "#1f77b4"), ("dv", "#ff7f0e"))):
        ax.hist(res[:, k], bins=bins, histtype="step", lw=1.4, color=colour,
                label=f"{label}: σ = {sd[k]:.3f} px")
        pdf = np.exp(-0.5 * (x / sd[k]) ** 2) / (sd[k] * math.sqrt(2 * math.pi)) if sd[k] > 0 else 0 * x
        ax.plot(x, pdf * len(res) * width, color=colour, lw=0.8, ls="--")
    set_title(ax, f"{name}: residual components ({len(res)} corners, RMS {rms_px(res):.3f} px)")
    ax.set_xlabel("residual (px)")
    ax.set_ylabel("corners per bin")
    ax.legend(frameon=False, fontsize=8, title="dashed: normal, same σ", title_fontsize=7.5)
    return fig


def view_rms_figure(view_rms: dict[str, dict[str, float]], camera_rms: dict[str, float],
                    outliers: dict[str, list[str]], outlier_limit_px: dict[str, float],
                    dropped_rms: dict[str, dict[str, float]], unmeasured: dict[str, list[str]]) -> Figure:
    """Per-view RMS bars grouped by view, one bar per camera, outliers and photos not used marked.

    ``view_rms[camera][view]``; ``camera_rms[camera]`` is drawn as a dashed line and
    ``outlier_limit_px[camera]`` as a dotted one; ``outliers[camera]`` lists the views above
    that limit (hatched bars). ``dropped_rms[camera][view]``: photos the calibration dropped, drawn
    as dashed outlines at the RMS they had; ``unmeasured[camera]``: photos without any RMS (board
    not found, left out), a cross on the axis. No bar is ever drawn at 0 for a photo not used.
    """
    cams = list(view_rms)
    views = sorted({v for per in (view_rms, dropped_rms) for d in per.values() for v in d}
                   | {v for vs in unmeasured.values() for v in vs})
    n = max(1, len(cams))
    fig = Figure(figsize=(min(14.0, max(7.0, 0.32 * len(views) * n + 1.5)), 3.6), layout="constrained")
    ax = fig.add_subplot()
    width = 0.8 / n
    x = np.arange(len(views))
    for i, cam in enumerate(cams):
        colour = camera_colour(i)
        pos = dict(zip(views, x - 0.4 + width * (i + 0.5)))
        kept = [v for v in views if v in view_rms[cam]]
        bars = ax.bar([pos[v] for v in kept], [view_rms[cam][v] for v in kept], width * 0.92, color=colour,
                      alpha=0.85, label=wrap_text(cam, 24))
        for bar, v in zip(bars, kept):
            if v in outliers.get(cam, ()):
                bar.set_edgecolor(_OUTLIER_COLOUR)
                bar.set_linewidth(1.6)
                bar.set_hatch("///")
                ax.annotate("!", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                            ha="center", va="bottom", color=_OUTLIER_COLOUR, fontweight="bold")
        dropped = dropped_rms.get(cam, {})
        ax.bar([pos[v] for v in dropped], list(dropped.values()), width * 0.92, fill=False, edgecolor=colour,
               linestyle="--", linewidth=1.2)
        gone = [pos[v] for v in unmeasured.get(cam, ())]
        ax.plot(gone, np.zeros(len(gone)), "x", color=colour, ms=7, mew=2, clip_on=False)
        for level, style in ((camera_rms.get(cam, math.nan), "--"), (outlier_limit_px.get(cam, math.nan), ":")):
            if math.isfinite(level):
                ax.axhline(level, color=colour, ls=style, lw=0.9)
    ax.plot([], [], color="0.4", ls="--", lw=0.9, label="overall RMS")
    ax.plot([], [], color="0.4", ls=":", lw=0.9, label="outlier limit")
    if any(outliers.values()):
        ax.bar([np.nan], [np.nan], color="white", edgecolor=_OUTLIER_COLOUR, hatch="///", label="outlier")
    if any(dropped_rms.values()):
        ax.bar([np.nan], [np.nan], fill=False, edgecolor="0.4", linestyle="--", label="dropped")
    if any(unmeasured.values()):
        ax.plot([], [], "x", color="0.4", ms=7, mew=2, label="no RMS (not found,\nleft out)")
    ax.set_xticks(x, views, rotation=60 if len(views) > 8 else 0, ha="right" if len(views) > 8 else "center",
                  fontsize=7.5)
    ax.set_xlim(-0.6, len(views) - 0.4)
    ax.set_ylim(bottom=0)
    ax.set_ylabel("RMS (px)")
    ax.set_title("RMS residual per view", loc="left")
    ax.legend(frameon=False, fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return fig


# ---------------------------------------------------------------------------- coverage


def coverage_figure(name: str, image_size: tuple[int, int], boards_uv_px: list[np.ndarray],
                    counts: np.ndarray, cell_px: float, outer_ring: float) -> Figure:
    """How many boards covered each part of the sensor, with every corner as a dot.

    The dashed circle bounds the outer ``outer_ring`` share of the half-diagonal.
    """
    fig, ax = _image_axes_figure(image_size)
    w, h = image_size
    rows, cols = counts.shape
    masked = np.ma.masked_equal(counts, 0)
    im = ax.imshow(masked, extent=(-0.5, cols * cell_px - 0.5, rows * cell_px - 0.5, -0.5),
                   interpolation="nearest", cmap="Blues", vmin=0, vmax=max(1, int(counts.max())),
                   origin="upper")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    if boards_uv_px:
        uv = np.vstack(boards_uv_px)
        ax.plot(uv[:, 0], uv[:, 1], ".", ms=1.6, color="#222", alpha=0.7)
    ax.add_patch(Circle(((w - 1) / 2, (h - 1) / 2), (1 - outer_ring) * 0.5 * math.hypot(w, h),
                        fill=False, ls="--", lw=0.9, ec="#d62728"))
    fig.colorbar(im, ax=ax, shrink=0.6, label="views covering")
    share = float(np.mean(counts > 0))
    set_title(ax, f"{name}: coverage ({len(boards_uv_px)} views, {share:.0%} of the image)")
    return fig


# ---------------------------------------------------------------------------- distortion


def distortion_curve_figure(curves: dict[str, DistortionCurve], reach_px: dict[str, float]) -> Figure:
    """Radial displacement (px) against the observed radius (px), one line per camera.

    The curve is solid out to the farthest corner actually observed (a dot and a dotted line
    mark it) and dashed beyond, where it is extrapolated. A cross marks where the model folds
    over (undistortion no longer unique).
    """
    fig = Figure(figsize=(5.6, 3.6), layout="constrained")
    ax = fig.add_subplot()
    for i, (name, c) in enumerate(curves.items()):
        colour = camera_colour(i)
        reach = reach_px.get(name, math.nan)
        seen = c.radius_px <= reach if math.isfinite(reach) else np.zeros(len(c.radius_px), bool)
        ax.plot(c.radius_px[seen], c.shift_px[seen], color=colour, lw=1.8, label=wrap_text(name, 24))
        ax.plot(c.radius_px[~seen], c.shift_px[~seen], color=colour, lw=1.0, ls="--")
        if seen.any():
            ax.axvline(reach, color=colour, ls=":", lw=1.0)
            ax.plot(c.radius_px[seen][-1], c.shift_px[seen][-1], "o", color=colour, ms=5)
        if c.fold_radius_px is not None:
            ax.plot(c.radius_px[-1], c.shift_px[-1], "x", color=colour, ms=8, mew=2)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlim(left=0)
    ax.set_xlabel("distance from the principal point (px)")
    ax.set_ylabel("radial displacement (px)")
    ax.set_title("Radial distortion out to the image corner", loc="left")
    ax.legend(frameon=False, fontsize=8, title="solid to the last observed corner (•, dotted),\n"
              "dashed beyond: extrapolated", title_fontsize=7.5)
    return fig


def distortion_map_figure(name: str, camera: CameraModel, u: np.ndarray, v: np.ndarray,
                          displacement: np.ndarray) -> Figure:
    """Contours of the distortion's length (px) over the image, principal point marked."""
    fig, ax = _image_axes_figure(camera.image_size)
    finite = displacement[np.isfinite(displacement)]
    top = float(finite.max()) if finite.size else 1.0
    levels = MaxNLocator(nbins=10).tick_values(0.0, max(top, 1e-3))
    cf = ax.contourf(u, v, displacement, levels=levels, cmap="magma_r")
    cs = ax.contour(u, v, displacement, levels=levels[1:-1:2], colors="0.15", linewidths=0.6)
    ax.clabel(cs, fmt="%g", fontsize=7)
    ax.plot(camera.cx, camera.cy, "+", color="#1f77b4", ms=10, mew=1.6)
    fig.colorbar(cf, ax=ax, shrink=0.6, label="distortion (px)")
    set_title(ax, f"{name}: distortion over the image")
    return fig


# ---------------------------------------------------------------------------- rig in 3-D


def _to_plot(X: np.ndarray) -> np.ndarray:
    """Camera frame (x right, y down, z forward) -> plot axes (x, z, -y): up is up."""
    X = np.asarray(X, float)
    return np.stack([X[..., 0], X[..., 2], -X[..., 1]], axis=-1)


def _frustum(camera: CameraModel, frame: Pose, depth_mm: float) -> np.ndarray:
    """(5, 3) apex and the four image corners at ``depth_mm``, in the reference frame."""
    w, h = camera.image_size
    uv = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    base = np.column_stack([normalized_from_pixel(camera, uv), np.ones(4)]) * depth_mm
    return frame.apply(np.vstack([np.zeros(3), base]))


def rig_figure(board: Board, board_poses: dict[str, Pose], cameras: dict[str, CameraModel],
               frames: dict[str, Pose], reference: str) -> Figure:
    """The board in every view and the rig's cameras, in the reference camera frame (mm).

    Left: 3-D view (plot axes x, z, -y so that up is up). Right, when there is more than one
    camera: the perspective centres ``C = -R^T t`` seen from the front (x right, y down), where the
    rig's few millimetres are visible, each labelled with its coordinates as the report's table
    gives them.
    ``frames[camera]`` maps that camera's frame to the reference frame (camera -> reference).
    """
    centres = len(frames) > 1
    fig = Figure(figsize=(10.5 if centres else 7.0, 5.2), layout="constrained")
    gs = fig.add_gridspec(1, 3 if centres else 1)
    colours = {name: camera_colour(i) for i, name in enumerate(cameras)}
    ax3d = fig.add_subplot(gs[0, :2] if centres else gs[0, 0], projection="3d")
    _draw_rig_3d(ax3d, board, board_poses, cameras, frames, colours)
    set_title(ax3d, f"Board poses and cameras in the {reference} camera frame")
    if centres:
        _draw_centres(fig.add_subplot(gs[0, 2]), {n: f.t_mm for n, f in frames.items()}, reference, colours)
    return fig


def _draw_rig_3d(ax, board: Board, board_poses: dict[str, Pose], cameras: dict[str, CameraModel],
                 frames: dict[str, Pose], colours: dict[str, str]) -> None:
    """Board outlines (outer ring included) coloured by view, and a frustum per camera."""
    s = board.square_mm
    outline = np.array([[-s, -s, 0], [board.cols * s, -s, 0], [board.cols * s, board.rows * s, 0],
                        [-s, board.rows * s, 0]], float)
    pts = [np.zeros((1, 3))]
    cmap = matplotlib.colormaps["viridis"]
    for k, (view, pose) in enumerate(board_poses.items()):
        quad = pose.apply(outline)
        pts.append(quad)
        colour = cmap(k / max(1, len(board_poses) - 1))
        ax.add_collection3d(Poly3DCollection([_to_plot(quad)], facecolor=(*colour[:3], 0.12),
                                             edgecolor=colour, linewidths=0.9))
        ax.text(*_to_plot(pose.t_mm), view, fontsize=6, color=colour[:3])   # at board corner 0
    depth = 0.12 * float(np.median([np.linalg.norm(p.t_mm) for p in board_poses.values()] or [100.0]))
    for name, frame in frames.items():
        f = _frustum(cameras[name], frame, depth)
        pts.append(f)
        p = _to_plot(f)
        for j in range(1, 5):
            ax.plot(*zip(p[0], p[j]), color=colours[name], lw=1.0)
        ax.plot(*np.vstack([p[1:], p[1:2]]).T, color=colours[name], lw=1.4, label=wrap_text(name, 24))
    allp = _to_plot(np.vstack(pts))
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    span = np.maximum(hi - lo, 1e-6)
    ax.set_box_aspect(tuple(span / span.max()), zoom=1.15)     # equal scale on all three axes
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(nbins=4))
    ax.tick_params(labelsize=7, pad=0)
    ax.set_xlabel("x (mm)", labelpad=-2)
    ax.set_ylabel("z (mm, forward)", labelpad=2)
    ax.set_zlabel("−y (mm, up)", labelpad=-2)
    ax.view_init(elev=24, azim=-58)
    ax.legend(loc="upper left", frameon=False, fontsize=8, title="cameras", title_fontsize=8)


def _draw_centres(ax, centres_mm: dict[str, np.ndarray], reference: str, colours: dict[str, str]) -> None:
    """Perspective centres (reference frame, mm) seen from the front, baselines to the reference."""
    ref = centres_mm[reference]
    xy = np.array(list(centres_mm.values()))[:, :2]
    mid = (xy.min(axis=0) + xy.max(axis=0)) / 2
    for name, c in centres_mm.items():
        ax.plot(c[0], c[1], "o", color=colours[name], ms=8)
        right = c[0] <= mid[0]            # label towards the middle, so it stays inside the axes
        ax.annotate(f"{wrap_text(name, 18)}\nC = ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f})", (c[0], c[1]),
                    textcoords="offset points", xytext=(6 if right else -6, 4), ha="left" if right else "right",
                    fontsize=7.5, color=colours[name])
        if name != reference:
            ax.plot([ref[0], c[0]], [ref[1], c[1]], color="0.5", lw=0.8, ls="--")
            half_way = (ref + c) / 2
            ax.annotate(f"D = {np.linalg.norm(c - ref):.2f} mm", (half_way[0], half_way[1]),
                        textcoords="offset points", xytext=(6, -10), fontsize=8, color="0.25")
    half = max(3.0, 0.7 * float(np.ptp(xy, axis=0).max()))
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] + half, mid[1] - half)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm, down)")
    set_title(ax, f"Perspective centres C (mm) in the {reference} frame, front view")
