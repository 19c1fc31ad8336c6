"""Gain schedules that make a plant ring stably, with the best predicted precision of m, c, k.

``design`` proposes the gains (Pᵢ, Dᵢ) of a PHO experiment (seed eq. 23) from a prior guess of
the plant — each of m, c, k a value or a range — the loop delay and the rig's limits; ``check``
evaluates given gains the same way. Both return a :class:`Design`: per-run predicted modes,
cycles, stability margins and the **Cramér–Rao standard errors** of m, c, k
(:mod:`phoid.planning.fisher`) for the planned noise level and record length.

The prior
---------
Each of m, c, k is a value or a range (lo, hi). A value is widened to ±``tolerance`` (default
10 %) for the safety checks — a schedule must not go unstable because the guess was a little
off — but the predicted uncertainty is the one at the value itself. The *nominal* plant is the
midpoint of each range; the safety checks cover the 3ᵈ grid of the (lo, mid, hi) values of the
d parameters that span a range (the corners, edge midpoints and centre of the prior box).

What a run must satisfy (``design`` only proposes such runs; ``check`` reports which fail)
---------------------------------------------------------------------------------------
*Safety*, on **every** plant of the prior grid:

* *stable and ringing:* the rightmost characteristic roots of
  f(s) = m s² + c s + k + (D s + P) e^{−sΔt} are a complex pair s = −σ + iω_d whose damping
  ratio ζ = σ/|s| is at least half the band's lower edge;
* *stability margins:* the **decay margin** is the distance σ of the rightmost root from the
  imaginary axis (1/s, reported); the **delay margin** is the extra loop delay (s) the loop
  tolerates before it loses stability, which must be at least ``delay_margin`` (default
  max(0.2 Δt, 1/f_s): a misjudged delay, or one more sample of latency in a digital loop, must
  not drive the rig unstable);
* *bandwidth:* ω_d ≤ ``max_freq`` and ≤ 0.2 of the Nyquist rate π f_s (10 samples per period);
* *limits:* |P| ≤ ``pmax``, |D| ≤ ``dmax``.

*Information*, at the nominal plant (elsewhere in the prior reported as warnings):

* ζ in the ``zeta`` band (default 0.03–0.2: lightly damped enough for many cycles above the
  noise floor, damped enough to die out within the record);
* at least ``min_cycles`` (default 5) oscillation cycles while the envelope |w|e^{−σt} is above
  the noise sd, within the record length (|w| the release amplitude of the dominant mode,
  :func:`phoid.planning.fisher.release_amplitude`);
* every other root left of ``separation``·Re s (default 2: the other modes die at least twice
  as fast, so the record is a single-mode decay after a short transient).

A prior so wide that no run meets the band while staying safe on all of it (e.g. c 20–60 with a
5 ms delay: a run that rings lightly at c = 20 is heavily damped at c = 60) falls back to safe
runs with at least 3 cycles (``phoid.fits.MIN_CYCLES``) at the nominal plant, with a warning:
such a schedule is a first experiment whose identification narrows the prior for a second
design. With so few cycles the prediction is optimistic (bench/bench_design.py: the spread of
``identify`` at c = 60 is ≈ 1.3 × the bound).

Stability and dominance are decided exactly and cheaply by counting roots in a half-plane with
the stability-switch (D-subdivision) method of Cooke & van den Driessche (1986): for the shifted
quasi-polynomial g(u) = f(u + a) = P̃(u) + Q̃(u) e^{−uΔt} (P̃ quadratic, Q̃ linear, fixed
coefficients), the number of roots with Re u > 0 at delay 0 follows from the quadratic
P̃ + Q̃, and it changes only where a root pair crosses the imaginary axis at u = ±iω, i.e. at a
positive root ω² of F(ω²) = |P̃(iω)|² − |Q̃(iω)|² (a quadratic in ω²), at the delays where
e^{−iωτ} = −P̃(iω)/Q̃(iω); each crossing adds two roots when F′(ω²) > 0 and removes two when
F′(ω²) < 0. The count is verified against :func:`phoid.dynamics.loop.count_roots_right_of` in the
tests.
The delay margin is the first crossing delay beyond Δt of the unshifted f.

The schedule
------------
Runs are chosen by *pole placement* at the nominal plant: a target dominant root s* fixes the
gains through f(s*) = 0, which is linear in (P, D): D s* + P = −(m s*² + c s* + k) e^{s*Δt}.
Targets are taken on a grid of natural frequencies ω₀ (geometric, from the lowest that gives
``min_cycles`` within the record to the bandwidth limit) and damping ratios in the band (and
above it, for the fallback); every target is checked against the constraints above on the whole
prior grid. For each ω₀ the
lowest feasible ζ is kept (lighter damping means a slower decay and more information). The N runs
form a **sweep** along that frontier between two ends, spaced as Chebyshev–Lobatto points in ω₀²
(the abscissa of the eq. 35 stiffness line), so that they cluster towards the ends, where
information is greatest, yet spread over the whole range — distinct runs let the eq. (35) lines
be checked for straightness, which replicates at two optimal points would not. The ends are
chosen to minimise the **worst case over the prior grid** of Σⱼ log Var(θⱼ), θ = (m, c, k), of
the Cramér–Rao covariance: a unit-free criterion (it does not change when a parameter's unit or
size changes, so a mass–damper's k ≈ 0 is handled like any other parameter) that balances the
three relative precisions. Overdamped plants get negative D by the placement itself.

Model assumptions of the prediction (:mod:`phoid.planning.fisher`): white Gaussian sensor noise,
feedback
on the true position, a release from a held position x₀ = ``amplitude``, the record starting at
the release, the delay known.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phoid import _validate as v
from phoid._output import OutputFolder, png_writer
from phoid.dynamics.loop import characteristic, rightmost_roots
from phoid.errors import PhoidError
from phoid.fits import MIN_CYCLES
from phoid.methods.pho import Estimate
from phoid.planning.fisher import _safe_inverse, mode_information, release_amplitude

__all__ = [
    "Design",
    "DesignError",
    "DesignSettings",
    "PlannedRun",
    "check",
    "check_experiment",
    "count_roots_right",
    "delay_margin",
    "design",
    "read_schedule",
]

#: most runs ``design`` plans (its work and memory grow with the number of runs)
MAX_RUNS = 1000
_NYQUIST_FRACTION = 0.2  # ω_d ≤ 0.2 π f_s: at least 10 samples per period
_N_OMEGA = 96  # grid of target natural frequencies
_N_ZETA = 10  # grid of target damping ratios in the band
_N_ZETA_ABOVE = 7  # … and above it, up to _ZETA_CAP, for priors too wide for the band
_ZETA_CAP = 0.7
_UNITS = {"m": "kg", "c": "N s/m", "k": "N/m"}


class DesignError(PhoidError):
    """No schedule satisfies the request (limits, delay, prior), or a schedule cannot be read."""


# --------------------------------------------------------------------------------------------
# exact root counting for the delayed PD loop (Cooke & van den Driessche stability switches)


def _crossings(m, c, k, P, D):
    """Crossing frequencies of f = P̃(s) + Q̃(s)e^{−sτ} and the phase at which they occur.

    Returns (omega, theta, direction, valid) with shape (2, ...): for each of the two roots
    y = ω² of F(y) = m²y² + (c² − 2mk − D²)y + k² − P², the root pair ±iω lies on the axis at
    the delays τ = (θ + 2πn)/ω, n = 0, 1, …; ``direction`` is +1 when the pair crosses to the
    right as τ grows (F′(y) > 0), −1 when to the left.
    """
    A = m * m
    B = c * c - 2.0 * m * k - D * D
    C = k * k - P * P
    disc = B * B - 4.0 * A * C
    sq = np.sqrt(np.maximum(disc, 0.0))
    out = []
    for sgn in (1.0, -1.0):
        y = (-B + sgn * sq) / (2.0 * A)
        valid = (disc > 0) & (y > 0)
        w = np.sqrt(np.where(valid, y, 1.0))
        iw = 1j * w
        Pw = m * iw * iw + c * iw + k
        Qw = D * iw + P
        with np.errstate(all="ignore"):
            theta = np.mod(-np.angle(-Pw / Qw), 2.0 * np.pi)
        valid = valid & np.isfinite(theta)
        out.append((w, theta, sgn, valid))
    return out


def count_roots_right(
    a: np.ndarray | float,
    m: np.ndarray | float,
    c: np.ndarray | float,
    k: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> np.ndarray:
    """Number of roots of m s² + c s + k + (D s + P)e^{−sΔt} with Re s > a, exactly, vectorised.

    Parameters
    ----------
    a : array_like
        Abscissa, 1/s.
    m, c, k : array_like
        Plant (kg > 0, N·s/m, N/m; any sign for c, k).
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s (≥ 0).

    Returns
    -------
    ndarray of float
        The count (an integer value), or NaN where a root lies on the line Re s = a (or so close
        that the count is undecided), broadcast over the inputs.

    Notes
    -----
    With s = u + a, f(u + a) = m u² + (c + 2ma)u + (k + ca + ma²) + e^{−aΔt}[D u + (P + Da)]
    e^{−uΔt}, a quasi-polynomial of the same retarded form with fixed coefficients. At delay 0
    its right-half-plane roots are those of the quadratic m u² + (c̃ + D̃)u + (k̃ + P̃); as the
    delay grows from 0 to Δt, roots enter or leave only in pairs through u = ±iω at the
    crossings of :func:`_crossings` (Cooke & van den Driessche 1986).
    """
    a, m, c, k, P, D = np.broadcast_arrays(
        *(np.asarray(x, dtype=float) for x in (a, m, c, k, P, D)))
    with np.errstate(all="ignore"):
        return _count_right(a, m, c, k, P, D, delay)


def _count_right(a, m, c, k, P, D, delay):
    g = np.exp(-a * delay)
    c1 = c + 2.0 * m * a
    k1 = k + c * a + m * a * a
    D1 = D * g
    P1 = (P + D * a) * g
    b0 = c1 + D1
    e0 = k1 + P1
    total = np.where(e0 < 0, 1.0, np.where(b0 < 0, 2.0, 0.0))
    scale = np.abs(k1) + np.abs(P1) + np.abs(m * a * a) + 1e-300
    bad = (np.abs(e0) <= 1e-12 * scale) | ((np.abs(b0) <= 1e-12 * (np.abs(c1) + np.abs(D1)))
                                           & (e0 > 0))
    if delay > 0:
        for w, theta, sgn, valid in _crossings(m, c1, k1, P1, D1):
            wt = w * delay
            n = np.where(theta < wt, np.floor((wt - theta) / (2.0 * np.pi)) + 1.0, 0.0)
            total = total + np.where(valid, 2.0 * sgn * n, 0.0)
            # a crossing at (almost) exactly Δt: the line passes through a root
            r = np.mod(wt - theta, 2.0 * np.pi)
            bad = bad | (valid & (np.minimum(r, 2.0 * np.pi - r) <= 1e-9 * (1.0 + wt)))
    bad = bad | ~np.isfinite(g * (np.abs(c1) + np.abs(k1) + np.abs(P1) + np.abs(D1)))
    return np.where(bad, np.nan, total)


def delay_margin(
    m: np.ndarray | float,
    c: np.ndarray | float,
    k: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> np.ndarray:
    """Extra loop delay a stable loop tolerates before a root reaches the imaginary axis, s.

    Parameters
    ----------
    m, c, k, P, D : array_like
        Plant (kg, N·s/m, N/m) and gains (N/m, N·s/m).
    delay : float
        The loop's delay Δt, s.

    Returns
    -------
    ndarray
        min over the crossings (ω, θ) of f (:func:`_crossings`) of (θ + 2πn)/ω − Δt over the
        delays beyond Δt; ``inf`` when no root ever reaches the axis (F has no positive root).
        Meaningful for a loop that is stable at Δt (then the first crossing destabilises it).
    """
    m, c, k, P, D = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (m, c, k, P, D)))
    best = np.full(m.shape, np.inf)
    with np.errstate(all="ignore"):
        for w, theta, _sgn, valid in _crossings(m, c, k, P, D):
            wt = w * delay
            n = np.where(theta > wt, 0.0, np.floor((wt - theta) / (2.0 * np.pi)) + 1.0)
            tau = (theta + 2.0 * np.pi * n) / w - delay
            best = np.where(valid, np.minimum(best, tau), best)
    return best


# --------------------------------------------------------------------------------------------
# inputs


# a prior m, c or k beyond this (or, if not 0, below its inverse) makes the loop's roots and
# their squares overflow: no rig's plant, a unit mistake
_PRIOR_MAX = 1e100


def _range(name: str, value: Any, *, positive: bool) -> tuple[float, float]:
    """A prior value or range as (lo, hi); accepts a number, a (lo, hi) pair or 'lo:hi'."""
    unit = {"m": "kg", "c": "N·s/m", "k": "N/m"}[name]
    if isinstance(value, str):
        parts = value.split(":")
        if len(parts) > 2 or not all(p.strip() for p in parts):
            raise ValueError(f"`{name}` must be a number or a range lo:hi ({unit}); got {value!r}")
        value = [float(p) if _is_number(p) else p for p in parts]
        if len(value) == 1:
            value = value[0]
    if isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, str):
        vals = list(value)
        if len(vals) != 2:
            raise ValueError(f"`{name}` range must be (lo, hi); got {value!r}")
        lo, hi = (v.finite(name, x, unit) for x in vals)
    else:
        lo = hi = v.finite(name, value, unit)
    if not lo <= hi:
        raise ValueError(f"`{name}` range must have lo ≤ hi; got {lo:g}:{hi:g} {unit}")
    if hi > _PRIOR_MAX or (lo > 0 and lo < 1 / _PRIOR_MAX):
        given = f"{lo:g}" if lo == hi else f"{lo:g}:{hi:g}"
        raise ValueError(f"`{name}` = {given} {unit} is beyond the loop computations' range "
                         f"({1 / _PRIOR_MAX:g} … {_PRIOR_MAX:g}): is it in {unit}?")
    if positive and not lo > 0:
        raise ValueError(f"`{name}` must be > 0 {unit}; got {lo:g}")
    if not positive and not lo >= 0:
        raise ValueError(f"`{name}` must be ≥ 0 {unit}; got {lo:g}")
    return lo, hi


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class DesignSettings:
    """The conditions a schedule is designed or checked for (all SI).

    Attributes
    ----------
    delay : float
        Loop delay Δt, s.
    fs : float
        Sample rate, Hz.
    duration : float
        Record length after the release, s.
    noise : float
        Sensor noise standard deviation, m.
    amplitude : float
        Release position x₀ (held before the release), m.
    zeta : (float, float)
        Band of the dominant mode's damping ratio at the nominal plant.
    pmax, dmax : float
        Limits on |P| (N/m) and |D| (N·s/m); ``inf`` when none.
    max_freq : float
        Highest damped frequency, rad/s (``inf``: only the sample-rate cap).
    min_cycles : float
        Fewest cycles above the noise floor within the record.
    delay_margin : float
        Least delay margin, s.
    separation : float
        Other roots must lie left of ``separation``·Re s of the dominant one.
    tolerance : float
        Relative width given to a prior that is a single value (safety checks only).
    """

    delay: float
    fs: float = 1000.0
    duration: float = 10.0
    noise: float = 1e-5
    amplitude: float = 0.01
    zeta: tuple[float, float] = (0.03, 0.2)
    pmax: float = math.inf
    dmax: float = math.inf
    max_freq: float = math.inf
    min_cycles: float = 5.0
    delay_margin: float | None = None
    separation: float = 2.0
    tolerance: float = 0.1

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "delay", v.nonnegative("delay", self.delay, "s"))
        set_(self, "fs", v.positive("fs", self.fs, "Hz"))
        set_(self, "duration", v.positive("duration", self.duration, "s"))
        set_(self, "noise", v.positive("noise", self.noise, "m"))
        set_(self, "amplitude", v.positive("amplitude", self.amplitude, "m"))
        for name in ("pmax", "dmax", "max_freq"):
            val = getattr(self, name)
            if val is None:
                val = math.inf
            try:
                val = float(val)
            except (TypeError, ValueError):
                raise ValueError(f"`{name}` must be a number; got {val!r}") from None
            if not val > 0:  # NaN fails too
                raise ValueError(f"`{name}` must be > 0; got {val:g}")
            set_(self, name, val)
        try:
            lo, hi = (float(z) for z in self.zeta)
        except (TypeError, ValueError):
            raise ValueError(f"`zeta` must be a band (lo, hi); got {self.zeta!r}") from None
        if not 0 < lo < hi < 1:
            raise ValueError(f"`zeta` band must satisfy 0 < lo < hi < 1; got {lo:g}:{hi:g}")
        set_(self, "zeta", (lo, hi))
        set_(self, "min_cycles", v.positive("min_cycles", self.min_cycles))
        dm = self.delay_margin
        if dm is None:
            dm = max(0.2 * self.delay, 1.0 / self.fs)
        set_(self, "delay_margin", v.nonnegative("delay_margin", dm, "s"))
        sep = v.finite("separation", self.separation)
        if not sep >= 1.0:
            raise ValueError(f"`separation` must be ≥ 1; got {sep:g}")
        set_(self, "separation", sep)
        tol = v.nonnegative("tolerance", self.tolerance)
        if not tol < 1.0:
            raise ValueError(f"`tolerance` must be < 1; got {tol:g}")
        set_(self, "tolerance", tol)

    @property
    def omega_max(self) -> float:
        """Highest allowed damped frequency, rad/s: min(max_freq, 0.2 π f_s)."""
        return min(self.max_freq, _NYQUIST_FRACTION * math.pi * self.fs)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings (``None`` for an absent limit)."""

        def lim(x):
            return None if math.isinf(x) else float(x)

        return {
            "delay": self.delay, "fs": self.fs, "duration": self.duration,
            "noise": self.noise, "amplitude": self.amplitude, "zeta": list(self.zeta),
            "pmax": lim(self.pmax), "dmax": lim(self.dmax), "max_freq": lim(self.max_freq),
            "omega_max": self.omega_max, "min_cycles": self.min_cycles,
            "delay_margin": self.delay_margin, "separation": self.separation,
            "tolerance": self.tolerance,
        }


