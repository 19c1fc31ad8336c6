r"""Coulomb friction with the sensor noise inside a digital loop: the output error of the plant
with friction driven by the force the controller applied.

With the noise in the loop (a rig's controller reads the recorded, noisy encoder) the
controller turns the noise into a force on the plant, which the friction route's model (the
closed loop simulated from the true position) does not have: its residual carries the loop's
response to the noise, coloured, and its stderr do not cover the errors (3–10 stderr off,
issue 28). Given the record that force is known (:func:`phoid.methods.inloop_model.
applied_force`: the law on the recorded positions, delayed and held), and the conditional
likelihood of the record is the output error of the plant

    m x'' + c x' + k x + f_c sign(x') = u(t),   x̃_j = x_j + b + e_j,

u piecewise constant over the recorder's steps (known), e white (docs/design-notes/inloop.md
for the argument; docs/design-notes/friction.md for the measurements).

The plant's response (:func:`driven_response`) is exact: between velocity zero crossings the
motion is the linear plant under the constant force u − f_c·sign(v), stepped by the exact
transition over a recorder step; where the velocity's sign at a step's end differs from its
start, the crossing is located inside the step on the step's exact Taylor series (summed to
rounding) and there the mass sticks if |u − k x| ≤ f_c (static = kinetic), else slides on in
the direction of u − k x for the rest of the step. A stuck mass stays at its position until a
step whose force breaks it free (|u_j − k x| > f_c: the force changes only at the steps'
boundaries). A velocity that would change sign twice within one step (dynamics faster than
the recorder) is not resolved. Python iterates per step per run (scalar arithmetic): the time
per set is in the design note.

The fit (:func:`fit_friction_inloop`): θ = (m, c, k, f_c), one position offset b for the set,
and per run its state (x, ẋ) at the window's first sample and, for a recursive velocity
estimator, the weights of its start-state force patterns — all jointly, by
``scipy.optimize.least_squares`` (trust region, forward differences with the Jacobian's
sparsity: each run's nuisances touch only its own residuals). The model is continuous and
piecewise smooth in the parameters (a stick's end moves by whole steps, but only where the
net force crosses zero, so the trajectory moves continuously); the Jacobian is the forward
difference at the optimum, i.e. the derivative of the smooth piece the optimum lies on (a
difference step that straddles a stick–slip decision is improbable at the step used, 1.5e-8
relative). Stderr: the (θ, θ) block of σ̂²(JᵀJ)⁻¹, σ̂² = RSS/(n − p).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid.errors import IdentificationError
from phoid.methods.inloop_model import RunWindow

if TYPE_CHECKING:
    from phoid.methods.friction.results import FrictionFit
    from phoid.methods.inloop_route import PlacementTest

__all__ = ["FrictionInLoopFit", "apply_placement", "closed_loop_rss", "driven_response",
           "fit_friction_inloop", "fit_from_route", "friction_windows", "placement_test"]

#: most events (zero crossings) resolved inside one step
_MAX_EVENTS_PER_STEP = 8
#: most residual evaluations of the fit per parameter (scipy's max_nfev)
_NFEV_PER_PARAM = 60
#: least_squares' ftol, xtol and gtol: a noise-free record is fitted to ~1e-8 relative; a noisy
#: one stops within ~1e-3 of its stderr
_TOL = 1e-10
#: trust-region steps of the preliminary fit behind the data's placement test
_TEST_NFEV = 4


@dataclass(frozen=True)
class FrictionInLoopFit:
    """The in-loop output-error fit of a friction set (module docstring).

    Attributes
    ----------
    theta : ndarray, shape (4,)
        (m, c, k, f_c).
    cov : ndarray, shape (4, 4)
        σ̂²·[(JᵀJ)⁻¹]_θθ, every nuisance profiled out.
    sigma : float
        σ̂ = √(RSS/(n − p)), the white sensor noise's sd.
    rss : float
    samples, parameters : int
    offset : float
        The set's position offset b.
    states : ndarray, shape (S, 2)
        Each window's fitted (x, ẋ) at its first sample.
    residuals : tuple of ndarray
        Each window's residual.
    converged : bool
    nfev : int
        Residual evaluations.
    """

    theta: np.ndarray
    cov: np.ndarray
    sigma: float
    rss: float
    samples: int
    parameters: int
    offset: float
    states: np.ndarray
    residuals: tuple[np.ndarray, ...] = field(repr=False)
    converged: bool = True
    nfev: int = 0

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors of (m, c, k, f_c)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def _transition(m: float, c: float, k: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ (2 × 2) and Γ (2,) of the exact step h of m x'' + c x' + k x = F (F constant):
    (x, v)(h) = Φ (x, v)(0) + Γ F. The step's Taylor series (:func:`_taylor`) over h/2ˢ, the
    scaled step short enough (|λ|h/2ˢ ≤ 0.5) for 30 terms to reach rounding, then squared s
    times (Φ₂ₜ = Φₜ², Γ₂ₜ = ΦₜΓₜ + Γₜ); plain arithmetic, no matrix exponential call (whose
    fixed cost, with a busy BLAS, exceeded the whole response's)."""
    lam = math.sqrt(abs(k) / m) + abs(c) / m
    sq = 0
    while lam * h / 2.0**sq > 0.5 and sq < 60:
        sq += 1
    t = h / 2.0**sq
    cols = []
    for x0, v0, F in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
        a = _taylor(x0, v0, F, m, c, k, 30)
        x, v, _ = _poly(a, t)
        cols.append((x, v))
    Phi = np.array([[cols[0][0], cols[1][0]], [cols[0][1], cols[1][1]]])
    Gam = np.array(cols[2])
    for _ in range(sq):
        Gam = Phi @ Gam + Gam
        Phi = Phi @ Phi
    return Phi, Gam


