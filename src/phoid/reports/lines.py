"""Figures of the straight lines m, c, k are read from, and of the m–k confidence region.

* :func:`pho_lines_figure` — the two lines of eq. (35), c′ᵢ = 2mσᵢ − c and k′ᵢ = mω₀ᵢ² − k,
  with each run's point, its error bars and a panel of residuals in units of their standard
  error;
* :func:`forced_lines_figure` — the two lines of eq. (20), R cos ρ = k − mω² and
  R sin ρ = cω, likewise;
* :func:`mk_ellipse_figure` — the joint confidence region of (m, k) from a result's covariance.

The points, error bars and residuals are computed by :func:`pho_line_points` and
:func:`forced_line_points` (what the figures draw, for tests and notebooks). Results are taken
by duck typing; matplotlib is imported inside the functions that draw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid.dynamics.loop import inverse_map
from phoid.reports.text import format_estimate

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Line", "forced_line_points", "forced_lines_figure", "mk_covariance",
           "mk_ellipse_figure", "pho_line_points", "pho_lines_figure"]

#: Δχ² of the two drawn joint regions of (m, k) and their probability content (χ², 2 dof):
#: P = 1 − exp(−Δχ²/2), i.e. 39.3 % and 86.5 %.
ELLIPSE_LEVELS = (1.0, 4.0)

#: size (inches) and base font size (points) of a lines figure: drawn for the HTML report's
#: two-column grid (shown about 560 px wide, half its width at 120 dpi), where 11 pt text
#: is still about 10 px high
LINES_SIZE = (9.0, 6.0)
LINES_FONT = 12


@dataclass(frozen=True)
class Line:
    """One straight line with its points, as a lines figure draws it.

    Attributes
    ----------
    x, y : ndarray
        The points (one per used run).
    xerr, yerr : ndarray
        Their standard errors (0 where a coordinate carries none).
    slope, intercept : float
        The line drawn, y = slope·x + intercept.
    residual : ndarray
        y − (slope·x + intercept).
    residual_stderr : ndarray
        Standard error of each residual (propagated from the run's own fit: see the figure
        functions).
    label : str
        The line's legend entry.
    """

    x: np.ndarray
    y: np.ndarray
    xerr: np.ndarray
    yerr: np.ndarray
    slope: float
    intercept: float
    residual: np.ndarray
    residual_stderr: np.ndarray
    label: str

    @property
    def normalised(self) -> np.ndarray:
        """Residuals in units of their standard error (nan where that is 0 or unknown)."""
        se = np.where(self.residual_stderr > 0, self.residual_stderr, np.nan)
        return self.residual / se


def _used_delay(ident: Any) -> float:
    """The delay the c′ᵢ, k′ᵢ were mapped with: the fit's own (a sampled loop's equivalent
    continuous delay, or an estimated one), else the result's."""
    d = getattr(ident.fit, "delay", None)
    return float(ident.delay if d is None else d)


def _pho_jacobian(r: Any, delay: float, compensate: bool) -> np.ndarray:
    """∂(2σ, c′, ω₀², k′)/∂(σ, ω_d) of one run: eq. (32) by central differences (step 10⁻⁶ of
    each coordinate's scale), the added mass's known part taken off as in the result."""
    s, w = float(r.sigma), float(r.omega_d)
    dm = float(getattr(r, "added_mass", 0.0) or 0.0)

    def f(s_, w_):
        cp, kp = inverse_map(s_, w_, r.P, r.D, delay, compensate=compensate)
        w0 = s_**2 + w_**2
        return np.array([2 * s_, float(cp) - 2 * dm * s_, w0, float(kp) - dm * w0])

    h = 1e-6 * np.array([max(abs(s), abs(w), 1e-3)] * 2)
    J = np.empty((4, 2))
    J[:, 0] = (f(s + h[0], w) - f(s - h[0], w)) / (2 * h[0])
    J[:, 1] = (f(s, w + h[1]) - f(s, w - h[1])) / (2 * h[1])
    return J


