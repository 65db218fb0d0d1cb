"""The paper's result tables (Tables 2-4) and the per-photo table, as rich tables for the terminal.

Table 2/3: intrinsics and radial distortion of each camera, value +- sigma, Model 1 (skew = 0)
next to Model 2 (skew free). ``sigma`` is the one that holds on real photos (from the scatter
between the instants, never below the textbook one, which calib.json keeps as ``sigma_formal``):
one standard deviation of the value, while RMS values are of the 2-D length of a corner's residual.
Table 4: the rig, distance D between perspective centres (mm) and the relative angles (minutes of
arc), for every non-reference camera. :func:`photo_table`: every photo of the calibration, its RMS
per camera and whether it was kept, dropped or left out, and why.
"""

from __future__ import annotations

from rich import box
from rich.cells import cell_len
from rich.table import Table

from ..geometry.camera import DISTORTION_NAMES, FISHEYE_MODELS, INTRINSIC_NAMES, intrinsic_names
from ..geometry.model import RigModel
from ..pages.photos import photo_quality, photo_rows, photo_status
from ..geometry.scale import relative_sigma, scale_share
from ..terminal import printable

_PAPER_NAMES = {"fx": "alpha = fx", "fy": "beta = fy", "skew": "gamma = skew", "cx": "u0 = cx",
                "cy": "v0 = cy", "k1": "k1", "k2": "k2", "p1": "p1", "p2": "p2", "k3": "k3", "k4": "k4"}


def _measured(t: Table) -> Table:
    """``t`` with the width of each column that does not wrap given as its widest cell's (its header's included),
    where every cell is a one-line string: the widths rich measures, given so that it does not measure every cell
    once more as it renders (a table of 50 rows renders in two thirds of the time; the same text)."""
    for column in t.columns:
        cells = [column.header, *column.cells]
        if column.no_wrap and column.width is None and all(isinstance(c, str) and "\n" not in c for c in cells):
            column.width = max(cell_len(printable(c)) for c in cells)
    return t


def _pm(value: float, sigma: float, digits: int) -> tuple[str, str]:
    return f"{value:.{digits}f}", ("-" if sigma == 0 else f"{sigma:.{digits}f}")


def _model_label(rig: RigModel) -> str:
    return "Model 2 (skew free)" if rig.skew else "Model 1 (skew = 0)"


def camera_table(name: str, models: list[RigModel]) -> Table:
    """Intrinsics of camera ``name`` in each model (the paper's Tables 2 and 3)."""
    lens = {m.cameras[name].model for m in models}
    kind = "radial" if lens <= {"k1k2", "k1k2k3"} else "fisheye" if lens <= FISHEYE_MODELS else "lens"
    t = Table(title=f"Camera {name!r}: intrinsics (px) and {kind} distortion ({', '.join(sorted(lens))}), 1 sigma",
              box=box.SIMPLE_HEAD,
              caption=_SIGMA_CAPTION)
    t.add_column("parameter")
    for m in models:
        t.add_column(f"{_model_label(m)}", justify="right")
        t.add_column("sigma", justify="right")
    for p in [p for p in INTRINSIC_NAMES if any(p in intrinsic_names(model) for model in lens)]:
        digits = 5 if p in DISTORTION_NAMES else 3
        row = [_PAPER_NAMES[p]]
        for m in models:
            row += _pm(getattr(m.cameras[name], p), m.camera_sigma[name][p], digits)
        t.add_row(*row)
    t.add_row("RMS (px, 2-D)", *[x for m in models for x in (f"{m.camera_rms_px[name]:.3f}", "")])
    return t


_SIGMA_CAPTION = ("sigma: from the scatter between the instants, never below the textbook value "
                  "(calib.json: sigma_formal); RMS: of each corner's 2-D residual")


