"""Per-run figures: one record, its fit, and what the fit leaves over.

Every run figure stacks, on one time axis: the record with the fitted model and the ±2 noise-sd
band around it; the residual (record − model) with the same band; the recorded force where the
run has one (u of a PHO run, F of a forced run); and below, on a lag axis, the residual's
autocorrelation with the ±1.96/√n band of white noise (:func:`residual_acf`). A friction run's
figure (:func:`friction_run_figure`) adds the fitted motion's velocity and shades the intervals
where the fitted mass sticks (:func:`stick_intervals`).

Results are taken by duck typing (each function names the attributes it reads); matplotlib is
imported inside the functions that draw.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "COLUMNS",
    "DPI",
    "column_envelope",
    "decimate_line",
    "display_unit",
    "forced_run_figure",
    "free_run_figure",
    "friction_run_figure",
    "pho_run_figure",
    "plain",
    "recycle",
    "residual_acf",
    "run_figure",
    "stick_intervals",
]

_ACF_MAX_LAGS = 2000  # most lags drawn (the band and the first periods are what matters)
#: run figures handed back (:func:`recycle`), by layout (kind, panel heights), and the layout
#: of each run figure made; at most _SPARES kept per layout
_SPARE: dict[tuple[str, tuple[float, ...]], list[Figure]] = {}
_LAYOUT: weakref.WeakKeyDictionary[Figure, tuple[str, tuple[float, ...]]] = \
    weakref.WeakKeyDictionary()
_SPARES = 1
#: resolution the figures are written at (dots per inch; :func:`phoid.reports.figures.save_png`)
DPI = 120
#: a per-run figure's width and its fixed margins, inches (a fixed layout: no layout engine
#: measuring every text at each save)
_WIDTH, _LEFT, _RIGHT = 8.5, 0.9, 0.2
#: pixel columns of a per-run figure's time axes: the most distinct x positions it can show
COLUMNS = int((_WIDTH - _LEFT - _RIGHT) * DPI)


def _columns_of(t: np.ndarray, columns: int,
                span: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Each sample's column (0 … columns − 1) over ``span`` (default: t's range) and the
    first index of each run of equal columns in ``t``'s order."""
    t0, t1 = (float(np.min(t)), float(np.max(t))) if span is None else span
    width = (t1 - t0) / columns if t1 > t0 else 1.0
    col = np.clip(np.floor((t - t0) / width), 0, columns - 1).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    return col, starts, t0, width


