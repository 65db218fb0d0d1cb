"""The fleet page (``OUTDIR/fleet.html`` of ``dualcal batch``): how the units of a fleet differ.

From the fleet table (:func:`dualcal.batch.fleet_table`, one row per device):

* the spread of every parameter over the devices that succeeded: median, robust spread
  (1.4826 x the median absolute deviation, a standard deviation for normal data), range, and the
  ratio of the spread to the devices' own sigmas: near 1 the units are alike within what one
  calibration can tell, far above 1 they really differ; one small plot per parameter;
* the devices that differ from the fleet's median by more than ``flag_sigmas`` of their own
  sigmas, in any parameter;
* with an earlier table (``--baseline``), the drift of each device present in both,
  ``now - before`` in units of ``sqrt(sigma_now^2 + sigma_before^2)``.

A parameter is a column ``X`` with a sigma column ``X`` with ``.sigma.`` inserted after its
camera (``wide.fx`` and ``wide.sigma.fx``; ``rig.tele.baseline_mm`` and
``rig.tele.sigma.baseline_mm``); one held fixed in every device (sigma 0) is left out. The page is
self-contained like the calibration report and uses its style and figure helpers.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd
from markupsafe import Markup
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ... import __version__
from .analysis import format_value_sigma
from .figures import camera_colour, figure_svg, style
from .html import slug
from .templating import environment

_FLAG_COLOUR = "#d62728"
_PIXEL_PARAMETERS = {"fx", "fy", "cx", "cy", "skew"}


@dataclass(frozen=True)
class Parameter:
    """A column of the fleet table shown on the page; ``sigma`` is its sigma column or None."""

    column: str
    sigma: str | None
    group: str
    name: str

    @property
    def unit(self) -> str:
        parts = self.name.split(".")
        if parts[-1] in _PIXEL_PARAMETERS:
            return "px"
        for part in parts:
            for suffix, unit in (("_mm", "mm"), ("_arcmin", "arcmin"), ("_px", "px")):
                if part.endswith(suffix):
                    return unit
        return ""

    @property
    def label(self) -> str:
        return f"{self.name} ({self.unit})" if self.unit else self.name


def _numeric(table, column: str) -> np.ndarray:
    return pd.to_numeric(table[column], errors="coerce").to_numpy(float)


def estimated_parameters(table) -> list[Parameter]:
    """Every column with a sigma column beside it, in table order, unless fixed (sigma 0) everywhere."""
    out = []
    for column in table.columns:
        group, sep, name = column.partition(".sigma.")
        value = f"{group}.{name}"
        if sep and value in table.columns and np.nanmax(_numeric(table, column), initial=0.0) > 0:
            out.append(Parameter(value, column, group, name))
    return sorted(out, key=lambda p: table.columns.get_loc(p.column))


def quality_parameters(table) -> list[Parameter]:
    """RMS columns and the 3-D check's RMSE columns (no sigma): the fit and the check of each device."""
    pattern = re.compile(r"^(rms_px|.+\.rms_px|eval\..+\.rmse_mm\.[xyz])$")
    return [Parameter(c, None, "fit and 3-D check", c) for c in table.columns if pattern.match(c)]


def succeeded(table):
    """The rows of the devices that were calibrated."""
    return table[table["status"] == "ok"].reset_index(drop=True)


