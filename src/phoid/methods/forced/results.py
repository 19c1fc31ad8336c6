"""Results of the forced identification: per-run R, ρ and the plant's m, c, k."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from phoid.methods._modal import release_basis
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import residual_noise_ratio, window_noise
from phoid.methods.forced.stiffness import ResponseFit
from phoid.methods.result_base import PlantResult

__all__ = ["ForcedIdentification", "ForcedRun"]


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class ForcedRun:
    """One forced run: frequency, amplitudes, R and ρ (eq. 21) with their uncertainties.

    Attributes
    ----------
    file : str
        Data file (as named in the manifest).
    omega, omega_stderr : float
        Forcing frequency from F, rad/s.
    B, B_stderr : float
        Force amplitude from F, N (eq. 16).
    C, C_stderr : float
        Steady-state displacement amplitude, m (eq. 17; ERRATA 3).
    R, R_stderr : float
        Relative stiffness B/C, N/m (eq. 21).
    rho, rho_stderr : float
        Phase lag of x behind F, rad, in (−π, π] (eq. 21).
    Z : complex
        R e^{iρ} = k − mω² + icω (eq. 20), N/m.
    Z_cov : ndarray, shape (2, 2)
        Covariance of (Re Z, Im Z), (N/m)².
    t_start, t_end : float
        Analysed window (from the force's constant-amplitude onset to the end), s.
    t_ref : float
        Time origin of the phasors, s.
    settle_time : float
        Time after which the fitted start-up transient stays below the noise sd, s
        (``t_start`` if it never exceeds it).
    settled : bool
        False when the transient is still above 3 noise sd at the end of the record.
    periods : float
        Forcing periods in the window.
    noise_sd, residual_rms : float
        White-noise sd and RMS residual of x, m.
    F_distortion : float
        RMS of F not explained by the sine, relative to the sine's rms.
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    coef : ndarray
        Fitted (x_off, a, b, x₀, v₀) of the response model (see :meth:`model`).
    transient_rates : (float, float)
        (σ, ω₀²) of the transient model, 1/s and 1/s².
    """

    file: str
    omega: float
    omega_stderr: float
    B: float
    B_stderr: float
    C: float
    C_stderr: float
    R: float
    R_stderr: float
    rho: float
    rho_stderr: float
    Z: complex
    Z_cov: np.ndarray = field(repr=False)
    t_start: float = math.nan
    t_end: float = math.nan
    t_ref: float = math.nan
    settle_time: float = math.nan
    settled: bool = True
    periods: float = math.nan
    noise_sd: float = math.nan
    residual_rms: float = math.nan
    F_distortion: float = math.nan
    used: bool = True
    warnings: tuple[str, ...] = ()
    coef: np.ndarray = field(default_factory=lambda: np.full(5, np.nan), repr=False)
    transient_rates: tuple[float, float] = (math.nan, math.nan)

    def model(self, t: np.ndarray | float, *, transient: bool = True) -> np.ndarray:
        """Fitted x at times ``t`` (s), m: offset, steady state and (optionally) transient."""
        t = np.asarray(t, dtype=float)
        d, a, b, x0, v0 = self.coef
        tau = t - self.t_ref
        out = d + a * np.cos(self.omega * tau) + b * np.sin(self.omega * tau)
        if transient:
            B1, B2 = release_basis(np.maximum(t - self.t_start, 0.0), *self.transient_rates)
            out = out + np.where(t >= self.t_start, x0 * B1 + v0 * B2, 0.0)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the keys of ``phoid identify --json``'s ``runs``)."""
        return {
            "file": self.file,
            "omega": _num(self.omega), "omega_stderr": _num(self.omega_stderr),
            "R": _num(self.R), "R_stderr": _num(self.R_stderr),
            "rho": _num(self.rho), "rho_stderr": _num(self.rho_stderr),
            "B": _num(self.B), "B_stderr": _num(self.B_stderr),
            "C": _num(self.C), "C_stderr": _num(self.C_stderr),
            "t_start": _num(self.t_start), "t_end": _num(self.t_end),
            "settle_time": _num(self.settle_time), "settled": self.settled,
            "periods": _num(self.periods),
            "noise_sd": _num(self.noise_sd), "residual_rms": _num(self.residual_rms),
            "F_distortion": _num(self.F_distortion),
            "used": self.used,
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True, repr=False)
class ForcedIdentification(PlantResult):
    """Result of :func:`identify_forced`: m, c, k with uncertainties, per-run R and ρ.

    The shared fields (``warnings``, ``source``, ``data``: each run's (t, x, F), ``adequacy``),
    ``omega0``, ``zeta``, ``cov``, ``report()`` and ``plot()`` come from
    :class:`~phoid.methods.result_base.PlantResult`.

    Attributes
    ----------
    m, c, k : Estimate
        Mass (kg), viscous damping (N s/m), stiffness (N/m).
    fit : ResponseFit
        The eq. (20) fit (covariance, χ², dof).
    runs : tuple of ForcedRun
    transient : (float, float)
        (σ, ω₀²) of the start-up transient model, 1/s and 1/s².
    transient_fitted : bool
        Whether those rates were fitted (False: the transient was too weak to determine them).
    warnings : tuple of str
    source : str
    """

    m: Estimate
    c: Estimate
    k: Estimate
    fit: ResponseFit
    runs: tuple[ForcedRun, ...]
    transient: tuple[float, float] = (math.nan, math.nan)
    transient_fitted: bool = False
    #: what the set's x is in ("m"; "rad": m, c, k are J, N m s/rad, N m/rad), set by the
    #: registry (phoid.methods.registry.labelled)
    x_unit: str = "m"

    METHOD: ClassVar[str] = "forced"
    REPORT: ClassVar[str] = "phoid.reports.text:forced_text"
    FIGURES: ClassVar[str] = "phoid.reports.figures:plot_forced"

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --json`` for a forced set.

        Keys: ``method`` ("forced"), ``m``, ``c``, ``k`` (``{"value", "stderr", "unit"}``),
        ``omega0`` and ``zeta`` when defined, ``runs`` (per run ``file``, ``omega``, ``R``
        (N/m), ``rho`` (rad), each with ``*_stderr``, plus ``B``, ``C``, the window, settling
        and diagnostics, and ``residual_noise_ratio``: :meth:`residual_noise_ratios`),
        ``warnings``, and ``covariance``, ``correlation``, ``statistics``
        (:meth:`fit_statistics`).
        """
        return {"method": self.METHOD, "x_unit": self.x_unit, **self.estimate_entries(),
                **self.derived_entries(),
                "runs": self.run_entries(), **self.summary_tail()}

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the RMS of its response fit's residual of x over the record's noise level
        estimated without the model (:func:`phoid.methods.fit_statistics.difference_noise`
        over the analysed window); ≈ 1 when the model explains x to its noise, ≫ 1 for a
        misfit. None for a run set aside, or when the result carries no records."""
        out: list[float | None] = []
        for i, r in enumerate(self.runs):
            if not r.used or i >= len(self.data):
                out.append(None)
                continue
            t, x = self.data[i][0], self.data[i][1]
            out.append(residual_noise_ratio(r.residual_rms,
                                            window_noise(t, x, r.t_start, r.t_end)))
        return out

    def statistics_of(self) -> tuple[Sequence[str], Sequence[str], np.ndarray,
                                     float | None, int | None, str]:
        """The parameters of the ``covariance``, ``correlation`` and ``statistics`` blocks of
        :meth:`summary` (:meth:`~phoid.methods.result_base.ResultBase.fit_statistics`).

        The parameters are m (kg), c (N s/m), k (N/m). χ² is that of the eq. (20) fit: the
        generalised least squares of Re Zᵢ = k − mωᵢ² and Im Zᵢ = cωᵢ to the runs' dynamic
        stiffnesses Zᵢ = Rᵢe^{iρᵢ}, each weighted by the inverse covariance of its (Re Zᵢ,
        Im Zᵢ) (:class:`~phoid.methods.forced.stiffness.ResponseFit`), dof = 2·runs − 3.
        """
        return (["m", "c", "k"], ["kg", "N s/m", "N/m"], self.fit.cov, self.fit.chi2,
                self.fit.dof, "the weighted (GLS) fit of the eq. (20) lines Re Zᵢ = k − mωᵢ², "
                              "Im Zᵢ = cωᵢ to the runs' dynamic stiffnesses")
