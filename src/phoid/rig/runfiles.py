"""The set's files on the host's side: each run's streamed CSV, the manifest, a resume's state.

:class:`RunFile` streams one attempt's samples into a new hidden ``.part`` file, checks the
stream against the run configured and moves the file to its name when the run ends;
:func:`write_manifest` rewrites ``experiment.toml`` (atomically) after every attempt
(docs/format.md, "Keys written by `phoid run`"); :func:`read_state` and :func:`check_resumed`
read and check the set a ``--resume`` continues; :func:`check_targets`, :func:`check_size` and
:func:`check_writable` refuse, before anything moves, a file in the way, a manifest that could
outgrow the reader's limit and a folder phoid cannot write its files in.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import secrets
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError
from phoid.io.limits import MAX_MANIFEST_BYTES
from phoid.io.manifest import read_manifest
from phoid.rig.checks import MANIFEST, MAX_COUNT, RigError, clip, variant
from phoid.rig.native import VELOCITIES

__all__ = [
    "EVENT_CHARS",
    "REASON_CHARS",
    "RunFile",
    "check_resumed",
    "check_size",
    "check_targets",
    "check_writable",
    "compose",
    "read_state",
    "write_manifest",
]

STORED_EVENTS = 64  # events recorded per attempt; the rest are counted (events_dropped)
EVENT_CHARS = 96  # the longest event text recorded, characters
REASON_CHARS = 400  # the longest reason recorded (and printed), characters
CLOCK_TOLERANCE = 0.1  # a run whose mean or median interval is further from T is incomplete
FLUSH_ROWS = 256  # rows written to the file at a time
STEPS_KEPT = 64  # the file's first intervals kept for their median (as identify reads them)
DIGEST = "blake2b-256"  # the content digest a complete attempt records (its file's bytes)
MAX_VALUE = 1e100  # the largest |u| recorded (what phoid identify squares without overflow)
_RANK = {"idle": 0, "hold": 0, "run": 1, "done": 2, "fault": 2}  # the order of the states


class RunFile:
    """One attempt's bookkeeping and its streamed CSV (a new hidden ``.part`` file)."""

    def __init__(self, out: OutputFolder, name: str, cfg: Mapping[str, Any]) -> None:
        self.out, self.name = out, name
        self.hold, self.run = int(cfg["hold_samples"]), int(cfg["run_samples"])
        self.T = float(cfg["sample_time"])
        lo, hi = float(cfg["x_min"]), float(cfg["x_max"])  # the controller's limits
        self.x_limits = (lo, hi)
        self.x_range = (lo - (hi - lo), hi + (hi - lo))  # with their span again as a margin
        self.total = self.hold + self.run + 1
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
        for _ in range(100):  # a fresh name: never an existing file
            self.part = f".{name}.{secrets.token_hex(4)}.part"
            try:
                os.makedirs(out.folder, exist_ok=True)
                fd = os.open(out.path(self.part), flags, 0o666)
                break
            except FileExistsError:
                continue
            except OSError as exc:
                raise RigError(f"cannot create {out.path(self.part)}: "
                               f"{exc.strerror or exc}") from None
        else:
            raise RigError(f"{out.folder}: no free temporary name for {name}")
        self.fd = fd
        self.pending = ["t,x,u\n"]  # rows not yet written (written every FLUSH_ROWS)
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
        self.error = ""  # the file could not be written: the run stops, the plan too
        self.written = [0, 0]  # bytes and rows on disk
        self.bytes = 6  # bytes of the rows taken (written or pending)
        self.steps: list[float] = []  # the file's first intervals (identify's sample step)
        self.last_row_t: float | None = None

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
        if state in ("hold", "idle", "run"):
            self.check_values(idx, f)
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
        if self.error:
            return
        self.pending.append(row)
        self.bytes += len(row)  # ASCII: characters are bytes
        self.digest.update(row.encode())
        self.samples += 1
        if len(self.pending) >= FLUSH_ROWS:
            self._write()
        if self.last_row_t is not None and len(self.steps) < STEPS_KEPT:
            self.steps.append(t - self.last_row_t)
        self.last_row_t = t

    def check_values(self, idx: int, f: Mapping[str, Any]) -> None:
        """A sample the controller streams without a fault has a finite force and its x
        within the configured limits (the span of [x_min, x_max] again as a margin for the
        sample that trips the fault and for sensor noise): anything else is not the run
        configured."""
        x, lo, hi = float(f["x"]), *self.x_range
        if not lo <= x <= hi:
            self.damage(f"sample {idx}: x = {x!r} m, beyond the configured limits "
                        f"[{self.x_limits[0]:g}, {self.x_limits[1]:g}] m (and their span again) "
                        "without a fault")
        for key in ("u", "force"):
            if key in f and not abs(float(f[key])) <= MAX_VALUE:
                self.damage(f"sample {idx}: {key} = {float(f[key])!r} N, not a finite force "
                            f"of at most {MAX_VALUE:g} N")

    def event(self, f: Mapping[str, Any]) -> None:
        self.event_lines += 1
        name = str(f["name"])
        self.faulted = self.faulted or name.startswith("fault-")
        if len(self.events) < STORED_EVENTS:
            self.events.append(clip(f"{name} {f['index']} {float(f['value'])!r}", EVENT_CHARS))

    def shortfall(self) -> str:
        """Why a run that ended ``done`` is not the run configured ("" when it is)."""
        want = {"hold": self.hold, "run": self.run, "done": 1, "fault": 0}
        if self.count != self.total or self.states != want:
            got = ", ".join(f"{v} {k}" for k, v in self.states.items() if v)
            return (f"the rig ended the run after {self.count} samples ({got or 'none'}); the "
                    f"run configured has {self.total} ({self.hold} hold, {self.run} run, 1 done)")
        return ""

    def clock(self) -> str:
        """Why the rig's clock is not the configured period T ("" when it is): the mean
        interval, or the median of the file's first intervals (what ``phoid identify`` takes
        as the records' sample step), more than :data:`CLOCK_TOLERANCE` away from T."""
        n, s, _, _ = self.dt
        mean = s / n if n and math.isfinite(s) else math.nan
        mid = sorted(self.steps)[len(self.steps) // 2] if self.steps else mean
        for what, val in (("mean", mean), ("median", mid)):
            if not abs(val - self.T) <= CLOCK_TOLERANCE * self.T:
                return (f"the rig's sample intervals have a {what} of {val:.6g} s, not the "
                        f"configured T = {self.T:g} s (more than {CLOCK_TOLERANCE:.0%} off: a "
                        "clock in other units, or a rig not running the configured loop)")
        return ""

    def _write(self) -> None:
        """Write the pending rows; on failure :attr:`error` names the file and why."""
        data = memoryview("".join(self.pending).encode())
        self.pending = []
        try:
            while data:
                n = os.write(self.fd, data)
                data = data[n:]
        except OSError as exc:
            self.error = f"cannot write {self.out.path(self.part)}: {exc.strerror or exc}"
            return
        self.written = [self.bytes, self.samples]

    def close(self) -> None:
        """Write the rest, flush the file to disk and close it; when that fails, or a write
        failed before, :attr:`error` says so and the file is cut back to its last row written
        whole (:attr:`samples` then counts the rows it holds)."""
        if not self.error:
            self._write()
        if not self.error:
            try:
                os.fsync(self.fd)
            except OSError as exc:
                self.error = f"cannot write {self.out.path(self.part)}: {exc.strerror or exc}"
        if self.error:
            self.bytes, self.samples = self.written
            with contextlib.suppress(OSError):  # a cut frees space: it needs none
                os.ftruncate(self.fd, self.bytes)
        with contextlib.suppress(OSError):
            os.close(self.fd)
        self.fd = -1

    def finish(self, target: str) -> str:
        """Move the closed file to ``target``, or a free name if that one is taken (an
        ``OSError`` when it cannot be moved; :meth:`discard` then removes it)."""
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

    def discard(self) -> None:
        """Remove the hidden file (a run that cannot be kept: nothing hidden is left)."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = -1
        with contextlib.suppress(OSError):
            os.unlink(self.out.path(self.part))

    def timing(self) -> dict[str, float]:
        n, s, lo, hi = self.dt
        if not n or not math.isfinite(s):
            return {}
        return {"sample_time_mean": s / n, "sample_time_min": lo, "sample_time_max": hi}


def read_state(out: OutputFolder, sched: Mapping[str, Any]
               ) -> tuple[list[dict[str, Any]], dict[str, Any]] | None:
    """The attempts of the set in ``out`` and the configuration it recorded (None: no
    manifest), checked to be this plan's (:func:`check_resumed` checks the rest)."""
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
                       f"({clip(rig.get('plan'), 200)!r})")
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
    config = rig.get("config")
    if isinstance(config, Mapping):
        recorded = dict(config)
    else:  # a set written before [rig.config]: what its [loop] and [rig] record
        loop = doc.get("loop") if isinstance(doc.get("loop"), Mapping) else {}
        recorded = {k: loop[k] for k in ("sample_time", "delay_samples") if k in loop}
        recorded.update({k: rig[k] for k in ("hold_P", "hold_D", "hold_samples", "x_start")
                         if k in rig})
    return [dict(a) for a in attempts], recorded


