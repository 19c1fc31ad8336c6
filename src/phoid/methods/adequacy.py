r"""Model adequacy: does the fitted model explain the record, and what uncertainty survives if not.

Every identification method fits a model to records and reports white-noise least-squares
standard errors, which are the Cramér–Rao bound only when the model is the record's own and the
residual is white noise. This module tests that on the residual and, where a test fails, gives
a standard error that accounts for the misfit and a warning in the user's terms. It is pure:
functions over arrays and small frozen results, shared by every method (free decay in
:mod:`phoid.methods.free`; the others call the same functions). docs/adequacy.md gives the
reasoning and the measurements behind every threshold.

The checks (each a :class:`Check`)
----------------------------------
``noise`` — the residual against the record's own noise level ŝ, estimated without the model
(:func:`phoid.methods.fit_statistics.difference_noise`): per run the ratio r = RMS(e)/ŝ. With
the right model r = √((n − p)/n) ≈ 1 with an sd of about 1.7/√n (fit_statistics' docstring).
It fails when r > 1 + max(0.1, 10/√n): 10/√n is ~6 sd of the ratio's own spread (no false
alarm on any record length), and the floor 0.1 covers the noise estimator's bias on records
whose noise is not Gaussian (quantisation, spikes) or whose motion is coarsely sampled (a
smooth motion adds up to (ωΔt)³A to a third difference). χ² = Σ nᵢ rᵢ² is reported beside it.

``whiteness`` — the Ljung–Box statistic of each run's residual,
Q = n(n + 2) Σ_{k=1}^{h} ρ̂ₖ²/(n − k), ρ̂ₖ the residual's lag-k autocorrelation, with
h = min(20, ⌊n/5⌋) lags (Ljung and Box, 1978: for white noise Q ~ χ²_h; 20 lags see the
sample-to-sample correlation of coloured noise and the slow swing of a model error, while the
χ² approximation still holds at n/5). The runs' Q add up (independent records), and the test
fails when P(χ²_{Σh} ≥ ΣQ) < α = 10⁻³ (:func:`phoid.methods.chi2.chi2_sf`): a simulated
set with white noise trips it once in a thousand.

``structure`` — the decay rate σ and the damped frequency ω_d of windows of a few cycles (each
window fitted alone with the same model; :func:`phoid.methods._modal.window_rates` for the
free response) against the window's amplitude A, by weighted least squares y = a + bA with
weights 1/se², the slope's stderr scaled by √max(1, χ²/dof) of the regression (the windows'
own scatter: never smaller than their stderr say). A slope is significant when
|b|/se(b) > 3.29 (two-sided α = 10⁻³ for a normal statistic; with the scaling never more often
than that under the model). The cause in the user's terms: σ rising as the amplitude falls →
Coulomb friction (a constant friction force removes a constant amplitude per cycle: the local
rate q/A grows as A falls), the more so when the motion ends stuck; σ falling as the amplitude
falls → amplitude-dependent damping (drag ∝ v|v|: σ ∝ A); ω_d changing with A →
amplitude-dependent stiffness (Duffing: ω² ≈ ω₀² + ¾βA²).

``halves`` and ``runs`` — agreement between parts of the data, each fitted alone with its
robust covariance Cᵢ: χ² = Σᵢ (θᵢ − θ̄)ᵀCᵢ⁻¹(θᵢ − θ̄), θ̄ the inverse-covariance weighted
mean, dof = p(k − 1), failing at P(χ²_dof ≥ χ²) < α (:func:`agreement`).

The residual's spectrum (:func:`spectral_peak`) tells a second mode from coloured noise when the
residual is not white and the windows show no trend (a trend explains the residual: the
sidebands of a drifting frequency are no second mode).

Uncertainty that survives misfit
--------------------------------
:func:`sandwich` is the Newey–West covariance (:func:`phoid.fits.hac.hac_covariance`,
prewhitened, Andrews' lag window) of the fit from its Jacobian and residual: the residual of a
misfit is a slow, correlated error, and the sandwich counts its correlation. Where the
parameters drift along the record (the halves or the runs disagree, or the windows show a
trend), no single value describes the record and the sandwich alone measures only how well the
fit pins down a weighted average; the spread between the parts is added as a batch-means
variance (:func:`agreement`'s ``between``: for the runs the covariance of their mean, S/k with S
their sample covariance; for the halves of a drifting record S itself, d dᵀ/2 for halves
differing by d — the parameter is not one number along the record, and the value the whole
fit reports depends on how it weighs the parts). :func:`assess`
gives the robust covariance only when a check fails; where every check passes the white-noise
covariance stands unchanged (no inflation where the model is right: docs/adequacy.md measures
the sandwich against it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phoid._notation import unit_text
from phoid.fits.hac import hac_covariance
from phoid.methods.chi2 import chi2_isf, chi2_sf
from phoid.methods.envelope import Envelope, envelope_test, normal_isf, t_isf, turning_points

__all__ = [
    "ALPHA",
    "Adequacy",
    "Agreement",
    "Check",
    "Envelope",
    "Windows",
    "agreement",
    "assess",
    "envelope_test",
    "ljung_box",
    "noise_check",
    "noise_threshold",
    "normal_isf",
    "not_below_white",
    "residual_warnings",
    "sandwich",
    "spectral_peak",
    "structure_check",
    "t_isf",
    "turning_points",
    "whiteness_check",
]

#: false-alarm probability of every test (a simulated set trips one once in a thousand)
ALPHA = 1e-3
#: multiples of the motion's band excluded from the second-mode search: a Coulomb or cubic
#: decay's odd harmonics reach the 7th on the real torsion pendulum (152.5 rad/s at ω₀ 21.8)
_HARMONICS = 9
#: |slope|/stderr beyond which a trend against amplitude is significant (two-sided 1e-3)
T_SLOPE = 3.29
#: a residual below this fraction of the motion's RMS is rounding: the checks do not apply
_EXACT = 1e-7


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


@dataclass(frozen=True)
class Check:
    """One adequacy test.

    Attributes
    ----------
    name : str
        ``"noise"``, ``"whiteness"``, ``"structure"``, ``"halves"`` or ``"runs"``.
    statistic : float
        The test's statistic (the residual/noise ratio; Ljung–Box Q; the largest
        |slope|/stderr; the agreement χ²).
    threshold : float
        The value beyond which it fails (for Q and χ² their upper quantile at α).
    passed : bool or None
        None when the test does not apply (too few windows, one run, a noise-free record).
    detail : str
        What it saw, in words.
    """

    name: str
    statistic: float
    threshold: float
    passed: bool | None
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (non-finite numbers as null)."""
        return {"name": self.name, "statistic": _num(self.statistic),
                "threshold": _num(self.threshold), "passed": self.passed,
                "detail": self.detail}


