"""`phoid run` against rigs that misbehave: every read bounded, every run's record true, every
option checked before connecting, no file replaced.

The rigs here are written in the test: small socket servers speaking PHOID-RIG 1 badly
(:class:`FakeRig`), and a relay in front of the real virtual rig that damages one run's
stream (:class:`Relay`), so that the other runs are real recordings `phoid identify` must
still read. The limits asserted are the ones docs/rig-protocol.md ("Limits of the host")
states: each line within --timeout, each run within --timeout + (hold + run + 1)·(2T + 0.1 ms)
on a socket, at most 100 damaged lines and (samples + 64) EVENT lines a run, 64 events
recorded, counts of at most 2^31 − 1, the manifest within the reader's 2 MiB.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import pytest
import tomli_w
from typer.testing import CliRunner

from phoid.cli import app
from phoid.dynamics.plant import Plant
from phoid.io.limits import MAX_MANIFEST_BYTES
from phoid.rig.native import build_library, find_compiler
from phoid.rig.protocol import encode, hello, parse

runner = CliRunner()
TIMEOUT = 1.0  # --timeout of the timing cases, s
# the plan of the fake rigs: fs 200 Hz (T = 5 ms), 0.5 s runs (100 samples); with --hold 0.1
# (20 samples) a run is 20 + 100 + 1 = 121 samples
FAST = dict(fs=200.0, duration=0.5)
HOLD, RUN = 20, 100
TOTAL = HOLD + RUN + 1
# the deadline docs/rig-protocol.md gives such a run on a socket: --timeout + 121·(2T + 0.1 ms)
BUDGET = TIMEOUT + TOTAL * (2 * 0.005 + 1e-4)
# what the host may take beyond it: the ABORT and BYE it sends (each bounded by --timeout) and
# the interpreter's own start-up and scheduling on a loaded machine
SLACK = 2 * TIMEOUT + 2.0


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _plan(tmp_path, runs=2, duration=FAST["duration"], name="plan"):
    plan = tmp_path / name
    r = _cli("design", "--m", 2, "--c", 1, "--k", 64, "--delay", 0.005, "--fs", FAST["fs"],
             "--duration", duration, "--runs", runs, "--noise", 1e-5, "--amplitude", 0.01,
             "--out", plan)
    assert r.exit_code == 0, r.output
    return plan


def _manifest(folder):
    return tomllib.loads((Path(folder) / "experiment.toml").read_text())


def _fail_line(r):
    err = r.stderr.strip().splitlines()
    assert r.exit_code == 2, r.output
    assert len(err) == 1 and err[0].startswith("phoid: error:"), r.stderr
    return err[0]


def _sample(n, T, state, x=0.001):
    return encode("SAMPLE", n, n * T, x, 0.0, state)


def _state(n, cfg):
    hold, run = cfg["hold_samples"], cfg["run_samples"]
    return "hold" if n < hold else "run" if n < hold + run else "done"


def _good_run(conn, cfg, x=0.001):
    """The run configured, as a rig must send it (x constant: these runs are not identified)."""
    T, total = cfg["sample_time"], cfg["hold_samples"] + cfg["run_samples"] + 1
    conn.sendall(b"".join(_sample(n, T, _state(n, cfg), x) for n in range(total))
                 + encode("END", "done"))


class FakeRig:
    """A rig written for one test: it answers the hello (``greet``: True, or a function
    ``greet(conn, stop)`` sending something else), OK to every CONFIG (``config``: a function
    ``config(conn, stop)`` instead) and CLEAR, and to the k-th START calls
    ``script(conn, cfg, k, stop)``; it counts the connections. ``stop`` (an Event) is set when
    the test ends: endless scripts watch it."""

    def __init__(self, script=None, greet=True, config=None):
        self.script, self.greet, self.config = script, greet, config
        self.connections = 0
        self.stop = threading.Event()
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.srv.settimeout(0.1)
        self.port = f"tcp://127.0.0.1:{self.srv.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            with conn, contextlib.suppress(OSError, ValueError):
                conn.settimeout(None)
                self._session(conn)

    def _session(self, conn):
        f = conn.makefile("rb")
        f.readline()
        if self.greet is not True:
            if callable(self.greet):
                self.greet(conn, self.stop)
            self.stop.wait(30)
            return
        conn.sendall(hello())
        cfg, starts = {}, 0
        while (line := f.readline()):
            msg = parse(line)
            if msg.kind == "CONFIG" and self.config is not None:
                return self.config(conn, self.stop)
            if msg.kind == "CONFIG":
                cfg = msg.fields
                conn.sendall(encode("OK"))
            elif msg.kind == "START":
                starts += 1
                self.script(conn, cfg, starts, self.stop)
            elif msg.kind == "CLEAR":
                conn.sendall(encode("OK"))
            elif msg.kind == "BYE":
                return

    def close(self):
        self.stop.set()
        self.srv.close()
        self.thread.join(timeout=10)


@pytest.fixture
def fake():
    rigs = []

    def make(script=None, greet=True, config=None):
        rigs.append(FakeRig(script, greet, config))
        return rigs[-1]

    yield make
    for rig in rigs:
        rig.close()


def _timed_run(plan, port, out, *extra):
    t0 = time.monotonic()
    r = _cli("run", plan, "--port", port, "--out", out, "--timeout", TIMEOUT, "--hold", 0.1,
             *extra)
    return r, time.monotonic() - t0


def _endless(conn, stop, chunk):
    while not stop.is_set():
        conn.sendall(chunk)


def _samples_for_ever(conn, stop, cfg):
    """The rest of the run, then samples numbered on, for ever, and no END."""
    n = HOLD + 30
    while not stop.is_set():
        conn.sendall(_sample(n, 0.005, _state(n, cfg)))
        n += 1


def _drip(conn, stop, cfg):
    """One damaged line every 0.3 s: each wait is shorter than --timeout."""
    while not stop.wait(0.3):
        conn.sendall(b"noise\n")


# ---------------------------------------------------------------------------------------------
# 1. a flood ends the run as surely as silence


def _half_then(flood):
    """Run 2: the hold and 30 run samples, then ``flood(conn, stop, cfg)``; run 1 is good."""

    def script(conn, cfg, k, stop):
        if k == 1:
            return _good_run(conn, cfg)
        T = cfg["sample_time"]
        conn.sendall(b"".join(_sample(n, T, _state(n, cfg)) for n in range(HOLD + 30)))
        flood(conn, stop, cfg)

    return script


@pytest.mark.parametrize("flood, why", [
    (lambda conn, stop, cfg: _endless(conn, stop, b"x" * 65536), "damaged lines"),
    (lambda conn, stop, cfg: _endless(conn, stop, b"garbage\n" * 4096), "damaged lines"),
    (_samples_for_ever, "more than the run's 121 samples"),
    (_drip, "did not end within"),  # the run's deadline
    # silence (the classic): the line timeout
    (lambda conn, stop, cfg: stop.wait(30), "sent nothing for 1 s"),
], ids=["bytes-without-newline", "newline-garbage", "samples-without-end", "slow-drip",
        "silence"])
def test_a_flooding_rig_is_cut_off_within_the_run_deadline(tmp_path, fake, flood, why):
    plan = _plan(tmp_path)
    rig = fake(_half_then(flood))
    r, took = _timed_run(plan, rig.port, tmp_path / "set")
    print(f"took {took:.2f} s; bound {BUDGET + SLACK:.2f} s")
    assert took < BUDGET + SLACK, (took, r.output)
    assert r.exit_code == 1, r.output
    assert "run 2 (run02.csv) incomplete" in r.stderr and why in r.stderr
    doc = _manifest(tmp_path / "set")
    first, second = doc["rig"]["attempt"]
    assert first["status"] == "complete" and second["status"] == "incomplete"
    assert why in second["reason"] and len(second["reason"]) <= 400
    # the 30 run samples before the flood are kept (the third case sends all 100)
    assert second["samples"] == (RUN if "121" in why else 30)
    rows = (tmp_path / "set" / second["file"]).read_text().splitlines()
    assert len(rows) - 1 == second["samples"]
    assert not list((tmp_path / "set").glob(".*.part"))  # no temporary file left


@pytest.mark.parametrize("greet, why", [
    (None, "sent nothing for 1 s (waiting for hello)"),
    (lambda conn, stop: _endless(conn, stop, b"y" * 65536), "longer than 4096 bytes"),
    (lambda conn, stop: _endless(conn, stop, b"PHOID-RIG 1\n"), "damaged"),
], ids=["silent", "bytes", "lines"])
def test_a_rig_that_never_says_hello_is_one_line_within_the_timeout(tmp_path, fake, greet,
                                                                    why):
    plan = _plan(tmp_path)
    rig = fake(greet=greet or False)
    t0 = time.monotonic()
    line = _fail_line(_cli("run", plan, "--port", rig.port, "--out", tmp_path / "set",
                           "--timeout", TIMEOUT))
    assert time.monotonic() - t0 < TIMEOUT + SLACK
    assert why in line and len(line) < 600
    assert not (tmp_path / "set").exists()


def test_a_config_reply_flood_is_one_line(tmp_path, fake):
    # CONFIG answered with an endless line: the reply read is one line of at most 4096 bytes
    rig = fake(config=lambda conn, stop: _endless(conn, stop, b"z" * 65536))
    plan = _plan(tmp_path)
    t0 = time.monotonic()
    line = _fail_line(_cli("run", plan, "--port", rig.port, "--out", tmp_path / "set",
                           "--timeout", TIMEOUT))
    assert time.monotonic() - t0 < TIMEOUT + SLACK
    assert "run 1:" in line and "reply to CONFIG" in line and "longer than 4096" in line


# ---------------------------------------------------------------------------------------------
# 2. a run is complete only as configured; the set stays readable


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    if find_compiler() is None:
        pytest.skip("no C compiler: the virtual rig's controller cannot be built")
    folder = tmp_path_factory.mktemp("rig-build")
    build_library(folder)
    return folder


class Relay:
    """A fake rig in front of the real virtual rig: the host's lines go to the virtual rig
    unchanged; the virtual rig's lines come back through ``mangle(start, line)`` (start: the
    STARTs the host sent so far), which returns the bytes to send instead (b"" drops the
    line)."""

    def __init__(self, upstream, mangle):
        self.upstream, self.mangle = upstream, mangle
        self.starts = 0
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = f"tcp://127.0.0.1:{self.srv.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        with contextlib.suppress(OSError):
            conn, _ = self.srv.accept()
            up = socket.create_connection(self.upstream)
            down = threading.Thread(target=self._down, args=(up, conn), daemon=True)
            down.start()
            with conn, up:
                with contextlib.suppress(OSError):
                    f = conn.makefile("rb")
                    while (line := f.readline()):
                        if line.startswith(b"START"):
                            self.starts += 1
                        up.sendall(line)
                with contextlib.suppress(OSError):
                    up.shutdown(socket.SHUT_RDWR)
                down.join(timeout=10)

    def _down(self, up, conn):
        with contextlib.suppress(OSError):
            f = up.makefile("rb")
            while (line := f.readline()):
                conn.sendall(self.mangle(self.starts, line))

    def close(self):
        self.srv.close()


def _relayed_run(build, tmp_path, mangle, runs=4):
    from phoid.rig.virtual import VirtualRig

    plan = _plan(tmp_path, runs=runs, duration=1.0)
    rig = VirtualRig(Plant(m=2.0, c=1.0, k=64.0), build=build, noise=1e-5, seed=2)
    with rig:
        relay = Relay(rig.listen("127.0.0.1", 0), mangle)
        r = _cli("run", plan, "--port", relay.port, "--out", tmp_path / "set", "--timeout", 5)
        relay.close()
    return r, _manifest(tmp_path / "set")


def _identifies(folder, files):
    """`phoid identify` reads the set: exactly the complete runs ``files``."""
    doc = _manifest(folder)
    assert [run["file"] for run in doc["run"]] == files
    assert len((Path(folder) / "experiment.toml").read_bytes()) <= MAX_MANIFEST_BYTES
    r = _cli("identify", folder, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["m"]["value"] > 0


def _edit(run, change):
    """mangle: on run ``run`` apply change(fields) -> bytes to each SAMPLE line."""

    def mangle(start, line):
        if start != run or not line.startswith(b"SAMPLE"):
            return line
        return change(parse(line).fields)

    return mangle


def _resample(f, **new):
    f = {**f, **new}
    return encode("SAMPLE", f["index"], f["t"], f["x"], f["u"], f["state"])


@pytest.mark.parametrize("mangle, why", [
    # the clock stands still at sample 150 (t of sample 149)
    (_edit(2, lambda f: _resample(f, t=f["t"] - 0.005) if f["index"] == 150
           else _resample(f)), "time did not increase at sample 150"),
    # ... or goes back
    (_edit(2, lambda f: _resample(f, t=-1.0) if f["index"] == 150
           else _resample(f)), "time did not increase at sample 150"),
    # END right after START: no sample at all
    (lambda start, line: b"" if start == 2 and line[:5] in (b"SAMPL", b"EVENT") else line,
     "after 0 samples"),
    # the hold samples called run: 124 + 200 run rows for a run of 200
    (_edit(2, lambda f: _resample(f, state="run") if f["state"] == "hold" else _resample(f)),
     "after 325 samples (324 run, 1 done)"),
], ids=["time-stands-still", "time-goes-back", "end-after-start", "extra-run-rows"])
def test_a_run_that_is_not_the_run_configured_is_incomplete_and_the_plan_goes_on(
        build, tmp_path, mangle, why):
    r, doc = _relayed_run(build, tmp_path, mangle)
    assert r.exit_code == 1, r.output
    st = [a["status"] for a in doc["rig"]["attempt"]]
    assert st == ["complete", "incomplete", "complete", "complete"], st
    bad = doc["rig"]["attempt"][1]
    assert why in bad["reason"] and bad["file"] == "run02.incomplete.csv"
    _identifies(tmp_path / "set", ["run01.csv", "run03.csv", "run04.csv"])


def test_sample_floods_and_event_floods_stop_the_plan_and_the_set_stays_readable(
        build, tmp_path):
    # run 4 sends each run sample six times (a run of 200 as 1 200 rows); in a second set run
    # 4 ends with 300 000 EVENT lines (a 5 MB manifest if recorded). Both are cut off at the
    # caps: the run's 325 samples, 325 + 64 EVENT lines
    def sixfold(start, line):
        return line * 6 if start == 4 and b" run *" in line else line

    r, doc = _relayed_run(build, tmp_path, sixfold)
    assert r.exit_code == 1, r.output
    bad = doc["rig"]["attempt"][3]
    assert bad["status"] == "incomplete" and "out of order" in bad["reason"]
    assert "more than the run's 325 samples" in bad["reason"]
    # at most the 325 lines read, less the 124 hold samples, are rows
    assert len((tmp_path / "set" / bad["file"]).read_text().splitlines()) - 1 \
        == bad["samples"] <= 325 - 124
    _identifies(tmp_path / "set", ["run01.csv", "run02.csv", "run03.csv"])

    flood = encode("EVENT", 7, "clip", 0.5) * 300_000

    def events(start, line):
        return flood + line if start == 4 and line.startswith(b"END") else line

    (tmp_path / "plan").rename(tmp_path / "plan1")
    (tmp_path / "set").rename(tmp_path / "set1")
    r, doc = _relayed_run(build, tmp_path, events)
    assert r.exit_code == 1, r.output
    bad = doc["rig"]["attempt"][3]
    assert bad["status"] == "incomplete" and "more than 389 EVENT lines" in bad["reason"]
    assert len(bad["events"]) == 64 and bad["events_dropped"] == 389 - 64
    _identifies(tmp_path / "set", ["run01.csv", "run02.csv", "run03.csv"])


def test_events_beyond_the_record_are_counted_and_the_run_completes(build, tmp_path):
    # 100 extra events in run 2 (fewer than one per sample): complete; 64 recorded
    seen = []

    def mangle(start, line):
        if start == 2 and line.startswith(b"EVENT"):
            seen.append(line)
        if start == 2 and line.startswith(b"END"):
            extra = encode("EVENT", 200, "clip", 0.25)
            seen.extend([extra] * 100)
            return extra * 100 + line
        return line

    r, doc = _relayed_run(build, tmp_path, mangle, runs=3)
    assert r.exit_code == 0, r.output
    a = doc["rig"]["attempt"][1]
    assert a["status"] == "complete"
    assert len(a["events"]) == 64 and a["events_dropped"] == len(seen) - 64
    _identifies(tmp_path / "set", ["run01.csv", "run02.csv", "run03.csv"])


def test_a_repeated_recording_is_incomplete(tmp_path, fake):
    # a rig that sends the same samples for every run: `phoid identify` refuses two data files
    # of the same content (a recording counted twice), so only the first run is complete
    plan = _plan(tmp_path, runs=3)
    rig = fake(lambda conn, cfg, k, stop: _good_run(conn, cfg))
    r = _cli("run", plan, "--port", rig.port, "--out", tmp_path / "set", "--hold", 0.1)
    assert r.exit_code == 1, r.output
    doc = _manifest(tmp_path / "set")
    assert [a["status"] for a in doc["rig"]["attempt"]] == ["complete", "incomplete",
                                                            "incomplete"]
    assert all("the same samples, byte for byte, as run 1 (run01.csv)" in a["reason"]
               for a in doc["rig"]["attempt"][1:])
    assert [run["file"] for run in doc["run"]] == ["run01.csv"]


def test_a_real_time_rig_completes_within_the_deadline(build, tmp_path):
    # the virtual rig paced to the wall clock: each run takes its 121 samples · 5 ms = 0.6 s;
    # the deadline (--timeout 1 + 121·(2T + 0.1 ms) = 2.2 s) leaves it room
    from phoid.rig.virtual import VirtualRig

    plan = _plan(tmp_path)
    rig = VirtualRig(Plant(m=2.0, c=1.0, k=64.0), build=build, realtime=True)
    with rig:
        host, num = rig.listen("127.0.0.1", 0)
        r, took = _timed_run(plan, f"tcp://{host}:{num}", tmp_path / "set")
    assert r.exit_code == 0, r.output
    assert took >= 2 * TOTAL * 0.005  # it did run in real time


# ---------------------------------------------------------------------------------------------
# 3. every option and what it makes: finite, in range, refused before connecting


@pytest.fixture
def listener():
    """A port that listens and records whether anything connected."""
    srv = socket.create_server(("127.0.0.1", 0))

    def connected():
        srv.setblocking(False)
        try:
            srv.accept()[0].close()
        except BlockingIOError:
            return False
        return True

    yield f"tcp://127.0.0.1:{srv.getsockname()[1]}", connected
    srv.close()


@pytest.mark.parametrize("option, value", [
    ("--pmax", "nan"), ("--pmax", "-1"), ("--dmax", "inf"), ("--hold", "1e300"),
    ("--hold", "nan"), ("--hold", "0"), ("--hold-p", "nan"), ("--hold-p", "-5"),
    ("--hold-d", "nan"), ("--hold-d", "-1"), ("--x-limit", "nan"), ("--x-limit", "0.005"),
    ("--x-limit", "1e309"), ("--u-max", "0"), ("--u-max", "-inf"), ("--timeout", "1e300"),
    ("--timeout", "nan"), ("--timeout", "0"), ("--timeout", "-1"),
])
def test_an_option_out_of_range_is_one_line_before_connecting(tmp_path, listener, option,
                                                              value):
    port, connected = listener
    plan = _plan(tmp_path)
    line = _fail_line(_cli("run", plan, "--port", port, "--out", tmp_path / "set", option,
                           value))
    assert option in line, line
    assert not connected()
    assert not (tmp_path / "set").exists()


def _edited_plan(tmp_path, change):
    plan = _plan(tmp_path)
    doc = tomllib.loads((plan / "experiment.toml").read_text())
    change(doc)
    (plan / "experiment.toml").write_text(tomli_w.dumps(doc))
    return plan


@pytest.mark.parametrize("change, words", [
    (lambda d: d["design"].update(fs=1e12), "[design] fs"),  # T = 1 ps < the 1 ns the C takes
    (lambda d: d["design"].update(fs=1e-320), "[design] fs"),  # T = inf
    (lambda d: d["design"].update(fs=1e-6), "[design] fs"),  # T = 11.6 days: over the day
    (lambda d: d["design"].update(duration=1e9), "[design] duration"),  # 2e11 samples
    (lambda d: d["design"].update(amplitude=1e308), "--x-limit"),  # 3 A overflows
    (lambda d: d["loop"].update(delay=1e10), "[loop] delay"),  # 2e12 samples of delay
    (lambda d: d["design"]["prior"].update(m=1e300, k=1e300), "hold_D"),  # √(m k) overflows
    (lambda d: d["run"][1].update(file="../run02.csv"), "plain file name"),
    (lambda d: d["run"][1].update(file="experiment.toml"), "plain file name"),
    (lambda d: d["run"][1].update(file="run01.csv"), "would both write"),
    (lambda d: d["run"][1].update(file="run01.aborted.csv"), "would both write"),
    (lambda d: d["design"].update(padding="x" * (2 * 2**20 - 4000)), "2 MiB"),
], ids=["fs-huge", "fs-tiny", "fs-slow", "duration", "amplitude", "delay", "prior", "name-outside",
        "name-manifest", "name-twice", "name-variant", "manifest-size"])
def test_a_plan_that_cannot_run_is_one_line_before_connecting(tmp_path, listener, change,
                                                              words):
    port, connected = listener
    plan = _edited_plan(tmp_path, change)
    line = _fail_line(_cli("run", plan, "--port", port, "--out", tmp_path / "set"))
    assert words in line, line
    assert not connected()
    assert not (tmp_path / "set").exists()


def test_a_negative_prior_mass_falls_back_and_does_not_fail(tmp_path, fake):
    # a prior m < 0 (a hand-edited plan) once raised "math domain error"; the hold loop's
    # defaults then use m = 1 kg
    plan = _edited_plan(tmp_path, lambda d: d["design"]["prior"].update(m=-2.0))
    rig = fake(lambda conn, cfg, k, stop: _good_run(conn, cfg, x=0.001 * k))  # runs differ
    r = _cli("run", plan, "--port", rig.port, "--out", tmp_path / "set", "--hold", 0.1)
    assert r.exit_code == 0, r.output


# ---------------------------------------------------------------------------------------------
# 4. no file in --out is replaced


@pytest.mark.parametrize("name", ["run01.csv", "run02.incomplete.csv", "run01.aborted.csv"])
def test_a_users_file_in_the_way_is_refused_before_connecting(tmp_path, listener, name):
    port, connected = listener
    plan = _plan(tmp_path)
    out = tmp_path / "set"
    out.mkdir()
    (out / name).write_text("my own data\n")
    line = _fail_line(_cli("run", plan, "--port", port, "--out", out))
    assert name in line and "not a file of this set" in line
    assert (out / name).read_text() == "my own data\n"
    assert not connected()
    assert sorted(p.name for p in out.iterdir()) == [name]


def _cut(conn, cfg):
    """The hold and 10 run samples, then the connection closed."""
    conn.sendall(b"".join(_sample(n, 0.005, _state(n, cfg)) for n in range(HOLD + 10)))
    conn.shutdown(socket.SHUT_RDWR)


def test_resume_touches_only_the_files_of_its_own_set(tmp_path, fake, listener):
    # run 2 of 3 is cut off (the rig closes mid-run): run01.csv complete, run02.incomplete.csv
    def script(conn, cfg, k, stop):
        return _good_run(conn, cfg) if k == 1 else _cut(conn, cfg)

    plan = _plan(tmp_path, runs=3)
    out = tmp_path / "set"
    rig = fake(script)
    r = _cli("run", plan, "--port", rig.port, "--out", out, "--hold", 0.1)
    assert r.exit_code == 1, r.output
    assert sorted(p.name for p in out.iterdir()) == [
        "experiment.toml", "run01.csv", "run02.incomplete.csv"]
    # a file of the user's where run 3 will write: refused, even with --resume
    (out / "run03.csv").write_text("mine\n")
    port, connected = listener
    line = _fail_line(_cli("run", plan, "--port", port, "--out", out, "--resume"))
    assert "run03.csv" in line and (out / "run03.csv").read_text() == "mine\n"
    assert not connected()
    (out / "run03.csv").unlink()
    # its own incomplete file stays, and a new attempt takes a free name beside it
    rig = fake(lambda conn, cfg, k, stop: _cut(conn, cfg))  # run 2 cut off again
    r = _cli("run", plan, "--port", rig.port, "--out", out, "--hold", 0.1, "--resume")
    assert r.exit_code == 1, r.output
    files = [a["file"] for a in _manifest(out)["rig"]["attempt"]]
    assert files == ["run01.csv", "run02.incomplete.csv", "run02.incomplete-2.csv"]
    # a manifest that is not a set of `phoid run` is not resumed
    other = tmp_path / "other"
    other.mkdir()
    (other / "experiment.toml").write_text('format = "phoid/1"\n')
    line = _fail_line(_cli("run", plan, "--port", port, "--out", other, "--resume"))
    assert "not a set of `phoid run`" in line


# ---------------------------------------------------------------------------------------------
# 5. a resumed set is the set recorded: its complete runs' files, its configuration


def _partial_set(tmp_path, fake, runs=2):
    """A set whose run 1 completed and run 2 was cut off (exit status 1)."""
    def script(conn, cfg, k, stop):
        return _good_run(conn, cfg) if k == 1 else _cut(conn, cfg)

    plan = _plan(tmp_path, runs=runs)
    out = tmp_path / "set"
    r = _cli("run", plan, "--port", fake(script).port, "--out", out, "--hold", 0.1)
    assert r.exit_code == 1, r.output
    return plan, out


def _point_run1_at(name):
    def change(out):
        doc = _manifest(out)
        doc["rig"]["attempt"][0]["file"] = name
        (out / "experiment.toml").write_text(tomli_w.dumps(doc))
    return change


def _fifo(out):
    (out / "run01.csv").unlink()
    os.mkfifo(out / "run01.csv")


def _link(out):
    (out / "run01.csv").unlink()
    (out / "run01.csv").symlink_to("/etc/hostname")


@pytest.mark.parametrize("change, words", [
    (lambda out: (out / "run01.csv").unlink(), "is missing"),
    (_point_run1_at("experiment.toml"), "is not the file the plan names"),
    (_point_run1_at("run02.csv"), "is not the file the plan names"),
    (_point_run1_at("run02.incomplete.csv"), "is not the file the plan names"),
    (_point_run1_at("run01.csv\n"), "is not the file the plan names"),
    (lambda out: ((out / "run01.csv").unlink(), (out / "run01.csv").mkdir()),
     "is not a regular file"),
    (_fifo, "is not a regular file"),
    (_link, "is a symbolic link"),
    (lambda out: (out / "run01.csv").write_text("t,x,u\n0,0,0\n0.005,0,0\n"),
     "its bytes changed"),
], ids=["missing", "manifest", "other-run", "other-attempt", "newline", "folder", "fifo", "link",
        "edited"])
def test_resume_refuses_a_complete_run_whose_file_is_not_its_own(tmp_path, fake, listener,
                                                                  change, words):
    # run 1 is recorded complete; its file gone, replaced or renamed in the manifest would
    # give a set phoid identify refuses (or reads the wrong data): one line naming run 1,
    # before connecting (docs/rig-protocol.md, "Limits of the host": Files)
    plan, out = _partial_set(tmp_path, fake)
    change(out)
    port, connected = listener
    line = _fail_line(_cli("run", plan, "--port", port, "--out", out, "--hold", 0.1,
                           "--resume"))
    assert "run 1 is recorded complete" in line and words in line, line
    assert not connected()


@pytest.mark.parametrize("change, extra, words", [
    (lambda d: d["design"].update(fs=400.0), (), "sample_time"),
    (lambda d: d["loop"].update(delay=0.01), (), "delay_samples"),
    (lambda d: d["design"].update(duration=1.0), (), "run_samples"),
    (lambda d: d["run"][0].update(P=d["run"][0]["P"] + 1.0), (), "P = "),
    (lambda d: None, ("--u-max", 5), "u_max"),
    (lambda d: None, ("--hold", 0.2), "hold_samples"),
], ids=["fs", "delay", "duration", "gain", "u-max", "hold"])
def test_resume_refuses_a_changed_configuration(tmp_path, fake, listener, change, extra, words):
    # a plan edited (or an option changed) between sessions would give a set whose [loop]
    # is not the loop its recorded runs were sampled with: refused before connecting, naming
    # the field that changed
    plan, out = _partial_set(tmp_path, fake)
    doc = tomllib.loads((plan / "experiment.toml").read_text())
    change(doc)
    (plan / "experiment.toml").write_text(tomli_w.dumps(doc))
    port, connected = listener
    args = ("--hold", 0.1, *extra) if "--hold" not in extra else extra
    line = _fail_line(_cli("run", plan, "--port", port, "--out", out, "--resume", *args))
    assert words in line and "--resume" in line, line
    assert not connected()


# ---------------------------------------------------------------------------------------------
# 6. a rig whose clock is not the configured period


@pytest.mark.parametrize("clock, complete", [
    (lambda n, T: n * T * 1e6, False),  # t in µs read as s: identify refuses such a set
    (lambda n, T: n * T * 1e300, False),  # finite, absurd
    (lambda n, T: n * T * 1e-3, False),  # t in ks: every step 1000 times short
    (lambda n, T: n * T * 1.5, False),  # 50 % slow: not the loop configured
    # a mean of T but a median step 1000 times short: the file's sample step identify reads
    (lambda n, T: n * T * 1e-3 + (n >= 2 * HOLD) * (TOTAL - 1) * T * 0.999, False),
    (lambda n, T: n * T * 1.02, True),  # 2 % slow: kept, with the documented note
], ids=["us", "1e300", "ks", "slow-50%", "median", "slow-2%"])
def test_a_rig_clock_off_the_configured_period_is_incomplete(tmp_path, fake, clock, complete):
    # docs/rig-protocol.md: the mean or the median interval more than 10 % from T makes the run
    # incomplete (identify would refuse the set, or model the wrong loop); within it a note
    def script(conn, cfg, k, stop):
        T = cfg["sample_time"]
        conn.sendall(b"".join(encode("SAMPLE", n, clock(n, T), 0.001 * k, 0.0, _state(n, cfg))
                              for n in range(TOTAL)) + encode("END", "done"))

    plan = _plan(tmp_path)
    r = _cli("run", plan, "--port", fake(script).port, "--out", tmp_path / "set", "--hold", 0.1)
    attempts = _manifest(tmp_path / "set")["rig"]["attempt"]
    if complete:
        assert r.exit_code == 0, r.output
        assert "the rig's sample intervals were" in r.stderr
        assert [a["status"] for a in attempts] == ["complete", "complete"]
    else:
        assert r.exit_code == 1, r.output
        assert [a["status"] for a in attempts] == ["incomplete", "incomplete"]
        assert "not the configured T = 0.005 s" in attempts[0]["reason"]


# ---------------------------------------------------------------------------------------------
# 7. the file system: names, a folder that cannot be written, a write that fails mid-run


def test_a_file_name_too_long_for_the_file_system_is_refused_before_connecting(tmp_path,
                                                                              listener):
    # 62 emoji: 66 characters (under the plan check's 200) but 252 bytes; its hidden .part
    # name is 267 bytes, over the 255 of NAME_MAX on Linux file systems
    plan = _edited_plan(tmp_path, lambda d: d["run"][0].update(file="\U0001F600" * 62 + ".csv"))
    port, connected = listener
    line = _fail_line(_cli("run", plan, "--port", port, "--out", tmp_path / "set"))
    assert "too long for the file system" in line, line
    assert not connected()
    assert not (tmp_path / "set").exists()


def test_a_folder_that_cannot_be_written_is_refused_before_connecting(tmp_path, listener):
    plan = _plan(tmp_path)
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() == 0:  # root writes through modes: a read-only mount instead
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)],
                           capture_output=True)
        if r.returncode:
            pytest.skip(f"root, and no read-only tmpfs to test with: {r.stderr!r}")
    else:
        ro.chmod(0o555)
    try:
        port, connected = listener
        line = _fail_line(_cli("run", plan, "--port", port, "--out", ro / "set"))
        assert "cannot write its files there" in line and str(ro / "set") in line, line
        assert not connected()
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", str(ro)], capture_output=True)
        ro.chmod(0o755)


PHOID = [sys.executable, "-c", "from phoid.cli import main; main()"]  # `phoid` in a subprocess


def _limit_file_size(limit):
    def preexec():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of the signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return preexec


def test_a_write_that_fails_mid_run_is_one_line_and_the_run_is_recorded(tmp_path, fake):
    # the file system refuses bytes beyond 8 kB (RLIMIT_FSIZE: the same failure as a full
    # disk, EFBIG for ENOSPC); a 2 s run at 200 Hz is 400 rows of about 45 bytes, written 256
    # (11 kB) at a time, so the first write fails mid-run (the manifest, about 4 kB, fits):
    # ABORT to the rig, the attempt recorded incomplete, no hidden .part left, one line naming
    # the run and the file
    got = []

    def script(conn, cfg, k, stop):
        _good_run(conn, cfg, x=0.0012345678901234567)  # rows of about 45 bytes
        conn.settimeout(5)
        with contextlib.suppress(OSError):
            while b"ABORT" not in b"".join(got) and (data := conn.recv(4096)):
                got.append(data)

    plan = _plan(tmp_path, duration=2.0)
    out = tmp_path / "set"
    r = subprocess.run([*PHOID, "run", str(plan), "--port",
                        fake(script).port, "--out", str(out), "--hold", "0.1", "--timeout", "5"],
                       capture_output=True, text=True, timeout=60,
                       preexec_fn=_limit_file_size(8192))
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1, r.stderr
    assert "run 1 (run01.csv): cannot write" in err[0] and ".part" in err[0], err
    assert b"ABORT" in b"".join(got)
    attempt = _manifest(out)["rig"]["attempt"][0]
    assert attempt["status"] == "incomplete" and "cannot write" in attempt["reason"]
    assert sorted(p.name for p in out.iterdir()) == ["experiment.toml", "run01.incomplete.csv"]
    # the file holds what its record says: the rows written whole (none here: the first write
    # of 256 rows was cut)
    rows = (out / "run01.incomplete.csv").read_text().splitlines()
    assert max(len(rows) - 1, 0) == attempt["samples"]


# ---------------------------------------------------------------------------------------------
# 8. SIGTERM, paths and ports


def test_sigterm_records_the_run_and_aborts_like_ctrl_c(tmp_path, fake):
    got, started = [], threading.Event()

    def script(conn, cfg, k, stop):  # a slow run: one sample every 20 ms
        conn.settimeout(0.02)
        for n in range(TOTAL):
            conn.sendall(_sample(n, cfg["sample_time"], _state(n, cfg)))
            started.set()
            with contextlib.suppress(TimeoutError):
                if (data := conn.recv(4096)):
                    got.append(data)
            if b"ABORT" in b"".join(got) or stop.is_set():
                return

    plan = _plan(tmp_path)
    out = tmp_path / "set"
    proc = subprocess.Popen([*PHOID, "run", str(plan), "--port",
                             fake(script).port, "--out", str(out), "--hold", "0.1",
                             "--timeout", "5"], stderr=subprocess.PIPE, text=True)
    assert started.wait(30)
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 143, stderr  # 128 + SIGTERM, as documented in phoid run's help
    assert "SIGTERM" in stderr and "Traceback" not in stderr
    assert b"ABORT" in b"".join(got)
    attempt = _manifest(out)["rig"]["attempt"][0]
    assert attempt["status"] == "incomplete" and "SIGTERM" in attempt["reason"]
    assert sorted(p.name for p in out.iterdir()) == ["experiment.toml", "run01.incomplete.csv"]


def test_the_default_out_is_beside_the_plan_even_as_dot(tmp_path, fake, monkeypatch):
    plan = _plan(tmp_path)
    rig = fake(lambda conn, cfg, k, stop: _good_run(conn, cfg, x=0.001 * k))
    monkeypatch.chdir(plan)
    r = _cli("run", ".", "--port", rig.port, "--hold", 0.1)
    assert r.exit_code == 0, r.output
    assert (tmp_path / "plan-run" / "experiment.toml").is_file()
    assert sorted(p.name for p in plan.iterdir()) == ["experiment.toml"]


@pytest.mark.parametrize("args, words", [
    (("--out", ""), "--out"),
    (("--out", "   "), "--out"),
    (("--port", "tcp://" + "a" * 64 + ":80"), "--port"),  # a DNS label is at most 63
    (("--port", "tcp://a b:80"), "--port"),
    (("--port", "tcp://" + "a." * 130 + ":80"), "--port"),  # a name is at most 253
], ids=["out-empty", "out-blank", "label", "space", "name"])
def test_an_empty_out_or_a_bad_host_name_is_one_line(tmp_path, listener, args, words):
    plan = _plan(tmp_path)
    port, connected = listener
    extra = ("--port", port, *args) if args[0] == "--out" else ("--out", tmp_path / "s", *args)
    line = _fail_line(_cli("run", plan, *extra))
    assert words in line, line
    assert not connected()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan"]


def test_a_plan_whose_path_is_not_utf8_is_one_line(tmp_path, listener):
    folder = Path(os.fsdecode(bytes(tmp_path) + b"/\xff"))
    try:
        folder.mkdir()
    except (OSError, UnicodeError):
        pytest.skip("the file system takes no name that is not UTF-8")
    plan = folder / "plan"
    _plan(tmp_path).rename(plan)  # designed where its path prints, then moved
    port, connected = listener
    line = _fail_line(_cli("run", plan, "--port", port, "--out", tmp_path / "set"))
    assert "not UTF-8" in line and "\\udcff" in line, line
    assert not connected()


# ---------------------------------------------------------------------------------------------
# 9. Samples beyond the configured run, interruptions before the first sample, one session a
# folder


def _far_run(key, value):
    """Run samples whose ``key`` (x or u) is ``value``: valid lines the controller configured
    with x within [x_min, x_max] (±3 A = ±0.03 m for the plan's 0.01 m) never streams without
    a fault. Each run's x is 1 nm off the last (k, the START's count), so that no two runs'
    samples are the same bytes (a repeated recording is incomplete)."""
    def script(conn, cfg, k, stop):
        T = cfg["sample_time"]
        lines = []
        for n in range(TOTAL):
            x, u = 0.001, 0.0
            if _state(n, cfg) == "run":
                x, u = (value + 1e-9 * k, u) if key == "x" else (x, value)
            lines.append(encode("SAMPLE", n, n * T, x, u, _state(n, cfg)))
        conn.sendall(b"".join(lines) + encode("END", "done"))
    return script


@pytest.mark.parametrize("key,value", [
    ("x", 1e308), ("x", -1e308),
    # 0.1 m: beyond the ±0.03 m limits and their span (0.06 m) again, yet no fault
    ("x", 0.1),
    ("u", 1.7976931348623157e308),  # beyond the 1e100 phoid identify squares without overflow
])
def test_a_run_sample_beyond_the_configured_limits_is_incomplete(tmp_path, fake, key, value):
    plan = _plan(tmp_path)
    out = tmp_path / "set"
    r, _ = _timed_run(plan, fake(_far_run(key, value)).port, out)
    assert r.exit_code == 1, r.output  # not "every run complete": identify could not read it
    attempts = _manifest(out)["rig"]["attempt"]
    assert [a["status"] for a in attempts] == ["incomplete", "incomplete"]
    assert all(f"sample {HOLD}: {key} = " in a["reason"] for a in attempts), attempts
    assert "run" not in _manifest(out)


def test_x_within_the_limits_and_their_margin_still_completes(tmp_path, fake):
    # 0.05 m: beyond x_max = 0.03 m but within its span again (0.09 m), the margin the host
    # allows the sample that trips a fault and sensor noise
    plan = _plan(tmp_path)
    out = tmp_path / "set"
    r, _ = _timed_run(plan, fake(_far_run("x", 0.05)).port, out)
    # x constant over the run (these runs are not identified): the host judges the stream only
    assert [a["status"] for a in _manifest(out)["rig"]["attempt"]] == ["complete"] * 2, r.output


@pytest.mark.parametrize("sig,rc,name", [(signal.SIGINT, 130, "SIGINT"),
                                         (signal.SIGTERM, 143, "SIGTERM")])
@pytest.mark.parametrize("phase", ["config", "start"])
def test_an_interruption_before_the_first_sample_is_recorded(tmp_path, fake, sig, rc, name,
                                                            phase):
    """The rig stalls after CONFIG (no OK) or after START (no sample): the host waits on it
    with the run's hidden file open; the signal (sent twice, as a shell's process-group kill
    and ``timeout`` together do) must leave the attempt recorded and no hidden file."""
    waiting = threading.Event()

    def stall(conn, *args):
        waiting.set()
        args[-1].wait(30)

    plan = _plan(tmp_path)
    out = tmp_path / "set"
    rig = fake(stall) if phase == "start" else fake(config=stall)
    proc = subprocess.Popen([*PHOID, "run", str(plan), "--port", rig.port, "--out", str(out),
                             "--hold", "0.1", "--timeout", "20"], stderr=subprocess.PIPE,
                            text=True)
    assert waiting.wait(30)
    time.sleep(0.2)  # the host is in its read now
    proc.send_signal(sig)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == rc, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"phoid: stopped by {name}"), stderr
    assert "the runs recorded are in" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == ["experiment.toml", "run01.incomplete.csv"]
    attempt = _manifest(out)["rig"]["attempt"][0]
    assert attempt["status"] == "incomplete" and attempt["samples"] == 0
    assert "interrupted on the host" in attempt["reason"]


def test_a_second_session_into_the_same_out_is_refused_before_connecting(tmp_path, fake,
                                                                          listener):
    waiting = threading.Event()

    def stall(conn, cfg, k, stop):
        waiting.set()
        stop.wait(30)

    plan = _plan(tmp_path)
    out = tmp_path / "set"
    first = subprocess.Popen([*PHOID, "run", str(plan), "--port", fake(stall).port, "--out",
                              str(out), "--hold", "0.1", "--timeout", "20"],
                             stderr=subprocess.PIPE, text=True)
    try:
        assert waiting.wait(30)
        port, connected = listener
        for extra in ((), ("--resume",)):
            line = _fail_line(_cli("run", plan, "--port", port, "--out", out, *extra))
            assert "another `phoid run` is writing a set there" in line, line
            assert not connected()
    finally:
        first.send_signal(signal.SIGINT)
        _, stderr = first.communicate(timeout=30)
    assert first.returncode == 130, stderr
    # the first session's record is whole; its lock went with it: a --resume now runs
    assert sorted(p.name for p in out.iterdir()) == ["experiment.toml", "run01.incomplete.csv"]
    r = _cli("run", plan, "--port", fake(_far_run("x", 0.001)).port, "--out", out, "--resume",
             "--hold", 0.1, "--timeout", TIMEOUT)
    assert r.exit_code == 0, r.output


def _edit_record(change):
    def edit(out):
        doc = _manifest(out)
        change(doc["rig"])
        (out / "experiment.toml").write_text(tomli_w.dumps(doc))
    return edit


@pytest.mark.parametrize("change, words", [
    # a key the plan never sends would be dropped silently by a resumed session
    (lambda rig: rig["config"].update(stall_samples=5), "'stall_samples', which phoid run "
                                                        "never sends"),
    (lambda rig: rig["config"].update(hold_samples=str(rig["config"]["hold_samples"])),
     "hold_samples = '20' is not a number"),  # 20: --hold 0.1 s at 200 Hz
    (lambda rig: rig["attempt"][0].update(digest="md5:" + "0" * 32), "malformed digest"),
    (lambda rig: rig["attempt"][0].update(digest=12), "malformed digest 12"),
], ids=["unknown-key", "string", "md5", "number"])
def test_resume_refuses_a_malformed_record(tmp_path, fake, listener, change, words):
    plan, out = _partial_set(tmp_path, fake)
    _edit_record(change)(out)
    port, connected = listener
    line = _fail_line(_cli("run", plan, "--port", port, "--out", out, "--hold", 0.1,
                           "--resume"))
    assert words in line and "its bytes changed" not in line, line
    assert not connected()
