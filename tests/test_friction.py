"""friction: m, c, k and the Coulomb friction force f_c by the full-record fit (issue 6).

Where the expected values come from
-----------------------------------
- Truth: the plant handed to ``phoid.simulate``, whose stick–slip integration is exact up to
  the event interpolation (≈ 1e−7·x₀) and whose loop is checked against jitcdde in
  test_simulate.py. Records carry seeded ``np.random.default_rng`` noise, quantisation and a
  sensor offset, as the issue asks.
- Gains: D solved so that the loop's dominant root has a chosen decay rate σ
  (``phoid.dynamics.dominant_roots``), then checked independently by the certified root finder
  ``characteristic_roots``: the loop rings (complex dominant pair) and is stable (or, for the
  negative-damping runs, unstable with that σ < 0).
- Bounded or growing: with negative viscous damping c_eff = 2mσ < 0, friction removes 4f_cA per
  cycle and the damping feeds π|c_eff|ωA², so records released below A* = 4f_c/(π|c_eff|ω)
  decay (the seed's "bullet-shaped" envelope) and those above grow without bound (energy
  balance of the half-cycle motion; for the runs below A* ≈ 7.6 mm).
- Stick times: the simulator's exact velocity (its last non-zero sample).
- "Within 3 stderr": the spec's promise (|error| < 3·stderr in ≥ 99 % of experiments), checked
  on seeded sets; the calibration itself by a small Monte Carlo here and a larger one in
  bench/bench_friction.py (30 replicas of the acceptance set: sd of z 0.8–1.1 for all four).
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from scipy.optimize import brentq

from phoid import (
    DelayedPD,
    Plant,
    characteristic_roots,
    identify_data,
    read_experiment,
    simulate,
)
from phoid.dynamics.rightmost import dominant_roots
from phoid.errors import ExperimentError, IdentificationError
from phoid.methods.friction import FrictionFit, friction_evidence, identify_friction

M, C, K, FC = 1.0, 2.0, 100.0, 0.05  # the plant: kg, N s/m, N/m, N
DELAY = 0.02  # s
NOISE = 10e-6  # m
QUANTUM = 1e-6  # m
OFFSET = 3e-4  # m
HOLD = 0.2  # s
FS = 1000.0  # Hz
TRUE = {"m": M, "c": C, "k": K, "fc": FC}


def gains_for(P, sigmas) -> np.ndarray:
    """D such that each loop's dominant root has decay rate σ (1/s), checked independently."""

    def sigma(p, d):
        return -dominant_roots(M, C, K, np.array([p]), np.array([d]), DELAY)[0].real

    D = np.array([brentq(lambda d, p=p, s=s: sigma(p, d) - s, -5.0, 10.0)
                  for p, s in zip(P, sigmas, strict=True)])
    plant = Plant(M, C, K)
    for p, d, s in zip(P, D, sigmas, strict=True):
        r = characteristic_roots(plant, DelayedPD(float(p), float(d), DELAY), count=2)[0]
        assert r.imag > 0, "the loop must ring"
        assert math.isclose(-r.real, s, rel_tol=1e-6, abs_tol=1e-9), "σ as designed"
    return D


def simulate_set(P, D, x0, *, fc=FC, duration=10.0, seed=1):
    sim = simulate(Plant(M, C, K, fc), P, D, delay=DELAY, duration=duration, fs=FS, x0=x0,
                   hold=HOLD, noise=NOISE, quantum=QUANTUM, offset=OFFSET,
                   rng=np.random.default_rng(seed))
    return sim, [(sim.t, x) for x in sim.x]


def true_stick_time(sim, i) -> float:
    """Last instant at which run i still moves (exact velocity of the simulator)."""
    moving = np.flatnonzero(sim.v[i] != 0.0)
    return float(sim.t[moving[-1]])


def z_scores(fit: FrictionFit) -> dict[str, float]:
    return {n: (getattr(fit, n).value - TRUE[n]) / getattr(fit, n).stderr for n in TRUE}


# --------------------------------------------------------------------------------------------
# the acceptance set

