r"""The least-squares fit of the Coulomb + viscous free decay to a free set's releases.

Parameters: (σ, ω₀², a) shared by all releases, and per release the offset x_off, the position
y₀ (from the offset) and the velocity v₀ at the start of its window (the windows and the
release detection are those of the viscous fit, :func:`phoid.methods.free.identify_free_data`).
The residual of release i is (xᵢ − x_offᵢ − y(t; σ, ω₀², a, y₀ᵢ, v₀ᵢ))/ŝᵢ, ŝᵢ its noise level
estimated without a model (:func:`phoid.methods.fit_statistics.difference_noise` over the
window), y the exact piecewise motion of :func:`phoid.methods.free_friction_model.coulomb_decay`;
the sum of squares is then the χ² of the fit. It is minimised by
:func:`scipy.optimize.least_squares` (trust-region reflective, stopped at a relative change
of 10⁻⁸ in the cost or the parameters: ~10⁻⁴ √n of a stderr at most, and on a real record's
kinked valley of stops it saves the long creep along it) with a Jacobian by forward
differences, each step √ε ≈ 1.5·10⁻⁸ of its parameter's scale (|σ| or 1 % of ω₀, ω₀², |a| or
1 % of ω₀²·amplitude, the amplitude, the amplitude·ω₀), the offset's column exact; the
covariances' Jacobian at the solution by central differences (steps 10⁻⁶ of the scale: a
forward difference across a kink of the stop would distort the Newey–West sandwich). The Jacobian is
dense while it holds under 5·10⁶ numbers and sparse (block-diagonal in the releases, LSMR
steps) beyond. The motion is continuous in the parameters (the stop moves continuously: a
stuck position at the band's edge |y| = d starts a half-cycle of zero height), so the
objective is continuous with kinks, which the trust region handles.

Starts: the viscous fit with a = 0 (so that the friction fit can only improve on it: it nests
the viscous model at a = 0) and the half-cycle amplitude regression of
:func:`~phoid.methods.free_friction_model.envelope_start` on the release with the largest
motion (its turning points' spacing and heights); the lower final χ² wins. From each start
the fit runs over growing windows — the first 4, 16, 64 … half periods of every release, then
all of it — each warm-started from the last: a start's phase error grows along the record, and
on the whole record at once it pulls the rates into the basin of a neighbouring stop (the
mass sticking one half-cycle early or late is a separate local minimum of χ²). The viscous
start on the whole record at once is tried too, and from the best of all, two restarts
with f_c/m changed by ±1/K (K the most velocity zeros of a release: the change that moves a
stop by about one half-cycle).

The Gauss–Newton covariance of (σ, ω₀², a), with the release parameters profiled out (each
release's Jacobian projected off its own three columns, which is exact for the block
structure), each release weighted by its residual variance: (Σᵢ J̃ᵢᵀJ̃ᵢ/sᵢ²)⁻¹. The solution
keeps each release's Jacobian blocks and residual variance, from which
:func:`phoid.methods.adequacy.sandwich` gives the Newey–West one
(:mod:`phoid.methods.free_friction`). ``start`` refits from a given solution alone (the
halves and the runs of the adequacy checks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.methods.free_friction_model import CoulombDecay, coulomb_decay, envelope_start

__all__ = ["FrictionProblem", "FrictionSolution", "ReleaseWindow", "fit_free_friction"]

#: most evaluations of the residual per start
MAX_NFEV = 200
#: largest dense Jacobian, numbers
_DENSE_MAX = 5_000_000
#: relative forward-difference step: √ε, where truncation (∝ step) and rounding (∝ ε/step)
#: errors of the derivative balance, each ~1e-8 of it
_STEP = 1.5e-8
#: relative central-difference step of the covariances' Jacobian (error ~1e-12 of it)
_STEP_CENTRAL = 1e-6


@dataclass(frozen=True)
class ReleaseWindow:
    """One release's fitted window and its start from the viscous fit.

    Attributes
    ----------
    t, x : ndarray
        Samples in the window, s and m.
    noise : float
        Its noise level from the record alone, m.
    offset, y0, v0 : float
        The viscous fit's offset (m), position from it (m) and velocity (m/s) at ``t[0]``.
    """

    t: np.ndarray
    x: np.ndarray
    noise: float
    offset: float
    y0: float
    v0: float


@dataclass(frozen=True)
class FrictionProblem:
    """The releases and the viscous estimates the fit starts from."""

    windows: tuple[ReleaseWindow, ...]
    sigma: float
    w0sq: float


@dataclass(frozen=True)
class FrictionSolution:
    """The fitted parameters, motions, residuals and covariances.

    Attributes
    ----------
    theta : ndarray, shape (3,)
        σ (1/s), ω₀² (1/s²), a (m/s²).
    own : ndarray, shape (runs, 3)
        Per release: offset (m), y₀ (m), v₀ (m/s) at the window's start.
    motions : tuple of CoulombDecay
    resid : tuple of ndarray
        Record − model, m.
    cov_white : ndarray, shape (3, 3)
        Gauss–Newton covariance of θ.
    jac, jac_own : tuple of ndarray, each (nᵢ, 3)
        Per release: ∂model/∂θ and ∂model/∂(offset, y₀, v₀) at the solution.
    resid_var : tuple of float
        Per release: the residual variance sᵢ² that weighs it (RSS/(nᵢ − 3)).
    converged : bool
    nfev : int
    """

    theta: np.ndarray
    own: np.ndarray
    motions: tuple[CoulombDecay, ...]
    resid: tuple[np.ndarray, ...]
    cov_white: np.ndarray
    jac: tuple[np.ndarray, ...]
    jac_own: tuple[np.ndarray, ...]
    resid_var: tuple[float, ...]
    converged: bool
    nfev: int


def _motion(w: ReleaseWindow, theta: np.ndarray, own: np.ndarray) -> CoulombDecay:
    return coulomb_decay(w.t - w.t[0], float(theta[0]), float(theta[1]), float(theta[2]),
                         float(own[1]), float(own[2]))


class _Objective:
    """Residuals and Jacobian of the stacked weighted problem."""

    def __init__(self, prob: FrictionProblem) -> None:
        self.w = prob.windows
        self.n = [w.t.size for w in self.w]
        self.edges = np.concatenate([[0], np.cumsum(self.n)])
        self.R = len(self.w)
        self.P = 3 + 3 * self.R
        w0 = math.sqrt(prob.w0sq)
        self.amp = [max(float(np.max(np.abs(w.x - w.offset))), 1e-300) for w in self.w]
        self.w0 = w0
        self.sparse = self.edges[-1] * self.P > _DENSE_MAX

    def split(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return p[:3], p[3:].reshape(self.R, 3)

    def model(self, i: int, theta: np.ndarray, own: np.ndarray) -> np.ndarray:
        w = self.w[i]
        try:
            y = _motion(w, theta, own[i]).y
        except ValueError:  # ω₀² ≤ 0 in a trial step: no model
            return np.full(w.t.size, np.inf)
        return own[i, 0] + y

    def __call__(self, p: np.ndarray) -> np.ndarray:
        theta, own = self.split(p)
        out = np.concatenate([(w.x - self.model(i, theta, own)) / w.noise
                              for i, w in enumerate(self.w)])
        bad = ~np.isfinite(out)
        if bad.any():  # a trial step outside the model's range: a large, finite penalty
            out[bad] = 1e150
        return out

    def steps(self, theta: np.ndarray, i: int) -> np.ndarray:
        amp = self.amp[i]
        return _STEP * np.array([
            max(abs(theta[0]), 0.01 * self.w0), abs(theta[1]),
            max(abs(theta[2]), 0.01 * abs(theta[1]) * amp), amp, amp * self.w0])

    def blocks(self, p: np.ndarray, *,
               central: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per release: ∂model/∂θ (nᵢ, 3) and ∂model/∂(offset, y₀, v₀) (nᵢ, 3), unweighted:
        forward differences from one evaluation at ``p`` (6 motions per release, the steps of
        the fit), or ``central`` ones (10 motions, steps of :data:`_STEP_CENTRAL`, for the
        covariances)."""
        theta, own = self.split(p)
        out = []
        for i, w in enumerate(self.w):
            h = self.steps(theta, i) * (_STEP_CENTRAL / _STEP if central else 1.0)
            base = None if central else _motion(w, theta, own[i]).y
            Js = np.empty((w.t.size, 3))
            Jo = np.empty((w.t.size, 3))
            Jo[:, 0] = 1.0
            for j in range(5):
                vec, k = (theta, j) if j < 3 else (own[i], j - 2)
                up, down = vec.copy(), vec.copy()
                up[k] += h[j]
                down[k] -= h[j] if central else 0.0
                args = [(up, own[i]) if j < 3 else (theta, up),
                        (down, own[i]) if j < 3 else (theta, down)]
                y_up = _motion(w, *args[0]).y
                y_down = _motion(w, *args[1]).y if central else base
                col = (y_up - y_down) / (up[k] - down[k])
                if j < 3:
                    Js[:, j] = col
                else:
                    Jo[:, k] = col
            out.append((Js, Jo))
        return out

    def jac(self, p: np.ndarray):
        blocks = self.blocks(p)
        if self.sparse:
            from scipy.sparse import lil_matrix

            J = lil_matrix((int(self.edges[-1]), self.P))
        else:
            J = np.zeros((int(self.edges[-1]), self.P))
        for i, ((Js, Jo), w) in enumerate(zip(blocks, self.w, strict=True)):
            a, b = int(self.edges[i]), int(self.edges[i + 1])
            J[a:b, :3] = -Js / w.noise
            J[a:b, 3 + 3 * i: 6 + 3 * i] = -Jo / w.noise
        return J.tocsr() if self.sparse else J


