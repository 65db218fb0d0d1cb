"""Photo-like renders of a textured object (no board): measurement photos with exactly known geometry.

A :class:`TexturedBox` is a box (three edge lengths, mm) at a pose in the reference camera's frame,
its six faces printed with a random texture (shapes of random grey at many scales over fine grain, as
packaging or a wooden crate shows), in front of a textured wall. A rendered photo is the scene seen
through the full camera model, like :mod:`dualcal.synthetic.render`'s board: for each pixel centre the
ray of the camera (its lens undone, :func:`~dualcal.geometry.camera.ray_directions`) meets the nearest
face; the texture is sampled there from a pyramid of the texture (the level of the pixel's footprint
on the face, blended between the two nearest: trilinear, so a tele and a wide see the same texture at
their own resolution); then the lens blurs (a Gaussian) and the sensor adds signal-dependent noise.

The ground truth of a tap is :meth:`TexturedBox.surface_point`: the surface point a ray meets, so the
point a pixel shows is known exactly (up to the texture's own interpolation).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from ..geometry.camera import CameraModel, check_invertible_in_image, ray_directions
from ..geometry.model import Pose

__all__ = ["TexturedBox", "render_object", "texture_image"]

#: Texture image size, px per face (square; each face's texture is stretched over it).
TEXTURE_PX = 1024
#: Most points a pixel's footprint is read at along its long axis (a face seen more obliquely is filtered as at
#: this slant).
ANISOTROPY = 8
#: The wall behind the box, mm beyond its centre, and its half-width.
WALL_BEHIND_MM, WALL_HALF_MM = 400.0, 4000.0


def texture_image(seed: int, size_px: int = TEXTURE_PX) -> np.ndarray:
    """(size, size) float32 reflectance in 0.05-0.95: random boxes, discs and strokes of random grey at scales
    from a fiftieth to a third of the side, over fine grain (a smoothed noise a few texels wide)."""
    rng = np.random.default_rng([int(seed), 7])
    img = np.full((size_px, size_px), 0.5, np.float32)
    for _ in range(400):
        grey = float(rng.uniform(0.1, 0.9))
        cx, cy = rng.uniform(0, size_px, 2)
        extent = float(np.exp(rng.uniform(np.log(0.02), np.log(0.33))) * size_px)
        kind = int(rng.integers(3))
        if kind == 0:
            box = cv2.boxPoints(((cx, cy), (extent, extent * rng.uniform(0.2, 1.0)), rng.uniform(0, 180)))
            cv2.fillConvexPoly(img, np.int32(np.rint(box)), grey, cv2.LINE_AA)
        elif kind == 1:
            cv2.circle(img, (int(cx), int(cy)), max(1, int(extent / 2)), grey, -1, cv2.LINE_AA)
        else:
            end = (int(cx + rng.normal() * extent), int(cy + rng.normal() * extent))
            cv2.line(img, (int(cx), int(cy)), end, grey, max(1, int(0.06 * extent)), cv2.LINE_AA)
    grain = cv2.GaussianBlur(rng.normal(0.0, 1.0, img.shape).astype(np.float32), (0, 0), 1.5)
    img = img + 0.12 * grain / grain.std()
    return np.clip(img, 0.05, 0.95)


def _pyramid(texture: np.ndarray, levels: int = 8) -> list[np.ndarray]:
    out = [texture]
    while len(out) < levels and min(out[-1].shape) > 8:
        out.append(cv2.pyrDown(out[-1]))
    return out


def _remap_flat(image: np.ndarray, u: np.ndarray, v: np.ndarray, width: int = 4096) -> np.ndarray:
    """``image`` bilinearly at points ``(u, v)`` (N,) (OpenCV's maps are 2-D and under 32767 a side)."""
    n = len(u)
    rows = -(-n // width)
    maps = [np.zeros(rows * width, np.float32) for _ in range(2)]
    maps[0][:n], maps[1][:n] = u, v
    out = cv2.remap(image, maps[0].reshape(rows, width), maps[1].reshape(rows, width), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT)
    return out.ravel()[:n]


def _trilinear(pyramid: list[np.ndarray], st_mm: np.ndarray, texel: np.ndarray, level: np.ndarray) -> np.ndarray:
    """The texture at face points ``st_mm`` (N, 2), read at mip ``level`` (N,), blended between its two levels.

    Texel ``j`` of level 0 is centred at ``s = (j + 0.5) texel``; ``cv2.pyrDown`` centres level ``k``'s pixel ``j`` on
    level 0's pixel ``2^k j``."""
    lo = np.floor(level).astype(int)
    value = np.zeros(len(st_mm))
    for L in np.unique(lo):
        sel = lo == L
        for k, w in ((L, 1.0 - (level[sel] - L)), (L + 1, level[sel] - L)):
            scale = 2.0 ** k
            value[sel] += w * _remap_flat(pyramid[k], (st_mm[sel, 0] / texel[0] - 0.5) / scale,
                                          (st_mm[sel, 1] / texel[1] - 0.5) / scale)
    return value


@dataclass(frozen=True)
class _Face:
    origin: np.ndarray       # (3,) a corner, reference frame, mm
    s_axis: np.ndarray       # (3,) unit, along the first side
    t_axis: np.ndarray       # (3,) unit, along the second side
    size_mm: tuple[float, float]
    texture: int             # index into the textures

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.s_axis, self.t_axis)


@dataclass(frozen=True)
class TexturedBox:
    """A textured box in front of a textured wall (module docstring).

    ``pose``: box frame -> reference camera frame (``X_ref = R X_box + t``), the box frame at the box's
    centre, its axes along the edges; ``size_mm`` (3,) the edges' lengths; ``seed`` of the textures.
    """

    pose: Pose
    size_mm: tuple[float, float, float]
    seed: int = 0
    faces: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        half = np.asarray(self.size_mm, float) / 2
        R, t = self.pose.R, self.pose.t_mm
        faces = []
        for axis in range(3):
            a, b = [i for i in range(3) if i != axis]
            for sign in (-1.0, 1.0):
                corner = np.zeros(3)
                corner[axis] = sign * half[axis]
                corner[a], corner[b] = -half[a], -half[b]
                faces.append(_Face(R @ corner + t, R[:, a], R[:, b], (2 * half[a], 2 * half[b]), len(faces)))
        centre = t
        back = centre / np.linalg.norm(centre)
        wall_centre = centre + back * (WALL_BEHIND_MM + half.max())
        s = np.cross([0.0, 1.0, 0.0], back)
        s /= np.linalg.norm(s)
        tt = np.cross(back, s)
        faces.append(_Face(wall_centre - WALL_HALF_MM * (s + tt), s, tt, (2 * WALL_HALF_MM, 2 * WALL_HALF_MM),
                           len(faces)))
        object.__setattr__(self, "faces", tuple(faces))

    @cached_property
    def _textures(self) -> list[list[np.ndarray]]:
        return [_pyramid(texture_image(self.seed * 100 + f.texture)) for f in self.faces]

    def corners_mm(self) -> np.ndarray:
        """(8, 3) the box's corners in the reference frame."""
        half = np.asarray(self.size_mm, float) / 2
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        return self.pose.apply(signs * half)

    def _hits(self, centre: np.ndarray, directions: np.ndarray):
        """Nearest face along rays ``centre + lam d`` (d (N, 3)): ``lam`` (N,), face index (N,; -1 none),
        face coordinates ``(s, t)`` mm (N, 2)."""
        n = len(directions)
        best = np.full(n, np.inf)
        index = np.full(n, -1)
        st = np.zeros((n, 2))
        for i, f in enumerate(self.faces):
            den = directions @ f.normal
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = ((f.origin - centre) @ f.normal) / den
            X = centre + lam[:, None] * directions
            s, t = (X - f.origin) @ f.s_axis, (X - f.origin) @ f.t_axis
            hit = (np.abs(den) > 1e-12) & (lam > 0) & (lam < best) & (s >= 0) & (s <= f.size_mm[0]) \
                & (t >= 0) & (t <= f.size_mm[1])
            best = np.where(hit, lam, best)
            index = np.where(hit, i, index)
            st = np.where(hit[:, None], np.column_stack([s, t]), st)
        return best, index, st

    def surface_point(self, centre_mm, direction) -> np.ndarray:
        """(3,) the first surface point (box or wall) the ray ``centre + lam direction`` meets, reference frame;
        NaN where it meets none."""
        d = np.asarray(direction, float)[None]
        lam, index, _ = self._hits(np.asarray(centre_mm, float), d)
        return (np.asarray(centre_mm, float) + lam[0] * d[0]) if index[0] >= 0 else np.full(3, np.nan)

    def shade(self, centre: np.ndarray, directions: np.ndarray, footprint_mm: np.ndarray) -> np.ndarray:
        """Reflectance seen along rays (N, 3) from ``centre`` whose pixels span ``footprint_mm`` (N,) per mm of
        distance (the pixel's angular size), the texture filtered over the pixel's footprint on the face: an
        ellipse ``lam a`` across the slant and ``lam a / cos(theta)`` along it (``theta`` the ray's angle to the
        face's normal). The texture is read at the level of the ellipse's short axis (trilinear) at up to
        :data:`ANISOTROPY` points spread along its long axis, averaged (anisotropic filtering), so that a tele and
        a wide see a slanted face blurred alike, as optics and pixels blur it."""
        lam, index, st = self._hits(centre, directions)
        out = np.full(len(directions), 0.5)
        for i, f in enumerate(self.faces):
            on = index == i
            if not on.any():
                continue
            pyramid = self._textures[i]
            texel = np.array(f.size_mm) / pyramid[0].shape[::-1]
            d = directions[on] / np.linalg.norm(directions[on], axis=1, keepdims=True)
            cos = np.maximum(np.abs(d @ f.normal), 1.0 / ANISOTROPY)
            short = lam[on] * footprint_mm[on]                                       # mm
            along = np.column_stack([d @ f.s_axis, d @ f.t_axis])                     # the slant, in (s, t)
            along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-12)
            extra = short * (1.0 / cos - 1.0)                                        # long axis beyond the short
            taps = int(np.clip(np.ceil(np.max(1.0 / cos)), 1, ANISOTROPY))
            level = np.clip(np.log2(np.maximum(short / texel.min(), 1.0)), 0, len(pyramid) - 1.001)
            value = np.zeros(on.sum())
            for t in (np.arange(taps) + 0.5) / taps - 0.5:                         # spread along the long axis
                value += _trilinear(pyramid, st[on] + (t * extra)[:, None] * along, texel, level) / taps
            out[on] = value
        return out


