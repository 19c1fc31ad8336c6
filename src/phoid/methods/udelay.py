"""The loop delay Δt from the recorded feedback force u as well as from x.

A continuous PD loop with a delay applies (seed eq. 23)

    u(t) = −[P x(t − Δt) + D ẋ(t − Δt)],

so the recorded force is the position record, differentiated, scaled by the known gains and
shifted by Δt. While the mass is held u = −P x₀; after the release at t_r it stays there until
t_r + Δt and then follows the delayed modes: for each mode x ∝ C e^{s(t − t_ref)},

    u ∝ −(P + D s) e^{−sΔt} C e^{s(t − t_ref)},

so the ratio of u's to x's complex amplitude carries Δt through its phase, −ω_dΔt (its modulus,
e^{σΔt}, is confounded with the calibration of u and is not relied on, see below).

Method (per run, then all runs together):

1. **Joint fit of x and u per run** (:func:`fit_run`). The x model is the run's decay fit
   (:class:`phoid.fits.DecayFit`: offset, dominant mode s = −σ + iω_d with complex amplitude
   C₀, the loop's fitted fast modes with free complex amplitudes and fixed rates), over the
   decay fit's own window. The u model is that same x model pushed through the loop,
   u = u_off + g Re Σⱼ −(P + D sⱼ) Cⱼ e^{sⱼ(t − Δt − t_ref)}, over the samples where the delayed
   position lies in the x window and the loop's first mode left out of the x model has died
   below 0.3 of u's noise in u (the factor P + Ds amplifies fast modes, so u needs a longer
   skip than x). All x and u parameters and Δt are fitted together by Gauss–Newton, each
   signal weighted by its own white-noise variance estimated from its own residuals
   (RSS/(n − p) of x and of u separately). The covariance (JᵀWJ)⁻¹ of all parameters therefore
   propagates the x fit's uncertainty in s and the amplitudes into Δt, and gives the run's
   (σ, ω_d, Δt) with their full 3 × 3 covariance.
2. **Shared delay, all evidence** (:func:`combine`). m, c, k, Δt are the weighted least squares
   fit of every run's measured (σᵢ, ω_dᵢ) — and, where u was used, Δtᵢ — through the exact
   dominant root of m s² + c s + k + (Dᵢ s + Pᵢ) e^{−sΔt} = 0 (the estimator of
   :func:`phoid.methods.pho.fit_modes` with a third measured component). The x-only evidence on the
   delay (only the right Δt maps all runs onto one plant) is kept, runs without u contribute
   through x only, and the (4, 4) covariance gives m, c, k stderr that include the delay's.

Why the gain g and offset u_off are free: a force record's calibration (sensor or amplifier
gain, units) is rarely known to the 1 % that the modulus e^{σΔt} − 1 ≈ σΔt would need
(σΔt ≈ 0.05 on the sample set: a 2 % gain error would move Δt by 40 %), and a force bias is
common. With g free the delay rests on timing (phase and time shift), which calibration does not
touch. A u whose fitted gain is negative (a sign convention: u recorded as +Px + Dẋ) or outside
[0.8, 1.25] (a scale factor: volts, an amplifier gain) is not the force the manifest's gains
imply; the run's u is then set aside with a warning, as is a constant or clipped u or one whose
residuals exceed twice its own noise (the sd of its held segment, at least its quantisation
step q/√12 and 1e−6 of its swing: a noise-free record rounded to six digits). A u used with a
scale off 1 by more than 2 % (and 5 stderr) gets a note asking to check its calibration.

What is left out, and why: the held u and its kink at t_r + Δt. The kink's time is t_r + Δt, and
t_r is known only from x (to 0.05–0.6 ms), while right after the release the x model lacks the
loop's faster modes, which the factor P + Ds magnifies in u; the samples there would need a model
of every mode. The timing over the whole decay carries the same Δt without that risk.

What u adds: with g free, one run's Δtᵢ is limited by how well x fixes its own phase (u's
timing is measured against it). But u is also a second, often less noisy, record of the same
modes (scaled by |P + Ds|), so the runs' σᵢ, ω_dᵢ improve, and with them the x-only route to Δt
(measurements: docs/design-notes/pho.md, "delay from the recorded force").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from phoid.dynamics import characteristic, dominant_roots
from phoid.errors import IdentificationError
from phoid.fits import DecayFit, diff_noise, is_clipped
from phoid.methods.chi2 import chi2_isf
from phoid.methods.loop_modes import distinct_modes, mode_residue

__all__ = ["UDelayFit", "URun", "check_u", "combine", "fit_run", "u_skip", "with_u"]

#: accepted range of u's fitted scale g (u = g × the force the gains imply)
GAIN_RANGE = (0.8, 1.25)
#: a used u whose scale differs from 1 by more than this (and 5 stderr) gets a note
_GAIN_NOTE = 0.02
#: u's first omitted loop mode must be below this fraction of u's noise sd
_OMIT_NOISE_FRACTION = 0.3
#: u residual rms above this multiple of u's own noise estimate: u does not fit
_MISFIT_RATIO = 2.0
#: resolution floor of u relative to its largest excursion (a noise-free or rounded record:
#: e.g. six significant digits in a CSV); u's noise is never taken below it
_U_RESOLUTION = 1e-6
#: fewest u samples a run's u fit needs
_MIN_U_SAMPLES = 64
_MAXIT = 30


@dataclass(frozen=True)
class URun:
    """One run's joint fit of x and u (:func:`fit_run`).

    Attributes
    ----------
    used : bool
        Whether the run's u enters the delay estimate.
    reason : str or None
        Why u was set aside (None when used).
    sigma, omega_d : float
        Dominant mode from the joint fit, 1/s and rad/s.
    delay : float
        The run's loop delay Δtᵢ, s.
    cov : ndarray, shape (3, 3)
        Covariance of (σ, ω_d, Δt).
    gain, gain_stderr : float
        Fitted scale g of u against −(P x + D ẋ)(t − Δt) (1: u is the force the gains imply).
    u_offset : float
        Fitted force offset of u, N.
    noise_u : float
        White-noise sd of u from the joint fit's u residuals, N.
    noise_x : float
        White-noise sd of x from the joint fit's x residuals, m.
    n_u : int
        u samples fitted.
    u_start : float
        First u sample time fitted, s.
    """

    used: bool
    reason: str | None = None
    sigma: float = math.nan
    omega_d: float = math.nan
    delay: float = math.nan
    cov: np.ndarray = field(default_factory=lambda: np.full((3, 3), math.nan), repr=False)
    gain: float = math.nan
    gain_stderr: float = math.nan
    u_offset: float = math.nan
    noise_u: float = math.nan
    noise_x: float = math.nan
    n_u: int = 0
    u_start: float = math.nan

    @property
    def delay_stderr(self) -> float:
        """Standard error of the run's Δt, s."""
        return math.sqrt(max(float(self.cov[2, 2]), 0.0))

    def to_dict(self) -> dict:
        """JSON-ready dict: ``used``, and either ``reason`` or the run's ``delay`` and
        ``delay_stderr`` (s), ``gain`` and ``gain_stderr``, ``offset`` (N), ``noise_sd`` (N)."""
        if not self.used:
            return {"used": False, "reason": self.reason}
        return {"used": True, "delay": self.delay, "delay_stderr": self.delay_stderr,
                "gain": self.gain, "gain_stderr": self.gain_stderr, "offset": self.u_offset,
                "noise_sd": self.noise_u}


