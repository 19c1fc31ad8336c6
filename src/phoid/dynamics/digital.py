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
2. estimates the velocity, either by the **backward difference**
   v̂_n = (x_n − x_{n−1})/T_s, or by the **filtered** backward difference
   v̂_n = a v̂_{n−1} + (1 − a)(x_n − x_{n−1})/T_s with a = e^{−ω_c T_s}: a first-order low pass
   of cut-off ω_c (rad/s) whose pole is mapped exactly (z = e^{−ω_c T_s}) and whose DC gain is 1.
   The backward difference is its ω_c → ∞ limit, a = 0; both are written with
   c_f = (1 − a)/T_s, v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1});
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

The controller is K(z) = P + D c_f (z − 1)/(z − a), the delay z^{−d}; the closed loop
1 + z^{−d} K(z) G(z) = 0 is the polynomial equation of degree d + 3 (monic)

    χ(z) = z^d (z − a) Δ(z) + [P (z − a) + D c_f (z − 1)] N(z) = 0.

It is exact: no approximation of the delay, the hold or the difference quotient. Each root z_j
is a mode z_j^n of the loop at the sample instants; its continuous-time rate is
s_j = ln(z_j)/T_s (principal branch, |Im s_j| ≤ π/T_s), s_j = −σ_j + iω_{d,j} as in the paper's
eqs. (2)–(15). The loop is stable when every |z_j| < 1.

The response at the sample instants
-----------------------------------
Released at a controller instant from a held position x₀ (the controller running meanwhile, so
x_{−1} = x₀, v̂_{−1} = 0 and the queued commands are −P x₀) with velocity v₀, the z-transform of
x_n is X(z) = Q(z)/χ(z) with

    Q(z) = z^{d+1}(z − a)[(z − Φ₂₂) x₀ + Φ₁₂ v₀] − P x₀ (z − a) N(z) Σ_{j=1}^{d} z^j
           + D c_f x₀ z N(z),

so, for simple roots, x_n = Σ_j a_j z_j^n exactly for every n ≥ 0 (n ≥ 1 when χ(0) = 0,
e.g. D = 0 with the backward difference), a_j = Q(z_j)/(z_j χ′(z_j))
(:func:`digital_residues`). A decay fit of a record taken at the controller's instants therefore
measures s_j = ln(z_j)/T_s exactly: the sampled loop *is* a sum of damped sinusoids there, with
the rates of this module, not an approximation of a continuous loop.

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
from dataclasses import dataclass

import numpy as np

from phoid import _validate as v
from phoid.dynamics.plant import quadratic_roots

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
    "zoh_plant",
]

