"""Coulomb-friction fit (phoid.methods.friction): stderr calibration, bias of the viscous fit, time.

Monte Carlo over noisy replicas of the issue-6 acceptance set — m 1 kg, c 2 N s/m, k 100 N/m,
f_c 0.05 N, Δt 20 ms, 10 runs with P = 0 … 200 N/m and D chosen so that the loop's dominant
root has σ = 0.15 … 0.6 1/s (lightly damped, stable, ringing; checked by the certified root
finder), release 5–10 mm held 0.2 s, 10 µm noise, 1 µm quantisation, 0.3 mm offset, 10 s at
1 kHz — simulated by ``phoid.simulate`` (exact stick–slip) with independent seeds
(``SeedSequence(seed).spawn``).

For every replica: ``identify_friction`` (the full-record fit) and ``identify_data`` (the
viscous dominant-mode fit). Reported: per parameter the mean and sd of z = (estimate − truth) /
stderr (a calibrated estimator gives mean 0, sd 1), the share with |z| < 3 (≥ 99 % promised),
the RMSE next to the mean stderr, the viscous fit's error on c, and the wall time per fit.

    python bench/bench_friction.py                 # 50 replicas (~5 min on 2 busy cores)
    python bench/bench_friction.py --replicas 10   # a quick look
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy.optimize import brentq

from phoid import Plant, simulate
from phoid.api import identify_data
from phoid.dynamics import DelayedPD, characteristic_roots, dominant_roots
from phoid.methods.friction import identify_friction

TRUTH = {"m": 1.0, "c": 2.0, "k": 100.0, "fc": 0.05}
DELAY = 0.02
P_GAINS = np.linspace(0.0, 200.0, 10)
SIGMAS = np.linspace(0.15, 0.6, 10)


def gains() -> tuple[np.ndarray, np.ndarray]:
    """D for each P such that the loop's dominant root has the target σ (viscous part)."""
    m, c, k = TRUTH["m"], TRUTH["c"], TRUTH["k"]

    def sigma(p, d):
        return -dominant_roots(m, c, k, np.array([p]), np.array([d]), DELAY)[0].real

    D = np.array([brentq(lambda d, p=p, s=s: sigma(p, d) - s, -5.0, 10.0)
                  for p, s in zip(P_GAINS, SIGMAS, strict=True)])
    plant = Plant(m, c, k)
    for p, d in zip(P_GAINS, D, strict=True):
        r = characteristic_roots(plant, DelayedPD(p, d, DELAY), count=2)[0]
        assert r.real < 0 and r.imag > 0, (p, d, r)
    return P_GAINS.copy(), D


def replica(rng: np.random.Generator, P: np.ndarray, D: np.ndarray):
    x0 = rng.uniform(5e-3, 10e-3, P.size)
    sim = simulate(Plant(**TRUTH), P, D, delay=DELAY, duration=10.0, fs=1000.0, x0=x0,
                   hold=0.2, noise=10e-6, quantum=1e-6, offset=3e-4, rng=rng)
    return [(sim.t, x) for x in sim.x]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicas", type=int, default=50)
    ap.add_argument("--seed", type=int, default=20261122)
    args = ap.parse_args()
    P, D = gains()
    names = ("m", "c", "k", "fc")
    z = {n: [] for n in names}
    err = {n: [] for n in names}
    se = {n: [] for n in names}
    visc_c, visc_z, times, chi2 = [], [], [], []
    for i, ss in enumerate(np.random.SeedSequence(args.seed).spawn(args.replicas)):
        data = replica(np.random.default_rng(ss), P, D)
        t0 = time.perf_counter()
        fit = identify_friction(data, P, D, DELAY)
        times.append(time.perf_counter() - t0)
        chi2.append(fit.chi2_red)
        for n in names:
            e = getattr(fit, n)
            err[n].append(e.value - TRUTH[n])
            se[n].append(e.stderr)
            z[n].append((e.value - TRUTH[n]) / e.stderr)
        v = identify_data(data, P, D, DELAY)
        visc_c.append(v.c.value)
        visc_z.append((v.c.value - TRUTH["c"]) / v.c.stderr)
        print(f"replica {i + 1}/{args.replicas}: {times[-1]:.2f} s, "
              + ", ".join(f"z_{n} = {z[n][-1]:+.2f}" for n in names), flush=True)
    print(f"\n{args.replicas} replicas of the issue-6 acceptance set (seed {args.seed})")
    print(f"{'':4} {'mean z':>8} {'sd z':>6} {'|z|<3':>6} {'RMSE':>10} {'mean se':>10}")
    for n in names:
        zz = np.array(z[n])
        rmse = math.sqrt(float(np.mean(np.square(err[n]))))
        print(f"{n:4} {zz.mean():+8.3f} {zz.std(ddof=1):6.3f} {np.mean(np.abs(zz) < 3):6.1%} "
              f"{rmse:10.3g} {np.mean(se[n]):10.3g}")
    vc = np.array(visc_c)
    print(f"viscous identify_data: c = {vc.mean():.3f} ± {vc.std(ddof=1):.3f} N s/m "
          f"(truth 2; {100 * (vc.mean() / 2 - 1):+.0f} %, median z = {np.median(visc_z):.0f})")
    print(f"chi2/dof: median {np.median(chi2):.4f}; time per fit: median "
          f"{np.median(times):.2f} s (min {min(times):.2f}, max {max(times):.2f})")


if __name__ == "__main__":
    main()
