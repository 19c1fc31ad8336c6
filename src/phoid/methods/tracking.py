r"""Output-error identification of a PD-controlled axis from its tracking record.

Most rigs record the position x and the reference r but no force. With the controller known
(:class:`~phoid.dynamics.controller.SampledController`: gains, estimator, saturation, command
gain, delay), the loop driven by the recorded r is simulated exactly
(:func:`~phoid.simulation.tracking.simulate_tracking`, from the recorded state and history) and
the plant parameters θ = (m, c, k, f_c, f₀) — those not fixed — and, when asked, the command
delay τ are those that minimise Σ (x_n − x_n^sim(θ))² over all runs (``scipy.optimize.
least_squares``, trust region, forward-difference Jacobian: the simulation is exact to rounding,
so the differences are clean).

Uncertainty. The residual of a real record is mostly model error and strongly autocorrelated
(lag-1 autocorrelation ≈ 1 at 1 kHz), so the white-noise covariance σ²(JᵀJ)⁻¹ is far too small.
The reported stderrs are the Newey–West ones (:mod:`phoid.fits.hac`); the white-noise ones are
kept in the result only to show by how much they would understate.

The delay. The command delay τ and the mass are nearly confounded in a stiff tracking loop: a
little more delay and a little less mass shape the tracking error alike. When τ is estimated,
the result reports corr(m, τ) and, where |corr| > 0.95, warns that m and τ are not separable
and that τ should be given.

Start. The fit starts from an inverse-dynamics least-squares estimate
(:func:`~phoid.methods.idim.idim_ls`) on the force that the known controller computes from the
recorded x and r (or on the recorded command u when there is one), so no guess is asked of the
user.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from phoid.dynamics.controller import SampledController, closed_loop_poles
from phoid.dynamics.plant import Plant
from phoid.fits.hac import hac_covariance
from phoid.methods.estimate import Estimate
from phoid.reports.display import NotebookDisplay
from phoid.reports.text import format_number
from phoid.simulation.tracking import TrackingSimulation, simulate_tracking

__all__ = [
    "MAX_POSITION",
    "PARAMETERS",
    "TrackingFit",
    "TrackingRecord",
    "check_parameters",
    "check_stable",
    "controller_commands",
    "fit_tracking",
    "fit_tracking_runs",
    "replay",
]

PARAMETERS = ("m", "c", "k", "fc", "offset", "delay")
UNITS = {"m": "kg", "c": "N s/m", "k": "N/m", "fc": "N", "offset": "N", "delay": "s"}
CONFOUNDED = 0.95  # |corr(m, τ)| above which the delay is reported as not separable
MAX_POSITION = 1e6  # m: a record beyond this is in another unit (or broken), not a machine


@dataclass(frozen=True, eq=False)
class TrackingRecord:
    """One tracking run: what was recorded and the controller that ran.

    Attributes
    ----------
    x : numpy.ndarray, shape (N,)
        Recorded position at the controller instants, m.
    r : numpy.ndarray, shape (N,)
        Reference, m.
    controller : SampledController
        The loop (its ``delay`` is used unless the fit estimates τ).
    u : numpy.ndarray or None
        Recorded command, command units (used for the start and the validation).
    w : numpy.ndarray or None
        Additive command input as the plant receives it, command units.
    u_contains_w : bool
        Whether the recorded u already holds w: u = u_c + w, the controller's output u_c with
        the input added, clipped with it, F = G·sat(u) (as the EMPS benchmark's validation
        record is made; :mod:`phoid.methods.tracking_semantics` measures it); or (the default)
        u is u_c alone and w is added after the saturation, F = G·(sat(u) + w).
    t0 : float
        Time of the first sample, s.
    name : str
        How messages name the run.
    """

    x: np.ndarray
    r: np.ndarray
    controller: SampledController
    u: np.ndarray | None = None
    w: np.ndarray | None = None
    t0: float = 0.0
    name: str = "run 1"
    u_contains_w: bool = False

    def __post_init__(self) -> None:
        x = _vector(self.name, "x", self.x)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "r", _vector(self.name, "r", self.r, x.size))
        for key in ("u", "w"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, _vector(self.name, key, getattr(self, key), x.size))
        if not isinstance(self.controller, SampledController):
            raise ValueError(f"{self.name}: `controller` must be a SampledController")
        if self.u_contains_w and (self.u is None or self.w is None):
            raise ValueError(f"{self.name}: u_contains_w needs both the recorded command u and "
                             "the additive input w")
        for key in ("x", "r"):
            top = float(np.max(np.abs(getattr(self, key))))
            if top > MAX_POSITION:
                raise ValueError(
                    f"{self.name}: {key}: values up to {top:.3g} m; phoid takes positions within "
                    f"±{MAX_POSITION:g} m (check the unit of the record)"
                )
        need = self.controller.taps + 8
        if x.size < need:
            raise ValueError(
                f"{self.name}: x: the record has {x.size} samples; the velocity estimator reads "
                f"{self.controller.taps + 1} and a fit needs at least {need}"
            )

    @property
    def controller_u(self) -> np.ndarray | None:
        """The controller's own output u_c as recorded: u, less w where u contains it (None
        without u), command units."""
        if self.u is None or not self.u_contains_w:
            return self.u
        return self.u - self.w

    @property
    def start(self) -> int:
        """First simulated instant: the estimator's taps of recorded history before it."""
        return max(self.controller.taps, 1)

    @property
    def start_state(self) -> tuple[float, float]:
        """The recorded state at :attr:`start`: x_s (m) and (x_{s+1} − x_{s−1})/(2T) (m/s)."""
        s = self.start
        return (float(self.x[s]),
                float(self.x[s + 1] - self.x[s - 1]) / (2.0 * self.controller.sample_time))

    @property
    def state_scales(self) -> tuple[float, float]:
        """Typical sizes of the start state's uncertainty: the sample-to-sample scatter of x
        (m) and that over 2T (m/s), for the fit's scaling."""
        dx = np.diff(self.x[: min(self.x.size, 200)])
        sx = max(float(np.std(dx)), 1e-9 * float(np.max(np.abs(self.x))), 1e-15)
        return sx, sx / self.controller.sample_time


@dataclass(frozen=True, eq=False, repr=False)
class TrackingFit(NotebookDisplay):
    """The result of :func:`fit_tracking`.

    Attributes
    ----------
    estimates : Mapping[str, Estimate]
        ``m`` (kg), ``c`` (N s/m), ``k`` (N/m), ``fc`` (N), ``offset`` (N), ``delay`` (s): the
        value and its autocorrelation-robust stderr (a fixed parameter: its value, stderr 0).
    free : tuple of str
        The parameters fitted, in the order of the covariance.
    covariance : numpy.ndarray
        Newey–West covariance of the free parameters.
    white_stderr : Mapping[str, float]
        The white-noise stderrs σ·sqrt(diag (JᵀJ)⁻¹) — invalid for this residual, kept to show it.
    correlation : numpy.ndarray
        Correlation matrix of the free parameters (from the robust covariance).
    bandwidth : int
        Newey–West lag window, samples.
    lag1_autocorrelation : float
        Of the position residual.
    rms_residual : float
        sqrt(mean (x − x_sim)²), m.
    relative_error : float
        100·‖e − e_sim‖/‖e‖ of the tracking error e = x − r over all runs, %.
    simulations : tuple of TrackingSimulation
        Each run simulated with the estimates.
    records : tuple of TrackingRecord
    nfev : int
        Simulations of the whole set during the fit.
    delay_status : str
        ``"given"`` (τ was not fitted), ``"estimated"``, ``"confounded"`` (|corr(m, τ)| >
        0.95: m's stderr is the widened one with τ free) or ``"on-bound"`` (the best τ is 0 or
        5T, where no ± exists: the record does not determine it; give the delay).
    warnings : tuple of str
    converged : bool
        Whether the optimiser converged (else a warning says why it stopped).
    white_covariance : numpy.ndarray or None
        The white-noise covariance σ²(JᵀJ)⁻¹ of the free parameters (the start states
        profiled), whose diagonal ``white_stderr`` gives.
    """

    estimates: Mapping[str, Estimate]
    free: tuple[str, ...]
    covariance: np.ndarray
    white_stderr: Mapping[str, float]
    correlation: np.ndarray
    bandwidth: int
    lag1_autocorrelation: float
    rms_residual: float
    relative_error: float
    simulations: tuple[TrackingSimulation, ...]
    records: tuple[TrackingRecord, ...]
    nfev: int
    delay_status: str = "given"
    warnings: tuple[str, ...] = field(default=())
    converged: bool = True
    white_covariance: np.ndarray | None = field(default=None, repr=False)

    def corr(self, a: str, b: str) -> float | None:
        """corr(a, b) of two free parameters (None when either is fixed)."""
        if a not in self.free or b not in self.free:
            return None
        return float(self.correlation[self.free.index(a), self.free.index(b)])

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: estimates, fit statistics, correlations, warnings."""
        return {
            "method": "output-error",
            "parameters": {k: e.to_dict() for k, e in self.estimates.items()},
            "free": list(self.free),
            "white_noise_stderr": {k: float(v) for k, v in self.white_stderr.items()},
            "correlation": np.asarray(self.correlation, dtype=float).tolist(),
            "hac_bandwidth": int(self.bandwidth),
            "lag1_autocorrelation": float(self.lag1_autocorrelation),
            "rms_residual": float(self.rms_residual),
            "relative_error_percent": float(self.relative_error),
            "n_evaluations": int(self.nfev),
            "delay_status": self.delay_status,
            "warnings": list(self.warnings),
        }


def controller_commands(x: np.ndarray, r: np.ndarray, ctrl: SampledController,
                        w: np.ndarray | None = None) -> np.ndarray:
    """The commands u_n = K·(P·(r_n − x_n) − D·v̂_n) the controller computes from a record.

    The velocity estimate runs over x with the samples before the first repeated (a record
    that starts at rest); units: command units, before saturation (``w`` is not added: it
    enters after the saturation).
    """
    from scipy.signal import lfilter

    b, a = ctrl.velocity_filter()
    pad = 4 * max(b.size, a.size)
    xp = np.concatenate((np.full(pad, x[0]), x))
    vhat = lfilter(b, a, xp)[pad:]
    return ctrl.gain * (ctrl.P * (r - x) - ctrl.D * vhat)


def replay(record: TrackingRecord, plant: Plant, *, offset: float = 0.0,
           controller: SampledController | None = None, x0: float | None = None,
           v0: float | None = None) -> TrackingSimulation:
    """Simulate a record's loop with given parameters, driven by its reference, from its state.

    The simulation starts at :attr:`TrackingRecord.start` s with the recorded positions before
    it as the estimator's history and, for the delay, the recorded commands before it (the
    controller's own part, :attr:`TrackingRecord.controller_u`, with the recorded w; or those
    the controller computes from the record). The plant's state at the start is (x0, v0),
    by default the recorded x_s and (x_{s+1} − x_{s−1})/(2T).

    Returns
    -------
    TrackingSimulation
        Covering the instants s … N − 1.
    """
    ctrl = record.controller if controller is None else controller
    x0_rec, v0_rec = record.start_state
    s = record.start
    x_init = record.x[: s + 1].copy()
    x_init[-1] = x0_rec if x0 is None else x0
    u_hist = record.controller_u
    if u_hist is None:
        u_hist = controller_commands(record.x, record.r, ctrl)
    return simulate_tracking(
        plant, ctrl, record.r[s:], offset=offset,
        w=None if record.w is None else record.w[s:],
        x_init=x_init, v0=v0_rec if v0 is None else v0, u_init=u_hist[:s],
        w_init=None if record.w is None else record.w[:s], w_in_command=record.u_contains_w,
        t0=record.t0 + s * ctrl.sample_time,
    )


def fit_tracking(x, r, controller: SampledController, *, u=None, w=None, t0: float = 0.0,
                 fixed: Mapping[str, float] | None = None,
                 estimate_delay: bool = False, u_contains_w: bool = False) -> TrackingFit:
    """Identify m, c, k, f_c, f₀ (and τ) of a PD-controlled axis from one tracking record.

    Parameters
    ----------
    x : array_like, shape (N,)
        Recorded position at the controller instants, m.
    r : array_like, shape (N,)
        Reference, m.
    controller : SampledController
        The loop that ran (its ``delay`` is used unless ``estimate_delay``).
    u : array_like, optional
        Recorded controller output (command units): the start values and the history.
    w : array_like, optional
        Additive command input (command units).
    t0 : float, default 0
        Time of the first sample, s.
    fixed : mapping, optional
        Parameters known and not fitted, e.g. ``{"k": 0.0}`` (keys among m, c, k, fc, offset).
    estimate_delay : bool, default False
        Fit the command delay τ too (bounded to [0, 5T]).
    u_contains_w : bool, default False
        Whether the recorded ``u`` already holds ``w`` (u = sat(u_c) + w;
        :func:`~phoid.methods.tracking_semantics.measure_w_in_u` tells from the record).

    Returns
    -------
    TrackingFit

    Raises
    ------
    ValueError
        One line naming the argument: mis-shaped or non-finite inputs, a record too short, a
        fixed key that is not a parameter, a loop unstable for the start values.
    """
    record = TrackingRecord(x=x, r=r, controller=controller, u=u, w=w, t0=t0,
                            u_contains_w=u_contains_w)
    return fit_tracking_runs([record], fixed=fixed, estimate_delay=estimate_delay)


def fit_tracking_runs(records: Sequence[TrackingRecord], *,
                      fixed: Mapping[str, float] | None = None,
                      estimate_delay: bool = False,
                      delay_bounds: tuple[float, float] | None = None,
                      max_nfev: int = 200) -> TrackingFit:
    """:func:`fit_tracking` over several runs of the same plant (shared parameters and delay).

    ``delay_bounds`` (s), with ``estimate_delay``: the range the delay is searched in
    (default [0, 5T]); the fit starts from the runs' controllers' delay, moved inside it.
    ``max_nfev``: the most evaluations of the optimiser (``scipy.optimize.least_squares``).
    """
    from scipy.optimize import least_squares

    records = tuple(records)
    if not records:
        raise ValueError("`records` must hold at least one TrackingRecord")
    fixed = _check_fixed(fixed)
    if estimate_delay and "delay" in fixed:
        raise ValueError("`fixed` holds 'delay' while estimate_delay=True")
    if "delay" in fixed:  # a known delay: the runs' controllers take it
        if fixed["delay"] < 0:
            raise ValueError(f"`fixed`: delay must be ≥ 0 s; got {fixed['delay']}")
        records = tuple(replace(rec, controller=rec.controller.with_delay(fixed["delay"]))
                        for rec in records)
    names = tuple(p for p in PARAMETERS[:5] if p not in fixed)
    if estimate_delay:
        names += ("delay",)
    if not names:
        raise ValueError("every parameter is fixed: nothing to fit")
    start = _stable_start(records, _start_values(records, fixed), fixed)
    T = min(rec.controller.sample_time for rec in records)
    P = len(names)
    # the start state (x_s, v_s) of each run is a nuisance parameter: the recorded one carries
    # the sensor's noise, and its transient would otherwise bias the fit
    theta0 = np.array([start[p] for p in names]
                      + [q for rec in records for q in rec.start_state])
    lower = np.array([_LOWER[p](T) for p in names] + [-np.inf] * 2 * len(records))
    upper = np.array([_UPPER[p](T) for p in names] + [np.inf] * 2 * len(records))
    if estimate_delay and delay_bounds is not None:
        lo, hi = (float(q) for q in delay_bounds)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi):
            raise ValueError(f"`delay_bounds` must be finite with 0 ≤ low < high (s); got "
                             f"{delay_bounds!r}")
        lower[names.index("delay")], upper[names.index("delay")] = lo, hi
    scale = np.array([_scale(p, start, T) for p in names]
                     + [q for rec in records for q in rec.state_scales])
    # strictly inside the bounds (an IDIM start may be negative where the bound is 0)
    theta0 = np.minimum(np.maximum(theta0, lower + 1e-3 * scale), upper - 1e-3 * scale)

    def params(theta) -> dict[str, float]:
        return {**start, **fixed,
                **dict(zip(names, (float(q) for q in theta[:P]), strict=True))}

    def simulate_all(theta):
        p = params(theta)
        plant = Plant(m=p["m"], c=p["c"], k=p["k"], fc=p["fc"])
        sims = []
        for i, rec in enumerate(records):
            ctrl = rec.controller.with_delay(p["delay"]) if estimate_delay else rec.controller
            sims.append(replay(rec, plant, offset=p["offset"], controller=ctrl,
                               x0=float(theta[P + 2 * i]), v0=float(theta[P + 2 * i + 1])))
        return sims

    n_res = sum(rec.x.size - rec.start for rec in records)
    # a trial point where the loop diverges (the optimiser's step beyond the stable region)
    # counts as a very poor fit, not as the end of the fit: a residual far above any the
    # record can give, so that the trust region rejects the step and shrinks
    penalty = 1e3 * max(float(np.max(np.abs(rec.x - rec.r))) + rec.state_scales[0]
                        for rec in records)
    diverged = [0]

    def residual(theta):
        try:
            sims = simulate_all(theta)
        except (ValueError, OverflowError, FloatingPointError):
            diverged[0] += 1
            return np.full(n_res, penalty)
        return np.concatenate([rec.x[rec.start:] - s.x for rec, s in zip(records, sims,
                                                                          strict=True)])

    sol = least_squares(residual, theta0, bounds=(lower, upper), x_scale=scale,
                        diff_step=1e-7, method="trf", xtol=1e-10, ftol=1e-12, gtol=1e-10,
                        max_nfev=max_nfev)
    theta = sol.x
    sims = simulate_all(theta)
    e = np.concatenate([rec.x[rec.start:] - s.x for rec, s in zip(records, sims, strict=True)])
    # the Jacobian at the optimum for the covariance: central differences of steps 1e-4 of
    # each parameter's scale (one-sided at a bound), so that neither rounding (≈ 1e-12
    # relative in the simulation) nor curvature matters at the printed digits
    J = _jacobian(residual, theta, e, 1e-4 * scale, lower, upper)
    cut = np.cumsum([rec.x.size - rec.start for rec in records])[:-1]
    cov = hac_covariance(np.split(J, cut), np.split(e, cut))
    robust = cov.robust[:P, :P]
    stderr = np.sqrt(np.clip(np.diag(robust), 0.0, None))
    white = np.sqrt(np.clip(np.diag(cov.white)[:P], 0.0, None))
    dsd = np.where(stderr > 0, stderr, 1.0)
    corr = robust / np.outer(dsd, dsd)
    theta, lower, upper, scale = theta[:P], lower[:P], upper[:P], scale[:P]
    p = params(theta)
    delay_status = "given"
    if estimate_delay:
        i = names.index("delay")
        on_bound = _on_bound(theta[i], lower[i], upper[i], scale[i])
        confounded = "m" in names and abs(corr[names.index("m"), i]) > CONFOUNDED
        delay_status = "on-bound" if on_bound else "confounded" if confounded else "estimated"
    estimates = {}
    for key in PARAMETERS:
        if key in names:
            i = names.index(key)
            # a parameter on its bound has no Gaussian ±: the constraint, not the data, holds it
            on_bound = _on_bound(theta[i], lower[i], upper[i], scale[i])
            estimates[key] = Estimate(p[key], None if on_bound else float(stderr[i]), UNITS[key])
        elif key == "delay":
            estimates[key] = Estimate(_common_delay(records), 0.0, UNITS[key])
        else:
            estimates[key] = Estimate(p[key], 0.0, UNITS[key])
    e_meas = np.concatenate([(rec.x - rec.r)[rec.start:] for rec in records])
    rel = 100.0 * float(np.linalg.norm(e)) / max(float(np.linalg.norm(e_meas)), 1e-300)
    warnings = _warnings(names, theta, [_on_bound(*q) for q in zip(theta, lower, upper, scale,
                                                                      strict=True)],
                         corr, stderr, cov, sims, sol)
    if diverged[0]:
        warnings.append(f"{diverged[0]} of the optimiser's trial points made the simulated loop "
                        "diverge (rejected as very poor fits); the estimates are at a stable "
                        "point")
    return TrackingFit(
        estimates=estimates, free=names, covariance=robust,
        white_stderr=dict(zip(names, (float(q) for q in white), strict=True)),
        correlation=corr, bandwidth=cov.bandwidth, lag1_autocorrelation=cov.lag1,
        rms_residual=float(np.sqrt(np.mean(e**2))), relative_error=rel,
        simulations=tuple(sims), records=records, nfev=int(sol.nfev),
        delay_status=delay_status, warnings=tuple(warnings), converged=bool(sol.success),
        white_covariance=np.asarray(cov.white[:P, :P], dtype=float),
    )


def check_parameters(values: Mapping[str, Any]) -> dict[str, float]:
    """The plant's parameters as floats, each checked by name: m finite and > 0 (kg); c, k, fc
    finite and ≥ 0; offset finite; delay finite and ≥ 0 (s). A ValueError names the first
    that is not, e.g. "`m` must be > 0 kg; got 0"."""
    out = {key: float(value) for key, value in values.items()
           if not isinstance(value, bool) and isinstance(value, (int, float, np.floating))}
    for key, value in values.items():
        if key not in out:
            raise ValueError(f"`{key}` must be a real number; got {value!r}")
        if not math.isfinite(out[key]):
            raise ValueError(f"`{key}` must be finite; got {out[key]}")
    Plant(m=out["m"], c=out["c"], k=out["k"], fc=out["fc"])  # m > 0; c, k, fc ≥ 0, by name
    if out.get("delay", 0.0) < 0:
        raise ValueError(f"`delay` must be ≥ 0 s; got {out['delay']:g}")
    return out


def _jacobian(fun, theta, f0, steps, lower, upper) -> np.ndarray:
    """Central (one-sided at a bound) differences of ``fun`` at ``theta``."""
    cols = []
    for i, h in enumerate(steps):
        up, down = theta.copy(), theta.copy()
        up[i] = min(theta[i] + h, upper[i])
        down[i] = max(theta[i] - h, lower[i])
        f_up = fun(up) if up[i] > theta[i] else f0
        f_down = fun(down) if down[i] < theta[i] else f0
        cols.append((f_up - f_down) / (up[i] - down[i]))
    return np.column_stack(cols)


# the plant model (phoid.Plant) takes m > 0 and c, k, f_c ≥ 0
_LOWER = {"m": lambda T: 1e-9, "c": lambda T: 0.0, "k": lambda T: 0.0,
          "fc": lambda T: 0.0, "offset": lambda T: -np.inf, "delay": lambda T: 0.0}
_UPPER = {"m": lambda T: np.inf, "c": lambda T: np.inf, "k": lambda T: np.inf,
          "fc": lambda T: np.inf, "offset": lambda T: np.inf, "delay": lambda T: 5.0 * T}


def _scale(name: str, start: Mapping[str, float], T: float) -> float:
    """Typical size of a parameter, for the trust region's scaling."""
    if name == "delay":
        return T
    force = max(abs(start["fc"]), abs(start["offset"]), 1e-3 * start["m"], 1e-12)
    if name in ("fc", "offset"):
        return force
    return max(abs(start[name]), 1e-6 * start["m"], 1e-12)


def _common_delay(records: Sequence[TrackingRecord]) -> float:
    return float(records[0].controller.delay)


def _check_fixed(fixed) -> dict[str, float]:
    out: dict[str, float] = {}
    for key, value in (fixed or {}).items():
        if key not in PARAMETERS:
            raise ValueError(f"`fixed`: unknown parameter {key!r}; the parameters are "
                             f"{', '.join(PARAMETERS)}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"`fixed`: {key} must be a finite number; got {value!r}")
        if key == "m" and v <= 0:
            raise ValueError(f"`fixed`: m must be > 0 kg; got {v}")
        if key == "fc" and v < 0:
            raise ValueError(f"`fixed`: fc must be ≥ 0 N; got {v}")
        out[key] = v
    return out


def _start_values(records: Sequence[TrackingRecord], fixed: Mapping[str, float]):
    """Inverse-dynamics least squares on the force the controller applied (module docstring)."""
    from phoid.methods.idim import idim_ls

    qs, fs = [], []
    for rec in records:
        ctrl = rec.controller
        u = rec.u if rec.u is not None else controller_commands(rec.x, rec.r, ctrl)
        if ctrl.saturation is not None:
            u = np.clip(u, -ctrl.saturation, ctrl.saturation)
        if rec.w is not None and not rec.u_contains_w:  # else u holds w already
            u = u + rec.w
        d = round(ctrl.delay / ctrl.sample_time)
        force = ctrl.command_gain * u
        if d:
            force = np.concatenate((np.full(d, force[0]), force[:-d]))
        qs.append(rec.x)
        fs.append(force)
    i = int(np.argmax([q.size for q in qs]))
    rec = records[i]
    T = rec.controller.sample_time
    n = qs[i].size
    decimation = int(min(10, max(1, n // 2000)))
    cutoff = 0.1 / T
    try:
        fit = idim_ls(T * np.arange(qs[i].size), qs[i], fs[i], gain=1.0, cutoff=cutoff,
                      decimation=decimation, trim=min(50, qs[i].size // 10))
        m, c, fc, f0 = (fit.M.value, fit.Fv.value, fit.Fc.value, fit.OF.value)
    except ValueError:
        m, c, fc, f0 = math.nan, 0.0, 0.0, 0.0
    if not math.isfinite(m) or m <= 0:
        m = fixed.get("m", 1.0)
    start = {"m": m, "c": c, "k": 0.0, "fc": max(fc, 0.0), "offset": f0,
             "delay": float(rec.controller.delay)}
    start.update(fixed)
    return start


# the longest delay (controller periods) for which an unstable start is retried (_stable_start)
_RETRY_DELAY = 20


def _stable_start(records: Sequence[TrackingRecord], start: dict[str, float],
                  fixed: Mapping[str, float]) -> dict[str, float]:
    """The start values, with m doubled (at most 8 times) while the loop is unstable for them.

    IDIM's mass from a noisy position is biased toward 0 (errors in variables: the noise of the
    twice-differentiated x enters the regressor: 6 times too small with 0.3 mm of noise on the
    test axis of tests/test_hostile_tracking_delay.py), and a mass too small makes a stiff
    sampled loop unstable, where no simulation can start; a heavier mass slows the loop's
    poles. Only for delays of at most :data:`_RETRY_DELAY` periods: the poles of a loop
    delayed by d periods are the roots of a polynomial of degree ≈ d (8 s at d = 900). When no
    doubling helps (or m is fixed), the first instability is reported (a ValueError naming the
    gains, as :func:`check_stable` words it).
    """
    try:
        check_stable(records, {**start, **fixed}, "the start values")
        return start
    except ValueError as first:
        if ("m" in fixed or "unstable" not in str(first)
                or any(rec.controller.delay > _RETRY_DELAY * rec.controller.sample_time
                       for rec in records)):
            raise
        error = first
    trial = dict(start)
    for _ in range(8):  # 2⁸ = 256 times IDIM's mass: beyond it the gains, not m, are wrong
        trial["m"] *= 2.0
        try:
            check_stable(records, {**trial, **fixed}, "the start values")
            return trial
        except ValueError:
            continue
    raise error


def check_stable(records: Sequence[TrackingRecord], p: Mapping[str, float], what: str) -> None:
    """A one-line ValueError when a record's linear loop is unstable for the parameters p."""
    for rec in records:
        with np.errstate(all="ignore"):  # absurd parameters overflow: no poles, said below
            try:
                poles = closed_loop_poles(p["m"], p["c"], p["k"], rec.controller)
            except ValueError as exc:
                if str(exc).startswith("`"):  # a parameter refused, by name (m ≤ 0, c = inf)
                    raise ValueError(f"{what}: {exc}") from None
                poles = np.array([np.nan])
            except (np.linalg.LinAlgError, OverflowError):
                poles = np.array([np.nan])
        rho = float(np.max(np.abs(poles), initial=0.0))
        if not np.isfinite(rho):
            raise ValueError(
                f"{rec.name}: the loop's poles cannot be computed with {what} (m = "
                f"{p['m']:.4g} kg, c = {p['c']:.4g} N s/m, k = {p['k']:.4g} N/m): the arithmetic "
                "overflows; the parameters are out of any physical range for this loop"
            )
        if rho >= 1.0:
            raise ValueError(
                f"{rec.name}: the loop is unstable for the given gains with {what} (m = "
                f"{p['m']:.4g} kg, c = {p['c']:.4g} N s/m, k = {p['k']:.4g} N/m): largest "
                f"closed-loop pole |z| = {format_number(rho, 4)} ≥ 1; check P, D, gain, "
                "command_gain and the sign convention u = K·(P·(r − x) − D·v̂)"
            )


def _on_bound(value: float, lo: float, hi: float, scale: float) -> bool:
    """Whether a fitted value sits on a (finite) bound: within 1e-3 of its scale (for the
    delay 1e-3·T, a microsecond at 1 kHz: no record resolves a delay that small, and the
    optimiser stops short of an active bound by more than rounding)."""
    return bool(value <= lo + 1e-3 * scale or value >= hi - 1e-3 * scale)


def _warnings(names, theta, bound, corr, stderr, cov, sims, sol) -> list[str]:
    out = [
        f"the stderrs are Newey–West (autocorrelation-robust, lag window {cov.bandwidth} "
        f"samples): the position residual's lag-1 autocorrelation is {cov.lag1:.4f}, so the "
        "white-noise stderrs (white_noise_stderr) would understate the uncertainty and are "
        "invalid here"
    ]
    if "delay" in names and "m" in names:
        c = float(corr[names.index("m"), names.index("delay")])
        if abs(c) > CONFOUNDED:
            i = names.index("m")
            out.append(
                f"the command delay is nearly confounded with the mass: corr(m, delay) = "
                f"{c:.4f}; m = {theta[i]:.4g} ± {stderr[i]:.3g} kg with the delay free — give "
                "the delay ([loop] delay, or --delay) if it is known"
            )
    for i, name in enumerate(names):
        if bound[i]:
            if name == "delay":
                out.append(
                    f"the command delay ended on its bound ({theta[i] * 1e3:.3f} ms): the "
                    "record favours a delay outside [0, 5T], which the loop model cannot "
                    "take, so it does not determine the delay and no ± is given — give the "
                    "delay ([loop] delay, or --delay) if it is known"
                )
            else:
                out.append(f"{name} ended on its bound ({theta[i]:.4g} {UNITS[name]}): no ± "
                           "is given for it")
    if not sol.success:
        out.append(f"the optimiser stopped without converging: {sol.message}")
    n_sat = sum(int(np.sum(s.saturated)) for s in sims)
    if n_sat:
        out.append(f"the simulated command saturates at {n_sat} instant(s)")
    return out


def _vector(run: str, name: str, value, size: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{run}: {name} must be a 1-D array; got shape {arr.shape}")
    if size is not None and arr.size != size:
        raise ValueError(f"{run}: {name} has {arr.size} samples but x has {size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{run}: {name} has {int(np.sum(~np.isfinite(arr)))} non-finite values")
    return arr
