"""``phoid batch``: many sets identified on a Dask cluster, one row each (registered in cli.py).

Errors a user can cause print one line ``phoid: error: …`` and exit with status 2; a set that
cannot be identified is a row with its error, not an error of the command.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from phoid._output import exit_with_error

__all__ = ["batch"]


def _fail(message: str, code: int = 2) -> NoReturn:
    exit_with_error(message, code)


def _finished(store) -> str:
    """Where the sets finished before a failure are: only a file that exists is named."""
    from phoid._output import safe_text

    held = [p for p in (store.parquet, store.journal) if p.is_file()]
    if not held:
        return f"no set was finished (nothing was written to {safe_text(store.parquet)})"
    return (f"the sets finished are in {' and '.join(safe_text(p) for p in held)} (run the "
            "same command again to finish the batch)")


def batch(
    sets: Annotated[list[str], typer.Argument(
        help="Experiment sets: folders (or their experiment.toml), glob patterns ('fleet/*') "
             "or text files listing one set per line (# comments and blank lines skipped; "
             "relative paths taken from the list file's folder).")],
    out: Annotated[Path, typer.Option(
        help="Parquet file of the rows (a CSV of the same name is written beside it). Sets "
             "it already holds with the same checksum and options are skipped, so a batch "
             "that was stopped is finished by running the same command again.")],
    scheduler: Annotated[str | None, typer.Option(
        help="Address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786. Default: a "
             "local cluster of --workers processes, started and closed here.")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Worker processes of the local cluster [default: the number of CPUs]; 0 runs "
             "the sets one after the other in this process.")] = None,
    timeout: Annotated[float, typer.Option(
        help="Seconds to wait for --scheduler to answer.")] = 10.0,
    estimator: Annotated[str | None, typer.Option(
        help="As for `phoid identify`: pho 'gls' (default) or 'ols'; tracking 'idim', "
             "'output-error' or 'auto'.")] = None,
    delay: Annotated[float | None, typer.Option(
        help="Loop delay in s, overriding each manifest's (as for `phoid identify`).")] = None,
    no_compensation: Annotated[bool, typer.Option(
        "--no-compensation", help="Ignore the loop delay (only with --estimator ols).")
    ] = False,
    mass: Annotated[float | None, typer.Option(
        "--mass", help="Known mass, kg, for free-decay sets.")] = None,
    friction: Annotated[bool, typer.Option(
        "--friction",
        help="pho and free sets: fit Coulomb friction f_c too (pho: slow; free: with the "
             "stop).")] = False,
    retry_errors: Annotated[bool, typer.Option(
        "--retry-errors", help="Identify again the sets --out holds as errors (skipped by "
                               "default: the same bytes give the same error).")] = False,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print the counts and the files written as one JSON object.")] = False,
) -> None:
    """Identify many experiment sets, one task per set, and write one row per set.

    Every set is identified as `phoid identify SET --json` would with the options given (the
    same numbers); the rows (estimates, standard errors, correlations, warnings, timing, the
    set's path and SHA-256) go to --out as Parquet and beside it as CSV (docs/format.md,
    "phoid batch output"). A set that fails is a row with its error. While the batch runs,
    each finished row is appended to OUT's .journal.jsonl file and the table is rewritten
    every few seconds: a batch killed halfway loses no finished set.
    """
    from phoid.batch.cluster import cluster_client, require_batch
    from phoid.batch.engine import run_batch
    from phoid.batch.rows import options_key
    from phoid.batch.store import BatchStore

    options = {"estimator": estimator, "delay": delay, "no_compensation": no_compensation,
               "mass": mass, "friction": friction}
    from phoid.batch.cluster import check_timeout

    try:
        check_timeout(timeout)  # before anything: a bad --timeout is refused whatever runs
        require_batch("batch")
        options_key(options)
        store = BatchStore(out)
        if workers is not None and workers < 0:
            raise ValueError(f"--workers must be 0 or more, got {workers}")
    except ValueError as exc:
        _fail(str(exc))
    try:
        if scheduler is None and workers == 0:
            report = run_batch(sets, client=None, options=options, store=store,
                               retry_errors=retry_errors)
        else:
            with cluster_client(scheduler, workers, timeout=timeout) as client:
                link = getattr(client, "dashboard_link", None) if scheduler else None
                if link and not as_json:
                    typer.echo(f"Dask dashboard: {link}", err=True)
                report = run_batch(sets, client=client, options=options, store=store,
                                   retry_errors=retry_errors)
    except KeyboardInterrupt:
        typer.echo(f"phoid: interrupted; {_finished(store)}", err=True)
        raise typer.Exit(130) from None
    except ValueError as exc:  # a glob that matches nothing, an output that cannot be written
        _fail(str(exc))
    except Exception as exc:  # the cluster failed (a worker lost, the scheduler gone)
        what = "the batch" if scheduler is None and workers == 0 else "the Dask cluster"
        _fail(f"{what} failed ({type(exc).__name__}: {exc}); {_finished(store)}", code=1)
    counts = {"sets": len(report.rows), "computed": report.computed,
              "identified": report.identified, "computed_errors": report.computed_errors,
              "errors": report.errors, "skipped": report.skipped,
              "skipped_errors": report.skipped_errors,
              "parquet": str(store.parquet), "csv": str(store.csv)}
    if as_json:
        typer.echo(json.dumps(counts, indent=1))
    else:
        from phoid._output import echo_text

        n = counts["sets"]
        held = (f" ({report.skipped_errors} of them an error row, not retried: --retry-errors)"
                if report.skipped_errors else "")
        echo_text(f"{n} set{'s' * (n != 1)}: {report.identified} identified, "
                  f"{report.computed_errors} with an error, {report.skipped} already done"
                  f"{held}; rows in {store.parquet} and {store.csv}", wrap=False)
