"""Benchmark of phoid.simulate against jitcdde and scipy's solve_ivp (method of steps).

The workload is the seed paper's Table 1 sweep (ERRATA 6): m = 2 kg, c = 1 N·s/m, k = 64 N/m,
Δt = 0.1 s, Pᵢ = 0.25 + 1.375 i N/m, Dᵢ = 0.6 + 0.3 i N·s/m (i = 0 … 18), released from
x₀ = 0.01 m, 15 s at 1 kHz (15 000 samples per run). Accuracy is the largest deviation from a
tight jitcdde solution (rtol 1e-12) over all samples, relative to x₀.

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

from phoid.plant import Plant
from phoid.simulation import simulate

M, C, K, DELAY, X0 = 2.0, 1.0, 64.0, 0.1, 0.01
DURATION, FS = 15.0, 1000.0
I19 = np.arange(19)
P19 = 0.25 + 1.375 * I19
D19 = 0.6 + 0.3 * I19
TIGHT_RTOL = 1e-12


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


def _jitcdde_sweep(t: np.ndarray, rtol: float) -> np.ndarray:
    return np.array(
        [
            jitc_reference.jitcdde_reference(M, C, K, p, d, DELAY, X0, t, rtol=rtol)
            for p, d in zip(P19, D19, strict=True)
        ]
    )


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


def run(repeats: int = 5) -> dict:
    """Measure phoid, jitcdde and solve_ivp on the Table 1 sweep; return JSON-ready numbers.

    Parameters
    ----------
    repeats : int, default 5
        Timed repetitions of each measurement (median and min–max are reported).

    Returns
    -------
    dict
        ``phoid_table1``, ``phoid_batch1000``: timing statistics; ``jitcdde``: compile time and,
        per rtol, timing statistics and deviation; ``solve_ivp_method_of_steps``: one run;
        ``max_deviation_rel_x0``: largest |x − x_tight| / x₀ of each method; ``speedup``: phoid's
        median sample rate over the others'; ``table``, ``notes``, ``speedup_vs_jitcdde``
        (rtol 1e-10) and ``phoid_max_deviation``: the summary bench/run.py reports;
        ``environment``.
    """
    repeats = max(1, int(repeats))
    plant = Plant(M, C, K)
    n_samples = round(DURATION * FS)
    t = np.arange(n_samples) / FS
    out: dict = {
        "workload": "seed Table 1: 19 runs, m=2 kg, c=1 N·s/m, k=64 N/m, delay 0.1 s, "
        "x0=0.01 m, 15 s at 1 kHz",
        "repeats": repeats,
    }

    # --- phoid, the 19-run batch (first call outside the timing: imports, caches)
    def phoid19():
        return simulate(plant, P19, D19, delay=DELAY, duration=DURATION, fs=FS, x0=X0)

    phoid19()
    times, sim = _timed(phoid19, repeats)
    out["phoid_table1"] = _stats(times, 19 * n_samples)

    # --- jitcdde: compile once (fresh, into a temporary cache), then integrate
    with tempfile.TemporaryDirectory() as tmp:
        old = jitc_reference._module_path
        jitc_reference._module_path = lambda delay: os.path.join(tmp, "phoid_ref_bench.so")
        try:
            _, compile_s = jitc_reference.compile_module(DELAY)
        finally:
            jitc_reference._module_path = old
    jitc_reference.compile_module(DELAY)  # the shared cache used below
    tight = _jitcdde_sweep(t, TIGHT_RTOL)
    out["jitcdde"] = {"compile_seconds": compile_s, "tight_rtol": TIGHT_RTOL, "by_rtol": {}}
    jit_rates = {}
    for rtol in (1e-10, 1e-12):
        times, xs = _timed(lambda rtol=rtol: _jitcdde_sweep(t, rtol), repeats)
        st = _stats(times, 19 * n_samples)
        st["max_deviation_rel_x0"] = float(np.max(np.abs(xs - tight)) / X0)
        out["jitcdde"]["by_rtol"][f"{rtol:g}"] = st
        jit_rates[rtol] = st["samples_per_s_median"]

    # --- scipy solve_ivp, method of steps, one run (the paper's last, fastest-decaying one)
    i = 18
    times, x_mos = _timed(lambda: method_of_steps(P19[i], D19[i], t), repeats)
    mos = _stats(times, n_samples)
    mos["run"] = i
    mos["rtol"] = 1e-10
    mos["max_deviation_rel_x0"] = float(np.max(np.abs(x_mos - tight[i])) / X0)
    out["solve_ivp_method_of_steps"] = mos

    out["max_deviation_rel_x0"] = {
        "phoid": float(np.max(np.abs(sim.x_true - tight)) / X0),
        "jitcdde_rtol_1e-10": out["jitcdde"]["by_rtol"]["1e-10"]["max_deviation_rel_x0"],
        "solve_ivp_method_of_steps": mos["max_deviation_rel_x0"],
        "reference": f"jitcdde rtol {TIGHT_RTOL:g}",
    }

    # --- phoid on 1000 runs spanning the Table 1 gain range
    P1k = np.linspace(P19[0], P19[-1], 1000)
    D1k = np.linspace(D19[0], D19[-1], 1000)

    def phoid1000():
        return simulate(plant, P1k, D1k, delay=DELAY, duration=DURATION, fs=FS, x0=X0)

    times, _ = _timed(phoid1000, max(1, min(repeats, 3)))
    out["phoid_batch1000"] = _stats(times, 1000 * n_samples)

    rate = out["phoid_table1"]["samples_per_s_median"]
    out["speedup"] = {
        "vs_jitcdde_rtol_1e-10": rate / jit_rates[1e-10],
        "vs_jitcdde_rtol_1e-12_equal_accuracy": rate / jit_rates[1e-12],
        "vs_solve_ivp_method_of_steps": rate / mos["samples_per_s_median"],
    }

    # summary rows for bench/run.py's BENCHMARKS.md
    def rate(st: dict) -> str:
        return (
            f"{st['samples_per_s_median']:.3g} ({st['samples_per_s_min']:.3g}–"
            f"{st['samples_per_s_max']:.3g})"
        )

    jit = out["jitcdde"]["by_rtol"]
    out["table"] = [
        {
            "name": "phoid (19-run batch)",
            "rate": rate(out["phoid_table1"]),
            "deviation": f"{out['max_deviation_rel_x0']['phoid']:.1e}",
        },
        {"name": "phoid (1000-run batch)", "rate": rate(out["phoid_batch1000"]), "deviation": "–"},
        {
            "name": "jitcdde rtol 1e-10",
            "rate": rate(jit["1e-10"]),
            "deviation": f"{jit['1e-10']['max_deviation_rel_x0']:.1e}",
        },
        {
            "name": "jitcdde rtol 1e-12 (the reference)",
            "rate": rate(jit["1e-12"]),
            "deviation": "0 (itself)",
        },
        {
            "name": "solve_ivp DOP853 rtol 1e-10, method of steps (1 run)",
            "rate": rate(mos),
            "deviation": f"{mos['max_deviation_rel_x0']:.1e}",
        },
    ]
    out["notes"] = [
        f"jitcdde compile time (once, excluded above): {compile_s:.2f} s. Deviations are the "
        f"largest |x − x_ref|/x₀ over all samples, x_ref = jitcdde at rtol {TIGHT_RTOL:g} "
        "(itself good to ~1e-11·x₀, which bounds what phoid's figure can show).",
        f"At equal accuracy (jitcdde rtol 1e-12) phoid is "
        f"{out['speedup']['vs_jitcdde_rtol_1e-12_equal_accuracy']:.0f}× faster.",
    ]
    out["speedup_vs_jitcdde"] = out["speedup"]["vs_jitcdde_rtol_1e-10"]
    out["phoid_max_deviation"] = out["max_deviation_rel_x0"]["phoid"]
    out["environment"] = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
    }
    return out


if __name__ == "__main__":
    print(json.dumps(run(int(sys.argv[1]) if len(sys.argv) > 1 else 5), indent=2))
