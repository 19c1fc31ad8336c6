r"""The virtual rig: the compiled C controller stepping against phoid's exact plant, over TCP.

A :class:`VirtualRig` serves the ``PHOID-RIG 1`` protocol (docs/rig-protocol.md) on a TCP port,
one connection at a time, in a background thread. For each ``START`` it initialises the C
controller (:class:`phoid.rig.native.Controller`, built into the rig's build folder) with the
last ``CONFIG`` and steps it sample by sample against
:class:`phoid.simulation.tracking.ExactPlant`, the plant

    m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = G·uₙ   on [nT, (n + 1)T)

starting at rest at x = 0: per sample n the measured position x̃ₙ = x(nT) + εₙ (εₙ white
Gaussian, standard deviation ``noise``) goes into ``phoid_step`` (or, with
``noise_in_loop=False``, the exact x(nT) does and only the streamed x̃ₙ is noisy), whose
returned command uₙ (the controller's own delay ring has already delayed it) is held for one
period. Each step is
streamed as ``SAMPLE n nT x̃ₙ uₙ state``; with ``force_noise`` set, the rig also reports a
measured force f̃ₙ = G·uₙ + ηₙ (N: the force applied to the plant over [nT, (n + 1)T), ηₙ white
Gaussian of standard deviation ``force_noise``) as the line's ``force`` field, and steps the
controller with the force measured at the previous sample (what a load cell reads at nT; 0 at
the first sample) through ``phoid_step_force``. At the end come the controller's events and
``END``. It runs as fast as it can, or paced to the wall clock with ``realtime``.

Fault injection (for tests, Python only): ``faults`` maps ``"drop"``, ``"corrupt"`` or
``"gap"`` to ``(run, index)`` — the connection is closed before sample ``index`` of the
``run``-th START, that sample's line has a byte changed, or it is not sent.
"""

from __future__ import annotations

import contextlib
import math
import shutil
import socket
import socketserver
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from phoid.rig.link import Link, LinkClosed
from phoid.rig.native import Controller, build_library
from phoid.rig.protocol import ProtocolError, check_hello, encode, hello, parse
from phoid.simulation.tracking import ExactPlant

__all__ = ["VirtualRig"]

