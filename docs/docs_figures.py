"""The documentation's figures, made at build time from dualcal itself (``gen_pages.py`` runs this).

Every picture is synthetic, with known truth, and says so in its caption:

* the practice camera roll of *Getting started* as a contact sheet (the same preset, seed and positions as
  ``dualcal synth practice --roll --scale 0.25``, drawn smaller);
* the positions of *How to shoot*, good and bad, rendered by :func:`dualcal.synthetic.render.render_view`
  through a three-lens phone (``phone3``: a fisheye ultra-wide, a wide and a 3x tele);
* the report's key figures and the advice page of a calibration like the practice roll's (the report's
  own figure functions, :mod:`dualcal.pages.report`).

Each function returns ``{path in the site: bytes}``.
"""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np

#: The practice set of *Getting started*: ``dualcal synth practice --roll --scale 0.25`` (its defaults).
PRACTICE = dict(preset="note8", views=13, seed=0)


def _png(fig, dpi: int = 100) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight", pad_inches=0.05)
    return buf.getvalue()


def contact_sheet() -> dict[str, bytes]:
    """The practice roll's photos in shooting order, named as the camera roll names them."""
    from PIL import Image, ImageDraw

    from dualcal.synthetic.synth import make_truth
    from dualcal.synthetic.synth_roll import write_camera_roll

    truth = make_truth(**PRACTICE, scale=0.06)
    with tempfile.TemporaryDirectory() as tmp:
        shot = write_camera_roll(truth, Path(tmp) / "roll", seed=PRACTICE["seed"], jobs=1, progress=False)
        names = sorted(shot["photos"])
        thumbs = [Image.open(Path(tmp) / "roll" / n).convert("L") for n in names]
    w, h = thumbs[0].size
    cols, label = 10, 14
    rows = -(-len(thumbs) // cols)
    sheet = Image.new("L", (cols * (w + 6) + 6, rows * (h + label + 6) + 6), 255)
    draw = ImageDraw.Draw(sheet)
    for i, (name, thumb) in enumerate(zip(names, thumbs)):
        x, y = 6 + (i % cols) * (w + 6), 6 + (i // cols) * (h + label + 6)
        sheet.paste(thumb, (x, y))
        camera = shot["photos"][name][0] or "no board"
        draw.text((x, y + h + 1), f"{name[:8]} {camera}", fill=0)
    buf = io.BytesIO()
    sheet.save(buf, format="JPEG", quality=82)
    return {"figures/practice-roll.jpg": buf.getvalue()}


# ------------------------------------------------------------------ how to shoot

def _board_pose(truth, camera: str, fill: float, tilt_x_deg: float, tilt_y_deg: float, aim=(0.5, 0.5),
                roll_deg: float = 0.0):
    """The board's pose in the reference camera's frame: its centre on the ray of ``camera``'s pixel at ``aim``
    (fractions of the image), as far as makes the board ``fill`` of that camera's image width, tilted."""
    from dualcal.geometry.camera import pixel_rays
    from dualcal.geometry.model import Pose
    from dualcal.geometry.rotation import rotation_from_opk

    board, cam = truth.board, truth.cameras[camera]
    w, h = cam.image_size
    width_mm = (board.cols + 1) * board.square_mm
    distance = min(cam.fx, cam.fy) * width_mm / (fill * min(w, h))
    ray = pixel_rays(cam, np.array([[aim[0] * w, aim[1] * h]]))[0]
    ray = ray / np.linalg.norm(ray)
    centre_cam = ray * distance
    R_board = rotation_from_opk(np.radians([tilt_x_deg, tilt_y_deg, roll_deg]))
    middle = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0]) * board.square_mm
    seen = Pose(R_board, centre_cam - R_board @ middle)            # board -> this camera
    if camera == truth.reference:
        return seen
    to_ref = truth.rig[camera].inverse()                           # this camera -> reference
    return to_ref.compose(seen)


#: (title, camera the pose is set by, fill, tilt about x, tilt about y, aim, render options)
GOOD = [
    ("Tilted 45 degrees, its right side farther away; the tele sees it whole", "tele", 0.75, 0.0, 45.0,
     (0.5, 0.5), {}),
    ("Tilted 40 degrees the other way, its top side farther away", "tele", 0.7, -40.0, 0.0, (0.5, 0.5), {}),
    ("In a corner of the ultra-wide's frame, where its distortion is strongest (the tele misses it: fine)",
     "ultra", 0.45, 20.0, -30.0, (0.2, 0.2), {}),
]
BAD = [
    ("Square-on and small in the wide's frame: tells little about the focal length or the distortion", "wide",
     0.25, 0.0, 0.0, (0.5, 0.5), {}),
    ("Cut off by the tele's frame: its corners outside are lost, and a symmetric board is skipped", "tele", 1.35,
     0.0, 20.0, (0.5, 0.5), {}),
    ("Out of focus (or moving)", "tele", 0.7, 0.0, 30.0, (0.5, 0.5), {"blur_px": 5.0}),
    ("Glare on the board", "tele", 0.7, 0.0, -30.0, (0.5, 0.5), {"glare": True}),
]