VELOCITY_ESTIMATORS = ("backward-difference", "filtered")


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
    (the module docstring gives the velocity estimators and the exact loop).

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
    velocity : {"backward-difference", "filtered"}
        Velocity estimator: v̂_n = (x_n − x_{n−1})/T_s, or that difference low-pass filtered,
        v̂_n = a v̂_{n−1} + (1 − a)(x_n − x_{n−1})/T_s with a = e^{−ω_c T_s}.
    cutoff : float, optional
        The filter's cut-off ω_c, rad/s (> 0); required with ``velocity="filtered"`` and
        refused otherwise.

    Raises
    ------
    ValueError
        Naming the parameter, for a non-finite gain, a non-positive sample time, a delay that is
        not a whole number ≥ 0, an unknown estimator or a missing/superfluous cut-off.
    """

    P: float
    D: float
    sample_time: float
    delay_samples: int = 0
    velocity: str = "backward-difference"
    cutoff: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "P", v.finite("P", self.P, "N/m"))
        object.__setattr__(self, "D", v.finite("D", self.D, "N·s/m"))
        object.__setattr__(self, "sample_time", v.positive("sample_time", self.sample_time, "s"))
        object.__setattr__(self, "delay_samples", _delay_samples(self.delay_samples))
        if self.velocity not in VELOCITY_ESTIMATORS:
            raise ValueError(
                f"`velocity` must be one of {', '.join(map(repr, VELOCITY_ESTIMATORS))}; "
                f"got {self.velocity!r}"
            )
        if self.velocity == "filtered":
            if self.cutoff is None:
                raise ValueError(
                    "`cutoff` (rad/s) is required with velocity='filtered'; got None"
                )
            object.__setattr__(self, "cutoff", v.positive("cutoff", self.cutoff, "rad/s"))
        elif self.cutoff is not None:
            raise ValueError(
                "`cutoff` applies only to velocity='filtered' (the backward difference has no "
                f"filter); got cutoff={self.cutoff!r} with velocity={self.velocity!r}"
            )

    @property
    def filter_pole(self) -> float:
        """a = e^{−ω_c T_s} (0 for the backward difference), dimensionless."""
        if self.velocity == "filtered":
            return math.exp(-self.cutoff * self.sample_time)
        return 0.0

    @property
    def filter_gain(self) -> float:
        """c_f = (1 − a)/T_s, 1/s: v̂_n = a v̂_{n−1} + c_f (x_n − x_{n−1})."""
        if self.velocity == "filtered":
            return -math.expm1(-self.cutoff * self.sample_time) / self.sample_time
        return 1.0 / self.sample_time

    @property
    def delay(self) -> float:
        """The command delay d·T_s, s (the ZOH and the difference add about T_s/2 each)."""
        return self.delay_samples * self.sample_time

    @property
    def order(self) -> int:
        """Degree of the characteristic polynomial, d + 3."""
        return self.delay_samples + 3


def record_problem(loop: DigitalPD, span: float) -> tuple[str, str] | None:
    """What a record of ``span`` seconds after the release cannot show of ``loop``, or None.

    A sample time longer than the record (the controller never samples the motion), a command
    delay d·T_s longer than it (the command never reaches the plant within it; the loop's
    polynomial would have degree d + 3) or a velocity filter whose time constant 1/ω_c is longer
    than it (the filtered velocity hardly moves: the D term is not in the record).

    Returns
    -------
    tuple of str or None
        (key, reason): the :class:`DigitalPD` field at fault and the rest of a one-line message
        (it begins with `` = value``).
    """
    if not (math.isfinite(span) and span > 0):
        return None
    T = loop.sample_time
    if T > span:
        return ("sample_time", f" = {T:g} s is longer than the record ({span:.4g} s): the "
                               "controller would not sample it")
    if loop.delay_samples * T > span:
        return ("delay_samples", f" = {loop.delay_samples} periods ({loop.delay_samples * T:.4g} "
                                 f"s at sample_time {T:g} s) is longer than the record "
                                 f"({span:.4g} s): the command would never reach the plant")
    if loop.velocity == "filtered" and loop.cutoff * span < 1.0:
        return ("cutoff", f" = {loop.cutoff:g} rad/s: the velocity filter's time constant "
                          f"1/cutoff = {1.0 / loop.cutoff:.3g} s is longer than the record "
                          f"({span:.4g} s), so the filtered velocity would hardly move; is it "
                          "in rad/s?")
    return None


# --------------------------------------------------------------------------------------------
# zero-order-hold discretisation of the plant


def expm_stack(M: np.ndarray) -> np.ndarray:
    """e^M for a stack (G, n, n) of small matrices: scaling and squaring of a Taylor series.

    After scaling to ‖M/2^s‖₁ ≤ 1/2, 20 Taylor terms leave < 1e-25 of truncation, and the s
    squarings cost a few ulps. Plain matrix products only: no LAPACK call, whose thread pool
    would otherwise wake up on every simulation (costly on a busy machine).
    """
    nrm = float(np.max(np.sum(np.abs(M), axis=-2))) if M.size else 0.0
    s = max(0, math.ceil(math.log2(nrm / 0.5))) if nrm > 0.5 else 0
    X = M / 2.0**s
    n = M.shape[-1]
    E = np.broadcast_to(np.eye(n), M.shape).copy()
    term = E.copy()
    for i in range(1, 21):
        term = np.matmul(term, X) / i
        E += term
    for _ in range(s):
        E = np.matmul(E, E)
    return E


@dataclass(frozen=True)
class ZOHPlant:
    """Zero-order-hold discretisation of m x'' + c x' + k x = u over one sample time.

    Attributes
    ----------
    phi : ndarray, shape (2, 2)
        Φ = e^{AT_s} (state y = (x, ẋ)).
    gamma : ndarray, shape (2,)
        Γ = ∫₀^{T_s} e^{Aτ}dτ b, (m, m/s) per N.
    lam : ndarray, shape (2,)
        Eigenvalues of Φ, e^{p T_s} with p the plant's roots (eqs. 2–15): Δ(z) = (z−λ₁)(z−λ₂).
    tau, delta : float
        τ = tr Φ and δ = det Φ = e^{−cT_s/m} (Δ(z) = z² − τz + δ).
    b1, b0 : float
        N(z) = b₁z + b₀, m/N: b₁ = Γ₁, b₀ = Φ₁₂Γ₂ − Φ₂₂Γ₁.
    d_tau, d_delta, d_b1, d_b0 : ndarray, shape (3,) or None
        Their derivatives with respect to (m, c, k) when requested.
    """

    phi: np.ndarray
    gamma: np.ndarray
    lam: np.ndarray
    tau: float
    delta: float
    b1: float
    b0: float
    d_tau: np.ndarray | None = None
    d_delta: np.ndarray | None = None
    d_b1: np.ndarray | None = None
    d_b0: np.ndarray | None = None


def zoh_plant(
    m: float, c: float, k: float, sample_time: float, *, derivatives: bool = False
) -> ZOHPlant:
    """Exact ZOH discretisation Φ = e^{AT_s}, Γ = ∫₀^{T_s}e^{Aτ}dτ b of the plant (eq. 1).

    Φ and Γ come from one exponential of the augmented matrix [[A, b], [0, 0]]·T_s, valid for
    every damping (eqs. 2–15 all follow from e^{At}); their derivatives with respect to
    θ = (m, c, k) from the block-triangular exponential exp([[X, E], [0, X]]) whose upper-right
    block is the Fréchet derivative of e^X in the direction E = (∂[[A, b], [0, 0]]/∂θ)·T_s.

    Parameters
    ----------
    m, c, k : float
        Mass (kg, > 0), damping (N·s/m) and stiffness (N/m); c and k may have any sign (fits).
    sample_time : float
        T_s, s.
    derivatives : bool, default False
        Also return ∂(τ, δ, b₁, b₀)/∂(m, c, k).

    Returns
    -------
    ZOHPlant
    """
    T = sample_time
    X = np.zeros((3, 3))
    X[0, 1] = T
    X[1, 0] = -k / m * T
    X[1, 1] = -c / m * T
    X[1, 2] = T / m
    if derivatives:
        E = np.zeros((3, 3, 3))
        E[0, 1, :] = np.array([k / m**2, c / m**2, -1.0 / m**2]) * T  # ∂/∂m of row 1
        E[1, 1, 1] = -T / m  # ∂/∂c
        E[2, 1, 0] = -T / m  # ∂/∂k
        big = np.zeros((4, 6, 6))
        big[:, :3, :3] = X
        big[:, 3:, 3:] = X
        big[1:, :3, 3:] = E
        ex = expm_stack(big)
        F = ex[0, :3, :3]
        dF = ex[1:, :3, 3:]  # (3, 3, 3): ∂ exp / ∂θ_j
    else:
        F = expm_stack(X[None])[0]
    phi = F[:2, :2].copy()
    gamma = F[:2, 2].copy()
    p = quadratic_roots(m, c, k)
    lam = np.exp(p * T)
    tau = float(phi[0, 0] + phi[1, 1])
    delta = float(phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0])
    b1 = float(gamma[0])
    b0 = float(phi[0, 1] * gamma[1] - phi[1, 1] * gamma[0])
    if not derivatives:
        return ZOHPlant(phi, gamma, lam, tau, delta, b1, b0)
    dphi = dF[:, :2, :2]
    dgam = dF[:, :2, 2]
    d_tau = dphi[:, 0, 0] + dphi[:, 1, 1]
    # δ = e^{−cT/m} exactly (Liouville): its derivatives in closed form
    d_delta = delta * np.array([c * T / m**2, -T / m, 0.0])
    d_b1 = dgam[:, 0].copy()
    d_b0 = dphi[:, 0, 1] * gamma[1] + phi[0, 1] * dgam[:, 1] - dphi[:, 1, 1] * gamma[0] - (
        phi[1, 1] * dgam[:, 0]
    )
    return ZOHPlant(phi, gamma, lam, tau, delta, b1, b0, d_tau, d_delta, d_b1, d_b0)


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


def characteristic_coefficients(zp: ZOHPlant, P, D, a: float, cf: float, d: int) -> np.ndarray:
    """Coefficients of χ (highest power first), shape (B, d + 4)."""
    B = P.size
    coef = np.zeros((B, d + 4))
    coef[:, 0] = 1.0
    coef[:, 1] = -(zp.tau + a)
    coef[:, 2] = zp.delta + a * zp.tau
    coef[:, 3] = -a * zp.delta
    k1 = P + D * cf  # Kn(z) = k1 z + k0
    k0 = -(P * a + D * cf)
    coef[:, -3] += k1 * zp.b1
    coef[:, -2] += k1 * zp.b0 + k0 * zp.b1
    coef[:, -1] += k0 * zp.b0
    return coef


def digital_coefficients(
    m: float, c: float, k: float, P: np.ndarray | float, D: np.ndarray | float, loop: DigitalPD
) -> np.ndarray:
    """Coefficients of the characteristic polynomial χ(z), highest power first.

    χ(z) = z^d (z − a)(z² − τz + δ) + [P(z − a) + D c_f (z − 1)](b₁z + b₀) (module docstring).

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
    ndarray, shape (B, d + 4)
        Monic, dimensionless; ``np.roots(coef[i])`` are run i's closed-loop z-roots.
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    zp = zoh_plant(m, c, k, loop.sample_time)
    return characteristic_coefficients(zp, P, D, loop.filter_pole,
                                       loop.filter_gain, loop.delay_samples)


