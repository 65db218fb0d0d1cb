"""The app's measuring page (dualcal.app.measure_photos, static/measure.js): photos of an object, one tap per point.

Through the API (Starlette's test client): the photos' upload and refusals, the match with its epipolar line,
the measurement and the record. In a browser (Playwright driving Debian's Chromium, a phone's viewport with
touch and a desktop's): a project calibrated by the commands, the photos of a textured box added through the
page, two points tapped in the wide photo and found in the tele (the epipolar line drawn), the magnifier, the
lengths read off the page against the truth, the record downloaded. Screenshots go to
``out/app-screens/measure-<device>/`` (printed), to be looked at.
"""

from __future__ import annotations

import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("uvicorn", reason="the app extra")
from starlette.testclient import TestClient  # noqa: E402

from test_app_browser import TOKEN, chromium, server, sync_api  # noqa: E402,F401  (its fixtures: the app, Chromium)
from dualcal.app.server import AppConfig, create_app  # noqa: E402
from dualcal.estimation.calibrate import calibrate_rig  # noqa: E402
from dualcal.files.io import save_rig  # noqa: E402
from dualcal.geometry.camera import project_points  # noqa: E402
from dualcal.geometry.model import Pose  # noqa: E402
from dualcal.geometry.rotation import rotation_from_opk  # noqa: E402
from dualcal.synthetic.render_object import TexturedBox, render_object  # noqa: E402
from dualcal.synthetic.synth import make_truth, noisy_corner_set  # noqa: E402

BASE = "http://127.0.0.1:8000"
AUTH = {"authorization": f"Bearer {TOKEN}"}
SCREENS = Path(__file__).resolve().parents[1] / "out" / "app-screens"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A project folder with the note8 rig's calibration (a quarter of its size), photos of a textured box 0.45 m
    away as JPEG files, and two points on its front face with their true pixels."""
    root = tmp_path_factory.mktemp("measure-app")
    truth = make_truth("note8", views=10, seed=2, scale=0.25)
    project = root / "workspace" / "box"
    project.mkdir(parents=True)
    save_rig(project / "calib.json", calibrate_rig(noisy_corner_set(truth, 0.3, seed=5), board_shape="flat"))
    box = TexturedBox(Pose(rotation_from_opk(np.radians([15.0, -20.0, 5.0])), np.array([0.0, 0.0, 450.0])),
                      (180.0, 130.0, 90.0), seed=4)
    to_camera = {"wide": Pose(np.eye(3), np.zeros(3)), "tele": truth.rig["tele"]}
    files = {}
    for i, camera in enumerate(truth.cameras):
        files[camera] = root / f"{camera}.jpg"
        Image.fromarray(render_object(truth.cameras[camera], to_camera[camera], box, np.random.default_rng(i))).save(
            files[camera], quality=92)
    X = box.pose.apply(np.array([[-50.0, -35.0, -45.0], [55.0, 30.0, -45.0]]))     # on the face towards the rig
    uv = {c: project_points(truth.cameras[c], to_camera[c].apply(X)) for c in truth.cameras}
    return root / "workspace", files, X, uv


@pytest.fixture(scope="module")
def client(scene):
    app = create_app(AppConfig(workspace=scene[0], token=TOKEN, host="127.0.0.1", url=f"{BASE}/?token={TOKEN}",
                               max_photo_bytes=3_000_000, workers=1))
    with TestClient(app, base_url=BASE) as c:
        yield c


def test_the_api_takes_the_photos_finds_a_tap_and_measures(client, scene):
    _, files, X, uv = scene
    base = "/api/projects/box/measure"
    state = client.get(base + "/state", headers=AUTH).json()
    assert state["reference"] == "wide" and not any(c["photo"] for c in state["cameras"].values())
    assert client.put(base + "/photos/wide", content=b"not a photo", headers=AUTH).status_code == 400
    small = io.BytesIO()
    Image.new("L", (64, 48)).save(small, "JPEG")
    r = client.put(base + "/photos/wide", content=small.getvalue(), headers=AUTH)
    assert r.status_code == 400 and "calibrated at 756x1008 px" in r.json()["error"]
    assert client.put(base + "/photos/ultra", content=files["wide"].read_bytes(), headers=AUTH).status_code == 400
    for camera, path in files.items():
        r = client.put(base + f"/photos/{camera}", content=path.read_bytes(), headers=AUTH)
        assert r.status_code == 200, r.text
    state = r.json()
    assert state["cameras"]["tele"]["photo"] and state["cameras"]["tele"]["file"] == "tele.jpg"
    assert sorted(p.name for p in (scene[0] / "box" / "measure").iterdir()) == ["tele.jpg", "wide.jpg"]
    assert not (scene[0] / "box" / "photos").exists()                    # never among the calibration's photos
    screen = client.get(base + "/photos/tele", headers=AUTH)
    assert screen.headers["content-type"] == "image/jpeg"
    crop = Image.open(io.BytesIO(client.get(base + "/crop/wide?u=300&v=400&r=40", headers=AUTH).content))
    assert crop.size == (81, 81)
    found = client.post(base + "/match", json={"camera": "wide", "uv": uv["wide"][0].tolist()}, headers=AUTH).json()
    m = found["matched"]["tele"]
    assert np.linalg.norm(np.array(m["uv"]) - uv["tele"][0]) < 3.0 and m["sigma_px"] < 0.5
    line = np.array([p for p in found["epipolar"]["tele"] if p is not None])
    gap = np.min(np.linalg.norm(line - uv["tele"][0], axis=1))
    assert len(line) > 20 and gap < 3.0                                    # the line passes by the true point
    points = {"points": {"A": {"wide": uv["wide"][0].tolist()}, "B": {"wide": uv["wide"][1].tolist()}},
              "lengths": [["A", "B"]], "pixel_sigma": 1.0}
    doc = client.post(base + "/points", json=points, headers=AUTH).json()
    (L,) = doc["lengths"]
    assert abs(L["length_mm"] - np.linalg.norm(X[0] - X[1])) < 3 * L["sigma_mm"] + 0.5
    record = client.post(base + "/record", json=points, headers=AUTH)
    assert record.status_code == 200 and "attachment" in record.headers["content-disposition"]
    assert "A&ndash;B" in record.text and record.text.count("data:image/jpeg") == 4


def test_the_page_in_a_phone_and_on_a_desktop(server, chromium, scene):
    """The app as a process and Chromium as the app's own browser test starts them (its fixtures)."""
    url, workspace = server
    devices, browser = chromium
    shutil.copytree(scene[0] / "box", workspace / "box", ignore=shutil.ignore_patterns("measure"))
    for device in ("iPhone 13", "desktop"):
        _page_flow(devices, browser, url, device, *scene[1:])


