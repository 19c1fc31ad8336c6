"""Hostile inputs to `phoid batch`, `phoid trend` and `phoid design --rehearse` (issue 20 review).

Each test is the regression test of one finding of the review: bad input must give one line
naming the argument or file and exit status 2 (DEVELOPERS standards), never a hang, a
traceback, a file replaced unasked or a silently dropped number.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
from pathlib import Path

import pytest
from typer.testing import CliRunner

from phoid.batch.cluster import MAX_WORKERS_PER_CPU, cluster_client
from phoid.batch.drift_plot import MAX_NAME, trend_figure_names
from phoid.batch.sets import expand_sets
from phoid.cli import app
from phoid.errors import ExperimentError, OutputError, PhoidError

pd = pytest.importorskip("pandas", reason="the batch extra (pandas) is not installed")
pytest.importorskip("pyarrow", reason="the batch extra (pyarrow) is not installed")
pytest.importorskip("distributed", reason="the batch extra (dask.distributed) is not installed")

runner = CliRunner()

# a hang guard, not a performance bound: a call that should end within about 2 x its 0.5 s
# timeout must have ended long before this (a regression hangs for ever)
HANG_GUARD_S = 60.0


def _one_line_error(result, *needles: str) -> None:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def _set(folder: Path) -> Path:
    """A folder that names a set (expand_sets reads no manifest)."""
    folder.mkdir(parents=True)
    (folder / "experiment.toml").write_text('method = "pho"\n')
    return folder


# --- which sets ------------------------------------------------------------------------------


def test_a_folder_and_its_manifest_are_one_set(tmp_path):
    # finding: `s1` and `s1/experiment.toml` were two rows (the set identified twice)
    s1 = _set(tmp_path / "s1")
    (tmp_path / "link").symlink_to(s1)
    names = expand_sets([s1, s1 / "experiment.toml", tmp_path / "link",
                         tmp_path / "link" / "experiment.toml", str(tmp_path / "s*")])
    assert names == [str(s1.resolve())]


def test_an_empty_list_file_is_an_error_naming_it(tmp_path):
    # finding: a list of only comments and blank lines ran a batch of no set, status 0
    listing = tmp_path / "sets.txt"
    listing.write_text("# nothing yet\n\n   \n")
    with pytest.raises(ExperimentError, match=r"sets\.txt: the list of sets names no set"):
        expand_sets([listing])
    res = runner.invoke(app, ["batch", str(listing), "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0"])
    _one_line_error(res, "sets.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sets.txt"]  # nothing written


def test_list_file_entries_are_relative_to_the_list_files_folder(tmp_path, monkeypatch):
    # documented in `phoid batch --help`: relative to the list file, not to the cwd
    s1 = _set(tmp_path / "fleet" / "s1")
    (tmp_path / "fleet" / "sets.txt").write_text("# the fleet\n\n  s1  \ns1/experiment.toml\n")
    monkeypatch.chdir(tmp_path)
    assert expand_sets(["fleet/sets.txt"]) == [str(s1.resolve())]
    help_text = " ".join(runner.invoke(app, ["batch", "--help"]).output.split())
    assert "list file's folder" in help_text.replace("│ ", "").replace(" │", "")


def test_a_set_path_that_is_not_utf8_is_refused_before_any_work(tmp_path):
    # finding: a folder named b"s\xff" ended the batch halfway with "'utf-8' codec can't
    # encode character '\udcff'", a journal left behind
    import os

    s1 = _set(tmp_path / "s1")
    try:
        os.mkdir(os.path.join(os.fsencode(tmp_path), b"s\xff"))
    except (OSError, UnicodeError):
        pytest.skip("this file system refuses names that are not UTF-8")
    bad = os.fsdecode(os.path.join(os.fsencode(tmp_path), b"s\xff"))
    with pytest.raises(ExperimentError, match="not UTF-8 text"):
        expand_sets([s1, bad])
    res = runner.invoke(app, ["batch", str(s1), bad, "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0"])
    _one_line_error(res, "not UTF-8 text")
    assert not (tmp_path / "r.parquet").exists()
    assert not (tmp_path / "r.journal.jsonl").exists()


# --- the output ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["r.csv", "r.CSV", "r.Csv"])
def test_an_output_named_csv_is_refused_in_any_case(tmp_path, name):
    # finding: --out r.CSV wrote the Parquet table into r.CSV and the CSV into r.csv (one
    # file on a case-insensitive file system: the table overwritten by its CSV)
    from phoid.batch.store import BatchStore

    with pytest.raises(OutputError, match="must not end in"):
        BatchStore(tmp_path / name)
    s1 = _set(tmp_path / "s1")
    res = runner.invoke(app, ["batch", str(s1), "--out", str(tmp_path / name), "--workers", "0"])
    _one_line_error(res, name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1"]


# --- the scheduler ---------------------------------------------------------------------------


@contextlib.contextmanager
def _listener(reply: bytes | None):
    """A TCP port on 127.0.0.1 that accepts connections and sends ``reply`` (None: nothing,
    ever): a firewall's black hole, or another service on the scheduler's port."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.settimeout(0.2)
    stop = threading.Event()
    held = []

    def serve():
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            held.append(conn)
            if reply is not None:
                with contextlib.suppress(OSError):
                    conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        server.close()


