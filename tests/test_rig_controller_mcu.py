"""The rig's C controller as a microcontroller runs it, checked on the host (issue 29, part 1).

src/phoid/rig/c/phoid_ctrl.{h,c} build with a compile-time real type (``PHOID_REAL`` float or
double), a finiteness test on the bits that survives ``-ffast-math``, power-of-two rings with
unsigned masks, O(1) state transitions and a 64-bit sample counter. Here, with the machine's C
compiler (each test is skipped with the reason when there is none):

* the float build steps a ringing run within a float-rounding bound of the double build, the
  bound derived from the loop's own amplification (see test_float_build_...);
* a ``-ffast-math`` build of either real type still faults on NaN and infinite input and on an
  overflowing command, and still refuses non-finite gains;
* both real types compile with ``-std=c99 -pedantic -Wfloat-equal -Werror`` (and, where the
  cross compilers are installed, for a Cortex-M4F and an AVR: a quick compile-only check; the
  full build gate with flash and RAM limits is tests/test_mcu_build.py's);
* the compile-time checks of the sizes (power of two, ring > the largest delay, the real type);
* the sample counter and the events' indices past 2^32;
* transitions and ``phoid_init`` leave the delay ring's memory alone, and the slots not written
  since then still read as zero (the first d samples after a fault, a done or an init).

The C driver program below is compiled with the controller (a real subprocess, real files in
tmp_path); its expected outputs come from the contract in src/phoid/rig/c/README.md.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from phoid.dynamics.controller import zoh_pieces
from phoid.rig.native import CFLAGS, SOURCES, Controller, build_library, find_compiler

NO_CC = "no C compiler (CC, cc, gcc, clang): the rig's controller cannot be built"
C_DIR = SOURCES[0].parent
STRICT = ("-std=c99", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
          "-Wfloat-equal")
EPS_FLOAT = 2.0 ** -24  # unit roundoff of IEEE binary32 (round to nearest)

# the README's overdamped plant (ζ ≈ 6.3) made to ring by a negative D at 500 Hz with a
# 2-sample delay: phoid's closed_loop_poles give max |z| = 0.99890, a decay of e^−0.55 per
# second, so it rings for the whole 3 s run
RING = dict(m=0.5, c=40.0, k=20.0, T=0.002, P=300.0, D=-38.0, x0=0.004)


def _cc() -> list[str]:
    cc = find_compiler()
    if cc is None:
        pytest.skip(NO_CC)
    return cc


@pytest.fixture(scope="module")
def lib_dir(tmp_path_factory):
    _cc()
    folder = tmp_path_factory.mktemp("rig-lib-mcu")
    build_library(folder, "double")
    build_library(folder, "float")
    return folder


def _ringing_run(ctrl: Controller, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Step ``ctrl`` against the exact ZOH plant (double precision) for n samples.

    The plant starts at rest at x0; the controller holds with zero gains for one sample (its
    command is exactly 0 in both builds, so the builds see the same plant until the release)
    and runs from sample 1 on. Returns the positions and the returned commands.
    """
    Phi, Gam = zoh_pieces(RING["m"], RING["c"], RING["k"], [RING["T"]])
    p00, p01, p10, p11 = (float(q) for q in Phi[0].ravel())
    g0, g1 = (float(q) for q in Gam[0])
    x, v = RING["x0"], 0.0
    xs, us = np.empty(n), np.empty(n)
    ctrl.start()
    for i in range(n):
        xs[i] = x
        us[i] = u = ctrl.step(x, 0.0)
        x, v = p00 * x + p01 * v + g0 * u, p10 * x + p11 * v + g1 * u
    return xs, us