def _taylor(x0: float, v0: float, F: float, m: float, c: float, k: float,
            K: int) -> list[float]:
    """Coefficients a_0 … a_K of x(t) = Σ a_n tⁿ for m x'' + c x' + k x = F from (x0, v0)."""
    a = [x0, v0]
    for n in range(K - 1):
        a.append(((F if n == 0 else 0.0) - c * (n + 1) * a[n + 1] - k * a[n])
                 / (m * (n + 1) * (n + 2)))
    return a


def _poly(a: list[float], t: float) -> tuple[float, float, float]:
    """x(t), x'(t), x''(t) of the series a."""
    x = v = w = 0.0
    for n in range(len(a) - 1, -1, -1):
        x = x * t + a[n]
        if n >= 1:
            v = v * t + n * a[n]
        if n >= 2:
            w = w * t + n * (n - 1) * a[n]
    return x, v, w


def _zero(a: list[float], t_end: float) -> float:
    """The root of x'(t) in (0, t_end] of the series a, whose x'(0) and x'(t_end) differ in
    sign (or x'(t_end) = 0): Newton safeguarded by bisection, to 1e-13 of the step (x' = 0
    there, so the position's error is second order in the time's: far below rounding)."""
    v_lo = _poly(a, 0.0)[1]
    v_hi = _poly(a, t_end)[1]
    lo, hi = 0.0, t_end
    t = t_end * v_lo / (v_lo - v_hi) if v_lo != v_hi else 0.5 * t_end
    tol = 1e-13 * t_end
    for _ in range(60):
        _, v, acc = _poly(a, t)
        if v == 0.0:
            return t
        if (v > 0) == (v_lo > 0):
            lo = t
        else:
            hi = t
        tn = t - v / acc if acc != 0.0 else math.nan
        if not (lo <= tn <= hi):
            tn = 0.5 * (lo + hi)
        if abs(tn - t) <= tol or hi - lo <= tol:
            return tn
        t = tn
    return t


