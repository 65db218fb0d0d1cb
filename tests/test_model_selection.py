"""The held-out error of a calibration and the lens model it recommends, on synthetic rigs."""

from dataclasses import replace

import numpy as np
import pytest

from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import intrinsic_names, project_points
from dualcal.errors import EstimationError
from dualcal.estimation.evaluation import resect_view
from dualcal.estimation.model_selection import compare_lens_models, rig_fit, score_lens_models
from dualcal.synthetic.synth import make_truth, noisy_corner_set
from dualcal.estimation.validation import instants_of

FLAT = dict(rig_mode="rigid", drop_outliers=False, board_shape="flat")


def _tangential(truth, p1, p2):
    """The truth with tangential distortion in every camera."""
    cams = {n: replace(c, p1=p1, p2=p2, model="k1k2p1p2") for n, c in truth.cameras.items()}
    return replace(truth, cameras=cams)


def test_the_held_out_error_is_that_of_a_calibration_without_the_instant():
    """The linearised leave-one-instant-out of the full adjustment against the real thing: calibrate
    without the instant, resect it with that calibration (one pose for the rig), its residuals.
    Within 3 % of the RMS, and above the instant's own fit."""
    corners = noisy_corner_set(make_truth("stereo", 9, seed=21), 0.3, seed=22)
    rig = calibrate_rig(corners, **FLAT)
    per_instant = rig.adjustment["held_out_per_instant"]
    assert sorted(per_instant) == instants_of(corners)
    for view in instants_of(corners)[::4]:
        fold = calibrate_rig(corners.with_views(lambda _, v: v != view), **FLAT)
        squares, n = 0.0, 0
        for photo in resect_view(fold, view, corners).values():
            X = photo.pose.apply(fold.board_points_mm())
            squares += np.sum((project_points(photo.camera, X) - photo.uv_px) ** 2)
            n += len(photo.uv_px)
        assert per_instant[view]["corners"] == n
        assert per_instant[view]["rms_px"] == pytest.approx(np.sqrt(squares / n), rel=0.03)
        fit_rms = np.sqrt(np.mean(np.square(list(rig.view_rms_px[view].values()))))   # every corner seen
        assert per_instant[view]["rms_px"] > fit_rms
    assert rig.adjustment["held_out_rms_px"] > rig.rms_px


def test_a_radial_lens_gets_the_papers_model_recommended():
    """No tangential term in the truth: every richer model fits better, none predicts the unseen
    instants clearly better, and k1k2 is recommended."""
    rig = calibrate_rig(noisy_corner_set(make_truth("stereo", 12, seed=31), 0.25, seed=32), **FLAT)
    scores = compare_lens_models(rig)
    assert [s.model for s in scores] == ["k1k2", "k1k2k3", "k1k2p1p2", "k1k2p1p2k3"]
    assert [s.model for s in scores if s.recommended] == ["k1k2"]
    assert all(s.fit_rms_px <= scores[0].fit_rms_px + 1e-12 for s in scores)
    assert all(s.held_out_rms_px > s.fit_rms_px for s in scores)


def test_a_lens_with_tangential_terms_gets_them_recommended():
    """p1 = 0.003, p2 = -0.00225 with 0.1 px noise (most of it the principal point absorbs: the
    radial fit is only 3 % worse): the radial models are several standard errors worse on held-out
    instants; k1k2p1p2 is recommended (k3 is not needed)."""
    truth = _tangential(make_truth("stereo", 12, seed=31), 0.003, -0.00225)
    rig = calibrate_rig(noisy_corner_set(truth, 0.1, seed=32), **FLAT)
    scores = {s.model: s for s in compare_lens_models(rig)}
    assert scores["k1k2"].worse_se > 3 and scores["k1k2k3"].worse_se > 3
    assert [m for m, s in scores.items() if s.recommended] == ["k1k2p1p2"]