P_ACC = np.linspace(0.0, 200.0, 10)
SIGMA_ACC = np.linspace(0.15, 0.6, 10)  # lightly damped, stable: the loops ring


@pytest.fixture(scope="module")
def acceptance():
    D = gains_for(P_ACC, SIGMA_ACC)
    x0 = np.random.default_rng(7).uniform(5e-3, 10e-3, P_ACC.size)
    sim, data = simulate_set(P_ACC, D, x0, seed=11)
    fit = identify_friction(data, P_ACC, D, DELAY)
    return {"sim": sim, "data": data, "D": D, "x0": x0, "fit": fit}


def test_acceptance_within_3_stderr_and_c_within_2_percent(acceptance):
    fit = acceptance["fit"]
    assert fit.converged
    for name, z in z_scores(fit).items():
        assert abs(z) < 3.0, f"{name}: {getattr(fit, name)} vs {TRUE[name]} (z = {z:.2f})"
    assert abs(fit.c.value - C) < 0.02 * C
    # χ²/dof ≈ 1: each run is weighted by its noise sd estimated from ~200 held samples
    # (±5 %, so its (s/ŝ)² is ±10 %); the mean over 10 runs is within ±0.032 (1 sd): 0.15 is
    # more than 4 sd
    assert abs(fit.chi2_red - 1.0) < 0.15
    assert all(r.used for r in fit.runs)
    # the nuisances. The held segment alone fixes x₀ + b to NOISE/√200 ≈ 0.7 µm and the
    # oscillation's centre fixes b about as well: 5 µm is ~7 of those. The release time is a
    # continuous parameter pinned by the departure from rest: a tenth of a sample (the
    # data-only detection, decay.detect_release, is off by samples)
    for r, x0 in zip(fit.runs, acceptance["x0"], strict=True):
        assert abs(r.x0 - x0) < 5e-6
        assert abs(r.offset - OFFSET) < 5e-6
        assert abs(r.release - HOLD) < 0.1 / FS


def test_viscous_fit_is_biased_far_beyond_its_stderr(acceptance):
    """identify_data (dominant-mode, no friction) takes the friction loss for damping.

    On this set: viscous c = 3.41 ± 0.08 N s/m (+71 %, 18 stderr; m 0.9998 ± 0.013 kg, k 98.2 ±
    2.6 N/m), the friction fit c = 1.99988 ± 0.00015 N s/m (f_c 0.050008 ± 0.000006 N). Over 40
    replicas (bench/bench_friction.py) the viscous c is 3.47 ± 0.08, median 19 stderr off."""
    fit = acceptance["fit"]
    visc = identify_data(acceptance["data"], P_ACC, acceptance["D"], DELAY)
    err_visc = visc.c.value - C
    assert err_visc > 0.25 * C  # more than 12 times the 2 % the friction fit must meet
    assert err_visc > 10.0 * visc.c.stderr  # a bias, not noise
    assert abs(fit.c.value - C) < 0.01 * abs(err_visc)  # the friction fit: < 1 % of that


def test_sticking_is_detected_and_timed(acceptance):
    fit, sim = acceptance["fit"], acceptance["sim"]
    for i, r in enumerate(fit.runs):
        t_true = true_stick_time(sim, i)
        assert t_true < sim.t[-1] - 1.0, "the design sticks well before the record ends"
        assert r.stick_time is not None
        # the fitted trajectory stops within 2 samples of the true one (sampled truth, and
        # the fit's stop extrapolated within a step)
        assert abs(r.stick_time - t_true) < 2.0 / FS
        assert r.reversals >= 4
        assert any("sticks" in w for w in r.warnings)
    assert fit.stick_times == tuple(r.stick_time for r in fit.runs)


def test_summary_is_json_with_fc(acceptance):
    out = json.loads(json.dumps(acceptance["fit"].summary(), allow_nan=False))
    assert set(out) == {"method", "m", "c", "k", "fc", "delay", "runs", "warnings",
                        "covariance", "correlation", "statistics", "adequacy", "x_unit"}
    for key, unit in (("m", "kg"), ("c", "N s/m"), ("k", "N/m"), ("fc", "N")):
        assert out[key]["unit"] == unit
        assert out[key]["stderr"] > 0
    assert len(out["runs"]) == P_ACC.size
    assert out["runs"][0]["stick_time"] > HOLD


