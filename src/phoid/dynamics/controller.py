r"""The industrial sampled PD controller: reference input, any velocity filter, fractional delay.

A positioning axis, a robot joint or a test rig runs a digital PD position loop that
:class:`~phoid.dynamics.digital.DigitalPD` (the seed's release loop, eq. 23 sampled) models only
in part. :class:`SampledController` is the general form. With period T (instants t_n = t₀ + nT)
the controller

1. samples the position, x_n = x(t_n);
2. estimates the velocity with a linear filter (b, a),
   a₀ v̂_n = Σ_j b_j x_{n−j} − Σ_{i≥1} a_i v̂_{n−i}, one of phoid's estimators
   (:mod:`phoid.dynamics.velocity`, the one definition: ``"backward-difference"``
   (x_n − x_{n−1})/T, ``"central-difference"`` (x_n − x_{n−2})/(2T), ``"filtered"``, the
   first-order low pass of the backward difference; or any FIR coefficients b_j in 1/s);
3. computes the command u_n = K·(P·(r_n − x_n) − D·v̂_n) in its own units (volts, say), r the
   reference;
4. saturates it to ±u_max and adds a sampled command input w_n (test pulses), and an amplifier
   turns it into the force F_n = G·(sat(u_n) + w_n), N;
5. holds F_n from t_n + τ until F_{n+1} takes over at t_{n+1} + τ (zero-order hold, command
   delay τ ≥ 0, any real value: τ = dT + φ, 0 ≤ φ < T).

The plant m ẍ + c ẋ + k x + f_c sign(ẋ) + f₀ = F(t) (seed eq. 1 with Coulomb friction and a
constant offset force f₀) is simulated exactly by :mod:`phoid.simulation.tracking`.

The release loop of the seed is the special case r = 0, K = G = 1, τ = d·T
(:meth:`SampledController.from_digital`): u_n = −(P x_n + D v̂_n).

Linear stability (no friction, no saturation): within period n the plant sees F_{n−d−1} for φ
and F_{n−d} for T − φ, so with y = (x, ẋ)

    y_{n+1} = Φ(T) y_n + Φ(T − φ) Γ(φ) F_{n−d−1} + Γ(T − φ) F_{n−d},

Φ(h) = e^{Ah}, Γ(h) = ∫₀^h e^{As} ds b (the zero-order-hold discretisation of
:mod:`phoid.dynamics.digital`). With q = z⁻¹, N_Γ(q) = Γ₁ + (Φ₁₂Γ₂ − Φ₂₂Γ₁) q the numerator of
the pulse transfer function q²·[1 0](I − Φq)⁻¹Γ/q and Δ(q) = 1 − tr Φ q + det Φ q², the closed
loop's characteristic polynomial in q is

    χ(q) = Δ(q) A(q) + G K q^{d+1} [q N_{Γa}(q) + N_{Γb}(q)] [P A(q) + D B(q)],

A(q) = Σ a_i q^i, B(q) = Σ b_j q^j; its coefficients, read as a polynomial in z (descending
powers), have the closed-loop poles as roots (:func:`closed_loop_poles`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from phoid import _validate as v
from phoid.dynamics.digital import DigitalPD
from phoid.dynamics.velocity import VELOCITY_PRESETS, VelocityFilter
from phoid.dynamics.zoh import expm_stack

__all__ = [
    "VELOCITY_PRESETS",
    "SampledController",
    "closed_loop_poles",
    "zoh_pieces",
]

# the smallest scale whose square is a normal float (≈ 1.5e-154): the loop's statistics square
# forces, periods and filter gains, and below it they underflow to zero (a zero norm, a zero
# covariance) — a period, command gain or saturation that small is refused, not computed
_SMALLEST = math.sqrt(sys.float_info.min)
# the largest period whose square is finite (≈ 1.3e154 s): the plant's ZOH map holds T²/m
_LARGEST = 1.0 / _SMALLEST


@dataclass(frozen=True)
class SampledController:
    """A sampled PD position controller tracking a reference (module docstring: the law).

    Parameters
    ----------
    sample_time : float
        Controller period T, s (> 0).
    P : float
        Proportional gain on the tracking error r − x, command units per m (any sign).
    D : float
        Derivative gain on the velocity estimate, command units per (m/s) (any sign).
    gain : float, default 1
        Overall gain K multiplying P(r − x) − D v̂ (e.g. a velocity-loop gain), dimensionless.
    command_gain : float, default 1
        G, N per command unit (amplifier and motor: volts to newtons); > 0.
    velocity : str or sequence of float, default "backward-difference"
        A name of :data:`VELOCITY_PRESETS`: ``"backward-difference"``, ``"central-difference"``,
        ``"filtered"`` (needs ``cutoff``), or FIR coefficients b₀, b₁, … in 1/s,
        v̂_n = Σ_j b_j x_{n−j} (kept as a tuple; :class:`phoid.dynamics.velocity.VelocityFilter`).
    cutoff : float, optional
        ω_c of the ``"filtered"`` estimator, rad/s (> 0); refused otherwise.
    delay : float, default 0
        Command delay τ, s (≥ 0; any real value, not only whole periods).
    saturation : float, optional
        u_max, command units (> 0): the command is clipped to ±u_max before w is added.

    Raises
    ------
    ValueError
        Naming the parameter, for a non-finite gain, a non-positive period or command gain, a
        negative delay, an unknown estimator, coefficients that are not finite numbers, or a
        missing or superfluous cut-off; a period, command gain or saturation whose square is
        not a normal float (below ≈ 1.5e-154; a period above ≈ 1.3e154 s), and a cut-off so
        low for the period that the rounded filter pole e^(−ω_c T) misstates the filter.

    Attributes
    ----------
    estimator : phoid.dynamics.velocity.VelocityFilter
        The velocity estimator with its coefficients (b, a) at this period.
    """

    sample_time: float
    P: float
    D: float
    gain: float = 1.0
    command_gain: float = 1.0
    velocity: str | tuple[float, ...] = "backward-difference"
    cutoff: float | None = None
    delay: float = 0.0
    saturation: float | None = None
    estimator: VelocityFilter = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "sample_time", _scale("sample_time", self.sample_time, "s", _LARGEST))
        set_(self, "P", v.finite("P", self.P, "command units/m"))
        set_(self, "D", v.finite("D", self.D, "command units/(m/s)"))
        set_(self, "gain", v.finite("gain", self.gain, ""))
        set_(self, "command_gain", _scale("command_gain", self.command_gain,
                                          "N per command unit"))
        set_(self, "delay", v.nonnegative("delay", self.delay, "s"))
        if self.saturation is not None:
            set_(self, "saturation", _scale("saturation", self.saturation, "command units"))
        est = VelocityFilter(self.velocity, self.sample_time, self.cutoff)
        set_(self, "velocity", est.velocity)
        set_(self, "cutoff", est.cutoff)
        set_(self, "estimator", est)

    @classmethod
    def from_digital(cls, loop: DigitalPD) -> SampledController:
        """The release loop u_n = −(P x_n + D v̂_n) of a :class:`DigitalPD` (r = 0, K = G = 1)."""
        return cls(sample_time=loop.sample_time, P=loop.P, D=loop.D, velocity=loop.velocity,
                   cutoff=loop.cutoff, delay=loop.delay)

    def velocity_filter(self) -> tuple[np.ndarray, np.ndarray]:
        """The estimator as a linear filter (b in 1/s, a dimensionless), v̂ = lfilter(b, a, x)
        (:meth:`phoid.dynamics.velocity.VelocityFilter.coefficients`)."""
        return self.estimator.coefficients()

    @property
    def taps(self) -> int:
        """Past samples the velocity estimate reads, len(b) − 1 (the record needs taps + 1)."""
        return self.estimator.taps

    @property
    def delay_split(self) -> tuple[int, float]:
        """(d, φ): τ = d·T + φ with d whole and 0 ≤ φ < T (φ in s)."""
        T = self.sample_time
        d = math.floor(self.delay / T + 1e-12)
        phi = self.delay - d * T
        if phi < 1e-12 * T:
            phi = 0.0
        return d, phi

    def with_delay(self, delay: float) -> SampledController:
        """The same controller with another command delay τ (s)."""
        return replace(self, delay=delay)


def _scale(name: str, value, unit: str, largest: float = math.inf) -> float:
    """``value`` as a float > 0 whose square is a normal float (at least ``_SMALLEST``) and at
    most ``largest``, or a one-line ValueError naming ``name``."""
    x = v.positive(name, value, unit)
    if not _SMALLEST <= x <= largest:
        bound = (f"at least {_SMALLEST:.2g}" if x < _SMALLEST else f"at most {largest:.2g}")
        raise ValueError(
            f"`{name}` = {x:g} {unit} is out of range: it must be {bound} {unit}, where its "
            "square is still a normal floating-point number (the loop's statistics square it)"
        )
    return x


def zoh_pieces(m: float, c: float, k: float, hs: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Φ(h) = e^{Ah} and Γ(h) = ∫₀^h e^{As} ds b for each h, from one augmented exponential.

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg), damping (N·s/m), stiffness (N/m); A = [[0, 1], [−k/m, −c/m]],
        b = (0, 1/m) (seed eq. 1 in state form, force input in N).
    hs : sequence of float
        Interval lengths, s (≥ 0).

    Returns
    -------
    Phi : numpy.ndarray, shape (len(hs), 2, 2)
    Gamma : numpy.ndarray, shape (len(hs), 2)
        Per newton of constant force over the interval, (m, m/s).
    """
    h = np.asarray(hs, dtype=float)
    M = np.zeros((h.size, 3, 3))
    M[:, 0, 1] = h
    M[:, 1, 0] = -k / m * h
    M[:, 1, 1] = -c / m * h
    M[:, 1, 2] = h / m
    E = expm_stack(M)
    return E[:, :2, :2].copy(), E[:, :2, 2].copy()


