"""Scaling of phoid.simulate and phoid.identify_data: time and peak memory against problem size.

Two axes, each point measured in a fresh subprocess (so one point's caches and freed memory do
not flatter the next):

* **record length** — samples per run n = 1e3 … 1e7: a 10 s record (0.2 s hold, 9.8 s after the
  release) at f_s = n / 10 s (100 Hz … 1 MHz; f_sΔt is an integer, so samples are on the
  simulator's grid). ``simulate``: one run (Table 1 plant, P = 7.125 N/m, D = 2.1 N·s/m);
  ``identify``: three runs (Table 1 runs 1, 10 and 19: the fewest that give the eq. (35) lines a
  residual), 0.1 mm noise, 1 µm quantisation.
* **number of runs** — 1 … 1000 runs (2 … 1000 for ``identify``, which needs two gain pairs) of
  10 s at 1 kHz (1e4 samples each), gains evenly spread over the Table 1 range.

Time: median (min–max) of up to 3 calls (fewer when a call takes more than a few seconds),
after an untimed warm-up call on a small problem (imports, caches). Memory: the peak of
``tracemalloc`` (numpy registers its array buffers with it) during one more call, above what
was allocated before it — the inputs (t and x records) are not counted, the outputs are.
Reported per sample and as a multiple of the record's own size: its time and position columns,
t and x in float64, 16 bytes per sample.
The growth exponent is the least-squares slope of log(time) and log(peak) against log(size),
over the sizes at which the fixed per-call cost is below ~10 % (the upper three points) and
over the whole range.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
M, C, K, DELAY = 2.0, 1.0, 64.0, 0.1
P19 = 0.25 + 1.375 * np.arange(19)
D19 = 0.6 + 0.3 * np.arange(19)
RECORD_S, HOLD = 10.0, 0.2
LENGTHS = (1_000, 10_000, 100_000, 1_000_000, 10_000_000)
RUNS_SIM = (1, 10, 100, 1000)
RUNS_ID = (2, 10, 100, 1000)


def _gains(runs: int, axis: str) -> tuple[np.ndarray, np.ndarray]:
    if axis == "length":
        return (np.array([7.125]), np.array([2.1])) if runs == 1 else (P19[[0, 9, 18]],
                                                                      D19[[0, 9, 18]])
    return (np.linspace(P19[0], P19[-1], runs), np.linspace(D19[0], D19[-1], runs))


def _measure(func: str, axis: str, size: int) -> dict:
    """One point, in this process: time and peak memory of ``func`` at ``size``."""
    from phoid import Plant, simulate
    from phoid.api import identify_data

    plant = Plant(M, C, K)
    if axis == "length":
        n_per_run, runs, fs = size, (1 if func == "simulate" else 3), size / RECORD_S
    else:
        n_per_run, runs, fs = round(RECORD_S * 1000.0), size, 1000.0
    P, D = _gains(runs, axis)
    kw = {"delay": DELAY, "duration": RECORD_S - HOLD, "fs": fs, "x0": 0.01, "hold": HOLD}

    if func == "simulate":
        simulate(plant, P[:1], D[:1], **{**kw, "fs": 1000.0})  # warm-up

        def call():
            return simulate(plant, P, D, **kw)
    else:
        rng = np.random.default_rng(1)
        noisy = {"noise": 1e-4, "quantum": 1e-6, "offset": -3e-4, "rng": rng}
        if runs * n_per_run <= 10_000_000:
            sim = simulate(plant, P, D, **noisy, **kw)
            t, xs = sim.t, list(sim.x)
        else:  # one run at a time: the generator's temporaries stay small
            xs = []
            for i in range(runs):
                sim = simulate(plant, P[i:i + 1], D[i:i + 1], **noisy, **kw)
                t = sim.t
                xs.append(sim.x[0].copy())
        del sim
        data = [(t, x) for x in xs]
        w = simulate(plant, P19[[0, 18]], D19[[0, 18]], noise=1e-4, rng=rng,
                     **{**kw, "fs": 1000.0})
        identify_data([(w.t, w.x[0]), (w.t, w.x[1])], P19[[0, 18]], D19[[0, 18]], DELAY)
        del w

        def call():
            return identify_data(data, P, D, DELAY)

    times: list[float] = []
    while len(times) < 3 and sum(times) < 4.0:
        t0 = time.perf_counter()
        res = call()
        times.append(time.perf_counter() - t0)
        del res
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    res = call()
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    out = {"func": func, "axis": axis, "size": size, "runs": runs,
           "samples_per_run": n_per_run, "samples": runs * n_per_run,
           "median_s": float(np.median(times)), "min_s": min(times), "max_s": max(times),
           "calls": len(times), "peak_bytes": int(peak)}
    if func == "identify":
        out["m"] = float(res.m.value)
    import resource

    out["maxrss_bytes"] = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
    return out


def _slope(x, y) -> float:
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


def run(*, max_length: int = LENGTHS[-1], max_runs: int = RUNS_SIM[-1],
        timeout: float = 300.0) -> dict:
    """All points of both axes (each in a subprocess) and their log–log slopes.

    Returns
    -------
    dict
        ``points``: one dict per (func, axis, size) as :func:`_measure` gives it (or with
        ``error`` when the subprocess failed); ``slopes``: per (func, axis) the time and peak
        memory exponents over the upper three sizes and over all sizes.
    """
    plan = [("simulate", "length", n) for n in LENGTHS if n <= max_length]
    plan += [("identify", "length", n) for n in LENGTHS if n <= max_length]
    plan += [("simulate", "runs", r) for r in RUNS_SIM if r <= max_runs]
    plan += [("identify", "runs", r) for r in RUNS_ID if r <= max_runs]
    points = []
    for func, axis, size in plan:
        cmd = [sys.executable, str(Path(__file__).resolve()), func, axis, str(size)]
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                               check=False)
            if p.returncode == 0:
                points.append(json.loads(p.stdout.strip().splitlines()[-1]))
            else:
                err = (p.stderr.strip().splitlines() or ["?"])[-1]
                points.append({"func": func, "axis": axis, "size": size,
                               "error": f"exit {p.returncode}: {err}"})
        except subprocess.TimeoutExpired:
            points.append({"func": func, "axis": axis, "size": size,
                           "error": f"took more than {timeout:g} s"})
    slopes = {}
    for func in ("simulate", "identify"):
        for axis in ("length", "runs"):
            every = [p for p in points if p["func"] == func and p["axis"] == axis]
            pts = [p for p in every if "error" not in p]
            if len(pts) < 3 or "error" in every[-1]:
                slopes[f"{func}/{axis}"] = {"error": "too few points, or the largest failed"}
                continue
            x = [p["samples"] for p in pts]
            top = pts[-3:]
            xt = [p["samples"] for p in top]
            slopes[f"{func}/{axis}"] = {
                "time_upper": _slope(xt, [p["median_s"] for p in top]),
                "time_all": _slope(x, [p["median_s"] for p in pts]),
                "memory_upper": _slope(xt, [max(p["peak_bytes"], 1) for p in top]),
                "memory_all": _slope(x, [max(p["peak_bytes"], 1) for p in pts]),
                "upper_sizes": [p["size"] for p in top],
            }
    return {"points": points, "slopes": slopes}


RECORD_BYTES_PER_SAMPLE = 16  # t and x, float64


def bytes_per_sample(p: dict) -> float:
    """Peak bytes per sample of a point (NaN for a failed one)."""
    return p["peak_bytes"] / p["samples"] if "peak_bytes" in p else math.nan


def times_record(p: dict) -> float:
    """Peak memory as a multiple of the record's own size (t and x, 16 bytes per sample)."""
    return bytes_per_sample(p) / RECORD_BYTES_PER_SAMPLE


if __name__ == "__main__":
    if len(sys.argv) == 4:
        print(json.dumps(_measure(sys.argv[1], sys.argv[2], int(float(sys.argv[3])))))
    else:
        print(json.dumps(run(), indent=1))
