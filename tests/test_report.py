"""The HTML report: its numbers against synthetic truth, its content, self-containedness and look."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from dualcal.files import io
from dualcal.synthetic import synth
from dualcal.estimation.outliers import outlier_limit_px
from dualcal.geometry.camera import (CameraModel, distort_normalized, max_distorted_radius, project_points,
                                     undistort_points)
from dualcal.geometry.model import CameraCorners, CornerSet, Pose
from dualcal.pages.report import analysis, figures, html as report_html, render_report
from dualcal.pages.photos import photo_status

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
NOISE_PX = 0.3

SIGMA = {"fx": 3.1, "fy": 3.0, "skew": 0.0, "cx": 2.5, "cy": 1.5, "k1": 0.011, "k2": 0.2}
EVALUATION = {"cases": {"dual": {"rmse_mm": [1.892, 1.488, 5.590], "pairs": 13},
                        "wide": {"rmse_mm": [0.120, 0.190, 0.528], "pairs": 78},
                        "tele": {"rmse_mm": [0.156, 0.219, 0.504], "pairs": 78}},
              "pose_free": {"dual": {"rms_mm": 6.538, "max_mm": 68.027, "lengths": 6240, "instants": 8}}}


@pytest.fixture(scope="module")
def rig():
    """The note8 truth with noisy corners, and plausible sigmas filled in."""
    truth = synth.make_truth("note8", views=8, seed=0, scale=0.25)
    rig = synth.truth_rig_model(truth, synth.noisy_corner_set(truth, NOISE_PX, seed=1))
    rig.camera_sigma = {name: dict(SIGMA) for name in rig.cameras}
    for rel in rig.rig.values():
        rel.sigma_t_mm, rel.sigma_baseline_mm = np.array([0.3, 0.2, 1.1]), 0.21
        rel.sigma_opk_arcmin = np.array([2.1, 3.3, 0.9])
    rig.skew, rig.rig_mode, rig.rms_px = False, "rigid", NOISE_PX * math.sqrt(2)
    rig.dropped_views = [{"camera": "tele", "view": "IMG_08", "rms_px": 3.2, "reason": "reprojection RMS 3.2 px"}]
    rig.adjustment = {"s0_px": 0.301, "redundancy": 1100, "iterations": 6, "n_observations": 1200,
                      "n_parameters": 100, "n_constraints": 0, "converged": True,
                      "termination": "the step fell below the tolerance",
                      "options": {"drop_outliers": True, "outlier_factor": 3.0},
                      "held_out_rms_px": 0.4431,
                      "lens_models": [{"model": "k1k2", "coefficients": 2, "fit_rms_px": 0.425, "held_out_rms_px": 0.4431,
                                       "worse_se": 3.4, "recommended": False},
                                      {"model": "k1k2p1p2", "coefficients": 4, "fit_rms_px": 0.418,
                                       "held_out_rms_px": 0.4372, "worse_se": 0.0, "recommended": True}]}
    del rig.camera_poses["tele"]["IMG_08"]
    rig.corners.cameras["wide"].views["IMG_07"] = None     # board not found in that photo
    rig.camera_sigma_formal = {name: {k: v / 3 for k, v in SIGMA.items()} for name in rig.cameras}
    for rel in rig.rig.values():
        rel.sigma_formal = {"t_mm": rel.sigma_t_mm / 3, "baseline_mm": rel.sigma_baseline_mm / 3,
                            "opk_arcmin": rel.sigma_opk_arcmin / 3}
    rig.checks = {"converged": {"ok": True, "message": "the adjustment converged in 6 iterations"},
                  "determination": {"ok": False, "message": "tele distortion known only to +-1.6 px at the outermost "
                                    "corner measured: add photos with the board near the corners and edges of the "
                                    "frame; wide fx known only to +-1.2 %: add photos with the board tilted"}}
    return rig


@pytest.fixture(scope="module")
def html(rig):
    return render_report(rig, EVALUATION)


# ---------------------------------------------------------------------------- the numbers


def test_residuals_are_recomputed_from_corners_and_poses(rig):
    """With true poses and intrinsics, the residuals are the added noise: sigma 0.3 px per axis."""
    res = analysis.rig_residuals(rig)
    assert set(res) == {"wide", "tele"}
    assert sorted(res["wide"]) == [f"IMG_0{i}" for i in (1, 2, 3, 4, 5, 6, 8)]
    assert sorted(res["tele"]) == [f"IMG_0{i}" for i in range(1, 8)]
    for views in res.values():
        all_res = np.vstack([r.residual_px for r in views.values()])
        np.testing.assert_allclose(all_res.std(axis=0), NOISE_PX, rtol=0.12)
        assert analysis.rms_px(all_res) == pytest.approx(NOISE_PX * math.sqrt(2), rel=0.1)


def test_exact_corners_give_zero_residuals():
    truth = synth.make_truth("stereo", views=3, seed=2)
    res = analysis.rig_residuals(synth.truth_rig_model(truth))
    assert max(np.abs(r.residual_px).max() for views in res.values() for r in views.values()) < 1e-9


def test_views_without_corners_or_pose_are_left_out(rig):
    cams = dict(rig.corners.cameras)
    tele = cams["tele"]
    cams["tele"] = CameraCorners(tele.image_size, {**tele.views, "IMG_02": None})
    poses = {**rig.camera_poses, "wide": {k: v for k, v in rig.camera_poses["wide"].items() if k != "IMG_03"}}
    res = analysis.rig_residuals(replace(rig, corners=CornerSet(rig.board, cams), camera_poses=poses))
    assert "IMG_02" not in res["tele"] and "IMG_02" in res["wide"]
    assert "IMG_03" not in res["wide"] and "IMG_03" in res["tele"]


def _views(lengths):
    """ViewResiduals whose corner residuals have the given lengths (along u)."""
    return {v: analysis.ViewResiduals(np.zeros((len(x), 2)), np.column_stack([x, np.zeros(len(x))]))
            for v, x in lengths.items()}


def test_outlier_views_follow_the_calibrations_rule():
    """A view is out of line when its RMS exceeds calibrate's limit for one corner: factor x the
    median corner residual of the camera, at least 0.05 px."""
    res = _views({"a": [0.3, 0.3], "b": [0.32, 0.32], "c": [0.28, 0.28], "d": [0.97, 0.97], "e": [0.7, 0.7]})
    assert analysis.view_outlier_limit_px(res, 3.0) == pytest.approx(0.96)     # median 0.32
    assert analysis.outlier_views(res, 3.0) == ["d"]
    assert analysis.outlier_views(res, 2.0) == ["d", "e"]
    tiny = _views({"a": [0.010], "b": [0.012], "c": [0.040]})                # 3 x median 0.036 < 0.05
    assert analysis.view_outlier_limit_px(tiny, 3.0) == outlier_limit_px(0.012, 3.0) == 0.05
    assert analysis.outlier_views(tiny, 3.0) == []
    assert analysis.outlier_views({}, 3.0) == []


def test_coverage_counts_half_the_image():
    """A board over the left half of a 100 x 60 image covers exactly the left half of the cells."""
    board = np.array([[-0.5, -0.5], [49.5, -0.5], [49.5, 59.5], [-0.5, 59.5]])
    counts = analysis.coverage_counts((100, 60), [board, board + [50, 0]], cell_px=10)
    assert counts.shape == (6, 10)
    np.testing.assert_array_equal(counts[:, :5], 1)
    np.testing.assert_array_equal(counts[:, 5:], 1)
    counts = analysis.coverage_counts((100, 60), [board], cell_px=10)
    assert counts[:, :5].min() == 1 and counts[:, 5:].max() == 0


def test_coverage_hints_name_what_is_missing():
    size = (400, 300)
    centre = [np.array([[190.0, 140.0], [210.0, 140.0], [210.0, 160.0], [190.0, 160.0]])]
    hints = analysis.coverage_hints("tele", size, centre, area_share=0.01)
    assert len(hints) == 3
    assert hints[0].startswith("no corners in the outer 20% of the tele image")
    assert "distortion there is extrapolated" in hints[0]
    assert "corners only in the centre of the tele image" in hints[1]
    assert "covered only 1% of the tele image" in hints[2]
    u, v = np.meshgrid(np.linspace(0, 399, 12), np.linspace(0, 299, 9))
    full = [np.column_stack([u.ravel(), v.ravel()])]
    assert analysis.coverage_hints("tele", size, full, area_share=1.0) == []


def test_distortion_curve_follows_the_model():
    cam = CameraModel((640, 480), 533.5, 533.5, 0.0, 341.6, 235.2, -0.288, 0.097)
    curve = analysis.distortion_curve(cam)
    f = math.sqrt(cam.fx * cam.fy)
    assert curve.fold_radius_px is None
    assert curve.radius_px[0] == 0 and curve.radius_px[-1] == pytest.approx(curve.corner_radius_px, rel=1e-9)
    r = (curve.radius_px - curve.shift_px) / f            # ideal radius
    rd = distort_normalized(np.column_stack([r, 0 * r]), cam.k1, cam.k2)[:, 0]
    np.testing.assert_allclose(rd * f, curve.radius_px, atol=1e-9)
    assert curve.shift_px[-1] < -50                         # strong barrel at the corner


def test_distortion_curve_stops_where_the_model_folds():
    cam = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.5, 0.0)   # folds at r = 1/sqrt(1.5)
    curve = analysis.distortion_curve(cam)
    r_fold = 1 / math.sqrt(1.5)
    assert curve.fold_radius_px == pytest.approx(300 * r_fold * (1 - 0.5 * r_fold**2), rel=1e-9)
    assert curve.fold_radius_px == 300 * max_distorted_radius(cam.k1, cam.k2)   # the library's fold
    assert curve.radius_px[-1] == pytest.approx(curve.fold_radius_px, rel=1e-9)
    assert curve.fold_radius_px < curve.corner_radius_px


def test_displacement_matches_undistortion():
    cam = CameraModel((640, 480), 533.5, 530.0, 1.5, 341.6, 235.2, -0.288, 0.097)
    uv = np.array([[0.0, 0.0], [639.0, 479.0], [341.6, 235.2], [500.0, 100.0]])
    expected = np.linalg.norm(uv - undistort_points(cam, uv), axis=1)
    np.testing.assert_allclose(analysis.displacement_px(cam, uv), expected, atol=1e-9)
    folded = CameraModel((640, 480), 300.0, 300.0, 0.0, 320.0, 240.0, -0.5, 0.0)
    d = analysis.displacement_px(folded, np.array([[320.0, 240.0], [0.0, 0.0]]))
    assert d[0] == 0 and np.isnan(d[1])


def test_a_tangential_lens_has_its_radial_part_as_curve_and_the_whole_lens_as_map():
    cam = synth.PRESETS["stereo5"]["cameras"]["left"]                   # k1 k2 p1 p2 k3
    radial = replace(cam, p1=0.0, p2=0.0, model="k1k2k3")
    curve, radial_curve = analysis.distortion_curve(cam), analysis.distortion_curve(radial)
    np.testing.assert_array_equal(curve.radius_px, radial_curve.radius_px)
    np.testing.assert_array_equal(curve.shift_px, radial_curve.shift_px)
    uv = np.array([[0.0, 0.0], [639.0, 479.0], [100.0, 400.0]])
    d = analysis.displacement_px(cam, uv)
    np.testing.assert_allclose(d, np.linalg.norm(uv - undistort_points(cam, uv), axis=1), atol=1e-9)
    assert np.max(np.abs(d - analysis.displacement_px(radial, uv))) > 0.1      # p1 = 0.0018 moves corners


def test_the_page_of_a_tangential_lens_lists_its_coefficients_and_says_what_the_curve_shows():
    rig = synth.truth_rig_model(synth.make_truth("stereo5", views=4, seed=0))
    sigma = dict(SIGMA, p1=1e-4, p2=2e-4, k3=0.05)
    rig.camera_sigma = {name: sigma for name in rig.cameras}
    p = _Page()
    p.feed(render_report(rig))
    cells = p.cells["table-intrinsics"]
    for label in ("p1", "p2", "k3"):
        values = [analysis.format_value_sigma(getattr(rig.cameras[n], label), sigma[label]) for n in ("left", "right")]
        assert _row(cells, label, 3)[1:] == [f"{v} ± {s}" for v, s in values]
    assert "radial part of the lens only" in p.figures["fig-distortion-curve"]["caption"]


@pytest.mark.parametrize("value, sigma, expected", [
    (3127.2083, 12.894, ("3127", "13")),
    (-0.01834, 0.0431, ("-0.018", "0.043")),
    (1.6359, 0.0996, ("1.64", "0.10")),
    (11.00712, 0.00021, ("11.00712", "0.00021")),
    (-0.0004, 0.02, ("0.000", "0.020")),
    (0.0, 0.0, ("0", "fixed")),
    (781.8, float("nan"), ("781.8", "–")),
])
def test_format_value_sigma(value, sigma, expected):
    assert analysis.format_value_sigma(value, sigma) == expected


# ---------------------------------------------------------------------------- the page


class _Page(HTMLParser):
    """Collects ids, figure ids with the tags inside them, table cells and all attributes."""

    def __init__(self):
        super().__init__()
        self.ids, self.attrs, self.figures, self.cells = set(), [], {}, {}
        self._figure, self._table, self._cell = None, None, None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.attrs += [(tag, k, v) for k, v in attrs]
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "figure":
            self._figure = a.get("id")
            self.figures[self._figure] = {"tags": set(), "caption": ""}
        elif self._figure:
            self.figures[self._figure]["tags"].add(tag)
        if tag == "table":
            self._table = a.get("id")
            self.cells[self._table] = []
        if tag in ("td", "th") and self._table:
            self._cell = []

    def handle_endtag(self, tag):
        if tag == "figure":
            self._figure = None
        if tag in ("td", "th") and self._cell is not None:
            self.cells[self._table].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)
        if self._figure and "figcaption" in self.figures[self._figure]["tags"]:
            self.figures[self._figure]["caption"] += data


@pytest.fixture(scope="module")
def page(html):
    p = _Page()
    p.feed(html)
    return p


FIGURES = {  # id -> words its caption must hold
    "fig-residuals-wide": "Residual vectors", "fig-residuals-tele": "Residual vectors",
    "fig-histogram-wide": "Histogram", "fig-histogram-tele": "Histogram",
    "fig-view-rms": "RMS residual of every view",
    "fig-coverage-wide": "Coverage", "fig-coverage-tele": "Coverage",
    "fig-distortion-curve": "Radial distortion",
    "fig-distortion-map-wide": "Distortion", "fig-distortion-map-tele": "Distortion",
    "fig-rig-3d": "reference (wide) camera frame",
}


def test_every_figure_is_there_with_svg_and_caption(page):
    assert set(FIGURES) <= set(page.figures)
    for fig_id, words in FIGURES.items():
        fig = page.figures[fig_id]
        assert "svg" in fig["tags"] and "path" in fig["tags"], fig_id
        assert words in fig["caption"], fig_id
    rule = "3× the median residual of the camera's corners, but at least 0.05 px (the calibration leaves out"
    assert rule in page.figures["fig-view-rms"]["caption"]


def test_evaluation_labels_every_dual_case_as_two_cameras():
    cases = {name: {"rmse_mm": [0.1, 0.2, 0.3], "pairs": 2}
             for name in ("dual", "dual:ultra", "ultra", "dualcam")}
    labels = {row["case"]: row["label"] for row in report_html.evaluation_table({"cases": cases})}
    assert labels == {"dual": "two cameras, same instant", "dual:ultra": "two cameras, same instant",
                      "ultra": "ultra camera, two instants", "dualcam": "dualcam camera, two instants"}


def test_frustum_corners_project_to_the_image_corners():
    """The frustum's base lies on the rays of the image's outer corners (skew included)."""
    cam = CameraModel((400, 300), 420.0, 410.0, 6.0, 205.0, 148.0, 0.0, 0.0)
    frame = Pose(np.eye(3), np.array([10.0, -4.0, 2.0]))
    f = figures._frustum(cam, frame, depth_mm=50.0)
    np.testing.assert_allclose(f[0], frame.t_mm)
    X_cam = frame.inverse().apply(f[1:])
    np.testing.assert_allclose(X_cam[:, 2], 50.0)
    corners = [[-0.5, -0.5], [399.5, -0.5], [399.5, 299.5], [-0.5, 299.5]]
    np.testing.assert_allclose(project_points(cam, X_cam), corners, atol=1e-9)


def _row(cells, label, n):
    """The ``n`` cells from the one labelled ``label`` on."""
    i = cells.index(label)
    return cells[i:i + n]


def test_tables_hold_the_calibration(page, rig):
    assert {"table-intrinsics", "table-rig", "table-evaluation", "table-photos", "table-adjustment"} <= page.ids
    cells = page.cells["table-intrinsics"]
    wide, tele = rig.cameras["wide"], rig.cameras["tele"]
    fx = [analysis.format_value_sigma(c.fx, 3.1) for c in (wide, tele)]
    # with the textbook sigma (here a third) beside it, to the sigma's digits
    assert _row(cells, "fx = α (px)", 3)[1:] == [f"{v} ± {s} (formal {3.1 / 3:.1f})" for v, s in fx]
    assert _row(cells, "k2", 2)[1].startswith(analysis.format_value_sigma(wide.k2, 0.2)[0] + " ")
    assert _row(cells, "skew = γ (px)", 2)[1].endswith("± fixed")
    rig_cells = page.cells["table-rig"]
    tele_rel = rig.rig["tele"]
    assert _row(rig_cells, "baseline D (mm)", 2)[1] == "{} ± {} (formal 0.07)".format(*analysis.format_value_sigma(
        tele_rel.baseline_mm, 0.21))
    assert _row(rig_cells, "κ (′)", 2)[1] == "{} ± {} (formal 0.30)".format(*analysis.format_value_sigma(
        tele_rel.pose.opk_arcmin[2], 0.9))
    # the perspective centre, as the rig figure labels it: C = -R^T t, the opposite sign of t
    centre = tele_rel.pose.center_mm
    assert _row(rig_cells, "centre CY (mm)", 2)[1] == analysis.format_value_sigma(centre[1], math.nan)[0]
    assert np.sign(centre[1]) == -np.sign(tele_rel.pose.t_mm[1])
    ev = page.cells["table-evaluation"]
    total = f"{math.sqrt(1.892**2 + 1.488**2 + 5.59**2):.3f}"
    assert _row(ev, "dual: two cameras, same instant", 5)[1:] == ["1.892", "1.488", "5.590", total]
    pose_free = page.cells["table-pose-free"]           # next to Tables 5/6
    assert _row(pose_free, "dual: two cameras, same instant", 5)[1:] == ["6.538", "68.027", "6240", "8"]
    photos = page.cells["table-photos"]
    assert _row(photos, "IMG_07", 4)[3] == "wide: board not found"
    assert _row(photos, "IMG_08", 4)[2:] == ["3.200", "tele: dropped: reprojection RMS 3.2 px"]
    assert _row(photos, "IMG_01", 4)[3] == "kept"


def test_the_adjustment_has_plain_labels(page):
    cells = page.cells["table-adjustment"]
    assert "outliers" in cells
    assert "corners above 3× the camera's median residual left out, photos where most corners are dropped" in cells
    assert _row(cells, "a-posteriori σ of a corner coordinate, s0 (px)", 2)[1] == "0.301"
    assert _row(cells, "converged", 2)[1] == "yes"
    assert _row(cells, "why the solver stopped", 2)[1] == "the step fell below the tolerance"
    assert not any(c.startswith("constraints") for c in cells)      # none in rig mode rigid
    assert not [c for c in cells if "_" in c or c in ("True", "False")]
    assert _row(cells, "RMS error of an instant left out of the calibration (px, per corner)", 2)[1] == "0.4431"


def test_the_lens_models_compared_are_on_the_page(page):
    cells = page.cells["table-lens-models"]
    assert _row(cells, "k1k2", 6)[1:] == ["2", "0.4250", "0.4431", "3.4", "used"]
    assert _row(cells, "k1k2p1p2", 6)[1:] == ["4", "0.4180", "0.4372", "0.0", "recommended"]


def test_summary_states_modes_and_rms(html):
    assert "Model 1: skew fixed to 0" in html and "rigid: one relative pose per camera" in html
    assert f"{NOISE_PX * math.sqrt(2):.3f} px" in html


def _with_noisy_tele_view(rig, gain: float):
    """``rig`` with tele/IMG_04's corners given ``gain`` x the noise."""
    cams = dict(rig.corners.cameras)
    tele = cams["tele"]
    noise = np.random.default_rng(7).normal(0, gain * NOISE_PX, (40, 2))
    cams["tele"] = CameraCorners(tele.image_size, {**tele.views, "IMG_04": tele.views["IMG_04"] + noise})
    return replace(rig, corners=CornerSet(rig.board, cams))


