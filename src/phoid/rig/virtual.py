r"""The virtual rig: the compiled C controller stepping against phoid's exact plant, over TCP.

A :class:`VirtualRig` serves the ``PHOID-RIG 1`` protocol (docs/rig-protocol.md) on a TCP port,
one connection at a time, in background threads. For each ``START`` it initialises the C
controller (:class:`phoid.rig.native.Controller`, built into the rig's build folder) with the
last ``CONFIG`` and steps it sample by sample against
:class:`phoid.simulation.tracking.ExactPlant`, the plant

    m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = G·uₙ   on [nT, (n + 1)T)

starting at rest at x = 0: per sample n the measured position x̃ₙ = Q(x(nT) + εₙ) (εₙ white
Gaussian, standard deviation ``noise``; Q the encoder's rounding to a multiple of ``quantum``,
none when 0) goes into ``phoid_step`` (or, with ``noise_in_loop=False``, the exact x(nT) does
and only the streamed x̃ₙ is noisy and quantised), whose returned command uₙ (the controller's
own delay ring has already delayed it: u_{n−d} of its law) is held for one period. Each step is
streamed as ``SAMPLE n nT x̃ₙ uₙ state`` — x̃ₙ exactly the number the controller read (in the
loop), uₙ the command applied over [nT, (n + 1)T); with ``force_noise`` set, the rig also reports a
measured force f̃ₙ = G·uₙ + ηₙ (N: the force applied to the plant over [nT, (n + 1)T), ηₙ white
Gaussian of standard deviation ``force_noise``) as the line's ``force`` field, and steps the
controller with the force measured at the previous sample (what a load cell reads at nT; 0 at
the first sample) through ``phoid_step_force``. At the end come the controller's events and
``END``. It runs as fast as it can, or paced to the wall clock with ``realtime``. A host that
sends ``FRAMING cobs`` after the hello is answered ``OK`` and served binary frames from then on
(:mod:`phoid.rig.frames`: the same messages, the values f8, so the records are the text
session's, byte for byte).

The rig trusts nothing the host sends. Every ``CONFIG`` is checked against what the C
controller holds (``phoid_init``'s checks and the C types' ranges) and what this rig can run
(the sample time within ``max_rate`` and 1 s, a hold that ends, at most ``max_samples``
samples, a finite largest force, a plant motion over one sample that does not overflow); a
refusal is ``ERROR`` naming the field, and every line the rig refuses (a damaged line may have
been a CONFIG) leaves no configuration: START is refused until a CONFIG is accepted. Every
failure of a session becomes an ``ERROR`` line to the host, never a traceback: a line it cannot
use is answered and the session goes on; a host silent for ``idle_timeout`` s, a session older than
``max_session`` s or a failure of the rig ends the session with a last ``ERROR``. One host is
served at a time; another gets ``ERROR busy: …`` at once and is closed. A line longer than the
protocol allows is refused once and skipped as it arrives, never buffered whole.

Fault injection (for tests, Python only): ``faults`` maps ``"drop"``, ``"corrupt"`` or
``"gap"`` to ``(run, index)`` — the connection is closed before sample ``index`` of the
``run``-th START, that sample's line has a byte changed, or it is not sent.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import select
import shutil
import socket
import socketserver
import sys
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from phoid.rig.frames import (
    MAX_FRAME,
    NO_LIMIT,
    decode_frame,
    end_frame,
    error_frame,
    event_frame,
    message_frame,
    parse_host_frame,
    sample_frame,
)
from phoid.rig.link import Link, LinkClosed
from phoid.rig.native import Controller, build_library
from phoid.rig.protocol import (
    MAX_LINE,
    Message,
    ProtocolError,
    check_hello,
    encode,
    hello,
    parse,
)
from phoid.simulation.tracking import MAX_SUBSTEPS, ExactPlant

__all__ = ["VirtualRig", "encoder_reading"]

IDLE_TIMEOUT = 30.0  # s without a line from the host before the rig ends the session
HELLO_TIMEOUT = 10.0  # s for the host's hello (at most the idle timeout)
MAX_SESSION = 3600.0  # s a session may hold the rig
MAX_SAMPLES = 2_000_000  # samples of one run (hold, run and the sample after it)
MAX_SAMPLE_TIME = 1.0  # s: the slowest sample rate the rig runs (1 Hz)
MAX_RATE = 1e9  # Hz: the fastest --max-rate (the controller's shortest sample time is 1 ns)
MAX_WAIT = 86400.0  # s: the longest --idle-timeout and --max-session (a day)
MAX_FORCE_NOISE = 1e300  # N: the largest --force-noise (G·u + η stays a finite double)
MIN_QUANTUM, MAX_QUANTUM = 1e-30, 1e30  # m: --quantum other than 0 (x/quantum stays finite)
BUSY_GRACE = 1.0  # s a new connection waits for the last session to finish closing
LINGER = 1.0  # s the rig reads what the host still sends after its last ERROR, then closes
SEND_TIMEOUT = 5.0  # s, at least: a host that reads nothing for this long is dropped
FLUSH = 512  # samples per send when not in real time
MAX_REFUSING = 16  # busy answers closed gracefully at once; more are answered and cut off
BUSY = "busy: another host is connected to this rig; try again when it is done"



def encoder_reading(x: float, noise: float, quantum: float, rng: np.random.Generator) -> float:
    """What a rig's encoder reads of the position ``x`` (m): x + ε, rounded to the quantum.

    Parameters
    ----------
    x : float
        The exact position, m.
    noise : float
        The standard deviation of ε, m (0: none; one draw from ``rng`` otherwise).
    quantum : float
        The encoder's count, m (0: none): the reading is rounded to the nearest multiple of
        it, ties to even, as ``phoid simulate`` rounds (a reading too large to count is left
        unrounded).
    rng : numpy.random.Generator
        The noise's generator.

    Returns
    -------
    float
        The reading, m. The virtual rig and the virtual plant (phoid.rig.plant) read alike.
    """
    if noise:
        x += noise * float(rng.standard_normal())
    if quantum:
        counts = x / quantum
        if math.isfinite(counts):
            x = quantum * round(counts)
    return x

class _SessionOver(Exception):
    """The rig ends the session; the message goes to the host as its last ``ERROR``."""


class _Lines:
    """The host's lines, read within the session's bounds.

    A line longer than the protocol's ``MAX_LINE`` is refused once (:class:`ProtocolError`):
    :meth:`Link.readline` hands it out in pieces of ``MAX_LINE + 1`` bytes without an LF
    (never buffering it whole) and drops its end; the pieces after the first are skipped.
    :meth:`check` ends the session when the rig closes or the session has held the rig for
    ``max_session`` s (checked between pieces too: an endless line cannot hold the rig).
    """

    def __init__(self, link: Link, closing: threading.Event, max_session: float) -> None:
        self.link, self.closing, self.max_session = link, closing, max_session
        self.deadline = time.monotonic() + max_session
        self.skipping = False
        self.binary = False  # binary frames (after FRAMING cobs), both ways

    def parse(self, raw: bytes) -> Message:
        """A host's line or frame, checked and parsed."""
        return parse_host_frame(decode_frame(raw)) if self.binary else parse(raw)

    def ok(self) -> bytes:
        return message_frame("OK") if self.binary else encode("OK")

    def error(self, message: str) -> bytes:
        return error_frame(message) if self.binary else encode("ERROR", message)

    def check(self) -> None:
        if self.closing.is_set():
            raise _SessionOver("the rig is shutting down: closing the session")
        if time.monotonic() > self.deadline:
            raise _SessionOver(f"this session has held the rig for {self.max_session:g} s, "
                               "its limit (the rig's --max-session): closing it")

    def read(self, timeout: float) -> bytes | None:
        """The next line (with its LF), or frame, within ``timeout`` s (0: poll); None when
        none came."""
        end = time.monotonic() + timeout
        if self.binary:
            read, limit, delim, what = self.link.read_frame, MAX_FRAME, b"\0", "frame"
        else:
            read, limit, delim, what = self.link.readline, MAX_LINE, b"\n", "line"
        while True:
            self.check()
            left = end - time.monotonic()
            line = read(min(left, 0.5) if timeout > 0 and left > 0 else 0)
            if line is None:
                if timeout <= 0 or time.monotonic() >= end:
                    return None
                continue
            if len(line) > limit and not line.endswith(delim):  # a piece of a long line
                if self.skipping:
                    continue
                self.skipping = True
                raise ProtocolError(f"a {what} longer than {limit} bytes (refused; the rig "
                                    "skips it to its end): "
                                    f"{line[:40].decode('latin-1')!a}...")
            self.skipping = False
            return line


