"""`phoid batch` benchmark: sets per second against workers, and the cost of a task (issue 20).

Measured on the same sets, in the same run:

* the work itself: ``identify_job`` (read, identify, row) called set after set;
* a plain loop in one process: ``run_batch`` without a cluster (the work plus each set's
  checksum) — the alternative;
* ``run_batch`` on a ``distributed.LocalCluster`` of 1 and of 2 worker processes (one thread
  each), the cluster started before the clock (its start-up is timed apart);
* the overhead of one task: a trivial function (``abs``) mapped over many items with
  ``map_unordered`` on the same clusters, seconds per task;
* the bytes a set's task moves: the pickled job (path, checksum, metadata, options) to the
  worker and the pickled row back.

Two kinds of set: 48 small pho sets simulated by ``phoid simulate`` (3 runs of 4 s at 200 Hz,
each its own noise draw: the per-task overhead weighs most), and 16 copies of the Table 1
sample set (19 runs of 15 s at 1 kHz: a set as recorded).

Usage::

    python bench/bench_batch.py [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

SIMULATE = ["--P", "1,3,6", "--D", "0.6,1,1.5", "--duration", "4", "--fs", "200",
            "--noise", "1e-5"]
TRIVIAL_TASKS = 400
PAPER = Path(__file__).resolve().parents[1] / "examples" / "paper-sample"
DESCRIPTION = {
    "small": "`phoid simulate " + " ".join(SIMULATE) + "` (3 runs, 2400 samples)",
    "paper": "copies of examples/paper-sample (Table 1: 19 runs of 15.2 s at 1 kHz, 289 000 "
             "samples, gzip CSV)",
}


def _stats(values: list[float]) -> dict:
    return {"median_s": statistics.median(values), "min_s": min(values), "max_s": max(values),
            "n": len(values)}


def _make_sets(root: Path, n: int) -> list[Path]:
    from typer.testing import CliRunner

    from phoid.cli import app

    runner = CliRunner()
    sets = []
    for i in range(n):
        folder = root / f"set{i:03d}"
        r = runner.invoke(app, ["simulate", str(folder), *SIMULATE, "--seed", str(i)])
        if r.exit_code != 0:
            raise RuntimeError(r.output)
        sets.append(folder)
    return sets


def _time_batch(sets: list[Path], client, repeats: int) -> dict:
    from phoid.batch.engine import run_batch

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        report = run_batch(sets, client=client)
        times.append(time.perf_counter() - t0)
        assert report.errors == 0, [r["error"] for r in report.rows if r["error"]]
    return _stats(times)


def _time_trivial(client, repeats: int) -> dict:
    from phoid.batch.cluster import map_unordered

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = sum(1 for _ in map_unordered(client, abs, range(TRIVIAL_TASKS), description="x"))
        times.append((time.perf_counter() - t0) / n)
    return _stats(times)


def run(n_sets: int = 48, repeats: int = 3, workers: tuple[int, ...] = (1, 2),
        kind: str = "small") -> dict:
    """Sets per second: plain loop, and local clusters of ``workers`` processes.

    Returns a dict: ``sets``, ``set_description``, ``work`` (wall of ``identify_job`` called
    set after set, its jobs made beforehand: median_s, min_s, max_s, n), ``loop`` (wall of
    ``run_batch`` without a cluster: the same plus each set's checksum), ``clusters``
    (workers -> ``start_s`` (the cluster's start-up), ``batch`` (wall of ``run_batch`` over
    the sets), ``task_overhead`` (wall per trivial task)), ``bytes`` (``job``, ``row``:
    pickled sizes of one set's task), ``cores``.
    """
    import cloudpickle

    from phoid.batch.cluster import cluster_client
    from phoid.batch.engine import identify_job
    from phoid.batch.rows import options_key
    from phoid.batch.sets import set_digest

    with tempfile.TemporaryDirectory(prefix="phoid-bench-batch-") as tmp:
        if kind == "small":
            sets = _make_sets(Path(tmp), n_sets)
        else:  # copies of the Table 1 sample set
            sets = []
            for i in range(n_sets):
                sets.append(Path(tmp) / f"paper{i:03d}")
                shutil.copytree(PAPER, sets[-1])
        jobs = []
        for s in sets:
            d = set_digest(s)
            jobs.append((str(s.resolve()), d.checksum, d.metadata, {}))
        options_key({})
        identify_job(jobs[0])  # imports paid before the clock
        work = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for job in jobs:
                identify_job(job)
            work.append(time.perf_counter() - t0)
        loop = _time_batch(sets, None, repeats)
        row = identify_job(jobs[0])
        sizes = {"job": len(cloudpickle.dumps(jobs[0])), "row": len(cloudpickle.dumps(row))}
        clusters = {}
        for n in workers:
            t0 = time.perf_counter()
            with cluster_client(workers=n) as client:
                start = time.perf_counter() - t0
                _time_batch(sets[: 2 * n], client, 1)  # workers import phoid before the clock
                clusters[n] = {"start_s": start,
                               "batch": _time_batch(sets, client, repeats),
                               "task_overhead": _time_trivial(client, repeats)}
    return {"sets": n_sets, "kind": kind, "set_description": DESCRIPTION[kind],
            "work": _stats(work), "loop": loop, "clusters": clusters, "bytes": sizes,
            "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
            else os.cpu_count()}


def section(res: dict) -> list[str]:
    """BENCHMARKS.md's section "Many sets (phoid batch)" from :func:`run`'s results
    (``res["runs"]``: one per kind of set)."""
    if not res or not res.get("runs"):
        return []
    first = res["runs"][0]
    lines = [
        "## Many sets (phoid batch)",
        "",
        "Sets identified by `run_batch` (each set's checksum on the driver, then the task of "
        "`phoid batch`, `identify_job`: read, identify, row), in sets per second, median "
        "(slowest–fastest) over the repeats, on this machine's "
        f"{first['cores']} cores. The clusters are `distributed.LocalCluster`s of worker "
        "processes (one thread each), started before the clock; the task overhead is the "
        f"wall time per task of {TRIVIAL_TASKS} trivial tasks (`abs`) on the same cluster. "
        "`python bench/bench_batch.py` runs it alone.",
        "",
        "| sets | how | sets per second | vs the loop | cluster start | overhead per task |",
        "|---|---|---|---|---|---|",
    ]
    for r in res["runs"]:
        n = r["sets"]
        loop = r["loop"]["median_s"]

        def rate(s: dict, n: int = n) -> str:
            return f"{n / s['median_s']:.3g} ({n / s['max_s']:.3g}–{n / s['min_s']:.3g})"

        what = f"{n} × {r['set_description']}"
        lines += [
            f"| {what} | `identify_job` alone, set after set (the work) | {rate(r['work'])} | "
            f"{loop / r['work']['median_s']:.2f}× | | |",
            f"| | plain loop, one process (`run_batch`, no cluster) | {rate(r['loop'])} | 1 "
            "| | |",
        ]
        for w, c in r["clusters"].items():
            lines.append(f"| | local cluster, {w} worker{'s' if int(w) > 1 else ''} | "
                         f"{rate(c['batch'])} | {loop / c['batch']['median_s']:.2f}× | "
                         f"{c['start_s']:.1f} s | {c['task_overhead']['median_s'] * 1e3:.2f} "
                         "ms |")
    b = first["bytes"]
    lines += [
        "",
        f"One task per set; it moves {b['job']} bytes to the worker (the set's path, checksum, "
        f"metadata and options: the worker reads the set's files itself) and {b['row']} bytes "
        "back (the row). docs/design-notes/batch.md scales this to a real cluster.",
    ]
    if res.get("load_average"):
        lines += ["", "Load average at the end (1, 5, 15 min): "
                  + ", ".join(f"{v:.2f}" for v in res["load_average"]) + "."]
    return lines


def run_all(quick: bool = False) -> dict:
    """Both kinds of set: many small ones and fewer Table 1 sized ones (``run_bench``'s
    entry; ``quick``: fewer sets, one repeat)."""
    repeats = 1 if quick else 3
    runs = [run(16 if quick else 48, repeats, kind="small"),
            run(6 if quick else 16, repeats, kind="paper")]
    return {"runs": runs,
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer sets, one repeat")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    res = run_all(args.quick)
    print("\n".join(section(res)))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
