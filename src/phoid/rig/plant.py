r"""The virtual plant: phoid's exact plant for a firmware in the loop, over TCP (lockstep).

A microcontroller running phoid's firmware (``src/phoid/rig/c/firmware``, its board
``board_mps2_hil.c`` in QEMU) reads its position from this plant and sends back the command
it applies, one sample at a time, over a second serial line (QEMU's
``-serial tcp:HOST:PORT``). The frames are the rig link's binary frames
(:mod:`phoid.rig.frames`: COBS of payload ‖ CRC-32, then 0x00):

* plant → MCU ``P``: flags u1 (0), x f8 — the position read at this sample, m;
* MCU → plant ``R``: sample_time f8, command_gain f8 — a run starts: its period T (s) and the
  amplifier's gain G (N per command unit);
* MCU → plant ``U``: index u4, u f8 — the command applied from this sample on.

Lockstep: the plant sends its first ``P`` when the MCU connects; for each ``U`` it moves the
plant

    m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = G·u   over one period T, exactly

(:class:`phoid.simulation.tracking.ExactPlant`, the zero-order hold that ``phoid
virtual-rig`` and ``phoid simulate`` use) and sends the next ``P``. The position read is
x̃ = Q(x + ε) (ε white Gaussian of standard deviation ``noise``, Q the encoder's rounding to a
multiple of ``quantum``), as in :class:`phoid.rig.virtual.VirtualRig`. Outside a run the MCU
leaves the last ``P`` unanswered, so the plant's time stands still between runs. The plant
starts at rest at x = 0 and keeps its state from run to run (the hold brings it back).

The plant trusts nothing it reads: a frame it cannot use (bad COBS or CRC, an unknown type, a
``U`` before any ``R``, a period outside 1 ns to 1 s (the virtual rig's range) or a gain that
is not a finite number > 0, a period over which the plant's motion cannot be simulated) is
named in one short line on stderr and left unanswered; the MCU then waits, and the host's
``phoid run`` times out on the run. One MCU at a time: a second one is told it is busy in one
text line and closed, unless the one served has been silent for the idle timeout.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from phoid.rig.frames import decode_frame, encode_frame
from phoid.rig.protocol import ProtocolError
from phoid.rig.virtual import encoder_reading
from phoid.simulation.tracking import ExactPlant

__all__ = ["PlantModel", "Step", "VirtualPlant", "position_frame"]

MAX_QUANTUM_LOW, MAX_QUANTUM_HIGH = 1e-30, 1e30  # m: --quantum other than 0
FASTEST, SLOWEST = 1e-9, 1.0  # s: the controller's shortest sample time; the virtual rig's longest
IDLE_TIMEOUT = 30.0  # s: an MCU silent this long gives the plant up to another that connects
MAX_FRAME_BYTES = 300  # bytes before a 0x00: more is not a frame of this link
_P = struct.Struct("<BBd")
_U = struct.Struct("<BId")
_R = struct.Struct("<Bdd")


def _short(exc: BaseException, chars: int = 200) -> str:
    """An exception's message in at most ``chars`` characters (a log line stays a line)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= chars else text[:chars] + "..."


def position_frame(x: float) -> bytes:
    """The ``P`` frame of a position read (m)."""
    return encode_frame(_P.pack(ord("P"), 0, float(x)))


@dataclass
class Step:
    """One lockstep sample as the plant saw it: the MCU's index, the position read, the
    command the MCU applied."""

    index: int
    x: float
    u: float


