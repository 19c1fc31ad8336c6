"""Figures drawn in worker processes (:func:`phoid.reports.figures.render_pngs`).

The rule under test: where the figures are drawn changes nothing a user sees. The same files,
the same bytes as drawn one after another in the calling process, the same error and the same
warnings; drawing stays in the calling process where forking is unsafe (a daemonic process,
other Python threads). Expected values are those of the serial drawing
(``PHOID_FIGURE_WORKERS=1``, or ``workers=1``) and, for the file names, the set's manifest
(each run's file name without folders and extensions, then ``lines.png``, ``mk-ellipse.png``:
the names :func:`phoid.reports.figures.plot_identification` documents). Which process drew a
figure is read from files the drawing writes (its process id): real processes, real files.

Set: examples/paper-sample (19 runs, each with a fit: 21 figures); small figures of a few
artists where only the mechanism is under test. No timings here (bench/bench_figures.py).
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest
from typer.testing import CliRunner

import phoid
from phoid._output import OutputFolder
from phoid.cli import app
from phoid.io import read_experiment
from phoid.reports import figures
from phoid.reports.figures import (
    WORKERS_ENV,
    figure_workers,
    plot_identification,
    png_bytes,
    render_pngs,
    write_pngs,
)
from phoid.reports.lines import mk_ellipse_figure, pho_lines_figure
from phoid.reports.runs import pho_run_figure

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
FORKS = sys.platform != "darwin" and "fork" in multiprocessing.get_all_start_methods()
needs_fork = pytest.mark.skipif(not FORKS, reason="no fork start method: figures are drawn "
                                "in the calling process only")


@pytest.fixture(scope="module")
def gls():
    return phoid.identify(read_experiment(SAMPLE))


def _small_figure(folder: Path, k: int, fail: str = ""):
    """Figure ``k``: a line through k's points and its number, after writing the id of the
    process drawing it to ``folder``/``k``.pid. ``fail``: "raise" raises ValueError, "warn"
    gives a UserWarning, "die" ends a worker process (not the caller) at once, "hang" blocks
    a worker process (not the caller) for 60 s."""
    from matplotlib.figure import Figure

    (folder / f"{k}.pid").write_text(str(os.getpid()))
    if fail == "raise":
        raise ValueError(f"figure {k} cannot be drawn")
    if fail == "warn":
        warnings.warn(f"figure {k} says so", UserWarning, stacklevel=1)
    if fail == "die" and os.getpid() != int((folder / "caller.pid").read_text()):
        os._exit(3)
    if fail == "hang" and os.getpid() != int((folder / "caller.pid").read_text()):
        time.sleep(60)
    fig = Figure(figsize=(2, 1.5))
    ax = fig.subplots()
    ax.plot(range(k + 2), [j * j for j in range(k + 2)], label=f"figure {k}")
    ax.legend(fontsize=8)
    return fig


def _draws(folder: Path, n: int, **fail: str):
    """``n`` small figures; ``fail`` maps "k<number>" to that figure's ``fail``."""
    (folder / "caller.pid").write_text(str(os.getpid()))
    return [functools.partial(_small_figure, folder, k, fail.get(f"k{k}", ""))
            for k in range(n)]


def _pids(folder: Path, n: int) -> list[int]:
    return [int((folder / f"{k}.pid").read_text()) for k in range(n)]


# --------------------------------------------------------------------------------------------
# the example set: the files and their bytes


@needs_fork
def test_parallel_files_are_the_serial_files(gls, tmp_path, monkeypatch):
    assert all(r.fit is not None for r in gls.runs)  # every run has its figure
    monkeypatch.setenv(WORKERS_ENV, "1")
    serial = plot_identification(gls, tmp_path / "serial")
    monkeypatch.setenv(WORKERS_ENV, "3")
    parallel = plot_identification(gls, tmp_path / "parallel")
    expected = [Path(r.file).name.split(".")[0] + ".png" for r in read_experiment(SAMPLE).runs]
    expected += ["lines.png", "mk-ellipse.png"]
    assert [p.name for p in serial] == expected
    assert [p.name for p in parallel] == expected
    # nothing else in the folder (no temporary file left), and every file byte for byte
    assert sorted(p.name for p in (tmp_path / "parallel").iterdir()) == sorted(expected)
    for s, p in zip(serial, parallel, strict=True):
        assert p.read_bytes() == s.read_bytes(), p.name