def test_outlier_view_is_found_and_hinted(rig):
    """A view with 5x the noise is an outlier of its camera, named in a hint."""
    found = analysis.camera_findings(_with_noisy_tele_view(rig, 5.0))
    assert found["tele"].outliers == ["IMG_04"] and found["wide"].outliers == []
    limit = found["tele"].outlier_limit_px
    hint = f"tele: view IMG_04 has an RMS above the camera's outlier limit of {limit:.3g} px"
    assert hint in found["tele"].hints[-1]
    assert found["tele"].view_rms_px["IMG_04"] > 4 * NOISE_PX


def test_outliers_use_the_factor_the_calibration_was_run_with(rig):
    """The recorded ``outlier_factor`` sets the limit (that of one corner: ``factor`` x the median
    length of the camera's corner residuals); files without it get calibrate's 6."""
    noisy = _with_noisy_tele_view(rig, 5.0)
    for options, factor in [(None, 6.0), ({"drop_outliers": True, "outlier_factor": 12.0}, 12.0)]:
        adjustment = {} if options is None else {"options": options}
        found = analysis.camera_findings(replace(noisy, adjustment=adjustment))["tele"]
        median = float(np.median(np.concatenate([np.linalg.norm(r.residual_px, axis=1)
                                                 for r in found.residuals.values()])))
        assert found.outlier_limit_px == outlier_limit_px(median, factor)
        assert found.outliers == [v for v, r in found.view_rms_px.items() if r > found.outlier_limit_px]
    assert found.outliers == [] and found.view_rms_px["IMG_04"] > 4 * median   # 12 x the median is not reached


