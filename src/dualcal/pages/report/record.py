"""The measurement record (``dualcal measure ... --record record.html``): one self-contained HTML page to keep or send.

It holds what a measurement was and how far to trust it: the lengths with their sigmas, every point with its
coordinates and sigmas, the crops of each point in every photo (the tapped pixel, the match found with its
sigma along the epipolar line, which is drawn through the crop; a point given by hand in a photo marked as
such; a point that was not found, with the reason), the focus each photo's camera was taken at and where
that came from, the pixel noise assumed, and the calibration, points file and photos it was made from.
The crops show the same patch of the scene in every photo (a tele's is wider in pixels by its focal
length over the wide's), enlarged to :data:`CROP_PX` and embedded as JPEG data URIs, so the page is a
few hundred kilobytes; measure.json itself is embedded too (a ``<script type="application/json">``).
"""

from __future__ import annotations

import base64
from datetime import datetime

import cv2
import numpy as np

from ... import __version__
from ...estimation.matching import epipolar_curve
from ...geometry.model import RigModel
from .pick import script_json
from .templating import environment

__all__ = ["CROP_PX", "render_record", "point_crop"]

#: Size of a crop on the page, px.
CROP_PX = 200
#: Half-size of a crop in the camera of the smallest focal length, source px (others: scaled by focal length).
HALF_CROP_PX = 40
_TAP, _MATCH, _LINE, _HAND = (255, 212, 0), (0, 229, 255), (255, 80, 200), (120, 255, 120)     # RGB
_JPEG_QUALITY = 85


def _epipolar_segment(rig: RigModel, tapped: str, uv_tap, camera: str) -> np.ndarray:
    """(N, 2) the epipolar line of ``uv_tap`` (camera ``tapped``) in ``camera``'s pixels, from 50 mm to 100 m."""
    pose = rig.pose_from_reference(camera).compose(rig.pose_from_reference(tapped).inverse())
    uv = epipolar_curve(rig.cameras[tapped], rig.cameras[camera], pose, uv_tap, np.geomspace(50.0, 1e5, 600))
    return uv[np.all(np.isfinite(uv), axis=1)]


def point_crop(image: np.ndarray, centre_uv, half_px: float, marks: list[tuple], line: np.ndarray | None = None,
               size_px: int = CROP_PX) -> np.ndarray:
    """An RGB crop (size, size, 3) of a grey ``image`` around ``centre_uv``, ``half_px`` source pixels each way,
    enlarged, with ``marks`` drawn (``(uv, colour, kind)``, ``kind`` ``"cross"`` or ``"ring"``; a ring's radius
    is ``uv``'s fourth value when given) and the polyline ``line`` (source pixels) through it.

    Source pixel ``(u, v)`` lands at ``(u - u0) s`` of the crop, ``u0 = centre - half``, ``s = size / (2 half)``
    (pixel centres: the crop spans the source's ``[u0 - 0.5, u0 + 2 half - 0.5]``, resampled by OpenCV's affine
    warp)."""
    s = size_px / (2.0 * half_px)
    u0, v0 = np.asarray(centre_uv, float) - half_px
    M = np.array([[s, 0.0, -(u0 - 0.5) * s - 0.5], [0.0, s, -(v0 - 0.5) * s - 0.5]])
    crop = cv2.warpAffine(np.ascontiguousarray(image), M, (size_px, size_px), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=40)
    rgb = np.ascontiguousarray(np.repeat(crop[:, :, None], 3, axis=2))

    def at(uv):
        return (np.asarray(uv, float)[..., :2] - [u0 - 0.5, v0 - 0.5]) * s - 0.5

    shift = 4                                              # sub-pixel drawing: coordinates x 16
    if line is not None and len(line) > 1:
        pts = np.rint(at(line) * (1 << shift)).astype(np.int32)
        cv2.polylines(rgb, [pts], False, _LINE, 1, cv2.LINE_AA, shift)
    for uv, colour, kind in marks:
        x, y = np.rint(at(uv) * (1 << shift)).astype(int)
        r = 9 << shift
        if kind == "cross":
            for dx, dy in ((r, 0), (0, r)):
                cv2.line(rgb, (x - dx, y - dy), (x + dx, y + dy), (0, 0, 0), 3, cv2.LINE_AA, shift)
                cv2.line(rgb, (x - dx, y - dy), (x + dx, y + dy), colour, 1, cv2.LINE_AA, shift)
        else:
            radius = int(max(uv[3] * s if len(uv) > 3 else 0.0, 6.0) * (1 << shift))
            cv2.circle(rgb, (x, y), radius, (0, 0, 0), 3, cv2.LINE_AA, shift)
            cv2.circle(rgb, (x, y), radius, colour, 1, cv2.LINE_AA, shift)
    return rgb


