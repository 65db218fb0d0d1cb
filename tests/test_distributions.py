"""dualcal's F and chi-square quantiles (the calibration's and the measurement's paths do not import scipy)
against scipy's."""

import pytest
from scipy.special import betainc, chdtri, fdtrc, fdtri, gammainc

from dualcal.estimation.distributions import (chi2_quantile, f_quantile, f_sf, regularized_beta, regularized_gamma,
                                              sidak)


@pytest.mark.parametrize("d1", [1, 2, 3, 6, 10])
def test_the_f_quantile_is_scipys(d1):
    for d2 in (1, 2, 3, 5, 10, 13, 47, 200, 5000):
        for q in (0.5, 0.9, 0.99, 0.999):
            assert f_quantile(d1, d2, q) == pytest.approx(fdtri(d1, d2, q), rel=1e-8), (d1, d2, q)


@pytest.mark.parametrize("d1", [1, 2, 6, 12, 72])
def test_the_f_tail_is_scipys(d1):
    for d2 in (1, 3, 11, 66, 500):
        for f in (0.0, 0.01, 0.5, 1.0, 3.0, 11.6, 80.0):
            assert f_sf(f, d1, d2) == pytest.approx(fdtrc(d1, d2, f), rel=1e-9, abs=1e-300), (d1, d2, f)
        assert f_sf(f_quantile(d1, d2, 0.999), d1, d2) == pytest.approx(0.001, rel=1e-7)


def test_the_sidak_rate_makes_the_family_rate():
    for rate in (0.01, 0.05):
        for m in (1, 2, 13, 40):
            assert 1 - (1 - sidak(rate, m)) ** m == pytest.approx(rate, rel=1e-12)
            assert rate / m <= sidak(rate, m) <= -__import__("math").log1p(-rate) / m


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
