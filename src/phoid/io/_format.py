"""The ``phoid/1`` format's names, and the checks and messages its records, reader and writer share.

The format's constants (:data:`FORMAT`, :data:`MANIFEST`, :data:`METHODS`, the known keys and
columns and their units), the checks of manifest numbers and data columns, the read-only
mappings that keep a set's extra keys, and the one-line
:class:`~phoid.errors.ExperimentError` messages (input quoted printable and length-capped).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, NoReturn

import numpy as np

from phoid.errors import ExperimentError

__all__ = [
    "COLUMNS",
    "FORMAT",
    "LOOP_KEYS",
    "MANIFEST",
    "MAX_MESSAGE",
    "METHODS",
    "RUN_KEYS",
    "TOP_KEYS",
    "UNITS",
    "FrozenMap",
    "case_clash",
    "checked_extra",
    "checked_number",
    "fail",
    "freeze",
    "frozen_array",
    "kind_of",
    "optional_number",
    "printable",
    "show",
    "thaw",
    "unknown_hint",
]

FORMAT = "phoid/1"
"""The value of the manifest's ``format`` key."""
MANIFEST = "experiment.toml"
"""The manifest's file name inside an experiment-set folder."""
METHODS = ("pho", "forced", "free", "tracking")
"""The values of the manifest's ``method`` key."""

TOP_KEYS = ("title", "format", "method", "loop", "run", "mass", "estimator", "fixed", "units",
            "sample_rate")
"""The manifest's top-level keys (``estimator`` and ``fixed``: tracking sets only; ``units``:
the data columns' units, converted to SI on reading, so never kept; ``sample_rate``: t rebuilt
from it on reading, so never kept)."""
RUN_KEYS = ("file", "P", "D", "B", "omega", "added_mass", "bias", "gain", "command_gain",
            "columns", "sample_rate")
"""The keys of a ``[[run]]`` table (``gain``, ``command_gain``, ``columns``: tracking sets
only; ``sample_rate``: not in tracking sets)."""
LOOP_KEYS = ("delay",)
"""The ``[loop]`` keys this package checks (the identification checks the others)."""
COLUMNS = ("t", "x", "u", "F")
"""The data files' known columns, in the order they are kept."""
UNITS = {"P": "N/m", "D": "N·s/m", "B": "N", "omega": "rad/s", "added_mass": "kg",
         "bias": "N", "delay": "s", "mass": "kg", "sample_time": "s", "cutoff": "rad/s",
         "m": "kg", "fc": "N", "sample_rate": "Hz"}
"""The unit of each numeric key, for messages."""
MAX_MESSAGE = 2000
"""Longest error message, characters."""


def fail(where: str, message: str) -> NoReturn:
    """Raise ExperimentError("where: message") on one printable line."""
    text = f"{where}: {message}" if where else message
    raise ExperimentError(printable(text, MAX_MESSAGE)) from None


