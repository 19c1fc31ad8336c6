"""Free-decay identification (method = "free", seed eqs. 2-15): every damping, honest stderr.

The records are the exact closed-form free response (phoid.dynamics.plant.free_response, itself
checked
against the ODE in test_plant.py) plus seeded white noise; the truths are the parameters the
records were made from.
"""

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid import IdentificationError, run_from_arrays, write_experiment
from phoid.cli import app
from phoid.dynamics.plant import free_response
from phoid.io import read_experiment
from phoid.methods.free import identify_free, identify_free_data

runner = CliRunner()


def release(zeta, omega0, *, x0=0.01, v0=0.0, noise_rel=0.0, hold=0.5, duration=10.0,
            fs=1000.0, offset=3e-4, rng=None):
    """A record held at x0 for `hold` s, then released with velocity v0 (exact response);
    white noise of sd `noise_rel` times the largest displacement."""
    t = np.arange(round((hold + duration) * fs)) / fs
    x, _ = free_response(np.maximum(t - hold, 0.0), zeta * omega0, omega0**2, x0, v0)
    sd = noise_rel * float(np.max(np.abs(x)))
    noise = sd * rng.standard_normal(t.size) if noise_rel > 0 else 0.0
    return t, x + offset + noise


def roots_of(zeta, omega0):
    s = zeta * omega0
    q = complex(s * s - omega0 * omega0)
    return sorted([-s + q**0.5, -s - q**0.5], key=lambda r: (-r.real, -r.imag))


def check_within(est, truth, rel):
    # |error| < 3 stderr (the stderr a user can trust) and within `rel` of the truth
    assert abs(est.value - truth) < 3 * est.stderr, (est, truth)
    assert abs(est.value - truth) < rel * truth, (est, truth)


# --------------------------------------------------------------------------------------------
# acceptance (issue 4)


def test_underdamped_acceptance():
    # zeta = 0.02, omega0 = 10 rad/s, noise sd 1 % of the release amplitude
    rng = np.random.default_rng(41)
    t, x = release(0.02, 10.0, noise_rel=0.01, duration=15.0, rng=rng)
    res = identify_free_data([(t, x)])
    check_within(res.zeta, 0.02, 0.01)
    check_within(res.omega0, 10.0, 0.01)
    assert res.regime == "underdamped" and res.warnings == ()
    # the complex pair: real part -sigma, imaginary parts +-omega_d (eq. 4), within 3 stderr
    for got, se, want in zip(res.roots, res.roots_stderr, roots_of(0.02, 10.0), strict=True):
        assert abs(got.real - want.real) < 3 * se[0] and abs(got.imag - want.imag) < 3 * se[1]
    assert res.m is None and res.c is None and res.k is None


def test_overdamped_acceptance():
    # zeta = 2.1, omega0 = sqrt(50) = 7.07 rad/s, noise sd 0.2 % of the largest displacement;
    # a release from a general initial state (x0 and v0: a held mass that is also tapped), so
    # both real exponentials of eq. (2) are well excited
    rng = np.random.default_rng(42)
    w0 = math.sqrt(50.0)
    t, x = release(2.1, w0, x0=0.005, v0=0.3, noise_rel=0.002, rng=rng)
    res = identify_free_data([(t, x)])
    check_within(res.zeta, 2.1, 0.01)
    check_within(res.omega0, w0, 0.01)
    assert res.regime == "overdamped"
    # two real roots, slow one first: -sigma +- sqrt(sigma^2 - omega0^2) (eq. 4)
    for got, se, want in zip(res.roots, res.roots_stderr, roots_of(2.1, w0), strict=True):
        assert got.imag == 0.0 and abs(got.real - want.real) < 3 * se[0]


def test_critically_damped():
    # zeta = 1 exactly: omega_d = 0, eq. (12); the fit passes through it continuously
    rng = np.random.default_rng(43)
    t, x = release(1.0, 8.0, noise_rel=0.002, duration=3.0, rng=rng)
    res = identify_free_data([(t, x)])
    check_within(res.zeta, 1.0, 0.01)
    check_within(res.omega0, 8.0, 0.01)
    # sigma^2 - omega0^2 is 0 within its uncertainty: the split of the roots is undetermined,
    # and said so rather than given a delta-method stderr that does not exist there
    assert res.regime == "critical"
    assert res.roots_stderr == ((None, None), (None, None))
    assert any("critical within its uncertainty" in w for w in res.warnings)


