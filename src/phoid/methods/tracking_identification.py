r"""Identification of a tracking set (``method = "tracking"``): estimate, then validate.

A tracking set holds records of a PD-controlled axis following a reference (the EMPS
benchmark's kind of data). Two estimators, chosen by the set's ``estimator`` (or the caller):

* ``"idim"`` — inverse dynamics least squares (:func:`~phoid.methods.idim.idim_ls_runs`), the
  robotics standard, when every run records the controller's output u: the force is
  G·(u + w), or G·u where the recorded u already contains w (stated by ``[loop]
  u_contains_w`` or measured from the record: :mod:`phoid.methods.tracking_semantics`) (the
  command delayed by the loop's τ, as the plant sees it on average over a period), the
  parameters M, Fv, Fc, OF (and k unless fixed) by ordinary least squares. As in the
  published recipe, F_n is paired with q̈ at t_n although the held F_n acts on
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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from phoid._notation import unit_text
from phoid.dynamics.controller import SampledController
from phoid.errors import IdentificationError
from phoid.interop.exports import PlantExports
from phoid.io.units import unit_hint
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import difference_noise
from phoid.methods.result_base import ResultBase
from phoid.methods.tracking import (
    PARAMETERS,
    UNITS,
    TrackingRecord,
    check_stable,
    fit_tracking_runs,
)
from phoid.methods.tracking_adequacy import assess_idim, assess_output_error
from phoid.methods.tracking_delay import (
    delay_warnings,
    estimator_disagreement,
    idim_noise_hint,
    misfit_warning,
    validation_misfit,
)
from phoid.methods.tracking_replay import TrackingReplay, replay_set
from phoid.methods.tracking_runs import (
    command_input,
    input_entries,
    input_warnings,
    json_safe,
    replay_records,
    run_controller,
    run_records,
    validation_entries,
    validation_noise_ratio,
)

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
# TrackingReplay, replay_set, run_controller, command_input, validation_entries and
# validation_noise_ratio live in phoid.methods.tracking_replay and tracking_runs; they are
# re-exported here, where they were first defined


@dataclass(frozen=True, eq=False, repr=False)
class TrackingIdentification(ResultBase, PlantExports):
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
    delay_check : DelayCheck or None
        The stated (or assumed) command delay checked against the record
        (:func:`~phoid.methods.tracking_delay.check_delay`); None where the delay was estimated or
        the check was not made.
    command_inputs : tuple of CommandInput or None
        Per run, how its additive input w reached the plant — whether the recorded u already
        contains it, and with what gain, stated or measured
        (:mod:`phoid.methods.tracking_semantics`); None for a run without w.

    The base's ``warnings`` and ``adequacy`` (:mod:`phoid.methods.tracking_adequacy`: the
    estimator's residual against the record's noise and for whiteness, the halves and runs,
    the validation; where a check fails the free parameters' stderr are the robust ones,
    the white ones in ``Estimate.white_stderr``).
    """

    estimator: str
    estimates: Mapping[str, Estimate]
    delay_source: str
    fit: Any
    validations: tuple[Any, ...]
    run_names: tuple[str, ...]
    path: Path | None
    delay_check: Any = None
    command_inputs: tuple[Any, ...] = ()

    METHOD: ClassVar[str] = "tracking"
    REPORT: ClassVar[str] = "phoid.reports.tracking:identification_text"

    @property
    def validation(self) -> Any:
        """The first run's validation (the reports' default)."""
        return self.validations[0]

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict (docs/format.md, "tracking sets"): with each validation's
        ``residual_noise_ratio``, ``w_in_u`` where a run records an additive input w, and the
        ``adequacy`` block, and the ``covariance``, ``correlation`` and ``statistics`` blocks of
        :meth:`fit_statistics`."""
        fit = self.fit.summary()
        fit.pop("warnings", None)
        fit.pop("parameters", None)
        out: dict[str, Any] = {
            "method": "tracking",
            "estimator": self.estimator,
            "parameters": {k: e.to_dict() for k, e in self.estimates.items()},
            "delay_source": self.delay_source,
            "fit": fit,
            "validation": validation_entries(self.run_names, self.validations),
        }
        inputs = (input_entries(self.run_names, self.command_inputs)
                  if self.command_inputs else None)
        if inputs is not None:
            out["w_in_u"] = inputs
        return json_safe({**out, **self.summary_tail()})

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: the RMS of the validation's position residual x − x_sim over the record's
        noise level estimated without the model (:func:`validation_noise_ratio`)."""
        return [validation_noise_ratio(v) for v in self.validations]

    def statistics_of(self) -> tuple[Sequence[str], Sequence[str], np.ndarray,
                                     float | None, int | None, str]:
        """The parameters, units, covariance, χ², dof and what the fit was, for the
        ``covariance``, ``correlation`` and ``statistics`` blocks of :meth:`summary`.

        The parameters are the estimator's free ones (phoid's names ``m``, ``c``, ``k``,
        ``fc``, ``offset``, ``delay``; IDIM's ``M``, ``Fv``, ``Fc``, ``OF`` renamed) in its
        covariance's order: the covariance the estimates carry (IDIM's OLS covariance where
        every adequacy check passes, else the robust one; output error's Newey–West one). χ² is
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
            of = ("the position x − x_sim of the output-error fit over its fitted samples, each "
                  "over its run's noise level estimated from third differences")
        else:
            pairs = [(v.x[v.window[0]:v.window[1]], v.x_sim[v.window[0]:v.window[1]])
                     for v in self.validations]
            starts = 0
            of = ("the position x − x_sim of the loop simulated with the estimates (the "
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
        cov = self.fit.covariance if self.adequacy is None else self.adequacy.robust_cov
        return names, units, cov, chi2 if n else None, dof if n else None, of

    def plot(self, folder: str | Path, *, overwrite: bool = False) -> list[Path]:
        """One PNG per run (measured vs simulated, residual, force) into ``folder``."""
        from phoid.reports.tracking import plot_tracking

        folder = Path(folder)
        written = []
        for i, v in enumerate(self.validations, start=1):
            written.append(plot_tracking(v, folder / f"tracking_run{i:02d}.png",
                                         overwrite=overwrite))
        return written


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
        raise IdentificationError(f"{where}: the command delay (--delay, or `delay` in "
                                  f"Python) must be a finite number ≥ 0 s; got {delay}")
    ctrls = [run_controller(experiment, r, delay=given) for r in runs]
    warnings: list[str] = []
    idim_records: tuple[TrackingRecord, ...] = ()  # the records, once IDIM has run on them
    try:
        records, inputs = run_records(experiment, runs, ctrls)
        if choice == "idim":
            estimates, fit, source = _idim(where, records, fixed, given)
        else:
            estimates, fit, source = _output_error(where, records, fixed, given)
        idim_records = records if choice == "idim" else ()
        values = _simulable(estimates, warnings)
        # the loop as estimated (a negative c or k as it is: the message shows the estimates)
        check_stable(records, {k: e.value for k, e in estimates.items()}, "the estimates")
        validations = [v for _, v in replay_records(records, values)]
    except ValueError as exc:
        hint = _delay_hint(str(exc), delay, given, ctrls) + idim_noise_hint(idim_records)
        raise IdentificationError(f"{where}: {exc}{hint}") from None
    # the model's adequacy: IDIM's OLS warning gives way to its checks (module
    # phoid.methods.tracking_adequacy)
    names = tuple(rec.name for rec in records)
    ratios = [validation_noise_ratio(v) for v in validations]
    if choice == "idim":
        adequacy = assess_idim(fit, records, validations, ratios, values)
        own = ()
    else:
        adequacy = assess_output_error(fit, validations, ratios, values)
        own = fit.warnings
    estimates = _with_adequacy(estimates, adequacy)
    # the estimator's first, then how w reaches the plant, then the simulation's
    warnings = [*own, *input_warnings(records, inputs), *warnings]
    if source == "assumed-zero":
        warnings.append("no command delay given ([loop] delay): the validation simulates the "
                        "loop with delay 0")
    for name, v in zip((rec.name for rec in records), validations, strict=True):
        warnings += [f"{name}: {w}" for w in v.warnings]
    x_unit = str(getattr(experiment, "x_unit", "m"))
    warnings += [w for w in (_scale_mismatch(r, x_unit) for r in records) if w]
    gross = False
    for rec, v in zip(records, validations, strict=True):
        text = misfit_warning(rec.name, *validation_misfit([rec], [v]))
        if text:
            gross = True
            warnings.append(text)
    warnings += list(adequacy.warnings)
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
        validations=tuple(validations), run_names=names,
        path=getattr(experiment, "path", None), warnings=tuple(warnings),
        delay_check=checked, command_inputs=inputs, adequacy=adequacy,
        source=str(getattr(experiment, "path", "") or ""),
    )


def _with_adequacy(estimates: Mapping[str, Estimate], adequacy: Any) -> dict[str, Estimate]:
    """The estimates with the stderr the adequacy chose: where it reports robust ones, each
    free parameter's stderr is the robust one and its white one goes to ``white_stderr``
    (a parameter on a bound keeps no ±)."""
    out = dict(estimates)
    if adequacy.stderr != "robust":
        return out
    robust = np.sqrt(np.clip(np.diag(adequacy.robust_cov), 0.0, None))
    white = np.sqrt(np.clip(np.diag(adequacy.white_cov), 0.0, None))
    for i, key in enumerate(adequacy.names):
        e = out[key]
        if e.stderr is None or not math.isfinite(float(robust[i])):
            continue  # no ± (a bound), or an overflowed covariance: the white one stands
        out[key] = replace(e, stderr=float(robust[i]), white_stderr=float(white[i]))
    return out


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


def _scale_mismatch(rec: TrackingRecord, x_unit: str = "m") -> str:
    """A warning when a run's r and x differ in scale by a unit's factor, else ``""``.

    The loop makes x follow r, so the ratio ρ = rms(r − r̄)/rms(x − x̄) of the recorded
    columns (read in SI, after ``[units]``) is near 1; within a factor 2 of a unit's factor
    (10³ for mm read as m, 39.4 for in, …: :func:`phoid.io.units.unit_hint`) the two
    columns are most likely in different units. The units suggested are ``x_unit``'s
    quantity's (angles in a rotational set).
    """
    rx = float(np.std(rec.x))
    ratio = float(np.std(rec.r)) / rx if rx > 0 else math.nan
    hints = [h for h in (unit_hint("r", ratio, x_unit), unit_hint("x", 1.0 / ratio, x_unit))
             if h]
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
                            "are the signals' units and the gains right?); it is not reported "
                            "(the value stands alone)")
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
                f"{key} = {e.value:.4g}{se} {unit_text(e.unit)} is negative, which the plant model "
                f"cannot take: the validation simulates {key} = 0 (if {key} is known, give it "
                "in [fixed])"
            )
            values[key] = 0.0
    return values


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
                f"±{np.max(np.abs(rec.u)):.6g} for {flat} samples, as a saturated "
                "command does; declare the saturation ([loop] saturation) and use estimator = "
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
        # G·(u + w): the recorded u, and w unless u already contains it (counted once)
        force = ctrl.command_gain * (rec.u + (0.0 if rec.w is None or rec.u_contains_w
                                              else rec.w))
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