@dataclass(frozen=True)
class UDelayFit:
    """m, c, k and Δt from x and u together (:func:`combine`).

    Attributes
    ----------
    m, c, k : float
        Mass (kg), viscous damping (N s/m), stiffness (N/m).
    delay : float
        Loop delay Δt, s.
    cov_full : ndarray, shape (4, 4)
        Covariance of (m, c, k, Δt).
    chi2 : float
        Weighted residual sum of squares.
    dof : int
        Degrees of freedom (measured components − 4).
    n_u : int
        Runs whose u entered.
    warnings : tuple of str
    """

    m: float
    c: float
    k: float
    delay: float
    cov_full: np.ndarray = field(repr=False)
    chi2: float
    dof: int
    n_u: int
    warnings: tuple[str, ...] = ()

    @property
    def delay_stderr(self) -> float:
        """Standard error of Δt, s."""
        return math.sqrt(max(float(self.cov_full[3, 3]), 0.0))


def u_skip(omitted: complex | None, amplitude: float, P: float, D: float, level: float) -> float:
    """Time (s) after the delayed release until u's first omitted loop mode is below ``level``.

    Parameters
    ----------
    omitted : complex or None
        The first loop root left out of the x model, 1/s (None: none left out).
    amplitude : float
        Its amplitude in x, m (from its residue, as for the x fit's own skip).
    P, D : float
        Gains, N/m and N s/m.
    level : float
        Level it must fall below in u, N.

    Returns
    -------
    float
        log(|P + D s| a / level) / σ_s, the time for |P + D s| a e^{−σ_s τ} (the mode in u,
        eq. 23) to reach ``level``; 0 when it is already below.
    """
    if omitted is None or not omitted.real < 0.0:
        return 0.0
    a_u = abs(P + D * omitted) * amplitude
    if not (a_u > level > 0.0):
        return 0.0
    return math.log(a_u / level) / -omitted.real


