"""`phoid design` benchmark: time to design, gain over the paper's sweep, and Monte Carlo check.

For each case a schedule is designed; its predicted (Cramér–Rao) standard errors of m, c, k are
compared with the spread of ``phoid.identify_data`` over noisy replicas simulated by
``phoid.simulate`` (same settings as the design: record length, sample rate, noise, release
amplitude), and the coverage of |estimate − truth| < 3·stderr is counted.

With n replicas the sample sd has a relative sd of ≈ 1/√(2(n − 1)) (3.5 % at n = 400), so
ratios MC sd / predicted within a few per cent of 1 mean the prediction is right and the
estimator efficient.

Usage::

    python bench/bench_design.py [--replicas 400] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from phoid.api import identify_data
from phoid.dynamics.plant import Plant
from phoid.planning import design
from phoid.planning.fisher import cramer_rao
from phoid.simulation import simulate

PAPER_P = 0.25 + 1.375 * np.arange(19)  # ERRATA 6
PAPER_D = 0.6 + 0.3 * np.arange(19)

CASES = {
    # name: (prior m, c, k), design keywords, true plant
    "paper plant, 19 runs": (
        (2.0, 1.0, 64.0),
        dict(delay=0.1, runs=19, pmax=25.0, dmax=6.0, duration=15.0, noise=1e-4), (2, 1, 64)),
    "overdamped": ((0.5, 40.0, 20.0), dict(delay=0.005), (0.5, 40, 20)),
    "mass-damper": ((1.0, 10.0, 0.0), dict(delay=0.01), (1, 10, 0)),
    "overdamped, c 20:60 (truth c = 60)": (
        (0.5, "20:60", 20.0), dict(delay=0.005), (0.5, 60, 20)),
}


def monte_carlo(d, truth, n: int, seed: int, chunk: int = 50) -> dict:
    """Identify n simulated replicas of the designed set; spread, coverage, bias."""
    st = d.settings
    R = len(d.runs)
    m, c, k = truth
    rng = np.random.default_rng(seed)
    est, se, failed = [], [], 0
    for start in range(0, n, chunk):
        b = min(chunk, n - start)
        sim = simulate(Plant(m, c, k), np.tile(d.P, b), np.tile(d.D, b), delay=st.delay,
                       duration=st.duration, fs=st.fs, x0=st.amplitude, hold=0.2,
                       noise=st.noise, rng=rng)
        for j in range(b):
            try:
                res = identify_data([(sim.t, sim.x[j * R + i]) for i in range(R)], d.P, d.D,
                                    st.delay)
            except ValueError:
                failed += 1
                continue
            est.append([res.m.value, res.c.value, res.k.value])
            se.append([res.m.stderr, res.c.stderr, res.k.stderr])
    est, se = np.array(est), np.array(se)
    err = est - np.array([m, c, k], dtype=float)
    return {
        "replicas": len(est),
        "failed": failed,
        "mc_sd": est.std(axis=0, ddof=1).tolist(),
        "coverage_3se": np.mean(np.abs(err) < 3 * se, axis=0).tolist(),
        "bias_over_sd": (err.mean(axis=0) / est.std(axis=0, ddof=1)).tolist(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicas", type=int, default=400)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None, help="write the results here")
    args = ap.parse_args()
    results = {}
    for name, (prior, kw, truth) in CASES.items():
        t0 = time.perf_counter()
        d = design(*prior, **kw)
        t_design = time.perf_counter() - t0
        # predicted stderr at the true plant (differs from the nominal one for a prior range)
        st = d.settings
        pred = cramer_rao(*map(float, truth), d.P, d.D, st.delay, fs=st.fs,
                          duration=st.duration, noise=st.noise, x0=st.amplitude).stderr
        row = {"design_s": t_design, "runs": len(d.runs), "predicted": pred.tolist()}
        if name.startswith("paper"):
            ref = cramer_rao(2.0, 1.0, 64.0, PAPER_P, PAPER_D, 0.1, fs=st.fs,
                             duration=st.duration, noise=st.noise, x0=st.amplitude).stderr
            row["paper_sweep"] = ref.tolist()
            row["gain"] = (ref / pred).tolist()
        t0 = time.perf_counter()
        row.update(monte_carlo(d, truth, args.replicas, args.seed))
        row["mc_s"] = time.perf_counter() - t0
        row["ratio"] = (np.array(row["mc_sd"]) / pred).tolist()
        results[name] = row
        print(f"{name}: design {t_design * 1e3:.0f} ms, {row['runs']} runs")
        if "gain" in row:
            print("  paper sweep / designed stderr (m, c, k): "
                  + ", ".join(f"{g:.1f}" for g in row["gain"]))
        print("  MC sd / predicted (m, c, k): " + ", ".join(f"{r:.3f}" for r in row["ratio"])
              + f"  [{row['replicas']} replicas, {row['failed']} failed, {row['mc_s']:.0f} s]")
        print("  coverage |err| < 3 stderr: "
              + ", ".join(f"{v:.3f}" for v in row["coverage_3se"]))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
