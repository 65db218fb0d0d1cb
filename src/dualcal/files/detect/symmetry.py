"""One numbering of a 180-degree symmetric board across the cameras of a rig.

A board with ``cols + rows`` even looks the same turned by 180 degrees about its normal
through its centre, so colour cannot tell corner 0 from corner N-1: each photo is numbered by
the top-left rule (:func:`dualcal.files.detect.order.order_grid`), and two cameras of one instant,
which see the board from different places (or the board turned past 90 degrees between them),
may number it the other way round. The rig then looks as if one camera were turned by 180
degrees in some instants and not in others, and its calibration is garbage.

The rule here works for any rig. Per camera, a rough pose of the board in each photo (Zhang's
closed form over that camera's photos, :mod:`dualcal.geometry.zhang`, or a guessed camera where that
fails); renumbering a photo (corner k -> N-1-k) turns its board pose by 180 degrees about the
board's normal. The reference camera keeps its numbering. For every other camera, the relative
rotation reference -> camera of each instant is computed with both numberings of the camera's
photo; the rotation that most instants agree on (within :data:`AGREEMENT_DEG`) is the rig's,
and each photo takes the numbering that agrees with it. A camera on which fewer than half of
the instants agree is refused (the photos are not of a rigid rig, or not synchronised); a
single photo that agrees with neither numbering is dropped with a warning.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...geometry.board import Board
from ...errors import EstimationError, InputError
from ...geometry.model import CameraCorners, CornerSet, observed_mask
from ...geometry.rotation import rotation_angle_deg
from ...progress import warn

__all__ = ["AGREEMENT_DEG", "align_symmetric_numbering", "rough_rotations"]

#: Rough per-photo poses agree to a few degrees; the two numberings differ by 180.
AGREEMENT_DEG = 20.0

_HALF_TURN = np.diag([-1.0, -1.0, 1.0])          # Rz(pi): the board turned about its normal


def rough_rotations(board: Board, views: dict[str, np.ndarray], image_size) -> dict[str, np.ndarray]:
    """Board-to-camera rotation of every view, from its homography and a rough camera.

    The camera is Zhang's closed form over the views (:func:`dualcal.geometry.zhang.intrinsics_from_homographies`),
    or, with too few or too similar views, a guess (focal length the image's long side,
    principal point in the middle): the rotation is then off by some degrees, far less than
    the 180 that tell the two numberings apart. Only measured corners are used.
    """
    from ...geometry.camera import CameraModel
    from ...geometry.homography import estimate_homography
    from ...geometry.zhang import extrinsics_from_homography, intrinsics_from_homographies

    xy = board.object_points_mm()[:, :2]
    Hs = {}
    for key, uv in views.items():
        seen = observed_mask(uv)
        Hs[key] = estimate_homography(xy[seen], uv[seen], refine=False)
    w, h = image_size
    guess = CameraModel(tuple(image_size), float(max(w, h)), float(max(w, h)), 0.0, (w - 1) / 2, (h - 1) / 2).K
    try:
        K = intrinsics_from_homographies(list(Hs.values()), image_size).K
    except EstimationError:
        K = guess
    if not np.all(np.isfinite(K)):
        K = guess
    return {key: extrinsics_from_homography(K, H).R for key, H in Hs.items()}


def align_symmetric_numbering(corners: CornerSet, reference: str) -> tuple[CornerSet, int]:
    """Renumber the photos of the non-reference cameras so that every instant agrees with the rig.

    Parameters
    ----------
    corners : detected corners of a 180-degree symmetric board (each photo by the top-left rule).
    reference : the camera whose numbering is kept.

    Returns
    -------
    The corner set with renumbered (and, for photos that fit neither way, dropped) views, and
    the number of photos renumbered.

    Raises
    ------
    InputError
        When fewer than half of a camera's instants agree on one relative rotation.
    """
    board = corners.board
    ref = corners.cameras[reference]
    ref_found = ref.found()
    if len(ref_found) == 0:
        return corners, 0
    R_ref = rough_rotations(board, ref_found, ref.image_size)
    cameras, renumbered = dict(corners.cameras), 0
    for name, cam in corners.cameras.items():
        shared = sorted(set(cam.found()) & set(ref_found))
        if name == reference or not shared:
            continue
        R_cam = rough_rotations(board, {k: cam.views[k] for k in shared}, cam.image_size)
        # candidate relative rotations: (instant, numbering kept / turned)
        cand = np.stack([[R_cam[k] @ R_ref[k].T, R_cam[k] @ _HALF_TURN @ R_ref[k].T] for k in shared])
        flat = cand.reshape(-1, 3, 3)
        close = rotation_angle_deg(flat[:, None], flat[None, :]) <= AGREEMENT_DEG                      # (2n, 2n)
        support = close.reshape(len(flat), len(shared), 2).any(axis=2).sum(axis=1)
        rig = flat[int(np.argmax(support))]
        to_rig = rotation_angle_deg(cand.reshape(-1, 3, 3), rig).reshape(len(shared), 2)
        turn = np.argmin(to_rig, axis=1)
        fits = to_rig[np.arange(len(shared)), turn] <= AGREEMENT_DEG
        if 2 * fits.sum() < len(shared):
            raise InputError(
                f"the board ({board.spec()}, which looks the same turned by 180 degrees) cannot be numbered alike "
                f"in cameras {reference!r} and {name!r}: their relative pose agrees in only {int(fits.sum())} of "
                f"{len(shared)} instants; are the photos of one instant taken together by a rigid rig?")
        views = dict(cam.views)
        for k, t, ok in zip(shared, turn, fits):
            if not ok:
                warn(f"camera {name!r}, photo {k!r}: skipped: its board pose fits the rig neither way round "
                     f"(a 180-degree symmetric {board.spec()} board)")
                views[k] = None
            elif t:
                views[k] = views[k][::-1].copy()
                renumbered += 1
        cameras[name] = CameraCorners(cam.image_size, views, cam.meta)
    return replace(corners, cameras=cameras), renumbered
