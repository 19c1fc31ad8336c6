"""The conditions a schedule is designed or checked for, and the prior plant.

Each of m, c, k is a value or a range (lo, hi). A value is widened to ±``tolerance`` (default
10 %) for the safety checks — a schedule must not go unstable because the guess was a little
off — but the predicted uncertainty is the one at the value itself. The *nominal* plant is the
midpoint of each range; the safety checks cover the 3ᵈ grid of the (lo, mid, hi) values of the
d parameters that span a range (the corners, edge midpoints and centre of the prior box).
"""

from __future__ import annotations

import itertools
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import phoid._validate as v
from phoid.errors import PhoidError
from phoid.io.limits import MAX_LINES
from phoid.io.loop import MAX_DELAY_SAMPLES, PHO_VELOCITIES
from phoid.planning.inloop_bound import MAX_LOOP_ORDER

__all__ = ["UNITS", "DesignError", "DesignSettings", "Prior", "equivalent_delay", "fmt_range",
           "make_prior", "whole_number"]


_NYQUIST_FRACTION = 0.2  # ω_d ≤ 0.2 π f_s: at least 10 samples per period
# amplitude / noise: beyond 1e15 the noise is below the rounding of a double position
# (2.2e-16 relative), and the Fisher information overflows long before 1e300
_MAX_SNR = 1e15
# a nonzero delay below a millionth of a sample period puts the loop's roots out of the
# range where they can be certified (1e-30 s at 1 kHz failed); 0 is the loop without delay
_MIN_DELAY_SAMPLES = 1e-6
_MIN_CYCLES = 0.01  # fewer cycles: the frequency grid spans hundreds of decades
_MIN_ZETA = 1e-6  # a band from 1e-300 spreads the damping-ratio grid over 300 decades
UNITS = {"m": "kg", "c": "N s/m", "k": "N/m"}
"""Units of m, c, k in reports (ASCII)."""


class DesignError(PhoidError):
    """No schedule satisfies the request (limits, delay, prior), or a schedule cannot be read."""


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


def whole_number(name: str, value: Any, least: int = 0, most: int | None = None) -> int:
    """``value`` as an int when it is a whole number ≥ ``least`` (and ≤ ``most``); else one
    ValueError naming ``name`` (a bool, a fraction, NaN or a string is refused)."""
    bad = isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real,))
    if not bad:
        f = float(value)
        bad = not (math.isfinite(f) and f.is_integer())
    top = "" if most is None else f" and ≤ {most}"
    if bad:
        raise ValueError(f"`{name}` must be a whole number ≥ {least}{top}; got {value!r}")
    n = int(value)
    if n < least or (most is not None and n > most):
        raise ValueError(f"`{name}` must be a whole number ≥ {least}{top}; got {n}")
    return n


