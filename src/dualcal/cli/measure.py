"""``dualcal measure``: points and lengths from one instant's photos, each with its 1-sigma; ``--pick``
writes the page on which to click the points."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from . import cli
from .common import echo, table_console


def _photos(specs: tuple[str, ...]) -> dict[str, Path]:
    """``("wide=a.jpg", "tele=b.jpg")`` -> ``{"wide": Path("a.jpg"), "tele": Path("b.jpg")}``: the photos of one
    instant, positional ``NAME=IMAGE`` and ``--photo CAMERA=PATH`` alike."""
    from ..files.dataset import parse_camera_spec

    photos = {}
    for spec in specs:
        if "=" not in spec:
            raise InputError(f"{spec!r}: give each photo as NAME=IMAGE, the camera's name in calib.json, "
                             "e.g. wide=IMG_01.jpg")
        name, image = parse_camera_spec(spec)
        if name in photos:
            raise InputError(f"the photos name camera {name!r} twice: give one photo of each camera, taken at one "
                             "instant")
        photos[name] = Path(image)
    return photos


def lengths_table(doc: dict):
    """measure.json's lengths as a rich table: length +- sigma, sigma in % of the length."""
    from rich.table import Table

    table = Table(title="Lengths (mm, +- one standard deviation)",
                  caption="sigma from the calibration's uncertainty and the pixel noise together")
    for col in ("Length", "mm", "+- sigma", "sigma %", "Note"):
        table.add_column(col, justify="left" if col in ("Length", "Note") else "right")
    for L in doc["lengths"]:
        table.add_row(f"{L['from']}-{L['to']}", f"{L['length_mm']:.2f}", f"{L['sigma_mm']:.2f}",
                      f"{L['sigma_percent']:.2f}", "not meaningful (see the warning)" if L["meaningless"] else "")
    return table


def points_table(doc: dict):
    """measure.json's points as a rich table: X, Y, Z and their sigmas in the reference camera's frame."""
    from rich.table import Table

    table = Table(title=f"Points (mm, in the {doc['frame']} camera's frame: x right, y down, z forward)")
    for col in ("Point", "X", "Y", "Z", "+- X", "+- Y", "+- Z", "Distance", "Cameras"):
        table.add_column(col, justify="left" if col in ("Point", "Cameras") else "right")
    for name, p in doc["points"].items():
        table.add_row(name, *(f"{x:.2f}" for x in p["xyz_mm"]), *(f"{s:.2f}" for s in p["sigma_mm"]),
                      f"{p['distance_mm']:.1f}", "+".join(p["cameras"]))
    return table


def matches_table(doc: dict):
    """measure.json's matched points: where each tap was found, its sigma along the epipolar line and its score;
    the points not found, and why. None when no point was matched or left unmatched."""
    from rich.table import Table

    rows = [(name, cam, f"{m['uv'][0]:.1f}, {m['uv'][1]:.1f}", f"{m['sigma_px']:.3f}", f"{m['score']:.3f}", "")
            for name, p in doc["points"].items() for cam, m in p.get("matched", {}).items()]
    rows += [(name, cam, "-", "-", "-", reason) for name, missed in doc.get("unmatched", {}).items()
             for cam, reason in missed.items()]
    if not rows:
        return None
    table = Table(title="Taps found in the other photos (along the epipolar line)",
                  caption="sigma: px along the epipolar line; score: normalised cross-correlation (1 = identical)")
    for col in ("Point", "Camera", "Pixel (u, v)", "sigma px", "score", "Not found"):
        table.add_column(col, justify="right" if col in ("sigma px", "score") else "left")
    for row in rows:
        table.add_row(*row)
    return table


def _read_photos(photos: dict[str, Path]) -> tuple[dict, dict]:
    """The photos as grey arrays and the focus distance each one's metadata states (None: none)."""
    from ..files.photos import read_focus, read_gray

    return ({name: read_gray(path) for name, path in photos.items()},
            {name: read_focus(path).focus_m for name, path in photos.items()})


