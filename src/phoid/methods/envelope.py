r"""The envelope of a decay's turning points: a pure exponential, or a constant loss as well?

A linear viscous decay's turning points lie on one exponential; Coulomb friction removes a
constant amount of amplitude per half cycle besides; drag ∝ v|v| removes less and less as the
amplitude falls. :func:`turning_points` finds the crests of a record, :func:`envelope_test`
fits dA/dt = −σA − q to them against q = 0 (the ``structure`` check of
:mod:`phoid.methods.adequacy` names the cause by q's sign). docs/adequacy.md gives the
measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Envelope", "envelope_test", "normal_isf", "t_isf", "turning_points"]

#: false-alarm probability (as :data:`phoid.methods.adequacy.ALPHA`)
ALPHA = 1e-3
#: |slope|/stderr of the backbone beyond which the time is warped (two-sided 1e-3)
T_SLOPE = 3.29


def normal_isf(p: float) -> float:
    """z with P(N(0, 1) > z) = p (0 < p < 1), by bisection on erfc (to 1e-12)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1); got {p}")
    lo, hi = -40.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 0.5 * math.erfc(mid / math.sqrt(2.0)) > p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12:
            break
    return 0.5 * (lo + hi)


def t_isf(p: float, dof: float) -> float:
    """Student's t upper quantile, P(t_dof > x) = p, by the Cornish–Fisher expansion about the
    normal one (Abramowitz and Stegun 26.7.5, four terms): within 0.5 % of the exact value for
    dof ≥ 6 and p ≥ 5e-4 (tests/test_adequacy.py checks it against scipy.stats.t)."""
    z = normal_isf(p)
    v = float(dof)
    z2 = z * z
    g1 = (z2 + 1) * z / 4
    g2 = ((5 * z2 + 16) * z2 + 3) * z / 96
    g3 = (((3 * z2 + 19) * z2 + 17) * z2 - 15) * z / 384
    g4 = ((((79 * z2 + 776) * z2 + 1482) * z2 - 1920) * z2 - 945) * z / 92160
    return z + g1 / v + g2 / v**2 + g3 / v**3 + g4 / v**4


