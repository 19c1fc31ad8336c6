"""One row of a batch: a set's identification (or its error) as flat columns.

The row schema is the contract of ``phoid batch``'s Parquet and CSV output (docs/format.md,
"phoid batch output"), read back by ``phoid trend``: the set (path, checksum, options), the
outcome (status, error), the manifest's ``[metadata]``, each estimated parameter with its
standard error, the correlations, the fit statistic, the warnings, and where and when the
identification ran.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from phoid.methods.registry import METHODS, OPTIONS

__all__ = ["BASE_COLUMNS", "ESTIMATOR_VALUES", "OPTION_DEFAULTS", "PARAMETERS", "SCHEMA",
           "canonical_options", "error_row", "options_key", "result_row"]

# the schema's name, stored in the Parquet file's key-value metadata under b"phoid"
SCHEMA = "phoid-batch/1"

# the parameters every table has a column for (null where a method does not give them)
PARAMETERS = ("m", "c", "k", "fc", "delay", "omega0", "zeta")

# the columns of every row, in this order; parameters, correlations and meta_ keys follow
BASE_COLUMNS = ("set", "checksum", "options", "status", "error", "method", "axis", "time",
                *(c for p in PARAMETERS for c in (p, f"{p}_stderr")),
                "chi2_dof", "n_runs", "n_warnings", "warnings", "seconds", "worker",
                "finished", "phoid_version")

# the identify options a batch takes, with their defaults (those of `phoid identify`): the
# registry's table of options, so that a new option reaches `phoid batch` by itself
OPTION_DEFAULTS: dict[str, Any] = {o.name: o.unset for o in OPTIONS}
#: every value `estimator` takes for some method (which applies is the set's method's business)
ESTIMATOR_VALUES: tuple[str, ...] = tuple(dict.fromkeys(
    e for m in METHODS.values() for v in m.variants for e in v.estimators))


def canonical_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """Every identify option with its value (defaults filled in); unknown names refused.

    Raises
    ------
    ValueError
        Naming an option that ``phoid identify`` does not take, or one of the wrong type
        (``delay`` in s and ``mass`` in kg: finite numbers or None; ``estimator``: None or
        one of pho's ``gls``, ``ols`` and tracking's ``auto``, ``idim``, ``output-error``;
        ``no_compensation``, ``friction``: bools).
    """
    unknown = sorted(set(options) - set(OPTION_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown identify option {unknown[0]!r}; the options are "
                         f"{', '.join(OPTION_DEFAULTS)}")
    kinds = {o.name: o for o in OPTIONS}
    for name, value in options.items():
        default = OPTION_DEFAULTS[name]
        text = kinds[name].kind == "text"
        if isinstance(default, bool):
            ok = isinstance(value, bool)
        elif text:  # estimator, noise: a string or None
            ok = value is None or isinstance(value, str)
        else:  # delay (s) and mass (kg): a finite number or None
            ok = value is None or (isinstance(value, int | float) and not isinstance(value, bool)
                                   and math.isfinite(value))
        choices = ESTIMATOR_VALUES if name == "estimator" else kinds[name].choices
        if ok and text and value is not None and choices and value not in choices:
            raise ValueError(f"identify option {name!r} must be one of "
                             f"{', '.join(choices)}; got {value!r}")
        if not ok:
            raise ValueError(f"identify option {name!r} must be "
                             + ("True or False" if isinstance(default, bool) else
                                "a string or None" if text else
                                "a finite number or None") + f"; got {value!r}")
    return {**OPTION_DEFAULTS, **options}


def options_key(options: Mapping[str, Any]) -> str:
    """The options as canonical JSON: every key, sorted, no spaces (the ``options`` column)."""
    return json.dumps(canonical_options(options), sort_keys=True, separators=(",", ":"))


def _timestamp(value: Any) -> str | None:
    """A ``[metadata] time`` (TOML datetime, date or ISO string) as ISO 8601 UTC, or None."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value)
        except ValueError:
            return None
    if not isinstance(value, datetime):  # a TOML date or time of day: no instant
        return None
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return value.astimezone(UTC).isoformat()


