"""Checks of the sigmas that need no ground truth: two disjoint halves of the instants.

Calibrate two disjoint halves ``A``, ``B`` of the instants with the same settings; for every
parameter ``p`` with sigma ``s``, ``z = (p_A - p_B) / sqrt(s_A^2 + s_B^2)``. Over many random
splits, honest sigmas give ``z`` a spread of about 1 (each half's sigma is that of its own, half-size
calibration); sigmas that are too small give a larger one. The spread is pooled as
``sqrt(mean(z^2))`` over the splits and over the parameters of one kind:

``f``         fx, fy of every camera (px)
``c``         cx, cy of every camera (px)
``k``         k1, k2 of every camera
``baseline``  D of every camera of the rig (mm)
``angles``    omega, phi, kappa of every camera of the rig (arcmin)

for ``sigma`` (calib.json's, the one that holds on real photos) and ``sigma_formal`` (textbook).
"""

from __future__ import annotations

import numpy as np

from .duplicates import moments_of
from ..geometry.model import CornerSet, RigModel

__all__ = ["GROUPS", "split_half_z", "pooled_spread", "instants_of", "moments_of"]

GROUPS = {"f": ("fx", "fy"), "c": ("cx", "cy"), "k": ("k1", "k2")}


def instants_of(corners: CornerSet) -> list[str]:
    """The view keys where at least one camera found the board."""
    return sorted({v for cc in corners.cameras.values() for v in cc.found()})


def _values(rig: RigModel) -> dict[tuple[str, str], tuple[float, float, float]]:
    """``(group, parameter) -> (value, sigma, sigma_formal)`` for every parameter of the groups."""
    out = {}
    for name, cam in rig.cameras.items():
        for group, params in GROUPS.items():
            for p in params:
                formal = rig.camera_sigma_formal.get(name, {}).get(p, np.nan)
                out[(group, f"{name}.{p}")] = (getattr(cam, p), rig.camera_sigma[name][p], formal)
    for name, rel in rig.rig.items():
        f = rel.sigma_formal
        out[("baseline", f"{name}.D")] = (rel.baseline_mm, rel.sigma_baseline_mm, f.get("baseline_mm", np.nan))
        for i, a in enumerate(("omega", "phi", "kappa")):
            formal = f["opk_arcmin"][i] if "opk_arcmin" in f else np.nan
            out[("angles", f"{name}.{a}")] = (rel.pose.opk_arcmin[i], rel.sigma_opk_arcmin[i], formal)
    return out


def split_half_z(corners: CornerSet, splits: int = 20, seed: int = 0, calibrate=None, groups=None, **kwargs):
    """``z`` scores of ``splits`` random splits of the instants into two halves.

    Parameters
    ----------
    corners : the corner set (all instants).
    splits, seed : how many random splits, from which random seed.
    groups : ``{instant: group}``: instants of one group go to the same half (the frames of one held moment
        of a clip, whose errors are not independent: :func:`moments_of`); default: every instant its own.
    calibrate : the calibration function (default :func:`dualcal.estimation.calibrate.calibrate_rig`), called
        as ``calibrate(half, **kwargs)``.

    Returns
    -------
    ``{"sigma": {group: [z, ...]}, "sigma_formal": {group: [z, ...]}}``.
    """
    if calibrate is None:
        from .calibrate import calibrate_rig as calibrate
    keys = instants_of(corners)
    groups = groups or {}
    units = sorted({groups.get(k, k) for k in keys}, key=str)
    rng = np.random.default_rng(seed)
    z = {"sigma": {}, "sigma_formal": {}}
    for _ in range(splits):
        order = [units[i] for i in rng.permutation(len(units))]
        first = set(order[:len(units) // 2])
        halves = ([k for k in keys if groups.get(k, k) in first], [k for k in keys if groups.get(k, k) not in first])
        a, b = (_values(calibrate(corners.with_views(lambda _, v, part=set(part): v in part), **kwargs))
                for part in halves)
        for key in a.keys() & b.keys():
            (va, sa, fa), (vb, sb, fb) = a[key], b[key]
            diff = va - vb
            z["sigma"].setdefault(key[0], []).append(diff / np.hypot(sa, sb))
            z["sigma_formal"].setdefault(key[0], []).append(diff / np.hypot(fa, fb))
    return z


def pooled_spread(z: dict[str, list[float]]) -> dict[str, float]:
    """``sqrt(mean(z^2))`` per group (finite values only)."""
    out = {}
    for group, values in z.items():
        v = np.asarray(values, float)
        v = v[np.isfinite(v)]
        if len(v):
            out[group] = float(np.sqrt(np.mean(v ** 2)))
    return out
