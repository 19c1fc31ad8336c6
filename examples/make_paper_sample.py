"""Make ``examples/paper-sample/``: the seed paper's Table 1 experiment, by an independent solver.

The records are NOT made by phoid's simulator: each run's closed loop (eq. 23 of the seed paper,
docs/equations.md),

    m x'' + c x' + k x = u(t),   u(t) = −P x(t − Δt) − D x'(t − Δt),

is integrated by jitcdde (tests/jitc_reference.py, relative tolerance 1e−10, every step landing
on the output instants and on the release's kinks at multiples of Δt), the reference the test
suite checks phoid's simulator against. phoid is used only for the Cramér–Rao bound written to
``truth.json`` (bench/crb.py), never for the data.

The experiment (the seed paper's, ERRATA 6 in docs/equations.md):

* plant m = 2 kg, c = 1 N·s/m, k = 64 N/m, no friction; loop delay Δt = 0.1 s;
* 19 runs, Pᵢ = 0.25 + 1.375 i N/m, Dᵢ = 0.6 + 0.3 i N·s/m (i = 0 … 18), each gain the double
  nearest its decimal (D₁ = 0.9, not the sum 0.8999999999999999; the records were first
  computed with the sums, at most 1 ulp from these: rerun with these, every data file came out
  byte for byte the same);
* each run held at x₀ = 10 mm (the loop closed, u = −P x₀) for 0.2 s, then released from rest
  (the past before the release is the held x₀), and recorded for 15 s after the release at
  1 kHz: 15 200 samples from t = 0;
* x: the solution plus an offset of −0.3 mm plus white Gaussian noise of sd 0.1 mm, then
  rounded to 1 µm (an encoder's quantisation); written with 6 decimals (m);
* u: the applied loop force (N), noise-free, u(t) = −P x(t − 0.2 − Δt) − D x'(t − 0.2 − Δt)
  from the solution (−P x₀ until Δt after the release), rounded to 1 µN (a controller's
  output resolution; 2e−5 to 3e−6 of the runs' largest |u|);
* t: s, written with 3 decimals (exact at 1 kHz).

Deterministic: the noise comes from ``numpy.random.default_rng(SEED)``, and the files are
gzipped without a time stamp, so a rerun with the same numpy and jitcdde rewrites the same
bytes (a different compiler or CPU may move the solution by ~1e−12 m, which can flip a rare
1 µm rounding).

Run from the repository root, with the test extras installed (jitcdde needs a C compiler)::

    python examples/make_paper_sample.py            # rewrites examples/paper-sample/

It takes a few seconds (plus ≈3 s to compile the jitcdde module on first use).
"""

from __future__ import annotations

import argparse
import gzip
import importlib.metadata
import io
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "bench")]

import jitc_reference  # noqa: E402  (tests/: the independent DDE solver)

SEED = 20240615
M, C, K = 2.0, 1.0, 64.0  # kg, N·s/m, N/m
DELAY = 0.1  # s
I19 = np.arange(19)
P = 0.25 + 1.375 * I19  # N/m   (the same doubles as bench/sets.py's TABLE1)
# N·s/m: the decimals 0.6, 0.9, …, 6.0 (an integer over 10 is the double nearest each);
# 0.6 + 0.3 i would be 0.8999999999999999 for i = 1 and 5.999999999999999 for i = 18
D = (6 + 3 * I19) / 10
X0 = 0.01  # m, release position
FS = 1000.0  # Hz
HOLD = 0.2  # s, held segment before the release
DURATION = 15.0  # s, record after the release
NOISE = 1e-4  # m, white Gaussian sd
QUANTUM = 1e-6  # m
U_QUANTUM = 1e-6  # N, resolution of the written u
OFFSET = -3e-4  # m
RTOL = 1e-10  # jitcdde relative tolerance (absolute: RTOL·x₀)


