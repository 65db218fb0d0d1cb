"""Photo-like synthetic chessboard photos with exactly known geometry.

A rendered photo is the board seen through the full camera model of :mod:`dualcal.geometry.camera`
(distortion included), so every inner corner sits exactly where
:func:`~dualcal.geometry.camera.project_points` puts it. For each pixel centre ``(u, v)``:

1. pixels -> distorted normalised coordinates (``A^-1``, paper eq. 24), then Newton on the
   radial polynomial (paper eqs. 25-27, :func:`~dualcal.geometry.camera.undistort_normalized`) -> the
   ideal ray ``(x, y, 1)``;
2. the ray meets the board plane ``Z = 0``: ``(X, Y, 1) ~ H^-1 (x, y, 1)`` with
   ``H = [r1 r2 t]`` (paper eq. 2 without ``A``); the third component is ``1 / Z_cam`` and
   must be positive;
3. the board's reflectance is box-filtered over the pixel's footprint, analytically: the
   checker is ``(1 + sq(X) sq(Y)) / 2`` with a square wave ``sq``, and every term is a
   product of one-dimensional piecewise-constant functions whose box average is a difference
   of their antiderivatives. The footprint is the axis-aligned box (in board millimetres)
   spanned by one pixel; it is centred on the pixel's board point, so the filter is
   point-symmetric and cannot move a corner;
4. beyond the board's white margin lies a cluttered room (random boxes, discs and bars);
   light falls off towards the image corners (vignetting) and along a random direction
   (uneven lighting), the lens blurs (a Gaussian, and where the photo is out of focus a disc:
   the defocus of an aperture, both point-symmetric), and the sensor adds signal-dependent noise;
5. optionally, a phone's processing of the photo (:class:`PhoneProcessing`): denoising, an
   unsharp mask and JPEG compression, all point-symmetric filters too but for JPEG's 8 x 8 blocks.

The photo is produced in horizontal bands (with a halo for the blur), so memory stays
bounded at 12 MP. :func:`write_photo_set` writes a whole synthetic rig as JPEG files.

Board layout (see :mod:`dualcal.geometry.board`): squares ``a = -1 .. cols-1``, ``b = -1 .. rows-1``
(black where ``a + b`` is even), then a white margin of ``margin_squares`` squares, then the
background.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..geometry.board import Board, shape_basis
from ..geometry.camera import CameraModel, check_invertible_in_image, project_points, ray_directions
from ..files.io import write_jpeg_atomic
from ..geometry.model import Pose
from ..parallel import interruptible_map
from ..progress import progress_bar
from .render_charuco import MarkerTexture, marker_darkness, marker_texture
from .render_circles import circle_darkness
from .render_marks import marks_texture

__all__ = ["board_height_mm", "shaped_corners_mm", "render_view", "write_photo_set", "photo_seed", "PhoneProcessing",
           "defocus_kernel", "process_like_a_phone"]


# ---------------------------------------------------------------------- 1-D box averages

def _square_wave_integral(x: np.ndarray, s: float) -> np.ndarray:
    """Antiderivative of the square wave ``sq(x) = +1`` on ``[2ks, (2k+1)s)``, ``-1`` elsewhere.

    ``sq`` has zero mean, so the antiderivative is the periodic triangle wave starting at 0.
    """
    q = x * (0.5 / s)
    return s * (1.0 - np.abs(2.0 * (q - np.floor(q)) - 1.0))


def _box_mean(F, x: np.ndarray, h: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Mean over ``[x - h, x + h]`` of ``f * 1[lo, hi]``, where ``F`` is an antiderivative of ``f``."""
    return (F(np.clip(x + h, lo, hi)) - F(np.clip(x - h, lo, hi))) / (2.0 * h)


