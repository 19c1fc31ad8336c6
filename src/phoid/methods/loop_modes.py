"""The delayed loop's modes as a release from a held position excites them.

Two small pieces of loop algebra shared by the PHO pipeline (:mod:`phoid.methods.pho_measure`)
and the delay fit with the recorded force (:mod:`phoid.methods.udelay`): the distinct modes of a
set of characteristic roots, and each mode's amplitude after a release.
"""

from __future__ import annotations

import numpy as np

from phoid.dynamics import characteristic

__all__ = ["distinct_modes", "mode_residue"]


def mode_residue(s: complex, m: float, c: float, k: float, P: float, D: float,
                 delay: float) -> complex:
    """Amplitude per metre of release of the mode e^{st} after a release from a held position.

    With the history x = x₀ on [−Δt, 0], X(s) = x₀N(s)/f(s) with
    N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt})/s (from eq. 23), so the mode's residue is
    N(s)/f′(s).

    Parameters
    ----------
    s : complex
        A root of the characteristic function f (eq. 24), 1/s.
    m, c, k : float
        Mass (kg), damping (N·s/m) and stiffness (N/m) of the plant.
    P, D : float
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    complex
        N(s)/f′(s): the mode's complex amplitude for a unit release, m/m.
    """
    e = np.exp(-s * delay)
    p_term = P * (1 - e) / s if s != 0 else P * delay
    _, df = characteristic(s, m, c, k, P, D, delay)
    return complex((m * s + c + D * e - p_term) / df)


def distinct_modes(roots: np.ndarray) -> list[complex]:
    """Distinct modes (one root of each conjugate pair, Im ≥ 0), rightmost first.

    Parameters
    ----------
    roots : array_like of complex
        Characteristic roots, 1/s, in decreasing real part.

    Returns
    -------
    list of complex
        One root per mode, roots within 1e−9 max(1, |s|) of a kept one dropped.
    """
    out: list[complex] = []
    tol: list[float] = []  # 1e−9 max(1, |o|) of each kept mode o
    for z in np.asarray(roots, dtype=complex).tolist():
        r = complex(z.real, abs(z.imag))
        if not any(abs(r - o) <= e for o, e in zip(out, tol, strict=True)):
            out.append(r)
            tol.append(1e-9 * max(1.0, abs(r)))
    return out
