"""Cramér–Rao bound of m, c, k for a planned or recorded PHO experiment set.

The model of the bound (the one ``examples/paper-sample/truth.json`` states for its
``crb_sd``): each run records, from its release on, the loop's **dominant mode only**,

    x(τ) = offset + Re[w e^{sτ}],   s = −σ + iω_d,   τ = n/f_s, n = 0 … N−1,

with white Gaussian sensor noise of standard deviation ``noise``; the offset and the complex
amplitude w (amplitude and phase) are unknown nuisance parameters of each run, the loop delay is
known. The per-run Fisher information of (σ, ω_d) is the Schur complement of the 5 × 5 Fisher
matrix of (offset, Re w, Im w, σ, ω_d) onto its last two coordinates (the nuisance parameters
profiled out). Its entries are sums over the samples of products of the model's derivatives,

    1,  Re(e^{sτ}),  Re(−i e^{sτ}),  ∂/∂σ = Re(−τ w e^{sτ}),  ∂/∂ω_d = Re(iτ w e^{sτ}),

which :func:`mode_information` evaluates in closed form from the finite power sums
Σ nʳ zⁿ (r = 0, 1, 2) of z = e^{sh}, e^{2sh} and e^{−2σh} (h = 1/f_s), using
Re(u)Re(v) = ½ Re(uv + uv̄): the cost does not grow with the record length.

The modes of all runs depend on θ = (m, c, k) through the characteristic equation of the delayed
loop (seed eq. 23), f(s) = m s² + c s + k + (D s + P) e^{−sΔt} = 0, so by the implicit function
theorem ∂s/∂θ = −(s², s, 1)/f′(s) (the Jacobian of :func:`phoid.methods.pho.fit_modes`), and the
information of θ is Σᵢ Gᵢᵀ Iᵢ Gᵢ with Gᵢ = ∂(σᵢ, ω_dᵢ)/∂θ. Its inverse is the bound.

The release amplitude of the dominant mode is not x₀: a run released from a held position x₀
(history x = x₀ on [−Δt, 0]) has X(s) = x₀ N(s)/f(s) with
N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt})/s, so the mode e^{st} carries the residue
x₀ N(s)/f′(s) and w = 2 x₀ N(s)/f′(s) (:func:`release_amplitude`; docs/design-notes/history.md).

Sensor noise is the only noise in this model: the feedback acts on the true position (as in
:func:`phoid.simulation.simulate`). The non-dominant modes that ring right after the release
are left out of the model, as in ``truth.json``; phoid's estimator fits them too (how close
its spread comes to this bound: docs/design-notes/planning.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from phoid.dynamics import characteristic, dominant_roots

__all__ = [
    "CramerRao",
    "cramer_rao",
    "mode_information",
    "mode_jacobian",
    "power_sums",
    "release_amplitude",
    "safe_inverse",
]


def power_sums(z: np.ndarray | complex, n: np.ndarray | int) -> tuple[np.ndarray, ...]:
    """Finite power sums Gᵣ = Σ_{j=0}^{n−1} jʳ zʲ for r = 0, 1, 2, vectorised.

    Parameters
    ----------
    z : array_like of complex
        Ratio of the geometric sequence (|z| < 1 for a decaying mode; any z ≠ 1 is exact).
    n : int or array_like of int
        Number of terms (≥ 1), broadcast against ``z``.

    Returns
    -------
    G0, G1, G2 : ndarray of complex

    Notes
    -----
    With Aᵣ = Σ_{j≥0} jʳ zʲ (A₀ = 1/(1−z), A₁ = z/(1−z)², A₂ = z(1+z)/(1−z)³) and
    (j+n)² = j² + 2nj + n², the tail from j = n is zⁿ(A₀), zⁿ(A₁ + nA₀), zⁿ(A₂ + 2nA₁ + n²A₀);
    these rational identities hold for every z ≠ 1. Where n|log z| < 0.5 (almost no decay
    or rotation over the record, where the closed form cancels) the sums are taken by Taylor
    series of jʳ e^{jL}, L = log z, to rounding level.
    """
    z, n = np.broadcast_arrays(np.asarray(z, dtype=complex), np.asarray(n))
    shape = z.shape
    z, n = z.ravel(), n.ravel()
    n_f = n.astype(float)
    with np.errstate(all="ignore"):
        one_minus = 1.0 - z
        A0 = 1.0 / one_minus
        A1 = z * A0 * A0
        A2 = z * (1.0 + z) * A0 * A0 * A0
        zn = z**n_f
        G0 = A0 * (1.0 - zn)
        G1 = A1 - zn * (A1 + n_f * A0)
        G2 = A2 - zn * (A2 + 2.0 * n_f * A1 + n_f * n_f * A0)
        L = np.log(z)
    small = ~(np.abs(n_f * L) >= 0.5)  # also catches z = 1 (L = 0) and NaN
    for i in np.flatnonzero(small):
        G0[i], G1[i], G2[i] = _power_sums_series(complex(L[i]), int(n[i]))
    return G0.reshape(shape), G1.reshape(shape), G2.reshape(shape)


def _power_sums_series(L: complex, n: int) -> tuple[complex, complex, complex]:
    """Σ jʳ e^{jL} (r = 0, 1, 2) for |nL| < 0.5 by the series Σ_q Lᵠ/q! Σ j^{r+q}.

    24 terms of the series of e^{jL} reach rounding level for |jL| < 0.5.
    """
    j = np.arange(n, dtype=float)
    out = []
    for r in range(3):
        total = 0j
        term = 1.0 + 0j
        for q in range(24):
            total += term * float(np.sum(j ** (r + q)))
            term = term * L / (q + 1)
        out.append(total)
    return out[0], out[1], out[2]


def mode_information(
    s: np.ndarray | complex,
    w: np.ndarray | complex,
    *,
    fs: np.ndarray | float,
    duration: np.ndarray | float,
    noise: np.ndarray | float,
) -> np.ndarray:
    """Fisher information of one damped mode's (σ, ω_d), nuisance amplitude/phase/offset profiled.

    Parameters
    ----------
    s : array_like of complex
        The mode's root −σ + iω_d (1/s), one per run, Im s > 0.
    w : array_like of complex
        Its complex amplitude, m: the record is offset + Re[w e^{sτ}] (τ in s from the release).
    fs : float or array_like
        Sample rate, Hz.
    duration : float or array_like
        Record length after the release, s; N = round(duration·f_s) samples at τ = n/f_s.
    noise : float or array_like
        White sensor noise standard deviation, m (> 0).

    Returns
    -------
    ndarray, shape (n, 2, 2)
        Information matrix of (σ, ω_d) of each run (units 1/(1/s)²); its inverse is the
        Cramér–Rao covariance of the run's (σ, ω_d).
    """
    s = np.atleast_1d(np.asarray(s, dtype=complex))
    w = np.atleast_1d(np.asarray(w, dtype=complex))
    fs_a = np.atleast_1d(np.asarray(fs, dtype=float))
    s, w, fs_a, dur, sd = np.broadcast_arrays(
        s, w, fs_a, np.atleast_1d(np.asarray(duration, dtype=float)),
        np.atleast_1d(np.asarray(noise, dtype=float)),
    )
    h = 1.0 / fs_a
    N = np.maximum(np.rint(dur * fs_a), 1).astype(np.int64)
    sigma = -s.real
    hp = np.stack([np.ones_like(h), h, h * h])  # h^r, r = 0, 1, 2
    S1 = np.stack(power_sums(np.exp(s * h), N)) * hp  # Σ τ^r e^{sτ}
    S2 = np.stack(power_sums(np.exp(2 * s * h), N)) * hp  # Σ τ^r e^{2sτ}
    R = np.stack(power_sums(np.exp(-2 * sigma * h), N)) * hp  # Σ τ^r e^{−2στ}
    # oscillatory columns Re(c_j τ^{p_j} e^{sτ}): cos, sin, ∂/∂σ, ∂/∂ω_d
    cvec = np.stack([np.ones_like(w), -1j * np.ones_like(w), -w, 1j * w], axis=1)  # (n, 4)
    p = np.array([0, 0, 1, 1])
    n = s.size
    F = np.empty((n, 5, 5))
    F[:, 0, 0] = N
    idx = np.arange(n)
    F[:, 0, 1:] = (cvec * S1[p][:, idx].T).real
    F[:, 1:, 0] = F[:, 0, 1:]
    pp = p[:, None] + p[None, :]  # (4, 4) power of τ in each product
    S2pp = S2[pp][:, :, idx].transpose(2, 0, 1)  # (n, 4, 4)
    Rpp = R[pp][:, :, idx].transpose(2, 0, 1)
    cc = cvec[:, :, None] * cvec[:, None, :]
    ccb = cvec[:, :, None] * np.conj(cvec[:, None, :])
    F[:, 1:, 1:] = 0.5 * (cc * S2pp + ccb * Rpp).real
    F = F / (sd * sd)[:, None, None]
    # profile out (offset, Re w, Im w): Schur complement on (σ, ω_d)
    Fnn = F[:, :3, :3]
    Fns = F[:, :3, 3:]
    Fss = F[:, 3:, 3:]
    X = np.linalg.solve(Fnn, Fns)
    info = Fss - np.einsum("nji,njk->nik", Fns, X)
    return 0.5 * (info + info.transpose(0, 2, 1))


def release_amplitude(
    s: np.ndarray | complex,
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
    x0: np.ndarray | float,
) -> np.ndarray:
    """Complex amplitude w of the mode e^{st} after a release from a held position x₀.

    Parameters
    ----------
    s : array_like of complex
        A characteristic root of the loop, 1/s.
    m, c, k : float
        Plant, kg, N·s/m, N/m.
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    x0 : float or array_like
        Release position (held on [−Δt, 0]), m.

    Returns
    -------
    ndarray of complex
        w = 2 x₀ N(s)/f′(s), N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt})/s (from eq. 23),
        so that the mode and its conjugate contribute Re[w e^{sτ}] to x (m).
    """
    s = np.asarray(s, dtype=complex)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    with np.errstate(all="ignore"):  # far-left roots with a long delay overflow: inf/nan
        e = np.exp(-s * delay)
        p_term = np.where(s != 0, P * (1.0 - e) / np.where(s != 0, s, 1.0), P * delay)
        _, df = characteristic(s, m, c, k, P, D, delay)
        return 2.0 * np.asarray(x0, dtype=float) * (m * s + c + D * e - p_term) / df


def mode_jacobian(
    s: np.ndarray | complex,
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> np.ndarray:
    """∂(σ, ω_d)/∂(m, c, k) of a loop root, by the implicit function theorem.

    Parameters
    ----------
    s : array_like of complex
        Roots −σ + iω_d of f(s) = m s² + c s + k + (D s + P) e^{−sΔt} (eq. 23), 1/s.
    m, c, k, P, D, delay : float or array_like
        Plant (kg, N·s/m, N/m), gains (N/m, N·s/m) and delay (s).

    Returns
    -------
    ndarray, shape (n, 2, 3)
        Row 0: ∂σ/∂(m, c, k) = −Re ∂s/∂θ; row 1: ∂ω_d/∂(m, c, k) = Im ∂s/∂θ, with
        ∂s/∂θ = −(s², s, 1)/f′(s).
    """
    s = np.atleast_1d(np.asarray(s, dtype=complex))
    _, df = characteristic(s, m, c, k, P, D, delay)
    ds = -np.stack([s * s, s, np.ones_like(s)], axis=1) / df[:, None]
    return np.stack([-ds.real, ds.imag], axis=1)


@dataclass(frozen=True)
class CramerRao:
    """The Cramér–Rao bound of (m, c, k) for a set of runs (see the module docstring).

    Attributes
    ----------
    cov : ndarray, shape (3, 3)
        Covariance bound of (m, c, k): kg², (N·s/m)², (N/m)² and cross terms; ``inf`` on the
        diagonal where the set cannot determine a parameter.
    information : ndarray, shape (3, 3)
        Fisher information of (m, c, k) (inverse of ``cov`` when regular).
    sigma, omega_d : ndarray
        Each run's dominant mode, 1/s and rad/s.
    amplitude : ndarray of complex
        Each run's complex release amplitude w of the dominant mode, m.
    mode_cov : ndarray, shape (n, 2, 2)
        Each run's own bound on (σ, ω_d) (``inf`` for a run that does not ring).
    run_information : ndarray, shape (n, 3, 3)
        Each run's contribution Gᵢᵀ Iᵢ Gᵢ to ``information``.
    """

    cov: np.ndarray
    information: np.ndarray
    sigma: np.ndarray
    omega_d: np.ndarray
    amplitude: np.ndarray
    mode_cov: np.ndarray
    run_information: np.ndarray

    @property
    def stderr(self) -> np.ndarray:
        """Standard deviations of (m, c, k): kg, N·s/m, N/m."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def sigma_stderr(self) -> np.ndarray:
        """Per-run bound on the standard deviation of σᵢ, 1/s."""
        return np.sqrt(self.mode_cov[:, 0, 0])

    @property
    def omega_d_stderr(self) -> np.ndarray:
        """Per-run bound on the standard deviation of ω_dᵢ, rad/s."""
        return np.sqrt(self.mode_cov[:, 1, 1])