@dataclass(frozen=True)
class _Prior:
    """The prior box and its 3ᵈ check grid; row 0 of ``plants`` is the nominal plant."""

    ranges: dict[str, tuple[float, float]]
    given: dict[str, tuple[float, float]]
    plants: np.ndarray  # (G, 3): m, c, k

    @property
    def nominal(self) -> tuple[float, float, float]:
        m, c, k = self.plants[0]
        return float(m), float(c), float(k)


def _prior(m: Any, c: Any, k: Any, tolerance: float) -> _Prior:
    given = {"m": _range("m", m, positive=True), "c": _range("c", c, positive=False),
             "k": _range("k", k, positive=False)}
    ranges = {}
    for name, (lo, hi) in given.items():
        if lo == hi:
            lo, hi = lo * (1.0 - tolerance), hi * (1.0 + tolerance)
        ranges[name] = (lo, hi)
    nominal = {n: 0.5 * (sum(given[n])) for n in given}
    levels = []
    for name in ("m", "c", "k"):
        lo, hi = ranges[name]
        mid = nominal[name]
        levels.append([mid] if lo == hi else [mid, lo, hi])
    grid = [tuple(p) for p in itertools.product(*levels)]
    # nominal first (product of the first levels), duplicates removed
    seen: list[tuple[float, float, float]] = []
    for p in grid:
        if p not in seen:
            seen.append(p)
    return _Prior(ranges=ranges, given=given, plants=np.array(seen, dtype=float))