def _page_flow(devices, browser, url, device, files, X, uv):
    screens = SCREENS / f"measure-{device.split()[0].lower()}"
    screens.mkdir(parents=True, exist_ok=True)
    print(f"screenshots: {screens}")
    options = dict(devices[device]) if device != "desktop" else {"viewport": {"width": 1280, "height": 900}}
    context = browser.new_context(**options, accept_downloads=True)
    page = context.new_page()
    touch = bool(options.get("has_touch"))

    def shot(n, name):
        page.screenshot(path=screens / f"{n:02d}-{name}.png", full_page=True, scale="css")

    page.goto(url)
    page.goto(url.split("?")[0].rstrip("/") + "/projects/box/measure")
    status = page.get_by_role("status")
    sync_api.expect(status).to_contain_text(re.compile("Add the photo|Tap a point"), timeout=30_000)
    for camera, path in files.items():
        page.locator(f"#m-file-{camera}").set_input_files(path)
        sync_api.expect(page.locator(f'.m-photo[data-camera="{camera}"] img')).to_be_visible(timeout=30_000)
    sync_api.expect(status).to_contain_text("Tap a point", timeout=30_000)
    shot(1, "photos")
    for k, name in enumerate("AB"):
        if k:
            (page.get_by_role("button", name="New point").tap if touch else
             page.get_by_role("button", name="New point").click)()
        img = page.locator('.m-photo[data-camera="wide"] img')
        img.scroll_into_view_if_needed()
        box = img.bounding_box()
        u, v = uv["wide"][k]
        x, y = box["x"] + (u + 0.5) / 756 * box["width"], box["y"] + (v + 0.5) / 1008 * box["height"]
        (page.touchscreen.tap if touch else page.mouse.click)(x, y)
        sync_api.expect(status).to_contain_text(f"{name}: found in tele", timeout=60_000)
        assert page.locator('.m-photo[data-camera="tele"] polyline.epipolar').count() >= 1
        assert page.locator(f'.m-photo[data-camera="tele"] g.m-mark.match[data-point="{name}"]').count() == 1
        sync_api.expect(page.locator("#m-loupe")).to_be_visible()
        shot(2 + k, f"point-{name}")
    page.locator("#m-loupe").screenshot(path=screens / "04-magnifier.png", scale="css")
    (page.get_by_role("button", name="Measure the lengths").tap if touch else
     page.get_by_role("button", name="Measure the lengths").click)()
    result = page.locator("#m-result li").first
    sync_api.expect(result).to_contain_text("mm", timeout=60_000)
    length, sigma = (float(x) for x in re.match(r"A.B: ([\d.]+) ± ([\d.]+) mm", result.inner_text()).groups())
    true = float(np.linalg.norm(X[0] - X[1]))
    assert abs(length - true) < 3 * sigma + 1.0, (length, sigma, true)
    shot(5, "lengths")
    with page.expect_download() as download:
        (page.get_by_role("button", name="Download the record").tap if touch else
         page.get_by_role("button", name="Download the record").click)()
    html = Path(download.value.path()).read_text()
    assert "Measurement record" in html and "A&ndash;B" in html
    context.close()