def _solve(obj: _Objective, p0: np.ndarray, lb: np.ndarray, ub: np.ndarray,
           free: np.ndarray | None = None):
    """least_squares from ``p0`` over the parameters where ``free`` (all by default)."""
    from scipy.optimize import least_squares

    theta, _ = obj.split(p0)
    scale = np.concatenate([obj.steps(theta, 0)[:3]]
                           + [obj.steps(theta, i)[[3, 3, 4]] for i in range(obj.R)]) / _STEP
    p0 = np.clip(p0, lb + 1e-12 * scale, ub - 1e-12 * scale)
    if free is None:
        free = np.ones(obj.P, dtype=bool)
    cols = np.flatnonzero(free)

    def full(q: np.ndarray) -> np.ndarray:
        p = p0.copy()
        p[cols] = q
        return p

    def fun(q: np.ndarray) -> np.ndarray:
        return obj(full(q))

    def jac(q: np.ndarray):
        return obj.jac(full(q))[:, cols]

    sol = least_squares(fun, p0[cols], jac=jac, bounds=(lb[cols], ub[cols]), method="trf",
                        x_scale=scale[cols], max_nfev=MAX_NFEV,
                        tr_solver="lsmr" if obj.sparse else "exact",
                        xtol=1e-8, ftol=1e-8, gtol=1e-8)
    sol.x = full(sol.x)
    return sol


