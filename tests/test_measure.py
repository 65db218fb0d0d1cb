"""Measuring with a calibrated rig (dualcal.estimation.measurement), ``dualcal measure`` and its pick page.

The Monte Carlo tests draw the calibration photos' corner noise and the measured pixels' noise
afresh in every draw, calibrate, measure one dual shot of a tilted 3 x 3 grid of points at two
distances, and check z = (measured - true) / sigma for every length and every point coordinate.
"""

import contextlib
import io
import json
import re
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from schema_check import assert_valid
from dualcal.estimation.calibrate import calibrate_rig
from dualcal.geometry.camera import project_points
from dualcal.errors import EstimationError, InputError
from dualcal.files.io import load_points, save_rig
from dualcal.estimation.measurement import _covariances, calibration_pixel_sigma, intersect_point, measure
from dualcal.geometry.model import Pose
from dualcal.geometry.rotation import rotation_from_opk, rotation_from_rotvec
from dualcal.synthetic.synth import make_truth, noisy_corner_set, truth_rig_model

CORNER_NOISE_PX = 0.3     # of the calibration photos' corners, px per coordinate
PIXEL_SIGMA = 0.3         # of the measured points' pixels
DRAWS = 40
#: preset -> (the two distances measured at, mm; the grid's share of the narrowest camera's field of view)
SCENES = {"note8": ((400.0, 1000.0), 0.6), "stereo": ((500.0, 1200.0), 0.4)}


def shot(truth, X_ref: np.ndarray, rng=None, pixel_sigma: float = PIXEL_SIGMA) -> dict:
    """A points.json of points ``X_ref`` (P, 3; reference camera's frame) seen by every camera at one instant,
    true pixels plus Gaussian noise; lengths between every two points."""
    points = {}
    for i, X in enumerate(X_ref):
        points[f"P{i}"] = {}
        for cam, model in truth.cameras.items():
            X_cam = X[None] if cam == truth.reference else truth.rig[cam].apply(X[None])
            uv = project_points(model, X_cam)[0]
            if rng is not None:
                uv = uv + rng.normal(0.0, pixel_sigma, 2)
            points[f"P{i}"][cam] = uv.tolist()
    names = list(points)
    return {"points": points, "lengths": [[a, b] for i, a in enumerate(names) for b in names[i + 1:]],
            "pixel_sigma": pixel_sigma}


def grid(truth, distance_mm: float, share: float) -> np.ndarray:
    """A 3 x 3 grid of points tilted by 15-20 degrees, filling ``share`` of the narrowest camera's view at ``distance_mm``."""
    cam = max(truth.cameras.values(), key=lambda c: c.fx / min(c.image_size))
    w, h = cam.image_size
    step = np.array([w / cam.fx, h / cam.fy]) * distance_mm * share / 2
    X = np.array([[i * step[0], j * step[1], 0.0] for j in (-1, 0, 1) for i in (-1, 0, 1)])
    return X @ rotation_from_opk(np.radians([15.0, -20.0, 5.0])).T + [0.0, 0.0, distance_mm]


def quiet_measure(rig, points):
    with contextlib.redirect_stderr(io.StringIO()):
        return measure(rig, points)


@pytest.fixture(scope="module")
def draws(computed_once):
    """``{preset: (truth, [DRAWS calibrations, each from its own corner noise])}``, shared by the Monte Carlo tests."""
    def compute():
        out = {}
        for preset in SCENES:
            truth = make_truth(preset, views=8, seed=1)
            out[preset] = truth, [calibrate_rig(noisy_corner_set(truth, CORNER_NOISE_PX, seed=100 + k),
                                                board_shape="flat") for k in range(DRAWS)]
        return out
    return computed_once("measure-draws", compute)


# ---------------------------------------------------------------------------- Monte Carlo: the sigmas hold


@pytest.mark.parametrize("preset,distance_mm", [(p, d) for p, (ds, _) in SCENES.items() for d in ds])
def test_length_and_point_sigmas_hold_over_noise_draws(draws, preset, distance_mm):
    """40 draws x 36 lengths (every two of 9 points, 100-700 mm long) of one dual shot, and 40 x 27 point
    coordinates: z = (measured - true) / sigma has sd within 0.8-1.25 and mean within +-0.2."""
    truth, rigs = draws[preset]
    X = grid(truth, distance_mm, SCENES[preset][1])
    rng = np.random.default_rng(int(distance_mm))
    z_len, z_pt = [], []
    for rig in rigs:
        doc = quiet_measure(rig, shot(truth, X, rng))
        for L in doc["lengths"]:
            true = np.linalg.norm(X[int(L["from"][1:])] - X[int(L["to"][1:])])
            z_len.append((L["length_mm"] - true) / L["sigma_mm"])
        for name, p in doc["points"].items():
            z_pt.extend((np.array(p["xyz_mm"]) - X[int(name[1:])]) / np.array(p["sigma_mm"]))
    z_len, z_pt = np.array(z_len), np.array(z_pt)
    assert len(z_len) == DRAWS * 36 and len(z_pt) == DRAWS * 27
    summary = (f"{preset} at {distance_mm:.0f} mm: {len(z_len)} lengths z mean {z_len.mean():+.3f} sd {z_len.std():.3f}; "
               f"{len(z_pt)} coordinates z mean {z_pt.mean():+.3f} sd {z_pt.std():.3f}")
    print(summary)
    assert 0.8 <= z_len.std() <= 1.25 and abs(z_len.mean()) <= 0.2, summary
    assert 0.8 <= z_pt.std() <= 1.25 and abs(z_pt.mean()) <= 0.2, summary


