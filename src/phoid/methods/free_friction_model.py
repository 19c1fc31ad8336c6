r"""The exact free decay of a plant with viscous and Coulomb friction, including the stop.

The model (per unit mass; a = f_c/m, 2σ = c/m, ω₀² = k/m)::

    x'' + 2σ x' + ω₀² (x − x_off) + a·sgn(x') = 0.

Write y = x − x_off and d = a/ω₀² (the half-width of the band of positions where the spring
cannot overcome friction). While the velocity keeps one sign s the motion is a viscous free decay
about the shifted equilibrium e = −s·d. At each velocity zero the mass stops for good when
|ω₀² y| ≤ a, i.e. |y| ≤ d, else the next half-cycle starts with the opposite sign. The static
friction is taken equal to the kinetic one (the same a decides the stop).

Underdamped (ω_d² = ω₀² − σ² > 0). From the state (y₀, v₀) at the window's start, the first
velocity zero is at τ₁ = φ₁/ω_d with φ₁ = atan2(s v₀ ω_d, s (σ v₀ + ω₀² (y₀ − e))) ∈ (0, π)
(s = sgn v₀; τ₁ = 0 when v₀ = 0). From a velocity zero the next one is exactly h = π/ω_d later,
and the half-amplitudes u_k = |y_k| of the turning points obey the closed linear recursion

    u_{k+1} = r·u_k − d(1 + r),   r = e^{−σh},

so u_k = r^{k−1} u₁ − d(1 + r)(1 − r^{k−1})/(1 − r) (= u₁ − 2d(k − 1) when σ = 0), the turning
points alternate in sign, and the mass sticks at the first turning point K with u_K ≤ d
(there y_K = ±u_K ∈ [−d, d], on the side the formula gives). Between turning points the motion is
y = e_k + (y_k − e_k)·e^{−σθ}(cos ω_dθ + (σ/ω_d) sin ω_dθ), θ the time since the turning point.

Overdamped or critical (ω₀² ≤ σ²): at most one velocity zero, where tanh(wτ)/w = v₀/(σ v₀ +
ω₀²(y₀ − e)) (w = √(σ² − ω₀²); τ = that ratio at w = 0); from rest the motion then creeps to the
shifted equilibrium without another velocity zero (it never formally stops).

:func:`coulomb_decay` evaluates this exactly on an array of times: the turning points and their
amplitudes are computed at once (vectorised closed form), each sample is placed in its
half-cycle by its index ⌊(τ − τ₁)/h⌋, and no loop runs over samples or half-cycles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid.dynamics.plant import modal_basis

__all__ = ["CoulombDecay", "coulomb_decay", "envelope_start"]

#: exponent cap for r^k (σ < 0 in a trial step would otherwise overflow)
_EXP_CAP = 700.0


@dataclass(frozen=True)
class CoulombDecay:
    """The evaluated motion of one release (positions from x_off).

    Attributes
    ----------
    y, v : ndarray
        Position from the offset (m) and velocity (m/s) at the requested times.
    turns : ndarray
        Times of the velocity zeros (s, since the start) up to the last requested time,
        the stop included.
    stop : float or None
        Time (s, since the start) at which the mass sticks for good; None when it is still
        moving at the last requested time (or, overdamped, creeps without stopping).
    stuck : float or None
        Position (m, from the offset) where it sticks; None with ``stop``.
    """

    y: np.ndarray
    v: np.ndarray
    turns: np.ndarray
    stop: float | None
    stuck: float | None


def _sign(x: float) -> float:
    return -1.0 if x < 0 else 1.0


def _first_turn(sigma: float, w0sq: float, d: float, y0: float, v0: float) -> float:
    """Time of the first velocity zero after the start (inf when there is none)."""
    if v0 == 0.0:
        return 0.0
    s = _sign(v0)
    B = sigma * v0 + w0sq * (y0 + s * d)
    q = sigma * sigma - w0sq
    if q < 0:
        wd = math.sqrt(-q)
        return math.atan2(s * v0 * wd, s * B) / wd
    rho = v0 / B if B != 0.0 else math.inf
    if not rho > 0:
        return math.inf
    w = math.sqrt(q)
    xw = rho * w
    if xw >= 1.0:
        return math.inf
    return rho if xw == 0.0 else math.atanh(xw) / w


def _free(theta: np.ndarray, sigma: float, w0sq: float, z0: np.ndarray | float,
          v0: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Viscous free response z, z' at θ from (z0, v0) (any damping)."""
    C, S = modal_basis(theta, sigma, w0sq)
    return z0 * (C + sigma * S) + v0 * S, v0 * (C - sigma * S) - w0sq * z0 * S


