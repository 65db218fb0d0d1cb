"""Synthetic clips with known truth: a board carried by hand, filmed by two or more cameras at once.

A :class:`VideoTruth` is a rig (:class:`~dualcal.synthetic.synth.SynthTruth`: its cameras, the pose of
each relative to the reference and the board poses where the board is held) and a motion through
time: the board is held at each of those poses for a while (with a hand's tremor), then carried to
the next along a smooth (minimum-jerk) path, and, if asked, carried out of view a few times between
holds (``away``). Every camera films it at its own frame rate from its own
start: camera ``c``'s frame ``j`` is exposed at the reference's clock time ``offset_s[c] + j / fps[c]``
(the reference's ``offset_s`` is 0), as two streams that one app starts are a few frames and a
fraction of a frame apart (the contract's ``video.offset_s``). A frame's time is its exposure's middle;
with a rolling shutter (``readout_s``) the middle of its middle row's, the rows above exposed earlier.

Each frame is rendered as :mod:`dualcal.synthetic.render` renders a photo (the same exact box-filtered
board, clutter behind it, vignetting, lens blur, sensor noise), with the motion within the exposure
averaged over sub-frames (motion blur), and the clip is encoded as a phone encodes it: H.264 (or HEVC)
in an ``.mp4``, a key frame a second and no B-frames, at constant quality or a phone's bit rate (PyAV, the
``video`` extra). The rays of every pixel and the frame without the board are computed once per camera, so
a frame costs a few array operations over the board's part of the image and its sensor noise.
:data:`VIDEO_PRESETS` are rigs as phones film them: note8's wide and tele in 1080p and 4K.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..extras import require
from ..files.io import write_bytes_atomic
from ..geometry.camera import CameraModel, check_invertible_in_image, ray_directions
from ..geometry.model import Pose
from ..geometry.rotation import rotation_from_rotvec, rotvec_from_rotation
from ..progress import progress_bar
from .render import _board_support, _clutter, _reflectance
from .synth import PRESETS, SynthTruth, make_truth, scale_camera

__all__ = ["VIDEO_PRESETS", "VideoTruth", "encode_clip", "make_video_truth", "phone_video_rig", "render_frame",
           "tracked_corners", "video_truth_doc", "write_clips"]


def phone_video_rig(width_px: int, still_preset: str = "note8") -> dict:
    """A phone's rig as it films: the lenses of ``still_preset`` (its photos stored upright, 4:3) on the
    sensor as it lies (landscape), the 16:9 band of its rows that video keeps, resampled to ``width_px``
    wide (1920: 1080p, 3840: 4K). A rig as :data:`dualcal.synthetic.synth.PRESETS` holds one.

    An upright photo's pixel ``(u, v)`` is the lying sensor's ``(v, W - 1 - u)`` (``W`` the photo's width):
    camera coordinates turn by ``Q`` (a quarter turn about the optical axis), every lens's ``fx`` and
    ``fy`` swap, and the rig's poses become ``Q R Q^T``, ``Q t``.
    """
    p = PRESETS[still_preset]
    Q = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cameras = {}
    for name, cam in p["cameras"].items():
        W, H = cam.image_size                                      # upright: W < H
        band = round(H * 9 / 16)                                   # the 16:9 rows of the lying sensor
        lying = replace(cam, image_size=(H, band), fx=cam.fy, fy=cam.fx, cx=cam.cy,
                        cy=(W - 1 - cam.cx) - (W - band) / 2, skew=0.0)
        cameras[name] = scale_camera(lying, width_px / H)
    rig = {n: Pose(Q @ q.R @ Q.T, Q @ q.t_mm) for n, q in p["rig"].items()}
    return {**p, "cameras": cameras, "rig": rig}


#: Rigs as phones film them (:func:`phone_video_rig`): note8's wide and tele in 1080p and 4K video.
VIDEO_PRESETS = {"phone-1080p": lambda: phone_video_rig(1920), "phone-4k": lambda: phone_video_rig(3840)}


def _min_jerk(s: np.ndarray) -> np.ndarray:
    """The minimum-jerk profile 10 s^3 - 15 s^4 + 6 s^5 on [0, 1] (a hand's reach: no jerk at its ends)."""
    s = np.clip(s, 0.0, 1.0)
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


@dataclass
class VideoTruth:
    """A board's motion and the cameras that film it (module docstring).

    ``route`` are the poses the board is held at, in order (default: ``truth.view_poses``); ``hold_s[i]``
    the time it is held at pose ``i``, ``move_s[i]`` the time it takes to carry it from pose ``i`` to
    ``i + 1``; ``tremor_mm`` and ``tremor_deg`` the amplitudes of the hand's tremor (smooth, a few hertz,
    all the time).
    """

    truth: SynthTruth
    hold_s: np.ndarray
    move_s: np.ndarray
    fps: dict[str, float]
    offset_s: dict[str, float]
    exposure_s: float = 1 / 60
    readout_s: float = 0.0
    tremor_mm: float = 0.15
    tremor_deg: float = 0.015
    seed: int = 0
    route: list[Pose] | None = None
    _tremor: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        rng = np.random.default_rng([self.seed, 7])
        # 6 components (3 rotation, 3 translation) x 3 sinusoids: frequency (Hz), phase, weight
        self._tremor = np.stack([rng.uniform(0.8, 3.0, (6, 3)), rng.uniform(0, 2 * np.pi, (6, 3)),
                                 rng.normal(0, 1 / np.sqrt(3), (6, 3))], axis=-1)

    @property
    def holds(self) -> list[tuple[float, float]]:
        """``(start_s, end_s)`` of every hold, reference clock."""
        starts = np.concatenate([[0.0], np.cumsum(self.hold_s[:-1] + self.move_s)])
        return [(float(a), float(a + h)) for a, h in zip(starts, self.hold_s)]

    @property
    def duration_s(self) -> float:
        return float(self.hold_s.sum() + self.move_s.sum())

    def board_pose(self, t_s: float) -> Pose:
        """Board-to-reference-camera pose at reference clock time ``t_s`` (held, carried, with tremor)."""
        poses = self.route or list(self.truth.view_poses.values())
        holds = self.holds
        i = int(np.clip(np.searchsorted([a for a, _ in holds], t_s, side="right") - 1, 0, len(holds) - 1))
        a, b = holds[i]
        if t_s <= b or i == len(holds) - 1:
            base = poses[i]
        else:
            s = float(_min_jerk(np.array((t_s - b) / self.move_s[i])))
            p, q = poses[i], poses[i + 1]
            R = rotation_from_rotvec(s * rotvec_from_rotation(q.R @ p.R.T)) @ p.R
            base = Pose(R, (1 - s) * p.t_mm + s * q.t_mm)
        f, phase, w = np.moveaxis(self._tremor, -1, 0)
        wave = np.sum(w * np.sin(2 * np.pi * f * t_s + phase), axis=1)      # (6,), each about unit amplitude
        turn = rotation_from_rotvec(np.radians(self.tremor_deg) * wave[:3])
        return Pose(turn @ base.R, base.t_mm + self.tremor_mm * wave[3:])

    def frame_times(self, camera: str) -> np.ndarray:
        """Reference clock times of camera ``camera``'s frames, from its first (exposed at its ``offset_s``:
        before the reference's first where that is negative, the board then held at its first pose) to the
        end of the motion."""
        start = self.offset_s[camera]
        last = int(np.floor((self.duration_s - start) * self.fps[camera]))
        return start + np.arange(last + 1) / self.fps[camera]

    def camera_pose(self, camera: str, t_s: float) -> Pose:
        return self.truth.seen_by(camera, self.board_pose(t_s))


def make_video_truth(preset: str = "stereo", holds: int = 12, seed: int = 0, scale: float = 1.0,
                     fps: float = 30.0, offset_frames: float = 3.4, hold_s: tuple[float, float] = (0.6, 1.2),
                     move_s: tuple[float, float] = (0.5, 0.9), readout_s: float = 0.0,
                     exposure_s: float = 1 / 60, away: int = 0, **truth_options) -> VideoTruth:
    """A synthetic rig (``preset``, :func:`~dualcal.synthetic.synth.make_truth`, or one of
    :data:`VIDEO_PRESETS`) filmed as clips.

    Parameters
    ----------
    holds : how many times the board is held still (at the poses of ``make_truth``, each seen whole by
        every camera).
    fps : every camera's frame rate.
    offset_frames : when every other camera starts, after the reference, in frames (whole frames and a
        fraction; negative: before it).
    hold_s, move_s : the ranges of the times the board is held and carried (drawn per hold).
    readout_s : a rolling shutter's readout time, top row to bottom row (0: a global shutter).
    exposure_s : each frame's exposure (the motion within it blurs the frame).
    away : that many times, spread over the clip, the board is carried out of every camera's view (to the
        side, below or above: three times as far off the reference's axis as it is in front of it) and held
        there before the next hold, as a board is lowered or carried aside: frames without it, and frames
        that show part of it.
    """
    rig = VIDEO_PRESETS[preset]() if preset in VIDEO_PRESETS else preset
    truth = make_truth(rig, holds, seed, scale, **truth_options)
    route = list(truth.view_poses.values())
    sides = np.array([[3.0, 0, 0], [0, 3.0, 0], [-3.0, 0, 0], [0, -3.0, 0]])
    for k, after in enumerate(sorted(np.linspace(0, holds - 1, away + 2)[1:-1].round().astype(int), reverse=True)):
        held = route[after]
        route.insert(after + 1, Pose(held.R, held.t_mm + sides[k % 4] * held.t_mm[2]))
    rng = np.random.default_rng([seed, 3])
    names = list(truth.cameras)
    return VideoTruth(truth, rng.uniform(*hold_s, len(route)), rng.uniform(*move_s, len(route) - 1),
                      dict.fromkeys(names, float(fps)),
                      {n: (0.0 if n == truth.reference else offset_frames / fps) for n in names},
                      exposure_s=exposure_s, readout_s=readout_s, seed=seed, route=route if away else None)


# ---------------------------------------------------------------------------- frames


@dataclass
class _Scene:
    """What one camera's frames share: its pixels' rays, the room behind the board, the light, and the
    frame without the board (:meth:`empty`), blurred and with its noise's sigma, which a frame differs from
    only around the board."""

    cam: CameraModel
    rays: np.ndarray          # (H, W, 3)
    background: np.ndarray    # (H, W) reflectance of the room
    gain: np.ndarray          # (H, W) float32, vignetting and uneven light
    _empty: dict = field(default_factory=dict, repr=False)

    def empty(self, blur_px: float, noise: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(H, W) float32 each: the room lit, the same blurred by ``blur_px``, and the sensor noise's sigma there."""
        key = (blur_px, noise)
        if key not in self._empty:
            lit = (self.background * self.gain).astype(np.float32)
            blurred = cv2.GaussianBlur(lit, (0, 0), blur_px, borderType=cv2.BORDER_REFLECT) if blur_px > 0 else lit
            self._empty[key] = lit, blurred, _noise_sigma(blurred, noise)
        return self._empty[key]


def _noise_sigma(signal: np.ndarray, noise: float) -> np.ndarray:
    """A sensor's noise (shot and read noise) at ``signal`` (0-1): ``noise`` at full white, a third of it at black."""
    return noise * np.sqrt(0.1 + 0.9 * np.clip(signal, 0.0, None))


def _scene(cam: CameraModel, rng: np.random.Generator, vignetting: float = 0.3, uneven_light: float = 0.15,
           background: float = 0.3, clutter: int = 60) -> _Scene:
    check_invertible_in_image(cam)
    W, H = cam.image_size
    v, u = np.mgrid[0:H, 0:W].astype(float)
    yd = (v - cam.cy) / cam.fy
    xd = (u - cam.cx - cam.skew * yd) / cam.fx
    rays = ray_directions(cam, np.stack([xd, yd], axis=-1))
    du, dv = u - cam.cx, v - cam.cy
    r_corner = np.hypot(max(cam.cx, W - 1 - cam.cx), max(cam.cy, H - 1 - cam.cy))
    light = rng.normal(size=2)
    light *= uneven_light / (np.linalg.norm(light) * r_corner)
    gain = (1.0 - vignetting * (du * du + dv * dv) / r_corner ** 2) * (1.0 + light[0] * du + light[1] * dv)
    room = _clutter((W, H), rng, clutter, background) / 255.0
    return _Scene(cam, rays, room, gain.astype(np.float32))


def _board_plane(rays: np.ndarray, pose: Pose):
    """Board coordinates ``X, Y`` (mm) where each ray meets the board and whether it does in front."""
    Hinv = np.linalg.inv(np.column_stack([pose.R[:, 0], pose.R[:, 1], pose.t_mm]))
    q = rays @ Hinv.T
    front = q[..., 2] > 0
    w = np.where(front, q[..., 2], 1.0)
    return q[..., 0] / w, q[..., 1] / w, front


def _span(boxes) -> tuple[int, int, int, int]:
    """The box ``(c0, c1, r0, r1)`` that holds every one of ``boxes``."""
    return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))


def render_frame(scene: _Scene, poses: list[Pose], board, rng: np.random.Generator, *, blur_px: float = 0.8,
                 noise: float = 0.012, white: float = 0.88, black: float = 0.07,
                 margin_squares: float = 0.8) -> np.ndarray:
    """One frame: the board at each of ``poses`` (board to this camera, one per sub-frame of the exposure;
    with a rolling shutter a pair, the top row's and the bottom row's pose, the rows between interpolated),
    averaged (motion blur), then lens blur and sensor noise. Returns (H, W) uint8.

    Only the board's surroundings are computed: elsewhere the frame is the scene's :meth:`_Scene.empty` and
    its noise (the lens blur reaches ``ceil(4 blur_px) + 1`` px at most, OpenCV's kernel's radius).
    """
    cam = scene.cam
    W, H = cam.image_size
    margin_mm = margin_squares * board.square_mm
    lit, signal, sigma = (a.copy() for a in scene.empty(blur_px, noise))
    pairs = [pose if isinstance(pose, tuple) else (pose, pose) for pose in poses]
    boxes = [_span([_board_support(cam, p, board, margin_mm) for p in pair]) for pair in pairs]
    c0, c1, r0, r1 = _span(boxes)
    if c1 - c0 > 1 and r1 - r0 > 1:
        acc = np.zeros((r1 - r0, c1 - c0))
        for rows_pose, (a0, a1, b0, b1) in zip(pairs, boxes):
            refl = scene.background[r0:r1, c0:c1].copy()
            if a1 - a0 > 1 and b1 - b0 > 1:
                rays = scene.rays[b0:b1, a0:a1]
                if rows_pose[0] is rows_pose[1]:
                    X, Y, front = _board_plane(rays, rows_pose[0])
                else:     # a rolling shutter: each row its own time, the pose between top and bottom row's
                    share = (np.arange(b0, b1) / max(H - 1, 1))[:, None]
                    Xa, Ya, fa = _board_plane(rays, rows_pose[0])
                    Xb, Yb, fb = _board_plane(rays, rows_pose[1])
                    X, Y, front = (1 - share) * Xa + share * Xb, (1 - share) * Ya + share * Yb, fa & fb
                hX = 0.5 * (np.abs(np.gradient(X, axis=1)) + np.abs(np.gradient(X, axis=0))) + 1e-9
                hY = 0.5 * (np.abs(np.gradient(Y, axis=1)) + np.abs(np.gradient(Y, axis=0))) + 1e-9
                bg = refl[b0 - r0:b1 - r0, a0 - c0:a1 - c0]
                bg[...] = np.where(front, _reflectance(X, Y, hX, hY, board, margin_mm, white, black, bg), bg)
            acc += refl
        lit[r0:r1, c0:c1] = (acc / len(pairs)) * scene.gain[r0:r1, c0:c1]
        # the blur of the board's surroundings, from a box wide enough that its own edges do not reach them
        reach = int(np.ceil(4 * blur_px)) + 1 if blur_px > 0 else 0
        p0, q0 = max(r0 - 2 * reach, 0), max(c0 - 2 * reach, 0)
        part = lit[p0:min(r1 + 2 * reach, H), q0:min(c1 + 2 * reach, W)]
        if blur_px > 0:
            part = cv2.GaussianBlur(part, (0, 0), blur_px, borderType=cv2.BORDER_REFLECT)
        y0, x0 = max(r0 - reach, 0), max(c0 - reach, 0)
        y1, x1 = min(r1 + reach, H), min(c1 + reach, W)
        signal[y0:y1, x0:x1] = part[y0 - p0:y1 - p0, x0 - q0:x1 - q0]
        sigma[y0:y1, x0:x1] = _noise_sigma(signal[y0:y1, x0:x1], noise)
    noisy = sigma
    noisy *= rng.standard_normal(signal.shape, dtype=np.float32)
    noisy += signal
    noisy *= 255.0
    np.rint(noisy, out=noisy)
    return np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)


