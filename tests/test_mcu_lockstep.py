"""The rig firmware in QEMU, in lockstep with phoid's exact plant: bit for bit the host build.

The firmware (src/phoid/rig/c/firmware: phoid_fw.c on the controller, board_mps2_hil.c) is
cross-built with its own Makefile for three emulated ARM MPS2 boards — mps2-an385 (Cortex-M3,
no FPU: double in software), mps2-an386 (Cortex-M4F: float in hardware, double in software),
mps2-an500 (Cortex-M7, double-precision FPU) — and run in QEMU. This test is the host
(`phoid run`'s side of UART0: the text hello, FRAMING cobs, then binary CONFIG/START/ABORT
frames, phoid.rig.frames) and, over UART1, the plant (phoid.rig.plant: phoid's exact ZOH plant,
one position per sample, one command back). Both serial lines are real TCP sockets on the
loopback (QEMU's -serial tcp:…,nodelay=on).

The same plant (same seed: the same noise) then drives the host build of the same controller
(phoid.rig.native.Controller, the ctypes library) in the same loop. The expected values are
that host run's, computed here, not copied from the firmware:

* the double firmware is bit-identical to the host double build on every board: every
  sample's x, u and state, every event (index, name, value), the END reason — the ARM FPUs and
  libgcc's software double are IEEE-correct, and -std=c99 -ffp-contract=off keeps GCC from
  fusing multiply-adds on either side;
* the float firmware (M4F) is bit-identical to the host float build (real="float") and within
  a bound of the double build derived below (test_float_build_within_its_bound).

Runs: hold → release → run → done with the hold's first commands clipped; a growth fault; an
abort from the host mid-run; the link's refusals. Each run is a few hundred samples (QEMU
steps about 1000 lockstep samples per second here), so the file takes a few seconds.
"""

from __future__ import annotations

import math
import shutil
import socket
import struct
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from mcu_tools import FIRMWARE_DIR, tool

from phoid.dynamics.plant import Plant
from phoid.rig import frames
from phoid.rig.native import Controller, build_library, find_compiler
from phoid.rig.plant import PlantModel, VirtualPlant
from phoid.rig.protocol import hello, parse

BOARDS = {  # QEMU machine → (firmware TARGET, the CPU)
    "mps2-an385": "m3",
    "mps2-an386": "m4f",
    "mps2-an500": "m7",
}
FRAMING = b"FRAMING cobs *df590735\n"  # zlib.crc32(b"FRAMING cobs") = 0xdf590735
WAIT = 30.0  # s for any one reply of the emulated board (they come in milliseconds)
STATES = ("idle", "hold", "run", "done", "fault")

# the seed paper's plant, m 2 kg, c 1 N s/m, k 64 N/m, at 200 Hz: the hold pulls it to
# x_start = 1 cm (P 192 = 3k, D 20), the run (P 40, D -0.5: a lightly damped ring) lasts 300
# samples; u_max 1.5 clips the hold's first commands (192·0.01 = 1.92 > 1.5)
PLANT = Plant(m=2.0, c=1.0, k=64.0)
RUN = {"sample_time": 0.005, "P": 40.0, "D": -0.5, "hold_P": 192.0, "hold_D": 20.0,
       "x_start": 0.01, "hold_samples": 80, "run_samples": 300, "u_max": 1.5,
       "x_min": -0.05, "x_max": 0.05, "command_gain": 1.0, "delay_samples": 1}
NOISE = 1e-6  # m: the encoder's noise, in the loop (seeded: both sides read the same)


@pytest.fixture(scope="module")
def tools():
    tool("arm-none-eabi-gcc")
    tool("qemu-system-arm")
    tool("make")
    if find_compiler() is None:
        pytest.skip("no C compiler (CC, cc, gcc, clang): the host build cannot be made")


@pytest.fixture(scope="module")
def host_build(tmp_path_factory, tools):
    folder = tmp_path_factory.mktemp("host-build")
    build_library(folder)
    build_library(folder, real="float")
    return folder


