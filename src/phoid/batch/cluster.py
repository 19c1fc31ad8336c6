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
import math
import os
import pickle
import socket
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from phoid._progress import task
from phoid.errors import PhoidError

__all__ = ["MAX_TIMEOUT", "check_timeout", "cluster_client", "map_unordered", "require_batch"]

# the modules of the batch extra, as imported
_BATCH_MODULES = ("distributed", "pandas", "pyarrow")

MAX_WORKERS_PER_CPU = 4
"""The most local worker processes per CPU :func:`cluster_client` starts (each one a Python
process of about 100 MB); a larger cluster is started apart and reached by its address."""


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


async def _identity(address: str, timeout: float) -> Any:
    """The scheduler's answer to ``identity``, read over one connection of its own."""
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


MAX_GREETING = 1 << 16
"""Most bytes of a Dask scheduler's first message (its handshake: a few hundred bytes) that
the probe reads; a larger declared length is not a scheduler's."""
_MAX_FRAMES = 64


class _NotDask(Exception):
    """What answered at the scheduler's address is not a Dask scheduler (the reason)."""


def _recv_exactly(sock: socket.socket, n: int, deadline: float) -> bytes:
    """``n`` bytes from ``sock`` before ``deadline`` (time.monotonic); TimeoutError after."""
    out = bytearray()
    while len(out) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        sock.settimeout(left)
        piece = sock.recv(n - len(out))
        if not piece:
            raise _NotDask(f"it closed the connection after {len(out)} of the {n} bytes "
                           "expected")
        out += piece
    return bytes(out)


def _check_greeting(address: str, timeout: float) -> None:
    """Read a TCP scheduler's first message with a bounded read and check its framing.

    A Dask scheduler speaks first: on each new connection it sends its handshake, framed as
    distributed's TCP comm frames every message (an 8-byte little-endian length, then that
    many bytes: a frame count, the frames' lengths, the frames; the handshake's first frame a
    msgpack map). distributed allocates
    whatever length the first 8 bytes declare, so another service on the port (an HTTP
    server's reply, random bytes) made it allocate exabytes and fail with a MemoryError;
    here at most :data:`MAX_GREETING` bytes are read and the framing is checked before
    distributed is let near the address. Addresses that are not ``tcp://`` (or a plain
    host:port) are left to distributed.

    Raises
    ------
    _NotDask
        The reply is not framed as a Dask message.
    TimeoutError, OSError
        No connection, or no complete first message, within ``timeout`` seconds.
    """
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        return  # distributed names what is wrong with the address
    if scheme != "tcp" or not host:
        return
    deadline = time.monotonic() + timeout
    with socket.create_connection((host, port), timeout=timeout) as sock:
        (size,) = struct.unpack("<Q", _recv_exactly(sock, 8, deadline))
        if not 16 <= size <= MAX_GREETING:
            raise _NotDask(f"its first message declares {size:,} bytes, where a Dask "
                           f"scheduler's handshake takes 16 to {MAX_GREETING:,}")
        body = _recv_exactly(sock, size, deadline)
    (frames,) = struct.unpack_from("<Q", body)
    if not 1 <= frames <= _MAX_FRAMES or 8 * (1 + frames) > size:
        raise _NotDask(f"its first message declares {frames:,} frames")
    lengths = struct.unpack_from(f"<{frames}Q", body, 8)
    if 8 * (1 + frames) + sum(lengths) != size:
        raise _NotDask("its first message's frames do not add up to its length")
    import msgpack  # distributed's own dependency: its messages are msgpack

    start = 8 * (1 + frames)
    try:
        handshake = msgpack.loads(body[start:start + lengths[0]], raw=False)
    except Exception:  # msgpack raises several kinds on bytes that are not msgpack
        handshake = None
    if not isinstance(handshake, dict):
        raise _NotDask("its first message is not a handshake (a msgpack map)")


