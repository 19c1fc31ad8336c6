"""The ``phoid`` command line: a thin shell over the public functions.

Every error a user can cause (bad files, bad parameters, data that cannot determine the answer)
is printed as one line on standard error with exit status 2; never a traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from phoid import __version__

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
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _fail(message: str) -> None:
    typer.echo(f"phoid: error: {message}", err=True)
    raise typer.Exit(2)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"phoid {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True,
                           help="Print the version and exit.")
    ] = False,
) -> None:
    """phoid: identify m, c, k of second-order systems by parametric harmonic oscillation."""


@app.command()
def paper(
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Folder for the Figure 1 PNG files (created if needed).")
    ] = Path("phoid-out"),
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
    from phoid.report import figure1

    try:
        result = reproduce_table1(duration=duration, fs=fs)
        fa, fb = figure1(result, out)
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    if as_json:
        summary = result.summary()
        summary["figures"] = [str(fa), str(fb)]
        typer.echo(json.dumps(summary, indent=1))
        typer.echo(f"figures written to {fa} and {fb}", err=True)
    else:
        typer.echo(result.table())
        typer.echo("")
        typer.echo(f"Figure 1(a) written to {fa}")
        typer.echo(f"Figure 1(b) written to {fb}")


@app.command()
def identify(
    experiment: Annotated[Path, typer.Argument(
        help="Experiment set: a folder with experiment.toml (format phoid/1), or the manifest.")],
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print the result as one JSON object (the phoid/1 spec) on standard "
                       "output; warnings also go to standard error.")] = False,
    plots: Annotated[Path | None, typer.Option(
        "--plots", help="Write per-run decay fits with residuals and the eq. (35) lines with "
                        "error bars as PNG files into this folder.")] = None,
    estimator: Annotated[str, typer.Option(
        help="'gls': weighted fit of m, c, k through the exact loop roots (efficient, default); "
             "'ols': the paper's eq. (35) lines by ordinary least squares.")] = "gls",
    delay: Annotated[float | None, typer.Option(
        help="Loop delay in s, overriding the manifest's [loop] delay.")] = None,
    no_compensation: Annotated[bool, typer.Option(
        "--no-compensation", help="Ignore the loop delay (the paper's uncompensated column; "
                                  "only with --estimator ols).")] = False,
) -> None:
    """Identify m, c, k (with standard errors) from a recorded PHO experiment set.

    Each run's free decay is fitted for its dominant mode (decay rate sigma and damped frequency
    omega_d with their uncertainty); the delay-corrected modes of all runs then give m, c, k.
    Prints the estimates with +- one standard error and units, the open-loop zeta and omega0,
    a per-run table and any warnings.
    """
    from phoid.identify import identify as _identify
    from phoid.io import read_experiment

    try:
        exp = read_experiment(experiment)
        result = _identify(exp, delay=delay, estimator=estimator,
                           compensate=not no_compensation)
        written = result.plot(plots) if plots is not None else []
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    if as_json:
        typer.echo(json.dumps(result.summary(), indent=1))
        for w in result.warnings:
            typer.echo(f"phoid: warning: {w}", err=True)
    else:
        typer.echo(result.report())
    if written:
        typer.echo(f"{len(written)} figures written to {plots}", err=as_json)


def main() -> None:
    """Console entry point."""
    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)


if __name__ == "__main__":
    main()
