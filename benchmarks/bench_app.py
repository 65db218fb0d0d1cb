"""dualcal app against dualcal calibrate, on a three-lens 12 MP camera roll uploaded through the API.

    .venv/bin/python benchmarks/bench_app.py [--rounds 2] [--preset phone3] [--views 20] [--scale 1] [--browser]

The roll is ``dualcal synth DIR --preset phone3 --views 20 --roll`` (a wide, a 3x tele and a fisheye ultra-wide,
12 MP each: about 60 photos, cached under out/bench-app/). Printed, each with the issue's aim (the two sides of
each ratio take turns, and the medians are compared: this machine's speed drifts):

* the time from the upload's last byte (its response) to the verdict (``calibration.current``) against
  ``dualcal calibrate ROLL`` as a process on the same photos;
* the time from leaving a photo out (``POST /use``) to the new verdict against ``dualcal calibrate
  corners.json --exclude PHOTO`` as a process on the corners the app stored (its corners.json before);
  with ``--browser``, both waits while the project's page is open in Chromium with an iPhone's viewport;
* the server's peak memory: its processes and every worker's, RSS and PSS (shared pages counted once);
* the API's latency (``GET /api/projects/{id}``, every 50 ms) while the photos are detected: median, p95;
* two clients uploading halves of the roll into one project at once: every photo there, byte for byte.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "bench-token-0123456789"
AUTH = {"authorization": f"Bearer {TOKEN}"}
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "DUALCAL_APP_TOKEN": TOKEN}
DUALCAL = [sys.executable, "-m", "dualcal"]


def synth_roll(preset: str, views: int, scale: float) -> Path:
    folder = ROOT / "out" / "bench-app" / f"{preset}-{views}-{scale:g}"
    if not (folder / "roll").is_dir():
        folder.parent.mkdir(parents=True, exist_ok=True)
        print(f"rendering the roll ({preset}, {views} positions, scale {scale:g}) into {folder} ...", flush=True)
        subprocess.run([*DUALCAL, "synth", str(folder), "--preset", preset, "--views", str(views), "--roll",
                        "--scale", str(scale)], env=ENV, check=True, capture_output=True)
    return folder / "roll"


def tree_memory(pid: int) -> tuple[float, float]:
    """RSS and PSS (MB) of ``pid`` and all its descendants."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                ppid = int(open(f"/proc/{entry}/stat").read().rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
            children.setdefault(ppid, []).append(int(entry))
    todo, rss, pss = [pid], 0.0, 0.0
    while todo:
        p = todo.pop()
        todo += children.get(p, [])
        try:
            for line in open(f"/proc/{p}/smaps_rollup"):
                if line.startswith("Rss:"):
                    rss += int(line.split()[1]) / 1024
                elif line.startswith("Pss:"):
                    pss += int(line.split()[1]) / 1024
        except OSError:
            pass
    return rss, pss


