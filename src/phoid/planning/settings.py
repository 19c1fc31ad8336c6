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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import phoid._validate as v
from phoid.errors import PhoidError
from phoid.io.limits import MAX_LINES

__all__ = ["UNITS", "DesignError", "DesignSettings", "Prior", "fmt_range", "make_prior"]


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
        if 3.0 * self.delay >= self.duration:
            # the identification fits each decay from 3 delays after the release (the loop's
            # fast transient): a longer delay leaves nothing to fit, and the loop's roots for
            # it are many and slow to certify
            raise ValueError(f"`delay` (--delay) = {self.delay:g} s is too long for the record "
                             f"(`duration` = {self.duration:g} s): the identification fits "
                             "each decay from 3 delays after the release; is the delay in "
                             "seconds?")
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
        dm = self.delay_margin
        given = dm is not None
        if dm is None:
            dm = max(0.2 * self.delay, 1.0 / self.fs)
        set_(self, "delay_margin", v.nonnegative("delay_margin", dm, "s"))
        if given and self.delay_margin > self.duration:  # the default's: the delay's message
            raise ValueError(f"`delay_margin` = {self.delay_margin:g} s is longer than the "
                             f"record (`duration` = {self.duration:g} s): no loop that rings "
                             "within the record tolerates that much extra delay")
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