def _zoh_map(plant: ExactPlant, T: float) -> tuple[str, bool]:
    """Why the plant's motion over a sample of T s cannot be simulated ("" when it can), and
    whether that is an overflow (else: the plant is too fast for T).

    The exact discretisation (:meth:`ExactPlant.zoh_map`) of an extreme plant overflows
    (``m`` so small or ``c``, ``k`` so large that c/m, k/m or 1/m·T pass the largest double):
    an arithmetic error or a map that is not finite is refused here, never met in a run.
    """
    try:
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            mp = plant.zoh_map(T)
    except ValueError:  # more quarter periods in T than the simulation cuts it into
        return (f"the plant oscillates far faster than a sample of {T:g} s can follow (more "
                f"than {MAX_SUBSTEPS} quarter periods in one sample)"), False
    except ArithmeticError as exc:  # FloatingPointError, OverflowError, ZeroDivisionError
        return (f"its motion over a sample of {T:g} s overflows a double "
                f"({type(exc).__name__})"), True
    if not all(math.isfinite(val) for val in mp[:6]):
        return f"its motion over a sample of {T:g} s overflows a double", True
    return "", False


def _check_plant(plant, offset: float, max_rate: float) -> None:
    """Refuse (ValueError naming `m`, `c`, `k`) a plant the rig cannot simulate.

    The plant is checked (:class:`ExactPlant`) and its exact discretisation tried at the
    fastest sample time the rig accepts (1/``max_rate``) and at the slowest (1 s): an overflow
    at either, or a plant too fast to simulate even at the fastest, would fail every run.
    A plant only too fast for slow sample times is served (CONFIG refuses those).
    """
    try:
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            exact = ExactPlant(plant, offset=offset)  # checks the plant and the offset
    except ArithmeticError as exc:
        why = f"its parameters overflow a double ({type(exc).__name__})"
    else:
        fast, slow = 1.0 / max_rate, MAX_SAMPLE_TIME
        why, _ = _zoh_map(exact, fast)
        if why:
            why += ", the fastest sample time the rig accepts (1/`max_rate`)"
        else:
            why, overflow = _zoh_map(exact, slow)
            if not overflow:
                why = ""  # at most too fast for slow sample times: CONFIG refuses those
    if why:
        m, c, k, fc = (float(getattr(plant, name)) for name in ("m", "c", "k", "fc"))
        raise ValueError(f"`m` {m:g} kg, `c` {c:g} N s/m, `k` {k:g} N/m, `fc` {fc:g} N: the "
                         f"rig cannot simulate this plant: {why}")


