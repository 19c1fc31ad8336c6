"""The second-order plant m x'' + c x' + k x + f_c sign(x') = F(t) (seed eq. 1).

The free response is implemented once, in the unified hyperbolic form of the seed's eqs. (2)–(15)
(see ERRATA 4 in docs/equations.md): with q = σ² − ω₀² and w = √|q|,

    x(t) = x₀ C(t) + (ẋ₀ + σ x₀) S(t),
    C(t) = e^{−σt} cosh(w t)         (q ≥ 0)   or   e^{−σt} cos(w t)      (q < 0),
    S(t) = e^{−σt} sinh(w t) / w     (q ≥ 0)   or   e^{−σt} sin(w t) / w  (q < 0),

which is eq. (2) with the amplitude and phase of eqs. (6)–(7) expanded. S(t) is evaluated as
t·(…) with ``expm1``/``sinc`` so that it is continuous through critical damping (eq. 11: the
w → 0 limit of sinh(wt)/w and sin(wt)/w is t) with no 0/0, and the overdamped branch is written
with the slow root s₁ = −ω₀²/(σ + w) (no cancellation for ζ ≫ 1) and e^{−σt}cosh(wt) =
e^{s₁t}(1 + e^{−2wt})/2, which neither overflows nor loses precision for large ζ or t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid import _validate as v

__all__ = ["Plant", "free_response", "modal_basis", "quadratic_roots"]


def modal_basis(
    t: np.ndarray | float, sigma: float, omega0_sq: float
) -> tuple[np.ndarray, np.ndarray]:
    """Fundamental solutions C(t), S(t) of x'' + 2σ x' + ω₀² x = 0, for every damping.

    Parameters
    ----------
    t : array_like
        Time since the initial instant, s.
    sigma : float
        Decay rate σ = c/(2m), 1/s (eq. 3). Any sign (negative means growth).
    omega0_sq : float
        ω₀² = k/m, 1/s² (eq. 5). Any sign (negative means an unstable spring).

    Returns
    -------
    C, S : ndarray
        C(0) = 1, C'(0) = −σ and S(0) = 0, S'(0) = 1, in the sense that the free response is
        x = x₀ (C + σ S) + ẋ₀ S.  Units: C dimensionless, S in s.

    Notes
    -----
    Implements the unified eq. (2) (hyperbolic form) with eq. (11) as the continuous limit at
    critical damping; eq. (15) is the q < 0 branch after eq. (14).
    """
    t = np.asarray(t, dtype=float)
    q = sigma * sigma - omega0_sq
    w = math.sqrt(abs(q))
    if q >= 0.0:
        # slow root s1 = -sigma + w, written without cancellation
        if sigma > 0.0:
            s1 = -omega0_sq / (sigma + w)
        else:
            s1 = -sigma + w
        e1 = np.exp(s1 * t)
        y = 2.0 * w * t
        with np.errstate(invalid="ignore", divide="ignore"):
            g = np.where(y != 0.0, -np.expm1(-y) / np.where(y != 0.0, y, 1.0), 1.0)
        C = e1 * 0.5 * (1.0 + np.exp(-y))
        S = e1 * t * g
    else:
        env = np.exp(-sigma * t)
        C = env * np.cos(w * t)
        S = env * t * np.sinc(w * t / math.pi)
    return C, S


def free_response(
    t: np.ndarray | float, sigma: float, omega0_sq: float, x0: float, v0: float
) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity of the free (homogeneous) response, eqs. (2)–(15).

    Parameters
    ----------
    t : array_like
        Time since release, s.
    sigma, omega0_sq : float
        σ (1/s) and ω₀² (1/s²) of the (possibly equivalent closed-loop) oscillator.
    x0, v0 : float
        Initial position (m) and velocity (m/s), eq. (8).

    Returns
    -------
    x, xdot : ndarray
        Position (m) and velocity (m/s) at ``t``.
    """
    C, S = modal_basis(t, sigma, omega0_sq)
    x = x0 * C + (v0 + sigma * x0) * S
    xdot = v0 * C - (sigma * v0 + omega0_sq * x0) * S
    return x, xdot