def test_models_compared_must_share_their_corners_and_three_instants():
    truth = make_truth("stereo", 6, seed=41)
    a = calibrate_rig(noisy_corner_set(truth, 0.2, seed=1), **FLAT)
    fewer = replace(a.corners, cameras={n: replace(c, views=dict(list(c.views.items())[:5]))
                                        for n, c in a.corners.cameras.items()})
    b = calibrate_rig(fewer, **{**FLAT, "model": "k1k2p1p2"})
    assert len(score_lens_models({"k1k2": rig_fit(a), "k1k2p1p2": rig_fit(b)})) == 2      # on the 5 instants both have

    def edited(rig, edit):
        per_instant = {v: dict(d) for v, d in rig.adjustment["held_out_per_instant"].items()}
        edit(per_instant)
        return replace(rig, adjustment={**rig.adjustment, "held_out_per_instant": per_instant})

    one_corner_less = edited(b, lambda d: d[min(d)].update(corners=d[min(d)]["corners"] - 1))
    with pytest.raises(EstimationError, match="did not use the same corners"):
        score_lens_models({"k1k2": rig_fit(a), "k1k2p1p2": rig_fit(one_corner_less)})
    two_instants = edited(b, lambda d: [d.pop(v) for v in sorted(d)[2:]])
    with pytest.raises(EstimationError, match="2 instant\\(s\\) can be left out by every model: a comparison needs 3"):
        score_lens_models({"k1k2": rig_fit(a), "k1k2p1p2": rig_fit(two_instants)})


@pytest.fixture(scope="module")
def phone3_auto():
    """phone3 (fisheye ultra-wide, wide, 3x tele; 20 instants, 8 of them near the ultra-wide's or the
    wide's edges), 0.02 px corners, calibrated with ``model="auto"``."""
    truth = make_truth("phone3", 20, seed=0)
    return truth, calibrate_rig(noisy_corner_set(truth, 0.02, seed=1), model="auto")


def test_auto_gives_the_fisheye_ultra_kb4_and_the_others_the_papers_model(phone3_auto):
    """kb4 is a candidate of the ultra-wide alone (73 degrees at its corners; the wide's are at 40);
    the wide's k3 (0.2) shows in the instants that put the board near its edges (4 of its 14)."""
    truth, rig = phone3_auto
    assert rig.models == {"tele": "k1k2", "ultra": "kb4", "wide": "k1k2k3"} == rig.adjustment["lens_models_chosen"]
    assert rig.model == "mixed"
    entries = {e["model"]: e for e in rig.adjustment["lens_models"]}
    assert set(entries) == {"k1k2", "k1k2k3", "k1k2p1p2", "kb4", "k1k2p1p2k3"}
    assert [n for n, d in entries["kb4"]["per_camera"].items() if d["candidate"]] == ["ultra"]
    ultra = {m: e["per_camera"]["ultra"] for m, e in entries.items()}
    assert ultra["kb4"]["held_out_rms_px"] < 0.1 * ultra["k1k2"]["held_out_rms_px"]   # k1k2 cannot follow 73 degrees
    assert ultra["kb4"]["recommended"] and not ultra["k1k2"]["recommended"]
    assert all(len(rig.adjustment["held_out_per_camera"][n]) >= 3 for n in rig.cameras)


def test_auto_recovers_every_intrinsic_and_the_rig_within_4_sigma(phone3_auto):
    truth, rig = phone3_auto
    for name, cam in rig.cameras.items():
        true = truth.cameras[name]
        for p in intrinsic_names(cam.model):
            if p != "skew":
                assert abs(getattr(cam, p) - getattr(true, p)) < 4 * rig.camera_sigma[name][p], (name, p)
    for name, rel in rig.rig.items():
        true = truth.rig[name]
        assert abs(rel.baseline_mm - np.linalg.norm(true.t_mm)) < 4 * rel.sigma_baseline_mm
        assert np.all(np.abs(rel.pose.opk_arcmin - true.opk_arcmin) < 4 * rel.sigma_opk_arcmin)
        assert np.all(np.abs(rel.pose.t_mm - true.t_mm) < 4 * rel.sigma_t_mm)
    # the fisheye's residual is the corners' noise: 0.02 px per coordinate is 0.028 px of 2-D length
    assert rig.camera_rms_px["ultra"] < 1.1 * 0.02 * np.sqrt(2)