def _data_uri(rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, _JPEG_QUALITY])
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _point_crops(rig: RigModel, name: str, given: dict, point: dict | None, missed: dict,
                 images: dict[str, np.ndarray]) -> list[dict]:
    """Each photo's crop of point ``name``: ``given`` its pixels as points.json has them, ``point`` its entry in
    measure.json (None: not measured), ``missed`` ``{camera: reason}`` where it was not found."""
    f_min = min(min(rig.cameras[c].fx, rig.cameras[c].fy) for c in images)
    matched = (point or {}).get("matched", {})
    tapped = next(iter(given)) if len(given) == 1 else None
    crops = []
    for camera, image in images.items():
        cam = rig.cameras[camera]
        half = HALF_CROP_PX * min(cam.fx, cam.fy) / f_min
        if camera in given:
            uv, kind = given[camera], ("tap" if tapped else "hand")
            marks = [(uv, _TAP if tapped else _HAND, "cross")]
            note = "tapped" if tapped else "given by hand"
            line = None
        elif camera in matched:
            m = matched[camera]
            uv, kind = m["uv"], "match"
            marks = [((*m["uv"], 0.0, 2.0 * m["sigma_px"]), _MATCH, "ring"), (m["uv"], _MATCH, "cross")]
            note = f"found: +-{m['sigma_px']:.2f} px along the line, score {m['score']:.3f}"
            line = _epipolar_segment(rig, tapped, given[tapped], camera)
        else:
            if tapped is None or camera not in missed:
                continue
            line = _epipolar_segment(rig, tapped, given[tapped], camera)
            inside = line[np.all((line >= 0) & (line <= np.asarray(cam.image_size) - 1), axis=1)]
            if not len(inside):
                crops.append({"camera": camera, "src": None, "note": f"not found: {missed[camera]}", "kind": "missed"})
                continue
            uv, kind, marks = inside[len(inside) // 2], "missed", []
            note = f"not found: {missed[camera]} (the epipolar line drawn)"
        crops.append({"camera": camera, "kind": kind, "note": note, "uv": [float(uv[0]), float(uv[1])],
                      "src": _data_uri(point_crop(image, uv, half, marks, line))})
    return crops


def render_record(rig: RigModel, doc: dict, images: dict[str, np.ndarray], photo_names: dict[str, str],
                  given: dict, points_name: str = "points.json", calib_name: str = "calib.json",
                  taken: datetime | None = None) -> str:
    """The measurement record (module docstring) as one HTML string.

    Parameters
    ----------
    rig : RigModel
        The calibration measured with.
    doc : dict
        The measurement, measure.json's content (:func:`dualcal.estimation.measurement.measure`).
    images : dict
        ``{camera: (H, W) grey image}``: the instant's photos (empty: a record without crops).
    photo_names : dict
        ``{camera: file name}`` of those photos.
    given : dict
        ``{point: {camera: (2,) uv}}``: the points as points.json gave them.
    points_name, calib_name : str
        The names of the files measured from, as the record states them.
    taken : datetime or None
        When the measurement was made (default: now).

    Returns
    -------
    str
        The page.
    """
    missed = doc.get("unmatched", {})
    points = []
    for name, seen in given.items():
        p = doc["points"].get(name)
        points.append({"name": name, "measured": p is not None, "p": p,
                       "missed": missed.get(name, {}),
                       "crops": _point_crops(rig, name, seen, p, missed.get(name, {}), images) if images else []})
    cameras = [{"name": c, "photo": photo_names.get(c), **doc.get("cameras", {}).get(c, {})}
               for c in rig.camera_order() if c in images or c in doc.get("cameras", {})]
    names = ", ".join(f"{L['from']}-{L['to']}" for L in doc["lengths"]) or "points"
    return environment().get_template("record.html").render(
        title=f"Measurement record: {names}",
        version=__version__, doc=doc, points=points, cameras=cameras, calib_name=calib_name,
        points_name=points_name, taken=(taken or datetime.now()).strftime("%Y-%m-%d %H:%M"),
        reference=rig.reference, square_mm=rig.board.square_mm,
        square_sigma_mm=rig.board.square_sigma_mm, doc_json=script_json(doc))
