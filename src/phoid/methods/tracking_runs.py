"""A tracking set's runs as loop records: their controllers, inputs, replays and validations.

Shared by the identification (:mod:`phoid.methods.tracking_identification`) and the replay
(:mod:`phoid.methods.tracking_replay`) of a ``method = "tracking"`` set: each run's
:class:`~phoid.dynamics.controller.SampledController` from the set's ``[loop]`` and the run's
gains (:func:`run_controller`), how its additive input w reaches the plant — stated by the
manifest or measured from the record (:mod:`phoid.methods.tracking_semantics`) —, the run as a
:class:`~phoid.methods.tracking.TrackingRecord` (:func:`run_records`), its loop simulated with
given parameters from the recorded state and compared with the record (:func:`replay_records`:
the benchmark's relative errors), and the JSON entries of the validations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import SimpleNamespace
from typing import Any

import numpy as np

from phoid.dynamics.controller import SampledController
from phoid.dynamics.plant import Plant
from phoid.errors import IdentificationError
from phoid.io.units import unit_hint
from phoid.methods.fit_statistics import difference_noise, residual_noise_ratio
from phoid.methods.tracking import TrackingRecord, replay
from phoid.methods.tracking_semantics import CommandInput, command_input_semantics
from phoid.methods.tracking_validation import validate_tracking

__all__ = [
    "check_resolvable",
    "command_input",
    "input_entries",
    "input_warnings",
    "json_safe",
    "replay_records",
    "run_controller",
    "run_records",
    "run_semantics",
    "validate_run",
    "validation_entries",
    "validation_noise_ratio",
]


def validation_noise_ratio(validation: Any) -> float | None:
    """RMS of a validation's position residual x − x_sim over the noise level of the recorded
    x, both in the compared window (:func:`~phoid.methods.fit_statistics.difference_noise`,
    independent of the model): ≈ 1 when the simulated loop reproduces the record to its
    noise, ≫ 1 otherwise. None when the noise level is 0 (an exactly quantised still record)."""
    start, stop = validation.window
    x = np.asarray(validation.x[start:stop], dtype=float)
    r = x - np.asarray(validation.x_sim[start:stop], dtype=float)
    if r.size == 0:
        return None
    return residual_noise_ratio(float(np.sqrt(np.mean(r * r))), difference_noise(x))


def validation_entries(run_names: Any, validations: Any) -> list[dict[str, Any]]:
    """The ``validation`` list of a summary: per run ``run``, the validation's own summary and
    ``residual_noise_ratio`` (:func:`validation_noise_ratio`)."""
    return [{"run": name, **v.summary(), "residual_noise_ratio": validation_noise_ratio(v)}
            for name, v in zip(run_names, validations, strict=True)]


def json_safe(value: Any) -> Any:
    """``value`` with every float that is not finite (an overflowed statistic) as None: the
    output is strict JSON (docs/format.md, "phoid identify --json")."""
    if isinstance(value, dict):
        return {k: json_safe(q) for k, q in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(q) for q in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def run_controller(experiment: Any, run: Any, *, delay: float | None = None) -> SampledController:
    """The :class:`SampledController` of one run of a tracking set (loop keys, run's gains).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A tracking set (``[loop]``: sample_time, velocity, cutoff, delay, saturation).
    run : phoid.io.Run
        Its run (P, D, gain, command_gain resolved to numbers by the reader).
    delay : float, optional
        Command delay τ (s) overriding the set's (None: the set's, or 0 when it has none).
    """
    loop = experiment.loop
    where = f"{experiment.path}: run {run.index} ({run.file})"
    T = loop.get("sample_time")
    mean_step = float((run.t[-1] - run.t[0]) / (run.t.size - 1))
    if T is None:
        steps = np.diff(run.t)
        T = mean_step
        if np.max(np.abs(steps - T)) > 1e-3 * T:
            raise IdentificationError(
                f"{where}: t is not uniformly sampled and [loop] sample_time is not given"
            )
    elif isinstance(T, (int, float)) and T > 0:
        # the record holds one sample per controller instant: a period that does not match
        # t's spacing would scale every time derivative, silently
        steps = np.diff(run.t)
        typical = float(np.median(steps))
        gaps = np.abs(steps - T) > 0.5 * T
        if abs(typical - T) > 1e-3 * T or (abs(mean_step - T) > 1e-3 * T and not gaps.any()):
            hint = unit_hint("t", typical / T)
            raise IdentificationError(
                f"{where}: t: the samples are {typical:.6g} s apart (median; {mean_step:.6g} s "
                f"on average) but [loop] sample_time is {T:g} s; the record must hold one "
                f"sample per controller period{'; ' + hint if hint else ''}"
            )
        # every step, not only the typical one: a dropped sample shifts the rest of the
        # record by a period, which the loop model would take for dynamics
        bad = np.flatnonzero(gaps)
        if bad.size:
            i = int(bad[0]) + 1
            gap = float(run.t[i] - run.t[i - 1])
            raise IdentificationError(
                f"{where}: t: samples {i} and {i + 1} (1-based) are {gap:.6g} s apart, not one "
                f"controller period {T:g} s ({bad.size} such gap(s)): a dropped or repeated "
                "sample; the record must hold one sample per controller period"
            )
    velocity = loop.get("velocity", "backward-difference")
    if isinstance(velocity, list):
        velocity = tuple(velocity)
    tau = loop.get("delay") if delay is None else delay
    span = float(run.t[-1] - run.t[0])
    if isinstance(tau, (int, float)) and math.isfinite(tau) and tau > span:
        # a command that reaches the plant only after the record ends: nothing to fit, and
        # the simulator would hold a history of τ/T commands
        raise IdentificationError(
            f"{where}: the command delay {tau:g} s exceeds the record's length {span:g} s: "
            "the plant would not see the controller's command within the record (the delay is "
            "in s, and so is t unless the manifest's [units] t says otherwise)"
        )
    try:
        return SampledController(
            sample_time=T, P=run.P, D=run.D,
            gain=1.0 if run.gain is None else run.gain,
            command_gain=1.0 if run.command_gain is None else run.command_gain,
            velocity=velocity, cutoff=loop.get("cutoff"),
            delay=0.0 if tau is None else tau, saturation=loop.get("saturation"),
        )
    except ValueError as exc:
        # the estimator's keys are [loop]'s (the period T is this run's, from its t)
        msg = str(exc).replace("`cutoff`", "[loop] key 'cutoff'").replace(
            "`velocity`", "[loop] key 'velocity'")
        raise IdentificationError(f"{where}: {msg}") from None


def run_semantics(experiment: Any, run: Any, ctrl: SampledController) -> CommandInput | None:
    """How a run's additive input w reaches the plant (None when the run records no w): as
    ``[loop] u_contains_w`` / ``w_in_u_gain`` state, else as the record shows
    (:func:`~phoid.methods.tracking_semantics.command_input_semantics`). A ValueError names
    the run."""
    try:
        return command_input_semantics(experiment.loop, run.u, run.w, run.x, run.r, ctrl)
    except ValueError as exc:
        raise ValueError(f"run {run.index} ({run.file}): {exc}") from None


def command_input(experiment: Any, run: Any, ctrl: SampledController) -> np.ndarray | None:
    """A run's additive input w as the plant receives it, in command units: gain·w, the gain
    of :func:`run_semantics` (1 by default; 1/G with ``[loop] w_unit = "N"``, a force added to
    the plant's input like the EMPS description's ``pulses_N``; or the gain with which the
    recorded u already contains w)."""
    sem = run_semantics(experiment, run, ctrl)
    return None if sem is None else _applied(sem, run)


def _applied(sem: CommandInput, run: Any) -> np.ndarray:
    """:meth:`CommandInput.applied` on the run's w (a ValueError names the run)."""
    try:
        return sem.applied(run.w)
    except ValueError as exc:
        raise ValueError(f"run {run.index} ({run.file}): {exc}") from None


