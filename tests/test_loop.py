"""Delayed-PD loop: exact roots, ERRATA 1 (α₁), forward and inverse maps (eqs. 23–35)."""

import math

import numpy as np
import pytest

from phoid import DelayedPD, Plant, alphas, characteristic_roots, forward_map, inverse_map, loop
from phoid.loop import (
    characteristic,
    count_roots_right_of,
    count_roots_right_of_many,
    dominant_roots,
    is_stable,
)

# Table 1 of the seed paper, sweep per ERRATA 6
TABLE1 = Plant(2.0, 1.0, 64.0)
IDX = np.arange(19)
P1 = 0.25 + 1.375 * IDX
D1 = 0.6 + 0.3 * IDX
DELAY1 = 0.1


def ols_lines(sigma, omega_d, c_prime, k_prime):
    """Eq. (35) by ordinary least squares, both lines: returns (m_c, c, m_k, k)."""
    A = np.c_[2 * sigma, -np.ones_like(sigma)]
    B = np.c_[sigma**2 + omega_d**2, -np.ones_like(sigma)]
    mc, c = np.linalg.lstsq(A, c_prime, rcond=None)[0]
    mk, k = np.linalg.lstsq(B, k_prime, rcond=None)[0]
    return mc, c, mk, k


def test_corrected_alpha1_recovers_table1_exactly_and_printed_fails():
    # ERRATA 1: from the exact roots, corrected alpha_1 gives m, c, k to machine precision,
    # the printed one about m = 1.90, c = 0.61, k = 60.6.
    modes = forward_map(TABLE1, P1, D1, DELAY1)
    cp, kp = inverse_map(modes.sigma, modes.omega_d, P1, D1, DELAY1)
    mc, c, mk, k = ols_lines(modes.sigma, modes.omega_d, cp, kp)
    for est, true in [(mc, 2.0), (mk, 2.0), (c, 1.0), (k, 64.0)]:
        assert abs(est - true) <= 1e-10 * true
    cp, kp = inverse_map(modes.sigma, modes.omega_d, P1, D1, DELAY1, printed_alpha1=True)
    mc, c, mk, k = ols_lines(modes.sigma, modes.omega_d, cp, kp)
    assert mk == pytest.approx(1.90, abs=0.01)  # ERRATA 1's numbers
    assert c == pytest.approx(0.61, abs=0.01)
    assert k == pytest.approx(60.6, abs=0.1)


def test_without_compensation_matches_errata5():
    modes = forward_map(TABLE1, P1, D1, DELAY1)
    cp, kp = inverse_map(modes.sigma, modes.omega_d, P1, D1, DELAY1, compensate=False)
    np.testing.assert_array_equal(cp, D1)
    _mc, c, mk, k = ols_lines(modes.sigma, modes.omega_d, cp, kp)
    assert mk == pytest.approx(0.98, abs=0.01)  # ERRATA 5
    assert c == pytest.approx(2.9, abs=0.05)
    assert k == pytest.approx(31.3, abs=0.1)


def test_delay_identity_eq28a():
    # ERRATA 1: e^{-s dt} = (alpha1 - sigma alpha2) - alpha2 s exactly for s = -sigma + i omega_d
    s = forward_map(TABLE1, P1, D1, DELAY1)
    root = -s.sigma + 1j * s.omega_d
    a1, a2 = alphas(s.sigma, s.omega_d, DELAY1)
    np.testing.assert_allclose(
        np.exp(-root * DELAY1), (a1 - s.sigma * a2) - a2 * root, rtol=0, atol=1e-14
    )


def test_forward_map_consistent_with_eq33():
    s = forward_map(TABLE1, P1, D1, DELAY1)
    np.testing.assert_allclose(s.c_eq, 2 * TABLE1.m * s.sigma, rtol=1e-12)
    np.testing.assert_allclose(s.k_eq, TABLE1.m * s.omega0_sq, rtol=1e-12)
    # the spec's example run: sigma 0.3803, omega_d 5.7389 for run 1
    assert s.sigma[0] == pytest.approx(0.3803, abs=5e-5)
    assert s.omega_d[0] == pytest.approx(5.7389, abs=5e-5)


def test_no_delay_reduces_to_added_gains():
    # Δt = 0: alpha1 = 1, alpha2 = 0, c'_i = D_i, k'_i = P_i (text after eq. 32)
    s = forward_map(TABLE1, P1, D1, 0.0)
    np.testing.assert_allclose(s.c_prime, D1, rtol=1e-14)
    np.testing.assert_allclose(s.k_prime, P1, rtol=1e-14)
    roots = characteristic_roots(TABLE1, DelayedPD(3.0, 1.2, 0.0))
    np.testing.assert_allclose(np.sort_complex(roots), np.sort_complex(np.roots([2, 2.2, 67])))