def pho_line_points(ident: Any) -> tuple[Line, Line]:
    """The eq. (35) lines of a PHO identification as :func:`pho_lines_figure` draws them.

    Parameters
    ----------
    ident : phoid.Identification or alike
        Read: ``runs`` (each with ``used``, ``P`` (N/m), ``D`` (N s/m), ``sigma`` (1/s),
        ``omega_d`` (rad/s), ``c_prime`` (N s/m), ``k_prime`` (N/m), ``added_mass`` (kg,
        optional) and ``fit.cov``, the (2, 2) covariance of (σᵢ, ω_dᵢ)); ``fit`` (an
        :class:`phoid.methods.pho.MCKFit`: ``estimator``, ``compensated``, ``delay``,
        ``c_line``, ``k_line``); ``delay`` (s); ``m``, ``c``, ``k`` (each with ``value``).

    Returns
    -------
    (Line, Line)
        The damping line (x = 2σᵢ, y = c′ᵢ) and the stiffness line (x = ω₀ᵢ² = σᵢ² + ω_dᵢ²,
        y = k′ᵢ). The lines drawn are the ones fitted: for ``estimator="ols"`` each line's own
        least-squares slope and intercept (``fit.c_line``, ``fit.k_line``; the two slopes differ
        where the points are not those of one plant, e.g. without delay compensation); for the
        weighted fit the joint estimate, slope m and intercepts −c and −k.

    Notes
    -----
    The error bars propagate each run's (σᵢ, ω_dᵢ) covariance Σᵢ through eq. (32) to first
    order (delta method): with Jᵢ the Jacobian of (2σᵢ, c′ᵢ, ω₀ᵢ², k′ᵢ) with respect to
    (σᵢ, ω_dᵢ) (central differences), the variances are diag(Jᵢ Σᵢ Jᵢᵀ). The residual
    rᵢ = yᵢ − (slope·xᵢ + intercept) depends on (σᵢ, ω_dᵢ) through both coordinates, which are
    correlated, so its standard error is √(gᵢ Σᵢ gᵢᵀ) with gᵢ = ∂yᵢ − slope·∂xᵢ (the rows of
    Jᵢ); the line's own uncertainty is not included. Without compensation c′ᵢ = Dᵢ and
    k′ᵢ = Pᵢ carry no error, and the residual's is the slope times that of xᵢ.
    """
    used = [r for r in ident.runs if r.used]
    fit = ident.fit
    compensate = bool(getattr(fit, "compensated", True))
    delay = _used_delay(ident)
    Js = [_pho_jacobian(r, delay, compensate) for r in used]
    covs = [np.asarray(r.fit.cov, dtype=float)[:2, :2] for r in used]
    x = np.array([[2 * r.sigma, r.sigma**2 + r.omega_d**2] for r in used]).T
    y = np.array([[r.c_prime, r.k_prime] for r in used]).T
    m, c, k = ident.m.value, ident.c.value, ident.k.value
    if getattr(fit, "estimator", "gls") == "ols" and fit.c_line is not None:
        lines = [(fit.c_line.slope, fit.c_line.intercept,
                  f"OLS line: slope {fit.c_line.slope:.5g} kg, intercept "
                  f"{fit.c_line.intercept:.5g} N s/m (c = {c:.5g} N s/m)"),
                 (fit.k_line.slope, fit.k_line.intercept,
                  f"OLS line: slope m = {fit.k_line.slope:.5g} kg, intercept "
                  f"{fit.k_line.intercept:.5g} N/m (k = {k:.5g} N/m)")]
    else:
        lines = [(m, -c, f"c′ = 2mσ − c: m = {m:.5g} kg, c = {c:.5g} N s/m"),
                 (m, -k, f"k′ = mω₀² − k: m = {m:.5g} kg, k = {k:.5g} N/m")]
    out = []
    for j, (slope, intercept, label) in enumerate(lines):
        ix, iy = 2 * j, 2 * j + 1
        pairs = list(zip(Js, covs, strict=True))
        xerr = np.array([math.sqrt(max(J[ix] @ S @ J[ix], 0.0)) for J, S in pairs])
        yerr = np.array([math.sqrt(max(J[iy] @ S @ J[iy], 0.0)) for J, S in pairs])
        g = [J[iy] - slope * J[ix] for J in Js]
        rse = np.array([math.sqrt(max(gi @ S @ gi, 0.0)) for gi, S in zip(g, covs, strict=True)])
        res = y[j] - (slope * x[j] + intercept)
        out.append(Line(x[j], y[j], xerr, yerr, float(slope), float(intercept), res, rse,
                        label))
    return out[0], out[1]


