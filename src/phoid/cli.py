"""The ``phoid`` command line: a thin shell over the public functions.

Every error a user can cause (bad files, bad parameters, data that cannot determine the answer)
is printed as one line on standard error with exit status 2; never a traceback.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from phoid import __version__
from phoid._output import echo_text, exit_with_error

app = typer.Typer(
    name="phoid",
    help=(
        "Identify the mass m, viscous damping c and stiffness k of second-order systems - even "
        "ones so overdamped they never oscillate on their own - by parametric harmonic "
        "oscillation: close a PD loop with known gains (and a known or measured delay) around "
        "the plant, record each run's free decay, and phoid turns the decays into m, c, k with "
        "honest uncertainties."
    ),
    add_completion=False,
    # click's plain help, not typer's rich panels: the panels print every option's type,
    # flags too (`--json <bool>`), and keep the docstrings' line breaks inside their boxes;
    # the plain help names a flag bare, a value's type once (`--delay <float>`), and rewraps
    # the text to the terminal
    rich_markup_mode=None,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _fail(message: str) -> NoReturn:
    exit_with_error(message)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"phoid {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    ctx: typer.Context,
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True,
                           help="Print the version and exit.")
    ] = False,
) -> None:
    """phoid: identify m, c, k of second-order systems by parametric harmonic oscillation."""
    from phoid._output import cli_wording

    # a file in the way: the messages name the CLI's --overwrite, not the Python keyword
    ctx.with_resource(cli_wording())


@app.command()
def paper(
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Folder for the Figure 1 PNG files (created if needed).")
    ] = Path("phoid-out"),
    overwrite: Annotated[bool, typer.Option(
        help="Replace existing figure1a.png and figure1b.png in --out.")] = False,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print the numbers as one JSON object on standard output instead of the "
                       "table (figures are still written).")
    ] = False,
    duration: Annotated[float, typer.Option(help="Record length after release, s.")] = 15.0,
    fs: Annotated[float, typer.Option(help="Sample rate, Hz.")] = 1000.0,
) -> None:
    """Reproduce the seed paper's Table 1 and Figure 1.

    Simulates the paper's experiment (m = 2 kg, c = 1 N s/m, k = 64 N/m, loop delay 0.1 s,
    19 runs with P = 0.25 + 1.375 i N/m and D = 0.6 + 0.3 i N s/m), measures each run's decay,
    and identifies m, c, k from the straight lines of eq. (35) with and without compensating the
    delay. Prints Table 1 next to the paper's numbers and writes Figure 1(a) (c' against 2 sigma)
    and 1(b) (k' against omega0^2) as PNG files into --out.
    """
    from phoid.paper import reproduce_table1
    from phoid.reports.figures import figure1

    try:
        from phoid._output import OutputFolder

        OutputFolder(out, overwrite=overwrite).check(["figure1a.png", "figure1b.png"])
        result = reproduce_table1(duration=duration, fs=fs)
        fa, fb = figure1(result, out, overwrite=overwrite)
    except (ValueError, OSError) as exc:
        _fail(_in_option_words(str(exc)))  # `fs` → --fs, `duration` → --duration
    if as_json:
        summary = result.summary()
        summary["figures"] = [str(fa), str(fb)]
        typer.echo(json.dumps(summary, indent=1))
        typer.echo(f"figures written to {fa} and {fb}", err=True)
    else:
        echo_text(result.table)
        echo_text(f"\nFigure 1(a) written to {fa}\nFigure 1(b) written to {fb}", wrap=False)


@app.command()
def identify(
    experiment: Annotated[Path, typer.Argument(
        help="Experiment set: a folder with experiment.toml (format phoid/1), or the manifest.")],
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print the result as one JSON object (the phoid/1 spec) on standard "
                       "output; warnings also go to standard error.")] = False,
    plots: Annotated[Path | None, typer.Option(
        "--plots", help="Write figures as PNG files into this folder: per run <stem>.png "
                        "(record, fit, noise band, residual and its autocorrelation, recorded "
                        "force; with --friction the stick intervals), lines.png (the eq. (35) "
                        "or eq. (20) lines, residuals in stderr units), mk-ellipse.png.")] = None,
    estimator: Annotated[str | None, typer.Option(
        help="pho: 'gls', weighted fit of m, c, k through the exact loop roots (efficient, "
             "default), or 'ols', the paper's eq. (35) lines by ordinary least squares. "
             "tracking: 'idim' (inverse dynamics least squares on the recorded command), "
             "'output-error' (x and r only, through the simulated loop) or 'auto' (default: "
             "the manifest's estimator).")] = None,
    delay: Annotated[float | None, typer.Option(
        help="Loop delay in s, overriding the manifest's [loop] delay (tracking: the command "
             "delay).")] = None,
    no_compensation: Annotated[bool, typer.Option(
        "--no-compensation", help="Ignore the loop delay (the paper's uncompensated column; "
                                  "only with --estimator ols).")] = False,
    mass: Annotated[float | None, typer.Option(
        "--mass", help="Known mass, kg, for a free-decay set (overrides the manifest's "
                       "`mass`): c and k are then given too.")] = None,
    friction: Annotated[bool, typer.Option(
        "--friction", help="pho: fit Coulomb friction f_c too (JSON key fc), by a full-record "
                           "fit through the stick-slip simulator (seconds, not milliseconds; "
                           "the loop delay must be known). free: a decay with Coulomb and "
                           "viscous friction and its stop (fc_over_m; fc with --mass).")] = False,
    noise: Annotated[str | None, typer.Option(
        "--noise", help="pho: where the sensor noise enters. 'in-loop': the controller reads "
                        "the recorded position (a digital rig), m, c, k from the output error "
                        "of the plant driven by the applied force; 'outside': from the runs' "
                        "modes; 'auto' (default): the manifest's [loop] noise, else chosen by "
                        "the data (digital loops).")] = None,
    html: Annotated[Path | None, typer.Option(
        "--html", help="Write a single-file HTML report (summary, runs, figures, environment, "
                       "SHA-256 of the input files) to this path.")] = None,
    overwrite: Annotated[bool, typer.Option(
        help="Replace existing figures in --plots and an existing --html file.")] = False,
) -> None:
    """Identify m, c, k (with standard errors) from a recorded experiment set.

    The set's method decides how: "pho" (below), "forced" (a sine sweep: R and rho per
    frequency, then m, c, k from eq. 20), "free" (free releases: sigma, omega0, zeta, the two
    roots, c/m and k/m; c and k too with --mass) or "tracking" (a PD loop following a
    reference: m, c, k, fc, the offset force and the command delay by IDIM-LS or output error,
    then every run validated against its simulation).

    Each run's free decay is fitted for its dominant mode (decay rate sigma and damped frequency
    omega_d with their uncertainty); the delay-corrected modes of all runs then give m, c, k.
    Prints the estimates with +/- one standard error and units, the open-loop zeta and omega0,
    a per-run table and any warnings.
    """
    from phoid._output import protect_inputs
    from phoid.batch.sets import set_files
    from phoid.io import read_experiment
    from phoid.methods.dispatch import identify_set

    try:
        # no output (--html, --plots) may replace the set's own files, even with --overwrite
        with protect_inputs(set_files(experiment)):
            if html is not None:  # a file in the way: refused before the work
                from phoid.reports.html import check_report_target

                check_report_target(html, overwrite=overwrite, figures=plots)
            exp = read_experiment(experiment)
            with protect_inputs(_experiment_files(exp)):
                result = identify_set(exp, estimator=estimator, delay=delay, mass=mass,
                                      no_compensation=no_compensation, friction=friction,
                                      noise=noise)
                written = result.plot(plots, overwrite=overwrite) if plots is not None else []
                # the figures just written to --plots are embedded, not drawn again
                _write_html(result, html, exp, overwrite,
                            figures=written if plots is not None else True)
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    _print_result(result, as_json, written, plots, html)


def _experiment_files(experiment) -> list[Path]:
    """The manifest and data files of a set as read (``path``, ``runs[i].file``)."""
    if getattr(experiment, "path", None) is None:
        return []
    folder = Path(experiment.path).parent
    return [Path(experiment.path), *(folder / r.file for r in experiment.runs
                                     if getattr(r, "file", ""))]


def _write_html(result, html: Path | None, experiment, overwrite: bool,
                figures=True) -> None:
    """--html: the single-file report, with the checksums of the set's files (``figures``:
    see :func:`phoid.reports.html.report_html`)."""
    if html is not None:
        from phoid.reports.html import write_report

        write_report(result, html, experiment=experiment, overwrite=overwrite,
                     figures=figures)


def _print_result(result, as_json: bool, written, plots, html=None) -> None:
    """The result as JSON (warnings also on stderr) or as the text report; figures written."""
    from phoid._output import safe_text

    if as_json:  # JSON escapes its unicode itself
        typer.echo(json.dumps(result.summary(), indent=1))
        for w in result.warnings:
            echo_text(f"phoid: warning: {safe_text(w)}", err=True, wrap=False)
    else:  # the report's own fields are escaped; this catches any other control character
        echo_text(result.report)
    if written:
        echo_text(f"{len(written)} figure{'s' * (len(written) != 1)} written to {plots}",
                  err=as_json, wrap=False)
    if html is not None:
        echo_text(f"report written to {html}", err=as_json, wrap=False)


_REPLAY_OPTIONS = {"out", "m", "c", "k", "fc", "offset_force", "delay", "gzip", "overwrite",
                   "plots", "as_json", "replay"}


def _simulate_replay(ctx, out, replay, *, m, c, k, fc, offset_force, delay, gzip, overwrite,
                     plots, as_json) -> None:
    """``phoid simulate OUT --replay SET``: the set's loop with given parameters, validated."""
    from phoid.io import read_experiment
    from phoid.methods.tracking import check_parameters
    from phoid.methods.tracking_identification import replay_set

    def given(name: str) -> bool:
        return getattr(ctx.get_parameter_source(name), "name", "") != "DEFAULT"

    stray = sorted(n for n in ctx.params if given(n) and n not in _REPLAY_OPTIONS)
    if stray:
        _fail(f"--{stray[0].replace('_', '-')} does not apply to --replay (the recorded set "
              "gives the loop, the reference and the timing)")
    if not given("m"):
        _fail("--replay needs the mass: give --m (and --c, --k, --fc, --offset-force, which "
              "are 0 when not given)")
    params = {"m": m, "c": c if given("c") else 0.0, "k": k if given("k") else 0.0,
              "fc": fc if given("fc") else 0.0, "offset": offset_force}
    if given("delay"):
        params["delay"] = delay
    written = []
    try:
        exp = read_experiment(replay)
        if exp.method != "tracking":
            raise ValueError(f"{exp.path}: --replay needs a tracking set (method = "
                             f"\"tracking\"); this one is {exp.method!r}")
        # every option by name before the loop divides by it (--m 0) or takes its exponential
        # (--c inf): one line naming the option and the set
        for option, key in (("--m", "m"), ("--c", "c"), ("--k", "k"), ("--fc", "fc"),
                            ("--offset-force", "offset"), ("--delay", "delay")):
            if key in params:
                try:
                    check_parameters({"m": 1.0, "c": 0.0, "k": 0.0, "fc": 0.0,
                                      key: params[key]})
                except ValueError as exc:
                    raise ValueError(f"{exp.path}: {option} {params[key]:g}: {exc}") from None
        if exp.path is not None and Path(out).resolve() == Path(exp.path).parent.resolve():
            # --overwrite there would replace the recording with its own simulation
            raise ValueError(f"{out}: is the folder of the replayed set {exp.path}; write the "
                             "simulated set to another folder")
        result = replay_set(exp, params)
        manifest = result.write(out, gzip=gzip, overwrite=overwrite)
        if plots is not None:
            written = result.plot(plots, overwrite=overwrite)
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    _print_result(result, as_json, written, plots)
    echo_text(f"simulated set written to {manifest}", err=as_json, wrap=False)


