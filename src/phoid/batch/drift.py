"""Drift of the estimates over time: a Shewhart chart of each unit's parameters from a batch output.

The batch output (``phoid batch``, docs/format.md "phoid batch output") holds one row per
identified set. For each unit (the value of a grouping column, ``axis`` by default) and each
estimated parameter p, the rows with ``status = "ok"`` are put in time order and charted:

* **baseline** — the inverse-variance weighted mean of the first ``baseline`` points,
  b = Σ wᵢxᵢ / Σ wᵢ with wᵢ = 1/sᵢ², and its standard error s_b = (Σ wᵢ)^(-1/2);
* **each later point** — z_i = (x_i − b) / √(s_i² + s_b²), flagged when |z_i| > ``threshold``.

Under no change, with the reported standard errors sᵢ correct and the estimates normal, x_i − b
is normal with variance s_i² + s_b² exactly (x_i is independent of the baseline points), so
each z_i is standard normal and the chance that a point is flagged is the nominal
α = 2 Φ(−threshold) (0.27 % for 3): the false alarm rate per point, whatever the number of
baseline points. Points share the baseline, so the flags of one series are correlated; the
rate per point is still α. The baseline points themselves are not tested; their scatter is
checked instead: χ² = Σ wᵢ(xᵢ − b)² on ``baseline − 1`` degrees of freedom, and a warning when
its upper tail is below 0.001 (the baseline moved, or the stderrs are too small — either makes
the chart's limits wrong).

An estimate that is not finite or has no finite stderr > 0 (a normal float: a subnormal one,
below 2.2e-308, is no measured uncertainty) cannot be weighed or tested: it is left out of
its chart with a warning naming its set (a parameter with no stderr in any row, e.g. a
delay given rather than estimated, is not charted). The sums are scaled (values by their
largest magnitude, weights by the largest weight), so that estimates near the largest float
do not overflow.

Units whose rows all carry a ``time`` are ordered by it; a unit with a row without one is
ordered by ``finished`` (when each set was identified) with a warning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from phoid.errors import ExperimentError

__all__ = ["REQUIRED_COLUMNS", "ChartPoint", "ParameterChart", "Trend", "UnitTrend",
           "control_chart", "read_results", "trend"]

REQUIRED_COLUMNS = ("set", "checksum", "status", "method", "time", "finished")
"""The batch output's columns the trend reads, besides ``--by`` and the estimates."""

# the estimated parameters in the order a report lists them; any other column p with a
# p_stderr column beside it is charted after these
_ORDER = ("m", "c", "k", "fc", "delay", "omega0", "zeta", "sigma", "omega_d")


#: how a parameter is written in the report: its symbol as in the other text reports (σ is
#: the decay rate); a parameter not listed by its name
_SYMBOLS = {"omega0": "ω₀", "zeta": "ζ", "sigma": "σ", "omega_d": "ω_d", "c_over_m": "c/m",
            "k_over_m": "k/m", "offset_force": "offset force"}

_TINY = float(np.finfo(float).tiny)  # the smallest normal float: a stderr below it is no stderr


def _normal_tail(z: float) -> float:
    """Two-sided tail 2 Φ(−|z|) of the standard normal (math.erfc: no scipy needed)."""
    return math.erfc(abs(z) / math.sqrt(2.0))


@dataclass(frozen=True)
class ChartPoint:
    """One estimate on a unit's chart.

    Attributes
    ----------
    set : str
        The set's path as the batch output names it.
    time : str or None
        The set's time (ISO 8601, UTC) or, for a unit ordered by ``finished``, None.
    order : str
        The ISO 8601 time the point is ordered by (``time`` or ``finished``).
    value, stderr : float
        The estimate and its standard error (the parameter's SI unit).
    z : float or None
        (value − baseline) / √(stderr² + baseline_stderr²); None for a baseline point.
    flagged : bool
        |z| > threshold.
    baseline : bool
        One of the points the baseline is computed from.
    """

    set: str
    time: str | None
    order: str
    value: float
    stderr: float
    z: float | None
    flagged: bool
    baseline: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"set": self.set, "time": self.time, "order": self.order,
                "value": self.value, "stderr": self.stderr, "z": self.z,
                "flagged": self.flagged, "baseline": self.baseline}


