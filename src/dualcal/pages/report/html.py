"""Assemble the self-contained HTML report from a calibrated rig (and an evaluation).

:func:`render_report` computes the report's numbers (:mod:`.analysis`), draws its figures
(:mod:`.figures`) and fills ``templates/report.html`` with jinja2. The page needs nothing
else: CSS is inline, figures are inline SVG (raster parts embedded as ``data:`` PNG), there
is no script and no link to anything outside the file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from markupsafe import Markup

from ... import __version__
from ...geometry.board import SHAPE_TERMS
from ...estimation.outliers import OUTLIER_FLOOR_PX
from ...geometry.camera import INTRINSIC_NAMES, intrinsic_names
from ...estimation.checks import check_limits, verdict
from ...geometry.model import RigModel
from ...progress import track
from ...geometry.scale import relative_sigma, scale_share
from . import analysis, figures
from ..photos import photo_quality, photo_rows, photo_status
from .templating import environment

#: Intrinsic parameters: label with the paper's name (Tables 2 and 3) and unit.
PARAMETER_LABELS = {"fx": "f<sub>x</sub> = α (px)", "fy": "f<sub>y</sub> = β (px)", "skew": "skew = γ (px)",
                    "cx": "c<sub>x</sub> = u<sub>0</sub> (px)", "cy": "c<sub>y</sub> = v<sub>0</sub> (px)",
                    "k1": "k<sub>1</sub>", "k2": "k<sub>2</sub>", "p1": "p<sub>1</sub>", "p2": "p<sub>2</sub>",
                    "k3": "k<sub>3</sub>", "k4": "k<sub>4</sub>"}

#: Plain labels of the adjustment's numbers (calib.json ``adjustment``), in the order shown.
ADJUSTMENT_LABELS = {
    "s0_px": "a-posteriori σ of a corner coordinate, s0 (px)",
    "redundancy": "redundancy (observations − unknowns + constraints)",
    "n_observations": "observations (corner coordinates)",
    "n_parameters": "unknowns",
    "held_out_rms_px": "RMS error of an instant left out of the calibration (px, per corner)",
    "n_constraints": "constraints (the paper's, rig mode paper)",
    "iterations": "iterations",
    "converged": "converged",
    "termination": "why the solver stopped",
}


#: Plain words for the rig modes (calib.json ``rig_mode``).
RIG_MODE_LABELS = {"rigid": "rigid: one relative pose per camera",
                   "paper": "paper: poses per view, equal baseline and angles",
                   "none": "none: each camera alone", "truth": "synthetic truth"}


@dataclass
class FigureBlock:
    """One figure on the page: its HTML id, caption and inline SVG."""

    id: str
    caption: str
    svg: Markup


@dataclass
class CameraSection:
    """The figures of one camera."""

    name: str
    slug: str
    figures: list[FigureBlock] = field(default_factory=list)


def slug(name: str) -> str:
    """A string usable in an HTML id: lower case letters, digits and dashes."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "camera"


def _unique_slugs(names) -> dict[str, str]:
    out, used = {}, set()
    for name in names:
        base = s = slug(name)
        k = 2
        while s in used:
            s, k = f"{base}-{k}", k + 1
        used.add(s)
        out[name] = s
    return out


# ---------------------------------------------------------------------------- tables


def _cell(value: float, sigma: float, formal: float | None = None) -> dict:
    """A value ± its sigma, and the textbook sigma (``formal``, None where unknown) to the sigma's digits."""
    v, sig = analysis.format_value_sigma(value, sigma)
    cell = {"value": v, "sigma": sig, "formal": None}
    if formal is not None and math.isfinite(formal) and math.isfinite(sigma) and sigma > 0:
        digits = len(sig.split(".")[1]) if "." in sig else 0
        cell["formal"] = f"{formal:.{digits}f}"
    return cell


