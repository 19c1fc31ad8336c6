r"""The stated command delay of a tracking set, and the estimates, checked against the record.

:func:`check_delay` fits the loop by output error with the delay free (docs/design-notes/
tracking-validation.md, "The stated delay, checked"): the delay the record implies, its
Newey–West stderr, and whether the stated one is contradicted. The search starts over
[0, stated + 5T] and widens geometrically (×2 beyond the stated delay) while the fit ends on the
range's upper end, up to half the shortest run's length (:data:`DELAY_RANGE`): a command that
reaches the plant after half the record has passed leaves too little of it to read a delay
from, and :func:`~phoid.methods.tracking_identification.run_controller` refuses a delay longer
than the record. A fit that still ends on that bound, or that does not converge, is compared
with the loop fitted at the stated delay: a misfit :data:`MISFIT_GAIN` times smaller away from
it contradicts the stated delay as well.

:func:`delay_warnings` turns the check into warnings (naming ``[loop] delay`` or ``--delay``,
telling a delay that the record contradicts from a loop model that does not follow the record
at all), :func:`gross_misfit` says when a position misfit is gross, and
:func:`estimator_disagreement` compares IDIM's estimates with the check's output-error fit, and
:func:`idim_noise_hint` names the position noise where IDIM's estimates cannot be simulated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from phoid.methods.chi2 import chi2_isf
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import difference_noise
from phoid.methods.tracking import UNITS, TrackingFit, TrackingRecord, fit_tracking_runs

__all__ = [
    "DELAY_RANGE",
    "DELAY_SEARCH",
    "DELAY_Z",
    "ESTIMATOR_ALPHA",
    "GROSS_RATIO",
    "GROSS_TRACKING",
    "MISFIT_GAIN",
    "DelayCheck",
    "check_delay",
    "delay_warnings",
    "estimator_disagreement",
    "gross_misfit",
    "idim_noise_hint",
    "misfit_warning",
    "validation_misfit",
]

# the first range searched beyond the stated delay, controller periods
DELAY_SEARCH = 5
# the widest range searched: this fraction of the shortest run's length (module docstring)
DELAY_RANGE = 0.5
# the most evaluations each of the check's fits may take: it starts at the stated delay's
# parameters and converges in 4–25 on the test records and EMPS; one that has not converged by
# then is wandering on a record the loop model does not follow (r and x in different units:
# 200 evaluations, 16 s, before the limit), where no delay can be read from it
_CHECK_NFEV = 60
# stderrs of the implied delay from the stated one above which the record contradicts it: the
# Newey–West stderrs of a persistent residual can be ≈ 2× short (docs/design-notes/tracking.md),
# so 5 of them are ≥ 2.5 true ones, and for a white residual a normal deviate exceeds 5 with
# probability 6e-7 (the project's "5 stderr" of the recorded u's scale, phoid.methods.udelay)
DELAY_Z = 5.0
# the rms misfit at the stated delay over that at a delay the search could not resolve (on the
# widest range's end, or a fit that did not converge) above which the stated delay is
# contradicted: freeing one parameter (the delay) of a right model lowers the sum of squares
# by about σ²·χ²₁, a fraction ≈ 1/n_eff of it (n_eff ≥ 20 on every record tried, even with the
# residual's lag-1 autocorrelation ≈ 0.9); a rms halved is a sum of squares quartered
MISFIT_GAIN = 2.0
# a gross misfit of the loop: a position residual GROSS_RATIO times the record's noise (with a
# right model the ratio is 1 ± 1.7/√n, phoid.methods.fit_statistics: 10 is beyond any chance
# for n ≥ 10; model error is ≥ 99 % of the residual's power) that is also more than
# GROSS_TRACKING % of the tracking error x − r (what the loop did not follow). Both: a
# quantised real record leaves a residual ≫ its noise with a model right to 0.3 % of its
# tracking error (EMPS: 97 times its noise, 0.28 %), and a very noisy one a residual near the
# size of its tracking error that is only its noise; a right model misses 0.3–1 % (EMPS and
# the test records), a wrong gain or unit 50–100 %
GROSS_RATIO = 10.0
GROSS_TRACKING = 10.0
# the false-alarm probability of the test of IDIM's estimates against output error's
# (:func:`estimator_disagreement`): over the p parameters both fitted, d = θ_IDIM − θ_OE is
# tested jointly, d'(C_IDIM + C_OE)⁻¹d against χ²_p's upper ESTIMATOR_ALPHA/2 quantile (25.0 for
# p = 4), and per parameter, |d_i| in combined stderrs √(se_IDIM² + se_OE²) against the normal's
# two-sided ESTIMATOR_ALPHA/(2p) quantile (4.37 for p = 4): the union's false-alarm rate is at
# most ESTIMATOR_ALPHA (Bonferroni). The joint test adds up evidence spread over the parameters;
# the per-parameter one keeps its power where noise biases one parameter (the mass, errors in
# variables), which the joint one dilutes over p degrees of freedom (probe K: m 4.6 combined
# stderrs off, the others < 1, joint 21 < χ²₄'s 23.5 at 10⁻⁴). Both use C_IDIM + C_OE: the two
# are fits of the same record, so their estimates are positively correlated; where output error
# is the efficient one, Cov(θ_IDIM, θ_OE) = C_OE (Hausman) and Var(d) = C_IDIM − C_OE ≤ C_IDIM +
# C_OE, so each statistic is at most the one with the true Var(d) and each false-alarm rate at
# most its share. 10⁻⁴ is small because IDIM's OLS stderrs may be short on an autocorrelated
# residual (right records: 1.2–1.4 combined stderrs; EMPS: no warning).
ESTIMATOR_ALPHA = 1e-4
# phoid's names of the parameters in phoid.methods.idim's spelling
_IDIM_SPELLING = {"M": "m", "Fv": "c", "Fc": "fc", "OF": "offset"}


@dataclass(frozen=True, eq=False)
class DelayCheck:
    """The result of :func:`check_delay`: the stated command delay against the record's.

    Attributes
    ----------
    stated : float
        The delay the set states (or assumes), s.
    implied : float
        The delay of the output-error fit with the delay free, s.
    stderr : float
        Its Newey–West stderr, s (from the fit's covariance also where it ends on a bound; nan
        when the fit did not converge).
    z : float
        (implied − stated)/stderr.
    searched : (float, float)
        The range the delay was last searched in, s; ``implied`` on its upper end means "at
        least".
    at_upper_end : bool
        ``implied`` sits on the searched range's upper end (within 10⁻³ T) or the fit did not
        converge: the record's delay may be longer still.
    contradicts : bool
        The record contradicts the stated delay: |z| > :data:`DELAY_Z` and the two differ by
        more than the fit resolves (10⁻³ T), or the misfit at the stated delay is
        :data:`MISFIT_GAIN` times that at the implied one.
    fit : TrackingFit
        The fit with the delay free (its estimates are those the implied delay gives).
    stated_rms : float or None
        The rms position misfit of the loop fitted by output error at the stated delay, m;
        computed only where the implied delay is not resolved (``at_upper_end``).
    limit : float
        The widest range's upper end the search could reach, s.
    """

    stated: float
    implied: float
    stderr: float
    z: float
    searched: tuple[float, float]
    at_upper_end: bool
    contradicts: bool
    fit: TrackingFit
    stated_rms: float | None = None
    limit: float = math.inf

    def message(self, label: str, fix: str, reported: Mapping[str, Estimate], *,
                stated_misfit: float, noise: float, stated_gross: bool = False) -> str:
        """The warning of a stated delay that the record contradicts.

        It gives the delay implied, how far, the position misfits (m, rms) at both against
        the record's ``noise`` (m), and the estimates the implied delay gives against the
        ``reported`` ones. Where the loop misfits grossly at the implied delay too
        (:func:`gross_misfit`), or where a shift of less than half a sample is all the record
        implies while the validation at the stated delay misfits grossly (``stated_gross``),
        the message says that the loop model does not follow the record and names the
        possible causes rather than the delay alone. ``label`` names the delay (``"[loop]
        delay = 10 ms"``), ``fix`` ends the message.
        """
        ms = 1e3
        T = min(rec.controller.sample_time for rec in self.fit.records)
        more = " or more (the end of the range searched)" if self.at_upper_end else ""
        z = f"{abs(self.z):.3g}" if math.isfinite(self.z) else "infinitely many"
        spread = "" if not math.isfinite(self.stderr) else f" ± {self.stderr * ms:.2g}"
        est = self.fit.estimates
        free = [k for k in self.fit.free if k != "delay"]
        shifts = [(abs(reported[k].value - est[k].value) / reported[k].stderr, k) for k in free
                  if reported[k].stderr and math.isfinite(reported[k].stderr)]
        worst = max(shifts, default=None)
        values = ", ".join(f"{k} = {est[k].value:.5g}"
                           + ("" if est[k].stderr is None else f" ± {est[k].stderr:.2g}")
                           + f" {UNITS[k]}" for k in free)
        how = (f"{z} stderrs from the stated one" if math.isfinite(self.stderr)
               else "where the fit did not converge")
        if self.stated_rms is not None:
            how += (f"; the loop fitted at the stated delay misses the record by "
                    f"{self.stated_rms:.3g} m rms, {self.fit.rms_residual:.3g} m there")
        implied = (f"it implies a delay of {self.implied * ms:.4g}{spread} ms{more}, {how} "
                   f"(the loop fitted by output error with the delay free over "
                   f"{self.searched[0] * ms:g}–{self.searched[1] * ms:g} ms)")
        causes = ("check the gains (P, D, gain, command_gain), the units of x, r and u, the "
                  "sign convention u = K·(P·(r − x) − D·v̂) and [loop] delay (or --delay)")
        if gross_misfit(self.fit.rms_residual, noise, self.fit.relative_error):
            return (f"{label} cannot be confirmed, and the loop model does not follow the "
                    f"record at any delay searched: {implied}; even there the position misfit "
                    f"is {self.fit.rms_residual:.3g} m rms, {_times(self.fit.rms_residual, noise)}"
                    f" the record's noise ({noise:.3g} m) and "
                    f"{self.fit.relative_error:.3g} % of its tracking error — the delay may be "
                    f"wrong, but so may the rest of the loop: {causes}")
        if stated_gross and abs(self.implied - self.stated) < 0.5 * T:
            return (f"{label}: {implied}; but a shift of less than half a sample does not "
                    f"explain the validation's misfit at the stated delay ({stated_misfit:.3g} "
                    f"m rms, {_times(stated_misfit, noise)} the record's noise {noise:.3g} m): "
                    f"the loop as stated does not reproduce the record with the estimates — "
                    f"{causes}")
        text = (f"{label} is contradicted by the record: {implied}; position misfit rms "
                f"{self.fit.rms_residual:.3g} m there against {stated_misfit:.3g} m in the "
                f"validation at the stated delay (the record's noise: {noise:.3g} m); with the "
                f"delay free {values}: the estimates above rest on the stated delay and their "
                "stderrs do not include its error")
        if worst is not None:
            text += f" ({worst[1]} moves by {worst[0]:.3g} of its stderrs)"
        return f"{text} — {fix}"


def _times(misfit: float, noise: float) -> str:
    return f"{misfit / noise:.3g} times" if noise > 0 else "far above"


def gross_misfit(rms: float, noise: float, tracking_percent: float) -> bool:
    """Whether a position misfit (``rms``, m) is gross: above :data:`GROSS_RATIO` times the
    record's ``noise`` (m) and above :data:`GROSS_TRACKING` % of the tracking error (its
    relative error ``tracking_percent``), or not finite."""
    if not (math.isfinite(rms) and math.isfinite(tracking_percent)):
        return True
    return bool(rms > GROSS_RATIO * noise and tracking_percent > GROSS_TRACKING)


def misfit_warning(name: str, misfit: float, noise: float, tracking: float) -> str | None:
    """The warning of a run whose validation misfits grossly (:func:`gross_misfit`: position
    ``misfit`` and ``noise`` in m, ``tracking`` the misfit's share of the tracking error, %),
    naming the possible causes; None when the misfit is not gross."""
    if not gross_misfit(misfit, noise, tracking):
        return None
    return (f"{name}: the loop simulated with the estimates does not follow the record: "
            f"position misfit {misfit:.3g} m rms, {_times(misfit, noise)} the record's noise "
            f"({noise:.3g} m) and {tracking:.3g} % of its tracking error x − r (a right model "
            "leaves about the noise, and ≲ 1 % of the tracking error) — check the gains (P, D, "
            "gain, command_gain), the units of x, r and u, the sign convention u = K·(P·(r − x) "
            "− D·v̂) and [loop] delay (or --delay)")


def check_delay(records: Sequence[TrackingRecord], *, stated: float,
                fixed: Mapping[str, float] | None = None) -> DelayCheck:
    """Check a stated command delay against the record: the delay that the record implies.

    The loop is fitted by output error (:func:`~phoid.methods.tracking.fit_tracking_runs`)
    with the delay free, over [0, stated + 5T], starting from the stated delay: the delay that
    minimises the position misfit, with all the plant's parameters and each run's start state
    refitted alongside it, and its Newey–West stderr (which covers a residual that is model
    error as well as noise). While the fit ends on the range's upper end, the range beyond the
    stated delay is doubled (up to half the shortest run, :data:`DELAY_RANGE`) and the fit
    made again from where the last one ended (converged or not). The stated delay is
    contradicted when the implied one lies more than :data:`DELAY_Z` stderrs from it (and
    further than the fit's resolution, 10⁻³ T: a noise-free record's stderr is rounding), or,
    where the implied delay is not resolved (on the widest range's end, or a fit that did not
    converge), when the loop fitted at the stated delay misses the record by
    :data:`MISFIT_GAIN` times more.

    Parameters
    ----------
    records : sequence of TrackingRecord
        The runs (their controllers' delay is replaced by ``stated``).
    stated : float
        The delay to check, s (≥ 0).
    fixed : mapping, optional
        Parameters known, as for :func:`fit_tracking_runs` (a ``delay`` entry is ignored).

    Returns
    -------
    DelayCheck

    Raises
    ------
    ValueError
        When the check cannot be made: an unstable start, a record too short, no fit that
        converged and none that beats the stated delay's misfit, ….
    """
    stated = float(stated)
    fixed = {k: q for k, q in (fixed or {}).items() if k != "delay"}
    T = min(rec.controller.sample_time for rec in records)
    span = min((rec.x.size - 1) * rec.controller.sample_time for rec in records)
    limit = max(stated + DELAY_SEARCH * T, DELAY_RANGE * span)
    hi, start = stated + DELAY_SEARCH * T, stated
    last: tuple[TrackingFit, tuple[float, float]] | None = None  # the last that converged
    while True:  # at most log₂(limit/5T) + 1 fits: the range doubles each time
        searched = (0.0, hi)
        fit = _fit(records, start, fixed, searched)
        if fit.converged:
            last = (fit, searched)
        implied = float(fit.estimates["delay"].value)
        # an unconverged fit that pushes on the range's end is widened too: it went there
        if implied < hi - 1e-3 * T or hi >= limit:
            break
        start, hi = implied, min(stated + 2.0 * (hi - stated), limit)
    unresolved = (not fit.converged
                  or float(fit.estimates["delay"].value) >= searched[1] - 1e-3 * T)
    stated_rms, beaten = None, False
    if unresolved:
        with np.errstate(all="ignore"):
            at_stated = fit_tracking_runs(_with_delay(records, stated), fixed=fixed,
                                          max_nfev=_CHECK_NFEV)
        stated_rms = float(at_stated.rms_residual)
        beaten = bool(stated_rms > MISFIT_GAIN * fit.rms_residual)
        if not fit.converged and not beaten:
            if last is None:
                raise ValueError(f"no fit of the loop converged in {_CHECK_NFEV} evaluations, "
                                 f"and none beats the misfit at the stated delay")
            fit, searched = last
            beaten = bool(stated_rms > MISFIT_GAIN * fit.rms_residual)
    implied = float(fit.estimates["delay"].value)
    stderr = math.nan
    if fit.converged:
        i = fit.free.index("delay")
        stderr = math.sqrt(max(float(fit.covariance[i, i]), 0.0))
    diff = implied - stated
    if stderr > 0:
        z = diff / stderr
    elif math.isnan(stderr):
        z = math.nan
    else:  # an exact record: only the resolution below decides
        z = 0.0 if diff == 0 else math.copysign(math.inf, diff)
    contradicts = beaten or bool(math.isfinite(stderr) and abs(z) > DELAY_Z
                                 and abs(diff) > 1e-3 * T)
    return DelayCheck(stated=stated, implied=implied, stderr=stderr, z=float(z),
                      searched=searched, at_upper_end=unresolved, contradicts=contradicts,
                      fit=fit, stated_rms=stated_rms, limit=limit)


def _with_delay(records: Sequence[TrackingRecord], delay: float) -> tuple[TrackingRecord, ...]:
    return tuple(replace(rec, controller=rec.controller.with_delay(delay)) for rec in records)


def _fit(records, start: float, fixed, searched) -> TrackingFit:
    with np.errstate(all="ignore"):  # absurd scales overflow: the fit's own warnings say so
        return fit_tracking_runs(_with_delay(records, start), fixed=fixed, estimate_delay=True,
                                 delay_bounds=searched, max_nfev=_CHECK_NFEV)


def validation_misfit(records: Sequence[TrackingRecord],
                      validations: Sequence[Any]) -> tuple[float, float, float]:
    """The validations' position misfit rms (m) over their compared windows, the records'
    noise (m, from third differences: :func:`~phoid.methods.fit_statistics.difference_noise`,
    independent of any model) and the misfit's share of the tracking error x − r (%)."""
    noise = float(np.sqrt(np.mean([difference_noise(rec.x) ** 2 for rec in records])))
    sq = e = 0.0
    n = 0
    for v in validations:
        sel = slice(*v.window)
        sq += float(np.sum((v.x - v.x_sim)[sel] ** 2))
        e += float(np.sum((v.x - v.r)[sel] ** 2))
        n += v.window[1] - v.window[0]
    misfit = math.sqrt(sq / max(n, 1))
    return misfit, noise, (100.0 * math.sqrt(sq / e) if e > 0 else math.inf)


def delay_warnings(records: Sequence[TrackingRecord], validations: Sequence[Any],
                   estimates: Mapping[str, Estimate], *, stated: float, label: str, fix: str,
                   fixed: Mapping[str, float]) -> tuple[DelayCheck | None, str | None]:
    """The stated delay checked (:func:`check_delay`), as a warning.

    Returns the check (None when it could not be made) and the warning (the delay
    contradicted, or not confirmable; None when the record agrees with it). ``validations``
    are the runs' validations at the stated delay; ``label`` names the delay, ``fix`` ends the
    warning.
    """
    misfit, noise, tracking = validation_misfit(records, validations)
    try:
        if any(v.departs for v in validations):
            # the loop as modelled does not follow the record (r and x in different units, a
            # wrong gain, or a delay so wrong that the loop oscillates): a fit with the delay
            # free would wander, for seconds
            raise ValueError("the simulated loop departs from the record at the stated delay, "
                             "so no delay can be read from a fit")
        checked = check_delay(records, stated=stated, fixed=fixed)
    except ValueError as exc:
        return None, (f"{label} could not be confirmed by the record: {exc} — the delay may be "
                      "wrong, as may the gains (P, D, gain, command_gain), the units of x, r "
                      f"and u or the sign convention; {fix}")
    if not checked.contradicts:
        return checked, None
    return checked, checked.message(label, fix, estimates, stated_misfit=misfit, noise=noise,
                                    stated_gross=gross_misfit(misfit, noise, tracking))


def estimator_disagreement(estimates: Mapping[str, Estimate], fit: TrackingFit, *,
                           gross: bool,
                           covariance: tuple[Sequence[str], np.ndarray] | None = None
                           ) -> str | None:
    """A warning when IDIM's ``estimates`` and the output-error ``fit`` (the delay check's)
    disagree jointly, else None.

    Over the p parameters both fitted (with a finite, positive stderr in each), d = θ_IDIM −
    θ_OE is tested by d'(C_IDIM + C_OE)⁻¹d against χ²_p's upper :data:`ESTIMATOR_ALPHA`/2
    quantile and per parameter in combined stderrs against the normal's ESTIMATOR_ALPHA/(2p)
    one (the constant's comment: why the sum of the covariances and that probability).
    ``covariance``: IDIM's (names in phoid's or IDIM's spelling, matrix in their order);
    without it (or for a parameter it lacks) IDIM's stderrs alone, uncorrelated. The warning
    lists each parameter's difference in combined stderrs √(se_IDIM² + se_OE²). ``gross``: whether
    IDIM's validation misfits grossly (:func:`gross_misfit`), which says which of the two to
    trust."""
    keys = [key for key in ("m", "c", "k", "fc", "offset")
            if key in fit.free and estimates[key].stderr and fit.estimates[key].stderr is not None
            and math.isfinite(estimates[key].stderr) and math.isfinite(fit.estimates[key].stderr)]
    if not keys:
        return None
    a_cov = np.diag([float(estimates[k].stderr) ** 2 for k in keys])
    if covariance is not None:
        # IDIM's spelling (M, Fv, Fc, OF) or phoid's
        names = [_IDIM_SPELLING.get(n, n) for n in covariance[0]]
        matrix = np.asarray(covariance[1], dtype=float)
        for i, ki in enumerate(keys):
            for j, kj in enumerate(keys):
                if ki in names and kj in names:
                    a_cov[i, j] = matrix[names.index(ki), names.index(kj)]
    at = [fit.free.index(k) for k in keys]
    b_cov = np.asarray(fit.covariance, dtype=float)[np.ix_(at, at)]
    d = np.array([estimates[k].value - fit.estimates[k].value for k in keys], dtype=float)
    combined = a_cov + b_cov
    scale = np.sqrt(np.clip(np.diag(combined), 0.0, None))
    if not (np.all(np.isfinite(combined)) and np.all(np.isfinite(d)) and np.all(scale > 0)):
        return None
    # in units of the combined stderrs (a correlation-like matrix: lstsq is well scaled), and
    # by least squares, so that a singular sum (a parameter the record does not excite) is safe
    ds, cs = d / scale, combined / np.outer(scale, scale)
    statistic = float(ds @ np.linalg.lstsq(cs, ds, rcond=None)[0])
    threshold = chi2_isf(0.5 * ESTIMATOR_ALPHA, len(keys))
    z_limit = math.sqrt(chi2_isf(0.5 * ESTIMATOR_ALPHA / len(keys), 1))
    if not (statistic > threshold or float(np.max(np.abs(ds))) > z_limit):
        return None
    rows = [(abs(float(z)), k, estimates[k], fit.estimates[k]) for z, k in zip(ds, keys,
                                                                                 strict=True)]
    rows.sort(reverse=True, key=lambda row: row[0])
    listed = "; ".join(f"{k} = {a.value:.5g} ± {a.stderr:.2g} {UNITS[k]} by IDIM against "
                       f"{b.value:.5g} ± {b.stderr:.2g} by output error, {z:.3g} combined "
                       "stderrs" for z, k, a, b in rows)
    head = (f"the estimator 'idim' and output error (the delay check's fit of the loop, delay "
            f"{fit.estimates['delay'].value * 1e3:.3g} ms) disagree: jointly over "
            f"{', '.join(keys)}, d'(C_IDIM + C_OE)⁻¹d = {statistic:.3g} (χ²_{len(keys)}'s limit "
            f"{threshold:.3g}), and per parameter (limit {z_limit:.3g} combined stderrs): "
            f"{listed}")
    if gross:
        return (f"{head}. IDIM reads the force from the recorded command u, output error from "
                "the controller the set states, and the loop simulated with IDIM's estimates "
                "does not follow the record: the stated controller does not produce the "
                "recorded command — check the gains (P, D, gain, command_gain), the units of "
                "x, r and u, the sign convention and [loop] delay")
    return (f"{head}. IDIM differentiates the recorded position twice, so the noise on x "
            "biases its estimates (the mass toward 0: errors in variables), which output error "
            "does not (it takes the noise as measurement noise): trust output error's — "
            "identify with --estimator output-error (or estimator = \"output-error\" in the "
            "manifest)")


def idim_noise_hint(records: Sequence[TrackingRecord]) -> str:
    """The position noise named among the causes where IDIM's estimates cannot be simulated
    (an unstable loop, a mass not > 0, …): IDIM differentiates x twice, so noise on it biases
    the estimates (the mass toward 0: errors in variables) and can make the loop as estimated
    unstable with the gains and delay right; output error takes the noise as measurement
    noise. The record's noise (third differences) is stated against its motion (the rms of
    x − mean), the largest of the runs'. ``""`` for no records (IDIM did not run)."""
    if not records:
        return ""
    ratios = []
    for rec in records:
        noise = difference_noise(rec.x)
        motion = float(np.std(rec.x))
        if math.isfinite(noise) and motion > 0:
            ratios.append((noise / motion, noise, rec.name))
    level = ""
    if ratios:
        ratio, noise, name = max(ratios)
        level = (f" ({name}: noise ≈ {noise:.3g} m rms from third differences, "
                 f"{100 * ratio:.3g} % of its motion's rms)")
    return ("; or IDIM's estimates are biased by the position noise" + level + ": IDIM "
            "differentiates x twice, so noise biases the mass toward 0 and can make the loop "
            "as estimated unstable with the gains and delay right — identify with --estimator "
            "output-error (or estimator = \"output-error\" in the manifest), which takes the "
            "noise as measurement noise")
