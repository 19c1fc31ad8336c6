"""Model adequacy in the pho method (issue 27): each run's residual against its noise and for
whiteness, the runs' agreement, and the robust stderr where a check fails.

The synthetic records are computed here by an independent exact formula, not by phoid's
simulator: the loop has no delay (Δt = 0), so the closed loop m x'' + (c + D) x' + (k + P) x
= 0 is a damped oscillator released from rest, x = x₀e^{−στ}(cos ω_dτ + σ/ω_d sin ω_dτ); with
Coulomb friction f_c each half-cycle is the same oscillation about the shifted rest
±f_c/(k + P), joined where the velocity vanishes, until the spring force no longer beats f_c
(the mass sticks). The coloured noise is an AR(1) series generated here.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from phoid.methods.identification import identify_pho_data

ROOT = Path(__file__).resolve().parents[1]
# the plant and gains of the synthetic sets (the paper's plant: m = 2 kg, c = 1 N s/m, k = 64 N/m)
M, C, K = 2.0, 1.0, 64.0
P = np.array([20.0, 40.0, 60.0, 80.0, 30.0])
D = np.array([1.0, 3.0, 2.0, 4.0, 0.5])
FS, T, X0, T_REL, NOISE = 200.0, 12.0, 0.01, 0.5, 1e-5


def _ring(Pi: float, Di: float, fc: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free record of one run (module docstring), held at X0 until T_REL."""
    t = np.arange(0.0, T, 1.0 / FS)
    kk = K + Pi
    s = (C + Di) / (2 * M)
    wd = math.sqrt(kk / M - s * s)
    x = np.full(t.size, X0)
    start, xs = T_REL, X0
    for _ in range(1000):  # bounded: every half-cycle loses at least 2 f_c/kk of amplitude
        if fc > 0 and abs(xs) <= fc / kk:
            break
        if start >= t[-1]:
            break
        xe = math.copysign(fc / kk, xs) if fc > 0 else 0.0
        end = start + math.pi / wd if fc > 0 else math.inf
        sel = (t >= start) & (t < end)
        tau = t[sel] - start
        x[sel] = xe + (xs - xe) * np.exp(-s * tau) * (np.cos(wd * tau) + s / wd * np.sin(wd * tau))
        if fc == 0:
            return t, x
        xs = xe - (xs - xe) * math.exp(-s * math.pi / wd)
        start = end
    x[t >= start] = xs
    return t, x


def _ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    """AR(1) noise of sd NOISE and lag-1 correlation rho (stationary from the first sample)."""
    e = rng.normal(0.0, NOISE * math.sqrt(1 - rho * rho), n)
    out = np.empty(n)
    acc = rng.normal(0.0, NOISE)
    for j in range(n):
        acc = rho * acc + e[j]
        out[j] = acc
    return out


def _identify(rng: np.random.Generator, *, rho: float = 0.0, fc: float = 0.0):
    data = []
    for p, d in zip(P, D, strict=True):
        t, x = _ring(p, d, fc)
        noise = _ar1(rng, t.size, rho) if rho else rng.normal(0.0, NOISE, t.size)
        data.append((t, x + noise))
    return identify_pho_data(data, P, D, 0.0)


def test_coloured_noise_warns_and_widens_the_stderr() -> None:
    """AR(1) noise (ρ = 0.8): the whiteness check fails, the warning says so, and the stderr
    are the robust ones (≥ the white-noise ones, which are kept in white_stderr)."""
    res = _identify(np.random.default_rng(8), rho=0.8)
    ad = res.adequacy
    white = {c.name: c for c in ad.checks}["whiteness"]
    assert white.passed is False
    assert ad.stderr == "robust"
    assert any("not white noise" in w for w in res.warnings)
    for est in (res.m, res.c, res.k):
        assert est.white_stderr is not None
        assert est.stderr >= est.white_stderr
    assert res.summary()["m"]["stderr_white"] == pytest.approx(res.m.white_stderr)


def test_coloured_noise_coverage_better_than_white() -> None:
    """Over 12 replicas with AR(1) noise (ρ = 0.8) the robust stderr cover the truth (m, c, k
    of the formula) within 3 stderr at least 34 times of 36, the white-noise ones markedly
    less often. With ρ = 0.8 the white stderr understate by about √((1 + ρ)/(1 − ρ)) = 3:
    their 3-stderr band is a 1-stderr one, ~68 % coverage; 34/36 = 94 % leaves room for the
    robust estimate's own spread over so few replicas."""
    robust = white = 0
    for seed in range(12):
        res = _identify(np.random.default_rng(100 + seed), rho=0.8)
        for est, truth in ((res.m, M), (res.c, C), (res.k, K)):
            wse = est.white_stderr if est.white_stderr is not None else est.stderr
            robust += abs(est.value - truth) < 3 * est.stderr
            white += abs(est.value - truth) < 3 * wse
    assert robust >= 34
    assert white < robust - 3


def test_coulomb_friction_without_friction_warns() -> None:
    """Coulomb friction (f_c = 0.05 N) identified as viscous: the residual misfits, some runs
    end stuck, and a warning names friction and --friction."""
    res = _identify(np.random.default_rng(3), fc=0.05)
    ad = res.adequacy
    assert not ad.passed
    assert "coulomb" in ad.causes
    assert any("Coulomb friction" in w and "--friction" in w for w in ad.warnings)
    assert ad.stderr == "robust"
    assert res.m.stderr > res.m.white_stderr


