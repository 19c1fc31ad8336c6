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

Rotational sets and sensor units: ``x`` may be an **angle** (``rad``, ``mrad``, ``deg``,
``rev``), converted to rad; the set is then rotational, its ``u``/``F`` are torques (N m, or
``"mN m"``, ``"kN m"``) and a tracking set's ``r`` an angle too, and every result is labelled
with the rotational quantities (:func:`quantity_unit`: J in kg m^2, N m s/rad, N m/rad). Or
``x`` may be a **sensor signal** (``V``, ``mV``, ``µV``, ``counts``, or any name declared as
``x = {signal = "NAME"}``), which is *not* converted: only σ, ω₀, ζ, c/m and k/m are
identifiable from it, so only a ``free`` set without a known mass accepts it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from phoid.io._format import case_clash, fail, kind_of, show

__all__ = ["SIGNAL_UNITS", "UNITS_TABLE", "UNIT_QUANTITIES", "Units", "check_units",
           "check_x_unit", "quantity_unit", "read_units", "relabel", "to_si", "x_quantity"]

_TIME = {"s": (1.0, 1.0), "ms": (1.0, 1e3), "us": (1.0, 1e6), "µs": (1.0, 1e6),
         "μs": (1.0, 1e6), "min": (60.0, 1.0)}
_LENGTH = {"m": (1.0, 1.0), "mm": (1.0, 1e3), "um": (1.0, 1e6), "µm": (1.0, 1e6),
           "μm": (1.0, 1e6), "nm": (1.0, 1e9), "in": (0.0254, 1.0)}
_FORCE = {"N": (1.0, 1.0), "kN": (1e3, 1.0), "mN": (1.0, 1e3), "lbf": (4.4482216152605, 1.0)}
_ANGLE = {"rad": (1.0, 1.0), "mrad": (1.0, 1e3), "deg": (math.pi / 180.0, 1.0),
          "rev": (2.0 * math.pi, 1.0)}
_TORQUE = {"N m": (1.0, 1.0), "N·m": (1.0, 1.0), "mN m": (1.0, 1e3), "mN·m": (1.0, 1e3),
           "kN m": (1e3, 1.0), "kN·m": (1e3, 1.0)}
UNITS_TABLE: dict[str, dict[str, tuple[float, float]]] = {
    "time": _TIME, "length": _LENGTH, "force": _FORCE, "angle": _ANGLE, "torque": _TORQUE}
"""Each quantity's units: name → (multiplier, divisor) to SI (x_SI = x·multiplier/divisor;
one of the two is 1). ``µ`` may be the micro sign (U+00B5), the Greek mu (U+03BC) or ``u``."""
SIGNAL_UNITS = ("V", "mV", "uV", "µV", "μV", "counts")
"""Sensor units ``[units] x`` may name without declaring them (``x = {signal = "…"}`` names
any other): x is then a raw sensor signal, not converted."""
UNIT_QUANTITIES = {"t": "time", "x": "length", "u": "force", "F": "force"}
"""The ``[units]`` keys of a ``pho``, ``forced`` or ``free`` set: column → quantity (of a
translational set; a rotational one's x is an angle and u, F torques)."""
_TRACKING_QUANTITIES = {"t": "time", "x": "length", "r": "length"}
_ROTATIONAL = {"x": "angle", "r": "angle", "u": "torque", "F": "torque"}
#: the longest name of a declared signal unit
_MAX_SIGNAL_NAME = 32
#: SI unit strings of phoid's results → their rotational counterparts (x an angle)
_ROTATIONAL_LABELS = {
    "kg": "kg m^2", "N s/m": "N m s/rad", "N·s/m": "N m s/rad", "N/m": "N m/rad",
    "N": "N m", "m": "rad", "m/s": "rad/s", "m/s^2": "rad/s^2", "kg/s": "kg m^2/s",
    "m^2": "rad^2", "N/m^2": "N m/rad^2"}


class Units(NamedTuple):
    """A checked ``[units]`` table (:func:`read_units`)."""

    conversions: dict[str, tuple[str, float, float]]
    """Each column given a unit other than its SI one → (unit, multiplier, divisor)."""
    x_unit: str
    """The unit x is in once read: ``"m"`` (a length), ``"rad"`` (an angle) or the sensor
    unit's name (a signal, not converted)."""