# where each CONFIG field comes from, to name what changed between sessions
_SOURCE = {"sample_time": "the plan's [loop] sample_time or [design] fs",
           "delay_samples": "the plan's [loop] delay_samples or delay",
           "hold_P": "--hold-p, or the plan's prior", "hold_D": "--hold-d, or the plan's prior",
           "hold_samples": "--hold, or the plan's fs and prior",
           "run_samples": "the plan's [design] duration and fs",
           "x_start": "the plan's [design] amplitude and prior k, or --hold-p",
           "x_min": "--x-limit, or the plan's [design] amplitude",
           "x_max": "--x-limit, or the plan's [design] amplitude", "u_max": "--u-max",
           "growth_limit": "the growth limit", "gain": "the host's loop gain K",
           "command_gain": "the host's command gain G",
           "velocity": "the plan's [loop] velocity", "filter_pole": "the plan's [loop] cutoff",
           "P": "the plan's [[run]] P",
           "D": "the plan's [[run]] D"}


def _same(was: Any, now: Any) -> bool:
    """Two recorded values the same (numbers to 1e-12, TOML's round trip is exact)."""
    if was is None or now is None:
        return was is None and now is None
    if isinstance(was, bool) or not isinstance(was, (int, float)):
        return False
    return was == now or math.isclose(was, now, rel_tol=1e-12, abs_tol=0.0)


