"""Variable-projection Gauss–Newton for (σ, ω_d) on a stack of records, and the exact-residual
polish at its optimum.

Every record of a :class:`phoid.fits._stack.Stack` keeps its own iteration, step length and
stopping point; the records still iterating are evaluated together. A single record is a
stack of one.
"""

from __future__ import annotations

import numpy as np

from phoid.fits._stack import Stack

__all__ = ["MAXIT", "descend", "gauss_newton", "polish", "put", "take"]

#: most Gauss–Newton iterations of one fit
MAXIT = 50




def take(pt: dict, sel) -> dict:
    """The rows ``sel`` of every array of the point ``pt``."""
    return {k: v[sel] for k, v in pt.items()}


def put(pt: dict, sel, new: dict) -> None:
    """Overwrite the rows ``sel`` of the point ``pt`` with ``new``."""
    for k, v in new.items():
        pt[k][sel] = v


def step_se(Minv, g, sse, dof):
    """Gauss–Newton step (σ, ω_d) and its standard errors at residual variance sse/dof."""
    step = np.einsum("rij,rj->ri", Minv[:, -2:], g)
    var = sse / dof
    se0 = np.sqrt(np.maximum(Minv[:, -2, -2] * var, 0.0))
    se1 = np.sqrt(np.maximum(Minv[:, -1, -1] * var, 0.0))
    return step, se0, se1


def gauss_newton(bt: Stack, pt: dict, rtol_se: float = 0.05, maxit: int | None = None):
    """Variable-projection Gauss–Newton (Kaufman's step from the full Jacobian) for (σ, ω_d)
    of every record of the point ``pt`` (all evaluable), in lock step.

    Each record stops on its own test: converged when its proposed step is below ``rtol_se``
    standard errors, or below 10⁻¹⁰ of |σ| + ω_d (noise-free data, where the tabulated
    gradient's rounding sets the floor; the last steps are left to :func:`polish`). A step
    that would raise the RSS (beyond rounding) is halved, down to 2⁻¹²; a record with no
    descent left is converged if its step is below 10⁻⁶ of |σ| + ω_d, else stuck. At most
    ``maxit`` (default :data:`MAXIT`) iterations. Returns (point, Minv (NaN where none),
    converged, iterations), one row per record."""
    maxit = MAXIT if maxit is None else maxit
    R = bt.R
    Minv = np.full((R, bt.m, bt.m), np.nan)
    converged = np.zeros(R, bool)
    iters = np.zeros(R, int)
    act = np.arange(R)
    for it in range(maxit + 1):
        sub = take(pt, act)
        Mi, g, ok = bt.normal(sub)
        Minv[act] = Mi
        iters[act] = it
        act, Mi, g, sub = act[ok], Mi[ok], g[ok], take(sub, ok)
        if act.size == 0:
            break
        step, se0, se1 = step_se(Mi, g, sub["sse"], bt.dof[act])
        scale = np.abs(sub["sig"]) + np.abs(sub["om"])
        done = (np.abs(step[:, 0]) <= np.maximum(rtol_se * se0, 1e-10 * scale)) & (
            np.abs(step[:, 1]) <= np.maximum(rtol_se * se1, 1e-10 * scale))
        converged[act[done]] = True
        keep = ~done
        act, step, scale, sub = act[keep], step[keep], scale[keep], take(sub, keep)
        if act.size == 0 or it == maxit:
            break
        # step halving per record, all records still searching evaluated together
        lam = np.ones(act.size)
        moved = np.zeros(act.size, bool)
        search = np.arange(act.size)
        while search.size:
            rows = act[search]
            cand = bt.evaluate(rows, sub["sig"][search] + lam[search] * step[search, 0],
                               np.abs(sub["om"][search] + lam[search] * step[search, 1]))
            good = cand["ok"] & (cand["sse"] <= sub["sse"][search] + bt.floor[rows])
            put(pt, rows[good], take(cand, good))
            moved[search[good]] = True
            lam[search[~good]] *= 0.5
            search = search[~good & (lam[search] >= 2.0**-12)]
        # no descent: at the rounding floor if the step is tiny, else stuck
        stuck = ~moved
        tiny = (np.abs(step[:, 0]) <= 1e-6 * scale) & (np.abs(step[:, 1]) <= 1e-6 * scale)
        converged[act[stuck & tiny]] = True
        act = act[moved]
        if act.size == 0:
            break
    return pt, Minv, converged, iters


def polish(bt: Stack, pt: dict, Minv: np.ndarray, rtol_se: float = 0.05):
    """Exact residual at the Gauss–Newton optimum ``pt`` of every record (sample by sample)
    and up to three more steps with the exact gradient while they are not negligible (below
    ``rtol_se`` standard errors or 10⁻¹⁵ relative) and lower the RSS. Returns (point,
    residuals, Minv), one row per record."""
    R = bt.R
    rows = np.arange(R)
    r, Gr = bt.residual(rows, pt)
    has = np.isfinite(Minv).all(axis=(1, 2))
    _m, g_all, _ok = bt.normal(pt, Gr, minv=Minv)
    act = rows[has]
    for _ in range(3):
        if act.size == 0:
            break
        sub = take(pt, act)
        sse = np.array([float(r[i] @ r[i]) for i in act.tolist()])
        step, se0, se1 = step_se(Minv[act], g_all[act], sse, np.maximum(bt.n[act] - bt.m, 1))
        tiny = 1e-15 * (np.abs(sub["sig"]) + np.abs(sub["om"]))
        small = (np.abs(step[:, 0]) <= np.maximum(rtol_se * se0, tiny)) & (
            np.abs(step[:, 1]) <= np.maximum(rtol_se * se1, tiny))
        act, step, sse, sub = act[~small], step[~small], sse[~small], take(sub, ~small)
        if act.size == 0:
            break
        q = bt.evaluate(act, sub["sig"] + step[:, 0], np.abs(sub["om"] + step[:, 1]))
        ok = q["ok"]
        r2, Gr2 = bt.residual(act, q)
        ok &= np.array([float(x @ x) for x in r2]) <= sse
        M2, g2, okn = bt.normal(q, Gr2)
        ok &= okn
        sel = act[ok]
        put(pt, sel, take(q, ok))
        for k in np.flatnonzero(ok).tolist():
            r[int(act[k])] = r2[k]
        Minv[sel], g_all[sel] = M2[ok], g2[ok]
        act = sel
    return pt, r, Minv


def descend(st: Stack, sig: np.ndarray, om: np.ndarray, rtol_se: float = 0.05,
            maxit: int | None = None) -> tuple[np.ndarray, Stack, dict, np.ndarray, np.ndarray,
                                               np.ndarray] | None:
    """:func:`gauss_newton` of the records of ``st`` from the starts (σ 1/s, ω_d rad/s) at which
    the model can be evaluated.

    Returns (rows, stack, point, Minv, converged, iterations) for those records (``rows``
    their indices in ``st``; ``stack`` holds just them, so that no record's sums see another's
    padding), or None when there are none.
    """
    pt = st.evaluate(np.arange(st.R), sig, om)
    ok = pt["ok"]
    if not ok.any():
        return None
    rows = np.flatnonzero(ok)
    if not ok.all():
        st = st.subset(rows)
        pt = st.evaluate(np.arange(rows.size), sig[rows], om[rows])
    pt, Minv, converged, iters = gauss_newton(st, pt, rtol_se, maxit)
    return rows, st, pt, Minv, converged, iters
