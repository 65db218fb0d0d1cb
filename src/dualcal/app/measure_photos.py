"""The app's measurement with photos of an object (not calibration photos; the calibration is the project's).

A page (``/projects/{id}/measure``, ``templates/measure.html`` and ``static/measure.js``) where a person adds one
photo per camera of the object, taken at one instant, taps a point in one photo and sees the epipolar line in the
others, the point found there (which they can move), a magnifier at full resolution where they tap, and the
lengths between the points with their sigmas; the measurement record downloads as one HTML page. The photos are
kept in the project's ``measure/`` folder, one per camera (a new one replaces it), never among the calibration's.
The routes (listed with the others by ``GET /api``):

=======  ==============================================  =======================================================
GET      /projects/{id}/measure                          the page
GET      /api/projects/{id}/measure/state                the cameras (size, whether a photo is there, its focus)
PUT      /api/projects/{id}/measure/photos/{camera}      the body is the photo of that camera -> its size, focus
GET      /api/projects/{id}/measure/photos/{camera}      that photo reduced for the screen (JPEG)
GET      /api/projects/{id}/measure/crop/{camera}?u&v&r  a full-resolution crop of it, ``2 r + 1`` px around (u, v)
POST     /api/projects/{id}/measure/match                ``{"camera", "uv"}`` -> the epipolar line and the match in
                                                         every other photo
POST     /api/projects/{id}/measure/points               a points.json -> measure.json's content, from these photos
POST     /api/projects/{id}/measure/record               a points.json -> the measurement record (HTML)
=======  ==============================================  =======================================================
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import anyio
import numpy as np
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route

from ..errors import InputError
from .uploads import KINDS, photo_kind

__all__ = ["MEASURE_DIR", "measure_routes"]

#: The project's folder of measurement photos.
MEASURE_DIR = "measure"
#: Long side of a photo as the page shows it, px.
DISPLAY_MAX_PX = 1600
#: Largest half-size of a crop, px.
MAX_CROP_RADIUS = 200
#: Distances along a tapped ray at which its epipolar line is drawn, mm.
EPIPOLAR_MM = np.geomspace(50.0, 1e5, 160)


class _Photos:
    """A project's measurement photos and calibration, read once per file version (its modification time)."""

    def __init__(self):
        self._gray: dict[Path, tuple[float, np.ndarray]] = {}
        self._rig: dict[Path, tuple[float, object]] = {}

    def rig(self, folder: Path):
        from ..workflow import read_calibration

        path = folder / "calib.json"
        if not path.is_file():
            raise InputError("this project has no calibration yet: calibrate first, then measure")
        stamp = path.stat().st_mtime
        if self._rig.get(path, (None,))[0] != stamp:
            self._rig[path] = (stamp, read_calibration(path))
        return self._rig[path][1]

    @staticmethod
    def path(folder: Path, camera: str) -> Path | None:
        found = sorted(p for p in (folder / MEASURE_DIR).glob(f"{camera}.*") if p.suffix.lower() in _SUFFIXES)
        return found[0] if found else None

    def gray(self, path: Path) -> np.ndarray:
        from ..files.photos import read_gray

        stamp = path.stat().st_mtime
        if self._gray.get(path, (None,))[0] != stamp:
            self._gray[path] = (stamp, read_gray(path))
        return self._gray[path][1]

    def instant(self, folder: Path, rig) -> tuple[dict, dict]:
        """``({camera: grey image}, {camera: focus its metadata states})`` of the photos there are."""
        from ..files.photos import read_focus

        paths = {c: self.path(folder, c) for c in rig.camera_order()}
        paths = {c: p for c, p in paths.items() if p is not None}
        return {c: self.gray(p) for c, p in paths.items()}, {c: read_focus(p).focus_m for c, p in paths.items()}


_SUFFIXES = {s for suffixes in KINDS.values() for s in suffixes}
_NO_PHOTO = JSONResponse({"error": "no photo of this camera yet"}, status_code=404)


def _camera(request: Request, rig) -> str:
    camera = request.path_params["camera"]
    if camera not in rig.cameras:
        raise InputError(f"camera {camera!r} is not in the calibration (cameras: {', '.join(rig.camera_order())})")
    return camera


def _jpeg(gray: np.ndarray, quality: int = 85) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return buf.tobytes()


