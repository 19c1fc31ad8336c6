"""The rig's C controller (src/phoid/rig/c), compiled here and driven sample by sample.

The reference is phoid's own model of the sampled loop: the RUN phase (and the HOLD phase, a
loop with the hold gains) must give the records of
:func:`phoid.simulation.tracking.simulate_tracking` with the same controller, started from the
plant's state, the estimator's history and the delayed commands at the release. The plant is
simulated exactly here too (zero-order hold, :func:`phoid.dynamics.controller.zoh_pieces`), so
both sides differ only by rounding: the tolerance 1e−12 of the release amplitude is the issue's
acceptance bound (≈ 10⁴ ε, room for the rounding of a few thousand samples of a stable loop).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from phoid.dynamics.controller import SampledController, closed_loop_poles, zoh_pieces
from phoid.dynamics.plant import Plant
from phoid.rig.native import (
    CFLAGS,
    SOURCES,
    CompilerNotFoundError,
    Controller,
    build_library,
    find_compiler,
)
from phoid.simulation.tracking import simulate_tracking

NO_CC = "no C compiler (CC, cc, gcc, clang): the rig's controller cannot be built"


def _cc() -> list[str]:
    """The compiler's command; the test is skipped without one."""
    cc = find_compiler()
    if cc is None:
        pytest.skip(NO_CC)
    return cc


# the seed's plant and a Table 1 gain pair (paper.py: P = 0.25 + 1.375 i, D = 0.6 + 0.3 i, i = 9),
# sampled at 100 Hz; the overdamped plant of the README (ζ ≈ 6.3) with a negative D at 500 Hz
PAPER = dict(m=2.0, c=1.0, k=64.0, T=0.01, P=0.25 + 1.375 * 9, D=0.6 + 0.3 * 9,
             hold_P=150.0, hold_D=25.0, x_start=0.01)
OVERDAMPED = dict(m=0.5, c=40.0, k=20.0, T=0.002, P=300.0, D=-35.0,
                  hold_P=2000.0, hold_D=20.0, x_start=0.004)
TOL = 1e-12  # of the release amplitude (the acceptance bound)


@pytest.fixture(scope="module")
def lib_dir(tmp_path_factory):
    _cc()
    folder = tmp_path_factory.mktemp("rig-lib")
    build_library(folder)
    return folder


def _controller(lib_dir, case, velocity, d, **extra):
    cfg = dict(sample_time=case["T"], P=case["P"], D=case["D"], velocity=velocity,
               delay_samples=d, hold_P=case["hold_P"], hold_D=case["hold_D"],
               x_start=case["x_start"], hold_samples=60, run_samples=1500, growth_limit=2.0)
    if velocity == "filtered":
        cfg["cutoff"] = 0.3 / case["T"]
    cfg.update(extra)
    return Controller(cfg, lib_dir)


def _drive(ctrl, case, n_idle, n, r=None, G=1.0, x0=0.0):
    """Step the C controller against the exact ZOH plant for n samples (start after n_idle).

    x_{n+1}, v_{n+1} = Φ(T)(x_n, v_n) + Γ(T)·G·u_n, u_n the command the step returned.
    Returns positions, velocities, returned commands and the estimate v̂ after each sample.
    """
    Phi, Gam = zoh_pieces(case["m"], case["c"], case["k"], [case["T"]])
    p00, p01, p10, p11 = (float(q) for q in Phi[0].ravel())
    g0, g1 = (float(q) for q in Gam[0])
    x, v = x0, 0.0
    xs, vs, us, vh = (np.empty(n) for _ in range(4))
    for i in range(n):
        if i == n_idle:
            ctrl.start()
        xs[i], vs[i] = x, v
        u = ctrl.step(x, 0.0 if r is None else float(r[i]))
        us[i] = u
        vh[i] = ctrl.velocity
        fn = G * u
        x, v = p00 * x + p01 * v + g0 * fn, p10 * x + p11 * v + g1 * fn
    return xs, vs, us, vh


