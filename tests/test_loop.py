"""Delayed-PD loop: exact roots, ERRATA 1 (α₁), forward and inverse maps (eqs. 23–35)."""

import math

import numpy as np
import pytest

from phoid import DelayedPD, Plant, alphas, characteristic_roots, forward_map, inverse_map
from phoid.dynamics import (
    characteristic,
    count_roots_right_of,
    count_roots_right_of_many,
    counting,
    dominant_roots,
    is_stable,
    rightmost,
    rightmost_roots,
    rightmost_roots_many,
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
    # rightmost_roots_many (continuation across runs, batched and one at a time, certified)
    # must return, run by run, the roots that the certified per-run computation
    # rightmost_roots gives (the same number of roots, in the same order). Each root is
    # Newton-converged (|f| at rounding level) from a different start in the two, so they
    # agree to a few ulps; 1e-12 of max(|s|, 1) is far below any spacing between the roots
    # (> 1 1/s here) and 1000 times the differences seen (6e-16).
    plant, P, D, delay = ROOT_SWEEPS[name]
    ref = [rightmost.rightmost_roots(plant.m, plant.c, plant.k, float(p), float(d), delay,
                                 count=count) for p, d in zip(P, D, strict=True)]
    full = rightmost.rightmost_roots
    calls = []
    monkeypatch.setattr(rightmost, "rightmost_roots",
                        lambda *a, **kw: calls.append(a) or full(*a, **kw))
    got = rightmost.rightmost_roots_many(plant.m, plant.c, plant.k, P, D, delay, count=count)
    assert len(got) == P.size
    for r, g in zip(ref, got, strict=True):
        assert g.shape == r.shape
        np.testing.assert_array_less(np.abs(g - r), 1e-12 * np.maximum(np.abs(r), 1.0))
    if name == "table1":
        assert len(calls) == 1  # smooth: only the first run is computed in full
    elif count == 8:
        # the sweep does cross the change: runs without a real root and runs with one
        assert {r.size % 2 for r in ref} == {0, 1}


# the bench's mass-damper set with the rough plant identify_data continues from (k < 0: the
# fitted lines' stiffness of a spring-less plant): D crosses 0 between runs 4 and 5, where the
# delay chain moves by ln|D|/Δt and a real root enters from the left
MASS_DAMPER = (Plant(0.999075, 9.997728, 1.0), 110.0 + 80.0 * np.arange(12.0),
               -6.8 + 1.4 * np.arange(12.0), 0.01)
_MD_K = -0.2597680858367359


def test_continuation_crosses_d_zero_from_one_full_computation(monkeypatch):
    # With the chain's own starts (_chain_starts) added to the runs whose continuation lost
    # roots, every run of the mass-damper set continues from the first: one full computation
    # (there were three, and two more certificate rounds, before). The roots are those of the
    # per-run computation to 1e-12 of max(|s|, 1): Newton-converged from different starts
    # (differences of a few ulps, 2e-16 seen), far below the roots' spacing (> 1 1/s). Run 5
    # (D = 0.2) per run also exercises the quick attempt's fallback: its abscissa falls so
    # near a root it missed that the count does not resolve.
    plant, P, D, delay = MASS_DAMPER
    m, c = plant.m, plant.c
    ref = [rightmost.rightmost_roots(m, c, _MD_K, float(p), float(d), delay, count=12)
           for p, d in zip(P, D, strict=True)]
    full = rightmost.rightmost_roots
    calls = []
    monkeypatch.setattr(rightmost, "rightmost_roots",
                        lambda *a, **kw: calls.append(a) or full(*a, **kw))
    got = rightmost.rightmost_roots_many(m, c, _MD_K, P, D, delay, count=8)
    assert len(calls) == 1
    for r, g in zip(rightmost._trim_pairs(ref, 8), got, strict=True):
        assert g.shape == r.shape
        np.testing.assert_array_less(np.abs(g - r), 1e-12 * np.maximum(np.abs(r), 1.0))
        # a real root is exactly real in both (identification tells real modes by Im s == 0)
        assert np.array_equal(g.imag == 0, r.imag == 0)
    assert {g.size % 2 for g in got} == {0, 1}  # runs with and without the real root


def test_chain_starts_lead_newton_to_the_chain_roots():
    # Newton from the asymptotic starts finds the delay chain's roots (all but the dominant
    # pair of the first 12, for either sign of D, the real root of D > 0 included) to the
    # same 1e-12 of max(|s|, 1) as the per-run computation (both are Newton-converged)
    plant, P, D, delay = MASS_DAMPER
    P, D = P[[0, 6]], D[[0, 6]]
    starts = rightmost._chain_starts(plant.m, plant.c, _MD_K, P, D, delay, 8)
    z, res = rightmost._newton_rows(starts, plant.m, plant.c, _MD_K, P[:, None], D[:, None], delay)
    for i in range(2):
        ref = rightmost.rightmost_roots(plant.m, plant.c, _MD_K, float(P[i]), float(D[i]), delay,
                                    count=12)
        chain = [r for r in ref[2:] if r.imag >= 0]
        zi = z[i][np.isfinite(res[i])]
        for r in chain:
            assert np.min(np.abs(zi - r)) < 1e-12 * max(abs(r), 1.0)




def _designs(seed: int, count: int) -> list[tuple]:
    """Random designs (m, c, k, P, D, Δt): m in [0.1, 10] kg, c in [0, 50] N·s/m, k in
    [0, 200] N/m, Δt in [0.2, 5] ms, 5–25 runs on a line in (P, D), D of both signs."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        m, c, k, tau = rng.uniform(0.1, 10), rng.uniform(0, 50), rng.uniform(0, 200), \
            rng.uniform(2e-4, 5e-3)
        n = int(rng.integers(5, 26))
        p0, p1 = rng.uniform(0, 3 * k + 200, 2)
        d0, d1 = rng.uniform(-0.9 * c - 2, c + 10, 2)
        out.append((m, c, k, np.linspace(p0, p1, n), np.linspace(d0, d1, n), tau))
    return out


DESIGNS = _designs(11, 6)


@pytest.mark.parametrize("j", range(len(DESIGNS)))
def test_quick_full_computation_and_its_fallback_agree(j, monkeypatch):
    # rightmost_roots first tries a coarse discretisation with a short Newton; forcing that
    # attempt to find nothing (its Newton returns no converged root) exercises the fallback,
    # the full computation. Both are certified, so they are the same roots, to 1e-12 of
    # max(|s|, 1) (Newton-converged from different eigenvalues: a few ulps apart, far below
    # the roots' spacing); the same for the continuation over the design's runs.
    m, c, k, P, D, tau = DESIGNS[j]
    quick = [rightmost.rightmost_roots(m, c, k, float(p), float(d), tau, count=8)
             for p, d in zip(P, D, strict=True)]
    many = rightmost.rightmost_roots_many(m, c, k, P, D, tau, count=8)
    rows = rightmost._newton_rows
    calls = []

    def no_roots(s, *a, **kw):
        calls.append(1)
        z, res = rows(s, *a, **kw)
        return z, np.full(res.shape, np.inf)

    monkeypatch.setattr(rightmost, "_newton_rows", no_roots)
    full = [rightmost.rightmost_roots(m, c, k, float(p), float(d), tau, count=8)
            for p, d in zip(P, D, strict=True)]
    assert len(calls) == P.size  # each run tried the quick attempt once, then fell back
    for q, f, g in zip(quick, full, many, strict=True):
        assert q.shape == f.shape == g.shape
        np.testing.assert_array_less(np.abs(q - f), 1e-12 * np.maximum(np.abs(f), 1.0))
        np.testing.assert_array_less(np.abs(g - f), 1e-12 * np.maximum(np.abs(f), 1.0))


@pytest.mark.parametrize("j", range(len(DESIGNS)))
def test_outer_edges_bound_gives_the_sampled_count(j, monkeypatch):
    # The outer edges' turn of arg f from the bound |f − m s²| < m|s|² (_outer_turn) must
    # give the count of the fully sampled contour (the bound switched off: the scalar count
    # samples all edges, the batched one leaves every loop to it). Counts are integers:
    # equality. Abscissae between consecutive roots (as the certificates place them) and just
    # left of the dominant pair (as pho._dominant_many does).
    m, c, k, P, D, tau = DESIGNS[j]
    roots = rightmost.rightmost_roots_many(m, c, k, P, D, tau, count=8)
    for pick in (lambda r: 0.5 * (r[1].real + r[2].real),
                 lambda r: r[0].real - max(0.5, 0.5 * abs(r[0].real))):
        a = np.array([pick(r) for r in roots])
        got = count_roots_right_of_many(a, m, c, k, P, D, tau, near=roots)
        scalar = [count_roots_right_of(a[i], m, c, k, P[i], D[i], tau, near=roots[i])
                  for i in range(P.size)]
        want = [int(np.count_nonzero(r.real > x)) for r, x in zip(roots, a, strict=True)]
        with monkeypatch.context() as mp:
            mp.setattr(counting, "_outer_turn",
                       lambda a_, *args: (np.zeros(np.size(a_)), np.zeros(np.size(a_), bool)))
            assert np.all(count_roots_right_of_many(a, m, c, k, P, D, tau, near=roots) == -1)
            sampled = [count_roots_right_of(a[i], m, c, k, P[i], D[i], tau, near=roots[i])
                       for i in range(P.size)]
        assert scalar == sampled
        assert [g for g in got.tolist() if g >= 0] == [s for g, s in zip(got, scalar,
                                                                          strict=True) if g >= 0]
        assert scalar == want  # every root right of a is one of the certified ones


def test_left_ordinates_are_the_scalar_counts_samples():
    # the batched left edges (_left_ordinates) hold exactly the scalar count's ordinates
    # (np.unique of the uniform and the local samples, descending), padded by repeats:
    # bit-for-bit, so the batched and the scalar count sum the same angles
    plant, P, D, delay = MASS_DAMPER
    roots = rightmost.rightmost_roots_many(plant.m, plant.c, _MD_K, P, D, delay, count=8)
    a = np.array([0.5 * (r[1].real + r[2].real) - 0.3 for r in roots])
    R = 1.05 * np.array([counting._root_radius(plant.m, plant.c, _MD_K, p, d, delay, x)
                         for p, d, x in zip(P, D, a, strict=True)]) + 1.0
    n = 160
    Y = counting._left_ordinates(roots, a, R, n)
    u = np.linspace(0.0, 1.0, n, endpoint=False)
    for i in range(P.size):
        y = np.unique(np.concatenate([R[i] * (1.0 - u),
                                      counting._local_samples(roots[i], a[i], R[i], n)]))[::-1]
        row = Y[i][np.concatenate([[True], Y[i][1:] != Y[i][:-1]])]
        assert np.array_equal(row, y)


# --- regressions from the review of the 2026-12-01 speed work ---------------------------------


@pytest.mark.parametrize("args", [
    # (m, c, k, P, D, Δt): a far-left real root (small D > 0) that the quick first attempt's
    # coarse discretisation has no real eigenvalue for; Newton from a complex start converged
    # onto it with Im ≈ 1e−27 (1e−41), which identification takes for a complex pair
    (0.17694871307830098, 0.0444688574705507, 1.057570884739352, 2.9995684284455826,
     0.016748895071099047, 0.023682513007618047),
    (369.3466025223794, 10574.266950135421, 96838.0442495711, 441437.48890873895,
     300.2590775978475, 0.0027372528937925304),
])
def test_real_roots_come_back_exactly_real(args):
    # expected: every root either exactly real (Im == 0, as Newton from a real start keeps it)
    # or clearly complex (|Im| > 1e−6 |s|: these loops' pairs are far from the axis)
    roots = rightmost_roots(*args, count=6)
    assert roots.size >= 6
    for z in roots:
        assert z.imag == 0 or abs(z.imag) > 1e-6 * abs(z)
    assert any(z.imag == 0 for z in roots)


def test_continuation_across_d_zero_keeps_real_roots_exactly_real():
    # the chain-start retry (gains crossing D = 0): its complex starts landed on the entering
    # real root with Im ≈ 1e−33. Expected: the roots of the per-run computation (1e−12
    # relative: both are Newton-converged, to ~1e−15) with the same real/complex pattern
    m, c, k = 0.08131448170937326, 0.04679323639257897, 0.5420258995121682
    tau = 0.12844755385671094
    P = np.array([2.0436855855962657, 1.8617162920749128, 1.8278896880910795, 0.9562268612807474,
                  1.7290284164689478, 0.9152673661165458, 1.0514550303355548])
    D = np.array([-0.16536439438798123, -0.19422788153438936, 0.07155138843885685,
                  -0.1287967143580461, 0.19164243187796617, 0.027293359994510845,
                  0.032109535045036816])
    many = rightmost_roots_many(m, c, k, P, D, tau, count=8)
    for i, got in enumerate(many):
        want = rightmost_roots(m, c, k, P[i], D[i], tau, count=12)[: got.size]
        assert got.size >= 8
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
        assert [z.imag == 0 for z in got] == [z.imag == 0 for z in want]


@pytest.mark.parametrize("args, count", [
    ((156.9744368877158, 0.0, 0.0, 2163361.5283653736, 10957.263035892202,
      0.00024618634981964685), 14),
    ((161.79483518168934, 0.0, 66181834.329523236, 68166471.900587, 683.3887137201364,
      2.274545459849884e-05), 12),
])
def test_quick_attempt_never_returns_fewer_roots_than_asked(args, count):
    # the quick first attempt found too few roots for a real-part gap after `count` and cut at
    # all it had (13 of 14, 11 of 12); its certificate proved no root missed right of the last,
    # not that `count` were there. Expected: at least `count` roots (whole pairs)
    assert rightmost_roots(*args, count=count).size >= count


@pytest.mark.parametrize("a, m, c, k, want", [
    # P = D = 0: the roots are those of m s² + c s + k, exact (s = 0 and 10; s = 3 and −2)
    (-1.0, 1.0, -10.0, 0.0, 2),
    (-1.0, 1.0, -1.0, -6.0, 1),
    (-3.0, 1.0, -1.0, -6.0, 2),
])
def test_root_count_with_negative_damping_or_stiffness(a, m, c, k, want):
    # the disc holding every root right of `a` used c and k with their signs: too small for
    # c < 0 or k < 0 (the count missed roots, or its square root failed)
    assert count_roots_right_of(a, m, c, k, 0.0, 0.0, 1.0) == want
