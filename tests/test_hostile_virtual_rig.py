"""The virtual rig against a hostile host: real sockets against a real VirtualRig (and the
`phoid virtual-rig` subprocess), every failure an ERROR line, never a traceback.

What is checked comes from docs/rig-protocol.md ("The rig's side"): a line the rig cannot use
is answered `ERROR` (sendable: printable ASCII without `*`, at most 4096 bytes) and the session
goes on; a line longer than 4096 bytes is refused once and skipped; CONFIG values are checked
against the C types (counts at most 2^31 − 1, the portable bound of phoid_ctrl.h's
PHOID_MAX_COUNT) and what the rig can run; a run whose simulation overflows ends with a fault;
an idle host, a session over its time and a second host get an ERROR and are closed. Every test
skips without a C compiler; idle timeouts here are a fraction of a second, so the file is fast.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import zlib
from pathlib import Path

import pytest

from phoid.dynamics.plant import Plant
from phoid.rig.native import Controller, build_library, find_compiler
from phoid.rig.protocol import MAX_LINE, ProtocolError, encode, encode_config, hello, parse

NO_CC = "no C compiler (CC, cc, gcc, clang): the rig's controller cannot be built"
PAPER = Plant(m=2.0, c=1.0, k=64.0)  # the seed paper's plant, as in test_rig_end_to_end.py
# a run the rig accepts: 100 Hz, 10 samples held, 20 run (a few ms of simulation)
GOOD = {"sample_time": 0.01, "P": 12.625, "D": 3.3, "hold_P": 150.0, "hold_D": 25.0,
        "x_start": 0.01, "hold_samples": 10, "run_samples": 20}
IDLE = 0.5  # s: the rigs' idle timeout in these tests (short, so the file is fast)
WAIT = 5.0  # s a test waits for a line: far above every bound the rig keeps (≤ ~1.5 s here)


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    if find_compiler() is None:
        pytest.skip(NO_CC)
    folder = tmp_path_factory.mktemp("rig-build")
    build_library(folder)
    return folder


@pytest.fixture
def rig(build):
    """A factory of listening rigs (closed after the test)."""
    from phoid.rig.virtual import VirtualRig

    made = []

    def make(plant=PAPER, **kw):
        kw.setdefault("idle_timeout", IDLE)
        r = VirtualRig(plant, build=build, **kw)
        made.append(r)
        return r.listen("127.0.0.1", 0)

    yield make
    while _OPEN:  # the hosts first: a rig closed under an open session waits for it
        _OPEN.pop().close()
    for r in made:
        r.close()


_OPEN: list[Host] = []


@pytest.fixture(autouse=True)
def _close_hosts():
    yield
    while _OPEN:
        _OPEN.pop().close()


class Host:
    """A host speaking the protocol by hand over a real socket (closed after the test)."""

    def __init__(self, addr, say_hello=True):
        self.sock = socket.create_connection(addr, timeout=WAIT)
        self.f = self.sock.makefile("rb")
        _OPEN.append(self)
        if say_hello:
            self.send(hello())
            assert self.msg().kind == "HELLO"

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def raw(self) -> bytes:
        return self.f.readline()

    def msg(self):
        line = self.raw()
        assert line, "the rig closed the connection"
        assert len(line) <= MAX_LINE and line.endswith(b"\n")
        return parse(line)  # a valid line: checksum, printable ASCII, no `*` in the payload

    def error(self) -> str:
        m = self.msg()
        assert m.kind == "ERROR", m
        return str(m.fields["message"])

    def closed(self) -> bool:
        return self.raw() == b""

    def config_ok(self, cfg=GOOD) -> None:
        self.send(encode_config(cfg))
        assert self.msg().kind == "OK"

    def run(self):
        """START, and the run's lines up to END (all of them parsed)."""
        self.send(encode("START"))
        out = []
        while True:
            m = self.msg()
            out.append(m)
            if m.kind in ("END", "ERROR"):
                return out

    def close(self) -> None:
        self.f.close()
        self.sock.close()


def _framed(payload: bytes) -> bytes:
    return payload + b" *" + f"{zlib.crc32(payload):08x}".encode() + b"\n"


# --- issue 5: lines the rig cannot use --------------------------------------------------------

