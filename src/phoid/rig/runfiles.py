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
import secrets
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError
from phoid.io.limits import MAX_MANIFEST_BYTES
from phoid.io.manifest import read_manifest
from phoid.rig.checks import MANIFEST, MAX_COUNT, RigError, clip, variant

__all__ = [
    "EVENT_CHARS",
    "REASON_CHARS",
    "RunFile",
    "check_size",
    "check_targets",
    "complete_digests",
    "compose",
    "read_state",
    "write_manifest",
]

STORED_EVENTS = 64  # events recorded per attempt; the rest are counted (events_dropped)
EVENT_CHARS = 96  # the longest event text recorded, characters
REASON_CHARS = 400  # the longest reason recorded (and printed), characters
_RANK = {"idle": 0, "hold": 0, "run": 1, "done": 2, "fault": 2}  # the order of the states


class RunFile:
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
            self.events.append(clip(f"{name} {f['index']} {float(f['value'])!r}", EVENT_CHARS))

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


def read_state(out: OutputFolder, sched: Mapping[str, Any]) -> list[dict[str, Any]] | None:
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
    return [dict(a) for a in attempts]


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



def complete_digests(folder: OutputFolder, attempts: list[dict[str, Any]]) -> dict[bytes, str]:
    """The complete runs' files by their content's digest (a repeat would be refused)."""
    out: dict[bytes, str] = {}
    for a in attempts:
        path = folder.path(a["file"])
        if a["status"] == "complete" and path.is_file() and not path.is_symlink():
            with contextlib.suppress(OSError), open(path, "rb") as fh:
                out[hashlib.file_digest(fh, lambda: hashlib.blake2b(digest_size=32)).digest()] \
                    = f"run {a['run']} ({clip(a['file'], 80)})"
    return out



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
                "u_source": "measured", "events": [], "events_dropped": MAX_COUNT,
                "time": "2000-01-01T00:00:00Z", "sample_time_mean": big,
                "sample_time_min": big, "sample_time_max": big,
                "reason": '"' * (REASON_CHARS + 8)})
    size = len(compose(sched, configs, worst, ["incomplete"] * len(status), 0))
    if size + 4096 > MAX_MANIFEST_BYTES:
        raise RigError(f"{folder.path(MANIFEST)}: the set's manifest could grow to {size} bytes, "
                       f"more than the {MAX_MANIFEST_BYTES // 2**20} MiB phoid reads (a plan of "
                       f"{len(status)} runs, its [design] table and the attempts recorded); "
                       "split the plan; nothing was sent")
