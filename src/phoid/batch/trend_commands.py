"""The ``phoid trend`` command: drift of a batch output's estimates per unit, registered in cli.py.

Errors a user can cause print one line ``phoid: error: …`` and exit with status 2.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from phoid._output import exit_with_error

__all__ = ["trend"]


def _fail(message: str) -> NoReturn:
    exit_with_error(message)


def trend(
    results: Annotated[Path, typer.Argument(
        help="A batch output: results.parquet (or the results.csv beside it) from phoid batch.",
        show_default=False)],
    by: Annotated[str, typer.Option(
        help="The column naming the unit (a manifest's [metadata] axis by default).")] = "axis",
    baseline: Annotated[int, typer.Option(
        help="Number of first points of each series the baseline is the weighted mean of.")
    ] = 5,
    threshold: Annotated[float, typer.Option(
        help="Flag a point when |z| exceeds this (3: 0.27 % false alarms per point).")] = 3.0,
    plots: Annotated[Path | None, typer.Option(
        help="Write one figure per unit, trend-<unit>.png, into this folder.")] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print one JSON object (units, parameters, points, warnings).")] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace existing figures.")] = False,
) -> None:
    """Estimates over time per unit, flagging changes larger than their stderrs explain.

    Reads the rows with status ok, groups them by --by, orders each unit's rows by their time
    (or, where a row has none, by when it was identified, with a warning) and charts every
    estimated parameter: the baseline is the inverse-variance weighted mean b of the first
    --baseline points, and each later point gets z = (x - b) / sqrt(stderr^2 + stderr_b^2),
    flagged when |z| > --threshold. Prints per unit and parameter the last value +/- stderr,
    its change from the baseline, z and the number of flagged points.
    """
    from phoid._output import echo_text, protect_inputs, safe_text
    from phoid.batch.cluster import require_batch
    from phoid.batch.drift import trend as make_trend

    try:
        require_batch("trend")
        result = make_trend(results, by=by, baseline=baseline, threshold=threshold)
        written = []
        if plots is not None:
            from phoid.batch.drift_plot import plot_trend

            # a figure never replaces the results read (or the CSV beside them)
            with protect_inputs([results, results.with_suffix(".csv")]):
                written = plot_trend(result, plots, overwrite=overwrite)
    except (ValueError, OSError) as exc:
        _fail(str(exc))
    if as_json:
        typer.echo(json.dumps(result.summary(), indent=1))
        for w in result.warnings:
            echo_text(f"phoid: warning: {safe_text(w)}", err=True, wrap=False)
    else:
        echo_text(result.report)
    if written:
        echo_text(f"{len(written)} figure{'s' * (len(written) != 1)} written to {plots}",
                  err=as_json, wrap=False)