def test_hints_and_left_out_views_are_on_the_page(html, rig):
    found = analysis.camera_findings(rig)
    status = photo_status(rig)                       # what the page's photo table and per-view figure show
    assert status["IMG_07"]["wide"] == (None, "board not found")
    assert status["IMG_08"]["tele"] == (3.2, "dropped: reprojection RMS 3.2 px")
    hints = [h for f in found.values() for h in f.hints]
    assert hints and any("outer 20% of the wide image" in h for h in hints)
    for h in hints:
        assert h in html


def test_page_is_self_contained(html):
    """No URL of any kind: nothing to fetch, no script; only local anchors and data: images."""
    assert not re.search(r"https?:|//[a-z0-9.-]+\.[a-z]{2,}/", html, re.I)
    assert not re.search(r"<(script|link|iframe|object|embed)\b", html, re.I)
    assert "@import" not in html
    for target in re.findall(r"url\(\s*['\"]?([^)'\"]*)", html):
        assert target.startswith("#"), target
    p = _Page()
    p.feed(html)
    for tag, key, value in p.attrs:
        if key in ("src", "href", "xlink:href"):
            assert value.startswith(("#", "data:image/png;base64,")), (tag, key, value[:40])


def test_ids_are_unique_on_the_page(html):
    """Several inline SVGs share one page: their internal ids must not collide."""
    ids = re.findall(r"\sid=\"([^\"]+)\"", html)
    assert len(ids) > 20 and len(ids) == len(set(ids))