def column_envelope(t: np.ndarray, y: np.ndarray, columns: int = COLUMNS,
                    span: tuple[float, float] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The minimum, maximum and mean of ``y`` in each pixel column of a time axis.

    The axis ``span`` (default: t's range) is cut into ``columns`` equal columns; every
    sample falls in one. Drawn as a band from minimum to maximum, the envelope shows what
    every sample would (each column's extremes, so a spike or a misfit stays visible) at
    a cost of ``columns`` points, and the mean line shows a residual's systematic part that
    a solid block of noise hides.

    Parameters
    ----------
    t, y : ndarray
        Sample times (s, in increasing order) and values; NaN values are left out.
    columns : int
        Pixel columns of the axis (:data:`COLUMNS` for a per-run figure).
    span : (float, float), optional
        The axis's time range; default ``(min(t), max(t))``.

    Returns
    -------
    tc, lo, hi, mean : ndarray
        Each occupied column's centre (s), and the minimum, maximum and mean of its samples
        (NaN where all are NaN).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.size == 0:
        e = np.empty(0)
        return e, e, e, e
    col, starts, t0, width = _columns_of(t, max(int(columns), 1), span)
    ok = np.isfinite(y)
    lo = np.fmin.reduceat(np.where(ok, y, np.nan), starts)
    hi = np.fmax.reduceat(np.where(ok, y, np.nan), starts)
    cnt = np.add.reduceat(ok.astype(float), starts)
    tot = np.add.reduceat(np.where(ok, y, 0.0), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, tot / np.where(cnt > 0, cnt, 1.0), np.nan)
    return t0 + (col[starts] + 0.5) * width, lo, hi, mean


def decimate_line(t: np.ndarray, y: np.ndarray, columns: int = COLUMNS,
                  span: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The samples a line through (t, y) needs to look as it does at ``columns`` pixels.

    Keeps, in each pixel column (as :func:`column_envelope`), the first and last samples and
    the first at its minimum and maximum, in time order: the line through them spans each
    column's extremes and joins its neighbours as the full line does. Records of at most
    4 samples per column are returned whole.

    Parameters
    ----------
    t, y : ndarray
        Sample times (s, increasing) and values.
    columns : int
        Pixel columns of the axis.
    span : (float, float), optional
        The axis's time range; default ``(min(t), max(t))``.

    Returns
    -------
    (ndarray, ndarray)
        The kept samples' times and values.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    columns = max(int(columns), 1)
    if t.size <= 4 * columns:
        return t, y
    _col, starts, _t0, _w = _columns_of(t, columns, span)
    group = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, t.size]))
    yy = np.where(np.isfinite(y), y, np.nan)
    keep = np.zeros(t.size, dtype=bool)
    keep[starts] = True
    keep[np.r_[starts[1:] - 1, t.size - 1]] = True
    for red in (np.fmin, np.fmax):
        ext = red.reduceat(yy, starts)
        at = np.flatnonzero(yy == ext[group])
        _g, first = np.unique(group[at], return_index=True)
        keep[at[first]] = True
    return t[keep], y[keep]


def _fast_length(n: int) -> int:
    """The least 2ᵃ·3ᵇ·5ᶜ ≥ ``n`` (≥ 1): a length the FFT does fast."""
    best = 1 << max(int(n) - 1, 0).bit_length()
    odd = 1
    while odd < best:  # odd: each 3ᵇ·5ᶜ below the power of 2, times the least 2ᵃ reaching n
        f3 = odd
        while f3 < best:
            m = f3
            while m < n:
                m *= 2
            best = min(best, m)
            f3 *= 3
        odd *= 5
    return best


def residual_acf(r: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation ρ̂(j) = Σₜ r̃ₜ r̃ₜ₊ⱼ / Σₜ r̃ₜ², j = 0 … max_lag, r̃ = r − mean(r).

    The biased (1/n) estimator, computed by FFT; ρ̂(0) = 1. For white noise each ρ̂(j), j ≥ 1,
    is ≈ N(0, 1/n): 95 % of them lie within ±1.96/√n.
    """
    r = np.asarray(r, dtype=float)
    r = r - r.mean()
    n = r.size
    max_lag = int(min(max_lag, n - 1))
    den = float(r @ r)
    if n < 2 or den == 0.0:
        return np.ones(max(max_lag, 0) + 1)
    nfft = _fast_length(n + max_lag)  # zero padding to n + max_lag: no lag ≤ max_lag wraps
    f = np.fft.rfft(r, nfft)
    acov = np.fft.irfft(f * np.conj(f), nfft)[: max_lag + 1]
    return acov / den


def stick_intervals(t: np.ndarray, v: np.ndarray, after: float) -> list[tuple[float, float]]:
    """Intervals of t > ``after`` where the velocity ``v`` is exactly 0 (the simulator's stuck
    state) at two or more consecutive samples: [(start, end), …], s."""
    t = np.asarray(t, dtype=float)
    stuck = (np.asarray(v) == 0.0) & (t > after)
    out = []
    edges = np.flatnonzero(np.diff(np.r_[0, stuck.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a >= 2:
            out.append((float(t[a]), float(t[b - 1])))
    return out


def plain(text: str) -> str:
    """``text`` drawn as it is in a figure whose labels use mathtext: its ``$`` escaped."""
    return str(text).replace("$", r"\$")


def display_unit(x_unit: str = "m") -> tuple[float, str]:
    """The scale and unit a record in ``x_unit`` is drawn in: m as mm, rad as mrad (both
    ×1000), any other unit (a sensor's: V, counts) as it is. Every x label, band and legend
    entry of a run figure uses this one rule."""
    return {"m": (1e3, "mm"), "rad": (1e3, "mrad")}.get(str(x_unit), (1.0, str(x_unit)))


def _run_axes(fig: Figure, heights: Sequence[float]) -> list[Axes]:
    """The panels of a run figure in a fixed layout (inches; no layout engine): the time
    panels stacked on one axis, the last height the autocorrelation's on its own lag axis
    below. Sets the figure's height."""
    from matplotlib.ticker import MaxNLocator

    top, gap, acf_gap, bottom = 0.4, 0.12, 0.62, 0.5
    *timed, acf = heights
    height = top + sum(timed) + gap * (len(timed) - 1) + acf_gap + acf + bottom
    fig.set_size_inches(_WIDTH, height)
    left, right = _LEFT / _WIDTH, 1.0 - _RIGHT / _WIDTH
    axes: list[Axes] = []
    y = height - top
    for h in timed:
        y -= h
        axes.append(fig.add_axes((left, y / height, right - left, h / height),
                                 sharex=axes[0] if axes else None))
        y -= gap
    axes.append(fig.add_axes((left, bottom / height, right - left, acf / height)))
    # few ticks (each one is drawn text, and a fifth of the drawing time): 5 on the time and
    # lag axes (one locator for the time panels, which share it) and the record's y axis, 4
    # on the short panels
    for axis, nbins in ((axes[0].xaxis, 5), (axes[-1].xaxis, 5), (axes[0].yaxis, 5),
                        *((ax.yaxis, 4) for ax in axes[1:])):
        axis.set_major_locator(MaxNLocator(nbins=nbins))
    return axes


def _blank_figure(kind: str, heights: Sequence[float]) -> tuple[Figure, list[Axes]]:
    """A run figure's empty panels (:func:`_run_axes`): a figure handed back by
    :func:`recycle` with the same ``kind`` and panel heights, cleared, else a new one.

    Building the axes and their ticks is a third of the cost of a run figure; a set's run
    figures share one layout, so one figure per layout serves them all, one after another.
    """
    from matplotlib.figure import Figure

    key = (kind, tuple(float(h) for h in heights))
    spare = _SPARE.get(key)
    fig = spare.pop() if spare else None
    if fig is None:
        fig = Figure()
        axes = _run_axes(fig, heights)
    else:
        axes = list(fig.axes)
        _clear(fig, axes)
    _LAYOUT[fig] = key
    return fig, axes


def _clear(fig: Figure, axes: Sequence[Axes]) -> None:
    """Back to what :func:`_run_axes` made: every artist, legend and figure text removed, data
    limits, view limits (autoscaled) and property cycle as on new axes; the axes, their
    locators, tick settings and ticks kept."""
    from matplotlib.transforms import Bbox

    for text in list(fig.texts):
        text.remove()
    for ax in axes:
        legend = ax.get_legend()
        if legend is not None:
            legend.remove()
        for artist in [*ax.lines, *ax.patches, *ax.collections, *ax.texts, *ax.images]:
            artist.remove()
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.dataLim.set_points(Bbox.null().get_points())
        ax.ignore_existing_data_limits = True
        ax.set_prop_cycle(None)
        ax.set_xlim(0.0, 1.0, auto=True)
        ax.set_ylim(0.0, 1.0, auto=True)


def recycle(fig: Figure) -> None:
    """Hand back a run figure whose drawing is done (its PNG written): the next run figure of
    the same layout made in this process reuses its axes. The figure must not be used after;
    a figure that is not a run figure is left alone.
    """
    key = _LAYOUT.pop(fig, None)
    if key is not None:
        spare = _SPARE.setdefault(key, [])
        if len(spare) < _SPARES:
            spare.append(fig)


def _title(fig: Figure, text: str) -> None:
    """A run figure's title, placed in the fixed top margin (an axes title would be moved
    clear of the tick labels at every draw, a fifth of the drawing time)."""
    fig.text(0.5, 1.0 - 0.1 / fig.get_figheight(), text, ha="center", va="top", fontsize=10)


def _residual_panel(ax: Axes, ts: np.ndarray, resid: np.ndarray, span: tuple[float, float],
                    scale: float, color: str = "C1") -> None:
    """The residual, readable at any record length: each sample as a dot where the axis has
    room for them (at most 2 per pixel column); else each pixel column's minimum–maximum as a
    band (every spike kept) and its mean as a line (a misfit's systematic part, which a solid
    block of noise hides)."""
    if resid.size <= 2 * COLUMNS:
        ax.plot(ts, resid * scale, ".", ms=2.5, color=color, label="residual")
        return
    tc, lo, hi, mean = column_envelope(ts, resid * scale, COLUMNS, span)
    ax.fill_between(tc, lo, hi, step="mid", color=color, alpha=0.35, lw=0,
                    label="residual: min–max per pixel column")
    ax.plot(tc, mean, lw=0.8, color=color, label="mean per pixel column")


def _acf_panel(ax: Axes, t: np.ndarray, resid: np.ndarray, period: float | None) -> None:
    """The residual's autocorrelation against lag (s), with the white-noise band."""
    n = resid.size
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    want = 2.0 * period / dt if period and math.isfinite(period) and period > 0 else 500
    max_lag = int(min(n // 4, max(50, want), _ACF_MAX_LAGS))
    rho = residual_acf(resid, max(max_lag, 1))
    lags = np.arange(rho.size) * dt
    band = 1.96 / math.sqrt(max(n, 1))
    ax.axhspan(-band, band, color="0.85", lw=0, label=f"±1.96/√n (white noise, n = {n})")
    ax.plot(*decimate_line(lags[1:], rho[1:]), lw=0.8, color="C4")  # named by the y label
    ax.axhline(0, color="0.4", lw=0.5)
    ax.set_xlabel("lag (s)")
    ax.set_ylabel("residual ACF (–)")
    ax.legend(loc="upper right", fontsize=8)


def _record(ax: Axes, t: np.ndarray, y: np.ndarray, span: tuple[float, float]) -> None:
    """The record, under the fit: dots where the axis has room for each sample, else the
    line through each pixel column's extremes (:func:`decimate_line`)."""
    if t.size <= 2 * COLUMNS:
        ax.plot(t, y, ".", ms=2.5, color="0.35", label="record", zorder=2)
    else:
        ax.plot(*decimate_line(t, y, COLUMNS, span), lw=0.8, color="0.45", label="record",
                zorder=2)


def _fit_line(ax: Axes, t: np.ndarray, y: np.ndarray, label: str,
              span: tuple[float, float]) -> None:
    """A fitted model over the record: thin and half transparent, so the record shows on
    both sides of it and a misfit is seen."""
    ax.plot(*decimate_line(t, y, COLUMNS, span), lw=0.7, color="C0", alpha=0.85,
            label=label, zorder=3)


def run_figure(t: np.ndarray, x: np.ndarray, sel: np.ndarray, model: np.ndarray, *,
               noise_sd: float, title: str, model_label: str,
               markers: Sequence[tuple[float, str]] = (), force: np.ndarray | None = None,
               force_label: str = "u (N)", period: float | None = None,
               x_unit: str = "m") -> Figure:
    """One run's figure (module docstring), from plain arrays.

    Drawn for what the eye can see at :data:`DPI`: lines through each pixel column's extremes
    (:func:`decimate_line`) and the residual as its per-column envelope and mean
    (:func:`column_envelope`), in a fixed layout.

    Parameters
    ----------
    t, x : ndarray
        The whole record, s and ``x_unit``.
    sel : ndarray of bool
        The samples the model was fitted to (residual and autocorrelation over these).
    model : ndarray
        The fitted x at ``t[sel]``, ``x_unit``.
    noise_sd : float
        The fit's white-noise sd, ``x_unit`` (the band is ±2 sd; none when not finite).
    title, model_label : str
    markers : sequence of (float, str)
        Vertical lines (time s, label), e.g. the release.
    force : ndarray, optional
        A recorded force on the samples ``t`` (N): its own panel.
    force_label : str
    period : float, optional
        The oscillation period, s: the autocorrelation is drawn over two of them (at least
        50 lags, at most a quarter of the samples).
    x_unit : str
        The unit of x: drawn as :func:`display_unit` says (m as mm).
    """
    scale, unit = display_unit(x_unit)
    unit = plain(unit)  # a declared sensor unit is the manifest's text: drawn as written
    has_f = force is not None and np.shape(force) == np.shape(t)
    fig, axes = _blank_figure("run", [3.2, 1.4] + ([1.1] if has_f else []) + [1.3])
    ax, axr = axes[0], axes[1]
    span = (float(np.min(t)), float(np.max(t))) if t.size else (0.0, 1.0)
    ts, xs = t[sel], x[sel]
    resid = xs - model
    _record(ax, t, x * scale, span)
    _fit_line(ax, ts, model * scale, model_label, span)
    band = 2.0 * noise_sd if math.isfinite(noise_sd) and noise_sd > 0 else None
    if band is not None:
        axr.axhspan(-band * scale, band * scale, color="C0", alpha=0.15, lw=0,
                    label=f"±2 noise sd (sd {noise_sd * scale:.3g} {unit})")
    _residual_panel(axr, ts, resid, span, scale)
    for j, (tm, label) in enumerate(markers):
        for a in (ax, axr):
            a.axvline(tm, color=f"C{3 + j}", ls=":", lw=1, label=label if a is ax else None)
    ax.set_ylabel(f"x ({unit})")
    _title(fig, title)
    ax.legend(loc="upper right", fontsize=8)
    axr.set_ylabel(f"residual ({unit})")
    axr.legend(loc="upper right", fontsize=8, ncols=3)
    last = axr
    if has_f:
        axf = axes[2]
        axf.plot(*decimate_line(t, np.asarray(force, dtype=float), COLUMNS, span), lw=0.6,
                 color="C2")
        axf.set_ylabel(force_label)
        last = axf
    last.set_xlabel("t (s)")
    for a in axes[:-1]:
        if a is not last:
            a.tick_params(labelbottom=False)
    _acf_panel(axes[-1], ts, resid, period)
    return fig


def pho_run_figure(ident: Any, i: int) -> Figure:
    """Run ``i`` of a PHO identification: its decay fit (dominant mode and the loop's fast
    modes) over the fitted window, the noise band, residual, autocorrelation and the recorded
    u where there is one.

    Reads ``ident.runs[i]`` (``file``, ``P``, ``D``, ``sigma``, ``omega_d`` and ``fit``, a
    :class:`phoid.fits.DecayFit`: ``t_start``, ``t_end``, ``release`` (s), ``noise_sd`` (m),
    ``fast_modes``, ``model``), ``ident.data[i]`` (``(t, x)``, s and m) and ``ident.u`` (per run
    the recorded force in N on the same samples, or None; optional).
    """
    r = ident.runs[i]
    t, x = (np.asarray(a, dtype=float) for a in ident.data[i][:2])
    sel = (t >= r.fit.t_start) & (t <= r.fit.t_end)
    model = r.fit.model(t[sel], fast=True)
    u_all = getattr(ident, "u", ()) or ()
    u = u_all[i] if i < len(u_all) else None
    label = "fitted dominant mode" + (" + fast loop modes" if r.fit.fast_modes else "")
    period = 2 * math.pi / r.omega_d if r.omega_d > 0 else None
    return run_figure(
        t, x, sel, model, noise_sd=float(r.fit.noise_sd), model_label=label,
        title=(f"{plain(r.file)}: P = {r.P:g} N/m, D = {r.D:g} N s/m, σ = {r.sigma:.5g} 1/s, "
               f"$\\omega_d$ = {r.omega_d:.5g} rad/s"),
        markers=[(r.fit.release, "release")],
        force=None if u is None else np.asarray(u, dtype=float), force_label="u (N)",
        period=period)


def free_run_figure(result: Any, i: int) -> Figure:
    """Run ``i`` of a free-decay identification: the fitted free response over the analysed
    window, the noise band, residual and autocorrelation.

    Reads ``result.runs[i]`` (``file``, ``release``, ``t_start``, ``t_end`` (s), ``noise_sd``
    (m)), ``result.data[i]`` (``(t, x)``), ``result.model(i, t)`` (m) and ``sigma``,
    ``omega0``, ``zeta`` (each with ``value``: 1/s, rad/s, 1).
    """
    r = result.runs[i]
    t, x = (np.asarray(a, dtype=float) for a in result.data[i][:2])
    sel = (t >= r.t_start) & (t <= r.t_end)
    model = result.model(i, t[sel])
    w0, s = result.omega0.value, result.sigma.value
    wd2 = w0**2 - s**2
    period = 2 * math.pi / math.sqrt(wd2) if wd2 > 0 else None
    return run_figure(
        t, x, sel, model, noise_sd=float(r.noise_sd), model_label="fitted free response",
        title=(f"{plain(r.file)}: σ = {s:.5g} 1/s, ω₀ = {w0:.5g} rad/s, "
               f"ζ = {result.zeta.value:.4g}"),
        markers=[(r.release, "release")], period=period, x_unit=getattr(result, "x_unit", "m"))


def forced_run_figure(result: Any, i: int) -> Figure:
    """Run ``i`` of a forced identification: steady state + transient, the noise band,
    residual, the force F and the residual's autocorrelation.

    Reads ``result.runs[i]`` (``file``, ``t_start``, ``settle_time`` (s), ``noise_sd`` (m),
    ``model(t)`` (m), ``omega`` (rad/s), ``R`` (N/m), ``rho`` (rad)) and ``result.data[i]``
    (``(t, x, F)``, s, m and N).
    """
    r = result.runs[i]
    t, x, F = (np.asarray(a, dtype=float) for a in result.data[i][:3])
    sel = t >= r.t_start
    model = r.model(t[sel])
    markers = [(r.settle_time, "transient < noise")] if math.isfinite(r.settle_time) else []
    return run_figure(
        t, x, sel, model, noise_sd=float(getattr(r, "noise_sd", math.nan)),
        model_label="steady state + transient",
        title=f"{plain(r.file)}: ω = {r.omega:.5g} rad/s, R = {r.R:.5g} N/m, ρ = {r.rho:.4g} rad",
        markers=markers, force=F, force_label="F (N)",
        period=2 * math.pi / r.omega if r.omega > 0 else None)


def friction_run_figure(result: Any, i: int) -> Figure:
    """Run ``i`` of a friction fit: the record and the full-record simulated fit over the whole
    record, the fitted window's end, the noise band, residual, the fitted velocity, the
    residual's autocorrelation, and the intervals where the fitted mass sticks shaded (with
    the final stick time marked).

    Reads ``result.runs[i]`` (``name``, ``P``, ``D``, ``release``, ``t_end``, ``stick_time``
    (s or None), ``noise_sd`` (m), ``sigma``, ``omega_d``), ``result.data[i]`` (``(t, x)``),
    ``result.model(i, t)`` (the fitted position, m, and velocity, m/s, at times ``t``; the
    simulator's velocity is exactly 0 while stuck: :func:`stick_intervals`) and ``fc``
    (``value``, N).
    """
    r = result.runs[i]
    t, x = (np.asarray(a, dtype=float) for a in result.data[i][:2])
    xm, vm = result.model(i, t)
    sel = t <= r.t_end
    resid = x[sel] - xm[sel]
    sticks = stick_intervals(t, vm, r.release)
    fig, (ax, axr, axv, axa) = _blank_figure("friction", [3.2, 1.4, 1.1, 1.3])
    span = (float(np.min(t)), float(np.max(t))) if t.size else (0.0, 1.0)
    _record(ax, t, x * 1e3, span)
    _fit_line(ax, t, xm * 1e3, "fitted stick–slip simulation", span)
    sd = float(r.noise_sd)
    if math.isfinite(sd) and sd > 0:
        axr.axhspan(-2e3 * sd, 2e3 * sd, color="C0", alpha=0.15, lw=0,
                    label=f"±2 noise sd (sd {sd * 1e3:.3g} mm)")
    for j, (a, b) in enumerate(sticks):
        for axx in (ax, axr, axv):
            axx.axvspan(a, b, color="C2", alpha=0.18, lw=0,
                        label="fitted mass stuck" if (j == 0 and axx is ax) else None)
    for axx in (ax, axr, axv):
        axx.axvline(r.release, color="C3", ls=":", lw=1,
                    label="release" if axx is ax else None)
        axx.axvline(r.t_end, color="0.3", ls="--", lw=0.8,
                    label="end of fitted window" if axx is ax else None)
        if r.stick_time is not None:
            axx.axvline(r.stick_time, color="C2", ls="-", lw=1.2,
                        label=f"sticks for good ({r.stick_time:.4g} s)" if axx is ax else None)
    ax.set_ylabel("x (mm)")
    _title(fig, f"{plain(r.name)}: P = {r.P:g} N/m, D = {r.D:g} N s/m, $f_c$ = "
                f"{result.fc.value:.4g} N, {len(sticks)} stick interval"
                f"{'' if len(sticks) == 1 else 's'}")
    ax.legend(loc="upper right", fontsize=8)
    _residual_panel(axr, t[sel], resid, span, 1e3)
    axr.set_ylabel("residual (mm)")
    axr.legend(loc="upper right", fontsize=8, ncols=3)
    axv.plot(*decimate_line(t, vm * 1e3, COLUMNS, span), lw=0.8, color="C0")
    axv.set_ylabel("fitted v (mm/s)")
    axv.set_xlabel("t (s)")
    ax.tick_params(labelbottom=False)
    axr.tick_params(labelbottom=False)
    w = float(r.omega_d)
    _acf_panel(axa, t[sel], resid,
               2 * math.pi / w if math.isfinite(w) and w > 0 else None)
    return fig
