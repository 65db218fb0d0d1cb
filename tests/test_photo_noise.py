"""Photos weighed by their own noise (issue 38, :mod:`dualcal.estimation.photo_noise`), on synthetic rigs with
known truth: a blurred photo keeps its corners and counts for what they are worth; the weighted solution is more
accurate than the unweighted one and its sigmas hold; photos alike are weighed alike; a photo whose corners are no
measurement of the board (numbered at random) is left out."""

import numpy as np
import pytest

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.photo_noise import ALIKE_LEVEL
from dualcal.files.io import rig_to_dict
from dualcal.files.schemas import validate
from dualcal.geometry.model import CameraCorners, CornerSet
from dualcal.progress import collect_warnings
from dualcal.synthetic.synth import make_truth, noisy_corner_set, true_corners

PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _blurred_corners(truth, sharp_px: float, blur_px: tuple[float, float], share: float, seed: int):
    """The truth's corners with ``sharp_px`` of noise (per coordinate), and in a random ``share`` of the photos
    ``blur_px`` (drawn from the range) instead: ``(corners, {(camera, view): noise px})``."""
    rng = np.random.default_rng(seed)
    cams, noise = {}, {}
    for name, views in true_corners(truth).items():
        out = {}
        for v, uv in views.items():
            noise[name, v] = rng.uniform(*blur_px) if rng.random() < share else sharp_px
            out[v] = uv + rng.normal(0.0, noise[name, v], uv.shape)
        cams[name] = CameraCorners(truth.cameras[name].image_size, out)
    return CornerSet(truth.board, cams), noise


def _errors(rig, truth) -> tuple[np.ndarray, np.ndarray]:
    """Every intrinsic, the baseline and the angles: (error, sigma)."""
    err, sig = [], []
    for name in sorted(truth.cameras):
        for p in PARAMETERS:
            err.append(getattr(rig.cameras[name], p) - getattr(truth.cameras[name], p))
            sig.append(rig.camera_sigma[name][p])
    for name, rel in rig.rig.items():
        true = truth.rig[name]
        err += [rel.baseline_mm - np.linalg.norm(true.t_mm), *(rel.pose.opk_arcmin - true.opk_arcmin)]
        sig += [rel.sigma_baseline_mm, *rel.sigma_opk_arcmin]
    return np.array(err), np.array(sig)


def test_half_the_photos_blurred_the_weighted_solution_is_more_accurate_and_its_sigmas_hold():
    """The stereo pair, 14 instants, half the photos 5-10 x noisier (0.25-0.5 px against 0.05 px): over 12
    draws, every parameter's RMS error weighted is below the unweighted one's (their geometric mean under 0.7),
    and the weighted sigmas hold: the spread of error / sigma over every parameter and draw is 0.7-1.4."""
    truth = make_truth("stereo", 14, seed=40)
    weighted, unweighted, z = [], [], []
    for draw in range(12):
        corners, _ = _blurred_corners(truth, 0.05, (0.25, 0.5), 0.5, seed=400 + draw)
        with collect_warnings():
            rig = calibrate_rig(corners, model="k1k2")
            plain = calibrate_rig(corners, model="k1k2", weigh_photos=False)
        e, s = _errors(rig, truth)
        weighted.append(e)
        unweighted.append(_errors(plain, truth)[0])
        z.append(e / s)
    ratio = np.sqrt(np.mean(np.square(weighted), axis=0) / np.mean(np.square(unweighted), axis=0))
    assert np.all(ratio < 1.0), np.round(ratio, 2)
    assert np.exp(np.mean(np.log(ratio))) < 0.7, np.round(ratio, 2)
    spread = float(np.sqrt(np.mean(np.square(z))))
    assert 0.7 <= spread <= 1.4, spread


def test_a_blurred_photo_keeps_its_corners_and_its_noise_is_its_own():
    """One photo of the 12 MP wide 10 x noisier than the others (1 px against 0.1): with the photos weighed by
    their noise it loses no corner, its noise is found within 20 % (the others' median within 10 % of 0.1 px), its
    weight and its share of the information it would give if sharp are about 1 / 100, and calib.json records
    both (checked against its schema); judged against its camera's median (``weigh_photos=False``), it loses
    its corners."""
    truth = make_truth("note8", 12, seed=41)
    corners = noisy_corner_set(truth, 0.1, seed=42)
    view = sorted(truth.view_poses)[4]
    rng = np.random.default_rng(43)
    corners.cameras["wide"].views[view] = true_corners(truth)["wide"][view] + rng.normal(0, 1.0, (40, 2))
    with collect_warnings():
        rig = calibrate_rig(corners, model="k1k2")
        plain = calibrate_rig(corners, model="k1k2", weigh_photos=False)
    assert rig.dropped_views == [] and rig.dropped_corners == []
    noise = rig.adjustment["photo_noise"]["photos"]
    assert noise["wide"][view]["noise_px"] == pytest.approx(1.0, rel=0.2)
    others = [d["noise_px"] for cam, views in noise.items() for v, d in views.items() if (cam, v) != ("wide", view)]
    assert np.median(others) == pytest.approx(0.1, rel=0.1)
    assert 0.005 < noise["wide"][view]["weight"] < 0.02
    assert 0.005 < noise["wide"][view]["information_share"] < 0.02
    doc = rig_to_dict(rig)
    validate(doc, "calib", "calib.json")
    assert doc["views"][view]["noise_px"]["wide"] == noise["wide"][view]["noise_px"]
    lost = [d for d in plain.dropped_corners if (d["camera"], d["view"]) == ("wide", view)]
    lost += [d for d in plain.dropped_views if (d["camera"], d["view"]) == ("wide", view)]
    assert lost


def test_photos_alike_are_weighed_alike():
    """White corner noise on every photo of the three-camera rig, 10 draws: the photos' log-variances scatter no
    more than their estimates do, so that (at the stated level, 99 %) every weight is 1 and the solution is the
    unweighted one (every parameter within 1e-6 of its sigma) in at least 8 of 10 calibrations."""
    assert ALIKE_LEVEL == 0.99
    truth = make_truth("triple", 10, seed=44)
    alike = 0
    for draw in range(10):
        corners = noisy_corner_set(truth, 0.2, seed=440 + draw)
        rig = calibrate_rig(corners, model="k1k2", board_shape="flat")
        plain = calibrate_rig(corners, model="k1k2", board_shape="flat", weigh_photos=False)
        e, s = _errors(rig, truth)
        alike += bool(np.all(np.abs(e - _errors(plain, truth)[0]) <= 1e-6 * s))
    assert alike >= 8


def test_a_photo_numbered_at_random_is_left_out_as_no_measurement_of_the_board():
    """A photo whose corners are numbered at random (its median residual is of the size of a square, beyond a
    tenth of one: no blur does that) is left out with the reason, with every camera alone too."""
    truth = make_truth("stereo", 12, seed=45)
    corners = noisy_corner_set(truth, 0.1, seed=46)
    view = sorted(truth.view_poses)[3]
    uv = corners.cameras["right"].views[view]
    corners.cameras["right"].views[view] = uv[np.random.default_rng(47).permutation(len(uv))]
    with collect_warnings() as warnings:
        rig = calibrate_rig(corners, model="k1k2", rig_mode="none")
    assert [(d["camera"], d["view"]) for d in rig.dropped_views] == [("right", view)]
    assert "another numbering" in rig.dropped_views[0]["reason"]
    assert any(f"dropping right/{view}" in w for w in warnings)
