"""The PHO identification's result: m, c, k with uncertainties and each run's measured mode.

:class:`Identification` carries its own statistics (covariance, derived ω₀ and ζ) and its JSON
summary; its text report and figures are rendered by :mod:`phoid.reports`, which takes the
result by duck typing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from phoid.fits import DecayFit
from phoid.interop.exports import LoopExports
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import residual_noise_ratio, window_noise
from phoid.methods.pho import MCKFit
from phoid.methods.result_base import PlantResult

__all__ = ["Identification", "RunMode"]


@dataclass(frozen=True)
class RunMode:
    """One run's measured dominant mode and its place in eq. (35).

    Attributes
    ----------
    file : str
        Data file of the run (as named in the manifest).
    P, D : float
        Gains, N/m and N·s/m.
    sigma, omega_d : float
        Decay rate (1/s) and damped frequency (rad/s) of the dominant mode.
    sigma_stderr, omega_d_stderr : float
        Their standard errors.
    c_prime, k_prime : float
        Equivalent feedback damping (N·s/m) and stiffness (N/m), eq. (32); for a run with an
        added mass Δm the known part is taken off (c′ − 2Δmσ, k′ − Δmω₀²), so that every run's
        point lies on the lines of the mass without additions.
    cycles : float
        Oscillation cycles used (above the noise floor).
    residual_rms : float
        RMS of the decay fit's residual, m.
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    fit : DecayFit or None
        The full decay fit (None when the run could not be fitted at all).
    added_mass : float
        Known mass added for this run, kg (0: none).
    u_fit : phoid.methods.udelay.URun or None
        The joint fit of x and the recorded u (an estimated delay with u; None otherwise).
    """

    file: str
    P: float
    D: float
    sigma: float
    omega_d: float
    sigma_stderr: float
    omega_d_stderr: float
    c_prime: float
    k_prime: float
    cycles: float
    residual_rms: float
    used: bool
    warnings: tuple[str, ...] = ()
    fit: DecayFit | None = None
    added_mass: float = 0.0
    u_fit: Any = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the spec's keys (file, P, D, sigma, omega_d, c_prime, k_prime,
        cycles) and extra diagnostics."""

        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "file": self.file,
            "P": float(self.P),
            "D": float(self.D),
            "sigma": num(self.sigma),
            "omega_d": num(self.omega_d),
            "c_prime": num(self.c_prime),
            "k_prime": num(self.k_prime),
            "cycles": num(self.cycles),
            "sigma_stderr": num(self.sigma_stderr),
            "omega_d_stderr": num(self.omega_d_stderr),
            "residual_rms": num(self.residual_rms),
            "used": self.used,
            "warnings": list(self.warnings),
        } | ({"added_mass": float(self.added_mass)} if self.added_mass else {}) | (
            {"u": self.u_fit.to_dict()} if self.u_fit is not None else {})


@dataclass(frozen=True, repr=False)
class Identification(PlantResult, LoopExports):
    """Result of :func:`phoid.identify`: m, c, k with uncertainties, per-run modes, warnings.

    The shared fields (``warnings``, ``source``, ``data``, ``adequacy``), ``omega0``, ``zeta``,
    ``cov``, ``report()`` and ``plot()`` come from
    :class:`~phoid.methods.result_base.PlantResult`.

    Attributes
    ----------
    m, c, k : Estimate
        Mass (kg), viscous damping (N s/m), stiffness (N/m).
    delay : float
        Loop delay used (given) or estimated, s.
    delay_source : str
        ``"given"`` (from the manifest or the caller) or ``"estimated"``.
    delay_stderr : float or None
        Standard error of an estimated delay, s.
    digital : phoid.dynamics.digital.DigitalPD or None
        The sampled loop the modes were modelled with (None: a continuous loop with a delay).
    delay_from : str or None
        What an estimated delay came from: ``"x"`` (the runs' modes only) or ``"x+u"`` (also
        the recorded feedback force, :mod:`phoid.methods.udelay`); None for a given delay.
    runs : tuple of RunMode
    fit : MCKFit
        The underlying fit (covariance, eq. 35 lines, χ²).
    warnings : tuple of str
    source : str
        Where the data came from (a path or a description).
    data : tuple of (t, x)
        Each run's record, s and m (for the figures).
    u : tuple of (ndarray or None)
        Each run's recorded feedback force, N, on the record's samples (None where not
        recorded; empty when none was given), for the figures.
    noise_placement, noise_placement_source : str
        Where the sensor noise enters (``"outside"`` the loop: m, c, k from the runs' modes;
        ``"in-loop"``: from the output error of the plant driven by the applied force) and
        what decided it (``"manifest"``, ``"data"``, ``"option"``, ``"continuous loop"``).
    placement_test : phoid.methods.inloop_route.PlacementTest or None
        The data's test of the placement (where made).
    inloop : phoid.methods.inloop.InLoopFit or None
        The in-loop fit (with ``noise_placement == "in-loop"``): its Jacobian-based
        covariance ``cov`` and ``information``.
    """

    m: Estimate
    c: Estimate
    k: Estimate
    delay: float
    delay_source: str
    runs: tuple[RunMode, ...]
    fit: MCKFit
    delay_stderr: float | None = None
    digital: Any = None
    delay_from: str | None = None
    u: tuple[np.ndarray | None, ...] = field(default=(), repr=False)
    #: what the set's x is in ("m"; "rad": m, c, k are J, N m s/rad, N m/rad), set by the
    #: registry (phoid.methods.registry.labelled)
    x_unit: str = "m"
    #: where the sensor noise enters: "outside" the loop (m, c, k from the runs' modes) or
    #: "in-loop" (the output error of the plant driven by the applied force,
    #: phoid.methods.inloop_route)
    noise_placement: str = "outside"
    #: what decided it: "manifest" ([loop] noise), "data" (the residuals' test), "option"
    #: (noise_placement / --noise) or "continuous loop" (no in-loop route)
    noise_placement_source: str = "continuous loop"
    #: the data's test of the placement (phoid.methods.inloop_route.PlacementTest; None where
    #: not made)
    placement_test: Any = None
    #: the in-loop output-error fit (phoid.methods.inloop.InLoopFit: its Jacobian-based
    #: covariance and information), None for the modal route
    inloop: Any = field(default=None, repr=False)

    METHOD: ClassVar[str] = "pho"
    REPORT: ClassVar[str] = "phoid.reports.text:identification_text"
    FIGURES: ClassVar[str] = "phoid.reports.figures:plot_identification"

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --json`` (docs/format.md).

        Top-level keys are the spec's (method, m, c, k, delay, runs, warnings) plus the optional
        ``omega0`` and ``zeta`` in the same {value, stderr, unit} shape; each run carries the
        spec's keys plus sigma_stderr, omega_d_stderr, residual_rms, residual_noise_ratio
        (:meth:`residual_noise_ratios`), used and its warnings. ``covariance``,
        ``correlation`` and ``statistics`` are :meth:`fit_statistics`.
        """
        out: dict[str, Any] = {
            "method": self.METHOD,
            "x_unit": self.x_unit,
            **self.estimate_entries(),
            "delay": {"value": float(self.delay),
                      "stderr": None if self.delay_stderr is None else float(self.delay_stderr),
                      "unit": "s", "source": self.delay_source}
            | ({"from": self.delay_from} if self.delay_from else {}),
            "runs": self.run_entries(),
            "warnings": list(self.warnings),
        }
        if self.digital is not None:
            # a format extension, only for sampled loops: which model the modes went through
            g = self.digital
            out["loop"] = {"model": "digital", "sample_time": g.sample_time,
                           "delay_samples": g.delay_samples, "velocity": g.velocity,
                           "cutoff": g.cutoff}
        out["noise_placement"] = self.noise_placement
        out["noise_placement_source"] = self.noise_placement_source
        if self.placement_test is not None:
            out["noise_placement_test"] = self.placement_test.to_dict()
        return out | self.derived_entries() | self.adequacy_entry() | self.fit_statistics()

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the RMS of its decay fit's residual over the record's noise level estimated
        without the model (:func:`phoid.methods.fit_statistics.difference_noise` over the fit's
        window); ≈ 1 when the decay model explains the record to its noise, ≫ 1 for a misfit.
        None for a run set aside or not fitted, or when the result carries no records."""
        if self.inloop is not None:  # the in-loop fit's own residuals
            return list(self.inloop.noise_ratios(len(self.runs)))
        out: list[float | None] = []
        for i, r in enumerate(self.runs):
            f = r.fit
            if f is None or i >= len(self.data) or not r.used:
                out.append(None)
                continue
            t, x = self.data[i][0], self.data[i][1]
            out.append(residual_noise_ratio(r.residual_rms,
                                            window_noise(t, x, f.t_start, f.t_end)))
        return out

    def statistics_of(self) -> tuple[Sequence[str], Sequence[str], np.ndarray,
                                     float | None, int | None, str]:
        """The parameters of the ``covariance``, ``correlation`` and ``statistics`` blocks of
        :meth:`summary` (:meth:`~phoid.methods.result_base.ResultBase.fit_statistics`).

        The parameters are m (kg), c (N s/m), k (N/m), and the delay Δt (s) when it was
        estimated with them. χ² is that of the set's fit: for the weighted estimator (``gls``)
        Σᵢ rᵢᵀ Covᵢ⁻¹ rᵢ of the runs' measured modes rᵢ = (σ̂ᵢ − σᵢ(θ), ω̂_dᵢ − ω_dᵢ(θ)) through
        the exact loop roots (eq. 35 weighted by each decay fit's covariance), dof = 2·runs − p;
        χ²/dof ≈ 1 when one plant explains every run's mode within its own noise. With a delay
        estimated from x and u (``delay_from == "x+u"``) the runs' delays from their joint
        x–u fits are residuals too (:func:`phoid.methods.udelay.combine`), dof = 2·runs +
        runs with u − 4. The paper's OLS lines (``ols``) have no χ² (null). With the noise in
        the loop (``inloop`` set) the parameters are m, c, k of the output-error fit and χ² is
        Σ over its windows of the residual's squares over the window's noise level from third
        differences, dof = samples − parameters (θ, start states, offset).
        """
        fit = self.fit
        if self.inloop is not None:
            return (["m", "c", "k"], ["kg", "N s/m", "N/m"], fit.cov, fit.chi2, fit.dof,
                    "the output error of the plant driven by the force the controller applied "
                    "(the noise in the loop): each run's residual over its noise level from "
                    "third differences, dof = samples − (m, c, k, start states, offset)")
        if fit.cov_full is not None:
            names, units, cov = ["m", "c", "k", "delay"], ["kg", "N s/m", "N/m", "s"], \
                fit.cov_full
        else:
            names, units, cov = ["m", "c", "k"], ["kg", "N s/m", "N/m"], fit.cov
        if fit.estimator == "gls":
            of = ("the weighted fit of the runs' modes (σᵢ, ω_dᵢ) through the exact loop "
                  "roots (eq. 35), each run weighted by its decay fit's covariance")
            if self.delay_from == "x+u":
                of = ("the weighted fit of the runs' modes (σᵢ, ω_dᵢ) through the exact loop "
                      "roots (eq. 35) and of the delays of the runs' joint x–u fits, each "
                      "weighted by its own fit's variance")
            return names, units, cov, fit.chi2, fit.dof, of
        return names, units, cov, None, None, "not computed: the paper's OLS lines of eq. (35)"
