"""Figures of results written as PNG files (matplotlib's object API, Agg canvas: no global state).

The ``plot_*`` functions name and write the files; the figures themselves are drawn by
:mod:`phoid.reports.runs` (one per run) and :mod:`phoid.reports.lines` (the lines m, c, k are
read from, the (m, k) confidence region). File names: ``<stem>.png`` per run (the run's file
name without folders and extensions; :func:`run_names`), ``lines.png``, ``mk-ellipse.png``;
the seed paper's ``figure1a.png`` and ``figure1b.png``.

Figures are drawn in parallel (:func:`render_pngs`): a set's figures are independent, and
each costs matplotlib a few tenths of a second of fixed work (axes, ticks, text, legends),
whatever its data. Where the platform forks (POSIX), the figures are shared out among
worker processes forked from this one (at most one per usable CPU, :data:`MAX_WORKERS`, one
per figure), each returning its figures' PNG bytes, which this process writes in order: the
files and their bytes are those of drawing them one after another. They are drawn here, one
after another, where forking is not possible or not safe: one usable CPU, no ``fork`` start
method (Windows; macOS, where Apple's libraries are not fork-safe), a daemonic process (a
``multiprocessing`` or Dask worker, which may have no children), a process running other
Python threads (a notebook kernel, a threaded server). The environment variable
:data:`WORKERS_ENV` (``PHOID_FIGURE_WORKERS``), a whole number ≥ 1, sets how many processes
draw (``1``: this one, one after another); unset, one per usable CPU.

Nothing waits forever on a worker: one that dies leaves its figures to this process, and so
do all of them when no figure has come back for :data:`STALL_S` seconds (a worker stopped or
deadlocked), the workers then killed, or when a worker cannot be forked (a limit on processes
or memory reached). A worker ends itself when the process that forked it
is gone (killed, say, by SIGTERM or SIGKILL): no drawing process outlives its caller.

matplotlib is imported inside the functions that draw, so importing this module is cheap. The
results are taken by duck typing (see :mod:`phoid.reports.text`): this subpackage never
imports the methods that make them.
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid._output import OutputFolder
from phoid._threads import single_blas_thread
from phoid.reports.text import format_number

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["DPI", "MAX_WORKERS", "STALL_S", "WORKERS_ENV", "figure1", "figure1_panel",
           "figure_workers", "plot_forced", "plot_free", "plot_friction", "plot_identification",
           "png_bytes", "render_pngs", "run_names", "save_png", "write_pngs"]


#: resolution of the PNG files, dots per inch
DPI = 120
#: the environment variable that bounds the processes drawing figures (a whole number ≥ 1;
#: 1 draws them in the calling process, one after another)
WORKERS_ENV = "PHOID_FIGURE_WORKERS"
#: the most worker processes drawing figures at once (each holds a copy of matplotlib's state)
MAX_WORKERS = 8
#: seconds without any figure coming back from the workers after which they are killed and
#: the figures still missing are drawn in the calling process (a figure takes a fraction of
#: a second; the time this process is stopped, by Ctrl-Z, counts as one second at most)
STALL_S = 120.0
#: seconds between a worker's checks that the process that forked it is still there
_ORPHAN_POLL_S = 0.25

#: the figures the worker processes draw: set just before they are forked, read there by index
#: (the draw callables are closures over results: inherited, never pickled)
_PENDING: list[Callable[[], Figure]] = []


def png_bytes(fig: Figure, dpi: float = DPI) -> bytes:
    """``fig`` rendered by Agg as an indexed-colour PNG (an adaptive palette of 256 colours).

    A figure is lines, text and flat fills in a few colours and their anti-aliased edges: 256
    colours hold them, and the file is about a third of the true-colour PNG's size and
    quicker to compress (the HTML report embeds every figure).
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    # a figure drawn again (a run figure's axes reused: :func:`phoid.reports.runs.recycle`)
    # keeps its canvas, and the canvas its renderer: the sizes of texts drawn before are known
    canvas = fig.canvas if type(fig.canvas) is FigureCanvasAgg else FigureCanvasAgg(fig)
    fig.set_dpi(dpi)
    canvas.draw()
    image = Image.fromarray(np.asarray(canvas.buffer_rgba())).convert("RGB")
    buf = io.BytesIO()
    image.quantize(colors=256, method=Image.Quantize.FASTOCTREE,
                   dither=Image.Dither.NONE).save(buf, format="png")
    return buf.getvalue()


