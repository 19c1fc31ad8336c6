"""The modal engine of the classical methods: shared rates, per-run linear coefficients.

A free release of the plant m x'' + c x' + k x = 0 follows the unified response of the seed's
eq. (2) with eqs. (3)–(8), for every damping (ERRATA 4 in docs/equations.md):

    x(t) = x_off + x₀ [C(τ) + σS(τ)] + v₀ S(τ),   τ = t − t₀ ≥ 0,

with C, S the fundamental solutions of :func:`phoid.dynamics.plant.modal_basis`. Both classical
methods fit records made of such a response plus columns that do not depend on the plant's
rates: the free decay (:mod:`phoid.methods.free`: an offset) and the forced response's start-up
transient (:mod:`phoid.methods.forced`: an offset and the steady-state cosine and sine). The two
rates (σ, ω₀²) are shared by all runs of a set and fitted by variable projection
(:func:`fit_modal`): for trial rates every run's linear coefficients follow by least squares
(:class:`State`), and a Levenberg–Marquardt step on Kaufman's Jacobian updates the rates.
:func:`esprit_rates` and :func:`pick_start` give the starting rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from phoid.dynamics.plant import modal_basis
from phoid.errors import IdentificationError
from phoid.fits import esprit

__all__ = [
    "SCALE_RANGE",
    "ModalFit",
    "Prep",
    "Segment",
    "State",
    "check_scales",
    "esprit_rates",
    "fit_modal",
    "pick_start",
    "release_basis",
    "window_rates",
]


@dataclass(frozen=True)
class Segment:
    """One run's window for :func:`fit_modal`.

    ``fixed`` holds the columns that do not depend on the rates (offset; for forced runs the
    steady-state cosine and sine); the free-response columns B₁ = C + σS and B₂ = S at
    τ = t − t₀ are appended (their coefficients are x₀ and v₀ at t₀, eq. 8).

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times, s (strictly increasing).
    x : ndarray, shape (n,)
        Measured positions, m.
    fixed : ndarray, shape (n, p)
        The columns that do not depend on the rates.
    t0 : float
        Time origin τ = 0 of the free response, s.
    """

    t: np.ndarray
    x: np.ndarray
    fixed: np.ndarray
    t0: float


@dataclass(frozen=True)
class ModalFit:
    """Result of :func:`fit_modal`.

    The rates (σ, ω₀²) and their covariance ``cov`` (zero when they were held fixed); per run:
    the linear coefficients (``fixed`` columns, then x₀, v₀), their covariance including the
    rates' uncertainty, their sensitivity ``K`` (n_coef × 2) to the rates (so that
    cov(cᵢ, cⱼ) = Kᵢ cov Kⱼᵀ for i ≠ j), residual and residual noise sd; and what a sandwich
    covariance needs (:func:`phoid.methods.adequacy.sandwich`): ``jac``, the model's
    derivative in (σ, ω₀²) at the solution (n × 2), and ``design``, the linear columns
    (``fixed``, B₁, B₂; n × p) — together the Jacobian of the residual in every parameter,
    up to its sign.
    """

    sigma: float
    w0sq: float
    cov: np.ndarray
    coef: tuple[np.ndarray, ...]
    coef_cov: tuple[np.ndarray, ...]
    K: tuple[np.ndarray, ...]
    noise: tuple[float, ...]
    resid: tuple[np.ndarray, ...]
    fit_rates: bool
    converged: bool
    iterations: int
    jac: tuple[np.ndarray, ...] = ()
    design: tuple[np.ndarray, ...] = ()


def release_basis(tau: np.ndarray, sigma: float, w0sq: float) -> tuple[np.ndarray, np.ndarray]:
    """The free response's two columns at τ, eqs. (2)–(8).

    Parameters
    ----------
    tau : ndarray
        Time since the release, s.
    sigma : float
        Decay rate σ = c/(2m), 1/s (eq. 3).
    w0sq : float
        ω₀² = k/m, 1/s² (eq. 5).

    Returns
    -------
    B1, B2 : ndarray
        B₁ = C + σS, the response to x₀ = 1, v₀ = 0 (m per m), and B₂ = S, the response to
        x₀ = 0, v₀ = 1 (m per m/s): x = x₀B₁ + v₀B₂ (eq. 8).
    """
    C, S = modal_basis(tau, sigma, w0sq)
    return C + sigma * S, S


class Prep:
    """Per-run constants of the projection: the fixed columns' orthonormal basis Qf (n × p),
    their triangular factor, the record with its fixed part removed, and τ = t − t₀."""

    def __init__(self, seg: Segment) -> None:
        self.seg = seg
        self.tau = seg.t - seg.t0
        self.Qf, self.Rf = np.linalg.qr(seg.fixed)
        self.xt = seg.x - self.Qf @ (self.Qf.T @ seg.x)
        self.n = seg.t.size


class State:
    """Linear least squares of every run at the rates (σ, ω₀²), by Frisch–Waugh: the two
    free-response columns B = (B₁, B₂) are projected off the fixed columns, B̃ = B − QfQfᵀB, and
    their coefficients β = (x₀, v₀) solve B̃ᵀB̃β = B̃ᵀx̃ (2 × 2, eigen-decomposed: a direction
    whose singular value is below 10⁻¹⁰ of the columns' scale is dropped, e.g. B₁ ∝ the offset
    when ω₀² = 0). Per run: (Qb, β, residual, B)."""

    def __init__(self, preps: Sequence[Prep], sigma: float, w0sq: float,
                 weights: np.ndarray) -> None:
        self.sigma, self.w0sq = float(sigma), float(w0sq)
        self.sse_w = math.inf
        self.items: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for p in preps:
            with np.errstate(over="ignore", invalid="ignore"):
                B = np.column_stack(release_basis(p.tau, self.sigma, self.w0sq))
            # trial rates whose response grows beyond any record's scale: reject them
            if not np.abs(B).max() < 1e100:
                return
            Bt = B - p.Qf @ (p.Qf.T @ B)
            ev, V = np.linalg.eigh(Bt.T @ Bt)
            scale = max(float(np.max(np.einsum("ij,ij->j", B, B))), 1e-300)
            keep = ev > 1e-20 * scale
            sv = np.sqrt(ev[keep])
            Qb = (Bt @ V[:, keep]) / sv
            proj = Qb.T @ p.xt
            beta = V[:, keep] @ (proj / sv)
            r = p.xt - Qb @ proj
            self.items.append((Qb, beta, r, B))
        self.rss = np.array([float(item[2] @ item[2]) for item in self.items])
        self.sse_w = float(weights @ self.rss)


def _jacobian(preps: Sequence[Prep], st: State, weights: np.ndarray):
    """Kaufman's normal matrix M and gradient g of the weighted SSE in (σ, ω₀²), and each
    run's raw model derivative (n × 2).

    With C = e^{−στ}ch(q, τ), S = e^{−στ}sh(q, τ), q = σ² − ω₀², the derivative in σ at fixed
    q is exact and free: ∂B₁/∂σ = −τB₁ + B₂, ∂B₂/∂σ = −τB₂. The one in ω₀² at fixed σ (that is,
    −∂/∂q) is a forward difference of :func:`release_basis` with a step of 10⁻⁷ of the rate
    scale squared (relative error ~10⁻⁷, far below what matters for a Gauss–Newton step or a
    standard error); then ∂/∂σ at fixed ω₀² = ∂/∂σ|_q − 2σ ∂/∂ω₀²|_σ.
    """
    sigma, w0sq = st.sigma, st.w0sq
    span = max(float(p.tau[-1]) for p in preps)
    scale = max(abs(sigma) + math.sqrt(abs(w0sq)), 1.0 / span)
    hw = 1e-7 * scale * scale
    M = np.zeros((2, 2))
    g = np.zeros(2)
    raws = []
    for i, p in enumerate(preps):
        Qb, beta, r, B = st.items[i]
        a, b = beta
        base = B @ beta
        with np.errstate(over="ignore", invalid="ignore"):
            p1, p2 = release_basis(p.tau, sigma, w0sq + hw)
        d_w = (a * p1 + b * p2 - base) / hw
        d_s = a * B[:, 1] - p.tau * base - 2.0 * sigma * d_w
        J = np.column_stack([d_s, d_w])
        Jt = J - p.Qf @ (p.Qf.T @ J)
        Jt -= Qb @ (Qb.T @ Jt)
        M += weights[i] * (Jt.T @ Jt)
        g += weights[i] * (Jt.T @ r)
        raws.append(J)
    return M, g, raws


def _noise_from(preps: Sequence[Prep], st: State, fit_rates: bool) -> np.ndarray:
    """Each run's white-noise sd from its residual, √(RSS/dof) (a floor of 10⁻¹³ of its range
    keeps noise-free records finite)."""
    total = sum(p.n for p in preps)
    out = []
    for p, rss in zip(preps, st.rss, strict=True):
        k = p.seg.fixed.shape[1] + 2 + (2 * p.n / total if fit_rates else 0.0)
        dof = max(p.n - k, 1.0)
        out.append(max(math.sqrt(rss / dof), 1e-13 * float(np.ptp(p.seg.x)), 1e-300))
    return np.array(out)


def pick_start(segs: Sequence[Segment], cands: Sequence[tuple[float, float]],
               weights: np.ndarray) -> tuple[float, float]:
    """Starting rates (σ, ω₀²) for :func:`fit_modal`: the best of the candidates after a
    short refinement.

    Every candidate is scored by the weighted residual sum of squares on the runs thinned to
    ~4096 samples (the first 2048 kept, where a fast mode lives, every d-th of the rest); the
    four best distinct ones are refined there by :func:`fit_modal` (at most 15 steps) and the
    lowest refined score wins. A single score ranks starts poorly when the SSE surface has
    more than one valley (a weakly excited fast mode: a critically damped pair at the slow
    root is a local minimum), hence the refinement.

    Parameters
    ----------
    segs : sequence of Segment
        The runs' windows.
    cands : sequence of (float, float)
        Candidate rates (σ in 1/s, ω₀² in 1/s²); the last one is returned when none can be
        scored.
    weights : ndarray, shape (len(segs),)
        Each run's weight 1/noise², 1/m².

    Returns
    -------
    (float, float)
        The starting (σ, ω₀²).
    """
    T, X = scales(segs)  # worked in units of T and X (fit_modal): the same in any unit
    sg, wq = _pick_start_unit(_scaled(segs, T, X), [(a * T, b * T * T) for a, b in cands],
                              np.asarray(weights, dtype=float) * X * X)
    return sg / T, wq / (T * T)


def _pick_start_unit(segs: Sequence[Segment], cands: Sequence[tuple[float, float]],
                     weights: np.ndarray) -> tuple[float, float]:
    """:func:`pick_start` on a record in units where its span and largest |x| are ~1."""
    thin = []
    for s in segs:
        d = max(1, (s.t.size - 2048) // 2048)
        keep = np.r_[np.arange(min(2048, s.t.size)), np.arange(2048, s.t.size, d)]
        thin.append(Segment(t=s.t[keep], x=s.x[keep], fixed=s.fixed[keep], t0=s.t0))
    preps = [Prep(s) for s in thin]

    def score(sg: float, wq: float) -> float:
        if not (math.isfinite(sg) and math.isfinite(wq)):
            return math.inf
        st = State(preps, sg, wq, weights)
        return st.sse_w if math.isfinite(st.sse_w) else math.inf

    scored = sorted((score(sg, wq), sg, wq) for sg, wq in cands)
    top: list[tuple[float, float]] = []
    for sse, sg, wq in scored:
        if not math.isfinite(sse):
            break
        if all(abs(sg - a) > 1e-3 * (abs(a) + 1e-12) or abs(wq - b) > 1e-3 * (abs(b) + 1e-12)
               for a, b in top):
            top.append((sg, wq))
        if len(top) == 4:
            break
    if not top:
        return cands[-1]
    best, best_sse = top[0], math.inf
    for sg, wq in top:
        try:
            fit = _fit_modal_unit(thin, sg, wq, noise=1.0 / np.sqrt(weights), maxit=15)
        except (IdentificationError, np.linalg.LinAlgError):
            continue
        sse = score(fit.sigma, fit.w0sq)
        if sse < best_sse:
            best, best_sse = (fit.sigma, fit.w0sq), sse
    return best


#: the sample step (s) and the largest |x| a free record may have (:func:`check_scales`)
SCALE_RANGE = (1e-30, 1e30)
_SCALE_TEXT = "1e-30 … 1e30"  # SCALE_RANGE in words


def check_scales(t: np.ndarray, x: np.ndarray, where: str, x_unit: str) -> None:
    """Refuse a record whose sample step or x lies outside :data:`SCALE_RANGE` (one line
    naming ``where`` — the manifest and the run —, the field and the cure).

    The fit itself works in units of the record's span and largest |x| (exact: powers of two,
    :func:`fit_modal`), so any unit within the range gives the same
    σ, ω₀ — but what it reports is in SI: σ ∝ 1/step, ω₀² and its covariance ∝ 1/step² and
    1/step⁴, x's squares in the adequacy checks ∝ x², and out of the range these leave the
    floating-point range (an inf, a 0, a wrong number)."""
    lo, hi = SCALE_RANGE
    lo, hi = lo * (1 - 1e-9), hi * (1 + 1e-9)  # the ends included, to a t's rounding
    if t.size >= 2:
        step = float(np.median(np.diff(t)))
        if not lo <= step <= hi:
            raise IdentificationError(
                f"{where}: the sample step of t (from sample_rate where the manifest gives one) "
                f"is {step:.3g} s, outside {_SCALE_TEXT} s, where the free fit's σ, ω₀² and "
                "their covariances stay within the floating-point range; give t in seconds "
                "([units] t = \"ms\", \"us\", … for a column in another unit), or check "
                "sample_rate (Hz)")
    big = float(np.max(np.abs(x))) if x.size else 0.0
    if big != 0.0 and not lo <= big <= hi:
        raise IdentificationError(
            f"{where}: x reaches {big:.3g} {x_unit} at most, outside {_SCALE_TEXT} (its "
            f"largest |x|), where the free fit's squares of x stay within the floating-point "
            f"range; give x in a unit where it is ([units] x = \"mm\", \"um\", …)")


def _pow2(v: float) -> float:
    """The power of two nearest below |v| (1 for 0 or a non-finite v): dividing by it is exact."""
    if not (math.isfinite(v) and v != 0.0):
        return 1.0
    return math.ldexp(1.0, math.frexp(abs(v))[1] - 1)


def scales(segs: Sequence[Segment]) -> tuple[float, float]:
    """The time and x scales (T, X), powers of two, that :func:`fit_modal`,
    :func:`pick_start` and :func:`esprit_rates` divide by before they work: T of the longest
    window's span, X of the largest |x|. Dividing by a power of two is exact, so the fit is
    the same for a record given in any time or x unit (no constant of the engine — a
    tolerance, a floor, a step — meets a number whose size depends on the unit)."""
    span = max((float(s.t[-1] - s.t0) for s in segs if s.t.size), default=1.0)
    big = max((float(np.max(np.abs(s.x))) for s in segs if s.x.size), default=1.0)
    return _pow2(span), _pow2(big)


def _scaled(segs: Sequence[Segment], T: float, X: float) -> list[Segment]:
    return [Segment(t=s.t / T, x=s.x / X, fixed=s.fixed, t0=s.t0 / T) for s in segs]


def fit_modal(
    segs: Sequence[Segment],
    sigma: float,
    w0sq: float,
    *,
    noise: Sequence[float],
    fit_rates: bool = True,
    maxit: int = 60,
) -> ModalFit:
    """Fit the shared rates (σ, ω₀²) and every run's linear coefficients, in any units.

    The work is done by :func:`_fit_modal_unit` on the record with t divided by T and x by X
    (:func:`scales`, powers of two: exact), and every number is scaled back: the same record in
    any time or x unit gives the same fit. Parameters, returns and raises as
    :func:`_fit_modal_unit`.
    """
    T, X = scales(segs)
    nz = [float(n) / X for n in noise]
    f = _fit_modal_unit(_scaled(segs, T, X), sigma * T, w0sq * T * T, noise=nz,
                        fit_rates=fit_rates, maxit=maxit)
    r = np.array([T, T * T])  # d rate'/d rate: the rates in units of 1/T and 1/T²

    def coef_scale(c: np.ndarray) -> np.ndarray:
        # fixed columns and x₀ scale with X; v₀ (the last coefficient, of B₂ = S, in x per
        # time) with X/T
        out = np.full(c.shape[0], X)
        out[-1] = X / T
        return out

    coefs, ccovs, Ks, jacs, designs = [], [], [], [], []
    for c, cc, K, J, G in zip(f.coef, f.coef_cov, f.K, f.jac, f.design, strict=True):
        d = coef_scale(c)
        coefs.append(c * d)
        ccovs.append(cc * np.outer(d, d))
        Ks.append(K * d[:, None] * r[None, :])
        jacs.append(J * X * r[None, :])
        g = G.copy()
        g[:, -1] *= T
        designs.append(g)
    return ModalFit(
        sigma=f.sigma / T, w0sq=f.w0sq / (T * T), cov=f.cov / np.outer(r, r),
        coef=tuple(coefs), coef_cov=tuple(ccovs), K=tuple(Ks),
        noise=tuple(n * X for n in f.noise), resid=tuple(e * X for e in f.resid),
        fit_rates=f.fit_rates, converged=f.converged, iterations=f.iterations,
        jac=tuple(jacs), design=tuple(designs),
    )


def _fit_modal_unit(
    segs: Sequence[Segment],
    sigma: float,
    w0sq: float,
    *,
    noise: Sequence[float],
    fit_rates: bool = True,
    maxit: int = 60,
) -> ModalFit:
    """Fit the shared rates (σ, ω₀²) and every run's linear coefficients.

    Levenberg–Marquardt on the variable projection (Kaufman's Jacobian), each run weighted by
    1/noiseᵢ², the noise re-estimated from that run's residual after every accepted step
    (``noise`` only weighs the starting point). Stops when the step is below 10⁻³ stderr. With
    ``fit_rates`` False the rates stay at the values given (no rate uncertainty is
    propagated).

    Covariance: the Gauss–Newton inverse of the full weighted normal matrix (rates and all
    linear coefficients), taken block-wise: cov(rates) = M⁻¹ (M the Schur complement, i.e.
    Kaufman's normal matrix), cov(cᵢ) = (GᵢᵀWᵢGᵢ)⁻¹ + Kᵢ M⁻¹ Kᵢᵀ, Kᵢ = −Gᵢ⁺Jᵢ.

    Parameters
    ----------
    segs : sequence of Segment
        The runs' windows.
    sigma, w0sq : float
        Starting rates σ (1/s) and ω₀² (1/s²).
    noise : sequence of float
        Starting noise sd of each run, m.
    fit_rates : bool, default True
        Whether the rates are fitted (else held at ``sigma``, ``w0sq``).
    maxit : int, default 60
        Most Levenberg–Marquardt iterations.

    Returns
    -------
    ModalFit

    Raises
    ------
    IdentificationError
        If the model overflows at the starting rates.
    """
    preps = [Prep(s) for s in segs]
    weights = 1.0 / np.square(np.asarray(noise, dtype=float))
    st = State(preps, sigma, w0sq, weights)
    if not math.isfinite(st.sse_w):
        raise IdentificationError("the free-response model overflows at the starting rates")

    def reweight(state: State) -> np.ndarray:
        # each run's weight from its own residual (the relative weights are what matter)
        w = 1.0 / np.square(_noise_from(preps, state, fit_rates))
        state.sse_w = float(w @ state.rss)
        return w

    weights = reweight(st)
    converged = not fit_rates
    iterations = 0
    lam = 1e-4
    for _ in range(maxit if fit_rates else 0):
        iterations += 1
        M, g, _raws = _jacobian(preps, st, weights)
        dg = np.maximum(np.diag(M), 1e-300)
        new = None
        while lam < 1e10:
            try:
                delta = np.linalg.solve(M + lam * np.diag(dg), g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            trial = State(preps, st.sigma + delta[0], st.w0sq + delta[1], weights)
            if math.isfinite(trial.sse_w) and trial.sse_w <= st.sse_w:
                new = trial
                break
            lam *= 10
        if new is None:
            converged = True  # no descent left: at the minimum to rounding
            break
        try:
            se = np.sqrt(np.abs(np.diag(np.linalg.inv(M))))
        except np.linalg.LinAlgError:
            se = np.full(2, np.inf)
        gain = st.sse_w - new.sse_w
        st = new
        weights = reweight(st)
        lam = max(lam / 10, 1e-12)
        if np.all(np.abs(delta) <= 1e-3 * se) or gain <= 1e-13 * max(st.sse_w, 1e-300):
            converged = True
            break
    M, _g, raws = _jacobian(preps, st, weights)
    cov = np.zeros((2, 2))
    if fit_rates:
        try:
            cov = np.linalg.inv(M)
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(M)
    coefs, ccovs, Ks, resids, designs = [], [], [], [], []
    for i, p in enumerate(preps):
        # the full design at the solution, once: coefficients, (GᵀG)⁻¹ and G⁺J (SVD)
        G = np.column_stack([p.seg.fixed, *release_basis(p.tau, st.sigma, st.w0sq)])
        designs.append(G)
        U, sv, Vt = np.linalg.svd(G, full_matrices=False)
        keep = sv > sv[0] * 1e-12
        U, sv, Vt = U[:, keep], sv[keep], Vt[keep]
        coef = Vt.T @ ((U.T @ p.seg.x) / sv)
        K = -(Vt.T @ ((U.T @ raws[i]) / sv[:, None])) if fit_rates else np.zeros((coef.size, 2))
        coefs.append(coef)
        ccovs.append((Vt.T / sv**2) @ Vt / weights[i] + K @ cov @ K.T)
        Ks.append(K)
        resids.append(st.items[i][2])
    return ModalFit(
        sigma=st.sigma, w0sq=st.w0sq, cov=cov, coef=tuple(coefs), coef_cov=tuple(ccovs),
        K=tuple(Ks), noise=tuple(float(1 / math.sqrt(w)) for w in weights),
        resid=tuple(resids), fit_rates=fit_rates, converged=converged, iterations=iterations,
        jac=tuple(raws), design=tuple(designs),
    )


def esprit_rates(t: np.ndarray, y: np.ndarray, noise: float, *,
                 grid: bool = False) -> list[tuple[float, float]]:
    """Starting (σ, ω₀²) from ESPRIT (order 3: an offset and two modes) on the active part of
    ``y`` (until it stays within 5 noise sd of its final level), block-averaged to ≤ ~1024
    points; one candidate per pair of roots that can be a real plant's (a conjugate pair or
    two real roots).

    With ``grid``, each real decaying root r found is also paired with a second real root at
    r (critical damping) and at 12 log-spaced multiples of r up to half the sampling rate: in a
    release from rest the fast exponential of an overdamped plant is weak and mostly gone
    before the fit window starts, and ESPRIT then places it poorly, while r — the slow root —
    is well found.

    Parameters
    ----------
    t : ndarray
        Sample times, s.
    y : ndarray
        The free response (offset allowed), m.
    noise : float
        Its white-noise sd, m.
    grid : bool, default False
        Add the critical and overdamped pairs at each real root.

    Returns
    -------
    list of (float, float)
        Candidate (σ, ω₀²), 1/s and 1/s²; empty when ESPRIT fails or ``y`` is too short.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.size < 2:
        return []
    # worked in units of the record's span and largest |y| (fit_modal): the same in any unit
    T = _pow2(float(t[-1] - t[0]))
    X = _pow2(float(np.max(np.abs(y))))
    return [(a / T, b / (T * T))
            for a, b in _esprit_rates_unit(t / T, y / X, noise / X, grid=grid)]


def _esprit_rates_unit(t: np.ndarray, y: np.ndarray, noise: float, *,
                       grid: bool = False) -> list[tuple[float, float]]:
    """:func:`esprit_rates` on a record in units where its span and largest |y| are ~1."""
    n = y.size
    if n < 8:
        return []
    tail = y[-max(n // 10, 1):]
    level = float(np.median(tail))
    far = np.flatnonzero(np.abs(y - level) > 5.0 * noise)
    n_act = min(n, max(int(far[-1]) + 1 if far.size else n, 64))
    tt, yy = t[:n_act], y[:n_act]
    dt = (tt[-1] - tt[0]) / (n_act - 1)
    yg = np.interp(tt[0] + dt * np.arange(n_act), tt, yy)
    q = max(1, n_act // 1024)
    m = n_act // q
    yb = yg[: m * q].reshape(m, q).mean(axis=1)
    if yb.size < 8:
        return []
    try:
        with np.errstate(all="ignore"):
            s, _energy = esprit(yb, q * dt, order=3)
    except (np.linalg.LinAlgError, ValueError):
        return []
    out = []
    s = s[np.isfinite(s)]
    for i in range(s.size):
        for j in range(i + 1, s.size):
            a, b = s[i], s[j]
            tol = 1e-6 * max(abs(a), abs(b), 1.0)
            real_pair = abs(a.imag) <= tol and abs(b.imag) <= tol
            conj_pair = abs(a - b.conjugate()) <= 1e-6 * max(abs(a), 1.0) and abs(a.imag) > tol
            if real_pair or conj_pair:
                out.append((float(-(a + b).real / 2), float((a * b).real)))
    if grid:
        fastest = 0.5 / float(np.median(np.diff(t)))
        for r in s:
            if abs(r.imag) <= 1e-6 * max(abs(r), 1.0) and 0 < -r.real < fastest / 1.5:
                slow = float(r.real)
                for f in np.r_[slow, slow * np.geomspace(1.5, fastest / -slow, 12)]:
                    out.append((-(slow + f) / 2, slow * f))
    return out


def window_rates(
    seg: Segment,
    motion: np.ndarray,
    sigma: float,
    w0sq: float,
    noise: float,
    *,
    cycles: float = 4.0,
    max_windows: int = 40,
    min_nsd: float = 10.0,
) -> tuple[np.ndarray, ...]:
    """Local decay rate and damped frequency over consecutive windows of a few cycles.

    Each window is fitted alone with the same model (its own offset and state, and its own
    rates, by :func:`fit_modal` started at the whole fit's rates): a decay whose rate or
    frequency depends on the amplitude shows as a trend of the windows' rates against their
    amplitude (:func:`phoid.methods.adequacy.structure_check`).

    Parameters
    ----------
    seg : Segment
        The run's window of the whole fit (its fixed columns are replaced by an offset).
    motion : ndarray
        The whole fit's motion about its offset on ``seg.t``; a window is used where the
        record's amplitude there, √2·RMS of the record less its mean over the window, or the
        motion's, is above ``min_nsd`` noise sd.
    sigma, w0sq : float
        The whole fit's rates (underdamped: w0sq > σ²; else nothing is returned).
    noise : float
        The run's noise sd.
    cycles : float
        Window length in damped periods (widened so that there are at most ``max_windows``;
        windows shorter than 24 samples are not fitted).
    max_windows, min_nsd : int, float

    Returns
    -------
    (amplitude, sigma, sigma_se, omega_d, omega_d_se) : ndarrays
        One entry per fitted window (white-noise stderr of the window's fit; ω_d = √(ω₀² − σ²)
        and its stderr by the delta method).
    """
    empty = tuple(np.empty(0) for _ in range(5))
    q = w0sq - sigma * sigma
    n = seg.t.size
    if not (q > 0 and math.isfinite(q) and noise > 0) or n < 48:
        return empty
    wd = math.sqrt(q)
    span = float(seg.t[-1] - seg.t[0])
    length = max(cycles * 2 * math.pi / wd, span / max(int(max_windows), 1))
    edges = np.searchsorted(seg.t, seg.t[0] + length * np.arange(int(span // length) + 1))
    out: list[list[float]] = [[], [], [], [], []]
    for k in range(edges.size - 1):
        a, b = int(edges[k]), int(edges[k + 1])
        if b - a < 24:
            continue
        xw = seg.x[a:b]
        amp = math.sqrt(2.0 * max(float(np.mean(motion[a:b] ** 2)),
                                  float(np.mean((xw - xw.mean()) ** 2))))
        if not amp > min_nsd * noise:
            continue
        w = Segment(t=seg.t[a:b], x=seg.x[a:b], fixed=np.ones((b - a, 1)), t0=float(seg.t[a]))
        try:
            f = fit_modal([w], sigma, w0sq, noise=[noise], maxit=20)
        except (IdentificationError, np.linalg.LinAlgError):
            continue
        qq = f.w0sq - f.sigma**2
        if not (f.converged and qq > 0 and np.all(np.isfinite(f.cov))):
            continue
        wdl = math.sqrt(qq)
        g = np.array([-f.sigma / wdl, 0.5 / wdl])
        out[0].append(math.sqrt(2.0 * float(np.mean((w.x - f.coef[0][0] - f.resid[0]) ** 2))))
        out[1].append(f.sigma)
        out[2].append(math.sqrt(max(float(f.cov[0, 0]), 0.0)))
        out[3].append(wdl)
        out[4].append(math.sqrt(max(float(g @ f.cov @ g), 0.0)))
    return tuple(np.array(v) for v in out)
