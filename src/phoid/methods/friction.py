r"""Coulomb friction: m, c, k and the kinetic friction force f_c from a PHO set (issue 6).

The model is the seed's plant (eq. 1) with kinetic friction, closed by the delayed PD loop of
eq. (23):

    m x''(t) + c x'(t) + k x(t) + f_c sign(x'(t)) = −[Dᵢ x'(t − Δt) + Pᵢ x(t − Δt)],

each run held at x₀ᵢ until its release at τᵢ and measured as yᵢ(t) = x(t) + bᵢ + noise (bᵢ a
sensor offset). Friction changes the free decay qualitatively: over each half-cycle the mass
oscillates about an equilibrium shifted by ∓f_c/(k + Pᵢ) (the static loop stiffness), so the
peak-to-peak height drops by a constant 4f_c/(k + Pᵢ) per cycle on top of the exponential decay,
and the motion stops (sticks) in finite time once the spring and feedback force fall below f_c.
A dominant-mode (viscous) fit of such a record takes the friction loss for damping: c comes out
far too large (tests/test_friction.py: +70 % on the issue's set).

Method: a full-record maximum-likelihood fit through the exact simulator
---------------------------------------------------------------------------
The decay is no longer a sum of exponentials, so the estimator fits the records themselves:
θ = (m, c, k, f_c) shared by all runs, and per run the release position x₀ᵢ, the offset bᵢ and
the release time τᵢ. The model of run i is

    ŷᵢ(t) = bᵢ + x₀ᵢ                  (t ≤ τᵢ, held),
    ŷᵢ(t) = bᵢ + X(t − τᵢ; θ, x₀ᵢ)     (t > τᵢ),

X the closed loop's response released from rest at x₀ᵢ, computed by
:func:`phoid.simulate` (exact plant propagation, exact stick–slip events; all runs
in
one batched call) on a grid of step h = 1/f_s aligned with the delay, and read at the sample
times by the cubic Hermite interpolant of the simulated x and ẋ (error ≤ h⁴‖x⁗‖/384, about
10⁻¹¹ m for the issue's set, and O(h²·2f_c/m) within a step that holds a velocity reversal,
10⁻⁸ m: both far below the noise). Under white Gaussian noise of sd sᵢ the likelihood is
maximised by minimising Σᵢ Σⱼ (yᵢⱼ − ŷᵢ(tⱼ))²/sᵢ², by Levenberg–Marquardt (Nielsen's damping
update). The Jacobian columns are:

* ∂ŷ/∂bᵢ = 1; ∂ŷ/∂τᵢ = −Ẋ(t − τᵢ) (the Hermite interpolant's derivative: the exact derivative of
  the model as evaluated), 0 while held;
* ∂ŷ/∂(m, c, k, f_c) by forward differences of batched simulations (step 10⁻⁵ of the scale);
* ∂ŷ/∂x₀ᵢ for free: the loop is positively homogeneous, X(t; λx₀, λf_c) = λX(t; x₀, f_c)
  (every term of the equation is linear in x except f_c sign(ẋ), which scales with f_c), so
  x₀ ∂X/∂x₀ + f_c ∂X/∂f_c = X.

A sampled (digital) controller (``digital``, a :class:`phoid.DigitalPD`, or the
manifest's ``[loop] sample_time`` …) replaces the delayed loop by the hybrid one — zero-order
hold, d-sample command delay, the loop's velocity estimator — simulated exactly with stick–slip
by the same :func:`phoid.simulate` (a whole number of steps per controller sample),
its clock started at each run's release.

Runs recorded with a known added mass Δmᵢ (the paper's added-mass trick, ``added_mass``) are
simulated with the plant m + Δmᵢ (one batched simulation per distinct Δm); θ keeps the mass
without additions.

Runs whose command carries a known DC offset bᵢ in the direction of the controller's velocity
(``bias``: the seed's "PD feedback augmented with a DC offset in the (alternating) direction of
oscillation", Discussion, last paragraph), u = −Pᵢx(t − Δt) − Dᵢẋ(t − Δt) + bᵢ sign(ẋ(t − Δt))
(or + bᵢ sign(v̂ₙ₋d) in a sampled command), are simulated with it (exactly, by the same
simulator). The bias partly cancels the friction, so such a run rings for many more cycles
before it sticks. Homogeneity then scales the bias too, X(t; λx₀, λf_c, λb) = λX(t; x₀, f_c, b),
so x₀ ∂X/∂x₀ = X − f_c ∂X/∂f_c − b ∂X/∂b, the last term by one more batched simulation with
every bᵢ scaled by 1 + 10⁻⁵. The envelope start's f_c adds bᵢ to each run's net friction.
A sampled (digital) loop with a bias is refused here. Its record jumps (by the effect of 2bᵢ
held for one period) wherever a velocity reversal crosses a controller instant, so the
likelihood is not smooth in θ, and the fit proved unreliable: with the finite differences
taken at a fixed bias pattern, a 4-run 500 Hz design stalled in 4 of 4 noisy replicas
(χ²/dof 3.8–5.5, c off by up to 58 stderr) and did not formally converge even from the truth,
and the 8-run acceptance design of tests/test_bias.py ended 7 stderr off in m from a start
that differed in the seventh digit. The simulator does model such loops exactly
(``phoid simulate --sample-time … --bias …``). Continuous loops have no such jumps (the switch
times move continuously with θ).

The covariance of θ is the (θ, θ) block of (JᵀWJ)⁻¹ scaled by χ²/dof (the residual variance
in units of the noise sd): the Gauss–Newton (Fisher) covariance with every nuisance parameter
profiled out.

Memory and work are linear in the data: run i's nuisances (x₀ᵢ, bᵢ, τᵢ) touch only its own
rows, so the Jacobian is kept as its dense global columns plus three local columns per row
(:class:`_BlockJacobian`), JᵀJ as a block-arrow matrix, and each linear system is solved
through the Schur complement of its block-diagonal part (a 4 × 4 system plus one 3 × 3 per
run). The dense N × (4 + 3B) Jacobian needed 11 GB for 300 runs of 3 s at 1 kHz; the block
form peaks at 0.4 GB. Every loop is bounded by the input: at most ``max_iter`` steps per fit,
at most one refit per run set aside, and the simulation's step is at least a tenth of the
sample interval (next section).

Checks before fitting
---------------------
* **Time base.** A sample interval longer than 10 loop delays is refused: t in milliseconds
  (or the delay in the wrong unit) is the likely cause, and the fit, which simulates in steps
  of at most one delay, would take that many steps per sample.
* **The recorded force u**, where given (continuous loops): the gains u implies, by least
  squares of u − bᵢ sign(ẋ(t − Δt)) on x(t − Δt), ẋ(t − Δt) and a constant (ẋ a
  Savitzky–Golay derivative over a tenth of the dominant period), must agree with (Pᵢ, Dᵢ) to
  20 % of the force swing. Runs that do not are named in a warning with the probable cause:
  D of the opposite sign (the sign convention), u of the opposite sign, one factor on both
  gains (1e−3: x in mm; or the gains themselves), or — where a delay among whole sample
  intervals up to 3Δt reconciles them — the delay u implies. When the viscous starting point
  then fails, the error carries that diagnosis.

Starting point, and two stages. m, c, k come from :func:`phoid.methods.identification.identify_data`
(the viscous dominant-mode fit of the same runs), τᵢ from its model-fitted releases. The
envelopes then give the rest: successive extrema pₙ of each record lie about bᵢ with a
peak-to-peak height Hₙ that obeys Hₙ₊₁ = ρᵢHₙ − 2f_c(1 + ρᵢ)/(k + Pᵢ) (the half-cycle recursion
of a linear oscillator about the shifted equilibria), fitted by least squares per run: f_c is
the median of the runs' values, the friction-free decay σᵢ = −ln(ρᵢ)ω_dᵢ/π corrects c (which the
viscous fit inflates), bᵢ is the median of (pₙ + 2pₙ₊₁ + pₙ₊₂)/4 and x₀ᵢ the held level minus
bᵢ. Of two such starts (the viscous m, k with the corrected c; or m, c, k from the paper's lines
through the corrected σᵢ) the one that fits the first stage's windows better is used.

Stage 1 fits the first half of each run's motion, to about 2 standard errors; stage 2 fits the
whole windows from there. Going straight to the whole windows can end in a false optimum: a
model that sticks one half-cycle too early has no sensitivity to the data of the half-cycle it
misses, so nothing pulls it back (one of the 8 seeded 3-run sets of the first Monte Carlo in
tests/test_friction.py ended there, 29 standard errors off in c); the first halves hold no
sticking, and their fit puts stage 2 in the right basin.

Each run's window runs from its first sample (the held segment fixes x₀ᵢ + bᵢ) to where its
motion ends — the last sample more than 6 noise sd from the record's final level, i.e. where the
mass sticks or the oscillation sinks into the noise — plus a margin of one period (at least
0.1 s and 4Δt, so that a stuck mass is seen at rest for longer than the delay), which also pins
the stuck position. Later samples only repeat that position; leaving them out keeps a 10-run,
10 s, 1 kHz set to a few seconds (the simulations are the cost).

Runs set aside (with a warning)
-------------------------------
* **Growing records.** When the loop's damping is negative (σᵢ < 0, c′ᵢ < −c) the oscillation
  grows unless friction bounds it. Friction removes a fixed energy per cycle and negative damping
  feeds one that grows with the amplitude squared, so there is an amplitude A* below which the
  record still decays, with an envelope that steepens as it falls (the seed's "bullet-shaped"
  envelope, Discussion), and above which it grows without bound. A bounded record is modelled
  exactly and is used (it is informative); one whose amplitude in the last quarter of the record
  exceeds 1.5 times that of the first quarter grows without bound (or saturates on a real rig)
  and is set aside.
* **No motion** after the release (friction holds the mass: |(k + Pᵢ)x₀ᵢ| ≤ f_c).
* **Friction that stops the motion within a cycle** (fewer than two velocity reversals before the
  fitted motion sticks for good): such a record says little about the oscillation and much about
  the static-friction details that the model idealises (static = kinetic); it is set aside and
  the fit repeated without it. An error is raised when no run remains.

Sticking is reported per run: the fitted model's stick time (when the motion stops for good
before the record ends) with a warning.

Evidence for friction
---------------------
:func:`friction_evidence` tests f_c = 0 by the score (Lagrange-multiplier) test at the viscous
full-record fit: with r the weighted residual of the best friction-free model, j the sensitivity
of the model to f_c at f_c = 0⁺ and Π the projection off the other parameters' columns,
z = jᵀr / (s·‖Πj‖) is standard normal when there is no friction (one-sided: friction only adds
a positive multiple of j). It needs the friction-free fit (fast: no stick–slip events) and one
simulation with friction, not the whole friction fit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal, stats

from phoid._threads import single_blas_thread
from phoid.dynamics.loop import dominant_roots, inverse_map
from phoid.errors import ExperimentError, IdentificationError, PhoidError
from phoid.fits import detect_release
from phoid.methods.pho import Estimate, fit_lines

__all__ = ["FrictionEvidence", "FrictionFit", "FrictionRun", "friction_evidence",
           "identify_friction", "identify_friction_set"]

_UNITS = ("kg", "N s/m", "N/m", "N")
_MIN_SAMPLES = 32
_MOTION_NSD = 6.0  # motion: more than 6 noise sd away from the record's final level
_GROWTH = 1.5  # last-quarter amplitude / first-quarter amplitude above which a record grows
_MARGIN_PERIODS = 1.0  # window margin after the end of motion, in dominant periods …
_MARGIN_MIN = 0.1  # … and at least this many seconds (and 4Δt)
_FD_REL = 1e-5  # forward-difference step, relative to the parameter's scale
_MIN_REVERSALS = 2  # fewer velocity reversals before sticking: "stops within a cycle"
_MAX_CHORDS = 3  # chord steps in a row before the globals' columns are recomputed
_CHORD_SPAN = 10.0  # the covariance needs the globals' columns within this many stderr
_DT_PER_DELAY = 10.0  # a sample interval longer than this many loop delays: a wrong time base
_U_TOL = 0.2  # u's implied gains off by more than this part of the force swing: a warning
_U_R2 = 0.9  # … when the delayed x, ẋ explain at least this part of u's variance


# --------------------------------------------------------------------------------------------
# results


@dataclass(frozen=True)
class FrictionRun:
    """One run of a friction fit.

    Attributes
    ----------
    name : str
        Run name (as given, or ``run1`` …).
    P, D : float
        Gains, N/m and N·s/m.
    used : bool
        False when the run was set aside (see ``warnings``).
    release : float
        Fitted release time τᵢ, s (the detected one when the run was set aside).
    x0 : float
        Fitted release position x₀ᵢ (sensor offset removed), m.
    offset : float
        Fitted sensor offset bᵢ, m.
    sigma, omega_d : float
        Decay rate (1/s) and damped frequency (rad/s) of the fitted loop's dominant mode
        (the viscous part of the motion; σᵢ < 0 is a negatively damped loop that friction
        bounds). nan when not computed.
    stick_time : float or None
        Time at which the fitted motion stops for good, s on the record's clock; None when it
        is still moving at the end of the fitted window.
    reversals : int
        Velocity reversals of the fitted motion before it sticks (−1 when not computed).
    t_end : float
        End of the fitted window, s.
    n_samples : int
        Samples fitted (held segment included).
    noise_sd : float
        Noise sd used to weight the run, m (held segment, or third differences).
    residual_rms : float
        RMS residual of the fit over the window, m (nan when set aside).
    warnings : tuple of str
    added_mass : float
        Known mass added for this run, kg (its plant is m + added_mass; default 0).
    bias : float
        Known DC offset of the run's command in the direction of the velocity, N (default 0).
    """

    name: str
    P: float
    D: float
    used: bool
    release: float
    x0: float
    offset: float
    sigma: float
    omega_d: float
    stick_time: float | None
    reversals: int
    t_end: float
    n_samples: int
    noise_sd: float
    residual_rms: float
    warnings: tuple[str, ...] = ()
    added_mass: float = 0.0
    bias: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (nan as None)."""

        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        out = {
            "name": self.name, "P": float(self.P), "D": float(self.D), "used": self.used,
            "release": num(self.release), "x0": num(self.x0), "offset": num(self.offset),
            "sigma": num(self.sigma), "omega_d": num(self.omega_d),
            "stick_time": num(self.stick_time), "reversals": int(self.reversals),
            "t_end": num(self.t_end), "n_samples": int(self.n_samples),
            "noise_sd": num(self.noise_sd), "residual_rms": num(self.residual_rms),
            "warnings": list(self.warnings),
        }
        if self.added_mass:
            out["added_mass"] = float(self.added_mass)
        if self.bias:
            out["bias"] = float(self.bias)
        return out


