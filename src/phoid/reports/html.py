"""HTML views of results: the notebook display, a one-line ``repr`` and a single-file report.

Every result (and a design) is read through its ``summary()`` (the JSON of ``--json``) by duck
typing, so this module imports no method: the estimates are the entries shaped
``{"value", "stderr", "unit"}`` (at the top level, under ``parameters`` or under
``predicted``), the per-run table is ``runs`` (a value ``X`` and its ``X_stderr`` shown as one
``X ± stderr`` cell), a tracking set's per-run comparison is ``validation``, and the optional
``statistics`` (χ², dof, …), ``covariance`` (``{"params", "units", "matrix"}``) and
``correlation`` (``{"params", "matrix"}``) are shown when present. Every text taken from the
result (run files, warnings, sources) is escaped (:func:`html.escape`): it comes from users'
files.

:func:`report_html` is a whole page with no external reference (figures embedded as base64 PNG,
a Content-Security-Policy that loads nothing from elsewhere and runs no script): the summary,
every figure the result's ``plot()`` writes, the warnings, the environment and the SHA-256 of
the input files. :func:`write_report` writes it through :mod:`phoid._output`.
"""

from __future__ import annotations

import base64
import datetime
import hashlib
import html
import inspect
import io
import json
import math
import os
import platform
import stat
import sys
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from phoid._notation import unit_text
from phoid._output import OutputFolder
from phoid.errors import OutputError
from phoid.reports.text import format_estimate, format_gain

__all__ = ["check_report_target", "column_label", "environment", "estimates_of",
           "file_checksums",
           "report_html", "result_figures", "result_html", "short_repr", "summary_of",
           "write_report"]

# units of the per-run columns phoid's results use (a column not listed is shown bare)
_RUN_UNITS = {
    "P": "N/m", "D": "N s/m", "sigma": "1/s", "omega_d": "rad/s", "c_prime": "N s/m",
    "k_prime": "N/m", "residual_rms": "m", "added_mass": "kg", "omega": "rad/s", "R": "N/m",
    "rho": "rad", "release": "s", "x0": "m", "v0": "m/s", "offset": "m", "noise": "m",
    "stick_time": "s", "omega0": "rad/s", "amplitude": "m", "margin": "1/s",
    "delay_margin": "s", "B": "N", "bias": "N", "noise_sd": "m", "stuck_position": "m",
    "viscous_residual_rms": "m", "stop_time": "s", "C": "m",
}
_MAIN = ("m", "c", "k", "fc")
# the words (and the text report's notation) a summary's JSON key is shown with; a key not
# listed is shown with spaces for its underscores
_LABELS = {
    "file": "run", "name": "run", "sigma": "σ", "omega_d": "ω_d", "omega0": "ω₀",
    "omega": "ω", "zeta": "ζ", "rho": "ρ", "c_prime": "c′", "k_prime": "k′",
    "residual_rms": "resid", "residual_noise_ratio": "resid/noise", "chi2": "χ²",
    "chi2_dof": "χ²/dof", "p_value": "P(χ² ≥ this)", "of": "χ² of", "n_samples": "samples",
    "stick_time": "sticks at", "c_over_m": "c/m", "k_over_m": "k/m", "fc": "f_c",
    "fc_over_m": "f_c/m", "x_unit": "unit of x", "noise_placement_source": "noise placement from",
    "settle_time": "settled at", "t_start": "start", "x0": "x₀", "v0": "v₀",
    "relative_error_percent": "relative error (%)", "dof": "dof", "rss": "RSS",
    "n_residuals": "residuals", "k_over_m_stderr": "k/m stderr",
}
# the per-run values a user gives (gains, bias): shown exactly as given, never rounded
_GAINS = ("P", "D", "bias", "hold_P", "hold_D")
_STYLE = """
.phoid-result{font-family:system-ui,sans-serif;font-size:13px;color:#111;max-width:100%}
.phoid-result h3{margin:.2em 0;font-size:15px}
.phoid-result table{border-collapse:collapse;margin:.4em 0 .8em 0}
.phoid-result th,.phoid-result td{border:1px solid #ccc;padding:2px 6px;text-align:right;
 white-space:normal}
.phoid-result th{background:#f2f2f2;vertical-align:bottom}
.phoid-result .phoid-unit{font-weight:normal;color:#555}
.phoid-result td.phoid-text,.phoid-result th.phoid-text{text-align:left;white-space:normal}
.phoid-result td.phoid-wide{min-width:14em;width:18em}
.phoid-result .phoid-scroll{overflow-x:auto;max-width:100%}
.phoid-result tr.phoid-aside td{color:#999;text-decoration:line-through}
.phoid-warnings{background:#fff3cd;border:1px solid #e0a800;padding:4px 10px;margin:.4em 0}
.phoid-warnings li{margin:.1em 0}
.phoid-ok{color:#2a7a2a}
.phoid-source{color:#555}
.phoid-result caption{text-align:left;font-weight:600;padding:2px 0}
"""


