"""The seed's DC-offset augmentation: a bias b·sign(ẋ(t − Δt)) added to the PD command.

The seed (Discussion, last paragraph): with high kinetic friction and little viscous damping a
PHO run sticks after a few cycles, "unless the PD feedback is augmented with a DC offset in the
(alternating) direction of oscillation". Here u = −P x(t − Δt) − D ẋ(t − Δt) + b sign(ẋ(t − Δt))
(sign(0) = 0), or uₙ = −P xₙ − D v̂ₙ + b sign(v̂ₙ) for the sampled controller, with b known per
run (``[[run]] bias``).

Where the expected values come from
-----------------------------------
- Simulator: an independent integration of the same equations, written here from the model's
  definition — scipy's ``solve_ivp`` (DOP853, rtol 1e−12) by the method of steps (segments no
  longer than Δt, so the delayed terms are read from already computed dense output), with the
  velocity reversals located as terminal events and the stick test (|g| ≤ f_c) applied there;
  the sampled loop by the same integration period by period with the commands computed from
  their definition. No matrix exponential, no Hermite interpolation.
- Acceptance: the plant handed to the simulator (m 1 kg, c 0.3 N s/m, k 100 N/m, f_c 0.2 N,
  the brief's set); D solved (brentq) so that each loop's dominant root decays at a chosen
  σ (0.03–0.12 1/s: little viscous damping, the seed's scenario); "within 3 stderr" is the
  spec's promise for m, c, k (and f_c). Cycle counts are the simulator's exact velocity
  reversals / 2, with and without bias, measured (printed in the report of the commit).
"""

from __future__ import annotations

import bisect
import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from typer.testing import CliRunner

from phoid import Plant, read_experiment, run_from_arrays, simulate, write_experiment
from phoid.api import identify
from phoid.cli import app
from phoid.dynamics.rightmost import dominant_roots
from phoid.errors import ExperimentError, IdentificationError

M, C, K, FC = 1.0, 0.3, 100.0, 0.2  # kg, N s/m, N/m, N
DELAY = 0.01  # s
X0 = 5e-3  # m
NOISE = 10e-6  # m
TRUE = {"m": M, "c": C, "k": K, "fc": FC}


# --------------------------------------------------------------------------------------------
# independent references