def _events(x: float, v: float, s: int, u: float, m: float, c: float, k: float, fc: float,
            h: float, K: int) -> tuple[float, float, int]:
    """The state (x, v, s) at the end of a step of force u in which the velocity, sliding in
    the direction s from (x, v), reaches zero: at each crossing the mass sticks where
    |u − k x| ≤ f_c, else it slides on in the direction of u − k x (module docstring)."""
    left = h
    for _ in range(_MAX_EVENTS_PER_STEP):
        a = _taylor(x, v, u - fc * s, m, c, k, K)
        ts = _zero(a, left)
        xs, _, _ = _poly(a, ts)
        left -= ts
        g = u - k * xs
        if abs(g) <= fc:
            return xs, 0.0, 0
        s = 1 if g > 0 else -1
        a = _taylor(xs, 0.0, u - fc * s, m, c, k, K)
        xe, ve, _ = _poly(a, left)
        if ve * s > 0 or left <= 0.0:
            return xe, ve, s
        x, v = xs, 0.0  # reverses again within the step: from the crossing on
    return x, v, s


def driven_response(m: float, c: float, k: float, fc: float, h: float, force: np.ndarray,
                    x0: float, v0: float) -> np.ndarray:
    """The position of m x'' + c x' + k x + f_c sign(x') = u at the recorder's samples,
    exact (module docstring).

    Parameters
    ----------
    m, c, k, fc : float
        The plant (m > 0, f_c ≥ 0).
    h : float
        The recorder's step, s.
    force : ndarray, shape (L,)
        The force held from each sample to the next, N (the last unused).
    x0, v0 : float
        The state at the first sample.

    Returns
    -------
    ndarray, shape (L,)
        x at the L samples (nan from where the motion overflows).
    """
    L = int(force.size)
    if L == 0:
        return np.empty(0)
    Phi, Gam = _transition(m, c, k, h)
    p11, p12, p21, p22 = (float(v) for v in Phi.ravel())
    g1, g2 = float(Gam[0]), float(Gam[1])
    # Taylor order for the steps' insides: the terms (|λ|h)ⁿ/n! below rounding
    lam_h = (math.sqrt(abs(k) / m) + abs(c) / m) * h
    K = 6
    while K < 60 and lam_h**K / math.factorial(K) > 1e-18:
        K += 1
    x, v = float(x0), float(v0)
    f = force.tolist()
    xs_out = [0.0] * L
    if v > 0:
        s = 1
    elif v < 0:
        s = -1
    else:
        g = f[0] - k * x
        s = 0 if abs(g) <= fc else (1 if g > 0 else -1)
    last = L - 1
    for j in range(L):
        xs_out[j] = x
        if j == last:
            break
        u = f[j]
        if s == 0:  # stuck: breaks free where the step's force exceeds f_c
            g = u - k * x
            if -fc <= g <= fc:
                continue
            s = 1 if g > 0 else -1
        F = u - fc * s
        vn = p21 * x + p22 * v + g2 * F
        if vn * s > 0:
            x = p11 * x + p12 * v + g1 * F
            v = vn
            continue
        x, v, s = _events(x, v, s, u, m, c, k, fc, h, K)
        if not (math.isfinite(x) and math.isfinite(v)):
            xs_out[j + 1:] = [math.nan] * (L - j - 1)
            break
    out = np.array(xs_out)
    return out


