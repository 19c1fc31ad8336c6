"""The PHO pipeline: runs → dominant modes → m, c, k (and the loop delay when not given).

Each run's free decay is measured for its dominant mode past the loop's fast transient
(:mod:`phoid.methods.pho_measure`), the modes are mapped through the delayed loop (eqs. 28–32)
and m, c, k follow from all runs together (:mod:`phoid.methods.pho`). When the weighted fit's
runs disagree beyond their noise the modes are remeasured with its plant; when the delay is not
given it is estimated with m, c, k (and refined with the recorded feedback force,
:mod:`phoid.methods.udelay`). The set-level checks are :mod:`phoid.methods.pho_checks`; the
dispatch between PHO, forced and free sets is :func:`phoid.identify` (:mod:`phoid.api`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from phoid._threads import single_blas_thread
from phoid.errors import IdentificationError
from phoid.fits import start_decays
from phoid.methods.chi2 import chi2_isf
from phoid.methods.estimate import Estimate
from phoid.methods.inloop_route import check_placement, identify_digital, read_stated_placement
from phoid.methods.pho import MCKFit, delay_profile, fit_lines, fit_modes
from phoid.methods.pho_adequacy import apply_pho
from phoid.methods.pho_checks import (
    check_added_mass,
    check_delay,
    check_gain_magnitudes,
    check_sample_time,
    coarse_sampling,
    extreme_gain,
    read_digital_loop,
    refuse_bias,
    u_contradicts_gains,
)
from phoid.methods.pho_lines_check import check_lines
from phoid.methods.pho_measure import N_FAST, measure_runs, start_run
from phoid.methods.pho_result import Identification, RunMode
from phoid.methods.udelay import check_u, with_u
from phoid.reports.statistics import correlation
from phoid.reports.text import format_estimate, format_ratio

__all__ = ["check_estimator", "identify_pho", "identify_pho_data"]


def check_estimator(estimator: str, compensate: bool) -> None:
    """Refuse an unknown ``estimator``, or ``compensate=False`` with the weighted fit.

    Parameters
    ----------
    estimator : str
        ``"gls"`` or ``"ols"``.
    compensate : bool
        Whether the delay is corrected for (False only with ``"ols"``).

    Raises
    ------
    ValueError
        Naming the argument and its value.
    """
    if estimator not in ("gls", "ols"):
        raise ValueError(f"`estimator` must be 'gls' or 'ols'; got {estimator!r}")
    if estimator == "gls" and not compensate:
        raise ValueError("`compensate=False` is only available with estimator='ols'")


def _lines_note(fits, used, P, D, delay, compensate, dm, mck) -> str | None:
    """The warning when the eq. (35) lines misfit their points
    (:func:`phoid.methods.pho_lines_check.check_lines`), naming the delay left out when it
    is (``--no-compensation``) with what the compensated lines give; None when they fit."""
    sig = np.array([fits[i].sigma for i in used])
    wd = np.array([fits[i].omega_d for i in used])
    cov = np.array([fits[i].cov for i in used])
    Pu, Du, dmu = P[used], D[used], dm[used]
    kw = {"added_mass": dmu}
    chk = check_lines(sig, wd, cov, Pu, Du, delay, compensate=compensate, m_c=mck.c_line.slope,
                      m=mck.m, c=mck.c, k=mck.k, **kw)
    if chk is None or not chk.misfit:
        return None
    text = (f"the eq. (35) points lie off the straight lines by far more than the runs "
            f"measured them (χ²/dof {format_ratio(chk.chi2_c, chk.dof)} for the damping line, "
            f"{format_ratio(chk.chi2_k, chk.dof)} for the stiffness line): the lines' m, c, k "
            "are biased and their stderr (from the points' scatter) does not show it")
    if not compensate and delay > 0:
        alt = fit_lines(sig, wd, Pu, Du, delay, compensate=True, **kw)
        se = np.sqrt(np.clip(np.diag(alt.cov), 0.0, None))
        again = check_lines(sig, wd, cov, Pu, Du, delay, compensate=True, m_c=alt.c_line.slope,
                            m=alt.m, c=alt.c, k=alt.k, **kw)
        fits_now = ("" if again is None or again.misfit else
                    f"; the compensated lines fit (χ²/dof {format_ratio(again.chi2_c, again.dof)}"
                    f", {format_ratio(again.chi2_k, again.dof)})")
        return (f"{text}; the cause: the loop delay ({delay:.4g} s) is left out "
                f"(--no-compensation) — with it compensated m = {format_estimate(alt.m, se[0])} "
                f"kg, c = {format_estimate(alt.c, se[1])} N s/m, k = "
                f"{format_estimate(alt.k, se[2])} N/m{fits_now}")
    return (f"{text}; likely causes: a loop delay that is not the rig's, gains given in other "
            "units or sign, or decays that are not linear (Coulomb friction: --friction)")


def _misfit(mck: MCKFit) -> bool:
    """True when the weighted fit's χ² exceeds its 99.9 % quantile (runs disagree)."""
    return mck.dof > 0 and mck.chi2 > chi2_isf(0.001, mck.dof)


