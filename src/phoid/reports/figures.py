"""Figures of results written as PNG files (matplotlib's object API, Agg canvas: no global state).

The ``plot_*`` functions name and write the files; the figures themselves are drawn by
:mod:`phoid.reports.runs` (one per run) and :mod:`phoid.reports.lines` (the lines m, c, k are
read from, the (m, k) confidence region). File names: ``<stem>.png`` per run (the run's file
name without folders and extensions; :func:`run_names`), ``lines.png``, ``mk-ellipse.png``;
the seed paper's ``figure1a.png`` and ``figure1b.png``.

matplotlib is imported inside the functions that draw, so importing this module is cheap. The
results are taken by duck typing (see :mod:`phoid.reports.text`): this subpackage never
imports the methods that make them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phoid._output import OutputFolder
from phoid.reports.text import format_number

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["DPI", "figure1", "figure1_panel", "plot_forced", "plot_free", "plot_friction",
           "plot_identification", "png_bytes", "run_names", "save_png"]


#: resolution of the PNG files, dots per inch
DPI = 120


def png_bytes(fig: Figure, dpi: float = DPI) -> bytes:
    """``fig`` rendered by Agg as an indexed-colour PNG (an adaptive palette of 256 colours).

    A figure is lines, text and flat fills in a few colours and their anti-aliased edges: 256
    colours hold them, and the file is about a third of the true-colour PNG's size and
    quicker to compress (the HTML report embeds every figure).
    """
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    canvas = FigureCanvasAgg(fig)
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
    written = [save_png(draw_run(i), out, names[i]) for i in plotted]
    written += [save_png(draw(), out, name) for name, draw in extra]
    return written


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
    paths = [save_png(figure1_panel(result, tag), out, f"figure1{tag}.png") for tag in "ab"]
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
