r"""The host driver: run a designed plan on a rig (``PHOID-RIG 1``), write the ``phoid/1`` set.

:func:`run_plan` checks every option, the plan's runs against the rig's limits and every file
name it will write before anything moves; then, for each run, ``CONFIG`` and ``START``, and
the samples streamed into the run's CSV (``t, x, u`` from the release on; ``u`` the measured
force when the SAMPLE lines carry one, else the command). After every run it rewrites
``experiment.toml`` (atomically): the complete runs as ``[[run]]`` with the digital loop in
``[loop]``, so that ``phoid identify`` reads the set as it stands, and every attempt —
complete, aborted by the controller, or incomplete — in ``[[rig.attempt]]`` (docs/format.md,
"Keys written by `phoid run`"). Aborted and incomplete runs keep their samples in their own
files (``run03.aborted.csv``, ``run03.incomplete.csv``), never listed as ``[[run]]``.

A run is complete only when its stream is exactly the run configured: END ``done`` after
``hold_samples + run_samples + 1`` samples, indices consecutive from 0, states in order with
those counts, times strictly increasing. Every read is bounded (docs/rig-protocol.md, "Limits
of the host"); the manifest stays within the reader's limit whatever the rig sends; nothing
in ``--out`` is replaced but the set's own manifest.

The checks before anything moves are in :mod:`phoid.rig.checks` (options, the plan, each
run's configuration: :func:`plan_configs`) and :mod:`phoid.rig.runfiles` (the files, the
manifest, a resumed set).
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # not POSIX: no lock
    fcntl = None  # type: ignore[assignment]
try:
    import termios
except ImportError:  # not POSIX: no serial ports
    termios = None  # type: ignore[assignment]

from phoid._output import OutputFolder
from phoid.rig.checks import MANIFEST, MAX_TIMEOUT, RigError, clip, option, plan_configs, variant
from phoid.rig.frames import (
    abort_frame,
    config_frame,
    decode_frame,
    message_frame,
    parse_rig_frame,
)
from phoid.rig.link import Link, LinkClosed, connect, open_serial
from phoid.rig.protocol import (
    HELLO,
    VERSION,
    Message,
    ProtocolError,
    check_hello,
    encode,
    encode_config,
    hello,
    parse,
)
from phoid.rig.runfiles import (
    DIGEST,
    EVENT_CHARS,
    REASON_CHARS,
    RunFile,
    check_resumed,
    check_size,
    check_targets,
    check_writable,
    read_state,
    write_manifest,
)

__all__ = ["FRAMINGS", "RigError", "RunPlanResult", "open_port", "parse_port", "plan_configs",
           "run_plan"]

HELLO_SKIP = 65536  # bytes before the hello reply skipped (a cut-off session's rest) at most
MAX_DAMAGED = 100  # damaged lines (checksum, syntax, too long) in a run before the link is given up
EXTRA_EVENTS = 64  # EVENT lines a run may bring beyond one per sample
LINE_BYTES = 160  # bytes per line in a run's deadline on a serial line
LINE_TIME = 1e-4  # s per sample in a run's deadline for the host's and a fast rig's own work
FRAMINGS = ("auto", "text", "binary")  # --framing: offer the binary one, never, or insist
_DIGITS = re.compile(r"[0-9]{1,9}")


@dataclass(frozen=True)
class RunPlanResult:
    """What :func:`run_plan` did.

    Attributes
    ----------
    manifest : Path
        The set's manifest.
    statuses : tuple of str
        Per plan run: ``"complete"``, ``"aborted"``, ``"incomplete"`` or ``"pending"``.
    messages : tuple of str
        One line per run that did not complete (which run, why, where its samples are).
    """

    manifest: Path
    statuses: tuple[str, ...]
    messages: tuple[str, ...] = field(default=())

    @property
    def complete(self) -> bool:
        """Every run of the plan completed."""
        return all(s == "complete" for s in self.statuses)


def parse_port(port: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` (or ``HOST:PORT``) → (host, port); RigError otherwise."""
    text = port[6:] if port.startswith("tcp://") else port
    host, sep, num = text.rpartition(":")
    if "://" in text or not sep or not host or not _DIGITS.fullmatch(num) \
            or not 0 < int(num) < 65536:
        raise RigError(f"--port must be tcp://HOST:PORT or serial:///dev/DEVICE[?baud=N] "
                       f"(port 1 to 65535); got {clip(port, 200)!r}")
    host = host.strip("[]")
    try:
        ipaddress.ip_address(host)
    except ValueError:
        try:
            size = len(host.encode("idna"))  # each label 1 to 63 characters
        except UnicodeError:
            size = 0
        if not 0 < size <= 253 or any(not ch.isprintable() or ch.isspace() or ch in "/@?#"
                                      for ch in host):
            raise RigError(f"--port: {clip(host, 80)!r} is not a host name (labels of 1 to 63 "
                           "characters, 253 in all, no spaces) nor an IP address; got "
                           f"{clip(port, 200)!r}") from None
    return host, int(num)


