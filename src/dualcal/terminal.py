"""Text for the terminal: names that are data (file, camera, device names) never steer it.

:func:`printable` is applied by every printing path of dualcal (:func:`dualcal.progress.warn`, the
rich consoles of the tables, the CLI's lines), so an escape sequence in a file or camera name is shown as
its visible characters and never runs. No dependencies: the CLI imports this at start-up.
"""

from __future__ import annotations

import re

#: C0 controls but tab and newline, DEL, and the C1 controls (ESC, CSI 0x9b, OSC 0x9d, ...).
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def printable(text) -> str:
    """``text`` without control characters (tab and newline kept): ``"a\\x1b[2Jb"`` -> ``"a[2Jb"``."""
    return _CONTROL.sub("", str(text))
