"""Results as pandas DataFrames: the estimates (value, stderr, unit) and the runs' table.

Both are built from the result's own ``summary()`` (its JSON object, docs/format.md), by
duck typing: every top-level entry of the form ``{"value", "stderr", "unit"}`` is an estimate,
and the entries of ``runs`` (``validation`` for a tracking set) are the runs. pandas is
optional (``pip install 'phoid[pandas]'``) and imported inside the functions.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

__all__ = ["Frames", "estimates_frame", "require_pandas", "runs_frame", "to_pandas"]


def require_pandas() -> Any:
    """The ``pandas`` module, or an ImportError of one line saying how to install it."""
    try:
        import pandas
    except ImportError:
        raise ImportError("pandas is not installed: pip install 'phoid[pandas]'") from None
    return pandas


class Frames(NamedTuple):
    """The two tables of a result (:func:`to_pandas`).

    Attributes
    ----------
    estimates : pandas.DataFrame
        One row per estimate (index ``parameter``: m, c, k, …), columns ``value``,
        ``stderr`` (NaN where unknown) and ``unit``.
    runs : pandas.DataFrame
        One row per run, the columns of the result's run table (``summary()["runs"]``);
        a list (the warnings) is joined with "; ", a nested object's keys are prefixed
        with its name and a dot (``u.delay``).
    """

    estimates: Any
    runs: Any


def _is_estimate(v: Any) -> bool:
    return isinstance(v, dict) and {"value", "stderr", "unit"} <= set(v)


def _num(x: Any) -> float:
    return math.nan if x is None else float(x)


def estimates_frame(result: Any) -> Any:
    """The estimates of a result as a DataFrame (rows m, c, k, …; value, stderr, unit)."""
    pd = require_pandas()
    summary = result.summary()
    source = summary.get("parameters") if isinstance(summary.get("parameters"), dict) else {}
    rows = {name: v for name, v in {**summary, **source}.items() if _is_estimate(v)}
    frame = pd.DataFrame(
        {"value": [_num(v["value"]) for v in rows.values()],
         "stderr": [_num(v["stderr"]) for v in rows.values()],
         "unit": [str(v["unit"]) for v in rows.values()]},
        index=pd.Index(list(rows), name="parameter"))
    return frame


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in d.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flat(value, f"{name}."))
        elif isinstance(value, (list, tuple)):
            out[name] = "; ".join(map(str, value))
        else:
            out[name] = math.nan if value is None else value
    return out


def runs_frame(result: Any) -> Any:
    """The runs of a result as a DataFrame: one row per run, the run table's columns."""
    pd = require_pandas()
    summary = result.summary()
    runs = summary.get("runs", summary.get("validation", []))
    rows = [_flat(r) for r in runs]
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    return pd.DataFrame(rows, columns=columns)


def to_pandas(result: Any) -> Frames:
    """Both tables of a result: ``Frames(estimates, runs)`` (see :class:`Frames`).

    Examples
    --------
    >>> est, runs = result.to_pandas()  # doctest: +SKIP
    >>> est.loc["m", "value"], len(runs)  # doctest: +SKIP
    """
    return Frames(estimates_frame(result), runs_frame(result))