def _impulse_response(d: int, n: int) -> np.ndarray:
    """x_j of the run's closed loop after a unit error in the command computed at sample 0.

    The loop of the README (backward difference, r = 0, K = G = 1): v̂_j = (x_j − x_{j−1})/T,
    u_j = P·(0 − x_j) − D·v̂_j (+1 at j = 0), applied at j + d, through the same exact ZOH
    plant, from rest at 0 — the linear map from a command error to the position error.
    """
    T, P, D = RING["T"], RING["P"], RING["D"]
    Phi, Gam = zoh_pieces(RING["m"], RING["c"], RING["k"], [T])
    p00, p01, p10, p11 = (float(q) for q in Phi[0].ravel())
    g0, g1 = (float(q) for q in Gam[0])
    x = v = x_prev = 0.0
    pending = [0.0] * d
    h = np.empty(n)
    for j in range(n):
        h[j] = x
        u = P * (0.0 - x) - D * ((x - x_prev) / T) + (1.0 if j == 0 else 0.0)
        pending.append(u)
        a = pending.pop(0)
        x_prev = x
        x, v = p00 * x + p01 * v + g0 * a, p10 * x + p11 * v + g1 * a
    return h


def test_float_build_follows_the_double_build_within_float_rounding(lib_dir):
    # The float build rounds every input (x, the gains, T) to float and every operation to
    # float. Per sample n its command differs from the double build's (same x) by at most
    #   eps_n = γ_m·S_n,   S_n = |K|·(|P|·(|r| + |x_n|) + |D|·|c0|·(|x_n| + |x_{n−1}|)),
    # the forward error bound of u = K·(P·(r − x) − D·(c0·x_n + (−c0)·x_{n−1})) evaluated
    # with absolute values (Higham, γ_m = m·u/(1 − m·u), u = 2^−24), m = 10 the roundings on
    # the longest path (the leaves K, D, x: 1 each, c0 = 1/T: 2, then c0·x, +, D·v̂, −, K·:
    # 5). To first order these command errors reach x through the closed loop's linear
    # response h (a unit command error at sample k moves x_n by h_{n−k}), so
    #   |x_float,n − x_double,n| ≤ Σ_k |h_{n−k}|·eps_k,
    # and the test allows twice that (the second-order terms are ~1e−7 of the first).
    n, d = 1500, 2
    cfg = dict(sample_time=RING["T"], P=RING["P"], D=RING["D"], delay_samples=d,
               x_start=RING["x0"], hold_samples=1, run_samples=n)
    runs = {}
    for real in ("double", "float"):
        ctrl = Controller(cfg, lib_dir, real=real)
        xs, us = _ringing_run(ctrl, n + 1)
        runs[real] = (xs, us, [(e.name, e.index) for e in ctrl.events()])
    xd, ud, ev_d = runs["double"]
    xf, uf, ev_f = runs["float"]
    assert ev_d == ev_f == [("start", 0), ("release", 1), ("done", n + 1)]
    amp = RING["x0"]
    # the premise: the run rings (sign changes over the whole run, not settled)
    assert np.sum(np.diff(np.sign(xd[1:n])) != 0) >= 20
    assert np.max(np.abs(xd[n - 100:n])) > 1e-3 * amp

    m = 10
    gamma = m * EPS_FLOAT / (1.0 - m * EPS_FLOAT)
    c0 = 1.0 / RING["T"]
    x, x1 = np.abs(xd[1:n + 1]), np.abs(xd[0:n])
    eps = gamma * (abs(RING["P"]) * x + abs(RING["D"]) * c0 * (x + x1))
    h = np.abs(_impulse_response(d, n + 1))
    bound = 2.0 * np.convolve(h, eps)[: n]  # bound on |Δx| at samples 1 .. n
    dx = np.abs(xf[1:n + 1] - xd[1:n + 1])
    # samples 1 .. d + 1: no command of the run has acted yet (h_0 .. h_d = 0): no difference
    acted = bound > 0.0
    assert np.all(dx[~acted] == 0.0) and np.all(acted[d + 1:])
    worst = float(np.max(dx[acted] / bound[acted]))
    print(f"float vs double: max |Δx| = {np.max(dx):.3g} m ({np.max(dx) / amp:.2g} of the "
          f"amplitude), amplification Σ|h|·|D|·c0 = {np.sum(h) * abs(RING['D']) * c0:.3g}, "
          f"max |Δx|/bound = {worst:.3g}")
    assert worst <= 1.0
    # the bound is a float-rounding one: float's 2^-24 times the loop's amplification of a
    # rounding of x (|D|·c0 = 19000 N/m through Σ|h| ≈ 0.06 m/N: ~1.2e3, printed above),
    # ~1e-3 of the amplitude; and the float build really is float (it differs from double)
    assert np.max(bound) < 2e-3 * amp
    assert np.max(dx) > 0.0
    # the commands agree to the same order (the command of a float build rounds to float)
    assert np.max(np.abs(uf - ud)) < 1e-4 * np.max(np.abs(ud))


