"""The rightmost characteristic roots of the delayed PD loop, certified (eq. 23).

The rightmost roots of f(s) = m s² + c s + k + (D s + P) e^{−sΔt} are found by the spectral
(Chebyshev collocation) discretisation of the DDE's infinitesimal generator (Breda, Maset &
Vermiglio 2005, the method of TRACE-DDE), refined by Newton's method on f
(:mod:`phoid.dynamics.quasipolynomial`), and **certified** by the argument principle
(:mod:`phoid.dynamics.counting`): the number of zeros of f in the half-plane Re s ≥ a (which
all lie in a computable disc) is counted along a rectangle's boundary and must equal the number
of roots found there, so a root cannot be missed. Many runs of one plant are solved by
continuation from run to run, each result certified the same way.
"""

from __future__ import annotations

import numpy as np

from phoid.dynamics.counting import count_roots_right_of, count_roots_right_of_many
from phoid.dynamics.plant import quadratic_roots
from phoid.dynamics.quasipolynomial import (
    _newton,
    _newton_few,
    _newton_rows,
    _sort_pairs,
    _unique,
)

__all__ = ["dominant_roots", "rightmost_roots", "rightmost_roots_many"]


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


def rightmost_roots(
    m: float, c: float, k: float, P: float, D: float, tau: float, *,
    count: int = 6, verify: bool = True,
) -> np.ndarray:
    """The rightmost roots of f(s) = m s² + c s + k + (D s + P) e^{−sΔt}, certified.

    :func:`phoid.dynamics.loop.characteristic_roots` on raw numbers (m > 0; c, k of any sign).

    The first attempt is a quick one: a coarser discretisation (order 16, or 24 where more
    than 3 roots are asked) and Newton of at most :data:`_CONT_ITERS` steps per start, each
    start stopped on its own (:func:`_newton_rows`; the wanted roots converge in a handful from
    the eigenvalues, the spurious ones would take all 30 of the full iteration). Its result is
    certified like any other (and only a certified set is returned), so it is the same set of
    roots as the full computation's; where it does not certify (a root missed or not
    converged, or its abscissa so near a missed root that the count does not resolve), the
    full computation follows: order 16 or 32, Newton of up to 30 steps, the order doubled
    until the certificate agrees.

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg, > 0), damping (N·s/m) and stiffness (N/m).
    P, D : float
        Gains, N/m and N·s/m.
    tau : float
        Loop delay Δt, s (≥ 0; Δt = 0 gives the two roots of the quadratic in closed form).
    count : int, default 6
        At least this many roots (conjugates counted), cut after whole conjugate pairs.
    verify : bool, default True
        Certify by the argument principle that no root right of the last one is missing.

    Returns
    -------
    ndarray of complex
        The roots, 1/s, by decreasing real part (for a pair, positive imaginary part first).

    Raises
    ------
    RuntimeError
        If the roots could not be certified (a pathological loop).
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


def rightmost_roots_many(
    m: float, c: float, k: float, P: np.ndarray, D: np.ndarray, tau: float, *, count: int = 6,
) -> list[np.ndarray]:
    """:func:`rightmost_roots` for many runs of one plant, by continuation.

    The first run's roots are computed in full; each further run starts Newton from the roots
    of a run near it in (P, D) already done, and the result is accepted only if the argument
    principle certifies it (no other root right of an abscissa between the kept roots and the
    next one); otherwise that run's roots are computed in full. Same results as calling
    :func:`rightmost_roots` per run, with far fewer full computations when the gains vary
    smoothly.

    The work is done in rounds, and each round in two passes, each pass certified by one
    batched count of all its runs (:func:`count_roots_right_of_many`):

    1. every run still to do is continued from the settled run (one whose roots are certified)
       nearest to it, all at once: Newton on a (runs × roots) array (:func:`_newton_rows`), the
       de-duplication, sorting and cut of every run's roots on that array
       (:func:`_continued_roots`). The runs whose continuation lost roots (the gains crossed a
       change of the root structure: D through 0, where the delay chain moves by ln|D|/Δt and
       a real root enters) are continued once more, batched, with the chain's asymptotic
       starts (:func:`_chain_starts`) added. Where the gains vary smoothly, or cross D = 0,
       this settles every run.
    2. the runs pass 1 did not settle are continued one at a time, each from its nearest
       neighbour (settled, or continued in this pass, certified on its own all the same), so
       that the steps are short; a run whose continuation loses roots (the gains crossed a
       change of the loop's root structure, e.g. a new real root at D ≈ 0) is computed in full
       at once, a seed for the runs beyond.

    After the count, the first run that failed its certificate is computed in full, and the
    next round continues the other failures, from it where it is nearest.

    Parameters
    ----------
    m, c, k : float
        Plant mass (kg, > 0), damping (N·s/m) and stiffness (N/m), shared by the runs.
    P, D : array_like, shape (n,)
        Each run's gains, N/m and N·s/m.
    tau : float
        Loop delay Δt, s (≥ 0).
    count : int, default 6
        Roots per run, as ``count`` of :func:`rightmost_roots`.

    Returns
    -------
    list of ndarray of complex
        Each run's roots, 1/s, as :func:`rightmost_roots` returns them.
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
        ``certify=True``, each root is computed by :func:`rightmost_roots`.
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