class PlantModel:
    """The plant and its encoder, moved sample by sample (what the server and a test share).

    Parameters
    ----------
    plant : phoid.Plant
        m (kg), c (N·s/m), k (N/m), f_c (N).
    offset_force : float, default 0
        Constant offset force f₀, N.
    noise : float, default 0
        Standard deviation of the position sensor's white noise, m (finite, ≥ 0).
    quantum : float, default 0
        The encoder's count, m: the position read is rounded to a multiple of it (0: none;
        else 1e-30 to 1e30).
    seed : int, optional
        Seed of the noise.

    Raises
    ------
    ValueError
        For a parameter out of its range (named), or a plant ExactPlant refuses.
    """

    def __init__(self, plant, *, offset_force: float = 0.0, noise: float = 0.0,
                 quantum: float = 0.0, seed: int | None = None) -> None:
        if isinstance(noise, bool) or not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a finite number ≥ 0 m; got {noise!r}")
        if isinstance(quantum, bool) or not (
                quantum == 0 or MAX_QUANTUM_LOW <= quantum <= MAX_QUANTUM_HIGH):
            raise ValueError(f"quantum must be 0 (no rounding) or a number from "
                             f"{MAX_QUANTUM_LOW:g} to {MAX_QUANTUM_HIGH:g} m; got {quantum!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)
                                 or not 0 <= seed < 2**128):
            raise ValueError(f"seed must be a whole number from 0 to 2^128 - 1; got {seed!r}")
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            try:
                self.exact = ExactPlant(plant, offset=float(offset_force))
            except ArithmeticError as exc:
                raise ValueError(f"`m`, `c`, `k`: the plant's parameters overflow a double "
                                 f"({type(exc).__name__})") from None
        for T in (FASTEST, SLOWEST):  # a plant no run could move is refused now, not per run
            why = self._overflow(T)
            if why:
                m, c, k = (float(getattr(plant, name)) for name in ("m", "c", "k"))
                raise ValueError(f"`m` {m:g} kg, `c` {c:g} N s/m, `k` {k:g} N/m: the plant "
                                 f"cannot be simulated: {why}")
        self.noise, self.quantum = float(noise), float(quantum)
        self.rng = np.random.default_rng(seed)
        self.sample_time: float | None = None
        self.command_gain = 1.0

    def _overflow(self, T: float) -> str:
        """Why the motion over a period T overflows a double ("" when it does not; a plant
        too fast for T is not an overflow: :meth:`run` refuses that period alone)."""
        try:
            with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
                mp = self.exact.zoh_map(T)
        except ValueError:
            return ""
        except ArithmeticError as exc:
            return f"its motion over {T:g} s overflows a double ({type(exc).__name__})"
        if not all(math.isfinite(v) for v in mp[:6]):
            return f"its motion over {T:g} s overflows a double"
        return ""

    def run(self, sample_time: float, command_gain: float) -> None:
        """A run starts: its period T (s) and gain G (N per command unit).

        Raises
        ------
        ValueError
            T or G not a finite number > 0, or a period over which the motion cannot be
            simulated (it overflows, or the plant rings too fast for it).
        """
        if not FASTEST <= sample_time <= SLOWEST:  # NaN too
            raise ValueError(f"sample_time must be from {FASTEST:g} to {SLOWEST:g} s; got "
                             f"{sample_time:.6g}")
        if not (math.isfinite(command_gain) and command_gain > 0):
            raise ValueError(f"command_gain must be a finite number > 0; got {command_gain:.6g}")
        try:
            with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
                mp = self.exact.zoh_map(sample_time)
        except (ArithmeticError, ValueError) as exc:
            raise ValueError(f"sample_time {sample_time:g} s: the plant's motion over one "
                             f"sample cannot be simulated ({_short(exc)})") from None
        if not all(math.isfinite(v) for v in mp[:6]):
            raise ValueError(f"sample_time {sample_time:g} s: the plant's motion over one "
                             "sample overflows a double")
        self.sample_time, self.command_gain = float(sample_time), float(command_gain)

    def read(self) -> float:
        """The encoder's reading of the position now: x + ε, rounded to the quantum."""
        return encoder_reading(self.exact.x, self.noise, self.quantum, self.rng)

    def apply(self, u: float) -> None:
        """Hold the command u (command units) for one period: the force G·u, exactly.

        A motion that overflows leaves the position NaN (the MCU's controller reads it as a
        sensor failure and faults: ``fault-input``).
        """
        if self.sample_time is None:
            raise ValueError("a command before the run's period (an R frame) was given")
        try:
            with np.errstate(all="ignore"):
                self.exact.advance(self.command_gain * float(u), self.sample_time)
        except (ArithmeticError, ValueError):
            self.exact.x = math.nan


@dataclass
class _Conn:
    sock: socket.socket
    buf: bytearray = field(default_factory=bytearray)