FLT_MAX = (2.0 - 2.0 ** -23) * 2.0 ** 127  # IEEE binary32's largest finite value


def test_float_build_refuses_values_beyond_float_and_reports_its_real(lib_dir):
    with pytest.raises(ValueError, match=r"`P` must be within .*float build"):
        Controller({"P": 1e300}, lib_dir, real="float")
    with pytest.raises(ValueError, match=r"`real` must be one of double, float"):
        Controller({}, lib_dir, real="half")
    # the double build takes it (a finite double gain; phoid_init accepts any finite gain)
    assert Controller({"P": 1e300}, lib_dir).real == "double"
    # a value above FLT_MAX that rounds to it (3.4028235e38 is 3.4e30 above it, a third of
    # half the gap to the next binary32 step, 2^103 ≈ 1.0e31) is held as FLT_MAX; one past
    # the half gap (3.41e38) rounds to infinity and is refused, on either side
    ctrl = Controller({"x_max": 3.4028235e38, "x_min": -3.4028235e38}, lib_dir, real="float")
    assert (ctrl.config.x_max, ctrl.config.x_min) == (FLT_MAX, -FLT_MAX)
    for field, value in (("x_max", 3.41e38), ("x_min", -3.41e38), ("stall_epsilon", 1e39)):
        with pytest.raises(ValueError, match=rf"`{field}` must be within .*float build"):
            Controller({field: value}, lib_dir, real="float")


@pytest.mark.parametrize("field", ["P", "D", "hold_P", "u_max", "stall_epsilon", "x_start"])
def test_float_build_refuses_a_value_that_rounds_to_zero(lib_dir, field):
    # 1e-50 is below binary32's smallest subnormal (2^-149 ≈ 1.4e-45): it rounds to 0, which
    # means "off" or "none" to several fields (stall_epsilon 0: any motion counts), so the
    # float build refuses it, naming the field; the double build holds it
    cfg = {field: 1e-50, "stall_samples": 3}
    assert getattr(Controller(cfg, lib_dir).config, field) == 1e-50
    with pytest.raises(ValueError, match=rf"^controller field `{field}` is too small for the "
                                         r"float build \(it rounds to 0 there\)"):
        Controller(cfg, lib_dir, real="float")
    # an exact 0 is a value float holds: taken where the field allows 0 (u_max must be > 0)
    if field != "u_max":
        assert getattr(Controller({field: 0.0}, lib_dir, real="float").config, field) == 0.0


@pytest.mark.parametrize("cfg, field", [
    # 1 - 1e-9 rounds to 1.0 in float (its step below 1 is 2^-24 ≈ 6e-8), which the float
    # phoid_init would take; the rule (0 or >= 1) is the double build's too
    ({"growth_limit": 1 - 1e-9}, "growth_limit"),
    # 0.99999999e-9 s rounds to float's 1e-9f (9.99999972e-10), PHOID_MIN_SAMPLE_TIME there
    ({"sample_time": 0.99999999e-9}, "sample_time"),
])
def test_float_build_refuses_what_the_double_build_refuses(lib_dir, cfg, field):
    # the configuration is checked as given by the double build before it is rounded: the
    # same one-line message from both builds, naming the field and the value given
    with pytest.raises(ValueError) as double:
        Controller(cfg, lib_dir)
    with pytest.raises(ValueError) as single:
        Controller(cfg, lib_dir, real="float")
    assert str(single.value) == str(double.value)
    assert f"`{field}`" in str(double.value) and repr(cfg[field]) in str(double.value)


