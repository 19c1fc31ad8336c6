r"""The adequacy of a tracking identification: the checks of :mod:`phoid.methods.adequacy` on
IDIM's force residual and output error's position residual, and the stderr that survive a
misfit (docs/adequacy.md, "Tracking").

IDIM (:func:`assess_idim`), per run, on the decimated regression's residual e = y − Xθ̂ (N):

- ``noise``: e against the force noise that the record's own position noise gives the right
  model. The recorded command u is the controller's computed output, the force the plant
  received: its noise (the controller's reaction to the sensor's noise) is real force and
  leaves no residual. What the right model leaves is the position noise n (sd ŝ from the
  third differences of x, :func:`~phoid.methods.fit_statistics.difference_noise`) carried by
  the columns −(M q̈ + Fv q̇ + k q) of the filtered position through IDIM's filters:
  ŝ_F² = ŝ² Σ h_q², h_q the chain's impulse response (:func:`phoid.methods.idim.
  residual_filters`). Anything above it — a force disturbance, an unmodelled friction shape, a
  flexible mode, a half-sample or wrong delay, a noisy recording of u — is model error;
- ``whiteness``: the residual's autocorrelation ρ̂ₖ (k = 1 … h, h = min(20, ⌊n/5⌋)) against
  the one the right model's residual has, ρₖ from the autocovariance ŝ²(h_q ⋆ h_q)(k·r) +
  σ_F²(h_F ⋆ h_F)(k·r) at the decimated lags (σ_F² the residual's variance above ŝ_F², taken as
  white force noise through the decimation filter h_F): IDIM's filters colour the residual of
  the right model (ρ₁ ≈ −0.5 for a position-noise residual, +0.2 for a force-noise one), so
  the plain Ljung–Box test would fail on every record. Q' = n/(1 + 2Σρⱼ²)·Σₖ(ρ̂ₖ − ρₖ)²
  (Bartlett's variance of ρ̂ₖ), summed over the runs, against χ²_{Σh} at α = 10⁻³;
- ``halves``: each run's rows cut at the middle, the first halves and the second halves each
  fitted alone by OLS (exactly IDIM on those rows), compared with their Newey–West covariances;
- ``runs``: each run fitted alone, compared the same way (sets of two runs or more);
- ``validation``: the loop simulated with the estimates (the validation) against the recorded
  position, RMS(x − x_sim)/ŝ against ρ₀·max(1.5, 1 + max(0.1, 10/√n)) (:data:`VALIDATION_SLACK`:
  the estimates' own error moves the simulated loop too — IDIM's half-sample pairing and the
  noise of q̈ in its regressor bias them by a few stderr — and the right model's records
  reach 1.11–1.21 with IDIM's estimates, tests/test_tracking_adequacy.py; EMPS 97.5).
  ρ₀ = √(1 + Σ tₖ²) is the ratio
  the right model gives: the controller reads the sensor's noise n and moves the plant by
  −T(z)n (T the loop's complementary sensitivity, tₖ its impulse response, from the loop
  simulated with the estimates: :func:`sensor_noise_floor`), which the simulated loop, fed no
  noise, does not reproduce (uncorrelated with n at the same instant: the loop holds its
  command over a period).

Output error (:func:`assess_output_error`): ``noise`` on the fit's own position residual
against ρ₀ŝ; ``whiteness`` (Ljung–Box) reported but not a cause of its own — the simulated loop
cannot reproduce the sensor noise fed back through the controller, so the residual of the
right model is coloured, and output error's stderr are Newey–West ones in every case;
``validation`` as for IDIM. The halves and the runs are not refitted (each output-error fit
simulates the loop hundreds of times): their checks are n/a.

Robust covariance: IDIM's Newey–West sandwich of its regression (each run's rows,
:func:`phoid.methods.adequacy.sandwich`), never below the OLS one, plus the halves' spread
d dᵀ where the model misfits or the halves disagree, plus the covariance of the runs' mean
where they disagree — reported only where a check fails (else the OLS stderr stand).
Output error: its Newey–West covariance always, with the white one as ``stderr_white``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid.methods import adequacy as aq
from phoid.methods.chi2 import chi2_isf, chi2_sf
from phoid.methods.fit_statistics import difference_noise
from phoid.methods.idim import residual_filters
from phoid.methods.tracking import UNITS
from phoid.simulation.tracking import simulate_tracking

__all__ = ["assess_idim", "assess_output_error", "misfit_causes", "sensor_noise_floor",
           "validation_check"]

#: phoid's names of IDIM's parameters
_PHOID = {"M": "m", "Fv": "c", "Fc": "fc", "OF": "offset", "k": "k"}
#: the halves' spread added to a misfit's covariance: d dᵀ (twice their sample covariance), as
#: for the free decay (phoid.methods.free_adequacy)
_SPREAD = 2.0
#: fewest decimated rows of a half
_MIN_HALF = 20
#: lags of the expected autocovariance kept for Bartlett's variance
_LAGS = 200
#: the least threshold of the validation's position residual/noise (module docstring)
VALIDATION_SLACK = 1.5

#: the likely causes of a tracking misfit, in the user's terms
CAUSES = ("friction that is not Coulomb plus viscous (a Stribeck dip at low speed, "
          "sticking at the reversals), a flexible mode (a second mass, a belt, a coupling), a "
          "wrong command delay ([loop] delay), a command that saturates, or the command's "
          "meaning (does u already contain w? [loop] u_contains_w, [loop] command_gain)")


def misfit_causes() -> str:
    """The likely causes of a tracking misfit, in words."""
    return CAUSES


def _ols(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """OLS of y on X: (θ, the robust covariance (Newey–West, not below the OLS one), e)."""
    n, p = X.shape
    if n <= p + 1:
        return None
    theta, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
    if rank < p:
        return None
    e = y - X @ theta
    try:
        white = float(np.var(e, ddof=1)) * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return None
    cov = aq.not_below_white(aq.sandwich([X], [e]), white)
    if not np.all(np.isfinite(cov)):
        return None
    return theta, cov, e


def _expected_rho(h_q: np.ndarray, h_F: np.ndarray, sx: float, var_e: float,
                  dec: int) -> np.ndarray:
    """ρ₀ … ρ_L of the right model's residual at the decimated lags (module docstring)."""
    def acov(h: np.ndarray) -> np.ndarray:
        return np.array([float(h[: h.size - j * dec] @ h[j * dec:])
                         for j in range(min(_LAGS, h.size // dec - 1) + 1)])
    gq, gF = acov(h_q), acov(h_F)
    var_q = sx * sx * gq[0]
    sF2 = max(0.0, var_e - var_q) / gF[0] if gF[0] > 0 else 0.0
    g = sx * sx * gq + sF2 * gF
    return g / g[0] if g[0] > 0 else np.zeros_like(g)


def _whiteness(resids: Sequence[np.ndarray], rhos: Sequence[np.ndarray | None]) -> aq.Check:
    """Q' of each run's residual against its expected autocorrelation, summed."""
    q_all, h_all, worst = 0.0, 0, (0.0, 0.0, 0.0)
    for e, rho in zip(resids, rhos, strict=True):
        n = e.size
        h = min(20, n // 5, rho.size - 1 if rho is not None else 0)
        if rho is None or h < 1:
            continue
        ec = e - e.mean()
        c0 = float(ec @ ec)
        if not c0 > 0:
            continue
        rh = np.array([float(ec[k:] @ ec[:-k]) / c0 for k in range(1, h + 1)])
        bart = 1.0 + 2.0 * float(np.sum(rho[1:] ** 2))
        q_all += n / bart * float(np.sum((rh - rho[1: h + 1]) ** 2))
        h_all += h
        if abs(rh[0] - rho[1]) >= abs(worst[0] - worst[1]):
            worst = (float(rh[0]), float(rho[1]), 0.0)
    if h_all == 0:
        return aq.Check("whiteness", math.nan, aq.ALPHA, None,
                        "not tested (records too short or noise-free)")
    p = chi2_sf(q_all, float(h_all))
    detail = (f"the residual's autocorrelation against the one IDIM's filters give the record's "
              f"noise: Q' = {q_all:.4g} over {h_all} lags, p = {p:.2g} (as expected above "
              f"p = {aq.ALPHA:g}); lag-1 autocorrelation {worst[0]:.3f}, expected {worst[1]:.3f}")
    return aq.Check("whiteness", q_all, chi2_isf(aq.ALPHA, float(h_all)), bool(p >= aq.ALPHA),
                    detail)


def sensor_noise_floor(controller: Any, values: Any, n: int = 4000) -> float:
    """ρ₀ = √(1 + Σ tₖ²): the position residual/noise of the right model's simulated loop
    (module docstring), tₖ the loop's response x to a unit reference impulse (its
    complementary sensitivity), simulated with the estimates (c, k ≥ 0, no Coulomb friction:
    the linear loop). 1 where the loop cannot be simulated."""
    from phoid.dynamics.plant import Plant

    amp = 1e-6
    try:
        plant = Plant(m=float(values["m"]), c=max(float(values["c"]), 0.0),
                      k=max(float(values["k"]), 0.0), fc=0.0)
        r = np.zeros(n)
        r[1] = amp
        sim = simulate_tracking(plant, controller, r, x_init=[0.0])
        t = np.asarray(sim.x, dtype=float) / amp
    except (ValueError, OverflowError, FloatingPointError, KeyError):
        return 1.0
    if not np.all(np.isfinite(t)) or not abs(t[-1]) < 1e-3:
        return 1.0
    return math.sqrt(1.0 + float(t @ t))


def validation_check(names: Sequence[str], validations: Sequence[Any],
                     ratios: Sequence[float | None],
                     floors: Sequence[float] | None = None) -> aq.Check:
    """The validation's position residual over the record's noise, the worst run against
    ρ₀·max(1.5, 1 + max(0.1, 10/√n)) (n the compared samples, ρ₀ its run's ``floors``, 1
    without; module docstring)."""
    worst: tuple[float, float, str] | None = None
    for i, (name, v, q) in enumerate(zip(names, validations, ratios, strict=True)):
        if q is None or not math.isfinite(q):
            continue
        start, stop = v.window
        thr = max(VALIDATION_SLACK, aq.noise_threshold(stop - start)) * (
            1.0 if floors is None else floors[i])
        if worst is None or q / thr > worst[0] / worst[1]:
            worst = (float(q), thr, name)
    if worst is None:
        return aq.Check("validation", math.nan, math.nan, None,
                        "no run with a usable noise level")
    q, thr, name = worst
    detail = (f"the loop simulated with the estimates misses the recorded position by "
              f"{q:.3g} times its noise in {name} (≤ {thr:.3g} when the model reproduces the "
              "record to its noise)")
    return aq.Check("validation", q, thr, bool(q <= thr), detail)


def _misfit_warning(check: aq.Check, what: str) -> str:
    return (f"the model misfits the record: {what} {check.statistic:.3g} times the noise "
            f"(at most {check.threshold:.3g} when the model explains the record to its noise); "
            f"likely causes: {CAUSES}; the stderr are robust ones (Newey–West), the white-noise "
            "ones understate the uncertainty")


def assess_idim(fit: Any, records: Sequence[Any], validations: Sequence[Any],
                ratios: Sequence[float | None], values: Any) -> aq.Adequacy:
    """The adequacy of an IDIM fit (module docstring).

    Parameters
    ----------
    fit : phoid.methods.idim.IDIMFit
        With its regression (``regressor``, ``target``, ``rows``, ``recipe``).
    records : sequence of TrackingRecord
        The runs, in the fit's order (their ``x`` for the noise, ``name`` for the words).
    validations : sequence of TrackingValidation
    ratios : sequence of float or None
        Each validation's position residual/noise.
    values : Mapping
        The estimates' values as simulated (``m``, ``c``, ``k``).

    Returns
    -------
    phoid.methods.adequacy.Adequacy
        Its covariances are of the fit's free parameters, with phoid's names.
    """
    # a record whose forces overflow (a command gain of 1e300) gives non-finite statistics,
    # reported as undefined (null), not as numpy warnings
    with np.errstate(all="ignore"):
        return _assess_idim(fit, records, validations, ratios, values)


def _assess_idim(fit: Any, records: Sequence[Any], validations: Sequence[Any],
                 ratios: Sequence[float | None], values: Any) -> aq.Adequacy:
    names = tuple(_PHOID[n] for n in fit.free)
    units = tuple(UNITS[n] for n in names)
    labels = [rec.name for rec in records]
    X, y = fit.regressor, fit.target
    p = len(names)
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(fit.residual))
            and np.all(np.isfinite(fit.covariance))):
        # overflowed arithmetic: nothing can be tested (a warning names the overflow)
        why = "not tested (the regression's arithmetic overflowed)"
        return aq.assess([aq.Check(n, math.nan, math.nan, None, why)
                          for n in ("noise", "whiteness", "validation")],
                         names=names, units=units,
                         white_cov=np.where(np.isfinite(fit.covariance), fit.covariance,
                                            math.nan),
                         sandwich_cov=np.full((p, p), math.nan))
    cut = np.cumsum(fit.rows)[:-1]
    Xs, ys = np.split(X, cut), np.split(y, cut)
    es = np.split(fit.residual, cut)
    rc = fit.recipe
    est = {n: getattr(fit, n).value for n in ("M", "Fv")}
    kval = fit.k.value if fit.k is not None else 0.0
    h_q, h_F = residual_filters(rc["dt"], cutoff=rc["cutoff"], order=rc["order"],
                                decimation=rc["decimation"], M=est["M"], Fv=est["Fv"], k=kval)
    sx = [difference_noise(rec.x) for rec in records]
    noise_f = [s * math.sqrt(float(h_q @ h_q)) if s > 0 else None for s in sx]
    noise = aq.noise_check(es, noise_f, labels, x_unit="N")
    if noise.passed is not None:
        noise = aq.Check("noise", noise.statistic, noise.threshold, noise.passed,
                         "force " + noise.detail + "; the noise is the record's position noise "
                         "carried through IDIM's filters")
    rhos = [_expected_rho(h_q, h_F, s, float(np.mean(e * e)), rc["decimation"])
            if s > 0 else None for s, e in zip(sx, es, strict=True)]
    white = _whiteness(es, rhos)
    floors = [sensor_noise_floor(rec.controller, values) for rec in records]
    valid = validation_check(labels, validations, ratios, floors)
    checks = [noise, white, valid]
    causes: list[str] = []
    warns: list[str] = []
    if noise.passed is False:
        causes.append("misfit")
        warns.append(_misfit_warning(noise, "the force residual of IDIM is"))
    elif valid.passed is False:
        causes.append("misfit")
        warns.append(_misfit_warning(valid, "the loop simulated with the estimates misses the "
                                            "recorded position by"))
    if white.passed is False and noise.passed is not False:
        causes.append("coloured")
        warns.append(f"the force residual is not the noise the record's sensor gives it "
                     f"({white.detail}): a slow force disturbance or a misfit phoid does not "
                     "name; the stderr are Newey–West ones that account for it")
    sw = aq.sandwich(Xs, es)
    between: list[np.ndarray] = []
    misfit = noise.passed is False or valid.passed is False
    # halves: every run's rows cut at the middle, the first halves fitted jointly, then the
    # second halves
    agreements = []
    if min(fit.rows) >= 2 * _MIN_HALF:
        parts = []
        for half in (0, 1):
            hx = [x[: x.shape[0] // 2] if half == 0 else x[x.shape[0] // 2:] for x in Xs]
            hy = [v[: v.size // 2] if half == 0 else v[v.size // 2:] for v in ys]
            parts.append(_ols(np.vstack(hx), np.concatenate(hy)))
        if all(p is not None for p in parts):
            ag = aq.agreement("halves", [p[0] for p in parts], [p[1] for p in parts],
                              params=names, units=units, labels=("first half", "second half"),
                              of_mean=False)
            agreements.append(ag)
            checks.append(ag.check)
            if ag.check.passed is False or misfit:
                between.append(_SPREAD * ag.between)
    if len(Xs) >= 2:
        runs = [_ols(x, v) for x, v in zip(Xs, ys, strict=True)]
        ok = [i for i, p in enumerate(runs) if p is not None]
        if len(ok) >= 2:
            ag = aq.agreement("runs", [runs[i][0] for i in ok], [runs[i][1] for i in ok],
                              params=names, units=units, labels=[labels[i] for i in ok])
            agreements.append(ag)
            checks.append(ag.check)
            if ag.check.passed is False:
                between.append(ag.between)
    for ag in agreements:
        w = ag.warning()
        if w is not None:
            causes.append("drift" if ag.check.name == "halves" else "runs_differ")
            warns.append(w)
    return aq.assess(checks, names=names, units=units, white_cov=fit.covariance,
                     sandwich_cov=sw, between=between, causes=causes, warnings=warns)


def assess_output_error(fit: Any, validations: Sequence[Any],
                        ratios: Sequence[float | None], values: Any) -> aq.Adequacy:
    """The adequacy of an output-error fit (module docstring).

    Parameters
    ----------
    fit : phoid.methods.tracking.TrackingFit
    validations : sequence of TrackingValidation
    ratios : sequence of float or None
        Each validation's position residual/noise.
    values : Mapping
        The estimates' values as simulated (``m``, ``c``, ``k``).

    Returns
    -------
    phoid.methods.adequacy.Adequacy
        ``stderr`` "robust": output error reports its Newey–West covariance in every case
        (plus nothing: its halves and runs are not refitted), the white one beside it.
    """
    with np.errstate(all="ignore"):
        return _assess_output_error(fit, validations, ratios, values)


def _assess_output_error(fit: Any, validations: Sequence[Any],
                         ratios: Sequence[float | None], values: Any) -> aq.Adequacy:
    names = tuple(fit.free)
    units = tuple(UNITS[n] for n in names)
    labels = [rec.name for rec in fit.records]
    resids = [rec.x[rec.start:] - sim.x for rec, sim in zip(fit.records, fit.simulations,
                                                           strict=True)]
    floors = [sensor_noise_floor(rec.controller, values) for rec in fit.records]
    # the noise the right model leaves: the sensor's, and the plant's reaction to it (ρ₀)
    noise = aq.noise_check(resids, [difference_noise(rec.x[rec.start:]) * f
                                    for rec, f in zip(fit.records, floors, strict=True)],
                           labels, x_unit="m")
    white = aq.whiteness_check(resids)
    valid = validation_check(labels, validations, ratios, floors)
    skip = "not refitted for output error (each fit simulates the loop hundreds of times)"
    checks = [noise, white, valid, aq.Check("halves", math.nan, math.nan, None, skip)]
    causes: list[str] = []
    warns: list[str] = []
    for c, what in ((noise, "the position residual of the output-error fit is"),
                    (valid, "the loop simulated with the estimates misses the recorded "
                            "position by")):
        if c.passed is False:
            causes.append("misfit")
            warns.append(_misfit_warning(c, what))
            break
    white_cov = fit.white_covariance if fit.white_covariance is not None else \
        np.diag([fit.white_stderr[n] ** 2 for n in names])
    robust = np.asarray(fit.covariance, dtype=float)
    return aq.Adequacy(checks=tuple(checks), warnings=tuple(warns), causes=tuple(causes),
                       names=names, units=units, white_cov=np.asarray(white_cov, dtype=float),
                       robust_cov=robust.copy(), sandwich_cov=robust.copy(), stderr="robust")