# the largest magnitude (and the smallest non-zero one) a number given to `simulate` may have,
# in SI units: nothing on a rig is 1e30 kg or 1e-30 s, and within these bounds the simulator's
# products and ratios of a few options (rates (c + D)/m, (k + P)/m and their squares) stay
# inside the floating-point range, where its own limits (samples, steps) can refuse them
_MAGNITUDE = 1e30


def _number(option: str, value: float, unit: str, sign: str = "any") -> float:
    """Check one number of ``simulate`` by its option: finite, of the sign ``sign`` ('> 0',
    '≥ 0' or 'any') and of magnitude 0 or 1e-30 … 1e30 (ValueError naming the option)."""
    u = f" {unit}" if unit else ""
    if not math.isfinite(value):
        raise ValueError(f"{option} must be a finite number{u}; got {value:g}")
    if sign == "> 0" and not value > 0:
        raise ValueError(f"{option} must be > 0{u}; got {value:g}")
    if sign == "≥ 0" and value < 0:
        raise ValueError(f"{option} must be ≥ 0{u}; got {value:g}")
    if value != 0 and not 1 / _MAGNITUDE <= abs(value) <= _MAGNITUDE:
        zero = "" if sign == "> 0" else "0 or "
        raise ValueError(f"{option} must be {zero}of magnitude {1 / _MAGNITUDE:g} … "
                         f"{_MAGNITUDE:g}{u} (SI units); got {value:g}")
    return float(value)


