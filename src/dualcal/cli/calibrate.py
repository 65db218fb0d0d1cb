"""``dualcal calibrate`` and ``dualcal synth``."""

from __future__ import annotations

from . import cli  # noqa: F401
