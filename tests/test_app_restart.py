"""``dualcal app`` killed at any moment (SIGKILL during an upload, a detection, a calibration) and started again
on the same workspace: every photo uploaded whole is there, no part of the one cut off, the last complete
calibration stays readable, and the work it had queued finishes (CONTRACT.md, "app")."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

httpx = pytest.importorskip("httpx", reason="the tests' HTTP client")
pytest.importorskip("uvicorn", reason="the app extra")

TOKEN = "restart-token-0123456789"
AUTH = {"authorization": f"Bearer {TOKEN}"}


class Server:
    """``dualcal app WORKSPACE --port 0 --no-browser`` in a process of its own."""

    def __init__(self, workspace: Path):
        env = {**os.environ, "DUALCAL_APP_TOKEN": TOKEN, "OPENBLAS_NUM_THREADS": "1"}
        self.process = subprocess.Popen([sys.executable, "-m", "dualcal", "app", str(workspace), "--port", "0",
                                         "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                        text=True)
        line = self.process.stdout.readline()
        assert line.startswith("dualcal app: http://127.0.0.1:"), (line, self.process.stderr.read())
        self.url = line.split(": ", 1)[1].strip().split("/?")[0]
        self.client = httpx.Client(base_url=self.url, headers=AUTH, timeout=60)
        self.client.get("/api/projects").raise_for_status()       # the lifespan has run: the server answers

    def state(self, pid: str) -> dict:
        return self.client.get(f"/api/projects/{pid}").json()

    def wait(self, pid: str, until, timeout: float = 120, every: float = 0.05) -> dict:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            doc = self.state(pid)
            if until(doc):
                return doc
            time.sleep(every)
        raise AssertionError(f"not reached in {timeout} s: {doc}")

    def kill(self) -> None:
        """SIGKILL the server; every process it started (fork server, workers, a calibration) ends with it."""
        self.client.close()
        before = descendants(self.process.pid)
        assert before, "the server runs its work in processes of its own"
        self.process.send_signal(signal.SIGKILL)
        self.process.wait()
        self.process.stdout.close()
        self.process.stderr.close()
        end = time.monotonic() + 20
        while (alive := [p for p in before if Path(f"/proc/{p}").exists() and not _zombie(p)]) and time.monotonic() < end:
            time.sleep(0.1)
        assert not alive, f"processes of the killed server still run: {alive}"


def descendants(pid: int) -> list[int]:
    """Every process under ``pid`` (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.fixture(scope="module")
def roll(tmp_path_factory) -> Path:
    from dualcal.synthetic.synth import make_truth
    from dualcal.synthetic.synth_roll import write_camera_roll

    folder = tmp_path_factory.mktemp("roll")
    write_camera_roll(make_truth("note8", views=5, seed=5, scale=0.25), folder, seed=5, jobs=2)
    return folder


def _multipart(name: str, data: bytes, boundary: str = "dualcalboundary") -> tuple[bytes, bytes]:
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"photos\"; filename=\"{name}\"\r\n"
            "Content-Type: image/jpeg\r\n\r\n").encode()
    return head + data + b"\r\n", f"--{boundary}--\r\n".encode()


def test_killed_during_an_upload_a_detection_and_a_calibration(tmp_path, roll):
    photos = sorted(roll.glob("*.JPG"))
    whole, cut = photos[:-1], photos[-1]
    server = Server(tmp_path)
    try:
        pid = server.client.post("/api/projects", json={"name": "restart", "board": "8x5", "square_mm": 30}).json()["id"]
        sent = server.client.post(f"/api/projects/{pid}/photos", files=[
            ("photos", (p.name, p.read_bytes(), "image/jpeg")) for p in whole]).json()
        assert sent["added"] == [p.name for p in whole]
        detecting = server.state(pid)["work"]["detecting"]

        # an upload cut off: half of a photo's bytes arrive, then the server is killed
        part, end = _multipart(cut.name, cut.read_bytes())
        started = threading.Event()

        def body():
            yield part[: len(part) // 2]
            started.set()
            time.sleep(30)
            yield part[len(part) // 2:] + end

        def send():
            try:
                httpx.post(f"{server.url}/api/projects/{pid}/photos", content=body(), timeout=60,
                           headers={**AUTH, "content-type": "multipart/form-data; boundary=dualcalboundary"})
            except httpx.HTTPError:
                pass                                              # the server was killed under it

        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        assert started.wait(30)
        server.wait(pid, lambda d: d["work"]["uploads"] == 1)
    finally:
        server.kill()
    assert detecting > 0, "the kill was meant to come while photos were being detected"

    server = Server(tmp_path)                      # 2: the photos uploaded whole are there, the cut one is not
    try:
        doc = server.state(pid)
        assert sorted(p["name"] for p in doc["photos"]) == [p.name for p in whole]
        assert not [p for p in (tmp_path / pid / "photos").iterdir() if p.name.startswith(".")]
        for p in whole:
            assert (tmp_path / pid / "photos" / p.name).read_bytes() == p.read_bytes()
        first = server.wait(pid, lambda d: d["state"] == "idle")   # the detection and calibration it had queued
        assert first["calibration"]["current"] and first["error"] is None, first
        complete = (tmp_path / pid / "calib.json").read_bytes()
        left = next(p["name"] for p in first["photos"] if p["status"] == "kept")
        changed = server.client.post(f"/api/projects/{pid}/use", json={"photos": {left: False}}).json()
        server.wait(pid, lambda d: d["work"]["calibrating"], every=0.01)
    finally:
        server.kill()                              # during the calibration of that change
    on_disk = (tmp_path / pid / "calib.json").read_bytes()
    if on_disk != complete:                        # a calibration lands whole or not at all
        from dualcal.files.io import load_rig
        load_rig(tmp_path / pid / "calib.json")

    server = Server(tmp_path)                      # 3: the change it had acknowledged is calibrated
    try:
        done = server.wait(pid, lambda d: d["state"] == "idle" and d["version"] == changed["version"])
        assert done["calibration"]["current"] and done["error"] is None, done
        assert not {p["name"]: p for p in done["photos"]}[left]["used"]
        corners = json.loads((tmp_path / pid / "corners.json").read_text())
        assert any(left in json.dumps(c.get("excluded", {})) for c in corners["cameras"].values())
    finally:
        server.kill()


def test_served_over_tls_with_a_certificate_and_its_key(tmp_path):
    """``--certfile/--keyfile``: the app serves https (a self-signed certificate made here with openssl); the
    printed URL says https, the API answers over TLS with the token, and plain http on that port gets no page."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not here to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert),
                    "-days", "1", "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"], check=True,
                   capture_output=True)
    env = {**os.environ, "DUALCAL_APP_TOKEN": TOKEN, "OPENBLAS_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "dualcal", "app", str(tmp_path / "ws"), "--port", "0",
                                "--no-browser", "--certfile", str(cert), "--keyfile", str(key)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    try:
        line = process.stdout.readline()
        assert line.startswith("dualcal app: https://127.0.0.1:"), (line, process.stderr.read())
        url = line.split(": ", 1)[1].strip().split("/?")[0]
        with httpx.Client(base_url=url, headers=AUTH, timeout=30, verify=str(cert)) as client:
            assert client.get("/api/projects").status_code == 200
            assert client.get("/api/projects", headers={"authorization": "Bearer wrong"}).status_code == 401
        with pytest.raises(httpx.HTTPError):
            httpx.get(url.replace("https://", "http://") + "/api/projects", headers=AUTH, timeout=10)
    finally:
        process.kill()
        process.wait()
        process.stdout.close()
        process.stderr.close()