def printable(text: str, limit: int = 120) -> str:
    """``text`` with every non-printable character escaped as ``repr`` does, length-capped.

    Messages quote file names, keys and cells from the input: a NUL byte, a terminal escape
    sequence or a line break in them must not reach the user's terminal raw, and a 10 MB cell
    must not make a 10 MB message.
    """
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def show(value: Any, limit: int = 60) -> str:
    """A short, one-line rendering of a (TOML or cell) value for messages."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str | bytes):
        text = repr(value[: 4 * limit])
    elif isinstance(value, numbers.Real):
        text = repr(float(value)) if isinstance(value, float) else repr(value)
    elif isinstance(value, Mapping | list | tuple):
        text = f"{kind_of(value)} of {len(value)} item(s)"
    else:
        text = repr(value)
    return printable(text, limit)


def kind_of(value: Any) -> str:
    """What a (TOML) value is, for messages: "a string", "a table", "an array", …"""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array"
    return f"a {type(value).__name__}"


def checked_number(
    where: str, key: str, value: Any, *, minimum: float | None = None, strict: bool = False
) -> float:
    """Check a manifest/run number: a real, finite, and ≥ (or >) ``minimum`` when given."""
    unit = UNITS.get(key, "")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        fail(where, f"key '{key}' must be a number; got {show(value)} ({kind_of(value)})")
    v = float(value)
    if not math.isfinite(v):
        fail(where, f"key '{key}' must be finite; got {v}")
    if minimum is not None:
        ok = v > minimum if strict else v >= minimum
        if not ok:
            rel = ">" if strict else "≥"
            fail(where, f"key '{key}' must be {rel} {minimum:g}{' ' + unit if unit else ''}; "
                         f"got {v!r}")
    return v


def optional_number(where: str, key: str, value: Any, **kw: Any) -> float | None:
    """None for None, else :func:`checked_number` (same keywords)."""
    return None if value is None else checked_number(where, key, value, **kw)


def checked_extra(where: str, extra: Any, known: Any, what: str) -> Mapping[str, Any]:
    """Validate the unknown keys kept beside a table's known ones and freeze them."""
    extra = extra if extra is not None else {}
    if not isinstance(extra, Mapping):
        fail(where, f"`extra` must be a mapping; got {kind_of(extra)}")
    for k in extra:
        if not isinstance(k, str) or k in known:
            fail(where, f"`extra` may not hold the key {show(k)}: it is not an extra key")
    case_clash(where, extra, known, what)
    return freeze(extra)


def case_clash(where: str, keys: Iterable[str], known: Sequence[str], table: str) -> None:
    """Reject keys that differ from a known key only by letter case."""
    lower = {k.lower(): k for k in known}
    for k in keys:
        if k not in known and k.lower() in lower:
            fail(where, f"unknown key '{k}' in {table}: keys are case-sensitive; "
                         f"did you mean '{lower[k.lower()]}'?")


def unknown_hint(keys: Iterable[str], known: Sequence[str]) -> str:
    """A hint naming the keys not in ``known`` (`` (the table has unknown keys 'a', 'b')``),
    or an empty string when there are none."""
    unknown = [k for k in keys if k not in known]
    return f" (the table has unknown keys {', '.join(map(repr, unknown))})" if unknown else ""


class FrozenMap(Mapping[str, Any]):
    """A read-only, picklable mapping (nested tables frozen, arrays turned into tuples)."""

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[str, Any] | None = None) -> None:
        self._data = {str(k): freeze(v) for k, v in (data or {}).items()}

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __repr__(self) -> str:
        return repr(self._data)

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenMap, (self._data,))


def freeze(value: Any) -> Any:
    """Tables as :class:`FrozenMap`, arrays as tuples, recursively; other values as they are."""
    if isinstance(value, Mapping):
        return value if isinstance(value, FrozenMap) else FrozenMap(value)
    if isinstance(value, list | tuple):
        return tuple(freeze(v) for v in value)
    return value


def thaw(value: Any) -> Any:
    """Back to plain dicts and lists (for tomli_w)."""
    if isinstance(value, Mapping):
        return {str(k): thaw(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [thaw(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def frozen_array(where: str, name: str, value: Any, n: int | None) -> np.ndarray:
    """A read-only, 1-D, finite float64 array (copied unless it already is one)."""
    if (isinstance(value, np.ndarray) and value.dtype == np.float64 and value.ndim == 1
            and not value.flags.writeable and value.flags.c_contiguous):
        a = value
    else:
        try:
            a = np.array(value, dtype=np.float64, copy=True)
        except (TypeError, ValueError):
            fail(where, f"column '{name}' must be an array of real numbers")
        if a.ndim != 1:
            fail(where, f"column '{name}' must be 1-dimensional; got shape {a.shape}")
        a.flags.writeable = False
    if n is not None and a.size != n:
        fail(where, f"column '{name}' has {a.size} samples but 't' has {n}")
    if not np.isfinite(a).all():
        i = int(np.flatnonzero(~np.isfinite(a))[0])
        fail(where, f"column '{name}' has a non-finite value at index {i}: {a[i]}")
    return a