def test_float_build_names_a_refusal_caused_by_rounding(lib_dir):
    # x_min < x_max and a pole below 1 hold in double and not after rounding to float
    # (0.1 and 0.1 + 1e-12 are the same float; 0.99999999 rounds to 1.0): the float
    # phoid_init refuses them, and the message shows the value given and the one held
    cfg = {"x_min": 0.1, "x_max": 0.1 + 1e-12, "x_start": 0.1}
    Controller(cfg, lib_dir)
    with pytest.raises(ValueError, match=r"`x_min, x_max` .*x_min=0\.1 \(the float build "
                                         r"holds 0\.10000000149011612\)"):
        Controller(cfg, lib_dir, real="float")
    pole = {"velocity": "filtered", "filter_pole": 0.99999999}
    Controller(pole, lib_dir)
    with pytest.raises(ValueError, match=r"`filter_pole` .*filter_pole=0\.99999999 \(the "
                                         r"float build holds 1\.0\)"):
        Controller(pole, lib_dir, real="float")


def test_sample_counter_and_event_indices_pass_2_to_the_32(lib_dir):
    # a 32-bit counter wraps after 2^32 samples (49.7 days at 1 kHz); this one is 64-bit.
    # phoid_set_sample_index (IDLE only) puts the counter 3 samples short of 2^32, then a
    # whole start → hold (2) → run (4) → done cycle crosses it.
    base = 2**32 - 3
    for real in ("double", "float"):
        ctrl = Controller(dict(sample_time=0.01, hold_P=10.0, x_start=0.001, hold_samples=2,
                               run_samples=4), lib_dir, real=real)
        ctrl.set_index(base)
        assert ctrl.index == base
        ctrl.start()
        with pytest.raises(ValueError, match="state 'idle' only; it is 'hold'"):
            ctrl.set_index(0)
        for _ in range(8):
            ctrl.step(0.0)
        assert ctrl.index == base + 8 == 2**32 + 5
        assert [(e.name, e.index) for e in ctrl.events()] == [
            ("start", base), ("release", base + 2), ("done", base + 6)]
    with pytest.raises(ValueError, match="whole number from 0 to 2"):
        ctrl.set_index(2**64)
    for bad in (-1, 3.0, "3", True):
        with pytest.raises(ValueError, match="whole number from 0 to 2"):
            ctrl.set_index(bad)


# --- the C driver: -ffast-math, the ring's memory ------------------------------------------

