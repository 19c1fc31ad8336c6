r"""Cramér–Rao bound of (m, c, k) for a digital PHO set, sensor noise inside or outside the loop.

On a digital rig the controller reads the recorded, noisy encoder: the sensor noise enters the
loop as a force. Given the record that force is known (the controller law applied to the
recorded positions), so the likelihood is the **output error** (OE) of the plant driven by the
applied command, under white sensor noise (docs/design-notes/planning.md, "The in-loop bound").
:func:`inloop_cramer_rao` evaluates the expected Fisher information of that model exactly, or,
with ``noise_in_loop=False``, the dominant-mode bound of :mod:`phoid.planning.fisher` at the
sampled loop's exact dominant mode. All quantities in SI units (m, s, kg, N).

The loop and the record
-----------------------
The conventions of :mod:`phoid.dynamics.digital` and phoid's sampled simulator: controller
instants t_n = nT (T = ``loop.sample_time``) from the record's start; recorder rate
f_s = M/T (M whole ≥ 1), h = T/M; the recorded position x̃_j = x(jh) + b + e_j with e white
Gaussian of variance

    σ² = noise² + quantum²/12                                   (``sigma_eff``²)

(quantisation as uniform white noise); the controller reads x̃ at its instants,
u_n = −(P x̃_n + D v̂_n), v̂ = (B/A)x̃ the velocity estimator (``loop.estimator``, lfilter
coefficients b, a), so u = −K x̃ with K = (P A + D B)/A = K_n/A (polynomials in z⁻¹); the
plant m ẍ + c ẋ + k x = u(t) gets u_{n−d} on [nT, (n + 1)T) (zero-order hold, d whole periods).
The mass is held at x₀ — long enough before the record starts for the estimator to be at rest,
the commands −P x₀ queuing — and released with velocity v₀ at the controller instant
n_r = ``hold``/T. The bound is evaluated at the offset b = 0.

The output-error model
----------------------
Applied command u_{n−d} is computable from the record when x̃ at instants n − d − taps … n − d
lies in it (taps = ``loop.estimator.taps``; an IIR estimator's state there is a nuisance), so
run i's fitted window starts at the instant n₀ = max(n_r, d + taps) and ends with the record:
the default ``hold`` = (d + taps)T makes it start at the release. In the window the model is
the plant at rate h from its state y_s = (x, ẋ) at the window's first sample, driven by the
applied (held) command u_j:

    Δ_h(q) x_j = q[(q − Φ₂₂)x_s + Φ₁₂ẋ_s] + N_h(q) u_j,   μ_j = x_j + b,

with Φ = e^{A h}, Δ_h = z² − τz + δ and N_h = b₁z + b₀ the plant's ZOH pulse transfer at rate h
(exact, every damping). Its parameters: θ = (m, c, k); per run y_s and (IIR estimator, D ≠ 0)
the estimator's state, whose columns are the plant's response to −D·(the homogeneous
solutions of A); one offset b for the set. The sensitivities at fixed data follow by
differentiating the model (zoh derivatives by the Fréchet derivative of the block exponential):

    J_θ,j = [q(−∂Φ₂₂ x_s + ∂Φ₁₂ ẋ_s) δ_j + ∂N_h u_j − ∂Δ_h x_j] / Δ_h.

The expected information
------------------------
The true command and position are u = u_det + u_e, x = x_det + x_e: the noise-free closed loop
(from the release, deterministic) and the loop's response to the noise, linear in e. So
J_θ = J_det + R with R a linear filter of e, E[R] = 0, and the nuisance columns are
deterministic; with Π the projection on the nuisance columns the profiled information is

    I_θ = Schur_b( Σᵢ J_det,iᵀ(I − Π_i)J_det,i ) / σ²  +  Σᵢ E[R_iᵀR_i] / σ²
        = ``response_information``                     +  ``excitation_information``.

The random part is not projected (its nuisance share varies from record to record), and
E[RᵀR]/σ² does not depend on σ: as σ → 0 the bound falls as σ, as σ grows it tends to the
excitation term's — the noise in the loop is also a known excitation of the plant.

At the controller instants the noise's command is ũ = −z⁻ᵈK/(1 + z⁻ᵈKG) e = −z⁻ᵈK_nΔ_T/χ e
(χ the loop's characteristic polynomial, :func:`phoid.dynamics.digital.digital_coefficients`);
held M recorder samples and filtered by the sensitivity above it gives the impulse response g
(3 columns) of a noise at one controller instant. The noise at instants l ≥ n₀ − d (relative
to the release) reaches the plant inside the window; each gives the same response shifted by
lM samples, so

    E[RᵀR]/σ² ⊃ Σ_r g[r] g[r]ᵀ · #{l ≥ n₀ − d : lM + r in the window}

(r the lag; the count falls linearly with r — M > 1 counts only the controller's instants).
The older noise acts through the state s of the filter K_n/A when the release's commands are
computed: it adds ũ = −Σ_k s_k z⁻ᵏΔ_T/χ after the release, s Gaussian with the stationary
covariance of the filter's state (discrete Lyapunov equation). When the window starts after
the release (a hold shorter than the default), the noise at n_r − d ≤ l < n₀ − d also moves
the state at the window's start; each such instant, and the older noise's state, are taken
exactly through the model above (its y_s then random), one by one. No loop runs over samples:
every response is one :func:`scipy.signal.lfilter` call over all samples at once.

Noise outside the loop
----------------------
``noise_in_loop=False`` is the model of :mod:`phoid.planning.fisher` (each run's dominant mode
with offset, amplitude and phase nuisances, :func:`~phoid.planning.fisher.mode_information`)
at the sampled loop's exact dominant root and ∂s/∂θ
(:func:`phoid.dynamics.digital.digital_modes`) and its release amplitude w = 2a₀, a₀ the
dominant residue (:func:`phoid.dynamics.digital.digital_residues`); a run that does not ring
adds nothing, as there.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

import phoid._validate as v
from phoid.dynamics.digital import (
    DigitalPD,
    digital_coefficients,
    digital_modes,
    digital_residues,
    digital_roots,
    expm_stack,
    record_problem,
    zoh_plant,
)
from phoid.dynamics.plant import quadratic_roots
from phoid.planning.fisher import mode_information, safe_inverse

__all__ = ["MAX_LOOP_ORDER", "MAX_RUNS", "MAX_SAMPLES", "MAX_TOTAL_SAMPLES", "InLoopBound",
           "inloop_cramer_rao"]

MAX_RUNS = 1000
"""Most runs in one set (``phoid.design``'s limit too)."""
MAX_SAMPLES = 2_000_000
"""Most recorder samples of one run's record after the release (memory: a few arrays of it)."""
MAX_TOTAL_SAMPLES = 50_000_000
"""Most recorder samples of all runs together (time: ≈ 4 µs per sample in-loop)."""
MAX_LOOP_ORDER = 400
"""Highest degree d + r + 2 of a run's characteristic polynomial (its roots, for the stability
check and the dominant mode, cost ∝ degree³: about 1 s per run at 300)."""
_MARGINAL = 1e-12
"""A sampled loop whose largest |z| is within this of 1 neither decays nor grows to the
floating point's accuracy over a period: no bound (its modes are rounding)."""
_SLOW = 1e-8
"""Below this, c·T/m, k·T²/m and the gains' P·T²/m, D·T/m leave a sampled loop's poles
within rounding of 1 (its characteristic polynomial's coefficients differ by less than
about √ε): the mass, not the gains, is then why the loop is not stable."""
_MIN_WINDOW = 3
"""Fewest fitted samples of a run: its start state (x, ẋ) and one more."""
_MAX_GROWTH = math.log(1e8)  # an unstable plant's e^{p·duration}: rounding grows by as much
_CHUNK = 4_000_000  # floats per batch of responses taken through the window model at once


@dataclass(frozen=True)
class InLoopBound:
    """The Cramér–Rao bound of (m, c, k) for a digital PHO set (module docstring).

    Attributes
    ----------
    cov : ndarray, shape (3, 3)
        Covariance bound of (m, c, k): kg², (N·s/m)², (N/m)² and cross terms; ``inf`` on the
        diagonal where the set cannot determine a parameter (:func:`safe_inverse`).
    information : ndarray, shape (3, 3)
        Fisher information of (m, c, k), nuisances profiled; ``response_information +
        excitation_information``.
    run_information : ndarray, shape (n, 3, 3)
        Each run's information: its own nuisances profiled, the shared offset b taken as known
        (in-loop); Gᵢᵀ Iᵢ Gᵢ of the run's mode (outside). In-loop, their sum exceeds
        ``information`` by what profiling the shared offset costs.
    noise_in_loop : bool
        Which model: the output error with the noise in the loop, or the dominant modes.
    sigma_eff : float
        σ = √(noise² + quantum²/12), m: the white noise of the record (and, in-loop, the loop).
    response_information : ndarray, shape (3, 3)
        In-loop: the part carried by the noise-free response (J_det), ∝ 1/σ². Outside: all of
        ``information``.
    excitation_information : ndarray, shape (3, 3)
        In-loop: the part carried by the plant's response to the noise the loop turns into a
        force (E[RᵀR]/σ², independent of σ). Outside: zero.
    window_start : ndarray, shape (n,)
        Time from each run's release to its first fitted sample, s (0 with the default hold;
        0 outside).
    samples : ndarray of int, shape (n,)
        Fitted samples of each run.
    hold : float
        The hold recorded before each release, s (outside: as given, or the default).
    modes : ndarray of complex, shape (n,)
        Each run's dominant root −σᵢ + iω_dᵢ of the sampled loop, 1/s (Im ≥ 0).
    """

    cov: np.ndarray
    information: np.ndarray
    run_information: np.ndarray
    noise_in_loop: bool
    sigma_eff: float
    response_information: np.ndarray
    excitation_information: np.ndarray
    window_start: np.ndarray
    samples: np.ndarray
    hold: float
    modes: np.ndarray

    @property
    def stderr(self) -> np.ndarray:
        """Standard deviations of (m, c, k): kg, N·s/m, N/m."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


# --------------------------------------------------------------------------------------------
# inputs


def _bounded(name: str, a: np.ndarray, unit: str) -> np.ndarray:
    """``a`` unless some |value| exceeds :data:`phoid._validate.MAGNITUDE` (SI units)."""
    big = np.abs(a) > v.MAGNITUDE
    if np.any(big):
        raise ValueError(f"`{name}` must be of magnitude at most {v.MAGNITUDE:.0e} {unit} (SI "
                         f"units); got {a[big].flat[0]:g}")
    return a


def _not_bool(name: str, value) -> None:
    """A one-line refusal of a boolean (or boolean array) given for a number: True is not 1 m."""
    if isinstance(value, bool | np.bool_) or (
            isinstance(value, np.ndarray | list | tuple)
            and np.asarray(value, dtype=object).size
            and any(isinstance(e, bool | np.bool_)
                    for e in np.asarray(value, dtype=object).ravel())):
        raise ValueError(f"`{name}` must be a number, not a boolean; got {value!r}")


def _scalar(name: str, value, unit: str) -> float:
    return float(_bounded(name, np.array(v.finite(name, value, unit)), unit))


def _per_run(name: str, value, n: int, unit: str) -> np.ndarray:
    a = _bounded(name, v.finite_array(name, value), unit)
    if a.ndim > 1 or (a.ndim == 1 and a.size not in (1, n)):
        raise ValueError(f"`{name}` must be a scalar or one value per run ({n}); got shape "
                         f"{a.shape}")
    return np.broadcast_to(a.reshape(-1) if a.ndim else a, (n,)).astype(float)


def _gains(P, D) -> tuple[np.ndarray, np.ndarray]:
    P = np.atleast_1d(v.finite_array("P", P))
    D = np.atleast_1d(v.finite_array("D", D))
    if P.ndim != 1 or D.ndim != 1:
        raise ValueError(f"`P` and `D` must be scalars or 1-D arrays (one gain per run); got "
                         f"shapes {P.shape} and {D.shape}")
    if P.size == 0 or D.size == 0:
        raise ValueError("`P` and `D` must hold at least one run's gains; got none")
    if P.size != D.size and 1 not in (P.size, D.size):
        raise ValueError(f"`P` and `D` must have one entry per run; got {P.size} and {D.size}")
    if P.size > MAX_RUNS or D.size > MAX_RUNS:
        raise ValueError(f"`P` and `D` may hold at most {MAX_RUNS} runs; got "
                         f"{max(P.size, D.size)}")
    P, D = np.broadcast_arrays(_bounded("P", P, "N/m"), _bounded("D", D, "N·s/m"))
    return P.astype(float), D.astype(float)


def _whole_periods(name: str, value: float, per: float, what: str) -> int:
    n = round(value / per)
    if not abs(value / per - n) <= 1e-9 * max(1.0, abs(value / per)):
        raise ValueError(f"`{name}` = {value:g} s must be a whole number of {what} "
                         f"({per:g} s); got {value / per:.6g} of them")
    return int(n)


# --------------------------------------------------------------------------------------------
# the plant at the recorder's rate and its sensitivities


@dataclass(frozen=True)
class _Plant:
    """The plant's ZOH recursion at step h and its derivatives with respect to θ = (m, c, k)."""

    phi: np.ndarray  # (2, 2)
    gamma: np.ndarray  # (2,)
    dphi: np.ndarray  # (3, 2, 2)
    den: np.ndarray  # Δ_h in z⁻¹: [1, −τ, δ]
    num: np.ndarray  # N_h: [0, b₁, b₀]
    num_v: np.ndarray  # velocity's numerator: [0, Γ₂, Φ₂₁Γ₁ − Φ₁₁Γ₂]
    d_den: np.ndarray  # (3, 3): ∂Δ_h/∂θ = [0, −∂τ, ∂δ]
    d_num: np.ndarray  # (3, 3): ∂N_h/∂θ = [0, ∂b₁, ∂b₀]


def _plant(m: float, c: float, k: float, h: float) -> _Plant:
    """Φ = e^{Ah}, Γ and their θ-derivatives from one block exponential (as zoh_plant)."""
    X = np.zeros((3, 3))
    X[0, 1] = h
    X[1, 0] = -k / m * h
    X[1, 1] = -c / m * h
    X[1, 2] = h / m
    E = np.zeros((3, 3, 3))
    E[0, 1, :] = np.array([k / m**2, c / m**2, -1.0 / m**2]) * h
    E[1, 1, 1] = -h / m
    E[2, 1, 0] = -h / m
    big = np.zeros((4, 6, 6))
    big[:, :3, :3] = X
    big[:, 3:, 3:] = X
    big[1:, :3, 3:] = E
    ex = expm_stack(big)
    F, dF = ex[0, :3, :3], ex[1:, :3, 3:]
    phi, gam = F[:2, :2], F[:2, 2]
    dphi, dgam = dF[:, :2, :2], dF[:, :2, 2]
    tau = phi[0, 0] + phi[1, 1]
    det = phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0]
    b1 = gam[0]
    b0 = phi[0, 1] * gam[1] - phi[1, 1] * gam[0]
    d_tau = dphi[:, 0, 0] + dphi[:, 1, 1]
    d_det = (dphi[:, 0, 0] * phi[1, 1] + phi[0, 0] * dphi[:, 1, 1]
             - dphi[:, 0, 1] * phi[1, 0] - phi[0, 1] * dphi[:, 1, 0])
    d_b1 = dgam[:, 0]
    d_b0 = dphi[:, 0, 1] * gam[1] + phi[0, 1] * dgam[:, 1] - dphi[:, 1, 1] * gam[0] - (
        phi[1, 1] * dgam[:, 0])
    zero = np.zeros(3)
    return _Plant(
        phi=phi, gamma=gam, dphi=dphi,
        den=np.array([1.0, -tau, det]), num=np.array([0.0, b1, b0]),
        num_v=np.array([0.0, gam[1], phi[1, 0] * gam[0] - phi[0, 0] * gam[1]]),
        d_den=np.stack([zero, -d_tau, d_det], axis=1),
        d_num=np.stack([zero, d_b1, d_b0], axis=1),
    )


