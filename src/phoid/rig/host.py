r"""The host driver: run a designed plan on a rig (``PHOID-RIG 1``), write the ``phoid/1`` set.

:func:`run_plan` reads a plan (``phoid design --out``), checks every run's gains against the
rig's limits before anything moves, connects, says hello, and for each run sends ``CONFIG`` and
``START`` and streams the samples into the run's CSV (``t, x, u``: the samples from the release
on) as they arrive; ``u`` is the measured force when the rig's SAMPLE lines carry one (a rig
with a force sensor), else the command it applied (N with the command gain 1). After every run
it rewrites the manifest ``experiment.toml`` (atomically):
the complete runs as ``[[run]]`` tables with the digital loop in ``[loop]`` (``sample_time``,
``delay_samples``, ``velocity``), so that ``phoid identify`` reads the set as it stands, and
every attempt — complete, aborted by the controller, or incomplete (the link failed) — in
``[[rig.attempt]]`` with its reason, events and measured sample times (docs/format.md, "Keys
written by `phoid run`"). Aborted and incomplete runs keep their samples in their own files
(``run03.aborted.csv``, ``run03.incomplete.csv``) and are never listed as ``[[run]]``.

Each run's configuration: T = 1/fs, the plan's P and D, K = G = 1, backward-difference
velocity, d = Δt/T whole samples of command delay (the plan's ``[loop] delay``), the hold at
the plan's release amplitude A with a stiff, about critically damped loop on the plan's prior
(hold_P = 3 k, hold_D = 2√(m (k + hold_P)) − c, at least 0) for about seven of its slowest time
constants, position limits ±3A and the growth bound 2.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError, PhoidError
from phoid.io.manifest import read_manifest
from phoid.planning.schedule import read_schedule
from phoid.rig.link import Link, LinkClosed, connect, open_serial
from phoid.rig.protocol import ProtocolError, check_hello, encode, encode_config, hello, parse

__all__ = ["RigError", "RunPlanResult", "open_port", "parse_port", "plan_configs", "run_plan"]

MANIFEST = "experiment.toml"


class RigError(PhoidError):
    """Bad input to the host (plan, port, limits, a refusal of the rig): one line."""


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
    if "://" in text or not sep or not host or not num.isdigit() or not 0 < int(num) < 65536:
        raise RigError(f"--port must be tcp://HOST:PORT or serial:///dev/DEVICE[?baud=N] "
                       f"(port 1 to 65535); got {port!r}")
    return host.strip("[]"), int(num)


def open_port(port: str, timeout: float) -> Link:
    """Connect to the rig: ``tcp://HOST:PORT`` or ``serial:///dev/DEVICE[?baud=N]`` (115200)."""
    if port.startswith("serial://"):
        path, _, query = port[len("serial://"):].partition("?")
        key, _, val = query.partition("=")
        if not path or (query and (key != "baud" or not val.isdigit())):
            raise RigError(f"--port must be serial:///dev/DEVICE or serial:///dev/DEVICE?baud=N; "
                           f"got {port!r}")
        return open_serial(path, int(val) if query else 115200)
    host, num = parse_port(port)
    return connect(host, num, timeout)


def _prior_value(prior: Mapping[str, Any], key: str, pick: Callable) -> float | None:
    val = prior.get(key)
    if isinstance(val, list) and len(val) == 2:
        val = pick(val)
    if isinstance(val, (int, float)) and not isinstance(val, bool) and math.isfinite(val):
        return float(val)
    return None