@dataclass(frozen=True)
class FrictionFit:
    """Result of :func:`identify_friction`.

    Attributes
    ----------
    m, c, k, fc : Estimate
        Mass (kg), viscous damping (N s/m), stiffness (N/m) and kinetic friction force (N), each
        with its standard error.
    cov : ndarray, shape (4, 4)
        Covariance of (m, c, k, f_c), nuisance parameters profiled out.
    delay : float
        Loop delay Δt used, s.
    runs : tuple of FrictionRun
    chi2 : float
        Weighted residual sum of squares Σ (y − ŷ)²/sᵢ² at the optimum.
    dof : int
        Samples fitted minus parameters.
    residual_rms : float
        RMS residual over all fitted samples, m.
    converged : bool
        Whether Levenberg–Marquardt met its step criterion (< 1 % of every stderr).
    iterations : int
        Levenberg–Marquardt iterations (accepted and rejected steps), all fits together.
    start : tuple of float
        Starting (m, c, k, f_c).
    warnings : tuple of str
    digital : phoid.DigitalPD or None
        The sampled controller the records were simulated with (None: a continuous loop with
        delay Δt); ``delay`` is then its command delay d·T_s.
    """

    m: Estimate
    c: Estimate
    k: Estimate
    fc: Estimate
    cov: np.ndarray
    delay: float
    runs: tuple[FrictionRun, ...]
    chi2: float
    dof: int
    residual_rms: float
    converged: bool
    iterations: int
    start: tuple[float, float, float, float]
    warnings: tuple[str, ...] = ()
    digital: Any = None

    @property
    def chi2_red(self) -> float:
        """χ²/dof (≈ 1 when the model and the noise estimates fit the data)."""
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    @property
    def stick_times(self) -> tuple[float | None, ...]:
        """Per-run stick times, s (None where the fitted motion does not stop in its window)."""
        return tuple(r.stick_time for r in self.runs)

    def summary(self) -> dict[str, Any]:
        """The JSON of ``phoid identify --friction --json``: the spec's keys (method, m, c, k,
        delay, runs, warnings) plus ``fc`` in the same {value, stderr, unit} shape.

        Each run carries the spec's keys — ``file``, ``P``, ``D``, ``sigma``, ``omega_d`` (the
        fitted loop's dominant mode), ``c_prime``, ``k_prime`` (eq. 32 at that mode) and
        ``cycles`` (velocity reversals / 2) — and the friction fit's own (release, x0, offset,
        stick_time, …). χ²/dof and convergence are in :attr:`chi2_red` and :attr:`converged`
        (a fit that did not converge, or misfits, says so in the warnings).
        """
        runs = []
        for r in self.runs:
            d = r.to_dict()
            if math.isfinite(r.sigma) and math.isfinite(r.omega_d):
                # a sampled loop: eq. (32) at its equivalent continuous delay, as identify does
                dly = self.delay if self.digital is None else (
                    self.digital.delay + 0.5 * self.digital.sample_time)
                cp, kp = inverse_map(r.sigma, r.omega_d, r.P, r.D, dly)
                # an added mass's known part taken off, as phoid identify does (all runs then
                # lie on the same eq. 35 lines)
                cp = float(cp) - 2.0 * r.added_mass * r.sigma
                kp = float(kp) - r.added_mass * (r.sigma**2 + r.omega_d**2)
            else:
                cp = kp = None
            runs.append({"file": d.pop("name"), "P": d.pop("P"), "D": d.pop("D"),
                         "sigma": d.pop("sigma"), "omega_d": d.pop("omega_d"),
                         "c_prime": cp, "k_prime": kp,
                         "cycles": r.reversals / 2 if r.reversals >= 0 else None, **d})
        return {
            "method": "pho",
            "m": self.m.to_dict(),
            "c": self.c.to_dict(),
            "k": self.k.to_dict(),
            "fc": self.fc.to_dict(),
            "delay": {"value": float(self.delay), "stderr": None, "unit": "s",
                      "source": "given"},
            "runs": runs,
            "warnings": list(self.warnings),
            **({"loop": {"model": "digital", "sample_time": self.digital.sample_time,
                         "delay_samples": self.digital.delay_samples,
                         "velocity": self.digital.velocity, "cutoff": self.digital.cutoff}}
               if self.digital is not None else {}),
        }

    def report(self) -> str:
        """A plain-text report: m, c, k, f_c with ± one stderr, the runs, warnings."""
        from phoid.reports.text import friction_text

        return friction_text(self)


@dataclass(frozen=True)
class FrictionEvidence:
    """Result of :func:`friction_evidence`: a score test of f_c = 0.

    Attributes
    ----------
    z : float
        Score statistic; standard normal when the plant has no friction, large and positive
        when it has.
    p_value : float
        One-sided p-value P(Z ≥ z).
    detected : bool
        ``p_value < alpha``.
    fc : Estimate
        One Gauss–Newton step from f_c = 0 along the profiled score: a first estimate of f_c (N)
        and its stderr (biased low when friction is strong: use :func:`identify_friction`).
    m, c, k : Estimate
        The viscous (f_c = 0) full-record maximum-likelihood estimates.
    chi2_red : float
        χ²/dof of the viscous full-record fit (≫ 1 when friction or another effect is missing).
    warnings : tuple of str
    """

    z: float
    p_value: float
    detected: bool
    fc: Estimate
    m: Estimate
    c: Estimate
    k: Estimate
    chi2_red: float
    warnings: tuple[str, ...] = ()


# --------------------------------------------------------------------------------------------
# per-run survey of the data (model-free)


@dataclass(frozen=True)
class _Survey:
    name: str
    t: np.ndarray
    y: np.ndarray
    release: float
    level: float  # held level (x₀ + b)
    final: float  # final level of the record (median of its last 5 %)
    sd: float  # noise sd
    motion_end: float  # last sample more than 6 sd from the final level, s
    reason: str | None  # why the run is set aside before fitting


