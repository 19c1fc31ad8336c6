r"""The in-loop output-error model of a digital PD loop: the applied force, the window, the
plant's response (pure functions over arrays).

With the sensor noise inside the loop (a rig's controller reads the same noisy, quantised
encoder that is recorded) the controller turns the noise into a force on the plant. Given the
record, that force is known exactly: the controller's law applied to the recorded positions at
its instants, delayed and held. The plant m x'' + c x' + k x = u is then driven by a known
input, and the record is its response plus white sensor noise (docs/design-notes/inloop.md).

The controller (:class:`phoid.dynamics.digital.DigitalPD`'s conventions)
-------------------------------------------------------------------------
Instants t_n = nT from t = 0 of the record; the recorder samples every h = T/M (M whole ≥ 1),
so recorder sample j, at t_j = q_j h with the whole clock q_j = round(t_j/h), lies in period
n(j) = ⌊q_j/M⌋ and is an instant when M divides q_j. At its instants the controller reads x̃_n
(the record there), estimates the velocity by its filter (:attr:`DigitalPD.estimator`,
Σᵢ aᵢ v̂_{n−i} = Σⱼ bⱼ x̃_{n−j}: the backward difference, its first-order low pass, the
central difference, an FIR filter) and computes u_n = −(P x̃_n + D v̂_n); sample j is driven,
until sample j + 1, by u_{n(j)−d} (zero-order hold, d whole periods).

Known from the record: with the record's first instant n₀ and the filter's taps len(b) − 1,
the numerator's part of v̂_n is known for n ≥ n_s = n₀ + taps. An FIR estimator (a = 1) then
gives u_n exactly. A recursive one (the first-order low pass: Σᵢ aᵢ v̂_{n−i} with r = len(a) − 1
> 0) carries a state from before the record: v̂_n is the filter of the known part plus a
solution of the homogeneous recursion, spanned by the responses of 1/A to unit impulses at
n_s … n_s + r − 1 (for the low pass, a^{n−n_s}). Each enters the command as −D times it,
linear in its unknown weight (:func:`applied_force` returns these patterns; each is a nuisance
column of the fit, left out where it has decayed below 1e-12 of its start by the window's
first command).

The window (:func:`window_start`): from the first sample at least ``margin`` samples after the
release whose applied command is known, to the record's end.

The plant at the recorder's rate
--------------------------------
Exact zero-order-hold discretisation at h (:func:`phoid.dynamics.digital.zoh_plant`):
z_{s} − τ z_{s−1} + δ z_{s−2} = b₁ f_{s−1} + b₀ f_{s−2} for s ≥ 2, z_s the position at the
window's sample s, f_s the force held over [t_s, t_{s+1}). The start state is given by z₀ and
z₁ (a linear reparametrisation of (x, ẋ) at the first sample: the same fit and the same
covariance of m, c, k), so the response is F (the forced part, z₀ = z₁ = 0) plus z₀·C₀ + z₁·C₁
with C₀, C₁ the free responses, one IIR filter each (:func:`recursion`, all runs at once).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.dynamics.digital import zoh_plant

__all__ = [
    "JITTER",
    "PATTERN_FLOOR",
    "Layout",
    "RunWindow",
    "applied_force",
    "drive",
    "free_columns",
    "live_patterns",
    "plant_coefficients",
    "record_layout",
    "recursion",
    "stack",
    "window_start",
]

#: largest deviation of a record's sample step from its median, relative, for the in-loop
#: model (which places the controller's instants on the recorder's samples)
JITTER = 0.01
#: a filtered estimator's start state is a nuisance only while a^{n−n₀} at the window's first
#: command is above this (below it the state has decayed out of every command)
PATTERN_FLOOR = 1e-12


@dataclass(frozen=True)
class Layout:
    """Where a record's samples fall on the controller's clock.

    Attributes
    ----------
    step : float
        The recorder's sample step h, s.
    per_period : int
        M = T/h, recorder samples per controller period.
    clock0 : int
        round(t₀/h): the sample clock of the record's first sample (t = 0 at clock 0).
    """

    step: float
    per_period: int
    clock0: int


def record_layout(t: np.ndarray, sample_time: float) -> Layout | str:
    """The record's :class:`Layout`, or why the in-loop model cannot place the controller's
    instants on it (a reason in words).

    Parameters
    ----------
    t : ndarray
        The record's times, s (float, increasing).
    sample_time : float
        The controller's period T, s.

    Returns
    -------
    Layout or str
    """
    if t.size < 2:
        return "fewer than two samples"
    dt = np.diff(t)
    h = float(np.median(dt))
    if not (h > 0 and math.isfinite(h)):
        return "its times do not increase"
    if float(np.max(np.abs(dt - h))) > JITTER * h:
        return (f"its sample step varies by more than {100 * JITTER:g} % (the controller's "
                "instants cannot be placed on its samples)")
    ratio = sample_time / h
    M = round(ratio)
    if M < 1 or abs(ratio - M) > 1e-6 * max(1.0, ratio):
        return (f"the controller's period ({sample_time:g} s) is not a whole number of its "
                f"sample steps ({h:.6g} s)")
    q0 = float(t[0]) / h
    if M > 1 and abs(q0 - round(q0)) > 0.01:
        return (f"its first time ({float(t[0]):g} s) is not on its sample grid counted from "
                "t = 0, where the controller's instants are")
    if not abs(q0) < 2.0**52:
        return "its times are too large to count samples on"
    return Layout(h, M, round(q0))


def applied_force(x: np.ndarray, layout: Layout, P: float, D: float, estimator: Any,
                  delay_samples: int) -> tuple[np.ndarray, np.ndarray | None, int]:
    """The force the controller applied at each recorded sample, from the recorded positions.

    Parameters
    ----------
    x : ndarray
        The recorded positions x̃ (what the controller read at its instants).
    layout : Layout
        :func:`record_layout` of the record.
    P, D : float
        The run's gains, N/m and N·s/m.
    estimator : phoid.dynamics.velocity.VelocityFilter
        The velocity estimator (:attr:`phoid.dynamics.digital.DigitalPD.estimator`: its
        ``coefficients()`` (b, a)).
    delay_samples : int
        d, whole controller periods.

    Returns
    -------
    force : ndarray
        The known part of the force held from each sample to the next, N (nan where the
        command is not known from the record).
    patterns : ndarray or None
        Shape (r, N): the force per unit weight of each homogeneous solution of a recursive
        estimator (module docstring); None for an FIR estimator, or D = 0.
    first : int
        The first sample whose force is known (the record's length when none is).
    """
    n_samples = x.size
    M = layout.per_period
    b, a = (np.asarray(c, dtype=float) for c in estimator.coefficients())
    b, a = b / a[0], a / a[0]
    taps, r = b.size - 1, a.size - 1
    clock = layout.clock0 + np.arange(n_samples, dtype=np.int64)
    inst = np.flatnonzero(clock % M == 0)
    force = np.full(n_samples, math.nan)
    if inst.size == 0:
        return force, None, n_samples
    n0 = int(clock[inst[0]] // M)
    xi = x[inst]
    # the numerator's part from zero history: exact for n ≥ n₀ + taps, up to the recursion's
    # homogeneous solutions (the patterns)
    vel = _lfilter(b.tolist(), a.tolist(), xi) if r > 0 else np.convolve(xi, b)[: xi.size]
    u = -(P * xi + D * vel)
    cmd = clock // M - delay_samples - n0  # index (from n₀) of the command held at each sample
    known = (cmd >= taps) & (cmd < xi.size)
    force[known] = u[cmd[known]]
    patterns = None
    if r > 0 and D != 0.0:
        imp = np.zeros((r, xi.size))
        for k in range(r):
            if taps + k < xi.size:
                imp[k, taps + k] = 1.0
        g = _lfilter([1.0], a.tolist(), imp)
        patterns = np.zeros((r, n_samples))
        patterns[:, known] = -D * g[:, cmd[known]]
    idx = np.flatnonzero(known)
    first = int(idx[0]) if idx.size else n_samples
    return force, patterns, first


def window_start(first_known: int, release: int, margin: int) -> int:
    """The window's first sample: ``margin`` samples after the release's, and not before the
    first sample whose applied force is known."""
    return max(int(first_known), int(release) + int(margin))


@dataclass(frozen=True)
class RunWindow:
    """One run's fitted window: the record and the force over it.

    Attributes
    ----------
    run : int
        The run's position in the set.
    start : int
        The window's first sample in the run's record.
    y : ndarray
        The recorded positions over the window (L samples).
    force : ndarray
        The known force held from each window sample to the next, N (L; the last unused).
    patterns : ndarray or None
        The recursive estimator's start-state force patterns over the window, shape (r, L)
        (None: none).
    step : float
        h, s.
    added_mass : float
        The run's known added mass, kg.
    """

    run: int
    start: int
    y: np.ndarray
    force: np.ndarray
    patterns: np.ndarray | None
    step: float
    added_mass: float = 0.0

    def part(self, lo: int, hi: int) -> RunWindow:
        """The window's samples lo … hi − 1 as a window of their own (its own start state)."""
        return RunWindow(self.run, self.start + lo, self.y[lo:hi], self.force[lo:hi],
                         live_patterns(None if self.patterns is None
                                       else self.patterns[:, lo:hi], 0.0),
                         self.step, self.added_mass)

    @property
    def size(self) -> int:
        """L, the window's samples."""
        return int(self.y.size)


def plant_coefficients(m: float, c: float, k: float, step: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(τ, δ, b₁, b₀) of the plant's exact ZOH recursion at the step h and their derivatives
    with respect to (m, c, k), shape (4,) and (4, 3) (:func:`phoid.dynamics.digital.zoh_plant`).
    """
    zp = zoh_plant(m, c, k, step, derivatives=True)
    coef = np.array([zp.tau, zp.delta, zp.b1, zp.b0])
    dcoef = np.stack([zp.d_tau, zp.d_delta, zp.d_b1, zp.d_b0])
    return coef, dcoef


def drive(b1: float, b0: float, f: np.ndarray) -> np.ndarray:
    """The recursion's input b₁ f_{s−1} + b₀ f_{s−2} for s ≥ 2 (0 at s = 0, 1), along the last
    axis."""
    w = np.zeros_like(f)
    w[..., 2:] = b1 * f[..., 1:-1] + b0 * f[..., :-2]
    return w


def _lfilter(b: list[float], a: list[float], x: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter`` along the last axis, imported when first used: only a digital
    set's in-loop route needs it, and the PHO path of a continuous set imports no scipy
    module (docs/design-notes/pho-path-imports.md)."""
    from scipy.signal import lfilter

    return lfilter(b, a, x, axis=-1)


def recursion(tau: float, delta: float, w: np.ndarray) -> np.ndarray:
    """z_s = τ z_{s−1} − δ z_{s−2} + w_s along the last axis (z_{−1} = z_{−2} = 0)."""
    return _lfilter([1.0], [1.0, -tau, delta], w)


def free_columns(tau: float, delta: float, length: int) -> np.ndarray:
    """The free responses C₀ (z₀ = z₁ = 1: at rest) and C₁ (z₀ = 0, z₁ = 1), shape (2, L)."""
    w = np.zeros((2, max(length, 2)))
    w[0, 0], w[0, 1] = 1.0, 1.0 - tau
    w[1, 1] = 1.0
    return recursion(tau, delta, w)[:, :length]


def live_patterns(patterns: np.ndarray | None, floor: float) -> np.ndarray | None:
    """The rows of ``patterns`` whose largest magnitude exceeds ``floor`` (None if none)."""
    if patterns is None:
        return None
    keep = np.max(np.abs(patterns), axis=1, initial=0.0) > floor
    return patterns[keep] if np.any(keep) else None


def stack(windows: Sequence[RunWindow]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray]:
    """The windows as padded arrays: y, force and the mask, each (S, L_max), and the
    patterns (S, R, L_max), R the most any window has (zeros where none, and after each
    window's end)."""
    S = len(windows)
    L = max(w.size for w in windows)
    R = max((0 if w.patterns is None else w.patterns.shape[0]) for w in windows)
    y = np.zeros((S, L))
    f = np.zeros((S, L))
    g = np.zeros((S, R, L))
    mask = np.zeros((S, L))
    for i, w in enumerate(windows):
        y[i, : w.size] = w.y
        f[i, : w.size] = w.force
        if w.patterns is not None:
            g[i, : w.patterns.shape[0], : w.size] = w.patterns
        mask[i, : w.size] = 1.0
    return y, f, g, mask