def _numbers(option: str, text: str, unit: str, sign: str = "any") -> list[float]:
    """Parse '1,2,3' or 'start:stop:count' (inclusive linspace) into floats, each checked by
    :func:`_number`; the count is checked against MAX_RUNS before any list is built."""
    import numpy as np

    from phoid.io import MAX_RUNS

    form = f"{option} must be comma-separated numbers or start:stop:count"
    text = text.strip()
    parts = text.split(":") if ":" in text else text.split(",")
    if ":" in text and len(parts) != 3:
        raise ValueError(f"{form}; got {text[:40]!r}")
    if len(parts) > MAX_RUNS:  # (the text itself is bounded by the command line)
        raise ValueError(f"{option} gives {len(parts):,} values; a set holds at most "
                         f"{MAX_RUNS:,} runs (MAX_RUNS)")
    values = []
    for i, part in enumerate(parts):
        if not part.strip():
            raise ValueError(f"{form}; got {text[:40]!r} (value {i + 1} is empty)")
        try:
            values.append(int(part) if ":" in text and i == 2 else float(part))
        except ValueError:
            raise ValueError(f"{form}; got {text[:40]!r} ({part.strip()[:20]!r} is not "
                             f"{'a whole count' if ':' in text and i == 2 else 'a number'})"
                             ) from None
    if ":" in text:
        a, b, n = values
        if not 1 <= n <= MAX_RUNS:
            raise ValueError(f"{option} {text[:40]}: the count must be 1 … {MAX_RUNS:,} (a set "
                             f"holds at most {MAX_RUNS:,} runs, MAX_RUNS); got {n}")
        for end in (a, b):
            _number(option, end, unit, sign)
        values = _decimal_steps(np.linspace(a, b, n).tolist())
    for val in values:
        _number(option, val, unit, sign)
    return values


