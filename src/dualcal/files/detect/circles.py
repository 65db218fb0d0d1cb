"""Circle grids in a photo: OpenCV's grid finder on the reduced photo, each centre refined at full size.

Per photo (called by :func:`dualcal.files.detect.pipeline.detect_photo` for a board whose ``pattern`` is
``"circles"`` or ``"acircles"``), one photo in memory at a time and, at full resolution, small windows only:

1. on the photo reduced to 1/2-1/8 (:func:`.coarse.reduce_image`), OpenCV's ``findCirclesGrid``
   (symmetric or asymmetric; its clustering variant where that fails) with a blob detector tuned to the
   reduced photo's scale (:func:`blob_detector`: circles from about 6 pixels across to a board filling the
   frame twice over); where the grid is not found, or its circles are under :data:`MIN_CIRCLE_PX` across, the same at
   twice the resolution, down to the full photo;
2. the grid put in the contract's order (:func:`canonical_order`): OpenCV may number a grid from any of the
   corners its layout's symmetries allow; of those numberings, the one whose board frame is right-handed
   with Z into the board (the printed side faces the camera) is kept. An asymmetric grid of odd ``rows``
   (OpenCV's 4 x 11) has one; a symmetric grid, or an asymmetric one of even ``rows``, looks the same
   turned by 180 degrees: point 0 is then the candidate nearest the image's top-left (``ambiguous``), as for
   a symmetric chessboard, and the dataset's warning and cross-camera alignment follow;
3. each centre refined at full resolution (:func:`refine_centre`): the pixels around it are mapped to the
   board by the affine map of its neighbours' centres; the paper's level is a plane fitted to a ring between
   the circle and its neighbours, and each pixel's darkness ``1 - I / paper`` its share covered by the
   circle (a multiplicative light fall-off cancels); the centre is the darkness-weighted mean of the pixels
   within half the spacing (in board mm) of the circle's centre, twice. A blur, the box-sampling of pixels
   and sensor noise move the mean of darkness nowhere, so this is the centre of the circle's image
   (its area's centroid: an ellipse's centre), which :mod:`dualcal.geometry.circles` models;
4. a centre whose refinement left its window, or that its neighbours' homography misplaces by more than
   :data:`MAX_NEIGHBOUR_SHARE` of the spacing, is a NaN row; a grid with fewer than half its centres left is
   not found.
"""

from __future__ import annotations

import cv2
import numpy as np

from ...errors import DetectionError, InputError
from ...geometry.board import Board
from ...parallel import raise_if_cancelled
from .coarse import reduce_image, reduction_factor, to_full_resolution

__all__ = ["MIN_CIRCLE_PX", "MAX_NEIGHBOUR_SHARE", "blob_detector", "find_circle_grid", "canonical_order",
           "refine_centre", "detect_circles"]

#: Circles (diameter, reduced pixels) below which the grid is searched for again at twice the resolution:
#: OpenCV's blobs are thresholded shapes, whose centres need a few pixels across to be placed.
MIN_CIRCLE_PX = 8.0

#: A refined centre further than this share of the local spacing from where the affine map of its neighbours'
#: centres puts it is not measured (a circle smeared by glare, a speck of dirt on it).
MAX_NEIGHBOUR_SHARE = 0.1

#: Pixels beyond a circle's edge that its mean of darkness takes in (a blur's tail; fewer pixels of paper, whose
#: noise moves the mean, the nearer), and the width of the ring of paper beyond them that gives the paper's level;
#: where the circles are closer than that, each takes half the gap.
EDGE_PX = 5.0

#: Neighbours (nearest on the board) whose centres give a circle's local affine map.
_NEIGHBOURS = 8


