"""Tests of phoid.dynamics.digital and the sampled-controller path of phoid.simulate.

Where every expected value comes from:
- the z-roots: eigenvalues of an explicit augmented state matrix built here from
  scipy.signal.cont2discrete (an independent construction of the same hybrid loop);
- the simulation: a plain per-sample Python loop on scipy's ZOH discretisation (and, with an
  external force or Coulomb friction, solve_ivp with events between the recorder's samples);
- the T_s → 0 limit: the continuous delayed loop of phoid.dynamics (eq. 23), certified roots;
- the Jacobian: central finite differences of the roots;
- the statistics: Monte Carlo of a Gauss–Newton fit written in this file.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.integrate import solve_ivp
from scipy.optimize import linear_sum_assignment
from scipy.signal import cont2discrete

from phoid.dynamics.digital import (
    DigitalPD,
    digital_characteristic,
    digital_coefficients,
    digital_is_dominant,
    digital_is_stable,
    digital_modes,
    digital_residues,
    digital_roots,
    zoh_plant,
)
from phoid.dynamics.plant import Plant
from phoid.dynamics.rightmost import dominant_roots
from phoid.fits import fit_decay
from phoid.methods.pho import fit_modes
from phoid.simulation import simulate

# the acceptance loop: T_s = 2 ms, backward difference, 3-sample delay
M_, C_, K_ = 1.0, 2.0, 100.0
PLANT = Plant(M_, C_, K_)
TS, DS = 0.002, 3
P10 = np.linspace(20.0, 200.0, 10)
D10 = np.linspace(0.5, 5.0, 10)
X0 = 0.01

LOOPS = [
    DigitalPD(0.0, 0.0, TS, 0),
    DigitalPD(0.0, 0.0, TS, 1),
    DigitalPD(0.0, 0.0, TS, DS),
    DigitalPD(0.0, 0.0, TS, 7),
    DigitalPD(0.0, 0.0, TS, 0, "filtered", 300.0),
    DigitalPD(0.0, 0.0, TS, DS, "filtered", 150.0),
]
LOOP_IDS = ["bd-d0", "bd-d1", "bd-d3", "bd-d7", "filt-d0", "filt-d3"]


# --------------------------------------------------------------------------------------------
# independent constructions (test-only references)


def _zoh(m, c, k, h):
    A = np.array([[0.0, 1.0], [-k / m, -c / m]])
    B = np.array([[0.0], [1.0 / m]])
    Ad, Bd, *_ = cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), h, method="zoh")
    return Ad, Bd[:, 0]


def _augmented_matrix(m, c, k, P, D, loop):
    """State (x_n, ẋ_n, x_{n−1}, v̂_{n−1}, u_{n−1}, …, u_{n−d}) → next, from cont2discrete.

    Non-minimal on purpose (x_{n−1} and v̂_{n−1} enter only through a v̂_{n−1} − c_f x_{n−1}),
    so its eigenvalues are χ's roots plus one at 0.
    """
    Ad, Bd = _zoh(m, c, k, loop.sample_time)
    d = loop.delay_samples
    a = math.exp(-loop.cutoff * loop.sample_time) if loop.velocity == "filtered" else 0.0
    cf = (1.0 - a) / loop.sample_time
    n = 4 + d
    # v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1});  u_n = −P x_n − D v̂_n  (rows over the state)
    ve = np.zeros(n)
    ve[0], ve[2], ve[3] = cf, -cf, a
    un = -P * np.eye(n)[0] - D * ve
    uapp = un if d == 0 else np.eye(n)[4 + d - 1]
    M = np.zeros((n, n))
    M[0:2, 0:2] = Ad
    M[0:2, :] += np.outer(Bd, uapp)
    M[2, 0] = 1.0
    M[3] = ve
    if d > 0:
        M[4] = un
        for j in range(1, d):
            M[4 + j, 4 + j - 1] = 1.0
    return M


def _loop_reference(m, c, k, loop, x0, v0, hold, fs, N):
    """Per-sample Python loop: scipy's ZOH plant at the recorder interval, the controller
    updated at its instants. Returns x, ẋ, applied u (N,)."""
    T, d = loop.sample_time, loop.delay_samples
    a = math.exp(-loop.cutoff * T) if loop.velocity == "filtered" else 0.0
    cf = (1.0 - a) / T
    Mr = round(fs * T)
    jr = round(hold * fs)
    Ad, Bd = _zoh(m, c, k, 1.0 / fs)
    x = np.empty(N)
    v = np.empty(N)
    u = np.empty(N)
    U: dict[int, float] = {}
    y = np.array([x0, 0.0])
    x_prev, ve = x0, 0.0
    for j in range(N):
        if j == jr:
            y = np.array([x0, v0])
        if j % Mr == 0:
            ve = a * ve + cf * (y[0] - x_prev)
            x_prev = y[0]
            U[j // Mr] = -(loop.P * y[0] + loop.D * ve)
        ua = U.get(j // Mr - d, -loop.P * x0)
        x[j], v[j], u[j] = y[0], y[1], ua
        if j >= jr:
            y = Ad @ y + Bd * ua
    return x, v, u


def _force_reference(m, c, k, fc, loop, x0, hold, fs, N, force):
    """Event-located integration between samples (DOP853, rtol 1e-12) of the hybrid loop with
    Coulomb friction (static = kinetic) and an external force; no matrix exponential involved.

    Sliding: until ẋ = 0 (event); there the mass sticks if |u + F − k x| ≤ f_c, else slides
    on in the direction of that force. Stuck: until |u + F − k x| exceeds f_c (event, or at a
    new command)."""
    T, d = loop.sample_time, loop.delay_samples
    a = math.exp(-loop.cutoff * T) if loop.velocity == "filtered" else 0.0
    cf = (1.0 - a) / T
    Mr = round(fs * T)
    jr = round(hold * fs)
    F = force if force is not None else (lambda t: 0.0)
    U: dict[int, float] = {}
    xs = np.empty(N)
    vs = np.empty(N)

    def g(t, x, ua):
        return ua + F(t) - k * x

    def decide(t, x, ua):
        gg = g(t, x, ua)
        return 0 if abs(gg) <= fc else int(np.sign(gg))

    y = np.array([x0, 0.0])
    mode = 0
    x_prev, ve = x0, 0.0
    for j in range(N):
        t = j / fs
        if j % Mr == 0:
            ve = a * ve + cf * (y[0] - x_prev)
            x_prev = y[0]
            U[j // Mr] = -(loop.P * y[0] + loop.D * ve)
        xs[j], vs[j] = y
        ua = U.get(j // Mr - d, -loop.P * x0)
        if j < jr or j == N - 1:
            continue
        if mode == 0:
            mode = decide(t, y[0], ua)
        t0, t1 = t, (j + 1) / fs
        while t0 < t1:
            if mode == 0:
                if force is None:
                    break

                def unstick(tt, yy, x=y[0], ua=ua):
                    return abs(g(tt, x, ua)) - fc

                unstick.terminal, unstick.direction = True, 1
                sol = solve_ivp(lambda tt, yy: [0.0, 0.0], (t0, t1), y, events=unstick,
                                rtol=1e-12, atol=1e-16)
                if sol.status != 1:
                    break
                t0 = sol.t_events[0][0]
                mode = int(np.sign(g(t0, y[0], ua)))
            else:

                def rhs(tt, yy, s=mode, ua=ua):
                    return [yy[1], (ua + F(tt) - k * yy[0] - c * yy[1] - fc * s) / m]

                def halt(tt, yy):
                    return yy[1]

                halt.terminal, halt.direction = True, -mode
                sol = solve_ivp(rhs, (t0, t1), y, method="DOP853", events=halt, rtol=1e-12,
                                atol=1e-16)
                y = sol.y[:, -1].copy()
                if sol.status != 1:
                    break
                t0 = sol.t_events[0][0]
                y = np.array([sol.y_events[0][0][0], 0.0])
                mode = decide(t0, y[0], ua)
    return xs, vs


def _fit_digital(sigma, omega_d, cov, P, D, loop, theta0, iters=30):
    """Gauss–Newton of (m, c, k) to measured modes with digital_modes (test-only estimator)."""
    Wh = np.array([np.linalg.inv(np.linalg.cholesky(C)) for C in cov])
    meas = np.c_[sigma, omega_d]
    theta = np.array(theta0, dtype=float)
    guess = -sigma + 1j * omega_d
    for _ in range(iters):
        s, ds = digital_modes(*theta, P, D, loop, guess)
        r = np.einsum("nij,nj->ni", Wh, meas - np.c_[-s.real, s.imag]).ravel()
        J = np.einsum("nij,njk->nik", Wh, np.stack([ds.real, -ds.imag], axis=1)).reshape(-1, 3)
        step = -np.linalg.lstsq(J, r, rcond=None)[0]
        theta = theta + step
        guess = s
        if np.all(np.abs(step) <= 1e-13 * np.abs(theta)):
            break
    s, ds = digital_modes(*theta, P, D, loop, guess)
    J = np.einsum("nij,njk->nik", Wh, np.stack([ds.real, -ds.imag], axis=1)).reshape(-1, 3)
    r = np.einsum("nij,nj->ni", Wh, meas - np.c_[-s.real, s.imag]).ravel()
    return theta, np.linalg.inv(J.T @ J), float(r @ r)


# --------------------------------------------------------------------------------------------
# the loop and its validation


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(P=float("nan")), "P"),
        (dict(D=float("inf")), "D"),
        (dict(sample_time=0.0), "sample_time"),
        (dict(sample_time=-1e-3), "sample_time"),
        (dict(sample_time=float("nan")), "sample_time"),
        (dict(delay_samples=-1), "delay_samples"),
        (dict(delay_samples=2.5), "delay_samples"),
        (dict(delay_samples=True), "delay_samples"),
        (dict(delay_samples="2"), "delay_samples"),
        (dict(velocity="central"), "velocity"),
        (dict(velocity="filtered"), "cutoff"),
        (dict(velocity="filtered", cutoff=0.0), "cutoff"),
        (dict(velocity="filtered", cutoff=float("nan")), "cutoff"),
        (dict(cutoff=100.0), "cutoff"),
    ],
)
def test_digital_pd_rejects_bad_input_naming_the_parameter(kwargs, name):
    args = {"P": 1.0, "D": 0.1, "sample_time": TS, **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        DigitalPD(**args)


def test_digital_pd_normalises_and_derives():
    loop = DigitalPD(np.float32(2.0), 1, 0.001, np.int64(3))
    assert loop.delay_samples == 3 and isinstance(loop.delay_samples, int)
    assert DigitalPD(1.0, 0.1, TS, 2.0).delay_samples == 2  # a whole float is a whole number
    assert loop.order == 6 and loop.delay == pytest.approx(0.003, rel=1e-15)
    # backward difference: a = 0, c_f = 1/T_s; filtered: a = e^{−ω_c T_s}, c_f = (1 − a)/T_s
    assert (loop.filter_pole, loop.filter_gain) == (0.0, 1000.0)
    f = DigitalPD(1.0, 0.1, TS, 0, "filtered", 200.0)
    assert f.filter_pole == pytest.approx(math.exp(-0.4), rel=1e-15)
    assert f.filter_gain == pytest.approx((1 - math.exp(-0.4)) / TS, rel=1e-14)


def test_zoh_plant_matches_scipy_and_closed_form():
    zp = zoh_plant(M_, C_, K_, TS, derivatives=True)
    Ad, Bd = _zoh(M_, C_, K_, TS)
    # both are matrix exponentials of the same matrix (Padé in scipy, Taylor here): ~1e-15
    np.testing.assert_allclose(zp.phi, Ad, rtol=0, atol=1e-14)
    np.testing.assert_allclose(zp.gamma, Bd, rtol=1e-12, atol=0)
    # Liouville: det Φ = e^{tr A T} = e^{−cT/m}; eigenvalues e^{pT}, p the plant's roots
    assert zp.delta == pytest.approx(math.exp(-C_ * TS / M_), rel=1e-14)
    assert zp.tau == pytest.approx(float(np.sum(zp.lam).real), rel=1e-14)
    # derivatives of τ, δ, b₁, b₀ against central differences (h = 1e-6 relative: truncation
    # ~1e-12, rounding ~1e-10 relative)
    theta = np.array([M_, C_, K_])
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1e-6 * theta[j]
        hi = zoh_plant(*(theta + e), TS)
        lo = zoh_plant(*(theta - e), TS)
        for name in ("tau", "delta", "b1", "b0"):
            fd = (getattr(hi, name) - getattr(lo, name)) / (2 * e[j])
            an = getattr(zp, "d_" + name)[j]
            assert an == pytest.approx(fd, rel=1e-6, abs=1e-9 * abs(getattr(zp, name)) / K_)


# --------------------------------------------------------------------------------------------
# the characteristic polynomial and its roots


@pytest.mark.parametrize("loop", LOOPS, ids=LOOP_IDS)
def test_roots_are_the_eigenvalues_of_the_augmented_state_matrix(loop):
    roots = digital_roots(M_, C_, K_, P10, D10, loop)
    assert roots.z.shape == (10, loop.delay_samples + 3)
    for i in range(10):
        eig = np.linalg.eigvals(_augmented_matrix(M_, C_, K_, P10[i], D10[i], loop))
        ours = np.append(roots.z[i], 0.0)  # the reference's extra (non-minimal) zero
        cost = np.abs(ours[:, None] - eig[None, :])
        r, c = linear_sum_assignment(cost)
        # eigenvalues of a matrix with entries up to D c_f ≈ 2500 near a pair 0.04 apart:
        # ~2500·ε/0.04 ≈ 1e-11 (the plant pair near 1), and ~ε^{1/2} for the reference's
        # double zero eigenvalue with P = D = 0 (not the case here)
        assert np.max(cost[r, c]) <= 1e-9
    # sorted by decreasing Re s = ln|z|/T_s; the dominant root is the first with Im ≥ 0
    assert np.all(np.diff(np.abs(roots.z), axis=1) <= 1e-12)
    np.testing.assert_allclose(roots.s, np.log(roots.z) / TS, rtol=1e-14)
    dom = roots.s[:, 0]
    np.testing.assert_allclose(roots.dominant, dom.real + 1j * np.abs(dom.imag), rtol=0, atol=0)


@pytest.mark.parametrize("loop", LOOPS, ids=LOOP_IDS)
def test_characteristic_value_and_derivative(loop):
    rng = np.random.default_rng(3)
    z = rng.normal(size=8) + 1j * rng.normal(size=8)
    P, D = 60.0, 1.5
    chi, dchi = digital_characteristic(z, M_, C_, K_, P, D, loop)
    # the factored evaluation against the expanded coefficients (two forms of one polynomial)
    coef = digital_coefficients(M_, C_, K_, P, D, loop)[0]
    np.testing.assert_allclose(chi, np.polyval(coef, z), rtol=1e-12)
    np.testing.assert_allclose(dchi, np.polyval(np.polyder(coef), z), rtol=1e-12)
    # and the roots are zeros of it (rounding of χ's terms, |z|^{d+3} ≈ 1 near the roots)
    zr = digital_roots(M_, C_, K_, P, D, loop).z[0]
    chi_r, _ = digital_characteristic(zr, M_, C_, K_, P, D, loop)
    assert np.max(np.abs(chi_r)) <= 1e-13


def test_stability_is_all_roots_inside_the_unit_circle():
    loop = DigitalPD(0.0, 0.0, TS, DS)
    P = np.array([50.0, 50.0, 50.0])
    D = np.array([1.0, -2.5, 300.0])  # stable; negative damping (c + D < 0); too much D·delay
    stable = digital_is_stable(M_, C_, K_, P, D, loop)
    np.testing.assert_array_equal(stable, [True, False, False])
    # independent: the spectral radius of the augmented state matrix
    rho = [np.max(np.abs(np.linalg.eigvals(_augmented_matrix(M_, C_, K_, P[i], D[i], loop))))
           for i in range(3)]
    np.testing.assert_array_equal(np.array(rho) < 1.0, stable)
    # and the simulation grows where unstable, decays where stable
    sim = simulate(PLANT, P, D, duration=2.0, fs=1 / TS, x0=X0, sample_time=TS,
                   delay_samples=DS)
    late = np.max(np.abs(sim.x_true[:, -100:]), axis=1)
    np.testing.assert_array_equal(late < X0, stable)


# --------------------------------------------------------------------------------------------
# the simulator: exact at the sample instants, and against independent references


@pytest.mark.parametrize("loop", LOOPS, ids=LOOP_IDS)
@pytest.mark.parametrize("M", [1, 4])
def test_sampled_response_is_the_sum_of_the_modes(loop, M):
    """x(nT_s) = Σ a_j z_j^n (module docstring), a_j = Q(z_j)/(z_j χ′(z_j)), from the release."""
    P = np.array([20.0, 80.0, 200.0, 50.0])
    D = np.array([0.5, 2.0, 5.0, 0.0])  # the last: P only, where χ(0) = 0 for a = 0
    hold, v0 = 0.1, 0.03
    sim = simulate(PLANT, P, D, duration=10.0, fs=M / TS, x0=X0, v0=v0, hold=hold,
                   sample_time=TS, delay_samples=loop.delay_samples, velocity=loop.velocity,
                   cutoff=loop.cutoff)
    s, amp = digital_residues(M_, C_, K_, P, D, loop, X0, v0)
    j0 = round(hold / TS) * M
    n = np.arange((sim.t.size - j0 + M - 1) // M)
    with np.errstate(invalid="ignore"):  # roots at z = 0 (s = −inf) carry amplitude 0
        modes = np.exp(s[:, :, None] * (n * TS)[None, None, :])
        modes = np.where(np.isfinite(s)[:, :, None], modes, 0.0)
    pred = np.einsum("bj,bjn->bn", amp, modes)
    assert np.max(np.abs(pred.imag)) <= 1e-12 * X0  # conjugate pairs
    # 5000 controller periods of rounding (~1e-13 relative) and the residues' conditioning:
    # 1e-11·x₀ is far below any sensor, and far above what a wrong model would leave (the
    # continuous-delay loop differs by ~1e-3·x₀, see test_equivalent_continuous_delay…)
    np.testing.assert_allclose(sim.x_true[:, j0::M][:, 1:], pred.real[:, 1:], rtol=0,
                               atol=1e-11 * X0)
    np.testing.assert_array_equal(sim.x_true[:, : j0 + 1], X0)  # held, released at x₀


@pytest.mark.parametrize(
    ("loop", "fs", "hold"),
    [
        (DigitalPD(60.0, 1.5, TS, DS), 500.0, 0.0),
        (DigitalPD(60.0, 1.5, TS, 0, "filtered", 200.0), 2000.0, 0.0125),  # mid-period release
        (DigitalPD(150.0, -0.5, TS, 2), 1500.0, 0.004),
        (DigitalPD(20.0, 3.0, TS, 5, "filtered", 80.0), 1000.0, 0.021),
    ],
)
def test_simulation_matches_a_per_sample_scipy_loop(loop, fs, hold):
    N = round((hold + 1.5) * fs)
    sim = simulate(PLANT, [loop.P, 1.0], [loop.D, 0.2], duration=1.5, fs=fs, x0=X0, v0=0.02,
                   hold=hold, sample_time=TS, delay_samples=loop.delay_samples,
                   velocity=loop.velocity, cutoff=loop.cutoff)
    x, v, u = _loop_reference(M_, C_, K_, loop, X0, 0.02, hold, fs, N)
    # both are exact ZOH recursions; they differ by rounding. Each of the N steps rounds the
    # state update (two products and a sum per component) and the two discretisations (scipy's
    # expm here, phoid's own there) differ by ~1 ulp per entry: <= ~4 ε of the state scale per
    # step, and that difference is systematic, so it adds up linearly (not as √N) while the
    # slowly decaying loop keeps it: bound 4 N ε; tolerance 16 N ε (N = 750 … 3025: 3e-12 …
    # 1e-11 of x₀). Measured ≤ 1.6 N ε (7.4e-13 x₀ for loop2, N = 2256, varying by ±8 % with
    # the BLAS kernel); a modelling error (a sample of delay, the hold) is ≥ 1e-4 x₀.
    tol = 16 * N * np.finfo(float).eps * X0
    np.testing.assert_allclose(sim.x_true[0], x, rtol=0, atol=tol)
    np.testing.assert_allclose(sim.v[0], v, rtol=0, atol=tol * 20.0)  # |ẋ| ≲ 20 x₀/s
    # u = −(P x + D v̂): rounding of x times |P| + |D| c_f
    np.testing.assert_allclose(sim.u[0], u, rtol=0, atol=tol * (abs(loop.P) + abs(loop.D) / TS))


def test_sampled_loop_with_an_external_force_matches_solve_ivp():
    loop = DigitalPD(60.0, 1.5, TS, 2, "filtered", 250.0)

    def force(t):
        return 0.3 * np.sin(7.0 * t) + 0.1 * np.cos(40.0 * t)

    fs, hold = 1000.0, 0.01
    sim = simulate(PLANT, loop.P, loop.D, duration=1.0, fs=fs, x0=X0, hold=hold, force=force,
                   sample_time=TS, delay_samples=2, velocity="filtered", cutoff=250.0)
    x, v = _force_reference(M_, C_, K_, 0.0, loop, X0, hold, fs, sim.t.size, force)
    # DOP853 at rtol 1e-12 (~1e-14 m) vs quintic force interpolation on ρh ≤ 0.1 sub-steps
    # (O(h⁶) of a 40 rad/s force over 1 ms: ~1e-14 relative)
    np.testing.assert_allclose(sim.x_true[0], x, rtol=0, atol=1e-10 * X0)
    np.testing.assert_allclose(sim.v[0], v, rtol=0, atol=1e-10 * X0 * 20.0)


@pytest.mark.parametrize(
    ("loop", "fs", "hold", "force"),
    [
        (DigitalPD(60.0, -1.5, TS, DS), 500.0, 0.0, None),
        (DigitalPD(20.0, 0.5, TS, DS), 500.0, 0.0, None),
        (DigitalPD(60.0, 1.0, TS, 1, "filtered", 300.0), 1000.0, 0.003,
         lambda t: 0.4 * np.sin(4.0 * t)),
    ],
)
def test_sampled_loop_with_coulomb_friction_matches_event_located_reference(
    loop, fs, hold, force
):
    fc = 0.05
    sim = simulate(Plant(M_, C_, K_, fc), loop.P, loop.D, duration=1.5, fs=fs, x0=X0,
                   hold=hold, force=force, sample_time=TS, delay_samples=loop.delay_samples,
                   velocity=loop.velocity, cutoff=loop.cutoff)
    x, v = _force_reference(M_, C_, K_, fc, loop, X0, hold, fs, sim.t.size, force)
    # events located to ~1e-15 s by both (root finding vs solve_ivp's event location at
    # rtol 1e-12): ~1e-13·x₀ apart
    np.testing.assert_allclose(sim.x_true[0], x, rtol=0, atol=1e-10 * X0)
    np.testing.assert_allclose(sim.v[0], v, rtol=0, atol=1e-10 * X0 * 20.0)
    if loop.D > 0 and force is None:
        assert np.mean(sim.v[0] == 0.0) > 0.02  # friction stops the decay: the test has teeth


def test_applied_force_is_the_delayed_held_command():
    loop = DigitalPD(0.0, 0.0, TS, DS, "filtered", 300.0)
    M, hold = 3, 0.05
    sim = simulate(PLANT, P10, D10, duration=2.0, fs=M / TS, x0=X0, hold=hold, sample_time=TS,
                   delay_samples=DS, velocity="filtered", cutoff=300.0)
    # recompute the commands from the recorded positions at the controller's instants
    xn = sim.x_true[:, ::M]
    a, cf = loop.filter_pole, loop.filter_gain
    dx = np.diff(np.concatenate([np.full((10, 1), X0), xn], axis=1), axis=1)
    ve = np.zeros_like(xn)
    for n in range(xn.shape[1]):  # the estimator, written as its definition
        ve[:, n] = (a * ve[:, n - 1] if n else 0.0) + cf * dx[:, n]
    un = -(P10[:, None] * xn + D10[:, None] * ve)
    held = np.repeat(-P10[:, None] * X0, DS, axis=1)
    applied = np.concatenate([held, un], axis=1)[:, : xn.shape[1]]
    # rounding of x (1e-15·x₀) times D c_f ≈ 1000 N/m
    np.testing.assert_allclose(sim.u, np.repeat(applied, M, axis=1), rtol=0, atol=1e-12)
    assert sim.sample_time == TS and sim.delay_samples == DS and sim.cutoff == 300.0
    assert sim.velocity == "filtered" and sim.delay == pytest.approx(DS * TS, rel=1e-15)
    assert sim.digital_loop(4) == DigitalPD(P10[4], D10[4], TS, DS, "filtered", 300.0)


def test_batch_equals_runs_one_by_one():
    kw = dict(duration=3.0, fs=2 / TS, x0=X0, hold=0.1, sample_time=TS, delay_samples=DS)
    batch = simulate(PLANT, P10, D10, **kw)
    # the same arithmetic per row, but a batched matrix product may round differently from a
    # single row's (BLAS blocking, FMA, a gemv path for one row): <= ~2 ε of the state per
    # step, at worst linearly over the N = 3100 samples: 2 N ε = 1.4e-12 x₀; tolerance 4× that
    # (measured 0 on x86-64 with three BLAS kernels); another run's gains differ by > 1e-3 x₀
    tol = 8 * 3100 * np.finfo(float).eps * X0
    for i in (0, 9):
        one = simulate(PLANT, P10[i], D10[i], **kw)
        np.testing.assert_allclose(one.x_true[0], batch.x_true[i], rtol=0, atol=tol)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(sample_time=TS, fs=750.0), "fs"),  # 1.5 recorder samples per period
        (dict(sample_time=TS, fs=250.0), "fs"),  # slower than the controller
        (dict(sample_time=TS, hold=0.0105), "hold"),  # not on the recorder's grid
        (dict(sample_time=TS, delay=0.006), "delay"),
        (dict(sample_time=-TS), "sample_time"),
        (dict(sample_time=TS, delay_samples=-2), "delay_samples"),
        (dict(sample_time=TS, velocity="filtered"), "cutoff"),
        (dict(sample_time=TS, velocity="kalman"), "velocity"),
        (dict(delay_samples=2), "delay_samples"),
        (dict(velocity="filtered", cutoff=100.0), "velocity"),
        (dict(cutoff=100.0), "cutoff"),
    ],
)
def test_simulate_rejects_bad_sampled_settings_naming_the_parameter(kwargs, name):
    args = {"duration": 1.0, "fs": 1000.0, "x0": X0, **kwargs}
    with pytest.raises(ValueError, match=f"`{name}`"):
        simulate(PLANT, [10.0, 20.0], [1.0, 1.0], **args)


# --------------------------------------------------------------------------------------------
# the continuous limit, the Jacobian, dominance


def test_roots_converge_to_the_continuous_delayed_loop_as_the_sample_time_shrinks():
    """d·T_s = Δt = 10 ms fixed, T_s → 0: the digital roots → the roots of eq. (23), O(T_s).

    The hold and the backward difference each lag by about T_s/2, so the error is first order
    in T_s: it must halve with T_s (ratio 2 within 2 %: the next term is O(T_s²)).
    """
    delay = 0.01
    P, D = np.array([50.0, 200.0]), np.array([1.0, 5.0])
    exact = dominant_roots(M_, C_, K_, P, D, delay, certify=True)
    errs = []
    for d in (10, 20, 40, 80):
        loop = DigitalPD(0.0, 0.0, delay / d, d)
        errs.append(np.abs(digital_roots(M_, C_, K_, P, D, loop).dominant - exact))
    errs = np.array(errs)
    ratio = errs[:-1] / errs[1:]
    np.testing.assert_allclose(ratio, 2.0, rtol=0.02)
    assert np.all(errs[-1] <= 1e-3 * np.abs(exact))  # 125 µs samples: within 0.1 %


@pytest.mark.parametrize("loop", LOOPS, ids=LOOP_IDS)
def test_jacobian_matches_finite_differences(loop):
    P, D = P10[::3], D10[::3]
    s, J = digital_modes(M_, C_, K_, P, D, loop)
    np.testing.assert_allclose(s, digital_roots(M_, C_, K_, P, D, loop).dominant, rtol=1e-14)
    theta = np.array([M_, C_, K_])
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1e-6 * theta[j]
        sp, _ = digital_modes(*(theta + e), P, D, loop)
        sm, _ = digital_modes(*(theta - e), P, D, loop)
        fd = (sp - sm) / (2 * e[j])
        # central difference: truncation ~1e-12 relative, rounding ~ε|s|/h ≈ 1e-9 relative
        np.testing.assert_allclose(J[:, j], fd, rtol=1e-6)


def test_tracking_from_a_guess_and_the_dominance_check():
    loop = DigitalPD(0.0, 0.0, TS, DS)
    roots = digital_roots(M_, C_, K_, P10, D10, loop)
    guess = roots.dominant * (1 + 0.02j)  # a measured mode a few per cent off
    s, _ = digital_modes(M_, C_, K_, P10, D10, loop, guess)
    np.testing.assert_allclose(s, roots.dominant, rtol=1e-13)
    # a guess near the conjugate still reports the upper half-plane root
    s, _ = digital_modes(M_, C_, K_, P10, D10, loop, np.conj(guess))
    np.testing.assert_allclose(s, roots.dominant, rtol=1e-13)
    # a guess one alias up (ω_d + 2π/T_s) stays on that branch of ln z
    alias = roots.dominant + 2j * math.pi / TS
    s, _ = digital_modes(M_, C_, K_, P10, D10, loop, alias * (1 + 1e-3))
    np.testing.assert_allclose(s, alias, rtol=1e-13)
    assert digital_is_dominant(roots.dominant, M_, C_, K_, P10, D10, loop).all()
    # the third root (a real, fast one here) is a root but not the dominant one
    assert not digital_is_dominant(roots.s[:, 2], M_, C_, K_, P10, D10, loop).any()


# --------------------------------------------------------------------------------------------
# what the identification gains


def test_decay_fit_of_sampled_records_measures_the_digital_root():
    """A decay fit at the controller's instants measures s = ln z/T_s exactly; a recorder 10×
    faster sees an intra-period ripple of ~1e-8 of the amplitude, a 1e-9 relative effect."""
    P, D = np.array([50.0, 200.0]), np.array([1.0, 5.0])
    loop = DigitalPD(0.0, 0.0, TS, DS)
    exact = digital_roots(M_, C_, K_, P, D, loop).dominant
    for M, tol in ((1, 1e-11), (10, 1e-8)):
        sim = simulate(PLANT, P, D, duration=8.0, fs=M / TS, x0=X0, hold=0.1, sample_time=TS,
                       delay_samples=DS)
        for i in range(2):
            f = fit_decay(sim.t, sim.x[i], release=0.1, skip=0.05)
            assert abs(f.sigma + exact[i].real) <= tol * abs(exact[i].real)
            assert abs(f.omega_d - exact[i].imag) <= tol * exact[i].imag


@pytest.fixture(scope="module")
def acceptance_modes():
    """The issue's acceptance set: exact digital modes and the covariances of decay fits of
    8 s records at 500 Hz with 10 µm noise (weights as the identification would have them)."""
    loop = DigitalPD(0.0, 0.0, TS, DS)
    roots = digital_roots(M_, C_, K_, P10, D10, loop)
    rng = np.random.default_rng(2024)
    sim = simulate(PLANT, P10, D10, duration=8.0, fs=1 / TS, x0=X0, hold=0.1, sample_time=TS,
                   delay_samples=DS, noise=1e-5, rng=rng, noise_in_loop=False)
    fits = [fit_decay(sim.t, sim.x[i], release=0.1, fast_roots=roots.s[i, 2:3])
            for i in range(10)]
    sigma = np.array([f.sigma for f in fits])
    omega_d = np.array([f.omega_d for f in fits])
    cov = np.array([f.cov for f in fits])
    return loop, roots.dominant, sigma, omega_d, cov


def test_equivalent_continuous_delay_is_biased(acceptance_modes):
    """T_s = 2 ms, backward difference, d = 3 (m 1, c 2, k 100; P 20–200, D 0.5–5).

    Measured on the exact digital modes (docs/design-notes/dynamics.md):
      Δt = d·T_s = 6 ms:        m 0.9923, c 1.917, k 99.25, χ²/dof 2504
      Δt = (d + ½)·T_s = 7 ms:  m 0.9934, c 1.983, k 99.23, χ²/dof 23
    i.e. m and k off by 65–107 standard errors of the noise alone (before fit_modes inflates
    them by √(χ²/dof)), while the digital model returns m, c, k exactly.
    """
    loop, exact, sigma, omega_d, cov = acceptance_modes
    truth = np.array([M_, C_, K_])
    dof = 2 * 10 - 3
    limit = stats.chi2.ppf(0.999, dof)
    for delay in (DS * TS, (DS + 0.5) * TS):
        f = fit_modes(-exact.real, exact.imag, cov, P10, D10, delay)
        est = np.array([f.m, f.c, f.k])
        assert f.chi2 > limit  # the continuous model cannot fit the digital loop's modes
        assert f.warnings  # and says so
        # the error in units of the noise's own standard errors (undo the χ² inflation)
        z = (est - truth) / (f.stderr / math.sqrt(f.chi2 / dof))
        assert abs(z[0]) > 10 and abs(z[2]) > 10, (delay, est, z)
    # the digital model: exact modes in, the plant out (Gauss–Newton to rounding)
    theta, _, chi2 = _fit_digital(-exact.real, exact.imag, cov, P10, D10, loop, (0.9, 2.5, 95))
    np.testing.assert_allclose(theta, truth, rtol=1e-9)
    assert chi2 <= 1e-12
    # and the noisy decay fits give the plant within 3 stderr
    theta, covt, chi2 = _fit_digital(sigma, omega_d, cov, P10, D10, loop, (0.9, 2.5, 95))
    assert np.all(np.abs(theta - truth) <= 3 * np.sqrt(np.diag(covt)))
    assert chi2 <= limit


def test_digital_fit_stderr_is_honest(acceptance_modes):
    """Monte Carlo: modes drawn from N(exact, Cov_i); |error| < 3 stderr in ≥ 99 % of the fits
    (binomial: 300 draws at a true 99.73 % give ≥ 98.3 % with probability > 0.999), and the
    z-scores have unit spread."""
    loop, exact, _, _, cov = acceptance_modes
    rng = np.random.default_rng(11)
    L = np.linalg.cholesky(cov)
    truth = np.array([M_, C_, K_])
    zs = []
    for _ in range(300):
        noise = np.einsum("nij,nj->ni", L, rng.standard_normal((10, 2)))
        theta, covt, _ = _fit_digital(-exact.real + noise[:, 0], exact.imag + noise[:, 1], cov,
                                      P10, D10, loop, truth, iters=8)
        zs.append((theta - truth) / np.sqrt(np.diag(covt)))
    zs = np.array(zs)
    assert np.mean(np.all(np.abs(zs) < 3, axis=1)) >= 0.983
    # sd of 300 unit normals: 1 ± 0.041 (1 sd); 0.85–1.15 is a > 3.5 sd band
    assert np.all((np.std(zs, axis=0) > 0.85) & (np.std(zs, axis=0) < 1.15))