def _window(pl: _Plant, u: np.ndarray, y0: np.ndarray | None, j0: int, nw: int) -> np.ndarray:
    """The OE model's sensitivities J_θ (B, 3, nw) on the window [j0, j0 + nw).

    ``u`` (B, ≥ j0 + nw): the applied command at the recorder's samples from the release;
    ``y0`` (B, 2) the plant's state at the release (None: zero). The window model restarts at
    j0 from the true state there (module docstring).
    """
    from scipy.signal import lfilter

    nf = j0 + nw
    u = u[:, :nf]
    den = pl.den
    x = lfilter(pl.num, den, u, axis=-1)
    imp = np.zeros(nf)
    imp[0] = 1.0
    if y0 is not None:
        fx = np.stack([lfilter([1.0, -pl.phi[1, 1]], den, imp), lfilter([0.0, pl.phi[0, 1]],
                                                                        den, imp)])
        x = x + y0 @ fx
    if j0 > 0:
        vel = lfilter(pl.num_v, den, u[:, : j0 + 1], axis=-1)[:, j0]
        if y0 is not None:
            fv = np.array([lfilter([0.0, pl.phi[1, 0]], den, imp[: j0 + 1])[j0],
                           lfilter([1.0, -pl.phi[0, 0]], den, imp[: j0 + 1])[j0]])
            vel = vel + y0 @ fv
        ys = np.stack([x[:, j0], vel], axis=1)
    else:
        ys = y0 if y0 is not None else np.zeros((u.shape[0], 2))
    pu = lfilter([1.0], den, u[:, j0:], axis=-1)
    px = lfilter([1.0], den, x[:, j0:], axis=-1)
    pd = lfilter([1.0], den, imp[:nw])
    q = -pl.dphi[None, :, 1, 1] * ys[:, :1] + pl.dphi[None, :, 0, 1] * ys[:, 1:]  # (B, 3)
    J = np.zeros((u.shape[0], 3, nw))
    dn, dd = pl.d_num, pl.d_den
    J[:, :, 1:] = (dn[None, :, 1, None] * pu[:, None, :-1] - dd[None, :, 1, None]
                   * px[:, None, :-1] + q[:, :, None] * pd[None, None, :-1])
    J[:, :, 2:] += (dn[None, :, 2, None] * pu[:, None, :-2] - dd[None, :, 2, None]
                    * px[:, None, :-2])
    return J


