r"""Whether the eq. (35) straight lines fit their points within the points' own measurement error.

The paper's ordinary-least-squares route (``--estimator ols``) draws the lines
c′ᵢ = 2mσᵢ − c and k′ᵢ = mω₀ᵢ² − k through the runs' points and takes its standard errors from
the points' scatter about the lines. That scatter says nothing about whether the points *should*
lie on lines: with the loop delay left out (``--no-compensation``) the points move off the
lines by far more than each run measured them to, and the lines' slope and intercepts are
biased (the seed's Table 1, "without compensation"), while the OLS stderr stays small.

The check: each point's residual from its line, over its own measurement error — the decay
fit's covariance of (σᵢ, ω_dᵢ) carried through the points' coordinates (eq. 32 with the
corrected α₁, then the line's residual y − slope·x) by forward differences, elementwise (one
evaluation of the inverse map per parameter for all runs at once):

    χ²_line = Σᵢ rᵢ² / var(rᵢ),   dof = runs − 2,

one for each line. A χ² beyond its upper 0.1 % quantile means the points do not lie on a
straight line within their noise: the eq. (35) model, as applied, does not describe the runs.
On the example set (examples/paper-sample, 19 runs, delay 0.1 s) χ²/dof is 0.6 and 1.4 for the
compensated lines and 59 and 8 000 with the delay left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from phoid.dynamics import inverse_map
from phoid.methods.chi2 import chi2_isf

__all__ = ["LinesCheck", "check_lines"]

# the χ² test's level: the same 99.9 % as the weighted fit's misfit test (identification._misfit)
_ALPHA = 1e-3
# relative forward-difference step of the propagation (the inverse map is smooth; 1e-6 of a
# rate keeps the truncation error ~1e-6 relative, far below the 1 % a variance needs)
_STEP = 1e-6


@dataclass(frozen=True)
class LinesCheck:
    """χ² of the two eq. (35) lines against their points' measurement error.

    Attributes
    ----------
    chi2_c, chi2_k : float
        χ² of the damping line and of the stiffness line.
    dof : int
        Degrees of freedom of each (runs − 2).
    misfit : bool
        Either χ² beyond its 99.9 % quantile.
    """

    chi2_c: float
    chi2_k: float
    dof: int
    misfit: bool


def _residuals(sigma, omega_d, P, D, delay, compensate, dm, m_c, m, c, k):
    """The points' residuals from the lines, elementwise (eq. 35 with the added masses)."""
    cp, kp = inverse_map(sigma, omega_d, P, D, delay, compensate=compensate)
    cp = cp - 2.0 * dm * sigma
    kp = kp - dm * (sigma**2 + omega_d**2)
    return cp - (2.0 * m_c * sigma - c), kp - (m * (sigma**2 + omega_d**2) - k)


def check_lines(sigma: np.ndarray, omega_d: np.ndarray, cov: np.ndarray, P: np.ndarray,
                D: np.ndarray, delay: float, *, compensate: bool, added_mass: np.ndarray,
                m_c: float, m: float, c: float, k: float) -> LinesCheck | None:
    """χ² of the eq. (35) lines against the points' measurement error (module docstring).

    Parameters
    ----------
    sigma, omega_d : numpy.ndarray, shape (n,)
        The used runs' decay rates (1/s) and damped frequencies (rad/s).
    cov : numpy.ndarray, shape (n, 2, 2)
        Each run's covariance of (σᵢ, ω_dᵢ) from its decay fit.
    P, D : numpy.ndarray, shape (n,)
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    compensate : bool
        Whether the points were corrected for the delay (eq. 32).
    added_mass : numpy.ndarray, shape (n,)
        Known mass added per run, kg.
    m_c, m, c, k : float
        The damping line's slope (kg), the stiffness line's slope m (kg), c (N s/m), k (N/m).

    Returns
    -------
    LinesCheck or None
        None with fewer than three runs (the lines then have no residual) or when a point's
        error cannot be propagated.
    """
    n = sigma.size
    if n < 3:
        return None
    base = _residuals(sigma, omega_d, P, D, delay, compensate, added_mass, m_c, m, c, k)
    hs = _STEP * np.maximum(np.abs(sigma), 1e-3 * np.abs(omega_d))
    hw = _STEP * np.abs(omega_d)
    with np.errstate(all="ignore"):
        ds = _residuals(sigma + hs, omega_d, P, D, delay, compensate, added_mass, m_c, m, c, k)
        dw = _residuals(sigma, omega_d + hw, P, D, delay, compensate, added_mass, m_c, m, c, k)
    chi2 = []
    for line in range(2):
        g = np.stack([(ds[line] - base[line]) / hs, (dw[line] - base[line]) / hw], axis=1)
        var = np.einsum("ni,nij,nj->n", g, cov, g)
        if not (np.all(np.isfinite(var)) and np.all(var > 0) and np.all(np.isfinite(base[line]))):
            return None
        chi2.append(float(np.sum(base[line] ** 2 / var)))
    dof = n - 2
    limit = chi2_isf(_ALPHA, dof)
    return LinesCheck(chi2[0], chi2[1], dof, bool(chi2[0] > limit or chi2[1] > limit))