def intrinsics_table(rig: RigModel, names: list[str]) -> list[dict]:
    """Rows of the intrinsics table (paper Tables 2-3): one row per parameter of any camera's lens model,
    a cell per camera (empty where its model lacks the parameter)."""
    params = [p for p in INTRINSIC_NAMES if any(p in intrinsic_names(rig.cameras[n].model) for n in names)]

    def cell(name, p):
        if p not in intrinsic_names(rig.cameras[name].model):
            return {"value": "–", "sigma": "", "formal": None}
        return _cell(getattr(rig.cameras[name], p), rig.camera_sigma.get(name, {}).get(p, math.nan),
                     rig.camera_sigma_formal.get(name, {}).get(p))
    return [{"label": Markup(PARAMETER_LABELS[p]), "cells": [cell(name, p) for name in names]} for p in params]


def lens_model_choice(rig: RigModel) -> dict | None:
    """The per-camera comparison of ``--model auto`` (``adjustment["lens_models_chosen"]``) as
    ``{"models": [...], "rows": [{"camera", "cells": [text, ...]}]}``, None without one."""
    from ...estimation.model_selection import lens_model_grid

    if not rig.adjustment.get("lens_models_chosen"):
        return None
    models, grid = lens_model_grid(rig.adjustment)

    def text(c):
        return f"{c['held_out_rms_px']:.4f} ({c['worse_se']:.1f})" + (" chosen" if c["chosen"] else "") if c else "–"

    return {"models": models, "rows": [{"camera": name, "cells": [text(c) for c in cells]} for name, cells in grid]}


def rig_table(rig: RigModel) -> tuple[list[str], list[dict]]:
    """The relative orientation (paper Table 4, plus t and the perspective centre): camera columns, rows.

    One column per non-reference camera; rows D, omega, phi, kappa, t and ``C = -R^T t``, the
    camera's perspective centre in the reference frame (what the rig figure draws; no sigma).
    """
    names = list(rig.rig)

    def formal(r, key, i=None):
        value = r.sigma_formal.get(key)
        return None if value is None else float(value if i is None else value[i])
    quantities = [("baseline D (mm)", lambda r: (r.baseline_mm, r.sigma_baseline_mm, formal(r, "baseline_mm")))]
    for i, a in enumerate(("ω", "φ", "κ")):
        quantities.append((f"{a} (′)", lambda r, i=i: (r.pose.opk_arcmin[i], r.sigma_opk_arcmin[i],
                                                       formal(r, "opk_arcmin", i))))
    for i, a in enumerate("xyz"):
        quantities.append((f"t<sub>{a}</sub> (mm)", lambda r, i=i: (r.pose.t_mm[i], r.sigma_t_mm[i],
                                                                   formal(r, "t_mm", i))))
    for i, a in enumerate("XYZ"):
        quantities.append((f"centre C<sub>{a}</sub> (mm)", lambda r, i=i: (r.pose.center_mm[i], math.nan)))
    rel = relative_sigma(rig.board)
    if rel:     # how much of a length's sigma the printed squares' tolerance is (dualcal.geometry.scale)
        quantities.insert(1, (f"share of σ<sub>D</sub><sup>2</sup> from the squares' ±{rig.board.square_sigma_mm:g} mm "
                              "(%)", lambda r: (100 * float(scale_share(r.sigma_baseline_mm, r.baseline_mm, rel)),
                                                math.nan)))
    rows = [{"label": Markup(label), "cells": [_cell(*get(rig.rig[n])) for n in names]} for label, get in quantities]
    return names, rows


def evaluation_table(evaluation: dict | None) -> list[dict]:
    """Rows of the evaluation table (paper Tables 5-6): case, RMSE X, Y, Z (mm), 3-D, pairs."""
    if not evaluation:
        return []
    rows = []
    for case, entry in evaluation.get("cases", {}).items():
        rmse = [float(x) for x in entry.get("rmse_mm", [math.nan] * 3)]
        total = math.sqrt(sum(x * x for x in rmse))
        dual = case == "dual" or case.startswith("dual:")
        label = "two cameras, same instant" if dual else f"{case} camera, two instants"
        rows.append({"case": case, "label": label, "rmse": [f"{x:.3f}" for x in rmse],
                     "total": f"{total:.3f}", "pairs": entry.get("pairs", "–")})
    return rows