def test_figures_are_reproducible(rig):
    """The same calibration gives the same bytes (no dates, no random ids)."""
    res = analysis.rig_residuals(rig)["tele"]
    with figures.style():
        a, b = (figures.figure_svg(figures.residual_quiver_figure("tele", (756, 1008), res), "fig-x")
                for _ in range(2))
    assert a == b and a.startswith("<svg ")


def test_page_size_is_reasonable(html):
    assert len(html.encode()) < 3_000_000


def test_report_of_single_camera_and_no_rig():
    """A lone camera (rig mode none): no rig table, the page still renders every camera figure."""
    truth = synth.make_truth("stereo", views=4, seed=5, scale=0.5)
    full = synth.truth_rig_model(truth)
    left = CornerSet(full.board, {"left": full.corners.cameras["left"]})
    lone = replace(full, cameras={"left": full.cameras["left"]}, rig={}, rig_mode="none", reference="left",
                   camera_poses={"left": full.camera_poses["left"]}, corners=left,
                   camera_sigma={"left": dict(SIGMA)})
    out = render_report(lone)
    assert "a single camera" in out and "table-rig" not in out and "table-evaluation" not in out
    assert 'id="fig-residuals-left"' in out and 'id="fig-rig-3d"' in out


# ---------------------------------------------------------------------------- what the figures draw


