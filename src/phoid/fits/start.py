"""The start of a dominant-mode fit: the record's spectral period, an ESPRIT estimate of its
dominant root, and :func:`start_decay` (release, window, noise, start, a Gauss–Newton
confirmation), for one record or many (:func:`start_decays`, the ESPRIT stage stacked).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from phoid.fits._solver import descend
from phoid.fits._stack import make_stack
from phoid.fits.release import check_record, diff_noise, med, releases, window
from phoid.fits.result import MIN_SAMPLES

__all__ = [
    "DecayStart",
    "dominant_period",
    "esprit",
    "initial_guess",
    "staged",
    "start_decay",
    "start_decays",
    "uniform_grid",
    "uniform_step",
]


def uniform_step(tau: np.ndarray, origin: float = 0.0) -> float | None:
    """The sampling interval if ``tau`` is uniform, else None.

    Uniform: every τ within 10⁻⁹ of a step of the grid τ₀ + n·dt, or within the rounding of the
    absolute times τ + ``origin`` (64 ulp of the largest): at 1 MHz, time stamps near 10 s
    carry rounding of ~2·10⁻⁹ of a step, which a test against the step alone would take for
    non-uniform sampling."""
    n = tau.size
    dt = (tau[-1] - tau[0]) / (n - 1)
    g = np.arange(n, dtype=float)  # the grid τ₀ + n dt, then its deviation, in place
    g *= dt
    g += tau[0]
    g -= tau
    dev = max(float(g.max()), -float(g.min()))
    ulp = np.spacing(abs(origin) + max(abs(float(tau[0])), abs(float(tau[-1]))))
    return float(dt) if dev <= max(1e-9 * dt, 64.0 * ulp) else None


# --------------------------------------------------------------------------------------------
# starting guess


def dominant_period(xg: np.ndarray) -> float:
    """Period, in samples, of the spectral peak of a uniformly sampled record (≤ its length).

    The first 4096 samples are used (where a decay is largest) unless the peak they give lies
    in the lowest bins, then the whole record."""
    for seg in (xg[:4096], xg):
        n = seg.size
        nfft = 1 << math.ceil(math.log2(n))
        spec = np.abs(np.fft.rfft(seg - seg.mean(), nfft))
        k = int(np.argmax(spec[1:])) + 1
        if k > 2 or n == xg.size:
            break
    return min(nfft / k, float(xg.size))


def dominant_periods(xgs: Sequence[np.ndarray]) -> list[float]:
    """:func:`dominant_period` of many records, the spectra of their first 4096 samples in
    one FFT (the same transform per row, so the same periods bit for bit)."""
    out: list[float | None] = [None] * len(xgs)
    rows = [i for i, xg in enumerate(xgs) if xg.size >= 4096]
    if len(rows) > 1:
        S = np.stack([xgs[i][:4096] for i in rows])
        S -= S.mean(axis=1, keepdims=True)
        k = np.argmax(np.abs(np.fft.rfft(S, 4096, axis=1))[:, 1:], axis=1) + 1
        for i, kk in zip(rows, k.tolist(), strict=True):
            if kk > 2 or xgs[i].size == 4096:
                out[i] = min(4096 / kk, float(xgs[i].size))
    return [dominant_period(xg) if p is None else p for xg, p in zip(xgs, out, strict=True)]


def uniform_grid(
    tau: np.ndarray, x: np.ndarray, origin: float = 0.0
) -> tuple[np.ndarray, float, float | None]:
    """x on a uniform grid from tau[0] (linear interpolation if the sampling is not uniform),
    its step, and the step if the sampling was uniform already (else None)."""
    n = tau.size
    dt = (tau[-1] - tau[0]) / (n - 1)
    udt = uniform_step(tau, origin) if n >= 64 else None
    if udt is not None:
        return x, dt, udt
    tg = tau[0] + dt * np.arange(n)
    return np.interp(tg, tau, x), dt, None


def _blocks(xg: np.ndarray, q: int) -> np.ndarray:
    """Means of consecutive blocks of q samples (a moving average sampled every q: every
    exponential mode e^{st} passes with only a complex gain, so σ and ω_d are untouched)."""
    m = xg.size // q
    return xg[: m * q].reshape(m, q).mean(axis=1) if q > 1 else xg


def esprit(y: np.ndarray, dt: float, order: int = 3) -> tuple[np.ndarray, np.ndarray | None]:
    """Roots s (1/s) of a sum of ``order`` damped exponentials fitted to y (ESPRIT), and their
    energies Σ|c zⁿ|² (None when there is exactly one complex pair: nothing to choose)."""
    _L, HH = esprit_gram(y, order)
    w, U = np.linalg.eigh(HH)
    return esprit_roots(y, dt, U[:, np.argsort(w)[::-1][:order]])


def esprit_gram(y: np.ndarray, order: int) -> tuple[int, np.ndarray]:
    """ESPRIT's Hankel order L and the L × L Gram matrix H Hᵀ of y's Hankel matrix."""
    n = y.size
    L = max(order + 1, min(n // 3, 20))
    K = n - L + 1
    H = y[np.add.outer(np.arange(L), np.arange(K))]  # Hankel matrix, L × K
    return L, H @ H.T


def esprit_phi(Us: np.ndarray) -> np.ndarray:
    """The shift-invariance solution Φ of Us[:-1] Φ = Us[1:] (least squares)."""
    # with orthonormal columns Us[:-1]ᵀUs[:-1] = I − vvᵀ (v the last row), well conditioned
    # unless |v| ≈ 1; normal equations then, else lstsq
    v = Us[-1]
    if float(v @ v) < 0.5:
        A = Us[:-1]
        return np.linalg.solve(A.T @ A, A.T @ Us[1:])
    return np.linalg.lstsq(Us[:-1], Us[1:], rcond=None)[0]


def esprit_roots(y: np.ndarray, dt: float, Us: np.ndarray, z: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`esprit` from the signal subspace ``Us`` (L × order) on, or from Φ's
    eigenvalues ``z`` when they are given."""
    order = Us.shape[1]
    if z is None:
        z = np.linalg.eigvals(esprit_phi(Us)).astype(complex)
    n = y.size
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        s = np.log(z) / dt
        if np.count_nonzero(s.imag > 0) == 1:
            return s, None
        energy = np.zeros(order)
        V = np.exp(np.multiply.outer(np.arange(n), np.log(z)))
        ok = np.all(np.isfinite(V), axis=0) & np.isfinite(s)
        if np.any(ok):
            c = np.linalg.lstsq(V[:, ok], y.astype(complex), rcond=None)[0]
            energy[ok] = np.abs(c) ** 2 * np.sum(np.abs(V[:, ok]) ** 2, axis=0)
    return s, energy


