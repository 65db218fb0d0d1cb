"""The calibration report: one self-contained HTML page (``dualcal report``).

* :mod:`.analysis`: the numbers (residuals, per-view RMS, coverage, distortion, rig frames);
* :mod:`.figures`: matplotlib figures of those numbers, as inline SVG;
* :mod:`.html`: the page itself, from ``templates/report.html`` (jinja2).
"""

from .html import render_report

__all__ = ["render_report"]