# ------------------------------------------------------------------------------------------
# reading a result
def summary_of(result: Any) -> dict[str, Any]:
    """``result.summary()``; for an object without one, its estimate-shaped attributes
    (``value``, ``stderr``, ``unit``), numbers, strings and ``warnings``."""
    summary = getattr(result, "summary", None)
    if callable(summary):
        return summary()
    out: dict[str, Any] = {}
    names = getattr(result, "__dataclass_fields__", None) or vars(result)
    for name in names:
        if name.startswith("_"):
            continue
        value = getattr(result, name, None)
        if all(hasattr(value, a) for a in ("value", "stderr", "unit")):
            out[name] = {"value": value.value, "stderr": value.stderr, "unit": value.unit}
        elif isinstance(value, (bool, int, float, str)):
            out[name] = value
    out["warnings"] = list(getattr(result, "warnings", ()))
    return out


def _is_estimate(value: Any) -> bool:
    return isinstance(value, dict) and "value" in value and "unit" in value


def estimates_of(summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The estimate-shaped entries of a summary: top level, ``parameters`` and ``predicted``."""
    found = {k: v for k, v in summary.items() if _is_estimate(v)}
    for group in ("parameters", "predicted"):
        sub = summary.get(group)
        if isinstance(sub, dict):
            found.update({k: v for k, v in sub.items() if _is_estimate(v)})
    return found


def _runs_count(result: Any, summary: dict[str, Any]) -> int | None:
    for key in ("runs", "validation"):
        if isinstance(summary.get(key), list):
            return len(summary[key])
    runs = getattr(result, "runs", None)
    return len(runs) if isinstance(runs, (list, tuple)) else None


def _estimate_text(est: dict[str, Any]) -> str:
    value, se = est.get("value"), est.get("stderr")
    if value is None or not isinstance(value, (int, float)) or math.isnan(value):
        return "undefined"
    return format_estimate(float(value), None if se is None else float(se))


def _scalar_text(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float, str)) for v in value):
        return ", ".join(_scalar_text(v) for v in value)
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(value, default=str, ensure_ascii=False)  # χ², ≤ as written
    return str(value)


def column_label(key: str) -> str:
    """The words a summary's JSON key is shown with in HTML (``c_prime`` → ``c′``,
    ``chi2_dof`` → ``χ²/dof``, ``omega0`` → ``ω₀``; others with spaces for underscores).

    Parameters
    ----------
    key : str

    Returns
    -------
    str

    Examples
    --------
    >>> column_label("chi2_dof"), column_label("noise_placement")
    ('χ²/dof', 'noise placement')
    """
    key = str(key)
    if key in _LABELS:
        return _LABELS[key]
    if key.endswith("_stderr") and key[: -len("_stderr")] in _LABELS:
        return f"{_LABELS[key[: -len('_stderr')]]} stderr"
    return key.replace("_", " ")


def _e(value: Any) -> str:
    """Escaped text of any value (quotes too: safe in attributes)."""
    return html.escape(value if isinstance(value, str) else _scalar_text(value), quote=True)


# ------------------------------------------------------------------------------------------
# the one-line repr
def short_repr(result: Any, *, limit: int = 6) -> str:
    """A short ``repr`` of a result: its class, the main estimates ± stderr with units, the
    number of runs and of warnings.

    Parameters
    ----------
    result : any object with ``summary()`` (or estimate-shaped attributes) and ``warnings``
    limit : int
        Most estimates shown (m, c, k, f_c first when present).

    Returns
    -------
    str
        E.g. ``Identification(m = 1.99957 ± 0.00049 kg, c = …, k = …; 19 runs, 0 warnings)``.
    """
    name = type(result).__name__
    try:
        summary = summary_of(result)
    except Exception as exc:  # a repr must not raise: say why the numbers are missing
        return f"<{name}: summary() failed: {type(exc).__name__}>"
    ests = estimates_of(summary)
    keys = [k for k in _MAIN if k in ests] or list(ests)
    parts = [f"{k} = {_estimate_text(ests[k])} {ests[k].get('unit', '')}".rstrip()
             for k in keys[:limit]]
    tail = []
    n = _runs_count(result, summary)
    if n is not None:
        tail.append(f"{n} run{'s' if n != 1 else ''}")
    nw = len(summary.get("warnings") or ())
    tail.append(f"{nw} warning{'s' if nw != 1 else ''}")
    kind = summary.get("kind") or summary.get("estimator")
    head = f"{kind}: " if isinstance(kind, str) else ""
    return f"{name}({head}{', '.join(parts)}; {', '.join(tail)})"


# ------------------------------------------------------------------------------------------
# the HTML fragment
def _table(head: Sequence[str], rows: Iterable[Sequence[str]], *, caption: str = "",
           text_cols: Sequence[int] = (0,), row_classes: Sequence[str] | None = None,
           wide: int | None = None) -> str:
    """A table of already-escaped cells (column ``wide`` about 18 em wide) that fits its box:
    headers and cells wrap at their spaces (a value ± stderr on two lines), and the box
    scrolls sideways only where even that is not enough (a number is never cut)."""
    def cls(j: int) -> str:
        names = ["phoid-text"] * (j in text_cols) + ["phoid-wide"] * (j == wide)
        return f' class="{" ".join(names)}"' if names else ""

    out = ['<div class="phoid-scroll"><table>']
    if caption:
        out.append(f"<caption>{caption}</caption>")
    out.append("<tr>" + "".join(f"<th{cls(j)}>{h}</th>" for j, h in enumerate(head)) + "</tr>")
    for i, row in enumerate(rows):
        rc = f' class="{row_classes[i]}"' if row_classes and row_classes[i] else ""
        out.append(f"<tr{rc}>" + "".join(f"<td{cls(j)}>{c}</td>" for j, c in enumerate(row))
                   + "</tr>")
    out.append("</table></div>")
    return "\n".join(out)


def _estimates_table(ests: dict[str, dict[str, Any]]) -> str:
    rows = []
    for name, est in ests.items():
        value, se = est.get("value"), est.get("stderr")
        rel = (f"{100 * abs(se / value):.2g} %" if isinstance(value, (int, float))
               and isinstance(se, (int, float)) and math.isfinite(value) and value
               and math.isfinite(se) and se > 0 else "")
        notes = "; ".join(f"{k} {_scalar_text(v)}" for k, v in est.items()
                          if k not in ("value", "stderr", "unit"))
        notes = "; ".join(f"{column_label(k)} {_scalar_text(v)}" for k, v in est.items()
                          if k not in ("value", "stderr", "unit"))
        rows.append([_e(column_label(name)), _e(_estimate_text(est)),
                     _e(unit_text(str(est.get("unit", "")))),
                     _e(rel), _e(notes)])
    return _table(["parameter", "estimate ± stderr", "unit", "rel. stderr", "notes"], rows,
                  caption="Estimates", text_cols=(0, 2, 4))


def _warnings_block(warnings: Sequence[Any], title: str = "warning") -> str:
    if not warnings:
        return '<p class="phoid-ok">No warnings.</p>'
    n = len(warnings)
    items = "".join(f"<li>{_e(w)}</li>" for w in warnings)
    return (f'<div class="phoid-warnings" role="alert"><strong>⚠ {n} {title}'
            f'{"s" if n != 1 else ""}</strong><ul>{items}</ul></div>')


def _key_values(mapping: dict[str, Any], caption: str) -> str:
    rows = [[_e(column_label(k)), _e(v)] for k, v in mapping.items()]
    return _table(["", "value"], rows, caption=caption, text_cols=(0, 1)) if rows else ""


def _matrix(params: Sequence[Any], matrix: Any, caption: str,
            units: Sequence[Any] | None = None) -> str:
    try:
        rows_in = [[float(v) for v in row] for row in matrix]
    except (TypeError, ValueError):
        return ""
    names = [column_label(str(p)) + (f" ({unit_text(str(u))})" if units and u else "")
             for p, u in zip(params, units or [None] * len(params), strict=False)]
    if len(names) != len(rows_in):
        names = [str(i + 1) for i in range(len(rows_in))]
    rows = [[_e(names[i]), *(_e(f"{v:.4g}") for v in row)] for i, row in enumerate(rows_in)]
    return _table(["", *(_e(n) for n in names)], rows, caption=caption)


def _run_units(result: Any, summary: dict[str, Any]) -> Any:
    """The labeller of the run columns' SI units: the result's ``unit_of`` where it has one
    (N/m is N m/rad for x in rad); else from the summary's ``x_unit`` (x's own unit for m,
    per s for m/s: a rotational or sensor set's positions), the unit itself without one."""
    unit_of = getattr(result, "unit_of", None)
    if callable(unit_of):
        return unit_of
    x_unit = summary.get("x_unit")
    if not isinstance(x_unit, str) or x_unit == "m":
        return lambda unit: unit
    return lambda unit: {"m": x_unit, "m/s": f"{x_unit}/s",
                         "m/s^2": f"{x_unit}/s^2"}.get(unit, unit)