def _reflectance(X: np.ndarray, Y: np.ndarray, hX: np.ndarray, hY: np.ndarray, board: Board,
                 margin_mm: float, white: float, black: float, background: np.ndarray,
                 markers: MarkerTexture | None = None, inverted: bool = False) -> np.ndarray:
    """Box-filtered reflectance at board points ``(X, Y)`` mm with footprint half-widths ``hX, hY``.

    ``markers``: a ChArUco board's markers (:mod:`dualcal.synthetic.render_charuco`) or a chessboard's marks
    (:mod:`dualcal.synthetic.render_marks`), drawn in its white squares. ``inverted``: the other squares black.
    """
    s = board.square_mm
    tri = lambda x: _square_wave_integral(x, s)  # noqa: E731
    ident = lambda x: x                          # noqa: E731
    # the printed area: a chessboard's squares a = -1 .. cols-1, b = -1 .. rows-1, or a circle grid's circles
    x0, x1, y0, y1 = board.pattern_extent_mm()
    if board.is_circle_grid:
        black_share = circle_darkness(board, X, Y, hX, hY)
    else:
        inside = _box_mean(ident, X, hX, x0, x1) * _box_mean(ident, Y, hY, y0, y1)
        product = _box_mean(tri, X, hX, x0, x1) * _box_mean(tri, Y, hY, y0, y1)
        black_share = 0.5 * (inside + product)          # black where sq(X) sq(Y) = +1, i.e. a + b even
        if board.black_parity() != inverted:            # OpenCV's legacy ChArUco layout: the other squares
            black_share = inside - black_share
    if markers is not None:
        black_share = black_share + marker_darkness(markers, X, Y, hX, hY)
    paper = (_box_mean(ident, X, hX, x0 - margin_mm, x1 + margin_mm)
             * _box_mean(ident, Y, hY, y0 - margin_mm, y1 + margin_mm))
    return background * (1.0 - paper) + white * paper - (white - black) * black_share


# ---------------------------------------------------------------------- pixels -> board

def board_height_mm(board: Board, X: np.ndarray, Y: np.ndarray, shape_mm) -> np.ndarray:
    """Height ``Z`` (mm) of a shaped board at board points ``(X, Y)`` mm.

    ``shape_mm``: the three coefficients of the model of :data:`~dualcal.geometry.board.SHAPE_TERMS`,
    with :func:`~dualcal.geometry.board.shape_basis`'s scaling over the corner grid (``x' = -1 .. 1`` from
    corner column 0 to ``cols - 1``), extended beyond it over the outer squares and the margin; or any
    smooth function ``(X, Y) -> Z`` of board millimetres (a sheet whose edge curls up, which that model
    does not hold)."""
    if callable(shape_mm):
        return np.asarray(shape_mm(X, Y), float)
    X, Y = np.broadcast_arrays(np.asarray(X, float), np.asarray(Y, float))
    corners = board.object_points_mm()[:, :2]
    basis = shape_basis(np.column_stack([X.ravel(), Y.ravel()]), (corners.min(axis=0), corners.max(axis=0)))
    return (basis @ np.asarray(shape_mm, float)).reshape(X.shape)


def board_coordinates(cam: CameraModel, pose: Pose, u: np.ndarray, v: np.ndarray, board: Board | None = None,
                      shape_mm=None):
    """Board point seen by each pixel centre.

    Parameters
    ----------
    cam, pose : the camera and its board-to-camera pose (``X_cam = R X_board + t``).
    u, v : (W,) and (B,) pixel coordinates of the columns and rows of a band.
    board, shape_mm : a board that is not flat: its shape coefficients (:func:`board_height_mm`), or None
        for a plane.

    Returns
    -------
    X, Y : (B, W) board coordinates, mm (for a shaped board, of the surface point the ray meets).
    front : (B, W) bool, True where the ray meets the board in front of the camera.
    """
    yd = ((v - cam.cy) / cam.fy)[:, None]
    xd = (u[None, :] - cam.cx - cam.skew * yd) / cam.fx
    ray = ray_directions(cam, np.stack(np.broadcast_arrays(xd, yd), axis=-1))   # (B, W, 3): (x, y, 1) or a fisheye's
    if shape_mm is not None:
        return _surface_coordinates(pose, ray, board, shape_mm)
    x, y, z = ray[..., 0], ray[..., 1], ray[..., 2]
    Hinv = np.linalg.inv(np.column_stack([pose.R[:, 0], pose.R[:, 1], pose.t_mm]))
    w = Hinv[2, 0] * x + Hinv[2, 1] * y + Hinv[2, 2] * z      # = 1 / (distance along the ray)
    front = w > 0
    w = np.where(front, w, 1.0)
    X = (Hinv[0, 0] * x + Hinv[0, 1] * y + Hinv[0, 2] * z) / w
    Y = (Hinv[1, 0] * x + Hinv[1, 1] * y + Hinv[1, 2] * z) / w
    return X, Y, front


