"""The delayed proportional–derivative loop of the seed paper (eqs. 23–35).

The closed loop m x'' + c x' + k x = −[D x'(t−Δt) + P x(t−Δt)] (eq. 23) has the characteristic
equation

    f(s) = m s² + c s + k + (D s + P) e^{−sΔt} = 0,

a retarded quasi-polynomial with infinitely many roots but finitely many in any right half-plane.
Its rightmost roots are found by the spectral (Chebyshev collocation) discretisation of the DDE's
infinitesimal generator (Breda, Maset & Vermiglio 2005, the method of TRACE-DDE), refined by
Newton's method on f, and **certified** by the argument principle: the number of zeros of f in the
half-plane Re s ≥ a (which all lie in a computable disc) is counted along a rectangle's boundary
and must equal the number of roots found there, so a root cannot be missed.

For a dominant mode s = −σ + iω_d the delayed signal is exactly x(t−Δt) = e^{−sΔt}x(t) =
[(α₁ − σα₂) x − α₂ ẋ](t) with α₁ = e^{σΔt} cos(ω_dΔt) (ERRATA 1 in docs/equations.md — the
paper's eq. 29 prints an extra −(σ/ω_d) sin term) and α₂ = e^{σΔt} sin(ω_dΔt)/ω_d, which gives
eqs. (28)–(32).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from phoid import _validate as v
from phoid.dynamics.plant import Plant, quadratic_roots

__all__ = [
    "DelayedPD",
    "LoopModes",
    "alphas",
    "characteristic",
    "characteristic_roots",
    "count_roots_right_of",
    "count_roots_right_of_many",
    "dominant_roots",
    "forward_map",
    "inverse_map",
    "is_stable",
]


@dataclass(frozen=True)
class DelayedPD:
    """Proportional–derivative feedback u = −[D ẋ(t−Δt) + P x(t−Δt)] (eq. 23).

    Parameters
    ----------
    P : float
        Proportional gain, N/m (any sign).
    D : float
        Derivative gain, N·s/m (any sign; negative D removes damping).
    delay : float, default 0
        Loop delay Δt, s (≥ 0).
    """

    P: float
    D: float
    delay: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "P", v.finite("P", self.P, "N/m"))
        object.__setattr__(self, "D", v.finite("D", self.D, "N·s/m"))
        object.__setattr__(self, "delay", v.nonnegative("delay", self.delay, "s"))


# --------------------------------------------------------------------------------------------
# characteristic function


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


# Newton steps a continued root may take: from a neighbouring run's root it converges in a
# handful (at most 11 on the sample set's longest step); one that has not in 12 is rejected, and
# its run continues from a nearer one or is computed in full, instead of wandering for 30 steps
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
    :func:`_newton_rows`. For a few starts a numpy call's overhead would dominate the work;
    plain ``cmath`` is several times faster. Returns the refined points and |f| there, ∞ for a
    start that ran off or has not converged in ``iters`` steps (rejected by the callers).
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
    iters : int, default 30
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


def _cheb(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev extremal points on [−1, 1] (x₀ = 1) and the differentiation matrix."""
    j = np.arange(n + 1)
    x = np.cos(np.pi * j / n)
    cj = np.ones(n + 1)
    cj[0] = cj[-1] = 2.0
    cj = cj * (-1.0) ** j
    X = x[:, None] - x[None, :]
    Dm = (cj[:, None] / cj[None, :]) / (X + np.eye(n + 1))
    Dm -= np.diag(Dm.sum(axis=1))
    return x, Dm


def _generator_eigs(m, c, k, P, D, delay, n):
    """Eigenvalues of the order-n spectral discretisation of the DDE's infinitesimal generator."""
    A0 = np.array([[0.0, 1.0], [-k / m, -c / m]])
    A1 = np.array([[0.0, 0.0], [-P / m, -D / m]])
    _, Dm = _cheb(n)
    Dm = Dm * (2.0 / delay)  # map [-1, 1] -> [-delay, 0]; node 0 is theta = 0
    M = np.kron(Dm, np.eye(2))
    M[0:2, :] = 0.0
    M[0:2, 0:2] = A0
    M[0:2, -2:] = A1
    return np.linalg.eigvals(M)


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


def characteristic_roots(
    plant: Plant, loop: DelayedPD, *, count: int = 6, verify: bool = True
) -> np.ndarray:
    """The rightmost roots of m s² + c s + k + (D s + P) e^{−sΔt} = 0, exactly.

    Parameters
    ----------
    plant : Plant
        The plant (its f_c is ignored: the roots are those of the linear loop).
    loop : DelayedPD
        Gains and delay.
    count : int, default 6
        At least this many roots (fewer if the loop has fewer, e.g. Δt = 0 gives 2) are returned,
        conjugates counted separately.
    verify : bool, default True
        Certify with the argument principle that no root lies to the right of the last one
        returned that is not in the list.

    Returns
    -------
    ndarray of complex
        Roots, 1/s, sorted by decreasing real part (for a conjugate pair, positive imaginary
        part first), each accurate to Newton convergence (|f| at rounding level).

    Notes
    -----
    Δt = 0: the quadratic m s² + (c + D)s + (k + P) = 0 is solved in closed form. Otherwise the
    spectral discretisation (order n, increased until the requested rightmost roots converge)
    gives starting points that Newton refines; the result is certified as described in the
    module docstring.
    """
    return rightmost_roots(
        plant.m, plant.c, plant.k, loop.P, loop.D, loop.delay, count=count, verify=verify
    )


def rightmost_roots(m, c, k, P, D, tau, *, count=6, verify=True):
    """:func:`characteristic_roots` on raw numbers (m > 0; c, k of any sign).

    The first attempt is a quick one: a coarser discretisation (order 16, or 24 where more
    than 3 roots are asked) and Newton of at most :data:`_CONT_ITERS` steps per start, each
    start stopped on its own (:func:`_newton_rows`; the wanted roots converge in a handful from
    the eigenvalues, the spurious ones would take all 30 of the full iteration). Its result is
    certified like any other (and only a certified set is returned), so it is the same set of
    roots as the full computation's; where it does not certify (a root missed or not
    converged, or its abscissa so near a missed root that the count does not resolve), the
    full computation follows: order 16 or 32, Newton of up to 30 steps, the order doubled
    until the certificate agrees.
    """
    if tau == 0.0:
        return quadratic_roots(m, c + D, k + P)
    n = 16 if count <= 3 else 32  # doubled until the certificate (argument principle) agrees
    for attempt in range(7 if verify else 6):
        quick = verify and attempt == 0
        eig = _generator_eigs(m, c, k, P, D, tau, (16 if count <= 3 else 24) if quick else n)
        eig = eig[np.isfinite(eig)]
        # candidates: the rightmost eigenvalues, generously many
        order = np.argsort(-eig.real)
        cand = eig[order[: max(4 * count, 16)]]
        if quick:
            roots, res = _newton_rows(cand[None, :], m, c, k, np.array([[P]]), np.array([[D]]),
                                      tau)
            roots, res = roots[0], res[0]
        else:
            roots, res = _newton(cand, m, c, k, P, D, tau)
        scale = np.abs(m * roots**2) + np.abs(c * roots) + k + np.abs(D * roots) + abs(P)
        ok = res <= 1e-9 * np.maximum(scale, 1e-300)
        roots = _unique(roots[ok])
        roots = roots[np.argsort(-roots.real, kind="stable")]
        if roots.size >= min(count, 2):
            # keep whole conjugate pairs: cut at the first real-part gap after `count` roots
            re = roots.real
            gaps = np.flatnonzero(
                re[:-1] - re[1:] > 1e-9 * np.maximum(np.abs(re[:-1]), 1.0)
            )
            cut = next((g + 1 for g in gaps if g + 1 >= count), roots.size)
            if quick and cut == roots.size:
                # no gap after `count` roots among those found: the certificate below would
                # only prove that none is missed right of the last, not that `count` are there
                continue
            sel = roots[:cut]
            if not verify:
                return _sort_pairs(sel)
            # certify: count zeros right of an abscissa between the last kept root and the next
            nxt = roots[cut].real if roots.size > cut else sel[-1].real - 1.0
            a = 0.5 * (sel[-1].real + nxt)
            try:
                if count_roots_right_of(a, m, c, k, P, D, tau, near=roots) == sel.size:
                    return _sort_pairs(sel)
            except (RuntimeError, ValueError):
                # a root the quick attempt missed lies (almost) on its abscissa: the count
                # cannot resolve there; the full computation places its own abscissa
                if not quick:
                    raise
        if not quick:
            n *= 2
    raise RuntimeError(
        f"could not certify the rightmost roots for P={P:g}, D={D:g}, delay={tau:g}"
    )


def rightmost_roots_many(m, c, k, P, D, tau, *, count=6):
    """:func:`rightmost_roots` for many runs of one plant, by continuation.

    The first run's roots are computed in full; each further run starts Newton from the roots
    of a run near it in (P, D) already done, and the result is accepted only if the argument
    principle certifies it (no other root right of an abscissa between the kept roots and the
    next one); otherwise that run's roots are computed in full. Same results as calling
    :func:`rightmost_roots` per run, at a fraction of the cost when the gains vary smoothly.

    The work is done in rounds, and each round in two passes, each pass certified by one
    batched count of all its runs (:func:`count_roots_right_of_many`):

    1. every run still to do is continued from the settled run (one whose roots are certified)
       nearest to it, all at once: Newton on a (runs × roots) array (:func:`_newton_rows`), the
       de-duplication, sorting and cut of every run's roots on that array
       (:func:`_continued_roots`). The runs whose continuation lost roots (the gains crossed a
       change of the root structure: D through 0, where the delay chain moves by ln|D|/Δt and
       a real root enters) are continued once more, batched, with the chain's asymptotic
       starts (:func:`_chain_starts`) added. Where the gains vary smoothly, or cross D = 0
       (the bench's mass–damper set), this settles every run.
    2. the runs pass 1 did not settle are continued one at a time, each from its nearest
       neighbour (settled, or continued in this pass, certified on its own all the same), so
       that the steps are short; a run whose continuation loses roots (the gains crossed a
       change of the loop's root structure, e.g. a new real root at D ≈ 0) is computed in full
       at once, a seed for the runs beyond.

    After the count, the first run that failed its certificate is computed in full, and the
    next round continues the other failures, from it where it is nearest.
    """
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    n = P.size
    out: list[np.ndarray | None] = [None] * n
    if tau == 0.0 or n == 0:
        return [quadratic_roots(m, c + D[i], k + P[i]) for i in range(n)]
    sp = max(float(np.ptp(P)), 1e-300)
    sd = max(float(np.ptp(D)), 1e-300)

    def full(i):
        # two pairs more than asked: seeds for the continuation and an abscissa beyond
        out[i] = rightmost_roots(m, c, k, float(P[i]), float(D[i]), tau, count=count + 4)

    def nearest(runs, seeds):
        # for each run, the nearest of the seed runs in the scaled (P, D) plane (first of ties)
        dist = (((P[seeds][None, :] - P[runs][:, None]) / sp) ** 2
                + ((D[seeds][None, :] - D[runs][:, None]) / sd) ** 2)
        return seeds[np.argmin(dist, axis=1)]

    def cont(ids, seed):
        # continue runs `ids` from runs `seed`; returns the (run, cut, abscissa) of those with
        # a cut to certify (their roots stored) and the runs that lost roots
        ups = {j: out[j][out[j].imag >= 0] for j in np.unique(seed).tolist()}
        table = np.full((len(ups), max(u.size for u in ups.values())), np.nan, dtype=complex)
        row = {}
        for r, (j, u) in enumerate(ups.items()):
            table[r, : u.size] = u
            row[j] = r
        starts = table[[row[j] for j in seed.tolist()]]
        roots, size, pairs, cut = _continued_roots(starts, m, c, k, P[ids], D[ids], tau, count)
        if np.any(lost := cut == 0):
            # the gains crossed a change of the root structure (the delay chain moves by
            # ln|D|/Δt, a real root enters as D turns positive): those runs again, the chain's
            # own starts added to the neighbour's roots (the real one first; a complex start
            # that lands on the real root is made exactly real by _snap_real)
            chain = _chain_starts(m, c, k, P[ids[lost]], D[ids[lost]], tau, count)
            more = np.concatenate([chain[:, :1], starts[lost], chain[:, 1:]], axis=1)
            rl, sl, pl, cl = _continued_roots(more, m, c, k, P[ids[lost]], D[ids[lost]], tau,
                                              count)
            w = max(roots.shape[1], rl.shape[1])
            roots, pairs = (np.pad(x, ((0, 0), (0, w - x.shape[1])), constant_values=np.nan)
                            for x in (roots, pairs))
            roots[lost, : rl.shape[1]], pairs[lost, : pl.shape[1]] = rl, pl
            size[lost], cut[lost] = sl, cl
        ok = np.flatnonzero(cut > 0)
        for r in ok.tolist():
            out[int(ids[r])] = pairs[r, : size[r]]
        # the abscissa of each certificate: midway between the kept roots and the next
        a = 0.5 * (roots[ok, cut[ok] - 1].real + roots[ok, cut[ok]].real)
        return (ids[ok], cut[ok], a), ids[cut == 0]

    def certify(ids, cuts, a):
        # the runs whose count right of `a` is their cut (settled) and the others (failed)
        got = count_roots_right_of_many(a, m, c, k, P[ids], D[ids], tau,
                                        near=[out[i] for i in ids.tolist()])
        for j in np.flatnonzero(got < 0).tolist():
            i = int(ids[j])
            try:
                got[j] = count_roots_right_of(a[j], m, c, k, P[i], D[i], tau, near=out[i])
            except (RuntimeError, ValueError):
                got[j] = -1
        return ids[got == cuts], ids[got != cuts]

    full(0)
    settled = np.array([0])
    todo = np.arange(1, n)
    while todo.size:
        # pass 1: all at once from the nearest settled runs
        (ids, cuts, a), lost = cont(todo, nearest(todo, settled))
        good, failed = certify(ids, cuts, a) if ids.size else (ids, ids)
        settled = np.concatenate([settled, good])
        todo = np.sort(np.concatenate([lost, failed]))
        if not todo.size:
            break
        # pass 2: one at a time, each from its nearest neighbour
        seeds = settled
        pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for i in todo.tolist():
            j = int(nearest(np.array([i]), seeds)[0])
            r, cut = _continued_one(out[j][out[j].imag >= 0], m, c, k, float(P[i]),
                                    float(D[i]), tau, count)
            if cut:
                out[i] = _sort_pairs(r)
                pending.append((np.array([i]), np.array([cut]),
                                np.array([0.5 * (r[cut - 1].real + r[cut].real)])))
            else:
                full(i)
                settled = np.append(settled, i)
            seeds = np.append(seeds, i)
        failed = np.zeros(0, dtype=int)
        if pending:
            ids, cuts, a = (np.concatenate(x) for x in zip(*pending, strict=True))
            good, failed = certify(ids, cuts, a)
            settled = np.concatenate([settled, good])
        if not failed.size:
            break
        # the first failure in run order is computed in full; the others try again from it
        failed = np.sort(failed)
        full(int(failed[0]))
        settled = np.append(settled, failed[0])
        todo = failed[1:]
    return _trim_pairs(out, count)


def _chain_starts(m, c, k, P, D, tau, count):
    """Starting points for the delay chain's roots of many loops, from their asymptotics.

    f(s) = 0 is e^{sΔt} = −(D s + P)/(m s² + c s + k), i.e. s is a fixed point of

        G_j(s) = [Log(−(D s + P)/(m s² + c s + k)) + 2πi j]/Δt,   j = 0, 1, …

    (Log the principal logarithm), whose derivative is ≈ 1/(Δt|s|): a contraction on the chain
    (|Im s| ≳ π/Δt), converging from s = i(2j + ½)π/Δt. The branch j = 0 from a real start
    −ln(e + m/(|D|Δt))/Δt heads for the real root that a positive D adds far left (where the
    right-hand side is negative there, its Log leaves the axis; Newton's :func:`_snap_real`
    makes a root found that way exactly real). Eight steps each; only starting points (Newton
    refines them and the certificate judges the result).

    Parameters
    ----------
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : ndarray, shape (n,)
        Each loop's gains, N/m and N·s/m.
    tau : float
        Loop delay Δt, s (> 0).
    count : int
        Roots the caller keeps: branches j = 0 … count/2 + 1 are started.

    Returns
    -------
    ndarray of complex, shape (n, count//2 + 3)
        The starts (the real one first: Im exactly 0 while the iteration stays real), NaN
        where an iteration ran off.
    """
    j = np.arange(count // 2 + 2)
    Pc, Dc = P[:, None], D[:, None]
    real0 = -np.log(np.e + m / (np.maximum(np.abs(Dc), 1e-300) * tau)) / tau
    s = np.concatenate([real0 + 0j,
                        np.broadcast_to(1j * (2.0 * j + 0.5) * np.pi / tau, (P.size, j.size))],
                       axis=1)
    twopij = np.concatenate([[0.0], 2j * np.pi * j])
    with np.errstate(all="ignore"):
        for _ in range(8):
            s = (np.log(-(Dc * s + Pc) / (m * s * s + c * s + k)) + twopij) / tau
    return np.where(np.isfinite(s), s, np.nan)


def _continued_roots(starts, m, c, k, P, D, tau, count):
    """One continuation step for many runs: Newton, de-duplication, sorting and cut, batched.

    Parameters
    ----------
    starts : ndarray of complex, shape (n, r)
        Each run's starting points (a settled run's upper-half-plane roots), NaN-padded.
    m, c, k : float
        Plant (kg, N·s/m, N/m).
    P, D : ndarray, shape (n,)
        Each run's gains, N/m and N·s/m.
    tau : float
        Loop delay, s.
    count : int
        Roots (conjugates counted) the run must keep, in whole pairs.

    Returns
    -------
    roots : ndarray of complex, shape (n, w)
        Each run's distinct converged roots and the conjugates of the complex ones, sorted by
        decreasing real part (stable: first found first), NaN-padded.
    size : ndarray of int, shape (n,)
        How many of each row are roots.
    pairs : ndarray of complex, shape (n, w)
        The same roots in :func:`_sort_pairs` order.
    cut : ndarray of int, shape (n,)
        The number of roots to certify: the first real-part gap at or after ``count`` with a
        root beyond it; 0 where there is none (the continuation lost roots).
    """
    Pc, Dc = P[:, None], D[:, None]
    z, res = _newton_rows(starts, m, c, k, Pc, Dc, tau)
    scale = np.abs(m * z**2) + np.abs(c * z) + abs(k) + np.abs(Dc * z) + np.abs(Pc)
    with np.errstate(invalid="ignore"):
        z = np.where(res <= 1e-9 * scale, z, np.nan)
    # the converged roots, then the conjugates of the complex ones (as _unique sees them)
    z = np.concatenate([z, np.where(np.abs(z.imag) > 0, np.conj(z), np.nan)], axis=1)
    with np.errstate(invalid="ignore"):
        close = (np.abs(z[:, :, None] - z[:, None, :])
                 <= 1e-8 * np.maximum(np.abs(z)[:, None, :], 1.0))
    dup = np.any(np.tril(close, -1), axis=2)
    valid = np.isfinite(z) & ~dup
    size = valid.sum(axis=1)
    key = np.where(valid, -z.real, np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    roots = np.take_along_axis(np.where(valid, z, np.nan), order, axis=1)
    re = roots.real
    with np.errstate(invalid="ignore"):
        gap = re[:, :-1] - re[:, 1:] > 1e-9 * np.maximum(np.abs(re[:, :-1]), 1.0)
    gap[:, : max(count - 1, 0)] = False
    cut = np.where(gap.any(axis=1), np.argmax(gap, axis=1) + 1, 0)
    # _sort_pairs on each row (lexsort is stable: ties keep the real-part order)
    skey = np.where(np.isfinite(roots), -np.round(roots.real, 10), np.inf)
    pairs = np.take_along_axis(roots, np.lexsort((-roots.imag, skey), axis=1), axis=1)
    return roots, size, pairs, cut


def _continued_one(start, m, c, k, P, D, tau, count):
    """:func:`_continued_roots` for one run, in scalar arithmetic (:func:`_newton_few`): for a
    single run the array machinery costs more than it saves.

    Returns the run's distinct converged roots and the conjugates of the complex ones, sorted
    by decreasing real part, and the cut (0 where the continuation lost roots).
    """
    r, res = _newton_few(start, m, c, k, P, D, tau)
    scale = np.abs(m * r**2) + np.abs(c * r) + abs(k) + np.abs(D * r) + abs(P)
    r = r[res <= 1e-9 * scale]
    r = _unique(np.concatenate([r, np.conj(r[np.abs(r.imag) > 0])]))
    r = r[np.argsort(-r.real, kind="stable")]
    re = r.real
    gaps = np.flatnonzero(re[:-1] - re[1:] > 1e-9 * np.maximum(np.abs(re[:-1]), 1.0))
    return r, next((int(g) + 1 for g in gaps if g + 1 >= count), 0)


def _trim_pairs(roots: list[np.ndarray], count: int) -> list[np.ndarray]:
    """Each root list (decreasing real part) cut at its first real-part gap at or after
    ``count`` roots, so whole conjugate pairs are kept (as :func:`rightmost_roots` does)."""
    size = np.array([r.size for r in roots])
    re = np.full((len(roots), int(size.max())), np.nan)
    for j, r in enumerate(roots):
        re[j, : r.size] = r.real
    with np.errstate(invalid="ignore"):
        gap = re[:, :-1] - re[:, 1:] > 1e-9 * np.maximum(np.abs(re[:, :-1]), 1.0)
    gap[:, : max(count - 1, 0)] = False
    cut = np.where(gap.any(axis=1), np.argmax(gap, axis=1) + 1, size)
    return [r[:n] for r, n in zip(roots, cut.tolist(), strict=True)]


def _unique(z: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
    """z without near-duplicates (first occurrence kept)."""
    z = np.asarray(z, dtype=complex)
    close = np.abs(z[:, None] - z[None, :]) <= rtol * np.maximum(np.abs(z)[None, :], 1.0)
    dup = np.any(np.tril(close, -1), axis=1)
    return z[~dup]


def _sort_pairs(z: np.ndarray) -> np.ndarray:
    key = np.lexsort((-z.imag, -np.round(z.real, 10)))
    return z[key]


def is_stable(plant: Plant, loop: DelayedPD) -> bool:
    """True when every characteristic root has a negative real part (certified)."""
    return bool(characteristic_roots(plant, loop, count=2)[0].real < 0)


# --------------------------------------------------------------------------------------------
# dominant root, vectorised over runs (the identification's hot path)


def dominant_roots(
    m: float,
    c: float,
    k: float,
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    guess: np.ndarray | None = None,
    *,
    certify: bool = False,
) -> np.ndarray:
    """Dominant (rightmost, upper-half-plane) root of each run's loop, 1/s.

    Parameters
    ----------
    m, c, k : float
        Plant parameters (kg, N·s/m, N/m); need not satisfy Plant's sign checks (used inside
        fits).
    P, D : array_like
        Gains of each run (N/m, N·s/m).
    delay : float
        Loop delay, s.
    guess : array_like of complex, optional
        Starting points for Newton (e.g. the measured roots −σᵢ + iω_dᵢ). Without a guess, or with
        ``certify=True``, each root is computed by :func:`characteristic_roots`.
    certify : bool, default False
        Compute each root with the certified method instead of Newton from the guess.

    Returns
    -------
    ndarray of complex
        s_i = −σᵢ + iω_dᵢ with ω_dᵢ ≥ 0.
    """
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    if guess is None or certify:
        out = []
        for Pi, Di in zip(P, D, strict=True):
            r = rightmost_roots(m, c, k, float(Pi), float(Di), delay, count=2)
            out.append(complex(r[0].real, abs(r[0].imag)))
        return np.array(out)
    s, _ = _newton(np.asarray(guess, dtype=complex), m, c, k, P, D, delay)
    return s.real + 1j * np.abs(s.imag)


# --------------------------------------------------------------------------------------------
# eqs. (26)-(35): alphas, forward and inverse maps


def alphas(
    sigma: np.ndarray | float,
    omega_d: np.ndarray | float,
    delay: float,
    *,
    printed: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Delay coefficients α₁, α₂ of eqs. (28)–(29), corrected per ERRATA 1.

    Parameters
    ----------
    sigma : array_like
        Decay rate σᵢ of the closed-loop dominant mode, 1/s.
    omega_d : array_like
        Its damped frequency ω_dᵢ, rad/s (> 0).
    delay : float
        Loop delay Δt, s.
    printed : bool, default False
        Return the paper's misprinted α₁ = e^{σΔt}[cos Δφ − (σ/ω_d) sin Δφ] instead (kept only to
        demonstrate the erratum; do not use).

    Returns
    -------
    alpha1 : ndarray
        α₁ = e^{σΔt} cos Δφ, with Δφ = ω_dΔt (eq. 26). Dimensionless.
    alpha2 : ndarray
        α₂ = e^{σΔt} sin(Δφ)/ω_d, s. (Its Δφ → 0 limit, Δt e^{σΔt}, is used when ω_d = 0.)
    """
    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    e = np.exp(sigma * delay)
    dphi = omega_d * delay
    a1 = e * np.cos(dphi)
    a2 = e * delay * np.sinc(dphi / np.pi)
    if printed:
        a1 = a1 - sigma * a2
    return a1, a2


@dataclass(frozen=True)
class LoopModes:
    """Dominant closed-loop modes of a set of runs and the equivalent parameters (eqs. 31–33).

    Attributes
    ----------
    sigma : ndarray
        σᵢ, 1/s (dominant root −σᵢ + iω_dᵢ).
    omega_d : ndarray
        ω_dᵢ, rad/s.
    c_eq, k_eq : ndarray
        cᵢ = c + c′ᵢ (N·s/m) and kᵢ = k + k′ᵢ (N/m), eq. (32).
    c_prime, k_prime : ndarray
        c′ᵢ (N·s/m) and k′ᵢ (N/m), eq. (32).
    """

    sigma: np.ndarray
    omega_d: np.ndarray
    c_eq: np.ndarray
    k_eq: np.ndarray
    c_prime: np.ndarray
    k_prime: np.ndarray

    @property
    def omega0_sq(self) -> np.ndarray:
        """ω₀ᵢ² = σᵢ² + ω_dᵢ², 1/s² (eq. 4 for the underdamped loop)."""
        return self.sigma**2 + self.omega_d**2


def inverse_map(
    sigma: np.ndarray | float,
    omega_d: np.ndarray | float,
    P: np.ndarray | float,
    D: np.ndarray | float,
    delay: float,
    *,
    compensate: bool = True,
    printed_alpha1: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Equivalent feedback damping c′ᵢ and stiffness k′ᵢ from a measured mode (eqs. 29, 32).

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured σᵢ (1/s) and ω_dᵢ (rad/s) of each run's decay.
    P, D : array_like
        The run's gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    compensate : bool, default True
        With False, ignore the delay: c′ᵢ = Dᵢ, k′ᵢ = Pᵢ (the paper's "without compensation").
    printed_alpha1 : bool, default False
        Use the paper's misprinted α₁ (ERRATA 1), for demonstration only.

    Returns
    -------
    c_prime : ndarray
        c′ᵢ = (α₁ + σα₂)Dᵢ − α₂Pᵢ, N·s/m (eq. 32a).
    k_prime : ndarray
        k′ᵢ = (α₁ − σα₂)Pᵢ + ω₀ᵢ²α₂Dᵢ, N/m (eq. 32b), with ω₀ᵢ² = σᵢ² + ω_dᵢ².
    """
    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    if not compensate:
        return np.broadcast_to(D, sigma.shape).copy(), np.broadcast_to(P, sigma.shape).copy()
    a1, a2 = alphas(sigma, omega_d, delay, printed=printed_alpha1)
    w0sq = sigma**2 + omega_d**2
    c_prime = (a1 + sigma * a2) * D - a2 * P
    k_prime = (a1 - sigma * a2) * P + w0sq * a2 * D
    return c_prime, k_prime


def forward_map(
    plant: Plant, P: np.ndarray | float, D: np.ndarray | float, delay: float
) -> LoopModes:
    """Plant + gains → dominant modes σᵢ, ω_dᵢ and the equivalent cᵢ, kᵢ (eqs. 31–32).

    Parameters
    ----------
    plant : Plant
        The plant.
    P, D : array_like
        Gains of each run, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    LoopModes
        Exact dominant roots (certified) and, through eq. (32) with the corrected α₁, the
        equivalent parameters; by construction cᵢ = 2mσᵢ and kᵢ = m(σᵢ² + ω_dᵢ²) (eq. 33).
    """
    delay = v.nonnegative("delay", delay, "s")
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    s = dominant_roots(plant.m, plant.c, plant.k, P, D, delay)
    sigma, omega_d = -s.real, s.imag
    cp, kp = inverse_map(sigma, omega_d, P, D, delay)
    return LoopModes(sigma, omega_d, plant.c + cp, plant.k + kp, cp, kp)