def check_resumed(folder: OutputFolder, sched: Mapping[str, Any], configs: list[dict[str, Any]],
                  attempts: list[dict[str, Any]], recorded: Mapping[str, Any]
                  ) -> dict[bytes, str]:
    """Refuse, before anything moves, a resume the set cannot take: a configuration other
    than the one recorded (the plan or an option changed between sessions), or a run
    recorded complete whose file is not that run's file as it was written.

    A complete run's file must be a regular file (no link, folder or special file) in
    ``folder``, named as the plan names the run (or a later free name of it, ``-2``, …), the
    file of no other attempt, and — when the attempt records its ``digest`` — the same bytes.

    Returns
    -------
    dict
        The complete runs' files by their content's digest (a repeat would be refused).
    """
    path = folder.path(MANIFEST)
    cfg0 = configs[0]
    keys = [k for k in _SOURCE if k not in ("P", "D")]
    if "run_samples" in recorded and (extra := [k for k in recorded if k not in keys]):
        raise RigError(f"--resume: {path}: [rig.config] has {clip(extra[0], 40)!r}, which "
                       "phoid run never sends (the table is the CONFIG every run was sent: "
                       f"{', '.join(keys)}); nothing was sent")
    for key in keys if "run_samples" in recorded else list(recorded):
        was, now = recorded.get(key), cfg0.get(key)
        if was is not None and (isinstance(was, bool) or not isinstance(was, (int, float))):
            raise RigError(f"--resume: {path}: [rig.config] {key} = {clip(repr(was), 40)} is "
                           "not a number; nothing was sent")
        if not _same(was, now):
            raise RigError(f"--resume: {path} was recorded with {key} = {clip(was, 40)}, but "
                           f"the plan and options now give {key} = "
                           f"{'none' if now is None else f'{now:g}'} ({_SOURCE[key]} changed); "
                           "a set is one configuration: run the changed plan into another "
                           "--out; nothing was sent")
    for j, a in enumerate(attempts, start=1):
        for key in ("P", "D"):
            now = configs[a["run"] - 1][key]
            if key in a and not _same(a[key], now):
                raise RigError(f"--resume: {path}: [[rig.attempt]] {j} ran run {a['run']} with "
                               f"{key} = {clip(a[key], 40)}, but the plan now gives {now:g} "
                               f"({_SOURCE[key]} changed); run the changed plan into another "
                               "--out; nothing was sent")
    last = {a["run"]: a for a in attempts if a["status"] == "complete"}
    out: dict[bytes, str] = {}
    for run, a in sorted(last.items()):
        name, planned = a["file"], sched["files"][run - 1]
        later = re.escape(planned[:-4]) + r"-[0-9]{1,4}" + re.escape(planned[-4:])
        others = [j for j, b in enumerate(attempts, start=1) if b is not a
                  and b["file"].casefold() == name.casefold()
                  and not (b["run"] == run and b["status"] == "complete")]
        what, digest = "", None
        if name != planned and not re.fullmatch(later, name):
            what = f"is not the file the plan names for run {run} ({clip(planned, 80)!r})"
        elif others:
            what = f"is also the file of [[rig.attempt]] {others[0]}"
        else:
            what, digest = _file_digest(folder.path(name))
            recorded_digest = a.get("digest")
            if recorded_digest is not None and not (
                    isinstance(recorded_digest, str)
                    and re.fullmatch(DIGEST + r":[0-9a-f]{64}", recorded_digest)):
                what = (f"records a malformed digest {clip(repr(recorded_digest), 80)} (phoid "
                        f"run writes \"{DIGEST}:\" and 64 lower-case hexadecimal digits)")
            elif not what and recorded_digest is not None \
                    and recorded_digest != f"{DIGEST}:{digest.hex()}":
                what = "is not the file recorded (its bytes changed since the run)"
        if what:
            raise RigError(f"--resume: run {run} is recorded complete in {path}, but its file "
                           f"{clip(name, 80)!r} {what}; put the run's own file back, or run the "
                           "plan into another --out; nothing was sent")
        assert digest is not None
        out[digest] = f"run {run} ({clip(name, 80)})"
    return out


