r"""The velocity estimators of a sampled controller: the one definition phoid uses everywhere.

A digital controller with period T reads the position at its instants, x_n = x(nT), and
estimates the velocity with a linear filter

    a₀ v̂_n + a₁ v̂_{n−1} + … = b₀ x_n + b₁ x_{n−1} + …,   a₀ = 1,

b in 1/s, a dimensionless (the convention of :func:`scipy.signal.lfilter`). The presets
(:data:`VELOCITY_PRESETS`) are

==========================  ======================================  ============================
name                        v̂_n                                     (b, a)
==========================  ======================================  ============================
``"backward-difference"``   (x_n − x_{n−1})/T                        ((1/T, −1/T), (1,))
``"central-difference"``    (x_n − x_{n−2})/(2T)                     ((1/(2T), 0, −1/(2T)), (1,))
``"filtered"``              a v̂_{n−1} + c_f (x_n − x_{n−1}),          ((c_f, −c_f), (1, −a))
                            a = e^{−ω_c T}, c_f = (1 − a)/T
==========================  ======================================  ============================

and any FIR filter v̂_n = Σ_j b_j x_{n−j} given by its coefficients b₀, b₁, … (1/s, at least
two, summing to zero: a constant position has zero velocity). The ``"filtered"`` estimator is
the backward difference through a first-order low pass of cut-off ω_c (rad/s) whose pole is
mapped exactly (z = e^{−ω_c T}); with c_f = (1 − a)/T its DC gain is 1 for the pole as rounded,
and the backward difference is its ω_c → ∞ limit (a = 0). These two are the **first-order**
estimators, v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1}) (:attr:`VelocityFilter.filter_pole`,
:attr:`VelocityFilter.filter_gain`).

Every part of phoid takes its estimator from here: the exact sampled loop
(:mod:`phoid.dynamics.digital`, with the polynomials of :meth:`VelocityFilter.polynomials`),
the industrial controller (:mod:`phoid.dynamics.controller`) and its simulator, the tracking
set's keys (:mod:`phoid.io.tracking`), the PHO set's digital ``[loop]``
(:mod:`phoid.io.loop`) and the rig's C controller (``phoid/rig/c``, whose presets a test
compares with these).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from phoid import _validate as v

__all__ = [
    "FILTER_DC_RTOL",
    "FIRST_ORDER_PRESETS",
    "FIR_WORDS",
    "MAGNITUDE",
    "VELOCITY_PRESETS",
    "VelocityFilter",
    "check_cutoff",
    "estimator_taps",
    "fir_problem",
]

VELOCITY_PRESETS = ("backward-difference", "central-difference", "filtered")
"""The velocity estimators by name (module docstring: their formulas)."""
FIRST_ORDER_PRESETS = ("backward-difference", "filtered")
"""The presets of the form v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1})."""
FILTER_DC_RTOL = 1e-6
"""The largest relative error of the ``"filtered"`` estimator's rounded pole accepted: the
pole a = e^{−ω_c T} is rounded to a float, which misstates 1 − a (the filter's cut-off, and the
DC gain of c_f = (1 − e^{−ω_c T})/T) by about ε/(ω_c T); below ω_c·T ≈ 1e-10 that is more than
this, and at ω_c·T < 1.1e-16 the pole is 1 exactly: a pure integrator, no velocity at all."""
MAGNITUDE = v.MAGNITUDE
"""The largest magnitude of a cut-off (rad/s) and of an estimator's coefficient (1/s), and the
inverse of the smallest non-zero one: 1e30, as every physical number phoid takes (nothing on a
rig differentiates at 1e30 1/s, and within it the sums and products of the coefficients with
gains and positions stay inside the floating-point range)."""
FIR_WORDS = " or a sequence of FIR coefficients (1/s)"
"""The part of the unknown-name message that offers FIR coefficients (a command line that
takes only a name drops it)."""


def check_cutoff(value: object) -> float:
    """ω_c (rad/s) as a float, or a one-line ValueError naming `cutoff`: a real number (not a
    bool, not a string) > 0 of magnitude 1e-30 … 1e30 (:data:`MAGNITUDE`)."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise ValueError(f"`cutoff` must be a finite number > 0 of magnitude 1e-30 … 1e30 "
                         f"rad/s; got {value!r} ({type(value).__name__})")
    return v.physical("`cutoff`", value, "rad/s")


def fir_problem(coefficients: Sequence[float]) -> str | None:
    """Why finite FIR coefficients b_j (1/s) are no velocity estimator, or None.

    At least two coefficients, each 0 or of magnitude 1e-30 … 1e30 (:data:`MAGNITUDE`), not
    all zero, summing to zero within 1e-9 of Σ|b_j| (a constant position must read as zero
    velocity). The reason is the rest of a sentence whose subject is the estimator (``"needs
    at least 2 …"``).
    """
    n = len(coefficients)
    if n < 2:
        return f"needs at least 2 FIR coefficients (1/s); got {n}"
    for i, c in enumerate(coefficients):
        if c != 0.0 and not 1.0 / MAGNITUDE <= abs(c) <= MAGNITUDE:
            return (f"has FIR coefficient {i} = {c:g} 1/s: each must be 0 or of magnitude "
                    "1e-30 … 1e30 1/s")
    total = math.fsum(coefficients)
    scale = math.fsum(abs(c) for c in coefficients)
    if scale == 0.0:
        return "has FIR coefficients that are all 0: the estimate would always be 0"
    if abs(total) > 1e-9 * scale:
        return ("has FIR coefficients that must sum to 0 (a constant position has zero "
                f"velocity); they sum to {total:.6g} 1/s")
    return None


