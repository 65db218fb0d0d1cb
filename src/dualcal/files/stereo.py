"""Stereo rectification of two cameras of a rig: OpenCV's ``stereoRectify`` quantities and photos.

Two cameras 1 and 2 of the rig, ``X_2 = R X_1 + T`` (from calib.json, README "Conventions"),
are turned into one ideal pinhole camera ``K'`` (no distortion, no skew, square pixels) looking
the same way from both perspective centres, so that corresponding points lie on the same row
(a horizontal rig) or the same column (a vertical rig):

* rotations as OpenCV's ``stereoRectify`` makes them: each camera turns by half the relative
  rotation, ``r = exp(-log(R) / 2)``, then both by the rotation ``W`` that takes the half-turned
  baseline ``r T`` onto the x axis (or the y axis when ``|t_y| > |t_x|``, a vertical rig),
  keeping its sign: ``R1 = W r^T``, ``R2 = W r``, ``X_rect_k = R_k X_k``;
* one camera matrix for both: the focal length is the smallest of the two cameras' ``fx, fy``,
  so no photo is enlarged (for wide + tele the wide keeps its resolution and the tele is reduced
  to it, smoothed first against aliasing); the image is the part of the rectified plane that
  both photos fill (``keep="valid"``: the largest axis-aligned rectangle inside both traced
  borders, OpenCV's ``alpha = 0``) or that either photo reaches (``keep="all"``, ``alpha = 1``),
  its outer pixel centres on that rectangle's edges;
* ``P1 = K' [I | 0]``, ``P2 = K' [I | R2 T]`` (``R2 T = (T_x', 0, 0)`` or ``(0, T_y', 0)``), and
  ``Q``, which takes ``(u, v, disparity, 1)`` to homogeneous coordinates in rectified camera 1
  (disparity ``u1 - u2``, or ``v1 - v2`` for a vertical rig), all with OpenCV's conventions and
  ``CALIB_ZERO_DISPARITY`` (both images share their principal point), so they can be given to
  ``cv2.initUndistortRectifyMap`` and ``cv2.reprojectImageTo3D`` as they are.

The photos are resampled with :mod:`dualcal.files.rectify`'s banded remap, with the camera's own
distortion model; points go the same way with :func:`rectify_points`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..geometry.camera import CameraModel, check_invertible_in_image, ideal_normalized_from_pixel
from ..errors import EstimationError, InputError
from ..geometry.model import RigModel
from .photos import output_suffix
from .rectify import DEFAULT_BAND_ROWS, _border_pixels, undistort_file
from ..geometry.rotation import rotation_from_rotvec, rotvec_from_rotation

__all__ = ["KEEP_REGIONS", "StereoRectification", "epipolar_check_image", "rectify_pair_files",
           "rectify_points", "stereo_rectify"]

KEEP_REGIONS = ("valid", "all")
#: Largest rectified image, as a multiple of the larger photo's pixel count (beyond: cameras far from parallel).
_MAX_AREA_RATIO = 4.0


@dataclass(frozen=True)
class StereoRectification:
    """The rectification of cameras ``names = (first, second)`` (OpenCV's names and conventions).

    ``R1``, ``R2`` (3, 3): ``X_rect = R_k X_k``; ``P1``, ``P2`` (3, 4): projection of points in
    rectified camera 1's frame (mm) into each rectified image; ``Q`` (4, 4): ``(u, v, d, 1)`` to
    homogeneous points of rectified camera 1; ``camera``: the common pinhole camera ``K'`` with
    the output ``image_size`` ``(W, H)``; ``vertical``: the baseline runs along the columns
    (corresponding points share a column, the disparity is ``v1 - v2``).
    """

    names: tuple[str, str]
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    camera: CameraModel
    vertical: bool
    keep: str

    @property
    def image_size(self) -> tuple[int, int]:
        """``(W, H)`` of both rectified images, px."""
        return self.camera.image_size

    @property
    def baseline_mm(self) -> float:
        """Signed distance between the perspective centres along the rectified axis (``T_x'`` or ``T_y'``)."""
        return float(self.P2[1 if self.vertical else 0, 3] / self.camera.fx)

    def rotation(self, name: str) -> np.ndarray:
        """``R1`` or ``R2`` of camera ``name``."""
        return self.R1 if name == self.names[0] else self.R2

    def to_dict(self) -> dict:
        """The content of rectify.json (lists, OpenCV's names)."""
        return {"cameras": list(self.names), "image_size": list(self.image_size),
                "layout": "vertical" if self.vertical else "horizontal", "keep": self.keep,
                "baseline_mm": self.baseline_mm,
                **{k: getattr(self, k).tolist() for k in ("R1", "R2", "P1", "P2", "Q")}}


def _relative_pose(rig: RigModel, first: str, second: str) -> tuple[np.ndarray, np.ndarray]:
    """``R, T`` with ``X_second = R X_first + T`` (mm), from the rig's poses relative to the reference."""
    for name in (first, second):
        if name not in rig.cameras:
            raise InputError(f"camera {name!r} is not in the calibration (cameras: {', '.join(rig.cameras)})")
        if name != rig.reference and name not in rig.rig:
            raise InputError(f"camera {name!r} has no pose relative to {rig.reference!r} (rig mode "
                             f"{rig.rig_mode!r}): calibrate with --rig rigid or paper to rectify a pair")
    if first == second:
        raise InputError(f"a stereo pair needs two different cameras, got {first!r} twice")
    pose = rig.pose_from_reference(second).compose(rig.pose_from_reference(first).inverse())
    return pose.R, pose.t_mm


def _rectifying_rotations(R: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """OpenCV's ``R1, R2`` for ``X_2 = R X_1 + T`` and whether the rig is vertical (module docstring)."""
    half = rotation_from_rotvec(-0.5 * rotvec_from_rotation(R))
    t = half @ T
    axis = 0 if abs(t[0]) >= abs(t[1]) else 1
    target = np.zeros(3)
    target[axis] = 1.0 if t[axis] > 0 else -1.0
    w = np.cross(t, target)
    nw = np.linalg.norm(w)
    angle = np.arccos(min(1.0, abs(t[axis]) / np.linalg.norm(t)))
    W = rotation_from_rotvec(w * (angle / nw)) if nw > 0 else np.eye(3)
    return W @ half.T, W @ half, axis == 1


def _traced_border(cam: CameraModel, R: np.ndarray) -> dict[str, np.ndarray]:
    """Each image edge (``left, right, top, bottom``) in rectified normalised coordinates."""
    out = {}
    for edge, uv in _border_pixels(cam.image_size).items():
        rays = np.column_stack([ideal_normalized_from_pixel(cam, uv), np.ones(len(uv))]) @ R.T
        if np.any(rays[:, 2] <= 0):
            raise EstimationError("the rectifying rotation turns part of the image behind the camera: "
                                  "the two cameras are too far from parallel to rectify")
        out[edge] = rays[:, :2] / rays[:, 2:]
    return out


def stereo_rectify(rig: RigModel, first: str, second: str, keep: str = "valid") -> StereoRectification:
    """The stereo rectification of cameras ``first`` (OpenCV's camera 1) and ``second`` of ``rig``.

    Parameters
    ----------
    rig : RigModel
        the calibration.
    first, second : str
        camera names; any two cameras with a pose relative to the reference.
    keep : str
        ``"valid"``: the rectified images show the region both photos fill, with no empty
        border (OpenCV's ``alpha = 0``); ``"all"``: every pixel of both photos is kept (empty
        borders appear where a photo has no pixels, OpenCV's ``alpha = 1``).

    Returns
    -------
    StereoRectification
        OpenCV's ``R1 R2 P1 P2 Q``, the common camera and whether the rig is vertical.

    Raises
    ------
    InputError
        Unknown ``keep`` or camera, the same camera twice, a camera without a relative pose.
    NotInvertibleError
        A camera's distortion folds over inside its image.
    EstimationError
        The two rectified photos do not overlap, or the cameras are too far from parallel.
    """
    if keep not in KEEP_REGIONS:
        raise InputError(f"--keep {keep!r} is unknown (choose from {', '.join(KEEP_REGIONS)})")
    R, T = _relative_pose(rig, first, second)
    if not np.linalg.norm(T) > 0:
        raise EstimationError(f"cameras {first!r} and {second!r} share their perspective centre: no baseline")
    cams = [rig.cameras[first], rig.cameras[second]]
    for cam in cams:
        check_invertible_in_image(cam)
    R1, R2, vertical = _rectifying_rotations(R, T)
    borders = [_traced_border(cam, Rk) for cam, Rk in zip(cams, (R1, R2))]
    if keep == "all":
        xy = np.vstack([e for b in borders for e in b.values()])
        (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
    else:   # inside every traced edge of both photos
        x0 = max(b["left"][:, 0].max() for b in borders)
        x1 = min(b["right"][:, 0].min() for b in borders)
        y0 = max(b["top"][:, 1].max() for b in borders)
        y1 = min(b["bottom"][:, 1].min() for b in borders)
    if not (x1 > x0 and y1 > y0):
        raise EstimationError(f"the rectified photos of {first!r} and {second!r} do not overlap")
    f = float(min(min(c.fx, c.fy) for c in cams))
    size = (int(np.floor((x1 - x0) * f)) + 1, int(np.floor((y1 - y0) * f)) + 1)
    if size[0] * size[1] > _MAX_AREA_RATIO * max(c.image_size[0] * c.image_size[1] for c in cams):
        raise EstimationError(f"the rectified images of {first!r} and {second!r} would be {size[0]}x{size[1]} px: "
                              "the cameras are too far from parallel for a useful rectification (try --keep valid)")
    camera = CameraModel(size, f, f, 0.0, float(-x0 * f), float(-y0 * f))
    K = camera.K
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K, (K @ (R2 @ T)).reshape(3, 1)])
    axis = 1 if vertical else 0
    P2[1 - axis, 3] = 0.0           # exactly zero: R2 T lies on the axis up to rounding
    P2[2, 3] = 0.0
    Q = np.array([[1.0, 0.0, 0.0, -camera.cx], [0.0, 1.0, 0.0, -camera.cy], [0.0, 0.0, 0.0, f],
                  [0.0, 0.0, -1.0 / (R2 @ T)[axis], 0.0]])
    return StereoRectification((first, second), R1, R2, P1, P2, Q, camera, vertical, keep)


def rectify_points(rect: StereoRectification, name: str, cam: CameraModel, uv_px: np.ndarray) -> np.ndarray:
    """Observed pixels (N, 2) of camera ``name`` -> their pixels (N, 2) in its rectified image.

    NaN rows (corners not measured) stay NaN.

    Parameters
    ----------
    rect : StereoRectification
        The rectification (:func:`stereo_rectify`).
    name : str
        The camera, one of ``rect.names``.
    cam : CameraModel
        That camera's model (``rig.cameras[name]``).
    uv_px : (N, 2) ndarray
        Pixels as the camera observed them.

    Returns
    -------
    (N, 2) ndarray
        Their pixels in the rectified image: corresponding points share a row (a column for a vertical rig).
    """
    uv_px = np.asarray(uv_px, float)
    out = np.full(uv_px.shape, np.nan)
    ok = np.all(np.isfinite(uv_px), axis=1)
    rays = np.column_stack([ideal_normalized_from_pixel(cam, uv_px[ok]), np.ones(ok.sum())]) @ rect.rotation(name).T
    K = rect.camera.K
    out[ok] = (rays @ K.T)[:, :2] / rays[:, 2:]
    return out


def _blur_sigma_px(cam: CameraModel, rect: StereoRectification) -> float:
    """Gaussian sigma (source px) that removes what the reduction to ``rect``'s focal length cannot show.

    A photo reduced by ``s = f_photo / f'`` needs a low-pass of about ``0.5 sqrt(s^2 - 1)`` px
    (the usual pre-filter for resampling); none below ``s = 1.2``.
    """
    s = min(cam.fx, cam.fy) / rect.camera.fx
    return 0.5 * float(np.sqrt(s * s - 1.0)) if s > 1.2 else 0.0


def rectify_pair_files(rig: RigModel, rect: StereoRectification, photos: dict[str, Path], out_dir: Path,
                       jobs: int = 2, band_rows: int = DEFAULT_BAND_ROWS) -> dict[str, Path]:
    """Rectify one photo of each camera of ``rect`` into ``out_dir/<NAME>-<stem><suffix>`` (a DNG's: ``.tif``).

    ``photos[name]`` is the photo of camera ``name`` (of its calibrated size; read and written
    as :func:`dualcal.files.rectify.undistort_file` does, EXIF kept). Both are done at once (threads,
    :func:`dualcal.parallel.interruptible_map`). Returns ``{name: rectified path}``.
    """
    from ..parallel import interruptible_map

    dests = {name: Path(out_dir) / f"{name}-{Path(photos[name]).stem}{output_suffix(photos[name])}"
             for name in rect.names}

    def work(name):
        cam = rig.cameras[name]
        return undistort_file(photos[name], dests[name], cam, rect.camera, band_rows, R=rect.rotation(name),
                              blur_sigma_px=_blur_sigma_px(cam, rect))

    return dict(zip(rect.names, interruptible_map(work, rect.names, jobs)))


def epipolar_check_image(images: list[np.ndarray], vertical: bool, lines: int = 24,
                         max_side_px: int = 2400) -> np.ndarray:
    """Both rectified images side by side (stacked for a vertical rig) with lines across both.

    ``images``: two (H, W, 3) uint8 RGB arrays of one size. The lines run along the rows
    (along the columns for a vertical rig), ``lines`` of them, alternately green and magenta:
    a point and its correspondence lie on the same line. Scaled so that the long side is at
    most ``max_side_px``.
    """
    both = np.concatenate(images, axis=0 if vertical else 1)
    scale = min(1.0, max_side_px / max(both.shape[:2]))
    if scale < 1:
        both = cv2.resize(both, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    both = np.ascontiguousarray(both)
    h, w = both.shape[:2]
    span = w if vertical else h
    for k, pos in enumerate(np.linspace(0, span - 1, lines + 2)[1:-1]):
        colour = (0, 200, 0) if k % 2 == 0 else (220, 0, 220)
        p = int(round(pos))
        ends = ((p, 0), (p, h - 1)) if vertical else ((0, p), (w - 1, p))
        cv2.line(both, *ends, colour, 1, cv2.LINE_AA)
    return both
