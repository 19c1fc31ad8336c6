"""Checks applied where inputs enter phoid (scipy.signal style: name and value in the message).

Each check is written so that NaN fails it (``not (value >= 0)`` rather than ``value < 0``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def finite(name: str, value: Any, unit: str = "") -> float:
    """Return ``value`` as a float, or raise ValueError if it is not a finite real number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"`{name}` must be a real number; got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"`{name}` must be finite; got {v}")
    return v


def positive(name: str, value: Any, unit: str = "") -> float:
    """Return ``value`` as a float, or raise ValueError unless it is finite and > 0."""
    v = finite(name, value, unit)
    if not v > 0:
        raise ValueError(f"`{name}` must be > 0{' ' + unit if unit else ''}; got {v:g}")
    return v


def nonnegative(name: str, value: Any, unit: str = "") -> float:
    """Return ``value`` as a float, or raise ValueError unless it is finite and ≥ 0."""
    v = finite(name, value, unit)
    if not v >= 0:
        raise ValueError(f"`{name}` must be ≥ 0{' ' + unit if unit else ''}; got {v:g}")
    return v


def finite_array(name: str, value: Any, ndim: int | None = None) -> np.ndarray:
    """Return ``value`` as a float array, or raise ValueError if any element is NaN/inf."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"`{name}` must be an array of real numbers") from None
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"`{name}` must be {ndim}-dimensional; got shape {a.shape}")
    # a finite sum means every element is finite (a NaN or inf makes it NaN or inf), in one
    # pass; an infinite one (NaN/inf, or finite values whose sum overflows) is looked at closely
    with np.errstate(over="ignore", invalid="ignore"):
        total = float(np.add.reduce(a, axis=None))
    if not math.isfinite(total) and not np.all(np.isfinite(a)):
        bad = a[~np.isfinite(a)].ravel()[0]
        raise ValueError(f"`{name}` must be finite; got {bad}")
    return a
