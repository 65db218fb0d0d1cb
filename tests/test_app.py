"""``dualcal app``: the API (Starlette's TestClient), its security rules, uploads, and that what it computes is
what the commands compute for the same photos (CONTRACT.md, "app").

One module-scoped app serves every test here; its calibrations run in its worker processes as in use.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("starlette", reason="the app extra (starlette, uvicorn, python-multipart, segno)")
pytest.importorskip("httpx", reason="Starlette's test client needs httpx")

import warnings  # noqa: E402

with warnings.catch_warnings():        # Starlette 1.x would rather have httpx2; httpx is what the test extra installs
    warnings.simplefilter("ignore", DeprecationWarning)
    from starlette.testclient import TestClient  # noqa: E402

from dualcal.app.security import HostRule, same_origin  # noqa: E402
from dualcal.app.server import AppConfig, create_app  # noqa: E402
from dualcal.app.store import exclude_pattern  # noqa: E402
from dualcal.app.uploads import photo_kind, safe_photo_name  # noqa: E402

TOKEN = "test-token-0123456789"
BASE = "http://127.0.0.1:8765"
AUTH = {"authorization": f"Bearer {TOKEN}"}
BOARD = {"board": "8x5", "square_mm": 30}


@pytest.fixture(scope="module")
def roll(tmp_path_factory) -> Path:
    """A synthetic camera roll of a wide + tele phone (5 positions, quarter resolution), as a phone's camera
    app leaves it: EXIF, a retake, a photo without the board, sidecar files."""
    from dualcal.synthetic.synth import make_truth
    from dualcal.synthetic.synth_roll import write_camera_roll

    folder = tmp_path_factory.mktemp("roll")
    write_camera_roll(make_truth("note8", views=5, seed=3, scale=0.25), folder, seed=3, jobs=2)
    return folder


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("workspace")


@pytest.fixture(scope="module")
def client(workspace):
    app = create_app(AppConfig(workspace=workspace, token=TOKEN, host="127.0.0.1", url=f"{BASE}/?token={TOKEN}",
                               max_photo_bytes=2_000_000, workers=2))
    with TestClient(app, base_url=BASE) as c:
        yield c


def new_project(client, **settings) -> str:
    r = client.post("/api/projects", json={"name": "phone", **(settings or BOARD)}, headers=AUTH)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def files_of(folder: Path, names=None):
    return [("photos", (p.name, p.read_bytes(), "application/octet-stream"))
            for p in sorted(folder.iterdir()) if names is None or p.name in names]


def wait_idle(client, pid: str, version: int | None = None, timeout: float = 120) -> dict:
    """The project's state once it is idle (at ``version`` or later, when given)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        doc = client.get(f"/api/projects/{pid}", headers=AUTH).json()
        if doc["state"] == "idle" and (version is None or doc["version"] >= version):
            return doc
        time.sleep(0.2)
    raise AssertionError(f"still busy after {timeout} s: {doc}")