def _history(xs, vh, i, velocity, T):
    """x_init for simulate_tracking starting at sample i: the estimator's history there.

    For the filtered estimator simulate_tracking starts v̂_{−1} at (x_{−1} − x_{−2})/T, so
    x_{−2} is chosen to make that the controller's running v̂_{i−1}.
    """
    if velocity == "filtered":
        return [xs[i - 1] - T * vh[i - 1], xs[i - 1], xs[i]]
    return [xs[i - 2], xs[i - 1], xs[i]]


def _events(ctrl):
    return [(e.name, e.index) for e in ctrl.events()]


def test_the_c_code_compiles_without_warnings(tmp_path):
    # -pedantic on top of the binding's flags: strict C99, no extensions
    cc = _cc()
    out = tmp_path / "obj.o"
    flags = [f for f in CFLAGS if f != "-shared"]
    proc = subprocess.run([*cc, *flags, "-pedantic", "-c", "-o", str(out), str(SOURCES[1])],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
    # no heap, no stdio, no libm in the controller
    text = SOURCES[1].read_text() + SOURCES[0].read_text()
    for forbidden in ("malloc", "<stdio.h>", "<math.h>", "<stdlib.h>", "printf"):
        assert forbidden not in text


@pytest.mark.parametrize("case", [PAPER, OVERDAMPED], ids=["paper", "overdamped"])
@pytest.mark.parametrize("velocity", ["backward-difference", "central-difference", "filtered"])
@pytest.mark.parametrize("d", [0, 1, 3])
def test_hold_and_run_are_phoids_sampled_loop(lib_dir, case, velocity, d):
    T = case["T"]
    cutoff = 0.3 / T if velocity == "filtered" else None
    run = SampledController(sample_time=T, P=case["P"], D=case["D"], velocity=velocity,
                            cutoff=cutoff, delay=d * T)
    hold = SampledController(sample_time=T, P=case["hold_P"], D=case["hold_D"],
                             velocity=velocity, cutoff=cutoff, delay=d * T)
    m, c, k = case["m"], case["c"], case["k"]
    # the premise: both loops are stable (phoid's closed-loop poles inside the unit circle)
    assert np.max(np.abs(closed_loop_poles(m, c, k, run))) < 1
    assert np.max(np.abs(closed_loop_poles(m, c, k, hold))) < 1
    ctrl = _controller(lib_dir, case, velocity, d)
    n_idle, n_hold, n_run = 5, 60, 1500
    xs, vs, us, vh = _drive(ctrl, case, n_idle, n_idle + n_hold + n_run + 3)
    rel = n_idle + n_hold
    assert _events(ctrl) == [("start", n_idle), ("release", rel), ("done", rel + n_run)]
    plant = Plant(m=m, c=c, k=k)

    # HOLD: from rest at 0 with the zeros issued in IDLE still in the delay line
    sim_h = simulate_tracking(plant, hold, np.full(n_hold, case["x_start"]),
                              x_init=xs[:n_idle + 1], v0=0.0, u_init=np.zeros(max(d, 1)))
    dev_h = np.max(np.abs(xs[n_idle:rel] - sim_h.x)) / case["x_start"]
    assert dev_h <= TOL

    # RUN: from the plant's state, the estimator's history and the hold's commands at the
    # release (the delay line brings them out during the first d samples of the run)
    amp = abs(xs[rel])
    assert amp > 0.1 * case["x_start"]  # a real release, not a settled zero
    u_init = us[rel:rel + d] if d else np.zeros(1)
    sim_r = simulate_tracking(plant, run, np.zeros(n_run),
                              x_init=_history(xs, vh, rel, velocity, T), v0=vs[rel],
                              u_init=u_init)
    dev_r = np.max(np.abs(xs[rel:rel + n_run] - sim_r.x)) / amp
    assert dev_r <= TOL
    # the commands returned in the run: the run's own, d samples late
    dev_u = np.max(np.abs(us[rel + d:rel + n_run] - sim_r.command[:n_run - d]))
    assert dev_u <= TOL * np.max(np.abs(sim_r.command))
    # DONE: command 0 from the sample after the last run sample
    assert ctrl.state == "done" and np.all(us[rel + n_run:] == 0.0)
    name = "paper" if case is PAPER else "overdamped"
    print(f"{name} {velocity} d={d}: hold {dev_h:.2e}, run {dev_r:.2e} of the amplitude")


def test_run_with_a_reference_gain_and_clipping_is_phoids_loop(lib_dir):
    # K = 1.5, G = 2 (N per command unit), a moving reference, and u_max tight enough that
    # the hold and the run clip: simulate_tracking's saturation is the controller's clip
    # (the Table 1 pair i = 18, P = 25, D = 6: with K·G = 3 the run's first commands exceed
    # u_max; a stable loop, max |z| = 0.94 by closed_loop_poles)
    case, velocity, d = dict(PAPER, P=25.0, D=6.0), "central-difference", 2
    T, K, G, umax = case["T"], 1.5, 2.0, 0.1
    n_idle, n_hold, n_run = 3, 80, 1000
    n = n_idle + n_hold + n_run
    t = T * np.arange(n)
    r = 0.002 * np.sin(2.0 * t)
    ctrl = _controller(lib_dir, case, velocity, d, gain=K, command_gain=G, u_max=umax,
                       hold_samples=n_hold, run_samples=n_run)
    xs, vs, us, vh = _drive(ctrl, case, n_idle, n, r=r, G=G)
    rel = n_idle + n_hold
    plant = Plant(m=case["m"], c=case["c"], k=case["k"])
    hold = SampledController(sample_time=T, P=case["hold_P"], D=case["hold_D"], gain=K,
                             command_gain=G, velocity=velocity, delay=d * T, saturation=umax)
    sim_h = simulate_tracking(plant, hold, np.full(n_hold, case["x_start"]),
                              x_init=xs[:n_idle + 1], u_init=np.zeros(d))
    run = SampledController(sample_time=T, P=case["P"], D=case["D"], gain=K, command_gain=G,
                            velocity=velocity, delay=d * T, saturation=umax)
    sim = simulate_tracking(plant, run, r[rel:], x_init=_history(xs, vh, rel, velocity, T),
                            v0=vs[rel], u_init=us[rel:rel + d])
    amp = max(abs(case["x_start"] - r[rel]), abs(xs[rel] - r[rel]))
    assert np.max(np.abs(xs[n_idle:rel] - sim_h.x)) / case["x_start"] <= TOL
    assert np.max(np.abs(xs[rel:] - sim.x)) / amp <= TOL
    # the clips counted: every command of the hold and of the run beyond ±u_max (phoid's
    # model flags the same samples as saturated), and both phases do clip
    n_h, n_r = int(np.sum(sim_h.saturated)), int(np.sum(sim.saturated))
    assert n_h > 0 and n_r > 0
    assert ctrl.clips == n_h + n_r
    assert np.all(np.abs(us) <= umax)
    # one `clip` event at the start of each clipping episode
    flags = np.concatenate((sim_h.saturated, sim.saturated))
    episodes = int(flags[0]) + int(np.sum(flags[1:] & ~flags[:-1]))
    clip_events = [i for name, i in _events(ctrl) if name == "clip"]
    assert len(clip_events) == episodes and clip_events[0] == n_idle


def test_explicit_release_and_restart(lib_dir):
    case = PAPER
    ctrl = _controller(lib_dir, case, "backward-difference", 1, hold_samples=0, run_samples=10)
    Phi, Gam = zoh_pieces(case["m"], case["c"], case["k"], [case["T"]])
    ctrl.start()
    x = np.zeros(2)
    for _ in range(500):  # hold_samples = 0: holds until released
        u = ctrl.step(float(x[0]))
        x = Phi[0] @ x + Gam[0] * u
    assert ctrl.state == "hold"
    ctrl.release()
    for _ in range(10):
        u = ctrl.step(float(x[0]))
        x = Phi[0] @ x + Gam[0] * u
    assert ctrl.state == "done"
    assert _events(ctrl) == [("start", 0), ("release", 500), ("done", 510)]
    with pytest.raises(ValueError, match="cannot release"):
        ctrl.release()
    ctrl.start()  # DONE → HOLD: the next run
    assert ctrl.state == "hold"


def _unstable_case(lib_dir, growth):
    # a large negative P: the loop's rightmost pole is real and outside the unit circle
    case = dict(PAPER, P=-200.0, D=2.0)
    run = SampledController(sample_time=case["T"], P=case["P"], D=case["D"])
    assert np.max(np.abs(closed_loop_poles(case["m"], case["c"], case["k"], run))) > 1
    ctrl = _controller(lib_dir, case, "backward-difference", 0, growth_limit=growth,
                       run_samples=5000)
    return case, ctrl


def test_an_unstable_run_aborts_at_the_first_sample_past_the_bound(lib_dir):
    growth = 3.0
    case, ctrl = _unstable_case(lib_dir, growth)
    n_idle, n_hold = 2, 60
    xs, vs, us, _ = _drive(ctrl, case, n_idle, n_idle + n_hold + 200)
    rel = n_idle + n_hold
    events = ctrl.events()
    assert [e.name for e in events] == ["start", "release", "fault-growth"]
    fault = events[-1]
    # where phoid's model of the run (no abort) first passes |x − r| > growth·A (r = 0)
    run = SampledController(sample_time=case["T"], P=case["P"], D=case["D"])
    sim = simulate_tracking(Plant(m=case["m"], c=case["c"], k=case["k"]), run, np.zeros(200),
                            x_init=xs[rel - 2:rel + 1], v0=vs[rel], u_init=[us[rel]])
    amp = max(abs(case["x_start"]), abs(xs[rel]))
    first = rel + int(np.argmax(np.abs(sim.x) > growth * amp))
    assert first > rel
    # bounded: the abort is at that sample, within a second (100 samples) of the release
    assert fault.index == first <= rel + 100
    assert fault.value == abs(xs[first])
    # from the fault on: command 0, latched until cleared
    assert np.all(us[first:] == 0.0) and ctrl.state == "fault"
    with pytest.raises(ValueError, match="cannot start"):
        ctrl.start()
    ctrl.clear_fault()
    assert ctrl.state == "idle" and [e.name for e in ctrl.events()] == ["clear"]
    ctrl.start()
    assert ctrl.state == "hold"


def test_position_limit_trips_in_the_run(lib_dir):
    case = PAPER
    # the released run swings to the other side; x_min = −0.3·x_start trips on the way
    xmin = -0.3 * case["x_start"]
    ctrl = _controller(lib_dir, case, "backward-difference", 0, x_min=xmin, x_max=1.0)
    xs, _, us, _ = _drive(ctrl, case, 0, 400)
    events = ctrl.events()
    assert [e.name for e in events] == ["start", "release", "fault-position"]
    first = int(np.argmax(xs < xmin))
    assert first > events[1].index and events[-1].index == first
    assert events[-1].value == xs[first]
    assert np.all(us[first:] == 0.0) and ctrl.state == "fault"


def test_stall_trips_after_the_given_samples(lib_dir):
    # a plant stuck in place (the controller reads a constant x): the run stalls
    ctrl = _controller(lib_dir, PAPER, "backward-difference", 0, hold_samples=5,
                       stall_samples=7, stall_epsilon=1e-9)
    ctrl.start()
    out = [ctrl.step(0.003) for _ in range(30)]
    events = ctrl.events()
    assert [e.name for e in events] == ["start", "release", "fault-stall"]
    # the run starts at sample 5; the 7th still sample of the run is sample 11
    assert events[1].index == 5 and events[2].index == 11
    assert all(u == 0.0 for u in out[11:]) and ctrl.state == "fault"


def test_non_finite_input_faults(lib_dir):
    ctrl = _controller(lib_dir, PAPER, "filtered", 0)
    ctrl.start()
    ctrl.step(0.0)
    assert ctrl.step(float("nan")) == 0.0
    assert [e.name for e in ctrl.events()] == ["start", "fault-input"]
    ctrl.step(0.0)
    assert ctrl.state == "fault"


def test_a_measured_force_is_stored_and_does_not_change_the_loop(lib_dir):
    # phoid_step_force stores the force (phoid_force) but the loop is on x only: the same
    # positions give bit-identical commands with and without forces; no sensor declared
    # (has_force = 0), so a NaN force is stored without a fault
    a = _controller(lib_dir, PAPER, "filtered", 2)
    b = _controller(lib_dir, PAPER, "filtered", 2)
    assert np.isnan(a.force)  # before the first sample: none given
    a.start()
    b.start()
    rng = np.random.default_rng(3)
    xs = PAPER["x_start"] + 1e-4 * rng.standard_normal(200)
    forces = 5.0 * rng.standard_normal(200)
    forces[17] = np.nan
    for x, f in zip(xs, forces, strict=True):
        assert a.step(x, 0.0, float(f)) == b.step(x)
        assert a.force == f or (np.isnan(f) and np.isnan(a.force))
        assert np.isnan(b.force)  # phoid_step gives no force
    assert a.state == b.state == "run"
    assert [e.name for e in a.events()] == [e.name for e in b.events()] == ["start", "release"]


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), None])
def test_a_declared_force_sensor_without_a_finite_force_faults(lib_dir, bad):
    # has_force = 1: a sample whose force is NaN, infinite or not given (phoid_step) is a
    # fault-input with value 1 (the force; x or r give value 0), command 0 from that sample
    ctrl = _controller(lib_dir, PAPER, "backward-difference", 0, has_force=1)
    ctrl.start()
    assert ctrl.step(PAPER["x_start"] + 1e-3, 0.0, 2.5) != 0.0  # hold pulls back: nonzero
    assert ctrl.force == 2.5 and ctrl.state == "hold"
    assert ctrl.step(PAPER["x_start"] + 1e-3, 0.0, bad) == 0.0
    events = ctrl.events()
    assert [(e.name, e.index, e.value) for e in events] == [
        ("start", 0, PAPER["x_start"]), ("fault-input", 1, 1.0)]
    assert ctrl.state == "fault"
    ctrl.clear_fault()
    ctrl2 = _controller(lib_dir, PAPER, "backward-difference", 0, has_force=1)
    ctrl2.start()
    ctrl2.step(float("nan"), 0.0, 1.0)
    assert [(e.name, e.value) for e in ctrl2.events()][-1] == ("fault-input", 0.0)


