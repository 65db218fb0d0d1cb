"""Duplicate instants and files (issue 24, finding 2): a copied photo or a burst counts once, so the sigmas,
which come from the scatter between instants, hold (synthetic truth, Monte Carlo)."""

from __future__ import annotations

import numpy as np
import pytest

from dualcal.synthetic import synth
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import project_points
from dualcal.estimation.duplicates import find_duplicate_instants, merge_duplicate_instants
from dualcal.files.dataset import duplicate_files
from dualcal.geometry.model import CameraCorners, CornerSet

NOISE_PX = 0.2


def repeated(cs: CornerSet, copies: int, jitter_px: float = 0.0, seed: int = 0) -> CornerSet:
    """Every instant ``copies`` times (``KEY_0`` the original, ``KEY_1``... its copies, moved by white noise of
    ``jitter_px`` per coordinate: a burst)."""
    rng = np.random.default_rng(seed)
    cams = {}
    for name, cam in cs.cameras.items():
        views = {}
        for key, uv in cam.views.items():
            for j in range(copies):
                moved = uv if uv is None or j == 0 else uv + jitter_px * rng.standard_normal(uv.shape)
                views[f"{key}_{j}"] = moved
        cams[name] = CameraCorners(cam.image_size, views, dict(cam.meta))
    return CornerSet(cs.board, cams, cs.reference)


@pytest.fixture(scope="module")
def stereo():
    truth = synth.make_truth("stereo", views=8, seed=1)
    return truth, synth.noisy_corner_set(truth, NOISE_PX, seed=2)


def test_copies_are_found_and_merged_into_the_first(stereo):
    _, cs = stereo
    merged, records = merge_duplicate_instants(repeated(cs, 4))
    assert len(records) == 8
    for r in records:
        base = r["kept"].rsplit("_", 1)[0]
        assert r["kept"] == f"{base}_0" and r["merged"] == [f"{base}_1", f"{base}_2", f"{base}_3"]
        assert max(r["rms_px"].values()) == 0.0
    for cam in merged.cameras.values():
        assert sorted(cam.views) == sorted(f"{k}_0" for k in cs.cameras["left"].views)
        assert cam.meta["duplicates"] == [{"kept": r["kept"], "merged": r["merged"]} for r in records]


def test_a_burst_within_the_noise_is_one_instant_but_a_board_moved_a_little_is_not(stereo):
    _, cs = stereo
    assert len(find_duplicate_instants(repeated(cs, 3, jitter_px=0.3 * NOISE_PX))) == 8
    # the board moved by a tenth of a square (3 mm along its X) between two shots of IMG_01: a new instant
    truth, _ = stereo
    X = truth.board.object_points_mm() + [3.0, 0.0, 0.0]
    rng = np.random.default_rng(5)
    shifted = {name: project_points(cam, truth.camera_pose(name, "IMG_01").apply(X))
               + rng.normal(0.0, NOISE_PX, (len(X), 2)) for name, cam in truth.cameras.items()}
    views = {n: {**c.views, "IMG_01b": shifted[n]} for n, c in cs.cameras.items()}
    with_moved = CornerSet(cs.board, {n: CameraCorners(c.image_size, views[n], {}) for n, c in cs.cameras.items()})
    assert find_duplicate_instants(with_moved) == []


def test_instants_whose_cameras_saw_the_board_differently_are_not_merged(stereo):
    _, cs = stereo
    twice = repeated(cs, 2)
    twice.cameras["right"].views["IMG_01_1"] = None           # the copy's right photo lost its board
    keys = {r["kept"] for r in find_duplicate_instants(twice)}
    assert "IMG_01_0" not in keys and len(keys) == 7


def test_calibrating_copies_gives_the_calibration_of_the_distinct_instants(stereo, capsys):
    _, cs = stereo
    plain = calibrate_rig(cs, board_shape="flat")
    copied = calibrate_rig(repeated(cs, 4), board_shape="flat")
    assert "24 instant(s) repeat another's view" in capsys.readouterr().err
    assert [r["kept"] for r in copied.adjustment["duplicates"]] == sorted(f"{k}_0" for k in cs.cameras["left"].views)
    for name in plain.cameras:
        np.testing.assert_allclose(copied.cameras[name].as_vector(), plain.cameras[name].as_vector(), rtol=1e-9)
        for p, s in plain.camera_sigma[name].items():
            assert copied.camera_sigma[name][p] == pytest.approx(s, rel=1e-6, abs=1e-12)
    assert copied.rig["right"].sigma_baseline_mm == pytest.approx(plain.rig["right"].sigma_baseline_mm, rel=1e-6)