def _truncated(prob: FrictionProblem, span: float) -> FrictionProblem:
    """The problem on each window's first ``span`` seconds (at least 16 samples)."""
    out = []
    for w in prob.windows:
        n = max(int(np.searchsorted(w.t, w.t[0] + span, side="right")), min(16, w.t.size))
        out.append(ReleaseWindow(t=w.t[:n], x=w.x[:n], noise=w.noise, offset=w.offset, y0=w.y0,
                                 v0=w.v0))
    return FrictionProblem(windows=tuple(out), sigma=prob.sigma, w0sq=prob.w0sq)


def _pow2(v: float) -> float:
    """The power of two nearest below |v| (1 for 0 or a non-finite v): dividing by it is exact."""
    if not (math.isfinite(v) and v != 0.0):
        return 1.0
    return math.ldexp(1.0, math.frexp(abs(v))[1] - 1)


def fit_free_friction(prob: FrictionProblem, *,
                      start: np.ndarray | None = None) -> FrictionSolution:
    """Fit (σ, ω₀², a) and each release's (offset, y₀, v₀) (module docstring), in any units.

    The work is done by :func:`_fit_unit` on the windows with t divided by T (the longest
    window's span) and x by X (the largest |x|), both powers of two (exact), and every number
    is scaled back: the same record in any time or x unit gives the same fit (no step, bound
    or tolerance meets a number whose size depends on the unit). Parameters, returns and
    raises as :func:`_fit_unit`.
    """
    T = _pow2(max(float(w.t[-1] - w.t[0]) for w in prob.windows))
    X = _pow2(max(float(np.max(np.abs(w.x))) for w in prob.windows))
    unit = FrictionProblem(
        windows=tuple(ReleaseWindow(t=w.t / T, x=w.x / X, noise=w.noise / X,
                                    offset=w.offset / X, y0=w.y0 / X, v0=w.v0 * T / X)
                      for w in prob.windows),
        sigma=prob.sigma * T, w0sq=prob.w0sq * T * T)
    rt = np.array([T, T * T, T * T / X])  # θ' = θ·rt: σ, ω₀², a in units of T and X
    ro = np.array([X, X, X / T])           # own = own'·ro: offset, y₀, v₀
    f = _fit_unit(unit, start=None if start is None else np.asarray(start, float) * rt)
    motions = tuple(CoulombDecay(
        y=m.y * X, v=m.v * (X / T), turns=m.turns * T,
        stop=None if m.stop is None else m.stop * T,
        stuck=None if m.stuck is None else m.stuck * X) for m in f.motions)
    return FrictionSolution(
        theta=f.theta / rt, own=f.own * ro[None, :], motions=motions,
        resid=tuple(e * X for e in f.resid), cov_white=f.cov_white / np.outer(rt, rt),
        jac=tuple(J * (X * rt)[None, :] for J in f.jac),
        jac_own=tuple(J * (X / ro)[None, :] for J in f.jac_own),
        resid_var=tuple(v * X * X for v in f.resid_var), converged=f.converged, nfev=f.nfev)


