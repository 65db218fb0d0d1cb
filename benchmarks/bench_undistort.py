"""Undistorting one 12 MP photo: dualcal against OpenCV, on one core, time and peak memory.

The photo is a colour 3024 x 4032 JPEG (a smooth random texture with grain, so it compresses
like a real photo) with an EXIF block; the camera is the ``note8`` preset's wide camera
(k1 = 0.08, k2 = -0.20). Each method runs in this process for the wall time (median and best
of ``--repeat``) and once more in a fresh child process for the memory: ``tracemalloc`` peak
(numpy and Python allocations during the call) and the child's peak resident set during the
call (the whole process, OpenCV's own buffers too), next to its resident set before the call
(imports, and the decoded photo for the in-memory methods).

Peers: ``cv2.undistort`` and ``cv2.initUndistortRectifyMap`` + ``cv2.remap`` for the image in
memory; ``cv2.imread`` + ``cv2.undistort`` + ``cv2.imwrite`` (no EXIF) for file to file.

Usage::

    .venv/bin/python benchmarks/bench_undistort.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from dualcal.files.rectify import JPEG_QUALITY, rectify_map, undistort_file, undistort_image
from dualcal.synthetic.synth import PRESETS

CAMERA = PRESETS["note8"]["cameras"]["wide"]
DIST = np.array([CAMERA.k1, CAMERA.k2, 0.0, 0.0])


def make_photo(path: Path, seed: int = 0) -> None:
    """A 12 MP colour JPEG with EXIF: smooth texture plus grain."""
    w, h = CAMERA.image_size
    rng = np.random.default_rng(seed)
    coarse = rng.random((h // 8, w // 8, 3)).astype(np.float32)
    img = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC) * 200 + 20
    img += rng.normal(0, 6, img.shape).astype(np.float32)
    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "bench", "12 MP"
    Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)).save(path, quality=92, exif=exif.tobytes())


def _cv2_maps_and_remap(img):
    m1, m2 = cv2.initUndistortRectifyMap(CAMERA.K, DIST, None, CAMERA.K, CAMERA.image_size, cv2.CV_16SC2)
    return cv2.remap(img, m1, m2, cv2.INTER_LINEAR)


def _cv2_file(src: Path, dst: Path) -> None:
    img = cv2.imread(str(src), cv2.IMREAD_COLOR)
    cv2.imwrite(str(dst), cv2.undistort(img, CAMERA.K, DIST), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])


# name -> (needs the decoded image, function(image, src, dst))
METHODS = {
    "dualcal undistort_image": (True, lambda img, src, dst: undistort_image(img, CAMERA)),
    "cv2.undistort": (True, lambda img, src, dst: cv2.undistort(img, CAMERA.K, DIST)),
    "cv2 initUndistortRectifyMap+remap": (True, lambda img, src, dst: _cv2_maps_and_remap(img)),
    "dualcal undistort_file (JPEG->JPEG, EXIF)": (False, lambda img, src, dst: undistort_file(src, dst, CAMERA)),
    "cv2 imread+undistort+imwrite": (False, lambda img, src, dst: _cv2_file(src, dst)),
}
PEERS = {"dualcal undistort_image": ["cv2.undistort", "cv2 initUndistortRectifyMap+remap"],
         "dualcal undistort_file (JPEG->JPEG, EXIF)": ["cv2 imread+undistort+imwrite"]}


def _decode(src: Path) -> np.ndarray:
    return np.asarray(Image.open(src).convert("RGB"))


def _status_mb(key: str) -> float | None:
    """A ``Vm*`` line of /proc/self/status in MB (Linux), else None."""
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    return None


def child(name: str, src: Path, dst: Path) -> None:
    """Run one method once in this (fresh) process and print its memory as JSON.

    The peak resident set is Linux's ``VmHWM``, reset just before the call (``clear_refs``),
    so it is the peak during the call. Elsewhere it falls back on ``ru_maxrss``, the peak of
    the whole process (Linux carries ``ru_maxrss`` over fork and exec, hence ``VmHWM``).
    """
    cv2.setNumThreads(1)
    needs_image, fn = METHODS[name]
    img = _decode(src) if needs_image else None
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    before = _status_mb("VmRSS") or 0.0
    tracemalloc.start()
    fn(img, src, dst)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    maxrss = _status_mb("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"tracemalloc_mb": peak / 2**20, "rss_before_mb": before, "peak_rss_mb": maxrss}))


def time_method(name: str, src: Path, dst: Path, repeat: int) -> list[float]:
    needs_image, fn = METHODS[name]
    img = _decode(src) if needs_image else None
    fn(img, src, dst)                                     # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(img, src, dst)
        times.append(time.perf_counter() - t0)
    return times


def memory_of(name: str, src: Path, dst: Path) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", name, str(src), str(dst)],
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def agreement(src: Path) -> tuple[float, float]:
    """Max map difference (px) and mean pixel difference (grey levels) against cv2.undistort."""
    w, h = CAMERA.image_size
    cv_x, cv_y = cv2.initUndistortRectifyMap(CAMERA.K, DIST, None, CAMERA.K, (w, h), cv2.CV_32FC1)
    map_x, map_y = rectify_map(CAMERA, CAMERA.with_distortion(0, 0), 0, h)
    img = _decode(src)
    diff = np.abs(undistort_image(img, CAMERA).astype(int) - cv2.undistort(img, CAMERA.K, DIST))
    return float(max(np.abs(map_x - cv_x).max(), np.abs(map_y - cv_y).max())), float(diff.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--child", nargs=3, metavar=("METHOD", "SRC", "DST"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        name, src, dst = args.child
        child(name, Path(src), Path(dst))
        return

    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "photo.jpg", Path(tmp) / "out.jpg"
        make_photo(src)
        w, h = CAMERA.image_size
        print(f"one {w}x{h} colour JPEG ({src.stat().st_size / 1e6:.1f} MB), camera note8/wide, "
              f"one OpenCV thread, {args.repeat} repeats (median, best), OpenCV {cv2.__version__}\n")
        rows = {name: memory_of(name, src, dst) for name in METHODS}     # while this process is small
        for name in METHODS:
            times = time_method(name, src, dst, args.repeat)
            rows[name].update(median=statistics.median(times), best=min(times))

        head = (f"{'method':44s} {'median s':>9s} {'best s':>8s} {'tracemalloc MB':>15s} "
                f"{'RSS before MB':>14s} {'peak RSS MB':>12s} {'added MB':>9s}")
        print(head)
        print("-" * len(head))
        for name, r in rows.items():
            print(f"{name:44s} {r['median']:9.3f} {r['best']:8.3f} {r['tracemalloc_mb']:15.1f} "
                  f"{r['rss_before_mb']:14.1f} {r['peak_rss_mb']:12.1f} {r['peak_rss_mb'] - r['rss_before_mb']:9.1f}")
        print("\nratios (dualcal / OpenCV peer; below 1 means dualcal is faster / smaller)")
        for ours, peers in PEERS.items():
            for peer in peers:
                a, b = rows[ours], rows[peer]
                added = (a["peak_rss_mb"] - a["rss_before_mb"]) / (b["peak_rss_mb"] - b["rss_before_mb"])
                print(f"  {ours} / {peer}: time {a['median'] / b['median']:.2f}, added RSS {added:.2f}")
        map_px, grey = agreement(src)
        print(f"\nagreement with cv2.undistort: maps differ by at most {map_px:.2g} px, "
              f"images by {grey:.3f} grey levels on average")
        ours = rows["dualcal undistort_file (JPEG->JPEG, EXIF)"]
        print(f"targets: file to file < 1 s ({ours['median']:.2f} s), peak < 300 MB ({ours['peak_rss_mb']:.0f} MB)")


if __name__ == "__main__":
    main()