def _chi(z, zp: ZOHPlant, P, D, a, cf, d):
    """χ(z) and χ′(z) in factored form (accurate near the plant poles λ)."""
    z = np.asarray(z, dtype=complex)
    l1, l2 = zp.lam
    delta_z = (z - l1) * (z - l2)
    ddelta_z = 2.0 * z - (l1 + l2)
    A = (z - a) * delta_z
    dA = delta_z + (z - a) * ddelta_z
    N = zp.b1 * z + zp.b0
    k1 = P + D * cf
    Kn = k1 * z - (P * a + D * cf)
    zd = z**d
    dzd = d * z ** (d - 1) if d > 0 else 0.0
    chi = zd * A + Kn * N
    dchi = dzd * A + zd * dA + k1 * N + Kn * zp.b1
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
    return _chi(z, zp, P, D, loop.filter_pole, loop.filter_gain, loop.delay_samples)


# --------------------------------------------------------------------------------------------
# roots


@dataclass(frozen=True)
class DigitalRoots:
    """All closed-loop roots of B runs' sampled loops.

    Attributes
    ----------
    z : ndarray of complex, shape (B, d + 3)
        Roots of χ, sorted by decreasing |z| (decreasing Re s); of a conjugate pair the one
        with positive imaginary part first.
    s : ndarray of complex, shape (B, d + 3)
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
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(z) / T


def _polish(z, zp, P, D, a, cf, d, iters=3):
    """Newton steps on the factored χ, each kept only where it lowers |χ|."""
    chi, dchi = _chi(z, zp, P, D, a, cf, d)
    for _ in range(iters):
        with np.errstate(all="ignore"):
            zn = z - chi / dchi
        chin, dchin = _chi(zn, zp, P, D, a, cf, d)
        better = np.isfinite(zn) & (np.abs(chin) < np.abs(chi))
        if not better.any():
            break
        z = np.where(better, zn, z)
        chi = np.where(better, chin, chi)
        dchi = np.where(better, dchin, dchi)
    return z


def _all_roots(zp: ZOHPlant, P, D, a, cf, d, T) -> DigitalRoots:
    coef = characteristic_coefficients(zp, P, D, a, cf, d)
    B, n = P.size, d + 3
    comp = np.zeros((B, n, n))
    comp[:, 0, :] = -coef[:, 1:]
    idx = np.arange(1, n)
    comp[:, idx, idx - 1] = 1.0
    z = np.linalg.eigvals(comp).astype(complex)
    z = _polish(z, zp, P[:, None], D[:, None], a, cf, d)
    s = _log_s(z, T)
    order = np.lexsort((-z.imag, -np.round(np.abs(z), 12)), axis=-1)
    z = np.take_along_axis(z, order, axis=1)
    s = np.take_along_axis(s, order, axis=1)
    dom = s[:, 0].real + 1j * np.abs(s[:, 0].imag)
    return DigitalRoots(z, s, dom, T)


def digital_roots(
    m: float, c: float, k: float, P: np.ndarray | float, D: np.ndarray | float, loop: DigitalPD
) -> DigitalRoots:
    """All d + 3 closed-loop roots of each run's sampled loop, and the dominant one.

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
        ``z``, ``s`` (B, d + 3) sorted by decreasing real part of s, ``dominant`` (B,) and
        ``stable`` (B,).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    zp = zoh_plant(m, c, k, loop.sample_time)
    return _all_roots(zp, P, D, loop.filter_pole, loop.filter_gain, loop.delay_samples,
                      loop.sample_time)


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
        ∂χ/∂θ = z^d (z − a)(−z ∂τ/∂θ + ∂δ/∂θ) + [P(z − a) + D c_f(z − 1)](z ∂b₁/∂θ + ∂b₀/∂θ).

    Notes
    -----
    Tracked roots are not certified here; :func:`digital_is_dominant` checks a solution
    (exactly: the loop has d + 3 roots).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    T = loop.sample_time
    a, cf, d = loop.filter_pole, loop.filter_gain, loop.delay_samples
    zp = zoh_plant(m, c, k, T, derivatives=True)
    if s_guess is None:
        s0 = _all_roots(zp, P, D, a, cf, d, T).dominant
        z = np.exp(s0 * T)
        ref = s0
    else:
        ref = np.broadcast_to(np.asarray(s_guess, dtype=complex), P.shape)
        z = np.exp(ref * T)
        for _ in range(40):
            chi, dchi = _chi(z, zp, P, D, a, cf, d)
            with np.errstate(all="ignore"):
                step = chi / dchi
            z = z - step
            # quadratic convergence: a step of 1e-12 |z| leaves an error at rounding level
            if np.all(np.abs(step) <= 1e-12 * np.abs(z)):
                break
        chi, dchi = _chi(z, zp, P, D, a, cf, d)
        with np.errstate(all="ignore"):
            ok = np.isfinite(z) & (np.abs(chi) <= 1e-10 * np.abs(dchi * z))
        if not ok.all():  # a start that went astray: the dominant root from all roots
            dom = _all_roots(zp, P[~ok], D[~ok], a, cf, d, T).dominant
            z = z.copy()
            z[~ok] = np.exp(dom * T)
    z = _polish(z, zp, P, D, a, cf, d, iters=2)
    _, dchi = _chi(z, zp, P, D, a, cf, d)
    zd = z**d
    Kn = (P + D * cf) * z - (P * a + D * cf)
    dth = (
        zd[:, None] * (z - a)[:, None] * (-z[:, None] * zp.d_tau + zp.d_delta)
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
    instant): x(nT_s) = Σ_j a_j z_j^n exactly for n ≥ 0 (n ≥ 1 if χ(0) = 0), with
    a_j = Q(z_j)/(z_j χ′(z_j)) and Q the numerator of the module docstring.

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
    s : ndarray of complex, shape (B, d + 3)
        s_j = ln(z_j)/T_s, sorted as in :func:`digital_roots` (roots at z = 0 have s = −inf and
        amplitude 0: they contribute at n = 0 only).
    amplitude : ndarray of complex, shape (B, d + 3)
        a_j, m. Conjugate roots have conjugate amplitudes. Requires simple roots (a repeated
        root gives inf/nan).
    """
    _check_loop(loop)
    m = v.positive("m", m, "kg")
    P, D = _gains(P, D)
    T = loop.sample_time
    a, cf, d = loop.filter_pole, loop.filter_gain, loop.delay_samples
    zp = zoh_plant(m, c, k, T)
    rts = _all_roots(zp, P, D, a, cf, d, T)
    z = rts.z
    Pc, Dc = P[:, None], D[:, None]
    _, dchi = _chi(z, zp, Pc, Dc, a, cf, d)
    N = zp.b1 * z + zp.b0
    geo = np.zeros_like(z)
    for j in range(1, d + 1):
        geo = geo + z**j
    Q = (
        z ** (d + 1) * (z - a) * ((z - zp.phi[1, 1]) * x0 + zp.phi[0, 1] * v0)
        - Pc * x0 * (z - a) * N * geo
        + Dc * cf * x0 * z * N
    )
    zero = z == 0
    with np.errstate(all="ignore"):
        amp = np.where(zero, 0.0, Q / np.where(zero, 1.0, z * dchi))
    return rts.s, amp
