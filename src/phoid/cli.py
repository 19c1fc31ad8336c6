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
    from phoid.identification import identify as _identify
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


def _numbers(name: str, text: str) -> list[float]:
    """Parse '1,2,3' or 'start:stop:count' (inclusive linspace) into floats."""
    import numpy as np

    text = text.strip()
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
            if n < 1:
                raise ValueError
            return np.linspace(a, b, n).tolist()
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(
            f"`{name}` must be comma-separated numbers or start:stop:count; got {text!r}"
        ) from None


@app.command()
def simulate(
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
    delay: Annotated[float, typer.Option(help="Loop delay, s.")] = 0.1,
    duration: Annotated[float, typer.Option(help="Record length after release, s.")] = 15.0,
    fs: Annotated[float, typer.Option(help="Sample rate, Hz.")] = 1000.0,
    x0: Annotated[float, typer.Option(help="Release position, m.")] = 0.01,
    hold: Annotated[float, typer.Option(
        help="Held segment before the release (controller on), s.")] = 0.2,
    noise: Annotated[float, typer.Option(help="Sensor noise standard deviation, m.")] = 0.0,
    quantum: Annotated[float, typer.Option(
        help="Encoder quantisation step, m (0: none).")] = 0.0,
    offset: Annotated[float, typer.Option(help="Constant sensor offset, m.")] = 0.0,
    seed: Annotated[int | None, typer.Option(help="Random seed for the noise.")] = None,
    omit_delay: Annotated[bool, typer.Option(
        "--omit-delay", help="Do not write [loop] delay into the manifest (to rehearse "
                             "estimating it).")] = False,
    gzip: Annotated[bool, typer.Option(help="Compress the data files (.csv.gz).")] = True,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing set in OUT.")] = False,
) -> None:
    """Simulate a PHO experiment and write it as a phoid/1 experiment set.

    The plant m x'' + c x' + k x + fc sign(x') = u runs under u = -[D x'(t - delay) +
    P x(t - delay)], held at x0 for --hold seconds with the controller on, then released; the
    recorded position gets the offset, white noise and quantisation asked for. Columns t, x and
    the applied feedback force u. Use it to rehearse an experiment or to build test fixtures.
    """
    import numpy as np

    from phoid.io import run_from_arrays, write_experiment
    from phoid.plant import Plant
    from phoid.simulation import simulate as _simulate

    try:
        Ps = _numbers("P", P)
        Ds = _numbers("D", D)
        if len(Ds) == 1:
            Ds = Ds * len(Ps)
        if len(Ps) == 1:
            Ps = Ps * len(Ds)
        if len(Ps) != len(Ds) or not Ps:
            raise ValueError(f"`P` and `D` must have the same number of runs; "
                             f"got {len(Ps)} and {len(Ds)}")
        plant = Plant(m, c, k, fc)
        rng = np.random.default_rng(seed)
        sim = _simulate(plant, np.array(Ps), np.array(Ds), delay=delay, duration=duration,
                        fs=fs, x0=x0, hold=hold, noise=noise, quantum=quantum, offset=offset,
                        rng=rng)
        runs = [
            run_from_arrays(sim.t, sim.x[i], u=sim.u[i], P=Ps[i], D=Ds[i], index=i + 1)
            for i in range(len(Ps))
        ]
        truth = {"m": m, "c": c, "k": k, "fc": fc, "delay": delay, "noise": noise,
                 "quantum": quantum, "offset": offset, "x0": x0, "hold": hold}
        if seed is not None:
            truth["seed"] = seed
        path = write_experiment(
            out, runs, method="pho", delay=None if omit_delay else delay,
            title=f"phoid simulate: m={m:g} kg, c={c:g} N s/m, k={k:g} N/m",
            extra={"simulated": truth}, gzip=gzip, overwrite=overwrite,
        )
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    typer.echo(f"wrote {len(Ps)} runs to {path}")


def main() -> None:
    """Console entry point.

    Errors a user can cause exit with status 2 and one line (see the commands). Anything else is
    a fault of phoid's: it too is reported in one line, with exit status 1, never a traceback
    (set PHOID_DEBUG=1 to see one).
    """
    import os

    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as exc:  # the last line of defence of a command-line tool
        if os.environ.get("PHOID_DEBUG"):
            raise
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"phoid: internal error ({type(exc).__name__}): {msg} -- please report it",
              file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