def identify_pho(
    experiment: Any,
    *,
    delay: float | None = None,
    estimator: str = "gls",
    compensate: bool = True,
    noise_placement: str | None = None,
) -> Identification:
    """Identify m, c, k from a PHO experiment set (``method = "pho"``).

    The PHO pipeline's entry point for a set; :func:`phoid.identify` dispatches here for PHO
    sets (and to the forced and free methods for theirs).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        The runs (t, x, P, D), the loop delay (``[loop] delay``) or the digital loop
        (``[loop] sample_time``, …), as read by :func:`phoid.io.read_experiment`.
    delay : float, optional
        Loop delay Δt (s), overriding the manifest's; None: the manifest's, estimated if it
        gives none.
    estimator : {"gls", "ols"}
        ``"gls"``: the efficient weighted fit through the exact loop roots (default).
        ``"ols"``: the paper's eq. (35) lines by ordinary least squares.
    compensate : bool, default True
        Correct for the delay (eqs. 28–32). False reproduces the paper's uncompensated column
        (only with ``estimator="ols"``).
    noise_placement : {"auto", "in-loop", "outside"}, optional
        Where the sensor noise enters; None or ``"auto"``: the manifest's ``[loop] noise``,
        else the data's choice (:mod:`phoid.methods.inloop_route`).

    Returns
    -------
    Identification

    Raises
    ------
    IdentificationError
        When the set is not a PHO set, or the data cannot determine m, c, k (no usable runs,
        all gains equal, …).
    """
    check_estimator(estimator, compensate)
    check_placement(noise_placement)
    noise = {"noise_placement": noise_placement, "stated": read_stated_placement(experiment)}
    method = getattr(experiment, "method", "pho")
    if method != "pho":
        raise IdentificationError(
            f"{experiment.path}: method = {method!r}: not a PHO set (phoid.identify takes every "
            "method)")
    refuse_bias(experiment, method)
    runs = list(experiment.runs)
    if not runs:
        raise IdentificationError(f"{experiment.path}: no runs")
    added_mass = np.array([getattr(r, "added_mass", 0.0) for r in runs], dtype=float)
    digital = read_digital_loop(experiment)
    if digital is not None:
        note = check_sample_time(experiment, digital, runs)
        if delay is not None:
            raise IdentificationError(
                f"{experiment.path}: --delay (delay = {delay!r}) does not apply to a digital "
                "loop ([loop] sample_time): its delay is [loop] delay_samples, in whole "
                "samples; leave the option out")
        if experiment.delay is not None:
            raise IdentificationError(
                f"{experiment.path}: [loop] delay: a digital loop (sample_time) takes its delay "
                "as delay_samples, in whole samples; give one or the other"
            )
        result = identify_pho_data(
            [(r.t, r.x) for r in runs],
            np.array([r.P for r in runs], dtype=float),
            np.array([r.D for r in runs], dtype=float),
            None, files=[r.file for r in runs], names=[getattr(r, "name", r.file) for r in runs],
            estimator=estimator, source=str(experiment.path), digital=digital,
            added_mass=added_mass, **noise,
        )
        return result if note is None else replace(result, warnings=(note, *result.warnings))
    if delay is None:
        delay = experiment.delay
    if delay is None and estimator != "gls":
        raise IdentificationError(
            f"{experiment.path}: [loop] delay is not given: estimating it needs the weighted "
            "fit (estimator 'gls'), or give the delay (phoid identify --delay)"
        )
    return identify_pho_data(
        [(r.t, r.x) for r in runs],
        np.array([r.P for r in runs], dtype=float),
        np.array([r.D for r in runs], dtype=float),
        None if delay is None else float(delay),
        added_mass=added_mass if np.any(added_mass) else None,
        files=[r.file for r in runs],
        names=[getattr(r, "name", r.file) for r in runs],
        estimator=estimator,
        compensate=compensate,
        source=str(experiment.path),
        u=[getattr(r, "u", None) for r in runs],
        x_unit=str(getattr(experiment, "x_unit", "m")), **noise,
    )