def render_object(cam: CameraModel, pose: Pose, scene: TexturedBox, rng: np.random.Generator | None = None, *,
                  blur_px: float = 1.0, noise: float = 0.01, band_rows: int = 256) -> np.ndarray:
    """Render ``scene`` as photographed by ``cam`` at ``pose`` (reference frame -> camera).

    Parameters
    ----------
    cam : CameraModel
        The camera; ``cam.image_size`` sets the photo's size.
    pose : Pose
        ``X_cam = R X_ref + t_mm``.
    scene : TexturedBox
        The box and its wall.
    rng : numpy.random.Generator or None
        The sensor noise's generator (None: a fixed seed).
    blur_px : float
        The lens's Gaussian blur, px (0: none).
    noise : float
        Sensor noise at full white, in units of full scale (shot noise: with the square root of the signal,
        over a read-noise floor).
    band_rows : int
        Rows rendered at once.

    Returns
    -------
    (H, W) uint8 image, stored frame.
    """
    check_invertible_in_image(cam)
    rng = np.random.default_rng(0) if rng is None else rng
    W, H = cam.image_size
    centre = pose.center_mm
    u = np.arange(W, dtype=float)
    signal = np.empty((H, W), np.float32)
    pixel_angle = 1.0 / min(cam.fx, cam.fy)
    for r0 in range(0, H, band_rows):
        v = np.arange(r0, min(H, r0 + band_rows), dtype=float)
        yd = ((v - cam.cy) / cam.fy)[:, None]
        xd = (u[None, :] - cam.cx - cam.skew * yd) / cam.fx
        rays = ray_directions(cam, np.stack(np.broadcast_arrays(xd, yd), axis=-1)).reshape(-1, 3)
        lengths = np.linalg.norm(rays, axis=1)
        directions = (rays / lengths[:, None]) @ pose.R             # reference frame
        # a pixel's angular size shrinks off-axis by the ray's length (pinhole: 1 / |(x, y, 1)|^2 per axis)
        footprint = pixel_angle / lengths
        signal[r0:r0 + len(v)] = scene.shade(centre, directions, footprint).reshape(len(v), W)
    if blur_px > 0:
        signal = cv2.GaussianBlur(signal, (0, 0), blur_px, borderType=cv2.BORDER_REFLECT)
    sigma = noise * np.sqrt(0.1 + 0.9 * np.clip(signal, 0.0, None))
    noisy = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
    return np.clip(np.rint(noisy * 255.0), 0, 255).astype(np.uint8)