def rig_table(models: list[RigModel]) -> Table | None:
    """Distance and relative angles of every non-reference camera (the paper's Table 4)."""
    first = models[0]
    if not first.rig:
        return None
    t = Table(title=f"Rig relative to {first.reference!r}: D (mm) and angles (minutes of arc), 1 sigma",
              box=box.SIMPLE_HEAD, caption=_SIGMA_CAPTION)
    rel = relative_sigma(first.board)
    t.add_column("camera")
    t.add_column("value")
    for m in models:
        t.add_column(_model_label(m), justify="right")
        t.add_column("sigma", justify="right")
    if rel:
        t.add_column("of it the squares' tolerance", justify="right")
        t.caption += (f"; the printed squares are known to +-{first.board.square_sigma_mm:g} mm in "
                      f"{first.board.square_mm:g} mm: that part of each length's variance")
    for cam in first.rig:
        rows = [("D (mm)", lambda r: (r.baseline_mm, r.sigma_baseline_mm), True)]
        for i, a in enumerate(("d_omega", "d_phi", "d_kappa")):
            rows.append((f"{a} (')", lambda r, i=i: (r.pose.opk_arcmin[i], r.sigma_opk_arcmin[i]), False))
        for i, a in enumerate("xyz"):
            rows.append((f"t_{a} (mm)", lambda r, i=i: (r.pose.t_mm[i], r.sigma_t_mm[i]), True))
        for k, (label, get, length) in enumerate(rows):
            row = [cam if k == 0 else "", label]
            for m in models:
                row += _pm(*get(m.rig[cam]), 3)
            if rel:
                value, sigma = get(first.rig[cam])
                row.append(f"{100 * scale_share(sigma, value, rel):.0f} %" if length else "-")
            t.add_row(*row)
    return t


def result_tables(models: list[RigModel]) -> list[Table]:
    """All tables for one or more calibrations of the same data (e.g. Model 1 and Model 2)."""
    tables = [camera_table(name, models) for name in models[0].cameras]
    rig = rig_table(models)
    return tables + ([rig] if rig is not None else [])


def photo_table(rig: RigModel) -> Table:
    """Every photo: its RMS (px) per camera, its blur and corner noise (px) where the detection measured them,
    and, where a photo was not kept, which and why, and which photos are blurred."""
    names = rig.camera_order()
    status = photo_status(rig)
    kept = sum(s == "kept" for per in status.values() for _, s in per.values())
    total = sum(len(per) for per in status.values())
    quality = photo_quality(rig)
    t = Table(title=f"Photos: {kept} of {total} kept; RMS reprojection error (px) per camera",
              caption="blur: the squares' edge width (px); noise: the corner noise (px), measured at detection"
              if quality else None, box=box.SIMPLE_HEAD)
    t.add_column("view", no_wrap=True)
    for name in names:
        t.add_column(name, justify="right", no_wrap=True)
    for name in names if quality else []:
        t.add_column(f"{name} blur / noise", justify="right", no_wrap=True)
    t.add_column("status")
    for view, cells, note in photo_rows(status, names, quality=quality or None):
        t.add_row(view, *cells, note)
    return _measured(t)


def checks_table(rig: RigModel) -> Table:
    """Every check: passed or not, its statistic, limit and false-alarm rate (calib.json ``checks``;
    :func:`dualcal.estimation.checks.check_limits`)."""
    from ..estimation.checks import check_limits

    t = Table(title="Checks: statistic, limit and false-alarm rate", box=box.SIMPLE_HEAD)
    for col, justify in (("check", "left"), ("", "left"), ("statistic", "right"), ("limit", "right"),
                         ("false alarms", "left")):
        t.add_column(col, justify=justify, no_wrap=True)
    for name, check in rig.checks.items():
        cells = check_limits(check)
        t.add_row(name, "pass" if check.get("ok", True) else "FAIL", cells["statistic"], cells["limit"], cells["rate"])
    return _measured(t)


def lens_model_table(scores, used: str) -> Table:
    """The lens models side by side (:func:`dualcal.estimation.model_selection.score_lens_models`): fit and
    held-out RMS (px), how many standard errors worse than the best held out, the one recommended
    and the one ``used`` by the calibration."""
    t = Table(title="Lens models: RMS (px) on the photos fitted, and on each instant left out of the calibration",
              caption="vs best: how many standard errors the held-out error exceeds the best model's",
              box=box.SIMPLE_HEAD)
    for col in ("model", "terms", "fit", "held out", "vs best", ""):
        t.add_column(col, justify="left" if col in ("model", "") else "right", no_wrap=True)
    for s in scores:
        notes = (["recommended"] if s.recommended else []) + (["used"] if s.model == used else [])
        t.add_row(s.model, str(s.coefficients), f"{s.fit_rms_px:.4f}", f"{s.held_out_rms_px:.4f}",
                  f"{s.worse_se:.1f}", ", ".join(notes))
    return _measured(t)


