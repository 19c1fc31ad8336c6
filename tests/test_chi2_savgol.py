"""phoid's own χ² quantile (phoid.methods.chi2) and Savitzky–Golay filter (phoid.methods.savgol).

The PHO path computes both without importing scipy.special or scipy.signal; scipy's
implementations (which the tests may import) are the reference. Tolerances: 1e-10 relative for
the quantile (it reaches ~1e-13 over dof 1 … 10⁶ and tails 1e-12 … 0.5), 1e-12 of the record's
scale for the filter (rounding in the least-squares weights).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal, special

from phoid.methods.chi2 import chi2_isf, chi2_sf, gamma_p, gamma_q
from phoid.methods.savgol import savgol_filter

DOFS = np.unique(np.round(np.logspace(0, 6, 31)))      # 1 … 10⁶, log-spaced
TAILS = np.logspace(-12, math.log10(0.5), 25)          # 1e-12 … 0.5


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_isf_matches_scipy(dof):
    got = np.array([chi2_isf(p, dof) for p in TAILS])
    want = special.chdtri(dof, TAILS)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=0)


@pytest.mark.parametrize("dof", [0.3, 1, 2, 7, 1000, 123456])
def test_chi2_isf_is_the_inverse_of_the_tail_and_covers_the_lower_half(dof):
    for p in (1e-300, 1e-30, 1e-3, 0.5, 0.7, 0.99, 1 - 1e-9):
        x = chi2_isf(p, dof)
        np.testing.assert_allclose(x, special.chdtri(dof, p), rtol=1e-10)
        # the smaller tail, computed without cancellation, returns p
        if p <= 0.5:
            np.testing.assert_allclose(chi2_sf(x, dof), p, rtol=1e-11)
        else:
            np.testing.assert_allclose(gamma_p(0.5 * dof, 0.5 * x), 1 - p, rtol=1e-11)


def test_the_pho_threshold_is_scipys():
    # the 99.9 % test of the PHO fits: chdtri(dof, 0.001)
    for dof in range(1, 400):
        assert chi2_isf(0.001, dof) == pytest.approx(special.chdtri(dof, 0.001), rel=1e-12)


def test_incomplete_gamma_matches_scipy():
    rng = np.random.default_rng(7)
    a = 10 ** rng.uniform(-1, 5, 400)
    x = a * np.exp(rng.normal(0, 1.0, a.size) / np.sqrt(np.maximum(a, 1) / 10))
    P = np.array([gamma_p(ai, xi) for ai, xi in zip(a, x, strict=True)])
    Q = np.array([gamma_q(ai, xi) for ai, xi in zip(a, x, strict=True)])
    np.testing.assert_allclose(P + Q, 1.0, rtol=0, atol=1e-15)
    # relative where the value is not negligible (the far tails differ in the last digits
    # between implementations, scipy's included)
    big = special.gammainc(a, x) > 1e-6
    np.testing.assert_allclose(P[big], special.gammainc(a, x)[big], rtol=1e-12)
    big = special.gammaincc(a, x) > 1e-6
    np.testing.assert_allclose(Q[big], special.gammaincc(a, x)[big], rtol=1e-12)
    assert gamma_p(2.0, 0.0) == 0.0 and gamma_q(2.0, 0.0) == 1.0
    assert gamma_p(2.0, math.inf) == 1.0 and gamma_q(2.0, math.inf) == 0.0


def test_incomplete_gamma_far_below_the_mode():
    """x ≪ a (a noise-free fit's χ² of ~1e-300 on many degrees of freedom): x/a − 1 rounds to
    −1, where ln(1 + u) is undefined; P and Q are still scipy's (to rounding) and Q ≤ 1."""
    a = np.array([10.5, 50.0, 700.0, 1e4, 1e5])
    for x in (1e-300, 1e-20, 1e-3):
        P = np.array([gamma_p(ai, x) for ai in a])
        Q = np.array([gamma_q(ai, x) for ai in a])
        np.testing.assert_allclose(Q, special.gammaincc(a, x), rtol=1e-15)
        np.testing.assert_allclose(P, special.gammainc(a, x), rtol=1e-12, atol=1e-300)
    frac = np.linspace(0.05, 0.6, 12)  # across the switch of forms at x = a/2
    for ai in (20.0, 700.0):
        P = np.array([gamma_p(ai, f * ai) for f in frac])
        big = special.gammainc(ai, frac * ai) > 1e-280
        np.testing.assert_allclose(P[big], special.gammainc(ai, frac * ai)[big], rtol=1e-11)


@pytest.mark.parametrize("dof", [0, -1, math.nan, math.inf])
def test_chi2_isf_refuses_bad_dof(dof):
    with pytest.raises(ValueError, match="dof"):
        chi2_isf(0.01, dof)


@pytest.mark.parametrize("p", [0.0, 1.0, -0.1, 1.5, math.nan])
def test_chi2_isf_refuses_bad_probability(p):
    with pytest.raises(ValueError, match="p must be in"):
        chi2_isf(p, 3)


@pytest.mark.parametrize(("a", "x"), [(0.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, math.nan)])
def test_incomplete_gamma_refuses_bad_arguments(a, x):
    with pytest.raises(ValueError):
        gamma_p(a, x)
    with pytest.raises(ValueError):
        gamma_q(a, x)


@pytest.mark.parametrize("n", [11, 12, 31, 1000])
@pytest.mark.parametrize(("window", "order"), [(11, 2), (5, 2), (7, 3), (3, 0), (1, 0)])
def test_savgol_matches_scipy(n, window, order):
    rng = np.random.default_rng(n * 100 + window * 10 + order)
    x = 3 * rng.normal(size=n) + np.cumsum(rng.normal(size=n))
    for deriv in range(order + 2):
        for delta in (1.0, 0.37e-3):
            got = savgol_filter(x, window, order, deriv=deriv, delta=delta)
            want = signal.savgol_filter(x, window, order, deriv=deriv, delta=delta)
            scale = max(np.max(np.abs(want)), 1e-300)
            assert np.max(np.abs(got - want)) <= 1e-12 * scale, (deriv, delta)


def test_savgol_of_a_polynomial_is_exact():
    t = np.linspace(0.0, 1.0, 101)
    h = t[1] - t[0]
    x = 2 - 3 * t + 5 * t**2
    np.testing.assert_allclose(savgol_filter(x, 11, 2), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(savgol_filter(x, 11, 2, deriv=1, delta=h), -3 + 10 * t,
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize(("args", "match"), [
    ((np.zeros(20), 10, 2), "odd"),
    ((np.zeros(20), 5, 5), "polyorder"),
    ((np.zeros(8), 11, 2), "shorter"),
    ((np.zeros((4, 20)), 5, 2), "1-D"),
])
def test_savgol_refuses_bad_arguments(args, match):
    with pytest.raises(ValueError, match=match):
        savgol_filter(*args)