@pytest.mark.parametrize(("zeta", "omega0"), [(0.02, 10.0), (1.0, 8.0), (2.1, math.sqrt(50)),
                                              (1.0 + 1e-9, 8.0), (0.3, 0.0 + 3.0)])
def test_noise_free_records_are_exact(zeta, omega0):
    # exact data: the unified model of eqs. (2)-(15) is the data's own, so sigma and omega0^2
    # come back to near rounding (1e-7 relative: the fit stops at 1e-3 of a stderr that is
    # itself ~1e-13 of the value) in every regime, including an exact and a near-critical one
    t, x = release(zeta, omega0, x0=0.01, v0=0.05, duration=6.0)
    res = identify_free_data([(t, x)])
    assert res.sigma.value == pytest.approx(zeta * omega0, rel=1e-7)
    assert res.k_over_m.value == pytest.approx(omega0**2, rel=1e-7)


# --------------------------------------------------------------------------------------------
# standard errors a user can trust


@pytest.mark.parametrize(
    ("zeta", "omega0", "kw"),
    [
        (0.02, 10.0, {"noise_rel": 0.01}),
        # released from rest: the fast exponential is weakly excited, zeta is ~1 % uncertain
        (2.1, math.sqrt(50.0), {"noise_rel": 0.002}),
    ],
)
def test_stderr_calibration_monte_carlo(zeta, omega0, kw):
    # 100 seeded replicas of one release: the standardised errors of zeta and omega0 must have
    # sd within [0.8, 1.25] (a 100-sample sd has a ~7 % sd: a 3-sigma band around 1) and at
    # most 2 of 100 may fall outside +-3 (expected 0.27 for a calibrated Gaussian stderr)
    t, x_exact = release(zeta, omega0, duration=10.0, **{"noise_rel": 0.0})
    amp = float(np.max(np.abs(x_exact - 3e-4)))
    rng = np.random.default_rng(7)
    z = []
    for _ in range(100):
        x = x_exact + kw["noise_rel"] * amp * rng.standard_normal(t.size)
        res = identify_free_data([(t, x)])
        z.append([(res.zeta.value - zeta) / res.zeta.stderr,
                  (res.omega0.value - omega0) / res.omega0.stderr])
    z = np.array(z)
    assert np.all((z.std(axis=0) > 0.8) & (z.std(axis=0) < 1.25)), z.std(axis=0)
    assert np.all(np.count_nonzero(np.abs(z) > 3, axis=0) <= 2)


# --------------------------------------------------------------------------------------------
# several releases, known mass, record shapes


def test_several_releases_share_the_rates():
    # two releases of the same plant with different noise and initial states: the joint fit
    # weighs each by its own noise and lands within 3 stderr; it is more precise than either
    rng = np.random.default_rng(44)
    a = release(0.05, 6.0, x0=0.01, noise_rel=0.002, rng=rng)
    b = release(0.05, 6.0, x0=-0.004, v0=0.02, noise_rel=0.01, hold=0.0, rng=rng)
    both = identify_free_data([a, b])
    check_within(both.zeta, 0.05, 0.01)
    check_within(both.omega0, 6.0, 0.01)
    single = identify_free_data([a])
    assert both.zeta.stderr < single.zeta.stderr
    assert [r.held for r in both.runs] == [True, False]
    # the first release's held segment was found: released at 0.5 s (detection within ~10 ms)
    assert abs(both.runs[0].release - 0.5) < 0.01


