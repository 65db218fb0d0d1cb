"""The jinja2 environment of every page dualcal writes (report, fleet page, pick page)."""

from __future__ import annotations

import jinja2


def environment() -> jinja2.Environment:
    """Templates from ``dualcal/pages/report/templates``, HTML autoescaped, undefined names an error."""
    return jinja2.Environment(loader=jinja2.PackageLoader("dualcal.pages.report", "templates"),
                              autoescape=jinja2.select_autoescape(["html"]),
                              undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