def _runs_table(runs: list[Any], label: Any = None) -> str:
    label = label if label is not None else (lambda unit: unit)
    runs = [r for r in runs if isinstance(r, dict)]
    if not runs:
        return ""
    keys: list[str] = []
    for r in runs:
        for k, v in r.items():
            if k not in keys and (v is None or isinstance(v, (bool, int, float, str))):
                keys.append(k)
    for first in ("name", "file", "run"):
        if first in keys:
            keys.remove(first)
            keys.insert(0, first)
    cols = [k for k in keys if not (k.endswith("_stderr") and k[: -len("_stderr")] in keys)]
    warned = any(r.get("warnings") for r in runs)
    # the column's words, its unit on a line of its own: narrow columns, a table that fits
    head = [_e(column_label(k)) + (f'<br><span class="phoid-unit">'
                                   f'({_e(unit_text(label(_RUN_UNITS[k])))})'
                                   "</span>" if k in _RUN_UNITS else "") for k in cols]
    rows, classes = [], []
    for r in runs:
        row = []
        for k in cols:
            v, se = r.get(k), r.get(f"{k}_stderr")
            if isinstance(v, (int, float)) and not isinstance(v, bool) and se is not None:
                row.append(_e(format_estimate(float(v), float(se))))
            elif k in _GAINS and isinstance(v, (int, float)) and not isinstance(v, bool):
                row.append(_e(format_gain(v)))  # a gain as given: 12.625, never 12.62
            else:
                row.append(_e(v))
        if warned:
            row.append("<br>".join(_e(w) for w in r.get("warnings") or ()))
        rows.append(row)
        classes.append("phoid-aside" if r.get("used") is False else "")
    if warned:
        head.append("warnings")
    text = [0, *([len(head) - 1] if warned else [])]
    return _table(head, rows, caption=f"Runs ({len(runs)})", text_cols=text,
                  row_classes=classes, wide=len(head) - 1 if warned else None)


