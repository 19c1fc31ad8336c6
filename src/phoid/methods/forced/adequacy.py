r"""The adequacy of a forced (sine-sweep) identification (:mod:`phoid.methods.forced.pipeline`).

Per run, the residual of its response fit (steady sine plus the start-up transient, the joint
fit of :func:`phoid.methods._modal.fit_modal`) against the record's own noise level (third
differences, :func:`phoid.methods.fit_statistics.difference_noise`) and for whiteness
(Ljung–Box) — :func:`phoid.methods.adequacy.noise_check` and
:func:`~phoid.methods.adequacy.whiteness_check`. A Duffing spring leaves harmonics of the
forcing in the residual, a filtered sensor leaves coloured noise.

Between runs, ``runs``: the χ² of the sweep points about eq. (20)
(:func:`phoid.methods.forced.stiffness.fit_response`; the fit's own test), with each run's
robust covariance where a residual check failed.

Uncertainty. Each run's phasor (the sine's two amplitudes) gets the Newey–West sandwich of its
response fit (:func:`phoid.methods.adequacy.sandwich`: the cosine and sine columns, the offset
and the transient's two columns projected off), never below its white covariance; carried to
Zᵢ = F̂ᵢ/x̂ᵢ as the white one is, it gives Ω. The eq. (20) fit's estimate is kept and its
covariance becomes (AᵀWA)⁻¹AᵀWΩWA(AᵀWA)⁻¹ (W the fit's weights), scaled by the runs' χ²/dof
where they still disagree. Where every check passes the fit's own covariance stands.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from phoid.methods import adequacy as aq
from phoid.methods.chi2 import chi2_isf, chi2_sf
from phoid.methods.fit_statistics import difference_noise

__all__ = ["RUNS_DISAGREE", "assess_forced", "phasor_sandwich"]

#: the start of the eq. (20) fit's own runs-disagree warning, replaced by the ``runs`` check's
RUNS_DISAGREE = "the runs disagree with eq. (20) more than their noise explains"
_ALPHA = 1e-3


def phasor_sandwich(seg_t: np.ndarray, fixed: np.ndarray, basis: tuple[np.ndarray, np.ndarray],
                    resid: np.ndarray) -> np.ndarray:
    """Newey–West covariance of a run's sine amplitudes (a, b) (columns 1, 2 of ``fixed``),
    the offset and the transient's columns ``basis`` projected off; nan where it fails."""
    J = fixed[:, 1:3]
    G = np.column_stack([fixed[:, :1], *basis])
    G = G[:, np.any(G != 0, axis=0)]
    if resid.size <= J.shape[1] + G.shape[1] or not np.all(np.isfinite(G)):
        return np.full((2, 2), math.nan)
    return aq.sandwich([J], [resid], nuisance=[G])


