"""The adequacy of a Coulomb + viscous free-decay fit (:mod:`phoid.methods.free_friction`): the
checks of :mod:`phoid.methods.adequacy` applied to the joint friction fit of
:func:`phoid.methods.free_friction_fit.fit_free_friction`, and the covariance of
(σ, ω₀², f_c/m) that survives a misfit. It follows :mod:`phoid.methods.free_adequacy` (the
viscous fit's) check for check:

- ``noise`` and ``whiteness`` on each release's residual, the noise level its model-free one
  (third differences over the window);
- no ``structure`` check: its windows fit the viscous model, whose rising decay rate at small
  amplitude is what the friction model explains (the evidence against the viscous fit,
  :class:`~phoid.methods.free_friction.FreeFrictionEvidence`, measures it);
- ``halves``: every release's window cut at its middle sample, the first halves refitted jointly
  with the friction model and the second halves jointly (each started at the whole fit's
  (σ, ω₀², a) and its motion's state at the half's first sample), compared on (ω₀, ζ) with
  their robust covariances — only where the second half still holds motion (the whole fit's
  motion there at least 50 noise sd in norm, so not a mass already stuck), each half holds at
  least 2 velocity zeros and both determine ω₀ to better than 5 %;
- ``runs``: each release refitted alone, compared the same way (sets of two runs or more).

The robust covariance is the Newey–West sandwich (:func:`phoid.methods.adequacy.sandwich`; the
Jacobian in (σ, ω₀², a) with each release's offset and state projected off, each release
weighted by its residual variance as in the fit), raised to at least the white one, plus the
halves' spread d dᵀ/2 where they disagree and the covariance of the runs' mean where the runs
disagree, both mapped from (ω₀, ζ) to (σ, ω₀²) at the whole fit (f_c/m is widened by the
sandwich alone), exactly as the viscous fit's (docs/adequacy.md). Where no halves are compared
(the second half's mass already stuck) and the model misfits, the windows' spread of ω₀² is
added when their frequency trends with the amplitude (:func:`_frequency_drift`): the friction
model's frequency is constant, a spring's that stiffens or softens is not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from phoid.methods import adequacy as aq
from phoid.methods._modal import Segment, window_rates
from phoid.methods.free_adequacy import agreement_words, rates_agreement
from phoid.methods.free_friction_fit import (
    FrictionProblem,
    FrictionSolution,
    ReleaseWindow,
    fit_free_friction,
)

__all__ = ["assess_free_friction", "friction_sandwich"]

#: fewest samples of a half
_MIN_HALF = 16
#: least motion (its norm, in noise sd) in the second half for the halves to be compared
_MIN_SNR = 50.0
#: largest relative stderr of ω₀ (white) of a part compared
_MAX_REL = 0.05
#: fewest velocity zeros of a part (f_c/m is not determined by less)
_MIN_TURNS = 2

_NAMES = ("sigma", "k_over_m", "fc_over_m")


def friction_sandwich(sol: FrictionSolution) -> np.ndarray:
    """The Newey–West covariance of (σ, ω₀², a) of a friction fit (each release weighted by
    its residual variance, its offset and state projected off)."""
    return aq.sandwich(sol.jac, sol.resid, weights=[1.0 / v for v in sol.resid_var],
                       nuisance=sol.jac_own)


def _w_zeta_jac(theta: np.ndarray) -> np.ndarray:
    """∂(ω₀, ζ)/∂(σ, ω₀², a)."""
    sigma, w0sq = float(theta[0]), float(theta[1])
    w0 = math.sqrt(w0sq)
    return np.array([[0.0, 0.5 / w0, 0.0], [1.0 / w0, -sigma / (2 * w0**3), 0.0]])


def _part(windows: list[ReleaseWindow], theta: np.ndarray) -> tuple[np.ndarray,
                                                                    np.ndarray] | None:
    """Refit the friction model on other windows from ``theta``: ((ω₀, ζ), their robust
    covariance), or None where the part does not determine them (module docstring)."""
    prob = FrictionProblem(windows=tuple(windows), sigma=float(theta[0]),
                           w0sq=float(theta[1]))
    try:
        f = fit_free_friction(prob, start=np.asarray(theta, dtype=float))
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not f.theta[1] > 0 or min(m.turns.size for m in f.motions) < _MIN_TURNS:
        return None
    if not math.sqrt(max(float(f.cov_white[1, 1]), 0.0)) / f.theta[1] < 2 * _MAX_REL:
        return None
    cov = aq.not_below_white(friction_sandwich(f), f.cov_white)
    if not np.all(np.isfinite(cov)):
        return None
    J = _w_zeta_jac(f.theta)
    w0 = math.sqrt(float(f.theta[1]))
    return np.array([w0, float(f.theta[0]) / w0]), J @ cov @ J.T


def _window(w: ReleaseWindow, sel: slice, sol: FrictionSolution, j: int) -> ReleaseWindow:
    """Release ``j``'s window cut to ``sel``, started at the whole fit's state there."""
    mot = sol.motions[j]
    k = sel.start or 0
    return ReleaseWindow(t=w.t[sel], x=w.x[sel], noise=w.noise, offset=float(sol.own[j, 0]),
                         y0=float(mot.y[k]), v0=float(mot.v[k]))


def _frequency_drift(windows: Sequence[ReleaseWindow], sol: FrictionSolution
                     ) -> np.ndarray | None:
    """Where no halves are compared (the second half already stuck) but the model misfits: the
    spread of ω₀² over windows of a few cycles when the windows' frequency trends with their
    amplitude (an amplitude-dependent stiffness, which the Coulomb + viscous model does not
    have and no sandwich covers), as a covariance of (σ, ω₀², a) with only its ω₀² entry; None
    when the windows show no significant trend (|slope|/stderr ≤ T_SLOPE, the structure
    check's threshold) or are too few."""
    theta = sol.theta
    amp: list[np.ndarray] = []
    om: list[np.ndarray] = []
    se: list[np.ndarray] = []
    for w, m in zip(windows, sol.motions, strict=True):
        seg = Segment(t=w.t, x=w.x, fixed=np.ones((w.t.size, 1)), t0=float(w.t[0]))
        a, _s, _sse, o, ose = window_rates(seg, m.y, float(theta[0]), float(theta[1]), w.noise)
        amp.append(a)
        om.append(o)
        se.append(ose)
    a, o, e = (np.concatenate(v) for v in (amp, om, se))
    ok = np.isfinite(a) & np.isfinite(o) & np.isfinite(e) & (e > 0)
    a, o, e = a[ok], o[ok], e[ok]
    if a.size < 3 or np.ptp(a) == 0:
        return None
    # weighted least squares o = c₀ + b·a, the slope's stderr scaled by √max(1, χ²/dof)
    X = np.column_stack([np.ones_like(a), a]) / e[:, None]
    coef, *_ = np.linalg.lstsq(X, o / e, rcond=None)
    r = o / e - X @ coef
    scale = max(1.0, float(r @ r) / (a.size - 2))
    cov = np.linalg.inv(X.T @ X) * scale
    if not abs(float(coef[1])) > aq.T_SLOPE * math.sqrt(float(cov[1, 1])):
        return None
    out = np.zeros((3, 3))
    out[1, 1] = float(np.var(o**2, ddof=1))
    return out


def assess_free_friction(windows: Sequence[ReleaseWindow], sol: FrictionSolution,
                         labels: Sequence[str], *, x_unit: str = "m") -> aq.Adequacy:
    """The adequacy of a joint friction fit (module docstring).

    Parameters
    ----------
    windows : sequence of ReleaseWindow
        The releases as fitted (their ``noise``: the model-free noise level).
    sol : FrictionSolution
        :func:`~phoid.methods.free_friction_fit.fit_free_friction` on ``windows``.
    labels : sequence of str
        The releases' names, for the words.
    x_unit : str
        x's unit, for the words.

    Returns
    -------
    phoid.methods.adequacy.Adequacy
        Its covariances are of (σ, ω₀², f_c/m), in 1/s, 1/s² and x's unit per s².
    """
    from phoid.io.units import quantity_unit

    windows = list(windows)
    resid = list(sol.resid)
    rms = [float(np.sqrt(np.mean(m.y * m.y))) for m in sol.motions]
    noise = [w.noise for w in windows]
    units = ("1/s", "1/s^2", quantity_unit("m/s^2", x_unit))
    noise_c = aq.noise_check(resid, noise, labels, x_unit=x_unit)
    white = aq.whiteness_check(resid, motion_rms=rms)
    checks = [noise_c, white]
    exact = white.passed is None
    sw = friction_sandwich(sol) if not exact else np.full((3, 3), math.nan)
    theta = sol.theta
    if exact or not theta[1] > 0:
        return aq.assess(checks, names=_NAMES, units=units, white_cov=sol.cov_white,
                         sandwich_cov=sw)
    peak = None
    q = float(theta[1] - theta[0] ** 2)
    if noise_c.passed is False or white.passed is False:
        for w, r in zip(windows, resid, strict=True):
            dt = float(np.median(np.diff(w.t)))
            fs = [math.sqrt(q) / (2 * math.pi)] if q > 0 else []
            spec = np.abs(np.fft.rfft(w.x - w.x.mean())) ** 2
            fs.append(float(np.fft.rfftfreq(w.x.size, dt)[1 + int(np.argmax(spec[1:]))]))
            peak = aq.spectral_peak(r, dt, (min(fs), max(fs)))
            if peak is not None:
                break
    r_causes, r_warns = aq.residual_warnings(noise_c, white, (), peak)
    causes, warns = list(r_causes), list(r_warns)
    # "coloured": in this fit's words (the amplitude trend is not tested here)
    warns = [f"the residual of the friction fit is not white noise ({white.detail}): coloured "
             "noise (a filtered sensor, a slow disturbance) or a misfit the Coulomb + viscous "
             "model leaves (amplitude-dependent stiffness or damping); the stderr are "
             "Newey–West ones that account for it" if c == "coloured" else w
             for c, w in zip(causes, warns, strict=True)]
    w0 = math.sqrt(float(theta[1]))
    # ∂(σ, ω₀², a)/∂(ω₀, ζ) at the whole fit (σ = ζω₀); a is not mapped
    Jb = np.array([[float(theta[0]) / w0, w0], [2 * w0, 0.0], [0.0, 0.0]])
    between: list[np.ndarray] = []
    agreements = []
    mids = [w.t.size // 2 for w in windows]
    snr2 = math.sqrt(sum(float(m.y[k:] @ m.y[k:]) / w.noise**2
                         for m, k, w in zip(sol.motions, mids, windows, strict=True)))
    if min(w.t.size for w in windows) >= 2 * _MIN_HALF and snr2 >= _MIN_SNR:
        halves = [_part([_window(w, slice(0, k), sol, j) for j, (w, k) in
                         enumerate(zip(windows, mids, strict=True))], theta),
                  _part([_window(w, slice(k, None), sol, j) for j, (w, k) in
                         enumerate(zip(windows, mids, strict=True))], theta)]
        ag = rates_agreement("halves", halves, ("first half", "second half"), of_mean=False)
        if ag is not None:
            checks.append(ag.check)
            agreements.append(ag)
            if ag.check.passed is False:
                between.append(Jb @ ag.between @ Jb.T)
    if not agreements and noise_c.passed is False:
        drift = _frequency_drift(windows, sol)
        if drift is not None:
            between.append(drift)
    if len(windows) >= 2:
        parts = [_part([_window(w, slice(0, None), sol, j)], theta)
                 for j, w in enumerate(windows)]
        ag = rates_agreement("runs", parts, labels)
        if ag is not None:
            checks.append(ag.check)
            agreements.append(ag)
            if ag.check.passed is False:
                between.append(Jb @ ag.between @ Jb.T)
    a_causes, a_warns = agreement_words(agreements)
    causes += a_causes
    warns += a_warns
    return aq.assess(checks, names=_NAMES, units=units, white_cov=sol.cov_white,
                     sandwich_cov=sw, between=between, causes=causes, warnings=warns)
