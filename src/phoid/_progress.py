"""Progress bars for long work: a no-op unless switched on.

Library code marks its long loops (a friction fit's iterations, a simulation's runs, a
benchmark's cases) with :func:`task` and :func:`step`; nothing is drawn unless progress is
switched on, by :func:`progress` (the Python API's opt-in, ``phoid.progress(True)``) or by the
command line, which switches it on only when standard output and standard error are terminals
and ``--json`` is not given. The bar is rich's, drawn on standard error (only where that is a
terminal or a notebook) and erased when the work ends (transient), so that what a command
prints is unchanged.

Switched off, :func:`task` yields a function that does nothing and :func:`step` returns after
one context-variable look-up: call them once per run or per iteration, never per sample.
rich is imported only when a bar is drawn. The switch and the current bar are context
variables, so a thread started inside a task draws nothing unless it switches progress on
itself.

>>> from phoid._progress import task, step
>>> with task("runs", total=3) as advance:  # switched off: nothing is drawn
...     for _ in range(3):
...         advance()
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["enabled", "progress", "step", "task"]

# None: off; else the rich Console to draw on (None inside the tuple: rich's stderr console)
_SWITCH: contextvars.ContextVar[tuple[Any] | None] = contextvars.ContextVar(
    "phoid_progress", default=None)
# the bar drawn now and the stack of its open tasks (innermost last), or None
_BAR: contextvars.ContextVar[tuple[Any, list[Any]] | None] = contextvars.ContextVar(
    "phoid_progress_bar", default=None)


def _noop(n: float = 1, *, description: str | None = None, total: float | None = None,
          completed: float | None = None) -> None:
    return None


def progress(on: bool = True, *, console: Any = None) -> None:
    """Switch progress bars on or off for long work in this thread (and its context).

    Parameters
    ----------
    on : bool, default True
        Draw a bar (on standard error, erased when the work ends) while a friction fit, a long
        simulation or another long computation runs; only where standard error is a terminal
        or a notebook (nothing is written to a file or a pipe).
    console : rich.console.Console, optional
        Where to draw (default: a console on standard error). Tests pass one that writes to
        a string.

    Examples
    --------
    >>> import phoid
    >>> phoid.progress(True)   # bars from now on  # doctest: +SKIP
    >>> phoid.progress(False)
    """
    _SWITCH.set((console,) if on else None)


def enabled() -> bool:
    """Whether progress bars are switched on here."""
    return _SWITCH.get() is not None


@contextlib.contextmanager
def task(description: str, total: float | None = None, *, show: bool = True
         ) -> Iterator[Callable[..., None]]:
    """A unit of long work, shown as one line of the progress bar while it runs.

    Yields ``advance(n=1, *, description=None, total=None, completed=None)``: moves the task
    on by ``n`` (of ``total``; ``total=None`` shows a count with no end), and optionally
    renames it (e.g. a fit's stage), sets its total, or sets how much is done (``completed``,
    which replaces the advance by ``n``). Tasks nest: an inner task is a second line under the
    outer one. :func:`step` advances the innermost open task from code that was not handed
    ``advance``.

    Parameters
    ----------
    description : str
        What the work is, e.g. ``"friction fit"``.
    total : float, optional
        The number of steps, when known.
    show : bool, default True
        False: the work is too short to show (e.g. one of a fit's many small simulations);
        nothing is drawn, and :func:`step` inside it advances nothing.
    """
    switch = _SWITCH.get()
    if switch is None:
        yield _noop
        return
    outer = _BAR.get()
    if not show:
        if outer is None:
            yield _noop
            return
        outer[1].append(None)  # step() inside advances nothing
        try:
            yield _noop
        finally:
            outer[1].pop()
        return
    if outer is None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )

        console = switch[0] if switch[0] is not None else Console(stderr=True)
        if not (console.is_terminal or console.is_jupyter):  # a file or a pipe: nothing
            yield _noop
            return
        bar = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                       MofNCompleteColumn(), TimeElapsedColumn(), console=console,
                       transient=True)
        stack: list[Any] = []
        token = _BAR.set((bar, stack))
        bar.start()
    else:
        bar, stack = outer
        token = None
    tid = bar.add_task(description, total=total)
    stack.append(tid)

    def advance(n: float = 1, *, description: str | None = None, total: float | None = None,
                completed: float | None = None) -> None:
        if description is None and total is None and completed is None:
            bar.advance(tid, n)
        else:
            bar.update(tid, completed=completed, advance=n, description=description,
                       total=total)

    try:
        yield advance
    finally:
        stack.pop()
        bar.remove_task(tid)
        if token is not None:
            bar.stop()
            _BAR.reset(token)


def step(n: float = 1, *, description: str | None = None, total: float | None = None
         ) -> None:
    """Advance the innermost open :func:`task` by ``n`` (a no-op when none is open, or when
    it was opened with ``show=False``); ``description`` and ``total`` as for its ``advance``.

    Code that calls it must run inside a task of its own (``show=False`` where it is too short
    to show), so that its steps never advance a caller's task.
    """
    current = _BAR.get()
    if current is None or not current[1] or current[1][-1] is None:
        return
    bar, stack = current
    if description is None and total is None:
        bar.advance(stack[-1], n)
    else:
        bar.update(stack[-1], advance=n, description=description, total=total)
