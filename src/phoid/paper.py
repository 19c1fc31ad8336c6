"""The seed paper's Table 1 and Figure 1, reproduced.

The paper simulates m = 2 kg, c = 1 N·s/m, k = 64 N/m under PD feedback delayed by Δt = 0.1 s,
19 runs with Pᵢ = 0.25 + 1.375 i N/m and Dᵢ = 0.6 + 0.3 i N·s/m (i = 0 … 18, ERRATA 6 in
docs/equations.md), measures each run's σᵢ, ω_dᵢ and fits the two lines of eq. (35) with and
without delay compensation.

phoid does the same with its own simulator (noise-free, 15 s at 1 kHz, released from 10 mm with
the controller already running during a short hold) and its dominant-mode decay fit in place of the
logarithmic decrement. With compensation it returns m, c, k to about 1e−9 (the paper: 0.3–0.6 %).
Without compensation the numbers differ from the paper's column (ERRATA 5): those depend on the
authors' unpublished simulation details, and what the method gives on exact modes is
m ≈ 0.98, c ≈ 2.9, k ≈ 31.3; the qualitative finding (wrong slope, c far off) is the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid._threads import single_blas_thread
from phoid.dynamics import forward_map
from phoid.dynamics.plant import Plant
from phoid.methods.pho import MCKFit, fit_lines
from phoid.methods.pho_measure import measure_modes
from phoid.reports.text import text_table
from phoid.simulation import simulate

__all__ = [
    "PAPER_D",
    "PAPER_DELAY",
    "PAPER_P",
    "PAPER_PLANT",
    "PAPER_WITH",
    "PAPER_WITHOUT",
    "PaperResult",
    "reproduce_table1",
]

PAPER_PLANT = Plant(m=2.0, c=1.0, k=64.0)
PAPER_DELAY = 0.1  # s
PAPER_P = 0.25 + 1.375 * np.arange(19)  # N/m
PAPER_D = (6 + 3 * np.arange(19)) / 10  # N s/m: 0.6, 0.9, … 6 (0.6 + 0.3 i: 0.8999999999999999)
PAPER_WITH = {"m": 1.9884, "c": 1.0035, "k": 63.7668}  # Table 1, "with compensation"
PAPER_WITHOUT = {"m": 1.0169, "c": 4.2321, "k": 35.1812}  # Table 1, "without compensation"


@dataclass(frozen=True)
class PaperResult:
    """phoid's reproduction of Table 1 / Figure 1.

    Attributes
    ----------
    with_compensation, without_compensation : MCKFit
        The eq. (35) line fits (OLS) on phoid's measured modes.
    sigma, omega_d : ndarray
        Measured σᵢ (1/s), ω_dᵢ (rad/s) of the 19 runs.
    sigma_exact, omega_d_exact : ndarray
        The exact dominant roots of the delayed loop, for reference.
    duration, fs : float
        Simulated record length (s) and sample rate (Hz).
    """

    with_compensation: MCKFit
    without_compensation: MCKFit
    sigma: np.ndarray
    omega_d: np.ndarray
    sigma_exact: np.ndarray
    omega_d_exact: np.ndarray
    duration: float
    fs: float

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: actual, paper_with, paper_without, with_compensation,
        without_compensation (each {m, c, k}, kg, N s/m, N/m) and relative errors."""
        actual = {"m": PAPER_PLANT.m, "c": PAPER_PLANT.c, "k": PAPER_PLANT.k}

        def mck(f: MCKFit) -> dict[str, float]:
            return {"m": float(f.m), "c": float(f.c), "k": float(f.k)}

        def rel(d: dict[str, float]) -> dict[str, float]:
            return {q: (d[q] - actual[q]) / actual[q] for q in "mck"}

        w, wo = mck(self.with_compensation), mck(self.without_compensation)
        return {
            "actual": actual,
            "paper_with": dict(PAPER_WITH),
            "paper_without": dict(PAPER_WITHOUT),
            "with_compensation": w,
            "without_compensation": wo,
            "relative_error_with": rel(w),
            "relative_error_without": rel(wo),
            "relative_error_paper_with": rel(PAPER_WITH),
            "mass_from_damping_line": {
                "with_compensation": float(self.with_compensation.c_line.slope),
                "without_compensation": float(self.without_compensation.c_line.slope),
            },
            "runs": [
                {"P": float(p), "D": float(d), "sigma": float(s), "omega_d": float(o)}
                for p, d, s, o in zip(PAPER_P, PAPER_D, self.sigma, self.omega_d, strict=True)
            ],
            "simulation": {"duration_s": self.duration, "fs_hz": self.fs, "noise_m": 0.0},
        }

    def table(self) -> str:
        """Table 1 side by side: actual, the paper's two columns, phoid's two, relative errors."""
        s = self.summary()
        units = {"m": "kg", "c": "N s/m", "k": "N/m"}
        cells = [[f"{q} ({units[q]})", f"{s['actual'][q]:g}", f"{s['paper_with'][q]:.4f}",
                  f"{s['with_compensation'][q]:.10f}", f"{s['relative_error_with'][q]:.2e}",
                  f"{s['paper_without'][q]:.4f}", f"{s['without_compensation'][q]:.4f}",
                  f"{s['relative_error_without'][q]:+.1%}"] for q in "mck"]
        rows = ["Table 1: parametric oscillation with and without delay compensation", "",
                *text_table([("", ""), ("actual", ""), ("paper with", ""), ("phoid with", ""),
                             ("rel. error", ""), ("paper without", ""), ("phoid without", ""),
                             ("rel. error", "")], cells, indent=0)]
        mw = s["mass_from_damping_line"]
        rows += [
            "",
            "m is the slope of the stiffness line k′ = mω₀² − k; the damping line c′ = 2mσ − c",
            f"gives m = {mw['with_compensation']:.10f} with and "
            f"{mw['without_compensation']:.4f} without compensation.",
            "Without compensation phoid's numbers differ from the paper's column (ERRATA 5): the",
            "paper's depend on its unpublished simulation; exact modes give m ≈ 0.98, c ≈ 2.9,",
            "k ≈ 31.3. The finding is the same: the wrong slope and a damping estimate far off.",
        ]
        return "\n".join(rows)


