"""The board positions of a camera roll from its clues (dualcal.files.roll_positions): the best split, its margins."""

import itertools

import numpy as np
import pytest

from dualcal.files import roll_positions as rp


def _score(runs, P, T):
    """The summed log-odds of a split: successive shots' times and every pair's, within each run."""
    return sum(sum(T[j - 1] for j in r[1:]) + sum(P[a, b] for a, b in itertools.combinations(r, 2)) for r in runs)


def _all_splits(n, max_run):
    for cuts in itertools.product([False, True], repeat=n - 1):
        runs, start = [], 0
        for k, cut in enumerate(cuts, 1):
            if cut:
                runs.append(list(range(start, k)))
                start = k
        runs.append(list(range(start, n)))
        if max(len(r) for r in runs) <= max_run:
            yield runs


@pytest.mark.parametrize("seed", range(4))
def test_the_best_split_and_its_margins_are_those_of_every_split_tried(seed):
    rng = np.random.default_rng(seed)
    n, max_run = 9, 4
    P = np.triu(rng.normal(0, 3, (n, n)), 1)
    P[2, 3] = -np.inf                                   # a board moved in one camera's photos: never one run
    T = rng.normal(0, 2, n - 1)
    runs, margins = rp.best_split(P, T, max_run)
    scores = {tuple(map(tuple, r)): _score(r, P, T) for r in _all_splits(n, max_run)}
    best = max(scores.values())
    assert _score(runs, P, T) == pytest.approx(best)
    assert all(3 not in r or 2 not in r for r in runs)
    cut_at = {r[0] for r in runs[1:]}
    for k in range(1, n):
        other = max(s for split, s in scores.items() if (k in {r[0] for r in split[1:]}) != (k in cut_at))
        assert margins[k - 1] == pytest.approx(best - other)


def test_the_capture_times_are_learnt_from_the_split_and_a_given_gap_decides():
    gaps = np.array([2.0, 3.0, 40.0, 2.5, 4.6, 30.0, 1.0, 10.0])
    prior, turn = rp.time_log_odds(gaps)
    assert turn == rp.TYPICAL_GAP_S and np.all(np.diff(prior[np.argsort(gaps)]) <= 0)   # longer: less one position
    learnt, turn = rp.time_log_odds(gaps, inside=np.array([2.0, 3.0, 2.5, 4.6, 1.0]), between=np.array([40.0, 30.0]))
    assert 4.6 < turn < 30.0 and learnt[2] < -1 < 1 < learnt[4]
    given, turn = rp.time_log_odds(gaps, given_gap_s=5.0)
    assert turn == 5.0 and np.all(given[gaps <= 5] > 10) and np.all(np.isneginf(given[gaps > 5]))


def test_a_decision_is_refused_only_where_the_clues_disagree():
    split = rp.PositionSplit([[0, 1], [2]], np.array([1.0, 1.5]), np.array([-3.0, -0.5]), np.array([4.0, 0.3]), [])
    assert split.unsure_gaps() == [1, 2]
    assert split.disagreeing_gaps() == [1]             # times say two positions, boards one; gap 2: weak clues only
    assert split.run_margin(0) == 1.0 and split.run_margin(1) == 1.5


def test_the_rig_is_found_from_the_pairs_most_nearby_photos_agree_on():
    rng = np.random.default_rng(3)
    rig = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cameras, poses = [], []                           # a quarter turn about z: any rig, not only a phone's
    for _ in range(8):                                 # eight positions, two cameras each
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        c = np.append(rng.uniform(-200, 200, 2), rng.uniform(400, 900))
        cameras += ["wide", "tele"]
        poses += [rp.BoardPose(R, c), rp.BoardPose(rig @ R, rig @ c + np.array([0.0, -12.0, 0.0]))]
    relation = rp.rig_relations(cameras, poses, window=2)[("wide", "tele")]
    angle = np.degrees(np.arccos(np.clip((np.trace(relation.R.T @ rig) - 1) / 2, -1, 1)))
    assert angle < 1e-6 and relation.misfit(poses[0], poses[1])[0] < 1e-6
    assert relation.log_odds(poses[0], poses[1]) > 5 > -5 > relation.log_odds(poses[0], poses[3])