def lens_model_advice(scores, used: str) -> str:
    """One line: the recommended model and, where it is not ``used``, how to calibrate with it."""
    best = next(s for s in scores if s.recommended)
    if best.model == used:
        return (f"lens model {used}: no richer model predicts the instants left out better by more than "
                f"its noise (held-out RMS {best.held_out_rms_px:.4f} px)")
    mine = next(s for s in scores if s.model == used)
    return (f"lens model {best.model} recommended (held-out RMS {best.held_out_rms_px:.4f} px vs "
            f"{mine.held_out_rms_px:.4f} px for {used}, {mine.worse_se:.1f} SE worse): calibrate again with "
            f"--model {best.model}")


def lens_model_choice_table(adjustment: dict) -> Table:
    """Each camera's lens models by their held-out RMS (px) and how many standard errors worse than
    that camera's best (:func:`dualcal.estimation.model_selection.choose_lens_models`: ``adjustment["lens_models"]``),
    the one chosen marked; ``-`` where a model is no candidate of the camera."""
    from ..estimation.model_selection import lens_model_grid

    models, grid = lens_model_grid(adjustment)
    t = Table(title="Lens model of each camera (--model auto): held-out RMS (px) and SE worse than the camera's best",
              caption="chosen (*): the preferred model (kb4 for a fisheye's field of view, else k1k2) where it is "
                      "within 2 SE of the best, else the one with the fewest terms that is; one whose residuals grow "
                      "towards the image's edge only where no better one's stay even; -: no candidate",
              box=box.SIMPLE_HEAD)
    t.add_column("camera", no_wrap=True)
    for model in models:
        t.add_column(model, justify="right", no_wrap=True)
    for name, cells in grid:
        t.add_row(name, *(f"{c['held_out_rms_px']:.4f} {c['worse_se']:.1f}{'*' if c['chosen'] else ' '}" if c else "- "
                          for c in cells))
    return _measured(t)