def assess_forced(*, x: Sequence[np.ndarray], resid: Sequence[np.ndarray],
                  motion: Sequence[np.ndarray], phasor_robust: Sequence[np.ndarray],
                  phasor_white: Sequence[np.ndarray], Jx: np.ndarray, cov_u: np.ndarray,
                  covF: np.ndarray, omega: np.ndarray, Z: np.ndarray, omega_var: np.ndarray,
                  added_mass: np.ndarray, fit: object, labels: Sequence[str]) -> aq.Adequacy:
    """The adequacy of the eq. (20) fit (module docstring).

    Parameters
    ----------
    x, resid, motion : sequence of ndarray
        Each used run's analysed record, its fit residual and its fitted motion (about the
        offset), m.
    phasor_robust, phasor_white : sequence of ndarray (2, 2)
        Each run's sandwich (:func:`phasor_sandwich`) and white covariance of (a, b).
    Jx, cov_u, covF : ndarray
        The pipeline's maps: ∂Z/∂(a, b) per run (block diagonal), the phasors' covariance
        (rates included), F's share of cov Z.
    omega, Z, omega_var, added_mass : ndarray
        The sweep points (rad/s, N/m, (rad/s)², kg).
    fit : phoid.methods.forced.stiffness.ResponseFit
        The eq. (20) fit.
    labels : sequence of str
        The runs' names.

    Returns
    -------
    phoid.methods.adequacy.Adequacy
        Covariances of (m, c, k).
    """
    rms = [float(np.sqrt(np.mean(m * m))) for m in motion]
    # a noise-free record (noise at the motion's rounding) has no noise to test against
    noise: list[float | None] = [nz if nz > 1e-9 * r else None
                                 for nz, r in zip((difference_noise(xi) for xi in x), rms,
                                                  strict=True)]
    noise_c = aq.noise_check(list(resid), noise, labels)
    white = aq.whiteness_check(list(resid), motion_rms=rms)
    if white.passed is None and noise_c.passed is False:
        # noise-free records (every residual at rounding level): the residual has no noise
        # to be measured against
        noise_c = aq.Check("noise", noise_c.statistic, noise_c.threshold, None,
                           "not tested (noise-free records: the residual is rounding)")
    checks = [noise_c, white]
    causes: list[str] = []
    warns: list[str] = []
    if white.passed is not None:
        c, w = aq.residual_warnings(noise_c, white, (), None)
        causes += list(c)
        for text in w:
            text = text.replace(" and shows no trend with the amplitude nor a second mode: ",
                                ": ")
            if text.startswith("the model misfits"):
                text += ("; in a forced run most often a nonlinear plant (a stiffening spring "
                         "leaves harmonics of the forcing, friction a distorted response), a "
                         "force not acting on the measured mass, or coloured noise")
            warns.append(text)
    residual_failed = any(c.passed is False for c in checks)
    n = omega.size
    cov_r = cov_u.copy()
    if residual_failed:
        for p in range(n):
            sw, cw = phasor_robust[p], phasor_white[p]
            if np.all(np.isfinite(sw)):
                b = slice(2 * p, 2 * p + 2)
                cov_r[b, b] = cov_u[b, b] + aq.not_below_white(sw, cw) - cw
    covZ = Jx @ cov_u @ Jx.T + covF
    covZr = Jx @ cov_r @ Jx.T + covF
    m, c = float(fit.m), float(fit.c)  # type: ignore[attr-defined]
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = -omega * omega
    A[0::2, 2] = 1.0
    A[1::2, 1] = omega
    h = np.zeros((2 * n, n))
    h[0::2] = np.diag(-2.0 * (m + added_mass) * omega)
    h[1::2] = np.diag(np.full(n, c))
    extra = (h * omega_var) @ h.T
    Wi = np.linalg.pinv(covZ + extra)
    Om = covZr + extra
    Ai = np.linalg.pinv(A.T @ Wi @ A)
    sand = Ai @ A.T @ Wi @ Om @ Wi @ A @ Ai
    dof = int(fit.dof)  # type: ignore[attr-defined]
    chi2 = float(fit.chi2)  # type: ignore[attr-defined]
    lim = chi2_isf(_ALPHA, dof) if dof > 0 else math.nan
    scaled = dof > 0 and chi2 > lim
    own = np.asarray(fit.cov, dtype=float)  # type: ignore[attr-defined]
    white_cov = own / (chi2 / dof) if scaled else own
    if residual_failed:
        y = np.empty(2 * n)
        y[0::2] = Z.real + added_mass * omega * omega
        y[1::2] = Z.imag
        r = y - A @ np.array([m, c, float(fit.k)])  # type: ignore[attr-defined]
        chi2 = float(r @ np.linalg.pinv(Om) @ r)
    runs_pass = not (dof > 0 and chi2 > lim)
    if dof > 0:
        how = "each run's robust covariance" if residual_failed else "each run's fit"
        checks.append(aq.Check(
            "runs", chi2, lim, runs_pass,
            f"χ² of the sweep points about eq. (20) = {chi2:.4g} on {dof} dof (χ²/dof "
            f"{chi2 / dof:.3g}, p = {chi2_sf(chi2, float(dof)):.2g}), weighted by {how}"))
        if not runs_pass:
            causes.append("runs_differ")
            warns.append(f"{RUNS_DISAGREE} (χ²/dof = {chi2 / dof:.3g}); stderr scaled up "
                         "accordingly: check for nonlinearity (friction, amplitude-dependent "
                         "stiffness) or a force not acting on the measured mass")
    failed = any(ch.passed is False for ch in checks)
    if not failed:
        robust = white_cov
    elif not residual_failed:
        robust = own
    else:
        robust = aq.not_below_white(sand, white_cov)
        if not runs_pass:
            robust = robust * (chi2 / dof)
    ad = aq.assess(checks, names=("m", "c", "k"), units=("kg", "N s/m", "N/m"),
                   white_cov=white_cov, sandwich_cov=sand, causes=causes, warnings=warns)
    return replace(ad, robust_cov=0.5 * (robust + robust.T))
