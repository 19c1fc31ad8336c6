r"""The adequacy of a PHO identification (:mod:`phoid.methods.identification`): the checks of
:mod:`phoid.methods.adequacy` applied to each run's dominant-mode fit and to the runs'
agreement, and the covariance of m, c, k that survives a misfit.

Per run (its decay fit :class:`phoid.fits.DecayFit` over the fitted window, fast loop modes
included):

- ``noise``: the residual against the record's own noise level (third differences over the
  window, :func:`phoid.methods.fit_statistics.window_noise`);
- ``whiteness``: the Ljung–Box test of the residual;
- ``structure``: windows of 4 damped cycles of each run's ring after its fast modes have died
  out (below one noise sd), fitted alone (:func:`phoid.methods._modal.window_rates`), their σ
  and ω_d against their amplitude — a Coulomb-friction rig's rate rises as the amplitude falls;
  not applicable where the rings are too short for 4 windows.

Between runs: ``runs`` — the weighted fit's χ² of the runs' modes (the test the weighted fit
already makes, :func:`phoid.methods.pho.fit_modes`, here with each run's robust covariance when
a residual check failed, since a coloured residual makes the white covariances too small and
the runs then seem to disagree); for the OLS lines ``lines`` — the eq. (35) points against
their measurement error (:func:`phoid.methods.pho_lines_check.check_lines`; its warning is
:func:`phoid.methods.identification`'s, which names the delay left out).

Uncertainty. Each run's robust covariance Ωᵢ of (σᵢ, ω_dᵢ) is the Newey–West sandwich of its
decay fit (:func:`phoid.methods.adequacy.sandwich`: the columns ∂x/∂σ and ∂x/∂ω_d of the
dominant mode, the offset, the mode's two amplitudes and the fast modes' amplitudes projected
off), never below the white one. The weighted fit's estimate θ̂ = argmin Σ rᵢᵀCᵢ⁻¹rᵢ is kept
(where the model is right it is the efficient one) and its covariance becomes the sandwich

    (JᵀWJ)⁻¹ JᵀWΩWJ (JᵀWJ)⁻¹,   W = diag(Cᵢ⁻¹), Ω = diag(Ωᵢ),

Jᵢ = ∂(σᵢ, ω_dᵢ)/∂θ from the exact loop root (implicit differentiation, as the fit's own
Jacobian). Where the runs still disagree under Ωᵢ, it is scaled by their χ²/dof, as the fit
does with the white ones. For a sampled loop and for a delay estimated with the recorded force
(other residuals in the fit) the bound λ²(JᵀWJ)⁻¹ is used instead, λ² the largest generalised
eigenvalue of (Ωᵢ, Cᵢ) over the runs (Ωᵢ ≼ λ²Cᵢ for all i gives JᵀWΩWJ ≼ λ²JᵀWJ). The OLS
lines keep their stderr: it comes from the points' scatter about the lines, which already holds
each run's error, coloured or not. Where every check passes, the reported covariance is the
fit's own, unchanged. docs/adequacy.md ("pho") gives the reasons.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from phoid.dynamics import characteristic, dominant_roots
from phoid.errors import IdentificationError
from phoid.methods import adequacy as aq
from phoid.methods._modal import Segment, window_rates
from phoid.methods.chi2 import chi2_isf, chi2_sf
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import window_noise
from phoid.methods.pho_lines_check import check_lines

__all__ = ["RUNS_DISAGREE", "apply_pho", "assess_pho", "run_sandwich"]

#: the start of the weighted fit's own runs-disagree warning (phoid.methods.pho.fit_modes),
#: replaced by the ``runs`` check's
RUNS_DISAGREE = "the runs disagree more than their noise explains"
#: fewest windows of 4 cycles a run needs to count in the structure check
_MIN_WINDOWS = 3
#: cycles per window (window_rates' default): a run ringing fewer than _WINDOW_CYCLES ×
#: _MIN_WINDOWS cycles above its noise sd cannot give that many windows above 10 noise sd,
#: so its window fits are not tried
_WINDOW_CYCLES = 4.0
#: a record whose noise is below this fraction of its motion's RMS is noise-free (rounding)
_ROUNDING = 1e-9
#: false alarm of the runs' χ² test (the weighted fit's own 99.9 % quantile)
_ALPHA = 1e-3


def _window(t: np.ndarray, fit: Any) -> np.ndarray:
    return (t >= fit.t_start) & (t <= fit.t_end)


def run_sandwich(t: np.ndarray, x: np.ndarray, fit: Any, *, cov: bool = True
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """One run's decay-fit residual over its window and the Newey–West covariance of (σ, ω_d).

    Parameters
    ----------
    t, x : ndarray
        The run's record (s, x's unit).
    fit : phoid.fits.DecayFit
        Its dominant-mode fit (fast modes included).
    cov : bool, default True
        Compute the sandwich (False: the residual alone, the covariance None — the checks
        need only the residual, and the sandwich is used only where one fails).

    Returns
    -------
    (residual, cov)
        The residual x − model over the window; the (2, 2) sandwich of (σ, ω_d), with the
        offset, the dominant mode's amplitudes and the fast modes' amplitudes projected off
        (nan when it cannot be computed; None with ``cov=False``).
    """
    sel = _window(t, fit)
    tw, xw = t[sel], x[sel]
    e = xw - fit.model(tw, fast=True)
    if not cov:
        return e, None
    tau = tw - fit.t_ref
    with np.errstate(over="ignore", invalid="ignore"):
        env = np.exp(-fit.sigma * tau)
        dom = fit.amplitude * env * np.sin(fit.omega_d * tau - fit.phase)
        d_omega = tau * fit.amplitude * env * np.cos(fit.omega_d * tau - fit.phase)
        cols = [np.ones_like(tw), env * np.sin(fit.omega_d * tau), env * np.cos(fit.omega_d * tau)]
        after = np.maximum(tau, 0.0)
        for r, _a in fit.fast_modes:
            z = np.where(tau >= 0, np.exp(r * after), 0.0)
            cols += [z.real, z.imag]
    J = np.column_stack([-tau * dom, d_omega])
    G = np.column_stack(cols)
    G = G[:, np.any(G != 0, axis=0)]
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(G)) and e.size > J.shape[1] + G.shape[1]):
        return e, np.full((2, 2), math.nan)
    return e, aq.sandwich([J], [e], nuisance=[G])


def _windows(t: np.ndarray, x: np.ndarray, fit: Any, noise: float) -> tuple[np.ndarray, ...]:
    """The run's local rates over windows of 4 damped cycles, after its fast modes are below
    one noise sd (:func:`phoid.methods._modal.window_rates`)."""
    sel = _window(t, fit)
    tw, xw = t[sel], x[sel]
    dom = fit.model(tw) - fit.offset
    fast = fit.model(tw, fast=True) - fit.offset - dom
    loud = np.flatnonzero(np.abs(fast) > noise)
    a = int(loud[-1]) + 1 if loud.size else 0
    seg = Segment(t=tw[a:], x=xw[a:], fixed=np.ones((tw.size - a, 1)), t0=float(tw[a])
                  if a < tw.size else 0.0)
    if tw.size - a < 48:
        return tuple(np.empty(0) for _ in range(5))
    return window_rates(seg, dom[a:], fit.sigma, fit.sigma**2 + fit.omega_d**2, noise,
                        max_windows=12)


def _stuck(t: np.ndarray, x: np.ndarray, fit: Any, noise: float, x_unit: str) -> str:
    """Where a run ends at rest away from its fitted rest, in words ("" if not): the last
    tenth of its record after the release (≥ 16 samples) within 8 noise sd, while the fitted
    mode there still swings above 10 noise sd or the record rests more than 5 noise sd off the
    fitted offset (a viscous ring ends at its offset; a Coulomb one stops anywhere within
    ±f_c/k of it)."""
    after = t >= fit.release
    ta, xa = t[after], x[after]
    k = max(16, ta.size // 10)
    if not (noise > 0 and math.isfinite(noise)) or ta.size < 4 * k:
        return ""
    tail = xa[-k:]
    if not float(np.ptp(tail)) <= 8 * noise:
        return ""
    motion = fit.model(ta[-k:]) - fit.offset
    amp = math.sqrt(2.0 * float(np.mean(motion * motion)))
    off = float(np.mean(tail)) - fit.offset
    if amp > 10 * noise or abs(off) > 5 * noise:
        return (f"still over its last {ta[-1] - ta[-k]:.3g} s, {off:.3g} {x_unit} off the "
                f"fitted rest ({abs(off) / noise:.3g} noise sd)")
    return ""


def _loop_jacobian(res: Any, idx: list[int]) -> np.ndarray | None:
    """Per used run, ∂(σᵢ, ω_dᵢ)/∂θ at the solution, θ = (m, c, k[, Δt]) (n, 2, p); None for a
    sampled loop or where the loop's roots cannot be evaluated."""
    if res.digital is not None:
        return None
    fit = res.fit
    m, c, k = fit.m, fit.c, fit.k
    tau = float(res.delay)
    P = np.array([res.runs[i].P for i in idx])
    D = np.array([res.runs[i].D for i in idx])
    dm = np.array([res.runs[i].added_mass for i in idx])
    guess = np.array([complex(-res.runs[i].sigma, res.runs[i].omega_d) for i in idx])
    try:
        with np.errstate(all="ignore"):
            s = dominant_roots(m + dm, c, k, P, D, tau, guess)
            _f, df = characteristic(s, m + dm, c, k, P, D, tau)
            cols = [s**2, s, np.ones_like(s)]
            if fit.cov_full is not None:
                cols.append(-s * (D * s + P) * np.exp(-s * tau))
            ds = -np.stack(cols, axis=1) / df[:, None]
    except (ValueError, RuntimeError, ArithmeticError, IdentificationError):
        return None
    jac = np.stack([-ds.real, ds.imag], axis=1)
    return jac if np.all(np.isfinite(jac)) else None


