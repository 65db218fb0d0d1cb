"""The optional parts of dualcal and the packages they need (``pip install 'dualcal[NAME]'``).

The core (detect, calibrate, evaluate, measure, rectify, undistort, export) needs numpy, fastjsonschema,
OpenCV, Pillow, rich and click. Five parts need more and are extras of the package: ``report`` (the
HTML report's figures, the printable board and the manual mode's window: matplotlib), ``fleet``
(``batch``: Dask, pandas, pyarrow), ``video`` (clips instead of photos: PyAV, FFmpeg's decoders), ``app``
(``dualcal app``: Starlette, uvicorn, python-multipart, segno) and ``kalibr`` (a Kalibr camchain read:
PyYAML). :func:`require` imports what a part needs, or says in one line which extra installs it.
"""

from __future__ import annotations

import importlib

from .errors import InputError

__all__ = ["EXTRAS", "require"]

#: extra -> (what it is for, the modules it needs)
EXTRAS = {
    "report": ("the report, the printable board and the manual mode", ("matplotlib",)),
    "fleet": ("batch (a fleet of devices on a Dask cluster)", ("dask.distributed", "pandas", "pyarrow")),
    "video": ("calibrating from video clips", ("av",)),
    "app": ("the local web app (dualcal app)", ("starlette", "uvicorn", "python_multipart", "segno", "anyio")),
    "kalibr": ("reading a Kalibr camchain (dualcal import kalibr, calibrate --intrinsics)", ("yaml",)),
}


def require(extra: str) -> None:
    """Import the modules of ``extra`` (a key of :data:`EXTRAS`), or raise :class:`InputError` naming it."""
    what, modules = EXTRAS[extra]
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError:
            raise InputError(f"{what} needs {name.split('.')[0]}, which is not installed: "
                             f"pip install 'dualcal[{extra}]'") from None
