"""The release time of each run, refitted with the rough loop's own response from rest.

The PHO pipeline's second pass fits each decay from the release on, so the release must be
placed to a fraction of a sample: :func:`model_releases` fits x = a + b·g(t − τ) near the
data-only release, g being the rough plant's loop response released from rest.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid.fits import uniform_step

__all__ = ["REL_HALF", "interp_uniform", "model_releases", "release_fit"]

REL_HALF = 32  # model-fitted release: samples searched either side of the detected one


def model_releases(data: Sequence[tuple[np.ndarray, np.ndarray]], fits: Sequence[Any],
                   rough: tuple[float, float, float], P: np.ndarray, D: np.ndarray,
                   delay: float, dm: np.ndarray | None = None, digital: Any = None
                   ) -> list[float | None]:
    """Release times fitted with each loop's own response from rest (None where not done).

    The data-only detection (:func:`phoid.fits.detect_release`: a quadratic, then an even
    quartic departure from the held level) is off by a few samples — and, for stiff loops on
    heavily damped plants, whose departure from rest is not of that shape (strong damping; the
    delayed feedback changes it after Δt), sometimes by many samples, early. The second pass
    fits from the release on, so an early release puts held samples into the window, which the
    decay model cannot fit: σ comes out several stderr off and the weighted fit reports runs
    that disagree (docs/design-notes/pho.md, "model-fitted release").

    Here the record near the release is fitted by x = a + b·g(t − τ), with g the exact response
    of the rough plant's loop released from rest at 1 (g = 1 before the release; one batched
    simulation per sample rate, :func:`phoid.simulation.release_response`). Where the span is
    sampled uniformly (to the rounding of its times), t − τ is a whole number of sample
    intervals, so g is simulated at the data's own rate (the same g, to simulate's rounding of
    ~1e−12, as on a finer grid) and is one vector per run for all its candidates; otherwise
    (or where the data's rate is below simulate's rule for the loop) on a grid 4 times finer,
    linearly interpolated (error ~1e−5 of the release displacement at most), each candidate
    with its own t − τ. a and b are free, τ on the sample times within ±32 samples of the
    detected release (every 4th, then around the best), refined by a parabola through the
    three best (:func:`release_fit`). The span runs from 64 samples before the detected release
    to a quarter period of the dominant mode (at most 512 samples) after the latest candidate:
    there the response is the sharpest function of τ, and the rough plant's error is far below
    the noise. Only which samples fall after τ matters downstream, so sub-sample accuracy is
    enough.

    A digital loop gets the response of its sampled controller instead, on a grid of a whole
    number of steps per controller sample (at least 4 per data sample), its clock started at
    the release.

    Parameters
    ----------
    data : sequence of (t, x)
        Each run's time (s) and position (m) arrays, float.
    fits : sequence of DecayFit-like or None
        Each run's first look (``release``, s, and ``omega_d``, rad/s, are used); None: skipped.
    rough : (float, float, float)
        The rough plant's m (kg), c (N·s/m), k (N/m).
    P, D : ndarray
        Each run's gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    dm : ndarray, optional
        Each run's added mass, kg (None: none).
    digital : phoid.dynamics.digital.DigitalPD, optional
        The sampled loop (its gains ignored); None: a continuous loop with ``delay``.

    Returns
    -------
    list of float or None
        Each run's release time, s; None for a run without a held segment, a rough plant that
        is not physical, or a τ on the edge of the search (the detected release is used then).
    """
    from phoid.dynamics.plant import Plant
    from phoid.simulation import release_response, simulate

    out: list[float | None] = [None] * len(data)
    m, c, k = rough
    if not m > 0:
        return out
    half = REL_HALF
    jobs: dict[float, list[tuple[int, int, int, int]]] = {}
    uniform = True
    for i, f in enumerate(fits):
        if f is None or not 0 < f.omega_d < math.inf:
            continue
        t = data[i][0]
        j0 = int(np.searchsorted(t, f.release, side="left"))
        if j0 < half or j0 + half >= t.size:
            continue
        dt = float(t[j0 + 1] - t[j0])
        # every candidate τ has ≥ 32 held samples before it and a quarter period after it
        t_end = t[j0 + half] + min(0.5 * math.pi / f.omega_d, 512 * dt)
        hi = int(np.searchsorted(t, t_end, side="right"))
        if hi < j0 + half + 4:
            continue
        key = (float(f"{dt:.12g}"), 0.0 if dm is None else float(dm[i]))
        lo = max(j0 - 2 * half, 0)
        jobs.setdefault(key, []).append((i, lo, hi, j0))
        # uniform sampling over the span (the decay fit's test: every time within 1e−9 of a
        # step of the grid, or the rounding of the times; g then errs by ≲ 1e−9 of its jump)
        tr = np.asarray(t[lo:hi], dtype=float)
        uniform &= uniform_step(tr - tr[0], float(tr[0])) is not None
    # each simulated run: (run, span start, span end, detected release), grid rate, response
    runs: list[tuple[tuple[int, int, int, int], float, np.ndarray]] = []
    for (dt, added), items in jobs.items():
        plant = Plant(m + added, max(c, 0.0), max(k, 0.0))
        idx = [it[0] for it in items]
        span = max(float(data[i][0][hi - 1] - data[i][0][j0 - half]) for i, _, hi, j0 in items)
        if digital is None:
            # uniform sampling needs g at whole sample intervals only: simulated at the data's
            # rate (the same g to 1e−11 as on a finer grid), else (or where that rate is below
            # simulate's rule for the loop) on a grid 4 times finer, interpolated
            rates = (1.0 / dt, 4.0 / dt) if uniform else (4.0 / dt,)
        else:
            ts = digital.sample_time
            opts = {"sample_time": ts, "delay_samples": digital.delay_samples,
                    "velocity": digital.velocity, "cutoff": digital.cutoff}
            rates = (max(1, math.ceil(4.0 * ts / dt - 1e-9)) / ts,)  # whole steps per sample
        x = None
        for fs in rates:
            try:
                if digital is None:
                    x = release_response(plant, P[idx], D[idx], delay=delay,
                                          duration=span + 2 * dt, fs=fs)
                else:
                    x = simulate(plant, P[idx], D[idx], duration=span + 2 * dt, fs=fs, x0=1.0,
                                 **opts).x_true
                break
            except ValueError:
                continue
        if x is None:
            continue
        for row, it in enumerate(items):
            runs.append((it, fs, x[row]))
    if not runs:
        return out
    n, nc = len(runs), 2 * half + 1
    # the responses, padded to the longest by their last value (what np.interp holds beyond)
    ng = max(g.size for _, _, g in runs)
    resp = np.empty((n, ng))
    rate = np.array([fs for _, fs, _ in runs])
    size = np.array([hi - lo for (_, lo, hi, _), _, _ in runs])
    first = np.array([j0 - half - lo for (_, lo, _, j0), _, _ in runs])  # candidate 0's sample
    after = int(np.max(size - 1 - first))  # samples after candidate 0, at most
    # every span's record minus its mean over the span, zero-padded so that any candidate's
    # `after` following samples can be taken
    xc = np.zeros((n, int(np.max(first)) + nc + after))
    tt = np.empty_like(xc)  # the sample times, padded by repeating the last
    xx2 = np.empty(n)
    cand = np.empty((n, nc))
    for row, ((i, lo, hi, j0), _, g) in enumerate(runs):
        t, x = data[i]
        tr = np.asarray(t[lo:hi], dtype=float)
        xr = np.asarray(x[lo:hi], dtype=float)
        xr = xr - xr.mean()
        resp[row, : g.size], resp[row, g.size :] = g, g[-1]
        tt[row, : tr.size], tt[row, tr.size :] = tr, tr[-1]
        xc[row, : tr.size] = xr
        xx2[row] = float(xr @ xr)
        cand[row] = np.asarray(t[j0 - half : j0 + half + 1], dtype=float)
    lag = np.arange(after + 1)
    if uniform:  # t − τ is a whole number of sample intervals: one g per run
        dts = (tt[np.arange(n), size - 1] - tt[:, 0]) / (size - 1)  # sample intervals, s
        h = interp_uniform(dts[:, None] * lag, rate, resp) - 1.0
    else:  # every candidate's own t − τ
        pos = np.minimum(first[:, None, None] + np.arange(nc)[:, None] + lag, xc.shape[1] - 1)
        off = np.take_along_axis(tt, pos.reshape(n, -1), axis=1).reshape(pos.shape)
        h = interp_uniform(off - cand[:, :, None], rate, resp) - 1.0
    taus = release_fit(xc, xx2, size, first, cand, h)
    for ((i, _lo, _hi, _j0), _, _), tau in zip(runs, taus, strict=True):
        out[i] = tau
    return out


def interp_uniform(x: np.ndarray, rate: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Linear interpolation on uniform grids from 0, as ``np.interp`` (held beyond either end).

    Parameters
    ----------
    x : ndarray, shape (n, ...)
        Finite points, s; row r on grid r.
    rate : ndarray, shape (n,)
        Each grid's rate, Hz: its nodes are at i/rate, i = 0 … ng − 1.
    fp : ndarray, shape (n, ng)
        The values at the nodes (ng ≥ 2).

    Returns
    -------
    ndarray, shape of ``x``
        fp interpolated at x: fp[:, 0] before 0, fp[:, −1] beyond the last node.
    """
    n, ng = fp.shape
    u = np.clip(x * rate.reshape((n,) + (1,) * (x.ndim - 1)), 0.0, ng - 1.0)
    i = np.minimum(u.astype(np.intp), ng - 2)  # u ≥ 0: the cast is the floor
    u -= i
    i = i.reshape(n, -1)
    lo = np.take_along_axis(fp, i, axis=1).reshape(x.shape)
    hi = np.take_along_axis(fp, i + 1, axis=1).reshape(x.shape)
    return lo + u * (hi - lo)


