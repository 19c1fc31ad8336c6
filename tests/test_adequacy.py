"""The generic adequacy checks (phoid.methods.adequacy), on series whose truth is known by
construction: seeded white and AR(1) noise, straight lines with a known slope."""

import math

import numpy as np
import pytest
from scipy import stats

from phoid.methods import adequacy as aq


def ar1(n, rho, rng):
    e = np.empty(n)
    w = rng.standard_normal(n)
    e[0] = w[0] / math.sqrt(1 - rho * rho)
    for i in range(1, n):
        e[i] = rho * e[i - 1] + w[i]
    return e


def test_ljung_box_formula_and_distribution():
    # Q = n(n+2) sum rho_k^2/(n-k) over h = min(20, n/5) lags (Ljung and Box 1978), computed
    # here from its definition with numpy's correlate; the p-value against scipy's chi2
    rng = np.random.default_rng(1)
    e = rng.standard_normal(500)
    q, h, lag1 = aq.ljung_box(e)
    d = e - e.mean()
    full = np.correlate(d, d, "full")[d.size - 1:] / (d @ d)
    want = 500 * 502 * sum(full[k] ** 2 / (500 - k) for k in range(1, 21))
    assert h == 20 and q == pytest.approx(want, rel=1e-12) and lag1 == pytest.approx(full[1])
    check = aq.whiteness_check([e])
    assert check.passed
    assert check.threshold == pytest.approx(stats.chi2.isf(aq.ALPHA, 20), rel=1e-6)


def test_whiteness_false_alarms_are_rare_and_ar1_is_caught():
    # 400 white series: at alpha = 1e-3 the expected number of failures is 0.4; 3 or more has
    # probability ~8e-4 (Poisson(0.4)) -- a calibrated test passes this
    rng = np.random.default_rng(2)
    fails = sum(not aq.whiteness_check([rng.standard_normal(800)]).passed for _ in range(400))
    assert fails <= 2
    # AR(1) with rho = 0.5 over 800 samples: rho_1^2 n ~ 200, far beyond chi2_20's 1e-3 tail
    assert aq.whiteness_check([ar1(800, 0.5, rng)]).passed is False


def test_noise_check_threshold():
    # 1 + max(0.1, 10/sqrt(n)): 10/sqrt(n) is ~6 sd of the ratio's spread 1.7/sqrt(n)
    assert aq.noise_threshold(100) == pytest.approx(2.0)
    assert aq.noise_threshold(1_000_000) == pytest.approx(1.1)
    rng = np.random.default_rng(3)
    e = rng.standard_normal(2000)
    rms = float(np.sqrt(np.mean(e * e)))
    assert aq.noise_check([e], [rms], ["r"]).passed
    bad = aq.noise_check([3 * e], [rms], ["r"])
    assert bad.passed is False and "residual/noise 3" in bad.detail
    # an unknown noise level leaves the check not applicable, never passed on nothing
    assert aq.noise_check([e], [None], ["r"]).passed is None


def test_agreement_chi2_and_between():
    # two estimates 10 combined stderr apart (each sd 1 on one parameter, 1e-3 on another):
    # chi2 = d^2/(s1^2 + s2^2) = 100 + 0; between = d d^T/4 (the covariance of the mean of two)
    c = np.diag([0.5, 1e-6])
    ag = aq.agreement("halves", [np.array([0.0, 1.0]), np.array([10.0, 1.0])], [c, c],
                      params=("ω₀", "ζ"), units=("rad/s", ""), labels=("a", "b"))
    assert ag.check.statistic == pytest.approx(100.0)
    assert ag.check.passed is False and "10 combined stderr" in ag.check.detail
    assert ag.between == pytest.approx(np.array([[25.0, 0.0], [0.0, 0.0]]))
    assert "halves of the record disagree" in ag.warning()
    # a drifting record's halves: their spread itself, d d^T/2
    ag2 = aq.agreement("halves", [np.array([0.0, 1.0]), np.array([10.0, 1.0])], [c, c],
                       params=("ω₀", "ζ"), units=("rad/s", ""), labels=("a", "b"),
                       of_mean=False)
    assert ag2.between == pytest.approx(np.array([[50.0, 0.0], [0.0, 0.0]]))
    same = aq.agreement("runs", [np.zeros(2)] * 3, [c] * 3, params=("a", "b"), units=("", ""),
                        labels=("1", "2", "3"))
    assert same.check.passed and same.warning() is None