def _coefficients(value: Sequence[object] | np.ndarray) -> tuple[float, ...]:
    out = []
    for i, c in enumerate(value):
        if isinstance(c, bool) or not isinstance(c, numbers.Real) or not math.isfinite(c):
            raise ValueError(f"`velocity` coefficient {i} must be a finite number (1/s); "
                             f"got {c!r}")
        out.append(float(c))
    problem = fir_problem(out)
    if problem is not None:
        raise ValueError(f"`velocity` {problem}")
    return tuple(out)


def _spec(velocity: object) -> str | tuple[float, ...]:
    """A preset name or the checked FIR coefficients, or a one-line ValueError."""
    if isinstance(velocity, str):
        if velocity not in VELOCITY_PRESETS:
            raise ValueError(
                f"`velocity` must be one of {', '.join(map(repr, VELOCITY_PRESETS))}"
                f"{FIR_WORDS}; got {velocity!r}")
        return velocity
    if isinstance(velocity, Sequence | np.ndarray) and not isinstance(velocity, bytes):
        if isinstance(velocity, np.ndarray) and velocity.ndim != 1:
            raise ValueError(f"`velocity` FIR coefficients must be a 1-D sequence; got shape "
                             f"{velocity.shape}")
        return _coefficients(velocity)
    raise ValueError(
        f"`velocity` must be a preset name or a sequence of FIR coefficients; got {velocity!r}")


def estimator_taps(velocity: object) -> int:
    """The earlier samples x_{n−1}, x_{n−2}, … an estimate reads: len(b) − 1.

    Parameters
    ----------
    velocity : str or sequence of float
        A name of :data:`VELOCITY_PRESETS` or FIR coefficients (1/s), checked as
        :class:`VelocityFilter` checks them.

    Returns
    -------
    int
        1 for the first-order presets, 2 for the central difference, the number of FIR
        coefficients − 1.
    """
    spec = _spec(velocity)
    if isinstance(spec, tuple):
        return len(spec) - 1
    # the preset's own coefficients decide (their count does not depend on T or ω_c)
    return VelocityFilter(spec, 1.0, 1.0 if spec == "filtered" else None).taps


