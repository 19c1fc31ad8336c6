r"""Zero-order-hold discretisation of the plant over one controller period, and its derivatives.

The sampled loops of :mod:`phoid.dynamics.digital` (and the in-loop models built on it) hold the
command constant over each period: with y = (x, ẋ), y' = A y + b u, A = [[0, 1], [−k/m, −c/m]],
b = (0, 1/m) (seed eq. 1 in state form) a constant input over T_s gives exactly
y_{n+1} = Φ y_n + Γ u, Φ = e^{AT_s}, Γ = ∫₀^{T_s} e^{Aτ} dτ b (:func:`zoh_plant`), computed by
:func:`expm_stack` without LAPACK.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phoid.dynamics.plant import quadratic_roots

__all__ = ["ZOHPlant", "expm_stack", "zoh_plant"]



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