def save_png(fig: Figure, out: OutputFolder, name: str) -> Path:
    """Render ``fig`` as PNG (:func:`png_bytes`) into ``out``/``name`` (atomic, no links
    followed)."""
    return out.write(name, png_bytes(fig))


@single_blas_thread
def _png_of(draw: Callable[[], Figure]) -> bytes:
    """The PNG of the figure ``draw`` returns; a run figure is then handed back for the next
    one to reuse (:func:`phoid.reports.runs.recycle`).

    With one BLAS thread (:mod:`phoid._threads`): drawing is many tiny matrix products
    (matplotlib's transforms), for which OpenBLAS's pool only spins; with a thread per core
    it used half again the CPU time of the drawing, and two processes drawing at once got
    in each other's way.
    """
    from phoid.reports.runs import recycle

    fig = draw()
    png = png_bytes(fig)
    recycle(fig)
    return png


def _usable_cpus() -> int:
    """The CPUs this process may run on (its affinity where the platform says, else all)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _workers_setting() -> int | None:
    """:data:`WORKERS_ENV` as a whole number ≥ 1, or None where it is unset or empty.

    Raises
    ------
    ValueError
        It is set to anything else (one line naming the variable and its value).
    """
    text = os.environ.get(WORKERS_ENV, "").strip()
    if not text:
        return None
    try:
        value = int(text, 10)
    except ValueError:
        value = 0
    if value < 1 or not (text.isascii() and text.isdigit()):
        raise ValueError(f"environment variable {WORKERS_ENV}={text[:40]!r}: give a whole "
                         "number >= 1 (the processes drawing figures; 1: one after another "
                         "in this process)")
    return value


def figure_workers(n: int, workers: int | None = None) -> int:
    """How many processes :func:`render_pngs` draws ``n`` figures with (1: this process alone).

    ``workers`` if given, else :data:`WORKERS_ENV` if set, else the usable CPUs
    (``os.sched_getaffinity``); at most ``n`` and :data:`MAX_WORKERS`. 1 where forking is
    not possible or not safe, whatever was asked: no ``fork`` start method (or macOS, whose
    system libraries are not fork-safe), a daemonic process (which may have no children), or
    other Python threads running in this one (a fork copies only the calling thread, and the
    locks the others hold).

    Raises
    ------
    ValueError
        :data:`WORKERS_ENV` is set to something other than a whole number ≥ 1.
    """
    if workers is None:
        workers = _workers_setting() or _usable_cpus()
    cap = min(int(workers), int(n), MAX_WORKERS)
    if cap < 2 or sys.platform == "darwin" \
            or "fork" not in multiprocessing.get_all_start_methods() \
            or multiprocessing.current_process().daemon or threading.active_count() > 1:
        return 1
    return cap


def _draw_png(k: int) -> tuple[bytes | None, list[tuple[Any, str, str, int]]]:
    """In a worker: figure ``k`` of :data:`_PENDING` as PNG bytes, and the warnings drawing it
    gave (category, message, file name, line: where it was given); None for the bytes where
    drawing failed (the caller draws it again, to raise what drawing it there raises)."""
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            png = _png_of(_PENDING[k])
        said = []
        for w in caught:
            category = w.category
            try:
                pickle.dumps(category)
            except Exception:  # a category defined where it cannot be named: kept as text
                category = RuntimeWarning
            said.append((category, str(w.message), str(w.filename), int(w.lineno)))
        return png, said
    except BaseException:  # any failure: drawn again by the caller, which raises it
        return None, []


def _worker_start(parent: int) -> None:
    """A worker ignores Ctrl-C: the process that forked it stops the work, once. It ends
    itself as soon as that process (id ``parent``) is gone: a caller killed with no chance
    to stop its pool (SIGTERM, SIGKILL) would otherwise leave its workers blocked forever on
    the pipes it held."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_ORPHAN_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="phoid-orphan-watch", daemon=True).start()