def _connect_in_thread(address: str, timeout: float) -> BaseException | None:
    """cluster_client(address) entered in a thread: the exception it raised (None: none);
    fails the test when it has not returned within HANG_GUARD_S."""
    outcome: list[BaseException | None] = []

    def attempt():
        try:
            with cluster_client(address, timeout=timeout):
                outcome.append(None)
        except BaseException as exc:  # handed to the test
            outcome.append(exc)

    thread = threading.Thread(target=attempt, daemon=True)
    thread.start()
    thread.join(HANG_GUARD_S)
    assert outcome, f"cluster_client({address!r}, timeout={timeout}) hangs"
    return outcome[0]


@pytest.mark.parametrize("reply", [None, b"HTTP/1.0 400 Bad Request\r\n\r\n" + b"\xff" * 64],
                         ids=["silent", "not-dask"])
def test_a_scheduler_that_accepts_but_does_not_answer_is_one_line_in_bounded_time(reply):
    # finding: distributed.Client bounds the TCP connect but not the handshake after it; a
    # listener that accepts and never answers hung `phoid batch --scheduler` for ever
    with _listener(reply) as address:
        exc = _connect_in_thread(address, 0.5)
    assert isinstance(exc, PhoidError), repr(exc)
    assert address in str(exc) and "\n" not in str(exc)


@pytest.mark.parametrize("address", ["foo", "tcp://", "http://x", "inproc://x"])
def test_a_malformed_scheduler_address_is_one_line_naming_it(address):
    # finding: 'inproc://x' said only "not enough values to unpack (expected 3, got 1)"
    exc = _connect_in_thread(address, 0.5)
    assert isinstance(exc, PhoidError), repr(exc)
    assert f"{address!r}" in str(exc)


@pytest.mark.parametrize("timeout", ["0", "-1", "nan", "inf"])
def test_a_bad_scheduler_timeout_is_refused(tmp_path, timeout):
    # finding: --timeout nan/inf reached distributed (a KeyError, exit status 1), -1 a
    # ValueError about the string '1-1.0'
    s1 = _set(tmp_path / "s1")
    res = runner.invoke(app, ["batch", str(s1), "--out", str(tmp_path / "r.parquet"),
                              "--scheduler", "tcp://127.0.0.1:9", f"--timeout={timeout}"])
    _one_line_error(res, "--timeout")
    assert not (tmp_path / "r.parquet").exists()


def test_the_cli_reports_a_silent_scheduler_with_status_2(tmp_path):
    s1 = _set(tmp_path / "s1")
    results = []
    with _listener(None) as address:
        thread = threading.Thread(target=lambda: results.append(runner.invoke(app, [
            "batch", str(s1), "--out", str(tmp_path / "r.parquet"), "--scheduler", address,
            "--timeout", "0.5"])), daemon=True)
        thread.start()
        thread.join(HANG_GUARD_S)
    assert results, "phoid batch --scheduler hangs on a scheduler that does not answer"
    _one_line_error(results[0], address, "does not answer within 0.5 s")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1"]


# --- the workers -----------------------------------------------------------------------------


def test_more_local_workers_than_the_limit_are_refused_before_starting_any(tmp_path):
    # finding: --workers 1000 started a thousand Python processes on a 2-CPU machine
    from phoid.batch.cluster import _cpus

    too_many = MAX_WORKERS_PER_CPU * _cpus() + 1
    with pytest.raises(PhoidError, match=f"--workers {too_many} is more than"), \
            cluster_client(workers=too_many):
        pass
    s1 = _set(tmp_path / "s1")
    res = runner.invoke(app, ["batch", str(s1), "--out", str(tmp_path / "r.parquet"),
                              "--workers", str(too_many)])
    _one_line_error(res, f"--workers {too_many}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1"]