def _file_digest(path: Path) -> tuple[str, bytes | None]:
    """("", the file's digest) for a regular file; (what is wrong, None) otherwise."""
    try:
        st = os.lstat(path)
        if stat.S_ISLNK(st.st_mode):
            return "is a symbolic link", None
        if not stat.S_ISREG(st.st_mode):
            return "is not a regular file", None
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | os.O_NONBLOCK)
        with open(fd, "rb") as fh:
            return "", hashlib.file_digest(fh, lambda: hashlib.blake2b(digest_size=32)).digest()
    except FileNotFoundError:
        return "is missing", None
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})", None


def check_targets(folder: OutputFolder, files: list[str], status: list[str],
                   own: set[str]) -> None:
    """Refuse, before anything moves, a file in the way of a run that this set did not write."""
    names = [MANIFEST]
    for name, st in zip(files, status, strict=True):
        if st == "pending":
            names += [name, variant(name, "aborted"), variant(name, "incomplete")]
    for name in names[1:]:
        path = folder.path(name)
        if (path.exists() or path.is_symlink()) and name not in own:
            raise RigError(f"{path} exists already and is not a file of this set; phoid run "
                           "never replaces a file (move it away or choose another --out); "
                           "nothing was sent")
    folder.check(names)  # links, folders, special files in the way



