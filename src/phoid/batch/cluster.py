"""A Dask cluster for many independent tasks: connect or start one, map a function over items.

The helpers behind ``phoid batch`` and ``phoid design --rehearse``: :func:`cluster_client`
yields a ``distributed.Client`` (to a running scheduler, or to a local cluster of worker
processes started and closed with the block), :func:`map_unordered` runs one function per item
on it and yields the results as they finish, with a progress bar, and :func:`require_batch`
turns a missing optional dependency into a one-line error naming the extra to install.

dask, distributed, pandas and pyarrow are the optional extra ``phoid[batch]``; they are
imported inside the functions, so importing this module costs nothing without them.

>>> from phoid.batch.cluster import cluster_client, map_unordered  # doctest: +SKIP
>>> with cluster_client(workers=2) as client:  # doctest: +SKIP
...     for i, result in map_unordered(client, abs, [-1, -2, 3], description="abs"):
...         print(i, result)
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from phoid._progress import task
from phoid.errors import PhoidError

__all__ = ["cluster_client", "map_unordered", "require_batch"]

# the modules of the batch extra, as imported
_BATCH_MODULES = ("distributed", "pandas", "pyarrow")


def require_batch(command: str) -> None:
    """Raise a one-line :class:`~phoid.errors.PhoidError` when the batch extra is missing.

    Parameters
    ----------
    command : str
        The command that needs it, as typed after ``phoid`` (``"batch"``, ``"trend"``,
        ``"design --rehearse"``), named in the message.

    Raises
    ------
    PhoidError
        ``phoid <command> needs the batch extra: pip install 'phoid[batch]'`` when any of
        dask.distributed, pandas or pyarrow cannot be imported.
    """
    import importlib

    for name in _BATCH_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:
            raise PhoidError(
                f"phoid {command} needs the batch extra: pip install 'phoid[batch]'") from None


@contextlib.contextmanager
def cluster_client(scheduler: str | None = None, workers: int | None = None, *,
                   timeout: float = 10.0, dashboard: bool = False) -> Iterator[Any]:
    """A ``distributed.Client`` for the block: to a running scheduler, or to a local cluster.

    Parameters
    ----------
    scheduler : str, optional
        The address of a running Dask scheduler, e.g. ``"tcp://10.0.0.5:8786"``. Omitted: a
        ``distributed.LocalCluster`` of worker processes is started here and closed when the
        block ends.
    workers : int, optional
        The number of worker processes of the local cluster (one thread each); default
        ``os.cpu_count()``. Ignored with ``scheduler``.
    timeout : float, default 10.0
        Seconds to wait for the scheduler to answer before giving up.
    dashboard : bool, default False
        Serve the local cluster's dashboard on a free port (``client.dashboard_link``; needs
        bokeh). Off: no dashboard, no port taken for it.

    Yields
    ------
    distributed.Client
        Closed (and the local cluster with it) when the block ends, also on an exception.

    Raises
    ------
    PhoidError
        One line naming the address when the scheduler does not answer within ``timeout``
        seconds; one line naming the extra when distributed is not installed.
    """
    require_batch("batch")
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise PhoidError(
                f"the Dask scheduler at {scheduler} does not answer within {timeout:g} s "
                f"({type(exc).__name__})") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise PhoidError(f"workers must be at least 1, got {n}")
    # no dashboard: the scheduler's plain HTTP server (health, metrics) still starts, on a
    # free port rather than on 8787, which another cluster may hold (distributed would warn)
    cluster = LocalCluster(n_workers=n, processes=True, threads_per_worker=1,
                           dashboard_address=":0" if dashboard else None,
                           scheduler_kwargs={"dashboard_address": ":0"},
                           silence_logs=logging.ERROR)
    try:
        client = Client(cluster, timeout=timeout)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def _call_caught(fn: Callable[[Any], Any], item: Any) -> Any:
    """``fn(item)``, or the exception it raised (one that pickles), as the result."""
    try:
        return fn(item)
    except Exception as exc:  # every failure of one item is its result
        try:
            pickle.dumps(exc)
        except Exception:  # cannot travel back: its text does
            return RuntimeError(f"{type(exc).__name__}: {exc}")
        return exc


def map_unordered(client: Any, fn: Callable[[Any], Any], items: Iterable[Any], *,
                  description: str) -> Iterator[tuple[int, Any]]:
    """Run ``fn(item)`` for every item on the cluster; yield ``(index, result)`` as each ends.

    Parameters
    ----------
    client : distributed.Client
        E.g. from :func:`cluster_client`.
    fn : callable
        A function of one argument that pickles (a module-level function, or a
        ``functools.partial`` of one); it runs on the workers, once per item.
    items : iterable
        The arguments; each pickles.
    description : str
        The progress bar's label (``phoid._progress``: drawn only where progress is on).

    Yields
    ------
    (int, object)
        The item's position in ``items`` and ``fn(item)``, in the order the tasks finish. An
        exception raised by ``fn`` is caught on the worker and yielded as the result (its
        text only, as a ``RuntimeError``, when the exception does not pickle): one failing
        item never ends the map.

    Raises
    ------
    Exception
        Only a failure of the cluster itself (a worker lost, the client closed, a result that
        does not pickle); the tasks not yet finished are cancelled. Stopping the iteration
        early cancels them too.
    """
    from distributed import as_completed

    items = list(items)
    futures = [client.submit(_call_caught, fn, item, pure=False) for item in items]
    position = {future.key: i for i, future in enumerate(futures)}
    try:
        with task(description, total=len(items)) as advance:
            for future in as_completed(futures):
                result = future.result()
                advance()
                yield position[future.key], result
                future.release()
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            with contextlib.suppress(Exception):
                client.cancel(pending)