def forced_line_points(result: Any) -> tuple[Line, Line]:
    """The eq. (20) lines of a forced identification as :func:`forced_lines_figure` draws them.

    Parameters
    ----------
    result : phoid.methods.forced.ForcedIdentification or alike
        Read: ``runs`` (each with ``used``, ``omega`` and ``omega_stderr`` (rad/s), ``Z``
        (R e^{iρ}, N/m) and ``Z_cov`` (the (2, 2) covariance of its real and imaginary parts,
        (N/m)²)) and ``m``, ``c``, ``k`` (each with ``value``).

    Returns
    -------
    (Line, Line)
        x = ω², y = R cos ρ on the line k − mω²; x = ω, y = R sin ρ on the line cω.

    Notes
    -----
    The y error bars are the square roots of ``Z_cov``'s diagonal; the x error bars propagate
    ω's stderr (2ω·se(ω) for ω²). The residual's standard error adds the two in quadrature,
    √(se(y)² + (slope·se(x))²), treating ω's error as independent of Z's.
    """
    used = [r for r in result.runs if r.used]
    w = np.array([r.omega for r in used], dtype=float)
    sw = np.array([getattr(r, "omega_stderr", 0.0) for r in used], dtype=float)
    sw = np.where(np.isfinite(sw), sw, 0.0)
    Z = np.array([r.Z for r in used], dtype=complex)
    se = np.array([np.sqrt(np.clip(np.diag(r.Z_cov), 0, None)) for r in used]).reshape(-1, 2)
    m, c, k = result.m.value, result.c.value, result.k.value
    out = []
    for x, xerr, y, yerr, slope, intercept, label in (
        (w**2, 2 * w * sw, Z.real, se[:, 0], -m, k,
         f"k − mω²: m = {m:.5g} kg, k = {k:.5g} N/m"),
        (w, sw, Z.imag, se[:, 1], c, 0.0, f"cω: c = {c:.5g} N s/m"),
    ):
        res = y - (slope * x + intercept)
        rse = np.sqrt(yerr**2 + (slope * xerr) ** 2)
        out.append(Line(x, y, xerr, yerr, float(slope), float(intercept), res, rse, label))
    return out[0], out[1]