def test_an_instant_one_model_cannot_predict_is_left_out_of_every_score_and_said():
    """Issue 23: the models are scored on the same instants; one that a model can only fit, not predict
    (it alone determines some of its terms), is left out for all of them, with a warning naming it."""
    from dualcal.estimation.model_selection import score_lens_models
    from dualcal.progress import collect_warnings

    def fake(rms):
        held = {v: {"rms_px": r, "corners": 40} for v, r in rms.items()}
        return {"held_out_per_instant": held, "rms_px": 0.1}

    rigs = {"k1k2": fake({"A": 0.2, "B": 0.3, "C": 0.25, "D": 0.9}),
            "k1k2k3": fake({"A": 0.1, "B": 0.2, "C": 0.15})}            # D: k1k2k3 cannot predict it
    with collect_warnings() as warnings:
        scores = score_lens_models(rigs)
    assert len(warnings) == 1 and "3 instants" in warnings[0] and "D (k1k2k3)" in warnings[0]
    by_model = {s.model: s for s in scores}
    assert by_model["k1k2"].held_out_rms_px == pytest.approx(np.sqrt((0.04 + 0.09 + 0.0625) / 3))   # A, B, C only


def test_models_compared_camera_by_camera_are_those_of_one_adjustment_of_every_camera_alone():
    """With a flat board no camera's fit depends on another's: the comparison's one-camera adjustments, put
    together (a fisheye ultra-wide's radial models from Zhang's closed form, the others from their nested
    models' solutions), give every camera's fit and held-out errors as one adjustment of every camera alone
    per model gives them (how each model was refitted before issue 32), to the comparison's tolerance, and
    the same scores and choice."""
    from dualcal.estimation.calibrate import Settings, adjusted, lens_models, photos_to_calibrate
    from dualcal.estimation.fitting import rig_model_from_solution
    from dualcal.estimation.model_selection import _camera_fits, _refits
    from dualcal.geometry.camera import LENS_MODELS

    corners = noisy_corner_set(make_truth("triple", 10, seed=2), 0.2, seed=3)
    photos = photos_to_calibrate(corners, Settings(board_shape="flat"))
    lenses = lens_models(photos, "auto")
    candidates, preferred = lenses.candidates, lenses.preferred
    assert preferred["ultra"] == "kb4"
    fit = adjusted(photos, lenses.models, Settings(board_shape="flat"))
    base = rig_model_from_solution(fit.solution, photos.corners, fit.dropped, fit.dropped_corners)
    mappings = {m: {n: m if m in candidates[n] else preferred[n] for n in candidates} for m in LENS_MODELS}
    apart = _camera_fits(fit.solution, fit.alone, candidates, preferred, mappings)
    joint = _refits(base, mappings, "none")
    assert set(apart) == set(joint) == set(LENS_MODELS)
    for m in mappings:
        for n in candidates:
            assert apart[m]["camera_rms_px"][n] == pytest.approx(joint[m]["camera_rms_px"][n], rel=1e-4), (m, n)
            a, j = apart[m]["held_out_per_camera"][n], joint[m]["held_out_per_camera"][n]
            assert set(a) == set(j)
            assert all(a[v]["rms_px"] == pytest.approx(j[v]["rms_px"], rel=5e-3) for v in a), (m, n)
    for n in candidates:
        ours = score_lens_models({m: f for m, f in apart.items() if m in candidates[n]}, n, first=preferred[n])
        theirs = score_lens_models({m: f for m, f in joint.items() if m in candidates[n]}, n, first=preferred[n])
        assert [s.recommended for s in ours] == [s.recommended for s in theirs]
        assert np.allclose([s.worse_se for s in ours], [s.worse_se for s in theirs], atol=0.02), n


def test_a_model_whose_residuals_grow_towards_the_edge_gives_way_to_one_that_predicts_better():
    """The paired test over instants can recommend k1k2 for a lens with k3 (within 2 SE on few instants); where its
    residuals grow towards the edge (the lens_model check's limit) and a richer candidate's do not and predict the
    unseen instants better, the richer one is chosen; where the recommended one's residuals are even, it stays."""
    from dualcal.estimation.model_selection import LensModelScore, _edge_consistent

    scores = [LensModelScore("k1k2", 2, 0.028, 0.031, 1.9, True), LensModelScore("k1k2k3", 3, 0.015, 0.017, 0.0, False),
              LensModelScore("k1k2p1p2k3", 5, 0.015, 0.020, 1.1, False)]
    fits = {"k1k2": {"camera_edge_ratio": {"wide": 2.6}}, "k1k2k3": {"camera_edge_ratio": {"wide": 1.1}},
            "k1k2p1p2k3": {"camera_edge_ratio": {"wide": 1.0}}}
    assert _edge_consistent("wide", "k1k2", scores, fits) == "k1k2k3"
    fits["k1k2"]["camera_edge_ratio"]["wide"] = 1.4
    assert _edge_consistent("wide", "k1k2", scores, fits) == "k1k2"