def reference_delayed(m, c, k, fc, P, D, delay, b, x0, t_end):
    """Method-of-steps integration (DOP853, rtol 1e−12) of m ẍ + c ẋ + k x + f_c sign(ẋ) = u,
    u = −P x(t − Δt) − D ẋ(t − Δt) + b sign(ẋ(t − Δt)), released from rest at x₀ at t = 0
    (history: x = x₀, ẋ = 0). Returns a function of t giving (x, ẋ)."""
    segs: list[tuple] = []  # (t0, t1, dense solution or None, mode, stuck position)
    starts: list[float] = []

    def look(tau):
        if tau <= 0.0:
            return x0, 0.0, 0
        i = bisect.bisect_right(starts, tau) - 1
        _t0, t1, sol, mode, xs = segs[i]
        if sol is None:
            return xs, 0.0, 0
        y = sol(min(tau, t1))
        return y[0], y[1], mode

    def u_of(t, mode, y):
        if delay == 0.0:
            return -P * y[0] - D * y[1] + b * mode
        xd, vd, md = look(t - delay)
        return -P * xd - D * vd + b * md

    def decide(t, x):
        g = -k * x + u_of(t, 0, (x, 0.0))
        return 0 if abs(g) <= fc else int(np.sign(g))

    t, y = 0.0, np.array([x0, 0.0])
    mode = decide(0.0, x0)
    breaks: list[float] = []  # a reversal's images Δt, 2Δt, 3Δt later (input kinks, jumps)
    while t < t_end - 1e-13:
        nxt = min([bt for bt in breaks if bt > t + 1e-13] + [t_end]
                  + ([t + delay] if delay > 0 else []))
        if mode != 0:
            def rhs(tt, yy, s=mode):
                return [yy[1], (-c * yy[1] - k * yy[0] - fc * s + u_of(tt, s, yy)) / m]

            def rev(tt, yy, s=mode, t0=t):
                return yy[1] * s if tt > t0 + 1e-12 else abs(yy[1]) + 1.0

            rev.terminal, rev.direction = True, -1
            sol = solve_ivp(rhs, (t, nxt), y, method="DOP853", rtol=1e-12, atol=1e-15,
                            dense_output=True, events=rev)
            t1 = float(sol.t[-1])
            segs.append((t, t1, sol.sol, mode, 0.0))
            starts.append(t)
            y = sol.y[:, -1].copy()
            if sol.status == 1:
                y[1] = 0.0
                mode = decide(t1, y[0])
                breaks += [t1 + j * delay for j in (1, 2, 3)]
            t = t1
        else:
            xs = y[0]
            if delay == 0.0:  # at rest with constant forces: stuck for good
                segs.append((t, t_end, None, 0, xs))
                starts.append(t)
                break

            def unstick(tt, yy, xs=xs):
                return abs(-k * xs + u_of(tt, 0, (xs, 0.0))) - fc

            unstick.terminal, unstick.direction = True, 1
            sol = solve_ivp(lambda tt, yy: [0.0, 0.0], (t, nxt), [xs, 0.0], method="DOP853",
                            rtol=1e-12, atol=1e-15, events=unstick, max_step=delay / 50)
            t1 = float(sol.t[-1])
            segs.append((t, t1, None, 0, xs))
            starts.append(t)
            if sol.status == 1:
                mode = int(np.sign(-k * xs + u_of(t1, 0, (xs, 0.0))))
                breaks += [t1 + j * delay for j in (1, 2, 3)]
            t, y = t1, np.array([xs, 0.0])

    def evaluate(tt):
        out = np.empty((2, tt.size))
        for j, tau in enumerate(tt):
            _t0, t1, sol, _, xs = segs[bisect.bisect_right(starts, tau) - 1]
            out[:, j] = (xs, 0.0) if sol is None else sol(min(tau, t1))
        return out

    return evaluate


