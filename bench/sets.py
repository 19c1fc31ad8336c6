"""The three experiment sets of the benchmark, and the checks that every run of them rings.

* **table1** — the seed paper's Table 1 set (ERRATA 6): m = 2 kg, c = 1 N·s/m, k = 64 N/m,
  Δt = 0.1 s, Pᵢ = 0.25 + 1.375 i N/m, Dᵢ = 0.6 + 0.3 i N·s/m (i = 0 … 18), 15 s at 1 kHz,
  released from 10 mm after a 0.2 s hold; 0.1 mm noise, 1 µm quantisation, −0.3 mm offset (as
  examples/paper-sample and ../shared/data/paper-sample).
* **overdamped** — m = 0.5 kg, c = 40 N·s/m, k = 20 N/m (ζ = 6.3: open-loop roots −0.5 and
  −79.5 1/s), Δt = 5 ms. The loop must *remove* damping to ring, so D < 0:
  Pᵢ = 50 + 72 i N/m, Dᵢ = −38.4 + 0.6 i N·s/m (i = 0 … 14). The end points were chosen by
  placing the dominant root at −1 + 10i and −4 + 40i 1/s (D s + P = −(m s² + c s + k)e^{sΔt}
  there) and rounding; the runs ring at σ = 1.0 … 4.0 1/s, ω_d = 10 … 40 rad/s. 5 s at 1 kHz,
  released from 5 mm.
* **mass_damper** — m = 1 kg, c = 10 N·s/m, k = 0 (no spring: open-loop roots 0 and −10 1/s),
  Δt = 10 ms. P supplies all the stiffness; D < 0 in the first runs lowers the damping:
  Pᵢ = 110 + 80 i N/m, Dᵢ = −6.8 + 1.4 i N·s/m (i = 0 … 11); σ = 1.0 … 4.4 1/s,
  ω_d = 10 … 32 rad/s. 5 s at 1 kHz, released from 20 mm.

Noise and quantisation scale with the release amplitude as in the Table 1 set: noise sd
1 % of x₀, quantisation step 1e−4 x₀, offset −3 % of x₀, 0.2 s hold. Each set's σ_min × record
length is about 5, so the slowest run decays into the noise (ln 100 ≈ 4.6) within the record, as
the Table 1 set's does (0.38 × 15).

:func:`check_rings` verifies, with phoid's certified root finder (:mod:`phoid.dynamics`), that
every
run is stable and its dominant pair is complex (the loop rings) and well separated from the next
mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid import DelayedPD, Plant, characteristic_roots, simulate


@dataclass(frozen=True)
class SetSpec:
    """A PHO experiment set for the benchmark: plant, loop, gains, timing and measurement.

    Attributes
    ----------
    name : str
    m, c, k : float
        Plant mass (kg), viscous damping (N·s/m), stiffness (N/m).
    delay : float
        Loop delay Δt, s.
    P, D : tuple of float
        Gains of the runs, N/m and N·s/m.
    fs : float
        Sample rate, Hz.
    duration : float
        Record length after the release, s.
    hold : float
        Held segment before the release, s.
    x0 : float
        Release displacement, m.
    noise : float
        White Gaussian sensor-noise sd, m.
    quantum : float
        Quantisation step, m.
    offset : float
        Sensor offset, m.
    """

    name: str
    m: float
    c: float
    k: float
    delay: float
    P: tuple[float, ...]
    D: tuple[float, ...]
    fs: float
    duration: float
    hold: float
    x0: float
    noise: float
    quantum: float
    offset: float

    @property
    def theta(self) -> np.ndarray:
        """(m, c, k) as an array."""
        return np.array([self.m, self.c, self.k])

    @property
    def plant(self) -> Plant:
        return Plant(self.m, self.c, self.k)

    @property
    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        """(P, D) as arrays."""
        return np.asarray(self.P, dtype=float), np.asarray(self.D, dtype=float)

    @property
    def runs(self) -> int:
        return len(self.P)

    @property
    def noise_sd(self) -> float:
        """Effective white-noise sd, m: √(s² + q²/12) (rounding to a step q adds q²/12)."""
        return math.sqrt(self.noise**2 + self.quantum**2 / 12.0)

    def describe(self) -> str:
        """One line: plant, delay, gains, timing, noise."""
        P, D = self.gains
        return (
            f"m {self.m:g} kg, c {self.c:g} N s/m, k {self.k:g} N/m, Δt {self.delay * 1e3:g} ms;"
            f" {self.runs} runs, P {P[0]:g}…{P[-1]:g} N/m, D {D[0]:g}…{D[-1]:g} N s/m;"
            f" {self.duration:g} s at {self.fs / 1e3:g} kHz after a {self.hold:g} s hold,"
            f" x₀ {self.x0 * 1e3:g} mm, noise {self.noise * 1e6:g} µm,"
            f" quantum {self.quantum * 1e6:g} µm, offset {self.offset * 1e3:g} mm"
        )


def _scaled(name, m, c, k, delay, P, D, *, fs, duration, x0) -> SetSpec:
    return SetSpec(name, m, c, k, delay, tuple(float(p) for p in P), tuple(float(d) for d in D),
                   fs=fs, duration=duration, hold=0.2, x0=x0, noise=1e-2 * x0,
                   quantum=1e-4 * x0, offset=-3e-2 * x0)


_I19, _I15, _I12 = np.arange(19), np.arange(15), np.arange(12)
TABLE1 = _scaled("table1", 2.0, 1.0, 64.0, 0.1, 0.25 + 1.375 * _I19, (6 + 3 * _I19) / 10,
                 fs=1000.0, duration=15.0, x0=0.01)
OVERDAMPED = _scaled("overdamped", 0.5, 40.0, 20.0, 0.005, 50.0 + 72.0 * _I15,
                     -38.4 + 0.6 * _I15, fs=1000.0, duration=5.0, x0=0.005)
MASS_DAMPER = _scaled("mass_damper", 1.0, 10.0, 0.0, 0.01, 110.0 + 80.0 * _I12,
                      -6.8 + 1.4 * _I12, fs=1000.0, duration=5.0, x0=0.02)
SETS = {s.name: s for s in (TABLE1, OVERDAMPED, MASS_DAMPER)}


def check_rings(spec: SetSpec) -> dict:
    """Certify that every run of the set is stable and rings; return its dominant modes.

    For each run, :func:`phoid.characteristic_roots` (certified by the argument principle)
    must give a rightmost pair with Re s < 0 and Im s > 0, and the next root must be at least
    5× faster (so the run's decay is one dominant mode after the loop's fast transient).

    Returns
    -------
    dict
        ``sigma``, ``omega_d`` (dominant modes, 1/s and rad/s) and ``next_rate`` (−Re of the
        next root, 1/s) of every run.

    Raises
    ------
    ValueError
        Naming the run that is unstable, does not ring or has no separated dominant pair.
    """
    sig, wd, nxt = [], [], []
    for i, (p, d) in enumerate(zip(*spec.gains, strict=True)):
        r = characteristic_roots(spec.plant, DelayedPD(float(p), float(d), spec.delay), count=4)
        s0 = r[0] if r[0].imag >= 0 else r[1]
        if not (s0.real < 0 and s0.imag > 0):
            raise ValueError(f"{spec.name}: run {i + 1} (P={p:g}, D={d:g}) does not ring "
                             f"stably: dominant root {s0:.4g}")
        if not r[2].real < 5 * s0.real:
            raise ValueError(f"{spec.name}: run {i + 1}: next root {r[2]:.4g} is not well "
                             f"separated from the dominant pair {s0:.4g}")
        sig.append(-s0.real)
        wd.append(s0.imag)
        nxt.append(-r[2].real)
    return {"sigma": sig, "omega_d": wd, "next_rate": nxt}


def simulate_replicas(spec: SetSpec, n: int, rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` noisy replicas of the set by phoid's simulator: t (N,), x (n, runs, N)."""
    P, D = spec.gains
    sim = simulate(spec.plant, np.tile(P, n), np.tile(D, n), delay=spec.delay,
                   duration=spec.duration, fs=spec.fs, x0=spec.x0, hold=spec.hold,
                   noise=spec.noise, quantum=spec.quantum, offset=spec.offset, rng=rng)
    return sim.t, sim.x.reshape(n, spec.runs, -1)