def initial_guess(xg: np.ndarray, dt: float, per: float, noise: float):
    """Start (σ, ω_d), whether a complex dominant pair was found, active length (samples).

    The part of the window above the noise (period blocks whose sd exceeds 3 noise sds), at most
    40 periods of it, block-averaged to ~16 samples a period; ESPRIT of order 3 (offset and one
    complex pair); the complex root of largest energy.
    """
    y, q, n_act = _guess_input(xg, per, noise)
    s, energy = esprit(y, q * dt, order=3)
    return _guess_pick(s, energy, q, dt, xg.size, n_act)


def _guess_input(xg: np.ndarray, per: float, noise: float) -> tuple[np.ndarray, int, int]:
    """:func:`initial_guess`'s ESPRIT input: the block means y, their block length q and the
    active length (samples)."""
    n = xg.size
    lb = int(min(max(round(per), 4), max(n // 8, 4)))
    nb = n // lb
    if nb >= 2:
        xb = xg[: nb * lb].reshape(nb, lb)
        bvar = (xb * xb).mean(axis=1) - xb.mean(axis=1) ** 2
        above = np.flatnonzero(bvar > 9.0 * noise * noise)
        n_act = (int(above[-1]) + 1) * lb if above.size else lb
    else:
        n_act = n
    n_act = min(max(n_act, 4 * lb), n)
    n_seg = max(min(n_act, int(40 * per)), min(n, 64))
    q = max(1, int(per // 16), n_seg // 1024)
    while n_seg // q < 16 and q > 1:
        q //= 2
    return _blocks(xg[:n_seg], q), q, n_act


def _guess_pick(s: np.ndarray, energy: np.ndarray | None, q: int, dt: float, n: int,
                n_act: int):
    """:func:`initial_guess`'s choice among the ESPRIT roots ``s`` (of block means of q
    samples, step dt, n samples in the window)."""
    if energy is None:
        energy = np.ones(s.size)
    nyq = math.pi / (q * dt)
    cand = np.flatnonzero((s.imag > 1e-6 * nyq) & (s.imag < 0.9 * nyq) & (energy > 0))
    if cand.size:
        i = cand[np.argmax(energy[cand])]
        return float(-s[i].real), float(s[i].imag), True, n_act
    # no complex pair: the dominant motion is not oscillatory; start from the real root of
    # largest energy that is not the offset, and half a cycle over the window
    T = n * dt
    real = np.flatnonzero((np.abs(s.imag) <= 1e-6 * nyq) & (np.abs(s.real) > 1.0 / T))
    sig = float(-s[real[np.argmax(energy[real])]].real) if real.size else 1.0 / T
    return sig, math.pi / T, False, n_act


def staged(xg: np.ndarray, dt: float, per: float, sig: float, om: float) -> tuple[float, float]:
    """Refine a start (σ, ω_d) made from 40 periods of a barely damped record with many more:
    fit block means (~32 a period) of windows growing fourfold, each from the last."""
    q = max(1, int(per // 32))
    yb = _blocks(xg, q)
    tb = dt * (q * np.arange(yb.size) + 0.5 * (q - 1))
    lim = 40 * per * dt
    while True:
        m = int(np.searchsorted(tb, lim, side="right"))
        if m >= MIN_SAMPLES:
            res = descend(make_stack([tb[:m]], [yb[:m]], dt * q), np.array([sig]),
                          np.array([om]))
            if res is not None:
                sig, om = float(res[2]["sig"][0]), float(res[2]["om"][0])
        if lim >= tb[-1]:
            break
        lim = min(4.0 * lim, tb[-1])
    return sig, om


@dataclass(frozen=True)
class DecayStart:
    """What :func:`start_decay` learns from a record cheaply: enough to plan a full fit.

    Attributes
    ----------
    sigma, omega_d : float
        Estimate of the dominant mode (1/s, rad/s): the Gauss–Newton optimum of
        :func:`fit_decay` (or only its ESPRIT start, see :func:`start_decay`).
    oscillating : bool
        Whether a complex dominant pair was found and, with ``refine``, the fit converged on it
        (else σ, ω_d are no more than a bland start).
    release : float
        Release time, s (detected, as in :func:`detect_release`).
    offset : float
        Median of the window, m (a rough level for amplitude scales).
    noise_sd : float
        Noise sd, m: of the held segment, else from second differences of the tail.
    t_start, t_end : float
        The window, s.
    """

    sigma: float
    omega_d: float
    oscillating: bool
    release: float
    offset: float
    noise_sd: float
    t_start: float
    t_end: float


#: Gauss–Newton stops in :func:`start_decay` when its next step is below this many standard
#: errors: a start only has to be within about one of the optimum (the full fit that follows
#: converges to 0.05 from there), and at this tolerance an ESPRIT start close enough already is
#: accepted without a second evaluation.
_START_RTOL_SE = 0.5
#: ``start_decay(refine="auto")``: an ESPRIT start with |σ| above this fraction of ω_d is
#: refined (and confirmed) by Gauss–Newton
_START_MAX_DAMPING = 0.25


def start_decay(
    t: ArrayLike,
    x: ArrayLike,
    *,
    release: float | None = None,
    skip: float = 0.0,
    refine: bool | str = True,
    coarse_release: bool = False,
) -> DecayStart:
    """The first stages of :func:`fit_decay`: release, noise, window, start and Gauss–Newton.

    What is left out is what a full fit adds for reporting: the exact residual, covariance and
    warnings. :func:`fit_decay` with ``guess=(start.sigma, start.omega_d)`` and
    ``release=start.release`` continues from it. With ``refine=False`` only the ESPRIT start
    is made (it can be lost on records where a slow non-dominant real mode is strong).
    ``refine="auto"`` runs Gauss–Newton only where the ESPRIT start is in doubt: where its
    frequency disagrees with the record's spectral peak (by more than a quarter, and more than
    1.5 bins of the FFT), or where it is a heavily damped pair (|σ| > 0.25 ω_d, ζ ≳ 0.24,
    where a ringing PHO run has ζ ≲ 0.2) — which is how a start goes wrong on such records; a
    start the Gauss–Newton cannot confirm (no convergence) is marked not oscillating. A clean
    start costs no evaluation of the model (docs/design-notes/fits.md, "start_decay").
    ``coarse_release=True`` detects the release by its first stage only (the quadratic change
    point; the refinement with an even quartic is left out), for callers that refine it with a
    model of their own. Raises ValueError as :func:`fit_decay` does for unusable input.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing.
    x : array_like, shape (n,)
        Position, m.
    release : float, optional
        Release time, s; default: detected.
    skip : float, default 0
        Time after the release left out, s.
    refine : bool or "auto", default True
        Whether to confirm the ESPRIT start by Gauss–Newton (see above).
    coarse_release : bool, default False
        Detect the release by its change point only.

    Returns
    -------
    DecayStart
    """
    pre = _start_prepare(t, x, release=release, skip=skip, coarse_release=coarse_release)
    s, energy = esprit(pre.y, pre.q * pre.dt, order=3)
    return _start_finish(pre, s, energy, refine)


@dataclass(frozen=True)
class _StartGrid:
    """:func:`_start_grid`'s window: release (s), t and x, τ = t − t[0] (s), noise (m), x on
    a uniform grid, its step (s) and the step if the sampling was uniform (else None)."""

    release: float
    tw: np.ndarray
    xw: np.ndarray
    tau: np.ndarray
    noise: float
    xg: np.ndarray
    dt: float
    udt: float | None


@dataclass(frozen=True)
class _StartInput(_StartGrid):
    """What :func:`start_decay` computes before its ESPRIT (by :func:`_start_prepare`): the
    window of :class:`_StartGrid` (release, ``tw``, ``xw``, ``tau``, noise, ``xg``, ``dt``,
    ``udt``), the spectral period ``per`` (samples) and ESPRIT's input (block means ``y`` of
    ``q`` samples, active length ``n_act``)."""

    per: float
    y: np.ndarray
    q: int
    n_act: int


def _start_prepare(t, x, *, release=None, skip=0.0, coarse_release=False) -> _StartInput:
    """:func:`start_decay` up to its ESPRIT (checks, release, window, noise, period)."""
    t, x = check_record(t, x)
    grid = _start_grid(t, x, release, skip, not coarse_release)
    return _start_input(grid, dominant_period(grid.xg))


def _start_grid(t, x, release, skip, refine_release=True, detected=None) -> _StartGrid:
    """The window of :func:`start_decay` (release, window, noise, uniform grid) of a checked
    record; ``detected`` as for :func:`window`."""
    release, hold_sd, tw, xw, ptp = window(t, x, release, skip, None, refine_release, detected)
    tau = tw - tw[0]
    noise = hold_sd if hold_sd else diff_noise(xw[-4096:])
    noise = max(noise, 1e-15 * ptp)
    xg, dt, udt = uniform_grid(tau, xw, float(tw[0]))
    return _StartGrid(float(release), tw, xw, tau, float(noise), xg, float(dt), udt)


def _start_input(g: _StartGrid, per: float) -> _StartInput:
    """:func:`start_decay`'s ESPRIT input from its window and the spectral period ``per``
    (samples)."""
    y, q, n_act = _guess_input(g.xg, per, g.noise)
    return _StartInput(**vars(g), per=float(per), y=y, q=q, n_act=n_act)


def _start_finish(pre: _StartInput, s: np.ndarray, energy: np.ndarray | None,
                  refine: bool | str = True) -> DecayStart:
    """:func:`start_decay` from ESPRIT's roots ``s`` and energies on (the choice of the start,
    the staged refinement, the Gauss–Newton confirmation)."""
    tw, xw, tau, xg, dt, per = pre.tw, pre.xw, pre.tau, pre.xg, pre.dt, pre.per
    release, noise, _udt = pre.release, pre.noise, pre.udt
    sig, om, oscill, n_act = _guess_pick(s, energy, pre.q, dt, xg.size, pre.n_act)
    if oscill and n_act > 40 * per:
        sig, om = staged(xg, dt, per, sig, om)
    if refine == "auto" and oscill:
        om_fft = 2.0 * math.pi / (per * dt)
        tol = max(0.25 * om_fft, 1.5 * 2.0 * math.pi / (min(xg.size, 4096) * dt))
        refine = abs(om - om_fft) > tol or abs(sig) > _START_MAX_DAMPING * om
    if refine and oscill:
        # a start the fit cannot confirm (no convergence) is no oscillating start
        res = descend(make_stack([tau], [xw], _udt), np.array([sig]), np.array([om]),
                      rtol_se=_START_RTOL_SE)
        oscill = res is not None and bool(res[4][0])
        if oscill:
            sig, om = float(res[2]["sig"][0]), float(res[2]["om"][0])
    return DecayStart(
        sigma=float(sig), omega_d=float(om), oscillating=bool(oscill), release=float(release),
        offset=med(xw), noise_sd=float(noise), t_start=float(tw[0]), t_end=float(tw[-1]),
    )


def start_decays(records: Sequence[tuple[np.ndarray, np.ndarray]], *, skip: float = 0.0,
                 refine: bool | str = True, coarse_release: bool = False
                 ) -> list[DecayStart | str]:
    """:func:`start_decay` of every record (t s, x m), the ESPRIT stage stacked.

    Returns per record its DecayStart, or the message of the ValueError, RuntimeError or
    LinAlgError that starting it alone raises. Identical to calling
    :func:`start_decay` per record.
    """
    out: list[DecayStart | str | None] = [None] * len(records)
    pres: dict[int, _StartInput] = {}
    checked: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i, (t, x) in enumerate(records):
        try:
            checked[i] = check_record(t, x)
        except ValueError as exc:
            out[i] = str(exc)
    # the releases' change points in one batch, the spectral periods in one FFT
    detected = dict(zip(checked, releases([t for t, _ in checked.values()],
                                               [x for _, x in checked.values()],
                                               not coarse_release), strict=True))
    grids: dict[int, _StartGrid] = {}
    for i, (t, x) in checked.items():
        try:
            grids[i] = _start_grid(t, x, None, skip, not coarse_release, detected[i])
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
    periods = dominant_periods([g.xg for g in grids.values()])
    for (i, g), per in zip(grids.items(), periods, strict=True):
        pres[i] = _start_input(g, per)
    order = 3
    grams: dict[int, list[tuple[int, np.ndarray]]] = {}
    for i, pre in pres.items():
        L, HH = esprit_gram(pre.y, order)
        grams.setdefault(L, []).append((i, HH))
    roots: dict[int, tuple] = {}
    for items in grams.values():
        ids = [i for i, _ in items]
        try:
            w, U = np.linalg.eigh(np.stack([HH for _, HH in items]))
        except np.linalg.LinAlgError:
            for i in ids:
                try:
                    pre = pres[i]
                    roots[i] = esprit(pre.y, pre.q * pre.dt, order)
                except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                    out[i] = str(exc)
            continue
        top = np.argsort(w, axis=1)[:, ::-1][:, :order]
        Us = np.take_along_axis(U, top[:, None, :], axis=2)  # (runs, L, order)
        v = Us[:, -1, :]
        normal = np.einsum("ri,ri->r", v, v) < 0.5
        Phi = np.empty((len(ids), order, order))
        if normal.any():
            A = Us[normal, :-1]
            At = A.transpose(0, 2, 1)
            try:
                Phi[normal] = np.linalg.solve(At @ A, At @ Us[normal, 1:])
            except np.linalg.LinAlgError:
                normal[:] = False
        for k in np.flatnonzero(~normal).tolist():
            try:
                Phi[k] = esprit_phi(Us[k])
            except np.linalg.LinAlgError as exc:
                out[ids[k]] = str(exc)
                Phi[k] = np.nan
        good = np.isfinite(Phi).all(axis=(1, 2))
        z = np.full((len(ids), order), np.nan, complex)
        if good.any():
            try:
                z[good] = np.linalg.eigvals(Phi[good]).astype(complex)
            except np.linalg.LinAlgError:
                good[:] = False
        for k, i in enumerate(ids):
            if out[i] is not None:
                continue
            pre = pres[i]
            try:
                roots[i] = esprit_roots(pre.y, pre.q * pre.dt, Us[k],
                                            z[k] if good[k] else None)
            except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                out[i] = str(exc)
    for i, (s_, energy) in roots.items():
        try:
            out[i] = _start_finish(pres[i], s_, energy, refine)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            out[i] = str(exc)
    return out  # type: ignore[return-value]
