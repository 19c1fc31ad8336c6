"""Figure times: ``phoid identify`` on the example set with ``--plots`` and ``--html``, against
``identify`` alone (issue 30: ≤ 3 s, median).

Each figure is the wall time of a fresh ``phoid`` process (``subprocess`` timed with
``time.perf_counter``), median (min–max) over the repeats; the commands run in turn round by
round, so that a busy spell of the machine falls on each alike, and the child's CPU time
(user + system, ``getrusage``) is recorded beside it. The outputs go to a temporary folder;
the sizes of the PNG files and of the HTML page are recorded too.

    python bench/bench_figures.py [REPEATS]           # print the section
    python bench/bench_figures.py [REPEATS] --write   # and splice it into BENCHMARKS.md
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from bench_startup import _phoid_command, _stats, time_command  # noqa: E402
from sections import splice_section  # noqa: E402

SAMPLE = ROOT / "examples" / "paper-sample"  # the README's example set (examples/README.md)
TARGET = 3.0  # s, median of --plots and of --html (issue 30)
TITLE = "## Figures (`--plots`, `--html`)"


def _workers() -> int:
    """The worker processes ``phoid`` draws the 21 figures with here (its own rule)."""
    from phoid.reports.figures import figure_workers

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return figure_workers(21, cpus or 1)


def run(repeats: int = 5) -> dict:
    """Median wall and CPU times of identify, identify --plots and identify --html.

    Returns a dict: ``wall`` and ``cpu`` (label -> median_s, min_s, max_s, n), ``sizes``
    (label -> bytes written: all PNG files of --plots, the page of --html), ``target`` (s)
    and ``load_average`` (1, 5, 15 min, after the runs).
    """
    phoid = [*_phoid_command(), "identify", str(SAMPLE)]
    wall: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    sizes: dict[str, int] = {}
    env = {k: v for k, v in os.environ.items() if k != "PHOID_FIGURE_WORKERS"}  # the default
    with tempfile.TemporaryDirectory(prefix="phoid-bench-figures-") as tmp:
        for rnd in range(repeats + 1):  # round 0 untimed: caches warm
            out = Path(tmp) / f"r{rnd}"
            commands = {"identify": phoid,
                        "identify --plots DIR": [*phoid, "--plots", str(out / "plots")],
                        "identify --html FILE": [*phoid, "--html", str(out / "r.html")]}
            for label, cmd in commands.items():
                dt, used = time_command(label, cmd, env)
                if rnd:
                    wall.setdefault(label, []).append(dt)
                    cpu.setdefault(label, []).append(used)
            sizes = {"identify --plots DIR": sum(p.stat().st_size
                                                 for p in (out / "plots").glob("*.png")),
                     "identify --html FILE": (out / "r.html").stat().st_size}
    return {"wall": {k: _stats(v) for k, v in wall.items()},
            "cpu": {k: _stats(v) for k, v in cpu.items()}, "sizes": sizes,
            "target": TARGET, "workers": _workers(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


def section(res: dict) -> list[str]:
    """BENCHMARKS.md's section of :func:`run`'s result."""
    lines = [TITLE, "",
             f"`phoid identify examples/paper-sample` (19 runs of 15 000 samples: 21 figures), "
             f"a fresh process each, median (min–max) of {res['wall']['identify']['n']} rounds; "
             f"target ≤ {res['target']:g} s for `--plots` and `--html`. The figures are drawn "
             f"by {res.get('workers', '?')} worker processes (one per usable CPU; "
             "`PHOID_FIGURE_WORKERS` unset); CPU s is the command's and its workers' (user + "
             "system).", "",
             "| command | wall s | CPU s | written |", "|---|---|---|---|"]
    for label, w in res["wall"].items():
        c = res["cpu"][label]
        size = res["sizes"].get(label)
        lines.append(f"| `{label}` | {w['median_s']:.2f} ({w['min_s']:.2f}–{w['max_s']:.2f}) "
                     f"| {c['median_s']:.2f} | "
                     + (f"{size / 1e6:.2f} MB" if size is not None else "—") + " |")
    if res.get("load_average"):
        lines += ["", "Load average after the runs: "
                  + ", ".join(f"{v:.2f}" for v in res["load_average"]) + "."]
    return lines


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--write"]
    result = run(int(args[0]) if args else 5)
    part = section(result)
    print("\n".join(part))
    if "--write" in sys.argv[1:]:
        md = ROOT / "BENCHMARKS.md"
        md.write_text(splice_section(md.read_text(encoding="utf-8"), TITLE, part),
                      encoding="utf-8")
