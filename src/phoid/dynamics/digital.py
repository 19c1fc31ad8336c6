r"""Digital (sampled-data) PD loops: the exact closed-loop characteristic polynomial and modes.

Real PHO loops (the seed's eq. 23) run on a digital controller. The Discussion of the seed paper
notes the effects of sampling; this module replaces the continuous delayed loop by the exact
model of the sampled one, so that no "equivalent" continuous delay has to be guessed.

The loop
--------
The plant m x'' + c x' + k x = u(t) (eq. 1; Coulomb friction and an external force only in the
simulator) runs in continuous time. With sample time T_s (controller clock t_n = nT_s) the
controller

1. samples the position, x_n = x(nT_s);
2. estimates the velocity with one of phoid's estimators (:mod:`phoid.dynamics.velocity`, the
   one definition), a linear filter Σ_i a_i v̂_{n−i} = Σ_j b_j x_{n−j}: the **backward
   difference** v̂_n = (x_n − x_{n−1})/T_s, the **central difference**
   v̂_n = (x_n − x_{n−2})/(2T_s), the **filtered** backward difference
   v̂_n = a v̂_{n−1} + (1 − a)(x_n − x_{n−1})/T_s with a = e^{−ω_c T_s} (a first-order low pass
   of cut-off ω_c, rad/s, whose pole is mapped exactly and whose DC gain is 1), or any FIR
   filter v̂_n = Σ_j b_j x_{n−j}. With r the filter's order, its polynomials in z are
   A(z) = z^r Σ_i a_i z^{−i} (monic) and B(z) = z^r Σ_j b_j z^{−j}; for the first-order
   estimators (backward difference: a = 0) A(z) = z − a and B(z) = c_f (z − 1),
   c_f = (1 − a)/T_s;
3. computes u_n = −(P x_n + D v̂_n) (eq. 23's PD law on the sampled signals);
4. applies it through a zero-order hold, d whole samples late:
   u(t) = u_{n−d} for nT_s ≤ t < (n+1)T_s.

Exact discretisation and characteristic polynomial
--------------------------------------------------
With y = (x, ẋ), y' = A y + b u, A = [[0, 1], [−k/m, −c/m]], b = (0, 1/m) (eq. 1 in state form),
a constant input over one period gives exactly (zero-order-hold discretisation)

    y_{n+1} = Φ y_n + Γ u_{n−d},   Φ = e^{AT_s},   Γ = ∫₀^{T_s} e^{Aτ} dτ b,

so the plant's pulse transfer function is G(z) = [1 0](zI − Φ)^{−1}Γ = N(z)/Δ(z) with

    Δ(z) = z² − τ z + δ,  τ = tr Φ,  δ = det Φ = e^{−cT_s/m};
    N(z) = b₁ z + b₀,     b₁ = Γ₁,   b₀ = Φ₁₂Γ₂ − Φ₂₂Γ₁.

The controller is K(z) = P + D B(z)/A(z), the delay z^{−d}; the closed loop
1 + z^{−d} K(z) G(z) = 0 is the polynomial equation of degree d + r + 2 (monic)

    χ(z) = z^d A(z) Δ(z) + [P A(z) + D B(z)] N(z) = 0,

for the first-order estimators (degree d + 3)
χ(z) = z^d (z − a) Δ(z) + [P (z − a) + D c_f (z − 1)] N(z).
It is exact: no approximation of the delay, the hold or the difference quotient. Each root z_j
is a mode z_j^n of the loop at the sample instants; its continuous-time rate is
s_j = ln(z_j)/T_s (principal branch, |Im s_j| ≤ π/T_s), s_j = −σ_j + iω_{d,j} as in the paper's
eqs. (2)–(15). The loop is stable when every |z_j| < 1.

The response at the sample instants
-----------------------------------
Released at a controller instant from a held position x₀ (the controller running meanwhile, so
x_{−1} = x_{−2} = … = x₀, v̂_{−1} = v̂_{−2} = … = 0 and the queued commands are −P x₀) with
velocity v₀, the one-sided transforms obey A(z)V̂(z) = B(z)X(z) + x₀E(z) with
E(z) = Σ_{k=0}^{r−1} (Σ_{j>k} b_j) z^{r−k}
(:meth:`phoid.dynamics.velocity.VelocityFilter.polynomials`; E = −c_f z for the first-order
estimators), and the z-transform of x_n is X(z) = Q(z)/χ(z) with

    Q(z) = z^{d+1} A(z) [(z − Φ₂₂) x₀ + Φ₁₂ v₀] − P x₀ A(z) N(z) Σ_{j=1}^{d} z^j
           − D x₀ E(z) N(z),

so, for simple roots, x_n = Σ_j a_j z_j^n exactly for every n ≥ n₀, n₀ the multiplicity of the
root z = 0 (0 when χ(0) ≠ 0; e.g. 1 for D = 0 with the backward difference), a_j =
Q(z_j)/(z_j χ′(z_j)) (:func:`digital_residues`). A decay fit of a record taken at the
controller's instants therefore measures s_j = ln(z_j)/T_s exactly: the sampled loop *is* a sum
of damped sinusoids there, with the rates of this module, not an approximation of a continuous
loop.

A recorder faster than the controller (f_s = M/T_s) also sees the plant between the controller's
instants, where it moves under a constant command: x(nT_s + θ) = Σ_j a_j(θ) z_j^n, 0 ≤ θ < T_s.
Each mode is then e^{s_j t} times a T_s-periodic factor (Floquet form); the factor's mean is
the mode itself, and its other Fourier components are the aliases s_j + 2πil/T_s, l ≠ 0, at
least 2π/T_s − 2|ω_d| away in frequency. The dominant rate is the same s_j; a single-mode decay
fit over many periods sees the ripple as a small, out-of-band, deterministic residual (its
size on an example loop: docs/design-notes/dynamics.md).

No "equivalent" continuous delay
--------------------------------
The zero-order hold delays both the P and the D path by about T_s/2, the backward difference
delays the D path by another T_s/2, and both change the gain with frequency, so no single
continuous delay Δt makes the delayed loop of :mod:`phoid.dynamics.loop` reproduce the sampled
loop's modes; fitting them with it biases m, c and k (the measured bias:
docs/design-notes/dynamics.md). The exact model of this module has no such bias.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from phoid import _validate as v
from phoid.dynamics.velocity import VELOCITY_PRESETS, VelocityFilter
from phoid.dynamics.zoh import ZOHPlant, expm_stack, zoh_plant

__all__ = [
    "VELOCITY_ESTIMATORS",
    "DigitalPD",
    "DigitalRoots",
    "ZOHPlant",
    "characteristic_coefficients",
    "digital_characteristic",
    "digital_coefficients",
    "digital_is_dominant",
    "digital_is_stable",
    "digital_modes",
    "digital_residues",
    "digital_roots",
    "expm_stack",
    "record_problem",
    "timing_problem",
    "zoh_plant",
]

VELOCITY_ESTIMATORS = VELOCITY_PRESETS
"""The velocity estimators :class:`DigitalPD` models by name: the one list,
:data:`phoid.dynamics.velocity.VELOCITY_PRESETS` itself (and FIR coefficients)."""


# --------------------------------------------------------------------------------------------
# the loop


def _delay_samples(value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"`delay_samples` must be a whole number of samples (≥ 0); got {value!r}")
    if isinstance(value, numbers.Integral):
        d = int(value)
    else:
        f = float(value)
        if not (math.isfinite(f) and f.is_integer()):
            raise ValueError(
                f"`delay_samples` must be a whole number of samples (≥ 0); got {value!r}"
            )
        d = int(f)
    if d < 0:
        raise ValueError(f"`delay_samples` must be ≥ 0; got {d}")
    return d


@dataclass(frozen=True)
class DigitalPD:
    """A sampled PD controller with zero-order hold and a whole-sample delay.

    u_n = −(P x_n + D v̂_n) from x_n = x(nT_s), applied as u(t) = u_{n−d} on [nT_s, (n+1)T_s)
    (the module docstring gives the exact loop; :mod:`phoid.dynamics.velocity` the estimators).

    Parameters
    ----------
    P : float
        Proportional gain, N/m (any sign).
    D : float
        Derivative gain, N·s/m (any sign).
    sample_time : float
        Controller sample time T_s, s (> 0).
    delay_samples : int, default 0
        Command delay d in whole samples (≥ 0); d = 0 applies u_n from t_n on.
    velocity : str or sequence of float, default "backward-difference"
        The velocity estimator: a name of :data:`VELOCITY_ESTIMATORS` (``"backward-difference"``
        v̂_n = (x_n − x_{n−1})/T_s, ``"central-difference"`` (x_n − x_{n−2})/(2T_s),
        ``"filtered"`` v̂_n = a v̂_{n−1} + (1 − a)(x_n − x_{n−1})/T_s with a = e^{−ω_c T_s}),
        or FIR coefficients b₀, b₁, … (1/s) of v̂_n = Σ_j b_j x_{n−j} (kept as a tuple).
    cutoff : float, optional
        The filter's cut-off ω_c, rad/s (> 0); required with ``velocity="filtered"`` and
        refused otherwise.

    Attributes
    ----------
    estimator : phoid.dynamics.velocity.VelocityFilter
        The velocity estimator with its coefficients (b, a) at this sample time.

    Raises
    ------
    ValueError
        Naming the parameter, for a non-finite gain, a non-positive sample time, a delay that is
        not a whole number ≥ 0, an unknown estimator, FIR coefficients that are no velocity
        estimator, or a missing, superfluous or (for the period) too low cut-off.
    """

    P: float
    D: float
    sample_time: float
    delay_samples: int = 0
    velocity: str | tuple[float, ...] = "backward-difference"
    cutoff: float | None = None
    estimator: VelocityFilter = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "P", v.finite("P", self.P, "N/m"))
        object.__setattr__(self, "D", v.finite("D", self.D, "N·s/m"))
        object.__setattr__(self, "sample_time", v.positive("sample_time", self.sample_time, "s"))
        object.__setattr__(self, "delay_samples", _delay_samples(self.delay_samples))
        est = VelocityFilter(self.velocity, self.sample_time, self.cutoff)
        object.__setattr__(self, "velocity", est.velocity)
        object.__setattr__(self, "cutoff", est.cutoff)
        object.__setattr__(self, "estimator", est)

    @property
    def filter_pole(self) -> float:
        """a = e^{−ω_c T_s} (0 for the backward difference), dimensionless.

        Raises
        ------
        ValueError
            For an estimator that is not first-order (the central difference, FIR): use
            :attr:`estimator`.
        """
        return self.estimator.filter_pole

    @property
    def filter_gain(self) -> float:
        """c_f = (1 − a)/T_s, 1/s: v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1}).

        Raises
        ------
        ValueError
            For an estimator that is not first-order: use :attr:`estimator`.
        """
        return self.estimator.filter_gain

    @property
    def delay(self) -> float:
        """The command delay d·T_s, s (the ZOH and the difference add about T_s/2 each)."""
        return self.delay_samples * self.sample_time

    @property
    def order(self) -> int:
        """Degree of the characteristic polynomial, d + r + 2 (d + 3 for a first-order
        estimator; r the estimator's order)."""
        return self.delay_samples + self.estimator.order + 2


def record_problem(loop: DigitalPD, span: float) -> tuple[str, str] | None:
    """What a record of ``span`` seconds after the release cannot show of ``loop``, or None.

    :func:`timing_problem` of the loop's sample time, delay, cut-off (of ``"filtered"``) and
    estimator.

    Returns
    -------
    tuple of str or None
        (key, reason): the :class:`DigitalPD` field at fault and the rest of a one-line message
        (it begins with `` = value``).
    """
    return timing_problem(loop.sample_time, loop.delay_samples,
                          loop.cutoff if loop.velocity == "filtered" else None,
                          loop.estimator.taps, span, loop.estimator.name)


def timing_problem(sample_time: float, delay_samples: int, cutoff: float | None, taps: int,
                   span: float, velocity: str = "the estimator") -> tuple[str, str] | None:
    """What a record of ``span`` seconds after the release cannot show of a sampled loop, or None.

    A sample time longer than the record (the controller never samples the motion), a command
    delay d·T_s longer than it (the command never reaches the plant within it; the loop's
    polynomial would have degree d + r + 2), a velocity filter whose time constant 1/ω_c is
    longer than it (the filtered velocity hardly moves: the D term is not in the record) or an
    estimator whose taps span more than it (its estimate never fills).

    Parameters
    ----------
    sample_time : float
        T_s, s (> 0).
    delay_samples : int
        d, whole periods.
    cutoff : float or None
        ω_c of a ``"filtered"`` estimator, rad/s (None for the others).
    taps : int
        The estimator's earlier samples (:func:`phoid.dynamics.velocity.estimator_taps`).
    span : float
        The record's length after the release, s (no check unless finite and > 0).
    velocity : str, default "the estimator"
        The estimator's name, for the message.

    Returns
    -------
    tuple of str or None
        (key, reason): the :class:`DigitalPD` field at fault and the rest of a one-line message
        (it begins with `` = value``).
    """
    if not (math.isfinite(span) and span > 0):
        return None
    T = sample_time
    if T > span:
        return ("sample_time", f" = {T:g} s is longer than the record ({span:.4g} s): the "
                               "controller would not sample it")
    if delay_samples * T > span:
        return ("delay_samples", f" = {delay_samples} periods ({delay_samples * T:.4g} "
                                 f"s at sample_time {T:g} s) is longer than the record "
                                 f"({span:.4g} s): the command would never reach the plant")
    if cutoff is not None and cutoff * span < 1.0:
        return ("cutoff", f" = {cutoff:g} rad/s: the velocity filter's time constant "
                          f"1/cutoff = {1.0 / cutoff:.3g} s is longer than the record "
                          f"({span:.4g} s), so the filtered velocity would hardly move; is it "
                          "in rad/s?")
    if taps * T > span:
        return ("velocity", f" = {velocity} reads {taps} earlier samples ({taps * T:.4g} s at "
                            f"sample_time {T:g} s), more than the record ({span:.4g} s) holds")
    return None


# --------------------------------------------------------------------------------------------
# characteristic polynomial


def _check_loop(loop) -> DigitalPD:
    if not isinstance(loop, DigitalPD):
        raise ValueError(f"`loop` must be a phoid.DigitalPD; got {type(loop).__name__}")
    return loop


def _gains(P, D) -> tuple[np.ndarray, np.ndarray]:
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    if P.ndim != 1 or D.ndim != 1:
        raise ValueError(f"`P` and `D` must be scalars or 1-D arrays; got shapes {P.shape}, "
                         f"{D.shape}")
    try:
        P, D = np.broadcast_arrays(P, D)
    except ValueError:
        raise ValueError(
            f"`P` and `D` must have one entry per run; got {P.size} and {D.size}"
        ) from None
    return P, D


def _filter_polys(a: float, cf: float) -> tuple[np.ndarray, np.ndarray]:
    """A(z) = z − a and B(z) = c_f (z − 1) of a first-order estimator."""
    return np.array([1.0, -a]), np.array([cf, -cf])


def _coefficients(zp: ZOHPlant, P, D, fp, d: int) -> np.ndarray:
    """Coefficients of χ = z^d A Δ + (P A + D B) N, highest power first, shape (B, d + r + 3)."""
    Af, Bf = fp
    r = Af.size - 1
    B = P.size
    coef = np.zeros((B, d + r + 3))
    coef[:, : r + 3] = np.convolve(Af, [1.0, -zp.tau, zp.delta])
    K = P[:, None] * Af + D[:, None] * Bf  # P A(z) + D B(z), (B, r + 1)
    coef[:, -(r + 2):-1] += K * zp.b1
    coef[:, -(r + 1):] += K * zp.b0
    return coef


def characteristic_coefficients(zp: ZOHPlant, P, D, a: float, cf: float, d: int) -> np.ndarray:
    """Coefficients of χ for a first-order estimator (highest power first), shape (B, d + 4).

    χ(z) = z^d (z − a)Δ(z) + [P(z − a) + D c_f (z − 1)]N(z) (module docstring), ``a`` and
    ``cf`` the estimator's :attr:`DigitalPD.filter_pole` and :attr:`DigitalPD.filter_gain`
    (:func:`digital_coefficients`: every estimator).
    """
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    return _coefficients(zp, P, D, _filter_polys(a, cf), d)


def digital_coefficients(
    m: float, c: float, k: float, P: np.ndarray | float, D: np.ndarray | float, loop: DigitalPD
) -> np.ndarray:
    """Coefficients of the characteristic polynomial χ(z), highest power first.

    χ(z) = z^d A(z)(z² − τz + δ) + [P A(z) + D B(z)](b₁z + b₀) (module docstring); for the
    first-order estimators A = z − a, B = c_f (z − 1).

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg), damping (N·s/m), stiffness (N/m).
    P, D : float or array_like, shape (B,)
        Gains of each run, N/m and N·s/m (these, not ``loop.P``, ``loop.D``, are used).
    loop : DigitalPD
        Sample time, delay, velocity estimator (its own gains are ignored here).

    Returns
    -------
    ndarray, shape (B, loop.order + 1)
        Monic, dimensionless; ``np.roots(coef[i])`` are run i's closed-loop z-roots.
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    zp = zoh_plant(m, c, k, loop.sample_time)
    return _coefficients(zp, P, D, _polys(loop), loop.delay_samples)


def _polys(loop: DigitalPD) -> tuple[np.ndarray, np.ndarray]:
    """The estimator's A(z) and B(z), highest power first."""
    return loop.estimator.polynomials()[:2]


def _horner(c: np.ndarray, z):
    """p(z) and p′(z) of the real polynomial c (highest power first)."""
    p = np.zeros_like(z) + c[0]
    dp = np.zeros_like(z)
    for ci in c[1:]:
        dp = dp * z + p
        p = p * z + ci
    return p, dp


def _chi(z, zp: ZOHPlant, P, D, fp, d):
    """χ(z) and χ′(z) in factored form (accurate near the plant poles λ)."""
    z = np.asarray(z, dtype=complex)
    Af, Bf = fp
    l1, l2 = zp.lam
    delta_z = (z - l1) * (z - l2)
    ddelta_z = 2.0 * z - (l1 + l2)
    Az, dAz = _horner(Af, z)
    Bz, dBz = _horner(Bf, z)
    A = Az * delta_z
    dA = dAz * delta_z + Az * ddelta_z
    N = zp.b1 * z + zp.b0
    Kn = P * Az + D * Bz
    dKn = P * dAz + D * dBz
    zd = z**d
    dzd = d * z ** (d - 1) if d > 0 else 0.0
    chi = zd * A + Kn * N
    dchi = dzd * A + zd * dA + dKn * N + Kn * zp.b1
    return chi, dchi


def digital_characteristic(
    z: np.ndarray | complex,
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    loop: DigitalPD,
) -> tuple[np.ndarray, np.ndarray]:
    """χ(z) and dχ/dz of the sampled loop (module docstring), dimensionless.

    Parameters
    ----------
    z : complex or array_like
        The z-variable (broadcast against P and D).
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : float or array_like
        Gains, N/m and N·s/m (the loop's own gains are ignored).
    loop : DigitalPD
        Timing and velocity estimator.

    Returns
    -------
    chi, dchi : ndarray of complex
        Evaluated with Δ(z) = (z − λ₁)(z − λ₂), λ = e^{pT_s}, so that near the plant's poles
        no cancellation between z² − τz + δ's terms occurs.
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    zp = zoh_plant(m, c, k, loop.sample_time)
    return _chi(z, zp, P, D, _polys(loop), loop.delay_samples)


# --------------------------------------------------------------------------------------------
# roots


@dataclass(frozen=True)
class DigitalRoots:
    """All closed-loop roots of B runs' sampled loops.

    Attributes
    ----------
    z : ndarray of complex, shape (B, loop.order)
        Roots of χ, sorted by decreasing |z| (decreasing Re s); of a conjugate pair the one
        with positive imaginary part first. A root at z = 0 is exactly 0 (as many as χ has
        zero trailing coefficients).
    s : ndarray of complex, shape (B, loop.order)
        s = ln(z)/T_s, 1/s (principal branch; −inf for a root at z = 0).
    dominant : ndarray of complex, shape (B,)
        The rightmost s of each run, with Im s ≥ 0 (the paper's −σ + iω_d).
    sample_time : float
        T_s, s.
    """

    z: np.ndarray
    s: np.ndarray
    dominant: np.ndarray
    sample_time: float

    @property
    def stable(self) -> np.ndarray:
        """True where every root lies inside the unit circle (|z| < 1)."""
        return np.max(np.abs(self.z), axis=1) < 1.0


def _log_s(z: np.ndarray, T: float) -> np.ndarray:
    """ln(z)/T, part by part: a root at z = 0 gives −inf + 0j (not −inf + nan·j)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.log(z)
    return w.real / T + 1j * (w.imag / T)


def _polish(z, zp, P, D, fp, d, iters=3):
    """Newton steps on the factored χ, each kept only where it lowers |χ|."""
    chi, dchi = _chi(z, zp, P, D, fp, d)
    for _ in range(iters):
        with np.errstate(all="ignore"):
            zn = z - chi / dchi
        chin, dchin = _chi(zn, zp, P, D, fp, d)
        better = np.isfinite(zn) & (np.abs(chin) < np.abs(chi))
        if not better.any():
            break
        z = np.where(better, zn, z)
        chi = np.where(better, chin, chi)
        dchi = np.where(better, dchin, dchi)
    return z


def _all_roots(zp: ZOHPlant, P, D, fp, d, T) -> DigitalRoots:
    coef = _coefficients(zp, P, D, fp, d)
    B, n = P.size, coef.shape[1] - 1
    comp = np.zeros((B, n, n))
    comp[:, 0, :] = -coef[:, 1:]
    idx = np.arange(1, n)
    comp[:, idx, idx - 1] = 1.0
    z = np.linalg.eigvals(comp).astype(complex)
    # χ's exactly zero trailing coefficients are as many exact roots at z = 0 (e.g. D = 0 with
    # the backward difference, or an FIR estimator): the eigenvalue solver returns them only
    # to rounding (a multiple root at 0 as a tiny circle), so the smallest are set to 0
    trailing = np.argmax(coef[:, ::-1] != 0.0, axis=1)
    if trailing.any():
        smallest = np.argsort(np.abs(z), axis=1)
        rows, cols = np.nonzero(np.arange(n)[None, :] < trailing[:, None])
        z[rows, smallest[rows, cols]] = 0.0
    z = _polish(z, zp, P[:, None], D[:, None], fp, d)
    s = _log_s(z, T)
    order = np.lexsort((-z.imag, -np.round(np.abs(z), 12)), axis=-1)
    z = np.take_along_axis(z, order, axis=1)
    s = np.take_along_axis(s, order, axis=1)
    dom = s[:, 0].real + 1j * np.abs(s[:, 0].imag)
    return DigitalRoots(z, s, dom, T)


def digital_roots(
    m: float, c: float, k: float, P: np.ndarray | float, D: np.ndarray | float, loop: DigitalPD
) -> DigitalRoots:
    """All d + r + 2 closed-loop roots of each run's sampled loop, and the dominant one.

    The roots of χ are the eigenvalues of its companion matrix (batched over runs, as
    ``np.roots`` does one at a time), polished by Newton's method on the factored χ, and mapped
    to s = ln(z)/T_s.

    Parameters
    ----------
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : float or array_like, shape (B,)
        Gains of each run, N/m and N·s/m (the loop's own gains are ignored).
    loop : DigitalPD
        Timing and velocity estimator.

    Returns
    -------
    DigitalRoots
        ``z``, ``s`` (B, ``loop.order``) sorted by decreasing real part of s, ``dominant`` (B,)
        and ``stable`` (B,).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    zp = zoh_plant(m, c, k, loop.sample_time)
    return _all_roots(zp, P, D, _polys(loop), loop.delay_samples, loop.sample_time)


def digital_is_stable(
    m: float, c: float, k: float, P: np.ndarray | float, D: np.ndarray | float, loop: DigitalPD
) -> np.ndarray:
    """True for each run whose sampled loop is asymptotically stable (all |z_j| < 1)."""
    return digital_roots(m, c, k, P, D, loop).stable


def digital_is_dominant(
    s: np.ndarray | complex,
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    loop: DigitalPD,
    *,
    rtol: float = 1e-9,
) -> np.ndarray:
    """True where the root s (one per run) is the rightmost root of that run's loop.

    The loop has finitely many roots, so the check is exact: all are computed
    (:func:`digital_roots`) and s must be as far right as the rightmost one, up to
    ``rtol``·max(1, |s|) (1/s).
    """
    P, D = _gains(P, D)
    s = np.broadcast_to(np.asarray(s, dtype=complex), P.shape)
    dom = digital_roots(m, c, k, P, D, loop).dominant
    return s.real >= dom.real - rtol * np.maximum(1.0, np.abs(dom))


# --------------------------------------------------------------------------------------------
# the identification's hot path: tracked dominant roots and their Jacobian


def digital_modes(
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    loop: DigitalPD,
    s_guess: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each run's dominant root s_i(m, c, k) of the sampled loop and ∂s_i/∂(m, c, k).

    The digital counterpart of ``phoid.dynamics.rightmost.dominant_roots`` plus the implicit
    differentiation in ``phoid.methods.pho.fit_modes``: the model σᵢ = −Re sᵢ, ω_dᵢ = Im sᵢ
    for measured modes.

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg, > 0), damping (N·s/m), stiffness (N/m); c, k may have any sign.
    P, D : float or array_like, shape (B,)
        Gains of each run, N/m and N·s/m.
    loop : DigitalPD
        Timing and velocity estimator (its own gains are ignored).
    s_guess : array_like of complex, shape (B,), optional
        Starting points, e.g. the measured −σᵢ + iω_dᵢ: Newton's method on χ from
        z = e^{s_guess T_s} (a start that fails to converge falls back to the dominant root).
        Without a guess, the dominant root from all roots (:func:`digital_roots`).

    Returns
    -------
    s : ndarray of complex, shape (B,)
        sᵢ = −σᵢ + iω_dᵢ, 1/s, Im sᵢ ≥ 0, on the branch of ln z nearest the guess.
    ds_dtheta : ndarray of complex, shape (B, 3)
        ∂sᵢ/∂(m, c, k), in 1/(s·kg), m/(N·s²) and m/(N·s) (s per unit of each parameter),
        from χ(z; θ) = 0: ∂z/∂θ = −(∂χ/∂θ)/(∂χ/∂z), ∂s/∂θ = (∂z/∂θ)/(z T_s), with
        ∂χ/∂θ = z^d A(z)(−z ∂τ/∂θ + ∂δ/∂θ) + [P A(z) + D B(z)](z ∂b₁/∂θ + ∂b₀/∂θ).

    Notes
    -----
    Tracked roots are not certified here; :func:`digital_is_dominant` checks a solution
    (exactly: the loop has d + r + 2 roots).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    T = loop.sample_time
    fp, d = _polys(loop), loop.delay_samples
    zp = zoh_plant(m, c, k, T, derivatives=True)
    if s_guess is None:
        s0 = _all_roots(zp, P, D, fp, d, T).dominant
        z = np.exp(s0 * T)
        ref = s0
    else:
        ref = np.broadcast_to(np.asarray(s_guess, dtype=complex), P.shape)
        z = np.exp(ref * T)
        for _ in range(40):
            chi, dchi = _chi(z, zp, P, D, fp, d)
            with np.errstate(all="ignore"):
                step = chi / dchi
            z = z - step
            # quadratic convergence: a step of 1e-12 |z| leaves an error at rounding level
            if np.all(np.abs(step) <= 1e-12 * np.abs(z)):
                break
        chi, dchi = _chi(z, zp, P, D, fp, d)
        with np.errstate(all="ignore"):
            ok = np.isfinite(z) & (np.abs(chi) <= 1e-10 * np.abs(dchi * z))
        if not ok.all():  # a start that went astray: the dominant root from all roots
            dom = _all_roots(zp, P[~ok], D[~ok], fp, d, T).dominant
            z = z.copy()
            z[~ok] = np.exp(dom * T)
    z = _polish(z, zp, P, D, fp, d, iters=2)
    _, dchi = _chi(z, zp, P, D, fp, d)
    zd = z**d
    Az, _ = _horner(fp[0], z)
    Bz, _ = _horner(fp[1], z)
    Kn = P * Az + D * Bz
    dth = (
        zd[:, None] * Az[:, None] * (-z[:, None] * zp.d_tau + zp.d_delta)
        + Kn[:, None] * (z[:, None] * zp.d_b1 + zp.d_b0)
    )
    dz = -dth / dchi[:, None]
    ds = dz / (z[:, None] * T)
    s = _log_s(z, T)
    # branch of ln z nearest the reference (the guess), then the upper half plane
    turns = np.round((ref.imag - s.imag) * T / (2 * math.pi))
    s = s + 2j * math.pi * turns / T
    flip = s.imag < 0
    s = np.where(flip, np.conj(s), s)
    ds = np.where(flip[:, None], np.conj(ds), ds)
    return s, ds


# --------------------------------------------------------------------------------------------
# the response to a release


def digital_residues(
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    loop: DigitalPD,
    x0: float = 1.0,
    v0: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Modes and amplitudes of the response to a release at a controller instant.

    Held at x₀ with the controller running, released with velocity v₀ at t = 0 (a controller
    instant): x(nT_s) = Σ_j a_j z_j^n exactly for n ≥ n₀ (n₀ the multiplicity of a root at
    z = 0, else 0), with a_j = Q(z_j)/(z_j χ′(z_j)) and Q the numerator of the module
    docstring, Q(z) = z^{d+1}A(z)[(z − Φ₂₂)x₀ + Φ₁₂v₀] − P x₀ A(z)N(z)Σ_{j=1}^d z^j
    − D x₀ E(z)N(z).

    Parameters
    ----------
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : float or array_like, shape (B,)
        Gains of each run.
    loop : DigitalPD
        Timing and velocity estimator.
    x0 : float, default 1
        Held position, m.
    v0 : float, default 0
        Velocity at release, m/s.

    Returns
    -------
    s : ndarray of complex, shape (B, loop.order)
        s_j = ln(z_j)/T_s, sorted as in :func:`digital_roots` (roots at z = 0 have s = −inf and
        amplitude 0: they contribute at n < n₀ only).
    amplitude : ndarray of complex, shape (B, loop.order)
        a_j, m. Conjugate roots have conjugate amplitudes. Requires simple roots (a repeated
        root other than 0 gives inf/nan).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    T = loop.sample_time
    Af, Bf, Ef = loop.estimator.polynomials()
    fp, d = (Af, Bf), loop.delay_samples
    zp = zoh_plant(m, c, k, T)
    rts = _all_roots(zp, P, D, fp, d, T)
    z = rts.z
    Pc, Dc = P[:, None], D[:, None]
    _, dchi = _chi(z, zp, Pc, Dc, fp, d)
    N = zp.b1 * z + zp.b0
    Az, _ = _horner(Af, z)
    Ez, _ = _horner(Ef, z)
    geo = np.zeros_like(z)
    for j in range(1, d + 1):
        geo = geo + z**j
    Q = (
        z ** (d + 1) * Az * ((z - zp.phi[1, 1]) * x0 + zp.phi[0, 1] * v0)
        - Pc * x0 * Az * N * geo
        - Dc * x0 * Ez * N
    )
    zero = z == 0
    with np.errstate(all="ignore"):
        amp = np.where(zero, 0.0, Q / np.where(zero, 1.0, z * dchi))
    return rts.s, amp
