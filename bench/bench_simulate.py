"""Benchmark of phoid.simulate against jitcdde and scipy's solve_ivp (method of steps).

The plant and loop are the seed paper's Table 1 (ERRATA 6): m = 2 kg, c = 1 N·s/m, k = 64 N/m,
Δt = 0.1 s, released from x₀ = 0.01 m, 15 s at 1 kHz (15 000 samples per run). Three workloads:

* **single run** — the paper's last run (P = 25 N/m, D = 6 N·s/m, the fastest decay);
* **Table 1 set** — the 19 runs Pᵢ = 0.25 + 1.375 i N/m, Dᵢ = 0.6 + 0.3 i N·s/m;
* **1000-run batch** — 1000 runs with (P, D) evenly spread over the Table 1 range (a Monte
  Carlo-sized batch).

phoid simulates every workload whole (one batched call). jitcdde and solve_ivp integrate one
run at a time, so their time grows in proportion to the run count: on the 1000-run batch they
are timed on an evenly spread subset of its runs (named in the table) and their samples per
second are those of the subset. Accuracy is the largest |x − x_ref| / x₀ over all samples of
the runs compared, x_ref a tight jitcdde solution (rtol 1e-12) of the same runs; on the 1000-run
batch phoid's deviation is taken on the same subset.

jitcdde is driven as in tests/jitc_reference.py (steps land on every output time and on every
multiple of Δt, where the release kink propagates; max step Δt/4). Because of that landing, its
accuracy hardly depends on rtol below 1e-5 while its speed does; the comparison that matters for
the target (≥ 20× jitcdde at ≤ 1e−6 relative deviation) is with the *fastest* rtol tried whose
deviation is ≤ 1e−6 (rtol 1e-6).

Usage: ``python bench/bench_simulate.py [repeats]`` prints the dict of :func:`run` as JSON.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import jitc_reference  # test-only helper, shared with tests/test_simulate.py

from phoid.dynamics.plant import Plant
from phoid.simulation import simulate

M, C, K, DELAY, X0 = 2.0, 1.0, 64.0, 0.1, 0.01
DURATION, FS = 15.0, 1000.0
I19 = np.arange(19)
P19 = 0.25 + 1.375 * I19
D19 = 0.6 + 0.3 * I19
TIGHT_RTOL = 1e-12
JIT_RTOLS = (1e-6, 1e-10)
DEVIATION_TARGET = 1e-6


def _stats(times: list[float], samples: int) -> dict:
    """Median and min–max of wall times (s) and of the sample rates (samples/s) they give."""
    return {
        "seconds_median": statistics.median(times),
        "seconds_min": min(times),
        "seconds_max": max(times),
        "samples": samples,
        "samples_per_s_median": samples / statistics.median(times),
        "samples_per_s_min": samples / max(times),
        "samples_per_s_max": samples / min(times),
    }


def _timed(fn: Callable[[], object], repeats: int) -> tuple[list[float], object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def _jitcdde(P: np.ndarray, D: np.ndarray, t: np.ndarray, rtol: float) -> np.ndarray:
    return np.array([
        jitc_reference.jitcdde_reference(M, C, K, p, d, DELAY, X0, t, rtol=rtol)
        for p, d in zip(P, D, strict=True)
    ])


def method_of_steps(P: float, D: float, t: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Eq. (23) by scipy's DOP853, one delay interval at a time (method of steps).

    On [jΔt, (j+1)Δt] the delayed state is the previous interval's dense output (the constant
    x₀ before the release), so every propagated release kink is an interval boundary.
    """
    x = np.empty(t.size)
    prev = None
    y = np.array([X0, 0.0])
    n_int = int(np.ceil(t[-1] / DELAY - 1e-12))
    for j in range(n_int):
        a, b = j * DELAY, (j + 1) * DELAY

        def rhs(tt, yy, prev=prev):
            if prev is None:
                xd, vd = X0, 0.0
            else:
                xd, vd = prev(tt - DELAY)
            return [yy[1], (-C * yy[1] - K * yy[0] - D * vd - P * xd) / M]

        sol = solve_ivp(
            rhs, (a, b), y, method="DOP853", rtol=rtol, atol=rtol * X0, dense_output=True
        )
        sel = (t >= a) & ((t < b) | (j == n_int - 1))
        x[sel] = sol.sol(t[sel])[0]
        prev, y = sol.sol, sol.y[:, -1]
    return x


def _dev(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(x - ref)) / X0)


def _row(workload: str, name: str, st: dict, dev: float | None, *, runs_timed: str = "all",
         is_phoid: bool = False, rtol: float | None = None) -> dict:
    return {"workload": workload, "simulator": name, "runs_timed": runs_timed,
            "phoid": is_phoid, "rtol": rtol, "max_deviation_rel_x0": dev, **st}