@dataclass(frozen=True)
class VelocityFilter:
    r"""A velocity estimator with its period: v̂ = lfilter(b, a, x) (module docstring).

    Parameters
    ----------
    velocity : str or sequence of float
        A name of :data:`VELOCITY_PRESETS`, or FIR coefficients b₀, b₁, … (1/s) of
        v̂_n = Σ_j b_j x_{n−j} (kept as a tuple).
    sample_time : float
        The controller's period T, s (> 0).
    cutoff : float, optional
        ω_c of ``"filtered"``, rad/s (> 0); required with it, refused otherwise.

    Attributes
    ----------
    name : str
        The preset's name, or ``"fir"``.
    b : tuple of float
        Numerator coefficients, 1/s.
    a : tuple of float
        Denominator coefficients, dimensionless, a₀ = 1.

    Raises
    ------
    ValueError
        One line naming the parameter: a period not finite or not > 0, an unknown name,
        coefficients that are not finite numbers, fewer than two, all zero or not summing to
        zero, a missing or superfluous cut-off, and a cut-off so low for the period that the
        rounded pole e^{−ω_c T} misstates the filter by more than :data:`FILTER_DC_RTOL`.
    """

    velocity: str | tuple[float, ...]
    sample_time: float
    cutoff: float | None = None
    name: str = field(init=False)
    b: tuple[float, ...] = field(init=False)
    a: tuple[float, ...] = field(init=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        T = v.positive("sample_time", self.sample_time, "s")
        set_(self, "sample_time", T)
        spec = _spec(self.velocity)
        set_(self, "velocity", spec)
        if spec == "filtered":
            if self.cutoff is None:
                raise ValueError("`cutoff` (rad/s) is required with the 'filtered' `velocity`")
            wc = check_cutoff(self.cutoff)
            set_(self, "cutoff", wc)
            wT = wc * T
            pole = math.exp(-wT)
            exact = -math.expm1(-wT)  # 1 − e^{−ω_c T}, to rounding
            if not abs((1.0 - pole) - exact) <= FILTER_DC_RTOL * exact:
                raise ValueError(
                    f"`cutoff` ω_c = {wc:g} rad/s is too low for the period T = {T:g} s: "
                    f"ω_c·T = {wT:.3g}, and the filter's pole e^(-ω_c·T) rounds so close to 1 "
                    f"that the filter (its 1 - e^(-ω_c·T)) is off by more than "
                    f"{FILTER_DC_RTOL:g} (give ω_c in rad/s, not Hz·T or similar)")
            cf = (1.0 - pole) / T
            name, b, a = spec, (cf, -cf), (1.0, -pole)
        else:
            if self.cutoff is not None:
                raise ValueError(
                    f"`cutoff` applies only to the 'filtered' `velocity`; got `cutoff` "
                    f"{self.cutoff!r} with `velocity` {self.velocity!r}")
            if spec == "backward-difference":
                name, b, a = spec, (1.0 / T, -1.0 / T), (1.0,)
            elif spec == "central-difference":
                h = 1.0 / (2.0 * T)
                name, b, a = spec, (h, 0.0, -h), (1.0,)
            else:
                name, b, a = "fir", tuple(spec), (1.0,)
        if not all(math.isfinite(c) and abs(c) <= MAGNITUDE for c in b):
            raise ValueError(f"`sample_time` is too short for the velocity estimator: "
                             f"sample_time = {T:g} s makes its coefficients (1/s) exceed 1e30 "
                             "(is it in seconds?)")
        set_(self, "name", name)
        set_(self, "b", b)
        set_(self, "a", a)

    @property
    def taps(self) -> int:
        """Earlier samples of x an estimate reads, len(b) − 1 (a record needs taps + 1)."""
        return len(self.b) - 1

    @property
    def order(self) -> int:
        """r = max(len(b), len(a)) − 1: the degree of the filter's polynomials in z."""
        return max(len(self.b), len(self.a)) - 1

    @property
    def first_order(self) -> bool:
        """True for v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1}) (:data:`FIRST_ORDER_PRESETS`)."""
        return self.name in FIRST_ORDER_PRESETS

    def _first_order(self, what: str) -> None:
        if not self.first_order:
            raise ValueError(
                f"`velocity` = {self.velocity!r} is not a first-order estimator "
                f"(v̂_n = a v̂_(n-1) + c_f (x_n - x_(n-1))), so it has no {what}; the "
                f"first-order ones are {', '.join(map(repr, FIRST_ORDER_PRESETS))}")

    @property
    def filter_pole(self) -> float:
        """a = e^{−ω_c T} of ``"filtered"``, 0 for the backward difference; dimensionless.

        Raises
        ------
        ValueError
            For an estimator that is not first-order.
        """
        self._first_order("filter pole a")
        return -self.a[1] if len(self.a) > 1 else 0.0

    @property
    def filter_gain(self) -> float:
        """c_f = (1 − a)/T, 1/s, of a first-order estimator (b = (c_f, −c_f)).

        Raises
        ------
        ValueError
            For an estimator that is not first-order.
        """
        self._first_order("filter gain c_f")
        return self.b[0]

    def coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) as arrays: b in 1/s, a dimensionless, for :func:`scipy.signal.lfilter`."""
        return np.array(self.b), np.array(self.a)

    def polynomials(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r"""The filter's polynomials in z, highest power first, each of degree r = :attr:`order`.

        With A(z) = z^r Σ_i a_i z^{−i} and B(z) = z^r Σ_j b_j z^{−j}, the estimate is
        V̂(z) = B(z)/A(z)·X(z). E(z) = Σ_{k=0}^{r−1} (Σ_{j>k} b_j) z^{r−k} is the estimator's
        part of a release from rest: held at x₀ (x_{−1} = x_{−2} = … = x₀, v̂_{−1} = … = 0),
        the one-sided transforms obey A(z)V̂(z) = B(z)X(z) + x₀E(z).

        Returns
        -------
        A : numpy.ndarray, shape (r + 1,)
            Monic, dimensionless.
        B : numpy.ndarray, shape (r + 1,)
            1/s.
        E : numpy.ndarray, shape (r + 1,)
            1/s; its constant term is 0.

        Examples
        --------
        The first-order estimators: A = z − a, B = c_f(z − 1), E = −c_f z.
        """
        r = self.order
        A = np.zeros(r + 1)
        A[: len(self.a)] = self.a
        B = np.zeros(r + 1)
        B[: len(self.b)] = self.b
        b = np.array(self.b)
        E = np.zeros(r + 1)
        for k in range(r):
            E[k] = math.fsum(b[k + 1:])
        return A, B, E

    def apply(self, x: np.ndarray, *, at_rest: bool = False) -> np.ndarray:
        """The estimates v̂ of the positions x (m/s): ``scipy.signal.lfilter(b, a, x, axis=-1)``.

        Parameters
        ----------
        x : array_like
            Positions at the controller's instants, m (the last axis is time).
        at_rest : bool, default False
            False: zero initial state (x and v̂ zero before ``x[..., 0]``). True: at rest at
            ``x[..., 0]`` before it (x_{−1} = x_{−2} = … = x₀, v̂ = 0: a held mass), which is
            the filter of x − x₀ from zero state, since Σ b_j = 0.

        Returns
        -------
        numpy.ndarray
            Same shape as x, m/s.
        """
        from scipy.signal import lfilter

        xs = np.asarray(x, dtype=float)
        if at_rest and xs.size:
            xs = xs - xs[..., :1]
        b, a = self.coefficients()
        return lfilter(b, a, xs, axis=-1)
