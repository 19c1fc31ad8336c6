"""Validation of a simulated tracking record (phoid.methods.tracking_validation) and its reports:
exact relative errors on synthetic records, warnings, bad input, the figure and the text, and the
EMPS record simulated with the benchmark's published IDIM-LS parameters."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from phoid.errors import OutputError
from phoid.methods.tracking_validation import TrackingValidation, validate_tracking
from phoid.reports.tracking import plot_tracking, tracking_text

EMPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "emps"
EMPS_FILE = EMPS / "DATA_EMPS.mat"
EMPS_ABSENT = (
    f"the EMPS record is absent ({EMPS_FILE}): it lies beside the checkout (../shared/data/emps) "
    "in CI, not in a clone")

T = 1e-3  # s, sample interval of the synthetic records
N = 2000  # samples: 2 s, two whole periods of the 1 Hz sine below
A = 0.1  # m, amplitude of x
W = 2 * math.pi  # rad/s
# Rounding: the residuals are differences of O(0.1) numbers, ~1e-17 m, against norms ≥ 1e-3: a
# relative error that should be 0 is below 1e-10 %.
ZERO = 1e-10


def _record(offset: float = 0.0):
    """x = A sin(ωt) + offset, r = x − 1 mm: the tracking error is exactly 1 mm everywhere.

    With ``velocity="central-difference"`` the measured velocity at an interior sample is
    exactly (x_{n+1} − x_{n−1})/(2T) = A ω cos(ω t_n) · sin(ωT)/(ωT) (the difference of two
    sines), which the tests use as the simulated velocity that matches the record.
    """
    t = np.arange(N) * T
    x = A * np.sin(W * t) + offset
    r = x - 1e-3
    v_cd = A * W * np.cos(W * t) * math.sin(W * T) / (W * T)
    return t, x, r, v_cd


def _sim(t, x, v, force, **extra):
    return SimpleNamespace(t=t, x=x, v=v, force=force, **extra)


def test_identical_record_has_zero_error():
    """The simulation that reproduces the record exactly: every relative error and RMS is 0
    (up to rounding), no warning; the compared window is the interior (one sample at each end,
    where central differences become one-sided)."""
    t, x, r, v = _record()
    u = np.sin(3 * W * t)
    sim = _sim(t, x.copy(), v, 35.0 * u)
    val = validate_tracking(t, x, r, sim, u=u, command_gain=35.0,
                            velocity="central-difference", trim=1)
    assert isinstance(val, TrackingValidation)
    assert [e.name for e in val.errors] == ["position", "tracking error", "velocity", "force"]
    for e in val.errors:
        assert e.relative_error < ZERO, e
        assert e.rms < 1e-12, e
    assert val.window == (1, N - 1)
    assert val.warnings == ()


def test_known_residuals_give_known_errors():
    """x_sim = x + δ with δ = 10 µm constant: position relative error 100·δ·√N/‖x‖, here with
    x = A sin over two whole periods, ‖x‖ = A·√(N/2) exactly (Σ sin² over whole periods is
    N/2), so 100·δ·√2/A; tracking error 100·δ/1 mm = 1 % (‖x − r‖ = 1 mm·√N); RMS δ for both.
    A force scaled by (1 + 0.05): 5 % (‖α y‖/‖y‖ = α). Whole periods need all N samples: trim 0
    (the velocity, one-sided at the ends, is tested on the interior below)."""
    t, x, r, v = _record()
    u = np.cos(2 * W * t) + 0.5
    delta = 10e-6
    val = validate_tracking(t, x, r, _sim(t, x + delta, v, 1.05 * 2.0 * u), u=u,
                            command_gain=2.0, velocity="central-difference", trim=0)
    pos, trk = val.error("position"), val.error("tracking error")
    assert pos.relative_error == pytest.approx(100 * delta * math.sqrt(2) / A, rel=1e-9)
    assert trk.relative_error == pytest.approx(1.0, rel=1e-9)
    assert pos.rms == pytest.approx(delta, rel=1e-9)
    assert trk.rms == pytest.approx(delta, rel=1e-9)
    assert trk.measured_rms == pytest.approx(1e-3, rel=1e-12)
    assert pos.measured_rms == pytest.approx(A / math.sqrt(2), rel=1e-12)
    assert val.error("force").relative_error == pytest.approx(5.0, rel=1e-9)
    np.testing.assert_allclose(val.position_residual, -delta, rtol=1e-6)
    np.testing.assert_allclose(val.force_residual, -0.05 * 2.0 * u, atol=1e-15)
    np.testing.assert_allclose(val.e - val.e_sim, val.position_residual, atol=0)


def test_velocity_rms_on_the_interior():
    """Velocity scaled by 0.98 on the interior samples, trim 1: relative error 2 % and RMS
    0.02·‖v‖/√(N − 2), ‖v‖² = (Aω sinc)²·Σcos² over the samples 1..N−2: the whole periods'
    N/2 less the two end samples, cos²(0) = 1 and cos²(ω(N − 1)T)."""
    t, x, r, v = _record()
    val = validate_tracking(t, x, r, _sim(t, x, 0.98 * v, np.zeros(N)),
                            velocity="central-difference", trim=1)
    amp = A * W * math.sin(W * T) / (W * T)
    norm = amp * math.sqrt(N / 2 - 1 - math.cos(W * (N - 1) * T) ** 2)
    e = val.error("velocity")
    assert e.relative_error == pytest.approx(2.0, rel=1e-9)
    assert e.rms == pytest.approx(0.02 * norm / math.sqrt(N - 2), rel=1e-9)
    assert val.error("force") is None  # no u: the force is not compared


def test_benchmark_velocity_estimator_on_a_slow_sine():
    """The default estimator (Butterworth order 4 at 100 Hz forward-backward, then central
    differences): at 1 Hz its gain is 1 − O((1/100)^8) and it has no phase, so away from its end
    transients (time constant ~ 2 ms; 200 samples left out) the measured velocity is the central
    difference of the sine itself: relative error below 1e-6 % against it."""
    t, x, r, v = _record()
    val = validate_tracking(t, x, r, _sim(t, x, v, np.zeros(N)), trim=200)
    assert val.error("velocity").relative_error < 1e-6
    assert "Butterworth order 4, 100 Hz" in val.velocity_estimator


def test_position_and_tracking_error_normalise_differently():
    """Moving the origin of x (and r) by 1 m changes the position's relative error (‖x‖ grows)
    but not the tracking error's: x − r and the residual are unchanged."""
    base, moved = _record(0.0), _record(1.0)
    out = []
    for t, x, r, v in (base, moved):
        out.append(validate_tracking(t, x, r, _sim(t, x + 5e-6, v, np.zeros(N)),
                                     velocity="central-difference", trim=1))
    assert out[1].error("position").relative_error < out[0].error("position").relative_error / 5
    assert out[1].error("tracking error").relative_error == pytest.approx(
        out[0].error("tracking error").relative_error, rel=1e-6)