def pose_free_table(evaluation: dict | None) -> list[dict]:
    """Rows of the pose-free length check (eval.json ``pose_free``): case, RMS and largest length error (mm),
    lengths and instants; empty for an eval.json without it."""
    rows = []
    for case, entry in (evaluation or {}).get("pose_free", {}).items():
        rows.append({"case": case, "rms": f"{entry['rms_mm']:.3f}", "max": f"{entry['max_mm']:.3f}",
                     "lengths": entry["lengths"], "instants": entry["instants"]})
    return rows


def photos_table(rig: RigModel, names: list[str]) -> list[dict]:
    """Every photo: RMS per camera (px), blur and corner noise per camera (px) where the detection measured them,
    and, for a photo not kept, why, and which are blurred (:func:`dualcal.pages.photos.photo_status`,
    :func:`dualcal.pages.photos.photo_quality`)."""
    quality = photo_quality(rig)
    return [{"view": view, "cells": cells, "status": note}
            for view, cells, note in photo_rows(photo_status(rig), names, missing="–", quality=quality or None)]


SOURCE_FORMAT_LABELS = {"dng": "RAW (DNG): the sensor's pixels", "jpeg": "JPEG: the phone's processed photo",
                        "heic": "HEIC: the phone's processed photo", "png": "PNG", "tiff": "TIFF"}


def source_formats(rig: RigModel, names: list[str]) -> dict[str, str] | None:
    """``{camera: what its photos were}`` (corners.json ``meta.source_format``), or None where
    the corners do not say (written before dualcal recorded it, or synthetic)."""
    kinds = {n: rig.corners.cameras[n].meta.get("source_format") for n in names}
    if not any(kinds.values()):
        return None
    return {n: ", ".join(SOURCE_FORMAT_LABELS.get(k, k) for k in (kinds[n] or "?").split(",")) for n in names}


def checks_table(rig: RigModel) -> list[dict]:
    """The calibration's checks (calib.json ``checks``): name, passed or not, the message, and its statistic,
    limit and false-alarm rate (:func:`dualcal.estimation.checks.check_limits`)."""
    return [{"name": name, "ok": bool(check.get("ok", True)), "message": check.get("message", ""),
             **check_limits(check)} for name, check in rig.checks.items()]


def loops_table(rig: RigModel) -> list[dict]:
    """The ``loop_closure`` check's loops (misclosure and its sigma, norm over the three axes) and pairs."""
    check = rig.checks.get("loop_closure")
    if not check:
        return []
    rows = []
    for name, lp in check.get("loops", {}).items():
        rows.append({"name": name, "ok": lp["ok"], "stat": f"{lp['t2']:.1f} ({lp['limit']:.1f})",
                     "rotation": f"{np.linalg.norm(lp['rotation_arcmin']):.3f} ± {np.linalg.norm(lp['sigma_rotation_arcmin']):.3f}",
                     "t": f"{np.linalg.norm(lp['t_mm']):.4f} ± {np.linalg.norm(lp['sigma_t_mm']):.4f}"})
    for name, pair in check.get("pairs", {}).items():
        stat = f"{pair['ratio']:.2f} x the noise" if "ratio" in pair else pair.get("message", "")
        rows.append({"name": f"pair {name} ({pair['views']} instants)", "ok": pair["ok"], "rotation": "–", "t": "–",
                     "stat": stat})
    return rows


def board_shape_text(rig: RigModel) -> dict | None:
    """The board's shape, where the calibration estimated it: ``{"sag_mm", "text"}``."""
    if rig.board_shape_mm is None:
        return None
    sag = rig.board_sag_mm()
    terms = ", ".join(f"{t} {w:+.2f} ± {s:.2f} mm" for t, w, s in
                      zip(SHAPE_TERMS, rig.board_shape_mm, rig.board_shape_sigma_mm))
    return {"sag_mm": sag, "text": f"its corners are up to {sag:.2f} mm off a plane (the heights reached at "
                                   f"the edges and corners of the grid by its sag, bend and twist: {terms})"}