def test_the_calibration_part_of_a_length_is_its_scatter_over_calibrations(draws):
    """Exact pixels: what is left is the calibration's error, common to the whole shot; its spread over the
    draws is the sigma propagated from the calibration's covariance (within 0.75-1.3)."""
    truth, rigs = draws["note8"]
    X = grid(truth, 400.0, SCENES["note8"][1])
    exact = shot(truth, X)
    docs = [quiet_measure(rig, exact) for rig in rigs]
    true = np.array([np.linalg.norm(X[int(L["from"][1:])] - X[int(L["to"][1:])]) for L in docs[0]["lengths"]])
    err = np.array([[L["length_mm"] for L in d["lengths"]] for d in docs]) - true
    sigma = np.array([[L["sigma_calibration_mm"] for L in d["lengths"]] for d in docs]).mean(axis=0)
    ratio = err.std(axis=0) / sigma
    assert 0.75 <= np.median(ratio) <= 1.3, ratio


# ---------------------------------------------------------------------------- the linearisation


def _perturbed(rig, names: list[str], delta: np.ndarray):
    """``rig`` moved by ``delta`` in the covariance's parametrisation (intrinsics; rotation's LEFT increment, t)."""
    index = {n: i for i, n in enumerate(names)}
    cams = {c: replace(m, **{k: getattr(m, k) + delta[index[f"{c}.{k}"]] for k in m.__dataclass_fields__
                             if f"{c}.{k}" in index}) for c, m in rig.cameras.items()}
    rels = {}
    for c, rel in rig.rig.items():
        d = np.array([delta[index[f"{c}.rig.rotation_rad.{a}"]] for a in "xyz"])
        t = np.array([delta[index[f"{c}.rig.t_mm.{a}"]] for a in "xyz"])
        rels[c] = replace(rel, pose=Pose(rotation_from_rotvec(d) @ rel.pose.R, rel.pose.t_mm + t))
    return replace(rig, cameras=cams, rig=rels)


