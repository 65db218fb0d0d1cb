"""How a camera roll without EXIF is split into lenses that share an image size (dualcal.files.roll.cameras_from_boards).

    .venv/bin/python benchmarks/bench_roll_lenses.py [--seeds 4] [--views 12] [--noise 0.1]

Synthetic rigs of one image size (2016 x 1512 at a quarter, ``dualcal.synthetic.synth_roll.shared_size_rig``), shot
as a tripod session (``shooting_script``), each photo's corners the truth's with ``--noise`` px of noise, no EXIF.
For each rig and seed it prints what became of the roll: split right (every photo with the board in a camera of
its own lens only, one camera per lens), refused (one line, InputError), or wrong (photos of two lenses in one
camera, or a lens in two), with the photos left out as unclear and the closest two lenses' separation in sigma.
Synthetic figures: real photos add what the synthetic lenses leave out.
"""

from __future__ import annotations

import argparse
import time

from dualcal.errors import InputError
from dualcal.files import roll
from dualcal.synthetic.synth_roll import roll_without_exif

#: name -> (focal lengths in px at 2016 x 1512, the fisheyes among them)
RIGS = {
    "fisheye 1130 + wide 1340 (19 %)": ({"wide": 1340.0, "ultra": 1130.0}, ("ultra",)),
    "fisheye 1218 + wide 1340 (10 %)": ({"wide": 1340.0, "ultra": 1218.0}, ("ultra",)),
    "fisheye + wide + 1650 (19 %, 23 %)": ({"wide": 1340.0, "ultra": 1130.0, "wide2": 1650.0}, ("ultra",)),
    "mild 1340 + 1742 (30 %)": ({"wide": 1340.0, "wide2": 1742.0}, ()),
    "mild 1340 + 1474 (10 %)": ({"wide": 1340.0, "wide2": 1474.0}, ()),
    "mild 1130 + 1340 + 1500 (19 %, 12 %)": ({"wide": 1340.0, "ultra": 1130.0, "wide2": 1500.0}, ()),
    "mild 1340 + 1407 (5 %)": ({"wide": 1340.0, "wide2": 1407.0}, ()),
    "mild 1340 + 1380 (3 %)": ({"wide": 1340.0, "wide2": 1380.0}, ()),
    "one mild lens": ({"wide": 1340.0}, ()),
    "one fisheye": ({"wide": 1130.0}, ("wide",)),
}


def one_roll(focal, fisheye, seed: int, views: int, noise: float) -> str:
    truth, photos, uv, true_camera = roll_without_exif(focal, fisheye, seed, views, noise)
    t = time.perf_counter()
    try:
        cameras, facts, _, left_out = roll.cameras_from_boards(photos, uv, truth.board.object_points_mm()[:, :2])
    except InputError as exc:
        return f"refused ({time.perf_counter() - t:.1f} s): {str(exc)[:90]}..."
    seconds = time.perf_counter() - t
    lenses = [{true_camera[p.path.name] for p in members} for members in cameras.values()]
    right = all(len(found) == 1 for found in lenses) and len({next(iter(f)) for f in lenses}) == len(focal) \
        and len(cameras) == len(focal)
    unclear = sum(not why.startswith("no board") for why in left_out.values())
    apart = min((c["separation_sigma"] for c in facts.values() if c["separation_sigma"] is not None), default=None)
    return (f"{'split right' if right else 'WRONG'} ({seconds:.1f} s): {len(cameras)} cameras, {unclear} photos unclear"
            + (f", closest lenses {apart:.1f} sigma apart" if apart is not None else ""))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--noise", type=float, default=0.1)
    args = parser.parse_args()
    print(f"{args.views} positions, {args.noise:g} px of corner noise, photos 504 x 378 px, {args.seeds} seeds")
    for name, (focal, fisheye) in RIGS.items():
        print(name)
        for seed in range(args.seeds):
            print(f"  seed {seed}: {one_roll(focal, fisheye, seed, args.views, args.noise)}", flush=True)


if __name__ == "__main__":
    main()