def test_friction_evidence_detects_friction(acceptance):
    ev = friction_evidence(acceptance["data"], P_ACC, acceptance["D"], DELAY)
    assert ev.detected
    assert ev.z > 10.0
    assert ev.chi2_red > 10.0  # the viscous model cannot fit these records
    assert any("friction detected" in w for w in ev.warnings)


# --------------------------------------------------------------------------------------------
# no friction: nothing detected, nothing invented

P_FREE = np.array([0.0, 60.0, 130.0, 200.0])
SIGMA_FREE = np.array([0.6, 0.8, 1.0, 1.2])


@pytest.fixture(scope="module")
def friction_free():
    D = gains_for(P_FREE, SIGMA_FREE)
    _sim, data = simulate_set(P_FREE, D, np.full(P_FREE.size, 8e-3), fc=0.0, duration=4.0,
                              seed=3)
    return data, D


def test_no_friction_is_not_detected(friction_free):
    data, D = friction_free
    ev = friction_evidence(data, P_FREE, D, DELAY)
    assert not ev.detected  # z is standard normal here: P(z > 3.09) = 0.1 %
    assert abs(ev.z) < 4.0
    # the viscous full-record fit is then the right model: within 3 stderr
    for name in ("m", "c", "k"):
        est = getattr(ev, name)
        assert abs(est.value - TRUE[name]) < 3.0 * est.stderr, name


def test_evidence_on_the_independent_sample_set(sample_set_path, truth):
    """The paper-sample set (examples/, made by jitcdde, not by phoid; no friction): nothing is
    detected, and the viscous full-record fit behind the test finds m, c, k within 3 stderr,
    with stderr at the set's Cramér–Rao bound (truth.json: 0.9–1.5 × crb_sd; the fit uses
    the residual variance and more nuisances than the bound's model)."""
    ex = read_experiment(sample_set_path)
    runs = list(ex.runs)
    ev = friction_evidence([(r.t, r.x) for r in runs], [r.P for r in runs],
                           [r.D for r in runs], ex.delay)
    assert truth["fc"] == 0.0
    assert not ev.detected
    for name in ("m", "c", "k"):
        est = getattr(ev, name)
        assert abs(est.value - truth[name]) < 3.0 * est.stderr, name
        assert 0.9 < est.stderr / truth["crb_sd"][name] < 1.5, name


def test_friction_fit_without_friction_gives_fc_near_zero(friction_free):
    data, D = friction_free
    fit = identify_friction(data, P_FREE, D, DELAY)
    assert fit.fc.value >= 0.0
    assert fit.fc.value < 3.0 * fit.fc.stderr  # consistent with f_c = 0 (at or near its bound)
    for name in ("m", "c", "k"):
        est = getattr(fit, name)
        assert abs(est.value - TRUE[name]) < 3.0 * est.stderr, name


# --------------------------------------------------------------------------------------------
# negative damping, growing records, friction that stops the motion, no motion

SIGMA_NEG = -0.3  # 1/s: c_eff = −0.6 N s/m; at P = 100, ω ≈ 13.9 rad/s, A* ≈ 7.6 mm


@pytest.fixture(scope="module")
def hard_set():
    P = np.array([0.0, 50.0, 100.0, 150.0, 200.0, 100.0, 100.0, 0.0, 0.0])
    sig = np.array([0.2, 0.3, 0.4, 0.5, 0.6, SIGMA_NEG, SIGMA_NEG, 0.2, 0.2])
    D = gains_for(P, sig)
    x0 = np.array([8e-3, 6e-3, 9e-3, 7e-3, 10e-3,
                   5e-3,  # below A*: bounded, bullet-shaped
                   14e-3,  # above A*: grows without bound
                   1.5e-3,  # 3 dead bands (f_c/k = 0.5 mm): stops within a cycle
                   0.3e-3])  # inside the dead band: never moves
    sim, data = simulate_set(P, D, x0, duration=8.0, seed=5)
    names = ["n1", "n2", "n3", "n4", "n5", "bullet", "growing", "short", "still"]
    fit = identify_friction(data, P, D, DELAY, names=names)
    return {"sim": sim, "fit": fit, "P": P, "D": D, "x0": x0}


