"""dualcal's F and chi-square quantiles (the calibration's and the measurement's paths do not import scipy)
against scipy's."""

import pytest
from scipy.special import betainc, chdtri, fdtri, gammainc

from dualcal.estimation.distributions import chi2_quantile, f_quantile, regularized_beta, regularized_gamma


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


@pytest.mark.parametrize("dof", [1, 2, 3, 5, 7, 30, 100])
def test_the_chi_square_quantile_is_scipys(dof):
    for q in (0.5, 0.9, 0.99, 0.999, 0.9999):
        assert chi2_quantile(dof, q) == pytest.approx(chdtri(dof, 1.0 - q), rel=1e-12), (dof, q)


def test_the_incomplete_gamma_is_scipys():
    for a in (0.5, 1.0, 1.5, 2.5, 10.0, 50.0):
        for x in (0.0, 1e-6, 0.3, 1.0, 3.0, 10.0, 60.0, 200.0):
            assert regularized_gamma(a, x) == pytest.approx(gammainc(a, x), abs=1e-13), (a, x)


def test_a_quantile_outside_its_domain_is_refused():
    with pytest.raises(ValueError, match="0 < q < 1"):
        f_quantile(3, 10, 1.0)
    with pytest.raises(ValueError, match="0 < q < 1"):
        chi2_quantile(3, 0.0)
