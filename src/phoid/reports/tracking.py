"""Reports of a tracking validation: the relative errors as text, and the records as a figure.

The validation is taken by duck typing (the attributes each function reads are named in its
docstring): this module never imports the method that computes it. matplotlib is imported
inside :func:`plot_tracking` only.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid._notation import fit_width, unit_text
from phoid._output import safe_text, save_figure
from phoid.reports.statistics import correlation_lines, ratio_text, statistics_lines
from phoid.reports.text import adequacy_lines, format_number, text_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["identification_text", "plot_tracking", "tracking_text", "validation_lines"]


def _validation_of(result: Any) -> Any:
    """``result.validation`` when the result carries one (a fit), else ``result`` itself."""
    inner = getattr(result, "validation", None)
    return result if inner is None else inner


def _number(value: float, fmt: str) -> str:
    if math.isnan(value):
        return "undefined"
    if math.isinf(value):
        return "inf"
    return format(value, fmt)


def validation_lines(validation: Any) -> list[str]:
    """The validation block of a report: window, velocity estimator, one line per signal.

    Parameters
    ----------
    validation : phoid.methods.tracking_validation.TrackingValidation or alike
        Read: ``t`` (s), ``window`` ((start, stop), 0-based, stop exclusive),
        ``velocity_estimator`` (str) and ``errors`` (each with ``name``, ``unit``,
        ``relative_error`` (%), ``rms`` and ``measured_rms`` in ``unit``).

    Returns
    -------
    list of str
    """
    start, stop = validation.window
    t = validation.t
    lines = [f"  simulated vs recorded, samples {start + 1}–{stop} of {len(t)} "
             f"(t = {t[start]:g} … {t[stop - 1]:g} s); relative error 100·‖y − ŷ‖/‖y‖",
             f"  measured velocity: {validation.velocity_estimator}",
             ""]
    rows = [[safe_text(e.name), _number(e.relative_error, ".4g"), _number(e.rms, ".3g"),
             _number(e.measured_rms, ".3g"), safe_text(e.unit)] for e in validation.errors]
    lines += text_table([("signal", ""), ("rel. error", "%"), ("rms residual", ""),
                         ("rms measured", ""), ("unit", "")], rows)
    return lines


def tracking_text(result: Any) -> str:
    """Plain-text report of a tracking validation (or of a result that carries one), no line
    wider than 100 columns.

    Parameters
    ----------
    result : TrackingValidation or alike, or any result with a ``validation`` attribute
        Read: what :func:`validation_lines` reads, and ``warnings`` (of the validation).

    Returns
    -------
    str
    """
    validation = _validation_of(result)
    lines = ["phoid tracking validation", *validation_lines(validation)]
    if validation.warnings:
        lines += ["", "warnings:"] + [f"  - {safe_text(w)}" for w in validation.warnings]
    return fit_width("\n".join(lines))


def plot_tracking(result: Any, path: str | Path | None = None, *,
                  overwrite: bool = False) -> Path | Figure:
    """Measured against simulated: position, tracking error, their residual, and the force.

    Panels, over time: the position x measured and simulated with the reference r (mm); the
    tracking error x − r measured and simulated (mm); the residual x − x_sim (µm), the same for
    both; and, when a force was measured, the force measured and simulated (N). The samples left
    out of the errors are shaded; each panel's title gives its relative error.

    Parameters
    ----------
    result : TrackingValidation or alike, or any result with a ``validation`` attribute
        Read: ``t`` (s), ``x``, ``x_sim``, ``r`` (m), ``force`` (N, or None), ``force_sim`` (N),
        ``window`` and ``errors`` (each with ``name`` and ``relative_error``, %).
    path : str, Path or None
        The PNG file to write (its folder is created when missing); None: write nothing and
        return the figure.
    overwrite : bool
        Replace an existing file (otherwise it is an error; links are refused either way: see
        :mod:`phoid._output`).

    Returns
    -------
    Path or matplotlib.figure.Figure
        ``path`` as written, or the figure when ``path`` is None.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way (without ``overwrite``), or a link.
    """
    from matplotlib.figure import Figure

    from phoid.reports.runs import decimate_line

    def _thin(tt: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # what the figure's ~1000 pixel columns can show: each column's extremes
        return decimate_line(tt, np.asarray(y, dtype=float), 1000)

    val = _validation_of(result)
    t = np.asarray(val.t)
    rel = {e.name: e.relative_error for e in val.errors}
    has_force = val.force is not None
    rows = 4 if has_force else 3
    fig = Figure(figsize=(9, 2.2 * rows + 0.6), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True)
    ax_x, ax_e, ax_res = axes[:3]

    def title(ax: Any, text: str, name: str) -> None:
        value = rel.get(name, math.nan)
        ax.set_title(f"{text}: relative error {_number(value, '.4g')} %", fontsize=9)

    ax_x.plot(*_thin(t, val.r * 1e3), lw=0.6, color="0.6", label="reference r")
    ax_x.plot(*_thin(t, val.x * 1e3), lw=0.9, color="C0", label="measured x")
    ax_x.plot(*_thin(t, val.x_sim * 1e3), lw=0.8, ls="--", color="C1", label="simulated x")
    ax_x.set_ylabel("x (mm)")
    title(ax_x, "position", "position")
    ax_e.plot(*_thin(t, (val.x - val.r) * 1e3), lw=0.7, color="C0", label="measured")
    ax_e.plot(*_thin(t, (val.x_sim - val.r) * 1e3), lw=0.7, ls="--", color="C1", label="simulated")
    ax_e.set_ylabel("x − r (mm)")
    title(ax_e, "tracking error", "tracking error")
    ax_res.plot(*_thin(t, (val.x - val.x_sim) * 1e6), lw=0.6, color="C3")
    ax_res.axhline(0.0, color="0.7", lw=0.5)
    ax_res.set_ylabel("x − x_sim (µm)")
    ax_res.set_title("residual, measured − simulated (position and tracking error alike)",
                     fontsize=9)
    if has_force:
        ax_f = axes[3]
        ax_f.plot(*_thin(t, val.force), lw=0.7, color="C0", label="measured")
        ax_f.plot(*_thin(t, val.force_sim), lw=0.7, ls="--", color="C1", label="simulated")
        ax_f.set_ylabel("F (N)")
        title(ax_f, "force", "force")
    start, stop = val.window
    for ax in axes:
        if start > 0:
            ax.axvspan(t[0], t[start], color="0.9", lw=0)
        if stop < len(t):
            ax.axvspan(t[stop - 1], t[-1], color="0.9", lw=0)
        if ax is not ax_res:
            ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t (s)")
    if path is None:
        return fig
    return save_figure(fig, path, overwrite=overwrite)


def identification_text(result: Any) -> str:
    """Plain-text report of a tracking set's identification and validation.

    Parameters
    ----------
    result : phoid.methods.tracking_identification.TrackingIdentification or alike
        Read: ``estimator``, ``estimates`` (name → value, stderr, unit), ``delay_source``,
        ``fit.summary()`` (the estimator's statistics), ``run_names``, ``validations`` (each read
        as by :func:`validation_lines`), ``warnings``, ``path``, ``residual_noise_ratios()``
        (one per run), ``fit_statistics()`` (``"statistics"`` and ``"correlation"`` as in
        :mod:`phoid.reports.statistics`) and ``adequacy`` (the ``[[Adequacy]]`` block of
        :func:`phoid.reports.text.adequacy_lines`).

    Returns
    -------
    str
    """
    labels = {"m": "mass m", "c": "viscous c (Fv)", "k": "stiffness k", "fc": "Coulomb fc (Fc)",
              "offset": "offset force (OF)", "delay": "command delay"}
    title = {"idim": "inverse dynamics least squares (IDIM-LS)",
             "output-error": "output error through the simulated loop"}
    fit = result.fit.summary()
    lines = [f"phoid tracking identification: {safe_text(result.path)}",
             f"  estimator: {title.get(result.estimator, result.estimator)}", ""]
    for key, est in result.estimates.items():
        value, se, unit = est.value, est.stderr, est.unit
        if key == "delay":
            value, se, unit = value * 1e3, None if se is None else se * 1e3, "ms"
        spread, note = (f" ± {se:.4g}", "") if se else ("", "")
        if se is None:
            note = "  (no ±: see the warnings)"
        elif se == 0.0:
            note = ("  (assumed)" if result.delay_source == "assumed-zero" else "  (given)") \
                if key == "delay" else "  (fixed)"
        white = getattr(est, "white_stderr", None)
        if white is not None and se:
            # a robust stderr reported: the white-noise least-squares one beside it
            white = white * 1e3 if key == "delay" else white
            note = f"  (white-noise ± {white:.4g})"
        lines.append(f"  {labels.get(key, key):<20}{value:>12.7g}{spread} {unit_text(unit)}{note}")
    if "delay" not in result.estimates or result.delay_source not in ("given", "assumed-zero"):
        lines.append(f"  command delay: {result.delay_source}")  # (given)/(assumed) said above
    lines.append("")
    if result.estimator == "idim":
        rel = format_number(fit["relative_error_percent"])
        lines.append(f"  force relative error {rel} %, condition "
                     f"number {fit['condition_number']:.4g}, residual lag-1 autocorrelation "
                     f"{fit['lag1_autocorrelation']:.3f}, {fit['n_samples']} rows")
    else:
        white = ", ".join(f"{k} {v:.3g}" for k, v in fit["white_noise_stderr"].items())
        rel = format_number(fit["relative_error_percent"])
        lines.append(f"  tracking-error relative error {rel} %, "
                     f"rms residual {fit['rms_residual']:.3g} m, residual lag-1 "
                     f"autocorrelation {fit['lag1_autocorrelation']:.4f}")
        lines.append(f"  stderrs: Newey–West, lag window {fit['hac_bandwidth']} samples; the "
                     f"white-noise ones (invalid here) would be {white}")
        free = fit["free"]
        if "delay" in free and "m" in free:
            c = fit["correlation"][free.index("m")][free.index("delay")]
            lines.append(f"  corr(m, delay) = {c:.4f}")
    blocks = result.fit_statistics()
    lines += ["", *statistics_lines(blocks["statistics"]),
              *correlation_lines(blocks["correlation"])]
    for name, v, q in zip(result.run_names, result.validations, result.residual_noise_ratios(),
                          strict=True):
        lines += ["", f"validation, {safe_text(name)}:", *validation_lines(v),
                  f"  position residual / noise (noise from the record's third differences): "
                  f"{ratio_text(q)}"]
    lines += adequacy_lines(result)
    if result.warnings:
        lines += ["", "warnings:"] + [f"  - {safe_text(w)}" for w in result.warnings]
    return "\n".join(lines)
