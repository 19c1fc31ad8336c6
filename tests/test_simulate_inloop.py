"""Sensor noise and quantisation inside the loop (``simulate(..., noise_in_loop=...)``).

The sampled loop is checked against an independent reference written here: the plant's exact
zero-order-hold map over one recorder interval from ``scipy.linalg.expm`` and a plain Python
loop over the recorder samples in which the controller, at its instants, reads
x̃ = quantise(x + offset + e) with the same noise draws (``noise * rng.standard_normal((B, N))``
of the same seed, the simulator's documented stream). The continuous option is checked against
``scipy.integrate.solve_ivp`` (DOP853) run interval by interval with the delayed force.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from phoid import Plant
from phoid.errors import PhoidError
from phoid.simulation import simulate

M_, C_, K_ = 1.0, 2.0, 100.0
P2 = np.array([50.0, 80.0])
D2 = np.array([0.5, -0.2])
X0, V0 = 0.01, 0.02
NOISE, OFFSET = 1e-5, 2e-5
TS = 0.002
# Rounding: simulator and reference take different (exact) routes — one-period maps, the
# closed loop's recursion and its refinement against one-interval maps — so they agree to
# accumulated rounding, ≈ N·ε·(loop gain) ≲ 1e-12 of the motion over these ≤ 2400 samples.
# 1e-9 of the motion leaves three decades and still fails on any modelling slip (a reading one
# sample late, a missed offset or noise draw moves x by ≥ 1e-6 of the motion).
# With a quantiser a reading could flip by one step only if x + offset + e fell within ~1e-17 m
# of a rounding boundary: probability ~1e-11 per reading, negligible.
REL = 1e-9


# velocity estimators, by hand: Σᵢ aᵢ v̂ₙ₋ᵢ = Σⱼ bⱼ x̃ₙ₋ⱼ (b in 1/s)
_POLE = np.exp(-300.0 * TS)
ESTIMATORS = {
    "backward-difference": (dict(velocity="backward-difference"), (1 / TS, -1 / TS), (1.0,)),
    "filtered": (dict(velocity="filtered", cutoff=300.0),
                 ((1 - _POLE) / TS, -(1 - _POLE) / TS), (1.0, -_POLE)),
    "central-difference": (dict(velocity="central-difference"),
                           (0.5 / TS, 0.0, -0.5 / TS), (1.0,)),
    "fir": (dict(velocity=(3 / (6 * TS), -1 / (6 * TS), -1 / (6 * TS), -1 / (6 * TS))),
            (3 / (6 * TS), -1 / (6 * TS), -1 / (6 * TS), -1 / (6 * TS)), (1.0,)),
}


def _sampled_reference(P, D, *, M, d, est, hold, duration, e, quantum, plant=(M_, C_, K_),
                       v0=V0, offset=OFFSET):
    """Per-recorder-interval loop: exact ZOH maps Φ(h), Γ(h) from expm; the controller reads
    x̃ = Q(x + offset + e_j) at j = nM, v̂_n = Σ b_j x̃_{n−j} − Σ_{i≥1} a_i v̂_{n−i} with
    x̃ = Q(x₀ + offset), v̂ = 0 before the record; applied u_{n−d} (−P Q(x₀ + offset) before
    the record)."""
    b, a = (np.array(c) for c in ESTIMATORS[est][1:])
    m, c, k = plant
    fs = M / TS
    h = 1.0 / fs
    N = round((hold + duration) * fs)
    j_rel = round(hold * fs)
    Mx = np.zeros((3, 3))
    Mx[:2, :2] = np.array([[0.0, 1.0], [-k / m, -c / m]]) * h
    Mx[1, 2] = h / m
    E = expm(Mx)
    Phi, Gam = E[:2, :2], E[:2, 2]

    def Q(z):
        return np.round(z / quantum) * quantum if quantum > 0 else z

    B = len(P)
    X, XR, UA = np.empty((B, N)), np.empty((B, N)), np.empty((B, N))
    for r in range(B):
        x_pre = Q(X0 + offset)
        xs, vs, U = [x_pre] * (b.size - 1), [0.0] * (a.size - 1), {}  # the histories
        y = np.array([X0, 0.0])
        for j in range(N):
            if j == j_rel:
                y = np.array([X0, v0])
            X[r, j] = y[0]
            XR[r, j] = Q(y[0] + offset + e[r, j])
            n = j // M
            if j % M == 0:
                xs.append(XR[r, j])
                ve = sum(b[i] * xs[-1 - i] for i in range(b.size))
                ve -= sum(a[i] * vs[-i] for i in range(1, a.size))
                vs.append(ve)
                U[n] = -(P[r] * XR[r, j] + D[r] * ve)
            UA[r, j] = U[n - d] if n - d >= 0 else -P[r] * x_pre
            if j >= j_rel:
                y = Phi @ y + Gam * UA[r, j]
    return X, XR, UA


def _draws(seed, shape):
    """The simulator's documented noise stream."""
    return NOISE * np.random.default_rng(seed).standard_normal(shape)


