"""The friction fit: m, c, k and f_c by full-record maximum likelihood, in two stages.

θ = (m, c, k, f_c) is shared by all runs, and per run the release position x₀ᵢ, the offset bᵢ
and the release time τᵢ are fitted (the model: :mod:`phoid.methods.friction.model`; the start:
:mod:`phoid.methods.friction.setup`).

Two stages. Stage 1 fits the first half of each run's motion, to about 2 standard errors; stage 2
fits the whole windows from there. Going straight to the whole windows can end in a false
optimum: a model that sticks one half-cycle too early has no sensitivity to the data of the
half-cycle it misses, so nothing pulls it back (docs/design-notes/friction.md); the first halves
hold no sticking, and their fit puts stage 2 in the right basin.

Each run's window runs from its first sample (the held segment fixes x₀ᵢ + bᵢ) to where its
motion ends — the last sample more than 6 noise sd from the record's final level, i.e. where the
mass sticks or the oscillation sinks into the noise — plus a margin of one period (at least 0.1 s
and 4Δt, so that a stuck mass is seen at rest for longer than the delay), which also pins the
stuck position. Later samples only repeat that position; leaving them out bounds the
simulations, which are the cost.

Runs set aside with a warning: those of :mod:`phoid.methods.friction.survey` (no motion, a
growing record), and those where friction stops the motion within a cycle (fewer than two
velocity reversals before the fitted motion sticks for good): such a record says little about
the oscillation and much about the static-friction details that the model idealises (static =
kinetic); it is set aside and the fit repeated without it. An error is raised when no run
remains. Every loop is bounded by the input: at most ``max_iter`` steps per fit, at most one
refit per run set aside, and the simulation's step is at least a tenth of the sample interval.

Sticking is reported per run: the fitted model's stick time (when the motion stops for good
before the record ends) with a warning.

The covariance of θ is the (θ, θ) block of (JᵀWJ)⁻¹ scaled by χ²/dof (the residual variance in
units of the noise sd): the Gauss–Newton (Fisher) covariance with every nuisance parameter
profiled out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid._progress import task
from phoid._threads import single_blas_thread
from phoid.errors import ExperimentError, IdentificationError
from phoid.methods.estimate import Estimate
from phoid.methods.friction.adequacy import assess_friction
from phoid.methods.friction.inloop import apply_placement
from phoid.methods.friction.model import Problem
from phoid.methods.friction.results import FrictionFit, FrictionRun
from phoid.methods.friction.setup import Setup, StartError, dominant, prepare
from phoid.methods.friction.solver import LMResult, levenberg_marquardt

__all__ = ["fit_runs", "identify_friction", "identify_friction_set"]

_UNITS = ("kg", "N s/m", "N/m", "N")
_MARGIN_PERIODS = 1.0  # window margin after the end of motion, in dominant periods …
_MARGIN_MIN = 0.1  # … and at least this many seconds (and 4Δt)
_MIN_REVERSALS = 2  # fewer velocity reversals before sticking: "stops within a cycle"


def _windows(setup: Setup, idx: list[int]) -> np.ndarray:
    out = []
    for i in idx:
        s = setup.surveys[i]
        period = 2 * math.pi / setup.omega[i]
        margin = max(_MARGIN_PERIODS * period, _MARGIN_MIN, 4 * setup.delay)
        out.append(min(float(s.t[-1]), s.motion_end + margin))
    return np.array(out)


def _early_windows(setup: Setup, idx: list[int], release: np.ndarray) -> np.ndarray:
    """Ends of the first half of each run's motion (at least two periods of it, where it has
    them): the stage-1 windows, which hold no sticking (module docstring)."""
    full = _windows(setup, idx)
    out = []
    for j, i in enumerate(idx):
        moving = setup.surveys[i].motion_end - release[j]
        period = 2 * math.pi / setup.omega[i]
        out.append(min(full[j], release[j] + max(0.5 * moving, min(2.0 * period, moving))))
    return np.array(out)


def fit_runs(setup: Setup, idx: list[int], theta0: np.ndarray, local0: np.ndarray,
             free: tuple[bool, ...], max_iter: int, *, t_end: np.ndarray | None = None,
             tol: float = 0.1, confirm: bool = True) -> tuple[Problem, np.ndarray, LMResult]:
    """One Levenberg–Marquardt fit of the runs ``idx`` of ``setup``.

    Parameters
    ----------
    setup : Setup
        The prepared set (:func:`phoid.methods.friction.setup.prepare`).
    idx : list of int
        The runs fitted.
    theta0 : ndarray, shape (4,)
        Starting (m, c, k, f_c), kg, N s/m, N/m, N; the entries not ``free`` stay fixed.
    local0 : ndarray, shape (len(idx), 3)
        Starting (x₀ᵢ m, bᵢ m, τᵢ s) of each run.
    free : tuple of 4 bool
        Which of (m, c, k, f_c) are fitted.
    max_iter : int
        Most Levenberg–Marquardt iterations.
    t_end : ndarray, optional
        End of each run's window, s (default: the whole motion plus a margin, module
        docstring).
    tol, confirm
        As for :func:`phoid.methods.friction.solver.levenberg_marquardt`.

    Returns
    -------
    prob : Problem
    fixed : ndarray, shape (4,)
        The globals' vector the fitted ones are written into (:meth:`Problem.split`).
    res : LMResult
    """
    surveys = [setup.surveys[i] for i in idx]
    t_end = _windows(setup, idx) if t_end is None else t_end
    prob = Problem(surveys, t_end, setup.P[idx], setup.D[idx], setup.delay, setup.fs, free,
                   setup.dm[idx], setup.digital, setup.bias[idx])
    fixed = theta0.copy()
    p0 = np.concatenate([theta0[np.array(free)], local0.ravel()])
    res = levenberg_marquardt(prob, p0, fixed, max_iter=max_iter, tol=tol, confirm=confirm)
    return prob, fixed, res


def _motion_facts(prob: Problem, local: np.ndarray, XV) -> list[tuple[float | None, int]]:
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
    noise_placement: str | None = None,
    stated_placement: str | None = None,
) -> FrictionFit:
    """Estimate m, c, k and the kinetic friction force f_c from a PHO experiment set.

    Full-record maximum-likelihood fit of every run through the exact stick–slip simulator of
    m x'' + c x' + k x + f_c sign(x') = −[Dᵢ x'(t − Δt) + Pᵢ x(t − Δt)] (seed eqs. 1 and 23);
    see :mod:`phoid.methods.friction.model` for the model, this module's docstring for the
    estimator and the runs it sets aside, :mod:`phoid.methods.friction.setup` for the start.

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
    noise_placement : {"auto", "in-loop", "outside"}, optional
        Where the sensor noise enters (a digital loop): ``"in-loop"`` (the controller reads
        the recorded position: m, c, k, f_c then come from the output error of the plant with
        friction driven by the force the controller applied, started from this fit,
        :mod:`phoid.methods.friction.inloop`), ``"outside"`` (the closed loop simulated from
        the true position), or ``"auto"``/None: ``stated_placement``, else the data's test.
    stated_placement : {"in-loop", "outside"}, optional
        The manifest's ``[loop] noise`` (:func:`identify_friction_set` passes it).

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
    from phoid.methods.inloop_route import check_placement

    if check_placement(noise_placement) == "in-loop" and digital is None:
        raise IdentificationError(
            "the noise placement 'in-loop' needs a digital loop ([loop] sample_time): a "
            "continuous loop's friction fit simulates the closed loop")
    if stated_placement not in (None, "in-loop", "outside"):
        raise ExperimentError("`stated_placement` must be 'in-loop', 'outside' or None; got "
                              f"{stated_placement!r}")
    with task("friction fit: the starting point") as advance:  # then one step per LM step
        setup = prepare(data, P, D, delay, start, names, need_fc=True, added_mass=added_mass,
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
            probe = Problem([setup.surveys[i] for i in idx], early, setup.P[idx], setup.D[idx],
                            setup.delay, setup.fs, free, setup.dm[idx], setup.digital,
                            setup.bias[idx])
            costs = []
            for th in setup.candidates:
                XV = probe.simulate(th, local[idx, 0], local[idx, 2])
                r = probe.residual(local[idx], XV) if XV is not None else None
                costs.append(float(r @ r) if r is not None else math.inf)
            theta = setup.candidates[int(np.argmin(costs))].copy()
            setup.start = theta.copy()
        advance(0, description="friction fit, stage 1 of 2 (early windows)")
        prob, fixed, res = fit_runs(setup, idx, theta, local[idx], free, max_iter, t_end=early,
                                    tol=2.0, confirm=False)
        iterations = res.iterations
        theta, local[idx] = prob.split(res.p, fixed)
        advance(0, description="friction fit, stage 2 of 2 (whole records)")
        while True:
            prob, fixed, res = fit_runs(setup, idx, theta, local[idx], free, max_iter)
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
        base = _result(setup, idx, reasons, prob, fixed, res, facts, iterations)
    return apply_placement(base, setup.P, setup.D, setup.digital, setup.dm,
                           option=noise_placement, stated=stated_placement)


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
            roots[g] = dominant(m + added, c, k, setup.P[g], setup.D[g], setup.delay,
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
        warnings.append(f"χ²/dof = {chi2_red:.3g}: the model does not fit the records to "
                        "their noise (stderr scaled up accordingly): check the delay, the "
                        "gains or unmodelled dynamics")
    if len(idx) < 3:
        warnings.append(f"only {len(idx)} usable runs: m, c, k, fc are barely determined")
    used_s = [setup.surveys[i] for i in idx]
    adequacy = assess_friction(
        resid, [s.sd for s in used_s],
        [float(np.sqrt(np.mean((vals[j] - local[j, 1]) ** 2))) for j in range(len(idx))],
        [s.name for s in used_s], J, list(prob.w), cov, chi2, dof)
    warnings.extend(w for w in adequacy.warnings if w not in warnings)
    wse: list[float | None] = [None] * 4
    if adequacy.stderr == "robust":
        cov = adequacy.robust_cov
        wse = [float(x) for x in se]
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return FrictionFit(
        m=Estimate(m, float(se[0]), _UNITS[0], white_stderr=wse[0]),
        c=Estimate(c, float(se[1]), _UNITS[1], white_stderr=wse[1]),
        k=Estimate(k, float(se[2]), _UNITS[2], white_stderr=wse[2]),
        fc=Estimate(fc, float(se[3]), _UNITS[3], white_stderr=wse[3]),
        adequacy=adequacy, cov=cov,
        delay=setup.delay if setup.digital is None else setup.digital.delay,
        runs=tuple(runs), chi2=chi2, dof=dof,
        residual_rms=rms_all, converged=res.converged, iterations=iterations,
        start=tuple(float(a) for a in setup.start), warnings=tuple(warnings),
        digital=setup.digital, data=tuple((s.t, s.y) for s in setup.surveys),
        sim_rate=float(setup.fs),
    )


def identify_friction_set(experiment: Any, *, delay: float | None = None,
                          noise_placement: str | None = None) -> FrictionFit:
    """:func:`identify_friction` on an experiment set (``phoid identify --friction``).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A ``pho`` set with a known loop delay (``[loop] delay``), or a sampled controller
        (``[loop] sample_time``, ``delay_samples``, ``velocity``, ``cutoff``).
    delay : float, optional
        Loop delay Δt (s), overriding the manifest's (continuous loops only).
    noise_placement : {"auto", "in-loop", "outside"}, optional
        Where the sensor noise enters (``--noise``); the manifest's ``[loop] noise`` where not
        given, else the data (:func:`identify_friction`).

    Raises
    ------
    IdentificationError
        A set the friction fit does not model (not ``pho``, no delay), conflicting loop keys,
        or no usable run; the message names the set.
    """
    from phoid.io.loop import read_noise_placement
    from phoid.methods.inloop_route import check_placement
    from phoid.methods.pho_checks import read_digital_loop

    where = str(getattr(experiment, "path", "experiment"))
    try:
        check_placement(noise_placement)
    except IdentificationError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
    stated = read_noise_placement(experiment)
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
                                 u=[getattr(r, "u", None) for r in runs],
                                 noise_placement=noise_placement, stated_placement=stated)
    except ExperimentError as exc:
        raise ExperimentError(f"{where}: {exc}") from None
    except StartError as exc:  # in the command line's words (no `start=`)
        cause = f" ({exc.cause})" if exc.cause else ""
        hint = exc.hint or (
            "check the loop delay ([loop] delay or --delay), the gains' sign convention "
            "(u = -P x(t - delay) - D x'(t - delay)) and the units of t (s) and x (m)")
        raise IdentificationError(
            f"{where}: the friction fit needs the viscous identification of the same runs as "
            f"its starting point, and it failed{cause}: {hint}") from None
    except IdentificationError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
