"""Hostile probe, tracking sets: a wrong command delay, and values the loop divides by.

Sets are made here from the exact loop simulator on the small axis of
tests/test_hostile_tracking.py (m = 2 kg, c = 15 N s/m, k = 0, f_c = 1.5 N, f₀ = −0.3 N, a
1 kHz PD loop with P = 4000, D = 60, a two-sine reference), 1000 samples (1 s), with white
position noise of 1 µm (an encoder's resolution on a 20 mm stroke) unless said otherwise.

1. A delay stated wrongly ([loop] delay) must not pass silently: identify warns, naming
   ``[loop] delay`` (or ``--delay``) and the delay the record implies
   (docs/design-notes/tracking-validation.md, "the stated delay, checked").
2. Every value the loop divides by, or squares, is checked by name: one line, exit 2.
3. A delay beyond the first 5 samples searched, a loop that misfits whatever the delay, a
   delay far too long, and IDIM biased by the position's noise: each warned, or named in the
   error (a second hostile probe).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid.io
from phoid.cli import app
from phoid.dynamics.controller import SampledController, closed_loop_poles
from phoid.dynamics.plant import Plant
from phoid.methods.idim import idim_ls
from phoid.methods.tracking import TrackingRecord
from phoid.methods.tracking_delay import DELAY_RANGE, check_delay
from phoid.simulation.tracking import simulate_tracking

runner = CliRunner()

PLANT = Plant(2.0, 15.0, 0.0, 1.5)
OFFSET = -0.3
N = 1000
T = 1e-3
NOISE = 1e-6  # m


def _set(folder: Path, *, true_delay: float, stated: float | None, noise: float = NOISE,
         seed: int = 0, u: bool = True, loop: dict | None = None,
         run_keys: dict | None = None) -> Path:
    """A one-run tracking set recorded with ``true_delay`` and stating ``stated`` (None: no
    [loop] delay)."""
    ctrl = SampledController(sample_time=T, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0, delay=true_delay)
    t = T * np.arange(N)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = simulate_tracking(PLANT, ctrl, r, offset=OFFSET, x_init=[0.0])
    x = sim.x + noise * np.random.default_rng(seed).standard_normal(N)
    run = phoid.io.run_from_arrays(t, x, r=r, u=sim.command if u else None, P=4000.0, D=60.0,
                                   index=1, **(run_keys or {}))
    lp = {"sample_time": T, "velocity": "central-difference", "saturation": 200.0,
          **({} if stated is None else {"delay": stated}), **(loop or {})}
    phoid.io.write_experiment(folder, [run], method="tracking", fixed={"k": 0.0}, loop=lp)
    return folder


def cli(*args, code=0):
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == code, (r.exit_code, repr(r.exception), r.output)
    if code == 2:
        # a user's error: one line, not a traceback (CliRunner would hold the exception)
        assert isinstance(r.exception, SystemExit), repr(r.exception)
        assert r.output.count("\n") == 1 and r.output.startswith("phoid: error: "), r.output
    return r


def _delay_warnings(out: dict) -> list[str]:
    return [w for w in out["warnings"] if "contradicted by the record" in w]


def _identify(folder: Path, *extra: str) -> dict:
    return json.loads(cli("identify", folder, "--json", *extra).stdout)


# ---------------------------------------------------------------------------------------------
# 1. the stated delay, checked against the record


def test_the_issue_case_warns_naming_the_field_and_the_delay_the_record_implies(tmp_path):
    # the issue: a record made with no delay, identified with [loop] delay = 0.01 s (IDIM: m
    # 8 stderr off, c 11 stderr off, no warning but the OLS one)
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.01, noise=0.0)
    out = _identify(folder)
    assert out["estimator"] == "idim"
    (w,) = _delay_warnings(out)
    assert w.startswith("[loop] delay = 10 ms is contradicted by the record"), w
    implied = float(re.search(r"implies a delay of ([-\d.e+]+) ±", w).group(1))
    # the truth is 0; the fit resolves a noise-free record's delay to a few µs (half a
    # sample, 0.5 ms, is far wider than the fit's error and far narrower than the 10 ms stated)
    assert abs(implied) < 0.5, w
    # the estimates with the delay free are named, and are the truth's (noise-free record:
    # the optimiser's tolerance; 1 % bound)
    m = float(re.search(r"m = ([\d.]+)", w.split("; with the delay free ")[1]).group(1))
    assert m == pytest.approx(2.0, rel=0.01), w


@pytest.mark.parametrize(("true_ms", "stated_ms"), [(0.0, 2.0), (3.0, 0.0), (0.4, 2.4),
                                                    (2.4, 0.4), (1.0, 0.0)])
@pytest.mark.parametrize("estimator", ["idim", "output-error"])
def test_a_delay_off_by_whole_samples_warns(tmp_path, true_ms, stated_ms, estimator):
    folder = _set(tmp_path / "set", true_delay=true_ms * 1e-3, stated=stated_ms * 1e-3)
    out = _identify(folder, "--estimator", estimator)
    (w,) = _delay_warnings(out)
    assert w.startswith(f"[loop] delay = {stated_ms:g} ms"), w
    implied = float(re.search(r"implies a delay of ([-\d.e+]+) ±", w).group(1))
    # the record's delay, to a fraction of a sample (noise 1 µm resolves it to ≈ 2 µs)
    assert implied == pytest.approx(true_ms, abs=0.1), w


def test_a_delay_given_by_option_is_named_as_the_option(tmp_path):
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.0)
    out = _identify(folder, "--delay", "0.002")
    (w,) = _delay_warnings(out)
    assert w.startswith("--delay 2 ms is contradicted by the record"), w


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(("true_ms", "noise"), [(0.0, NOISE), (0.4, 1e-5), (2.0, 3e-6)])
def test_a_right_delay_with_ordinary_noise_raises_no_alarm(tmp_path, seed, true_ms, noise):
    # false alarms over seeds: the check's level is 5 stderr of the implied delay (a normal
    # variable exceeds it with probability 6e-7), so none of these 12 records may warn
    folder = _set(tmp_path / "set", true_delay=true_ms * 1e-3, stated=true_ms * 1e-3,
                  noise=noise, seed=seed)
    out = _identify(folder)
    assert not _delay_warnings(out), out["warnings"]
    # nor the other checks: a gross misfit, IDIM against output error, a delay not confirmed
    assert not [w for w in out["warnings"] if "does not follow the record" in w
                or "disagree" in w or "could not be confirmed" in w], out["warnings"]


@pytest.mark.parametrize("true_ms", [0.0, 0.4])
def test_a_right_delay_on_a_noise_free_record_raises_no_alarm(tmp_path, true_ms):
    # the model exact: the implied delay equals the stated one to the optimiser's rounding
    folder = _set(tmp_path / "set", true_delay=true_ms * 1e-3, stated=true_ms * 1e-3,
                  noise=0.0)
    for estimator in ("idim", "output-error"):
        out = _identify(folder, "--estimator", estimator)
        assert not _delay_warnings(out), out["warnings"]


def test_idim_without_a_stated_delay_warns_when_the_record_has_one(tmp_path):
    # IDIM assumes 0 when no delay is given; a record with 2 ms says otherwise
    folder = _set(tmp_path / "set", true_delay=2e-3, stated=None)
    out = _identify(folder, "--estimator", "idim")
    (w,) = _delay_warnings(out)
    assert w.startswith("[loop] delay (not given: 0 assumed) is contradicted"), w


# ---------------------------------------------------------------------------------------------
# 2. values the loop divides by, squares or exponentiates: one line, exit 2


@pytest.mark.parametrize("value", ["0", "-2", "nan", "inf", "-inf", "-1e-300"])
@pytest.mark.parametrize("option", ["--m", "--c", "--k", "--fc", "--offset-force", "--delay"])
def test_replay_options_are_checked_by_name(tmp_path, option, value):
    # before: --m 0 raised ZeroDivisionError in the loop's poles (dynamics/controller.py),
    # --c inf and --k inf an OverflowError in the matrix exponential
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.0)
    args = ["simulate", tmp_path / "sim", "--replay", folder]
    if option != "--m":
        args += ["--m", "2"]
    # 0 is a valid c, k, fc, offset and delay; a negative finite offset is valid, but not one
    # of magnitude below 1e-30 (simulate's bound on every number, commit 8957ba4)
    ok = ((value == "0" and option != "--m")
          or (option == "--offset-force" and value == "-2"))
    r = cli(*args, option, value, code=0 if ok else 2)
    if not ok:
        # named by the option: checked before the set is read ("--m must be > 0 kg", since
        # commit 8957ba4), or after, with the set ("experiment.toml: --m `m` must be …")
        name = option.lstrip("-").replace("offset-force", "offset")
        assert (f"{option} must be" in r.output
                or (f"experiment.toml: {option} " in r.output
                    and f"`{name}` must be" in r.output)), r.output


@pytest.mark.parametrize(("where", "key", "value", "message"), [
    ("run", "command_gain", "1e-300", "`command_gain` = 1e-300"),
    ("run", "command_gain", "1e-200", "`command_gain` = 1e-200"),
    ("loop", "saturation", "1e-300", "`saturation` = 1e-300"),
    ("loop", "cutoff", "1e-300", "key 'cutoff' must be a finite number > 0 of magnitude 1e-30"),
])
@pytest.mark.parametrize("command", ["idim", "output-error", "replay"])
def test_manifest_values_that_underflow_are_refused_by_name(tmp_path, where, key, value,
                                                            message, command):
    # before: command_gain = 1e-300 raised ZeroDivisionError in IDIM's relative error (the
    # force's norm underflowed to 0), so did saturation = 1e-300 in output error's start, and a
    # "filtered" estimator with cutoff 1e-300 rad/s divided by its DC gain 1 − e^(−ω_c T) = 0
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.0)
    manifest = folder / "experiment.toml"
    text = manifest.read_text(encoding="utf-8")
    if where == "run":
        text = text.replace('file = "run01.csv.gz"\n', f'file = "run01.csv.gz"\n{key} = {value}\n')
    elif key == "cutoff":
        text = text.replace('velocity = "central-difference"',
                            f'velocity = "filtered"\ncutoff = {value}')
    else:
        text = re.sub(rf"\n{key} = [^\n]+", f"\n{key} = {value}", text)
    manifest.write_text(text, encoding="utf-8")
    assert f"{key} = {value}" in manifest.read_text(encoding="utf-8")
    if command == "replay":
        r = cli("simulate", tmp_path / "sim", "--replay", folder, "--m", "2", code=2)
    else:
        r = cli("identify", folder, "--estimator", command, code=2)
    # a [loop] value refused on its own (its bounds) names [loop]; one refused against a run's
    # record names the run
    named = "experiment.toml: [loop]" if where == "loop" and key == "cutoff" else \
        "experiment.toml: run 1 (run01.csv.gz)"
    assert message in r.output and named in r.output


def test_closed_loop_poles_refuses_a_zero_mass_by_name():
    ctrl = SampledController(sample_time=T, P=4000.0, D=60.0)
    with pytest.raises(ValueError, match="`m` must be > 0 kg; got 0"):
        closed_loop_poles(0.0, 15.0, 0.0, ctrl)
    with pytest.raises(ValueError, match="`c` must be finite"):
        closed_loop_poles(2.0, float("inf"), 0.0, ctrl)


def test_idim_ls_on_a_tiny_force_keeps_its_digits():
    """The force in units of 2^e (IDIM's statistics): a force 1e-250 times smaller gives
    estimates and stderrs 1e-250 times smaller, to rounding (before: the force's squares
    underflowed — at 1e-300 its norm was 0 and the relative error a ZeroDivisionError; 1e-250
    keeps the decimation filter's products, ≈ 1e-10 of the force, above the subnormal range,
    where digits would be lost to the number format, not to the code)."""
    ctrl = SampledController(sample_time=T, P=4000.0, D=60.0, velocity="central-difference")
    t = T * np.arange(3000)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = simulate_tracking(PLANT, ctrl, r, offset=OFFSET, x_init=[0.0])
    ref = idim_ls(t, sim.x, sim.force, gain=1.0)
    tiny = idim_ls(t, sim.x, sim.force, gain=1e-250)
    # any change of scale moves the results by ≈ 1e-8 relative (gain 3 against 1: the rounding
    # of gain·u, amplified by the regression's sensitivity); 1e-6 leaves room for that, and a
    # force whose squares underflowed would be off by orders of magnitude
    for a, b in ((ref.M, tiny.M), (ref.Fv, tiny.Fv), (ref.Fc, tiny.Fc), (ref.OF, tiny.OF)):
        assert b.value == pytest.approx(1e-250 * a.value, rel=1e-6)
        assert b.stderr == pytest.approx(1e-250 * a.stderr, rel=1e-6)
    assert tiny.relative_error == pytest.approx(ref.relative_error, rel=1e-6)


# ---------------------------------------------------------------------------------------------
# 3. the second probe: delays beyond 5 samples, a wrong gain, a huge delay, IDIM's noise bias


@pytest.mark.parametrize(("true_ms", "stated_ms", "estimator"), [
    (8.0, 0.0, "idim"), (10.0, 2.0, "idim"), (0.0, 8.0, "idim"), (6.5, 0.0, "output-error")])
def test_a_delay_off_by_more_than_five_samples_warns(tmp_path, true_ms, stated_ms, estimator):
    # before: the check searched [0, stated + 5 ms] only, so 6.5–10 ms stated as 0 passed
    # silently with c pulled from 15 to 8.5–2.8 N s/m; the search now widens (×2) while the
    # fit ends on its upper end
    folder = _set(tmp_path / "set", true_delay=true_ms * 1e-3, stated=stated_ms * 1e-3)
    out = _identify(folder, "--estimator", estimator)
    (w,) = _delay_warnings(out)
    assert w.startswith(f"[loop] delay = {stated_ms:g} ms"), w
    implied = float(re.search(r"implies a delay of ([-\d.e+]+) ±", w).group(1))
    # the record's delay to a tenth of a sample (1 µm of noise resolves it to ≈ 2 µs)
    assert implied == pytest.approx(true_ms, abs=0.1), w


def test_the_delay_search_stops_at_half_the_record(tmp_path):
    # the widest range is DELAY_RANGE (1/2) of the record: 1000 samples of 1 ms → 0.4995 s;
    # a 12 ms delay (near where this loop turns unstable) is found inside it
    folder = _set(tmp_path / "set", true_delay=0.012, stated=0.0)
    exp = phoid.io.read_experiment(folder)
    run = exp.runs[0]
    ctrl = SampledController(sample_time=T, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0)
    rec = TrackingRecord(x=run.x, r=run.r, controller=ctrl, u=run.u)
    check = check_delay([rec], stated=0.0, fixed={"k": 0.0})
    assert check.limit == pytest.approx(DELAY_RANGE * (N - 1) * T)
    assert check.contradicts and not check.at_upper_end
    assert check.implied == pytest.approx(0.012, abs=1e-4)  # a tenth of a sample
    assert check.searched[1] > 0.012  # found after widening, not on the range's end


def test_a_wrong_gain_is_not_blamed_on_a_right_delay(tmp_path):
    # the probe's A2: the record made with D = 60, the set stating D = 0, the delay right (0).
    # Before: "[loop] delay = 0 ms is contradicted … 0.04151 ms, 19.2 stderrs" and nothing
    # else, with a position misfit 2060 times the noise
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.0)
    manifest = folder / "experiment.toml"
    manifest.write_text(manifest.read_text(encoding="utf-8").replace("D = 60.0", "D = 0"),
                        encoding="utf-8")
    out = _identify(folder)
    assert not _delay_warnings(out), out["warnings"]
    first = out["warnings"][0]
    assert first.startswith("[loop] delay = 0 ms: "), first
    assert "does not explain the validation's misfit" in first and "(P, D, gain" in first
    # the gross misfit of the validation is warned on its own, naming the run
    (gross,) = [w for w in out["warnings"] if w.startswith("run 1 (run01.csv.gz): the loop "
                                                           "simulated with the estimates")]
    assert "does not follow the record" in gross and "sign convention" in gross
    # and IDIM (force from u) against output error (the stated loop) says which to check
    (both,) = [w for w in out["warnings"] if "disagree" in w]
    assert "the stated controller does not produce the recorded command" in both


@pytest.mark.parametrize(("stated", "option", "named"), [
    (0.9, None, "[loop] delay = 900 ms is 900 controller periods"),
    (0.0, "0.5", "--delay 500 ms is 500 controller periods")])
def test_a_delay_far_too_long_is_named_among_the_causes(tmp_path, stated, option, named):
    # the probe's A3: before, the error blamed the gains ("check P, D, gain…") or said "the
    # record does not determine the mass", naming no delay
    folder = _set(tmp_path / "set", true_delay=0.0, stated=stated)
    r = cli("identify", folder, *(() if option is None else ("--delay", option)), code=2)
    assert "or the command delay is wrong: " + named in r.output, r.output


@pytest.mark.parametrize("seed", [21, 22])
def test_idim_biased_by_position_noise_is_warned(tmp_path, seed):
    # the probe's B: 0.1 mm of position noise; IDIM gave m = 1.22 ± 0.12 and 0.73 ± 0.13 kg
    # (truth 2) silently, output error 1.989 ± 0.009
    folder = _set(tmp_path / "set", true_delay=0.0, stated=0.0, noise=1e-4, seed=seed)
    out = _identify(folder)
    assert out["estimator"] == "idim"
    (w,) = [w for w in out["warnings"] if "disagree" in w]
    assert w.startswith("the estimator 'idim' and output error"), w
    assert "--estimator output-error" in w and "trust output error's" in w
    oe = float(re.search(r"m = [-\d.e+]+ ± [\d.e+-]+ kg by IDIM against ([\d.e+-]+)", w)[1])
    # output error's mass is the truth within its stderr ≈ 0.009 kg: 3 % is > 5 stderrs
    assert oe == pytest.approx(2.0, rel=0.03), w
    # and what the warning recommends does give it
    m = _identify(folder, "--estimator", "output-error")["parameters"]["m"]
    assert abs(m["value"] - 2.0) < 5 * m["stderr"], m


def test_idim_biased_at_a_right_ten_ms_delay_is_warned(tmp_path):
    # the probe's K: a right stated delay of 10 ms, 0.1 mm of noise, seed 1: IDIM gave m =
    # 1.568 ± 0.093 kg (truth 2, 4.6 combined stderrs from output error's 1.99 ± 0.005) and no
    # warning: the per-parameter 5-stderr trigger sat just above it
    folder = _set(tmp_path / "set", true_delay=0.01, stated=0.01, noise=1e-4, seed=1)
    out = _identify(folder)
    m = out["parameters"]["m"]
    # the record's IDIM mass is indeed biased: > 4 of its OLS stderrs below the truth (the
    # case); the misfit's robust stderr (docs/adequacy.md, "Tracking") are wider
    assert (2.0 - m["value"]) > 4 * m.get("stderr_white", m["stderr"]), m
    (w,) = [w for w in out["warnings"] if "disagree" in w]
    assert "jointly over m, c, fc, offset" in w and "--estimator output-error" in w, w
    assert "m = " in w.split("per parameter")[1], w  # the per-parameter detail is kept


def _fit_like(values, cov):
    """What :func:`estimator_disagreement` reads of a delay check's fit (free, estimates,
    covariance), with the delay fitted too."""
    from types import SimpleNamespace

    from phoid.methods.estimate import Estimate
    names = ("m", "c", "fc", "offset", "delay")
    est = {k: Estimate(v, float(np.sqrt(cov[i, i])), "") for i, (k, v) in
           enumerate(zip(names, values, strict=True))}
    est["k"] = Estimate(0.0, 0.0, "")
    return SimpleNamespace(free=names, estimates=est, covariance=cov)


@pytest.mark.parametrize(("sds", "warned"), [
    # each parameter 3.5 combined sds off: below the per-parameter limit (the normal's two-sided
    # 1.25e-5 quantile, 4.37) but jointly 4·3.5² = 49 > χ²₄'s upper 5e-5 quantile (25.0)
    ((3.5, 3.5, 3.5, 3.5), True),
    # one parameter 4.6 off, the others 0: jointly 21 < 25, but 4.6 > 4.37 (the probe's K)
    ((4.6, 0.0, 0.0, 0.0), True),
    # each 2 off: 16 < 25 and 2 < 4.37
    ((2.0, 2.0, 2.0, 2.0), False),
])
def test_estimator_disagreement_tests_jointly_and_per_parameter(sds, warned):
    from phoid.methods.estimate import Estimate
    from phoid.methods.tracking_delay import estimator_disagreement
    # IDIM's covariance and output error's each the identity/2 (uncorrelated), so that the
    # combined covariance is the identity and the statistic is the sum of the squared sds
    half = np.eye(5) * 0.5
    fit = _fit_like([2.0, 15.0, 1.5, -0.3, 0.0], half)
    idim = {k: Estimate(fit.estimates[k].value + d, float(np.sqrt(0.5)), "")
            for k, d in zip(("m", "c", "fc", "offset"), sds, strict=True)}
    idim["k"] = Estimate(0.0, 0.0, "")
    idim["delay"] = Estimate(0.0, 0.0, "")
    text = estimator_disagreement(idim, fit, gross=False,
                                  covariance=(["m", "c", "fc", "offset"], half[:4, :4]))
    assert (text is not None) == warned, text
    # a correlation in the sum changes the joint statistic: with all four correlated 0.9 in
    # both, equal shifts are expected together and a joint 49 drops to 4·3.5²/(1 + 3·0.9) =
    # 13.2 < 25
    if sds == (3.5, 3.5, 3.5, 3.5):
        corr = np.eye(5) * 0.5
        corr[:4, :4] += 0.45 * (1.0 - np.eye(4))
        fit = _fit_like([2.0, 15.0, 1.5, -0.3, 0.0], corr)
        assert estimator_disagreement(idim, fit, gross=False,
                                      covariance=(["m", "c", "fc", "offset"], corr[:4, :4])
                                      ) is None


def test_idim_made_unstable_by_noise_names_the_noise_and_output_error(tmp_path):
    # the probe's L: a right delay of 10 ms, 0.3 mm of noise: IDIM's m ≈ 0.5 kg makes the loop
    # unstable and the error named only the gains and the delay; output error gives m = 1.983
    # ± 0.011 kg on it
    folder = _set(tmp_path / "set", true_delay=0.01, stated=0.01, noise=3e-4, seed=1)
    r = cli("identify", folder, code=2)
    assert "the loop is unstable" in r.output, r.output
    assert "biased by the position noise" in r.output and "--estimator output-error" in r.output
    # the noise stated: 0.3 mm (third differences estimate it within a few % on 1000 samples)
    noise = float(re.search(r"noise ≈ ([\d.e+-]+) m rms", r.output)[1])
    assert noise == pytest.approx(3e-4, rel=0.1), r.output
    # and the advice is right: output error identifies the mass within 5 of its stderrs
    m = _identify(folder, "--estimator", "output-error")["parameters"]["m"]
    assert abs(m["value"] - 2.0) < 5 * m["stderr"], m
