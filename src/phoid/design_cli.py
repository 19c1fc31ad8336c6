"""The ``phoid design`` command: a PHO experiment's gains designed or checked, and rehearsed.

Registered in cli.py. ``--rehearse N`` identifies N simulated replicas of the schedule on a Dask
cluster (:func:`phoid.batch.rehearsal.rehearse`); the top level may import every subpackage, so
the design (``planning``) and its rehearsal (``batch``) meet here. Errors a user can cause
print one line ``phoid: error: …`` and exit with status 2.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from phoid._output import exit_with_error

__all__ = ["design"]


def _fail(message: str) -> NoReturn:
    exit_with_error(message)


def _band(text: str) -> tuple[float, float]:
    """Parse the zeta band 'lo:hi'."""
    parts = text.split(":")
    try:
        lo, hi = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"`zeta` must be a band lo:hi, e.g. 0.03:0.2; got {text!r}") from None
    return lo, hi


# the sampled loop's keywords as the command spells them (messages from the library name the
# Python keyword in backticks)
_OPTIONS = {"sample_time": "--sample-time", "delay_samples": "--delay-samples",
            "velocity": "--velocity", "cutoff": "--cutoff", "noise_in_loop": "--noise-in-loop",
            "delay_margin_samples": "--delay-margin-samples"}


def _option_words(message: str) -> str:
    """A library message in the command's words for the sampled loop's keywords."""
    import re

    from phoid.dynamics.velocity import FIR_WORDS

    # the option takes a preset's name only (no FIR coefficients)
    message = message.replace(FIR_WORDS, "")
    return re.sub(r"`(\w+)`", lambda mt: _OPTIONS.get(mt.group(1), mt.group(0)), message)


def _check_loop_options(settings: dict, delay: float | None, *, check: bool) -> None:
    """The loop's options together, refused in one line naming them (ValueError)."""
    sampled = settings.get("sample_time") is not None
    if sampled and delay is not None:
        raise ValueError("--delay (s) and --sample-time together: a sampled loop's delay is "
                         "--delay-samples, whole periods of --sample-time; give one or the "
                         "other")
    if sampled and settings.get("delay_margin") is not None:
        raise ValueError("--delay-margin (s) is a continuous loop's; a sampled loop's least "
                         "delay margin is --delay-margin-samples (whole samples)")
    if not sampled and not check:
        for key in ("delay_samples", "velocity", "cutoff", "delay_margin_samples"):
            if settings.get(key) is not None:
                raise ValueError(f"{_OPTIONS[key]} applies to a sampled loop: give its "
                                 "--sample-time (s)")
        if settings.get("noise_in_loop") is not None:
            raise ValueError("--noise-in-loop/--noise-outside apply to a sampled loop "
                             "(--sample-time): a continuous loop's prediction is the modal "
                             "bound, with the noise outside the loop")


