"""Forced harmonic (sine-sweep) identification (method = "forced", seed eqs. 16-22).

Records come from phoid's own simulator (phoid.simulate with P = D = 0 and a sinusoidal force,
checked against the closed form in test_forced_simulation_is_exact below) plus seeded noise;
the truths are the plant the records were made from. The exact dynamic stiffness of eq. (20)
is Z(omega) = k - m omega^2 + i c omega = R e^{i rho}.
"""

import gzip
import json
import math
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid import IdentificationError, Plant, run_from_arrays, write_experiment
from phoid.cli import app
from phoid.dynamics.plant import free_response
from phoid.io import read_experiment
from phoid.methods.forced import (
    fit_response,
    identify_forced,
    identify_forced_data,
    simulate_forced,
    two_frequency,
)

runner = CliRunner()
PLANT = Plant(2.0, 1.0, 64.0)  # the seed paper's plant; the acceptance set


def Z_exact(w, m=2.0, c=1.0, k=64.0):
    return k - m * np.asarray(w) ** 2 + 1j * c * np.asarray(w)


def data_of(runs, noise=0.0, rng=None, force_noise=0.0):
    out = []
    for r in runs:
        x = r.x + (noise * rng.standard_normal(r.t.size) if noise else 0.0)
        F = r.F + (force_noise * rng.standard_normal(r.t.size) if force_noise else 0.0)
        out.append((r.t, x, F))
    return out


# --------------------------------------------------------------------------------------------
# eqs. (20) and (22)


def test_two_frequency_formulas_exact():
    # eq. (22) with ERRATA 2 on exact R, rho (eq. 20) returns m, c, k to rounding
    for wi, wj in ((2.0, 14.0), (5.0, 6.0), (9.0, 3.0)):
        zi, zj = Z_exact(wi), Z_exact(wj)
        m, c, k = two_frequency(wi, abs(zi), np.angle(zi), wj, abs(zj), np.angle(zj))
        assert (m, c, k) == pytest.approx((2.0, 1.0, 64.0), rel=1e-12)


def test_eq22b_as_printed_is_not_the_mean():
    # ERRATA 2: eq. (22b) as printed, (w_i R_j sin rho_j + w_i R_j sin rho_j)/(2 w_i w_j),
    # uses run j twice; the corrected form is the mean of R sin rho / w over the two runs.
    # Two runs whose own damping estimates differ (1.0 and 1.2 N s/m, as noisy runs would):
    wi, wj = 3.0, 9.0
    zi, zj = Z_exact(wi, c=1.0), Z_exact(wj, c=1.2)
    Ri, pi, Rj, pj = abs(zi), np.angle(zi), abs(zj), np.angle(zj)
    _m, c, _k = two_frequency(wi, Ri, pi, wj, Rj, pj)
    printed = (wi * Rj * math.sin(pj) + wi * Rj * math.sin(pj)) / (2 * wi * wj)
    assert c == pytest.approx(1.1, rel=1e-12)  # the mean, as the text under eq. (22b) says
    assert printed == pytest.approx(1.2, rel=1e-12)  # run j's value alone


def test_two_frequency_rejects_equal_frequencies():
    with pytest.raises(ValueError, match="must differ"):
        two_frequency(5.0, 10.0, 0.5, 5.0, 11.0, 0.6)


def test_fit_response_exact_and_errors():
    # GLS on eq. (20) with exact Z at five frequencies: exact m, c, k, chi2 ~ 0; with an added
    # mass per run, m is the mass without it
    w = np.array([2.0, 4.0, 6.0, 8.0, 10.0])
    cov = np.tile(np.eye(2) * 1e-4, (5, 1, 1))
    fit = fit_response(w, Z_exact(w), cov)
    assert (fit.m, fit.c, fit.k) == pytest.approx((2.0, 1.0, 64.0), rel=1e-12)
    assert fit.chi2 < 1e-20 and fit.dof == 7
    added = np.array([0.0, 0.5, 0.5, 1.0, 0.0])
    fit = fit_response(w, Z_exact(w) - added * w**2, cov, added_mass=added)
    assert (fit.m, fit.c, fit.k) == pytest.approx((2.0, 1.0, 64.0), rel=1e-12)
    # the stderr is the GLS one: with equal, independent errors s on Re Z and Im Z, c's is
    # s / sqrt(sum w^2) (the Im Z = c w line alone)
    assert fit.stderr[1] == pytest.approx(1e-2 / math.sqrt(float(w @ w)), rel=1e-10)
    with pytest.raises(IdentificationError, match="one frequency"):
        fit_response(np.array([5.0, 5.0]), Z_exact([5.0, 5.0]), np.tile(np.eye(2), (2, 1, 1)))