def reference_sampled(m, c, k, fc, P, D, Ts, d, b, x0, fs, N):
    """The sampled loop integrated sample by sample (DOP853, rtol 1e−12, events): commands
    uₙ = −P xₙ − D v̂ₙ + b sign(v̂ₙ), v̂ₙ = (xₙ − xₙ₋₁)/T_s, applied d periods later and held;
    −P x₀ before (released from rest at x₀ at t = 0)."""
    Mr = round(fs * Ts)
    U: dict[int, float] = {}
    xs, vs = np.empty(N), np.empty(N)
    y, mode, x_prev = np.array([x0, 0.0]), 0, x0
    for j in range(N):
        t = j / fs
        if j % Mr == 0:
            ve = (y[0] - x_prev) / Ts
            x_prev = y[0]
            U[j // Mr] = -(P * y[0] + D * ve) + b * np.sign(ve)
        xs[j], vs[j] = y
        ua = U.get(j // Mr - d, -P * x0)
        if j == N - 1:
            break
        if mode == 0:
            g = ua - k * y[0]
            mode = 0 if abs(g) <= fc else int(np.sign(g))
        t0, t1 = t, (j + 1) / fs
        while t0 < t1 and mode != 0:
            def rhs(tt, yy, s=mode, ua=ua):
                return [yy[1], (ua - k * yy[0] - c * yy[1] - fc * s) / m]

            def halt(tt, yy, s=mode, ts=t0):
                return yy[1] * s if tt > ts + 1e-12 else 1.0

            halt.terminal, halt.direction = True, -1
            sol = solve_ivp(rhs, (t0, t1), y, method="DOP853", rtol=1e-12, atol=1e-16,
                            events=halt)
            y = sol.y[:, -1].copy()
            if sol.status != 1:
                break
            t0 = float(sol.t[-1])
            y[1] = 0.0
            g = ua - k * y[0]
            mode = 0 if abs(g) <= fc else int(np.sign(g))
    return xs, vs


def reversals(v: np.ndarray) -> int:
    nz = v[v != 0.0]
    return int(np.count_nonzero(np.diff(np.sign(nz)) != 0))


# --------------------------------------------------------------------------------------------
# simulator


@pytest.mark.parametrize(
    ("fc", "P", "D", "delay", "b"),
    [
        (FC, 200.0, 0.1, DELAY, 0.15),  # friction, delayed bias
        (FC, 100.0, -0.2, DELAY, 0.18),  # negative D, bias close to f_c
        (0.0, 200.0, 0.1, DELAY, 0.1),  # no friction: the bias alone (velocity reversals)
        (FC, 200.0, 0.1, 0.0, 0.15),  # Δt = 0: the bias acts as negative friction
    ],
)
def test_simulator_matches_the_method_of_steps_reference(fc, P, D, delay, b):
    T = 3.0
    ref = reference_delayed(M, C, K, fc, P, D, delay, b, X0, T)
    sim = simulate(Plant(M, C, K, fc), [P], [D], delay=delay, duration=T, fs=1000.0, x0=X0,
                   bias=b)
    x, v = ref(sim.t)
    err = np.max(np.abs(sim.x_true[0] - x))
    if delay == 0.0:
        # both exact up to rounding and event location (~1e−15 s): measured 1.5e−14 m
        assert err < 1e-12 * X0 / 5e-3
        return
    # the bias enters exactly (steps cut at its switches); what is left is the simulator's
    # documented O(h²) interpolation of the delayed PD input across a step holding an event
    # (module docstring): measured 1.8e−10 … 8.2e−10 m at 1 kHz over ~16 reversals; bound
    # ×2.5. At 4 kHz it must fall by ≥ 4 (O(h²) would give 16; measured 8–12): an O(h)
    # treatment of the bias's jumps would fall by 4 only and start 100× higher.
    assert err < 2e-9
    # velocity: the same error times the loop's frequency (~17 rad/s): measured ≤ 1.5e−8 m/s
    assert np.max(np.abs(sim.v[0] - v)) < 4e-8
    fine = simulate(Plant(M, C, K, fc), [P], [D], delay=delay, duration=T, fs=4000.0, x0=X0,
                    bias=b)
    xf, _ = ref(fine.t)
    assert np.max(np.abs(fine.x_true[0] - xf)) < err / 4
    # the test has teeth: the bias changes the motion by far more than the tolerance
    plain = simulate(Plant(M, C, K, fc), [P], [D], delay=delay, duration=T, fs=1000.0, x0=X0)
    assert np.max(np.abs(plain.x_true[0] - sim.x_true[0])) > 1e-4
    assert reversals(sim.v[0]) >= 8


def test_sampled_loop_with_bias_matches_the_per_sample_reference():
    Ts, d, fs, T = 0.002, 3, 1000.0, 2.5
    P, D, b = 150.0, 1.5, 0.15
    sim = simulate(Plant(M, C, K, FC), [P], [D], duration=T, fs=fs, x0=X0, sample_time=Ts,
                   delay_samples=d, bias=b)
    x, v = reference_sampled(M, C, K, FC, P, D, Ts, d, b, X0, fs, sim.t.size)
    # both exact between events (commands constant over each period), events located to
    # ~1e−15 s: as test_digital.py's friction reference, 1e−10·x₀
    np.testing.assert_allclose(sim.x_true[0], x, rtol=0, atol=1e-10 * X0)
    np.testing.assert_allclose(sim.v[0], v, rtol=0, atol=2e-9 * X0)
    assert reversals(sim.v[0]) >= 6  # it rings: the bias is exercised at many switches
    # the applied force is the delayed held command, bias included
    xn = sim.x_true[0, ::2]
    ve = np.diff(np.concatenate([[X0], xn])) / Ts
    un = -(P * xn + D * ve) + b * np.sign(ve)
    applied = np.concatenate([np.full(d, -P * X0), un])[: xn.size]
    np.testing.assert_allclose(sim.u[0], np.repeat(applied, 2), rtol=0, atol=1e-12)


def test_sampled_bias_pattern_is_recorded_and_can_be_held_fixed():
    # the friction fit differentiates a sampled loop with its bias pattern sign(v̂ₙ) held fixed
    # (phoid.methods.friction: the model jumps where a reversal crosses a controller instant)
    kw = dict(duration=1.5, fs=1000.0, x0=X0, sample_time=0.002, delay_samples=3, bias=0.15)
    a = simulate(Plant(M, C, K, FC), [150.0, 200.0], [1.5, 2.0], **kw)
    assert a.bias_signs.shape == (2, 750) and set(np.unique(a.bias_signs)) <= {-1.0, 0.0, 1.0}
    # recomputed from the record: the sign of the backward difference at each instant
    ve = np.diff(np.concatenate([np.full((2, 1), X0), a.x_true[:, ::2]], axis=1), axis=1)
    np.testing.assert_array_equal(a.bias_signs, np.sign(ve))
    same = simulate(Plant(M, C, K, FC), [150.0, 200.0], [1.5, 2.0], bias_signs=a.bias_signs,
                    **kw)
    np.testing.assert_array_equal(same.x_true, a.x_true)  # the same pattern: bit for bit
    flipped = a.bias_signs.copy()
    flipped[:, 100] *= -1.0  # one command's bias flipped: a different motion
    other = simulate(Plant(M, C, K, FC), [150.0, 200.0], [1.5, 2.0], bias_signs=flipped, **kw)
    assert np.max(np.abs(other.x_true - a.x_true)) > 1e-6
    with pytest.raises(ValueError, match="`bias_signs` must be an array"):
        simulate(Plant(M, C, K, FC), [150.0, 200.0], [1.5, 2.0], bias_signs=[[0.5]], **kw)
    with pytest.raises(ValueError, match="`bias_signs` applies only to a sampled controller"):
        simulate(Plant(M, C, K, FC), [150.0], [1.5], delay=DELAY, duration=0.5, fs=1000.0,
                 bias=0.1, bias_signs=[[1.0]])


def test_zero_bias_is_the_unbiased_simulation_and_bad_bias_is_refused():
    kw = dict(delay=DELAY, duration=1.0, fs=1000.0, x0=X0)
    a = simulate(Plant(M, C, K, FC), [200.0, 100.0], [0.1, 0.2], **kw)
    b = simulate(Plant(M, C, K, FC), [200.0, 100.0], [0.1, 0.2], bias=0.0, **kw)
    np.testing.assert_array_equal(a.x_true, b.x_true)  # same code path: bit for bit
    np.testing.assert_array_equal(b.bias, [0.0, 0.0])
    with pytest.raises(ValueError, match="`bias` must be ≥ 0 N"):
        simulate(Plant(M, C, K, FC), [200.0], [0.1], bias=-0.1, **kw)
    with pytest.raises(ValueError, match="`bias`"):
        simulate(Plant(M, C, K, FC), [200.0], [0.1], bias=math.nan, **kw)


# --------------------------------------------------------------------------------------------
# format


def _small_set(tmp_path, bias=(0.12, 0.0)):
    sim = simulate(Plant(M, C, K, FC), [200.0, 150.0], [2.0, 1.6], delay=DELAY, duration=0.5,
                   fs=1000.0, x0=X0, bias=np.array(bias))
    runs = [run_from_arrays(sim.t, sim.x[i], P=float(sim.P[i]), D=float(sim.D[i]),
                            bias=bias[i], index=i + 1) for i in range(2)]
    return write_experiment(tmp_path / "set", runs, method="pho", delay=DELAY)


def test_manifest_round_trip(tmp_path):
    path = _small_set(tmp_path)
    text = path.read_text()
    assert text.count("bias = 0.12") == 1 and text.count("bias") == 1  # absent when 0
    exp = read_experiment(path)
    assert [r.bias for r in exp.runs] == [0.12, 0.0]
    assert "bias" not in exp.runs[0].extra  # a known key, not an unknown one
    # an old manifest (no bias key) reads with bias 0: backward compatible
    old = path.read_text().replace("bias = 0.12\n", "")
    path.write_text(old)
    assert [r.bias for r in read_experiment(path).runs] == [0.0, 0.0]


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("-0.1", "key 'bias' must be ≥ 0 N; got -0.1"),
        ("nan", "key 'bias' must be finite; got nan"),
        ('"0.1"', "key 'bias' must be a number; got '0.1' (a string)"),
    ],
)
def test_bad_bias_is_one_line_naming_file_run_and_field(tmp_path, value, message):
    path = _small_set(tmp_path)
    path.write_text(path.read_text().replace("bias = 0.12", f"bias = {value}"))
    with pytest.raises(ExperimentError) as exc:
        read_experiment(path)
    text = str(exc.value)
    assert "\n" not in text and str(path) in text and "run 1 (run01.csv" in text
    assert message in text
    out = CliRunner().invoke(app, ["identify", str(path.parent), "--friction"])
    assert out.exit_code == 2
    assert out.stderr.strip().splitlines() == [f"phoid: error: {text}"]