def test_z_scores_of_duplicated_sets_spread_as_they_should():
    """Monte Carlo (synthetic truth, white corner noise of 0.2 px): photo sets whose every position is copied
    4 times, or shot as a burst of 4 with a jitter of 0.3 x the noise, give z = (estimate - truth) / sigma of
    every intrinsic whose spread is 0.8-1.25 (without the merge it is about 1.8: 4 copies halve the sigmas)."""
    z = []
    for seed in range(8):
        truth = synth.make_truth("stereo", views=10, seed=seed)
        cs = repeated(synth.noisy_corner_set(truth, NOISE_PX, seed=seed + 100), 4,
                      jitter_px=0.0 if seed % 2 else 0.3 * NOISE_PX, seed=seed)
        rig = calibrate_rig(cs, board_shape="flat")
        assert len(rig.corners.cameras["left"].views) == 10
        for name, cam in truth.cameras.items():
            z += [(getattr(rig.cameras[name], p) - getattr(cam, p)) / rig.camera_sigma[name][p]
                  for p in ("fx", "fy", "cx", "cy", "k1", "k2")]
    spread = float(np.std(z))
    assert 0.8 <= spread <= 1.25, spread


def test_duplicate_files_by_content(tmp_path):
    files = []
    for name, content in [("a.jpg", b"one"), ("b.jpg", b"two"), ("c.jpg", b"one"), ("d.jpg", b"onf"), ("e.jpg", b"two")]:
        (tmp_path / name).write_bytes(content)
        files.append(tmp_path / name)
    assert duplicate_files(files) == [[files[0], files[2]], [files[1], files[4]]]
    assert duplicate_files(files[:2]) == []


def test_a_copied_partial_view_is_a_duplicate(stereo):
    """A ChArUco board's partial view (a third of its corners) and its copy share every corner they have."""
    _, cs = stereo
    twice = repeated(cs, 2)
    for cam in twice.cameras.values():
        for key in ("IMG_02_0", "IMG_02_1"):
            uv = cam.views[key].copy()
            uv[len(uv) // 3:] = np.nan
            cam.views[key] = uv
    assert len(find_duplicate_instants(twice)) == 8


def test_the_corner_noise_is_estimated_only_where_two_instants_come_close(stereo, monkeypatch):
    """The noise sets the limit of a duplicate; where no two instants are within the limit of the largest
    noise admitted (:data:`MAX_NOISE_PX`), as the set's distinct board positions are not, it is not
    estimated and nothing is merged; with a burst it is, for every camera, and each limit is the camera's own."""
    import dualcal.estimation.duplicates as duplicates

    _, cs = stereo
    calls = []
    real = duplicates.corner_noise_px
    monkeypatch.setattr(duplicates, "corner_noise_px", lambda views, shape: calls.append(len(views)) or real(views, shape))
    assert find_duplicate_instants(cs) == [] and calls == []
    records = find_duplicate_instants(repeated(cs, 2, jitter_px=0.3 * NOISE_PX))
    assert len(records) == 8 and len(calls) == 2
    for r in records:
        for name, limit in r["limit_px"].items():
            assert limit < 4 * np.sqrt(2) * duplicates.MAX_NOISE_PX
            assert limit == pytest.approx(4 * np.sqrt(2) * NOISE_PX, rel=0.3)      # from the noise of 0.2 px


def test_a_camera_that_filmed_the_board_alone_has_its_repeats_merged_whatever_the_others_saw(stereo):
    """caliscope's intrinsic session: each camera filmed the board on its own, so the same key in two cameras is
    no shared moment. The left camera's burst (KEY_1 a copy of KEY_0) is merged for it alone; the right camera's
    frames under the same keys are other views and stay."""
    _, cs = stereo
    burst = repeated(cs, 2, jitter_px=0.01, seed=3)
    other = repeated(cs, 2, jitter_px=0.0, seed=4)
    right = {k: (None if uv is None else uv + 30.0 * (k.endswith("_1"))) for k, uv in other.cameras["right"].views.items()}
    cams = {"left": CameraCorners(burst.cameras["left"].image_size, burst.cameras["left"].views,
                                  {"imported": {"instants_shared": False}}),
            "right": CameraCorners(other.cameras["right"].image_size, right, {"imported": {"instants_shared": False}})}
    merged, records = merge_duplicate_instants(CornerSet(cs.board, cams, cs.reference))
    assert {r["camera"] for r in records} == {"left"}
    assert sorted(merged.cameras["left"].views) == sorted(k for k in burst.cameras["left"].views if k.endswith("_0"))
    assert sorted(merged.cameras["right"].views) == sorted(right)
    # the same corners as one shared session: the right camera's frames differ, so nothing repeats
    shared = CornerSet(cs.board, {n: CameraCorners(c.image_size, c.views, {}) for n, c in cams.items()}, cs.reference)
    assert merge_duplicate_instants(shared)[1] == []