def test_saturation_and_w_enter_the_measured_force():
    """Measured force G·(clip(u, ±s) + w): a simulation that applies exactly that matches."""
    t, x, r, v = _record()
    u = 15.0 * np.sin(W * t)  # beyond ±10 half of the time
    w = 0.3 * np.cos(5 * W * t)
    force = 2.0 * (np.clip(u, -10.0, 10.0) + w)
    val = validate_tracking(t, x, r, _sim(t, x, v, force), u=u, w=w, command_gain=2.0,
                            saturation=10.0, velocity="central-difference", trim=1)
    assert val.error("force").relative_error < ZERO
    unclipped = validate_tracking(t, x, r, _sim(t, x, v, force), u=u, w=w, command_gain=2.0,
                                  velocity="central-difference", trim=1)
    assert unclipped.error("force").relative_error > 1.0


def test_warnings_saturation_divergence_nonfinite_and_zero():
    t, x, r, v = _record()
    sat = np.zeros(N, dtype=bool)
    sat[500:600] = True
    val = validate_tracking(t, x, r, _sim(t, x, v, np.zeros(N), saturated=sat),
                            velocity="central-difference", trim=1)
    assert any("saturates at 100 of 2000 samples" in w and "t = 0.5 s" in w
               for w in val.warnings), val.warnings
    # a simulation 3 mm off: the tracking error (1 mm) is followed 300 % wrong
    far = validate_tracking(t, x, r, _sim(t, x + 3e-3, v, np.zeros(N)),
                            velocity="central-difference", trim=1)
    assert far.error("tracking error").relative_error == pytest.approx(300.0, rel=1e-9)
    assert any("tracking error departs" in w and "diverges" in w for w in far.warnings)
    assert not any("position departs" in w for w in far.warnings)  # 3 mm of 0.1 m
    blown = x.copy()
    blown[1500:] = np.inf
    bad = validate_tracking(t, x, r, _sim(t, blown, v, np.zeros(N)),
                            velocity="central-difference", trim=1)
    assert math.isinf(bad.error("position").relative_error)
    assert any("not finite from t = 1.5 s" in w for w in bad.warnings)
    assert bad.summary()["signals"]["position"]["relative_error_percent"] is None
    still = np.full(N, 0.2)
    zero = validate_tracking(t, still, still, _sim(t, still, np.zeros(N), np.zeros(N)),
                             velocity="central-difference", trim=1)
    assert math.isnan(zero.error("tracking error").relative_error)
    assert any("tracking error is zero" in w for w in zero.warnings)


