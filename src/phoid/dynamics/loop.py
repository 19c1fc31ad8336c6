"""The delayed proportional–derivative loop of the seed paper (eqs. 23–35).

The closed loop m x'' + c x' + k x = −[D x'(t−Δt) + P x(t−Δt)] (eq. 23). Its characteristic
roots are those of :mod:`phoid.dynamics.rightmost` (certified by the argument principle).

For a dominant mode s = −σ + iω_d the delayed signal is exactly x(t−Δt) = e^{−sΔt}x(t) =
[(α₁ − σα₂) x − α₂ ẋ](t) with α₁ = e^{σΔt} cos(ω_dΔt) (ERRATA 1 in docs/equations.md — the
paper's eq. 29 prints an extra −(σ/ω_d) sin term) and α₂ = e^{σΔt} sin(ω_dΔt)/ω_d, which gives
eqs. (28)–(32).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from phoid import _validate as v
from phoid.dynamics.plant import Plant
from phoid.dynamics.rightmost import dominant_roots, rightmost_roots

__all__ = [
    "DelayedPD",
    "LoopModes",
    "alphas",
    "characteristic_roots",
    "forward_map",
    "inverse_map",
    "is_stable",
]


@dataclass(frozen=True)
class DelayedPD:
    """Proportional–derivative feedback u = −[D ẋ(t−Δt) + P x(t−Δt)] (eq. 23).

    Parameters
    ----------
    P : float
        Proportional gain, N/m (any sign).
    D : float
        Derivative gain, N·s/m (any sign; negative D removes damping).
    delay : float, default 0
        Loop delay Δt, s (≥ 0).
    """

    P: float
    D: float
    delay: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "P", v.finite("P", self.P, "N/m"))
        object.__setattr__(self, "D", v.finite("D", self.D, "N·s/m"))
        object.__setattr__(self, "delay", v.nonnegative("delay", self.delay, "s"))


def characteristic_roots(
    plant: Plant, loop: DelayedPD, *, count: int = 6, verify: bool = True
) -> np.ndarray:
    """The rightmost roots of m s² + c s + k + (D s + P) e^{−sΔt} = 0, exactly.

    Parameters
    ----------
    plant : Plant
        The plant (its f_c is ignored: the roots are those of the linear loop).
    loop : DelayedPD
        Gains and delay.
    count : int, default 6
        At least this many roots (fewer if the loop has fewer, e.g. Δt = 0 gives 2) are returned,
        conjugates counted separately.
    verify : bool, default True
        Certify with the argument principle that no root lies to the right of the last one
        returned that is not in the list.

    Returns
    -------
    ndarray of complex
        Roots, 1/s, sorted by decreasing real part (for a conjugate pair, positive imaginary
        part first), each accurate to Newton convergence (|f| at rounding level).

    Notes
    -----
    Δt = 0: the quadratic m s² + (c + D)s + (k + P) = 0 is solved in closed form. Otherwise the
    spectral discretisation (order n, increased until the requested rightmost roots converge)
    gives starting points that Newton refines; the result is certified as described in
    :mod:`phoid.dynamics.rightmost`.
    """
    return rightmost_roots(
        plant.m, plant.c, plant.k, loop.P, loop.D, loop.delay, count=count, verify=verify
    )


def is_stable(plant: Plant, loop: DelayedPD) -> bool:
    """True when every characteristic root has a negative real part (certified)."""
    return bool(characteristic_roots(plant, loop, count=2)[0].real < 0)


# --------------------------------------------------------------------------------------------
# eqs. (26)-(35): alphas, forward and inverse maps


def alphas(
    sigma: np.ndarray | float,
    omega_d: np.ndarray | float,
    delay: float,
    *,
    printed: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Delay coefficients α₁, α₂ of eqs. (28)–(29), corrected per ERRATA 1.

    Parameters
    ----------
    sigma : array_like
        Decay rate σᵢ of the closed-loop dominant mode, 1/s.
    omega_d : array_like
        Its damped frequency ω_dᵢ, rad/s (> 0).
    delay : float
        Loop delay Δt, s.
    printed : bool, default False
        Return the paper's misprinted α₁ = e^{σΔt}[cos Δφ − (σ/ω_d) sin Δφ] instead (kept only to
        demonstrate the erratum; do not use).

    Returns
    -------
    alpha1 : ndarray
        α₁ = e^{σΔt} cos Δφ, with Δφ = ω_dΔt (eq. 26). Dimensionless.
    alpha2 : ndarray
        α₂ = e^{σΔt} sin(Δφ)/ω_d, s. (Its Δφ → 0 limit, Δt e^{σΔt}, is used when ω_d = 0.)
    """
    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    e = np.exp(sigma * delay)
    dphi = omega_d * delay
    a1 = e * np.cos(dphi)
    a2 = e * delay * np.sinc(dphi / np.pi)
    if printed:
        a1 = a1 - sigma * a2
    return a1, a2


