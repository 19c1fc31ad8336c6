"""`phoid design` for the rig's sampled loop (issue 28, item 4): exact modes, margins in samples,
the in-loop prediction, the plan, --check of a digital set, --rehearse.

Expected values come from independent computations written out here: the sampled loop's
characteristic polynomial for one sample of delay and the backward difference, built from the
plant's zero-order-hold discretisation (scipy.linalg.expm of the augmented state matrix) and
solved with np.roots; stability at a delay by the same polynomial, and by simulating the loop
(phoid.simulation.simulate, no noise) and watching it grow. The in-loop prediction is checked
against phoid.planning.inloop_bound evaluated afresh on the printed gains (the design's claim is
that its prediction *is* that bound for its runs), the plan against what `phoid run` reads of
it, and the check of a set against the set `phoid simulate` wrote.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from typer.testing import CliRunner

from phoid.cli import app
from phoid.dynamics.digital import DigitalPD
from phoid.planning import check, design, read_schedule
from phoid.planning.inloop_bound import inloop_cramer_rao
from phoid.simulation import simulate

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"
OVERDAMPED = {"m": 0.5, "c": 40.0, "k": 20.0}  # the README's plant
T = 1e-3


def _phoid(*args, cwd: Path, timeout: float = 300.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    cmd = [sys.executable, "-c", "from phoid.cli import main; main()", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=timeout)


def _cli(*args):
    """The command line in this process (typer's runner: the options parsed as by `phoid`)."""
    return runner.invoke(app, [str(a) for a in args])


def _chi_d(m, c, k, P, D, T, d):
    """χ(z) of the sampled PD loop with the backward difference and d samples of delay, from
    first principles: ZOH plant G(z) = N(z)/Δ(z) from Φ = e^{AT}, Γ = ∫e^{Aτ}dτ b (the
    augmented matrix's exponential), controller P + D(1 − z⁻¹)/T, delay z⁻ᵈ:
    z^{d+1}Δ(z) + (P z + D(z − 1)/T)N(z) = 0."""
    M = np.zeros((3, 3))
    M[0, 1] = 1.0
    M[1, :] = [-k / m, -c / m, 1.0 / m]
    E = scipy.linalg.expm(M * T)
    Phi, Gam = E[:2, :2], E[:2, 2]
    delta = np.array([1.0, -np.trace(Phi), np.linalg.det(Phi)])
    N = np.array([Gam[0], Phi[0, 1] * Gam[1] - Phi[1, 1] * Gam[0]])  # [1 0] adj(zI − Φ) Γ
    K = np.array([P + D / T, -D / T])
    return np.polyadd(np.concatenate([delta, np.zeros(d + 1)]), np.polymul(K, N))


def _roots_s(m, c, k, P, D, T, d):
    z = np.roots(_chi_d(m, c, k, P, D, T, d))
    return z, np.log(z.astype(complex)) / T


@pytest.fixture(scope="module")
def sampled():
    """A small design for the overdamped plant on a 1 kHz loop, one sample of delay (the
    modal prediction: the in-loop bound is the CLI test's)."""
    return design(OVERDAMPED["m"], OVERDAMPED["c"], OVERDAMPED["k"], sample_time=T,
                  delay_samples=1, noise=1e-6, runs=4, duration=3.0, noise_in_loop=False)


def test_the_runs_modes_are_the_sampled_loops_roots(sampled):
    m, c, k = OVERDAMPED.values()
    assert sampled.settings.fs == 1 / T  # a rig records at the loop's rate
    for r in sampled.runs:
        z, s = _roots_s(m, c, k, r.P, r.D, T, 1)
        assert len(r.roots) == z.size == 4  # d + 3 roots
        order = np.argsort(-np.abs(z))
        # each reported root is one of np.roots' (to 1e-9 relative: the two root finders
        # differ by rounding of a degree-4 polynomial with well-separated roots)
        for got in r.roots:
            assert np.min(np.abs(s - got)) <= 1e-9 * abs(got), (r.P, r.D, got, s)
        dominant = s[order[0]]
        assert r.sigma == pytest.approx(-dominant.real, rel=1e-9)
        assert r.omega_d == pytest.approx(abs(dominant.imag), rel=1e-9)
        assert np.all(np.abs(z) < 1.0)  # stable, as the design says
        # the zeta band of the design: its target is placed exactly, at the nominal plant
        assert 0.03 * (1 - 1e-9) <= r.zeta <= 0.2 * (1 + 1e-9)


def test_delay_margins_in_samples_hold_by_roots_and_simulation():
    # the overdamped plant on a 1 kHz loop with 1 sample of delay, three pairs of gains with
    # margins from 2 to 27 samples; at the nominal plant only (tolerance 0: the prior grid is
    # that one plant)
    m, c, k, d = 0.5, 40.0, 20.0, 1
    P, D = np.array([3070.0, 1110.0, 2000.0]), np.array([-28.6, -33.0, 10.0])
    ch = check(P, D, m, c, k, sample_time=T, delay_samples=d, noise=1e-5, duration=3.0,
               tolerance=0.0, noise_in_loop=False)
    tops = []
    for r in ch.runs:
        top = r.max_delay_samples
        assert math.isfinite(top) and top == d + r.delay_margin_samples
        top = int(top)
        tops.append(top)
        # stable at every delay from d to d' (np.roots of the polynomial written above) …
        for dd in range(d, top + 1):
            assert np.max(np.abs(_roots_s(m, c, k, r.P, r.D, T, dd)[0])) < 1.0, (r.P, dd)
        # … and not one sample more
        assert np.max(np.abs(_roots_s(m, c, k, r.P, r.D, T, top + 1)[0])) > 1.0, (r.P, top)
    assert min(tops) - d <= 3 and max(tops) - d >= 20  # small and large margins both tested
    # the simulated loop (no noise) dies out at d' and grows at d' + 1, for the two runs
    # whose unstable root at d' + 1 grows fastest (0.42 and 0.60 1/s from np.roots: ×e^4.7
    # and more over the last three quarters of 15 s; measured ×109 and ×845)
    for i in (0, 2):
        ratio = []
        for dd in (tops[i], tops[i] + 1):
            sim = simulate(_plant(m, c, k), P[i], D[i], duration=15.0, fs=1 / T, x0=0.01,
                           sample_time=T, delay_samples=dd, noise_in_loop=False)
            x = np.abs(sim.x[0])
            n = x.size // 4
            ratio.append(np.max(x[-n:]) / np.max(x[:n]))
        assert ratio[0] < 1.0 and ratio[1] > 10.0, (P[i], tops[i], ratio)


def _plant(m, c, k):
    from phoid.dynamics.plant import Plant

    return Plant(m, c, k)


def test_the_plan_is_the_sampled_loop_phoid_run_executes(sampled, tmp_path):
    from phoid.rig.host import plan_configs

    path = sampled.write(tmp_path / "plan")
    doc = tomllib.loads(path.read_text())
    # the loop as the set's [loop] states it (docs/format.md), no continuous delay beside it
    assert doc["loop"] == {"sample_time": T, "delay_samples": 1,
                           "velocity": "backward-difference", "noise": "outside"}
    assert doc["design"]["fs"] == 1 / T
    sched = read_schedule(tmp_path / "plan")
    assert (sched["sample_time"], sched["delay_samples"], sched["delay"]) == (T, 1, T)
    # phoid run's controller: period T, one sample of delay, the gains of the design
    _, cfgs = plan_configs(tmp_path / "plan")
    assert {(c["sample_time"], c["delay_samples"]) for c in cfgs} == {(T, 1)}
    assert [c["P"] for c in cfgs] == list(sampled.P)


def test_design_cli_prints_the_loop_and_the_inloop_prediction(tmp_path):
    r = _phoid("design", "--m", 0.5, "--c", 40, "--k", 20, "--sample-time", 0.001,
               "--delay-samples", 1, "--noise", 1e-6, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "sampled loop: sample_time 0.001 s, delay_samples 1" in out
    assert "noise in the loop" in out and "in-loop Cramér–Rao bound" in out
    # the delay margin's column, in whole samples (its unit in the row under the names)
    head = out.splitlines().index(next(x for x in out.splitlines() if "delay margin" in x))
    assert "samples" in out.splitlines()[head + 1] and "Sampled loop modes" in out
    # --json (in this process; a smaller design: 4 runs of 3 s): the new keys, and the
    # prediction is the in-loop bound of the printed gains, evaluated afresh
    r = _cli("design", "--m", 0.5, "--c", 40, "--k", 20, "--sample-time", 0.001,
             "--delay-samples", 1, "--noise", 1e-6, "--runs", 4, "--duration", 3, "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    assert js["loop"]["kind"] == "sampled"
    assert (js["loop"]["sample_time"], js["loop"]["delay_samples"]) == (0.001, 1)
    assert (js["noise_placement"], js["bound"]) == ("in-loop", "in-loop")
    assert js["settings"]["fs"] == 1000.0
    for run in js["runs"]:
        assert run["delay_margin_samples"] >= 1 and len(run["roots"]) == 4
        assert run["max_delay_samples"] == 1 + run["delay_margin_samples"]
    P = [run["P"] for run in js["runs"]]
    D = [run["D"] for run in js["runs"]]
    b = inloop_cramer_rao(0.5, 40.0, 20.0, P, D, DigitalPD(0.0, 0.0, T, 1), fs=1000.0,
                          duration=3.0, noise=1e-6, x0=0.01)
    for j, name in enumerate("mck"):
        # the same bound on the same (JSON-rounded, 17 digits) gains: rounding only
        assert js["predicted"][name]["stderr"] == pytest.approx(b.stderr[j], rel=1e-6)
        # the noise in the loop costs information here (issue 28: several times the modal)
        assert js["predicted"][name]["stderr"] > js["predicted"][name]["modal_stderr"]


def test_check_accepts_a_digital_set(tmp_path):
    # a digital set as `phoid simulate` writes it: [loop] sample_time, delay_samples, noise
    r = _cli("simulate", tmp_path / "set", "--m", 0.5, "--c", 40, "--k", 20,
             "--P", "330,1110,3070", "--D", "-35,-33,-28.6", "--sample-time", 0.001,
             "--delay-samples", 1, "--noise", 1e-6, "--duration", 2, "--hold", 0.01,
             "--seed", 3)
    assert r.exit_code == 0, r.output
    manifest = tomllib.loads((tmp_path / "set" / "experiment.toml").read_text())
    assert manifest["loop"]["sample_time"] == 0.001 and "delay" not in manifest["loop"]
    r = _cli("design", "--check", tmp_path / "set", "--m", 0.5, "--c", 40, "--k", 20,
             "--json")
    assert r.exit_code == 0, r.output  # accepted, and every run safe on the prior
    js = json.loads(r.stdout)
    assert js["kind"] == "check" and js["loop"]["kind"] == "sampled"
    assert (js["loop"]["sample_time"], js["loop"]["delay_samples"]) == (0.001, 1)
    assert js["settings"]["fs"] == 1000.0 and js["settings"]["duration"] == pytest.approx(
        2.0, abs=0.01)
    # the set states the noise in the loop: the in-loop bound, and a note saying so
    assert manifest["loop"]["noise"] == "in-loop"
    assert js["bound"] == "in-loop"
    assert any("[loop] noise" in n for n in js["notes"]), js["notes"]
    assert [run["P"] for run in js["runs"]] == [330.0, 1110.0, 3070.0]


@pytest.mark.parametrize(("args", "words"), [
    (["--delay", "0.002", "--sample-time", "0.001"], "--delay (s) and --sample-time"),
    (["--delay", "0.002", "--delay-samples", "1"], "--delay-samples applies to a sampled"),
    (["--delay", "0.002", "--noise-in-loop"], "--noise-in-loop/--noise-outside apply"),
    (["--sample-time", "0.001", "--delay-margin", "0.01"], "--delay-margin-samples"),
    (["--sample-time", "0.001", "--fs", "1500"], "whole multiple"),
    (["--sample-time", "0.001", "--fs", "500"], "whole multiple"),
    (["--sample-time", "0.001", "--delay-samples", "-1"], "--delay-samples"),
    (["--sample-time", "0.001", "--delay-samples", "1001"], "--delay-samples"),
    (["--sample-time", "1e-4", "--delay-samples", "500"], "degree 503"),
    (["--sample-time", "0", "--delay-samples", "1"], "--sample-time"),
    (["--sample-time", "nan"], "--sample-time"),
    (["--sample-time", "0.001", "--velocity", "fir"], "--velocity"),
    (["--sample-time", "0.001", "--velocity", "filtered"], "--cutoff"),
    (["--sample-time", "0.001", "--cutoff", "300"], "--cutoff"),
    (["--sample-time", "20"], "--sample-time"),  # longer than the 10 s record
    (["--sample-time", "0.001", "--delay-samples", "1", "--delay-margin-samples", "-2"],
     "--delay-margin-samples"),
])
def test_bad_loop_options_are_one_line(args, words):
    res = runner.invoke(app, ["design", "--m", "0.5", "--c", "40", "--k", "20", *args])
    assert res.exit_code == 2, res.output
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phoid: error:"), res.stderr
    assert words in err[0], (words, err[0])


def test_python_keywords_are_checked_by_name():
    m, c, k = OVERDAMPED.values()
    with pytest.raises(ValueError, match=r"`delay` \(s\) and `sample_time` together"):
        design(m, c, k, delay=0.002, sample_time=T)
    with pytest.raises(ValueError, match="`noise_in_loop` = True needs a sampled loop"):
        design(m, c, k, delay=0.002, noise_in_loop=True)
    with pytest.raises(ValueError, match="`noise_in_loop` must be True, False or None"):
        design(m, c, k, sample_time=T, noise_in_loop="yes")
    with pytest.raises(ValueError, match="`delay_samples` must be a whole number"):
        design(m, c, k, sample_time=T, delay_samples=1.5)
    with pytest.raises(ValueError, match="give the loop delay"):
        design(m, c, k)


def test_rehearse_a_sampled_design():
    r = _cli("design", "--m", 0.5, "--c", 40, "--k", 20, "--sample-time", 0.001,
             "--delay-samples", 1, "--noise", 1e-6, "--runs", 3, "--duration", 1.5,
             "--rehearse", 2, "--workers", 0, "--seed", 5, "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    reh = js["rehearsal"]
    assert reh["replicas"] == 2 and reh["identified"] == 2, reh
    for name in "mck":
        p = reh["parameters"][name]
        assert p["predicted"] == js["predicted"][name]["stderr"]
        # the replicas' own stderr come from the in-loop route, whose stderr is the in-loop
        # bound at the estimate with σ̂ (within 30 %: two replicas, 4500 samples each)
        assert p["mean_stderr"] == pytest.approx(p["predicted"], rel=0.3), (name, p)
