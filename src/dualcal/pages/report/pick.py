"""The page on which to click the points to measure (``dualcal measure --pick``).

One self-contained HTML file (no network): the photos of one instant, one per camera, embedded as
JPEGs reduced to at most :data:`DISPLAY_MAX_PX` on their long side for display. Every click is
mapped back to the photo's full resolution in its stored frame (as corners are: the EXIF
orientation is not applied, contract "Input"), with the pixel-centre convention of the contract:
the displayed image spans the stored pixels' extent ``[-0.5, W - 0.5]`` (pixel ``j``'s centre at
``u = j``), so a click at ``x`` of a displayed width ``w`` is ``u = x W / w - 0.5``. The page zooms
(buttons, mouse wheel) so that a click can be placed more finely than one displayed pixel; points
are named (the same name clicked in two or more photos makes a point), lengths join two named
points, and "Export points.json" downloads the contract's points.json ("measure").
"""

from __future__ import annotations

import base64
import io
import json
from pathlib import Path

from markupsafe import Markup
from PIL import Image

from ... import __version__
from ...files.photos import open_image
from ...errors import InputError
from ...geometry.model import RigModel
from .templating import environment

#: Long side of a photo as embedded in the page, px (clicks are mapped back to full resolution).
DISPLAY_MAX_PX = 2048
_JPEG_QUALITY = 88


def display_jpeg(img: Image.Image, max_px: int = DISPLAY_MAX_PX) -> tuple[bytes, tuple[int, int]]:
    """The photo reduced so that its long side is at most ``max_px``, as JPEG bytes, and its size (w, h).

    The reduction maps the photo's whole extent onto the reduced one (Pillow's convention), which
    is what the page's click mapping assumes.
    """
    rgb = img.convert("RGB")
    scale = min(1.0, max_px / max(rgb.size))
    if scale < 1.0:
        rgb = rgb.resize((max(1, round(rgb.width * scale)), max(1, round(rgb.height * scale))),
                         Image.Resampling.LANCZOS)
    buf = io.BytesIO()
    rgb.save(buf, "JPEG", quality=_JPEG_QUALITY)
    return buf.getvalue(), rgb.size


def pick_photos(rig: RigModel, photos: dict[str, Path], max_px: int = DISPLAY_MAX_PX) -> list[dict]:
    """Each photo as the page needs it: camera, file name, full size, displayed size, JPEG data URL.

    Raises
    ------
    InputError
        A camera the calibration does not have, or a photo whose size is not its camera's
        (another camera's photo, or a resized one: its pixels would not be the calibration's).
    """
    unknown = [name for name in photos if name not in rig.cameras]
    if unknown:
        raise InputError(f"camera {unknown[0]!r} is not in the calibration (cameras: {', '.join(rig.camera_order())})")
    out = []
    for name, path in photos.items():
        with open_image(path) as img:
            size = img.size
            if tuple(size) != tuple(rig.cameras[name].image_size):
                w, h = rig.cameras[name].image_size
                raise InputError(f"{path}: {size[0]}x{size[1]} px, but camera {name!r} was calibrated at {w}x{h} px: "
                                 "give that camera's photo as it was stored (not resized or turned)")
            data, shown = display_jpeg(img, max_px)
        out.append({"camera": name, "file": Path(path).name, "size": list(size), "shown": list(shown),
                    "src": "data:image/jpeg;base64," + base64.b64encode(data).decode("ascii")})
    return out


def render_pick_page(rig: RigModel, photos: dict[str, Path], max_px: int = DISPLAY_MAX_PX) -> str:
    """The pick page (module docstring) for ``photos`` ``{camera: path}`` of one instant, as one HTML string."""
    env = environment()
    shown = pick_photos(rig, photos, max_px)
    data = [{k: p[k] for k in ("camera", "file", "size")} for p in shown]
    return env.get_template("pick.html").render(
        title=f"dualcal measure: pick points in {' + '.join(p['camera'] for p in shown)}",
        version=__version__, photos=shown, reference=rig.reference, photos_json=script_json(data))


def script_json(value) -> Markup:
    """``value`` as JSON to embed in a ``<script type="application/json">``: every ``<`` (and ``>``, ``&``)
    written as its ``\\u`` escape, so that no name (``</script>``, ``<!--<script``) can end or change the
    script element; ``JSON.parse`` reads the same value back."""
    text = json.dumps(value, ensure_ascii=False)
    return Markup(text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))