def roll_tables(roll: dict) -> list[Table]:
    """A camera roll's split (corners.json ``roll``, :mod:`dualcal.files.roll`) as tables: the cameras found
    (what told them, lens, focal length, image size, photos), every instant with the photo of each camera and how
    sure its split is, then the photos left out and why. The titles say which clues told the cameras and the
    instants apart."""
    cams = roll["cameras"]
    clues = roll.get("clues", {})
    told = f" told apart by {', '.join(clues['cameras'])}" if clues.get("cameras") else ""
    if roll.get("cameras_separation_sigma") is not None:
        told += (f" ({roll['cameras_sure']}: the closest two lenses of one size {roll['cameras_separation_sigma']:.1f} "
                 "sigma apart)")
    found = Table(title=f"Camera roll {roll['folder']}: {len(cams)} cameras{told}", box=box.SIMPLE_HEAD)
    for col in ("camera", "lens", "f (35 mm equiv.)", "image size", "photos"):
        found.add_column(col, justify="left" if col in ("camera", "lens") else "right")
    for name, c in cams.items():
        f35 = c.get("focal_length_35mm_mm")
        if str(c.get("told_by", "")).startswith("focal length from the board"):
            lens = f"f {c['focal_length_board_px']:.0f} px from the boards"
            if c.get("focal_length_board_sigma_px") is not None:
                lens = (f"f {c['focal_length_board_px']:.0f} +- {c['focal_length_board_sigma_px']:.0f} px, bend "
                        f"{c['distortion_board']:+.2f} +- {c['distortion_board_sigma']:.2f} from the boards")
            if c.get("nearest_lens"):
                lens += f"; {c['separation_sigma']:.1f} sigma from {c['nearest_lens']}"
        else:
            lens = c.get("lens_model") or f"{c.get('focal_length_mm') or '?'} mm"
        found.add_row(name, lens, f"{f35:.0f} mm" if f35 else "?", "x".join(map(str, c["image_size"])), str(c["photos"]))
    gap = roll.get("instant_gap_s")
    if clues.get("instants"):
        how = f"split by {', '.join(clues['instants'])}"
        if gap and roll.get("instant_gap_found"):
            how += f"; capture-time gaps beyond {gap:.1f} s point to a new position"
        elif gap:
            how += f"; capture-time gaps beyond {gap:.1f} s (given) make a new position"
        how += f" ({roll['order']} order; the split is {roll['split_sure']}, margin {roll['split_margin']:.1f})"
    else:
        how = (f"a new board position after a gap of more than {gap:.1f} s "
               f"({'found from the capture times' if roll.get('instant_gap_found') else 'given'})" if gap
               else "one board position")
    instants = Table(title=f"Instants: {how}", box=box.SIMPLE_HEAD)
    instants.add_column("instant")
    days = {inst["taken"][:10] for inst in roll["instants"].values() if inst.get("taken")}
    one_day = len(days) == 1                  # the date in the header, the times alone in the rows
    instants.add_column(f"taken ({min(days)})" if one_day else "taken")
    for name in cams:
        instants.add_column(name)
    instants.add_column("sure")
    for key, inst in roll["instants"].items():
        taken = (inst.get("taken") or "-").replace("T", " ")[:21]
        taken = taken[11:] if one_day and taken != "-" else taken
        sure = "-" if "sure" not in inst else inst["sure"] if inst["sure"] == "certain" else \
            f"{inst['sure']} ({inst['margin']:.1f})"
        instants.add_row(key, taken, *(inst["photos"].get(n, "-") for n in cams), sure)
    tables = [found, instants]
    if roll.get("left_out"):
        out = Table(title="Left out", box=box.SIMPLE_HEAD)
        out.add_column("photo")
        out.add_column("why")
        for file_name, why in roll["left_out"].items():
            out.add_row(file_name, why)
        tables.append(out)
    return tables


def lens_motion_lines(rig: RigModel) -> list[str]:
    """What the calibration found of its lenses' motion: each focus model (its breathing coefficient, the focus its
    intrinsics hold at, its photos' focus range) and the stabiliser's spread, where modelled."""
    lines = [f"focus modelled, {name}: breathing b = {m.breathing:.2f} +- {m.breathing_sigma:.2f} (a thin lens of "
             f"{m.focal_length_mm:g} mm: 1), its intrinsics at {m.focus_m:.2f} m, its photos focused "
             f"{m.focus_range_m[0]:.2f}-{m.focus_range_m[1]:.2f} m" for name, m in rig.focus_models.items()]
    shifting = {n: s for n, s in rig.ois_sigma_px.items() if s > 0}
    if shifting:
        lines.append("stabiliser: each photo's principal point shifted by "
                     + ", ".join(f"{s:.2f} px ({n})" for n, s in shifting.items()) + " per coordinate (1-sigma)")
    return lines


def video_lines(corners) -> list[str]:
    """Lines for the terminal: what became of each clip's frames (read, board found, held still, chosen,
    and why the others were not) and each camera's offset from the reference; none without clips."""
    lines = []
    for name, cam in corners.cameras.items():
        record = cam.meta.get("video")
        if not record:
            continue
        why = ", ".join(f"{what} {n}" for what, n in record["not_used"].items() if n)
        lines.append(f"{name}: {record['frames_read']} frames read, board found in {record['board_found']}, "
                     f"held still in {record['still']} ({record['moments']} moments), {record['chosen']} chosen"
                     + (f"; not chosen: {why}" if why else ""))
        if "offset_s" in record and name != corners.reference:
            fps = record["fps"]
            lines.append(f"{name}: first frame at {record['offset_s']:+.4f} s +- {record['offset_sigma_s']:.4f} s on "
                         f"{corners.reference}'s clock ({record['offset_s'] * fps:+.2f} frames)")
    return lines