DRIVER = r"""
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include "phoid_ctrl.h"

/* a real from its IEEE bits (no arithmetic: the controller may be built with -ffast-math) */
static phoid_real from_bits(int what)
{
    phoid_real r;
    if (sizeof(phoid_real) == 8) {
        uint64_t b = what == 0 ? 0x7ff8000000000000ULL
                   : what == 1 ? 0x7ff0000000000000ULL : 0xfff0000000000000ULL;
        memcpy(&r, &b, sizeof r);
    } else {
        uint32_t b = what == 0 ? 0x7fc00000UL : what == 1 ? 0x7f800000UL : 0xff800000UL;
        memcpy(&r, &b, sizeof r);
    }
    return r;
}

static phoid_config base(void)
{
    phoid_config cfg;
    phoid_config_default(&cfg);
    cfg.sample_time = PHOID_R(0.01);
    cfg.hold_P = PHOID_R(100.0);
    cfg.hold_D = PHOID_R(1.0);
    cfg.x_start = PHOID_R(0.001);
    cfg.hold_samples = 3;
    cfg.run_samples = 4;
    cfg.P = PHOID_R(50.0);
    return cfg;
}

/* one line: the case, the command returned, the state, the last event (code, value, index) */
static void report(const char *name, phoid_ctrl *c, phoid_real u)
{
    phoid_event e, last;
    last.code = 0;
    last.value = PHOID_R(0.0);
    last.index = 0;
    while (phoid_pop_event(c, &e)) {
        last = e;
    }
    printf("%s %.17g %s %d %.17g %llu\n", name, (double)u, phoid_state_name(phoid_state(c)),
           last.code, (double)last.value, last.index);
}

static phoid_ctrl ctl;

static int ring_slots_changed(const phoid_real *before)
{
    int i, n = 0;
    for (i = 0; i < PHOID_RING_SIZE; i++) {
        n += memcmp(&before[i], &ctl.ring[i], sizeof(phoid_real)) != 0;
    }
    return n;
}

int main(void)
{
    static phoid_real snap[PHOID_RING_SIZE];
    phoid_config cfg = base();
    int i;

    /* non-finite input and an overflowing command fault, whatever the flags */
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("nan-x", &ctl, phoid_step(&ctl, from_bits(0), PHOID_R(0.0)));
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("inf-x", &ctl, phoid_step(&ctl, from_bits(1), PHOID_R(0.0)));
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("inf-r", &ctl, phoid_step(&ctl, PHOID_R(0.0), from_bits(2)));
    cfg.has_force = 1;
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("nan-force", &ctl, phoid_step_force(&ctl, PHOID_R(0.0), PHOID_R(0.0), from_bits(0)));
    cfg = base();
    cfg.hold_P = PHOID_REAL_MAX / PHOID_R(4.0);
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("overflow", &ctl, phoid_step(&ctl, PHOID_R(-1000.0), PHOID_R(0.0)));
    cfg = base();
    phoid_init(&ctl, &cfg); phoid_start(&ctl);
    report("finite", &ctl, phoid_step(&ctl, PHOID_R(0.0), PHOID_R(0.0)));
    cfg.P = from_bits(1);
    printf("inf-gain %d\n", phoid_init(&ctl, &cfg));
    cfg.P = from_bits(0);
    printf("nan-gain %d\n", phoid_init(&ctl, &cfg));
    /* every real field of the configuration: NaN, +inf and -inf, one at a time */
    {
        static const struct { const char *name; size_t off; } fields[] = {
            {"sample_time", offsetof(phoid_config, sample_time)},
            {"P", offsetof(phoid_config, P)}, {"D", offsetof(phoid_config, D)},
            {"gain", offsetof(phoid_config, gain)},
            {"command_gain", offsetof(phoid_config, command_gain)},
            {"filter_pole", offsetof(phoid_config, filter_pole)},
            {"hold_P", offsetof(phoid_config, hold_P)},
            {"hold_D", offsetof(phoid_config, hold_D)},
            {"x_start", offsetof(phoid_config, x_start)},
            {"x_min", offsetof(phoid_config, x_min)}, {"x_max", offsetof(phoid_config, x_max)},
            {"u_max", offsetof(phoid_config, u_max)},
            {"growth_limit", offsetof(phoid_config, growth_limit)},
            {"stall_epsilon", offsetof(phoid_config, stall_epsilon)}
        };
        size_t f;
        int what;
        for (f = 0; f < sizeof fields / sizeof fields[0]; f++) {
            printf("field-%s", fields[f].name);
            for (what = 0; what < 3; what++) {
                phoid_real v = from_bits(what);
                cfg = base();
                cfg.velocity = PHOID_VEL_FILTERED;
                memcpy((char *)&cfg + fields[f].off, &v, sizeof v);
                printf(" %d", phoid_init(&ctl, &cfg));
            }
            printf("\n");
        }
    }

    /* the delay ring: init on garbage, then a fault, a clear, a start and a done leave it
       alone; the slots not written since read as 0 */
    cfg = base();
    cfg.delay_samples = 3;
    memset(&ctl, 0xA5, sizeof ctl);
    memcpy(snap, ctl.ring, sizeof snap);
    phoid_init(&ctl, &cfg);
    printf("init-slots %d\n", ring_slots_changed(snap));
    phoid_start(&ctl);
    printf("hold-after-init");
    for (i = 0; i < 5; i++) {
        printf(" %.17g", (double)phoid_step(&ctl, PHOID_R(0.0), PHOID_R(0.0)));
    }
    printf("\n");
    memcpy(snap, ctl.ring, sizeof snap);
    phoid_abort(&ctl, PHOID_R(7.0));
    phoid_clear_fault(&ctl);
    phoid_start(&ctl);
    printf("transition-slots %d\n", ring_slots_changed(snap));
    printf("hold-after-fault");
    for (i = 0; i < 5; i++) {
        printf(" %.17g", (double)phoid_step(&ctl, PHOID_R(0.0), PHOID_R(0.0)));
    }
    printf("\n");
    /* 3 hold samples, then RUN: step to the end of its 4 samples */
    while (phoid_state(&ctl) != PHOID_DONE) {
        memcpy(snap, ctl.ring, sizeof snap);
        (void)phoid_step(&ctl, PHOID_R(0.0), PHOID_R(0.0));
    }
    printf("done-slots %d\n", ring_slots_changed(snap));
    phoid_start(&ctl);
    printf("hold-after-done");
    for (i = 0; i < 5; i++) {
        printf(" %.17g", (double)phoid_step(&ctl, PHOID_R(0.0), PHOID_R(0.0)));
    }
    printf("\n");
    return 0;
}
"""


