"""The applied force of a forced run: frequency, amplitude, phase and analysed window.

Each run applies one sinusoidal force F(t) = B sin(ωt − θ) (seed eq. 16). ω comes from the
spectral peak of F, refined by Gauss–Newton on a sine fit
(F = d + a cos ω(t − t_ref) + b sin ω(t − t_ref), t_ref the window's centre); B and θ from the
same fit. The analysed window starts at the force's onset (a record may begin before the force
is switched on, or with a ramp): a coarse start surely after it (F has left its initial level,
and every later one-period block has the final amplitude), a sine fitted from there, and the
onset just after the last earlier sample that departs from that sine (more than 5 noise sd or
10⁻³ of the amplitude), plus a tenth of a period. F must be a sinusoid: a sine that leaves more
than 30 % rms of its amplitude unexplained is an error (:data:`F_REJECT`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid.errors import IdentificationError
from phoid.fits import diff_noise

__all__ = ["F_REJECT", "MIN_SAMPLES", "Force", "fit_force"]

#: fewest samples a run's analysed window must hold
MIN_SAMPLES = 16
#: F is rejected when a sine leaves this fraction (rms, of the sine's rms) unexplained
F_REJECT = 0.3


@dataclass(frozen=True)
class Force:
    """The fitted force of one run: F = d + a cos ω(t − t_ref) + b sin ω(t − t_ref).

    Attributes
    ----------
    start : int
        Index of the analysed window's first sample (the force's constant-amplitude onset).
    omega, omega_var : float
        Frequency ω (rad/s) and its variance ((rad/s)²).
    t_ref : float
        Time origin of the phasor (the window's centre), s.
    coef : ndarray, shape (3,)
        (d, a, b), N.
    cov_ab : ndarray, shape (2, 2)
        Covariance of (a, b), N².
    noise : float
        White-noise sd of F about the sine, N.
    distortion : float
        RMS of F not explained by the sine, relative to the sine's rms.
    """

    start: int
    omega: float
    omega_var: float
    t_ref: float
    coef: np.ndarray
    cov_ab: np.ndarray
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


def fit_force(t: np.ndarray, F: np.ndarray, where: str) -> Force:
    """Frequency, phasor and window of one run's force (Gauss–Newton on the sine fit).

    ω from the spectral peak of F, refined by Gauss–Newton on the sine fit; the window starts
    at the force's onset (module docstring).

    Parameters
    ----------
    t : ndarray
        Sample times, s (strictly increasing).
    F : ndarray
        Applied force, N.
    where : str
        The run's name, for messages.

    Returns
    -------
    Force

    Raises
    ------
    IdentificationError
        If F is constant or not sinusoidal (a sine leaves more than ``F_REJECT`` of its rms
        unexplained).
    """
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
    return Force(start=start, omega=float(omega), omega_var=float(omega_var),
                 t_ref=float(t_ref), coef=coef, cov_ab=cov[1:, 1:], noise=nsd,
                 distortion=float(distortion))