def _decimal_steps(values: list[float]) -> list[float]:
    """The inner values of a start:stop:count range as the decimals it means: each the shortest
    decimal within 4 ulp of the binary step (0.6:6:19 gives 0.9, not 0.8999999999999999;
    11.666666666666666 of 5:25:4 has none and stays); the ends exactly as given."""

    def short(v: float) -> float:
        return next((d for d in (float(f"{v:.{n}g}") for n in range(1, 16))
                     if abs(d - v) <= 4 * math.ulp(v)), v)

    return [v if i in (0, len(values) - 1) else short(v) for i, v in enumerate(values)]


# simulate's numeric options: (parameter, option, unit, sign)
_SIMULATE_NUMBERS = (
    ("m", "--m", "kg", "> 0"), ("c", "--c", "N s/m", "any"), ("k", "--k", "N/m", "any"),
    ("fc", "--fc", "N", "≥ 0"), ("delay", "--delay", "s", "≥ 0"),
    ("duration", "--duration", "s", "> 0"), ("fs", "--fs", "Hz", "> 0"),
    ("x0", "--x0", "m", "any"), ("hold", "--hold", "s", "≥ 0"), ("noise", "--noise", "m", "≥ 0"),
    ("quantum", "--quantum", "m", "≥ 0"), ("offset", "--offset", "m", "any"),
    ("u_noise", "--u-noise", "N", "≥ 0"), ("sample_time", "--sample-time", "s", "> 0"),
    ("cutoff", "--cutoff", "rad/s", "> 0"), ("B", "--B", "N", "any"),
    ("v0", "--v0", "m/s", "any"), ("offset_force", "--offset-force", "N", "any"),
)
_OPTION_OF = {name: option for name, option, _u, _s in _SIMULATE_NUMBERS} | {
    "P": "--P", "D": "--D", "bias": "--bias", "omega": "--omega",
    "delay_samples": "--delay-samples", "velocity": "--velocity", "seed": "--seed",
    "noise_in_loop": "--noise-in-loop"}


def _check_simulate_options(params: dict) -> None:
    """Every number of ``simulate`` by its option, before anything is built (ValueError)."""
    for name, option, unit, sign in _SIMULATE_NUMBERS:
        if params.get(name) is not None:
            _number(option, params[name], unit, sign)
    seed = params.get("seed")
    if seed is not None and not 0 <= seed < 2**63:
        raise ValueError(f"--seed must be a whole number 0 … 2^63 − 1; got {seed}")
    d = params.get("delay_samples", 0)
    if not 0 <= d < 2**63:
        raise ValueError(f"--delay-samples must be a whole number ≥ 0; got {d}")


def _in_option_words(message: str) -> str:
    """A simulator's message in the command's words: `fs` → --fs, `sample_time` →
    --sample-time (the keyword arguments it names are the options)."""
    import re

    from phoid.dynamics.velocity import FIR_WORDS

    message = message.replace("noise_in_loop=False", "--noise-outside")
    # the option takes a preset's name only (no FIR coefficients)
    message = message.replace(FIR_WORDS, "")
    return re.sub(r"`(\w+)`", lambda mt: _OPTION_OF.get(mt.group(1), mt.group(0)), message)