def _draw_lines(fig: Figure, lines: tuple[Line, Line], xlabels: tuple[str, str],
                ylabels: tuple[str, str]) -> None:
    """Two columns: each line with its error-barred points above, its residuals in stderr
    units below."""
    axes = fig.subplots(2, 2, sharex="col", height_ratios=[3, 1.3])
    fs = LINES_FONT
    for j, ln in enumerate(lines):
        a, ar = axes[0, j], axes[1, j]
        span = float(np.ptp(ln.y)) if ln.y.size > 1 else 0.0
        tiny = span > 0 and float(np.nanmax(ln.yerr, initial=0.0)) < 0.01 * span
        a.errorbar(ln.x, ln.y, xerr=ln.xerr, yerr=ln.yerr, fmt="o", ms=4, capsize=3,
                   elinewidth=1, color="C0",
                   label="runs (±1 stderr" + (", bars within the markers)" if tiny else ")"))
        hi = float(np.max(ln.x)) if ln.x.size else 1.0
        xx = np.linspace(min(0.0, float(np.min(ln.x, initial=0.0))), hi * 1.05, 50)
        a.plot(xx, ln.slope * xx + ln.intercept, "-", color="C1", lw=1,
               label=ln.label.replace(": ", "\n", 1))  # the equation, then the values
        a.set_ylabel(ylabels[j], fontsize=fs)
        a.tick_params(labelsize=fs - 1)
        a.legend(fontsize=fs - 2, loc="best")
        a.grid(alpha=0.3)
        z = ln.normalised
        ar.axhspan(-2, 2, color="0.85", lw=0, label="±2")
        ar.axhline(0, color="C1", lw=1)
        ar.errorbar(ln.x, z, yerr=np.where(np.isfinite(z), 1.0, np.nan), fmt="o", ms=4,
                    capsize=3, elinewidth=1, color="C0")
        ar.set_ylabel("residual (stderr)", fontsize=fs)
        ar.set_xlabel(xlabels[j], fontsize=fs)
        ar.tick_params(labelsize=fs - 1)
        ar.grid(alpha=0.3)


def pho_lines_figure(ident: Any) -> Figure:
    """The two lines of eq. (35) with error bars and residuals in stderr units.

    Left: c′ᵢ against 2σᵢ; right: k′ᵢ against ω₀ᵢ²; below each, (yᵢ − line(xᵢ))/stderr with
    ±1 bars and a ±2 band. What is drawn and how the errors are propagated:
    :func:`pho_line_points` (its attributes read from ``ident``, and ``digital``). Error bars
    in the upper panels are to scale (often smaller than the markers); the residual panels
    show them. For a sampled loop (``ident.digital`` set) the points are eq. (32) at the
    equivalent continuous delay (d + ½)T_s while m, c, k come from the sampled loop's exact
    roots, so the residuals hold that approximation's error too (the title says so).
    """
    from matplotlib.figure import Figure

    lines = pho_line_points(ident)
    fig = Figure(figsize=LINES_SIZE, layout="constrained")
    _draw_lines(fig, lines, (r"$2\sigma_i$ (1/s)",
                             r"$\omega_{0i}^2 = \sigma_i^2 + \omega_{di}^2$ (rad²/s²)"),
                (r"$c'_i$ (N s/m)", r"$k'_i$ (N/m)"))
    fit = ident.fit
    how = ("OLS per line" if getattr(fit, "estimator", "") == "ols"
           else "joint weighted fit")
    comp = "" if getattr(fit, "compensated", True) else ", delay not compensated"
    fig.suptitle(f"eq. (35) lines ({how}{comp}); bars ±1 stderr from each run's "
                 r"$\sigma$, $\omega_d$", fontsize=LINES_FONT + 1)
    if getattr(ident, "digital", None) is not None:
        fig.text(0.5, 0.0, f"sampled loop: points through eq. (32) at the equivalent delay "
                 f"{_used_delay(ident):.4g} s (the residuals include that approximation); "
                 "m, c, k from the loop's exact roots", ha="center", va="bottom",
                 fontsize=LINES_FONT - 3)
    return fig


def forced_lines_figure(result: Any) -> Figure:
    """The two lines of eq. (20) with error bars and residuals in stderr units.

    Left: R cos ρ against ω² (line k − mω²); right: R sin ρ against ω (line cω); below each,
    (yᵢ − line(xᵢ))/stderr with ±1 bars and a ±2 band (:func:`forced_line_points`).
    """
    from matplotlib.figure import Figure

    lines = forced_line_points(result)
    fig = Figure(figsize=LINES_SIZE, layout="constrained")
    _draw_lines(fig, lines, ("ω² (rad²/s²)", "ω (rad/s)"), ("R cos ρ (N/m)", "R sin ρ (N/m)"))
    fig.suptitle("eq. (20) lines; bars ±1 stderr of each run's response",
                 fontsize=LINES_FONT + 1)
    return fig


