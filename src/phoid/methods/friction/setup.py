"""Preparation shared by the friction fit and the score test: checks and the starting point.

Checks before fitting (:func:`prepare`): malformed input is an
:class:`~phoid.errors.ExperimentError` naming the run and the field; a sample interval longer
than 10 loop delays is refused (t in milliseconds, or the delay in the wrong unit, is the likely
cause, and the fit, which simulates in steps of at most one delay, would take that many steps per
sample); a sampled (digital) loop with a bias is refused (its record jumps, by the effect of 2bᵢ
held for one period, wherever a velocity reversal crosses a controller instant, so the
likelihood is not smooth in θ and the fit is unreliable: docs/design-notes/friction.md; the
simulator does model such loops exactly, ``phoid simulate --sample-time … --bias …``). The
recorded force u, where given, is checked against the gains
(:func:`phoid.methods.friction.survey.check_u`); when the viscous starting point then fails,
the error (:class:`StartError`) carries that diagnosis.

Starting point. m, c, k come from :func:`phoid.identify_data` (the
viscous dominant-mode fit of the same runs), τᵢ from its model-fitted releases. The envelopes
then give the rest: successive extrema pₙ of each record lie about bᵢ with a peak-to-peak height
Hₙ that obeys Hₙ₊₁ = ρᵢHₙ − 2f_c(1 + ρᵢ)/(k + Pᵢ) (the half-cycle recursion of a linear
oscillator about the shifted equilibria), fitted by least squares per run: f_c is the median of
the runs' values, the friction-free decay σᵢ = −ln(ρᵢ)ω_dᵢ/π corrects c (which the viscous fit
inflates), bᵢ is the median of (pₙ + 2pₙ₊₁ + pₙ₊₂)/4 and x₀ᵢ the held level minus bᵢ. Of two
such starts (the viscous m, k with the corrected c; or m, c, k from the paper's lines through the
corrected σᵢ) :func:`phoid.methods.friction.fit.identify_friction` uses the one that fits the
first stage's windows better. A run's known bias bᵢ adds to its net friction in the envelope.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.dynamics import dominant_roots, inverse_map
from phoid.errors import ExperimentError, IdentificationError, PhoidError
from phoid.methods.friction.survey import Survey, check_run, check_u, survey_run
from phoid.methods.pho import fit_lines

__all__ = ["Setup", "StartError", "dominant", "prepare"]

_DT_PER_DELAY = 10.0  # a sample interval longer than this many loop delays: a wrong time base


@dataclass
class Setup:
    """A friction set checked and prepared for fitting: :func:`prepare`'s result (units as
    in :func:`phoid.methods.friction.fit.identify_friction`)."""

    names: list[str]
    P: np.ndarray
    D: np.ndarray
    delay: float
    surveys: list[Survey]
    reasons: list[str | None]
    start: np.ndarray  # (m, c, k, fc)
    candidates: list[np.ndarray]  # starts to choose from (the best fitting first samples)
    release: np.ndarray
    offset: np.ndarray
    omega: np.ndarray  # dominant angular frequency per run (start plant), rad/s
    fs: float
    warnings: list[str]
    dm: np.ndarray  # known added mass per run, kg
    digital: Any = None  # phoid.DigitalPD of a sampled loop, else None
    bias: np.ndarray | None = None  # known DC offset of each run's command, N


def _as_gains(name: str, a: Any, n: int) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ExperimentError(f"`{name}` must be an array of real numbers") from None
    if arr.size != n:
        raise ExperimentError(f"`{name}` must have one entry per run ({n}); got {arr.size}")
    if not np.all(np.isfinite(arr)):
        j = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ExperimentError(f"run{j + 1}: `{name}` must be finite; got {arr[j]}")
    return arr


def _check_start(start) -> list[float] | None:
    if start is None:
        return None
    try:
        st = [float(a) for a in start]
    except (TypeError, ValueError):
        raise ExperimentError(f"`start` must be (m, c, k) or (m, c, k, fc); got {start!r}") \
            from None
    if len(st) not in (3, 4) or not all(math.isfinite(a) for a in st) or not st[0] > 0 \
            or (len(st) == 4 and not st[3] >= 0):
        raise ExperimentError(
            f"`start` must be (m, c, k) or (m, c, k, fc), finite, m > 0, fc ≥ 0; got {start!r}"
        )
    return st


class StartError(IdentificationError):
    """No viscous starting point; ``cause`` is the viscous identification's own message (None
    when it failed internally) and ``hint`` what the recorded u says, if anything."""

    def __init__(self, message: str, cause: str | None, hint: str | None):
        super().__init__(message)
        self.cause = cause
        self.hint = hint


def _check_time_base(names, surveys, delay: float) -> None:
    """Refuse a record whose sample interval is many loop delays long: t in ms (or the delay
    in the wrong unit). The fit simulates the loop in steps of at most one delay, so this also
    bounds its work to _DT_PER_DELAY steps per recorded sample."""
    if not delay > 0:
        return
    for name, s in zip(names, surveys, strict=True):
        dt = float(np.median(np.diff(s.t)))
        if dt > _DT_PER_DELAY * delay:
            raise ExperimentError(
                f"{name}: the sample interval {dt:.3g} s is {dt / delay:.3g} times the loop "
                f"delay {delay:.3g} s: t in milliseconds instead of seconds (then give "
                f"[units] t = \"ms\" in the manifest), or the delay in the wrong unit? (the "
                f"friction fit needs a sample interval of at most {_DT_PER_DELAY:g} delays)")


def dominant(m: float, c: float, k: float, P: Any, D: Any, delay: float,
             digital: Any) -> np.ndarray:
    """Dominant root of each run's loop: the continuous delayed loop, or the sampled one.

    Parameters
    ----------
    m, c, k : float
        The plant, kg, N s/m, N/m.
    P, D : array_like
        Gains of each run, N/m and N s/m.
    delay : float
        Loop delay Δt, s (continuous loops).
    digital : phoid.DigitalPD or None
        The sampled controller, if any.

    Returns
    -------
    ndarray of complex
        The dominant (rightmost) root of each run's loop, 1/s
        (:func:`phoid.dynamics.rightmost.dominant_roots`, or
        :func:`phoid.dynamics.digital.digital_roots` for a sampled loop).
    """
    if digital is None:
        return dominant_roots(m, c, k, P, D, delay)
    from phoid.dynamics.digital import digital_roots

    return digital_roots(m, c, k, P, D, digital).dominant


def prepare(data: Sequence[Any], P: Any, D: Any, delay: float | None, start: Any,
            names: Sequence[str] | None, need_fc: bool, added_mass: Any = None,
            digital: Any = None, bias: Any = None, u: Any = None) -> Setup:
    """Check a friction set and find its starting point (module docstring).

    Parameters
    ----------
    data, P, D, delay, start, names, added_mass, digital, bias, u
        As for :func:`phoid.methods.friction.fit.identify_friction`.
    need_fc : bool
        Whether f_c is fitted (its start from the envelopes, and several candidate starts);
        False for the score test, which fits f_c = 0.

    Returns
    -------
    Setup

    Raises
    ------
    ExperimentError
        Malformed input (the message names the run and the field).
    IdentificationError
        No usable run; :class:`StartError` when there is no starting point.
    """
    from phoid.methods.identification import identify_pho_data as identify_data

    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    names = list(names) if names is not None else [f"run{i + 1}" for i in range(n)]
    if len(names) != n:
        raise ExperimentError(f"`names` must have one entry per run ({n}); got {len(names)}")
    P = _as_gains("P", P, n)
    D = _as_gains("D", D, n)
    dm = np.zeros(n) if added_mass is None else _as_gains("added_mass", added_mass, n)
    if np.any(dm < 0):
        j = int(np.flatnonzero(dm < 0)[0])
        raise ExperimentError(f"{names[j]}: `added_mass` must be ≥ 0 kg; got {dm[j]}")
    bs = np.zeros(n) if bias is None else _as_gains("bias", bias, n)
    if np.any(bs < 0):
        j = int(np.flatnonzero(bs < 0)[0])
        raise ExperimentError(f"{names[j]}: `bias` must be ≥ 0 N; got {bs[j]}")
    if digital is not None:
        from phoid.dynamics.digital import DigitalPD

        if not isinstance(digital, DigitalPD):
            raise ExperimentError(f"`digital` must be a phoid.DigitalPD; got {digital!r}")
        if delay is not None:
            raise ExperimentError(
                "`delay` must be None with a digital loop: its command delay is "
                f"`delay_samples` whole samples; got delay={delay!r}")
        if np.any(bs > 0):
            j = int(np.flatnonzero(bs > 0)[0])
            raise ExperimentError(
                f"{names[j]}: bias = {bs[j]:g} N with a sampled (digital) loop: not supported "
                "by the friction fit (the biased sampled loop's record jumps where a velocity "
                "reversal crosses a controller instant, and the fit is unreliable there); "
                "record the runs without bias, or with a continuous-delay model of the loop")
        # the equivalent continuous delay (d samples and half a sample of hold): only for the
        # starting point, the windows' margins and the reported c′, k′
        delay = digital.delay + 0.5 * digital.sample_time
    else:
        try:
            delay = float(delay)
        except (TypeError, ValueError):
            raise ExperimentError(f"`delay` must be a real number (s); got {delay!r}") from None
        if not (math.isfinite(delay) and delay >= 0):
            raise ExperimentError(f"`delay` must be finite and ≥ 0 s; got {delay}")
    st = _check_start(start)
    surveys = []
    for i, run in enumerate(data):
        try:
            t, x = run
        except (TypeError, ValueError):
            raise ExperimentError(f"{names[i]}: each run must be a pair (t, x)") from None
        t, x = check_run(names[i], t, x)
        surveys.append(survey_run(names[i], t, x))
    _check_time_base(names, surveys, delay)
    # the recorded force (continuous loops): u = −P x(t − Δt) − D ẋ(t − Δt) + b sign(ẋ(t − Δt))
    warnings: list[str] = check_u(names, surveys, u, P, D, delay, bs) \
        if u is not None and digital is None else []
    reasons = [s.reason for s in surveys]
    cand = [i for i in range(n) if reasons[i] is None]
    if not cand:
        raise IdentificationError(
            "no usable runs: " + "; ".join(f"{names[i]}: {reasons[i]}" for i in range(n))
        )
    release = np.array([s.release for s in surveys])
    offset = np.array([s.final for s in surveys])
    omega = np.full(n, math.nan)
    if start is None:
        try:
            visc = identify_data([data[i] for i in cand], P[cand], D[cand],
                                 delay if digital is None else None,
                                 names=[names[i] for i in cand], added_mass=dm[cand],
                                 digital=digital)
        except (IdentificationError, ValueError, ArithmeticError) as exc:
            cause = str(exc) if isinstance(exc, PhoidError) else None
            hint = "; ".join(warnings) or None
            raise StartError(
                f"no viscous starting point for the friction fit"
                f"{f' ({cause})' if cause else ''}{f'; {hint}' if hint else ''}; pass "
                "`start=(m, c, k)` or `start=(m, c, k, fc)`", cause, hint
            ) from None
        m0, c0, k0 = visc.m.value, visc.c.value, visc.k.value
        fc0 = None
        for i, rm in zip(cand, visc.runs, strict=True):
            if rm.fit is not None:
                release[i] = rm.fit.release
                offset[i] = rm.fit.offset
                if rm.fit.omega_d > 0:
                    omega[i] = rm.fit.omega_d
    else:
        m0, c0, k0 = st[:3]
        fc0 = st[3] if len(st) == 4 else None
    if not (m0 > 0 and math.isfinite(c0) and math.isfinite(k0)):
        cause = (f"the viscous identification gives m = {m0:.6g} kg, c = {c0:.6g} N s/m, "
                 f"k = {k0:.6g} N/m")
        hint = "; ".join(warnings) or None
        raise StartError(f"no physical starting point for the friction fit ({cause}"
                         f"{f'; {hint}' if hint else ''}); pass `start=(m, c, k)`", cause, hint)
    todo = [i for i in cand if not omega[i] > 0]
    if todo:
        for added in np.unique(dm[todo]):  # one plant per added mass
            g = [i for i in todo if dm[i] == added]
            try:
                omega[g] = np.abs(dominant(m0 + added, c0, k0, P[g], D[g], delay,
                                           digital).imag)
            except (ValueError, RuntimeError):
                pass
    for i in cand:
        if not omega[i] > 0:
            omega[i] = math.sqrt(max(abs(k0 + P[i]) / (m0 + dm[i]), 1e-12))
    cands, offs = _envelope_guess([surveys[i] for i in cand], P[cand], D[cand], delay, m0, c0,
                                  k0, omega[cand], release[cand], dm[cand], bs[cand])
    for i, b in zip(cand, offs, strict=True):
        if math.isfinite(b):
            offset[i] = b
    if start is None and need_fc:
        candidates = cands
    else:
        fc = cands[0][3] if fc0 is None and need_fc else (fc0 or 0.0)
        candidates = [np.array([m0, c0, k0, fc])]
    dts = [float(np.median(np.diff(surveys[i].t))) for i in cand]
    fs = 1.0 / min(dts)
    if digital is not None:  # a whole number of steps per controller sample
        fs = max(1, math.ceil(fs * digital.sample_time - 1e-9)) / digital.sample_time
    elif delay > 0:
        fs = math.ceil(fs * delay - 1e-9) / delay  # a whole number of steps per delay
    return Setup(names, P, D, delay, surveys, reasons, candidates[0], candidates, release,
                 offset, omega, fs, warnings, dm, digital, bs)


# --------------------------------------------------------------------------------------------
# the friction guess from the envelope's linear part


def _extrema(t: np.ndarray, y: np.ndarray, omega: float, sd: float):
    """Successive alternating extrema (times, s, and values, m) of a ringing record, while the
    peak-to-peak height stays above 20 noise sd.

    The record is smoothed by a moving average over a tenth of a half period (amplitude
    −0.4 %); each extremum is the vertex of a parabola fitted over ±a fifth of a half period.
    """
    from scipy import signal

    dt = float(np.median(np.diff(t)))
    nh = math.pi / omega / dt  # samples per half period
    empty = (np.empty(0), np.empty(0))
    if not nh >= 4:
        return empty
    L = max(1, round(nh / 10))
    ys = np.convolve(y, np.ones(L) / L, mode="valid")
    dist = max(1, int(0.7 * nh))
    hi, _ = signal.find_peaks(ys, distance=dist)
    lo, _ = signal.find_peaks(-ys, distance=dist)
    idx = np.concatenate([hi, lo])
    kind = np.concatenate([np.ones(hi.size), -np.ones(lo.size)])
    order = np.argsort(idx)
    idx, kind = idx[order], kind[order]
    # keep alternating extrema (the more extreme of two of a kind in a row)
    keep_i: list[int] = []
    keep_k: list[float] = []
    for i, kd in zip(idx, kind, strict=True):
        if keep_k and keep_k[-1] == kd:
            if kd * ys[i] > kd * ys[keep_i[-1]]:
                keep_i[-1] = int(i)
            continue
        keep_i.append(int(i))
        keep_k.append(float(kd))
    w = max(2, round(nh / 5))
    keep = np.array([i for i in keep_i if w <= i < ys.size - w], dtype=int)
    if keep.size == 0:
        return empty
    off = np.arange(-w, w + 1, dtype=float)
    Y = ys[keep[:, None] + off.astype(int)[None, :]]  # (n, 2w + 1)
    a2, a1, a0 = np.polyfit(off, Y.T, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(a2 != 0, -a1 / (2 * a2), 0.0)
    shift = np.clip(shift, -w, w)
    vals = a0 + a1 * shift + a2 * shift**2
    times = t[0] + (keep + shift + 0.5 * (L - 1)) * dt
    small = np.flatnonzero(np.abs(np.diff(vals)) < 20.0 * sd)
    n = small[0] + 1 if small.size else vals.size
    return times[:n], vals[:n]


def _envelope_guess(surveys, P, D, delay, m, c, k, omegas, releases, dm=None, bias=None):
    """Candidate starts (m, c, k, f_c) and per-run offsets from the envelopes.

    Per run, the peak-to-peak heights obey Hₙ₊₁ = ρᵢHₙ − δᵢ (least squares, module
    docstring); the half-cycles last π/ω_dᵢ whatever the friction (each is a linear oscillation
    about a shifted equilibrium), so ω_dᵢ comes from the extrema's times, and the viscous part
    of the decay is σᵢ = −ln(ρᵢ)ω_dᵢ/π. Candidates, each with f_c the median of
    δᵢ(k + Pᵢ)/(2(1 + ρᵢ)):

    1. the given m, k with c the median of 2(m + Δmᵢ)σᵢ − c′ᵢ (eq. 35, c′ᵢ from eq. 32; Δmᵢ
       the known added masses);
    2. m, c, k from the paper's lines through (σᵢ, ω_dᵢ) (eqs. 32–35,
       :func:`phoid.methods.pho.fit_lines`), when three runs with two gain pairs have enough peaks.

    A run's known bias bᵢ cancels part of the friction while it slides, so its envelope gives
    f_c − bᵢ: bᵢ is added back. Without such runs, the given (m, c, k) with f_c = 0. The offset
    of run i is the median of
    (pₙ + 2pₙ₊₁ + pₙ₊₂)/4 over successive extrema pₙ (exact for an envelope linear over a
    cycle; nan with fewer than 3 extrema).
    """
    rows = []
    offsets = np.full(len(surveys), math.nan)
    dm = np.zeros(len(surveys)) if dm is None else np.asarray(dm, dtype=float)
    bs = np.zeros(len(surveys)) if bias is None else np.asarray(bias, dtype=float)
    for i, (s, Pi, Di, om, tau) in enumerate(zip(surveys, P, D, omegas, releases,
                                                  strict=True)):
        if not (om > 0 and math.isfinite(om)):
            continue
        post = s.t > tau
        te, p = _extrema(s.t[post], s.y[post], om, s.sd)
        if p.size >= 3:
            offsets[i] = float(np.median((p[:-2] + 2.0 * p[1:-1] + p[2:]) / 4.0))
        H = np.abs(np.diff(p))
        if H.size < 4:
            continue
        A = np.c_[H[:-1], -np.ones(H.size - 1)]
        (rho, delta), *_ = np.linalg.lstsq(A, H[1:], rcond=None)
        half = float(np.polyfit(np.arange(te.size), te, 1)[0])
        if 0 < rho < 1.5 and half > 0:
            om = math.pi / half
            rows.append((-math.log(rho) * om / math.pi, om, Pi, Di, rho, delta, dm[i], bs[i]))
    if not rows:
        return [np.array([m, c, k, float(np.min(bs)) if bs.size else 0.0])], offsets
    sig, om, Pr, Dr, rho, delta, dmr, br = (np.array(a) for a in zip(*rows, strict=True))

    def fc_for(kk):
        return max(float(np.median(delta * (kk + Pr) / (2.0 * (1.0 + rho)) + br)), 0.0)

    cp, _ = inverse_map(sig, om, Pr, Dr, delay)
    c1 = float(np.median(2.0 * (m + dmr) * sig - cp))
    out = [np.array([m, c1, k, fc_for(k)])]
    if sig.size >= 3 and np.unique(np.c_[Pr, Dr], axis=0).shape[0] >= 2:
        try:
            lines = fit_lines(sig, om, Pr, Dr, delay, added_mass=dmr)
            if lines.m > 0 and math.isfinite(lines.c) and math.isfinite(lines.k):
                out.append(np.array([lines.m, lines.c, lines.k, fc_for(lines.k)]))
        except (ValueError, np.linalg.LinAlgError):
            pass
    return out, offsets