def robust_spread(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation of the finite values (NaN when there are none)."""
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else math.nan


def deviation_sigmas(table, parameters: list[Parameter]):
    """``(value - fleet median) / own sigma`` per device (rows) and parameter (columns)."""
    z = {}
    for p in parameters:
        x, s = _numeric(table, p.column), _numeric(table, p.sigma)
        with np.errstate(invalid="ignore", divide="ignore"):
            z[p.column] = np.where(s > 0, (x - np.nanmedian(x)) / s, np.nan)
    return pd.DataFrame(z, index=table["device"].to_numpy())


def drift_sigmas(table, baseline, parameters: list[Parameter]):
    """Drift of the devices that succeeded in both tables: ``(now - before) / sqrt(s_now^2 + s_before^2)``
    and ``now - before``, as two frames (devices x parameter columns present in both)."""
    now = succeeded(table).set_index("device")
    before = succeeded(baseline).drop_duplicates("device").set_index("device")
    devices = [d for d in now.index if d in before.index]
    shared = [p for p in parameters if p.column in before.columns and p.sigma in before.columns]
    z, delta = {}, {}
    for p in shared:
        x1, s1 = _numeric(now.loc[devices], p.column), _numeric(now.loc[devices], p.sigma)
        x0, s0 = _numeric(before.loc[devices], p.column), _numeric(before.loc[devices], p.sigma)
        delta[p.column] = x1 - x0
        with np.errstate(invalid="ignore", divide="ignore"):
            z[p.column] = (x1 - x0) / np.hypot(s1, s0)
    return pd.DataFrame(z, index=devices), pd.DataFrame(delta, index=devices)


def _worst_rows(z, k: float, values=None) -> list[dict]:
    """Per device with any ``|z| > k``: how many parameters, the worst one and its z (and value in
    ``values``, a frame like ``z``), worst first."""
    rows = []
    for device, zs in z.iterrows():
        a = np.abs(zs.to_numpy(float))
        beyond = int(np.sum(a > k))
        if not beyond:
            continue
        worst = zs.index[int(np.nanargmax(a))]
        row = {"device": device, "beyond": beyond, "parameter": worst, "z": float(zs[worst])}
        if values is not None:
            row["value"] = float(values.loc[device, worst])
        rows.append(row)
    return sorted(rows, key=lambda r: -abs(r["z"]))


# ---------------------------------------------------------------------------- figures


def spread_figure(parameters: list[Parameter], ok, z, k: float) -> Figure:
    """One small plot per parameter: each device's value (with its 1-sigma bar) in fleet order, the
    fleet median (line) and robust spread (band); devices beyond ``k`` own sigmas in red."""
    ncols = min(4, len(parameters))
    nrows = math.ceil(len(parameters) / ncols)
    fig = Figure(figsize=(2.7 * ncols, 1.9 * nrows + 0.3))
    # fixed margins: the constrained layout engine would double the time of these many small axes
    fig.subplots_adjust(left=0.07, right=0.99, top=1 - 0.32 / (1.9 * nrows + 0.3), bottom=0.2 / (1.9 * nrows + 0.3),
                        wspace=0.4, hspace=0.5)
    x = np.arange(len(ok))
    for i, p in enumerate(parameters):
        ax = fig.add_subplot(nrows, ncols, i + 1)
        y = _numeric(ok, p.column)
        med, spread = np.nanmedian(y), robust_spread(y)
        if np.isfinite(spread):
            ax.axhspan(med - spread, med + spread, color="0.9", lw=0)
        ax.axhline(med, color="0.45", lw=0.8)
        yerr = _numeric(ok, p.sigma) if p.sigma else None
        ax.errorbar(x, y, yerr=yerr, fmt="o", ms=3, lw=0.8, color=camera_colour(0))
        if p.column in z:
            flag = np.abs(z[p.column].to_numpy(float)) > k
            ax.plot(x[flag], y[flag], "o", ms=4.5, color=_FLAG_COLOUR, zorder=3)
        ax.set_title(p.label, fontsize=8.5)
        ax.set_xticks([])
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    return fig


def drift_figure(z, k: float) -> Figure:
    """Drift of every device in combined sigmas, one column of points per parameter; the lines at +-k."""
    fig = Figure(figsize=(max(5.0, 0.42 * len(z.columns) + 1.5), 3.4), layout="constrained")
    ax = fig.add_subplot()
    rng = np.random.default_rng(0)      # a fixed jitter: the same input gives the same page
    for j, column in enumerate(z.columns):
        values = z[column].to_numpy(float)
        jitter = rng.uniform(-0.18, 0.18, len(values))
        colours = np.where(np.abs(values) > k, _FLAG_COLOUR, camera_colour(0))
        ax.scatter(j + jitter, values, s=9, c=colours, lw=0)
    for level in (-k, k):
        ax.axhline(level, color="0.5", lw=0.8, ls="--")
    ax.axhline(0, color="0.7", lw=0.6)
    ax.set_xticks(range(len(z.columns)), z.columns, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("drift / combined sigma")
    return fig


# ---------------------------------------------------------------------------- the page


def _spread_rows(parameters: list[Parameter], ok) -> list[dict]:
    rows = []
    for p in parameters:
        y = _numeric(ok, p.column)
        finite = y[np.isfinite(y)]
        if not len(finite):
            continue
        med, spread = float(np.median(finite)), robust_spread(finite)
        med_text, spread_text = format_value_sigma(med, spread)
        own = float(np.nanmedian(_numeric(ok, p.sigma))) if p.sigma else math.nan
        rows.append({"group": p.group, "name": p.name, "unit": p.unit, "n": len(finite), "median": med_text,
                     "spread": spread_text, "min": format_value_sigma(finite.min(), spread)[0],
                     "max": format_value_sigma(finite.max(), spread)[0],
                     "own_sigma": f"{own:.2g}" if math.isfinite(own) else "",
                     "ratio": f"{spread / own:.2g}" if math.isfinite(own) and own > 0 else ""})
    return rows


def _is_false(value) -> bool:
    return isinstance(value, (bool, np.bool_)) and not value


def _failing_checks(ok) -> list[dict]:
    """Devices with a failed check (a column ``checks.<name>.ok`` that is false) and those checks."""
    columns = [c for c in ok.columns if c.startswith("checks.") and c.endswith(".ok") and c != "checks.ok"]
    rows = []
    for _, row in ok.iterrows():
        failing = [c[len("checks."):-len(".ok")] for c in columns if _is_false(row[c])]
        if failing:
            rows.append({"device": row["device"], "checks": ", ".join(failing)})
    return rows


def _groups(parameters: list[Parameter]) -> dict[str, list[Parameter]]:
    out: dict[str, list[Parameter]] = {}
    for p in parameters:
        out.setdefault(p.group, []).append(p)
    return out


def render_fleet(table, baseline=None, flag_sigmas: float = 5.0, title: str | None = None,
                 inputs_digest: str | None = None) -> str:
    """The fleet page as one self-contained HTML string.

    Parameters
    ----------
    table : the fleet table (``pandas.DataFrame`` of :func:`dualcal.batch.fleet_table`, or read
        back from fleet.parquet).
    baseline : an earlier fleet table to compare with, or None.
    flag_sigmas : a device is listed where it differs from the fleet median (or, with a
        baseline, from its earlier self) by more than this many sigmas.
    title : page title.
    inputs_digest : recorded in the page's head (:func:`dualcal.batch.fleet_inputs_digest`), so that
        a re-run with the same inputs need not write it again.
    """
    ok = succeeded(table)
    estimated = estimated_parameters(ok)
    z = deviation_sigmas(ok, estimated)
    figures = []
    with style():
        for group, params in _groups(estimated).items():
            fig_id = f"fig-spread-{slug(group)}"
            svg = figure_svg(spread_figure(params, ok, z, flag_sigmas), fig_id)
            figures.append({"id": fig_id, "group": group, "svg": Markup(svg)})
        drift = None
        if baseline is not None:
            dz, delta = drift_sigmas(table, baseline, estimated)
            now, before = set(table["device"]), set(baseline["device"])
            drift = {"compared": len(dz), "rows": _worst_rows(dz, flag_sigmas, delta),
                     "new": sorted(now - before), "gone": sorted(before - now), "svg": None}
            if len(dz) and len(dz.columns):
                drift["svg"] = Markup(figure_svg(drift_figure(dz, flag_sigmas), "fig-drift"))
    failed = table[table["status"] != "ok"]
    env = environment()
    return env.get_template("fleet.html").render(
        title=title or f"dualcal fleet: {len(table)} devices",
        version=__version__, inputs_digest=inputs_digest, k=f"{flag_sigmas:g}",
        n_devices=len(table), n_ok=len(ok),
        failed=[{"device": d, "reason": s.removeprefix("failed: ")} for d, s in zip(failed["device"], failed["status"])],
        checks=_failing_checks(ok),
        spread=_spread_rows(estimated + quality_parameters(ok), ok),
        flagged=_worst_rows(z, flag_sigmas, ok.set_index("device")[[p.column for p in estimated]]),
        figures=figures, drift=drift)