def open_port(port: str, timeout: float) -> Link:
    """Connect to the rig: ``tcp://HOST:PORT`` or ``serial:///dev/DEVICE[?baud=N]`` (115200).

    ``timeout`` bounds the connection and every send on the link.
    """
    if port.startswith("serial://"):
        path, _, query = port[len("serial://"):].partition("?")
        key, _, val = query.partition("=")
        if not path or (query and (key != "baud" or not _DIGITS.fullmatch(val)
                                   or int(val) == 0)):
            raise RigError(f"--port must be serial:///dev/DEVICE or serial:///dev/DEVICE?baud=N; "
                           f"got {clip(port, 200)!r}")
        return open_serial(path, int(val) if query else 115200, timeout)
    host, num = parse_port(port)
    return connect(host, num, timeout)


def run_plan(plan: str | Path, port: str, out: str | Path, *, resume: bool = False,
             timeout: float = 10.0, progress: Callable[[int, int, int], None] | None = None,
             framing: str = "text", **limits: Any) -> RunPlanResult:
    """Run every run of a plan on the rig at ``port`` and write the set into ``out``.

    Parameters
    ----------
    plan : str or Path
        The plan (``phoid design --out``): its folder or manifest.
    port : str
        The rig: ``tcp://HOST:PORT`` or ``serial:///dev/DEVICE[?baud=N]`` (POSIX).
    out : str or Path
        The set's folder (created); its ``experiment.toml`` is rewritten after every run, no
        other file is replaced (one in the way of a run is refused before anything moves).
    resume : bool
        Continue a set written before: the runs complete or aborted there are kept, the rest
        run. Without it an existing manifest in ``out`` is refused.
    timeout : float
        Seconds (finite, > 0, at most a day) to wait for the connection, each line and each
        send; each run ends within a deadline from it and the run's samples.
    progress : callable, optional
        Called as ``progress(run, samples, total)`` while samples arrive.
    framing : {"text", "auto", "binary"}
        How the samples travel (docs/rig-protocol.md, "Binary framing"): ``"text"`` lines only
        (the default: every ``PHOID-RIG 1`` rig); ``"auto"`` offers ``FRAMING cobs`` after
        the hello and keeps the text lines when the rig answers ERROR; ``"binary"`` insists
        (a rig that answers ERROR is one RigError).
    **limits
        ``pmax``, ``dmax``, ``hold_p``, ``hold_d``, ``hold``, ``x_limit``, ``u_max``,
        ``growth_limit`` of :func:`plan_configs`.

    Raises
    ------
    RigError
        One line: bad input, found before anything moves (an option, the plan, a file in the
        way, the port, the protocol version), a CONFIG refused, a wrong reply to CONFIG/CLEAR.
    """
    if not str(out).strip():
        raise RigError("--out must name a folder; got an empty name; nothing was sent")
    if framing not in FRAMINGS:
        raise RigError(f"--framing must be {', '.join(FRAMINGS[:-1])} or {FRAMINGS[-1]}; got "
                       f"{clip(repr(framing), 80)}")
    timeout = option("--timeout", timeout, lambda v: 0 < v <= MAX_TIMEOUT,
                     f"a finite number of seconds > 0 and at most {MAX_TIMEOUT:g}")
    sched, configs = plan_configs(plan, **limits)
    folder = OutputFolder(out, overwrite=True, error=RigError)
    lock, created = _lock(folder)  # one session a folder: before anything in it is read
    try:
        mpath = folder.path(MANIFEST)
        if (mpath.exists() or mpath.is_symlink()) and not resume:
            raise RigError(f"{mpath} exists already (pass --resume to continue it, or choose "
                           "another --out)")
        state = read_state(folder, sched)
        attempts, recorded = state or ([], {})
        files = sched["files"]
        status = ["pending"] * len(files)
        for a in attempts:
            if a["status"] in ("complete", "aborted"):
                status[a["run"] - 1] = a["status"]
        created = check_writable(folder, [f for f, s in zip(files, status, strict=True)
                                          if s == "pending"]) or created  # names first
        check_targets(folder, files, status, {a["file"] for a in attempts})
        check_size(folder, sched, configs, attempts, status)
        digests = check_resumed(folder, sched, configs, attempts, recorded) if state else {}
        link = open_port(port, timeout)
        try:
            signals = _Interrupts()
            with signals.installed():
                messages = _session(link, port, timeout, folder, sched, configs, attempts,
                                    status, digests, progress, signals, framing)
        except LinkClosed as exc:
            raise RigError(clip(exc, REASON_CHARS)) from None
        finally:
            link.close()
    except LinkClosed as exc:
        raise RigError(str(exc)) from None
    finally:
        if created:  # a folder made for a set that wrote nothing: removed (only when empty)
            with contextlib.suppress(OSError):
                os.rmdir(folder.folder)
        if lock >= 0:
            os.close(lock)  # the lock goes with it
    return RunPlanResult(folder.path(MANIFEST), tuple(status), tuple(messages))


