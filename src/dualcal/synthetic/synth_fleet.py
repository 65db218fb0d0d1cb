"""A synthetic fleet: many units of one phone model, each with its own known truth.

Units of one model differ a little: focal lengths by a fraction of a percent, principal points
by a few pixels, distortion and the rig's relative pose slightly. :func:`device_truth` draws one
such unit from a :mod:`dualcal.synthetic.synth` preset; :func:`write_fleet` writes a folder per device
with its ``corners.json`` (the input of ``dualcal batch``), and :func:`write_device_photos` a
device as photos instead. The truths are what tests and benchmarks compare ``fleet.parquet``
with.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..geometry.camera import project_points
from ..errors import EstimationError
from ..files.io import make_output_folder, save_corners
from ..geometry.model import Pose
from ..geometry.rotation import ARCMIN_PER_RAD, rotation_from_opk
from .synth import SynthTruth, make_truth, noisy_corner_set

#: One standard deviation of the unit-to-unit differences.
UNIT_SPREAD = {"focal_rel": 0.004, "centre_px_rel": 0.002, "k1": 0.005, "k2_rel": 0.03,
               "rig_arcmin": 2.0, "rig_mm": 0.1}


def _inside(truth: SynthTruth, view: str) -> bool:
    """Every corner of ``view`` in front of every camera and inside its image."""
    X = truth.board.object_points_mm()
    for name, cam in truth.cameras.items():
        Xc = truth.camera_pose(name, view).apply(X)
        uv = project_points(cam, Xc)
        w, h = cam.image_size
        if np.any(Xc[:, 2] <= 0) or np.any(uv < 0) or np.any(uv[:, 0] > w - 1) or np.any(uv[:, 1] > h - 1):
            return False
    return True


def device_truth(preset: str = "note8", views: int = 8, seed: int = 0, scale: float = 1.0,
                 spread: dict | None = None) -> SynthTruth:
    """One unit of the ``preset`` phone: its intrinsics and rig drawn around the preset's.

    Parameters
    ----------
    preset, views, scale : as for :func:`dualcal.synthetic.synth.make_truth`.
    seed : seed of the unit (its differences) and of its board poses.
    spread : one standard deviation of each difference (keys of :data:`UNIT_SPREAD`): focal
        lengths scaled by ``1 + N(0, focal_rel)``, the principal point moved by
        ``N(0, centre_px_rel * width)`` px, ``k1 + N(0, k1)``, ``k2 (1 + N(0, k2_rel))``, the rig
        turned by ``N(0, rig_arcmin)`` per angle and moved by ``N(0, rig_mm)`` per axis.

    Returns
    -------
    A :class:`~dualcal.synthetic.synth.SynthTruth` with ``views`` board poses whose corners all fall inside
    every camera's image.
    """
    s = {**UNIT_SPREAD, **(spread or {})}
    rng = np.random.default_rng([seed, 16])
    base = make_truth(preset, views + 8, seed, scale)
    cameras = {}
    for name, cam in base.cameras.items():
        focal = 1 + rng.normal(0, s["focal_rel"])
        shift = rng.normal(0, s["centre_px_rel"] * cam.image_size[0], 2)
        cameras[name] = replace(cam, fx=cam.fx * focal, fy=cam.fy * focal, cx=cam.cx + shift[0],
                                cy=cam.cy + shift[1], k1=cam.k1 + rng.normal(0, s["k1"]),
                                k2=cam.k2 * (1 + rng.normal(0, s["k2_rel"])))
    rig = {name: Pose(rotation_from_opk(rng.normal(0, s["rig_arcmin"], 3) / ARCMIN_PER_RAD) @ pose.R,
                      pose.t_mm + rng.normal(0, s["rig_mm"], 3))
           for name, pose in base.rig.items()}
    unit = replace(base, cameras=cameras, rig=rig)
    kept = [v for v in base.view_poses if _inside(unit, v)][:views]
    if len(kept) < views:
        raise EstimationError(f"device seed {seed}: only {len(kept)} of {views} views keep the board in every image")
    return replace(unit, view_poses={f"IMG_{i + 1:02d}": base.view_poses[v] for i, v in enumerate(kept)})


def device_names(n: int) -> list[str]:
    """``unit-001``, ``unit-002``, ...: names that sort in fleet order."""
    return [f"unit-{i + 1:03d}" for i in range(n)]


def write_fleet(root, n_devices: int = 12, preset: str = "note8", views: int = 8, noise_px: float = 0.1,
                seed: int = 0, scale: float = 1.0) -> dict[str, SynthTruth]:
    """Write ``root/<device>/corners.json`` for ``n_devices`` units of ``preset``.

    Device ``i`` is :func:`device_truth` with seed ``seed + i``, its corners have Gaussian noise of
    ``noise_px`` per coordinate. ``root`` is created if its parent exists. Returns the truths by
    device name.
    """
    root = make_output_folder(root)
    truths = {}
    for i, name in enumerate(device_names(n_devices)):
        truth = device_truth(preset, views, seed + i, scale)
        save_corners(make_output_folder(root / name) / "corners.json",
                     noisy_corner_set(truth, noise_px, seed=seed + i))
        truths[name] = truth
    return truths


def write_device_photos(folder, truth: SynthTruth, seed: int = 0, jobs: int | None = None) -> Path:
    """Write ``truth`` as a device of photos, ``folder/<camera>/<view>.jpg`` (a dataset)."""
    from .render import write_photo_set

    folder = make_output_folder(folder)
    write_photo_set(truth, folder, seed=seed, jobs=jobs, progress=False)
    return folder