def _fit_unit(prob: FrictionProblem, *,
              start: np.ndarray | None = None) -> FrictionSolution:
    """Fit (σ, ω₀², a) and each release's (offset, y₀, v₀) (module docstring).

    Parameters
    ----------
    prob : FrictionProblem
    start : ndarray, shape (3,), optional
        (σ, ω₀², a) to refit from, alone (each release from its window's ``offset``, ``y0``
        and ``v0``); by default the starts, continuation and restarts of the module
        docstring.

    Returns
    -------
    FrictionSolution

    Raises
    ------
    ValueError
        When the fitted JᵀJ is singular (the data do not determine a parameter).
    """
    obj = _Objective(prob)
    T = max(float(w.t[-1] - w.t[0]) for w in prob.windows)
    own0 = np.array([[w.offset, w.y0, w.v0] for w in prob.windows])
    big = np.inf
    lb = np.full(obj.P, -big)
    ub = np.full(obj.P, big)
    lb[0] = -5.0 / T  # growth beyond e⁵ over the window is no decay
    lb[1], ub[1] = prob.w0sq / 100.0, prob.w0sq * 100.0
    if start is not None:
        return _finish(obj, prob, _solve(obj, np.concatenate([start, own0.ravel()]), lb, ub))
    starts = [np.concatenate([[prob.sigma, prob.w0sq, 0.0], own0.ravel()])]
    k = int(np.argmax([a / w.noise for a, w in zip(obj.amp, prob.windows, strict=True)]))
    wk = prob.windows[k]
    env = envelope_start(wk.t, wk.x - wk.offset, prob.sigma, prob.w0sq, wk.noise)
    if env is not None and env[0] > lb[0] and lb[1] < env[1] < ub[1]:
        starts.append(np.concatenate([list(env), own0.ravel()]))
    best = None
    h = math.pi / math.sqrt(max(prob.w0sq - prob.sigma**2, prob.w0sq * 1e-6))
    spans = [4 * h * 4**j for j in range(8) if 4 * h * 4**j < T] + [math.inf]
    for j, p0 in enumerate(starts):
        if j == 0:  # the viscous start on the whole record at once: the nested guarantee
            best = _solve(obj, p0, lb, ub)
        # continuation over growing windows (4, 16, 64 … half periods, then all): the phase
        # error of a start accumulates over the record and would pull the rates into the
        # basin of a neighbouring stop; a short window locks ω₀ first
        p = p0
        for span in spans:
            sub = _Objective(_truncated(prob, span)) if math.isfinite(span) else obj
            sol = _solve(sub, p, lb, ub)
            p = sol.x
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    # the neighbouring stops: f_c/m changed by the share that moves a stop by one half-cycle
    theta, own = obj.split(best.x)
    turns = max(_motion(w, theta, own[i]).turns.size for i, w in enumerate(prob.windows))
    for f in (1.0 + 1.0 / max(turns, 2), 1.0 - 1.0 / max(turns, 2)):
        p0 = best.x.copy()
        p0[2] *= f
        sol = _solve(obj, p0, lb, ub)
        if sol.cost < best.cost:
            best = sol
    return _finish(obj, prob, best)


def _finish(obj: _Objective, prob: FrictionProblem, best: Any) -> FrictionSolution:
    """The solution at ``best`` (a least_squares result): motions, residuals, the Jacobian
    blocks (central differences) and the Gauss–Newton covariance."""
    p = best.x
    theta, own = obj.split(p)
    motions = tuple(_motion(w, theta, own[i]) for i, w in enumerate(prob.windows))
    resid = tuple(w.x - own[i, 0] - m.y for i, (w, m) in
                  enumerate(zip(prob.windows, motions, strict=True)))
    blocks = obj.blocks(p, central=True)
    info = np.zeros((3, 3))
    var = []
    for (Js, Jo), r in zip(blocks, resid, strict=True):
        # profile out the release's own parameters: project Js off the columns of Jo
        coef, *_ = np.linalg.lstsq(Jo, Js, rcond=None)
        Jp = Js - Jo @ coef
        s2 = float(r @ r) / max(r.size - 3, 1)
        s2 = s2 if s2 > 0 else 1.0
        var.append(s2)
        info += Jp.T @ Jp / s2
    try:
        cov_white = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        raise ValueError("the friction fit's JᵀJ is singular: the records do not determine "
                         "σ, ω₀² and f_c/m together") from None
    if not np.all(np.isfinite(cov_white)) or np.any(np.diag(cov_white) < 0):
        raise ValueError("the friction fit's JᵀJ is singular: the records do not determine "
                         "σ, ω₀² and f_c/m together")
    return FrictionSolution(theta=np.array(theta, dtype=float), own=np.array(own, dtype=float),
                            motions=motions, resid=resid, cov_white=cov_white,
                            jac=tuple(b[0] for b in blocks), jac_own=tuple(b[1] for b in blocks),
                            resid_var=tuple(var), converged=bool(best.status > 0),
                            nfev=int(best.nfev))
