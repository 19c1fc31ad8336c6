"""Records given as pandas objects: a Series or DataFrame with a time index, read into arrays.

pandas is never imported: a table is recognised by duck typing (an ``index`` and a
``to_numpy`` method), so that phoid reads pandas objects without depending on pandas.

* A Series: its index is t, its values x (a Series named after another column, ``u``, ``F``,
  ``r``, ``w`` or ``t``, is refused: it is not a position).
* A DataFrame: the columns ``x`` and optionally ``u``, ``F``, ``r``, ``w``; t is the
  column ``t`` when there is one, else the index.
* A datetime or timedelta index (or ``t`` column) becomes seconds from the first sample,
  from its integer nanoseconds: t_i = (n_i − n_0)/10⁹, exact to rounding.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from phoid.errors import ExperimentError

__all__ = ["TABLE_COLUMNS", "is_table", "table_columns"]

#: the columns a record's DataFrame may have besides ``t`` (docs/format.md's data columns)
TABLE_COLUMNS = ("x", "u", "F", "r", "w")


def is_table(obj: Any) -> bool:
    """True for a pandas Series or DataFrame (or anything with ``index`` and ``to_numpy``)."""
    return hasattr(obj, "index") and callable(getattr(obj, "to_numpy", None)) and not (
        isinstance(obj, np.ndarray))


def _seconds(values: Any, where: str) -> np.ndarray:
    """Times as float seconds: numbers as they are, datetimes and timedeltas from the first."""
    if type(values).__name__ == "RangeIndex":
        raise ExperimentError(f"{where} is the default 0, 1, 2, …, not times: give a column "
                              "'t' (s) or a time index (seconds, datetimes or timedeltas)")
    arr = np.asarray(values)
    if arr.dtype == object and arr.size:
        # timezone-aware datetimes: their differences from the first are timedeltas
        try:
            first = values.iloc[0] if hasattr(values, "iloc") else values[0]
            arr = np.asarray(values - first)
        except (TypeError, ValueError, AttributeError):
            pass
    if arr.dtype.kind in "mM":
        if np.isnat(arr).any():
            i = int(np.flatnonzero(np.isnat(arr))[0])
            raise ExperimentError(f"{where} has a missing time (NaT) at position {i}")
        ns = (arr - arr[0]).astype("timedelta64[ns]").astype(np.int64) if arr.size else (
            np.zeros(0, dtype=np.int64))
        return ns / 1e9
    try:
        out = _real(arr, where)
    except ExperimentError:
        raise ExperimentError(f"{where} is neither real numbers (s) nor datetimes/timedeltas; "
                              f"got dtype {arr.dtype}") from None
    return out


def _real(values: Any, where: str) -> np.ndarray:
    """``values`` as float64; complex numbers (whose imaginary part a cast would drop) and
    what is not numbers (strings, objects) refused, naming ``where``."""
    arr = np.asarray(values)
    if arr.dtype.kind == "c" or (arr.dtype == object and any(isinstance(v, complex)
                                                             for v in arr.flat)):
        raise ExperimentError(f"{where} is complex (dtype {arr.dtype}); a record's values are "
                              "real numbers")
    try:
        return np.asarray(arr, dtype=float)
    except (TypeError, ValueError):
        raise ExperimentError(f"{where} is not numeric (dtype {arr.dtype})") from None


def _check_column(values: np.ndarray, where: str, *, increasing: bool = False) -> np.ndarray:
    if values.ndim != 1:
        raise ExperimentError(f"{where} must be one-dimensional; got shape {values.shape}")
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ExperimentError(f"{where} has a non-finite value ({float(values[i])!r}) at "
                              f"position {i}")
    if increasing:
        d = np.diff(values)
        if not (d > 0).all():
            i = int(np.flatnonzero(~(d > 0))[0]) + 1
            raise ExperimentError(f"{where} is not strictly increasing at position {i}: "
                             f"{float(values[i])!r} s follows {float(values[i - 1])!r} s")
    return values


def table_columns(obj: Any, name: str = "data") -> dict[str, np.ndarray]:
    """The columns of a record given as a Series or DataFrame, as float arrays.

    Parameters
    ----------
    obj : pandas.Series or pandas.DataFrame
        A Series (index t, values x) or a DataFrame (columns ``x`` and optionally ``u``,
        ``F``, ``r``, ``w``; t from a column ``t`` or the index).
    name : str
        The argument's name, for messages.

    Returns
    -------
    dict
        ``t`` (s) and ``x`` (m), and whichever of ``u``, ``F``, ``r``, ``w`` the table has:
        1-D float64 arrays, finite, t strictly increasing.

    Raises
    ------
    ExperimentError
        (a ValueError) naming ``name`` and the column: a missing ``x``, an unknown column,
        a non-finite value, a time that does not increase.
    """
    columns = getattr(obj, "columns", None)
    if columns is None:  # a Series
        t = _seconds(obj.index, f"{name}: the index (t)")
        label = getattr(obj, "name", None)
        if isinstance(label, str) and label in ("t", *TABLE_COLUMNS) and label != "x":
            raise ExperimentError(f"{name}: a Series is read as x (the position, m) but this "
                                  f"one is named {label!r}; give a DataFrame with columns 'x' "
                                  f"and {label!r}")
        where_x = f"{name}: the values (x{'' if label is None else f', named {label!r}'})"
        cols = {"x": _real(obj.to_numpy(), where_x)}
        out = {"t": _check_column(t, f"{name}: the index (t)", increasing=True),
               "x": _check_column(cols["x"], where_x)}
    else:
        labels = [str(c) for c in columns]
        unknown = [c for c in labels if c not in ("t", *TABLE_COLUMNS)]
        if unknown:
            raise ExperimentError(f"{name}: unknown column(s) {', '.join(map(repr, unknown))}; a "
                             f"record's columns are 't' (or the index), "
                             f"{', '.join(map(repr, TABLE_COLUMNS))}")
        if len(set(labels)) != len(labels):
            raise ExperimentError(f"{name}: repeated column names {labels}")
        if "x" not in labels:
            raise ExperimentError(f"{name}: missing column 'x' (the position, m); columns are "
                             f"{labels}")
        if "t" in labels:
            where_t = f"{name}: column 't'"
            t = _seconds(obj[columns[labels.index("t")]], where_t)
        else:
            where_t = f"{name}: the index (t)"
            t = _seconds(obj.index, where_t)
        out = {"t": _check_column(t, where_t, increasing=True)}
        for label, col in zip(labels, columns, strict=True):
            if label == "t":
                continue
            values = _real(obj[col].to_numpy(), f"{name}: column {label!r}")
            out[label] = _check_column(values, f"{name}: column {label!r}")
    if out["t"].size < 2:
        raise ExperimentError(f"{name}: {out['t'].size} sample(s); at least 2 are needed")
    return out