def _build_driver(tmp: Path, real: str, fast_math: bool) -> dict[str, list[str]]:
    """Compile the driver with the controller (strict C99, the controller's object with
    -ffast-math when asked) and run it: its lines, keyed by their first word."""
    cc = _cc()
    (tmp / "driver.c").write_text(DRIVER)
    flags = [f for f in CFLAGS if f not in ("-shared", "-fPIC")]
    real_flag = f"-DPHOID_REAL={real}"
    ctrl_obj, drv_obj, exe = tmp / "ctrl.o", tmp / "driver.o", tmp / "driver"
    steps = [
        [*cc, *flags, "-pedantic", "-Wfloat-equal", real_flag,
         *(("-ffast-math",) if fast_math else ()), "-c", "-o", str(ctrl_obj), str(SOURCES[1])],
        [*cc, *flags, "-pedantic", real_flag, f"-I{C_DIR}", "-c", "-o", str(drv_obj),
         str(tmp / "driver.c")],
        [*cc, "-o", str(exe), str(drv_obj), str(ctrl_obj)],
    ]
    for cmd in steps:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        assert proc.returncode == 0 and not proc.stderr.strip(), (cmd, proc.stderr)
    run = subprocess.run([str(exe)], capture_output=True, text=True, check=False, timeout=30)
    assert run.returncode == 0, run.stderr
    return {ln.split()[0]: ln.split()[1:] for ln in run.stdout.splitlines()}


BUILDS = [("double", False), ("float", False), ("double", True), ("float", True)]


@pytest.fixture(scope="module", params=BUILDS, ids=[f"{r}{'-fast-math' if f else ''}"
                                                     for r, f in BUILDS])
def driver(request, tmp_path_factory):
    real, fast_math = request.param
    return real, _build_driver(tmp_path_factory.mktemp("drv"), real, fast_math)