@pytest.mark.parametrize(
    ("plant", "P", "D", "delay"),
    [
        (TABLE1, 0.25, 0.6, 0.1),
        (TABLE1, 25.0, 6.0, 0.1),
        (Plant(0.5, 40.0, 20.0), 300.0, -35.0, 0.005),  # heavily overdamped plant, negative D
        (Plant(1.0, 10.0, 0.0), 150.0, -8.0, 0.01),  # mass-damper
        (Plant(1.0, 2.0, 50.0), 40.0, 0.0, 0.03),  # P-only loop
        (Plant(1.0, 0.1, 10.0), 60.0, 3.0, 0.2),  # unstable loop
    ],
)
def test_roots_are_roots_and_none_missed(plant, P, D, delay):
    roots = characteristic_roots(plant, DelayedPD(P, D, delay), count=4)
    f, _ = characteristic(roots, plant.m, plant.c, plant.k, P, D, delay)
    scale = plant.m * np.abs(roots) ** 2 + abs(P) + plant.k
    assert np.all(np.abs(f) <= 1e-12 * scale)
    assert np.all(np.diff(roots.real) <= 1e-12)
    # Independent brute force: Newton from a dense grid of starting points in the region where
    # every root right of the last returned one must lie; none may be right of the returned set.
    a = roots[-1].real - 0.1  # strictly between roots: the brute force covers [a, ...)
    gx, gy = np.meshgrid(np.linspace(a, 60, 60), np.linspace(-400, 400, 801))
    z = (gx + 1j * gy).ravel()
    for _ in range(60):
        fz, dfz = characteristic(z, plant.m, plant.c, plant.k, P, D, delay)
        z = z - fz / dfz
    fz, _ = characteristic(z, plant.m, plant.c, plant.k, P, D, delay)
    found = z[np.isfinite(z) & (np.abs(fz) < 1e-8 * (np.abs(z) ** 2 + 1)) & (z.real > a)]
    for zi in found:
        assert np.min(np.abs(roots - zi)) < 1e-6 * max(1.0, abs(zi))
    # the argument-principle certificate agrees with the list
    assert count_roots_right_of(a, plant.m, plant.c, plant.k, P, D, delay) == roots.size


def test_critical_delay_of_p_loop_matches_analytic_crossing():
    # m s^2 + c s + P e^{-s tau}: at a crossing s = i w, P^2 = m^2 w^4 + c^2 w^2 and
    # w tau = atan2(c w, m w^2) (derived by hand from |.| and arg of the equation).
    m, c, P = 1.0, 0.5, 30.0
    w2 = (-(c**2) + math.sqrt(c**4 + 4 * m**2 * P**2)) / (2 * m**2)
    w = math.sqrt(w2)
    tau_star = math.atan2(c * w, m * w2) / w
    plant = Plant(m, c, 0.0)
    r = characteristic_roots(plant, DelayedPD(P, 0.0, tau_star), count=2)[0]
    assert abs(r.real) < 1e-9 and r.imag == pytest.approx(w, rel=1e-9)
    assert is_stable(plant, DelayedPD(P, 0.0, 0.99 * tau_star))
    assert not is_stable(plant, DelayedPD(P, 0.0, 1.01 * tau_star))


def test_pure_delayed_spring_is_unstable():
    # m s^2 + P e^{-s tau} = 0 always has roots in the right half-plane for tau > 0
    assert not is_stable(Plant(1.0, 0.0, 0.0), DelayedPD(10.0, 0.0, 0.01))


def test_dominant_roots_newton_matches_certified():
    s_cert = dominant_roots(2.0, 1.0, 64.0, P1, D1, DELAY1)
    guess = s_cert * (1 + 0.02)
    s_newton = dominant_roots(2.0, 1.0, 64.0, P1, D1, DELAY1, guess)
    np.testing.assert_allclose(s_newton, s_cert, rtol=1e-13)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"P": 1, "D": 1, "delay": -0.1}, "`delay`"), ({"P": float("nan"), "D": 1}, "`P`"),
     ({"P": 1, "D": float("inf")}, "`D`")],
)
def test_bad_loop_raises(kwargs, name):
    with pytest.raises(ValueError, match=name):
        DelayedPD(**kwargs)


