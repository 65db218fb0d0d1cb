"""Calibrating from clips end to end: rendered, encoded (H.264 .mp4), decoded, tracked, aligned in time,
the held moments chosen, measured and calibrated (``dualcal calibrate clips/``), against the known truth."""

import json
import re
import sys

import numpy as np
import pytest

pytest.importorskip("av", reason="the video extra (PyAV)")

from dualcal.synthetic.synth_video import make_video_truth, write_clips  # noqa: E402

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Two 320x240 clips of 7 holds (about 10 s at 30 fps, rolling shutters of 10 ms), the right camera 3.4
    frames late."""
    video = make_video_truth("stereo", holds=7, seed=5, scale=0.5, offset_frames=3.4, readout_s=0.01)
    folder = tmp_path_factory.mktemp("clips")
    write_clips(video, folder, seed=5, progress=False)
    return video, folder


def test_a_rig_from_two_clips(clips, run_cli, tmp_path):
    video, folder = clips
    out = tmp_path / "calib.json"
    res = run_cli("calibrate", folder, "--board", "9x6", "--square", "30", "-o", out, "--no-compare-models")
    assert res.code == 0, res.err
    doc = json.loads(out.read_text())
    truth = video.truth
    for name, cam in doc["cameras"].items():
        for p in PARAMS:
            z = (cam[p] - getattr(truth.cameras[name], p)) / cam["sigma"][p]
            assert abs(z) < 4, (name, p, z)
    rel = doc["rig"]["right"]
    true = truth.rig["right"]
    z_t = (np.array(rel["t_mm"]) - true.t_mm) / np.array(rel["sigma"]["t_mm"])
    z_a = (np.array(rel["opk_arcmin"]) - true.opk_arcmin) / np.array(rel["sigma"]["opk_arcmin"])
    assert np.all(np.abs(z_t) < 4) and np.all(np.abs(z_a) < 4), (z_t, z_a)
    offset, sigma = doc["video"]["offset_s"]["right"], doc["video"]["offset_sigma_s"]["right"]
    assert abs(offset - video.offset_s["right"]) < 0.002
    assert abs(offset - video.offset_s["right"]) < 4 * sigma
    assert doc["video"]["offset_s"]["left"] == 0.0 and doc["video"]["unmatched"] == []
    # one instant per hold, keyed by the reference's frame; what became of the frames is said
    keys = list(doc["views"])
    assert 5 <= len(keys) <= 7 and all(k.startswith("f") and len(k) == 7 for k in keys)
    frames = doc["video"]["frames"]["left"]
    assert frames["chosen"] == len(keys) and frames["frames_read"] == len(video.frame_times("left"))
    assert sum(frames["not_used"].values()) + frames["chosen"] == frames["frames_read"]
    assert "frames read" in res.out and "held still" in res.out
    assert re.search(r"right: first frame at \+0\.11\d\d s \+- 0\.\d+ s on left's clock \(\+3\.[34]\d frames\)", res.out)


def test_one_clip_calibrates_its_camera(clips, run_cli, tmp_path):
    video, folder = clips
    out = tmp_path / "calib.json"
    res = run_cli("calibrate", "--camera", f"left={folder / 'left.mp4'}", "--board", "9x6", "--square", "30",
                  "-o", out, "--no-compare-models")
    assert res.code == 0, res.err
    doc = json.loads(out.read_text())
    assert list(doc["cameras"]) == ["left"] and doc["video"]["offset_s"] == {"left": 0.0}
    for p in PARAMS:
        z = (doc["cameras"]["left"][p] - getattr(video.truth.cameras["left"], p)) / doc["cameras"]["left"]["sigma"][p]
        assert abs(z) < 4, (p, z)


def test_a_file_that_is_no_video_is_one_line(tmp_path, run_cli):
    (tmp_path / "wide.mp4").write_bytes(b"not a video at all" * 100)
    res = run_cli("calibrate", tmp_path, "--board", "9x6", "--square", "30", "-o", tmp_path / "c.json")
    assert res.code == 2 and len(res.err_lines) == 1 and "wide.mp4: not a readable video" in res.err, res.err


def test_clips_beside_photos_are_a_camera_rolls_live_photos(tmp_path, run_cli):
    from dualcal.files.video import find_clips

    (tmp_path / "IMG_0101.MOV").write_bytes(b"x")
    (tmp_path / "IMG_0101.HEIC").write_bytes(b"x")
    assert find_clips(tmp_path) is None                            # photos: the dataset skips the .MOV
    res = run_cli("calibrate", "--camera", "wide=a.mp4", "--camera", "tele=b*.jpg", "--board", "9x6",
                  "--square", "30", "-o", tmp_path / "c.json")
    assert res.code == 2 and "give every camera as a clip" in res.err and len(res.err_lines) == 1, res.err


def test_without_the_video_extra_one_line_says_what_to_install(monkeypatch, tmp_path, run_cli):
    (tmp_path / "wide.mp4").write_bytes(b"x")
    monkeypatch.setitem(sys.modules, "av", None)
    res = run_cli("calibrate", tmp_path, "--board", "9x6", "--square", "30", "-o", tmp_path / "c.json")
    assert res.code == 2 and "pip install 'dualcal[video]'" in res.err and len(res.err_lines) == 1, res.err


@pytest.mark.parametrize("codec", ["libx264", "libx265"])
def test_a_phones_clip_is_read_as_stored_and_its_rotation_reported(tmp_path, codec):
    from dualcal.files.video import probe_clip, read_frames
    from dualcal.synthetic.synth_video import encode_clip

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (48, 64), dtype=np.uint8) for _ in range(5)]
    path = tmp_path / "wide.mp4"
    path.write_bytes(encode_clip(frames, (64, 48), 30.0, crf=0, codec=codec, rotation_deg=90))
    info = probe_clip(path)
    assert (info.size, info.rotation_deg, info.codec) == ((64, 48), 90, "h264" if codec == "libx264" else "hevc")
    decoded = list(read_frames(path))
    assert [i for i, _, _ in decoded] == list(range(5))
    assert np.allclose([t for _, t, _ in decoded], np.arange(5) / 30.0)
    assert all(g.shape == (48, 64) for _, _, g in decoded)        # the stored frame, not turned
    # near-lossless: the luma within a few grey levels of what was encoded
    assert np.abs(decoded[2][2].astype(int) - frames[2]).mean() < 3


def test_a_phones_1080p_frames_are_tracked_where_the_board_is(tmp_path):
    """The board's corners as tracked (on the frame reduced by a power of two: 1920 / 640 once made a reduction
    of 3, an image halved and its corners scaled back by 3, every one 1.5 x too far from the origin) and as
    measured where it is held, against the truth: a quarter of a second of note8's wide filming in 1080p."""
    from dualcal.files.video import track_clip
    from dualcal.synthetic.synth_video import tracked_corners

    video = make_video_truth("phone-1080p", holds=1, seed=1, hold_s=(0.25, 0.25))
    path = write_clips(video, tmp_path, seed=1, progress=False, cameras=["wide"])["wide"]
    track = track_clip(path, video.truth.board, progress=False)
    _, truth = tracked_corners(video, "wide")
    assert track.info.size == (1920, 1080) and track.frames_found == track.frames_read == len(truth)
    assert np.abs(track.coarse_px - truth).max() < 0.5
    j = max(track.windows)                                    # held: its corners measured as a photo's are
    assert np.abs(track.windows[j].measure(track.info.size, video.truth.board) - truth[j]).max() < 0.25