def safe_inverse(info: np.ndarray) -> np.ndarray:
    """Inverse of a (3, 3) information matrix; ``inf`` variances for undetermined directions.

    The matrix is scaled to unit diagonal (Z = S⁻¹ I S⁻¹, S = diag(√Iⱼⱼ)) and inverted when
    cond(Z) < 10¹², so that the test does not depend on the units of m, c, k.

    Parameters
    ----------
    info : ndarray, shape (3, 3)
        Fisher information of (m, c, k).

    Returns
    -------
    ndarray, shape (3, 3)
        The covariance I⁻¹ (kg², (N·s/m)², (N/m)² and cross terms); when I is singular or
        ill-conditioned, ``inf`` on the diagonal and NaN elsewhere.
    """
    scale = np.sqrt(np.clip(np.diag(info), 0.0, None))
    if np.all(scale > 0):
        Z = info / np.outer(scale, scale)
        if np.linalg.cond(Z) < 1e12:
            return np.linalg.inv(Z) / np.outer(scale, scale)
    cov = np.full((3, 3), np.nan)
    cov[np.diag_indices(3)] = np.inf
    return cov


def cramer_rao(
    m: float,
    c: float,
    k: float,
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    *,
    fs: np.ndarray | float,
    duration: np.ndarray | float,
    noise: np.ndarray | float,
    x0: np.ndarray | float,
    roots: np.ndarray | None = None,
) -> CramerRao:
    """Cramér–Rao bound of (m, c, k) from a PHO set (single dominant mode per run).

    Parameters
    ----------
    m, c, k : float
        The plant at which the bound is evaluated: kg, N·s/m, N/m.
    P, D : array_like
        Gains of the runs, N/m and N·s/m.
    delay : float
        Loop delay Δt, s (known).
    fs : float or array_like
        Sample rate of each run, Hz.
    duration : float or array_like
        Record length of each run after its release, s.
    noise : float or array_like
        Sensor noise standard deviation, m (> 0).
    x0 : float or array_like
        Release position of each run (held before), m; the amplitude of the dominant mode
        follows from its residue (:func:`release_amplitude`).
    roots : array_like of complex, optional
        The runs' dominant roots (Im ≥ 0) if already known; otherwise computed (certified).

    Returns
    -------
    CramerRao

    Examples
    --------
    The seed paper's sweep (ERRATA 6) at the sample set's settings (``truth.json``):

    >>> import numpy as np
    >>> i = np.arange(19)
    >>> b = cramer_rao(2.0, 1.0, 64.0, 0.25 + 1.375 * i, 0.6 + 0.3 * i, 0.1, fs=1000.0,
    ...                duration=15.0, noise=1e-4, x0=0.01)
    >>> [f"{v:.2g}" for v in b.stderr]
    ['0.00049', '0.00071', '0.019']
    """
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    if roots is None:
        roots = dominant_roots(m, c, k, P, D, delay)
    s = np.atleast_1d(np.asarray(roots, dtype=complex))
    n = s.size
    w = release_amplitude(s, m, c, k, P, D, delay, x0) * np.ones(n)
    rings = s.imag > 0
    info = np.zeros((n, 2, 2))
    mode_cov = np.full((n, 2, 2), np.inf)
    if np.any(rings):
        fs_b, dur_b, sd_b = (np.broadcast_to(np.asarray(a, dtype=float), (n,))
                             for a in (fs, duration, noise))
        ri = mode_information(s[rings], w[rings], fs=fs_b[rings], duration=dur_b[rings],
                              noise=sd_b[rings])
        info[rings] = ri
        with np.errstate(all="ignore"):
            det = ri[:, 0, 0] * ri[:, 1, 1] - ri[:, 0, 1] ** 2
            inv = np.stack([np.stack([ri[:, 1, 1], -ri[:, 0, 1]], -1),
                            np.stack([-ri[:, 1, 0], ri[:, 0, 0]], -1)], 1) / det[:, None, None]
        mode_cov[rings] = np.where(det[:, None, None] > 0, inv, np.inf)
    G = mode_jacobian(s, m, c, k, P, D, delay)
    run_info = np.einsum("nai,nab,nbj->nij", G, info, G)
    total = run_info.sum(axis=0)
    return CramerRao(
        cov=safe_inverse(total),
        information=total,
        sigma=-s.real,
        omega_d=np.abs(s.imag),
        amplitude=w,
        mode_cov=mode_cov,
        run_information=run_info,
    )

