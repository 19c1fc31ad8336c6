"""Hostile probe of issue 27 (io): w_in_u_gain's range and gain·w overflow, under- and
overflow worded as such in the w-in-u measurement, rotational unit hints, signal names that are
units.

Records come from tests/test_tracking_semantics.py's independent loop simulator (``_loop``);
sets are written into tmp_path and read by the real CLI in a subprocess.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_tracking_semantics import _ctrl, _loop, _set_loop, _write

from phoid.io.units import unit_hint
from phoid.methods.pho_checks import u_contradicts_gains
from phoid.methods.tracking_semantics import command_input_semantics, measure_w_in_u


def _cli(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "phoid.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


# ------------------------------------------------------------------------------------------
# 1. w_in_u_gain


@pytest.mark.parametrize("gain", [1e308, 1e31, -1e31, 1e-31, -1e-300])
def test_w_in_u_gain_out_of_range_is_refused_by_its_name(tmp_path, gain):
    folder = _write(tmp_path / "set", _loop(True, 1.0, n=300))
    _set_loop(folder / "experiment.toml", w_in_u_gain=gain)
    for args in (("identify", folder), ("simulate", tmp_path / "o", "--replay", folder,
                                        "--m", "2")):
        r = _cli(*args, cwd=tmp_path)
        assert r.returncode == 2, r.stderr
        # one line naming the file, the table and the key (not "w has … non-finite values")
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
        assert "experiment.toml: [loop]: key 'w_in_u_gain'" in r.stderr
        assert "1e-30 … 1e30" in r.stderr and "non-finite" not in r.stderr


def test_gain_times_w_overflow_is_named_not_blamed_on_w():
    # a gain in range (1e30, the range's edge) on a w of 2e290: gain·w = 4e320 > 1.8e308
    rec = _loop(True, 1.0, n=600)
    assert np.any(rec["w"] == 2.0)  # _loop's pulses, of amplitude 2
    w = rec["w"] * 1e290
    sem = command_input_semantics({"w_in_u_gain": 1e30}, rec["u"], w, rec["x"], rec["r"],
                                  _ctrl())
    with pytest.raises(ValueError, match=r"gain·w overflows .*\[loop\] w_in_u_gain = 1e\+30"):
        sem.applied(w)
    # in range, the product is gain·w itself
    assert np.array_equal(sem.applied(rec["w"]), 1e30 * rec["w"])


# ------------------------------------------------------------------------------------------
# 1b. under- and overflow in the measurement


@pytest.mark.parametrize("scale", [1e-20, 1e20])
def test_a_small_or_large_w_is_measured_with_its_gain(scale):
    # u holds 1·w0; given w = scale·w0 the gain is 1/scale (1e20 or 1e-20, within the range
    # 1e-30 … 1e30 of a stated gain). 1 % tolerance: the gain's stderr is ~1e-4 relative here
    # (test_tracking_semantics's expected stderr).
    rec = _loop(True, 1.0, n=600)
    got = measure_w_in_u(rec["u"], rec["w"] * scale, rec["x"], rec["r"], _ctrl())
    assert got.status == "contains"
    assert got.gain * scale == pytest.approx(1.0, rel=0.01)


@pytest.mark.parametrize("scale", [1e-40, 1e-200, 1e-300, 1e-310])
def test_a_w_too_small_for_u_is_said_to_be_small(scale):
    # u holds 1·w0 but w = scale·w0: the gain 1/scale is beyond 1e30 (or overflows)
    rec = _loop(True, 1.0, n=600)
    got = measure_w_in_u(rec["u"], rec["w"] * scale, rec["x"], rec["r"], _ctrl())
    assert got.status == "undetermined"
    assert "too small" in got.reason and "overflow" not in got.reason, got.reason


@pytest.mark.parametrize("scale", [1e160, 1e300])
def test_a_w_too_large_for_the_arithmetic_is_said_to_be_large(scale):
    rec = _loop(True, 1.0, n=600)
    got = measure_w_in_u(rec["u"], rec["w"] * scale, rec["x"], rec["r"], _ctrl())
    assert got.status == "undetermined"
    assert "w is too large" in got.reason and "overflows" in got.reason


def test_a_replayed_tiny_w_is_not_called_an_overflow(tmp_path):
    # the probe: a replay wrote w ≈ 5e-300 (applied through a tiny gain) with u holding it;
    # identifying that record must not say the arithmetic overflows
    rec = _loop(True, 1e-300, n=600)
    assert np.any(rec["w"] == 2.0)  # _loop's pulses, of amplitude 2
    rec["w"] = rec["w"] * 1e-300
    got = measure_w_in_u(rec["u"], rec["w"], rec["x"], rec["r"], _ctrl())
    assert got.status == "undetermined"
    assert "overflow" not in got.reason and "too small" in got.reason


# ------------------------------------------------------------------------------------------
# 2. hints by the set's quantities


def test_unit_hint_words_a_rotational_sets_units():
    # expected ratios from the units' definitions: kN m is 1e3 N m, mrad 1e-3 rad, deg π/180
    assert unit_hint("u", 1e-3, "rad") == 'is u in kN m? (then give [units] u = "kN m")'
    assert unit_hint("F", 1e3, "rad") == 'is F in mN m? (then give [units] F = "mN m")'
    assert unit_hint("x", 1e3, "rad") == 'is x in mrad? (then give [units] x = "mrad")'
    assert unit_hint("r", 180 / np.pi, "rad") == 'is r in deg? (then give [units] r = "deg")'
    assert unit_hint("x", 1e3, "V") == ""  # a signal is not converted: nothing to suggest
    assert unit_hint("u", 1e-3) == 'is u in kN? (then give [units] u = "kN")'  # translational


def test_u_against_gains_warning_names_rad_and_newton_metres():
    # a pho loop's u recorded 1000 times too small (as if in kN m read as N m): u = −(P x + D ẋ)
    t = np.arange(4000) * 1e-3
    wd, s = 6.0, 0.4
    x = 0.01 * np.exp(-s * t) * np.cos(wd * t)
    v = np.gradient(x, t)
    P, D = np.array([20.0]), np.array([1.0])
    u = -(P[0] * x + D[0] * v) * 1e-3
    note = u_contradicts_gains([(t, x)], [u], P, D, 0.0, ["run 1"], [wd], x_unit="rad")
    assert note is not None
    assert "the units of x (rad) and u (N m)" in note
    assert '[units] u = "kN m"' in note and '[units] x = "mrad"' in note
    assert '"kN"' not in note and '"mm"' not in note


# ------------------------------------------------------------------------------------------
# 3. signal names that are units


@pytest.mark.parametrize("name", ["kg", "KG", "Hz", "hz", "kHz", "rad/s", "1/s", "N m", "N·m",
                                  "Nm", "MM", "S", "DEG", "N s/m", "kg m^2", "m/s"])
def test_a_signal_named_after_a_known_unit_is_refused(tmp_path, name):
    folder = tmp_path / "set"
    folder.mkdir()
    t = np.arange(2000) * 1e-3
    x = np.exp(-0.5 * t) * np.cos(2 * np.pi * 3 * t)
    np.savetxt(folder / "r.csv", np.column_stack([t, x]), delimiter=",", header="t,x",
               comments="")
    esc = name.replace("\\", "\\\\").replace('"', '\\"')
    (folder / "experiment.toml").write_text(
        f'format = "phoid/1"\nmethod = "free"\n[units]\nx = {{signal = "{esc}"}}\n\n'
        '[[run]]\nfile = "r.csv"\n', encoding="utf-8")
    r = _cli("identify", folder, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "experiment.toml: [units]: x = {signal =" in r.stderr
    assert "not a length, angle, time or force unit, nor a torque, mass" in r.stderr


@pytest.mark.parametrize("name", ["V", "counts", "lux", "mV"])
def test_a_signal_that_is_no_known_unit_is_kept(name):
    from phoid.io.units import read_units

    assert read_units("e.toml", {"x": {"signal": name}}, "free").x_unit == name