class _Problem:
    """The windows and the parameter vector: θ (4), b, then per window (x, ẋ, weights…)."""

    def __init__(self, windows: Sequence[RunWindow]) -> None:
        self.windows = list(windows)
        self.R = [0 if w.patterns is None else w.patterns.shape[0] for w in self.windows]
        self.local = [2 + r for r in self.R]
        self.cols = np.concatenate([[5], 5 + np.cumsum(self.local)]).astype(int)
        self.rows = np.concatenate([[0], np.cumsum([w.size for w in self.windows])]).astype(int)
        self.n = int(self.rows[-1])
        self.p = int(self.cols[-1])

    def sparsity(self):
        from scipy.sparse import lil_matrix

        A = lil_matrix((self.n, self.p), dtype=int)
        A[:, :5] = 1
        for i in range(len(self.windows)):
            A[self.rows[i]:self.rows[i + 1], self.cols[i]:self.cols[i + 1]] = 1
        return A

    def model(self, p: np.ndarray) -> np.ndarray:
        m, c, k, fc, b = (float(a) for a in p[:5])
        out = np.empty(self.n)
        if not (m > 0 and fc >= 0 and all(math.isfinite(a) for a in (m, c, k, fc, b))):
            out.fill(math.nan)
            return out
        for i, w in enumerate(self.windows):
            loc = p[self.cols[i]:self.cols[i + 1]]
            force = w.force
            if self.R[i]:
                force = force + loc[2:] @ w.patterns
            out[self.rows[i]:self.rows[i + 1]] = b + driven_response(
                m + w.added_mass, c, k, fc, w.step, force, float(loc[0]), float(loc[1]))
        return out

    def residual(self, p: np.ndarray) -> np.ndarray:
        r = np.concatenate([w.y for w in self.windows]) - self.model(p)
        # a plant that overflows: a large, finite residual (least_squares needs finite values)
        return np.where(np.isfinite(r), r, 1e6 * (1.0 + np.nanmax(np.abs(r), initial=1.0)))


def fit_friction_inloop(windows: Sequence[RunWindow], theta0: Sequence[float], offset0: float,
                        states0: np.ndarray, *, max_nfev: int | None = None
                        ) -> FrictionInLoopFit:
    """The in-loop output-error fit of (m, c, k, f_c) over the runs' windows.

    Parameters
    ----------
    windows : sequence of RunWindow
        The runs' windows with the applied force (:func:`phoid.methods.inloop_route.
        inloop_windows`).
    theta0 : sequence of 4 float
        Starting (m, c, k, f_c) (the friction route's estimate).
    offset0 : float
        Starting offset b.
    states0 : ndarray, shape (S, 2)
        Starting (x, ẋ) of each window at its first sample.
    max_nfev : int, optional
        Most trust-region steps (default 60 per global parameter); a preliminary fit for the
        data's placement test takes a few (its RSS only over-states the in-loop fit's).

    Returns
    -------
    FrictionInLoopFit

    Raises
    ------
    IdentificationError
        No window, fewer samples than parameters, or m, c, k, f_c left undetermined.
    """
    from scipy.optimize import least_squares

    if not windows:
        raise IdentificationError("no run has a window for the in-loop friction fit")
    prob = _Problem(windows)
    if prob.n <= prob.p:
        raise IdentificationError(f"the in-loop friction fit has {prob.n} samples for "
                                  f"{prob.p} parameters")
    p0 = np.zeros(prob.p)
    th = np.asarray(theta0, dtype=float)
    p0[:4] = [th[0], th[1], th[2], max(th[3], 0.0)]
    p0[4] = offset0
    for i in range(len(windows)):
        p0[prob.cols[i]:prob.cols[i] + 2] = states0[i]
    lower = np.full(prob.p, -np.inf)
    lower[0] = 1e-12 * max(abs(th[0]), 1e-300)
    lower[3] = 0.0
    p0[0] = max(p0[0], 2 * lower[0])
    res = least_squares(prob.residual, p0, jac_sparsity=prob.sparsity(), method="trf",
                        bounds=(lower, np.full(prob.p, np.inf)), x_scale="jac",
                        ftol=_TOL, xtol=_TOL, gtol=_TOL,
                        max_nfev=_NFEV_PER_PARAM * 5 if max_nfev is None else max_nfev)
    r = prob.residual(res.x)
    rss = float(r @ r)
    dof = prob.n - prob.p
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    d = np.sqrt(np.einsum("ij,ij->j", J, J))
    if not np.all(d[:4] > 0):
        raise IdentificationError("the in-loop friction fit leaves m, c, k, fc undetermined")
    Js = J / np.where(d > 0, d, 1.0)
    H = Js.T @ Js
    # a nuisance the records do not determine (a column of zeros: a run stuck throughout its
    # window leaves its velocity free) is held at its value; θ must be determined
    live = np.flatnonzero(d > 0)
    inv = np.zeros_like(H)
    try:
        Hl = H[np.ix_(live, live)]
        if not np.linalg.cond(Hl) < 1e12:
            raise np.linalg.LinAlgError
        inv[np.ix_(live, live)] = np.linalg.inv(Hl)
    except np.linalg.LinAlgError:
        raise IdentificationError("the in-loop friction fit leaves m, c, k, fc undetermined "
                                  "(the runs' responses do not separate them)") from None
    s2 = rss / dof
    cov = s2 * inv[:4, :4] / np.outer(d[:4], d[:4])
    resid = tuple(r[prob.rows[i]:prob.rows[i + 1]].copy() for i in range(len(windows)))
    states = np.array([res.x[prob.cols[i]:prob.cols[i] + 2] for i in range(len(windows))])
    return FrictionInLoopFit(res.x[:4].copy(), 0.5 * (cov + cov.T), math.sqrt(s2), rss,
                             prob.n, prob.p, float(res.x[4]), states, resid,
                             bool(res.status > 0), int(res.nfev))


