"""Levenberg–Marquardt for the friction fit, with f_c ≥ 0 and m > 0.

Marquardt's scaling (λ diag JᵀJ) and Nielsen's damping update, on the block-structured Jacobian
of :class:`phoid.methods.friction.model.Problem`. The columns of the globals (m, c, k, f_c)
cost a batched simulation each and the local ones none, so the globals' columns are reused over
a few steps (a chord method) and recomputed where it matters (:func:`levenberg_marquardt`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid._progress import step
from phoid.errors import IdentificationError
from phoid.methods.friction.model import BlockJacobian, Normal, Problem

__all__ = ["LMResult", "levenberg_marquardt"]

_MAX_CHORDS = 3  # chord steps in a row before the globals' columns are recomputed
_CHORD_SPAN = 10.0  # the covariance needs the globals' columns within this many stderr


@dataclass
class LMResult:
    """:func:`levenberg_marquardt`'s result: the parameter vector ``p``, the simulation ``XV``
    and the Jacobian ``J`` there, the cost ‖r‖², convergence and the iterations taken."""

    p: np.ndarray
    XV: Any
    J: BlockJacobian
    cost: float
    converged: bool
    iterations: int


def _solve_step(A: Normal, g, lam, p, ifc, ng):
    """(A + λ diag A) δ = g, holding f_c at its bound 0 when the step would push it below."""
    dA = np.maximum(A.diag(), 1e-300)
    keep = np.ones(ng, dtype=bool)
    for _ in range(2):
        try:
            delta = A.solve(g, lam, keep, dA)
        except np.linalg.LinAlgError:
            return None
        if ifc is not None and keep[ifc] and p[ifc] <= 0 and delta[ifc] < 0:
            keep[ifc] = False
            continue
        return delta
    return None


def levenberg_marquardt(prob: Problem, p0: np.ndarray, fixed: np.ndarray,
                        max_iter: int = 40, tol: float = 0.1,
                        confirm: bool = True) -> LMResult:
    """Minimise ‖r‖² (r the weighted residual) by Levenberg–Marquardt with f_c ≥ 0, m > 0.

    Marquardt's scaling (λ diag JᵀJ) and Nielsen's damping update. The columns of the globals
    cost a simulation each, the others none, so the globals' columns are recomputed only when
    a step fails, after three steps without them, or when the fit has converged more than
    ``_CHORD_SPAN`` standard errors (in the covariance metric below) from where they were
    computed (to confirm it there and to give the covariance); the other steps use the last
    columns with exact local ones (a chord method: near the optimum JᵀJ changes little over a
    few standard errors, so these steps converge like Gauss–Newton's).

    Converged when the Gauss–Newton step is shorter than ``tol`` in the metric of the
    parameters' covariance (δᵀJᵀJδ/s² ≤ tol², s² = χ²/dof: with tol = 0.1 no linear
    combination of the parameters would move by more than 0.1 of its standard error), or when a
    step fails although the full Gauss–Newton step promised less than one s² of decrease.
    ``confirm=False`` skips the confirmation with fresh columns (a preliminary fit).

    Parameters
    ----------
    prob : Problem
        The least-squares problem.
    p0 : ndarray
        Starting parameter vector (the free globals, then (x₀ᵢ, bᵢ, τᵢ) per run).
    fixed : ndarray, shape (4,)
        (m, c, k, f_c) with the values of the globals that are not fitted.
    max_iter : int, default 40
        Most iterations (accepted and rejected steps).
    tol : float, default 0.1
        Convergence tolerance, in standard errors.
    confirm : bool, default True
        Confirm a convergence with columns computed at the solution.

    Returns
    -------
    LMResult

    Raises
    ------
    IdentificationError
        If the starting plant cannot be simulated or its sensitivities computed.
    """
    p = p0.copy()
    theta, local = prob.split(p, fixed)
    XV = prob.simulate(theta, local[:, 0], local[:, 2])
    if XV is None:
        raise IdentificationError(
            f"the starting plant (m, c, k, fc) = {tuple(round(float(a), 6) for a in theta)} "
            "cannot be simulated for these gains"
        )
    r = prob.residual(local, XV)
    cost = float(r @ r)
    G = prob.global_columns(theta, local, XV)
    if G is None:
        raise IdentificationError("the model's sensitivities cannot be computed at the start")
    p_G = p.copy()  # where G was computed
    J = prob.jacobian(theta, local, XV, G)
    ifc = prob.ng - 1 if prob.free[3] else None  # index of f_c in p
    im = 0 if prob.free[0] else None
    dof = max(r.size - p.size, 1)
    lam, nu = 1e-3, 2.0
    converged = False
    it = chords = 0
    while it < max_iter:
        step()  # the progress bar's count of steps (a no-op unless switched on)
        A = J.normal()
        g = J.tdot(r)
        s2 = cost / dof
        exact = bool(np.array_equal(p, p_G))
        d_gn = _solve_step(A, g, 0.0, p, ifc, prob.ng)
        if d_gn is not None and A.quad(d_gn) <= tol * tol * s2:
            if not confirm or A.quad(p - p_G) <= _CHORD_SPAN**2 * s2:
                converged = True
                break
            # converged with columns from far away: confirm (and get the covariance) with
            # columns computed here
            G_new = prob.global_columns(theta, local, XV)
            if G_new is None:
                break
            G, p_G = G_new, p.copy()
            J = prob.jacobian(theta, local, XV, G)
            continue
        it += 1
        delta = _solve_step(A, g, lam, p, ifc, prob.ng)
        ok = delta is not None
        if ok:
            p_new = p + delta
            if ifc is not None and p_new[ifc] < 0:
                p_new[ifc] = 0.0
                delta = p_new - p
            ok = im is None or p_new[im] > 0
        cost_n = math.inf
        if ok:
            theta_n, local_n = prob.split(p_new, fixed)
            XVn = prob.simulate(theta_n, local_n[:, 0], local_n[:, 2])
            if XVn is not None:
                r_n = prob.residual(local_n, XVn)
                cost_n = float(r_n @ r_n)
        if not cost_n < cost:
            if not exact:  # the chord columns may be what failed: recompute them here
                G_new = prob.global_columns(theta, local, XV)
                if G_new is None:
                    break
                G, p_G = G_new, p.copy()
                J = prob.jacobian(theta, local, XV, G)
                continue
            if d_gn is not None and float(d_gn @ g) <= s2:
                # even the full Gauss–Newton step promised less than one s² of decrease
                converged = True
                break
            lam *= nu
            nu *= 2.0
            if lam > 1e12:
                break
            continue
        pred = float(2 * delta @ g) - A.quad(delta)
        rho = (cost - cost_n) / pred if pred > 0 else 0.0
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        p, theta, local, XV, r, cost = p_new, theta_n, local_n, XVn, r_n, cost_n
        chords = 0 if exact else chords + 1
        if chords >= _MAX_CHORDS:  # slow chord convergence: fresh columns
            G_new = prob.global_columns(theta, local, XV)
            if G_new is None:
                break
            G, p_G, chords = G_new, p.copy(), 0
        J = prob.jacobian(theta, local, XV, G)
    return LMResult(p, XV, J, cost, converged, it)