@dataclass(frozen=True)
class LoopModes:
    """Dominant closed-loop modes of a set of runs and the equivalent parameters (eqs. 31–33).

    Attributes
    ----------
    sigma : ndarray
        σᵢ, 1/s (dominant root −σᵢ + iω_dᵢ).
    omega_d : ndarray
        ω_dᵢ, rad/s.
    c_eq, k_eq : ndarray
        cᵢ = c + c′ᵢ (N·s/m) and kᵢ = k + k′ᵢ (N/m), eq. (32).
    c_prime, k_prime : ndarray
        c′ᵢ (N·s/m) and k′ᵢ (N/m), eq. (32).
    """

    sigma: np.ndarray
    omega_d: np.ndarray
    c_eq: np.ndarray
    k_eq: np.ndarray
    c_prime: np.ndarray
    k_prime: np.ndarray

    @property
    def omega0_sq(self) -> np.ndarray:
        """ω₀ᵢ² = σᵢ² + ω_dᵢ², 1/s² (eq. 4 for the underdamped loop)."""
        return self.sigma**2 + self.omega_d**2


def inverse_map(
    sigma: np.ndarray | float,
    omega_d: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
    *,
    compensate: bool = True,
    printed_alpha1: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Equivalent feedback damping c′ᵢ and stiffness k′ᵢ from a measured mode (eqs. 29, 32).

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured σᵢ (1/s) and ω_dᵢ (rad/s) of each run's decay.
    P, D : array_like
        The run's gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    compensate : bool, default True
        With False, ignore the delay: c′ᵢ = Dᵢ, k′ᵢ = Pᵢ (the paper's "without compensation").
    printed_alpha1 : bool, default False
        Use the paper's misprinted α₁ (ERRATA 1), for demonstration only.

    Returns
    -------
    c_prime : ndarray
        c′ᵢ = (α₁ + σα₂)Dᵢ − α₂Pᵢ, N·s/m (eq. 32a).
    k_prime : ndarray
        k′ᵢ = (α₁ − σα₂)Pᵢ + ω₀ᵢ²α₂Dᵢ, N/m (eq. 32b), with ω₀ᵢ² = σᵢ² + ω_dᵢ².
    """
    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    if not compensate:
        return np.broadcast_to(D, sigma.shape).copy(), np.broadcast_to(P, sigma.shape).copy()
    a1, a2 = alphas(sigma, omega_d, delay, printed=printed_alpha1)
    w0sq = sigma**2 + omega_d**2
    c_prime = (a1 + sigma * a2) * D - a2 * P
    k_prime = (a1 - sigma * a2) * P + w0sq * a2 * D
    return c_prime, k_prime


def forward_map(
    plant: Plant, P: np.ndarray | float, D: np.ndarray | float, delay: float
) -> LoopModes:
    """Plant + gains → dominant modes σᵢ, ω_dᵢ and the equivalent cᵢ, kᵢ (eqs. 31–32).

    Parameters
    ----------
    plant : Plant
        The plant.
    P, D : array_like
        Gains of each run, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    LoopModes
        Exact dominant roots (certified) and, through eq. (32) with the corrected α₁, the
        equivalent parameters; by construction cᵢ = 2mσᵢ and kᵢ = m(σᵢ² + ω_dᵢ²) (eq. 33).
    """
    delay = v.nonnegative("delay", delay, "s")
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    s = dominant_roots(plant.m, plant.c, plant.k, P, D, delay)
    sigma, omega_d = -s.real, s.imag
    cp, kp = inverse_map(sigma, omega_d, P, D, delay)
    return LoopModes(sigma, omega_d, plant.c + cp, plant.k + kp, cp, kp)