def run(repeats: int = 5, *, batch: int = 1000, subset: int = 20, mos_subset: int = 4) -> dict:
    """Measure phoid, jitcdde and solve_ivp on the three workloads; return JSON-ready numbers.

    Parameters
    ----------
    repeats : int, default 5
        Timed repetitions of each measurement (median and min–max are reported); jitcdde and
        solve_ivp on multi-run workloads get at most 3, and sub-10 ms measurements at least 10.
    batch : int, default 1000
        Runs in the Monte Carlo-sized batch.
    subset, mos_subset : int
        Runs of the batch on which jitcdde and solve_ivp are timed (evenly spread).

    Returns
    -------
    dict
        ``rows``: one dict per (workload, simulator) with timing statistics (``_stats``),
        ``max_deviation_rel_x0`` and ``runs_timed``; ``jitcdde_compile_s``; ``speedup``:
        phoid's median sample rate over each alternative's, per workload; ``target``: the
        simulation target's inputs; ``environment``.
    """
    repeats = max(1, int(repeats))
    few = max(1, min(repeats, 3))
    plant = Plant(M, C, K)
    n = round(DURATION * FS)
    t = np.arange(n) / FS
    out: dict = {
        "workload": "seed Table 1 plant and loop: m=2 kg, c=1 N·s/m, k=64 N/m, delay 0.1 s, "
        "x0=0.01 m, 15 s at 1 kHz per run",
        "repeats": repeats,
        "tight_rtol": TIGHT_RTOL,
    }

    # jitcdde: compile once (fresh, into a temporary cache, to time it), then integrate
    with tempfile.TemporaryDirectory() as tmp:
        old = jitc_reference._module_path
        jitc_reference._module_path = lambda delay: os.path.join(tmp, "phoid_ref_bench.so")
        try:
            _, compile_s = jitc_reference.compile_module(DELAY)
        finally:
            jitc_reference._module_path = old
    jitc_reference.compile_module(DELAY)  # the shared cache used below
    out["jitcdde_compile_s"] = compile_s

    def phoid_sim(P, D):
        return simulate(plant, P, D, delay=DELAY, duration=DURATION, fs=FS, x0=X0).x_true

    phoid_sim(P19[:1], D19[:1])  # imports, caches
    rows: list[dict] = []
    Pb = np.linspace(P19[0], P19[-1], batch)
    Db = np.linspace(D19[0], D19[-1], batch)
    sub = np.unique(np.linspace(0, batch - 1, min(subset, batch)).round().astype(int))
    mos_sub = sub[np.unique(np.linspace(0, sub.size - 1, min(mos_subset, sub.size))
                            .round().astype(int))]
    workloads = [
        ("single run", P19[-1:], D19[-1:], np.array([0]), np.array([0])),
        ("Table 1 set (19 runs)", P19, D19, I19, np.array([0, 9, 18])),
        (f"{batch}-run batch", Pb, Db, sub, mos_sub),
    ]
    for wname, P, D, jit_idx, mos_idx in workloads:
        nruns = P.size
        t0 = time.perf_counter()
        ref = _jitcdde(P[jit_idx], D[jit_idx], t, TIGHT_RTOL)
        ref_s = time.perf_counter() - t0
        # phoid: the whole workload in one call
        reps = repeats if nruns > 1 else max(repeats, 10)
        times, x = _timed(lambda P=P, D=D: phoid_sim(P, D), reps)
        rows.append(_row(wname, "phoid", _stats(times, nruns * n), _dev(x[jit_idx], ref),
                         is_phoid=True))
        del x
        label = "all" if jit_idx.size == nruns else f"{jit_idx.size} of {nruns}"
        for rtol in JIT_RTOLS:
            times, xj = _timed(lambda rtol=rtol, P=P, D=D, j=jit_idx: _jitcdde(P[j], D[j], t,
                                                                                rtol),
                               few if nruns > 1 else repeats)
            rows.append(_row(wname, f"jitcdde rtol {rtol:g}", _stats(times, jit_idx.size * n),
                             _dev(xj, ref), runs_timed=label, rtol=rtol))
        rows.append(_row(wname, f"jitcdde rtol {TIGHT_RTOL:g} (the reference, 1 call)",
                         _stats([ref_s], jit_idx.size * n), 0.0, runs_timed=label,
                         rtol=TIGHT_RTOL))
        pos = [int(np.flatnonzero(jit_idx == i)[0]) for i in mos_idx]
        times, xm = _timed(lambda P=P, D=D, mi=mos_idx: np.array(
            [method_of_steps(P[i], D[i], t) for i in mi]), few if nruns > 1 else repeats)
        rows.append(_row(wname, "solve_ivp DOP853 rtol 1e-10, method of steps",
                         _stats(times, mos_idx.size * n), _dev(xm, ref[pos]),
                         runs_timed="all" if mos_idx.size == nruns
                         else f"{mos_idx.size} of {nruns}", rtol=1e-10))
    out["rows"] = rows

    speed: dict = {}
    for wname, *_ in workloads:
        wr = [r for r in rows if r["workload"] == wname]
        ph = next(r for r in wr if r["phoid"])
        speed[wname] = {r["simulator"]: ph["samples_per_s_median"] / r["samples_per_s_median"]
                        for r in wr if not r["phoid"]}
    out["speedup"] = speed

    # target: ≥ 20× the fastest jitcdde setting that stays within 1e-6 x0, at ≤ 1e-6 x0
    table1 = [r for r in rows if r["workload"] == "Table 1 set (19 runs)"]
    ok_jit = [r for r in table1 if r["simulator"].startswith("jitcdde")
              and r["max_deviation_rel_x0"] <= DEVIATION_TARGET]
    fastest = max(ok_jit, key=lambda r: r["samples_per_s_median"])
    ph = next(r for r in table1 if r["phoid"])
    out["target"] = {
        "workload": "Table 1 set (19 runs)",
        "jitcdde_setting": fastest["simulator"],
        "speedup": ph["samples_per_s_median"] / fastest["samples_per_s_median"],
        "phoid_max_deviation_all_workloads": max(r["max_deviation_rel_x0"] for r in rows
                                                 if r["phoid"]),
        "deviation_target": DEVIATION_TARGET,
    }
    out["environment"] = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "machine": platform.machine(),
    }
    return out


if __name__ == "__main__":
    print(json.dumps(run(int(sys.argv[1]) if len(sys.argv) > 1 else 5), indent=2))
