"""Identify many sets: one task per set, on a Dask cluster or in this process.

:func:`identify_job` is the task (it runs on a worker: read the set, identify it through
:func:`phoid.methods.dispatch.identify_set`, the code path of ``phoid identify``, and return
its row); :func:`run_batch` expands the sets, skips those an output already holds, runs the
others and records each row as it comes back; :func:`identify_many` is the Python entry
(``phoid.identify_many``).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from phoid._progress import task
from phoid.batch.rows import error_row, options_key, result_row
from phoid.batch.sets import expand_sets, set_digest

__all__ = ["BatchReport", "identify_job", "identify_many", "run_batch"]

# seconds between two rewrites of the Parquet and CSV files while a batch runs
FLUSH_SECONDS = 5.0


def _version() -> str:
    return str(getattr(sys.modules.get("phoid"), "__version__", "unknown"))


def _worker() -> str:
    """The Dask worker's address, or ``local:<pid>`` outside a worker."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return f"local:{os.getpid()}"


def identify_job(job: tuple[str, str, Mapping[str, Any], Mapping[str, Any]]) -> dict[str, Any]:
    """Identify one set and return its row (the task of a batch; never raises for the set).

    Parameters
    ----------
    job : tuple
        ``(set, checksum, metadata, options)``: the set's resolved path, its
        :func:`~phoid.batch.sets.set_digest` checksum and ``[metadata]``, and the identify
        options (``estimator``, ``delay``, ``no_compensation``, ``mass``, ``friction``).

    Returns
    -------
    dict
        :func:`~phoid.batch.rows.result_row` of the result's ``summary()``, or
        :func:`~phoid.batch.rows.error_row` with the one-line error when the set cannot be
        read or identified. ``seconds`` is the wall time of reading and identifying.
    """
    from phoid.io import read_experiment
    from phoid.methods.dispatch import identify_set

    set_path, checksum, metadata, options = job
    key = options_key(options)
    start = time.perf_counter()
    method = None
    try:
        exp = read_experiment(set_path)
        method = exp.method
        summary = identify_set(exp, **options).summary()
    except (ValueError, OSError, ArithmeticError) as exc:
        return error_row(set_path, checksum, key, metadata, exc, method=method,
                         seconds=time.perf_counter() - start, worker=_worker(),
                         finished=datetime.now(UTC), version=_version())
    return result_row(set_path, checksum, key, metadata, summary,
                      seconds=time.perf_counter() - start, worker=_worker(),
                      finished=datetime.now(UTC), version=_version(), n_runs=len(exp.runs))


@dataclass(frozen=True)
class BatchReport:
    """What a batch did.

    Attributes
    ----------
    rows : list of dict
        One row per set named, in the order named.
    skipped : int
        Sets whose row the output already held (same checksum and options): not recomputed.
    computed : int
        Sets this batch worked on: ``identified + computed_errors``.
    errors : int
        Rows of this batch's sets with ``status = "error"``, this run's and the skipped ones
        of an earlier run: ``computed_errors + skipped_errors`` (the meaning it has always had
        in ``phoid batch --json``).
    identified : int
        Sets this batch identified (``status = "ok"``).
    computed_errors : int
        Sets this batch worked on that ended in an error.
    skipped_errors : int
        Of the ``skipped`` rows, those with ``status = "error"`` (from an earlier run; tried
        again with ``retry_errors``).
    """

    rows: list[dict[str, Any]]
    skipped: int
    computed: int
    errors: int
    identified: int = 0
    computed_errors: int = 0
    skipped_errors: int = 0


def _serial(fn: Callable[[Any], Any], items: list[Any], description: str
            ) -> Iterator[tuple[int, Any]]:
    """:func:`~phoid.batch.cluster.map_unordered` in this process, one item after the other."""
    with task(description, total=len(items)) as advance:
        for i, item in enumerate(items):
            try:
                result = fn(item)
            except Exception as exc:  # as on a worker: the item's failure is its result
                result = exc
            advance()
            yield i, result


