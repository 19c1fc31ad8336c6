r"""Identification of a tracking set (``method = "tracking"``): estimate, then validate.

A tracking set holds records of a PD-controlled axis following a reference (the EMPS
benchmark's kind of data). Two estimators, chosen by the set's ``estimator`` (or the caller):

* ``"idim"`` — inverse dynamics least squares (:func:`~phoid.methods.idim.idim_ls_runs`), the
  robotics standard, when every run records the controller's output u: the force is
  G·(u + w) (the command delayed by the loop's τ, as the plant sees it on average over a
  period), the parameters M, Fv, Fc, OF (and k unless fixed) by ordinary least squares. As in
  the published recipe, F_n is paired with q̈ at t_n although the held F_n acts on
  [t_n, t_n+1): IDIM at τ models τ − T/2 (docs/design-notes/tracking.md);
* ``"output-error"`` — from x and r alone (:func:`~phoid.methods.tracking.fit_tracking_runs`):
  the loop simulated exactly and fitted to the recorded x, Newey–West stderrs, the delay
  estimated when the set does not give it;
* ``"auto"`` (the default) — ``"idim"`` when every run records u, else ``"output-error"``.

Either way each run is then **validated**: the loop simulated with the estimates, driven by the
recorded reference from the recorded state (:func:`~phoid.methods.tracking.replay`), compared
with the record by :func:`~phoid.methods.tracking_validation.validate_tracking` (the
benchmark's relative errors of position, tracking error, velocity and force).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from phoid.dynamics.controller import SampledController
from phoid.dynamics.plant import Plant
from phoid.errors import IdentificationError
from phoid.interop.exports import PlantExports
from phoid.io.units import unit_hint
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import difference_noise, fit_blocks, residual_noise_ratio
from phoid.methods.tracking import (
    PARAMETERS,
    UNITS,
    TrackingRecord,
    check_parameters,
    check_stable,
    fit_tracking_runs,
    replay,
)
from phoid.methods.tracking_delay import (
    delay_warnings,
    estimator_disagreement,
    idim_noise_hint,
    misfit_warning,
    validation_misfit,
)
from phoid.methods.tracking_validation import validate_tracking
from phoid.reports.display import NotebookDisplay
from phoid.reports.statistics import ratio_text

__all__ = [
    "TrackingIdentification",
    "TrackingReplay",
    "command_input",
    "identify_tracking",
    "replay_set",
    "run_controller",
    "validation_entries",
    "validation_noise_ratio",
]

ESTIMATORS = ("auto", "idim", "output-error")
_IDIM_NAMES = {"m": "M", "c": "Fv", "fc": "Fc", "offset": "OF", "k": "k"}


@dataclass(frozen=True, eq=False, repr=False)
class TrackingIdentification(PlantExports, NotebookDisplay):
    """The result of :func:`identify_tracking`.

    Attributes
    ----------
    estimator : str
        ``"idim"`` or ``"output-error"``.
    estimates : Mapping[str, Estimate]
        ``m`` (kg), ``c`` (N s/m), ``k`` (N/m), ``fc`` (N), ``offset`` (N), ``delay`` (s); a fixed
        or given parameter has stderr 0.
    delay_source : str
        ``"given"`` (manifest or caller), ``"estimated"``, ``"confounded"`` (estimated, nearly
        confounded with m) or ``"assumed-zero"`` (IDIM without a given delay: validation with 0).
    fit : IDIMFit or TrackingFit
        The estimator's own result (its statistics and warnings).
    validations : tuple of TrackingValidation
        One per run, with the estimates.
    run_names : tuple of str
    path : Path or None
        The set's manifest.
    warnings : tuple of str
    delay_check : DelayCheck or None
        The stated (or assumed) command delay checked against the record
        (:func:`~phoid.methods.tracking_delay.check_delay`); None where the delay was estimated or
        the check was not made.
    """

    estimator: str
    estimates: Mapping[str, Estimate]
    delay_source: str
    fit: Any
    validations: tuple[Any, ...]
    run_names: tuple[str, ...]
    path: Path | None
    warnings: tuple[str, ...]
    delay_check: Any = None

    @property
    def validation(self) -> Any:
        """The first run's validation (the reports' default)."""
        return self.validations[0]

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict (docs/format.md, "tracking sets"): with each validation's
        ``residual_noise_ratio`` and the ``covariance``, ``correlation`` and ``statistics``
        blocks of :meth:`fit_statistics`."""
        fit = self.fit.summary()
        fit.pop("warnings", None)
        fit.pop("parameters", None)
        return _json_safe({
            "method": "tracking",
            "estimator": self.estimator,
            "parameters": {k: e.to_dict() for k, e in self.estimates.items()},
            "delay_source": self.delay_source,
            "fit": fit,
            "validation": validation_entries(self.run_names, self.validations),
            "warnings": list(self.warnings),
            **self.fit_statistics(),
        })

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the RMS of the validation's position residual x − x_sim over the record's
        noise level estimated without the model (:func:`validation_noise_ratio`)."""
        return [validation_noise_ratio(v) for v in self.validations]

    def fit_statistics(self) -> dict[str, Any]:
        """The ``covariance``, ``correlation`` and ``statistics`` blocks of :meth:`summary`.

        The parameters are the estimator's free ones (phoid's names ``m``, ``c``, ``k``,
        ``fc``, ``offset``, ``delay``; IDIM's ``M``, ``Fv``, ``Fc``, ``OF`` renamed) in its
        covariance's order: IDIM's OLS covariance, or output error's Newey–West one. χ² is
        that of the position, Σ (x − x_sim)²/ŝ², ŝ each run's noise level from its record
        alone (:func:`~phoid.methods.fit_statistics.difference_noise`): for output error over
        the fitted samples of its own fit (x_sim: each run's loop simulated from its fitted
        start state), dof = samples − free parameters − 2 start states per run; for IDIM,
        whose own residual is a force without an independent noise level, over the
        validation's compared window (the loop simulated with the estimates from the
        recorded state), dof = samples − free parameters. Encoder quantisation and
        unmodelled dynamics make it ≫ dof on real records: it measures the model's position
        error against the sensor's noise, not the stderrs' validity (those are the
        estimator's own, see ``fit``).
        """
        inverse = {v: k for k, v in _IDIM_NAMES.items()}
        names = [inverse.get(n, n) for n in self.fit.free]
        units = [UNITS.get(n, "") for n in names]
        records = getattr(self.fit, "records", ())
        sims = getattr(self.fit, "simulations", ())
        if self.estimator == "output-error" and records and len(records) == len(sims):
            pairs = [(rec.x[rec.start:], sim.x) for rec, sim in zip(records, sims, strict=True)]
            starts = 2 * len(pairs)
            of = ("the position x - x_sim of the output-error fit over its fitted samples, each "
                  "over its run's noise level estimated from third differences")
        else:
            pairs = [(v.x[v.window[0]:v.window[1]], v.x_sim[v.window[0]:v.window[1]])
                     for v in self.validations]
            starts = 0
            of = ("the position x - x_sim of the loop simulated with the estimates (the "
                  "validation), each sample over its run's noise level estimated from third "
                  "differences")
        chi2, n = 0.0, 0
        for x, x_sim in pairs:
            q = difference_noise(x)
            if not q > 0:
                continue
            r = np.asarray(x, dtype=float) - np.asarray(x_sim, dtype=float)
            chi2 += float(r @ r) / q**2
            n += r.size
        dof = n - len(names) - starts
        return fit_blocks(names, units, self.fit.covariance, chi2 if n else None,
                          dof if n else None, of=of)

    def report(self) -> str:
        """Plain-text report: estimates ± stderr, the fit's statistics, the validation."""
        from phoid.reports.tracking import identification_text

        return identification_text(self)

    def plot(self, folder: str | Path, *, overwrite: bool = False) -> list[Path]:
        """One PNG per run (measured vs simulated, residual, force) into ``folder``."""
        from phoid.reports.tracking import plot_tracking

        folder = Path(folder)
        written = []
        for i, v in enumerate(self.validations, start=1):
            written.append(plot_tracking(v, folder / f"tracking_run{i:02d}.png",
                                         overwrite=overwrite))
        return written


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


def _json_safe(value: Any) -> Any:
    """``value`` with every float that is not finite (an overflowed statistic) as None: the
    output is strict JSON (docs/format.md, "phoid identify --json")."""
    if isinstance(value, dict):
        return {k: _json_safe(q) for k, q in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(q) for q in value]
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
        raise IdentificationError(f"{where}: {exc}") from None


def command_input(experiment: Any, run: Any, ctrl: SampledController) -> np.ndarray | None:
    """A run's additive input w in command units: as recorded, or, with ``[loop] w_unit =
    "N"`` (a force added to the plant's input, like the EMPS benchmark's ``pulses_N``), divided
    by the command gain G (F = G·(sat(u) + w/G))."""
    if run.w is None:
        return None
    if experiment.loop.get("w_unit", "command") == "N":
        return run.w / ctrl.command_gain
    return run.w


def identify_tracking(experiment: Any, *, delay: float | None = None,
                      estimator: str | None = None,
                      check_delay: bool = True) -> TrackingIdentification:
    """Identify m, c, k, f_c, f₀ (and τ) from a tracking set, and validate on every run.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A ``method = "tracking"`` set as read by :func:`phoid.io.read_experiment`.
    delay : float, optional
        Command delay τ (s), overriding ``[loop] delay``. With neither, output error estimates it
        (and refuses when the record does not determine it); IDIM validates with τ = 0.
    estimator : {"auto", "idim", "output-error"}, optional
        Overrides the set's ``estimator``.
    check_delay : bool, default True
        Check the delay given (or IDIM's assumed 0) against the record
        (:func:`~phoid.methods.tracking_delay.check_delay`: an output-error fit with the delay free,
        one more fit of the loop) and warn, naming ``[loop] delay`` or ``--delay`` and the
        delay the record implies, when it contradicts the given one.

    Returns
    -------
    TrackingIdentification

    Raises
    ------
    IdentificationError
        One line naming the set (and run): a saturated recorded command (IDIM), an unstable
        loop, a delay the record cannot determine, too short a record, …
    """
    where = str(experiment.path)
    choice = estimator or getattr(experiment, "estimator", None) or "auto"
    if choice not in ESTIMATORS:
        raise IdentificationError(f"{where}: estimator must be one of "
                                  f"{', '.join(map(repr, ESTIMATORS))}; got {choice!r}")
    runs = experiment.runs
    if choice == "auto":
        choice = "idim" if all(r.u is not None for r in runs) else "output-error"
    fixed = dict(getattr(experiment, "fixed", {}) or {})
    given = delay if delay is not None else experiment.loop.get("delay")
    if delay is not None and not (math.isfinite(delay) and delay >= 0):
        raise IdentificationError(f"{where}: --delay must be a finite number ≥ 0 s; got {delay}")
    ctrls = [run_controller(experiment, r, delay=given) for r in runs]
    warnings: list[str] = []
    idim_records: tuple[TrackingRecord, ...] = ()  # the records, once IDIM has run on them
    try:
        records = _records(experiment, runs, ctrls)
        if choice == "idim":
            estimates, fit, source = _idim(where, records, fixed, given)
        else:
            estimates, fit, source = _output_error(where, records, fixed, given)
        idim_records = records if choice == "idim" else ()
        values = _simulable(estimates, warnings)
        # the loop as estimated (a negative c or k as it is: the message shows the estimates)
        check_stable(records, {k: e.value for k, e in estimates.items()}, "the estimates")
        validations = [v for _, v in _replay_all(records, values)]
    except ValueError as exc:
        hint = _delay_hint(str(exc), delay, given, ctrls) + idim_noise_hint(idim_records)
        raise IdentificationError(f"{where}: {exc}{hint}") from None
    warnings = [*fit.warnings, *warnings]  # the estimator's first, then the simulation's
    if source == "assumed-zero":
        warnings.append("no command delay given ([loop] delay): the validation simulates the "
                        "loop with delay 0")
    for name, v in zip((rec.name for rec in records), validations, strict=True):
        warnings += [f"{name}: {w}" for w in v.warnings]
    warnings += [w for w in map(_scale_mismatch, records) if w]
    gross = False
    for rec, v in zip(records, validations, strict=True):
        text = misfit_warning(rec.name, *validation_misfit([rec], [v]))
        if text:
            gross = True
            warnings.append(text)
    checked = None
    if check_delay and source in ("given", "assumed-zero"):
        if delay is not None:
            label, fix = f"--delay {float(delay) * 1e3:g} ms", "check --delay"
        elif given is None:
            label = "[loop] delay (not given: 0 assumed)"
            fix = "give the delay as [loop] delay (s) or --delay"
        else:
            label, fix = f"[loop] delay = {float(given) * 1e3:g} ms", "check [loop] delay (s)"
        checked, text = delay_warnings(records, validations, estimates,
                                       stated=0.0 if given is None else float(given),
                                       label=label, fix=fix, fixed=fixed)
        if text is not None:
            warnings.insert(0, text)
        if checked is not None and choice == "idim" and (gross or not checked.contradicts):
            # where the delay is blamed, its warning gives the estimates with the delay free
            text = estimator_disagreement(estimates, checked.fit, gross=gross,
                                          covariance=(fit.free, fit.covariance))
            if text is not None:
                warnings.insert(1 if checked.contradicts else 0, text)
    return TrackingIdentification(
        estimator=choice, estimates=estimates, delay_source=source, fit=fit,
        validations=tuple(validations), run_names=tuple(rec.name for rec in records),
        path=getattr(experiment, "path", None), warnings=tuple(warnings),
        delay_check=checked,
    )


@dataclass(frozen=True, eq=False, repr=False)
class TrackingReplay(NotebookDisplay):
    """The result of :func:`replay_set`: each run simulated with given parameters and compared.

    Attributes
    ----------
    parameters : Mapping[str, float]
        m (kg), c (N s/m), k (N/m), fc (N), offset (N), delay (s) simulated.
    simulations : tuple of TrackingSimulation
    validations : tuple of TrackingValidation
    run_names : tuple of str
    path : Path or None
    warnings : tuple of str
    """

    parameters: Mapping[str, float]
    simulations: tuple[Any, ...]
    validations: tuple[Any, ...]
    run_names: tuple[str, ...]
    path: Path | None
    warnings: tuple[str, ...]
    _inputs: tuple[Any, ...] = ()

    @property
    def validation(self) -> Any:
        """The first run's validation."""
        return self.validations[0]

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: the parameters and each run's validation."""
        return _json_safe({
            "parameters": {k: float(v) for k, v in self.parameters.items()},
            "validation": validation_entries(self.run_names, self.validations),
            "warnings": list(self.warnings),
        })

    def report(self) -> str:
        """Plain text: the parameters and each run's relative errors."""
        from phoid.reports.tracking import validation_lines

        p = self.parameters
        lines = [f"phoid replay of {self.path}: the loop simulated with m = {p['m']:.6g} kg, "
                 f"c = {p['c']:.6g} N s/m, k = {p['k']:.6g} N/m, fc = {p['fc']:.6g} N, offset = "
                 f"{p['offset']:.6g} N, delay = {p['delay'] * 1e3:.6g} ms, driven by the "
                 "recorded reference from the recorded state"]
        for name, v in zip(self.run_names, self.validations, strict=True):
            q = validation_noise_ratio(v)
            lines += ["", f"{name}:", *validation_lines(v),
                      "  position residual / noise (noise from the record's third "
                      f"differences): {ratio_text(q)}"]
        if self.warnings:
            lines += ["", "warnings:"] + [f"  - {w}" for w in self.warnings]
        return "\n".join(lines)

    def plot(self, folder: str | Path, *, overwrite: bool = False) -> list[Path]:
        """One PNG per run (measured vs simulated, residual, force) into ``folder``."""
        from phoid.reports.tracking import plot_tracking

        folder = Path(folder)
        return [plot_tracking(v, folder / f"tracking_run{i:02d}.png", overwrite=overwrite)
                for i, v in enumerate(self.validations, start=1)]

    def write(self, folder: str | Path, *, gzip: bool = True, overwrite: bool = False) -> Path:
        """Write the simulated runs as a tracking set (``phoid/1``) into ``folder``.

        Columns t, x (simulated), r, u (the simulated command, before saturation) and w; each
        run's gains and the loop as simulated; the parameters as the table ``[simulated]``
        (with ``replay_of``, the recorded set's manifest). Returns the manifest's path.
        """
        from phoid.io import run_from_arrays, write_experiment

        runs = []
        for i, (sim, w) in enumerate(zip(self.simulations, self._inputs, strict=True), start=1):
            ctrl = sim.controller
            runs.append(run_from_arrays(sim.t, sim.x, r=sim.r, u=sim.command, w=w, P=ctrl.P,
                                        D=ctrl.D, gain=ctrl.gain, command_gain=ctrl.command_gain,
                                        index=i))
        ctrl = self.simulations[0].controller
        loop = {"sample_time": ctrl.sample_time, "delay": ctrl.delay,
                "velocity": (ctrl.velocity if isinstance(ctrl.velocity, str)
                             else list(ctrl.velocity))}
        if ctrl.cutoff is not None:
            loop["cutoff"] = ctrl.cutoff
        if ctrl.saturation is not None:
            loop["saturation"] = ctrl.saturation
        simulated = {k: float(v) for k, v in self.parameters.items()}
        if self.path is not None:
            simulated["replay_of"] = str(self.path)
        return write_experiment(folder, runs, method="tracking", loop=loop,
                                extra={"simulated": simulated}, gzip=gzip,
                                overwrite=overwrite,
                                title="phoid simulate --replay: the loop simulated with given "
                                      "parameters, driven by a recorded reference")


def replay_set(experiment: Any, parameters: Mapping[str, float]) -> TrackingReplay:
    """Simulate every run of a tracking set with given parameters and compare with the record.

    Each run's loop (its gains, the set's ``[loop]``) is driven by the recorded reference from
    the recorded state (:func:`~phoid.methods.tracking.replay`) and validated
    (:func:`~phoid.methods.tracking_validation.validate_tracking`: the benchmark's relative
    errors). Use it to validate a model identified on another record of the same axis.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        A ``method = "tracking"`` set.
    parameters : mapping
        ``m`` (kg, required), ``c`` (N s/m), ``k`` (N/m), ``fc`` (N), ``offset`` (N), each 0 when
        absent, and ``delay`` (s; absent: the set's ``[loop] delay``, else 0).

    Returns
    -------
    TrackingReplay

    Raises
    ------
    IdentificationError
        One line naming the set: an unknown parameter, a loop that diverges, …
    """
    where = str(experiment.path)
    unknown = sorted(set(parameters) - set(PARAMETERS))
    if unknown:
        raise IdentificationError(f"{where}: unknown parameter(s) {', '.join(unknown)}; the "
                                  f"parameters are {', '.join(PARAMETERS)}")
    if "m" not in parameters:
        raise IdentificationError(f"{where}: the mass m is needed to simulate the loop")
    delay = parameters.get("delay", experiment.loop.get("delay")) or 0.0
    values = {"c": 0.0, "k": 0.0, "fc": 0.0, "offset": 0.0, **parameters}
    try:
        # each value checked by name before any arithmetic (m = 0 divided in the loop's poles)
        values = check_parameters({**values, "delay": delay})
    except ValueError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
    runs = experiment.runs
    ctrls = [run_controller(experiment, r, delay=delay) for r in runs]  # errors name the run
    unstable: list[str] = []
    try:
        records = _records(experiment, runs, ctrls)
        try:
            check_stable(records, values, "these parameters")
        except ValueError as exc:  # simulated all the same: the user asked for this loop
            unstable.append(f"{exc}; the replay shows it")
        pairs = _replay_all(records, values)
    except ValueError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
    warnings = unstable + [f"{rec.name}: {w}" for rec, (_, v) in zip(records, pairs, strict=True)
                           for w in v.warnings]
    return TrackingReplay(
        parameters=values, simulations=tuple(s for s, _ in pairs),
        validations=tuple(v for _, v in pairs), run_names=tuple(r.name for r in records),
        path=getattr(experiment, "path", None), warnings=tuple(warnings),
        _inputs=tuple(None if rec.w is None else rec.w[rec.start:] for rec in records),
    )


def _delay_hint(message: str, option: float | None, given: Any, ctrls) -> str:
    """The stated delay named among the causes of a loop that is unstable or a mass that is
    not determined, when it is a sample period or more: the tracking loop's phase lag grows
    with it, and a delay the record does not have misleads both estimators (``""`` else)."""
    T = min(c.sample_time for c in ctrls)
    if given is None or not float(given) >= T or not any(
            key in message for key in ("unstable", "does not determine", "diverge")):
        return ""
    name = "--delay" if option is not None else "[loop] delay ="
    return (f"; or the command delay is wrong: {name} {float(given) * 1e3:g} ms is "
            f"{float(given) / T:.4g} controller periods (a delay the record does not have "
            "destabilises the simulated loop and biases the estimates)")


def _records(experiment, runs, ctrls) -> tuple[TrackingRecord, ...]:
    """The runs as :class:`TrackingRecord` (a ValueError names the run)."""
    return tuple(
        TrackingRecord(x=r.x, r=r.r, controller=c, u=r.u, w=command_input(experiment, r, c),
                       t0=float(r.t[0]), name=f"run {r.index} ({r.file})")
        for r, c in zip(runs, ctrls, strict=True)
    )


def _scale_mismatch(rec: TrackingRecord) -> str:
    """A warning when a run's r and x differ in scale by a unit's factor, else ``""``.

    The loop makes x follow r, so the ratio ρ = rms(r − r̄)/rms(x − x̄) of the recorded
    columns (read in SI, after ``[units]``) is near 1; within a factor 2 of a unit's factor
    (10³ for mm read as m, 39.4 for in, …: :func:`phoid.io.units.unit_hint`) the two
    columns are most likely in different units.
    """
    rx = float(np.std(rec.x))
    ratio = float(np.std(rec.r)) / rx if rx > 0 else math.nan
    hints = [h for h in (unit_hint("r", ratio), unit_hint("x", 1.0 / ratio)) if h]
    if not hints:
        return ""
    return (f"{rec.name}: the reference r varies {ratio:.3g} times as much as the position x "
            f"that tracks it: are they in the same units? ({'; or '.join(hints)}; "
            "a [units] entry already given may be the wrong one)")


def _simulable(estimates: Mapping[str, Estimate], warnings: list[str]) -> dict[str, float]:
    """The estimates' values for the validation's simulation.

    The plant model needs m > 0 and c, k, f_c ≥ 0. An estimate of m ≤ 0 is refused (the record
    does not determine the mass); a negative c, k or f_c (the least-squares value of a
    parameter near 0, or one the record does not determine) is simulated as 0, and a warning
    says so: the estimate itself is reported as it is.
    """
    values = {k: e.value for k, e in estimates.items()}
    for key, e in estimates.items():
        if e.stderr is not None and not math.isfinite(e.stderr):
            warnings.append(f"the stderr of {key} is not finite (the arithmetic overflowed: "
                            "are the signals' units and the gains right?); it is reported as "
                            "null")
    m = estimates["m"]
    if not m.value > 0:
        se = "" if m.stderr is None else f" ± {m.stderr:.3g}"
        raise ValueError(f"the estimate of the mass is m = {m.value:.4g}{se} kg, not > 0: the "
                         "record does not determine the mass (does it move, and does the "
                         "command u vary?)")
    for key in ("c", "k", "fc"):
        e = estimates[key]
        if e.value < 0:
            se = "" if e.stderr is None else f" ± {e.stderr:.3g}"
            warnings.append(
                f"{key} = {e.value:.4g}{se} {e.unit} is negative, which the plant model "
                f"cannot take: the validation simulates {key} = 0 (if {key} is known, give it "
                "in [fixed])"
            )
            values[key] = 0.0
    return values


# the most sub-steps per controller period that a replay accepts (below)
_MAX_STEPS_PER_PERIOD = 1000


def _replay_all(records, values):
    """(simulation, validation) of each record with the parameter values given."""
    plant = Plant(m=values["m"], c=values["c"], k=values["k"], fc=values["fc"])
    out = []
    for rec in records:
        _check_resolvable(rec, values)
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
        out.append((sim, _validate(rec, sim)))
    return out


def _check_resolvable(rec: TrackingRecord, values: Mapping[str, float]) -> None:
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


def _clipped(rec: TrackingRecord) -> int:
    """Samples of a recorded command u that sit on its extreme value in runs of ≥ 3 (a clipped
    command: the amplifier's limit, undeclared), or 0."""
    if rec.u is None:
        return 0
    top = float(np.max(np.abs(rec.u)))
    if top == 0.0:
        return 0
    at = np.abs(rec.u) >= top * (1.0 - 1e-9)
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate(([0], at.view(np.int8), [0])))))[::2]
    return int(np.sum(runs[runs >= 3]))