def test_forced_simulation_is_exact():
    # phoid's simulator against the closed form: steady state Im(B e^{i w t}/Z) plus the free
    # response of eq. (2) that brings it to rest at t = 0 (state and derivative continuous)
    w = 5.0
    run = simulate_forced(PLANT, [w], B=1.0, duration=10.0, fs=200.0)[0]
    H = 1.0 / Z_exact(w)
    xp = np.imag(H * np.exp(1j * w * run.t))
    xh, _ = free_response(run.t, 0.25, 32.0, -float(np.imag(H)), -float(np.imag(1j * w * H)))
    assert np.max(np.abs(run.x - (xp + xh))) < 1e-12
    assert np.array_equal(run.F, np.sin(w * run.t)) and run.omega == w and run.B == 1.0


# --------------------------------------------------------------------------------------------
# acceptance (issue 4)


@pytest.fixture(scope="module")
def acceptance():
    # m = 2, c = 1, k = 64; B = 1 N; 8 frequencies 2..14 rad/s; 40 s at 500 Hz; 10 um noise
    runs = simulate_forced(PLANT, np.linspace(2.0, 14.0, 8), B=1.0, duration=40.0, fs=500.0,
                           noise=1e-5, rng=np.random.default_rng(2024))
    return runs, identify_forced_data(data_of(runs))


def test_acceptance_mck(acceptance):
    _runs, res = acceptance
    for q, want in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        est = getattr(res, q)
        assert abs(est.value - want) < 3 * est.stderr, (q, est)
        assert abs(est.value - want) <= 0.005 * want, (q, est)
    # the frequencies straddle the resonance and the transient (sigma = 0.25 1/s: still near
    # the noise at the end of the resonant run) is modelled, so there is nothing to warn about
    assert res.warnings == ()
    assert res.transient_fitted
    assert res.transient == pytest.approx((0.25, 32.0), rel=1e-3)


def test_acceptance_per_run_R_rho(acceptance):
    # each run's R e^{i rho} against eq. (20)'s exact Z: 16 numbers, all within 4 stderr
    # (P(any of 16 beyond 4 sigma) ~ 1e-3)
    runs, res = acceptance
    for run, r in zip(runs, res.runs, strict=True):
        z = Z_exact(run.omega)
        assert r.omega == pytest.approx(run.omega, rel=1e-12)  # noise-free F: exact
        assert r.B == pytest.approx(1.0, rel=1e-10)
        assert abs(r.R - abs(z)) < 4 * r.R_stderr
        assert abs(r.rho - np.angle(z)) < 4 * r.rho_stderr
        assert 0 < r.rho < math.pi  # a passive plant: x lags F by 0..pi


def test_summary_follows_the_contract(acceptance):
    _runs, res = acceptance
    s = json.loads(json.dumps(res.summary()))
    assert s["method"] == "forced"
    for q, unit in (("m", "kg"), ("c", "N s/m"), ("k", "N/m")):
        assert set(s[q]) == {"value", "stderr", "unit"} and s[q]["unit"] == unit
    run = s["runs"][0]
    assert {"file", "omega", "omega_stderr", "R", "R_stderr", "rho", "rho_stderr"} <= set(run)
    assert s["warnings"] == []
    # omega0 and zeta of the plant: sqrt(32) rad/s and 1/(2 sqrt(128))
    assert abs(s["omega0"]["value"] - math.sqrt(32)) < 3 * s["omega0"]["stderr"]


# --------------------------------------------------------------------------------------------
# standard errors a user can trust


def test_stderr_calibration_monte_carlo():
    # 100 seeded replicas of a smaller sweep (6 frequencies, 20 s at 200 Hz, 0.1 mm noise on x,
    # 1 % noise on F, the force switched on after 1 s of rest: every path is exercised). The
    # standardised errors of m, c, k must have sd within [0.8, 1.25] (a 3-sigma band for a
    # 100-sample sd) and at most 2 of 100 outside +-3 (0.27 expected if calibrated).
    base = simulate_forced(PLANT, np.linspace(2.0, 14.0, 6), duration=20.0, fs=200.0,
                           hold=1.0)
    rng = np.random.default_rng(99)
    z = []
    for _ in range(100):
        res = identify_forced_data(data_of(base, 1e-4, rng, force_noise=0.01))
        z.append([(res.m.value - 2) / res.m.stderr, (res.c.value - 1) / res.c.stderr,
                  (res.k.value - 64) / res.k.stderr])
    z = np.array(z)
    sd = z.std(axis=0)
    assert np.all((sd > 0.8) & (sd < 1.25)), sd
    assert np.all(np.count_nonzero(np.abs(z) > 3, axis=0) <= 2), z


# --------------------------------------------------------------------------------------------
# transients, onsets, other plants


