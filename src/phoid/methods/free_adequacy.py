"""The adequacy of a free-decay fit (:mod:`phoid.methods.free`): the checks of
:mod:`phoid.methods.adequacy` applied to the joint free-response fit of
:func:`phoid.methods._modal.fit_modal`, and the covariance of (σ, ω₀²) that survives a misfit.

- ``noise`` and ``whiteness`` on each run's residual, the noise level from the run's own third
  differences (:func:`phoid.methods.fit_statistics.difference_noise` over the fitted window);
- ``structure``: windows of 4 damped cycles, each fitted alone
  (:func:`phoid.methods._modal.window_rates`), their σ and ω_d against their amplitude; a run
  that ends still while the model still swings, or away from the fitted rest, is "stuck";
- ``halves``: every run's window cut at its middle sample, the first halves fitted jointly and
  the second halves jointly (started at the whole fit's rates), compared on (ω₀, ζ) with their
  robust covariances — only where the second half still holds motion (its norm at least 50
  noise sd) and both halves determine ω₀ to better than 5 % (an overdamped decay is gone into
  the noise by its second half: a fit there finds a mode in the noise, outside the linear
  regime in which a covariance means anything);
- ``runs``: each run fitted alone, compared the same way (sets of two runs or more).

The robust covariance is the Newey–West sandwich of the rates (the Jacobian in (σ, ω₀²) with
each run's offset and state projected off, each run weighted as in the fit), raised to at least
the white one, plus the halves' spread (the part of d dᵀ, for halves differing by d, that their
own covariances C₁ + C₂ do not explain) where the model misfits the record (the residual above
its noise), the halves disagree or the windows show a trend (the windows' own spread of
(σ, ω₀²) where there are no halves to compare), plus the covariance of the runs' mean where
they disagree (mapped from (ω₀, ζ) to (σ, ω₀²) at the whole fit). A run that ends stuck while
the model still swings names Coulomb friction where the windows and the envelope are too few to
test it. docs/adequacy.md gives the reasons and the measurements.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from phoid.errors import IdentificationError
from phoid.methods import adequacy as aq
from phoid.methods._modal import ModalFit, Segment, fit_modal, window_rates
from phoid.methods.fit_statistics import difference_noise

__all__ = ["agreement_words", "assess_free", "rates_agreement"]

#: fewest samples of a half
_MIN_HALF = 16
#: least motion (its norm, in noise sd) in the second half for the halves to be compared
_MIN_SNR = 50.0
#: largest relative stderr of ω₀ (white) of a part compared (halves, runs)
_MAX_REL = 0.05
#: the halves' spread added to a misfit's covariance: d dᵀ for halves differing by d, twice
#: their sample covariance d dᵀ/2 (a one-dof variance estimate: d dᵀ/2 falls below the
#: variance it estimates more than half the time, by a factor 0.45 at its median; d dᵀ is
#: about it at its median, docs/adequacy.md)
_SPREAD = 2.0


def _rates_cov(fit: ModalFit) -> np.ndarray:
    """The Newey–West covariance of (σ, ω₀²) of a modal fit (each run weighted as fitted, its
    offset and state projected off)."""
    return aq.sandwich(fit.jac, fit.resid, weights=[1.0 / s**2 for s in fit.noise],
                       nuisance=fit.design)


def _w_zeta(sigma: float, w0sq: float, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ω₀, ζ) and their covariance from (σ, ω₀²) (delta method; ω₀² > 0)."""
    w0 = math.sqrt(w0sq)
    J = np.array([[0.0, 0.5 / w0], [1.0 / w0, -sigma / (2 * w0**3)]])
    return np.array([w0, sigma / w0]), J @ cov @ J.T