def test_non_finite_input_and_overflow_fault_in_every_build(driver):
    # README, Safety: x or r not finite → fault-input (value 0); the measured force with
    # has_force = 1 → fault-input (value 1); a command that is not finite → fault-command
    # (value x); the command returned is 0; the index is the sample that tripped (0).
    # With -ffast-math too: the checks read the bits.
    _, out = driver
    for name, value in (("nan-x", 0.0), ("inf-x", 0.0), ("inf-r", 0.0), ("nan-force", 1.0)):
        u, state, code, val, index = out[name]
        assert (float(u), state, int(code), float(val), int(index)) == (
            0.0, "fault", 8, value, 0), name
    u, state, code, val, index = out["overflow"]
    # hold_P = max/4 times (x_start − x) = 1000.001 m overflows; fault-command with x = −1000
    assert (float(u), state, int(code), float(val), int(index)) == (0.0, "fault", 11,
                                                                     -1000.0, 0)
    # a finite sample does not trip: the hold command 100·(0.001 − 0) − 1·0 (rounded to the
    # build's real: 0.1 within float's relative 2^-24·a few)
    u, state, code, val, index = out["finite"]
    assert state == "hold" and int(code) == 1
    assert float(u) == pytest.approx(0.1, rel=1e-6)
    # phoid_init refuses non-finite gains (PHOID_E_GAIN = -6)
    assert out["inf-gain"] == out["nan-gain"] == ["-6"]


# phoid_init's answer to NaN, +inf, −inf in each real field (the README's error codes; the
# filtered estimator, so that filter_pole is checked): every NaN is refused naming its field;
# the limits may be infinite where the contract allows it (x_min = −inf, x_max = u_max = +inf:
# "no limit"), and −inf u_max is not > 0
NON_FINITE = {
    "sample_time": [-2, -2, -2], "P": [-6, -6, -6], "D": [-6, -6, -6], "gain": [-6, -6, -6],
    "command_gain": [-7, -7, -7], "filter_pole": [-4, -4, -4], "hold_P": [-6, -6, -6],
    "hold_D": [-6, -6, -6], "x_start": [-9, -9, -9], "x_min": [-8, -8, 0],
    "x_max": [-8, 0, -8], "u_max": [-10, 0, -10], "growth_limit": [-11, -11, -11],
    "stall_epsilon": [-12, -12, -12],
}


def test_every_real_field_refuses_nan_in_every_build(driver):
    # the configuration's checks read NaN from the bits: under -ffast-math a comparison
    # such as !(u_max > 0) may be compiled as u_max <= 0, which a NaN passes
    _, out = driver
    got = {key[len("field-"):]: [int(v) for v in vals] for key, vals in out.items()
           if key.startswith("field-")}
    assert got == NON_FINITE


def test_transitions_and_init_leave_the_delay_ring_alone(driver):
    # O(1) transitions: phoid_init (on memory full of 0xA5), an abort, a clear and a start
    # write no slot of the ring; the step that ends the run writes only its own slot. The
    # slots not written since read as 0: with d = 3 the first 3 samples after an init, a
    # fault or a done return 0, then the hold command 100·0.001 = 0.1 (x = 0, at rest).
    _, out = driver
    assert out["init-slots"] == ["0"]
    assert out["transition-slots"] == ["0"]
    assert int(out["done-slots"][0]) <= 1
    for key in ("hold-after-init", "hold-after-fault", "hold-after-done"):
        values = [float(v) for v in out[key]]
        assert values[:3] == [0.0, 0.0, 0.0], key
        assert values[3:] == pytest.approx([0.1, 0.1], rel=1e-6), key


# --- compiling: strict flags, the sizes' checks, the cross compilers ------------------------

