"""m, c, k from the runs' measured dominant modes (seed eqs. 32–35).

Two estimators, both pure functions of the per-run measurements (σᵢ, ω_dᵢ and their covariance)
and the known gains Pᵢ, Dᵢ and delay Δt:

``fit_lines`` — the paper's route: delay-corrected c′ᵢ, k′ᵢ (eq. 32, corrected α₁), then the two
straight lines c′ᵢ = 2mσᵢ − c and k′ᵢ = mω₀ᵢ² − k (eq. 35) by ordinary least squares. Kept for
reproduction and comparison; it ignores how precisely each run was measured and so is
inefficient with noisy data.

``fit_modes`` — the efficient estimator: weighted (generalised) least squares of m, c, k directly
to all runs' (σᵢ, ω_dᵢ), through the exact dominant root sᵢ(m, c, k) of
m s² + c s + k + (Dᵢ s + Pᵢ)e^{−sΔt} = 0, each run weighted by the inverse covariance of its own
decay fit. Because each run's decay fit is the maximum-likelihood estimate of (σᵢ, ω_dᵢ) with the
nuisance amplitude, phase and offset profiled out, this second stage is (asymptotically) the
maximum-likelihood estimate of m, c, k from all the data and reaches the Cramér–Rao bound.
The Jacobian comes from implicit differentiation of the characteristic equation:
∂s/∂θ = −(∂f/∂θ)/(∂f/∂s) with ∂f/∂(m, c, k) = (s², s, 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phoid._threads import single_blas_thread
from phoid.dynamics import (
    characteristic,
    count_roots_right_of,
    count_roots_right_of_many,
    dominant_roots,
    inverse_map,
    rightmost_roots,
)
from phoid.dynamics.digital import digital_is_dominant, digital_modes
from phoid.errors import IdentificationError
from phoid.methods.chi2 import chi2_isf
from phoid.methods.estimate import Estimate

__all__ = ["Estimate", "LineFit", "MCKFit", "delay_profile", "fit_lines", "fit_modes"]


@dataclass(frozen=True)
class LineFit:
    """Ordinary least-squares fit of y = slope·x + intercept (one line of eq. 35).

    Attributes
    ----------
    slope, intercept : float
        Fitted slope and intercept (units of y per unit of x, and of y).
    slope_stderr, intercept_stderr : float
        Their standard errors from the residual scatter (nan with only two points).
    x, y : ndarray
        The fitted points.
    """

    slope: float
    intercept: float
    slope_stderr: float
    intercept_stderr: float
    x: np.ndarray
    y: np.ndarray


def _ols(x: np.ndarray, y: np.ndarray) -> LineFit:
    A = np.c_[x, np.ones_like(x)]
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    n = x.size
    if n > 2:
        r = y - A @ coef
        with np.errstate(over="ignore", invalid="ignore"):  # absurd inputs: inf, said below
            s2 = float(r @ r) / (n - 2)
            cov = s2 * np.linalg.inv(A.T @ A)
            se = np.sqrt(np.diag(cov))
    else:
        se = np.array([math.nan, math.nan])
    return LineFit(float(coef[0]), float(coef[1]), float(se[0]), float(se[1]), x, y)


@dataclass(frozen=True)
class MCKFit:
    """m, c, k from a set of runs, with covariance and diagnostics.

    Attributes
    ----------
    m, c, k : float
        Mass (kg), viscous damping (N·s/m), stiffness (N/m).
    cov : ndarray
        (3, 3) covariance of (m, c, k).
    estimator : str
        ``"gls"`` (:func:`fit_modes`) or ``"ols"`` (:func:`fit_lines`).
    compensated : bool
        Whether the delay was compensated (eqs. 28–32) or ignored.
    c_prime, k_prime : ndarray
        Per-run equivalent feedback damping and stiffness, N·s/m and N/m (eq. 32), evaluated at
        the measured σᵢ, ω_dᵢ.
    c_line, k_line : LineFit or None
        The two eq. (35) lines (OLS), kept for plots and for the paper's route.
    chi2, dof : float, int
        Weighted residual sum of squares and degrees of freedom (gls only; nan otherwise).
    warnings : tuple of str
    delay : float or None
        The loop delay Δt, s: estimated with m, c, k (``fit_modes(..., estimate_delay=True)``)
        or the given one.
    delay_stderr : float or None
        Standard error of an estimated delay, s (None when it was given).
    cov_full : ndarray or None
        (4, 4) covariance of (m, c, k, Δt) when the delay was estimated; ``cov`` is its
        (m, c, k) block, so the stderr of m, c, k include the delay's uncertainty.
    """

    m: float
    c: float
    k: float
    cov: np.ndarray
    estimator: str
    compensated: bool
    c_prime: np.ndarray
    k_prime: np.ndarray
    c_line: LineFit | None = None
    k_line: LineFit | None = None
    chi2: float = math.nan
    dof: int = 0
    warnings: tuple[str, ...] = field(default_factory=tuple)
    delay: float | None = None
    delay_stderr: float | None = None
    cov_full: np.ndarray | None = None

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors of (m, c, k)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def open_loop_omega0(m: float, k: float, cov: np.ndarray) -> Estimate:
    """Open-loop natural frequency ω₀ = √(k/m), rad/s (eq. 5), with its delta-method stderr
    from the (3, 3) covariance of (m, c, k); 0 for k = 0, nan where undefined."""
    if not (m > 0 and k > 0):
        return Estimate(0.0 if k == 0 else math.nan, None, "rad/s")
    w = math.sqrt(k / m)
    g = np.array([-0.5 * w / m, 0.0, 0.5 * w / k])
    return Estimate(w, float(math.sqrt(max(g @ cov @ g, 0.0))), "rad/s")


def open_loop_zeta(m: float, c: float, k: float, cov: np.ndarray) -> Estimate:
    """Open-loop damping ratio ζ = c/(2√(mk)) (eq. 10), with its delta-method stderr from the
    (3, 3) covariance of (m, c, k); inf for k = 0 (a mass–damper), nan where undefined."""
    if not (m > 0 and k > 0):
        return Estimate(math.inf if m > 0 and k == 0 else math.nan, None, "")
    s = 2 * math.sqrt(m * k)
    z = c / s
    g = np.array([-0.5 * z / m, 1 / s, -0.5 * z / k])
    return Estimate(z, float(math.sqrt(max(g @ cov @ g, 0.0))), "")


def _check_inputs(sigma, omega_d, P, D):
    sigma = np.atleast_1d(np.asarray(sigma, dtype=float))
    omega_d = np.atleast_1d(np.asarray(omega_d, dtype=float))
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    n = sigma.size
    if not (omega_d.size == P.size == D.size == n):
        raise ValueError("`sigma`, `omega_d`, `P` and `D` must have one entry per run")
    if n == 0:
        raise IdentificationError("no usable runs: nothing to identify")
    gains = np.unique(np.c_[P, D], axis=0)
    if gains.shape[0] < 2:
        raise IdentificationError(
            "all runs have the same gains (P, D): the lines of eq. (35) are undetermined; "
            "record runs with at least two different gain pairs"
        )
    return sigma, omega_d, P, D


def _mass_groups(dm: np.ndarray) -> list[np.ndarray]:
    """Indices of the runs sharing each added mass (one group when no mass is added)."""
    return [np.flatnonzero(dm == a) for a in np.unique(dm)]


def _digital_modes_by_mass(m, dm, c, k, P, D, digital, s_guess):
    """:func:`phoid.dynamics.digital.digital_modes` of runs whose masses are m + Δmᵢ, a call per Δm
    (the sampled plant depends on the mass); ∂s/∂m is the same as ∂s/∂(m + Δmᵢ)."""
    s = np.empty(P.size, dtype=complex)
    ds = np.empty((P.size, 3), dtype=complex)
    for idx in _mass_groups(dm):
        guess = None if s_guess is None else np.asarray(s_guess)[idx]
        s[idx], ds[idx] = digital_modes(m + dm[idx[0]], c, k, P[idx], D[idx], digital, guess)
    return s, ds


def _added(added_mass, n: int) -> np.ndarray:
    """Per-run added mass as an array (zeros if None), checked finite and ≥ 0."""
    if added_mass is None:
        return np.zeros(n)
    dm = np.broadcast_to(np.asarray(added_mass, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(dm) & (dm >= 0)):
        raise ValueError(f"`added_mass` must be finite and ≥ 0 kg; got {dm.tolist()}")
    return dm


def fit_lines(
    sigma: np.ndarray,
    omega_d: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    *,
    compensate: bool = True,
    added_mass: np.ndarray | None = None,
) -> MCKFit:
    """The paper's route: eq. (32) then the two lines of eq. (35) by ordinary least squares.

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured decay rate σᵢ (1/s) and damped frequency ω_dᵢ (rad/s) of each run.
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    compensate : bool, default True
        Correct c′ᵢ, k′ᵢ for the delay (eqs. 28–32 with the corrected α₁); False uses
        c′ᵢ = Dᵢ, k′ᵢ = Pᵢ (the paper's "without compensation").
    added_mass : array_like, optional
        Known mass Δmᵢ added in each run (kg): run i's plant mass is m + Δmᵢ, so its points
        are moved by the known part, c′ᵢ − 2Δmᵢσᵢ = 2mσᵢ − c and k′ᵢ − Δmᵢω₀ᵢ² = mω₀ᵢ² − k
        (eq. 35 with m + Δmᵢ); m is the mass without additions.

    Returns
    -------
    MCKFit
        m is the slope of the stiffness line k′ᵢ = mω₀ᵢ² − k (the better conditioned of the two;
        the damping line's slope is in ``c_line``), c and k the negated intercepts. The
        covariance is block-diagonal from the two independent OLS fits.
    """
    sigma, omega_d, P, D = _check_inputs(sigma, omega_d, P, D)
    cp, kp = inverse_map(sigma, omega_d, P, D, delay, compensate=compensate)
    dm = _added(added_mass, sigma.size)
    cp = cp - 2.0 * dm * sigma
    kp = kp - dm * (sigma**2 + omega_d**2)
    cl = _ols(2.0 * sigma, cp)
    kl = _ols(sigma**2 + omega_d**2, kp)
    cov = np.diag([kl.slope_stderr**2, cl.intercept_stderr**2, kl.intercept_stderr**2])
    warnings: list[str] = []
    if sigma.size < 3:
        warnings.append("only two runs: the eq. (35) lines have no residual, so the standard "
                        "errors of m, c, k are unknown (null in --json)")
    return MCKFit(
        m=kl.slope, c=-cl.intercept, k=-kl.intercept, cov=cov, estimator="ols",
        compensated=compensate, c_prime=cp, k_prime=kp, c_line=cl, k_line=kl,
        warnings=tuple(warnings),
    )


def _is_dominant(s, m, c, k, P, D, delay) -> bool:
    """True if the root s (Im s ≥ 0) and its conjugate are the rightmost roots of the loop.

    A cheap argument-principle count just left of s settles it; only when another root lies very
    close to the left does it fall back to the full certified root computation.
    """
    a = s.real - max(0.5, 0.5 * abs(s.real))  # 1/s: far enough from s to count cheaply
    n_expected = 1 if s.imag == 0 else 2
    try:
        if count_roots_right_of(a, m, c, k, P, D, delay, near=[s]) == n_expected:
            return True
    except (RuntimeError, ValueError):
        pass
    r0 = rightmost_roots(m, c, k, P, D, delay, count=2)[0]
    return abs(r0.real - s.real) <= 1e-6 * max(1.0, abs(r0))


def damped_gauss_newton(fun, theta, s, scale, feasible, max_iter: int):
    """Gauss–Newton with step halving, as the weighted fits of the runs' modes use it.

    Parameters
    ----------
    fun : callable
        ``fun(θ, s_guess) -> (r, J, s)``: the whitened residual, its Jacobian and the tracked
        roots (the next call's Newton start).
    theta : ndarray
        Start.
    s : ndarray of complex
        Start of the tracked roots.
    scale : ndarray
        Each parameter's scale in the experiment: the step is solved in scaled coordinates and
        judged against it (a value may be ~0, e.g. k of a mass–damper).
    feasible : callable
        ``feasible(θ) -> bool``; an infeasible trial point (m ≤ 0, Δt < 0) is halved like one
        that raises χ².
    max_iter : int
        Iterations at most.

    Returns
    -------
    (θ, r, J, s, χ², converged)
        Converged when a step taken is below 10⁻¹² of the scales, or the last step proposed
        (taken or not: no descent is left) is below 10⁻⁸ of them. A step is halved (down to
        10⁻⁶) until χ² does not rise by more than 10⁻¹² relative.
    """
    r, J, s = fun(theta, s)
    chi2 = float(r @ r)
    step = np.zeros_like(theta)
    for _ in range(max_iter):
        step = -np.linalg.lstsq(J * scale, r, rcond=None)[0] * scale
        lam = 1.0
        while lam > 1e-6:
            trial = theta + lam * step
            if feasible(trial):
                try:  # a trial whose model overflows (a long delay's powers) is rejected
                    with np.errstate(all="ignore"):
                        r_t, J_t, s_t = fun(trial, s)
                        chi2_t = float(r_t @ r_t)
                except (np.linalg.LinAlgError, ArithmeticError):
                    chi2_t = math.inf
                if np.isfinite(chi2_t) and chi2_t <= chi2 * (1 + 1e-12):
                    break
            lam *= 0.5
        else:
            break
        done = bool(np.all(np.abs(lam * step) <= 1e-12 * scale))
        theta, r, J, s, chi2 = trial, r_t, J_t, s_t, chi2_t
        if done:
            return theta, r, J, s, chi2, True
    return theta, r, J, s, chi2, bool(np.all(np.abs(step) <= 1e-8 * scale))


def dominant_many(s, m, c, k, P, D, delay) -> np.ndarray:
    """Whether each run's tracked root s (Im s ≥ 0) and its conjugate are the loop's rightmost
    roots, certified: one batched argument-principle count for all runs, and
    :func:`_is_dominant` for the runs it leaves undecided."""
    ok = _dominant_many(s, m, c, k, P, D, delay)
    mm = np.broadcast_to(np.asarray(m, dtype=float), ok.shape)
    for i in np.flatnonzero(~ok).tolist():
        ok[i] = _is_dominant(complex(s[i]), float(mm[i]), c, k, float(P[i]), float(D[i]), delay)
    return ok


def _dominant_many(s, m, c, k, P, D, delay) -> np.ndarray:
    """:func:`_is_dominant`'s cheap count for every run at once (True where it settles that
    the run's root is dominant; the others are for :func:`_is_dominant` to decide)."""
    s = np.asarray(s, dtype=complex)
    a = s.real - np.maximum(0.5, 0.5 * np.abs(s.real))
    expected = np.where(s.imag == 0, 1, 2)
    got = count_roots_right_of_many(a, m, c, k, P, D, delay, near=[[z] for z in s.tolist()])
    return got == expected


def _whiteners(cov: np.ndarray) -> np.ndarray:
    """Per-run matrices Wᵢ^{1/2} with Wᵢ = Covᵢ⁻¹ (so that ‖Wᵢ^{1/2} rᵢ‖² = rᵢᵀWᵢrᵢ)."""
    return np.linalg.inv(np.linalg.cholesky(cov))  # stacked: one LAPACK call per run, no loop


@single_blas_thread
def fit_modes(
    sigma: np.ndarray,
    omega_d: np.ndarray,
    cov: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    *,
    start: tuple[float, float, float] | None = None,
    max_iter: int = 50,
    estimate_delay: bool = False,
    digital: Any = None,
    added_mass: np.ndarray | None = None,
) -> MCKFit:
    """Weighted least squares of m, c, k to all runs' modes through the exact loop roots.

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured σᵢ (1/s) and ω_dᵢ (rad/s) of each run's dominant mode.
    cov : array_like
        (n, 2, 2) covariance of each run's (σᵢ, ω_dᵢ).
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s; with ``estimate_delay`` the starting value.
    start : (m, c, k), optional
        Starting point; by default the compensated eq. (35) OLS solution.
    max_iter : int
        Gauss–Newton iterations at most.
    estimate_delay : bool, default False
        Fit Δt too (θ = m, c, k, Δt). Only the right delay makes all runs' modes consistent
        with one plant (eq. 35's points collinear), so with at least three distinct gain pairs
        it is identifiable; ∂s/∂Δt = s(Ds + P)e^{−sΔt}/f′(s) by the implicit function theorem.
    digital : phoid.dynamics.digital.DigitalPD, optional
        A sampled (digital) loop: the modes are then the roots of its exact characteristic
        polynomial (:func:`phoid.dynamics.digital.digital_modes`) instead of the continuous delayed
        loop's; ``delay`` only serves the starting eq. (35) lines (an equivalent continuous
        delay). Not with ``estimate_delay``.
    added_mass : array_like, optional
        Known mass added in each run, kg (the paper's added-mass trick): run i's loop has mass
        m + Δmᵢ; the estimate is the mass without additions.

    Returns
    -------
    MCKFit
        Estimates minimising Σ rᵢᵀ Covᵢ⁻¹ rᵢ, rᵢ = (σ̂ᵢ − σᵢ(θ), ω̂_dᵢ − ω_dᵢ(θ)), with the
        covariance (JᵀWJ)⁻¹. If χ² exceeds its 99.9 % quantile the runs disagree more than their
        own noise explains (model error such as friction or a wrong delay): the covariance is
        then scaled by χ²/dof and a warning says so.

    Raises
    ------
    IdentificationError
        If the fit cannot converge or the tracked root stops being the dominant one.
    """
    sigma, omega_d, P, D = _check_inputs(sigma, omega_d, P, D)
    cov = np.asarray(cov, dtype=float).reshape(sigma.size, 2, 2)
    dm = _added(added_mass, sigma.size)
    lines = fit_lines(sigma, omega_d, P, D, delay, added_mass=dm)
    theta = np.array(start if start is not None else (lines.m, lines.c, lines.k), dtype=float)
    if not np.all(np.isfinite(theta)):
        raise IdentificationError(
            "the runs give no usable start for the weighted fit: the eq. (35) lines give "
            f"m = {float(theta[0]):.4g} kg, c = {float(theta[1]):.4g} N s/m, "
            f"k = {float(theta[2]):.4g} N/m")
    npar = 4 if estimate_delay else 3
    if digital is not None and estimate_delay:
        raise ValueError("`estimate_delay` is not available for a digital loop")
    if estimate_delay:
        if len({(float(a), float(b)) for a, b in zip(P, D, strict=True)}) < 3:
            raise IdentificationError(
                "estimating the loop delay needs at least three distinct gain pairs (P, D)"
            )
        theta = np.r_[theta, delay]
    # numerical floor: decay fits of noise-free records are exact only to ~1e-9 of |s_i|
    # (simulation and rounding), so a covariance at rounding level would turn that into a
    # spurious chi2; 1e-9 |s_i| in each of sigma, omega_d is far below any real noise
    floor = (1e-9 * np.hypot(sigma, omega_d)) ** 2
    cov = cov + floor[:, None, None] * np.eye(2)
    Wh = _whiteners(cov)
    meas = np.c_[sigma, omega_d]
    s = -sigma + 1j * omega_d

    def residual_and_jacobian(th, s_guess):
        m, c, k = th[:3]
        tau = th[3] if estimate_delay else delay
        if digital is not None:
            s_mod, ds = _digital_modes_by_mass(m, dm, c, k, P, D, digital, s_guess)
        else:
            s_mod = dominant_roots(m + dm, c, k, P, D, tau, s_guess)
            _, df = characteristic(s_mod, m + dm, c, k, P, D, tau)
            cols = [s_mod**2, s_mod, np.ones_like(s_mod)]
            if estimate_delay:  # ∂f/∂Δt = −s(Ds + P)e^{−sΔt}
                cols.append(-s_mod * (D * s_mod + P) * np.exp(-s_mod * tau))
            ds = -np.stack(cols, axis=1) / df[:, None]
        model = np.c_[-s_mod.real, s_mod.imag]
        # d(meas - model)/dθ = (d Re s, -d Im s)/dθ, shape (n, 2, 3)
        jac = np.stack([ds.real, -ds.imag], axis=1)
        r = np.einsum("nij,nj->ni", Wh, meas - model).ravel()
        J = np.einsum("nij,njk->nik", Wh, jac).reshape(-1, npar)
        return r, J, s_mod

    # convergence is judged against each parameter's scale in this experiment, not against
    # its value, which may be ~0 (k of a mass-damper, c of an undamped plant)
    m_scale = max(abs(theta[0]), 1e-300)
    scale = np.array([
        m_scale,
        max(abs(theta[1]), float(np.max(np.abs(D))), float(np.max(2 * m_scale * np.abs(sigma)))),
        max(abs(theta[2]), float(np.max(np.abs(P))),
            float(np.max(m_scale * (sigma**2 + omega_d**2)))),
    ][:3] + ([max(abs(theta[3]), 1e-3 / float(np.max(np.hypot(sigma, omega_d))))]
             if estimate_delay else []))
    if not theta[0] > 0:  # the lines' start is no plant: the modes fit none at this loop
        raise IdentificationError(
            f"the runs' modes give no plant at the stated loop (the start of the weighted fit "
            f"has m = {theta[0]:.3g} kg ≤ 0)")
    theta, _r, J, s, chi2, converged = damped_gauss_newton(
        residual_and_jacobian, theta, s, scale,
        lambda th: th[0] > 0 and (not estimate_delay or th[3] >= 0), max_iter)
    if not converged:
        raise IdentificationError("the weighted fit of m, c, k did not converge")
    # the tracked roots must be the dominant ones at the solution (certified check)
    m, c, k = theta[:3]
    tau = float(theta[3]) if estimate_delay else delay
    if digital is not None:
        dom = np.empty(sigma.size, dtype=bool)
        for idx in _mass_groups(dm):
            dom[idx] = digital_is_dominant(s[idx], m + dm[idx[0]], c, k, P[idx], D[idx],
                                           digital, rtol=1e-6)
        if not np.all(dom):
            raise IdentificationError(
                f"run {int(np.argmin(dom)) + 1}: the fitted mode is not the sampled loop's "
                "dominant root at the solution"
            )
    if digital is None and not np.all(dom := dominant_many(s, m + dm, c, k, P, D, tau)):
        raise IdentificationError(
            f"run {int(np.argmin(dom)) + 1}: the fitted mode is not the loop's dominant root at "
            "the solution"
        )
    JtJ = J.T @ J
    covp = np.linalg.inv(JtJ)
    dof = 2 * sigma.size - npar
    warnings: list[str] = []
    if dof > 0 and chi2 > chi2_isf(0.001, dof):
        red = chi2 / dof
        covp = covp * red
        warnings.append(
            f"the runs disagree more than their noise explains (χ²/dof = {red:.2f}); "
            "stderr scaled up accordingly: check the delay, friction or unmodelled dynamics"
        )
    cp, kp = inverse_map(sigma, omega_d, P, D, tau)
    cp = cp - 2.0 * dm * sigma
    kp = kp - dm * (sigma**2 + omega_d**2)
    if estimate_delay:
        lines = fit_lines(sigma, omega_d, P, D, tau, added_mass=dm)
    return MCKFit(
        m=float(theta[0]), c=float(theta[1]), k=float(theta[2]), cov=covp[:3, :3],
        estimator="gls", compensated=True, c_prime=cp, k_prime=kp, c_line=lines.c_line,
        k_line=lines.k_line, chi2=chi2, dof=dof, warnings=tuple(warnings), delay=tau,
        delay_stderr=float(math.sqrt(max(covp[3, 3], 0.0))) if estimate_delay else None,
        cov_full=covp if estimate_delay else None,
    )


def delay_profile(
    sigma: np.ndarray,
    omega_d: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    delays: np.ndarray,
    added_mass: np.ndarray | None = None,
) -> np.ndarray:
    """How far the runs' modes are from one plant, for each candidate loop delay (a start).

    For each Δt the modes are mapped to c′ᵢ, k′ᵢ (eq. 32) and the two lines of eq. (35) are fitted
    jointly with one mass, c′ᵢ = 2mσᵢ − c and k′ᵢ = mω₀ᵢ² − k, each line's residuals scaled by the
    spread of its c′ᵢ or k′ᵢ. Only the right delay makes the points collinear with a common
    slope, so the returned residual sum of squares is smallest near it; :func:`fit_modes` with
    ``estimate_delay=True`` then refines the minimum through the exact roots.

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured σᵢ (1/s) and ω_dᵢ (rad/s).
    P, D : array_like
        Gains, N/m and N·s/m.
    delays : array_like
        Candidate delays, s (≥ 0).

    Returns
    -------
    ndarray
        The scaled residual sum of squares at each candidate (dimensionless).
    """
    sigma, omega_d, P, D = _check_inputs(sigma, omega_d, P, D)
    n = sigma.size
    w0sq = sigma**2 + omega_d**2
    dm = _added(added_mass, n)
    out = np.empty(np.size(delays))
    for j, tau in enumerate(np.atleast_1d(np.asarray(delays, dtype=float))):
        cp, kp = inverse_map(sigma, omega_d, P, D, float(tau))
        cp, kp = cp - 2.0 * dm * sigma, kp - dm * w0sq
        sc = max(float(np.std(cp)), 1e-300)
        sk = max(float(np.std(kp)), 1e-300)
        A = np.zeros((2 * n, 3))
        A[:n, 0], A[:n, 1] = 2.0 * sigma / sc, -1.0 / sc
        A[n:, 0], A[n:, 2] = w0sq / sk, -1.0 / sk
        y = np.r_[cp / sc, kp / sk]
        coef = np.linalg.lstsq(A, y, rcond=None)[0]
        r = y - A @ coef
        out[j] = float(r @ r) if np.all(np.isfinite(r)) else math.inf
    return out
