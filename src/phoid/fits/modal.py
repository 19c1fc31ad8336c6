"""The dominant-mode decay fit: σ and ω_d of one record (:func:`fit_decay`) or of many at once
(:func:`fit_decays`), by maximum likelihood.

Nonlinear least squares on the whole window (maximum likelihood for white Gaussian noise) by
variable projection: at every (σ, ω_d) the linear part (offset, the mode's two amplitudes, the
fast modes' amplitudes) is solved exactly (:mod:`phoid.fits._stack`), and Kaufman's
Gauss–Newton step moves (σ, ω_d) (:mod:`phoid.fits._solver`). Its standard errors reach the
Cramér–Rao bound of the single-mode model. There is one implementation, for a stack of records:
the records that share a sampling step, a block size and a number of fast-mode columns are
fitted together, each keeping its own iteration and stopping point; a single record is a stack
of one, and a record's result does not depend on the others fitted with it (beyond rounding).
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from phoid import _validate as v
from phoid._threads import single_blas_thread
from phoid.fits._solver import descend, polish
from phoid.fits._stack import make_stack, n_columns, stack_key
from phoid.fits.release import check_record, diff_noise, window
from phoid.fits.result import DecayFit, common_warnings, count_cycles, phase_amp, unfitted
from phoid.fits.start import dominant_period, initial_guess, staged, uniform_grid

__all__ = ["FitJob", "check_fast_roots", "fit_checked", "fit_decay", "fit_decays"]

#: a fitted mode weaker than this many noise sds (its norm over the window) is no oscillation
_MIN_MODE_SNR = 10.0
#: a stack holds at most about this many samples (its stacked copy of the data and the
#: residuals it keeps are then ≤ 8 MB each): long records are fitted in smaller stacks, a
#: record of more samples alone, so the memory stays that of one-by-one fits
_BATCH_SAMPLES = 1 << 20


@dataclass(frozen=True)
class FitJob:
    """One record to fit: the arguments of :func:`fit_decay` (``t`` s, ``x`` m, ``release`` s,
    ``skip`` s, ``fast_roots`` 1/s, ``guess`` (σ 1/s, ω_d rad/s), ``t_end`` s, ``noise_sd``
    m). The record must have passed :func:`phoid.fits.release.check_record` (float64, finite,
    t strictly increasing)."""

    t: np.ndarray
    x: np.ndarray
    release: float | None = None
    skip: float = 0.0
    fast_roots: np.ndarray | None = None
    guess: tuple[float, float] | None = None
    t_end: float | None = None
    noise_sd: float | None = None


def check_fast_roots(fast_roots: ArrayLike | None) -> np.ndarray:
    """The fast roots (1/s) as a complex array, a root and its conjugate as one mode
    (Im ≥ 0); ValueError unless every root is finite and decaying (Re s < 0)."""
    if fast_roots is None:
        return np.zeros(0, complex)
    try:
        r = np.asarray(fast_roots, dtype=complex).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"`fast_roots` must be complex numbers; got {fast_roots!r}") from None
    roots = r.tolist()  # (a handful: plain Python is faster than array calls here)
    for z in roots:
        if not cmath.isfinite(z):
            raise ValueError(f"`fast_roots` must be finite; got {z}")
    for z in roots:
        if not z.real < 0:
            raise ValueError(f"`fast_roots` must be decaying modes (Re s < 0, 1/s); got {z}")
    keep: list[complex] = []
    for z in (complex(q.real, abs(q.imag)) for q in roots):  # a root and its conjugate: one mode
        if not any(abs(z - w) <= 1e-9 * abs(w) for w in keep):
            keep.append(z)
    return np.array(keep, dtype=complex)




@single_blas_thread
def fit_decay(
    t: ArrayLike,
    x: ArrayLike,
    *,
    release: float | None = None,
    skip: float = 0.0,
    t_end: float | None = None,
    noise_sd: float | None = None,
    fast_roots: ArrayLike | None = None,
    guess: tuple[float, float] | None = None,
) -> DecayFit:
    """Decay rate σ and damped frequency ω_d of the dominant mode by maximum likelihood.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing (need not be uniform).
    x : array_like, shape (n,)
        Position, m.
    release : float, optional
        Release time of the held mass, s (may precede the record). Default:
        :func:`detect_release`.
    skip : float, default 0
        Time after the release left out of the fit, s (≥ 0), so that the closed loop's fast
        non-dominant modes have died (compute it from the loop model; see Notes).
    t_end : float, optional
        Last time fitted, s. Default: the end of the record (no truncation; see Notes).
    noise_sd : float, optional
        Known white-noise sd, m (> 0). Used for the noise floor (``cycles``, warnings); the
        covariance always uses the residual variance. Default: the sd of the held segment, or
        a robust estimate from second differences when there is no held segment.
    fast_roots : array_like of complex, optional
        Roots s = −σ_j + iω_j (1/s, Re s < 0) of non-dominant modes to fit alongside the
        dominant one, with free amplitudes and fixed rates (a root and its conjugate are one
        mode) — e.g. the closed loop's next roots from the current plant estimate. With them
        the fit can start at the release (``skip`` = 0) and keep the information of the first
        instants instead of discarding it.
    guess : (float, float), optional
        Starting (σ, ω_d) (1/s, rad/s), e.g. from an earlier fit of the same record; skips the
        FFT/ESPRIT starting stage. The record is then taken to be oscillatory.

    Returns
    -------
    DecayFit
        ``method == "mode-fit"``; ``t_ref`` is the first fitted sample. ``model`` is the
        dominant mode and the offset (the fast modes are left out).

    Raises
    ------
    ValueError
        If the input is unusable: NaN/inf, t not strictly increasing, lengths differ, fewer
        than 16 samples (in the record or the window), a constant record, a bad option.

    Notes
    -----
    Model over the window [release + skip, t_end], with τ = t − t_ref (eq. 15 plus an offset):

        x = x_off + e^{−στ} (a cos ω_dτ + b sin ω_dτ) + white noise.

    Start: the FFT peak gives the period; the part of the window above the noise (≤ 40 periods
    of it) is block-averaged to ~16 samples a period (a moving average keeps every exponential
    mode exactly) and ESPRIT (order 3: offset and one complex pair) gives (σ, ω_d). Solver:
    variable projection — (x_off, a, b) by linear least squares at every (σ, ω_d) — with
    Kaufman's Gauss–Newton step from the full 5-column Jacobian, step halving on any increase of
    the residual sum of squares, stopped when the next step is below 0.05 standard errors
    (where Gauss–Newton contracts by ~10⁻³ a step) — then up to three steps more from the
    exactly recomputed residual while they are larger (noise-free data: to 10⁻¹⁵). Records much
    longer than the start segment (barely damped loops with hundreds of cycles) are first
    fitted on block means of windows growing fourfold, each started from the last.
    On uniform sampling every sum the solver needs (Σ τᵖ e^{2sτ}, Σ x τᵖ e^{sτ}, …) is formed
    from two √n-long exponential tables (n = bB + j), with no transcendental per sample
    (:class:`phoid.fits._stack.TableStack`).

    Covariance: RSS/(n − p) · (JᵀJ)⁻¹ with J the n × p Jacobian of all p parameters (5, plus
    the fast modes' amplitudes) at the optimum, its (σ, ω_d) block taken — the Cramér–Rao bound
    of this model at the estimate, with the noise variance from the residuals (so unmodelled
    signal inflates it).

    Window: the whole record after release + skip is fitted. The tail lost in noise is kept:
    it costs little time, biases nothing and pins the offset (truncating it only loses offset
    information); ``t_end`` caps the window.

    Fast modes of a delayed loop: its non-dominant roots leave a transient right after the
    release that biases a single-mode fit started there. Either skip it — until the slowest
    fast mode's envelope |A₂|e^{−σ₂t} is below ~0.01 noise sd, e.g.
    ``skip = max(2Δt, 5/(σ₂ − σ))`` — or give the two slowest non-dominant roots as
    ``fast_roots`` and fit from the release, which keeps the information of the first
    instants (docs/design-notes/fits.md, "fit_decay: skip or fast roots", has the figures).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(15000) / 1000  # 15 s at 1 kHz
    >>> x = -3e-4 + 0.01 * np.exp(-0.5 * t) * np.cos(6.2 * t)
    >>> fit = fit_decay(t, x, release=0.0)
    >>> print(f"{fit.sigma:.9f} {fit.omega_d:.9f} {fit.offset:.6f}")
    0.500000000 6.200000000 -0.000300
    >>> rng = np.random.default_rng(0)
    >>> fit = fit_decay(t, x + 1e-4 * rng.standard_normal(t.size), release=0.0)
    >>> abs(fit.sigma - 0.5) < 3 * fit.sigma_stderr
    True
    """
    t, x = check_record(t, x)
    return fit_checked(t, x, release=release, skip=skip, t_end=t_end, noise_sd=noise_sd,
                        fast_roots=fast_roots, guess=guess)




def fit_checked(t: np.ndarray, x: np.ndarray, *, release: float | None = None,
                skip: float = 0.0, t_end: float | None = None, noise_sd: float | None = None,
                fast_roots: ArrayLike | None = None,
                guess: tuple[float, float] | None = None) -> DecayFit:
    """:func:`fit_decay` on a record that has passed ``check_record`` already (float64
    arrays, finite, t strictly increasing): a stack of one. Raises as :func:`fit_decay`."""
    prep = _fit_prepare(t, x, release=release, skip=skip, t_end=t_end, noise_sd=noise_sd,
                        fast_roots=fast_roots, guess=guess)
    out = _fit_prepared([prep])[0]
    if isinstance(out, Exception):
        raise out
    return out


def fit_decays(jobs: Sequence[FitJob]) -> list[DecayFit | str]:
    """:func:`fit_decay` of every job, fitted in stacks.

    Parameters
    ----------
    jobs : sequence of FitJob
        The records (already checked) and their fit options.

    Returns
    -------
    list of DecayFit or str
        Per job its fit (``method == "mode-fit"``, as :func:`fit_decay` returns it), or the
        message of the ValueError, RuntimeError or LinAlgError that fitting it alone raises.
    """
    out: list[DecayFit | str | None] = [None] * len(jobs)
    preps: list[_Prepared] = []
    where: list[int] = []
    for i, job in enumerate(jobs):
        try:
            preps.append(_fit_prepare(job.t, job.x, release=job.release, skip=job.skip,
                                      t_end=job.t_end, noise_sd=job.noise_sd,
                                      fast_roots=job.fast_roots, guess=job.guess))
            where.append(i)
        except _FIT_ERRORS as exc:
            out[i] = str(exc)
    for i, res in zip(where, _fit_prepared(preps), strict=True):
        out[i] = str(res) if isinstance(res, Exception) else res
    return out  # type: ignore[return-value]


_FIT_ERRORS = (ValueError, RuntimeError, np.linalg.LinAlgError)


def _fit_prepared(preps: Sequence[_Prepared]) -> list[DecayFit | Exception]:
    """The fits of prepared records: stacked by :func:`phoid.fits._stack.stack_key` (in
    batches of at most ``_BATCH_SAMPLES`` samples), Gauss–Newton from each record's start,
    from the bland fallback start (σ = 0, the spectral period) where the start cannot be
    evaluated, polish, result. Per record its DecayFit or the exception finishing it raised."""
    out: list[DecayFit | Exception | None] = [None] * len(preps)
    starts = {i: (p.sigma, p.omega_d) for i, p in enumerate(preps)}
    for fallback in (False, True):
        groups: dict[tuple, list[int]] = {}
        for i in starts:
            p = preps[i]
            groups.setdefault(stack_key(p.xw.size, p.udt, n_columns(p.fast)), []).append(i)
        failed: list[int] = []
        for members in groups.values():
            for idx in _chunks(members, [preps[i].xw.size for i in members]):
                failed += _fit_stack(idx, preps, starts, out)
        # a start that cannot be evaluated: once more from a bland one
        starts = {i: (0.0, 2 * math.pi / (preps[i].period * preps[i].dt)) for i in failed}
        if fallback:
            for i in failed:  # no (σ, ω_d) where the linear part is solvable: nothing to report
                out[i] = _fit_unevaluable(preps[i])
    return out  # type: ignore[return-value]


def _chunks(members: list[int], sizes: list[int]) -> list[list[int]]:
    """``members`` cut into consecutive batches of at most ``_BATCH_SAMPLES`` samples."""
    out: list[list[int]] = [[]]
    total = 0
    for i, n in zip(members, sizes, strict=True):
        if out[-1] and total + n > _BATCH_SAMPLES:
            out.append([])
            total = 0
        out[-1].append(i)
        total += n
    return out


def _fit_stack(idx: list[int], preps: Sequence[_Prepared], starts: dict, out: list
               ) -> list[int]:
    """Fit the records ``idx`` (of one stack key) from ``starts`` into ``out``; returns those
    whose start cannot be evaluated."""
    ps = [preps[i] for i in idx]
    st = make_stack([p.tau for p in ps], [p.xw for p in ps], ps[0].udt, [p.fast for p in ps])
    res = descend(st, np.array([starts[i][0] for i in idx]),
                  np.array([starts[i][1] for i in idx]))
    if res is None:
        return list(idx)
    rows, st, pt, Minv, converged, iters = res
    pt, r, Minv = polish(st, pt, Minv)
    for row, j in enumerate(rows.tolist()):
        M = Minv[row]
        try:
            out[idx[j]] = _fit_finish(ps[j], float(pt["sig"][row]), float(pt["om"][row]),
                                      pt["beta"][row], pt["K"][row], r[row],
                                      M if np.isfinite(M).all() else np.full_like(M, np.nan),
                                      bool(converged[row]), int(iters[row]))
        except _FIT_ERRORS as exc:
            out[idx[j]] = exc
    good = set(rows.tolist())
    return [i for j, i in enumerate(idx) if j not in good]


@dataclass(frozen=True)
class _Prepared:
    """A record made ready for the Gauss–Newton of :func:`fit_decay` (by :func:`_fit_prepare`):
    the window (``tw``, ``xw``; ``tau`` = tw − tw[0], s), the release (s) and held-segment sd
    (m, None without one), the noise level (m) and the caller's ``noise_sd``, the record's range
    ``ptp`` (m), its sampling (``dt`` s; ``udt`` the step if uniform, else None), the start
    (``sigma`` 1/s, ``omega_d`` rad/s, ``oscillating``, ``period`` in samples) and the fast
    roots (1/s)."""

    tw: np.ndarray
    xw: np.ndarray
    tau: np.ndarray
    release: float
    hold_sd: float | None
    noise: float
    noise_sd: float | None
    ptp: float
    dt: float
    udt: float | None
    sigma: float
    omega_d: float
    oscillating: bool
    period: float
    fast: np.ndarray


def _fit_prepare(t, x, *, release=None, skip=0.0, t_end=None, noise_sd=None, fast_roots=None,
                 guess=None) -> _Prepared:
    """Window, noise and start of :func:`fit_decay` (everything before its Gauss–Newton).

    Raises ValueError as :func:`fit_decay` does for unusable options or windows."""
    if noise_sd is not None:
        noise_sd = v.positive("noise_sd", noise_sd, "m")
    fast = check_fast_roots(fast_roots)
    release, hold_sd, tw, xw, ptp = window(t, x, release, skip, t_end)
    tau = tw - float(tw[0])
    if noise_sd is not None:
        noise = noise_sd
    else:  # the tail, where the signal is least, is the best place for a difference estimate
        noise = hold_sd if hold_sd else diff_noise(xw[-4096:])
    noise = max(noise, 1e-15 * ptp)

    # start: FFT period, ESPRIT on the block-averaged active part (or the caller's guess)
    xg, dt, udt = uniform_grid(tau, xw, float(tw[0]))
    if guess is not None:
        sig = v.finite("guess[0]", guess[0], "1/s")
        om = v.positive("guess[1]", guess[1], "rad/s")
        oscill, n_act = True, 0
        per = 2 * math.pi / (om * dt)
    else:
        per = dominant_period(xg)
        sig, om, oscill, n_act = initial_guess(xg, dt, per, noise)
    if oscill and n_act > 40 * per:
        sig, om = staged(xg, dt, per, sig, om)
    return _Prepared(tw=tw, xw=xw, tau=tau, release=float(release), hold_sd=hold_sd,
                     noise=float(noise), noise_sd=noise_sd, ptp=ptp, dt=float(dt), udt=udt,
                     sigma=float(sig), omega_d=float(om), oscillating=bool(oscill),
                     period=float(per), fast=fast)


def _fit_unevaluable(prep: _Prepared) -> DecayFit:
    """The result of a fit whose model could not be evaluated at any start."""
    msg = "not converged: no start at which the damped-mode model could be evaluated"
    return unfitted("mode-fit", prep.tw, prep.release, prep.noise, float(np.median(prep.xw)),
                     [msg])


def _fit_finish(prep: _Prepared, sig: float, om: float, beta: np.ndarray, K: np.ndarray,
                r: np.ndarray, Minv: np.ndarray, converged: bool, iterations: int) -> DecayFit:
    """The DecayFit of a converged (or stopped) Gauss–Newton: at (σ, ω_d) = (``sig``, ``om``)
    with linear parameters ``beta`` (x_off, a, b, fast amplitudes …), their Gram matrix ``K``,
    the exact residual ``r`` (m, per sample of the window) and (JᵀJ)⁻¹ ``Minv`` (σ, ω_d last);
    covariance, amplitude, noise floor, cycles and warnings."""
    tw, xw, fast, noise_sd = prep.tw, prep.xw, prep.fast, prep.noise_sd
    bl = beta.tolist()
    off, a, b = bl[:3]
    n = xw.size
    rss = float(r @ r)
    s2 = rss / max(n - K.shape[0], 1)
    amp, phase = phase_amp(a, b)
    # the fast columns are e^{rτ} (real r) or Re, Im of e^{rτ}: amplitude A with Re(A e^{rτ})
    fast_modes, j = [], 3
    fl = fast.tolist()
    for root in fl:
        if root.imag != 0:
            fast_modes.append((complex(root), complex(bl[j], -bl[j + 1])))
            j += 2
        else:
            fast_modes.append((complex(root), complex(bl[j])))
            j += 1
    cov = s2 * Minv[-2:, -2:]
    (c00, _c01), (_c10, c11) = cov.tolist()
    sig_se, om_se = math.sqrt(max(c00, 0.0)), math.sqrt(max(c11, 0.0))  # DecayFit's stderrs
    fit_noise = math.sqrt(s2)
    floor = noise_sd if noise_sd is not None else max(fit_noise, 1e-15 * prep.ptp)
    cycles = count_cycles(amp, sig, om, float(tw[-1] - tw[0]), floor)
    warnings = common_warnings(sig, sig_se, cycles, xw, r, floor)
    # detection statistic of the mode: its norm over the window in noise sds (pure noise gives
    # ~5 for the best of all (σ, ω_d); a real decay of the sample set ~10³)
    (k11, k12), (k21, k22) = K[1:3, 1:3].tolist()
    snr = math.sqrt(max(a * (k11 * a + k12 * b) + b * (k21 * a + k22 * b), 0.0)) / max(
        fit_noise, 1e-300)
    if (
        # the order-3 starting guess sees no complex pair when a slow non-dominant real mode is
        # in the record; with that mode given in ``fast_roots`` the final fit decides alone
        (not prep.oscillating and fast.size == 0)
        or not om > 3.0 * om_se
        or om * (tw[-1] - tw[0]) < math.pi
        or snr < _MIN_MODE_SNR
    ):
        warnings.append(
            "no oscillation: the dominant motion is not a resolvable damped oscillation "
            f"(ω_d = {om:.4g} ± {om_se:.2g} rad/s, mode {snr:.3g} noise sds "
            "strong); σ and ω_d describe no underdamped mode"
        )
    if any(-z.real <= sig for z in fl):
        warnings.append(
            "fast_roots: a root given as non-dominant decays no faster than the fitted dominant "
            f"mode (σ = {sig:.4g} 1/s); check the roots"
        )
    if not converged:
        warnings.append(
            f"not converged: the fit stopped after {iterations} Gauss–Newton iterations; "
            "the estimate may not be the least-squares optimum"
        )
    ref = noise_sd if noise_sd is not None else prep.hold_sd
    if ref and fit_noise > 1.5 * ref:
        warnings.append(
            f"misfit: residual sd {fit_noise:.3g} m is {fit_noise / ref:.2f} times the "
            f"noise sd {ref:.3g} m ({'given' if noise_sd is not None else 'held segment'}); "
            "the record holds more than one damped mode (increase `skip`?) or friction"
        )
    return DecayFit(
        sigma=float(sig),
        omega_d=float(om),
        cov=cov,
        amplitude=amp,
        phase=phase,
        offset=off,
        t_ref=float(tw[0]),
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=prep.release,
        n_samples=int(n),
        cycles=cycles,
        noise_sd=fit_noise,
        residual_rms=math.sqrt(rss / n),
        method="mode-fit",
        fast_modes=tuple(fast_modes),
        warnings=tuple(warnings),
    )


