"""Fit statistics of the identification results (docs/format-extensions.md): the correlation
helper, χ²/dof, the model-independent noise level and each run's residual/noise ratio, the text
blocks, and Estimate as a number.

Expected values come from numpy computed here (the correlation), from the χ² distribution
(scipy.stats) and from the straight-line geometry of eq. (35) (corr(m, k) on the sample set);
the tolerances are derived next to each assertion.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid.cli import app
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import (
    difference_noise,
    fit_blocks,
    residual_noise_ratio,
    window_noise,
)
from phoid.reports.statistics import correlation, correlation_lines, statistics_lines

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
runner = CliRunner()


def cli(*args) -> str:
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, (args, r.output)
    return r.stdout


def json_of(*args) -> dict:
    return json.loads(cli(*args))


@pytest.fixture(scope="module")
def sample_json() -> dict:
    return json_of("identify", SAMPLE, "--json")


# --------------------------------------------------------------------------------------------
# covariance → correlation


def test_correlation_is_cov_over_the_outer_product_of_the_stderrs():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((5, 5)) * np.array([1e-3, 1.0, 1e3, 1e-6, 10.0])
    cov = a @ a.T  # a covariance with very different scales
    expected = cov / np.sqrt(np.multiply.outer(np.diag(cov), np.diag(cov)))
    # rounding only: a few ulp of 1 after the division
    np.testing.assert_allclose(correlation(cov), expected, rtol=1e-12, atol=1e-15)
    assert np.all(np.diag(correlation(cov)) == 1.0)


def test_a_parameter_without_variance_has_a_null_correlation():
    cov = np.diag([4.0, 0.0, 9.0])
    cov[0, 2] = cov[2, 0] = 3.0
    rho = correlation(cov)
    assert rho[0, 2] == pytest.approx(0.5)  # 3 / (2·3)
    assert np.all(np.isnan(rho[1])) and np.all(np.isnan(rho[:, 1]))
    block = fit_blocks(["a", "b", "c"], ["m", "m", "m"], cov, None, None, of="test")
    assert block["correlation"]["matrix"][1] == [None, None, None]
    assert block["statistics"]["chi2"] is None and block["statistics"]["chi2_dof"] is None


def test_the_json_correlation_is_the_json_covariance_normalised(sample_json):
    cov = np.array(sample_json["covariance"]["matrix"], dtype=float)
    d = np.diag(cov)
    expected = cov / np.sqrt(np.multiply.outer(d, d))
    got = np.array(sample_json["correlation"]["matrix"], dtype=float)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)
    # the covariance's diagonal holds the squared stderrs that m, c, k report
    se = [sample_json[k]["stderr"] for k in ("m", "c", "k")]
    np.testing.assert_allclose(np.sqrt(d), se, rtol=1e-12)
    assert sample_json["covariance"]["params"] == ["m", "c", "k"]
    assert sample_json["covariance"]["units"] == ["kg", "N s/m", "N/m"]


def test_m_k_correlation_on_the_sample_set_is_the_stiffness_lines_geometry(sample_json):
    # m and −k are the slope and intercept of k′ᵢ = m ω₀ᵢ² − k (eq. 35). For a straight line
    # fitted by least squares with equal weights, corr(slope, −intercept) = x̄/√(mean x²),
    # x = ω₀ᵢ² = σᵢ² + ω_dᵢ²: the runs' ω₀ᵢ² (33 to 58 1/s²) are far from 0, hence ≈ 0.99.
    # The weighted fit weighs the runs by their precision instead of equally, which moves the
    # weighted mean of ω₀ᵢ² within that range; over it x̄/√(mean x²) changes by less than
    # 0.005 for any weights that are not dominated by one run.
    runs = [r for r in sample_json["runs"] if r["used"]]
    x = np.array([r["sigma"] ** 2 + r["omega_d"] ** 2 for r in runs])
    geometric = float(np.mean(x) / np.sqrt(np.mean(x * x)))
    rho = sample_json["correlation"]["matrix"][0][2]
    assert rho == pytest.approx(geometric, abs=0.005)
    assert 0.98 < rho < 0.995


# --------------------------------------------------------------------------------------------
# the noise level without a model, and the residual/noise ratio


def test_difference_noise_of_white_noise_is_its_sd_with_the_documented_spread():
    # 400 records of n = 5000 samples of unit white noise: the mean estimate is unbiased and
    # its relative sd is ≈ 1.5/√n (docs/format-extensions.md quotes it). 400 replicates give
    # the mean to 1.5/√(400·5000) ≈ 0.001 (asserted within 5 of those) and the sd to ±3.5 %
    # (1/√(2·400)), so the band 1.3–1.7 is more than 5 of those around 1.5.
    rng = np.random.default_rng(1)
    n = 5000
    est = np.array([difference_noise(rng.standard_normal(n)) for _ in range(400)])
    assert abs(est.mean() - 1.0) < 5 * 1.5 / math.sqrt(400 * n)
    assert 1.3 < est.std(ddof=1) * math.sqrt(n) < 1.7


def test_difference_noise_ignores_a_smooth_motion():
    # a decaying oscillation 1000 noise sd high, 100 samples per period: it adds at most
    # A(ωΔt)³ = 1000·(2π/100)³ ≈ 0.25 noise sd to a third difference of sd √20 ≈ 4.5, i.e.
    # < 0.2 % to the variance; the estimate's own spread is 1.5/√n = 0.021 at n = 5000, so
    # 5 of those bound it
    rng = np.random.default_rng(2)
    n = 5000
    k = np.arange(n)
    x = 1000.0 * np.exp(-k / 3000) * np.sin(2 * np.pi * k / 100) + rng.standard_normal(n)
    assert difference_noise(x) == pytest.approx(1.0, abs=5 * 1.5 / math.sqrt(n))
    # the window helper picks the samples inside [t0, t1]: a noisier half does not leak in
    t = k * 1e-3
    y = np.where(k < n // 2, rng.standard_normal(n), 10 * rng.standard_normal(n))
    assert window_noise(t, y, 0.0, t[n // 2 - 1]) == pytest.approx(1.0, abs=5 * 1.5 /
                                                                  math.sqrt(n / 2))


def _sine_fit(t, x, omega):
    """Least squares of x ≈ a cos ωt + b sin ωt + d (ω given): the residual RMS."""
    A = np.c_[np.cos(omega * t), np.sin(omega * t), np.ones_like(t)]
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    r = x - A @ coef
    return float(np.sqrt(np.mean(r * r)))


def test_the_ratio_is_one_for_the_right_model_and_large_for_a_wrong_one():
    # a sine (80 samples per period, 300 noise sd high) in white noise, n = 4000: the right
    # model's residual is the noise, ratio √((n − 3)/n) ≈ 1 with spread ≈ 1.7/√n (the
    # residual RMS 1/√(2n) and the noise level 1.5/√n combined) = 0.027: 5 of those bound it
    rng = np.random.default_rng(3)
    n = 4000
    t = np.arange(n) * 1e-3
    omega = 2 * np.pi / 0.08
    for seed in range(5):
        noise = np.random.default_rng(seed).standard_normal(n) * 1e-5
        x = 3e-3 * np.sin(omega * t + 0.3) + noise
        q = residual_noise_ratio(_sine_fit(t, x, omega), difference_noise(x))
        assert q == pytest.approx(1.0, abs=5 * 1.7 / math.sqrt(n))
    # the wrong model (a frequency 1 % off, so the fitted sine drifts out of phase over the
    # record's 50 periods): the residual is a fraction of the 300-sd signal, far above 1 + 10/√n
    x = 3e-3 * np.sin(omega * t + 0.3) + rng.standard_normal(n) * 1e-5
    q = residual_noise_ratio(_sine_fit(t, x, 1.01 * omega), difference_noise(x))
    assert q > 10.0
    assert residual_noise_ratio(1.0, 0.0) is None and residual_noise_ratio(math.nan, 1) is None


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> dict[str, list[dict]]:
    """identify --json of four independent noisy sets (seeds 1–4) per method, each with the
    right model (no friction): pho (6 runs, the delay given), forced (3 frequencies), free."""
    root = tmp_path_factory.mktemp("fit-stats")
    plant = ("--m", "1", "--c", "2", "--k", "100")
    out: dict[str, list[dict]] = {"pho": [], "forced": [], "free": []}
    for seed in range(1, 5):
        cli("simulate", root / f"p{seed}", *plant, "--P", "20:200:6", "--D", "0.5:3:6",
            "--delay", "0.02", "--duration", "3", "--fs", "500", "--noise", "1e-5", "--seed",
            seed)
        out["pho"].append(json_of("identify", root / f"p{seed}", "--json"))
        cli("simulate", root / f"f{seed}", "--method", "forced", *plant, "--omega", "6,9,14",
            "--duration", "8", "--fs", "200", "--noise", "1e-5", "--seed", seed)
        out["forced"].append(json_of("identify", root / f"f{seed}", "--json"))
        cli("simulate", root / f"e{seed}", "--method", "free", *plant, "--duration", "3",
            "--fs", "500", "--noise", "1e-5", "--seed", seed)
        out["free"].append(json_of("identify", root / f"e{seed}", "--json"))
    return out


@pytest.mark.parametrize("method", ["pho", "forced"])
def test_chi2_of_the_right_model_follows_the_chi2_distribution(simulated, method):
    from scipy import stats

    # four independent sets: Σχ² ~ χ² with Σdof degrees of freedom when the weights are the
    # real noise; the two-sided 99.9 % interval of that distribution
    chi2 = sum(d["statistics"]["chi2"] for d in simulated[method])
    dof = sum(d["statistics"]["dof"] for d in simulated[method])
    assert dof == 4 * (2 * len(simulated[method][0]["runs"]) - 3)  # 2·runs − (m, c, k)
    assert stats.chi2.ppf(0.0005, dof) < chi2 < stats.chi2.ppf(0.9995, dof)
    for d in simulated[method]:
        s = d["statistics"]
        assert s["weighted"] is True and s["chi2_dof"] == pytest.approx(s["chi2"] / s["dof"])
        assert s["p_value"] == pytest.approx(stats.chi2.sf(s["chi2"], s["dof"]), rel=1e-9)


def test_chi2_dof_of_the_free_fit_is_one_within_the_noise_estimates_spread(simulated):
    # χ² = Σ nᵢ rmsᵢ²/ŝᵢ² with ŝ from third differences: its χ²/dof spreads by √(2/n) from the
    # residual and by 2·1.5/√n from ŝ² (the noise level's relative sd 1.5/√n, doubled for the
    # square); 5 of that combined sd
    for d in simulated["free"]:
        s = d["statistics"]
        tol = 5 * math.sqrt(2 / s["dof"] + (2 * 1.5) ** 2 / s["dof"])
        assert s["chi2_dof"] == pytest.approx(1.0, abs=tol)


@pytest.mark.parametrize("method", ["pho", "forced", "free"])
def test_every_run_of_the_right_model_has_a_ratio_near_one(simulated, method):
    # each run's window holds ≥ 900 samples (3 s at 500 Hz after the release, or 8 s at
    # 200 Hz after the start-up), so the ratio's spread 1.7/√n is ≤ 0.057: 5 of those
    for d in simulated[method]:
        for r in d["runs"]:
            assert r["residual_noise_ratio"] == pytest.approx(1.0, abs=5 * 1.7 / math.sqrt(900))


def test_a_friction_set_identified_as_linear_shows_misfit_ratios(tmp_path):
    # Coulomb friction (0.3 N on 1 kg) makes the decays linear-ish, not exponential: the
    # linear model leaves structure far above the 10 µm noise (beyond 1 + 10/√n ≈ 1.3)
    cli("simulate", tmp_path / "s", "--m", "1", "--c", "2", "--k", "100", "--fc", "0.3",
        "--P", "20:150:4", "--D", "0.5:3:4", "--delay", "0.02", "--duration", "3", "--fs",
        "500", "--noise", "1e-5", "--seed", "3")
    d = json_of("identify", tmp_path / "s", "--json", "--delay", "0.02")
    ratios = [r["residual_noise_ratio"] for r in d["runs"] if r["used"]]
    assert ratios and min(ratios) > 3.0


def test_statistics_are_present_and_finite_for_every_method(simulated, sample_json):
    for d in [sample_json, *simulated["pho"], *simulated["forced"], *simulated["free"]]:
        for key in ("chi2", "dof", "chi2_dof", "p_value"):
            assert math.isfinite(d["statistics"][key]), (d["method"], key)
        n = len(d["covariance"]["params"])
        assert np.array(d["covariance"]["matrix"], dtype=float).shape == (n, n)
        assert np.all(np.isfinite(np.array(d["correlation"]["matrix"], dtype=float)))
        assert all(math.isfinite(r["residual_noise_ratio"]) for r in d["runs"] if r["used"])
    assert simulated["free"][0]["covariance"]["params"] == ["sigma", "k_over_m"]


# --------------------------------------------------------------------------------------------
# text


def test_the_text_report_has_the_statistics_and_correlation_blocks(sample_json):
    text = cli("identify", SAMPLE)
    assert "[[Fit statistics]]" in text and "[[Correlations]]" in text
    rho = sample_json["correlation"]["matrix"][0][2]
    assert f"C(m, k) = {rho:+.4f}" in text
    assert f"χ²/dof         {sample_json['statistics']['chi2_dof']:.4g}" in text
    assert "resid/noise" in text
    # the correlations are listed largest first, as lmfit's fit_report does
    lines = correlation_lines(sample_json["correlation"])
    values = [abs(float(s.rsplit("=", 1)[1])) for s in lines[1:]]
    assert values == sorted(values, reverse=True) and len(values) == 3
    assert correlation_lines(sample_json["correlation"], min_correl=0.99)[1] == "    (none)"
    assert any("RSS" in s for s in statistics_lines({**sample_json["statistics"],
                                                     "weighted": False}))


# --------------------------------------------------------------------------------------------
# Estimate as a number


def test_estimate_float_and_format():
    e = Estimate(2.000123, 0.0042, "kg")
    assert float(e) == 2.000123
    assert f"{e:.4f}" == "2.0001" and format(e, ".2e") == "2.00e+00"
    assert f"{e}" == "2.0001 ± 0.0042 kg" == format(e, "")
    assert f"{Estimate(64.0, None, 'N/m')}" == "64 N/m"
    assert f"{Estimate(0.0442, 3e-5, '')}" == "0.044200 ± 3e-05"
    assert (e.value, e.stderr, e.unit) == (2.000123, 0.0042, "kg")
    assert math.isclose(np.float64(e), 2.000123)


def test_tracking_output_error_chi2_is_that_of_its_fit(tmp_path):
    # a simulated tracking record with 2 µm white position noise, fitted by output error: the
    # right model, so χ²/dof of its own position residual is 1 within its spread √(2/dof) from
    # the residual and 2·1.5/√n from the third-difference noise level (5 of that combined sd)
    from test_json_schema import _tracking_set

    folder = _tracking_set(tmp_path / "set")
    d = json_of("identify", folder, "--json", "--estimator", "output-error")
    s = d["statistics"]
    assert "output-error fit" in s["of"]
    assert s["chi2_dof"] == pytest.approx(1.0, abs=5 * math.sqrt(11 / s["dof"]))
    assert d["correlation"]["params"] == d["fit"]["free"]
    # the Newey–West correlation that fit prints is the top-level block's
    np.testing.assert_allclose(np.array(d["correlation"]["matrix"], dtype=float),
                               np.array(d["fit"]["correlation"], dtype=float), atol=1e-12)