def test_known_mass_gives_c_and_k():
    # c = 2 sigma m and k = omega0^2 m (eqs. 3, 5) with the mass taken as exact
    rng = np.random.default_rng(45)
    t, x = release(0.1, 5.0, noise_rel=0.005, rng=rng)
    bare = identify_free_data([(t, x)])
    res = identify_free_data([(t, x)], mass=2.0)
    assert res.c.value == pytest.approx(2 * bare.sigma.value * 2.0, rel=1e-12)
    assert res.c.stderr == pytest.approx(2 * bare.sigma.stderr * 2.0, rel=1e-12)
    assert res.k.value == pytest.approx(bare.k_over_m.value * 2.0, rel=1e-12)
    assert res.k.stderr == pytest.approx(bare.k_over_m.stderr * 2.0, rel=1e-12)
    s = res.summary()
    assert s["m"] == {"value": 2.0, "stderr": 0.0, "unit": "kg", "source": "given"}
    assert s["c"]["unit"] == "N s/m" and s["k"]["unit"] == "N/m"
    # truth: c = 2 zeta omega0 m = 2 N s/m, k = omega0^2 m = 50 N/m
    assert abs(res.c.value - 2.0) < 3 * res.c.stderr and abs(res.k.value - 50.0) < 3 * res.k.stderr
    with pytest.raises(ValueError, match="mass"):
        identify_free_data([(t, x)], mass=0.0)


def test_summary_keys():
    rng = np.random.default_rng(46)
    s = identify_free_data([release(0.3, 4.0, noise_rel=0.002, rng=rng)]).summary()
    assert s["method"] == "free"
    for key, unit in (("sigma", "1/s"), ("omega0", "rad/s"), ("zeta", ""),
                      ("c_over_m", "1/s"), ("k_over_m", "1/s^2")):
        assert set(s[key]) == {"value", "stderr", "unit"} and s[key]["unit"] == unit
    assert not {"m", "c", "k"} & set(s)  # only ratios are identifiable without a mass
    assert len(s["roots"]) == 2
    assert set(s["roots"][0]) == {"re", "im", "re_stderr", "im_stderr", "unit"}
    # the pair is conjugate: -sigma +- i omega_d
    assert s["roots"][0]["im"] == -s["roots"][1]["im"] > 0
    assert s["roots"][0]["re"] == pytest.approx(-s["sigma"]["value"])
    json.dumps(s)


# --------------------------------------------------------------------------------------------
# bad input


def test_record_that_never_moves():
    rng = np.random.default_rng(47)
    t = np.arange(5000) / 1000.0
    still = (t, 1e-3 + 1e-5 * rng.standard_normal(t.size))
    with pytest.raises(IdentificationError, match=r"run1: x never moves"):
        identify_free_data([still])
    with pytest.raises(IdentificationError, match="never moves"):
        identify_free_data([(t, np.full(t.size, 2e-3))])
    # beside a good release it is set aside with a warning naming it
    good = release(0.05, 6.0, noise_rel=0.002, rng=rng)
    res = identify_free_data([good, still], files=["a.csv", "b.csv"])
    assert [r.used for r in res.runs] == [True, False]
    assert any(w.startswith("b.csv: set aside: x never moves") for w in res.warnings)


def test_too_short_record():
    t = np.arange(10) / 1000.0
    with pytest.raises(IdentificationError, match="too short: 10 samples"):
        identify_free_data([(t, np.sin(t * 100))])


def test_malformed_arrays():
    with pytest.raises(ValueError, match="run1: `x` must be finite"):
        identify_free_data([(np.arange(20.0), np.r_[np.zeros(19), np.nan])])
    with pytest.raises(ValueError, match="same length"):
        identify_free_data([(np.arange(20.0), np.zeros(19))])


def test_free_set_with_feedback_gains_is_refused(tmp_path):
    t, x = release(0.05, 6.0)
    path = write_experiment(tmp_path / "s", [run_from_arrays(t, x, P=1.0, D=0.5)],
                            method="free")
    with pytest.raises(IdentificationError, match=r"run 1 \(run01.csv.gz\): P = 1.0"):
        identify_free(read_experiment(path))
    with pytest.raises(IdentificationError, match="not a free-decay set"):
        identify_free(read_experiment(
            write_experiment(tmp_path / "p", [run_from_arrays(t, x, P=1.0, D=0.5)])))


