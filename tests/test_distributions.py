"""dualcal's F quantile (the calibration's path does not import scipy) against scipy's."""

import pytest
from scipy.special import betainc, fdtri

from dualcal.estimation.distributions import f_quantile, regularized_beta


@pytest.mark.parametrize("d1", [1, 2, 3, 6, 10])
def test_the_f_quantile_is_scipys(d1):
    for d2 in (1, 2, 3, 5, 10, 13, 47, 200, 5000):
        for q in (0.5, 0.9, 0.99, 0.999):
            assert f_quantile(d1, d2, q) == pytest.approx(fdtri(d1, d2, q), rel=1e-8), (d1, d2, q)


def test_the_incomplete_beta_is_scipys():
    for a in (0.5, 1.0, 3.0, 40.0):
        for b in (0.5, 2.5, 60.0):
            for x in (0.0, 1e-6, 0.2, 0.5, 0.9, 1 - 1e-7, 1.0):
                assert regularized_beta(a, b, x) == pytest.approx(betainc(a, b, x), abs=1e-13), (a, b, x)


def test_a_quantile_outside_its_domain_is_refused():
    with pytest.raises(ValueError, match="0 < q < 1"):
        f_quantile(3, 10, 1.0)