def test_negative_damping_design(hard_set):
    """The designed records behave as the energy balance says (independent of the fit)."""
    sim = hard_set["sim"]
    post = sim.t > HOLD
    bullet, growing = sim.x_true[5, post], sim.x_true[6, post]
    q = bullet.size // 4
    assert np.max(np.abs(bullet[-q:])) < 0.1 * np.max(np.abs(bullet[:q]))  # decays, stops
    assert np.max(np.abs(growing[-q:])) > 3.0 * np.max(np.abs(growing[:q]))  # grows
    assert np.all(sim.v[8] == 0.0)  # inside the dead band the mass never moves


def test_bounded_negative_damping_run_is_used(hard_set):
    fit = hard_set["fit"]
    run = fit.runs[5]
    assert run.used
    assert run.sigma < 0  # the fitted loop is negatively damped …
    # … as designed: σ from the fitted plant's loop root (m, c, k within ~1e−3 relative: its
    # error ≪ 0.05 1/s)
    assert abs(run.sigma - SIGMA_NEG) < 0.05
    assert any("negatively damped" in w for w in run.warnings)
    assert run.stick_time is not None  # … yet friction stops it
    assert abs(run.stick_time - true_stick_time(hard_set["sim"], 5)) < 2.0 / FS


def test_growing_run_is_set_aside(hard_set):
    run = hard_set["fit"].runs[6]
    assert not run.used
    assert any("grows" in w for w in run.warnings)
    assert any(w.startswith("growing: set aside") and "grows" in w
               for w in hard_set["fit"].warnings)


def test_run_stopped_within_a_cycle_is_set_aside(hard_set):
    fit = hard_set["fit"]
    short, still = fit.runs[7], fit.runs[8]
    assert not short.used
    assert any("within a cycle" in w for w in short.warnings)
    assert not still.used
    assert any("no motion" in w for w in still.warnings)


def test_hard_set_estimates_within_3_stderr(hard_set):
    fit = hard_set["fit"]
    assert [r.used for r in fit.runs] == [True] * 6 + [False] * 3
    for name, z in z_scores(fit).items():
        assert abs(z) < 3.0, f"{name}: z = {z:.2f}"


def test_no_run_left_is_an_error():
    P = np.array([0.0, 0.0])
    D = gains_for(P, [0.2, 0.2])
    _sim, data = simulate_set(P, D, np.array([1.5e-3, 1.2e-3]), duration=2.0, seed=9)
    with pytest.raises(IdentificationError, match="within a cycle"):
        identify_friction(data, P, D, DELAY, start=(M, C, K, FC))
    Pn = np.array([100.0, 100.0])
    Dn = gains_for(Pn, [SIGMA_NEG, SIGMA_NEG])
    _sim, grow = simulate_set(Pn, Dn, np.array([14e-3, 16e-3]), duration=4.0, seed=9)
    with pytest.raises(IdentificationError, match=r"no usable runs.*grows"):
        identify_friction(grow, Pn, Dn, DELAY)


# --------------------------------------------------------------------------------------------
# stderr calibration: a small Monte Carlo (the larger one is bench/bench_friction.py)