def turning_points(t: Any, x: Any, offset: float, omega_d: float, noise: float, *,
                   min_nsd: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The turning points (extremes) of an oscillation, one per half cycle, each from a local
    parabola.

    From the largest |x − offset| of the first half period on, each next extreme is sought,
    with the opposite sign, within a third of a half period of where the last half period
    puts it (the local half period follows the record: a frequency that changes with the
    amplitude is followed). Its time and value are the vertex of the least-squares parabola
    through the samples within ±T/8 of the sample found (T = 2π/ω_d, the local period), its
    stderr the vertex value's (delta method, noise sd ``noise``). The parabola's error on a
    cosine's crest is a fixed fraction of the amplitude (the crests of a linear decay are one
    shape at every scale), so it changes no ratio of amplitudes. It stops at the first extreme
    whose |value − offset| is below ``min_nsd`` noise sd, that is not a crest of the expected
    sign, or whose vertex leaves its window.

    Parameters
    ----------
    t, x : array_like
        The record (t increasing).
    offset : float
        The rest level the motion swings about.
    omega_d : float
        The damped frequency, rad/s (a first guess: the local one is followed).
    noise : float
        The noise sd, x's unit.
    min_nsd : float
        The smallest |extreme − offset| used, in noise sd. A noisy parabola's vertex
        overshoots the crest by about se(slope)²/(4|curvature|), a bias that grows as the
        amplitude falls and reads as a slowing decay: at 10 noise sd the envelope test's t had
        an sd of 1.13 over 150 simulated linear decays, at 30 noise sd 0.98.

    Returns
    -------
    (t_k, p_k, se_k) : ndarrays
        The turning points' times, values (x's unit, the offset not removed) and stderr; empty
        when the record is sampled too coarsely (fewer than 5 samples within ±T/8) or too short.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(x, dtype=float) - offset
    empty = (np.empty(0), np.empty(0), np.empty(0))
    if not (omega_d > 0 and noise > 0 and math.isfinite(omega_d)) or t.size < 16:
        return empty
    half = math.pi / omega_d
    dt = float(np.median(np.diff(t)))
    if not half / 4 >= 2.5 * dt:
        return empty
    out: list[tuple[float, float, float]] = []
    i0 = int(np.searchsorted(t, t[0] + half))
    k = int(np.argmax(np.abs(y[: max(i0, 1)])))
    sign = 1.0 if y[k] >= 0 else -1.0
    loc_half = half
    t_prev = math.nan
    for _ in range(int((t[-1] - t[0]) / (0.6 * half)) + 2):  # bounded: one per 0.6 half
        w = np.flatnonzero(np.abs(t - t[k]) <= loc_half / 4)
        if w.size < 5:
            break
        tau = t[w] - t[k]
        X = np.column_stack([np.ones_like(tau), tau, tau * tau])
        try:
            XtX_inv = np.linalg.inv(X.T @ X)
        except np.linalg.LinAlgError:
            break
        c0, c1, c2 = XtX_inv @ (X.T @ y[w])
        if not sign * c2 < 0:
            break
        tv = -c1 / (2 * c2)
        if abs(tv) > loc_half / 4:
            break
        pv = c0 - c1 * c1 / (4 * c2)
        g = np.array([1.0, -c1 / (2 * c2), c1 * c1 / (4 * c2 * c2)])
        se = noise * math.sqrt(max(float(g @ XtX_inv @ g), 0.0))
        if not sign * pv > min_nsd * noise:
            break
        tk = float(t[k] + tv)
        if out and math.isfinite(t_prev):
            loc_half = min(max(tk - t_prev, 0.7 * half), 1.4 * half)
        if t[k] - loc_half / 4 >= t[0]:  # not one cut by the record's start (extrapolated)
            out.append((tk, float(pv) + offset, se))
        t_prev = tk
        # the next extreme: opposite sign, about a half period on
        sign = -sign
        a = int(np.searchsorted(t, tk + loc_half * (1 - 1 / 3)))
        b = int(np.searchsorted(t, tk + loc_half * (1 + 1 / 3)))
        if b >= t.size or b - a < 3:
            break
        k = a + int(np.argmax(sign * y[a:b]))
    if len(out) < 2:
        return empty
    arr = np.array(out)
    return arr[:, 0], arr[:, 1], arr[:, 2]


@dataclass(frozen=True)
class Envelope:
    """Result of :func:`envelope_test`: the turning points' amplitudes against a pure
    exponential decay and against one with a constant loss as well.

    Attributes
    ----------
    n : int
        Turning points used.
    sigma : float
        The exponential rate of the fit with the constant loss, 1/s.
    loss, loss_se : float
        The constant loss rate q of dA/dt = −σA − q (x's unit per s; positive: the amplitude
        falls faster than exponentially, Coulomb friction; negative: slower, damping that
        grows with the amplitude) and its stderr.
    t : float
        q / se(q), the test statistic.
    threshold : float
        |t| beyond which the constant loss is significant (Student's t at two-sided α).
    amp_first, amp_last : float
        The first and last turning point's amplitude, x's unit.
    """

    n: int
    sigma: float
    loss: float
    loss_se: float
    t: float
    threshold: float
    amp_first: float
    amp_last: float

    @property
    def significant(self) -> bool:
        """|t| above its threshold."""
        return abs(self.t) > self.threshold

    def detail(self, x_unit: str) -> str:
        """The fit in words."""
        return (f"envelope of {self.n} turning points ({self.amp_first:.3g} to "
                f"{self.amp_last:.3g} {x_unit}): dA/dt = −σA − q with σ = {self.sigma:.4g} 1/s, "
                f"q = {self.loss:.3g} ± {self.loss_se:.2g} {x_unit}/s, q/stderr {self.t:.3g} "
                f"(|q/stderr| ≤ {self.threshold:.3g} for an exponential decay)")


#: columns of the rest level in the envelope fit (a cubic drift in time)
_ENV_DRIFT = 4
#: least ratio of the first to the last turning point's amplitude for the envelope test
_ENV_RANGE = 3.0


