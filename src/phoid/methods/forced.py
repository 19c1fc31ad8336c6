"""Forced harmonic (sine-sweep) identification (``method = "forced"``), seed eqs. (16)–(22).

Each run applies one sinusoidal force F(t) = B sin(ωt − θ) (eq. 16) and records x(t) and F(t).
Once the start-up transient has died the response is x_p = C sin(ωt − φ) (eq. 17), and eq. (18)
gives, per frequency (eq. 20; ERRATA 3 in docs/equations.md: R in N/m, C in m),

    k − mω² = R cos ρ,    cω = R sin ρ,    R = B/C,  ρ = φ − θ   (eq. 21).

In complex form R e^{iρ} = F̂/x̂, the ratio of the force and displacement phasors (a signal
a cos ωτ + b sin ωτ has the phasor a − ib), i.e. the dynamic stiffness k − mω² + icω.

Per run (:func:`identify_forced_data`):

1. **Force.** ω from the spectral peak of F, refined by Gauss–Newton on a sine fit
   (F = d + a cos ω(t − t_ref) + b sin ω(t − t_ref), t_ref the window's centre); B and θ from
   the same fit. The analysed window starts at the force's onset (a record may begin before
   the force is switched on, or with a ramp): a coarse start surely after it (F has left its
   initial level, and every later one-period block has the final amplitude), a sine fitted
   from there, and the onset just after the last earlier sample that departs from that sine
   (more than 5 noise sd or 10⁻³ of the amplitude), plus a tenth of a period. F must be a
   sinusoid: a sine that leaves more than 30 % rms of its amplitude unexplained
   is an error, more than 5 % a warning. The manifest's ``B`` and ``omega`` are optional
   and only checked against F.
2. **Response, with the transient modelled.** Over the same window
   x = x_off + a cos ω(t − t_ref) + b sin ω(t − t_ref) + x₀[C(τ) + σS(τ)] + v₀S(τ), τ = t − t_start:
   the steady state plus the free response of eq. (2) left by the start (C, S of
   :func:`phoid.dynamics.plant.modal_basis`, any damping). The transient's rates (σ, ω₀²) are those
   of
   the plant, shared by all runs, and are fitted jointly by variable projection
   (:func:`phoid.methods.free._fit_modal`) from a start given by a first pass on each run's second
   half. Skipping the transient instead would not do: a lightly damped plant forced near
   resonance (σ = 0.25 1/s, the acceptance set) still rings at 0.6 noise sd after 40 s, and
   its leakage into a sine fit biases R by ~10³ stderr; modelled, it costs nothing. The
   settling time (the last sample where the fitted transient exceeds the noise sd) is
   reported; a transient still above 3 noise sd at the end of the record draws a warning.
3. **R, ρ** from the phasor ratio, with the covariance of both fits (the transient rates'
   uncertainty included, correlated across runs through the shared rates).

Then m, c, k from all runs by generalised least squares on eq. (20) (:func:`fit_response`), the
frequency's own uncertainty entering through ∂(k − mω², cω)/∂ω = (−2mω, c). The seed's
two-frequency formulas of eq. (22), with ERRATA 2 (eq. 22b), are :func:`two_frequency`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from phoid import _validate as v
from phoid._threads import single_blas_thread
from phoid.errors import IdentificationError
from phoid.fits import diff_noise
from phoid.io.experiment import Run, run_from_arrays
from phoid.methods.free import (
    _esprit_rates,
    _fit_modal,
    _pick_start,
    _Prep,
    _release_basis,
    _Segment,
    _State,
)
from phoid.methods.pho import Estimate, open_loop_omega0, open_loop_zeta

__all__ = [
    "ForcedIdentification",
    "ForcedRun",
    "ResponseFit",
    "fit_response",
    "identify_forced",
    "identify_forced_data",
    "simulate_forced",
    "two_frequency",
]

#: fewest samples, and fewest forcing periods, a run's analysed window must hold
MIN_SAMPLES = 16
MIN_PERIODS = 1.0
#: fewer periods than this draw a warning
FEW_PERIODS = 3.0
#: F is rejected when a sine leaves this fraction (rms, of the sine's rms) unexplained …
F_REJECT = 0.3
#: … and flagged above this one
F_WARN = 0.05
#: a record whose peak-to-peak motion is within this many noise sds never moved
_STILL_NSD = 12.0
#: below this transient energy (in noise sds, the largest over the runs) the transient's rates
#: are not fitted (they are not determined; the transient columns stay in the model)
_TRANSIENT_SNR = 20.0
#: frequencies closer than this (relative) count as one
_SAME_OMEGA = 1e-3


# --------------------------------------------------------------------------------------------
# eqs. (20) and (22)


def two_frequency(
    omega_i: float, R_i: float, rho_i: float, omega_j: float, R_j: float, rho_j: float
) -> tuple[float, float, float]:
    """m, c, k from two frequencies by the seed's eq. (22), with ERRATA 2 applied to eq. (22b).

    Parameters
    ----------
    omega_i, omega_j : float
        The two forcing frequencies, rad/s (distinct, > 0).
    R_i, R_j : float
        Relative stiffness R = B/C at each, N/m (eq. 21; ERRATA 3: C is a displacement).
    rho_i, rho_j : float
        Phase lag ρ = φ − θ of x behind F at each, rad (eq. 21).

    Returns
    -------
    m, c, k : float
        kg, N·s/m, N/m:

        - m = (R_j cos ρ_j − R_i cos ρ_i)/(ω_i² − ω_j²)                  (eq. 22a)
        - c = (ω_j R_i sin ρ_i + ω_i R_j sin ρ_j)/(2 ω_i ω_j)           (eq. 22b, corrected)
        - k = (ω_i² R_j cos ρ_j − ω_j² R_i cos ρ_i)/(ω_i² − ω_j²)      (eq. 22c)

        The printed eq. (22b) repeats the j term; the corrected form is the mean of the two
        per-frequency values R sin ρ/ω of eq. (20).

    Raises
    ------
    ValueError
        If the frequencies are equal, not positive or not finite.

    Examples
    --------
    >>> import numpy as np
    >>> Z = lambda w: 64 - 2 * w**2 + 1j * w  # m = 2, c = 1, k = 64: R e^{iρ} of eq. (20)
    >>> m, c, k = two_frequency(3, abs(Z(3)), np.angle(Z(3)), 9, abs(Z(9)), np.angle(Z(9)))
    >>> round(m, 12), round(c, 12), round(k, 12)
    (2.0, 1.0, 64.0)
    """
    wi = v.positive("omega_i", omega_i, "rad/s")
    wj = v.positive("omega_j", omega_j, "rad/s")
    if wi == wj:
        raise ValueError(f"`omega_i` and `omega_j` must differ; both are {wi:g} rad/s")
    Ri, Rj = v.finite("R_i", R_i, "N/m"), v.finite("R_j", R_j, "N/m")
    pi, pj = v.finite("rho_i", rho_i, "rad"), v.finite("rho_j", rho_j, "rad")
    den = wi * wi - wj * wj
    m = (Rj * math.cos(pj) - Ri * math.cos(pi)) / den
    c = (wj * Ri * math.sin(pi) + wi * Rj * math.sin(pj)) / (2.0 * wi * wj)
    k = (wi * wi * Rj * math.cos(pj) - wj * wj * Ri * math.cos(pi)) / den
    return m, c, k


@dataclass(frozen=True)
class ResponseFit:
    """m, c, k from per-frequency dynamic stiffnesses by generalised least squares (eq. 20).

    Attributes
    ----------
    m, c, k : float
        kg, N·s/m, N/m.
    cov : ndarray, shape (3, 3)
        Covariance of (m, c, k) (scaled by χ²/dof when the runs disagree, see ``warnings``).
    chi2 : float
        Weighted residual sum of squares.
    dof : int
        2n − 3 for n runs.
    warnings : tuple of str
    """

    m: float
    c: float
    k: float
    cov: np.ndarray = field(repr=False)
    chi2: float
    dof: int
    warnings: tuple[str, ...] = ()

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors of (m, c, k)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def fit_response(
    omega: Any,
    Z: Any,
    cov: Any,
    *,
    omega_var: Any = None,
    added_mass: Any = None,
) -> ResponseFit:
    """m, c, k from R e^{iρ} at several frequencies: GLS on eq. (20).

    Re Zᵢ = k − (m + m_aᵢ) ωᵢ² and Im Zᵢ = c ωᵢ, Zᵢ = Rᵢ e^{iρᵢ}, weighted by the inverse of the
    full covariance of the stacked (Re Z₁, Im Z₁, …, Re Zₙ, Im Zₙ), to which each frequency's
    own variance adds var ωᵢ · hᵢhᵢᵀ with hᵢ = (−2mωᵢ, c) (the model's derivative in ω,
    evaluated at a first solution and then iterated once).

    Parameters
    ----------
    omega : array_like, shape (n,)
        Forcing frequencies, rad/s.
    Z : array_like of complex, shape (n,)
        Dynamic stiffness R e^{iρ} at each, N/m.
    cov : array_like, shape (2n, 2n) or (n, 2, 2)
        Covariance of the stacked real and imaginary parts (full, or per-run blocks).
    omega_var : array_like, shape (n,), optional
        Variance of each ω, (rad/s)².
    added_mass : array_like, shape (n,), optional
        Known mass added in each run, kg (then m is the mass without it).

    Returns
    -------
    ResponseFit

    Raises
    ------
    IdentificationError
        With fewer than two distinct frequencies (m and k are then not separable) or a
        singular covariance.
    """
    w = v.finite_array("omega", omega, ndim=1)
    Zc = np.asarray(Z, dtype=complex).ravel()
    n = w.size
    if Zc.size != n:
        raise ValueError(f"`Z` must have one value per frequency; got {Zc.size} for {n}")
    if not np.all(np.isfinite(Zc)):
        raise ValueError("`Z` must be finite")
    C = np.asarray(cov, dtype=float)
    if C.shape == (n, 2, 2):
        full = np.zeros((2 * n, 2 * n))
        for i in range(n):
            full[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = C[i]
        C = full
    if C.shape != (2 * n, 2 * n):
        raise ValueError(f"`cov` must have shape ({2 * n}, {2 * n}) or ({n}, 2, 2); "
                         f"got {C.shape}")
    wv = np.zeros(n) if omega_var is None else v.finite_array("omega_var", omega_var, ndim=1)
    ma = np.zeros(n) if added_mass is None else v.finite_array("added_mass", added_mass, ndim=1)
    distinct = _distinct(w)
    if distinct < 2:
        raise IdentificationError(
            f"all runs are forced at one frequency ({float(np.mean(w)):.6g} rad/s): m and k "
            "are not separable (eq. 20 needs at least two distinct frequencies)")
    y = np.empty(2 * n)
    y[0::2] = Zc.real + ma * w * w
    y[1::2] = Zc.imag
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = -w * w
    A[0::2, 2] = 1.0
    A[1::2, 1] = w
    theta, covp, chi2 = _gls(A, y, C)
    for _ in range(2 if np.any(wv > 0) else 0):
        # the frequencies' own errors: var ωᵢ · hᵢhᵢᵀ, hᵢ = ∂(k − (m + m_aᵢ)ω², cω)/∂ω
        h = np.zeros((2 * n, n))
        h[0::2] = np.diag(-2.0 * (theta[0] + ma) * w)
        h[1::2] = np.diag(np.full(n, theta[1]))
        theta, covp, chi2 = _gls(A, y, C + (h * wv) @ h.T)
    dof = 2 * n - 3
    warnings: list[str] = []
    if dof > 0 and chi2 > stats.chi2.ppf(0.999, dof):
        red = chi2 / dof
        covp = covp * red
        warnings.append(
            f"the runs disagree with eq. (20) more than their noise explains (chi2/dof = "
            f"{red:.3g}); stderr scaled up accordingly: check for nonlinearity (friction, "
            "amplitude-dependent stiffness) or a force not acting on the measured mass")
    return ResponseFit(m=float(theta[0]), c=float(theta[1]), k=float(theta[2]), cov=covp,
                       chi2=float(chi2), dof=dof, warnings=tuple(warnings))


def _distinct(w: np.ndarray) -> int:
    """Number of distinct frequencies (closer than 10⁻³ relative counts as one)."""
    ws = np.sort(w)
    gaps = np.diff(ws) > _SAME_OMEGA * ws[1:]
    return int(1 + np.count_nonzero(gaps))


def _gls(A: np.ndarray, y: np.ndarray, Sigma: np.ndarray):
    """Generalised least squares with a full covariance (Cholesky whitening)."""
    scale = np.sqrt(np.clip(np.diag(Sigma), 1e-300, None))
    Sn = Sigma / np.outer(scale, scale)
    try:
        L = np.linalg.cholesky(Sn + 1e-14 * np.eye(Sn.shape[0]))
    except np.linalg.LinAlgError:
        raise IdentificationError("the covariance of the measured R, ρ is singular") from None
    Aw = np.linalg.solve(L, A / scale[:, None])
    yw = np.linalg.solve(L, y / scale)
    Q, R = np.linalg.qr(Aw)
    theta = np.linalg.solve(R, Q.T @ yw)
    r = yw - Aw @ theta
    Rinv = np.linalg.inv(R)
    return theta, Rinv @ Rinv.T, float(r @ r)


# --------------------------------------------------------------------------------------------
# the force: frequency, amplitude, phase, window


@dataclass(frozen=True)
class _Force:
    start: int
    omega: float
    omega_var: float
    t_ref: float
    coef: np.ndarray  # (d, a, b)
    cov_ab: np.ndarray  # (2, 2)
    noise: float
    distortion: float


def _spectral_peak(t: np.ndarray, y: np.ndarray) -> float:
    """Angular frequency of the largest spectral peak (zero-padded FFT, parabolic vertex)."""
    n = t.size
    dt = (t[-1] - t[0]) / (n - 1)
    yg = np.interp(t[0] + dt * np.arange(n), t, y)
    yg = yg - yg.mean()
    nfft = 4 << max(math.ceil(math.log2(n)), 4)
    spec = np.abs(np.fft.rfft(yg * np.hanning(n), nfft))
    k = int(np.argmax(spec[1:])) + 1
    shift = 0.0
    if 1 <= k < spec.size - 1:
        a, b, c = np.log(spec[k - 1 : k + 2] + 1e-300)
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den < 0 else 0.0
    return 2 * math.pi * (k + shift) / (nfft * dt)


def _sine_fit(tau: np.ndarray, y: np.ndarray, omega: float):
    """Least squares y ≈ d + a cos ωτ + b sin ωτ (normal equations: on a window of a period or
    more centred on τ = 0 the three columns are nearly orthogonal). Returns the columns, the
    inverse normal matrix, the coefficients and the residual."""
    G = np.column_stack([np.ones_like(tau), np.cos(omega * tau), np.sin(omega * tau)])
    Ninv = np.linalg.inv(G.T @ G)
    coef = Ninv @ (G.T @ y)
    return G, Ninv, coef, y - G @ coef


def _onset(t: np.ndarray, F: np.ndarray, omega: float) -> int:
    """First sample from which F has a constant amplitude.

    F is demodulated at ``omega`` in one-period blocks (at least 16 samples); a block is good
    when its amplitude is within 2 % (+ 5 noise sd of a block amplitude) of the median of the
    later half. The window starts one block after the last bad one: the block holding the
    onset itself may pass the test when the force starts in its first few per cent, and
    must not be analysed (the response model assumes the force on throughout the window).
    """
    n = t.size
    dt = (t[-1] - t[0]) / (n - 1)
    L = max(MIN_SAMPLES, round(2 * math.pi / omega / dt))
    nb = n // L
    if nb < 4:
        return 0
    tb = t[: nb * L].reshape(nb, L)
    yb = F[: nb * L].reshape(nb, L)
    tb = tb - tb[:, :1]
    G = np.stack([np.ones_like(tb), np.cos(omega * tb), np.sin(omega * tb)], axis=2)
    GtG = np.einsum("bij,bik->bjk", G, G)
    Gty = np.einsum("bij,bi->bj", G, yb)
    try:
        coef = np.linalg.solve(GtG, Gty[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return 0
    amp = np.hypot(coef[:, 1], coef[:, 2])
    ref = float(np.median(amp[nb // 2 :]))
    tol = 0.02 * ref + 5.0 * diff_noise(F) * math.sqrt(2.0 / L)
    bad = np.flatnonzero(np.abs(amp - ref) > tol)
    if bad.size == 0:
        return 0
    first_good = int(bad[-1]) + 2
    return first_good * L if first_good < nb else 0


def _step(t: np.ndarray) -> float:
    return float(t[-1] - t[0]) / (t.size - 1)


def _refine_omega(tw: np.ndarray, Fw: np.ndarray, omega: float, where: str):
    """Gauss–Newton on ω of the sine fit over the window (time origin at its centre); returns
    ω, the coefficients (d, a, b) and the residual sd."""
    tau = tw - 0.5 * (tw[0] + tw[-1])
    for _ in range(30):
        G, Ninv, coef, r = _sine_fit(tau, Fw, omega)
        J = tau * (-coef[1] * np.sin(omega * tau) + coef[2] * np.cos(omega * tau))
        Jt = J - G @ (Ninv @ (G.T @ J))
        jj = float(Jt @ Jt)
        if not jj > 0:
            break
        step = float(Jt @ r) / jj
        nsd2 = float(r @ r) / max(r.size - 4, 1)
        omega += step
        if not omega > 0:
            raise IdentificationError(f"{where}: column 'F' is not sinusoidal (no frequency "
                                      "could be fitted)")
        # converged: the step is below 10⁻³ stderr, or at rounding level (noise-free F)
        if step * step <= 1e-6 * nsd2 / jj or abs(step) <= 1e-13 * omega:
            break
    _G, _Ninv, coef, r = _sine_fit(tau, Fw, omega)
    return omega, coef, math.sqrt(float(r @ r) / max(r.size - 4, 1))


def _fit_force(t: np.ndarray, F: np.ndarray, where: str) -> _Force:
    """Frequency, phasor and window of one run's force (Gauss–Newton on the sine fit)."""
    if not np.ptp(F) > 0:
        raise IdentificationError(f"{where}: column 'F' is constant ({F[0]:g} N): no forcing")
    omega = _spectral_peak(t, F)
    # a coarse start surely after the onset: F has left its initial level (a force switched
    # on after a rest) and every later one-period block has the final amplitude (a ramp)
    level = float(np.median(F[:8]))
    moved = np.flatnonzero(np.abs(F - level) > 5 * diff_noise(F) + 1e-3 * float(np.ptp(F)))
    coarse = max(int(moved[0]) if moved.size else 0, _onset(t, F, omega))
    if coarse > t.size - MIN_SAMPLES:
        coarse = 0
    omega, coef, nsd = _refine_omega(t[coarse:], F[coarse:], omega, where)
    # the exact onset, with the sine fitted after the coarse one: just after the last earlier
    # sample where F departs from that sine by more than 5 noise sd or 10⁻³ of its amplitude,
    # plus a tenth of a period (a force switched on at a zero crossing departs from 0 only
    # gradually); the whole record when F follows the sine throughout
    t_ref = 0.5 * (t[coarse] + t[-1])
    head = t[: coarse + 1] - t_ref
    model = coef[0] + coef[1] * np.cos(omega * head) + coef[2] * np.sin(omega * head)
    amp = math.hypot(coef[1], coef[2])
    bad = np.flatnonzero(np.abs(F[: coarse + 1] - model) > max(5 * nsd, 1e-3 * amp))
    start = 0
    if bad.size:
        margin = max(2, round(0.1 * 2 * math.pi / omega / _step(t)))
        start = min(int(bad[-1]) + 1 + margin, coarse)
    if start != coarse:
        omega, coef, nsd = _refine_omega(t[start:], F[start:], omega, where)
    tw, Fw = t[start:], F[start:]
    t_ref = 0.5 * (tw[0] + tw[-1])
    tau = tw - t_ref
    G, Ninv, coef, r = _sine_fit(tau, Fw, omega)
    amp = math.hypot(coef[1], coef[2])
    dof = max(r.size - 4, 1)
    nsd = max(math.sqrt(float(r @ r) / dof), 1e-13 * amp)
    J = tau * (-coef[1] * np.sin(omega * tau) + coef[2] * np.cos(omega * tau))
    Jt = J - G @ (Ninv @ (G.T @ J))
    omega_var = nsd * nsd / max(float(Jt @ Jt), 1e-300)
    cov = nsd * nsd * Ninv
    distortion = math.sqrt(float(r @ r) / r.size) / (amp / math.sqrt(2)) if amp > 0 else math.inf
    if not distortion <= F_REJECT:
        raise IdentificationError(
            f"{where}: column 'F' is not sinusoidal: the best sine ({omega:.6g} rad/s, "
            f"amplitude {amp:.4g} N) leaves {distortion:.0%} rms unexplained (at most "
            f"{F_REJECT:.0%} allowed)")
    return _Force(start=start, omega=float(omega), omega_var=float(omega_var),
                  t_ref=float(t_ref), coef=coef, cov_ab=cov[1:, 1:], noise=nsd,
                  distortion=float(distortion))


