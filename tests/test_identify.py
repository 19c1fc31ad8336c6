"""phoid.identify on the independent sample sets (made by jitcdde, not by phoid).

The sample-set tests run on examples/paper-sample (in the repository) and again, as a
cross-check, on ../shared/data/paper-sample (the project's own set: another noise draw, other
digits; CI has it), skipped where that is absent (tests/conftest.py's ``paper_sample``).

Statistical tolerances: "within 3 reported stderr of the truth" (|z| < 3) fails with probability
0.27 % per quantity for a calibrated Gaussian stderr (under 1 % for m, c, k together). The noise
is seeded or recorded, so each such check gives the same verdict on every machine: the measured
|z| move across BLAS kernels and thread counts by < 1e-7 relative (3e-8 measured), and no |z|
here is that close to 3.
"""

import numpy as np
import pytest

from phoid import IdentificationError
from phoid.api import identify, identify_data
from phoid.io import read_experiment


@pytest.fixture(scope="module")
def sample(paper_sample):
    return read_experiment(paper_sample.path)


@pytest.fixture(scope="module")
def truth(paper_sample):
    """The truth of the set under test (overrides conftest's, which is the examples set's)."""
    return paper_sample.truth


@pytest.fixture(scope="module")
def gls(sample):
    return identify(sample)


def test_sample_set_within_3_stderr_and_near_crb(gls, truth):
    # Issue 3's acceptance: each of m, c, k within 3 stderr of the truth (truth.json), each
    # stderr at most 1.5x the Cramer-Rao bound that truth.json gives for this set (the same
    # experiment in both sets: README and examples/README.md quote the examples set's numbers).
    for q in "mck":
        est = getattr(gls, q)
        assert abs(est.value - truth[q]) < 3 * est.stderr, q
        assert est.stderr <= 1.5 * truth["crb_sd"][q], q
        # and not implausibly small: the CRB is a lower bound on an unbiased estimator's sd
        assert est.stderr >= 0.9 * truth["crb_sd"][q], q


def test_runs_modes_agree_with_exact_roots(gls, truth):
    # each run's sigma, omega_d against the exact dominant root of the true loop
    # (phoid.dynamics,
    # itself checked by the argument principle): |z| < 4 for all 38 numbers
    from phoid import Plant, forward_map

    P = np.array([r.P for r in gls.runs])
    D = np.array([r.D for r in gls.runs])
    ex = forward_map(Plant(truth["m"], truth["c"], truth["k"]), P, D, truth["delay"])
    zs = [(r.sigma - s) / r.sigma_stderr for r, s in zip(gls.runs, ex.sigma, strict=True)]
    zw = [(r.omega_d - w) / r.omega_d_stderr for r, w in zip(gls.runs, ex.omega_d, strict=True)]
    assert np.max(np.abs(zs)) < 4 and np.max(np.abs(zw)) < 4


def test_summary_follows_the_spec(gls):
    s = gls.summary()
    assert s["method"] == "pho"
    for q, unit in (("m", "kg"), ("c", "N s/m"), ("k", "N/m")):
        assert set(s[q]) >= {"value", "stderr", "unit"} and s[q]["unit"] == unit
    assert s["delay"] == {"value": 0.1, "stderr": None, "unit": "s", "source": "given"}
    assert len(s["runs"]) == 19
    assert set(s["runs"][0]) >= {"file", "P", "D", "sigma", "omega_d", "c_prime", "k_prime",
                                 "cycles"}
    assert s["runs"][0]["file"] == "run01.csv.gz"
    assert isinstance(s["warnings"], list)


def test_ols_route_is_consistent_but_less_precise(sample, gls, truth):
    ols = identify(sample, estimator="ols")
    for q in "mck":
        assert abs(getattr(ols, q).value - truth[q]) < 3 * getattr(ols, q).stderr
    assert ols.c.stderr > gls.c.stderr


def test_report_text_lists_estimates_and_runs(gls):
    text = gls.report()
    assert "m = " in text and "kg" in text and "run19.csv.gz" in text


def test_identify_data_errors():
    t = np.linspace(0, 5, 5001)
    x = 0.01 * np.exp(-0.5 * t) * np.cos(6 * t)
    with pytest.raises(IdentificationError, match="same gains"):
        identify_data([(t, x), (t, x)], np.array([1.0, 1.0]), np.array([0.5, 0.5]), 0.0)
    with pytest.raises(IdentificationError, match="no runs"):
        identify_data([], np.array([]), np.array([]), 0.0)


def test_run_with_slow_second_root_is_refined_without_false_warning():
    # A gain pair whose next loop root is slow (P 7.38, D 23.36 on the paper plant: roots
    # -1.0 +- 15i and -2.80) biases the first pass, hence the fast modes of the second; the
    # weighted fit's chi2 flags it and the modes are refitted with the better plant. Noise-free
    # records: no warning, m, c, k to 1e-6 (issue 3), that run's sigma to 1e-6 of the exact root.
    from phoid import Plant, forward_map, simulate
    from phoid.paper import PAPER_D, PAPER_P

    plant = Plant(2.0, 1.0, 64.0)
    P = np.r_[PAPER_P[::3], 7.38]
    D = np.r_[PAPER_D[::3], 23.36]
    sim = simulate(plant, P, D, delay=0.1, duration=15, fs=1000, x0=0.01, hold=0.2)
    r = identify_data([(sim.t, sim.x[i]) for i in range(len(P))], P, D, 0.1)
    assert r.warnings == ()
    for q, v in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(r, q).value / v - 1) <= 1e-6
    exact = forward_map(plant, P, D, 0.1)
    assert abs(r.runs[-1].sigma / exact.sigma[-1] - 1) < 1e-6


def test_no_delay_loop_noise_free_and_noisy():
    # Δt = 0: the closed loop is exactly second order (eq. 31 with c'_i = D_i, k'_i = P_i);
    # noise-free records give m, c, k to 1e-6 (issue 3); a noisy seeded set is within 3 stderr
    from phoid import Plant, simulate

    plant = Plant(2.0, 1.0, 64.0)
    P, D = np.linspace(0.25, 25, 10), np.linspace(0.6, 6, 10)
    sim = simulate(plant, P, D, delay=0.0, duration=15, fs=1000, x0=0.01, hold=0.2)
    r = identify_data([(sim.t, sim.x[i]) for i in range(10)], P, D, 0.0)
    assert r.warnings == ()
    for q, v in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(r, q).value / v - 1) <= 1e-6
    rng = np.random.default_rng(11)
    sim = simulate(plant, P, D, delay=0.0, duration=15, fs=1000, x0=0.01, hold=0.2,
                   noise=1e-4, quantum=1e-6, rng=rng)
    r = identify_data([(sim.t, sim.x[i]) for i in range(10)], P, D, 0.0)
    for q, v in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(r, q).value - v) < 3 * getattr(r, q).stderr
