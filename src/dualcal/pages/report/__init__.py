"""The calibration report: one self-contained HTML page (``dualcal report``).

* :mod:`.analysis`: the numbers (residuals, per-view RMS, coverage, distortion, rig frames);
* :mod:`.figures`: matplotlib figures of those numbers, as inline SVG;
* :mod:`.html`: the page itself, from ``templates/report.html`` (jinja2).
"""

__all__ = ["render_report"]


def __getattr__(name: str):
    # the page's modules import matplotlib: only when the report is made, not for the pick page
    if name == "render_report":
        from ...extras import require
        require("report")
        from .html import render_report
        return render_report
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