def _inv(a: np.ndarray) -> np.ndarray:
    return np.linalg.inv(a)


def assess_pho(res: Any, *, x_unit: str = "m") -> tuple[aq.Adequacy, np.ndarray | None]:
    """The adequacy of a PHO identification (module docstring).

    Parameters
    ----------
    res : phoid.methods.pho_result.Identification
        The identification (its runs' decay fits, records and the set's fit).
    x_unit : str
        x's unit, for the words.

    Returns
    -------
    (Adequacy, robust_full)
        The checks, warnings and covariances of (m, c, k); ``robust_full``: the robust (4, 4)
        covariance of (m, c, k, Δt) when the delay was estimated with them (None otherwise or
        where the fit's own stands).
    """
    fit = res.fit
    idx = [i for i, r in enumerate(res.runs)
           if r.used and r.fit is not None and i < len(res.data)]
    resid: list[np.ndarray] = []
    noise: list[float] = []
    rms: list[float] = []
    omegas: list[np.ndarray] = []
    win_cols: list[list[np.ndarray]] = [[], [], [], [], []]
    checked: list[int] = []
    for i in idx:
        t = np.asarray(res.data[i][0], dtype=float)
        x = np.asarray(res.data[i][1], dtype=float)
        f = res.runs[i].fit
        e, _ = run_sandwich(t, x, f, cov=False)
        resid.append(e)
        omegas.append(None)
        nz = window_noise(t, x, f.t_start, f.t_end)
        sel = _window(t, f)
        motion = x[sel] - e - f.offset  # the fitted model less its offset (e = x − model)
        mrms = float(np.sqrt(np.mean(motion * motion))) if motion.size else 0.0
        erms = float(np.sqrt(np.mean(e * e))) if e.size else 0.0
        if not nz > _ROUNDING * mrms or (erms <= 1e-5 * mrms and erms < 0.5 * nz):
            # a noise-free record: its noise at the motion's rounding, or its residual far
            # below both the motion (10⁻⁵) and the record's noise estimate (which then reads
            # the motion's own third differences): numerical error, nothing to test
            resid.pop()
            omegas.pop()
            continue
        noise.append(nz)
        rms.append(mrms)
        checked.append(i)
    all_idx, idx = idx, checked
    labels = [res.runs[i].file for i in idx]
    noise_c = aq.noise_check(resid, noise, labels, x_unit=x_unit)
    white = aq.whiteness_check(resid, motion_rms=rms)
    if white.passed is None and noise_c.passed is False:
        # noise-free records (every residual at rounding level): the residual has no noise
        # to be measured against
        noise_c = aq.Check("noise", noise_c.statistic, noise_c.threshold, None,
                           "not tested (noise-free records: the residual is rounding)")
    checks = [noise_c, white]
    exact = white.passed is None
    causes: list[str] = []
    warns: list[str] = []
    if not exact:
        for i, nz in zip(idx, noise, strict=True):
            if not (nz > 0 and math.isfinite(nz)):
                continue
            t = np.asarray(res.data[i][0], dtype=float)
            x = np.asarray(res.data[i][1], dtype=float)
            f = res.runs[i].fit
            if not f.cycles >= _WINDOW_CYCLES * _MIN_WINDOWS:
                continue  # too short a ring for that many windows: no window fits tried
            a, sg, sg_se, om_d, om_se = _windows(t, x, f, nz)
            if a.size < _MIN_WINDOWS:  # too short a ring to show a trend of its own
                continue
            # each run rings at its own rates (its own gains): its windows are taken about
            # them, so that only a trend within the runs counts, not the runs' differences
            for j, col in enumerate((a, sg - f.sigma, sg_se, om_d - f.omega_d, om_se)):
                win_cols[j].append(col)
        ref_s = float(np.mean([res.runs[i].sigma for i in idx])) if idx else 0.0
        ref_w = float(np.mean([res.runs[i].omega_d for i in idx])) if idx else 0.0
        win = (aq.Windows(np.concatenate(win_cols[0]), np.concatenate(win_cols[1]) + ref_s,
                          np.concatenate(win_cols[2]), np.concatenate(win_cols[3]) + ref_w,
                          np.concatenate(win_cols[4]))
               if win_cols[0] else None)
        struct, s_causes, s_warns = aq.structure_check(win, x_unit=x_unit)
        checks.append(struct)
        stuck = [(res.runs[i].file, w) for i, nz in zip(idx, noise, strict=True)
                 if (w := _stuck(np.asarray(res.data[i][0], dtype=float),
                                 np.asarray(res.data[i][1], dtype=float), res.runs[i].fit, nz,
                                 x_unit))]
        if stuck and "coulomb" not in s_causes:
            s_causes = (*s_causes, "coulomb")
            s_warns = (*s_warns, f"{len(stuck)} of {len(idx)} runs end stuck ({stuck[0][0]}: "
                       f"{stuck[0][1]}): Coulomb friction (linear amplitude loss, sticking), "
                       "not viscous damping; try `phoid identify SET --friction`")
        peak = None
        if (noise_c.passed is False or white.passed is False) and not s_causes and idx:
            # the band every run's ring sweeps (their own ω_d differ with the gains)
            fds = [res.runs[i].omega_d / (2 * math.pi) for i in idx]
            for i, e in zip(idx, resid, strict=True):
                t = np.asarray(res.data[i][0], dtype=float)
                dt = float(np.median(np.diff(t)))
                peak = aq.spectral_peak(e, dt, (min(fds), max(fds)))
                if peak is not None:
                    break
        r_causes, r_warns = aq.residual_warnings(noise_c, white, s_causes, peak)
        causes += list(r_causes) + list(s_causes)
        warns += list(r_warns) + list(s_warns)
    residual_failed = any(c.passed is False for c in checks)
    if residual_failed:
        # the runs' sandwiches, only where a check failed (where none did the white
        # covariances stand, and the sandwich would cost more than the rest together)
        omegas = [run_sandwich(np.asarray(res.data[i][0], dtype=float),
                               np.asarray(res.data[i][1], dtype=float), res.runs[i].fit)[1]
                  for i in idx]
    om_of = dict(zip(idx, omegas, strict=True))
    idx = all_idx  # every used run enters the set's fit (a noise-free one with its own cov)
    white_run = [np.asarray(res.runs[i].fit.cov, dtype=float) for i in idx]
    robust_run = []
    for i, cw in zip(idx, white_run, strict=True):
        om = om_of.get(i)
        ok = residual_failed and om is not None and np.all(np.isfinite(om))
        robust_run.append(aq.not_below_white(om, cw) if ok else cw)
    names, units = ("m", "c", "k"), ("kg", "N s/m", "N/m")
    own = np.asarray(fit.cov, dtype=float)
    if fit.estimator != "gls":
        return _ols(res, idx, checks, causes, warns, robust_run, residual_failed), None
    # the weighted fit: the runs' χ² with the covariances the runs are trusted to
    sig = np.array([res.runs[i].sigma for i in idx])
    wd = np.array([res.runs[i].omega_d for i in idx])
    floor = (1e-9 * np.hypot(sig, wd)) ** 2
    Cw = np.array(white_run) + floor[:, None, None] * np.eye(2)
    Cr = np.array(robust_run) + floor[:, None, None] * np.eye(2)
    dof = int(fit.dof)
    red_white = fit.chi2 / dof if dof > 0 else math.nan
    scaled = dof > 0 and fit.chi2 > chi2_isf(_ALPHA, dof)
    jac = _loop_jacobian(res, idx) if res.delay_from != "x+u" else None
    full = fit.cov_full is not None
    own_full = np.asarray(fit.cov_full if full else own, dtype=float)
    white_full = own_full / red_white if scaled else own_full
    p = white_full.shape[0]
    chi2 = float(fit.chi2)
    if residual_failed and jac is not None and jac.shape[2] == p:
        sj = _model_modes(res, idx)  # the residuals from the loop's roots at the solution
        if sj is not None:
            r = np.c_[sig, wd] - sj
            chi2 = float(np.einsum("ni,nij,nj->", r, np.linalg.inv(Cr), r))
        Wi = np.linalg.inv(Cw)
        A = np.einsum("nji,njk,nkl->il", jac, Wi, jac)
        B = np.einsum("nji,njk,nkl,nlm,nmo->io", jac, Wi, Cr, Wi, jac)
        Ai = _inv(A)
        sand_full = Ai @ B @ Ai
    elif residual_failed:
        lam = max(float(np.max(np.linalg.eigvals(np.linalg.solve(cw, cr)).real))
                  for cw, cr in zip(Cw, Cr, strict=True)) if idx else 1.0
        sand_full = max(lam, 1.0) * white_full
        chi2 = float(fit.chi2) / max(lam, 1.0)
    else:
        sand_full = white_full
    runs_pass = not (dof > 0 and chi2 > chi2_isf(_ALPHA, dof))
    if dof > 0:
        pv = chi2_sf(chi2, float(dof))
        how = "each run's robust covariance" if residual_failed else "each run's decay fit"
        runs_c = aq.Check("runs", chi2, chi2_isf(_ALPHA, dof), runs_pass,
                          f"χ² of the runs' modes about the fitted loop = {chi2:.4g} on {dof} "
                          f"dof (χ²/dof {chi2 / dof:.3g}, p = {pv:.2g}), weighted by {how}")
        checks.append(runs_c)
        if not runs_pass:
            causes.append("runs_differ")
            warns.append(f"{RUNS_DISAGREE} (χ²/dof = {chi2 / dof:.2f}); stderr scaled up "
                         "accordingly: check the delay, friction or unmodelled dynamics")
    else:
        checks.append(aq.Check("runs", math.nan, math.nan, None,
                               "no degrees of freedom left (as many parameters as numbers)"))
    failed = any(c.passed is False for c in checks)
    if not failed:
        robust_full = white_full
    elif not residual_failed:
        robust_full = own_full  # the runs alone disagree: the fit's own χ²/dof scaling
    else:
        robust_full = aq.not_below_white(sand_full, white_full)
        if not runs_pass:
            robust_full = robust_full * (chi2 / dof)
    white3, sand3, rob3 = white_full[:3, :3], sand_full[:3, :3], robust_full[:3, :3]
    ad = aq.assess(checks, names=names, units=units, white_cov=white3, sandwich_cov=sand3,
                   causes=causes, warnings=warns)
    ad = replace(ad, robust_cov=0.5 * (rob3 + rob3.T))
    return ad, (robust_full if full and failed else None)


