"""The board positions of a camera roll: which of its photos were shot together, from every clue the roll gives.

At each board position the phone stands still on its tripod and each lens shoots in turn; then the board
is moved (CONTRACT.md, "A phone's camera roll"). People shoot as people do: a lens switch that takes
longer, a retake, a stray photo, a lens that misses a position, positions shot quickly one after another.
So no one clue is trusted alone; each is a log-odds (natural logarithm of the odds) that two photos were
shot at one position, and the split that agrees best with all of them is chosen:

* **the board's image** in two photos of one camera (:func:`image_change`): at one position nothing moves,
  so a retake shows the board where the first photo did (within :data:`SAME_IMAGE` of the board's size in
  the image); a board that moved by more than :data:`MOVED_IMAGE` is another position, for certain.
* **the board's pose** in photos of two cameras (:func:`rig_relations`): at one position the two poses
  differ by the rig's relative pose, which is the same at every position. It is found as the relative
  rotation that most pairs of nearby photos of the two cameras agree on (a pair from two positions agrees
  with none), with the spread of those pairs, which says how far a pose of this roll can be trusted;
  a pair is then judged by how far it is from the rig in rotation and in the board's position.
* **capture times** (:func:`time_log_odds`): the gap between two successive photos is short between the
  lenses of one position and long when the board is moved. What short and long are is learnt from the
  roll: a first split uses a prior (:data:`TYPICAL_GAP_S`), the second the gaps inside and between the
  positions of the first (a linear discriminant on log gaps). Without capture times, the photos' order
  is still a clue: only successive photos can be one position.
* **the lens order**: at every position the lenses are shot in much the same order (widest first, say);
  the second split counts a pair of photos in the other order than the first split's runs mostly show
  against their being one position.

A split cuts the photos, in shooting order, into runs; its score is the sum of the log-odds of every pair
of photos in one run (the capture time of successive photos only). The best split is found exactly by
dynamic programming over runs of at most :func:`longest_run` photos, and the same recursion run backwards
gives, at every gap between two successive photos, the best split that decides the other way there: the
difference of the two scores is the split's *margin* at that gap, the log-odds that its decision there is
right given the clues (:class:`PositionSplit`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.one_view import OneView, board_pixels, board_pose, spread_px
from ..geometry.rotation import nearest_rotation, rotation_angle_deg

__all__ = ["MOVED_IMAGE", "SAME_IMAGE", "PositionSplit", "Shot", "best_split", "image_change", "longest_run",
           "rig_relations", "split_positions", "time_log_odds"]

#: A retake: the board's corners moved by less than this share of the board's size in the image.
SAME_IMAGE = 0.03
#: Another position, for certain: the board's corners moved by more than this share.
MOVED_IMAGE = 0.08
#: The log-odds a retake (or a position) gets from the board's image that did not move.
STILL_LOG_ODDS = 6.0
#: Relative rotations of the rig within this of each other agree (degrees): poses from one view are
#: rough, those of two positions differ by tens of degrees.
AGREEMENT_DEG = 5.0
#: The spreads of a pose's rotation (degrees) and of the board's position (share of its distance) never
#: count as less than these.
MIN_ROTATION_SIGMA_DEG, MIN_POSITION_SIGMA = 1.0, 0.02
#: How far the board's pose moves between two positions, at most: the range over which the poses of two
#: positions spread (rotation in degrees, position as a share of the distance).
MOVE_RANGE = (60.0, 1.0)
#: The most a clue of one pair of photos counts against their being one position (a rough pose can be
#: wrong; only the board's image in one camera is certain).
MAX_AGAINST = 10.0
#: The capture-time prior: gaps shorter than this are more likely one position, longer ones not.
TYPICAL_GAP_S = 10.0
#: Below this margin a split's decision is unsure; where the clues there also disagree, it is refused.
MIN_MARGIN = 2.0
#: The margin recorded for a decision no split could change (a board moved in one camera's photos).
CERTAIN = 99.0


@dataclass(frozen=True)
class Shot:
    """One photo of a roll, as the split sees it: its camera, its board (:class:`~dualcal.geometry.one_view.OneView`)
    and its capture time in seconds (None: unknown)."""

    camera: str
    view: OneView
    taken_s: float | None = None


@dataclass
class PositionSplit:
    """The board positions of a roll's shots (in shooting order).

    ``runs`` are lists of shot indices, one per position; ``margins`` (n-1,) the log-odds margin of the
    decision at each gap between successive shots (module docstring; :data:`CERTAIN` where no split could
    decide otherwise); ``time_log_odds`` and ``board_log_odds`` (n-1,) what the capture times and the
    boards of the two shots at each gap say alone (positive: one position); ``clues`` the clues that took
    part (``board image``, ``board pose``, ``capture time``, ``order``, ``lens order``); ``gap_s`` the
    capture-time gap at which the time clue turns from one position to two (None without times).
    """

    runs: list[list[int]]
    margins: np.ndarray
    time_log_odds: np.ndarray
    board_log_odds: np.ndarray
    clues: list[str]
    gap_s: float | None = None

    def run_margin(self, r: int) -> float:
        """The smallest margin of the decisions that make run ``r``: the gaps inside it and at its ends."""
        first, last = self.runs[r][0], self.runs[r][-1]
        gaps = range(max(first, 1), min(last + 1, len(self.margins) + 1))
        return float(min((self.margins[k - 1] for k in gaps), default=CERTAIN))

    def unsure_gaps(self) -> list[int]:
        """The gaps ``k`` (between shots k-1 and k) whose margin is below :data:`MIN_MARGIN`."""
        return [k + 1 for k in np.flatnonzero(self.margins < MIN_MARGIN)]

    def disagreeing_gaps(self) -> list[int]:
        """The unsure gaps where the capture times and the boards say opposite things, each with
        log-odds of at least :data:`MIN_MARGIN` / 2."""
        t, b = self.time_log_odds, self.board_log_odds
        return [k for k in self.unsure_gaps()
                if t[k - 1] * b[k - 1] < 0 and min(abs(t[k - 1]), abs(b[k - 1])) >= MIN_MARGIN / 2]


def longest_run(n_cameras: int) -> int:
    """The most photos one position can hold in a split: every lens twice (retakes), and two more."""
    return 2 * n_cameras + 2


def image_change(a: OneView, b: OneView, xy_board: np.ndarray, symmetric: bool = False) -> float:
    """How far the board's corners moved between two photos of one camera, as a share of the board's
    size in the first (the RMS of the moves over the RMS distance of the corners from their centre); for a
    board that looks the same turned by 180 degrees (``symmetric``), with either numbering of ``b``."""
    pa, pb = board_pixels(a, xy_board), board_pixels(b, xy_board)
    size = spread_px(pa)
    return float(min(np.sqrt(np.mean(np.sum((pa - other) ** 2, axis=1)))
                     for other in ([pb, pb[::-1]] if symmetric else [pb])) / size)


_HALF_TURN = np.diag([-1.0, -1.0, 1.0])          # Rz(pi): the board turned about its normal


@dataclass(frozen=True)
class BoardPose:
    """A board's rough pose in one photo: its rotation ``R`` (board to camera) and its centre in the camera's
    frame ``centre_mm`` (which does not depend on the corners' numbering), with their spreads measured on the
    quarters of the corners (:class:`~dualcal.geometry.one_view.OneView`): ``sigma_deg`` and ``sigma_position``
    (share of the distance)."""

    R: np.ndarray
    centre_mm: np.ndarray
    sigma_deg: float = 0.0
    sigma_position: float = 0.0

    @classmethod
    def of(cls, view: OneView, f_px: float, xy_board: np.ndarray) -> "BoardPose":
        """The pose of a view for a camera of focal length ``f_px``; each quarter of its corners has a quarter of
        the corners, so the spread of their poses is twice the whole's."""
        middle = np.append(0.5 * (xy_board.min(axis=0) + xy_board.max(axis=0)), 0.0)
        pose = board_pose(view, f_px)
        centre = pose.apply(middle[None])[0]
        angles, moves = [], []
        for H in view.H_quarters:
            if np.all(np.isfinite(H)):
                q = board_pose(view, f_px, H)
                angles.append(float(rotation_angle_deg(q.R, pose.R)))
                moves.append(float(np.linalg.norm(q.apply(middle[None])[0] - centre) / np.linalg.norm(centre)))
        if len(angles) < 2:
            return cls(pose.R, centre, np.inf, np.inf)
        return cls(pose.R, centre, float(np.sqrt(np.mean(np.square(angles)))) / 2,
                   float(np.sqrt(np.mean(np.square(moves)))) / 2)


@dataclass(frozen=True)
class RigRelation:
    """The relative pose of two cameras as a roll's poses show it: camera b's pose of the board is about
    ``R @ R_a`` (or that turned by 180 degrees about the board's normal, for a board that looks the same
    turned, ``symmetric``) and the board's centre about ``scale * R @ c_a + t``; the spreads of agreeing
    pairs ``sigma_deg`` and ``sigma_position`` (share of the distance)."""

    R: np.ndarray
    scale: float
    t: np.ndarray
    sigma_deg: float
    sigma_position: float
    symmetric: bool = False

    def misfit(self, a: BoardPose, b: BoardPose) -> tuple[float, float]:
        """The rotation (degrees) and position (share of the distance) by which ``b`` misses ``a`` moved by the rig."""
        angle = float(min(rotation_angle_deg(b.R @ turn, self.R @ a.R) for turn in _turns(self.symmetric)))
        position = np.linalg.norm(b.centre_mm - self.scale * self.R @ a.centre_mm - self.t) / np.linalg.norm(b.centre_mm)
        return angle, float(position)

    def log_odds(self, a: BoardPose, b: BoardPose) -> float:
        """The log-odds that two poses are of one position: a folded normal of the misfits (the rig's spreads
        and the two poses' own) against a board moved anywhere within :data:`MOVE_RANGE`, at worst
        ``-MAX_AGAINST``."""
        angle, position = self.misfit(a, b)
        s_angle = np.sqrt(self.sigma_deg**2 + a.sigma_deg**2 + b.sigma_deg**2)
        s_position = np.sqrt(self.sigma_position**2 + a.sigma_position**2 + b.sigma_position**2)
        if not np.isfinite(s_angle * s_position):
            return 0.0
        d2 = (angle / s_angle) ** 2 + (position / s_position) ** 2
        peak = np.log(2.0 * MOVE_RANGE[0] * MOVE_RANGE[1] / (np.pi * s_angle * s_position))
        return float(max(peak - 0.5 * d2, -MAX_AGAINST))


def _turns(symmetric: bool) -> list[np.ndarray]:
    return [np.eye(3), _HALF_TURN] if symmetric else [np.eye(3)]


def rig_relations(cameras: list[str], poses: list[BoardPose], window: int,
                  symmetric: bool = False) -> dict[tuple[str, str], RigRelation]:
    """The relative pose of each two cameras (:class:`RigRelation`) from the pairs of their photos at most
    ``window`` apart in the roll (module docstring), where at least three pairs agree on one. ``symmetric``:
    the board looks the same turned by 180 degrees, so each photo's numbering may be the other's turned."""
    names = list(dict.fromkeys(cameras))
    out = {}
    for ia, a in enumerate(names):
        for b in names[ia + 1:]:
            pairs = [(i, j) for i in range(len(poses)) if cameras[i] == a
                     for j in range(max(0, i - window), min(len(poses), i + window + 1)) if cameras[j] == b]
            if len(pairs) < 3:
                continue
            Ra = np.stack([poses[i].R for i, _ in pairs])
            # each pair's relative rotation, with each numbering of camera b's photo: (pairs, turns, 3, 3)
            relative = np.stack([np.stack([poses[j].R @ turn for _, j in pairs]) @ np.swapaxes(Ra, 1, 2)
                                 for turn in _turns(symmetric)], axis=1)
            flat = relative.reshape(-1, 3, 3)
            agree = (rotation_angle_deg(flat[:, None], flat[None, :]) <= AGREEMENT_DEG).reshape(len(flat), len(pairs), -1)
            support = agree.any(axis=2).sum(axis=1)
            best = int(np.argmax(support))
            members = agree[best].any(axis=1)
            if members.sum() < 3:
                continue
            closest = np.argmin(rotation_angle_deg(relative, flat[best]), axis=1)
            chosen = relative[np.arange(len(pairs)), closest][members]
            R = nearest_rotation(chosen.sum(axis=0))
            sigma_deg = max(MIN_ROTATION_SIGMA_DEG, 1.4826 * float(np.median(rotation_angle_deg(chosen, R))))
            ta = np.stack([poses[i].centre_mm for i, _ in pairs])[members]
            tb = np.stack([poses[j].centre_mm for _, j in pairs])[members]
            scale = float(np.median(np.linalg.norm(tb, axis=1) / np.linalg.norm(ta, axis=1)))
            rest = tb - scale * ta @ R.T
            t = np.median(rest, axis=0)
            spread = np.linalg.norm(rest - t, axis=1) / np.linalg.norm(tb, axis=1)
            out[(a, b)] = RigRelation(R, scale, t, sigma_deg, max(MIN_POSITION_SIGMA, 1.4826 * float(np.median(spread))),
                                      symmetric)
    return out


def time_log_odds(gaps_s: np.ndarray, inside: np.ndarray | None = None, between: np.ndarray | None = None,
                  given_gap_s: float | None = None) -> tuple[np.ndarray, float]:
    """The capture-time clue of each gap between successive photos, and the gap at which it turns.

    With ``given_gap_s``, a gap up to it is one position for certain and a longer one two. Else, with at
    least two gaps ``inside`` positions and two ``between`` them (from a first split), a linear
    discriminant on the logarithms of the gaps (the two groups' means, their pooled spread, at least
    0.35); without them the prior ``1.5 ln(TYPICAL_GAP_S / gap)``. At most 6 either way.
    """
    g = np.maximum(np.asarray(gaps_s, float), 0.1)
    if given_gap_s is not None:
        return np.where(g <= given_gap_s, 15.0, -np.inf), float(given_gap_s)
    if inside is not None and between is not None and len(inside) >= 2 and len(between) >= 2:
        li, lb = np.log(np.maximum(inside, 0.1)), np.log(np.maximum(between, 0.1))
        if lb.mean() > li.mean():
            pooled = np.sqrt((np.sum((li - li.mean()) ** 2) + np.sum((lb - lb.mean()) ** 2)) / (len(li) + len(lb) - 2))
            pooled = max(pooled, 0.35)
            mid = 0.5 * (li.mean() + lb.mean())
            slope = (lb.mean() - li.mean()) / pooled**2
            return np.clip(slope * (mid - np.log(g)), -6.0, 6.0), float(np.exp(mid))
    return np.clip(1.5 * np.log(TYPICAL_GAP_S / g), -3.0, 3.0), TYPICAL_GAP_S


def best_split(pair_log_odds: np.ndarray, gap_log_odds: np.ndarray, max_run: int) -> tuple[list[list[int]], np.ndarray]:
    """The runs that maximise the summed log-odds of the pairs within them, and the margin at every gap.

    Parameters
    ----------
    pair_log_odds : (n, n) log-odds that shots i < j are one position (upper triangle; -inf: never).
    gap_log_odds : (n-1,) log-odds of successive shots from their capture times (0 without).
    max_run : the most shots in one run.

    Returns
    -------
    ``(runs, margins)``: the runs (lists of successive indices) and, for each gap k = 1..n-1 (between shots k-1
    and k), the best score minus the best score of the splits that decide the other way there (inf where none
    can).
    """
    n = len(pair_log_odds)
    run = np.full((n + 1, max_run + 1), -np.inf)     # run[s, L]: the score of the run of shots s..s+L-1
    for s in range(n):
        score = 0.0
        for L in range(1, min(max_run, n - s) + 1):
            e = s + L - 1
            if L > 1:
                score += gap_log_odds[e - 1] + pair_log_odds[s:e, e].sum()
            run[s, L] = score
    forward = np.full(n + 1, -np.inf)
    forward[0] = 0.0
    length = np.zeros(n + 1, int)
    for e in range(1, n + 1):
        options = [forward[e - L] + run[e - L, L] for L in range(1, min(max_run, e) + 1)]
        length[e] = 1 + int(np.argmax(options))
        forward[e] = options[length[e] - 1]
    backward = np.full(n + 1, -np.inf)
    backward[n] = 0.0
    for s in range(n - 1, -1, -1):
        backward[s] = max(run[s, L] + backward[s + L] for L in range(1, min(max_run, n - s) + 1))
    runs, e = [], n
    while e > 0:
        runs.append(list(range(e - length[e], e)))
        e -= length[e]
    runs.reverse()
    cuts = {r[0] for r in runs[1:]}
    best = forward[n]
    margins = np.zeros(max(n - 1, 0))
    for k in range(1, n):
        cut = forward[k] + backward[k]
        joined = max((forward[s] + run[s, e - s] + backward[e]
                      for s in range(max(0, k - max_run + 1), k) for e in range(k + 1, min(n, s + max_run) + 1)),
                     default=-np.inf)
        margins[k - 1] = best - (joined if k in cuts else cut)
    return runs, margins


def _pair_log_odds(shots: list[Shot], poses: list[BoardPose], xy_board: np.ndarray, relations, max_run: int,
                   order: dict[tuple[str, str], float] | None, symmetric: bool = False) -> np.ndarray:
    """(n, n) log-odds of each pair of shots at most ``max_run`` apart (upper triangle; module docstring)."""
    n = len(shots)
    P = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, min(n, i + max_run)):
            a, b = shots[i].camera, shots[j].camera
            if a == b:
                d = image_change(shots[i].view, shots[j].view, xy_board, symmetric)
                P[i, j] = (STILL_LOG_ODDS if d <= SAME_IMAGE else -np.inf if d >= MOVED_IMAGE else
                           STILL_LOG_ODDS * (1.0 - 2.0 * (d - SAME_IMAGE) / (MOVED_IMAGE - SAME_IMAGE)))
                continue
            if (a, b) in relations:
                P[i, j] = relations[(a, b)].log_odds(poses[i], poses[j])
            elif (b, a) in relations:
                P[i, j] = relations[(b, a)].log_odds(poses[j], poses[i])
            if order:
                P[i, j] += order.get((a, b), 0.0)
    return P