#: Motion blur: sub-frames so that the board moves at most this many pixels between two (at most
#: :data:`MAX_SUBFRAMES`; fast motion then shows as a few ghosts, in frames no corner is taken from).
SUBFRAME_STEP_PX = 1.0
MAX_SUBFRAMES = 8


def _exposure_poses(video: VideoTruth, camera: str, t_s: float) -> list:
    """The sub-frames' poses of the frame exposed around ``t_s`` (with a rolling shutter, each a pair:
    the top row's and the bottom row's pose)."""
    cam, board = video.truth.cameras[camera], video.truth.board
    X = board.object_points_mm()[[0, board.cols - 1, -1]]
    e, r = video.exposure_s, video.readout_s

    def pixels(t):
        Xc = video.camera_pose(camera, t).apply(X)
        return cam.fx * Xc[:, :2] / Xc[:, 2:]

    moved = np.abs(pixels(t_s + e / 2 + r / 2) - pixels(t_s - e / 2 - r / 2)).max()
    n = int(np.clip(np.ceil(moved / SUBFRAME_STEP_PX), 1, MAX_SUBFRAMES))
    times = t_s + e * ((np.arange(n) + 0.5) / n - 0.5) if n > 1 else np.array([t_s])
    if r <= 0:
        return [video.camera_pose(camera, t) for t in times]
    return [(video.camera_pose(camera, t - r / 2), video.camera_pose(camera, t + r / 2)) for t in times]