def test_default_identify_refuses_a_biased_set(tmp_path):
    # the mode fit models a linear loop; a biased command is not one, and its decay is not a
    # sum of modes: refused (one line, exit 2) with a pointer to --friction, never a number
    path = _small_set(tmp_path)
    with pytest.raises(IdentificationError, match=r"bias = 0\.12 N.*--friction"):
        identify(read_experiment(path))
    out = CliRunner().invoke(app, ["identify", str(path.parent), "--json"])
    assert out.exit_code == 2 and out.stdout == ""
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "run 1 (run01.csv" in lines[0] and "--friction" in lines[0]
    # the way it names is public (issue 30: it named phoid.methods.friction's function)
    assert "phoid.methods" not in lines[0] and "phoid.identify(experiment, friction=True)" \
        in lines[0]
    import phoid

    assert "identify" in phoid.__all__


def test_cli_simulate_writes_bias_per_run(tmp_path):
    r = CliRunner().invoke(app, ["simulate", str(tmp_path / "a"), "--m", "1", "--c", "0.3",
                                 "--k", "100", "--fc", "0.2", "--P", "150,200", "--D", "1.5,2",
                                 "--delay", "0.01", "--duration", "0.5", "--x0", "0.005",
                                 "--bias", "0.1,0.15"])
    assert r.exit_code == 0, r.output
    exp = read_experiment(tmp_path / "a")
    assert [run.bias for run in exp.runs] == [0.1, 0.15]
    # the recorded force u includes the bias: the same simulation in memory
    sim = simulate(Plant(1.0, 0.3, 100.0, 0.2), [150.0, 200.0], [1.5, 2.0], delay=0.01,
                   duration=0.5, fs=1000.0, x0=0.005, hold=0.2, bias=np.array([0.1, 0.15]))
    np.testing.assert_allclose(exp.runs[1].u, sim.u[1], rtol=0, atol=1e-12)
    assert np.any(np.abs(sim.u[1] + 200.0 * np.roll(sim.x_true[1], 10)) > 0.1)  # bias shows
    r = CliRunner().invoke(app, ["simulate", str(tmp_path / "b"), "--P", "1,2", "--D", "1",
                                 "--bias", "0.1,0.2,0.3"])
    assert r.exit_code == 2 and "--bias must have one value, or one per run (2)" in r.stderr
    r = CliRunner().invoke(app, ["simulate", str(tmp_path / "c"), "--bias", "-1"])
    assert r.exit_code == 2 and "--bias must be ≥ 0 N" in r.stderr
    r = CliRunner().invoke(app, ["simulate", str(tmp_path / "d"), "--method", "free",
                                 "--bias", "0.1"])
    assert r.exit_code == 2 and "--bias does not apply to --method free" in r.stderr