def test_a_run_figure_drawn_after_others_is_the_one_drawn_alone(gls, tmp_path):
    # the run figures of one layout reuse one figure's axes, one after another: run 8 drawn
    # alone in a fresh interpreter must be the bytes of run 8 drawn eighth
    serial = list(render_pngs([functools.partial(pho_run_figure, gls, i) for i in range(8)],
                              workers=1))
    alone = tmp_path / "alone.png"
    code = ("import sys, phoid; from phoid.io import read_experiment; "
            "from phoid.reports.figures import png_bytes; "
            "from phoid.reports.runs import pho_run_figure; "
            "r = phoid.identify(read_experiment(sys.argv[1])); "
            "open(sys.argv[2], 'wb').write(png_bytes(pho_run_figure(r, 7)))")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "src"), *filter(None, [os.environ.get("PYTHONPATH")])]))
    subprocess.run([sys.executable, "-c", code, str(SAMPLE), str(alone)], check=True,
                   env=env, timeout=120)
    assert alone.read_bytes() == serial[7]
    # and the public function still gives a figure of its own, not one handed back
    a, b = pho_run_figure(gls, 0), pho_run_figure(gls, 1)
    assert a is not b and png_bytes(a) == serial[0]


# --------------------------------------------------------------------------------------------
# where the figures are drawn


@needs_fork
def test_figures_are_drawn_in_worker_processes_with_the_same_bytes(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    one.mkdir()
    two.mkdir()
    serial = list(render_pngs(_draws(one, 5), workers=1))
    assert set(_pids(one, 5)) == {os.getpid()}
    parallel = list(render_pngs(_draws(two, 5), workers=2))
    assert os.getpid() not in _pids(two, 5)
    assert parallel == serial


def _in_daemon(folder: str) -> None:
    """A daemonic process's work: draw 4 small figures and write them (it may have no
    children, so they must be drawn here)."""
    out = OutputFolder(folder)
    write_pngs(out, [(f"{k}.png", d) for k, d in enumerate(_draws(Path(folder), 4))])


@needs_fork
def test_a_daemonic_process_draws_its_figures_itself(tmp_path):
    ctx = multiprocessing.get_context("fork")
    proc = ctx.Process(target=_in_daemon, args=(str(tmp_path),), daemon=True)
    proc.start()
    proc.join(120)
    assert proc.exitcode == 0  # a daemon forking a worker would have failed (AssertionError)
    assert set(_pids(tmp_path, 4)) == {proc.pid}
    ref = tmp_path / "ref"
    ref.mkdir()
    serial = list(render_pngs(_draws(ref, 4), workers=1))
    assert [(tmp_path / f"{k}.png").read_bytes() for k in range(4)] == serial


@needs_fork
def test_with_another_thread_running_the_figures_are_drawn_here(tmp_path):
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()
    try:
        assert figure_workers(5, 4) == 1
        list(render_pngs(_draws(tmp_path, 5), workers=4))
    finally:
        stop.set()
        other.join()
    assert set(_pids(tmp_path, 5)) == {os.getpid()}
    assert figure_workers(5, 4) == 4  # the thread gone: workers again


# --------------------------------------------------------------------------------------------
# errors and warnings


@needs_fork
def test_an_error_in_a_figure_is_raised_as_drawn_here(tmp_path, capfd, monkeypatch):
    folders = [tmp_path / "serial", tmp_path / "parallel"]
    errors = []
    for folder, workers in zip(folders, ("1", "2"), strict=True):
        monkeypatch.setenv(WORKERS_ENV, workers)
        folder.mkdir()
        out = OutputFolder(folder / "png")
        with pytest.raises(ValueError) as info:
            write_pngs(out, [(f"{k}.png", d)
                             for k, d in enumerate(_draws(folder, 4, k2="raise"))])
        errors.append((type(info.value), str(info.value)))
    assert errors[0] == errors[1] == (ValueError, "figure 2 cannot be drawn")
    # the files before the failing one are written, as drawn one after another; none after
    for folder in folders:
        assert sorted(p.name for p in (folder / "png").iterdir()) == ["0.png", "1.png"]
    assert "Traceback" not in capfd.readouterr().err  # no worker printed its own


@needs_fork
def test_a_worker_that_dies_leaves_its_figures_to_the_caller(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    serial = list(render_pngs(_draws(tmp_path / "a", 4), workers=1))
    got = list(render_pngs(_draws(tmp_path / "b", 4, k1="die"), workers=2))
    assert got == serial
    assert int((tmp_path / "b" / "1.pid").read_text()) == os.getpid()  # drawn again here


@needs_fork
def test_a_warning_in_a_worker_is_given_here(tmp_path):
    with pytest.warns(UserWarning, match="figure 3 says so"):
        pngs = list(render_pngs(_draws(tmp_path, 4, k3="warn"), workers=2))
    assert len(pngs) == 4
    assert os.getpid() not in _pids(tmp_path, 4)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie, dead but not yet reaped, does not)."""
    proc = Path(f"/proc/{pid}/stat")
    if proc.parent.parent.is_dir() and Path("/proc/self").exists():
        try:
            return proc.read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
        except OSError:
            return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@needs_fork
def test_a_worker_that_hangs_is_not_waited_for_forever(tmp_path, monkeypatch):
    # figure 1's worker blocks for 60 s; with STALL_S set to 1 s, the caller gives up on
    # the workers after 1 s without a figure, kills them and draws figure 1 itself
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    serial = list(render_pngs(_draws(tmp_path / "a", 4), workers=1))
    monkeypatch.setattr(figures, "STALL_S", 1.0)
    start = time.monotonic()
    got = list(render_pngs(_draws(tmp_path / "b", 4, k1="hang"), workers=2))
    # 20 s: the stall bound (1 s) and four small figures, with room for a loaded machine;
    # far below the 60 s the hung worker would have taken
    assert time.monotonic() - start < 20
    assert got == serial
    assert int((tmp_path / "b" / "1.pid").read_text()) == os.getpid()  # drawn again here
    workers = {int(p.read_text()) for p in (tmp_path / "b").glob("*.pid")} - {os.getpid()}
    assert workers and not any(_alive(pid) for pid in workers)  # killed, not left behind


@needs_fork
def test_a_worker_that_cannot_be_forked_leaves_the_figures_here(tmp_path, monkeypatch):
    # the system refuses the second fork (EAGAIN: fork(2) at a process limit, as
    # RLIMIT_NPROC gives; not reproducible for root, who is exempt): the figures are drawn
    # here, as one after another, and the worker forked first is not left behind
    import errno

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    serial = list(render_pngs(_draws(tmp_path / "a", 4), workers=1))
    forked: list[int] = []
    real_fork = os.fork

    def fork() -> int:
        if forked:
            raise BlockingIOError(errno.EAGAIN, os.strerror(errno.EAGAIN))
        pid = real_fork()
        if pid:
            forked.append(pid)
        return pid

    monkeypatch.setattr(os, "fork", fork)
    got = list(render_pngs(_draws(tmp_path / "b", 4), workers=2))
    monkeypatch.undo()
    assert got == serial
    assert set(_pids(tmp_path / "b", 4)) == {os.getpid()}
    assert len(forked) == 1 and not _alive(forked[0])  # killed (and reaped)


@needs_fork
def test_workers_end_when_their_caller_is_killed(tmp_path):
    # a caller killed with SIGKILL cannot stop its pool: its workers, each blocked in a
    # figure, must end by themselves rather than wait forever on the caller's pipes
    code = (
        "import os, sys, time\n"
        "from pathlib import Path\n"
        "from matplotlib.figure import Figure\n"
        "from phoid.reports.figures import render_pngs\n"
        "folder, me = Path(sys.argv[1]), os.getpid()\n"
        "def draw(k):\n"
        "    (folder / f'{k}.pid').write_text(str(os.getpid()))\n"
        "    if os.getpid() != me:\n"
        "        time.sleep(60)\n"
        "    return Figure(figsize=(1, 1))\n"
        "list(render_pngs([lambda k=k: draw(k) for k in range(2)], workers=2))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "src"), *filter(None, [os.environ.get("PYTHONPATH")])]))
    env.pop(WORKERS_ENV, None)
    caller = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], env=env)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 60  # start-up: importing matplotlib, forking
        while len(workers) < 2 and time.monotonic() < deadline and caller.poll() is None:
            time.sleep(0.1)
            workers = {int(p.read_text() or 0) for p in tmp_path.glob("*.pid")} - {0}
        assert len(workers) == 2 and caller.pid not in workers
        caller.kill()
        caller.wait(30)
        # 10 s: the workers look for their caller every 0.25 s; far below their 60 s figure
        deadline = time.monotonic() + 10
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(pid) for pid in workers)
    finally:
        caller.kill()
        for pid in workers:  # left behind (the failure under test): ended here, by id
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


@needs_fork
def test_a_warning_from_a_worker_is_filtered_as_one_given_here(tmp_path):
    # the same place (file, line) as drawn here, so that a filter naming the module that gave
    # it treats it alike: here, every warning an error but this module's UserWarnings ignored
    places = []
    for workers in (1, 2):
        folder = tmp_path / str(workers)
        folder.mkdir()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            list(render_pngs(_draws(folder, 4, k3="warn"), workers=workers))
        places.append([(w.category, str(w.message), w.filename, w.lineno) for w in caught])
    assert places[0] == places[1] and len(places[0]) == 1
    assert places[0][0][2] == __file__  # given in _small_figure, stacklevel 1
    folder = tmp_path / "filtered"
    folder.mkdir()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", category=UserWarning, module=__name__)
        pngs = list(render_pngs(_draws(folder, 4, k3="warn"), workers=2))
    assert len(pngs) == 4 and os.getpid() not in _pids(folder, 4)


@pytest.mark.parametrize("report", ["run01.png/report.html", "lines.png/a/b.html",
                                    "X.PNG", "."])
def test_a_report_in_the_way_of_a_figure_is_refused_before_the_work(report, tmp_path):
    # --html under a name --plots writes (run01.png, the sample's first run; lines.png) would
    # make a folder of it, or the figure a folder: refused before anything is written
    plots = tmp_path / "png"
    r = CliRunner().invoke(app, ["identify", str(SAMPLE), "--plots", str(plots),
                                 "--html", str(plots / report)])
    assert r.exit_code == 2, r.output
    assert r.output.startswith("phoid: error: ") and "would collide" in r.output
    assert not plots.exists()


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5", "+3", "3 4"])
def test_a_bad_workers_setting_is_an_error_naming_the_variable(value, monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, value)
    with pytest.raises(ValueError, match=f"environment variable {WORKERS_ENV}="):
        figure_workers(5)


def test_the_command_line_says_which_setting_is_wrong(tmp_path):
    r = CliRunner().invoke(app, ["identify", str(SAMPLE), "--plots", str(tmp_path / "p")],
                           env={WORKERS_ENV: "many"})
    assert r.exit_code == 2
    assert r.output.startswith("phoid: error: ") and WORKERS_ENV in r.output
    assert "Traceback" not in r.output


def test_an_empty_setting_is_unset_and_one_is_serial(monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, "")
    assert figure_workers(1) == 1  # one figure: never a worker
    monkeypatch.setenv(WORKERS_ENV, "1")
    assert figure_workers(21) == 1


# --------------------------------------------------------------------------------------------
# legends readable (issue 30: 7-pt legends were too small)


def test_every_legend_is_at_least_8_pt(gls):
    figures = [pho_run_figure(gls, 0), pho_lines_figure(gls), mk_ellipse_figure(gls)]
    sizes = [t.get_fontsize() for fig in figures for ax in fig.axes
             if ax.get_legend() is not None for t in ax.get_legend().get_texts()]
    assert len(sizes) >= 8  # 3 legends of the run figure, the lines', the region's
    assert min(sizes) >= 8