def encode_clip(frames, size: tuple[int, int], fps: float, crf: int = 18, codec: str = "libx264",
                rotation_deg: int = 0, bitrate_mbps: float | None = None) -> bytes:
    """An .mp4 of grey ``frames`` (an iterable of (H, W) uint8) as a phone records it: H.264 (``codec``
    ``"libx265"``: HEVC), yuv420p, a key frame every second and no B-frames (a camera's real-time encoder),
    with the display rotation a phone held upright writes (``rotation_deg``); at constant quality ``crf``, or
    at the bit rate ``bitrate_mbps`` (phones: about 17 Mbit/s in 1080p, 50 in 4K)."""
    require("video")
    import av

    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as container:
        stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = size
        stream.pix_fmt = "yuv420p"
        stream.codec_context.gop_size = max(1, round(fps))
        stream.codec_context.max_b_frames = 0
        # (x265's veryfast takes minutes a second of 1080p: its ultrafast, as a phone's hardware encoder, is quick)
        stream.options = {"preset": "ultrafast" if codec == "libx265" else "veryfast"}
        if bitrate_mbps:
            stream.bit_rate = int(bitrate_mbps * 1e6)
        else:
            stream.options["crf"] = str(crf)
        if codec == "libx265":
            stream.options["x265-params"] = "log-level=error"
        if rotation_deg:
            stream.set_display_rotation(rotation_deg)
        for img in frames:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="gray").reformat(format="yuv420p")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return buffer.getvalue()


