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

Each run's configuration: T = 1/fs, the plan's P and D, K = G = 1, backward-difference
velocity, d = Δt/T whole samples of command delay (the plan's ``[loop] delay``), the hold at
the plan's release amplitude A with a stiff, about critically damped loop on the plan's prior
(hold_P = 3 k, hold_D = 2√(m (k + hold_P)) − c, at least 0) for about seven of its slowest time
constants, position limits ±3A and the growth bound 2.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import secrets
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError, PhoidError
from phoid.io.limits import MAX_LINES, MAX_MANIFEST_BYTES, MAX_SET_ROWS
from phoid.io.manifest import read_manifest
from phoid.planning.schedule import read_schedule
from phoid.rig.link import Link, LinkClosed, connect, open_serial
from phoid.rig.protocol import ProtocolError, check_hello, encode, encode_config, hello, parse

__all__ = ["RigError", "RunPlanResult", "open_port", "parse_port", "plan_configs", "run_plan"]

MANIFEST = "experiment.toml"
# the limits of the host (docs/rig-protocol.md, "Limits of the host")
MAX_COUNT = 2**31 - 1  # samples of one run, hold + run + 1: a C long of 32 bits (an MCU's)
MAX_DELAY = 2**15 - 1  # samples of command delay: a C int of 16 bits
MIN_SAMPLE_TIME = 1e-9  # s: the controller's shortest sample time
MAX_TIMEOUT = 86400.0  # s: the longest --timeout (a day)
MAX_DAMAGED = 100  # damaged lines (checksum, syntax, too long) in a run before the link is given up
EXTRA_EVENTS = 64  # EVENT lines a run may bring beyond one per sample
STORED_EVENTS = 64  # events recorded per attempt; the rest are counted (events_dropped)
EVENT_CHARS = 96  # the longest event text recorded, characters
REASON_CHARS = 400  # the longest reason recorded (and printed), characters
LINE_BYTES = 160  # bytes per line in a run's deadline on a serial line
LINE_TIME = 1e-4  # s per sample in a run's deadline for the host's and a fast rig's own work
_DIGITS = re.compile(r"[0-9]{1,9}")
_RANK = {"idle": 0, "hold": 0, "run": 1, "done": 2, "fault": 2}  # the order of the states


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
    if "://" in text or not sep or not host or not _DIGITS.fullmatch(num) \
            or not 0 < int(num) < 65536:
        raise RigError(f"--port must be tcp://HOST:PORT or serial:///dev/DEVICE[?baud=N] "
                       f"(port 1 to 65535); got {_clip(port, 200)!r}")
    return host.strip("[]"), int(num)


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
                           f"got {_clip(port, 200)!r}")
        return open_serial(path, int(val) if query else 115200, timeout)
    host, num = parse_port(port)
    return connect(host, num, timeout)


def _clip(text: object, limit: int) -> str:
    """``text`` as one line of printable ASCII (the rest escaped), at most ``limit`` characters."""
    line = "".join(ch if " " <= ch <= "~" else ch.encode("unicode_escape").decode("ascii")
                   for ch in " ".join(str(text)[:limit + 1].split()))
    return line if len(line) <= limit else line[:limit - 3] + "..."


def _option(name: str, value: Any, ok: Callable[[float], bool], what: str) -> float:
    """``value`` as a float when it is a finite number with ``ok(value)``; else one RigError."""
    try:
        num = math.nan if isinstance(value, (bool, str)) else float(value)
    except (TypeError, ValueError, OverflowError):
        num = math.nan
    if not (math.isfinite(num) and ok(num)):
        raise RigError(f"{name} must be {what}; got {_clip(value, 60)}; nothing was sent")
    return num


