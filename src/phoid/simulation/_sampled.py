r"""The sampled (digital) control loop of :mod:`phoid.dynamics.digital`, simulated exactly.

With ``sample_time`` = T_s the controller samples x_n = x(nT_s) on its own clock (t_n = nT_s
from t = 0), estimates the velocity (:mod:`phoid.dynamics.velocity`: the backward difference,
its first-order low pass, the central difference or FIR coefficients), computes
u_n = −(P x_n + D v̂_n) and holds u(t) = u_{n−d} on [nT_s, (n+1)T_s) (``delay_samples`` = d).
While the mass is held the controller runs on x = x₀ (v̂ = 0, commands −P x₀), as in the
continuous path. The recorder samples at f_s = M/T_s, M a whole
number ≥ 1, and ``hold`` must be a whole number of recorder intervals (a release between two
controller instants is allowed: the first period after it is partial). Scheme, for the linear
plant (f_c = 0) and a first-order estimator (v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1})):

1. **Controller instants.** From the first controller instant after the release, x_n obeys
   χ(q) x_n = [Q-terms of the release state] + [the external force], χ the exact characteristic
   polynomial of :mod:`~phoid.dynamics.digital`: X(z) = [Q(z) + z^d(z − a)((z − Φ₂₂)F₁(z) +
   Φ₁₂F₂(z))]/χ(z)
   with F_n the plant state that the external force alone adds over period n. One IIR
   recursion per run (order d + 3, :mod:`phoid.simulation._recursion`, all runs in one call)
   gives every x_n at once.
2. **One step of iterative refinement.** From x_n, the estimator state (a first-order
   recursion), the commands and the held, delayed input follow; the plant's exact 2 × 2
   recursion y_{n+1} = Φ y_n + Γ u_{n−d} + F_n driven by them (the Cayley–Hamilton filter with
   its own refinement, :mod:`phoid.simulation._propagation`) gives x̃_n. The defect e = x̃ − x
   is mapped back through the closed loop's sensitivity z^d(z − a)Δ(z)/χ(z) (one more
   recursion) and added to x; the commands and the plant state are recomputed from the
   corrected x. The recorded x, ẋ are the plant recursion's, so x, ẋ and u are consistent to
   rounding (≈ N·ε).
3. **Between controller instants** (M > 1): y(nT_s + ih) = Φ(ih) y_n + Γ(ih) u_{n−d} plus the
   force's share, with Φ(ih), Γ(ih) exact exponentials (h = T_s/M), for all n at once.
4. **External force.** Quintic interpolants on sub-steps of the recorder interval
   (Chebyshev–Lobatto nodes, as for the continuous loop; sub-steps so that ρh ≤ 0.1 for the
   plant's and the loop's dominant rates), propagated exactly; shared by all runs.

Python thus loops over the sub-steps of one period, never over runs, periods or samples. With
Coulomb friction (f_c > 0) the plant is propagated by the stick–slip machinery of
:mod:`phoid.simulation._stickslip` in blocks of d + 1 controller periods (within such a block
every applied command is already known), and the commands are updated after each block:
Python loops over blocks, i.e. ≈ N/(M(d + 1)) iterations.

A DC-offset bias b adds one more term to the command, uₙ = −P xₙ − D v̂ₙ + b·sign(v̂ₙ), held by
the zero-order hold; the loop is then nonlinear and takes the block-by-block path of the
friction, exact like it (commands after each block).

Sensor in the loop
------------------
With the noise in the loop (:class:`Reading`, ``noise_in_loop``) the controller reads, at its
instant n, x̃ₙ = Q(x(nT_s) + offset + eⱼ) (j = nM the recorder sample there, eⱼ that sample's
noise draw, Q the quantiser of step q, or none): exactly the value the recorder keeps at that
sample. Before the record (n < 0) it has read the held position without noise,
x̃ = Q(x₀ + offset) (v̂ = 0, queued commands −P x̃); while the mass is held it reads
Q(x₀ + offset + eⱼ), and its commands (v̂ no longer 0) queue with the delay.

* **Linear loop** (f_c = 0, no bias, no quantiser). The estimator is linear, so
  uₙ = −(P xₙ + D v̂(x)ₙ) + rₙ with rₙ = −(P εₙ + D v̂(ε)ₙ), εₙ = offset + eₙ (ε = offset
  before the record): the loop of the noise-free case driven by the extra, known command r
  (superposition). r enters the recursion of item 1 like any applied command, through
  (z − a)N(z) z^{−3} (as the queued commands' own term), and the commands of item 2 carry it:
  every instant at once, as exact as the noise-free loop, no extra Python loop.
* **Quantiser, no friction or bias.** Q makes the loop nonlinear: one Python iteration per
  controller period after the release (≈ duration/T_s, vectorised over the runs), each the
  exact 2 × 2 map y_{n+1} = Φ y_n + Γ u_{n−d} (+ the force's share); the samples between
  instants as in item 3.
* **Friction or bias.** The block-by-block path reads x̃ instead of x (the same blocks).

Other estimators
----------------
An estimator that is not first-order (the central difference, FIR coefficients; Σᵢ aᵢ v̂ₙ₋ᵢ =
Σⱼ bⱼ xₙ₋ⱼ) has no χ recursion here: the linear loop takes the period-by-period path of the
quantiser (reading x, or x̃ with the noise in the loop), and the block path runs the estimator
from its histories (the last r_b readings and r_a estimates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid._progress import step as progress_step
from phoid.dynamics.digital import (
    DigitalPD,
    ZOHPlant,
    characteristic_coefficients,
    digital_roots,
    expm_stack,
)
from phoid.dynamics.plant import quadratic_roots
from phoid.errors import PhoidError
from phoid.simulation._checks import MAX_STEPS
from phoid.simulation._propagation import NQ, RHO_H, Engine, force_coeffs
from phoid.simulation._recursion import recurse
from phoid.simulation._stickslip import Friction

__all__ = ["Reading", "run_sampled"]


@dataclass(frozen=True)
class Reading:
    """The sensor that the sampled controller reads (noise in the loop).

    x̃ = Q(x + offset + eⱼ), Q rounding to a multiple of ``quantum`` (none when 0).

    Attributes
    ----------
    e : ndarray, shape (B, N), or None
        The noise draw at every recorder sample, m (None: no noise).
    offset : float
        Sensor offset, m.
    quantum : float
        Quantisation step, m (0: none).
    """

    e: np.ndarray | None
    offset: float
    quantum: float

    @property
    def linear(self) -> bool:
        """No quantiser: x̃ is x plus a known signal."""
        return self.quantum == 0

    def read(self, x: np.ndarray, j: np.ndarray | None) -> np.ndarray:
        """x̃ of the true positions x (B, k) at recorder samples j (k,); j None: before the
        record (no noise). The recorded position's formula, operation for operation, so the
        reading at a controller instant is the recorded value there bit for bit."""
        z = x + self.offset
        if self.e is not None and j is not None:
            z = z + self.e[:, j]
        if self.quantum > 0:
            z = np.round(z / self.quantum) * self.quantum
        return z


def run_sampled(m, c, k, fc, P, D, x0, v0, hold, fs, N, force, loop: DigitalPD, bias=None,
                 signs=None, reading: Reading | None = None):
    """The hybrid loop of :mod:`~phoid.dynamics.digital`: exact positions, velocities, commands.

    Returns x (B, N), ẋ (B, N), the applied force u (B, N), the bias signs (B, n) or None, and,
    with ``reading``, what the controller read at its instants (B, n) (else None).
    """
    B = P.size
    T = loop.sample_time
    d = loop.delay_samples
    Mr = round(fs * T)
    if Mr < 1 or abs(fs * T - Mr) > 1e-9 * max(1.0, fs * T):
        raise ValueError(
            f"`fs` must be a whole multiple of the controller rate 1/sample_time = {1.0 / T:g} "
            f"Hz for a sampled controller; got {fs:g} Hz (fs·sample_time = {fs * T:.6g})"
        )
    j_rel = round(hold * fs)
    if abs(hold * fs - j_rel) > 1e-9 * max(1.0, hold * fs):
        raise ValueError(
            f"`hold` must be a whole number of recorder intervals 1/fs = {1.0 / fs:g} s for a "
            f"sampled controller; got {hold:g} s"
        )
    h = T / Mr
    n_last = (N - 1) // Mr  # last controller instant in the record
    if d > n_last + 1:  # its companion arrays hold d + 4 values per run: bounded by the record
        raise ValueError(
            f"`delay_samples` = {d} periods ({d * T:.4g} s) is longer than the record "
            f"({n_last + 1} controller periods): the command would never reach the plant")
    x_true = np.empty((B, N))
    vel = np.empty((B, N))
    jr = min(j_rel, N)
    x_true[:, :jr] = x0[:, None]
    vel[:, :jr] = 0.0
    n1 = -(-j_rel // Mr)  # first controller instant at or after the release
    r0 = n1 * Mr - j_rel  # recorder intervals from the release to it
    U = np.repeat((-P * x0)[:, None], n_last + 1, axis=1)  # commands u_n (held: −P x₀)
    S_out = None
    if bias is not None:  # sign(v̂_n) of each command: prescribed, or recorded here
        S_out = np.zeros((B, n_last + 1))
        if signs is not None:
            S_out[:, : min(n_last + 1, signs.shape[1])] = signs[:, : n_last + 1]
    u_pre = -P * x0  # the commands queued before the record
    first = loop.estimator.first_order  # v̂ₙ = a v̂ₙ₋₁ + c_f (xₙ − xₙ₋₁): the χ recursion
    n_hold = min(n1, n_last + 1)  # the instants while the mass is held
    Xr = rfull = None
    held = (x0, np.zeros((B, n_hold)))  # reading before the record, v̂ while held
    if reading is not None:
        Xr = np.empty((B, n_last + 1))
        Xr[:, :n_hold] = reading.read(x0[:, None], np.arange(n_hold) * Mr)
        if fc == 0 and bias is None and reading.linear and first:
            rfull = _perturbation(P, D, loop, reading, Mr, n_last)
            U[:, :n_hold] += rfull[:, d + 1 : d + 1 + n_hold]
            u_pre = u_pre + rfull[:, 0]
        else:
            held = _held_commands(P, D, loop, reading, x0, Xr[:, :n_hold], U, bias,
                                  None if bias is None else (S_out, signs is not None))
            u_pre = -P * held[0]
    if j_rel <= N - 1:
        S = 1
        if force is not None or fc > 0 or bias is not None:
            # sub-steps of the recorder interval: ρh ≤ 0.1 for the plant's and the loop's
            # dominant rates (force interpolation; Taylor series of the friction events)
            rho = float(np.max(np.abs(quadratic_roots(m, c, k))))
            dom = digital_roots(m, c, k, P, D, loop).dominant
            rho = max(rho, float(np.max(np.abs(dom[np.isfinite(dom)]), initial=0.0)))
            subs = rho * h / RHO_H
            if not B * (N - 1 - j_rel) * subs <= MAX_STEPS:  # an infinite rate too
                raise PhoidError(
                    f"the simulation would take {B * (N - 1 - j_rel) * subs:.3g} internal steps "
                    f"({B} runs, {N - 1 - j_rel} recorder intervals in sub-steps of 0.1/(fastest "
                    f"rate {rho:.3g} 1/s)), above the limit of {MAX_STEPS:.0e}: check the "
                    "plant's m, c, k and the gains, or shorten the duration")
            S = max(1, math.ceil(subs - 1e-9))
        k_total = (N - 1 - j_rel) * S  # sub-steps simulated after the release
        cF = force_coeffs(force, hold, h / S, k_total)
        geo = _SampledGeometry(Mr, S, h, j_rel, n1, r0, n_last, k_total)
        out = (x_true, vel, U)
        if fc > 0 or bias is not None:  # the bias makes the loop nonlinear: block by block
            _sampled_friction(m, c, k, fc, P, D, x0, v0, loop, geo, cF, out, bias,
                              None if bias is None else (S_out, signs is not None),
                              (reading, Xr, held, u_pre))
        elif not first or (reading is not None and not reading.linear):
            _sampled_stepwise(m, c, k, P, D, x0, v0, loop, geo, cF, out, reading, Xr, held,
                              u_pre)
        else:
            _sampled_linear(m, c, k, P, D, x0, v0, loop, geo, cF, out, rfull, reading, Xr)
    # the force applied at each sample: the command u_{n−d} of the period holding it
    n_of = np.arange(N) // Mr - d
    u = np.where(n_of[None, :] >= 0, U[:, np.maximum(n_of, 0)], u_pre[:, None])
    return x_true, vel, u, S_out, Xr


def _perturbation(P, D, loop: DigitalPD, reading: Reading, Mr: int, n_last: int) -> np.ndarray:
    """The commands' share of the reading's error, rₙ = −(P εₙ + D v̂(ε)ₙ), εₙ = offset + eₙ.

    Returns (B, n_last + d + 2): column n + d + 1 holds rₙ, n = −d − 1 … n_last (ε = offset,
    v̂(ε) = 0 before the record, so rₙ = −P·offset there).
    """
    B = P.size
    d = loop.delay_samples
    a, cf = loop.filter_pole, loop.filter_gain
    eps = np.full((B, n_last + 1), reading.offset)
    if reading.e is not None:
        eps = eps + reading.e[:, : n_last * Mr + 1 : Mr]
    de = np.diff(eps, axis=1, prepend=reading.offset)  # εₙ − εₙ₋₁ (= eₙ − eₙ₋₁, e₋₁ = 0)
    ve = recurse([1.0, -a], de, b=[cf])
    r = np.empty((B, n_last + d + 2))
    r[:, : d + 1] = (-P * reading.offset)[:, None]
    r[:, d + 1 :] = -(P[:, None] * eps + D[:, None] * ve)
    return r


def _estimate(est, xs, x_hist, v_hist) -> np.ndarray:
    """v̂ (B, k) of the estimator ``est`` (:class:`~phoid.dynamics.velocity.VelocityFilter`,
    Σᵢ aᵢ v̂ₙ₋ᵢ = Σⱼ bⱼ xₙ₋ⱼ) at the readings xs (B, k), after the readings x_hist (B, ≥ r_b)
    and estimates v_hist (B, ≥ r_a) before them (oldest first)."""
    b, a = est.coefficients()
    rb, ra = b.size - 1, a.size - 1
    k = xs.shape[1]
    z = np.zeros((xs.shape[0], min(max(rb, ra), k)))  # the history's share of the first ones
    for n in range(z.shape[1]):
        for j in range(n + 1, rb + 1):
            z[:, n] += b[j] * x_hist[:, x_hist.shape[1] + n - j]
        for i in range(n + 1, ra + 1):
            z[:, n] -= a[i] * v_hist[:, v_hist.shape[1] + n - i]
    return recurse(a, xs, b=b, zi=z if z.size else None)


def _histories(est, x_pre, v_held, Xh):
    """The last r_b readings and r_a estimates (oldest first) at the last held instant: the
    held readings Xh (B, n) and estimates v_held after the pre-record reading x_pre at rest."""
    B = x_pre.size
    b, a = est.coefficients()
    rb, ra = b.size - 1, a.size - 1
    xh = np.concatenate([np.repeat(x_pre[:, None], rb, axis=1), Xh], axis=1)[:, Xh.shape[1]:]
    vh = np.concatenate([np.zeros((B, ra)), v_held], axis=1)[:, v_held.shape[1]:]
    return xh, vh


def _held_commands(P, D, loop: DigitalPD, reading: Reading, x0, Xh, U, bias, signs):
    """The commands of the held instants (readings Xh (B, n)) into U[:, :n].

    The estimator starts from the reading before the record, Q(x₀ + offset), at rest. Returns
    that reading and the estimates v̂ (B, n) of the held instants.
    """
    x_pre = reading.read(x0[:, None], None)[:, 0]
    n = Xh.shape[1]
    est = loop.estimator
    ve = _estimate(est, Xh, *_histories(est, x_pre, np.zeros((P.size, 0)), Xh[:, :0]))
    if n:
        U[:, :n] = -(P[:, None] * Xh + D[:, None] * ve)
    if bias is not None and n:
        S, given = signs
        if not given:
            S[:, :n] = np.sign(ve)
        U[:, :n] += bias[:, None] * S[:, :n]
    return x_pre, ve


@dataclass(frozen=True)
class _SampledGeometry:
    """Where the release, the controller instants and the recorder samples fall."""

    Mr: int  # recorder samples per controller period
    S: int  # sub-steps per recorder interval
    h: float  # recorder interval, s
    j_rel: int  # sample index of the release
    n1: int  # first controller instant at or after the release
    r0: int  # recorder intervals from the release to instant n1
    n_last: int  # last controller instant in the record
    k_total: int  # sub-steps after the release

    def k_inst(self, n):
        """Sub-step index (from the release) of controller instant n."""
        return (n * self.Mr - self.j_rel) * self.S


def _to_first_instant(A0, m, x0, v0, up, geo: _SampledGeometry, cF, out):
    """From the release to the first controller instant n1 under the held command ``up``
    (+ force), in sub-steps; the samples on the way written. Returns the state (B, 2) at n1."""
    x_true, vel, _ = out
    S, j_rel = geo.S, geo.j_rel
    y = np.stack([x0, v0], axis=1)
    x_true[:, j_rel] = x0
    vel[:, j_rel] = v0
    if cF is not None or geo.r0 > 0:
        sub = Engine(A0[None], m, geo.h / S, 1)
        Phs, Ks = sub.Phi[0], sub.K[0]
    for kk in range(min(geo.r0 * S, geo.k_total)):
        y = y @ Phs.T + up[:, None] * Ks[:, 0]
        if cF is not None:
            y = y + Ks @ cF[kk]
        if (kk + 1) % S == 0:
            j = j_rel + (kk + 1) // S
            x_true[:, j] = y[:, 0]
            vel[:, j] = y[:, 1]
    return y


def _force_shares(A0, m, geo: _SampledGeometry, cF, L: int):
    """The external force's share of the plant state over each period n1 … n_last − 1 (L, 2),
    and inside each period at its recorder samples (L + 1, M, 2); (None, None) without one."""
    if cF is None:
        return None, None
    Mr, S = geo.Mr, geo.S
    sub = Engine(A0[None], m, geo.h / S, 1)
    Phs, Ks = sub.Phi[0], sub.K[0]
    MS = Mr * S
    idx = geo.r0 * S + np.arange((L + 1) * MS)
    cP = np.zeros((idx.size, NQ))
    ok = idx < geo.k_total
    cP[ok] = cF[idx[ok]]
    cP = cP.reshape(L + 1, MS, NQ)
    zF = np.zeros((L + 1, 2))
    part = np.zeros((L + 1, Mr, 2))
    for sl in range(MS):
        zF = zF @ Phs.T + cP[:, sl] @ Ks.T
        if (sl + 1) % S == 0 and (sl + 1) // S < Mr:
            part[:, (sl + 1) // S] = zF
    return zF[:L], part


def _record(A0, m, geo: _SampledGeometry, Y, uapp, part, out) -> None:
    """The recorder's samples from instant n1 on: the plant's states at the instants Y
    (B, 2, L + 1) and, between them, the exact maps Φ(ih), Γ(ih) of the applied command."""
    x_true, vel, _ = out
    B = Y.shape[0]
    Mr = geo.Mr
    j0 = geo.n1 * Mr
    cnt = x_true.shape[1] - j0
    if Mr == 1 and part is None:
        x_true[:, j0:] = Y[:, 0, :cnt]
        vel[:, j0:] = Y[:, 1, :cnt]
        return
    L = Y.shape[2] - 1
    X = np.zeros((Mr, 3, 3))
    X[:, :2, :2] = A0
    X[:, 1, 2] = 1.0 / m
    X = X * (np.arange(Mr) * geo.h)[:, None, None]
    E = expm_stack(X)  # Φ(ih), Γ(ih), i = 0 … M−1 (i = 0: exactly I and 0)
    ys = np.einsum("irc,bcn->bnir", E[:, :2, :2], Y)
    ys += E[None, None, :, :2, 2] * uapp[:, :, None, None]
    if part is not None:
        ys += part[None]
    ys = ys.reshape(B, (L + 1) * Mr, 2)
    x_true[:, j0:] = ys[:, :cnt, 0]
    vel[:, j0:] = ys[:, :cnt, 1]


def _sampled_linear(m, c, k, P, D, x0, v0, loop, geo: _SampledGeometry, cF, out,
                    rfull=None, reading=None, Xr=None) -> None:
    """f_c = 0: every controller instant at once (IIR filter of χ), refined once; then samples.

    With the noise in the loop (``rfull`` of :func:`_perturbation`) the commands carry rₙ and
    the readings at the instants go into ``Xr``."""
    _, _, U = out
    B = P.size
    T, d = loop.sample_time, loop.delay_samples
    a, cf = loop.filter_pole, loop.filter_gain
    Mr, n1, n_last = geo.Mr, geo.n1, geo.n_last
    A0 = np.array([[0.0, 1.0], [-k / m, -c / m]])
    # 1. from the release to the first controller instant: the held command u_{n1−1−d} (+ force)
    up = -P * x0 if rfull is None else -P * x0 + rfull[:, n1]
    y = _to_first_instant(A0, m, x0, v0, up, geo, cF, out)
    if n1 > n_last:
        return
    L = n_last - n1  # periods propagated by the closed loop
    eng = Engine(A0[None], m, T, max(L, 1))
    Phi, Gam = eng.Phi[0], eng.K[0][:, 0]
    # 2. the external force's share of the plant state, per period and inside each period
    gF, part = _force_shares(A0, m, geo, cF, L)
    # 3. x at the controller instants n1 … n_last: X(z) = [Q(z) + force terms]/χ(z)
    zp = ZOHPlant(Phi, Gam, np.zeros(2), float(Phi[0, 0] + Phi[1, 1]),
                  float(Phi[0, 0] * Phi[1, 1] - Phi[0, 1] * Phi[1, 0]), float(Gam[0]),
                  float(Phi[0, 1] * Gam[1] - Phi[1, 1] * Gam[0]))
    chi = characteristic_coefficients(zp, P, D, a, cf, d)  # (B, d + 4)
    xi, eta = y[:, 0], y[:, 1]
    g1 = Phi[0, 1] * eta - Phi[1, 1] * xi
    Qc = np.zeros((B, d + 4))
    Qc[:, 0] += xi
    Qc[:, 1] += g1 - a * xi
    Qc[:, 2] += -a * g1
    c3 = np.array([zp.b1, zp.b0 - a * zp.b1, -a * zp.b0])  # (z − a)N(z)
    if d > 0:
        Qc[:, 1 : d + 3] -= (P * x0)[:, None] * np.convolve(c3, np.ones(d))[None, :]
    Qc[:, d + 1] += D * cf * x0 * zp.b1
    Qc[:, d + 2] += D * cf * x0 * zp.b0
    inp = np.zeros((B, L + 1))
    nq = min(d + 4, L + 1)
    inp[:, :nq] = Qc[:, :nq]
    if gF is not None and L > 0:
        b1c = np.array([0.0, 1.0, -(a + Phi[1, 1]), a * Phi[1, 1]])
        b2c = np.array([0.0, 0.0, Phi[0, 1], -a * Phi[0, 1]])
        inp += (np.convolve(gF[:, 0], b1c) + np.convolve(gF[:, 1], b2c))[None, : L + 1]
    ra = rcl = None
    if rfull is not None:  # the applied r_{n1+i−d} enters through (z − a)N(z) z^{−3}, as u does
        ra = rfull[:, n1 + 1 : n1 + L + 2]
        rcl = rfull[:, n1 + d + 1 : n_last + d + 2]
        for j in range(3):
            if L - j > 0:
                inp[:, 1 + j :] += c3[j] * ra[:, : L - j]
    x = recurse(chi, inp, overwrite_x=True)  # each run with its own χ

    def commands(x):
        """Commands u_n and applied inputs u_{n−d} at n1 … n_last from the sampled x."""
        w = np.empty_like(x)
        w[:, 0] = -cf * x0
        w[:, 1:] = (a - 1.0) * cf * x[:, :-1]
        q = recurse([1.0, -a], w, overwrite_x=True) if a != 0.0 else w  # q_n = v̂_n − c_f x_n
        Ucl = -(P + D * cf)[:, None] * x - D[:, None] * q
        uapp = np.repeat((-P * x0)[:, None], L + 1, axis=1)  # held commands first
        if ra is not None:
            Ucl += rcl
            uapp += ra
        if d <= L:
            uapp[:, d:] = Ucl[:, : L + 1 - d]
        return Ucl, uapp

    def plant(uapp):
        if L == 0:  # the record ends at instant n1
            return y[:, :, None].copy()
        w = Gam[None, :, None] * uapp[:, None, :L]
        if gF is not None:
            w = w + gF.T[None]
        return eng.recur(0, y, w)  # (B, 2, L + 1)

    # 4. one step of iterative refinement through the loop's sensitivity z^d(z−a)Δ(z)/χ(z)
    _, uapp = commands(x)
    Y = plant(uapp)
    sens = np.array([1.0, -(zp.tau + a), zp.delta + a * zp.tau, -a * zp.delta])
    e = Y[:, 0] - x
    x += recurse(chi, e, b=sens)
    Ucl, uapp = commands(x)
    Y = plant(uapp)
    U[:, n1:] = Ucl
    if reading is not None:
        Xr[:, n1:] = reading.read(x, np.arange(n1, n_last + 1) * Mr)
    # 5. the recorder's samples
    _record(A0, m, geo, Y, uapp, part, out)


def _sampled_stepwise(m, c, k, P, D, x0, v0, loop, geo: _SampledGeometry, cF, out,
                      reading: Reading | None, Xr, held, u_pre) -> None:
    """f_c = 0 with a quantiser in the loop, or an estimator that is not first-order: one exact
    period at a time from the release (y_{n+1} = Φ y_n + Γ u_{n−d} + the force's share),
    vectorised over the runs; then samples. ``reading`` None: the controller reads x."""
    _, _, U = out
    B = P.size
    T, d = loop.sample_time, loop.delay_samples
    Mr, n1, n_last = geo.Mr, geo.n1, geo.n_last
    A0 = np.array([[0.0, 1.0], [-k / m, -c / m]])
    up = U[:, n1 - 1 - d] if n1 - 1 - d >= 0 else u_pre
    y = _to_first_instant(A0, m, x0, v0, up, geo, cF, out)
    if n1 > n_last:
        return
    L = n_last - n1
    eng = Engine(A0[None], m, T, 1)
    PhiT, Gam = eng.Phi[0].T.copy(), eng.K[0][:, 0]
    gF, part = _force_shares(A0, m, geo, cF, L)
    # the readings and estimates from r_b and r_a instants before n1 on (oldest first)
    b, a = loop.estimator.coefficients()
    rb, ra = b.size - 1, a.size - 1
    x_pre, v_held = held
    n_held = v_held.shape[1]  # = n1 (the held instants)
    Xh = np.repeat(x0[:, None], n_held, axis=1) if reading is None else Xr[:, :n_held]
    xh, vh = _histories(loop.estimator, x_pre, v_held, Xh)
    XP = np.empty((B, rb + L + 1))
    XP[:, :rb] = xh
    VP = np.empty((B, ra + L + 1))
    VP[:, :ra] = vh
    b_rev, a_rev = b[::-1].copy(), a[:0:-1].copy()  # b_rb … b_0 and a_ra … a_1
    # the draws at the instants, period-major (Reading.read's operations, inlined)
    e_at = None
    if reading is not None and reading.e is not None:
        e_at = np.ascontiguousarray(reading.e[:, n1 * Mr : n_last * Mr + 1 : Mr].T)
    Y = np.empty((B, 2, L + 1))
    uapp = np.empty((B, L + 1))
    progress_step(0, total=L + 1)  # the progress bar's total (a no-op unless shown)
    for i in range(L + 1):  # one iteration per controller period
        n = n1 + i
        Y[:, :, i] = y
        xr = y[:, 0]
        if reading is not None:
            xr = xr + reading.offset
            if e_at is not None:
                xr = xr + e_at[i]
            if reading.quantum > 0:
                xr = np.round(xr / reading.quantum) * reading.quantum
        XP[:, rb + i] = xr
        ve = XP[:, i : i + rb + 1] @ b_rev
        if ra:
            ve = ve - VP[:, i : i + ra] @ a_rev
        VP[:, ra + i] = ve
        U[:, n] = -(P * xr + D * ve)
        ua = U[:, n - d] if n - d >= 0 else u_pre
        uapp[:, i] = ua
        if i < L:
            y = y @ PhiT + ua[:, None] * Gam
            if gF is not None:
                y = y + gF[i]
        if i % 1024 == 1023:
            progress_step(1024)
    if Xr is not None:
        Xr[:, n1:] = XP[:, rb:]
    _record(A0, m, geo, Y, uapp, part, out)


def _sampled_friction(m, c, k, fc, P, D, x0, v0, loop, geo: _SampledGeometry, cF, out,
                      bias=None, signs=None, inloop=None) -> None:
    """f_c > 0 or a bias: stick–slip propagation in blocks of d + 1 periods, commands after
    each block (u_n = −(P x_n + D v̂_n) + b sign(v̂_n)). ``signs`` = (S, prescribed): S (B, n)
    receives sign(v̂_n), or, when prescribed, gives it (the switching pattern held fixed).
    ``inloop`` = (reading, Xr, held, u_pre): with a ``reading`` the commands read
    x̃ = reading.read(x) (into Xr); ``held`` = (the reading before the record, the estimates
    of the held instants) (:func:`_held_commands`); u_pre the commands queued before the
    record."""
    x_true, vel, U = out
    B = P.size
    d = loop.delay_samples
    if loop.estimator.first_order:
        a, cf = loop.filter_pole, loop.filter_gain
    Mr, S, j_rel, n1, n_last = geo.Mr, geo.S, geo.j_rel, geo.n1, geo.n_last
    A0 = np.array([[0.0, 1.0], [-k / m, -c / m]])
    eng = Engine(A0[None], m, geo.h / S, geo.k_total)
    fr = Friction(eng, np.zeros(B, dtype=np.int64), fc)
    y = np.stack([x0, v0], axis=1)
    xs = x0.copy()
    Xc = np.empty((B, n_last + 1))  # x at the controller instants
    state = {"done": n1 - 1, "x": x0.copy(), "ve": np.zeros(B)}
    reading, Xr, held, u_pre = inloop
    est = loop.estimator
    general = reading is not None or not est.first_order
    if general:  # the estimator's histories (oldest first) at the last held instant
        x_pre, v_held = held
        n_h = v_held.shape[1]
        Xh = Xr[:, :n_h] if reading is not None else np.repeat(x0[:, None], n_h, axis=1)
        state["xh"], state["vh"] = _histories(est, x_pre, v_held, Xh)

    def commands(upto: int) -> None:
        """u_n for the instants after the last one done, up to ``upto``."""
        lo = state["done"] + 1
        if upto < lo:
            return
        xseq = Xc[:, lo : upto + 1]
        if reading is not None:  # what the controller reads
            xseq = reading.read(xseq, np.arange(lo, upto + 1) * Mr)
            Xr[:, lo : upto + 1] = xseq
        if general:
            ve = _estimate(est, xseq, state["xh"], state["vh"])
            cnt = xseq.shape[1]
            state["xh"] = np.concatenate([state["xh"], xseq], axis=1)[:, cnt:]
            state["vh"] = np.concatenate([state["vh"], ve], axis=1)[:, cnt:]
        else:  # first-order, the exact x
            dx = np.diff(np.concatenate([state["x"][:, None], xseq], axis=1), axis=1)
            ve = recurse([1.0, -a], dx, b=[cf], zi=(a * state["ve"])[:, None])
        U[:, lo : upto + 1] = -(P[:, None] * xseq + D[:, None] * ve)
        if bias is not None:
            S, given = signs
            if not given:
                S[:, lo : upto + 1] = np.sign(ve)
            U[:, lo : upto + 1] += bias[:, None] * S[:, lo : upto + 1]
        state.update(done=upto, x=xseq[:, -1].copy(), ve=ve[:, -1].copy())

    if reading is None:
        f0 = -P * x0
    else:  # the command applied at the release (one read there when it is an instant)
        if geo.k_inst(n1) == 0 and n1 <= n_last:
            Xc[:, n1] = x0
            commands(n1)
        n_app = j_rel // Mr - d
        f0 = U[:, n_app] if n_app >= 0 else u_pre
    f0 = f0 + (cF[0, 0] if cF is not None else 0.0)
    mode = np.sign(v0).astype(np.int64)
    still = np.flatnonzero(mode == 0)
    if still.size:
        mode[still] = fr.decide(still, f0[still, None], x0[still], np.zeros(still.size))
    x_true[:, j_rel] = x0
    vel[:, j_rel] = v0

    kb = 0
    progress_step(0, total=geo.k_total)  # the progress bar's total (a no-op unless shown)
    while kb < geo.k_total:
        nb = (j_rel + kb // S) // Mr  # period of the block's first step
        if nb >= n1 and geo.k_inst(nb) == kb:
            Xc[:, nb] = y[:, 0]
            commands(nb)
        ke = min(geo.k_total, geo.k_inst(nb + d + 1))
        ks = np.arange(kb, ke)
        n_step = (j_rel + ks // S) // Mr - d  # the command each step applies
        uapp = np.where(n_step[None, :] >= 0, U[:, np.maximum(n_step, 0)], u_pre[:, None])
        cb = np.zeros((B, ke - kb, NQ))
        if cF is not None:
            cb += cF[None, kb:ke]
        cb[:, :, 0] += uapp
        Y, _, _, mode, xs = fr.block(cb, y, mode, xs)
        kk = np.arange(kb + 1, ke + 1)
        on = kk % S == 0
        j = j_rel + kk[on] // S
        x_true[:, j] = Y[:, kk[on] - kb, 0]
        vel[:, j] = Y[:, kk[on] - kb, 1]
        n_in = np.arange(nb + 1, n_last + 1)
        k_in = geo.k_inst(n_in)
        inside = (k_in > kb) & (k_in <= ke)
        Xc[:, n_in[inside]] = Y[:, k_in[inside] - kb, 0]
        y = Y[:, -1]
        progress_step(ke - kb)
        kb = ke
    if n1 == j_rel // Mr and n1 * Mr == j_rel and n1 <= n_last:
        Xc[:, n1] = x0  # release on the last instant: nothing propagated
    commands(n_last)
