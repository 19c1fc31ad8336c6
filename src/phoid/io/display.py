"""An experiment set shown in a notebook: its settings and a table of its runs, as HTML.

Built here rather than in :mod:`phoid.reports` because ``io`` imports only the base modules.
Every text from the set's files (title, file names, keys) is escaped (:func:`html.escape`).
"""

from __future__ import annotations

import html
from typing import Any

__all__ = ["experiment_html"]

_COLUMNS = ("t", "x", "u", "F", "r", "w")
_GAINS = (("P", "N/m"), ("D", "N s/m"), ("B", "N"), ("omega", "rad/s"), ("added_mass", "kg"),
          ("bias", "N"), ("gain", ""), ("command_gain", "N per unit"))


def _e(value: Any) -> str:
    return html.escape(f"{value:.6g}" if isinstance(value, float) else str(value), quote=True)


def experiment_html(exp: Any) -> str:
    """An HTML fragment of an experiment set: title, method, delay, mass and the runs.

    Parameters
    ----------
    exp : phoid.ExperimentSet or alike
        Read: ``path``, ``title``, ``method``, ``delay`` (s), ``mass`` (kg), ``estimator``,
        ``fixed`` and ``runs`` (each ``file``, ``t`` (s), the optional columns ``u``, ``F``,
        ``r``, ``w`` and the gains of :class:`phoid.io.records.Run`).

    Returns
    -------
    str
    """
    runs = list(exp.runs)
    gains = [(k, u) for k, u in _GAINS
             if any(getattr(r, k, None) not in (None, 0.0) for r in runs)]
    head = ["run", "file", "samples", "t (s)", "columns",
            *(f"{k} ({u})" if u else k for k, u in gains)]
    rows = []
    for r in runs:
        cols = ",".join(c for c in _COLUMNS if getattr(r, c, None) is not None)
        cells = [r.index or "", r.file, r.t.size, f"{r.t[0]:g} … {r.t[-1]:g}", cols,
                 *(getattr(r, k) if getattr(r, k) is not None else "—" for k, _u in gains)]
        rows.append("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in cells) + "</tr>")
    info = [("path", exp.path), ("method", exp.method),
            ("delay (s)", "not given" if exp.delay is None else exp.delay)]
    info += [(k, v) for k, v in (("mass (kg)", exp.mass), ("estimator", exp.estimator))
             if v is not None]
    if getattr(exp, "fixed", None):
        info.append(("fixed", ", ".join(f"{k} = {v:g}" for k, v in exp.fixed.items())))
    title = f": {_e(exp.title)}" if exp.title else ""
    cell = 'style="border:1px solid #ccc;padding:2px 6px;text-align:left"'
    return "\n".join([
        '<div class="phoid-experiment" style="font-family:system-ui,sans-serif;font-size:13px">',
        f"<h3 style=\"margin:.2em 0\">ExperimentSet{title}</h3>",
        "<table style=\"border-collapse:collapse\">"
        + "".join(f"<tr><th {cell}>{_e(k)}</th><td {cell}>{_e(v)}</td></tr>" for k, v in info)
        + "</table>",
        f"<table style=\"border-collapse:collapse;margin-top:.5em\"><caption style=\"text-align:"
        f"left;font-weight:600\">Runs ({len(runs)})</caption><tr>"
        + "".join(f"<th {cell}>{_e(h)}</th>" for h in head) + "</tr>"
        + "".join(rows).replace("<td>", f"<td {cell}>") + "</table>",
        "</div>",
    ])