@pytest.mark.parametrize("line", [
    b"hello\n",                                    # no checksum
    b"\x00\xff\xfe*** \x1b[2J junk *\n",           # random bytes, stars, control characters
    b"*\n",
    b"START *zzzzzzzz\n",                          # a checksum that is not hex
    b"START *0x682d97\n",                          # int(..., 16) would take it; not 8 hex digits
    _framed(b"CONFIG P=1_000"),                    # not a decimal number (Python int() takes it)
    _framed("CONFIG P=\u00e9".encode("latin-1")),  # not ASCII
    b"START",                                      # no LF yet: completed by the next line
])
def test_a_line_the_rig_cannot_use_is_answered_error_and_the_session_goes_on(rig, line):
    host = Host(rig())
    host.send(line)
    if not line.endswith(b"\n"):
        host.send(b"\n")
    assert host.error()  # an ERROR the host can parse (msg() checks checksum and framing)
    host.config_ok()  # the same session goes on
    assert host.run()[-1].fields == {"reason": "done"}
    host.close()


def test_error_text_is_always_sendable():
    # the rig quotes hostile lines back: `*`, control and non-ASCII characters are escaped,
    # and a long text is cut to one line of at most MAX_LINE bytes (docs/rig-protocol.md)
    for text in ["a*b", "\x00\x1b\xff\u20ac\U0001f600", "x" * 10 * MAX_LINE, "", "a\nb\tc"]:
        line = encode("ERROR", text)
        assert len(line) <= MAX_LINE
        back = parse(line).fields["message"]
        assert "*" not in back and back.isascii() and back.isprintable()
    assert parse(encode("ERROR", "a*b")).fields["message"] == "a\\x2ab"  # Python's escape
    with pytest.raises(ProtocolError, match="not ASCII"):
        parse("START \u20ac *00000000\n")


def test_garbage_instead_of_the_hello_is_answered_and_closed(rig):
    host = Host(rig(), say_hello=False)
    host.send(b"\xff\xfe not a hello * at all\n")
    assert "checksum" in host.error()
    assert host.closed()


def test_a_10_mb_line_is_refused_once_and_skipped_to_its_end(rig):
    host = Host(rig())
    host.send(b"A" * 10_000_000 + b"\n")
    assert f"longer than {MAX_LINE} bytes" in host.error()
    # one ERROR for the whole line: the next line the rig answers is this CONFIG's OK
    host.config_ok()
    # a long line that ends within the rig's receive buffer is refused the same way
    host.send(b"B" * (MAX_LINE + 100) + b"\n")
    assert f"longer than {MAX_LINE} bytes" in host.error()
    host.config_ok()
    host.close()


def test_a_run_whose_commands_overflow_ends_with_a_fault(rig):
    # the CONFIG: P = D = 1e300 without a growth bound; the noise moves x off the
    # reference, so P·x and D·v̂ overflow a double (u would be inf or NaN)
    host = Host(rig(noise=1e-5, seed=3))
    host.config_ok(dict(GOOD, P=1e300, D=1e300, growth_limit=0.0, run_samples=2000))
    lines = host.run()
    end = lines[-1]
    assert end.kind == "END" and end.fields["reason"].startswith("fault-")
    # the fault that ended it is in the event log (docs: END names the fault)
    assert end.fields["reason"] in [m.fields["name"] for m in lines if m.kind == "EVENT"]
    host.config_ok()  # the session goes on
    host.close()


def test_a_plant_that_overflows_faults_the_run_and_the_session_goes_on(rig):
    # a free mass of 1 mg pushed by a constant 1e300 N: x = −f₀t²/(2m) = −5e305·n² m at
    # T = 1 s passes the largest double (1.8e308) at n = 19 (1.62e308 at n = 18): the rig reads
    # a non-finite position, the controller faults (fault-input, the C README) and that
    # sample is not sent (a SAMPLE carries finite numbers only)
    host = Host(rig(Plant(m=1e-6, c=0.0, k=0.0), offset_force=1e300))
    host.config_ok({"sample_time": 1.0, "hold_samples": 1, "run_samples": 100,
                    "x_min": -1.7e308, "x_max": 1.7e308})
    lines = host.run()
    samples = [m.fields["index"] for m in lines if m.kind == "SAMPLE"]
    assert samples == list(range(19))
    assert ("fault-input", 19) in [(m.fields["name"], m.fields["index"])
                                   for m in lines if m.kind == "EVENT"]
    assert lines[-1].fields == {"reason": "fault-input"}
    host.config_ok()
    host.close()


