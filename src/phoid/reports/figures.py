"""Figures of results (matplotlib's object API with the Agg canvas: no global state).

matplotlib is imported inside the functions that draw, so importing this module is cheap. The
results are taken by duck typing (see :mod:`phoid.reports.text`): this subpackage never
imports the methods that make them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid._output import OutputFolder, png_writer
from phoid.dynamics.loop import inverse_map

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["figure1", "plot_forced", "plot_free", "plot_identification", "save_png"]


def save_png(fig: Figure, out: OutputFolder, name: str) -> Path:
    """Render ``fig`` as PNG into ``out``/``name`` (atomic, no links followed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    return out.write(name, png_writer(fig, 120))


def plot_identification(ident: Any, out_dir: str | Path, *,
                        overwrite: bool = False) -> list[Path]:
    """Per-run record with fitted decay and residuals, and the eq. (35) lines with error bars.

    Parameters
    ----------
    ident : phoid.Identification or alike
        Read: ``runs`` (each with ``fit`` (a :class:`phoid.fits.DecayFit` or None: its
        ``t_start``, ``t_end``, ``release`` in s, ``fast_modes``, ``cov`` and ``model``),
        ``file``, ``P`` (N/m), ``D`` (N s/m), ``sigma`` (1/s), ``omega_d`` (rad/s),
        ``c_prime`` (N s/m), ``k_prime`` (N/m), ``used``), ``data`` (per run ``(t, x)``, s and
        m), ``delay`` (s) and ``m``, ``c``, ``k`` (each with ``value``: kg, N s/m, N/m).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``run-NN-<file>.png`` for every run with a fit, then
        ``eq35-lines.png``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    plotted = [i for i, r in enumerate(ident.runs) if r.fit is not None and i < len(ident.data)]
    return _write_figures(out_dir, overwrite, "run", ident.runs, plotted,
                          lambda i: _pho_run_figure(ident, i),
                          [("eq35-lines.png", lambda: _lines_figure(ident))])


def _write_figures(out_dir: str | Path, overwrite: bool, prefix: str, runs: Sequence[Any],
                   plotted: Sequence[int], draw_run: Callable[[int], Figure],
                   extra: Sequence[tuple[str, Callable[[], Figure]]] = ()) -> list[Path]:
    """The per-run scaffolding of the ``plot_*`` functions: names, checks, then the writes.

    Run ``i`` (0-based, in ``plotted``) is drawn by ``draw_run(i)`` into
    ``<prefix>-<i + 1:02d>-<stem of runs[i].file>.png``; the ``extra`` figures follow, each
    ``(name, draw)``. Every name is checked in ``out_dir`` before the first figure is drawn
    (:meth:`phoid._output.OutputFolder.check`), so a file in the way writes nothing. Returns
    the paths written, in that order.
    """
    names = {i: f"{prefix}-{i + 1:02d}-{Path(runs[i].file).name.split('.')[0]}.png"
             for i in plotted}
    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check([*names.values(), *(name for name, _ in extra)])
    written = [save_png(draw_run(i), out, names[i]) for i in plotted]
    written += [save_png(draw(), out, name) for name, draw in extra]
    return written


def _pho_run_figure(ident: Any, i: int) -> Figure:
    """Run ``i``'s record, its fitted dominant mode (with the fast loop modes) and residual."""
    from matplotlib.figure import Figure

    r = ident.runs[i]
    t, x = ident.data[i]
    fig = Figure(figsize=(8, 5.5), layout="constrained")
    ax, axr = fig.subplots(2, 1, sharex=True, height_ratios=[3, 1])
    ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
    sel = (t >= r.fit.t_start) & (t <= r.fit.t_end)
    model = r.fit.model(t[sel], fast=True)
    label = "fitted dominant mode" + (" + fast loop modes" if r.fit.fast_modes else "")
    ax.plot(t[sel], model * 1e3, lw=1.0, color="C0", label=label)
    ax.axvline(r.fit.release, color="C3", ls=":", lw=1, label="release")
    ax.set_ylabel("x (mm)")
    ax.set_title(f"{r.file}: P = {r.P:g} N/m, D = {r.D:g} N s/m, "
                 f"σ = {r.sigma:.5g} 1/s, ω_d = {r.omega_d:.5g} rad/s")
    ax.legend(loc="upper right", fontsize=8)
    axr.plot(t[sel], (x[sel] - model) * 1e3, lw=0.5, color="C1")
    axr.set_ylabel("residual (mm)")
    axr.set_xlabel("t (s)")
    return fig


def _line_errors(ident: Any) -> np.ndarray:
    """Standard errors of 2σᵢ, ω₀ᵢ², c′ᵢ, k′ᵢ from each run's (σ, ω_d) covariance (delta method)."""
    rows = []
    for r in ident.runs:
        if not r.used:
            continue
        cov = r.fit.cov
        s, w = r.sigma, r.omega_d
        h = 1e-7 * np.array([max(abs(s), 1e-3), max(w, 1e-3)])
        base = np.array(inverse_map(s, w, r.P, r.D, ident.delay))
        J = np.empty((4, 2))
        for j in range(2):
            d = np.zeros(2)
            d[j] = h[j]
            up = np.array(inverse_map(s + d[0], w + d[1], r.P, r.D, ident.delay))
            J[2:, j] = (up - base) / h[j]
        J[0] = [2.0, 0.0]
        J[1] = [2 * s, 2 * w]
        rows.append(np.sqrt(np.clip(np.diag(J @ cov @ J.T), 0, None)))
    return np.array(rows)


def _lines_figure(ident: Any) -> Figure:
    """The two lines of eq. (35), c′ᵢ against 2σᵢ and k′ᵢ against ω₀ᵢ², with the fitted m, c, k."""
    from matplotlib.figure import Figure

    used = [r for r in ident.runs if r.used]
    s = np.array([r.sigma for r in used])
    w = np.array([r.omega_d for r in used])
    cp = np.array([r.c_prime for r in used])
    kp = np.array([r.k_prime for r in used])
    err = _line_errors(ident)
    m, c, k = ident.m.value, ident.c.value, ident.k.value
    fig = Figure(figsize=(11, 4.5), layout="constrained")
    a, b = fig.subplots(1, 2)
    a.errorbar(2 * s, cp, xerr=err[:, 0], yerr=err[:, 2], fmt="o", ms=4, capsize=2)
    xx = np.linspace(0, 2 * s.max() * 1.05, 50)
    a.plot(xx, m * xx - c, "-", label=f"c′ = 2mσ − c: m = {m:.5g} kg, c = {c:.5g} N s/m")
    a.set_xlabel("2σᵢ (1/s)")
    a.set_ylabel("c′ᵢ (N s/m)")
    a.legend(fontsize=8)
    w0 = s**2 + w**2
    b.errorbar(w0, kp, xerr=err[:, 1], yerr=err[:, 3], fmt="o", ms=4, capsize=2)
    xx = np.linspace(0, w0.max() * 1.05, 50)
    b.plot(xx, m * xx - k, "-", label=f"k′ = mω₀² − k: m = {m:.5g} kg, k = {k:.5g} N/m")
    b.set_xlabel("ω₀ᵢ² (rad²/s²)")
    b.set_ylabel("k′ᵢ (N/m)")
    b.legend(fontsize=8)
    fig.suptitle("eq. (35) lines, per-run error bars ±1 stderr")
    return fig


def plot_free(result: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Per-run record of a free-decay set with its fitted free response and residual.

    Parameters
    ----------
    result : phoid.methods.free.FreeIdentification or alike
        Read: ``runs`` (each with ``file``, ``used``, ``release``, ``t_start`` and ``t_end``,
        s), ``data`` (per run ``(t, x)``, s and m), ``model(i, t)`` (run ``i``'s fitted
        position at times ``t``, m) and ``sigma`` (1/s), ``omega0`` (rad/s), ``zeta`` (each
        with ``value``).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``free-NN-<file>.png`` for every run used.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    return _write_figures(out_dir, overwrite, "free", result.runs, plotted,
                          lambda i: _free_run_figure(result, i))


def _free_run_figure(result: Any, i: int) -> Figure:
    """Run ``i``'s record, the fitted free response over the analysed window, and residual."""
    from matplotlib.figure import Figure

    r = result.runs[i]
    t, x = result.data[i]
    sel = (t >= r.t_start) & (t <= r.t_end)
    model = result.model(i, t[sel])
    fig = Figure(figsize=(8, 5.5), layout="constrained")
    ax, axr = fig.subplots(2, 1, sharex=True, height_ratios=[3, 1])
    ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
    ax.plot(t[sel], model * 1e3, lw=1.0, color="C0", label="fitted free response")
    ax.axvline(r.release, color="C3", ls=":", lw=1, label="release")
    ax.set_ylabel("x (mm)")
    ax.set_title(f"{r.file}: σ = {result.sigma.value:.5g} 1/s, "
                 f"ω₀ = {result.omega0.value:.5g} rad/s, ζ = {result.zeta.value:.4g}")
    ax.legend(loc="upper right", fontsize=8)
    axr.plot(t[sel], (x[sel] - model) * 1e3, lw=0.5, color="C1")
    axr.set_ylabel("residual (mm)")
    axr.set_xlabel("t (s)")
    return fig


def plot_forced(result: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Per-run fits of a forced set (x, model, residual; F) and the eq. (20) lines.

    Parameters
    ----------
    result : phoid.methods.forced.ForcedIdentification or alike
        Read: ``runs`` (each with ``file``, ``used``, ``t_start`` and ``settle_time`` (s),
        ``model(t)`` (the fitted x at times ``t``, m), ``omega`` (rad/s), ``R`` (N/m), ``rho``
        (rad), ``Z`` (R e^{iρ}, N/m) and ``Z_cov`` (its (2, 2) covariance of real and
        imaginary parts, (N/m)²)), ``data`` (per run ``(t, x, F)``, s, m and N) and ``m``,
        ``c``, ``k`` (each with ``value``: kg, N s/m, N/m).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``forced-NN-<file>.png`` for every run used, then
        ``eq20-lines.png``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    return _write_figures(out_dir, overwrite, "forced", result.runs, plotted,
                          lambda i: _forced_run_figure(result, i),
                          [("eq20-lines.png", lambda: _eq20_figure(result))])


def _forced_run_figure(result: Any, i: int) -> Figure:
    """Run ``i``'s record with its steady state + transient, the residual, and the force F."""
    from matplotlib.figure import Figure

    r = result.runs[i]
    t, x, F = result.data[i]
    sel = t >= r.t_start
    model = r.model(t[sel])
    fig = Figure(figsize=(8, 6.5), layout="constrained")
    ax, axr, axf = fig.subplots(3, 1, sharex=True, height_ratios=[3, 1, 1.2])
    ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
    ax.plot(t[sel], model * 1e3, lw=0.9, color="C0", label="steady state + transient")
    ax.axvline(r.settle_time, color="C3", ls=":", lw=1, label="transient < noise")
    ax.set_ylabel("x (mm)")
    ax.set_title(f"{r.file}: ω = {r.omega:.5g} rad/s, R = {r.R:.5g} N/m, "
                 f"ρ = {r.rho:.4g} rad")
    ax.legend(loc="upper right", fontsize=8)
    axr.plot(t[sel], (x[sel] - model) * 1e3, lw=0.5, color="C1")
    axr.set_ylabel("residual (mm)")
    axf.plot(t, F, lw=0.6, color="C2")
    axf.set_ylabel("F (N)")
    axf.set_xlabel("t (s)")
    return fig


def _eq20_figure(result: Any) -> Figure:
    """The two lines of eq. (20): R cos ρ = k − mω² against ω², R sin ρ = cω against ω."""
    from matplotlib.figure import Figure

    used = [r for r in result.runs if r.used]
    w = np.array([r.omega for r in used])
    Z = np.array([r.Z for r in used])
    se = np.array([np.sqrt(np.clip(np.diag(r.Z_cov), 0, None)) for r in used])
    m, c, k = result.m.value, result.c.value, result.k.value
    fig = Figure(figsize=(11, 4.5), layout="constrained")
    a, b = fig.subplots(1, 2)
    a.errorbar(w**2, Z.real, yerr=se[:, 0], fmt="o", ms=4, capsize=2)
    xx = np.linspace(0, (w**2).max() * 1.05, 50)
    a.plot(xx, k - m * xx, "-", label=f"k − mω²: m = {m:.5g} kg, k = {k:.5g} N/m")
    a.axhline(0, color="0.7", lw=0.5)
    a.set_xlabel("ω² (rad²/s²)")
    a.set_ylabel("R cos ρ (N/m)")
    a.legend(fontsize=8)
    b.errorbar(w, Z.imag, yerr=se[:, 1], fmt="o", ms=4, capsize=2)
    xx = np.linspace(0, w.max() * 1.05, 50)
    b.plot(xx, c * xx, "-", label=f"cω: c = {c:.5g} N s/m")
    b.set_xlabel("ω (rad/s)")
    b.set_ylabel("R sin ρ (N/m)")
    b.legend(fontsize=8)
    fig.suptitle("eq. (20), per-run error bars ±1 stderr")
    return fig


def figure1(result: Any, out_dir: str | Path, *,
            overwrite: bool = False) -> tuple[Path, Path]:
    """The seed paper's Figure 1(a) and 1(b) as PNG files.

    (a) c′ᵢ against 2σᵢ, (b) k′ᵢ against ω₀ᵢ²: delay-compensated points as circles with the solid
    least-squares line, uncompensated points as crosses with the dashed line.

    Parameters
    ----------
    result : phoid.paper.PaperResult or alike
        Read: ``with_compensation`` and ``without_compensation``, each with ``c_line`` and
        ``k_line`` (``x``, ``y``, ``slope``, ``intercept``).
    out_dir : path
        Folder to write the PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    (Path, Path)
        ``figure1a.png`` and ``figure1b.png`` in ``out_dir``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for both figures before the first is written.
    """
    from matplotlib.figure import Figure

    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check(["figure1a.png", "figure1b.png"])
    paths = []
    w, wo = result.with_compensation, result.without_compensation
    for tag, line_w, line_wo, xlabel, ylabel, unit, title in (
        ("a", w.c_line, wo.c_line, "2σᵢ (1/s)", "c′ᵢ (N s/m)", "N s/m",
         "(a) Mass (slope) and viscous friction (intercept)"),
        ("b", w.k_line, wo.k_line, "ω₀ᵢ² (rad²/s²)", "k′ᵢ (N/m)", "N/m",
         "(b) Mass (slope) and stiffness (intercept)"),
    ):
        fig = Figure(figsize=(6.4, 4.8), layout="constrained")
        ax = fig.subplots()
        xx = np.linspace(0.0, max(line_w.x.max(), line_wo.x.max()) * 1.05, 50)
        ax.plot(line_w.x, line_w.y, "o", mfc="none", color="C0", label="with delay compensation")
        ax.plot(xx, line_w.slope * xx + line_w.intercept, "-", color="C0",
                label=f"fit: slope {line_w.slope:.4f} kg, intercept {line_w.intercept:.4f} {unit}")
        ax.plot(line_wo.x, line_wo.y, "x", color="C3", label="without compensation")
        ax.plot(xx, line_wo.slope * xx + line_wo.intercept, "--", color="C3",
                label=f"fit: slope {line_wo.slope:.4f} kg, "
                      f"intercept {line_wo.intercept:.4f} {unit}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        paths.append(save_png(fig, out, f"figure1{tag}.png"))
    return paths[0], paths[1]