def run_batch(sets: Iterable[str | os.PathLike[str]], *, client: Any = None,
              options: Mapping[str, Any] | None = None, store: Any = None,
              flush_seconds: float = FLUSH_SECONDS, retry_errors: bool = False) -> BatchReport:
    """Identify every set: skip those ``store`` holds, run the rest, record each row.

    Parameters
    ----------
    sets : iterable of str or path
        Folders, manifests, glob patterns or list files (:func:`~phoid.batch.sets.expand_sets`);
        the files of ``store`` among them (a glob matching the output) are left out.
    client : distributed.Client, optional
        Where the tasks run; None: one after the other in this process.
    options : mapping, optional
        The identify options, the same for every set.
    store : phoid.batch.store.BatchStore, optional
        The output: its rows of the same set, checksum and options are taken, not
        recomputed; each new row is appended to its journal, the table rewritten every
        ``flush_seconds`` and at the end (also when the batch is interrupted).
    flush_seconds : float, default FLUSH_SECONDS
        Seconds between rewrites of the table while the batch runs.
    retry_errors : bool, default False
        Identify again the sets ``store`` holds as errors (the same bytes usually give the
        same error, so they are skipped by default; a failure of the machine, or of a phoid
        since fixed, is worth a retry).

    Returns
    -------
    BatchReport

    Raises
    ------
    Exception
        A failure of the cluster (a lost worker, the client closed) or KeyboardInterrupt;
        the rows finished before it are in the store.
    """
    options = dict(options or {})
    key = options_key(options)  # refuses an unknown option before any work
    names = expand_sets(sets)
    if store is not None:  # `fleet/*` with --out fleet/results.parquet: not sets
        own = {str(path.resolve()) for path in (store.parquet, store.csv, store.journal)}
        names = [name for name in names if name not in own]
    done = store.done() if store is not None else {}
    rows: dict[str, dict[str, Any]] = {}
    jobs: list[tuple[str, str, dict[str, Any], dict[str, Any]]] = []
    skipped = 0
    worked: set[str] = set()  # the sets this run made a row for (not skipped)

    def record(row: dict[str, Any]) -> None:
        rows[row["set"]] = row
        worked.add(row["set"])
        if store is not None:
            store.append(row)

    digests: list[Any] = []
    for name in names:
        try:
            digests.append(set_digest(name))
        except (ValueError, OSError) as exc:
            digests.append(exc)
    if store is not None:  # no output file may be one of the sets' files (--overwrite or not)
        from phoid._output import check_not_input, protect_inputs

        with protect_inputs(f for d in digests if not isinstance(d, BaseException)
                            for f in d.files):
            for path in (store.parquet, store.csv, store.journal):
                check_not_input(path)
        store.begin()
    for name, digest in zip(names, digests, strict=True):
        if isinstance(digest, BaseException):
            record(error_row(name, None, key, {}, digest, worker=_worker(),
                             finished=datetime.now(UTC), version=_version()))
            continue
        before = done.get((name, key))
        if (before is not None and before.get("checksum") == digest.checksum
                and not (retry_errors and before.get("status") == "error")):
            rows[name] = before
            skipped += 1
            continue
        jobs.append((name, digest.checksum, digest.metadata, options))
    if client is None:
        results = _serial(identify_job, jobs, "sets")
    else:
        from phoid.batch.cluster import map_unordered

        results = map_unordered(client, identify_job, jobs, description="sets")
    last = time.monotonic()
    try:
        for i, row in results:
            if isinstance(row, BaseException):  # the task itself failed, not the set
                name, checksum, metadata, _ = jobs[i]
                row = error_row(name, checksum, key, metadata, row, worker=_worker(),
                                finished=datetime.now(UTC), version=_version())
            record(row)
            if store is not None and time.monotonic() - last > flush_seconds:
                store.write()
                last = time.monotonic()
    finally:
        if store is not None:
            store.write()
    if store is not None:
        store.finish()
    ordered = [rows[n] for n in names if n in rows]
    new = [r for r in ordered if r["set"] in worked]
    errors = sum(r["status"] == "error" for r in new)
    held = sum(r["status"] == "error" for r in ordered if r["set"] not in worked)
    return BatchReport(rows=ordered, skipped=skipped, computed=len(new), errors=errors + held,
                       identified=len(new) - errors, computed_errors=errors,
                       skipped_errors=held)


def identify_many(sets: Iterable[str | os.PathLike[str]], client: Any = None, *,
                  out: str | os.PathLike[str] | None = None, workers: int | None = None,
                  **options: Any) -> Any:
    """Identify many experiment sets, one task each, on a Dask cluster; one row per set.

    Parameters
    ----------
    sets : str, path or iterable of them
        Set folders (or manifests), glob patterns (``"fleet/*/"``) or text files listing
        sets, one per line (a single str or path: one of these).
    client : distributed.Client, optional
        The cluster to run on. None: a local cluster of ``workers`` processes is started and
        closed; ``workers=0`` runs the sets one after the other in this process instead.
    out : str or path, optional
        A Parquet file to write the rows to (and a CSV beside it); sets it already holds with
        the same checksum and options are not recomputed (``phoid batch --out``).
    workers : int, optional
        Worker processes of the local cluster (default: the number of CPUs).
    **options
        The options of ``phoid identify``, the same for every set: ``estimator``, ``delay``
        (s), ``no_compensation``, ``mass`` (kg), ``friction``.

    Returns
    -------
    pandas.DataFrame
        One row per set named, in order, with the columns of docs/format.md ("phoid batch
        output"): ``set``, ``checksum``, ``options``, ``status``, ``error``, the estimates
        and their ``_stderr``, ``corr_*``, ``chi2_dof``, ``warnings``, ``seconds``,
        ``worker``, ``finished``, ...

    Raises
    ------
    PhoidError
        The batch extra missing, an output file in the way, a scheduler that does not answer.
    ValueError
        An unknown option, or one of the wrong type.

    Examples
    --------
    >>> import phoid
    >>> table = phoid.identify_many(["fleet/a", "fleet/b"], workers=2)  # doctest: +SKIP
    >>> table[["set", "m", "m_stderr", "status"]]  # doctest: +SKIP
    """
    from phoid.batch.cluster import cluster_client, require_batch
    from phoid.batch.store import BatchStore, to_frame

    require_batch("batch")
    options_key(options)
    store = BatchStore(out) if out is not None else None
    if client is not None or workers == 0:
        report = run_batch(sets, client=client, options=options, store=store)
    else:
        with cluster_client(workers=workers) as local:
            report = run_batch(sets, client=local, options=options, store=store)
    return to_frame(report.rows)
