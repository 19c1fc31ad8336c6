"""`phoid identify` on the hard cases of issue 3, one test (or two) per case.

Fixtures are simulated in memory by ``phoid.simulate`` (the exact-step DDE solver, itself checked
against jitcdde in test_simulate.py) — or, for one noise-free test, by jitcdde — with seeded
``np.random.default_rng`` noise, and written with ``phoid.write_experiment`` where the command
line or the file names matter.

Where the expected values come from
-----------------------------------
- Truth: the plant handed to the simulator.
- Gains: solved so that the loop's rightmost root is a chosen target s = −σ + iω_d
  (``gains_for``), then *checked* independently (``assert_rings``): ``forward_map`` (certified
  root finder) returns the target as the dominant root, and ``characteristic_roots`` shows the
  whole loop stable and the dominant pair complex (the loop rings).
- "Within 3 stderr": the spec's promise — |estimate − truth| < 3·stderr in ≥ 99 % of repeated
  experiments — checked on one seeded set (a calibrated estimator misses it 0.3 % of the time).
- Stderr sanity: every stderr is compared with the Cramér–Rao bound of the full simulated model
  (``crb_sd``: derivatives of phoid.simulate's exact records by finite differences, white noise of
  the sd used, an offset and a scale per run as nuisance). No unbiased estimator of m, c, k from
  these records can do better, and the pipeline has more nuisance parameters (amplitude, phase,
  fast-mode amplitudes per run), so its stderr must not fall below the bound (0.9×: the stderr
  uses the residual variance, not the true one); more than 2× the bound would mean the pipeline
  throws away three quarters of the information (issue 3 asks for ≤ 1.5× the dominant-mode
  bound, which is
  itself above this one). The file's runs see 1.1–1.5×.
- JSON: every result's ``summary()`` goes through ``json.dumps(..., allow_nan=False)`` and the
  spec's shape check (``assert_spec_json``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid import (
    DelayedPD,
    IdentificationError,
    Plant,
    characteristic_roots,
    detect_release,
    forward_map,
    identify,
    identify_data,
    read_experiment,
    run_from_arrays,
    simulate,
    write_experiment,
)
from phoid.cli import app
from phoid.methods.pho_measure import measure_modes

runner = CliRunner()

X0 = 5e-3  # m, release displacement
NOISE = 10e-6  # m, white sensor noise sd (the brief's "10 µm on a 5 mm release")
HOLD = 0.1  # s, held segment before the release (controller on), as on a real rig


# --------------------------------------------------------------------------------------------
# helpers


def gains_for(plant: Plant, delay: float, sigma: float, omega_d: float) -> tuple[float, float]:
    """(P, D) that put a root of m s² + c s + k + (D s + P)e^{−sΔt} at s = −σ + iω_d (eq. 23).

    D s + P = −(m s² + c s + k)e^{sΔt} =: Z, with real P, D: D = Im Z/ω_d, P = Re Z + σD.
    Whether that root is the *dominant* one is checked separately (``assert_rings``).
    """
    s = complex(-sigma, omega_d)
    z = -(plant.m * s * s + plant.c * s + plant.k) * np.exp(s * delay)
    D = z.imag / omega_d
    return float(z.real + sigma * D), float(D)


@dataclass(frozen=True)
class Design:
    """A PHO experiment design: plant, delay, and groups of runs (fs Hz, duration s, targets)."""

    plant: Plant
    delay: float
    groups: tuple[tuple[float, float, tuple[tuple[float, float], ...]], ...]

    @property
    def targets(self) -> list[tuple[float, float]]:
        return [tg for _, _, tgs in self.groups for tg in tgs]

    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        pd = np.array([gains_for(self.plant, self.delay, s, w) for s, w in self.targets])
        return pd[:, 0], pd[:, 1]

    def simulate(self, *, noise=0.0, seed=None, x0=X0, hold=HOLD, offset=0.0):
        """[(t, x)] for every run (group order), the gains P, D, and the exact records."""
        rng = np.random.default_rng(seed) if noise > 0 else None
        data, exact, P, D = [], [], [], []
        for fs, duration, targets in self.groups:
            g = np.array([gains_for(self.plant, self.delay, s, w) for s, w in targets])
            sim = simulate(self.plant, g[:, 0], g[:, 1], delay=self.delay, duration=duration,
                           fs=fs, x0=x0, hold=hold, noise=noise, offset=offset, rng=rng)
            for i in range(len(targets)):
                data.append((sim.t, sim.x[i]))
                exact.append(sim.x_true[i])
            P.extend(g[:, 0])
            D.extend(g[:, 1])
        return data, np.array(P), np.array(D), exact

    def crb_sd(self, noise: float, *, x0=X0, hold=HOLD) -> np.ndarray:
        """Cramér–Rao sd of (m, c, k) for white noise of sd ``noise`` on every sample.

        Model: each run's exact record from phoid.simulate, with an unknown offset and scale per
        run (nuisance, profiled out by a Schur complement); derivatives by central differences
        with steps of 1e−6 of each parameter's scale (forward where the parameter is 0: k = 0).
        The simulator's error (~1e−11·x₀) makes these derivatives good to ~1e−5.
        """
        m, c, k = self.plant.m, self.plant.c, self.plant.k
        P, _ = self.gains()
        theta = np.array([m, c, k])
        h = 1e-6 * np.array([m, max(c, 2 * m), max(k, float(np.max(np.abs(P))))])
        info = np.zeros((3, 3))
        for fs, duration, targets in self.groups:
            g = np.array([gains_for(self.plant, self.delay, s, w) for s, w in targets])

            def rec(th, g=g, fs=fs, duration=duration):
                return simulate(Plant(*th), g[:, 0], g[:, 1], delay=self.delay,
                                duration=duration, fs=fs, x0=x0, hold=hold).x_true

            base = rec(theta)
            der = []
            for j in range(3):
                up, dn = theta.copy(), theta.copy()
                up[j] += h[j]
                dn[j] -= h[j]
                if dn[j] < 0:
                    dn[j] = theta[j]
                der.append((rec(up) - rec(dn)) / (up[j] - dn[j]))
            der = np.array(der)  # (3, runs, samples)
            for i in range(base.shape[0]):
                A = der[:, i]
                U = np.stack([np.ones(base.shape[1]), base[i] / x0])
                cross = A @ U.T
                info += A @ A.T - cross @ np.linalg.solve(U @ U.T, cross.T)
        return noise * np.sqrt(np.diag(np.linalg.inv(info)))


def assert_rings(design: Design) -> None:
    """Every loop of the design is stable, rings (complex dominant pair) at its target."""
    P, D = design.gains()
    modes = forward_map(design.plant, P, D, design.delay)  # certified dominant roots
    sig, wd = np.array(design.targets).T
    np.testing.assert_allclose(modes.sigma, sig, rtol=1e-9)
    np.testing.assert_allclose(modes.omega_d, wd, rtol=1e-9)
    for p, d in zip(P, D, strict=True):
        roots = characteristic_roots(design.plant, DelayedPD(p, d, design.delay), count=4)
        assert roots[0].real < 0 and roots[0].imag > 0  # stable, underdamped dominant pair
        assert roots[2].real < roots[0].real  # the next mode is a different, faster one


def zscores(res, plant: Plant) -> dict[str, float]:
    return {q: (getattr(res, q).value - getattr(plant, q)) / getattr(res, q).stderr
            for q in "mck"}


def assert_honest(res, plant: Plant, crb: np.ndarray | None = None, label: str = "") -> None:
    """m, c, k within 3 stderr of the truth; stderr finite, positive and near the CRB."""
    ratios = []
    for j, q in enumerate("mck"):
        est = getattr(res, q)
        assert est.stderr is not None and math.isfinite(est.stderr) and est.stderr > 0, q
        assert abs(est.value - getattr(plant, q)) < 3 * est.stderr, (q, est, zscores(res, plant))
        if crb is not None:
            ratios.append(est.stderr / crb[j])
    if crb is not None:
        assert all(0.9 <= r <= 2.0 for r in ratios), (label, ratios)
    z = zscores(res, plant)
    print(f"\n{label}: z = " + ", ".join(f"{q} {z[q]:+.2f}" for q in "mck")
          + ("; stderr/CRB = " + ", ".join(f"{r:.2f}" for r in ratios) if ratios else ""))


SPEC_RUN_KEYS = {"file", "P", "D", "sigma", "omega_d", "c_prime", "k_prime", "cycles"}
UNITS = {"m": "kg", "c": "N s/m", "k": "N/m"}
# top-level keys beyond the spec's that summary() writes today (zeta/omega0: the spec's optional
# {value, stderr, unit}; covariance/correlation/statistics: the fit statistics of
# docs/format-extensions.md) — a new key must be added knowingly
EXTRA_KEYS = {"zeta", "omega0", "covariance", "correlation", "statistics", "adequacy", "x_unit",
              "noise_placement", "noise_placement_source", "noise_placement_test"}


def assert_spec_json(res, n_runs: int, set_aside: tuple[int, ...] = ()) -> dict:
    """summary() is the spec's JSON: strict JSON (no NaN), the spec's keys and shapes, every
    run listed in order with ``used`` false exactly for the set-aside ones."""
    s = res.summary()
    text = json.dumps(s, allow_nan=False)  # raises on NaN/inf anywhere
    s = json.loads(text)
    assert s["method"] == "pho"
    for q, unit in UNITS.items():
        assert set(s[q]) == {"value", "stderr", "unit"} and s[q]["unit"] == unit
        assert isinstance(s[q]["value"], float) and isinstance(s[q]["stderr"], float)
    # the spec's four keys, plus the optional "from" ("x" or "x+u") of an estimated delay
    assert set(s["delay"]) - {"from"} == {"value", "stderr", "unit", "source"}
    assert s["delay"].get("from", "x") in ("x", "x+u")
    assert ("from" in s["delay"]) == (s["delay"]["source"] == "estimated")
    assert s["delay"]["unit"] == "s" and s["delay"]["source"] in ("given", "estimated")
    assert isinstance(s["warnings"], list) and all(isinstance(w, str) for w in s["warnings"])
    assert set(s) - {"method", "m", "c", "k", "delay", "runs", "warnings"} <= EXTRA_KEYS
    for q in ("zeta", "omega0"):
        if q in s:
            assert set(s[q]) == {"value", "stderr", "unit"}
    assert len(s["runs"]) == n_runs
    for i, r in enumerate(s["runs"]):
        assert set(r) >= SPEC_RUN_KEYS | {"used"}
        assert r["used"] is (i not in set_aside), (i, r)
        if r["used"]:
            assert all(isinstance(r[key], float) for key in ("sigma", "omega_d", "c_prime",
                                                                 "k_prime", "cycles"))
    return s


def strict_json(text: str):
    """json.loads that rejects NaN and ±Infinity (which json.loads accepts by default)."""

    def bad(name):
        raise AssertionError(f"non-finite number {name} in the JSON")

    return json.loads(text, parse_constant=bad)


def one_line_error(result, *needles) -> str:
    """Exit status 2, exactly one 'phoid: error:' line on stderr, nothing on stdout."""
    assert result.exit_code == 2, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phoid: error:"), result.stderr
    assert result.stdout == "" and "Traceback" not in result.output
    for n in needles:
        assert n in err[0], (n, err[0])
    return err[0]


def write_set(folder, data, P, D, delay, **kw):
    runs = [run_from_arrays(t, x, P=float(p), D=float(d), index=i + 1)
            for i, ((t, x), p, d) in enumerate(zip(data, P, D, strict=True))]
    return write_experiment(folder, runs, delay=delay, gzip=False, **kw)


# --------------------------------------------------------------------------------------------
# designs (targets σ [1/s], ω_d [rad/s] spread in σ and in ω₀² = σ² + ω_d²)

# 1. heavily overdamped plant: ζ = 40/(2√(0.5·20)) = 6.3; Δt = 5 ms; rings only with D ≈ −c
OVERDAMPED = Design(
    Plant(0.5, 40.0, 20.0), 0.005,
    ((1000.0, 10.0, ((0.3, 6.0), (0.6, 10.0), (1.0, 15.0), (1.5, 20.0), (0.5, 25.0),
                     (2.0, 30.0), (1.2, 8.0), (0.8, 18.0), (2.5, 12.0), (1.8, 35.0))),),
)
# 2. mass–damper, k = 0 (eq. 9): m = 1 kg, c = 10 N s/m, Δt = 10 ms
MASS_DAMPER = Design(
    Plant(1.0, 10.0, 0.0), 0.01,
    ((1000.0, 10.0, ((0.3, 4.0), (0.6, 7.0), (1.0, 10.0), (1.5, 14.0), (0.5, 18.0),
                     (2.0, 22.0), (1.2, 5.0), (0.8, 12.0), (2.5, 9.0), (1.8, 25.0))),),
)
# 3. runs at 500 Hz / 750 Hz / 1 kHz / 2 kHz, 5–15 s long, in one set
MIXED = Design(
    Plant(1.5, 3.0, 40.0), 0.02,
    ((500.0, 5.0, ((0.8, 6.0), (1.5, 12.0))),
     (1000.0, 15.0, ((0.3, 5.0), (0.6, 9.0), (1.0, 16.0))),
     (2000.0, 8.0, ((0.7, 20.0), (1.2, 8.0), (2.0, 14.0))),
     (750.0, 12.0, ((0.4, 11.0),))),
)
# 4. barely damped (closed-loop ζ = σ/ω₀ = 0.002: 140 and 215 cycles in 15 s) and runs that decay
#    in about two cycles (ζ ≈ 0.4: e^{−σt} reaches the noise, 10 µm of 5 mm, after ~2.3 cycles)
ZETA_LOW = 0.002
MIXED_DAMPING = Design(
    Plant(0.8, 2.0, 30.0), 0.01,
    ((1000.0, 15.0, ((ZETA_LOW * 60.0, 60.0 * math.sqrt(1 - ZETA_LOW**2)),
                     (ZETA_LOW * 90.0, 90.0 * math.sqrt(1 - ZETA_LOW**2)),
                     (0.5, 8.0), (1.0, 14.0), (0.8, 20.0),
                     (6.0, 14.0), (8.0, 18.0), (4.0, 9.0))),),
)
SHORT_RUNS = (5, 6, 7)  # indices of the two-cycle runs in MIXED_DAMPING


@pytest.mark.parametrize("design", [OVERDAMPED, MASS_DAMPER, MIXED, MIXED_DAMPING],
                         ids=["overdamped", "mass-damper", "mixed-rates", "mixed-damping"])
def test_designs_ring_stably_at_their_targets(design):
    assert_rings(design)


def test_the_overdamped_plant_does_not_ring_by_itself():
    plant = OVERDAMPED.plant
    assert plant.zeta > 6.0  # c/(2√(mk)) = 6.32 (eq. 10)
    roots = characteristic_roots(plant, DelayedPD(0.0, 0.0, OVERDAMPED.delay), count=2)
    assert np.all(roots.imag == 0)  # both roots real: no oscillation without the loop
    _, D = OVERDAMPED.gains()
    assert np.all(D < 0)  # ringing needs damping removed: D ≈ −c


# --------------------------------------------------------------------------------------------
# 1, 2. heavily overdamped plant; mass–damper


def test_heavily_overdamped_plant_through_files_and_cli(tmp_path):
    # the full path a user takes: a phoid/1 set on disk (with a sensor offset), `phoid identify
    # --json`; the JSON's numbers are the API's
    data, P, D, _ = OVERDAMPED.simulate(noise=NOISE, seed=1, offset=2e-4)
    path = write_set(tmp_path / "od", data, P, D, OVERDAMPED.delay)
    res = identify(read_experiment(path))
    assert_honest(res, OVERDAMPED.plant, OVERDAMPED.crb_sd(NOISE), "overdamped")
    assert res.warnings == ()
    s = assert_spec_json(res, 10)
    r = runner.invoke(app, ["identify", str(tmp_path / "od"), "--json"])
    assert r.exit_code == 0, r.output
    out = strict_json(r.stdout)
    for q in "mck":
        assert out[q] == s[q]
    assert out["runs"][0]["file"] == "run01.csv"


def test_release_of_a_stiff_loop_is_found_from_the_loop_model():
    # Regression: the data-only release detection (a quadratic, then an even quartic departure
    # from the held level) can be 15+ samples early on the stiff runs of this design, whose
    # departure from rest is not of that shape (strong damping, c/m = 80 1/s; the delayed
    # feedback changing it after Δt = 5 samples).
    # Held samples then entered the second pass's fit window: that run's σ came out 8 stderr off
    # and a false "runs disagree" warning inflated every stderr 2.7× (10 sets in 100). Seed 10006
    # is such a set (run 6, ω_d = 30 rad/s, detected 15 ms early: asserted, so that the fixture
    # keeps testing what it is meant to). The pipeline now fits the release time with the loop's
    # own response (identification._model_releases); half a sample (0.5 ms) is its bound here
    # (over 80 runs of this design its error has an sd of 0.05 ms).
    data, P, D, _ = OVERDAMPED.simulate(noise=NOISE, seed=10006)
    t, x = data[5]
    assert detect_release(t, x) < HOLD - 0.010
    res = identify_data(data, P, D, OVERDAMPED.delay)
    exact = forward_map(OVERDAMPED.plant, P, D, OVERDAMPED.delay)
    for r, s, w in zip(res.runs, exact.sigma, exact.omega_d, strict=True):
        assert abs(r.fit.release - HOLD) < 0.5e-3, (r.file, r.fit.release)
        assert abs(r.sigma - s) < 4 * r.sigma_stderr and abs(r.omega_d - w) < 4 * r.omega_d_stderr
    assert res.warnings == ()
    assert_honest(res, OVERDAMPED.plant, OVERDAMPED.crb_sd(NOISE), "overdamped, seed 10006")


def test_mass_damper_k0():
    data, P, D, _ = MASS_DAMPER.simulate(noise=NOISE, seed=2)
    res = identify_data(data, P, D, MASS_DAMPER.delay)
    assert_honest(res, MASS_DAMPER.plant, MASS_DAMPER.crb_sd(NOISE), "mass-damper")
    assert res.warnings == ()
    assert_spec_json(res, 10)
    assert "k = " in res.report()  # the text report copes with k ≈ 0 (ζ, ω₀ undefined)


# --------------------------------------------------------------------------------------------
# 3. runs of different lengths and sample rates


def test_runs_of_different_lengths_and_sample_rates():
    data, P, D, _ = MIXED.simulate(noise=NOISE, seed=3)
    rates = {round(1 / (t[1] - t[0])) for t, _ in data}
    lengths = {round(t[-1] - t[0]) for t, _ in data}
    assert rates == {500, 750, 1000, 2000} and len(lengths) == 4
    res = identify_data(data, P, D, MIXED.delay)
    assert_honest(res, MIXED.plant, MIXED.crb_sd(NOISE), "mixed rates")
    assert all(r.used for r in res.runs) and res.warnings == ()
    assert_spec_json(res, len(data))


# --------------------------------------------------------------------------------------------
# 4. barely damped runs and two-cycle runs in one set


def test_barely_damped_and_two_cycle_runs():
    data, P, D, _ = MIXED_DAMPING.simulate(noise=NOISE, seed=4)
    res = identify_data(data, P, D, MIXED_DAMPING.delay)
    assert_honest(res, MIXED_DAMPING.plant, MIXED_DAMPING.crb_sd(NOISE), "mixed damping")
    assert_spec_json(res, len(data))
    cycles = [r.cycles for r in res.runs]
    assert cycles[0] > 100 and cycles[1] > 200  # hundreds of cycles
    for i, r in enumerate(res.runs):
        assert r.used, r  # every run kept ...
        few = [w for w in res.warnings if w.startswith(f"{r.file}: few cycles")]
        # ... and exactly the two-cycle runs carry the few-cycles warning, naming the run
        assert bool(few) == (i in SHORT_RUNS), (i, r.cycles, res.warnings)
        if i in SHORT_RUNS:
            assert 1.5 < r.cycles < 3.0
    # each run's (σ, ω_d) against the exact dominant root of the true loop: its covariance is
    # what the weighted fit uses as weight, so it must be honest for the short runs too (|z| < 4
    # for 16 numbers; the calibration of the short runs is checked in the next test)
    exact = forward_map(MIXED_DAMPING.plant, P, D, MIXED_DAMPING.delay)
    for r, s, w in zip(res.runs, exact.sigma, exact.omega_d, strict=True):
        assert abs(r.sigma - s) < 4 * r.sigma_stderr and abs(r.omega_d - w) < 4 * r.omega_d_stderr
    # a two-cycle run weighs far less than a barely damped one: σ known 100× less precisely
    assert min(res.runs[i].sigma_stderr for i in SHORT_RUNS) > 100 * res.runs[0].sigma_stderr


def test_two_cycle_runs_are_weighted_by_an_honest_covariance():
    # 30 noisy replicas of one two-cycle run (σ = 6, ω_d = 14) measured by the pipeline's mode
    # stage (with two well-damped anchor runs, as in a set, for the first-pass plant estimate):
    # the weights the m, c, k fit gives these runs are their inverse covariances, so those must
    # match the scatter. With 30 replicas the sd of a z-score's sample sd is ≈ 0.13; the band
    # 0.7–1.35 is ±2.5 of it. The mean is checked to ±0.6 (3/√30).
    design = Design(MIXED_DAMPING.plant, MIXED_DAMPING.delay,
                    ((1000.0, 15.0, ((0.5, 8.0), (1.0, 14.0)) + ((6.0, 14.0),) * 30),))
    data, P, D, _ = design.simulate(noise=NOISE, seed=41)
    fits, reasons, _ = measure_modes(data, P, D, design.delay)
    assert all(r is None for r in reasons)
    z_sig = np.array([(f.sigma - 6.0) / f.sigma_stderr for f in fits[2:]])
    z_om = np.array([(f.omega_d - 14.0) / f.omega_d_stderr for f in fits[2:]])
    print(f"\ntwo-cycle runs: z(sigma) mean {z_sig.mean():+.2f} sd {z_sig.std(ddof=1):.2f}; "
          f"z(omega_d) mean {z_om.mean():+.2f} sd {z_om.std(ddof=1):.2f}")
    for z in (z_sig, z_om):
        assert abs(z.mean()) < 0.6 and 0.7 < z.std(ddof=1) < 1.35


def test_marginally_stable_run_is_kept():
    # a run right on the stability boundary (σ = 0: the loop neither decays nor grows) is the
    # most precise run of its set; noise makes its σ̂ negative half the time, which must not get
    # it set aside as "growing" — only a sure growth (σ̂ < −2 stderr) does. This seed gives
    # σ̂ < 0 (asserted), so the test exercises that branch.
    design = Design(MIXED_DAMPING.plant, MIXED_DAMPING.delay,
                    ((1000.0, 10.0, ((0.0, 40.0), (0.5, 8.0), (1.0, 14.0), (0.8, 20.0),
                                     (4.0, 9.0))),))
    data, P, D, _ = design.simulate(noise=NOISE, seed=0)
    res = identify_data(data, P, D, design.delay)
    r0 = res.runs[0]
    assert -2 * r0.sigma_stderr < r0.sigma < 0
    assert r0.used
    assert any(w.startswith("run1: growing oscillation") and "marginally" in w
               for w in res.warnings)
    assert_honest(res, design.plant, label="marginal run")
    assert_spec_json(res, 5)


# --------------------------------------------------------------------------------------------
# 5. noise-free data: relative error ≤ 1e-6


@pytest.mark.parametrize("design", [OVERDAMPED, MIXED, MIXED_DAMPING],
                         ids=["overdamped", "mixed-rates", "mixed-damping"])
def test_noise_free_simulation(design):
    data, P, D, _ = design.simulate()
    res = identify_data(data, P, D, design.delay)  # estimator="gls", the default
    rel = [abs(getattr(res, q).value / getattr(design.plant, q) - 1) for q in "mck"]
    print(f"\nnoise-free {design.plant}: relative errors {rel}")
    assert max(rel) <= 1e-6
    assert all(r.used for r in res.runs)
    assert_spec_json(res, len(data))


def test_noise_free_mass_damper_through_phoid_simulate(tmp_path):
    # `phoid simulate` (no noise) then `phoid identify --json`. k = 0 has no relative error: the
    # bound is 1e-6 of the experiment's stiffness scale, the largest closed-loop kᵢ = mω₀ᵢ².
    P, D = MASS_DAMPER.gains()
    out = tmp_path / "md"
    r = runner.invoke(app, ["simulate", str(out), "--m", "1", "--c", "10", "--k", "0",
                            "--P=" + ",".join(repr(float(p)) for p in P),
                            "--D=" + ",".join(repr(float(d)) for d in D),
                            "--delay", "0.01", "--duration", "10", "--noise", "0"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["identify", str(out), "--json"])
    assert r.exit_code == 0, r.output
    s = strict_json(r.stdout)
    k_scale = max(MASS_DAMPER.plant.m * (s_ * s_ + w * w) for s_, w in MASS_DAMPER.targets)
    errs = (abs(s["m"]["value"] - 1.0), abs(s["c"]["value"] / 10.0 - 1), abs(s["k"]["value"]))
    print(f"\nnoise-free mass-damper (CLI): |dm|/m, |dc|/c, |k|: {errs}")
    assert errs[0] <= 1e-6 and errs[1] <= 1e-6 and errs[2] <= 1e-6 * k_scale


@pytest.fixture(scope="module")
def jitc_records(tmp_path_factory):
    """MIXED's 1 kHz group (5 runs, 10 s) solved by jitcdde at rtol 1e-10, a 0.1 s held segment
    prepended; and one run again at rtol 1e-12 to measure jitcdde's own error."""
    pytest.importorskip("jitcdde")
    from jitc_reference import jitcdde_reference

    plant, delay = MIXED.plant, MIXED.delay
    targets = ((0.8, 6.0), (1.5, 12.0), (0.3, 5.0), (0.6, 9.0), (1.0, 16.0))
    g = np.array([gains_for(plant, delay, s, w) for s, w in targets])
    fs, duration = 1000.0, 10.0
    t = np.arange(round(duration * fs)) / fs
    with pytest.MonkeyPatch.context() as mp:
        # compile (first use, cached in the temp dir) outside the checkout: setuptools, which
        # jitcdde drives, would otherwise read the project's own pyproject.toml
        mp.chdir(tmp_path_factory.mktemp("jitc"))
        xs = [jitcdde_reference(plant.m, plant.c, plant.k, p, d, delay, X0, t, rtol=1e-10)
              for p, d in g]
        fine = jitcdde_reference(plant.m, plant.c, plant.k, g[0, 0], g[0, 1], delay, X0, t,
                                 rtol=1e-12)
    n_hold = round(HOLD * fs)
    th = np.r_[-HOLD + np.arange(n_hold) / fs, t]
    data = [(th, np.r_[np.full(n_hold, X0), x]) for x in xs]
    return data, g[:, 0], g[:, 1], float(np.max(np.abs(xs[0] - fine)))