def _env_design(tau: np.ndarray, s: np.ndarray, sigma: float, loss: bool) -> np.ndarray:
    e = np.exp(-sigma * tau)
    u = 2 * tau / tau[-1] - 1  # the rest level's slow drift: a cubic in time
    cols = [np.ones_like(tau), u, u * u, u**3, s * e]
    if loss:
        # (1 − e^{−στ})/σ, τ at σ = 0
        g = -np.expm1(-sigma * tau) / sigma if sigma != 0 else tau
        cols.append(-s * g)
    return np.column_stack(cols)


def _env_rss(tau: np.ndarray, p: np.ndarray, s: np.ndarray, w: np.ndarray, sigma: float,
             loss: bool) -> tuple[float, np.ndarray, np.ndarray]:
    X = _env_design(tau, s, sigma, loss) * np.sqrt(w)[:, None]
    yw = p * np.sqrt(w)
    beta, *_ = np.linalg.lstsq(X, yw, rcond=None)
    r = yw - X @ beta
    return float(r @ r), beta, r


def _env_min(tau: np.ndarray, p: np.ndarray, s: np.ndarray, w: np.ndarray,
             loss: bool) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Least squares over σ (a grid, then golden-section refinement): (rss, σ, β, residual)."""
    span = float(tau[-1] - tau[0])
    # σ from the amplitudes' log-linear slope, then a bracket wide enough for any decay whose
    # turning points are above the noise over the span
    grid = np.linspace(-2.0 / span, 20.0 / span, 111)
    rss = [_env_rss(tau, p, s, w, g, loss)[0] for g in grid]
    j = int(np.argmin(rss))
    lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]
    gr = (math.sqrt(5) - 1) / 2
    a, b = hi - gr * (hi - lo), lo + gr * (hi - lo)
    fa, fb = (_env_rss(tau, p, s, w, a, loss)[0], _env_rss(tau, p, s, w, b, loss)[0])
    for _ in range(60):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - gr * (hi - lo)
            fa = _env_rss(tau, p, s, w, a, loss)[0]
        else:
            lo, a, fa = a, b, fb
            b = lo + gr * (hi - lo)
            fb = _env_rss(tau, p, s, w, b, loss)[0]
    sg = 0.5 * (lo + hi)
    r, beta, res = _env_rss(tau, p, s, w, sg, loss)
    return r, sg, beta, res


def envelope_test(t_k: Any, p_k: Any, se_k: Any, *, alpha: float = ALPHA) -> Envelope | None:
    r"""Does the amplitude fall by a constant amount per cycle besides its exponential decay?

    The turning points pₖ (:func:`turning_points`), alternately above and below the rest
    level c, are fitted by weighted least squares (weights 1/seₖ²) with

        pₖ = c + sₖ A(tₖ),   A(τ) = A₀e^{−στ} − q(1 − e^{−στ})/σ,   sₖ = ±1 alternating,

    the solution of dA/dt = −σA − q: viscous damping (σ) and a constant loss rate q — Coulomb
    friction removes 4F/k per cycle, q = 2F/(πk)·ω (exact per half cycle: Aₖ₊₁ = e^{−σT/2}Aₖ
    − q′), and against q = 0, the pure exponential that a linear decay's turning points follow
    exactly (the crests of e^{−σt}cos(ω_d t + φ) all lie on one exponential). Both are
    minimised over σ. The statistic is the F test of the extra parameter,
    t = sign(q)·√((RSS₀ − RSS₁)/(RSS₁/(m − 4))), m turning points: Student's t with m − 4 dof
    under the linear decay, its scale taken from the fit's own scatter (the seₖ give only the
    weights). Where the residuals of the fit are correlated from one turning point to the
    next (coloured noise, with a correlation time of a half period or more), q's variance is
    larger by (1 + ρ)/(1 − ρ) (a smooth trend under AR(1) errors, ρ the residuals' lag-1
    autocorrelation, taken ≥ 0): t is divided by its square root. It is significant beyond
    Student's two-sided α quantile (:func:`t_isf`).

    The sign names the cause: q > 0, a loss that does not shrink with the amplitude (Coulomb
    friction: the local rate σ + q/A rises as A falls); q < 0, a loss that shrinks faster
    than the amplitude (drag ∝ v|v|: its rate falls with A). A frequency that changes with
    the amplitude does not enter: the turning points' own times are used, and with viscous
    damping the amplitude decays as e^{−σt} whatever the spring (first-order averaging).

    Parameters
    ----------
    t_k, p_k, se_k : array_like
        The turning points' times, values and stderr.
    alpha : float
        Two-sided false-alarm probability.

    Returns
    -------
    Envelope or None
        None with fewer than 13 turning points (m − 7 ≥ 6 dof), an amplitude range under 3×
        (first over last), or a degenerate fit.
    """
    tk = np.asarray(t_k, dtype=float)
    pk = np.asarray(p_k, dtype=float)
    sk = np.asarray(se_k, dtype=float)
    m = tk.size
    if m < _ENV_DRIFT + 9 or not (np.all(np.isfinite(pk)) and np.all(sk > 0)
                                  and np.all(np.isfinite(sk))):
        return None
    h = np.diff(tk)
    if not np.all(h > 0):
        return None
    dev = pk - np.median(pk)
    s = np.where(np.arange(m) % 2 == 0, 1.0, -1.0) * (1.0 if dev[0] >= 0 else -1.0)
    # the spring's own share of an amplitude-dependent decay rate (docstring): the backbone
    # ω² = ω₀²(1 + βA²) from the half periods against the half cycles' mean amplitude, and the
    # time warped by 1 − (5/12)βA²
    amid = 0.5 * np.abs(np.diff(pk))
    Xb = np.column_stack([np.ones(m - 1), amid * amid])
    yb = (math.pi / h) ** 2
    (b0, b1), *_ = np.linalg.lstsq(Xb, yb, rcond=None)
    rb = yb - Xb @ np.array([b0, b1])
    cb = np.linalg.pinv(Xb.T @ Xb) * float(rb @ rb) / max(m - 3, 1)
    # only a backbone the half periods show (|slope| > 3.29 stderr): a warp of noise would add
    # its own scatter to the test
    trend = abs(b1) > T_SLOPE * math.sqrt(max(float(cb[1, 1]), 0.0))
    kappa = 5.0 / 12.0 * b1 / b0 if b0 > 0 and trend else 0.0
    tau = np.concatenate([[0.0], np.cumsum(h * (1.0 - kappa * amid * amid))])
    if not (tau[-1] > 0 and np.all(np.diff(tau) > 0)):
        return None
    w = 1.0 / sk**2
    w = w / np.mean(w)
    try:
        rss0 = _env_min(tau, pk, s, w, False)[0]
        rss1, sg, beta, res = _env_min(tau, pk, s, w, True)
    except (np.linalg.LinAlgError, ValueError):
        return None
    dof = m - (_ENV_DRIFT + 3)
    if not (rss1 > 0 and math.isfinite(rss0)):
        return None
    s2 = rss1 / dof
    f = max(rss0 - rss1, 0.0) / s2
    rho = float(res[1:] @ res[:-1]) / float(res @ res)
    f /= (1.0 + max(rho, 0.0)) / (1.0 - min(max(rho, 0.0), 0.95))
    q = float(beta[_ENV_DRIFT + 1])
    tstat = math.copysign(math.sqrt(f), q)
    se_q = abs(q) / abs(tstat) if tstat != 0 else math.inf
    X = _env_design(tau, s, sg, True)
    amp = s * (pk - X[:, :_ENV_DRIFT] @ beta[:_ENV_DRIFT])
    if not amp[0] >= _ENV_RANGE * amp[-1] > 0:
        # over a narrow range a constant loss and an exponential are nearly one curve, and
        # any modulation of the envelope (a nearby mode's beating, a start-up transient)
        # reads as q
        return None
    return Envelope(n=m, sigma=float(sg), loss=q, loss_se=se_q, t=tstat,
                    threshold=t_isf(alpha / 2, dof), amp_first=float(amp[0]),
                    amp_last=float(amp[-1]))