def shaped_corners_mm(board: Board, shape_mm=None) -> np.ndarray:
    """(N, 3) the board's inner corners, mm, raised to the height :func:`board_height_mm` gives them
    (``shape_mm`` None: flat); for the model's coefficients the same as
    :func:`~dualcal.geometry.board.shaped_points_mm`."""
    X = board.object_points_mm()
    if shape_mm is not None:
        X[:, 2] = board_height_mm(board, X[:, 0], X[:, 1], shape_mm)
    return X


def _surface_coordinates(pose: Pose, ray: np.ndarray, board: Board, shape_mm, tol_mm: float = 1e-7,
                         iterations: int = 100):
    """:func:`board_coordinates` on the shaped board ``Z = h(X, Y)`` (:func:`board_height_mm`).

    In the board's frame each ray is ``O + lam d`` (``O = -R^T t``, ``d = R^T ray``); it meets the level
    ``Z = h`` at ``lam = (h - O_z) / d_z``. Fixed point: start on the plane ``h = 0``, take the height of
    the surface under the point found, meet that level, again. It contracts while the surface's slope
    along the ray, times ``|d_xy| / |d_z|``, is below 1 (a sheet curled by a few mm over a square or
    two, seen up to 70 degrees off frontal); a ray that grazes the surface (no fixed point in
    ``iterations``) is taken as not meeting it.
    """
    origin = -pose.R.T @ pose.t_mm
    d = (ray @ pose.R).reshape(-1, 3)                      # R^T ray, one row per pixel
    dz = np.where(np.abs(d[:, 2]) > 1e-12, d[:, 2], 1e-12)
    h = np.zeros(len(d))
    converged = np.zeros(len(d), bool)
    active = np.arange(len(d))
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(iterations):
            lam = (h[active] - origin[2]) / dz[active]
            h_new = board_height_mm(board, origin[0] + lam * d[active, 0], origin[1] + lam * d[active, 1], shape_mm)
            done = np.abs(h_new - h[active]) < tol_mm
            h[active] = h_new
            converged[active[done]] = True
            active = active[~done & np.isfinite(h_new)]
            if len(active) == 0:
                break
    lam = (h - origin[2]) / dz
    front = (converged & (lam > 0)).reshape(ray.shape[:-1])
    X = np.where(front, (origin[0] + lam * d[:, 0]).reshape(front.shape), 0.0)
    Y = np.where(front, (origin[1] + lam * d[:, 1]).reshape(front.shape), 0.0)
    return X, Y, front


# ---------------------------------------------------------------------- optics and processing

def defocus_kernel(radius_px: float, samples: int = 8) -> np.ndarray:
    """(n, n) float32 point-spread function of a defocused lens: a uniform disc (pillbox) of ``radius_px``,
    each pixel weighed by the share of its area inside the disc (``samples x samples`` points a pixel), summing
    to 1. Point-symmetric, so it blurs a corner without moving it."""
    r = float(radius_px)
    half = int(np.ceil(r))
    sub = (np.arange(samples) + 0.5) / samples - 0.5
    x = (np.arange(-half, half + 1)[:, None] + sub[None, :]).ravel()
    inside = (x[:, None] ** 2 + x[None, :] ** 2 <= r * r).astype(np.float32)
    n = 2 * half + 1
    k = inside.reshape(n, samples, n, samples).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


@dataclass(frozen=True)
class PhoneProcessing:
    """What a phone's camera app does to a photo after the sensor: denoising, sharpening, JPEG.

    ``denoise``: the spatial standard deviation (px) of an edge-preserving bilateral filter (OpenCV's, its
    range 3 x the photo's noise in grey levels; 0: none). ``sharpen`` and ``sharpen_sigma_px``: an unsharp
    mask, ``I + sharpen (I - G_sigma * I)`` (0: none; phones use 0.5-1.5 at 1-2 px, which leaves a light halo
    along each edge). ``quality``: the JPEG quality the photo is compressed at and decoded from (None: not
    compressed here; :func:`write_photo_set` writes its own JPEG anyway).
    """

    denoise: float = 1.0
    sharpen: float = 0.8
    sharpen_sigma_px: float = 1.5
    quality: int | None = 85


