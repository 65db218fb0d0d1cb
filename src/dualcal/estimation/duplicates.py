"""Duplicate instants: the same view counted twice makes every sigma lie.

dualcal's sigmas come from the scatter between instants (:mod:`dualcal.estimation.uncertainty`), so an instant
must be an independent look at the board. A photo copied (a camera roll exported twice, a re-run into
the same folder) or a burst (the phone and the board still, several shots) is the same view again: its
corners agree with the first one's within their noise, and counting it shrinks every sigma by about
``sqrt(copies)`` while the errors stay. Such instants are one instant.

Two instants are duplicates when the same cameras found the board in both and, in every one of them,
the corners both measured agree to within :data:`DUPLICATE_SIGMAS` times what two measurements of one
corner differ by (``sqrt(2)`` x the camera's corner noise per coordinate, :func:`corner_noise_px`),
as an RMS over the corners. Two different board positions never come that close: a board moved by a
tenth of a square, or turned by a tenth of a degree, moves its corners by far more than a few tenths
of a pixel. Groups are closed transitively; the first key of a group (in sorted order) is kept. (The
noise is taken between :data:`MIN_NOISE_PX` and :data:`MAX_NOISE_PX`; a camera none of whose instants
come within the limit of the largest is spared estimating it.)

The same holds, more generally, for frames of one clip taken while the board was held still: whatever
their corners, they are one moment, and the instants of one moment (each camera's ``video`` record in the
corners says which moment an instant's frame belongs to: ``moment_of_view``, :mod:`dualcal.files.video`) are
one instant too, so that using more frames of a moment cannot shrink a sigma.

Identical files are found where a dataset lists its photos (:func:`dualcal.files.dataset.duplicate_files`).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace

import numpy as np

from ..geometry.grid import predict_from_neighbours
from ..geometry.model import CameraCorners, CornerSet, observed_mask

#: Corners of two instants agree "within the noise" up to this many sigmas of their difference (RMS).
DUPLICATE_SIGMAS = 4.0
#: Corner noise assumed at least this (px per coordinate), so that noise-free synthetic corners still
#: merge only what is the same to well below a pixel.
MIN_NOISE_PX = 0.02
#: ... and at most this: corners noisier than that are no measurement to judge by. Where no two instants
#: are within the limit this noise sets, the camera's own noise is not needed (nor computed).
MAX_NOISE_PX = 2.0
#: A camera's corners of two instants are compared only where both measured this share of those the fuller
#: view measured.
MIN_COMMON_SHARE = 0.5


#: :func:`corner_noise_px` looks at this many of a camera's views at most (spread over them): the median
#: of a few views' noise is as good as of all, and each costs a small fit per corner.
NOISE_VIEWS = 8


def corner_noise_px(views: list[np.ndarray], shape: tuple[int, int]) -> float:
    """A camera's corner noise, px per coordinate: the median over its views (:data:`NOISE_VIEWS` of them
    at most, spread over the list) of the RMS of each corner against its prediction from its 5 x 5
    neighbours (:func:`dualcal.geometry.grid.predict_from_neighbours`), the prediction's own noise taken
    out (``/ sqrt(1 + gain^2)``), within :data:`MIN_NOISE_PX` .. :data:`MAX_NOISE_PX`."""
    per_view = []
    picked = np.unique(np.linspace(0, len(views) - 1, min(len(views), NOISE_VIEWS)).round().astype(int))
    for uv in (views[i] for i in picked):
        pred, gain = predict_from_neighbours(uv, shape)
        e2 = np.sum((uv - pred) ** 2, axis=1) / (1.0 + gain ** 2)
        e2 = e2[np.isfinite(e2)]
        if len(e2):
            per_view.append(np.sqrt(np.mean(e2) / 2.0))
    return min(max(float(np.median(per_view)) if per_view else 0.0, MIN_NOISE_PX), MAX_NOISE_PX)


def _found(cam: CameraCorners) -> dict[str, np.ndarray]:
    return {k: v for k, v in cam.views.items() if v is not None and observed_mask(v).any()}


#: :func:`_rms_differences` compares this many corner differences at most in one batch (memory: 8 bytes each).
_BATCH_DIFFERENCES = 2_000_000


def _rms_differences(stack: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RMS 2-D difference per corner between each view ``rows`` (A,) and every view of ``stack`` (V, N, 2), over
    the corners both measured, and their share of the corners the fuller of the two views measured (a partial
    view of a ChArUco board and its copy share all of theirs): two (A, V) arrays, the rows in batches of
    :data:`_BATCH_DIFFERENCES` differences."""
    u, v = np.ascontiguousarray(stack[..., 0]), np.ascontiguousarray(stack[..., 1])   # (V, N) each
    measured = np.isfinite(u).sum(axis=1)                                              # (V,)
    rms, share = np.empty((len(rows), len(stack))), np.empty((len(rows), len(stack)))
    step = max(1, _BATCH_DIFFERENCES // max(u.size, 1))
    for i in range(0, len(rows), step):
        a = rows[i:i + step]
        du, dv = u[None] - u[a][:, None], v[None] - v[a][:, None]
        d2 = du * du + dv * dv                                              # (A, V, N), NaN where either is missing
        common = np.isfinite(d2)
        n = common.sum(axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms[i:i + step] = np.where(n > 0, np.sqrt(np.where(common, d2, 0.0).sum(axis=2) / n), np.inf)
            share[i:i + step] = n / np.maximum(np.maximum(measured[None, :], measured[a][:, None]), 1)
    return rms, share


def moments_of(corners: CornerSet) -> dict[str, int]:
    """``{instant: moment}`` of corners from clips (each camera's ``video`` record, :mod:`dualcal.files.video`);
    empty for photos."""
    out = {}
    for cam in corners.cameras.values():
        record = cam.meta.get("video")
        if isinstance(record, dict):
            out.update(record.get("moment_of_view", {}))
    return out


def same_moment(corners: CornerSet, keys: list[str]) -> np.ndarray:
    """(V, V) bool: the instants ``keys`` whose frames some camera's clip records as one moment."""
    moment = moments_of(corners)
    ids = np.array([moment.get(k, -1 - i) for i, k in enumerate(keys)])
    return ids[:, None] == ids[None, :]


def find_duplicate_instants(corners: CornerSet, sigmas: float = DUPLICATE_SIGMAS) -> list[dict]:
    """Groups of instants whose views are the same within the noise, or frames of one moment of a clip
    (module docstring).

    Returns
    -------
    One record per group of two or more instants, in key order: ``{"kept": key, "merged": [keys],
    "rms_px": {camera: largest RMS difference to the kept instant}, "limit_px": {camera: limit}}``.
    """
    shape = (corners.board.rows, corners.board.cols)
    found = {name: _found(cam) for name, cam in corners.cameras.items()}
    keys = sorted({k for views in found.values() for k in views})
    if len(keys) < 2:
        return []
    index = {k: i for i, k in enumerate(keys)}
    names = sorted(found)
    seen = np.array([[k in found[n] for n in names] for k in keys])           # (V, C)
    close = np.all(seen[:, None, :] == seen[None, :, :], axis=2)             # the same cameras found the board
    rms_of, limit_of = {}, {}
    for name, views in found.items():
        if not views:
            continue
        stack = np.full((len(keys), corners.board.n_corners, 2), np.nan)
        for k, uv in views.items():
            stack[index[k]] = uv
        rms = np.full((len(keys), len(keys)), np.inf)
        rows = np.array([index[k] for k in views])
        r, share = _rms_differences(stack, rows)
        rms[rows] = np.where(share >= MIN_COMMON_SHARE, r, np.inf)
        rms_of[name] = rms
        both = np.outer(seen[:, names.index(name)], seen[:, names.index(name)])
        limit = sigmas * np.sqrt(2.0) * MAX_NOISE_PX
        if np.any(close & both & (rms <= limit) & ~np.eye(len(keys), dtype=bool)):
            limit = sigmas * np.sqrt(2.0) * corner_noise_px(list(views.values()), shape)
        limit_of[name] = limit
        close &= ~both | (rms <= limit)
    records = []
    for group in _connected_groups(close | (same_moment(corners, keys) & ~np.eye(len(keys), dtype=bool))):
        first, cams = group[0], [n for c, n in enumerate(names) if seen[group[0], c]]
        records.append({"kept": keys[first], "merged": [keys[i] for i in group[1:]],
                        "rms_px": {n: float(max(r)) for n in cams if (r := [rms_of[n][first, i] for i in group[1:]
                                                                            if np.isfinite(rms_of[n][first, i])])},
                        "limit_px": {n: float(limit_of[n]) for n in cams}})
    return records


def _connected_groups(close: np.ndarray) -> list[list[int]]:
    """The groups (two or more members, each sorted) of the graph whose edges are ``close[i, j]`` for i != j."""
    parent = list(range(len(close)))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(close, 1))):
        ri, rj = root(i), root(j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    members = defaultdict(list)
    for i in range(len(close)):
        members[root(i)].append(i)
    return [sorted(g) for g in members.values() if len(g) > 1]


def merge_duplicate_instants(corners: CornerSet, sigmas: float = DUPLICATE_SIGMAS) -> tuple[CornerSet, list[dict]]:
    """``corners`` with one instant per group of duplicates (:func:`find_duplicate_instants`; the kept one's
    corners) and the groups' records, which every camera's ``meta["duplicates"]`` also holds (corners.json).

    A camera whose view keys name no moment the others share (:meth:`CornerSet.cameras_alone`: it filmed the board
    on its own) is judged alone: its repeated views are merged whatever the other cameras saw under the same keys,
    and its records say ``"camera"``."""
    alone = set(corners.cameras_alone())
    together = corners if not alone else replace(corners, cameras={n: c for n, c in corners.cameras.items()
                                                                   if n not in alone})
    groups = [(None, find_duplicate_instants(together, sigmas))] if together.cameras else []
    groups += [(name, find_duplicate_instants(replace(corners, cameras={name: corners.cameras[name]}), sigmas))
               for name in sorted(alone)]
    records = [{**r, "camera": name} if name else r for name, found in groups for r in found]
    if not records:
        return corners, []
    merged = {(name, k) for name, found in groups for r in found for k in r["merged"]}
    out = corners.with_views(lambda camera, view: (camera if camera in alone else None, view) not in merged)
    for name, cam in out.cameras.items():
        own = [r for r in records if r.get("camera") in (None, name)]
        if own:
            cam.meta = {**cam.meta, "duplicates": [{"kept": r["kept"], "merged": r["merged"]} for r in own]}
    return out, records


def describe_duplicates(records: list[dict]) -> str:
    """One line saying which instants were merged into which."""
    n = sum(len(r["merged"]) for r in records)
    pairs = "; ".join(f"{r['camera'] + ' ' if 'camera' in r else ''}{', '.join(r['merged'])} = {r['kept']}"
                      for r in records[:8])
    more = f"; and {len(records) - 8} more groups" if len(records) > 8 else ""
    return (f"{n} instant(s) repeat another's view (the same corners within {DUPLICATE_SIGMAS:g} sigma of their "
            f"noise: a copied photo or a burst; or frames of one moment a clip held the board still) and count "
            f"once, so that the sigmas come from distinct instants: {pairs}{more}")
