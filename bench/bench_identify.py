"""Identification benchmark: phoid vs a curve_fit pipeline vs the paper's log-decrement pipeline.

Three pipelines on the same records:

* **phoid** — ``phoid.identify`` (dominant-mode fit per run, weighted fit through exact roots);
* **curve_fit + OLS** — per run ``scipy.optimize.curve_fit`` of offset + A e^{−σt}cos(ωt + φ)
  on the same window phoid uses, then eq. (35) by ordinary least squares (what a careful
  notebook user would write);
* **log-decrement + OLS** — ``phoid.decay.logdec`` per run (peaks, sub-sample interpolation,
  noise-floor cut-off), then eq. (35) by OLS (the paper's route).

Accuracy is a Monte Carlo over noisy replicas of the Table 1 set made by phoid's simulator (0.1 mm
noise, 1 µm quantisation, −0.3 mm offset, 0.2 s hold, as in ../shared/data/paper-sample), judged
against the Cramér–Rao standard deviation of that set (../shared/data/truth.json).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from scipy.optimize import curve_fit

from phoid.decay import logdec
from phoid.identification import identify_data, measure_modes
from phoid.io import read_experiment
from phoid.paper import PAPER_D, PAPER_DELAY, PAPER_P, PAPER_PLANT
from phoid.pho import fit_lines
from phoid.simulation import simulate

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
TRUE = np.array([PAPER_PLANT.m, PAPER_PLANT.c, PAPER_PLANT.k])


def _crb() -> np.ndarray:
    t = json.loads((SHARED / "data" / "truth.json").read_text())["paper-sample"]["crb_sd"]
    return np.array([t["m"], t["c"], t["k"]])


def _damped(t, off, a, b, s, w):
    e = np.exp(-s * t)
    return off + e * (a * np.cos(w * t) + b * np.sin(w * t))


def curve_fit_pipeline(data, P, D, delay, windows):
    """Per-run curve_fit on the given windows (t0, t1), then eq. (35) by OLS."""
    sig, om = [], []
    for (t, x), (t0, guess) in zip(data, windows, strict=True):
        sel = t >= t0
        tt, xx = t[sel] - t0, x[sel]
        p0 = [xx[-len(xx) // 10:].mean(), xx[0] - xx[-1], 0.0, guess[0], guess[1]]
        popt, _ = curve_fit(_damped, tt, xx, p0=p0, maxfev=20000)
        sig.append(popt[3])
        om.append(abs(popt[4]))
    f = fit_lines(np.array(sig), np.array(om), P, D, delay)
    return np.array([f.m, f.c, f.k])


def logdec_pipeline(data, P, D, delay, windows):
    """Per-run logarithmic decrement on the same windows, then eq. (35) by OLS."""
    sig, om = [], []
    for (t, x), (t0, _g) in zip(data, windows, strict=True):
        f = logdec(t, x, skip=0.0, release=t0)
        sig.append(f.sigma)
        om.append(f.omega_d)
    f = fit_lines(np.array(sig), np.array(om), P, D, delay)
    return np.array([f.m, f.c, f.k])


def _windows(data):
    fits, _reasons, _ = measure_modes(data, PAPER_P, PAPER_D, PAPER_DELAY)
    return [(f.t_start, (f.sigma, f.omega_d)) for f in fits]


def speed(repeats: int = 7) -> dict:
    """Median (min–max) compute time to identify the 19-run sample set, per pipeline."""
    exp = read_experiment(SHARED / "data" / "paper-sample")
    data = [(r.t, r.x) for r in exp.runs]
    P = np.array([r.P for r in exp.runs])
    D = np.array([r.D for r in exp.runs])
    win = _windows(data)
    out = {}
    for name, fn in (
        ("phoid", lambda: identify_data(data, P, D, exp.delay)),
        ("curve_fit+OLS", lambda: curve_fit_pipeline(data, P, D, exp.delay, win)),
        ("logdec+OLS", lambda: logdec_pipeline(data, P, D, exp.delay, win)),
    ):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        out[name] = {"median_s": float(np.median(times)), "min_s": float(min(times)),
                     "max_s": float(max(times))}
    t0 = time.perf_counter()
    read_experiment(SHARED / "data" / "paper-sample")
    out["read_experiment_s"] = time.perf_counter() - t0
    return out


def monte_carlo(replicas: int = 200, seed: int = 2026) -> dict:
    """Bias, RMSE, RMSE/CRB, mean stderr/observed sd and ±3σ coverage for each pipeline."""
    rng = np.random.default_rng(seed)
    crb = _crb()
    est = {"phoid": [], "curve_fit+OLS": [], "logdec+OLS": []}
    se = []
    batch = 25
    done = 0
    while done < replicas:
        nb = min(batch, replicas - done)
        P = np.tile(PAPER_P, nb)
        D = np.tile(PAPER_D, nb)
        sim = simulate(PAPER_PLANT, P, D, delay=PAPER_DELAY, duration=15.0, fs=1000.0, x0=0.01,
                       hold=0.2, noise=1e-4, quantum=1e-6, offset=-3e-4, rng=rng)
        for b in range(nb):
            data = [(sim.t, sim.x[b * 19 + i]) for i in range(19)]
            r = identify_data(data, PAPER_P, PAPER_D, PAPER_DELAY)
            est["phoid"].append([r.m.value, r.c.value, r.k.value])
            se.append([r.m.stderr, r.c.stderr, r.k.stderr])
            win = [(rr.fit.t_start, (rr.sigma, rr.omega_d)) for rr in r.runs]
            try:
                est["curve_fit+OLS"].append(curve_fit_pipeline(data, PAPER_P, PAPER_D,
                                                               PAPER_DELAY, win))
            except RuntimeError:
                est["curve_fit+OLS"].append([math.nan] * 3)
            est["logdec+OLS"].append(logdec_pipeline(data, PAPER_P, PAPER_D, PAPER_DELAY, win))
        done += nb
    se = np.array(se)
    out = {"replicas": replicas, "crb_sd": dict(zip("mck", crb.tolist(), strict=True))}
    for name, e in est.items():
        e = np.array(e, dtype=float)
        e = e[np.all(np.isfinite(e), axis=1)]
        err = e - TRUE
        rmse = np.sqrt(np.mean(err**2, axis=0))
        row = {
            "n": int(e.shape[0]),
            "bias": dict(zip("mck", err.mean(axis=0).tolist(), strict=True)),
            "rmse": dict(zip("mck", rmse.tolist(), strict=True)),
            "rmse_over_crb": dict(zip("mck", (rmse / crb).tolist(), strict=True)),
            "bias_over_crb": dict(zip("mck", (err.mean(axis=0) / crb).tolist(), strict=True)),
        }
        if name == "phoid":
            sd = e.std(axis=0, ddof=1)
            row["stderr_over_sd"] = dict(zip("mck", (se.mean(axis=0) / sd).tolist(),
                                             strict=True))
            row["coverage_3se"] = dict(zip("mck", (np.abs(err) < 3 * se).mean(axis=0).tolist(),
                                           strict=True))
        out[name] = row
    return out


if __name__ == "__main__":
    print(json.dumps({"speed": speed(), "monte_carlo": monte_carlo(40)}, indent=1))