@dataclass(frozen=True)
class DesignSettings:
    """The conditions a schedule is designed or checked for (all SI).

    The loop is either continuous with a delay Δt (``delay``), or sampled (``sample_time``
    given): the digital PD controller of :mod:`phoid.dynamics.digital`, zero-order hold,
    ``delay_samples`` whole periods of command delay and the ``velocity`` estimator.

    Attributes
    ----------
    delay : float
        Loop delay Δt, s; for a sampled loop its command delay d·T (set from
        ``delay_samples``; giving ``delay`` with ``sample_time`` is refused).
    fs : float
        Sample rate of the record, Hz (default 1000, or 1/T for a sampled loop: a rig records
        at its loop's rate); for a sampled loop a whole multiple of 1/T.
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
        Least delay margin, s (a sampled loop: ``delay_margin_samples`` × T).
    separation : float
        Other roots must lie left of ``separation``·Re s of the dominant one.
    tolerance : float
        Relative width given to a prior that is a single value (safety checks only).
    sample_time : float or None
        The controller's period T, s (None: a continuous loop).
    delay_samples : int or None
        Command delay d of a sampled loop, whole periods (default 0).
    velocity : str or None
        A sampled loop's velocity estimator, one of :data:`phoid.io.loop.PHO_VELOCITIES`
        (the estimators a PHO set's ``[loop]`` takes): ``"backward-difference"`` (default),
        ``"central-difference"`` or ``"filtered"`` (with ``cutoff``, rad/s).
    cutoff : float or None
        The filtered velocity's cut-off, rad/s.
    noise_in_loop : bool
        Whether the controller reads the noisy recorded position (the prediction is then the
        in-loop bound); default True for a sampled loop, False for a continuous one (where
        True is refused: the in-loop bound models a digital controller).
    delay_margin_samples : int or None
        A sampled loop's least delay margin, whole samples (default max(1, ⌈0.2 d⌉): one more
        sample of latency must not drive the rig unstable).
    """

    delay: float | None = None
    fs: float | None = None
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
    sample_time: float | None = None
    delay_samples: int | None = None
    velocity: str | None = None
    cutoff: float | None = None
    noise_in_loop: bool | None = None
    delay_margin_samples: int | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        sampled = self.sample_time is not None
        if sampled:
            self._sampled_loop()
        else:
            stray = [n for n in ("delay_samples", "velocity", "cutoff", "delay_margin_samples")
                     if getattr(self, n) is not None]
            if stray:
                raise ValueError(f"`{stray[0]}` applies to a sampled loop: give its "
                                 "`sample_time` (s)")
            if self.delay is None:
                raise ValueError("give the loop delay `delay` (s), or a sampled loop's "
                                 "`sample_time` (s) and `delay_samples`")
            if self.noise_in_loop is not None and not isinstance(self.noise_in_loop,
                                                                 (bool, np.bool_)):
                raise ValueError(f"`noise_in_loop` must be True, False or None; got "
                                 f"{self.noise_in_loop!r}")
            if self.noise_in_loop:
                raise ValueError("`noise_in_loop` = True needs a sampled loop (`sample_time`): "
                                 "the in-loop bound models a digital controller reading the "
                                 "recorded position")
            set_(self, "noise_in_loop", False)
            set_(self, "delay", v.nonnegative("delay", self.delay, "s"))
            set_(self, "fs", v.positive("fs", 1000.0 if self.fs is None else self.fs, "Hz"))
        set_(self, "duration", v.positive("duration", self.duration, "s"))
        set_(self, "noise", v.positive("noise", self.noise, "m"))
        set_(self, "amplitude", v.positive("amplitude", self.amplitude, "m"))
        if sampled:  # a sample time or delay the record cannot show, named first
            self._sampled_record()
        # each option's range error names that option (a record of 1e300 s used to come out
        # as "a delay of 0.01 s makes every useful gain unstable")
        samples = self.fs * self.duration
        if not samples >= 2:
            raise ValueError(f"`duration` × `fs` = {self.duration:g} s × {self.fs:g} Hz is "
                             f"{samples:.3g} samples per run, fewer than 2: is `duration` in "
                             "s and `fs` in Hz?")
        if samples > MAX_LINES:
            raise ValueError(f"`duration` × `fs` = {self.duration:g} s × {self.fs:g} Hz is "
                             f"{samples:.3g} samples per run, more than a data file phoid "
                             f"reads holds ({MAX_LINES:,} lines, MAX_LINES): is `duration` "
                             "in s and `fs` in Hz?")
        if self.amplitude > _MAX_SNR * self.noise:
            raise ValueError(f"`noise` = {self.noise:g} m is below 1e-15 × the release "
                             f"`amplitude` {self.amplitude:g} m: positions recorded as doubles "
                             "cannot resolve it; are `noise` and `amplitude` in m?")
        if not sampled:
            if 3.0 * self.delay >= self.duration:
                # the identification fits each decay from 3 delays after the release (the
                # loop's fast transient): a longer delay leaves nothing to fit, and the loop's
                # roots for it are many and slow to certify
                raise ValueError(f"`delay` (--delay) = {self.delay:g} s is too long for the "
                                 f"record (`duration` = {self.duration:g} s): the "
                                 "identification fits each decay from 3 delays after the "
                                 "release; is the delay in seconds?")
            if 0 < self.delay * self.fs < _MIN_DELAY_SAMPLES:
                raise ValueError(f"`delay` = {self.delay:g} s is less than a millionth of a "
                                 f"sample period (`fs` = {self.fs:g} Hz), too short for the "
                                 "loop's roots to be computed: give 0 for a loop without delay")
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
        if lo < _MIN_ZETA:
            raise ValueError(f"`zeta` band must start at {_MIN_ZETA:g} or above (the design's "
                             f"grid of damping ratios spans the band); got {lo:g}:{hi:g}")
        set_(self, "zeta", (lo, hi))
        set_(self, "min_cycles", v.positive("min_cycles", self.min_cycles))
        if self.min_cycles < _MIN_CYCLES:
            raise ValueError(f"`min_cycles` must be ≥ {_MIN_CYCLES:g} (a run that rings for "
                             f"less does not ring); got {self.min_cycles:g}")
        if not sampled:
            dm = self.delay_margin
            given = dm is not None
            if dm is None:
                dm = max(0.2 * self.delay, 1.0 / self.fs)
            set_(self, "delay_margin", v.nonnegative("delay_margin", dm, "s"))
            if given and self.delay_margin > self.duration:  # the default's: the delay's message
                raise ValueError(f"`delay_margin` = {self.delay_margin:g} s is longer than the "
                                 f"record (`duration` = {self.duration:g} s): no loop that "
                                 "rings within the record tolerates that much extra delay")
        sep = v.finite("separation", self.separation)
        if not sep >= 1.0:
            raise ValueError(f"`separation` must be ≥ 1; got {sep:g}")
        set_(self, "separation", sep)
        tol = v.nonnegative("tolerance", self.tolerance)
        if not tol < 1.0:
            raise ValueError(f"`tolerance` must be < 1; got {tol:g}")
        set_(self, "tolerance", tol)

    def _sampled_loop(self) -> None:
        """A sampled loop's keys checked and completed (before the record's checks)."""
        from phoid.dynamics.digital import DigitalPD

        set_ = object.__setattr__
        if self.delay is not None:
            raise ValueError("`delay` (s) and `sample_time` together: a sampled loop's delay is "
                             "`delay_samples`, whole periods of `sample_time`; give one or the "
                             "other")
        if self.delay_margin is not None:
            raise ValueError("`delay_margin` (s) is a continuous loop's; a sampled loop's least "
                             "delay margin is `delay_margin_samples`, whole samples")
        T = v.positive("sample_time", self.sample_time, "s")
        d = whole_number("delay_samples", 0 if self.delay_samples is None
                         else self.delay_samples, 0, MAX_DELAY_SAMPLES)
        velocity = "backward-difference" if self.velocity is None else self.velocity
        if not isinstance(velocity, str) or velocity not in PHO_VELOCITIES:
            raise ValueError(f"`velocity` must be one of "
                             f"{', '.join(map(repr, PHO_VELOCITIES))} (the estimators a "
                             f"PHO set's [loop] takes); got {velocity!r}")
        # the loop's own checks (cut-off), with its messages
        loop = DigitalPD(P=0.0, D=0.0, sample_time=T, delay_samples=d, velocity=velocity,
                         cutoff=self.cutoff)
        if loop.order > MAX_LOOP_ORDER:
            raise ValueError(f"`delay_samples` = {d}: the sampled loop's polynomial would have "
                             f"degree {loop.order} (delay_samples + the estimator's order + 2); "
                             f"the design takes at most {MAX_LOOP_ORDER} (all its roots over the "
                             "prior grid, and the in-loop bound's limit, cost its cube)")
        fs = 1.0 / T if self.fs is None else v.positive("fs", self.fs, "Hz")
        M = fs * T
        if not (M >= 1.0 - 1e-9 and abs(M - round(M)) <= 1e-9 * max(1.0, M)):
            raise ValueError(f"`fs` = {fs:g} Hz must be a whole multiple of the loop's rate "
                             f"{1.0 / T:g} Hz (the inverse of `sample_time`: a rig records at "
                             f"its loop's rate, or a whole number of samples per period); got "
                             f"{M:.6g} samples per period")
        nil = self.noise_in_loop
        if nil is not None and not isinstance(nil, (bool, np.bool_)):
            raise ValueError(f"`noise_in_loop` must be True, False or None; got {nil!r}")
        margin = (max(1, math.ceil(0.2 * d)) if self.delay_margin_samples is None
                  else whole_number("delay_margin_samples", self.delay_margin_samples, 0,
                                    MAX_DELAY_SAMPLES))
        set_(self, "sample_time", T)
        set_(self, "delay_samples", d)
        set_(self, "velocity", velocity)
        set_(self, "fs", float(fs))
        set_(self, "delay", d * T)
        set_(self, "noise_in_loop", True if nil is None else bool(nil))
        set_(self, "delay_margin_samples", margin)
        set_(self, "delay_margin", margin * T)

    def _sampled_record(self) -> None:
        """What a record of ``duration`` cannot show of the sampled loop, refused."""
        from phoid.dynamics.digital import record_problem

        problem = record_problem(self.digital, self.duration)
        if problem is not None:
            raise ValueError(f"`{problem[0]}`{problem[1]}")
        if 3.0 * self.model_delay >= self.duration:
            raise ValueError(f"`delay_samples` = {self.delay_samples} at `sample_time` "
                             f"{self.sample_time:g} s (a loop lag of about "
                             f"{self.model_delay:.4g} s) is too long for the record "
                             f"(`duration` = {self.duration:g} s); is `sample_time` in "
                             "seconds?")

    @property
    def digital(self) -> Any:
        """The sampled loop as a :class:`phoid.dynamics.digital.DigitalPD` (gains 0), or None."""
        if self.sample_time is None:
            return None
        from phoid.dynamics.digital import DigitalPD

        return DigitalPD(P=0.0, D=0.0, sample_time=self.sample_time,
                         delay_samples=self.delay_samples, velocity=self.velocity,
                         cutoff=self.cutoff)

    @property
    def model_delay(self) -> float:
        """The continuous loop's delay, s; for a sampled loop the equivalent delay of its
        continuous surrogate (:func:`equivalent_delay`), which the search works with."""
        if self.sample_time is None:
            return self.delay
        return equivalent_delay(self.sample_time, self.delay_samples, self.velocity,
                                self.cutoff)

    @property
    def noise_placement(self) -> str:
        """``"in-loop"`` or ``"outside"``: where the sensor noise enters (the bound's model)."""
        return "in-loop" if self.noise_in_loop else "outside"

    @property
    def omega_max(self) -> float:
        """Highest allowed damped frequency, rad/s: min(max_freq, 0.2 π f_s), with f_s the
        loop's rate 1/T for a sampled loop."""
        rate = self.fs if self.sample_time is None else min(self.fs, 1.0 / self.sample_time)
        return min(self.max_freq, _NYQUIST_FRACTION * math.pi * rate)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings (``None`` for an absent limit, and for a continuous loop's
        sampled-loop keys)."""

        def lim(x):
            return None if math.isinf(x) else float(x)

        sampled = self.sample_time is not None
        return {
            "delay": self.delay, "fs": self.fs, "duration": self.duration,
            "noise": self.noise, "amplitude": self.amplitude, "zeta": list(self.zeta),
            "pmax": lim(self.pmax), "dmax": lim(self.dmax), "max_freq": lim(self.max_freq),
            "omega_max": self.omega_max, "min_cycles": self.min_cycles,
            "delay_margin": self.delay_margin, "separation": self.separation,
            "tolerance": self.tolerance, "sample_time": self.sample_time,
            "delay_samples": self.delay_samples, "velocity": self.velocity,
            "cutoff": self.cutoff, "delay_margin_samples": self.delay_margin_samples,
            "equivalent_delay": self.model_delay if sampled else None,
            "noise_placement": self.noise_placement,
        }


def equivalent_delay(sample_time: float, delay_samples: int, velocity: Any = "backward-difference",
                     cutoff: float | None = None) -> float:
    """The delay of the continuous surrogate of a sampled loop, s: (d + ½ + τ_v)·T.

    The zero-order hold lags both paths by T/2 and the command delay by d·T; the velocity
    estimator v̂ = lfilter(b, a, x) (:class:`phoid.dynamics.velocity.VelocityFilter`) lags the D
    path by its low-frequency group delay τ_v = Σ j²b_j/(2 Σ j b_j) − Σ i a_i/Σ a_i samples
    (½ for the backward difference, 1 for the central difference, ½ + a/(1 − a) for the
    filtered one, a = e^{−ω_c T}). The P path's lag is (d + ½)·T, the D path's
    (d + ½ + τ_v)·T: the surrogate takes the longer, which errs on the side of less stability
    margin (docs/design-notes/planning.md, "Sampled loops").
    """
    from phoid.dynamics.velocity import VelocityFilter

    est = VelocityFilter(velocity, sample_time, cutoff)
    b, a = np.array(est.b), np.array(est.a)
    j, i = np.arange(b.size), np.arange(a.size)
    lag = 0.5 * float(np.sum(j * j * b) / np.sum(j * b)) - float(np.sum(i * a) / np.sum(a))
    return (delay_samples + 0.5 + max(lag, 0.0)) * sample_time


@dataclass(frozen=True)
class Prior:
    """The prior box and its 3ᵈ check grid; row 0 of ``plants`` is the nominal plant."""

    ranges: dict[str, tuple[float, float]]
    given: dict[str, tuple[float, float]]
    plants: np.ndarray  # (G, 3): m, c, k

    @property
    def nominal(self) -> tuple[float, float, float]:
        m, c, k = self.plants[0]
        return float(m), float(c), float(k)


def make_prior(m: Any, c: Any, k: Any, tolerance: float) -> Prior:
    """The prior box of m, c, k (each a value or a range, see :func:`_range`) and its check
    grid, a single value widened by ±``tolerance`` (relative) for the safety checks."""
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
    return Prior(ranges=ranges, given=given, plants=np.array(seen, dtype=float))


def fmt_range(r: tuple[float, float]) -> str:
    """A prior range as text: ``"2"`` for a single value, ``"1:3"`` for a range."""
    lo, hi = r
    return f"{lo:g}" if lo == hi else f"{lo:g}:{hi:g}"
