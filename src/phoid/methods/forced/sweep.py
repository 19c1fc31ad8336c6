"""Simulated sine sweeps: the records of a forced experiment, one run per frequency."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from phoid import _validate as v
from phoid.io import Run, run_from_arrays

__all__ = ["simulate_forced"]


def simulate_forced(
    plant: Any,
    omega: Any,
    *,
    B: float = 1.0,
    theta: float = 0.0,
    duration: float,
    fs: float,
    hold: float = 0.0,
    x0: float = 0.0,
    noise: float = 0.0,
    force_noise: float = 0.0,
    quantum: float = 0.0,
    offset: float = 0.0,
    rng: np.random.Generator | None = None,
) -> list[Run]:
    """Simulate a sine sweep: one run per frequency, as :class:`~phoid.io.Run` with column F.

    The plant (no feedback) rests at x₀ (held there during ``hold``), then the force
    F(t) = B sin(ω(t − hold) − θ) (eq. 16) is switched on; the record holds t, the measured
    x (offset, white noise, quantisation as in :func:`phoid.simulate`) and F (0 before the
    onset, plus optional white noise).

    Parameters
    ----------
    plant : phoid.Plant
    omega : float or array_like
        Forcing frequencies, rad/s (> 0, below the Nyquist rate π f_s).
    B : float, default 1
        Force amplitude, N (> 0).
    theta : float, default 0
        Force phase θ of eq. (16), rad.
    duration : float
        Record length after the onset, s.
    fs : float
        Sample rate, Hz.
    hold : float, default 0
        Rest before the force starts, s.
    x0 : float, default 0
        Position during the rest, m (0: the equilibrium).
    noise, force_noise : float, default 0
        White-noise sd added to x (m) and to F (N); need ``rng``.
    quantum, offset : float, default 0
        Quantisation step and offset of the measured x, m.
    rng : numpy.random.Generator, optional

    Returns
    -------
    list of phoid.io.Run
        One run per frequency, with ``B`` and ``omega`` set.
    """
    from phoid.simulation import simulate

    ws = np.atleast_1d(v.finite_array("omega", omega))
    fs = v.positive("fs", fs, "Hz")
    B = v.positive("B", B, "N")
    theta = v.finite("theta", theta, "rad")
    hold = v.nonnegative("hold", hold, "s")
    force_noise = v.nonnegative("force_noise", force_noise, "N")
    if ws.size == 0:
        raise ValueError("`omega` must hold at least one frequency")
    for w in ws:
        if not 0 < w < math.pi * fs:
            raise ValueError(f"`omega` must be > 0 and below the Nyquist rate π·fs = "
                             f"{math.pi * fs:.6g} rad/s; got {w:g}")
    if force_noise > 0 and not isinstance(rng, np.random.Generator):
        raise ValueError("`rng` must be a numpy.random.Generator when `force_noise` > 0")

    def force_of(w: float) -> Callable[[np.ndarray], np.ndarray]:
        return lambda t: B * np.sin(w * (t - hold) - theta)

    runs = []
    for i, w in enumerate(ws):
        sim = simulate(plant, 0.0, 0.0, duration=duration, fs=fs, x0=x0, hold=hold,
                       force=force_of(float(w)), noise=noise, quantum=quantum, offset=offset,
                       rng=rng)
        F = np.where(sim.t >= hold, B * np.sin(w * (sim.t - hold) - theta), 0.0)
        if force_noise > 0:
            F = F + force_noise * rng.standard_normal(F.size)  # type: ignore[union-attr]
        runs.append(run_from_arrays(sim.t, sim.x[0], F=F, B=B, omega=float(w), index=i + 1))
    return runs