def _options(pmax: Any, dmax: Any, hold_p: Any, hold_d: Any, hold: Any, x_limit: Any,
             u_max: Any, growth_limit: Any) -> dict[str, float | None]:
    """Every limit option checked (finite, in range), by its name; one RigError otherwise."""
    checks: dict[str, tuple[str, Any, Callable[[float], bool], str]] = {
        "pmax": ("--pmax", pmax, lambda v: v >= 0, "a finite number >= 0 (N/m)"),
        "dmax": ("--dmax", dmax, lambda v: v >= 0, "a finite number >= 0 (N s/m)"),
        "hold_p": ("--hold-p", hold_p, lambda v: v > 0, "a finite number > 0 (N/m)"),
        "hold_d": ("--hold-d", hold_d, lambda v: v >= 0, "a finite number >= 0 (N s/m)"),
        "hold": ("--hold", hold, lambda v: v > 0, "a finite number of seconds > 0"),
        "x_limit": ("--x-limit", x_limit, lambda v: v > 0, "a finite number > 0 (m)"),
        "u_max": ("--u-max", u_max, lambda v: v > 0, "a finite number > 0 (N)"),
        "growth_limit": ("growth_limit", growth_limit, lambda v: v == 0 or v >= 1,
                         "0 (off) or a finite number >= 1"),
    }
    return {key: None if val is None else _option(name, val, ok, what)
            for key, (name, val, ok, what) in checks.items()}


def _prior_value(prior: Mapping[str, Any], key: str, pick: Callable, least: float
                 ) -> float | None:
    """The prior's ``key`` (a value or ``[lo, hi]`` through ``pick``) when finite and > least."""
    val = prior.get(key)
    if isinstance(val, list) and len(val) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in val):
        val = float(pick([float(v) for v in val]))  # overflow: inf, refused below
    if isinstance(val, (int, float)) and not isinstance(val, bool) and math.isfinite(val) \
            and val > least:
        return float(val)
    return None


def _variant(name: str, kind: str) -> str:
    """``run03.csv`` → ``run03.KIND.csv`` (``aborted``, ``incomplete``)."""
    return f"{name[:-4]}.{kind}{name[-4:]}"


def _check_names(manifest: Path, files: list[str]) -> None:
    """The plan's file names: plain ``*.csv`` names, none the same as another's or a variant."""
    seen: dict[str, int] = {}
    for i, name in enumerate(files, start=1):
        if (not name.lower().endswith(".csv") or len(name) > 200 or name.startswith(".")
                or any(ch in name for ch in "/\\:") or not name.isprintable()
                or name.lower() in (".csv", MANIFEST)):
            raise RigError(f"{manifest}: run {i}: file {_clip(name, 80)!r} must be a plain file "
                           "name ending in .csv (no folder, not hidden, at most 200 "
                           "characters); nothing was sent")
        for each in (name, _variant(name, "aborted"), _variant(name, "incomplete")):
            other = seen.setdefault(each.casefold(), i)
            if other != i:
                raise RigError(f"{manifest}: runs {other} and {i} would both write "
                               f"{_clip(each, 80)!r}; give each run its own file name")