def _warn_again(category: Any, message: str, filename: str, lineno: int) -> None:
    """Give here a warning a worker's drawing gave, from where it was given (its file, line
    and module, and that module's registry of warnings given): the filters that match it
    (by module: ``ignore::RuntimeWarning:numpy``) and the once-per-place rule treat it as
    they treat it drawn here."""
    module = next((name for name, mod in list(sys.modules.items())
                   if getattr(mod, "__file__", None) == filename), None)
    registry = (vars(sys.modules[module]).setdefault("__warningregistry__", {})
                if module is not None else None)
    warnings.warn_explicit(message, category, filename, lineno, module=module,
                           registry=registry)


class _Stalled(Exception):
    """No figure came back from the workers for :data:`STALL_S` seconds."""


def _result(futures: dict[int, Any], k: int) -> Any:
    """Figure ``k``'s result, waiting while the workers make progress: :class:`_Stalled`
    once no figure has come back for :data:`STALL_S` seconds, counted in ticks of at most
    one second (a pause of this process, Ctrl-Z, counts as one tick, not as its length)."""
    from concurrent.futures import TimeoutError as FutureTimeout

    tick = min(1.0, STALL_S / 10)
    done, idle = -1, 0.0
    while True:
        try:
            return futures[k].result(timeout=tick)
        except FutureTimeout:
            now = sum(f.done() for f in futures.values())
            idle = 0.0 if now > done else idle + tick
            done = now
            if idle >= STALL_S:
                raise _Stalled from None


def _kill_workers(pool: Any) -> None:
    """Kill ``pool``'s worker processes (stalled, or the caller stopped): its pending
    figures fail with BrokenProcessPool, and its shutdown no longer waits on them."""
    # concurrent.futures keeps its processes in ``_processes`` (Python 3.14: kill_workers)
    kill = getattr(pool, "kill_workers", None)
    if callable(kill):
        kill()
        return
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.kill()
    for proc in procs:  # reaped: no zombie left where the pool's own thread never ran
        with contextlib.suppress(Exception):
            proc.join(5)


def _prepare_to_fork() -> None:
    """Import what drawing needs and load the font list here, once, for every worker."""
    from matplotlib import font_manager
    from matplotlib.backends import backend_agg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401
    from PIL import Image  # noqa: F401

    font_manager.findfont(font_manager.FontProperties())


