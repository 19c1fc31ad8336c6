"""Checking given gains, or the gains of an experiment set, the way design does.

:func:`check` evaluates gains on the prior grid with the requirements of
:mod:`phoid.planning.evaluation` and reports which runs are unsafe or uninformative;
:func:`check_experiment` does so for a read set or a designed skeleton, taking the plant from
the set's own identification and the recording settings from its records when not given.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

import phoid._validate as v
from phoid._notation import unit_text
from phoid._threads import single_blas_thread
from phoid.errors import PhoidError
from phoid.fits import detect_release
from phoid.io import ExperimentSet, read_experiment
from phoid.io.loop import read_digital_loop, read_noise_placement
from phoid.planning.result import Design, assemble, roots_in_range
from phoid.planning.schedule import read_schedule
from phoid.planning.settings import DesignError, DesignSettings, make_prior

__all__ = ["check", "check_experiment"]


@roots_in_range
@single_blas_thread
def check(
    P: Sequence[float] | np.ndarray,
    D: Sequence[float] | np.ndarray,
    m: Any,
    c: Any,
    k: Any,
    *,
    delay: float | None = None,
    fs: float | None = None,
    duration: float = 10.0,
    noise: float = 1e-5,
    amplitude: float = 0.01,
    zeta: tuple[float, float] = (0.03, 0.2),
    pmax: float | None = None,
    dmax: float | None = None,
    max_freq: float | None = None,
    min_cycles: float = 5.0,
    delay_margin: float | None = None,
    separation: float = 2.0,
    tolerance: float = 0.1,
    sample_time: float | None = None,
    delay_samples: int | None = None,
    velocity: str | None = None,
    cutoff: float | None = None,
    noise_in_loop: bool | None = None,
    delay_margin_samples: int | None = None,
) -> Design:
    """Evaluate given gains like :func:`~phoid.planning.search.design`: which runs are unsafe or
    uninformative.

    Parameters are those of :func:`design`, with the gains ``P`` (N/m) and ``D`` (N·s/m) of the
    runs instead of ``runs``; with ``sample_time`` the gains are judged on the sampled loop
    (exact modes, margins in samples, the bound for ``noise_in_loop``).

    Returns
    -------
    Design
        ``kind = "check"``; each run's ``safe``/``informative`` flags and warnings say what is
        wrong, and the predicted standard errors are those of the given set.
    """
    st = DesignSettings(delay=delay, fs=fs, duration=duration, noise=noise,
                        amplitude=amplitude, zeta=zeta, pmax=pmax, dmax=dmax,
                        max_freq=max_freq, min_cycles=min_cycles, delay_margin=delay_margin,
                        separation=separation, tolerance=tolerance, sample_time=sample_time,
                        delay_samples=delay_samples, velocity=velocity, cutoff=cutoff,
                        noise_in_loop=noise_in_loop, delay_margin_samples=delay_margin_samples)
    P = v.finite_array("P", P, ndim=1)
    D = v.finite_array("D", D, ndim=1)
    if P.size != D.size or P.size == 0:
        raise ValueError(f"`P` and `D` must have one entry per run; got {P.size} and {D.size}")
    prior = make_prior(m, c, k, st.tolerance)
    return assemble(P, D, prior, st, "check")


def check_experiment(
    experiment: Any,
    m: Any = None,
    c: Any = None,
    k: Any = None,
    **settings: Any,
) -> Design:
    """:func:`check` the gains of an experiment set (a read set or a designed skeleton).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet, str or Path
        A set read by :func:`phoid.read_experiment`, or the path of a set or skeleton manifest
        (data files not needed).
    m, c, k : prior, optional
        The plant to check against; when omitted, the set's data are identified
        (:func:`phoid.identify`) and the estimate is used.
    **settings
        Further keywords of :func:`check`. The loop defaults to the set's: ``delay`` from
        ``[loop] delay``, or a digital loop (``[loop] sample_time``, ``delay_samples``,
        ``velocity``, ``cutoff``, read by :func:`phoid.io.loop.read_digital_loop`) whose keys
        given here override the set's (``delay`` with a digital set is refused); the noise
        placement (``noise_in_loop``) from ``[loop] noise``, else in the loop for a digital
        set (a note says which). For a set with data, ``fs``, ``duration`` (from the release),
        ``amplitude`` and ``noise`` default to what the records show (median over the runs;
        a digital set's ``fs`` the whole multiple of 1/T nearest; the noise the fits'
        residual sd where the set is identified, else the records' third-difference noise,
        with or without the prior ``m``, ``c``, ``k``) — the skeleton's ``[design]`` values
        for a skeleton. A note says which noise was used.

    Returns
    -------
    Design
    """
    exp = experiment
    sched = None
    read_error = None
    if not isinstance(exp, ExperimentSet):
        try:
            exp = read_experiment(experiment)
        except (PhoidError, OSError) as exc:
            try:
                sched = read_schedule(experiment)
            except DesignError:
                raise exc from None
            exp, read_error = None, " ".join(str(exc).split())
    notes: list[str] = []
    if exp is not None:
        if exp.method != "pho":
            raise DesignError(f"{exp.path}: method is {exp.method!r}; only pho sets have gains "
                              "to check")
        P = np.array([r.P for r in exp.runs], dtype=float)
        D = np.array([r.D for r in exp.runs], dtype=float)
        delay = exp.delay
        try:
            digital = read_digital_loop(exp)
            stated = read_noise_placement(exp)
        except PhoidError as exc:
            raise DesignError(str(exc)) from None
        loop = {} if digital is None else {
            "sample_time": digital.sample_time, "delay_samples": digital.delay_samples,
            "velocity": digital.velocity, "cutoff": digital.cutoff}
        from_data = _record_settings(exp, digital)
        noise_from = "records"
    else:
        P, D, delay = sched["P"], sched["D"], sched["delay"]
        stated = sched.get("noise_placement")
        loop = {key: sched[key] for key in ("sample_time", "delay_samples", "velocity",
                                            "cutoff") if sched.get(key) is not None}
        from_data = {key: sched[key] for key in ("fs", "duration", "noise", "amplitude")
                     if sched.get(key) is not None}
        noise_from = "skeleton"
    where = exp.path if exp is not None else experiment
    digital_keys = ("sample_time", "delay_samples", "velocity", "cutoff")
    asked = settings.get("noise_in_loop")
    given_loop = [key for key in digital_keys if settings.get(key) is not None]
    if loop or settings.get("sample_time") is not None:  # a sampled loop
        if settings.get("delay") is not None:
            raise DesignError(
                f"{where}: the loop is sampled ([loop] sample_time): its delay is whole "
                "samples (--delay-samples), not --delay" if loop else
                "--delay (s) and --sample-time together: a sampled loop's delay is "
                "--delay-samples, whole periods of --sample-time; give one or the other")
        if not loop and delay is not None:
            raise DesignError(f"{where}: the set's loop is continuous ([loop] delay = "
                              f"{delay:g} s); --sample-time would judge another loop: give "
                              "--delay to change its delay")
        settings.pop("delay", None)
        for key in digital_keys:
            if settings.get(key) is None and key in loop:
                settings[key] = loop[key]
        if settings.get("velocity") != "filtered" and "cutoff" not in given_loop:
            settings.pop("cutoff", None)
        if settings.get("noise_in_loop") is None:
            if stated is not None:
                settings["noise_in_loop"] = stated == "in-loop"
                notes.append(f"noise placement {stated!r}: the set's [loop] noise")
            else:
                settings["noise_in_loop"] = True
                notes.append("noise placement 'in-loop': the default for a digital loop (the "
                             "set does not state [loop] noise)")
    else:
        if settings.get("delay") is None:
            settings.pop("delay", None)
            if delay is None:
                raise DesignError("the set has no [loop] delay and no digital loop ([loop] "
                                  "sample_time): give --delay, or --sample-time and "
                                  "--delay-samples")
            settings["delay"] = delay
    carried: list[str] = []  # warnings of the identification the check relies on
    if read_error is not None:
        notes.append(f"the set's data were not used ({read_error}): gains checked against the "
                     "prior only")
    if m is None or c is None or k is None:
        if exp is None:
            raise DesignError(f"cannot identify the set ({read_error}); to check its gains "
                              "alone give the prior plant --m, --c and --k")
        from phoid.methods.identification import identify_pho as identify

        if loop:  # the set's digital loop, the placement asked for (else the data's)
            ident = identify(exp, noise_placement=None if asked is None
                             else ("in-loop" if asked else "outside"))
        elif settings.get("sample_time") is not None:
            ident = identify(exp)
        else:
            ident = identify(exp, delay=settings["delay"])
        m = ident.m.value if m is None else m
        c = ident.c.value if c is None else c
        k = ident.k.value if k is None else k
        notes.append(
            "plant from the set's own identification: "
            + ", ".join(f"{n} = {e.value:.6g} ± {e.stderr:.3g} {unit_text(e.unit)}"
                        for n, e in (("m", ident.m), ("c", ident.c), ("k", ident.k))))
        if noise_from == "records":  # the fits' residual: the records' noise, model-aware
            fit = getattr(ident, "inloop", None)
            sds = [float(fit.sigma)] if fit is not None and math.isfinite(fit.sigma) else [
                r.fit.noise_sd for r in ident.runs if r.fit is not None
                and math.isfinite(r.fit.noise_sd)]
            if sds and float(np.median(sds)) > 0:
                from_data["noise"] = float(np.median(sds))
                noise_from = "fits"
        # the check relies on this estimate: what the identification warned of stays with it
        carried.extend(f"identification of the set: {w}" for w in ident.warnings)
        for name, val in (("c", c), ("k", k)):
            if not isinstance(val, (str, Sequence)) and float(val) < 0.0:
                carried.append(f"the set's identification gives {name} = {float(val):.4g} < 0: "
                               f"the check uses {name} = 0; give the prior --{name}")
        c = max(float(c), 0.0) if not isinstance(c, (str, Sequence)) else c
        k = max(float(k), 0.0) if not isinstance(k, (str, Sequence)) else k
    given_noise = settings.get("noise")
    for key, val in from_data.items():
        if settings.get(key) is None:
            settings[key] = val
    dur, given_delay = settings.get("duration"), settings.get("delay")
    if (isinstance(given_delay, int | float) and isinstance(dur, int | float)
            and math.isfinite(dur) and not 3.0 * given_delay < dur):
        # before the loop's roots: a delay in the wrong unit names itself, not the plant
        raise DesignError(f"{where}: the loop delay (--delay, else the set's [loop] delay) = "
                          f"{given_delay:g} s is too long for the set's records ({dur:g} s "
                          "after the release; --duration): the identification fits each decay "
                          "from 3 delays after the release; is the delay in seconds?")
    settings = {key: val for key, val in settings.items() if val is not None}
    d = check(P, D, m, c, k, **settings)  # validates the settings, --noise among them
    notes.append(_noise_note(given_noise, from_data.get("noise"), noise_from))
    negative = [name for name, g in (("P", P), ("D", D)) if g.size and np.all(g < 0)]
    if negative:
        from phoid.methods.diagnose import SIGN_CONVENTION

        what = " and ".join(negative)
        carried.insert(0, f"every run's {what} is negative: {SIGN_CONVENTION}; if the rig's "
                          f"controller uses the other sign, give {what} with phoid's")
    if notes:
        d = dataclasses.replace(d, notes=tuple(notes))
    if carried:
        d = dataclasses.replace(d, warnings=tuple(carried) + tuple(d.warnings))
    return d


def _noise_note(given: Any, found: float | None, source: str) -> str:
    """The note saying which sensor noise the check used: ``given`` (``--noise``), else
    ``found`` from ``source`` ("fits", "records" or "skeleton"), else the default."""
    what = {"fits": "measured from the records (the fits' residual sd, median over the runs)",
            "records": "measured from the records (their third differences, median over the "
                       "runs)",
            "skeleton": "from the manifest's [design] noise (its records not read)"}[source]
    if given is not None:
        other = f"; {what.split(' (')[0]}: {found:.3g} m" if found is not None else ""
        return f"noise {float(given):.3g} m as given (--noise){other}"
    if found is not None:
        return f"noise {found:.3g} m {what}; give --noise to use another"
    why = ("the records show none above rounding" if source != "skeleton"
           else "no records read, no [design] noise")
    return (f"noise {DesignSettings.noise:.3g} m: the default ({why}); give --noise for the "
            "rig's")


def _record_settings(exp, digital=None) -> dict[str, float]:
    """Sample rate, record length after the release, release amplitude and sensor noise
    (third differences, :func:`phoid.methods.fit_statistics.difference_noise`) seen in a set;
    a digital set's rate the whole multiple of its loop's rate 1/T nearest the records' (one
    line naming the set when none is within 10 %)."""
    from phoid.methods.fit_statistics import difference_noise

    fs, dur, amp, noise = [], [], [], []
    for r in exp.runs:
        t, x = np.asarray(r.t), np.asarray(r.x)
        dt = np.diff(t)
        fs.append(1.0 / float(np.median(dt)))
        try:
            t0 = detect_release(t, x)
        except (ValueError, RuntimeError):
            t0 = float(t[0])
        dur.append(float(t[-1] - t0))
        j = int(np.searchsorted(t, t0))
        tail = x[-max(10, x.size // 10):]
        amp.append(abs(float(x[min(j, x.size - 1)]) - float(np.median(tail))))
        noise.append(difference_noise(x, rounding=True))
    out = {"fs": float(np.median(fs)), "duration": float(np.median(dur))}
    if digital is not None:
        T = digital.sample_time
        per = out["fs"] * T
        M = max(1, round(per))
        if not abs(per - M) <= 0.1 * M:
            raise DesignError(f"{exp.path}: the records' sample rate {out['fs']:.6g} Hz is not a "
                              f"whole multiple of the loop's rate 1/sample_time = {1 / T:g} Hz "
                              f"([loop] sample_time = {T:g} s): is sample_time in seconds?")
        out["fs"] = M / T
    a = float(np.median(amp))
    if a > 0:
        out["amplitude"] = a
    sd = float(np.median(noise))
    if math.isfinite(sd) and sd > 0:
        out["noise"] = sd
    return out
