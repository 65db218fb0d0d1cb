"""The app's routes: parse, authorise (:mod:`.security`), call (:mod:`.jobs`, :mod:`.store`), answer.

Every page reads the JSON API below like any client; ``GET /api`` lists the routes. The contract's
routes (CONTRACT.md, "app") and the added ones:

=======  ======================================  ===============================================================
GET      /api/projects                           ``{"projects": [{"id", "name"}]}``
POST     /api/projects                           ``{"name", "board", "square_mm", "square_sigma_mm"?, "marker_mm"?,
                                                 "dictionary"?}`` (or ``"printed"``: the options in the margin of a
                                                 board ``dualcal board`` printed) -> 201 ``{"id"}``
GET      /api/projects/{id}                      state, version, photos, calibration, error
GET      /api/projects/{id}/events               the same state as server-sent events, on every change
GET      /api/projects/{id}/result               the calibration as the page shows it (verdict, checks, parameters
                                                 with sigma, rig, photos, advice)
POST     /api/projects/{id}/photos               multipart ``photos`` -> ``{"added", "skipped", "renamed", "version"}``
POST     /api/projects/{id}/use                  ``{"photos": {NAME: bool}, "version"?}`` -> ``{"version"}``;
                                                 409 when ``version`` is not the project's (a stale page)
POST     /api/projects/{id}/measure              a points.json (``{"points": {P: {camera: [u, v]}}, "lengths"?,
                                                 "pixel_sigma"?}``, pixels of one instant) -> measure.json's content
GET      /api/projects/{id}/files/NAME           corners.json, calib.json, eval.json, report.html, advise.json,
                                                 advise.html, exports/...
GET      /api/projects/{id}/archive.zip          every file of the project
GET      /api/projects/{id}/photos/NAME          a photo as uploaded; ``thumbs/NAME``, ``screen/NAME``: its previews
GET      /api/qr.svg                             the QR code of the app's URL (with the token)
GET      /projects/{id}/measure                  the page measuring with photos of an object
ANY      /api/projects/{id}/measure/...          its routes (:mod:`dualcal.app.measure_photos`)
=======  ======================================  ===============================================================
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import anyio
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from .. import __version__
from ..errors import DualcalError, InputError
from .jobs import ProjectState, Runner
from .measure_photos import measure_routes
from .security import Guard, HostRule
from .store import EXPORTS, FILES, Settings, Workspace
from .summary import chart_labels
from .uploads import PhotoStream, safe_photo_name

__all__ = ["AppConfig", "create_app"]

HERE = Path(__file__).parent
#: A page's HTML may load only the app's own script, style and images.
PAGE_POLICY = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
               "form-action 'self'; base-uri 'none'; frame-ancestors 'none'")
#: A file of the project shown as a page (report.html, advise.html: self-contained, inline script and style) is
#: sandboxed: an origin of its own, no request to the app.
FILE_POLICY = ("sandbox allow-scripts allow-popups; default-src 'none'; img-src data: blob:; style-src 'unsafe-inline'; "
               "script-src 'unsafe-inline'; font-src data:")


@dataclass
class AppConfig:
    """What a server is started with.

    ``url`` is the address to print and draw as a QR code (the LAN address with ``--host 0.0.0.0``), with the token.
    """

    workspace: Path
    token: str
    host: str = "127.0.0.1"
    url: str = ""
    max_photo_bytes: int = 256_000_000
    workers: int | None = None


class NoProject(LookupError):
    """The id names no project of the workspace (404)."""


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


async def _json_body(request: Request, limit: int = 1_000_000) -> dict:
    body = await request.body()
    if len(body) > limit:
        raise InputError("the request body is too large")
    try:
        doc = json.loads(body or b"{}")
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise InputError("the request body is not JSON") from None
    if not isinstance(doc, dict):
        raise InputError("the request body must be a JSON object")
    return doc


def create_app(config: AppConfig) -> Starlette:
    """The ASGI application: the routes (module docstring) behind the :class:`~.security.Guard`."""
    from jinja2 import Environment, FileSystemLoader, select_autoescape

    workspace = Workspace(config.workspace)
    phone_url = config.url if HostRule(config.host).wildcard else ""      # a QR code only where a phone can reach it
    runner = Runner(workspace, config.workers)
    templates = Environment(loader=FileSystemLoader(HERE / "templates"), autoescape=select_autoescape(("html",)))
    templates.filters.update(anchor=_anchor, num=_number, brief=_brief)

    def page(template: str, **context) -> HTMLResponse:
        html = templates.get_template(template).render(version=__version__, **context)
        return HTMLResponse(html, headers={"content-security-policy": PAGE_POLICY, "cache-control": "no-store"})

    async def state_of(request: Request) -> ProjectState:
        project = workspace.get(request.path_params["project_id"])
        if project is None:
            raise NoProject("no such project")
        return await runner.open(project)

    def project_route(handler):
        async def wrapped(request: Request):
            try:
                return await handler(request, await state_of(request))
            except NoProject as exc:
                return _error(404, str(exc))
            except DualcalError as exc:
                return _error(400, str(exc))
        return wrapped

    # -- pages
    async def index(request: Request):
        projects = [{"id": p.id, "name": (await runner.open(p)).name} for p in workspace.projects()]
        return page("index.html", projects=projects, url=phone_url)

    async def project_page(request: Request):
        try:
            state = await state_of(request)
        except NoProject:
            return HTMLResponse("no such project", status_code=404)
        return page("project.html", project=state.project, name=state.name, url=phone_url,
                    settings=state.settings, exports=EXPORTS)

    async def project_part(request: Request):
        try:
            state = await state_of(request)
        except NoProject:
            return HTMLResponse("no such project", status_code=404)
        described = describe(state)
        summary = state.summary or {}
        names = [ph["name"] for ph in described["photos"]]
        html = templates.get_template("part.html").render(
            p=described, s=summary, bars=_bars(described), advice_cards=_advice_cards(summary),
            exports=_exports(state.project.folder), labels=dict(zip(names, chart_labels(names, width=18))))
        return HTMLResponse(html, headers={"content-security-policy": PAGE_POLICY, "cache-control": "no-store"})

    # -- the API
    async def api_index(request: Request):
        return JSONResponse({"dualcal": __version__, "routes": __doc__.split("=\n", 1)[1].rsplit("\n=", 1)[0]})

    async def list_projects(request: Request):
        return JSONResponse({"projects": [{"id": p.id, "name": (await runner.open(p)).name}
                                          for p in workspace.projects()]})

    async def create_project(request: Request):
        try:
            doc = await _json_body(request)
            settings = await anyio.to_thread.run_sync(Settings.from_request, doc)
            project = await anyio.to_thread.run_sync(workspace.create, str(doc.get("name") or ""), settings)
        except DualcalError as exc:
            return _error(400, str(exc))
        await runner.open(project)
        return JSONResponse({"id": project.id}, status_code=201)

    @project_route
    async def get_project(request: Request, state: ProjectState):
        return JSONResponse(describe(state))

    @project_route
    async def get_result(request: Request, state: ProjectState):
        return JSONResponse({"version": state.version, "summary": state.summary, "files": state.results.get("files", {}),
                             "complete": state.results.get("complete")})

    @project_route
    async def events(request: Request, state: ProjectState):
        async def stream():
            yield "retry: 2000\n\n"
            while True:
                yield f"event: state\ndata: {json.dumps(describe(state))}\n\n"
                if not await state.wait(15):
                    yield ": still here\n\n"
                await asyncio.sleep(0.1)       # at most ten a second
        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"cache-control": "no-store", "x-accel-buffering": "no"})

    @project_route
    async def upload(request: Request, state: ProjectState):
        if state.settings is None:
            return _error(400, "this project has no board yet")
        state.project.photos_dir.mkdir(exist_ok=True)
        try:
            stream = PhotoStream(request.headers.get("content-type", ""), state.project.photos_dir,
                                 config.max_photo_bytes)
        except ValueError as exc:
            return _error(400, str(exc))
        added, skipped, renamed = [], [], []
        state.uploads += 1
        state.changed()
        try:
            async for chunk in request.stream():
                stream.feed(chunk)
                for part in stream.take():
                    await _land(state, part, added, skipped, renamed)
            stream.finish()
            for part in stream.take():
                await _land(state, part, added, skipped, renamed)
        except ValueError as exc:
            stream.abandon()
            return _error(413 if "files" in str(exc) else 400, str(exc))
        except BaseException:
            stream.abandon()
            raise
        finally:
            state.uploads -= 1
            runner.schedule(state)
            state.changed()
        return JSONResponse({"added": added, "skipped": skipped, "renamed": renamed, "version": state.version})

    async def _land(state: ProjectState, part, added, skipped, renamed) -> None:
        """Move a complete upload into photos/ under its safe name (module docstring of .uploads)."""
        if part.temp is None:
            skipped.append({"name": part.raw_name, "reason": part.problem})
            return
        name, problem = safe_photo_name(part.raw_name, part.kind)
        layout = state.project.layout()
        if name and layout and (layout == "cameras") != ("/" in name):
            problem = ("this project's photos are one folder (a camera roll): add photos without a folder"
                       if layout == "roll" else "this project's photos are in camera folders: add them as "
                                                "CAMERA/NAME (drop the dataset's folder)")
            name = None
        if name is None:
            part.temp.unlink(missing_ok=True)
            skipped.append({"name": part.raw_name, "reason": problem})
            return
        async with state.lock:
            final, same = await anyio.to_thread.run_sync(_place, state.project.photos_dir, part, name)
            if same is not None:
                skipped.append({"name": part.raw_name, "reason": f"already in the project as {same} (the same file)"})
                return
            added.append(final)
            if final != name or part.raw_name != name:
                renamed.append({"from": part.raw_name, "to": final})
            await runner.photo_added(state, final)

    @project_route
    async def use(request: Request, state: ProjectState):
        doc = await _json_body(request)
        photos = doc.get("photos")
        if not isinstance(photos, dict) or not all(isinstance(v, bool) for v in photos.values()):
            return _error(400, 'expected {"photos": {"NAME": true | false, ...}}')
        unknown = sorted(set(photos) - set(state.photos))
        if unknown:
            return _error(400, f"not photos of this project: {', '.join(unknown[:5])}")
        async with state.lock:
            if "version" in doc and doc["version"] != state.version:
                return JSONResponse({"error": f"the project changed (version {state.version}, the page had "
                                              f"{doc['version']}): reload it and try again", "version": state.version},
                                    status_code=409)
            left_out = (state.left_out - {n for n, used in photos.items() if used}) | \
                       {n for n, used in photos.items() if not used}
            if left_out != state.left_out:
                state.left_out = left_out
                state.version += 1
                await runner.save(state)
                runner.schedule(state)
                state.changed()
        return JSONResponse({"version": state.version})

    @project_route
    async def measure(request: Request, state: ProjectState):
        doc = await _json_body(request)
        if not (state.project.folder / "calib.json").exists():
            return _error(409, "there is no calibration yet")
        result = await anyio.to_thread.run_sync(_measure, state, doc)
        return JSONResponse(result)

    @project_route
    async def get_file(request: Request, state: ProjectState):
        name = request.path_params["name"]
        if name == "report.html" and (state.project.folder / "calib.json").is_file():
            await runner.report(state)
        path = _project_file(state, name)
        if path is None:
            return _error(404, f"{name}: no such file of this project (one of {', '.join(FILES)}, exports/...)")
        headers = {"cache-control": "no-store"}
        if request.query_params.get("download"):
            headers["content-disposition"] = f'attachment; filename="{Path(name).name}"'
        if path.suffix == ".html":
            headers["content-security-policy"] = FILE_POLICY
        media = {".json": "application/json", ".html": "text/html; charset=utf-8"}.get(path.suffix, "text/plain; charset=utf-8")
        return FileResponse(path, media_type=media, headers=headers)

    @project_route
    async def archive(request: Request, state: ProjectState):
        from starlette.background import BackgroundTask
        path = await anyio.to_thread.run_sync(_zip, state)
        return FileResponse(path, media_type="application/zip", filename=f"{state.project.id}.zip",
                            background=BackgroundTask(path.unlink, missing_ok=True))

    def photo_route(kind: str):
        @project_route
        async def serve(request: Request, state: ProjectState):
            name = request.path_params["name"]
            if name not in state.photos:
                return _error(404, "no such photo")
            path = state.project.photos_dir / name if kind == "photos" else state.project.preview(kind, name)
            if kind == "screen" and not path.is_file() and (state.project.photos_dir / name).is_file():
                from .work import write_screen_preview
                try:
                    path = await anyio.to_thread.run_sync(write_screen_preview, state.project, name)
                except Exception:             # a photo that cannot be decoded has no preview
                    return _error(404, "this photo cannot be shown")
            if not path.is_file():
                return _error(404, "not there yet")
            return FileResponse(path, media_type=None if kind == "photos" else "image/jpeg",
                                headers={"cache-control": "private, max-age=60"})
        return serve

    async def qr_svg(request: Request):
        import segno
        svg = segno.make(config.url or str(request.url_for("index")), error="m").svg_inline(scale=4, border=2)
        return Response(svg, media_type="image/svg+xml", headers={"cache-control": "no-store"})

    def describe(state: ProjectState) -> dict:
        """``GET /api/projects/{id}`` (CONTRACT.md, "app"), with added keys."""
        summary = state.summary or {}
        in_summary = summary.get("photos", {})
        roll_left = (summary.get("roll") or {}).get("left_out", {})
        photos = []
        for name in state.photos:
            det = state.detections.get(name, {})
            info = in_summary.get(name, {})
            status = info.get("status")
            if name in state.left_out:
                status = "left out"
            elif name in state.detecting:
                status = "detecting"
            elif Path(name).name in roll_left and status is None:
                status = f"not used: {roll_left[Path(name).name]}"
            elif det.get("found") is False:
                status = f"board not found: {det.get('reason', '')}"
            elif status is None:
                status = "new" if state.busy else "not used"
            photos.append({"name": name, "camera": info.get("camera"), "view": info.get("view"),
                           "found": det.get("found"), "used": name not in state.left_out,
                           "status": status, "rms_px": info.get("rms_px")})
        calibration = None
        if summary.get("verdict"):
            calibration = {"verdict": summary["verdict"], "ok": summary["ok"], "version": summary.get("version"),
                           "current": summary.get("version") == state.version, "rms_px": summary.get("rms_px")}
        return {"id": state.project.id, "name": state.name, "state": "busy" if state.busy else "idle",
                "version": state.version, "photos": photos, "calibration": calibration, "error": state.error,
                "settings": state.settings.to_dict() if state.settings else None,
                "flags": state.settings.flags() if state.settings else None,
                "work": {"uploads": state.uploads, "detecting": len(state.detecting),
                         "calibrating": state.job is not None},
                "files": sorted(n for n in FILES if (state.project.folder / n).is_file()
                                or (n == "report.html" and (state.project.folder / "calib.json").is_file()))}

    routes = [
        Route("/", index, name="index"),
        Route("/projects/{project_id}", project_page),
        Route("/projects/{project_id}/part", project_part),
        Route("/api", api_index),
        Route("/api/qr.svg", qr_svg),
        Route("/api/projects", list_projects, methods=["GET"]),
        Route("/api/projects", create_project, methods=["POST"]),
        Route("/api/projects/{project_id}", get_project),
        Route("/api/projects/{project_id}/events", events),
        Route("/api/projects/{project_id}/result", get_result),
        Route("/api/projects/{project_id}/photos", upload, methods=["POST"]),
        Route("/api/projects/{project_id}/use", use, methods=["POST"]),
        Route("/api/projects/{project_id}/measure", measure, methods=["POST"]),
        *measure_routes(page, project_route, _json_body, config.max_photo_bytes),
        Route("/api/projects/{project_id}/archive.zip", archive),
        Route("/api/projects/{project_id}/files/{name:path}", get_file),
        *(Route(f"/api/projects/{{project_id}}/{kind}/{{name:path}}", photo_route(kind))
          for kind in ("photos", "thumbs", "screen")),
        Mount("/static", StaticFiles(directory=HERE / "static"), name="static"),
    ]

    @contextlib.asynccontextmanager
    async def lifespan(app):
        runner.start()
        await runner.resume_all()
        yield
        runner.stop()

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.runner = runner
    return Guard(app, config.token, HostRule(config.host))


def _anchor(name: str) -> str:
    """A stable HTML id for a photo's name (any characters): a short digest."""
    import hashlib
    return hashlib.sha1(name.encode()).hexdigest()[:12]