_ELVES: dict[tuple[str, str], Path] = {}


def firmware(target: str, real: str, root: Path) -> Path:
    """The firmware ELF of a target and real type, built by its Makefile into ``root``."""
    key = (target, real)
    if key not in _ELVES:
        out = root / f"fw-{target}-{real}"
        proc = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), f"TARGET={target}",
                               f"REAL={real}", "BOARD=mps2_hil", f"OUT={out}"],
                              capture_output=True, text=True, timeout=120, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        _ELVES[key] = out / "phoid_fw.elf"
    return _ELVES[key]


@pytest.fixture(scope="module")
def fw_root(tmp_path_factory, tools):
    return tmp_path_factory.mktemp("firmware")


@dataclass
class Record:
    samples: list[tuple[int, str, float, float]]  # index, state, x, u
    events: list[tuple[int, str, float]]
    end: str


class Board:
    """One emulated board: QEMU with UART0 on a socket to this test and UART1 on the plant."""

    def __init__(self, machine: str, elf: Path, model: PlantModel) -> None:
        self.plant = VirtualPlant(model, record=True, log=self._complain)
        self.complaints: list[str] = []
        _, plant_port = self.plant.listen("127.0.0.1", 0)
        server = socket.create_server(("127.0.0.1", 0))
        self.proc = None
        try:
            server.settimeout(WAIT)
            port = server.getsockname()[1]
            self.proc = subprocess.Popen(
                [tool("qemu-system-arm"), "-M", machine, "-display", "none", "-monitor",
                 "none", "-serial", f"tcp:127.0.0.1:{port},nodelay=on",
                 "-serial", f"tcp:127.0.0.1:{plant_port},nodelay=on", "-kernel", str(elf)],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            self.sock, _ = server.accept()
        except BaseException:
            self.close()
            raise
        finally:
            server.close()
        self.sock.settimeout(WAIT)
        self.buf = bytearray()

    def _complain(self, msg: str) -> None:
        self.complaints.append(msg)

    def close(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(timeout=10)
            self.proc.stderr.close()
        if hasattr(self, "sock"):
            self.sock.close()
        self.plant.close()

    def __enter__(self) -> Board:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _until(self, end: bytes) -> bytes:
        while (i := self.buf.find(end)) < 0:
            data = self.sock.recv(65536)
            assert data, "the board closed the link"
            self.buf += data
        out = bytes(self.buf[:i + 1])
        del self.buf[:i + 1]
        return out

    def line(self) -> bytes:
        return self._until(b"\n")

    def frame(self, sample_time: float = 1.0) -> frames.Message:
        return frames.parse_rig_frame(frames.decode_frame(self._until(b"\0")), sample_time)

    def handshake(self) -> None:
        self.sock.sendall(hello())
        assert parse(self.line()).kind == "HELLO"
        self.sock.sendall(FRAMING)
        assert parse(self.line()).kind == "OK"

    def run(self, cfg: dict, abort_after: int | None = None, reason: float = 2.5) -> Record:
        self.sock.sendall(frames.config_frame(cfg))
        msg = self.frame()
        assert msg.kind == "OK", msg
        self.sock.sendall(frames.message_frame("START"))
        samples, events = [], []
        while True:
            msg = self.frame()
            f = msg.fields
            if msg.kind == "SAMPLE":
                samples.append((f["index"], f["state"], f["x"], f["u"]))
                if abort_after is not None and f["index"] == abort_after:
                    self.sock.sendall(frames.abort_frame(reason))
            elif msg.kind == "EVENT":
                events.append((f["index"], f["name"], f["value"]))
            else:
                assert msg.kind == "END", msg
                return Record(samples, events, f["reason"])


def host_run(cfg: dict, model: PlantModel, folder: Path, real: str = "double",
             abort_at: int | None = None, reason: float = 2.5) -> Record:
    """The host build in the firmware's loop: phoid_fw_tick's rules, stepped on ``model``.

    As the firmware: a fresh controller started at sample 0; the host's abort before the
    step of sample ``abort_at``; each sample's state after its step, the last run sample
    `run`; the run ends after the first sample in `done` or `fault`; r = 0.
    """
    ctrl = Controller(cfg, folder, real=real)
    model.run(cfg["sample_time"], cfg["command_gain"])
    ctrl.start()
    samples = []
    for n in range(cfg["hold_samples"] + cfg["run_samples"] + 2):
        x = model.read()
        if n == abort_at:
            ctrl.abort(reason)
        before = ctrl.state
        u = ctrl.step(x, 0.0)
        after = ctrl.state
        shown = "run" if (before, after) == ("run", "done") else after
        samples.append((n, shown, _as(real, x), u))
        if after in ("done", "fault") and shown != "run":
            break
        model.apply(u)
    events = [(ev.index, ev.name, ev.value) for ev in ctrl.events()]
    faults = [name for _, name, _ in events if name.startswith("fault-")]
    return Record(samples, events, "done" if ctrl.state == "done" else faults[-1])


def _as(real: str, x: float) -> float:
    """x as the controller of that real type holds it (what the firmware's SAMPLE carries)."""
    return x if real == "double" else float(np.float32(x))


def model(seed: int = 5) -> PlantModel:
    return PlantModel(PLANT, noise=NOISE, seed=seed)


def bits(rec: Record) -> tuple:
    """The record with every real as its IEEE bits (so -0.0 and 0.0 differ, as they would)."""
    def b(v: float) -> str:
        return struct.pack("<d", v).hex()
    return ([(i, s, b(x), b(u)) for i, s, x, u in rec.samples],
            [(i, n, b(v)) for i, n, v in rec.events], rec.end)


def fw_run(machine: str, elf: Path, cfg: dict, **kw) -> tuple[Record, Board]:
    with Board(machine, elf, model()) as board:
        board.handshake()
        t0 = time.monotonic()
        rec = board.run(cfg, **kw)
        rate = len(rec.samples) / (time.monotonic() - t0)
    print(f"{machine}: {len(rec.samples)} lockstep samples, {rate:.0f} samples/s")
    assert not board.complaints, board.complaints
    # the plant saw what the firmware reported: the positions it sent, the commands back
    steps = board.plant.steps
    assert [s.index for s in steps] == [i for i, *_ in rec.samples]
    assert [s.u for s in steps] == [u for *_, u in rec.samples]
    return rec, board


@pytest.mark.parametrize("machine", list(BOARDS))
def test_double_run_is_bit_identical_to_the_host_build(machine, fw_root, host_build):
    elf = firmware(BOARDS[machine], "double", fw_root)
    rec, board = fw_run(machine, elf, RUN)
    want = host_run(RUN, model(), host_build)
    assert bits(rec) == bits(want)
    assert [s.x for s in board.plant.steps] == [x for _, _, x, _ in rec.samples]
    # the run is the one configured: hold, release after 80, 300 run samples, done
    states = [s for _, s, _, _ in rec.samples]
    assert states == ["hold"] * 80 + ["run"] * 300 + ["done"]
    names = [n for _, n, _ in rec.events]
    assert names == ["start", "clip", "release", "done"]
    assert rec.events[0][0] == 0 and rec.events[2][0] == 80 and rec.events[3][0] == 380
    assert rec.samples[1][3] == RUN["u_max"]  # the first hold command (1 sample late), clipped
    assert rec.end == "done"


def test_growth_fault_is_bit_identical(fw_root, host_build):
    # P -80 N/m against k 64: an unstable loop, stopped when |x| passes 2 x the release
    # amplitude (growth_limit 2)
    cfg = dict(RUN, P=-80.0, D=0.0, growth_limit=2.0, run_samples=400)
    rec, _ = fw_run("mps2-an386", firmware("m4f", "double", fw_root), cfg)
    want = host_run(cfg, model(), host_build)
    assert bits(rec) == bits(want)
    assert rec.end == "fault-growth" and rec.samples[-1][1] == "fault"
    assert rec.samples[-1][3] == 0.0  # the command of the sample that tripped
    assert len(rec.samples) < 80 + 400 + 1


def test_position_fault_is_bit_identical(fw_root, host_build):
    # the same unstable loop without the growth check: it leaves [x_min, x_max]
    cfg = dict(RUN, P=-80.0, D=0.0, x_min=-0.02, x_max=0.02, run_samples=400)
    rec, _ = fw_run("mps2-an385", firmware("m3", "double", fw_root), cfg)
    want = host_run(cfg, model(), host_build)
    assert bits(rec) == bits(want)
    assert rec.end == "fault-position" and abs(rec.samples[-1][2]) > 0.02


def test_abort_from_the_host_is_bit_identical(fw_root, host_build):
    # ABORT sent once sample 150 arrives: it lands at the firmware's next tick, whenever the
    # frame gets there; the host build is aborted before that same sample
    rec, _ = fw_run("mps2-an500", firmware("m7", "double", fw_root), RUN, abort_after=150)
    assert rec.end == "fault-host"
    at = next(i for i, name, _ in rec.events if name == "fault-host")
    assert 150 < at <= rec.samples[-1][0]
    want = host_run(RUN, model(), host_build, abort_at=at)
    assert bits(rec) == bits(want)
    assert rec.events[-1][1:] == ("fault-host", 2.5)


def _l1_gain(cfg: dict, P: float, D: float, n: int) -> float:
    """Σ|h_k| over n samples: the position's response to a unit force held for one sample, in
    the sampled loop of gains P, D (backward difference, delay d): h_k = C A^k B, A the loop's
    map over a period (phoid's exact ZOH of the plant, the controller's law)."""
    T, K, d = cfg["sample_time"], 1.0, cfg["delay_samples"]
    p00, p01, p10, p11, g0, g1, _, reps = model().exact.zoh_map(T)
    assert reps == 1
    # state: x, v, x_{n-1}, then the d commands in flight (oldest first)
    size = 3 + d
    A = np.zeros((size, size))
    law = np.zeros(size)  # u_n = -K(P x + D (x - x_prev)/T)
    law[0], law[2] = -K * (P + D / T), K * D / T
    applied = law if d == 0 else np.eye(size)[3]  # the command applied now
    A[0, :2], A[1, :2] = (p00, p01), (p10, p11)
    A[0] += g0 * applied
    A[1] += g1 * applied
    A[2, 0] = 1.0
    for j in range(3, size - 1):
        A[j, j + 1] = 1.0
    if d:
        A[size - 1] = law
    B = np.zeros(size)
    B[0], B[1] = g0, g1
    total, z = 0.0, B.copy()
    for _ in range(n):
        total += abs(z[0])
        z = A @ z
    return total


def test_float_build_within_its_bound(fw_root, host_build):
    elf = firmware("m4f", "float", fw_root)
    rec, _ = fw_run("mps2-an386", elf, RUN)
    # bit-identical to the host's float build (c_float: the same rounding of x and the fields)
    assert bits(rec) == bits(host_run(RUN, model(), host_build, real="float"))
    dbl = host_run(RUN, model(), host_build)
    assert [s for _, s, _, _ in rec.samples] == [s for _, s, _, _ in dbl.samples]
    dx = max(abs(a[2] - b[2]) for a, b in zip(rec.samples, dbl.samples, strict=True))
    # The bound. The float step differs from the double one by rounding only: x, the gains
    # and 1/T rounded to float, and each of the law's operations (c0·x, c0·x₁, their
    # difference, P·x, D·v̂, the difference, K·(…)): at most 8 roundings of 2⁻²⁴ relative,
    # each on a term no larger than |K|(|P| + 2|D|/T)·X, X = max|x| — the command error
    # per sample e ≤ 8·2⁻²⁴·|K|(|P| + 2|D|/T)·X. A command error e held for one sample moves
    # the position by G·e·h_k k samples later, so over the record
    # |Δx| ≤ G·max(e)·max(Σ|h_k|) of the two loops (hold and run), plus the positions' own
    # rounding to float in the record (2⁻²⁴·X).
    X = max(abs(x) for _, _, x, _ in dbl.samples)
    n = len(dbl.samples)
    eps = 2.0**-24
    worst = 0.0
    for P, D in ((RUN["hold_P"], RUN["hold_D"]), (RUN["P"], RUN["D"])):
        e = 8 * eps * (abs(P) + 2 * abs(D) / RUN["sample_time"]) * X
        worst = max(worst, RUN["command_gain"] * e * _l1_gain(RUN, P, D, n))
    bound = worst + eps * X
    print(f"float vs double: max |dx| {dx:.3g} m ({dx / X:.3g} of max|x|), bound {bound:.3g} m")
    assert dx <= bound
    assert dx > 0  # the float build does round: a bound that could not fail would be no test


def test_the_link_refuses_what_it_cannot_use(fw_root):
    elf = firmware("m3", "double", fw_root)
    with Board("mps2-an385", elf, model()) as board:
        # a text line that is not the hello, before it
        board.sock.sendall(b"CONFIG P=1 *00000000\n")
        assert b"send the hello PHOID-RIG 1 first" in board.line()
        board.sock.sendall(hello())
        assert parse(board.line()).kind == "HELLO"
        # a text CONFIG after the hello: this rig speaks binary only (a constant line)
        board.sock.sendall(b"CONFIG P=1 *2c2a1a9a\n")
        err = parse(board.line())
        assert err.kind == "ERROR" and "FRAMING cobs" in err.fields["message"]
        board.sock.sendall(FRAMING)
        assert parse(board.line()).kind == "OK"
        board.sock.sendall(frames.message_frame("START"))
        msg = board.frame()
        assert msg.kind == "ERROR" and "START without an accepted CONFIG" in msg.fields["message"]
        # a damaged frame: one byte changed
        bad = bytearray(frames.config_frame(RUN))
        bad[20] ^= 0x01 if bad[20] not in (0x01,) else 0x02
        board.sock.sendall(bytes(bad))
        assert "CRC" in board.frame().fields["message"]
        # fields the controller refuses, named; a count beyond PHOID_MAX_COUNT
        board.sock.sendall(frames.config_frame(dict(RUN, u_max=-1.0)))
        assert "`u_max`" in board.frame().fields["message"]
        board.sock.sendall(frames.config_frame(dict(RUN, run_samples=2**31)))
        assert "run_samples" in board.frame().fields["message"]
        board.sock.sendall(frames.config_frame(dict(RUN, hold_samples=0)))
        assert "hold_samples 0" in board.frame().fields["message"]
        # a host that connects again says hello in text: the rig starts over. In binary
        # mode the hello is the bytes since the last 0x00 or LF (here: the end of noise)
        board.sock.sendall(b"\x05garbage\n" + hello())
        assert parse(board.line()).kind == "HELLO"
        board.sock.sendall(FRAMING)
        assert parse(board.line()).kind == "OK"
        board.sock.sendall(frames.abort_frame(1.0))  # no run: nothing to abort
        assert board.frame().kind == "OK"
        # a short run still works after all that
        rec = board.run(dict(RUN, hold_samples=5, run_samples=10))
        assert rec.end == "done" and len(rec.samples) == 16
        assert not math.isnan(rec.samples[-1][2])


@pytest.mark.parametrize(("target", "real"), [("m4f", "float"), ("m3", "double")])
def test_the_board_template_builds(target, real, tmp_path, tools):
    # the real-board template (SysTick, the user's functions left empty) builds with the
    # same strict flags and links with nothing but libgcc and fw_libc.c
    out = tmp_path / "template"
    proc = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), f"TARGET={target}",
                           f"REAL={real}", "BOARD=template", f"OUT={out}"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "phoid_fw.elf").stat().st_size > 0
    assert sorted(p.name for p in FIRMWARE_DIR.iterdir() if p.suffix == ".o") == []