def _loop_table(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The set's ``[loop]`` from the controller's configuration: its period, delay and velocity
    estimator, named as phoid names it (the C code's preset, :data:`phoid.rig.native.VELOCITIES`;
    a filtered one with its cut-off −ln(a)/T from the pole a), and ``noise = "in-loop"``: a
    rig's controller reads the encoder that is recorded (the file's x is what it read)."""
    code = cfg.get("velocity", 0)
    name = next((n for n, c in VELOCITIES.items() if c == code), None)
    if name is None:
        raise RigError(f"the controller's velocity estimator {code!r} is none of "
                       f"{', '.join(f'{c} ({n})' for n, c in VELOCITIES.items())}")
    loop = {"sample_time": cfg["sample_time"], "delay_samples": cfg["delay_samples"],
            "velocity": name}
    if name == "filtered":
        loop["cutoff"] = -math.log(cfg["filter_pole"]) / cfg["sample_time"]
    loop["noise"] = "in-loop"
    return loop


def compose(sched: Mapping[str, Any], configs: list[dict[str, Any]],
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
        "loop": _loop_table(cfg0),
        "rig": {"tool": "phoid run", "protocol": 1, "plan": str(Path(sched["path"]).resolve()),
                "complete": all(s == "complete" for s in status),
                "hold_P": cfg0["hold_P"], "hold_D": cfg0["hold_D"],
                "hold_samples": cfg0["hold_samples"], "x_start": cfg0["x_start"],
                "config": {k: v for k, v in cfg0.items() if k not in ("P", "D")},
                "attempt": shown},
    }
    if sched.get("design"):
        doc["design"] = sched["design"]
    if runs:
        doc["run"] = runs
    return tomli_w.dumps(doc).encode()


_KEEP = (STORED_EVENTS, 8, 0)  # events kept per attempt, tried in turn until the manifest fits


def write_manifest(folder: OutputFolder, sched: Mapping[str, Any],
                    configs: list[dict[str, Any]], attempts: list[dict[str, Any]],
                    status: list[str]) -> None:
    for keep in _KEEP:
        data = compose(sched, configs, attempts, status, keep)
        if len(data) <= MAX_MANIFEST_BYTES:
            break
    folder.write(MANIFEST, data)


def check_size(folder: OutputFolder, sched: Mapping[str, Any], configs: list[dict[str, Any]],
          attempts: list[dict[str, Any]], status: list[str]) -> None:
    """Refuse, before anything moves, a set whose manifest could outgrow the reader's limit
    (each run to do counted with its largest record; :func:`write_manifest` cuts events)."""
    worst = list(attempts)
    for i, (name, st) in enumerate(zip(sched["files"], status, strict=True)):
        if st == "pending":
            big = -1.2345678901234567e-300
            worst.append({
                "run": i + 1, "file": '"' * (len(name.encode()) + 20), "P": big, "D": big,
                "status": "complete", "samples": MAX_COUNT, "received": MAX_COUNT,
                "u_source": "measured", "framing": "text", "events": [],
                "events_dropped": MAX_COUNT,
                "time": "2000-01-01T00:00:00Z", "sample_time_mean": big,
                "sample_time_min": big, "sample_time_max": big,
                "digest": f"{DIGEST}:{'0' * 64}", "reason": '"' * (REASON_CHARS + 8)})
    size = len(compose(sched, configs, worst, ["incomplete"] * len(status), 0))
    if size + 4096 > MAX_MANIFEST_BYTES:
        raise RigError(f"{folder.path(MANIFEST)}: the set's manifest could grow to {size} bytes, "
                       f"more than the {MAX_MANIFEST_BYTES // 2**20} MiB phoid reads (a plan of "
                       f"{len(status)} runs, its [design] table and the attempts recorded); "
                       "split the plan; nothing was sent")


def check_writable(folder: OutputFolder, names: list[str]) -> bool:
    """Refuse, before anything moves, a folder phoid cannot write its files in: a file name
    (with its hidden ``.part`` and later ``-NNNN`` variants) longer than the file system's
    NAME_MAX bytes, a path longer than its PATH_MAX, a folder that cannot be created or
    written (a probe file is created and removed). Returns whether the folder was created.
    """
    root = Path(os.path.abspath(folder.folder))
    here = root
    while not here.exists() and here != here.parent:
        here = here.parent
    limits = []
    for key, default in (("PC_NAME_MAX", 255), ("PC_PATH_MAX", 4096)):
        try:
            limits.append(int(os.pathconf(here, key)))
        except (OSError, ValueError, AttributeError):
            limits.append(default)
    name_max, path_max = limits
    for name in names:
        longest = max((f".{name}.{'0' * 8}.part", f"{variant(name, 'incomplete')[:-4]}-9999.csv",
                       f"{variant(name, 'aborted')[:-4]}-9999.csv"),
                      key=lambda s: len(os.fsencode(s)))
        size = len(os.fsencode(longest))
        if size > name_max:
            raise RigError(f"{folder.path(name)}: the file name is too long for the file system "
                           f"there: with the hidden .part or a later -NNNN name phoid writes "
                           f"it takes {size} bytes, more than its {name_max}; shorten the "
                           "plan's file names; nothing was sent")
        if len(os.fsencode(str(root / longest))) >= path_max:
            raise RigError(f"{folder.path(name)}: the path is longer than the {path_max} bytes "
                           "the file system takes; choose a shorter --out; nothing was sent")
    created = not root.exists()
    probe = root / f".phoid-run.{secrets.token_hex(4)}.probe"
    try:
        os.makedirs(root, exist_ok=True)
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL
                     | getattr(os, "O_NOFOLLOW", 0), 0o666)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        if created:
            with contextlib.suppress(OSError):
                os.rmdir(root)
        raise RigError(f"{folder.folder}: phoid run cannot write its files there "
                       f"({exc.strerror or exc}); choose another --out; nothing was sent") \
            from None
    return created
