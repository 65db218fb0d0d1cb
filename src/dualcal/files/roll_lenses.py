"""A camera roll's lenses told apart by what its photos show, where no EXIF says which lens took each photo.

A phone's browser uploads photos without EXIF (CONTRACT.md, "A phone's camera roll"), and two or three of a
phone's lenses may take photos of one size (an ultra-wide and a wide at 2016 x 1512). Each photo's board then
tells its lens alone: the focal length ``f`` and the division model's ``lam`` (a fisheye's board is bent as no
other lens bends it), with their covariance from that photo's own corners
(:func:`dualcal.geometry.one_view.view_lens`). Each photo is a point ``x = (ln f, lam)`` with its covariance
``C`` (plus :data:`LENS_SPREAD`, what moves a lens between its photos, more for a lens that bends more), and the lenses follow from three rules,
each with a stated margin:

* **two photos, one lens**: two photos are of one lens where their points differ by less than
  :data:`SAME_LENS_SIGMA` sigma of the difference (``d^2 = (x_i - x_j)^T (C_i + C_j)^-1 (x_i - x_j)``); photos
  linked so, directly or through others, form one group (single linkage);
* **a group, one lens**: a group is one lens where its photos scatter about their mean (weighted by their
  covariances) as their own sigmas allow: its chi-square ``sum_i (x_i - m)^T C_i^-1 (x_i - m)`` within the
  quantile of ``2 (n - 1)`` degrees of freedom at the false-alarm rate :data:`ONE_LENS_RATE`. A group that
  scatters more is cut into two or three parts (the cuts that leave the least chi-square within the parts,
  then each photo to its nearest mean); where every two parts lie apart by :data:`TWO_LENSES_GAP` times their
  photos' own scatter (a gap, not the halves of one spread: those lie 2.7 times apart however many photos
  there are), a lens whose photos split into groups is that many lenses. A spread without a gap stays one
  lens;
* **two lenses told apart**: where two lenses' means differ by less than :data:`SPLIT_SIGMA` sigma of their
  difference, which photo is which cannot be told; :func:`find_lenses` reports it (``unresolved``), as it does a
  group that scatters more than one lens without a gap (``spread``: lenses too close to tell, or one lens that
  moved between its photos), and the roll is refused, saying what to do.

A photo whose board fixes no focal length (a board seen square-on: :data:`MAX_GROUPING_SIGMA`) makes no group;
its lens is told by its likelihood under each lens found (:func:`log_likelihoods`) and by the photos beside it.
How sure the split is: each pair of lenses' separation in sigma (:attr:`LensSplit.separation_sigma`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimation.distributions import chi2_quantile
from ..geometry.division import LAMBDA_RANGE
from ..geometry.one_view import PRINCIPAL_POINT_SIGMA

__all__ = ["LENS_SPREAD", "MAX_GROUPING_SIGMA", "MIN_LENS_PHOTOS", "ONE_LENS_RATE", "SAME_LENS_SIGMA", "SPLIT_SIGMA",
           "TWO_LENSES_GAP", "Lens", "LensSplit", "gap_ratio", "find_lenses", "lens_of", "lens_points", "log_likelihoods",
           "separation", "separations", "shared_principal_point"]

#: What moves one lens's point between its photos beyond their corners' noise (1-sigma of ``ln f`` and of
#: ``lam``): a refocus changes the focal length by up to 1.5 % (a thin lens focused at 0.3 m), and the division
#: model, one term, fits a real lens a little differently where the board lies in the image: the more so the more
#: the lens bends (:data:`LENS_SPREAD_PER_BEND` of ``|lam|`` more; measured on renders of a 145-degree fisheye,
#: whose boards near the edge give ``lam`` 0.05 and ``f`` 5-10 % from those near the centre).
LENS_SPREAD = (0.015, 0.02)
LENS_SPREAD_PER_BEND = (0.05, 0.15)
#: A board that is not flat (paper that bows by 1 % of its size) looks like perspective to one view: it moves the
#: focal length that view gives by about this over the tangent of the board's tilt (on the Huawei's home-made
#: board, a photo 9 degrees from square-on gives 22 % less than the others).
BOARD_SHAPE_SPREAD = 0.015
#: Two photos are of one lens where their points differ by less than this many sigma of the difference.
SAME_LENS_SIGMA = 4.0
#: A group whose photos scatter more than their sigmas allow at this false-alarm rate is more than one lens.
ONE_LENS_RATE = 1e-4
#: A group that scatters more than one lens is two where its two parts lie this many times their photos'
#: own scatter apart (:func:`gap_ratio`): photos of one lens that scatter more than their sigmas (a refocus,
#: optical stabilisation) give about 2.7 however many they are (a normal's halves; a uniform spread's, 3.5),
#: two lenses the ratio of their distance to their photos' scatter.
TWO_LENSES_GAP = 5.0
#: Two lenses are told apart where their means differ by at least this many sigma of their difference.
SPLIT_SIGMA = 5.0
#: A lens is found from at least this many photos; fewer that fit no other lens are left out.
MIN_LENS_PHOTOS = 3
#: A photo whose ``ln f`` is less sure than this (1-sigma) makes no group (a board seen nearly square-on).
MAX_GROUPING_SIGMA = 0.25
#: A linked group is cut into at most this many lenses (a phone has three lenses at most that could share a size).
MAX_LENSES = 3


@dataclass(frozen=True)
class Lens:
    """One lens found: ``members`` (indices of its photos), its principal point ``pp`` (2,) (offset from the image
    centre, half-diagonals; :mod:`dualcal.geometry.one_view`) with ``pp_covariance`` (2, 2), its ``mean`` (2,)
    ``(ln f, lam)`` and that mean's ``covariance`` (2, 2), the ``chi2`` of its photos about it on ``dof``
    degrees of freedom."""

    members: np.ndarray
    pp: np.ndarray
    pp_covariance: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    chi2: float
    dof: int

    @property
    def f_px(self) -> float:
        return float(np.exp(self.mean[0]))

    @property
    def f_sigma_px(self) -> float:
        return float(np.exp(self.mean[0]) * np.sqrt(self.covariance[0, 0]))

    @property
    def lam(self) -> float:
        return float(self.mean[1])

    @property
    def lam_sigma(self) -> float:
        return float(np.sqrt(self.covariance[1, 1]))


@dataclass(frozen=True)
class LensSplit:
    """The lenses of one image size: ``lenses`` in order of focal length, ``separation_sigma`` (m, m) each pair's
    (inf on the diagonal), ``unresolved`` the pairs (i, j) closer than :data:`SPLIT_SIGMA`, ``stray`` the photos
    that made groups too small for a lens (fewer than :data:`MIN_LENS_PHOTOS`), ``spread`` the groups of photos
    (indices) that scatter more than one lens's photos do but show no gap between lenses; ``by_ratio`` the lenses
    told apart by the ratio their photos of one position show (:func:`dualcal.files.roll.scale_step`), not by their
    points."""

    lenses: list[Lens]
    separation_sigma: np.ndarray
    unresolved: list[tuple[int, int]]
    stray: np.ndarray
    spread: list[np.ndarray]
    by_ratio: tuple[int, ...] = ()

    @property
    def told(self) -> bool:
        """Whether every lens is told apart: no pair too close, no group that scatters without a gap."""
        return not self.unresolved and not self.spread


def _prior() -> tuple[np.ndarray, np.ndarray]:
    """The principal point before any photo: the image centre, :data:`PRINCIPAL_POINT_SIGMA` about it."""
    return np.zeros(2), np.eye(2) * PRINCIPAL_POINT_SIGMA**2


def lens_points(views: list, pp: np.ndarray, pp_covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each photo's point ``(ln f, lam)`` (n, 2) and its covariance (n, 2, 2), with :data:`LENS_SPREAD` and
    :data:`BOARD_SHAPE_SPREAD` added,
    where the principal point is ``pp`` with ``pp_covariance`` (:meth:`dualcal.geometry.one_view.ViewLens.given`);
    NaN for a photo without a lens (None)."""
    x, C = np.full((len(views), 2), np.nan), np.full((len(views), 2, 2), np.nan)
    for i, v in enumerate(views):
        if v is not None:
            x[i], C[i] = v.given(pp, pp_covariance)
    bend = np.abs(np.clip(np.nan_to_num(x[:, 1]), *LAMBDA_RANGE))
    spread = np.array(LENS_SPREAD) + bend[:, None] * np.array(LENS_SPREAD_PER_BEND)
    tilt = np.radians([90.0 if v is None or not np.isfinite(v.tilt_deg) else max(v.tilt_deg, 1.0) for v in views])
    C = C + spread[:, :, None] * np.eye(2) * spread[:, None, :]
    C[:, 0, 0] += (BOARD_SHAPE_SPREAD / np.tan(tilt)) ** 2
    return x, C