def _lens_order(shots: list[Shot], runs: list[list[int]]) -> dict[tuple[str, str], float]:
    """The log-odds against a pair of cameras shot in the order (a, b) in one position, where the runs show
    (b, a) more often: ``ln((n_ab + 1) / (n_ba + 1))``, at most 3 against; 0 for the usual order."""
    count: dict[tuple[str, str], int] = {}
    for r in runs:
        for x, i in enumerate(r):
            for j in r[x + 1:]:
                key = (shots[i].camera, shots[j].camera)
                if key[0] != key[1]:
                    count[key] = count.get(key, 0) + 1
    return {(a, b): max(float(np.log((count.get((a, b), 0) + 1) / (n_ba + 1))), -3.0)
            for (b, a), n_ba in count.items() if n_ba > count.get((a, b), 0)}


def split_positions(shots: list[Shot], xy_board: np.ndarray, focal_px: dict[str, float],
                    given_gap_s: float | None = None, symmetric: bool = False) -> PositionSplit:
    """Split a roll's shots (in shooting order, each with a board) into board positions (module docstring).

    Parameters
    ----------
    shots : the photos with a board, in shooting order.
    xy_board : (N, 2) the board's corners, mm.
    focal_px : each camera's focal length, pixels (the board's pose in its photos needs it).
    given_gap_s : a capture-time gap that decides alone (photos further apart are two positions).
    symmetric : the board looks the same turned by 180 degrees (its photos may be numbered either way round).

    Returns
    -------
    :class:`PositionSplit`, from a first split with the time prior and a second with what it taught
    (capture-time gaps, the lens order).
    """
    n = len(shots)
    if n == 0:
        return PositionSplit([], np.zeros(0), np.zeros(0), np.zeros(0), [])
    cameras = [s.camera for s in shots]
    max_run = min(longest_run(len(set(cameras))), n)
    poses = [BoardPose.of(s.view, focal_px[s.camera], xy_board) for s in shots]
    relations = rig_relations(cameras, poses, len(set(cameras)), symmetric)
    timed = all(s.taken_s is not None for s in shots)
    gaps = np.diff([s.taken_s for s in shots]) if timed else np.zeros(n - 1)
    P = _pair_log_odds(shots, poses, xy_board, relations, max_run, None, symmetric)
    T, gap_s = time_log_odds(gaps, given_gap_s=given_gap_s) if timed else (np.zeros(n - 1), None)
    runs, margins = best_split(P, T, max_run)
    order = _lens_order(shots, runs)
    if timed and given_gap_s is None:
        cut = np.zeros(n - 1, bool)
        cut[[r[0] - 1 for r in runs[1:]]] = True
        T, gap_s = time_log_odds(gaps, gaps[~cut], gaps[cut])
    if order or timed:
        P = _pair_log_odds(shots, poses, xy_board, relations, max_run, order, symmetric)
        runs, margins = best_split(P, T, max_run)
    clues = ["order"]
    if len(set(cameras)) < n:
        clues.append("board image")
    if relations:
        clues.append("board pose")
    if timed:
        clues.append("capture time")
    if order:
        clues.append("lens order")
    board = np.array([P[k - 1, k] for k in range(1, n)])
    return PositionSplit(runs, np.minimum(margins, CERTAIN), T, board, clues, gap_s)