def _probe_scheduler(address: str, timeout: float) -> None:
    """Ask the scheduler at ``address`` who it is; raise a one-line error unless it answers
    as a Dask scheduler within ``timeout`` seconds.

    ``distributed.Client`` bounds the TCP connect by its timeout but not the handshake after
    it, so a listener that accepts and never answers (a firewall, another service on the
    port) would hang it; this probe bounds the whole exchange (connect, handshake, reply)
    with ``asyncio.wait_for``, in a thread of its own (the caller may run an event loop).

    Raises
    ------
    PhoidError
        Naming the address: not a valid address, no answer within ``timeout`` s, or an
        answer that is not a Dask scheduler's.
    """
    import asyncio
    import concurrent.futures

    not_dask = f"{address!r} answers, but not as a Dask scheduler"
    try:
        _check_greeting(address, timeout)
    except _NotDask as exc:
        raise PhoidError(f"{not_dask} ({exc})") from None
    except TimeoutError:
        raise PhoidError(f"the Dask scheduler at {address!r} does not answer within "
                         f"{timeout:g} s") from None
    except OSError as exc:
        raise PhoidError(f"the Dask scheduler at {address!r} does not answer within "
                         f"{timeout:g} s ({type(exc).__name__}: {exc})") from None

    def run() -> Any:
        return asyncio.run(asyncio.wait_for(_identity(address, timeout), timeout))

    pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="phoid-probe")
    try:
        reply = pool.submit(run).result(timeout + 5.0)
    except (TimeoutError, concurrent.futures.TimeoutError):  # asyncio.TimeoutError too
        raise PhoidError(f"the Dask scheduler at {address!r} does not answer within "
                         f"{timeout:g} s") from None
    except OSError as exc:
        raise PhoidError(f"the Dask scheduler at {address!r} does not answer within "
                         f"{timeout:g} s ({type(exc).__name__}: {exc})") from None
    except MemoryError:  # a later reply declaring an absurd length: not Dask's either
        raise PhoidError(f"{not_dask} (a reply declares more bytes than memory holds)"
                         ) from None
    except Exception as exc:  # a bad address, a reply that is not Dask's
        raise PhoidError(f"the Dask scheduler at {address!r} cannot be used: "
                         f"{type(exc).__name__}: {' '.join(str(exc).split())}") from None
    finally:
        pool.shutdown(wait=False)
    if not (isinstance(reply, dict) and reply.get("type") == "Scheduler"):
        raise PhoidError(not_dask)


def _cpus() -> int:
    """The CPUs this process may run on (its affinity where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0)) or 1
    return os.cpu_count() or 1


MAX_TIMEOUT = 86400.0
"""The longest wait for a scheduler, s (a day): beyond it the socket layer overflows."""


def check_timeout(timeout: float) -> float:
    """``timeout`` checked: a number of seconds, finite, > 0 and at most :data:`MAX_TIMEOUT`.

    Raises
    ------
    PhoidError
        One line naming ``--timeout`` and the value.
    """
    if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not (
            math.isfinite(timeout) and 0 < timeout <= MAX_TIMEOUT):
        raise PhoidError(f"--timeout must be a number of seconds, finite, > 0 and at most "
                         f"{MAX_TIMEOUT:g} (a day); got {timeout!r}")
    return float(timeout)


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
        The number of worker processes of the local cluster (one thread each); default the
        number of CPUs this process may use (``os.sched_getaffinity``, else
        ``os.cpu_count()``). Ignored with ``scheduler``.
    timeout : float, default 10.0
        Seconds (finite, > 0, at most a day: :data:`MAX_TIMEOUT`) to wait for the scheduler
        to answer before giving up: the connection, its handshake and a first request each
        bounded by it (see ``_probe_scheduler``), so a call with ``scheduler`` that fails
        ends within about ``2 * timeout`` seconds.
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
        seconds, the address is not one, or what answers is not a Dask scheduler; one line
        for a bad ``timeout``, or ``workers`` below 1 or above ``MAX_WORKERS_PER_CPU`` per
        CPU; one line naming the extra when distributed is not installed.
    """
    require_batch("batch")
    from distributed import Client, LocalCluster

    check_timeout(timeout)
    if scheduler is not None:
        _probe_scheduler(scheduler, timeout)
        try:
            client = Client(scheduler, timeout=timeout)
        except Exception as exc:  # any failure to connect: one line
            raise PhoidError(f"the Dask scheduler at {scheduler!r} cannot be used: "
                             f"{type(exc).__name__}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers if workers is not None else _cpus()
    if n < 1:
        raise PhoidError(f"--workers must be at least 1 for a cluster, got {n}")
    if n > MAX_WORKERS_PER_CPU * _cpus():
        raise PhoidError(f"--workers {n} is more than {MAX_WORKERS_PER_CPU} worker processes "
                         f"per CPU ({_cpus()} CPUs here); for more, start a cluster and "
                         "pass its --scheduler")
    # no dashboard: the scheduler's plain HTTP server (health, metrics) still starts, on a
    # free port rather than on 8787, which another cluster may hold (distributed would warn);
    # the workers' logs silenced below CRITICAL: a heartbeat racing the shutdown logs a
    # traceback otherwise (a failure that matters reaches the client as an exception)
    cluster = LocalCluster(n_workers=n, processes=True, threads_per_worker=1,
                           dashboard_address=":0" if dashboard else None,
                           scheduler_kwargs={"dashboard_address": ":0"},
                           silence_logs=logging.CRITICAL)
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