def plan_configs(plan: str | Path, *, pmax: float | None = None, dmax: float | None = None,
                 hold_p: float | None = None, hold_d: float | None = None,
                 hold: float | None = None, x_limit: float | None = None,
                 u_max: float | None = None, growth_limit: float = 2.0
                 ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The plan and each run's controller configuration (CONFIG fields); nothing is sent.

    Every option must be finite and in its range, and what the plan and the options make
    must fit the controller and the reader (docs/rig-protocol.md, "Limits of the host").

    Returns
    -------
    (plan, configs)
        ``plan``: the schedule (:func:`phoid.planning.read_schedule`) with ``path``,
        ``delay_samples``, ``design`` (its ``[design]`` table); ``configs``: one dict of
        CONFIG fields per run.

    Raises
    ------
    RigError
        One line naming the option, or the plan, run and field: an option that is not a
        finite number in its range, no plan, not a plan, no ``fs``, a delay that is not a
        whole number of samples, a gain beyond ``pmax``/``dmax``, a run too long.
    """
    opts = _options(pmax, dmax, hold_p, hold_d, hold, x_limit, u_max, growth_limit)
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
    _check_names(manifest, sched["files"])
    fs, amp = sched["fs"], sched["amplitude"]
    T = 1.0 / fs
    if not (math.isfinite(T) and MIN_SAMPLE_TIME <= T <= MAX_TIMEOUT):
        raise RigError(f"{manifest}: [design] fs = {fs:g} Hz: the sample time 1/fs must be "
                       f"from {MIN_SAMPLE_TIME:g} s to {MAX_TIMEOUT:g} s (a day)")
    delay = sched["delay"] if sched["delay"] is not None else 0.0
    ds = delay * fs
    if not (math.isfinite(ds) and ds <= MAX_DELAY):
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is more than {MAX_DELAY} "
                       f"samples at fs = {fs:g} Hz")
    d = round(ds)
    if abs(d - ds) > 1e-6 * max(1.0, d):
        raise RigError(f"{manifest}: [loop] delay = {delay:g} s is not a whole number of "
                       f"samples at fs = {fs:g} Hz (T = {T:g} s); design with --delay d/fs")
    for i, (P, D) in enumerate(zip(sched["P"], sched["D"], strict=True), start=1):
        if opts["pmax"] is not None and abs(P) > opts["pmax"]:
            raise RigError(f"{manifest}: run {i}: |P| = {abs(P):g} N/m exceeds the rig's limit "
                           f"--pmax {opts['pmax']:g}; nothing was sent")
        if opts["dmax"] is not None and abs(D) > opts["dmax"]:
            raise RigError(f"{manifest}: run {i}: |D| = {abs(D):g} N·s/m exceeds the rig's "
                           f"limit --dmax {opts['dmax']:g}; nothing was sent")
    prior = design.get("prior") if isinstance(design.get("prior"), Mapping) else {}
    m = _prior_value(prior, "m", lambda v: math.sqrt(abs(v[0] * v[1])), 0.0) or 1.0
    c = _prior_value(prior, "c", min, -math.inf) or 0.0
    k = _prior_value(prior, "k", max, -math.inf) or 0.0
    k = max(k, 0.0)
    with np.errstate(all="ignore"):
        hP = 3.0 * k if opts["hold_p"] is None else opts["hold_p"]
        if opts["hold_p"] is None and not hP + k > 0:
            hP = 16.0 * m
        hD = max(0.0, 2.0 * math.sqrt(m * (k + hP)) - c) if opts["hold_d"] is None \
            else opts["hold_d"]
        hold_s = opts["hold"]
        if hold_s is None:
            slow = 1.0
            coef = [m, c + hD, k + hP]
            if all(math.isfinite(v) for v in coef):
                poles = np.roots(coef)
                if poles.size and np.all(np.isfinite(poles)) and np.all(poles.real < 0):
                    slow = float(np.min(np.abs(poles.real)))
            hold_s = min(30.0, max(0.5, 7.0 / slow))
    n_hold, n_run = hold_s * fs, sched["duration"] * fs
    most = min(MAX_COUNT - 2, MAX_LINES - 1)  # the controller's count; the reader's rows
    if not (math.isfinite(n_run) and round(n_run) <= most):
        raise RigError(f"{manifest}: [design] duration = {sched['duration']:g} s at fs = "
                       f"{fs:g} Hz is {n_run:.6g} samples; a run holds at most {most}")
    n_run = max(2, round(n_run))
    if not (math.isfinite(n_hold) and round(n_hold) + n_run + 1 <= MAX_COUNT):
        what = "--hold" if opts["hold"] is not None else "the default --hold"
        raise RigError(f"{what} {hold_s:g} s at fs = {fs:g} Hz is {n_hold:.6g} samples; with "
                       f"the run's {n_run} the hold, run and last sample must be at most "
                       f"{MAX_COUNT} (a 32-bit count); nothing was sent")
    if n_run * len(sched["files"]) > MAX_SET_ROWS:
        raise RigError(f"{manifest}: {len(sched['files'])} runs of {n_run} samples are more "
                       f"rows than phoid reads in one set ({MAX_SET_ROWS})")
    x_lim = 3.0 * amp if opts["x_limit"] is None else opts["x_limit"]
    if not (math.isfinite(x_lim) and x_lim > amp):
        what = "--x-limit" if opts["x_limit"] is not None else "the default --x-limit (3 A)"
        raise RigError(f"{what} {x_lim:g} m must be finite and larger than the plan's release "
                       f"amplitude A ([design] amplitude = {amp:g} m); nothing was sent")
    base = {
        "sample_time": T, "gain": 1.0, "command_gain": 1.0, "velocity": 0, "delay_samples": d,
        "hold_P": float(hP), "hold_D": float(hD), "x_start": amp,
        "hold_samples": max(1, round(n_hold)), "run_samples": n_run,
        "x_min": -x_lim, "x_max": x_lim, "growth_limit": opts["growth_limit"],
    }
    if opts["u_max"] is not None:
        base["u_max"] = opts["u_max"]
    source = {"hold_P": "--hold-p (default: 3 k of the plan's prior)",
              "hold_D": "--hold-d (default: from the plan's prior m, c, k)"}
    for key, val in base.items():
        if not math.isfinite(val):
            raise RigError(f"{manifest}: the hold loop's {key} = {val} is not finite; set "
                           f"{source.get(key, key)}; nothing was sent")
    configs = [dict(base, P=float(P), D=float(D))
               for P, D in zip(sched["P"], sched["D"], strict=True)]
    sched.update(path=manifest, delay_samples=d, design=dict(design))
    return sched, configs




class _Run:
    """One attempt's bookkeeping and its streamed CSV (a new hidden ``.part`` file)."""

    def __init__(self, out: OutputFolder, name: str, cfg: Mapping[str, Any]) -> None:
        self.out, self.name = out, name
        self.hold, self.run = int(cfg["hold_samples"]), int(cfg["run_samples"])
        self.total = self.hold + self.run + 1
        os.makedirs(out.folder, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
        for _ in range(100):  # a fresh name: never an existing file
            self.part = f".{name}.{secrets.token_hex(4)}.part"
            try:
                fd = os.open(out.path(self.part), flags, 0o666)
                break
            except FileExistsError:
                continue
        else:
            raise RigError(f"{out.folder}: no free temporary name for {name}")
        self.fh: IO[str] = os.fdopen(fd, "w")
        self.fh.write("t,x,u\n")
        self.digest = hashlib.blake2b(b"t,x,u\n", digest_size=32)  # the file's, as the reader's
        self.samples = self.count = 0  # rows written; SAMPLE lines received
        self.last_index, self.last_t, self.rank = -1, None, 0  # rank of the state (_RANK)
        self.states = {"hold": 0, "run": 0, "done": 0, "fault": 0}
        self.dt = [0, 0.0, math.inf, -math.inf]  # intervals: count, sum, min, max
        self.events: list[str] = []
        self.event_lines = self.damaged_lines = 0
        self.damaged = ""  # the first damage: the run goes on, its record is incomplete
        self.faulted = False
        self.u_source = ""  # "measured" (SAMPLE's force) or "command", from the first run sample

    def damage(self, why: str) -> None:
        self.damaged = self.damaged or why

    def sample(self, f: Mapping[str, Any]) -> None:
        """Record one SAMPLE: check its index, time and state; write it when a run sample."""
        self.count += 1
        idx, t, state = int(f["index"]), float(f["t"]), str(f["state"])
        if idx != self.last_index + 1:
            self.damage(f"sample gap: index {idx} after {self.last_index}" if idx > self.last_index
                        else f"sample out of order: index {idx} after {self.last_index}")
        if self.last_t is not None:
            step = t - self.last_t
            if not (math.isfinite(step) and step > 0):
                self.damage(f"the rig's time did not increase at sample {idx}: t = {t!r} s "
                            f"after {self.last_t!r} s")
            if math.isfinite(step):
                n, s, lo, hi = self.dt
                self.dt = [n + 1, s + step, min(lo, step), max(hi, step)]
        if _RANK[state] < self.rank or self.rank == 2:
            self.damage(f"sample {idx} in state {state} after a sample in state "
                        f"{'done or fault' if self.rank == 2 else 'run'}")
        self.last_index, self.last_t, self.rank = idx, t, max(self.rank, _RANK[state])
        self.states["hold" if state == "idle" else state] += 1
        if state != "run":
            return
        source = "measured" if "force" in f else "command"
        if self.u_source and source != self.u_source:
            self.damage(f"sample {idx}: the force field "
                        f"{'appears' if source == 'measured' else 'is missing'} mid-run (u "
                        f"would mix the measured force and the command); the samples "
                        f"{'with' if source == 'measured' else 'without'} it are left out")
            return
        self.u_source = source
        u = float(f["force"] if source == "measured" else f["u"])
        row = f"{t!r},{float(f['x'])!r},{u!r}\n"
        self.fh.write(row)
        self.digest.update(row.encode())
        self.samples += 1
        if self.samples % 100 == 0:
            self.fh.flush()

    def event(self, f: Mapping[str, Any]) -> None:
        self.event_lines += 1
        name = str(f["name"])
        self.faulted = self.faulted or name.startswith("fault-")
        if len(self.events) < STORED_EVENTS:
            self.events.append(_clip(f"{name} {f['index']} {float(f['value'])!r}", EVENT_CHARS))

    def shortfall(self) -> str:
        """Why a run that ended ``done`` is not the run configured ("" when it is)."""
        want = {"hold": self.hold, "run": self.run, "done": 1, "fault": 0}
        if self.count != self.total or self.states != want:
            got = ", ".join(f"{v} {k}" for k, v in self.states.items() if v)
            return (f"the rig ended the run after {self.count} samples ({got or 'none'}); the "
                    f"run configured has {self.total} ({self.hold} hold, {self.run} run, 1 done)")
        return ""

    def finish(self, target: str) -> str:
        """Close the file and move it to ``target``, or a free name if that one is taken."""
        self.fh.flush()
        os.fsync(self.fh.fileno())
        self.fh.close()
        part = self.out.path(self.part)
        stem, suffix = target[:-4], target[-4:]
        for i in range(1, 10000):
            name = target if i == 1 else f"{stem}-{i}{suffix}"
            path = self.out.path(name)
            if path.exists() or path.is_symlink():
                continue
            try:  # a hard link never replaces a file that appeared meanwhile
                os.link(part, path, follow_symlinks=False)
            except FileExistsError:
                continue
            except OSError:  # no hard links on this file system: rename (checked just above)
                os.replace(part, path)
                return name
            os.unlink(part)
            return name
        raise RigError(f"{self.out.folder}: no free name for {target} (samples in {self.part})")

    def timing(self) -> dict[str, float]:
        n, s, lo, hi = self.dt
        if not n or not math.isfinite(s):
            return {}
        return {"sample_time_mean": s / n, "sample_time_min": lo, "sample_time_max": hi}


def _read_state(out: OutputFolder, sched: Mapping[str, Any]) -> list[dict[str, Any]] | None:
    """The attempts of the set in ``out`` (None: no manifest), checked to be this plan's."""
    path = out.path(MANIFEST)
    if not (path.exists() or path.is_symlink()):
        return None
    try:
        doc = read_manifest(str(path), path)
    except ExperimentError as exc:
        raise RigError(f"--resume: {exc}") from None
    rig = doc.get("rig")
    if not isinstance(rig, Mapping) or rig.get("tool") != "phoid run":
        raise RigError(f"{path} exists and is not a set of `phoid run` (no [rig] tool = "
                       "\"phoid run\"); choose another --out")
    if str(rig.get("plan")) != str(Path(sched["path"]).resolve()):
        raise RigError(f"--resume: {path} was run from another plan "
                       f"({_clip(rig.get('plan'), 200)!r})")
    attempts = rig.get("attempt", [])
    if not isinstance(attempts, list):
        raise RigError(f"--resume: {path}: [rig] attempt must be an array of tables")
    n = len(sched["files"])
    for j, a in enumerate(attempts, start=1):
        bad = ""
        if not isinstance(a, Mapping):
            bad = "not a table"
        elif not (isinstance(a.get("run"), int) and 1 <= a["run"] <= n):
            bad = f"run must be a whole number from 1 to {n}"
        elif not isinstance(a.get("file"), str) or a["file"].startswith(".") or any(
                ch in a["file"] for ch in "/\\") or a.get("status") not in (
                "complete", "aborted", "incomplete"):
            bad = "file must be a plain file name and status complete, aborted or incomplete"
        elif a["status"] == "complete" and not all(
                isinstance(a.get(k), (int, float)) and not isinstance(a.get(k), bool)
                and math.isfinite(a[k]) for k in ("P", "D")):
            bad = "a complete attempt needs finite P and D"
        if bad:
            raise RigError(f"--resume: {path}: [[rig.attempt]] {j}: {bad}")
    return [dict(a) for a in attempts]


def _check_targets(folder: OutputFolder, files: list[str], status: list[str],
                   own: set[str]) -> None:
    """Refuse, before anything moves, a file in the way of a run that this set did not write."""
    names = [MANIFEST]
    for name, st in zip(files, status, strict=True):
        if st == "pending":
            names += [name, _variant(name, "aborted"), _variant(name, "incomplete")]
    for name in names[1:]:
        path = folder.path(name)
        if (path.exists() or path.is_symlink()) and name not in own:
            raise RigError(f"{path} exists already and is not a file of this set; phoid run "
                           "never replaces a file (move it away or choose another --out); "
                           "nothing was sent")
    folder.check(names)  # links, folders, special files in the way


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
    **limits
        ``pmax``, ``dmax``, ``hold_p``, ``hold_d``, ``hold``, ``x_limit``, ``u_max``,
        ``growth_limit`` of :func:`plan_configs`.

    Raises
    ------
    RigError
        One line: bad input, found before anything moves (an option, the plan, a file in the
        way, the port, the protocol version), a CONFIG refused, a wrong reply to CONFIG/CLEAR.
    """
    timeout = _option("--timeout", timeout, lambda v: 0 < v <= MAX_TIMEOUT,
                      f"a finite number of seconds > 0 and at most {MAX_TIMEOUT:g}")
    sched, configs = plan_configs(plan, **limits)
    folder = OutputFolder(out, overwrite=True, error=RigError)
    mpath = folder.path(MANIFEST)
    if (mpath.exists() or mpath.is_symlink()) and not resume:
        raise RigError(f"{mpath} exists already (pass --resume to continue it, or choose "
                       "another --out)")
    state = _read_state(folder, sched)
    attempts = state or []
    files = sched["files"]
    status = ["pending"] * len(files)
    for a in attempts:
        if a["status"] in ("complete", "aborted"):
            status[a["run"] - 1] = a["status"]
    _check_targets(folder, files, status, {a["file"] for a in attempts})
    _fits(folder, sched, configs, attempts, status)
    digests = _digests(folder, attempts)
    try:
        link = open_port(port, timeout)
    except LinkClosed as exc:
        raise RigError(str(exc)) from None
    messages: list[str] = []
    try:
        link.send(hello())
        try:
            check_hello(_reply(link, timeout, "hello"), f"the rig at {port}")
        except ProtocolError as exc:
            raise RigError(_clip(exc, REASON_CHARS)) from None
        for i, cfg in enumerate(configs):
            if status[i] != "pending":
                continue
            link.send(encode_config(cfg))
            reply = _reply(link, timeout, "the reply to CONFIG", f"run {i + 1}: ")
            if reply.kind == "ERROR":
                raise RigError(f"the rig refused run {i + 1} ({files[i]}): "
                               f"{_clip(reply.fields['message'], REASON_CHARS)}")
            if reply.kind != "OK":
                raise RigError(f"the rig answered CONFIG of run {i + 1} with {reply.kind}, "
                               "not OK")
            attempt, msg, stop, alive, faulted = _one_run(link, folder, i, files[i], cfg,
                                                          timeout, progress, digests)
            attempts.append(attempt)
            status[i] = attempt["status"]
            _write_manifest(folder, sched, configs, attempts, status)
            if stop is not None:  # Ctrl-C: the samples and the manifest are on disk first
                raise stop
            if msg:
                messages.append(msg)
            if not alive:
                break  # the link failed: stop; --resume runs the rest
            if faulted:  # latched: clear it
                link.send(encode("CLEAR"))
                reply = _reply(link, timeout, "the reply to CLEAR", f"after run {i + 1}: ")
                if reply.kind != "OK":
                    raise RigError(f"the rig did not clear its fault after run {i + 1}: "
                                   f"{_clip(reply.fields.get('message', reply.kind), 200)}")
        with contextlib.suppress(LinkClosed):  # the link may be gone after a failed run
            link.send(encode("BYE"))
    except LinkClosed as exc:
        raise RigError(_clip(exc, REASON_CHARS)) from None
    finally:
        link.close()
    return RunPlanResult(folder.path(MANIFEST), tuple(status), tuple(messages))


def _reply(link: Link, timeout: float, what: str, where: str = "") -> Any:
    """The rig's next line, parsed: within ``timeout`` s and one line, else one RigError."""
    line = link.readline(timeout)
    if line is None:
        raise RigError(f"{where}the rig sent nothing for {timeout:g} s (waiting for {what})")
    try:
        return parse(line)
    except ProtocolError as exc:
        raise RigError(f"{where}the rig's line is damaged (waiting for {what}): "
                       f"{_clip(exc, REASON_CHARS)}") from None


def _digests(folder: OutputFolder, attempts: list[dict[str, Any]]) -> dict[bytes, str]:
    """The complete runs' files by their content's digest (a repeat would be refused)."""
    out: dict[bytes, str] = {}
    for a in attempts:
        path = folder.path(a["file"])
        if a["status"] == "complete" and path.is_file() and not path.is_symlink():
            with contextlib.suppress(OSError), open(path, "rb") as fh:
                out[hashlib.file_digest(fh, lambda: hashlib.blake2b(digest_size=32)).digest()] \
                    = f"run {a['run']} ({_clip(a['file'], 80)})"
    return out


def _one_run(link: Link, folder: OutputFolder, i: int, name: str, cfg: Mapping[str, Any],
             timeout: float, progress: Callable | None, digests: dict[bytes, str]
             ) -> tuple[dict[str, Any], str, BaseException | None, bool, bool]:
    """START one run and stream it: the attempt's record, a message when it did not complete,
    an interruption (Ctrl-C) to raise once the record is written, whether the link still works
    (not after a drop, a timeout, an ERROR, the deadline or a cap) and whether the controller
    faulted (the host then sends CLEAR)."""
    run = _Run(folder, name, cfg)
    T, total = float(cfg["sample_time"]), run.total
    wait = max(timeout, 2.0 * T)  # a rig streaming in real time sends a sample every T
    budget = (timeout + total * (2.0 * T + LINE_TIME)
              + (2 * total + EXTRA_EVENTS + 1) * LINE_BYTES * link.byte_time)
    link.send(encode("START"))
    deadline = time.monotonic() + budget
    reason, end = "", ""
    stop: BaseException | None = None
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                reason = (f"the run did not end within {budget:.4g} s (its {total} samples at "
                          f"T = {T:g} s, and --timeout {timeout:g} s)")
                break
            line = link.readline(min(wait, left))
            if line is None:
                if left > wait:
                    reason = f"the rig sent nothing for {wait:g} s"
                    break
                continue  # the deadline: said at the top
            try:
                msg = parse(line)
            except ProtocolError as exc:  # keep reading: every later sample is kept
                run.damaged_lines += 1
                run.damage(f"{exc} (after sample {run.last_index})")
                if run.damaged_lines > MAX_DAMAGED:
                    reason = f"more than {MAX_DAMAGED} damaged lines in one run"
                    break
                continue
            if msg.kind == "SAMPLE":
                if run.count >= total:
                    reason = (f"the rig sent more than the run's {total} samples ({run.hold} "
                              f"hold, {run.run} run, 1 done)")
                    break
                run.sample(msg.fields)
                if progress is not None and run.count % 50 == 0:
                    progress(i + 1, run.count, total)
            elif msg.kind == "EVENT":
                if run.event_lines >= total + EXTRA_EVENTS:
                    reason = (f"the rig sent more than {total + EXTRA_EVENTS} EVENT lines "
                              f"(one per sample and {EXTRA_EVENTS})")
                    break
                run.event(msg.fields)
            elif msg.kind == "END":
                end = _clip(msg.fields["reason"], EVENT_CHARS)
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
        with contextlib.suppress(LinkClosed):
            link.send(encode("ABORT", 1.0))
    elif end == "done":
        run.damage(run.shortfall())
        if (same := digests.get(run.digest.digest())) is not None:
            run.damage(f"the same samples, byte for byte, as {same}: a repeated recording, "
                       "which phoid identify refuses")
    faulted = run.faulted or end.startswith("fault")
    if reason or run.damaged:
        reason = f"{run.damaged}; {reason}" if run.damaged and reason else run.damaged or reason
        status, target = "incomplete", _variant(name, "incomplete")
    elif end == "done":
        status, target = "complete", name
    else:
        status, target = "aborted", _variant(name, "aborted")
        fault = next((e for e in run.events if e.startswith(end)), end)
        reason = f"the controller aborted: {fault}"
    reason = _clip(reason, REASON_CHARS)
    if progress is not None and stop is None:
        try:
            progress(i + 1, run.count, total)
        except BaseException as exc:  # Ctrl-C here too: record the run first
            stop = exc
    written = run.finish(target)
    if status == "complete":
        digests[run.digest.digest()] = f"run {i + 1} ({written})"
    attempt = {"run": i + 1, "file": written, "P": cfg["P"], "D": cfg["D"], "status": status,
               "samples": run.samples, "received": run.count,
               "u_source": run.u_source or "command",
               "events": run.events, "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
               **run.timing()}
    if run.event_lines > len(run.events):
        attempt["events_dropped"] = run.event_lines - len(run.events)
    if reason:
        attempt["reason"] = reason
    msg = "" if status == "complete" else (
        f"run {i + 1} ({name}) {status}: {reason}; its {run.samples} samples are in {written}")
    if "sample_time_mean" in attempt and (
            abs(attempt["sample_time_mean"] - T) > 1e-3 * T
            or max(T - attempt["sample_time_min"], attempt["sample_time_max"] - T) > 0.1 * T):
        late = (f"run {i + 1} ({name}): the rig's sample intervals were "
                f"{attempt['sample_time_min']:.6g}–{attempt['sample_time_max']:.6g} s (mean "
                f"{attempt['sample_time_mean']:.6g} s), not T = {T:g} s; the digital loop's "
                "model assumes a fixed period")
        msg = f"{msg}; {late}" if msg else late
    return attempt, msg, stop, alive, faulted


def _compose(sched: Mapping[str, Any], configs: list[dict[str, Any]],
             attempts: list[dict[str, Any]], status: list[str], keep: int) -> bytes:
    """The manifest's bytes, with at most ``keep`` events recorded per attempt."""
    cfg0 = configs[0]
    done: dict[int, dict[str, Any]] = {}
    shown = []
    for a in attempts:
        events = a.get("events", [])
        if isinstance(events, list) and len(events) > keep:
            dropped = a.get("events_dropped") if type(a.get("events_dropped")) is int else 0
            a = dict(a, events=events[:keep], events_dropped=dropped + len(events) - keep)
        shown.append(a)
        if a["status"] == "complete":
            done[int(a["run"])] = a  # the last complete attempt of each run
    runs = [{"file": a["file"], "P": a["P"], "D": a["D"],
             **{f"rig_{k}": a[k] for k in ("sample_time_mean", "sample_time_max") if k in a}}
            for _, a in sorted(done.items())]
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
                "attempt": shown},
    }
    if sched.get("design"):
        doc["design"] = sched["design"]
    if runs:
        doc["run"] = runs
    return tomli_w.dumps(doc).encode()


