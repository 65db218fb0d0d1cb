"""Accuracy of the stereo rectification on photo-like renders with known truth.

For three rigs (a horizontal 640x480 stereo pair, the note8 wide + tele with its vertical baseline,
the triple rig's ultra-wide + tele with focal lengths 1700 and 6100 px) it rectifies pairs of
rendered photos of the true rig with ``dualcal.files.stereo``, detects the board in both rectified photos
and prints how far corresponding corners are from sharing a row (a column for a vertical rig), next
to the same figure for the true corners mapped through :func:`dualcal.files.stereo.rectify_points` (the
exact math) and for OpenCV's own rectification (``cv2.stereoRectify`` + ``initUndistortRectifyMap``
+ ``remap``, same rotations and camera) of the same photos.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from dualcal.files.detect import detect_photo
from dualcal.synthetic.render import render_view
from dualcal.files.stereo import rectify_pair_files, rectify_points, stereo_rectify
from dualcal.synthetic.synth import make_truth, true_corners, truth_rig_model

RIGS = [("stereo", "left", "right", 1.0), ("note8", "wide", "tele", 0.5), ("triple", "ultra", "tele", 0.5)]


def _opencv_rectified(rig, rect, name, photo: Path, out: Path) -> Path:
    cam = rig.cameras[name]
    maps = cv2.initUndistortRectifyMap(cam.K, np.array([cam.k1, cam.k2, 0, 0, 0.0]), rect.rotation(name),
                                       rect.P1[:, :3], rect.image_size, cv2.CV_32FC1)
    cv2.imwrite(str(out), cv2.remap(cv2.imread(str(photo)), *maps, cv2.INTER_LINEAR))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=4)
    args = parser.parse_args()
    print(f"{'rig':22s} {'layout':10s} {'true pts max':>12s} {'dualcal RMS':>11s} {'max':>7s} "
          f"{'OpenCV RMS':>10s} {'max':>7s}  (px off the common row/column)")
    for preset, a, b, scale in RIGS:
        truth = make_truth(preset, views=args.views, seed=7, scale=scale)
        rig = truth_rig_model(truth)
        rect = stereo_rectify(rig, a, b, "all")
        ax = 0 if rect.vertical else 1
        tc = true_corners(truth)
        exact = max(np.max(np.abs(rectify_points(rect, a, rig.cameras[a], tc[a][v])[:, ax]
                                  - rectify_points(rect, b, rig.cameras[b], tc[b][v])[:, ax])) for v in truth.view_poses)
        d = Path(tempfile.mkdtemp())
        ours, theirs = [], []
        for k, view in enumerate(truth.view_poses):
            photos = {}
            for n in (a, b):
                img = render_view(truth.cameras[n], truth.camera_pose(n, view), truth.board, np.random.default_rng(k))
                photos[n] = d / f"{n}_{view}.png"
                cv2.imwrite(str(photos[n]), img)
            out = rectify_pair_files(rig, rect, photos, d)
            cv = {n: _opencv_rectified(rig, rect, n, photos[n], d / f"cv-{n}_{view}.png") for n in (a, b)}
            for files, acc in ((out, ours), (cv, theirs)):
                found = [detect_photo(files[n], truth.board).uv for n in (a, b)]
                if found[0] is not None and found[1] is not None:
                    acc.append(found[0][:, ax] - found[1][:, ax])
        ours, theirs = np.concatenate(ours), np.concatenate(theirs)
        print(f"{preset + ' ' + a + '+' + b:22s} {'vertical' if rect.vertical else 'horizontal':10s} {exact:12.1e} "
              f"{np.sqrt(np.mean(ours**2)):11.4f} {np.abs(ours).max():7.4f} "
              f"{np.sqrt(np.mean(theirs**2)):10.4f} {np.abs(theirs).max():7.4f}")


if __name__ == "__main__":
    main()
