"""The board's scale (dualcal.geometry.scale): the printed squares' tolerance in every length-like sigma."""

from dataclasses import replace

import numpy as np
import pytest

from dualcal.synthetic import synth
from dualcal.geometry.board import Board
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import project_points
from dualcal.estimation.measurement import measure
from dualcal.geometry.scale import scale_share, with_scale, with_scale_in_measurement


def _with_tolerance(corners, sigma_mm, square_mm=None):
    board = replace(corners.board, square_sigma_mm=sigma_mm,
                    square_mm=corners.board.square_mm if square_mm is None else square_mm)
    return replace(corners, board=board)


def test_with_scale_adds_the_fully_correlated_part():
    assert with_scale(0.3, 100.0, 0.002) == pytest.approx(np.hypot(0.3, 0.2))
    assert scale_share(np.hypot(0.3, 0.2), 100.0, 0.002) == pytest.approx(0.04 / 0.13)
    doc = {"points": {"A": {"xyz_mm": [0.0, 30.0, 400.0], "sigma_mm": [0.1, 0.1, 0.5], "distance_mm": 401.1,
                            "depth_sigma_mm": 0.5}},
           "lengths": [{"from": "A", "to": "B", "length_mm": 50.0, "sigma_mm": 0.05, "sigma_percent": 0.1}]}
    out = with_scale_in_measurement(doc, 0.001)
    assert out["points"]["A"]["sigma_mm"] == pytest.approx([0.1, np.hypot(0.1, 0.03), np.hypot(0.5, 0.4)])
    assert out["lengths"][0]["sigma_mm"] == pytest.approx(np.hypot(0.05, 0.05))
    assert out["lengths"][0]["sigma_scale_mm"] == pytest.approx(0.05)


def test_a_005_mm_tolerance_on_a_25_mm_board_raises_a_100_mm_baseline_sigma_by_about_02_mm():
    truth = synth.make_truth("stereo", 10, seed=1, board=Board(9, 6, 25.0))
    corners = synth.noisy_corner_set(truth, 0.1, seed=1)
    exact = calibrate_rig(corners).rig["right"]
    printed = calibrate_rig(_with_tolerance(corners, 0.05)).rig["right"]
    D = printed.baseline_mm
    assert 95 < D < 105
    added = np.sqrt(printed.sigma_baseline_mm ** 2 - exact.sigma_baseline_mm ** 2)
    assert added == pytest.approx(0.05 / 25.0 * D, rel=1e-6)       # 0.2 mm for 100 mm
    assert printed.sigma_baseline_mm - exact.sigma_baseline_mm > 0.1
    np.testing.assert_allclose(printed.sigma_opk_arcmin, exact.sigma_opk_arcmin)   # angles do not scale
    np.testing.assert_allclose(printed.sigma_t_mm ** 2 - exact.sigma_t_mm ** 2,
                               (0.05 / 25.0 * printed.pose.t_mm) ** 2, rtol=1e-6, atol=1e-12)


def _points_json(truth, rng, n=4):
    """Pixels of ``n`` points 0.5-0.8 m in front of the rig, in both cameras, with 0.1 px noise."""
    X = np.column_stack([rng.uniform(-150, 150, n), rng.uniform(-100, 100, n), rng.uniform(500, 800, n)])
    ref = truth.reference
    pts = {}
    for name, cam in truth.cameras.items():
        Xc = X if name == ref else truth.rig[name].apply(X)
        uv = project_points(cam, Xc) + rng.normal(0, 0.1, (n, 2))
        for i in range(n):
            pts.setdefault(f"P{i}", {})[name] = uv[i].tolist()
    lengths = [[f"P{i}", f"P{j}"] for i in range(n) for j in range(i + 1, n)]
    true = [float(np.linalg.norm(X[i] - X[j])) for i in range(n) for j in range(i + 1, n)]
    return {"points": pts, "lengths": lengths, "pixel_sigma": 0.1}, true


@pytest.mark.slow
def test_lengths_from_boards_printed_at_random_scales_have_z_scores_of_spread_one():
    """Monte Carlo: each draw prints the board at 25 mm * (1 + e), e ~ N(0, 1 %), and the user says
    25 +- 0.25 mm; lengths measured with the calibration scatter as their sigmas say (60 draws, 6 lengths
    each; the lengths of one draw share its scale error). Without the tolerance they would not."""
    rng = np.random.default_rng(7)
    z, z_exact = [], []
    for draw in range(60):
        true_square = 25.0 * (1.0 + rng.normal(0.0, 0.01))
        truth = synth.make_truth("stereo", 8, seed=100 + draw, board=Board(9, 6, true_square))
        corners = _with_tolerance(synth.noisy_corner_set(truth, 0.1, seed=100 + draw), 0.25, square_mm=25.0)
        rig = calibrate_rig(corners, drop_outliers=False, board_shape="flat")
        points, true = _points_json(truth, rng)
        for m, t in zip(measure(rig, points)["lengths"], true):
            z.append((m["length_mm"] - t) / m["sigma_mm"])
            z_exact.append((m["length_mm"] - t) / np.sqrt(m["sigma_mm"] ** 2 - m["sigma_scale_mm"] ** 2))
    assert 0.8 < np.std(z) < 1.25, np.std(z)                 # measured: 0.87
    assert abs(np.mean(z)) < 0.3
    assert np.std(z_exact) > 1.5, np.std(z_exact)            # the squares taken as exact: 2.6
