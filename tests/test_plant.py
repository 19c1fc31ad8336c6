"""Plant: the unified free response of eqs. (2)–(15) against closed forms and an ODE solver.

References: closed forms evaluated in 50-digit arithmetic with mpmath (so the reference itself has
no cancellation near critical damping), and the ODE integrated by mpmath's Taylor-series solver at
20 digits (independent of the closed forms).
"""

import math

import mpmath as mp
import numpy as np
import pytest

from phoid import Plant

mp.mp.dps = 50


def closed_form(m, c, k, x0, v0, t):
    """Textbook closed form, exact in 50-digit arithmetic, per regime (eqs. 2, 12, 15)."""
    m, c, k, x0, v0 = (mp.mpf(repr(float(z))) for z in (m, c, k, x0, v0))
    sig = c / (2 * m)
    w0sq = k / m
    q = sig**2 - w0sq
    out = []
    for ti in t:
        ti = mp.mpf(repr(float(ti)))
        if q > 0:  # two real exponentials
            w = mp.sqrt(q)
            s1, s2 = -sig + w, -sig - w
            a = (v0 - s2 * x0) / (s1 - s2)
            b = x0 - a
            out.append(a * mp.e ** (s1 * ti) + b * mp.e ** (s2 * ti))
        elif q == 0:  # critical: (x0 + (v0 + sig x0) t) e^{-sig t}
            out.append((x0 + (v0 + sig * x0) * ti) * mp.e ** (-sig * ti))
        else:  # eq. (15) with amplitude and phase of eqs. (6)-(7), conjugate form
            wd = mp.sqrt(-q)
            amp = mp.sqrt(v0**2 + 2 * sig * v0 * x0 + w0sq * x0**2) / wd
            phi0 = mp.atan2(-x0, (v0 + sig * x0) / wd)
            out.append(amp * mp.e ** (-sig * ti) * mp.sin(wd * ti - phi0))
    return np.array([float(z) for z in out])


def plant_with_zeta(zeta, m=2.0, k=64.0):
    return Plant(m, 2.0 * zeta * math.sqrt(m * k), k)


@pytest.mark.parametrize("zeta", [0.05, 1 - 1e-9, 1.0, 1 + 1e-9, 5.0, 50.0])
@pytest.mark.parametrize(("x0", "v0"), [(0.01, 0.0), (0.0, 0.05), (0.01, -0.2)])
def test_free_response_matches_closed_form(zeta, x0, v0):
    p = plant_with_zeta(zeta)
    t = np.linspace(0.0, 6.0, 61)
    x, _ = p.free_response(t, x0, v0)
    ref = closed_form(p.m, p.c, p.k, x0, v0, t)
    # 1e-13 of the initial state scale: double-precision rounding of the unified formula
    scale = abs(x0) + abs(v0) / p.omega0
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-13 * scale)


def test_continuous_through_critical_damping():
    # The same formula on both sides of zeta = 1 must differ only by O(delta zeta): no 0/0 jump.
    t = np.linspace(0.0, 3.0, 301)
    xs = [plant_with_zeta(z).free_response(t, 0.01, 0.0)[0] for z in (1 - 1e-12, 1, 1 + 1e-12)]
    # d x / d zeta is O(x0) here, so a 1e-12 change in zeta moves x by ~1e-14 m
    assert np.max(np.abs(xs[0] - xs[1])) < 1e-13
    assert np.max(np.abs(xs[2] - xs[1])) < 1e-13


def test_eq12_critical_from_rest_position():
    # eq. (12) holds for x0 = 0 (it needs phi0 = 0): x = t e^{-sigma t} |v0|
    p = plant_with_zeta(1.0)
    t = np.linspace(0, 2, 21)
    x, _ = p.free_response(t, 0.0, 0.3)
    # a few roundings and one exp on each side (<= ~4 ulp each): ~1e-15 relative; 10x that
    # (observed 1.3e-16); atol for x(0) = 0
    np.testing.assert_allclose(x, t * np.exp(-p.sigma * t) * 0.3, rtol=1e-14, atol=1e-16)


def test_mass_damper_k_zero():
    # k = 0: x = x0 + v0 (1 - e^{-2 sigma t}) / (2 sigma), integral of a first-order decay (eq. 9)
    p = Plant(1.5, 3.0, 0.0)
    t = np.linspace(0, 5, 51)
    x, xd = p.free_response(t, 0.01, 0.2)
    s2 = 2 * p.sigma
    # x ~ x0 + v0/2σ with no cancellation: a few roundings and one exp, ~1e-15; 10x that
    np.testing.assert_allclose(x, 0.01 + 0.2 * (1 - np.exp(-s2 * t)) / s2, rtol=1e-14)
    # velocity to rounding of the initial velocity scale (C − σS cancels to e^{-2σt} here): the
    # terms are ~v0/2 each, so a handful of roundings (1.1e-16 each) plus exp's error (<= ~4 ulp
    # in numpy's SIMD/libm variants) bound it by ~1e-15 v0; 10x that (observed 3e-17, ~1 ulp)
    np.testing.assert_allclose(xd, 0.2 * np.exp(-s2 * t), rtol=0, atol=1e-14 * 0.2)
    assert p.zeta == math.inf and p.omega0 == 0.0
    np.testing.assert_allclose(p.roots, [0.0, -s2])


