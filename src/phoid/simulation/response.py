r"""Batched time-domain simulation of the PHO loop: :func:`simulate` and :func:`release_response`.

The model (seed eq. 1 with the feedback of eq. 23 and an optional external force) is

    m x''(t) + c x'(t) + k x(t) + f_c sign(x'(t)) = F(t) + u(t),
    u(t) = −[D x'(t − Δt) + P x(t − Δt)],

for a batch of B runs that share the plant (m, c, k, f_c), the delay Δt, the force F and the
timing, and differ in the gains (Pᵢ, Dᵢ) and, optionally, the initial position; or, with a
``sample_time``, the same plant under the sampled controller of :mod:`phoid.dynamics.digital`.

Experiment timeline
-------------------
For 0 ≤ t < ``hold`` the mass is held still at x₀ (x = x₀, ẋ = 0) while the controller already
runs (u = −P x₀). It is released at t = ``hold`` with x = x₀, ẋ = v₀; the history the delayed
term sees on [hold − Δt, hold] is therefore the constant x₀ (velocity 0). Samples are taken at
t_j = j/f_s, j = 0 … N−1, N = round((hold + duration)·f_s).

:func:`simulate` checks the inputs and the size limits (:mod:`phoid.simulation._checks`) and
dispatches to the continuous loop (:mod:`phoid.simulation._continuous`: the scheme, the
DC-offset bias and the sample-rate rule) or to the sampled one
(:mod:`phoid.simulation._sampled`); Coulomb friction and the bias go through the stick–slip
bookkeeping of :mod:`phoid.simulation._stickslip` in either.

Where the sensor is
-------------------
The recorded position is x̃ = quantise(x + offset + e), e one white draw per sample. With
``noise_in_loop`` (the default of a sampled loop, as on a rig) the controller reads x̃ too, so
the sensor's error is a force on the plant: the sampled scheme's "Sensor in the loop"
(:mod:`phoid.simulation._sampled`) and, for a continuous controller, that of
:mod:`phoid.simulation._continuous`. Otherwise it reads the exact x and e only enters the
record.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from phoid import _validate as v
from phoid._progress import task
from phoid.dynamics.digital import DigitalPD, record_problem
from phoid.errors import PhoidError
from phoid.simulation._checks import MAX_SAMPLES, batch_array, broadcast_batch, plant_params
from phoid.simulation._continuous import (
    continuous_grid,
    feedback_maps,
    history,
    run_continuous,
    run_delayed,
)
from phoid.simulation._propagation import NQ, Engine
from phoid.simulation._sampled import Reading, run_sampled
from phoid.simulation.result import Simulation

__all__ = ["release_response", "simulate"]


def simulate(
    plant: Any,
    P: np.ndarray | float,
    D: np.ndarray | float,
    *,
    delay: float = 0.0,
    duration: float,
    fs: float,
    x0: np.ndarray | float = 0.01,
    v0: np.ndarray | float = 0.0,
    hold: float = 0.0,
    force: Callable[[np.ndarray], np.ndarray] | None = None,
    noise: float = 0.0,
    quantum: float = 0.0,
    offset: float = 0.0,
    rng: np.random.Generator | None = None,
    sample_time: float | None = None,
    velocity: str | Sequence[float] = "backward-difference",
    cutoff: float | None = None,
    delay_samples: int = 0,
    bias: np.ndarray | float = 0.0,
    bias_signs: np.ndarray | None = None,
    noise_in_loop: bool | None = None,
) -> Simulation:
    """Simulate B runs of the delayed PD loop of eq. (23), with Coulomb friction (eq. 1).

    m x'' + c x' + k x + f_c sign(x') = F(t) + u(t), u(t) = −[D x'(t − Δt) + P x(t − Δt)];
    or, with ``sample_time``, the sampled controller of :mod:`~phoid.dynamics.digital`:
    u(t) = u_{n−d} on [nT_s, (n+1)T_s), u_n = −(P x̃_n + D v̂_n), x̃_n the measured position
    (noise in the loop, the default of a sampled loop) or x(nT_s) (``noise_in_loop=False``).

    Parameters
    ----------
    plant : phoid.Plant
        The plant: mass ``m`` (kg), damping ``c`` (N·s/m), stiffness ``k`` (N/m), Coulomb
        friction ``fc`` (N; static = kinetic).
    P : float or array_like, shape (B,)
        Proportional gains, N/m (any sign). One run per entry.
    D : float or array_like, shape (B,)
        Derivative gains, N·s/m (any sign; overdamped plants need D < 0 to oscillate).
    delay : float, default 0
        Loop delay Δt, s (≥ 0). Δt = 0 is the plain ODE with the gains folded in.
    duration : float
        Time simulated after the release, s (> 0).
    fs : float
        Sample rate, Hz (> 0); at least 4 samples per period of the fastest closed-loop mode
        (the sample-rate rule of :mod:`phoid.simulation._continuous`).
    x0 : float or array_like, shape (B,), default 0.01
        Position at which the mass is held and released, m.
    v0 : float or array_like, shape (B,), default 0
        Velocity given at release, m/s.
    hold : float, default 0
        Duration of the held segment before the release, s (≥ 0). While held, x = x₀, ẋ = 0 and
        u = −P x₀; the delayed history at release is the constant x₀.
    force : callable, optional
        External force F(t), N, on the absolute time axis of the result (release at t = hold);
        called once with a 1-D array of times and must return an array of the same shape.
        Ignored while the mass is held.
    noise : float, default 0
        Standard deviation of white Gaussian sensor noise, m (≥ 0); needs ``rng``. One draw
        per recorder sample, inside or outside the loop (``noise_in_loop``).
    quantum : float, default 0
        Quantisation step of the measured position, m (≥ 0; 0 means none). Applied last:
        x̃ = quantum·round((x + offset + noise)/quantum).
    offset : float, default 0
        Offset added to the measured position, m. Read by the controller (noise in the loop),
        a constant offset is a constant command −P·offset: it moves the equilibrium.
    rng : numpy.random.Generator, optional
        Source of the noise (required when ``noise`` > 0; global random state is never used).
        The draws are ``noise * rng.standard_normal((B, N))`` wherever the noise is.
    sample_time : float, optional
        Controller sample time T_s, s (> 0): simulate the sampled (digital) loop instead of the
        continuous one (``delay`` must then be 0; the command delay is ``delay_samples``).
        ``fs`` must be a whole multiple M ≥ 1 of 1/T_s and ``hold`` a whole number of 1/fs.
        The four-samples-per-period rule of the continuous loop does not apply.
    velocity : str or sequence of float, default "backward-difference"
        Velocity estimator of the sampled controller: a preset of
        :mod:`phoid.dynamics.velocity` (``"backward-difference"``, ``"central-difference"``,
        ``"filtered"``) or FIR coefficients b₀, b₁, … (1/s) of v̂ₙ = Σⱼ bⱼ xₙ₋ⱼ (see
        :class:`phoid.dynamics.digital.DigitalPD`). The first-order ones take the χ recursion
        of :mod:`phoid.simulation._sampled`; the others one exact step per controller period.
    cutoff : float, optional
        Cut-off ω_c of the filtered estimator, rad/s (required with ``velocity="filtered"``).
    delay_samples : int, default 0
        Command delay d of the sampled controller, whole samples (≥ 0).
    bias : float or array_like, shape (B,), default 0
        DC offset b ≥ 0 of the command in the direction of the controller's velocity, N (the
        seed's "PD feedback augmented with a DC offset in the (alternating) direction of
        oscillation", Discussion, last paragraph): u gains + b·sign(ẋ(t − Δt)) (continuous
        loop; sign(0) = 0, so none while held or stuck) or + b·sign(v̂_{n}) in the sampled
        command u_n. Simulated exactly: see "DC-offset bias" in
        :mod:`phoid.simulation._continuous` and :mod:`phoid.simulation._sampled`.
    noise_in_loop : bool or None, default None
        Whether the controller reads the measured position x̃ (offset, noise and quantisation
        inside the loop, as on a rig) or the exact one (the sensor's error added to the record
        afterwards). None: True for a sampled controller (``sample_time``), False for the
        continuous loop. Sampled loop, in the loop: at its instant n the controller reads
        x̃ₙ = quantise(x(nT_s) + offset + eⱼ), j = nM, exactly the recorded value there (the
        samples between instants carry their own draws, not read); while the mass is held it
        reads x₀ + offset + noise (quantised) and its commands queue with the delay; before
        the record it had read quantise(x₀ + offset). Continuous loop, in the loop: the
        controller reads x + offset + ẽ(t), ẽ the draws joined by straight lines (its slope
        feeds D; 0 before the record's first sample); it needs every sample on the internal
        grid (delay and hold whole samples, or small-denominator ratios of them) and refuses
        friction, a bias and a quantiser. Outside the loop, results are those of phoid before
        the option (the same draws, bit for bit).
    bias_signs : array_like, shape (B, n), optional
        Sampled controller with a bias only: prescribe sign(v̂_n) (−1, 0, 1) for the commands
        n = 0 … n − 1 instead of taking it from v̂_n (later ones 0), e.g. a previous
        simulation's :attr:`Simulation.bias_signs` (to see what one switch of the bias
        does: the sampled loop's output jumps where a velocity reversal crosses a controller
        instant, the bias flipping a period earlier or later).

    Returns
    -------
    Simulation
        Times, measured and exact positions, velocities and applied feedback forces of the B
        runs, and where the noise was (``noise_in_loop``).

    Raises
    ------
    ValueError
        For a non-finite, negative or inconsistent input (the message names the parameter and
        its value), a sample rate too low for the closed-loop dynamics (``fs``), or, for a
        sampled controller, an ``fs`` that is not a whole multiple of 1/T_s or a ``hold`` that
        is not a whole number of recorder intervals; with the noise in a continuous loop,
        friction, a bias, a quantiser or samples off the internal grid.
    phoid.errors.PhoidError
        (a ValueError) Before anything is allocated, when the simulation would exceed its size
        limits: B × (``hold`` + ``duration``) × ``fs`` above :data:`MAX_SAMPLES` (5e7 samples,
        about 3 GB), or B × (``hold`` + ``duration``)/h above :data:`MAX_STEPS` (2e8 internal
        steps of h ≤ min(1/``fs``, Δt)).

    Examples
    --------
    >>> from phoid import Plant
    >>> sim = simulate(Plant(2.0, 1.0, 64.0), [0.25, 25.0], [0.6, 6.0], delay=0.1,
    ...                duration=1.0, fs=1000.0)
    >>> sim.x.shape, float(sim.x_true[0, 0])
    ((2, 1000), 0.01)
    """
    m, c, k, fc = plant_params(plant)
    delay = v.nonnegative("delay", delay, "s")
    duration = v.positive("duration", duration, "s")
    fs = v.positive("fs", fs, "Hz")
    hold = v.nonnegative("hold", hold, "s")
    noise = v.nonnegative("noise", noise, "m")
    quantum = v.nonnegative("quantum", quantum, "m")
    offset = v.finite("offset", offset, "m")
    if force is not None and not callable(force):
        raise ValueError(f"`force` must be a callable F(t) or None; got {force!r}")
    if noise > 0 and not isinstance(rng, np.random.Generator):
        raise ValueError(f"`rng` must be a numpy.random.Generator when `noise` > 0; got {rng!r}")
    B, arr = broadcast_batch(
        P=batch_array("P", P, "N/m"),
        D=batch_array("D", D, "N·s/m"),
        x0=batch_array("x0", x0, "m"),
        v0=batch_array("v0", v0, "m/s"),
        bias=batch_array("bias", bias, "N"),
    )
    P, D, x0a, v0a = arr["P"], arr["D"], arr["x0"], arr["v0"]
    if np.any(arr["bias"] < 0):
        raise ValueError(f"`bias` must be ≥ 0 N; got {float(np.min(arr['bias']))!r}")
    biased = arr["bias"].copy() if np.any(arr["bias"] > 0) else None
    n_samples = (hold + duration) * fs
    if B * n_samples > MAX_SAMPLES:
        raise PhoidError(
            f"{B} runs × (`hold` + `duration`) × `fs` = {B:d} × ({hold:g} + {duration:g}) s × "
            f"{fs:g} Hz = {B * n_samples:.3g} samples, above the simulator's limit of "
            f"{MAX_SAMPLES:.0e} (about {64 * MAX_SAMPLES / 1e9:.0f} GB): shorten the duration, "
            "lower the sample rate or simulate fewer runs at a time")
    N = round(n_samples)
    if N < 1:
        raise ValueError(f"`duration` × `fs` must give at least one sample; got {duration:g} s")
    if noise_in_loop is not None and not isinstance(noise_in_loop, (bool, np.bool_)):
        raise ValueError("`noise_in_loop` must be True, False or None (the loop's default); "
                         f"got {noise_in_loop!r}")
    in_loop = (sample_time is not None) if noise_in_loop is None else bool(noise_in_loop)
    # the sensor's error reaches the plant only when the controller reads it
    sensed = in_loop and (noise > 0 or quantum > 0 or offset != 0)
    if sensed and sample_time is None:
        what = ("Coulomb friction (fc > 0)" if fc > 0 else "a bias" if biased is not None
                else "a quantiser (quantum > 0)" if quantum > 0 else None)
        if what is not None:
            raise ValueError(
                f"`noise_in_loop`: {what} with the sensor in a continuous loop is not simulated; "
                "give a sampled controller (`sample_time`) or noise_in_loop=False")
    e = None
    if sensed and noise > 0:  # the draws the recorder keeps, and the controller reads
        e = noise * rng.standard_normal((B, N))

    signs = None
    if bias_signs is not None and sample_time is None:
        raise ValueError("`bias_signs` applies only to a sampled controller (`sample_time`)")
    if sample_time is not None:
        if delay != 0.0:
            raise ValueError(
                f"`delay` must be 0 with a sampled controller (`sample_time`); give the command "
                f"delay in whole samples as `delay_samples`; got delay={delay:g} s"
            )
        loop = DigitalPD(0.0, 0.0, sample_time, delay_samples, velocity, cutoff)
        problem = record_problem(loop, duration)  # the record after the release
        if problem is not None:
            raise ValueError(f"`{problem[0]}`{problem[1]}")
        if bias_signs is not None:
            bias_signs = np.asarray(bias_signs, dtype=float)
            if bias_signs.ndim != 2 or bias_signs.shape[0] != B \
                    or not np.all(np.isin(bias_signs, (-1.0, 0.0, 1.0))):
                raise ValueError("`bias_signs` must be an array (B, n) of −1, 0, 1; got shape "
                                 f"{bias_signs.shape}")
        # a motion that overflows becomes inf/nan, refused below in one line (not a warning)
        with task(_LONG_TEXT.format(B), show=B * N >= _LONG_SAMPLES), np.errstate(all="ignore"):
            x_true, vel, u, signs, read = run_sampled(
                m, c, k, fc, P, D, x0a, v0a, hold, fs, N, force, loop, biased, bias_signs,
                Reading(e, offset, quantum) if sensed else None)
    else:
        if delay > duration:  # (and its grid would hold delay/h steps of history)
            raise ValueError(
                f"`delay` = {delay:g} s is longer than `duration` ({duration:g} s): the "
                "feedback would never act on the released motion within the record")
        plain = isinstance(velocity, str) and velocity == "backward-difference"
        if delay_samples != 0 or not plain or cutoff is not None:
            name = "delay_samples" if delay_samples != 0 else (
                "velocity" if not plain else "cutoff")
            raise ValueError(
                f"`{name}` applies only to a sampled controller: give `sample_time` as well"
            )
        with task(_LONG_TEXT.format(B), show=B * N >= _LONG_SAMPLES), np.errstate(all="ignore"):
            x_true, vel, u = run_continuous(
                m, c, k, fc, P, D, delay, x0a, v0a, hold, fs, N, force, biased,
                (e, offset) if sensed else None
            )
        loop = read = None

    if not (_finite(x_true) and _finite(vel) and _finite(u)):
        raise PhoidError(
            "the simulated motion overflows the floating-point range: check the plant's m, c, "
            "k, the gains P, D, the release state x0, v0 and the force"
            + (" (and `offset`, `noise`, `quantum`: the controller reads them, "
               "`noise_in_loop`)" if sensed else ""))
    with np.errstate(all="ignore"):
        x = x_true + offset
        if noise > 0:
            x = x + (noise * rng.standard_normal((B, N)) if e is None else e)
        if quantum > 0:
            x = np.round(x / quantum) * quantum
        if read is not None:  # at its instants, what the controller read (the same draws)
            Mr = round(fs * loop.sample_time)
            x[:, : (read.shape[1] - 1) * Mr + 1 : Mr] = read
    if not _finite(x):
        raise PhoidError(
            f"the measured position overflows the floating-point range: check `offset` "
            f"({offset:g} m), `noise` ({noise:g} m) and `quantum` ({quantum:g} m) against the "
            "motion")
    return Simulation(
        t=np.arange(N) / fs,
        x=x,
        x_true=x_true,
        v=vel,
        u=u,
        release=hold,
        P=P.copy(),
        D=D.copy(),
        delay=delay if loop is None else loop.delay,
        fs=fs,
        sample_time=None if loop is None else loop.sample_time,
        delay_samples=0 if loop is None else loop.delay_samples,
        velocity=None if loop is None else loop.velocity,
        cutoff=None if loop is None else loop.cutoff,
        bias=arr["bias"].copy(),
        bias_signs=signs,
        noise_in_loop=in_loop,
    )


def _finite(a: np.ndarray) -> bool:
    """Every element finite (one pass: a NaN or inf makes the sum NaN or inf; an overflowing
    sum of finite values is looked at closely)."""
    with np.errstate(all="ignore"):
        return bool(np.isfinite(np.add.reduce(a, axis=None)) or np.all(np.isfinite(a)))


_LONG_SAMPLES = 10_000_000  # runs × samples from which a progress bar is shown (~1 s)
_LONG_TEXT = "simulating {} run(s): steps"
_TOEPLITZ_STEPS = 32  # release_response: at most this many steps per delay by products


def release_response(plant: Any, P: np.ndarray, D: np.ndarray, *, delay: float,
                      duration: float, fs: float) -> np.ndarray:
    """``simulate(plant, P, D, delay=delay, duration=duration, fs=fs, x0=1.0).x_true``, cheaper
    where a delay spans few internal steps.

    The loop's response from rest at 1 (no hold, force, friction or bias), for the
    identification's model-fitted release. Same scheme and grid as :func:`simulate`;
    where the grid is the sample grid and one delay is d ≤ 32 steps, each block of d steps is
    solved by one product instead of the Cayley–Hamilton ``lfilter``: Y_n = Φⁿ y₀ +
    Σ_{i<n} Φ^{n−1−i} w_i (n = 0 … d) is a fixed (2 + 2d) × 2(d + 1) matrix applied to
    (y₀, w) of all the runs. A short delay means many blocks (Python iterations), so the fewer
    array operations per block are what count (docs/design-notes/simulation.md).
    The sums are those of the exact 2 × 2 recursion, so the result agrees with
    :func:`simulate`'s to its rounding (≲ 1e−11 of x₀; no refinement needed). Otherwise
    simulate's own recursion on the same grid (the same numbers).

    Parameters
    ----------
    plant : phoid.Plant
        The plant (m, kg; c, N·s/m; k, N/m; its ``fc`` must be 0 N).
    P, D : ndarray, shape (B,)
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    duration : float
        Time simulated after the release, s.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    ndarray, shape (B, N)
        The positions at t_j = j/f_s, m per m of release displacement.

    Raises
    ------
    ValueError
        As :func:`simulate` (e.g. ``fs`` below the sample-rate rule).
    """
    m, c, k, fc = plant_params(plant)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    N = round(duration * fs)

    if not (delay > 0 and fc == 0 and N >= 1 and P.ndim == 1 and P.shape == D.shape):
        return simulate(plant, P, D, delay=delay, duration=duration, fs=fs, x0=1.0).x_true
    grid = continuous_grid(m, c, k, P, D, delay, 0.0, fs, N)
    d = grid.d
    B = P.size
    A0 = np.array([[0.0, 1.0], [-k / m, -c / m]])
    if not grid.unit or d > _TOEPLITZ_STEPS:  # simulate's own path (run_continuous)
        out = (np.empty((B, N)), np.empty((B, N)), np.empty((B, N)))
        with task("release response", show=False):  # its steps advance no outer bar
            run_delayed(m, fc, A0, P, D, np.ones(B), np.zeros(B), None, grid, out)
        return out[0]
    eng = Engine(A0[None], m, grid.h, grid.n_steps)
    L10, _ = feedback_maps(A0, m, grid.h, P, D)
    L10T = np.swapaxes(L10, 1, 2)  # (B, 6, 10)
    G = np.concatenate([L10T, np.matmul(eng.K[0], L10T)], axis=1)  # -> (c^u, w = K c^u)
    # Φ^j, j = 0 … d, and the block map (y₀, w_0 … w_{d−1}) -> Y_0 … Y_d (component-major)
    pw = np.empty((d + 1, 2, 2))
    pw[0], pw[1] = np.eye(2), eng.Phi[0]
    j = 1
    while j < d:  # doubling: Φ^{j+1} … Φ^{2j} from Φ … Φ^j
        top = min(2 * j, d)
        pw[j + 1 : top + 1] = pw[1 : top - j + 1] @ pw[j]
        j = top
    n = np.arange(d + 1)
    lag = n[None, :] - 1 - np.arange(d)[:, None]  # (i, n): n − 1 − i
    T = np.zeros((2 + 2 * d, 2, d + 1))
    T[:2] = np.moveaxis(pw, 0, 2).transpose(1, 0, 2)  # [c, a, n] = (Φⁿ)_ac
    blk = pw[np.maximum(lag, 0)].transpose(3, 0, 2, 1) * (lag >= 0)[None, :, None, :]
    T[2:] = blk.reshape(2 * d, 2, d + 1)  # [(c, i), a, n] = (Φ^{n−1−i})_ac, i < n
    T = T.reshape(2 + 2 * d, 2 * (d + 1))
    nb = -(-grid.n_steps // d)
    x = np.empty((B, nb * d + 1))
    S = history(B, d, np.ones(B), m * -A0[1, 0])
    y = np.stack([np.ones(B), np.zeros(B)], axis=1)
    for n0 in range(0, nb * d, d):  # the last block in full: the steps past the end unused
        Z = np.matmul(G, S)  # (B, 8, d)
        Y = (np.concatenate([y, Z[:, NQ:].reshape(B, 2 * d)], axis=1) @ T).reshape(B, 2, d + 1)
        x[:, n0 : n0 + d + 1] = Y[:, 0]
        S = np.concatenate([Y[:, :, :-1], Y[:, :, 1:], Z[:, :NQ]], axis=1)
        y = Y[:, :, -1]
    return x[:, :N]