def test_design_rehearse_with_workers_0_runs_in_this_process():
    # finding: `phoid batch --workers 0` runs in this process, `phoid design --rehearse N
    # --workers 0` failed with "workers must be at least 1"; the replicas are the seed's
    # whichever way they run (phoid.rehearse without a client is the reference)
    import json

    import phoid

    args = ["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.1", "--runs", "6",
            "--noise", "1e-4", "--duration", "4"]
    res = runner.invoke(app, [*args, "--rehearse", "2", "--workers", "0", "--seed", "7",
                              "--json"])
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["rehearsal"]
    plan = phoid.design(2, 1, 64, delay=0.1, runs=6, noise=1e-4, duration=4.0)
    here = phoid.rehearse(plan, 2, seed=7)
    assert [got["parameters"][p.name]["rmse"] for p in here.parameters] == [
        p.rmse for p in here.parameters]
    res = runner.invoke(app, [*args, "--rehearse", "2", "--workers", "-1"])
    _one_line_error(res, "--workers")


# --- trend -----------------------------------------------------------------------------------


def _rows(stderr_of_last: float) -> pd.DataFrame:
    """Eight nightly rows of one axis: m = 1 kg ± 0.1 for seven, then m = 5 kg (a step of 40
    stderr) with the given stderr."""
    rows = []
    for i in range(8):
        rows.append({"set": f"sets/a-{i}", "checksum": f"{i:064x}", "options": "{}",
                     "status": "ok", "method": "pho", "axis": "a",
                     "time": pd.Timestamp("2026-11-01T02:00Z") + pd.Timedelta(days=i),
                     "finished": pd.Timestamp("2026-12-01T00:00Z"),
                     "m": 1.0 if i < 7 else 5.0, "m_stderr": 0.1 if i < 7 else stderr_of_last})
    return pd.DataFrame(rows)


@pytest.mark.parametrize("stderr", [0.0, math.nan, -0.1, math.inf])
def test_an_estimate_without_a_usable_stderr_is_not_dropped_silently(stderr):
    # finding: a point with a zero or NaN stderr left the chart without a word, so a step of
    # 4 kg did not show at all
    from phoid.batch.drift import trend

    result = trend(_rows(stderr))
    chart = result.units[0].charts[0]
    assert len(chart.points) == 7
    assert any("a, m: 1 of 8 estimates without a finite value and stderr > 0" in w
               and "sets/a-7" in w for w in result.warnings), result.warnings


def test_a_non_finite_estimate_is_left_out_with_a_warning_naming_its_set():
    # finding: one m = inf in the table ended the whole trend with "`values` must be finite
    # and `stderrs` finite and > 0", naming neither the unit nor the set
    from phoid.batch.drift import trend

    rows = _rows(0.1)
    rows.loc[3, "m"] = math.inf
    result = trend(rows)
    assert [p.set for p in result.units[0].charts[0].points] == [
        f"sets/a-{i}" for i in (0, 1, 2, 4, 5, 6, 7)]
    assert any("a, m: 1 of 8" in w and "sets/a-3" in w for w in result.warnings)


def test_figure_names_are_distinct_and_short_whatever_the_units():
    # finding: ["a_1-03", "a/1", "a_1"] gave trend-a_1-03.png twice (the third unit's
    # numbered name was the first's), and a 300-character unit a name the file system
    # refuses (ENAMETOOLONG after the other figures were written)
    units = ["a_1-03", "a/1", "a_1", "x" * 300, "x" * 300 + "y", "../x", "<script>", ".."]
    names = trend_figure_names(units)
    assert len(set(names)) == len(names), names
    for name in names:
        assert "/" not in name and "\\" not in name and not name.startswith(".")
        assert name.startswith("trend-") and name.endswith(".png")
        assert len(name.encode()) <= len("trend-") + MAX_NAME + len("-NN_.png") + 3 < 255


# --- the Python entry ------------------------------------------------------------------------


def test_one_set_given_as_a_string_is_one_set_not_its_characters(tmp_path):
    # finding: phoid.identify_many("fleet/a") identified the sets "f", "l", "e", ... (a str
    # is iterable), and a Path was a TypeError
    s1 = _set(tmp_path / "s1")
    assert expand_sets(str(s1)) == [str(s1.resolve())]
    assert expand_sets(s1) == [str(s1.resolve())]


@pytest.mark.parametrize("options", [{"delay": "abc"}, {"delay": math.nan}, {"mass": True},
                                     {"friction": "yes"}, {"estimator": 3}])
def test_identify_options_of_the_wrong_type_are_refused_before_any_set(tmp_path, options):
    # finding: identify_many(..., delay="abc") ran every set to the same error row
    import phoid

    s1 = _set(tmp_path / "s1")
    name = next(iter(options))
    with pytest.raises(ValueError, match=f"identify option {name!r} must be"):
        phoid.identify_many([s1], workers=0, out=tmp_path / "r.parquet", **options)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1"]