def _adequacy_block(ad: dict[str, Any], note: str = "") -> str:
    """The model checks (docs/adequacy.md) as the text report gives them: each check with its
    result, statistic, limit and detail; then each parameter's white-noise and robust stderr
    and the stderr reported (not the summary's JSON). ``note``: why white-noise stderr stand
    where a check failed (the result's ``adequacy.stderr_note``)."""
    rows, failed = [], []
    for c in ad.get("checks") or ():
        if not isinstance(c, dict):
            continue
        passed = c.get("passed")
        state = "n/a" if passed is None else "pass" if passed else "FAIL"
        if passed is False:
            failed.append(column_label(str(c.get("name", ""))))
        rows.append([_e(column_label(str(c.get("name", "")))), _e(state),
                     _e(_scalar_text(c.get("statistic"))), _e(_scalar_text(c.get("threshold"))),
                     _e(c.get("detail", ""))])
    stderr = ad.get("stderr")
    said = {"white": "the white-noise ones", "robust": "robust ones (Newey–West, widened by "
            "the spread between parts where they disagree)"}.get(str(stderr), str(stderr))
    if stderr == "white" and failed:  # as the text report: never "every check passed" then
        said += (f", not widened although {', '.join(failed)} failed: "
                 + (note or "no robust covariance was computed"))
    caption = f"Adequacy: the stderr reported are {said}"
    out = [_table(["check", "result", "statistic", "limit", "detail"], rows, caption=caption,
                  text_cols=(0, 1, 4)) if rows else ""]
    params = ad.get("params") or []
    cols = [(k, w) for k, w in (("stderr_white", "white-noise stderr"),
                                ("stderr_robust", "robust stderr"),
                                ("inflation", "robust / white"))
            if isinstance(ad.get(k), list) and len(ad[k]) == len(params)]
    units = ad.get("units") if isinstance(ad.get("units"), list) else []
    if params and cols:
        prow = [[_e(column_label(str(p))),
                 _e(unit_text(str(units[i])) if i < len(units) and units[i] else ""),
                 *(_e(_scalar_text(ad[k][i])) for k, _ in cols)]
                for i, p in enumerate(params)]
        out.append(_table(["parameter", "unit", *(w for _, w in cols)], prow,
                          caption="Stderr of the checked parameters", text_cols=(0, 1)))
    return "\n".join(x for x in out if x)


