"""simulate_tracking on the whole EMPS record against the 40-digit independent reference.

The benchmark loop (EMPS README: central-difference PD, kp, kv, gtau, ±10 V) on the published
IDIM-LS plant (M 95.1089 kg, Fv 203.5034 N s/m, Fc 20.3935 N, OF −3.1648 N, k = 0), driven by
the recorded reference qg from the recorded state at sample 2 (x history qm[0:3], v₀ the central
difference there, the commands before it from vir), for command delays 0 and 1 ms. Compared:
phoid.simulation.tracking.simulate_tracking, the reference of tests/_tracking_reference.py in
mpmath at 40 digits (~20 s per delay) and the same reference in plain floats. Printed: the
largest |x − x_ref| over the 24 839 steps (issue 17's acceptance bound: 1e-9 m) and the
benchmark's relative errors, tracking 100·‖e_meas − e_sim‖/‖e_meas‖ (e = q − qg) and force
100·‖gtau·vir − F_sim‖/‖gtau·vir‖ (issue 17's targets: ≤ 0.30 % and ≤ 5 % with no delay,
≤ 0.45 % and ≤ 7.5 % with a 1-sample delay).

    PYTHONPATH=src python bench/bench_tracking.py            # needs ../shared/data/emps
    PYTHONPATH=src python bench/bench_tracking.py --digits 0 # plain-float reference only
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _tracking_reference import reference_tracking  # noqa: E402

from phoid import Plant  # noqa: E402
from phoid.dynamics.controller import SampledController  # noqa: E402
from phoid.simulation.tracking import simulate_tracking  # noqa: E402

EMPS_FILE = ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat"
PLANT = {"m": 95.1089, "c": 203.5034, "k": 0.0, "fc": 20.3935}
OFFSET = -3.1648
T = 1e-3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--digits", type=int, default=40,
                        help="mpmath digits of the exact reference (0: skip it)")
    args = parser.parse_args()
    if not EMPS_FILE.is_file():
        sys.exit(f"the EMPS record is absent: {EMPS_FILE}")
    from scipy.io import loadmat

    data = loadmat(EMPS_FILE)
    t, qm, qg, vir = (data[k].ravel() for k in ("t", "qm", "qg", "vir"))
    gtau, kp, kv = (float(data[k].ravel()[0]) for k in ("gtau", "kp", "kv"))
    start = {"x_init": qm[:3], "v0": (qm[2] - qm[0]) / (2 * T), "u_init": vir[:2],
             "t0": float(t[2]), "offset": OFFSET}
    r = qg[2:]
    e_meas, f_meas = qm[2:] - qg[2:], gtau * vir[2:]

    def errors(x, force):
        return (100 * np.linalg.norm(e_meas - (x - r)) / np.linalg.norm(e_meas),
                100 * np.linalg.norm(f_meas - force) / np.linalg.norm(f_meas))

    for delay in (0.0, T):
        ctrl = SampledController(T, kp, 1.0, gain=kv, command_gain=gtau,
                                 velocity="central-difference", delay=delay, saturation=10.0)
        tic = time.perf_counter()
        sim = simulate_tracking(Plant(**PLANT), ctrl, r, **start)
        runs = {"simulate_tracking": (sim.x, sim.force, time.perf_counter() - tic)}
        for digits in ([None, args.digits] if args.digits else [None]):
            tic = time.perf_counter()
            ref = reference_tracking(*PLANT.values(), T=T, P=kp, D=1.0, K=kv, G=gtau,
                                     velocity="central-difference", delay=delay,
                                     saturation=10.0, r=r, precision=digits, **start)
            name = f"reference {digits} digits" if digits else "reference float64"
            runs[name] = (ref.x, ref.force, time.perf_counter() - tic)
        exact = runs[f"reference {args.digits} digits" if args.digits else "reference float64"]
        print(f"delay {delay * 1e3:g} ms, {len(r)} steps")
        for name, (x, force, secs) in runs.items():
            track, frel = errors(x, force)
            print(f"  {name:24s} max|x − x_ref| {np.max(np.abs(x - exact[0])):.2e} m   "
                  f"tracking {track:.4f} %   force {frel:.4f} %   {secs:.2f} s")


if __name__ == "__main__":
    main()