@pytest.mark.parametrize(("field", "value", "code"), [
    ("sample_time", 0.0, -2),
    ("sample_time", float("nan"), -2),
    ("velocity", 7, -3),
    ("filter_pole", 1.0, -4),
    ("delay_samples", 65, -5),
    ("delay_samples", -1, -5),
    ("P", float("inf"), -6),
    ("command_gain", 0.0, -7),
    ("x_min", 1.0, -8),
    ("x_start", 2.0, -9),
    ("u_max", 0.0, -10),
    ("growth_limit", 0.5, -11),
    ("stall_epsilon", -1.0, -12),
    ("run_samples", 0, -13),
    ("has_force", 2, -15),
])
def test_invalid_configs_are_refused_naming_the_field(lib_dir, field, value, code):
    cfg = dict(sample_time=0.01, x_min=-1.0, x_max=1.0)
    if field == "filter_pole":
        cfg["velocity"] = "filtered"
    cfg[field] = value
    with pytest.raises(ValueError, match=rf"`[^`]*{field}[^`]*`.*error {code}\)"):
        Controller(cfg, lib_dir)


def test_binding_refuses_unknown_fields_and_types(lib_dir):
    with pytest.raises(ValueError, match="unknown controller field `Kp`"):
        Controller({"Kp": 1.0}, lib_dir)
    with pytest.raises(ValueError, match="`delay_samples` must be a whole number"):
        Controller({"delay_samples": 1.5}, lib_dir)
    with pytest.raises(ValueError, match="`velocity` must be one of"):
        Controller({"velocity": "kalman"}, lib_dir)