def test_batched_root_count_matches_the_scalar_count():
    # count_roots_right_of_many is the scalar argument-principle count vectorised over loops
    # (same contour, common sampling): wherever it decides (not −1) it must give the scalar
    # count, and the count must equal the number of exact roots right of the abscissa
    # (characteristic_roots, certified). Abscissae sit midway between consecutive root real
    # parts, where both counts are well conditioned; the Table 1 sweep has a common delay.
    plant = TABLE1
    a_list, want, near = [], [], []
    for P, D in zip(P1, D1, strict=True):
        roots = characteristic_roots(plant, DelayedPD(P, D, DELAY1), count=8)
        re = np.unique(np.round(roots.real, 9))[::-1]
        j = int(P) % (re.size - 1)  # a different gap for different runs
        a = 0.5 * (re[j] + re[j + 1])
        a_list.append(a)
        want.append(int(np.count_nonzero(roots.real > a)))
        near.append(roots)
    got = count_roots_right_of_many(np.array(a_list), plant.m, plant.c, plant.k, P1, D1,
                                    DELAY1, near=near)
    scalar = [count_roots_right_of(a, plant.m, plant.c, plant.k, P, D, DELAY1, near=r)
              for a, P, D, r in zip(a_list, P1, D1, near, strict=True)]
    assert np.all(got >= 0)  # these loops need no refinement beyond the common sampling
    assert got.tolist() == scalar == want
    # added masses differ per loop: an array m broadcasts like P and D
    m_arr = plant.m + np.linspace(0.0, 1.0, P1.size)
    got_m = count_roots_right_of_many(np.full(P1.size, -0.05), m_arr, plant.c, plant.k, P1, D1,
                                      DELAY1)
    ref_m = [count_roots_right_of(-0.05, mm, plant.c, plant.k, P, D, DELAY1)
             for mm, P, D in zip(m_arr, P1, D1, strict=True)]
    assert [g for g in got_m.tolist() if g >= 0] == [r for g, r in zip(got_m, ref_m,
                                                                        strict=True) if g >= 0]


# the mass-damper loop at P = 400 N/m, Δt = 10 ms: between D = 0.5 and 1 N·s/m a real root
# comes in from the left (printed by characteristic_roots: 8 roots of the first 8, none real, at
# D ≤ 0.5; 9 with one real at D ≥ 1), a change of the root structure the continuation must
# cross (also with P rising from 200 to 680 N/m, runs shuffled); the Table 1 sweep is smooth
# (every run continues from the first)
_MD_D = np.linspace(-6.0, 6.0, 25)
_MD_ORDER = np.random.default_rng(1).permutation(25)  # the same runs in a shuffled order
ROOT_SWEEPS = {
    "table1": (TABLE1, P1, D1, DELAY1),
    "d-up": (Plant(1.0, 10.0, 0.0), np.full(25, 400.0), _MD_D, 0.01),
    "d-down": (Plant(1.0, 10.0, 0.0), np.full(25, 400.0), _MD_D[::-1].copy(), 0.01),
    "shuffled": (Plant(1.0, 10.0, 0.0), (200.0 + 20.0 * np.arange(25.0))[_MD_ORDER],
                 _MD_D[_MD_ORDER], 0.01),
}


@pytest.mark.parametrize("count", [8, 2])
@pytest.mark.parametrize("name", list(ROOT_SWEEPS))
def test_rightmost_roots_many_matches_per_run_roots(name, count, monkeypatch):
    # _rightmost_roots_many (continuation across runs, batched and one at a time, certified)
    # must return, run by run, the roots that the certified per-run computation
    # _rightmost_roots gives (the same number of roots, in the same order). Each root is
    # Newton-converged (|f| at rounding level) from a different start in the two, so they
    # agree to a few ulps; 1e-12 of max(|s|, 1) is far below any spacing between the roots
    # (> 1 1/s here) and 1000 times the differences seen (6e-16).
    plant, P, D, delay = ROOT_SWEEPS[name]
    ref = [loop._rightmost_roots(plant.m, plant.c, plant.k, float(p), float(d), delay,
                                 count=count) for p, d in zip(P, D, strict=True)]
    full = loop._rightmost_roots
    calls = []
    monkeypatch.setattr(loop, "_rightmost_roots",
                        lambda *a, **kw: calls.append(a) or full(*a, **kw))
    got = loop._rightmost_roots_many(plant.m, plant.c, plant.k, P, D, delay, count=count)
    assert len(got) == P.size
    for r, g in zip(ref, got, strict=True):
        assert g.shape == r.shape
        np.testing.assert_array_less(np.abs(g - r), 1e-12 * np.maximum(np.abs(r), 1.0))
    if name == "table1":
        assert len(calls) == 1  # smooth: only the first run is computed in full
    elif count == 8:
        # the sweep does cross the change: runs without a real root and runs with one
        assert {r.size % 2 for r in ref} == {0, 1}