def test_white_noise_set_passes_unchanged() -> None:
    """White noise and the right model: every applicable check passes and the stderr are
    the white-noise ones (no white_stderr beside them)."""
    res = _identify(np.random.default_rng(5))
    assert res.adequacy.passed
    assert res.adequacy.stderr == "white"
    assert all(e.white_stderr is None for e in (res.m, res.c, res.k))
    assert not res.warnings


@pytest.mark.parametrize("options", [[], ["--estimator", "ols"]])
def test_paper_sample_every_check_passes(options: list[str]) -> None:
    """The example set (examples/paper-sample): every applicable check passes and the stderr
    are the fit's own: no ``stderr_white`` key (the robust stderr is only reported where a
    check fails), no warning; the adequacy block is in the JSON."""
    out = subprocess.run([str(Path(sys.executable).parent / "phoid"), "identify",
                          str(ROOT / "examples" / "paper-sample"), "--json", *options],
                         capture_output=True, text=True, timeout=120, check=True)
    d = json.loads(out.stdout)
    assert d["adequacy"]["passed"] is True
    assert d["adequacy"]["stderr"] == "white"
    assert d["warnings"] == []
    for key in ("m", "c", "k"):
        assert "stderr_white" not in d[key]
        assert d["adequacy"]["stderr_robust"] == d["adequacy"]["stderr_white"]


def _forced_set(rng: np.random.Generator, rho: float) -> list:
    """A sweep in steady state, x = Re(B H(iω) e^{iωt}) with H = 1/(k − mω² + icω) (the exact
    response of eq. 19, computed here), with AR(1) noise of sd 1e-4 m on x and white noise on F."""
    out = []
    for w in (3.0, 4.5, 5.5, 6.5, 8.0, 10.0):
        t = np.arange(0.0, 20.0, 1.0 / FS)
        x = (np.exp(1j * w * t) / (K - M * w * w + 1j * C * w)).real
        e = rng.normal(0.0, 1e-4 * math.sqrt(1 - rho * rho), t.size)
        n = np.empty(t.size)
        acc = rng.normal(0.0, 1e-4)
        for j in range(t.size):
            acc = rho * acc + e[j]
            n[j] = acc
        out.append((t, x + n, np.cos(w * t) + rng.normal(0.0, 1e-3, t.size)))
    return out


def test_forced_coloured_noise_warns_and_widens() -> None:
    """A forced sweep with AR(1) noise (ρ = 0.8) on x: the residual checks fail with a
    warning, the stderr are the robust ones with the white-noise ones beside them; the same
    sweep with white noise passes with the fit's own stderr."""
    from phoid.methods.forced import identify_forced_data

    res = identify_forced_data(_forced_set(np.random.default_rng(4), 0.8))
    assert res.adequacy.stderr == "robust"
    assert any("not white noise" in w for w in res.warnings)
    for est in (res.m, res.c, res.k):
        assert est.white_stderr is not None and est.stderr >= est.white_stderr
    assert "stderr_white" in res.summary()["m"]
    ok = identify_forced_data(_forced_set(np.random.default_rng(4), 0.0))
    assert ok.adequacy.passed and ok.adequacy.stderr == "white"
    assert all(e.white_stderr is None for e in (ok.m, ok.c, ok.k))


def test_release_found_under_strongly_coloured_noise() -> None:
    """AR(1) noise with ρ = 0.9 and 0.95 (sd NOISE, the held segment's too): the white-noise
    threshold (8 second-difference sds, which understate such noise 4–5 times) is crossed in
    the held segment itself; the release is still found where the formula puts it (T_REL).
    Tolerance: 10 samples (50 ms; over 15 seeds the largest error was 7), well inside the
    ±32 samples the pipeline's model-fitted release searches; a held segment taken for the
    release was 20–100 samples early (sample 0 where the first samples crossed it)."""
    from phoid.fits import detect_release

    worst = 0.0
    for rho in (0.9, 0.95):
        rng = np.random.default_rng(21)
        for p, d in zip(P, D, strict=True):
            t, x = _ring(p, d)
            worst = max(worst, abs(detect_release(t, x + _ar1(rng, t.size, rho)) - T_REL))
    assert worst <= 10 / FS


@pytest.mark.parametrize("rho", [0.9, 0.95])
def test_strongly_coloured_noise_identified_with_warning(rho: float) -> None:
    """AR(1) noise with ρ = 0.9 and 0.95 (slower than the ρ = 0.8 above): every replica is
    identified (none fails at the start), each with an adequacy warning and the robust
    stderr, the coloured-noise warning in most, and m, c, k of the formula within 3 robust
    stderr in every replica (3 stderr: the 99.7 % band; the same sets over 40 seeds per ρ and
    sd 1e-5 or 1e-4 m gave 120 of 120 estimates covered, the coloured-noise cause named in 32
    to 37 of 40, none refused)."""
    coloured = 0
    for seed in range(6):
        res = _identify(np.random.default_rng(300 + seed), rho=rho)
        assert res.adequacy.stderr == "robust"
        assert res.warnings
        coloured += any("not white noise" in w for w in res.warnings)
        for est, truth in ((res.m, M), (res.c, C), (res.k, K)):
            assert abs(est.value - truth) < 3 * est.stderr, (seed, est, truth)
    assert coloured >= 4