def _renamed(rig, names: dict[str, str]):
    """``rig`` with its cameras renamed (``names[old] -> new``)."""
    def keyed(d):
        return {names.get(k, k): v for k, v in d.items()}

    corners = CornerSet(rig.board, keyed(rig.corners.cameras))
    return replace(rig, reference=names.get(rig.reference, rig.reference), cameras=keyed(rig.cameras),
                   camera_sigma=keyed(rig.camera_sigma), camera_rms_px=keyed(rig.camera_rms_px), rig=keyed(rig.rig),
                   camera_poses=keyed(rig.camera_poses), view_rms_px={v: keyed(d) for v, d in rig.view_rms_px.items()},
                   corners=corners, dropped_views=[{**d, "camera": names.get(d["camera"], d["camera"])}
                                                   for d in rig.dropped_views])


LONG_NAMES = {"wide": "wide_angle_main_camera_of_the_phone_0123456789", "tele": "telephoto periscope camera 3x"}


def test_dropped_and_missing_photos_are_not_drawn_as_bars_at_zero(rig):
    found = analysis.camera_findings(rig)
    with figures.style():
        fig = figures.view_rms_figure({n: found[n].view_rms_px for n in rig.cameras}, {}, {}, {},
                                      *report_html._not_kept(rig, list(rig.cameras)))
    ax = fig.axes[0]
    bars = [p for p in ax.patches if p.get_width() > 0 and np.isfinite(p.get_height())]
    assert len(bars) == 7 + 7 + 1                        # wide 7 views, tele 7, tele/IMG_08 dropped at its RMS
    assert min(b.get_height() for b in bars) > 0.1
    assert max(b.get_height() for b in bars) == pytest.approx(3.2)
    assert not bars[-1].get_fill()                        # the dropped photo: an outline