def test_a_data_file_linked_inside_the_set_is_read_as_phoid_identify_reads_it(tmp_path):
    # finding: the checksum opened data files with O_NOFOLLOW, so a set whose run file is a
    # link to a file inside its own folder (which `phoid identify` reads) was an error row
    import hashlib
    import json
    import shutil
    import tomllib

    sample = Path(__file__).resolve().parents[1] / "examples" / "paper-sample"
    linked = tmp_path / "linked"
    shutil.copytree(sample, linked)
    (linked / "data").mkdir()
    (linked / "run01.csv.gz").rename(linked / "data" / "run01.csv.gz")
    (linked / "run01.csv.gz").symlink_to("data/run01.csv.gz")
    ident = runner.invoke(app, ["identify", str(linked), "--json"])
    assert ident.exit_code == 0, ident.output
    res = runner.invoke(app, ["batch", str(linked), "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0"])
    assert res.exit_code == 0, res.output
    row = pd.read_parquet(tmp_path / "r.parquet").iloc[0]
    assert row["status"] == "ok", row["error"]
    assert row["m"] == json.loads(ident.stdout)["m"]["value"]
    # SHA-256 of the manifest's bytes, then each run file's bytes in [[run]] order
    # (docs/format.md, "phoid batch output"), computed here from the original sample
    manifest = (sample / "experiment.toml").read_bytes()
    digest = hashlib.sha256(manifest)
    for run in tomllib.loads(manifest.decode())["run"]:
        digest.update((sample / run["file"]).read_bytes())
    assert row["checksum"] == digest.hexdigest()


def test_a_metadata_nan_or_inf_is_a_null_not_the_end_of_the_batch(tmp_path):
    # finding: `[metadata] gain = nan` (valid TOML) ended the batch with "Out of range float
    # values are not JSON compliant" (the journal's json.dumps), naming no file
    import shutil

    sample = Path(__file__).resolve().parents[1] / "examples" / "paper-sample"
    folder = tmp_path / "odd"
    shutil.copytree(sample, folder)
    with open(folder / "experiment.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[metadata]\naxis = "a"\ngain = nan\nbig = -inf\nturns = 3\n')
    res = runner.invoke(app, ["batch", str(folder), "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0"])
    assert res.exit_code == 0, res.output
    row = pd.read_parquet(tmp_path / "r.parquet").iloc[0]
    assert row["status"] == "ok" and row["axis"] == "a" and row["meta_turns"] == 3
    assert pd.isna(row["meta_gain"]) and pd.isna(row["meta_big"])


def test_a_glob_that_matches_the_output_does_not_make_it_a_set(tmp_path):
    # finding: `phoid batch 'fleet/*' --out fleet/results.parquet` run twice added error rows
    # for results.parquet and results.csv ("not a TOML manifest") to the table
    fleet = tmp_path / "fleet"
    _set(fleet / "a")
    out = fleet / "results.parquet"
    (fleet / "results.csv").write_text("not a batch output either\n")  # refused, see below
    res = runner.invoke(app, ["batch", str(fleet / "*"), "--out", str(out), "--workers", "0"])
    _one_line_error(res, "results.csv")
    (fleet / "results.csv").unlink()
    for _ in range(2):
        res = runner.invoke(app, ["batch", str(fleet / "*"), "--out", str(out), "--workers",
                                  "0", "--json"])
        assert res.exit_code == 0, res.output
    assert list(pd.read_parquet(out)["set"]) == [str((fleet / "a").resolve())]


def test_trend_on_a_folder_says_it_is_a_folder(tmp_path):
    # finding: `phoid trend DIR` said "DIR: no such file"
    res = runner.invoke(app, ["trend", str(tmp_path)])
    _one_line_error(res, "is a folder")


def test_an_unknown_estimator_is_refused_before_any_set(tmp_path):
    # finding: `phoid batch SETS --estimator bogus` made every set an error row, status 0
    s1 = _set(tmp_path / "s1")
    res = runner.invoke(app, ["batch", str(s1), "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0", "--estimator", "bogus"])
    _one_line_error(res, "'estimator'", "'bogus'")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1"]


def test_a_loop_of_links_is_a_row_with_its_error(tmp_path):
    # finding: a set path that is a link to itself ended the batch with "the Dask cluster
    # failed (RuntimeError: Symlink loop ...)", exit status 1, even with --workers 0
    s1 = _set(tmp_path / "s1")
    (tmp_path / "loop").symlink_to("loop")
    assert expand_sets([tmp_path / "loop", s1]) == [str(tmp_path / "loop"), str(s1.resolve())]
    res = runner.invoke(app, ["batch", str(tmp_path / "loop"), "--out",
                              str(tmp_path / "r.parquet"), "--workers", "0"])
    assert res.exit_code == 0, res.output
    row = pd.read_parquet(tmp_path / "r.parquet").iloc[0]
    assert row["status"] == "error" and "no experiment set here" in row["error"]