def process_like_a_phone(img: np.ndarray, processing: PhoneProcessing, noise: float = 0.0) -> np.ndarray:
    """``img`` (H, W) uint8 as a phone's processing leaves it (:class:`PhoneProcessing`); ``noise`` the sensor's
    noise at full white (units of full scale), which sets the denoiser's range."""
    out = img
    if processing.denoise > 0:
        sigma_grey = max(3.0 * noise * 255.0, 2.0)
        d = 2 * int(np.ceil(2 * processing.denoise)) + 1
        out = cv2.bilateralFilter(out, d, sigma_grey, processing.denoise)
    if processing.sharpen > 0:
        soft = cv2.GaussianBlur(out, (0, 0), processing.sharpen_sigma_px)
        out = cv2.addWeighted(out, 1.0 + processing.sharpen, soft, -processing.sharpen, 0.0)
    if processing.quality is not None:
        ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(processing.quality)])
        out = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    return out


# ---------------------------------------------------------------------- the photo

def render_view(cam: CameraModel, pose: Pose, board: Board, rng: np.random.Generator | None = None, *,
                blur_px: float = 1.2, noise: float = 0.012, white: float = 0.88, black: float = 0.07,
                margin_squares: float = 0.8, vignetting: float = 0.3, uneven_light: float = 0.15,
                background: float = 0.3, clutter: int = 80, band_rows: int = 256,
                glare: Sequence[tuple[float, float, float, float]] = (),
                shadow: tuple[float, float, float, float] | None = None,
                outliers: Sequence[tuple[int, float, float]] = (),
                swapped_markers: Sequence[tuple[int, int]] = (), marks: str | None = None,
                inverted: bool = False, shape_mm: Sequence[float] | None = None, defocus_px: float = 0.0,
                processing: PhoneProcessing | None = None) -> np.ndarray:
    """Render the board as photographed by ``cam`` at ``pose``.

    Parameters
    ----------
    cam : camera model; ``cam.image_size = (W, H)`` sets the photo size.
    pose : board-to-camera pose.
    board : the chessboard (inner corners and square size), a ChArUco board with a known
        dictionary and layout (its markers drawn with :mod:`dualcal.synthetic.render_charuco`), or a
        circle grid (its circles drawn with :mod:`dualcal.synthetic.render_circles`).
    rng : random generator for the lighting direction, background and sensor noise
        (``None``: a fixed seed).
    blur_px : standard deviation of the Gaussian optical blur, pixels (0: none).
    defocus_px : radius of the disc a defocused lens spreads a point into, pixels (0: in focus); applied
        after the Gaussian blur (:func:`defocus_kernel`). A phone's photo taken too close, or focused on
        the room behind the board, blurs the squares' edges over 5-20 px at full size.
    processing : the phone's processing after the sensor (:class:`PhoneProcessing`: denoising, sharpening,
        JPEG), or None (the sensor's pixels as they are).
    noise : standard deviation of the sensor noise at full white, in units of full scale;
        it scales with the square root of the signal (shot noise) plus a read-noise floor.
    white, black : reflectance of the paper and of the black squares (0..1).
    margin_squares : white margin around the outer ring of squares (a circle grid: around half a spacing
        beyond its outer circles), in squares (spacings).
    vignetting : relative light loss at the image corners.
    uneven_light : relative change of light across the image along a random direction.
    background : reflectance beyond the board's edge, under the clutter (with smooth shading).
    clutter : number of random shapes (boxes, discs, bars of random grey) drawn in the
        background, as the room behind a board in a real photo (0: a plain background).
    band_rows : rows rendered at once (bounds memory: about 100 bytes per pixel of a band).
    glare : specular highlights, each ``(u, v, radius_px, strength)``: light added to the
        signal (in units of full white) as a Gaussian of standard deviation ``radius_px``; where
        the sum passes full white the sensor saturates. One on a dark square can wash it out.
    shadow : ``(angle_rad, offset_px, depth, softness_px)``: the light is dimmed by ``depth``
        (0..1) beyond the line at signed distance ``offset_px`` from the image centre, normal
        ``(cos angle, sin angle)``, with a soft edge of width ``softness_px``.
    outliers : planted bad corners, each ``(k, dX_mm, dY_mm)``: around inner corner ``k`` the
        board is drawn shifted by ``(dX_mm, dY_mm)`` along its X and Y (rigidly within a fifth of
        a square, fading out by half a square), so the photo shows that corner at board point
        ``X_k + (dX, dY)`` while :func:`~dualcal.geometry.camera.project_points` still gives the true
        one. Shifts up to 0.19 of a square are drawn exactly (the shading does not fold).
    swapped_markers : planted misread ids of a ChArUco board, each ``(i, j)``: marker ``i`` is
        drawn with the code of id ``j``, so a detector reads id ``j`` in marker ``i``'s square.
    marks : marks printed in a plain chessboard's white squares, one of
        :data:`dualcal.synthetic.render_marks.MARK_KINDS` (``code``, ``dots``, ``logo``, ``text``); the same
        board in every photo. None: plain white squares.
    inverted : a chessboard printed with the other squares black: square ``(-1, -1)`` is white
        (as on BoofCV's ECoCheck boards); where ``cols + rows`` is even no corner then has a black
        square diagonally outside it with the frame right-handed into the board.
    shape_mm : a board that is not flat (a sheet of paper curled on a table, a sagging card): the three
        coefficients of :data:`~dualcal.geometry.board.SHAPE_TERMS`, mm, or a function ``(X, Y) -> Z`` mm
        (:func:`board_height_mm`); the sheet's outer squares and margin follow the same surface. The
        surface must not hide part of itself from the camera (no fold seen edge-on).

    Returns
    -------
    (H, W) uint8 image. Corner ``k`` of the board sits at ``project_points(cam, pose.apply(X_k))``
    (except the ``outliers``), where for a shaped board ``X_k`` is raised to the height
    :func:`board_height_mm` gives it (:func:`shaped_corners_mm`).
    """
    check_invertible_in_image(cam)
    rng = np.random.default_rng(0) if rng is None else rng
    W, H = cam.image_size
    r_corner = np.hypot(max(cam.cx, W - 1 - cam.cx), max(cam.cy, H - 1 - cam.cy))
    light = rng.normal(size=2)
    light *= uneven_light / (np.linalg.norm(light) * r_corner)
    bg_phase = rng.uniform(0, 2 * np.pi, 3)
    bg_freq = rng.uniform(1.0, 3.0, 3) * 2 * np.pi / max(W, H)
    margin_mm = margin_squares * board.square_mm
    halo = (int(np.ceil(4 * blur_px)) + 1 if blur_px > 0 else 0) + int(np.ceil(defocus_px))
    disc = defocus_kernel(defocus_px) if defocus_px > 0 else None
    c0, c1, b0, b1 = _board_support(cam, pose, board, margin_mm, shape_mm)
    u = np.arange(W, dtype=float)
    du = (u - cam.cx).astype(np.float32)
    bg_u = [np.sin(bg_freq[0] * u + bg_phase[0]), np.sin(bg_freq[2] * u + bg_phase[2]),
            np.cos(bg_freq[2] * u + bg_phase[2])]
    scene = _clutter((W, H), rng, clutter, background)
    markers = marker_texture(board, swapped_markers) if board.charuco is not None else None
    if marks is not None:
        markers = marks_texture(board, marks, inverted=inverted)

    out = np.empty((H, W), np.uint8)
    for r0 in range(0, H, band_rows):
        r1 = min(H, r0 + band_rows)
        a0, a1 = max(0, r0 - halo), min(H, r1 + halo)
        v = np.arange(a0, a1, dtype=float)
        dv = (v - cam.cy).astype(np.float32)[:, None]
        # smooth background texture, separable in u and v (sin(a+b) = sin a cos b + cos a sin b)
        w2 = bg_freq[2] * v + bg_phase[2]
        shading = (1.0 + 0.25 * np.outer(np.sin(bg_freq[1] * v + bg_phase[1]), bg_u[0])
                   + 0.1 * (np.outer(np.cos(w2), bg_u[1]) + np.outer(np.sin(w2), bg_u[2])))
        refl = shading * (scene[a0:a1] * (1.0 / 255.0))
        rows = slice(max(a0, b0) - a0, min(a1, b1) - a0)
        if rows.stop - rows.start > 1 and c1 - c0 > 1:    # (a single row or column: the margin's edge)
            X, Y, front = board_coordinates(cam, pose, u[c0:c1], v[rows], board, shape_mm)
            X, Y = _plant_outliers(X, Y, board, outliers)
            # footprint of one pixel in board mm (axis-aligned, centred: symmetric)
            hX = 0.5 * (np.abs(np.gradient(X, axis=1)) + np.abs(np.gradient(X, axis=0))) + 1e-9
            hY = 0.5 * (np.abs(np.gradient(Y, axis=1)) + np.abs(np.gradient(Y, axis=0))) + 1e-9
            bg = refl[rows, c0:c1]
            refl[rows, c0:c1] = np.where(front, _reflectance(X, Y, hX, hY, board, margin_mm,
                                                             white, black, bg, markers, inverted), bg)
        gain = ((1.0 - (vignetting / r_corner**2) * (du * du + dv * dv))
                * (1.0 + light[0] * du + light[1] * dv))
        if shadow is not None:
            angle, offset, depth, soft = shadow
            dist = np.cos(angle) * (u - 0.5 * (W - 1))[None, :] + np.sin(angle) * (v - 0.5 * (H - 1))[:, None]
            gain = gain * (1.0 - depth / (1.0 + np.exp(-(dist - offset) / max(soft, 1e-3)))).astype(np.float32)
        signal = refl.astype(np.float32) * gain
        for gu, gv, radius, strength in glare:
            signal = signal + (strength * np.exp(-((u[None, :] - gu) ** 2 + (v[:, None] - gv) ** 2)
                                                 / (2.0 * radius**2))).astype(np.float32)
        if blur_px > 0:
            signal = cv2.GaussianBlur(signal, (0, 0), blur_px, borderType=cv2.BORDER_REFLECT)
        if disc is not None:
            signal = cv2.filter2D(signal, -1, disc, borderType=cv2.BORDER_REFLECT)
        signal = signal[r0 - a0: r0 - a0 + (r1 - r0)]
        if glare:
            signal = np.minimum(signal, 1.0)                # the sensor saturates
        sigma = noise * np.sqrt(0.1 + 0.9 * np.clip(signal, 0.0, None))
        noisy = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
        out[r0:r1] = np.clip(np.rint(noisy * 255.0), 0, 255).astype(np.uint8)
    return out if processing is None else process_like_a_phone(out, processing, noise)