def _held(uc: np.ndarray, M: int, n: int) -> np.ndarray:
    """Commands at the controller's instants (B, L) held over M recorder samples: (B, n)."""
    out = np.repeat(uc, M, axis=-1)[:, :n]
    if out.shape[1] < n:
        out = np.pad(out, ((0, 0), (0, n - out.shape[1])))
    return out


def _gram(J: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Σ_j J[:, :, j] J[:, :, j]ᵀ summed over the batch (and weighted per sample): (3, 3)."""
    if weights is None:
        return np.einsum("bij,bkj->ik", J, J)
    return np.einsum("bij,bkj,j->ik", J, J, weights)


def _orth(cols: np.ndarray) -> np.ndarray:
    """An orthonormal basis (nw, r) of the span of the nonzero columns (scale-free)."""
    norms = np.linalg.norm(cols, axis=0)
    keep = norms > 0
    if not keep.any():
        return np.zeros((cols.shape[0], 0))
    U, s, _ = np.linalg.svd(cols[:, keep] / norms[keep], full_matrices=False)
    return U[:, s > 1e-10 * s[0]]


# --------------------------------------------------------------------------------------------
# one run, in the loop


def _run_inloop(pl: _Plant, zT, P, D, loop: DigitalPD, chi: np.ndarray, *, M: int, n: int,
                n0: int, x0: float, v0: float, sig2: float):
    """Run's (θ, b) response Gram (4, 4) with its own nuisances profiled, and E[RᵀR]/σ²."""
    from scipy.linalg import solve_discrete_lyapunov
    from scipy.signal import lfilter

    d = loop.delay_samples
    bv, av = loop.estimator.coefficients()
    r = max(bv.size, av.size) - 1
    Kd = np.zeros(r + 1)
    Kd[: av.size] = av
    Kn = P * Kd
    Kn[: bv.size] += D * bv
    dT = np.array([1.0, -zT.tau, zT.delta])
    nT = np.array([0.0, zT.b1, zT.b0])
    phT = zT.phi
    j0, nw = n0 * M, n - n0 * M
    periods = -(-n // M) + 1
    # -- the noise-free closed loop from the release (module docstring of phoid.dynamics.digital)
    fr = np.array([x0, -phT[1, 1] * x0 + phT[0, 1] * v0])
    inner = np.convolve(fr, [1.0, -1.0])
    inner[: nT.size] -= P * x0 * nT
    inner[: dT.size] -= x0 * dT
    num = np.concatenate([np.zeros(d), np.convolve(Kn, inner)])
    imp = np.zeros(periods)
    imp[0] = 1.0
    u_app = -P * x0 - lfilter(num, np.convolve(chi, [1.0, -1.0]), imp)
    J = _window(pl, _held(u_app[None], M, n), np.array([[x0, v0]]), j0, nw)[0]
    # -- nuisance columns on the window: the start state, the estimator's state, then b
    impw = np.zeros(nw)
    impw[0] = 1.0
    cols = [lfilter([1.0, -pl.phi[1, 1]], pl.den, impw), lfilter([0.0, pl.phi[0, 1]], pl.den,
                                                                 impw)]
    ra = int(np.flatnonzero(av)[-1]) if av.size > 1 else 0
    if ra > 0 and D != 0.0:
        lw = -(-nw // M)
        impc = np.zeros(lw)
        impc[0] = 1.0
        for kk in range(ra):
            hom = lfilter(np.eye(ra)[kk], av, impc)
            cols.append(lfilter(pl.num, pl.den, _held(-D * hom[None], M, nw)[0]))
    Q = _orth(np.stack(cols, axis=1))
    A = np.vstack([J, np.ones((1, nw))])  # (4, nw): θ and the offset b
    A = A - (A @ Q) @ Q.T
    gram = A @ A.T
    # -- the loop's response to the noise: E[RᵀR]/σ² (σ-free)
    lag = nw + d * M  # lags r with a noise at l ≥ n0 − d that reaches the window
    ug = -lfilter(np.concatenate([np.zeros(d), np.convolve(Kn, dT)]), chi,
                  np.eye(1, -(-lag // M) + 1)[0])
    g = _window(pl, _held(ug[None], M, lag), None, 0, lag)
    rr = np.arange(lag)
    count = np.maximum((n - 1 - rr) // M - (n0 - d) + 1, 0).astype(float)
    exc = _gram(g, count)
    # older noise: the state s of K_n/A when the release's commands were computed
    if r > 0:
        Fm = np.zeros((r, r))
        Fm[:, 0] = -Kd[1:]
        Fm[np.arange(r - 1), np.arange(1, r)] = 1.0
        gv = Kn[1:] - Kd[1:] * Kn[0]
        S = solve_discrete_lyapunov(Fm, np.outer(gv, gv))
        if np.any(S != 0.0):
            uo = np.zeros((r, periods))
            for kk in range(r):
                e_k = np.zeros(periods)
                e_k[kk] = 1.0 if kk < periods else 0.0
                uo[kk] = -lfilter(dT, chi, e_k)
            Jo = _window(pl, _held(uo, M, n), None, j0, nw)
            exc += np.einsum("kl,kij,lmj->im", S, Jo, Jo)
    # noise at n_r − d ≤ l < n0 − d (a hold shorter than the default): one by one
    if n0 > 0:
        ugl = -lfilter(np.concatenate([np.zeros(d), np.convolve(Kn, dT)]), chi,
                       np.eye(1, periods + d)[0])
        ls = np.arange(-d, n0 - d)
        step = max(1, _CHUNK // (3 * n))
        for lo in range(0, ls.size, step):
            sl = ls[lo: lo + step]
            idx = np.arange(periods)[None, :] - sl[:, None]
            ub = np.where(idx >= 0, ugl[np.clip(idx, 0, ugl.size - 1)], 0.0)
            exc += _gram(_window(pl, _held(ub, M, n), None, j0, nw))
    return gram / sig2, exc


# --------------------------------------------------------------------------------------------
# the bound


def inloop_cramer_rao(
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    loop: DigitalPD,
    *,
    fs: float,
    duration: np.ndarray | float,
    noise: float,
    quantum: float = 0.0,
    x0: np.ndarray | float = 0.01,
    v0: np.ndarray | float = 0.0,
    hold: float | None = None,
    noise_in_loop: bool | None = True,
    window_start: int = 0,
) -> InLoopBound:
    """Cramér–Rao bound of (m, c, k) for a digital PHO set (module docstring: the models).

    Parameters
    ----------
    m, c, k : float
        The plant at which the bound is evaluated: kg (> 0), N·s/m, N/m.
    P, D : float or array_like, shape (n,)
        The runs' gains, N/m and N·s/m (``loop.P``, ``loop.D`` are ignored).
    loop : phoid.dynamics.digital.DigitalPD
        Sample time T, delay d (whole periods) and velocity estimator of the controller.
    fs : float
        Recorder rate, Hz: a whole multiple M of 1/T (a rig records M = 1).
    duration : float or array_like, shape (n,)
        Record length after each release, s: N = round(duration·fs) samples, the release's
        being the first.
    noise : float
        White sensor noise standard deviation, m (≥ 0).
    quantum : float, default 0
        The encoder's resolution, m (≥ 0): its rounding adds quantum²/12 to the variance.
    x0 : float or array_like, default 0.01
        The held position of each run, m.
    v0 : float or array_like, default 0
        The velocity at each release, m/s.
    hold : float, optional
        The time recorded before each release, s: a whole number of controller periods
        (the release falls on a controller instant). None: (d + taps)·T, the shortest that
        makes the first command applied after the release computable from the record, so
        that the window starts at the release. Shorter holds start the window later; longer
        ones change nothing (the samples of the hold are not fitted).
    window_start : int, default 0
        In-loop: the fit window's first sample, in controller periods after the release (at
        least the first whose applied command the record shows). 0: the whole response,
        as the likelihood allows; ``phoid identify``'s in-loop route starts its windows
        :data:`phoid.methods.inloop_route.MARGIN` (3) samples after a release it locates
        to the sample, 32 after one it detects from the data only, and this matches it.
    noise_in_loop : bool or None, default True
        True (and None, the default for a digital loop): the controller reads the noisy
        record; the output-error bound. False: the noise outside the loop; the dominant-mode
        bound at the sampled loop's exact modes.

    Returns
    -------
    InLoopBound

    Raises
    ------
    ValueError
        One line naming the parameter: m not in 1e-30 … 1e30 kg; c, k, gains, x0, v0 or fs
        not finite or over 1e30 in magnitude; gains of different lengths or more than
        :data:`MAX_RUNS` runs; a ``loop`` that is not a DigitalPD, whose timing the record
        cannot show (:func:`phoid.dynamics.digital.record_problem`) or of degree over
        :data:`MAX_LOOP_ORDER`; fs not a whole multiple of 1/T; a non-positive duration or
        more than :data:`MAX_SAMPLES` (:data:`MAX_TOTAL_SAMPLES`) samples; negative noise or
        quantum, both 0, or σ outside 1e-30 … 1e30 m; a hold that is not a time ≥ 0 of whole
        periods, or so short that no sample is left to fit; a record too short for the
        output-error fit (a run's window under 3 samples, or fewer than 4 + 2·runs samples in
        all); a boolean given for a number; a run whose sampled loop is not stable (the
        message names the cause: a mass too large for the loop's modes, negative damping, or
        gains that do not stabilise the plant); a plant unstable enough to grow by more than
        1e8 over the record (the OE sensitivities would be rounding); an information that
        overflows.

    Examples
    --------
    The README's overdamped plant on a 1 kHz loop with one period of delay, a 1 µm encoder
    with 0.2 µm noise, three runs of ``phoid.design(0.5, 40, 20, delay=0.002, ...)``: the
    bound with the noise in the loop, then outside it.

    >>> from phoid.dynamics.digital import DigitalPD
    >>> lp = DigitalPD(0.0, 0.0, 1e-3, 1)
    >>> P, D = [329.4, 532.5, 1113.3], [-34.81, -34.34, -32.52]
    >>> b = inloop_cramer_rao(0.5, 40, 20, P, D, lp, fs=1000, duration=10, noise=2e-7,
    ...                       quantum=1e-6)
    >>> [f"{s:.2g}" for s in b.stderr]
    ['8.4e-06', '0.00014', '0.0084']
    >>> o = inloop_cramer_rao(0.5, 40, 20, P, D, lp, fs=1000, duration=10, noise=2e-7,
    ...                       quantum=1e-6, noise_in_loop=False)
    >>> [f"{s:.2g}" for s in o.stderr]
    ['2.1e-06', '3.3e-05', '0.002']
    """
    for name, value in (("m", m), ("c", c), ("k", k), ("P", P), ("D", D), ("fs", fs),
                        ("duration", duration), ("noise", noise), ("quantum", quantum),
                        ("x0", x0), ("v0", v0)):
        _not_bool(name, value)
    m = v.physical("`m`", m, "kg")
    c = _scalar("c", c, "N·s/m")
    k = _scalar("k", k, "N/m")
    P, D = _gains(P, D)
    nr = P.size
    if not isinstance(loop, DigitalPD):
        raise ValueError(f"`loop` must be a phoid.DigitalPD; got {type(loop).__name__}")
    if noise_in_loop is None:
        noise_in_loop = True
    if not isinstance(noise_in_loop, bool | np.bool_):
        raise ValueError(f"`noise_in_loop` must be True, False or None; got {noise_in_loop!r}")
    noise_in_loop = bool(noise_in_loop)
    T = loop.sample_time
    d = loop.delay_samples
    fs = float(_bounded("fs", np.array(v.positive("fs", fs, "Hz")), "Hz"))
    M = round(fs * T)
    if M < 1 or not abs(fs * T - M) <= 1e-9 * max(1.0, fs * T):
        raise ValueError(f"`fs` must be a whole multiple of the controller rate 1/sample_time "
                         f"= {1.0 / T:g} Hz; got {fs:g} Hz (fs·sample_time = {fs * T:.6g})")
    dur = _per_run("duration", duration, nr, "s")
    if not np.all(dur > 0):
        raise ValueError(f"`duration` must be > 0 s; got {dur[~(dur > 0)][0]:g}")
    with np.errstate(over="ignore"):
        N = np.rint(dur * fs)
    if not (np.all(N <= MAX_SAMPLES) and np.sum(N) <= MAX_TOTAL_SAMPLES):
        raise ValueError(f"`duration` × fs must be at most {MAX_SAMPLES} samples per run and "
                         f"{MAX_TOTAL_SAMPLES} in all; got {float(np.max(N)):.4g} per run, "
                         f"{float(np.sum(N)):.4g} in all")
    N = np.maximum(N, 1).astype(np.int64)
    noise = v.nonnegative("noise", noise, "m")
    quantum = v.nonnegative("quantum", quantum, "m")
    sig = math.hypot(noise, quantum / math.sqrt(12.0))
    if not sig > 0:
        raise ValueError("`noise` and `quantum` are both 0: the bound is 0 (no noise); give "
                         "the sensor's noise (m)")
    if not 1.0 / v.MAGNITUDE <= sig <= v.MAGNITUDE:
        raise ValueError(f"`noise` (with `quantum`) gives σ = {sig:g} m; it must be of "
                         f"magnitude 1e-30 … 1e30 m (SI units)")
    x0a = _per_run("x0", x0, nr, "m")
    v0a = _per_run("v0", v0, nr, "m/s")
    taps = loop.estimator.taps
    if hold is None:
        n_r = d + taps
    else:
        if isinstance(hold, bool) or not isinstance(hold, numbers.Real):
            raise ValueError(f"`hold` must be a time in s (or None); got {hold!r}")
        hv = v.nonnegative("hold", hold, "s")
        n_r = _whole_periods("hold", hv, T, "controller periods")
    problem = record_problem(loop, float(np.min(N)) / fs)
    if problem is not None:
        raise ValueError(f"`loop.{problem[0]}`{problem[1]}")
    order = loop.order
    if order > MAX_LOOP_ORDER:
        raise ValueError(f"`loop.delay_samples` = {d} gives a loop of degree {order}, over "
                         f"{MAX_LOOP_ORDER} (its roots would take too long); use a coarser "
                         "sample time for the bound")
    with np.errstate(all="ignore"):  # a loop beyond the floating point is refused below
        chis = digital_coefficients(m, c, k, P, D, loop)
    over = np.flatnonzero(~np.all(np.isfinite(chis), axis=1))
    if over.size:
        i = int(over[0])
        raise ValueError(f"`m`, `c`, `k` = {m:g}, {c:g}, {k:g} with run {i}'s `P`, `D` = "
                         f"{P[i]:g}, {D[i]:g}: the sampled loop's polynomial overflows the "
                         "floating point")
    with np.errstate(all="ignore"):
        rts = digital_roots(m, c, k, P, D, loop)
        zmax = np.max(np.abs(rts.z), axis=1)
    bad = np.flatnonzero(~(zmax < 1.0 - _MARGINAL))
    if bad.size:
        raise ValueError(_unstable_cause(m, c, k, P, D, int(bad[0]), float(zmax[bad[0]]), T))
    modes = rts.dominant
    if not noise_in_loop:
        with np.errstate(all="ignore"):
            out = _outside(m, c, k, P, D, loop, fs=fs, N=N, sig=sig, x0=x0a, v0=v0a,
                           hold=n_r * T)
        _finite(out.run_information, m, c, k, sig)
        return out
    if isinstance(window_start, bool | np.bool_) or not isinstance(
            window_start, numbers.Integral) or not 0 <= int(window_start) <= MAX_SAMPLES:
        raise ValueError(f"`window_start` must be a whole number of controller periods 0 … "
                         f"{MAX_SAMPLES}; got {window_start!r}")
    # the window's first instant, from the release
    n0 = max(0, d + taps - n_r, int(window_start))
    nw = N - n0 * M
    short = np.flatnonzero((nw >= 1) & (nw < _MIN_WINDOW))
    if short.size or (np.all(nw >= 1) and int(np.sum(nw)) < 4 + 2 * nr):
        i = int(short[0]) if short.size else int(np.argmin(nw))
        raise ValueError(f"`duration` = {dur[i]:g} s: run {i}'s record is too short for the "
                         f"bound: {int(nw[i])} sample(s) fitted (at least {_MIN_WINDOW} a run, "
                         f"its start state and one more, and {4 + 2 * nr} in all: m, c, k, the "
                         "offset and each run's start state); record longer")
    if not np.all(nw >= 1):
        i = int(np.flatnonzero(nw < 1)[0])
        raise ValueError(f"`hold` = {n_r * T:g} s: the first command computable from the "
                         f"record reaches the plant {n0 * T:g} s after the release, at or after "
                         f"the end of run {i}'s record ({dur[i]:g} s); hold for "
                         f"{(d + taps) * T:g} s or record longer (`duration`)")
    grow = float(np.max(quadratic_roots(m, c, k).real)) * float(np.max(N)) / fs
    if grow > _MAX_GROWTH:
        raise ValueError(f"`k` = {k:g} N/m, `c` = {c:g} N·s/m: the plant alone is unstable and "
                         f"its output-error sensitivities grow by e^{grow:.3g} over the "
                         f"record, beyond the e^{_MAX_GROWTH:.3g} the bound computes to "
                         "accuracy; shorten `duration`")
    with np.errstate(all="ignore"):
        pl = _plant(m, c, k, T / M)
        zT = zoh_plant(m, c, k, T)
    sig2 = sig * sig
    grams = np.empty((nr, 4, 4))
    excs = np.empty((nr, 3, 3))
    with np.errstate(all="ignore"):  # overflow is refused below, naming the inputs
        for i in range(nr):
            grams[i], excs[i] = _run_inloop(pl, zT, P[i], D[i], loop, chis[i], M=M,
                                            n=int(N[i]), n0=n0, x0=x0a[i], v0=v0a[i],
                                            sig2=sig2)
    _finite(grams, m, c, k, sig)
    _finite(excs, m, c, k, sig)
    total = grams.sum(axis=0)
    resp = total[:3, :3].copy()
    if total[3, 3] > 0:
        resp -= np.outer(total[:3, 3], total[3, :3]) / total[3, 3]
    resp = 0.5 * (resp + resp.T)
    exc = excs.sum(axis=0)
    exc = 0.5 * (exc + exc.T)
    info = resp + exc
    return InLoopBound(
        cov=safe_inverse(info),
        information=info,
        run_information=grams[:, :3, :3] + excs,
        noise_in_loop=True,
        sigma_eff=sig,
        response_information=resp,
        excitation_information=exc,
        window_start=np.full(nr, n0 * T),
        samples=nw.astype(np.int64),
        hold=n_r * T,
        modes=modes,
    )


def _unstable_cause(m: float, c: float, k: float, P: np.ndarray, D: np.ndarray, i: int,
                    zmax: float, T: float) -> str:
    """Why run ``i``'s sampled loop is not stable, worded by its cause: a mass so large that
    the loop's slowest mode cannot decay within a period's rounding, a plant that feeds
    energy in (c < 0), or gains that do not stabilise the plant."""
    head = (f"run {i}'s sampled loop is not stable (largest |z| = {zmax:.6g}; `m`, `c`, `k` "
            f"= {m:g}, {c:g}, {k:g}, `P`, `D` = {P[i]:g}, {D[i]:g})")
    # what the damping, stiffness and gains change in a period, relative to the mass
    per_period = max(abs(c) * T, abs(k) * T * T, abs(float(P[i])) * T * T,
                     abs(float(D[i])) * T) / m
    if per_period < _SLOW:
        return (f"{head}: `m` = {m:g} kg is so large that `c`, `k` and the gains move it by "
                f"{per_period:.2g} of itself a period ({T:g} s), below the floating point's "
                "accuracy for the loop's modes; give m, c, k in SI units")
    if c < 0:
        return (f"{head}: the plant's damping `c` = {c:g} N·s/m is negative (it feeds energy "
                f"in), and run {i}'s `P`, `D` do not remove it")
    return f"{head}: the gains `P`, `D` of run {i} do not stabilise the plant"


def _finite(a: np.ndarray, m: float, c: float, k: float, sig: float) -> None:
    """A one-line refusal where the information overflows the floating point."""
    if not np.all(np.isfinite(a)):
        raise ValueError(f"`m`, `c`, `k` = {m:g}, {c:g}, {k:g} with σ = {sig:g} m: the "
                         "information of (m, c, k) overflows the floating point (the plant, "
                         "gains, x0 and noise are too far apart in scale for this bound)")


def _outside(m, c, k, P, D, loop, *, fs, N, sig, x0, v0, hold) -> InLoopBound:
    """The dominant-mode bound of :mod:`phoid.planning.fisher` at the sampled loop's modes."""
    nr = P.size
    s, ds = digital_modes(m, c, k, P, D, loop)
    # the residues are linear in (x0, v0): the dominant one (first) for a unit x0 and v0
    _, ax = digital_residues(m, c, k, P, D, loop, x0=1.0, v0=0.0)
    _, av = digital_residues(m, c, k, P, D, loop, x0=0.0, v0=1.0)
    amp = 2.0 * (x0 * ax[:, 0] + v0 * av[:, 0])
    rings = s.imag > 0
    info = np.zeros((nr, 2, 2))
    if np.any(rings):
        info[rings] = mode_information(s[rings], amp[rings], fs=fs, duration=N[rings] / fs,
                                       noise=sig)
    G = np.stack([-ds.real, ds.imag], axis=1)  # ∂(σ, ω_d)/∂(m, c, k)
    run_info = np.einsum("nai,nab,nbj->nij", G, info, G)
    total = run_info.sum(axis=0)
    total = 0.5 * (total + total.T)
    return InLoopBound(
        cov=safe_inverse(total),
        information=total,
        run_information=run_info,
        noise_in_loop=False,
        sigma_eff=sig,
        response_information=total,
        excitation_information=np.zeros((3, 3)),
        window_start=np.zeros(nr),
        samples=N.astype(np.int64),
        hold=hold,
        modes=s,
    )