@pytest.mark.parametrize(
    ("plant", "omegas"),
    [
        (Plant(1.0, 30.0, 100.0), np.linspace(2.0, 30.0, 6)),  # overdamped, zeta = 1.5
        (Plant(1.0, 0.2, 100.0), np.linspace(5.0, 15.0, 6)),  # zeta = 0.01: rings throughout
    ],
)
def test_other_plants(plant, omegas):
    runs = simulate_forced(plant, omegas, duration=12.0, fs=500.0, hold=0.3, x0=1e-3,
                           offset=2e-3, noise=1e-5, rng=np.random.default_rng(5))
    res = identify_forced_data(data_of(runs))
    for q in "mck":
        est, want = getattr(res, q), getattr(plant, q)
        assert abs(est.value - want) < 3 * est.stderr, (q, est)
    # the record starts with 0.3 s of rest: the window begins after the force's onset
    assert all(0.3 < r.t_start < 0.3 + 2 * math.pi / r.omega + 0.01 for r in res.runs)
    if plant.zeta < 0.1:
        # sigma = 0.1 1/s: the start-up transient is still far above the noise after 12 s
        assert any("has not died out" in w for w in res.warnings)
        assert not all(r.settled for r in res.runs)


def test_records_already_in_steady_state():
    # x recorded after the transient has died (the exact steady state Im(B e^{iwt}/Z), eq. 17,
    # plus noise): no transient to fit, its rates are left alone, and m, c, k come out
    rng = np.random.default_rng(9)
    t = np.arange(4000) / 200.0
    data = []
    for w in (3.0, 5.0, 7.0, 11.0):
        x = np.imag(np.exp(1j * w * t) / Z_exact(w)) + 1e-5 * rng.standard_normal(t.size)
        data.append((t, x, np.sin(w * t)))
    res = identify_forced_data(data)
    assert not res.transient_fitted and res.warnings == ()
    for q, want in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(res, q).value - want) < 3 * getattr(res, q).stderr
    assert all(r.settled and r.settle_time == r.t_start for r in res.runs)


def test_all_frequencies_below_resonance_warns():
    runs = simulate_forced(PLANT, [1.0, 2.0, 3.0, 4.0], duration=30.0, fs=200.0, noise=1e-5,
                           rng=np.random.default_rng(6))
    res = identify_forced_data(data_of(runs))
    assert any("lie below the resonance" in w for w in res.warnings)
    for q, want in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(res, q).value - want) < 3 * getattr(res, q).stderr


def test_manifest_values_are_checked_against_F():
    runs = simulate_forced(PLANT, [3.0, 8.0], duration=10.0, fs=200.0)
    res = identify_forced_data(data_of(runs), omega=[3.0, 8.1], B=[1.0, 1.5])
    w = [x for x in res.warnings if "manifest" in x]
    assert len(w) == 2 and all(x.startswith("run2") for x in w)
    assert "omega = 8.1" in w[0] and "B = 1.5" in w[1]


# --------------------------------------------------------------------------------------------
# bad input


def test_single_frequency_is_an_error():
    runs = simulate_forced(PLANT, [5.0, 5.0], duration=10.0, fs=200.0)
    with pytest.raises(IdentificationError, match=r"one frequency .* undetermined"):
        identify_forced_data(data_of(runs))


def test_F_missing_constant_or_not_sinusoidal():
    t = np.arange(4000) / 200.0
    x = 1e-3 * np.sin(3 * t)
    with pytest.raises(IdentificationError, match="run1: missing column 'F'"):
        identify_forced_data([(t, x, None)])
    with pytest.raises(IdentificationError, match="run1: column 'F' is constant"):
        identify_forced_data([(t, x, np.ones_like(t))])
    square = np.sign(np.sin(3 * t))  # its fundamental leaves 48 % rms unexplained
    with pytest.raises(IdentificationError, match="run1: column 'F' is not sinusoidal"):
        identify_forced_data([(t, x, square)])


def test_run_that_never_moves_is_set_aside():
    runs = simulate_forced(PLANT, [3.0, 6.0, 9.0], duration=10.0, fs=200.0)
    data = data_of(runs)
    rng = np.random.default_rng(8)
    t, _x, F = data[1]
    data[1] = (t, 1e-6 * rng.standard_normal(t.size), F)
    res = identify_forced_data(data)
    assert [r.used for r in res.runs] == [True, False, True]
    assert any(w.startswith("run2: set aside: x never moves") for w in res.warnings)


# --------------------------------------------------------------------------------------------
# the command line


def one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phoid: error:"), result.stderr
    assert "Traceback" not in result.output
    for n in needles:
        assert n in err[0], (n, err[0])