def _close(sim, ref, what=""):
    X, XR, UA = ref
    scale = np.max(np.abs(X))
    np.testing.assert_allclose(sim.x_true, X, rtol=0, atol=REL * scale, err_msg="x_true " + what)
    np.testing.assert_allclose(sim.x, XR, rtol=0, atol=REL * scale, err_msg="x " + what)
    np.testing.assert_allclose(sim.u, UA, rtol=0, atol=REL * np.max(np.abs(UA)),
                               err_msg="u " + what)


@pytest.mark.parametrize("quantum", [0.0, 1e-6])
@pytest.mark.parametrize("M", [1, 4])
@pytest.mark.parametrize("d", [0, 3])
@pytest.mark.parametrize("est", list(ESTIMATORS))
def test_sampled_in_loop_matches_reference(est, d, M, quantum):
    # hold 0.203 s with M = 4: a release between two controller instants (a partial period)
    hold = 0.203 if M == 4 else 0.2
    sim = simulate(Plant(M_, C_, K_), P2, D2, duration=1.0, fs=M / TS, x0=X0, v0=V0,
                   hold=hold, sample_time=TS, delay_samples=d, noise=NOISE, quantum=quantum,
                   offset=OFFSET, rng=np.random.default_rng(5), **ESTIMATORS[est][0])
    assert sim.noise_in_loop is True  # the default of a sampled loop
    e = _draws(5, sim.x.shape)
    _close(sim, _sampled_reference(P2, D2, M=M, d=d, est=est, hold=hold, duration=1.0,
                                   e=e, quantum=quantum))
    # the recorded value at a controller instant is what the controller read: bit for bit
    # with the quantiser (both are quantise(x_true + offset + e) of the same x_true there)
    if quantum:
        inst = sim.x[:, ::M]
        again = np.round((sim.x_true[:, ::M] + OFFSET + e[:, ::M]) / quantum) * quantum
        assert np.array_equal(inst, again)


@pytest.mark.parametrize("est", ["backward-difference", "central-difference"])
@pytest.mark.parametrize("quantum", [0.0, 1e-6])
def test_block_path_reads_the_sensor(quantum, est):
    # a bias with every sign prescribed 0 leaves the loop linear but takes the block-by-block
    # path (the friction's): it must read x̃ like the others
    M, d, hold = 3, 2, 0.006
    sim = simulate(Plant(M_, C_, K_), P2, D2, duration=0.8, fs=M / TS, x0=X0, v0=V0,
                   hold=hold, sample_time=TS, delay_samples=d, noise=NOISE, quantum=quantum,
                   offset=OFFSET, rng=np.random.default_rng(8), bias=0.1,
                   bias_signs=np.zeros((2, 1000)), **ESTIMATORS[est][0])
    _close(sim, _sampled_reference(P2, D2, M=M, d=d, est=est, hold=hold, duration=0.8,
                                   e=_draws(8, sim.x.shape), quantum=quantum))


