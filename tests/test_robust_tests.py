"""Values judged against a robust core of the others (dualcal.estimation.robust_tests): bad values cannot hide each
other, the tests have the stated rate on values of one normal, and a split into two groups is found."""

import numpy as np
import pytest

from dualcal.estimation.robust_tests import core_tests, cube_root_spread, robust_core, split_test


def _values(rng, n=20, bad=(), shift=8.0):
    r = rng.uniform(0.5, 2.0, n)                 # each value's own spread
    x = 3.0 + r * rng.standard_normal(n)
    x[list(bad)] += shift * r[list(bad)]
    return x, r


def test_three_far_values_cannot_hide_each_other():
    """Three of twenty values 8 of their spreads off: the core leaves them out and each is named at 1e-3, where
    judged against every other value (the textbook test) they widen each other's spread and none is."""
    x, r = _values(np.random.default_rng(1), bad=(3, 7, 11))
    core = robust_core(x, r, 1e-3)
    assert set(np.flatnonzero(~core)) == {3, 7, 11}
    named = {i for i, t in enumerate(core_tests(x, r, core, two_sided=True)) if t.p < 1e-3}
    assert named == {3, 7, 11}
    textbook = {i for i, t in enumerate(core_tests(x, r, np.ones(len(x), bool), two_sided=True)) if t.p < 1e-3}
    assert textbook == set()


def test_the_tests_are_scale_free_and_one_sided_tests_name_only_values_above():
    x, r = _values(np.random.default_rng(2), bad=(5,))
    x[9] -= 10 * r[9]                            # one far below: a better fit, not a fault (rig_rigid)
    a = core_tests(x, r, robust_core(x, r, 1e-3), two_sided=False)
    b = core_tests(1000 * x, 1000 * r, robust_core(1000 * x, 1000 * r, 1e-3), two_sided=False)
    assert [t.t for t in a] == pytest.approx([t.t for t in b]) and [t.p for t in a] == pytest.approx([t.p for t in b])
    assert a[5].p < 1e-4 and a[9].p > 0.99
    assert a[5].t == pytest.approx(a[5].limit(a[5].p, two_sided=False), rel=1e-6)   # the limit at its own p is t


def test_on_values_of_one_normal_the_tests_keep_their_rate():
    """800 draws of 13 values (a rig of 13 instants), the core found at 1e-3: each value's p-value against the
    core without it is uniform (the externally studentised residual's Student t), within the sampling error of
    10400 values; the core is every value but where a test fails, so below 1e-2 are about as many as with every
    other value as the core (the textbook test)."""
    rng = np.random.default_rng(3)
    p, textbook = [], []
    for _ in range(800):
        x, r = _values(rng, n=13)
        p += [t.p for t in core_tests(x, r, robust_core(x, r, 1e-3), two_sided=True)]
        textbook += [t.p for t in core_tests(x, r, np.ones(13, bool), two_sided=True)]
    p, textbook = np.array(p), np.array(textbook)
    for a in (0.01, 0.05, 0.2):
        assert abs(np.mean(p < a) - a) < 4 * np.sqrt(a * (1 - a) / len(p)) + 0.1 * a, (a, np.mean(p < a))
    assert np.mean(p < 0.01) < 1.2 * np.mean(textbook < 0.01)


def test_cube_roots_of_chi_square_statistics_have_the_spread_said():
    """(chi^2_k / k)^(1/3) has the standard deviation sqrt(2 / (9 k)) (Wilson and Hilferty), within 3 %."""
    rng = np.random.default_rng(4)
    for k in (6, 12):
        x = np.cbrt(rng.chisquare(k, 200000) / k)
        assert np.std(x) == pytest.approx(cube_root_spread([k])[0], rel=0.03)


def test_two_groups_are_split_and_one_is_not():
    """Sixteen values in two groups of eight, 6 of their spreads apart: the split test fails and finds the groups;
    one group of sixteen: it fails at its rate (50 of 1000 draws at 5 %, within their sampling error)."""
    rng = np.random.default_rng(5)
    r = rng.uniform(0.5, 2.0, 16)
    x = r * rng.standard_normal(16)
    x[8:] += 6.0 * np.sqrt(np.mean(r ** 2))
    found = split_test(x, r, 0.001)
    assert found["f"] > found["limit"] and set(np.flatnonzero(found["lower"])) == set(range(8))
    from dualcal.estimation.robust_tests import _split_f
    limit = split_test(x, r, 0.05)["limit"]
    null = np.max(_split_f(r * rng.standard_normal((1000, 16)), 1.0 / r ** 2)[1], axis=1)
    fails = int(np.sum(null > limit))
    assert 25 <= fails <= 80, fails
    assert split_test(x[:5], r[:5], 0.01) is None                     # too few to split into two groups of 3
