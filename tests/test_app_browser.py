"""``dualcal app`` in a browser: the whole flow on a phone's screen (Playwright's iPhone and Pixel descriptors,
touch) and on a desktop, driving Debian's Chromium (no browser download).

A synthetic camera roll is uploaded through the page's "Add photos", the verdict is read from the element with
role ``status``, a photo is left out by tapping it (its checkbox, or its bar in the error chart), the result
updates, the advice's board outlines are drawn, a length is measured by tapping two board corners in one
instant's photos, and a download is the file on disk. Each step's screenshot is saved under
``out/app-screens/<device>/`` (printed), to be looked at.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("uvicorn", reason="the app extra")
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (test extra) drives Chromium")
from conftest import CHROMIUM  # noqa: E402

TOKEN = "browser-token-0123456789"
SCREENS = Path(__file__).resolve().parents[1] / "out" / "app-screens"
DEVICES = {"iphone": "iPhone 13", "pixel": "Pixel 7", "desktop": None}


@pytest.fixture(scope="module")
def roll(tmp_path_factory) -> Path:
    """A three-lens phone's roll (``phone3``: a fisheye ultra-wide, a wide, a tele; 7 positions at a quarter of
    12 MP, two near the fisheye's edge, where the others miss the board or see part of it), named as an Android
    phone names its photos (``IMG_20261130_100001.jpg``, ...: the same 17 characters first in every name)."""
    from dualcal.synthetic.synth import make_truth
    from dualcal.synthetic.synth_roll import write_camera_roll

    shot = tmp_path_factory.mktemp("shot")
    write_camera_roll(make_truth("phone3", views=7, seed=7, scale=0.25), shot, seed=7, jobs=2)
    folder = tmp_path_factory.mktemp("roll")
    for n, photo in enumerate(sorted(shot.glob("*.JPG"))):
        (folder / f"IMG_20261130_1000{n:02d}.jpg").write_bytes(photo.read_bytes())
    return folder


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    workspace = tmp_path_factory.mktemp("workspace")
    env = {**os.environ, "DUALCAL_APP_TOKEN": TOKEN, "OPENBLAS_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "dualcal", "app", str(workspace), "--port", "0", "--no-browser"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True)
    line = process.stdout.readline()
    assert line.startswith("dualcal app: "), line
    yield line.split(": ", 1)[1].strip(), workspace
    process.send_signal(signal.SIGINT)
    try:
        process.wait(20)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
    process.stdout.close()


@pytest.fixture(scope="module")
def chromium():
    if CHROMIUM is None:
        pytest.skip("no Chromium here (Debian: apt-get install chromium); the app's API tests still ran")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
            "--disable-component-update", "--disable-sync"])
        yield pw.devices, browser
        browser.close()


def _status(page) -> str:
    return page.get_by_role("status").inner_text()


def test_the_whole_flow_on_an_iphone_a_pixel_and_a_desktop(server, chromium, roll):
    """One test for the three screens (one server and one browser, however the tests are spread over workers)."""
    for device in DEVICES:
        whole_flow(device, server, chromium, roll)


def whole_flow(device, server, chromium, roll):
    url, workspace = server
    devices, browser = chromium
    screens = SCREENS / device
    screens.mkdir(parents=True, exist_ok=True)
    print(f"screenshots: {screens}")
    options = dict(devices[DEVICES[device]]) if DEVICES[device] else {"viewport": {"width": 1280, "height": 900}}
    context = browser.new_context(**options, accept_downloads=True)
    page = context.new_page()
    touch = bool(options.get("has_touch"))
    shot = lambda n, name: page.screenshot(path=screens / f"{n:02d}-{name}.png", full_page=True,  # noqa: E731
                                           scale="css")

    def tap(locator):
        (locator.tap if touch else locator.click)()

    page.goto(url)                                          # the token becomes a cookie, the URL loses it
    assert "token" not in page.url
    shot(1, "projects")
    page.get_by_label("Name").fill(f"{device} tripod session")
    page.get_by_label(re.compile("^Inner corners")).fill("8x5")
    page.get_by_label(re.compile("^Square size")).fill("30")
    tap(page.get_by_role("button", name="Create the project"))
    page.wait_for_url(re.compile(r"/projects/"))
    pid = page.url.rsplit("/", 1)[1]
    folder = workspace / pid
    shot(2, "new-project")

    page.get_by_label("Add photos").set_input_files(sorted(roll.iterdir()))
    page.get_by_text(re.compile(r"^Added \d+ photos")).wait_for(timeout=60_000)
    shot(3, "uploaded")
    status = page.get_by_role("status")
    sync_api.expect(status).to_have_text(re.compile(r"^(Good: all|Use with care: )"), timeout=120_000)
    verdict = _status(page)
    shot(4, "verdict")
    first_text = (folder / "calib.json").read_text()
    first = json.loads(first_text)

    # leave a photo out: its checkbox (phones: a tap), or its bar in the chart
    photos = page.get_by_role("checkbox")
    assert photos.count() == len(list(roll.glob("*.jpg")))
    # clear on a phone's screen: the photos left out summed up in one line, their reasons folded; the chart's
    # labels tell the photos apart; no text runs out of its box, nor the page out of the screen
    left_out = page.locator("#problem details.left-out-photos")
    sync_api.expect(left_out.locator("summary")).to_have_text(re.compile(r"^\d+ photos? left out: \d+ "))
    assert left_out.get_attribute("open") is None and page.locator("#problem p.warning").count() <= 5
    labels = page.locator("#chart .bar-name").all_inner_texts()
    assert len(set(labels)) == len(labels) and all(len(t) <= 24 for t in labels), labels
    overflowing = page.evaluate("""() => [document.scrollingElement, ...document.querySelectorAll(
        '#live section, #live li, #live p, #live figcaption, #live caption')]
        .filter((e) => e.scrollWidth > e.clientWidth + 1 && getComputedStyle(e).overflowX === 'visible')
        .map((e) => e.id || e.className || e.tagName)""")
    assert not overflowing, overflowing
    state = json.loads((folder / ".dualcal-app" / "summary.json").read_text())
    left = next(n for n, p in sorted(state["photos"].items()) if p["camera"] == "tele" and p["status"] == "kept")
    if device == "pixel":
        tap(page.get_by_role("button", name=re.compile(rf"^Leave out {re.escape(left)} ")))
    else:
        tap(page.get_by_role("checkbox", name=left))
    sync_api.expect(page.get_by_role("checkbox", name=left)).not_to_be_checked(timeout=30_000)
    sync_api.expect(status).to_have_text(re.compile(r"^(Good: all|Use with care: )"), timeout=120_000)
    # the verdict on screen may still be the first one while the new calibration waits to start: wait for
    # calib.json to change (or two minutes), then for the page to show no work
    deadline = time.monotonic() + 120
    while (folder / "calib.json").read_text() == first_text and time.monotonic() < deadline:
        time.sleep(0.2)
    page.wait_for_function("() => !document.getElementById('work').textContent.includes('calibrating')")
    shot(5, "left-out")
    second = json.loads((folder / "calib.json").read_text())
    assert second["views"].keys() != first["views"].keys() or second["cameras"] != first["cameras"]
    assert left in json.dumps(second["corners"]["cameras"]["tele"].get("excluded", {}))
    assert _status(page) and verdict

    # the advice: the board's outline in each camera's frame
    advice = page.locator("#advice")
    advice.scroll_into_view_if_needed()
    sync_api.expect(advice.locator("polygon.board-outline").first).to_be_visible()
    assert advice.locator("svg").count() >= 2
    advice.screenshot(path=screens / "06-advice.png", scale="css")

    # measure: board corners 0 and 7 (210 mm apart) tapped in each photo of one instant
    measure = page.locator("#measure")
    sync_api.expect(measure).to_be_visible(timeout=30_000)
    instant = page.get_by_label("Instant").input_value()
    corners = json.loads((folder / "corners.json").read_text())
    images = measure.locator("#measure-photos img")
    sync_api.expect(images.first).to_be_visible()
    for k in (0, 7):
        for i in range(images.count()):
            img = images.nth(i)
            img.scroll_into_view_if_needed()
            camera = img.get_attribute("data-camera")
            u, v = corners["cameras"][camera]["views"][instant][k]
            w, h = corners["cameras"][camera]["image_size"]
            box = img.bounding_box()
            x, y = box["x"] + (u + 0.5) / w * box["width"], box["y"] + (v + 0.5) / h * box["height"]
            (page.touchscreen.tap if touch else page.mouse.click)(x, y)
        if k == 0:
            tap(page.get_by_role("button", name="Next point"))
    tap(page.get_by_role("button", name="Measure the lengths"))
    result = page.locator("#measure-result li").first
    sync_api.expect(result).to_contain_text("mm", timeout=30_000)
    text = result.inner_text()
    length, sigma = (float(x) for x in re.match(r"A.B: ([\d.]+) ± ([\d.]+) mm", text).groups())
    assert abs(length - 210.0) < max(4 * sigma, 0.5), text
    measure.screenshot(path=screens / "07-measure.png", scale="css")

    # a download is the file on disk
    link = page.locator("#downloads").get_by_role("link", name="calib.json", exact=True)
    link.scroll_into_view_if_needed()
    with page.expect_download() as download:
        tap(link)
    assert Path(download.value.path()).read_bytes() == (folder / "calib.json").read_bytes()
    shot(8, "downloads")
    context.close()