@pytest.mark.parametrize("est", ["central-difference", "fir"])
@pytest.mark.parametrize("bias", [None, 0.1])
def test_other_estimators_outside_the_loop(est, bias):
    # estimators that are not first-order (no χ recursion): the exact x read, one exact step
    # per period (linear) or the block path (a bias, its signs prescribed 0), as the reference
    # reading x itself (offset and noise 0)
    M, d, hold = 2, 1, 0.1
    kw = {} if bias is None else dict(bias=bias, bias_signs=np.zeros((2, 1000)))
    sim = simulate(Plant(M_, C_, K_), P2, D2, duration=0.8, fs=M / TS, x0=X0, v0=V0, hold=hold,
                   sample_time=TS, delay_samples=d, noise=NOISE, offset=OFFSET,
                   rng=np.random.default_rng(4), noise_in_loop=False, **kw,
                   **ESTIMATORS[est][0])
    X, _, UA = _sampled_reference(P2, D2, M=M, d=d, est=est, hold=hold, duration=0.8,
                                  e=np.zeros(sim.x.shape), quantum=0.0, offset=0.0)
    np.testing.assert_allclose(sim.x_true, X, rtol=0, atol=REL * np.max(np.abs(X)))
    np.testing.assert_allclose(sim.u, UA, rtol=0, atol=REL * np.max(np.abs(UA)))
    assert np.array_equal(sim.x, sim.x_true + OFFSET + _draws(4, sim.x.shape))


def test_friction_stuck_mass_commands_from_readings():
    # friction far above every force the loop makes (k x0 + P x̃ ≈ 1.5 N < 5 N): the mass never
    # moves, so the controller reads Q(x0 + offset + e) throughout; its commands (filtered
    # estimator, d = 1) are then the reference's with the mass held for the whole record
    M, d, q = 2, 1, 1e-6
    sim = simulate(Plant(M_, C_, K_, 5.0), P2, D2, duration=0.5, fs=M / TS, x0=X0, hold=0.1,
                   sample_time=TS, delay_samples=d, velocity="filtered", cutoff=300.0,
                   noise=NOISE, quantum=q, offset=OFFSET, rng=np.random.default_rng(9))
    _, XR, UA = _sampled_reference(P2, D2, M=M, d=d, est="filtered", hold=0.6, duration=1e-9,
                                   e=_draws(9, sim.x.shape), quantum=q, v0=0.0)
    assert np.all(sim.x_true == X0)
    assert np.array_equal(sim.x, XR)
    np.testing.assert_allclose(sim.u, UA, rtol=0, atol=1e-12 * np.max(np.abs(UA)))


def test_force_in_loop_agrees_across_paths():
    # an external force with the noise in the loop: the superposition (linear path), the
    # period-by-period path (a quantiser of 1e-16 m: it moves a reading by ≤ 5e-17 m, 5e-15 of
    # x0) and the block-by-block path (bias signs all 0) must give the same motion
    def force(t):
        return 0.3 * np.sin(7.0 * t)

    kw = dict(duration=0.8, fs=4 / TS, x0=X0, v0=V0, hold=0.203, sample_time=TS,
              delay_samples=3, noise=NOISE, offset=OFFSET, force=force, velocity="filtered",
              cutoff=300.0)
    lin = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(5), **kw)
    step = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(5), quantum=1e-16,
                    **kw)
    block = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(5), bias=0.1,
                     bias_signs=np.zeros((2, 1000)), **kw)
    for other in (step, block):
        np.testing.assert_allclose(other.x_true, lin.x_true, rtol=0, atol=REL * X0)
        np.testing.assert_allclose(other.u, lin.u, rtol=0, atol=REL * np.max(np.abs(lin.u)))