def test_the_distortion_curve_is_dashed_beyond_the_last_observed_corner(rig):
    found = analysis.camera_findings(rig)
    with figures.style():
        fig = figures.distortion_curve_figure({"wide": found["wide"].curve}, {"wide": found["wide"].reach_px})
    solid, dashed = [line for line in fig.axes[0].lines if len(line.get_xdata()) > 2][:2]
    assert solid.get_linestyle() == "-" and dashed.get_linestyle() == "--"
    assert max(solid.get_xdata()) <= found["wide"].reach_px < min(dashed.get_xdata())
    assert max(dashed.get_xdata()) == pytest.approx(found["wide"].curve.corner_radius_px)


def test_one_camera_has_no_perspective_centre_plot():
    truth = synth.make_truth("stereo", views=3, seed=5, scale=0.5)
    full = synth.truth_rig_model(truth)
    with figures.style():
        one = figures.rig_figure(full.board, full.reference_poses(), {"left": full.cameras["left"]},
                                 analysis.rig_camera_frames(replace(full, rig={})), "left")
        two = figures.rig_figure(full.board, full.reference_poses(), full.cameras, analysis.rig_camera_frames(full),
                                 "left")
    assert len(one.axes) == 1 and len(two.axes) == 2
    labels = [t.get_text() for t in two.axes[1].texts if t.get_text().startswith("right")]
    centre = full.rig["right"].pose.center_mm
    assert labels == [f"right\nC = ({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f})"]


def test_corners_not_measured_are_left_out_of_residuals_and_the_page_renders(rig):
    """A view with NaN rows (corners not measured): residuals of the measured ones only, finite RMS."""
    cams = dict(rig.corners.cameras)
    uv = cams["wide"].views["IMG_02"].copy()
    uv[[0, 9, 17]] = np.nan
    cams["wide"] = CameraCorners(cams["wide"].image_size, {**cams["wide"].views, "IMG_02": uv})
    holed = replace(rig, corners=CornerSet(rig.board, cams))
    res = analysis.rig_residuals(holed)["wide"]["IMG_02"]
    assert res.uv_px.shape == (37, 2) and np.isfinite(res.residual_px).all()
    found = analysis.camera_findings(holed)
    assert np.isfinite(found["wide"].rms_px) and np.isfinite(found["wide"].view_rms_px["IMG_02"])
    assert "IMG_02" in render_report(holed)


# ---------------------------------------------------------------------------- in a browser

_OVERFLOWS = """() => {
  const bad = [];
  const root = document.documentElement;
  if (root.scrollWidth > root.clientWidth + 1) bad.push(`the page scrolls sideways (${root.scrollWidth} px)`);
  for (const el of document.querySelectorAll("h1, h2, h3, caption, figcaption, th, td, p, li, .fact .v")) {
    if (el.scrollWidth > el.clientWidth + 1) bad.push(`${el.tagName} overflows: ${el.textContent.slice(0, 50)}`);
  }
  for (const el of document.querySelectorAll("table, nav a, figure")) {
    const box = el.getBoundingClientRect(), outer = el.parentElement.getBoundingClientRect();
    if (box.left < outer.left - 1 || box.right > outer.right + 1)
      bad.push(`${el.tagName} ${el.id || el.textContent.slice(0, 30)} is wider than its container`);
  }
  for (const svg of document.querySelectorAll("figure svg")) {
    const s = svg.getBoundingClientRect();
    for (const t of svg.querySelectorAll("text")) {
      const b = t.getBoundingClientRect();
      if (b.width > 0 && (b.left < s.left - 1 || b.right > s.right + 1 || b.top < s.top - 1 || b.bottom > s.bottom + 1))
        bad.push(`text cut off in ${svg.closest("figure").id}: ${t.textContent.slice(0, 50)}`);
    }
  }
  return bad;
}"""


