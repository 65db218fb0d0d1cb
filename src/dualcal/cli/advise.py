"""``dualcal advise``: which board poses to photograph next (or first, with ``--plan``)."""

from __future__ import annotations

from pathlib import Path

import click

from . import cli
from .common import board_from_flags, board_options, echo


def _goals(values) -> dict[str, float]:
    from ..errors import InputError
    out = {}
    for item in values:
        name, sep, sigma = item.partition("=")
        try:
            out[name.strip()] = float(sigma)
        except ValueError:
            raise InputError(f"--target {item!r}: expected NAME=SIGMA, e.g. tele.fx=2.5") from None
        if not sep or not name.strip():
            raise InputError(f"--target {item!r}: expected NAME=SIGMA, e.g. tele.fx=2.5")
    return out


def _plan_camera(item: str):
    """``NAME=WxH:FOCAL35MM`` or ``NAME=PHOTO`` (its image size and 35 mm focal length from EXIF)."""
    from ..estimation.advise import nominal_camera
    from ..errors import InputError
    name, sep, spec = item.partition("=")
    if not sep or not name:
        raise InputError(f"--camera {item!r}: expected NAME=WxH:FOCAL35MM (e.g. wide=4032x3024:26) or NAME=PHOTO")
    size, colon, focal = spec.rpartition(":")
    if colon and "x" in size:
        try:
            w, h = (int(x) for x in size.lower().split("x"))
            f35 = float(focal)
        except ValueError:
            raise InputError(f"--camera {item!r}: expected NAME=WxH:FOCAL35MM, e.g. wide=4032x3024:26") from None
    else:
        from ..files.photos import read_exif
        if not Path(spec).is_file():
            raise InputError(f"--camera {item!r}: {spec!r} is neither WxH:FOCAL35MM nor a photo")
        (w, h), exif = read_exif(spec)
        f35 = exif.get("focal_length_35mm_mm")
        if not f35:
            raise InputError(f"--camera {item!r}: the photo's EXIF has no 35 mm-equivalent focal length; "
                             "give NAME=WxH:FOCAL35MM instead")
    if w <= 0 or h <= 0 or not f35 > 0:
        raise InputError(f"--camera {item!r}: the size and focal length must be positive")
    return name, nominal_camera((w, h), f35)


def _plan_prior(cameras, board, baseline_mm: float):
    """Nominal prior: the cameras side by side, ``baseline_mm`` apart along the phone's long side."""
    import numpy as np

    from ..estimation.advise import nominal_prior
    from ..errors import InputError
    from ..geometry.model import Pose, choose_reference
    if not cameras:
        raise InputError("--plan needs the cameras: --camera NAME=WxH:FOCAL35MM (repeatable) or NAME=PHOTO")
    if board is None:
        raise InputError("--plan needs the board: --board COLSxROWS --square MM")
    cams = dict(_plan_camera(c) for c in cameras)
    reference = choose_reference(sorted(cams))
    others = [n for n in cams if n != reference]
    rig = {n: Pose(np.eye(3), np.array([0.0, -baseline_mm * (i + 1), 0.0])) for i, n in enumerate(others)}
    return nominal_prior(cams, board, reference, rig)


@cli.command("advise")
@click.argument("calib", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="advise.json to write (advise.html is written beside it).")
@click.option("--count", type=click.IntRange(1, 50), default=None, help="How many poses (default 5; 8 with --plan).")
@click.option("--target", "targets", multiple=True, metavar="NAME=SIGMA",
              help="A goal 1-sigma for one value (repeatable), e.g. tele.fx=2 or tele.baseline_mm=0.02; NAME is a "
                   "key of current_sigma in advise.json. Default: shrink every camera's key sigmas.")
@click.option("--plan", is_flag=True, help="No calibration yet: propose a first set of poses from nominal cameras.")
@click.option("--camera", "cameras", multiple=True, metavar="NAME=WxH:FOCAL35MM|NAME=PHOTO",
              help="--plan: a camera, by its image size and 35 mm-equivalent focal length, or by one of its "
                   "photos (EXIF); repeatable.")
@click.option("--baseline", "baseline_mm", type=float, default=10.0, show_default=True, metavar="MM",
              help="--plan: nominal distance between neighbouring lenses.")
@board_options(required=False)
@click.option("--seed", type=int, default=0, help="Seed of the candidate poses drawn.")
def advise_command(calib, output, count, targets, plan, cameras, baseline_mm, board_spec, square_mm, marker_mm,
                   dictionary, circle_mm, seed) -> None:
    """Advise where to hold the board for the next photos.

    From the calibration's own honest covariance, the board poses that shrink the uncertainty of the
    targets the most, best first, each assuming the ones before it were taken; each is one a person
    can hold (in front of the camera, within 0.67-1.5 x the distances of the photos so far, at most
    60 degrees from facing it). advise.html beside advise.json draws the board's outline where it
    must appear in each camera's frame.

    \b
    dualcal advise calib.json -o advise.json --count 3
    dualcal advise calib.json -o advise.json --target tele.fx=2 --target tele.baseline_mm=0.02
    dualcal advise --plan --camera wide=4032x3024:26 --camera tele=4032x3024:52 \\
        --board 8x5 --square 30 -o plan.json
    """
    from ..estimation.advise import advice_to_dict, advise, describe, prior_from_rig
    from ..errors import InputError
    from ..files.io import check_output_file, load_rig, write_json_atomic, write_text_atomic
    from ..pages.report.advice import render_advice_page

    check_output_file(output)
    page = output.with_suffix(".html")
    if page == output:
        raise InputError(f"-o {output}: give a .json name (the page is written beside it as .html)")
    board = board_from_flags(board_spec, square_mm, marker_mm, dictionary, circle_mm)
    if plan:
        if calib is not None:
            raise InputError("--plan proposes first photos without a calibration: drop the calib.json or --plan")
        prior = _plan_prior(cameras, board, baseline_mm)
    else:
        if calib is None:
            raise InputError("give a calib.json to advise from (or --plan with --camera for a first set)")
        if cameras:
            raise InputError("--camera is for --plan: a calib.json names its own cameras")
        from ..workflow import check_board

        rig = load_rig(calib)
        check_board(board, rig.board, str(calib))
        prior = prior_from_rig(rig)
    advice = advise(prior, count or (8 if plan else 5), _goals(targets), seed=seed)
    write_json_atomic(output, advice_to_dict(advice))
    write_text_atomic(page, render_advice_page(advice, {n: c.image_size for n, c in prior.cameras.items()}))
    for i, p in enumerate(advice.poses, start=1):
        echo(f"{i}. {describe(p)}; seen by {', '.join(p.cameras)}; shrinks the uncertainty by {100 * p.gain:.0f} %")
    if advice.goals and advice.done:
        echo("done: every target is met")
    elif advice.goals:
        met = [i for i, p in enumerate(advice.poses, start=1)
               if all(p.predicted_sigma[n] <= s for n, s in advice.goals.items())]
        echo(f"every target is met after photo {met[0]} (predicted)" if met else
                   f"the targets are not met after {len(advice.poses)} photos (predicted): ask for more with --count")
    elif advice.done:
        echo(f"stop: more photos will not help more than {100 * advice.next_gain:.1f} %")
    echo(f"advice written to {output} and {page}")
