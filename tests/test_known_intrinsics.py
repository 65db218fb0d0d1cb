"""Known intrinsics as priors (issue 39): a rig calibrated with the lenses given, staged and incremental.

Each camera calibrated from its own photos first, then the rig from a few joint instants with those intrinsics
as a prior (their covariance) or fixed; the rig within its sigma of the truth; a lens that changed named by the
``intrinsics_prior`` check; a camera added to a calibrated rig; a board too small in every frame for Zhang's
closed form calibrates with the lenses given; photos seen by one camera only keep counting for it.
"""

from dataclasses import replace

import numpy as np
import pytest

from dualcal.errors import EstimationError
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.estimation.covariance import JointCovariance, intrinsic_name
from dualcal.geometry.camera import intrinsic_names, project_points
from dualcal.geometry.model import CameraCorners, CornerSet, KnownIntrinsics
from dualcal.progress import collect_warnings
from dualcal.synthetic.synth import make_truth, noisy_corner_set


def known_of(rig, name: str) -> KnownIntrinsics:
    """Camera ``name`` of calibration ``rig`` as a prior: its intrinsics with their reported sigmas (the larger of
    the clustered and the textbook one) and the textbook correlations (of full rank, where the clustered ones of
    12 instants are not well determined)."""
    cam = rig.cameras[name]
    names = tuple(n for n in intrinsic_names(cam.model) if rig.camera_sigma[name].get(n, 0.0) > 0)
    formal = JointCovariance.from_dict(rig.covariance).block([intrinsic_name(name, n) for n in names], "formal")
    d = np.sqrt(np.diag(formal))
    s = np.array([rig.camera_sigma[name][n] for n in names])
    return KnownIntrinsics(cam, "prior", parameters=names, covariance=formal / np.outer(d, d) * np.outer(s, s))


def only(corners: CornerSet, cameras) -> CornerSet:
    """``corners`` of the ``cameras`` named alone."""
    return replace(corners, cameras={n: c for n, c in corners.cameras.items() if n in cameras})


def _staged(preset: str, seed: int, joint: int = 5, noise: float = 0.1):
    """Every camera of ``preset`` calibrated from 12 instants of its own (drawn apart: each at its own
    distance), then the rig from ``joint`` instants with those intrinsics as priors: ``(truth, rig)``."""
    truth = make_truth(preset, joint, seed=seed)
    known = {}
    for k, name in enumerate(sorted(truth.cameras)):
        own = make_truth(preset, 12, seed=seed + 100 + k)
        with collect_warnings():
            known[name] = known_of(calibrate_rig(only(noisy_corner_set(own, noise, seed=seed + 200 + k), [name]),
                                                 model="k1k2"), name)
    with collect_warnings():
        rig = calibrate_rig(noisy_corner_set(truth, noise, seed=seed + 300), known_intrinsics=known)
    return truth, rig


def _rig_z(rig, truth) -> np.ndarray:
    z = []
    for name, rel in rig.rig.items():
        true = truth.rig[name]
        z += list((rel.pose.t_mm - true.t_mm) / rel.sigma_t_mm)
        z += list((rel.pose.opk_arcmin - true.opk_arcmin) / rel.sigma_opk_arcmin)
    return np.array(z)


def test_the_rig_from_five_joint_instants_with_the_lenses_given_holds_its_sigmas():
    """note8's wide and tele, each calibrated from 12 instants of its own, then the rig from 5 joint instants with
    those as priors, over 6 seeds: the rig's translation and angles within 4 sigma of the truth, error / sigma
    spreading by 0.7-1.4; the intrinsics are the priors' as the photos moved them (within 4 of their sigmas),
    their sigmas no larger than the priors', and the photos agree with them (``intrinsics_prior`` passes)."""
    z = []
    for seed in range(6):
        truth, rig = _staged("note8", 60 + 10 * seed)
        z.append(_rig_z(rig, truth))
        for name, cam in rig.cameras.items():
            known = rig.adjustment["known_intrinsics"]["cameras"][name]
            assert known["mode"] == "prior"
            for p in ("fx", "fy", "cx", "cy"):
                assert abs(getattr(cam, p) - getattr(truth.cameras[name], p)) < 4 * rig.camera_sigma[name][p]
                assert rig.camera_sigma[name][p] <= np.sqrt(known["covariance"][known["names"].index(p)][
                    known["names"].index(p)]) * 1.001
        assert rig.checks["intrinsics_prior"]["ok"], rig.checks["intrinsics_prior"]["message"]
    z = np.concatenate(z)
    assert np.all(np.abs(z) < 4), np.round(z, 2)
    assert 0.7 <= np.sqrt(np.mean(z ** 2)) <= 1.4, np.sqrt(np.mean(z ** 2))