# --------------------------------------------------------------------------------------------
# the command line


def one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    err = result.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phoid: error:"), result.stderr
    for n in needles:
        assert n in err[0], (n, err[0])


def test_cli_simulate_and_identify_free(tmp_path):
    out = tmp_path / "free"
    r = runner.invoke(app, ["simulate", str(out), "--method", "free", "--m", "1", "--c", "2",
                            "--k", "100", "--duration", "6", "--noise", "1e-5", "--seed", "3"])
    assert r.exit_code == 0, r.output
    manifest = (out / "experiment.toml").read_text()
    assert 'method = "free"' in manifest and "P =" not in manifest and "[loop]" not in manifest
    r = runner.invoke(app, ["identify", str(out), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    # truth: sigma = c/2m = 1 1/s, omega0 = sqrt(k/m) = 10 rad/s, zeta = 0.1 (eqs. 3, 5, 10)
    for key, want in (("sigma", 1.0), ("omega0", 10.0), ("zeta", 0.1)):
        assert abs(s[key]["value"] - want) < 3 * s[key]["stderr"], key
    assert "m" not in s
    r = runner.invoke(app, ["identify", str(out), "--json", "--mass", "1"])
    s = json.loads(r.stdout)
    assert s["m"]["value"] == 1.0 and abs(s["k"]["value"] - 100) < 3 * s["k"]["stderr"]
    r = runner.invoke(app, ["identify", str(out), "--plots", str(tmp_path / "p")])
    assert r.exit_code == 0 and "ζ" in r.stdout and "--mass" in r.stdout
    assert [p.name for p in (tmp_path / "p").glob("*.png")] == ["run01.png"]  # <stem>.png


def test_cli_manifest_mass_and_override(tmp_path):
    out = tmp_path / "free"
    r = runner.invoke(app, ["simulate", str(out), "--method", "free", "--m", "2", "--c", "40",
                            "--k", "100", "--v0", "0.1", "--write-mass", "--noise", "1e-6",
                            "--seed", "4", "--duration", "4"])
    assert r.exit_code == 0, r.output
    assert "mass = 2.0" in (out / "experiment.toml").read_text()
    s = json.loads(runner.invoke(app, ["identify", str(out), "--json"]).stdout)
    assert s["regime"] == "overdamped"  # zeta = 40 / (2 sqrt(200)) = 1.41
    assert abs(s["c"]["value"] - 40) < 3 * s["c"]["stderr"]
    s2 = json.loads(runner.invoke(app, ["identify", str(out), "--json", "--mass", "4"]).stdout)
    assert s2["c"]["value"] == pytest.approx(2 * s["c"]["value"], rel=1e-12)


def test_cli_bad_inputs(tmp_path):
    out = tmp_path / "free"
    assert runner.invoke(app, ["simulate", str(out), "--method", "free",
                               "--duration", "3"]).exit_code == 0
    one_line_error(runner.invoke(app, ["identify", str(out), "--mass", "-1"]), "--mass")
    one_line_error(runner.invoke(app, ["identify", str(out), "--delay", "0.1"]),
                   "--delay does not apply to free sets")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "x"), "--method", "free",
                                       "--P", "1"]), "--P does not apply to --method free")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "y"), "--method", "free",
                                       "--omega", "3"]), "--omega")
    one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "z"), "--method", "nope"]),
                   "method")
    # a free set whose only record never moves: one line naming the file
    rng = np.random.default_rng(5)
    t = np.arange(3000) / 1000.0
    still = write_experiment(tmp_path / "still",
                             [run_from_arrays(t, 1e-5 * rng.standard_normal(t.size))],
                             method="free")
    one_line_error(runner.invoke(app, ["identify", str(still)]), "run01.csv.gz",
                   "never moves")
    # --mass on a pho set
    pho = tmp_path / "pho"
    assert runner.invoke(app, ["simulate", str(pho), "--P", "1,5", "--D", "1",
                               "--duration", "4"]).exit_code == 0
    one_line_error(runner.invoke(app, ["identify", str(pho), "--mass", "2"]), "--mass")