def _as_record(run) -> tuple[Any, Any]:
    """(t, x) as float64 arrays where they convert (the first pass reports those that do
    not, or that are not 1-d, finite and increasing)."""
    try:
        t, x = run
        return np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return run


@single_blas_thread
def identify_pho_data(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    estimator: str = "gls",
    compensate: bool = True,
    source: str = "",
    digital: Any = None,
    added_mass: np.ndarray | None = None,
    u: Sequence[np.ndarray | None] | None = None,
    x_unit: str = "m",
    noise_placement: str | None = None,
    stated: str | None = None,
) -> Identification:
    """The PHO pipeline on plain arrays: ``data`` is a sequence of (t, x) per run.

    The route by the noise placement (:func:`phoid.methods.inloop_route.identify_digital`:
    for a digital loop the output error of the plant driven by the applied force where the
    noise is in the loop), else the estimates of :func:`_identify_runs`, then their
    adequacy (:func:`phoid.methods.pho_adequacy.apply_pho`: each run's residual against its
    noise and for whiteness, the runs' agreement; where a check fails, the robust stderr with
    the white-noise ones in ``white_stderr`` and a warning).

    Parameters
    ----------
    data : sequence of (t, x)
        Each run's time (s) and position (m) arrays.
    P, D : array_like
        Each run's gains, N/m and N·s/m.
    delay : float or None
        Loop delay Δt, s; None estimates it with m, c, k.
    files, names, estimator, compensate, source, digital, added_mass, u, x_unit
        As in :func:`_identify_runs`.
    noise_placement, stated : str, optional
        The option (``"auto"``, ``"in-loop"``, ``"outside"``) and the manifest's ``[loop]
        noise``.

    Returns
    -------
    Identification

    Raises
    ------
    IdentificationError
        When the data cannot determine m, c, k (no usable runs, all gains equal, …).
    """
    def modal() -> Identification:
        return apply_pho(_identify_runs(data, P, D, delay, files=files, names=names,
                                        estimator=estimator, compensate=compensate,
                                        source=source, digital=digital,
                                        added_mass=added_mass, u=u, x_unit=x_unit))

    n = len(data)
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    return identify_digital(modal, data, P, D, digital, option=noise_placement, stated=stated,
                            names=list(names) if names is not None else files, files=files,
                            added_mass=added_mass, source=source, estimator=estimator,
                            x_unit=x_unit)