def test_the_controller_faults_on_a_command_that_is_not_finite(build):
    # phoid_ctrl.c: a command that is not finite faults (fault-command, value x) and 0 goes out
    ctrl = Controller(dict(sample_time=0.01, P=1e300, hold_samples=1, run_samples=10), build)
    ctrl.start()
    assert ctrl.step(0.0) == 0.0  # hold (hold gains 0)
    u = ctrl.step(1e10)  # released: u = −1e300·1e10 = −inf
    assert u == 0.0 and ctrl.state == "fault"
    assert [(e.name, e.index, e.value) for e in ctrl.events()][-1] == (
        "fault-command", 1, 1e10)


# --- issue 6: CONFIG values ---------------------------------------------------------------

@pytest.mark.parametrize("field, value", [
    ("hold_samples", 2**64),       # wrapped to 0 (hold for ever) before
    ("hold_samples", 2**31),       # past a 32-bit long (PHOID_MAX_COUNT = 2^31 − 1)
    ("hold_samples", -1),
    ("hold_samples", 0),           # hold until a release: the protocol has none
    ("run_samples", 2**31),
    ("run_samples", 0),
    ("stall_samples", 2**31),
    ("stall_samples", -(2**63) - 1),
    ("velocity", 2**32),           # a C int: would wrap to 0
    ("delay_samples", 2**32 + 1),  # would wrap to 1
    ("has_force", 2**32 + 1),
    ("sample_time", 1e300),        # slower than the rig samples (1 s)
    ("sample_time", 1e-300),       # faster than --max-rate
    ("sample_time", -0.01),
    ("growth_limit", 0.5),
    ("x_start", 5.0),              # outside [x_min, x_max]
    ("u_max", 0.0),
    ("filter_pole", 1.0),
    ("command_gain", 1e300),       # × the default u_max 1e300: no finite largest force
    ("has_force", 1),              # this rig has no force sensor
])
def test_config_values_out_of_range_are_refused_naming_the_field(rig, field, value):
    host = Host(rig())
    cfg = dict(GOOD, x_min=-1.0, x_max=1.0, **{field: value})
    if field == "filter_pole":
        cfg["velocity"] = 2
    host.send(encode_config(cfg))
    assert field in host.error()
    host.send(encode("START"))
    assert "without an accepted CONFIG" in host.error()  # nothing runs
    host.close()


def test_a_run_longer_than_the_rig_runs_is_refused(rig):
    addr = rig(max_samples=1000)
    host = Host(addr)
    host.send(encode_config(dict(GOOD, hold_samples=500, run_samples=500)))  # 1001 samples
    err = host.error()
    assert "run_samples" in err and "--max-samples" in err
    host.config_ok(dict(GOOD, hold_samples=499, run_samples=500))  # 1000: the bound
    host.close()


def test_a_real_time_run_longer_than_a_session_is_refused(rig):
    host = Host(rig(realtime=True, max_session=2.0))
    host.send(encode_config(dict(GOOD, hold_samples=100, run_samples=200)))  # 3.01 s at 100 Hz
    assert "--max-session" in host.error()
    host.close()


# --- issue 6: idle, busy, session time --------------------------------------------------------

def test_an_idle_host_is_closed_and_a_second_host_is_refused_at_once(rig):
    addr = rig()
    idle = Host(addr)  # says hello, then nothing
    t0 = time.monotonic()
    second = Host(addr, say_hello=False)
    second.send(hello())
    assert second.error().startswith("busy: another host is connected")
    assert second.closed()
    assert time.monotonic() - t0 < 3.0  # never a silent wait (the rig's grace is 1 s)
    assert "--idle-timeout" in idle.error()  # after IDLE s without a line
    assert idle.closed()
    assert time.monotonic() - t0 < IDLE + 3.0
    third = Host(addr)  # the rig is free again
    third.config_ok()
    assert third.run()[-1].fields == {"reason": "done"}
    for h in (idle, second, third):
        h.close()


