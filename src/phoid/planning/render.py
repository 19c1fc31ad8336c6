"""The text report and the figure of a design (taken by duck typing: any object with the
attributes of :class:`phoid.planning.result.Design`). matplotlib is imported only when
plotting."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from phoid._notation import fit_width, notation, unit_text
from phoid._output import OutputFolder, png_writer
from phoid.planning.settings import UNITS, DesignError, fmt_range
from phoid.reports.text import format_gain, text_table

__all__ = ["design_report", "loop_words", "plot_design"]


def design_report(d: Any) -> str:
    """Human-readable schedule, margins and predicted uncertainties of a design ``d``."""
    st = d.settings
    sampled = st.sample_time is not None
    lines = []
    title = "Designed PHO schedule" if d.kind == "design" else "Checked PHO schedule"
    pr = ", ".join(f"{n} = {fmt_range(d.prior[n])} {UNITS[n]}" for n in "mck")
    if sampled:
        lines.append(f"{title} for {pr}")
        lines.append(loop_words(st) + "; noise "
                     + ("in the loop (the controller reads the noisy record)"
                        if st.noise_in_loop else "outside the loop"))
    else:
        lines.append(f"{title} for {pr}, delay {format_gain(st.delay)} s")
    lines.append(f"record {st.duration:g} s at {st.fs:g} Hz, noise {st.noise:g} m, "
                 f"release amplitude {st.amplitude:g} m; safety checked over "
                 + ", ".join(f"{n} {fmt_range(r)} {UNITS.get(n, '')}".rstrip()
                             for n, r in d.prior["checked_ranges"].items()))
    lines.append("")
    # a checked schedule's gains exactly as given; a design's to 6 significant digits (the
    # schedule it writes, --out, and --json hold every digit)
    gain = format_gain if d.kind != "design" else (lambda g: f"{g:.6g}")
    rows = [[str(i), gain(r.P), gain(r.D), f"{r.sigma:.4g}", f"{r.omega_d:.4g}",
             f"{r.zeta:.3f}", f"{r.cycles:.1f}", f"{r.margin:.3g}",
             f"{r.delay_margin_samples:g}" if sampled else f"{r.delay_margin:.3g}",
             f"{r.share:.3f}",
             "ok" if r.safe and r.informative else "UNSAFE" if not r.safe else "uninformative"]
            for i, r in enumerate(d.runs, start=1)]
    lines.extend(text_table([("run", ""), ("P", "N/m"), ("D", "N s/m"), ("σ", "1/s"),
                             ("ω_d", "rad/s"), ("ζ", ""), ("cycles", ""), ("margin", "1/s"),
                             ("delay margin", "samples" if sampled else "s"), ("share", ""),
                             ("status", "")], rows, indent=0))
    mode = ("the dominant mode of the sampled loop, exact, at the nominal plant" if sampled
            else "the dominant mode at the nominal plant")
    extra = (f" (stable up to delay_samples {st.delay_samples} + the margin)" if sampled
             else "")
    lines.append(f"  σ, ω_d, ζ: {mode}; margin: the smallest decay rate of the rightmost root "
                 "over the prior; delay margin: the smallest extra delay before instability "
                 f"over the prior{extra}; share: the run's share of the set's information")
    if d.kind == "design":
        lines.append("  gains to 6 significant digits; the schedule written (--out, Design.write) "
                     "and the summary (--json) hold every digit")
    if sampled:
        lines.append("")
        order = len(d.runs[0].roots) if d.runs else 0
        lines.append(f"Sampled loop modes at the nominal plant (all {order} roots of its "
                     "characteristic polynomial, rightmost first; s = ln(z)/T, 1/s):")
        for i, r in enumerate(d.runs, start=1):
            lines.append(f"  run {i}: " + _modes_text(r.roots))
    lines.append("")
    if d.bound == "in-loop":
        lines.append("Predicted standard errors (in-loop Cramér–Rao bound at the nominal plant: "
                     "the controller reads the noisy record, the plant is driven by the "
                     "command it applied; worst over the prior in brackets, the modal bound "
                     "of the runs' dominant modes after it):")
    elif sampled:
        lines.append("Predicted standard errors (Cramér–Rao bound of the sampled loop's "
                     "dominant modes, noise outside the loop, at the nominal plant; worst over "
                     "the prior in brackets):")
    else:
        lines.append("Predicted standard errors (Cramér–Rao bound at the nominal plant; worst "
                     "over the prior in brackets):")
    for j, name in enumerate(("m", "c", "k")):
        e = getattr(d, name)
        extra = f"  (modal {_g(d.modal_stderr[j])})" if d.bound == "in-loop" else ""
        lines.append(f"  {name} = {e.value:.6g} ± {_g(e.stderr)} {unit_text(e.unit)}  "
                     f"[{_g(d.stderr_worst[j])}]{extra}")
    if d.notes:
        lines.append("")
        lines.extend(f"Note: {n}" for n in d.notes)
    if d.warnings:
        lines.append("")
        lines.append("warnings:")  # as in every other report
        lines.extend(f"  - {w}" for w in d.warnings)
    return fit_width(notation("\n".join(lines)))


def loop_words(st: Any) -> str:
    """A sampled loop in words: ``"sampled loop: sample_time 0.001 s, delay_samples 1,
    backward-difference velocity"``."""
    vel = (st.velocity if st.cutoff is None
           else f"{st.velocity} (cutoff {format_gain(st.cutoff)} rad/s)")
    per = round(st.fs * st.sample_time)
    rec = "" if per == 1 else f", {per} recorded samples per period"
    return (f"sampled loop: sample_time {format_gain(st.sample_time)} s, delay_samples "
            f"{st.delay_samples}, {vel} velocity{rec}")


