"""Named exceptions.

Every failure a user can cause is a :class:`DualcalError`; the CLI turns it into one line on
stderr and exit code 2. Anything else escaping the library is a bug in dualcal.
"""


class DualcalError(Exception):
    """Base of all errors caused by the input (the CLI exits with code 2)."""


class InputError(DualcalError):
    """A file, folder, flag or JSON document is missing, malformed or inconsistent."""


class EstimationError(DualcalError):
    """An estimate could not be made: too few views, a degenerate configuration, no convergence."""


class NotInvertibleError(EstimationError):
    """The radial distortion model cannot be inverted (radius not monotonic) where asked."""


class DetectionError(DualcalError):
    """No chessboard could be found, or the grid found failed its own checks."""


class OutputError(DualcalError):
    """An output cannot be written: a full disk, a read-only or missing folder. Nothing was replaced."""