@pytest.fixture(scope="module")
def long_names_page(rig, tmp_path_factory):
    """The report of the rig with long camera names, with its evaluation."""
    evaluation = {"cases": {"dual": EVALUATION["cases"]["dual"],
                            **{LONG_NAMES[k]: v for k, v in EVALUATION["cases"].items() if k != "dual"}}}
    path = tmp_path_factory.mktemp("page") / "report.html"
    bent = replace(_renamed(rig, LONG_NAMES), board_shape_mm=np.array([0.12, -0.25, 0.68]),
                   board_shape_sigma_mm=np.array([0.04, 0.07, 0.04]))
    path.write_text(render_report(bent, evaluation), encoding="utf-8")
    return path


@pytest.mark.parametrize("width", [1280, 420])
def test_nothing_overflows_at_desktop_and_phone_widths(browser, long_names_page, width):
    """Titles, tables and figure texts stay inside their containers, with long camera names too."""
    page = browser.new_page(viewport={"width": width, "height": 900})
    try:
        page.goto(long_names_page.as_uri())
        assert page.title().startswith("dualcal calibration")
        assert page.locator("#table-photos tr").count() == 9          # header and 8 views
        assert page.evaluate(_OVERFLOWS) == []
        shot = np.frombuffer(page.screenshot(full_page=False, type="png"), np.uint8)
        assert shot.size > 10_000
    finally:
        page.close()


def test_the_checks_catch_an_overflow(browser, tmp_path):
    """The same measurement fails on a table that is too wide and a cut-off SVG text."""
    path = tmp_path / "bad.html"
    path.write_text("<main style='width:300px'><table id='t'><tr><td style='white-space:nowrap'>"
                    + "x" * 200 + "</td></tr></table><figure id='f'><svg width='50' height='20'>"
                    "<text x='0' y='15'>far too long a title for this figure</text></svg></figure></main>")
    page = browser.new_page(viewport={"width": 420, "height": 300})
    try:
        page.goto(path.as_uri())
        bad = page.evaluate(_OVERFLOWS)
    finally:
        page.close()
    assert any("TABLE t is wider" in b for b in bad) and any("text cut off in f" in b for b in bad)


# ---------------------------------------------------------------------------- command line and real data



def test_cli_report_with_evaluation(rig, tmp_path, run_cli):
    calib, ev, out = tmp_path / "calib.json", tmp_path / "eval.json", tmp_path / "report.html"
    io.save_rig(calib, rig)
    io.write_json_atomic(ev, EVALUATION)
    code, stdout, _ = run_cli("report", str(calib), "--eval", str(ev), "-o", str(out))
    assert code == 0 and "report written to" in stdout
    text = out.read_text(encoding="utf-8")
    assert 'id="table-evaluation"' in text and 'id="fig-rig-3d"' in text


@pytest.mark.parametrize("case, message", [
    ("corners", "this is a corners.json, expected a calib.json"),
    ("eval-is-calib", "this is a calib.json, expected an eval.json"),
    ("no-folder", "output folder"),
])
def test_cli_report_errors_are_one_line(rig, tmp_path, run_cli, case, message):
    calib = tmp_path / "calib.json"
    io.save_rig(calib, rig)
    args = ["report", str(calib), "-o", str(tmp_path / "r.html")]
    if case == "corners":
        io.save_corners(tmp_path / "corners.json", rig.corners)
        args[1] = str(tmp_path / "corners.json")
    elif case == "eval-is-calib":
        args += ["--eval", str(calib)]
    else:
        args[3] = str(tmp_path / "missing" / "r.html")
    code, _, err = run_cli(*args)
    assert code == 2 and message in err
    assert len(err.strip().splitlines()) == 1


STEREO = DATA / "opencv-samples-stereo"


@pytest.mark.slow
@pytest.mark.skipif(not (STEREO / "left01.jpg").exists(), reason=f"real photos not found at {STEREO}")
# detection now leaves a few null corners in these photos; until the solver takes them (another
# branch) it fails on them with LinAlgError; any assertion failure is still a failure
def test_end_to_end_real_stereo_photos(tmp_path, run_cli):
    """Bouguet's stereo pairs: detect, calibrate, report and export; T against Bouguet's published value.

    Bouguet (joint stereo optimisation, 14 pairs): T = [-99.80198, 1.12443, 0.05041] mm with
    about 3-sigma uncertainties [0.142, 0.114, 0.498] mm (SOURCE.md). The exported T must agree
    within those plus a margin for the different distortion model (k1, k2 only, 13 pairs).
    """
    import cv2

    from dualcal.geometry.board import Board
    from dualcal.estimation.calibrate import calibrate_rig
    from dualcal.files.dataset import open_dataset
    from dualcal.files.detect.pipeline import detect_dataset

    ds = open_dataset(None, [f"left={STEREO}/left*.jpg", f"right={STEREO}/right*.jpg"])
    corners = detect_dataset(ds, Board(9, 6, 30.0), jobs=1, progress=False)
    calib = tmp_path / "calib.json"
    io.save_rig(calib, calibrate_rig(corners))

    code, _, _ = run_cli("report", str(calib), "-o", str(tmp_path / "report.html"))
    assert code == 0
    page = _Page()
    page.feed((tmp_path / "report.html").read_text(encoding="utf-8"))
    assert {"fig-residuals-left", "fig-residuals-right", "fig-coverage-right", "fig-rig-3d"} <= set(page.figures)

    code, _, _ = run_cli("export", str(calib), "--format", "opencv", "-o", str(tmp_path / "stereo.yml"))
    assert code == 0
    fs = cv2.FileStorage(str(tmp_path / "stereo.yml"), cv2.FILE_STORAGE_READ)
    T = fs.getNode("right").getNode("T").mat()
    assert np.all(np.abs(T.ravel() - [-99.80198, 1.12443, 0.05041]) < [0.3, 0.3, 0.8]), T.ravel()