def test_noise_free_independent_solver(jitc_records):
    data, P, D, jitc_err = jitc_records
    # jitcdde at rtol 1e-10 is itself off by ~5e-10·x₀ here (against rtol 1e-12; up to ~1.4e-9
    # over all five runs); its error enters m, c, k at about that relative order, far below the
    # 1e-6 asked for
    print(f"\njitcdde rtol 1e-10 vs 1e-12: max |dx| = {jitc_err / X0:.2e}·x0")
    assert jitc_err <= 1e-8 * X0
    res = identify_data(data, P, D, MIXED.delay)
    rel = [abs(getattr(res, q).value / getattr(MIXED.plant, q) - 1) for q in "mck"]
    print(f"noise-free jitcdde set: relative errors {rel}")
    assert max(rel) <= 1e-6
    assert_spec_json(res, 5)


# --------------------------------------------------------------------------------------------
# 6. an unstable run in a good set; a set with no usable run

UNSTABLE = (-0.3, 10.0)  # σ < 0: the loop grows as e^{0.3 t}


def test_unstable_run_is_set_aside(tmp_path):
    plant, delay = MIXED.plant, MIXED.delay
    good = ((0.8, 6.0), (1.5, 12.0), (0.3, 5.0), (0.6, 9.0), (1.0, 16.0))
    P_u, D_u = gains_for(plant, delay, *UNSTABLE)
    roots = characteristic_roots(plant, DelayedPD(P_u, D_u, delay), count=2)
    assert roots[0].real == pytest.approx(0.3)  # rightmost root in the right half-plane
    design = Design(plant, delay, ((1000.0, 10.0, (*good[:3], UNSTABLE, *good[3:])),))
    data, P, D, _ = design.simulate(noise=NOISE, seed=6)
    path = write_set(tmp_path / "u", data, P, D, delay)
    res = identify(read_experiment(path))
    aside = [w for w in res.warnings if "set aside" in w]
    assert len(aside) == 1 and aside[0].startswith("run 4 (run04.csv): set aside: growing")
    assert "unstable" in aside[0]
    assert [r.used for r in res.runs] == [True, True, True, False, True, True]
    assert_honest(res, plant, label="with an unstable run")  # m, c, k from the other five
    assert_spec_json(res, 6, set_aside=(3,))
    # the command line: JSON on stdout, the warning (naming the file) on stderr
    r = runner.invoke(app, ["identify", str(tmp_path / "u"), "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["runs"][3]["used"] is False
    assert "run04.csv" in r.stderr and "set aside" in r.stderr


def test_no_usable_run(tmp_path):
    plant, delay = MIXED.plant, MIXED.delay
    design = Design(plant, delay, ((1000.0, 6.0, (UNSTABLE, (-0.2, 6.0), (-0.5, 14.0))),))
    data, P, D, _ = design.simulate(noise=NOISE, seed=7)
    with pytest.raises(IdentificationError, match=r"no usable runs: run1: growing") as exc:
        identify_data(data, P, D, delay)
    assert "\n" not in str(exc.value) and "run3: growing" in str(exc.value)
    write_set(tmp_path / "bad", data, P, D, delay)
    line = one_line_error(runner.invoke(app, ["identify", str(tmp_path / "bad"), "--json"]),
                          "no usable runs", "run01.csv", "run02.csv", "run03.csv")
    assert "growing" in line


# --------------------------------------------------------------------------------------------
# 7, 8. a clipped record; fewer than ~3 cycles


def test_clipped_run_is_set_aside():
    # a sensor saturating at ±3 mm (0.6·x₀): the held position and the first peaks of run 3
    # (σ = 0.3, ω_d = 5: peaks at −4.2, +3.4, −2.9 mm …) are flat
    groups = (MIXED.groups[1], (1000.0, 10.0, ((0.3, 5.0), (0.7, 20.0))))
    data, P, D, _ = Design(MIXED.plant, MIXED.delay, groups).simulate(noise=NOISE, seed=8)
    t, x = data[3]
    xc = np.clip(x, -0.6 * X0, 0.6 * X0)
    assert np.count_nonzero(xc == -0.6 * X0) > 100  # flat bottoms
    data[3] = (t, xc)
    res = identify_data(data, P, D, MIXED.delay)
    aside = [w for w in res.warnings if "set aside" in w]
    assert len(aside) == 1 and aside[0].startswith("run4: set aside: clipped")
    assert "saturat" in aside[0]
    assert [r.used for r in res.runs] == [True, True, True, False, True]
    assert_honest(res, MIXED.plant, label="with a clipped run")
    assert_spec_json(res, 5, set_aside=(3,))


def test_run_with_fewer_than_three_cycles_is_flagged():
    # a record stopped early: run 1 (σ = 0.3, ω_d = 5, period 1.26 s) ends 2 cycles after its
    # release, while its envelope is still far above the noise
    groups = (MIXED.groups[1], (1000.0, 10.0, ((0.8, 6.0), (1.5, 12.0))))
    data, P, D, _ = Design(MIXED.plant, MIXED.delay, groups).simulate(noise=NOISE, seed=9)
    t, x = data[0]
    keep = t <= HOLD + 2 * (2 * math.pi / 5.0)
    data[0] = (t[keep], x[keep])
    res = identify_data(data, P, D, MIXED.delay)
    few = [w for w in res.warnings if "few cycles" in w]
    assert len(few) == 1 and few[0].startswith("run1: few cycles: only")
    assert 1.8 < res.runs[0].cycles < 2.1
    assert res.runs[0].used  # kept, weighted by its (larger) covariance
    assert_honest(res, MIXED.plant, label="with a 2-cycle record")
    assert_spec_json(res, 5)


# --------------------------------------------------------------------------------------------
# 9. the delay omitted from the manifest


def test_delay_omitted_from_manifest(tmp_path):
    # three distinct gain pairs: the delay is estimated with m, c, k (issue 6), and the JSON
    # says so with a stderr; the truth (MIXED.delay) lies within 3 of them
    data, P, D, _ = Design(MIXED.plant, MIXED.delay,
                           ((1000.0, 4.0, ((0.8, 6.0), (1.5, 12.0), (1.0, 16.0))),)).simulate()
    path = write_set(tmp_path / "nd", data, P, D, None)
    res = identify(read_experiment(path))
    assert res.delay_source == "estimated" and res.delay_stderr > 0
    assert abs(res.delay - MIXED.delay) < 3 * res.delay_stderr
    r = runner.invoke(app, ["identify", str(tmp_path / "nd"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["delay"]["source"] == "estimated" and out["delay"]["stderr"] > 0
    # the delay given on the command line instead: used as given
    r = runner.invoke(app, ["identify", str(tmp_path / "nd"), "--json", "--delay", "0.02"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["delay"] == {"value": 0.02, "stderr": None, "unit": "s",
                                              "source": "given"}
    # two distinct gain pairs cannot fix a delay: one-line error naming the set
    path2 = write_set(tmp_path / "nd2", data[:2], P[:2], D[:2], None)
    with pytest.raises(IdentificationError, match="at least three"):
        identify(read_experiment(path2))
    for extra in ([], ["--json"]):
        one_line_error(runner.invoke(app, ["identify", str(tmp_path / "nd2"), *extra]),
                       str(path2), "three")


# --------------------------------------------------------------------------------------------
# statistical honesty on a non-paper plant: a small Monte Carlo of case 2


def test_monte_carlo_coverage_mass_damper():
    # 40 noisy replicas of MASS_DAMPER (seeds 100–139). For a calibrated estimator z = (est −
    # truth)/stderr is ~N(0, 1): all 120 |z| < 3 is expected (a miss is a 0.3 % event; at most
    # one is allowed per parameter); the sample sd of 40 z's has sd ≈ 0.11, so 0.75–1.3 is about
    # ±2.5 of it; the mean's sd is 0.16, so |mean| < 0.5 is ±3 of it.
    P, D = MASS_DAMPER.gains()
    z = []
    for seed in range(100, 140):
        data, _, _, _ = MASS_DAMPER.simulate(noise=NOISE, seed=seed)
        res = identify_data(data, P, D, MASS_DAMPER.delay)
        zs = zscores(res, MASS_DAMPER.plant)
        z.append([zs[q] for q in "mck"])
    z = np.array(z)
    inside = np.mean(np.abs(z) < 3, axis=0)
    print("\nMonte Carlo (40 x mass-damper): within 3 stderr "
          + ", ".join(f"{q} {f:.3f}" for q, f in zip("mck", inside, strict=True))
          + "; z mean " + ", ".join(f"{v:+.2f}" for v in z.mean(axis=0))
          + "; z sd " + ", ".join(f"{v:.2f}" for v in z.std(axis=0, ddof=1)))
    assert np.all(inside >= 39 / 40)
    assert np.all(np.abs(z.mean(axis=0)) < 0.5)
    assert np.all((z.std(axis=0, ddof=1) > 0.75) & (z.std(axis=0, ddof=1) < 1.3))
