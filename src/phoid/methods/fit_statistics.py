r"""Statistics that every identification result reports: the model-independent noise level of
a record, each run's residual/noise ratio, and the ``covariance``/``correlation``/``statistics``
blocks of a summary (built by :mod:`phoid.reports.statistics`, with the χ² tail probability
from :mod:`phoid.methods.chi2`).

The noise level
---------------
:func:`difference_noise` estimates the sd of a record's white measurement noise from its third
differences, without any model of the motion: for white noise of sd s, Δ³x = x₃ − 3x₂ + 3x₁ − x₀
has sd s·√20 (1 + 9 + 9 + 1 = 20), and its median absolute deviation is 0.6745 of that sd for
Gaussian noise, so

    ŝ = 1.4826 · MAD(Δ³x) / √20.

A smooth motion of amplitude A and angular frequency ω sampled every Δt adds at most
A·(2 sin(ωΔt/2))³ ≤ A(ωΔt)³ to a third difference: 2.5·10⁻⁴ A at 100 samples per period
(ωΔt = 2π/100), 3·10⁻⁵ A at 200, far below any usable noise. The
median makes a few steps or spikes harmless. A record so finely quantised that most third
differences are 0 (MAD = 0) falls back to the RMS of Δ³x over √20. "0" is up to rounding: a
quantised record holds the floats nearest k·q, not k·q, so a third difference that is 0 in
counts comes out as a few units in the last place of the largest |x| (|Δ³x| ≤ 8 · ε/2 ·
max|x| ≈ 9·10⁻¹⁶ max|x|, ε = 2.2·10⁻¹⁶), and their MAD (~10⁻¹⁹ m for a µm encoder) would pass
for a noise level. Third differences below :data:`ROUNDING_RTOL` · max|x| (10⁻⁹: a million
times that rounding, and a noise 10⁻⁹ of the record's largest value is below any sensor's
resolution, 30 bits) count as 0 with ``rounding=True`` (the in-loop routes, whose residual is
the sensor's error itself); when over half do, the RMS fallback (of the third differences so
counted) gives the noise. The other routes keep the exact comparison: their adequacy checks were
calibrated on it (a real pendulum's quantised half record is flagged through it).

The ratio
---------
:func:`residual_noise_ratio` is the RMS of a run's fit residual over that noise level. With
the right model and white noise it is √((n − p)/n) ≈ 1 (n residuals, p fitted numbers); its
spread is about 1.7/√n (the residual RMS has relative sd 1/√(2n); the MAD of the correlated
third differences 1.5/√n, tests/test_fit_statistics.py measures it). A value well above 1
(beyond 1 + 10/√n, or simply above 1.5 on records of a few thousand samples) means the model
leaves structure in the record that the noise does not explain: a misfit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid.methods.chi2 import chi2_sf
from phoid.reports.statistics import correlation_json, covariance_json, statistics_json

__all__ = [
    "ROUNDING_RTOL",
    "difference_noise",
    "fit_blocks",
    "residual_noise_ratio",
    "window_noise",
]

_SQRT20 = math.sqrt(20.0)
ROUNDING_RTOL = 1e-9
"""Third differences below this × max|x| are rounding, not noise (module docstring)."""
_MAD_TO_SD = 1.482602218505602  # 1 / Φ⁻¹(3/4)


def difference_noise(x: Any, rounding: bool = False) -> float:
    """White-noise sd of a record from the MAD of its third differences, m (module docstring).

    Parameters
    ----------
    x : array_like
        Uniformly sampled record (any unit; the result is in the same unit).

    Returns
    -------
    float
        ŝ = 1.4826·MAD(Δ³x)/√20; the RMS of Δ³x over √20 when the MAD is 0 (a quantised or
        noise-free record), third differences below :data:`ROUNDING_RTOL` · max|x| counting
        as 0 (rounding) with ``rounding``; nan for fewer than 4 samples.
    """
    x = np.asarray(x, dtype=float).ravel()
    if x.size < 4:
        return math.nan
    d3 = x[3:] - 3.0 * x[2:-1] + 3.0 * x[1:-2] - x[:-3]
    tol = ROUNDING_RTOL * float(np.max(np.abs(x))) if rounding else 0.0
    d3_counted = np.where(np.abs(d3) < tol, 0.0, d3)
    mad = float(np.median(np.abs(d3_counted - np.median(d3_counted))))
    if mad > 0:
        return _MAD_TO_SD * mad / _SQRT20
    return float(np.sqrt(np.mean(d3_counted * d3_counted))) / _SQRT20


def window_noise(t: Any, x: Any, t_start: float, t_end: float) -> float:
    """:func:`difference_noise` of the samples of ``x`` with ``t_start ≤ t ≤ t_end`` (s): the
    noise in the window a fit used (the whole record when the window has fewer than 10
    samples or is not finite)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if math.isfinite(t_start) and math.isfinite(t_end):
        sel = (t >= t_start) & (t <= t_end)
        if int(np.count_nonzero(sel)) >= 10:
            return difference_noise(x[sel])
    return difference_noise(x)


def residual_noise_ratio(residual_rms: float | None, noise: float | None) -> float | None:
    """``residual_rms / noise`` (≈ 1: the model explains the record to its noise; ≫ 1: a
    misfit); None when either is missing, not finite or the noise is 0."""
    if residual_rms is None or noise is None:
        return None
    if not (math.isfinite(residual_rms) and math.isfinite(noise) and noise > 0):
        return None
    return float(residual_rms) / float(noise)


def fit_blocks(names: Sequence[str], units: Sequence[str], cov: Any, chi2: float | None,
               dof: int | None, *, of: str, weighted: bool = True,
               **extra: Any) -> dict[str, Any]:
    """The ``covariance``, ``correlation`` and ``statistics`` keys of a summary.

    Parameters
    ----------
    names, units : sequence of str
        The estimated parameters, in the covariance's order, and their units.
    cov : array_like, shape (p, p)
        Their covariance.
    chi2, dof : float, int
        The fit's χ² and degrees of freedom (see
        :func:`phoid.reports.statistics.statistics_json`).
    of : str
        What χ² is of, in words.
    weighted : bool
        χ² weighted by the noise (True) or a plain residual sum of squares (False).
    **extra
        Further numbers for the statistics block.

    Returns
    -------
    dict
        ``{"covariance": …, "correlation": …, "statistics": …}``; ``p_value`` =
        P(χ²_dof ≥ χ²) for a weighted χ² with dof > 0.
    """
    p = None
    if weighted and chi2 is not None and dof is not None and dof > 0 and math.isfinite(chi2) \
            and chi2 >= 0:
        p = chi2_sf(float(chi2), float(dof))
    return {
        "covariance": covariance_json(names, units, cov),
        "correlation": correlation_json(names, cov),
        "statistics": statistics_json(chi2, dof, of=of, weighted=weighted, p_value=p, **extra),
    }
