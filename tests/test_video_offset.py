"""The clocks of two clips matched from the board's motion, and the moments chosen (no rendering: the board's
corners as a tracker follows them, from :func:`dualcal.synthetic.synth_video.tracked_corners`)."""

import numpy as np
import pytest

from dualcal.estimation.duplicates import find_duplicate_instants
from dualcal.estimation.moments import choose_moments
from dualcal.estimation.time_offset import estimate_offsets
from dualcal.synthetic.synth_video import make_video_truth, tracked_corners


def _tracks(video, noise_px=0.05):
    return {n: (*tracked_corners(video, n, noise_px, seed=i), c.image_size)
            for i, (n, c) in enumerate(video.truth.cameras.items())}


@pytest.mark.parametrize("offset_frames, fps, other_fps, seed", [(3.4, 30.0, 30.0, 0), (-2.73, 30.0, 30.0, 1),
                                                                 (0.2, 30.0, 24.0, 2)])
def test_the_offset_is_found_within_2_ms_and_its_sigma(offset_frames, fps, other_fps, seed):
    video = make_video_truth("stereo", holds=6, seed=seed, scale=0.5, fps=fps, offset_frames=offset_frames)
    video.fps["right"] = other_fps                                  # a stream at another frame rate
    found = estimate_offsets(_tracks(video), video.truth.board, "left")
    true = video.offset_s["right"]
    error = found["right"].offset_s - true
    assert abs(error) < 0.002, (found["right"], true)
    assert abs(error) < 4 * found["right"].sigma_s, (found["right"], true)
    assert found["right"].sigma_s < 0.002
    assert found["left"].offset_s == 0.0


def test_clocks_that_never_see_the_board_together_are_not_matched():
    video = make_video_truth("stereo", holds=6, seed=3, scale=0.5)
    tracks = _tracks(video)
    t_ref, uv_ref, size_ref = tracks["left"]
    t_o, uv_o, size_o = tracks["right"]
    # the reference sees the board only in the first half of the clip, the other camera only in the second
    half = 0.5 * video.duration_s
    uv_ref[t_ref > half] = np.nan
    uv_o[t_o + video.offset_s["right"] < half + 0.5] = np.nan
    found = estimate_offsets({"left": (t_ref, uv_ref, size_ref), "right": (t_o, uv_o, size_o)},
                             video.truth.board, "left")
    assert found["right"] is None


def test_moments_are_the_holds_each_camera_at_its_frame_nearest_the_moment():
    video = make_video_truth("stereo", holds=8, seed=4, scale=0.5, offset_frames=2.6)
    tracks = _tracks(video, noise_px=0.02)
    measured = {n: (t, {j: uv for j, uv in enumerate(c) if np.isfinite(uv).all()}) for n, (t, c, _) in tracks.items()}
    offsets = {"left": 0.0, "right": video.offset_s["right"]}
    sizes = {n: c.image_size for n, c in video.truth.cameras.items()}
    choice = choose_moments(measured, video.truth.board, "left", offsets, sizes)
    assert 6 <= len(choice.moment_of) <= 8                         # one per hold (the first and last may be cut)
    holds = video.holds
    for key, j in choice.frames["left"].items():
        assert key == f"f{j:06d}"                                  # keyed by the reference's frame index
        t = measured["left"][0][j]
        assert any(a <= t <= b for a, b in holds)                   # held still
        k = choice.frames["right"].get(key)
        if k is not None:                                          # the other camera's frame nearest that moment
            assert abs(measured["right"][0][k] + offsets["right"] - t) <= 0.5 / 30 + 1e-9


def test_frames_of_one_moment_are_one_instant():
    from dualcal.geometry.model import CameraCorners, CornerSet
    from dualcal.synthetic import synth

    truth = synth.make_truth("stereo", views=4, seed=0, scale=0.5)
    corners = synth.noisy_corner_set(truth, 0.05, seed=0)
    shifted = {n: {f"{v}_b": uv + 2.0 for v, uv in c.views.items()} for n, c in corners.cameras.items()}
    moments = {**{v: i for i, v in enumerate(truth.view_poses)}, **{f"{v}_b": i for i, v in enumerate(truth.view_poses)}}
    both = CornerSet(corners.board, {n: CameraCorners(c.image_size, {**c.views, **shifted[n]},
                                                      {"video": {"moment_of_view": moments}})
                                     for n, c in corners.cameras.items()})
    records = find_duplicate_instants(both)
    assert sorted((r["kept"], tuple(r["merged"])) for r in records) == [(v, (f"{v}_b",)) for v in sorted(truth.view_poses)]
    untagged = CornerSet(both.board, {n: CameraCorners(c.image_size, c.views) for n, c in both.cameras.items()})
    assert find_duplicate_instants(untagged) == []                  # 2 px apart: not the same view by the corners


def test_lenses_whose_clocks_are_not_matched_are_calibrated_alone():
    from dualcal.geometry.model import CameraCorners, CornerSet
    from dualcal.synthetic import synth
    from dualcal.workflow import calibrate_corners

    truth = synth.make_truth("stereo", views=6, seed=0, scale=0.5)
    corners = synth.noisy_corner_set(truth, 0.05)
    left, right = corners.cameras["left"], corners.cameras["right"]
    clips = CornerSet(corners.board, {
        "left": CameraCorners(left.image_size, left.views, {"video": {"offset_s": 0.0}}),
        "right": CameraCorners(right.image_size, {f"right:{k}": v for k, v in right.views.items()}, {"video": {}})})
    rig = calibrate_corners(clips, model="k1k2", compare_lens=False)
    assert rig.rig_mode == "none" and rig.rig == {}
    assert abs(rig.cameras["right"].fx - truth.cameras["right"].fx) < 4 * rig.camera_sigma["right"]["fx"]


def test_split_half_keeps_the_frames_of_a_moment_in_one_half():
    from dualcal.estimation.validation import split_half_z
    from dualcal.synthetic import synth

    truth = synth.make_truth("stereo", views=8, seed=0, scale=0.5)
    corners = synth.noisy_corner_set(truth, 0.05)
    groups = {v: i // 2 for i, v in enumerate(sorted(truth.view_poses))}      # two frames per moment
    halves = []

    def calibrate(half):                       # no calibration needed to check how the instants were split
        halves.append(sorted(half.cameras["left"].views))
        return synth.truth_rig_model(truth, half)

    with np.errstate(invalid="ignore", divide="ignore"):       # the truth's sigmas are 0
        split_half_z(corners, splits=3, groups=groups, calibrate=calibrate)
    for keys in halves:
        moments = {groups[k] for k in keys}
        assert len(keys) == 2 * len(moments)                        # every moment whole in one half