def _plant_outliers(X: np.ndarray, Y: np.ndarray, board: Board, outliers) -> tuple[np.ndarray, np.ndarray]:
    """Board coordinates with the neighbourhood of each planted corner shifted (see :func:`render_view`)."""
    s = board.square_mm
    for k, dX, dY in outliers:
        r, c = divmod(int(k), board.cols)
        rho = np.hypot(X - c * s, Y - r * s) / (0.5 * s)
        # 1 within a fifth of a square of the corner, 0 beyond half a square, cosine between
        w = 0.5 + 0.5 * np.cos(np.pi * np.clip((rho - 0.4) / 0.6, 0.0, 1.0))
        X, Y = X - dX * w, Y - dY * w
    return X, Y


def _clutter(size: tuple[int, int], rng: np.random.Generator, shapes: int, level: float) -> np.ndarray:
    """(H, W) uint8 background reflectance (x 255): ``shapes`` random boxes, discs and bars."""
    W, H = size
    scene = np.full((H, W), int(round(255 * level)), np.uint8)
    scale = max(W, H)
    for _ in range(shapes):
        grey = (int(rng.uniform(0.08, 0.85) * 255),)
        kind = int(rng.integers(3))
        cx, cy, extent = rng.uniform(0, W), rng.uniform(0, H), rng.uniform(0.02, 0.3) * scale
        if kind == 0:
            box = cv2.boxPoints(((cx, cy), (extent, extent * rng.uniform(0.2, 1.0)), rng.uniform(0, 180)))
            cv2.fillConvexPoly(scene, np.int32(np.rint(box)), grey, cv2.LINE_AA)
        elif kind == 1:
            cv2.circle(scene, (int(cx), int(cy)), int(extent / 2), grey, -1, cv2.LINE_AA)
        else:
            end = (int(cx + rng.normal() * extent), int(cy + rng.normal() * extent))
            cv2.line(scene, (int(cx), int(cy)), end, grey, max(1, int(0.05 * extent)), cv2.LINE_AA)
    return scene