def test_the_verdict_the_checks_the_board_shape_and_both_sigmas_are_on_the_page():
    """A calibration of a bent board whose corners are far off (1.5 px): the verdict and the
    failing fit check at the top, the board's shape in the summary, the textbook sigma beside
    every sigma."""
    from dualcal.geometry.board import shaped_points_mm
    from dualcal.estimation.calibrate import calibrate_rig

    truth = synth.make_truth("stereo", 10, seed=3)
    X = shaped_points_mm(truth.board.object_points_mm(), np.array([0.8, 0.0, 0.6]))
    rng = np.random.default_rng(4)
    cams = {n: CameraCorners(c.image_size, {v: project_points(c, truth.camera_pose(n, v).apply(X))
                                            + rng.normal(0, 1.5, (len(X), 2)) for v in truth.view_poses})
            for n, c in truth.cameras.items()}
    rig = calibrate_rig(CornerSet(truth.board, cams), board_shape="fit")
    assert not rig.checks["fit"]["ok"]
    out = render_report(rig)
    page = _Page()
    page.feed(out)
    assert 'id="verdict"' in out and "verdict: use with care" in out
    checks = page.cells["table-checks"]
    assert _row(checks, "fit", 3)[1] == "FAIL" and _row(checks, "converged", 3)[1] == "pass"
    assert "bent by" in out and "sag, bend and twist" in out
    intrinsics = " ".join(page.cells["table-intrinsics"])
    assert intrinsics.count("(formal ") == 2 * 6 and "(formal " in " ".join(page.cells["table-rig"])


def test_a_fisheye_curve_is_against_the_pinhole_image_of_the_same_ray():
    """phone3's kb4 ultra-wide: the curve runs out to the image's corner (73 degrees off the axis),
    its ideal radius ``tan(theta)``, and the page lists k1 .. k4 of that camera alone."""
    truth = synth.make_truth("phone3", views=4, seed=0, scale=0.25)
    cam = truth.cameras["ultra"]
    curve = analysis.distortion_curve(cam)
    f = math.sqrt(cam.fx * cam.fy)
    assert curve.fold_radius_px is None
    assert curve.radius_px[-1] == pytest.approx(curve.corner_radius_px, rel=1e-9)
    theta = np.arctan((curve.radius_px - curve.shift_px) / f)
    k = np.array(cam.distortion)
    np.testing.assert_allclose(theta * (1 + sum(k[j] * theta ** (2 * j + 2) for j in range(4))) * f, curve.radius_px,
                               atol=1e-6)
    rig = synth.truth_rig_model(truth)
    rig.camera_sigma = {name: dict(SIGMA, p1=1e-4, p2=2e-4, k3=0.05, k4=0.01) for name in rig.cameras}
    p = _Page()
    p.feed(render_report(rig))
    cells = p.cells["table-intrinsics"]
    row = _row(cells, "k4", 4)[1:]                               # a cell per camera: only the ultra-wide has k4
    assert row.count("–") == 2
    assert next(c for c in row if c != "–").startswith(analysis.format_value_sigma(cam.k4, 0.01)[0])


def test_the_lens_models_auto_chose_are_on_the_page_camera_by_camera():
    rig = synth.truth_rig_model(synth.make_truth("phone3", views=4, seed=0, scale=0.25))
    rig.camera_sigma = {name: dict(SIGMA, p1=1e-4, p2=2e-4, k3=0.05, k4=0.01) for name in rig.cameras}
    score = {"candidate": True, "fit_rms_px": 0.03, "held_out_rms_px": 0.031, "worse_se": 0.0, "recommended": True}
    rig.adjustment["lens_models"] = [
        {"model": "k1k2", "per_camera": {n: {**score, "held_out_rms_px": 0.3 if n == "ultra" else 0.031} for n in rig.cameras}},
        {"model": "kb4", "per_camera": {n: score if n == "ultra" else {"candidate": False} for n in rig.cameras}}]
    rig.adjustment["lens_models_chosen"] = {"tele": "k1k2", "ultra": "kb4", "wide": "k1k2"}
    p = _Page()
    p.feed(render_report(rig))
    cells = p.cells["table-lens-model-choice"]
    assert _row(cells, "ultra", 3) == ["ultra", "0.3000 (0.0)", "0.0310 (0.0) chosen"]
    assert _row(cells, "tele", 3) == ["tele", "0.0310 (0.0) chosen", "–"]
    assert "table-lens-models" not in p.cells
