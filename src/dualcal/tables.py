"""The paper's result tables (Tables 2-4) as rich tables, for the terminal.

Table 2/3: intrinsics and radial distortion of each camera, value +- sigma, Model 1 (skew = 0)
next to Model 2 (skew free). Table 4: the rig, distance D between perspective centres (mm) and
the relative angles (minutes of arc), for every non-reference camera.
"""

from __future__ import annotations

from rich import box
from rich.table import Table

from .camera import INTRINSIC_NAMES
from .model import RigModel

_PAPER_NAMES = {"fx": "alpha = fx", "fy": "beta = fy", "skew": "gamma = skew", "cx": "u0 = cx",
                "cy": "v0 = cy", "k1": "k1", "k2": "k2"}


def _pm(value: float, sigma: float, digits: int) -> tuple[str, str]:
    return f"{value:.{digits}f}", ("-" if sigma == 0 else f"{sigma:.{digits}f}")


def _model_label(rig: RigModel) -> str:
    return "Model 2 (skew free)" if rig.skew else "Model 1 (skew = 0)"


def camera_table(name: str, models: list[RigModel]) -> Table:
    """Intrinsics of camera ``name`` in each model (the paper's Tables 2 and 3)."""
    t = Table(title=f"Camera {name!r}: intrinsics (px) and radial distortion, 1 sigma", box=box.SIMPLE_HEAD)
    t.add_column("parameter")
    for m in models:
        t.add_column(f"{_model_label(m)}", justify="right")
        t.add_column("sigma", justify="right")
    for p in INTRINSIC_NAMES:
        digits = 5 if p in ("k1", "k2") else 3
        row = [_PAPER_NAMES[p]]
        for m in models:
            row += _pm(getattr(m.cameras[name], p), m.camera_sigma[name][p], digits)
        t.add_row(*row)
    t.add_row("RMS (px)", *[x for m in models for x in (f"{m.camera_rms_px[name]:.3f}", "")])
    return t


def rig_table(models: list[RigModel]) -> Table | None:
    """Distance and relative angles of every non-reference camera (the paper's Table 4)."""
    first = models[0]
    if not first.rig:
        return None
    t = Table(title=f"Rig relative to {first.reference!r}: D (mm) and angles (minutes of arc), 1 sigma",
              box=box.SIMPLE_HEAD)
    t.add_column("camera")
    t.add_column("value")
    for m in models:
        t.add_column(_model_label(m), justify="right")
        t.add_column("sigma", justify="right")
    for cam in first.rig:
        rows = [("D (mm)", lambda r: (r.baseline_mm, r.sigma_baseline_mm))]
        for i, a in enumerate(("d_omega", "d_phi", "d_kappa")):
            rows.append((f"{a} (')", lambda r, i=i: (r.pose.opk_arcmin[i], r.sigma_opk_arcmin[i])))
        for i, a in enumerate("xyz"):
            rows.append((f"t_{a} (mm)", lambda r, i=i: (r.pose.t_mm[i], r.sigma_t_mm[i])))
        for k, (label, get) in enumerate(rows):
            row = [cam if k == 0 else "", label]
            for m in models:
                row += _pm(*get(m.rig[cam]), 3)
            t.add_row(*row)
    return t


def result_tables(models: list[RigModel]) -> list[Table]:
    """All tables for one or more calibrations of the same data (e.g. Model 1 and Model 2)."""
    tables = [camera_table(name, models) for name in models[0].cameras]
    rig = rig_table(models)
    return tables + ([rig] if rig is not None else [])