def test_stderr_calibration_small_monte_carlo():
    """20 replicas of a 3-run set (P = 0, 100, 200; released at 5–10 mm, 4 s records).

    A calibrated stderr gives z = (estimate − truth)/stderr ~ N(0, 1). Checked: every |z| < 4
    (P(any of the 80 beyond 4) ≈ 0.5 %), and for each of m, c, k, f_c the rms of its 20 z in
    [0.48, 1.6] (the χ²₂₀ interval holding it with probability 1 − 2.5e−4, Bonferroni over the
    four: 1e−3 in all). This catches a stderr off by a factor 1.6 or more; the finer check is
    bench/bench_friction.py. Replica 1 is the set that ends in a false optimum without stage 1
    (docs/design-notes/friction.md): there z_c was −29."""
    P = np.array([0.0, 100.0, 200.0])
    D = gains_for(P, [0.2, 0.4, 0.6])
    zs = []
    for rep in range(20):
        x0 = np.random.default_rng(100 + rep).uniform(5e-3, 10e-3, P.size)
        _sim, data = simulate_set(P, D, x0, duration=4.0, seed=200 + rep)
        fit = identify_friction(data, P, D, DELAY)
        assert fit.converged
        zs.append(list(z_scores(fit).values()))
    zs = np.array(zs)
    assert np.all(np.abs(zs) < 4.0), zs
    rms = np.sqrt(np.mean(zs**2, axis=0))
    assert np.all((rms > 0.48) & (rms < 1.6)), dict(zip(TRUE, rms, strict=True))


# --------------------------------------------------------------------------------------------
# bad input: one clear line naming run and field


def _tiny():
    t = np.arange(100) / FS
    return [(t, np.sin(30 * t)), (t, np.cos(30 * t))]


def test_bad_input_messages():
    data = _tiny()
    P, D = np.array([1.0, 2.0]), np.array([0.0, 0.0])
    with pytest.raises(ExperimentError, match=r"run2: `t` and `x` must be 1-D arrays of equal"):
        identify_friction([data[0], (data[1][0], data[1][1][:-1])], P, D, DELAY)
    bad = data[1][1].copy()
    bad[17] = np.nan
    with pytest.raises(ExperimentError, match=r"run2: `x` must be finite; got nan at row 17"):
        identify_friction([data[0], (data[1][0], bad)], P, D, DELAY)
    with pytest.raises(ExperimentError, match=r"`P` must have one entry per run \(2\); got 3"):
        identify_friction(data, [1.0, 2.0, 3.0], D, DELAY)
    with pytest.raises(ExperimentError, match=r"`delay` must be finite and ≥ 0 s"):
        identify_friction(data, P, D, -1.0)
    with pytest.raises(ExperimentError, match=r"`start` must be"):
        identify_friction(data, P, D, DELAY, start=(1.0, 2.0))
    t_bad = data[0][0].copy()
    t_bad[5] = t_bad[4]
    with pytest.raises(ExperimentError, match=r"a: `t` must be strictly increasing"):
        identify_friction([(t_bad, data[0][1]), data[1]], P, D, DELAY, names=["a", "b"])
    with pytest.raises(ValueError, match="alpha"):
        friction_evidence(data, P, D, DELAY, alpha=2.0)


# --------------------------------------------------------------------------------------------
# the command line: phoid identify --friction on a set written by phoid simulate --fc