def test_intrinsics_known_exactly_are_held_fixed():
    """The true intrinsics given without a covariance: held (no sigma of their own), the rig from 5 joint
    instants within 4 sigma of the truth, its textbook sigmas smaller than with the lenses free."""
    truth = make_truth("stereo", 5, seed=70)
    corners = noisy_corner_set(truth, 0.1, seed=71)
    rig = calibrate_rig(corners, known_intrinsics={n: KnownIntrinsics(cam) for n, cam in truth.cameras.items()})
    for name, cam in rig.cameras.items():
        assert cam == truth.cameras[name] and all(s == 0 for s in rig.camera_sigma[name].values())
    assert np.all(np.abs(_rig_z(rig, truth)) < 4)
    free = calibrate_rig(corners)
    assert np.all(rig.rig["right"].sigma_formal["t_mm"] < free.rig["right"].sigma_formal["t_mm"])
    assert rig.checks["intrinsics_prior"]["ok"]


def test_a_lens_that_changed_is_named():
    """The tele's intrinsics known from its own photos, then its lens refocused (fx, fy 1.5 % longer) before the
    rig's photos: ``intrinsics_prior`` fails naming the tele alone, with fx among the intrinsics that moved."""
    truth = make_truth("note8", 12, seed=72)
    known = {n: known_of(calibrate_rig(only(noisy_corner_set(make_truth("note8", 12, seed=73), 0.1, seed=74), [n]),
                                       model="k1k2"), n) for n in truth.cameras}
    tele = truth.cameras["tele"]
    truth.cameras["tele"] = replace(tele, fx=1.015 * tele.fx, fy=1.015 * tele.fy)
    with collect_warnings():
        rig = calibrate_rig(noisy_corner_set(truth, 0.1, seed=75), known_intrinsics=known)
    check = rig.checks["intrinsics_prior"]
    assert not check["ok"] and check["flagged"] == ["tele"], check["message"]
    assert "tele" in check["message"] and "fx" in check["message"]


def test_a_camera_added_to_a_calibrated_rig():
    """The triple rig's wide and tele calibrated as a rig; then the ultra-wide added from 10 instants of all
    three, the wide and tele given as priors: the ultra-wide's intrinsics and its relation to the wide within 4
    sigma of the truth."""
    truth = make_truth("triple", 12, seed=76)
    first = calibrate_rig(only(noisy_corner_set(truth, 0.1, seed=77), ["wide", "tele"]), model="k1k2")
    added = make_truth("triple", 10, seed=78)
    with collect_warnings():
        rig = calibrate_rig(noisy_corner_set(added, 0.1, seed=79), model="k1k2",
                            known_intrinsics={n: known_of(first, n) for n in ("wide", "tele")})
    ultra, true = rig.cameras["ultra"], added.cameras["ultra"]
    for p in ("fx", "fy", "cx", "cy", "k1", "k2"):
        assert abs(getattr(ultra, p) - getattr(true, p)) < 4 * rig.camera_sigma["ultra"][p], p
    assert np.all(np.abs(_rig_z(rig, added)) < 4)
    assert set(rig.adjustment["known_intrinsics"]["cameras"]) == {"wide", "tele"}


def test_a_board_too_small_for_the_closed_form_calibrates_with_the_lenses_given():
    """Every frame nearly square-on (tilt under half a degree): the closed form cannot tell the focal length and
    refuses; with the intrinsics given as priors the rig calibrates, within 4 sigma of the truth."""
    truth = make_truth("stereo", 12, seed=80, max_tilt_deg=0.5, min_tilt_deg=0.0)
    corners = noisy_corner_set(truth, 0.3, seed=81)
    with pytest.raises(EstimationError, match="fix no focal length"):
        calibrate_rig(corners)
    own = make_truth("stereo", 12, seed=82)
    known = {n: known_of(calibrate_rig(only(noisy_corner_set(own, 0.1, seed=83 + k), [n])), n)
             for k, n in enumerate(sorted(truth.cameras))}
    with collect_warnings():
        rig = calibrate_rig(corners, known_intrinsics=known)
    assert np.all(np.abs(_rig_z(rig, truth)) < 4)


def test_photos_of_one_camera_alone_keep_counting_for_it():
    """In the rig calibrated with the lenses given, instants where only the tele found the board are kept: its
    focal length's sigma is smaller with them than without them."""
    truth = make_truth("note8", 12, seed=84)
    corners = noisy_corner_set(truth, 0.1, seed=85)
    known = {"wide": KnownIntrinsics(truth.cameras["wide"])}
    solo = sorted(truth.view_poses)[:5]
    for v in solo:
        corners.cameras["wide"].views[v] = None
    with collect_warnings():
        kept = calibrate_rig(corners, known_intrinsics=known)
        without = calibrate_rig(corners.with_views(lambda _, v: v not in solo), known_intrinsics=known)
    assert set(solo) <= set(kept.camera_poses["tele"])
    assert kept.camera_sigma["tele"]["fx"] < without.camera_sigma["tele"]["fx"]