def render_pngs(draws: Sequence[Callable[[], Figure]], *,
                workers: int | None = None) -> Iterator[bytes]:
    """The PNG bytes (:func:`png_bytes`) of the figure each of ``draws`` returns, in order.

    Parameters
    ----------
    draws : sequence of callables
        Each returns a new matplotlib Figure that nothing else holds (made afresh, in
        whichever process draws it): a run figure is handed back once drawn, for the next one
        to reuse (:func:`phoid.reports.runs.recycle`).
    workers : int, optional
        The most processes to draw with (1: this process, one after another); default
        :data:`WORKERS_ENV`, else one per usable CPU. Bounded by :func:`figure_workers`.

    Yields
    ------
    bytes
        Figure ``k``'s PNG, as drawn in this process: the bytes do not depend on where or in
        which order the figures were drawn.

    Raises
    ------
    Exception
        What drawing a figure raises, as drawing it in this process raises it: a worker that
        fails leaves the figure to this process, which draws it again (and raises there);
        a warning a worker's drawing gives is given again here, from the file and line
        that gave it (filters naming its module apply). A worker that dies, or workers that
        return no figure for :data:`STALL_S` seconds (then killed), leave the figures still
        missing to this process.
    ValueError
        :data:`WORKERS_ENV` is not a whole number ≥ 1.
    """
    draws = list(draws)
    n = figure_workers(len(draws), workers)
    if n < 2:
        for draw in draws:
            yield _png_of(draw)
        return
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    _prepare_to_fork()
    pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"),
                               initializer=_worker_start, initargs=(os.getpid(),))
    finished = False
    try:
        _PENDING[:] = draws
        try:
            with warnings.catch_warnings():
                # Python ≥ 3.12 warns about forking a process with native threads (a BLAS
                # pool's): none of them runs Python or holds a lock the workers take, and
                # forking with other Python threads running is refused above
                warnings.filterwarnings("ignore", category=DeprecationWarning,
                                        message=r".*multi-threaded.*fork")
                # last first: the whole-set figures come last and cost the most
                futures = {k: pool.submit(_draw_png, k) for k in reversed(range(len(draws)))}
            broken = False
        except OSError:  # a worker could not be forked (a process or memory limit reached)
            futures, broken = {}, True  # drawn here, as where forking is not possible
            _kill_workers(pool)  # those forked before
        finally:
            _PENDING.clear()  # the workers hold their copy; nothing here keeps the figures
        for k in range(len(draws)):
            png, said = None, []
            if not broken:
                try:
                    png, said = _result(futures, k)
                except (BrokenProcessPool, _Stalled) as exc:  # the rest are drawn here
                    broken = True
                    if isinstance(exc, _Stalled):
                        _kill_workers(pool)
            for category, message, filename, lineno in said:
                _warn_again(category, message, filename, lineno)
            yield png if png is not None else _png_of(draws[k])
        finished = True
    finally:
        if not finished:  # an error, Ctrl-C or the consumer gone: no figure is waited for
            _kill_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)


def write_pngs(out: OutputFolder, figures: Sequence[tuple[str, Callable[[], Figure]]]
               ) -> list[Path]:
    """Draw ``figures`` (each ``(name, draw)``) with :func:`render_pngs` and write each to
    ``out``/``name`` as it comes, in order (:meth:`phoid._output.OutputFolder.write`:
    atomic, no links followed). Returns the paths written.

    The names are not checked here: check them all first (:meth:`OutputFolder.check`), so
    that a file in the way writes nothing.
    """
    names = [name for name, _ in figures]
    written = []
    with contextlib.closing(render_pngs([draw for _, draw in figures])) as pngs:
        for name, png in zip(names, pngs, strict=True):
            written.append(out.write(name, png))
    return written


def _stem(file: str) -> str:
    """A run's file name without folders and extensions (``data/run01.csv.gz`` → ``run01``)."""
    return Path(str(file)).name.split(".")[0] or "run"


def run_names(files: Sequence[str], reserved: Sequence[str] = ()) -> list[str]:
    """The PNG names of per-run figures: ``<stem>.png``, the run's file name without folders
    and extensions; where two runs share a stem, or a stem is one of the ``reserved`` names
    (``lines``, ``mk-ellipse``), those runs are ``NN-<stem>.png`` (NN the 1-based run number).
    """
    stems = [_stem(f) for f in files]
    taken = {Path(n).stem for n in reserved}
    counts: dict[str, int] = {}
    for s in stems:
        counts[s] = counts.get(s, 0) + 1
    return [f"{s}.png" if counts[s] == 1 and s not in taken else f"{i + 1:02d}-{s}.png"
            for i, s in enumerate(stems)]


