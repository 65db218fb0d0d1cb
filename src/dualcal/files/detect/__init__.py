"""Board corners: fast, accurate and self-checking (paper section 1.2).

A coarse search on a reduced image (:mod:`.coarse`), the contract's corner order and colour
checks (:mod:`.order`), sub-pixel refinement at full resolution in small windows only
(:mod:`.refine`), the paper's manual mode from four clicked corners (:mod:`.manual`), and the
per-photo / per-dataset drivers (:mod:`.pipeline`); ChArUco boards through :mod:`.charuco`
(OpenCV's markers and ids, checked against the board's geometry, then the same refinement).
"""

from ... import _lazy_names

#: Each public name and its module, imported on first use: nothing here costs the photo readers (Pillow, rawpy,
#: OpenCV) that the detectors import before a detector is used. The checks of a detected grid are geometry
#: (:mod:`dualcal.geometry.grid`).
_API = {"detect_charuco": "charuco", "resolve_board": "charuco", "find_grid": "coarse", "reduction_factor": "coarse",
        "display_problem": "manual", "grid_from_hints": "manual", "load_hints": "manual", "pick_hints": "manual",
        "save_hints": "manual", "order_grid": "order", "PhotoResult": "pipeline", "detect_dataset": "pipeline", "detect_photo": "pipeline", "fit_saddles": "refine",
        "measure_grid": "refine", "refine_corners": "refine"}

__all__ = sorted(_API)
__getattr__, __dir__ = _lazy_names(__name__, _API, __all__)