@cli.command("measure")
@click.argument("calib", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("photo_specs", nargs=-1, metavar="[NAME=IMAGE]...")
@click.option("--points", "points_path", type=click.Path(dir_okay=False, path_type=Path), metavar="points.json",
              help="The points' pixels in two or more cameras of one instant (or, with the photos, in one), and "
                   "the lengths to measure.")
@click.option("--photo", "photo_options", multiple=True, metavar="CAMERA=PATH",
              help="A photo of the instant the points are in, one per camera (the same as NAME=IMAGE): a point "
                   "given in one camera only is found in the others along its epipolar line.")
@click.option("--record", "record_path", type=click.Path(dir_okay=False, path_type=Path), metavar="record.html",
              help="Also write the measurement record: the lengths with their sigmas, each point's crops in every "
                   "photo with the match drawn, the focus used; one self-contained HTML page to keep or send.")
@click.option("--min-distance", "min_distance_mm", type=click.FloatRange(min=1.0), default=None, metavar="MM",
              help="The nearest distance from the camera a tapped point is searched at, mm (default 100).")
@click.option("--pick", is_flag=True,
              help="Write the page on which to click the points in the photos NAME=IMAGE (one per camera, "
                   "taken at one instant); it exports points.json.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="measure.json to write (with --pick: the HTML page).")
@click.option("--open", "open_page", is_flag=True, help="With --pick: open the page in the web browser.")
def measure_command(calib: Path, photo_specs: tuple[str, ...], points_path: Path | None, photo_options: tuple[str, ...],
                    record_path: Path | None, min_distance_mm: float, pick: bool, output: Path, open_page: bool) -> None:
    """Measure points and lengths with the calibrated rig, each with its 1-sigma.

    \b
    dualcal measure calib.json --pick wide=IMG_01.jpg tele=IMG_01.jpg -o pick.html
    dualcal measure calib.json --points points.json -o measure.json
    dualcal measure calib.json --points points.json --photo wide=W.jpg --photo tele=T.jpg -o measure.json

    With the instant's photos (--photo CAMERA=PATH, or NAME=IMAGE), a point given in one camera
    only is found in the other photos along its epipolar line, to a fraction of a pixel, with its
    own sigma; a point that cannot be found (no texture, a repeated pattern, hidden, off the
    photo) is said so and not measured. Each photo's focus distance is read from its metadata.

    Each point is intersected from its pixels in two or more photos of one instant, in the
    reference camera's frame (mm). Its sigma, and each length's, comes from the calibration's
    uncertainty (every parameter of the cameras involved and of the rig, correlations kept) and
    the pixel noise (points.json's pixel_sigma, px per coordinate; default each camera's noise in
    the calibration). A length whose sigma is large, or whose end points' depth is too uncertain
    for a linear sigma to hold, gets a warning saying what would help.
    """
    from ..files.io import check_output_file, load_rig

    if pick == (points_path is not None):
        raise InputError("give either --points points.json (to measure) or --pick NAME=IMAGE NAME2=IMAGE2 "
                         "(to write the page on which to click the points)")
    if record_path is not None and pick:
        raise InputError("--record writes the record of a measurement: give it with --points, not --pick")
    check_output_file(output)
    if record_path is not None:
        check_output_file(record_path)
    photos = _photos(photo_specs + photo_options)
    rig = load_rig(calib)
    if pick:
        _write_pick_page(rig, photos, output, open_page)
        return
    from ..files.io import load_points, write_json_atomic, write_text_atomic
    from ..estimation.measurement import measure

    points = load_points(points_path, single_camera=bool(photos))
    images, focus = _read_photos(photos)
    doc = measure(rig, points, images, focus, **({} if min_distance_mm is None else {"min_distance_mm": min_distance_mm}))
    write_json_atomic(output, doc)
    if record_path is not None:
        from ..pages.report.record import render_record

        write_text_atomic(record_path, render_record(rig, doc, images, {c: p.name for c, p in photos.items()},
                                                    points["points"], points_path.name, calib.name))
    console = table_console()
    console.print(points_table(doc))
    if doc["lengths"]:
        console.print(lengths_table(doc))
    matched = matches_table(doc)
    if matched is not None:
        console.print(matched)
    if photos:
        console.print("focus: " + ", ".join(
            f"{c} {f['focus_m']:.2f} m ({f['focus_from']})" if f["focus_m"] is not None else f"{c} unknown"
            for c, f in doc["cameras"].items()))
    if record_path is not None:
        console.print(f"wrote the record {record_path}")
    noise = ", ".join(f"{c} {s:.3g} px" for c, s in doc["pixel_sigma"].items())
    source = "points.json" if doc["pixel_sigma_source"] == "points.json" else "each camera's own in the calibration"
    console.print(f"pixel noise per coordinate: {noise} ({source}); wrote {output}")
    board = rig.board
    if board.square_sigma_mm:
        console.print(f"every sigma includes the printed squares' tolerance, +-{board.square_sigma_mm:g} mm in "
                      f"{board.square_mm:g} mm ({100 * board.square_sigma_mm / board.square_mm:.2g} % of each length)")
    else:
        console.print(f"lengths assume the printed squares are exactly {board.square_mm:g} mm (calibrate with "
                      "--square-sigma MM to include their tolerance)")


def _write_pick_page(rig, photos: dict[str, Path], output: Path, open_page: bool) -> None:
    from ..files.io import write_text_atomic
    from ..pages.report.pick import render_pick_page

    if len(photos) < 2:
        raise InputError("--pick needs the photos of two or more cameras of one instant: NAME=IMAGE NAME2=IMAGE2")
    write_text_atomic(output, render_pick_page(rig, photos))
    echo(f"wrote {output}: open it in a browser, click each point in every photo (the same name in each), "
         f"export points.json, then: dualcal measure CALIB --points points.json -o measure.json")
    if open_page:
        import webbrowser
        webbrowser.open(output.resolve().as_uri())