def write_clips(video: VideoTruth, clip_dir, seed: int = 0, progress: bool = True, crf: int = 18,
                codec: str = "libx264", cameras=None, **render_options) -> dict[str, Path]:
    """Render and encode every camera's clip (or those of ``cameras``) as ``clip_dir/<camera>.mp4``; returns
    ``{camera: path}``.

    ``codec`` as :func:`encode_clip` takes it (``"libx265"``: HEVC); ``render_options`` go to
    :func:`render_frame` (``blur_px``, ``noise``, ...). Camera sizes must be even (H.264's 4:2:0 sampling).
    """
    clip_dir = Path(clip_dir)
    paths = {}
    chosen = [n for n in video.truth.cameras if cameras is None or n in cameras]
    total = sum(len(video.frame_times(c)) for c in chosen)
    with progress_bar("rendering clips", total, enabled=progress) as advance:
        for ci, (name, cam) in enumerate(video.truth.cameras.items()):
            if name not in chosen:
                continue
            rng = np.random.default_rng([seed, ci, 11])
            scene = _scene(cam, rng)

            def frames():
                for t in video.frame_times(name):
                    yield render_frame(scene, _exposure_poses(video, name, t), video.truth.board, rng, **render_options)
                    advance()

            paths[name] = clip_dir / f"{name}.mp4"
            write_bytes_atomic(paths[name], encode_clip(frames(), cam.image_size, video.fps[name], crf, codec))
    return paths