def _render_rows(truth, rows) -> list[list[np.ndarray]]:
    from dualcal.geometry.camera import project_points
    from dualcal.synthetic.render import render_view

    order = ["ultra", "wide", "tele"]
    board = truth.board
    middle = np.array([[(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0], [0.0, 0.0, 0.0],
                       [board.cols - 1, 0.0, 0.0]]) * board.square_mm
    images = []
    for i, (_, camera, fill, tx, ty, aim, options) in enumerate(rows):
        pose = _board_pose(truth, camera, fill, tx, ty, aim)
        row = []
        for name in order:
            cam, seen = truth.cameras[name], truth.seen_by(name, pose)
            opts = {"blur_px": 0.7, **options}
            if opts.pop("glare", False):                  # a highlight on the board, a little off its centre
                (u, v), first, last = project_points(cam, seen.apply(middle))
                size = np.linalg.norm(last - first)
                opts["glare"] = [(u + 0.1 * size, v, 0.08 * size, 1.2)]
            row.append(render_view(cam, seen, board, np.random.default_rng(i), clutter=30, **opts))
        images.append(row)
    return images


def _grid_figure(truth, rows, images):
    from matplotlib.figure import Figure

    names = ["ultra", "wide", "tele"]
    h, w = images[0][0].shape[:2]
    height = len(rows) * 1.95 * h / w + 0.25
    fig = Figure(figsize=(7.2, height))
    axes = fig.subplots(len(rows), 3, squeeze=False)
    for r, (title, *_rest) in enumerate(rows):
        for c, name in enumerate(names):
            ax = axes[r][c]
            ax.imshow(images[r][c], cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"{name} ({truth.cameras[name].model})", fontsize=9)
        axes[r][0].set_ylabel("\n".join(_wrap(title, 22)), fontsize=8, rotation=0, ha="right", va="center",
                              labelpad=8)
    fig.subplots_adjust(left=0.22, right=0.99, bottom=0.01, top=1 - 0.25 / height, wspace=0.04, hspace=0.06)
    return fig


def _wrap(text: str, width: int) -> list[str]:
    import textwrap
    return textwrap.wrap(text, width)


def shooting_positions() -> dict[str, bytes]:
    """Good and bad positions of the board, through the three lenses of a phone."""
    from dualcal.synthetic.synth import make_truth

    truth = make_truth("phone3", views=1, seed=0, scale=0.1)
    out = {}
    for key, rows in (("good", GOOD), ("bad", BAD)):
        fig = _grid_figure(truth, rows, _render_rows(truth, rows))
        out[f"figures/positions-{key}.png"] = _png(fig, dpi=90)
    return out


# ------------------------------------------------------------------ a calibration's report and advice

def practice_calibration():
    """A calibration like the practice roll's: its rig's true corners with 0.01 px of noise, the paper's lens model."""
    import dualcal
    from dualcal.synthetic.synth import make_truth, noisy_corner_set

    truth = make_truth(**PRACTICE, scale=0.25)
    return dualcal.calibrate_rig(noisy_corner_set(truth, 0.01, seed=PRACTICE["seed"]))


#: The report's figures shown in the docs, by their id in the report.
REPORT_FIGURES = ("fig-view-rms", "fig-coverage-wide", "fig-residuals-tele", "fig-distortion-curve", "fig-rig-3d")


def report_figures(rig) -> dict[str, bytes]:
    """The report's key figures of ``rig``, made by the report's own functions."""
    from dualcal.pages.report import analysis, figures, html

    names = list(rig.cameras)
    jobs = html._figure_jobs(rig, names, analysis.camera_findings(rig), html._unique_slugs(names))
    out = {}
    with figures.style():
        for _, fig_id, _caption, make in jobs:
            if fig_id in REPORT_FIGURES:
                out[f"figures/report-{fig_id[4:]}.png"] = _png(make(), dpi=80)
    return out


def advice_page(rig) -> dict[str, bytes]:
    """The advice page (``advise.html``) for ``rig``'s next three photos, as ``dualcal advise`` writes it."""
    from dualcal.estimation.advise import advise, prior_from_rig
    from dualcal.pages.report.advice import render_advice_page

    advice = advise(prior_from_rig(rig), 3)
    sizes = {n: c.image_size for n, c in rig.cameras.items()}
    return {"examples/advise.html": render_advice_page(advice, sizes).encode()}


def all_figures() -> dict[str, bytes]:
    """Every figure of the documentation."""
    rig = practice_calibration()
    return {**contact_sheet(), **shooting_positions(), **report_figures(rig), **advice_page(rig)}