def run_records(p: float, d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t (s), noise-free x(t) (m) and u(t) (N, rounded to 1 µN) of one run, hold included."""
    n_hold = round(HOLD * FS)
    n = n_hold + round(DURATION * FS)
    k = np.arange(n)
    t = k / FS
    tau = (k[n_hold:] - n_hold) / FS  # time since the release, exact multiples of 1 ms
    xr, vr = jitc_reference.jitcdde_reference(M, C, K, p, d, DELAY, X0, tau, rtol=RTOL,
                                              return_velocity=True)
    x = np.concatenate([np.full(n_hold, X0), xr])
    v = np.concatenate([np.zeros(n_hold), vr])
    # the controller sees the state Δt ago: a shift by a whole number of samples at 1 kHz
    lag = round(DELAY * FS)
    assert abs(lag / FS - DELAY) < 1e-15
    x_lag = np.concatenate([np.full(lag, X0), x[:-lag]])
    v_lag = np.concatenate([np.zeros(lag), v[:-lag]])
    u = -p * x_lag - d * v_lag
    return t, x, np.round(u / U_QUANTUM) * U_QUANTUM + 0.0


def measured(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Offset, white noise, then 1 µm quantisation (m)."""
    y = x + OFFSET + NOISE * rng.standard_normal(x.size)
    return np.round(y / QUANTUM) * QUANTUM + 0.0  # + 0.0: no "-0.000000"


def csv_gz(t: np.ndarray, x: np.ndarray, u: np.ndarray) -> bytes:
    """The run's CSV (columns t, x, u), gzipped without a time stamp."""
    buf = io.StringIO()
    buf.write("t,x,u\n")
    for ti, xi, ui in zip(t, x, u, strict=True):
        buf.write(f"{ti:.3f},{xi:.6f},{ui:.6f}\n")
    return gzip.compress(buf.getvalue().encode(), compresslevel=9, mtime=0)


def manifest(files: list[str]) -> str:
    """The phoid/1 experiment.toml (docs/format.md)."""
    lines = ['title = "paper-sample"', 'format = "phoid/1"', 'method = "pho"', "",
             "[loop]", f"delay = {DELAY!r}", ""]
    for f, p, d in zip(files, P, D, strict=True):
        lines += ["[[run]]", f'file = "{f}"', f"P = {float(p)!r}", f"D = {float(d)!r}", ""]
    return "\n".join(lines)


def truth() -> dict:
    """True values, how the set was made, and the Cramér–Rao sd of m, c, k (bench/crb.py)."""
    import crb
    from sets import TABLE1, SetSpec

    spec = SetSpec("paper-sample", M, C, K, DELAY, tuple(map(float, P)), tuple(map(float, D)),
                   fs=FS, duration=DURATION, hold=HOLD, x0=X0, noise=NOISE, quantum=QUANTUM,
                   offset=OFFSET)
    assert (spec.P, spec.D) == (TABLE1.P, TABLE1.D)  # the benchmark's Table 1 set
    sd = crb.crb_sd(spec)  # residue amplitudes (the exact single-mode model)
    return {
        "m": M, "c": C, "k": K, "fc": 0.0, "delay": DELAY, "noise": NOISE,
        "quantum": QUANTUM, "u_quantum": U_QUANTUM, "offset": OFFSET, "x0": X0, "fs": FS,
        "T": DURATION, "hold": HOLD, "P": [float(p) for p in P], "D": [float(d) for d in D],
        "seed": SEED,
        "note": (
            "made by examples/make_paper_sample.py with an independent DDE solver "
            f"(jitcdde {importlib.metadata.version('jitcdde')}, rtol {RTOL:g}; "
            "tests/jitc_reference.py), not by phoid; a 0.2 s held segment (x = x0, "
            "u = -P x0) precedes the release from rest at t = 0.2 s; x: offset -0.3 mm, "
            "white Gaussian noise sd 0.1 mm, then 1 um quantisation; u: noise-free loop "
            "force -P x(t - delay) - D x'(t - delay), rounded to 1 uN"
        ),
        "crb_sd": {
            "m": float(sd[0]), "c": float(sd[1]), "k": float(sd[2]),
            "note": (
                "Cramer-Rao standard deviations for this set (bench/crb.py, amplitude "
                "'residue'): per run a single dominant mode with amplitude, phase and "
                "offset unknown, its true amplitude the mode's residue in the response to "
                "the release; delay known; white noise of sd sqrt(noise^2 + quantum^2/12)"
            ),
        },
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "examples" / "paper-sample",
                    help="output folder (rewritten)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    files = []
    for i, (p, d) in enumerate(zip(P, D, strict=True), start=1):
        t, x, u = run_records(float(p), float(d))
        name = f"run{i:02d}.csv.gz"
        (args.out / name).write_bytes(csv_gz(t, measured(x, rng), u))
        files.append(name)
    (args.out / "experiment.toml").write_text(manifest(files))
    (args.out / "truth.json").write_text(json.dumps(truth(), indent=1) + "\n")
    size = sum(f.stat().st_size for f in args.out.iterdir())
    print(f"wrote {len(files)} runs to {args.out} ({size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
