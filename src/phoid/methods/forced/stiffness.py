"""The dynamic stiffness of a forced plant: m, c, k from R e^{iρ}, seed eqs. (20)–(22).

Per forcing frequency ω, eq. (18) gives (eq. 20; ERRATA 3 in docs/equations.md: R in N/m, C in m)

    k − mω² = R cos ρ,    cω = R sin ρ,    R = B/C,  ρ = φ − θ   (eq. 21),

in complex form R e^{iρ} = F̂/x̂ = k − mω² + icω, the dynamic stiffness.
:func:`fit_response` fits m, c, k to several frequencies by generalised least squares, the
frequency's own uncertainty entering through ∂(k − mω², cω)/∂ω = (−2mω, c);
:func:`two_frequency` is the seed's two-frequency solution of eq. (22), with ERRATA 2 (eq. 22b).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phoid import _validate as v
from phoid.errors import IdentificationError

__all__ = ["SAME_OMEGA", "ResponseFit", "distinct_count", "fit_response", "two_frequency"]

#: frequencies closer than this (relative) count as one
SAME_OMEGA = 1e-3


def two_frequency(
    omega_i: float, R_i: float, rho_i: float, omega_j: float, R_j: float, rho_j: float
) -> tuple[float, float, float]:
    """m, c, k from two frequencies by the seed's eq. (22), with ERRATA 2 applied to eq. (22b).

    Parameters
    ----------
    omega_i, omega_j : float
        The two forcing frequencies, rad/s (distinct, > 0).
    R_i, R_j : float
        Relative stiffness R = B/C at each, N/m (eq. 21; ERRATA 3: C is a displacement).
    rho_i, rho_j : float
        Phase lag ρ = φ − θ of x behind F at each, rad (eq. 21).

    Returns
    -------
    m, c, k : float
        kg, N·s/m, N/m:

        - m = (R_j cos ρ_j − R_i cos ρ_i)/(ω_i² − ω_j²)                  (eq. 22a)
        - c = (ω_j R_i sin ρ_i + ω_i R_j sin ρ_j)/(2 ω_i ω_j)           (eq. 22b, corrected)
        - k = (ω_i² R_j cos ρ_j − ω_j² R_i cos ρ_i)/(ω_i² − ω_j²)      (eq. 22c)

        The printed eq. (22b) repeats the j term; the corrected form is the mean of the two
        per-frequency values R sin ρ/ω of eq. (20).

    Raises
    ------
    ValueError
        If the frequencies are equal, not positive or not finite.

    Examples
    --------
    >>> import numpy as np
    >>> Z = lambda w: 64 - 2 * w**2 + 1j * w  # m = 2, c = 1, k = 64: R e^{iρ} of eq. (20)
    >>> m, c, k = two_frequency(3, abs(Z(3)), np.angle(Z(3)), 9, abs(Z(9)), np.angle(Z(9)))
    >>> round(m, 12), round(c, 12), round(k, 12)
    (2.0, 1.0, 64.0)
    """
    wi = v.positive("omega_i", omega_i, "rad/s")
    wj = v.positive("omega_j", omega_j, "rad/s")
    if wi == wj:
        raise ValueError(f"`omega_i` and `omega_j` must differ; both are {wi:g} rad/s")
    Ri, Rj = v.finite("R_i", R_i, "N/m"), v.finite("R_j", R_j, "N/m")
    pi, pj = v.finite("rho_i", rho_i, "rad"), v.finite("rho_j", rho_j, "rad")
    den = wi * wi - wj * wj
    m = (Rj * math.cos(pj) - Ri * math.cos(pi)) / den
    c = (wj * Ri * math.sin(pi) + wi * Rj * math.sin(pj)) / (2.0 * wi * wj)
    k = (wi * wi * Rj * math.cos(pj) - wj * wj * Ri * math.cos(pi)) / den
    return m, c, k


@dataclass(frozen=True)
class ResponseFit:
    """m, c, k from per-frequency dynamic stiffnesses by generalised least squares (eq. 20).

    Attributes
    ----------
    m, c, k : float
        kg, N·s/m, N/m.
    cov : ndarray, shape (3, 3)
        Covariance of (m, c, k) (scaled by χ²/dof when the runs disagree, see ``warnings``).
    chi2 : float
        Weighted residual sum of squares.
    dof : int
        2n − 3 for n runs.
    warnings : tuple of str
    """

    m: float
    c: float
    k: float
    cov: np.ndarray = field(repr=False)
    chi2: float
    dof: int
    warnings: tuple[str, ...] = ()

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors of (m, c, k)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def fit_response(
    omega: Any,
    Z: Any,
    cov: Any,
    *,
    omega_var: Any = None,
    added_mass: Any = None,
) -> ResponseFit:
    """m, c, k from R e^{iρ} at several frequencies: GLS on eq. (20).

    Re Zᵢ = k − (m + m_aᵢ) ωᵢ² and Im Zᵢ = c ωᵢ, Zᵢ = Rᵢ e^{iρᵢ}, weighted by the inverse of the
    full covariance of the stacked (Re Z₁, Im Z₁, …, Re Zₙ, Im Zₙ), to which each frequency's
    own variance adds var ωᵢ · hᵢhᵢᵀ with hᵢ = (−2mωᵢ, c) (the model's derivative in ω,
    evaluated at a first solution and then iterated once).

    Parameters
    ----------
    omega : array_like, shape (n,)
        Forcing frequencies, rad/s.
    Z : array_like of complex, shape (n,)
        Dynamic stiffness R e^{iρ} at each, N/m.
    cov : array_like, shape (2n, 2n) or (n, 2, 2)
        Covariance of the stacked real and imaginary parts (full, or per-run blocks).
    omega_var : array_like, shape (n,), optional
        Variance of each ω, (rad/s)².
    added_mass : array_like, shape (n,), optional
        Known mass added in each run, kg (then m is the mass without it).

    Returns
    -------
    ResponseFit

    Raises
    ------
    IdentificationError
        With fewer than two distinct frequencies (m and k are then not separable) or a
        singular covariance.
    """
    from scipy import stats

    w = v.finite_array("omega", omega, ndim=1)
    Zc = np.asarray(Z, dtype=complex).ravel()
    n = w.size
    if Zc.size != n:
        raise ValueError(f"`Z` must have one value per frequency; got {Zc.size} for {n}")
    if not np.all(np.isfinite(Zc)):
        raise ValueError("`Z` must be finite")
    C = np.asarray(cov, dtype=float)
    if C.shape == (n, 2, 2):
        full = np.zeros((2 * n, 2 * n))
        for i in range(n):
            full[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = C[i]
        C = full
    if C.shape != (2 * n, 2 * n):
        raise ValueError(f"`cov` must have shape ({2 * n}, {2 * n}) or ({n}, 2, 2); "
                         f"got {C.shape}")
    wv = np.zeros(n) if omega_var is None else v.finite_array("omega_var", omega_var, ndim=1)
    ma = np.zeros(n) if added_mass is None else v.finite_array("added_mass", added_mass, ndim=1)
    distinct = distinct_count(w)
    if distinct < 2:
        raise IdentificationError(
            f"all runs are forced at one frequency ({float(np.mean(w)):.6g} rad/s): m and k "
            "are not separable (eq. 20 needs at least two distinct frequencies)")
    y = np.empty(2 * n)
    y[0::2] = Zc.real + ma * w * w
    y[1::2] = Zc.imag
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = -w * w
    A[0::2, 2] = 1.0
    A[1::2, 1] = w
    theta, covp, chi2 = _gls(A, y, C)
    for _ in range(2 if np.any(wv > 0) else 0):
        # the frequencies' own errors: var ωᵢ · hᵢhᵢᵀ, hᵢ = ∂(k − (m + m_aᵢ)ω², cω)/∂ω
        h = np.zeros((2 * n, n))
        h[0::2] = np.diag(-2.0 * (theta[0] + ma) * w)
        h[1::2] = np.diag(np.full(n, theta[1]))
        theta, covp, chi2 = _gls(A, y, C + (h * wv) @ h.T)
    dof = 2 * n - 3
    warnings: list[str] = []
    if dof > 0 and chi2 > stats.chi2.ppf(0.999, dof):
        red = chi2 / dof
        covp = covp * red
        warnings.append(
            f"the runs disagree with eq. (20) more than their noise explains (χ²/dof = "
            f"{red:.3g}); stderr scaled up accordingly: check for nonlinearity (friction, "
            "amplitude-dependent stiffness) or a force not acting on the measured mass")
    return ResponseFit(m=float(theta[0]), c=float(theta[1]), k=float(theta[2]), cov=covp,
                       chi2=float(chi2), dof=dof, warnings=tuple(warnings))


def distinct_count(w: np.ndarray) -> int:
    """Number of distinct frequencies among ``w`` (rad/s): closer than 10⁻³ relative (the
    ``SAME_OMEGA`` tolerance) counts as one."""
    ws = np.sort(w)
    gaps = np.diff(ws) > SAME_OMEGA * ws[1:]
    return int(1 + np.count_nonzero(gaps))


def _gls(A: np.ndarray, y: np.ndarray, Sigma: np.ndarray):
    """Generalised least squares with a full covariance (Cholesky whitening)."""
    scale = np.sqrt(np.clip(np.diag(Sigma), 1e-300, None))
    Sn = Sigma / np.outer(scale, scale)
    try:
        L = np.linalg.cholesky(Sn + 1e-14 * np.eye(Sn.shape[0]))
    except np.linalg.LinAlgError:
        raise IdentificationError("the covariance of the measured R, ρ is singular") from None
    Aw = np.linalg.solve(L, A / scale[:, None])
    yw = np.linalg.solve(L, y / scale)
    Q, R = np.linalg.qr(Aw)
    theta = np.linalg.solve(R, Q.T @ yw)
    r = yw - Aw @ theta
    Rinv = np.linalg.inv(R)
    return theta, Rinv @ Rinv.T, float(r @ r)