@app.command()
def simulate(
    ctx: typer.Context,
    out: Annotated[Path, typer.Argument(help="Folder to write the experiment set into.")],
    m: Annotated[float, typer.Option("--m", help="Mass, kg.")] = 2.0,
    c: Annotated[float, typer.Option("--c", help="Viscous damping, N s/m.")] = 1.0,
    k: Annotated[float, typer.Option("--k", help="Stiffness, N/m.")] = 64.0,
    fc: Annotated[float, typer.Option("--fc", help="Coulomb friction force, N.")] = 0.0,
    P: Annotated[str, typer.Option(
        "--P", help="Proportional gains, N/m: '1,2,3' or start:stop:count. Default: the "
                    "paper's Table 1 sweep.")] = "0.25:25:19",
    D: Annotated[str, typer.Option(
        "--D", help="Derivative gains, N s/m, paired with --P (same count, or one value for "
                    "all runs).")] = "0.6:6:19",
    bias: Annotated[str, typer.Option(
        "--bias", help="pho: DC offset b >= 0 of the command in the direction of the "
                       "controller's velocity, N (u += b sign(x'(t - delay))): one value for "
                       "all runs, or one per run ('0.1,0.12' or start:stop:count); written as "
                       "each run's `bias`.")] = "0",
    schedule: Annotated[Path | None, typer.Option(
        "--schedule", help="Take the runs (P, D, file names) and, unless given here, the delay, "
                           "--fs, --duration, --noise and --x0 from a schedule written by "
                           "`phoid design --out` (instead of --P/--D).")] = None,
    delay: Annotated[float, typer.Option(help="Loop delay, s.")] = 0.1,
    duration: Annotated[float, typer.Option(
        help="Record length after release, s. Limit: runs x (hold + duration) x fs at most "
             "5e7 samples (about 3 GB).")] = 15.0,
    fs: Annotated[float, typer.Option(
        help="Sample rate, Hz (see --duration for the size limit).")] = 1000.0,
    x0: Annotated[float, typer.Option(help="Release position, m.")] = 0.01,
    hold: Annotated[float, typer.Option(
        help="Held segment before the release (controller on), s.")] = 0.2,
    noise: Annotated[float, typer.Option(help="Sensor noise standard deviation, m.")] = 0.0,
    quantum: Annotated[float, typer.Option(
        help="Encoder quantisation step, m (0: none).")] = 0.0,
    offset: Annotated[float, typer.Option(help="Constant sensor offset, m.")] = 0.0,
    noise_in_loop: Annotated[bool, typer.Option(
        "--noise-in-loop",
        help="pho: whether the controller reads the recorded position (--offset, --noise and "
             "--quantum inside the loop, as on a rig: the recorded x at each controller "
             "instant is what it read) or the exact one (the sensor's error added to the "
             "record only). Default: in the loop for a digital loop (--sample-time), outside "
             "for the continuous one (which, in the loop, needs --delay and --hold in whole "
             "samples and takes no --fc, --bias or --quantum). A digital loop with --noise or "
             "--quantum writes it as [loop] noise = \"in-loop\" or \"outside\".")] = False,
    noise_outside: Annotated[bool, typer.Option(
        "--noise-outside",
        help="pho: the controller reads the exact position; the sensor's error is added to "
             "the record only (the opposite of --noise-in-loop; give one of them).")] = False,
    u_noise: Annotated[float, typer.Option(
        "--u-noise", help="pho: white-noise standard deviation on the recorded force u, N.")
    ] = 0.0,
    seed: Annotated[int | None, typer.Option(help="Random seed for the noise.")] = None,
    omit_delay: Annotated[bool, typer.Option(
        "--omit-delay", help="Do not write [loop] delay into the manifest (to rehearse "
                             "estimating it).")] = False,
    sample_time: Annotated[float | None, typer.Option(
        "--sample-time", help="pho: a digital controller sampling x every SAMPLE_TIME s "
                              "(zero-order hold; --fs a whole multiple of its rate); the "
                              "delay is then --delay-samples whole periods, not --delay.")
    ] = None,
    delay_samples: Annotated[int, typer.Option(
        "--delay-samples", help="digital: periods between sampling and applying the command.")
    ] = 0,
    velocity: Annotated[str, typer.Option(
        help="digital: velocity estimator, 'backward-difference' or 'filtered' (with "
             "--cutoff).")] = "backward-difference",
    cutoff: Annotated[float | None, typer.Option(
        help="digital: cut-off of the filtered velocity, rad/s.")] = None,
    gzip: Annotated[bool, typer.Option(help="Compress the data files (.csv.gz).")] = True,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing set in OUT.")] = False,
    method: Annotated[str, typer.Option(
        "--method", help="'pho' (PD loop, default), 'forced' (a sine sweep, no loop: one run "
                         "per --omega, column F) or 'free' (one free release, no loop).")
    ] = "pho",
    B: Annotated[float, typer.Option(
        "--B", help="forced: force amplitude, N.")] = 1.0,
    omega: Annotated[str, typer.Option(
        "--omega", help="forced: forcing frequencies, rad/s: '2,5,9' or start:stop:count.")
    ] = "2:14:8",
    v0: Annotated[float, typer.Option(
        "--v0", help="free: velocity given at the release, m/s.")] = 0.0,
    write_mass: Annotated[bool, typer.Option(
        "--write-mass", help="free: write the mass into the manifest as the known mass.")
    ] = False,
    replay: Annotated[Path | None, typer.Option(
        "--replay", help="A recorded tracking set: simulate its loop with --m, --c, --k, --fc, "
                         "--offset-force (and --delay, else the set's) driven by each run's "
                         "recorded reference from its recorded state, write the simulated "
                         "set into OUT and print the benchmark's relative errors against the "
                         "record (position, tracking error, velocity, force).")] = None,
    offset_force: Annotated[float, typer.Option(
        "--offset-force", help="--replay: constant offset force f0 of the plant, N "
                               "(m x'' + c x' + k x + fc sign(x') + f0 = F).")] = 0.0,
    plots: Annotated[Path | None, typer.Option(
        "--plots", help="--replay: write measured-vs-simulated figures (PNG) into this "
                        "folder.")] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", help="--replay: print the validation as one JSON object.")] = False,
) -> None:
    """Simulate a PHO experiment and write it as a phoid/1 experiment set.

    With --method forced: the plant (no loop) rests for --hold seconds (at --x0 if given, else
    at 0), then F = B sin(omega (t - hold)) acts; one run per --omega, columns t, x, F. With
    --method free: the plant is held at --x0 for --hold seconds and released (with --v0); one
    run, columns t, x.

    The plant m x'' + c x' + k x + fc sign(x') = u runs under u = -[D x'(t - delay) +
    P x(t - delay)] (+ bias sign(x'(t - delay)) with --bias), held at x0 for --hold seconds
    with the controller on, then released; the recorded position gets the offset, white noise
    and quantisation asked for, which the controller reads too with --noise-in-loop (the
    default for a digital loop, --sample-time). Columns t, x and the applied feedback force u
    (with --u-noise: plus white noise of that sd, N, as a force sensor would record it). Use
    it to rehearse an experiment or to build test fixtures; --schedule rehearses a schedule
    written by `phoid design --out` (same runs and file names).
    """
    import numpy as np

    from phoid._output import protect_inputs
    from phoid.dynamics.plant import Plant
    from phoid.io import run_from_arrays, write_experiment
    from phoid.simulation import simulate as _simulate

    if noise_in_loop and noise_outside:
        _fail("--noise-in-loop and --noise-outside contradict each other: give one of them")
    placement = True if noise_in_loop else (False if noise_outside else None)
    try:
        _check_simulate_options(ctx.params)
    except ValueError as exc:
        _fail(str(exc))
    if replay is not None:
        _simulate_replay(ctx, out, replay, m=m, c=c, k=k, fc=fc, offset_force=offset_force,
                         delay=delay, gzip=gzip, overwrite=overwrite, plots=plots,
                         as_json=as_json)
        return
    for flag, given in (("--offset-force", offset_force != 0.0), ("--plots", plots is not None),
                        ("--json", as_json)):
        if given:
            _fail(f"{flag} applies to --replay only")
    if method != "pho":
        if u_noise:
            _fail("--u-noise applies to --method pho only (the other methods record no u)")
        _simulate_other(ctx, out, method=method, m=m, c=c, k=k, fc=fc, B=B, omega=omega,
                        duration=duration, fs=fs, x0=x0, v0=v0, hold=hold, noise=noise,
                        quantum=quantum, offset=offset, seed=seed, write_mass=write_mass,
                        gzip=gzip, overwrite=overwrite)
        return
    try:
        given = {n for n in ("B", "omega", "v0", "write_mass")
                 if getattr(ctx.get_parameter_source(n), "name", "") != "DEFAULT"}
        if given:
            raise ValueError(f"--{sorted(given)[0].replace('_', '-')} does not apply to "
                             "--method pho")
        names = None
        if schedule is not None:
            from phoid.planning import read_schedule

            given = {n for n in ("P", "D", "delay", "fs", "duration", "noise", "x0")
                     if getattr(ctx.get_parameter_source(n), "name", "") != "DEFAULT"}
            if given & {"P", "D"}:
                raise ValueError("give either --schedule or --P/--D, not both")
            sched = read_schedule(schedule)
            P = ",".join(map(repr, sched["P"].tolist()))
            D = ",".join(map(repr, sched["D"].tolist()))
            names = sched["files"]
            if "delay" not in given and sched["delay"] is not None:
                delay = sched["delay"]
            fs = sched.get("fs", fs) if "fs" not in given else fs
            duration = sched.get("duration", duration) if "duration" not in given else duration
            noise = sched.get("noise", noise) if "noise" not in given else noise
            x0 = sched.get("amplitude", x0) if "x0" not in given else x0
            if sched.get("sample_time") is not None and sample_time is None:
                # a sampled loop's plan: its loop, not a continuous one with delay d·T
                sample_time, delay_samples = sched["sample_time"], sched["delay_samples"]
                velocity, cutoff = sched.get("velocity") or velocity, sched.get("cutoff")
                if placement is None and sched.get("noise_placement") is not None:
                    placement = sched["noise_placement"] == "in-loop"
        Ps = _numbers("--P", P, "N/m")
        Ds = _numbers("--D", D, "N s/m")
        if len(Ds) == 1:
            Ds = Ds * len(Ps)
        if len(Ps) == 1:
            Ps = Ps * len(Ds)
        if len(Ps) != len(Ds) or not Ps:
            raise ValueError(f"--P and --D must have the same number of runs; "
                             f"got {len(Ps)} and {len(Ds)}")
        bs = _numbers("--bias", bias, "N", "≥ 0")
        if len(bs) == 1:
            bs = bs * len(Ps)
        if len(bs) != len(Ps):
            raise ValueError(f"--bias must have one value, or one per run ({len(Ps)}); "
                             f"got {len(bs)}")
        _check_simulation_size(len(Ps), hold, duration, fs)
        plant = Plant(m, c, k, fc)
        rng = np.random.default_rng(seed)
        digital: dict = {}
        loop_table = None
        if sample_time is not None:
            if getattr(ctx.get_parameter_source("delay"), "name", "") != "DEFAULT":
                raise ValueError("a digital loop's delay is --delay-samples (whole periods of "
                                 "--sample-time); do not give --delay with --sample-time")
            digital = {"sample_time": sample_time, "delay_samples": delay_samples,
                       "velocity": velocity, "cutoff": cutoff}
            loop_table = {key: val for key, val in digital.items() if val is not None}
            delay = delay_samples * sample_time
        else:
            stray = [n for n in ("delay_samples", "velocity", "cutoff")
                     if getattr(ctx.get_parameter_source(n), "name", "") != "DEFAULT"]
            if stray:
                raise ValueError(f"--{stray[0].replace('_', '-')} needs --sample-time")
        sim = _simulate(plant, np.array(Ps), np.array(Ds),
                        **({} if digital else {"delay": delay}), duration=duration,
                        fs=fs, x0=x0, hold=hold, noise=noise, quantum=quantum, offset=offset,
                        rng=rng, bias=np.array(bs), noise_in_loop=placement, **digital)
        # the recorded force: the applied u plus the force sensor's white noise (same rng,
        # drawn after the position noise)
        u_rec = (sim.u + u_noise * rng.standard_normal(sim.u.shape)) if u_noise else sim.u
        runs = [
            run_from_arrays(sim.t, sim.x[i], u=u_rec[i], P=Ps[i], D=Ds[i], bias=bs[i],
                            index=i + 1)
            for i in range(len(Ps))
        ]
        truth = {"m": m, "c": c, "k": k, "fc": fc, "delay": delay, "noise": noise,
                 "quantum": quantum, "offset": offset, "x0": x0, "hold": hold,
                 **({"u_noise": u_noise} if u_noise else {}), **(loop_table or {})}
        if seed is not None:
            truth["seed"] = seed
        if noise > 0 or quantum > 0 or offset != 0:  # where the sensor's error was (either
            # loop: a continuous loop's in-loop placement is stated too, though only the
            # digital loop has an in-loop identification route)
            loop_table = {**(loop_table or {}),
                          "noise": "in-loop" if sim.noise_in_loop else "outside"}
            truth["noise_in_loop"] = bool(sim.noise_in_loop)
        # the schedule read is an input: not even --overwrite writes the set over it
        inputs = [] if schedule is None else [
            schedule / "experiment.toml" if schedule.is_dir() else schedule]
        with protect_inputs(inputs):
            path = write_experiment(
                out, runs, method="pho", delay=None if omit_delay or digital else delay,
                loop=loop_table,
                title=f"phoid simulate: m={m:g} kg, c={c:g} N s/m, k={k:g} N/m",
                extra={"simulated": truth}, gzip=gzip, overwrite=overwrite, names=names,
            )
    except (ValueError, OSError) as exc:
        _fail(_in_option_words(str(exc)))
    _wrote(len(Ps), path)


