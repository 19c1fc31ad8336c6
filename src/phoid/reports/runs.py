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
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["forced_run_figure", "free_run_figure", "friction_run_figure", "pho_run_figure",
           "residual_acf", "run_figure", "stick_intervals"]

_ACF_MAX_LAGS = 2000  # most lags drawn (the band and the first periods are what matters)


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
    nfft = 1 << (2 * n - 1).bit_length()
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
    ax.plot(lags[1:], rho[1:], lw=0.8, color="C4", label="autocorrelation of the residual")
    ax.axhline(0, color="0.4", lw=0.5)
    ax.set_xlabel("lag (s)")
    ax.set_ylabel("residual ACF")
    ax.legend(fontsize=7, loc="upper right")


def run_figure(t: np.ndarray, x: np.ndarray, sel: np.ndarray, model: np.ndarray, *,
               noise_sd: float, title: str, model_label: str,
               markers: Sequence[tuple[float, str]] = (), force: np.ndarray | None = None,
               force_label: str = "u (N)", period: float | None = None) -> Figure:
    """One run's figure (module docstring), from plain arrays.

    Parameters
    ----------
    t, x : ndarray
        The whole record, s and m.
    sel : ndarray of bool
        The samples the model was fitted to (residual and autocorrelation over these).
    model : ndarray
        The fitted x at ``t[sel]``, m.
    noise_sd : float
        The fit's white-noise sd, m (the band is ±2 sd; none when not finite).
    title, model_label : str
    markers : sequence of (float, str)
        Vertical lines (time s, label), e.g. the release.
    force : ndarray, optional
        A recorded force on the samples ``t`` (N): its own panel.
    force_label : str
    period : float, optional
        The oscillation period, s: the autocorrelation is drawn over two of them (at least
        50 lags, at most a quarter of the samples).
    """
    from matplotlib.figure import Figure

    has_f = force is not None and np.shape(force) == np.shape(t)
    heights = [3.0, 1.2] + ([1.1] if has_f else []) + [1.3]
    fig = Figure(figsize=(8.5, 2.0 + 1.45 * sum(heights) / 1.2), layout="constrained")
    gs = fig.add_gridspec(len(heights), 1, height_ratios=heights)
    ax = fig.add_subplot(gs[0])
    axr = fig.add_subplot(gs[1], sharex=ax)
    ts, xs = t[sel], x[sel]
    resid = xs - model
    ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
    ax.plot(ts, model * 1e3, lw=1.0, color="C0", label=model_label)
    band = 2.0 * noise_sd if math.isfinite(noise_sd) and noise_sd > 0 else None
    if band is not None:
        ax.fill_between(ts, (model - band) * 1e3, (model + band) * 1e3, color="C0", alpha=0.25,
                        lw=0, label=f"±2 noise sd ({noise_sd:.3g} m)")
        axr.axhspan(-band * 1e3, band * 1e3, color="C0", alpha=0.2, lw=0,
                    label="±2 noise sd")
    for j, (tm, label) in enumerate(markers):
        for a in (ax, axr):
            a.axvline(tm, color=f"C{3 + j}", ls=":", lw=1, label=label if a is ax else None)
    ax.set_ylabel("x (mm)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    axr.plot(ts, resid * 1e3, lw=0.5, color="C1")
    axr.set_ylabel("residual (mm)")
    last = axr
    if has_f:
        axf = fig.add_subplot(gs[2], sharex=ax)
        axf.plot(t, force, lw=0.6, color="C2")
        axf.set_ylabel(force_label)
        last = axf
    last.set_xlabel("t (s)")
    for a in fig.axes:
        if a is not last:
            a.tick_params(labelbottom=False)
    _acf_panel(fig.add_subplot(gs[-1]), ts, resid, period)
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
        title=(f"{r.file}: P = {r.P:g} N/m, D = {r.D:g} N s/m, σ = {r.sigma:.5g} 1/s, "
               f"ω_d = {r.omega_d:.5g} rad/s"),
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
        title=(f"{r.file}: σ = {s:.5g} 1/s, ω₀ = {w0:.5g} rad/s, "
               f"ζ = {result.zeta.value:.4g}"),
        markers=[(r.release, "release")], period=period)


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
        title=f"{r.file}: ω = {r.omega:.5g} rad/s, R = {r.R:.5g} N/m, ρ = {r.rho:.4g} rad",
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
    from matplotlib.figure import Figure

    r = result.runs[i]
    t, x = (np.asarray(a, dtype=float) for a in result.data[i][:2])
    xm, vm = result.model(i, t)
    sel = t <= r.t_end
    resid = x[sel] - xm[sel]
    sticks = stick_intervals(t, vm, r.release)
    heights = [3.0, 1.2, 1.1, 1.3]
    fig = Figure(figsize=(8.5, 9.0), layout="constrained")
    gs = fig.add_gridspec(len(heights), 1, height_ratios=heights)
    ax = fig.add_subplot(gs[0])
    axr = fig.add_subplot(gs[1], sharex=ax)
    axv = fig.add_subplot(gs[2], sharex=ax)
    ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
    ax.plot(t, xm * 1e3, lw=1.0, color="C0", label="fitted stick–slip simulation")
    sd = float(r.noise_sd)
    if math.isfinite(sd) and sd > 0:
        ax.fill_between(t[sel], (xm[sel] - 2 * sd) * 1e3, (xm[sel] + 2 * sd) * 1e3,
                        color="C0", alpha=0.25, lw=0, label=f"±2 noise sd ({sd:.3g} m)")
        axr.axhspan(-2e3 * sd, 2e3 * sd, color="C0", alpha=0.2, lw=0)
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
    ax.set_title(f"{r.name}: P = {r.P:g} N/m, D = {r.D:g} N s/m, f_c = "
                 f"{result.fc.value:.4g} N, {len(sticks)} stick interval"
                 f"{'' if len(sticks) == 1 else 's'}", fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    axr.plot(t[sel], resid * 1e3, lw=0.5, color="C1")
    axr.set_ylabel("residual (mm)")
    axv.plot(t, vm * 1e3, lw=0.8, color="C0")
    axv.set_ylabel("fitted v (mm/s)")
    axv.set_xlabel("t (s)")
    ax.tick_params(labelbottom=False)
    axr.tick_params(labelbottom=False)
    w = float(r.omega_d)
    _acf_panel(fig.add_subplot(gs[3]), t[sel], resid,
               2 * math.pi / w if math.isfinite(w) and w > 0 else None)
    return fig