def measure_routes(page, project_route, json_body, max_photo_bytes: int) -> list[Route]:
    """The routes of the module docstring; ``page(template, **context)`` renders a page, ``project_route`` wraps a
    handler ``(request, state)`` with the project and the errors' answers, ``json_body`` reads a request's JSON."""
    photos = _Photos()

    @project_route
    async def measure_page(request: Request, state):
        return page("measure.html", project=state.project, name=state.name)

    def state_doc(state) -> dict:
        from ..files.photos import read_exif, read_focus

        folder = state.project.folder
        rig = photos.rig(folder)
        cameras = {}
        for c in rig.camera_order():
            path = photos.path(folder, c)
            cameras[c] = {"size": list(rig.cameras[c].image_size), "photo": path is not None,
                          "file": path.name if path else None,
                          "focus_m": read_focus(path).focus_m if path else None,
                          "stored_size": list(read_exif(path)[0]) if path else None}
        return {"reference": rig.reference, "cameras": cameras}

    @project_route
    async def get_state(request: Request, state):
        return JSONResponse(await anyio.to_thread.run_sync(state_doc, state))

    @project_route
    async def put_photo(request: Request, state):
        folder = state.project.folder
        rig = await anyio.to_thread.run_sync(photos.rig, folder)
        camera = _camera(request, rig)
        (folder / MEASURE_DIR).mkdir(exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=".upload-", dir=folder / MEASURE_DIR)
        temp, size, head = Path(name), 0, b""
        try:
            with os.fdopen(fd, "wb") as out:
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > max_photo_bytes:
                        raise InputError(f"the photo is larger than {max_photo_bytes / 1e6:.0f} MB")
                    head = (head + chunk)[:16] if len(head) < 16 else head
                    out.write(chunk)
            kind = photo_kind(head)
            if kind is None:
                raise InputError("that file is not a photo (JPEG, PNG, TIFF, DNG or HEIC)")
            suffix = KINDS[kind][0]
            target = folder / MEASURE_DIR / f"{camera}{suffix}"
            await anyio.to_thread.run_sync(_check_size, temp, rig.cameras[camera], camera)
            for old in (folder / MEASURE_DIR).glob(f"{camera}.*"):
                old.unlink()
            os.replace(temp, target)
        finally:
            temp.unlink(missing_ok=True)
        return JSONResponse(await anyio.to_thread.run_sync(state_doc, state))

    async def photo_of(request: Request, state) -> Path | None:
        """The measurement photo of the camera the route names (None: none yet)."""
        rig = await anyio.to_thread.run_sync(photos.rig, state.project.folder)
        return photos.path(state.project.folder, _camera(request, rig))

    @project_route
    async def get_photo(request: Request, state):
        path = await photo_of(request, state)
        if path is None:
            return _NO_PHOTO

        def screen() -> bytes:
            import cv2

            gray = photos.gray(path)
            scale = min(1.0, DISPLAY_MAX_PX / max(gray.shape))
            small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else gray
            return _jpeg(small)

        return Response(await anyio.to_thread.run_sync(screen), media_type="image/jpeg",
                        headers={"cache-control": "no-store"})

    @project_route
    async def crop(request: Request, state):
        path = await photo_of(request, state)
        if path is None:
            return _NO_PHOTO
        try:
            u, v = float(request.query_params["u"]), float(request.query_params["v"])
            r = int(request.query_params.get("r", 40))
        except (KeyError, ValueError):
            raise InputError("a crop needs u, v (px) and r (its half-size, px)") from None
        if not (np.isfinite(u) and np.isfinite(v) and 1 <= r <= MAX_CROP_RADIUS):
            raise InputError(f"a crop needs finite u, v and 1 <= r <= {MAX_CROP_RADIUS}")

        def cut() -> bytes:
            gray = photos.gray(path)
            i0, j0 = int(round(v)) - r, int(round(u)) - r
            out = np.full((2 * r + 1, 2 * r + 1), 40, np.uint8)
            h, w = gray.shape
            a0, b0 = max(i0, 0), max(j0, 0)
            a1, b1 = min(i0 + 2 * r + 1, h), min(j0 + 2 * r + 1, w)
            if a1 > a0 and b1 > b0:
                out[a0 - i0:a1 - i0, b0 - j0:b1 - j0] = gray[a0:a1, b0:b1]
            return _jpeg(out, 92)

        return Response(await anyio.to_thread.run_sync(cut), media_type="image/jpeg",
                        headers={"cache-control": "no-store"})

    def match_doc(state, body: dict) -> dict:
        from ..estimation.matching import epipolar_curve, match_point
        from ..estimation.measurement import match_to_dict

        folder = state.project.folder
        rig = photos.rig(folder)
        camera, uv = body.get("camera"), body.get("uv")
        if camera not in rig.cameras or camera != rig.reference and camera not in rig.rig:
            raise InputError(f"camera {camera!r} is not a camera of the calibrated rig")
        try:
            uv = np.asarray(uv, float).reshape(2)
        except (TypeError, ValueError):
            raise InputError("uv: expected two numbers [u, v]") from None
        images, _ = photos.instant(folder, rig)
        if camera not in images:
            raise InputError(f"there is no photo of {camera!r} yet")
        out = {"epipolar": {}, "matched": {}, "unmatched": {}}
        pose_a = rig.pose_from_reference(camera)
        for other in rig.camera_order():
            if other == camera or (other != rig.reference and other not in rig.rig):
                continue
            pose_ab = rig.pose_from_reference(other).compose(pose_a.inverse())
            line = epipolar_curve(rig.cameras[camera], rig.cameras[other], pose_ab, uv, EPIPOLAR_MM)
            out["epipolar"][other] = [None if not np.all(np.isfinite(p)) else p.tolist() for p in line]
            if other not in images:
                out["unmatched"][other] = "no photo yet"
                continue
            m = match_point(images[camera], rig.cameras[camera], images[other], rig.cameras[other], pose_ab, uv)
            if m.ok:
                out["matched"][other] = match_to_dict(m)
            else:
                out["unmatched"][other] = m.reason
        return out

    @project_route
    async def match(request: Request, state):
        body = await json_body(request)
        return JSONResponse(await anyio.to_thread.run_sync(match_doc, state, body))

    def measured(state, body: dict) -> tuple:
        from ..estimation.measurement import measure

        folder = state.project.folder
        rig = photos.rig(folder)
        images, focus = photos.instant(folder, rig)
        points = {k: body[k] for k in ("points", "lengths", "pixel_sigma") if k in body}
        return rig, measure(rig, points, images, focus), images, points

    @project_route
    async def measure_points(request: Request, state):
        body = await json_body(request)
        _, doc, _, _ = await anyio.to_thread.run_sync(measured, state, body)
        return JSONResponse(doc)

    @project_route
    async def record(request: Request, state):
        from ..estimation.measurement import points_from_dict
        from ..pages.report.record import render_record

        body = await json_body(request)

        def page_html() -> str:
            rig, doc, images, points = measured(state, body)
            names = {c: p.name for c in images if (p := photos.path(state.project.folder, c)) is not None}
            given = points_from_dict(points, "points", single_camera=True)["points"]
            return render_record(rig, doc, images, names, given, "the points tapped in the app", "calib.json")

        html = await anyio.to_thread.run_sync(page_html)
        return HTMLResponse(html, headers={"content-disposition": 'attachment; filename="record.html"',
                                           "cache-control": "no-store",
                                           "content-security-policy": "sandbox; default-src 'none'; "
                                                                      "img-src data:; style-src 'unsafe-inline'"})

    base = "/api/projects/{project_id}/measure"
    return [Route("/projects/{project_id}/measure", measure_page),
            Route(base + "/state", get_state),
            Route(base + "/photos/{camera}", put_photo, methods=["PUT"]),
            Route(base + "/photos/{camera}", get_photo, methods=["GET"]),
            Route(base + "/crop/{camera}", crop),
            Route(base + "/match", match, methods=["POST"]),
            Route(base + "/points", measure_points, methods=["POST"]),
            Route(base + "/record", record, methods=["POST"])]


def _check_size(path: Path, cam, camera: str) -> None:
    """The photo must be its camera's as stored (the size it was calibrated at)."""
    from ..files.photos import read_exif

    size, _ = read_exif(path)
    if tuple(size) != tuple(cam.image_size):
        w, h = cam.image_size
        raise InputError(f"the {camera} photo is {size[0]}x{size[1]} px, but that camera was calibrated at {w}x{h} px: "
                         "give the photo as the phone stored it (not resized or turned)")