def _check_simulation_size(runs: int, hold: float, duration: float, fs: float) -> None:
    """Refuse, in the command's words, a simulation above the simulator's sample limit."""
    from phoid.simulation import MAX_SAMPLES

    for flag, val, unit in (("--duration", duration, "s"), ("--fs", fs, "Hz")):
        if not (math.isfinite(val) and val > 0):
            raise ValueError(f"{flag} must be finite and > 0 {unit}; got {val:g}")
    if not (math.isfinite(hold) and hold >= 0):
        raise ValueError(f"--hold must be finite and ≥ 0 s; got {hold:g}")
    total = runs * (hold + duration) * fs
    if math.isfinite(total) and total > MAX_SAMPLES:
        raise ValueError(
            f"--duration {duration:g} s and --fs {fs:g} Hz give {total:.3g} samples over {runs} "
            f"runs (with --hold {hold:g} s), above the limit of {MAX_SAMPLES:.0e} samples "
            f"(about {64 * MAX_SAMPLES / 1e9:.0f} GB): shorten --duration, lower --fs or "
            "simulate fewer runs")


def _simulate_other(ctx, out, *, method, m, c, k, fc, B, omega, duration, fs, x0, v0, hold,
                    noise, quantum, offset, seed, write_mass, gzip, overwrite) -> None:
    """`phoid simulate --method forced|free`: a sine sweep or a free release, no loop."""
    import numpy as np

    from phoid.dynamics.plant import Plant
    from phoid.io import write_experiment

    def given(name: str) -> bool:
        return getattr(ctx.get_parameter_source(name), "name", "") != "DEFAULT"

    try:
        if method not in ("forced", "free"):
            raise ValueError(f"`method` must be 'pho', 'forced' or 'free'; got {method!r}")
        own = {"forced": ("B", "omega"), "free": ("v0", "write_mass")}
        for name in ("P", "D", "schedule", "delay", "omit_delay", "sample_time",
                     "delay_samples", "velocity", "cutoff", "bias", "noise_in_loop",
                     "noise_outside",
                     *own["free" if method ==
                                                                      "forced" else "forced"]):
            if given(name):
                flag = f"--{name.replace('_', '-')}"
                raise ValueError(f"{flag} does not apply to --method {method}")
        plant = Plant(m, c, k, fc)
        rng = np.random.default_rng(seed)
        truth = {"m": m, "c": c, "k": k, "fc": fc, "noise": noise, "quantum": quantum,
                 "offset": offset, "hold": hold}
        if seed is not None:
            truth["seed"] = seed
        title = f"phoid simulate --method {method}: m={m:g} kg, c={c:g} N s/m, k={k:g} N/m"
        if method == "forced":
            from phoid.methods.forced import simulate_forced

            omegas = _numbers("--omega", omega, "rad/s", "> 0")
            _check_simulation_size(len(omegas), hold, duration, fs)
            rest = x0 if given("x0") else 0.0
            runs = simulate_forced(plant, omegas, B=B, duration=duration, fs=fs, hold=hold,
                                   x0=rest, noise=noise, quantum=quantum, offset=offset,
                                   rng=rng)
            truth.update({"B": B, "omega": omegas, "x0": rest})
            path = write_experiment(out, runs, method="forced", title=title,
                                    extra={"simulated": truth}, gzip=gzip, overwrite=overwrite)
        else:
            from phoid.io import run_from_arrays
            from phoid.simulation import simulate as _simulate

            _check_simulation_size(1, hold, duration, fs)
            sim = _simulate(plant, 0.0, 0.0, duration=duration, fs=fs, x0=x0, v0=v0,
                            hold=hold, noise=noise, quantum=quantum, offset=offset, rng=rng)
            runs = [run_from_arrays(sim.t, sim.x[0], index=1)]
            truth.update({"x0": x0, "v0": v0})
            path = write_experiment(out, runs, method="free", title=title,
                                    mass=m if write_mass else None,
                                    extra={"simulated": truth}, gzip=gzip, overwrite=overwrite)
    except (ValueError, OSError) as exc:
        _fail(_in_option_words(str(exc)))
    _wrote(len(runs), path)