_STUB_BOARD = """
#include "board.h"
int board_link_getc(void) { return -1; }
void board_link_putc(unsigned char byte) { (void)byte; }
const char *board_configure(const phoid_config *cfg, const unsigned char t[8],
                            const unsigned char g[8]) { (void)cfg; (void)t; (void)g; return 0; }
void board_run_start(void) {}
"""


def test_f8_to_f4_by_the_bits_rounds_as_numpy(tmp_path):
    # where a double has 32 bits (AVR), the link converts the host's f8 fields by their bits:
    # built here on the host, it must give what numpy's (the FPU's) binary64 → binary32
    # conversion gives — round to nearest even, ±inf beyond the range, subnormals, signed
    # zeros, NaN — and the way back must be exact
    import ctypes

    cc = find_compiler()
    if cc is None:
        pytest.skip("no C compiler (CC, cc, gcc, clang)")
    (tmp_path / "board_stub.c").write_text(_STUB_BOARD)
    lib = tmp_path / "fwconv.so"
    ctrl = FIRMWARE_DIR.parent
    proc = subprocess.run([*cc, "-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra",
                           "-Werror", "-pedantic", "-Wfloat-equal", "-ffp-contract=off",
                           f"-I{ctrl}", f"-I{FIRMWARE_DIR}", "-o", str(lib),
                           str(FIRMWARE_DIR / "phoid_fw.c"), str(ctrl / "phoid_ctrl.c"),
                           str(tmp_path / "board_stub.c")],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    fw = ctypes.CDLL(str(lib))
    rng = np.random.default_rng(29)
    # random bit patterns over every exponent, and the edges: float's largest, the rounding
    # ties at its top, its smallest normal and subnormal and half of it, zeros, inf, NaN
    f32 = np.finfo(np.float32)
    edges = [0.0, -0.0, math.inf, -math.inf, float(f32.max), -float(f32.max),
             float(f32.max) * (1 + 2**-25), float(f32.max) * (1 + 2**-24),
             float(f32.tiny), float(f32.smallest_subnormal), float(f32.smallest_subnormal) / 2,
             float(f32.smallest_subnormal) * 0.75, float(f32.smallest_subnormal) * 1.5,
             1.0 + 2**-24, 1.0 + 3 * 2**-24, 1e-300, 5e-324, 1e300]
    inside = rng.standard_normal(5000) * 10.0 ** rng.uniform(-46, 39, 5000)  # float's range
    values = np.concatenate([rng.integers(0, 2**64, 20000, dtype=np.uint64).view(np.float64),
                             inside, np.array(edges)])
    out = ctypes.create_string_buffer(4)
    back = ctypes.create_string_buffer(8)
    for v in values:
        fw.phoid_fw_f8_to_f4(struct.pack("<d", v), out)
        with np.errstate(over="ignore", invalid="ignore"):  # inf and NaN: as they are
            want = np.float64(v).astype(np.float32)
        got = np.frombuffer(out.raw, dtype="<f4")[0]
        if np.isnan(want):
            assert np.isnan(got), v
            continue
        assert got.tobytes() == want.tobytes(), (v, got, want)
        fw.phoid_fw_f4_to_f8(out.raw, back)
        assert back.raw == struct.pack("<d", float(want)), (v, back.raw)


def test_the_arduino_sketch_builds(tmp_path):
    # firmware/arduino/phoid_rig: the sketch (C++, as the Arduino IDE compiles an .ino) with
    # the link and the controller (C99, strict flags; a double of 32 bits) for the Mega 2560,
    # linked with a main() that calls setup() and loop() as the Arduino core does
    tool("avr-gcc")
    if shutil.which("avr-g++") is None:
        pytest.skip("avr-g++ not found on PATH: install Debian's gcc-avr")
    ctrl, sketch = FIRMWARE_DIR.parent, FIRMWARE_DIR / "arduino" / "phoid_rig" / "phoid_rig.ino"
    mcu, inc = "-mmcu=atmega2560", [f"-I{FIRMWARE_DIR.parent}", f"-I{FIRMWARE_DIR}"]
    strict = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wfloat-equal",
              "-ffp-contract=off"]
    (tmp_path / "main.cpp").write_text("void setup(void);\nvoid loop(void);\n"
                                       "int main(void) { setup(); for (;;) loop(); }\n")
    steps = [
        ["avr-gcc", mcu, *strict, *inc, "-c", str(ctrl / "phoid_ctrl.c"), "-o", "ctrl.o"],
        ["avr-gcc", mcu, *strict, *inc, "-c", str(FIRMWARE_DIR / "phoid_fw.c"), "-o", "fw.o"],
        ["avr-g++", mcu, "-O2", "-Wall", "-Wextra", "-Werror", *inc, "-x", "c++", "-c",
         str(sketch), "-o", "sketch.o"],
        ["avr-g++", mcu, "-O2", "-c", "main.cpp", "-o", "main.o"],
        ["avr-gcc", mcu, "-o", "sketch.elf", "sketch.o", "main.o", "fw.o", "ctrl.o"],
    ]
    for cmd in steps:
        proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120,
                              check=False)
        assert proc.returncode == 0, (cmd, proc.stderr[-2000:])
    assert (tmp_path / "sketch.elf").stat().st_size > 0