def adjustment_rows(rig: RigModel) -> list[tuple[str, str]]:
    """The adjustment's numbers and the options it ran with, with plain labels."""
    adj, options = rig.adjustment, rig.calibration_options()
    rows = []
    for key, label in ADJUSTMENT_LABELS.items():
        value = adj.get(key)
        if value is None or (key == "n_constraints" and not value):
            continue
        if isinstance(value, bool):
            value = "yes" if value else "no"
        elif isinstance(value, float):
            value = f"{value:.4g}"
        rows.append((label, str(value)))
    rows.append(("outliers", f"corners above {options['outlier_factor']:g}× the camera's median residual left out, "
                             "photos where most corners are dropped"
                 if options["drop_outliers"] else "all kept (--keep-outliers)"))
    return rows


# ---------------------------------------------------------------------------- the page


def _not_kept(rig: RigModel, names: list[str]) -> tuple[dict, dict]:
    """``dropped[camera][view] -> RMS`` and ``unmeasured[camera] -> views`` for the per-view figure."""
    dropped: dict[str, dict[str, float]] = {n: {} for n in names}
    unmeasured: dict[str, list[str]] = {n: [] for n in names}
    for view, per in photo_status(rig).items():
        for n, (rms, status) in per.items():
            if status.startswith("dropped") and rms is not None:
                dropped[n][view] = rms
            elif status != "kept":
                unmeasured[n].append(view)
    return dropped, unmeasured


def _figure_jobs(rig: RigModel, names: list[str], found: dict[str, analysis.CameraFindings],
                 slugs: dict[str, str]) -> list[tuple]:
    """``(camera or None, HTML id, caption, figure factory)`` of every figure, in page order."""
    cameras = {name: rig.cameras[name] for name in names}
    options = rig.calibration_options()
    jobs = []
    for name, camera in cameras.items():
        f, s = found[name], slugs[name]
        jobs += [
            (name, f"fig-residuals-{s}",
             f"Residual vectors of the {name} camera (observed − projected), magnified; "
             "the arrow at the top is the scale bar.",
             lambda n=name, c=camera, f=f: figures.residual_quiver_figure(n, c.image_size, f.residuals)),
            (name, f"fig-histogram-{s}",
             f"Histogram of the {name} camera's residual components.",
             lambda n=name, f=f: figures.residual_histogram_figure(n, f.residuals)),
            (name, f"fig-coverage-{s}",
             f"Coverage of the {name} sensor: how many boards covered each cell, corners as dots; "
             f"outside the dashed circle lies the outer {analysis.OUTER_RING:.0%} of the image.",
             lambda n=name, c=camera, f=f: figures.coverage_figure(
                 n, c.image_size, f.boards_uv_px, f.coverage, f.coverage_cell_px, analysis.OUTER_RING)),
            (name, f"fig-distortion-map-{s}",
             f"Distortion of the {name} camera over the image (px between observed and ideal "
             "position); + marks the principal point.",
             lambda n=name, c=camera: figures.distortion_map_figure(n, c, *analysis.displacement_map(c))),
        ]
    jobs += [
        (None, "fig-view-rms",
         f"RMS residual of every view, per camera; hatched bars are outliers, views above their camera's "
         f"outlier limit for one corner (dotted): {options['outlier_factor']:g}× the median residual of the "
         f"camera's corners, but at least {OUTLIER_FLOOR_PX:g} px (the calibration leaves out corners above it, "
         "and drops a photo where most of its corners are)"
         f"{'' if options['drop_outliers'] else ' (this one kept them all: --keep-outliers)'}. "
         "Dashed outlines are photos the calibration dropped, at the RMS they had; × marks a photo with no "
         "RMS (board not found, or left out); the table of photos says why.",
         lambda: figures.view_rms_figure({n: found[n].view_rms_px for n in names},
                                         {n: found[n].rms_px for n in names},
                                         {n: found[n].outliers for n in names},
                                         {n: found[n].outlier_limit_px for n in names},
                                         *_not_kept(rig, names))),
        (None, "fig-distortion-curve",
         "Radial distortion (paper eq. 13; of a fisheye, against the pinhole image of the same ray) against "
         "the distance from the principal point, out to "
         "the farthest image corner: solid where corners were observed, dashed beyond the last one "
         "(dot and dotted line), where the model is extrapolated."
         + (" This is the radial part of the lens only: its tangential terms (p1, p2) move points "
            "across the radius, so they have no curve along it; each camera's distortion map shows the "
            "whole lens." if any(cam.tangential for cam in cameras.values()) else ""),
         lambda: figures.distortion_curve_figure({n: found[n].curve for n in names},
                                                 {n: found[n].reach_px for n in names})),
        (None, "fig-rig-3d",
         f"Board poses and cameras in the reference ({rig.reference}) camera frame, mm"
         + ("; right: the perspective centres C = −Rᵀt seen from the front, as in the relative orientation "
            "table." if rig.rig else "."),
         lambda: figures.rig_figure(rig.board, rig.reference_poses(), cameras,
                                    analysis.rig_camera_frames(rig), rig.reference)),
    ]
    return jobs


