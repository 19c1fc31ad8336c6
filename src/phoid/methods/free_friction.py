r"""Free decay with viscous and Coulomb friction, including the stop (``--friction`` on a
free set).

The plant m x'' + c x' + k (x − x_off) + f_c sgn(x') = 0, released free, loses amplitude both
exponentially (viscous) and linearly (Coulomb: 2f_c/k per half-cycle) and sticks for good at
the first velocity zero where the spring force is at most the friction force, |k(x − x_off)|
≤ f_c: the static friction is taken equal to the kinetic one. Per unit mass, with a = f_c/m::

    x'' + 2σ x' + ω₀² (x − x_off) + a·sgn(x') = 0,    c/m = 2σ,  k/m = ω₀².

A free decay determines σ, ω₀² and a; with a known mass, c = 2σm, k = ω₀²m, f_c = a·m (the
mass taken as exact). The motion is evaluated exactly, half-cycle by half-cycle
(:mod:`phoid.methods.free_friction_model`), and fitted to every release at once
(:mod:`phoid.methods.free_friction_fit`), starting from the viscous fit of
:func:`phoid.methods.free.identify_free_data` (whose windows and release detection it keeps)
and from the half-cycle amplitudes.

Evidence for friction: Δχ² = χ²(viscous) − χ²(friction), both weighted by each release's noise
level estimated without a model (:func:`phoid.methods.fit_statistics.difference_noise`). The
models are nested (a = 0 is the viscous model, and a may take either sign in the fit, so a = 0
is inside the parameter space): with white noise and no friction Δχ² is χ² with 1 degree of
freedom. Friction is called significant when that test's p < 10⁻³ and a is more than 3 of its
(robust, where used) stderr from 0; otherwise a warning says the viscous model suffices. The
likelihood ratio with each release's noise variance unknown, Σᵢ nᵢ ln(RSS_viscous/RSS_friction),
is reported beside it.

Adequacy and uncertainty (:mod:`phoid.methods.free_friction_adequacy`, the checks of
:mod:`phoid.methods.adequacy`): the residual against each release's noise level and its
whiteness (Ljung–Box), the halves of the records and the runs refitted with the friction model
and compared on ω₀ and ζ. Where every check passes the stderr are the Gauss–Newton ones (each
release weighted by its residual variance); where one fails they are the Newey–West sandwich,
never below the white ones, widened by the halves' (or the runs') spread where those disagree,
and each estimate keeps its white-noise stderr in ``white_stderr`` (JSON ``stderr_white``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from phoid import _validate as valid
from phoid._notation import unit_text
from phoid._threads import single_blas_thread
from phoid.dynamics.plant import free_response
from phoid.errors import IdentificationError
from phoid.io.units import quantity_unit
from phoid.methods.chi2 import chi2_sf
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import residual_noise_ratio, window_noise
from phoid.methods.free import FreeIdentification, identify_free, identify_free_data
from phoid.methods.free_friction_adequacy import assess_free_friction
from phoid.methods.free_friction_fit import (
    FrictionProblem,
    ReleaseWindow,
    fit_free_friction,
)
from phoid.methods.free_friction_model import coulomb_decay
from phoid.methods.result_base import ResultBase

__all__ = ["FreeFrictionEvidence", "FreeFrictionIdentification", "FreeFrictionRun",
           "identify_free_friction", "identify_free_friction_data"]

#: significance level of the Δχ² test for friction
P_FRICTION = 1e-3
#: |a| / stderr above which friction is significant
Z_FRICTION = 3.0
#: f_c/m this many stderr from 0 is well determined by the amplitude loss alone: a record that
#: ends before the mass sticks is then no reason for a warning
_Z_WELL = 10.0
#: fewest velocity zeros in a release to tell friction from damping
MIN_HALF_CYCLES = 4


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class FreeFrictionRun:
    """One release of a free set, as fitted with friction.

    Attributes
    ----------
    file : str
    release : float
        Release time from the viscous fit's detection, s.
    held : bool
        Whether a held segment precedes the release.
    t_start, t_end : float
        The fitted window, s.
    x0, v0 : float
        Position from the offset (m) and velocity (m/s) at ``t_start``, fitted.
    offset : float
        Fitted offset x_off, m (the centre of the friction band).
    n_samples : int
    noise_sd : float
        Noise level from the record alone (third differences over the window), m.
    residual_rms, viscous_residual_rms : float
        RMS residual of the friction fit and of the viscous fit over the window, m.
    half_cycles : int
        Velocity zeros of the fitted motion in the window, the stop included.
    stop_time : float or None
        When the fitted motion sticks for good, s on the record's clock; None when it is
        still moving at ``t_end``.
    stuck_position : float or None
        Where it sticks, m (record units, offset included); None with ``stop_time``.
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    """

    file: str
    release: float
    held: bool
    t_start: float
    t_end: float
    x0: float
    v0: float
    offset: float
    n_samples: int
    noise_sd: float
    residual_rms: float
    viscous_residual_rms: float
    half_cycles: int
    stop_time: float | None
    stuck_position: float | None
    used: bool
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the run."""
        return {
            "file": self.file, "release": _num(self.release), "held": self.held,
            "t_start": _num(self.t_start), "t_end": _num(self.t_end), "x0": _num(self.x0),
            "v0": _num(self.v0), "offset": _num(self.offset), "n_samples": int(self.n_samples),
            "noise_sd": _num(self.noise_sd), "residual_rms": _num(self.residual_rms),
            "viscous_residual_rms": _num(self.viscous_residual_rms),
            "half_cycles": int(self.half_cycles), "stop_time": _num(self.stop_time),
            "stuck_position": _num(self.stuck_position), "used": self.used,
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True)
class FreeFrictionEvidence:
    """The test of friction against the viscous fit (module docstring).

    Attributes
    ----------
    chi2_viscous, chi2_friction : float
        χ² of the two fits, each residual over its release's model-free noise level.
    delta_chi2 : float
        Their difference.
    p_value : float
        P(χ²₁ ≥ Δχ²): the chance of so large a drop without friction, for white noise.
    likelihood_ratio : float
        Σᵢ nᵢ ln(RSS_viscous,ᵢ/RSS_friction,ᵢ) (each release's noise variance unknown).
    z : float
        a over its reported stderr.
    significant : bool
    """

    chi2_viscous: float
    chi2_friction: float
    delta_chi2: float
    p_value: float
    likelihood_ratio: float
    z: float
    significant: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"chi2_viscous": _num(self.chi2_viscous), "chi2_friction": _num(self.chi2_friction),
                "delta_chi2": _num(self.delta_chi2), "p_value": _num(self.p_value),
                "likelihood_ratio": _num(self.likelihood_ratio), "z": _num(self.z),
                "significant": self.significant,
                "test": "friction against the viscous fit: Δχ² ~ χ²_1 without friction; "
                        f"significant when p < {P_FRICTION:g} and |f_c/m| > {Z_FRICTION:g} "
                        "stderr"}


@dataclass(frozen=True, repr=False, kw_only=True)
class FreeFrictionIdentification(ResultBase):
    """Result of :func:`identify_free_friction`: σ, ω₀, ζ, c/m, k/m and f_c/m (and m, c, k,
    f_c for a known mass), each release's stop, and the evidence for friction. The fields of
    :class:`~phoid.methods.result_base.ResultBase` (``warnings``, ``source``, ``data``,
    ``adequacy``) are its own too.

    Attributes
    ----------
    sigma : Estimate
        Viscous decay rate σ = c/(2m), 1/s.
    omega0 : Estimate
        ω₀ = √(k/m), rad/s.
    zeta : Estimate
        ζ = σ/ω₀.
    c_over_m, k_over_m, fc_over_m : Estimate
        2σ (1/s), ω₀² (1/s²) and a = f_c/m (x's unit per s²: m/s², rad/s² …).
    regime : str
        ``"underdamped"``, ``"critical"`` or ``"overdamped"`` (of the viscous part).
    cov : ndarray, shape (3, 3)
        Reported covariance of (σ, ω₀², a): the adequacy's robust one where a check fails.
    cov_white : ndarray, shape (3, 3)
        The Gauss–Newton (white-noise) covariance.
    evidence : FreeFrictionEvidence
    viscous : FreeIdentification
        The viscous fit the friction fit started from and is tested against.
    mass : float or None
    m, c, k, fc : Estimate or None
        With a known mass: m (stderr 0), c = 2σm (N s/m), k = ω₀²m (N/m), f_c = a·m (N)
        (J, N m s/rad, N m/rad, N m for x in rad).
    runs : tuple of FreeFrictionRun
    converged : bool
    x_unit : str
        What x is in (the viscous fit's ``x_unit``: ``"m"``, ``"rad"`` or a sensor unit): the
        unit of the runs' ``x0``, ``offset``, ``stuck_position``, ``noise_sd``,
        ``residual_rms`` (per s, ``v0``).
    """

    sigma: Estimate
    omega0: Estimate
    zeta: Estimate
    c_over_m: Estimate
    k_over_m: Estimate
    fc_over_m: Estimate
    regime: str
    cov: np.ndarray = field(repr=False)
    cov_white: np.ndarray = field(repr=False)
    evidence: FreeFrictionEvidence
    viscous: FreeIdentification = field(repr=False)
    mass: float | None = None
    m: Estimate | None = None
    c: Estimate | None = None
    k: Estimate | None = None
    fc: Estimate | None = None
    runs: tuple[FreeFrictionRun, ...] = ()
    converged: bool = True
    x_unit: str = "m"

    METHOD: ClassVar[str] = "free"
    REPORT: ClassVar[str] = "phoid.reports.free_friction:free_friction_text"
    FIGURES: ClassVar[str] = "phoid.reports.free_friction:plot_free_friction"

    @property
    def robust(self) -> bool:
        """Whether the stderr are the robust ones (an adequacy check failed)."""
        return self.adequacy is not None and self.adequacy.stderr == "robust"

    def motion(self, i: int, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Fitted position (m, offset included) and velocity (m/s) of run ``i`` at times
        ``t`` (s); nan before the run's window."""
        r = self.runs[i]
        t = np.atleast_1d(np.asarray(t, dtype=float))
        x = np.full(t.shape, math.nan)
        v = np.full(t.shape, math.nan)
        if not r.used:
            return x, v
        order = np.argsort(t, kind="stable")
        ts = t[order]
        ok = ts >= r.t_start
        mot = coulomb_decay(ts[ok] - r.t_start, self.sigma.value, self.k_over_m.value,
                            self.fc_over_m.value, r.x0, r.v0)
        xs = np.full(ts.shape, math.nan)
        vs = np.full(ts.shape, math.nan)
        xs[ok] = r.offset + mot.y
        vs[ok] = mot.v
        x[order] = xs
        v[order] = vs
        return x, v

    def model(self, i: int, t: np.ndarray | float) -> np.ndarray:
        """Fitted position of run ``i`` at times ``t`` (s), m (nan before its window)."""
        return self.motion(i, t)[0]

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: RMS residual of the friction fit over the model-free noise level."""
        return [residual_noise_ratio(r.residual_rms, r.noise_sd) if r.used else None
                for r in self.runs]

    def viscous_residual_noise_ratios(self) -> list[float | None]:
        """Per run: the same ratio for the viscous fit."""
        return [residual_noise_ratio(r.viscous_residual_rms, r.noise_sd) if r.used else None
                for r in self.runs]

    def statistics_of(self) -> tuple[list[str], list[str], np.ndarray, float, int, str]:
        """The fit statistics' parameters σ, ω₀² and f_c/m, their reported covariance, χ² of
        the joint friction fit (each residual over its run's model-free noise level) and
        dof = Σ n − 3 − 3·runs."""
        used = [r for r in self.runs if r.used]
        n = sum(r.n_samples for r in used)
        return (["sigma", "k_over_m", "fc_over_m"],
                ["1/s", "1/s^2", quantity_unit("m/s^2", self.x_unit)], self.cov,
                self.evidence.chi2_friction, n - 3 - 3 * len(used),
                "the joint Coulomb + viscous free-decay fit of x in every run, each residual "
                "over its run's noise level estimated from third differences")

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --friction --json`` for a free set.

        Keys: ``method`` ("free"), ``friction`` (true), ``x_unit``, ``sigma`` (1/s),
        ``omega0`` (rad/s), ``zeta``, ``c_over_m`` (1/s), ``k_over_m`` (1/s^2), ``fc_over_m``
        (x_unit/s^2), each ``{"value", "stderr", "unit"}`` (and ``stderr_white`` when the
        stderr is the robust one); ``regime``; ``converged``; ``evidence``
        (:class:`FreeFrictionEvidence`); with a known mass ``m`` (given), ``c``, ``k`` and
        ``fc``; ``runs`` (each with ``stop_time``, ``stuck_position``, ``half_cycles``,
        ``residual_noise_ratio`` and ``viscous_residual_noise_ratio``); then
        :meth:`~phoid.methods.result_base.ResultBase.summary_tail` (``warnings``,
        ``adequacy``, the fit statistics).
        """
        out: dict[str, Any] = {"method": self.METHOD, "friction": True, "x_unit": self.x_unit}
        for key in ("sigma", "omega0", "zeta", "c_over_m", "k_over_m", "fc_over_m"):
            out[key] = getattr(self, key).to_dict()
        out["regime"] = self.regime
        out["converged"] = self.converged
        out["evidence"] = self.evidence.to_dict()
        if self.m is not None and self.c is not None and self.k is not None \
                and self.fc is not None:
            out["m"] = {**self.m.to_dict(), "source": "given"}
            out["c"] = self.c.to_dict()
            out["k"] = self.k.to_dict()
            out["fc"] = self.fc.to_dict()
        out["runs"] = [e | {"viscous_residual_noise_ratio": qv} for e, qv in
                       zip(self.run_entries(), self.viscous_residual_noise_ratios(),
                           strict=True)]
        return {**out, **self.summary_tail()}


# --------------------------------------------------------------------------------------------


def _derived(sigma: float, w0sq: float, cov: np.ndarray, white: np.ndarray | None):
    """ω₀ and ζ by the delta method, their white stderr beside when ``white`` is given."""
    w0 = math.sqrt(w0sq)
    g_w = np.array([0.0, 1 / (2 * w0), 0.0])
    g_z = np.array([1 / w0, -sigma / (2 * w0**3), 0.0])

    def se(g: np.ndarray, c: np.ndarray | None) -> float | None:
        return None if c is None else math.sqrt(max(float(g @ c @ g), 0.0))

    omega0 = Estimate(w0, se(g_w, cov), "rad/s", se(g_w, white))
    zeta = Estimate(sigma / w0, se(g_z, cov), "", se(g_z, white))
    return omega0, zeta


def _est(value: float, var: float, white_var: float | None, unit: str,
         scale: float = 1.0) -> Estimate:
    # scale·value may overflow (a huge mass): inf, reported null with a warning (mass_warnings)
    with np.errstate(over="ignore"):
        return Estimate(float(np.float64(value) * scale),
                        float(np.float64(math.sqrt(max(var, 0.0))) * abs(scale)), unit,
                        None if white_var is None
                        else float(np.float64(math.sqrt(max(white_var, 0.0))) * abs(scale)))


def _carried(warnings: Sequence[str]) -> tuple[str, ...]:
    """The viscous result's warnings about the input (runs set aside, [loop] ignored)."""
    return tuple(w for w in warnings if ": set aside: " in w or w.startswith("[loop]"))


def identify_free_friction(experiment: Any, *,
                           mass: float | None = None) -> FreeFrictionIdentification:
    """Identify σ, ω₀², f_c/m (and c, k, f_c with a mass) from a free set, with the stop.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A set with ``method = "free"`` (checked as :func:`phoid.methods.free.identify_free`
        checks it).
    mass : float, optional
        Known mass, kg (> 0); overrides the manifest's ``mass``.

    Returns
    -------
    FreeFrictionIdentification

    Raises
    ------
    IdentificationError
        As :func:`phoid.methods.free.identify_free`, or when the friction fit is singular.
    """
    viscous = identify_free(experiment, mass=mass)
    return _from_viscous(viscous, [r.name for r in experiment.runs])


def identify_free_friction_data(
    data: Sequence[tuple[Any, Any]],
    *,
    mass: float | None = None,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    source: str = "",
) -> FreeFrictionIdentification:
    """:func:`identify_free_friction` on plain arrays: ``data`` is a sequence of (t, x).

    Parameters
    ----------
    data : sequence of (array_like, array_like)
        Each release's sample times (s, strictly increasing) and positions (m).
    mass : float, optional
        Known mass, kg (> 0).
    files, names : sequence of str, optional
        Labels of the runs (file names for the results, names for messages).
    source : str
        Where the data came from.

    Returns
    -------
    FreeFrictionIdentification

    Raises
    ------
    IdentificationError
        If no run can be fitted, or the fit is singular.
    ValueError
        For malformed arrays or a bad ``mass`` (as :func:`identify_free_data`).
    """
    n = len(data)
    if files is not None and len(files) != n:
        raise ValueError(f"`files` has {len(files)} names for {n} runs")
    if names is not None and len(names) != n:
        raise ValueError(f"`names` has {len(names)} names for {n} runs")
    viscous = identify_free_data(data, mass=mass, files=files, names=names, source=source)
    fallback = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    return _from_viscous(viscous, list(names) if names is not None else fallback)


@single_blas_thread
def _from_viscous(vis: FreeIdentification, names: list[str]) -> FreeFrictionIdentification:
    where = f"{vis.source}: " if vis.source else ""
    used = [i for i, r in enumerate(vis.runs) if r.used]
    if not vis.k_over_m.value > 0:
        raise IdentificationError(
            f"{where}the viscous fit finds no restoring spring (k/m = {vis.k_over_m.value:.4g} "
            "1/s² ≤ 0): a friction decay cannot be fitted")
    windows = []
    for i in used:
        r = vis.runs[i]
        t, x = vis.data[i]
        sel = (t >= r.t_start) & (t <= r.t_end)
        ts, xs = t[sel], x[sel]
        noise = window_noise(t, x, r.t_start, r.t_end)
        noise = max(noise, 1e-13 * float(np.ptp(xs))) if math.isfinite(noise) else 0.0
        if not noise > 0:
            noise = 1e-13 * max(float(np.max(np.abs(xs))), 1e-300)
        y0, v0 = free_response(float(ts[0]) - r.release, vis.sigma.value, vis.k_over_m.value,
                               r.x0, r.v0)
        windows.append(ReleaseWindow(t=ts, x=xs, noise=noise, offset=r.offset, y0=float(y0),
                                     v0=float(v0)))
    try:
        sol = fit_free_friction(FrictionProblem(windows=tuple(windows), sigma=vis.sigma.value,
                                                w0sq=vis.k_over_m.value))
    except ValueError as exc:
        raise IdentificationError(f"{where}{exc}") from None
    halves_of = [int(m.turns.size) for m in sol.motions]
    if halves_of and max(halves_of) < MIN_HALF_CYCLES:
        # two or three half-cycles: the stop, σ and f_c trade off (a 2-half-cycle record of
        # f_c/m = 0.15 fits at 0.074 with a stderr of 2e-5): no release can tell Coulomb from
        # viscous friction, so no number is given
        raise IdentificationError(
            f"{where}every release holds fewer than {MIN_HALF_CYCLES} half-cycles of motion "
            f"before it stops ({', '.join(str(h) for h in halves_of)}): Coulomb and viscous "
            "friction cannot be told apart from it; identify without --friction (σ, ω₀ of the "
            "viscous model, with its adequacy warnings), or record a larger release")
    sigma, w0sq, a = (float(v) for v in sol.theta)
    x_unit = vis.x_unit
    adequacy = assess_free_friction(windows, sol, [names[i] for i in used], x_unit=x_unit)
    robust = adequacy.stderr == "robust"
    cov = adequacy.robust_cov
    white = sol.cov_white if robust else None
    acc = quantity_unit("m/s^2", x_unit)
    acc_text = unit_text(acc)  # as the warnings write it (m/s²)

    def wv(j: int) -> float | None:
        return None if white is None else float(white[j, j])

    sig_e = _est(sigma, cov[0, 0], wv(0), "1/s")
    k_e = _est(w0sq, cov[1, 1], wv(1), "1/s^2")
    a_e = _est(a, cov[2, 2], wv(2), acc)
    omega0, zeta = _derived(sigma, w0sq, cov, white)
    q = sigma * sigma - w0sq
    gq = np.array([2 * sigma, -1.0, 0.0])
    se_q = math.sqrt(max(float(gq @ cov @ gq), 0.0))
    regime = ("critical" if abs(q) <= 2 * se_q else "overdamped" if q > 0 else "underdamped")

    chi2_v = sum(vis.runs[i].n_samples * vis.runs[i].residual_rms**2 / w.noise**2
                 for i, w in zip(used, windows, strict=True))
    chi2_f = sum(float(e @ e) / w.noise**2 for e, w in zip(sol.resid, windows, strict=True))
    dchi2 = chi2_v - chi2_f
    lr = 0.0
    for i, e in zip(used, sol.resid, strict=True):
        rss_f = float(e @ e)
        rss_v = vis.runs[i].n_samples * vis.runs[i].residual_rms**2
        if rss_f > 0 and rss_v > 0:
            lr += e.size * math.log(rss_v / rss_f)
    p = chi2_sf(max(dchi2, 0.0), 1.0)
    z = a / a_e.stderr if a_e.stderr else math.inf if a != 0 else 0.0
    significant = p < P_FRICTION and z > Z_FRICTION
    evidence = FreeFrictionEvidence(chi2_viscous=chi2_v, chi2_friction=chi2_f,
                                    delta_chi2=dchi2, p_value=p, likelihood_ratio=lr, z=z,
                                    significant=significant)

    warnings: list[str] = list(_carried(vis.warnings))
    runs: list[FreeFrictionRun] = []
    k_used = {i: j for j, i in enumerate(used)}
    for i, r in enumerate(vis.runs):
        if i not in k_used:
            runs.append(FreeFrictionRun(
                file=r.file, release=r.release, held=r.held, t_start=r.t_start, t_end=r.t_end,
                x0=math.nan, v0=math.nan, offset=math.nan, n_samples=r.n_samples,
                noise_sd=math.nan, residual_rms=math.nan, viscous_residual_rms=math.nan,
                half_cycles=0, stop_time=None, stuck_position=None, used=False,
                warnings=r.warnings))
            continue
        j = k_used[i]
        w, e, mot = windows[j], sol.resid[j], sol.motions[j]
        own = sol.own[j]
        rw: list[str] = []
        half = int(mot.turns.size)
        if half < MIN_HALF_CYCLES:
            rw.append(f"only {half} half-cycle{'s' if half != 1 else ''} of motion in the "
                      f"window (at least {MIN_HALF_CYCLES} are needed to tell Coulomb from "
                      "viscous friction)")
        if significant and mot.stop is None and z < _Z_WELL:
            # a friction well determined by the amplitude loss needs no stop to be believed
            # (every mild-friction record that ends before the mass sticks said so before:
            # bench/bench_adequacy.py, `coulomb-mild`); a barely significant one does
            rw.append("the fitted motion never sticks within the record and f_c/m is only "
                      f"{z:.3g} stderr from 0: the friction rests on the amplitude loss alone "
                      "(a longer record would show the stop)")
        warnings.extend(f"{names[i]}: {s}" for s in rw)
        runs.append(FreeFrictionRun(
            file=r.file, release=r.release, held=r.held, t_start=float(w.t[0]),
            t_end=float(w.t[-1]), x0=float(own[1]), v0=float(own[2]), offset=float(own[0]),
            n_samples=int(w.t.size), noise_sd=w.noise,
            residual_rms=math.sqrt(float(e @ e) / e.size),
            viscous_residual_rms=r.residual_rms, half_cycles=half,
            stop_time=None if mot.stop is None else float(w.t[0]) + mot.stop,
            stuck_position=None if mot.stuck is None else float(own[0]) + mot.stuck,
            used=True, warnings=tuple(rw)))
    if not significant:
        warnings.append(
            f"friction is not significant (f_c/m = {a:.4g} ± {a_e.stderr or math.nan:.2g} "
            f"{acc_text}, Δχ² = {dchi2:.3g} against the viscous fit, p = {p:.2g}): the viscous "
            "model suffices (phoid identify without --friction)")
    elif a < 0:
        warnings.append(f"f_c/m = {a:.4g} {acc_text} < 0: the decay is slower than viscous, not "
                        "Coulomb friction (not a passive plant)")
    warnings.extend(adequacy.warnings)
    if not sol.converged:
        warnings.append("the friction fit did not converge (evaluation limit reached); the "
                        "estimates may be poor")
    if not sigma > -2 * (sig_e.stderr or 0.0) and sigma < 0:
        warnings.append(f"σ = {sigma:.4g} 1/s < 0: viscous growth, not a passive plant")
    m_e = c_e = k_e2 = fc_e = None
    mass = vis.mass
    if mass is not None:
        m_e = Estimate(mass, 0.0, quantity_unit("kg", x_unit))
        c_e = _est(sigma, cov[0, 0], wv(0), quantity_unit("N s/m", x_unit), 2 * mass)
        k_e2 = _est(w0sq, cov[1, 1], wv(1), quantity_unit("N/m", x_unit), mass)
        fc_e = _est(a, cov[2, 2], wv(2), quantity_unit("N", x_unit), mass)
        warnings.extend(valid.overflow_warnings(mass, [("c = 2σm", c_e, 2 * sigma),
                                             ("k = ω₀²m", k_e2, w0sq),
                                             ("f_c = (f_c/m)·m", fc_e, a)]))
    return FreeFrictionIdentification(
        sigma=sig_e, omega0=omega0, zeta=zeta,
        c_over_m=_est(sigma, cov[0, 0], wv(0), "1/s", 2.0), k_over_m=k_e, fc_over_m=a_e,
        regime=regime, cov=np.array(cov), cov_white=np.array(sol.cov_white),
        evidence=evidence, viscous=vis, mass=mass, m=m_e, c=c_e, k=k_e2, fc=fc_e,
        runs=tuple(runs), warnings=tuple(warnings), source=vis.source,
        converged=sol.converged, data=vis.data, adequacy=adequacy, x_unit=x_unit)