def test_sandwich_is_white_for_white_noise_and_wider_for_ar1():
    # a straight line fitted by least squares: the white covariance is s^2 (X^T X)^-1; with
    # white noise the Newey-West sandwich agrees within its own noise (20 %), with AR(1) noise
    # of rho = 0.8 the slope's variance is ~ (1+rho)/(1-rho) = 9 times larger
    rng = np.random.default_rng(4)
    n = 4000
    X = np.column_stack([np.ones(n), np.linspace(-1, 1, n)])
    white = np.linalg.inv(X.T @ X)
    sw = aq.sandwich([X], [rng.standard_normal(n)])
    assert np.sqrt(np.diag(sw) / np.diag(white)) == pytest.approx([1, 1], rel=0.2)
    sw_ar = aq.sandwich([X], [ar1(n, 0.8, rng) * 0.6])  # marginal sd 1
    assert np.all(np.sqrt(np.diag(sw_ar) / np.diag(white)) > 2.0)


def test_structure_classifies_trends():
    # sigma = 0.1 + 0.02/A (Coulomb-like: rising as A falls), omega flat; then sigma = 0.5 A
    a = np.linspace(0.1, 1.0, 8)
    se = np.full(8, 1e-3)
    flat = np.full(8, 10.0)
    chk, causes, warns = aq.structure_check(aq.Windows(a, 0.1 + 0.02 / a, se, flat, se))
    assert chk.passed is False and causes == ("coulomb",) and "--friction" in warns[0]
    chk, causes, _ = aq.structure_check(aq.Windows(a, 0.5 * a, se, flat, se))
    assert causes == ("amplitude_damping",)
    chk, causes, _ = aq.structure_check(aq.Windows(a, np.full(8, 0.1), se, 10 + 0.3 * a**2,
                                                   se))
    assert causes == ("amplitude_stiffness",)
    # scatter within the stderr: no trend
    rng = np.random.default_rng(5)
    chk, causes, _ = aq.structure_check(aq.Windows(a, 0.1 + 1e-3 * rng.standard_normal(8), se,
                                                   flat + 1e-3 * rng.standard_normal(8), se))
    assert chk.passed and causes == ()
    assert aq.structure_check(None)[0].passed is None


def test_spectral_peak_finds_a_second_mode_not_the_first():
    rng = np.random.default_rng(6)
    t = np.arange(4096) / 100.0
    # a sine of amplitude 0.5 in unit white noise, 4096 samples: its Hann periodogram peak is
    # ~(0.5 N/4)^2 against a level 0.375 N, ~40x the threshold ln(N/2/1e-3) = 14.5
    e = rng.standard_normal(t.size) + 0.5 * np.sin(2 * np.pi * 4.7 * t)
    f, ratio = aq.spectral_peak(e, 0.01, (1.0, 1.1))
    assert f == pytest.approx(4.7, abs=0.05) and ratio > 20
    # a peak inside the motion's band (or at a harmonic) is not a second mode
    assert aq.spectral_peak(e, 0.01, (4.5, 4.9)) is None
    assert aq.spectral_peak(e, 0.01, (2.3, 2.4)) is None
    assert aq.spectral_peak(rng.standard_normal(4096), 0.01, (1.0, 1.1)) is None


def test_assess_keeps_white_when_everything_passes():
    white = np.diag([1.0, 4.0])
    sw = np.diag([1.1, 3.0])
    ok = aq.Check("noise", 1.0, 1.1, True, "")
    a = aq.assess([ok], names=("a", "b"), units=("", ""), white_cov=white, sandwich_cov=sw)
    assert a.stderr == "white" and np.array_equal(a.robust_cov, white)
    assert a.inflation == (1.0, 1.0) and a.passed
    bad = aq.Check("whiteness", 99.0, 40.0, False, "")
    b = aq.assess([ok, bad], names=("a", "b"), units=("", ""), white_cov=white,
                  sandwich_cov=sw, between=[np.diag([3.0, 0.0])])
    # the sandwich, raised to the white variance where below it, plus the between-parts one
    assert b.stderr == "robust" and not b.passed
    assert np.diag(b.robust_cov) == pytest.approx([1.1 + 3.0, 4.0])
    d = b.to_dict()
    assert d["stderr"] == "robust" and d["checks"][1]["passed"] is False
    assert d["inflation"] == pytest.approx([math.sqrt(4.1), 1.0])


def test_t_quantile_against_scipy():
    # the Cornish-Fisher t quantile (A&S 26.7.5) against scipy.stats.t, within its stated
    # 0.5 % for dof >= 6 and p >= 5e-4 (the envelope test uses p = 5e-4, dof >= 9)
    for dof in (6, 9, 20, 100, 1000):
        for p in (5e-4, 5e-3, 0.05):
            assert aq.t_isf(p, dof) == pytest.approx(stats.t.isf(p, dof), rel=5e-3)
    assert aq.normal_isf(5e-4) == pytest.approx(stats.norm.isf(5e-4), abs=1e-9)