# --------------------------------------------------------------------------------------------
# from the friction route's fit to the in-loop one


@dataclass(frozen=True)
class _Release:
    """A run's model-fitted release, as :func:`phoid.methods.inloop_route.inloop_windows`
    reads it (its ``release``)."""

    release: float


def friction_windows(base: FrictionFit, P: np.ndarray, D: np.ndarray, digital: Any,
                     added_mass: np.ndarray) -> tuple[list[RunWindow], list[str]]:
    """The used runs' in-loop windows (:func:`phoid.methods.inloop_route.inloop_windows`: the
    force the controller applied, from a few samples after the friction fit's release to the
    record's end), and why the others have none."""
    from phoid.methods.inloop_route import inloop_windows

    used = [i for i, r in enumerate(base.runs) if r.used]
    data = [(np.asarray(base.data[i][0], dtype=float), np.asarray(base.data[i][1], dtype=float))
            for i in used]
    windows, notes = inloop_windows(data, P[used], D[used], digital,
                                    names=[base.runs[i].name for i in used],
                                    added_mass=added_mass[used],
                                    fits=[_Release(base.runs[i].release) for i in used])
    # inloop_windows numbers the runs it was given: back to the set's numbering
    windows = [RunWindow(used[w.run], w.start, w.y, w.force, w.patterns, w.step, w.added_mass)
               for w in windows]
    return windows, notes


def fit_from_route(base: FrictionFit, windows: Sequence[RunWindow], *,
                   max_nfev: int | None = None) -> FrictionInLoopFit:
    """:func:`fit_friction_inloop` started from the friction route's fit: its m, c, k, f_c,
    the median of its offsets, and each window's state from its model at the first sample."""
    th0 = [base.m.value, base.c.value, base.k.value, max(base.fc.value, 0.0)]
    b0 = float(np.median([base.runs[w.run].offset for w in windows]))
    states = np.zeros((len(windows), 2))
    for j, w in enumerate(windows):
        t = np.asarray(base.data[w.run][0], dtype=float)[w.start: w.start + 1]
        pos, vel = base.model(w.run, t)
        states[j] = float(pos[0]) - base.runs[w.run].offset, float(vel[0])
    return fit_friction_inloop(windows, th0, b0, states, max_nfev=max_nfev)


def closed_loop_rss(base: FrictionFit, windows: Sequence[RunWindow]) -> float:
    """The residual sum of squares of the friction route's model (the closed loop simulated
    from the true position) over the in-loop windows' samples."""
    rss = 0.0
    for w in windows:
        t = np.asarray(base.data[w.run][0], dtype=float)[w.start: w.start + w.size]
        pos, _ = base.model(w.run, t)
        e = w.y - pos
        rss += float(e @ e)
    return rss