def run_records(experiment: Any, runs: Any, ctrls: Any
                ) -> tuple[tuple[TrackingRecord, ...], tuple[CommandInput | None, ...]]:
    """The runs as :class:`TrackingRecord` (w as applied, ``u_contains_w`` as stated or
    measured) and each run's :class:`CommandInput` (a ValueError names the run)."""
    records, inputs = [], []
    for r, c in zip(runs, ctrls, strict=True):
        sem = run_semantics(experiment, r, c)
        inputs.append(sem)
        records.append(TrackingRecord(
            x=r.x, r=r.r, controller=c, u=r.u, w=None if sem is None else _applied(sem, r),
            t0=float(r.t[0]), name=f"run {r.index} ({r.file})",
            u_contains_w=sem is not None and sem.contains))
    return tuple(records), tuple(inputs)


def input_warnings(records: Any, inputs: Any) -> list[str]:
    """Each run's :attr:`CommandInput.warning`, prefixed with the run."""
    return [f"{rec.name}: {sem.warning}" for rec, sem in zip(records, inputs, strict=True)
            if sem is not None and sem.warning]


def input_entries(run_names: Any, inputs: Any) -> list[dict[str, Any]] | None:
    """The ``w_in_u`` list of a summary (docs/format.md): per run that records w, ``run`` and
    :meth:`CommandInput.to_dict`; None when no run records w."""
    out = [{"run": name, **sem.to_dict()} for name, sem in zip(run_names, inputs, strict=True)
           if sem is not None]
    return out or None


