"""Free-decay estimators: σ and ω_d of the dominant mode of one recorded run.

A closed PD loop that rings like an underdamped oscillator (eqs. 31, 33) leaves, after the
release of the held mass and once the loop's fast non-dominant modes have died, the record

    x(t) = x_off + A e^{−σ(t−t_ref)} sin(ω_d (t−t_ref) − φ₀) + noise,          (eq. 15)

with the dominant root s = −σ + iω_d (σ > 0 when the oscillation decays, eq. 3). This module
turns one record (t, x) into σ, ω_d and a covariance a user can trust:

``fit_decay``
    the efficient estimator: nonlinear least squares on the whole window (maximum likelihood for
    white Gaussian noise) by variable projection. Its standard errors reach the Cramér–Rao bound
    of the single-mode model.
``logdec``
    the seed paper's logarithmic decrement, done carefully (all extrema, interpolated, weighted
    regression, honest covariance) for reproduction and comparison; far less efficient.
``detect_release``
    when the held mass is let go, from the data.

Both estimators return a :class:`DecayFit`. Estimates that the data cannot support (too few
cycles, growth, clipping, no oscillation, no convergence, misfit) are flagged by strings in
``DecayFit.warnings``; ValueError is raised only for unusable input.

A delayed loop (eq. 23) also has fast non-dominant roots; right after the release they leave a
transient that a single-mode fit must not see. ``fit_decay`` either skips it (``skip``) or fits
it with the roots given (``fast_roots``); see its Notes for the rule and the cost of each.
"""

from __future__ import annotations

import cmath
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from phoid import _validate as v
from phoid._threads import single_blas_thread

__all__ = ["DecayFit", "DecayStart", "detect_release", "fit_decay", "logdec", "start_decay"]

#: fewest samples a record (and a fitted window) must hold
MIN_SAMPLES = 16
#: cycles above the noise floor below which σ and ω_d are flagged as poorly supported
MIN_CYCLES = 3.0
#: release detection: the signal has left the held level when it is this many noise sds away
_RELEASE_NSD = 8.0
#: most Gauss–Newton iterations of one fit
_MAXIT = 50
#: a fitted mode weaker than this many noise sds (its norm over the window) is no oscillation
_MIN_MODE_SNR = 10.0
#: logdec: extrema whose amplitude is below this many noise sds end the peak sequence
_LOGDEC_FLOOR_NSD = 5.0


# --------------------------------------------------------------------------------------------
# result


@dataclass(frozen=True)
class DecayFit:
    """Dominant-mode estimate from one free-decay record.

    The fitted model is (eq. 15 with a sensor offset)

        x(t) = offset + amplitude · e^{−σ(t−t_ref)} sin(ω_d (t−t_ref) − phase).

    Attributes
    ----------
    sigma : float
        Decay rate σ, 1/s (eq. 3); positive when the oscillation decays. Root s = −σ + iω_d.
    omega_d : float
        Damped natural frequency ω_d, rad/s (eq. 4, underdamped form).
    cov : ndarray, shape (2, 2)
        Covariance of (sigma, omega_d), in (1/s)², (1/s)(rad/s), (rad/s)².
    amplitude : float
        Envelope A at ``t_ref``, m (eq. 15).
    phase : float
        φ₀ of eq. (15) with time measured from ``t_ref``, rad, in (−π, π].
    offset : float
        Constant sensor offset, m.
    t_ref : float
        Reference time of ``amplitude`` and ``phase``, s (the first fitted sample).
    t_start, t_end : float
        First and last sample times of the fitted window, s.
    release : float
        Detected (or given) release time, s.
    n_samples : int
        Number of samples in the fitted window.
    cycles : float
        Oscillation cycles in the window while the envelope is above the noise sd.
    noise_sd : float
        White-noise sd estimated from the residuals, m (√(RSS/(n − p)), p fitted parameters).
    residual_rms : float
        Root-mean-square residual of the fitted model over the window, m.
    method : str
        ``"mode-fit"`` (:func:`fit_decay`) or ``"logdec"`` (:func:`logdec`).
    warnings : tuple of str
    fast_modes : tuple of (complex, complex)
        The non-dominant modes fitted alongside (``fast_roots``): pairs (root r, 1/s; complex
        amplitude A, m), contributing Re(A e^{r(t − t_ref)}) for t ≥ t_ref.
        Reasons to distrust the estimate; empty when there are none.
    """

    sigma: float
    omega_d: float
    cov: np.ndarray = field(repr=False)
    amplitude: float
    phase: float
    offset: float
    t_ref: float
    t_start: float
    t_end: float
    release: float
    n_samples: int
    cycles: float
    noise_sd: float
    residual_rms: float
    method: str
    warnings: tuple[str, ...] = ()
    fast_modes: tuple[tuple[complex, complex], ...] = ()

    def __post_init__(self) -> None:
        cov = np.array(self.cov, dtype=float, copy=True).reshape(2, 2)
        cov.setflags(write=False)
        object.__setattr__(self, "cov", cov)
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def sigma_stderr(self) -> float:
        """Standard error of ``sigma``, 1/s."""
        return math.sqrt(max(self.cov[0, 0], 0.0))

    @property
    def omega_d_stderr(self) -> float:
        """Standard error of ``omega_d``, rad/s."""
        return math.sqrt(max(self.cov[1, 1], 0.0))

    @property
    def root(self) -> complex:
        """The dominant root s = −σ + iω_d, 1/s."""
        return complex(-self.sigma, self.omega_d)

    def model(self, t: np.ndarray | float, *, fast: bool = False) -> np.ndarray:
        """The fitted dominant mode x(t) = offset + A e^{−στ} sin(ω_d τ − φ₀), τ = t − t_ref.

        Parameters
        ----------
        t : array_like
            Times, s.
        fast : bool, default False
            Add the fitted non-dominant modes (:attr:`fast_modes`) for t ≥ t_ref: the whole
            fitted model, e.g. for residuals right after the release.

        Returns
        -------
        ndarray
            Model position, m (same shape as ``t``).
        """
        tau = np.asarray(t, dtype=float) - self.t_ref
        with np.errstate(over="ignore", invalid="ignore"):
            env = self.amplitude * np.exp(-self.sigma * tau)
            out = self.offset + env * np.sin(self.omega_d * tau - self.phase)
            if fast:
                after = np.maximum(tau, 0.0)
                for r, A in self.fast_modes:
                    out = out + np.where(tau >= 0, np.real(A * np.exp(r * after)), 0.0)
        return out

    def summary(self) -> dict:
        """Plain JSON-ready summary (floats, strings, lists; NaN becomes None)."""

        def num(v: float) -> float | None:
            v = float(v)
            return v if math.isfinite(v) else None

        return {
            "method": self.method,
            "sigma": num(self.sigma),
            "sigma_stderr": num(self.sigma_stderr),
            "omega_d": num(self.omega_d),
            "omega_d_stderr": num(self.omega_d_stderr),
            "cov": [[num(c) for c in row] for row in self.cov],
            "amplitude": num(self.amplitude),
            "phase": num(self.phase),
            "offset": num(self.offset),
            "t_ref": num(self.t_ref),
            "t_start": num(self.t_start),
            "t_end": num(self.t_end),
            "release": num(self.release),
            "n_samples": int(self.n_samples),
            "cycles": num(self.cycles),
            "noise_sd": num(self.noise_sd),
            "residual_rms": num(self.residual_rms),
            "warnings": list(self.warnings),
        }


# --------------------------------------------------------------------------------------------
# input checks and noise


def check_record(t, x) -> tuple[np.ndarray, np.ndarray]:
    t = v.finite_array("t", t, ndim=1)
    x = v.finite_array("x", x, ndim=1)
    if t.shape != x.shape:
        raise ValueError(f"`t` and `x` must have the same length; got {t.size} and {x.size}")
    if t.size < MIN_SAMPLES:
        raise ValueError(f"`x` must hold at least {MIN_SAMPLES} samples; got {t.size}")
    if not (t[1:] > t[:-1]).all():
        i = int(np.argmin(t[1:] > t[:-1]))
        raise ValueError(
            f"`t` must be strictly increasing; got t[{i}] = {t[i]:.9g} s, "
            f"t[{i + 1}] = {t[i + 1]:.9g} s"
        )
    if not x.max() > x.min():
        raise ValueError(f"`x` is constant ({x[0]:g} m): no motion to analyse")
    for name, a, unit in (("t", t, "s"), ("x", x, "m")):
        big = max(abs(float(a[0])), abs(float(a[-1])), float(np.abs(a).max()))
        if big > _MAX_MAGNITUDE:
            raise ValueError(f"`{name}` reaches {big:.3g} {unit}: beyond any record the fit "
                             f"can square without overflow (is it in {unit}?)")
    return t, x


# |t|, |x| beyond this overflow the fits' sums of squares (1e100² · samples ≪ 1.8e308) and are
# no position in m, or time in s, a rig records
_MAX_MAGNITUDE = 1e100


def _med(a: np.ndarray) -> float:
    """Median (the upper middle value for an even count): cheaper than np.median."""
    k = a.size // 2
    return float(np.partition(a, k)[k])


def diff_noise(x: np.ndarray) -> float:
    """Robust white-noise sd from second differences (MAD; var Δ²x = 6 sd² for white noise).

    A smooth signal sampled fast contributes ~A(ω dt)² per difference, negligible at ≥ ~20
    samples per period against noise of a few parts in 10⁴ of the amplitude.
    """
    if x.size < 3:
        return 0.0
    d1 = x[1:] - x[:-1]  # np.diff(x, 2), without its per-call overhead
    d2 = d1[1:] - d1[:-1]
    mad = _med(np.abs(d2 - _med(d2)))
    if mad > 0:
        return 1.4826 * mad / math.sqrt(6.0)
    # quantised or noise-free records: most differences are exactly 0
    return float(np.sqrt(np.mean(d2 * d2) / 6.0))


# --------------------------------------------------------------------------------------------
# release


def _hold_sd(x: np.ndarray, j: int) -> float | None:
    """sd of the held segment x[:j+1], if it has ≥ 10 samples and looks held (its sd is not
    above 1.5 times its second-difference noise: no motion)."""
    if j < 10:
        return None
    seg = x[: j + 1]
    d = seg - seg.sum() / seg.size  # np.std(seg, ddof=1), the same sums, fewer calls
    sd = math.sqrt(float(np.add.reduce(d * d)) / (seg.size - 1))
    return sd if sd <= 1.5 * diff_noise(seg) + 1e-300 else None


@dataclass(frozen=True)
class _Departure:
    """The release detection's first stage on one record: the held level (m), the threshold
    (m), the first sample ``i1`` from which the signal stays beyond it for 3 samples (None when
    there is none, or it is among the first 3), and the prefix length searched."""

    level: float
    thr: float
    i1: int | None
    m_search: int


