"""Adequacy of the free-decay fit (phoid.methods.free_adequacy, docs/adequacy.md): records with
the defects real decays carry, generated here independently of phoid (an exact piecewise
formula for Coulomb friction, scipy's solve_ivp for drag and a Duffing spring, the closed-form
viscous decay for the rest), and the measured records of ../shared/data/real when present."""

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from phoid.io import read_experiment
from phoid.methods.free import identify_free, identify_free_data

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"


def viscous(t, sigma, w0, x0=1.0):
    """Exact free decay from rest at x0: e^{-σt}(cos ω_d t + σ/ω_d sin ω_d t)."""
    wd = math.sqrt(w0 * w0 - sigma * sigma)
    return x0 * np.exp(-sigma * t) * (np.cos(wd * t) + sigma / wd * np.sin(wd * t))


def coulomb(t, w0=10.0, zeta=0.002, q=0.02, x0=1.0):
    """x'' + 2ζω₀x' + ω₀²x = −ω₀² q sign(x'), from rest at x0, exactly: each half-cycle a viscous
    decay about ∓q starting at a turning point; stuck at the first turning point within ±q."""
    s = zeta * w0
    wd = w0 * math.sqrt(1 - zeta**2)
    half = math.pi / wd
    starts, xs, tt = [], x0, 0.0
    while abs(xs) > q and len(starts) < 10_000:
        xe = q if xs > 0 else -q
        starts.append((tt, xs, xe))
        tt += half
        xs = xe - (xs - xe) * math.exp(-s * half)
    x = np.full(t.shape, xs)
    for t0, xa, xe in starts:
        sel = (t >= t0) & (t < t0 + half)
        tau = t[sel] - t0
        x[sel] = xe + (xa - xe) * np.exp(-s * tau) * (np.cos(wd * tau) + s / wd * np.sin(wd * tau))
    return x


def ode(accel, t, x0=1.0):
    sol = solve_ivp(lambda _t, y: [y[1], accel(y[0], y[1])], (0, t[-1]), [x0, 0.0], t_eval=t,
                    rtol=1e-10, atol=1e-12, method="DOP853")
    return sol.y[0]


