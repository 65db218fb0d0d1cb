"""The job runner: each project's work off the request path, in worker processes.

* **Detection** of each uploaded photo starts as soon as its last byte is on disk, in a pool of worker
  processes (:func:`.work.detect_upload`); a photo's detection is never thrown away.
* **Calibration** (:func:`.work.run_job`) brings a project's files to its version, in a process of its
  own, once no upload is arriving and every photo is detected; a newer change **supersedes** it (the
  process is killed: every file is written atomically, so the last complete ones stay). One job per
  project at a time, at most one per core over all projects; waiting projects go first come, first served.
* The processes come from a fork server that has imported the library once (a job starts in about
  10 ms); the event loop never computes, and wakes ahead of them when a request comes (the kernel's
  scheduler favours a task that slept), so one project's work never holds another's page. (A lower
  priority for the workers was tried: on a machine shared with other work it made them 2-3 x slower
  than the command, for no gain in latency.)
* **Restart**: :meth:`Runner.open` compares project.json's version with the version the files are of
  (``results.json``) and queues what is missing, photos not yet detected first: the version is the journal.

Each project's state changes wake its listeners (:meth:`ProjectState.wait`, the page's event stream).
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import anyio

from .store import Project, Settings, Workspace

__all__ = ["ProjectState", "Runner"]

_PRELOAD = ["dualcal.app.work", "dualcal.workflow", "dualcal.files.detect.pipeline", "dualcal.files.dataset",
            "dualcal.estimation.calibrate", "dualcal.estimation.model_selection", "dualcal.estimation.evaluation",
            "dualcal.estimation.advise", "dualcal.files.export", "dualcal.pages.report.advice",
            "dualcal.pages.report.html"]
def _die_with_server(server_pid: int) -> None:
    """A worker's start: it ends when the server does, even one killed with SIGKILL (a thread waits on the
    server's process; its queues would not tell, as the worker holds both of their ends, and neither would the
    fork server, which lives as long as any process it made)."""
    import threading

    def watch():
        try:
            import select
            fd = os.pidfd_open(server_pid)
            select.select([fd], [], [])
        except (AttributeError, OSError):          # no pidfd (not Linux, or the server is gone already): poll
            import time
            while True:
                try:
                    os.kill(server_pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    pass
                time.sleep(1)
        os._exit(0)

    threading.Thread(target=watch, name="dualcal-server-watch", daemon=True).start()


def _job_main(server_pid, folder, version, settings, left_out, conn, recompute) -> None:
    _die_with_server(server_pid)
    from .work import run_job
    run_job(folder, version, settings, left_out, conn, recompute)


@dataclass
class ProjectState:
    """What the server knows of one project between the files: the version (project.json's), the photos and
    what became of their detection, the work running, and the summary of the last calibration."""

    project: Project
    name: str
    settings: Settings | None
    version: int
    left_out: set[str]
    photos: list[str] = field(default_factory=list)
    detections: dict[str, dict] = field(default_factory=dict)
    detecting: set[str] = field(default_factory=set)
    uploads: int = 0
    job: object = None
    job_version: int = -1
    results: dict = field(default_factory=dict)
    summary: dict | None = None
    failed_version: int = -1
    has_calibration: bool = False
    adopted_version: int = -1
    report: object = None
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    _changed: asyncio.Event = field(default_factory=asyncio.Event)

    def changed(self) -> None:
        """Wake every listener."""
        self._changed.set()
        self._changed = asyncio.Event()

    async def wait(self, timeout: float) -> bool:
        """Until the next change (True) or ``timeout`` seconds (False)."""
        try:
            await asyncio.wait_for(self._changed.wait(), timeout)
            return True
        except asyncio.TimeoutError:
            return False

    @property
    def busy(self) -> bool:
        return bool(self.uploads or self.detecting or self.job is not None or self.pending)

    @property
    def pending(self) -> bool:
        """Files older than the version, with a calibration still to try (not one that failed at this version)."""
        if self.settings is None or not (self.photos or self.has_calibration):
            return False
        failed = self.failed_version >= self.version or (self.results.get("version") == self.version
                                                          and self.results.get("error"))
        return self.results.get("complete", -1) < self.version and not failed

    @property
    def error(self) -> str | None:
        """Why the files are not of the version (the calibration's error), or None."""
        if self.results.get("complete", -1) >= self.version or self.pending or self.job is not None:
            return None
        return self.results.get("error")


class Runner:
    """The worker processes and every project's state (module docstring)."""

    def __init__(self, workspace: Workspace, workers: int | None = None):
        self.workspace = workspace
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.states: dict[str, ProjectState] = {}
        self._queue: deque[str] = deque()
        self._running = 0
        self._pool = None
        self._context = None
        self._opening: dict[str, asyncio.Lock] = {}
        self._stopping = False

    # -- life cycle
    def start(self) -> None:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")     # as the commands run (dualcal.cli.main)
        self._context = multiprocessing.get_context("forkserver")
        self._context.set_forkserver_preload(_PRELOAD)
        self._pool = ProcessPoolExecutor(self.workers, mp_context=self._context, initializer=_die_with_server,
                                         initargs=(os.getpid(),))

    async def resume_all(self) -> None:
        """Open every project of the workspace: queued work resumes (module docstring, "Restart")."""
        for project in self.workspace.projects():
            await self.open(project)

    def stop(self) -> None:
        self._stopping = True
        for state in self.states.values():
            if state.job is not None:
                self._end_job(state, kill=True)
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)     # a detection running ends first (seconds)

    # -- a project's state
    async def open(self, project: Project) -> ProjectState:
        """The state of ``project``, read from its folder the first time (and its missing work queued)."""
        if project.id in self.states:
            return self.states[project.id]
        lock = self._opening.setdefault(project.id, asyncio.Lock())
        async with lock:
            if project.id in self.states:
                return self.states[project.id]
            doc = await anyio.to_thread.run_sync(project.read)
            state = ProjectState(project, doc["name"], doc["settings"], doc["version"], set(doc["left_out"]))
            await anyio.to_thread.run_sync(self._load_files, state)
            self.states[project.id] = state
            if state.settings is not None:
                known = await anyio.to_thread.run_sync(self._known_detections, state)
                state.detections.update(known)
                for photo in state.photos:
                    if photo not in known:
                        self._detect(state, photo)
            self.schedule(state)
            return state

    def _load_files(self, state: ProjectState) -> None:
        for partial in state.project.photos_dir.glob(".upload-*.part"):   # an upload a killed server was receiving
            partial.unlink(missing_ok=True)
        state.photos = state.project.photo_names()
        state.results = state.project.read_app_json("results.json") or {}
        state.summary = state.project.read_app_json("summary.json")
        # a folder the commands made has no results.json: its job makes the summary (from its photos, or
        # from calib.json alone where there are none), and the files come out as the commands wrote them
        state.has_calibration = (state.project.folder / "calib.json").exists()
        if state.has_calibration and not state.results:
            state.adopted_version = state.version          # its first job takes calib.json as it is

    def _known_detections(self, state: ProjectState) -> dict[str, dict]:
        from .work import RememberedDetection
        remembered = RememberedDetection(state.project.app_file("detections"), state.project.photos_dir)
        board = state.settings.make_board()
        out = {}
        for photo in state.photos:
            result = remembered.known(state.project.photos_dir / photo, board)
            if result is not None and state.project.preview("thumbs", photo).exists():
                out[photo] = {"found": result.uv is not None, "reason": result.reason}
        return out

    async def save(self, state: ProjectState) -> None:
        """project.json with the state's version, settings and photos left out (before a change is acknowledged)."""
        await anyio.to_thread.run_sync(state.project.save, state.name, state.settings, state.version,
                                       sorted(state.left_out))

    # -- detection
    def _detect(self, state: ProjectState, photo: str) -> None:
        from .work import detect_upload

        state.detecting.add(photo)
        future = self._pool.submit(detect_upload, str(state.project.folder), photo, state.settings.make_board())
        loop = asyncio.get_running_loop()
        wrapped = asyncio.wrap_future(future, loop=loop)
        wrapped.add_done_callback(lambda f: self._detected(state, photo, f))

    def _detected(self, state: ProjectState, photo: str, future) -> None:
        state.detecting.discard(photo)
        if future.cancelled():
            return
        exc = future.exception()
        state.detections[photo] = ({"found": None, "reason": f"detection failed: {type(exc).__name__}: {exc}"}
                                   if exc is not None else {"found": future.result()["found"],
                                                            "reason": future.result()["reason"]})
        state.changed()
        self.schedule(state)

    async def photo_added(self, state: ProjectState, photo: str) -> None:
        """A photo is in ``photos/``: one more version (saved), its detection started."""
        if photo not in state.photos:
            state.photos = sorted([*state.photos, photo])
        state.version += 1
        await self.save(state)
        if state.settings is not None:
            self._detect(state, photo)
        state.changed()

    async def report(self, state: ProjectState) -> None:
        """report.html of the calibration on disk, made now where it is not of it (:func:`.work.make_report`)."""
        files = state.results.get("files", {})
        if (state.project.folder / "report.html").exists() and files.get("report.html", -2) == files.get("calib.json"):
            return
        from .work import make_report
        if state.report is None or state.report.done():
            state.report = asyncio.wrap_future(self._pool.submit(make_report, str(state.project.folder)))
        try:
            state.results = await asyncio.shield(state.report) or state.results
        finally:
            state.changed()

    # -- calibration jobs
    def schedule(self, state: ProjectState) -> None:
        """Start (or queue) the job that brings the files to the version, once nothing is arriving; a job of
        an older version is killed first."""
        if state.uploads or state.detecting or not state.pending:
            return
        if state.job is not None:
            if state.job_version == state.version:
                return
            self._end_job(state, kill=True)
        if state.project.id not in self._queue:
            self._queue.append(state.project.id)
        self._start_queued()

    def _start_queued(self) -> None:
        while self._queue and self._running < self.workers and not self._stopping:
            state = self.states[self._queue.popleft()]
            if state.job is None and state.pending and not (state.uploads or state.detecting):
                self._start_job(state)

    def _start_job(self, state: ProjectState) -> None:
        ctx = self._context
        receive, send = ctx.Pipe(duplex=False)
        process = ctx.Process(target=_job_main, daemon=True, args=(
            os.getpid(), str(state.project.folder), state.version, state.settings.to_dict(), sorted(state.left_out), send,
            state.version != state.adopted_version))
        process.start()
        send.close()
        state.job, state.job_version = (process, receive), state.version
        self._running += 1
        loop = asyncio.get_running_loop()
        loop.add_reader(receive.fileno(), self._message, state, process, receive)
        state.changed()

    def _message(self, state: ProjectState, process, receive) -> None:
        try:
            kind, value = receive.recv()
        except (EOFError, OSError):
            self._job_ended(state, process)
            return
        if state.job is None or state.job[0] is not process:
            return
        if kind in ("calibrated", "file", "done", "error"):
            state.results = state.project.read_app_json("results.json") or {}
            if kind in ("calibrated", "file"):
                state.summary = state.project.read_app_json("summary.json")
            if kind == "error":
                state.failed_version = state.job_version
            state.changed()

    def _job_ended(self, state: ProjectState, process) -> None:
        if state.job is None or state.job[0] is not process:
            return
        process.join(timeout=1)
        if state.results.get("complete", -1) < state.job_version and state.failed_version < state.job_version:
            state.failed_version = state.job_version
            state.results = {**state.results, "error": f"the calibration stopped unexpectedly (exit code "
                                                      f"{process.exitcode}); change something to try again"}
        self._end_job(state, kill=False)
        self.schedule(state)
        state.changed()

    def _end_job(self, state: ProjectState, kill: bool) -> None:
        process, receive = state.job
        try:
            asyncio.get_running_loop().remove_reader(receive.fileno())
        except (RuntimeError, ValueError, OSError):
            pass
        if kill and process.is_alive():
            process.kill()
            process.join()
        receive.close()
        state.job = None
        self._running -= 1
        self._start_queued()