def _validation_table(validation: list[Any]) -> str:
    rows = []
    for v in validation:
        if not isinstance(v, dict):
            continue
        for sig, d in (v.get("signals") or {}).items():
            d = d if isinstance(d, dict) else {}
            rows.append([_e(v.get("run", "")), _e(sig), _e(d.get("unit", "")),
                         _e(d.get("relative_error_percent")), _e(d.get("rms")),
                         _e(d.get("measured_rms"))])
    if not rows:
        return ""
    return _table(["run", "signal", "unit", "relative error (%)", "RMS residual",
                   "RMS measured"], rows, caption="Validation: simulated against recorded",
                  text_cols=(0, 1, 2))


def _fit_block(fit: dict[str, Any]) -> str:
    """A tracking fit's statistics, with its covariance or correlation labelled by ``free``."""
    scalars = {k: v for k, v in fit.items()
               if v is None or isinstance(v, (bool, int, float, str))}
    out = [_key_values(scalars, "Fit")]
    free = fit.get("free") if isinstance(fit.get("free"), list) else []
    for key in ("covariance", "correlation"):
        value = fit.get(key)
        if isinstance(value, list):
            out.append(_matrix(free, value, key.capitalize()))
        elif isinstance(value, dict):
            out.append(_matrix(value.get("params", []), value.get("matrix", []),
                               key.capitalize(), value.get("units")))
    return "\n".join(o for o in out if o)


_SHOWN = {"runs", "warnings", "validation", "statistics", "covariance", "correlation", "fit",
          "notes", "parameters", "predicted", "method", "adequacy"}


