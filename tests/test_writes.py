"""Writes checked to the last byte (issue 24, findings 1 and 7): a full disk, a short write, a read-only
folder, the temporary files a killed run leaves, a failed undistort's leftovers."""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import uuid
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import dualcal.files.io as io_module
from dualcal.errors import OutputError
from dualcal.files.io import (TEMP_MARK, clean_stale_temporaries, make_output_folder, write_bytes_atomic,
                              write_json_atomic, write_text_atomic)
from dualcal.synthetic.synth import make_truth, truth_rig_model


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if TEMP_MARK in p.name)


def test_a_short_write_is_a_full_disk_and_replaces_nothing(tmp_path, monkeypatch):
    """The write that stops short (as a nearly full disk makes it) is found; the earlier file stays."""
    target = tmp_path / "photo.jpg"
    target.write_bytes(b"earlier result")
    real_write = os.write
    calls = []

    def short_write(fd, data):
        calls.append(len(data))
        return real_write(fd, bytes(data[:len(data) // 2])) if len(calls) == 1 else 0
    monkeypatch.setattr(io_module.os, "write", short_write)
    with pytest.raises(OutputError, match="disk is full"):
        write_bytes_atomic(target, b"x" * 10_000)
    monkeypatch.undo()
    assert target.read_bytes() == b"earlier result"
    assert _leftovers(tmp_path) == []


def test_enospc_is_said_as_such(tmp_path, monkeypatch):
    def full(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(io_module.os, "write", full)
    with pytest.raises(OutputError, match=r"disk is full \(No space left on device\).*nothing was replaced"):
        write_json_atomic(tmp_path / "calib.json", {"a": 1})
    assert list(tmp_path.iterdir()) == []


def test_a_size_that_disagrees_on_the_disk_is_refused(tmp_path, monkeypatch):
    """The size on the disk is compared with what was meant (a file system that loses the tail)."""
    real_fstat = os.fstat

    class Shorter:
        def __init__(self, st):
            self.st_size = st.st_size - 1
    monkeypatch.setattr(io_module.os, "fstat", lambda fd: Shorter(real_fstat(fd)))
    with pytest.raises(OutputError, match="99 of 100 bytes"):
        write_bytes_atomic(tmp_path / "x.bin", b"y" * 100)
    assert list(tmp_path.iterdir()) == []


def test_temporaries_of_killed_runs_are_cleaned_but_not_a_live_writers(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = tmp_path / f".calib.json{TEMP_MARK}{dead.pid}-abc.json"
    live = tmp_path / f".calib.json{TEMP_MARK}{os.getpid()}-def.json"
    other = tmp_path / ".calib.json.tmp"           # not ours: never touched
    for p in (stale, live, other):
        p.write_text("half")
    assert clean_stale_temporaries(tmp_path) == [stale]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other.name])


def test_a_sigkilled_write_is_cleaned_on_the_next_run_into_that_folder(tmp_path):
    """A process killed (SIGKILL) in the middle of a write leaves its temporary file; the next run into that
    folder removes it."""
    import sys
    code = ("import os, time, dualcal.files.io as io\n"
            "def stuck(fd, data):\n    os.write(fd, bytes(data[:10]))\n    time.sleep(60)\n"
            "io._write_all = stuck\n"
            f"io.write_text_atomic({str(tmp_path / 'calib.json')!r}, 'x' * 1000)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    for _ in range(200):
        if _leftovers(tmp_path):
            break
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(0.05)
    proc.kill()
    proc.wait()
    assert len(_leftovers(tmp_path)) == 1
    io_module._cleaned.clear()              # a new run: this process has not written there yet
    write_text_atomic(tmp_path / "other.json", "{}")
    assert _leftovers(tmp_path) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["other.json"]


# ---------------------------------------------------------------------------- a real tiny file system


@contextlib.contextmanager
def _tmpfs(where: Path, options: str):
    where.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


@pytest.fixture
def stereo_calib(tmp_path):
    path = tmp_path / "calib.json"
    io_module.save_rig(path, truth_rig_model(make_truth("stereo", views=3, seed=0)))
    return path


def _noise_jpeg(path: Path, size=(640, 480), seed=0) -> Path:
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (size[1], size[0]), np.uint8)).save(path, quality=95)
    return path


def test_undistort_on_a_full_tmpfs_exits_2_and_keeps_the_earlier_photo(tmp_path, stereo_calib, run_cli):
    """Finding 1: with a few KB free, undistort replaced a good JPEG by a cut-off one and exited 0."""
    photo = _noise_jpeg(tmp_path / "left01.jpg")
    with _tmpfs(tmp_path / "disk", "size=2m") as disk:
        out = disk / "out"
        first = run_cli("undistort", stereo_calib, "--camera", "left", photo, "-o", out)
        assert first.code == 0, first.err
        earlier = (out / "left01.jpg").read_bytes()
        free = os.statvfs(disk).f_bavail * os.statvfs(disk).f_frsize
        (disk / "filler").write_bytes(b"\0" * max(0, free - 12 * 1024))
        res = run_cli("undistort", stereo_calib, "--camera", "left", photo, "-o", out)
        assert res.code == 2, res.err
        assert len(res.err_lines) == 1 and "disk is full" in res.err and "left01.jpg" in res.err
        assert (out / "left01.jpg").read_bytes() == earlier
        assert _leftovers(out) == []


def test_a_read_only_output_folder_is_found_before_the_work(tmp_path, stereo_calib, run_cli, monkeypatch):
    photo = _noise_jpeg(tmp_path / "left01.jpg")
    with _tmpfs(tmp_path / "ro", "ro,size=64k") as ro:
        with pytest.raises(OutputError, match="cannot write there"):
            make_output_folder(ro)
        worked = []
        monkeypatch.setattr("dualcal.files.rectify._undistort_task", lambda task: worked.append(task))
        res = run_cli("undistort", stereo_calib, "--camera", "left", photo, "-o", ro)
        assert res.code == 2 and "cannot write there" in res.err and worked == []
        res = run_cli("evaluate", stereo_calib, "-o", ro / "eval.json")
        assert res.code == 2 and "cannot write there" in res.err


def test_a_failed_undistort_leaves_no_new_folder(tmp_path, stereo_calib, run_cli):
    """Finding 7: every photo failing left a new, empty (or black-JPEG) folder."""
    broken = tmp_path / f"{uuid.uuid4().hex}.jpg"
    broken.write_bytes(b"not a photo")
    out = tmp_path / "new"
    res = run_cli("undistort", stereo_calib, "--camera", "left", broken, "-o", out)
    assert res.code == 2 and not out.exists()


@pytest.mark.parametrize("command", ["evaluate", "rectify", "undistort"])
def test_a_full_disk_is_said_as_such_by_every_command_and_keeps_earlier_outputs(tmp_path, stereo_calib, run_cli,
                                                                              monkeypatch, command):
    """Finding 1: rectify blamed its own output, the JSON writers exited 1 "internal error"."""
    left, right = _noise_jpeg(tmp_path / "left01.jpg"), _noise_jpeg(tmp_path / "right01.jpg", seed=1)
    out = tmp_path / "out"
    args = {"evaluate": ("evaluate", stereo_calib, "-o", out / "eval.json"),
            "rectify": ("rectify", stereo_calib, "--pair", f"left={left}", f"right={right}", "-o", out),
            "undistort": ("undistort", stereo_calib, "--camera", "left", left, "-o", out)}[command]
    out.mkdir()
    first = run_cli(*args)
    assert first.code == 0, first.err
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}

    def full(fd, data):
        os.write(fd, bytes(data[:len(data) // 3]))
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(io_module, "_write_all", full)
    res = run_cli(*args)
    assert res.code == 2 and len(res.err_lines) == 1 and "the disk is full" in res.err, res.err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier
