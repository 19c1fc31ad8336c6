"""Variable-projection Gauss–Newton for (σ, ω_d) on a stack of records, and the exact-residual
polish at its optimum.

Every record of a :class:`phoid.fits._stack.Stack` keeps its own iteration, step length and
stopping point; the records still iterating are evaluated together. A single record is a
stack of one.
"""

from __future__ import annotations

import numpy as np

from phoid.fits._stack import Stack, every

__all__ = ["MAXIT", "descend", "gauss_newton", "polish", "put", "small_step", "take"]

#: most Gauss–Newton iterations of one fit
MAXIT = 50


def take(pt: dict, sel) -> dict:
    """The rows ``sel`` of every array of the point ``pt``."""
    return {k: v[sel] for k, v in pt.items()}


def put(pt: dict, sel, new: dict) -> None:
    """Overwrite the rows ``sel`` of the point ``pt`` with ``new``."""
    for k, v in new.items():
        pt[k][sel] = v


def small_step(Minv: np.ndarray, g: np.ndarray, sse: np.ndarray, dof: np.ndarray,
               rtol_se: float, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss–Newton step (σ, ω_d) per record, (JᵀJ)⁻¹ Jᵀr's last two rows, and whether
    both of its components are at most max(``rtol_se`` standard errors, ``floor``), the
    standard errors at the residual variance sse/dof."""
    step = (Minv[:, -2:] @ g[:, :, None])[:, :, 0]
    dg = Minv.diagonal(axis1=1, axis2=2)[:, -2:]
    se = np.sqrt(np.maximum(dg * (sse / dof)[:, None], 0.0))
    return step, (np.abs(step) <= np.maximum(rtol_se * se, floor[:, None])).all(axis=1)


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
        whole = act.size == R
        sub = pt if whole else take(pt, act)
        Mi, g, ok = bt.normal(sub)
        if whole:
            Minv, iters[:] = Mi, it
        else:
            Minv[act], iters[act] = Mi, it
        sig, om, sse = sub["sig"], sub["om"], sub["sse"]
        dof = bt.dof if whole else bt.dof[act]
        if not every(ok):
            act, Mi, g, dof = act[ok], Mi[ok], g[ok], dof[ok]
            sig, om, sse = sig[ok], om[ok], sse[ok]
            if act.size == 0:
                break
        scale = np.abs(sig) + np.abs(om)
        step, done = small_step(Mi, g, sse, dof, rtol_se, 1e-10 * scale)
        if every(done):
            converged[act] = True
            break
        if np.count_nonzero(done):
            converged[act[done]] = True
            keep = ~done
            act, step, scale = act[keep], step[keep], scale[keep]
            sig, om, sse = sig[keep], om[keep], sse[keep]
        if it == maxit:
            break
        # the full step for every record still iterating, then step halving for those whose
        # RSS it raised (beyond rounding), all records still searching evaluated together
        # (pt's rows still searched, read through sig, om, sse, are not written meanwhile)
        cand = bt.evaluate(act, sig + step[:, 0], np.abs(om + step[:, 1]))
        good = cand["ok"] & (cand["sse"] <= sse + (bt.floor if act.size == R else bt.floor[act]))
        if every(good):
            if act.size == R:
                pt = cand  # every record moved: the new point whole
            else:
                put(pt, act, cand)
            continue
        put(pt, act[good], take(cand, good))
        moved = good
        lam = np.full(act.size, 0.5)
        search = np.flatnonzero(~good)
        while search.size:
            rows = act[search]
            cand = bt.evaluate(rows, sig[search] + lam[search] * step[search, 0],
                               np.abs(om[search] + lam[search] * step[search, 1]))
            good = cand["ok"] & (cand["sse"] <= sse[search] + bt.floor[rows])
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
    act = rows if every(has) else rows[has]
    dof = np.maximum(bt.n - bt.m, 1)
    for _ in range(3):
        if act.size == 0:
            break
        sse = np.array([float(r[i] @ r[i]) for i in act.tolist()])
        if act.size == R:
            sig, om = pt["sig"], pt["om"]
            step, small = small_step(Minv, g_all, sse, dof, rtol_se,
                                     1e-15 * (np.abs(sig) + np.abs(om)))
        else:
            sig, om = pt["sig"][act], pt["om"][act]
            step, small = small_step(Minv[act], g_all[act], sse, dof[act], rtol_se,
                                     1e-15 * (np.abs(sig) + np.abs(om)))
        if every(small):
            break
        big = ~small
        act, step, sse, sig, om = act[big], step[big], sse[big], sig[big], om[big]
        q = bt.evaluate(act, sig + step[:, 0], np.abs(om + step[:, 1]))
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
    if not np.count_nonzero(ok):
        return None
    rows = np.flatnonzero(ok)
    if not every(ok):
        st = st.subset(rows)
        pt = st.evaluate(np.arange(rows.size), sig[rows], om[rows])
    pt, Minv, converged, iters = gauss_newton(st, pt, rtol_se, maxit)
    return rows, st, pt, Minv, converged, iters
