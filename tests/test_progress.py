"""Progress bars for long work (phoid._progress): drawn on a terminal, silent elsewhere.

A bar is recognised by rich's bar glyph "━" (U+2501) and the task's description; "silent" means
neither appears. The library tests draw on a rich Console that writes to a string as a terminal
would (force_terminal); the command-line tests run ``python -m phoid.cli`` under a real
pseudo-terminal (the ``pty`` module), in a pipe, and with ``--json``.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

import phoid
from phoid._progress import enabled, progress, step, task

BAR = "━"  # rich's bar glyph: present in every drawn bar, absent from phoid's own output


@pytest.fixture
def terminal():
    """Progress switched on, drawing on a terminal-like console that writes to a string."""
    from rich.console import Console

    buf = io.StringIO()
    progress(True, console=Console(file=buf, force_terminal=True, width=120))
    yield buf
    progress(False)


def test_off_by_default_and_a_no_op():
    assert not enabled()
    with task("anything", total=3) as advance:
        advance()
        advance(2, description="renamed", total=5, completed=1)
        step()  # no open task: nothing to advance, no error


def test_public_switch_is_the_module_function():
    assert phoid.progress is progress
    phoid.progress(True)
    try:
        assert enabled()
    finally:
        phoid.progress(False)
    assert not enabled()


def test_task_draws_description_bar_and_count(terminal):
    with task("demo work", total=4) as advance:
        advance()
        step(2)  # the innermost open task: this one
    out = terminal.getvalue()
    assert "demo work" in out and BAR in out
    assert "/4" in out  # the M/N column shows the total given


def test_a_console_that_is_no_terminal_gets_nothing():
    # phoid.progress(True) with standard error redirected to a file or a pipe: not one byte
    from rich.console import Console

    buf = io.StringIO()
    progress(True, console=Console(file=buf))  # a file: rich sees no terminal
    try:
        with task("demo work", total=2) as advance:
            advance()
            step()
    finally:
        progress(False)
    assert buf.getvalue() == ""


def test_hidden_inner_task_does_not_advance_the_outer_one(terminal):
    from phoid._progress import _BAR

    with task("outer", total=10):
        with task("inner", show=False):
            step(5)  # inside a hidden task: must not count for "outer"
        bar, _stack = _BAR.get()
        (outer,) = bar.tasks
        assert outer.completed == 0
        step(3)
        assert outer.completed == 3
    assert "inner" not in terminal.getvalue()


def test_other_threads_draw_nothing(terminal):
    # the switch is a context variable: a thread started here does not inherit it
    seen = []
    th = threading.Thread(target=lambda: seen.append(enabled()))
    th.start()
    th.join()
    assert seen == [False]


def test_long_simulation_shows_its_steps(terminal, monkeypatch):
    import phoid.simulation.response as response

    # a short simulation stands for a long one: the threshold lowered, the code path the same
    monkeypatch.setattr(response, "_LONG_SAMPLES", 10)
    sim = phoid.simulate(phoid.Plant(1.0, 2.0, 100.0), np.array([50.0, 100.0]),
                         np.array([0.5, 1.0]), delay=0.02, duration=1.0, fs=1000.0)
    out = terminal.getvalue()
    assert "simulating 2 run(s)" in out and BAR in out
    # the bar changes nothing: the same simulation without it, bit for bit
    progress(False)
    again = phoid.simulate(phoid.Plant(1.0, 2.0, 100.0), np.array([50.0, 100.0]),
                           np.array([0.5, 1.0]), delay=0.02, duration=1.0, fs=1000.0)
    np.testing.assert_array_equal(sim.x, again.x)


def test_short_simulation_shows_nothing(terminal):
    phoid.simulate(phoid.Plant(1.0, 2.0, 100.0), 50.0, 0.5, delay=0.02, duration=1.0,
                   fs=1000.0)
    assert terminal.getvalue() == ""


def test_tracking_simulation_shows_its_samples(terminal, monkeypatch):
    import phoid.simulation.tracking as tracking

    monkeypatch.setattr(tracking, "_LONG_SAMPLES", 10)
    ctrl = phoid.SampledController(P=200.0, D=5.0, sample_time=1e-3)
    r = np.full(10_000, 0.01)  # more than one chunk of 4096 samples
    phoid.simulate_tracking(phoid.Plant(1.0, 2.0, 0.0), ctrl, r)
    out = terminal.getvalue()
    assert "tracking loop" in out and BAR in out


def _friction_runs():
    # the friction fit's own doctest example (phoid.methods.friction.fit.identify_friction)
    P, D = np.array([0.0, 100.0, 200.0]), np.array([-1.6, 0.6, 2.8])
    sim = phoid.simulate(phoid.Plant(1.0, 2.0, 100.0, fc=0.05), P, D, delay=0.02,
                         duration=4.0, fs=1000.0, x0=0.008, hold=0.2, noise=1e-5,
                         rng=np.random.default_rng(1))
    return [(sim.t, x) for x in sim.x], P, D


def test_friction_fit_shows_its_stages(terminal):
    data, P, D = _friction_runs()
    fit = phoid.identify_friction(data, P, D, 0.02)
    out = terminal.getvalue()
    assert "friction fit" in out and BAR in out
    assert "stage 2 of 2" in out
    # and the bar changes nothing
    progress(False)
    again = phoid.identify_friction(data, P, D, 0.02)
    assert (fit.m.value, fit.c.value, fit.k.value, fit.fc.value) == \
        (again.m.value, again.c.value, again.k.value, again.fc.value)


# --- the command line -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def friction_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("progress") / "fr"
    r = _cli("simulate", str(out), "--fc", "0.02", "--seed", "1", "--noise", "1e-5",
             "--P", "0.25:25:6", "--D", "0.6:6:6")
    assert r.returncode == 0, r.stderr
    return out


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "phoid.cli", *args], capture_output=True,
                          text=True, timeout=300)


def _under_pty(*args) -> tuple[str, str, int]:
    """Run the CLI with stdout and stderr on two pseudo-terminals; what each got, and the
    exit status."""
    pty = pytest.importorskip("pty", reason="no pseudo-terminals on this platform")
    import select

    pairs = [pty.openpty(), pty.openpty()]  # (controller, terminal) for stdout, stderr
    proc = subprocess.Popen([sys.executable, "-m", "phoid.cli", *args],
                            stdin=subprocess.DEVNULL, stdout=pairs[0][1], stderr=pairs[1][1])
    for _, term in pairs:
        os.close(term)
    got: dict[int, list[bytes]] = {fd: [] for fd, _ in pairs}
    open_fds = set(got)
    while open_fds:
        ready, _, _ = select.select(list(open_fds), [], [], 300)
        if not ready:
            proc.kill()
            break
        for fd in ready:
            try:
                data = os.read(fd, 65536)
            except OSError:  # EIO: the child closed its end
                data = b""
            if data:
                got[fd].append(data)
            else:
                open_fds.discard(fd)
    code = proc.wait(timeout=60)
    for fd, _ in pairs:
        os.close(fd)
    out, err = (b"".join(got[fd]).decode("utf-8", "replace") for fd, _ in pairs)
    return out, err, code


def test_cli_on_a_terminal_draws_the_bar(friction_set):
    out, err, code = _under_pty("identify", str(friction_set), "--friction")
    assert code == 0, err
    assert "friction fit" in err and BAR in err  # the bar: on standard error
    assert BAR not in out and "fc" in out  # the report: on standard output, as before


def test_cli_with_json_on_a_terminal_prints_pure_json(friction_set):
    out, err, code = _under_pty("identify", str(friction_set), "--friction", "--json")
    assert code == 0, err
    for text in (out, err):  # no bar, no terminal control sequence, on either terminal
        assert BAR not in text and "\x1b[" not in text
    assert "fc" in json.loads(out)  # standard output: the JSON object and nothing else


def test_cli_in_a_pipe_is_silent(friction_set):
    r = _cli("identify", str(friction_set), "--friction")
    assert r.returncode == 0, r.stderr
    for text in (r.stdout, r.stderr):
        assert BAR not in text and "friction fit:" not in text and "\x1b[" not in text
    r = _cli("identify", str(friction_set), "--friction", "--json")
    assert r.returncode == 0, r.stderr
    assert BAR not in r.stderr
    assert "fc" in json.loads(r.stdout)


def test_cli_runner_is_silent(friction_set):
    from typer.testing import CliRunner

    from phoid.cli import app

    r = CliRunner().invoke(app, ["identify", str(friction_set), "--friction"])
    assert r.exit_code == 0, r.output
    assert BAR not in r.output and not enabled()
