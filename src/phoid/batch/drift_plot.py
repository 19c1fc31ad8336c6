"""Figures of a trend: each unit's estimates over time with their control limits, as PNG files.

One figure per unit, ``trend-<unit>.png`` (characters other than letters, digits, ``-``, ``_``
and ``.`` in the unit's name become ``_``), one panel per parameter: the estimates with ±1
stderr error bars, the baseline b, the control limits b ± threshold·√(sᵢ² + s_b²) of each
point (:mod:`phoid.batch.drift`), the baseline points in grey and the flagged points in red.
Written through :mod:`phoid._output` (inside the folder, atomic, ``overwrite`` asked);
matplotlib is imported inside the function.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid._output import OutputFolder, png_writer

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["axis_label", "plot_trend", "trend_figure", "trend_figure_names"]

#: the SI units of the parameters a batch row can hold (docs/format.md, "phoid batch output");
#: a parameter not listed is labelled by its name alone
UNITS = {"m": "kg", "c": "N s/m", "k": "N/m", "fc": "N", "delay": "s", "omega0": "rad/s",
         "zeta": "–", "sigma": "1/s", "c_over_m": "1/s", "k_over_m": "1/s²", "offset_force": "N"}

#: how a parameter is written on an axis: its symbol as in the text reports (σ is the decay
#: rate; mathtext where unicode has no glyph); a parameter not listed by its name
SYMBOLS = {"omega0": "ω₀", "zeta": "ζ", "sigma": "σ", "fc": "$f_c$", "c_over_m": "c/m",
           "k_over_m": "k/m", "offset_force": "offset force", "delay": "delay"}


def axis_label(name: str) -> str:
    """The y label of a parameter's panel: symbol and unit, e.g. ``ω₀ (rad/s)``, ``ζ (–)``.

    >>> axis_label("omega0"), axis_label("zeta"), axis_label("m")
    ('ω₀ (rad/s)', 'ζ (–)', 'm (kg)')
    """
    symbol = SYMBOLS.get(name, str(name).replace("$", r"\$"))
    unit = UNITS.get(name)
    return f"{symbol} ({unit})" if unit else symbol


#: the most characters of a unit's name in its figure's file name (file systems take 255 bytes)
MAX_NAME = 100


def trend_figure_names(units: list[str]) -> list[str]:
    """The PNG names of the units' figures: ``trend-<unit>.png``, made unique with ``-NN``.

    The unit's name is cut to its first :data:`MAX_NAME` characters; a name already taken
    gets ``-NN`` (NN the unit's position from 1), and ``_`` appended while that is taken too.

    >>> trend_figure_names(["x1", "x/1", "x_1"])
    ['trend-x1.png', 'trend-x_1.png', 'trend-x_1-03.png']
    """
    names: list[str] = []
    for i, unit in enumerate(units):
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", unit)[:MAX_NAME].strip(".")
        stem = "trend-" + (safe or "unit")
        name = f"{stem}.png"
        if name in names:
            name = f"{stem}-{i + 1:02d}.png"
        while name in names:  # the numbered name taken too: by a unit named like it
            name = f"{name[:-4]}_.png"
        names.append(name)
    return names


def plot_trend(trend: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Write one figure per unit of a trend into ``out_dir``.

    Parameters
    ----------
    trend : phoid.batch.drift.Trend
        Read by duck typing: ``units`` (each with ``unit``, ``ordered_by`` and ``charts``: each
        with ``name``, ``points``, ``baseline``, ``baseline_stderr``) and ``threshold``.
    out_dir : str or Path
        The folder (created when missing).
    overwrite : bool
        Replace existing figures; otherwise a file in the way refuses the whole call before
        anything is drawn.

    Returns
    -------
    list of Path
        The files written.
    """
    out = OutputFolder(out_dir, overwrite=overwrite)
    units = [u for u in trend.units if u.charts]
    names = trend_figure_names([u.unit for u in units])
    out.check(names)
    return [out.write(name, png_writer(trend_figure(trend, unit), 110))
            for unit, name in zip(units, names, strict=True)]


def trend_figure(trend: Any, unit: Any) -> Figure:
    """The figure of one unit of ``trend`` (one panel per chart), as :func:`plot_trend`
    writes it; ``trend`` and ``unit`` read as there."""
    import pandas as pd
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(unit.charts)
    fig = Figure(figsize=(7.5, 2.2 * n + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for ax, chart in zip(axes, unit.charts, strict=True):
        t = pd.to_datetime([p.order for p in chart.points], utc=True)
        x = np.array([p.value for p in chart.points])
        s = np.array([p.stderr for p in chart.points])
        base = np.array([p.baseline for p in chart.points])
        flag = np.array([p.flagged for p in chart.points])
        if chart.baseline is not None:
            half = trend.threshold * np.sqrt(s ** 2 + chart.baseline_stderr ** 2)
            ax.axhline(chart.baseline, color="0.3", lw=1, label="baseline")
            tested = ~base
            ax.fill_between(t[tested], (chart.baseline - half)[tested],
                            (chart.baseline + half)[tested], step="mid", color="C0",
                            alpha=0.15, label=f"±{trend.threshold:g} stderr limits")
        ax.errorbar(t[base], x[base], s[base], fmt="o", color="0.5", ms=4,
                    label="baseline points")
        ax.errorbar(t[~base & ~flag], x[~base & ~flag], s[~base & ~flag], fmt="o",
                    color="C0", ms=4, label="in control")
        if flag.any():
            ax.errorbar(t[flag], x[flag], s[flag], fmt="o", color="C3", ms=6,
                        label="flagged")
        ax.set_ylabel(axis_label(chart.name))
    axes[0].set_title(f"{trend.by} {unit.unit}: estimates ± stderr".replace("$", r"\$"))
    handles: dict[str, Any] = {}
    for ax in axes:  # one legend for the panels: every kind of mark, once
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    fig.legend(list(handles.values()), list(handles), loc="outside lower center",
               ncols=len(handles), fontsize="small")
    axes[-1].set_xlabel("time (UTC)" if unit.ordered_by == "time"
                        else "identified at (UTC; the sets carry no time)")
    return fig
