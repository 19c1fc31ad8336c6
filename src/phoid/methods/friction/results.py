"""Results of the friction fit and of the score test for friction."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from phoid.dynamics import inverse_map
from phoid.interop.exports import LoopExports
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import residual_noise_ratio
from phoid.methods.result_base import ResultBase
from phoid.reports.display import NotebookDisplay

__all__ = ["FrictionEvidence", "FrictionFit", "FrictionRun"]


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


@dataclass(frozen=True, repr=False)
class FrictionFit(ResultBase, LoopExports):
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
    data : tuple of (t, x)
        Each run's record, s and m (for :meth:`model` and the figures).
    sim_rate : float
        Rate of the fit's simulation grid, Hz (:meth:`model` simulates on the same grid).
    x_unit : str
        What x is in: ``"m"``, or ``"rad"`` for a rotational set (the registry labels the
        estimates by it: kg m^2, N m s/rad, N m/rad, N m).
    adequacy : phoid.methods.adequacy.Adequacy or None
        The fit's adequacy checks (:mod:`phoid.methods.friction.adequacy`); where one fails
        the stderr are the robust ones and ``white_stderr`` the fit's own.
    noise_placement : str or None
        Where the sensor noise was taken to be: ``"in-loop"`` (m, c, k, f_c from the output
        error of the plant driven by the force the controller applied,
        :mod:`phoid.methods.friction.inloop`) or ``"outside"`` (the stick–slip closed loop).
    noise_placement_source : str or None
        What decided it: ``"option"``, ``"manifest"``, ``"data"`` or ``"continuous loop"``.
    placement_test : phoid.methods.inloop_route.PlacementTest or None
        The data's test of the placement, where made.
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
    digital: Any = None
    sim_rate: float = math.nan
    x_unit: str = "m"
    noise_placement: str | None = None
    noise_placement_source: str | None = None
    placement_test: Any = None

    METHOD: ClassVar[str] = "pho"
    REPORT: ClassVar[str] = "phoid.reports.text:friction_text"
    FIGURES: ClassVar[str] = "phoid.reports.figures:plot_friction"

    def model(self, i: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Run ``i``'s fitted model at times ``t``: position (m, sensor offset included) and
        velocity (m/s).

        The fitted plant (m + the run's added mass, c, k, f_c) under the run's loop (and bias)
        released at rest from x₀ᵢ at τᵢ, simulated exactly with stick–slip on the fit's grid
        (:attr:`sim_rate`) and read by the cubic Hermite interpolant, as the fit reads it
        (:mod:`phoid.methods.friction.model`); before τᵢ the held level bᵢ + x₀ᵢ and velocity
        0. While the simulated mass sticks its velocity is exactly 0.
        """
        from phoid.methods.friction.model import _PlantParams, hermite
        from phoid.simulation import simulate

        r = self.runs[i]
        t = np.asarray(t, dtype=float)
        h = 1.0 / self.sim_rate
        dur = max(float(np.max(t, initial=r.release)) - r.release, 0.0) + 3.0 * h
        g = self.digital
        loop = {"delay": self.delay} if g is None else {
            "sample_time": g.sample_time, "delay_samples": g.delay_samples,
            "velocity": g.velocity, "cutoff": g.cutoff}
        sim = simulate(_PlantParams(self.m.value + r.added_mass, self.c.value, self.k.value,
                                    max(self.fc.value, 0.0)),
                       np.array([r.P]), np.array([r.D]), duration=max(dur, 4 * h),
                       fs=self.sim_rate, x0=np.array([r.x0]), bias=np.array([r.bias]),
                       **loop)
        u = t - r.release
        post = u > 0
        hv, hd = hermite(sim.x_true[0], sim.v[0], h, np.maximum(u, 0.0))
        return r.offset + np.where(post, hv, r.x0), np.where(post, hd, 0.0)

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
        stick_time, …) and ``residual_noise_ratio`` (:meth:`residual_noise_ratios`).
        A digital loop's result adds ``noise_placement``, ``noise_placement_source`` and,
        where made, ``noise_placement_test`` (:mod:`phoid.methods.friction.inloop`).
        ``covariance``, ``correlation`` and ``statistics`` (χ²/dof) are :meth:`fit_statistics`;
        convergence is :attr:`converged` (a fit that did not converge, or misfits, says so in
        the warnings).
        """
        runs = []
        for r, q in zip(self.runs, self.residual_noise_ratios(), strict=True):
            d = r.to_dict() | {"residual_noise_ratio": q}
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
            "x_unit": self.x_unit,
            "m": self.m.to_dict(),
            "c": self.c.to_dict(),
            "k": self.k.to_dict(),
            "fc": self.fc.to_dict(),
            "delay": {"value": float(self.delay), "stderr": None, "unit": "s",
                      "source": "given"},
            "runs": runs,
            **({"loop": {"model": "digital", "sample_time": self.digital.sample_time,
                         "delay_samples": self.digital.delay_samples,
                         "velocity": self.digital.velocity, "cutoff": self.digital.cutoff}}
               if self.digital is not None else {}),
            **({"noise_placement": self.noise_placement,
                "noise_placement_source": self.noise_placement_source}
               if self.noise_placement is not None and self.digital is not None else {}),
            **({"noise_placement_test": self.placement_test.to_dict()}
               if self.placement_test is not None else {}),
            **self.summary_tail(),
        }

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the fit's residual RMS over the run's noise sd, which comes from the record
        alone (its held segment, or the MAD of its third differences), not from the model; ≈ 1
        when the stick–slip model explains the record to its noise, ≫ 1 for a misfit. None
        for a run set aside."""
        return [residual_noise_ratio(r.residual_rms, r.noise_sd) if r.used else None
                for r in self.runs]

    def statistics_of(self) -> tuple[list[str], list[str], np.ndarray, float, int, str]:
        """The ``covariance``, ``correlation`` and ``statistics`` blocks' content
        (:meth:`phoid.methods.result_base.ResultBase.fit_statistics`).

        The parameters are m (kg), c (N s/m), k (N/m) and f_c (N), the nuisance parameters
        (each run's release, x₀, offset) profiled out. χ² is that of the full-record fit:
        Σ (xᵢ − x̂ᵢ)²/sᵣ² over every fitted sample, sᵣ the run's noise sd from the record
        (held segment or third differences), dof = samples − parameters (:attr:`chi2`,
        :attr:`dof`).
        """
        return (["m", "c", "k", "fc"], ["kg", "N s/m", "N/m", "N"], self.cov, self.chi2,
                self.dof, "the full-record fit of x through the stick-slip simulator, each "
                "sample over its run's noise sd (held segment or third differences)")


@dataclass(frozen=True, repr=False)
class FrictionEvidence(NotebookDisplay):
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
