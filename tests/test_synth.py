"""Synthetic rigs: the phone3 preset (a fisheye ultra-wide beside wide and tele)."""

import numpy as np

from dualcal.geometry.camera import normalized_from_pixel, undistort
from dualcal.synthetic.synth import PRESETS, make_truth, noisy_corner_set, true_corners


def test_phone3_is_a_three_lens_phone_with_a_fisheye_ultra_wide():
    cams = PRESETS["phone3"]["cameras"]
    assert {n: c.model for n, c in cams.items()} == {"wide": "k1k2p1p2k3", "ultra": "kb4", "tele": "k1k2"}
    assert all(c.image_size == (3024, 4032) for c in cams.values())
    ultra = cams["ultra"]
    w, h = ultra.image_size
    edge = np.array([[0.0, (h - 1) / 2], [(w - 1) / 2, 0.0], [0.0, 0.0]])
    half_angles = np.degrees(np.arctan(np.hypot(*undistort(ultra, normalized_from_pixel(ultra, edge)).T)))
    assert 100 < 2 * half_angles[0] < 2 * half_angles[1] < 135 and 140 < 2 * half_angles[2] < 150
    assert 2.8 < cams["tele"].fx / cams["wide"].fx < 3.2 and 1300 < ultra.fx < 1500
    baselines = {n: np.linalg.norm(p.t_mm) for n, p in PRESETS["phone3"]["rig"].items()}
    assert all(10 < b < 25 for b in baselines.values())


def test_phone3_views_show_the_board_whole_or_not_at_all_and_reach_the_ultras_edges():
    """Most instants every camera sees the whole board; in the others it is near the ultra-wide's
    edge, and a camera that does not see all of it misses the instant (None, as when detection
    fails), which calibration takes as it comes."""
    truth = make_truth("phone3", 15, seed=0)
    corners = noisy_corner_set(truth, 0.1, seed=0)
    seen = {n: [v for v, uv in c.views.items() if uv is not None] for n, c in corners.cameras.items()}
    assert len(seen["ultra"]) == 15 and 7 <= len(seen["tele"]) <= 10
    assert set(seen["tele"]) <= set(seen["wide"])
    for name, views in true_corners(truth).items():
        for uv in views.values():
            assert np.isnan(uv).all() or not np.isnan(uv).any()
    ultra = truth.cameras["ultra"]
    reach = max(np.max(np.hypot(uv[:, 0] - ultra.cx, uv[:, 1] - ultra.cy)) for uv in true_corners(truth)["ultra"].values())
    assert reach > 0.7 * np.hypot(*ultra.image_size) / 2


def test_cli_synth_writes_the_phone3_preset(tmp_path, run_cli):
    res = run_cli("synth", tmp_path / "p3", "--preset", "phone3", "--views", "6", "--no-photos")
    assert res.code == 0, res.err
    assert "phone3: 3 cameras x 6 views" in res.out