def closed_loop_poles(m: float, c: float, k: float, ctrl: SampledController) -> np.ndarray:
    """The poles z of the linear sampled loop (no friction, no saturation; module docstring).

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg, > 0), damping (N·s/m), stiffness (N/m).
    ctrl : SampledController
        The controller.

    Returns
    -------
    numpy.ndarray of complex
        The roots of χ; the loop is stable when every |z| < 1.

    Raises
    ------
    ValueError
        Naming the parameter: m not finite or not > 0, c or k not finite.
    """
    m = v.positive("m", m, "kg")
    c = v.finite("c", c, "N·s/m")
    k = v.finite("k", k, "N/m")
    T = ctrl.sample_time
    d, phi = ctrl.delay_split
    b, a = ctrl.velocity_filter()
    Phi, Gam = zoh_pieces(m, c, k, [T, phi, T - phi])
    PhiT = Phi[0]
    Ga = Phi[2] @ Gam[1]
    Gb = Gam[2]

    def numer(g):
        return np.array([g[0], PhiT[0, 1] * g[1] - PhiT[1, 1] * g[0]])

    delta = np.array([1.0, -np.trace(PhiT), np.linalg.det(PhiT)])
    # feed(q) = q·N_Γa(q) + N_Γb(q), ascending in q
    feed = _padd(np.concatenate(([0.0], numer(Ga))), numer(Gb))
    pd = _padd(ctrl.P * a, ctrl.D * b)
    loop = np.concatenate((np.zeros(d + 1), np.convolve(feed, pd))) * (ctrl.command_gain
                                                                      * ctrl.gain)
    chi = _padd(np.convolve(delta, a), loop)
    chi = np.trim_zeros(chi, "b")
    if chi.size < 2:
        return np.empty(0, dtype=complex)
    return np.roots(chi).astype(complex)


def _padd(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Sum of two polynomials given by ascending coefficients."""
    n = max(p.size, q.size)
    out = np.zeros(n)
    out[: p.size] += p
    out[: q.size] += q
    return out