def _meta_value(value: Any) -> Any:
    """A ``[metadata]`` scalar as a column value (dates and times as ISO strings; TOML's
    ``nan`` and ``inf`` as null, which JSON, the journal's format, cannot hold)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, bool | int | float | str):
        return value
    return value.isoformat() if hasattr(value, "isoformat") else str(value)


def _common(set_path: str, checksum: str | None, options: str, metadata: Mapping[str, Any],
            *, seconds: float, worker: str, finished: datetime, version: str
            ) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(BASE_COLUMNS)
    axis = metadata.get("axis")
    row.update({"set": set_path, "checksum": checksum, "options": options,
                "axis": None if axis is None else str(axis),
                "time": _timestamp(metadata.get("time")), "seconds": float(seconds),
                "worker": worker, "finished": finished.astimezone(UTC).isoformat(),
                "phoid_version": version, "n_warnings": 0, "warnings": "[]"})
    row.update({f"meta_{k}": _meta_value(v) for k, v in metadata.items()
                if k not in ("axis", "time")})
    return row


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def result_row(set_path: str, checksum: str | None, options: str, metadata: Mapping[str, Any],
               summary: Mapping[str, Any], *, seconds: float, worker: str, finished: datetime,
               version: str, n_runs: int | None = None) -> dict[str, Any]:
    """The row of an identified set, from its result's ``summary()`` (the phoid/1 JSON).

    Every entry of the summary with a ``value`` (at the top level, or in its ``parameters``
    block: a tracking set's) gives a column of that name and one ``<name>_stderr`` (null when
    the method gives none, e.g. a delay given, not estimated); the ``correlation`` block gives
    ``corr_<a>_<b>`` for each pair a before b in its ``params``; ``statistics`` gives
    ``chi2_dof``; ``n_runs`` is the set's number of runs
    (default: the length of the summary's ``runs``).
    """
    row = _common(set_path, checksum, options, metadata, seconds=seconds, worker=worker,
                  finished=finished, version=version)
    row["status"] = "ok"
    row["method"] = summary.get("method")
    nested = summary.get("parameters")
    entries = {**summary, **(nested if isinstance(nested, Mapping) else {})}
    for name, entry in entries.items():
        if (isinstance(entry, Mapping) and "value" in entry
                and (name in PARAMETERS or name not in row)):
            row[name] = _number(entry.get("value"))
            row[f"{name}_stderr"] = _number(entry.get("stderr"))
    corr = summary.get("correlation")
    if isinstance(corr, Mapping):
        names, matrix = list(corr.get("params", [])), corr.get("matrix", [])
        for i, a in enumerate(names):
            for j in range(i + 1, len(names)):
                row[f"corr_{a}_{names[j]}"] = _number(matrix[i][j])
    stats = summary.get("statistics")
    row["chi2_dof"] = _number(stats.get("chi2_dof")) if isinstance(stats, Mapping) else None
    runs = summary.get("runs")
    row["n_runs"] = n_runs if n_runs is not None else (
        len(runs) if isinstance(runs, list) else None)
    warnings = [str(w) for w in summary.get("warnings", [])]
    row["n_warnings"] = len(warnings)
    row["warnings"] = json.dumps(warnings, ensure_ascii=False)
    return row


def error_row(set_path: str, checksum: str | None, options: str, metadata: Mapping[str, Any],
              error: BaseException | str, *, method: str | None = None, seconds: float = 0.0,
              worker: str, finished: datetime, version: str) -> dict[str, Any]:
    """The row of a set that could not be identified: ``status = "error"`` and the message."""
    row = _common(set_path, checksum, options, metadata, seconds=seconds, worker=worker,
                  finished=finished, version=version)
    row["status"] = "error"
    row["method"] = method
    text = error if isinstance(error, str) else (str(error) or type(error).__name__)
    row["error"] = " ".join(text.splitlines())
    return row