def x_quantity(x_unit: str) -> str:
    """``"length"``, ``"angle"`` or ``"signal"``: what a set's x (in ``x_unit``, as
    :attr:`Units.x_unit`) measures.

    Examples
    --------
    >>> x_quantity("m"), x_quantity("rad"), x_quantity("V")
    ('length', 'angle', 'signal')
    """
    return {"m": "length", "rad": "angle"}.get(x_unit, "signal")


def quantity_unit(unit: str, x_unit: str) -> str:
    """One of phoid's SI unit strings as the quantity of a set whose x is in ``x_unit``.

    A translational set (``x_unit`` ``"m"``) keeps ``unit``. A rotational one (``"rad"``)
    reads kg as J (``"kg m^2"``), N s/m as ``"N m s/rad"``, N/m as ``"N m/rad"``, N as
    ``"N m"``, m as ``"rad"``, m/s as ``"rad/s"``. A sensor signal (``"V"``, …) reads m as
    the signal's unit and m/s as its unit per second. Units that do not involve x (s, 1/s,
    rad/s, …) are kept.

    Examples
    --------
    >>> quantity_unit("N s/m", "rad"), quantity_unit("kg", "rad"), quantity_unit("m/s", "V")
    ('N m s/rad', 'kg m^2', 'V/s')
    >>> quantity_unit("1/s", "rad")
    '1/s'
    """
    quantity = x_quantity(x_unit)
    if quantity == "angle":
        return _ROTATIONAL_LABELS.get(unit, unit)
    if quantity == "signal":
        return {"m": x_unit, "m/s": f"{x_unit}/s", "m/s^2": f"{x_unit}/s^2",
                "m^2": f"{x_unit}^2"}.get(unit, unit)
    return unit


def relabel(summary: Any, x_unit: str) -> Any:
    """A JSON summary (nested dicts and lists) with every ``"unit"`` string and every
    ``"units"`` list of strings read as :func:`quantity_unit` reads it; the rest as it is
    (a new object; the input is not changed). With ``x_unit`` ``"m"``, ``summary`` itself."""
    if x_unit == "m":
        return summary

    def walk(value: Any) -> Any:
        if isinstance(value, dict):
            out = {}
            for key, item in value.items():
                if key == "unit" and isinstance(item, str):
                    out[key] = quantity_unit(item, x_unit)
                elif key == "units" and isinstance(item, list) and all(
                        isinstance(u, str) for u in item):
                    out[key] = [quantity_unit(u, x_unit) for u in item]
                else:
                    out[key] = walk(item)
            return out
        if isinstance(value, list):
            return [walk(item) for item in value]
        return value

    return walk(summary)


def check_x_unit(where: str, x_unit: Any, method: str, mass: float | None = None) -> str:
    """Check the unit a set's x is in (:attr:`Units.x_unit`) against the set's method.

    ``"m"`` and ``"rad"`` suit every method; a sensor signal's name (``"V"``, …) only a
    ``free`` set without a known ``mass``: c and k (and a pho or forced set's m, c, k, whose
    gains and forces act on a physical x) need x in a length or an angle unit. Raises
    :class:`~phoid.errors.ExperimentError` (one line naming ``where``).
    """
    if not isinstance(x_unit, str) or (x_unit not in ("m", "rad")
                                        and not _signal_name_ok(x_unit)):
        fail(where, f"`x_unit` must be 'm', 'rad' or a sensor unit's name (1–"
                     f"{_MAX_SIGNAL_NAME} printable characters); got {show(x_unit)}")
    if x_quantity(x_unit) != "signal":
        return x_unit
    if method != "free":
        fail(where, f"[units] x = {show(x_unit)} is a sensor unit, not a position: a "
                     f"{method} set's {_PHYSICAL_NEED.get(method, 'model')} need x as a "
                     "length or an angle (give x in m, mm, … or rad, deg, …; a raw sensor "
                     "signal suits only a free set, which gives σ, ω₀, ζ, c/m and k/m)")
    if mass is not None:
        fail(where, f"key 'mass' cannot be used with [units] x = {show(x_unit)} (a sensor "
                     "unit): c and k need x in a length or an angle unit; a free decay in "
                     "sensor units gives only σ, ω₀, ζ, c/m and k/m")
    return x_unit


