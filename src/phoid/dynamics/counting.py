"""Certified counts of the delayed PD loop's characteristic roots (the argument principle).

The number of zeros of f(s) = m s² + c s + k + (D s + P) e^{−sΔt} (eq. 23) in the half-plane
Re s > a, which all lie in a computable disc, is the winding number of f along a rectangle's
boundary. The root finders of :mod:`phoid.dynamics.rightmost` compare it with the number of
roots they found there, so that a root cannot be missed.
"""

from __future__ import annotations

import numpy as np

from phoid.dynamics.quasipolynomial import characteristic

__all__ = ["count_roots_right_of", "count_roots_right_of_many"]


def _root_radius(m, c, k, P, D, delay, a):
    """Radius R such that every root with Re s ≥ a satisfies |s| ≤ R.

    From |m s² + c s + k| ≥ m|s|² − |c||s| − |k| and |(D s + P) e^{−sΔt}| ≤ (|D||s| + |P|)
    e^{−aΔt} (c, k of either sign: planning and the friction fits pass negative ones). ``a``,
    ``m``, ``P``, ``D`` may be arrays (broadcast together: R per element); floats give a float.
    """
    g = np.exp(-np.asarray(a) * delay)
    b = abs(c) + np.abs(D) * g
    d = abs(k) + np.abs(P) * g
    R = (b + np.sqrt(b * b + 4 * m * d)) / (2 * m) + 1e-9
    return float(R) if np.ndim(R) == 0 else R


def count_roots_right_of(
    a: float, m: float, c: float, k: float, P: float, D: float, delay: float,
    near: np.ndarray | None = None,
) -> int:
    """Number of roots of f (with multiplicity) in Re s > a, by the argument principle.

    The roots in that half-plane all lie in the disc |s| ≤ R (see :func:`_root_radius`), so the
    winding number of f along the rectangle [a, R] × [−R, R] counts them. By conjugate
    symmetry only the upper half of the boundary is sampled. On its outer edges (right and
    top) f = m s²(1 + w) with |w| < 1 bounded rigorously, so their turn of arg f follows
    exactly from the two corner values (:func:`_outer_turn`); only the left edge, where the
    roots near Re s = a make f turn, is sampled, finely enough that f turns by less than
    0.5 rad between samples (refined until so, up to 4·2²² samples; a RuntimeError beyond).
    Where that bound does not hold (|c|, |k| too large for the radius) the whole upper half
    boundary is sampled instead.

    Parameters
    ----------
    a : float
        Abscissa, 1/s. It must not pass through a root (callers choose it between roots).
    m, c, k, P, D, delay : float
        Plant (kg, N·s/m, N/m), gains (N/m, N·s/m) and delay (s).
    near : array_like of complex, optional
        Roots the caller knows (e.g. the ones it is certifying and the next one). Where one lies
        at a distance d from the line Re s = a, f turns by ~π over a stretch ~2d of it; that
        stretch gets samples d/6 apart, so the uniform sampling need not be that fine
        everywhere. An optimisation only: the count is the same, and the 0.5 rad check holds
        for every sample.

    Returns
    -------
    int
        The count of characteristic roots with real part greater than ``a``.
    """
    R = _root_radius(m, c, k, P, D, delay, a)
    if R <= a:
        return 0
    R = R * 1.05 + 1.0
    # f has real coefficients, f(s̄) = conj f(s): the lower half of the rectangle turns f by as
    # much as the upper half, so only the path (R, 0) → (R, R) → (a, R) → (a, 0) is followed
    # and its turn doubled (the count is the turn over 2π, i.e. the half path's over π)
    turn, sure = _outer_turn(np.array([a]), np.array([R]), np.array([float(m)]), c, k,
                             np.array([float(P)]), np.array([float(D)]), delay)
    outer = float(turn[0]) if sure[0] else None
    n = max(128, int(8 * (1 + R * delay)))
    corners = (complex(R, 0.0), complex(R, R), complex(a, R), complex(a, 0.0))
    # only roots the uniform spacing R/n would not resolve (f turns by ~spacing/d there)
    local = (np.zeros(0) if near is None
             else _local_samples(np.asarray(near, dtype=complex).ravel(), a, R, n))
    while n <= 1 << 22:  # beyond that the abscissa lies far left of any useful root
        u = np.linspace(0.0, 1.0, n, endpoint=False)
        # the left edge, from (a, R) down to (a, 0), with the local samples merged in
        y = np.unique(np.concatenate([R * (1.0 - u), local]))[::-1]
        left = [a + 1j * y, [corners[3]]]
        z = np.concatenate(left if outer is not None else
                           [corners[i] + (corners[i + 1] - corners[i]) * u for i in range(2)]
                           + left)
        f, _ = characteristic(z, m, c, k, P, D, delay)
        if np.any(f == 0):
            raise ValueError(f"abscissa a = {a:g} 1/s passes through a characteristic root")
        dang = np.angle(f[1:] / f[:-1])
        if np.max(np.abs(dang)) < 0.5:
            return round(((outer or 0.0) + float(dang.sum())) / np.pi)
        n *= 2
    raise RuntimeError("argument-principle count did not resolve; the loop is pathological")


def _outer_turn(a, R, m, c, k, P, D, delay):
    """Turn of arg f along the outer edges (R, 0) → (R, R) → (a, R), exactly, from two values.

    On those edges |s| ≥ R and Re s ≥ a, so (triangle inequality, with |c| and |k|: any sign)

        |f(s) − m s²| ≤ |c||s| + |k| + (|D||s| + |P|) e^{−aΔt} =: h(|s|),

    and h(r)/(m r²) decreases in r. Where h(R) < m R² ("sure"), w = f/(m s²) − 1 has |w| < 1
    all along the edges: f has no zero there (nor anywhere with Re s ≥ a and |s| ≥ R, so the
    rectangle holds every root right of a), and arg f = 2 arg s + Arg(1 + w) with the principal
    Arg continuous (Re(1 + w) > 0). Its turn is therefore exactly

        Δ arg f = 2 atan2(R, a) + Arg(f(a + iR)/(m (a + iR)²)) − Arg(f(R)/(m R²)),

    arg s going continuously from 0 to atan2(R, a) ∈ (0, π) (Im s = R > 0 on the top edge).
    No sampling is needed there: it is a bound, not a sampled check.

    Parameters
    ----------
    a, R : ndarray
        Abscissae (1/s) and contour half-widths (1/s), R > a.
    m : ndarray
        Masses, kg.
    c, k : float
        Damping (N·s/m) and stiffness (N/m).
    P, D : ndarray
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    turn : ndarray
        Δ arg f along the outer edges, rad (meaningful where ``sure``).
    sure : ndarray of bool
        Where the bound h(R) < m R² holds (with a relative margin of 1e-12 for rounding).
    """
    g = np.exp(-a * delay)
    h = abs(c) * R + abs(k) + (np.abs(D) * R + np.abs(P)) * g
    sure = (m > 0) & (h < (1.0 - 1e-12) * m * R * R)
    end = a + 1j * R
    with np.errstate(all="ignore"):
        fe, _ = characteristic(end, m, c, k, P, D, delay)
        fs, _ = characteristic(R + 0j, m, c, k, P, D, delay)
        turn = (2.0 * np.arctan2(R, a) + np.angle(fe / (m * end * end))
                - np.angle(fs / (m * R * R)))
    return turn, sure & np.isfinite(turn)


_LOCAL_OFF = np.linspace(-6.0, 6.0, 73)  # local samples: ±6d about a near root, d/6 apart


def _local_samples(r: np.ndarray, a: float, R: float, n: int) -> np.ndarray:
    """Extra left-edge ordinates near known roots ``r`` (see :func:`count_roots_right_of`)."""
    r = r[np.isfinite(r)]
    d = np.abs(r.real - a)
    keep = (d > 0) & (d < 3.0 * R / n) & (np.abs(r.imag) - 6 * d < R)
    if not np.any(keep):
        return np.zeros(0)
    local = (np.abs(r.imag[keep])[:, None] + d[keep][:, None] * _LOCAL_OFF).ravel()
    return local[(local > 0) & (local < R)]


def _left_ordinates(near, a, R, n):
    """Every loop's left-edge ordinates, descending: the uniform R(1 − u) and the local samples
    of :func:`_local_samples` (the same numbers), all loops at once.

    Parameters
    ----------
    near : list of array_like of complex, or None
        Each loop's known roots, 1/s.
    a, R : ndarray, shape (n_loops,)
        Abscissae and contour half-widths, 1/s.
    n : int
        Uniform samples per edge.

    Returns
    -------
    ndarray, shape (n_loops, w)
        Row i: the distinct ordinates of loop i in decreasing order, padded by repeating the
        last (a repeated point adds no turn of f, f(z)/f(z) = 1 exactly).
    """
    u = np.linspace(0.0, 1.0, n, endpoint=False)
    Y = np.multiply.outer(R, 1.0 - u)
    if near is None:
        return Y
    rs = [np.asarray(r, dtype=complex).ravel() for r in near]
    size = np.array([r.size for r in rs])
    if not size.sum():
        return Y
    # the known roots as a NaN-padded (loops × roots) table
    row = np.repeat(np.arange(len(rs)), size)
    col = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
    r = np.full((len(rs), int(size.max())), np.nan, dtype=complex)
    r[row, col] = np.concatenate(rs)
    with np.errstate(invalid="ignore"):
        d = np.abs(r.real - a[:, None])
        Rc = R[:, None]
        keep = (d > 0) & (d < 3.0 * Rc / n) & (np.abs(r.imag) - 6 * d < Rc)
        if not keep.any():
            return Y
        local = np.abs(r.imag)[:, :, None] + d[:, :, None] * _LOCAL_OFF
        Rc = Rc[:, :, None]
        local = np.where(keep[:, :, None] & (local > 0) & (local < Rc), local, np.nan)
    Y = -np.sort(-np.concatenate([Y, local.reshape(len(rs), -1)], axis=1), axis=1)  # NaN last
    valid = np.count_nonzero(np.isfinite(Y), axis=1)
    Y = Y[:, : int(valid.max())]
    return np.where(np.isnan(Y), Y[np.arange(len(rs)), valid - 1][:, None], Y)


def count_roots_right_of_many(
    a: np.ndarray, m: np.ndarray | float, c: float, k: float, P: np.ndarray, D: np.ndarray,
    delay: float, near: list[np.ndarray] | None = None,
) -> np.ndarray:
    """:func:`count_roots_right_of` for many loops at once (one abscissa each), vectorised.

    The outer edges' turn of arg f is exact (:func:`_outer_turn`); every loop's left edge is
    sampled with the points of the first refinement level of the scalar count (the uniform
    ones, as many for every loop: the most any of them needs, and the local ones), so that f
    is evaluated for all of them in one array operation; the left edges, which carry a
    different number of local samples per loop, are padded by repeating their last point (a
    repeated point adds no turn of f). A loop whose count does not resolve at that sampling (f
    turns by 0.5 rad or more between two samples), whose contour meets a root or whose outer
    edges the bound does not cover gets −1: the caller then asks :func:`count_roots_right_of`
    for it, which refines its own sampling or raises.

    Parameters
    ----------
    a : array_like, shape (n,)
        Abscissa of each loop, 1/s.
    m : float or array_like, shape (n,)
        Mass of each loop's plant, kg (an added mass differs per run).
    c, k : float
        Damping (N·s/m) and stiffness (N/m), shared.
    P, D : array_like, shape (n,)
        Each loop's gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s (> 0).
    near : list of array_like, optional
        Each loop's known roots (as ``near`` of :func:`count_roots_right_of`).

    Returns
    -------
    ndarray of int
        The count of roots right of each abscissa, or −1 where undecided here.
    """
    a = np.asarray(a, dtype=float).ravel()
    nl = a.size
    mm = np.broadcast_to(np.asarray(m, dtype=float), (nl,))
    P = np.broadcast_to(np.asarray(P, dtype=float), (nl,))
    D = np.broadcast_to(np.asarray(D, dtype=float), (nl,))
    out = np.full(nl, -1, dtype=int)
    if nl == 0:
        return out
    R = _root_radius(mm, c, k, P, D, delay, a)  # the disc holding every root with Re s ≥ a
    out[R <= a] = 0
    idx = np.flatnonzero(R > a)
    if idx.size == 0:
        return out
    R = R[idx] * 1.05 + 1.0
    ai, mi, Pi, Di = a[idx], mm[idx], P[idx], D[idx]
    outer, sure = _outer_turn(ai, R, mi, c, k, Pi, Di, delay)
    n = int(max(128, int(np.max(8 * (1 + R * delay)))))
    Y = _left_ordinates(None if near is None else [near[i] for i in idx.tolist()], ai, R, n)
    # the left edge (a, R) → (a, 0), local samples merged in, and its end (a, 0)
    z = np.concatenate([ai[:, None] + 1j * Y, ai[:, None] + 0j], axis=1)
    f, _ = characteristic(z, mi[:, None], c, k, Pi[:, None], Di[:, None], delay)
    with np.errstate(divide="ignore", invalid="ignore"):
        dang = np.angle(f[:, 1:] / f[:, :-1])
    good = sure & np.all(f != 0, axis=1) & np.all(np.abs(dang) < 0.5, axis=1)
    out[idx[good]] = np.rint((outer[good] + dang[good].sum(axis=1)) / np.pi).astype(int)
    return out