class Server:
    def __init__(self, workspace: Path):
        self.process = subprocess.Popen([*DUALCAL, "app", str(workspace), "--port", "0", "--no-browser"], env=ENV,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.url = self.process.stdout.readline().split(": ", 1)[1].strip().split("/?")[0]
        self.client = httpx.Client(base_url=self.url, headers=AUTH, timeout=600)
        self.peak = (0.0, 0.0)
        self._stop = threading.Event()
        threading.Thread(target=self._sample, daemon=True).start()

    def _sample(self):
        while not self._stop.is_set():
            rss, pss = tree_memory(self.process.pid)
            self.peak = (max(self.peak[0], rss), max(self.peak[1], pss))
            time.sleep(0.1)

    def project(self, name: str) -> str:
        return self.client.post("/api/projects", json={"name": name, "board": "8x5", "square_mm": 30}).json()["id"]

    def state(self, pid: str) -> dict:
        return self.client.get(f"/api/projects/{pid}").json()

    def wait_verdict(self, pid: str, version: int, every: float = 0.02) -> dict:
        while True:
            doc = self.state(pid)
            c = doc["calibration"]
            if c and c["current"] and doc["version"] >= version:
                return doc
            if doc["error"]:
                raise RuntimeError(doc["error"])
            time.sleep(every)

    def wait_idle(self, pid: str) -> dict:
        while (doc := self.state(pid))["state"] != "idle":
            time.sleep(0.2)
        return doc

    def stop(self):
        self._stop.set()
        self.client.close()
        self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()


def upload(server: Server, pid: str, photos: list[Path]) -> dict:
    handles = [open(p, "rb") for p in photos]
    try:
        r = server.client.post(f"/api/projects/{pid}/photos",
                               files=[("photos", (p.name, h, "image/jpeg")) for p, h in zip(photos, handles)])
    finally:
        for h in handles:
            h.close()
    r.raise_for_status()
    return r.json()


class Viewer:
    """The project's page open in Chromium with an iPhone's viewport (Playwright, Debian's /usr/bin/chromium), as a
    person follows the work on the phone: the page fetches its sections again as the state changes."""

    def __init__(self, server: Server):
        from playwright.sync_api import sync_playwright

        self._pw = sync_playwright().start()
        self._browser = self._pw.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
        self._context = self._browser.new_context(**self._pw.devices["iPhone 13"])
        self.page = self._context.new_page()
        self.page.goto(f"{server.url}/?token={TOKEN}")

    def follow(self, server: Server, pid: str) -> None:
        self.page.goto(f"{server.url}/projects/{pid}")

    def close(self) -> None:
        self._browser.close()
        self._pw.stop()


def app_round(server: Server, photos: list[Path], latencies: list[float], viewer: Viewer | None = None
              ) -> tuple[float, float]:
    pid = server.project("bench")
    if viewer is not None:
        viewer.follow(server, pid)
    done = threading.Event()

    def ping():                     # the API's latency while the photos arrive and are detected
        with httpx.Client(base_url=server.url, headers=AUTH, timeout=60) as c:
            while not done.is_set():
                t = time.perf_counter()
                doc = c.get(f"/api/projects/{pid}").json()
                if doc["work"]["detecting"] or doc["work"]["uploads"]:
                    latencies.append(time.perf_counter() - t)
                time.sleep(0.05)

    pinger = threading.Thread(target=ping, daemon=True)
    pinger.start()
    t0 = time.perf_counter()
    sent = upload(server, pid, photos)
    last_byte = time.perf_counter()
    server.wait_verdict(pid, sent["version"])
    verdict = time.perf_counter()
    done.set()
    pinger.join()
    print(f"  app: upload {last_byte - t0:.1f} s, last byte to verdict {verdict - last_byte:.1f} s", flush=True)
    server.wait_idle(pid)
    return verdict - last_byte, pid


def cli_round(roll: Path, out: Path) -> float:
    t = time.perf_counter()
    subprocess.run([*DUALCAL, "calibrate", str(roll), "--board", "8x5", "--square", "30", "-o", str(out)],
                   env=ENV, check=True, capture_output=True)
    elapsed = time.perf_counter() - t
    print(f"  dualcal calibrate: {elapsed:.1f} s", flush=True)
    return elapsed


def leave_out(server: Server, pid: str, workspace: Path, out: Path, times: int = 3) -> tuple[list[float], list[float]]:
    """Leave a kept tele photo out and wait for the new verdict, then ``dualcal calibrate corners.json --exclude``
    on the corners the app stored before (a process, as a person runs it), taking turns; put it back each time."""
    doc = server.state(pid)
    kept = [p["name"] for p in doc["photos"] if p["status"] == "kept" and p["camera"] == "tele"]
    app, cli = [], []
    for name in kept[:times]:
        stored = out / "stored-corners.json"
        stored.write_bytes((workspace / pid / "corners.json").read_bytes())
        version = server.state(pid)["version"]
        t = time.perf_counter()
        r = server.client.post(f"/api/projects/{pid}/use", json={"photos": {name: False}, "version": version}).json()
        server.wait_verdict(pid, r["version"])
        app.append(time.perf_counter() - t)
        server.wait_idle(pid)
        t = time.perf_counter()
        subprocess.run([*DUALCAL, "calibrate", str(stored), "--exclude", name, "-o", str(out / "left-out.json")],
                       env=ENV, check=True, capture_output=True)
        cli.append(time.perf_counter() - t)
        print(f"  left out {name}: app {app[-1]:.2f} s, dualcal calibrate corners.json --exclude {cli[-1]:.2f} s",
              flush=True)
        server.client.post(f"/api/projects/{pid}/use", json={"photos": {name: True}})
        server.wait_idle(pid)
    return app, cli


def two_clients(server: Server, photos: list[Path], workspace: Path) -> str:
    pid = server.project("two clients")
    results = []
    threads = [threading.Thread(target=lambda half: results.append(upload(server, pid, half)), args=(h,))
               for h in (photos[0::2], photos[1::2])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    added = sorted(n for r in results for n in r["added"])
    listed = sorted(p["name"] for p in server.state(pid)["photos"])
    same = all(hashlib.sha256((workspace / pid / "photos" / p.name).read_bytes()).digest()
               == hashlib.sha256(p.read_bytes()).digest() for p in photos)
    server.wait_idle(pid)
    ok = added == listed == sorted(p.name for p in photos) and same
    return f"{len(listed)} of {len(photos)} photos there, byte for byte: {'yes' if ok else 'NO'}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--preset", default="phone3")
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--browser", action="store_true",
                        help="follow the project's page in Chromium with an iPhone's viewport meanwhile")
    args = parser.parse_args()
    roll = synth_roll(args.preset, args.views, args.scale)
    photos = sorted(roll.glob("*.JPG"))
    print(f"{len(photos)} photos of {roll} ({sum(p.stat().st_size for p in photos) / 1e6:.0f} MB)")
    with tempfile.TemporaryDirectory(prefix="bench-app-") as tmp:
        workspace = Path(tmp) / "ws"
        workspace.mkdir()
        server = Server(workspace)
        viewer = Viewer(server) if args.browser else None
        try:
            latencies, app_times, cli_times, pid = [], [], [], None
            for _ in range(args.rounds):              # the two take turns
                cli_times.append(cli_round(roll, Path(tmp) / "cli.json"))
                t, pid = app_round(server, photos, latencies, viewer)
                app_times.append(t)
            instants = len(json.loads((workspace / pid / "calib.json").read_text())["views"])
            left_app, left_cli = leave_out(server, pid, workspace, Path(tmp))
            both = two_clients(server, photos, workspace)
            rss, pss = server.peak
        finally:
            if viewer is not None:
                viewer.close()
            server.stop()
    p95 = statistics.quantiles(latencies, n=20)[18] if len(latencies) >= 20 else max(latencies, default=float("nan"))
    app, cli = statistics.median(app_times), statistics.median(cli_times)
    left_a, left_c = statistics.median(left_app), statistics.median(left_cli)
    rows = [("last byte to verdict (app) / dualcal calibrate ROLL", f"{app:.1f} s / {cli:.1f} s = {app / cli:.2f} x",
             "<= 1.2 x"),
            (f"a photo left out to its verdict (app) / calibrate corners.json --exclude ({instants} instants)",
             f"{left_a:.2f} s / {left_c:.2f} s = {left_a / left_c:.2f} x", "<= 1.2 x"),
            ("server's peak memory (with its workers)", f"RSS {rss / 1024:.2f} GB, PSS {pss / 1024:.2f} GB", "< 1.5 GB"),
            ("API latency while detecting", f"median {1e3 * statistics.median(latencies):.0f} ms, p95 {1e3 * p95:.0f} ms "
                                            f"({len(latencies)} requests)", "< 200 ms"),
            ("two clients uploading at once", both, "nothing lost")]
    width = max(len(r[0]) for r in rows)
    print()
    for what, got, aim in rows:
        print(f"{what:<{width}}  {got:<48}  aim {aim}")


if __name__ == "__main__":
    main()
