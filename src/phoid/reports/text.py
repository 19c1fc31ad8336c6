"""Text reports and figures (matplotlib's object API with the Agg canvas: no global state)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from phoid._output import OutputFolder, png_writer
from phoid.dynamics import inverse_map

if TYPE_CHECKING:
    from phoid.methods.identification import Identification
    from phoid.paper import PaperResult

__all__ = ["figure1", "identification_text", "plot_identification"]


def format_estimate(value: float, se: float | None) -> str:
    if se is None or not math.isfinite(se) or se <= 0:
        return f"{value:.6g}"
    digits = max(0, 1 - math.floor(math.log10(se)))
    return f"{value:.{digits}f} ± {se:.2g}"


def identification_text(ident: Identification) -> str:
    """Plain-text report of an identification: estimates, derived ζ and ω₀, runs, warnings."""
    lines = [f"phoid identify: {ident.source}" if ident.source else "phoid identify"]
    delay = (f"{ident.delay:g} s" if ident.delay_stderr is None
             else f"{format_estimate(ident.delay, ident.delay_stderr)} s")
    origin = {"x": " from x", "x+u": " from x and u"}.get(getattr(ident, "delay_from", None), "")
    lines.append(f"  estimator {ident.fit.estimator}, delay {delay} ({ident.delay_source}"
                 f"{origin})")
    lines.extend(_digital_line(ident))
    lines.append("")
    for name, est in (("m", ident.m), ("c", ident.c), ("k", ident.k)):
        lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {est.unit}")
    w0, z = ident.omega0, ident.zeta
    zeta = format_estimate(z.value, z.stderr) if math.isfinite(z.value) else "inf (k = 0)"
    lines.append(f"  open-loop ω₀ = {format_estimate(w0.value, w0.stderr)} rad/s,  ζ = {zeta}")
    lines.append("")
    # a space before each wide column: a long value (σ ± stderr) never runs into the one before
    head = (f"  {'run':<16}{'P N/m':>10}{'D N s/m':>10} {'σ 1/s':>19} {'ω_d rad/s':>19}"
            f"{'c′ N s/m':>11}{'k′ N/m':>11}{'cycles':>8}{'resid m':>10}")
    lines.append(head)
    for r in ident.runs:
        mark = "" if r.used else "  (set aside)"
        lines.append(
            f"  {r.file:<16}{r.P:>10.4g}{r.D:>10.4g}"
            f" {format_estimate(r.sigma, r.sigma_stderr):>19}"
            f" {format_estimate(r.omega_d, r.omega_d_stderr):>19}"
            f"{r.c_prime:>11.5g}{r.k_prime:>11.5g}"
            f"{r.cycles:>8.1f}{r.residual_rms:>10.2g}{mark}"
        )
    if ident.warnings:
        lines.append("")
        lines.append("warnings:")
        lines.extend(f"  - {w}" for w in ident.warnings)
    return "\n".join(lines)


def save_png(fig: Figure, out: OutputFolder, name: str) -> Path:
    """Render ``fig`` as PNG into ``out``/``name`` (atomic, no links followed)."""
    FigureCanvasAgg(fig)
    return out.write(name, png_writer(fig, 120))


def plot_identification(ident: Identification, out_dir: str | Path, *,
                        overwrite: bool = False) -> list[Path]:
    """Per-run record with fitted decay and residuals, and the eq. (35) lines with error bars.

    Parameters
    ----------
    ident : Identification
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    plotted = [i for i, r in enumerate(ident.runs) if r.fit is not None and i < len(ident.data)]
    names = {i: f"run-{i + 1:02d}-{Path(ident.runs[i].file).name.split('.')[0]}.png"
             for i in plotted}
    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check([*names.values(), "eq35-lines.png"])
    written: list[Path] = []
    for i in plotted:
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
        written.append(save_png(fig, out, names[i]))
    written.append(_lines_figure(ident, out, "eq35-lines.png"))
    return written


def _line_errors(ident: Identification):
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


def _lines_figure(ident: Identification, out: OutputFolder, name: str) -> Path:
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
    return save_png(fig, out, name)


def figure1(result: PaperResult, out_dir: str | Path, *,
            overwrite: bool = False) -> tuple[Path, Path]:
    """The seed paper's Figure 1(a) and 1(b) as PNG files.

    (a) c′ᵢ against 2σᵢ, (b) k′ᵢ against ω₀ᵢ²: delay-compensated points as circles with the solid
    least-squares line, uncompensated points as crosses with the dashed line.

    Parameters
    ----------
    result : PaperResult
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


def _digital_line(result: Any) -> list[str]:
    """The sampled loop's description, when the result was computed with one."""
    g = getattr(result, "digital", None)
    if g is None:
        return []
    filt = f", cut-off {g.cutoff:g} rad/s" if g.cutoff is not None else ""
    return [f"  digital loop (exact sampled model): T_s = {g.sample_time:g} s, "
            f"{g.delay_samples}-sample delay, {g.velocity} velocity{filt}"]


def friction_text(fit: Any) -> str:
    """Plain-text report of a friction fit (:class:`phoid.methods.friction.FrictionFit`)."""
    lines = ["phoid identify --friction (full-record fit through the stick–slip simulator)"]
    lines.append(f"  delay {fit.delay:g} s (given), χ²/dof {fit.chi2_red:.3g}, "
                 f"{'converged' if fit.converged else 'NOT converged'}")
    lines.extend(_digital_line(fit))
    if any(getattr(r, "bias", 0.0) for r in fit.runs):
        lines.append("  command bias b·sign(velocity) per run (the seed's DC offset), N: "
                     + ", ".join(f"{r.bias:g}" for r in fit.runs))
    lines.append("")
    for name, est in (("m", fit.m), ("c", fit.c), ("k", fit.k), ("fc", fit.fc)):
        lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {est.unit}")
    lines.append("")
    lines.append(f"  {'run':<16}{'P N/m':>10}{'D N s/m':>10}{'σ 1/s':>10}{'ω_d rad/s':>11}"
                 f"{'x0 m':>11}{'sticks at s':>13}{'resid m':>10}")
    for r in fit.runs:
        stick = f"{r.stick_time:.4g}" if r.stick_time is not None else "-"
        mark = "" if r.used else "  (set aside)"
        lines.append(f"  {r.name:<16}{r.P:>10.4g}{r.D:>10.4g}{r.sigma:>10.4g}"
                     f"{r.omega_d:>11.5g}{r.x0:>11.3g}{stick:>13}{r.residual_rms:>10.2g}{mark}")
    if fit.warnings:
        lines.append("")
        lines.append("warnings:")
        lines.extend(f"  - {w}" for w in fit.warnings)
    return "\n".join(lines)