# --------------------------------------------------------------------------------------------
# evaluation of gains on the prior grid (vectorised over runs × plants)


@dataclass(frozen=True)
class _Eval:
    """Constraint evaluation of runs (axis 0) on the plants of the prior grid (axis 1)."""

    P: np.ndarray
    D: np.ndarray
    s: np.ndarray  # dominant roots (Im ≥ 0), NaN where not found
    w: np.ndarray  # release amplitudes
    stable: np.ndarray
    dominant: np.ndarray  # tracked root is the rightmost, complex, separated
    separated: np.ndarray
    zeta: np.ndarray
    cycles: np.ndarray
    dmargin: np.ndarray
    in_band: np.ndarray  # at the nominal plant (axis 1 index 0)
    ok_freq: np.ndarray
    ok_limits: np.ndarray  # per run
    ok: np.ndarray  # per run and plant: safe (stable, ringing, margins, bandwidth)

    def informative(self, st: DesignSettings) -> np.ndarray:
        """Per run: at the nominal plant, ζ in the band, enough cycles, separated modes."""
        return self.in_band & self.separated[:, 0] & (self.cycles[:, 0] >= st.min_cycles)

    def take(self, sel: np.ndarray) -> _Eval:
        """The runs ``sel`` only."""
        return _Eval(**{f: getattr(self, f)[sel] for f in self.__dataclass_fields__})


def _place(m: float, c: float, k: float, s: np.ndarray, delay: float):
    """Gains that put a root at s: D s + P = −(m s² + c s + k) e^{sΔt} (f(s) = 0, eq. 23)."""
    q = -(m * s * s + c * s + k) * np.exp(s * delay)
    D = q.imag / s.imag
    P = q.real - D * s.real
    return P, D


def _newton_masked(s, m, c, k, P, D, delay, iters):
    """Newton on f (eq. 23 characteristic) for flat arrays, iterating only unconverged entries."""
    s = s.copy()
    active = np.flatnonzero(np.isfinite(s))
    for _ in range(iters):
        if active.size == 0:
            break
        sa = s[active]
        with np.errstate(all="ignore"):
            f, df = characteristic(sa, m[active], c[active], k[active], P[active], D[active],
                                   delay)
            step = f / df
        s[active] = sa - step
        done = ~(np.abs(step) > 1e-14 * np.maximum(np.abs(sa), 1.0))  # NaN counts as done
        active = active[~done]
    return s


def _track(s0, plants, P, D, delay):
    """Continue the nominal roots s0 (per run) to every plant of the grid by Newton homotopy.

    Returns (R, G) roots with Im ≥ 0; NaN where Newton did not converge to a root.
    """
    R, G = s0.size, plants.shape[0]
    m0, c0, k0 = plants[0]
    s = np.repeat(s0[:, None], G, axis=1).ravel()
    PP = np.repeat(P[:, None], G, axis=1).ravel()
    DD = np.repeat(D[:, None], G, axis=1).ravel()
    for t in (0.25, 0.5, 0.75, 1.0):
        m = np.tile(m0 + t * (plants[:, 0] - m0), R)
        c = np.tile(c0 + t * (plants[:, 1] - c0), R)
        k = np.tile(k0 + t * (plants[:, 2] - k0), R)
        s = _newton_masked(s, m, c, k, PP, DD, delay, 8 if t < 1.0 else 40)
    with np.errstate(all="ignore"):
        f, _ = characteristic(s, m, c, k, PP, DD, delay)
        scale = m * np.abs(s) ** 2 + np.abs(c * s) + np.abs(k) + np.abs(DD * s) + np.abs(PP)
        good = np.isfinite(s) & (np.abs(f) <= 1e-9 * scale)
    s = np.where(good, s.real + 1j * np.abs(s.imag), np.nan + 0j)
    return s.reshape(R, G)


def _evaluate(P, D, s0, prior: _Prior, st: DesignSettings, *, s_grid=None) -> _Eval:
    """Check gains (P, D) with nominal dominant roots s0 on all plants of the prior grid."""
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    plants = prior.plants
    s = _track(np.asarray(s0, dtype=complex), plants, P, D, st.delay) if s_grid is None \
        else s_grid
    m, c, k = (plants[:, j][None, :] for j in range(3))
    PP, DD = P[:, None], D[:, None]
    re = s.real
    with np.errstate(invalid="ignore"):
        tiny = 1e-9 * np.abs(s) + 1e-12
        n_right = count_roots_right(np.where(np.isfinite(re), re + tiny, 0.0), m, c, k, PP, DD,
                                    st.delay)
        n_sep = count_roots_right(np.where(np.isfinite(re), st.separation * re - tiny, 0.0),
                                  m, c, k, PP, DD, st.delay)
        n_unstable = count_roots_right(np.zeros_like(re), m, c, k, PP, DD, st.delay)
    found = np.isfinite(re) & (s.imag > 0)
    rightmost = found & (n_right == 0)
    stable = (n_unstable == 0) & ~np.isnan(n_unstable)
    separated = rightmost & (n_sep == 2)
    zeta = np.where(found, -re / np.abs(s), np.nan)
    w = np.where(found, release_amplitude(np.where(found, s, -1.0 + 1j), m, c, k, PP, DD,
                                          st.delay, st.amplitude), np.nan)
    sig = -re
    with np.errstate(all="ignore"):
        t_above = np.where(np.abs(w) > st.noise,
                           np.minimum(st.duration, np.log(np.abs(w) / st.noise) / sig), 0.0)
        cycles = np.where(found & (sig > 0), s.imag * t_above / (2 * np.pi), 0.0)
    dmargin = delay_margin(m, c, k, PP, DD, st.delay)
    dmargin = np.where(stable, dmargin, 0.0)
    in_band = (zeta[:, 0] >= st.zeta[0] * (1 - 1e-9)) & (zeta[:, 0] <= st.zeta[1] * (1 + 1e-9))
    ok_freq = found & (s.imag <= st.omega_max * (1 + 1e-9))
    ok_limits = (np.abs(P) <= st.pmax * (1 + 1e-12)) & (np.abs(D) <= st.dmax * (1 + 1e-12))
    with np.errstate(invalid="ignore"):
        # safety, on every plant of the prior grid
        ok = (stable & rightmost & (zeta >= 0.5 * st.zeta[0]) & (dmargin >= st.delay_margin)
              & ok_freq)
    return _Eval(P=P, D=D, s=s, w=w, stable=stable, dominant=rightmost, separated=separated,
                 zeta=zeta, cycles=cycles, dmargin=dmargin, in_band=in_band, ok_freq=ok_freq,
                 ok_limits=ok_limits, ok=ok)


def _run_information(ev: _Eval, prior: _Prior, st: DesignSettings) -> np.ndarray:
    """Fisher information of (m, c, k) of every run at every plant: (R, G, 3, 3)."""
    R, G = ev.s.shape
    out = np.zeros((R, G, 3, 3))
    good = np.isfinite(ev.s) & (ev.s.imag > 0) & (ev.s.real < 0)
    if not np.any(good):
        return out
    ri, gi = np.nonzero(good)
    s = ev.s[ri, gi]
    info = mode_information(s, ev.w[ri, gi], fs=st.fs, duration=st.duration, noise=st.noise)
    pl = prior.plants[gi]
    Gm = _jacobian(s, pl, ev.P[ri], ev.D[ri], st.delay)
    out[ri, gi] = np.einsum("nai,nab,nbj->nij", Gm, info, Gm)
    return out


def _jacobian(s, plants, P, D, delay):
    """mode_jacobian for per-entry plants: (n, 2, 3)."""
    m, c, k = plants[:, 0], plants[:, 1], plants[:, 2]
    _, df = characteristic(s, m, c, k, P, D, delay)
    ds = -np.stack([s * s, s, np.ones_like(s)], axis=1) / df[:, None]
    return np.stack([-ds.real, ds.imag], axis=1)


def _log_var(info: np.ndarray) -> np.ndarray:
    """Σ log Var(θⱼ) of the Cramér–Rao covariance, batched over leading axes (inf if singular)."""
    d = np.sqrt(np.clip(np.einsum("...ii->...i", info), 1e-300, None))
    Z = info / (d[..., :, None] * d[..., None, :])
    det = np.linalg.det(Z)
    with np.errstate(all="ignore"):
        # diagonal of the inverse by cofactors of the 3×3 correlation-scaled matrix
        c0 = Z[..., 1, 1] * Z[..., 2, 2] - Z[..., 1, 2] * Z[..., 2, 1]
        c1 = Z[..., 0, 0] * Z[..., 2, 2] - Z[..., 0, 2] * Z[..., 2, 0]
        c2 = Z[..., 0, 0] * Z[..., 1, 1] - Z[..., 0, 1] * Z[..., 1, 0]
        val = (np.log(c0) + np.log(c1) + np.log(c2) - 3.0 * np.log(det)
               - 2.0 * np.sum(np.log(d), axis=-1))
    return np.where((det > 1e-12) & np.isfinite(val), val, np.inf)