@pytest.mark.parametrize("sample_time", [None, TS])
def test_outside_loop_is_todays_model(sample_time):
    # today's model: the loop runs on the exact position (the noise-free simulation) and the
    # record is quantise(x_true + offset + noise draws), the draws noise·standard_normal((B, N))
    loop = (dict(sample_time=sample_time, delay_samples=2, fs=4 / TS) if sample_time
            else dict(delay=0.01, fs=1000.0))
    kw = dict(duration=0.6, x0=X0, hold=0.1, **loop)
    clean = simulate(Plant(M_, C_, K_), P2, D2, **kw)
    q = 1e-6
    sim = simulate(Plant(M_, C_, K_), P2, D2, noise=NOISE, quantum=q, offset=OFFSET,
                   rng=np.random.default_rng(3), noise_in_loop=False, **kw)
    assert sim.noise_in_loop is False
    assert np.array_equal(sim.x_true, clean.x_true)
    assert np.array_equal(sim.u, clean.u)
    expected = np.round((clean.x_true + OFFSET + _draws(3, sim.x.shape)) / q) * q
    assert np.array_equal(sim.x, expected)


def test_default_by_loop_type():
    kw = dict(duration=0.6, x0=X0, hold=0.1, noise=NOISE, offset=OFFSET)
    dig = dict(sample_time=TS, delay_samples=1, fs=1 / TS)
    # sampled: in the loop unless told otherwise
    default = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(1), **kw, **dig)
    inside = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(1),
                      noise_in_loop=True, **kw, **dig)
    outside = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(1),
                       noise_in_loop=False, **kw, **dig)
    assert default.noise_in_loop and not outside.noise_in_loop
    assert np.array_equal(default.x_true, inside.x_true)
    # the loop's reaction to the offset alone is P·offset/(k + P) ≈ 7e-6 m: far above rounding
    assert np.max(np.abs(default.x_true - outside.x_true)) > 1e-6
    # continuous: outside unless told otherwise
    cont = dict(delay=0.01, fs=1000.0)
    default = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(1), **kw, **cont)
    outside = simulate(Plant(M_, C_, K_), P2, D2, rng=np.random.default_rng(1),
                       noise_in_loop=False, **kw, **cont)
    assert default.noise_in_loop is False
    assert np.array_equal(default.x, outside.x)
    # nothing for the controller to read (no noise, quantum or offset): in = out, bit for bit
    a = simulate(Plant(M_, C_, K_), P2, D2, duration=0.6, x0=X0, hold=0.1, **dig)
    b = simulate(Plant(M_, C_, K_), P2, D2, duration=0.6, x0=X0, hold=0.1, noise_in_loop=False,
                 **dig)
    assert np.array_equal(a.x_true, b.x_true) and np.array_equal(a.u, b.u)


def test_offset_in_the_loop_moves_the_equilibrium():
    # the controller reads x + offset: statics k x = −P (x + offset), x_eq = −P·offset/(k + P)
    # (the encoder's zero is not the spring's). The loops (ζ ≈ 0.1 at ω ≈ 12 rad/s) have decayed
    # to e^{−σ·8 s} < 1e-4 of x0 = 1e-3 m by the end: 1e-7 m is the tolerance.
    off = 1e-3
    sim = simulate(Plant(M_, C_, K_), P2, np.array([2.0, 2.5]), duration=8.0, fs=1 / TS,
                   x0=1e-3, sample_time=TS, delay_samples=1, offset=off)
    np.testing.assert_allclose(sim.x_true[:, -1], -P2 * off / (K_ + P2), rtol=0, atol=1e-7)
    # recorded = read = x + offset, to the rounding of the loop's two routes (≲ 1e-12 of x0)
    np.testing.assert_allclose(sim.x[:, -1], sim.x_true[:, -1] + off, rtol=0, atol=1e-15)