def placement_test(rss_outside: float, fit: FrictionInLoopFit) -> PlacementTest:
    """D = ``rss_outside`` (:func:`closed_loop_rss`) − the in-loop fit's RSS over the same
    samples, and z = sign(D)·√|D|/(2σ̂) (the test of
    :func:`phoid.methods.inloop_route.placement_test`, with the friction route's model in the
    modal route's place)."""
    from phoid.methods.inloop_route import Z_THRESHOLD, PlacementTest

    diff = rss_outside - fit.rss
    s = fit.sigma
    if s > 0:
        z = math.copysign(math.sqrt(abs(diff)) / (2.0 * s), diff)
    else:
        z = math.inf if diff > 0 else (0.0 if diff == 0 else -math.inf)
    return PlacementTest(z, Z_THRESHOLD, rss_outside, fit.rss, s, fit.samples)


def _inloop_result(base: FrictionFit, fit: FrictionInLoopFit, windows: Sequence[RunWindow],
                   notes: Sequence[str]) -> FrictionFit:
    """``base`` with the in-loop fit's m, c, k, f_c, covariance and statistics; the closed-loop
    fit's own misfit words (its residual carries the loop's response to the noise) left out."""
    from dataclasses import replace

    from phoid.methods.estimate import Estimate
    from phoid.methods.fit_statistics import difference_noise

    se = fit.stderr
    units = ("kg", "N s/m", "N/m", "N")
    est = [Estimate(float(v), float(s), u) for v, s, u in zip(fit.theta, se, units,
                                                              strict=True)]
    route_words = set(base.adequacy.warnings) if base.adequacy is not None else set()
    warnings = [w for w in base.warnings if w not in route_words
                and not w.startswith("χ²/dof = ") and ": misfit: " not in w]
    warnings += list(notes)
    noise = [s for s in (difference_noise(w.y, rounding=True) for w in windows) if s > 0]
    if noise and fit.sigma > 1.5 * float(np.median(noise)):
        warnings.append(
            f"misfit: the in-loop friction fit's residual sd {fit.sigma:.3g} is "
            f"{fit.sigma / float(np.median(noise)):.3g} times the records' noise: check the "
            "loop (gains, delay, velocity estimator) or unmodelled dynamics")
    if not fit.converged:
        warnings.append(f"the in-loop friction fit did not converge ({fit.nfev} evaluations): "
                        "m, c, k, fc may not be at the output error's minimum")
    if fit.theta[3] <= 0.0:
        warnings.append("fc is at its bound 0: no friction detected")
    runs = list(base.runs)
    for w, e in zip(windows, fit.residuals, strict=True):
        runs[w.run] = replace(runs[w.run], residual_rms=float(np.sqrt(np.mean(e * e))),
                              offset=fit.offset,
                              warnings=tuple(x for x in runs[w.run].warnings
                                             if not x.startswith("misfit:")))
    rms = float(np.sqrt(np.mean(np.concatenate(fit.residuals) ** 2)))
    sd = {w.run: base.runs[w.run].noise_sd for w in windows}
    chi2 = float(sum(float(e @ e) / sd[w.run] ** 2 for w, e in zip(windows, fit.residuals,
                                                                     strict=True)))
    return replace(base, m=est[0], c=est[1], k=est[2], fc=est[3], cov=fit.cov,
                   runs=tuple(runs), chi2=chi2, dof=fit.samples - fit.parameters,
                   residual_rms=rms, converged=fit.converged, warnings=tuple(warnings),
                   adequacy=None, noise_placement="in-loop")