@dataclass(frozen=True)
class ParameterChart:
    """One parameter of one unit, charted.

    Attributes
    ----------
    name : str
        The parameter (a column of the batch output).
    points : tuple of ChartPoint
        In time order.
    baseline, baseline_stderr : float or None
        b and s_b of the module's equations; None when the unit has fewer points than the
        baseline needs.
    baseline_chi2 : float or None
        Σ wᵢ(xᵢ − b)² of the baseline points (``baseline − 1`` degrees of freedom).
    baseline_p : float or None
        Its upper tail probability.
    """

    name: str
    points: tuple[ChartPoint, ...]
    baseline: float | None
    baseline_stderr: float | None
    baseline_chi2: float | None
    baseline_p: float | None

    @property
    def flagged(self) -> int:
        """Number of flagged points."""
        return sum(p.flagged for p in self.points)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"baseline": self.baseline, "baseline_stderr": self.baseline_stderr,
                "baseline_chi2": self.baseline_chi2, "baseline_p": self.baseline_p,
                "flagged": self.flagged, "points": [p.to_dict() for p in self.points]}


@dataclass(frozen=True)
class UnitTrend:
    """The charts of one unit.

    Attributes
    ----------
    unit : str
    ordered_by : {"time", "finished"}
    charts : tuple of ParameterChart
    """

    unit: str
    ordered_by: str
    charts: tuple[ParameterChart, ...]


@dataclass(frozen=True)
class Trend:
    """The charts of every unit of a batch output.

    Attributes
    ----------
    source : str
        The file read.
    by : str
        The grouping column.
    baseline : int
        Number of points the baseline is computed from.
    threshold : float
        The |z| a point must exceed to be flagged.
    units : tuple of UnitTrend
    warnings : tuple of str
    """

    source: str
    by: str
    baseline: int
    threshold: float
    units: tuple[UnitTrend, ...]
    warnings: tuple[str, ...] = ()

    @property
    def false_alarm_rate(self) -> float:
        """The chance per tested point of a flag under no change: 2 Φ(−threshold)."""
        return _normal_tail(self.threshold)

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: the settings, each unit's charts, the warnings."""
        return {
            "source": self.source, "by": self.by, "baseline": self.baseline,
            "threshold": self.threshold, "false_alarm_rate": self.false_alarm_rate,
            "units": [{"unit": u.unit, "ordered_by": u.ordered_by,
                       "parameters": {ch.name: ch.to_dict() for ch in u.charts}}
                      for u in self.units],
            "warnings": list(self.warnings),
        }

    def report(self) -> str:
        """A text table: per unit and parameter the last value ± stderr, its change from the
        baseline, z, and the number of flagged points."""
        from phoid._notation import fit_width
        from phoid._output import safe_text
        from phoid.batch.drift_plot import UNITS
        from phoid.reports.text import format_number, text_table

        lines = [f"trend of {safe_text(self.source)} by {safe_text(self.by)}: baseline = "
                 "weighted mean of the first "
                 f"{self.baseline} points; flag |z| > {self.threshold:g} "
                 f"(false alarm rate {100 * self.false_alarm_rate:.2g} % per point)", ""]
        rows = []
        for u in self.units:
            for ch in u.charts:
                last = ch.points[-1]
                rows.append([safe_text(u.unit), _SYMBOLS.get(ch.name, safe_text(ch.name)),
                             UNITS.get(ch.name, "").replace("–", ""), str(len(ch.points)),
                             f"{last.value:.6g}", f"{last.stderr:.3g}",
                             "" if ch.baseline is None else f"{_change(last.value, ch):.5g}",
                             "" if last.z is None else format_number(last.z, 2),
                             str(ch.flagged)])
        lines += text_table([(safe_text(self.by), ""), ("parameter", ""), ("unit", ""),
                             ("points", ""), ("last", ""), ("± stderr", ""),
                             ("change", ""), ("z", ""), ("flagged", "")], rows, indent=0,
                            left=3)
        flagged = [(u.unit, ch.name, p) for u in self.units for ch in u.charts
                   for p in ch.points if p.flagged]
        if flagged:
            lines += ["", "flagged points:"]
            lines += [f"  {safe_text(unit)} {_SYMBOLS.get(name, safe_text(name))} at {p.order}: "
                      f"{p.value:.6g} ± {p.stderr:.3g} "
                      f"{UNITS.get(name, '').replace('–', '')}".rstrip()
                      + f" (z = {format_number(p.z or 0.0, 2)}; {safe_text(p.set)})"
                      for unit, name, p in flagged]
        lines += [f"warning: {safe_text(w)}" for w in self.warnings]
        return fit_width("\n".join(lines))