_KEEP = (STORED_EVENTS, 8, 0)  # events kept per attempt, tried in turn until the manifest fits


def _write_manifest(folder: OutputFolder, sched: Mapping[str, Any],
                    configs: list[dict[str, Any]], attempts: list[dict[str, Any]],
                    status: list[str]) -> None:
    for keep in _KEEP:
        data = _compose(sched, configs, attempts, status, keep)
        if len(data) <= MAX_MANIFEST_BYTES:
            break
    folder.write(MANIFEST, data)


def _fits(folder: OutputFolder, sched: Mapping[str, Any], configs: list[dict[str, Any]],
          attempts: list[dict[str, Any]], status: list[str]) -> None:
    """Refuse, before anything moves, a set whose manifest could outgrow the reader's limit
    (each run to do counted with its largest record; :func:`_write_manifest` cuts events)."""
    worst = list(attempts)
    for i, (name, st) in enumerate(zip(sched["files"], status, strict=True)):
        if st == "pending":
            big = -1.2345678901234567e-300
            worst.append({
                "run": i + 1, "file": '"' * (len(name.encode()) + 20), "P": big, "D": big,
                "status": "complete", "samples": MAX_COUNT, "received": MAX_COUNT,
                "u_source": "measured", "events": [], "events_dropped": MAX_COUNT,
                "time": "2000-01-01T00:00:00Z", "sample_time_mean": big,
                "sample_time_min": big, "sample_time_max": big,
                "reason": '"' * (REASON_CHARS + 8)})
    size = len(_compose(sched, configs, worst, ["incomplete"] * len(status), 0))
    if size + 4096 > MAX_MANIFEST_BYTES:
        raise RigError(f"{folder.path(MANIFEST)}: the set's manifest could grow to {size} bytes, "
                       f"more than the {MAX_MANIFEST_BYTES // 2**20} MiB phoid reads (a plan of "
                       f"{len(status)} runs, its [design] table and the attempts recorded); "
                       "split the plan; nothing was sent")