def _brief(text, width: int = 44) -> str:
    """A status for a photo's card: cut at a word before ``width`` characters (the whole is in the list of photos
    left out, above the checks)."""
    text = str(text)
    if len(text) <= width:
        return text
    cut = text.rfind(" ", 0, width)
    return text[:cut if cut > width // 2 else width].rstrip(" :,(") + "…"


def _number(x) -> str:
    """A parameter or sigma for a table: 4 significant digits beyond the decimal point's need, "-" for none."""
    if x is None:
        return "-"
    x = float(x)
    if x == 0:
        return "0"
    magnitude = abs(x)
    digits = 2 if magnitude >= 100 else 3 if magnitude >= 1 else 4
    return f"{x:.{digits}f}" if magnitude >= 1e-3 else f"{x:.3g}"


def _bars(described: dict) -> list[dict]:
    """The per-photo chart: every photo with an RMS, used or left out, each labelled by what tells its name from
    the others' (:func:`.summary.chart_labels`)."""
    shown = [ph for ph in described["photos"] if ph["rms_px"] is not None]
    out = []
    for ph, label in zip(shown, chart_labels([ph["name"] for ph in shown])):
        kind = "left-out" if not ph["used"] else "dropped" if str(ph["status"]).startswith("dropped") else "kept"
        out.append({"photo": ph["name"], "label": label, "camera": ph["camera"], "rms": ph["rms_px"],
                    "used": ph["used"], "status_class": kind})
    return out


def _advice_cards(summary: dict) -> list[dict]:
    """Each advised pose with the board's outline drawn in every camera's frame (advise.html's drawing)."""
    import numpy as np

    from ..pages.report.advice import frame_svg

    advice = summary.get("advice")
    if not advice:
        return []
    sizes = summary.get("image_sizes", {})
    order = sorted(sizes, key=lambda n: n != summary.get("reference"))
    cards = []
    for i, pose in enumerate(advice["poses"], start=1):
        frames = [{"camera": n, "svg": frame_svg(tuple(sizes[n]), None if pose["outline_px"].get(n) is None
                                                 else np.asarray(pose["outline_px"][n], float), n, i, n in pose["cameras"])}
                  for n in order]
        cards.append({**pose, "frames": frames})
    return cards


def _exports(folder: Path) -> list[tuple[str, str]]:
    """``(format, file under exports/)`` of the exports written."""
    out = []
    for fmt, name in EXPORTS.items():
        path = folder / "exports" / name
        if path.is_dir():
            out += [(fmt, f"{name}/{p.name}") for p in sorted(path.iterdir()) if p.is_file() and not p.name.startswith(".")]
        elif path.is_file():
            out.append((fmt, name))
    return out


def _place(photos_dir: Path, part, name: str) -> tuple[str, str | None]:
    """Move an upload's temporary file to ``photos_dir/name`` atomically, never over another file: a file of
    the same content there -> ``(name, that name)`` and the upload is dropped; of other content ->
    ``NAME-2.EXT`` (then -3, ...)."""
    import hashlib

    target = photos_dir / name
    target.parent.mkdir(exist_ok=True)
    stem, suffix = target.stem, target.suffix
    n = 1
    while True:
        candidate = target if n == 1 else target.with_name(f"{stem}-{n}{suffix}")
        try:
            os.link(part.temp, candidate)          # fails where a file is: never replaces one
        except FileExistsError:
            digest = hashlib.sha256(candidate.read_bytes()).hexdigest()
            if digest == part.sha256:
                part.temp.unlink(missing_ok=True)
                return name, candidate.relative_to(photos_dir).as_posix()
            n += 1
            continue
        part.temp.unlink()
        fd = os.open(candidate.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        return candidate.relative_to(photos_dir).as_posix(), None


def _project_file(state: ProjectState, name: str) -> Path | None:
    folder = state.project.folder
    if name in FILES:
        path = folder / name
        return path if path.is_file() else None
    exports = (folder / "exports").resolve()
    path = (folder / name).resolve()
    if name.startswith("exports/") and exports in path.parents and path.is_file():
        return path
    return None


def _zip(state: ProjectState) -> Path:
    """Every file of the project (not the app's hidden folder) in a zip file, written to a temporary file."""
    import tempfile
    import zipfile

    folder = state.project.folder
    state.project.app_dir.mkdir(exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".archive-", suffix=".zip", dir=state.project.app_dir)
    os.close(fd)
    with zipfile.ZipFile(name, "w", zipfile.ZIP_DEFLATED) as z:
        for path in sorted(folder.rglob("*")):
            relative = path.relative_to(folder)
            if path.is_file() and not any(p.startswith(".") for p in relative.parts):
                z.write(path, f"{state.project.id}/{relative.as_posix()}",
                        compress_type=zipfile.ZIP_STORED if path.suffix.lower() in (".jpg", ".jpeg", ".heic")
                        else zipfile.ZIP_DEFLATED)
    return Path(name)


def _measure(state: ProjectState, doc: dict) -> dict:
    from ..estimation.measurement import measure
    from ..workflow import read_calibration

    rig = read_calibration(state.project.folder / "calib.json")
    points = {k: doc[k] for k in ("points", "lengths", "pixel_sigma") if k in doc}
    return measure(rig, points)