def quadratic_roots(a2: float, a1: float, a0: float) -> np.ndarray:
    """Roots of a2 s² + a1 s + a0 (a2 > 0), rightmost first, without cancellation.

    Real roots: the slow one is −ω₀²/(σ + w) (σ = a1/2a2, ω₀² = a0/a2, w = √(σ² − ω₀²)), so it
    keeps full precision for ζ ≫ 1 (eqs. 3–5); also used for the delay-free closed loop.
    """
    sigma = a1 / (2 * a2)
    w0sq = a0 / a2
    q = sigma * sigma - w0sq
    w = math.sqrt(abs(q))
    if q >= 0:
        if sigma > 0:
            slow, fast = -w0sq / (sigma + w), -sigma - w
        else:
            slow = -sigma + w
            fast = w0sq / slow if slow != 0 else -sigma - w
        return np.array([complex(slow), complex(fast)])
    return np.array([complex(-sigma, w), complex(-sigma, -w)])


@dataclass(frozen=True)
class Plant:
    """A mass–spring–damper with optional Coulomb friction (seed eq. 1).

    Parameters
    ----------
    m : float
        Mass, kg (> 0).
    c : float
        Viscous damping, N·s/m (≥ 0).
    k : float
        Stiffness, N/m (≥ 0; k = 0 is a mass–damper).
    fc : float, default 0
        Kinetic (Coulomb) friction force, N (≥ 0).

    Examples
    --------
    >>> p = Plant(2.0, 1.0, 64.0)
    >>> round(p.sigma, 6), round(p.omega0, 6), round(p.zeta, 6)
    (0.25, 5.656854, 0.044194)
    """

    m: float
    c: float
    k: float
    fc: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "m", v.positive("m", self.m, "kg"))
        object.__setattr__(self, "c", v.nonnegative("c", self.c, "N·s/m"))
        object.__setattr__(self, "k", v.nonnegative("k", self.k, "N/m"))
        object.__setattr__(self, "fc", v.nonnegative("fc", self.fc, "N"))

    @property
    def sigma(self) -> float:
        """Decay rate σ = c/(2m), 1/s (eq. 3)."""
        return self.c / (2.0 * self.m)

    @property
    def omega0(self) -> float:
        """Undamped natural frequency ω₀ = √(k/m), rad/s (eq. 5)."""
        return math.sqrt(self.k / self.m)

    @property
    def zeta(self) -> float:
        """Damping ratio ζ = σ/ω₀ = c/(2√(mk)) (eq. 10); ``inf`` for k = 0 with c > 0."""
        if self.k == 0.0:
            return math.inf if self.c > 0 else math.nan
        return self.c / (2.0 * math.sqrt(self.m * self.k))

    @property
    def regime(self) -> str:
        """``"underdamped"``, ``"critical"`` or ``"overdamped"`` (eqs. 4, 10)."""
        q = self.sigma**2 - self.k / self.m
        scale = max(self.sigma**2, self.k / self.m)
        if abs(q) <= 1e-12 * scale:
            return "critical"
        return "overdamped" if q > 0 else "underdamped"

    @property
    def omega_d(self) -> float:
        """|ω_d| = √|σ² − ω₀²|, rad/s (eq. 4; for underdamped plants its conjugate form)."""
        return math.sqrt(abs(self.sigma**2 - self.k / self.m))

    @property
    def roots(self) -> np.ndarray:
        """Both roots of m s² + c s + k = 0, 1/s, as complex numbers, rightmost first.

        Computed without cancellation: for real roots the slow one is −ω₀²/(σ + w).
        """
        return quadratic_roots(self.m, self.c, self.k)

    def free_response(
        self, t: np.ndarray | float, x0: float, v0: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Free response x(t), ẋ(t) from x₀ (m), ẋ₀ (m/s) at t = 0, eqs. (2)–(15).

        Valid for the linear plant (f_c = 0); with Coulomb friction the motion is piecewise
        and is computed by :func:`phoid.simulation.simulate`.

        Raises
        ------
        ValueError
            If ``fc`` > 0, or ``x0``/``v0`` are not finite.
        """
        if self.fc > 0:
            raise ValueError(
                f"`fc` must be 0 for the closed-form free response; got {self.fc:g} N "
                "(use phoid.simulate for friction)"
            )
        x0 = v.finite("x0", x0, "m")
        v0 = v.finite("v0", v0, "m/s")
        return free_response(t, self.sigma, self.k / self.m, x0, v0)