def tracked_corners(video: VideoTruth, camera: str, noise_px: float = 0.0, seed: int = 0):
    """A camera's board as a tracker would follow it, without rendering: ``(times_s, uv_px)``, each frame's
    time from the clip's first frame (F,) and the exact corners at its exposure's middle (F, N, 2) plus
    Gaussian noise of ``noise_px`` per coordinate; NaN where the camera does not see the whole board."""
    from .synth import seen_pixels

    rng = np.random.default_rng([seed, 5])
    times = video.frame_times(camera)
    X = video.truth.board.object_points_mm()
    uv = np.array([seen_pixels(video.truth.cameras[camera], video.camera_pose(camera, t), X) for t in times])
    uv[~np.isfinite(uv).all(axis=(1, 2))] = np.nan
    return times - video.offset_s[camera], uv + rng.normal(0.0, noise_px, uv.shape)


def video_truth_doc(video: VideoTruth) -> dict:
    """truth.json's ``video``: the true offsets and the motion's timing, as calib.json's ``video`` says them."""
    return {"reference": video.truth.reference, "fps": dict(video.fps),
            "offset_s": dict(video.offset_s), "offset_sigma_s": dict.fromkeys(video.offset_s, 0.0), "exposure_s": video.exposure_s, "readout_s": video.readout_s,
            "holds_s": [list(h) for h in video.holds], "duration_s": video.duration_s}
