r"""The adequacy of the in-loop output-error fit (:mod:`phoid.methods.inloop`): the checks of
:mod:`phoid.methods.adequacy` over its residuals, and the covariance that survives a misfit.

- ``noise``: each run's residual against the record's own noise over its window (third
  differences, :func:`phoid.methods.fit_statistics.difference_noise`): with the right model
  and the noise in the loop the residual is the sensor noise itself;
- ``whiteness``: the Ljung–Box test of the residuals (the sensor noise is white; a misfit —
  a wrong delay, friction, a second mode — leaves a slow, correlated residual);
- ``runs``: each run fitted alone (started from the joint estimate; a few iterations), the χ²
  of their (m, c, k) against each one's covariance (:func:`phoid.methods.adequacy.agreement`);
- ``halves``: every run's window cut in two, the first halves fitted together and the second
  halves together (each half its own start state), their agreement.

The refits start at the joint estimate and stop when a step moves θ by less than 0.01 of its
stderr, or after 20 iterations (a refit moves θ by a few of its stderr, which Gauss–Newton
covers in two or three). A part whose relative
stderr exceeds 20 % on any parameter is left out of its χ² (outside the linear regime in which
the covariance, and the χ², hold). Where every check passes the fit's own covariance stands;
where one fails the reported covariance is the Newey–West sandwich of the residuals (the
Jacobians already have the nuisances projected off) widened by the spread between the parts
that disagree (:func:`phoid.methods.adequacy.assess`), with the warning in the user's terms.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from phoid.errors import IdentificationError
from phoid.methods import adequacy as aq
from phoid.methods.free_adequacy import agreement_words
from phoid.methods.inloop import InLoopFit, fit_inloop
from phoid.methods.inloop_model import RunWindow

__all__ = ["assess_inloop"]

#: most iterations of a part's refit
_REFIT_ITER = 20
#: a part's refit has converged when a step moves it by less than this many of its stderr
#: (its χ² of agreement is then right to ~2 %)
_REFIT_TOL = 1e-2
#: a part pinning a parameter down to worse than this (relative stderr) is left out
_MAX_REL = 0.2
#: a residual below this fraction of the motion's RMS is rounding (noise-free records)
_EXACT = 1e-5
#: the encoder's count q is coarse when its uniform variance q²/12 exceeds this share of the
#: residual's variance: its error then follows the position instead of dithering into noise
_COARSE = 0.25


def encoder_count(windows: Sequence[RunWindow]) -> float | None:
    """The encoder's count q (x's unit) when every recorded position is a whole number of counts
    from the lowest one (to 1e-3 of a count), else None.

    q is the smallest step between distinct recorded values above rounding (1e-9 of max |x|).
    """
    y = np.concatenate([np.asarray(w.y, dtype=float) for w in windows]) if windows else None
    if y is None or y.size < 4 or not np.all(np.isfinite(y)):
        return None
    u = np.unique(y)
    steps = np.diff(u)
    steps = steps[steps > 1e-9 * float(np.max(np.abs(u)))]
    if steps.size == 0:
        return None
    q = float(np.min(steps))
    r = (u - u[0]) / q
    if not np.all(np.abs(r - np.round(r)) < 1e-3):
        return None
    return q


def _quantised(fit: InLoopFit, noise_c: aq.Check, white_c: aq.Check, q: float,
               units: Sequence[str], x_unit: str) -> aq.Adequacy:
    """A record whose encoder count is coarse against its noise: the quantiser's error is a
    function of the position (a mass resting within one count reads one value), neither white
    nor independent of the motion, so the residual's own variance understates the error the
    estimates carry and the whiteness and part-agreement checks (built on white noise) do not
    apply. The covariance takes the error's variance as σ̂² + q²/12 (the residual's plus the
    uniform quantiser's: the bound's σ² = noise² + q²/12 when σ̂ is the noise), and says so."""
    s2 = fit.sigma ** 2
    scale = (s2 + q * q / 12.0) / s2 if s2 > 0 else 1.0
    white = np.asarray(fit.cov, dtype=float) * scale
    whit = aq.Check("whiteness", white_c.statistic, white_c.threshold, None,
                    f"not used: the record is quantised ({white_c.detail})")
    causes, warns = (list(v) for v in aq.residual_warnings(noise_c, whit, (), None))
    warns.append(
        f"the position is quantised in counts of {q:.3g} {x_unit}, coarse against the residual "
        f"noise ({fit.sigma:.3g} {x_unit}): the quantiser's error follows the position rather "
        "than dithering into white noise, so the stderr take its variance q²/12 on top of the "
        "residual's and the whiteness, runs and halves checks are not used")
    failed = noise_c.passed is False
    sand = aq.sandwich(list(fit.jacobians), [np.asarray(e, dtype=float) for e in fit.residuals]
                       ) * scale if failed else white
    return aq.assess([noise_c, whit], names=("m", "c", "k"), units=units, white_cov=white,
                     sandwich_cov=sand, causes=causes, warnings=warns)


def _part_fit(windows: Sequence[RunWindow], theta: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """(θ, cov) of the windows fitted alone from θ; None where that fails or the part
    determines a parameter to worse than 20 %."""
    try:
        f = fit_inloop(windows, [theta], tries=1, max_iter=_REFIT_ITER, step_tol=_REFIT_TOL)
    except (IdentificationError, np.linalg.LinAlgError, ValueError):
        return None
    se = f.stderr
    scale = np.maximum(np.abs(f.theta), np.abs(theta))
    if not (np.all(np.isfinite(f.cov)) and np.all(se < _MAX_REL * np.where(scale > 0, scale,
                                                                           np.inf))):
        return None
    return f.theta, f.cov


def _agreement(name: str, parts: Sequence[tuple[np.ndarray, np.ndarray] | None],
               labels: Sequence[str], units: Sequence[str], of_mean: bool) -> aq.Agreement:
    ok = [i for i, p in enumerate(parts) if p is not None]
    if len(ok) < 2:
        return aq.Agreement(aq.Check(name, math.nan, math.nan, None,
                                     "fewer than two parts could be fitted alone"),
                            np.zeros((3, 3)))
    return aq.agreement(name, [parts[i][0] for i in ok], [parts[i][1] for i in ok],
                        params=("m", "c", "k"), units=units, labels=[labels[i] for i in ok],
                        of_mean=of_mean)


def assess_inloop(fit: InLoopFit, windows: Sequence[RunWindow], labels: Sequence[str], *,
                  units: Sequence[str] = ("kg", "N s/m", "N/m"), x_unit: str = "m"
                  ) -> aq.Adequacy:
    """The adequacy of an in-loop fit (module docstring).

    Parameters
    ----------
    fit : InLoopFit
        The joint fit.
    windows : sequence of RunWindow
        Its windows, in the fit's order.
    labels : sequence of str
        Each window's run name.
    units : sequence of str
        m, c, k's units, for the words.
    x_unit : str
        x's unit, for the words.

    Returns
    -------
    Adequacy
        With ``white_cov`` the fit's own covariance.
    """
    resid = [np.asarray(e, dtype=float) for e in fit.residuals]
    noise: list[float | None] = []
    motion: list[float | None] = []
    exact = True
    for w, e, s in zip(windows, resid, fit.noise, strict=True):
        mot = w.y - e - fit.offset
        mrms = float(np.sqrt(np.mean(mot * mot))) if mot.size else 0.0
        erms = float(np.sqrt(np.mean(e * e))) if e.size else 0.0
        exact_run = erms <= _EXACT * mrms and not erms > 0.5 * s
        exact = exact and exact_run
        noise.append(None if exact_run else s)
        motion.append(mrms)
    white = np.asarray(fit.cov, dtype=float)
    if exact:  # noise-free records: the residual is rounding, nothing to test
        checks = [aq.Check("noise", math.nan, math.nan, None,
                           "not tested (noise-free records: the residual is rounding)"),
                  aq.Check("whiteness", math.nan, aq.ALPHA, None,
                           "not tested (records too short or noise-free)")]
        return aq.assess(checks, names=("m", "c", "k"), units=units, white_cov=white,
                         sandwich_cov=white)
    noise_c = aq.noise_check(resid, noise, labels, x_unit=x_unit)
    white_c = aq.whiteness_check(resid, motion_rms=motion)
    q = encoder_count(windows)
    if q is not None and q * q / 12.0 > _COARSE * fit.sigma ** 2:
        return _quantised(fit, noise_c, white_c, q, units, x_unit)
    theta = fit.theta
    agreements = []
    if len(windows) >= 4:  # two interleaved groups, each with several gain pairs
        groups = [list(range(0, len(windows), 2)), list(range(1, len(windows), 2))]
        names = [f"runs {', '.join(labels[i] for i in g[:3])}{', …' if len(g) > 3 else ''}"
                 for g in groups]
        agreements.append(_agreement("runs", [_part_fit([windows[i] for i in g], theta)
                                              for g in groups], names, units, of_mean=False))
    halves = [w.size // 2 for w in windows]
    if all(hh >= 16 for hh in halves):
        first = _part_fit([w.part(0, hh) for w, hh in zip(windows, halves, strict=True)],
                          theta)
        second = _part_fit([w.part(hh, w.size) for w, hh in zip(windows, halves, strict=True)],
                           theta)
        agreements.append(_agreement("halves", [first, second], ["first half", "second half"],
                                     units, of_mean=False))
    checks = [noise_c, white_c, *(a.check for a in agreements)]
    causes, warns = (list(v) for v in aq.residual_warnings(noise_c, white_c, (), None))
    a_causes, a_warns = agreement_words(agreements)
    causes += a_causes
    warns += a_warns
    between = [a.between for a in agreements if a.check.passed is False]
    failed = any(c.passed is False for c in checks)
    sand = aq.sandwich(list(fit.jacobians), resid) if failed else white
    return aq.assess(checks, names=("m", "c", "k"), units=units, white_cov=white,
                     sandwich_cov=sand, between=between, causes=causes, warnings=warns)
