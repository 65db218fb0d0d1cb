"""Sessions of one webcam as peers record them, with known truth: what tests/test_zhang.py and
``benchmarks/bench_weak_views.py`` calibrate from.

caliscope's 12-corner ChArUco board (:data:`dualcal.synthetic.synth_caliscope.CALISCOPE_BOARD`) held by hand in front
of one of its webcams (:data:`WEBCAMS`): small in the frame, anywhere in it (partly out of it: 4-12 corners seen), near
square-on; or, for a session that cannot fix a camera, every board square-on near the middle of the frame.
"""

from __future__ import annotations

import numpy as np

from dualcal.geometry.camera import CameraModel
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_rotvec
from dualcal.synthetic.synth import SynthTruth, seen_pixels
from dualcal.synthetic.synth_caliscope import CALISCOPE_BOARD, make_caliscope_truth

#: caliscope's four webcams (1280 x 720, OpenCV's five coefficients, k1 from -0.33 to +0.03), as
#: dualcal.synthetic.synth_caliscope draws them.
WEBCAMS = list(make_caliscope_truth(moments=1).cameras.values())


def peer_session(cam: CameraModel, views: int, seed: int, tilt_deg=(0.0, 40.0), share=(0.05, 0.15),
                 reach=(-0.02, 1.02)) -> SynthTruth:
    """One webcam's session: the board's width ``share`` of the frame's, its centre anywhere in the frame
    (``reach``, in shares of the frame: the board partly out of it), tilted ``tilt_deg`` toward the camera and
    turned any way about its normal; ``views`` views with at least 4 corners in the frame. The camera is ``cam``."""
    rng = np.random.default_rng(seed)
    X = CALISCOPE_BOARD.object_points_mm()
    width = (CALISCOPE_BOARD.cols + 1) * CALISCOPE_BOARD.square_mm
    poses = {}
    while len(poses) < views:
        distance = cam.fx * width / (rng.uniform(*share) * cam.image_size[0])
        u, v = rng.uniform(*reach, 2) * cam.image_size
        at = np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0]) * distance
        phi = rng.uniform(0, 2 * np.pi)
        R = rotation_from_rotvec(np.radians(rng.uniform(*tilt_deg)) * np.array([np.cos(phi), np.sin(phi), 0.0])) \
            @ rotation_from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        pose = Pose(R, at - R @ X.mean(axis=0))
        if np.isfinite(seen_pixels(cam, pose, X)[:, 0]).sum() >= 4:
            poses[f"{len(poses):04d}"] = pose
    return SynthTruth(CALISCOPE_BOARD, {"cam": cam}, "cam", {}, poses)


def square_on_session(cam: CameraModel, seed: int, views: int = 30) -> SynthTruth:
    """``views`` views of the board seen square-on near the middle of the frame, 1-3 m away: no perspective, so no
    focal length."""
    rng = np.random.default_rng(seed)
    poses = {}
    for i in range(views):
        R = rotation_from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        at = np.array([rng.uniform(-100, 100), rng.uniform(-60, 60), rng.uniform(1000, 3000)])
        poses[f"{i:04d}"] = Pose(R, at - R @ CALISCOPE_BOARD.object_points_mm().mean(axis=0))
    return SynthTruth(CALISCOPE_BOARD, {"cam": cam}, "cam", {}, poses)