@dataclass(frozen=True)
class Agreement:
    """Result of :func:`agreement`: the check and the between-parts covariance of their mean
    (p × p, same parameters as the inputs)."""

    check: Check
    between: np.ndarray = field(repr=False)
    what: str = ""

    def warning(self) -> str | None:
        """The warning of a failed check, in the user's terms; None when it passed."""
        if self.check.passed is not False:
            return None
        if self.check.name == "halves":
            return (f"the halves of the record disagree ({self.what}): the parameters drift "
                    "along the record, the model does not hold over its whole length; the "
                    "stderr include the spread between the halves")
        return (f"the runs disagree ({self.what}): are they of one plant under the same "
                "conditions? The stderr include the spread between the runs")


@dataclass(frozen=True)
class Windows:
    """Local estimates over windows of a few cycles (all runs together).

    Attributes
    ----------
    amplitude : ndarray
        Each window's motion amplitude (√2 × RMS of the fitted motion), in x's unit.
    sigma, sigma_se : ndarray
        Local decay rate and its stderr, 1/s.
    omega, omega_se : ndarray
        Local damped frequency ω_d and its stderr, rad/s.
    stuck : bool
        Whether a record ends at rest while the fitted model still moves there.
    stuck_detail : str
        Where it stopped, in words (empty when not stuck).
    """

    amplitude: np.ndarray
    sigma: np.ndarray
    sigma_se: np.ndarray
    omega: np.ndarray
    omega_se: np.ndarray
    stuck: bool = False
    stuck_detail: str = ""


