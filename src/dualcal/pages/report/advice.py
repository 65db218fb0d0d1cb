"""The advice page (``advise.html``) and the report's advice section: where to hold the board next.

For every advised pose and every camera, an inline SVG of that camera's frame with the board's
outline drawn where it must appear (through the lens), the pose in words and the sigmas before
and after. No script, no link outside the page.
"""

from __future__ import annotations

import re

import numpy as np
from markupsafe import Markup, escape

from ... import __version__
from ...estimation.advise import Advice, describe, key_targets
from .templating import environment

#: The drawing's width in CSS pixels; its height follows the frame's aspect.
FRAME_WIDTH = 220


def frame_svg(image_size: tuple[int, int], outline_px: np.ndarray | None, camera: str, pose_index: int,
              sees: bool) -> Markup:
    """One camera's frame with the board's outline (a polygon of class ``board-outline``)."""
    w, h = image_size
    height = FRAME_WIDTH * h / w
    clip = f"clip-{pose_index}-{re.sub(r'[^A-Za-z0-9_-]', '-', camera)}"      # an id: no spaces or quotes
    stroke = max(w, h) / 150
    parts = [f'<svg viewBox="0 0 {w} {h}" width="{FRAME_WIDTH}" height="{height:.0f}" role="img" '
             f'aria-label="board in {escape(camera)}, pose {pose_index}" xmlns="http://www.w3.org/2000/svg">',
             f'<rect x="0" y="0" width="{w}" height="{h}" fill="#f4f6f9" stroke="#5b6473" stroke-width="{stroke:.1f}"/>',
             f'<clipPath id="{clip}"><rect width="{w}" height="{h}"/></clipPath>']
    if outline_px is not None:
        pts = " ".join(f"{u:.1f},{v:.1f}" for u, v in np.asarray(outline_px))
        colour = "#1f5fa8" if sees else "#c0392b"
        dash = "" if sees else f' stroke-dasharray="{3 * stroke:.0f}"'
        parts.append(f'<polygon class="board-outline" data-camera="{escape(camera)}" data-pose="{pose_index}" '
                     f'points="{pts}" fill="{colour}" fill-opacity="0.18" stroke="{colour}" '
                     f'stroke-width="{stroke:.1f}"{dash} clip-path="url(#{clip})"/>')
        corner0 = np.asarray(outline_px)[0]
        parts.append(f'<circle cx="{corner0[0]:.1f}" cy="{corner0[1]:.1f}" r="{3 * stroke:.1f}" fill="{colour}"/>')
    parts.append("</svg>")
    return Markup("".join(parts))


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def advice_context(advice: Advice, image_sizes: dict[str, tuple[int, int]]) -> dict:
    """What the advice's templates show: one card per pose and the sigma table."""
    cameras = sorted(image_sizes, key=lambda n: n != advice.frame)       # the reference camera first
    cards = []
    for i, pose in enumerate(advice.poses, start=1):
        frames = [{"camera": n, "sees": n in pose.cameras,
                   "svg": frame_svg(image_sizes[n], pose.outline_px.get(n), n, i, n in pose.cameras)}
                  for n in cameras]
        cards.append({"index": i, "words": describe(pose), "cameras": ", ".join(pose.cameras),
                      "gain": f"{100 * pose.gain:.0f} %", "frames": frames})
    shown = list(advice.goals) or [n for group in key_targets(advice.current_sigma).values() for n in group]
    shown.sort(key=lambda n: n.split(".")[0] != advice.frame)              # stable: the reference camera first
    rows = [{"name": n, "now": _fmt(advice.current_sigma[n]), "goal": _fmt(advice.goals[n]) if n in advice.goals else "",
             "after": [_fmt(p.predicted_sigma[n]) for p in advice.poses]} for n in shown]
    return {"cards": cards, "rows": rows, "done": advice.done, "next_gain": f"{100 * advice.next_gain:.1f} %",
            "has_goals": bool(advice.goals), "frame": advice.frame}


def render_advice_page(advice: Advice, image_sizes: dict[str, tuple[int, int]], title: str = "") -> str:
    """The self-contained advise.html."""
    return environment().get_template("advise.html").render(
        title=title or f"dualcal advice: {' + '.join(image_sizes)}", version=__version__,
        advice=advice_context(advice, image_sizes))
