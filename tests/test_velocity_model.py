"""One velocity-filter model (issue 28, item 2): phoid.dynamics.velocity, used everywhere.

Where every expected value comes from:
- the presets' (b, a): the formulas of docs/format.md ("Velocity estimators"), written here;
- the estimates: the difference equations run in a Python loop here, and the compiled C
  controller of the rig (src/phoid/rig/c, through phoid.rig.native as tests/test_rig_*.py
  build it);
- the exact sampled loop with any estimator: a per-period simulation written here (the plant's
  zero-order hold from scipy.linalg.expm of the augmented matrix, the controller's law, hold and
  delay in a Python loop over periods), and central finite differences of the roots;
- `[loop] noise`: real manifests written with phoid.io and read back, and the real command line.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from typer.testing import CliRunner

import phoid
import phoid.dynamics
import phoid.io
from phoid.cli import app
from phoid.dynamics.controller import SampledController, closed_loop_poles
from phoid.dynamics.digital import (
    VELOCITY_ESTIMATORS,
    DigitalPD,
    digital_modes,
    digital_residues,
    digital_roots,
    record_problem,
)
from phoid.dynamics.velocity import (
    FIRST_ORDER_PRESETS,
    VELOCITY_PRESETS,
    VelocityFilter,
    estimator_taps,
)
from phoid.errors import ExperimentError, IdentificationError
from phoid.io import read_experiment, run_from_arrays, write_experiment
from phoid.io.loop import NOISE_PLACEMENTS, read_digital_loop, read_noise_placement
from phoid.io.tracking import check_tracking_loop, velocity_taps
from phoid.rig import native

T = 0.002  # s, the controller's period of test_digital.py's acceptance loop
WC = 300.0  # rad/s, a cut-off with ω_c·T = 0.6
C_DIR = Path(native.__file__).parent / "c"


def _expected(name: str, T: float, wc: float | None = None):
    """(b, a) of each preset from the formulas of docs/format.md."""
    if name == "backward-difference":  # (x_n − x_{n−1})/T
        return [1 / T, -1 / T], [1.0]
    if name == "central-difference":  # (x_n − x_{n−2})/(2T)
        return [1 / (2 * T), 0.0, -1 / (2 * T)], [1.0]
    a = math.exp(-wc * T)  # a v̂_{n−1} + (1 − a)(x_n − x_{n−1})/T
    return [(1 - a) / T, -(1 - a) / T], [1.0, -a]


def _loop_estimates(b, a, x, x_before):
    """v̂_n of Σ a_i v̂_{n−i} = Σ b_j x_{n−j} by a plain loop; x_{<0} = x_before, v̂_{<0} = 0."""
    v = []
    for n in range(len(x)):
        acc = sum(bj * (x[n - j] if n - j >= 0 else x_before) for j, bj in enumerate(b))
        acc -= sum(a[i] * v[n - i] for i in range(1, len(a)) if n - i >= 0)
        v.append(acc / a[0])
    return np.array(v)


# --------------------------------------------------------------------------------------------
# the definition


@pytest.mark.parametrize("name", VELOCITY_PRESETS)
def test_presets_coefficients_are_the_documented_formulas(name):
    wc = WC if name == "filtered" else None
    f = VelocityFilter(name, T, wc)
    b, a = _expected(name, T, wc)
    # the same few floating-point operations in another order: a few ulps
    np.testing.assert_allclose(f.b, b, rtol=1e-14, atol=0)
    np.testing.assert_allclose(f.a, a, rtol=1e-14, atol=0)
    assert f.taps == len(b) - 1 == estimator_taps(name)
    assert f.first_order == (name in ("backward-difference", "filtered"))
    if f.first_order:  # v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1})
        assert f.filter_pole == pytest.approx(-a[1] if len(a) > 1 else 0.0, rel=1e-15)
        assert f.filter_gain == pytest.approx(b[0], rel=1e-14)
        # the DC gain of the rounded pole: c_f T/(1 − a) = 1 to rounding
        assert f.filter_gain * T / (1 - f.filter_pole) == pytest.approx(1.0, rel=1e-15)
    else:
        with pytest.raises(ValueError, match="`velocity` = 'central-difference' is not a "
                                             "first-order estimator"):
            _ = f.filter_pole


@pytest.mark.parametrize("velocity", [*VELOCITY_PRESETS, (1.5 / T, -2 / T, 0.5 / T)])
def test_apply_is_the_difference_equation(velocity):
    wc = WC if velocity == "filtered" else None
    f = VelocityFilter(velocity, T, wc)
    b, a = (_expected(velocity, T, wc) if isinstance(velocity, str) else (list(velocity), [1.0]))
    rng = np.random.default_rng(28)
    x = 0.01 + np.cumsum(rng.normal(0.0, 1e-4, 300))
    # the loop sums the same terms in another order: rounding of ≈ 300 samples' recursion
    scale = float(np.max(np.abs(b))) * float(np.max(np.abs(x)))
    np.testing.assert_allclose(f.apply(x), _loop_estimates(b, a, x, 0.0), rtol=0,
                               atol=1e-12 * scale)
    np.testing.assert_allclose(f.apply(x, at_rest=True), _loop_estimates(b, a, x, x[0]),
                               rtol=0, atol=1e-12 * scale)
    # a ramp at 3 m/s reads 3 m/s once the estimator has filled (filtered: up to a^n)
    ramp = 3.0 * T * np.arange(400)
    assert f.apply(ramp, at_rest=True)[-1] == pytest.approx(3.0, rel=1e-9)


def test_polynomials_are_the_filters_transfer_function():
    # A(z) = z^r Σ a_i z^−i, B(z) = z^r Σ b_j z^−j, E(z) = Σ_k (Σ_{j>k} b_j) z^(r−k)
    f = VelocityFilter((4.0, 1.0, -2.0, -3.0), T)
    A, B, E = f.polynomials()
    np.testing.assert_array_equal(A, [1, 0, 0, 0])
    np.testing.assert_array_equal(B, [4, 1, -2, -3])
    np.testing.assert_array_equal(E, [1 - 2 - 3, -2 - 3, -3, 0])
    A, B, E = VelocityFilter("filtered", T, WC).polynomials()
    a = math.exp(-WC * T)
    cf = (1 - a) / T
    np.testing.assert_allclose(A, [1, -a], rtol=1e-15)
    np.testing.assert_allclose(B, [cf, -cf], rtol=1e-14)
    np.testing.assert_allclose(E, [-cf, 0], rtol=1e-14)


@pytest.mark.parametrize(("kwargs", "name", "words"), [
    (dict(velocity="kalman"), "velocity", "must be one of 'backward-difference', "
                                          "'central-difference', 'filtered'"),
    (dict(velocity=3), "velocity", "preset name or a sequence"),
    (dict(velocity=(1.0,)), "velocity", "at least 2 FIR coefficients"),
    (dict(velocity=(1.0, 1.0)), "velocity", "must sum to 0"),
    (dict(velocity=(0.0, 0.0)), "velocity", "all 0"),
    (dict(velocity=(1.0, float("nan"), -1.0)), "velocity", "coefficient 1 must be a finite"),
    (dict(velocity=(1.0, True)), "velocity", "coefficient 1"),
    (dict(velocity="filtered"), "cutoff", "required"),
    (dict(velocity="filtered", cutoff=-5.0), "cutoff", "> 0"),
    (dict(velocity="filtered", cutoff=1e-14), "cutoff", "too low for the period"),
    (dict(velocity="filtered", cutoff=1e-300), "cutoff", "magnitude 1e-30 … 1e30"),
    (dict(velocity="central-difference", cutoff=100.0), "cutoff", "applies only"),
    (dict(velocity=(1.0, -1.0), cutoff=100.0), "cutoff", "applies only"),
    (dict(sample_time=0.0), "sample_time", "> 0"),
    # VelocityFilter: "too short", SampledController: "out of range"; both name and show it
    (dict(sample_time=5e-324), "sample_time", "4.94066e-324"),
])
@pytest.mark.parametrize("cls", ["VelocityFilter", "DigitalPD", "SampledController"])
def test_every_class_refuses_by_name_in_one_line(kwargs, name, words, cls):
    spec = dict(velocity="backward-difference", sample_time=T, cutoff=None) | kwargs
    with pytest.raises(ValueError) as info:
        if cls == "VelocityFilter":
            VelocityFilter(spec["velocity"], spec["sample_time"], spec["cutoff"])
        elif cls == "DigitalPD":
            DigitalPD(1.0, 0.1, **spec)
        else:
            SampledController(P=1.0, D=0.1, **spec)
    msg = str(info.value)
    assert f"`{name}`" in msg and words in msg and "\n" not in msg, msg


# --------------------------------------------------------------------------------------------
# one list, one (b, a), everywhere


def test_one_list_of_names_everywhere():
    assert VELOCITY_PRESETS == ("backward-difference", "central-difference", "filtered")
    for other in (phoid.dynamics.VELOCITY_PRESETS, phoid.io.VELOCITY_PRESETS,
                  phoid.dynamics.controller.VELOCITY_PRESETS, VELOCITY_ESTIMATORS):
        assert other is VELOCITY_PRESETS
    assert phoid.VelocityFilter is VelocityFilter
    assert set(FIRST_ORDER_PRESETS) <= set(VELOCITY_PRESETS)
    # the rig's C codes name the same presets
    assert tuple(native.VELOCITIES) == VELOCITY_PRESETS
    # the format's estimator table lists each
    doc = (Path(__file__).resolve().parents[1] / "docs" / "format.md").read_text("utf-8")
    table = doc[doc.index("#### Velocity estimators"):doc.index("### `[[run]]` keys")]
    assert all(f'`"{n}"`' in table for n in VELOCITY_PRESETS)


@pytest.mark.parametrize("velocity", [*VELOCITY_PRESETS, (1.5 / T, -2 / T, 0.5 / T)])
def test_one_coefficients_per_estimator_everywhere(velocity):
    wc = WC if velocity == "filtered" else None
    f = VelocityFilter(velocity, T, wc)
    loop = DigitalPD(10.0, 1.0, T, 2, velocity, wc)
    ctrl = SampledController(T, 10.0, 1.0, velocity=velocity, cutoff=wc, delay=2 * T)
    assert loop.estimator == f and ctrl.estimator == f
    assert SampledController.from_digital(loop).estimator == f
    b, a = ctrl.velocity_filter()
    assert tuple(b) == f.b and tuple(a) == f.a
    # the tracking set's taps come from the same definition
    spec = list(velocity) if isinstance(velocity, tuple) else velocity
    assert velocity_taps("set", spec, wc) == f.taps == ctrl.taps


@pytest.mark.parametrize(("velocity", "words"), [
    ([1.0, 1.0], "key 'velocity' has FIR coefficients that must sum to 0"),
    ([2.0], "key 'velocity' needs at least 2 FIR coefficients"),
    ([0.0, 0.0, 0.0], "key 'velocity' has FIR coefficients that are all 0"),
])
def test_tracking_set_refuses_what_the_controller_would(velocity, words):
    # before: accepted by the reader, refused only when the controller was built
    with pytest.raises(ExperimentError, match=re.escape(f"set/experiment.toml: [loop]: {words}")):
        velocity_taps("set/experiment.toml", velocity)
    with pytest.raises(ValueError, match="`velocity`"):
        VelocityFilter(tuple(velocity), T)


def test_record_problem_names_an_estimator_longer_than_the_record():
    loop = DigitalPD(1.0, 0.1, 0.01, 0, tuple([1.0] * 10 + [-10.0]))
    key, reason = record_problem(loop, 0.05)
    assert key == "velocity" and "reads 10 earlier samples" in reason
    assert record_problem(loop, 0.2) is None


# --------------------------------------------------------------------------------------------
# the rig's C controller


@pytest.fixture(scope="module")
def lib_dir(tmp_path_factory):
    if native.find_compiler() is None:
        pytest.skip("no C compiler (CC, cc, gcc, clang): the rig's controller cannot be built")
    folder = tmp_path_factory.mktemp("velocity-lib")
    native.build_library(folder)
    return folder


def test_c_codes_are_the_headers_and_readmes():
    header = (C_DIR / "phoid_ctrl.h").read_text("utf-8")
    enum = {m.group(1): int(m.group(2))
            for m in re.finditer(r"(PHOID_VEL_[A-Z]+) = (\d+)", header)}
    readme = (C_DIR / "README.md").read_text("utf-8")
    rows = re.findall(r"\| `(PHOID_VEL_[A-Z]+)` \((\d+)\) \| [^|]+\| `([a-z-]+)`", readme)
    assert len(rows) == len(VELOCITY_PRESETS)
    for const, code, name in rows:
        assert enum[const] == int(code) == native.VELOCITIES[name]


@pytest.mark.parametrize("name", VELOCITY_PRESETS)
def test_c_controller_estimates_are_the_definitions(lib_dir, name):
    wc = 0.3 / T if name == "filtered" else None
    cfg = {"sample_time": T, "velocity": name}
    if wc is not None:
        cfg["cutoff"] = wc
    ctrl = native.Controller(cfg, lib_dir)
    assert ctrl.config.velocity == native.VELOCITIES[name]
    if wc is not None:  # the pole the binding gives the C code is the definition's
        assert ctrl.config.filter_pole == VelocityFilter(name, T, wc).filter_pole
    rng = np.random.default_rng(7)
    x = 0.004 + np.cumsum(rng.normal(0.0, 2e-5, 400))
    got = []
    for xi in x:
        ctrl.step(float(xi))
        got.append(ctrl.velocity)
    # the C code is at rest before its first sample (x_{-1} = x_{-2} = x_0, v̂ = 0); both sides
    # differ by the rounding of the same few operations per sample (filtered: its recursion)
    want = VelocityFilter(name, T, wc).apply(x, at_rest=True)
    scale = float(np.max(np.abs(x))) / T
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * scale)


def test_c_binding_refuses_a_cutoff_the_definition_refuses(tmp_path):
    # no library is needed: the cut-off is checked (by VelocityFilter) before anything is built
    with pytest.raises(ValueError, match="`cutoff` ω_c = 1e-14 rad/s is too low"):
        native.Controller({"sample_time": T, "velocity": "filtered", "cutoff": 1e-14}, tmp_path)


# --------------------------------------------------------------------------------------------
# the exact sampled loop with every estimator, against a per-period simulation


def _zoh(m, c, k, h):
    M = np.zeros((3, 3))
    M[0, 1], M[1, 0], M[1, 1], M[1, 2] = 1.0, -k / m, -c / m, 1.0 / m
    E = scipy.linalg.expm(M * h)
    return E[:2, :2], E[:2, 2]


def _release(m, c, k, P, D, d, b, a, x0, v0, n_periods):
    """x at the controller's instants after a release at n = 0 from a hold at x0.

    Held: x_{n<0} = x0, v̂_{n<0} = 0, the queued commands u_{−d} … u_{−1} = −P x0. Then per
    period: x_n read, v̂_n = (Σ b_j x_{n−j} − Σ_{i≥1} a_i v̂_{n−i})/a_0, u_n = −(P x_n + D v̂_n),
    the plant driven by u_{n−d} held over the period (exact ZOH)."""
    Phi, Gam = _zoh(m, c, k, T)
    xs, vs, us = [], [], {n: -P * x0 for n in range(-d, 0)}
    y = np.array([x0, v0])
    for n in range(n_periods):
        xs.append(float(y[0]))
        acc = sum(bj * (xs[n - j] if n - j >= 0 else x0) for j, bj in enumerate(b))
        acc -= sum(a[i] * vs[n - i] for i in range(1, len(a)) if n - i >= 0)
        vs.append(acc / a[0])
        us[n] = -(P * xs[n] + D * vs[n])
        y = Phi @ y + Gam * us[n - d]
    return np.array(xs)


PLANT = (1.0, 2.0, 100.0)  # m (kg), c (N·s/m), k (N/m): test_digital.py's acceptance plant
# (x_n + x_{n−1} − x_{n−2} − x_{n−3})/(4T)
FIR4 = (1 / (4 * T), 1 / (4 * T), -1 / (4 * T), -1 / (4 * T))
FIR3 = (1.5 / T, -2 / T, 0.5 / T)  # the second-order backward difference
CASES = [
    ("central-difference", None, 0, 50.0, 1.0),
    ("central-difference", None, 2, 80.0, 2.0),
    (FIR3, None, 1, 120.0, 3.0),
    (FIR4, None, 3, 50.0, 1.5),
    (FIR4, None, 2, 60.0, 0.0),  # D = 0: a triple root at z = 0
    ("filtered", WC, 3, 100.0, 2.0),
    ("backward-difference", None, 2, 60.0, 0.0),  # D = 0: a root at z = 0
]


@pytest.mark.parametrize(("velocity", "wc", "d", "P", "D"), CASES)
def test_digital_residues_are_the_simulated_release(velocity, wc, d, P, D):
    loop = DigitalPD(0.0, 0.0, T, d, velocity, wc)
    m, c, k = PLANT
    x0, v0 = 0.01, -0.05
    roots = digital_roots(m, c, k, P, D, loop)
    assert roots.z.shape == (1, d + loop.estimator.order + 2) and roots.stable[0]
    s, amp = digital_residues(m, c, k, P, D, loop, x0, v0)
    z = np.exp(s[0].real * T) * np.exp(1j * s[0].imag * T)  # z = e^(sT): 0 where s = −inf
    n0 = int(np.sum(z == 0))  # the expansion holds from the zero root's multiplicity on
    assert n0 == (loop.estimator.taps if D == 0.0 else 0)
    n = np.arange(600)
    model = np.real(np.sum(amp[0][:, None] * z[:, None] ** n[None, :], axis=0))
    sim = _release(m, c, k, P, D, d, *_filter(velocity, wc), x0, v0, n.size)
    # both exact up to rounding: ≈ d + r + 2 terms of size ≈ x0, 600 periods of recursion
    np.testing.assert_allclose(model[n0:], sim[n0:], rtol=0, atol=1e-10 * x0)


def _filter(velocity, wc):
    return _expected(velocity, T, wc) if isinstance(velocity, str) else (list(velocity), [1.0])


@pytest.mark.parametrize(("velocity", "wc", "d", "P", "D"), CASES[:4])
def test_roots_agree_with_the_industrial_controllers_polynomial(velocity, wc, d, P, D):
    # closed_loop_poles builds χ in q = 1/z from (b, a) its own way (controller.py)
    m, c, k = PLANT
    loop = DigitalPD(0.0, 0.0, T, d, velocity, wc)
    z = digital_roots(m, c, k, P, D, loop).z[0]
    other = closed_loop_poles(m, c, k, SampledController(T, P, D, velocity=velocity, cutoff=wc,
                                                         delay=d * T))
    nz = other[np.abs(other) > 1e-6]
    for w in nz:  # each non-zero pole is one of χ's roots (np.roots: ~1e-10 on these)
        assert np.min(np.abs(z - w)) <= 1e-8
    assert nz.size == np.sum(np.abs(z) > 1e-6)


@pytest.mark.parametrize(("velocity", "wc", "d", "P", "D"), CASES[:4])
def test_digital_modes_jacobian_is_the_roots_derivative(velocity, wc, d, P, D):
    m, c, k = PLANT
    loop = DigitalPD(0.0, 0.0, T, d, velocity, wc)
    Ps, Ds = np.array([P, 1.5 * P]), np.array([D, 0.5 * D + 0.1])
    s, ds = digital_modes(m, c, k, Ps, Ds, loop)
    np.testing.assert_allclose(s, digital_roots(m, c, k, Ps, Ds, loop).dominant, rtol=1e-12)
    # from a guess: the same root (Newton on χ)
    s2, _ = digital_modes(m, c, k, Ps, Ds, loop, s_guess=s * (1 + 1e-3))
    np.testing.assert_allclose(s2, s, rtol=1e-11)
    theta = np.array(PLANT)
    for j in range(3):
        h = 1e-6 * theta[j]
        up, dn = theta.copy(), theta.copy()
        up[j] += h
        dn[j] -= h
        fd = (digital_roots(*up, Ps, Ds, loop).dominant
              - digital_roots(*dn, Ps, Ds, loop).dominant) / (2 * h)
        # central differences: O(h²) truncation, rounding ≈ ε|s|/h ≈ 1e-9 relative
        np.testing.assert_allclose(ds[:, j], fd, rtol=1e-6)


def test_first_order_only_api_says_so():
    loop = DigitalPD(1.0, 0.1, T, 1, "central-difference")
    with pytest.raises(ValueError, match="`velocity` = 'central-difference' is not a "
                                         "first-order estimator"):
        _ = loop.filter_gain
    assert loop.order == 1 + 2 + 2


# --------------------------------------------------------------------------------------------
# [loop] of a PHO set, read in io


def _pho_set(folder: Path, loop: dict) -> Path:
    t = np.arange(0.0, 2.0, 0.001)
    runs = [run_from_arrays(t, 0.01 * np.exp(-0.5 * t) * np.cos(w * t), P=P, D=0.5)
            for w, P in ((8.0, 1.0), (9.0, 5.0), (10.0, 10.0))]
    write_experiment(folder, runs, loop=loop, gzip=False)
    return folder


@pytest.mark.parametrize("value", NOISE_PLACEMENTS)
@pytest.mark.parametrize("digital", [True, False])
def test_noise_placement_is_read(tmp_path, value, digital):
    loop = {"sample_time": 0.001, "noise": value} if digital else {"delay": 0.01, "noise": value}
    exp = read_experiment(_pho_set(tmp_path / "set", loop))
    assert read_noise_placement(exp) == value
    # the digital loop's reader accepts the key (and returns the loop, or None)
    assert (read_digital_loop(exp) is not None) == digital


def test_noise_placement_absent_is_none(tmp_path):
    exp = read_experiment(_pho_set(tmp_path / "set", {"sample_time": 0.001}))
    assert read_noise_placement(exp) is None


BAD_NOISE = ["inside", "In-Loop", "", 1, True, ["in-loop"], 0.5]


@pytest.mark.parametrize("value", BAD_NOISE)
def test_noise_placement_refused_in_one_line(tmp_path, value):
    folder = _pho_set(tmp_path / "set", {"sample_time": 0.001, "noise": value})
    exp = read_experiment(folder)
    for reader in (read_noise_placement, read_digital_loop):
        with pytest.raises(IdentificationError) as info:
            reader(exp)
        msg = str(info.value)
        assert "\n" not in msg
        assert msg.startswith(f"{folder / 'experiment.toml'}: [loop] noise must be one of "
                              "'in-loop', 'outside'"), msg


@pytest.mark.parametrize("value", ['"inside"', "3"])
def test_identify_refuses_a_bad_noise_placement_exit_2(tmp_path, value):
    folder = _pho_set(tmp_path / "set", {"sample_time": 0.001, "noise": "in-loop"})
    manifest = folder / "experiment.toml"
    text = manifest.read_text("utf-8")
    assert 'noise = "in-loop"' in text
    manifest.write_text(text.replace('noise = "in-loop"', f"noise = {value}"), "utf-8")
    res = CliRunner().invoke(app, ["identify", str(folder)])
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), res.stderr
    assert "experiment.toml" in lines[0] and "[loop] noise" in lines[0], lines[0]


def test_pho_loop_refuses_other_keys_and_estimators(tmp_path):
    exp = read_experiment(_pho_set(tmp_path / "a", {"sample_time": 0.001, "noize": "outside"}))
    with pytest.raises(IdentificationError, match=r"\[loop\] noize: unknown key \(known: delay, "
                                                  r"sample_time, delay_samples, velocity, "
                                                  r"cutoff, noise\)"):
        read_digital_loop(exp)
    # every preset is a PHO loop's estimator (the one list); another name is refused
    exp = read_experiment(_pho_set(tmp_path / "b", {"sample_time": 0.001,
                                                    "velocity": "kalman"}))
    with pytest.raises(IdentificationError, match=r"\[loop\] velocity must be one of "
                                                  r"'backward-difference', "
                                                  r"'central-difference', 'filtered'"):
        read_digital_loop(exp)


def test_tracking_loop_has_no_noise_key():
    # docs/format.md: `noise` is a key of a pho set's loop only
    with pytest.raises(ExperimentError, match="unknown key 'noise' in a tracking set's"):
        check_tracking_loop("set", {"noise": "in-loop"})