def _model_modes(res: Any, idx: list[int]) -> np.ndarray | None:
    """(σᵢ, ω_dᵢ) of the fitted loop's dominant roots (continuous loops), (n, 2)."""
    fit = res.fit
    P = np.array([res.runs[i].P for i in idx])
    D = np.array([res.runs[i].D for i in idx])
    dm = np.array([res.runs[i].added_mass for i in idx])
    guess = np.array([complex(-res.runs[i].sigma, res.runs[i].omega_d) for i in idx])
    try:
        with np.errstate(all="ignore"):
            s = dominant_roots(fit.m + dm, fit.c, fit.k, P, D, float(res.delay), guess)
    except (ValueError, RuntimeError, ArithmeticError, IdentificationError):
        return None
    out = np.c_[-s.real, s.imag]
    return out if np.all(np.isfinite(out)) else None


def _ols(res: Any, idx: list[int], checks: list[aq.Check], causes: list[str],
         warns: list[str], robust_run: list[np.ndarray], residual_failed: bool) -> aq.Adequacy:
    """The OLS lines' adequacy: the ``lines`` check with the runs' (robust) covariances; the
    lines' own stderr stand (from the points' scatter)."""
    fit = res.fit
    own = np.asarray(fit.cov, dtype=float)
    if res.digital is None and fit.c_line is not None and len(idx) >= 3:
        sig = np.array([res.runs[i].sigma for i in idx])
        wd = np.array([res.runs[i].omega_d for i in idx])
        P = np.array([res.runs[i].P for i in idx])
        D = np.array([res.runs[i].D for i in idx])
        dm = np.array([res.runs[i].added_mass for i in idx])
        chk = check_lines(sig, wd, np.array(robust_run), P, D, float(res.delay),
                          compensate=fit.compensated, added_mass=dm, m_c=fit.c_line.slope,
                          m=fit.m, c=fit.c, k=fit.k)
        if chk is not None:
            lim = chi2_isf(_ALPHA, chk.dof)
            how = "robust" if residual_failed else "decay-fit"
            checks.append(aq.Check(
                "lines", max(chk.chi2_c, chk.chi2_k), lim, not chk.misfit,
                f"the eq. (35) points about their lines, against each run's {how} covariance: "
                f"χ² {chk.chi2_c:.4g} (damping line) and {chk.chi2_k:.4g} (stiffness line) on "
                f"{chk.dof} dof"))
    ad = aq.assess(checks, names=("m", "c", "k"), units=("kg", "N s/m", "N/m"),
                   white_cov=own, sandwich_cov=own, causes=causes, warnings=warns)
    note = ""
    if not ad.passed:
        # the lines' stderr come from the points' scatter about them: already as wide as that
        # scatter, whatever each run's error and its colour (docs/adequacy.md), so they are not
        # widened; a failed lines check is a bias, which no stderr shows
        note = ("the OLS lines' own, from the points' scatter about them (which holds each "
                "run's error whatever its colour)")
        if any(c.name == "lines" and c.passed is False for c in ad.checks):
            note += "; the lines check says m, c, k are biased, which no stderr shows"
    return replace(ad, robust_cov=own.copy(), stderr="white", stderr_note=note)