# --------------------------------------------------------------------------------------------
# acceptance: the brief's set (continuous loop; a biased digital loop is refused)

P8 = np.linspace(100.0, 300.0, 8)  # N/m
SIG8 = np.linspace(0.03, 0.12, 8)[[2, 5, 0, 7, 3, 1, 6, 4]]  # 1/s, little viscous damping
B8 = np.linspace(0.10, 0.18, 8)[[3, 7, 0, 5, 2, 6, 1, 4]]  # N, against f_c = 0.2 N
X08 = np.random.default_rng(3).uniform(4.5e-3, 5.5e-3, 8)  # m


def _gains_continuous():
    def sigma(p, d):
        return -dominant_roots(M, C, K, np.array([p]), np.array([d]), DELAY)[0].real

    return np.array([brentq(lambda d, p=p, s=s: sigma(p, d) - s, -5.0, 10.0)
                     for p, s in zip(P8, SIG8, strict=True)])


def _acceptance(tmp_path, loop_kw, loop_table, D, seed):
    plant = Plant(M, C, K, FC)
    common = dict(duration=5.0, fs=1000.0, x0=X08, hold=0.2, **loop_kw)
    clean = simulate(plant, P8, D, bias=B8, **common)
    bare = simulate(plant, P8, D, **common)
    cyc_bias = np.array([reversals(v) / 2 for v in clean.v])
    cyc_bare = np.array([reversals(v) / 2 for v in bare.v])
    sim = simulate(plant, P8, D, bias=B8, noise=NOISE, rng=np.random.default_rng(seed),
                   **common)
    runs = [run_from_arrays(sim.t, sim.x[i], P=float(P8[i]), D=float(D[i]),
                            bias=float(B8[i]), index=i + 1) for i in range(P8.size)]
    write_experiment(tmp_path / "acc", runs, method="pho", **loop_table)
    out = CliRunner().invoke(app, ["identify", str(tmp_path / "acc"), "--friction", "--json"])
    assert out.exit_code == 0, out.output
    return json.loads(out.stdout), cyc_bias, cyc_bare