def release_fit(xc: np.ndarray, xx2: np.ndarray, size: np.ndarray, first: np.ndarray,
                cand: np.ndarray, h: np.ndarray) -> list[float | None]:
    """Release time of each run: the τ minimising Σ(x − a − b·g(t − τ))² over its candidate
    times (every 4th, then the neighbours of the best), parabola-refined.

    With H = g(t − τ) − 1, zero up to τ, the centred sums need only the samples after τ:
    Σ(G − Ḡ)² = ΣH² − (ΣH)²/N and Σ(G − Ḡ)x_c = ΣH·x_c − ΣH·Σx_c/N over the span's N samples.
    The candidates of all the runs are evaluated at once, on arrays padded to the longest span
    (the padding kept out of every sum). When the sampling is uniform, H of the m-th sample
    after τ is the same function of m for every candidate (``h`` of shape (n, l)), and ΣH, ΣH²
    are cumulative sums of it.

    Parameters
    ----------
    xc : ndarray, shape (n, w)
        The record over each run's span minus its mean over the span, m, zero beyond the span
        (w ≥ max(first) + c + l − 1).
    xx2 : ndarray, shape (n,)
        Σ xc² of each run, m².
    size : ndarray of int, shape (n,)
        The number of samples in each span.
    first : ndarray of int, shape (n,)
        The sample of the span at candidate 0 (candidate j at sample first + j).
    cand : ndarray, shape (n, c)
        Each run's candidate release times, s (sample times around the detected release).
    h : ndarray, shape (n, l) or (n, c, l)
        g − 1 at the m-th sample after the candidate, m = 0 … l − 1, of each run (uniform
        sampling) or of each run's every candidate; g is the loop response from rest at 1.

    Returns
    -------
    list of float or None
        Each run's release time, s; None where a coarse candidate's fit is undefined or the
        best candidate is on the edge of the search.
    """
    n, c = cand.shape
    rows = np.arange(n)[:, None]
    lag = np.arange(1, h.shape[-1])
    sse = np.full((n, c), np.inf)
    xs = xc.sum(axis=1)[:, None]  # Σx_c: zero to rounding
    win = np.lib.stride_tricks.sliding_window_view(xc, lag.size, axis=1)
    if h.ndim == 2:
        cum = np.zeros((n, h.shape[1], 2))
        np.cumsum(np.stack([h, h * h], axis=2)[:, 1:], axis=1, out=cum[:, 1:])

    def evaluate(idx):
        # sse of the candidates idx (n, k) of every run
        pos = first[:, None] + idx  # (n, k)
        count = size[:, None] - 1 - pos  # samples after each candidate
        X = win[rows, pos + 1]  # (n, k, l − 1): the samples after each, zero beyond the span
        if h.ndim == 2:
            sh = np.take_along_axis(cum[:, :, 0], count, axis=1)
            shh = np.take_along_axis(cum[:, :, 1], count, axis=1)
            shx = np.matmul(X, h[:, 1:, None])[:, :, 0]
        else:
            H = np.where(lag <= count[:, :, None], h[rows, idx, 1:], 0.0)
            sh = H.sum(axis=2)
            shh = np.einsum("rkm,rkm->rk", H, H)
            shx = np.einsum("rkm,rkm->rk", H, X)
        gg = shh - sh * sh / size[:, None]
        gx = shx - sh * xs / size[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            sse[rows, idx] = np.where(gg > 0, xx2[:, None] - gx * gx / gg, np.nan)

    evaluate(np.broadcast_to(np.arange(0, c, 4), (n, len(range(0, c, 4)))))
    coarse_ok = np.all(np.isfinite(sse[:, ::4]), axis=1)
    best = 4 * np.argmin(np.where(coarse_ok[:, None], sse[:, ::4], 0.0), axis=1)
    evaluate(np.clip(best[:, None] + np.arange(-3, 4), 0, c - 1))  # (repeats at the edges)
    i = np.argmin(sse, axis=1)
    j = np.clip(i, 1, c - 2)[:, None] + np.arange(-1, 2)
    y0, y1, y2 = np.take_along_axis(sse, j, axis=1).T
    ok = coarse_ok & (i > 0) & (i < c - 1) & np.isfinite(y0) & np.isfinite(y1) & np.isfinite(y2)
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(den > 0, np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5), 0.0)
    t0, t1, t2 = np.take_along_axis(cand, j, axis=1).T
    tau = t1 + shift * np.where(shift > 0, t2 - t1, t1 - t0)
    return [float(x) if good else None for x, good in zip(tau.tolist(), ok.tolist(), strict=True)]