_PHYSICAL_NEED = {"pho": "gains P, D (N/m, N·s/m) and recorded force u",
                  "forced": "force F and m, c, k",
                  "tracking": "gains, reference r and forces"}


#: units of the quantities phoid reads or reports besides :data:`UNITS_TABLE`'s (mass,
#: frequency, rates, the gains' and results' units): a signal may not be named after one
_OTHER_UNITS = ("kg", "Hz", "kHz", "1/s", "rad/s", "rad/s^2", "m/s", "m/s^2", "kg/s", "m^2",
                "N s/m", "N/m", "N/m^2", "N m s/rad", "N m/rad", "kg m^2", "kg m^2/s", "rad^2",
                "N m/rad^2")


def _unit_key(name: str) -> str:
    """``name`` folded for comparing unit names: case, blanks and the product signs
    (``·``, ``*``, ``.``) and ``^`` dropped, micro signs read as ``u``."""
    folded = name.casefold().replace("µ", "u").replace("μ", "u").replace("²", "2")
    return "".join(c for c in folded if not c.isspace() and c not in "·*.^")


_KNOWN_UNIT_KEYS = frozenset(
    _unit_key(u) for u in (*(u for units in UNITS_TABLE.values() for u in units),
                           *_OTHER_UNITS, *_ROTATIONAL_LABELS, *_ROTATIONAL_LABELS.values()))


def _signal_name_ok(name: str) -> bool:
    """A declared signal unit's name: printable, no surrounding blanks, not a unit of another
    quantity phoid knows (time, length, angle, force, torque, mass, frequency, rates, the
    results' units; compared case-insensitively, blanks and product signs ignored): then x
    would be mistaken for that quantity or mislabelled."""
    if not (0 < len(name) <= _MAX_SIGNAL_NAME) or not name.isprintable() \
            or name != name.strip():
        return False
    return _unit_key(name) not in _KNOWN_UNIT_KEYS


def _x_entry(where: str, value: Any, method: str) -> tuple[str, str]:
    """``[units] x``: (quantity, unit): a length, an angle or a sensor signal."""
    allowed = (", ".join(u for u in _LENGTH if u != "μm") + " (length); "
               + ", ".join(_ANGLE) + " (angle); "
               + ", ".join(u for u in SIGNAL_UNITS if u != "μV")
               + ' (sensor signals; any other as x = {signal = "NAME"})')
    if isinstance(value, Mapping):
        keys = list(value)
        if keys != ["signal"]:
            fail(where, f"x as a table must be {{signal = \"NAME\"}} (a sensor unit's "
                         f"name); got the keys {', '.join(map(show, keys)) or 'none'}")
        name = value["signal"]
        if not isinstance(name, str) or not _signal_name_ok(name):
            fail(where, f"x = {{signal = {show(name)}}}: the signal's unit must be a name of "
                         f"1–{_MAX_SIGNAL_NAME} printable characters without surrounding "
                         "blanks, not a length, angle, time or force unit, nor a torque, "
                         "mass, frequency, rate or result unit phoid knows (kg, Hz, rad/s, "
                         "N/m, …; compared case-insensitively, blanks ignored): lengths and "
                         "angles are converted, give them as x = \"…\"")
        return "signal", name
    if not isinstance(value, str):
        fail(where, f"key 'x' must be a unit name (a string); got {show(value)} "
                     f"({kind_of(value)}); allowed: {allowed}")
    if value in _LENGTH:
        return "length", value
    if value in _ANGLE:
        return "angle", value
    if value in SIGNAL_UNITS:
        return "signal", value
    fail(where, f"x = {show(value)} is not a unit phoid knows; allowed: {allowed} "
                 "(case-sensitive)")


def check_units(where: str, table: Any, method: str) -> dict[str, tuple[str, float, float]]:
    """Check a manifest's ``[units]`` table: :func:`read_units`'s conversions."""
    return read_units(where, table, method).conversions