def test_library_is_built_inside_the_folder_and_reused(tmp_path):
    _cc()
    folder = tmp_path / "lib"
    first = build_library(folder)
    assert first.parent == folder and first.is_file()
    assert sorted(p.name for p in folder.iterdir()) == [first.name]  # no temporaries left
    assert build_library(folder) == first


def test_without_a_compiler_one_line_says_so(tmp_path, monkeypatch):
    # runs everywhere: CC names a compiler that does not exist (no fallback when CC is set)
    monkeypatch.setenv("CC", "no-such-compiler-phoid")
    with pytest.raises(CompilerNotFoundError, match=r"needs a C compiler.*rest of phoid works"):
        build_library(tmp_path)
    assert not any(tmp_path.iterdir())


def test_the_readmes_example_compiles_and_runs_as_a_c_program(tmp_path):
    # the README's first ```c block, as the body of main() with a simulated encoder and DAC
    # (the exact ZOH plant of OVERDAMPED at T = 1 ms): it must build strictly and run a
    # whole hold → run → done cycle without a fault
    readme = (SOURCES[0].parent / "README.md").read_text(encoding="utf-8")
    block = readme.split("```c\n", 1)[1].split("```", 1)[0]
    setup, loop = block.split("/* in the timer interrupt", 1)
    loop = loop.split("\n", 1)[1]
    Phi, Gam = zoh_pieces(0.5, 40.0, 20.0, [0.001])
    p, g = Phi[0].ravel().tolist(), Gam[0].tolist()
    program = f"""#include "phoid_ctrl.h"
static double xs = 0.0, vs = 0.0;
static double read_encoder_m(void) {{ return xs; }}
static void write_dac(double u) {{
    double x = {p[0]!r} * xs + {p[1]!r} * vs + {g[0]!r} * u;
    vs = {p[2]!r} * xs + {p[3]!r} * vs + {g[1]!r} * u;
    xs = x;
}}
int main(void) {{
{setup}
    for (long i = 0; i < 8000; i++) {{
{loop}
    }}
    {{
        phoid_event e;
        int n = 0, last = 0;
        while (phoid_pop_event(&ctl, &e)) {{ n++; last = e.code; }}
        return (phoid_state(&ctl) == PHOID_DONE && n == 3 && last == PHOID_EV_DONE) ? 0 : 1;
    }}
}}
"""
    (tmp_path / "main.c").write_text(program)
    exe = tmp_path / "example"
    cc = _cc()
    flags = [f for f in CFLAGS if f not in ("-shared", "-fPIC")]
    build = subprocess.run([*cc, *flags, "-pedantic", f"-I{SOURCES[0].parent}", "-o", str(exe),
                            str(tmp_path / "main.c"), str(SOURCES[1])],
                           capture_output=True, text=True, check=False)
    assert build.returncode == 0, build.stderr
    assert subprocess.run([str(exe)], check=False).returncode == 0


def test_a_full_event_log_drops_the_oldest_and_counts_them(lib_dir):
    ctrl = _controller(lib_dir, PAPER, "backward-difference", 0)
    for i in range(20):  # 60 events into a log of 32 (PHOID_EVENT_LOG)
        ctrl.start()
        ctrl.abort(float(i))
        ctrl.clear_fault()
    events = ctrl.events()
    assert len(events) == 32 and ctrl.events_lost == 28
    assert [e.name for e in events[-3:]] == ["start", "fault-host", "clear"]
    assert events[-2].value == 19.0