def _board_support(cam: CameraModel, pose: Pose, board: Board, margin_mm: float, shape_mm=None):
    """Columns ``[c0, c1)`` and rows ``[r0, r1)`` of the image that can see the board's paper.

    The paper's outline, densely sampled and projected, bounds its image (the board lies in
    front of the camera and the distortion is invertible), plus a few pixels for the filter.
    Where part of the board is behind the camera the whole image is returned.
    """
    W, H = cam.image_size
    x0, x1, y0, y1 = board.pattern_extent_mm()
    x0, x1, y0, y1 = x0 - margin_mm, x1 + margin_mm, y0 - margin_mm, y1 + margin_mm
    t = np.linspace(0.0, 1.0, 400)
    edges = np.concatenate([
        np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y0)]),
        np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y1)]),
        np.column_stack([np.full_like(t, x0), y0 + (y1 - y0) * t]),
        np.column_stack([np.full_like(t, x1), y0 + (y1 - y0) * t])])
    Z = np.zeros(len(edges))
    if shape_mm is not None:        # a curved sheet's image may bulge past its outline's: sample it all
        gx, gy = np.meshgrid(x0 + (x1 - x0) * t[::10], y0 + (y1 - y0) * t[::10])
        edges = np.concatenate([edges, np.column_stack([gx.ravel(), gy.ravel()])])
        Z = board_height_mm(board, edges[:, 0], edges[:, 1], shape_mm)
    Xc = pose.apply(np.column_stack([edges, Z]))
    if np.any(Xc[:, 2] <= 0):
        return 0, W, 0, H
    uv = project_points(cam, Xc)
    pad = 4
    c0, r0 = np.floor(uv.min(axis=0)).astype(int) - pad
    c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + pad + 1
    return max(0, c0), min(W, c1), max(0, r0), min(H, r1)


