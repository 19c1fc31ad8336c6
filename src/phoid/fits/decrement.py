"""The seed paper's logarithmic decrement, done carefully: σ and ω_d from all the extrema above
the noise floor (interpolated, weighted regression, honest covariance), for reproduction and
comparison with :func:`phoid.fits.modal.fit_decay` (far less efficient).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from phoid._threads import single_blas_thread
from phoid.fits._stack import make_stack
from phoid.fits.release import check_record, diff_noise, window
from phoid.fits.result import (
    MIN_CYCLES,
    DecayFit,
    common_warnings,
    count_cycles,
    phase_amp,
    unfitted,
)
from phoid.fits.start import dominant_period, uniform_grid

__all__ = ["logdec"]

#: extrema whose amplitude is below this many noise sds end the peak sequence
_LOGDEC_FLOOR_NSD = 5.0


def _local_vertex(tt, xx, tc, h, noise):
    """Vertex of a weighted quadratic least-squares fit over |t − tc| < h.

    Biweight weights (1 − (u/h)²)² let samples enter and leave the window smoothly, so the
    vertex does not jump with the sampling phase. Returns (time, value, var_time, var_value,
    curvature) with the variances per unit noise variance and the value corrected for the
    first-order noise bias of p₀ − p₁²/(4p₂); None if the window is unusable."""
    i0 = int(np.searchsorted(tt, tc - h, side="right"))
    i1 = int(np.searchsorted(tt, tc + h, side="left"))
    if i1 - i0 < 3:
        return None
    u = (tt[i0:i1] - tc) / h
    y = xx[i0:i1]
    w = (1.0 - u * u) ** 2
    X = np.stack([np.ones_like(u), u, u * u], axis=1)
    Xw = X * w[:, None]
    try:
        Ai = np.linalg.inv(X.T @ Xw)
    except np.linalg.LinAlgError:
        return None
    p0, p1, p2 = Ai @ (Xw.T @ y)
    if not p2 != 0:
        return None
    cov = Ai @ (Xw.T @ Xw) @ Ai  # per unit noise variance
    tv = -p1 / (2 * p2)
    val = p0 - p1 * p1 / (4 * p2) + noise * noise * cov[1, 1] / (4 * p2)
    gt = np.array([0.0, -1 / (2 * p2), p1 / (2 * p2 * p2)]) * h
    gv = np.array([1.0, -p1 / (2 * p2), p1 * p1 / (4 * p2 * p2)])
    return tc + tv * h, val, float(gt @ cov @ gt), float(gv @ cov @ gv), p2


def _extrema(tw, xw, offset, noise, per_t):
    """Lobes of the record about ``offset``: (sign, index of the extreme sample) for each run
    of the smoothed signal beyond a ±3-noise-sd hysteresis band (so noise cannot split one)."""
    n = tw.size
    dt = (tw[-1] - tw[0]) / (n - 1)
    w = max(1, round(per_t / dt / 12))
    y = xw - offset
    if w > 1:
        c = np.concatenate([[0.0], np.cumsum(y)])
        lo = np.clip(np.arange(n) - w // 2, 0, n)
        hi = np.clip(np.arange(n) + w - w // 2, 0, n)
        ys = (c[hi] - c[lo]) / (hi - lo)
    else:
        ys = y
    band = 3.0 * noise / math.sqrt(w)
    state = np.where(ys > band, 1, np.where(ys < -band, -1, 0))
    nz = np.flatnonzero(state)
    if nz.size == 0:
        return []
    # forward-fill the state, lobes are runs of equal state
    idx = np.maximum.accumulate(np.where(state != 0, np.arange(n), 0))
    st = state[idx]
    st[: nz[0]] = 0
    edges = np.flatnonzero(np.diff(st) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [n]])
    lobes = []
    for a, b in zip(starts, ends, strict=True):
        sgn = st[a]
        if sgn == 0:
            continue
        k = a + int(np.argmax(sgn * ys[a:b]))
        lobes.append((sgn, k))
    return lobes


@single_blas_thread
def logdec(t: ArrayLike, x: ArrayLike, *, release: float | None = None,
           skip: float = 0.0) -> DecayFit:
    """σ and ω_d by the logarithmic decrement of all the extrema above the noise floor.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing.
    x : array_like, shape (n,)
        Position, m.
    release : float, optional
        Release time, s. Default: :func:`detect_release`.
    skip : float, default 0
        Time after the release left out, s (≥ 0).

    Returns
    -------
    DecayFit
        ``method == "logdec"``. ``amplitude``, ``phase`` and ``offset`` are the linear least
        squares over the window at the logdec's (σ, ω_d). When fewer than three extrema are
        found, σ and ω_d are NaN and ``warnings`` says why.

    Raises
    ------
    ValueError
        For unusable input, as :func:`fit_decay`.

    Notes
    -----
    For x = x_off + A e^{−σt} sin(ω_d t − φ₀) (eq. 15) the extrema fall exactly π/ω_d apart
    and alternate in sign about x_off, so the difference of successive extremum values
    d_k = |v_k − v_{k+1}| = C e^{−σ k π/ω_d} holds no offset: the log decrement per half cycle
    δ = σπ/ω_d is minus the slope of ln d_k against k — exact, whatever the offset.

    Each extremum's time and value come from a quadratic least-squares fit over ±1/8 period
    about it with biweight weights (samples enter the window smoothly, so the result does not
    jump with the sampling phase), re-centred once on its vertex, the value corrected for the
    first-order noise bias of a vertex. The peak shape is the same for every extremum up to
    scale, so the small bias of the quadratic cancels in the decrement. The sequence ends where
    the decrement line fitted to the extrema crosses 5 noise sds (not at the first noisy
    extremum below it, which would select high values and bias σ down).
    π/ω_d is the weighted slope of the extremum times against k (weights from each local fit),
    δ the generalised least-squares slope of ln d_k against k with the covariance of the d_k
    (successive differences share an extremum) propagated from the local fits; σ = δω_d/π.
    Variances are scaled by the noise variance (held segment, else second differences), and by
    a regression's reduced χ² when that is significantly above 1 (misfit widens them).
    Its accuracy and efficiency against :func:`phoid.fits.modal.fit_decay`:
    docs/design-notes/fits.md, "logdec".

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(15000) / 1000
    >>> dec = logdec(t, -3e-4 + 0.01 * np.exp(-0.5 * t) * np.cos(6.2 * t), release=0.0)
    >>> print(f"{dec.sigma:.6f} {dec.omega_d:.6f}")
    0.500000 6.200000
    """
    t, x = check_record(t, x)
    release, hold_sd, tw, xw, _ptp = window(t, x, release, skip, None)
    t_ref = float(tw[0])
    noise = hold_sd if hold_sd else diff_noise(xw)
    noise = max(noise, 1e-15 * float(np.ptp(xw)))
    warnings: list[str] = []

    xg, dt, udt = uniform_grid(tw - t_ref, xw)
    per_t = dominant_period(xg) * dt
    st = make_stack([tw - t_ref], [xw], udt)
    one = np.arange(1)

    def at(sig: float, om: float) -> dict | None:
        """The linear part solved at (σ, ω_d), None where it cannot be evaluated."""
        q = st.evaluate(one, np.array([sig]), np.array([om]))
        return q if q["ok"][0] else None

    # lobes are split about the record's median first; if the offset from the first pass's mode
    # differs by more than half a noise sd, or its period from the FFT's by 10 %, once more
    offset = float(np.median(xw))
    ext = _logdec_extrema(tw, xw, offset, noise, per_t)
    if ext is not None:
        pt = at(ext["sigma"], ext["omega"])
        per2 = 2 * math.pi / ext["omega"]
        if pt is not None and (
            abs(pt["beta"][0, 0] - offset) > 0.5 * noise or abs(per2 - per_t) > 0.1 * per_t
        ):
            offset = float(pt["beta"][0, 0])
            ext = _logdec_extrema(tw, xw, offset, noise, per2) or ext
    if ext is None:
        warnings.append(
            "no oscillation: fewer than three extrema above the noise floor; the logarithmic "
            "decrement is undefined"
        )
        return unfitted("logdec", tw, release, noise, offset, warnings)
    sig, om = ext["sigma"], ext["omega"]
    pt = at(sig, om)
    if pt is None:  # the decrement's mode overflows over the window (violent growth)
        warnings.append("the mode of the decrement cannot be evaluated over the window")
        return unfitted("logdec", tw, release, noise, offset, warnings, sig, om, ext["cov"])
    r = st.residual(one, pt)[0][0]
    rss = float(r @ r)
    off, a, b = (float(c) for c in pt["beta"][0])
    amp, phase = phase_amp(a, b)
    n = xw.size
    fit = DecayFit(
        sigma=sig,
        omega_d=om,
        cov=ext["cov"],
        amplitude=amp,
        phase=phase,
        offset=off,
        t_ref=t_ref,
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=float(release),
        n_samples=int(n),
        cycles=0.0,
        noise_sd=math.sqrt(rss / (n - 5)),
        residual_rms=math.sqrt(rss / n),
        method="logdec",
    )
    cycles = count_cycles(amp, sig, om, float(tw[-1] - tw[0]), noise)
    warnings += common_warnings(fit.sigma, fit.sigma_stderr, cycles, xw, xw - fit.model(tw),
                                 noise)
    if ext["n_extrema"] < 2 * MIN_CYCLES:
        warnings.append(
            f"few extrema: only {ext['n_extrema']} extrema above the noise floor were used"
        )
    return replace(fit, cycles=cycles, warnings=tuple(warnings))


def _inflation(chi2_red: float, dof: int) -> float:
    """Variance factor for a regression: its reduced χ² when that is significantly above 1
    (beyond 3 sds of a χ²/dof with ``dof`` degrees of freedom: misfit), else 1."""
    if dof < 1:
        return 1.0
    return chi2_red if chi2_red > 1.0 + 3.0 * math.sqrt(2.0 / dof) else 1.0


def _logdec_extrema(tw, xw, offset, noise, per_t):
    """Extrema → (σ, ω_d, cov) by the two regressions of :func:`logdec`; None if < 3 extrema."""
    lobes = _extrema(tw, xw, offset, noise, per_t)
    dtmax = float(np.max(np.diff(tw)))
    h = max(per_t / 8.0, 2.5 * dtmax)
    out = []
    for sgn, k in lobes:
        tc = tw[k]
        if tc - h < tw[0] or tc + h > tw[-1]:
            continue
        r = _local_vertex(tw, xw, tc, h, noise)
        if r is None or not abs(r[0] - tc) < h:
            continue
        if tw[0] <= r[0] - h and r[0] + h <= tw[-1]:
            r2 = _local_vertex(tw, xw, r[0], h, noise)
            if r2 is not None and abs(r2[0] - r[0]) < h:
                r = r2
        # a maximum must be concave, a minimum convex
        if np.sign(-r[4]) != sgn:
            continue
        out.append((sgn, *r[:4]))
    if len(out) < 3:
        return None
    sg = np.array([o[0] for o in out], dtype=float)
    tk = np.array([o[1] for o in out])
    vk = np.array([o[2] for o in out])
    vt = np.array([o[3] for o in out])
    vv = np.array([o[4] for o in out])
    # usable pairs: the leading run of alternating extrema with positive differences. The run
    # ends at the first pair whose half-difference is below the floor — then, so that the end
    # does not depend on the noise of the last extrema (selecting them for being high would bias
    # σ down), it is moved to where the fitted decrement line crosses the floor.
    d = sg[:-1] * (vk[:-1] - vk[1:])
    ok = (sg[1:] == -sg[:-1]) & (d > 0)
    n_ok = int(np.argmin(ok)) if not np.all(ok) else d.size
    above = ok & (d / 2 > _LOGDEC_FLOOR_NSD * noise)
    npair = int(np.argmin(above)) if not np.all(above) else d.size
    if npair < 2:
        return None
    c1, c0 = np.polyfit(np.arange(npair, dtype=float), np.log(d[:npair]), 1, w=d[:npair])
    if c1 < 0:
        k_floor = (math.log(2 * _LOGDEC_FLOOR_NSD * noise) - c0) / c1
        npair = int(min(max(math.floor(k_floor) + 1, 2), n_ok))
    K = npair + 1
    tk, vk, vt, vv, sg, d = tk[:K], vk[:K], vt[:K], vv[:K], sg[:K], d[:npair]
    s2 = noise * noise
    # (1) extremum times: t_k = t_0 + k π/ω_d, weighted by 1/var(t_k)
    k = np.arange(K, dtype=float)
    X = np.stack([np.ones(K), k], axis=1)
    Wt = 1.0 / np.maximum(vt, 1e-300)
    Mt = X.T @ (X * Wt[:, None])
    Ct = np.linalg.inv(Mt)
    pt = Ct @ (X.T @ (Wt * tk))
    rt = tk - X @ pt
    chi_t = float(rt @ (Wt * rt)) / s2 / max(K - 2, 1)
    half = float(pt[1])  # π/ω_d
    var_half = float(Ct[1, 1]) * s2 * _inflation(chi_t, K - 2)
    # (2) ln d_k = c − δ k, covariance of ln d from the shared extrema
    B = np.zeros((npair, K))
    B[np.arange(npair), np.arange(npair)] = 1.0
    B[np.arange(npair), np.arange(npair) + 1] = -1.0
    Jd = (sg[:npair] / d)[:, None] * B
    Sd = Jd @ (vv[:, None] * Jd.T)
    y = np.log(d)
    Xd = np.stack([np.ones(npair), np.arange(npair, dtype=float)], axis=1)
    Si = np.linalg.inv(Sd)
    Md = Xd.T @ Si @ Xd
    Cd = np.linalg.inv(Md)
    pd = Cd @ (Xd.T @ Si @ y)
    rd = y - Xd @ pd
    chi_d = float(rd @ Si @ rd) / s2 / max(npair - 2, 1)
    delta = -float(pd[1])
    var_delta = float(Cd[1, 1]) * s2 * _inflation(chi_d, npair - 2)
    om = math.pi / half
    var_om = (math.pi / half**2) ** 2 * var_half
    sig = delta * om / math.pi
    var_sig = (om / math.pi) ** 2 * var_delta + (delta / math.pi) ** 2 * var_om
    cov_so = (delta / math.pi) * var_om
    cov = np.array([[var_sig, cov_so], [cov_so, var_om]])
    return {"sigma": sig, "omega": om, "cov": cov, "n_extrema": K}