class VirtualRig:
    """A rig simulator speaking ``PHOID-RIG 1``.

    Parameters
    ----------
    plant : phoid.Plant
        The plant m (kg), c (N·s/m), k (N/m), f_c (N).
    offset_force : float, default 0
        Constant offset force f₀, N.
    noise : float, default 0
        Standard deviation of the position sensor's white noise, m.
    quantum : float, default 0
        The encoder's count, m: the position read (and streamed) is rounded to a multiple of
        it, after the noise (0: no rounding; else from 1e-30 to 1e30 m).
    seed : int, optional
        Seed of the noise.
    realtime : bool, default False
        Pace the samples to the wall clock (one per ``sample_time``).
    build : str or Path, optional
        Where the C controller is built; default a temporary folder removed by :meth:`close`.
    max_rate : float, default 20000
        The fastest sample rate the rig accepts, Hz (1 to 1e9): a CONFIG with a shorter
        ``sample_time`` is refused (``ERROR``).
    faults : mapping, optional
        Injected faults (module docstring).
    noise_in_loop : bool, default True
        The controller reads the noisy position, as on a rig (the noise then also drives the
        plant through the loop). False: the controller reads the exact position and only the
        streamed x carries the noise (phoid's simulate model: pure measurement noise).
    force_noise : float, optional
        Standard deviation of the force sensor's white noise, N: the SAMPLE lines then carry
        the measured force G·uₙ + ηₙ (at most 1e300 N). None (default): no force sensor, no
        force field.
    idle_timeout : float, default 30
        Seconds without a line from the host (outside a run) after which the rig ends the
        session (``ERROR``, then it closes); the hello must come within
        min(10 s, ``idle_timeout``). At most a day (86 400 s).
    max_session : float, default 3600
        Seconds one session may hold the rig; then it ends (``ERROR``, close), a run in
        progress too. At most a day (86 400 s).
    max_samples : int, default 2000000
        The most samples one run may take (hold_samples + run_samples + 1); a CONFIG asking
        for more is refused.

    Raises
    ------
    CompilerNotFoundError
        Without a C compiler (the library is built when the rig is made).
    ValueError
        For a parameter out of its range (named), or a plant whose exact discretisation
        overflows at the fastest or the slowest sample time the rig accepts (naming `m`,
        `c`, `k`, `fc`).
    """

    def __init__(self, plant, *, offset_force: float = 0.0, noise: float = 0.0,
                 quantum: float = 0.0, seed: int | None = None, realtime: bool = False,
                 build: str | Path | None = None, max_rate: float = 20000.0,
                 faults: Mapping[str, tuple[int, int]] | None = None,
                 noise_in_loop: bool = True, force_noise: float | None = None,
                 idle_timeout: float = IDLE_TIMEOUT, max_session: float = MAX_SESSION,
                 max_samples: int = MAX_SAMPLES) -> None:
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a finite number ≥ 0 m; got {noise!r}")
        if not (isinstance(quantum, numbers.Real) and not isinstance(quantum, (bool, np.bool_))
                and (quantum == 0 or MIN_QUANTUM <= quantum <= MAX_QUANTUM)):
            raise ValueError(f"quantum must be 0 (no rounding) or a number from {MIN_QUANTUM:g} "
                             f"to {MAX_QUANTUM:g} m (the encoder's count); got {quantum!r}")
        if force_noise is not None and not (math.isfinite(force_noise) and force_noise >= 0):
            raise ValueError(f"force_noise must be a finite number ≥ 0 N; got {force_noise!r}")
        if force_noise is not None and force_noise > MAX_FORCE_NOISE:
            raise ValueError(f"force_noise must be at most {MAX_FORCE_NOISE:g} N (the measured "
                             f"force must stay a finite double); got {force_noise!r}")
        if not (math.isfinite(max_rate) and 1.0 / MAX_SAMPLE_TIME <= max_rate <= MAX_RATE):
            raise ValueError(f"max_rate must be a number from {1 / MAX_SAMPLE_TIME:g} to "
                             f"{MAX_RATE:g} Hz (the controller's 1 ns); got {max_rate!r}")
        for name, val in (("idle_timeout", idle_timeout), ("max_session", max_session)):
            if not (math.isfinite(val) and 0 < val <= MAX_WAIT):
                raise ValueError(f"{name} must be a number > 0 and at most {MAX_WAIT:g} s "
                                 f"(a day); got {val!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)
                                 or not 0 <= seed < 2**128):
            raise ValueError(f"seed must be a whole number from 0 to 2^128 - 1; got {seed!r}")
        if isinstance(max_samples, bool) or not isinstance(max_samples, int) or max_samples < 3:
            raise ValueError(f"max_samples must be a whole number ≥ 3; got {max_samples!r}")
        _check_plant(plant, float(offset_force), float(max_rate))
        self.plant, self.offset, self.noise = plant, float(offset_force), float(noise)
        self.quantum = float(quantum)
        self.rng = np.random.default_rng(seed)
        # the force noise has its own stream, so the position noise is the same with or without
        self.force_rng = np.random.default_rng(None if seed is None else [seed, 1])
        self.force_noise = None if force_noise is None else float(force_noise)
        self.realtime, self.max_rate = bool(realtime), float(max_rate)
        self.idle_timeout, self.max_session = float(idle_timeout), float(max_session)
        self.max_samples = int(max_samples)
        self.faults = dict(faults or {})
        self.noise_in_loop = bool(noise_in_loop)
        self._tmp = None if build is not None else tempfile.mkdtemp(prefix="phoid-rig-")
        self.folder = Path(build if build is not None else self._tmp)
        build_library(self.folder)
        self.starts = 0
        self._closing = threading.Event()
        self._busy = threading.Lock()  # held by the session being served
        self._refusing = threading.BoundedSemaphore(MAX_REFUSING)  # busy answers in progress
        self._socks: set[socket.socket] = set()  # the connections open now
        self._socks_lock = threading.Lock()
        self._server: socketserver.TCPServer | None = None
        self._thread: threading.Thread | None = None

    # -------------------------------------------------------------------------------------
    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start serving in a background thread; the address served (port 0: a free one).

        One host is served at a time; another that connects meanwhile gets
        ``ERROR busy: another host is connected …`` at once and is closed.
        """
        rig = self

        class Handler(socketserver.BaseRequestHandler):
            def handle(self) -> None:
                rig._connection(self.request)

        class Server(socketserver.ThreadingTCPServer):
            allow_reuse_address = True
            request_queue_size = 64  # the listen backlog: a burst of hosts is answered at once
            daemon_threads = False
            block_on_close = True  # close() waits for the connections' threads

            def handle_error(self, request, client_address) -> None:
                # _connection turns every failure into an ERROR line; nothing else to print
                exc = sys.exc_info()[1]
                sys.stderr.write(f"phoid virtual-rig: a connection from {client_address} "
                                 f"failed: {type(exc).__name__}: {exc}\n")

        try:
            self._server = Server((host, port), Handler)
        except OSError as exc:
            raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.1,),
                                        daemon=True, name="phoid-virtual-rig")
        self._thread.start()
        addr = self._server.server_address
        return str(addr[0]), int(addr[1])

    def close(self) -> None:
        """Stop serving (sessions end with an ``ERROR``) and remove the temporary build folder."""
        self._closing.set()  # a session gives up within about a second
        if self._server is not None:
            self._server.shutdown()
            if self._busy.acquire(timeout=3.0):  # the session ended by itself
                self._busy.release()
            else:  # it is stuck sending to a host that reads nothing: cut it off
                with self._socks_lock:
                    for sock in self._socks:
                        with contextlib.suppress(OSError):
                            sock.shutdown(socket.SHUT_RDWR)
            self._server.server_close()
            self._server = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> VirtualRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -------------------------------------------------------------------------------------
    def _connection(self, sock: socket.socket) -> None:
        """One accepted connection: its session, or ``ERROR busy`` while another is served."""
        with self._socks_lock:
            self._socks.add(sock)
        try:
            sock.settimeout(max(self.idle_timeout, SEND_TIMEOUT))  # bounds every send
            link = Link(sock)
            if not self._busy.acquire(timeout=BUSY_GRACE):
                if self._refusing.acquire(blocking=False):
                    try:
                        self._last_word(link, BUSY)
                    finally:
                        self._refusing.release()
                else:  # a flood of connections: no time for the graceful close
                    with contextlib.suppress(OSError):
                        sock.setblocking(False)
                        sock.send(encode("ERROR", BUSY))
                link.close()
                return
            try:
                self.session(link)
            finally:
                self._busy.release()
        finally:
            with self._socks_lock:
                self._socks.discard(sock)

    @staticmethod
    def _last_word(link: Link, message: str, binary: bool = False) -> None:
        """Send ``ERROR message`` (a line, or a frame in a binary session), stop sending, and
        read (at most LINGER s) until the host closes: closing at once could reset the
        connection before the host reads the line."""
        with contextlib.suppress(OSError):  # LinkClosed too
            link.send(error_frame(message) if binary else encode("ERROR", message))
            link.sock.shutdown(socket.SHUT_WR)
            end = time.monotonic() + LINGER
            while (left := end - time.monotonic()) > 0:
                ready, _, _ = select.select([link.sock], [], [], left)
                if not ready or not link.sock.recv(65536):
                    break

    def session(self, link: Link) -> None:
        """Serve one connection: hello, then CONFIG/START/CLEAR/ABORT until BYE or the end.

        Never raises: a line the rig cannot use is answered ``ERROR`` and the session goes
        on; a session the rig ends (no hello, a host idle for ``idle_timeout`` s, the
        ``max_session`` limit, the rig closing, a failure of the rig itself) gets a last
        ``ERROR`` naming why, then the connection is closed.
        """
        lines = _Lines(link, self._closing, self.max_session)
        try:
            self._serve(link, lines)
        except LinkClosed:
            pass
        except _SessionOver as end:
            self._last_word(link, str(end), lines.binary)
        except Exception as exc:  # a failure of the rig itself: the host hears of it
            self._last_word(link, f"the rig failed ({type(exc).__name__}: {exc}); closing "
                                  "the session", lines.binary)
        finally:
            link.close()

    def _serve(self, link: Link, lines: _Lines) -> None:
        wait = min(HELLO_TIMEOUT, self.idle_timeout)
        try:
            line = lines.read(wait)
            if line is None:
                raise _SessionOver(f"no hello ('PHOID-RIG 1') within {wait:g} s: closing")
            check_hello(parse(line), "the host")
        except LinkClosed:
            raise
        except ProtocolError as exc:
            raise _SessionOver(str(exc)) from None
        link.send(hello())
        config: dict[str, object] | None = None
        while True:
            try:
                line = lines.read(self.idle_timeout)
                if line is None:
                    raise _SessionOver(f"no line from the host for {self.idle_timeout:g} s "
                                       "(the rig's --idle-timeout): closing the session")
                msg = lines.parse(line)
            except LinkClosed:
                raise
            except ProtocolError as exc:
                # a line refused whole may have been a CONFIG (a damaged checksum, a bad
                # field): no configuration survives it (docs/rig-protocol.md)
                config = None
                link.send(lines.error(str(exc)))
                continue
            if msg.kind == "BYE":
                return
            if msg.kind == "FRAMING":  # only as a text line: binary frames from the OK on
                config = None
                if msg.fields["name"] != "cobs":
                    link.send(encode("ERROR", f"unknown framing {msg.fields['name']!r}; this "
                                              "rig speaks cobs (and text)"))
                    continue
                link.send(encode("OK"))
                lines.binary = True
            elif msg.kind == "CONFIG":
                fields = dict(msg.fields)
                if lines.binary:  # every field is sent: NO_LIMIT is the controller's "none"
                    for key, none in (("x_min", -NO_LIMIT), ("x_max", NO_LIMIT),
                                      ("u_max", NO_LIMIT)):
                        if fields[key] == none:
                            del fields[key]
                err = self._check_config(fields)
                config = None if err else fields
                link.send(lines.error(err) if err else lines.ok())
            elif msg.kind == "START":
                if config is None:
                    link.send(lines.error("START without an accepted CONFIG"))
                    continue
                ran = self._run(link, lines, config)
                if ran is None:
                    return  # the connection was dropped (an injected fault)
                if not ran:
                    config = None  # the host sent a line the rig refused during the run
            elif msg.kind in ("CLEAR", "ABORT"):
                link.send(lines.ok())  # no run in progress: nothing to clear or abort
            else:
                config = None  # every line the rig refuses clears the configuration
                link.send(lines.error(f"the rig does not take {msg.kind}"))

    def _check_config(self, cfg: Mapping[str, object]) -> str:
        """Why the rig refuses a configuration (naming the field), or ""."""
        try:
            c = Controller(cfg, self.folder).config  # phoid_init's checks, the C types' ranges
        except ValueError as exc:
            return str(exc)
        T = c.sample_time
        if T < 1.0 / self.max_rate:
            return (f"sample_time {T:g} s ({1 / T:g} Hz) is faster than this rig can sample "
                    f"(at most {self.max_rate:g} Hz, its --max-rate)")
        if T > MAX_SAMPLE_TIME:
            return (f"sample_time {T:g} s is slower than this rig samples (at most "
                    f"{MAX_SAMPLE_TIME:g} s, {1 / MAX_SAMPLE_TIME:g} Hz)")
        why, _ = _zoh_map(ExactPlant(self.plant, offset=self.offset), T)
        if why:
            return f"sample_time {T:g} s: {why}; give another sample_time"
        if c.hold_samples == 0:
            return ("hold_samples 0 (hold until a release) would hold for ever: the protocol "
                    "has no release command; give hold_samples >= 1")
        total = c.hold_samples + c.run_samples + 1
        if total > self.max_samples:
            return (f"hold_samples + run_samples = {total - 1} samples: more than this rig runs "
                    f"at once (at most {self.max_samples - 1}, its --max-samples)")
        if self.realtime and total * T > self.max_session:
            return (f"hold_samples + run_samples at sample_time {T:g} s take {total * T:g} s "
                    f"in real time, longer than a session may hold the rig "
                    f"({self.max_session:g} s, its --max-session)")
        if not math.isfinite(c.command_gain * c.u_max):
            return (f"command_gain x u_max = {c.command_gain:g} x {c.u_max:g} is not a finite "
                    "force: give a smaller u_max (command units)")
        if c.has_force and self.force_noise is None:
            return ("has_force 1: this rig has no force sensor (start it with --force-noise "
                    "to simulate one)")
        return ""

    def _run(self, link: Link, lines: _Lines, cfg: Mapping[str, object]) -> bool | None:
        """One run, streamed; True when it ran, False when it ran but the host sent a line
        the rig refused meanwhile, None when an injected fault dropped the connection.

        A simulation that diverges (the plant's position no longer a finite double, or an
        arithmetic error in its motion) is read by the controller as a sensor failure: it
        faults (``fault-input``), that sample is not sent (a SAMPLE carries finite numbers
        only), and the run ends with its events and ``END fault-input``. A measured force
        that is not a finite double is a sensor failure too: its sample is not sent and the
        controller faults (``fault-input``) at the next sample, where it reads that force
        (value 1 with ``has_force`` 1, else through the position input, value 0).
        """
        self.starts += 1
        ctrl = Controller(cfg, self.folder)
        T, G = float(ctrl.config.sample_time), float(ctrl.config.command_gain)
        total = int(ctrl.config.hold_samples) + int(ctrl.config.run_samples) + 1
        plant = ExactPlant(self.plant, offset=self.offset)
        fault = {kind: idx for kind, (run, idx) in self.faults.items() if run == self.starts}
        ctrl.start()
        out = bytearray()
        t0 = time.monotonic()
        n = 0
        sensed = 0.0 if self.force_noise is not None else None  # the force read at nT, N
        refused = False  # a line of the host's refused during the run
        while True:
            if n > total:  # the controller stops by itself; a bound all the same
                raise RuntimeError(f"the run went past its {total} samples")
            x = self._read(plant.x)
            if not (math.isfinite(x) and math.isfinite(plant.x)):  # diverged
                ctrl.step(math.nan, 0.0, sensed)  # the controller faults: fault-input
                break
            before = ctrl.state
            u = ctrl.step(x if self.noise_in_loop else plant.x, 0.0, sensed)
            state = ctrl.state
            if before == "run" and state == "done":
                state = "run"  # the last run sample (the controller is done after it)
            if self.force_noise is None:
                line = (sample_frame(n, state, x, u) if lines.binary
                        else encode("SAMPLE", n, n * T, x, u, state))
            else:
                sensed = G * u + self.force_noise * float(self.force_rng.standard_normal())
                if not math.isfinite(sensed):  # the force sensor failed: fault-input
                    ctrl.step(x if ctrl.config.has_force else math.nan, 0.0, math.nan)
                    break
                line = (sample_frame(n, state, x, u, sensed) if lines.binary
                        else encode("SAMPLE", n, n * T, x, u, state, sensed))
            if fault.get("drop") == n:
                link.send(bytes(out))
                with contextlib.suppress(OSError):
                    link.sock.shutdown(socket.SHUT_RDWR)
                return None
            if fault.get("corrupt") == n:
                line = (_corrupt(line) if lines.binary
                        else line.replace(b"SAMPLE", b"SAMPLF", 1))
            if fault.get("gap") != n:
                out += line
            if ctrl.state in ("done", "fault") and state != "run":
                break
            try:
                with np.errstate(all="ignore"):  # an overflow makes x non-finite: fault-input
                    plant.advance(G * u, T)
            except (ArithmeticError, ValueError):  # the motion itself failed (math's errors)
                plant.x = math.nan
            n += 1
            if self.realtime or len(out) >= FLUSH * 60:
                link.send(bytes(out))
                out.clear()
                lines.check()  # the rig closing, the session's time
                refused |= self._poll(link, lines, ctrl)
                if self.realtime:
                    time.sleep(max(0.0, min(T, t0 + n * T - time.monotonic())))
        events = ctrl.events()
        for ev in events:
            out += (event_frame(ev.index, ev.code, ev.value) if lines.binary
                    else encode("EVENT", ev.index, ev.name, ev.value))
        faults = [ev.name for ev in events if ev.name.startswith("fault-")]
        end = "done" if ctrl.state == "done" else (faults[-1] if faults else "fault")
        out += end_frame(end) if lines.binary else encode("END", end)
        link.send(bytes(out))
        return not refused

    def _read(self, x: float) -> float:
        """The encoder's reading of the position ``x``: x + ε, rounded to the quantum."""
        return encoder_reading(x, self.noise, self.quantum, self.rng)

    @staticmethod
    def _poll(link: Link, lines: _Lines, ctrl: Controller) -> bool:
        """Take an ABORT (or anything) the host sent during the run, without waiting; True
        when the rig refused a line (answered ``ERROR``)."""
        try:
            line = lines.read(0)
            if line is None:
                return False
            msg = lines.parse(line)
        except LinkClosed:
            raise
        except ProtocolError as exc:
            link.send(lines.error(str(exc)))
            return True
        if msg.kind == "ABORT":
            ctrl.abort(float(msg.fields["reason"]))  # type: ignore[arg-type]
            return False
        link.send(lines.error(f"{msg.kind} during a run: abort it first"))
        return True


def _corrupt(frame: bytes) -> bytes:
    """A frame with one byte changed in its middle (never to 0x00): its CRC no longer holds."""
    data = bytearray(frame)
    i = len(data) // 2
    data[i] ^= 0x40 if data[i] == 0x80 else 0x80
    return bytes(data)