# --------------------------------------------------------------------------------------------
# results


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class ForcedRun:
    """One forced run: frequency, amplitudes, R and ρ (eq. 21) with their uncertainties.

    Attributes
    ----------
    file : str
        Data file (as named in the manifest).
    omega, omega_stderr : float
        Forcing frequency from F, rad/s.
    B, B_stderr : float
        Force amplitude from F, N (eq. 16).
    C, C_stderr : float
        Steady-state displacement amplitude, m (eq. 17; ERRATA 3).
    R, R_stderr : float
        Relative stiffness B/C, N/m (eq. 21).
    rho, rho_stderr : float
        Phase lag of x behind F, rad, in (−π, π] (eq. 21).
    Z : complex
        R e^{iρ} = k − mω² + icω (eq. 20), N/m.
    Z_cov : ndarray, shape (2, 2)
        Covariance of (Re Z, Im Z), (N/m)².
    t_start, t_end : float
        Analysed window (from the force's constant-amplitude onset to the end), s.
    t_ref : float
        Time origin of the phasors, s.
    settle_time : float
        Time after which the fitted start-up transient stays below the noise sd, s
        (``t_start`` if it never exceeds it).
    settled : bool
        False when the transient is still above 3 noise sd at the end of the record.
    periods : float
        Forcing periods in the window.
    noise_sd, residual_rms : float
        White-noise sd and RMS residual of x, m.
    F_distortion : float
        RMS of F not explained by the sine, relative to the sine's rms.
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    coef : ndarray
        Fitted (x_off, a, b, x₀, v₀) of the response model (see :meth:`model`).
    transient_rates : (float, float)
        (σ, ω₀²) of the transient model, 1/s and 1/s².
    """

    file: str
    omega: float
    omega_stderr: float
    B: float
    B_stderr: float
    C: float
    C_stderr: float
    R: float
    R_stderr: float
    rho: float
    rho_stderr: float
    Z: complex
    Z_cov: np.ndarray = field(repr=False)
    t_start: float = math.nan
    t_end: float = math.nan
    t_ref: float = math.nan
    settle_time: float = math.nan
    settled: bool = True
    periods: float = math.nan
    noise_sd: float = math.nan
    residual_rms: float = math.nan
    F_distortion: float = math.nan
    used: bool = True
    warnings: tuple[str, ...] = ()
    coef: np.ndarray = field(default_factory=lambda: np.full(5, np.nan), repr=False)
    transient_rates: tuple[float, float] = (math.nan, math.nan)

    def model(self, t: np.ndarray | float, *, transient: bool = True) -> np.ndarray:
        """Fitted x at times ``t`` (s), m: offset, steady state and (optionally) transient."""
        t = np.asarray(t, dtype=float)
        d, a, b, x0, v0 = self.coef
        tau = t - self.t_ref
        out = d + a * np.cos(self.omega * tau) + b * np.sin(self.omega * tau)
        if transient:
            B1, B2 = _release_basis(np.maximum(t - self.t_start, 0.0), *self.transient_rates)
            out = out + np.where(t >= self.t_start, x0 * B1 + v0 * B2, 0.0)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the keys of ``phoid identify --json``'s ``runs``)."""
        return {
            "file": self.file,
            "omega": _num(self.omega), "omega_stderr": _num(self.omega_stderr),
            "R": _num(self.R), "R_stderr": _num(self.R_stderr),
            "rho": _num(self.rho), "rho_stderr": _num(self.rho_stderr),
            "B": _num(self.B), "B_stderr": _num(self.B_stderr),
            "C": _num(self.C), "C_stderr": _num(self.C_stderr),
            "t_start": _num(self.t_start), "t_end": _num(self.t_end),
            "settle_time": _num(self.settle_time), "settled": self.settled,
            "periods": _num(self.periods),
            "noise_sd": _num(self.noise_sd), "residual_rms": _num(self.residual_rms),
            "F_distortion": _num(self.F_distortion),
            "used": self.used,
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True)
class ForcedIdentification:
    """Result of :func:`identify_forced`: m, c, k with uncertainties, per-run R and ρ.

    Attributes
    ----------
    m, c, k : Estimate
        Mass (kg), viscous damping (N s/m), stiffness (N/m).
    fit : ResponseFit
        The eq. (20) fit (covariance, χ², dof).
    runs : tuple of ForcedRun
    transient : (float, float)
        (σ, ω₀²) of the start-up transient model, 1/s and 1/s².
    transient_fitted : bool
        Whether those rates were fitted (False: the transient was too weak to determine them).
    warnings : tuple of str
    source : str
    """

    m: Estimate
    c: Estimate
    k: Estimate
    fit: ResponseFit
    runs: tuple[ForcedRun, ...]
    transient: tuple[float, float] = (math.nan, math.nan)
    transient_fitted: bool = False
    warnings: tuple[str, ...] = ()
    source: str = ""
    data: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...] = field(default=(), repr=False)

    @property
    def cov(self) -> np.ndarray:
        """(3, 3) covariance of (m, c, k)."""
        return self.fit.cov

    @property
    def omega0(self) -> Estimate:
        """ω₀ = √(k/m), rad/s (eq. 5), delta-method stderr."""
        return open_loop_omega0(self.m.value, self.k.value, self.cov)

    @property
    def zeta(self) -> Estimate:
        """ζ = c/(2√(mk)) (eq. 10), delta-method stderr."""
        return open_loop_zeta(self.m.value, self.c.value, self.k.value, self.cov)

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --json`` for a forced set.

        Keys: ``method`` ("forced"), ``m``, ``c``, ``k`` (``{"value", "stderr", "unit"}``),
        ``omega0`` and ``zeta`` when defined, ``runs`` (per run ``file``, ``omega``, ``R``
        (N/m), ``rho`` (rad), each with ``*_stderr``, plus ``B``, ``C``, the window, settling
        and diagnostics), ``warnings``.
        """
        out: dict[str, Any] = {
            "method": "forced",
            "m": self.m.to_dict(),
            "c": self.c.to_dict(),
            "k": self.k.to_dict(),
        }
        for key in ("omega0", "zeta"):
            est = getattr(self, key)
            if math.isfinite(est.value):
                out[key] = est.to_dict()
        out["runs"] = [r.to_dict() for r in self.runs]
        out["warnings"] = list(self.warnings)
        return out

    def report(self) -> str:
        """Plain-text report: m, c, k ± stderr, ω₀, ζ, per-run table, warnings."""
        from phoid.reports.text import format_estimate

        lines = [f"phoid identify (forced): {self.source}" if self.source
                 else "phoid identify (forced)", ""]
        for name, est in (("m", self.m), ("c", self.c), ("k", self.k)):
            lines.append(f"  {name} = {format_estimate(est.value, est.stderr)} {est.unit}")
        w0, z = self.omega0, self.zeta
        if math.isfinite(w0.value):
            lines.append(f"  ω₀ = {format_estimate(w0.value, w0.stderr)} rad/s,  "
                         f"ζ = {format_estimate(z.value, z.stderr)}")
        lines.append("")
        lines.append(f"  {'run':<16}{'ω rad/s':>12}{'B N':>10}{'C m':>11} {'R N/m':>22} "
                     f"{'ρ rad':>22}{'settled s':>11}")
        for r in self.runs:
            mark = "" if r.used else "  (set aside)"
            lines.append(
                f"  {r.file:<16}{r.omega:>12.6g}{r.B:>10.4g}{r.C:>11.4g} "
                f"{format_estimate(r.R, r.R_stderr):>22} {format_estimate(r.rho, r.rho_stderr):>22}"
                f"{r.settle_time - r.t_start:>11.3g}{mark}")
        if self.warnings:
            lines += ["", "warnings:"] + [f"  - {w}" for w in self.warnings]
        return "\n".join(lines)

    def plot(self, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
        """Write per-run fits (x, model, residual; F) and the eq. (20) lines as PNG files.

        ``out_dir`` is created if needed; existing files are replaced only with ``overwrite``
        and links in it are refused (:mod:`phoid._output`; all names checked before the first
        figure is written). Returns the list of paths written.
        """
        from matplotlib.figure import Figure

        from phoid._output import OutputFolder
        from phoid.reports.text import save_png

        plotted = [i for i, r in enumerate(self.runs) if r.used and i < len(self.data)]
        names = {i: f"forced-{i + 1:02d}-{Path(self.runs[i].file).name.split('.')[0]}.png"
                 for i in plotted}
        out = OutputFolder(out_dir, overwrite=overwrite)
        out.check([*names.values(), "eq20-lines.png"])
        written: list[Path] = []
        for i in plotted:
            r = self.runs[i]
            t, x, F = self.data[i]
            sel = t >= r.t_start
            model = r.model(t[sel])
            fig = Figure(figsize=(8, 6.5), layout="constrained")
            ax, axr, axf = fig.subplots(3, 1, sharex=True, height_ratios=[3, 1, 1.2])
            ax.plot(t, x * 1e3, lw=0.6, color="0.5", label="record")
            ax.plot(t[sel], model * 1e3, lw=0.9, color="C0", label="steady state + transient")
            ax.axvline(r.settle_time, color="C3", ls=":", lw=1, label="transient < noise")
            ax.set_ylabel("x (mm)")
            ax.set_title(f"{r.file}: ω = {r.omega:.5g} rad/s, R = {r.R:.5g} N/m, "
                         f"ρ = {r.rho:.4g} rad")
            ax.legend(loc="upper right", fontsize=8)
            axr.plot(t[sel], (x[sel] - model) * 1e3, lw=0.5, color="C1")
            axr.set_ylabel("residual (mm)")
            axf.plot(t, F, lw=0.6, color="C2")
            axf.set_ylabel("F (N)")
            axf.set_xlabel("t (s)")
            written.append(save_png(fig, out, names[i]))
        written.append(self._eq20_figure(out, "eq20-lines.png"))
        return written

    def _eq20_figure(self, out: Any, name: str) -> Path:
        from matplotlib.figure import Figure

        from phoid.reports.text import save_png

        used = [r for r in self.runs if r.used]
        w = np.array([r.omega for r in used])
        Z = np.array([r.Z for r in used])
        se = np.array([np.sqrt(np.clip(np.diag(r.Z_cov), 0, None)) for r in used])
        m, c, k = self.m.value, self.c.value, self.k.value
        fig = Figure(figsize=(11, 4.5), layout="constrained")
        a, b = fig.subplots(1, 2)
        a.errorbar(w**2, Z.real, yerr=se[:, 0], fmt="o", ms=4, capsize=2)
        xx = np.linspace(0, (w**2).max() * 1.05, 50)
        a.plot(xx, k - m * xx, "-", label=f"k − mω²: m = {m:.5g} kg, k = {k:.5g} N/m")
        a.axhline(0, color="0.7", lw=0.5)
        a.set_xlabel("ω² (rad²/s²)")
        a.set_ylabel("R cos ρ (N/m)")
        a.legend(fontsize=8)
        b.errorbar(w, Z.imag, yerr=se[:, 1], fmt="o", ms=4, capsize=2)
        xx = np.linspace(0, w.max() * 1.05, 50)
        b.plot(xx, c * xx, "-", label=f"cω: c = {c:.5g} N s/m")
        b.set_xlabel("ω (rad/s)")
        b.set_ylabel("R sin ρ (N/m)")
        b.legend(fontsize=8)
        fig.suptitle("eq. (20), per-run error bars ±1 stderr")
        return save_png(fig, out, name)


# --------------------------------------------------------------------------------------------
# the pipeline


def identify_forced(experiment: Any) -> ForcedIdentification:
    """Identify m, c, k from a forced (sine-sweep) experiment set (eqs. 16–22).

    Parameters
    ----------
    experiment : phoid.io.experiment.ExperimentSet
        A set with ``method = "forced"``: each run one frequency, columns t, x and F.

    Returns
    -------
    ForcedIdentification

    Raises
    ------
    IdentificationError
        If the set is not forced, a run lacks F or F is not sinusoidal, a run carries
        feedback gains, or fewer than two distinct frequencies remain usable.
    """
    where = str(getattr(experiment, "path", ""))
    method = getattr(experiment, "method", "forced")
    if method != "forced":
        raise IdentificationError(f"{where}: method = {method!r} is not a forced set")
    runs = list(experiment.runs)
    if not runs:
        raise IdentificationError(f"{where}: no runs")
    for r in runs:
        if (r.P or 0.0) != 0.0 or (r.D or 0.0) != 0.0:
            raise IdentificationError(
                f"{where}: {r.name}: P = {r.P}, D = {r.D}: forced runs are taken to have no "
                "feedback loop")
    result = identify_forced_data(
        [(r.t, r.x, r.F) for r in runs],
        B=[r.B for r in runs], omega=[r.omega for r in runs],
        added_mass=[getattr(r, "added_mass", 0.0) for r in runs],
        files=[r.file for r in runs], names=[f"{where}: {r.name}" for r in runs],
        labels=[r.name for r in runs], source=where,
    )
    if getattr(experiment, "loop", None):
        from dataclasses import replace

        result = replace(result, warnings=(*result.warnings,
                                           "[loop] is ignored for a forced set"))
    return result


@single_blas_thread
def identify_forced_data(
    data: Sequence[tuple[Any, Any, Any]],
    *,
    B: Sequence[float | None] | None = None,
    omega: Sequence[float | None] | None = None,
    added_mass: Sequence[float] | None = None,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    labels: Sequence[str] | None = None,
    source: str = "",
) -> ForcedIdentification:
    """:func:`identify_forced` on plain arrays: ``data`` is a sequence of (t, x, F) per run.

    Parameters
    ----------
    data : sequence of (array_like, array_like, array_like or None)
        Each run's times (s), positions (m) and applied force (N).
    B, omega : sequence of float or None, optional
        Nominal force amplitude (N) and frequency (rad/s) per run, checked against F.
    added_mass : sequence of float, optional
        Known mass added in each run, kg.
    files : sequence of str, optional
        Run labels for the result (data-file names).
    names : sequence of str, optional
        Run names for error messages (e.g. ``"set/experiment.toml: run 3 (run03.csv)"``).
    labels : sequence of str, optional
        Short run names for warnings (default: ``files``).
    source : str
        Where the data came from, for the report.

    Returns
    -------
    ForcedIdentification

    Raises
    ------
    IdentificationError
        A run without F or with F not sinusoidal (the message names the run and column 'F'),
        or fewer than two distinct usable frequencies.
    ValueError
        Malformed arrays.
    """
    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    names = list(names) if names is not None else files
    labels = list(labels) if labels is not None else files
    Bn = list(B) if B is not None else [None] * n
    wn = list(omega) if omega is not None else [None] * n
    ma = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    arrays: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    forces: list[_Force | None] = []
    reasons: list[str | None] = []
    run_warn: list[list[str]] = [[] for _ in range(n)]
    for i, item in enumerate(data):
        t, x, F = item
        if F is None:
            raise IdentificationError(
                f"{names[i]}: missing column 'F': a forced run needs the applied force F (N)")
        try:
            t = v.finite_array("t", t, ndim=1)
            x = v.finite_array("x", x, ndim=1)
            F = v.finite_array("F", F, ndim=1)
        except ValueError as exc:
            raise ValueError(f"{names[i]}: {exc}") from None
        if not (t.shape == x.shape == F.shape):
            raise ValueError(f"{names[i]}: columns 't', 'x' and 'F' must have the same length")
        if t.size >= 2 and not (np.diff(t) > 0).all():
            raise ValueError(f"{names[i]}: `t` must be strictly increasing")
        arrays.append((t, x, F))
        if t.size < MIN_SAMPLES:
            forces.append(None)
            reasons.append(f"too short: {t.size} samples (at least {MIN_SAMPLES} are needed)")
            continue
        f = _fit_force(t, F, names[i])
        forces.append(f)
        nw = t.size - f.start
        periods = f.omega * float(t[-1] - t[f.start]) / (2 * math.pi)
        nsd = diff_noise(x[f.start:])
        ptp = float(np.ptp(x[f.start:]))
        if nw < MIN_SAMPLES or periods < MIN_PERIODS:
            reasons.append(f"too short: {nw} samples, {periods:.2g} forcing periods after the "
                           f"force's onset (at least {MIN_SAMPLES} samples and "
                           f"{MIN_PERIODS:g} period)")
        elif not ptp > _STILL_NSD * nsd or ptp == 0.0:
            reasons.append(f"x never moves: its peak-to-peak {ptp:.3g} m is within the noise "
                           f"(sd {nsd:.3g} m)")
        else:
            reasons.append(None)
        if f.distortion > F_WARN:
            run_warn[i].append(f"F deviates from a sinusoid by {f.distortion:.0%} rms "
                               "(harmonics or noise): only its fundamental is used")
        if periods < FEW_PERIODS and reasons[-1] is None:
            run_warn[i].append(f"only {periods:.1f} forcing periods in the record")
        if wn[i] is not None:
            se = math.sqrt(f.omega_var)
            if abs(f.omega - wn[i]) > max(5 * se, 1e-3 * wn[i]):
                run_warn[i].append(f"the manifest's omega = {wn[i]:g} rad/s differs from F's "
                                   f"frequency {f.omega:.6g} rad/s; F's is used")
        if Bn[i] is not None:
            amp = math.hypot(f.coef[1], f.coef[2])
            if abs(amp - abs(Bn[i])) > 0.02 * abs(Bn[i]):
                run_warn[i].append(f"the manifest's B = {Bn[i]:g} N differs from F's "
                                   f"amplitude {amp:.5g} N; F's is used")
    used = [i for i in range(n) if reasons[i] is None]
    prefix = f"{source}: " if source else ""
    if not used:
        raise IdentificationError(
            prefix + "no usable runs: "
            + "; ".join(f"{labels[i]}: {reasons[i]}" for i in range(n)))
    om = np.array([forces[i].omega for i in used])  # type: ignore[union-attr]
    if _distinct(om) < 2:
        raise IdentificationError(
            f"{prefix}all usable runs are forced at one frequency ({float(om.mean()):.6g} "
            "rad/s): m, c and k are undetermined (eq. 20 needs at least two distinct "
            "frequencies)")

    segs: list[_Segment] = []
    for i in used:
        t, x, _F = arrays[i]
        f = forces[i]
        assert f is not None
        tw = t[f.start:]
        tau = tw - f.t_ref
        fixed = np.column_stack([np.ones_like(tw), np.cos(f.omega * tau),
                                 np.sin(f.omega * tau)])
        segs.append(_Segment(t=tw, x=x[f.start:], fixed=fixed, t0=float(tw[0])))
    noise0 = [max(diff_noise(s.x), 1e-13 * float(np.ptp(s.x))) for s in segs]
    rates, fit_rates = _transient_start(segs, [forces[i] for i in used], noise0,  # type: ignore
                                        ma[used])
    modal = _fit_modal(segs, rates[0], rates[1], noise=noise0, fit_rates=fit_rates)
    warnings: list[str] = []
    if fit_rates and not modal.converged:
        warnings.append("the start-up transient's fit did not converge")

    # phasors, their covariance (correlated across runs through the shared rates)
    nu = len(used)
    cov_u = np.zeros((2 * nu, 2 * nu))
    for p in range(nu):
        Kp = modal.K[p][1:3]
        for q in range(nu):
            if p == q:
                cov_u[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = modal.coef_cov[p][1:3, 1:3]
            else:
                Kq = modal.K[q][1:3]
                cov_u[2 * p : 2 * p + 2, 2 * q : 2 * q + 2] = Kp @ modal.cov @ Kq.T
    Jx = np.zeros((2 * nu, 2 * nu))
    covF = np.zeros((2 * nu, 2 * nu))
    Z = np.empty(nu, dtype=complex)
    Px = np.empty(nu, dtype=complex)
    PF = np.empty(nu, dtype=complex)
    for p, i in enumerate(used):
        f = forces[i]
        assert f is not None
        c = modal.coef[p]
        Px[p] = complex(c[1], -c[2])
        PF[p] = complex(f.coef[1], -f.coef[2])
        Z[p] = PF[p] / Px[p]
        Jx[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = _phasor_jac(-Z[p] / Px[p])
        JF = _phasor_jac(1.0 / Px[p])
        covF[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = JF @ f.cov_ab @ JF.T
    covZ = Jx @ cov_u @ Jx.T + covF
    omega_var = np.array([forces[i].omega_var for i in used])  # type: ignore[union-attr]
    resp = fit_response(om, Z, covZ, omega_var=omega_var, added_mass=ma[used])
    warnings.extend(resp.warnings)
    warnings.extend(_side_warnings(om, Z, resp))

    se = resp.stderr
    out_runs: list[ForcedRun] = []
    p_of = {i: p for p, i in enumerate(used)}
    for i in range(n):
        t, x, F = arrays[i]
        f = forces[i]
        if i not in p_of:
            warnings.append(f"{labels[i]}: set aside: {reasons[i]}")
            warnings.extend(f"{labels[i]}: {w}" for w in run_warn[i])
            out_runs.append(_unused_run(files[i], t, f, reasons[i], run_warn[i]))
            continue
        assert f is not None
        p = p_of[i]
        cz = covZ[2 * p : 2 * p + 2, 2 * p : 2 * p + 2]
        R = abs(Z[p])
        gR = np.array([Z[p].real, Z[p].imag]) / R
        grho = np.array([-Z[p].imag, Z[p].real]) / (R * R)
        cu = modal.coef_cov[p][1:3, 1:3]
        Cabs = abs(Px[p])
        gC = np.array([Px[p].real, -Px[p].imag]) / Cabs
        Babs = abs(PF[p])
        gB = np.array([PF[p].real, -PF[p].imag]) / Babs
        seg = segs[p]
        coef = modal.coef[p]
        b1, b2 = _release_basis(seg.t - seg.t0, modal.sigma, modal.w0sq)
        tr = coef[3] * b1 + coef[4] * b2  # the fitted start-up transient
        nsd = modal.noise[p]
        above = np.flatnonzero(np.abs(tr) > nsd)
        settle = float(seg.t[min(above[-1] + 1, seg.t.size - 1)]) if above.size \
            else float(seg.t[0])
        period = 2 * math.pi / f.omega
        tail = np.abs(tr[seg.t >= seg.t[-1] - period])
        end_level = float(tail.max()) / nsd if tail.size else 0.0
        settled = end_level <= 3.0
        w_run = list(run_warn[i])
        if not settled:
            w_run.append(f"the start-up transient has not died out within the record (still "
                         f"{end_level:.3g} noise sd at the end): R and ρ rest on its model; "
                         "record longer")
        warnings.extend(f"{labels[i]}: {w}" for w in w_run)
        r = modal.resid[p]
        out_runs.append(ForcedRun(
            file=files[i], omega=f.omega, omega_stderr=math.sqrt(f.omega_var),
            B=Babs, B_stderr=math.sqrt(max(float(gB @ f.cov_ab @ gB), 0.0)),
            C=Cabs, C_stderr=math.sqrt(max(float(gC @ cu @ gC), 0.0)),
            R=R, R_stderr=math.sqrt(max(float(gR @ cz @ gR), 0.0)),
            rho=float(np.angle(Z[p])), rho_stderr=math.sqrt(max(float(grho @ cz @ grho), 0.0)),
            Z=complex(Z[p]), Z_cov=cz.copy(), t_start=float(seg.t[0]), t_end=float(seg.t[-1]),
            t_ref=f.t_ref, settle_time=settle, settled=settled,
            periods=f.omega * float(seg.t[-1] - seg.t[0]) / (2 * math.pi), noise_sd=nsd,
            residual_rms=math.sqrt(float(r @ r) / r.size), F_distortion=f.distortion,
            used=True, warnings=tuple(w_run), coef=np.array(coef, dtype=float),
            transient_rates=(modal.sigma, modal.w0sq),
        ))
    return ForcedIdentification(
        m=Estimate(resp.m, float(se[0]), "kg"), c=Estimate(resp.c, float(se[1]), "N s/m"),
        k=Estimate(resp.k, float(se[2]), "N/m"), fit=resp, runs=tuple(out_runs),
        transient=(modal.sigma, modal.w0sq), transient_fitted=fit_rates,
        warnings=tuple(warnings), source=source, data=tuple(arrays),
    )


def _phasor_jac(w: complex) -> np.ndarray:
    """∂(Re, Im of w·P)/∂(a, b) for a phasor P = a − ib."""
    return np.array([[w.real, w.imag], [w.imag, -w.real]])


def _unused_run(file: str, t: np.ndarray, f: _Force | None, reason: str | None,
                extra: list[str]) -> ForcedRun:
    nan = math.nan
    return ForcedRun(
        file=file, omega=f.omega if f else nan,
        omega_stderr=math.sqrt(f.omega_var) if f else nan,
        B=math.hypot(f.coef[1], f.coef[2]) if f else nan, B_stderr=nan, C=nan, C_stderr=nan,
        R=nan, R_stderr=nan, rho=nan, rho_stderr=nan, Z=complex(nan, nan),
        Z_cov=np.full((2, 2), nan), t_start=float(t[f.start]) if f else float(t[0]),
        t_end=float(t[-1]), settled=False, used=False,
        F_distortion=f.distortion if f else nan, warnings=(reason or "", *extra),
    )


def _side_warnings(om: np.ndarray, Z: np.ndarray, resp: ResponseFit) -> list[str]:
    """All frequencies on one side of the resonance ω₀ = √(k/m): the sign of R cos ρ."""
    below = Z.real > 0
    if below.all() or not below.any():
        side = "below" if below.all() else "above"
        w0 = math.sqrt(resp.k / resp.m) if resp.m > 0 and resp.k > 0 else math.nan
        what = ("m rests on the curvature of R cos ρ alone" if side == "below"
                else "k rests on the extrapolation of R cos ρ to ω = 0")
        return [f"all forcing frequencies ({om.min():.4g}–{om.max():.4g} rad/s) lie {side} "
                f"the resonance (ω₀ ≈ {w0:.4g} rad/s): {what}; sweep across ω₀ for a "
                "well-conditioned estimate"]
    return []


def _transient_start(segs: list[_Segment], forces: list[_Force], noise: list[float],
                     added: np.ndarray) -> tuple[tuple[float, float], bool]:
    """Starting rates of the start-up transient, and whether they can be fitted.

    Candidates: the plant of a first pass (each run's steady state fitted by a sine on the
    second half of its window, then eq. 20), and ESPRIT root pairs of the three largest
    residuals of that pass on the first part of the windows; the one with the lowest weighted
    SSE of the full model wins. The rates are fitted only when the transient it implies is
    strong enough somewhere (≥ 20 noise sd in all).
    """
    Zs, ws, covs = [], [], []
    resid = []
    for s, f in zip(segs, forces, strict=True):
        half = s.t >= s.t[0] + 0.5 * (s.t[-1] - s.t[0])
        G = s.fixed[half]
        coef, *_ = np.linalg.lstsq(G, s.x[half], rcond=None)
        r = s.x[half] - G @ coef
        s2 = float(r @ r) / max(r.size - 3, 1)
        Ginv = np.linalg.pinv(G.T @ G)
        Px = complex(coef[1], -coef[2])
        PF = complex(f.coef[1], -f.coef[2])
        Zi = PF / Px
        J = _phasor_jac(-Zi / Px)
        covs.append(J @ (s2 * Ginv[1:, 1:]) @ J.T + np.eye(2) * 1e-30)
        Zs.append(Zi)
        ws.append(f.omega)
        resid.append(s.x - s.fixed @ coef)
    cands: list[tuple[float, float]] = []
    first_ok = False
    try:
        first = fit_response(np.array(ws), np.array(Zs), np.array(covs), added_mass=added)
        if first.m > 0:
            cands.append((first.c / (2 * first.m), first.k / first.m))
            first_ok = True
    except (IdentificationError, ValueError, np.linalg.LinAlgError):
        pass
    order = np.argsort([-float(np.linalg.norm(r[: max(r.size // 4, 8)])) / nz
                        for r, nz in zip(resid, noise, strict=True)])
    for p in order[:3]:
        s = segs[int(p)]
        cands += _esprit_rates(s.t, resid[int(p)], noise[int(p)], grid=p == order[0])
    span = max(float(s.t[-1] - s.t[0]) for s in segs)
    cands.append((2.0 / span, float(np.median(ws)) ** 2))
    # the candidates are compared on the runs with the strongest transient only (the others
    # barely depend on the rates), and the transient's strength is judged at the winner
    top = [segs[int(p)] for p in order[:3]]
    w_top = 1.0 / np.square([noise[int(p)] for p in order[:3]])
    best = _pick_start(top, cands, w_top)
    st = _State([_Prep(s) for s in top], best[0], best[1], w_top)
    energy = max(float(np.linalg.norm(B @ beta)) * math.sqrt(w)
                 for (_Qb, beta, _r, B), w in zip(st.items, w_top, strict=True))
    if energy >= _TRANSIENT_SNR:
        return best, True
    # too weak to fit: keep the first pass's plant when it is a physical one (the rates barely
    # matter then, but a decaying transient is the right model)
    physical = [c for c in cands[:1] if c[0] > 0 and c[1] > 0] if first_ok else []
    return (physical[0] if physical else best), False


# --------------------------------------------------------------------------------------------
# simulation


def simulate_forced(
    plant: Any,
    omega: Any,
    *,
    B: float = 1.0,
    theta: float = 0.0,
    duration: float,
    fs: float,
    hold: float = 0.0,
    x0: float = 0.0,
    noise: float = 0.0,
    force_noise: float = 0.0,
    quantum: float = 0.0,
    offset: float = 0.0,
    rng: np.random.Generator | None = None,
) -> list[Run]:
    """Simulate a sine sweep: one run per frequency, as :class:`~phoid.io.Run` with column F.

    The plant (no feedback) rests at x₀ (held there during ``hold``), then the force
    F(t) = B sin(ω(t − hold) − θ) (eq. 16) is switched on; the record holds t, the measured
    x (offset, white noise, quantisation as in :func:`phoid.simulate`) and F (0 before the
    onset, plus optional white noise).

    Parameters
    ----------
    plant : phoid.Plant
    omega : float or array_like
        Forcing frequencies, rad/s (> 0, below the Nyquist rate π f_s).
    B : float, default 1
        Force amplitude, N (> 0).
    theta : float, default 0
        Force phase θ of eq. (16), rad.
    duration : float
        Record length after the onset, s.
    fs : float
        Sample rate, Hz.
    hold : float, default 0
        Rest before the force starts, s.
    x0 : float, default 0
        Position during the rest, m (0: the equilibrium).
    noise, force_noise : float, default 0
        White-noise sd added to x (m) and to F (N); need ``rng``.
    quantum, offset : float, default 0
        Quantisation step and offset of the measured x, m.
    rng : numpy.random.Generator, optional

    Returns
    -------
    list of phoid.io.experiment.Run
        One run per frequency, with ``B`` and ``omega`` set.
    """
    from phoid.simulation.core import simulate

    ws = np.atleast_1d(v.finite_array("omega", omega))
    fs = v.positive("fs", fs, "Hz")
    B = v.positive("B", B, "N")
    theta = v.finite("theta", theta, "rad")
    hold = v.nonnegative("hold", hold, "s")
    force_noise = v.nonnegative("force_noise", force_noise, "N")
    if ws.size == 0:
        raise ValueError("`omega` must hold at least one frequency")
    for w in ws:
        if not 0 < w < math.pi * fs:
            raise ValueError(f"`omega` must be > 0 and below the Nyquist rate π·fs = "
                             f"{math.pi * fs:.6g} rad/s; got {w:g}")
    if force_noise > 0 and not isinstance(rng, np.random.Generator):
        raise ValueError("`rng` must be a numpy.random.Generator when `force_noise` > 0")

    def force_of(w: float) -> Callable[[np.ndarray], np.ndarray]:
        return lambda t: B * np.sin(w * (t - hold) - theta)

    runs = []
    for i, w in enumerate(ws):
        sim = simulate(plant, 0.0, 0.0, duration=duration, fs=fs, x0=x0, hold=hold,
                       force=force_of(float(w)), noise=noise, quantum=quantum, offset=offset,
                       rng=rng)
        F = np.where(sim.t >= hold, B * np.sin(w * (sim.t - hold) - theta), 0.0)
        if force_noise > 0:
            F = F + force_noise * rng.standard_normal(F.size)  # type: ignore[union-attr]
        runs.append(run_from_arrays(sim.t, sim.x[0], F=F, B=B, omega=float(w), index=i + 1))
    return runs