def _continuous_reference(P, D, delay, fs, hold, duration, e):
    """solve_ivp (DOP853, rtol 1e-12) one sample interval at a time; the controller reads
    x + offset + ẽ, ẽ the draws joined by lines (0 at sample −1, the last slope continued);
    the delayed motion from the earlier intervals' dense output (x₀ at rest while held)."""
    N = round((hold + duration) * fs)
    j_rel = round(hold * fs)
    dd = round(delay * fs)
    B = len(P)
    X, UA = np.empty((B, N)), np.empty((B, N))
    for b in range(B):
        ext = np.zeros(N + 2)  # ẽ at samples −1 … N
        ext[1 : N + 1] = e[b]
        ext[N + 1] = 2 * e[b, -1] - e[b, -2]
        pieces = {}

        def force(j, t, y, b=b, ext=ext, pieces=pieces):
            jd = j - dd  # the sample interval the delayed reading lies in
            if dd == 0:
                xd, vd = y[0], y[1]
            elif jd < j_rel:
                xd, vd = X0, 0.0
            else:
                xd, vd = pieces[jd](t - delay)
            if jd < -1:
                eps, deps = OFFSET, 0.0
            else:
                e0, e1 = ext[jd + 1], ext[jd + 2]
                eps = OFFSET + e0 + (e1 - e0) * (t - j / fs) * fs
                deps = (e1 - e0) * fs
            return -P[b] * (xd + eps) - D[b] * (vd + deps)

        X[b, :j_rel] = X0
        for j in range(j_rel):
            UA[b, j] = force(j, j / fs, (X0, 0.0))
        y = np.array([X0, 0.0])
        for j in range(j_rel, N):
            X[b, j] = y[0]
            UA[b, j] = force(j, j / fs, y)
            if j == N - 1:
                break
            sol = solve_ivp(
                lambda t, yy, j=j: [yy[1], (force(j, t, yy) - C_ * yy[1] - K_ * yy[0]) / M_],
                (j / fs, (j + 1) / fs), y, method="DOP853", rtol=1e-12, atol=1e-16,
                dense_output=True)
            pieces[j] = sol.sol
            y = sol.y[:, -1]
    return X, UA


@pytest.mark.parametrize("delay", [0.0, 0.015])
def test_continuous_in_loop_matches_solve_ivp(delay):
    # 200 Hz, delay 0 or 3 whole samples, hold 10 samples. Tolerance 1e-8 of the motion: the
    # reference's DOP853 (rtol 1e-12) restarted at each of 300 samples and its dense output
    # (≈ 1e-12 each), the simulator's quintic Hermite of the delayed motion
    # ((ρh)⁶/46080 ≈ 1e-11 at ρh ≤ 0.1); both ~1e-12 here, so two decades of margin and still
    # 1e-4 of the noise's own effect (a noise draw read late or not at all is ≥ 1e-6).
    fs, hold, duration = 200.0, 0.05, 1.5
    sim = simulate(Plant(M_, C_, K_), P2, D2, delay=delay, duration=duration, fs=fs, x0=X0,
                   hold=hold, noise=NOISE, offset=OFFSET, rng=np.random.default_rng(5),
                   noise_in_loop=True)
    assert sim.noise_in_loop is True
    e = _draws(5, sim.x.shape)
    X, UA = _continuous_reference(P2, D2, delay, fs, hold, duration, e)
    np.testing.assert_allclose(sim.x_true, X, rtol=0, atol=1e-8 * np.max(np.abs(X)))
    np.testing.assert_allclose(sim.u, UA, rtol=0, atol=1e-8 * np.max(np.abs(UA)))
    np.testing.assert_allclose(sim.x, sim.x_true + OFFSET + e, rtol=0, atol=1e-17)


@pytest.mark.parametrize(("extra", "words"), [
    (dict(quantum=1e-6), "quantiser"),
    (dict(bias=0.1), "bias"),
    (dict(plant=Plant(M_, C_, K_, 0.05)), "friction"),
    (dict(delay=0.0123456789), "internal grid"),
    (dict(hold=0.00051), "internal grid"),
])
def test_continuous_in_loop_refusals(extra, words):
    kw = dict(delay=0.01, duration=0.5, fs=1000.0, x0=X0, noise=NOISE,
              rng=np.random.default_rng(1), noise_in_loop=True)
    plant = extra.pop("plant", Plant(M_, C_, K_))
    kw.update(extra)
    with pytest.raises(ValueError, match=words) as info:
        simulate(plant, P2, D2, **kw)
    assert "\n" not in str(info.value) and "noise_in_loop" in str(info.value)


@pytest.mark.parametrize("bad", ["yes", 1, 0.0])
def test_noise_in_loop_must_be_bool_or_none(bad):
    with pytest.raises(ValueError, match="noise_in_loop"):
        simulate(Plant(M_, C_, K_), P2, D2, duration=0.5, fs=1 / TS, sample_time=TS,
                 noise_in_loop=bad)