def test_a_flood_of_hosts_is_refused_and_the_session_goes_on(rig):
    addr = rig(idle_timeout=30.0)
    first = Host(addr)
    t0 = time.monotonic()
    others = [Host(addr, say_hello=False) for _ in range(40)]  # more than MAX_REFUSING (16)
    for other in others:
        assert other.error().startswith("busy: another host is connected")
        assert other.closed()
    assert time.monotonic() - t0 < WAIT  # each within the rig's 1 s grace, none waits on
    first.config_ok()
    assert first.run()[-1].fields == {"reason": "done"}


def test_a_host_that_never_says_hello_is_closed(rig):
    host = Host(rig(), say_hello=False)
    t0 = time.monotonic()
    assert "no hello" in host.error()
    assert host.closed()
    assert time.monotonic() - t0 < IDLE + 3.0


def test_a_session_ends_at_its_time_limit_however_busy_the_host(rig):
    host = Host(rig(max_session=1.0))
    t0 = time.monotonic()
    while True:  # a line every 0.1 s: never idle
        host.send(encode("CLEAR"))
        m = host.msg()
        if m.kind == "ERROR":
            break
        assert m.kind == "OK" and time.monotonic() - t0 < WAIT
        time.sleep(0.1)
    assert "--max-session" in m.fields["message"]
    assert host.closed()
    host.close()


def test_a_host_that_reads_nothing_is_dropped(rig, monkeypatch):
    from phoid.rig import virtual

    monkeypatch.setattr(virtual, "SEND_TIMEOUT", 0.5)  # the floor of the send timeout
    addr = rig()
    host = Host(addr)
    host.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    host.config_ok(dict(GOOD, sample_time=1e-4, hold_samples=10, run_samples=1_000_000))
    host.send(encode("START"))  # ~60 MB of samples, and this host reads none of them
    t0 = time.monotonic()
    while True:  # the rig gives up on the stuck send and serves the next host
        other = Host(addr, say_hello=False)
        other.send(hello())
        m = other.msg()
        other.close()
        if m.kind == "HELLO":
            break
        assert "busy" in m.fields["message"] and time.monotonic() - t0 < 15.0
    host.close()


# --- the command-line rig ---------------------------------------------------------------------

def test_the_cli_rig_answers_hostile_hosts_without_a_traceback(build):
    src = Path(__file__).resolve().parents[1] / "src"
    env = {**os.environ, "PYTHONPATH": f"{src}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    cmd = [sys.executable, "-c", "from phoid.cli import main; main()", "virtual-rig", "--m",
           "2", "--c", "1", "--k", "64", "--noise", "1e-5", "--seed", "1", "--listen",
           "127.0.0.1:0", "--build", str(build), "--idle-timeout", str(IDLE)]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stderr.readline()
        assert "listening on tcp://127.0.0.1:" in line, line
        host_, port = line.split("listening on tcp://")[1].split(";")[0].rsplit(":", 1)
        addr = (host_, int(port))
        host = Host(addr)
        host.send(b"no checksum * here\n")  # issue 5: the rig's own text held a `*`
        host.error()
        host.send(b"x" * 10_000_000 + b"\n")
        host.error()
        for cfg in ({"sample_time": 1e300}, {"hold_samples": 2**64}):
            host.send(encode_config(dict(GOOD, **cfg)))
            assert next(iter(cfg)) in host.error()
        host.config_ok(dict(GOOD, P=1e300, D=1e300, growth_limit=0.0))
        assert host.run()[-1].fields["reason"].startswith("fault-")
        second = Host(addr, say_hello=False)
        assert second.error().startswith("busy")
        second.close()
        assert "--idle-timeout" in host.error()
        host.close()
    finally:
        proc.terminate()
        rc = proc.wait(timeout=30)
        rest = proc.stderr.read()
        proc.stderr.close()
    assert rc == 0 and rest == "", rest  # nothing on stderr after the listening line