def shared_principal_point(views: list, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The principal point (2,) and its covariance (2, 2) that the photos ``members`` of one lens tell together:
    each photo's word on it (its lens's normal with ``(ln f, lam)`` eliminated, a Schur complement in canonical
    form) summed over the photos, with the prior (:data:`PRINCIPAL_POINT_SIGMA` about the centre) once."""
    info = np.eye(2) / PRINCIPAL_POINT_SIGMA**2
    eta = np.zeros(2)
    for i in members:
        I, e = views[i].canonical()
        A = I[:2, :2] + np.diag([1e-4, 1e-2])          # as ViewLens.given: a board seen square-on stays invertible
        K = I[2:, :2] @ np.linalg.inv(A)
        info += I[2:, 2:] - K @ I[:2, 2:]
        eta += e[2:] - K @ e[:2]
    covariance = np.linalg.inv(info)
    return covariance @ eta, covariance


def _lens(x: np.ndarray, C: np.ndarray, members: np.ndarray, pp, pp_covariance) -> Lens:
    """The lens of the photos ``members`` (their points ``x`` and covariances ``C`` at the principal point ``pp``):
    the information-weighted mean, its covariance and the chi-square of the points about it."""
    info = np.linalg.inv(C[members])
    covariance = np.linalg.inv(info.sum(axis=0))
    mean = covariance @ np.einsum("nij,nj->i", info, x[members])
    d = x[members] - mean
    chi2 = float(np.einsum("ni,nij,nj->", d, info, d))
    return Lens(np.sort(members), np.asarray(pp, float), np.asarray(pp_covariance, float), mean, covariance, chi2,
                2 * (len(members) - 1))


def lens_of(views: list, members: np.ndarray) -> Lens:
    """The lens of the photos ``members``: their principal point (:func:`shared_principal_point`), their points at it
    and their weighted mean."""
    pp = shared_principal_point(views, members)
    return _lens(*lens_points(views, *pp), np.asarray(members), *pp)


def one_lens(lens: Lens) -> bool:
    """Whether a group's photos scatter as one lens's do (their chi-square within :data:`ONE_LENS_RATE`)."""
    return lens.dof <= 0 or lens.chi2 <= chi2_quantile(lens.dof, 1.0 - ONE_LENS_RATE)


def separation(a: Lens, b: Lens) -> float:
    """How many sigma of their difference two lenses' means are apart (Mahalanobis)."""
    d = a.mean - b.mean
    return float(np.sqrt(d @ np.linalg.solve(a.covariance + b.covariance, d)))


