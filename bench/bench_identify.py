"""Identification benchmark: phoid vs a curve_fit pipeline vs the paper's log-decrement pipeline.

Three pipelines on the same records:

* **phoid** — ``phoid.identify`` (dominant-mode fit per run, weighted fit through exact roots);
* **curve_fit + OLS** — per run ``scipy.optimize.curve_fit`` of offset + e^{−σt}(a cos ωt +
  b sin ωt) from the release + 3Δt (past the loop's fast transient), started from an FFT peak
  and a Hilbert-envelope slope, then eq. (35) by ordinary least squares (what a careful notebook
  user would write);
* **log-decrement + OLS** — ``phoid.decay.logdec`` per run from the release + 3Δt (peaks,
  sub-sample interpolation, noise-floor cut-off), then eq. (35) by OLS (the paper's route).

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

from phoid.decay import detect_release, logdec
from phoid.identification import identify_data
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


def _naive_guess(tt: np.ndarray, xx: np.ndarray) -> list[float]:
    """Start values a notebook user would compute: FFT peak and Hilbert-envelope slope."""
    from scipy.signal import hilbert

    off = xx[-max(len(xx) // 10, 1):].mean()
    y = xx - off
    dt = tt[1] - tt[0]
    n = 1 << (len(y) * 4 - 1).bit_length()
    spec = np.abs(np.fft.rfft(y, n))
    w = 2 * np.pi * np.fft.rfftfreq(n, dt)[np.argmax(spec[1:]) + 1]
    env = np.abs(hilbert(y))
    keep = env > 0.2 * env.max()
    sl = np.polyfit(tt[keep][: len(tt) // 2], np.log(env[keep][: len(tt) // 2]), 1)[0]
    return [off, y[0], 0.0, max(-sl, 1e-3), w]


def curve_fit_pipeline(data, P, D, delay, releases):
    """Per-run curve_fit from release + 3Δt (past the loop's fast transient), then eq. (35) OLS."""
    sig, om = [], []
    for (t, x), tr in zip(data, releases, strict=True):
        sel = t >= tr + 3 * delay
        tt, xx = t[sel] - t[sel][0], x[sel]
        popt, _ = curve_fit(_damped, tt, xx, p0=_naive_guess(tt, xx), maxfev=20000)
        sig.append(popt[3])
        om.append(abs(popt[4]))
    f = fit_lines(np.array(sig), np.array(om), P, D, delay)
    return np.array([f.m, f.c, f.k])


def logdec_pipeline(data, P, D, delay, releases):
    """Per-run logarithmic decrement from release + 3Δt, then eq. (35) by OLS (the paper)."""
    sig, om = [], []
    for (t, x), tr in zip(data, releases, strict=True):
        f = logdec(t, x, release=tr, skip=3 * delay)
        sig.append(f.sigma)
        om.append(f.omega_d)
    f = fit_lines(np.array(sig), np.array(om), P, D, delay)
    return np.array([f.m, f.c, f.k])


def _releases(data):
    return [detect_release(t, x) for t, x in data]


def speed(repeats: int = 7) -> dict:
    """Median (min–max) compute time to identify the 19-run sample set, per pipeline."""
    exp = read_experiment(SHARED / "data" / "paper-sample")
    data = [(r.t, r.x) for r in exp.runs]
    P = np.array([r.P for r in exp.runs])
    D = np.array([r.D for r in exp.runs])
    out = {}
    for name, fn in (
        ("phoid", lambda: identify_data(data, P, D, exp.delay)),
        ("curve_fit+OLS", lambda: curve_fit_pipeline(data, P, D, exp.delay, _releases(data))),
        ("logdec+OLS", lambda: logdec_pipeline(data, P, D, exp.delay, _releases(data))),
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
            rel = [rr.fit.release for rr in r.runs]
            try:
                est["curve_fit+OLS"].append(curve_fit_pipeline(data, PAPER_P, PAPER_D,
                                                               PAPER_DELAY, rel))
            except RuntimeError:
                est["curve_fit+OLS"].append([math.nan] * 3)
            est["logdec+OLS"].append(logdec_pipeline(data, PAPER_P, PAPER_D, PAPER_DELAY, rel))
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
