"""The report of a free decay fitted with Coulomb and viscous friction: its text and figures.

Results are read by duck typing (each function names what it reads); matplotlib is imported
only where a figure is drawn.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from phoid._notation import notation, unit_text
from phoid._output import OutputFolder, safe_text
from phoid.reports.figures import run_names, write_pngs
from phoid.reports.statistics import ratio_text
from phoid.reports.text import adequacy_lines, fit_statistics_lines, format_estimate, text_table

__all__ = ["free_friction_text", "plot_free_friction"]


def _est_line(name: str, est: Any) -> str:
    val = format_estimate(est.value, est.stderr) if math.isfinite(est.value) else "undefined"
    white = getattr(est, "white_stderr", None)
    tail = f"   (white-noise stderr {white:.2g})" if white is not None else ""
    # "=" aligned in ASCII
    return f"  {notation(name):<7}= {val} {unit_text(est.unit)}{tail}".rstrip()


def _opt(x: float | None, fmt: str) -> str:
    return "—" if x is None or not math.isfinite(x) else format(x, fmt)


def free_friction_text(result: Any) -> str:
    """Plain-text report of a free decay with Coulomb + viscous friction.

    Parameters
    ----------
    result : phoid.methods.free_friction.FreeFrictionIdentification or alike
        Read: ``source``; ``sigma`` (1/s), ``omega0`` (rad/s), ``zeta``, ``c_over_m`` (1/s),
        ``k_over_m`` (1/s²), ``fc_over_m`` (x's unit/s²) (each with ``value``, ``stderr``,
        ``unit`` and optionally ``white_stderr``); ``regime``; ``robust``; ``x_unit``
        (optional, default "m"); ``adequacy`` (optional); ``evidence`` (``delta_chi2``,
        ``p_value``, ``likelihood_ratio``, ``z``, ``significant``); ``m``, ``c``, ``k``,
        ``fc`` (estimates or None); ``runs`` (each with ``file``, ``n_samples``,
        ``half_cycles``, ``stop_time`` (s or None), ``stuck_position`` (x's unit or None),
        ``residual_rms``, ``used``); ``residual_noise_ratios()``,
        ``viscous_residual_noise_ratios()``, ``fit_statistics()``; ``warnings``.

    Returns
    -------
    str
    """
    head = "phoid identify --friction (free decay, Coulomb + viscous)"
    lines = [f"{head}: {safe_text(result.source)}" if result.source else head, ""]
    for name, est in (("σ", result.sigma), ("ω₀", result.omega0), ("ζ", result.zeta),
                      ("c/m", result.c_over_m), ("k/m", result.k_over_m),
                      ("f_c/m", result.fc_over_m)):
        lines.append(_est_line(name, est))
    lines.append(f"  regime: {result.regime}; stderr: "
                 + ("robust (Newey–West; an adequacy check failed)" if result.robust
                    else "white-noise least squares"))
    if result.m is not None and result.c is not None and result.k is not None \
            and result.fc is not None:
        what = "moment of inertia J" if result.m.unit == "kg m^2" else "mass m"
        lines.append(f"  with the known {what} = {result.m.value:g} {unit_text(result.m.unit)}:")
        for name, est in (("c", result.c), ("k", result.k), ("f_c", result.fc)):
            lines.append(_est_line(name, est))
    else:
        lines.append("  (a free decay gives c/m, k/m and f_c/m, not m, c, k, f_c: a known mass "
                     "(the manifest's, --mass) adds them)")
    ev = result.evidence
    lines.append(f"  friction against the viscous fit: Δχ² = {ev.delta_chi2:.4g} "
                 f"(p = {ev.p_value:.2g}), likelihood ratio {ev.likelihood_ratio:.4g}, "
                 f"f_c/m at {ev.z:.3g} stderr: "
                 + ("significant" if ev.significant else "not significant"))
    lines.append("  (static friction taken equal to kinetic: the mass sticks at a velocity "
                 "zero where |k(x − x_off)| ≤ f_c)")
    lines.append("")
    xu = safe_text(str(getattr(result, "x_unit", "m")))
    rows = []
    for r, q, qv in zip(result.runs, result.residual_noise_ratios(),
                        result.viscous_residual_noise_ratios(), strict=True):
        stop = _opt(r.stop_time, ".5g") if r.used else "—"
        if r.used and r.stop_time is None:
            stop = "never"
        rows.append([safe_text(r.file), f"{r.n_samples:d}", f"{r.half_cycles:d}", stop,
                     _opt(r.stuck_position, ".4g"), ratio_text(q), ratio_text(qv),
                     *([] if r.used else ["(set aside)"])])
    lines.extend(text_table([("run", ""), ("samples", ""), ("half-cycles", ""),
                             ("stops at", "s"), ("stuck at", xu), ("resid/noise", ""),
                             ("viscous", "resid/noise")], rows))
    lines.extend(fit_statistics_lines(result))
    lines.extend(adequacy_lines(result))
    if result.warnings:
        lines += ["", "warnings:"] + [f"  - {safe_text(w)}" for w in result.warnings]
    return "\n".join(lines)


def _run_figure(result: Any, i: int):
    from phoid.reports.runs import plain, run_figure

    r = result.runs[i]
    t, x = (np.asarray(a, dtype=float) for a in result.data[i][:2])
    sel = (t >= r.t_start) & (t <= r.t_end)
    model = result.model(i, t[sel])
    w0, s = result.omega0.value, result.sigma.value
    wd2 = w0**2 - s**2
    markers = [(r.release, "release")]
    if r.stop_time is not None:
        markers.append((r.stop_time, f"sticks ({r.stop_time:.4g} s)"))
    return run_figure(
        t, x, sel, model, noise_sd=float(r.noise_sd),
        model_label="fitted Coulomb + viscous decay",
        title=(f"{plain(r.file)}: σ = {s:.5g} 1/s, ω₀ = {w0:.5g} rad/s, $f_c/m$ = "
               f"{result.fc_over_m.value:.4g} {plain(unit_text(result.fc_over_m.unit))}, "
               f"{r.half_cycles} half-cycles"),
        markers=markers, period=2 * math.pi / math.sqrt(wd2) if wd2 > 0 else None,
        x_unit=getattr(result, "x_unit", "m"))


def plot_free_friction(result: Any, out_dir: str | Path, *,
                       overwrite: bool = False) -> list[Path]:
    """One PNG per run used: record with the fitted decay and its stop, the noise band,
    residual and its autocorrelation (:func:`phoid.reports.runs.run_figure`).

    Parameters
    ----------
    result : phoid.methods.free_friction.FreeFrictionIdentification or alike
        Read: ``runs`` (``file``, ``used``, ``release``, ``t_start``, ``t_end``,
        ``stop_time``, ``noise_sd``, ``half_cycles``), ``data``, ``model(i, t)``, ``sigma``,
        ``omega0``, ``fc_over_m``.
    out_dir : path
        Folder (created if needed).
    overwrite : bool
        Replace existing files of the same names (else they are an error; links refused).

    Returns
    -------
    list of Path
        ``<stem>.png`` per run used (:func:`phoid.reports.figures.run_names`).

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for every figure before the first is written.
    """
    names = run_names([r.file for r in result.runs])
    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check([names[i] for i in plotted])
    return write_pngs(out, [(names[i], functools.partial(_run_figure, result, i))
                            for i in plotted])