def separations(lenses: list[Lens]) -> np.ndarray:
    """(m, m) each two lenses' :func:`separation` (inf on the diagonal)."""
    m = len(lenses)
    sep = np.full((m, m), np.inf)
    for i in range(m):
        for j in range(i + 1, m):
            sep[i, j] = sep[j, i] = separation(lenses[i], lenses[j])
    return sep


def _linked(x: np.ndarray, C: np.ndarray, idx: np.ndarray) -> list[np.ndarray]:
    """The groups of ``idx`` that pairs closer than :data:`SAME_LENS_SIGMA` link (connected components)."""
    d = x[idx, None, :] - x[None, idx, :]
    S = C[idx, None] + C[None, idx]
    near = np.einsum("abi,abi->ab", d, np.linalg.solve(S, d[..., None])[..., 0]) < SAME_LENS_SIGMA**2
    label = np.arange(len(idx))
    while True:                       # each photo takes the smallest label of those it is linked to
        new = np.min(np.where(near, label[None, :], len(idx)), axis=1)
        if np.array_equal(new, label):
            return [idx[label == k] for k in np.unique(label)]
        label = new


def _segment_costs(x: np.ndarray, C: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(n + 1, n + 1) the chi-square of the photos ``order[i:j]`` about their own mean, for every ``i < j`` (inf
    elsewhere): from running sums of each photo's information ``W``, ``W x`` and ``x^T W x``."""
    W = np.linalg.inv(C[order])
    Wx = np.einsum("nij,nj->ni", W, x[order])
    q = np.einsum("ni,ni->n", x[order], Wx)
    cW = np.concatenate([np.zeros((1, 2, 2)), np.cumsum(W, axis=0)])
    cWx = np.concatenate([np.zeros((1, 2)), np.cumsum(Wx, axis=0)])
    cq = np.concatenate([[0.0], np.cumsum(q)])
    A = cW[None, :] - cW[:, None]                                   # (i, j): the sums over order[i:j]
    b = cWx[None, :] - cWx[:, None]
    det = A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    n = len(order) + 1
    upper = np.triu(np.ones((n, n), bool), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        explained = (A[..., 1, 1] * b[..., 0] ** 2 - 2 * A[..., 0, 1] * b[..., 0] * b[..., 1]
                     + A[..., 0, 0] * b[..., 1] ** 2) / det           # b^T A^-1 b
        cost = cq[None, :] - cq[:, None] - explained
    return np.where(upper & np.isfinite(cost), cost, np.inf)


def _k_means(x: np.ndarray, C: np.ndarray, idx: np.ndarray, k: int) -> list[np.ndarray] | None:
    """``idx`` in ``k`` parts of at least :data:`MIN_LENS_PHOTOS`: the cuts along ``ln f`` or along ``lam`` (the
    photos ordered by it) that leave the least chi-square within the parts (dynamic programming over the cuts),
    then each photo moved to the mean it is nearest (Mahalanobis, its covariance and the mean's summed) until none
    moves; None where ``idx`` has too few photos."""
    if len(idx) < k * MIN_LENS_PHOTOS:
        return None
    best, parts = np.inf, None
    for axis in range(2):
        order = idx[np.argsort(x[idx, axis], kind="stable")]
        cost = _segment_costs(x, C, order)
        n = len(order)
        total = np.full((k + 1, n + 1), np.inf)
        cut = np.zeros((k + 1, n + 1), int)
        total[0, 0] = 0.0
        for m in range(1, k + 1):
            for j in range(m * MIN_LENS_PHOTOS, n + 1):
                starts = np.arange((m - 1) * MIN_LENS_PHOTOS, j - MIN_LENS_PHOTOS + 1)
                options = total[m - 1, starts] + cost[starts, j]
                total[m, j], cut[m, j] = options.min(), starts[np.argmin(options)]
        if total[k, n] < best:
            bounds = [n]
            for m in range(k, 0, -1):
                bounds.append(cut[m, bounds[-1]])
            bounds = bounds[::-1]
            best, parts = total[k, n], [order[bounds[m]:bounds[m + 1]] for m in range(k)]
    zero = (np.zeros(2), np.zeros((2, 2)))
    for _ in range(20):
        means = [_lens(x, C, p, *zero) for p in parts]
        d2 = np.array([np.einsum("ni,ni->n", x[idx] - m.mean,
                                 np.linalg.solve(C[idx] + m.covariance, (x[idx] - m.mean)[..., None])[..., 0])
                       for m in means])
        nearest = np.argmin(d2, axis=0)
        new = [idx[nearest == m] for m in range(k)]
        if min(len(p) for p in new) < MIN_LENS_PHOTOS or all(np.array_equal(a, b) for a, b in zip(new, parts)):
            break
        parts = new
    return parts


def _cut(x: np.ndarray, C: np.ndarray, members: np.ndarray) -> list[np.ndarray] | None:
    """A group that scatters more than one lens cut into lenses: into 2, then 3 parts (up to :data:`MAX_LENSES`,
    :func:`_k_means`), kept where every two parts lie :data:`TWO_LENSES_GAP` times their photos' scatter apart
    (:func:`gap_ratio`), and no further once every part is one lens; None where no cut has such gaps."""
    best = None
    for k in range(2, MAX_LENSES + 1):
        parts = _k_means(x, C, members, k)
        if parts is None:
            break
        if all(gap_ratio(x, C, parts[i], parts[j]) >= TWO_LENSES_GAP for i in range(k) for j in range(i + 1, k)):
            best = parts
            if all(one_lens(_lens(x, C, part, *_prior())) for part in parts):
                break
    return best


def _groups(x: np.ndarray, C: np.ndarray, idx: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """The photos ``idx`` in groups by the first two rules (module docstring): linked groups, those that scatter
    more than one lens cut (:func:`_cut`); the groups too small for a lens; and the groups that scatter more than one
    lens but could not be cut (kept whole among the groups too)."""
    groups, stray, spread = [], [], []
    for members in _linked(x, C, idx):
        if len(members) < MIN_LENS_PHOTOS:
            stray.append(members)
            continue
        parts = None if one_lens(_lens(x, C, members, *_prior())) else _cut(x, C, members)
        if parts is None and not one_lens(_lens(x, C, members, *_prior())):
            spread.append(members)
        groups += parts or [members]
    return groups, stray, spread


def gap_ratio(x: np.ndarray, C: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """How far apart two parts of a group are against the scatter of their photos about their own parts, along the
    line between their means: the distance of the means in a typical photo's sigma (its information the mean of
    the photos'), over the RMS of each photo's standardised distance from its part's mean along that line."""
    zero = (np.zeros(2), np.zeros((2, 2)))
    la, lb = _lens(x, C, a, *zero), _lens(x, C, b, *zero)
    d = la.mean - lb.mean
    members = np.concatenate([a, b])
    info = np.linalg.inv(C[members])
    gap = np.sqrt(d @ info.mean(axis=0) @ d)
    offsets = np.concatenate([x[a] - la.mean, x[b] - lb.mean])
    t = np.einsum("i,nij,nj->n", d, info, offsets) / np.sqrt(np.einsum("i,nij,j->n", d, info, d))
    return float(gap / max(np.sqrt(np.sum(t**2) / max(len(members) - 2, 1)), 1e-9))


def _grouping(x: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The photos whose points are sure enough to make groups (:data:`MAX_GROUPING_SIGMA`)."""
    finite = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
    return np.flatnonzero(finite & (np.sqrt(np.where(finite, C[:, 0, 0], np.inf)) <= MAX_GROUPING_SIGMA))


def find_lenses(views: list) -> LensSplit:
    """The lenses of photos of one image size, by the rules of the module docstring.

    The photos are grouped first with the principal point at its prior (every lens's about the image centre);
    then each group's photos tell its principal point together (:func:`shared_principal_point`), which sharpens
    each photo's focal length, and the group is judged again: two lenses whose focal lengths differ by 10 % fall
    apart only then. Each lens's mean, and each photo's likelihood under it, are at its own principal point.

    Parameters
    ----------
    views : each photo's lens (:func:`dualcal.geometry.one_view.view_lens`), None where its board gave none.

    Returns
    -------
    LensSplit
        Every lens found from at least :data:`MIN_LENS_PHOTOS` photos (one lens of them all where no group is that
        large), each pair's separation, the pairs too close to tell, the photos of groups too small for a lens, and
        the groups that scatter without a gap.
    """
    x, C = lens_points(views, *_prior())
    groups, stray, wide_spread = _groups(x, C, _grouping(x, C))
    lenses, spread = [], []
    for group in groups:
        pp = shared_principal_point(views, group)
        xs, Cs = lens_points(views, *pp)
        inner = group[np.isin(group, _grouping(xs, Cs))]
        parts = None if len(inner) < MIN_LENS_PHOTOS or one_lens(_lens(xs, Cs, inner, *pp)) else _cut(xs, Cs, inner)
        found = [lens_of(views, part) for part in parts or []]
        # the parts stand where each, at its own principal point, is surely apart from every other: a principal
        # point shared by two lenses moves their photos' focal lengths by how each board is tilted, and can make
        # one lens's photos look like two
        if found and all(separation(a, b) >= SPLIT_SIGMA for i, a in enumerate(found) for b in found[i + 1:]):
            lenses += found
            stray += [np.setdiff1d(group, np.concatenate(parts))]
        else:
            lenses.append(_lens(xs, Cs, group, *pp))
            if any(np.array_equal(group, g) for g in wide_spread):     # scattered at both steps: not told
                spread.append(group)
    if not lenses and stray:              # too few photos for a lens of their own: one lens of them all
        lenses, stray = [lens_of(views, np.concatenate(stray))], []
    lenses.sort(key=lambda lens: lens.mean[0])
    sep = separations(lenses)
    m = len(lenses)
    unresolved = [(i, j) for i in range(m) for j in range(i + 1, m) if sep[i, j] < SPLIT_SIGMA]
    return LensSplit(lenses, sep, unresolved, np.sort(np.concatenate(stray)) if stray else np.zeros(0, int),
                     [np.sort(g) for g in spread])


def log_likelihoods(views: list, lenses: list[Lens]) -> tuple[np.ndarray, np.ndarray]:
    """(n, m) the log-likelihood of each photo under each lens: its point at the lens's principal point, a normal
    about the lens's mean with the photo's covariance and the mean's summed (0 for a photo without a lens); and
    (n, m) each photo's Mahalanobis distance squared from each lens's mean (NaN without a lens)."""
    out, d2 = np.zeros((len(views), len(lenses))), np.full((len(views), len(lenses)), np.nan)
    for k, lens in enumerate(lenses):
        x, C = lens_points(views, lens.pp, lens.pp_covariance)
        ok = np.all(np.isfinite(x), axis=1)
        S = C[ok] + lens.covariance
        d = x[ok] - lens.mean
        d2[ok, k] = np.einsum("ni,ni->n", d, np.linalg.solve(S, d[..., None])[..., 0])
        out[ok, k] = -0.5 * d2[ok, k] - 0.5 * np.log(np.linalg.det(S))
    return out, d2