def _change(value: float, chart: ParameterChart) -> float:
    """value − baseline without overflow where both are near the largest float (inf when the
    difference itself is beyond it)."""
    b = chart.baseline if chart.baseline is not None else value
    return 0.0 if value == b else float(value) - float(b)  # Python floats: inf, no warning


def control_chart(values: Any, stderrs: Any, *, baseline: int = 5,
                  threshold: float = 3.0) -> dict[str, Any]:
    """The chart of one series: baseline from the first points, z of every later one.

    Parameters
    ----------
    values, stderrs : array_like, shape (n,)
        The estimates in time order and their standard errors (> 0, finite).
    baseline : int
        Number of leading points the baseline is the weighted mean of (≥ 1).
    threshold : float
        A point is flagged when |z| > threshold (> 0).

    Returns
    -------
    dict
        ``baseline`` (b), ``baseline_stderr`` (s_b), ``chi2`` and ``p`` of the baseline points'
        scatter (None with one point), ``z`` (ndarray, NaN at the baseline points) and
        ``flagged`` (bool ndarray). With fewer than ``baseline`` + 1 points, b and s_b are
        None and nothing is tested.

    Examples
    --------
    >>> chart = control_chart([1.0, 1.0, 1.0, 1.0, 1.0, 1.5], [0.1] * 6)
    >>> round(float(chart["z"][-1]), 3)  # 0.5 / sqrt(0.1**2 + 0.1**2 / 5)
    4.564
    >>> chart["flagged"].tolist()
    [False, False, False, False, False, True]
    """
    x = np.asarray(values, dtype=float)
    s = np.asarray(stderrs, dtype=float)
    if x.shape != s.shape or x.ndim != 1:
        raise ValueError(f"`values` and `stderrs` must be 1-D of one length; got shapes "
                         f"{x.shape} and {s.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(s)) and np.all(s >= _TINY)):
        raise ValueError("`values` must be finite and `stderrs` finite and ≥ "
                         f"{_TINY:.3g} (a normal float > 0)")
    if int(baseline) != baseline or baseline < 1:
        raise ValueError(f"`baseline` must be a whole number ≥ 1; got {baseline!r}")
    if not threshold > 0:
        raise ValueError(f"`threshold` must be > 0; got {threshold!r}")
    z = np.full(x.shape, np.nan)
    out: dict[str, Any] = {"baseline": None, "baseline_stderr": None, "chi2": None, "p": None,
                           "z": z, "flagged": np.zeros(x.shape, bool)}
    if len(x) <= baseline:
        return out
    # scaled so that nothing overflows or underflows between values near the largest float and
    # stderrs near the smallest: values by their largest magnitude, weights by the largest one
    # (w_i / w_max = (s_min / s_i)^2 in (0, 1])
    scale = float(np.max(np.abs(x))) or 1.0
    xs = x / scale
    s_min = float(np.min(s[:baseline]))
    w = (s_min / s[:baseline]) ** 2
    bs = float(np.sum(w * xs[:baseline]) / np.sum(w))
    b = bs * scale
    sb = s_min / math.sqrt(float(np.sum(w)))
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        diff = xs[baseline:] - bs  # |diff| ≤ 2: the difference in units of the scale
        spread = np.hypot(s[baseline:], sb) / scale
        z[baseline:] = np.where(diff == 0.0, 0.0, diff / spread)
        if baseline > 1:
            from phoid.methods.chi2 import chi2_sf

            dev = xs[:baseline] - bs
            chi2 = float(np.sum(w * np.where(dev == 0.0, 0.0, dev * (scale / s_min)) ** 2))
            out.update(chi2=chi2, p=float(chi2_sf(chi2, baseline - 1)))
    out.update(baseline=b, baseline_stderr=sb, z=z, flagged=np.abs(np.nan_to_num(z)) > threshold)
    return out


def read_results(path: str | Path, *, by: str = "axis") -> Any:
    """Read a batch output (Parquet, or its CSV) as a DataFrame and check its columns.

    Parameters
    ----------
    path : str or Path
        ``results.parquet`` or ``results.csv`` as ``phoid batch`` writes them. A Parquet file
        is read with pyarrow; where pyarrow is missing, the CSV beside it is read instead.
    by : str
        The grouping column; it must be one of the file's columns.

    Returns
    -------
    pandas.DataFrame
        ``time`` and ``finished`` as UTC timestamps (NaT where null).

    Raises
    ------
    ExperimentError
        The file cannot be read, or a column is missing (naming the file and the column).
    """
    import pandas as pd

    from phoid.io import not_regular, open_regular

    path = Path(path)
    give = "give the batch output file (results.parquet or results.csv)"
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise ExperimentError(f"{path}: no such file") from None
    except (OSError, RuntimeError, ValueError) as exc:  # a loop of links, a name too long
        raise ExperimentError(f"{path}: cannot be read: {getattr(exc, 'strerror', None) or exc}"
                              ) from None
    kind = not_regular(mode)
    if kind is not None:  # a named pipe would block the read, a device never end
        raise ExperimentError(f"{path}: is {kind}, not a regular file; {give}")
    try:
        if path.suffix.lower() == ".csv":
            # the Parquet's floats exactly: pandas 3 parses them so by default (and deprecates
            # the argument), pandas 2 when asked
            exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {
                "float_precision": "round_trip"}
            f, _ = open_regular(str(path), path, "batch output")  # not swapped for a pipe
            with f:
                frame = pd.read_csv(f, dtype={"set": str, "checksum": str, by: str}, **exact)
        else:
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                csv = path.with_suffix(".csv")
                if not csv.is_file():
                    raise ExperimentError(
                        f"{path}: reading Parquet needs pyarrow (pip install 'phoid[batch]'), "
                        f"and there is no {csv.name} beside it") from None
                return read_results(csv, by=by)
            f, _ = open_regular(str(path), path, "batch output")
            with f:
                frame = pd.read_parquet(f)
    except ExperimentError:
        raise
    except Exception as exc:  # a file that is not a table: pyarrow's and pandas' own errors
        raise ExperimentError(f"{path}: not a phoid batch output ({' '.join(str(exc).split())})"
                              ) from None
    for column in (*REQUIRED_COLUMNS, by):
        if column not in frame.columns:
            raise ExperimentError(f"{path}: not a phoid batch output: no column {column!r}"
                                  + (" (the --by column)" if column == by else ""))
    for column in ("time", "finished"):
        try:
            frame[column] = pd.to_datetime(frame[column], utc=True)
        except (ValueError, TypeError) as exc:
            raise ExperimentError(f"{path}: column {column!r} is not a time: "
                                  f"{' '.join(str(exc).split())}") from None
    return frame


def _parameters(frame: Any) -> list[str]:
    """The estimated parameters: columns p with a p_stderr column beside them."""
    names = [c for c in frame.columns if isinstance(c, str) and f"{c}_stderr" in frame.columns]
    return sorted(names, key=lambda n: (_ORDER.index(n) if n in _ORDER else len(_ORDER), n))


def _iso(stamp: Any) -> str | None:
    return None if stamp is None or stamp != stamp else stamp.isoformat()  # NaT != NaT


def trend(results: str | Path | Any, *, by: str = "axis", baseline: int = 5,
          threshold: float = 3.0) -> Trend:
    """Chart every unit's estimates over time and flag the changes their stderrs do not explain.

    Parameters
    ----------
    results : str, Path or pandas.DataFrame
        A batch output file (:func:`read_results`) or the DataFrame
        :func:`phoid.identify_many` returns.
    by : str
        The column naming the unit (``axis``: the manifest's ``[metadata] axis``).
    baseline : int
        Number of leading points of each series the baseline is the weighted mean of.
    threshold : float
        |z| above which a point is flagged (3: 0.27 % false alarms per point).

    Returns
    -------
    Trend

    Raises
    ------
    ExperimentError
        A missing column, or no row with ``status = "ok"`` and a unit.
    """
    if int(baseline) != baseline or baseline < 1:
        raise ValueError(f"`baseline` must be a whole number ≥ 1; got {baseline!r}")
    if not (math.isfinite(threshold) and threshold > 0):
        raise ValueError(f"`threshold` must be finite and > 0; got {threshold!r}")
    if isinstance(results, (str, Path)):
        source = str(results)
        frame = read_results(results, by=by)
    else:
        source = "<DataFrame>"
        frame = results.copy()
        for column in (*REQUIRED_COLUMNS, by):
            if column not in frame.columns:
                raise ExperimentError(f"{source}: not a phoid batch output: no column "
                                      f"{column!r}")
        import pandas as pd

        for column in ("time", "finished"):
            frame[column] = pd.to_datetime(frame[column], utc=True)
    warnings: list[str] = []
    ok = frame[(frame["status"] == "ok") & frame[by].notna()]
    if len(ok) == 0:
        raise ExperimentError(f"{source}: no row with status 'ok' and a value in the column "
                              f"{by!r}")
    if (dropped := int((frame["status"] == "ok").sum()) - len(ok)):
        warnings.append(f"{dropped} ok rows without a {by!r} left out")
    units = []
    for unit, rows in ok.groupby(ok[by].astype(str), sort=True):
        if rows["time"].isna().any():
            ordered_by = "finished"
            warnings.append(f"{by} {unit}: {int(rows['time'].isna().sum())} of {len(rows)} "
                            "rows have no time (the manifest's [metadata] time); ordered by "
                            "when they were identified (finished)")
        else:
            ordered_by = "time"
        rows = rows.sort_values([ordered_by, "finished"], kind="stable")
        mixed = [col for col in ("method", "options")
                 if col in rows.columns and rows[col].astype(str).nunique() > 1]
        if mixed:
            warnings.append(f"{by} {unit}: its sets were identified with different "
                            f"{' and '.join(mixed)}; a change there shows as a change of the "
                            "estimates")
        charts = []
        for name in _parameters(rows):
            estimated = rows[rows[name].notna()]
            shown = _SYMBOLS.get(name, name)  # as the report writes it
            spread = estimated[f"{name}_stderr"].to_numpy(float)
            with np.errstate(invalid="ignore"):
                usable = (np.isfinite(estimated[name].to_numpy(float)) & np.isfinite(spread)
                          & (spread >= _TINY))
            sel = estimated[usable]
            if len(sel) == 0 and not np.isfinite(spread).any():
                continue  # never estimated with an uncertainty (e.g. a delay given)
            if (left := len(estimated) - len(sel)):
                warnings.append(f"{by} {unit}, {shown}: {left} of {len(estimated)} estimates "
                                "without a finite value and stderr > 0 (a finite, normal "
                                f"float: at least {_TINY:.3g}) left out of the chart "
                                f"(first: {estimated['set'][~usable].iloc[0]})")
            if len(sel) == 0:
                continue
            x = sel[name].to_numpy(float)
            s = sel[f"{name}_stderr"].to_numpy(float)
            chart = control_chart(x, s, baseline=baseline, threshold=threshold)
            points = tuple(
                ChartPoint(set=str(r["set"]),
                           time=_iso(r["time"]) if ordered_by == "time" else None,
                           order=_iso(r[ordered_by]) or "", value=float(x[i]),
                           stderr=float(s[i]),
                           z=None if np.isnan(chart["z"][i]) else float(chart["z"][i]),
                           flagged=bool(chart["flagged"][i]), baseline=i < baseline)
                for i, (_, r) in enumerate(sel.iterrows()))
            if chart["baseline"] is None:
                warnings.append(f"{by} {unit}, {shown}: {len(x)} point{'s' * (len(x) != 1)}, "
                                f"no more than the baseline's {baseline}; nothing tested")
            elif chart["p"] is not None and chart["p"] < 1e-3:
                warnings.append(
                    f"{by} {unit}, {shown}: the {baseline} baseline points scatter more than "
                    f"their stderrs explain (χ² = {chart['chi2']:.3g} on {baseline - 1} dof, "
                    f"p = {chart['p']:.2g}); the control limits are too narrow")
            charts.append(ParameterChart(name, points, chart["baseline"],
                                         chart["baseline_stderr"], chart["chi2"], chart["p"]))
        units.append(UnitTrend(str(unit), ordered_by, tuple(charts)))
    return Trend(source, by, int(baseline), float(threshold), tuple(units), tuple(warnings))