@pytest.mark.parametrize(("option", "value"), [
    ("--idle-timeout", "-1"), ("--idle-timeout", "nan"), ("--max-session", "inf"),
    ("--max-rate", "0"), ("--max-samples", "1"), ("--noise", "-1"), ("--force-noise", "nan"),
    ("--offset-force", "inf"), ("--m", "nan"), ("--c", "inf"), ("--k", "-1"), ("--fc", "nan"),
    # a day at most: socket.settimeout overflowed for every connection at 1e10 s
    ("--idle-timeout", "1e10"), ("--max-session", "1e6"),
    ("--force-noise", "1e308"),  # G·u + noise would overflow: at most 1e300 N
    ("--max-rate", "1e12"),      # faster than the controller's 1 ns
    ("--seed", "-1"),            # NumPy's own message named no option
    ("--listen", "127.0.0.1:99999"),  # parse_port's message named --port
])
def test_the_cli_rig_names_the_option_out_of_range(option, value, tmp_path):
    # the rig's and the plant's checks speak of keyword arguments (max_rate, `m`); the command
    # line names the option the user typed, refused before anything is built or served
    args = {"--m": "1", "--c": "1", "--k": "1", option: value}
    cmd = [sys.executable, "-m", "phoid.cli", "virtual-rig", "--listen", "127.0.0.1:0",
           "--build", str(tmp_path / "build"), *[a for kv in args.items() for a in kv]]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"phoid: error: {option} "), proc.stderr
    assert not (tmp_path / "build").exists()  # refused before the controller was built


# --- the prober's round A: a refused line, options and plants that overflow -------------------

def _corrupt_crc(line: bytes) -> bytes:
    """The line with its checksum's last digit changed (a damaged line that may be a CONFIG)."""
    last = line[-2:-1]
    return line[:-2] + (b"0" if last != b"0" else b"1") + b"\n"


def _upper_crc() -> bytes:
    """A good CONFIG line with its checksum in upper case (the first P whose CRC has a letter)."""
    for p in range(1, 100):
        line = encode_config(dict(GOOD, P=float(p)))
        upper = line[:-9] + line[-9:].upper()
        if upper != line:
            return upper
    raise AssertionError("no CRC with a hex letter among 99 lines")  # 16^-8·... never


@pytest.mark.parametrize("bad", [
    _framed(b"CONFIG P=nan"),                                   # a field refused
    _framed(b"CONFIG P=1 P=2"),                                 # a field given twice
    _corrupt_crc(encode_config(dict(GOOD, P=5000.0))),          # a CONFIG with a broken checksum
    _upper_crc(),                                               # a CONFIG, crc in upper case
    encode_config(dict(GOOD, x_start=5.0, x_min=-1.0, x_max=1.0)),  # refused by its value
    _framed(b"SAMPLE 1 0.1 0.0 0.0 run"),                       # a line the rig does not take
    b"Z" * (MAX_LINE + 10) + b"\n",                             # an overlong line
])
def test_a_refused_line_leaves_no_configuration(rig, bad):
    # docs/rig-protocol.md: "A refused CONFIG leaves no configuration: a START after it is
    # refused too" — and a line refused whole may have been a CONFIG, so every line the rig
    # refuses clears the configuration accepted before it
    host = Host(rig())
    host.config_ok()
    host.send(bad)
    assert host.error()
    host.send(encode("START"))
    assert "without an accepted CONFIG" in host.error()  # the old configuration did not run
    host.config_ok()  # a new CONFIG is taken again
    assert host.run()[-1].fields == {"reason": "done"}


def test_a_line_refused_during_a_run_leaves_no_configuration(rig):
    # real time: the rig reads the host's lines between samples (0.01 s apart, 31 samples)
    host = Host(rig(realtime=True))
    host.config_ok()
    host.send(encode("START"))
    assert host.msg().kind == "SAMPLE"  # the run is under way
    host.send(_corrupt_crc(encode_config(GOOD)))
    kinds = []
    while (m := host.msg()).kind != "END":
        kinds.append(m.kind)
    assert "ERROR" in kinds  # the damaged line was refused while the run went on
    host.send(encode("START"))
    assert "without an accepted CONFIG" in host.error()


@pytest.mark.parametrize("line", [
    b"START *682D973F\n",   # zlib.crc32(b"START") in upper case (docs: lower-case hex)
    _framed(b"PHOID-RIG 01"),  # a version with a leading zero
    _framed(b"PHOID-RIG +1"),
])
def test_the_parser_takes_only_what_the_protocol_writes(line):
    with pytest.raises(ProtocolError):
        parse(line)
    assert parse(b"START *682d973f\n").kind == "START"  # the docs' example, lower case


