r"""m, c, k at the in-loop bound: the output error of the plant driven by the applied force.

Given the record, the force the controller applied is known (:mod:`phoid.methods.inloop_model`:
its law on the recorded positions, delayed and held), so the conditional likelihood of the
record is that of the plant's response to that force under white sensor noise: the output
error (docs/design-notes/inloop.md). Its parameters: θ = (m, c, k), and the nuisances — each
window's start state (z₀, z₁), for the filtered velocity estimator each run's estimator state
at the record's start (force patterns, :func:`phoid.methods.inloop_model.applied_force`), and
one position offset b shared by the set.

Variable projection
-------------------
For a trial θ the model is linear in the nuisances: every window's forced response F, free
responses C₀, C₁ and pattern responses G come from one IIR filter over all windows at once
(:func:`phoid.methods.inloop_model.recursion`; one call per distinct step and added mass). The
window-own columns (C₀, C₁, the G) are projected off by a batched SVD (their rank detected at
1e-10 of the largest singular value of the unit-norm columns), then the shared offset's
column; the residual is e(θ) = P⊥(x̃ − F). θ is found by a Levenberg–Marquardt iteration on
‖e(θ)‖² with Kaufman's Jacobian −P⊥ ∂x̂/∂θ, where ∂x̂/∂θ at the fitted nuisances is one more
IIR filter per parameter (the derivative of the recursion z_s − τz_{s−1} + δz_{s−2} =
b₁f_{s−1} + b₀f_{s−2} with respect to its coefficients, chained with ∂(τ, δ, b₁, b₀)/∂θ of
:func:`phoid.dynamics.digital.zoh_plant`). Started from the modal route's m, c, k and from an
equation-error least squares (the recursion's coefficients regressed on the record and the
force, mapped back to m, c, k), whichever fits better.

Standard errors: σ̂²(JᵀJ)⁻¹ of the full parameter vector, its θ block — by Frisch–Waugh
σ̂²(J_θᵀP⊥J_θ)⁻¹ with P⊥ the projection off every nuisance column — and σ̂² = RSS/(n − p), p
counting θ, the nuisances' rank and the offset.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from phoid.errors import IdentificationError
from phoid.methods.fit_statistics import difference_noise
from phoid.methods.inloop_model import (
    RunWindow,
    drive,
    free_columns,
    plant_coefficients,
    recursion,
    stack,
)
from phoid.methods.savgol import savgol_filter

__all__ = ["InLoopFit", "equation_error_starts", "fit_inloop"]

#: rank tolerance of the window-own columns (unit norm), relative to the largest singular value
_RANK_TOL = 1e-10
#: most Levenberg–Marquardt iterations (each one filter pass over the windows)
_MAX_ITER = 100
#: converged when the step moves θ by less than this many of its stderr (Mahalanobis)
_STEP_TOL = 1e-4


@dataclass(frozen=True)
class InLoopFit:
    """The output-error fit of the plant driven by the applied force.

    Attributes
    ----------
    m, c, k : float
        Mass (kg), damping (N·s/m), stiffness (N/m).
    cov : ndarray, shape (3, 3)
        σ̂²(JᵀJ)⁻¹'s θ block: the Jacobian-based covariance of (m, c, k), nuisances included.
    information : ndarray, shape (3, 3)
        J_θᵀP⊥J_θ (per unit noise variance): cov = σ̂²·information⁻¹.
    sigma : float
        σ̂ = √(RSS/(n − p)), the white sensor noise's sd, in x's unit.
    rss : float
        The residual sum of squares.
    samples, parameters : int
        n (fitted samples) and p (θ, the nuisances' rank, the offset).
    offset : float
        The shared position offset b.
    runs : tuple of int
        The set's runs each window belongs to.
    starts : tuple of int
        Each window's first sample in its run's record.
    residuals : tuple of ndarray
        Each window's residual.
    jacobians : tuple of ndarray
        Each window's P⊥ ∂x̂/∂θ, shape (L, 3) (for a sandwich covariance).
    noise : tuple of float
        Each window's noise sd from the record's third differences, without the model
        (:func:`phoid.methods.fit_statistics.difference_noise`).
    iterations : int
    converged : bool
    """

    m: float
    c: float
    k: float
    cov: np.ndarray
    information: np.ndarray
    sigma: float
    rss: float
    samples: int
    parameters: int
    offset: float
    runs: tuple[int, ...]
    starts: tuple[int, ...]
    residuals: tuple[np.ndarray, ...] = field(repr=False)
    jacobians: tuple[np.ndarray, ...] = field(repr=False)
    noise: tuple[float, ...] = ()
    iterations: int = 0
    converged: bool = True

    @property
    def theta(self) -> np.ndarray:
        """(m, c, k)."""
        return np.array([self.m, self.c, self.k])

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors of (m, c, k)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def chi2(self) -> float:
        """Σ over the windows of RSS/noise² (each window's noise from third differences)."""
        return float(sum(float(e @ e) / (s * s) for e, s in zip(self.residuals, self.noise,
                                                                strict=True)
                         if s > 0 and math.isfinite(s)))

    def noise_ratios(self, n_runs: int) -> list[float | None]:
        """Per run of the set: its residual's RMS over its noise (None: not fitted)."""
        out: list[float | None] = [None] * n_runs
        for r, e, s in zip(self.runs, self.residuals, self.noise, strict=True):
            rms = float(np.sqrt(np.mean(e * e))) if e.size else math.nan
            if 0 <= r < n_runs and s > 0 and math.isfinite(s) and math.isfinite(rms):
                out[r] = rms / s
        return out


class _Eval:
    """A trial θ's projected residual; its Jacobian P⊥ ∂x̂/∂θ computed when first asked for
    (a rejected step never needs it)."""

    def __init__(self, rss: float, resid: np.ndarray, rank: int, offset: float,
                 jac: Callable[[], np.ndarray | None]) -> None:
        self.rss = rss
        self.resid = resid  # (S, L), zero outside the windows
        self.rank = rank  # the nuisance columns' rank (window-own ones and the offset)
        self.offset = offset
        self._jac_fn: Callable[[], np.ndarray | None] | None = jac
        self._jac: np.ndarray | None = None

    @property
    def jac(self) -> np.ndarray:
        """(S, L, 3): P⊥ ∂x̂/∂θ at the fitted nuisances (non-finite entries as nan)."""
        if self._jac is None:
            fn, self._jac_fn = self._jac_fn, None
            out = fn() if fn is not None else None
            self._jac = out if out is not None else np.full((*self.resid.shape, 3), np.nan)
        return self._jac


class _Problem:
    """The windows as padded arrays, grouped by (step, added mass): each group one plant."""

    def __init__(self, windows: Sequence[RunWindow]) -> None:
        self.windows = list(windows)
        self.y, self.f, self.g, self.mask = stack(self.windows)
        groups: dict[tuple[float, float], list[int]] = {}
        for i, w in enumerate(self.windows):
            groups.setdefault((w.step, w.added_mass), []).append(i)
        self.groups = [(h, dm, np.array(rows)) for (h, dm), rows in groups.items()]
        self.n = int(self.mask.sum())

    def evaluate(self, theta: np.ndarray) -> _Eval | None:
        """The projected residual at θ (its Jacobian on demand); None where the plant is not
        evaluable (m ≤ 0, or a response that overflows)."""
        m, c, k = (float(v) for v in theta)
        if not (m > 0 and math.isfinite(m) and math.isfinite(c) and math.isfinite(k)):
            return None
        y, f, g, mask = self.y, self.f, self.g, self.mask
        S, L = y.shape
        R = g.shape[1]
        cols = np.zeros((S, L, 2 + R))
        F = np.zeros((S, L))
        plants = []
        with np.errstate(all="ignore"):
            for h, dm, rows in self.groups:
                if not m + dm > 0:
                    return None
                coef, dcoef = plant_coefficients(m + dm, c, k, h)
                if not (np.all(np.isfinite(coef)) and np.all(np.isfinite(dcoef))):
                    return None
                tau, delta, b1, b0 = coef
                out = recursion(tau, delta, np.concatenate(
                    [drive(b1, b0, f[rows]), drive(b1, b0, g[rows].reshape(-1, L))]))
                F[rows] = out[: rows.size]
                cols[rows, :, 2:] = np.moveaxis(out[rows.size:].reshape(rows.size, R, L), 1, 2)
                cols[rows, :, :2] = free_columns(tau, delta, L).T[None]
                plants.append((rows, coef, dcoef))
            cols *= mask[..., None]
            F *= mask
            if not (np.all(np.isfinite(cols)) and np.all(np.isfinite(F))):
                return None
            nrm = np.sqrt(np.einsum("slq,slq->sq", cols, cols))
            Xn = cols / np.where(nrm > 0, nrm, 1.0)[:, None, :]
            U, s, Vt = np.linalg.svd(Xn, full_matrices=False)
            keep = s > _RANK_TOL * s[:, :1]
            Uk = U * keep[:, None, :]

            def proj(X: np.ndarray) -> np.ndarray:
                if X.ndim == 2:
                    return X - np.einsum("slq,sq->sl", Uk, np.einsum("slq,sl->sq", Uk, X))
                return X - np.einsum("slq,sqk->slk", Uk, np.einsum("slq,slk->sqk", Uk, X))

            r0 = (y - F) * mask
            rp = proj(r0)
            op = proj(mask)
            oo = float(np.sum(op * op))
            free_b = oo > 1e-12 * self.n
            b = float(np.sum(op * rp)) / oo if free_b else 0.0
            e = rp - b * op
            rss = float(np.sum(e * e))
        if not math.isfinite(rss):
            return None

        def jacobian() -> np.ndarray | None:
            with np.errstate(all="ignore"):
                # the fitted trajectory (offset off) and force (the estimator's start state in)
                z = (y - b - e) * mask
                ur = np.einsum("slq,sl->sq", U, r0 - b * mask) * np.where(
                    keep, 1.0 / np.where(keep, s, 1.0), 0.0)
                beta = np.einsum("sqp,sq->sp", Vt, ur)
                vhat = np.where(nrm[:, 2:] > 0,
                                beta[:, 2:] / np.where(nrm[:, 2:] > 0, nrm[:, 2:], 1.0), 0.0)
                ftot = f + np.einsum("sr,srl->sl", vhat, g)
                J = np.zeros((S, L, 3))
                for rows, coef, dcoef in plants:
                    zr, fr = z[rows], ftot[rows]
                    w = np.zeros((rows.size, 3, L))
                    for j in range(3):
                        w[:, j, 2:] = (dcoef[0, j] * zr[:, 1:-1] - dcoef[1, j] * zr[:, :-2]
                                       + dcoef[2, j] * fr[:, 1:-1] + dcoef[3, j] * fr[:, :-2])
                    J[rows] = np.moveaxis(recursion(coef[0], coef[1], w), 1, 2)
                J *= mask[..., None]
                Jp = proj(J)
                if free_b:
                    Jp -= op[..., None] * (np.einsum("sl,slk->k", op, Jp) / oo)
            return Jp if np.all(np.isfinite(Jp)) else None

        return _Eval(rss, e, int(keep.sum()) + int(free_b), b, jacobian)


def _solve(H: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """H⁻¹g for a symmetric positive (semi)definite 3 × 3, scaled to unit diagonal first."""
    d = np.sqrt(np.diag(H))
    if not np.all(d > 0):
        return None
    Hs = H / np.outer(d, d)
    try:
        return np.linalg.solve(Hs, g / d) / d
    except np.linalg.LinAlgError:
        return None


def equation_error_starts(windows: Sequence[RunWindow]) -> list[np.ndarray]:
    """Starting points from the equation error m ẍ + c ẋ + k x + const = f, the record and its
    derivatives smoothed by Savitzky–Golay cubics (:func:`phoid.methods.savgol.savgol_filter`)
    over windows of 5 … 321 samples (shorter than a quarter of the longest run's window), the
    force averaged over the two holds about each sample and smoothed alike; one least squares
    per smoothing width, over every run's window. Biased (the noise in the smoothed record),
    only starts: the width that suits a record's noise and motion is not known beforehand, so
    each gives one, and the fit starts from whichever fits best. Those with m ≤ 0 are left
    out."""
    out: list[np.ndarray] = []
    longest = max((w.size for w in windows), default=0)
    for wl in (5, 11, 21, 41, 81, 161, 321):
        if 4 * wl > longest:
            break
        rows, rhs = [], []
        for w in windows:
            if w.size < 4 * wl:
                continue
            h, hw = w.step, wl // 2
            fc = w.force.copy()
            fc[1:] = 0.5 * (w.force[1:] + w.force[:-1])
            sl = slice(hw, w.size - hw - 1)
            x = savgol_filter(w.y, wl, 3)[sl]
            rows.append(np.column_stack([savgol_filter(w.y, wl, 3, 2, h)[sl],
                                         savgol_filter(w.y, wl, 3, 1, h)[sl], x,
                                         np.ones(x.size)]))
            rhs.append(savgol_filter(fc, wl, 3)[sl] - w.added_mass
                       * savgol_filter(w.y, wl, 3, 2, h)[sl])
        A = np.concatenate(rows)
        scale = np.sqrt(np.sum(A * A, axis=0))
        if not np.all(scale > 0):
            continue
        sol, *_ = np.linalg.lstsq(A / scale, np.concatenate(rhs), rcond=None)
        th = sol[:3] / scale[:3]
        if np.all(np.isfinite(th)) and th[0] > 0:
            out.append(th)
    return out


def _descend(prob: _Problem, theta: np.ndarray, ev: _Eval, max_iter: int, step_tol: float
             ) -> tuple[np.ndarray, _Eval, int, bool]:
    """Levenberg–Marquardt on ‖e(θ)‖² from θ: (θ, its evaluation, iterations, converged)."""
    lam = 1e-3
    it = 0
    for it in range(1, max_iter + 1):
        A = ev.jac.reshape(-1, 3)
        H = A.T @ A
        grad = A.T @ ev.resid.ravel()
        s2 = ev.rss / max(prob.n - 3 - ev.rank, 1)
        moved = math.nan
        while lam <= 1e12:
            step = _solve(H + lam * np.diag(np.diag(H)), grad)
            if step is None:
                break
            new = theta + step
            ev_new = prob.evaluate(new)
            if ev_new is not None and ev_new.rss < ev.rss:
                lam = max(lam / 10.0, 1e-12)
                moved = float(step @ H @ step)
                theta, ev = new, ev_new
                break
            lam *= 10.0
        if not moved >= 0:  # no step lowers the RSS: at its minimum, to rounding
            return theta, ev, it, True
        if moved <= step_tol**2 * s2 or moved <= 1e-28 * float(np.sum(theta**2 * np.diag(H))):
            return theta, ev, it, True
    return theta, ev, it, False


def fit_inloop(windows: Sequence[RunWindow], starts: Sequence[np.ndarray | None], *,
               tries: int = 3, good_sigma: float | None = None,
               max_iter: int = _MAX_ITER, step_tol: float = _STEP_TOL) -> InLoopFit:
    """The output-error fit of m, c, k over the runs' windows (module docstring).

    Parameters
    ----------
    windows : sequence of RunWindow
        The runs' windows (:mod:`phoid.methods.inloop_model`).
    starts : sequence of (m, c, k) or None
        Starting points (the modal route's estimate, :func:`equation_error_starts`).
    tries : int
        The fit descends from the ``tries`` starts that fit best (the output error has local
        minima) and keeps the lowest RSS; it stops early at a fit whose σ̂ is within
        ``good_sigma``.
    good_sigma : float, optional
        The records' noise sd (from their differences, without the model) times a tolerance.
    max_iter : int
        Most iterations per descent.
    step_tol : float
        Converged when a step moves θ by less than this many of its stderr (Mahalanobis).

    Returns
    -------
    InLoopFit

    Raises
    ------
    IdentificationError
        When no start can be evaluated, or the fit leaves m, c, k undetermined (a singular
        information matrix).
    """
    if not windows:
        raise IdentificationError("no run has a window for the in-loop fit")
    prob = _Problem(windows)
    cands: list[tuple[float, int, np.ndarray, _Eval]] = []
    for i, st in enumerate(starts):
        if st is None:
            continue
        th = np.asarray(st, dtype=float)
        ev = prob.evaluate(th)
        if ev is not None:
            cands.append((ev.rss, i, th, ev))
    if not cands:
        raise IdentificationError("the in-loop fit has no start at which the plant's response "
                                  "can be evaluated")
    cands.sort(key=lambda c: (c[0], c[1]))
    best: tuple[np.ndarray, _Eval, int, bool] | None = None
    for _rss, _i, th, ev in cands[: max(tries, 1)]:
        out = _descend(prob, th, ev, max_iter, step_tol)
        if best is None or out[1].rss < best[1].rss:
            best = out
        dof = max(prob.n - 3 - out[1].rank, 1)
        if good_sigma is not None and math.sqrt(out[1].rss / dof) <= good_sigma:
            break
    assert best is not None
    theta, ev, it, converged = best
    A = ev.jac.reshape(-1, 3)
    info = A.T @ A
    p = 3 + ev.rank
    dof = prob.n - p
    if dof <= 0:
        raise IdentificationError(f"the in-loop fit has {prob.n} samples for {p} parameters")
    d = np.sqrt(np.diag(info))
    try:
        if not np.all(d > 0):
            raise np.linalg.LinAlgError
        inv = np.linalg.inv(info / np.outer(d, d)) / np.outer(d, d)
    except np.linalg.LinAlgError:
        raise IdentificationError("the in-loop fit leaves m, c, k undetermined (the runs' "
                                  "responses do not separate them)") from None
    s2 = ev.rss / dof
    cov = s2 * 0.5 * (inv + inv.T)
    res = tuple(ev.resid[i, : w.size].copy() for i, w in enumerate(windows))
    jac = tuple(ev.jac[i, : w.size].copy() for i, w in enumerate(windows))
    noise = tuple(difference_noise(w.y, rounding=True) for w in windows)
    return InLoopFit(float(theta[0]), float(theta[1]), float(theta[2]), cov, info,
                     math.sqrt(s2), ev.rss, prob.n, p, ev.offset,
                     tuple(w.run for w in windows), tuple(w.start for w in windows), res, jac,
                     noise, it, converged)