FLUSH = 512  # samples per send when not in real time


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
    seed : int, optional
        Seed of the noise.
    realtime : bool, default False
        Pace the samples to the wall clock (one per ``sample_time``).
    build : str or Path, optional
        Where the C controller is built; default a temporary folder removed by :meth:`close`.
    max_rate : float, default 20000
        The fastest sample rate the rig accepts, Hz: a CONFIG with a shorter ``sample_time``
        is refused (``ERROR``).
    faults : mapping, optional
        Injected faults (module docstring).
    noise_in_loop : bool, default True
        The controller reads the noisy position, as on a rig (the noise then also drives the
        plant through the loop). False: the controller reads the exact position and only the
        streamed x carries the noise (phoid's simulate model: pure measurement noise).
    force_noise : float, optional
        Standard deviation of the force sensor's white noise, N: the SAMPLE lines then carry
        the measured force G·uₙ + ηₙ. None (default): no force sensor, no force field.

    Raises
    ------
    CompilerNotFoundError
        Without a C compiler (the library is built when the rig is made).
    """

    def __init__(self, plant, *, offset_force: float = 0.0, noise: float = 0.0,
                 seed: int | None = None, realtime: bool = False,
                 build: str | Path | None = None, max_rate: float = 20000.0,
                 faults: Mapping[str, tuple[int, int]] | None = None,
                 noise_in_loop: bool = True, force_noise: float | None = None) -> None:
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a finite number ≥ 0 m; got {noise!r}")
        if force_noise is not None and not (math.isfinite(force_noise) and force_noise >= 0):
            raise ValueError(f"force_noise must be a finite number ≥ 0 N; got {force_noise!r}")
        if not (math.isfinite(max_rate) and max_rate > 0):
            raise ValueError(f"max_rate must be a finite number > 0 Hz; got {max_rate!r}")
        ExactPlant(plant, offset=offset_force)  # checks the plant and the offset
        self.plant, self.offset, self.noise = plant, float(offset_force), float(noise)
        self.rng = np.random.default_rng(seed)
        # the force noise has its own stream, so the position noise is the same with or without
        self.force_rng = np.random.default_rng(None if seed is None else [seed, 1])
        self.force_noise = None if force_noise is None else float(force_noise)
        self.realtime, self.max_rate = bool(realtime), float(max_rate)
        self.faults = dict(faults or {})
        self.noise_in_loop = bool(noise_in_loop)
        self._tmp = None if build is not None else tempfile.mkdtemp(prefix="phoid-rig-")
        self.folder = Path(build if build is not None else self._tmp)
        build_library(self.folder)
        self.starts = 0
        self._closing = threading.Event()
        self._server: socketserver.TCPServer | None = None
        self._thread: threading.Thread | None = None

    # -------------------------------------------------------------------------------------
    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start serving in a background thread; the address served (port 0: a free one)."""
        rig = self

        class Handler(socketserver.BaseRequestHandler):
            def handle(self) -> None:
                rig.session(Link(self.request))

        class Server(socketserver.TCPServer):
            allow_reuse_address = True

        try:
            self._server = Server((host, port), Handler)
        except OSError as exc:
            raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True,
                                        name="phoid-virtual-rig")
        self._thread.start()
        addr = self._server.server_address
        return str(addr[0]), int(addr[1])

    def close(self) -> None:
        """Stop serving and remove the temporary build folder."""
        self._closing.set()  # a session waiting for the host's next line gives up within 1 s
        if self._server is not None:
            self._server.shutdown()
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
    def session(self, link: Link) -> None:
        """Serve one connection: hello, then CONFIG/START/CLEAR/ABORT until BYE or the end."""
        try:
            try:
                check_hello(parse(link.readline(10.0) or b""), "the host")
            except ProtocolError as exc:
                link.send(encode("ERROR", str(exc)))
                return
            link.send(hello())
            config: dict[str, object] | None = None
            while True:
                line = link.readline(1.0)
                if line is None:
                    if self._closing.is_set():
                        return
                    continue
                try:
                    msg = parse(line or b"")
                except ProtocolError as exc:
                    link.send(encode("ERROR", str(exc)))
                    continue
                if msg.kind == "BYE":
                    return
                if msg.kind == "CONFIG":
                    err = self._check_config(msg.fields)
                    config = None if err else dict(msg.fields)
                    link.send(encode("ERROR", err) if err else encode("OK"))
                elif msg.kind == "START":
                    if config is None:
                        link.send(encode("ERROR", "START without an accepted CONFIG"))
                    elif not self._run(link, config):
                        return  # the connection was dropped (an injected fault)
                elif msg.kind in ("CLEAR", "ABORT"):
                    link.send(encode("OK"))  # no run in progress: nothing to clear or abort
                else:
                    link.send(encode("ERROR", f"the rig does not take {msg.kind}"))
        except LinkClosed:
            return
        finally:
            link.close()

    def _check_config(self, cfg: Mapping[str, object]) -> str:
        T = cfg.get("sample_time")
        if isinstance(T, float) and 0 < T < 1.0 / self.max_rate:
            return (f"sample_time {T:g} s ({1 / T:g} Hz) is faster than this rig can sample "
                    f"(at most {self.max_rate:g} Hz)")
        try:
            Controller(cfg, self.folder)
        except ValueError as exc:
            return str(exc)
        return ""

    def _run(self, link: Link, cfg: Mapping[str, object]) -> bool:
        """One run, streamed; False when an injected fault dropped the connection."""
        self.starts += 1
        ctrl = Controller(cfg, self.folder)
        T = float(cfg["sample_time"])  # type: ignore[arg-type]
        G = float(cfg.get("command_gain", 1.0))  # type: ignore[arg-type]
        plant = ExactPlant(self.plant, offset=self.offset)
        fault = {kind: idx for kind, (run, idx) in self.faults.items() if run == self.starts}
        ctrl.start()
        out = bytearray()
        t0 = time.monotonic()
        n = 0
        sensed = 0.0 if self.force_noise is not None else None  # the force read at nT, N
        while True:
            x = plant.x + (self.noise * float(self.rng.standard_normal()) if self.noise else 0.0)
            before = ctrl.state
            u = ctrl.step(x if self.noise_in_loop else plant.x, 0.0, sensed)
            state = ctrl.state
            if before == "run" and state == "done":
                state = "run"  # the last run sample (the controller is done after it)
            if self.force_noise is None:
                line = encode("SAMPLE", n, n * T, x, u, state)
            else:
                sensed = G * u + self.force_noise * float(self.force_rng.standard_normal())
                line = encode("SAMPLE", n, n * T, x, u, state, sensed)
            if fault.get("drop") == n:
                link.send(bytes(out))
                with contextlib.suppress(OSError):
                    link.sock.shutdown(socket.SHUT_RDWR)
                return False
            if fault.get("corrupt") == n:
                line = line.replace(b"SAMPLE", b"SAMPLF", 1)
            if fault.get("gap") != n:
                out += line
            if ctrl.state in ("done", "fault") and state != "run":
                break
            plant.advance(G * u, T)
            n += 1
            if self.realtime or len(out) >= FLUSH * 60:
                link.send(bytes(out))
                out.clear()
                self._poll(link, ctrl)
                if self.realtime:
                    time.sleep(max(0.0, t0 + n * T - time.monotonic()))
        events = ctrl.events()
        for ev in events:
            out += encode("EVENT", ev.index, ev.name, ev.value)
        faults = [ev.name for ev in events if ev.name.startswith("fault-")]
        end = "done" if ctrl.state == "done" else (faults[-1] if faults else "fault")
        out += encode("END", end)
        link.send(bytes(out))
        return True

    @staticmethod
    def _poll(link: Link, ctrl: Controller) -> None:
        """Take an ABORT (or anything) the host sent during the run, without waiting."""
        line = link.readline(0)
        if line is None:
            return
        try:
            msg = parse(line)
        except ProtocolError as exc:
            link.send(encode("ERROR", str(exc)))
            return
        if msg.kind == "ABORT":
            ctrl.abort(float(msg.fields["reason"]))  # type: ignore[arg-type]
        else:
            link.send(encode("ERROR", f"{msg.kind} during a run: abort it first"))