def test_cli_identify_friction(tmp_path):
    from typer.testing import CliRunner

    from phoid.cli import app

    runner = CliRunner()
    out = tmp_path / "fr"
    r = runner.invoke(app, ["simulate", str(out), "--m", "1", "--c", "2", "--k", "100",
                            "--fc", "0.05", "--P", "0:150:5", "--D", "0.5:3:5", "--delay",
                            "0.02", "--duration", "6", "--noise", "1e-5", "--quantum", "1e-6",
                            "--x0", "0.008", "--seed", "3"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["identify", str(out), "--friction", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    # the spec's keys, plus fc in the same shape; runs with the spec's run keys
    assert {"method", "m", "c", "k", "fc", "delay", "runs", "warnings", "covariance",
            "correlation", "statistics", "adequacy", "x_unit"} == set(s)
    assert {"file", "P", "D", "sigma", "omega_d", "c_prime", "k_prime", "cycles"} <= set(
        s["runs"][0])
    for q, v in (("m", 1.0), ("c", 2.0), ("k", 100.0), ("fc", 0.05)):
        assert s[q]["unit"] and abs(s[q]["value"] - v) < 3 * s[q]["stderr"], (q, s[q])
    # the viscous identification of the same set is far off and says to fit friction
    r = runner.invoke(app, ["identify", str(out), "--json"])
    v = json.loads(r.stdout)
    assert abs(v["c"]["value"] - 2.0) > 0.2
    assert any("--friction" in w for w in v["warnings"])
    # options the friction fit does not take: one line, exit 2
    for extra in (["--estimator", "ols"], ["--estimator", "ols", "--no-compensation"]):
        r = runner.invoke(app, ["identify", str(out), "--friction", *extra])
        # the registry's one line names the option the friction fit refuses and the method
        assert r.exit_code == 2 and "--friction" in r.stderr and "pho sets" in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    manifest = out / "experiment.toml"
    text = manifest.read_text()
    loop = re.search(r"(?ms)^\[loop\]\n.*?\n\n", text)  # the whole table (delay, noise)
    assert loop is not None and "delay = 0.02" in loop.group(0)
    manifest.write_text(text.replace(loop.group(0), ""))
    r = runner.invoke(app, ["identify", str(out), "--friction"])
    assert r.exit_code == 2 and "needs the loop" in r.stderr and len(r.stderr.splitlines()) == 1


# --------------------------------------------------------------------------------------------
# added masses (the paper's added-mass trick) with friction


def test_added_mass_with_friction(tmp_path):
    # the plant with friction, six gain pairs each recorded bare and with 0.5 kg added
    # (phoid's simulator, plants m and m + 0.5). Expected: the simulation's bare plant and f_c
    # within 3 stderr, through the files, the manifest's added_mass and the CLI; the added
    # masses in the JSON's runs. Ignoring them, m is far off (the loaded runs ring slower)
    from typer.testing import CliRunner

    from phoid import read_experiment, run_from_arrays, write_experiment
    from phoid.cli import app

    P6 = np.linspace(20.0, 200.0, 6)
    D6 = gains_for(P6, np.linspace(0.2, 0.6, 6))
    x0 = 8e-3
    runs = []
    rng = np.random.default_rng(21)
    for added in (0.0, 0.5):
        sim = simulate(Plant(M + added, C, K, FC), P6, D6, delay=DELAY, duration=6.0, fs=FS,
                       x0=x0, hold=HOLD, noise=NOISE, quantum=QUANTUM, offset=OFFSET, rng=rng)
        for i in range(P6.size):
            runs.append(run_from_arrays(sim.t, sim.x[i], P=float(P6[i]), D=float(D6[i]),
                                        added_mass=added, index=len(runs) + 1))
    path = write_experiment(tmp_path / "fam", runs, method="pho", delay=DELAY)
    exp = read_experiment(path)
    data = [(r.t, r.x) for r in exp.runs]
    P12, D12 = np.tile(P6, 2), np.tile(D6, 2)
    dm = np.repeat([0.0, 0.5], 6)
    fit = identify_friction(data, P12, D12, DELAY, added_mass=dm)
    for name, z in z_scores(fit).items():
        assert abs(z) < 3.0, f"{name}: {getattr(fit, name)} vs {TRUE[name]} (z = {z:.2f})"
    assert [r.added_mass for r in fit.runs] == dm.tolist()
    out = CliRunner().invoke(app, ["identify", str(path), "--friction", "--json"])
    assert out.exit_code == 0, out.output
    s = json.loads(out.stdout)
    assert [r.get("added_mass", 0.0) for r in s["runs"]] == dm.tolist()
    for q in ("m", "c", "k", "fc"):
        assert abs(s[q]["value"] - TRUE[q]) < 3 * s[q]["stderr"], (q, s[q])
    # the known part taken off c′ and k′: every run on the bare plant's eq. (35) lines
    # (noise-level scatter: within 1 % of k's and 10 % of c's scale)
    for r in s["runs"]:
        assert abs(r["k_prime"] - (M * (r["sigma"] ** 2 + r["omega_d"] ** 2) - K)) < 1.0
        assert abs(r["c_prime"] - (2 * M * r["sigma"] - C)) < 0.2
    ignored = identify_friction(data, P12, D12, DELAY)
    assert abs(ignored.m.value - M) > 10 * fit.m.stderr
    with pytest.raises(ExperimentError, match=r"run3: `added_mass` must be ≥ 0 kg"):
        identify_friction(data, P12, D12, DELAY, added_mass=np.where(np.arange(12) == 2,
                                                                     -1.0, 0.0))


# --------------------------------------------------------------------------------------------
# a sampled (digital) controller with friction


def test_digital_loop_with_friction(tmp_path):
    # the plant with friction under a sampled PD loop (T_s = 2 ms, backward-difference
    # velocity, 3-sample command delay: tests/test_digital_identify.py's controller), eight
    # runs with D chosen so that the sampled loop's dominant root decays at σ = 0.2 … 0.6 1/s
    # (exact roots of phoid.dynamics.digital, brentq). Expected: the simulation's plant and f_c
    # within
    # 3 stderr (phoid's sampled-loop simulator with exact stick–slip, checked in
    # test_digital.py), through the manifest's [loop] keys and the CLI; the viscous fit of the
    # same records takes the friction for damping (measured: c 3.40 for 2)
    from typer.testing import CliRunner

    from phoid import read_experiment, run_from_arrays, write_experiment
    from phoid.api import identify_data
    from phoid.cli import app
    from phoid.dynamics.digital import DigitalPD, digital_roots

    loop = DigitalPD(0.0, 0.0, sample_time=0.002, delay_samples=3)

    def sigma(p, d):
        return -digital_roots(M, C, K, np.array([p]), np.array([d]), loop).dominant[0].real

    P8 = np.linspace(20.0, 200.0, 8)
    D8 = np.array([brentq(lambda d, p=p, s=s: sigma(p, d) - s, -1.9, 6.0)
                   for p, s in zip(P8, np.linspace(0.2, 0.6, 8), strict=True)])
    x0 = np.random.default_rng(1).uniform(5e-3, 10e-3, P8.size)
    sim = simulate(Plant(M, C, K, FC), P8, D8, duration=8.0, fs=FS, x0=x0, hold=HOLD,
                   noise=NOISE, quantum=QUANTUM, offset=OFFSET, rng=np.random.default_rng(101),
                   sample_time=0.002, delay_samples=3, noise_in_loop=False)
    runs = [run_from_arrays(sim.t, sim.x[i], P=float(P8[i]), D=float(D8[i]), index=i + 1)
            for i in range(P8.size)]
    folder = tmp_path / "dfr"
    path = write_experiment(folder, runs, method="pho",
                            loop={"sample_time": 0.002, "delay_samples": 3})
    out = CliRunner().invoke(app, ["identify", str(folder), "--friction", "--json"])
    assert out.exit_code == 0, out.output
    s = json.loads(out.stdout)
    assert s["loop"]["model"] == "digital" and s["delay"]["value"] == pytest.approx(0.006)
    for q in ("m", "c", "k", "fc"):
        assert abs(s[q]["value"] - TRUE[q]) < 3 * s[q]["stderr"], (q, s[q])
    assert abs(s["c"]["value"] - C) < 0.02 * C
    text = CliRunner().invoke(app, ["identify", str(folder), "--friction"])
    assert text.exit_code == 0 and "digital loop (exact sampled model)" in text.stdout
    data = [(r.t, r.x) for r in read_experiment(path).runs]
    viscous = identify_data(data, P8, D8, None, digital=loop)
    assert viscous.c.value - C > 0.3 * C
    # a digital loop takes its delay in samples: a delay as well is refused
    with pytest.raises(ExperimentError, match="`delay` must be None with a digital loop"):
        identify_friction(data, P8, D8, 0.006, digital=loop)
    manifest = folder / "experiment.toml"
    assert "[loop]\n" in manifest.read_text()
    manifest.write_text(manifest.read_text().replace("[loop]\n", "[loop]\ndelay = 0.006\n"))
    out = CliRunner().invoke(app, ["identify", str(folder), "--friction"])
    assert out.exit_code == 2 and "give one or the other" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