@dataclass(frozen=True)
class Adequacy:
    """Adequacy of one fit: the checks, the warnings, both covariances.

    Attributes
    ----------
    checks : tuple of Check
    warnings : tuple of str
        One per failed check, in the user's terms (what it saw, the likely cause).
    causes : tuple of str
        Machine-readable causes: ``"misfit"``, ``"coloured"``, ``"coulomb"``,
        ``"amplitude_damping"``, ``"amplitude_stiffness"``, ``"second_mode"``, ``"drift"``,
        ``"runs_differ"``.
    names, units : tuple of str
        The parameters of the covariances.
    white_cov : ndarray
        The white-noise least-squares covariance.
    robust_cov : ndarray
        The covariance reported: the white one when every check passes, else the sandwich
        widened by the between-parts spread (module docstring).
    sandwich_cov : ndarray
        The Newey–West sandwich alone (nan when it could not be computed).
    stderr : str
        ``"white"`` or ``"robust"``: which of the two the estimates carry.
    stderr_note : str
        Where a check failed but the estimates keep the white-noise stderr (``stderr`` is
        ``"white"``): what those stderr are and why they stand (empty otherwise; the text
        report's ``[[Adequacy]]`` block prints it).
    """

    checks: tuple[Check, ...]
    warnings: tuple[str, ...]
    causes: tuple[str, ...]
    names: tuple[str, ...]
    units: tuple[str, ...]
    white_cov: np.ndarray = field(repr=False)
    robust_cov: np.ndarray = field(repr=False)
    sandwich_cov: np.ndarray = field(repr=False)
    stderr: str = "white"
    stderr_note: str = ""

    @property
    def passed(self) -> bool:
        """True when no applicable check failed."""
        return all(c.passed is not False for c in self.checks)

    @property
    def inflation(self) -> tuple[float, ...]:
        """Per parameter: reported stderr over white stderr (1 when the white one stands)."""
        w = np.sqrt(np.abs(np.diag(self.white_cov)))
        r = np.sqrt(np.abs(np.diag(self.robust_cov)))
        return tuple(float(a / b) if b > 0 else math.nan for a, b in zip(r, w, strict=True))

    def to_dict(self) -> dict[str, Any]:
        """The ``adequacy`` object of ``--json``: ``passed``, ``stderr`` ("white" or
        "robust"), ``checks`` (each ``name``, ``statistic``, ``threshold``, ``passed``,
        ``detail``), ``causes``, ``warnings``, ``params``, ``inflation`` (robust/white stderr
        per parameter), ``stderr_white``, ``stderr_sandwich`` and ``stderr_robust`` (per
        parameter, in ``units``)."""
        def se(c: np.ndarray) -> list[float | None]:
            return [_num(math.sqrt(v)) if v >= 0 else None for v in np.diag(c)]
        return {
            "passed": self.passed,
            "stderr": self.stderr,
            "checks": [c.to_dict() for c in self.checks],
            "causes": list(self.causes),
            "warnings": list(self.warnings),
            "params": list(self.names),
            "units": list(self.units),
            "inflation": [_num(x) for x in self.inflation],
            "stderr_white": se(self.white_cov),
            "stderr_sandwich": se(self.sandwich_cov),
            "stderr_robust": se(self.robust_cov),
        }


# --------------------------------------------------------------------------------------------
# the residual against the noise


def noise_threshold(n: int) -> float:
    """Largest residual/noise ratio that the right model reaches: 1 + max(0.1, 10/√n)."""
    return 1.0 + max(0.1, 10.0 / math.sqrt(max(n, 1)))


def _exact(residual: np.ndarray, motion_rms: float | None) -> bool:
    rms = float(np.sqrt(np.mean(residual * residual))) if residual.size else 0.0
    return motion_rms is not None and motion_rms > 0 and rms <= _EXACT * motion_rms


def noise_check(residuals: Sequence[np.ndarray], noise: Sequence[float | None],
                labels: Sequence[str], *, x_unit: str = "m") -> Check:
    """The residual against the record's own noise (module docstring).

    Parameters
    ----------
    residuals : sequence of ndarray
        Each run's fit residual, in x's unit.
    noise : sequence of float or None
        Each run's model-free noise sd ŝ (None: unknown, the run is left out).
    labels : sequence of str
        The runs' names, for the detail.
    x_unit : str
        x's unit, for the detail.

    Returns
    -------
    Check
        ``statistic``: the worst run's ratio; ``threshold``: its 1 + max(0.1, 10/√n).
    """
    worst: tuple[float, float, str, int] | None = None
    chi2, n_all = 0.0, 0
    for e, s, lab in zip(residuals, noise, labels, strict=True):
        e = np.asarray(e, dtype=float)
        if s is None or not (s > 0 and math.isfinite(s)) or e.size < 2:
            continue
        r = float(np.sqrt(np.mean(e * e))) / s
        thr = noise_threshold(e.size)
        chi2 += e.size * r * r
        n_all += e.size
        if worst is None or r / thr > worst[0] / worst[1]:
            worst = (r, thr, lab, e.size)
    if worst is None:
        return Check("noise", math.nan, math.nan, None, "no run with a usable noise level")
    r, thr, lab, _n = worst
    detail = (f"residual/noise {r:.3g} in {lab} (≤ {thr:.3g} when the model explains the "
              f"record to its noise; χ²/n = {chi2 / n_all:.3g} over all runs)")
    return Check("noise", r, thr, bool(r <= thr), detail)


