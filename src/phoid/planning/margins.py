"""Exact root counting and delay margins of the delayed PD loop, vectorised.

Stability and dominance are decided exactly and cheaply by counting roots in a half-plane with
the stability-switch (D-subdivision) method of Cooke & van den Driessche (1986): for the shifted
quasi-polynomial g(u) = f(u + a) = P̃(u) + Q̃(u) e^{−uΔt} (P̃ quadratic, Q̃ linear, fixed
coefficients), the number of roots with Re u > 0 at delay 0 follows from the quadratic
P̃ + Q̃, and it changes only where a root pair crosses the imaginary axis at u = ±iω, i.e. at a
positive root ω² of F(ω²) = |P̃(iω)|² − |Q̃(iω)|² (a quadratic in ω²), at the delays where
e^{−iωτ} = −P̃(iω)/Q̃(iω); each crossing adds two roots when F′(ω²) > 0 and removes two when
F′(ω²) < 0. The count is verified against
:func:`phoid.dynamics.counting.count_roots_right_of` in the
tests. The delay margin is the first crossing delay beyond Δt of the unshifted f.
"""

from __future__ import annotations

import numpy as np

__all__ = ["count_roots_right", "delay_margin"]


def _crossings(m, c, k, P, D):
    """Crossing frequencies of f = P̃(s) + Q̃(s)e^{−sτ} and the phase at which they occur.

    Returns (omega, theta, direction, valid) with shape (2, ...): for each of the two roots
    y = ω² of F(y) = m²y² + (c² − 2mk − D²)y + k² − P², the root pair ±iω lies on the axis at
    the delays τ = (θ + 2πn)/ω, n = 0, 1, …; ``direction`` is +1 when the pair crosses to the
    right as τ grows (F′(y) > 0), −1 when to the left.
    """
    A = m * m
    B = c * c - 2.0 * m * k - D * D
    C = k * k - P * P
    disc = B * B - 4.0 * A * C
    sq = np.sqrt(np.maximum(disc, 0.0))
    out = []
    for sgn in (1.0, -1.0):
        y = (-B + sgn * sq) / (2.0 * A)
        valid = (disc > 0) & (y > 0)
        w = np.sqrt(np.where(valid, y, 1.0))
        iw = 1j * w
        Pw = m * iw * iw + c * iw + k
        Qw = D * iw + P
        with np.errstate(all="ignore"):
            theta = np.mod(-np.angle(-Pw / Qw), 2.0 * np.pi)
        valid = valid & np.isfinite(theta)
        out.append((w, theta, sgn, valid))
    return out


def count_roots_right(
    a: np.ndarray | float,
    m: np.ndarray | float,
    c: np.ndarray | float,
    k: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> np.ndarray:
    """Number of roots of m s² + c s + k + (D s + P)e^{−sΔt} with Re s > a, exactly, vectorised.

    Parameters
    ----------
    a : array_like
        Abscissa, 1/s.
    m, c, k : array_like
        Plant (kg > 0, N·s/m, N/m; any sign for c, k).
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s (≥ 0).

    Returns
    -------
    ndarray of float
        The count (an integer value), or NaN where a root lies on the line Re s = a (or so close
        that the count is undecided), broadcast over the inputs.

    Notes
    -----
    With s = u + a, f(u + a) = m u² + (c + 2ma)u + (k + ca + ma²) + e^{−aΔt}[D u + (P + Da)]
    e^{−uΔt}, a quasi-polynomial of the same retarded form with fixed coefficients. At delay 0
    its right-half-plane roots are those of the quadratic m u² + (c̃ + D̃)u + (k̃ + P̃); as the
    delay grows from 0 to Δt, roots enter or leave only in pairs through u = ±iω at the
    crossings of :func:`_crossings` (Cooke & van den Driessche 1986).
    """
    a, m, c, k, P, D = np.broadcast_arrays(
        *(np.asarray(x, dtype=float) for x in (a, m, c, k, P, D)))
    with np.errstate(all="ignore"):
        return _count_right(a, m, c, k, P, D, delay)


def _count_right(a, m, c, k, P, D, delay):
    g = np.exp(-a * delay)
    c1 = c + 2.0 * m * a
    k1 = k + c * a + m * a * a
    D1 = D * g
    P1 = (P + D * a) * g
    b0 = c1 + D1
    e0 = k1 + P1
    total = np.where(e0 < 0, 1.0, np.where(b0 < 0, 2.0, 0.0))
    scale = np.abs(k1) + np.abs(P1) + np.abs(m * a * a) + 1e-300
    bad = (np.abs(e0) <= 1e-12 * scale) | ((np.abs(b0) <= 1e-12 * (np.abs(c1) + np.abs(D1)))
                                           & (e0 > 0))
    if delay > 0:
        for w, theta, sgn, valid in _crossings(m, c1, k1, P1, D1):
            wt = w * delay
            n = np.where(theta < wt, np.floor((wt - theta) / (2.0 * np.pi)) + 1.0, 0.0)
            total = total + np.where(valid, 2.0 * sgn * n, 0.0)
            # a crossing at (almost) exactly Δt: the line passes through a root
            r = np.mod(wt - theta, 2.0 * np.pi)
            bad = bad | (valid & (np.minimum(r, 2.0 * np.pi - r) <= 1e-9 * (1.0 + wt)))
    bad = bad | ~np.isfinite(g * (np.abs(c1) + np.abs(k1) + np.abs(P1) + np.abs(D1)))
    return np.where(bad, np.nan, total)


def delay_margin(
    m: np.ndarray | float,
    c: np.ndarray | float,
    k: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> np.ndarray:
    """Extra loop delay a stable loop tolerates before a root reaches the imaginary axis, s.

    Parameters
    ----------
    m, c, k, P, D : array_like
        Plant (kg, N·s/m, N/m) and gains (N/m, N·s/m).
    delay : float
        The loop's delay Δt, s.

    Returns
    -------
    ndarray
        min over the crossings (ω, θ) of f (:func:`_crossings`) of (θ + 2πn)/ω − Δt over the
        delays beyond Δt; ``inf`` when no root ever reaches the axis (F has no positive root).
        Meaningful for a loop that is stable at Δt (then the first crossing destabilises it).
    """
    m, c, k, P, D = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (m, c, k, P, D)))
    best = np.full(m.shape, np.inf)
    with np.errstate(all="ignore"):
        for w, theta, _sgn, valid in _crossings(m, c, k, P, D):
            wt = w * delay
            n = np.where(theta > wt, 0.0, np.floor((wt - theta) / (2.0 * np.pi)) + 1.0)
            tau = (theta + 2.0 * np.pi * n) / w - delay
            best = np.where(valid, np.minimum(best, tau), best)
    return best
