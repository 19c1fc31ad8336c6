"""Checks applied where inputs enter phoid (scipy.signal style: name and value in the message).

Each check is written so that NaN fails it (``not (value >= 0)`` rather than ``value < 0``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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


#: the magnitudes a physical number given to phoid (a mass, …) may have, in SI units: nothing
#: on a rig is 1e30 kg or 1e-30 kg, and within these bounds the products of a few of them (c =
#: 2σm, k = ω₀²m, …) stay inside the floating-point range
MAGNITUDE = 1e30
_DECADES = 30  # log10(MAGNITUDE), for the messages


def physical(name: str, value: Any, unit: str = "") -> float:
    """Return ``value`` as a float, or raise ValueError unless it is a finite real number > 0 of
    magnitude 1e-30 … 1e30 (:data:`MAGNITUDE`, SI units). ``name`` is used as given (the caller
    spells it: ``--mass``, ```mass```)."""
    u = f" {unit}" if unit else ""
    want = (f"a finite number > 0 of magnitude 1e-{_DECADES} … 1e{_DECADES}{u} "
            "(SI units)")
    if isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be {want}; got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {want}; got {value!r}") from None
    if not (math.isfinite(v) and 1 / MAGNITUDE <= v <= MAGNITUDE):
        raise ValueError(f"{name} must be {want}; got {v:g}")
    return v


def overflow_warnings(mass: float, estimates: Sequence[tuple[str, Any, float]]) -> list[str]:
    """The warnings for a known mass's products that the floating point cannot hold.

    Parameters
    ----------
    mass : float
        The known mass, kg.
    estimates : sequence of (str, Estimate or None, float)
        Each product's name and formula (``"c = 2σm"``), its estimate, and the per-mass value
        it was made from (2σ, ω₀², …).

    Returns
    -------
    list of str
        One warning per product whose value or stderr is not finite (null in the JSON): the
        product overflows the floating-point range.
    """
    out = []
    for label, est, per_mass in estimates:
        if est is None:
            continue
        if not math.isfinite(est.value):
            out.append(f"{label} = {per_mass:.4g} × {mass:.4g} overflows the floating-point "
                       "range: not reported")
        elif est.stderr is not None and not math.isfinite(est.stderr):
            out.append(f"the stderr of {label} overflows the floating-point range: not "
                       "reported")
    return out