def coulomb_decay(tau: np.ndarray, sigma: float, w0sq: float, a: float, y0: float,
                  v0: float) -> CoulombDecay:
    """Exact motion of the Coulomb + viscous free decay at times ``tau`` (module docstring).

    Parameters
    ----------
    tau : ndarray
        Times since the start, s, ≥ 0 and increasing.
    sigma : float
        Decay rate σ = c/(2m), 1/s (any sign).
    w0sq : float
        ω₀² = k/m, 1/s² (> 0).
    a : float
        Friction acceleration f_c/m, m/s² (a < 0 is accepted as an unphysical extension that
        never sticks, so that a = 0 lies inside the parameter space).
    y0, v0 : float
        Position from the offset (m) and velocity (m/s) at τ = 0.

    Returns
    -------
    CoulombDecay

    Raises
    ------
    ValueError
        When ω₀² ≤ 0 (no restoring spring: the stop rule has no meaning).
    """
    tau = np.asarray(tau, dtype=float)
    if not w0sq > 0:
        raise ValueError(f"ω₀² = {w0sq!r} must be > 0")
    d = a / w0sq
    tmax = float(tau[-1]) if tau.size else 0.0
    y = np.empty_like(tau)
    v = np.empty_like(tau)
    with np.errstate(over="ignore", invalid="ignore"):
        if v0 == 0.0 and abs(y0) <= d:
            y[:] = y0
            v[:] = 0.0
            return CoulombDecay(y, v, np.array([0.0]), 0.0, float(y0))
        tau1 = _first_turn(sigma, w0sq, d, y0, v0)
        first = tau < tau1
        if v0 != 0.0:
            s = _sign(v0)
            e0 = -s * d
            zf, vf = _free(tau[first], sigma, w0sq, y0 - e0, v0)
            y[first] = e0 + zf
            v[first] = vf
            if not math.isfinite(tau1):
                return CoulombDecay(y, v, np.empty(0), None, None)
            z1, _ = _free(np.array(tau1), sigma, w0sq, y0 - e0, v0)
            y1 = float(e0 + z1)
        else:
            y1 = float(y0)
        rest = ~first
        q = sigma * sigma - w0sq
        if q >= 0:  # overdamped or critical: from rest, no further velocity zero
            if abs(y1) <= d:
                y[rest] = y1
                v[rest] = 0.0
                return CoulombDecay(y, v, np.array([tau1]), tau1, y1)
            e1 = _sign(y1) * d
            zr, vr = _free(tau[rest] - tau1, sigma, w0sq, y1 - e1, 0.0)
            y[rest] = e1 + zr
            v[rest] = vr
            return CoulombDecay(y, v, np.array([tau1]) if tau1 <= tmax else np.empty(0),
                                None, None)
        wd = math.sqrt(-q)
        h = math.pi / wd
        # turning points k = 1 … n_turn at τ₁ + (k − 1)h, as many as the window holds
        n_turn = int(min(max(math.floor((tmax - tau1) / h), 0) + 2, tau.size + 2))
        k = np.arange(n_turn, dtype=float)          # k − 1
        L = -sigma * h                               # log r
        rk = np.exp(np.minimum(k * L, _EXP_CAP))
        geo = k if L == 0.0 else np.expm1(np.minimum(k * L, _EXP_CAP)) / math.expm1(L)
        r = math.exp(min(L, _EXP_CAP))
        U = rk * abs(y1) - d * (1.0 + r) * geo       # u_k while moving; ±y_K at the stop
        stuck_at = np.flatnonzero(U <= d) if d >= 0 else np.empty(0, dtype=int)
        K = int(stuck_at[0]) if stuck_at.size else None
        sgn = _sign(y1) * np.where(np.arange(n_turn) % 2 == 0, 1.0, -1.0)
        yk = sgn * U
        idx = np.floor((tau[rest] - tau1) / h).astype(np.int64)
        idx = np.clip(idx, 0, n_turn - 1)
        theta = tau[rest] - tau1 - idx * h
        if K is not None:
            moving = idx < K
        else:
            moving = np.ones(idx.shape, dtype=bool)
        ek = sgn * d
        zk = (yk - ek)[idx]
        c_, s_ = np.cos(wd * theta), np.sin(wd * theta)
        ex = np.exp(np.minimum(-sigma * theta, _EXP_CAP))
        yr = np.where(moving, ek[idx] + zk * ex * (c_ + sigma / wd * s_), 0.0)
        vr = np.where(moving, -w0sq * zk * ex * s_ / wd, 0.0)
        if K is not None:
            yr = np.where(moving, yr, yk[K])
        y[rest] = yr
        v[rest] = vr
        t_turn = tau1 + h * np.arange(n_turn)
        last = n_turn if K is None else K + 1
        turns = t_turn[:last]
        turns = turns[turns <= tmax]
        if K is not None and t_turn[K] <= tmax:
            return CoulombDecay(y, v, turns, float(t_turn[K]), float(yk[K]))
        return CoulombDecay(y, v, turns, None, None)