def result_html(result: Any, *, figure: bool = True) -> str:
    """The result as an HTML fragment (the notebook's ``_repr_html_``).

    Parameters
    ----------
    result : any result with ``summary()`` (see the module's docstring for the keys read);
        also ``source`` or ``path`` (shown), and for the inline figure the attributes
        :mod:`phoid.reports.figures` reads
    figure : bool
        Add a small figure (base64 PNG) where one summarises the result: the eq. (35) lines of
        a PHO identification, the eq. (20) lines of a forced one, a design's root locus.

    Returns
    -------
    str
        A ``<div class="phoid-result">`` with its own ``<style>``.
    """
    summary = summary_of(result)
    name = type(result).__name__
    method = summary.get("method")
    source = getattr(result, "source", None) or getattr(result, "path", None)
    parts = [f"<style>{_STYLE}</style>", '<div class="phoid-result">',
             f"<h3>{_e(name)}{' — ' + _e(method) if isinstance(method, str) else ''}</h3>"]
    if source:
        parts.append(f'<p class="phoid-source">{_e(str(source))}</p>')
    parts.append(_warnings_block(summary.get("warnings") or ()))
    ests = estimates_of(summary)
    if ests:
        parts.append(_estimates_table(ests))
    info = {k: v for k, v in summary.items() if k not in _SHOWN and not _is_estimate(v)
            and (v is None or isinstance(v, (bool, int, float, str)))}
    n = _runs_count(result, summary)
    if n is not None:
        info["runs"] = n
    parts.append(_key_values(info, "Details"))
    stats = summary.get("statistics")
    if isinstance(stats, dict):
        parts.append(_key_values(stats, "Fit statistics"))
    for key in ("covariance", "correlation"):
        value = summary.get(key)
        if isinstance(value, dict):
            parts.append(_matrix(value.get("params", []), value.get("matrix", []),
                                 key.capitalize(), value.get("units")))
    if isinstance(summary.get("adequacy"), dict):
        parts.append(_adequacy_block(summary["adequacy"], getattr(
            getattr(result, "adequacy", None), "stderr_note", "") or ""))
    if isinstance(summary.get("fit"), dict):
        parts.append(_fit_block(summary["fit"]))
    if isinstance(summary.get("runs"), list):
        parts.append(_runs_table(summary["runs"], _run_units(result, summary)))
    if isinstance(summary.get("validation"), list):
        parts.append(_validation_table(summary["validation"]))
    for key, value in summary.items():  # the other tables (a design's settings, prior, …)
        if key not in _SHOWN and isinstance(value, dict) and not _is_estimate(value):
            parts.append(_key_values(value, _e(key)))
    if summary.get("notes"):
        parts.append("<p><strong>Notes</strong></p><ul>"
                     + "".join(f"<li>{_e(x)}</li>" for x in summary["notes"]) + "</ul>")
    if figure:
        parts.append(_inline_figure(result, summary))
    parts.append("</div>")
    return "\n".join(p for p in parts if p)


# ------------------------------------------------------------------------------------------
# figures
def _png(fig: Any, dpi: float) -> bytes:
    from matplotlib.backend_bases import FigureCanvasBase

    if type(fig.canvas) is FigureCanvasBase:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _img(png: bytes, alt: str, width: int | None = None) -> str:
    size = f' style="max-width:{width}px;width:100%"' if width else ' style="max-width:100%"'
    return (f'<img alt="{_e(alt)}"{size} '
            f'src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">')


def _summary_figure(result: Any, summary: dict[str, Any]) -> Any:
    """The one figure that summarises ``result`` (a matplotlib Figure), or None."""
    from phoid.reports import lines

    method = summary.get("method")
    if method == "pho" and hasattr(result, "delay_source") and hasattr(result, "fit"):
        if sum(1 for r in result.runs if r.used) >= 2:
            return lines.pho_lines_figure(result)
    elif method == "forced" and hasattr(result, "fit"):
        return lines.forced_lines_figure(result)
    elif "predicted" in summary and hasattr(result, "roots") and callable(
            getattr(result, "plot", None)):
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 4.2))  # the design's plot lays its axes out itself
        result.plot(ax=fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1]}))
        return fig
    return None


def _inline_figure(result: Any, summary: dict[str, Any]) -> str:
    try:
        fig = _summary_figure(result, summary)
        if fig is None:
            return ""
        return f"<div>{_img(_png(fig, 50), 'summary figure', 560)}</div>"
    except Exception as exc:  # the numbers above stand without the figure; say it is missing
        return f"<p><em>figure not drawn: {_e(type(exc).__name__)}: {_e(str(exc))}</em></p>"


def _close(fig: Any) -> None:
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None and hasattr(fig, "savefig"):
        pyplot.close(fig)