def _excess(spread: np.ndarray, own: np.ndarray) -> np.ndarray:
    """The part of the halves' spread d dᵀ their own covariances C₁ + C₂ do not explain: the
    positive part of d dᵀ − (C₁ + C₂) (negative eigenvalues set to 0).

    Halves that differ only by their noise (white or coloured: E[d dᵀ] = C₁ + C₂ when each
    half's robust covariance is right) add nothing beyond the sandwich, so coloured noise is
    not counted twice; halves that drift apart by far more than their noise add about d dᵀ.
    """
    e = np.asarray(spread, dtype=float) - np.asarray(own, dtype=float)
    w, v = np.linalg.eigh(0.5 * (e + e.T))
    return (v * np.clip(w, 0.0, None)) @ v.T


def rates_agreement(name: str, parts: Sequence[tuple[np.ndarray, np.ndarray] | None],
                    labels: Sequence[str], *, of_mean: bool = True) -> aq.Agreement | None:
    """The χ² of consistency (:func:`phoid.methods.adequacy.agreement`) of parts of a free
    set fitted alone — the halves of its records, or its runs — on (ω₀, ζ) with their robust
    covariances; None where fewer than two parts could be fitted (a part that could not is
    left out). Shared by the viscous and the friction fit's adequacy."""
    ok = [i for i, p in enumerate(parts) if p is not None]
    if len(ok) < 2:
        return None
    return aq.agreement(name, [parts[i][0] for i in ok], [parts[i][1] for i in ok],
                        params=("ω₀", "ζ"), units=("rad/s", ""),
                        labels=[labels[i] for i in ok], of_mean=of_mean)


def agreement_words(agreements: Sequence[aq.Agreement]) -> tuple[list[str], list[str]]:
    """The causes ("drift" for halves, "runs_differ" for runs) and warnings of the
    agreements that failed, in order."""
    causes: list[str] = []
    warns: list[str] = []
    for ag in agreements:
        w = ag.warning()
        if w is not None:
            causes.append("drift" if ag.check.name == "halves" else "runs_differ")
            warns.append(w)
    return causes, warns


def _part(segs: list[Segment], fit: ModalFit,
          noise: Sequence[float]) -> tuple[np.ndarray, np.ndarray] | None:
    """Refit the rates on other windows (started at ``fit``'s, each run's starting noise
    ``noise``): ((ω₀, ζ), their robust covariance)."""
    try:
        f = fit_modal(segs, fit.sigma, fit.w0sq, noise=list(noise))
    except (IdentificationError, np.linalg.LinAlgError):
        return None
    if not (f.w0sq > 0 and np.all(np.isfinite(f.cov))):
        return None
    # a part that pins ω₀ down to worse than 5 % (a decay gone into the noise by then) is
    # outside the linear regime in which its covariance, and the χ² of agreement, hold
    if not math.sqrt(max(float(f.cov[1, 1]), 0.0)) / f.w0sq < 2 * _MAX_REL:
        return None
    cov = aq.not_below_white(_rates_cov(f), f.cov)
    if not np.all(np.isfinite(cov)):
        return None
    return _w_zeta(f.sigma, f.w0sq, cov)


