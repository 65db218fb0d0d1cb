"""dualcal: photogrammetric calibration of smartphone multi-camera rigs from chessboard photos.

The package is the API; the ``dualcal`` command is a thin shell over it.
"""

__version__ = "0.1.0"
