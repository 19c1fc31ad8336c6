"""Forced harmonic (sine-sweep) identification: records → R, ρ per run → m, c, k.

Per run (:func:`identify_forced_data`):

1. **Force.** ω, B, θ and the analysed window from F (:func:`phoid.methods.forced.force.fit_force`).
   A sine that leaves more than 5 % rms of its amplitude unexplained draws a warning. The
   manifest's ``B`` and ``omega`` are optional and only checked against F.
2. **Response, with the transient modelled.** Over the same window
   x = x_off + a cos ω(t − t_ref) + b sin ω(t − t_ref) + x₀[C(τ) + σS(τ)] + v₀S(τ), τ = t − t_start:
   the steady state plus the free response of eq. (2) left by the start (C, S of
   :func:`phoid.dynamics.plant.modal_basis`, any damping). The transient's rates (σ, ω₀²) are
   those of the plant, shared by all runs, and are fitted jointly by variable projection
   (:func:`phoid.methods._modal.fit_modal`) from a start given by a first pass on each run's
   second half. Skipping the transient instead would bias R by its leakage into the sine fit
   (docs/design-notes/classical.md); modelled, it costs nothing. The settling time (the last
   sample where the fitted transient exceeds the noise sd) is reported; a transient still above
   3 noise sd at the end of the record draws a warning.
3. **R, ρ** from the phasor ratio R e^{iρ} = F̂/x̂ (a signal a cos ωτ + b sin ωτ has the phasor
   a − ib), with the covariance of both fits (the transient rates' uncertainty included,
   correlated across runs through the shared rates).

Then m, c, k from all runs by generalised least squares on eq. (20)
(:func:`phoid.methods.forced.stiffness.fit_response`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from phoid import _validate as v
from phoid._threads import single_blas_thread
from phoid.errors import IdentificationError
from phoid.fits import diff_noise
from phoid.io.units import quantity_unit, unit_hint
from phoid.methods._modal import (
    Prep,
    Segment,
    State,
    esprit_rates,
    fit_modal,
    pick_start,
    release_basis,
)
from phoid.methods.estimate import Estimate
from phoid.methods.forced.adequacy import RUNS_DISAGREE, assess_forced, phasor_sandwich
from phoid.methods.forced.force import MIN_SAMPLES, Force, fit_force
from phoid.methods.forced.results import ForcedIdentification, ForcedRun
from phoid.methods.forced.stiffness import ResponseFit, distinct_count, fit_response

__all__ = ["identify_forced", "identify_forced_data"]

#: fewest forcing periods a run's analysed window must hold
MIN_PERIODS = 1.0
#: fewer periods than this draw a warning
FEW_PERIODS = 3.0
#: F is flagged when a sine leaves this fraction (rms, of the sine's rms) unexplained
F_WARN = 0.05
#: a record whose peak-to-peak motion is within this many noise sds never moved
_STILL_NSD = 12.0
#: below this transient energy (in noise sds, the largest over the runs) the transient's rates
#: are not fitted (they are not determined; the transient columns stay in the model)
_TRANSIENT_SNR = 20.0


def identify_forced(experiment: Any) -> ForcedIdentification:
    """Identify m, c, k from a forced (sine-sweep) experiment set (eqs. 16–22).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A set with ``method = "forced"``: each run one frequency, columns t, x and F.

    Returns
    -------
    ForcedIdentification

    Raises
    ------
    IdentificationError
        If the set is not forced, a run lacks F or F is not sinusoidal, a run carries
        feedback gains, or fewer than two distinct frequencies remain usable.
    """
    where = str(getattr(experiment, "path", ""))
    method = getattr(experiment, "method", "forced")
    if method != "forced":
        raise IdentificationError(f"{where}: method = {method!r} is not a forced set")
    runs = list(experiment.runs)
    if not runs:
        raise IdentificationError(f"{where}: no runs")
    for r in runs:
        if (r.P or 0.0) != 0.0 or (r.D or 0.0) != 0.0:
            raise IdentificationError(
                f"{where}: {r.name}: P = {r.P}, D = {r.D}: forced runs are taken to have no "
                "feedback loop")
    result = identify_forced_data(
        [(r.t, r.x, r.F) for r in runs],
        B=[r.B for r in runs], omega=[r.omega for r in runs],
        added_mass=[getattr(r, "added_mass", 0.0) for r in runs],
        files=[r.file for r in runs], names=[f"{where}: {r.name}" for r in runs],
        labels=[r.name for r in runs], source=where,
        x_unit=str(getattr(experiment, "x_unit", "m")),
    )
    if getattr(experiment, "loop", None):

        result = replace(result, warnings=(*result.warnings,
                                           "[loop] is ignored for a forced set"))
    return result


@single_blas_thread
def identify_forced_data(
    data: Sequence[tuple[Any, Any, Any]],
    *,
    B: Sequence[float | None] | None = None,
    omega: Sequence[float | None] | None = None,
    added_mass: Sequence[float] | None = None,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    labels: Sequence[str] | None = None,
    source: str = "",
    x_unit: str = "m",
) -> ForcedIdentification:
    """:func:`identify_forced` on plain arrays: ``data`` is a sequence of (t, x, F) per run.

    Parameters
    ----------
    data : sequence of (array_like, array_like, array_like or None)
        Each run's times (s), positions (m) and applied force (N).
    B, omega : sequence of float or None, optional
        Nominal force amplitude (N) and frequency (rad/s) per run, checked against F.
    added_mass : sequence of float, optional
        Known mass added in each run, kg.
    files : sequence of str, optional
        Run labels for the result (data-file names).
    names : sequence of str, optional
        Run names for error messages (e.g. ``"set/experiment.toml: run 3 (run03.csv)"``).
    labels : sequence of str, optional
        Short run names for warnings (default: ``files``).
    source : str
        Where the data came from, for the report.
    x_unit : str, default "m"
        What x is in (:attr:`phoid.io.ExperimentSet.x_unit`): ``"rad"`` words the warnings
        as a rotational set's (B and F torques in N m, x in rad; the unit a hint suggests
        for F a torque unit, :func:`phoid.io.units.unit_hint`).

    Returns
    -------
    ForcedIdentification

    Raises
    ------
    IdentificationError
        A run without F or with F not sinusoidal (the message names the run and column 'F'),
        or fewer than two distinct usable frequencies.
    ValueError
        Malformed arrays.
    """
    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    names = list(names) if names is not None else files
    labels = list(labels) if labels is not None else files
    Bn = list(B) if B is not None else [None] * n
    wn = list(omega) if omega is not None else [None] * n
    ma = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    arrays: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    forces: list[Force | None] = []
    reasons: list[str | None] = []
    run_warn: list[list[str]] = [[] for _ in range(n)]
    for i, item in enumerate(data):
        t, x, F = item
        if F is None:
            raise IdentificationError(
                f"{names[i]}: missing column 'F': a forced run needs the applied force F (N)")
        try:
            t = v.finite_array("t", t, ndim=1)
            x = v.finite_array("x", x, ndim=1)
            F = v.finite_array("F", F, ndim=1)
        except ValueError as exc:
            raise ValueError(f"{names[i]}: {exc}") from None
        if not (t.shape == x.shape == F.shape):
            raise ValueError(f"{names[i]}: columns 't', 'x' and 'F' must have the same length")
        if t.size >= 2 and not (np.diff(t) > 0).all():
            raise ValueError(f"{names[i]}: `t` must be strictly increasing")
        arrays.append((t, x, F))
        if t.size < MIN_SAMPLES:
            forces.append(None)
            reasons.append(f"too short: {t.size} samples (at least {MIN_SAMPLES} are needed)")
            continue
        f = fit_force(t, F, names[i])
        forces.append(f)
        nw = t.size - f.start
        periods = f.omega * float(t[-1] - t[f.start]) / (2 * math.pi)
        nsd = diff_noise(x[f.start:])
        ptp = float(np.ptp(x[f.start:]))
        if nw < MIN_SAMPLES or periods < MIN_PERIODS:
            reasons.append(f"too short: {nw} samples, {periods:.2g} forcing periods after the "
                           f"force's onset (at least {MIN_SAMPLES} samples and "
                           f"{MIN_PERIODS:g} period)")
        elif not ptp > _STILL_NSD * nsd or ptp == 0.0:
            xu = quantity_unit("m", x_unit)
            reasons.append(f"x never moves: its peak-to-peak {ptp:.3g} {xu} is within the "
                           f"noise (sd {nsd:.3g} {xu})")
        else:
            reasons.append(None)
        if f.distortion > F_WARN:
            run_warn[i].append(f"F deviates from a sinusoid by {f.distortion:.0%} rms "
                               "(harmonics or noise): only its fundamental is used")
        if periods < FEW_PERIODS and reasons[-1] is None:
            run_warn[i].append(f"only {periods:.1f} forcing periods in the record")
        if wn[i] is not None:
            se = math.sqrt(f.omega_var)
            if abs(f.omega - wn[i]) > max(5 * se, 1e-3 * wn[i]):
                hint = unit_hint("t", wn[i] / f.omega) if f.omega > 0 else ""
                run_warn[i].append(f"the manifest's omega = {wn[i]:g} rad/s differs from F's "
                                   f"frequency {f.omega:.6g} rad/s; F's is used"
                                   + (f"; {hint}" if hint else ""))
        if Bn[i] is not None:
            amp = math.hypot(f.coef[1], f.coef[2])
            if abs(amp - abs(Bn[i])) > 0.02 * abs(Bn[i]):
                hint = unit_hint("F", amp / abs(Bn[i]), x_unit) if Bn[i] else ""
                fu = quantity_unit("N", x_unit)
                run_warn[i].append(f"the manifest's B = {Bn[i]:g} {fu} differs from F's "
                                   f"amplitude {amp:.5g} {fu}; F's is used"
                                   + (f"; {hint}" if hint else ""))
    used = [i for i in range(n) if reasons[i] is None]
    prefix = f"{source}: " if source else ""
    if not used:
        raise IdentificationError(
            prefix + "no usable runs: "
            + "; ".join(f"{labels[i]}: {reasons[i]}" for i in range(n)))
    om = np.array([forces[i].omega for i in used])  # type: ignore[union-attr]
    if distinct_count(om) < 2:
        raise IdentificationError(
            f"{prefix}all usable runs are forced at one frequency ({float(om.mean()):.6g} "
            "rad/s): m, c and k are undetermined (eq. 20 needs at least two distinct "
            "frequencies)")

    segs: list[Segment] = []
    for i in used:
        t, x, _F = arrays[i]
        f = forces[i]
        assert f is not None
        tw = t[f.start:]
        tau = tw - f.t_ref
        fixed = np.column_stack([np.ones_like(tw), np.cos(f.omega * tau),
                                 np.sin(f.omega * tau)])
        segs.append(Segment(t=tw, x=x[f.start:], fixed=fixed, t0=float(tw[0])))
    noise0 = [max(diff_noise(s.x), 1e-13 * float(np.ptp(s.x))) for s in segs]
    rates, fit_rates = _transient_start(segs, [forces[i] for i in used], noise0,  # type: ignore
                                        ma[used])
    modal = fit_modal(segs, rates[0], rates[1], noise=noise0, fit_rates=fit_rates)
    warnings: list[str] = []
    if fit_rates and not modal.converged:
        warnings.append("the start-up transient's fit did not converge")

    # phasors, their covariance (correlated across runs through the shared rates)
    nu = len(used)
    cov_u = np.zeros((2 * nu, 2 * nu))
    for p in range(nu):
        Kp = modal.K[p][1:3]
        for q in range(nu):
            if p == q:
                cov_u[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = modal.coef_cov[p][1:3, 1:3]
            else:
                Kq = modal.K[q][1:3]
                cov_u[2 * p : 2 * p + 2, 2 * q : 2 * q + 2] = Kp @ modal.cov @ Kq.T
    Jx = np.zeros((2 * nu, 2 * nu))
    covF = np.zeros((2 * nu, 2 * nu))
    Z = np.empty(nu, dtype=complex)
    Px = np.empty(nu, dtype=complex)
    PF = np.empty(nu, dtype=complex)
    for p, i in enumerate(used):
        f = forces[i]
        assert f is not None
        c = modal.coef[p]
        Px[p] = complex(c[1], -c[2])
        PF[p] = complex(f.coef[1], -f.coef[2])
        Z[p] = PF[p] / Px[p]
        Jx[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = _phasor_jac(-Z[p] / Px[p])
        JF = _phasor_jac(1.0 / Px[p])
        covF[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] = JF @ f.cov_ab @ JF.T
    covZ = Jx @ cov_u @ Jx.T + covF
    omega_var = np.array([forces[i].omega_var for i in used])  # type: ignore[union-attr]
    resp = fit_response(om, Z, covZ, omega_var=omega_var, added_mass=ma[used])
    phasors = []
    for p, seg in enumerate(segs):
        basis = release_basis(seg.t - seg.t0, modal.sigma, modal.w0sq)
        phasors.append(phasor_sandwich(seg.t, seg.fixed, basis, modal.resid[p]))
    adequacy = assess_forced(
        x=[s.x for s in segs], resid=list(modal.resid),
        motion=[s.x - c[0] - r for s, c, r in zip(segs, modal.coef, modal.resid, strict=True)],
        phasor_robust=phasors, phasor_white=[modal.coef_cov[p][1:3, 1:3] for p in range(nu)],
        Jx=Jx, cov_u=cov_u, covF=covF, omega=om, Z=Z, omega_var=omega_var,
        added_mass=ma[used], fit=resp, labels=[labels[i] for i in used])
    warnings.extend(w for w in resp.warnings if not w.startswith(RUNS_DISAGREE))
    warnings.extend(_side_warnings(om, Z, resp))
    warnings.extend(adequacy.warnings)

    se = resp.stderr
    wse: np.ndarray | None = None
    if adequacy.stderr == "robust":
        se = np.sqrt(np.clip(np.diag(adequacy.robust_cov), 0.0, None))
        wse = np.sqrt(np.clip(np.diag(adequacy.white_cov), 0.0, None))
        resp = replace(resp, cov=adequacy.robust_cov)
    out_runs: list[ForcedRun] = []
    p_of = {i: p for p, i in enumerate(used)}
    for i in range(n):
        t, x, F = arrays[i]
        f = forces[i]
        if i not in p_of:
            warnings.append(f"{labels[i]}: set aside: {reasons[i]}")
            warnings.extend(f"{labels[i]}: {w}" for w in run_warn[i])
            out_runs.append(_unused_run(files[i], t, f, reasons[i], run_warn[i]))
            continue
        assert f is not None
        p = p_of[i]
        cz = covZ[2 * p : 2 * p + 2, 2 * p : 2 * p + 2]
        R = abs(Z[p])
        gR = np.array([Z[p].real, Z[p].imag]) / R
        grho = np.array([-Z[p].imag, Z[p].real]) / (R * R)
        cu = modal.coef_cov[p][1:3, 1:3]
        Cabs = abs(Px[p])
        gC = np.array([Px[p].real, -Px[p].imag]) / Cabs
        Babs = abs(PF[p])
        gB = np.array([PF[p].real, -PF[p].imag]) / Babs
        seg = segs[p]
        coef = modal.coef[p]
        b1, b2 = release_basis(seg.t - seg.t0, modal.sigma, modal.w0sq)
        tr = coef[3] * b1 + coef[4] * b2  # the fitted start-up transient
        nsd = modal.noise[p]
        above = np.flatnonzero(np.abs(tr) > nsd)
        settle = float(seg.t[min(above[-1] + 1, seg.t.size - 1)]) if above.size \
            else float(seg.t[0])
        period = 2 * math.pi / f.omega
        tail = np.abs(tr[seg.t >= seg.t[-1] - period])
        end_level = float(tail.max()) / nsd if tail.size else 0.0
        settled = end_level <= 3.0
        w_run = list(run_warn[i])
        if not settled:
            w_run.append(f"the start-up transient has not died out within the record (still "
                         f"{end_level:.3g} noise sd at the end): R and ρ rest on its model; "
                         "record longer")
        warnings.extend(f"{labels[i]}: {w}" for w in w_run)
        r = modal.resid[p]
        out_runs.append(ForcedRun(
            file=files[i], omega=f.omega, omega_stderr=math.sqrt(f.omega_var),
            B=Babs, B_stderr=math.sqrt(max(float(gB @ f.cov_ab @ gB), 0.0)),
            C=Cabs, C_stderr=math.sqrt(max(float(gC @ cu @ gC), 0.0)),
            R=R, R_stderr=math.sqrt(max(float(gR @ cz @ gR), 0.0)),
            rho=float(np.angle(Z[p])), rho_stderr=math.sqrt(max(float(grho @ cz @ grho), 0.0)),
            Z=complex(Z[p]), Z_cov=cz.copy(), t_start=float(seg.t[0]), t_end=float(seg.t[-1]),
            t_ref=f.t_ref, settle_time=settle, settled=settled,
            periods=f.omega * float(seg.t[-1] - seg.t[0]) / (2 * math.pi), noise_sd=nsd,
            residual_rms=math.sqrt(float(r @ r) / r.size), F_distortion=f.distortion,
            used=True, warnings=tuple(w_run), coef=np.array(coef, dtype=float),
            transient_rates=(modal.sigma, modal.w0sq),
        ))
    return ForcedIdentification(
        m=_est(resp.m, se, wse, 0, "kg"), c=_est(resp.c, se, wse, 1, "N s/m"),
        k=_est(resp.k, se, wse, 2, "N/m"), fit=resp, runs=tuple(out_runs),
        transient=(modal.sigma, modal.w0sq), transient_fitted=fit_rates,
        warnings=tuple(warnings), source=source, data=tuple(arrays), adequacy=adequacy,
    )


def _est(value: float, se: np.ndarray, wse: np.ndarray | None, j: int, unit: str) -> Estimate:
    """An estimate with its reported stderr and, where that is the robust one, the white."""
    return Estimate(value, float(se[j]), unit,
                    white_stderr=None if wse is None else float(wse[j]))


def _phasor_jac(w: complex) -> np.ndarray:
    """∂(Re, Im of w·P)/∂(a, b) for a phasor P = a − ib."""
    return np.array([[w.real, w.imag], [w.imag, -w.real]])


def _unused_run(file: str, t: np.ndarray, f: Force | None, reason: str | None,
                extra: list[str]) -> ForcedRun:
    nan = math.nan
    return ForcedRun(
        file=file, omega=f.omega if f else nan,
        omega_stderr=math.sqrt(f.omega_var) if f else nan,
        B=math.hypot(f.coef[1], f.coef[2]) if f else nan, B_stderr=nan, C=nan, C_stderr=nan,
        R=nan, R_stderr=nan, rho=nan, rho_stderr=nan, Z=complex(nan, nan),
        Z_cov=np.full((2, 2), nan), t_start=float(t[f.start]) if f else float(t[0]),
        t_end=float(t[-1]), settled=False, used=False,
        F_distortion=f.distortion if f else nan, warnings=(reason or "", *extra),
    )


def _side_warnings(om: np.ndarray, Z: np.ndarray, resp: ResponseFit) -> list[str]:
    """All frequencies on one side of the resonance ω₀ = √(k/m): the sign of R cos ρ."""
    below = Z.real > 0
    if below.all() or not below.any():
        side = "below" if below.all() else "above"
        w0 = math.sqrt(resp.k / resp.m) if resp.m > 0 and resp.k > 0 else math.nan
        what = ("m rests on the curvature of R cos ρ alone" if side == "below"
                else "k rests on the extrapolation of R cos ρ to ω = 0")
        return [f"all forcing frequencies ({om.min():.4g}–{om.max():.4g} rad/s) lie {side} "
                f"the resonance (ω₀ ≈ {w0:.4g} rad/s): {what}; sweep across ω₀ for a "
                "well-conditioned estimate"]
    return []


def _transient_start(segs: list[Segment], forces: list[Force], noise: list[float],
                     added: np.ndarray) -> tuple[tuple[float, float], bool]:
    """Starting rates of the start-up transient, and whether they can be fitted.

    Candidates: the plant of a first pass (each run's steady state fitted by a sine on the
    second half of its window, then eq. 20), and ESPRIT root pairs of the three largest
    residuals of that pass on the first part of the windows; the one with the lowest weighted
    SSE of the full model wins. The rates are fitted only when the transient it implies is
    strong enough somewhere (≥ 20 noise sd in all).
    """
    Zs, ws, covs = [], [], []
    resid = []
    for s, f in zip(segs, forces, strict=True):
        half = s.t >= s.t[0] + 0.5 * (s.t[-1] - s.t[0])
        G = s.fixed[half]
        coef, *_ = np.linalg.lstsq(G, s.x[half], rcond=None)
        r = s.x[half] - G @ coef
        s2 = float(r @ r) / max(r.size - 3, 1)
        Ginv = np.linalg.pinv(G.T @ G)
        Px = complex(coef[1], -coef[2])
        PF = complex(f.coef[1], -f.coef[2])
        Zi = PF / Px
        J = _phasor_jac(-Zi / Px)
        covs.append(J @ (s2 * Ginv[1:, 1:]) @ J.T + np.eye(2) * 1e-30)
        Zs.append(Zi)
        ws.append(f.omega)
        resid.append(s.x - s.fixed @ coef)
    cands: list[tuple[float, float]] = []
    first_ok = False
    try:
        first = fit_response(np.array(ws), np.array(Zs), np.array(covs), added_mass=added)
        if first.m > 0:
            cands.append((first.c / (2 * first.m), first.k / first.m))
            first_ok = True
    except (IdentificationError, ValueError, np.linalg.LinAlgError):
        pass
    order = np.argsort([-float(np.linalg.norm(r[: max(r.size // 4, 8)])) / nz
                        for r, nz in zip(resid, noise, strict=True)])
    for p in order[:3]:
        s = segs[int(p)]
        cands += esprit_rates(s.t, resid[int(p)], noise[int(p)], grid=p == order[0])
    span = max(float(s.t[-1] - s.t[0]) for s in segs)
    cands.append((2.0 / span, float(np.median(ws)) ** 2))
    # the candidates are compared on the runs with the strongest transient only (the others
    # barely depend on the rates), and the transient's strength is judged at the winner
    top = [segs[int(p)] for p in order[:3]]
    w_top = 1.0 / np.square([noise[int(p)] for p in order[:3]])
    best = pick_start(top, cands, w_top)
    st = State([Prep(s) for s in top], best[0], best[1], w_top)
    energy = max(float(np.linalg.norm(B @ beta)) * math.sqrt(w)
                 for (_Qb, beta, _r, B), w in zip(st.items, w_top, strict=True))
    if energy >= _TRANSIENT_SNR:
        return best, True
    # too weak to fit: keep the first pass's plant when it is a physical one (the rates barely
    # matter then, but a decaying transient is the right model)
    physical = [c for c in cands[:1] if c[0] > 0 and c[1] > 0] if first_ok else []
    return (physical[0] if physical else best), False