def _idim(where, records, fixed, given):
    from phoid.methods.idim import idim_ls_runs

    rows = []
    for rec in records:
        if rec.u is None:
            raise ValueError(f"{rec.name}: estimator 'idim' needs the recorded command u")
        ctrl = rec.controller
        flat = _clipped(rec) if ctrl.saturation is None else 0
        if flat:
            raise ValueError(
                f"{rec.name}: u: the recorded command sits on its extreme value "
                f"±{np.max(np.abs(rec.u)):.6g} for {flat} samples, as a saturated command "
                "does; declare the saturation ([loop] saturation) and use estimator = "
                "'output-error', which models it"
            )
        if ctrl.saturation is not None:
            clipped = int(np.sum(np.abs(rec.u) >= ctrl.saturation))
            if clipped:
                raise ValueError(
                    f"{rec.name}: u: the recorded command reaches the saturation ±"
                    f"{ctrl.saturation:g} at {clipped} sample(s), where the force is not "
                    "G·u; IDIM cannot use such a record (use estimator = 'output-error', "
                    "which models the saturation)"
                )
        force = ctrl.command_gain * (rec.u + (0.0 if rec.w is None else rec.w))
        force = _delayed(force, ctrl)
        t = rec.t0 + ctrl.sample_time * np.arange(rec.x.size)
        rows.append((t, rec.x, force))
    if not any(np.any(force) for _, _, force in rows):  # a message naming the runs and files
        names = ", ".join(rec.name for rec in records[:3]) + (", …" if len(records) > 3 else "")
        raise ValueError(f"{names}: u: the force to fit, G·(u + w), is zero at every sample (a "
                         "recorded command u of zeros?): IDIM cannot determine m, c, fc, offset")
    # the benchmark's own script's conventions (samples 50:end, std of the residual), so that
    # a published IDIM-LS is reproduced to its printed digits (design-notes/idim.md)
    fit = idim_ls_runs(rows, fixed={_IDIM_NAMES[k]: v for k, v in fixed.items()
                                    if k in _IDIM_NAMES},
                       cutoff=min(100.0, 0.1 / records[0].controller.sample_time),
                       trim=(49, 0), sigma="sample-std")
    by_name = {"m": fit.M, "c": fit.Fv, "fc": fit.Fc, "offset": fit.OF}
    by_name["k"] = fit.k if fit.k is not None else Estimate(0.0, 0.0, UNITS["k"])
    source = "given" if given is not None else "assumed-zero"
    by_name["delay"] = Estimate(0.0 if given is None else float(given), 0.0, UNITS["delay"])
    return {k: by_name[k] for k in PARAMETERS}, fit, source


