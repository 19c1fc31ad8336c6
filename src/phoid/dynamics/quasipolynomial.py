"""The characteristic function of the delayed PD loop and its Newton refinement (eq. 23).

The closed loop m x'' + c x' + k x = −[D x'(t−Δt) + P x(t−Δt)] (eq. 23) has the characteristic
equation

    f(s) = m s² + c s + k + (D s + P) e^{−sΔt} = 0,

a retarded quasi-polynomial with infinitely many roots but finitely many in any right half-plane.
This module evaluates f and f′ and refines approximate roots by Newton's method, for one start,
a few, or a (loops × starts) array at once; the root finders of :mod:`phoid.dynamics.rightmost`
and the counts of :mod:`phoid.dynamics.counting` are built on it.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

__all__ = ["characteristic"]


def characteristic(
    s: np.ndarray | complex,
    m: float,
    c: float,
    k: float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
) -> tuple[np.ndarray, np.ndarray]:
    """f(s) = m s² + c s + k + (D s + P) e^{−sΔt} and f′(s) (from eq. 23).

    Parameters
    ----------
    s : array_like of complex
        Laplace variable, 1/s.
    m, c, k : float
        Plant mass (kg), damping (N·s/m) and stiffness (N/m).
    P, D : float or array_like
        Gains, N/m and N·s/m (broadcast against ``s``).
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    f, df : ndarray of complex
        The characteristic function (N/m) and its derivative with respect to s.
    """
    s = np.asarray(s, dtype=complex)
    e = np.exp(-s * delay)
    f = m * s * s + c * s + k + (D * s + P) * e
    df = 2.0 * m * s + c + (D - delay * (D * s + P)) * e
    return f, df


#: Newton steps a continued root may take: from a neighbouring run's root it converges in a
#: handful; one that has not in 12 is rejected, and its run continues from a nearer one or is
#: computed in full, instead of wandering for 30 steps (docs/design-notes/dynamics.md)
_CONT_ITERS = 12


def _newton(s, m, c, k, P, D, delay, iters=30):
    """Vectorised Newton iteration on f; returns refined roots and the final |f| residual.

    Iterates until every start has converged or ``iters`` is reached; starts that have not
    converged by then (spurious eigenvalues of the discretisation) keep a large residual and are
    discarded by the callers. f and f′ are those of :func:`characteristic`, evaluated inline
    (D s + P once per step) with the same arithmetic.
    """
    s = np.array(s, dtype=complex)
    with np.errstate(all="ignore"):
        for _ in range(iters):
            e = np.exp(-s * delay)
            q = D * s + P
            f = m * s * s + c * s + k + q * e
            df = 2.0 * m * s + c + (D - delay * q) * e
            step = np.where(df != 0, f / df, 0.0)
            s = s - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(np.abs(s), 1.0)):
                break
    f, _ = characteristic(s, m, c, k, P, D, delay)
    return _snap_real(s, np.abs(f), m, c, k, P, D, delay)


#: a converged root within this (relative) distance of the real axis, Im ≠ 0, is re-converged
#: from its real part in real arithmetic (:func:`_snap_real`)
_REAL_SNAP = 1e-10


def _snap_real(z, res, m, c, k, P, D, delay):
    """Roots that a complex start took onto a real root, made exactly real.

    Newton from a complex start converges to a real root with Im s at rounding level (1e−27
    … 1e−41), not 0, while from a real start it stays exactly real. A root so near the axis
    would be taken for a complex pair downstream (two fit columns, one of them ~1e−33 τe^{sτ}
    and, scaled, free), so every converged z with 0 < |Im z| ≤ 1e−10 max(|z|, 1) is iterated
    again from Re z + 0i (real arithmetic: the iterate stays real) and replaced by the result
    where that converges within 1e−6 max(|z|, 1) of z; a genuine complex pair that close to
    the axis has no real root there to converge to and is kept.

    Parameters
    ----------
    z : ndarray of complex
        Refined roots, 1/s.
    res : ndarray
        |f(z)|, N/m (∞ where the iteration ran off).
    m : float or ndarray broadcastable to z.shape
        Plant mass, kg (one per run where runs add mass).
    c, k : float
        Plant damping and stiffness (N·s/m, N/m).
    P, D : float or ndarray broadcastable to z.shape
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    (ndarray of complex, ndarray)
        z and res, the snapped entries replaced.
    """
    z = np.asarray(z, dtype=complex)
    res = np.asarray(res, dtype=float)
    with np.errstate(invalid="ignore"):
        near = (np.isfinite(res) & (z.imag != 0)
                & (np.abs(z.imag) <= _REAL_SNAP * np.maximum(np.abs(z), 1.0)))
    if not near.any():
        return z, res
    z, res = z.copy(), res.copy()
    # m too may be one per run (m + Δmᵢ: the added-mass trick); the scalar iteration takes
    # each run's own numbers
    Pb, Db = np.broadcast_to(P, z.shape), np.broadcast_to(D, z.shape)
    mb = np.broadcast_to(np.asarray(m, dtype=float), z.shape)
    for idx in zip(*np.nonzero(near), strict=True):
        w = complex(z[idx])
        x, r = _newton_scalar(np.array([complex(w.real, 0.0)]), float(mb[idx]), c, k,
                              float(Pb[idx]), float(Db[idx]), delay, _CONT_ITERS)
        if math.isfinite(r[0]) and x[0].imag == 0 and abs(x[0] - w) <= 1e-6 * max(abs(w), 1.0):
            z[idx], res[idx] = x[0], r[0]
    return z, res


def _newton_few(s, m, c, k, P, D, delay, iters=_CONT_ITERS):
    """:func:`_newton` for a handful of roots of one loop, in scalar complex arithmetic.

    Each start is iterated on its own until its step is below 1e-15 of its modulus (or of 1)
    or f′ vanishes or f is not finite there, for at most ``iters`` steps: the rule of
    :func:`_newton_rows`, in plain ``cmath`` (for a few starts a numpy call's overhead would
    dominate the work). Returns the refined points and |f| there, ∞ for a start that ran off
    or has not converged in ``iters`` steps (rejected by the callers).
    """
    z, res = _newton_scalar(s, m, c, k, P, D, delay, iters)
    return _snap_real(z, res, m, c, k, P, D, delay)


def _newton_scalar(s, m, c, k, P, D, delay, iters):
    """:func:`_newton_few` without its :func:`_snap_real` (a real start stays real here)."""
    out, res = [], []
    for z in np.asarray(s, dtype=complex).tolist():
        try:
            for _ in range(iters):
                e = cmath.exp(-z * delay)
                f = m * z * z + c * z + k + (D * z + P) * e
                df = 2.0 * m * z + c + (D - delay * (D * z + P)) * e
                if df == 0 or not cmath.isfinite(f):
                    break
                step = f / df
                z = z - step
                if abs(step) <= 1e-15 * max(abs(z), 1.0):
                    break
            else:
                raise OverflowError  # not converged in `iters` steps: rejected as run off
            r = abs(m * z * z + c * z + k + (D * z + P) * cmath.exp(-z * delay))
        except (OverflowError, ZeroDivisionError):
            r = math.inf  # a start that ran off: discarded by the caller's residual test
        out.append(z)
        res.append(r if math.isfinite(r) else math.inf)
    return np.array(out, dtype=complex), np.array(res)


def _newton_rows(s, m, c, k, P, D, delay, iters=_CONT_ITERS, tail=12):
    """Newton on f for many loops at once, every start with its own stopping rule.

    Each element of ``s`` (one row per loop; NaN marks an empty slot) is iterated until its
    own step is below 1e-15 of its modulus (or of 1), f′ vanishes or f is not finite there
    (the element is then left as it is), or ``iters`` steps are taken: the per-start rule of a
    scalar Newton iteration (:func:`_newton_few`), applied to the whole array at once
    (converged elements are no longer updated). Once at most ``tail`` elements are still
    iterating (a start far from its root), numpy's per-call overhead would dominate: those are
    finished by :func:`_newton_few`, with the steps left.

    Parameters
    ----------
    s : ndarray of complex, shape (n, r)
        Starting points, 1/s; NaN where a row has fewer than ``r``.
    m, c, k : float
        Plant mass (kg), damping (N·s/m) and stiffness (N/m), shared.
    P, D : ndarray, shape (n, 1)
        Each row's gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    iters : int, default _CONT_ITERS (12)
        Most steps per start.
    tail : int, default 12
        The number of elements still iterating below which they are finished one by one.

    Returns
    -------
    z : ndarray of complex, shape (n, r)
        The refined points.
    res : ndarray, shape (n, r)
        |f(z)| (N/m), ∞ where it is not finite (a start that ran off, or an empty slot).
    """
    z = np.array(s, dtype=complex)
    P, D = np.broadcast_to(P, z.shape), np.broadcast_to(D, z.shape)
    live = np.isfinite(z)
    res = np.full(z.shape, np.inf)
    done = 0
    if np.count_nonzero(live) > tail:
        with np.errstate(all="ignore"):
            while done < iters and np.count_nonzero(live) > tail:
                done += 1
                e = np.exp(z * -delay)  # the same number as exp(−z·Δt): negation is exact
                q = D * z + P
                f = m * z * z + c * z + k + q * e
                df = 2.0 * m * z + c + (D - delay * q) * e
                live &= (df != 0) & np.isfinite(f)
                step = f / df
                new = z - step
                z = np.where(live, new, z)
                # (a live step is finite or ±∞, never NaN: "not converged" is a comparison)
                live &= np.abs(step) > 1e-15 * np.maximum(np.abs(new), 1.0)
            r = np.abs(m * z * z + c * z + k + (D * z + P) * np.exp(-z * delay))
        res = np.where(np.isfinite(r) & ~live, r, np.inf)  # live at the end: not converged
    if done < iters:
        for i in np.flatnonzero(live.any(axis=1)).tolist():
            # the last few still iterating: scalar steps, as many as are left, one call a row
            j = live[i]
            z[i, j], res[i, j] = _newton_scalar(z[i, j], m, c, k, float(P[i, 0]),
                                                float(D[i, 0]), delay, iters - done)
    return _snap_real(z, res, m, c, k, P, D, delay)


def _unique(z: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
    """z without near-duplicates (first occurrence kept)."""
    z = np.asarray(z, dtype=complex)
    close = np.abs(z[:, None] - z[None, :]) <= rtol * np.maximum(np.abs(z)[None, :], 1.0)
    dup = np.any(np.tril(close, -1), axis=1)
    return z[~dup]


def _sort_pairs(z: np.ndarray) -> np.ndarray:
    key = np.lexsort((-z.imag, -np.round(z.real, 10)))
    return z[key]