def apply_pho(res: Any) -> Any:
    """``res`` with its adequacy (:func:`assess_pho`): the robust covariance in m, c, k, the
    fit and the delay's stderr where a check failed (the white-noise stderr kept in
    ``white_stderr``), the runs-disagree warning of the weighted fit replaced by the ``runs``
    check's, and the adequacy warnings added."""
    ad, full = assess_pho(res)
    robust = ad.stderr == "robust"
    warnings = [w for w in res.warnings if not w.startswith(RUNS_DISAGREE)]
    warnings += [w for w in ad.warnings if w not in warnings]
    if not robust:
        # only the white fit's warning may have been dropped: where the runs check passed the
        # fit did not scale either (same χ², same quantile)
        return replace(res, adequacy=ad, warnings=tuple(warnings))
    rob = ad.robust_cov
    wse = np.sqrt(np.clip(np.diag(ad.white_cov), 0.0, None))
    se = np.sqrt(np.clip(np.diag(rob), 0.0, None))

    def est(e: Estimate, j: int) -> Estimate:
        return Estimate(e.value, float(se[j]), e.unit, white_stderr=float(wse[j]))

    fit = replace(res.fit, cov=rob, cov_full=full if full is not None else res.fit.cov_full)
    extra: dict[str, Any] = {}
    if full is not None and res.delay_stderr is not None:
        extra["delay_stderr"] = float(math.sqrt(max(full[3, 3], 0.0)))
    return replace(res, m=est(res.m, 0), c=est(res.c, 1), k=est(res.k, 2), fit=fit,
                   adequacy=ad, warnings=tuple(warnings), **extra)
