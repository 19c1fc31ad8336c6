"""The result of a simulation: :class:`Simulation`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from phoid.dynamics.digital import DigitalPD

__all__ = ["Simulation"]


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`phoid.simulation.response.simulate`: B runs sampled at N instants.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times t_j = j/f_s, s.
    x : ndarray, shape (B, N)
        Measured (recorded) position, m: ``x_true + offset + noise``, then quantised. With the
        noise in a sampled loop, its values at the controller's instants are what the
        controller read (the same draws).
    x_true : ndarray, shape (B, N)
        Exact position, m (the plant's true motion).
    v : ndarray, shape (B, N)
        Exact velocity, m/s.
    u : ndarray, shape (B, N)
        Feedback force applied at the plant, u = −[D ẋ(t − Δt) + P x(t − Δt)] (+ the bias
        b·sign(ẋ(t − Δt))), N (eq. 23);
        −P x₀ while held. At an instant where u jumps (a v₀ ≠ 0 release seen through D), the
        value after the jump.
    release : float
        Release time, s (= ``hold``).
    P : ndarray, shape (B,)
        Proportional gains, N/m.
    D : ndarray, shape (B,)
        Derivative gains, N·s/m.
    delay : float
        Loop delay Δt, s.
    fs : float
        Sample rate, Hz.
    sample_time : float or None
        Controller sample time T_s, s, for a sampled controller (None: continuous loop). Then
        ``delay`` is the command delay d·T_s and ``u`` the held command u_{n−d}.
    delay_samples : int
        Command delay d of the sampled controller, samples (0 for a continuous loop).
    velocity : str, tuple of float or None
        Velocity estimator of the sampled controller: a preset name or FIR coefficients, 1/s
        (None for a continuous loop).
    cutoff : float or None
        Cut-off ω_c of the filtered velocity estimator, rad/s.
    bias : ndarray, shape (B,) or None
        DC offset b of each run's command in the direction of the controller's velocity, N
        (``u`` includes it).
    bias_signs : ndarray, shape (B, n) or None
        Sampled controller with a bias: sign(v̂_n) used in each command u_n (n = 0 … the last
        controller instant of the record); None otherwise.
    noise_in_loop : bool
        True when the controller read the measured position (its offset, noise and
        quantisation inside the loop; ``u`` is then the force from those readings), False
        when it read the exact one (the sensor's error only in ``x``).
    """

    t: np.ndarray
    x: np.ndarray
    x_true: np.ndarray
    v: np.ndarray
    u: np.ndarray
    release: float
    P: np.ndarray
    D: np.ndarray
    delay: float
    fs: float
    sample_time: float | None = None
    delay_samples: int = 0
    velocity: str | tuple[float, ...] | None = None
    cutoff: float | None = None
    bias: np.ndarray | None = None
    bias_signs: np.ndarray | None = None
    noise_in_loop: bool = False

    def digital_loop(self, i: int) -> DigitalPD:
        """Run i's sampled controller as a :class:`phoid.dynamics.digital.DigitalPD`.

        Raises
        ------
        ValueError
            If the simulation used a continuous loop (``sample_time`` is None).
        """
        if self.sample_time is None:
            raise ValueError("`sample_time`: this simulation used a continuous loop")
        return DigitalPD(float(self.P[i]), float(self.D[i]), self.sample_time,
                         self.delay_samples, self.velocity, self.cutoff)