class VirtualPlant:
    """Serve a :class:`PlantModel` to one MCU at a time over TCP, in a background thread.

    Parameters
    ----------
    model : PlantModel
        The plant and its encoder.
    record : bool, default False
        Keep every sample (:attr:`steps`: the position sent, the command received), for tests.
    log : callable, optional
        Where one-line complaints go (default: stderr).
    idle_timeout : float, default 30
        Seconds: an MCU that has sent nothing for this long gives the plant up to another
        that connects (it is dropped, named on the log). Otherwise a second MCU is told in
        one text line that the plant is busy and closed; an MCU alone keeps the plant however
        long it is silent (between runs it sends nothing).
    """

    def __init__(self, model: PlantModel, *, record: bool = False, log=None,
                 idle_timeout: float = IDLE_TIMEOUT) -> None:
        if not (math.isfinite(idle_timeout) and idle_timeout > 0):
            raise ValueError(f"idle_timeout must be a finite number > 0 s; got {idle_timeout!r}")
        self.idle_timeout = float(idle_timeout)
        self._next: socket.socket | None = None  # one that took a silent MCU's place
        self.model = model
        self.record = record
        self.steps: list[Step] = []
        self.runs = 0
        self._log = log or (lambda msg: sys.stderr.write(f"phoid virtual-plant: {msg}\n"))
        self._server: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self._conn: socket.socket | None = None
        self._lock = threading.Lock()

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start serving on host:port (0: a free port); the address served."""
        try:
            srv = socket.create_server((host, port))
        except OSError as exc:
            raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        srv.settimeout(0.2)
        self._server = srv
        self._thread = threading.Thread(target=self._serve, daemon=True,
                                        name="phoid-virtual-plant")
        self._thread.start()
        addr = srv.getsockname()
        return str(addr[0]), int(addr[1])

    def close(self) -> None:
        """Stop serving and close the connection."""
        self._closing.set()
        with self._lock:
            if self._conn is not None:
                with contextlib.suppress(OSError):
                    self._conn.shutdown(socket.SHUT_RDWR)
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._next is not None:
            self._next.close()
            self._next = None
        if self._server is not None:
            self._server.close()
            self._server = None

    def __enter__(self) -> VirtualPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _serve(self) -> None:
        assert self._server is not None
        while not self._closing.is_set():
            sock, self._next = self._next, None
            try:
                if sock is None:
                    sock, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                self._conn = sock
            try:
                self._session(sock)
            except (ConnectionResetError, BrokenPipeError):
                pass  # the MCU went away (QEMU stopped): wait for the next one
            except OSError as exc:
                if not self._closing.is_set():
                    self._log(f"the MCU's connection failed: {exc}")
            finally:
                with self._lock:
                    self._conn = None
                sock.close()

    def _session(self, sock: socket.socket) -> None:
        sock.settimeout(0.2)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sent = self.model.read()
        sock.sendall(position_frame(sent))
        buf = bytearray()
        heard = time.monotonic()
        while not self._closing.is_set():
            if self._knocked(heard):
                return
            try:
                data = sock.recv(4096)
            except TimeoutError:
                continue
            if not data:
                return
            heard = time.monotonic()
            buf += data
            while True:
                end = buf.find(b"\0")
                if end < 0:
                    if len(buf) > MAX_FRAME_BYTES:
                        self._log(f"{len(buf)} bytes without a frame's 0x00: dropped")
                        buf.clear()
                    break
                raw = bytes(buf[:end + 1])  # the frame with its 0x00
                del buf[:end + 1]
                if len(raw) == 1:
                    continue  # an empty frame: a lone delimiter
                reply = self._frame(raw, sent)
                if reply is not None:
                    sent = reply
                    sock.sendall(position_frame(sent))

    def _knocked(self, heard: float) -> bool:
        """Another MCU connecting while one is served: it takes the plant when the one served
        has sent nothing for ``idle_timeout`` s (True: end that session), else it is told
        the plant is busy, in one line, and closed."""
        if self._server is None:
            return False
        try:
            ready, _, _ = select.select([self._server], [], [], 0)
            if not ready:
                return False
            other, _ = self._server.accept()
        except (OSError, ValueError):
            return False
        silent = time.monotonic() - heard
        if silent >= self.idle_timeout:
            self._log(f"the MCU sent nothing for {silent:.0f} s and another connected: the "
                      "plant is the new one's")
            self._next = other
            return True
        with contextlib.suppress(OSError):
            other.settimeout(1.0)
            other.sendall(b"phoid virtual-plant: busy: it serves another MCU (one at a time)\n")
        other.close()
        self._log("a second MCU connected while one is served: told busy, closed")
        return False

    def _frame(self, raw: bytes, sent: float) -> float | None:
        """Handle one MCU frame; the next position read when one is to be sent."""
        try:
            payload = decode_frame(raw)
        except ProtocolError as exc:
            self._log(f"a frame from the MCU refused: {exc}")
            return None
        kind = payload[:1]
        if kind == b"R" and len(payload) == _R.size:
            _, T, G = _R.unpack(payload)
            try:
                self.model.run(T, G)
            except ValueError as exc:
                self._log(f"a run refused: {exc}")
                self.model.sample_time = None
            else:
                self.runs += 1
            return None
        if kind == b"U" and len(payload) == _U.size:
            _, index, u = _U.unpack(payload)
            if self.model.sample_time is None:
                self._log("a command (U) without a run's period (R) first: not answered")
                return None
            if not math.isfinite(u):
                self._log(f"a command that is not finite ({u!r}) at sample {index}: "
                          "not answered")
                return None
            if self.record:
                self.steps.append(Step(int(index), sent, float(u)))
            self.model.apply(u)
            return self.model.read()
        self._log(f"an unknown frame from the MCU (type {payload[:1]!a}, {len(payload)} "
                  "bytes): not answered")
        return None