def test_no_damping_no_stiffness():
    # m only: free flight x = x0 + v0 t
    p = Plant(1.0, 0.0, 0.0)
    t = np.linspace(0, 3, 7)
    x, _ = p.free_response(t, 0.1, 0.5)
    # x0 C + v0 S with C = 1, S = t: two or three roundings (<= 3.3e-16 relative), ~3x margin,
    # tight on purpose: any approximation in the σ = ω0 = 0 limit would show at >= 1e-12
    np.testing.assert_allclose(x, 0.1 + 0.5 * t, rtol=1e-15)


def ode_reference(m, c, k, x0, v0, t):
    """x, v of m x'' + c x' + k x = 0 integrated by mpmath's Taylor-series ODE solver.

    ``mp.odefun`` picks degree and step so that each step's error is below the working precision
    (20 digits here), so over these few hundred steps the reference is good to ~1e-17 of the state
    scale: it integrates the ODE, independently of the closed forms, with an error far below the
    double-precision rounding the tests allow the formula.
    """
    with mp.workdps(20):
        mm, cc, kk = (mp.mpf(repr(float(z))) for z in (m, c, k))
        sol = mp.odefun(
            lambda _t, y: [y[1], -(cc * y[1] + kk * y[0]) / mm],
            0,
            [mp.mpf(repr(float(x0))), mp.mpf(repr(float(v0)))],
        )
        out = [sol(mp.mpf(repr(float(ti)))) for ti in t]
    return np.array([[float(y[0]) for y in out], [float(y[1]) for y in out]])


@pytest.mark.parametrize("zeta", [0.05, 0.7, 1.0, 5.0])
def test_free_response_matches_ode_solver(zeta):
    # Reference: the ODE integrated to ~1e-17 of the state scale (mpmath Taylor series, see
    # ode_reference). It used to be scipy's DOP853 at rtol 1e-12, whose own error at zeta = 5
    # is ~1e-11 m here and machine-dependent (1.11e-11 failed a 1e-11 tolerance on another
    # CPU); that error does not shrink with a tighter rtol (3e-12 at rtol 2.2e-14), so DOP853
    # cannot serve as a reference at the formula's rounding level.
    p = plant_with_zeta(zeta)
    t = np.linspace(0.0, 4.0, 81)
    ref_x, ref_v = ode_reference(p.m, p.c, p.k, 0.01, 0.1, t)
    x, xd = p.free_response(t, 0.01, 0.1)
    # The bound is the unified formula's double-precision rounding, as in the closed-form test:
    # 1e-13 of the state scale (a few dozen operations at 1.1e-16 each is ~1e-14; observed
    # errors are <= 1e-16 of the scale, so the margin to the bound is ~10x and to the observed
    # ~1000x, and a wrong formula -- an error in a digit of sigma, a sign -- is off by >= 1e-6).
    scale_x = 0.01 + 0.1 / p.omega0
    scale_v = 0.1 + p.omega0 * 0.01 + 2 * p.sigma * 0.01
    np.testing.assert_allclose(x, ref_x, rtol=0, atol=1e-13 * scale_x)
    np.testing.assert_allclose(xd, ref_v, rtol=0, atol=1e-13 * scale_v)


def test_heavily_overdamped_long_time_no_overflow():
    # zeta = 50 over a time where e^{sigma t} overflows: the slow root dominates, exactly
    p = plant_with_zeta(50.0)
    t = np.array([0.0, 100.0, 2000.0])
    x, _ = p.free_response(t, 0.01, 0.0)
    assert np.all(np.isfinite(x))
    np.testing.assert_allclose(x, closed_form(p.m, p.c, p.k, 0.01, 0.0, t), rtol=1e-12)


def test_derived_quantities():
    p = Plant(2.0, 1.0, 64.0)
    assert p.sigma == 0.25  # eq. (3): c / 2m
    assert p.omega0 == pytest.approx(math.sqrt(32.0), rel=1e-15)  # eq. (5)
    assert p.zeta == pytest.approx(1.0 / (2 * math.sqrt(128.0)), rel=1e-15)  # eq. (10)
    assert p.regime == "underdamped"
    assert plant_with_zeta(1.0).regime == "critical"
    assert plant_with_zeta(3.0).regime == "overdamped"
    r = plant_with_zeta(3.0).roots
    np.testing.assert_allclose(2.0 * r**2 + plant_with_zeta(3.0).c * r + 64.0, 0, atol=1e-10)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"m": 0.0, "c": 1, "k": 1}, "`m`"),
        ({"m": -1.0, "c": 1, "k": 1}, "`m`"),
        ({"m": 1.0, "c": -0.1, "k": 1}, "`c`"),
        ({"m": 1.0, "c": 1, "k": -2}, "`k`"),
        ({"m": 1.0, "c": 1, "k": 1, "fc": -0.5}, "`fc`"),
        ({"m": float("nan"), "c": 1, "k": 1}, "`m`"),
        ({"m": 1.0, "c": float("inf"), "k": 1}, "`c`"),
        ({"m": "heavy", "c": 1, "k": 1}, "`m`"),
    ],
)
def test_bad_plant_raises_with_name_and_value(kwargs, name):
    with pytest.raises(ValueError, match=name) as err:
        Plant(**kwargs)
    bad = next(v for k, v in kwargs.items() if f"`{k}`" == name)
    assert str(bad if not isinstance(bad, float) else f"{bad:g}") in str(err.value) or "nan" in str(
        err.value
    ) or "inf" in str(err.value)


def test_free_response_refuses_friction():
    with pytest.raises(ValueError, match="`fc`"):
        Plant(1, 1, 1, fc=0.1).free_response(0.0, 0.01)
