"""The synthetic caliscope session (dualcal.synthetic.synth_caliscope): as caliscope's extrinsic test session is,
and a truth that OpenCV recovers from what dualcal imports of it."""

from __future__ import annotations

import numpy as np
import pytest

from dualcal.errors import InputError
from dualcal.files.imports import import_files
from dualcal.geometry.camera import project_points
from dualcal.synthetic.synth_caliscope import _sees, make_caliscope_truth, write_caliscope_session


def test_the_session_is_as_caliscope_s_extrinsic_test_session():
    """Four webcams of 1280 x 720, 50+ moments, each seen by three or four cameras, the board small in the frames."""
    truth = make_caliscope_truth(seed=0)
    assert len(truth.cameras) == 4 and len(truth.view_poses) >= 50
    assert all(cam.image_size == (1280, 720) for cam in truth.cameras.values())
    X = truth.board.object_points_mm()
    widths = []
    for view in truth.view_poses:
        seeing = 0
        for name, cam in truth.cameras.items():
            pose = truth.camera_pose(name, view)
            seen = _sees(cam, pose, truth.board)
            if seen.sum() >= 4:
                seeing += 1
                uv = project_points(cam, pose.apply(X[seen]))
                widths.append(np.ptp(uv[:, 0]))
        assert seeing >= 3, view
    assert np.median(widths) < 0.1 * 1280


def test_opencv_recovers_the_true_rig_from_the_imported_session(tmp_path):
    """The imported corners (ids, board frame, pixels) and intrinsics agree with the truth: OpenCV's stereoCalibrate,
    the intrinsics held, finds every pair's relative pose from the exact corners."""
    cv2 = pytest.importorskip("cv2")
    truth = write_caliscope_session(tmp_path / "session", noise_px=0.0)
    imported = import_files("caliscope", [tmp_path / "session"])
    corners = imported.corners
    X = corners.board.object_points_mm().astype(np.float32)
    for other in ("cam_2", "cam_3"):
        a, b = corners.cameras["cam_1"], corners.cameras[other]
        obj, uv_a, uv_b = [], [], []
        for view in sorted(set(a.views) & set(b.views)):
            both = np.isfinite(a.views[view][:, 0]) & np.isfinite(b.views[view][:, 0])
            if both.sum() >= 6:
                obj.append(X[both])
                uv_a.append(a.views[view][both].astype(np.float32))
                uv_b.append(b.views[view][both].astype(np.float32))
        ka, kb = imported.cameras["cam_1"].camera, imported.cameras[other].camera
        _, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(obj, uv_a, uv_b, ka.K, np.array(ka.distortion), kb.K,
                                                        np.array(kb.distortion), ka.image_size,
                                                        flags=cv2.CALIB_FIX_INTRINSIC)
        true = truth.rig[other].compose(truth.rig["cam_1"].inverse())
        assert np.abs(T.ravel() - true.t_mm).max() < 0.01                   # mm, of baselines of 1.4-2.6 m
        assert np.abs(R - true.R).max() < 1e-5


def test_a_session_has_two_to_four_cameras():
    with pytest.raises(InputError, match="2 to 4 cameras, not 5"):
        make_caliscope_truth(cameras=5)