def _check_acceptance(s, cyc_bias, cyc_bare):
    # the paper's motivation: without bias every run sticks within 2 cycles (measured 0.5–2);
    # with b = 0.10–0.18 N the same runs ring 2.5–10 cycles (measured), more in every run
    assert np.all(cyc_bare <= 2.0)
    assert np.all(cyc_bias > cyc_bare) and np.median(cyc_bias) >= 2 * np.median(cyc_bare)
    for q in ("m", "c", "k", "fc"):
        assert abs(s[q]["value"] - TRUE[q]) < 3 * s[q]["stderr"], (q, s[q])
    assert [r["bias"] for r in s["runs"]] == pytest.approx(B8.tolist(), abs=0)


@pytest.mark.slow
def test_acceptance_continuous_loop(tmp_path):
    s, cb, c0 = _acceptance(tmp_path, {"delay": DELAY}, {"delay": DELAY}, _gains_continuous(),
                            seed=5)
    _check_acceptance(s, cb, c0)


def test_digital_loop_with_bias_is_refused_by_the_friction_fit(tmp_path):
    # A biased sampled loop's record jumps where a velocity reversal crosses a controller
    # instant; the friction fit proved unreliable there (docs/design-notes/friction.md), so
    # it refuses such a set with one line naming the run and the key, exit status 2
    loop = {"sample_time": 0.002, "delay_samples": 3}
    sim = simulate(Plant(M, C, K, FC), P8[:3], np.full(3, 1.5), duration=1.0, fs=1000.0,
                   x0=X08[:3], hold=0.2, bias=B8[:3], noise=NOISE,
                   rng=np.random.default_rng(6), **loop)
    runs = [run_from_arrays(sim.t, sim.x[i], P=float(P8[i]), D=1.5, bias=float(B8[i]),
                            index=i + 1) for i in range(3)]
    write_experiment(tmp_path / "dig", runs, method="pho", loop=loop)
    out = CliRunner().invoke(app, ["identify", str(tmp_path / "dig"), "--friction", "--json"])
    assert out.exit_code == 2 and out.stdout == ""
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "experiment.toml: run01.csv" in lines[0] and "bias = " in lines[0]
    assert "sampled (digital) loop" in lines[0]