def half_cycle_decay(sigma, wd, qc, x0=1.0, fs=200.0):
    """Exact turning-point-to-turning-point motion of x'' + 2σx' + ω₀²x = −ω₀²qc·sign(x')
    (viscous about ±qc each half cycle, from rest at x0; qc = 0: the linear decay)."""
    half = math.pi / wd
    t_all, x_all, xs, t0 = [], [], x0, 0.0
    while abs(xs) > max(qc, 1e-3) and t0 < 60.0:
        xe = math.copysign(qc, xs)
        tau = np.arange(math.ceil(t0 * fs), math.ceil((t0 + half) * fs)) / fs - t0
        t_all.append(tau + t0)
        x_all.append(xe + (xs - xe) * np.exp(-sigma * tau)
                     * (np.cos(wd * tau) + sigma / wd * np.sin(wd * tau)))
        t0 += half
        xs = xe - (xs - xe) * math.exp(-sigma * half)
    return np.concatenate(t_all), np.concatenate(x_all)


@pytest.mark.parametrize(("qc", "sign"), [(0.0, 0), (0.004, 1)])
def test_envelope_tells_a_constant_loss_from_an_exponential(qc, sign):
    # the turning points of an exact decay (half_cycle_decay), noise sd 1e-3, about an
    # offset 0.3: the linear one is not significant, the Coulomb one is, with q = σ qc
    # (1 + e^{-σh})/(1 - e^{-σh}) (dA/dt = -σA - q over a half cycle h against the exact
    # A' = e^{-σh}A - qc(1 + e^{-σh})); 10 % (its stderr is ~1 %)
    sigma, wd = 0.05, 10.0
    t, x = half_cycle_decay(sigma, wd, qc)
    rng = np.random.default_rng(3)
    x = x + 0.3 + 1e-3 * rng.standard_normal(x.size)
    tk, pk, sk = aq.turning_points(t, x, 0.3, wd, 1e-3)
    # one per half cycle (the last, at the stop, 3 % long: sticking at v = 0 ends its parabola)
    assert tk.size >= 40 and np.all(np.diff(tk) == pytest.approx(math.pi / wd, rel=0.03))
    env = aq.envelope_test(tk, pk, sk)
    assert env is not None and env.sigma == pytest.approx(sigma, rel=0.1)
    if sign == 0:
        assert not env.significant
    else:
        h = math.pi / wd
        want = sigma * qc * (1 + math.exp(-sigma * h)) / (1 - math.exp(-sigma * h))
        assert env.significant and env.loss == pytest.approx(want, rel=0.1)


def test_envelope_false_alarms_on_exponential_decays():
    # 300 exponential envelopes with independent errors (the turning points of a linear decay,
    # drawn directly, down to 30 noise sd), each half cycle at its own slightly varying time
    # (the backbone fit finds no trend: the warp stays ~1): the two-sided test at
    # alpha = 1e-3 may trip at most 3 times (P(≥ 4 | 300, 1e-3) = 3.6e-4)
    rng = np.random.default_rng(4)
    trips = 0
    for _i in range(300):
        sigma = float(rng.uniform(0.01, 0.5))
        se = np.full(1, 10 ** rng.uniform(-4, -2))
        # as turning_points gives them: down to 30 noise sd
        m = int(min(math.log(1 / (30 * se[0])) / (sigma * 0.31), 150))
        tk = np.cumsum(rng.uniform(0.3, 0.32, m))
        s = np.where(np.arange(m) % 2 == 0, 1.0, -1.0)
        se = np.full(m, se[0])
        pk = 0.1 + s * np.exp(-sigma * tk) + se * rng.standard_normal(m)
        env = aq.envelope_test(tk, pk, se)
        trips += env is not None and env.significant
    assert trips <= 3


def test_structure_names_coulomb_from_the_envelope_and_drag_by_its_sign():
    base = dict(n=50, sigma=0.1, loss_se=1.0, threshold=3.5, amp_first=1.0, amp_last=0.01)
    for q, cause in ((5.0, "coulomb"), (-5.0, "amplitude_damping"), (1.0, None)):
        env = aq.Envelope(loss=q, t=q, **base)
        chk, causes, warns = aq.structure_check(None, envelope=env)
        assert chk.passed is (cause is None)
        assert causes == ((cause,) if cause else ())
    _chk, causes, warns = aq.structure_check(None, envelope=aq.Envelope(loss=5.0, t=5.0, **base))
    assert "--friction" in warns[0]
