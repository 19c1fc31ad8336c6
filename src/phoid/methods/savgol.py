"""Savitzky–Golay smoothing and differentiation of a uniformly sampled record, without scipy.signal.

The PHO pipeline's check of a recorded control force needs a smoothed record and its derivative
once per run; importing ``scipy.signal`` for that costs more than the identification itself.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["savgol_filter"]


def _derivative_rows(s: np.ndarray, polyorder: int, deriv: int) -> np.ndarray:
    """Rows d^deriv/ds^deriv of the monomials s^0 … s^polyorder, at the points s."""
    rows = np.zeros((s.size, polyorder + 1))
    for j in range(deriv, polyorder + 1):
        rows[:, j] = math.factorial(j) // math.factorial(j - deriv) * s ** (j - deriv)
    return rows


def savgol_filter(x: np.ndarray, window_length: int, polyorder: int, deriv: int = 0,
                  delta: float = 1.0) -> np.ndarray:
    """Smooth a record, or differentiate it, by local least-squares polynomials.

    Each sample is replaced by the ``deriv``-th derivative, at that sample, of the polynomial
    of degree ``polyorder`` fitted by least squares to the ``window_length`` samples centred
    on it (Savitzky and Golay, Anal. Chem. 36 (1964) 1627). With the window's sample offsets
    s = −h … h (h = window_length // 2) and the design matrix V_{ij} = s_i^j, the fitted
    coefficients are a = V⁺ x_window, so the result is a fixed linear combination of the
    window's samples,

    .. math:: y_n = \\frac{d!}{\\Delta^d}\\, (V^+)_{d,\\cdot}\\; x_{n-h \\ldots n+h},

    a correlation with constant weights in the interior. The first and last h samples, which
    have no centred window, take the derivative of the polynomial fitted to the first
    (last) whole window, evaluated at their own positions. This is
    ``scipy.signal.savgol_filter(x, window_length, polyorder, deriv, delta)`` with its
    default ``mode="interp"``, for a 1-D record.

    Parameters
    ----------
    x : ndarray
        The record, 1-D, uniformly sampled, at least ``window_length`` samples.
    window_length : int
        The number of samples in a window, odd.
    polyorder : int
        The degree of the fitted polynomial, < ``window_length``.
    deriv : int, optional
        The order of the derivative returned (0: the smoothed record).
    delta : float, optional
        The sampling interval (s), by which the derivative is scaled (``1/delta**deriv``).

    Returns
    -------
    ndarray
        The smoothed record or its derivative, same length as ``x`` (units of x per s^deriv).

    Raises
    ------
    ValueError
        If the window is even, not longer than ``polyorder``, or longer than the record.

    Examples
    --------
    >>> t = np.arange(20.0)
    >>> bool(np.allclose(savgol_filter(t**2, 5, 2, deriv=1), 2 * t))
    True
    """
    x = np.asarray(x, dtype=float)
    window_length, polyorder, deriv = int(window_length), int(polyorder), int(deriv)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    if window_length % 2 != 1 or window_length < 1:
        raise ValueError(f"window_length must be a positive odd integer, got {window_length}")
    if not 0 <= polyorder < window_length:
        raise ValueError(f"polyorder must be in [0, window_length), got {polyorder}")
    if deriv < 0:
        raise ValueError(f"deriv must be ≥ 0, got {deriv}")
    if x.size < window_length:
        raise ValueError(f"the record ({x.size} samples) is shorter than window_length "
                         f"({window_length})")
    n, half = x.size, window_length // 2
    if deriv > polyorder:
        return np.zeros(n)
    # the fits in the window's offsets from its centre scaled to [-1, 1] (a well-conditioned
    # design matrix); d/ds = (1/h) d/du
    unit = max(half, 1)
    u = np.arange(-half, half + 1, dtype=float) / unit
    hat = np.linalg.pinv(u[:, None] ** np.arange(polyorder + 1))     # (polyorder+1, window)
    rows = _derivative_rows(u, polyorder, deriv) * (1.0 / (unit * delta) ** deriv)
    weights = rows[half] @ hat          # interior: the centred fit's derivative at its centre
    y = np.empty(n)
    y[half:n - half] = np.lib.stride_tricks.sliding_window_view(x, window_length) @ weights
    # edges: the fit to the first (last) window, at the first (last) h samples' own positions
    y[:half] = (rows[:half] @ hat) @ x[:window_length]
    y[n - half:] = (rows[window_length - half:] @ hat) @ x[n - window_length:]
    return y