def cli_calibration(photos_parent: Path, out: Path, *flags, source: str = "photos") -> dict:
    """``cd PROJECT && dualcal calibrate photos ... -o OUT`` (or another ``source``: a corners.json) in a process of
    its own (as a user runs it)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    subprocess.run([sys.executable, "-m", "dualcal", "calibrate", source, "--board", "8x5", "--square", "30",
                    "-o", str(out), *flags], cwd=photos_parent, env=env, check=True, capture_output=True)
    return json.loads(out.read_text())


def assert_same_calibration(a: dict, b: dict, rel: float = 1e-9) -> int:
    """Every parameter and sigma of every camera and of the rig agree to ``rel``; returns how many were compared."""
    compared = 0
    assert a["cameras"].keys() == b["cameras"].keys() and a["rig"].keys() == b["rig"].keys()
    for group in ("cameras", "rig"):
        for name, entry in a[group].items():
            other = b[group][name]
            pairs = [(k, entry[k], other[k]) for k in entry if isinstance(entry[k], (int, float, list))
                     and not isinstance(entry[k], bool)]
            pairs += [(f"sigma.{k}", v, other["sigma"][k]) for k, v in entry["sigma"].items()]
            for key, x, y in pairs:
                x, y = (x if isinstance(x, list) else [x]), (y if isinstance(y, list) else [y])
                for p, q in zip(_flat(x), _flat(y)):
                    assert abs(p - q) <= rel * max(abs(p), abs(q), 1e-300), (group, name, key, p, q)
                    compared += 1
    assert a["views"].keys() == b["views"].keys()
    return compared


def assert_within_sigma(a: dict, b: dict, share: float = 1e-3) -> None:
    """Every camera's parameter and the rig's baseline agree within ``share`` of their sigma (two calibrations of
    corners that differ by the corners.json's rounding to 1e-5 px)."""
    assert a["cameras"].keys() == b["cameras"].keys() and a["views"].keys() == b["views"].keys()
    for name, cam in a["cameras"].items():
        for key, sigma in cam["sigma"].items():
            assert abs(cam[key] - b["cameras"][name][key]) <= share * sigma, (name, key, cam[key], b["cameras"][name][key])
    for name, rel in a["rig"].items():
        assert abs(rel["baseline_mm"] - b["rig"][name]["baseline_mm"]) <= share * rel["sigma"]["baseline_mm"], name


def _flat(x):
    for v in x:
        yield from (_flat(v) if isinstance(v, list) else [v])


# ---------------------------------------------------------------------------- security


def test_every_api_call_needs_the_token(client):
    assert client.get("/api/projects").status_code == 401
    assert client.get("/api/projects", headers={"authorization": "Bearer wrong"}).status_code == 401
    assert client.get("/api/projects", headers=AUTH).status_code == 200
    assert client.get("/").status_code == 401                         # pages too
    assert client.get("/static/app.css").status_code == 200           # assets hold no data


def test_the_token_in_the_url_becomes_a_cookie_and_leaves_the_url(client):
    r = client.get(f"/projects/x?token={TOKEN}&a=1", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/projects/x?a=1"
    assert "HttpOnly" in r.headers["set-cookie"] and "SameSite=Strict" in r.headers["set-cookie"]
    assert client.get("/?token=nope", follow_redirects=False).status_code == 401
    assert not client.get("//evil.example/?token=" + TOKEN, follow_redirects=False).headers["location"].startswith("//")
    fresh = TestClient(client.app, base_url=BASE)
    fresh.get(f"/?token={TOKEN}")
    assert fresh.get("/api/projects").status_code == 200                   # the cookie alone reads


def test_a_foreign_host_is_refused(client):
    for host in ("evil.example", "evil.example:8765", "10.1.2.3", "localhost.evil.example"):
        assert client.get("/api/projects", headers={**AUTH, "host": host}).status_code == 400, host
    for host in ("127.0.0.1:8765", "localhost:8765", "[::1]:8765", "LOCALHOST"):
        assert client.get("/api/projects", headers={**AUTH, "host": host}).status_code == 200, host
    wild = HostRule("0.0.0.0")
    assert wild.allows("192.168.1.20:8765") and wild.allows("localhost") and not wild.allows("attacker.example")


def test_a_change_by_cookie_must_come_from_the_apps_own_origin(client):
    c = TestClient(client.app, base_url=BASE)
    c.get(f"/?token={TOKEN}")
    body = {"name": "x", **BOARD}
    assert c.post("/api/projects", json=body).status_code == 403                                   # no Origin
    assert c.post("/api/projects", json=body, headers={"origin": "http://127.0.0.1:9999"}).status_code == 403
    assert c.post("/api/projects", json=body, headers={"origin": "http://evil.example"}).status_code == 403
    assert c.post("/api/projects", json=body, headers={"origin": BASE}).status_code == 201
    assert c.post("/api/projects", json=body, headers={"referer": BASE + "/"}).status_code == 201
    assert client.post("/api/projects", json=body, headers={**AUTH, "origin": "http://evil.example"}).status_code == 201
    assert same_origin("http://127.0.0.1:80", "http", "127.0.0.1") and not same_origin("https://a", "http", "a")


# ---------------------------------------------------------------------------- names and contents


def test_upload_names_are_data_never_paths():
    jpeg = "jpeg"
    assert safe_photo_name("IMG_0101.JPG", jpeg) == ("IMG_0101.JPG", "")
    assert safe_photo_name("wide/IMG_01.jpg", jpeg) == ("wide/IMG_01.jpg", "")
    assert safe_photo_name("IMG_0101.HEIC", jpeg) == ("IMG_0101.jpg", "")            # iOS: HEIC sent as JPEG
    assert safe_photo_name("photo", "png") == ("photo.png", "")
    for bad in ("../../x.jpg", "../x.jpg", "/etc/x.jpg", "a/b/c.jpg", "con.jpg", "NUL.jpeg", "lpt1.jpg", "x\x00.jpg",
                "x\n.jpg", "a\u202e.jpg", ".hidden.jpg", "x.jpg.", "w*.jpg", "x[1].jpg", "c:x.jpg", "..\\..\\x.jpg",
                "we ird/x.jpg", "", "a" * 200 + ".jpg"):
        name, reason = safe_photo_name(bad, jpeg)
        assert name is None and reason, bad
    assert safe_photo_name("x.jpg", None)[0] is None
    assert photo_kind(b"\xff\xd8\xff\xe0") == "jpeg" and photo_kind(b"\x89PNG\r\n\x1a\n") == "png"
    assert photo_kind(b"II*\x00") == "tiff" and photo_kind(b"\x00\x00\x00\x18ftypheic") == "heic"
    assert photo_kind(b"<html>") is None and photo_kind(b"") is None
    assert exclude_pattern("IMG_[1].JPG") == "IMG_[[]1].JPG" and exclude_pattern("tele/IMG_07.jpg") == "tele/IMG_07"


def _jpeg(seed: int) -> bytes:
    import cv2
    import numpy as np
    return cv2.imencode(".jpg", np.random.default_rng(seed).integers(0, 255, (48, 64), np.uint8))[1].tobytes()


def test_uploads_are_limited_told_by_content_and_land_inside(client, workspace):
    pid = new_project(client)
    photo = _jpeg(0)
    sent = [("photos", ("../../escape.jpg", photo, "image/jpeg")), ("photos", ("con.jpg", photo, "image/jpeg")),
            ("photos", ("page.jpg", b"<html><script>alert(1)</script></html>", "image/jpeg")),
            ("photos", ("big.jpg", b"\xff\xd8\xff" + b"\0" * 2_100_000, "image/jpeg")),
            ("photos", ("IMG_0101.JPG", photo, "image/jpeg")), ("photos", ("IMG_0101.JPG", photo, "image/jpeg")),
            ("other", ("ignored.jpg", photo, "image/jpeg"))]
    r = client.post(f"/api/projects/{pid}/photos", files=sent, headers=AUTH)
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["added"] == ["IMG_0101.JPG"]
    reasons = {s["name"]: s["reason"] for s in doc["skipped"]}
    assert set(reasons) == {"../../escape.jpg", "con.jpg", "page.jpg", "big.jpg", "IMG_0101.JPG"}
    assert "limit" in reasons["big.jpg"] and "not a photo" in reasons["page.jpg"] and "same file" in reasons["IMG_0101.JPG"]
    assert not (workspace.parent / "escape.jpg").exists() and not list(workspace.rglob("escape.jpg"))
    folder = workspace / pid
    assert sorted(p.name for p in (folder / "photos").iterdir()) == ["IMG_0101.JPG"]      # no temporary file left
    assert (folder / "photos" / "IMG_0101.JPG").read_bytes() == photo                      # byte for byte
    # another photo under the same name is kept under a new one; a camera folder is refused in a roll
    other = _jpeg(1)
    doc = client.post(f"/api/projects/{pid}/photos", files=[("photos", ("IMG_0101.JPG", other, "image/jpeg")),
                                                            ("photos", ("tele/IMG_9.jpg", other, "image/jpeg"))],
                      headers=AUTH).json()
    assert doc["added"] == ["IMG_0101-2.JPG"] and doc["skipped"][0]["name"] == "tele/IMG_9.jpg"
    assert client.post(f"/api/projects/{pid}/photos", content=b"x", headers={**AUTH, "content-type": "text/plain"}
                       ).status_code == 400


def test_a_projects_name_is_data(client, workspace):
    r = client.post("/api/projects", json={"name": "../../etc/<b>x</b>", **BOARD}, headers=AUTH)
    pid = r.json()["id"]
    assert "/" not in pid and ".." not in pid and (workspace / pid).is_dir()
    assert {"id": pid, "name": "../../etc/<b>x</b>"} in client.get("/api/projects", headers=AUTH).json()["projects"]
    page = client.get(f"/projects/{pid}", cookies={"dualcal_token": TOKEN}).text
    assert "&lt;b&gt;x&lt;/b&gt;" in page and "<b>x</b>" not in page
    for bad in ("%2e%2e", ".dualcal-app", "no-such-project", "a%2Fb"):
        assert client.get(f"/api/projects/{bad}", headers=AUTH).status_code == 404
    for body, needle in (({"name": "x", "board": "8x5"}, "square_mm"), ({"name": "x", "board": "nonsense", "square_mm": 30}, "board"),
                         ({"board": "8x5", "square_mm": 30}, "name"), ({"name": "x", "board": "8x5", "square_mm": "NaN"}, "finite")):
        r = client.post("/api/projects", json=body, headers=AUTH)
        assert r.status_code == 400 and needle in r.json()["error"], (body, r.text)
    r = client.post("/api/projects", json={"name": "x", "printed": "--board charuco:11x8 --square 25 --marker 18 "
                                                                   "--dictionary DICT_5X5_50"}, headers=AUTH)
    assert r.status_code == 201
    assert client.get(f"/api/projects/{r.json()['id']}", headers=AUTH).json()["flags"] == [
        "--board", "charuco:11x8", "--square", "25", "--marker", "18", "--dictionary", "DICT_5X5_50"]


# ---------------------------------------------------------------------------- what it computes


def test_a_camera_roll_through_the_api(client, workspace, roll, tmp_path):
    """The heavy part in one test (one set of calibrations, however the tests are spread over workers)."""
    a_camera_roll_calibrates_as_the_command_does(client, workspace, roll, tmp_path)
    a_folder_the_commands_made_opens_in_the_app(client, workspace, roll)
    two_clients_uploading_at_once_lose_nothing(client, workspace, roll)


def a_camera_roll_calibrates_as_the_command_does(client, workspace, roll, tmp_path):
    pid = new_project(client)
    r = client.post(f"/api/projects/{pid}/photos", files=files_of(roll), headers=AUTH)
    assert r.status_code == 200
    sent = r.json()
    assert {s["name"] for s in sent["skipped"]} == {p.name for p in roll.iterdir() if p.suffix in (".AAE", ".MOV")}
    doc = wait_idle(client, pid, sent["version"])
    assert doc["error"] is None and doc["calibration"]["current"], doc
    folder = workspace / pid
    assert set(doc["files"]) == {"corners.json", "calib.json", "eval.json", "report.html", "advise.json", "advise.html"}
    photos = {p["name"]: p for p in doc["photos"]}
    assert set(photos) == {p.name for p in roll.glob("*.JPG")}
    assert {p["camera"] for p in photos.values() if p["camera"]} == {"wide", "tele"}
    assert [n for n, p in photos.items() if p["found"] is False]            # the roll's photo without a board
    assert all(p["used"] for p in photos.values())
    app_calib = json.loads((folder / "calib.json").read_text())        # what the commands give on the corners.json
    compared = assert_same_calibration(app_calib, cli_calibration(folder, tmp_path / "cli.json", source="corners.json"))
    assert compared > 30                                    # and on the photos, but for that file's rounding to 1e-5 px
    assert_within_sigma(app_calib, cli_calibration(folder, tmp_path / "cli-photos.json"))
    # the files the page links to are the files on disk
    for name in doc["files"]:
        assert client.get(f"/api/projects/{pid}/files/{name}", headers=AUTH).content == (folder / name).read_bytes()
    assert client.get(f"/api/projects/{pid}/files/../project.json", headers=AUTH).status_code == 404
    assert client.get(f"/api/projects/{pid}/files/exports/rig-opencv.yml", headers=AUTH).status_code == 200
    report = client.get(f"/api/projects/{pid}/files/report.html", headers=AUTH)
    assert report.headers["content-security-policy"].startswith("sandbox")
    some = next(iter(photos))
    assert client.get(f"/api/projects/{pid}/photos/{some}", headers=AUTH).content == (folder / "photos" / some).read_bytes()
    assert client.get(f"/api/projects/{pid}/thumbs/{some}", headers=AUTH).headers["content-type"] == "image/jpeg"
    # the preview for the screen is made when it is first asked for, the photo's long side 1600 px
    screen = folder / ".dualcal-app" / "screen" / f"{some}.jpg"
    assert not screen.exists()
    got = client.get(f"/api/projects/{pid}/screen/{some}", headers=AUTH)
    assert got.status_code == 200 and got.content == screen.read_bytes()
    assert max(cv2.imdecode(np.frombuffer(got.content, np.uint8), cv2.IMREAD_COLOR).shape[:2]) <= 1600
    import io
    import zipfile
    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/api/projects/{pid}/archive.zip", headers=AUTH).content))
    assert f"{pid}/calib.json" in archive.namelist() and f"{pid}/photos/{some}" in archive.namelist()
    assert not [n for n in archive.namelist() if "/." in n]
    result = client.get(f"/api/projects/{pid}/result", headers=AUTH).json()["summary"]
    assert result["verdict"] == doc["calibration"]["verdict"] and result["advice"]["poses"]
    assert [c["name"] for c in result["cameras"]] == ["wide", "tele"] and result["rig"][0]["baseline_sigma_mm"] > 0

    # measure: two corners of the board in one instant's photos, 7 squares apart (210 mm)
    view, by_camera = next(iter(result["instants"].items()))
    corners = json.loads((folder / "corners.json").read_text())["cameras"]
    points = {f"c{k}": {cam: corners[cam]["views"][view][k] for cam in by_camera} for k in (0, 7)}
    measured = client.post(f"/api/projects/{pid}/measure", headers=AUTH,
                           json={"points": points, "lengths": [["c0", "c7"]]}).json()
    length = measured["lengths"][0]
    assert abs(length["length_mm"] - 210.0) < 4 * length["sigma_mm"] + 0.5, length

    # leave a photo out: a new calibration from the corners already found, as `calibrate corners.json --exclude`
    # gives it (and as `calibrate photos --exclude`, but for the corners.json's rounding to 1e-5 px)
    left = next(n for n, p in photos.items() if p["camera"] == "tele" and p["status"] == "kept")
    stored = tmp_path / "stored-corners.json"
    stored.write_bytes((folder / "corners.json").read_bytes())
    stale = doc["version"] - 1
    r = client.post(f"/api/projects/{pid}/use", json={"photos": {left: False}, "version": stale}, headers=AUTH)
    assert r.status_code == 409                                      # a page that has not seen the last change
    r = client.post(f"/api/projects/{pid}/use", json={"photos": {left: False}, "version": doc["version"]}, headers=AUTH)
    assert r.status_code == 200 and r.json()["version"] == doc["version"] + 1
    after = wait_idle(client, pid, r.json()["version"])
    assert after["calibration"]["current"] and not {p["name"]: p for p in after["photos"]}[left]["used"]
    app_left_out = json.loads((folder / "calib.json").read_text())
    assert_same_calibration(app_left_out, cli_calibration(folder, tmp_path / "cli-x.json", "--exclude",
                                                          exclude_pattern(left), source=str(stored)))
    assert_within_sigma(app_left_out, cli_calibration(folder, tmp_path / "cli-p.json", "--exclude", exclude_pattern(left)))
    assert left in json.dumps(json.loads((folder / "corners.json").read_text())["cameras"]["tele"]["excluded"])
    assert client.post(f"/api/projects/{pid}/use", json={"photos": {"nope.jpg": False}}, headers=AUTH).status_code == 400


def a_folder_the_commands_made_opens_in_the_app(client, workspace, roll):
    folder = workspace / "from-the-cli"
    shutil.copytree(roll, folder / "photos", ignore=shutil.ignore_patterns("*.AAE", "*.MOV"))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    subprocess.run([sys.executable, "-m", "dualcal", "calibrate", "photos", "--board", "8x5", "--square", "30",
                    "-o", "calib.json", "--exclude", "IMG_0104.JPG"], cwd=folder, env=env, check=True, capture_output=True)
    before = (folder / "calib.json").read_bytes()
    doc = wait_idle(client, "from-the-cli")
    assert doc["name"] == "from-the-cli" and doc["flags"] == ["--board", "8x5", "--square", "30"]
    assert not {p["name"]: p for p in doc["photos"]}["IMG_0104.JPG"]["used"]
    assert doc["calibration"]["ok"] is not None
    after = json.loads((folder / "calib.json").read_text())
    assert_same_calibration(after, json.loads(before))


def two_clients_uploading_at_once_lose_nothing(client, workspace, roll):
    """Every photo of two uploads into one project at once arrives, byte for byte, and counts once (no wait
    for the calibration it starts)."""
    pid = new_project(client)
    names = sorted(p.name for p in roll.glob("*.JPG"))
    halves = [names[0::2], names[1::2]]
    results = []

    def send(half):
        results.append(client.post(f"/api/projects/{pid}/photos", files=files_of(roll, half), headers=AUTH).json())

    threads = [threading.Thread(target=send, args=(h,)) for h in halves]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(n for r in results for n in r["added"]) == names
    doc = client.get(f"/api/projects/{pid}", headers=AUTH).json()
    assert sorted(p["name"] for p in doc["photos"]) == names and doc["version"] == len(names)
    for name in names:
        assert (workspace / pid / "photos" / name).read_bytes() == (roll / name).read_bytes()


def test_a_roll_without_exif_as_a_phones_browser_sends_it(client, workspace, tmp_path):
    """The issue's three-lens roll as a phone's browser uploads it: EXIF stripped, re-encoded as JPEG (iOS's upload
    of a HEIC photo), a fisheye ultra-wide (1130 px), a wide (1340 px) and a third lens (1650 px) all of one size.
    The app splits it as the roll with its EXIF (every photo in the same camera) and as ``dualcal calibrate`` on the
    same upload (one code path: the same split, the same calibration but for corners.json's rounding), every focal
    length and principal point within 4 sigma of the truth, and the page says how sure the split is."""
    import cv2

    from dualcal.synthetic.synth import make_truth
    from dualcal.synthetic.synth_roll import shared_size_rig, write_camera_roll

    truth = make_truth(shared_size_rig({"wide": 1340.0, "ultra": 1130.0, "wide2": 1650.0}), views=8, seed=11,
                       scale=0.25)
    original = tmp_path / "roll"
    original.mkdir()
    write_camera_roll(truth, original, seed=11, jobs=2)
    stripped = []
    for p in sorted(original.glob("*.JPG")):
        data = cv2.imencode(".jpg", cv2.imread(str(p), cv2.IMREAD_COLOR), [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
        assert b"Exif" not in data[:200]
        stripped.append(("photos", (p.stem + ".jpeg", data, "image/jpeg")))
    with_exif, without = new_project(client), new_project(client)
    client.post(f"/api/projects/{with_exif}/photos", files=files_of(original), headers=AUTH)
    client.post(f"/api/projects/{without}/photos", files=stripped, headers=AUTH)
    cameras = {}
    for pid in (with_exif, without):
        doc = wait_idle(client, pid)
        assert doc["error"] is None, doc["error"]
        cameras[pid] = {Path(p["name"]).stem: p["camera"] for p in doc["photos"] if p["camera"]}
    assert cameras[without] == cameras[with_exif] and set(cameras[without].values()) == {"ultra", "wide", "wide2"}
    calib = json.loads((workspace / without / "calib.json").read_text())
    for name, cam in calib["cameras"].items():
        true = truth.cameras[name]
        for key in ("fx", "fy", "cx", "cy"):
            assert abs(cam[key] - getattr(true, key)) < 4 * cam["sigma"][key], (name, key)
    command = cli_calibration(workspace / without, tmp_path / "cli.json")
    assert command["corners"]["roll"] == calib["corners"]["roll"]
    assert_within_sigma(calib, command)
    clues = {pid: client.get(f"/api/projects/{pid}/result", headers=AUTH).json()["summary"]["roll"]
             for pid in (with_exif, without)}
    assert clues[with_exif]["cameras"].startswith("EXIF lens")                 # the page says which clues were used
    assert clues[without]["cameras"] == "image size, focal length from the board", clues[without]
    assert {c["told_by"] for c in clues[without]["found"]} == {"focal length from the board"}
    assert clues[without]["cameras_sure"] in ("sure", "certain") and clues[without]["cameras_separation_sigma"] >= 5
    html = client.get(f"/projects/{without}/part", headers=AUTH).text
    assert f"{clues[without]['cameras_separation_sigma']:.1f} sigma apart" in html


def test_the_pages_the_route_list_the_qr_code_and_the_event_stream(client):
    pid = new_project(client)
    routes = client.get("/api", headers=AUTH).json()["routes"]
    for route in ("/api/projects", "/api/projects/{id}/photos", "/api/projects/{id}/use", "/api/projects/{id}/events",
                  "/api/projects/{id}/files/NAME", "/api/projects/{id}/measure", "/api/qr.svg"):
        assert route in routes, route
    qr = client.get("/api/qr.svg", headers=AUTH)
    assert qr.headers["content-type"].startswith("image/svg+xml") and qr.text.startswith("<svg")
    cookies = {"dualcal_token": TOKEN}
    index = client.get("/", cookies=cookies)
    assert index.status_code == 200 and "script-src 'self'" in index.headers["content-security-policy"]
    assert 'href="/projects/' + pid + '"' in index.text and "<script src=\"/static/index.js\">" in index.text
    page = client.get(f"/projects/{pid}", cookies=cookies).text
    assert '<label class="button" for="add-photos">Add photos</label>' in page and 'role="status"' in page
    assert "http" not in page.split("<body>")[1].replace(f"{BASE}/?token", "")      # nothing from elsewhere
    part = client.get(f"/projects/{pid}/part", cookies=cookies)
    assert part.status_code == 200 and 'id="photo-list"' in part.text
    assert TestClient(client.app, base_url=BASE).get(f"/projects/{pid}/part").status_code == 401
    with client.stream("GET", f"/api/projects/{pid}/events", headers=AUTH) as events:
        assert events.headers["content-type"].startswith("text/event-stream")
        lines = events.iter_lines()
        data = next(line for line in lines if line.startswith("data: "))
    state = json.loads(data[len("data: "):])
    assert state["id"] == pid and state["state"] == "idle" and state["photos"] == [] and state["calibration"] is None
    assert client.get(f"/api/projects/{pid}/files/calib.json", headers=AUTH).status_code == 404
    assert client.post(f"/api/projects/{pid}/measure", json={}, headers=AUTH).status_code == 409


def test_the_command_says_in_one_line_what_is_wrong(run_cli, tmp_path, monkeypatch):
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    cases = [(["--port", busy.getsockname()[1]], "give another --port"), (["--host", "10.9.9.9"], "not an address"),
             (["--certfile", __file__], "--keyfile"), ([], "DUALCAL_APP_TOKEN")]
    for args, needle in cases:
        if needle == "DUALCAL_APP_TOKEN":
            monkeypatch.setenv("DUALCAL_APP_TOKEN", "no spaces please")
        code, out, err = run_cli("app", tmp_path, "--no-browser", *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, (args, err)
    code, _, err = run_cli("app", tmp_path / "no" / "such", "--no-browser")
    assert code == 2 and "no such folder" in err
    busy.close()


def test_on_the_local_network_the_pages_show_the_qr_code(tmp_path):
    lan = "http://192.168.1.20:8765"
    app = create_app(AppConfig(workspace=tmp_path, token=TOKEN, host="0.0.0.0", url=f"{lan}/?token={TOKEN}", workers=1))
    with TestClient(app, base_url=lan) as c:
        page = c.get("/", cookies={"dualcal_token": TOKEN}).text
        assert '<img class="qr" src="/api/qr.svg"' in page
        assert c.get("/api/projects", headers={**AUTH, "host": "attacker.example:8765"}).status_code == 400


def test_photos_left_out_are_summed_up_by_kind_and_the_charts_labels_tell_the_photos_apart():
    """Eight photos left out stand in one line ("8 photos left out: 5 show part of the board, 3 show no board"),
    each once (the detection's reason, not the split's again), the other warnings apart; a phone's names, the same
    17 characters first, are labelled by what differs; a name in a camera's folder keeps its folder."""
    from dualcal.app.summary import chart_labels, split_warnings

    part = "only part of the 8x5 chessboard is in the photo (3x3 corners at the frame's edge): too little of it"
    names = [f"IMG_20210417_0103{n:02d}.jpg" for n in range(8)]
    warnings = [f"photos/{n}: skipped: {part if k < 5 else 'no 8x5 chessboard found'}" for k, n in enumerate(names)]
    warnings += [f"{n}: left out (no board found (wide))" for n in names] + ["a warning about no photo"]
    rest, out = split_warnings(warnings, names + ["IMG_20210417_010399.jpg"])
    assert rest == ["a warning about no photo"]
    assert out["count"] == 8 and out["kinds"] == [{"kind": "show part of the board", "count": 5},
                                                   {"kind": "show no board", "count": 3}]
    assert [p["photo"] for p in out["photos"]] == names and out["photos"][0]["why"] == part
    _, one = split_warnings(["IMG_1.JPG: left out (retake: IMG_2.JPG of the same camera is kept)"], ["IMG_1.JPG"])
    assert one["kinds"] == [{"kind": "retake", "count": 1}]
    assert chart_labels(names[:3]) == ["…010300", "…010301", "…010302"]
    assert chart_labels(["wide/IMG_01.jpg", "tele/IMG_01.jpg"]) == ["wide/IMG_01", "tele/IMG_01"]
    long = chart_labels(["a_photo_with_a_very_long_name_0001.jpeg", "b.jpeg"], width=14)
    assert long[0] == "a_phot…me_0001" and len(long[0]) == 14