@pytest.mark.parametrize("kw", [
    dict(plant=Plant(m=2.0, c=1e300, k=64.0)),    # (c/2m)^2 overflows in the plant's setup
    dict(plant=Plant(m=1e-200, c=1.0, k=64.0)),
    dict(plant=Plant(m=5e-324, c=1.0, k=64.0)),   # c/m = inf: the map at 50 us overflows
    dict(plant=Plant(m=5e-309, c=0.0, k=0.0)),    # 1/m·T = 2e308 at T = 1 s (Γ's velocity)
    dict(plant=Plant(m=2.0, c=1.0, k=1e300)),     # oscillates too fast even at 20 kHz
])
def test_a_plant_the_rig_cannot_simulate_is_refused_when_the_rig_is_made(build, kw):
    from phoid.rig.virtual import VirtualRig

    with pytest.raises(ValueError, match=r"`m` .*`k` .*cannot simulate this plant") as err:
        VirtualRig(build=build, **kw)
    assert "\n" not in str(err.value)


def test_a_sample_time_too_slow_for_the_plant_is_refused_naming_it(rig):
    # k = 1e12 N/m, m = 2 kg: ω = 7.1e5 rad/s, 2.2 us a quarter period — 23 in a 50 us sample
    # (served), 450 000 in a 1 s one (more than the simulation cuts a sample into, 1000)
    host = Host(rig(Plant(m=2.0, c=1.0, k=1e12)))
    host.send(encode_config(dict(GOOD, sample_time=1.0)))
    err = host.error()
    assert err.startswith("sample_time 1 s") and "the rig failed" not in err
    host.send(encode("START"))
    assert "without an accepted CONFIG" in host.error()
    host.config_ok(dict(GOOD, sample_time=1e-4, x_min=-1.0, x_max=1.0))


def test_a_measured_force_that_overflows_faults_the_run_and_the_session_goes_on(rig):
    # command_gain·u_max is the largest double, so G·u = ±1.8e308 N at every sample (|u| is
    # clipped to u_max = 1); adding noise of 1e300 N overflows whenever the draw has u's sign
    # and is not tiny (about half the samples: the chance that none of 31 does is ~5e-10).
    # A heavy mass (1e300 kg) keeps the position finite and inside its limits meanwhile.
    big = 1.7976931348623157e308  # the largest double (sys.float_info.max)
    host = Host(rig(Plant(m=1e300, c=1.0, k=64.0), force_noise=1e300, seed=5))
    host.config_ok(dict(GOOD, command_gain=big, u_max=1.0, x_start=1.0, x_min=-1e300,
                        x_max=1e300, has_force=1))
    lines = host.run()
    assert lines[-1].fields == {"reason": "fault-input"}
    samples = [m.fields["index"] for m in lines if m.kind == "SAMPLE"]
    assert samples == list(range(len(samples)))  # every one sent parsed: finite forces
    faults = [(m.fields["index"], m.fields["value"]) for m in lines
              if m.kind == "EVENT" and m.fields["name"] == "fault-input"]
    # the sample whose force overflowed is not sent; the controller reads that force at the
    # next sample and faults (value 1: the measured force, src/phoid/rig/c/README.md)
    assert faults == [(len(samples) + 1, 1.0)]
    host.config_ok()  # the session goes on


@pytest.mark.parametrize(("option", "value", "named"), [
    ("--c", "1e300", "--c 1e+300"),        # overflows in the plant's setup ((c/2m)^2)
    ("--m", "5e-324", "--m 4.94066e-324"),  # overflows in its map (c/m = inf)
])
def test_the_cli_rig_refuses_a_plant_it_cannot_simulate_in_one_line(option, value, named,
                                                                   tmp_path):
    args = {"--m": "2", "--c": "1", "--k": "64", option: value}
    cmd = [sys.executable, "-m", "phoid.cli", "virtual-rig", "--listen", "127.0.0.1:0",
           "--build", str(tmp_path / "build"), *[a for kv in args.items() for a in kv]]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: --m "), proc.stderr
    assert named in lines[0] and "cannot simulate this plant" in lines[0]
    assert not (tmp_path / "build").exists()  # refused before the controller was built