# --------------------------------------------------------------------------------------------
# the result


@dataclass(frozen=True)
class PlannedRun:
    """One run of a schedule with its predicted behaviour.

    Mode values (``sigma``, ``omega_d``, ``zeta``, ``omega0``, ``cycles``, ``amplitude`` and the
    stderr of σ and ω_d) are at the nominal plant; ``zeta_min``/``zeta_max`` and the margins are
    the extremes over the prior grid.

    Attributes
    ----------
    P, D : float
        Gains, N/m and N·s/m.
    sigma, omega_d : float
        Dominant mode's decay rate (1/s) and damped frequency (rad/s).
    zeta, omega0 : float
        Its damping ratio and natural frequency √(σ² + ω_d²) (rad/s).
    cycles : float
        Cycles above the noise floor within the record.
    amplitude : float
        Release amplitude |w| of the dominant mode, m.
    sigma_stderr, omega_d_stderr : float
        Cramér–Rao standard deviations of σ (1/s) and ω_d (rad/s) from this run.
    margin : float
        Decay margin, 1/s: the smallest distance of the rightmost root from the imaginary axis
        over the prior (negative: unstable somewhere).
    delay_margin : float
        Smallest extra delay the loop tolerates over the prior, s (0 where unstable).
    zeta_min, zeta_max : float
        Range of the dominant mode's ζ over the prior grid.
    share : float
        The run's share of the set's information, tr(I⁻¹Iᵢ)/3 (the shares sum to 1).
    safe : bool
        Stable and ringing with the required margins on the whole prior grid.
    informative : bool
        Rings with at least ``min_cycles`` cycles on the whole prior grid and ζ in the band at
        the nominal plant.
    warnings : tuple of str
    """

    P: float
    D: float
    sigma: float
    omega_d: float
    zeta: float
    omega0: float
    cycles: float
    amplitude: float
    sigma_stderr: float
    omega_d_stderr: float
    margin: float
    delay_margin: float
    zeta_min: float
    zeta_max: float
    share: float
    safe: bool
    informative: bool
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; non-finite numbers become null (a null ``delay_margin`` means that
        no extra delay destabilises the loop, a null mode that the run does not ring)."""

        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        out: dict[str, Any] = {"P": float(self.P), "D": float(self.D)}
        for key in ("sigma", "omega_d", "zeta", "omega0", "cycles", "amplitude",
                    "sigma_stderr", "omega_d_stderr", "margin", "delay_margin", "zeta_min",
                    "zeta_max", "share"):
            out[key] = num(getattr(self, key))
        out.update(safe=self.safe, informative=self.informative, warnings=list(self.warnings))
        return out


@dataclass(frozen=True)
class Design:
    """A gain schedule with its predicted modes, margins and Cramér–Rao uncertainties.

    Attributes
    ----------
    runs : tuple of PlannedRun
    m, c, k : Estimate
        The nominal plant with the predicted (Cramér–Rao) standard error at it.
    stderr_worst : ndarray, shape (3,)
        Worst predicted standard error of m, c, k over the prior grid (kg, N·s/m, N/m).
    cov : ndarray, shape (3, 3)
        Predicted covariance of (m, c, k) at the nominal plant.
    settings : DesignSettings
    prior : dict
        ``{"m": (lo, hi), ...}`` as given, and ``checked`` (the widened box of the safety
        checks) under ``"checked_ranges"``.
    kind : {"design", "check"}
        Proposed by :func:`design` or evaluated by :func:`check`.
    warnings : tuple of str
    notes : tuple of str
        Information that is not a problem (e.g. where a checked set's plant came from).
    plants : ndarray, shape (G, 3)
        The prior grid (row 0 the nominal plant).
    roots : ndarray, shape (n, G)
        Dominant root of every run at every plant of the grid.
    """

    runs: tuple[PlannedRun, ...]
    m: Estimate
    c: Estimate
    k: Estimate
    stderr_worst: np.ndarray
    cov: np.ndarray
    settings: DesignSettings
    prior: dict[str, Any]
    kind: str
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    plants: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    roots: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), complex), repr=False)

    @property
    def P(self) -> np.ndarray:
        """Proportional gains of the runs, N/m."""
        return np.array([r.P for r in self.runs])

    @property
    def D(self) -> np.ndarray:
        """Derivative gains of the runs, N·s/m."""
        return np.array([r.D for r in self.runs])

    @property
    def stderr(self) -> np.ndarray:
        """Predicted standard errors of (m, c, k) at the nominal plant."""
        return np.array([self.m.stderr, self.c.stderr, self.k.stderr], dtype=float)

    @property
    def safe(self) -> bool:
        """Every run is safe on the whole prior grid."""
        return all(r.safe for r in self.runs)

    def summary(self) -> dict[str, Any]:
        """Plain JSON-ready dict: ``runs``, ``predicted``, ``warnings`` and the inputs."""

        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        predicted = {}
        for j, name in enumerate(("m", "c", "k")):
            e = getattr(self, name)
            predicted[name] = {"value": float(e.value), "stderr": num(e.stderr),
                               "stderr_worst": num(self.stderr_worst[j]), "unit": e.unit}
        return {
            "kind": self.kind,
            "runs": [r.to_dict() for r in self.runs],
            "predicted": predicted,
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "delay": self.settings.delay,
            "prior": {n: list(self.prior[n]) for n in ("m", "c", "k")},
            "checked_ranges": {n: list(r) for n, r in self.prior["checked_ranges"].items()},
            "settings": self.settings.to_dict(),
            "safe": self.safe,
        }

    def report(self) -> str:
        """Human-readable schedule, margins and predicted uncertainties."""
        st = self.settings
        lines = []
        title = "Designed PHO schedule" if self.kind == "design" else "Checked PHO schedule"
        pr = ", ".join(f"{n} = {_fmt_range(self.prior[n])} {_UNITS[n]}" for n in "mck")
        lines.append(f"{title} for {pr}, delay {st.delay:g} s")
        lines.append(f"record {st.duration:g} s at {st.fs:g} Hz, noise {st.noise:g} m, "
                     f"release amplitude {st.amplitude:g} m; safety checked over "
                     + ", ".join(f"{n} {_fmt_range(r)}"
                                 for n, r in self.prior["checked_ranges"].items()))
        lines.append("")
        head = (f"{'run':>3} {'P (N/m)':>11} {'D (N s/m)':>11} {'sigma':>8} {'omega_d':>8} "
                f"{'zeta':>6} {'cycles':>7} {'margin':>8} {'dmargin':>8} {'share':>6}  status")
        lines.append(head)
        for i, r in enumerate(self.runs, start=1):
            status = "ok" if r.safe and r.informative else (
                "UNSAFE" if not r.safe else "uninformative")
            lines.append(
                f"{i:>3} {r.P:>11.5g} {r.D:>11.5g} {r.sigma:>8.4g} {r.omega_d:>8.4g} "
                f"{r.zeta:>6.3f} {r.cycles:>7.1f} {r.margin:>8.3g} {r.delay_margin:>8.3g} "
                f"{r.share:>6.3f}  {status}")
        lines.append("  sigma 1/s, omega_d rad/s (nominal plant); margin: smallest decay rate "
                     "of the rightmost root (1/s) and dmargin: smallest extra delay before "
                     "instability (s), both over the prior")
        lines.append("")
        lines.append("Predicted standard errors (Cramér–Rao bound at the nominal plant; worst "
                     "over the prior in brackets):")
        for j, name in enumerate(("m", "c", "k")):
            e = getattr(self, name)
            lines.append(f"  {name} = {e.value:.6g} {e.unit}  ± {_g(e.stderr)}  "
                         f"[{_g(self.stderr_worst[j])}]")
        if self.notes:
            lines.append("")
            lines.extend(f"Note: {n}" for n in self.notes)
        if self.warnings:
            lines.append("")
            lines.append("Warnings:")
            lines.extend(f"  - {w}" for w in self.warnings)
        return "\n".join(lines)

    def plot(self, path: str | Path | None = None, *, ax=None, overwrite: bool = False):
        """Root locus of the planned runs and their predicted uncertainties.

        Left: each run's dominant root at every plant of the prior grid (the nominal plant
        marked), with the ζ band's rays; right: the predicted relative standard errors of m, c,
        k (nominal and worst over the prior).

        Parameters
        ----------
        path : str or Path, optional
            Write the figure there as PNG (atomically; its folder is created if needed; an
            existing file is replaced only with ``overwrite``, a symbolic link never).
        ax : sequence of two matplotlib Axes, optional
            Draw into these instead of a new figure.
        overwrite : bool
            Replace an existing file at ``path``.

        Returns
        -------
        matplotlib.figure.Figure
        """
        import matplotlib

        if path is not None:  # refuse a file in the way before drawing
            out = OutputFolder(Path(path).parent, overwrite=overwrite, error=DesignError)
            out.check([Path(path).name])
        if ax is None:
            matplotlib.use("Agg", force=False)
            import matplotlib.pyplot as plt
            fig, axes = plt.subplots(1, 2, figsize=(10, 4.2),
                                     gridspec_kw={"width_ratios": [1.6, 1]})
        else:
            axes = list(ax)
            fig = axes[0].figure
        a0, a1 = axes
        cmap = matplotlib.colormaps["viridis"]
        n = len(self.runs)
        for i in range(n):
            col = cmap(i / max(n - 1, 1))
            r = self.roots[i]
            r = r[np.isfinite(r)]
            a0.plot(r.real, r.imag, ".", color=col, alpha=0.5, ms=4)
            if np.isfinite(self.roots[i, 0]):
                a0.plot(self.roots[i, 0].real, self.roots[i, 0].imag, "o", color=col, ms=6,
                        mec="k", mew=0.5)
        wmax = max([abs(x.imag) for x in self.roots.ravel() if np.isfinite(x)] or [1.0])
        for j, z in enumerate(self.settings.zeta):
            a0.plot([0, -z * wmax * 1.1 / math.sqrt(1 - z * z)], [0, wmax * 1.1], "k--", lw=0.7,
                    label="zeta band" if j == 0 else None)
        a0.legend(fontsize=8, loc="lower left")
        a0.axvline(0.0, color="r", lw=0.8)
        a0.set_xlabel("Re s (1/s)")
        a0.set_ylabel("Im s (rad/s)")
        a0.set_title("dominant roots over the prior (o: nominal plant)")
        names = ["m", "c", "k"]
        vals = np.array([getattr(self, x).value for x in names], dtype=float)
        scale = np.where(vals != 0, np.abs(vals), 1.0)
        x = np.arange(3)
        a1.bar(x - 0.2, self.stderr / scale, 0.4, label="nominal")
        a1.bar(x + 0.2, self.stderr_worst / scale, 0.4, label="worst over prior")
        a1.set_xticks(x, [f"{nm} ({'rel.' if vals[j] != 0 else _UNITS[nm]})"
                          for j, nm in enumerate(names)])
        a1.set_yscale("log")
        a1.set_title("predicted standard error")
        a1.legend(fontsize=8)
        fig.tight_layout()
        if path is not None:
            out.write(Path(path).name, png_writer(fig, 110))
        return fig

    def to_toml(self, *, gzip: bool = False) -> str:
        """The schedule as a ``phoid/1`` manifest skeleton (``experiment.toml``).

        Runs name the files the rig operator will record (``run01.csv`` …); the prediction is
        kept in extra keys (``[design]`` at the top level, ``predicted_*`` in each run), which
        :func:`phoid.read_experiment` keeps and ignores.
        """
        import tomli_w

        width = max(2, len(str(len(self.runs))))
        suffix = ".csv.gz" if gzip else ".csv"
        st = self.settings
        doc: dict[str, Any] = {
            "title": f"phoid design: {len(self.runs)} runs",
            "format": "phoid/1",
            "method": "pho",
            "design": {
                "tool": "phoid design",
                "prior": {n: (self.prior[n][0] if self.prior[n][0] == self.prior[n][1]
                              else list(self.prior[n])) for n in ("m", "c", "k")},
                "fs": st.fs, "duration": st.duration, "noise": st.noise,
                "amplitude": st.amplitude,
                "predicted_stderr": {n: float(getattr(self, n).stderr)
                                     for n in ("m", "c", "k")
                                     if math.isfinite(getattr(self, n).stderr)},
            },
            "loop": {"delay": st.delay},
        }
        parts = [tomli_w.dumps(doc)]
        for i, r in enumerate(self.runs, start=1):
            table = {"file": f"run{i:0{width}d}{suffix}", "P": float(r.P), "D": float(r.D)}
            for key in ("sigma", "omega_d", "zeta"):
                val = getattr(r, key)
                if math.isfinite(val):
                    table[f"predicted_{key}"] = float(val)
            parts.append("\n[[run]]\n")
            parts.extend(tomli_w.dumps({k: v}) for k, v in table.items())
        return "".join(parts)

    def write(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Write :meth:`to_toml` to ``path`` (a folder gets ``experiment.toml``); returns it.

        The file is written atomically (a temporary file beside it, then renamed); its folder
        is created if needed. An existing file is replaced only with ``overwrite``; a symbolic
        link as the file, or a dangling one as the folder, is refused either way
        (:mod:`phoid._output`).

        Raises
        ------
        DesignError
            A file in the way or a failed write, naming the path.
        """
        out, name = schedule_target(path, overwrite=overwrite)
        return out.write(name, self.to_toml().encode("utf-8"))