def _wrote(runs: int, path: Path) -> None:
    """The line `phoid simulate` ends with: how many runs, and the manifest written."""
    echo_text(f"wrote {runs} run{'s' * (runs != 1)} to {path}", wrap=False)


from phoid import design_cli as _design_cli  # noqa: E402  (typer functions, lazy inside)
from phoid.batch import commands as _batch_commands  # noqa: E402  (typer function, lazy inside)
from phoid.batch import trend_commands as _trend_commands  # noqa: E402
from phoid.rig import commands as _rig_commands  # noqa: E402  (typer functions, lazy inside)
from phoid.rig import plant_cli as _plant_cli  # noqa: E402  (typer function, lazy inside)

app.command(name="design")(_design_cli.design)
app.command(name="trend")(_trend_commands.trend)

app.command(name="virtual-rig")(_rig_commands.virtual_rig)
app.command(name="virtual-plant")(_plant_cli.virtual_plant)
app.command(name="run")(_rig_commands.run)
app.command(name="batch")(_batch_commands.batch)


def main() -> None:
    """Console entry point.

    Errors a user can cause exit with status 2 and one line (see the commands). Anything else is
    a fault of phoid's: it too is reported in one line, with exit status 1, never a traceback
    (set PHOID_DEBUG=1 to see one).
    """
    import os
    import warnings

    if not os.environ.get("PHOID_DEBUG"):
        # a library's Python warning (numpy's overflow, scipy's, h5py's) is no message for the
        # user: an error is one line, and what the data deserve is in the result's warnings
        warnings.simplefilter("ignore")
    if not sys.argv[1:]:
        # no arguments: the help on standard output and status 2 (click's plain help would
        # print it on standard error, as a usage error)
        app(args=["--help"], standalone_mode=False)
        sys.exit(2)
    if sys.stdout.isatty() and sys.stderr.isatty() and "--json" not in sys.argv[1:]:
        from phoid._progress import progress

        progress(True)  # bars on stderr for long work, never in a pipe or with --json
    try:
        status = app(standalone_mode=False)
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as exc:  # the last line of defence of a command-line tool
        if callable(getattr(exc, "format_message", None)) and hasattr(exc, "exit_code"):
            # a usage error (unknown option, value that does not parse, missing argument),
            # raised by typer's click: one line, like every other error, with the help pointer
            ctx = getattr(exc, "ctx", None)
            where = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
            msg = " ".join(str(exc.format_message()).split())
            from phoid._notation import stream_text

            print(stream_text(f"phoid: error: {msg}{where}", sys.stderr), file=sys.stderr)
            sys.exit(exc.exit_code)
        if type(exc).__name__ == "Abort":  # end of input at a prompt
            sys.exit(1)
        if os.environ.get("PHOID_DEBUG"):
            raise
        msg = " ".join(str(exc).split()) or type(exc).__name__
        from phoid._notation import stream_text

        print(stream_text(f"phoid: internal error ({type(exc).__name__}): {msg} -- please "
                          "report it", sys.stderr), file=sys.stderr)
        sys.exit(1)
    # standalone_mode=False: a command's typer.Exit(code) comes back as its code, a finished
    # command as its return value (None)
    sys.exit(status if isinstance(status, int) else 0)


if __name__ == "__main__":
    main()