def _departure(x: np.ndarray) -> _Departure:
    """The first sample from which x stays more than 8 noise sds from its held level for 3
    samples (a lone spike is no release), searched in growing prefixes."""
    n = x.size
    sd = diff_noise(x[:2048])
    n0 = max(3, min(20, n // 50))
    level = _med(x[:n0])
    thr = max(_RELEASE_NSD * sd, 1e-6 * (float(x.max()) - float(x.min())))
    m_search = 2048
    while True:
        out = np.abs(x[:m_search] - level) > thr
        hits = np.flatnonzero(out[:-2] & out[1:-1] & out[2:])
        if hits.size or m_search >= n:
            break
        m_search *= 4
    m_search = min(m_search, n)
    i1 = int(hits[0]) if hits.size else None
    return _Departure(level, thr, i1 if i1 is not None and i1 > 2 else None, m_search)


#: samples (records × padded length) per batch of :func:`_change_points`
_CHANGE_BATCH = 1 << 18


def _change_points(ts: Sequence[np.ndarray], xs: Sequence[np.ndarray], i1s: Sequence[int]
                   ) -> list[int]:
    """The quadratic change point of each record, up to its departure sample i1.

    x = L for t < τ, L + a (t − τ)² after (a held mass starts from rest, so the motion leaves
    the held level quadratically); least squares over τ at the samples ≤ i1, τ on the samples.
    For every candidate j the sums over i ≥ j come from reverse cumulative sums of u^p and
    y u^p (u = t − t[i1], p = 0..4), so all candidates cost O(i1). The records are stacked,
    right-aligned (every record's sample i1 in the last column, zeros before its first sample,
    which enter only the sums of masked candidates) and done together; the cumulative sums run
    sample by sample, so a record gives the same candidate, bit for bit, alone or in a batch.
    """
    out = [0] * len(ts)
    order = sorted(range(len(ts)), key=lambda i: i1s[i])
    groups: list[list[int]] = [[]]
    for i in order:
        if groups[-1] and (len(groups[-1]) + 1) * (i1s[i] + 1) > _CHANGE_BATCH:
            groups.append([])
        groups[-1].append(i)
    for grp in groups if order else []:
        ms = np.array([i1s[i] + 1 for i in grp])
        W = int(ms.max())
        R = len(grp)
        P = np.zeros((R, 9, W))  # u^0..u^4, y u^0..u^2, y² (suffix sums of each below)
        for r, i in enumerate(grp):
            m = int(ms[r])
            P[r, 1, W - m:] = ts[i][:m] - ts[i][m - 1]
            P[r, 5, W - m:] = xs[i][:m]
        P[:, 0] = 1.0
        u, y = P[:, 1], P[:, 5]
        np.multiply(u, u, out=P[:, 2])
        np.multiply(P[:, 2], u, out=P[:, 3])
        np.multiply(P[:, 2], P[:, 2], out=P[:, 4])
        np.multiply(P[:, 1:3], y[:, None], out=P[:, 6:8])
        np.multiply(y, y, out=P[:, 8])
        Sp = np.cumsum(P[:, :, ::-1], axis=2)[:, :, ::-1]
        first = (W - ms)[:, None]
        s_y = np.take_along_axis(Sp[:, 5], first, axis=1)  # Σ y, Σ y² over the whole record
        s_yy = np.take_along_axis(Sp[:, 8], first, axis=1)
        u2, u3, u4 = P[:, 2], P[:, 3], P[:, 4]
        # q_i = (u_i − u_j)², Σq and Σq² over i ≥ j, Σ y q over i ≥ j
        s_q = Sp[:, 2] - 2 * u * Sp[:, 1] + u2 * Sp[:, 0]
        s_qq = (Sp[:, 4] - 4 * u * Sp[:, 3] + 6 * u2 * Sp[:, 2] - 4 * u3 * Sp[:, 1]
                + u4 * Sp[:, 0])
        s_yq = Sp[:, 7] - 2 * u * Sp[:, 6] + u2 * Sp[:, 5]
        det = ms[:, None] * s_qq - s_q**2
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            L = (s_qq * s_y - s_q * s_yq) / det
            a = (ms[:, None] * s_yq - s_q * s_y) / det
            sse = s_yy - L * s_y - a * s_yq
        valid = np.arange(W)[None, :] >= first
        sse = np.where(valid & np.isfinite(sse) & (det > 0), sse, np.inf)
        # (a record none of whose candidates is finite gets 0, as alone: its padding is not
        # a candidate)
        j0 = np.where(np.isfinite(sse.min(axis=1)), np.argmin(sse, axis=1) - first[:, 0], 0)
        for r, i in enumerate(grp):
            out[i] = int(j0[r])
    return out


def _releases(ts: Sequence[np.ndarray], xs: Sequence[np.ndarray], refine: bool = True
              ) -> list[tuple[int, float | None]]:
    """:func:`locate_release` of many records, the change points of all of them in one batch."""
    deps = [_departure(x) for x in xs]
    live = [i for i, d in enumerate(deps) if d.i1 is not None]
    j0s = dict(zip(live, _change_points([ts[i] for i in live], [xs[i] for i in live],
                                        [deps[i].i1 for i in live]), strict=True))
    out: list[tuple[int, float | None]] = []
    for i, (t, x) in enumerate(zip(ts, xs, strict=True)):
        if i not in j0s:
            out.append((0, None))
            continue
        j = j0s[i] if not refine else _refine_release(t, x, deps[i], j0s[i])
        out.append((j, _hold_sd(x, j)))
    return out


def locate_release(t: np.ndarray, x: np.ndarray, refine: bool = True) -> tuple[int, float | None]:
    """Index of the release sample and the sd of the held segment (None if too short).

    The departure from the held level (:func:`_departure`), its quadratic change point before
    it (:func:`_change_points`) and, with ``refine``, a refinement with an even quartic
    (:func:`_refine_release`). ``refine=False`` stops after the change point (a few samples
    off, typically), for callers that refine the release with a model of their own."""
    return _releases([t], [x], refine)[0]


def _refine_release(t: np.ndarray, x: np.ndarray, dep: _Departure, j0: int) -> int:
    """The release refined on a longer stretch (until 4× the threshold) with x = L + a u² +
    b u⁴, u = (t − τ)₊ (the free response from rest is even in u), over candidates within 16
    samples of the change point ``j0``."""
    n = x.size
    level, thr, i1, m_search = dep.level, dep.thr, dep.i1, dep.m_search
    assert i1 is not None
    far = np.flatnonzero(np.abs(x[i1:m_search] - level) > 4 * thr)
    i2 = i1 + int(far[0]) if far.size else min(n - 1, 2 * i1)
    w = 16
    cand = np.arange(max(j0 - w, 0), min(j0 + w, i1) + 1)
    lo = max(int(cand[0]) - 4 * w, 0)
    tt = t[lo : i2 + 1]
    yy = x[lo : i2 + 1]
    U = np.maximum(tt[None, :] - t[cand][:, None], 0.0) / max(t[i2] - t[lo], 1e-300)
    y0 = yy - level
    # U², U⁴, U⁶, U⁸ and their sums
    Q = np.empty((4, *U.shape))
    np.multiply(U, U, out=Q[0])
    np.multiply(Q[0], Q[0], out=Q[1])
    np.multiply(Q[1], Q[0], out=Q[2])
    np.multiply(Q[1], Q[1], out=Q[3])
    s2, s4, s6, s8 = Q.sum(axis=2)
    AtA = np.empty((cand.size, 3, 3))
    AtA[:, 0, 0] = yy.size
    AtA[:, 0, 1] = AtA[:, 1, 0] = s2
    AtA[:, 0, 2] = AtA[:, 2, 0] = AtA[:, 1, 1] = s4
    AtA[:, 1, 2] = AtA[:, 2, 1] = s6
    AtA[:, 2, 2] = s8
    Aty = np.empty((cand.size, 3))
    Aty[:, 0] = y0.sum()
    Aty[:, 1] = Q[0] @ y0
    Aty[:, 2] = Q[1] @ y0
    try:
        coef = np.linalg.solve(AtA, Aty[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return j0
    sse2 = float(y0 @ y0) - (coef * Aty).sum(1)
    return int(cand[np.argmin(sse2)])


def detect_release(t, x) -> float:
    """Time at which the held mass is let go, s.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing.
    x : array_like, shape (n,)
        Position, m.

    Returns
    -------
    float
        Release time, s: the last sample at the held level; ``t[0]`` when the record holds no
        held segment.

    Raises
    ------
    ValueError
        For unusable input, as :func:`fit_decay`.

    Notes
    -----
    The record's white-noise sd is estimated robustly from second differences. The signal has
    left the held level (the median of the first samples) when it stays more than 8 sds away
    for 3 samples. The release is then refined backwards by least squares over the change point
    τ of x = L (t < τ), x = L + a(t − τ)² (t ≥ τ) up to that sample — the mass starts from
    rest, so it leaves the held level quadratically — and then of x = L + a u² + b u⁴,
    u = (t − τ)₊, up to 32 noise sds, over candidates within 16 samples. On records like the
    sample set (0.1 mm noise, 10 mm release, 1 kHz) the error has an sd of about 3 ms and no
    detectable mean; a held sample or two left in a fit, or a few lost, does not matter to it.
    """
    t, x = check_record(t, x)
    j, _ = locate_release(t, x)
    return float(t[j])


# --------------------------------------------------------------------------------------------
# the damped-mode basis and its least-squares evaluators
#
# Basis rows G = [1, C, S, τC, τS, F₁ … F_k] with C, S = e^{−στ}cos ω_dτ, e^{−στ}sin ω_dτ and
# F the optional fixed non-dominant mode columns. The model is x = x_off + aC + bS + Σ c_j F_j
# (linear parameters: rows 0, 1, 2, 5 …); ∂/∂σ = −(aτC + bτS), ∂/∂ω_d = bτC − aτS.


def uniform_step(tau: np.ndarray, origin: float = 0.0) -> float | None:
    """The sampling interval if ``tau`` is uniform, else None.

    Uniform: every τ within 10⁻⁹ of a step of the grid τ₀ + n·dt, or within the rounding of the
    absolute times τ + ``origin`` (64 ulp of the largest): at 1 MHz, time stamps near 10 s
    carry rounding of ~2·10⁻⁹ of a step, which a test against the step alone would take for
    non-uniform sampling."""
    n = tau.size
    dt = (tau[-1] - tau[0]) / (n - 1)
    g = np.arange(n, dtype=float)  # the grid τ₀ + n dt, then its deviation, in place
    g *= dt
    g += tau[0]
    g -= tau
    dev = max(float(g.max()), -float(g.min()))
    ulp = np.spacing(abs(origin) + max(abs(float(tau[0])), abs(float(tau[-1]))))
    return float(dt) if dev <= max(1e-9 * dt, 64.0 * ulp) else None


def _gram(G: np.ndarray) -> np.ndarray:
    """G Gᵀ by row dot products (faster than a skinny matrix product for 5 × n)."""
    k = G.shape[0]
    K = np.empty((k, k))
    for i in range(k):
        for j in range(i, k):
            K[i, j] = K[j, i] = G[i] @ G[j]
    return K


def _direct_basis(tau: np.ndarray, sig: float, om: float) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        z = np.exp(complex(-sig, om) * tau)
    G = np.empty((5, tau.size))
    G[0] = 1.0
    G[1] = z.real
    G[2] = z.imag
    np.multiply(tau, G[1], out=G[3])
    np.multiply(tau, G[2], out=G[4])
    return G


def _fast_columns(tau: np.ndarray, roots: np.ndarray, dt: float | None = None) -> np.ndarray:
    """e^{rτ} (real roots) or its real and imaginary parts (complex), over the samples where
    some column is above 10⁻¹⁶ of its start. With ``dt`` (uniform sampling, τ − τ₀ = n dt)
    the complex ones come from two short tables, e^{r dt (64 b + j)} = W_b F_j."""
    span = 37.0 / float(np.min(-roots.real))
    nf = int(np.searchsorted(tau, tau[0] + span, side="right"))
    tf = tau[:nf] - tau[0]
    cols = np.empty((roots.size + int(np.count_nonzero(roots.imag)), nf))
    i = 0
    for r in roots.tolist():
        if r.imag != 0:
            if dt is not None and nf > 256:
                ls = r * dt
                Ft = np.exp(ls * np.arange(64.0))
                Wt = np.exp((ls * 64) * np.arange(-(-nf // 64), dtype=float))
                e = np.multiply.outer(Wt, Ft).ravel()[:nf]
            else:
                e = np.exp(r * tf)
            cols[i] = e.real
            cols[i + 1] = e.imag
            i += 2
        else:
            np.exp(r.real * tf, out=cols[i])
            i += 1
    return cols


class _Point:
    """The linear part solved at one (σ, ω_d): ``K`` = G Gᵀ, ``Gx`` = G x, ``beta`` the linear
    parameters (x_off, a, b, c₁ … c_k), ``sse`` the residual sum of squares."""

    __slots__ = ("Gx", "K", "beta", "cache", "lin", "minv", "om", "sig", "sse")

    def gradient(self) -> np.ndarray:
        """G r for r = x − model (the linear rows vanish at the linear optimum)."""
        return self.Gx - self.K[:, self.lin] @ self.beta

    def normal(self, Gr: np.ndarray | None = None):
        """(JᵀJ)⁻¹ and Jᵀr for the parameters (linear …, σ, ω_d), J = T G.

        (JᵀJ)⁻¹ depends on the point only: it is kept, and a second call (the exact gradient
        after the tabulated one) only rotates the new G r."""
        a, b = float(self.beta[1]), float(self.beta[2])
        K = self.K
        m = K.shape[0]
        G = self.gradient() if Gr is None else Gr
        if self.minv is not None:
            if m == 5:
                g = G.copy()
            else:
                g = G[_lin_index(m - 5)[2]]
            g3, g4 = float(g[-2]), float(g[-1])
            g[-2] = -a * g3 - b * g4
            g[-1] = b * g3 - a * g4
            return self.minv, g
        # T = [[I_lin, 0], [0, R]] after ordering the rows (linear …, 3, 4), R = [[−a, −b],
        # [b, −a]]: M = T K Tᵀ and T G r with the rotation applied to the last two rows/columns
        if m == 5:
            Minv, g = _normal5(K, G, a, b)
            self.minv = Minv
            return Minv, g
        else:
            _, _, perm, pix = _lin_index(m - 5)
            M = K[pix]
            g = G[perm]
        i, j = m - 2, m - 1
        ci, cj = M[:, i].copy(), M[:, j].copy()
        c3 = -a * ci - b * cj
        c4 = b * ci - a * cj
        M[:, i] = c3
        M[:, j] = c4
        M[i, :] = c3
        M[j, :] = c4
        k33, k34, k44 = float(ci[i]), float(ci[j]), float(cj[j])
        M[i, i] = a * a * k33 + 2 * a * b * k34 + b * b * k44
        M[j, j] = b * b * k33 - 2 * a * b * k34 + a * a * k44
        M[i, j] = M[j, i] = a * b * (k44 - k33) + (a * a - b * b) * k34
        g3, g4 = float(g[i]), float(g[j])
        g[i] = -a * g3 - b * g4
        g[j] = b * g3 - a * g4
        d = np.sqrt(np.diagonal(M))
        if not (d > 0).all():
            return None, g
        dd = np.multiply.outer(d, d)
        try:
            Minv = np.linalg.inv(M / dd) / dd
        except np.linalg.LinAlgError:
            return None, g
        self.minv = Minv
        return Minv, g


@functools.lru_cache(maxsize=16)
def _lin_index(k: int):
    """For k fast columns: the linear parameters' rows ``lin`` (0, 1, 2, 5 … 4 + k), the
    index of their block of K, and the row order (lin …, 3, 4) with its block index."""
    lin = np.array([0, 1, 2, *range(5, 5 + k)])
    perm = np.array([*lin.tolist(), 3, 4])
    for a in (lin, perm):
        a.setflags(write=False)
    return lin, np.ix_(lin, lin), perm, np.ix_(perm, perm)


def _normal5(K: np.ndarray, G: np.ndarray, a: float, b: float):
    """:meth:`_Point.normal` for the 5 parameters (x_off, a, b, σ, ω_d), in scalars."""
    k0, k1, k2, k3, k4 = K.tolist()
    g0, g1, g2, g3, g4 = G.tolist()
    # rows/columns 3, 4 rotated by R = [[−a, −b], [b, −a]]
    c3 = [-a * k0[3] - b * k0[4], -a * k1[3] - b * k1[4], -a * k2[3] - b * k2[4]]
    c4 = [b * k0[3] - a * k0[4], b * k1[3] - a * k1[4], b * k2[3] - a * k2[4]]
    k33, k34, k44 = k3[3], k3[4], k4[4]
    m33 = a * a * k33 + 2 * a * b * k34 + b * b * k44
    m44 = b * b * k33 - 2 * a * b * k34 + a * a * k44
    m34 = a * b * (k44 - k33) + (a * a - b * b) * k34
    M = np.array(
        [
            [k0[0], k0[1], k0[2], c3[0], c4[0]],
            [k1[0], k1[1], k1[2], c3[1], c4[1]],
            [k2[0], k2[1], k2[2], c3[2], c4[2]],
            [c3[0], c3[1], c3[2], m33, m34],
            [c4[0], c4[1], c4[2], m34, m44],
        ]
    )
    g = np.array([g0, g1, g2, -a * g3 - b * g4, b * g3 - a * g4])
    diag = (k0[0], k1[1], k2[2], m33, m44)
    if not all(v > 0 for v in diag):  # also False for NaN
        return None, g
    d = np.sqrt(diag)
    dd = np.multiply.outer(d, d)
    try:
        Minv = np.linalg.inv(M / dd) / dd
    except np.linalg.LinAlgError:
        return None, g
    return Minv, g


def _solve3(k: list, y: list) -> np.ndarray | None:
    """Solution of the symmetric 3 × 3 system k β = y, equilibrated to a unit diagonal, by
    Gaussian elimination with partial pivoting; None if a diagonal entry is not positive or a
    pivot vanishes (singular)."""
    d0, d1, d2 = k[0][0], k[1][1], k[2][2]
    if not (d0 > 0 and d1 > 0 and d2 > 0):
        return None
    d = (math.sqrt(d0), math.sqrt(d1), math.sqrt(d2))
    A = [[k[i][j] / (d[i] * d[j]) for j in range(3)] + [y[i] / d[i]] for i in range(3)]
    for c in range(3):
        piv = max(range(c, 3), key=lambda i: abs(A[i][c]))
        if A[piv][c] == 0.0:
            return None
        if piv != c:
            A[c], A[piv] = A[piv], A[c]
        rc = A[c]
        for i in range(c + 1, 3):
            f = A[i][c] / rc[c]
            if f != 0.0:
                ri = A[i]
                for j in range(c, 4):
                    ri[j] -= f * rc[j]
    x2 = A[2][3] / A[2][2]
    x1 = (A[1][3] - A[1][2] * x2) / A[1][1]
    x0 = (A[0][3] - A[0][1] * x1 - A[0][2] * x2) / A[0][0]
    return np.array([x0 / d[0], x1 / d[1], x2 / d[2]])


class _Evaluator:
    """Solves the linear part at any (σ, ω_d); subclasses supply the 5 × 5 base sums."""

    def __init__(self, tau: np.ndarray, x: np.ndarray, fast: np.ndarray, dt=None):
        self.tau, self.x = tau, x
        self.xx = float(x @ x)
        # rounding of the RSS expansion xᵀx − βᵀGx, allowed for when comparing steps
        self.floor = 1e-13 * self.xx + 1e-300
        self.F = _fast_columns(tau, fast, dt) if fast.size else np.zeros((0, 0))
        k = self.F.shape[0]
        self.nf = self.F.shape[1] if k else 0
        self.lin, self.lin_ix = _lin_index(k)[:2]
        if k:
            self.FF = _gram(self.F)
            self.Fx = self.F @ x[: self.nf]
            # cross sums with the damped mode: Σ F, and (F; τF) · e^{sτ} in one product
            self.tf = tau[: self.nf] - tau[0]
            self.Fsum = self.F.sum(axis=1)
            self.FT = np.vstack([self.F, self.F * self.tf])

    def _head(self, sig, om):
        """e^{s(τ − τ₀)} over the fast columns' span (after ``_base`` at the same point)."""
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            return np.exp(complex(-sig, om) * self.tf)

    def _base(self, sig, om):  # pragma: no cover - abstract
        raise NotImplementedError

    def _model_base(self, sig, om):  # pragma: no cover - abstract
        raise NotImplementedError

    def __call__(self, sig: float, om: float) -> _Point | None:
        K5, Gx5 = self._base(sig, om)
        if self.nf:
            # K = [[K5, X], [Xᵀ, FF]], X = G F ᵀ over the span: rows 1, C, S, τC, τS
            k = self.F.shape[0]
            zh = self._head(sig, om)
            with np.errstate(over="ignore", invalid="ignore"):  # an overflowing start: None below
                P = self.FT @ zh.view(float).reshape(-1, 2)
            K = np.empty((5 + k, 5 + k))
            K[:5, :5] = K5
            X = K[:5, 5:]
            X[0] = self.Fsum
            X[1] = P[:k, 0]
            X[2] = P[:k, 1]
            X[3] = P[k:, 0]
            X[4] = P[k:, 1]
            K[5:, :5] = X.T
            K[5:, 5:] = self.FF
            Gx = np.concatenate((Gx5, self.Fx))
        else:
            K, Gx = K5, Gx5
        lin = self.lin
        if not (np.isfinite(K).all() and np.isfinite(Gx).all()):
            return None
        if self.nf:
            Kl, Gl = K[self.lin_ix], Gx[lin]
            d = np.sqrt(np.diagonal(Kl))
            if not (d > 0).all():
                return None
            try:
                beta = np.linalg.solve(Kl / np.multiply.outer(d, d), Gl / d) / d
            except np.linalg.LinAlgError:
                return None
        else:  # lin = 0, 1, 2
            Gl = Gx[:3]
            beta = _solve3(K[:3, :3].tolist(), Gl.tolist())
            if beta is None:
                return None
        p = _Point()
        p.sig, p.om, p.K, p.Gx, p.beta, p.lin = sig, om, K, Gx, beta, lin
        p.cache = self._cache
        p.minv = None
        # at the linear optimum RSS = xᵀx − βᵀ(Gx)_lin; recomputed from residuals at the end
        p.sse = max(self.xx - float(beta @ Gl), 0.0)
        return p

    #: per-point data a subclass's ``_base`` leaves for ``_model_base`` at the same point
    _cache = None

    def residual(self, p: _Point) -> tuple[np.ndarray, np.ndarray]:
        """Residual r (sample by sample, no cancellation) and G r."""
        self._cache = p.cache
        C, S = self._model_base(p.sig, p.om)
        r = self.x - (p.beta[0] + p.beta[1] * C + p.beta[2] * S)
        if self.nf:
            r[: self.nf] -= p.beta[3:] @ self.F
        Gr5 = self._project(r, p.sig, p.om, C, S)
        Gr = np.r_[Gr5, self.F @ r[: self.nf]] if self.nf else Gr5
        return r, Gr

    def model(self, p: _Point) -> np.ndarray:
        """The fitted dominant mode plus offset (no fast modes)."""
        self._cache = p.cache
        C, S = self._model_base(p.sig, p.om)
        return p.beta[0] + p.beta[1] * C + p.beta[2] * S


class _Direct(_Evaluator):
    """Any sampling: the basis is formed sample by sample."""

    def _base(self, sig, om):
        G = _direct_basis(self.tau, sig, om)
        return _gram(G), G @ self.x

    def _model_base(self, sig, om):
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            z = np.exp(complex(-sig, om) * self.tau)
        return z.real, z.imag

    def _project(self, r, sig, om, C, S):
        tr = self.tau * r
        return np.array([r.sum(), C @ r, S @ r, C @ tr, S @ tr])


@functools.lru_cache(maxsize=32)
def _table_constants(B: int, nb: int, dt: float):
    """Per-shape constants of :class:`_Table` (cached: every record of a set shares them)."""
    # j^p and b^p, p = 0, 1, 2, from one table of the larger range
    m = max(B, nb)
    pw = np.empty((m, 3))
    pw[:, 0] = 1.0
    pw[:, 1] = np.arange(m, dtype=float)
    np.multiply(pw[:, 1], pw[:, 1], out=pw[:, 2])
    jpow, bpow = pw[:B], pw[:nb]
    j, b = jpow[:, 1], bpow[:, 1]
    # exponents of one table [F_j; W_b] = e^{s dt [j; B b]} and its power sums in one
    # product: Pw is block diagonal (j^p on the first B rows, b^p on the next nb)
    jb = np.concatenate((j, B * b))
    Pw = np.zeros((B + nb, 6), complex)
    Pw[:B, :3] = jpow
    Pw[B:, 3:] = bpow
    # Σ_n n^p w^n = Σ_{p_b, p_j} c · (Σ_b b^{p_b} W_b)(Σ_j j^{p_j} F_j), n = bB + j
    Cm = np.zeros((3, 3, 3))
    Cm[0, 0, 0] = 1.0
    Cm[1, 0, 1], Cm[0, 1, 1] = B, 1.0
    Cm[2, 0, 2], Cm[1, 1, 2], Cm[0, 2, 2] = B * B, 2.0 * B, 1.0
    Cm = Cm.reshape(9, 3).astype(complex)
    bB = float((nb - 1) * B)
    Cpad = np.array([[1.0, bB, bB * bB], [0.0, 1.0, 2.0 * bB], [0.0, 0.0, 1.0]], complex)
    # K (flattened 5 × 5) as a linear map of the moments' real and imaginary parts,
    # index 6p + 2t + c for moment p of table t (w = e^{s dt}, e^{2s dt}, e^{−2σ dt}), part c
    A = np.zeros((25, 18))

    def put(i, k, terms):
        for coef, p_, t_, c_ in terms:
            A[5 * i + k, 6 * p_ + 2 * t_ + c_] = coef
            A[5 * k + i, 6 * p_ + 2 * t_ + c_] = coef

    h, h1, h2 = 0.5, 0.5 * dt, 0.5 * dt * dt
    put(0, 1, [(1.0, 0, 0, 0)])
    put(0, 2, [(1.0, 0, 0, 1)])
    put(0, 3, [(dt, 1, 0, 0)])
    put(0, 4, [(dt, 1, 0, 1)])
    put(1, 1, [(h, 0, 2, 0), (h, 0, 1, 0)])
    put(1, 2, [(h, 0, 1, 1)])
    put(1, 3, [(h1, 1, 2, 0), (h1, 1, 1, 0)])
    put(1, 4, [(h1, 1, 1, 1)])
    put(2, 2, [(h, 0, 2, 0), (-h, 0, 1, 0)])
    put(2, 3, [(h1, 1, 1, 1)])
    put(2, 4, [(h1, 1, 2, 0), (-h1, 1, 1, 0)])
    put(3, 3, [(h2, 2, 2, 0), (h2, 2, 1, 0)])
    put(3, 4, [(h2, 2, 1, 1)])
    put(4, 4, [(h2, 2, 2, 0), (-h2, 2, 1, 0)])
    out = (jpow, bpow, j, b, jb, Pw, Cm, Cpad, A)
    for arr in out:
        arr.setflags(write=False)
    return out


class _Table(_Evaluator):
    """Uniform sampling τ_n = n·dt: every sum over n of n^p e^{sτ_n} (p ≤ 2) and of
    y_n n^p e^{sτ_n} (p ≤ 1) factorises over n = bB + j into √n-sized exponential tables, so
    one (σ, ω_d) costs one pass over x and no transcendental function per sample."""

    def __init__(self, tau: np.ndarray, x: np.ndarray, fast: np.ndarray, dt: float):
        super().__init__(tau, x, fast, dt)
        n = x.size
        B = int(min(512, max(16, 2 ** round(math.log2(math.sqrt(n))))))
        nb = -(-n // B)
        self.n, self.B, self.nb, self.dt = n, B, nb, dt
        self.X = self._blocked(x)
        consts = _table_constants(B, nb, float(dt))
        self.jpow, self.bpow, self.j, self.b, self.jb = consts[:5]
        self.Pw, self.Cm, self.Cpad, self.Amap = consts[5:]
        self.j0 = n - (nb - 1) * B  # first padding index of the last block
        self.sx = float(x.sum())

    def _blocked(self, y):
        Y = np.zeros(self.nb * self.B)
        Y[: self.n] = y
        return Y.reshape(self.nb, self.B)

    def _tables(self, sig, om):
        c = self._cache
        if c is not None and c[0] == sig and c[1] == om:
            return c[2], c[3]
        ls = complex(-sig, om) * self.dt
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            return np.exp(ls * self.j), np.exp((ls * self.B) * self.b)

    def _data(self, X, F, W):
        """Σ_n y_n w^n and Σ_n n y_n w^n for blocked data X (zero-padded), w^n = W_b F_j."""
        Fm = np.empty((self.B, 2), complex)
        Fm[:, 0] = F
        np.multiply(self.j, F, out=Fm[:, 1])
        # columns Re F, Im F, Re jF, Im jF; the product back as complex (P0, P1)
        P = (X @ Fm.view(float)).view(complex)
        P0 = P[:, 0]
        return W @ P0, self.B * ((self.b * W) @ P0) + W @ P[:, 1]

    def _base(self, sig, om):
        """K from the moments Σ n^p w^n (p ≤ 2) of w = e^{s dt}, e^{2s dt} and e^{−2σ dt}:
        C² = (|z|² + Re z²)/2, S² = (|z|² − Re z²)/2, CS = Im z²/2 for z = e^{sτ}.

        The tables of e^{2s dt} and e^{−2σ dt} are those of e^{s dt} squared; the zero padding
        of the last block is taken off with that block's partial sums."""
        B = self.B
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            e = np.exp(complex(-sig * self.dt, om * self.dt) * self.jb)
            T = np.empty((3, e.size), complex)
            T[0] = e
            np.multiply(e, e, out=T[1])
            T[2] = e.real * e.real + e.imag * e.imag
            S = T @ self.Pw  # (table, [Σ j^p F_j, Σ b^p W_b])
            # moments m[t, p] = Σ_n n^p w_t^n over the padded blocks
            WF = S[:, 3:, None] * S[:, None, :3]
            m = WF.reshape(3, 9) @ self.Cm
            if self.j0 < B:
                # padding n = (nb − 1)B + j, j ≥ j0: the last block's partial sums
                Ps = T[:, self.j0 : B] @ self.Pw[self.j0 : B, :3]
                m -= T[:, -1:] * (Ps @ self.Cpad)
            K = (self.Amap @ m.T.copy().view(float).ravel()).reshape(5, 5)
            K[0, 0] = self.n
            F, W = e[:B], e[B:]
            s0, s1 = self._data(self.X, F, W)
        self._cache = (sig, om, F, W)
        dt = self.dt
        Gx = np.array([self.sx, s0.real, s0.imag, s1.real * dt, s1.imag * dt])
        return K, Gx

    def _model_base(self, sig, om):
        F, W = self._tables(sig, om)
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            z = np.multiply.outer(W, F).ravel()[: self.n]
        return z.real, z.imag

    def residual(self, p: _Point) -> tuple[np.ndarray, np.ndarray]:
        """Residual r (sample by sample, no cancellation) and G r, formed in blocks:
        a C + b S = Re((a − ib) z), z_{bB+j} = W_b F_j."""
        self._cache = p.cache
        F, W = self._tables(p.sig, p.om)
        beta = p.beta
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            mode = np.multiply.outer(W * complex(beta[1], -beta[2]), F)
        R = self.X - mode.real
        R -= beta[0]
        flat = R.reshape(-1)
        flat[self.n :] = 0.0  # the padding stays out of every sum
        r = flat[: self.n]
        if self.nf:
            r[: self.nf] -= beta[3:] @ self.F
        s0, s1 = self._data(R, F, W)
        Gr5 = np.array([r.sum(), s0.real, s0.imag, s1.real * self.dt, s1.imag * self.dt])
        Gr = np.concatenate((Gr5, self.F @ r[: self.nf])) if self.nf else Gr5
        return r, Gr

    def _head(self, sig, om):
        F, W = self._tables(sig, om)
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            return np.multiply.outer(W[: -(-self.nf // self.B)], F).ravel()[: self.nf]

    def _project(self, r, sig, om, C, S):
        F, W = self._tables(sig, om)
        s0, s1 = self._data(self._blocked(r), F, W)
        return np.array([r.sum(), s0.real, s0.imag, s1.real * self.dt, s1.imag * self.dt])


def _evaluator(tau, x, udt, fast=None):
    """The tabulated evaluator for uniform sampling of ≥ 64 samples, else the direct one."""
    fast = np.zeros(0, complex) if fast is None else fast
    if udt is not None and x.size >= 64:
        return _Table(tau, x, fast, udt)
    return _Direct(tau, x, fast)


def _gauss_newton(ev, sig, om, *, maxit=None, rtol_se=0.05):
    """Variable-projection Gauss–Newton (Kaufman's step from the full Jacobian) for (σ, ω_d).

    Returns (point, converged, iterations), or None if the start is unusable. Converged when
    the proposed step is below ``rtol_se`` standard errors, or below 10⁻¹⁰ of |σ| + ω_d
    (noise-free data, where the tabulated gradient's rounding sets the floor; the last steps
    are left to :func:`_polish`). A step that would raise the RSS (beyond rounding) is
    halved."""
    maxit = _MAXIT if maxit is None else maxit
    p = ev(sig, om)
    if p is None:
        return None
    dof = max(ev.x.size - ev.lin.size - 2, 1)
    for it in range(maxit + 1):
        Minv, g = p.normal()
        if Minv is None:
            return p, False, it
        step = (Minv[-2:] @ g).tolist()
        v = p.sse / dof
        se0 = math.sqrt(max(float(Minv[-2, -2]) * v, 0.0))
        se1 = math.sqrt(max(float(Minv[-1, -1]) * v, 0.0))
        scale = abs(p.sig) + abs(p.om)
        if abs(step[0]) <= max(rtol_se * se0, 1e-10 * scale) and abs(step[1]) <= max(
            rtol_se * se1, 1e-10 * scale
        ):
            return p, True, it
        if it == maxit:
            break
        lam = 1.0
        new = None
        while lam >= 2.0**-12:
            cand = ev(p.sig + lam * step[0], abs(p.om + lam * step[1]))
            if cand is not None and cand.sse <= p.sse + ev.floor:
                new = cand
                break
            lam *= 0.5
        if new is None:
            # no descent: at the rounding floor if the step is tiny, else stuck
            return p, abs(step[0]) <= 1e-6 * scale and abs(step[1]) <= 1e-6 * scale, it
        p = new
    return p, False, maxit


# --------------------------------------------------------------------------------------------
# starting guess


def _dominant_period(xg: np.ndarray) -> float:
    """Period, in samples, of the spectral peak of a uniformly sampled record (≤ its length).

    The first 4096 samples are used (where a decay is largest) unless the peak they give lies
    in the lowest bins, then the whole record."""
    for seg in (xg[:4096], xg):
        n = seg.size
        nfft = 1 << math.ceil(math.log2(n))
        spec = np.abs(np.fft.rfft(seg - seg.mean(), nfft))
        k = int(np.argmax(spec[1:])) + 1
        if k > 2 or n == xg.size:
            break
    return min(nfft / k, float(xg.size))


def _dominant_periods(xgs: Sequence[np.ndarray]) -> list[float]:
    """:func:`_dominant_period` of many records, the spectra of their first 4096 samples in
    one FFT (the same transform per row, so the same periods bit for bit)."""
    out: list[float | None] = [None] * len(xgs)
    rows = [i for i, xg in enumerate(xgs) if xg.size >= 4096]
    if len(rows) > 1:
        S = np.stack([xgs[i][:4096] for i in rows])
        S -= S.mean(axis=1, keepdims=True)
        k = np.argmax(np.abs(np.fft.rfft(S, 4096, axis=1))[:, 1:], axis=1) + 1
        for i, kk in zip(rows, k.tolist(), strict=True):
            if kk > 2 or xgs[i].size == 4096:
                out[i] = min(4096 / kk, float(xgs[i].size))
    return [_dominant_period(xg) if p is None else p for xg, p in zip(xgs, out, strict=True)]


def _uniform(
    tau: np.ndarray, x: np.ndarray, origin: float = 0.0
) -> tuple[np.ndarray, float, float | None]:
    """x on a uniform grid from tau[0] (linear interpolation if the sampling is not uniform),
    its step, and the step if the sampling was uniform already (else None)."""
    n = tau.size
    dt = (tau[-1] - tau[0]) / (n - 1)
    udt = uniform_step(tau, origin) if n >= 64 else None
    if udt is not None:
        return x, dt, udt
    tg = tau[0] + dt * np.arange(n)
    return np.interp(tg, tau, x), dt, None


def _blocks(xg: np.ndarray, q: int) -> np.ndarray:
    """Means of consecutive blocks of q samples (a moving average sampled every q: every
    exponential mode e^{st} passes with only a complex gain, so σ and ω_d are untouched)."""
    m = xg.size // q
    return xg[: m * q].reshape(m, q).mean(axis=1) if q > 1 else xg


def esprit(y: np.ndarray, dt: float, order: int = 3) -> tuple[np.ndarray, np.ndarray | None]:
    """Roots s (1/s) of a sum of ``order`` damped exponentials fitted to y (ESPRIT), and their
    energies Σ|c zⁿ|² (None when there is exactly one complex pair: nothing to choose)."""
    _L, HH = _esprit_gram(y, order)
    w, U = np.linalg.eigh(HH)
    return _esprit_roots(y, dt, U[:, np.argsort(w)[::-1][:order]])


def _esprit_gram(y: np.ndarray, order: int) -> tuple[int, np.ndarray]:
    """ESPRIT's Hankel order L and the L × L Gram matrix H Hᵀ of y's Hankel matrix."""
    n = y.size
    L = max(order + 1, min(n // 3, 20))
    K = n - L + 1
    H = y[np.add.outer(np.arange(L), np.arange(K))]  # Hankel matrix, L × K
    return L, H @ H.T


def _esprit_phi(Us: np.ndarray) -> np.ndarray:
    """The shift-invariance solution Φ of Us[:-1] Φ = Us[1:] (least squares)."""
    # with orthonormal columns Us[:-1]ᵀUs[:-1] = I − vvᵀ (v the last row), well conditioned
    # unless |v| ≈ 1; normal equations then, else lstsq
    v = Us[-1]
    if float(v @ v) < 0.5:
        A = Us[:-1]
        return np.linalg.solve(A.T @ A, A.T @ Us[1:])
    return np.linalg.lstsq(Us[:-1], Us[1:], rcond=None)[0]


def _esprit_roots(y: np.ndarray, dt: float, Us: np.ndarray, z: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`esprit` from the signal subspace ``Us`` (L × order) on, or from Φ's
    eigenvalues ``z`` when they are given."""
    order = Us.shape[1]
    if z is None:
        z = np.linalg.eigvals(_esprit_phi(Us)).astype(complex)
    n = y.size
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        s = np.log(z) / dt
        if np.count_nonzero(s.imag > 0) == 1:
            return s, None
        energy = np.zeros(order)
        V = np.exp(np.multiply.outer(np.arange(n), np.log(z)))
        ok = np.all(np.isfinite(V), axis=0) & np.isfinite(s)
        if np.any(ok):
            c = np.linalg.lstsq(V[:, ok], y.astype(complex), rcond=None)[0]
            energy[ok] = np.abs(c) ** 2 * np.sum(np.abs(V[:, ok]) ** 2, axis=0)
    return s, energy


def _initial_guess(xg: np.ndarray, dt: float, per: float, noise: float):
    """Start (σ, ω_d), whether a complex dominant pair was found, active length (samples).

    The part of the window above the noise (period blocks whose sd exceeds 3 noise sds), at most
    40 periods of it, block-averaged to ~16 samples a period; ESPRIT of order 3 (offset and one
    complex pair); the complex root of largest energy.
    """
    y, q, n_act = _guess_input(xg, per, noise)
    s, energy = esprit(y, q * dt, order=3)
    return _guess_pick(s, energy, q, dt, xg.size, n_act)


def _guess_input(xg: np.ndarray, per: float, noise: float) -> tuple[np.ndarray, int, int]:
    """:func:`_initial_guess`'s ESPRIT input: the block means y, their block length q and the
    active length (samples)."""
    n = xg.size
    lb = int(min(max(round(per), 4), max(n // 8, 4)))
    nb = n // lb
    if nb >= 2:
        xb = xg[: nb * lb].reshape(nb, lb)
        bvar = (xb * xb).mean(axis=1) - xb.mean(axis=1) ** 2
        above = np.flatnonzero(bvar > 9.0 * noise * noise)
        n_act = (int(above[-1]) + 1) * lb if above.size else lb
    else:
        n_act = n
    n_act = min(max(n_act, 4 * lb), n)
    n_seg = max(min(n_act, int(40 * per)), min(n, 64))
    q = max(1, int(per // 16), n_seg // 1024)
    while n_seg // q < 16 and q > 1:
        q //= 2
    return _blocks(xg[:n_seg], q), q, n_act


def _guess_pick(s: np.ndarray, energy: np.ndarray | None, q: int, dt: float, n: int,
                n_act: int):
    """:func:`_initial_guess`'s choice among the ESPRIT roots ``s`` (of block means of q
    samples, step dt, n samples in the window)."""
    if energy is None:
        energy = np.ones(s.size)
    nyq = math.pi / (q * dt)
    cand = np.flatnonzero((s.imag > 1e-6 * nyq) & (s.imag < 0.9 * nyq) & (energy > 0))
    if cand.size:
        i = cand[np.argmax(energy[cand])]
        return float(-s[i].real), float(s[i].imag), True, n_act
    # no complex pair: the dominant motion is not oscillatory; start from the real root of
    # largest energy that is not the offset, and half a cycle over the window
    T = n * dt
    real = np.flatnonzero((np.abs(s.imag) <= 1e-6 * nyq) & (np.abs(s.real) > 1.0 / T))
    sig = float(-s[real[np.argmax(energy[real])]].real) if real.size else 1.0 / T
    return sig, math.pi / T, False, n_act


def _staged(xg: np.ndarray, dt: float, per: float, sig: float, om: float) -> tuple[float, float]:
    """Refine a start (σ, ω_d) made from 40 periods of a barely damped record with many more:
    fit block means (~32 a period) of windows growing fourfold, each from the last."""
    q = max(1, int(per // 32))
    yb = _blocks(xg, q)
    tb = dt * (q * np.arange(yb.size) + 0.5 * (q - 1))
    lim = 40 * per * dt
    while True:
        m = int(np.searchsorted(tb, lim, side="right"))
        if m >= MIN_SAMPLES:
            r = _gauss_newton(_evaluator(tb[:m], yb[:m], dt * q), sig, om)
            if r is not None:
                sig, om = r[0].sig, r[0].om
        if lim >= tb[-1]:
            break
        lim = min(4.0 * lim, tb[-1])
    return sig, om


@dataclass(frozen=True)
class DecayStart:
    """What :func:`start_decay` learns from a record cheaply: enough to plan a full fit.

    Attributes
    ----------
    sigma, omega_d : float
        Estimate of the dominant mode (1/s, rad/s): the Gauss–Newton optimum of
        :func:`fit_decay` (or only its ESPRIT start, see :func:`start_decay`).
    oscillating : bool
        Whether a complex dominant pair was found and, with ``refine``, the fit converged on it
        (else σ, ω_d are no more than a bland start).
    release : float
        Release time, s (detected, as in :func:`detect_release`).
    offset : float
        Median of the window, m (a rough level for amplitude scales).
    noise_sd : float
        Noise sd, m: of the held segment, else from second differences of the tail.
    t_start, t_end : float
        The window, s.
    """

    sigma: float
    omega_d: float
    oscillating: bool
    release: float
    offset: float
    noise_sd: float
    t_start: float
    t_end: float


#: Gauss–Newton stops in :func:`start_decay` when its next step is below this many standard
#: errors: a start only has to be within about one of the optimum (the full fit that follows
#: converges to 0.05 from there), and at this tolerance an ESPRIT start close enough already is
#: accepted without a second evaluation.
_START_RTOL_SE = 0.5
#: ``start_decay(refine="auto")``: an ESPRIT start with |σ| above this fraction of ω_d is
#: refined (and confirmed) by Gauss–Newton
_START_MAX_DAMPING = 0.25


def start_decay(
    t, x, *, release=None, skip=0.0, refine: bool | str = True, coarse_release=False
) -> DecayStart:
    """The first stages of :func:`fit_decay`: release, noise, window, start and Gauss–Newton.

    What is left out is what a full fit adds for reporting: the exact residual, covariance and
    warnings. :func:`fit_decay` with ``guess=(start.sigma, start.omega_d)`` and
    ``release=start.release`` continues from it. With ``refine=False`` only the ESPRIT start
    is made (within about one standard error of the optimum on the seed paper's sweep, but
    lost on records where a slow non-dominant real mode is strong). ``refine="auto"`` runs
    Gauss–Newton only where the ESPRIT start is in doubt: where its frequency disagrees with
    the record's spectral peak (by more than a quarter, and more than 1.5 bins of the FFT), or
    where it is a heavily damped pair (|σ| > 0.25 ω_d, ζ ≳ 0.24, where a ringing PHO run has
    ζ ≲ 0.2) — which is how a start goes wrong on such records: on tests/test_identify.py's
    slow-root run ESPRIT gives σ = 1.0 1/s, ω_d = 1.3 rad/s for the true 1.0 ± 15.0i, and the
    Gauss–Newton that then runs finds no convergence, so the run is marked not oscillating
    and started from the rough loop's root. A clean start costs no evaluation of the model.
    ``coarse_release=True``
    detects the release by its first stage only (the quadratic change point; the refinement
    with an even quartic is left out), for callers that refine it with a model of their own.
    Raises ValueError as :func:`fit_decay` does for unusable input.
    """
    pre = _start_prepare(t, x, release=release, skip=skip, coarse_release=coarse_release)
    s, energy = esprit(pre.y, pre.q * pre.dt, order=3)
    return _start_finish(pre, s, energy, refine)


@dataclass(frozen=True)
class _StartGrid:
    """:func:`_start_grid`'s window: release (s), t and x, τ = t − t[0] (s), noise (m), x on
    a uniform grid, its step (s) and the step if the sampling was uniform (else None)."""

    release: float
    tw: np.ndarray
    xw: np.ndarray
    tau: np.ndarray
    noise: float
    xg: np.ndarray
    dt: float
    udt: float | None


@dataclass(frozen=True)
class _StartInput(_StartGrid):
    """What :func:`start_decay` computes before its ESPRIT (by :func:`_start_prepare`): the
    window of :class:`_StartGrid` (release, ``tw``, ``xw``, ``tau``, noise, ``xg``, ``dt``,
    ``udt``), the spectral period ``per`` (samples) and ESPRIT's input (block means ``y`` of
    ``q`` samples, active length ``n_act``)."""

    per: float
    y: np.ndarray
    q: int
    n_act: int


def _start_prepare(t, x, *, release=None, skip=0.0, coarse_release=False) -> _StartInput:
    """:func:`start_decay` up to its ESPRIT (checks, release, window, noise, period)."""
    t, x = check_record(t, x)
    grid = _start_grid(t, x, release, skip, not coarse_release)
    return _start_input(grid, _dominant_period(grid.xg))


def _start_grid(t, x, release, skip, refine_release=True, detected=None) -> _StartGrid:
    """The window of :func:`start_decay` (release, window, noise, uniform grid) of a checked
    record; ``detected`` as for :func:`_window`."""
    release, hold_sd, tw, xw, ptp = _window(t, x, release, skip, None, refine_release, detected)
    tau = tw - tw[0]
    noise = hold_sd if hold_sd else diff_noise(xw[-4096:])
    noise = max(noise, 1e-15 * ptp)
    xg, dt, udt = _uniform(tau, xw, float(tw[0]))
    return _StartGrid(float(release), tw, xw, tau, float(noise), xg, float(dt), udt)


def _start_input(g: _StartGrid, per: float) -> _StartInput:
    """:func:`start_decay`'s ESPRIT input from its window and the spectral period ``per``
    (samples)."""
    y, q, n_act = _guess_input(g.xg, per, g.noise)
    return _StartInput(**vars(g), per=float(per), y=y, q=q, n_act=n_act)


def _start_finish(pre: _StartInput, s: np.ndarray, energy: np.ndarray | None,
                  refine: bool | str = True) -> DecayStart:
    """:func:`start_decay` from ESPRIT's roots ``s`` and energies on (the choice of the start,
    the staged refinement, the Gauss–Newton confirmation)."""
    tw, xw, tau, xg, dt, per = pre.tw, pre.xw, pre.tau, pre.xg, pre.dt, pre.per
    release, noise, _udt = pre.release, pre.noise, pre.udt
    sig, om, oscill, n_act = _guess_pick(s, energy, pre.q, dt, xg.size, pre.n_act)
    if oscill and n_act > 40 * per:
        sig, om = _staged(xg, dt, per, sig, om)
    if refine == "auto" and oscill:
        om_fft = 2.0 * math.pi / (per * dt)
        tol = max(0.25 * om_fft, 1.5 * 2.0 * math.pi / (min(xg.size, 4096) * dt))
        refine = abs(om - om_fft) > tol or abs(sig) > _START_MAX_DAMPING * om
    if refine and oscill:
        # a start the fit cannot confirm (no convergence) is no oscillating start
        res = _gauss_newton(_evaluator(tau, xw, _udt), sig, om, rtol_se=_START_RTOL_SE)
        oscill = res is not None and res[1]
        if oscill:
            sig, om = res[0].sig, res[0].om
    return DecayStart(
        sigma=float(sig), omega_d=float(om), oscillating=bool(oscill), release=float(release),
        offset=_med(xw), noise_sd=float(noise), t_start=float(tw[0]), t_end=float(tw[-1]),
    )


def _polish(ev, p: _Point, rtol_se: float = 0.05):
    """Exact residual at the Gauss–Newton optimum (sample by sample) and up to three more
    steps with the exact gradient while they are not negligible (below ``rtol_se`` standard
    errors or 10⁻¹⁵ relative); returns the point, its residual and (JᵀJ)⁻¹."""
    r, Gr = ev.residual(p)
    Minv, g = p.normal(Gr)
    if Minv is None:
        m = p.K.shape[0]
        return p, r, np.full((m, m), np.nan)
    for _ in range(3):
        step = (Minv[-2:] @ g).tolist()
        sse = float(r @ r)
        v = sse / max(r.size - p.K.shape[0], 1)
        se0 = math.sqrt(max(float(Minv[-2, -2]) * v, 0.0))
        se1 = math.sqrt(max(float(Minv[-1, -1]) * v, 0.0))
        tiny = 1e-15 * (abs(p.sig) + abs(p.om))
        if abs(step[0]) <= max(rtol_se * se0, tiny) and abs(step[1]) <= max(rtol_se * se1, tiny):
            break
        q = ev(p.sig + step[0], abs(p.om + step[1]))
        if q is None:
            break
        r2, Gr2 = ev.residual(q)
        if not float(r2 @ r2) <= sse:
            break
        M2, g2 = q.normal(Gr2)
        if M2 is None:
            break
        p, r, Minv, g = q, r2, M2, g2
    return p, r, Minv


def _cycles(amplitude, sigma, omega, duration, noise) -> float:
    """Cycles while the envelope A e^{−σt} is above the noise sd, within ``duration``."""
    if not (amplitude > noise > 0):
        return 0.0 if amplitude <= noise else omega * duration / (2 * math.pi)
    t_above = duration if sigma <= 0 else min(duration, math.log(amplitude / noise) / sigma)
    return max(omega * t_above / (2 * math.pi), 0.0)


def is_clipped(x: np.ndarray, resid: np.ndarray, noise: float) -> bool:
    """Flat tops: ≥ 5 samples at the record's extreme value that the fitted mode overshoots
    (``resid`` = x − the fitted model, m)."""
    for ext, sign in ((x.max(), 1.0), (x.min(), -1.0)):
        at = x == ext
        if np.count_nonzero(at) >= 5:
            over = -sign * resid[at]  # how far the model goes beyond the flat level x = ext
            if over.max() > 5.0 * noise:
                return True
    return False


def _window(t, x, release, skip, t_end, refine_release=True, detected=None):
    """The release (s), the held segment's sd (m, or None), the window's t and x, and the
    range of x over it (m).

    ``detected``: the release's sample and held sd when they were already detected (as
    :func:`locate_release` gives them), for ``release=None``."""
    skip = v.nonnegative("skip", skip, "s")
    if release is None:
        j, hold_sd = locate_release(t, x, refine_release) if detected is None else detected
        release = float(t[j])
    else:
        release = v.finite("release", release, "s")
        if not release < t[-1]:
            raise ValueError(
                f"`release` must be before the record's end t[-1] = {t[-1]:g} s; got {release:g}"
            )
        j = int(np.searchsorted(t, release, side="right")) - 1
        hold_sd = _hold_sd(x, j)
    t0 = release + skip
    if t_end is None:
        t1 = float(t[-1])
    else:
        t1 = v.finite("t_end", t_end, "s")
        if not t1 > t0:
            raise ValueError(f"`t_end` must be > release + skip = {t0:g} s; got {t1:g}")
    # the sample at release + skip itself belongs to the window (tolerance: rounding of t)
    tol = 1e-9 * (abs(t0) + (t[-1] - t[0]) / t.size)
    i0 = int(np.searchsorted(t, t0 - tol, side="left"))
    i1 = int(np.searchsorted(t, t1 + tol, side="right"))
    nw = max(i1 - i0, 0)
    if nw < MIN_SAMPLES:
        raise ValueError(
            f"the window [release + skip, t_end] = [{t0:g}, {t1:g}] s holds {nw} samples; "
            f"at least {MIN_SAMPLES} are needed"
        )
    tw, xw = t[i0:i1], x[i0:i1]
    ptp = float(xw.max()) - float(xw.min())
    if not ptp > 0:
        raise ValueError(f"`x` is constant ({xw[0]:g} m) in the window [{t0:g}, {t1:g}] s")
    return release, hold_sd, tw, xw, ptp


def _unfitted(
    method, tw, release, noise, offset, warnings, sigma=math.nan, omega=math.nan, cov=None
) -> DecayFit:
    """A DecayFit for a record the method could not fit: NaN where there is no estimate."""
    nan = math.nan
    return DecayFit(
        sigma=sigma,
        omega_d=omega,
        cov=np.full((2, 2), nan) if cov is None else cov,
        amplitude=nan,
        phase=nan,
        offset=offset,
        t_ref=float(tw[0]),
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=float(release),
        n_samples=int(tw.size),
        cycles=0.0,
        noise_sd=noise,
        residual_rms=nan,
        method=method,
        warnings=tuple(warnings),
    )


def _phase_amp(a: float, b: float) -> tuple[float, float]:
    """(A, φ₀) with a cos ωτ + b sin ωτ = A sin(ωτ − φ₀)."""
    return math.hypot(a, b), math.atan2(-a, b)


def _check_fast_roots(fast_roots) -> np.ndarray:
    if fast_roots is None:
        return np.zeros(0, complex)
    try:
        r = np.asarray(fast_roots, dtype=complex).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"`fast_roots` must be complex numbers; got {fast_roots!r}") from None
    roots = r.tolist()  # (a handful: plain Python is faster than array calls here)
    for z in roots:
        if not cmath.isfinite(z):
            raise ValueError(f"`fast_roots` must be finite; got {z}")
    for z in roots:
        if not z.real < 0:
            raise ValueError(f"`fast_roots` must be decaying modes (Re s < 0, 1/s); got {z}")
    keep: list[complex] = []
    for z in (complex(q.real, abs(q.imag)) for q in roots):  # a root and its conjugate: one mode
        if not any(abs(z - w) <= 1e-9 * abs(w) for w in keep):
            keep.append(z)
    return np.array(keep, dtype=complex)


@single_blas_thread
def fit_decay(
    t, x, *, release=None, skip=0.0, t_end=None, noise_sd=None, fast_roots=None, guess=None
) -> DecayFit:
    """Decay rate σ and damped frequency ω_d of the dominant mode by maximum likelihood.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing (need not be uniform).
    x : array_like, shape (n,)
        Position, m.
    release : float, optional
        Release time of the held mass, s (may precede the record). Default:
        :func:`detect_release`.
    skip : float, default 0
        Time after the release left out of the fit, s (≥ 0), so that the closed loop's fast
        non-dominant modes have died (compute it from the loop model; see Notes).
    t_end : float, optional
        Last time fitted, s. Default: the end of the record (no truncation; see Notes).
    noise_sd : float, optional
        Known white-noise sd, m (> 0). Used for the noise floor (``cycles``, warnings); the
        covariance always uses the residual variance. Default: the sd of the held segment, or
        a robust estimate from second differences when there is no held segment.
    fast_roots : array_like of complex, optional
        Roots s = −σ_j + iω_j (1/s, Re s < 0) of non-dominant modes to fit alongside the
        dominant one, with free amplitudes and fixed rates (a root and its conjugate are one
        mode) — e.g. the closed loop's next roots from the current plant estimate. With them
        the fit can start at the release (``skip`` = 0) and keep the information of the first
        instants instead of discarding it.
    guess : (float, float), optional
        Starting (σ, ω_d) (1/s, rad/s), e.g. from an earlier fit of the same record; skips the
        FFT/ESPRIT starting stage. The record is then taken to be oscillatory.

    Returns
    -------
    DecayFit
        ``method == "mode-fit"``; ``t_ref`` is the first fitted sample. ``model`` is the
        dominant mode and the offset (the fast modes are left out).

    Raises
    ------
    ValueError
        If the input is unusable: NaN/inf, t not strictly increasing, lengths differ, fewer
        than 16 samples (in the record or the window), a constant record, a bad option.

    Notes
    -----
    Model over the window [release + skip, t_end], with τ = t − t_ref (eq. 15 plus an offset):

        x = x_off + e^{−στ} (a cos ω_dτ + b sin ω_dτ) + white noise.

    Start: the FFT peak gives the period; the part of the window above the noise (≤ 40 periods
    of it) is block-averaged to ~16 samples a period (a moving average keeps every exponential
    mode exactly) and ESPRIT (order 3: offset and one complex pair) gives (σ, ω_d). Solver:
    variable projection — (x_off, a, b) by linear least squares at every (σ, ω_d) — with
    Kaufman's Gauss–Newton step from the full 5-column Jacobian, step halving on any increase of
    the residual sum of squares, stopped when the next step is below 0.05 standard errors
    (where Gauss–Newton contracts by ~10⁻³ a step) — then up to three steps more from the
    exactly recomputed residual while they are larger (noise-free data: to 10⁻¹⁵). Records much
    longer than the start segment (barely damped loops with hundreds of cycles) are first
    fitted on block means of windows growing fourfold, each started from the last.
    On uniform sampling every sum the solver needs (Σ τᵖ e^{2sτ}, Σ x τᵖ e^{sτ}, …) is formed
    from two √n-long exponential tables (n = bB + j), with no transcendental per sample; one
    fit of 15 000 samples takes about 1–1.4 ms.

    Covariance: RSS/(n − p) · (JᵀJ)⁻¹ with J the n × p Jacobian of all p parameters (5, plus
    the fast modes' amplitudes) at the optimum, its (σ, ω_d) block taken — the Cramér–Rao bound
    of this model at the estimate, with the noise variance from the residuals (so unmodelled
    signal inflates it). Over seeded Monte Carlo replicas its square roots match the scatter of
    the estimates to a few per cent.

    Window: the whole record after release + skip is fitted. The tail lost in noise is kept:
    it costs little time, biases nothing and pins the offset (truncating it only loses offset
    information); ``t_end`` caps the window.

    Fast modes of a delayed loop: its non-dominant roots (for the seed paper's sweep the
    slowest is real, s₂ = −σ₂ with σ₂ = 22–52 1/s) leave a transient of up to ~5 % of the
    release displacement, which biases a single-mode fit started at the release (by 11
    stderr in σ for the sample set's run 19). Either skip it — until the slowest fast mode's
    envelope |A₂|e^{−σ₂t} is below ~0.01 noise sd; for the sample set
    ``skip = max(2Δt, 5/(σ₂ − σ))`` does it — or give the two slowest non-dominant roots as
    ``fast_roots`` and fit from the release. For the sample set the skip costs 13–15 % in the
    standard errors of m, c and k against the Cramér–Rao bound of truth.json; the fast roots
    (known to ≲ 1 %) cost 2–5 %, with a bias below 0.01 standard error.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(15000) / 1000  # 15 s at 1 kHz
    >>> x = -3e-4 + 0.01 * np.exp(-0.5 * t) * np.cos(6.2 * t)
    >>> fit = fit_decay(t, x, release=0.0)
    >>> print(f"{fit.sigma:.9f} {fit.omega_d:.9f} {fit.offset:.6f}")
    0.500000000 6.200000000 -0.000300
    >>> rng = np.random.default_rng(0)
    >>> fit = fit_decay(t, x + 1e-4 * rng.standard_normal(t.size), release=0.0)
    >>> abs(fit.sigma - 0.5) < 3 * fit.sigma_stderr
    True
    """
    t, x = check_record(t, x)
    return fit_checked(t, x, release=release, skip=skip, t_end=t_end, noise_sd=noise_sd,
                        fast_roots=fast_roots, guess=guess)


def fit_checked(t, x, *, release=None, skip=0.0, t_end=None, noise_sd=None, fast_roots=None,
                 guess=None) -> DecayFit:
    """:func:`fit_decay` on a record that has passed ``check_record`` already (float64
    arrays, finite, t strictly increasing): the identification validates each run once, in its
    first pass (:func:`start_decay`), and fits it in full afterwards."""
    prep = _fit_prepare(t, x, release=release, skip=skip, t_end=t_end, noise_sd=noise_sd,
                        fast_roots=fast_roots, guess=guess)
    ev = _evaluator(prep.tau, prep.xw, prep.udt, prep.fast)
    res = _gauss_newton(ev, prep.sigma, prep.omega_d)
    if res is None:  # the start overflowed: fall back to a bland one
        res = _gauss_newton(ev, 0.0, 2 * math.pi / (prep.period * prep.dt))
    if res is None:  # no (σ, ω_d) where the linear part is solvable: nothing to report
        return _fit_unevaluable(prep)
    p, converged, iterations = res
    p, r, Minv = _polish(ev, p)
    return _fit_finish(prep, p.sig, p.om, p.beta, p.K, r, Minv, converged, iterations)


@dataclass(frozen=True)
class _Prepared:
    """A record made ready for the Gauss–Newton of :func:`fit_decay` (by :func:`_fit_prepare`):
    the window (``tw``, ``xw``; ``tau`` = tw − tw[0], s), the release (s) and held-segment sd
    (m, None without one), the noise level (m) and the caller's ``noise_sd``, the record's range
    ``ptp`` (m), its sampling (``dt`` s; ``udt`` the step if uniform, else None), the start
    (``sigma`` 1/s, ``omega_d`` rad/s, ``oscillating``, ``period`` in samples) and the fast
    roots (1/s)."""

    tw: np.ndarray
    xw: np.ndarray
    tau: np.ndarray
    release: float
    hold_sd: float | None
    noise: float
    noise_sd: float | None
    ptp: float
    dt: float
    udt: float | None
    sigma: float
    omega_d: float
    oscillating: bool
    period: float
    fast: np.ndarray


def _fit_prepare(t, x, *, release=None, skip=0.0, t_end=None, noise_sd=None, fast_roots=None,
                 guess=None) -> _Prepared:
    """Window, noise and start of :func:`fit_decay` (everything before its Gauss–Newton).

    Raises ValueError as :func:`fit_decay` does for unusable options or windows."""
    if noise_sd is not None:
        noise_sd = v.positive("noise_sd", noise_sd, "m")
    fast = _check_fast_roots(fast_roots)
    release, hold_sd, tw, xw, ptp = _window(t, x, release, skip, t_end)
    tau = tw - float(tw[0])
    if noise_sd is not None:
        noise = noise_sd
    else:  # the tail, where the signal is least, is the best place for a difference estimate
        noise = hold_sd if hold_sd else diff_noise(xw[-4096:])
    noise = max(noise, 1e-15 * ptp)

    # start: FFT period, ESPRIT on the block-averaged active part (or the caller's guess)
    xg, dt, udt = _uniform(tau, xw, float(tw[0]))
    if guess is not None:
        sig = v.finite("guess[0]", guess[0], "1/s")
        om = v.positive("guess[1]", guess[1], "rad/s")
        oscill, n_act = True, 0
        per = 2 * math.pi / (om * dt)
    else:
        per = _dominant_period(xg)
        sig, om, oscill, n_act = _initial_guess(xg, dt, per, noise)
    if oscill and n_act > 40 * per:
        sig, om = _staged(xg, dt, per, sig, om)
    return _Prepared(tw=tw, xw=xw, tau=tau, release=float(release), hold_sd=hold_sd,
                     noise=float(noise), noise_sd=noise_sd, ptp=ptp, dt=float(dt), udt=udt,
                     sigma=float(sig), omega_d=float(om), oscillating=bool(oscill),
                     period=float(per), fast=fast)


def _fit_unevaluable(prep: _Prepared) -> DecayFit:
    """The result of a fit whose model could not be evaluated at any start."""
    msg = "not converged: no start at which the damped-mode model could be evaluated"
    return _unfitted("mode-fit", prep.tw, prep.release, prep.noise, float(np.median(prep.xw)),
                     [msg])


def _fit_finish(prep: _Prepared, sig: float, om: float, beta: np.ndarray, K: np.ndarray,
                r: np.ndarray, Minv: np.ndarray, converged: bool, iterations: int) -> DecayFit:
    """The DecayFit of a converged (or stopped) Gauss–Newton: at (σ, ω_d) = (``sig``, ``om``)
    with linear parameters ``beta`` (x_off, a, b, fast amplitudes …), their Gram matrix ``K``,
    the exact residual ``r`` (m, per sample of the window) and (JᵀJ)⁻¹ ``Minv`` (σ, ω_d last);
    covariance, amplitude, noise floor, cycles and warnings."""
    tw, xw, fast, noise_sd = prep.tw, prep.xw, prep.fast, prep.noise_sd
    bl = beta.tolist()
    off, a, b = bl[:3]
    n = xw.size
    rss = float(r @ r)
    s2 = rss / max(n - K.shape[0], 1)
    amp, phase = _phase_amp(a, b)
    # the fast columns are e^{rτ} (real r) or Re, Im of e^{rτ}: amplitude A with Re(A e^{rτ})
    fast_modes, j = [], 3
    fl = fast.tolist()
    for root in fl:
        if root.imag != 0:
            fast_modes.append((complex(root), complex(bl[j], -bl[j + 1])))
            j += 2
        else:
            fast_modes.append((complex(root), complex(bl[j])))
            j += 1
    cov = s2 * Minv[-2:, -2:]
    (c00, _c01), (_c10, c11) = cov.tolist()
    sig_se, om_se = math.sqrt(max(c00, 0.0)), math.sqrt(max(c11, 0.0))  # DecayFit's stderrs
    fit_noise = math.sqrt(s2)
    floor = noise_sd if noise_sd is not None else max(fit_noise, 1e-15 * prep.ptp)
    cycles = _cycles(amp, sig, om, float(tw[-1] - tw[0]), floor)
    warnings = _common_warnings(sig, sig_se, cycles, xw, r, floor)
    # detection statistic of the mode: its norm over the window in noise sds (pure noise gives
    # ~5 for the best of all (σ, ω_d); a real decay of the sample set ~10³)
    (k11, k12), (k21, k22) = K[1:3, 1:3].tolist()
    snr = math.sqrt(max(a * (k11 * a + k12 * b) + b * (k21 * a + k22 * b), 0.0)) / max(
        fit_noise, 1e-300)
    if (
        # the order-3 starting guess sees no complex pair when a slow non-dominant real mode is
        # in the record; with that mode given in ``fast_roots`` the final fit decides alone
        (not prep.oscillating and fast.size == 0)
        or not om > 3.0 * om_se
        or om * (tw[-1] - tw[0]) < math.pi
        or snr < _MIN_MODE_SNR
    ):
        warnings.append(
            "no oscillation: the dominant motion is not a resolvable damped oscillation "
            f"(omega_d = {om:.4g} ± {om_se:.2g} rad/s, mode {snr:.3g} noise sds "
            "strong); sigma and omega_d describe no underdamped mode"
        )
    if any(-z.real <= sig for z in fl):
        warnings.append(
            "fast_roots: a root given as non-dominant decays no faster than the fitted dominant "
            f"mode (sigma = {sig:.4g} 1/s); check the roots"
        )
    if not converged:
        warnings.append(
            f"not converged: the fit stopped after {iterations} Gauss–Newton iterations; "
            "the estimate may not be the least-squares optimum"
        )
    ref = noise_sd if noise_sd is not None else prep.hold_sd
    if ref and fit_noise > 1.5 * ref:
        warnings.append(
            f"misfit: residual sd {fit_noise:.3g} m is {fit_noise / ref:.2f} times the "
            f"noise sd {ref:.3g} m ({'given' if noise_sd is not None else 'held segment'}); "
            "the record holds more than one damped mode (increase `skip`?) or friction"
        )
    return DecayFit(
        sigma=float(sig),
        omega_d=float(om),
        cov=cov,
        amplitude=amp,
        phase=phase,
        offset=off,
        t_ref=float(tw[0]),
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=prep.release,
        n_samples=int(n),
        cycles=cycles,
        noise_sd=fit_noise,
        residual_rms=math.sqrt(rss / n),
        method="mode-fit",
        fast_modes=tuple(fast_modes),
        warnings=tuple(warnings),
    )


def _common_warnings(sigma: float, sigma_stderr: float, cycles: float, xw, resid, floor
                     ) -> list[str]:
    """The warnings every decay fit can give: few cycles, a growing oscillation (σ < 0, 1/s,
    with its stderr), a clipped record (``resid``: x − model over the window; ``floor``: noise
    sd, m)."""
    w = []
    if cycles < MIN_CYCLES:
        w.append(
            f"few cycles: only {cycles:.1f} oscillation cycles above the noise floor "
            f"(< {MIN_CYCLES:g}); sigma and omega_d are poorly supported by the data"
        )
    if sigma < 0:
        sure = sigma < -2.0 * sigma_stderr
        w.append(
            f"growing oscillation: sigma = {sigma:.4g} ± {sigma_stderr:.2g} 1/s < 0 "
            + ("(unstable loop)" if sure else "(within 2 stderr of 0: marginally stable loop?)")
        )
    if is_clipped(xw, resid, floor):
        w.append(
            "clipped record: flat tops at the extreme value of x that the fitted mode exceeds "
            "(sensor saturation?); the estimate is biased"
        )
    return w


# --------------------------------------------------------------------------------------------
# logarithmic decrement


def _local_vertex(tt, xx, tc, h, noise):
    """Vertex of a weighted quadratic least-squares fit over |t − tc| < h.

    Biweight weights (1 − (u/h)²)² let samples enter and leave the window smoothly, so the
    vertex does not jump with the sampling phase. Returns (time, value, var_time, var_value,
    curvature) with the variances per unit noise variance and the value corrected for the
    first-order noise bias of p₀ − p₁²/(4p₂); None if the window is unusable."""
    i0 = int(np.searchsorted(tt, tc - h, side="right"))
    i1 = int(np.searchsorted(tt, tc + h, side="left"))
    if i1 - i0 < 3:
        return None
    u = (tt[i0:i1] - tc) / h
    y = xx[i0:i1]
    w = (1.0 - u * u) ** 2
    X = np.stack([np.ones_like(u), u, u * u], axis=1)
    Xw = X * w[:, None]
    try:
        Ai = np.linalg.inv(X.T @ Xw)
    except np.linalg.LinAlgError:
        return None
    p0, p1, p2 = Ai @ (Xw.T @ y)
    if not p2 != 0:
        return None
    cov = Ai @ (Xw.T @ Xw) @ Ai  # per unit noise variance
    tv = -p1 / (2 * p2)
    val = p0 - p1 * p1 / (4 * p2) + noise * noise * cov[1, 1] / (4 * p2)
    gt = np.array([0.0, -1 / (2 * p2), p1 / (2 * p2 * p2)]) * h
    gv = np.array([1.0, -p1 / (2 * p2), p1 * p1 / (4 * p2 * p2)])
    return tc + tv * h, val, float(gt @ cov @ gt), float(gv @ cov @ gv), p2


def _extrema(tw, xw, offset, noise, per_t):
    """Lobes of the record about ``offset``: (sign, index of the extreme sample) for each run
    of the smoothed signal beyond a ±3-noise-sd hysteresis band (so noise cannot split one)."""
    n = tw.size
    dt = (tw[-1] - tw[0]) / (n - 1)
    w = max(1, round(per_t / dt / 12))
    y = xw - offset
    if w > 1:
        c = np.concatenate([[0.0], np.cumsum(y)])
        lo = np.clip(np.arange(n) - w // 2, 0, n)
        hi = np.clip(np.arange(n) + w - w // 2, 0, n)
        ys = (c[hi] - c[lo]) / (hi - lo)
    else:
        ys = y
    band = 3.0 * noise / math.sqrt(w)
    state = np.where(ys > band, 1, np.where(ys < -band, -1, 0))
    nz = np.flatnonzero(state)
    if nz.size == 0:
        return []
    # forward-fill the state, lobes are runs of equal state
    idx = np.maximum.accumulate(np.where(state != 0, np.arange(n), 0))
    st = state[idx]
    st[: nz[0]] = 0
    edges = np.flatnonzero(np.diff(st) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [n]])
    lobes = []
    for a, b in zip(starts, ends, strict=True):
        sgn = st[a]
        if sgn == 0:
            continue
        k = a + int(np.argmax(sgn * ys[a:b]))
        lobes.append((sgn, k))
    return lobes


@single_blas_thread
def logdec(t, x, *, release=None, skip=0.0) -> DecayFit:
    """σ and ω_d by the logarithmic decrement of all the extrema above the noise floor.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, strictly increasing.
    x : array_like, shape (n,)
        Position, m.
    release : float, optional
        Release time, s. Default: :func:`detect_release`.
    skip : float, default 0
        Time after the release left out, s (≥ 0).

    Returns
    -------
    DecayFit
        ``method == "logdec"``. ``amplitude``, ``phase`` and ``offset`` are the linear least
        squares over the window at the logdec's (σ, ω_d). When fewer than three extrema are
        found, σ and ω_d are NaN and ``warnings`` says why.

    Raises
    ------
    ValueError
        For unusable input, as :func:`fit_decay`.

    Notes
    -----
    For x = x_off + A e^{−σt} sin(ω_d t − φ₀) (eq. 15) the extrema fall exactly π/ω_d apart
    and alternate in sign about x_off, so the difference of successive extremum values
    d_k = |v_k − v_{k+1}| = C e^{−σ k π/ω_d} holds no offset: the log decrement per half cycle
    δ = σπ/ω_d is minus the slope of ln d_k against k — exact, whatever the offset.

    Each extremum's time and value come from a quadratic least-squares fit over ±1/8 period
    about it with biweight weights (samples enter the window smoothly, so the result does not
    jump with the sampling phase), re-centred once on its vertex, the value corrected for the
    first-order noise bias of a vertex. The peak shape is the same for every extremum up to
    scale, so the small bias of the quadratic cancels in the decrement. The sequence ends where
    the decrement line fitted to the extrema crosses 5 noise sds (not at the first noisy
    extremum below it, which would select high values and bias σ down).
    π/ω_d is the weighted slope of the extremum times against k (weights from each local fit),
    δ the generalised least-squares slope of ln d_k against k with the covariance of the d_k
    (successive differences share an extremum) propagated from the local fits; σ = δω_d/π.
    Variances are scaled by the noise variance (held segment, else second differences), and by
    a regression's reduced χ² when that is significantly above 1 (misfit widens them).

    On noise-free single-mode records sampled at ≥ ~100 samples a period the relative error is
    ~10⁻⁸ (≤ 10⁻⁷ for ζ up to 0.3); on the sample set's noise its standard errors are 2–4
    times those of :func:`fit_decay`.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(15000) / 1000
    >>> dec = logdec(t, -3e-4 + 0.01 * np.exp(-0.5 * t) * np.cos(6.2 * t), release=0.0)
    >>> print(f"{dec.sigma:.6f} {dec.omega_d:.6f}")
    0.500000 6.200000
    """
    t, x = check_record(t, x)
    release, hold_sd, tw, xw, _ptp = _window(t, x, release, skip, None)
    t_ref = float(tw[0])
    noise = hold_sd if hold_sd else diff_noise(xw)
    noise = max(noise, 1e-15 * float(np.ptp(xw)))
    warnings: list[str] = []

    xg, dt, udt = _uniform(tw - t_ref, xw)
    per_t = _dominant_period(xg) * dt
    ev = _evaluator(tw - t_ref, xw, udt)
    # lobes are split about the record's median first; if the offset from the first pass's mode
    # differs by more than half a noise sd, or its period from the FFT's by 10 %, once more
    offset = float(np.median(xw))
    ext = _logdec_extrema(tw, xw, offset, noise, per_t)
    if ext is not None:
        pt = ev(ext["sigma"], ext["omega"])
        per2 = 2 * math.pi / ext["omega"]
        if pt is not None and (
            abs(pt.beta[0] - offset) > 0.5 * noise or abs(per2 - per_t) > 0.1 * per_t
        ):
            offset = float(pt.beta[0])
            ext = _logdec_extrema(tw, xw, offset, noise, per2) or ext
    if ext is None:
        warnings.append(
            "no oscillation: fewer than three extrema above the noise floor; the logarithmic "
            "decrement is undefined"
        )
        return _unfitted("logdec", tw, release, noise, offset, warnings)
    sig, om = ext["sigma"], ext["omega"]
    pt = ev(sig, om)
    if pt is None:  # the decrement's mode overflows over the window (violent growth)
        warnings.append("the mode of the decrement cannot be evaluated over the window")
        return _unfitted("logdec", tw, release, noise, offset, warnings, sig, om, ext["cov"])
    r, _ = ev.residual(pt)
    rss = float(r @ r)
    off, a, b = (float(c) for c in pt.beta)
    amp, phase = _phase_amp(a, b)
    n = xw.size
    fit = DecayFit(
        sigma=sig,
        omega_d=om,
        cov=ext["cov"],
        amplitude=amp,
        phase=phase,
        offset=off,
        t_ref=t_ref,
        t_start=float(tw[0]),
        t_end=float(tw[-1]),
        release=float(release),
        n_samples=int(n),
        cycles=0.0,
        noise_sd=math.sqrt(rss / (n - 5)),
        residual_rms=math.sqrt(rss / n),
        method="logdec",
    )
    cycles = _cycles(amp, sig, om, float(tw[-1] - tw[0]), noise)
    warnings += _common_warnings(fit.sigma, fit.sigma_stderr, cycles, xw, xw - fit.model(tw),
                                 noise)
    if ext["n_extrema"] < 2 * MIN_CYCLES:
        warnings.append(
            f"few extrema: only {ext['n_extrema']} extrema above the noise floor were used"
        )
    return replace(fit, cycles=cycles, warnings=tuple(warnings))


def _inflation(chi2_red: float, dof: int) -> float:
    """Variance factor for a regression: its reduced χ² when that is significantly above 1
    (beyond 3 sds of a χ²/dof with ``dof`` degrees of freedom: misfit), else 1."""
    if dof < 1:
        return 1.0
    return chi2_red if chi2_red > 1.0 + 3.0 * math.sqrt(2.0 / dof) else 1.0


def _logdec_extrema(tw, xw, offset, noise, per_t):
    """Extrema → (σ, ω_d, cov) by the two regressions of :func:`logdec`; None if < 3 extrema."""
    lobes = _extrema(tw, xw, offset, noise, per_t)
    dtmax = float(np.max(np.diff(tw)))
    h = max(per_t / 8.0, 2.5 * dtmax)
    out = []
    for sgn, k in lobes:
        tc = tw[k]
        if tc - h < tw[0] or tc + h > tw[-1]:
            continue
        r = _local_vertex(tw, xw, tc, h, noise)
        if r is None or not abs(r[0] - tc) < h:
            continue
        if tw[0] <= r[0] - h and r[0] + h <= tw[-1]:
            r2 = _local_vertex(tw, xw, r[0], h, noise)
            if r2 is not None and abs(r2[0] - r[0]) < h:
                r = r2
        # a maximum must be concave, a minimum convex
        if np.sign(-r[4]) != sgn:
            continue
        out.append((sgn, *r[:4]))
    if len(out) < 3:
        return None
    sg = np.array([o[0] for o in out], dtype=float)
    tk = np.array([o[1] for o in out])
    vk = np.array([o[2] for o in out])
    vt = np.array([o[3] for o in out])
    vv = np.array([o[4] for o in out])
    # usable pairs: the leading run of alternating extrema with positive differences. The run
    # ends at the first pair whose half-difference is below the floor — then, so that the end
    # does not depend on the noise of the last extrema (selecting them for being high would bias
    # σ down), it is moved to where the fitted decrement line crosses the floor.
    d = sg[:-1] * (vk[:-1] - vk[1:])
    ok = (sg[1:] == -sg[:-1]) & (d > 0)
    n_ok = int(np.argmin(ok)) if not np.all(ok) else d.size
    above = ok & (d / 2 > _LOGDEC_FLOOR_NSD * noise)
    npair = int(np.argmin(above)) if not np.all(above) else d.size
    if npair < 2:
        return None
    c1, c0 = np.polyfit(np.arange(npair, dtype=float), np.log(d[:npair]), 1, w=d[:npair])
    if c1 < 0:
        k_floor = (math.log(2 * _LOGDEC_FLOOR_NSD * noise) - c0) / c1
        npair = int(min(max(math.floor(k_floor) + 1, 2), n_ok))
    K = npair + 1
    tk, vk, vt, vv, sg, d = tk[:K], vk[:K], vt[:K], vv[:K], sg[:K], d[:npair]
    s2 = noise * noise
    # (1) extremum times: t_k = t_0 + k π/ω_d, weighted by 1/var(t_k)
    k = np.arange(K, dtype=float)
    X = np.stack([np.ones(K), k], axis=1)
    Wt = 1.0 / np.maximum(vt, 1e-300)
    Mt = X.T @ (X * Wt[:, None])
    Ct = np.linalg.inv(Mt)
    pt = Ct @ (X.T @ (Wt * tk))
    rt = tk - X @ pt
    chi_t = float(rt @ (Wt * rt)) / s2 / max(K - 2, 1)
    half = float(pt[1])  # π/ω_d
    var_half = float(Ct[1, 1]) * s2 * _inflation(chi_t, K - 2)
    # (2) ln d_k = c − δ k, covariance of ln d from the shared extrema
    B = np.zeros((npair, K))
    B[np.arange(npair), np.arange(npair)] = 1.0
    B[np.arange(npair), np.arange(npair) + 1] = -1.0
    Jd = (sg[:npair] / d)[:, None] * B
    Sd = Jd @ (vv[:, None] * Jd.T)
    y = np.log(d)
    Xd = np.stack([np.ones(npair), np.arange(npair, dtype=float)], axis=1)
    Si = np.linalg.inv(Sd)
    Md = Xd.T @ Si @ Xd
    Cd = np.linalg.inv(Md)
    pd = Cd @ (Xd.T @ Si @ y)
    rd = y - Xd @ pd
    chi_d = float(rd @ Si @ rd) / s2 / max(npair - 2, 1)
    delta = -float(pd[1])
    var_delta = float(Cd[1, 1]) * s2 * _inflation(chi_d, npair - 2)
    om = math.pi / half
    var_om = (math.pi / half**2) ** 2 * var_half
    sig = delta * om / math.pi
    var_sig = (om / math.pi) ** 2 * var_delta + (delta / math.pi) ** 2 * var_om
    cov_so = (delta / math.pi) * var_om
    cov = np.array([[var_sig, cov_so], [cov_so, var_om]])
    return {"sigma": sig, "omega": om, "cov": cov, "n_extrema": K}