def read_units(where: str, table: Any, method: str) -> Units:
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
    Units
        ``conversions``: each column given a unit other than its SI one → (unit, multiplier,
        divisor); ``x_unit``: ``"m"``, ``"rad"`` (x an angle: the set is rotational, its
        ``u``, ``F`` torques and ``r`` an angle) or a sensor unit (x not converted; refused
        but in a ``free`` set, :func:`check_x_unit`).

    Raises
    ------
    ExperimentError
        One line naming the manifest, the ``[units]`` key and the units allowed.
    """
    if table is None:
        return Units({}, "m")
    if not isinstance(table, Mapping):
        fail(where, f"'units' must be a table ([units]); got {kind_of(table)}")
    known = dict(_TRACKING_QUANTITIES if method == "tracking" else UNIT_QUANTITIES)
    uwhere = f"{where}: [units]"
    case_clash(uwhere, table, tuple(known), "[units]")
    out: dict[str, tuple[str, float, float]] = {}
    x_unit = "m"
    if "x" in table:
        quantity, unit = _x_entry(uwhere, table["x"], method)
        if quantity == "signal":
            check_x_unit(where, unit, method)
            x_unit = unit
        elif quantity == "angle":
            x_unit = "rad"
            known.update({k: q for k, q in _ROTATIONAL.items() if k in known})
            mul, div = _ANGLE[unit]
            if (mul, div) != (1.0, 1.0):
                out["x"] = (unit, mul, div)
    for key, unit in table.items():
        if key == "x" and x_unit != "m":
            continue  # an angle or a signal: done above
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
        why = (" (x is an angle, so the set is rotational: " + {
            "torque": f"{key} is a torque", "angle": f"{key} is an angle too"}[known[key]]
            + ")") if known[key] in ("torque", "angle") else ""
        if not isinstance(unit, str):
            fail(uwhere, f"key {key!r} must be a unit name (a string); got {show(unit)} "
                          f"({kind_of(unit)}); allowed {known[key]} units: {allowed}{why}")
        if unit not in units:
            fail(uwhere, f"{key} = {show(unit)} is not a {known[key]} unit phoid knows; "
                          f"allowed: {allowed} (case-sensitive){why}")
        mul, div = units[unit]
        if (mul, div) != (1.0, 1.0):
            out[key] = (unit, mul, div)
    return Units(out, x_unit)


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


def unit_hint(column: str, ratio: float, x_unit: str = "m") -> str:
    """A hint naming the ``[units]`` entry a set probably needs, or ``""``.

    Parameters
    ----------
    column : str
        The data column whose unit is in doubt: ``t``, ``x``, ``r``, ``u`` or ``F``.
    ratio : float
        A quantity read from that column as if it were SI (a sample step, an amplitude)
        divided by what the manifest's numbers imply for it: about 1000 when t is in ms but
        read as s (or x in mm read as m), 1/1000 when F is in kN but read as N.
    x_unit : str, default "m"
        The set's :attr:`Units.x_unit`: in a rotational set (``"rad"``) x and r are angles
        and u and F torques, so the units suggested are theirs (``mrad``, ``deg``, …;
        ``"kN m"``, ``"mN m"``); with x a sensor signal no unit is suggested for x or r
        (a signal is not converted).

    Returns
    -------
    str
        ``'is t in ms? (then give [units] t = "ms")'`` when ``ratio`` is within a factor 2 of a
        unit's (one of :data:`UNITS_TABLE`'s for the column's quantity, other than SI), else
        ``""``.

    Examples
    --------
    >>> unit_hint("t", 1000.0)
    'is t in ms? (then give [units] t = "ms")'
    >>> unit_hint("F", 1e-3)
    'is F in kN? (then give [units] F = "kN")'
    >>> unit_hint("u", 1e-3, "rad"), unit_hint("x", 57.0, "rad")
    ('is u in kN m? (then give [units] u = "kN m")', 'is x in deg? (then give [units] x = "deg")')
    >>> unit_hint("t", 3.0)
    ''
    """
    quantity = {**UNIT_QUANTITIES, **_TRACKING_QUANTITIES}.get(column)
    if quantity is None or not (ratio > 0 and np.isfinite(ratio)):
        return ""
    if column in _ROTATIONAL:
        kind = x_quantity(x_unit)
        if kind == "signal" and quantity == "length":
            return ""
        if kind == "angle":
            quantity = _ROTATIONAL[column]
    for unit, (mul, div) in UNITS_TABLE[quantity].items():
        if (mul, div) == (1.0, 1.0) or not unit.isascii():
            continue
        if abs(np.log(ratio * mul / div)) <= np.log(2.0):
            return f'is {column} in {unit}? (then give [units] {column} = "{unit}")'
    return ""