def advice_section(rig: RigModel, count: int = 3) -> dict | None:
    """The next photos to take (:mod:`dualcal.estimation.advise`), as the page shows them; None where the
    calibration holds no covariance to advise from."""
    from ...estimation.advise import advise, prior_from_rig
    from ...errors import InputError
    from .advice import advice_context
    try:
        advice = advise(prior_from_rig(rig), count)
    except InputError:
        return None
    return advice_context(advice, {n: c.image_size for n, c in rig.cameras.items()})


def render_report(rig: RigModel, evaluation: dict | None = None, title: str | None = None,
                  progress: bool = False) -> str:
    """The HTML report of a calibrated rig, as one self-contained string.

    Parameters
    ----------
    rig : RigModel
        the calibration (content of calib.json); residuals are recomputed from its corners
        and poses
    evaluation : dict or None
        the content of an eval.json, or None to leave the evaluation section out
    title : str or None
        page title; default names the cameras
    progress : bool
        draw a progress bar on stderr while the figures are rendered

    Returns
    -------
    str
        The page's HTML, with every figure inline: it needs no other file.
    """
    names = rig.camera_order()
    found = analysis.camera_findings(rig)
    slugs = _unique_slugs(names)
    sections = {name: CameraSection(name, slugs[name]) for name in names}
    shared = {}
    with figures.style():
        for key, fig_id, caption, make in track(_figure_jobs(rig, names, found, slugs), "rendering figures",
                                                enabled=progress):
            block = FigureBlock(fig_id, caption, Markup(figures.figure_svg(make(), fig_id)))
            if key is None:
                shared[fig_id] = block
            else:
                sections[key].figures.append(block)

    env = environment()
    return env.get_template("report.html").render(
        title=title or f"dualcal calibration: {' + '.join(names)}",
        version=__version__,
        rig=rig,
        camera_names=names,
        found=found,
        intrinsics=intrinsics_table(rig, names),
        rig_table=rig_table(rig),
        photos=photos_table(rig, names),
        photo_quality_names=names if photo_quality(rig) else [],
        source_formats=source_formats(rig, names),
        evaluation=evaluation_table(evaluation),
        pose_free=pose_free_table(evaluation),
        evaluation_kind=("hold-out: each view oriented by a calibration that left it out"
                         if evaluation and evaluation.get("holdout")
                         else "photos oriented by the calibration's own poses"),
        adjustment=adjustment_rows(rig),
        lens_models=None if "lens_models_chosen" in rig.adjustment else rig.adjustment.get("lens_models"),
        lens_model_choice=lens_model_choice(rig),
        model=rig.model,
        checks=checks_table(rig),
        loops=loops_table(rig),
        verdict=verdict(rig.checks) if rig.checks else None,
        board_shape=board_shape_text(rig),
        hints=[h for n in names for h in found[n].hints],
        sections=list(sections.values()),
        shared=shared,
        skew_model="Model 2: skew free" if rig.skew else "Model 1: skew fixed to 0",
        rig_mode=RIG_MODE_LABELS.get(rig.rig_mode, rig.rig_mode),
        advice=advice_section(rig),
    )