def _stuck(seg: Segment, motion: np.ndarray, offset: float, noise: float, x_unit: str) -> str:
    """Where a run ends at rest while the fitted motion still swings, in words ("" if not):
    its last tenth (≥ 16 samples) within 8 noise sd while the model's amplitude there is above
    10 noise sd, or its level more than 5 noise sd off the fitted rest."""
    k = max(16, seg.t.size // 10)
    tail = seg.x[-k:]
    if seg.t.size < 4 * k or not np.ptp(tail) <= 8 * noise:
        return ""
    amp = math.sqrt(2.0 * float(np.mean(motion[-k:] ** 2)))
    off = float(np.mean(tail)) - offset
    if amp > 10 * noise or abs(off) > 5 * noise:
        return (f"still over its last {seg.t[-1] - seg.t[-k]:.3g} s, {off:.3g} {x_unit} off "
                f"the fitted rest, where the model still swings {amp:.3g} {x_unit}")
    return ""


def _envelope(segs: Sequence[Segment], fit: ModalFit,
              noise: Sequence[float]) -> aq.Envelope | None:
    """The envelope test (:func:`phoid.methods.adequacy.envelope_test`) on the run with the
    most turning points above 10 noise sd, about its fitted offset."""
    q = fit.w0sq - fit.sigma**2
    if not q > 0:
        return None
    best: aq.Envelope | None = None
    for s, c, nz in zip(segs, fit.coef, noise, strict=True):
        if not nz > 0:
            continue
        tk, pk, sk = aq.turning_points(s.t, s.x, float(c[0]), math.sqrt(q), nz)
        env = aq.envelope_test(tk, pk, sk)
        if env is not None and (best is None or env.n > best.n):
            best = env
    return best


def assess_free(segs: Sequence[Segment], fit: ModalFit, labels: Sequence[str], *,
                x_unit: str = "m") -> aq.Adequacy:
    """The adequacy of a joint free-response fit (module docstring).

    Parameters
    ----------
    segs : sequence of Segment
        The runs' windows as fitted (fixed columns: the offset).
    fit : ModalFit
        :func:`phoid.methods._modal.fit_modal` on ``segs``.
    labels : sequence of str
        The runs' names, for the words.
    x_unit : str
        x's unit, for the words.

    Returns
    -------
    phoid.methods.adequacy.Adequacy
        Its covariances are of (σ, ω₀²), 1/s and 1/s².
    """
    segs = list(segs)
    resid = list(fit.resid)
    motions = [s.x - c[0] - r for s, c, r in zip(segs, fit.coef, resid, strict=True)]
    rms = [float(np.sqrt(np.mean(m * m))) for m in motions]
    noise = [difference_noise(s.x) for s in segs]
    noise_c = aq.noise_check(resid, noise, labels, x_unit=x_unit)
    white = aq.whiteness_check(resid, motion_rms=rms)
    names, units = ("sigma", "k_over_m"), ("1/s", "1/s^2")
    exact = white.passed is None
    checks = [noise_c, white]
    sw = _rates_cov(fit) if not exact else np.full((2, 2), math.nan)
    q = fit.w0sq - fit.sigma**2
    if exact or not fit.w0sq > 0:
        return aq.assess(checks, names=names, units=units, white_cov=fit.cov, sandwich_cov=sw)
    # structure: windows of 4 cycles, all runs together
    cols: list[list[np.ndarray]] = [[], [], [], [], []]
    stuck = ""
    for s, m, c, nz in zip(segs, motions, fit.coef, noise, strict=True):
        nz = nz if nz > 0 else float(np.std(s.x - m - c[0]))
        for j, col in enumerate(window_rates(s, m, fit.sigma, fit.w0sq, nz)):
            cols[j].append(col)
        stuck = stuck or _stuck(s, m, float(c[0]), nz, x_unit)
    win = aq.Windows(*(np.concatenate(c) for c in cols), stuck=bool(stuck),
                     stuck_detail=stuck)
    struct, s_causes, s_warns = aq.structure_check(win, x_unit=x_unit,
                                                   envelope=_envelope(segs, fit, noise))
    if stuck and "coulomb" not in s_causes:
        # too few cycles for the windows or the envelope (a spring–mass that sticks after one
        # or two): the stop itself is the evidence — a viscous decay never stops while its
        # model still swings, a Coulomb one does (the pho method's rule, pho_adequacy)
        s_causes = ("coulomb", *s_causes)
        s_warns = (f"the motion ends stuck ({stuck}): Coulomb friction (linear amplitude "
                   "loss, sticking), not viscous damping; try `phoid identify SET --friction`",
                   *s_warns)
        struct = aq.Check("structure", struct.statistic, struct.threshold, False,
                          "; ".join(x for x in (struct.detail, f"ends stuck: {stuck}") if x))
    peak = None
    if (noise_c.passed is False or white.passed is False) and not s_causes:
        for s, r in zip(segs, resid, strict=True):
            dt = float(np.median(np.diff(s.t)))
            # the band the motion sweeps: the fit's ω_d, the record's own spectral peak and
            # the windows' local ω_d
            spec = np.abs(np.fft.rfft(s.x - s.x.mean())) ** 2
            fs = [math.sqrt(q) / (2 * math.pi)] if q > 0 else []
            fs.append(float(np.fft.rfftfreq(s.x.size, dt)[1 + int(np.argmax(spec[1:]))]))
            fs += list(win.omega / (2 * math.pi))
            peak = aq.spectral_peak(r, dt, (min(fs), max(fs)))
            if peak is not None:
                break
    r_causes, r_warns = aq.residual_warnings(noise_c, white, s_causes, peak)
    checks.append(struct)
    # halves: every run's first half of its window fitted jointly, then the second halves
    between: list[np.ndarray] = []
    Jb = np.array([[fit.sigma / math.sqrt(fit.w0sq), math.sqrt(fit.w0sq)],
                   [2 * math.sqrt(fit.w0sq), 0.0]])  # ∂(σ, ω₀²)/∂(ω₀, ζ)
    agreements = []
    firsts = [Segment(t=s.t[: s.t.size // 2], x=s.x[: s.t.size // 2],
                      fixed=s.fixed[: s.t.size // 2], t0=s.t0) for s in segs]
    seconds = [Segment(t=s.t[s.t.size // 2:], x=s.x[s.t.size // 2:],
                       fixed=s.fixed[s.t.size // 2:], t0=float(s.t[s.t.size // 2]))
               for s in segs]
    # the second half's motion (of the whole fit) in noise sd, all runs together
    # (the noise from the record's third differences: the fit's residual sd holds the misfit)
    snr2 = math.sqrt(sum(float(m[m.size // 2:] @ m[m.size // 2:]) / max(nz, fn * 1e-6)**2
                         for m, nz, fn in zip(motions, noise, fit.noise, strict=True)))
    halves = [_part(h, fit, fit.noise) for h in (firsts, seconds)] \
        if min(s.t.size for s in segs) >= 2 * _MIN_HALF and snr2 >= _MIN_SNR else [None]
    ag = rates_agreement("halves", halves, ("first half", "second half"), of_mean=False) \
        if len(halves) == 2 else None
    if ag is not None:
        checks.append(ag.check)
        agreements.append(ag)
        if ag.check.passed is False or struct.passed is False or noise_c.passed is False:
            # the halves' spread d dᵀ (= 2S, S their sample covariance d dᵀ/2): the model
            # misfits or the parameters drift, so the value depends on which part of the
            # record the fit weighs (module docstring)
            # the part of the halves' spread their own covariances do not explain (with the
            # residual's size alone failing, coloured noise looks the same as a misfit that
            # drifts below the halves' test: a gate per parameter then misses a real record's
            # drift, docs/adequacy.md; the excess over C₁ + C₂ keeps coloured noise near its
            # sandwich for ω₀, conservative for σ)
            extra = _excess(_SPREAD * ag.between, halves[0][1] + halves[1][1])
            between.append(Jb @ extra @ Jb.T)
    elif struct.passed is False and win.sigma.size >= 2:
        # a trend along the record and no halves to measure it: the windows' own spread of
        # (σ, ω₀² = ω_d² + σ²), the range the parameters sweep
        between.append(np.cov(np.vstack([win.sigma, win.omega**2 + win.sigma**2])))
    if len(segs) >= 2:
        parts = [_part([s], fit, [nz]) for s, nz in zip(segs, fit.noise, strict=True)]
        ag = rates_agreement("runs", parts, labels)
        if ag is not None:
            checks.append(ag.check)
            agreements.append(ag)
            if ag.check.passed is False:
                between.append(Jb @ ag.between @ Jb.T)
    causes = list(r_causes) + list(s_causes)
    warns = list(r_warns) + list(s_warns)
    if "coulomb" in causes:
        # the cause the user can act on first (`--friction`), its warning with it
        j = causes.index("coulomb")
        causes.insert(0, causes.pop(j))
        warns.insert(0, warns.pop(len(r_warns) + s_causes.index("coulomb")))
    a_causes, a_warns = agreement_words(agreements)
    causes += a_causes
    warns += a_warns
    return aq.assess(checks, names=names, units=units, white_cov=fit.cov, sandwich_cov=sw,
                     between=between, causes=causes, warnings=warns)