@pytest.mark.parametrize(("change", "message"), [
    (lambda a: a.update(x=a["x"][:-1]), "x: length 1999 differs from t's length 2000"),
    (lambda a: a.update(sim=_sim(a["t"] + 0.6 * T, a["x"], a["x"], a["x"])),
     "sim.t: the simulated samples lie up to"),
    (lambda a: a.update(sim=_sim(a["t"][:-1], a["x"], a["x"], a["x"])),
     "sim.t: length 1999"),
    (lambda a: a.update(w=np.zeros(N)), "w: an additive command input needs"),
    (lambda a: a.update(command_gain=0.0), "command_gain: must be a finite nonzero"),
    (lambda a: a.update(cutoff=600.0), "cutoff: must lie below the Nyquist frequency 500 Hz"),
    (lambda a: a.update(velocity="backward"), "velocity: must be one of"),
    (lambda a: a.update(trim=(1000, 999)), "trim: (1000, 999) leaves 1 of 2000 samples"),
    (lambda a: a.update(x=np.where(np.arange(N) == 3, np.nan, a["x"])), "x: contains non-fin"),
])
def test_bad_input_one_line(change, message):
    t, x, r, v = _record()
    args = {"t": t, "x": x, "r": r, "sim": _sim(t, x, v, np.zeros(N))}
    change(args)
    sim = args.pop("sim")
    pos = [args.pop(k) for k in ("t", "x", "r")]
    with pytest.raises(ValueError) as info:
        validate_tracking(*pos, sim, **args)
    text = str(info.value)
    assert text.startswith(message), text
    assert "\n" not in text


def _png_size(data: bytes) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk (bytes 16–24), after the 8-byte signature."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_plot_writes_a_png(tmp_path):
    """The figure is 9 in wide and 2.2 in per panel + 0.6 in, saved at 120 dpi: 1080 px wide,
    (2.2·4 + 0.6)·120 = 1128 px high with the force panel, 864 px without. The same four
    panels with their axes and ticks but no curves are 29 kB (matplotlib 3.x, Agg), the drawn
    figure about 200 kB: over 80 kB, the curves are there."""
    t, x, r, v = _record()
    u = np.sin(3 * W * t)
    val = validate_tracking(t, x, r, _sim(t, x + 1e-6 * np.sin(7 * W * t), v, 1.01 * u), u=u)
    out = plot_tracking(val, tmp_path / "fig" / "tracking.png")
    data = Path(out).read_bytes()
    assert _png_size(data) == (1080, 1128)
    assert len(data) > 80_000
    with pytest.raises(OutputError):
        plot_tracking(val, tmp_path / "fig" / "tracking.png")
    assert val.plot(tmp_path / "fig" / "tracking.png", overwrite=True) == out
    no_force = validate_tracking(t, x, r, _sim(t, x, v, np.zeros(N)))
    assert _png_size(Path(plot_tracking(no_force, tmp_path / "b.png")).read_bytes()) == (1080, 864)
    fig = plot_tracking(no_force)  # no path: the figure itself
    assert len(fig.axes) == 3