def test_a_frame_refused_during_a_run_leaves_no_configuration(fw_root):
    # docs/rig-protocol.md: during a run the rig takes ABORT only; a line (frame) it refuses
    # may have been a CONFIG, so none survives it: the next START is refused
    elf = firmware("m4f", "float", fw_root)
    with Board("mps2-an386", elf, model()) as board:
        board.handshake()
        board.sock.sendall(frames.config_frame(dict(RUN, hold_samples=20, run_samples=40)))
        assert board.frame().kind == "OK"
        board.sock.sendall(frames.message_frame("START") + frames.config_frame(RUN))
        kinds, errors = [], []
        while True:
            msg = board.frame()
            kinds.append(msg.kind)
            if msg.kind == "ERROR":
                errors.append(msg.fields["message"])
            if msg.kind == "END":
                break
        assert errors == ["only ABORT is taken during a run: abort it first"]
        assert kinds.count("SAMPLE") == 61 and msg.fields["reason"] == "done"
        board.sock.sendall(frames.message_frame("START"))
        msg = board.frame()
        assert msg.kind == "ERROR" and "without an accepted CONFIG" in msg.fields["message"]
        # a float rig cannot hold a gain beyond float's range (3.4e38): refused, named
        board.sock.sendall(frames.config_frame(dict(RUN, P=1e39)))
        msg = board.frame()
        assert msg.kind == "ERROR" and "`P` is beyond this build's 32-bit real" in \
            msg.fields["message"]
        # nor a force sensor (this firmware reads none), nor a sample time under 1 ns
        board.sock.sendall(frames.config_frame(dict(RUN, has_force=1)))
        assert "has_force 1" in board.frame().fields["message"]
        board.sock.sendall(frames.config_frame(dict(RUN, sample_time=1e-10)))
        assert "`sample_time`" in board.frame().fields["message"]