def _identify_runs(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    estimator: str = "gls",
    compensate: bool = True,
    source: str = "",
    digital: Any = None,
    added_mass: np.ndarray | None = None,
    u: Sequence[np.ndarray | None] | None = None,
    x_unit: str = "m",
) -> Identification:
    """The PHO pipeline on plain arrays: ``data`` is a sequence of (t, x) per run.

    Parameters
    ----------
    data : sequence of (t, x)
        Each run's time (s) and position (m) arrays.
    P, D : array_like
        Each run's gains, N/m and N·s/m.
    delay : float or None
        Loop delay Δt, s; None estimates it with m, c, k (:func:`_estimate_delay`).
    files, names : sequence of str, optional
        The runs' data files and names (labels in the result and messages).
    estimator : {"gls", "ols"}
        As in :func:`identify_pho`.
    compensate : bool, default True
        As in :func:`identify_pho`.
    source : str
        Where the data came from, for the result and messages.
    digital : phoid.dynamics.digital.DigitalPD, optional
        A sampled loop, modelled exactly (its gains ignored); ``delay`` is then ignored (the
        loop's own d·T_s is used for the starting lines).
    added_mass : array_like, optional
        Known mass added in each run, kg (the paper's added-mass trick): run i's loop has mass
        m + Δmᵢ and the estimate is the mass without additions.
    u : sequence of ndarray or None, optional
        The feedback force applied in each run, N (None where not recorded; same samples as
        x): with ``delay=None`` the delay is then estimated from x and u together
        (:func:`phoid.methods.udelay.with_u`); with a given delay, a u that contradicts the
        gains is reported.
    x_unit : str, default "m"
        What x is in (:attr:`phoid.io.ExperimentSet.x_unit`): ``"rad"`` words that report's
        units as a rotational set's (x in rad, u in N m).

    Returns
    -------
    Identification

    Raises
    ------
    IdentificationError
        When the data cannot determine m, c, k (no usable runs, all gains equal, …).
    """
    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    # float arrays once: every run is checked by its first pass and fitted unchecked after it
    data = [_as_record(run) for run in data]
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    names = list(names) if names is not None else files
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    for label, seq in (("P", P), ("D", D), ("files", files), ("names", names)):
        if np.ndim(seq) != 1 or len(seq) != n:
            raise ValueError(f"`{label}` must give one entry per run ({n} runs); got "
                             f"{'shape ' + str(np.shape(seq)) if np.ndim(seq) != 1 else len(seq)}")
    check_gain_magnitudes(P, D, names, source)
    if added_mass is not None:
        added_mass = np.broadcast_to(np.asarray(added_mass, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(added_mass) & (added_mass >= 0)):
            raise ValueError(f"`added_mass` must be finite and ≥ 0 kg; got {added_mass}")
    if digital is not None:
        if estimator != "gls":
            raise IdentificationError("a digital loop needs the weighted fit (estimator='gls')")
        # starting lines: the continuous loop with the delay of the samples, plus half a sample
        # (the hold) and, for a backward difference, half a sample more on the velocity
        res = _identify_core(data, P, D, digital.delay + 0.5 * digital.sample_time,
                             files=files, names=names, source=source, digital=digital,
                             added_mass=added_mass)
        return replace(res, delay=digital.delay, u=_recorded_u(u, data))
    if delay is None:
        if estimator != "gls":
            raise IdentificationError("estimating the loop delay needs estimator='gls'")
        u = None if u is None else check_u(u, data)
        res = _estimate_delay(data, P, D, files=files, names=names, source=source,
                              added_mass=added_mass)
        if u is None or all(ui is None for ui in u):
            return replace(res, delay_from="x", u=_recorded_u(u, data))

        dm = np.zeros(n) if added_mass is None else added_mass
        res = with_u(res, u, P, D, names=names, added_mass=dm, n_fast=N_FAST,
                     rerun=lambda tau: _identify_core(data, P, D, tau, files=files,
                                                      names=names, source=source,
                                                      estimate_delay=True, added_mass=dm))
        return replace(res, u=_recorded_u(u, data))
    check_delay(float(delay), data, source)
    res = _identify_core(data, P, D, float(delay), files=files, names=names,
                         estimator=estimator, compensate=compensate, source=source,
                         added_mass=added_mass)
    if u is not None and any(ui is not None for ui in u):
        wd = [r.omega_d for r in res.runs]
        note = u_contradicts_gains(data, check_u(u, data), P, D, float(delay), names, wd,
                                   x_unit)
        if note is not None:
            res = replace(res, warnings=(*res.warnings, note))
    return replace(res, u=_recorded_u(u, data))


def _recorded_u(u, data) -> tuple:
    """Each run's recorded force as a float array where it has one on its record's samples
    (None elsewhere); () when no u was given. Kept in the result for the figures."""
    if u is None:
        return ()
    out = []
    for j, (t, _x) in enumerate(data):
        ui = u[j] if j < len(u) else None
        try:
            arr = None if ui is None else np.asarray(ui, dtype=float)
        except (TypeError, ValueError):
            arr = None
        out.append(arr if arr is not None and arr.shape == np.shape(t) else None)
    return tuple(out)


_DELAY_GRID = 400  # candidate delays of the starting profile


def _estimate_delay(data, P, D, *, files, names, source, added_mass=None) -> Identification:
    """m, c, k and the loop delay Δt together (the manifest gives no delay).

    Only the right delay maps all runs' modes onto one plant (eq. 35's points collinear, with
    one slope), so with three or more distinct gain pairs Δt is identifiable. Start: each run's
    mode from the release on (:func:`phoid.fits.start_decay`, no transient skipped: a slightly
    biased but robust first look), then the profile of :func:`phoid.methods.pho.delay_profile` over
    0 … π/max ω_d (a delay of half the fastest run's period; the loop's phase lag at that delay
    is already beyond what a PD loop rings with). Then the full pipeline at that delay with
    Δt fitted alongside m, c, k through the exact roots (:func:`phoid.methods.pho.fit_modes`),
    twice:
    the second time with the transient skip and fast modes of the first estimate.
    """
    n = len(data)
    where = f"{source}: " if source else ""
    starts = [start_run(t, x, 0.0)[0] for t, x in data]
    ok = [i for i in range(n) if starts[i] is not None and starts[i].oscillating]
    if len({(P[i], D[i]) for i in ok}) < 3:
        raise IdentificationError(
            f"{where}[loop] delay is not given and cannot be estimated: that needs at least three "
            f"runs with distinct gains (P, D) that oscillate; {len(ok)} such runs found. Give "
            "the delay ([loop] delay in the manifest, or phoid identify --delay)"
        )
    sig = np.array([starts[i].sigma for i in ok])
    wd = np.array([starts[i].omega_d for i in ok])
    hi = math.pi / float(np.max(wd))
    grid = np.linspace(0.0, hi, _DELAY_GRID + 1)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    prof = delay_profile(sig, wd, P[ok], D[ok], grid, added_mass=dm[ok])
    j = int(np.argmin(prof))
    cause = None
    if j == grid.size - 1:
        cause = _probable_cause([(st, None) for st in starts], data, P, D, None, names, dm, True)
    if cause is not None:
        raise IdentificationError(f"{where}{cause}")
    if j == grid.size - 1:
        raise IdentificationError(
            f"{where}the loop delay estimate hits its upper bound ({hi:.4g} s, half the period "
            "of the fastest run): the runs do not look like one plant under a delayed PD loop; "
            "give the delay, or check the gains"
        )
    tau = float(grid[j])
    notes: list[str] = []
    result = None
    for _ in range(3):
        try:
            result = _identify_core(data, P, D, tau, files=files, names=names, source=source,
                                    estimate_delay=True, added_mass=dm)
        except IdentificationError as exc:
            cause = _probable_cause([(st, None) for st in starts], data, P, D, None, names, dm,
                                    True)
            if cause is not None:
                msg = str(exc) if cause in str(exc) else (
                    f"{where}{cause} (estimating the loop delay: {exc})")
                raise IdentificationError(msg) from None
            raise IdentificationError(
                f"{where}estimating the loop delay: {exc} (the delay is searched in 0–{hi:.4g} "
                "s, half the period of the fastest run: a longer delay must be given, [loop] "
                "delay or phoid identify --delay)") from None
        moved = abs(result.delay - tau)
        tau = result.delay
        if moved <= 0.1 * (result.delay_stderr or 0.0) + 1e-12 * max(tau, 1.0):
            break
    assert result is not None
    if not tau > 0.0:
        notes.append("the loop delay estimate is 0 (its lower bound): the loop behaves as if "
                     "it had no delay")
    elif result.delay_stderr is not None and result.delay_stderr > 0.2 * tau:
        notes.append(f"the loop delay is poorly determined ({tau:.4g} ± "
                     f"{result.delay_stderr:.2g} s): spread the gains more, or give the delay")
    if notes:
        result = replace(result, warnings=tuple(notes) + result.warnings)
    return result


def _cli_words(message: str) -> str:
    """A decay fit's message in the identification's words: its ``skip`` is not a setting
    here but three loop delays after the release (set through the delay, --delay)."""
    return (message.replace("(increase `skip`?)", "(is the loop delay, --delay, right?)")
            .replace("[release + skip, t_end]", "[release + 3 delay, end]"))


def _probable_cause(first, data, P, D, delay, names, dm, estimate_delay) -> str | None:
    """`diagnose.probable_cause` from the first pass's rough modes (``first``: each
    run's (start, error)); ``delay`` None (a digital loop, or a delay being estimated) skips
    the delay check."""
    from phoid.methods.diagnose import probable_cause

    sig = np.full(len(data), np.nan)
    wd = np.full(len(data), np.nan)
    steps = np.full(len(data), np.nan)
    for i, (st, _err) in enumerate(first):
        if st is not None and st.oscillating:
            sig[i], wd[i] = st.sigma, st.omega_d
        try:
            t = np.asarray(data[i][0], dtype=float)
            steps[i] = float(np.median(np.diff(t[: min(t.size, 64)])))
        except (TypeError, ValueError, IndexError):
            pass
    return probable_cause(sig, wd, P, D, None if estimate_delay else delay, steps=steps,
                          names=names, added_mass=dm)


def _identify_core(data, P, D, delay, *, files, names, estimator="gls", compensate=True,
                   source="", estimate_delay=False, notes=(), digital=None,
                   added_mass=None) -> Identification:
    """The pipeline at one delay: measure modes, combine (estimating the delay too if asked,
    ``delay`` then being its start), refine on misfit, and assemble the result."""
    n = len(data)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    first = None
    if np.any(dm):
        first = [(st, None) if not isinstance(st, str) else (None, st) for st in
                 start_decays(data, skip=3.0 * delay, refine="auto", coarse_release=True)]
        check_added_mass(first, P, D, delay, dm, names, source)
    first, fits, reasons, _skips, rough = measure_runs(data, P, D, delay, digital=digital,
                                                        added_mass=dm, first=first)
    used = [i for i in range(n) if reasons[i] is None]
    if not used:
        raise IdentificationError(
            "no usable runs: " + "; ".join(f"{names[i]}: {reasons[i]}" for i in range(n))
        )

    def combine(fits, used):
        sig = np.array([fits[i].sigma for i in used])
        wd = np.array([fits[i].omega_d for i in used])
        cov = np.array([fits[i].cov for i in used])
        if estimator == "gls":
            return fit_modes.__wrapped__(sig, wd, cov, P[used], D[used], delay,
                                         estimate_delay=estimate_delay, digital=digital,
                                         added_mass=dm[used])
        return fit_lines(sig, wd, P[used], D[used], delay, compensate=compensate,
                         added_mass=dm[used])

    try:
        mck = combine(fits, used)
    except IdentificationError as exc:
        cause = _probable_cause(first, data, P, D, None if digital is not None else delay,
                                names, dm, estimate_delay)
        where = f"{source}: " if source else ""
        if cause is None:
            text = str(exc)
            if source and not text.startswith(source):
                text = f"{where}{text}{extreme_gain(P, D, names)}"
                if digital is not None:  # the sampled loop's delay is these two keys
                    text += " ([loop] sample_time, delay_samples)"
            raise IdentificationError(text) from None
        raise IdentificationError(f"{where}{cause} ({exc})") from None
    # The second pass took the loop's fast modes from a rough plant (first pass). Where that
    # plant was poor — a run whose next root is slow biases the first pass — the runs then
    # disagree beyond their noise: refit the modes with the weighted estimate (at most twice)
    # and keep whichever combination fits best.
    for _ in range(2):
        if estimator != "gls" or rough is None or not _misfit(mck):
            break
        _first, fits2, reasons2, _s, _r = measure_runs(
            data, P, D, delay, rough=(mck.m, mck.c, mck.k), first=first, digital=digital,
            added_mass=dm,
            noise=[f.noise_sd if f is not None else None for f in fits],
        )
        used2 = [i for i in range(n) if reasons2[i] is None]
        if len(used2) < len(used):
            break
        try:
            mck2 = combine(fits2, used2)
        except (IdentificationError, ValueError, np.linalg.LinAlgError):
            break
        if not mck2.chi2 / max(mck2.dof, 1) < mck.chi2 / max(mck.dof, 1):
            break
        fits, reasons, used, mck, rough = fits2, reasons2, used2, mck2, (mck2.m, mck2.c, mck2.k)
    warnings: list[str] = list(notes)
    reasons = [None if r is None else _cli_words(r) for r in reasons]
    for i, f in enumerate(fits):
        if reasons[i] is not None:
            warnings.append(f"{names[i]}: set aside: {reasons[i]}")
        elif f is not None:
            warnings.extend(f"{names[i]}: {_cli_words(w)}" for w in f.warnings)
    warnings.extend(mck.warnings)
    if estimator == "ols" and digital is None and delay is not None:
        note = _lines_note(fits, used, P, D, float(delay), compensate, dm, mck)
        if note is not None:
            warnings.append(note)
    if _misfit(mck):
        cause = _probable_cause(first, data, P, D, None if digital is not None else delay,
                                names, dm, estimate_delay)
        if cause is not None:
            warnings.append(f"probably: {cause}")
    misfits = [i for i in used if any(w.startswith("misfit") for w in fits[i].warnings)]
    if digital is None and len(misfits) >= max(2, len(used) // 2):
        warnings.append(
            f"{len(misfits)} of {len(used)} runs do not decay like a linear loop (residuals well "
            "above the noise): if the rig has Coulomb friction, identify with friction "
            "(phoid identify --friction, phoid.identify_friction), which fits f_c too"
        )
    if len(used) >= 3 and np.ptp(D[used]) == 0.0:
        # P-only loops (the seed's Discussion): damping varies between runs only through the
        # delay, so the damping line's points crowd together; say how much that costs
        sd = np.sqrt(np.diag(mck.cov))
        corr = correlation(mck.cov)
        rho = float(np.max(np.abs(corr[np.triu_indices(3, 1)])))
        warnings.append(
            f"all runs have the same D ({D[used][0]:g} N s/m, a P-only sweep): the runs' "
            "damping differs only through the delay, so c rests on the delay being right; "
            f"conditioning: largest correlation of m, c, k {rho:.3f}, condition number of "
            f"their correlation matrix {float(np.linalg.cond(corr)):.3g}, c known to "
            f"{100 * sd[1] / max(abs(mck.c), 1e-300):.2g} %"
        )
    coarse = coarse_sampling(data, [fits[i] for i in used])
    if coarse is not None:
        warnings.append(coarse)
    if len(used) < 3:
        warnings.append(f"only {len(used)} usable runs: m, c, k are barely determined")
    se = mck.stderr
    runs: list[RunMode] = []
    j = 0
    for i in range(n):
        f = fits[i]
        if i in used:
            cp, kp = float(mck.c_prime[j]), float(mck.k_prime[j])
            j += 1
        else:
            cp = kp = math.nan
        runs.append(RunMode(
            file=files[i], P=float(P[i]), D=float(D[i]),
            sigma=f.sigma if f else math.nan, omega_d=f.omega_d if f else math.nan,
            sigma_stderr=f.sigma_stderr if f else math.nan,
            omega_d_stderr=f.omega_d_stderr if f else math.nan,
            c_prime=cp, k_prime=kp, cycles=f.cycles if f else math.nan,
            residual_rms=f.residual_rms if f else math.nan, used=i in used,
            warnings=tuple(([reasons[i]] if reasons[i] else [])
                           + ([_cli_words(w) for w in f.warnings] if f else [])),
            fit=f, added_mass=float(dm[i]),
        ))
    return Identification(
        m=Estimate(mck.m, float(se[0]), "kg"),
        c=Estimate(mck.c, float(se[1]), "N s/m"),
        k=Estimate(mck.k, float(se[2]), "N/m"),
        delay=delay if mck.delay is None else mck.delay,
        delay_source="estimated" if mck.delay_stderr is not None else "given",
        delay_stderr=mck.delay_stderr, runs=tuple(runs), fit=mck, digital=digital,
        warnings=tuple(warnings), source=source, data=tuple(data),
    )