def test_text_report_and_summary():
    t, x, r, v = _record()
    u = np.sin(3 * W * t)
    val = validate_tracking(t, x, r, _sim(t, x + 10e-6, v, 1.05 * 2.0 * u), u=u,
                            command_gain=2.0, velocity="central-difference", trim=(49, 0))
    text = tracking_text(val)
    assert val.report() == text
    lines = text.splitlines()
    assert "samples 50–2000 of 2000" in lines[1]  # the benchmark's 50:end
    tracking_line = next(line for line in lines if line.strip().startswith("tracking error"))
    assert float(tracking_line.split()[2]) == pytest.approx(1.0, rel=1e-3)  # 10 µm / 1 mm
    force_line = next(line for line in lines if line.strip().startswith("force"))
    assert float(force_line.split()[1]) == pytest.approx(5.0, rel=1e-3)
    # a result that carries a validation is reported through it
    assert tracking_text(SimpleNamespace(validation=val)) == text
    summary = val.summary()
    json.dumps(summary)  # JSON-ready
    assert summary["window"] == {"start": 49, "stop": N, "t_start": pytest.approx(0.049),
                                 "t_end": pytest.approx((N - 1) * T)}
    assert summary["signals"]["force"]["relative_error_percent"] == pytest.approx(5.0)


# ---- the EMPS record ---------------------------------------------------------------------

# The benchmark's published IDIM-LS estimates (EMPS README; "Data Set and Reference Models of
# EMPS", section 3.4) and the issue's acceptance for the simulated record, per command delay:
# (tracking-error relative error %, force relative error %).
IDIM = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "OF": -3.1648}
ACCEPT = {0.0: (0.30, 5.0), 1e-3: (0.45, 7.5)}
# The benchmark's own simulation (description, section 3.5: Simulink, one-sample delay after the
# controller) prints a velocity relative error of 0.22911 %, with the same velocity definition.
BENCHMARK_VELOCITY = 0.22911


@pytest.fixture(scope="module")
def emps_validations():
    if not EMPS_FILE.is_file():
        pytest.skip(EMPS_ABSENT)
    tracking = pytest.importorskip("phoid.simulation.tracking",
                                   reason="simulate_tracking is not on this branch")
    from scipy.io import loadmat

    from phoid import Plant
    from phoid.dynamics.controller import SampledController

    d = loadmat(EMPS_FILE)
    t, qm, qg, vir = (d[k].ravel() for k in ("t", "qm", "qg", "vir"))
    gtau, kp, kv = (float(d[k].ravel()[0]) for k in ("gtau", "kp", "kv"))
    plant = Plant(m=IDIM["M"], c=IDIM["Fv"], k=0.0, fc=IDIM["Fc"])
    out = {}
    for delay in ACCEPT:
        ctrl = SampledController(sample_time=1e-3, P=kp, D=1.0, gain=kv, command_gain=gtau,
                                 velocity="central-difference", delay=delay, saturation=10.0)
        # the recorded initial state: the first three positions (the central difference's
        # history), the velocity at the third by central difference, the two commands before
        sim = tracking.simulate_tracking(plant, ctrl, qg[2:], offset=IDIM["OF"],
                                         x_init=qm[:3], v0=(qm[3] - qm[1]) / 2e-3,
                                         u_init=vir[:2], t0=t[2])
        # trim 47 from sample 2 on: the benchmark's window, samples 50:end (MATLAB, 1-based)
        out[delay] = validate_tracking(t[2:], qm[2:], qg[2:], sim, u=vir[2:],
                                       command_gain=gtau, trim=(47, 0))
    return out


@pytest.mark.parametrize("delay", sorted(ACCEPT))
def test_emps_published_parameters_meet_the_acceptance(emps_validations, delay):
    val = emps_validations[delay]
    tracking_max, force_max = ACCEPT[delay]
    assert val.window[0] + 2 == 49  # 0-based index 49 of the record: MATLAB's sample 50
    assert val.error("tracking error").relative_error <= tracking_max, tracking_text(val)
    assert val.error("force").relative_error <= force_max, tracking_text(val)
    assert val.warnings == (), val.warnings  # |vir| ≤ 4.3 V: never at the 10 V saturation


def test_emps_velocity_error_as_the_benchmark_prints_it(emps_validations):
    """With the benchmark's one-sample delay its simulation prints a velocity relative error of
    0.22911 %; ours, with the same velocity definition, lies within 5 % of it. (The simulators
    differ — Simulink's ode45 with the delay block against the exact sampled loop — and so do
    the initial states, so agreement beyond a few per cent is not expected.)"""
    velocity = emps_validations[1e-3].error("velocity").relative_error
    assert velocity == pytest.approx(BENCHMARK_VELOCITY, rel=0.05)