def plot_identification(ident: Any, out_dir: str | Path, *,
                        overwrite: bool = False) -> list[Path]:
    """Per-run decay fits, the eq. (35) lines and the (m, k) confidence region, as PNG files.

    Parameters
    ----------
    ident : phoid.Identification or alike
        Read: what :func:`phoid.reports.runs.pho_run_figure`,
        :func:`phoid.reports.lines.pho_lines_figure` and
        :func:`phoid.reports.lines.mk_ellipse_figure` read (``runs``, ``data``, ``u``, ``fit``,
        ``delay``, ``m``, ``c``, ``k``, ``cov``).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``<stem>.png`` for every run with a fit (:func:`run_names`), then
        ``lines.png`` (eq. 35, residuals in stderr units) and ``mk-ellipse.png``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    from phoid.reports.lines import mk_ellipse_figure, pho_lines_figure
    from phoid.reports.runs import pho_run_figure

    plotted = [i for i, r in enumerate(ident.runs) if r.fit is not None and i < len(ident.data)]
    extra: list[tuple[str, Callable[[], Figure]]] = []
    if any(r.used for r in ident.runs):
        extra = [("lines.png", lambda: pho_lines_figure(ident)),
                 ("mk-ellipse.png", lambda: mk_ellipse_figure(ident))]
    return _write_figures(out_dir, overwrite, ident.runs, plotted,
                          lambda i: pho_run_figure(ident, i), extra)


def _write_figures(out_dir: str | Path, overwrite: bool, runs: Sequence[Any],
                   plotted: Sequence[int], draw_run: Callable[[int], Figure],
                   extra: Sequence[tuple[str, Callable[[], Figure]]] = ()) -> list[Path]:
    """The per-run scaffolding of the ``plot_*`` functions: names, checks, then the writes.

    Run ``i`` (0-based, in ``plotted``) is drawn by ``draw_run(i)`` into its
    :func:`run_names` name (from ``runs[i].file``, or ``.name``); the ``extra`` figures follow,
    each ``(name, draw)``. Every name is checked in ``out_dir`` before the first figure is
    drawn (:meth:`phoid._output.OutputFolder.check`), so a file in the way writes nothing.
    Returns the paths written, in that order.
    """
    files = [getattr(r, "file", None) or getattr(r, "name", f"run{j + 1}")
             for j, r in enumerate(runs)]
    all_names = run_names(files, [name for name, _ in extra])
    names = {i: all_names[i] for i in plotted}
    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check([*names.values(), *(name for name, _ in extra)])
    return write_pngs(out, [*((names[i], functools.partial(draw_run, i)) for i in plotted),
                            *extra])


def plot_free(result: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Per-run record of a free-decay set with its fitted free response, as PNG files.

    Parameters
    ----------
    result : phoid.methods.free.FreeIdentification or alike
        Read: what :func:`phoid.reports.runs.free_run_figure` reads.
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``<stem>.png`` for every run used (:func:`run_names`).

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    from phoid.reports.runs import free_run_figure

    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    return _write_figures(out_dir, overwrite, result.runs, plotted,
                          lambda i: free_run_figure(result, i))


def plot_forced(result: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Per-run fits of a forced set, the eq. (20) lines and the (m, k) region, as PNG files.

    Parameters
    ----------
    result : phoid.methods.forced.ForcedIdentification or alike
        Read: what :func:`phoid.reports.runs.forced_run_figure`,
        :func:`phoid.reports.lines.forced_lines_figure` and
        :func:`phoid.reports.lines.mk_ellipse_figure` read (``runs``, ``data``, ``m``, ``c``,
        ``k``, ``cov``).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``<stem>.png`` for every run used (:func:`run_names`), then
        ``lines.png`` (eq. 20, residuals in stderr units) and ``mk-ellipse.png``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    from phoid.reports.lines import forced_lines_figure, mk_ellipse_figure
    from phoid.reports.runs import forced_run_figure

    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    return _write_figures(out_dir, overwrite, result.runs, plotted,
                          lambda i: forced_run_figure(result, i),
                          [("lines.png", lambda: forced_lines_figure(result)),
                           ("mk-ellipse.png", lambda: mk_ellipse_figure(result))])


def plot_friction(result: Any, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
    """Per-run friction fits (record, simulated fit, stick intervals) and the (m, k) region.

    Parameters
    ----------
    result : phoid.methods.friction.FrictionFit or alike
        Read: what :func:`phoid.reports.runs.friction_run_figure` and
        :func:`phoid.reports.lines.mk_ellipse_figure` read (``runs`` with ``used``,
        ``data``, ``model``, ``fc``, ``m``, ``k`` and ``cov``, the (4, 4) covariance of
        (m, c, k, f_c)).
    out_dir : path
        Folder to write PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    list of Path
        The files written: ``<stem>.png`` for every run used (:func:`run_names` of the run
        names), then ``mk-ellipse.png``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for all figures before the first is written.
    """
    from phoid.reports.lines import mk_ellipse_figure
    from phoid.reports.runs import friction_run_figure

    plotted = [i for i, r in enumerate(result.runs) if r.used and i < len(result.data)]
    return _write_figures(out_dir, overwrite, result.runs, plotted,
                          lambda i: friction_run_figure(result, i),
                          [("mk-ellipse.png", lambda: mk_ellipse_figure(result))])


def figure1(result: Any, out_dir: str | Path, *,
            overwrite: bool = False) -> tuple[Path, Path]:
    """The seed paper's Figure 1(a) and 1(b) as PNG files.

    (a) c′ᵢ against 2σᵢ, (b) k′ᵢ against ω₀ᵢ²: delay-compensated points as circles with the solid
    least-squares line, uncompensated points as crosses with the dashed line.

    Parameters
    ----------
    result : phoid.paper.PaperResult or alike
        Read: ``with_compensation`` and ``without_compensation``, each with ``c_line`` and
        ``k_line`` (``x``, ``y``, ``slope``, ``intercept``).
    out_dir : path
        Folder to write the PNG files into (created if needed).
    overwrite : bool
        Replace existing files of the same names (otherwise they are an error; links in the
        folder are refused either way: see :mod:`phoid._output`).

    Returns
    -------
    (Path, Path)
        ``figure1a.png`` and ``figure1b.png`` in ``out_dir``.

    Raises
    ------
    phoid.errors.OutputError
        A file in the way; checked for both figures before the first is written.
    """
    out = OutputFolder(out_dir, overwrite=overwrite)
    out.check(["figure1a.png", "figure1b.png"])
    paths = write_pngs(out, [(f"figure1{tag}.png", functools.partial(figure1_panel, result, tag))
                             for tag in "ab"])
    return paths[0], paths[1]


def figure1_panel(result: Any, tag: str) -> Figure:
    """The seed paper's Figure 1(``tag``), ``tag`` "a" or "b", as :func:`figure1` writes it.

    (a) c′ᵢ against 2σᵢ: slope the mass, intercept minus the viscous damping c; (b) k′ᵢ
    against ω₀ᵢ²: slope the mass, intercept minus the stiffness k. ``result`` as
    :func:`figure1` reads it.
    """
    from matplotlib.figure import Figure

    w, wo = result.with_compensation, result.without_compensation
    line_w, line_wo, xlabel, ylabel, unit, title = {
        "a": (w.c_line, wo.c_line, r"$2\sigma_i$ (1/s)", r"$c'_i$ (N s/m)", "N s/m",
              "(a) Mass (slope) and viscous damping (intercept)"),
        "b": (w.k_line, wo.k_line, r"$\omega_{0i}^2$ (rad²/s²)", r"$k'_i$ (N/m)", "N/m",
              "(b) Mass (slope) and stiffness (intercept)"),
    }[tag]
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.subplots()
    xx = np.linspace(0.0, max(line_w.x.max(), line_wo.x.max()) * 1.05, 50)
    ax.plot(line_w.x, line_w.y, "o", mfc="none", color="C0", label="with delay compensation")
    ax.plot(xx, line_w.slope * xx + line_w.intercept, "-", color="C0",
            label=f"fit: slope {format_number(line_w.slope)} kg, intercept "
                  f"{format_number(line_w.intercept)} {unit}")
    ax.plot(line_wo.x, line_wo.y, "x", color="C3", label="without compensation")
    ax.plot(xx, line_wo.slope * xx + line_wo.intercept, "--", color="C3",
            label=f"fit: slope {format_number(line_wo.slope)} kg, "
                  f"intercept {format_number(line_wo.intercept)} {unit}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig
