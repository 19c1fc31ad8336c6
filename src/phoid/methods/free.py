"""Free-decay identification (``method = "free"``): σ, ω₀, ζ and both roots, for every damping.

A free release of the plant m x'' + c x' + k x = 0 (no feedback) follows the unified response of
the seed's eq. (2) with eqs. (3)–(8), valid for underdamped, critically damped and overdamped
plants alike (ERRATA 4 in docs/equations.md):

    x(t) = x_off + x₀ [C(τ) + σS(τ)] + v₀ S(τ),   τ = t − t₀ ≥ 0,

with C, S the fundamental solutions of :func:`phoid.dynamics.plant.modal_basis` (e^{−στ}cosh wτ and
e^{−στ}sinh(wτ)/w for q = σ² − ω₀² ≥ 0, their trigonometric forms for q < 0, and the w → 0 limit
of eq. (11) at critical damping), x₀ and v₀ the position (from the offset) and velocity at the
release t₀. An overdamped release is a sum of two real exponentials, on which the logarithmic
decrement has nothing to measure; this module never assumes an oscillation. It fits the two rates
(σ, ω₀²) — shared by all releases of a set — by variable-projection Gauss–Newton (Levenberg–
Marquardt safeguarded, :func:`phoid.methods._modal.fit_modal`): for each trial (σ, ω₀²) the
offsets, x₀ and v₀ of every release follow by linear least squares, and Kaufman's step updates
the rates. When a release starts from a held segment (the mass at rest, then let go), the fit
starts where the motion has surely begun (3 samples in a row more than 8 noise sd off the held
level): a held sample left in the window would bias the decay, while the few samples skipped,
within a few noise sd of the held level, carry almost no information. The state (x₀, v₀) is
fitted at the window's start and carried back to the detected release
(:func:`phoid.fits.detect_release`'s rule) for the report. The release time is not a
fitted parameter (docs/design-notes/classical.md says why).

Only ratios are identifiable from a free decay: c/m = 2σ (eq. 3) and k/m = ω₀² (eq. 5). With a
known mass m (``--mass``, or ``mass`` in the manifest) c = 2σm and k = ω₀²m follow, with the
mass taken as exact.

Uncertainties are the Gauss–Newton covariance of all parameters (rates, offsets, x₀, v₀) with
each run weighted by its own residual noise variance — the Cramér–Rao bound of this model at the
estimate — propagated to ω₀ = √(ω₀²), ζ = σ/ω₀ (eq. 10) and the roots
s = −σ ± √(σ² − ω₀²) (eq. 4) by the delta method. The fit's adequacy is then tested
(:mod:`phoid.methods.adequacy`, docs/adequacy.md): the residual against the record's noise, its
whiteness, the rates of windows of 4 cycles against their amplitude, the two halves of the
fitted windows (every run's first halves fitted jointly, and the second halves) and each run
alone. Where a test fails, the reported covariance of (σ, ω₀²) — and every stderr derived from
it — is the robust one (Newey–West sandwich, widened by the spread between the halves or the
runs where they disagree or the windows show a trend), the white-noise stderr kept beside it
(``white_stderr``), and the warnings say what was seen and its likely cause.

The fitting engine (:mod:`phoid.methods._modal`) is shared with :mod:`phoid.methods.forced`,
whose start-up transient is the same free response added to the steady state.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from phoid import _validate as v
from phoid._threads import single_blas_thread
from phoid.dynamics.plant import free_response
from phoid.errors import IdentificationError
from phoid.fits import diff_noise, locate_release
from phoid.fits.release import RecordStart, classify_start, impulse_peak_time
from phoid.io.units import check_x_unit, quantity_unit, x_quantity
from phoid.methods._modal import (
    ModalFit,
    Segment,
    check_scales,
    esprit_rates,
    fit_modal,
    pick_start,
    release_basis,
)
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import residual_noise_ratio, window_noise
from phoid.methods.free_adequacy import assess_free
from phoid.methods.result_base import ResultBase

__all__ = ["FreeIdentification", "FreeRun", "identify_free", "identify_free_data"]

#: fewest samples a record must hold after its release
MIN_SAMPLES = 16
#: a record whose peak-to-peak motion is within this many noise sds never moved
_STILL_NSD = 12.0
#: relative standard error above which an estimate is flagged as poorly determined
_POOR = 0.1
#: the roots are "critical within uncertainty" when |σ² − ω₀²| is below this many stderr
_CRITICAL_NSE = 2.0


# --------------------------------------------------------------------------------------------
# results


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class FreeRun:
    """One release of a free-decay set, as fitted.

    Attributes
    ----------
    file : str
        Data file (as named in the manifest).
    release : float
        Release time t₀, s: detected when the record holds a held segment (``held``), else the
        first sample analysed.
    held : bool
        Whether a held segment before the release was found and modelled.
    start : str
        How the record starts (:func:`phoid.fits.release.classify_start`): ``"release"``
        (let go from a held displacement), ``"impulse"`` (a kick from rest at the
        equilibrium: ``release`` is then the kick's time, and the fit starts after the first
        swing's largest excursion, where the push has ended) or ``"none"`` (already moving).
    x0, v0 : float
        Position (m, from the offset) and velocity (m/s) at ``release``, eq. (8), from the
        fitted response.
    offset : float
        Constant sensor offset (rest position), m.
    t_start, t_end : float
        First and last sample times analysed, s.
    n_samples : int
        Samples analysed.
    noise_sd : float
        White-noise sd from the residuals, m.
    residual_rms : float
        RMS residual, m.
    snr : float
        Norm of the fitted motion over the noise sd (its square root of energy, in noise sds).
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    """

    file: str
    release: float
    held: bool
    x0: float
    v0: float
    offset: float
    t_start: float
    t_end: float
    n_samples: int
    noise_sd: float
    residual_rms: float
    snr: float
    used: bool
    warnings: tuple[str, ...] = ()
    start: str = "none"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the run."""
        return {
            "file": self.file,
            "release": _num(self.release),
            "held": self.held,
            "start": self.start,
            "x0": _num(self.x0),
            "v0": _num(self.v0),
            "offset": _num(self.offset),
            "t_start": _num(self.t_start),
            "t_end": _num(self.t_end),
            "n_samples": int(self.n_samples),
            "noise_sd": _num(self.noise_sd),
            "residual_rms": _num(self.residual_rms),
            "snr": _num(self.snr),
            "used": self.used,
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True, repr=False)
class FreeIdentification(ResultBase):
    """Result of :func:`identify_free`: σ, ω₀, ζ, the roots, c/m and k/m (and c, k for a known
    mass), with uncertainties.

    Attributes
    ----------
    sigma : Estimate
        Decay rate σ = c/(2m), 1/s (eq. 3).
    omega0 : Estimate
        Natural frequency ω₀ = √(k/m), rad/s (eq. 5).
    zeta : Estimate
        Damping ratio ζ = σ/ω₀ (eq. 10).
    c_over_m, k_over_m : Estimate
        2σ (1/s) and ω₀² (1/s²): what a free decay determines of the plant.
    roots : tuple of complex
        The two roots of s² + 2σs + ω₀² = 0, 1/s, rightmost first (eq. 4).
    roots_stderr : tuple of (float or None, float or None)
        Standard errors of each root's real and imaginary parts (None when the damping is
        critical within its uncertainty: the split of the roots is then undetermined).
    regime : str
        ``"underdamped"``, ``"critical"`` (σ² − ω₀² within 2 stderr of 0) or ``"overdamped"``.
    cov : ndarray, shape (2, 2)
        Covariance of (σ, ω₀²).
    mass : float or None
        The known mass (kg) used for c and k, if any.
    m, c, k : Estimate or None
        Known mass (stderr 0), c = 2σm (N s/m) and k = ω₀²m (N/m); None without a mass.
    runs : tuple of FreeRun
    warnings : tuple of str
    source : str
    x_unit : str
        What x is in (``"m"``; ``"rad"`` for a rotational set, whose m, c, k are J in kg m^2,
        N m s/rad and N m/rad; a sensor unit such as ``"V"``, without c and k): the unit of
        the runs' ``x0``, ``offset``, ``noise_sd``, ``residual_rms`` (and per s, ``v0``).
    adequacy : phoid.methods.adequacy.Adequacy or None
        The adequacy checks (phoid.methods.free_adequacy), both covariances of (σ, ω₀²) and
        the stderr's inflation; where it says ``stderr == "robust"`` every estimate's
        ``stderr`` is the robust one and ``white_stderr`` the white-noise one.
    """

    sigma: Estimate
    omega0: Estimate
    zeta: Estimate
    c_over_m: Estimate
    k_over_m: Estimate
    roots: tuple[complex, complex]
    roots_stderr: tuple[tuple[float | None, float | None], ...]
    regime: str
    cov: np.ndarray = field(repr=False)
    mass: float | None = None
    m: Estimate | None = None
    c: Estimate | None = None
    k: Estimate | None = None
    runs: tuple[FreeRun, ...] = ()
    x_unit: str = "m"

    METHOD: ClassVar[str] = "free"
    REPORT: ClassVar[str] = "phoid.reports.text:free_text"
    FIGURES: ClassVar[str] = "phoid.reports.figures:plot_free"

    def model(self, i: int, t: np.ndarray | float) -> np.ndarray:
        """Fitted position of run ``i`` (0-based) at times ``t`` (s), m."""
        r = self.runs[i]
        B1, B2 = release_basis(np.asarray(t, dtype=float) - r.release, self.sigma.value,
                               self.k_over_m.value)
        return r.offset + r.x0 * B1 + r.v0 * B2

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --json`` for a free set.

        Keys: ``method`` ("free"), ``sigma`` (1/s), ``omega0`` (rad/s), ``zeta``, ``c_over_m``
        (1/s), ``k_over_m`` (1/s^2), each ``{"value", "stderr", "unit"}``; ``regime``;
        ``roots``: two objects ``{"re", "im", "re_stderr", "im_stderr", "unit": "1/s"}``,
        rightmost first (stderr null when the damping is critical within its uncertainty);
        ``runs``; ``warnings``. With a known mass also ``m`` (the given mass, stderr 0,
        ``"source": "given"``), ``c`` and ``k``. Each run has ``residual_noise_ratio``
        (:meth:`residual_noise_ratios`); ``covariance``, ``correlation`` and ``statistics`` are
        :meth:`fit_statistics`. ``x_unit``: the unit of x and of the runs' ``x0``,
        ``offset``, ``noise_sd``, ``residual_rms`` (``v0``: ``x_unit``/s).
        """
        out: dict[str, Any] = {
            "method": "free",
            "x_unit": self.x_unit,
            "sigma": self.sigma.to_dict(),
            "omega0": self.omega0.to_dict(),
            "zeta": self.zeta.to_dict(),
            "c_over_m": self.c_over_m.to_dict(),
            "k_over_m": self.k_over_m.to_dict(),
            "regime": self.regime,
            "roots": [
                {"re": float(s.real), "im": float(s.imag), "re_stderr": _num(se[0]),
                 "im_stderr": _num(se[1]), "unit": "1/s"}
                for s, se in zip(self.roots, self.roots_stderr, strict=True)
            ],
        }
        for key in ("omega0", "zeta"):
            if not math.isfinite(getattr(self, key).value):
                out[key] = {"value": None, "stderr": None, "unit": getattr(self, key).unit}
        if self.m is not None and self.c is not None and self.k is not None:
            out["m"] = {**self.m.to_dict(), "source": "given"}
            out["c"] = self.c.to_dict()
            out["k"] = self.k.to_dict()
        out["runs"] = self.run_entries()
        return out | self.summary_tail()

    def _noise_levels(self) -> list[float | None]:
        """Each used run's noise level from its record alone (difference_noise in its window)."""
        out: list[float | None] = []
        for i, r in enumerate(self.runs):
            if not r.used or i >= len(self.data):
                out.append(None)
                continue
            t, x = self.data[i]
            out.append(window_noise(t, x, r.t_start, r.t_end))
        return out

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the RMS of its free-response fit's residual over the record's noise level
        estimated without the model (:func:`phoid.methods.fit_statistics.difference_noise`
        over the fitted window); ≈ 1 when the free response explains the record to its noise,
        ≫ 1 for a misfit. None for a run set aside, or when the result carries no records."""
        return [residual_noise_ratio(r.residual_rms, q)
                for r, q in zip(self.runs, self._noise_levels(), strict=True)]

    def statistics_of(self) -> tuple[list[str], list[str], np.ndarray, float | None,
                                     int | None, str]:
        """The ``covariance``, ``correlation`` and ``statistics`` blocks' content
        (:meth:`phoid.methods.result_base.ResultBase.fit_statistics`).

        The parameters are σ (``sigma``, 1/s) and ω₀² (``k_over_m``, 1/s²), what a free decay
        determines (c and k of a known mass are these times the mass). χ² is that of the joint
        free-response fit of all runs, each residual weighted by its run's noise level
        estimated without the model: χ² = Σᵢ nᵢ·rmsᵢ²/ŝᵢ² (ŝᵢ from
        :func:`~phoid.methods.fit_statistics.difference_noise`; the fit's own weights come from
        its residuals, which would make χ²/dof 1 by construction), dof = Σᵢ nᵢ − 2 − 3·runs
        (σ, ω₀², and each run's offset, x₀ and v₀).
        """
        chi2, n, used = 0.0, 0, 0
        for r, q in zip(self.runs, self._noise_levels(), strict=True):
            if q is None or not (q > 0 and math.isfinite(r.residual_rms)):
                continue
            chi2 += r.n_samples * r.residual_rms**2 / q**2
            n += r.n_samples
            used += 1
        dof = n - 2 - 3 * used
        return (["sigma", "k_over_m"], ["1/s", "1/s^2"], self.cov,
                chi2 if used else None, dof if used else None,
                "the joint free-response fit of x in every run, each residual over its run's "
                "noise level estimated from third differences")

    # ---- export: python-control, scipy.signal, pandas (phoid.interop) ----

    def to_control(self, *, form: str = "tf", per_unit_mass: bool = False) -> Any:
        """The identified plant G(s) = 1/(m s² + c s + k), force (N) → position (m), as a
        python-control system (:func:`phoid.interop.control.to_control`).

        ``form="tf"`` gives a TransferFunction, ``"ss"`` a StateSpace with states x (m) and
        v (m/s); the covariance of (m, c, k) travels as ``.phoid.cov``.
        Without a known mass only c/m and k/m are known: ``per_unit_mass=True`` exports
        1/(s² + (c/m)s + k/m) (input F/m), else a ValueError says so.
        """
        from phoid.interop.control import to_control

        return to_control(self, form=form, per_unit_mass=per_unit_mass)

    def to_lti(self, *, form: str = "tf", per_unit_mass: bool = False) -> Any:
        """The identified plant as a :class:`scipy.signal.lti` (no python-control needed;
        :func:`phoid.interop.control.to_lti`)."""
        from phoid.interop.control import to_lti

        return to_lti(self, form=form, per_unit_mass=per_unit_mass)

    def sample_plants(self, n: int, rng: Any = None, *, form: str = "plant",
                      per_unit_mass: bool = False) -> list:
        """``n`` Monte Carlo plants: (m, c, k) drawn from the estimates' normal with this
        result's covariance, draws with m ≤ 0, c < 0 or k < 0 rejected
        (:func:`phoid.interop.sampling.sample_plants`; ``form`` "plant", "tf", "ss", "lti")."""
        from phoid.interop.sampling import sample_plants

        return sample_plants(self, n, rng, form=form, per_unit_mass=per_unit_mass)

    def to_pandas(self) -> Any:
        """``Frames(estimates, runs)``: the estimates (rows σ, ω₀, ζ, c/m, k/m, …; columns
        value, stderr, unit) and the runs (one row per run) as pandas DataFrames
        (:func:`phoid.interop.tables.to_pandas`)."""
        from phoid.interop.tables import to_pandas

        return to_pandas(self)


# --------------------------------------------------------------------------------------------
# derived quantities


def _derived(sigma: float, w0sq: float, cov: np.ndarray):
    """ω₀, ζ, roots and their stderr by the delta method (eqs. 4, 5, 10)."""
    var_s, var_w = float(cov[0, 0]), float(cov[1, 1])
    if w0sq > 0:
        w0 = math.sqrt(w0sq)
        omega0 = Estimate(w0, math.sqrt(max(var_w, 0.0)) / (2 * w0), "rad/s")
        g = np.array([1 / w0, -sigma / (2 * w0**3)])
        zeta = Estimate(sigma / w0, math.sqrt(max(float(g @ cov @ g), 0.0)), "")
    else:
        omega0 = Estimate(0.0 if w0sq == 0 else math.nan, None, "rad/s")
        zeta = Estimate(math.nan, None, "")
    q = sigma * sigma - w0sq
    gq = np.array([2 * sigma, -1.0])
    se_q = math.sqrt(max(float(gq @ cov @ gq), 0.0))
    w = math.sqrt(abs(q))
    se_s = math.sqrt(max(var_s, 0.0))
    if abs(q) <= _CRITICAL_NSE * se_q or q == 0.0:
        regime = "critical"
    else:
        regime = "overdamped" if q > 0 else "underdamped"
    if q >= 0:
        slow = -w0sq / (sigma + w) if sigma > 0 else -sigma + w
        fast = -sigma - w
        roots = (complex(slow), complex(fast))
    else:
        roots = (complex(-sigma, w), complex(-sigma, -w))
    if regime == "critical":
        ses: tuple[tuple[float | None, float | None], ...] = ((None, None), (None, None))
    elif q > 0:
        # s = −σ ± √q: ∂/∂σ = −1 ± σ/w, ∂/∂ω₀² = ∓1/(2w)
        out = []
        for sgn in (1.0, -1.0):
            gr = np.array([-1 + sgn * sigma / w, -sgn / (2 * w)])
            out.append((math.sqrt(max(float(gr @ cov @ gr), 0.0)), 0.0))
        ses = tuple(out)
    else:
        # s = −σ ± i√(−q): ∂Im/∂σ = −σ/w, ∂Im/∂ω₀² = 1/(2w)
        gi = np.array([-sigma / w, 1 / (2 * w)])
        se_im = math.sqrt(max(float(gi @ cov @ gi), 0.0))
        ses = ((se_s, se_im), (se_s, se_im))
    return omega0, zeta, roots, ses, regime, q, se_q


# --------------------------------------------------------------------------------------------
# the public functions


def identify_free(experiment: Any, *, mass: float | None = None) -> FreeIdentification:
    """Identify σ, ω₀, ζ and both roots from a free-decay experiment set (eqs. 2–15).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A set with ``method = "free"``: one or more releases (t, x) of the same plant without
        feedback, as read by :func:`phoid.io.read_experiment`.
    mass : float, optional
        Known mass, kg (> 0); overrides the manifest's ``mass``. With a mass, c and k are
        returned too.

    Returns
    -------
    FreeIdentification

    Raises
    ------
    IdentificationError
        If the set is not a free set, a run carries feedback gains or an added mass, or no run
        can be fitted (every record too short or never moving).
    """
    where = str(getattr(experiment, "path", ""))
    method = getattr(experiment, "method", "free")
    if method != "free":
        raise IdentificationError(f"{where}: method = {method!r} is not a free-decay set")
    runs = list(experiment.runs)
    if not runs:
        raise IdentificationError(f"{where}: no runs")
    for r in runs:
        if (r.P or 0.0) != 0.0 or (r.D or 0.0) != 0.0:
            raise IdentificationError(
                f"{where}: {r.name}: P = {r.P}, D = {r.D}: a free-decay run has no feedback "
                "(use method = \"pho\" for runs under PD feedback)")
        if getattr(r, "added_mass", 0.0):
            raise IdentificationError(
                f"{where}: {r.name}: added_mass is not supported for free-decay sets (every "
                "release must be of the same plant)")
    x_unit = getattr(experiment, "x_unit", "m")
    if mass is not None and x_quantity(x_unit) == "signal":
        raise IdentificationError(
            f"{where}: --mass cannot be used with x in {x_unit} (a sensor unit, [units] x): "
            "c and k need x in a length or an angle unit; a free decay in sensor units gives "
            "only σ, ω₀, ζ, c/m and k/m")
    label = "`mass`"
    if mass is None:
        mass, label = getattr(experiment, "mass", None), "mass (the manifest's)"
    if mass is not None:
        try:
            mass = v.physical(label, mass, "kg")
        except ValueError as exc:
            raise IdentificationError(f"{where}: {exc}") from None
    result = identify_free_data(
        [(r.t, r.x) for r in runs], mass=mass, files=[r.file for r in runs],
        names=[r.name for r in runs], source=where, x_unit=x_unit,
    )
    # what the reader did (a t column rebuilt from sample_rate), then a [loop] ignored
    extra = tuple(getattr(experiment, "notes", ()))
    loop = getattr(experiment, "loop", None) or {}
    if loop:
        extra += ("[loop] is ignored for a free-decay set (no feedback)",)
    return _with_warnings(result, extra) if extra else result


def _quantum_sd(x: np.ndarray) -> float:
    """The noise floor of a quantised record: q/√12, q its resolution (the smallest step between
    its distinct values), when it holds at most n/4 distinct values (a logger's counts); else 0.

    A quantised record that barely moves has second differences that are mostly zero, and their
    MAD (:func:`phoid.fits.diff_noise`) then says its noise is far below one count: a motion of
    a count or two would pass for a swing, and the fit latch onto the rounding.
    """
    u = np.unique(x)
    if u.size < 2 or u.size > x.size // 4:
        return 0.0
    return float(np.min(np.diff(u))) / math.sqrt(12.0)


def _with_warnings(result: FreeIdentification, extra: tuple[str, ...]) -> FreeIdentification:
    return replace(result, warnings=tuple(result.warnings) + extra)


@single_blas_thread
def identify_free_data(
    data: Sequence[tuple[Any, Any]],
    *,
    mass: float | None = None,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    source: str = "",
    x_unit: str = "m",
) -> FreeIdentification:
    """:func:`identify_free` on plain arrays: ``data`` is a sequence of (t, x) per release.

    Parameters
    ----------
    data : sequence of (array_like, array_like)
        Each release's sample times (s, strictly increasing) and positions (m).
    mass : float, optional
        Known mass, kg (> 0).
    files, names : sequence of str, optional
        Labels of the runs (file names for the results, names for messages).
    source : str
        Where the data came from, for the report.
    x_unit : str, default "m"
        What x is in: ``"m"``, ``"rad"`` (m, c, k then labelled J kg m^2, N m s/rad,
        N m/rad) or a sensor unit (``"V"``, …; no ``mass`` then).

    Returns
    -------
    FreeIdentification

    Raises
    ------
    IdentificationError
        If no run can be fitted, or a run's sample step (s) or largest |x| lies outside
        :data:`phoid.methods._modal.SCALE_RANGE` (1e-30 … 1e30; within it the fit is the
        same in any unit).
    ValueError
        For malformed arrays (NaN/inf, lengths differ, t not increasing) or a bad ``mass``
        (> 0, of magnitude 1e-30 … 1e30 kg: :func:`phoid._validate.physical`).

    Examples
    --------
    >>> import numpy as np
    >>> from phoid.dynamics.plant import free_response
    >>> t = np.arange(4000) / 1000.0                  # 4 s at 1 kHz
    >>> x, _ = free_response(t, 3.0, 100.0, 0.01, 0.0)  # σ = 3 1/s, ω₀ = 10 rad/s
    >>> res = identify_free_data([(t, x)])
    >>> round(res.zeta.value, 6), round(res.omega0.value, 6), res.regime
    (0.3, 10.0, 'underdamped')

    Notes
    -----
    Per run: the white-noise sd from second differences; a record whose peak-to-peak motion is
    within 12 noise sds never moved and is set aside, as is one with fewer than 16 samples after
    its release. The release is found by :func:`phoid.fits.detect_release`'s rule; when
    a held segment precedes it, the window starts where the motion has surely begun (module
    docstring). Starting rates: ESPRIT (an offset and two modes) on each run's motion, every
    admissible pair of roots tried, the best by the residual sum of squares
    (:func:`phoid.methods._modal.pick_start`). Then :func:`phoid.methods._modal.fit_modal`.
    """
    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    check_x_unit("identify_free_data", x_unit, "free")
    if mass is not None:
        mass = v.physical("`mass`", mass, "kg")
        if x_quantity(x_unit) == "signal":
            raise ValueError(f"`mass` cannot be used with x in {x_unit!r} (a sensor unit): "
                             "c and k need x in a length or an angle unit")
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    names = list(names) if names is not None else files
    arrays: list[tuple[np.ndarray, np.ndarray]] = []
    segs: list[Segment] = []
    seg_of: list[int | None] = []
    reasons: list[str | None] = []
    noise0: list[float] = []
    releases: list[tuple[float, bool]] = [(math.nan, False)] * n
    starts: list[RecordStart | None] = [None] * n
    for i, (t, x) in enumerate(data):
        try:
            t = v.finite_array("t", t, ndim=1)
            x = v.finite_array("x", x, ndim=1)
        except ValueError as exc:
            raise ValueError(f"{names[i]}: {exc}") from None
        if t.shape != x.shape:
            raise ValueError(f"{names[i]}: `t` and `x` must have the same length; "
                             f"got {t.size} and {x.size}")
        if t.size >= 2 and not (np.diff(t) > 0).all():
            raise ValueError(f"{names[i]}: `t` must be strictly increasing")
        check_scales(t, x, (f"{source}: " if source else "") + names[i], x_unit)
        arrays.append((t, x))
        seg_of.append(None)
        if t.size < MIN_SAMPLES:
            reasons.append(f"too short: {t.size} samples (at least {MIN_SAMPLES} are needed)")
            continue
        nsd = max(diff_noise(x), _quantum_sd(x))
        ptp = float(np.ptp(x))
        if not ptp > _STILL_NSD * nsd or ptp == 0.0:
            reasons.append(f"x never moves: its peak-to-peak {ptp:.3g} {x_unit} is within "
                           f"the noise (sd {nsd:.3g} {x_unit})")
            continue
        j, hold_sd = locate_release(t, x)
        how = starts[i] = classify_start(t, x, (j, hold_sd))
        held = hold_sd is not None and j >= 10 and how.kind != "impulse"
        if how.kind == "impulse":
            # a kick from rest: the response is free once the push has ended, after the first
            # swing's largest excursion (classify_start says why)
            start = how.fit_from
        elif held:
            # the window starts where the motion has surely begun: the first of 3 samples in
            # a row more than 8 noise sd off the held level (a held sample left in would bias
            # the fit; the few samples lost carry almost no information, the motion there
            # being within a few noise sd of the held level)
            level = float(np.mean(x[: j + 1]))
            out = np.abs(x - level) > 8.0 * max(float(hold_sd), nsd)
            hits = np.flatnonzero(out[:-2] & out[1:-1] & out[2:])
            hits = hits[hits > j]
            start = int(hits[0]) if hits.size else j + 1
        else:
            start = j if j > 2 else 0
            if how.kind == "release" and how.peak is not None:
                # a release whose hold was not still (a hand that drifts, pulls, lets go at
                # an unknown sample): the samples before the first swing's largest excursion
                # mix the hand's motion with the free one; from there on it is free (half a
                # cycle lost at most)
                start = max(start, how.peak + 1)
        if how.clipping is not None:  # clipped samples are no free response: left out
            start = max(start, how.clipping.last + 1)
        after = t.size - start
        if after < MIN_SAMPLES and how.kind == "impulse":
            reasons.append(f"starts with a kick from rest (an impulse at t = {how.time:.6g} s), "
                           f"not a release, and only {after} samples follow its first swing's "
                           f"largest excursion, where the push has surely ended (at least "
                           f"{MIN_SAMPLES} are needed)")
            continue
        if after < MIN_SAMPLES:
            reasons.append(f"too short: {after} samples after the release (at least "
                           f"{MIN_SAMPLES} are needed)")
            continue
        seg = Segment(t=t[start:], x=x[start:], fixed=np.ones((after, 1)), t0=float(t[start]))
        releases[i] = (how.time if how.kind == "impulse" else float(t[j]) if held
                       else float(t[start]), held)
        reasons.append(None)
        seg_of[i] = len(segs)
        segs.append(seg)
        noise0.append(max(nsd, 1e-13 * ptp))
    if not segs:
        raise IdentificationError(
            (f"{source}: " if source else "") + "no usable runs: "
            + "; ".join(f"{names[i]}: {reasons[i]}" for i in range(n)))
    fit = _best_fit(segs, noise0)

    sigma, w0sq = fit.sigma, fit.w0sq
    used = [i for i in range(n) if seg_of[i] is not None]
    adequacy = assess_free(segs, fit, [names[i] for i in used], x_unit=x_unit)
    cov = adequacy.robust_cov
    robust = adequacy.stderr == "robust"
    se_s = math.sqrt(max(cov[0, 0], 0.0))
    se_w = math.sqrt(max(cov[1, 1], 0.0))
    omega0, zeta, roots, ses, regime, q, se_q = _derived(sigma, w0sq, cov)
    ws = ww = None
    if robust:
        w_omega0, w_zeta, *_rest = _derived(sigma, w0sq, fit.cov)
        ws = math.sqrt(max(fit.cov[0, 0], 0.0))
        ww = math.sqrt(max(fit.cov[1, 1], 0.0))
        omega0 = replace(omega0, white_stderr=w_omega0.stderr)
        zeta = replace(zeta, white_stderr=w_zeta.stderr)

    def robust_est(value: float, se: float, wse: float | None, unit: str) -> Estimate:
        return Estimate(value, se, unit, white_stderr=wse)
    warnings: list[str] = []
    runs: list[FreeRun] = []
    for i in range(n):
        t, x = arrays[i]
        k_seg = seg_of[i]
        if k_seg is None:
            warnings.append(f"{names[i]}: set aside: {reasons[i]}")
            runs.append(FreeRun(file=files[i], release=math.nan, held=False, x0=math.nan,
                                v0=math.nan, offset=math.nan,
                                t_start=float(t[0]) if t.size else math.nan,
                                t_end=float(t[-1]) if t.size else math.nan,
                                n_samples=int(t.size), noise_sd=math.nan,
                                residual_rms=math.nan, snr=0.0, used=False,
                                warnings=(reasons[i] or "",),
                                start=starts[i].kind if starts[i] is not None else "none"))
            continue
        s = segs[k_seg]
        coef = fit.coef[k_seg]
        r = fit.resid[k_seg]
        nsd = fit.noise[k_seg]
        motion = s.x - coef[0] - r
        snr = float(np.linalg.norm(motion)) / nsd
        rw: list[str] = []
        if snr < 10:
            rw.append(f"the motion is barely above the noise ({snr:.1f} noise sd in all)")
        how = starts[i]
        if how is not None:
            rw.extend(_start_warnings(how, t, float(s.t[0]), sigma, w0sq, x_unit))
        warnings.extend(f"{names[i]}: {w}" for w in rw)
        # the state at the release, from the fitted state at the window's start (eq. 8)
        t_rel = releases[i][0]
        x_rel, v_rel = free_response(t_rel - s.t0, sigma, w0sq, coef[1], coef[2])
        runs.append(FreeRun(
            file=files[i], release=t_rel, held=releases[i][1], x0=float(x_rel),
            v0=float(v_rel), offset=float(coef[0]), t_start=float(s.t[0]),
            t_end=float(s.t[-1]), n_samples=int(s.t.size), noise_sd=nsd,
            residual_rms=float(math.sqrt(float(r @ r) / r.size)), snr=snr, used=True,
            warnings=tuple(rw), start=how.kind if how is not None else "none",
        ))
    warnings.extend(adequacy.warnings)
    if not fit.converged:
        warnings.append("the free-response fit did not converge; the estimates may be poor")
    if not sigma > 0:
        warnings.append(f"σ = {sigma:.4g} 1/s ≤ 0: the record does not decay (no damping, or "
                        "growth: not a passive plant)")
    if not w0sq > 0:
        warnings.append(f"ω₀² = {w0sq:.4g} 1/s² ≤ 0: no restoring spring (k ≈ 0); ω₀ and ζ "
                        "are undefined")
    for label, est in (("ω₀", omega0), ("ζ", zeta)):
        if est.stderr is not None and math.isfinite(est.value) and est.value != 0 \
                and est.stderr > _POOR * abs(est.value):
            why = ("the model does not hold over the record (the warnings above), and the "
                   "robust stderr counts that" if robust else
                   "the records are too short or too noisy")
            warnings.append(f"{label} is poorly determined (relative stderr "
                            f"{est.stderr / abs(est.value):.0%}): {why}")
    if regime == "critical":
        spread = math.sqrt(abs(q) + _CRITICAL_NSE * se_q)
        warnings.append(
            f"the damping is critical within its uncertainty (σ² − ω₀² = {q:.3g} ± {se_q:.2g} "
            f"1/s²): the two roots are not separately determined (both within ±{spread:.3g} "
            f"1/s of −σ = {-sigma:.5g} 1/s), so their stderr are not given")
    m_est = c_est = k_est = None
    if mass is not None:
        m_est = Estimate(mass, 0.0, quantity_unit("kg", x_unit))  # J in kg m^2 for x in rad
        c_est = robust_est(2 * sigma * mass, 2 * se_s * mass, ws and 2 * ws * mass,
                           quantity_unit("N s/m", x_unit))
        k_est = robust_est(w0sq * mass, se_w * mass, ww and ww * mass,
                           quantity_unit("N/m", x_unit))
        with np.errstate(over="ignore"):
            warnings.extend(v.overflow_warnings(mass, [("c = 2σm", c_est, 2 * sigma),
                                                 ("k = ω₀²m", k_est, w0sq)]))
    return FreeIdentification(
        sigma=robust_est(sigma, se_s, ws, "1/s"), omega0=omega0, zeta=zeta,
        c_over_m=robust_est(2 * sigma, 2 * se_s, ws and 2 * ws, "1/s"),
        k_over_m=robust_est(w0sq, se_w, ww, "1/s^2"),
        roots=roots, roots_stderr=ses, regime=regime, cov=cov.copy(), mass=mass,
        m=m_est, c=c_est, k=k_est, runs=tuple(runs), warnings=tuple(warnings),
        source=source, data=tuple(arrays), x_unit=x_unit, adequacy=adequacy,
    )


def _start_warnings(how: RecordStart, t: np.ndarray, t_fit: float, sigma: float, w0sq: float,
                    unit: str) -> list[str]:
    """The warnings on how a fitted run starts: a kick rather than a release (with the push's
    length judged against the fitted free response), samples clipped."""
    out: list[str] = []
    if how.kind == "impulse" and how.peak is not None:
        out.append(f"starts with a kick from rest (an impulse at t = {how.time:.6g} s), not a "
                   f"release: {how.evidence(unit)}; the free response is fitted from "
                   f"t = {t_fit:.6g} s, after the first swing's largest excursion, where the "
                   "push has ended")
        # a one-signed push of any length turns no sooner than the free response after an
        # ideal impulse (impulse_peak_time); much later, the push lasted that long (not
        # judged on a clipped record: its first peak is hidden)
        t_pk = impulse_peak_time(sigma, w0sq) if how.clipping is None else math.nan
        t_turn = float(t[how.peak]) - how.time
        dt = float(t[min(how.peak + 1, t.size - 1)] - t[how.peak])
        if math.isfinite(t_pk) and t_turn - 2 * dt > 2 * t_pk:
            out.append(f"its first swing took {t_turn:.3g} s to its largest excursion, "
                       f"{t_turn / t_pk:.2g}× a free response's after a kick ({t_pk:.3g} s): "
                       f"the push lasted about {t_turn - t_pk:.2g} s and may not have ended "
                       "there; the fit may include forced samples")
        elif math.isfinite(t_pk) and t_turn + 2 * dt < 0.5 * t_pk:
            out.append(f"its first swing turned after {t_turn:.3g} s, sooner than a free "
                       f"response can after a one-signed push ({t_pk:.3g} s): the force "
                       "reversed (a push and a pull) or the model misfits the start")
    c = how.clipping
    if c is not None:
        out.append(f"clipped at {c.level:.6g} {unit}: {c.n_samples} samples flat at the "
                   f"record's extreme (t = {float(t[c.runs[0][0]]):.6g} … "
                   f"{float(t[c.last]):.6g} s), left out: the fit starts after them")
    return out


def _best_fit(segs: list[Segment], noise: list[float]) -> ModalFit:
    """Starting rates from the three runs with the largest motion (ESPRIT root pairs, each run
    started 0, 2 and 8 samples into its window: a kink or a stray sample at the start can throw
    ESPRIT off) and a slow fallback; the start with the lowest weighted SSE is refined by
    :func:`fit_modal`."""
    cands: list[tuple[float, float]] = []
    order = np.argsort([-float(np.ptp(s.x)) / nz for s, nz in zip(segs, noise, strict=True)])
    for k in order[:3]:
        s = segs[int(k)]
        for lag in (0, 2, 8):
            cands += esprit_rates(s.t[lag:], s.x[lag:], noise[int(k)], grid=lag == 0)
    span = max(float(s.t[-1] - s.t0) for s in segs)
    cands.append((2.0 / span, (2 * math.pi / span) ** 2))
    start = pick_start(segs, cands, 1.0 / np.square(noise))
    return fit_modal(segs, start[0], start[1], noise=noise)
