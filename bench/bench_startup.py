"""Start-up times: what a user waits for before phoid starts working (issue 16).

Each figure is the wall time of a fresh interpreter (``subprocess`` timed with
``time.perf_counter``), median (min–max) over the repeats, measured in turn round by round so
that a busy spell of the machine falls on every command alike; the child's CPU time (user +
system, from ``getrusage``) is recorded beside the wall time. ``python -c pass`` and
``python -c "import numpy"`` are measured in the same rounds, for scale.
"""

from __future__ import annotations

import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"  # the Table 1 sample set (examples/README.md)
HELP_TARGET = 0.3  # s, `phoid --help` (issue 16)
IDENTIFY_TARGET = 0.6  # s, `phoid identify examples/paper-sample` (issue 16)

# in-process: the time of the import statement alone (no interpreter start)
_IMPORT = ("import time; t = time.perf_counter(); import phoid; "
           "print(time.perf_counter() - t)")
_IMPORT_ALL = ("import time; t = time.perf_counter(); import phoid; "
               "[getattr(phoid, n) for n in phoid.__all__]; print(time.perf_counter() - t)")


def _phoid_command() -> list[str]:
    """The ``phoid`` console script next to this interpreter, else the same entry point by -c."""
    script = Path(sys.executable).parent / "phoid"
    if script.exists() and os.access(script, os.X_OK):
        return [str(script)]
    found = shutil.which("phoid")
    if found and Path(found).resolve().parent == Path(sys.executable).resolve().parent:
        return [found]
    return [sys.executable, "-c", "from phoid.cli import main; main()"]


def _stats(values: list[float]) -> dict:
    return {"median_s": statistics.median(values), "min_s": min(values),
            "max_s": max(values), "n": len(values)}


def time_command(label: str, cmd: list[str], env: dict) -> tuple[float, float]:
    """(wall s, CPU s) of one run of ``cmd`` in a fresh process from the checkout's root: the
    wall time by ``time.perf_counter``, the child's user + system time by ``getrusage``. A
    command that fails stops the benchmark (RuntimeError naming ``label``)."""
    u0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    dt = time.perf_counter() - t
    u1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"{label} failed ({r.returncode}): {r.stderr[-500:]}")
    return dt, u1.ru_utime - u0.ru_utime + u1.ru_stime - u0.ru_stime


def run(repeats: int = 20) -> dict:
    """Median wall times of the start-up commands over ``repeats`` rounds (one untimed first).

    Returns a dict: ``phoid_command`` (how phoid was started), ``wall`` (label -> median_s,
    min_s, max_s, n) for python -c pass, import numpy, phoid --help and phoid identify;
    ``cpu`` (the same for the child's user + system CPU time: less sensitive to a busy
    machine than the wall time);
    ``import`` (label -> the same, in-process time of ``import phoid`` and of every public
    name); ``targets`` (the issue's limits, s); ``load_average`` (1, 5, 15 min, after the runs).
    """
    phoid = _phoid_command()
    py = [sys.executable]
    commands = {
        "python -c pass": [*py, "-c", "pass"],
        "python -c 'import numpy'": [*py, "-c", "import numpy"],
        "phoid --help": [*phoid, "--help"],
        "phoid identify examples/paper-sample": [*phoid, "identify", str(SAMPLE)],
    }
    imports = {"import phoid": [*py, "-c", _IMPORT],
               "import phoid + every public name": [*py, "-c", _IMPORT_ALL]}
    with tempfile.TemporaryDirectory(prefix="phoid-pycache-") as cache:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPYCACHEPREFIX"] = cache
        res = _rounds(commands, imports, repeats, env)
    return {"phoid_command": " ".join(phoid), **res,
            "targets": {"phoid --help": HELP_TARGET,
                        "phoid identify examples/paper-sample": IDENTIFY_TARGET},
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


def _rounds(commands: dict, imports: dict, repeats: int, env: dict) -> dict:
    wall: dict[str, list[float]] = {k: [] for k in commands}
    cpu: dict[str, list[float]] = {k: [] for k in commands}
    imp: dict[str, list[float]] = {k: [] for k in imports}
    for rnd in range(repeats + 1):
        for label, cmd in commands.items():
            dt, used = time_command(label, cmd, env)
            if rnd:
                wall[label].append(dt)
                cpu[label].append(used)
        for label, cmd in imports.items():
            r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env,
                               check=True)
            if rnd:
                imp[label].append(float(r.stdout.strip().splitlines()[-1]))
    return {"wall": {k: _stats(v) for k, v in wall.items()},
            "cpu": {k: _stats(v) for k, v in cpu.items()},
            "import": {k: _stats(v) for k, v in imp.items()}}


if __name__ == "__main__":
    import json

    print(json.dumps(run(int(sys.argv[1]) if len(sys.argv) > 1 else 20), indent=1))