@single_blas_thread
def reproduce_table1(*, duration: float = 15.0, fs: float = 1000.0, x0: float = 0.01,
                     hold: float = 0.2) -> PaperResult:
    """Simulate the paper's 19 runs and identify m, c, k with and without compensation.

    Parameters
    ----------
    duration : float, default 15
        Record length after release, s.
    fs : float, default 1000
        Sample rate, Hz.
    x0 : float, default 0.01
        Release position, m.
    hold : float, default 0.2
        Held segment before the release (controller on), s.

    Returns
    -------
    PaperResult

    Raises
    ------
    ValueError
        If the records are too short or too coarsely sampled to identify every run.
    """
    sim = simulate(PAPER_PLANT, PAPER_P, PAPER_D, delay=PAPER_DELAY, duration=duration, fs=fs,
                   x0=x0, hold=hold)
    data = [(sim.t, sim.x[i]) for i in range(sim.x.shape[0])]
    fits, reasons, _ = measure_modes(data, PAPER_P, PAPER_D, PAPER_DELAY)
    bad = [i for i, r in enumerate(reasons) if r is not None]
    if bad:
        raise ValueError(
            f"`duration` = {duration:g} s and `fs` = {fs:g} Hz: {len(bad)} of the 19 simulated "
            f"runs cannot be identified (run {bad[0] + 1}: {reasons[bad[0]]})"
        )
    sigma = np.array([f.sigma for f in fits])
    omega_d = np.array([f.omega_d for f in fits])
    exact = forward_map(PAPER_PLANT, PAPER_P, PAPER_D, PAPER_DELAY)
    return PaperResult(
        with_compensation=fit_lines(sigma, omega_d, PAPER_P, PAPER_D, PAPER_DELAY),
        without_compensation=fit_lines(sigma, omega_d, PAPER_P, PAPER_D, PAPER_DELAY,
                                       compensate=False),
        sigma=sigma, omega_d=omega_d, sigma_exact=exact.sigma, omega_d_exact=exact.omega_d,
        duration=duration, fs=fs,
    )
