"""Ctrl-C during every long command: exit 130, one line on stderr, no process left, earlier outputs kept.

Each command runs as a subprocess in its own process group; once its worker pool is busy (its
worker threads exist) SIGINT goes to the whole group, as a terminal's Ctrl-C does.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from dualcal.files.io import load_rig, save_rig
from dualcal.synthetic.synth import make_truth, truth_rig_model

pytestmark = pytest.mark.slow

DUALCAL = [sys.executable, "-m", "dualcal"]
EARLIER = '{"earlier": "result"}\n'


def _threads(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/task"))
    except FileNotFoundError:
        return 0


def _group_members(pgid: int) -> list[int]:
    """Pids of the processes still in process group ``pgid``."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if fields[0] != "Z" and int(fields[2]) == pgid:
                out.append(int(entry))
    return out


def interrupt_when_busy(args, busy_threads: int = 3, timeout_s: float = 120.0):
    """Run ``dualcal ARGS``, send SIGINT to its group once it runs ``busy_threads`` threads.

    Returns ``(exit code, stderr lines)``; fails if the command ended before it got busy.
    """
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen(DUALCAL + [str(a) for a in args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout_s
        while _threads(proc.pid) < busy_threads:
            assert proc.poll() is None, f"ended before its workers started: {proc.stderr.read()}"
            assert time.monotonic() < deadline, "the workers never started"
            time.sleep(0.005)
        time.sleep(0.1)                     # in the middle of the work
        assert proc.poll() is None, "the work ended before it could be interrupted"
        os.killpg(proc.pid, signal.SIGINT)
        err = proc.communicate(timeout=30)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert _group_members(proc.pid) == [], "a worker process was left behind"
    return proc.returncode, [line for line in err.splitlines() if line.strip()]


def _assert_interrupted(code, lines, out_dir: Path, earlier: list[Path]):
    assert code == 130, lines
    assert lines == ["dualcal: interrupted"]
    for path in earlier:
        assert path.read_text() == EARLIER, path
    assert not [p for p in out_dir.rglob(".*") if p.is_file()], "a temporary file was left behind"


@pytest.fixture(scope="module")
def photo_set(tmp_path_factory):
    """40 photo-like renders (note8 at 0.25 scale, 20 views)."""
    out = tmp_path_factory.mktemp("sigint") / "set"
    subprocess.run(DUALCAL + ["synth", str(out), "--views", "20", "--scale", "0.25", "--seed", "3"], check=True,
                   capture_output=True)
    return out


@pytest.fixture(scope="module")
def big_photos(tmp_path_factory):
    """The note8 truth as calib.json and a smooth 12 MP JPEG of each camera (slow enough to interrupt)."""
    d = tmp_path_factory.mktemp("sigint-big")
    save_rig(d / "calib.json", truth_rig_model(make_truth("note8", views=3, seed=0)))
    rng = np.random.default_rng(0)
    for k, name in enumerate(("wide", "tele", "wide2", "wide3", "wide4", "wide5")):
        img = cv2.resize((rng.random((64, 48, 3)) * 255).astype(np.uint8), (3024, 4032), interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(d / f"{name}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    return d


def test_ctrl_c_during_detect(photo_set, tmp_path):
    out = tmp_path / "corners.json"
    out.write_text(EARLIER)
    code, lines = interrupt_when_busy(["detect", photo_set / "photos", "--board", "8x5", "--square", "30",
                                       "-o", out, "--jobs", "2", "--overlays", tmp_path / "overlays"])
    _assert_interrupted(code, lines, tmp_path, [out])


def test_ctrl_c_during_calibrate_from_photos(photo_set, tmp_path):
    out = tmp_path / "calib.json"
    out.write_text(EARLIER)
    code, lines = interrupt_when_busy(["calibrate", photo_set / "photos", "--board", "8x5", "--square", "30",
                                       "-o", out, "--jobs", "2"])
    _assert_interrupted(code, lines, tmp_path, [out])


def test_ctrl_c_during_undistort(big_photos, tmp_path):
    out = tmp_path / "undistorted"
    out.mkdir()
    earlier = out / "wide.jpg"
    earlier.write_text(EARLIER)
    photos = [big_photos / f"{n}.jpg" for n in ("wide", "wide2", "wide3", "wide4", "wide5")]
    code, lines = interrupt_when_busy(["undistort", big_photos / "calib.json", "--camera", "wide", *photos,
                                       "-o", out, "--jobs", "2"])
    _assert_interrupted(code, lines, out, [earlier])
    assert not (out / "wide.rectified.json").exists()


def test_ctrl_c_during_rectify(big_photos, tmp_path):
    out = tmp_path / "pair"
    out.mkdir()
    earlier = [out / "wide-wide.jpg", out / "rectify.json"]
    for path in earlier:
        path.write_text(EARLIER)
    code, lines = interrupt_when_busy(["rectify", big_photos / "calib.json", "--pair", f"wide={big_photos}/wide.jpg",
                                       f"tele={big_photos}/tele.jpg", "-o", out, "--keep", "all"])
    _assert_interrupted(code, lines, out, earlier)
    assert not (out / "tele-tele.jpg").exists()


def test_the_same_commands_finish_when_not_interrupted(big_photos, tmp_path):
    """The rectify run above is interrupted in its work, not before: the same run completes."""
    res = subprocess.run(DUALCAL + ["rectify", str(big_photos / "calib.json"), "--pair", f"wide={big_photos}/wide.jpg",
                                    f"tele={big_photos}/tele.jpg", "-o", str(tmp_path)], capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr
    doc = json.loads((tmp_path / "rectify.json").read_text())
    assert doc["cameras"] == ["wide", "tele"] and doc["layout"] == "vertical"
    assert load_rig(big_photos / "calib.json").cameras["wide"].image_size == (3024, 4032)