def _modes_text(roots: Any, shown: int = 4) -> str:
    """The first ``shown`` roots of a run (conjugate pairs as ``a ± bi``), and how many more."""
    parts: list[str] = []
    used = 0
    i = 0
    rts = list(roots)
    while i < len(rts) and len(parts) < shown:
        r = rts[i]
        if not np.isfinite(r.real):
            parts.append("-inf (z = 0)")
            i += 1
        elif r.imag > 0 and i + 1 < len(rts) and abs(rts[i + 1] - r.conjugate()) <= 1e-9 * abs(r):
            parts.append(f"{r.real:.4g} ± {r.imag:.4g}i")
            i += 2
        else:  # a real root (s real for z > 0; Im s = ±π/T for z < 0)
            real = abs(r.imag) <= 1e-9 * abs(r)
            parts.append(f"{r.real:.4g}" + ("" if real else f" {'+' if r.imag >= 0 else '-'} "
                                                            f"{abs(r.imag):.4g}i"))
            i += 1
        used = i
    rest = len(rts) - used
    return ", ".join(parts) + (f", … ({rest} more, all faster)" if rest > 0 else "")


def plot_design(d: Any, path: str | Path | None = None, *, ax: Any = None,
                overwrite: bool = False) -> Any:
    """Root locus and predicted standard errors of a design ``d`` (see
    :meth:`phoid.planning.result.Design.plot`); returns the matplotlib Figure.

    Left: each run's dominant root at every plant of the prior grid (small dots) and at the
    nominal plant (large circle), coloured by run number as the colour bar beside it says
    (discrete, one colour per run); the ζ band's edges (dashed) and the stability boundary
    Re s = 0 (red) are in the legend. Right: the predicted standard errors, relative to the
    nominal value (absolute where it is 0), at the nominal plant and the worst over the prior.
    """
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm
    from matplotlib.lines import Line2D

    if path is not None:  # refuse a file in the way before drawing
        out = OutputFolder(Path(path).parent, overwrite=overwrite, error=DesignError)
        out.check([Path(path).name])
    if ax is None:
        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.4), layout="constrained",
                                 gridspec_kw={"width_ratios": [1.6, 1]})
    else:
        axes = list(ax)
        fig = axes[0].figure
    a0, a1 = axes
    n = len(d.runs)
    cmap = matplotlib.colormaps["viridis"].resampled(max(n, 1))
    norm = BoundaryNorm(np.arange(0.5, n + 1.5), cmap.N)
    for i in range(n):
        col = cmap(norm(i + 1))
        r = d.roots[i]
        r = r[np.isfinite(r)]
        a0.plot(r.real, r.imag, ".", color=col, alpha=0.5, ms=4)
        if np.isfinite(d.roots[i, 0]):
            a0.plot(d.roots[i, 0].real, d.roots[i, 0].imag, "o", color=col, ms=6,
                    mec="k", mew=0.5)
    wmax = max([abs(x.imag) for x in d.roots.ravel() if np.isfinite(x)] or [1.0])
    for z in d.settings.zeta:
        a0.plot([0, -z * wmax * 1.1 / math.sqrt(1 - z * z)], [0, wmax * 1.1], "k--", lw=0.7)
    a0.axvline(0.0, color="r", lw=0.8)
    handles = [
        Line2D([], [], ls="", marker=".", color="0.4", ms=6, label="plants of the prior"),
        Line2D([], [], ls="", marker="o", color="0.6", mec="k", mew=0.5, ms=6,
               label="nominal plant"),
        Line2D([], [], ls="--", color="k", lw=0.7,
               label="ζ band " + "–".join(f"{z:g}" for z in d.settings.zeta)),
        Line2D([], [], color="r", lw=0.8, label="stability boundary"),
    ]
    a0.legend(handles=handles, fontsize=8, loc="lower left")
    a0.set_xlabel("Re s (1/s)")
    a0.set_ylabel("Im s (rad/s)")
    a0.set_title("dominant roots over the prior")
    sm = ScalarMappable(norm=norm, cmap=cmap)
    cb = fig.colorbar(sm, ax=a0, pad=0.02, fraction=0.05)
    cb.set_label("run")
    step = max(1, math.ceil(n / 12))
    cb.set_ticks(list(range(1, n + 1, step)))
    names = ["m", "c", "k"]
    vals = np.array([getattr(d, x).value for x in names], dtype=float)
    scale = np.where(vals != 0, np.abs(vals), 1.0)
    x = np.arange(3)
    a1.bar(x - 0.2, d.stderr / scale, 0.4, label="nominal plant")
    a1.bar(x + 0.2, d.stderr_worst / scale, 0.4, label="worst over the prior")
    a1.set_xticks(x, [f"{nm} ({'rel.' if vals[j] != 0 else UNITS[nm]})"
                      for j, nm in enumerate(names)])
    a1.set_yscale("log")
    a1.set_title("predicted standard error")
    a1.legend(fontsize=8)
    if path is not None:
        out.write(Path(path).name, png_writer(fig, 110))
    return fig


def _g(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "undetermined"