def result_figures(result: Any) -> list[tuple[str, bytes]]:
    """Every figure ``result.plot()`` writes, as ``(file name, PNG bytes)``, in its order.

    ``plot`` is called with a temporary folder (a first parameter ``out_dir`` or ``folder``) or
    a temporary file (a first parameter ``path``); a result without ``plot`` has none.
    """
    plot = getattr(result, "plot", None)
    if not callable(plot):
        return []
    params = list(inspect.signature(plot).parameters)
    with tempfile.TemporaryDirectory(prefix="phoid-html-") as tmp:
        if params and params[0] == "path":
            target = Path(tmp) / "figure.png"
            _close(plot(target))
            written = [target]
        else:
            written = [Path(p) for p in plot(tmp)]
        return [(p.name, p.read_bytes()) for p in written]


# ------------------------------------------------------------------------------------------
# the report
def environment() -> dict[str, str]:
    """Versions of phoid, Python, numpy, scipy and matplotlib, the platform and the UTC date."""
    from importlib import metadata

    phoid = sys.modules.get("phoid")
    out = {"phoid": str(getattr(phoid, "__version__", "unknown")),
           "python": platform.python_version()}
    for name in ("numpy", "scipy", "matplotlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    out["platform"] = platform.platform()
    out["date (UTC)"] = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S")
    return out


def file_checksums(paths: Iterable[str | Path]) -> list[tuple[str, int, str]]:
    """``(path, size in bytes, SHA-256 hex)`` of each file, read in 1 MiB blocks."""
    out = []
    for p in paths:
        h = hashlib.sha256()
        with open(p, "rb") as fh:
            size = 0
            while block := fh.read(1 << 20):
                h.update(block)
                size += len(block)
        out.append((str(p), size, h.hexdigest()))
    return out


def _experiment_files(experiment: Any) -> list[Path]:
    """The manifest and the data files of an experiment set (``path``, ``runs[i].file``)."""
    manifest = Path(experiment.path)
    files = [manifest]
    for run in experiment.runs:
        name = getattr(run, "file", "")
        if name and (manifest.parent / name) not in files:
            files.append(manifest.parent / name)
    return files


def report_html(result: Any, *, experiment: Any = None, inputs: Iterable[str | Path] = (),
                title: str | None = None,
                figures: bool | Sequence[str | Path] = True) -> str:
    """A self-contained HTML page of ``result``: summary, runs, figures, environment, inputs.

    Parameters
    ----------
    result : a result or a design (see :func:`result_html`)
    experiment : phoid.ExperimentSet or alike, optional
        Its manifest (``path``) and data files (``runs[i].file``) are checksummed.
    inputs : iterable of path
        More files to checksum.
    title : str, optional
        The page's title (default: the result's class and source).
    figures : bool or sequence of path
        Embed every figure of ``result.plot()`` (base64 PNG): ``True`` draws them; a sequence
        gives the PNG files ``result.plot()`` has just written (``phoid identify --plots DIR
        --html FILE``), embedded as they are rather than drawn a second time; ``False`` embeds
        none.

    Returns
    -------
    str
        The page: no external URL, no script (its Content-Security-Policy forbids both).

    Raises
    ------
    OSError
        A figure file given is not a regular file or cannot be read.
    """
    summary = summary_of(result)
    source = getattr(result, "source", None) or getattr(result, "path", None)
    title = title or f"phoid {type(result).__name__}" + (f": {source}" if source else "")
    files = [*(_experiment_files(experiment) if experiment is not None else []),
             *(Path(p) for p in inputs)]
    body = [f"<h1>{_e(title)}</h1>", result_html(result, figure=False)]
    if figures is not False:
        drawn = (result_figures(result) if figures is True
                 else [(Path(p).name, _read_png(p)) for p in figures])
        # the whole-set figures (eq. 35 lines, …) before the per-run ones
        figs = sorted(drawn, key=lambda f: f[0].startswith("run"))
        body.append(f"<h2>Figures ({len(figs)})</h2>" if figs else
                    f"<h2>Figures</h2><p>{_e(type(result).__name__)} draws no figures.</p>")
        one = ' style="width:100%;max-width:1000px"' if len(figs) == 1 else ""
        body += [f"<figure{one}>{_img(png, name)}<figcaption>{_e(name)}</figcaption></figure>"
                 for name, png in figs]
    body.append("<h2>Environment</h2>")
    body.append(f'<div class="phoid-result">{_key_values(environment(), "")}</div>')
    body.append("<h2>Input files (SHA-256)</h2>")
    if files:
        rows = [[_e(p), _e(size), f"<code>{h}</code>"] for p, size, h in file_checksums(files)]
        body.append('<div class="phoid-result">'
                    + _table(["file", "bytes", "SHA-256"], rows, text_cols=(0, 2)) + "</div>")
    else:
        body.append("<p>No input files were given.</p>")
    body.append("<h2>Summary (JSON)</h2><details><summary>the result's summary()</summary>"
                f"<pre>{_e(json.dumps(summary, indent=1, default=str))}</pre></details>")
    csp = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f'<meta http-equiv="Content-Security-Policy" content="{csp}">'
            f"<title>{_e(title)}</title>"
            "<style>body{font-family:system-ui,sans-serif;margin:1.5em;max-width:1200px}"
            "figure{margin:.5em 0;display:inline-block;width:49%;vertical-align:top}"
            "figcaption{color:#555;font-size:12px}"
            "img{max-width:100%}pre{font-size:11px}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def _read_png(path: str | Path) -> bytes:
    """The bytes of a figure file just written: a regular file, never followed through a link."""
    # opened without following a link (O_NOFOLLOW, where the platform has it), then checked on
    # the open file: a file swapped for a link or a FIFO between the two is never read
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise OSError(f"{path}: {exc.strerror or exc}; the figure cannot be embedded") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise OSError(f"{path}: not a regular file; the figure cannot be embedded")
        return f.read()


def check_report_target(path: str | Path, *, overwrite: bool = False,
                        figures: str | Path | None = None) -> Path:
    """Refuse a report target that :func:`write_report` would refuse, before any work.

    Parameters
    ----------
    path : str or Path
        The report's file.
    overwrite : bool
        An existing regular file may be replaced.
    figures : str or Path, optional
        Where the same command writes its figures (a folder of PNG files, or one PNG file):
        ``path`` may be neither that path nor a PNG file inside it, nor lie under a name
        ending in ``.png`` inside it (a folder in the way of a figure, or under one).

    Raises
    ------
    phoid.errors.OutputError
        ``path`` is empty, ``.`` or ``..``, a link, a folder, not a regular file, exists
        without ``overwrite``, or would collide with ``figures``.
    """
    path = Path(path)
    if path.name in ("", ".", ".."):
        raise OutputError(f"{str(path)!r}: names a folder, not a file; give the report's file "
                          "name (e.g. report.html)")
    if figures is not None:
        h, f = path.resolve(), Path(figures).resolve()
        if h == f or (f in h.parents and h.relative_to(f).parts[0].lower().endswith(".png")):
            raise OutputError(f"{path}: would collide with the figures written to {figures}; "
                              "give the report another name")
    OutputFolder(path.parent, overwrite=overwrite).check([path.name])
    return path


def write_report(result: Any, path: str | Path, *, experiment: Any = None,
                 inputs: Iterable[str | Path] = (), overwrite: bool = False,
                 figures: bool | Sequence[str | Path] = True) -> Path:
    """Write :func:`report_html` of ``result`` to ``path`` (UTF-8) through :mod:`phoid._output`.

    Parameters
    ----------
    result : a result or a design
    path : str or Path
        The HTML file; its folder is the output folder (created when missing).
    experiment, inputs
        Files to checksum (see :func:`report_html`).
    overwrite : bool
        Replace an existing file (never a link, a folder or a special file).
    figures : bool or sequence of path
        The figures to embed (see :func:`report_html`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    phoid.errors.OutputError
        The target is refused (checked before the figures are drawn).
    OSError
        An input file cannot be read.
    """
    path = check_report_target(path, overwrite=overwrite)
    page = report_html(result, experiment=experiment, inputs=inputs, figures=figures)
    out = OutputFolder(path.parent, overwrite=overwrite)
    return out.write(os.fspath(path.name), page.encode("utf-8"))