def apply_placement(base: FrictionFit, P: np.ndarray, D: np.ndarray, digital: Any,
                    added_mass: np.ndarray, *, option: str | None,
                    stated: str | None) -> FrictionFit:
    """The friction result for the noise placement (the rules of
    :func:`phoid.methods.inloop_route.identify_digital`): an option (``"in-loop"``,
    ``"outside"``) decides, else the manifest's ``[loop] noise``, else the data (the in-loop
    fit is made and chosen where z > 3, :func:`placement_test`). A continuous loop keeps the
    closed-loop fit (``"in-loop"`` asked of it is refused).

    Parameters
    ----------
    base : FrictionFit
        The friction route's fit (the closed loop simulated from the true position).
    P, D : ndarray
        The runs' gains.
    digital : phoid.DigitalPD or None
        The sampled loop.
    added_mass : ndarray
        Each run's known added mass, kg.
    option : str or None
        ``noise_placement``: ``"auto"`` (or None), ``"in-loop"`` or ``"outside"``.
    stated : str or None
        The manifest's ``[loop] noise``.

    Returns
    -------
    FrictionFit
        With ``noise_placement``, ``noise_placement_source`` and (where made)
        ``placement_test``.

    Raises
    ------
    IdentificationError
        ``"in-loop"`` asked of a continuous loop, or of records the in-loop fit cannot fit.
    """
    from dataclasses import replace

    from phoid.methods.inloop_route import (
        Z_THRESHOLD,
        PlacementTest,
        check_placement,
        placement_source,
    )

    requested = check_placement(option)
    if digital is None:
        if requested == "in-loop":
            raise IdentificationError(
                "the noise placement 'in-loop' needs a digital loop ([loop] sample_time): a "
                "continuous loop's friction fit simulates the closed loop")
        extra = () if stated != "in-loop" else (
            "[loop] noise = 'in-loop', but the loop is continuous (no [loop] sample_time): "
            "the friction fit simulates the closed loop, whose stderr assume the noise "
            "outside the loop",)
        return replace(base, noise_placement="outside",
                       noise_placement_source="continuous loop",
                       warnings=(*base.warnings, *extra))
    placement, how, notes = placement_source(requested, stated)
    if placement == "outside":
        return replace(base, noise_placement="outside", noise_placement_source=how,
                       warnings=(*base.warnings, *notes))
    fit = None
    reason = None
    windows, skipped = friction_windows(base, P, D, digital, added_mass)
    if not windows:
        reason = "no run has a window for it" + (f" ({skipped[0]})" if skipped else "")
    else:
        try:
            # the data's test first from a few steps (its RSS over-states the optimum's, so D
            # is under-stated: the test errs toward the closed-loop fit), the fit to its end
            # only where the in-loop route is taken
            fit = fit_from_route(base, windows,
                                 max_nfev=_TEST_NFEV if placement is None else None)
            rss_o = closed_loop_rss(base, windows)
            if placement is None:
                test = placement_test(rss_o, fit)
                if test.z is not None and test.z > Z_THRESHOLD:
                    fit = fit_friction_inloop(windows, fit.theta, fit.offset, fit.states)
        except (IdentificationError, np.linalg.LinAlgError, ValueError) as exc:
            reason = str(exc)
            fit = None
    if fit is None:
        if placement == "in-loop" and how == "option":
            raise IdentificationError(f"the in-loop friction fit cannot be made: {reason}")
        test = PlacementTest(None, reason=f"the in-loop fit cannot be made: {reason}")
        extra = () if placement is None else (
            f"[loop] noise = 'in-loop', but the in-loop friction fit cannot be made "
            f"({reason}): m, c, k, fc come from the closed-loop fit, whose stderr assume the "
            "noise outside the loop",)
        return replace(base, noise_placement="outside", noise_placement_source=how,
                       placement_test=test, warnings=(*base.warnings, *notes, *extra))
    test = placement_test(rss_o, fit)
    if placement is None and not (test.z is not None and test.z > Z_THRESHOLD):
        return replace(base, noise_placement="outside", noise_placement_source="data",
                       placement_test=test)
    out = _inloop_result(base, fit, windows, [*notes, *skipped])
    return replace(out, noise_placement_source=how, placement_test=test)