def test_a_hello_after_noise_on_its_line_is_taken_in_text_mode(fw_root):
    # a host that comes after line noise or a cut-off line: the line that ends with the
    # hello (its bytes exactly, a CR before the LF allowed) is the hello, whatever came before
    # it on the line, even more than the rig's line buffer holds; other lines are still refused
    elf = firmware("m3", "double", fw_root)
    with Board("mps2-an385", elf, model()) as board:
        board.sock.sendall(b"\x7f\x03" + hello())
        assert parse(board.line()).kind == "HELLO"
        # waiting for FRAMING: noise and the hello again start over
        board.sock.sendall(b"FRAMING cob" + hello().replace(b"\n", b"\r\n"))
        assert parse(board.line()).kind == "HELLO"
        board.sock.sendall(b"x" * 1000 + hello())
        assert parse(board.line()).kind == "HELLO"
        board.sock.sendall(b"junk PHOID-RIG 1 *b79b4dcX\n")  # not the hello's bytes
        assert b"send FRAMING cobs" in board.line()
        board.handshake()
        rec = board.run(dict(RUN, hold_samples=5, run_samples=10))
        assert rec.end == "done" and len(rec.samples) == 16


def _spelling_config() -> bytes:
    """A CONFIG frame whose bytes spell the hello line inside it: P, D and gain's 24 bytes
    are the hello's 22 and two more (their reals finite, which the double build takes)."""
    raw = hello() + b"\x01\x3f"
    cfg = dict(RUN, P=struct.unpack("<d", raw[0:8])[0], D=struct.unpack("<d", raw[8:16])[0],
               gain=struct.unpack("<d", raw[16:24])[0])
    wire = frames.config_frame(cfg)
    assert hello() in wire and all(map(math.isfinite, (cfg["P"], cfg["D"], cfg["gain"])))
    return wire