def fit(x, t, noise=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    return identify_free_data([(t, x + noise * rng.standard_normal(t.size))])


T200 = np.arange(8000) / 200.0  # 40 s at 200 Hz


def test_clean_linear_decay_passes_and_keeps_its_stderr():
    # the model is the record's own: every check passes, the white-noise stderr stands (no
    # inflation), the result carries no robust/white split; and the Newey-West sandwich agrees
    # with the white covariance within its own noise (measured 0.9-1.1 on such records; 25 %)
    res = fit(viscous(T200, 0.1, 10.0), T200, seed=1)
    ad = res.adequacy
    assert ad.passed and ad.stderr == "white" and ad.inflation == (1.0, 1.0)
    assert res.warnings == () and res.zeta.white_stderr is None
    assert {c.name for c in ad.checks} >= {"noise", "whiteness", "structure", "halves"}
    ratio = np.sqrt(np.diag(ad.sandwich_cov) / np.diag(ad.white_cov))
    assert np.all((ratio > 0.75) & (ratio < 1.25)), ratio
    assert "stderr_white" not in res.summary()["zeta"]


def test_coulomb_decay_is_named():
    res = fit(coulomb(T200), T200, seed=2)
    assert "coulomb" in res.adequacy.causes and res.adequacy.stderr == "robust"
    w = next(w for w in res.warnings if "Coulomb friction" in w)
    assert "--friction" in w and "rises as the amplitude falls" in w
    # the robust stderr is at least the white one, which stays in the JSON
    assert res.zeta.stderr >= res.zeta.white_stderr
    assert res.summary()["zeta"]["stderr_white"] == res.zeta.white_stderr


def test_quadratic_drag_is_amplitude_dependent_damping():
    # x'' = -100x - 0.2x' - 0.5x'|x'|: the drag's share of the damping falls with amplitude
    x = ode(lambda x, v: -100 * x - 0.2 * v - 0.5 * v * abs(v), T200[:6000])
    res = fit(x, T200[:6000], noise=1e-4, seed=3)
    assert "amplitude_damping" in res.adequacy.causes
    assert any("amplitude-dependent damping" in w for w in res.warnings)


def test_duffing_spring_is_amplitude_dependent_stiffness():
    # x'' = -100(x + 0.3x^3) - 0.4x': ω² ≈ 100(1 + 0.225A²), 10 % higher at A = 1
    x = ode(lambda x, v: -100 * x - 0.4 * v - 30 * x**3, T200[:4000])
    res = fit(x, T200[:4000], seed=4)
    assert "amplitude_stiffness" in res.adequacy.causes
    assert any("amplitude-dependent stiffness" in w for w in res.warnings)
    assert "second_mode" not in res.adequacy.causes  # its sidebands are no second mode


def test_ar1_noise_is_coloured_and_widens_the_stderr():
    # AR(1) noise with rho = 0.9: the stderr of a mean-like quantity grows by
    # sqrt((1+rho)/(1-rho)) = 4.4; Newey-West must widen the white stderr by well over 2
    rng = np.random.default_rng(5)
    e = np.empty(T200[:6000].size)
    e[0] = 0.0
    w = rng.standard_normal(e.size)
    for i in range(1, e.size):
        e[i] = 0.9 * e[i - 1] + w[i]
    res = identify_free_data([(T200[:6000], viscous(T200[:6000], 0.2, 10.0) + 0.01 * e)])
    ad = res.adequacy
    assert "coloured" in ad.causes and any("not white noise" in w for w in res.warnings)
    assert min(ad.inflation) > 2.0
    # the truth (zeta = 0.02, omega0 = 10) within 3 robust stderr
    assert abs(res.zeta.value - 0.02) < 3 * res.zeta.stderr
    assert abs(res.omega0.value - 10.0) < 3 * res.omega0.stderr


def test_runs_of_different_plants_disagree():
    # omega0 10 and 10.5 rad/s: thousands of stderr apart
    t = T200[:4000]
    rng = np.random.default_rng(6)
    runs = [(t, viscous(t, 0.2, w0) + 1e-3 * rng.standard_normal(t.size)) for w0 in (10, 10.5)]
    res = identify_free_data(runs, names=["a.csv", "b.csv"])
    runs_check = next(c for c in res.adequacy.checks if c.name == "runs")
    assert runs_check.passed is False
    assert any(w.startswith("the runs disagree") and "a.csv" in w for w in res.warnings)
    # the spread between the runs is in the stderr: both plants within 3 stderr of the mean
    for w0 in (10.0, 10.5):
        assert abs(res.omega0.value - w0) < 3 * res.omega0.stderr


def halves_of(t, x, res):
    """The record cut at the middle sample of the whole fit's window, each half identified."""
    r = res.runs[0]
    sel = np.flatnonzero((t >= r.t_start) & (t <= r.t_end))
    mid = sel[sel.size // 2]
    return (identify_free_data([(t[sel[0]:mid], x[sel[0]:mid])]),
            identify_free_data([(t[mid:sel[-1] + 1], x[mid:sel[-1] + 1])]))


def check_halves(t, x, res):
    """The acceptance of issue 27: the halves agree within 3 combined stderr on ω₀ and ζ, and
    the whole record's stderr covers them (each half within 3 of its stderr). Where the record
    has decayed into its noise by its second half, the method compares no halves (the check is
    absent: docs/adequacy.md) and neither does this."""
    if not any(c.name == "halves" for c in res.adequacy.checks):
        return
    a, b = halves_of(t, x, res)
    for key in ("omega0", "zeta"):
        ea, eb, ew = getattr(a, key), getattr(b, key), getattr(res, key)
        assert abs(ea.value - eb.value) < 3 * math.hypot(ea.stderr, eb.stderr), (key, ea, eb)
        assert max(abs(ea.value - ew.value), abs(eb.value - ew.value)) < 3 * ew.stderr, \
            (key, ea, eb, ew)


def test_halves_acceptance_on_a_drifting_record():
    # Coulomb friction: the viscous model's zeta in the second half is several times the
    # first's; the robust stderr (sandwich plus the halves' spread) must cover it
    rng = np.random.default_rng(7)
    x = coulomb(T200) + 1e-3 * rng.standard_normal(T200.size)
    res = identify_free_data([(T200, x)])
    assert "drift" in res.adequacy.causes or "coulomb" in res.adequacy.causes
    check_halves(T200, x, res)


REAL_SETS = ["pendulum", "pendulum/angle60", "seismometer/Q3_10", "cantilever/w1-20",
             "springmass-short/exp1"]


@pytest.mark.skipif(not REAL.is_dir(), reason=f"the measured records are not here ({REAL}; "
                    "they may not be committed, see ../shared/data/real/*/README.md)")
@pytest.mark.parametrize("name", REAL_SETS)
def test_real_records(name):
    exp = read_experiment(REAL / name)
    res = identify_free(exp)
    # every measured record misfits the linear model, and says so
    assert not res.adequacy.passed and res.adequacy.stderr == "robust"
    assert any("misfits" in w or "not white" in w for w in res.warnings)
    run = exp.runs[0]
    check_halves(run.t, run.x, res)


def test_release_from_a_drifting_hand_is_fitted_after_its_first_swing():
    # a hand that pulls the mass 0.15 further over 0.6 s before letting go (the hold is not
    # still: no held segment to model); then an exact viscous decay from rest. The half that
    # holds the pull is the record's first: before, the fit took the pull for motion
    # (pendulum/angle100's first half: ω₀ 4.1 for 17.1 rad/s).
    fs, w0, sigma = 200.0, 17.0, 0.1
    rng = np.random.default_rng(11)
    n_hold = 120
    pull = 1.0 + 0.15 * (np.arange(n_hold) / n_hold) ** 2
    tf = np.arange(4000) / fs
    x = np.concatenate([pull, 1.15 * viscous(tf, sigma, w0)])
    x = x + 1e-4 * rng.standard_normal(x.size)
    t = np.arange(x.size) / fs
    res = identify_free_data([(t, x)])
    assert res.runs[0].t_start > t[n_hold]  # fitted from after the pull
    # 20 % of ω₀: the fit found the decay, not a slow "mode" through the pull (the noise,
    # 1e-4 of the motion, makes the stderr far smaller still)
    assert abs(res.omega0.value - w0) < 0.2 * w0
    assert abs(res.omega0.value - w0) < 3 * res.omega0.stderr + 1e-3


def test_quantised_record_within_a_count_or_two_is_set_aside():
    # a sensor in steps of 2 counts, the signal under one step: the record holds -2, 0, 2;
    # the second differences are mostly zero (their MAD says 0.28), yet nothing moves beyond
    # 12 rounding sd (q/√12 = 0.58): set aside, not fitted
    from phoid.errors import IdentificationError

    # (without the floor it was fitted: ω₀ 9.4 ± 0.37 rad/s for a 9.42 rad/s sine of 0.7 count
    # rounded, a "decay" read off the rounding; exp3's second half: 44.6 ± 1.5)
    t = np.arange(125) / 100.0
    x = 2.0 * np.round(0.7 * np.sin(2 * math.pi * 1.5 * t))
    with pytest.raises(IdentificationError, match="never moves"):
        identify_free_data([(t, x)])


def coulomb_soft(t, w0=10.0, zeta=0.003, qc=0.01, eps=-0.03, x0=1.0):
    """x'' = -ω₀²(x + εx³) - 2ζω₀x' - ω₀²qc·sign(x') from rest at x0 by solve_ivp, half cycle by
    half cycle (terminal events at v = 0), stuck where the spring cannot beat the friction:
    Coulomb friction with a frequency that rises as the amplitude falls (ε < 0), like the
    measured torsion pendulum."""
    x = np.empty(t.size)
    t0, y0, sgn, i = 0.0, [x0, 0.0], -1.0, 0
    for _ in range(1000):
        if abs(y0[0] + eps * y0[0] ** 3) <= qc or t0 >= t[-1]:
            break
        ev = lambda _t, y: y[1]  # noqa: E731
        ev.terminal, ev.direction = True, -sgn
        rhs = lambda _t, y, s=sgn: [y[1], -w0**2 * (y[0] + eps * y[0] ** 3)  # noqa: E731
                                    - 2 * zeta * w0 * y[1] - w0**2 * qc * s]
        sol = solve_ivp(rhs, (t0, t[-1]), y0, events=ev, rtol=1e-10, atol=1e-12,
                        method="DOP853", dense_output=True, first_step=1e-4)
        t1 = sol.t_events[0][0] if sol.t_events[0].size else t[-1]
        sel = (t >= t0) & (t < t1)
        x[sel] = sol.sol(t[sel])[0]
        i = int(np.searchsorted(t, t1))
        t0, y0, sgn = t1, [float(sol.sol(t1)[0]), 0.0], -sgn
    x[i:] = y0[0]
    return x


def test_coulomb_with_an_amplitude_dependent_frequency_is_named_coulomb_first():
    # the real pendulum's pattern: linear amplitude loss, a stop off zero, and ω rising ~1 % as
    # the amplitude falls; the envelope of the turning points names Coulomb friction first
    x = coulomb_soft(T200)
    res = fit(x, T200, noise=1e-3, seed=12)
    ad = res.adequacy
    assert ad.causes[0] == "coulomb", ad.causes
    assert "--friction" in ad.warnings[0] and "constant amount" in ad.warnings[0]


def test_duffing_is_not_taken_for_coulomb():
    # the Duffing decay of test_duffing_spring_is_amplitude_dependent_stiffness: its viscous
    # decay rate changes with the amplitude through the spring (-(5/6) of the frequency's
    # relative change), which the envelope's warp removes
    x = ode(lambda x, v: -100 * x - 0.4 * v - 30 * x**3, T200[:4000])
    res = fit(x, T200[:4000], seed=4)
    assert "coulomb" not in res.adequacy.causes


def test_a_few_cycles_that_end_stuck_name_coulomb_from_the_stop():
    # 0.5 Hz, Coulomb band q = 0.1/ω₀² of x₀ = 0.1: stuck after 5 half-cycles (5 s) of a 10 s
    # record (exact half-cycle formula above) — too few turning points for the envelope test
    # (13) and too few windows for the trend (4), so only the stop can say Coulomb: the viscous
    # model still swings where the record lies still, off the fitted rest
    w0 = 2 * math.pi * 0.5
    t = np.arange(2000) / 200.0
    x = 0.1 * coulomb(t, w0=w0, zeta=0.02 / w0, q=0.1 / w0**2 / 0.1)
    res = fit(x, t, noise=1e-4, seed=2)
    assert res.adequacy.causes[0] == "coulomb", res.adequacy.causes
    assert any("ends stuck" in w and "--friction" in w for w in res.warnings)
    # and a clean viscous decay of the same length says nothing of the kind (it never stops
    # while its model swings)
    clean = 0.1 * coulomb(t, w0=w0, zeta=0.05 / w0, q=0.0)
    assert "coulomb" not in fit(clean, t, noise=1e-4, seed=2).adequacy.causes
