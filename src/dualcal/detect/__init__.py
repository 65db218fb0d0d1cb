"""Board corners: fast, accurate and self-checking (paper section 1.2).

A coarse search on a reduced image (:mod:`.coarse`), the contract's corner order and colour
checks (:mod:`.order`), sub-pixel refinement at full resolution in small windows only
(:mod:`.refine`), the paper's manual mode from four clicked corners (:mod:`.manual`), and the
per-photo / per-dataset drivers (:mod:`.pipeline`); ChArUco boards through :mod:`.charuco`
(OpenCV's markers and ids, checked against the board's geometry, then the same refinement).
"""

from .charuco import detect_charuco, resolve_board
from .coarse import find_grid, reduction_factor
from .manual import display_problem, grid_from_hints, load_hints, pick_hints, save_hints
from .order import order_grid
from .grid import min_corners, neighbour_predictions, neighbour_residuals_px, predict_from_neighbours, validate_grid
from .pipeline import PhotoResult, detect_dataset, detect_photo
from .refine import fit_saddles, measure_grid, refine_corners

__all__ = ["PhotoResult", "detect_charuco", "detect_dataset", "detect_photo", "display_problem", "find_grid", "fit_saddles",
           "grid_from_hints", "load_hints", "measure_grid", "min_corners", "neighbour_predictions",
           "neighbour_residuals_px", "order_grid", "predict_from_neighbours", "pick_hints", "reduction_factor", "refine_corners",
           "resolve_board", "save_hints", "validate_grid"]
