"""Cramér–Rao standard deviations of (m, c, k) for a PHO experiment set (benchmark helper).

The model is the one stated in the sample sets' truth.json ``crb_sd`` notes
(examples/paper-sample/truth.json, whose numbers this module computes, and the project's
../shared/data/truth.json): every run i records,
from its release on (τ = t − t_release ≥ 0), a single dominant mode

    x_i(τ) = o_i + e^{−σ_i τ} (a_i cos ω_i τ + b_i sin ω_i τ) + white noise of sd s,

with the amplitude and phase (a_i, b_i) and the offset o_i unknown per run and the loop delay Δt
known. σ_i and ω_i are functions of θ = (m, c, k) through the dominant root s_i = −σ_i + iω_i of
the delayed loop's characteristic function (eq. 23)

    f(s) = m s² + c s + k + (D_i s + P_i) e^{−sΔt} = 0.

Fisher information (white Gaussian noise): I = Jᵀ J / s² with J the derivatives of the samples.

* Per run, the 5 × 5 information of (σ, ω, a, b, o) is computed from the analytic derivatives of
  the model at the sample times, and the nuisance parameters (a, b, o) are profiled out by a
  Schur complement, leaving the 2 × 2 information of (σ_i, ω_i).
* Chain rule to θ: by implicit differentiation of f(s_i; θ) = 0,
  ∂s_i/∂θ_j = −(∂f/∂θ_j)/f′(s_i) with ∂f/∂m = s², ∂f/∂c = s, ∂f/∂k = 1, so
  ∂σ_i/∂θ = −Re ∂s_i/∂θ and ∂ω_i/∂θ = Im ∂s_i/∂θ; I_θ = Σ_i G_iᵀ I_i G_i.
* CRB sd = s · √diag(I_θ⁻¹).

The information is "numerical" in that it is summed over the actual sample grid (no continuous-
time approximation). The true amplitude and phase of run i are those of the dominant mode of the
exact response to a release from a held position x₀ (history x = x₀ on [−Δt, 0]): its residue
x₀ N(s)/f′(s), N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt})/s (Laplace transform of eq. 23),
so a_i − i b_i = 2 x₀ N(s_i)/f′(s_i). (``amplitude="release"`` instead gives the single mode
the release's own initial conditions, x(0) = x₀ and ẋ(0) = 0: a_i = x₀, b_i = σ_i x₀/ω_i. That
variant ignores the share of the release taken by the loop's fast modes; it is kept because it
reproduces ../shared/data/truth.json's numbers to < 0.5 %, which identifies how those were
computed.)
"""

from __future__ import annotations

import numpy as np
from sets import SetSpec

from phoid.dynamics import characteristic, dominant_roots


def dominant_modes(spec: SetSpec) -> np.ndarray:
    """Certified dominant root s_i = −σ_i + iω_i (ω_i ≥ 0) of every run's loop, 1/s."""
    P, D = spec.gains
    return dominant_roots(spec.m, spec.c, spec.k, P, D, spec.delay)


def residue(s: complex, spec: SetSpec, P: float, D: float) -> complex:
    """Amplitude per metre of release of the mode e^{sτ}: N(s)/f′(s) (see module docstring)."""
    e = np.exp(-s * spec.delay)
    _, df = characteristic(s, spec.m, spec.c, spec.k, P, D, spec.delay)
    return complex((spec.m * s + spec.c + D * e - P * (1 - e) / s) / df)


def mode_information(tau: np.ndarray, sigma: float, omega: float, a: float, b: float
                     ) -> np.ndarray:
    """2 × 2 Fisher information (unit noise) of (σ, ω) with (a, b, offset) profiled out.

    Model o + e^{−στ}(a cos ωτ + b sin ωτ) on the sample offsets ``tau`` (s).
    """
    e = np.exp(-sigma * tau)
    co, si = e * np.cos(omega * tau), e * np.sin(omega * tau)
    y = a * co + b * si
    J = np.stack([-tau * y, tau * (b * co - a * si), co, si, np.ones_like(tau)])
    F = J @ J.T
    A, B, C = F[:2, :2], F[:2, 2:], F[2:, 2:]
    return A - B @ np.linalg.solve(C, B.T)


def crb_sd(spec: SetSpec, amplitude: str = "residue") -> np.ndarray:
    """Cramér–Rao sd of (m, c, k) (kg, N·s/m, N/m) for the set, per the module docstring.

    Parameters
    ----------
    spec : SetSpec
        The experiment set (plant, delay, gains, timing, noise).
    amplitude : {"residue", "release"}
        The true amplitude and phase of each run's dominant mode: its residue in the exact
        response (default), or the release's initial conditions (see the module docstring).

    Returns
    -------
    ndarray, shape (3,)
        CRB standard deviations of m (kg), c (N·s/m), k (N/m) for the effective noise sd
        √(s² + q²/12).
    """
    if amplitude not in ("residue", "release"):
        raise ValueError(f"`amplitude` must be 'residue' or 'release'; got {amplitude!r}")
    P, D = spec.gains
    s = dominant_modes(spec)
    n = round(spec.duration * spec.fs)
    tau = np.arange(n) / spec.fs
    info = np.zeros((3, 3))
    for i in range(P.size):
        if amplitude == "residue":
            r = residue(s[i], spec, P[i], D[i])
            a, b = 2 * spec.x0 * r.real, -2 * spec.x0 * r.imag
        else:
            a, b = spec.x0, -s[i].real * spec.x0 / s[i].imag
        Ii = mode_information(tau, -s[i].real, s[i].imag, a, b)
        _, df = characteristic(s[i], spec.m, spec.c, spec.k, P[i], D[i], spec.delay)
        ds = -np.array([s[i] ** 2, s[i], 1.0]) / complex(df)  # ∂s/∂(m, c, k)
        G = np.stack([-ds.real, ds.imag])  # ∂(σ, ω)/∂(m, c, k)
        info += G.T @ Ii @ G
    return spec.noise_sd * np.sqrt(np.diag(np.linalg.inv(info)))