def schedule_target(path: str | Path, *, overwrite: bool) -> tuple[OutputFolder, str]:
    """The folder and file name :meth:`Design.write` writes to, checked (nothing written).

    The CLI calls it before designing, so that a file in the way is refused before the work.
    """
    path = Path(path)
    if path.is_dir() or not path.suffix:
        folder, name = path, "experiment.toml"
    else:
        folder, name = path.parent, path.name
    out = OutputFolder(folder, overwrite=overwrite, error=DesignError)
    out.check([name])
    return out, name


def _fmt_range(r) -> str:
    lo, hi = r
    return f"{lo:g}" if lo == hi else f"{lo:g}:{hi:g}"


def _g(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else "undetermined"


# --------------------------------------------------------------------------------------------
# building the result from gains


def _result(P, D, prior: _Prior, st: DesignSettings, kind: str,
            extra_warnings: Sequence[str] = ()) -> Design:
    """Evaluate gains exactly on the prior grid and assemble the :class:`Design`."""
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    m0, c0, k0 = prior.nominal
    s0 = np.array([_nominal_root(m0, c0, k0, float(p), float(d), st.delay)
                   for p, d in zip(P, D, strict=True)])
    ev = _evaluate(P, D, s0, prior, st)
    # where tracking failed or another root is further right, take the certified rightmost
    s = ev.s.copy()
    redo = ~(ev.dominant)
    if np.any(redo):
        for i, g in zip(*np.nonzero(redo), strict=True):
            m, c, k = prior.plants[g]
            try:
                r = rightmost_roots(float(m), float(c), float(k), float(P[i]), float(D[i]),
                                     st.delay, count=2)[0]
            except RuntimeError:  # pathological loop: leave the root unknown (unsafe)
                continue
            s[i, g] = complex(r.real, abs(r.imag))
        ev = _evaluate(P, D, s0, prior, st, s_grid=s)
    info = _run_information(ev, prior, st)
    total = info.sum(axis=0)  # (G, 3, 3)
    cov0 = _safe_inverse(total[0])
    worst = np.array([max(_safe_inverse(t)[j, j] for t in total) for j in range(3)])
    # per-run information share at the nominal plant
    with np.errstate(all="ignore"):
        share = np.einsum("ij,nji->n", cov0, info[:, 0]) / 3.0 if np.all(
            np.isfinite(cov0)) else np.full(P.size, np.nan)
    runs: list[PlannedRun] = []
    warnings: list[str] = list(extra_warnings)
    found: dict[str, list[tuple[int, float]]] = {}  # warning kind -> [(run, value)]
    zlo, zhi = st.zeta
    G = prior.plants.shape[0]
    for i in range(P.size):
        si = ev.s[i, 0]
        rw: list[tuple[str, float, str]] = []
        sig_i, wd_i = -si.real, si.imag
        rings = bool(np.isfinite(si) and wd_i > 0)
        if rings:
            Ii = mode_information(si, ev.w[i, 0], fs=st.fs, duration=st.duration,
                                  noise=st.noise)[0]
            mc = np.linalg.inv(Ii)
            sse, wse = math.sqrt(mc[0, 0]), math.sqrt(mc[1, 1])
        else:
            sse = wse = math.inf
        margin_all = -np.where(np.isfinite(ev.s[i]), ev.s[i].real, np.nan)
        margin_all = np.where(ev.stable[i], margin_all, np.minimum(margin_all, 0.0))
        ringing = ev.dominant[i] & np.isfinite(ev.s[i]) & (ev.s[i].imag > 0)
        if not np.all(ev.stable[i]):
            bad = int(np.sum(~ev.stable[i]))
            rw.append(("unstable", bad,
                       f"UNSTABLE for {bad} of {G} plants of the prior grid"
                       + (" (including the nominal plant)" if not ev.stable[i, 0] else "")))
        elif not np.all(ringing):
            rw.append(("noring", 0.0, "does not ring (its slowest mode is not oscillatory) "
                                      "for some plants of the prior"))
        else:
            zmin = float(np.nanmin(ev.zeta[i]))
            if zmin < 0.5 * zlo:
                rw.append(("damping", zmin, f"barely damped for some plants (zeta down to "
                                            f"{zmin:.3g} < {0.5 * zlo:g})"))
            dm = float(np.min(ev.dmargin[i]))
            if dm < st.delay_margin:
                rw.append(("dmargin", dm, f"delay margin only {dm:.3g} s "
                                          f"(< {st.delay_margin:.3g} s)"))
            if not np.all(ev.separated[i]):
                rw.append(("separation", 0.0, f"another mode decays less than "
                                              f"{st.separation:g}x faster than the ringing one "
                                              "for some plants"))
        cyc = ev.cycles[i][np.isfinite(ev.cycles[i])]
        cyc_min = float(cyc.min()) if cyc.size else 0.0
        if rings and cyc_min < st.min_cycles:
            rw.append(("cycles", cyc_min, f"only {cyc_min:.1f} cycles above the noise floor "
                                          f"for some plants (< {st.min_cycles:g})"))
        if rings and not ev.in_band[i]:
            rw.append(("band", float(ev.zeta[i, 0]), f"zeta {ev.zeta[i, 0]:.3g} outside the "
                                                     f"band {zlo:g}-{zhi:g}"))
        if not np.all(ev.ok_freq[i] | ~np.isfinite(ev.s[i])):
            rw.append(("bandwidth", 0.0, f"omega_d above the bandwidth limit "
                                         f"{st.omega_max:.4g} rad/s"))
        if not ev.ok_limits[i]:
            rw.append(("limits", 0.0, f"gains beyond the limits (|P| <= {st.pmax:g} N/m, "
                                      f"|D| <= {st.dmax:g} N s/m)"))
        safe = bool(np.all(ev.stable[i]) and np.all(ringing)
                    and np.all(ev.zeta[i] >= 0.5 * zlo)
                    and np.all(ev.dmargin[i] >= st.delay_margin) and ev.ok_limits[i])
        informative = bool(rings and ev.cycles[i, 0] >= st.min_cycles and ev.in_band[i]
                           and np.all(ev.ok_freq[i]))
        if math.isfinite(share[i]) and share[i] < 0.1 / P.size and safe and informative:
            rw.append(("share", float(share[i]),
                       f"adds little information (share {share[i]:.2g})"))
        for kind_, val, _msg in rw:
            found.setdefault(kind_, []).append((i + 1, val))
        finite_z = ev.zeta[i][np.isfinite(ev.zeta[i])]
        runs.append(PlannedRun(
            P=float(P[i]), D=float(D[i]), sigma=float(sig_i) if rings else math.nan,
            omega_d=float(wd_i) if rings else math.nan,
            zeta=float(ev.zeta[i, 0]) if rings else math.nan,
            omega0=float(abs(si)) if rings else math.nan,
            cycles=float(ev.cycles[i, 0]) if rings else 0.0,
            amplitude=float(abs(ev.w[i, 0])) if rings else math.nan,
            sigma_stderr=sse, omega_d_stderr=wse,
            margin=float(np.nanmin(margin_all)) if np.any(np.isfinite(margin_all))
            else math.nan,
            delay_margin=float(np.min(ev.dmargin[i])),
            zeta_min=float(finite_z.min()) if finite_z.size else math.nan,
            zeta_max=float(finite_z.max()) if finite_z.size else math.nan,
            share=float(share[i]), safe=safe, informative=informative,
            warnings=tuple(msg for _k, _v, msg in rw),
        ))
    warnings.extend(_grouped(found, st, P.size))
    if not np.all(np.isfinite(np.diag(cov0))):
        warnings.append("the runs cannot determine m, c and k (fewer than two distinct ringing "
                        "runs): predicted stderr undetermined")
    se = np.sqrt(np.clip(np.diag(cov0), 0.0, None))
    worst_se = np.sqrt(np.clip(worst, 0.0, None))
    prior_info = dict(prior.given)
    prior_info["checked_ranges"] = dict(prior.ranges)
    return Design(
        runs=tuple(runs),
        m=Estimate(m0, float(se[0]), "kg"), c=Estimate(c0, float(se[1]), "N s/m"),
        k=Estimate(k0, float(se[2]), "N/m"), stderr_worst=worst_se, cov=cov0, settings=st,
        prior=prior_info, kind=kind, warnings=tuple(warnings), plants=prior.plants.copy(),
        roots=ev.s.copy(),
    )


def _runs_text(items: list[tuple[int, float]]) -> str:
    """'run 3' or 'runs 1-4, 7' for the run numbers in ``items``."""
    nums = sorted(i for i, _ in items)
    parts, start = [], nums[0]
    for a, b in zip(nums, [*nums[1:], None], strict=True):
        if b != a + 1:
            parts.append(str(start) if start == a else f"{start}-{a}")
            start = b
    return ("run " if len(nums) == 1 else "runs ") + ", ".join(parts)


def _grouped(found: dict[str, list[tuple[int, float]]], st: DesignSettings, n: int) -> list[str]:
    """One warning per kind of problem, naming the runs and the worst value."""
    out = []
    for kind, items in found.items():
        runs = _runs_text(items)
        vals = [v for _, v in items]
        if kind == "unstable":
            out.append(f"{runs}: UNSTABLE for some plants of the prior (do not use them)")
        elif kind == "noring":
            out.append(f"{runs}: do not ring for some plants of the prior")
        elif kind == "damping":
            out.append(f"{runs}: barely damped for some plants of the prior (zeta down to "
                       f"{min(vals):.3g})")
        elif kind == "dmargin":
            out.append(f"{runs}: delay margin down to {min(vals):.3g} s "
                       f"(< {st.delay_margin:.3g} s)")
        elif kind == "separation":
            out.append(f"{runs}: another loop mode decays less than {st.separation:g}x faster "
                       "than the ringing one for some plants")
        elif kind == "cycles":
            out.append(f"{runs}: as few as {min(vals):.1f} cycles above the noise floor for "
                       f"some plants of the prior (< {st.min_cycles:g})")
        elif kind == "band":
            out.append(f"{runs}: zeta at the nominal plant outside the band "
                       f"{st.zeta[0]:g}-{st.zeta[1]:g} ({min(vals):.3g} to {max(vals):.3g})")
        elif kind == "bandwidth":
            out.append(f"{runs}: omega_d above the bandwidth limit {st.omega_max:.4g} rad/s")
        elif kind == "limits":
            out.append(f"{runs}: gains beyond the limits |P| <= {st.pmax:g} N/m, "
                       f"|D| <= {st.dmax:g} N s/m")
        elif kind == "share":
            out.append(f"{runs}: add little information (share below {0.1 / n:.2g} each)")
    return out


def _nominal_root(m, c, k, P, D, delay) -> complex:
    """Certified rightmost root (Im ≥ 0) of one run at the nominal plant."""
    r = rightmost_roots(m, c, k, P, D, delay, count=2)[0]
    return complex(r.real, abs(r.imag))


# --------------------------------------------------------------------------------------------
# design


def _roots_in_range(func):
    """:func:`design` and :func:`check` with the loop-root computation's failure (a prior so far
    from the gains' scale that the roots cannot be certified: a unit mistake) as a DesignError
    that says so, instead of a RuntimeError."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except RuntimeError as exc:
            raise DesignError(
                f"the loop's roots cannot be computed for this prior plant and these gains "
                f"({exc}): a plant this far from the gains' scale is usually in other units "
                "(m in kg, c in N s/m, k in N/m; P in N/m, D in N s/m)") from None

    return wrapper


@_roots_in_range
def design(
    m: Any,
    c: Any,
    k: Any,
    *,
    delay: float,
    runs: int = 10,
    pmax: float | None = None,
    dmax: float | None = None,
    max_freq: float | None = None,
    fs: float = 1000.0,
    duration: float = 10.0,
    noise: float = 1e-5,
    amplitude: float = 0.01,
    zeta: tuple[float, float] = (0.03, 0.2),
    min_cycles: float = 5.0,
    delay_margin: float | None = None,
    separation: float = 2.0,
    tolerance: float = 0.1,
) -> Design:
    """Propose the gains of a PHO experiment for a plant known roughly (see the module doc).

    Parameters
    ----------
    m, c, k : float, (lo, hi) or "lo:hi"
        Prior guess of the mass (kg, > 0), damping (N·s/m, ≥ 0) and stiffness (N/m, ≥ 0); a
        range makes the schedule safe for every plant in it.
    delay : float
        Loop delay Δt, s.
    runs : int, default 10
        Number of runs N (2 ≤ N ≤ :data:`MAX_RUNS` = 1000: the work and memory grow with N, and
        1000 runs take about 35 s and 0.2 GB).
    pmax, dmax : float, optional
        Limits on |P| (N/m) and |D| (N·s/m).
    max_freq : float, optional
        Highest damped frequency of a run, rad/s (the bandwidth of the rig); the cap 0.2 π f_s
        (10 samples per period) applies in any case.
    fs : float, default 1000
        Sample rate, Hz.
    duration : float, default 10
        Record length after the release, s.
    noise : float, default 1e-5
        Sensor noise standard deviation, m.
    amplitude : float, default 0.01
        Release position x₀, m.
    zeta : (float, float), default (0.03, 0.2)
        Band of the dominant mode's damping ratio at the nominal plant.
    min_cycles : float, default 5
        Fewest cycles above the noise floor within the record, on the whole prior.
    delay_margin : float, optional
        Least delay margin (s); default max(0.2 Δt, 1/f_s).
    separation : float, default 2
        Other roots must decay at least this many times faster than the dominant one.
    tolerance : float, default 0.1
        Relative width of the safety checks around a prior given as a single value.

    Returns
    -------
    Design
        The schedule; ``.summary()`` (JSON), ``.report()`` (text), ``.plot()``, ``.write()``.

    Raises
    ------
    ValueError
        For a bad parameter (named in the message).
    DesignError
        When no gains within the limits make the loop ring stably with the required margins
        on the whole prior (e.g. a delay too long for the bandwidth, limits too tight).

    Examples
    --------
    >>> d = design(0.5, 40.0, 20.0, delay=0.005, runs=6)
    >>> d.safe, bool(d.D[0] < 0)  # overdamped: its slowest run rings by removing damping
    (True, True)
    """
    nruns = _count("runs", runs)
    st = DesignSettings(delay=delay, fs=fs, duration=duration, noise=noise,
                        amplitude=amplitude, zeta=zeta, pmax=pmax, dmax=dmax,
                        max_freq=max_freq, min_cycles=min_cycles, delay_margin=delay_margin,
                        separation=separation, tolerance=tolerance)
    prior = _prior(m, c, k, st.tolerance)
    m0, c0, k0 = prior.nominal
    zlo, zhi = st.zeta
    # target grid: natural frequency of the dominant mode at the nominal plant × damping
    w_lo = 2.0 * math.pi * st.min_cycles / st.duration
    w_hi = st.omega_max / math.sqrt(1.0 - zlo * zlo)
    if not w_hi > w_lo * 1.001:
        raise DesignError(
            f"no room for ringing runs: {st.min_cycles:g} cycles in {st.duration:g} s need "
            f"omega_d ≥ {w_lo:.4g} rad/s, but the bandwidth limit is {st.omega_max:.4g} rad/s "
            "(raise --max-freq or --fs, or record longer)"
        )
    W = np.geomspace(w_lo, w_hi, _N_OMEGA)
    Zs = np.unique(np.concatenate([np.geomspace(zlo, zhi, _N_ZETA),
                                   np.geomspace(zhi, max(_ZETA_CAP, zhi), _N_ZETA_ABOVE)]))
    nz = Zs.size
    WW, ZZ = np.meshgrid(W, Zs, indexing="ij")  # (n_w, n_z)
    S = (-ZZ * WW + 1j * WW * np.sqrt(1.0 - ZZ * ZZ)).ravel()
    P, D = _place(m0, c0, k0, S, st.delay)
    ok_lim = (np.abs(P) <= st.pmax) & (np.abs(D) <= st.dmax)
    idx = np.flatnonzero(ok_lim)
    if idx.size == 0:
        raise DesignError(_why_infeasible(st, prior, ok_lim, None, w_lo))
    ev = _evaluate(P[idx], D[idx], S[idx], prior, st)
    safe = np.all(ev.ok, axis=1)
    tier1 = safe & ev.informative(st)
    warnings: list[str] = []
    if np.any(tier1):
        usable = tier1
    else:
        # the band is given up, but each run must still ring for a few cycles at the nominal
        # plant (phoid's decay fit flags fewer than decay.MIN_CYCLES)
        usable = safe & ev.separated[:, 0] & (ev.cycles[:, 0] >= min(st.min_cycles,
                                                                      MIN_CYCLES))
        if not np.any(usable):
            raise DesignError(_why_infeasible(st, prior, ok_lim, ev, w_lo))
        warnings.append(
            "no gains give the nominal plant a mode in the zeta band with "
            f"{st.min_cycles:g} cycles while staying stable with margin over the whole prior: "
            "the runs are more damped than asked (see each run's zeta and cycles) and, with "
            "so few cycles, the predicted stderr is optimistic; narrow the prior (identify "
            "with this schedule, then design again)"
        )
    feasible = np.zeros(S.size, dtype=bool)
    feasible[idx] = usable
    feasible = feasible.reshape(W.size, nz)
    # frontier: lowest feasible ζ at each ω₀
    has = np.any(feasible, axis=1)
    zi = np.argmax(feasible, axis=1)
    cols = np.flatnonzero(has)
    pos = np.full(S.size, -1)
    pos[idx] = np.arange(idx.size)
    ev_front = ev.take(pos[cols * nz + zi[cols]])
    info = _run_information(ev_front, prior, st)  # (F, G, 3, 3)
    # contiguous stretches of the frontier (feasible ω₀ in a row)
    seg = np.concatenate([[0], np.cumsum(np.diff(cols) != 1)])
    ends = _best_sweep(W[cols], seg, info, nruns)
    if ends is None:
        raise DesignError(
            "no spread of feasible runs can determine m, c and k: the gains that ring stably "
            "within the limits all give nearly the same mode (widen --pmax/--dmax or "
            "--max-freq, or narrow the prior)"
        )
    a, b = ends
    u = _nodes(nruns)
    w2 = W[cols][a] ** 2 + u * (W[cols][b] ** 2 - W[cols][a] ** 2)
    wr = np.sqrt(w2)
    # each run: the larger frontier ζ of its two neighbouring grid points (conservative)
    fz = Zs[zi[cols]]
    j = np.clip(np.searchsorted(W[cols], wr) - 1, a, max(b - 1, a))
    zr = np.maximum(fz[j], fz[np.minimum(j + 1, b)])
    sr = -zr * wr + 1j * wr * np.sqrt(1.0 - zr * zr)
    Pr, Dr = _place(m0, c0, k0, sr, st.delay)
    evr = _evaluate(Pr, Dr, sr, prior, st)
    good = np.all(evr.ok, axis=1) & evr.ok_limits & (
        evr.informative(st) if np.any(tier1)
        else evr.separated[:, 0] & (evr.cycles[:, 0] >= min(st.min_cycles, MIN_CYCLES)))
    if not np.all(good):
        # snap runs that fall between grid points onto the nearest feasible grid point
        near = np.array([a + int(np.argmin(np.abs(np.log(W[cols][a:b + 1] / x)))) for x in wr])
        Pr = np.where(good, Pr, ev_front.P[near])
        Dr = np.where(good, Dr, ev_front.D[near])
    return _result(Pr, Dr, prior, st, "design", warnings)


def _count(name: str, value: Any, most: int = MAX_RUNS) -> int:
    try:
        n = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"`{name}` must be an integer from 2 to {most}; got {value!r}") \
            from None
    if n != value or not 2 <= n <= most:
        raise ValueError(f"`{name}` must be an integer from 2 to {most}; got {value!r}")
    return n


def _nodes(n: int) -> np.ndarray:
    """Chebyshev–Lobatto fractions in [0, 1], denser towards both ends."""
    return 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / (n - 1))


def _best_sweep(w: np.ndarray, seg: np.ndarray, info: np.ndarray, n: int):
    """Ends (a, b) of the frontier sweep minimising the worst-case Σ log Var over the prior.

    ``info`` holds each frontier point's information at every plant, (F, G, 3, 3); a sweep
    between frontier points a < b (same contiguous segment) has its runs at the Chebyshev–Lobatto
    fractions of ω₀², each run's information interpolated linearly (in log ω₀) between its
    neighbouring grid points.
    """
    F = w.size
    ia, ib = np.triu_indices(F, k=1)
    keep = seg[ia] == seg[ib]
    ia, ib = ia[keep], ib[keep]
    if ia.size == 0:
        return None
    u = _nodes(n)
    lw = np.log(w)
    best, best_val = None, np.inf
    for start in range(0, ia.size, 4096):
        a, b = ia[start:start + 4096], ib[start:start + 4096]
        total = np.zeros((a.size, *info.shape[1:]))
        for ur in u:
            x = np.log(np.sqrt(w[a] ** 2 + ur * (w[b] ** 2 - w[a] ** 2)))
            j = np.clip(np.searchsorted(lw, x) - 1, 0, F - 2)
            j = np.maximum(j, a)
            j = np.minimum(j, np.maximum(b - 1, a))
            t = np.clip((x - lw[j]) / (lw[j + 1] - lw[j]), 0.0, 1.0)[:, None, None, None]
            total += (1.0 - t) * info[j] + t * info[j + 1]
        val = np.max(_log_var(total), axis=1)
        i = int(np.argmin(val))
        if val[i] < best_val:
            best_val, best = val[i], (int(a[i]), int(b[i]))
    if not np.isfinite(best_val):
        return None
    return best


def _why_infeasible(st: DesignSettings, prior: _Prior, ok_lim: np.ndarray, ev: _Eval | None,
                    w_lo: float) -> str:
    """One line saying which requirement rules out every candidate run (checked in order)."""
    checked = ", ".join(f"{n} {_fmt_range(r)}" for n, r in prior.ranges.items())
    band = f"zeta {st.zeta[0]:g}-{st.zeta[1]:g}"
    if ev is None or not np.any(ok_lim):
        return (f"every gain pair that makes the loop ring with {band} exceeds the limits "
                f"|P| <= {st.pmax:g} N/m, |D| <= {st.dmax:g} N s/m: raise --pmax/--dmax")
    span = (f"omega_d {w_lo:.4g}-{st.omega_max:.4g} rad/s ({st.min_cycles:g} cycles in "
            f"{st.duration:g} s up to the bandwidth limit)")
    keep = ev.stable[:, 0] & ev.dominant[:, 0]
    if not np.any(keep):
        return (f"a delay of {st.delay:g} s makes every useful gain unstable: no gains within "
                f"the limits give a stable loop whose slowest mode rings with {band} and "
                f"{span}; shorten the delay, or record longer for slower runs")
    keep = np.all(ev.stable & ev.dominant, axis=1)
    if not np.any(keep):
        return (f"no gains keep the loop stable and ringing for every plant in the prior "
                f"({checked}) with delay {st.delay:g} s: narrow the prior")
    keep &= np.all(ev.zeta >= 0.5 * st.zeta[0], axis=1)
    if not np.any(keep):
        return (f"no gains keep the loop damped (zeta >= {0.5 * st.zeta[0]:g}) for every plant "
                f"in the prior ({checked}): narrow the prior")
    keep &= np.all(ev.dmargin >= st.delay_margin, axis=1)
    if not np.any(keep):
        return (f"no gains leave a delay margin of {st.delay_margin:.3g} s for every plant in "
                f"the prior ({checked}) with delay {st.delay:g} s: narrow the prior, or lower "
                "--delay-margin only if the delay is well known")
    keep &= np.all(ev.ok_freq, axis=1)
    if not np.any(keep):
        return (f"every safe run rings above the bandwidth limit {st.omega_max:.4g} rad/s for "
                "some plant of the prior: raise --max-freq or --fs")
    keep &= ev.separated[:, 0]
    if not np.any(keep):
        return (f"in every safe run another loop mode decays less than {st.separation:g}x "
                "faster than the ringing one, so the decay is not a single mode")
    return (f"no safe run gives {min(st.min_cycles, MIN_CYCLES):g} cycles above the noise "
            f"floor ({st.noise:g} m) in {st.duration:g} s from a release at {st.amplitude:g} "
            "m: record longer, raise --amplitude or lower the noise")


# --------------------------------------------------------------------------------------------
# check


@_roots_in_range
def check(
    P: Sequence[float] | np.ndarray,
    D: Sequence[float] | np.ndarray,
    m: Any,
    c: Any,
    k: Any,
    *,
    delay: float,
    fs: float = 1000.0,
    duration: float = 10.0,
    noise: float = 1e-5,
    amplitude: float = 0.01,
    zeta: tuple[float, float] = (0.03, 0.2),
    pmax: float | None = None,
    dmax: float | None = None,
    max_freq: float | None = None,
    min_cycles: float = 5.0,
    delay_margin: float | None = None,
    separation: float = 2.0,
    tolerance: float = 0.1,
) -> Design:
    """Evaluate given gains like :func:`design` does: which runs are unsafe or uninformative.

    Parameters are those of :func:`design`, with the gains ``P`` (N/m) and ``D`` (N·s/m) of the
    runs instead of ``runs``.

    Returns
    -------
    Design
        ``kind = "check"``; each run's ``safe``/``informative`` flags and warnings say what is
        wrong, and the predicted standard errors are those of the given set.
    """
    st = DesignSettings(delay=delay, fs=fs, duration=duration, noise=noise,
                        amplitude=amplitude, zeta=zeta, pmax=pmax, dmax=dmax,
                        max_freq=max_freq, min_cycles=min_cycles, delay_margin=delay_margin,
                        separation=separation, tolerance=tolerance)
    P = v.finite_array("P", P, ndim=1)
    D = v.finite_array("D", D, ndim=1)
    if P.size != D.size or P.size == 0:
        raise ValueError(f"`P` and `D` must have one entry per run; got {P.size} and {D.size}")
    prior = _prior(m, c, k, st.tolerance)
    return _result(P, D, prior, st, "check")


def check_experiment(
    experiment: Any,
    m: Any = None,
    c: Any = None,
    k: Any = None,
    **settings: Any,
) -> Design:
    """:func:`check` the gains of an experiment set (a read set or a designed skeleton).

    Parameters
    ----------
    experiment : phoid.io.experiment.ExperimentSet, str or Path
        A set read by :func:`phoid.read_experiment`, or the path of a set or skeleton manifest
        (data files not needed).
    m, c, k : prior, optional
        The plant to check against; when omitted, the set's data are identified
        (:func:`phoid.identify`) and the estimate is used.
    **settings
        Further keywords of :func:`check`. ``delay`` defaults to the set's; for a set with data,
        ``fs``, ``duration`` (from the release), ``amplitude`` and ``noise`` default to what
        the records show (median over the runs) — the skeleton's ``[design]`` values for a
        skeleton.

    Returns
    -------
    Design
    """
    from phoid.io.experiment import ExperimentSet, read_experiment

    exp = experiment
    sched = None
    read_error = None
    if not isinstance(exp, ExperimentSet):
        try:
            exp = read_experiment(experiment)
        except (PhoidError, OSError) as exc:
            try:
                sched = read_schedule(experiment)
            except DesignError:
                raise exc from None
            exp, read_error = None, " ".join(str(exc).split())
    if exp is not None:
        if exp.method != "pho":
            raise DesignError(f"{exp.path}: method is {exp.method!r}; only pho sets have gains "
                              "to check")
        P = np.array([r.P for r in exp.runs], dtype=float)
        D = np.array([r.D for r in exp.runs], dtype=float)
        delay = exp.delay
        from_data = _record_settings(exp)
    else:
        P, D, delay = sched["P"], sched["D"], sched["delay"]
        from_data = {key: sched[key] for key in ("fs", "duration", "noise", "amplitude")
                     if sched.get(key) is not None}
    if settings.get("delay") is None:
        settings.pop("delay", None)
        if delay is None:
            raise DesignError("the set has no [loop] delay: give --delay")
        settings["delay"] = delay
    notes: list[str] = []
    carried: list[str] = []  # warnings of the identification the check relies on
    if read_error is not None:
        notes.append(f"the set's data were not used ({read_error}): gains checked against the "
                     "prior only")
    if m is None or c is None or k is None:
        if exp is None:
            raise DesignError(f"cannot identify the set ({read_error}); to check its gains "
                              "alone give the prior plant --m, --c and --k")
        from phoid.methods.identification import identify

        ident = identify(exp, delay=settings["delay"])
        m = ident.m.value if m is None else m
        c = ident.c.value if c is None else c
        k = ident.k.value if k is None else k
        notes.append(
            "plant from the set's own identification: "
            + ", ".join(f"{n} = {e.value:.6g} ± {e.stderr:.3g} {e.unit}"
                        for n, e in (("m", ident.m), ("c", ident.c), ("k", ident.k))))
        if "noise" not in from_data:
            sds = [r.fit.noise_sd for r in ident.runs if r.fit is not None
                   and math.isfinite(r.fit.noise_sd)]
            if sds:
                from_data["noise"] = float(np.median(sds))
        # the check relies on this estimate: what the identification warned of stays with it
        carried.extend(f"identification of the set: {w}" for w in ident.warnings)
        for name, val in (("c", c), ("k", k)):
            if not isinstance(val, (str, Sequence)) and float(val) < 0.0:
                carried.append(f"the set's identification gives {name} = {float(val):.4g} < 0: "
                               f"the check uses {name} = 0; give the prior --{name}")
        c = max(float(c), 0.0) if not isinstance(c, (str, Sequence)) else c
        k = max(float(k), 0.0) if not isinstance(k, (str, Sequence)) else k
    for key, val in from_data.items():
        if settings.get(key) is None:
            settings[key] = val
    settings = {key: val for key, val in settings.items() if val is not None}
    d = check(P, D, m, c, k, **settings)
    negative = [name for name, g in (("P", P), ("D", D)) if g.size and np.all(g < 0)]
    if negative:
        from phoid.methods.diagnose import SIGN_CONVENTION

        what = " and ".join(negative)
        carried.insert(0, f"every run's {what} is negative: {SIGN_CONVENTION}; if the rig's "
                          f"controller uses the other sign, give {what} with phoid's")
    if notes:
        d = dataclasses.replace(d, notes=tuple(notes))
    if carried:
        d = dataclasses.replace(d, warnings=tuple(carried) + tuple(d.warnings))
    return d


def _record_settings(exp) -> dict[str, float]:
    """Sample rate, record length after the release and release amplitude seen in a set."""
    from phoid.fits import detect_release

    fs, dur, amp = [], [], []
    for r in exp.runs:
        t, x = np.asarray(r.t), np.asarray(r.x)
        dt = np.diff(t)
        fs.append(1.0 / float(np.median(dt)))
        try:
            t0 = detect_release(t, x)
        except (ValueError, RuntimeError):
            t0 = float(t[0])
        dur.append(float(t[-1] - t0))
        j = int(np.searchsorted(t, t0))
        tail = x[-max(10, x.size // 10):]
        amp.append(abs(float(x[min(j, x.size - 1)]) - float(np.median(tail))))
    out = {"fs": float(np.median(fs)), "duration": float(np.median(dur))}
    a = float(np.median(amp))
    if a > 0:
        out["amplitude"] = a
    return out


# --------------------------------------------------------------------------------------------
# reading a schedule (for `phoid simulate --schedule` and checks of skeletons)


def read_schedule(path: str | Path) -> dict[str, Any]:
    """Gains, delay and recording settings of a designed ``experiment.toml`` (no data needed).

    Parameters
    ----------
    path : str or Path
        The skeleton manifest or its folder.

    Returns
    -------
    dict
        ``P``, ``D`` (ndarrays), ``delay`` (s or None), ``files`` (names of the runs) and, from
        the ``[design]`` table when present, ``fs``, ``duration``, ``noise``, ``amplitude``.

    Raises
    ------
    DesignError
        One line naming the file, run and key for anything missing or malformed.
    """
    from phoid.errors import ExperimentError
    from phoid.io.experiment import read_manifest  # regular files only, size and nesting limited

    path = Path(path)
    if path.is_dir():
        path = path / "experiment.toml"
    try:
        doc = read_manifest(str(path), path)
    except ExperimentError as exc:
        raise DesignError(str(exc)) from None
    runs = doc.get("run")
    if not isinstance(runs, list) or not runs:
        raise DesignError(f"{path}: no [[run]] tables with gains P and D")
    P, D, files = [], [], []
    for i, r in enumerate(runs, start=1):
        if not isinstance(r, Mapping):
            raise DesignError(f"{path}: run {i}: not a table")
        for key, out in (("P", P), ("D", D)):
            val = r.get(key)
            if isinstance(val, bool) or not isinstance(val, (int, float)) \
                    or not math.isfinite(val):
                raise DesignError(f"{path}: run {i}: key '{key}' must be a finite number; "
                                  f"got {val!r}")
            out.append(float(val))
        files.append(str(r.get("file", f"run{i:02d}.csv")))
    loop = doc.get("loop", {})
    delay = loop.get("delay") if isinstance(loop, Mapping) else None
    if delay is not None and (isinstance(delay, bool) or not isinstance(delay, (int, float))
                              or not math.isfinite(delay) or delay < 0):
        raise DesignError(f"{path}: [loop] delay must be a finite number ≥ 0 s; got {delay!r}")
    out: dict[str, Any] = {"P": np.array(P), "D": np.array(D),
                           "delay": None if delay is None else float(delay), "files": files}
    des = doc.get("design", {})
    if isinstance(des, Mapping):
        for key in ("fs", "duration", "noise", "amplitude"):
            val = des.get(key)
            if isinstance(val, (int, float)) and not isinstance(val, bool) \
                    and math.isfinite(val) and val > 0:
                out[key] = float(val)
    return out