# the most sub-steps per controller period that a replay accepts (below)
_MAX_STEPS_PER_PERIOD = 1000


def replay_records(records, values):
    """(simulation, validation) of each record with the parameter values given."""
    plant = Plant(m=values["m"], c=values["c"], k=values["k"], fc=values["fc"])
    out = []
    for rec in records:
        check_resolvable(rec, values)
        ctrl = rec.controller.with_delay(values["delay"])
        try:
            sim = replay(rec, plant, offset=values["offset"], controller=ctrl)
        except (OverflowError, FloatingPointError) as exc:
            raise ValueError(
                f"{rec.name}: the loop cannot be simulated with m = {values['m']:.4g} kg, c = "
                f"{values['c']:.4g} N s/m, k = {values['k']:.4g} N/m, fc = {values['fc']:.4g} N "
                f"(the arithmetic overflows: {exc}); the parameters are out of any physical "
                "range for this loop"
            ) from None
        out.append((sim, validate_run(rec, sim)))
    return out


def check_resolvable(rec: TrackingRecord, values: Mapping[str, float]) -> None:
    """A ValueError when the plant oscillates so much faster than the loop samples that the
    exact simulator, which steps each period in quarter damped periods π/(2ω_d), ω_d² = k/m −
    (c/2m)², would need more than ``_MAX_STEPS_PER_PERIOD`` steps per period (a stiffness of
    1e18 N/m on 2 kg at 1 kHz: 5·10⁵ per period, minutes per record; 1e300: never ending)."""
    T = rec.controller.sample_time
    with np.errstate(over="ignore", invalid="ignore"):
        m, c, k = np.float64(values["m"]), np.float64(values["c"]), np.float64(values["k"])
        wd2 = k / m - (c / (2.0 * m)) ** 2
        steps = 2.0 * np.sqrt(wd2) * T / math.pi if wd2 > 0 else 0.0
    if not steps <= _MAX_STEPS_PER_PERIOD:
        raise ValueError(
            f"{rec.name}: the plant with m = {values['m']:.4g} kg, c = {values['c']:.4g} N s/m, "
            f"k = {values['k']:.4g} N/m oscillates at ω_d = {math.sqrt(wd2):.4g} rad/s, "
            f"{steps:.3g} quarter periods per controller period T = {T:g} s (at most "
            f"{_MAX_STEPS_PER_PERIOD} are simulated): the parameters are out of any range this "
            "loop can show"
        )


def validate_run(rec: TrackingRecord, sim: Any) -> Any:
    """The benchmark's validation (its samples 50:end; a record shorter than 200 samples from
    its first quarter on) in the record's own sample numbering.

    The simulation starts at the record's sample s (the estimator's taps); the s samples before
    it are outside the compared window anyway (s ≤ 49 for every preset; a longer filter moves
    the window's start to s).
    """
    s = rec.start
    ctrl = rec.controller
    n = rec.x.size
    t = rec.t0 + ctrl.sample_time * np.arange(n)
    pad = np.zeros(s)
    full = SimpleNamespace(
        t=np.concatenate((t[:s], sim.t)), x=np.concatenate((rec.x[:s], sim.x)),
        v=np.concatenate((pad, sim.v)), force=np.concatenate((pad, sim.force)),
        saturated=np.concatenate((np.zeros(s, dtype=bool), sim.saturated)),
    )
    return validate_tracking(
        t, rec.x, rec.r, full, u=rec.u, w=None if rec.u is None else rec.w,
        u_contains_w=rec.u_contains_w and rec.u is not None,
        command_gain=ctrl.command_gain, saturation=ctrl.saturation,
        cutoff=min(100.0, 0.1 / ctrl.sample_time), trim=(max(min(49, n // 4), s), 0),
    )