@pytest.mark.parametrize("real", ["double", "float"])
def test_both_real_types_compile_with_strict_flags(tmp_path, real):
    cc = _cc()
    proc = subprocess.run([*cc, *STRICT, "-O2", f"-DPHOID_REAL={real}", "-c", "-o",
                           str(tmp_path / "c.o"), str(SOURCES[1])],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr


@pytest.mark.parametrize("defines, message", [
    (["-DPHOID_REAL=int"], "PHOID_REAL must be float or double"),
    (["-DPHOID_RING_SIZE=100"], "PHOID_RING_SIZE must be a power of two"),
    (["-DPHOID_RING_SIZE=64"], "PHOID_RING_SIZE must be > PHOID_MAX_DELAY"),
    (["-DPHOID_MAX_DELAY=200"], "PHOID_RING_SIZE must be > PHOID_MAX_DELAY"),
    (["-DPHOID_EVENT_LOG=24"], "PHOID_EVENT_LOG must be a power of two"),
    (["-DPHOID_EVENT_LOG=0"], "PHOID_EVENT_LOG must be a power of two"),
    (["-DPHOID_RING_SIZE=256", "-DPHOID_MAX_DELAY=255", "-DPHOID_EVENT_LOG=8"], None),
], ids=["real-int", "ring-100", "ring-64", "delay-200", "log-24", "log-0", "sizes-ok"])
def test_the_sizes_and_the_real_type_are_checked_at_compile_time(tmp_path, defines, message):
    cc = _cc()
    proc = subprocess.run([*cc, *STRICT, *defines, "-c", "-o", str(tmp_path / "c.o"),
                           str(SOURCES[1])], capture_output=True, text=True, check=False)
    if message is None:
        assert proc.returncode == 0, proc.stderr
    else:
        assert proc.returncode != 0 and message in proc.stderr, proc.stderr


CROSS = {
    "cortex-m4f": ("arm-none-eabi-gcc", ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16",
                                         "-mfloat-abi=hard", "-O2"]),
    "cortex-m0": ("arm-none-eabi-gcc", ["-mcpu=cortex-m0", "-mthumb", "-O2"]),
    "avr": ("avr-gcc", ["-mmcu=atmega2560", "-Os"]),
}
# the Debian package of each cross compiler, for the skip reason
CROSS_PACKAGES = {"arm-none-eabi-gcc": "gcc-arm-none-eabi", "avr-gcc": "gcc-avr"}
# the integer division helpers of the ARM EABI (a % or an integer / where the core has no
# divide instruction: Cortex-M0)
INT_DIVISION = ("__aeabi_uidiv", "__aeabi_uidivmod", "__aeabi_idiv", "__aeabi_idivmod",
                "__aeabi_uldivmod", "__aeabi_ldivmod")


@pytest.mark.parametrize("target", sorted(CROSS))
@pytest.mark.parametrize("real", ["double", "float"])
def test_cross_compiles_with_strict_flags(tmp_path, target, real):
    # compile only (the link, flash and RAM limits and the other cores are
    # tests/test_mcu_build.py's); AVR's double is 32-bit: no constant may exceed it
    tool, flags = CROSS[target]
    if shutil.which(tool) is None:
        pytest.skip(f"{tool} not installed (Debian: {CROSS_PACKAGES[tool]})")
    obj = tmp_path / "c.o"
    proc = subprocess.run([tool, *flags, *STRICT, f"-DPHOID_REAL={real}", "-c", "-o", str(obj),
                           str(SOURCES[1])], capture_output=True, text=True, check=False)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
    nm = shutil.which(f"{tool.rsplit('-', 1)[0]}-nm")
    if nm is None or target == "avr":
        return
    undefined = subprocess.run([nm, "-u", str(obj)], capture_output=True, text=True,
                               check=True).stdout.split()
    # no integer division anywhere (power-of-two rings with masks; the issue's `% 65` cost
    # two helper calls per step on an M0)
    assert not set(undefined) & set(INT_DIVISION), undefined
    if target == "cortex-m4f" and real == "float":
        # the float build does no double arithmetic: no software double routine is called
        # (the only outside symbol, for a struct copy, is memcpy)
        assert not [s for s in undefined if s.startswith("__aeabi_d") or "df" in s], undefined