def test_a_motion_the_reading_overflows_is_refused_in_one_line():
    # an offset of 1e300 m read through P = 1e10 N/m drives the motion past the float range:
    # the one-line refusal names the sensor's parameters (no RuntimeWarning on the way)
    with pytest.raises(PhoidError, match="offset") as info:
        simulate(Plant(M_, C_, K_), 1e10, 0.5, duration=0.5, fs=1 / TS, sample_time=TS,
                 offset=1e300)
    assert "\n" not in str(info.value)


# --- the CLI ---------------------------------------------------------------------------------

_CLI_COMMON = ["--m", "1", "--c", "2", "--k", "100", "--P", "50,80", "--D", "0.5,1",
               "--duration", "0.5", "--hold", "0.1", "--seed", "3"]


def _manifest(folder):
    import tomllib

    return tomllib.loads((folder / "experiment.toml").read_text(encoding="utf-8"))


@pytest.mark.parametrize(("flag", "placement"), [
    ([], "in-loop"), (["--noise-in-loop"], "in-loop"), (["--noise-outside"], "outside")])
def test_cli_digital_loop_writes_the_noise_placement(tmp_path, flag, placement):
    from typer.testing import CliRunner

    from phoid.cli import app

    out = tmp_path / "set"
    r = CliRunner().invoke(app, ["simulate", str(out), *_CLI_COMMON, "--sample-time", "0.002",
                                 "--delay-samples", "1", "--fs", "500", "--noise", "1e-5",
                                 *flag])
    assert r.exit_code == 0, r.output
    assert _manifest(out)["loop"]["noise"] == placement
    # the recorded x is the simulator's for that placement (same seed, same draws)
    sim = simulate(Plant(1.0, 2.0, 100.0), [50.0, 80.0], [0.5, 1.0], duration=0.5, hold=0.1,
                   fs=500.0, sample_time=0.002, delay_samples=1, noise=1e-5,
                   rng=np.random.default_rng(3), noise_in_loop=placement == "in-loop")
    import phoid.io

    runs = phoid.io.read_experiment(out).runs
    for i in range(2):  # the CSV holds the shortest repr: the same doubles
        assert np.array_equal(runs[i].x, sim.x[i])


def test_cli_without_noise_writes_no_placement_continuous_states_it(tmp_path):
    from typer.testing import CliRunner

    from phoid.cli import app

    runner = CliRunner()
    clean = tmp_path / "clean"
    r = runner.invoke(app, ["simulate", str(clean), *_CLI_COMMON, "--sample-time", "0.002",
                            "--fs", "500"])
    assert r.exit_code == 0, r.output
    assert "noise" not in _manifest(clean)["loop"]
    cont = tmp_path / "cont"
    r = runner.invoke(app, ["simulate", str(cont), *_CLI_COMMON, "--delay", "0.01",
                            "--fs", "500", "--noise", "1e-5", "--noise-in-loop"])
    assert r.exit_code == 0, r.output
    # a continuous loop states it too (its identification stays modal, with a warning)
    assert _manifest(cont)["loop"]["noise"] == "in-loop"


@pytest.mark.parametrize(("args", "needle"), [
    (["--delay", "0.01", "--noise-in-loop", "--quantum", "1e-6"], "--noise-outside"),
    (["--delay", "0.0123456789", "--noise-in-loop"], "internal grid"),
    (["--method", "free", "--noise-outside"], "--noise-outside does not apply"),
])
def test_cli_noise_in_loop_refusals(tmp_path, args, needle):
    from typer.testing import CliRunner

    from phoid.cli import app

    common = [a for a in _CLI_COMMON if a not in ("--P", "50,80", "--D", "0.5,1")] \
        if "free" in args else _CLI_COMMON
    r = CliRunner().invoke(app, ["simulate", str(tmp_path / "x"), *common, "--fs", "1000",
                                 "--noise", "1e-5", *args])
    assert r.exit_code == 2 and "Traceback" not in r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], lines