def test_a_frame_that_spells_the_hello_does_not_reset_the_session(fw_root):
    # binary mode: the hello is taken only as the whole bytes since the last 0x00 or LF; a
    # CONFIG whose reals spell it is a CONFIG (answered OK), not a new session
    elf = firmware("m3", "double", fw_root)
    with Board("mps2-an385", elf, model()) as board:
        board.handshake()
        board.sock.sendall(_spelling_config())
        assert board.frame().kind == "OK"
        board.sock.sendall(frames.message_frame("START"))
        assert board.frame().kind in ("SAMPLE", "EVENT")  # configured: it runs
        board.sock.sendall(frames.abort_frame(1.0))
        while board.frame().kind != "END":
            pass
        # a hello after noise with no 0x00 or LF before it is part of that noise's frame
        board.sock.settimeout(1.0)
        board.sock.sendall(b"\x05garbage" + hello())
        with pytest.raises(TimeoutError):
            board.line()
        board.sock.settimeout(WAIT)
        board.sock.sendall(hello())  # after the first one's LF: taken
        assert parse(board.line()).kind == "HELLO"


def test_a_float_rig_checks_the_config_as_the_double_build(fw_root):
    # the float build checks CONFIG's reals as the double build does before it rounds them
    # (values within a float's rounding of a bound are refused as the double build refuses
    # them), and refuses a real the float cannot carry, naming the field; "no limit" (1e300)
    # is still no limit
    elf = firmware("m4f", "float", fw_root)
    refused = [
        ({"growth_limit": 0.99999999}, "`growth_limit`"),  # 1.0f after rounding
        ({"x_start": math.nextafter(RUN["x_max"], 1.0)}, "`x_start`"),
        ({"sample_time": 0.999999999e-9}, "`sample_time`"),  # rounds to 1e-9f
        ({"velocity": 2, "filter_pole": -1e-50}, "`filter_pole`"),  # -0.0f after rounding
        ({"P": 1e-50}, "`P` is not 0 but rounds to 0"),
        ({"stall_epsilon": 1e39}, "`stall_epsilon` is beyond"),
        ({"hold_D": -1e39}, "`hold_D` is beyond"),
    ]
    with Board("mps2-an386", elf, model()) as board:
        board.handshake()
        for change, why in refused:
            board.sock.sendall(frames.config_frame(dict(RUN, **change)))
            msg = board.frame()
            assert msg.kind == "ERROR" and why in msg.fields["message"], (change, msg)
        board.sock.sendall(frames.config_frame(dict(RUN, x_min=-1e300, x_max=1e300,
                                                    u_max=1e300, growth_limit=1.0)))
        assert board.frame().kind == "OK"
