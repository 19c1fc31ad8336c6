"""The manifest's optional ``[units]`` table: the data columns' units, converted to SI on reading.

A set recorded in other units than SI names them, e.g. ``[units] t = "ms"``, ``x = "mm"``; the
reader converts those columns to s, m, N before anything else sees them, so every method, check
and report works in SI (docs/format.md, "The `[units]` table"). The table covers the data
files' columns only — ``t`` (time), ``x`` and a tracking set's ``r`` (length), ``u`` and ``F``
(force) — never the manifest's own numbers (gains, delay, sample time, …), which are SI always.
A tracking set's ``u`` and ``w`` are in the controller's command units and are not converted.

Conversion: a column in a sub-unit (ms, mm, µm, …) is divided by the exact power of ten (one
correctly rounded division, so a value written in mm reads as the double nearest to the
metres it means, to one rounding); a column in a larger or non-decimal unit (min, in, kN, lbf)
is multiplied by the factor.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from phoid.io._format import case_clash, fail, kind_of, show

__all__ = ["UNITS_TABLE", "UNIT_QUANTITIES", "check_units", "to_si"]

_TIME = {"s": (1.0, 1.0), "ms": (1.0, 1e3), "us": (1.0, 1e6), "µs": (1.0, 1e6),
         "μs": (1.0, 1e6), "min": (60.0, 1.0)}
_LENGTH = {"m": (1.0, 1.0), "mm": (1.0, 1e3), "um": (1.0, 1e6), "µm": (1.0, 1e6),
           "μm": (1.0, 1e6), "nm": (1.0, 1e9), "in": (0.0254, 1.0)}
_FORCE = {"N": (1.0, 1.0), "kN": (1e3, 1.0), "mN": (1.0, 1e3), "lbf": (4.4482216152605, 1.0)}
UNITS_TABLE: dict[str, dict[str, tuple[float, float]]] = {
    "time": _TIME, "length": _LENGTH, "force": _FORCE}
"""Each quantity's units: name → (multiplier, divisor) to SI (x_SI = x·multiplier/divisor;
one of the two is 1). ``µ`` may be the micro sign (U+00B5), the Greek mu (U+03BC) or ``u``."""
UNIT_QUANTITIES = {"t": "time", "x": "length", "u": "force", "F": "force"}
"""The ``[units]`` keys of a ``pho``, ``forced`` or ``free`` set: column → quantity."""
_TRACKING_QUANTITIES = {"t": "time", "x": "length", "r": "length"}


def check_units(where: str, table: Any, method: str) -> dict[str, tuple[str, float, float]]:
    """Check a manifest's ``[units]`` table.

    Parameters
    ----------
    where : str
        The manifest, as messages name it.
    table : Any
        The parsed ``[units]`` value (None: no table).
    method : str
        The set's method (a tracking set's columns differ).

    Returns
    -------
    dict
        Each column given a unit other than its SI one → (unit, multiplier, divisor).

    Raises
    ------
    ExperimentError
        One line naming the manifest, the ``[units]`` key and the units allowed.
    """
    if table is None:
        return {}
    if not isinstance(table, Mapping):
        fail(where, f"'units' must be a table ([units]); got {kind_of(table)}")
    known = _TRACKING_QUANTITIES if method == "tracking" else UNIT_QUANTITIES
    uwhere = f"{where}: [units]"
    case_clash(uwhere, table, tuple(known), "[units]")
    out: dict[str, tuple[str, float, float]] = {}
    for key, unit in table.items():
        if key not in known:
            if method == "tracking" and key in ("u", "w"):
                reason = (f"a tracking set's {key} is in the controller's command units, which "
                          "phoid does not convert")
            else:
                reason = "phoid converts only the data columns " + ", ".join(
                    f"{k} ({q})" for k, q in known.items())
            fail(uwhere, f"unknown key {show(key)}: {reason}; the manifest's own numbers "
                          "(gains, delay, …) are SI always")
        units = UNITS_TABLE[known[key]]
        allowed = ", ".join(u for u in units if u not in ("μs", "μm"))
        if not isinstance(unit, str):
            fail(uwhere, f"key {key!r} must be a unit name (a string); got {show(unit)} "
                          f"({kind_of(unit)}); allowed {known[key]} units: {allowed}")
        if unit not in units:
            fail(uwhere, f"{key} = {show(unit)} is not a {known[key]} unit phoid knows; "
                          f"allowed: {allowed} (case-sensitive)")
        mul, div = units[unit]
        if (mul, div) != (1.0, 1.0):
            out[key] = (unit, mul, div)
    return out


def to_si(cols: dict[str, np.ndarray], units: Mapping[str, tuple[str, float, float]],
          where: str = "the data file") -> dict[str, np.ndarray]:
    """The columns with those named in ``units`` converted to SI (read-only arrays; the
    others as they are).

    A value the conversion takes beyond the largest double (1e308 kN) is an
    :class:`~phoid.errors.ExperimentError` naming ``where`` and the column, not a warning
    and an infinity.
    """
    if not units:
        return cols
    out = dict(cols)
    for key, (unit, mul, div) in units.items():
        col = out.get(key)
        if col is None:
            continue
        with np.errstate(over="ignore"):
            si = col / div if mul == 1.0 else col * mul
        if not np.isfinite(si).all():
            i = int(np.argmin(np.isfinite(si)))
            fail(where, f"column {key!r} overflows when converted from {unit} to SI: "
                         f"{float(col[i])!r} {unit} (row {i + 1}) is beyond the largest "
                         "double once converted")
        si.flags.writeable = False
        out[key] = si
    return out


def unit_hint(column: str, ratio: float) -> str:
    """A hint naming the ``[units]`` entry a set probably needs, or ``""``.

    Parameters
    ----------
    column : str
        The data column whose unit is in doubt: ``t``, ``x``, ``r``, ``u`` or ``F``.
    ratio : float
        A quantity read from that column as if it were SI (a sample step, an amplitude)
        divided by what the manifest's numbers imply for it: about 1000 when t is in ms but
        read as s (or x in mm read as m), 1/1000 when F is in kN but read as N.

    Returns
    -------
    str
        ``'is t in ms? (then give [units] t = "ms")'`` when ``ratio`` is within a factor 2 of a
        unit's (one of :data:`UNITS_TABLE`'s, other than SI), else ``""``.

    Examples
    --------
    >>> unit_hint("t", 1000.0)
    'is t in ms? (then give [units] t = "ms")'
    >>> unit_hint("F", 1e-3)
    'is F in kN? (then give [units] F = "kN")'
    >>> unit_hint("t", 3.0)
    ''
    """
    quantity = {**UNIT_QUANTITIES, **_TRACKING_QUANTITIES}.get(column)
    if quantity is None or not (ratio > 0 and np.isfinite(ratio)):
        return ""
    for unit, (mul, div) in UNITS_TABLE[quantity].items():
        if (mul, div) == (1.0, 1.0) or not unit.isascii():
            continue
        if abs(np.log(ratio * mul / div)) <= np.log(2.0):
            return f'is {column} in {unit}? (then give [units] {column} = "{unit}")'
    return ""