@pytest.mark.parametrize("preset,model", [("note8", "k1k2"), ("stereo5", "k1k2p1p2k3")])
def test_point_sensitivities_match_central_differences(preset, model):
    truth = make_truth(preset, views=6, seed=1)
    rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=3), board_shape="flat", model=model)
    index, cov = _covariances(rig)
    names = list(index)
    assert model == "k1k2" or {f"{c}.{k}" for c in rig.cameras for k in ("p1", "p2", "k3")} <= set(names)
    uv = shot(truth, np.array([[30.0, -20.0, 600.0]]))["points"]["P0"]
    point = intersect_point(rig, uv, index)
    step = np.sqrt(np.diag(cov["formal"])) * 1e-2
    B = np.empty_like(point.B)
    for k in range(len(names)):
        e = np.zeros(len(names))
        e[k] = step[k]
        B[:, k] = (intersect_point(_perturbed(rig, names, e), uv, index).xyz_mm
                   - intersect_point(_perturbed(rig, names, -e), uv, index).xyz_mm) / (2 * step[k])
    scale = np.abs(point.B * step).max() / 1e-2
    assert np.abs((B - point.B) * step / 1e-2).max() < 2e-3 * scale
    A = np.empty_like(point.A)
    for k in range(A.shape[1]):
        moved = []
        for h in (1e-3, -1e-3):
            pixels = {c: np.array(v, float) for c, v in uv.items()}
            pixels[point.cameras[k // 2]][k % 2] += h
            moved.append(intersect_point(rig, pixels, index).xyz_mm)
        A[:, k] = (moved[0] - moved[1]) / 2e-3
    assert np.abs(A - point.A).max() < 1e-4 * np.abs(point.A).max()


# ---------------------------------------------------------------------------- the document, flags and errors


@pytest.fixture(scope="module")
def note8(draws):
    truth, rigs = draws["note8"]
    return truth, rigs[0]


def test_measure_follows_the_contract_and_recovers_a_known_length(note8):
    truth, rig = note8
    X = np.array([[-60.0, -40.0, 450.0], [70.0, 30.0, 420.0]])
    doc = measure(rig, shot(truth, X, np.random.default_rng(0)))
    assert doc["frame"] == "wide" and set(doc["points"]) == {"P0", "P1"}
    for name, p in doc["points"].items():
        assert len(p["xyz_mm"]) == 3 and len(p["sigma_mm"]) == 3 and p["cameras"] == ["wide", "tele"]
        assert np.all(np.abs(np.array(p["xyz_mm"]) - X[int(name[1:])]) < 5 * np.array(p["sigma_mm"]))
        assert p["consistent"]
    (L,) = doc["lengths"]
    assert (L["from"], L["to"]) == ("P0", "P1") and not L["meaningless"] and L["warning"] is None
    assert abs(L["length_mm"] - np.linalg.norm(X[0] - X[1])) < 5 * L["sigma_mm"]
    assert L["sigma_mm"] ** 2 == pytest.approx(L["sigma_pixels_mm"] ** 2 + L["sigma_calibration_mm"] ** 2, rel=1e-9)
    assert L["sigma_percent"] == pytest.approx(100 * L["sigma_mm"] / L["length_mm"])
    json.dumps(doc, allow_nan=False)


def test_the_default_pixel_noise_is_the_calibrations_own(note8):
    truth, rig = note8
    own = calibration_pixel_sigma(rig)
    assert set(own) == {"wide", "tele"}
    for sigma in own.values():
        assert sigma == pytest.approx(CORNER_NOISE_PX, rel=0.1)
    points = shot(truth, np.array([[0.0, 0.0, 500.0], [50.0, 0.0, 500.0]]))
    del points["pixel_sigma"]
    doc = measure(rig, points)
    assert doc["pixel_sigma_source"] == "calibration" and doc["pixel_sigma"] == own
    per_camera = measure(rig, {**points, "pixel_sigma": {"tele": 1.0}})
    assert per_camera["pixel_sigma"] == {"wide": own["wide"], "tele": 1.0}
    assert per_camera["lengths"][0]["sigma_mm"] > doc["lengths"][0]["sigma_mm"]


def test_a_length_an_11_mm_baseline_cannot_measure_is_flagged_and_the_warning_says_what_would_help(note8, capsys):
    truth, rig = note8
    X = np.array([[-40.0, 0.0, 3000.0], [40.0, 10.0, 3000.0], [-60.0, -50.0, 400.0], [60.0, 40.0, 410.0]])
    points = shot(truth, X)
    points["lengths"] = [["P0", "P1"], ["P2", "P3"]]
    capsys.readouterr()
    far, near = measure(rig, points)["lengths"]
    err = capsys.readouterr().err
    assert far["meaningless"] and not near["meaningless"] and near["warning"] is None
    assert err.count("dualcal: warning:") == 1 and far["warning"] in " ".join(err.split())
    assert far["warning"].startswith("length P0-P1 = 80.") and "depth: P0 +-" in far["warning"]
    assert re.search(r"What would help: get closer \(P[01] is (29|30)\d\d mm away\)", far["warning"])
    assert "a pair of cameras with a longer baseline (wide+tele: 11.0 mm)" in far["warning"]


def test_pixels_that_disagree_are_flagged(note8, capsys):
    truth, rig = note8
    points = shot(truth, np.array([[0.0, 0.0, 500.0], [50.0, 0.0, 500.0]]))
    points["points"]["P1"]["tele"][0] += 25.0               # a mis-click in the tele photo (across the baseline)
    capsys.readouterr()
    doc = measure(rig, points)
    assert doc["points"]["P0"]["consistent"] and not doc["points"]["P1"]["consistent"]
    assert "point P1: its pixels disagree" in capsys.readouterr().err


def test_three_cameras_measure_together():
    truth = make_truth("triple", views=6, seed=0)
    rig = calibrate_rig(noisy_corner_set(truth, 0.2, seed=0), board_shape="flat")
    X = np.array([[-50.0, -30.0, 500.0], [40.0, 60.0, 520.0]])
    both = quiet_measure(rig, shot(truth, X, np.random.default_rng(1)))
    pair = shot(truth, X, np.random.default_rng(1))
    for p in pair["points"].values():
        del p["ultra"]
    two = quiet_measure(rig, pair)
    assert both["points"]["P0"]["cameras"] == ["wide", "tele", "ultra"]
    for doc in (both, two):
        assert abs(doc["lengths"][0]["length_mm"] - np.linalg.norm(X[0] - X[1])) < 4 * doc["lengths"][0]["sigma_mm"]
    assert both["lengths"][0]["sigma_mm"] < two["lengths"][0]["sigma_mm"]


@pytest.mark.parametrize("change, message", [
    (lambda d: d["points"]["P0"].pop("tele"), "point 'P0' is given in 1 camera(s) (wide)"),
    (lambda d: d["points"]["P0"].update(left=[1.0, 2.0]), "point 'P0': camera 'left' is not in the calibration"),
    (lambda d: d["lengths"].append(["P0", "Q"]), "names point 'Q', which is not in 'points'"),
    (lambda d: d["lengths"].append(["P0", "P0"]), "joins a point to itself"),
    (lambda d: d.update(pixel_sigma=-1), "pixel_sigma: expected a positive number of pixels, got -1"),
    (lambda d: d["points"]["P0"].update(wide=[1.0, "x"]), "point 'P0' in camera 'wide'"),
    (lambda d: d.update(points={}), "'points' must be a non-empty object"),
])
def test_bad_points_are_refused_with_a_clear_message(note8, change, message):
    truth, rig = note8
    doc = shot(truth, np.array([[0.0, 0.0, 500.0], [50.0, 0.0, 500.0]]))
    change(doc)
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        measure(rig, doc)


def test_a_calibration_without_its_covariance_and_rays_that_do_not_meet_are_refused(note8):
    truth, rig = note8
    doc = shot(truth, np.array([[0.0, 0.0, 500.0], [50.0, 0.0, 500.0]]))
    with pytest.raises(InputError, match="holds no joint covariance"):
        measure(truth_rig_model(truth), doc)
    with pytest.raises(InputError, match="no relative pose of camera 'tele'"):
        measure(replace(rig, rig={}), doc)
    same = {"points": {"A": {"wide": [100.0, 100.0], "tele": [100.0, 100.0]}}}   # rays that never meet in front
    with pytest.raises(EstimationError, match="point 'A'"):
        measure(rig, same)


# ---------------------------------------------------------------------------- the command


@pytest.fixture
def calib_file(note8, tmp_path):
    save_rig(tmp_path / "calib.json", note8[1])
    return tmp_path / "calib.json"


def test_measure_command_writes_measure_json_and_prints_the_tables(note8, calib_file, tmp_path, run_cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    truth, _ = note8
    points = shot(truth, np.array([[-60.0, -40.0, 450.0], [70.0, 30.0, 420.0], [0.0, 50.0, 3000.0],
                                   [80.0, 60.0, 3000.0]]))
    points["lengths"] = [["P0", "P1"], ["P2", "P3"]]
    (tmp_path / "points.json").write_text(json.dumps(points))
    res = run_cli("measure", calib_file, "--points", tmp_path / "points.json", "-o", tmp_path / "measure.json")
    assert res.code == 0, res.err
    doc = assert_valid(tmp_path / "measure.json")
    assert doc["frame"] == "wide" and list(doc["points"]) == ["P0", "P1", "P2", "P3"]
    rows = {r.split("│")[1].strip(): [c.strip() for c in r.split("│")[2:-1]]
            for r in res.out.split("Lengths")[1].splitlines() if r.startswith("│")}
    for L in doc["lengths"]:
        row = rows[f"{L['from']}-{L['to']}"]
        assert [float(x) for x in row[:3]] == pytest.approx(
            [L["length_mm"], L["sigma_mm"], L["sigma_percent"]], abs=6e-3)
        assert (row[3] != "") == L["meaningless"]
    assert not doc["lengths"][0]["meaningless"] and doc["lengths"][1]["meaningless"] and "length P2-P3" in res.err
    assert "pixel noise per coordinate: wide 0.3 px, tele 0.3 px (points.json)" in res.out


def test_measuring_imports_no_scipy(note8, calib_file, tmp_path):
    """``dualcal measure`` takes its chi-square quantile from :mod:`dualcal.estimation.distributions`:
    scipy, a third of a second to import, is not loaded (a fresh process)."""
    import subprocess
    import sys

    (tmp_path / "points.json").write_text(json.dumps(shot(note8[0], np.array([[-60.0, -40.0, 450.0]]))))
    code = ("import sys\nfrom dualcal.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "print('scipy' in sys.modules)")
    res = subprocess.run([sys.executable, "-c", code, "measure", str(calib_file), "--points", str(tmp_path / "points.json"),
                          "-o", str(tmp_path / "m.json")], capture_output=True, text=True, check=True)
    assert (tmp_path / "m.json").exists() and res.stdout.splitlines()[-1] == "False", res.stdout + res.stderr


def test_measure_command_errors(calib_file, tmp_path, run_cli):
    out = tmp_path / "measure.json"
    (tmp_path / "points.json").write_text(json.dumps({"points": {"A": {"wide": [1, 2]}}}))
    cases = [
        (("--points", tmp_path / "points.json"), "point 'A' is given in 1 camera(s)"),
        ((), "give either --points points.json"),
        (("--points", tmp_path / "points.json", "--pick"), "give either --points points.json"),
        (("wide=a.jpg", "--points", tmp_path / "points.json"), "a.jpg: cannot be read"),
        (("--photo", "wide=a.jpg", "--points", tmp_path / "points.json"), "a.jpg: cannot be read"),
        (("--pick", "wide=a.jpg", "tele=b.jpg", "--record", tmp_path / "r.html"), "give it with --points, not --pick"),
        (("--points", tmp_path / "missing.json"), "missing.json"),
        (("--pick", "wide=a.jpg"), "two or more cameras"),
        (("--pick", "wide.jpg", "tele.jpg"), "give each photo as NAME=IMAGE"),
        (("--pick", "wide=a.jpg", "wide=b.jpg"), "name camera 'wide' twice"),
        (("--points", tmp_path / "points.json", "wide=a.jpg", "--photo", "wide=b.jpg"), "name camera 'wide' twice"),
    ]
    for args, message in cases:
        res = run_cli("measure", calib_file, *args, "-o", out)
        assert res.code == 2 and message in res.err and len(res.err_lines) == 1, (args, res.err)
    assert not out.exists()
    (tmp_path / "small.png").parent.mkdir(exist_ok=True)
    Image.new("RGB", (640, 480)).save(tmp_path / "small.png")
    res = run_cli("measure", calib_file, "--pick", f"wide={tmp_path / 'small.png'}", f"tele={tmp_path / 'small.png'}",
                  "-o", tmp_path / "pick.html")
    assert res.code == 2 and "640x480 px, but camera 'wide' was calibrated at 3024x4032 px" in res.err
    res = run_cli("measure", calib_file, "--pick", f"wide={tmp_path / 'small.png'}", f"left={tmp_path / 'small.png'}",
                  "-o", tmp_path / "pick.html")
    assert res.code == 2 and "camera 'left' is not in the calibration" in res.err


# ---------------------------------------------------------------------------- the pick page, in a browser


def _photo(path, size, seed):
    rng = np.random.default_rng(seed)
    w, h = size
    small = rng.integers(0, 255, (h // 64 + 1, w // 64 + 1, 3), dtype=np.uint8)
    Image.fromarray(small).resize((w, h), Image.Resampling.BILINEAR).save(path, quality=80)
    return path


def test_the_pick_page_exports_the_clicked_full_resolution_pixels(browser, note8, calib_file, tmp_path, run_cli):
    """Clicks in both photos, at fit and zoomed in 4x; the exported points.json has each click's position mapped
    to the full-resolution stored frame (to a tenth of a displayed pixel), the lengths added, pixel_sigma."""
    truth, rig = note8
    photos = {c: _photo(tmp_path / f"{c}.jpg", rig.cameras[c].image_size, i) for i, c in enumerate(("wide", "tele"))}
    res = run_cli("measure", calib_file, "--pick", *(f"{c}={p}" for c, p in photos.items()), "-o", tmp_path / "pick.html")
    assert res.code == 0, res.err
    html = (tmp_path / "pick.html").read_text()
    assert "http" not in html.replace("http-equiv", "") and html.count("data:image/jpeg;base64,") == 2

    page = browser.new_page(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    page.goto((tmp_path / "pick.html").as_uri())
    page.wait_for_function("() => [...document.images].every((i) => i.complete && i.clientWidth > 0)")
    expected = {}

    def click(cam, fx, fy):
        box = page.locator(f"#photo-{cam}").bounding_box()
        view = page.locator(f"#view-{cam}").bounding_box()
        x = round(max(box["x"], view["x"]) + fx * min(box["width"], view["width"]))
        y = round(max(box["y"], view["y"]) + fy * min(box["height"], view["height"]))
        page.mouse.click(x, y)
        w, h = rig.cameras[cam].image_size
        per_shown_px = w / box["width"]
        return [(x - box["x"]) * w / box["width"] - 0.5, (y - box["y"]) * h / box["height"] - 0.5], per_shown_px

    assert page.input_value("#point-name") == "A"
    for name, where in (("A", (0.2, 0.3)), ("B", (0.7, 0.6))):
        for cam in ("wide", "tele"):
            expected[name, cam] = click(cam, *where)
        assert page.input_value("#point-name") == chr(ord(name) + 1)   # a point clicked in both photos: the next name
    for cam in ("wide", "tele"):
        page.locator(f"#view-{cam}").locator("xpath=..").locator(".zoom-in").click()
        page.locator(f"#view-{cam}").locator("xpath=..").locator(".zoom-in").click()
        page.locator(f"#view-{cam}").evaluate("(v) => { v.scrollLeft = 900; v.scrollTop = 700; }")
    page.fill("#point-name", "tip")
    for cam in ("wide", "tele"):
        expected["tip", cam] = click(cam, 0.5, 0.4)
    assert page.locator(".zoom-level").all_inner_texts() == ["400 %", "400 %"]
    for a, b in (("A", "B"), ("A", "tip")):
        page.select_option("#length-from", a)
        page.select_option("#length-to", b)
        page.click("#add-length")
    page.fill("#pixel-sigma", "0.5")
    with page.expect_download() as download:
        page.click("#export")
    assert download.value.suggested_filename == "points.json"
    got = json.loads(open(download.value.path()).read())
    page.close()

    assert got["lengths"] == [["A", "B"], ["A", "tip"]] and got["pixel_sigma"] == 0.5
    assert set(got["points"]) == {"A", "B", "tip"}
    for (name, cam), (uv, per_shown_px) in expected.items():
        assert np.abs(np.subtract(got["points"][name][cam], uv)).max() < 0.1 * per_shown_px, (name, cam)
    fit = expected["A", "wide"][1]
    assert fit > 1.4 and expected["tip", "wide"][1] == pytest.approx(fit / 4, rel=0.01)   # reduced, then zoomed 4x
    (tmp_path / "points.json").write_text(json.dumps(got))
    assert load_points(tmp_path / "points.json")["points"]["tip"]["tele"].shape == (2,)


def _dense_reference(rig, points: dict) -> tuple[dict, dict]:
    """The points' and lengths' sigmas from the full 3P x 3P covariance (the computation measure made before it
    went to fixed-size blocks): ``({point: sigma_mm (3,)}, {(a, b): (sigma_mm, bias_mm)})``."""
    from dualcal.estimation.measurement import COVARIANCE_KINDS, _covariances, _pixel_sigmas, intersect_point

    index, cov_theta = _covariances(rig)
    sigma_px, _ = _pixel_sigmas(rig, points.get("pixel_sigma"))
    found = {n: intersect_point(rig, {c: np.asarray(uv) for c, uv in seen.items()}, index)
             for n, seen in points["points"].items()}
    names = list(found)
    B = np.vstack([found[n].B for n in names])
    pixels = np.zeros((3 * len(names),) * 2)
    for i, n in enumerate(names):
        var = np.repeat([sigma_px[c] ** 2 for c in found[n].cameras], 2)
        pixels[3 * i:3 * i + 3, 3 * i:3 * i + 3] = (found[n].A * var) @ found[n].A.T
    cov = {k: pixels + B @ cov_theta[k] @ B.T for k in COVARIANCE_KINDS}
    point_sigma = {n: np.sqrt(np.max([np.diag(cov[k])[3 * i:3 * i + 3] for k in COVARIANCE_KINDS], axis=0))
                   for i, n in enumerate(names)}
    lengths = {}
    for a, b in points["lengths"]:
        ia, ib = names.index(a), names.index(b)
        d = found[a].xyz_mm - found[b].xyz_mm
        g = np.zeros(3 * len(names))
        g[3 * ia:3 * ia + 3], g[3 * ib:3 * ib + 3] = d / np.linalg.norm(d), -d / np.linalg.norm(d)
        kind = max(COVARIANCE_KINDS, key=lambda k: g @ cov[k] @ g)
        diff = np.zeros((3, 3 * len(names)))
        diff[:, 3 * ia:3 * ia + 3], diff[:, 3 * ib:3 * ib + 3] = np.eye(3), -np.eye(3)
        across = np.eye(3) - np.outer(d, d) / (d @ d)
        lengths[(a, b)] = (np.sqrt(g @ cov[kind] @ g),
                           np.trace(across @ diff @ cov[kind] @ diff.T) / (2 * np.linalg.norm(d)))
    return point_sigma, lengths


def test_the_fixed_size_blocks_give_the_dense_covariances_result(note8):
    """Issue 24, finding 6: measure is linear in the points; on a small case its sigmas are those of the full
    joint covariance of every point."""
    truth, rig = note8
    X = np.array([[-60.0, -40.0, 450.0], [70.0, 30.0, 420.0], [0.0, 50.0, 900.0], [80.0, 60.0, 700.0]])
    points = shot(truth, X, np.random.default_rng(4))
    doc = measure(rig, points)
    point_sigma, lengths = _dense_reference(rig, points)
    for n, s in point_sigma.items():
        np.testing.assert_allclose(doc["points"][n]["sigma_mm"], s, rtol=1e-9)
    for row in doc["lengths"]:
        sigma, bias = lengths[(row["from"], row["to"])]
        assert row["sigma_mm"] == pytest.approx(sigma, rel=1e-9) and row["bias_mm"] == pytest.approx(bias, rel=1e-9)


def test_a_fisheye_measures_with_the_wide():
    """phone3's wide + kb4 ultra-wide (0.05 px corners): lengths across the board of an instant both
    saw come out within 4 sigma, through the fisheye's rays and its Jacobians (k1 .. k4 in the
    covariance)."""
    full = make_truth("phone3", 12, seed=5)
    truth = replace(full, cameras={n: full.cameras[n] for n in ("wide", "ultra")}, rig={"ultra": full.rig["ultra"]})
    corners = noisy_corner_set(truth, 0.05, seed=1)
    rig = calibrate_rig(corners, model={"wide": "k1k2k3", "ultra": "kb4"}, board_shape="flat")
    assert "ultra.k4" in rig.covariance["parameters"]
    view = next(v for v, uv in corners.cameras["wide"].views.items() if uv is not None)
    uv = {c: corners.cameras[c].views[view] for c in ("wide", "ultra")}
    points = {"points": {f"c{k}": {c: uv[c][k].tolist() for c in uv} for k in (0, 7, 32, 39)},
              "lengths": [["c0", "c7"], ["c0", "c32"], ["c0", "c39"]]}
    for L, true_mm in zip(measure(rig, points)["lengths"], [210.0, 120.0, np.hypot(210.0, 120.0)]):
        assert abs(L["length_mm"] - true_mm) < 4 * L["sigma_mm"] and L["sigma_mm"] < 0.05 * true_mm


# ---------------------------------------------------------------------------- one tap, every photo


@pytest.fixture(scope="module")
def box_shots(computed_once):
    """The note8 rig at a quarter of its size calibrated from noisy corners, and photos of textured boxes at
    0.3-0.8 m rendered with the true rig: ``(truth, rig, [(box, {camera: image}), ...])``."""
    from dualcal.synthetic.render_object import TexturedBox, render_object

    def compute():
        truth = make_truth("note8", views=10, seed=2, scale=0.25)
        rig = calibrate_rig(noisy_corner_set(truth, CORNER_NOISE_PX, seed=5), board_shape="flat")
        shots = []
        for k, distance in enumerate((300.0, 450.0, 600.0, 800.0)):
            rng = np.random.default_rng(k)
            pose = Pose(rotation_from_opk(np.radians(rng.uniform(-30, 30, 3))), np.array([0.0, 0.0, distance]))
            box = TexturedBox(pose, (0.4 * distance, 0.3 * distance, 0.2 * distance), seed=k)
            to_cam = {"wide": Pose(np.eye(3), np.zeros(3)), "tele": truth.rig["tele"]}
            shots.append((box, {c: render_object(truth.cameras[c], to_cam[c], box, np.random.default_rng([k, i]))
                                for i, c in enumerate(truth.cameras)}))
        return truth, rig, shots
    return computed_once("measure-box-shots", compute)


def _box_points(truth, box, rng, count):
    """``count`` points on the box's faces that both cameras see, and each one's true pixels."""
    X, uv = [], {c: [] for c in truth.cameras}
    while len(X) < count:
        P = box.pose.apply(rng.uniform(-0.42, 0.42, 3) * np.array(box.size_mm))
        S = box.surface_point(np.zeros(3), P / np.linalg.norm(P))
        seen = {c: project_points(m, (S[None] if c == "wide" else truth.rig[c].apply(S[None])))[0]
                for c, m in truth.cameras.items()}
        if all(40 < u[0] < m.image_size[0] - 40 and 40 < u[1] < m.image_size[1] - 40
               for (c, u), m in zip(seen.items(), truth.cameras.values())):
            X.append(S)
            for c in uv:
                uv[c].append(seen[c])
    return np.array(X), {c: np.array(v) for c, v in uv.items()}


def test_one_tap_measures_lengths_far_better_than_tapping_every_photo(box_shots):
    """12 points on each of four boxes at 0.3-0.8 m, tapped with 2 px errors: once, in the wide (found in the
    tele), or by hand in both photos. The one-tap lengths' RMS error is at most 0.3 of the hand taps' (an 11 mm
    baseline turns 2 px of disparity into centimetres of depth); their z (error over sigma, the taps' own
    uncertainty given as pixel_sigma) has sd 0.7-1.4 over independent lengths (disjoint pairs)."""
    truth, rig, shots = box_shots
    rng = np.random.default_rng(7)
    err_one, err_hand, z = [], [], []
    for box, images in shots:
        X, uv = _box_points(truth, box, rng, 12)
        names = [f"P{i}" for i in range(len(X))]
        lengths = [[a, b] for i, a in enumerate(names) for b in names[i + 1:]]
        one = {n: {"wide": (uv["wide"][i] + rng.normal(0, 2.0, 2)).tolist()} for i, n in enumerate(names)}
        hand = {n: {c: (uv[c][i] + rng.normal(0, 2.0, 2)).tolist() for c in uv} for i, n in enumerate(names)}
        doc_one = quiet_measure_photos(rig, {"points": one, "lengths": lengths, "pixel_sigma": 2.0}, images)
        doc_hand = quiet_measure(rig, {"points": hand, "lengths": lengths, "pixel_sigma": 2.0})
        true = {(a, b): np.linalg.norm(X[int(a[1:])] - X[int(b[1:])]) for a, b in lengths}
        found = {(L["from"], L["to"]): L for L in doc_one["lengths"]}
        for L in doc_hand["lengths"]:
            key = (L["from"], L["to"])
            if key in found:
                err_hand.append(L["length_mm"] - true[key])
                err_one.append(found[key]["length_mm"] - true[key])
        for i in range(0, len(names) - 1, 2):
            L = found.get((names[i], names[i + 1]))
            if L is not None:
                z.append((L["length_mm"] - true[(names[i], names[i + 1])]) / L["sigma_mm"])
    ratio = np.sqrt(np.mean(np.square(err_one)) / np.mean(np.square(err_hand)))
    z = np.array(z)
    summary = (f"{len(err_one)} lengths: one tap {np.sqrt(np.mean(np.square(err_one))):.2f} mm rms, by hand "
               f"{np.sqrt(np.mean(np.square(err_hand))):.2f} mm (ratio {ratio:.3f}); {len(z)} independent z: "
               f"sd {z.std():.2f} mean {z.mean():+.2f}")
    print(summary)
    assert len(err_one) >= 200 and len(z) >= 20, summary
    assert ratio <= 0.3 and 0.7 <= z.std() <= 1.4 and abs(z.mean()) <= 0.5, summary


def quiet_measure_photos(rig, points, images, **kwargs):
    with contextlib.redirect_stderr(io.StringIO()):
        return measure(rig, points, images, **kwargs)


def test_measure_json_says_what_was_matched_and_what_not(box_shots, tmp_path):
    """A tap found in the tele gives ``matched`` (its pixel, sigma, score); a tap whose epipolar line leaves the
    tele is ``unmatched`` with the reason, and the length to it is listed as not measured; the focus is the
    calibration's (it models none). The document follows the schema."""
    truth, rig, shots = box_shots
    box, images = shots[1]
    X, uv = _box_points(truth, box, np.random.default_rng(1), 2)
    points = {"points": {"A": {"wide": uv["wide"][0].tolist()}, "B": {"wide": uv["wide"][1].tolist()},
                         "C": {"wide": [5.0, 5.0]}, "D": {c: v[1].tolist() for c, v in uv.items()}},
              "lengths": [["A", "B"], ["A", "C"], ["A", "D"]], "pixel_sigma": {"wide": 1.5, "tele": 1.0}}
    doc = quiet_measure_photos(rig, points, images)
    assert set(doc["points"]) == {"A", "B", "D"} and "matched" not in doc["points"]["D"]
    m = doc["points"]["A"]["matched"]["tele"]
    assert np.linalg.norm(np.array(m["uv"]) - uv["tele"][0]) < 3.0          # the tap's 0 px, plus the calibration
    assert 0 < m["sigma_px"] < 0.5 and 0.6 <= m["score"] <= 1 and np.linalg.norm(m["direction"]) == pytest.approx(1)
    assert doc["unmatched"] == {"C": {"tele": "off the image"}}
    assert doc["unmeasured_lengths"] == [{"from": "A", "to": "C", "reason": "point C is not measured (unmatched)"}]
    assert [(L["from"], L["to"]) for L in doc["lengths"]] == [("A", "B"), ("A", "D")]
    assert doc["lengths"][0]["length_mm"] == pytest.approx(np.linalg.norm(X[0] - X[1]), abs=3 * doc["lengths"][0]["sigma_mm"])
    for c in ("wide", "tele"):
        assert doc["cameras"][c]["focus_from"] == "calibration" and doc["cameras"][c]["focus_metadata_m"] is None
        assert 0.3 < doc["cameras"][c]["focus_m"] < 3.0
    (tmp_path / "m.json").write_text(json.dumps(doc))
    assert_valid(tmp_path / "m.json", "measure")


def test_a_tap_without_its_photo_or_a_photo_of_another_size_is_refused(box_shots):
    truth, rig, shots = box_shots
    images = shots[0][1]
    with pytest.raises(InputError, match="no photo of 'tele'"):
        measure(rig, {"points": {"A": {"tele": [100.0, 100.0]}}}, {"wide": images["wide"]})
    with pytest.raises(InputError, match="no photo of another camera"):
        measure(rig, {"points": {"A": {"wide": [100.0, 100.0]}}}, {"wide": images["wide"]})
    with pytest.raises(InputError, match="calibrated at 756x1008 px"):
        measure(rig, {"points": {"A": {"wide": [100.0, 100.0]}}}, {"wide": images["wide"][:-2], "tele": images["tele"]})


def test_each_photo_takes_its_camera_at_its_own_focus_where_the_calibration_models_focus(box_shots, monkeypatch):
    """The one place a focus model plugs in: with a (stand-in) model that grows fx as the focus comes near, a photo
    whose metadata states its focus is measured at it, one without at the distance of the points it measured; the
    points move with the camera used."""
    from dualcal.estimation import measurement

    truth, rig, shots = box_shots
    box, images = shots[0]
    X, uv = _box_points(truth, box, np.random.default_rng(2), 2)
    points = {"points": {"A": {"wide": uv["wide"][0].tolist()}, "B": {"wide": uv["wide"][1].tolist()}},
              "lengths": [["A", "B"]], "pixel_sigma": 1.0}
    plain = quiet_measure_photos(rig, points, images)
    used = {}

    def at_focus(rig_, name, focus_m):
        used[name] = focus_m
        cam = rig_.cameras[name]
        return replace(cam, fx=cam.fx * (1 + 0.005 / focus_m), fy=cam.fy * (1 + 0.005 / focus_m))

    monkeypatch.setattr(measurement, "focus_modelled", lambda rig_, name: True)
    monkeypatch.setattr(measurement, "camera_at_focus", at_focus)
    doc = quiet_measure_photos(rig, points, images, focus_metadata_m={"wide": 0.31, "tele": None})
    assert doc["cameras"]["wide"] == {"focus_m": 0.31, "focus_from": "metadata", "focus_metadata_m": 0.31}
    tele = doc["cameras"]["tele"]
    assert tele["focus_from"] == "points" and tele["focus_m"] == used["tele"]
    depth_tele = [truth.rig["tele"].apply(np.array(p["xyz_mm"])[None])[0, 2] / 1000 for p in doc["points"].values()]
    assert tele["focus_m"] == pytest.approx(np.median(depth_tele), rel=0.02)
    assert used["wide"] == 0.31
    assert doc["points"]["A"]["xyz_mm"] != pytest.approx(plain["points"]["A"]["xyz_mm"], abs=0.05)


def test_measure_command_with_photos_writes_the_record(box_shots, tmp_path, run_cli, monkeypatch):
    """``measure --photo wide=... --photo tele=... --record`` (and the positional NAME=IMAGE form): measure.json with
    the matches and the record page, self-contained (crops as data URIs) and small, naming every point and length."""
    from PIL import Image as PILImage

    monkeypatch.setenv("COLUMNS", "200")
    truth, rig, shots = box_shots
    box, images = shots[2]
    save_rig(tmp_path / "calib.json", rig)
    for c, image in images.items():
        PILImage.fromarray(image).save(tmp_path / f"{c}.jpg", quality=92)
    X, uv = _box_points(truth, box, np.random.default_rng(4), 3)
    points = {"points": {f"P{i}": {"wide": uv["wide"][i].tolist()} for i in range(3)} | {"Q": {"wide": [3.0, 3.0]}},
              "lengths": [["P0", "P1"], ["P1", "P2"], ["P0", "Q"]], "pixel_sigma": 1.0}
    (tmp_path / "points.json").write_text(json.dumps(points))
    res = run_cli("measure", tmp_path / "calib.json", "--points", tmp_path / "points.json", "--photo",
                  f"wide={tmp_path / 'wide.jpg'}", "--photo", f"tele={tmp_path / 'tele.jpg'}", "--record",
                  tmp_path / "record.html", "-o", tmp_path / "measure.json")
    assert res.code == 0, res.err
    doc = assert_valid(tmp_path / "measure.json")
    assert set(doc["points"]) == {"P0", "P1", "P2"} and doc["unmatched"] == {"Q": {"tele": "off the image"}}
    assert "Taps found in the other photos" in res.out and "off the image" in res.out
    assert "focus: wide" in res.out and "(calibration)" in res.out
    html = (tmp_path / "record.html").read_text()
    assert html.count("data:image/jpeg;base64,") == 3 * 2 + 1 and len(html) < 400_000
    for name in ("P0", "P1", "P2", "Q", "P0&ndash;P1", "not found: off the image", "wide.jpg", "tele.jpg"):
        assert name in html
    assert f"{doc['lengths'][0]['length_mm']:.2f}" in html
    embedded = json.loads(html.split('id="measure-json">')[1].split("</script>")[0])
    assert embedded["lengths"] == doc["lengths"]
    res = run_cli("measure", tmp_path / "calib.json", f"wide={tmp_path / 'wide.jpg'}", f"tele={tmp_path / 'tele.jpg'}",
                  "--points", tmp_path / "points.json", "-o", tmp_path / "again.json")
    assert res.code == 0 and json.loads((tmp_path / "again.json").read_text())["lengths"] == doc["lengths"]