def _lock(folder: OutputFolder) -> tuple[int, bool]:
    """Create ``folder`` if need be and lock it for this session (``flock`` on the folder
    itself, POSIX; released when the session ends or its process dies, nothing left behind):
    the folder's descriptor (-1 without ``flock``) and whether the folder was created. A
    folder another session holds is one RigError."""
    root = Path(os.path.abspath(folder.folder))
    created = not root.exists()
    try:
        os.makedirs(root, exist_ok=True)
        fd = os.open(root, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as exc:
        raise RigError(f"{folder.folder}: phoid run cannot write its files there "
                       f"({exc.strerror or exc}); choose another --out; nothing was sent") \
            from None
    if fcntl is None:
        os.close(fd)
        return -1, created
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        busy = isinstance(exc, BlockingIOError)
        raise RigError(f"{folder.folder}: " + (
            "another `phoid run` is writing a set there (it holds the folder's lock); wait "
            "for it to end or choose another --out" if busy else
            f"cannot lock the folder ({exc.strerror or exc})") + "; nothing was sent") from None
    return fd, created


def _session(link: Link, port: str, timeout: float, folder: OutputFolder,
             sched: Mapping[str, Any], configs: list[dict[str, Any]],
             attempts: list[dict[str, Any]], status: list[str], digests: dict[bytes, str],
             progress: Callable | None, signals: _Interrupts, framing: str = "text"
             ) -> list[str]:
    """The session on the rig: hello, the framing, then each pending run; the messages of runs
    that did not complete."""
    files = sched["files"]
    messages: list[str] = []
    _drop_input(link)
    link.send(hello())
    try:
        check_hello(_hello_reply(link, timeout, port), f"the rig at {port}")
    except ProtocolError as exc:
        raise RigError(clip(exc, REASON_CHARS)) from None
    wire = _negotiate(link, port, timeout, framing)
    for i, cfg in enumerate(configs):
        if status[i] != "pending":
            continue
        where = f"run {i + 1} ({clip(files[i], 80)})"
        # from the file's creation to its record, Ctrl-C and SIGTERM are held back but where
        # the host waits on the rig; one arriving there becomes the run's interruption
        signals.hold()
        try:  # the file first: nothing is configured for a run that cannot be written
            run = RunFile(folder, files[i], cfg)
        except RigError as exc:
            signals.release()
            raise RigError(f"{where}: {exc}; nothing was started") from None
        reason, end, stop = "", "", None
        try:
            signals.release()  # one held back raises here
            link.send(wire.config(cfg))
            reply = _reply(link, timeout, "the reply to CONFIG", f"run {i + 1}: ", wire)
            if reply.kind == "ERROR":
                why = str(reply.fields["message"])
                hint = ("; it asks for the binary framing: pass --framing auto" if
                        not wire.binary and "FRAMING" in why else "")
                raise RigError(f"the rig refused {where}: {clip(why, REASON_CHARS)}{hint}")
            if reply.kind != "OK":
                raise RigError(f"the rig answered CONFIG of run {i + 1} with {reply.kind}, "
                               "not OK")
            reason, end, stop = _stream(link, run, i, timeout, progress, wire)
            signals.hold()
        except KeyboardInterrupt as exc:  # before START, or just after the stream: recorded
            if not signals.held:
                signals.hold()
            stop = stop or exc
            reason = reason or _interrupted(exc)
        except BaseException:
            try:
                signals.hold()
            finally:
                run.discard()
            signals.release()
            raise
        try:
            attempt, msg = _record(run, i, cfg, reason, end, stop, progress, digests,
                                   wire.name)
            attempts.append(attempt)
            status[i] = attempt["status"]
            try:
                write_manifest(folder, sched, configs, attempts, status)
            except RigError as exc:
                told = "the rig was sent ABORT; " if reason and run.error else ""
                raise RigError(f"{where}: {run.error + '; ' if run.error else ''}{told}its "
                               f"samples are in {attempt['file']}, but {exc}") from None
        finally:
            signals.release()  # one held back raises here, after the record
        if run.error:  # the disk: the rig was told to stop, the plan stops here
            told = "the rig was sent ABORT; " if reason else ""
            raise RigError(f"{where}: {run.error}; {told}the run is recorded incomplete, its "
                           f"{run.samples} samples in {attempt['file']}")
        if stop is not None:  # Ctrl-C: the samples and the manifest are on disk first
            raise stop
        if msg:
            messages.append(msg)
        if reason:
            break  # the link failed: stop; --resume runs the rest
        if run.faulted or end.startswith("fault"):
            link.send(wire.message("CLEAR"))  # latched: clear it
            reply = _reply(link, timeout, "the reply to CLEAR", f"after run {i + 1}: ", wire)
            if reply.kind != "OK":
                raise RigError(f"the rig did not clear its fault after run {i + 1}: "
                               f"{clip(reply.fields.get('message', reply.kind), 200)}")
    with contextlib.suppress(LinkClosed):  # the link may be gone after a failed run
        link.send(wire.message("BYE"))
    return messages


class _Interrupts:
    """SIGINT and SIGTERM in a session (main thread, POSIX or not): only the first raises (a
    second, as ``timeout`` or a shell sends to the whole process group, is ignored), and one
    arriving while held (:meth:`hold`) raises at :meth:`release`, so that no file is left that
    the manifest does not name."""

    def __init__(self) -> None:
        self.fired = False
        self.held = 0
        self.pending: tuple[Callable[[int, Any], Any], int, Any] | None = None

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        """Wrap the handlers in place (Python's own for Ctrl-C, the CLI's for SIGTERM)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        for sig, handler in before.items():
            if callable(handler):
                signal.signal(sig, self._wrap(handler))
        try:
            yield
        finally:
            for sig, handler in before.items():
                if callable(handler):
                    signal.signal(sig, handler)

    def _wrap(self, handler: Callable[[int, Any], Any]) -> Callable[[int, Any], Any]:
        def handle(signum: int, frame: Any) -> Any:
            if self.fired:
                return None
            self.fired = True
            if self.held:
                self.pending = (handler, signum, frame)
                return None
            return handler(signum, frame)
        return handle

    def hold(self) -> None:
        self.held += 1

    def release(self) -> None:
        self.held -= 1
        if not self.held and self.pending is not None:
            handler, signum, frame = self.pending
            self.pending = None
            handler(signum, frame)


def _interrupted(exc: BaseException) -> str:
    why = exc.args[0] if exc.args and isinstance(exc.args[0], str) else type(exc).__name__
    return f"interrupted on the host ({why})"


class _Wire:
    """The session's framing: text lines, or binary frames once the rig took ``FRAMING cobs``
    (:mod:`phoid.rig.frames`); what the host sends and how it reads the rig's messages."""

    def __init__(self, binary: bool) -> None:
        self.binary = binary
        self.name = "cobs" if binary else "text"  # the attempt's `framing`
        self.unit = "frame" if binary else "line"

    def config(self, cfg: Mapping[str, Any]) -> bytes:
        return config_frame(cfg) if self.binary else encode_config(cfg)

    def message(self, kind: str) -> bytes:
        """START, CLEAR or BYE."""
        return message_frame(kind) if self.binary else encode(kind)

    def abort(self, reason: float) -> bytes:
        return abort_frame(reason) if self.binary else encode("ABORT", reason)

    def read(self, link: Link, timeout: float) -> bytes | None:
        return link.read_frame(timeout) if self.binary else link.readline(timeout)

    def parse(self, raw: bytes, sample_time: float | None = None) -> Message:
        """A line or frame, checked and parsed (a SAMPLE frame's t = index·sample_time)."""
        if self.binary:
            return parse_rig_frame(decode_frame(raw), sample_time)
        return parse(raw)


_TEXT = _Wire(False)


def _negotiate(link: Link, port: str, timeout: float, framing: str) -> _Wire:
    """Offer ``FRAMING cobs`` (unless ``framing`` is text): the binary wire when the rig
    answers OK; the text one when it answers ERROR (an old rig), unless ``framing`` is binary."""
    if framing == "text":
        return _TEXT
    link.send(encode("FRAMING", "cobs"))
    try:
        reply = _reply(link, timeout, "the reply to FRAMING cobs")
    except (RigError, LinkClosed) as exc:  # a rig that breaks on a line it does not know
        raise RigError(f"{clip(exc, REASON_CHARS)}; a rig that does not take FRAMING cobs "
                       "runs with --framing text") from None
    if reply.kind == "OK":
        return _Wire(True)
    if reply.kind != "ERROR":
        raise RigError(f"the rig at {port} answered FRAMING cobs with {reply.kind}, not OK or "
                       "ERROR")
    if framing == "binary":
        raise RigError(f"the rig at {port} does not speak the binary framing (--framing "
                       f"binary): it answered FRAMING cobs with ERROR "
                       f"{clip(reply.fields['message'], 200)}; nothing was run")
    return _TEXT


def _drop_input(link: Link) -> None:
    """On a serial line, drop what the port received before the hello (the rest of a session
    that was cut off, arrived since the port was opened raw with TCSAFLUSH); a socket has no
    such buffer to drop (:func:`_hello_reply` skips what comes)."""
    if not link.byte_time or termios is None:
        return
    with contextlib.suppress(OSError, ValueError, AttributeError, termios.error):
        termios.tcflush(link.sock.fileno(), termios.TCIFLUSH)


def _hello_tail(line: bytes) -> Message | None:
    """The hello reply (``PHOID-RIG …`` or ``ERROR …``, its checksum right) that ends
    ``line`` after bytes of something else (the end of a frame, line noise); None if none."""
    for key in (b"PHOID-RIG ", b"ERROR "):
        j = line.rfind(key)
        if j > 0:
            try:
                msg = parse(line[j:])
            except ProtocolError:
                continue
            if msg.kind in ("HELLO", "ERROR"):
                return msg
    return None


def _hello_reply(link: Link, timeout: float, port: str) -> Message:
    """The rig's reply to the hello: the first valid ``PHOID-RIG`` or ``ERROR`` line within
    ``timeout`` s.

    What comes before it is skipped: the rest of a session that was cut off (samples or
    frames of a run still in flight when a killed or interrupted ``phoid run`` left) and line
    noise, including bytes before the reply on its own line. Bounded: ``timeout`` s and
    ``HELLO_SKIP`` bytes, after which one RigError says what came instead.
    """
    deadline = time.monotonic() + timeout
    skipped = 0
    instead = ""  # what came instead of the reply: the first of it
    while True:
        left = deadline - time.monotonic()
        line = link.readline(left) if left > 0 else None
        if line is None:
            break
        try:
            msg = parse(line)
        except ProtocolError as exc:
            msg = _hello_tail(line)
            if msg is None:
                instead = instead or (f"the rig at {port} sent a damaged line (waiting for hello): "
                                      f"{clip(exc, REASON_CHARS)}")
        if msg is not None:
            if msg.kind in ("HELLO", "ERROR"):
                return msg
            instead = instead or (f"the rig at {port} did not say hello ('{HELLO} "
                                  f"{VERSION}'); it sent {msg.kind}")
        skipped += len(line)
        if skipped > HELLO_SKIP:
            raise RigError(f"{instead}; and no hello reply in the {skipped} bytes after it")
    if instead:
        raise RigError(f"{instead}; and no hello reply within {timeout:g} s")
    raise RigError(f"the rig at {port} sent nothing for {timeout:g} s (waiting for hello)")


def _reply(link: Link, timeout: float, what: str, where: str = "", wire: _Wire = _TEXT) -> Any:
    """The rig's next line (or frame), parsed: within ``timeout`` s and one line, else one
    RigError."""
    line = wire.read(link, timeout)
    if line is None:
        raise RigError(f"{where}the rig sent nothing for {timeout:g} s (waiting for {what})")
    try:
        return wire.parse(line)
    except ProtocolError as exc:
        raise RigError(f"{where}the rig's {wire.unit} is damaged (waiting for {what}): "
                       f"{clip(exc, REASON_CHARS)}") from None


def _stream(link: Link, run: RunFile, i: int, timeout: float, progress: Callable | None,
            wire: _Wire = _TEXT) -> tuple[str, str, BaseException | None]:
    """START one run and stream it into ``run``: why the link failed ("" when it still works:
    not after a drop, a timeout, an ERROR, the deadline, a cap or a file that cannot be
    written; the host then sends ABORT), the END reason, and an interruption (Ctrl-C,
    SIGTERM) to raise once the record is written."""
    T, total = run.T, run.total
    wait = max(timeout, 2.0 * T)  # a rig streaming in real time sends a sample every T
    budget = (timeout + total * (2.0 * T + LINE_TIME)
              + (2 * total + EXTRA_EVENTS + 1) * LINE_BYTES * link.byte_time)
    deadline = time.monotonic() + budget
    reason, end = "", ""
    stop: BaseException | None = None
    try:
        link.send(wire.message("START"))
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                reason = (f"the run did not end within {budget:.4g} s (its {total} samples at "
                          f"T = {T:g} s, and --timeout {timeout:g} s)")
                break
            line = wire.read(link, min(wait, left))
            if line is None:
                if left > wait:
                    reason = f"the rig sent nothing for {wait:g} s"
                    break
                continue  # the deadline: said at the top
            try:
                msg = wire.parse(line, T)
            except ProtocolError as exc:  # keep reading: every later sample is kept
                run.damaged_lines += 1
                run.damage(f"{exc} (after sample {run.last_index})")
                if run.damaged_lines > MAX_DAMAGED:
                    reason = f"more than {MAX_DAMAGED} damaged {wire.unit}s in one run"
                    break
                continue
            if msg.kind == "SAMPLE":
                if run.count >= total:
                    reason = (f"the rig sent more than the run's {total} samples ({run.hold} "
                              f"hold, {run.run} run, 1 done)")
                    break
                run.sample(msg.fields)
                if run.error:
                    reason = run.error
                    break
                if progress is not None and run.count % 50 == 0:
                    progress(i + 1, run.count, total)
            elif msg.kind == "EVENT":
                if run.event_lines >= total + EXTRA_EVENTS:
                    reason = (f"the rig sent more than {total + EXTRA_EVENTS} EVENT {wire.unit}s "
                              f"(one per sample and {EXTRA_EVENTS})")
                    break
                run.event(msg.fields)
            elif msg.kind == "END":
                end = clip(msg.fields["reason"], EVENT_CHARS)
                break
            elif msg.kind == "ERROR":
                reason = f"the rig reported an error: {msg.fields['message']}"
                break
            else:
                reason = f"unexpected {msg.kind} during the run"
                break
    except LinkClosed as exc:
        reason = str(exc)
    except BaseException as exc:  # Ctrl-C, SIGTERM: keep what arrived, then re-raise
        reason, stop = _interrupted(exc), exc
    if reason:  # ask the rig to stop, keep what arrived
        with contextlib.suppress(LinkClosed):
            link.send(wire.abort(1.0))
    return reason, end, stop


def _record(run: RunFile, i: int, cfg: Mapping[str, Any], reason: str, end: str,
            stop: BaseException | None, progress: Callable | None, digests: dict[bytes, str],
            framing: str = "text") -> tuple[dict[str, Any], str]:
    """Close the run's file, judge the run (complete, aborted, incomplete), move the file to
    its name and make the attempt's record; and the message when it did not complete or its
    clock was off."""
    name, T, total = run.name, run.T, run.total
    run.close()
    if run.error and run.error not in reason:
        reason = f"{reason}; {run.error}" if reason else run.error
    elif not reason and end == "done":
        run.damage(run.shortfall() or run.clock())
        if (same := digests.get(run.digest.digest())) is not None:
            run.damage(f"the same samples, byte for byte, as {same}: a repeated recording, "
                       "which phoid identify refuses")
    if reason or run.damaged:
        reason = f"{run.damaged}; {reason}" if run.damaged and reason else run.damaged or reason
        status, target = "incomplete", variant(name, "incomplete")
    elif end == "done":
        status, target = "complete", name
    else:
        status, target = "aborted", variant(name, "aborted")
        fault = next((e for e in run.events if e.startswith(end)), end)
        reason = f"the controller aborted: {fault}"
    reason = clip(reason, REASON_CHARS)
    if progress is not None and stop is None:
        with contextlib.suppress(Exception):
            progress(i + 1, run.count, total)
    try:
        written = run.finish(target)
    except OSError as exc:
        run.discard()
        raise RigError(f"run {i + 1} ({clip(name, 80)}): its samples could not be moved to "
                       f"{run.out.path(target)} ({exc.strerror or exc}) and are lost; "
                       f"{reason or 'the run had completed'}") from None
    if status == "complete":
        digests[run.digest.digest()] = f"run {i + 1} ({written})"
    attempt = {"run": i + 1, "file": written, "P": cfg["P"], "D": cfg["D"], "status": status,
               "samples": run.samples, "received": run.count,
               "u_source": run.u_source or "command", "framing": framing,
               "events": run.events, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
               **run.timing()}
    if status == "complete":
        attempt["digest"] = f"{DIGEST}:{run.digest.hexdigest()}"
    if run.event_lines > len(run.events):
        attempt["events_dropped"] = run.event_lines - len(run.events)
    if reason:
        attempt["reason"] = reason
    msg = "" if status == "complete" else (
        f"run {i + 1} ({name}) {status}: {reason}; its {run.samples} samples are in {written}")
    if status == "complete" and "sample_time_mean" in attempt and (
            abs(attempt["sample_time_mean"] - T) > 1e-3 * T
            or max(T - attempt["sample_time_min"], attempt["sample_time_max"] - T) > 0.1 * T):
        late = (f"run {i + 1} ({name}): the rig's sample intervals were "
                f"{attempt['sample_time_min']:.6g}–{attempt['sample_time_max']:.6g} s (mean "
                f"{attempt['sample_time_mean']:.6g} s), not T = {T:g} s; the digital loop's "
                "model assumes a fixed period")
        msg = late
    return attempt, msg