# ---------------------------------------------------------------------- photo sets

def photo_seed(seed: int, cam_index: int, view_index: int) -> np.random.Generator:
    """The random generator of one photo of a set: independent of the order photos are made in."""
    return np.random.default_rng([int(seed), int(cam_index), int(view_index)])


def _write_one(task) -> str:
    cam, pose, board, seed_key, path, quality, render_kwargs = task
    img = render_view(cam, pose, board, photo_seed(*seed_key), **render_kwargs)
    write_jpeg_atomic(path, img, quality)
    return str(path)


def write_photo_set(truth, photo_dir, seed: int = 0, jobs: int | None = None, quality: int = 92,
                    progress: bool = True, marks: str | None = None, **render_kwargs) -> dict[str, dict[str, Path]]:
    """Render every camera and view of a synthetic rig as ``photo_dir/<camera>/<view>.jpg``.

    Parameters
    ----------
    truth
        :class:`~dualcal.synthetic.synth.SynthTruth`.
    photo_dir
        output folder (created with one subfolder per camera).
    seed : int
        seed of the photos' randomness (lighting, background, noise); photo ``(c, v)`` uses
        :func:`photo_seed` ``(seed, c, v)``, so the result does not depend on ``jobs``.
    jobs : int or None
        photos rendered at once, in threads (default: all cores).
    quality : int
        JPEG quality (0-100).
    progress : bool
        draw a progress bar on stderr.
    marks : str or None
        marks printed in the chessboard's white squares (:mod:`dualcal.synthetic.render_marks`: ``code``,
        ``dots``, ``logo``, ``text``), the same board in every photo; None: plain squares.
    **render_kwargs
        passed on to :func:`render_view` (``blur_px``, ``noise``, ``inverted``, ...).

    Returns
    -------
    dict[str, dict[str, Path]]
        ``{camera: {view: path}}`` of the written files.
    """
    photo_dir = Path(photo_dir)
    tasks, paths = [], {}
    for ci, (name, cam) in enumerate(truth.cameras.items()):
        (photo_dir / name).mkdir(parents=True, exist_ok=True)
        paths[name] = {}
        for vi, view in enumerate(truth.view_poses):
            path = photo_dir / name / f"{view}.jpg"
            paths[name][view] = path
            tasks.append((cam, truth.camera_pose(name, view), truth.board, (seed, ci, vi), path,
                          quality, dict(render_kwargs, marks=marks)))
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(tasks)))
    with progress_bar("rendering photos", len(tasks), enabled=progress) as advance:
        # threads: numpy's array loops, OpenCV's blur and JPEG encoding release the GIL
        for _ in interruptible_map(_write_one, tasks, jobs):
            advance()
    return paths