def blob_detector(image_size: tuple[int, int], board: Board) -> cv2.SimpleBlobDetector:
    """OpenCV's blob detector for ``board``'s circles in an image of ``image_size = (W, H)``: OpenCV's defaults (dark
    blobs of at least 25 px^2, nearly convex; smaller specks of a cluttered room confuse the grid finder, and circles
    that small are searched for at a finer resolution anyway), up to the size the circles have when the board
    fills the image twice over (a steep view's near side; OpenCV's default stops at 5000 px^2)."""
    p = cv2.SimpleBlobDetector_Params()
    x0, x1, y0, y1 = board.pattern_extent_mm()
    px_per_mm = 2.0 * max(image_size) / max(x1 - x0, y1 - y0)
    p.maxArea = float(max(p.minArea + 1.0, np.pi / 4 * (board.circle_diameter_mm * px_per_mm) ** 2))
    return cv2.SimpleBlobDetector_create(p)


def find_circle_grid(gray: np.ndarray, board: Board) -> np.ndarray | None:
    """(N, 2) circle centres of ``board`` in ``gray`` in OpenCV's order (``k = r*cols + c`` from whichever corner
    OpenCV started), by ``findCirclesGrid`` then its clustering variant, or None."""
    raise_if_cancelled()
    kind = cv2.CALIB_CB_ASYMMETRIC_GRID if board.pattern == "acircles" else cv2.CALIB_CB_SYMMETRIC_GRID
    detector = blob_detector(gray.shape[::-1], board)
    for flags in (kind, kind | cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(gray, (board.cols, board.rows), flags=flags, blobDetector=detector)
        if found and centres is not None and len(centres) == board.n_corners:
            return centres.reshape(-1, 2).astype(float)
    return None


def _symmetries(board: Board) -> list[np.ndarray]:
    """Permutations ``p`` (N,) of the board's points under which its layout maps onto itself by a rotation or a
    reflection about its centre (the identity first): point ``k`` falls on point ``p[k]``."""
    xy = board.object_points_mm()[:, :2]
    centred = xy - 0.5 * (xy.min(axis=0) + xy.max(axis=0))
    tol = 1e-6 * board.square_mm
    perms = []
    for turn in range(4):
        c, s = np.round(np.cos(turn * np.pi / 2)), np.round(np.sin(turn * np.pi / 2))
        for mirror in (1.0, -1.0):
            T = np.array([[c, -s], [s, c]]) @ np.diag([1.0, mirror])
            moved = centred @ T.T
            d = np.hypot(*(moved[:, None, :] - centred[None, :, :]).transpose(2, 0, 1))
            p = np.argmin(d, axis=1)
            if np.all(d[np.arange(len(p)), p] < tol) and len(set(p.tolist())) == len(p):
                perms.append(p)
    return perms


def _right_handed(xy_board: np.ndarray, uv: np.ndarray) -> bool:
    """True when the board frame is right-handed in the image with Z away from the camera: the homography's
    Jacobian at the points' centroid has a positive determinant (X and Y turn as u and v do)."""
    H, _ = cv2.findHomography(xy_board, uv, 0)
    if H is None:
        return False
    x, y = xy_board.mean(axis=0)
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u, v = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    J = (H[:2, :2] - np.outer([u, v], H[2, :2])) / w
    return float(np.linalg.det(J)) > 0


def canonical_order(uv: np.ndarray, board: Board) -> tuple[np.ndarray, bool]:
    """The centres ``uv`` (N, 2), numbered as OpenCV found them, in the contract's order: of the numberings the
    layout's symmetries allow, those with the board's frame right-handed into the board, and of several the one
    whose point 0 is nearest the image's top-left. Returns the ordered (N, 2) centres and whether the choice was
    ambiguous (a layout that looks the same turned)."""
    xy = board.object_points_mm()[:, :2]
    keep = [uv[p] for p in _symmetries(board) if _right_handed(xy, uv[p])]
    if not keep:
        raise DetectionError("no numbering of the circles has the board's printed side facing the camera")
    keep.sort(key=lambda g: float(np.hypot(*g[0])))
    return keep[0], len(keep) > 1


def _local_affine(k: int, xy: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """(2, 3) affine map board mm -> pixels fitted to the centres of circle ``k``'s nearest neighbours on the board
    (``k`` itself left out), or None where too few of them are measured."""
    d = np.hypot(*(xy - xy[k]).T)
    d[k] = np.inf
    near = [j for j in np.argsort(d) if np.isfinite(uv[j]).all()][:_NEIGHBOURS]
    if len(near) < 4:
        return None
    A = np.column_stack([xy[near], np.ones(len(near))])
    sol, *_ = np.linalg.lstsq(A, uv[near], rcond=None)
    if np.linalg.matrix_rank(A) < 3:
        return None
    return sol.T


def _neighbour_miss(k: int, xy: np.ndarray, uv: np.ndarray, spacing_mm: float) -> float | None:
    """How far centre ``k`` is from where the homography of its :data:`_NEIGHBOURS` nearest measured neighbours
    puts it, in spacings there (None where it or too few of them are measured)."""
    if not np.isfinite(uv[k]).all():
        return None
    d = np.hypot(*(xy - xy[k]).T)
    d[k] = np.inf
    near = [j for j in np.argsort(d) if np.isfinite(uv[j]).all()][:_NEIGHBOURS]
    if len(near) < 6:
        return None
    H, _ = cv2.findHomography(xy[near], uv[near], 0)
    if H is None:
        return None
    ends = cv2.perspectiveTransform(np.array([[xy[k], xy[k] + [spacing_mm, 0.0]]]), H)[0]
    return float(np.hypot(*(ends[0] - uv[k])) / max(np.hypot(*(ends[1] - ends[0])), 1e-9))


def refine_centre(full: np.ndarray, affine: np.ndarray, start_px: np.ndarray, board: Board,
                  iterations: int = 6) -> np.ndarray | None:
    """A circle's centre (2,) in full-resolution pixels, as the darkness-weighted mean of the pixels around it (the
    module docstring, step 3), or None where its window leaves the image or holds no circle.

    Parameters
    ----------
    full : (H, W) uint8 ndarray
        the photo at full resolution.
    affine : (2, 3) ndarray
        board mm -> pixels near the circle (its neighbours' centres).
    start_px : (2,) ndarray
        where to start (the coarse centre at full resolution).
    board : Board
        the circle grid.
    iterations : int
        the mean taken again around the last one.
    """
    r = 0.5 * board.circle_diameter_mm
    reach = 0.5 * board.circle_gap_mm                                     # mm: halfway to the next centre
    A = affine[:, :2]
    Ainv = np.linalg.inv(A)
    # the circle and its blur: EDGE_PX beyond its edge (in mm along the map's shorter axis), within the reach
    edge_mm = EDGE_PX / float(np.linalg.svd(A, compute_uv=False)[-1])
    inside_mm = min(r + edge_mm, 0.5 * (r + reach))           # small circles: half the gap each, mean and ring
    outside_mm = min(reach, inside_mm + edge_mm)
    half = np.abs(A) @ np.array([outside_mm, outside_mm]) + 2.0           # the window's half-size, px
    H, W = full.shape
    centre = np.asarray(start_px, float)
    for _ in range(iterations):
        lo = np.floor(centre - half).astype(int)
        hi = np.ceil(centre + half).astype(int) + 1
        if np.any(lo < 0) or hi[0] > W or hi[1] > H:
            return None
        patch = full[lo[1]:hi[1], lo[0]:hi[0]].astype(float)
        v, u = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
        # each pixel's board offset from the circle's centre, mm (the affine map about the current centre)
        duv = np.stack([u - centre[0], v - centre[1]], axis=-1)
        dist = np.hypot(*np.moveaxis(duv @ Ainv.T, -1, 0))
        ring = (dist > inside_mm) & (dist < outside_mm)
        inner = dist < inside_mm
        if ring.sum() < 6 or inner.sum() < 6:
            return None
        # the paper's level: a plane over the ring (light falling off across the window)
        M = np.column_stack([np.ones(ring.sum()), u[ring] - centre[0], v[ring] - centre[1]])
        plane, *_ = np.linalg.lstsq(M, patch[ring], rcond=None)
        paper = plane[0] + plane[1] * (u[inner] - centre[0]) + plane[2] * (v[inner] - centre[1])
        if not np.all(paper > 0):
            return None
        dark = 1.0 - patch[inner] / paper
        core = dist[inner] < 0.5 * r
        if core.sum() >= 3:
            # darkness as the share covered (1 in the circle, 0 on paper), clipped: the noise of the pixels
            # wholly dark or wholly paper, which the clip halves, is spread evenly about the current centre, so
            # it slows the iteration towards the centroid but does not move where it converges
            dark = np.clip(dark / max(float(np.median(dark[core])), 1e-3), 0.0, 1.0)
        total = dark.sum()
        if not total > 0:
            return None
        new = np.array([np.sum(dark * u[inner]), np.sum(dark * v[inner])]) / total
        if np.hypot(*(Ainv @ (new - centre))) > 0.5 * r:
            return None                                                  # left the circle: not a circle here
        centre = new
    return centre


def _coarse_centres(full: np.ndarray, board: Board) -> np.ndarray:
    """The grid's coarse centres (N, 2) in full-resolution pixels, in OpenCV's order (module docstring, step 1)."""
    f = reduction_factor(full.shape[::-1])
    best = None
    while True:
        found = find_circle_grid(reduce_image(full, f) if f > 1 else full, board)
        if found is not None:
            best = to_full_resolution(found, f)
            spacing = np.median(np.hypot(*np.diff(found.reshape(board.rows, board.cols, 2), axis=1).reshape(-1, 2).T))
            pitch_mm = board.square_mm * (2.0 if board.pattern == "acircles" else 1.0)      # along a row
            circle = spacing * board.circle_diameter_mm / pitch_mm
            if circle >= MIN_CIRCLE_PX:
                return best
        elif best is not None:                 # small circles found coarser, not here: those, refined at full size
            return best
        if f == 1:
            if best is None:
                raise DetectionError(f"no {board.spec()} circle grid found")
            return best
        f //= 2


def detect_circles(full: np.ndarray, board: Board) -> tuple[np.ndarray, bool]:
    """The circle centres of ``board`` in the photo ``full`` ((H, W) uint8): (N, 2) pixels in the contract's order,
    NaN rows for centres not measured, and whether the numbering was ambiguous (module docstring).

    Raises
    ------
    DetectionError
        No grid of the board is found, or fewer than half its centres are measured.
    InputError
        ``board`` is not a circle grid (a target given by its points cannot be detected: its corners come from
        corners.json).
    """
    if not board.is_circle_grid:
        raise InputError(f"{board.describe()} cannot be detected in photos: give its corners in corners.json")
    coarse, ambiguous = canonical_order(_coarse_centres(full, board), board)
    xy = board.object_points_mm()[:, :2]
    uv = np.full_like(coarse, np.nan)
    for k in range(board.n_corners):
        affine = _local_affine(k, xy, coarse)
        refined = None if affine is None else refine_centre(full, affine, coarse[k], board)
        if refined is not None:
            uv[k] = refined
    for k in range(board.n_corners):                         # each refined centre against its refined neighbours
        miss = _neighbour_miss(k, xy, uv, board.square_mm)
        if miss is not None and miss > MAX_NEIGHBOUR_SHARE:
            uv[k] = np.nan
    if np.isfinite(uv).all(axis=1).sum() * 2 < board.n_corners:
        raise DetectionError(f"the {board.spec()} circle grid was found, but fewer than half its centres measured")
    return uv, ambiguous
