"""Does a tracking record's command u already contain its additive input w? (issue 27, item 5)

Records are made here by an independent loop simulator (``_loop``: the plant m ẍ + c ẋ = F
advanced by its exact zero-order-hold map, scipy.linalg.expm, one controller period at a time,
the controller's law written out), in both conventions: u is the controller's output u_c alone
and F = G·(sat(u_c) + w), or u = u_c + g·w and F = G·sat(u). phoid must tell which from the
record, with g, and identify and replay without counting w twice. Where ../shared is beside the
checkout, the EMPS benchmark's cross-test is run as a user would (``phoid identify`` on the
estimation record, ``phoid simulate --replay`` on the validation record) against issue 27's
acceptance.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED
from scipy.linalg import expm

import phoid.io
from phoid.dynamics.controller import SampledController
from phoid.methods.tracking_semantics import measure_w_in_u
from phoid.methods.tracking_validation import validate_tracking

ROOT = Path(__file__).resolve().parents[1]
EMPS = SHARED / "data" / "emps"

T = 1e-3  # s, the loop's period
TRUTH = {"m": 2.0, "c": 15.0}  # kg, N s/m: the simulated plant (k = 0, no friction)
P, D, K, G = 4000.0, 60.0, 1.0, 1.0  # the loop's gains (force units: G = 1 N per unit)
SATURATION = 200.0  # command units: the loop never reaches it in these records
U_NOISE = 0.05  # command units rms: the recorded u's own noise (an ADC's), white
X_NOISE = 1e-6  # m rms: the sensor's noise, which the controller reads


def _pulses(n: int, rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """0 or ``amplitude`` in blocks of 50–400 samples (like the EMPS record's pulses_N)."""
    w = np.zeros(n)
    i, on = 0, False
    while i < n:
        k = int(rng.integers(50, 400))
        if on:
            w[i: i + k] = amplitude
        on = not on
        i += k
    return w


def _loop(contains: bool, gain: float, *, n: int = 3000, amplitude: float = 2.0,
          seed: int = 0) -> dict:
    """A tracking record simulated independently of phoid (module docstring)."""
    rng = np.random.default_rng(seed)
    t = T * np.arange(n)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    w = _pulses(n, rng, amplitude)
    m, c = TRUTH["m"], TRUTH["c"]
    # exact ZOH map of ẋ = v, v̇ = (F − c v)/m over T
    M = np.zeros((3, 3))
    M[0, 1], M[1, 1], M[1, 2] = 1.0, -c / m, 1.0 / m
    E = expm(M * T)
    Phi, Gam = E[:2, :2], E[:2, 2]
    y = np.zeros(2)
    xm = np.empty(n)
    u_rec = np.empty(n)
    for k in range(n):
        xm[k] = y[0] + X_NOISE * rng.standard_normal()
        vhat = (xm[k] - xm[max(k - 2, 0)]) / (2 * T) if k >= 2 else 0.0
        uc = K * (P * (r[k] - xm[k]) - D * vhat)
        if contains:
            u = uc + gain * w[k]
            F = G * float(np.clip(u, -SATURATION, SATURATION))
        else:
            u = uc
            F = G * (float(np.clip(u, -SATURATION, SATURATION)) + w[k])
        u_rec[k] = u + U_NOISE * rng.standard_normal()
        y = Phi @ y + Gam * F
    return {"t": t, "x": xm, "r": r, "u": u_rec, "w": w}


def _ctrl(P_: float = P) -> SampledController:
    return SampledController(sample_time=T, P=P_, D=D, gain=K, command_gain=G,
                             velocity="central-difference", saturation=SATURATION)


def _write(folder: Path, rec: dict, **loop) -> Path:
    run = phoid.io.run_from_arrays(rec["t"], rec["x"], r=rec["r"], u=rec["u"], w=rec["w"], P=P,
                                   D=D, gain=K, command_gain=G, index=1)
    phoid.io.write_experiment(folder, [run], method="tracking", fixed={"k": 0.0, "fc": 0.0},
                              loop={"sample_time": T, "velocity": "central-difference",
                                    "saturation": SATURATION, "delay": 0.0, **loop})
    return folder


def _cli(*args: object, cwd: Path, code: int = 0) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "phoid.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == code, proc.stderr
    return proc


def _set_loop(manifest: Path, **keys: object) -> None:
    """Add keys to the [loop] table of a manifest phoid wrote."""
    text = manifest.read_text(encoding="utf-8")
    lines = "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())
    manifest.write_text(text.replace("[loop]\n", "[loop]\n" + lines, 1), encoding="utf-8")


# --------------------------------------------------------------------------------------------
# the measurement


@pytest.mark.parametrize("gain", [1.0, 0.8, -0.5])
def test_u_that_contains_w_is_found_with_its_gain(gain):
    rec = _loop(True, gain)
    got = measure_w_in_u(rec["u"], rec["w"], rec["x"], rec["r"], _ctrl())
    assert got.status == "contains"
    # the gain within 3 of its stderrs (the u noise is white: the stderr is its own)
    assert abs(got.gain - gain) <= 3 * got.stderr
    # and the stderr is the one the noise gives: σ_u/sqrt(Σw²), within a factor 2 (Newey–West
    # estimates it from the residual)
    on = rec["w"] != 0
    expected = U_NOISE / math.sqrt(float(rec["w"][on] @ rec["w"][on]))
    assert expected / 2 < got.stderr < 2 * expected
    assert got.rms_fit == pytest.approx(U_NOISE, rel=0.2)  # only the u noise is left


def test_u_that_does_not_contain_w_is_found_so():
    rec = _loop(False, 1.0)
    got = measure_w_in_u(rec["u"], rec["w"], rec["x"], rec["r"], _ctrl())
    assert got.status == "absent"
    assert abs(got.gain) <= 3 * got.stderr  # 0 within 3 stderr
    assert got.to_dict()["status"] == "absent"


def test_wrong_gains_leave_it_undetermined():
    rec = _loop(True, 1.0)
    got = measure_w_in_u(rec["u"], rec["w"], rec["x"], rec["r"], _ctrl(P_=2 * P))
    assert got.status == "undetermined"
    assert "controller law does not reproduce" in got.reason and "check P, D" in got.reason


def test_w_too_small_to_tell_is_undetermined():
    # pulses of 0.005 against the u noise of 0.05: neither "contains" nor "absent" is shown
    rec = _loop(False, 1.0, amplitude=0.005)
    got = measure_w_in_u(rec["u"], rec["w"], rec["x"], rec["r"], _ctrl())
    assert got.status == "undetermined" and "too small" in got.reason


def test_w_zero_almost_everywhere_is_undetermined():
    rec = _loop(True, 1.0)
    w = np.zeros_like(rec["w"])
    w[100:105] = 2.0
    got = measure_w_in_u(rec["u"], w, rec["x"], rec["r"], _ctrl())
    assert got.status == "undetermined" and "only 5 usable sample(s)" in got.reason


def test_a_w_of_zeros_says_nothing_and_absurd_values_are_undetermined():
    from phoid.methods.tracking_semantics import command_input_semantics

    rec = _loop(True, 1.0, n=300)
    zeros = np.zeros_like(rec["w"])
    got = command_input_semantics({}, rec["u"], zeros, rec["x"], rec["r"], _ctrl())
    assert got is not None and not got.contains and got.warning is None
    # values that overflow the arithmetic: no exception, no RuntimeWarning (pytest makes
    # warnings errors), an undetermined measurement that says why
    free = SampledController(sample_time=T, P=P, D=D, velocity="central-difference")
    huge = measure_w_in_u(np.full(300, 1e300), np.full(300, 1e300), rec["x"], rec["r"], free)
    assert huge.status == "undetermined" and "overflows" in huge.reason
    # with the saturation, such a u sits beyond it everywhere: said so
    clipped = measure_w_in_u(np.full(300, 1e300), np.full(300, 1e300), rec["x"], rec["r"],
                             _ctrl())
    assert "298 more where u or the controller's command reaches the saturation ±200" \
        in clipped.reason  # every sample but the estimator's first 2


def test_validation_force_counts_w_once():
    # a record whose u holds w: the measured force is G·sat(u), not G·(sat(u) + w)
    n = 100
    t = T * np.arange(n)
    u = np.linspace(-3.0, 3.0, n)
    w = np.where(np.arange(n) % 20 < 10, 2.0, 0.0)
    sim = type("S", (), {"t": t, "x": np.zeros(n), "v": np.zeros(n), "force": 4.0 * np.clip(
        u, -2.5, 2.5)})()
    val = validate_tracking(t, np.zeros(n), np.zeros(n), sim, u=u, w=w, command_gain=4.0,
                            saturation=2.5, velocity="central-difference", trim=0,
                            u_contains_w=True)
    assert val.error("force").relative_error == 0.0
    other = validate_tracking(t, np.zeros(n), np.zeros(n), sim, u=u, w=w, command_gain=4.0,
                              saturation=2.5, velocity="central-difference", trim=0)
    assert other.error("force").relative_error > 10.0  # w added again
    with pytest.raises(ValueError, match="u_contains_w: must be True or False"):
        validate_tracking(t, np.zeros(n), np.zeros(n), sim, u=u, w=w, trim=0,
                          velocity="central-difference", u_contains_w="no")


# --------------------------------------------------------------------------------------------
# identify and replay through the CLI


@pytest.mark.parametrize("contains", [True, False])
def test_identify_and_replay_use_the_measured_convention(tmp_path, contains):
    rec = _loop(contains, 0.8 if contains else 1.0)
    folder = _write(tmp_path / "set", rec)
    out = json.loads(_cli("identify", folder, "--json", cwd=tmp_path).stdout)
    (entry,) = out["w_in_u"]
    assert entry["u_contains_w"] is contains and entry["source"] == "measured"
    assert entry["measured"]["status"] == ("contains" if contains else "absent")
    if contains:
        assert abs(entry["gain"] - 0.8) <= 3 * entry["measured"]["stderr"]
        assert any("already contains the additive input w" in w for w in out["warnings"])
    else:
        assert entry["gain"] == 1.0  # the default: w in command units
        assert not any("additive input w" in w for w in out["warnings"])
    # IDIM on the force counted once: m within 3 % (IDIM's filter bias on a noise-free fast
    # reference is ≈ 1 %, tests/test_tracking_cli.py); with w counted twice (below) it is not
    assert out["estimator"] == "idim"
    assert out["parameters"]["m"]["value"] == pytest.approx(TRUTH["m"], rel=0.03)
    # the replay with the truth follows the record to its noise: the tracking error's
    # relative error is the sensor noise over the tracking error, ≪ 5 %; the force's is the
    # u noise's (0.05 against forces of tens of N), ≪ 5 %
    rep = json.loads(_cli("simulate", tmp_path / "sim", "--replay", folder, "--m", TRUTH["m"],
                          "--c", TRUTH["c"], "--json", cwd=tmp_path).stdout)
    sig = rep["validation"][0]["signals"]
    assert sig["tracking error"]["relative_error_percent"] < 5.0
    assert sig["force"]["relative_error_percent"] < 5.0
    assert rep["w_in_u"][0]["u_contains_w"] is contains
    # the written set states the convention it was simulated with, and reads back so
    text = (tmp_path / "sim" / "experiment.toml").read_text(encoding="utf-8")
    assert f"u_contains_w = {'true' if contains else 'false'}" in text
    back = json.loads(_cli("simulate", tmp_path / "sim2", "--replay", tmp_path / "sim", "--m",
                           TRUTH["m"], "--c", TRUTH["c"], "--json", cwd=tmp_path).stdout)
    assert back["w_in_u"][0]["source"] == "stated"
    assert back["w_in_u"][0]["measured"]["status"] == ("contains" if contains else "absent")
    assert not any("u_contains_w" in w or "additive input w" in w for w in back["warnings"])


def test_a_statement_the_record_contradicts_is_warned(tmp_path):
    from phoid.methods.tracking_identification import identify_tracking

    def identify(folder: Path) -> dict:  # the API, without the delay check's extra fit
        return identify_tracking(phoid.io.read_experiment(folder), check_delay=False).summary()

    rec = _loop(True, 1.0)
    out = identify(_write(tmp_path / "set", rec, u_contains_w=False))
    assert out["w_in_u"][0]["source"] == "stated" and out["w_in_u"][0]["u_contains_w"] is False
    assert any("u_contains_w = false, but the record says u already contains w" in w
               for w in out["warnings"])
    # the stated convention is used (the user asked for it): w counted twice in IDIM's force,
    # whose relative error is then the pulses' share of it (≈ 30 %) rather than the filters'
    # and the u noise's (≈ 4 %, the same record identified unstated)
    twice = out["fit"]["relative_error_percent"]
    once = identify(_write(tmp_path / "once", rec))["fit"]["relative_error_percent"]
    assert twice > 2 * once
    # the opposite statement on the opposite record, seen by the replay (which checks alike)
    replay = ("--m", TRUTH["m"], "--c", TRUTH["c"], "--json")
    folder = _write(tmp_path / "set2", _loop(False, 1.0), u_contains_w=True)
    out = json.loads(_cli("simulate", tmp_path / "s2", "--replay", folder, *replay,
                          cwd=tmp_path).stdout)
    assert any("u_contains_w = true, but the record says u does not contain w" in w
               for w in out["warnings"])
    # a stated gain far from the measured one
    folder = _write(tmp_path / "set3", _loop(True, 0.8), w_in_u_gain=1.0)
    out = json.loads(_cli("simulate", tmp_path / "s3", "--replay", folder, *replay,
                          cwd=tmp_path).stdout)
    assert out["w_in_u"][0]["gain"] == 1.0 and out["w_in_u"][0]["gain_source"] == "stated"
    assert out["w_in_u"][0]["u_contains_w"] is True  # the gain alone implies it
    assert any("w_in_u_gain = 1, but the record says" in w for w in out["warnings"])


@pytest.mark.parametrize(("keys", "expected"), [
    ({"u_contains_w": "yes"}, "key 'u_contains_w' must be true or false"),
    ({"u_contains_w": 1}, "key 'u_contains_w' must be true or false"),
    ({"w_in_u_gain": 0}, "key 'w_in_u_gain' (command units per unit of w) is 0"),
    ({"w_in_u_gain": "1.0"}, "key 'w_in_u_gain' must be a number"),
    ({"w_in_u_gain": 1.0, "u_contains_w": False}, "but u_contains_w = false"),
])
def test_bad_statements_are_one_line_errors(tmp_path, keys, expected):
    folder = _write(tmp_path / "set", _loop(True, 1.0, n=300))
    _set_loop(folder / "experiment.toml", **keys)
    r = _cli("identify", folder, cwd=tmp_path, code=2)
    assert expected in r.stderr and "[loop]" in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def test_a_stated_convention_whose_gain_cannot_be_measured_says_so():
    from phoid.methods.tracking_semantics import command_input_semantics

    rec = _loop(True, 1.0, n=300, amplitude=0.005)  # pulses far below the u noise
    got = command_input_semantics({"u_contains_w": True}, rec["u"], rec["w"], rec["x"],
                                  rec["r"], _ctrl())
    assert got.contains and got.gain == 1.0 and got.gain_source == "default"
    assert "cannot be measured from the record" in got.warning
    assert "w_in_u_gain" in got.warning


def test_u_contains_w_on_a_run_without_w_names_the_run(tmp_path):
    rec = _loop(True, 1.0, n=300)
    run = phoid.io.run_from_arrays(rec["t"], rec["x"], r=rec["r"], u=rec["u"], P=P, D=D,
                                   gain=K, command_gain=G, index=1)
    folder = tmp_path / "set"
    phoid.io.write_experiment(folder, [run], method="tracking", fixed={"k": 0.0},
                              loop={"sample_time": T, "velocity": "central-difference",
                                    "delay": 0.0, "u_contains_w": True})
    r = _cli("identify", folder, cwd=tmp_path, code=2)
    assert "run 1" in r.stderr and "records no w" in r.stderr
    assert r.stderr.count("\n") == 1


# --------------------------------------------------------------------------------------------
# the EMPS cross-test on the real records (issue 27's acceptance)


@pytest.mark.skipif(not (EMPS / "DATA_EMPS_PULSES.mat").is_file(),
                    reason=f"the EMPS records are absent ({EMPS}): they lie beside the checkout "
                           "(../shared/data/emps), not in the repository")
def test_emps_cross_test_as_a_user_runs_it(tmp_path):
    for name, data in (("emps", "DATA_EMPS.mat"), ("emps-pulses", "DATA_EMPS_PULSES.mat")):
        (tmp_path / name).mkdir()
        shutil.copyfile(ROOT / "examples" / name / "experiment.toml",
                        tmp_path / name / "experiment.toml")
        shutil.copyfile(EMPS / data, tmp_path / name / data)
    ident = json.loads(_cli("identify", tmp_path / "emps", "--json", cwd=tmp_path).stdout)
    p = {k: v["value"] for k, v in ident["parameters"].items()}
    # the published IDIM-LS (examples/emps/README.md), to its printed digits
    assert round(p["m"], 4) == 95.1089 and round(p["offset"], 4) == -3.1648
    rep = json.loads(_cli("simulate", tmp_path / "sim", "--replay", tmp_path / "emps-pulses",
                          "--m", p["m"], "--c", p["c"], "--fc", p["fc"], "--offset-force",
                          p["offset"], "--json", cwd=tmp_path).stdout)
    sig = rep["validation"][0]["signals"]
    # issue 27's acceptance: tracking error ≤ 0.45 %, force ≤ 6.5 % (the benchmark's own
    # Simulink cross-test: 8.94 % force; the independent simulation 0.347 %, 5.41 %)
    assert sig["tracking error"]["relative_error_percent"] <= 0.45
    assert sig["force"]["relative_error_percent"] <= 6.5
    # the pulses are in vir with gain 1.0139 (the median ratio on the pulse samples,
    # to its 5 printed digits: ± 0.00005)
    (entry,) = rep["w_in_u"]
    assert entry["u_contains_w"] is True and entry["source"] == "stated"
    assert entry["measured"]["status"] == "contains"
    assert entry["gain"] == pytest.approx(1.0139, abs=5e-5)
    # and the example's manifest states what the record shows: no warning about w
    assert not any("additive input w" in w or "u_contains_w" in w for w in rep["warnings"])