def mk_covariance(result: Any) -> np.ndarray:
    """The (2, 2) covariance of (m, k) a result's confidence region is drawn from.

    ``result.cov``'s (m, k) block (m, c, k first, in that order: a PHO, forced or friction
    result). For the paper's line route (``result.fit.estimator == "ols"``) m and k are the
    slope and the negated intercept of one OLS line, whose covariance the block-diagonal
    ``cov`` leaves out; it is put back from that line: cov(m, k) = x̄·var(m), x̄ the mean
    abscissa ω₀ᵢ² (for y = a·x + b by OLS, cov(a, b) = −x̄·var(a)).
    """
    cov = np.asarray(result.cov, dtype=float)
    out = cov[np.ix_([0, 2], [0, 2])].copy()
    fit = getattr(result, "fit", None)
    if getattr(fit, "estimator", None) == "ols" and getattr(fit, "k_line", None) is not None:
        kl = fit.k_line
        out[0, 1] = out[1, 0] = float(np.mean(kl.x)) * kl.slope_stderr**2
    return out


def mk_ellipse_figure(result: Any) -> Figure:
    """The joint confidence region of (m, k): the point estimate and two ellipses.

    The ellipses are {θ : (θ − θ̂)ᵀ C⁻¹ (θ − θ̂) = Δχ²} for Δχ² = 1 and 4
    (:data:`ELLIPSE_LEVELS`), C the (m, k) covariance of :func:`mk_covariance`: the "1σ" and
    "2σ" contours, whose shadows on each axis are ±1 and ±2 stderr, holding the true (m, k)
    with probability 39.3 % and 86.5 % under a Gaussian approximation. The ±1 stderr bars of
    m and k are drawn through the estimate.

    Parameters
    ----------
    result : a result with ``m``, ``k`` (each with ``value`` and ``stderr``: kg, N/m) and
        ``cov`` (see :func:`mk_covariance`).
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Ellipse

    m, k = float(result.m.value), float(result.k.value)
    C = mk_covariance(result)
    fig = Figure(figsize=(6.4, 5.2), layout="constrained")
    ax = fig.subplots()
    ok = np.all(np.isfinite(C)) and C[0, 0] > 0 and C[1, 1] > 0
    if ok:
        vals, vecs = np.linalg.eigh(C)
        vals = np.clip(vals, 0.0, None)
        angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
        for q, style, pct in zip(ELLIPSE_LEVELS, ("-", "--"), ("39.3", "86.5"), strict=True):
            ax.add_patch(Ellipse((m, k), 2 * math.sqrt(q * vals[1]), 2 * math.sqrt(q * vals[0]),
                                 angle=angle, fill=False, ls=style, color="C0", lw=1.2,
                                 label=f"Δχ² = {q:g} ({pct} % joint; ±{math.sqrt(q):g} "
                                       "stderr on each axis)"))
        sm, sk = math.sqrt(C[0, 0]), math.sqrt(C[1, 1])
        ax.errorbar([m], [k], xerr=[sm], yerr=[sk], fmt="o", color="C1", ms=4, capsize=3,
                    label=f"m = {format_estimate(m, sm)} kg, k = {format_estimate(k, sk)} N/m")
        rho = C[0, 1] / (sm * sk)
        ax.set_xlim(m - 2.6 * sm, m + 2.6 * sm)
        ax.set_ylim(k - 2.6 * sk, k + 2.6 * sk)
        ax.set_title(f"(m, k) confidence region, correlation {rho:.3f}")
    else:
        ax.plot([m], [k], "o", color="C1", label=f"m = {m:.5g} kg, k = {k:.5g} N/m")
        ax.set_title("(m, k): no finite covariance, no confidence region")
    ax.ticklabel_format(useOffset=False)
    ax.set_xlabel("m (kg)")
    ax.set_ylabel("k (N/m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    return fig