def envelope_start(t: np.ndarray, y: np.ndarray, sigma: float, w0sq: float,
                   noise: float) -> tuple[float, float, float] | None:
    """A start (σ, ω₀², a) from the turning points of a record (positions from the offset).

    The half-cycles are found without a model: y crosses from above +3 noise sd to below
    −3 noise sd or back (a hysteresis that noise cannot trip); each half-cycle's largest |y|
    and its time are its turning point (u_k, t_k), the swings before the largest set aside (a
    hand release rises first), and those after a gap of more than 1.5 median gaps (noise
    about the stuck position). Turning points are h = π/ω_d apart: a line through (k, t_k)
    gives h. While the motion lasts u_{k+1} = r·u_k − d(1 + r) (module docstring) is linear in
    u_k: a line through the pairs (u_k, u_{k+1}) gives r = e^{−σh} and d = a/ω₀².

    Parameters
    ----------
    t, y : ndarray
        The window's samples, s and m (from the viscous fit's offset).
    sigma, w0sq : float
        The viscous estimates (only to check the decay oscillates).
    noise : float
        The record's noise sd, m.

    Returns
    -------
    (sigma, w0sq, a) or None
        None when the viscous estimate is not underdamped or fewer than 4 turning points are
        found.
    """
    if not (sigma * sigma < w0sq) or t.size < 8:
        return None
    th = 3.0 * noise
    state = np.where(y > th, 1, np.where(y < -th, -1, 0))
    nz = np.flatnonzero(state)
    if nz.size < 2:
        return None
    st = state[nz]
    flips = nz[1:][st[1:] != st[:-1]]          # first sample of each new half-cycle
    bounds = np.concatenate([[0], flips, [t.size]])
    if bounds.size < 6:
        return None
    seg = np.repeat(np.arange(bounds.size - 1), np.diff(bounds))
    ay = np.abs(y)
    order = np.lexsort((ay, seg))               # per half-cycle, the largest |y| last
    last = np.concatenate([np.flatnonzero(np.diff(seg[order])), [t.size - 1]])
    peak = order[last]
    u, tk = ay[peak], t[peak]
    j0 = int(np.argmax(u))
    u, tk = u[j0:], tk[j0:]
    if u.size < 4:
        return None
    gaps = np.diff(tk)
    late = np.flatnonzero(gaps > 1.5 * float(np.median(gaps)))
    if late.size:  # noise about the stuck position read as a swing: the motion ended
        u, tk = u[: late[0] + 1], tk[: late[0] + 1]
    if u.size < 4:
        return None
    k = np.arange(u.size, dtype=float)
    h = float(np.polyfit(k, tk, 1)[0])
    A = np.column_stack([u[:-1], np.ones(u.size - 1)])
    (r, c0), *_ = np.linalg.lstsq(A, u[1:], rcond=None)
    if not (0.0 < r < 1.5 and h > 0):
        return None
    s_env = float(-math.log(r) / h)
    w2 = float((math.pi / h) ** 2 + s_env**2)
    return s_env, w2, float(-c0 / (1.0 + r) * w2)