def _check_run(name: str, t: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or x.ndim != 1 or t.shape != x.shape:
        raise ExperimentError(
            f"{name}: `t` and `x` must be 1-D arrays of equal length; got shapes {t.shape} "
            f"and {x.shape}"
        )
    for field_name, a in (("t", t), ("x", x)):
        if not np.all(np.isfinite(a)):
            j = int(np.flatnonzero(~np.isfinite(a))[0])
            raise ExperimentError(f"{name}: `{field_name}` must be finite; got {a[j]} at row {j}")
    if t.size < _MIN_SAMPLES:
        raise ExperimentError(
            f"{name}: the record needs at least {_MIN_SAMPLES} samples; got {t.size}"
        )
    if not np.all(np.diff(t) > 0):
        j = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ExperimentError(
            f"{name}: `t` must be strictly increasing; got t[{j}] = {t[j]:.9g} s, "
            f"t[{j + 1}] = {t[j + 1]:.9g} s"
        )
    return t, x


def _third_diff_sd(x: np.ndarray) -> float:
    """White-noise sd from third differences (var Δ³ = 20 s²), robust (MAD): the smooth signal
    contributes (ωh)³A, negligible at practical sample rates."""
    if x.size < 8:
        return 0.0
    d3 = np.diff(x, 3)
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def _survey(name: str, t: np.ndarray, y: np.ndarray) -> _Survey:
    """Release, held level, noise, end of motion and growth of one record, from the data."""
    amp = float(np.ptp(y))
    if not amp > 0:
        return _Survey(name, t, y, float(t[0]), float(y[0]), float(y[0]), 0.0, float(t[0]),
                       "the record is constant: no motion")
    release = detect_release(t, y)
    j = int(np.searchsorted(t, release, side="right")) - 1
    held = y[: j + 1]
    level = float(np.median(held)) if held.size >= 5 else float(y[0])
    sd = float(np.std(held, ddof=1)) if held.size >= 20 else 0.0
    if not sd > 0:
        sd = _third_diff_sd(y)
    sd = max(sd, 1e-9 * amp, 1e-15)
    post = y[j + 1 :]
    tp = t[j + 1 :]
    n_tail = max(20, y.size // 20)
    final = float(np.median(y[-n_tail:]))
    moving = np.flatnonzero(np.abs(post - final) > _MOTION_NSD * sd)
    if post.size < 8 or moving.size == 0 or abs(level - final) <= _MOTION_NSD * sd:
        return _Survey(name, t, y, release, level, final, sd, float(t[-1]),
                       "no motion after the release (friction holds the mass, or the record "
                       "has no release)")
    motion_end = float(tp[moving[-1]])
    q = max(post.size // 4, 1)
    centre = float(np.median(post))
    a_first = float(np.max(np.abs(post[:q] - centre)))
    a_last = float(np.max(np.abs(post[-q:] - centre)))
    reason = None
    if a_last > _GROWTH * a_first and a_last > 10.0 * sd:
        reason = (
            f"the oscillation grows (amplitude ×{a_last / a_first:.3g} from the first to the "
            "last quarter of the record): an unstable loop that friction does not bound"
        )
    return _Survey(name, t, y, release, level, final, sd, motion_end, reason)


# --------------------------------------------------------------------------------------------
# the recorded force u against the gains and x (model-free)


def _u_gains(t: np.ndarray, x: np.ndarray, u: np.ndarray, delay: float,
             bias: float) -> tuple[float, float, float, float, float] | None:
    """Gains that the recorded u implies: least squares of u − b sign(ẋ(t − Δt)) on
    x(t − Δt), ẋ(t − Δt) and a constant (the sensor offset times P).

    ẋ is a Savitzky–Golay derivative (cubic, over a tenth of the dominant period) of x; both
    are read at t − Δt by linear interpolation. Returns (P̂, D̂, R², sd of x(t − Δt), sd of
    ẋ(t − Δt)), or None when the record is too short or u is constant.
    """
    sel = t - delay >= t[0]
    if np.count_nonzero(sel) < _MIN_SAMPLES or not np.ptp(u[sel]) > 0:
        return None
    dt = float(np.median(np.diff(t)))
    # the window: a tenth of the record's dominant period (its spectrum's peak), at least 5
    # samples: it smooths the noise out of ẋ (a noisy regressor would bias D̂ low)
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f_peak = max(int(np.argmax(spec[1:])) + 1, 1) / (x.size * dt)
    win = max(5, min(round(0.1 / (f_peak * dt)), x.size // 4))
    win += 1 - win % 2
    v = signal.savgol_filter(x, win, 3, deriv=1, delta=dt)
    td = t[sel] - delay
    xd = np.interp(td, t, x)
    vd = np.interp(td, t, v)
    target = u[sel] - bias * np.sign(vd)
    A = np.c_[xd, vd, np.ones(xd.size)]
    coef, *_ = np.linalg.lstsq(A, target, rcond=None)
    res = target - A @ coef
    tss = float(np.sum((target - target.mean()) ** 2))
    r2 = 1.0 - float(res @ res) / tss if tss > 0 else 0.0
    return -float(coef[0]), -float(coef[1]), r2, float(np.std(xd)), float(np.std(vd))


def _u_diagnosis(P: float, D: float, Ph: float, Dh: float, sx: float,
                 sv: float) -> tuple[str, str] | None:
    """What the gains (P̂, D̂) implied by u say about the given (P, D): None when they agree
    within 20 % of the force swing, else (kind, the probable cause in words)."""
    F = math.hypot(P * sx, D * sv)
    Fh = math.hypot(Ph * sx, Dh * sv)
    scale = max(F, Fh)
    if not scale > 0 or math.hypot((Ph - P) * sx, (Dh - D) * sv) <= _U_TOL * scale:
        return None
    if D != 0 and math.hypot((Ph - P) * sx, (Dh + D) * sv) <= _U_TOL * scale:
        return "sign D", ("D has the opposite sign to the one u implies (phoid/1's convention: "
                          "u = -P x(t - delay) - D x'(t - delay))")
    if F > 0:  # one factor g for both gains?
        g = (Ph * P * sx * sx + Dh * D * sv * sv) / (F * F)
        if 1e-4 < abs(g) < 1e4 and \
                math.hypot((Ph - g * P) * sx, (Dh - g * D) * sv) <= _U_TOL * scale:
            if g < 0:
                return "sign u", ("u has the opposite sign to the force the gains imply "
                                  "(recorded as +P x + D x'?)")
            for factor, what in ((1e-3, "x in mm instead of m, or u in mN instead of N"),
                                 (1e-2, "x in cm instead of m"),
                                 (1e3, "x in km, or u in kN instead of N")):
                if abs(g / factor - 1.0) <= _U_TOL:
                    return f"units {factor:g}", (
                        f"u is {g:.3g} times the force the gains and x imply: {what}?")
            return "scale", (f"u is {g:.3g} times the force the gains and x imply: check the "
                             "gains (all off by one factor?) and the units of x and u")
    return "gains", (f"u implies P = {Ph:.4g} N/m, D = {Dh:.4g} N s/m where the set gives "
                     f"P = {P:.4g}, D = {D:.4g}: check the loop delay, the gains and their "
                     "sign convention")


def _u_delay(t, x, u, P, D, delay, bias) -> float | None:
    """The delay at which u agrees with the given gains (:func:`_u_diagnosis`), searched over
    whole sample intervals up to max(3Δt, 20 samples) (at most 200 trials); None if none."""
    dt = float(np.median(np.diff(t)))
    top = min(max(3.0 * delay, 20.0 * dt), 200.0 * dt, 0.25 * float(t[-1] - t[0]))
    best, best_err = None, math.inf
    for lag in np.arange(0.0, top + 0.5 * dt, dt):
        got = _u_gains(t, x, u, float(lag), bias)
        if got is None or not got[2] >= _U_R2:
            continue
        Ph, Dh, _, sx, sv = got
        err = math.hypot((Ph - P) * sx, (Dh - D) * sv)
        if err < best_err:
            best, best_err = float(lag), err
    if best is None or _u_diagnosis(P, D, *_u_gains(t, x, u, best, bias)[:2],
                                    *_u_gains(t, x, u, best, bias)[3:]) is not None:
        return None
    return best


def _check_u(names, surveys, u, P, D, delay, bias) -> list[str]:
    """Warnings for the runs whose recorded u contradicts the gains and x (one per probable
    cause, naming the runs; the text of the first such run)."""
    groups: dict[str, list[tuple[str, str]]] = {}
    lags: dict[str, float] = {}
    for i, s in enumerate(surveys):
        ui = None if u is None else u[i]
        if ui is None:
            continue
        ui = np.asarray(ui, dtype=float)
        if ui.shape != s.t.shape or not np.all(np.isfinite(ui)):
            continue
        got = _u_gains(s.t, s.y, ui, delay, float(bias[i]))
        if got is None or not got[2] >= _U_R2:  # u not a linear function of delayed x, ẋ
            continue
        found = _u_diagnosis(float(P[i]), float(D[i]), *got[:2], *got[3:])
        if found is not None and found[0] == "gains":
            lag = _u_delay(s.t, s.y, ui, float(P[i]), float(D[i]), delay, float(bias[i]))
            if lag is not None:
                lags[names[i]] = lag
                found = "delay", (f"u implies a loop delay of about {lag:.3g} s, not the "
                                  f"{delay:.3g} s given")
        if found is not None:
            groups.setdefault(found[0], []).append((names[i], found[1]))
    out = []
    for kind, runs in groups.items():
        text = runs[0][1]
        if kind == "delay":  # the runs' median
            lag = float(np.median([lags[n] for n, _ in runs]))
            text = f"u implies a loop delay of about {lag:.3g} s, not the {delay:.3g} s given"
        out.append(f"{', '.join(n for n, _ in runs)}: the recorded u contradicts the gains "
                   f"and x: {text}")
    return out


# --------------------------------------------------------------------------------------------
# the friction guess from the envelope's linear part


def _extrema(t: np.ndarray, y: np.ndarray, omega: float, sd: float):
    """Successive alternating extrema (times, s, and values, m) of a ringing record, while the
    peak-to-peak height stays above 20 noise sd.

    The record is smoothed by a moving average over a tenth of a half period (amplitude
    −0.4 %); each extremum is the vertex of a parabola fitted over ±a fifth of a half period.
    """
    dt = float(np.median(np.diff(t)))
    nh = math.pi / omega / dt  # samples per half period
    empty = (np.empty(0), np.empty(0))
    if not nh >= 4:
        return empty
    L = max(1, round(nh / 10))
    ys = np.convolve(y, np.ones(L) / L, mode="valid")
    dist = max(1, int(0.7 * nh))
    hi, _ = signal.find_peaks(ys, distance=dist)
    lo, _ = signal.find_peaks(-ys, distance=dist)
    idx = np.concatenate([hi, lo])
    kind = np.concatenate([np.ones(hi.size), -np.ones(lo.size)])
    order = np.argsort(idx)
    idx, kind = idx[order], kind[order]
    # keep alternating extrema (the more extreme of two of a kind in a row)
    keep_i: list[int] = []
    keep_k: list[float] = []
    for i, kd in zip(idx, kind, strict=True):
        if keep_k and keep_k[-1] == kd:
            if kd * ys[i] > kd * ys[keep_i[-1]]:
                keep_i[-1] = int(i)
            continue
        keep_i.append(int(i))
        keep_k.append(float(kd))
    w = max(2, round(nh / 5))
    keep = np.array([i for i in keep_i if w <= i < ys.size - w], dtype=int)
    if keep.size == 0:
        return empty
    off = np.arange(-w, w + 1, dtype=float)
    Y = ys[keep[:, None] + off.astype(int)[None, :]]  # (n, 2w + 1)
    a2, a1, a0 = np.polyfit(off, Y.T, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(a2 != 0, -a1 / (2 * a2), 0.0)
    shift = np.clip(shift, -w, w)
    vals = a0 + a1 * shift + a2 * shift**2
    times = t[0] + (keep + shift + 0.5 * (L - 1)) * dt
    small = np.flatnonzero(np.abs(np.diff(vals)) < 20.0 * sd)
    n = small[0] + 1 if small.size else vals.size
    return times[:n], vals[:n]


def _envelope_guess(surveys, P, D, delay, m, c, k, omegas, releases, dm=None, bias=None):
    """Candidate starts (m, c, k, f_c) and per-run offsets from the envelopes.

    Per run, the peak-to-peak heights obey Hₙ₊₁ = ρᵢHₙ − δᵢ (least squares, module
    docstring); the half-cycles last π/ω_dᵢ whatever the friction (each is a linear oscillation
    about a shifted equilibrium), so ω_dᵢ comes from the extrema's times, and the viscous part
    of the decay is σᵢ = −ln(ρᵢ)ω_dᵢ/π. Candidates, each with f_c the median of
    δᵢ(k + Pᵢ)/(2(1 + ρᵢ)):

    1. the given m, k with c the median of 2(m + Δmᵢ)σᵢ − c′ᵢ (eq. 35, c′ᵢ from eq. 32; Δmᵢ
       the known added masses);
    2. m, c, k from the paper's lines through (σᵢ, ω_dᵢ) (eqs. 32–35,
       :func:`phoid.methods.pho.fit_lines`), when three runs with two gain pairs have enough peaks.

    A run's known bias bᵢ cancels part of the friction while it slides, so its envelope gives
    f_c − bᵢ: bᵢ is added back. Without such runs, the given (m, c, k) with f_c = 0. The offset
    of run i is the median of
    (pₙ + 2pₙ₊₁ + pₙ₊₂)/4 over successive extrema pₙ (exact for an envelope linear over a
    cycle; nan with fewer than 3 extrema).
    """
    rows = []
    offsets = np.full(len(surveys), math.nan)
    dm = np.zeros(len(surveys)) if dm is None else np.asarray(dm, dtype=float)
    bs = np.zeros(len(surveys)) if bias is None else np.asarray(bias, dtype=float)
    for i, (s, Pi, Di, om, tau) in enumerate(zip(surveys, P, D, omegas, releases,
                                                  strict=True)):
        if not (om > 0 and math.isfinite(om)):
            continue
        post = s.t > tau
        te, p = _extrema(s.t[post], s.y[post], om, s.sd)
        if p.size >= 3:
            offsets[i] = float(np.median((p[:-2] + 2.0 * p[1:-1] + p[2:]) / 4.0))
        H = np.abs(np.diff(p))
        if H.size < 4:
            continue
        A = np.c_[H[:-1], -np.ones(H.size - 1)]
        (rho, delta), *_ = np.linalg.lstsq(A, H[1:], rcond=None)
        half = float(np.polyfit(np.arange(te.size), te, 1)[0])
        if 0 < rho < 1.5 and half > 0:
            om = math.pi / half
            rows.append((-math.log(rho) * om / math.pi, om, Pi, Di, rho, delta, dm[i], bs[i]))
    if not rows:
        return [np.array([m, c, k, float(np.min(bs)) if bs.size else 0.0])], offsets
    sig, om, Pr, Dr, rho, delta, dmr, br = (np.array(a) for a in zip(*rows, strict=True))

    def fc_for(kk):
        return max(float(np.median(delta * (kk + Pr) / (2.0 * (1.0 + rho)) + br)), 0.0)

    cp, _ = inverse_map(sig, om, Pr, Dr, delay)
    c1 = float(np.median(2.0 * (m + dmr) * sig - cp))
    out = [np.array([m, c1, k, fc_for(k)])]
    if sig.size >= 3 and np.unique(np.c_[Pr, Dr], axis=0).shape[0] >= 2:
        try:
            lines = fit_lines(sig, om, Pr, Dr, delay, added_mass=dmr)
            if lines.m > 0 and math.isfinite(lines.c) and math.isfinite(lines.k):
                out.append(np.array([lines.m, lines.c, lines.k, fc_for(lines.k)]))
        except (ValueError, np.linalg.LinAlgError):
            pass
    return out, offsets


# --------------------------------------------------------------------------------------------
# the model: batched simulation read by cubic Hermite interpolation


@dataclass(frozen=True)
class _PlantParams:
    """Duck-typed plant for :func:`phoid.simulate` (c, k may go negative in a fit)."""

    m: float
    c: float
    k: float
    fc: float


def _hermite(X: np.ndarray, V: np.ndarray, h: float, u: np.ndarray):
    """Cubic Hermite interpolant of grid values X, V (step h) and its derivative at u ≥ 0."""
    z = u / h
    j = np.clip(np.floor(z).astype(np.int64), 0, X.size - 2)
    s = z - j
    x0, x1 = X[j], X[j + 1]
    v0, v1 = V[j] * h, V[j + 1] * h
    s2 = s * s
    s3 = s2 * s
    val = (2 * s3 - 3 * s2 + 1) * x0 + (s3 - 2 * s2 + s) * v0 + (3 * s2 - 2 * s3) * x1 \
        + (s3 - s2) * v1
    der = ((6 * s2 - 6 * s) * (x0 - x1) + (3 * s2 - 4 * s + 1) * v0 + (3 * s2 - 2 * s) * v1) / h
    return val, der


class _Problem:
    """The weighted least-squares problem of the used runs.

    Parameter vector: the free globals among (m, c, k, f_c), then (x₀ᵢ, bᵢ, τᵢ) per run.
    """

    def __init__(self, surveys, t_end, P, D, delay, fs_sim, free, dm=None, digital=None,
                 bias=None):
        self.t = []
        self.y = []
        for s, te in zip(surveys, t_end, strict=True):
            sel = s.t <= te
            self.t.append(s.t[sel])
            self.y.append(s.y[sel])
        self.w = np.array([1.0 / s.sd for s in surveys])
        self.t_end = np.asarray(t_end, dtype=float)
        self.P = np.asarray(P, dtype=float)
        self.D = np.asarray(D, dtype=float)
        self.delay = delay
        self.digital = digital
        # after this long at rest the loop's command is constant: the delay, or for a sampled
        # controller its d samples plus the sample in progress
        self.settle = delay if digital is None else digital.delay + digital.sample_time
        self.fs = fs_sim
        self.h = 1.0 / fs_sim
        self.free = tuple(free)  # which of (m, c, k, fc) are fitted
        self.ng = sum(self.free)
        self.B = len(surveys)
        # known added mass per run (the added-mass trick): run i's plant is m + Δmᵢ
        self.dm = np.zeros(self.B) if dm is None else np.asarray(dm, dtype=float)
        self.groups = [np.flatnonzero(self.dm == a) for a in np.unique(self.dm)]
        # known DC offset of each run's command in the direction of the velocity, N
        self.bias = np.zeros(self.B) if bias is None else np.asarray(bias, dtype=float)
        self.biased = bool(np.any(self.bias > 0))
        self.n = np.array([tt.size for tt in self.t])
        self.rows = np.concatenate([[0], np.cumsum(self.n)])

    # parameter vector <-> (theta, local)
    def split(self, p: np.ndarray, fixed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        theta = fixed.copy()
        theta[np.array(self.free)] = p[: self.ng]
        return theta, p[self.ng :].reshape(self.B, 3)

    def simulate(self, theta: np.ndarray, x0: np.ndarray, tau: np.ndarray,
                 bias_scale: float = 1.0):
        """X, V of every run released at x₀ᵢ (hold 0, grid step h); None if not simulable.

        One batched simulation per distinct added mass (run i's plant is m + Δmᵢ); each run's
        command carries its bias bᵢ (times ``bias_scale``)."""
        from phoid.simulation.core import simulate

        m, c, k, fc = (float(a) for a in theta)
        if not (m > 0 and fc >= 0):
            return None
        dur = max(float(np.max(self.t_end - tau)) + 3.0 * self.h, 4 * self.h)
        X = V = None
        for g in self.groups:
            plant = _PlantParams(m + float(self.dm[g[0]]), c, k, fc)
            g_ = self.digital
            loop = {"delay": self.delay} if g_ is None else {
                "sample_time": g_.sample_time, "delay_samples": g_.delay_samples,
                "velocity": g_.velocity, "cutoff": g_.cutoff}
            try:
                sim = simulate(plant, self.P[g], self.D[g], duration=dur, fs=self.fs,
                               x0=np.asarray(x0)[g], bias=bias_scale * self.bias[g], **loop)
            except ValueError:
                return None
            if not (np.all(np.isfinite(sim.x_true)) and np.all(np.isfinite(sim.v))):
                return None
            if X is None:
                X = np.empty((self.B, sim.x_true.shape[1]))
                V = np.empty_like(X)
            X[g], V[g] = sim.x_true, sim.v
        return X, V

    def model(self, local: np.ndarray, XV) -> tuple[list, list, list]:
        """Per run: model values, post-release mask, Hermite value and derivative."""
        X, V = XV
        vals, posts, herm = [], [], []
        for i in range(self.B):
            x0, b, tau = local[i]
            u = self.t[i] - tau
            post = u > 0
            hv, hd = _hermite(X[i], V[i], self.h, np.maximum(u, 0.0))
            vals.append(b + np.where(post, hv, x0))
            posts.append(post)
            herm.append((hv, hd))
        return vals, posts, herm

    def residual(self, local: np.ndarray, XV) -> np.ndarray:
        vals, _, _ = self.model(local, XV)
        return np.concatenate([(self.y[i] - vals[i]) * self.w[i] for i in range(self.B)])

    def steps(self, theta: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Forward-difference steps of (m, c, k, f_c): 10⁻⁵ of each one's scale."""
        m, c, k, fc = theta
        w2 = float(np.median(np.abs(k + self.P))) / m if m > 0 else 1.0
        w = math.sqrt(max(w2, 1e-12))
        kp = float(np.median(np.abs(k + self.P)))
        x0 = float(np.median(np.abs(local[:, 0])))
        scale = np.array([abs(m), max(abs(c), 0.05 * m * w), max(abs(k), 0.05 * m * w2),
                          max(fc, 1e-3 * kp * x0)])
        return _FD_REL * scale

    def global_columns(self, theta, local, XV) -> np.ndarray | None:
        """Unweighted ∂ŷ/∂(free globals) by forward differences, shape (N, ng); one batched
        simulation per column (a backward difference where the forward point cannot be
        simulated). With a bias, one more column: Σ bᵢ ∂ŷ/∂bᵢ (every bias scaled by 1 + 10⁻⁵),
        for the homogeneity relation of :meth:`jacobian`."""
        _, posts, herm = self.model(local, XV)
        steps = self.steps(theta, local)
        G = np.zeros((int(self.rows[-1]), self.ng + int(self.biased)))

        def fill(col, XVp, step):
            # column `col`: the difference quotient of each run's model after its release
            for i in range(self.B):
                u = np.maximum(self.t[i] - local[i, 2], 0.0)
                hv, _ = _hermite(XVp[0][i], XVp[1][i], self.h, u)
                G[self.rows[i] : self.rows[i + 1], col] = np.where(
                    posts[i], (hv - herm[i][0]) / step, 0.0)
        col = 0
        for j in range(4):
            if not self.free[j]:
                continue
            th = theta.copy()
            th[j] += steps[j]
            hj = steps[j]
            XVp = self.simulate(th, local[:, 0], local[:, 2])
            if XVp is None:
                th[j] -= 2 * steps[j]
                hj = -steps[j]
                XVp = self.simulate(th, local[:, 0], local[:, 2])
                if XVp is None:
                    return None
            fill(col, XVp, hj)
            col += 1
        if self.biased:
            XVp = self.simulate(theta, local[:, 0], local[:, 2], bias_scale=1.0 + _FD_REL)
            if XVp is None:
                return None
            fill(col, XVp, _FD_REL)
        return G

    def jacobian(self, theta, local, XV, G: np.ndarray) -> _BlockJacobian:
        """Weighted Jacobian: the global columns G (unweighted) and the exact local ones, by
        blocks (:class:`_BlockJacobian`: memory linear in the data)."""
        _, posts, herm = self.model(local, XV)
        N = int(self.rows[-1])
        glob = np.empty((N, self.ng))
        loc = np.empty((N, 3))
        fc = theta[3]
        for i in range(self.B):
            r = slice(int(self.rows[i]), int(self.rows[i + 1]))
            x0 = local[i, 0]
            hv, hd = herm[i]
            post = posts[i]
            # homogeneity: x₀ ∂X/∂x₀ + f_c ∂X/∂f_c + b ∂X/∂b = X
            dfc = G[r, self.ng - 1] if self.free[3] else 0.0
            db = G[r, self.ng] if self.biased else 0.0
            dx0 = (hv - fc * dfc - db) / x0 if x0 != 0 else np.zeros_like(hv)
            wi = self.w[i]
            glob[r] = G[r, : self.ng] * wi
            loc[r, 0] = np.where(post, dx0, 1.0) * wi
            loc[r, 1] = wi
            loc[r, 2] = np.where(post, -hd, 0.0) * wi
        return _BlockJacobian(glob, loc, self.rows.astype(np.intp))


# --------------------------------------------------------------------------------------------
# the Jacobian's block structure: globals dense, each run's (x₀ᵢ, bᵢ, τᵢ) on its own rows


@dataclass(frozen=True)
class _BlockJacobian:
    """Weighted Jacobian of :class:`_Problem` stored by blocks, in memory linear in the data.

    The columns of the ``ng`` globals are dense (``glob``, shape (N, ng)); the three columns of
    run i's local parameters (x₀ᵢ, bᵢ, τᵢ) are zero outside its rows, so they are kept as one
    (N, 3) array ``loc`` whose rows ``rows[i]:rows[i+1]`` belong to run i. The dense
    N × (ng + 3B) matrix, quadratic in the number of runs (300 runs: 5.5 GB), is never formed.
    """

    glob: np.ndarray  # (N, ng)
    loc: np.ndarray  # (N, 3)
    rows: np.ndarray  # (B + 1,) row offsets of the runs

    @property
    def shape(self) -> tuple[int, int]:
        return (self.glob.shape[0], self.glob.shape[1] + 3 * (self.rows.size - 1))

    def tdot(self, r: np.ndarray) -> np.ndarray:
        """Jᵀr for a vector r of N rows (globals first, then (x₀ᵢ, bᵢ, τᵢ) per run)."""
        gl = self.glob.T @ r
        lr = self.loc * r[:, None]
        loc = np.add.reduceat(lr, self.rows[:-1], axis=0) if lr.shape[0] else lr
        return np.concatenate([gl, loc.ravel()])

    def dot(self, d: np.ndarray) -> np.ndarray:
        """J d for a parameter vector d."""
        ng = self.glob.shape[1]
        dl = d[ng:].reshape(-1, 3)
        per_row = np.repeat(dl, np.diff(self.rows), axis=0)  # (N, 3)
        return self.glob @ d[:ng] + np.einsum("nj,nj->n", self.loc, per_row)

    def normal(self) -> _Normal:
        """The normal matrix JᵀJ by blocks."""
        g, lc, rows = self.glob, self.loc, self.rows
        start = rows[:-1]
        # per run: Σ over its rows of g ⊗ l (ng × 3) and l ⊗ l (3 × 3)
        gl = np.add.reduceat(g[:, :, None] * lc[:, None, :], start, axis=0)
        ll = np.add.reduceat(lc[:, :, None] * lc[:, None, :], start, axis=0)
        return _Normal(g.T @ g, gl, ll)


@dataclass(frozen=True)
class _Normal:
    """JᵀJ of a :class:`_BlockJacobian`: the block-arrow matrix [[Agg, Agl], [Alg, diag(Allᵢ)]].

    ``gg`` (ng, ng); ``gl`` (B, ng, 3), run i's coupling of the globals with its locals; ``ll``
    (B, 3, 3), run i's locals. Linear systems are solved through the Schur complement of the
    block-diagonal part, S = Agg − Σᵢ Aglᵢ Allᵢ⁻¹ Alg ᵢ (ng × ng): O(B) memory and work.
    """

    gg: np.ndarray
    gl: np.ndarray
    ll: np.ndarray

    def diag(self) -> np.ndarray:
        return np.concatenate([np.diag(self.gg), np.einsum("bjj->bj", self.ll).ravel()])

    def quad(self, d: np.ndarray) -> float:
        """dᵀ (JᵀJ) d."""
        ng = self.gg.shape[0]
        dg, dl = d[:ng], d[ng:].reshape(-1, 3)
        return float(dg @ self.gg @ dg + 2.0 * np.einsum("i,bij,bj->", dg, self.gl, dl)
                     + np.einsum("bi,bij,bj->", dl, self.ll, dl))

    def solve(self, rhs: np.ndarray, lam: float = 0.0, keep: np.ndarray | None = None,
              floor: np.ndarray | None = None) -> np.ndarray:
        """Solve (A + λ diag A) δ = rhs over the globals ``keep`` (a boolean mask; the others
        held at δ = 0) and every local; raises numpy.linalg.LinAlgError when singular.

        ``floor`` is the diagonal used for the damping (default diag A)."""
        ng = self.gg.shape[0]
        dA = self.diag() if floor is None else floor
        keep = np.ones(ng, dtype=bool) if keep is None else keep
        kg = np.flatnonzero(keep)
        Mgg = self.gg[np.ix_(kg, kg)] + lam * np.diag(dA[:ng][kg])
        Mll = self.ll + lam * (np.eye(3)[None] * dA[ng:].reshape(-1, 1, 3))
        Mgl = self.gl[:, kg, :]  # (B, k, 3)
        rg, rl = rhs[:ng][kg], rhs[ng:].reshape(-1, 3)
        # Mll⁻¹ [Mlg, rl] per run in one batched solve
        Z = np.linalg.solve(Mll, np.concatenate([np.swapaxes(Mgl, 1, 2), rl[:, :, None]],
                                                axis=2))  # (B, 3, k + 1)
        S = Mgg - np.einsum("bik,bkj->ij", Mgl, Z[:, :, :-1])
        sg = rg - np.einsum("bik,bk->i", Mgl, Z[:, :, -1])
        dg = np.linalg.solve(S, sg)
        dl = Z[:, :, -1] - np.einsum("bkj,j->bk", Z[:, :, :-1], dg)
        out = np.zeros(rhs.size)
        out[kg] = dg
        out[ng:] = dl.ravel()
        return out

    def inv_globals(self) -> np.ndarray:
        """The globals' block of (JᵀJ)⁻¹: the inverse of the Schur complement."""
        Z = np.linalg.solve(self.ll, np.swapaxes(self.gl, 1, 2))  # (B, 3, ng)
        S = self.gg - np.einsum("bik,bkj->ij", self.gl, Z)
        return np.linalg.inv(S)


# --------------------------------------------------------------------------------------------
# Levenberg–Marquardt


@dataclass
class _LMResult:
    p: np.ndarray
    XV: Any
    J: _BlockJacobian
    cost: float
    converged: bool
    iterations: int


def _solve_step(A: _Normal, g, lam, p, ifc, ng):
    """(A + λ diag A) δ = g, holding f_c at its bound 0 when the step would push it below."""
    dA = np.maximum(A.diag(), 1e-300)
    keep = np.ones(ng, dtype=bool)
    for _ in range(2):
        try:
            delta = A.solve(g, lam, keep, dA)
        except np.linalg.LinAlgError:
            return None
        if ifc is not None and keep[ifc] and p[ifc] <= 0 and delta[ifc] < 0:
            keep[ifc] = False
            continue
        return delta
    return None


def _levenberg_marquardt(prob: _Problem, p0: np.ndarray, fixed: np.ndarray,
                         max_iter: int = 40, tol: float = 0.1,
                         confirm: bool = True) -> _LMResult:
    """Minimise ‖r‖² (r the weighted residual) by Levenberg–Marquardt with f_c ≥ 0, m > 0.

    Marquardt's scaling (λ diag JᵀJ) and Nielsen's damping update. The columns of the globals
    cost a simulation each, the others none, so the globals' columns are recomputed only when
    a step fails, after three steps without them, or when the fit has converged more than
    ``_CHORD_SPAN`` standard errors (in the covariance metric below) from where they were
    computed (to confirm it there and to give the covariance); the other steps use the last
    columns with exact local ones (a chord method: near the optimum JᵀJ changes by ~0.05 % over
    a few standard errors, so these steps converge like Gauss–Newton's).

    Converged when the Gauss–Newton step is shorter than ``tol`` in the metric of the
    parameters' covariance (δᵀJᵀJδ/s² ≤ tol², s² = χ²/dof: with tol = 0.1 no linear
    combination of the parameters would move by more than 0.1 of its standard error), or when a
    step fails although the full Gauss–Newton step promised less than one s² of decrease.
    ``confirm=False`` skips the confirmation with fresh columns (a preliminary fit).
    """
    p = p0.copy()
    theta, local = prob.split(p, fixed)
    XV = prob.simulate(theta, local[:, 0], local[:, 2])
    if XV is None:
        raise IdentificationError(
            f"the starting plant (m, c, k, fc) = {tuple(round(float(a), 6) for a in theta)} "
            "cannot be simulated for these gains"
        )
    r = prob.residual(local, XV)
    cost = float(r @ r)
    G = prob.global_columns(theta, local, XV)
    if G is None:
        raise IdentificationError("the model's sensitivities cannot be computed at the start")
    p_G = p.copy()  # where G was computed
    J = prob.jacobian(theta, local, XV, G)
    ifc = prob.ng - 1 if prob.free[3] else None  # index of f_c in p
    im = 0 if prob.free[0] else None
    dof = max(r.size - p.size, 1)
    lam, nu = 1e-3, 2.0
    converged = False
    it = chords = 0
    while it < max_iter:
        A = J.normal()
        g = J.tdot(r)
        s2 = cost / dof
        exact = bool(np.array_equal(p, p_G))
        d_gn = _solve_step(A, g, 0.0, p, ifc, prob.ng)
        if d_gn is not None and A.quad(d_gn) <= tol * tol * s2:
            if not confirm or A.quad(p - p_G) <= _CHORD_SPAN**2 * s2:
                converged = True
                break
            # converged with columns from far away: confirm (and get the covariance) with
            # columns computed here
            G_new = prob.global_columns(theta, local, XV)
            if G_new is None:
                break
            G, p_G = G_new, p.copy()
            J = prob.jacobian(theta, local, XV, G)
            continue
        it += 1
        delta = _solve_step(A, g, lam, p, ifc, prob.ng)
        ok = delta is not None
        if ok:
            p_new = p + delta
            if ifc is not None and p_new[ifc] < 0:
                p_new[ifc] = 0.0
                delta = p_new - p
            ok = im is None or p_new[im] > 0
        cost_n = math.inf
        if ok:
            theta_n, local_n = prob.split(p_new, fixed)
            XVn = prob.simulate(theta_n, local_n[:, 0], local_n[:, 2])
            if XVn is not None:
                r_n = prob.residual(local_n, XVn)
                cost_n = float(r_n @ r_n)
        if not cost_n < cost:
            if not exact:  # the chord columns may be what failed: recompute them here
                G_new = prob.global_columns(theta, local, XV)
                if G_new is None:
                    break
                G, p_G = G_new, p.copy()
                J = prob.jacobian(theta, local, XV, G)
                continue
            if d_gn is not None and float(d_gn @ g) <= s2:
                # even the full Gauss–Newton step promised less than one s² of decrease
                converged = True
                break
            lam *= nu
            nu *= 2.0
            if lam > 1e12:
                break
            continue
        pred = float(2 * delta @ g) - A.quad(delta)
        rho = (cost - cost_n) / pred if pred > 0 else 0.0
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        p, theta, local, XV, r, cost = p_new, theta_n, local_n, XVn, r_n, cost_n
        chords = 0 if exact else chords + 1
        if chords >= _MAX_CHORDS:  # slow chord convergence: fresh columns
            G_new = prob.global_columns(theta, local, XV)
            if G_new is None:
                break
            G, p_G, chords = G_new, p.copy(), 0
        J = prob.jacobian(theta, local, XV, G)
    return _LMResult(p, XV, J, cost, converged, it)


# --------------------------------------------------------------------------------------------
# preparation shared by identify_friction and friction_evidence


@dataclass
class _Setup:
    names: list[str]
    P: np.ndarray
    D: np.ndarray
    delay: float
    surveys: list[_Survey]
    reasons: list[str | None]
    start: np.ndarray  # (m, c, k, fc)
    candidates: list[np.ndarray]  # starts to choose from (the best fitting first samples)
    release: np.ndarray
    offset: np.ndarray
    omega: np.ndarray  # dominant angular frequency per run (start plant), rad/s
    fs: float
    warnings: list[str]
    dm: np.ndarray  # known added mass per run, kg
    digital: Any = None  # phoid.DigitalPD of a sampled loop, else None
    bias: np.ndarray | None = None  # known DC offset of each run's command, N


def _as_gains(name: str, a: Any, n: int) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ExperimentError(f"`{name}` must be an array of real numbers") from None
    if arr.size != n:
        raise ExperimentError(f"`{name}` must have one entry per run ({n}); got {arr.size}")
    if not np.all(np.isfinite(arr)):
        j = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ExperimentError(f"run{j + 1}: `{name}` must be finite; got {arr[j]}")
    return arr


def _check_start(start) -> list[float] | None:
    if start is None:
        return None
    try:
        st = [float(a) for a in start]
    except (TypeError, ValueError):
        raise ExperimentError(f"`start` must be (m, c, k) or (m, c, k, fc); got {start!r}") \
            from None
    if len(st) not in (3, 4) or not all(math.isfinite(a) for a in st) or not st[0] > 0 \
            or (len(st) == 4 and not st[3] >= 0):
        raise ExperimentError(
            f"`start` must be (m, c, k) or (m, c, k, fc), finite, m > 0, fc ≥ 0; got {start!r}"
        )
    return st


class _StartError(IdentificationError):
    """No viscous starting point; ``cause`` is the viscous identification's own message (None
    when it failed internally) and ``hint`` what the recorded u says, if anything."""

    def __init__(self, message: str, cause: str | None, hint: str | None):
        super().__init__(message)
        self.cause = cause
        self.hint = hint


def _check_time_base(names, surveys, delay: float) -> None:
    """Refuse a record whose sample interval is many loop delays long: t in ms (or the delay
    in the wrong unit). The fit simulates the loop in steps of at most one delay, so this also
    bounds its work to _DT_PER_DELAY steps per recorded sample."""
    if not delay > 0:
        return
    for name, s in zip(names, surveys, strict=True):
        dt = float(np.median(np.diff(s.t)))
        if dt > _DT_PER_DELAY * delay:
            raise ExperimentError(
                f"{name}: the sample interval {dt:.3g} s is {dt / delay:.3g} times the loop "
                f"delay {delay:.3g} s: t in milliseconds instead of seconds, or the delay in "
                f"the wrong unit? (the friction fit needs a sample interval of at most "
                f"{_DT_PER_DELAY:g} delays)")


def _dominant(m, c, k, P, D, delay, digital):
    """Dominant root of each run's loop: the continuous delayed loop, or the sampled one."""
    if digital is None:
        return dominant_roots(m, c, k, P, D, delay)
    from phoid.dynamics.digital import digital_roots

    return digital_roots(m, c, k, P, D, digital).dominant


def _prepare(data, P, D, delay, start, names, need_fc: bool, added_mass=None,
             digital=None, bias=None, u=None) -> _Setup:
    from phoid.methods.identification import identify_data

    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    names = list(names) if names is not None else [f"run{i + 1}" for i in range(n)]
    if len(names) != n:
        raise ExperimentError(f"`names` must have one entry per run ({n}); got {len(names)}")
    P = _as_gains("P", P, n)
    D = _as_gains("D", D, n)
    dm = np.zeros(n) if added_mass is None else _as_gains("added_mass", added_mass, n)
    if np.any(dm < 0):
        j = int(np.flatnonzero(dm < 0)[0])
        raise ExperimentError(f"{names[j]}: `added_mass` must be ≥ 0 kg; got {dm[j]}")
    bs = np.zeros(n) if bias is None else _as_gains("bias", bias, n)
    if np.any(bs < 0):
        j = int(np.flatnonzero(bs < 0)[0])
        raise ExperimentError(f"{names[j]}: `bias` must be ≥ 0 N; got {bs[j]}")
    if digital is not None:
        from phoid.dynamics.digital import DigitalPD

        if not isinstance(digital, DigitalPD):
            raise ExperimentError(f"`digital` must be a phoid.DigitalPD; got {digital!r}")
        if delay is not None:
            raise ExperimentError(
                "`delay` must be None with a digital loop: its command delay is "
                f"`delay_samples` whole samples; got delay={delay!r}")
        if np.any(bs > 0):
            j = int(np.flatnonzero(bs > 0)[0])
            raise ExperimentError(
                f"{names[j]}: bias = {bs[j]:g} N with a sampled (digital) loop: not supported "
                "by the friction fit (the biased sampled loop's record jumps where a velocity "
                "reversal crosses a controller instant, and the fit is unreliable there); "
                "record the runs without bias, or with a continuous-delay model of the loop")
        # the equivalent continuous delay (d samples and half a sample of hold): only for the
        # starting point, the windows' margins and the reported c′, k′
        delay = digital.delay + 0.5 * digital.sample_time
    else:
        try:
            delay = float(delay)
        except (TypeError, ValueError):
            raise ExperimentError(f"`delay` must be a real number (s); got {delay!r}") from None
        if not (math.isfinite(delay) and delay >= 0):
            raise ExperimentError(f"`delay` must be finite and ≥ 0 s; got {delay}")
    st = _check_start(start)
    surveys = []
    for i, run in enumerate(data):
        try:
            t, x = run
        except (TypeError, ValueError):
            raise ExperimentError(f"{names[i]}: each run must be a pair (t, x)") from None
        t, x = _check_run(names[i], t, x)
        surveys.append(_survey(names[i], t, x))
    _check_time_base(names, surveys, delay)
    # the recorded force (continuous loops): u = −P x(t − Δt) − D ẋ(t − Δt) + b sign(ẋ(t − Δt))
    warnings: list[str] = _check_u(names, surveys, u, P, D, delay, bs) \
        if u is not None and digital is None else []
    reasons = [s.reason for s in surveys]
    cand = [i for i in range(n) if reasons[i] is None]
    if not cand:
        raise IdentificationError(
            "no usable runs: " + "; ".join(f"{names[i]}: {reasons[i]}" for i in range(n))
        )
    release = np.array([s.release for s in surveys])
    offset = np.array([s.final for s in surveys])
    omega = np.full(n, math.nan)
    if start is None:
        try:
            visc = identify_data([data[i] for i in cand], P[cand], D[cand],
                                 delay if digital is None else None,
                                 names=[names[i] for i in cand], added_mass=dm[cand],
                                 digital=digital)
        except (IdentificationError, ValueError, ArithmeticError) as exc:
            cause = str(exc) if isinstance(exc, PhoidError) else None
            hint = "; ".join(warnings) or None
            raise _StartError(
                f"no viscous starting point for the friction fit"
                f"{f' ({cause})' if cause else ''}{f'; {hint}' if hint else ''}; pass "
                "`start=(m, c, k)` or `start=(m, c, k, fc)`", cause, hint
            ) from None
        m0, c0, k0 = visc.m.value, visc.c.value, visc.k.value
        fc0 = None
        for i, rm in zip(cand, visc.runs, strict=True):
            if rm.fit is not None:
                release[i] = rm.fit.release
                offset[i] = rm.fit.offset
                if rm.fit.omega_d > 0:
                    omega[i] = rm.fit.omega_d
    else:
        m0, c0, k0 = st[:3]
        fc0 = st[3] if len(st) == 4 else None
    if not (m0 > 0 and math.isfinite(c0) and math.isfinite(k0)):
        cause = (f"the viscous identification gives m = {m0:.6g} kg, c = {c0:.6g} N s/m, "
                 f"k = {k0:.6g} N/m")
        hint = "; ".join(warnings) or None
        raise _StartError(f"no physical starting point for the friction fit ({cause}"
                          f"{f'; {hint}' if hint else ''}); pass `start=(m, c, k)`", cause, hint)
    todo = [i for i in cand if not omega[i] > 0]
    if todo:
        for added in np.unique(dm[todo]):  # one plant per added mass
            g = [i for i in todo if dm[i] == added]
            try:
                omega[g] = np.abs(_dominant(m0 + added, c0, k0, P[g], D[g], delay,
                                            digital).imag)
            except (ValueError, RuntimeError):
                pass
    for i in cand:
        if not omega[i] > 0:
            omega[i] = math.sqrt(max(abs(k0 + P[i]) / (m0 + dm[i]), 1e-12))
    cands, offs = _envelope_guess([surveys[i] for i in cand], P[cand], D[cand], delay, m0, c0,
                                  k0, omega[cand], release[cand], dm[cand], bs[cand])
    for i, b in zip(cand, offs, strict=True):
        if math.isfinite(b):
            offset[i] = b
    if start is None and need_fc:
        candidates = cands
    else:
        fc = cands[0][3] if fc0 is None and need_fc else (fc0 or 0.0)
        candidates = [np.array([m0, c0, k0, fc])]
    dts = [float(np.median(np.diff(surveys[i].t))) for i in cand]
    fs = 1.0 / min(dts)
    if digital is not None:  # a whole number of steps per controller sample
        fs = max(1, math.ceil(fs * digital.sample_time - 1e-9)) / digital.sample_time
    elif delay > 0:
        fs = math.ceil(fs * delay - 1e-9) / delay  # a whole number of steps per delay
    return _Setup(names, P, D, delay, surveys, reasons, candidates[0], candidates, release,
                  offset, omega, fs, warnings, dm, digital, bs)


def _windows(setup: _Setup, idx: list[int]) -> np.ndarray:
    out = []
    for i in idx:
        s = setup.surveys[i]
        period = 2 * math.pi / setup.omega[i]
        margin = max(_MARGIN_PERIODS * period, _MARGIN_MIN, 4 * setup.delay)
        out.append(min(float(s.t[-1]), s.motion_end + margin))
    return np.array(out)


def _early_windows(setup: _Setup, idx: list[int], release: np.ndarray) -> np.ndarray:
    """Ends of the first half of each run's motion (at least two periods of it, where it has
    them): the stage-1 windows, which hold no sticking (module docstring)."""
    full = _windows(setup, idx)
    out = []
    for j, i in enumerate(idx):
        moving = setup.surveys[i].motion_end - release[j]
        period = 2 * math.pi / setup.omega[i]
        out.append(min(full[j], release[j] + max(0.5 * moving, min(2.0 * period, moving))))
    return np.array(out)


def _fit(setup: _Setup, idx: list[int], theta0: np.ndarray, local0: np.ndarray,
         free: tuple[bool, ...], max_iter: int, *, t_end: np.ndarray | None = None,
         tol: float = 0.1, confirm: bool = True):
    surveys = [setup.surveys[i] for i in idx]
    t_end = _windows(setup, idx) if t_end is None else t_end
    prob = _Problem(surveys, t_end, setup.P[idx], setup.D[idx], setup.delay, setup.fs, free,
                    setup.dm[idx], setup.digital, setup.bias[idx])
    fixed = theta0.copy()
    p0 = np.concatenate([theta0[np.array(free)], local0.ravel()])
    res = _levenberg_marquardt(prob, p0, fixed, max_iter=max_iter, tol=tol, confirm=confirm)
    return prob, fixed, res


def _motion_facts(prob: _Problem, local: np.ndarray, XV) -> list[tuple[float | None, int]]:
    """Per run: stick time on the record's clock (None if still moving at the window's end)
    and the velocity reversals before it."""
    _, V = XV
    out = []
    for i in range(prob.B):
        tau = local[i, 2]
        nwin = min(V.shape[1], math.ceil((prob.t_end[i] - tau) / prob.h) + 1)
        v = V[i, :nwin]
        nz = np.flatnonzero(v != 0.0)
        sv = np.sign(v[nz])
        reversals = int(np.count_nonzero(sv[1:] != sv[:-1]))
        if nz.size == 0:
            out.append((float(tau), 0))
            continue
        last = int(nz[-1])
        # stuck for good: at rest for longer than the delay before the window ends (after Δt
        # the feedback is constant and cannot unstick it)
        rest = (nwin - 1 - last) * prob.h
        if last < nwin - 1 and rest > prob.settle + 2 * prob.h:
            # the velocity falls linearly into the stop: extrapolate its last two samples
            a = (v[last] - v[last - 1]) / prob.h if last > 0 else 0.0
            ts = last * prob.h + (min(-v[last] / a, prob.h) if a * v[last] < 0 else 0.0)
            out.append((float(tau + ts), reversals))
        else:
            out.append((None, reversals))
    return out


# --------------------------------------------------------------------------------------------
# public API


@single_blas_thread
def identify_friction(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    start: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    max_iter: int = 40,
    added_mass: Sequence[float] | None = None,
    digital: Any = None,
    bias: Sequence[float] | None = None,
    u: Sequence[np.ndarray | None] | None = None,
) -> FrictionFit:
    """Estimate m, c, k and the kinetic friction force f_c from a PHO experiment set.

    Full-record maximum-likelihood fit of every run through the exact stick–slip simulator of
    m x'' + c x' + k x + f_c sign(x') = −[Dᵢ x'(t − Δt) + Pᵢ x(t − Δt)] (seed eqs. 1 and 23);
    see the module docstring for the model, the estimator and the runs it sets aside.

    Parameters
    ----------
    data : sequence of (t, x)
        Each run's sample times (s, strictly increasing) and measured positions (m), held
        segment before the release included — the arrays :func:`phoid.identify_data` takes.
    P, D : array_like, shape (n,)
        Gains of each run, N/m and N·s/m.
    delay : float or None
        Loop delay Δt, s (known); None with ``digital``.
    start : sequence of float, optional
        Starting (m, c, k) or (m, c, k, f_c). By default m, c, k come from the viscous
        dominant-mode identification (:func:`phoid.identify_data`) and f_c from the envelope's
        linear part.
    names : sequence of str, optional
        Run names for messages (default ``run1`` …).
    max_iter : int, default 40
        Levenberg–Marquardt iterations per fit.
    added_mass : array_like, shape (n,), optional
        Known mass added in each run, kg (≥ 0; the paper's added-mass trick): run i's plant is
        m + Δmᵢ, and m is the mass without additions.
    digital : phoid.DigitalPD, optional
        A sampled controller (its gains are ignored): the records are then modelled by the
        sampled-loop simulator (zero-order hold, d-sample command delay, the loop's velocity
        estimator), its clock started at each run's release; ``delay`` must be None.
    bias : array_like, shape (n,), optional
        Known DC offset bᵢ ≥ 0 (N) of each run's command in the direction of the controller's
        velocity, + bᵢ sign(ẋ(t − Δt)) (or + bᵢ sign(v̂) of a sampled loop): the seed's
        augmented PD feedback (Discussion, last paragraph); default none.
    u : sequence of ndarray or None, optional
        Each run's recorded feedback force, N, on the run's sample times (None where not
        recorded). Used as a check only (continuous loops): the gains u implies, by least
        squares of u − bᵢ sign(ẋ(t − Δt)) on x(t − Δt), ẋ(t − Δt) and a constant, must agree
        with (Pᵢ, Dᵢ) to 20 % of the force swing; runs that do not are named in a warning with
        the probable cause (D's sign convention, u's sign, the units of x or u, the gains or
        the delay).

    Returns
    -------
    FrictionFit
        m, c, k, f_c with standard errors, their covariance, per-run fitted nuisances, closed-
        loop σᵢ and stick times, χ²/dof and warnings.

    Raises
    ------
    ExperimentError
        Malformed input (the message names the run and the field).
    IdentificationError
        No usable run (all set aside: no motion, growing, friction stops the motion within a
        cycle), or no starting point.

    Examples
    --------
    >>> import numpy as np
    >>> from phoid import Plant, simulate
    >>> P, D = np.array([0.0, 100.0, 200.0]), np.array([-1.6, 0.6, 2.8])
    >>> sim = simulate(Plant(1.0, 2.0, 100.0, fc=0.05), P, D, delay=0.02, duration=4.0,
    ...                fs=1000.0, x0=0.008, hold=0.2, noise=1e-5,
    ...                rng=np.random.default_rng(1))
    >>> fit = identify_friction([(sim.t, x) for x in sim.x], P, D, 0.02)
    >>> round(fit.fc.value, 2), round(fit.c.value, 1)
    (0.05, 2.0)
    """
    setup = _prepare(data, P, D, delay, start, names, need_fc=True, added_mass=added_mass,
                     digital=digital, bias=bias, u=u)
    n = len(setup.surveys)
    reasons = list(setup.reasons)
    idx = [i for i in range(n) if reasons[i] is None]
    theta = setup.start.copy()
    local = np.array([[s.level - setup.offset[i], setup.offset[i], setup.release[i]]
                      for i, s in enumerate(setup.surveys)])
    free = (True, True, True, True)
    # stage 1: the first half of each run's motion, loosely (to 2 stderr), so that stage 2
    # starts in the right basin: a model that sticks one half-cycle too early is a local
    # optimum of the full records (the missing half-cycle has no sensitivity), not of these
    early = _early_windows(setup, idx, local[idx, 2])
    if len(setup.candidates) > 1:  # the candidate start that fits these windows best
        probe = _Problem([setup.surveys[i] for i in idx], early, setup.P[idx], setup.D[idx],
                         setup.delay, setup.fs, free, setup.dm[idx], setup.digital,
                         setup.bias[idx])
        costs = []
        for th in setup.candidates:
            XV = probe.simulate(th, local[idx, 0], local[idx, 2])
            r = probe.residual(local[idx], XV) if XV is not None else None
            costs.append(float(r @ r) if r is not None else math.inf)
        theta = setup.candidates[int(np.argmin(costs))].copy()
        setup.start = theta.copy()
    prob, fixed, res = _fit(setup, idx, theta, local[idx], free, max_iter, t_end=early,
                            tol=2.0, confirm=False)
    iterations = res.iterations
    theta, local[idx] = prob.split(res.p, fixed)
    while True:
        prob, fixed, res = _fit(setup, idx, theta, local[idx], free, max_iter)
        iterations += res.iterations
        theta_f, local_f = prob.split(res.p, fixed)
        facts = _motion_facts(prob, local_f, res.XV)
        short = [idx[j] for j, (ts, rev) in enumerate(facts)
                 if ts is not None and rev < _MIN_REVERSALS]
        if not short:
            break
        for j, i in enumerate(idx):
            local[i] = local_f[j]
        for i in short:
            reasons[i] = ("friction stops the motion within a cycle "
                          f"({facts[idx.index(i)][1]} velocity reversals before it sticks)")
        idx = [i for i in idx if i not in short]
        if not idx:
            raise IdentificationError(
                "no usable runs: " + "; ".join(f"{setup.names[i]}: {reasons[i]}"
                                               for i in range(n))
            )
        theta = theta_f
    return _result(setup, idx, reasons, prob, fixed, res, facts, iterations)


def _result(setup, idx, reasons, prob, fixed, res, facts, iterations) -> FrictionFit:
    theta, local = prob.split(res.p, fixed)
    m, c, k, fc = (float(a) for a in theta)
    J = res.J
    dof = max(J.shape[0] - J.shape[1], 1)
    chi2 = res.cost
    warnings = list(setup.warnings)
    try:
        cov = J.normal().inv_globals()[:4, :4] * (chi2 / dof)
    except np.linalg.LinAlgError:
        cov = np.full((4, 4), math.nan)
        warnings.append("the Jacobian is singular: m, c, k, fc are not all determined")
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    vals, _, _ = prob.model(local, res.XV)
    resid = [prob.y[j] - vals[j] for j in range(prob.B)]
    rms_all = float(np.sqrt(np.mean(np.concatenate(resid) ** 2)))
    roots = np.full(len(setup.surveys), complex(math.nan, math.nan))
    for added in np.unique(setup.dm):  # one plant per added mass
        g = np.flatnonzero(setup.dm == added)
        try:
            roots[g] = _dominant(m + added, c, k, setup.P[g], setup.D[g], setup.delay,
                                 setup.digital)
        except (ValueError, RuntimeError):
            pass
    runs = []
    n = len(setup.surveys)
    for i in range(n):
        s = setup.surveys[i]
        sig, wd = float(-roots[i].real), float(abs(roots[i].imag))
        w: list[str] = []
        if i in idx:
            j = idx.index(i)
            ts, rev = facts[j]
            x0, b, tau = (float(a) for a in local[j])
            rms = float(np.sqrt(np.mean(resid[j] ** 2)))
            if ts is not None and ts < float(s.t[-1]):
                w.append(f"the motion sticks at t = {ts:.4g} s, before the record ends "
                         f"({float(s.t[-1]):.4g} s)")
            if sig < 0:
                w.append(f"closed loop negatively damped (σ = {sig:.3g} 1/s, c′ < −c): the "
                         "record is bounded by friction (bullet-shaped envelope); used")
            if rms > 2.0 * s.sd:
                w.append(f"misfit: residual rms {rms:.3g} m is {rms / s.sd:.3g} times the "
                         f"noise sd {s.sd:.3g} m")
            runs.append(FrictionRun(s.name, float(setup.P[i]), float(setup.D[i]), True, tau,
                                    x0, b, sig, wd, ts, rev, float(prob.t_end[j]),
                                    int(prob.n[j]), s.sd, rms, tuple(w),
                                    float(setup.dm[i]), float(setup.bias[i])))
        else:
            w.append(f"set aside: {reasons[i]}")
            runs.append(FrictionRun(s.name, float(setup.P[i]), float(setup.D[i]), False,
                                    float(setup.release[i]), float(s.level - setup.offset[i]),
                                    float(setup.offset[i]), sig, wd, None, -1, float(s.t[-1]),
                                    0, s.sd, math.nan, tuple(w), float(setup.dm[i]),
                                    float(setup.bias[i])))
        warnings.extend(f"{s.name}: {x}" for x in w)
    if not res.converged:
        warnings.append(f"the fit did not converge in {iterations} iterations: the estimates "
                        "are not at the likelihood's optimum")
    if fc <= 0.0:
        warnings.append("fc is at its bound 0: no friction detected (its stderr is that of "
                        "the unconstrained estimate)")
    chi2_red = chi2 / dof
    if chi2_red > 1.0 + 5.0 * math.sqrt(2.0 / dof) and chi2_red > 1.2:
        warnings.append(f"chi2/dof = {chi2_red:.3g}: the model does not fit the records to "
                        "their noise (stderr scaled up accordingly): check the delay, the "
                        "gains or unmodelled dynamics")
    if len(idx) < 3:
        warnings.append(f"only {len(idx)} usable runs: m, c, k, fc are barely determined")
    return FrictionFit(
        m=Estimate(m, float(se[0]), _UNITS[0]), c=Estimate(c, float(se[1]), _UNITS[1]),
        k=Estimate(k, float(se[2]), _UNITS[2]), fc=Estimate(fc, float(se[3]), _UNITS[3]),
        cov=cov, delay=setup.delay if setup.digital is None else setup.digital.delay,
        runs=tuple(runs), chi2=chi2, dof=dof,
        residual_rms=rms_all, converged=res.converged, iterations=iterations,
        start=tuple(float(a) for a in setup.start), warnings=tuple(warnings),
        digital=setup.digital,
    )


@single_blas_thread
def friction_evidence(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    start: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    alpha: float = 1e-3,
    added_mass: Sequence[float] | None = None,
    digital: Any = None,
    bias: Sequence[float] | None = None,
) -> FrictionEvidence:
    """Score test of f_c = 0: is there Coulomb friction in a PHO set fitted as viscous?

    Fits the records by the friction-free model (full-record maximum likelihood, fast: no
    stick–slip events), then evaluates the profiled score of f_c at f_c = 0⁺ (module docstring):
    z = jᵀr/(s‖Πj‖), standard normal without friction.

    Parameters
    ----------
    data, P, D, delay, names, added_mass, digital, bias
        As for :func:`identify_friction`.
    start : sequence of float, optional
        Starting (m, c, k) for the viscous fit, e.g. a viscous identification's estimates
        (default: :func:`phoid.identify_data`).
    alpha : float, default 1e−3
        Significance level of ``detected``.

    Returns
    -------
    FrictionEvidence
    """
    if not 0 < alpha < 1:
        raise ValueError(f"`alpha` must be in (0, 1); got {alpha!r}")
    if start is not None:
        start = tuple(start)[:3]
    setup = _prepare(data, P, D, delay, start, names, need_fc=False, added_mass=added_mass,
                     digital=digital, bias=bias)
    n = len(setup.surveys)
    idx = [i for i in range(n) if setup.reasons[i] is None]
    theta = setup.start.copy()
    theta[3] = 0.0
    local = np.array([[setup.surveys[i].level - setup.offset[i], setup.offset[i],
                       setup.release[i]] for i in idx])
    prob, fixed, res = _fit(setup, idx, theta, local, (True, True, True, False), 40)
    theta_f, local_f = prob.split(res.p, fixed)
    # sensitivity to f_c at 0⁺ by a forward difference
    h = prob.steps(theta_f, local_f)[3]
    th = theta_f.copy()
    th[3] = h
    XVp = prob.simulate(th, local_f[:, 0], local_f[:, 2])
    if XVp is None:
        raise IdentificationError("the friction sensitivity cannot be simulated")
    _, posts, herm = prob.model(local_f, res.XV)
    jcol = []
    for i in range(prob.B):
        u = np.maximum(prob.t[i] - local_f[i, 2], 0.0)
        hv, _ = _hermite(XVp[0][i], XVp[1][i], prob.h, u)
        jcol.append(np.where(posts[i], (hv - herm[i][0]) / h, 0.0) * prob.w[i])
    j = np.concatenate(jcol)
    J = res.J
    r = prob.residual(local_f, res.XV)
    dof = max(J.shape[0] - J.shape[1] - 1, 1)
    s2 = res.cost / dof
    A = J.normal()
    coef = A.solve(J.tdot(j))
    jp = j - J.dot(coef)  # Πj
    info = float(jp @ jp)
    score = float(jp @ r)
    z = score / math.sqrt(s2 * info) if info > 0 else 0.0
    p_value = float(stats.norm.sf(z))
    fc1 = score / info if info > 0 else 0.0
    se = np.sqrt(np.clip(np.diag(A.inv_globals())[:3] * s2, 0.0, None))
    warnings = [f"{setup.names[i]}: set aside: {setup.reasons[i]}" for i in range(n)
                if setup.reasons[i] is not None]
    if not res.converged:
        warnings.append("the viscous full-record fit did not converge")
    detected = p_value < alpha
    if detected:
        warnings.append(f"friction detected (score z = {z:.3g}, p = {p_value:.2g}; first "
                        f"estimate fc ≈ {fc1:.3g} N): fit it with identify_friction")
    return FrictionEvidence(
        z=float(z), p_value=p_value, detected=bool(detected),
        fc=Estimate(float(fc1), float(math.sqrt(s2 / info)) if info > 0 else None, "N"),
        m=Estimate(float(theta_f[0]), float(se[0]), "kg"),
        c=Estimate(float(theta_f[1]), float(se[1]), "N s/m"),
        k=Estimate(float(theta_f[2]), float(se[2]), "N/m"),
        chi2_red=float(res.cost / dof), warnings=tuple(warnings),
    )


def identify_friction_set(experiment: Any, *, delay: float | None = None) -> FrictionFit:
    """:func:`identify_friction` on an experiment set (``phoid identify --friction``).

    Parameters
    ----------
    experiment : phoid.io.experiment.ExperimentSet
        A ``pho`` set with a known loop delay (``[loop] delay``), or a sampled controller
        (``[loop] sample_time``, ``delay_samples``, ``velocity``, ``cutoff``).
    delay : float, optional
        Loop delay Δt (s), overriding the manifest's (continuous loops only).

    Raises
    ------
    IdentificationError
        A set the friction fit does not model (not ``pho``, no delay), conflicting loop keys,
        or no usable run; the message names the set.
    """
    from phoid.methods.identification import read_digital_loop

    where = str(getattr(experiment, "path", "experiment"))
    if getattr(experiment, "method", "pho") != "pho":
        raise IdentificationError(f"{where}: --friction applies to PHO sets (method = \"pho\")")
    digital = read_digital_loop(experiment)
    runs = list(experiment.runs)
    if digital is not None:
        if delay is not None or experiment.delay is not None:
            raise IdentificationError(
                f"{where}: [loop] delay: a digital loop (sample_time) takes its delay as "
                "delay_samples, in whole samples; give one or the other")
    else:
        delay = experiment.delay if delay is None else delay
        if delay is None:
            raise IdentificationError(f"{where}: [loop] delay: the friction fit needs the loop "
                                      "delay (give it in the manifest or with --delay)")
        delay = float(delay)
    try:
        return identify_friction([(r.t, r.x) for r in runs],
                                 np.array([r.P for r in runs], dtype=float),
                                 np.array([r.D for r in runs], dtype=float), delay,
                                 names=[r.file for r in runs],
                                 added_mass=[getattr(r, "added_mass", 0.0) for r in runs],
                                 digital=digital,
                                 bias=[getattr(r, "bias", 0.0) for r in runs],
                                 u=[getattr(r, "u", None) for r in runs])
    except ExperimentError as exc:
        raise ExperimentError(f"{where}: {exc}") from None
    except _StartError as exc:  # in the command line's words (no `start=`)
        cause = f" ({exc.cause})" if exc.cause else ""
        hint = exc.hint or (
            "check the loop delay ([loop] delay or --delay), the gains' sign convention "
            "(u = -P x(t - delay) - D x'(t - delay)) and the units of t (s) and x (m)")
        raise IdentificationError(
            f"{where}: the friction fit needs the viscous identification of the same runs as "
            f"its starting point, and it failed{cause}: {hint}") from None
    except IdentificationError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