@pytest.fixture(scope="module")
def cli_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("forced") / "sweep"
    r = runner.invoke(app, ["simulate", str(out), "--method", "forced", "--omega", "2:14:6",
                            "--duration", "20", "--fs", "250", "--noise", "1e-5",
                            "--offset", "1e-3", "--seed", "12"])
    assert r.exit_code == 0, r.output
    return out


def test_cli_simulate_writes_a_forced_set(cli_set):
    exp = read_experiment(cli_set)
    assert exp.method == "forced" and len(exp.runs) == 6 and exp.delay is None
    assert all(r.F is not None and r.P is None for r in exp.runs)
    assert [r.omega for r in exp.runs] == pytest.approx(np.linspace(2, 14, 6).tolist())
    # the default 0.2 s of rest: F = 0 there, B sin(omega (t - 0.2)) after
    r = exp.runs[0]
    assert np.all(r.F[r.t < 0.2] == 0.0)
    assert r.F[r.t >= 0.2] == pytest.approx(np.sin(2.0 * (r.t[r.t >= 0.2] - 0.2)), abs=1e-12)
    res = identify_forced(exp)
    for q, want in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(getattr(res, q).value - want) < 3 * getattr(res, q).stderr


def test_cli_identify_json_text_plots(cli_set, tmp_path):
    r = runner.invoke(app, ["identify", str(cli_set), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["method"] == "forced" and len(s["runs"]) == 6
    for q, want in (("m", 2.0), ("c", 1.0), ("k", 64.0)):
        assert abs(s[q]["value"] - want) < 3 * s[q]["stderr"]
    r = runner.invoke(app, ["identify", str(cli_set), "--plots", str(tmp_path / "p")])
    assert r.exit_code == 0 and "m = " in r.stdout and "ρ ± stderr" in r.stdout
    names = sorted(p.name for p in (tmp_path / "p").glob("*.png"))
    assert {"lines.png", "mk-ellipse.png"} <= set(names)
    assert len(names) == 8  # 6 runs (<stem>.png) + the eq. (20) lines + the (m, k) ellipse


def test_cli_forced_bad_inputs(cli_set, tmp_path):
    # a data file without F: one line naming the file and the column
    bad = tmp_path / "noF"
    shutil.copytree(cli_set, bad)
    f = bad / "run03.csv.gz"
    lines = gzip.decompress(f.read_bytes()).decode().splitlines()
    f.write_bytes(gzip.compress(("\n".join(",".join(ln.split(",")[:2]) for ln in lines)
                                 + "\n").encode()))
    one_line_error(runner.invoke(app, ["identify", str(bad)]), "run03.csv.gz", "'F'")
    # F not sinusoidal (a square wave)
    bad = tmp_path / "square"
    shutil.copytree(cli_set, bad)
    f = bad / "run02.csv.gz"
    rows = [ln.split(",") for ln in gzip.decompress(f.read_bytes()).decode().splitlines()]
    body = [f"{t},{x},{1.0 if math.sin(4.4 * float(t)) >= 0 else -1.0}" for t, x, _ in rows[1:]]
    f.write_bytes(gzip.compress(("t,x,F\n" + "\n".join(body) + "\n").encode()))
    one_line_error(runner.invoke(app, ["identify", str(bad)]), "run02.csv.gz", "'F'",
                   "not sinusoidal")
    # a single frequency (with noise: two noise-free runs at one frequency are byte-identical,
    # which the reader refuses as a copy before the method sees them)
    one = tmp_path / "one"
    assert runner.invoke(app, ["simulate", str(one), "--method", "forced", "--omega", "5,5",
                               "--duration", "8", "--fs", "200", "--noise", "1e-6",
                               "--seed", "1"]).exit_code == 0
    one_line_error(runner.invoke(app, ["identify", str(one)]), "one frequency")
    # options that do not apply
    one_line_error(runner.invoke(app, ["identify", str(cli_set), "--mass", "2"]), "--mass")
    one_line_error(runner.invoke(app, ["identify", str(cli_set), "--estimator", "ols"]),
                   "--estimator")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "a"), "--method", "forced",
                                       "--D", "1"]), "--D does not apply")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "b"), "--B", "2"]),
                   "--B does not apply to --method pho")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "c"), "--method", "forced",
                                       "--omega", "1e6", "--fs", "100"]), "Nyquist")


def test_forced_set_with_gains_is_refused(tmp_path):
    runs = simulate_forced(PLANT, [3.0, 6.0], duration=5.0, fs=200.0)
    runs = [run_from_arrays(r.t, r.x, F=r.F, P=1.0, D=0.0) for r in runs]
    path = write_experiment(tmp_path / "s", runs, method="forced")
    with pytest.raises(IdentificationError, match=r"run 1 \(run01.csv.gz\): P = 1.0"):
        identify_forced(read_experiment(path))
