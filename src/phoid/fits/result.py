"""The result of a dominant-mode decay fit (:class:`DecayFit`) and the checks every fit shares.

A closed PD loop that rings like an underdamped oscillator (eqs. 31, 33) leaves, after the
release of the held mass and once the loop's fast non-dominant modes have died, the record

    x(t) = x_off + A e^{−σ(t−t_ref)} sin(ω_d (t−t_ref) − φ₀) + noise,          (eq. 15)

with the dominant root s = −σ + iω_d (σ > 0 when the oscillation decays, eq. 3). Both
estimators of this subpackage (:func:`phoid.fits.modal.fit_decay`,
:func:`phoid.fits.decrement.logdec`) return a :class:`DecayFit`; estimates the data cannot
support are flagged by strings in ``DecayFit.warnings``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "MIN_CYCLES",
    "MIN_SAMPLES",
    "DecayFit",
    "common_warnings",
    "count_cycles",
    "is_clipped",
    "phase_amp",
    "unfitted",
]

#: fewest samples a record (and a fitted window) must hold
MIN_SAMPLES = 16
#: cycles above the noise floor below which σ and ω_d are flagged as poorly supported
MIN_CYCLES = 3.0


@dataclass(frozen=True)
class DecayFit:
    """Dominant-mode estimate from one free-decay record.

    The fitted model is (eq. 15 with a sensor offset)

        x(t) = offset + amplitude · e^{−σ(t−t_ref)} sin(ω_d (t−t_ref) − phase).

    Attributes
    ----------
    sigma : float
        Decay rate σ, 1/s (eq. 3); positive when the oscillation decays. Root s = −σ + iω_d.
    omega_d : float
        Damped natural frequency ω_d, rad/s (eq. 4, underdamped form).
    cov : ndarray, shape (2, 2)
        Covariance of (sigma, omega_d), in (1/s)², (1/s)(rad/s), (rad/s)².
    amplitude : float
        Envelope A at ``t_ref``, m (eq. 15).
    phase : float
        φ₀ of eq. (15) with time measured from ``t_ref``, rad, in (−π, π].
    offset : float
        Constant sensor offset, m.
    t_ref : float
        Reference time of ``amplitude`` and ``phase``, s (the first fitted sample).
    t_start, t_end : float
        First and last sample times of the fitted window, s.
    release : float
        Detected (or given) release time, s.
    n_samples : int
        Number of samples in the fitted window.
    cycles : float
        Oscillation cycles in the window while the envelope is above the noise sd.
    noise_sd : float
        White-noise sd estimated from the residuals, m (√(RSS/(n − p)), p fitted parameters).
    residual_rms : float
        Root-mean-square residual of the fitted model over the window, m.
    method : str
        ``"mode-fit"`` (:func:`fit_decay`) or ``"logdec"`` (:func:`logdec`).
    warnings : tuple of str
        Reasons to distrust the estimate; empty when there are none.
    fast_modes : tuple of (complex, complex)
        The non-dominant modes fitted alongside (``fast_roots``): pairs (root r, 1/s; complex
        amplitude A, m), contributing Re(A e^{r(t − t_ref)}) for t ≥ t_ref.
    """

    sigma: float
    omega_d: float
    cov: np.ndarray = field(repr=False)
    amplitude: float
    phase: float
    offset: float
    t_ref: float
    t_start: float
    t_end: float
    release: float
    n_samples: int
    cycles: float
    noise_sd: float
    residual_rms: float
    method: str
    warnings: tuple[str, ...] = ()
    fast_modes: tuple[tuple[complex, complex], ...] = ()

    def __post_init__(self) -> None:
        cov = np.array(self.cov, dtype=float, copy=True).reshape(2, 2)
        cov.setflags(write=False)
        object.__setattr__(self, "cov", cov)
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def sigma_stderr(self) -> float:
        """Standard error of ``sigma``, 1/s."""
        return math.sqrt(max(self.cov[0, 0], 0.0))

    @property
    def omega_d_stderr(self) -> float:
        """Standard error of ``omega_d``, rad/s."""
        return math.sqrt(max(self.cov[1, 1], 0.0))

    @property
    def root(self) -> complex:
        """The dominant root s = −σ + iω_d, 1/s."""
        return complex(-self.sigma, self.omega_d)

    def model(self, t: np.ndarray | float, *, fast: bool = False) -> np.ndarray:
        """The fitted dominant mode x(t) = offset + A e^{−στ} sin(ω_d τ − φ₀), τ = t − t_ref.

        Parameters
        ----------
        t : array_like
            Times, s.
        fast : bool, default False
            Add the fitted non-dominant modes (:attr:`fast_modes`) for t ≥ t_ref: the whole
            fitted model, e.g. for residuals right after the release.

        Returns
        -------
        ndarray
            Model position, m (same shape as ``t``).
        """
        tau = np.asarray(t, dtype=float) - self.t_ref
        with np.errstate(over="ignore", invalid="ignore"):
            env = self.amplitude * np.exp(-self.sigma * tau)
            out = self.offset + env * np.sin(self.omega_d * tau - self.phase)
            if fast:
                after = np.maximum(tau, 0.0)
                for r, A in self.fast_modes:
                    out = out + np.where(tau >= 0, np.real(A * np.exp(r * after)), 0.0)
        return out

    def summary(self) -> dict:
        """Plain JSON-ready summary (floats, strings, lists; NaN becomes None)."""

        def num(v: float) -> float | None:
            v = float(v)
            return v if math.isfinite(v) else None

        return {
            "method": self.method,
            "sigma": num(self.sigma),
            "sigma_stderr": num(self.sigma_stderr),
            "omega_d": num(self.omega_d),
            "omega_d_stderr": num(self.omega_d_stderr),
            "cov": [[num(c) for c in row] for row in self.cov],
            "amplitude": num(self.amplitude),
            "phase": num(self.phase),
            "offset": num(self.offset),
            "t_ref": num(self.t_ref),
            "t_start": num(self.t_start),
            "t_end": num(self.t_end),
            "release": num(self.release),
            "n_samples": int(self.n_samples),
            "cycles": num(self.cycles),
            "noise_sd": num(self.noise_sd),
            "residual_rms": num(self.residual_rms),
            "warnings": list(self.warnings),
        }


def count_cycles(amplitude, sigma, omega, duration, noise) -> float:
    """Cycles while the envelope A e^{−σt} is above the noise sd, within ``duration``."""
    if not (amplitude > noise > 0):
        return 0.0 if amplitude <= noise else omega * duration / (2 * math.pi)
    t_above = duration if sigma <= 0 else min(duration, math.log(amplitude / noise) / sigma)
    return max(omega * t_above / (2 * math.pi), 0.0)


def is_clipped(x: np.ndarray, resid: np.ndarray, noise: float) -> bool:
    """Flat tops: ≥ 5 samples at the record's extreme value that the fitted mode overshoots
    (``resid`` = x − the fitted model, m)."""
    for ext, sign in ((x.max(), 1.0), (x.min(), -1.0)):
        at = x == ext
        if np.count_nonzero(at) >= 5:
            over = -sign * resid[at]  # how far the model goes beyond the flat level x = ext
            if over.max() > 5.0 * noise:
                return True
    return False


def unfitted(
    method, tw, release, noise, offset, warnings, sigma=math.nan, omega=math.nan, cov=None
) -> DecayFit:
    """A DecayFit for a record the method could not fit: NaN where there is no estimate."""
    nan = math.nan
    return DecayFit(
        sigma=sigma,
        omega_d=omega,
        cov=np.full((2, 2), nan) if cov is None else cov,
        amplitude=nan,
        phase=nan,
        offset=offset,
        t_ref=float(tw[0]),
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=float(release),
        n_samples=int(tw.size),
        cycles=0.0,
        noise_sd=noise,
        residual_rms=nan,
        method=method,
        warnings=tuple(warnings),
    )


def phase_amp(a: float, b: float) -> tuple[float, float]:
    """(A, φ₀) with a cos ωτ + b sin ωτ = A sin(ωτ − φ₀)."""
    return math.hypot(a, b), math.atan2(-a, b)


def common_warnings(sigma: float, sigma_stderr: float, cycles: float, xw, resid, floor
                     ) -> list[str]:
    """The warnings every decay fit can give: few cycles, a growing oscillation (σ < 0, 1/s,
    with its stderr), a clipped record (``resid``: x − model over the window; ``floor``: noise
    sd, m)."""
    w = []
    if cycles < MIN_CYCLES:
        w.append(
            f"few cycles: only {cycles:.1f} oscillation cycles above the noise floor "
            f"(< {MIN_CYCLES:g}); σ and ω_d are poorly supported by the data"
        )
    if sigma < 0:
        sure = sigma < -2.0 * sigma_stderr
        w.append(
            f"growing oscillation: σ = {sigma:.4g} ± {sigma_stderr:.2g} 1/s < 0 "
            + ("(unstable loop)" if sure else "(within 2 stderr of 0: marginally stable loop?)")
        )
    if is_clipped(xw, resid, floor):
        w.append(
            "clipped record: flat tops at the extreme value of x that the fitted mode exceeds "
            "(sensor saturation?); the estimate is biased"
        )
    return w