# --------------------------------------------------------------------------------------------
# whiteness


def ljung_box(residual: Any, lags: int | None = None) -> tuple[float, int, float]:
    """Ljung–Box Q of a residual series (module docstring).

    Parameters
    ----------
    residual : array_like
        The residual (its mean is removed).
    lags : int, optional
        h; default min(20, ⌊n/5⌋).

    Returns
    -------
    (Q, h, lag1)
        The statistic, its lags (0 when the series is too short, n < 10, or constant) and the
        lag-1 autocorrelation.
    """
    e = np.asarray(residual, dtype=float).ravel()
    n = e.size
    h = min(20, n // 5) if lags is None else int(lags)
    e = e - e.mean() if n else e
    c0 = float(e @ e)
    if n < 10 or h < 1 or c0 <= 0:
        return 0.0, 0, 0.0
    h = min(h, n - 1)
    rho = np.array([float(e[k:] @ e[:-k]) / c0 for k in range(1, h + 1)])
    q = n * (n + 2) * float(np.sum(rho * rho / (n - np.arange(1, h + 1))))
    return q, h, float(rho[0])


def whiteness_check(residuals: Sequence[np.ndarray], *,
                    motion_rms: Sequence[float | None] | None = None,
                    alpha: float = ALPHA) -> Check:
    """The runs' residuals white? Σ Ljung–Box Q against χ²_{Σh} at ``alpha``.

    Parameters
    ----------
    residuals : sequence of ndarray
        Each run's residual (uniformly sampled).
    motion_rms : sequence of float, optional
        Each run's fitted-motion RMS: a run whose residual is below 10⁻⁷ of it is a noise-free
        record (rounding, not noise) and is left out.
    alpha : float
        False-alarm probability.

    Returns
    -------
    Check
        ``statistic``: ΣQ; ``threshold``: the χ²_{Σh} upper quantile at α; the detail gives
        the p-value.
    """
    q_all, h_all, lag1 = 0.0, 0, []
    for i, e in enumerate(residuals):
        e = np.asarray(e, dtype=float)
        if motion_rms is not None and _exact(e, motion_rms[i]):
            continue
        q, h, r1 = ljung_box(e)
        if h:
            q_all += q
            h_all += h
            lag1.append(r1)
    if h_all == 0:
        return Check("whiteness", math.nan, alpha, None,
                     "not tested (records too short or noise-free)")
    p = chi2_sf(q_all, float(h_all))
    detail = (f"Ljung–Box Q = {q_all:.4g} over {h_all} lags, p = {p:.2g} (white below "
              f"p = {alpha:g}); lag-1 autocorrelation {max(lag1, key=abs):.3f}")
    return Check("whiteness", q_all, chi2_isf(alpha, float(h_all)), bool(p >= alpha), detail)


def spectral_peak(residual: Any, dt: float, band: tuple[float, float] | None, *,
                  alpha: float = ALPHA) -> tuple[float, float] | None:
    """A narrow peak in the residual's spectrum away from the main oscillation and its harmonics.

    The Hann-windowed periodogram Iₖ of the residual is compared with the local level
    Ŝₖ = median(I over ±25 bins)/ln 2 (a periodogram ordinate of a smooth spectrum is
    S·χ²₂/2, whose median is S ln 2): a peak counts when Iₖ/Ŝₖ > ln(N/α), N the number of
    frequencies (false alarm α over the whole spectrum), and it lies outside the band
    [lo, hi] of frequencies the motion itself sweeps and its multiples [k·lo, k·hi],
    k = 1 … 9, each widened by 0.15·lo (harmonics of a nonlinear oscillation, the sidebands of
    one whose frequency drifts, are not a mode), and above 0.15·lo (a slow drift is not a
    mode).

    Parameters
    ----------
    residual : array_like
        Uniformly sampled residual.
    dt : float
        Sample interval, s.
    band : (float, float) or None
        The lowest and highest frequency of the motion, Hz (the fitted one, the record's own
        spectral peak, the windows' local ones; None: only DC is excluded).
    alpha : float

    Returns
    -------
    (frequency Hz, ratio) or None
    """
    e = np.asarray(residual, dtype=float).ravel()
    n = e.size
    if n < 64 or not dt > 0:
        return None
    spec = np.abs(np.fft.rfft((e - e.mean()) * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, dt)
    nb = spec.size
    keep = np.ones(nb, dtype=bool)
    keep[:3] = False
    if band is not None and band[0] > 0:
        lo, hi = band
        keep &= f > 0.15 * lo
        for k in range(1, _HARMONICS + 1):
            keep &= (f < k * lo - 0.15 * lo) | (f > k * hi + 0.15 * lo)
    if not keep.any():
        return None
    from scipy.ndimage import median_filter

    idx = np.flatnonzero(keep)
    # the local level: the running median over ±25 bins, truncated at the spectrum's ends
    # (one vectorised filter inside; the ≤ 50 end bins, whose windows are cut, one by one)
    med = median_filter(spec, size=51, mode="nearest")
    for i in (*range(min(25, nb)), *range(max(25, nb - 25), nb)):
        med[i] = np.median(spec[max(0, i - 25):min(nb, i + 26)])
    level = med[idx] / math.log(2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.where(level > 0, spec[idx] / np.where(level > 0, level, 1.0), 0.0)
    best = int(np.argmax(ratios))
    if ratios[best] > math.log(nb / alpha):
        return float(f[idx[best]]), float(ratios[best])
    return None


def residual_warnings(noise: Check, white: Check, causes: Sequence[str],
                      peak: tuple[float, float] | None) -> tuple[tuple[str, ...],
                                                                 tuple[str, ...]]:
    """The warnings of the residual tests, in the user's terms.

    Parameters
    ----------
    noise, white : Check
        :func:`noise_check` and :func:`whiteness_check`.
    causes : sequence of str
        The causes the structure check found (:func:`structure_check`).
    peak : (float, float) or None
        :func:`spectral_peak`.

    Returns
    -------
    (causes, warnings)
        ``"misfit"`` (the residual above the noise) with its numbers; ``"second_mode"`` for a
        peak; ``"coloured"`` when the residual is not white noise and nothing else explains it.
    """
    out_c: list[str] = []
    out_w: list[str] = []
    if noise.passed is False:
        out_c.append("misfit")
        out_w.append(f"the model misfits the record: residual/noise {noise.statistic:.3g} "
                     f"(at most {noise.threshold:.3g} when the model explains the record to its "
                     "noise); the stderr are robust ones (Newey–West), the white-noise ones "
                     "understate the uncertainty")
    if peak is not None and (noise.passed is False or white.passed is False):
        out_c.append("second_mode")
        out_w.append(f"the residual holds an oscillation at {peak[0]:.4g} Hz "
                     f"({2 * math.pi * peak[0]:.4g} rad/s, {peak[1]:.3g}× the residual's "
                     "spectrum around it): a second mode (or a disturbance at that frequency); "
                     "the model has one")
    elif not causes and (noise.passed is False or white.passed is False):
        out_c.append("coloured")
        out_w.append(f"the residual is not white noise ({white.detail}) and shows no trend with "
                     "the amplitude nor a second mode: coloured noise (a filtered sensor, a slow "
                     "disturbance) or a misfit phoid does not name; the stderr are Newey–West "
                     "ones that account for it")
    return tuple(out_c), tuple(out_w)


# --------------------------------------------------------------------------------------------
# structure against amplitude


def _slope(a: np.ndarray, y: np.ndarray, se: np.ndarray) -> tuple[float, float, float]:
    """Weighted y = c + bA: (b, t = b/se(b) with se scaled by √max(1, χ²/dof), mean y)."""
    ok = np.isfinite(y) & np.isfinite(se) & (se > 0) & np.isfinite(a)
    a, y, se = a[ok], y[ok], se[ok]
    if a.size < 4 or np.ptp(a) <= 0:
        return math.nan, 0.0, math.nan
    w = 1.0 / se**2
    X = np.column_stack([np.ones_like(a), a])
    XtW = X.T * w
    try:
        cov = np.linalg.inv(XtW @ X)
    except np.linalg.LinAlgError:
        return math.nan, 0.0, math.nan
    beta = cov @ (XtW @ y)
    r = y - X @ beta
    chi2 = float(w @ (r * r))
    scale = max(1.0, chi2 / (a.size - 2))
    se_b = math.sqrt(cov[1, 1] * scale)
    return float(beta[1]), float(beta[1] / se_b) if se_b > 0 else 0.0, float(np.mean(y))


def structure_check(win: Windows | None, *, x_unit: str = "m",
                    envelope: Envelope | None = None) -> tuple[Check, tuple[str, ...],
                                                               tuple[str, ...]]:
    """σ and ω_d against amplitude over the windows (module docstring).

    Parameters
    ----------
    win : Windows or None
        The local estimates (None or fewer than 4 usable windows: not applicable).
    x_unit : str
        x's unit, for the words.
    envelope : Envelope, optional
        :func:`envelope_test` on the turning points. Where there is one it decides how the
        decay rate depends on the amplitude (a constant loss, q > 0: Coulomb friction; q < 0:
        amplitude-dependent damping) in place of the windows' σ slope: it uses every half
        cycle and the turning points' own times, so a frequency that changes with the
        amplitude does not hide the rate's trend, as it can in windows fitted with one
        frequency each.

    Returns
    -------
    (Check, causes, warnings)
        The check (statistic: the largest of the |slope|/stderr of σ and ω_d and the
        envelope's |q|/stderr scaled to the same threshold, |t|·3.29/threshold), the causes
        found and their warnings; "coulomb" first when found.
    """
    has_win = win is not None and win.amplitude.size >= 4
    if not has_win and envelope is None:
        return (Check("structure", math.nan, T_SLOPE, None,
                      "not tested (fewer than 4 windows of a few cycles above the noise)"),
                (), ())
    causes: list[str] = []
    warns: list[str] = []
    parts: list[str] = []
    stat = 0.0
    stuck_w = win is not None and win.stuck
    stuck = f"; the motion ends stuck ({win.stuck_detail})" if stuck_w and win is not None else ""
    ts = tw = 0.0
    bs = 0.0
    if has_win and win is not None:
        a = win.amplitude
        bs, ts, _ = _slope(a, win.sigma, win.sigma_se)
        _bw, tw, _ = _slope(a, win.omega, win.omega_se)
        order = np.argsort(a)
        lo, hi = int(order[0]), int(order[-1])
        parts += [f"σ against amplitude: slope/stderr {ts:.3g}",
                  f"ω_d against amplitude: slope/stderr {tw:.3g} ({a.size} windows)"]
        stat = max(abs(ts), abs(tw))

        def at(y: np.ndarray, unit: str, fmt: str = ".4g") -> str:
            return (f"{y[hi]:{fmt}} {unit} at amplitude {a[hi]:.3g} {x_unit} to "
                    f"{y[lo]:{fmt}} {unit} at {a[lo]:.3g} {x_unit}")
    if envelope is not None:
        parts.append(envelope.detail(x_unit))
        stat = max(stat, abs(envelope.t) * T_SLOPE / envelope.threshold)
        if envelope.significant and envelope.loss > 0:
            causes.append("coulomb")
            warns.append(f"the amplitude falls by a constant amount besides its exponential "
                         f"decay ({envelope.detail(x_unit)}{stuck}): the decay rate rises as the "
                         "amplitude falls — Coulomb friction (linear amplitude loss, sticking), "
                         "not viscous damping; try `phoid identify SET --friction`")
        elif envelope.significant:
            causes.append("amplitude_damping")
            warns.append(f"the amplitude decays ever more slowly as it falls, beyond an "
                         f"exponential ({envelope.detail(x_unit)}): the decay rate falls as the "
                         "amplitude falls — amplitude-dependent damping (e.g. drag ∝ v|v|), "
                         "not viscous damping")
    elif has_win and win is not None and abs(ts) > T_SLOPE and bs < 0:
        causes.append("coulomb")
        warns.append(f"the decay rate rises as the amplitude falls (σ from {at(win.sigma, '1/s')}"
                     f"{stuck}): Coulomb friction (linear amplitude loss, sticking), not viscous "
                     "damping; try `phoid identify SET --friction`")
    elif has_win and win is not None and abs(ts) > T_SLOPE:
        causes.append("amplitude_damping")
        warns.append(f"the decay rate falls as the amplitude falls (σ from "
                     f"{at(win.sigma, '1/s')}): amplitude-dependent damping (e.g. drag ∝ v|v|), "
                     "not viscous damping")
    if has_win and win is not None and abs(tw) > T_SLOPE:
        causes.append("amplitude_stiffness")
        warns.append(f"the frequency changes with the amplitude (ω_d from "
                     f"{at(win.omega, 'rad/s', '.5g')}): amplitude-dependent stiffness, not a "
                     "linear spring")
    return (Check("structure", stat, T_SLOPE, not causes, "; ".join(parts)), tuple(causes),
            tuple(warns))


# --------------------------------------------------------------------------------------------
# agreement between parts


def agreement(name: str, values: Sequence[Any], covs: Sequence[Any], *,
              params: Sequence[str], units: Sequence[str], labels: Sequence[str],
              alpha: float = ALPHA, of_mean: bool = True) -> Agreement:
    """χ² of consistency of k independent estimates of the same parameters.

    χ² = Σᵢ (θᵢ − θ̄)ᵀCᵢ⁻¹(θᵢ − θ̄), θ̄ = (ΣCᵢ⁻¹)⁻¹ΣCᵢ⁻¹θᵢ, dof = p(k − 1); it fails when
    P(χ²_dof ≥ χ²) < α. The detail names the pair and the parameter that differ most, in
    combined stderr |θᵢ − θⱼ|/√(σᵢ² + σⱼ²). ``between`` = S/k, S the parts' sample covariance:
    the covariance of their mean (batch means; runs, random draws of one plant's conditions),
    or S itself with ``of_mean`` False (the halves of a drifting record: the parameter is not
    one number along it, and which value the whole record reports depends on how the fit
    weighs its parts; S = d dᵀ/2 for two halves differing by d).

    Parameters
    ----------
    name : str
        ``"halves"`` or ``"runs"``.
    values : sequence of array_like, each (p,)
    covs : sequence of array_like, each (p, p)
        Each part's (robust) covariance.
    params, units : sequence of str
        The parameters' names and units, for the words.
    labels : sequence of str
        The parts' names.
    alpha : float
    of_mean : bool
        ``between`` is S/k (True) or S (False).

    Returns
    -------
    Agreement
    """
    th = [np.asarray(v, dtype=float) for v in values]
    cs = [np.asarray(c, dtype=float) for c in covs]
    k, p = len(th), th[0].size if th else 0
    if k < 2:
        return Agreement(Check(name, math.nan, alpha, None, "fewer than two parts"),
                         np.zeros((p, p)))
    try:
        inv = [np.linalg.pinv(c) for c in cs]
        mean = np.linalg.solve(sum(inv), sum(i @ t for i, t in zip(inv, th, strict=True)))
    except np.linalg.LinAlgError:
        return Agreement(Check(name, math.nan, alpha, None, "singular covariance"),
                         np.zeros((p, p)))
    # a sum of quadratic forms of PSD matrices: ≥ 0 but for rounding (pinv of a covariance
    # near its precision's end can leave −1e−17)
    chi2 = max(float(sum((t - mean) @ i @ (t - mean) for i, t in zip(inv, th, strict=True))),
               0.0)
    dof = p * (k - 1)
    pv = chi2_sf(chi2, float(dof)) if math.isfinite(chi2) else 0.0
    best = (0.0, 0, 0, 1)
    for a in range(k):
        for b in range(a + 1, k):
            for j in range(p):
                comb = math.sqrt(max(cs[a][j, j] + cs[b][j, j], 0.0))
                z = abs(th[a][j] - th[b][j]) / comb if comb > 0 else math.inf
                if z > best[0]:
                    best = (z, j, a, b)
    z, j, a, b = best
    unit = f" {unit_text(units[j])}" if units[j] else ""
    what = (f"{params[j]} {th[a][j]:.4g}{unit} ({labels[a]}) vs {th[b][j]:.4g}{unit} "
            f"({labels[b]}), {z:.3g} combined stderr")
    detail = f"χ² = {chi2:.4g} on {dof} dof, p = {pv:.2g}; largest difference: {what}"
    dev = np.array(th) - np.mean(th, axis=0)
    between = dev.T @ dev / (k - 1) / (k if of_mean else 1)
    return Agreement(Check(name, chi2, chi2_isf(alpha, float(dof)), bool(pv >= alpha), detail),
                     between, what)


# --------------------------------------------------------------------------------------------
# covariance


def sandwich(jacobians: Sequence[np.ndarray], residuals: Sequence[np.ndarray], *,
             weights: Sequence[float] | None = None,
             nuisance: Sequence[np.ndarray | None] | None = None) -> np.ndarray:
    """Newey–West covariance of the parameters of a (weighted) least-squares fit.

    Parameters
    ----------
    jacobians : sequence of ndarray, each (nᵢ, p)
        ∂model/∂θ of each record at the estimate (the sign does not matter).
    residuals : sequence of ndarray, each (nᵢ,)
    weights : sequence of float, optional
        Each record's weight wᵢ of the fit (1/noiseᵢ²); rows are scaled by √wᵢ.
    nuisance : sequence of ndarray or None, optional
        Per record, the columns of record-own linear parameters (an offset, the state at the
        release) that the fit also estimated: they are projected off the Jacobian first, so
        that the result is the θ block of the sandwich of all parameters (Frisch–Waugh).

    Returns
    -------
    ndarray, shape (p, p)
        (JᵀWJ)⁻¹ S (JᵀWJ)⁻¹ (:func:`phoid.fits.hac.hac_covariance`, prewhitened); nan when JᵀWJ
        is singular.
    """
    Js, es = [], []
    for i, (J, e) in enumerate(zip(jacobians, residuals, strict=True)):
        J = np.asarray(J, dtype=float)
        e = np.asarray(e, dtype=float)
        G = None if nuisance is None else nuisance[i]
        if G is not None and G.size:
            Q, _ = np.linalg.qr(np.asarray(G, dtype=float))
            J = J - Q @ (Q.T @ J)
        sw = 1.0 if weights is None else math.sqrt(float(weights[i]))
        Js.append(J * sw)
        es.append(e * sw)
    p = Js[0].shape[1]
    try:
        return hac_covariance(Js, es).robust
    except (ValueError, np.linalg.LinAlgError):
        return np.full((p, p), math.nan)


def not_below_white(cov: np.ndarray, white: np.ndarray) -> np.ndarray:
    """``cov`` with each parameter's variance raised to at least the white one (its
    correlations kept): a misfit never makes the uncertainty smaller."""
    d = np.sqrt(np.maximum(np.diag(white), 0.0))
    r = np.sqrt(np.maximum(np.diag(cov), 0.0))
    f = np.where(r > 0, np.maximum(1.0, d / np.where(r > 0, r, 1.0)), 1.0)
    out = cov * np.outer(f, f)
    bad = ~(r > 0)
    out[bad, :] = white[bad, :]
    out[:, bad] = white[:, bad]
    return out


def assess(
    checks: Sequence[Check],
    *,
    names: Sequence[str],
    units: Sequence[str],
    white_cov: Any,
    sandwich_cov: Any,
    between: Sequence[Any] = (),
    causes: Sequence[str] = (),
    warnings: Sequence[str] = (),
) -> Adequacy:
    """Gather the checks into an :class:`Adequacy` and choose the covariance to report.

    Parameters
    ----------
    checks : sequence of Check
    names, units : sequence of str
        The covariances' parameters.
    white_cov : array_like (p, p)
        The fit's white-noise covariance.
    sandwich_cov : array_like (p, p)
        :func:`sandwich` (nan where it failed: the white one is then widened alone).
    between : sequence of array_like (p, p)
        Between-parts covariances to add (:class:`Agreement`'s ``between`` of the checks that
        call for it: the caller chooses, see docs/adequacy.md).
    causes, warnings : sequence of str
        The causes and warnings the caller's checks found (in order).

    Returns
    -------
    Adequacy
        ``robust_cov`` = ``white_cov`` when every check passes, else
        max(sandwich, white) + Σ between (per parameter's variance; correlations from the
        sandwich).
    """
    white = np.asarray(white_cov, dtype=float)
    sw = np.asarray(sandwich_cov, dtype=float)
    failed = any(c.passed is False for c in checks)
    if failed:
        base = not_below_white(sw, white) if np.all(np.isfinite(sw)) else white.copy()
        robust = base + sum((np.asarray(b, dtype=float) for b in between),
                            np.zeros_like(white))
        robust = 0.5 * (robust + robust.T)
    else:
        robust = white.copy()
    return Adequacy(checks=tuple(checks), warnings=tuple(warnings), causes=tuple(causes),
                    names=tuple(names), units=tuple(units), white_cov=white.copy(),
                    robust_cov=robust, sandwich_cov=sw.copy(),
                    stderr="robust" if failed else "white")
