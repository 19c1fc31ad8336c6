"""A tracking set's loop simulated with given parameters and compared with the record.

``phoid simulate OUT --replay SET``: every run's loop (its gains, the set's ``[loop]``, its
additive input as stated or measured: :mod:`phoid.methods.tracking_semantics`) driven by the
recorded reference from the recorded state, and validated with the benchmark's relative errors
(:mod:`phoid.methods.tracking_validation`). Use it to validate a model identified on another
record of the same axis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from phoid.errors import IdentificationError
from phoid.methods.tracking import PARAMETERS, check_parameters, check_stable
from phoid.methods.tracking_runs import (
    input_entries,
    input_warnings,
    json_safe,
    replay_records,
    run_controller,
    run_records,
    validation_entries,
    validation_noise_ratio,
)
from phoid.reports.display import NotebookDisplay
from phoid.reports.statistics import ratio_text

__all__ = ["TrackingReplay", "replay_set"]


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
    command_inputs : tuple of CommandInput or None
        Per run, how its additive input w reached the plant (stated or measured:
        :mod:`phoid.methods.tracking_semantics`); None for a run without w.
    """

    parameters: Mapping[str, float]
    simulations: tuple[Any, ...]
    validations: tuple[Any, ...]
    run_names: tuple[str, ...]
    path: Path | None
    warnings: tuple[str, ...]
    _inputs: tuple[Any, ...] = ()
    command_inputs: tuple[Any, ...] = ()

    @property
    def validation(self) -> Any:
        """The first run's validation."""
        return self.validations[0]

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: the parameters, each run's validation and, where a run records an
        additive input w, ``w_in_u`` (how w reached the plant: docs/format.md)."""
        out: dict[str, Any] = {
            "parameters": {k: float(v) for k, v in self.parameters.items()},
            "validation": validation_entries(self.run_names, self.validations),
        }
        inputs = (input_entries(self.run_names, self.command_inputs)
                  if self.command_inputs else None)
        if inputs is not None:
            out["w_in_u"] = inputs
        out["warnings"] = list(self.warnings)
        return json_safe(out)

    def report(self) -> str:
        """Plain text: the parameters and each run's relative errors (100 columns)."""
        from phoid._notation import fit_width
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
        return fit_width("\n".join(lines))

    def plot(self, folder: str | Path, *, overwrite: bool = False) -> list[Path]:
        """One PNG per run (measured vs simulated, residual, force) into ``folder``."""
        from phoid.reports.tracking import plot_tracking

        folder = Path(folder)
        return [plot_tracking(v, folder / f"tracking_run{i:02d}.png", overwrite=overwrite)
                for i, v in enumerate(self.validations, start=1)]

    def write(self, folder: str | Path, *, gzip: bool = True, overwrite: bool = False) -> Path:
        """Write the simulated runs as a tracking set (``phoid/1``) into ``folder``.

        Columns t, x (simulated), r, u (the simulated command, before saturation; holding w
        where the record's u held it) and w (as applied, command units); each run's gains and
        the loop as simulated (with ``u_contains_w``, and ``w_in_u_gain = 1``, where w is
        recorded); the parameters as the table ``[simulated]``
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
        held = {sim.w_in_command for sim, w in zip(self.simulations, self._inputs, strict=True)
                if w is not None}
        if len(held) == 1:
            # u is the simulated command (holding w, or not), w the input as applied (command
            # units): stated, so that the set reads back as it was simulated
            loop["u_contains_w"] = held.pop()
            if loop["u_contains_w"]:
                loop["w_in_u_gain"] = 1.0
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

    Each run's loop (its gains, the set's ``[loop]``, its additive input w as the manifest
    states it or the record shows it: :mod:`phoid.methods.tracking_semantics`) is driven by the
    recorded reference from the recorded state (:func:`~phoid.methods.tracking.replay`) and
    validated (:func:`~phoid.methods.tracking_validation.validate_tracking`: the benchmark's
    relative errors). Use it to validate a model identified on another record of the same axis.

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
        records, inputs = run_records(experiment, runs, ctrls)
        try:
            check_stable(records, values, "these parameters")
        except ValueError as exc:  # simulated all the same: the user asked for this loop
            unstable.append(f"{exc}; the replay shows it")
        pairs = replay_records(records, values)
    except ValueError as exc:
        raise IdentificationError(f"{where}: {exc}") from None
    warnings = unstable + input_warnings(records, inputs) + [
        f"{rec.name}: {w}" for rec, (_, v) in zip(records, pairs, strict=True)
        for w in v.warnings]
    return TrackingReplay(
        parameters=values, simulations=tuple(s for s, _ in pairs),
        validations=tuple(v for _, v in pairs), run_names=tuple(r.name for r in records),
        path=getattr(experiment, "path", None), warnings=tuple(warnings),
        _inputs=tuple(None if rec.w is None else rec.w[rec.start:] for rec in records),
        command_inputs=inputs,
    )
