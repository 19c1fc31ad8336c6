r"""The adequacy of the friction fit (:mod:`phoid.methods.friction.fit`).

Per run, the residual of the stick–slip model against the record's own noise sd (held segment
or third differences, :mod:`phoid.methods.friction.survey`) and for whiteness (Ljung–Box) —
:func:`phoid.methods.adequacy.noise_check` and :func:`~phoid.methods.adequacy.whiteness_check`;
and ``chi2``, the fit's χ²/dof against 1 + 5√(2/dof) (and 1.2), the test the fit already made
(its warning is the fit's own).

Uncertainty. The fit's covariance is already its Fisher covariance scaled by χ²/dof (a misfit
that is white widens it). Where a check fails the Newey–West sandwich of the full-record fit
(:func:`phoid.methods.adequacy.sandwich`: each run's weighted rows of the Jacobian of
(m, c, k, f_c), its release, position and offset columns projected off) is reported instead,
never below the scaled one. Where every check passes the fit's own covariance stands.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from phoid.methods import adequacy as aq

__all__ = ["assess_friction"]


def assess_friction(resid: Sequence[np.ndarray], noise: Sequence[float],
                    motion_rms: Sequence[float], labels: Sequence[str], jac: Any,
                    weights: Sequence[float], cov: np.ndarray, chi2: float,
                    dof: int) -> aq.Adequacy:
    """The friction fit's adequacy (module docstring).

    Parameters
    ----------
    resid : sequence of ndarray
        Each used run's residual y − ŷ over its window, m.
    noise, motion_rms : sequence of float
        Each run's noise sd and its fitted motion's RMS, m.
    labels : sequence of str
    jac : phoid.methods.friction.model.BlockJacobian
        The weighted Jacobian at the optimum.
    weights : sequence of float
        Each run's weight 1/sd.
    cov : ndarray (4, 4)
        The fit's covariance of (m, c, k, f_c) (scaled by χ²/dof).
    chi2, dof : float, int
        The fit's χ² and degrees of freedom.

    Returns
    -------
    phoid.methods.adequacy.Adequacy
    """
    noise_c = aq.noise_check(list(resid), list(noise), labels)
    white = aq.whiteness_check(list(resid), motion_rms=list(motion_rms))
    if white.passed is None and noise_c.passed is False:
        # noise-free records (every residual at rounding level): nothing to measure against
        noise_c = aq.Check("noise", noise_c.statistic, noise_c.threshold, None,
                           "not tested (noise-free records: the residual is rounding)")
    red = chi2 / dof if dof > 0 else math.nan
    lim = max(1.0 + 5.0 * math.sqrt(2.0 / max(dof, 1)), 1.2)
    chk = aq.Check("chi2", red, lim, bool(red <= lim) if math.isfinite(red) else None,
                   f"χ²/dof of the full-record fit = {red:.4g} (at most {lim:.3g} when the "
                   "model explains the records to their noise)")
    checks = [noise_c, white, chk]
    causes: list[str] = []
    warns: list[str] = []
    if white.passed is not None:
        c, w = aq.residual_warnings(noise_c, white, ("friction-model",), None)
        causes += [x for x in c if x != "friction-model"]
        warns += list(w)
        if white.passed is False and noise_c.passed is not False:
            causes.append("coloured")
            warns.append(f"the residual is not white noise ({white.detail}): coloured noise "
                         "or a misfit of the stick-slip model; the stderr are Newey–West ones "
                         "that account for it")
    own = np.asarray(cov, dtype=float)
    sand = np.full((4, 4), math.nan)
    rows = getattr(jac, "rows", None)
    if rows is not None and jac.glob.shape[1] == 4 and any(ch.passed is False for ch in checks):
        Gs = [jac.glob[rows[i]:rows[i + 1]] for i in range(len(resid))]
        Ls = [jac.loc[rows[i]:rows[i + 1]] for i in range(len(resid))]
        es = [np.asarray(e) * w for e, w in zip(resid, weights, strict=True)]
        sand = aq.sandwich(Gs, es, nuisance=Ls)
    ad = aq.assess(checks, names=("m", "c", "k", "fc"), units=("kg", "N s/m", "N/m", "N"),
                   white_cov=own, sandwich_cov=sand, causes=causes, warnings=warns)
    if ad.stderr == "robust" and not np.all(np.isfinite(sand)):
        # no sandwich: the fit's own (scaled) covariance
        ad = replace(ad, stderr="white",
                     stderr_note="the fit's own, scaled by its χ²/dof: no Newey–West "
                                 "covariance could be computed for this fit")
    return ad