def _delayed(force: np.ndarray, ctrl: SampledController) -> np.ndarray:
    """The force the plant sees on average over each period: τ = dT + φ → (φ/T)·F_{n−d−1} +
    (1 − φ/T)·F_{n−d} (the first samples repeat the first force)."""
    d, phi = ctrl.delay_split
    frac = phi / ctrl.sample_time
    pad = np.concatenate((np.full(d + 1, force[0]), force))
    now = pad[1: 1 + force.size]  # F_{n−d}
    before = pad[: force.size]  # F_{n−d−1}
    return frac * before + (1.0 - frac) * now


def _output_error(where, records, fixed, given):
    fit = fit_tracking_runs(records, fixed=fixed, estimate_delay=given is None)
    if given is None and fit.delay_status == "on-bound":
        m = fit.estimates["m"]
        raise ValueError(
            "the command delay cannot be estimated from this record: the best fit puts it on "
            f"its bound, {fit.estimates['delay'].value * 1e3:.3f} ms, where no ± exists (there, "
            f"m = {m.value:.4g} kg) — give it as [loop] delay (s) or --delay"
        )
    source = "given" if given is not None else fit.delay_status
    return dict(fit.estimates), fit, source


def _validate(rec: TrackingRecord, sim: Any) -> Any:
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
        command_gain=ctrl.command_gain, saturation=ctrl.saturation,
        cutoff=min(100.0, 0.1 / ctrl.sample_time), trim=(max(min(49, n // 4), s), 0),
    )