def design(
    m: Annotated[str | None, typer.Option(
        "--m", help="Prior mass, kg: a value or a range lo:hi.")] = None,
    c: Annotated[str | None, typer.Option(
        "--c", help="Prior viscous damping, N s/m: a value or a range lo:hi.")] = None,
    k: Annotated[str | None, typer.Option(
        "--k", help="Prior stiffness, N/m: a value or a range lo:hi.")] = None,
    delay: Annotated[float | None, typer.Option(
        help="Loop delay of a continuous loop, s (with --check: default the set's).")] = None,
    sample_time: Annotated[float | None, typer.Option(
        "--sample-time", help="A sampled (digital) loop: the controller's period T, s; the "
                              "runs' modes, stability and margins are the sampled loop's, "
                              "exactly (with --check: default the set's [loop]).")] = None,
    delay_samples: Annotated[int | None, typer.Option(
        "--delay-samples", help="Sampled loop: command delay, whole periods [0].")] = None,
    velocity: Annotated[str | None, typer.Option(
        help="Sampled loop: velocity estimator, 'backward-difference', 'central-difference' "
             "or 'filtered' (with --cutoff) [backward-difference].")] = None,
    cutoff: Annotated[float | None, typer.Option(
        help="Sampled loop: cut-off of the filtered velocity, rad/s.")] = None,
    noise_in_loop: Annotated[bool | None, typer.Option(
        "--noise-in-loop/--noise-outside",
        help="Sampled loop: whether the controller reads the noisy record (predicted with the "
             "in-loop bound) or acts on the true position (the modal bound) [in the loop; "
             "with --check: the set's [loop] noise].")] = None,
    delay_margin_samples: Annotated[int | None, typer.Option(
        "--delay-margin-samples", help="Sampled loop: least delay margin, whole samples "
                                       "[max(1, 0.2 delay-samples)].")] = None,
    runs: Annotated[int, typer.Option(help="Number of runs, 2 to 1000.")] = 10,
    pmax: Annotated[float | None, typer.Option(help="Limit on |P|, N/m.")] = None,
    dmax: Annotated[float | None, typer.Option(help="Limit on |D|, N s/m.")] = None,
    max_freq: Annotated[float | None, typer.Option(
        "--max-freq", help="Highest damped frequency of a run, rad/s (rig bandwidth); "
                           "0.2 x the Nyquist rate caps it in any case.")] = None,
    fs: Annotated[float | None, typer.Option(
        help="Sample rate of the record, Hz [1000; a sampled loop 1/T, and a whole multiple "
             "of it].")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Record length after the release, s [10].")] = None,
    noise: Annotated[float | None, typer.Option(
        help="Sensor noise standard deviation, m [1e-5; with --check: measured from the "
             "set's records].")] = None,
    amplitude: Annotated[float | None, typer.Option(
        help="Release amplitude x0, m [0.01].")] = None,
    zeta: Annotated[str, typer.Option(
        help="Band of the dominant mode's damping ratio at the nominal plant, lo:hi.")
    ] = "0.03:0.2",
    min_cycles: Annotated[float, typer.Option(
        "--min-cycles", help="Fewest cycles above the noise floor within the record.")] = 5.0,
    delay_margin: Annotated[float | None, typer.Option(
        "--delay-margin", help="Continuous loop: least extra delay each loop must tolerate, s "
                               "[max(0.2 delay, 1/fs)].")] = None,
    tolerance: Annotated[float, typer.Option(
        help="Relative width of the safety checks around a prior given as one value.")
    ] = 0.1,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Write the schedule as an experiment.toml skeleton (a folder or a "
                            ".toml path) for the rig operator to fill in.")] = None,
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="Write the root locus and predicted uncertainties as PNG.")] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print one JSON object (runs, predicted, warnings) on standard output."
    )] = False,
    check_set: Annotated[Path | None, typer.Option(
        "--check", help="Evaluate the gains of an existing set or skeleton instead of "
                        "designing; without --m/--c/--k its data are identified first.")] = None,
    html: Annotated[Path | None, typer.Option(
        "--html", help="Write a single-file HTML report of the design to this path.")] = None,
    overwrite: Annotated[bool, typer.Option(
        help="Replace an existing --out, --plot or --html file.")] = False,
    rehearse: Annotated[int | None, typer.Option(
        "--rehearse", help="Simulate this many replicas of the schedule, identify them on a "
                           "Dask cluster and set their spread, bias and coverage against the "
                           "predicted stderrs (needs phoid[batch]).")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="With --rehearse: the address of a running Dask scheduler, tcp://HOST:PORT "
             "[a local cluster].")] = None,
    workers: Annotated[int | None, typer.Option(
        help="With --rehearse: worker processes of the local cluster [one per CPU]; 0 runs "
             "the replicas one after the other in this process.")] = None,
    seed: Annotated[int | None, typer.Option(
        help="With --rehearse: the root seed of the replicas' noise [drawn, and reported].")
    ] = None,
) -> None:
    """Design the gains of a PHO experiment: every run rings stably, m, c, k come out best.

    From a prior guess of the plant (each of --m, --c, --k a value or a range lo:hi), the loop
    delay and the rig's limits, proposes --runs pairs (P, D) such that, for every plant in the
    prior, each closed loop is stable with margin and rings with its damping ratio in the band,
    and prints each run's predicted sigma, omega_d, zeta, cycles above the noise floor and
    stability margins with the predicted (Cramer-Rao) standard errors of m, c, k for the given
    noise, sample rate and record length. With --sample-time T (and --delay-samples d) the loop
    is the rig's sampled one: the runs' modes are the sampled loop's, exactly, the delay margins
    are in whole samples, --fs defaults to 1/T, and the prediction is the in-loop bound (the
    controller reads the noisy record; --noise-outside for the modal bound). --out writes the
    schedule as an experiment.toml skeleton (`phoid run` runs it); --check evaluates an
    existing set's gains the same way (a digital set, such as `phoid run`'s, on its sampled
    loop) and exits with status 1 when any run is unsafe on the prior. --rehearse N simulates
    N replicas of the schedule (the nominal plant, the design's loop, noise placement, sample
    rate and record length; independent seeds spawned from --seed), identifies them on a Dask
    cluster (--scheduler, or a local cluster of --workers processes) and reports, for m, c,
    k, the predicted stderr against the replicas' SD, the mean reported stderr, the bias with
    its Monte Carlo error, RMSE/predicted and the coverage of +/-3 reported stderr.
    """
    from phoid._output import echo_text, protect_inputs, safe_text
    from phoid.batch.sets import set_files
    from phoid.planning import check_experiment
    from phoid.planning import design as make_design

    try:
        # no output (--plot, --html) may replace the checked set's files
        inputs = set_files(check_set) if check_set is not None else []
        with protect_inputs(inputs):
            settings = {key: val for key, val in {
                "fs": fs, "duration": duration, "noise": noise, "amplitude": amplitude,
                "pmax": pmax, "dmax": dmax, "max_freq": max_freq, "delay_margin": delay_margin,
                "sample_time": sample_time, "delay_samples": delay_samples,
                "velocity": velocity, "cutoff": cutoff, "noise_in_loop": noise_in_loop,
                "delay_margin_samples": delay_margin_samples,
            }.items() if val is not None}
            _check_loop_options(settings, delay, check=check_set is not None)
            settings.update(zeta=_band(zeta), min_cycles=min_cycles, tolerance=tolerance)
            if check_set is not None and out is not None:
                raise ValueError("`--out` writes a designed schedule; it cannot be used with "
                                 "--check")
            if out is not None or plot is not None:  # files in the way: refused before the work
                from phoid._output import OutputFolder
                from phoid.planning import schedule_target

                if out is not None:
                    schedule_target(out, overwrite=overwrite)
                if plot is not None:
                    OutputFolder(plot.parent, overwrite=overwrite).check([plot.name])
            stray = [name for name, val in (("--scheduler", scheduler), ("--workers", workers),
                                            ("--seed", seed)) if val is not None]
            if rehearse is None and stray:
                raise ValueError(f"{stray[0]} applies to --rehearse only")
            if rehearse is not None:
                from phoid.batch.cluster import require_batch
                from phoid.batch.rehearsal import MAX_REPLICAS

                if not 2 <= rehearse <= MAX_REPLICAS:
                    raise ValueError(f"--rehearse must be from 2 to {MAX_REPLICAS} replicas; "
                                     f"got {rehearse}")
                require_batch("design --rehearse")
            if html is not None:
                from phoid.reports.html import check_report_target

                check_report_target(html, overwrite=overwrite, figures=plot)
            if check_set is not None:
                result = check_experiment(check_set, m, c, k, delay=delay, **settings)
            else:
                missing = [f"--{n}" for n, val in (("m", m), ("c", c), ("k", k)) if val is None]
                if missing:
                    raise ValueError(f"give the prior plant: {', '.join(missing)} missing "
                                     "(a value or a range lo:hi each)")
                if delay is None and sample_time is None:
                    raise ValueError("give the loop: --delay (s) for a continuous loop, or "
                                     "--sample-time (s) and --delay-samples for a sampled one")
                from phoid.planning import MAX_RUNS

                if not 2 <= runs <= MAX_RUNS:
                    raise ValueError(f"--runs must be from 2 to {MAX_RUNS} (the design's work and "
                                     f"memory grow with the runs); got {runs}")
                result = make_design(m, c, k, delay=delay, runs=runs, **settings)
            rehearsal = None
            if rehearse is not None:
                from phoid.batch.cluster import cluster_client
                from phoid.batch.rehearsal import rehearse as run_rehearsal

                if scheduler is None and workers == 0:  # as `phoid batch --workers 0`
                    rehearsal = run_rehearsal(result, rehearse, client=None, seed=seed)
                else:
                    with cluster_client(scheduler, workers) as client:
                        rehearsal = run_rehearsal(result, rehearse, client=client, seed=seed)
            written = result.write(out, overwrite=overwrite) if out is not None else None
            if plot is not None:
                import matplotlib.pyplot as plt

                plt.close(result.plot(plot, overwrite=overwrite))
            if html is not None:  # a checked set: its manifest's checksum (a skeleton has no data)
                from phoid.reports.html import write_report

                write_report(result, html, overwrite=overwrite, inputs=inputs[:1])
    except (ValueError, OSError) as exc:
        _fail(_option_words(str(exc)))
    if as_json:
        summary = result.summary()
        if rehearsal is not None:
            summary["rehearsal"] = rehearsal.summary()
        typer.echo(json.dumps(summary, indent=1))
        for w in (*result.warnings, *(rehearsal.warnings if rehearsal is not None else ())):
            echo_text(f"phoid: warning: {safe_text(w)}", err=True, wrap=False)
    else:
        echo_text(result.report)
        if rehearsal is not None:
            echo_text(lambda: "\n" + rehearsal.report())
    if written is not None:
        echo_text(f"schedule written to {written}", err=as_json, wrap=False)
    if plot is not None:
        echo_text(f"figure written to {plot}", err=as_json, wrap=False)
    if html is not None:
        echo_text(f"report written to {html}", err=as_json, wrap=False)
    if check_set is not None and not result.safe:
        # a check that finds a run unsafe must fail a script that runs it before the rig does
        typer.echo("phoid: some runs are unsafe on the prior (see UNSAFE above)", err=True)
        raise typer.Exit(1)

