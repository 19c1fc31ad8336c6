"""The delayed loop's fast transient after a release from a held position.

A PHO run starts with the mass held at x₀ while the controller already runs, so the DDE's
initial history is the constant x₀. Its Laplace transform is then exactly

    X(s) = x₀ N(s) / f(s),   N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt}) / s,
    f(s) = m s² + c s + k + (D s + P) e^{−sΔt},

(from eq. 23 with x(t) = x₀ for −Δt ≤ t ≤ 0), so each characteristic root s_j contributes the
mode x₀ N(s_j)/f′(s_j) e^{s_j t}. The dominant pair rings for many cycles; every other root decays
much faster. This module computes that fast remainder

    W(τ) = U(τ) − 2 Re[N(s₁)/f′(s₁) e^{s₁τ}],   U = the response to x₀ = 1,

from phoid's simulator (exact to ~1e−8 of x₀) and the residue of the dominant root s₁, so that
the decay fit can include it as a known shape (with a free scale) and use the record right from
the release instead of skipping it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from phoid.loop import _rightmost_roots, characteristic
from phoid.plant import Plant
from phoid.simulate import simulate

__all__ = ["Transient", "dominant_residue", "loop_transients"]


def dominant_residue(
    s: complex, m: float, c: float, k: float, P: float, D: float, delay: float
) -> complex:
    """Residue N(s)/f′(s) of the unit release response at a simple root s (dimensionless).

    Parameters
    ----------
    s : complex
        A characteristic root, 1/s.
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : float
        Gains (N/m, N·s/m).
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    complex
        The mode's complex amplitude per metre of release position; the pair s, s̄ contributes
        2 Re[r e^{sτ}].
    """
    e = np.exp(-s * delay)
    p_term = P * (1 - e) / s if s != 0 else P * delay
    N = m * s + c + D * e - p_term
    _, df = characteristic(s, m, c, k, P, D, delay)
    return complex(N / df)


@dataclass(frozen=True)
class Transient:
    """The fast remainder W(τ) of one run's unit release response (see module docstring).

    Attributes
    ----------
    tau_end : float
        s; beyond it |W| < 1e−12 and W is taken as 0.
    spline : CubicHermiteSpline
        W on [0, tau_end] (dimensionless per metre of release), from values and derivatives.
    """

    tau_end: float
    spline: CubicHermiteSpline | None

    def __call__(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """W(τ) and dW/dτ (1/s) at times τ since the release (0 for τ < 0 and τ > tau_end)."""
        tau = np.asarray(tau, dtype=float)
        w = np.zeros_like(tau)
        dw = np.zeros_like(tau)
        if self.spline is None:
            return w, dw
        sel = (tau >= 0) & (tau <= self.tau_end)
        w[sel] = self.spline(tau[sel])
        dw[sel] = self.spline(tau[sel], 1)
        return w, dw


def loop_transients(
    m: float,
    c: float,
    k: float,
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    *,
    floor: float = 1e-12,
    fs: float = 4000.0,
) -> list[Transient]:
    """W(τ) for each run (batched simulation of the unit release).

    Parameters
    ----------
    m, c, k : float
        Plant (kg, N·s/m, N/m), e.g. a first estimate.
    P, D : array_like
        Gains of each run.
    delay : float
        Loop delay Δt, s. With Δt = 0 the loop is exactly second order and W ≡ 0.
    floor : float, default 1e−12
        W is followed until the next root's envelope falls below this (relative to x₀ = 1).
    fs : float, default 4000
        Internal sample rate of W, Hz (Hermite interpolation in between: error ~(ω/fs)⁴).

    Returns
    -------
    list of Transient
    """
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    if delay == 0.0:
        return [Transient(0.0, None) for _ in P]
    doms, ends = [], []
    for Pi, Di in zip(P, D, strict=True):
        roots = _rightmost_roots(m, c, k, float(Pi), float(Di), delay, count=3)
        s1 = complex(roots[0].real, abs(roots[0].imag))
        rest = roots[np.abs(roots.real - s1.real) > 1e-9 * max(1.0, abs(s1))]
        gap = s1.real - rest[0].real if rest.size else 1.0 / delay
        # W decays like e^{(Re s2) tau}; follow it until it is below the floor
        ends.append(min(max(math.log(1 / floor) / max(-rest[0].real if rest.size else gap,
                                                       gap, 1e-3), 2 * delay), 60.0))
        doms.append((s1, dominant_residue(s1, m, c, k, float(Pi), float(Di), delay)))
    duration = max(ends)
    fs_eff = max(fs, 40.0 * max(abs(s) for s, _ in doms) / (2 * math.pi))
    sim = simulate(Plant(m, max(c, 0.0), max(k, 0.0)) if c >= 0 and k >= 0 else _raw(m, c, k),
                   P, D, delay=delay, duration=duration, fs=fs_eff, x0=1.0, hold=0.0)
    tau = sim.t
    out = []
    for i, (s1, r1) in enumerate(doms):
        e = np.exp(s1 * tau)
        dom = 2 * np.real(r1 * e)
        ddom = 2 * np.real(r1 * s1 * e)
        w = sim.x_true[i] - dom
        dw = sim.v[i] - ddom
        sel = tau <= ends[i]
        out.append(Transient(float(tau[sel][-1]), CubicHermiteSpline(tau[sel], w[sel], dw[sel])))
    return out


def _raw(m: float, c: float, k: float) -> Plant:
    """A Plant with possibly negative c or k (a trial point inside a fit), unchecked."""
    p = object.__new__(Plant)
    object.__setattr__(p, "m", m)
    object.__setattr__(p, "c", c)
    object.__setattr__(p, "k", k)
    object.__setattr__(p, "fc", 0.0)
    return p