def _u_noise(t: np.ndarray, u: np.ndarray, release: float) -> float:
    """u's own white-noise sd, N: the held segment's sd (≥ 16 samples before the release), else
    the second-difference estimate on the record's last 4096 samples; at least q/√12 for a u
    quantised in steps q (the smallest nonzero change between samples: an ADC's step, whose
    held segment may read one constant value)."""
    held = u[t < release]
    sd = float(np.std(held, ddof=1)) if held.size >= 16 else diff_noise(u[-4096:])
    du = np.abs(np.diff(u))
    du = du[du > 0]
    return max(sd, float(du.min()) / math.sqrt(12.0) if du.size else 0.0)


def _modes_of(fit: DecayFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x model's modes: roots (1/s), complex amplitudes at t_ref (m), and whether each
    amplitude's imaginary part is a parameter (False for a real fast root)."""
    c0 = -1j * fit.amplitude * np.exp(-1j * fit.phase)  # A e^{−στ} sin(ωτ − φ) = Re(C₀e^{sτ})
    roots = [complex(-fit.sigma, fit.omega_d)] + [complex(r) for r, _a in fit.fast_modes]
    amps = [c0] + [complex(a) if complex(r).imag != 0 else complex(complex(a).real, 0.0)
                   for r, a in fit.fast_modes]
    cplx = [True] + [complex(r).imag != 0 for r, _a in fit.fast_modes]
    return np.array(roots), np.array(amps), np.array(cplx)


class _Joint:
    """Residuals and Jacobian of the joint x–u model of one run.

    Parameters θ = (x_off, Re C₀, Im C₀, σ, ω_d, fast amplitudes…, u_off, g, Δt).
    """

    def __init__(self, tx, x, tu, u, t_ref, fast_roots, cplx, P, D):
        self.tx, self.x, self.tu, self.u = tx, x, tu, u
        self.t_ref = t_ref
        self.fast = np.asarray(fast_roots, dtype=complex)
        self.cplx = np.asarray(cplx, dtype=bool)
        self.P, self.D = P, D
        self.nf = self.fast.size
        self.nfp = int(self.nf + np.count_nonzero(self.cplx[1:]))

    def pack(self, off, amps, sigma, omega, u_off, g, delay):
        fa = []
        for a, cx in zip(amps[1:], self.cplx[1:], strict=True):
            fa.extend([a.real, a.imag] if cx else [a.real])
        return np.array([off, amps[0].real, amps[0].imag, sigma, omega, *fa, u_off, g, delay])

    def unpack(self, th):
        amps = [complex(th[1], th[2])]
        j = 5
        for cx in self.cplx[1:]:
            if cx:
                amps.append(complex(th[j], th[j + 1]))
                j += 2
            else:
                amps.append(complex(th[j], 0.0))
                j += 1
        s = complex(-th[3], th[4])
        return (th[0], np.array([s, *self.fast]), np.array(amps), th[j], th[j + 1], th[j + 2])

    def evaluate(self, th, wx=1.0, wu=1.0, jac=True):
        """Weighted residuals (x rows, then u rows) and their Jacobian (n_x + n_u, p; None
        without ``jac``)."""
        off, roots, amps, u_off, g, delay = self.unpack(th)
        nx, p = self.tx.size, th.size
        K = -(self.P + self.D * roots)  # u's factor per mode (eq. 23)
        tau = self.tx - self.t_ref
        tq = self.tu - delay - self.t_ref
        Ex = np.exp(np.outer(tau, roots))  # (n_x, modes)
        Eu = np.exp(np.outer(tq, roots))  # (n_u, modes)
        V = np.real(Eu @ (K * amps))
        r = np.empty(nx + self.tu.size)
        r[:nx] = wx * (self.x - off - np.real(Ex @ amps))
        r[nx:] = wu * (self.u - u_off - g * V)
        if not jac:
            return r, None
        J = np.zeros((r.size, p))
        Jx, Ju = J[:nx], J[nx:]
        # columns: the derivative of each model's complex mode sum, real part
        cx = np.empty((nx, p - 4), dtype=complex)
        cu = np.empty((self.tu.size, p - 4), dtype=complex)
        cx[:, 0], cx[:, 1] = Ex[:, 0], 1j * Ex[:, 0]
        cx[:, 2] = -amps[0] * tau * Ex[:, 0]  # ∂/∂σ = −∂/∂s
        cx[:, 3] = 1j * amps[0] * tau * Ex[:, 0]  # ∂/∂ω = i ∂/∂s
        e0 = K[0] * Eu[:, 0]
        cu[:, 0], cu[:, 1] = e0, 1j * e0
        dsu = amps[0] * Eu[:, 0] * (K[0] * tq - self.D)  # ∂/∂s of −(P + Ds) C₀ e^{s tq}
        cu[:, 2], cu[:, 3] = -dsu, 1j * dsu
        j = 4
        for m_, cplx in enumerate(self.cplx[1:], start=1):
            cx[:, j], cu[:, j] = Ex[:, m_], K[m_] * Eu[:, m_]
            if cplx:
                cx[:, j + 1], cu[:, j + 1] = 1j * Ex[:, m_], 1j * K[m_] * Eu[:, m_]
                j += 2
            else:
                j += 1
        Jx[:, 0] = wx
        Jx[:, 1 : p - 3] = wx * cx.real
        Ju[:, 1 : p - 3] = (wu * g) * cu.real
        Ju[:, p - 3] = wu
        Ju[:, p - 2] = wu * V
        Ju[:, p - 1] = -(wu * g) * np.real(Eu @ (K * amps * roots))  # −g V′(t − Δt)
        return r, J


def _gauss_newton(model: _Joint, th, wx, wu, free=None):
    """Weighted Gauss–Newton with step halving; ``free`` (bool mask) fixes the others. Stops
    when a step is below 1e-4 of each free parameter's scale (the column norm of the weighted
    Jacobian: about its standard error) or the weighted sum of squares stops falling (by ≤ 1e-10
    of itself)."""
    free = np.ones(th.size, dtype=bool) if free is None else free
    r, J = model.evaluate(th, wx, wu)
    f = float(r @ r)
    for _ in range(_MAXIT):
        Jf = J[:, free]
        scale = np.linalg.norm(Jf, axis=0)
        scale[scale == 0] = 1.0
        Js = Jf / scale
        step = np.zeros(th.size)
        try:  # scaled normal equations (p ≤ ~12 columns, well scaled): cheaper than an SVD
            step[free] = np.linalg.solve(Js.T @ Js, Js.T @ r) / scale
        except np.linalg.LinAlgError:
            step[free] = np.linalg.lstsq(Js, r, rcond=None)[0] / scale
        lam = 1.0
        while lam > 1e-6:
            r_t, _ = model.evaluate(th + lam * step, wx, wu, jac=False)
            f_t = float(r_t @ r_t)
            if np.isfinite(f_t) and f_t <= f * (1 + 1e-12):
                break
            lam *= 0.5
        else:
            break
        # converged: a step below 1e-4 stderr, or no more than rounding-level progress
        done = np.all(np.abs(lam * step[free]) * scale <= 1e-4) or f - f_t <= 1e-10 * f
        th, f = th + lam * step, f_t
        r, J = model.evaluate(th, wx, wu)
        if done:
            break
    return th, J


def fit_run(
    t: np.ndarray,
    x: np.ndarray,
    u: np.ndarray,
    fit: DecayFit,
    P: float,
    D: float,
    delay: float,
    *,
    delay_sd: float = 0.0,
    omitted: complex | None = None,
    omitted_amplitude: float = 0.0,
) -> URun:
    """Joint fit of one run's x and u for its dominant mode and loop delay.

    Parameters
    ----------
    t, x, u : ndarray
        Sample times (s), position (m) and the recorded feedback force (N).
    fit : DecayFit
        The run's decay fit (its window, modes and fast modes start the joint fit).
    P, D : float
        Gains, N/m and N s/m.
    delay : float
        Starting Δt, s (e.g. the x-only estimate).
    delay_sd : float
        Uncertainty of that start, s: the u window starts 5 of them (and 2 samples) after the
        delayed start of the x window, so that every plausible Δt maps it into the x model's
        domain.
    omitted, omitted_amplitude : complex, float
        The first loop root left out of the x model (1/s) and its amplitude in x (m); sets u's
        extra skip (:func:`u_skip`).

    Returns
    -------
    URun
        Unused (with its ``reason``) when u is constant, clipped, of the wrong sign or scale,
        misfits, or too short.

    Notes
    -----
    Model (module docstring): x = x_off + Re Σⱼ Cⱼ e^{sⱼτ}, τ = t − t_ref ≥ 0, and
    u = u_off + g Re Σⱼ −(P + D sⱼ) Cⱼ e^{sⱼ(τ − Δt)} (eq. 23). Weighted least squares with
    weights 1/σ_x², 1/σ_u², each variance RSS/(n − p) of its own signal (p: the parameters that
    signal alone would need: the x model's, and 3 for u on top of it); covariance (JᵀWJ)⁻¹.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if not np.ptp(u) > 0:
        return URun(used=False, reason="u is constant")
    inx = (t >= fit.t_start) & (t <= fit.t_end)
    scale_u = float(np.max(np.abs(u - np.median(u))))
    noise_u0 = max(_u_noise(t, u, fit.release), _U_RESOLUTION * scale_u)
    level = _OMIT_NOISE_FRACTION * noise_u0
    dt = float(np.median(np.diff(t)))
    u_start = (fit.t_start + delay + 5.0 * delay_sd + 2.0 * dt
               + u_skip(omitted, omitted_amplitude, P, D, level))
    inu = (t >= u_start) & (t <= fit.t_end + delay)
    if np.count_nonzero(inu) < _MIN_U_SAMPLES:
        return URun(used=False, reason="too few u samples after the release and the loop's "
                                       "fast modes")
    tu, uu = t[inu], u[inu]
    if not np.ptp(uu) > 10.0 * noise_u0:
        return URun(used=False, reason="u is constant after the release (no feedback recorded)")
    roots, amps, cplx = _modes_of(fit)
    model = _Joint(t[inx], x[inx], tu, uu, fit.t_ref, roots[1:], cplx, float(P), float(D))
    th = model.pack(fit.offset, amps, fit.sigma, fit.omega_d, 0.0, 1.0, delay)
    p_x = th.size - 3
    # 1. u's offset, gain and delay with the x model fixed (its start; also u's noise level)
    fixed_x = np.zeros(th.size, dtype=bool)
    fixed_x[-3:] = True
    nx = model.tx.size
    u_only = _Joint(t[:0], x[:0], tu, uu, fit.t_ref, roots[1:], cplx, float(P), float(D))
    _r, J0 = u_only.evaluate(th)
    pred = J0[:, -2]  # the force the gains imply, −(P x + D ẋ)(t − Δt), from the x fit (g = 1)
    if is_clipped(uu, uu - (pred + float(np.median(uu - pred))), noise_u0):
        return URun(used=False, reason="clipped u: flat tops at its extreme value that the "
                                       "force −(P x + D ẋ)(t − Δt) exceeds (saturated "
                                       "amplifier?)")
    lin = np.linalg.lstsq(np.c_[np.ones(tu.size), J0[:, -2]], uu, rcond=None)[0]
    th[-3], th[-2] = lin
    th, _J = _gauss_newton(u_only, th, 0.0, 1.0, free=fixed_x)
    g = float(th[-2])
    if not g > 0:
        return URun(used=False, reason=f"u has the opposite sign of −(P x + D ẋ)(t − Δt) "
                                       f"(fitted scale {g:.3g}): check the sign convention of u")
    if not GAIN_RANGE[0] <= g <= GAIN_RANGE[1]:
        return URun(used=False, reason=f"u is {g:.3g} times the force the gains imply, "
                                       f"−(P x + D ẋ)(t − Δt) (accepted: {GAIN_RANGE[0]:g}–"
                                       f"{GAIN_RANGE[1]:g}): check u's units or amplifier gain")
    # 2. everything together, each signal weighted by its own noise variance
    r, _J = model.evaluate(th)
    ru = r[nx:]
    sx = max(fit.noise_sd, 1e-300)
    su = max(math.sqrt(float(ru @ ru) / max(ru.size - 3, 1)), 1e-15 * scale_u, 1e-300)
    for _ in range(2):
        th, _J = _gauss_newton(model, th, 1.0 / sx, 1.0 / su)
        r, J = model.evaluate(th)
        rx, ru = r[:nx], r[nx:]
        sx = max(math.sqrt(float(rx @ rx) / max(rx.size - p_x, 1)), 1e-300)
        su = max(math.sqrt(float(ru @ ru) / max(ru.size - 3, 1)), 1e-15 * scale_u, 1e-300)
    if su > _MISFIT_RATIO * noise_u0:
        return URun(used=False, reason=f"u does not follow −(P x + D ẋ)(t − Δt) of the x fit: "
                                       f"residual rms {su:.3g} N, {su / max(noise_u0, 1e-300):.3g}"
                                       " times u's own noise")
    J = np.r_[J[:nx] / sx, J[nx:] / su]
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return URun(used=False, reason="the joint x–u fit has no usable covariance")
    idx = [3, 4, th.size - 1]
    c3 = cov[np.ix_(idx, idx)]
    if not (np.all(np.isfinite(c3)) and np.all(np.diag(c3) > 0)):
        return URun(used=False, reason="the joint x–u fit has no usable covariance")
    return URun(
        used=True, sigma=float(th[3]), omega_d=float(th[4]), delay=float(th[-1]), cov=c3,
        gain=float(th[-2]), gain_stderr=math.sqrt(max(float(cov[-2, -2]), 0.0)),
        u_offset=float(th[-3]), noise_u=su, noise_x=sx, n_u=int(tu.size),
        u_start=float(tu[0]),
    )


def _whiten(cov: np.ndarray) -> np.ndarray:
    """W^{1/2} (lower-triangular inverse Cholesky factor) of each (3, 3) covariance, with a zero
    last row and column where the delay was not measured (nan there)."""
    out = np.zeros_like(cov)
    for i, C in enumerate(cov):
        k = 3 if np.isfinite(C[2, 2]) else 2
        out[i, :k, :k] = np.linalg.inv(np.linalg.cholesky(C[:k, :k]))
    return out


def combine(
    sigma: np.ndarray,
    omega_d: np.ndarray,
    delay_meas: np.ndarray,
    cov: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    start: Sequence[float],
    *,
    added_mass: np.ndarray | None = None,
    max_iter: int = 50,
) -> UDelayFit:
    """Weighted least squares of (m, c, k, Δt) to every run's (σᵢ, ω_dᵢ[, Δtᵢ]).

    Parameters
    ----------
    sigma, omega_d : array_like
        Measured σᵢ (1/s) and ω_dᵢ (rad/s) of each run's dominant mode.
    delay_meas : array_like
        Each run's delay Δtᵢ from its u (s); nan where the run's u was not used.
    cov : array_like, shape (n, 3, 3)
        Covariance of (σᵢ, ω_dᵢ, Δtᵢ) (the last row and column nan where Δtᵢ is nan).
    P, D : array_like
        Gains, N/m and N s/m.
    start : (m, c, k, Δt)
        Starting point (e.g. the x-only estimate).
    added_mass : array_like, optional
        Known mass added per run, kg (run i's loop has mass m + Δmᵢ).
    max_iter : int
        Gauss–Newton iterations at most.

    Returns
    -------
    UDelayFit
        The minimiser of Σ rᵢᵀ Covᵢ⁻¹ rᵢ, rᵢ = (σ̂ᵢ − σᵢ(θ), ω̂ᵢ − ωᵢ(θ), Δt̂ᵢ − Δt), sᵢ(θ) the
        dominant root of (m + Δmᵢ)s² + cs + k + (Dᵢs + Pᵢ)e^{−sΔt} = 0 (eq. 23), with covariance
        (JᵀWJ)⁻¹, ∂s/∂θ = −(s², s, 1, −s(Ds + P)e^{−sΔt})/f′(s). When χ² exceeds its 99.9 %
        quantile the covariance is scaled by χ²/dof and a warning says so.

    Raises
    ------
    IdentificationError
        When the fit does not converge, or a tracked root is not the dominant one.
    """
    from phoid.methods.pho import damped_gauss_newton, dominant_many

    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    dmeas = np.asarray(delay_meas, dtype=float)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    n = sigma.size
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    cov = np.array(cov, dtype=float).reshape(n, 3, 3)
    has = np.isfinite(dmeas)
    # numerical floor as in phoid.methods.pho.fit_modes: 1e-9 of |sᵢ| (and of Δt's scale 1/|sᵢ|)
    sabs = np.hypot(sigma, omega_d)
    cov[:, 0, 0] += (1e-9 * sabs) ** 2
    cov[:, 1, 1] += (1e-9 * sabs) ** 2
    cov[has, 2, 2] += (1e-9 / sabs[has]) ** 2
    Wh = _whiten(cov)
    meas = np.c_[sigma, omega_d, np.where(has, dmeas, 0.0)]
    theta = np.array(start, dtype=float)

    def residual_and_jacobian(th, s_guess):
        m, c, k, tau = th
        s = dominant_roots(m + dm, c, k, P, D, tau, s_guess)
        _, df = characteristic(s, m + dm, c, k, P, D, tau)
        cols = [s**2, s, np.ones_like(s), -s * (D * s + P) * np.exp(-s * tau)]
        ds = -np.stack(cols, axis=1) / df[:, None]
        model = np.c_[-s.real, s.imag, np.full(n, tau)]
        jac = np.stack([ds.real, -ds.imag, np.tile([0.0, 0.0, 0.0, -1.0], (n, 1))], axis=1)
        r = np.einsum("nij,nj->ni", Wh, meas - model).ravel()
        J = np.einsum("nij,njk->nik", Wh, jac).reshape(-1, 4)
        return r, J, s

    scale = np.maximum(np.abs(theta), [1e-300, float(np.max(D)) + 1e-300,
                                       float(np.max(P)) + 1e-300, 1e-3 / float(np.max(sabs))])
    theta, _r, J, s, chi2, converged = damped_gauss_newton(
        residual_and_jacobian, theta, -sigma + 1j * omega_d, scale,
        lambda th: th[0] > 0 and th[3] >= 0, max_iter)
    if not converged:
        raise IdentificationError("the weighted fit of m, c, k and the delay (x and u) did not "
                                  "converge")
    m, c, k, tau = (float(v) for v in theta)
    if not np.all(dom := dominant_many(s, m + dm, c, k, P, D, tau)):
        raise IdentificationError(f"run {int(np.argmin(dom)) + 1}: the fitted mode is not the "
                                  "loop's dominant root at the solution (x and u)")
    covp = np.linalg.inv(J.T @ J)
    dof = int(2 * n + np.count_nonzero(has) - 4)
    warnings: list[str] = []
    if dof > 0 and chi2 > chi2_isf(0.001, dof):
        red = chi2 / dof
        covp = covp * red
        warnings.append(
            f"the runs' modes and u-delays disagree more than their noise explains (χ²/dof = "
            f"{red:.2f}); stderr scaled up accordingly: check the delay, friction or "
            "unmodelled dynamics"
        )
    return UDelayFit(m=m, c=c, k=k, delay=tau, cov_full=covp, chi2=chi2, dof=dof,
                     n_u=int(np.count_nonzero(has)), warnings=tuple(warnings))


def check_u(u: Sequence[np.ndarray | None], data: Sequence[tuple[np.ndarray, np.ndarray]]
            ) -> list[np.ndarray | None]:
    """Each run's u as a float array (None kept), checked: one entry per run, as many samples
    as the run's t, finite values (N).

    Raises
    ------
    ValueError
        When it is not so.
    """
    u = list(u)
    if len(u) != len(data):
        raise ValueError(f"`u` must have one entry per run ({len(data)}); got {len(u)}")
    out: list[np.ndarray | None] = []
    for i, (ui, (t, _x)) in enumerate(zip(u, data, strict=True)):
        if ui is None:
            out.append(None)
            continue
        a = np.asarray(ui, dtype=float)
        if a.shape != np.shape(t):
            raise ValueError(f"`u` of run {i + 1} has shape {a.shape}; its t has {np.shape(t)}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"`u` of run {i + 1} has non-finite values")
        out.append(a)
    return out


def _omitted_modes(ident, P, D, dm, n_fast):
    """Per run: the first loop root left out of its x model and its amplitude in x (m), from the
    identified plant and delay (None where the roots are not available)."""
    from phoid.dynamics import rightmost_roots_many

    n = len(ident.runs)
    out: list[tuple[complex, float] | None] = [None] * n
    m, c, k, tau = ident.m.value, ident.c.value, ident.k.value, ident.delay
    todo = [i for i, r in enumerate(ident.runs) if r.fit is not None]
    for added in np.unique(dm[todo]) if todo else []:
        grp = [i for i in todo if dm[i] == added]
        try:
            roots = rightmost_roots_many(m + added, c, k, P[grp], D[grp], tau,
                                          count=2 * n_fast + 4)
        except (RuntimeError, ValueError):
            continue
        for i, r in zip(grp, roots, strict=True):
            fit = ident.runs[i].fit
            modes = distinct_modes(r)
            j = 1 + len(fit.fast_modes)
            if j >= len(modes):
                continue
            q = modes[j]
            x0 = float(np.max(np.abs(np.asarray(ident.data[i][1]) - fit.offset)))
            a = 2.0 * abs(mode_residue(q, m + added, c, k, float(P[i]), float(D[i]), tau)) * x0
            out[i] = (q, a)
    return out


def _fit_runs(ident, u, P, D, dm, names, n_fast):
    """:func:`fit_run` for every usable run that records u (None elsewhere), and the notes on
    each u set aside."""
    n = len(ident.runs)
    omitted = _omitted_modes(ident, P, D, dm, n_fast)
    out: list[URun | None] = [None] * n
    notes: list[str] = []
    sd = ident.delay_stderr or 0.0
    for i, run in enumerate(ident.runs):
        if u[i] is None or not run.used or run.fit is None:
            continue
        t, x = ident.data[i]
        if omitted[i] is None and run.fit.fast_modes:
            out[i] = URun(used=False, reason="the loop's roots for u's transient are not "
                                             "available")
        else:
            q, a = omitted[i] if omitted[i] is not None else (None, 0.0)
            try:
                out[i] = fit_run(t, x, u[i], run.fit, float(P[i]), float(D[i]), ident.delay,
                                 delay_sd=sd, omitted=q, omitted_amplitude=a)
            except (ValueError, np.linalg.LinAlgError) as exc:
                out[i] = URun(used=False, reason=f"the joint x–u fit failed: {exc}")
        r = out[i]
        if not r.used:
            notes.append(f"{names[i]}: u not used for the delay: {r.reason}")
        elif abs(r.gain - 1.0) > max(_GAIN_NOTE, 5.0 * r.gain_stderr):
            notes.append(f"{names[i]}: u is {r.gain:.4g} ± {r.gain_stderr:.2g} times the force "
                         "the gains imply: used for the delay's timing only (its scale is "
                         "free); check u's calibration")
    return out, notes


def with_u(ident, u, P, D, *, names, rerun, added_mass=None, n_fast=2):
    """An x-only identification with an estimated delay, refined with the runs' recorded u.

    Parameters
    ----------
    ident : phoid.methods.pho_result.Identification
        The x-only result (delay estimated with m, c, k).
    u : sequence of ndarray or None
        Each run's recorded feedback force, N (None: not recorded).
    P, D : ndarray
        Gains, N/m and N s/m.
    names : sequence of str
        Run names for messages.
    rerun : callable
        ``rerun(delay)`` → the x-only identification with the transient skip and fast modes
        taken at ``delay`` (the delay is estimated again from there).
    added_mass : ndarray, optional
        Known mass added per run, kg.
    n_fast : int
        Fast modes the x fits hold (for the first one left out).

    Returns
    -------
    Identification
        With m, c, k and the delay from :func:`combine` (``delay_from = "x+u"``), or the x-only
        result with ``delay_from = "x"`` and the reasons in its warnings when no run's u is
        usable. The pipeline is rerun at the new delay until it moves by ≤ 0.1 stderr (at most
        three times), so the x fits' transient modes belong to the delay reported.
    """
    from dataclasses import replace

    from phoid.dynamics import inverse_map
    from phoid.methods.estimate import Estimate

    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    n = len(ident.runs)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    tau_run = ident.delay
    sd_x = ident.delay_stderr or 0.0
    uf = None
    for _ in range(3):
        uruns, notes = _fit_runs(ident, u, P, D, dm, names, n_fast)
        used = [i for i, r in enumerate(ident.runs) if r.used]
        if not any(uruns[i] is not None and uruns[i].used for i in used):
            return replace(ident, delay_from="x", warnings=tuple(notes) + ident.warnings)
        sig, wd, dl = np.empty(len(used)), np.empty(len(used)), np.full(len(used), np.nan)
        cov = np.full((len(used), 3, 3), np.nan)
        for j, i in enumerate(used):
            ur = uruns[i]
            if ur is not None and ur.used:
                sig[j], wd[j], dl[j], cov[j] = ur.sigma, ur.omega_d, ur.delay, ur.cov
            else:
                f = ident.runs[i].fit
                sig[j], wd[j], cov[j, :2, :2] = f.sigma, f.omega_d, f.cov
        try:
            uf = combine(sig, wd, dl, cov, P[used], D[used],
                         (ident.m.value, ident.c.value, ident.k.value, ident.delay),
                         added_mass=dm[used])
        except (IdentificationError, np.linalg.LinAlgError) as exc:
            # the x-only result stands; say why u did not serve
            return replace(ident, delay_from="x", warnings=(
                *notes, f"the recorded u was not used for the delay: {exc}", *ident.warnings))
        # the x fits' fast modes and skip depend on the delay only weakly: rerun them when the
        # delay moved by more than 0.1 of the x-only stderr (the rule of the x-only estimate)
        if abs(uf.delay - tau_run) <= 0.1 * sd_x + 1e-12 * max(tau_run, 1.0):
            break
        tau_run = uf.delay
        ident = rerun(uf.delay)
    assert uf is not None
    se = np.sqrt(np.clip(np.diag(uf.cov_full), 0.0, None))
    sig_r = np.array([ident.runs[i].sigma for i in used])
    wd_r = np.array([ident.runs[i].omega_d for i in used])
    cp, kp = inverse_map(sig_r, wd_r, P[used], D[used], uf.delay)
    cp = cp - 2.0 * dm[used] * sig_r
    kp = kp - dm[used] * (sig_r**2 + wd_r**2)
    fit = replace(ident.fit, m=uf.m, c=uf.c, k=uf.k, cov=uf.cov_full[:3, :3], delay=uf.delay,
                  delay_stderr=uf.delay_stderr, cov_full=uf.cov_full, chi2=uf.chi2, dof=uf.dof,
                  c_prime=cp, k_prime=kp,
                  warnings=tuple(w for w in ident.fit.warnings if "disagree" not in w)
                  + uf.warnings)
    runs = list(ident.runs)
    for j, i in enumerate(used):
        extra = () if uruns[i] is None or uruns[i].used else (f"u not used: {uruns[i].reason}",)
        runs[i] = replace(runs[i], c_prime=float(cp[j]), k_prime=float(kp[j]),
                          warnings=runs[i].warnings + extra, u_fit=uruns[i])
    warnings = [w for w in ident.warnings if w not in ident.fit.warnings
                and not w.startswith("the loop delay is poorly determined")] + list(uf.warnings)
    if uf.delay_stderr > 0.2 * uf.delay:
        warnings.insert(0, f"the loop delay is poorly determined ({uf.delay:.4g} ± "
                           f"{uf.delay_stderr:.2g} s), even with u")
    return replace(
        ident, m=Estimate(uf.m, float(se[0]), "kg"), c=Estimate(uf.c, float(se[1]), "N s/m"),
        k=Estimate(uf.k, float(se[2]), "N/m"), delay=uf.delay, delay_stderr=uf.delay_stderr,
        delay_source="estimated", delay_from="x+u", fit=fit, runs=tuple(runs),
        warnings=tuple(notes) + tuple(warnings),
    )