def plan_configs(plan: str | Path, *, pmax: float | None = None, dmax: float | None = None,
                 hold_p: float | None = None, hold_d: float | None = None,
                 hold: float | None = None, x_limit: float | None = None,
                 u_max: float | None = None, growth_limit: float = 2.0
                 ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The plan and each run's controller configuration (CONFIG fields); nothing is sent.

    Returns
    -------
    (plan, configs)
        ``plan``: the schedule (:func:`phoid.planning.read_schedule`) with ``path``,
        ``delay_samples``, ``design`` (its ``[design]`` table); ``configs``: one dict of
        CONFIG fields per run.

    Raises
    ------
    RigError
        One line naming the plan, run and field: no plan, not a plan, no ``fs``, a delay that
        is not a whole number of samples, a gain beyond ``pmax``/``dmax``.
    """
    path = Path(plan)
    manifest = path / MANIFEST if path.is_dir() else path
    if not manifest.is_file():
        raise RigError(f"{manifest}: no such plan (write one with `phoid design --out`)")
    try:
        sched = read_schedule(manifest)
        doc = read_manifest(str(manifest), manifest)
    except (PhoidError, ValueError) as exc:
        raise RigError(f"not a plan: {exc}") from None
    design = doc.get("design") if isinstance(doc.get("design"), Mapping) else {}
    for key in ("fs", "duration", "amplitude"):
        if key not in sched:
            raise RigError(f"{manifest}: not a plan of `phoid design --out`: [design] {key} "
                           "is missing")
    fs, amp = sched["fs"], sched["amplitude"]
    T = 1.0 / fs
    delay = sched["delay"] if sched["delay"] is not None else 0.0
    d = round(delay * fs)
    if abs(d - delay * fs) > 1e-6 * max(1.0, d):
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is not a whole number of "
                       f"samples at fs = {fs:g} Hz (T = {T:g} s); design with --delay d/fs")
    for i, (P, D) in enumerate(zip(sched["P"], sched["D"], strict=True), start=1):
        if pmax is not None and abs(P) > pmax:
            raise RigError(f"{manifest}: run {i}: |P| = {abs(P):g} N/m exceeds the rig's limit "
                           f"--pmax {pmax:g}; nothing was sent")
        if dmax is not None and abs(D) > dmax:
            raise RigError(f"{manifest}: run {i}: |D| = {abs(D):g} N·s/m exceeds the rig's limit "
                           f"--dmax {dmax:g}; nothing was sent")
    prior = design.get("prior") if isinstance(design.get("prior"), Mapping) else {}
    m = _prior_value(prior, "m", lambda v: math.sqrt(abs(v[0] * v[1]))) or 1.0
    c = _prior_value(prior, "c", min) or 0.0
    k = _prior_value(prior, "k", max) or 0.0
    hP = 3.0 * k if hold_p is None else hold_p
    if hP + k <= 0:
        hP = 16.0 * m
    hD = max(0.0, 2.0 * math.sqrt(m * (k + hP)) - c) if hold_d is None else hold_d
    if hold is None:
        poles = np.roots([m, c + hD, k + hP])
        slow = float(np.min(np.abs(poles.real))) if np.all(poles.real < 0) else 1.0
        hold = min(30.0, max(0.5, 7.0 / slow))
    base = {
        "sample_time": T, "gain": 1.0, "command_gain": 1.0, "velocity": 0, "delay_samples": d,
        "hold_P": float(hP), "hold_D": float(hD), "x_start": amp,
        "hold_samples": max(1, round(hold * fs)), "run_samples": max(2, round(sched["duration"]
                                                                              * fs)),
        "x_min": -(3.0 * amp if x_limit is None else x_limit),
        "x_max": 3.0 * amp if x_limit is None else x_limit,
        "growth_limit": float(growth_limit),
    }
    if u_max is not None:
        base["u_max"] = float(u_max)
    configs = [dict(base, P=float(P), D=float(D))
               for P, D in zip(sched["P"], sched["D"], strict=True)]
    sched.update(path=manifest, delay_samples=d, design=dict(design))
    return sched, configs


class _Run:
    """One attempt's bookkeeping and its streamed CSV."""

    def __init__(self, out: OutputFolder, name: str) -> None:
        self.out, self.name = out, name
        self.part = f".{name}.part"
        out.check([self.part])
        os.makedirs(out.folder, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0)
        self.fh: IO[str] = os.fdopen(os.open(out.path(self.part), flags, 0o666), "w")
        self.fh.write("t,x,u\n")
        self.samples = 0
        self.last_index = -1
        self.times: list[float] = []
        self.events: list[str] = []
        self.u_source = ""  # "measured" (SAMPLE's force) or "command", from the first run sample

    def sample(self, f: Mapping[str, Any]) -> str:
        """Record one SAMPLE; a message when its force field breaks the run's (else "")."""
        self.times.append(float(f["t"]))
        if f["state"] == "run":
            source = "measured" if "force" in f else "command"
            if self.u_source and source != self.u_source:
                return (f"sample {f['index']}: the force field "
                        f"{'appears' if source == 'measured' else 'is missing'} mid-run (u "
                        f"would mix the measured force and the command); the samples "
                        f"{'with' if source == 'measured' else 'without'} it are left out")
            self.u_source = source
            u = float(f["force"] if source == "measured" else f["u"])
            self.fh.write(f"{float(f['t'])!r},{float(f['x'])!r},{u!r}\n")
            self.samples += 1
            if self.samples % 100 == 0:
                self.fh.flush()
        return ""

    def finish(self, target: str) -> str:
        """Close the file and move it to ``target`` (a free name if that one is taken)."""
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self.fh.close()
        name = target
        if target != self.name:  # an aborted or incomplete attempt: never replace another
            stem = target[:-len(".csv")]
            i = 1
            while self.out.path(name).exists() or self.out.path(name).is_symlink():
                i += 1
                name = f"{stem}-{i}.csv"
        self.out.check([name])
        os.replace(self.out.path(self.part), self.out.path(name))
        return name

    def timing(self) -> dict[str, float]:
        if len(self.times) < 2:
            return {}
        dt = np.diff(np.asarray(self.times))
        return {"sample_time_mean": float(np.mean(dt)), "sample_time_min": float(np.min(dt)),
                "sample_time_max": float(np.max(dt))}


def _read_state(out: OutputFolder) -> dict[str, Any] | None:
    path = out.path(MANIFEST)
    if not path.exists():
        return None
    try:
        return read_manifest(str(path), path)
    except ExperimentError as exc:
        raise RigError(f"--resume: {exc}") from None


def run_plan(plan: str | Path, port: str, out: str | Path, *, resume: bool = False,
             timeout: float = 10.0, progress: Callable[[int, int, int], None] | None = None,
             **limits: Any) -> RunPlanResult:
    """Run every run of a plan on the rig at ``port`` and write the set into ``out``.

    Parameters
    ----------
    plan : str or Path
        The plan (``phoid design --out``): its folder or manifest.
    port : str
        The rig: ``tcp://HOST:PORT`` or ``serial:///dev/DEVICE[?baud=N]`` (POSIX).
    out : str or Path
        The set's folder (created); its ``experiment.toml`` is rewritten after every run.
    resume : bool
        Continue a set written before: the runs complete or aborted there are kept, the rest
        run. Without it an existing manifest in ``out`` is refused.
    timeout : float
        Seconds to wait for the connection and for each line of the rig.
    progress : callable, optional
        Called as ``progress(run, samples, total)`` while samples arrive.
    **limits
        ``pmax``, ``dmax``, ``hold_p``, ``hold_d``, ``hold``, ``x_limit``, ``u_max``,
        ``growth_limit`` of :func:`plan_configs`.

    Raises
    ------
    RigError
        Bad input, found before anything moves (plan, limits, port, protocol version, a
        configuration the rig refuses): one line.
    """
    sched, configs = plan_configs(plan, **limits)
    folder = OutputFolder(out, overwrite=True, error=RigError)
    state = _read_state(folder)
    if state is not None and not resume:
        raise RigError(f"{folder.path(MANIFEST)} exists already (pass --resume to continue it, "
                       "or choose another --out)")
    rig_state = state.get("rig", {}) if state else {}
    attempts: list[dict[str, Any]] = list(rig_state.get("attempt", []))
    if state is not None and str(rig_state.get("plan")) != str(Path(sched["path"]).resolve()):
        raise RigError(f"--resume: {folder.path(MANIFEST)} was run from another plan "
                       f"({rig_state.get('plan')!r})")
    files = sched["files"]
    status = ["pending"] * len(files)
    for a in attempts:
        i = int(a.get("run", 0)) - 1
        if 0 <= i < len(files) and a.get("status") in ("complete", "aborted"):
            status[i] = a["status"]
    try:
        link = open_port(port, timeout)
    except LinkClosed as exc:
        raise RigError(str(exc)) from None
    messages: list[str] = []
    try:
        link.send(hello())
        try:
            check_hello(parse(_line(link, timeout, "hello")), f"the rig at {port}")
        except ProtocolError as exc:
            raise RigError(str(exc)) from None
        for i, cfg in enumerate(configs):
            if status[i] != "pending":
                continue
            link.send(encode_config(cfg))
            reply = parse(_line(link, timeout, "the reply to CONFIG"))
            if reply.kind == "ERROR":
                raise RigError(f"the rig refused run {i + 1} ({files[i]}): "
                               f"{reply.fields['message']}")
            if reply.kind != "OK":
                raise RigError(f"the rig answered CONFIG with {reply.kind}, not OK")
            attempt, msg, stop, alive = _one_run(link, folder, i, files[i], cfg, timeout,
                                                 progress)
            attempts.append(attempt)
            status[i] = attempt["status"]
            _write_manifest(folder, sched, configs, attempts, status)
            if stop is not None:  # Ctrl-C: the samples and the manifest are on disk first
                raise stop
            if msg:
                messages.append(msg)
            if not alive:
                break  # the link failed: stop; --resume runs the rest
            if any(e.startswith("fault-") for e in attempt["events"]):  # latched: clear it
                link.send(encode("CLEAR"))
                reply = parse(_line(link, timeout, "the reply to CLEAR"))
                if reply.kind != "OK":
                    raise RigError(f"the rig did not clear its fault after run {i + 1}: "
                                   f"{reply.fields.get('message', reply.kind)}")
        with contextlib.suppress(LinkClosed):  # the link may be gone after a failed run
            link.send(encode("BYE"))
    except LinkClosed as exc:
        raise RigError(str(exc)) from None
    finally:
        link.close()
    return RunPlanResult(folder.path(MANIFEST), tuple(status), tuple(messages))


def _line(link: Link, timeout: float, what: str) -> bytes:
    line = link.readline(timeout)
    if line is None:
        raise RigError(f"the rig sent nothing for {timeout:g} s (waiting for {what})")
    return line


def _one_run(link: Link, folder: OutputFolder, i: int, name: str, cfg: Mapping[str, Any],
             timeout: float, progress: Callable | None
             ) -> tuple[dict[str, Any], str, BaseException | None, bool]:
    """START one run and stream it.

    Returns the attempt's record, a message when it did not complete, an interruption
    (KeyboardInterrupt, …) to raise once the record is written, and whether the link still
    works (a damaged line or a sample gap leaves it working: the run's record is incomplete,
    every other sample is kept; a dropped connection, a timeout or an error does not).
    """
    run = _Run(folder, name)
    total = int(cfg["hold_samples"]) + int(cfg["run_samples"]) + 1
    link.send(encode("START"))
    reason, end = "", ""
    damaged = ""  # the first damaged line or gap: the run goes on, its record is incomplete
    stop: BaseException | None = None
    try:
        while True:
            line = link.readline(timeout)
            if line is None:
                reason = f"the rig sent nothing for {timeout:g} s"
                break
            try:
                msg = parse(line)
            except ProtocolError as exc:  # keep reading: every later sample is kept
                damaged = damaged or f"{exc} (after sample {run.last_index})"
                continue
            if msg.kind == "SAMPLE":
                idx = int(msg.fields["index"])
                if idx != run.last_index + 1:
                    damaged = damaged or f"sample gap: index {idx} after {run.last_index}"
                run.last_index = idx
                mixed = run.sample(msg.fields)
                damaged = damaged or mixed
                if progress is not None and idx % 50 == 0:
                    progress(i + 1, idx, total)
            elif msg.kind == "EVENT":
                f = msg.fields
                run.events.append(f"{f['name']} {f['index']} {float(f['value'])!r}")
            elif msg.kind == "END":
                end = str(msg.fields["reason"])
                break
            elif msg.kind == "ERROR":
                reason = f"the rig reported an error: {msg.fields['message']}"
                break
            else:
                reason = f"unexpected {msg.kind} during the run"
                break
    except LinkClosed as exc:
        reason = str(exc)
    except BaseException as exc:  # Ctrl-C: keep what arrived, then re-raise
        reason = f"interrupted on the host ({type(exc).__name__})"
        stop = exc
    alive = not reason  # the link still works: the plan can go on
    if reason:  # the link failed: ask the rig to stop, keep what arrived
        try:
            link.send(encode("ABORT", 1.0))
        except LinkClosed:
            pass
    if reason or damaged:
        reason = reason if not damaged else (f"{damaged}; {reason}" if reason else damaged)
        status, target = "incomplete", f"{Path(name).stem}.incomplete.csv"
    elif end == "done":
        status, target = "complete", name
    else:
        status, target = "aborted", f"{Path(name).stem}.aborted.csv"
        fault = next((e for e in run.events if e.startswith(end)), end)
        reason = f"the controller aborted: {fault}"
    if progress is not None and stop is None:
        try:
            progress(i + 1, run.last_index + 1, total)
        except BaseException as exc:  # Ctrl-C here too: record the run first
            stop = exc
    written = run.finish(target)
    attempt = {"run": i + 1, "file": written, "P": cfg["P"], "D": cfg["D"], "status": status,
               "samples": run.samples, "received": run.last_index + 1,
               "u_source": run.u_source or "command",
               "events": run.events, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
               **run.timing()}
    if reason:
        attempt["reason"] = reason
    msg = "" if status == "complete" else (
        f"run {i + 1} ({name}) {status}: {reason}; its {run.samples} samples are in {written}")
    T = float(cfg["sample_time"])
    if "sample_time_mean" in attempt and (
            abs(attempt["sample_time_mean"] - T) > 1e-3 * T
            or max(T - attempt["sample_time_min"], attempt["sample_time_max"] - T) > 0.1 * T):
        late = (f"run {i + 1} ({name}): the rig's sample intervals were "
                f"{attempt['sample_time_min']:.6g}–{attempt['sample_time_max']:.6g} s (mean "
                f"{attempt['sample_time_mean']:.6g} s), not T = {T:g} s; the digital loop's "
                "model assumes a fixed period")
        msg = f"{msg}; {late}" if msg else late
    return attempt, msg, stop, alive


def _write_manifest(folder: OutputFolder, sched: Mapping[str, Any],
                    configs: list[dict[str, Any]], attempts: list[dict[str, Any]],
                    status: list[str]) -> None:
    cfg0 = configs[0]
    runs = []
    for a in sorted(attempts, key=lambda a: int(a["run"])):  # plan order
        if a["status"] == "complete":
            runs.append({"file": a["file"], "P": a["P"], "D": a["D"],
                         **{f"rig_{k}": a[k] for k in ("sample_time_mean", "sample_time_max")
                            if k in a}})
    doc: dict[str, Any] = {
        "title": f"phoid run: {sum(s == 'complete' for s in status)} of {len(status)} runs of "
                 f"{sched['path']}",
        "format": "phoid/1", "method": "pho",
        "loop": {"sample_time": cfg0["sample_time"], "delay_samples": cfg0["delay_samples"],
                 "velocity": "backward-difference"},
        "rig": {"tool": "phoid run", "protocol": 1, "plan": str(Path(sched["path"]).resolve()),
                "complete": all(s == "complete" for s in status),
                "hold_P": cfg0["hold_P"], "hold_D": cfg0["hold_D"],
                "hold_samples": cfg0["hold_samples"], "x_start": cfg0["x_start"],
                "attempt": attempts},
    }
    if sched.get("design"):
        doc["design"] = sched["design"]
    if runs:
        doc["run"] = runs
    folder.write(MANIFEST, tomli_w.dumps(doc).encode())
