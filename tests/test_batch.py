"""`phoid batch` and `phoid.identify_many`: many sets, one row each, resumable (issue 20).

The sets are simulated here by `phoid simulate` (pho, forced, free) and by
phoid.simulation.simulate_tracking (a tracking set), small and short so that each identifies in
a fraction of a second. Expected numbers come from `phoid identify SET --json` on the same set
with the same options (the batch must give the very same floats: the same code path), never
from the batch code itself.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import pytest
from tracking_sets import write_tracking_set
from typer.testing import CliRunner

import phoid.io
from phoid.cli import app

pd = pytest.importorskip("pandas", reason="the batch extra (pandas) is not installed")
pytest.importorskip("pyarrow", reason="the batch extra (pyarrow) is not installed")
pytest.importorskip("distributed", reason="the batch extra (dask.distributed) is not installed")

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "src" / "phoid" / "schema" / "batch.schema.json"  # `phoid batch --json`
runner = CliRunner()

# `phoid simulate` options of the base sets: a few runs, a few seconds, a low sample rate
SMALL = {
    "pho": ["--P", "1,3,6", "--D", "0.6,1,1.5", "--duration", "4", "--fs", "200",
            "--noise", "1e-5"],
    "forced": ["--method", "forced", "--omega", "3:9:4", "--duration", "5", "--fs", "100",
               "--noise", "1e-5"],
    "free": ["--method", "free", "--duration", "4", "--fs", "200", "--noise", "1e-5"],
}


def cli(*args, code=0):
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == code, r.output
    return r


def _add_metadata(folder: Path, lines: str) -> None:
    manifest = folder / "experiment.toml"
    manifest.write_text(manifest.read_text(encoding="utf-8") + "\n[metadata]\n" + lines,
                        encoding="utf-8")


@pytest.fixture(scope="module")
def base_sets(tmp_path_factory) -> dict[str, Path]:
    """One small set per method (three pho sets of different noise draws)."""
    root = tmp_path_factory.mktemp("base")
    sets = {}
    for name, method, seed in (("pho-a", "pho", 1), ("pho-b", "pho", 2), ("pho-c", "pho", 3),
                               ("forced", "forced", 4), ("free", "free", 5)):
        cli("simulate", root / name, *SMALL[method], "--seed", seed)
        sets[name] = root / name
    sets["tracking"] = write_tracking_set(root / "tracking", n=1500)
    return sets


def _expected(folder: Path, *options: str) -> dict:
    """`phoid identify FOLDER --json` with the options: the reference for the batch's row."""
    return json.loads(cli("identify", folder, "--json", *options).stdout)


def _same(cell, value) -> bool:
    """A table cell equals a JSON value: null for null, else the same float."""
    return bool(pd.isna(cell)) if value is None else cell == value


def _assert_row_is_identify_json(row, summary, folder) -> None:
    """Every estimate and standard error of the summary (a tracking set's in its `parameters`
    block), and its correlations, as floats equal bit for bit (the batch runs the same code on
    the same bytes); n_runs as the set has runs."""
    assert row["method"] == summary["method"]
    for name, entry in {**summary, **summary.get("parameters", {})}.items():
        if isinstance(entry, dict) and "value" in entry:
            assert _same(row[name], entry["value"]), name
            assert _same(row[f"{name}_stderr"], entry.get("stderr")), name
    corr = summary["correlation"]
    names = corr["params"]
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            assert _same(row[f"corr_{names[i]}_{names[j]}"], corr["matrix"][i][j])
    assert _same(row["chi2_dof"], summary["statistics"]["chi2_dof"])
    assert json.loads(row["warnings"]) == summary["warnings"]
    assert row["n_runs"] == len(phoid.io.read_experiment(folder).runs)


def test_error_rows_are_skipped_unless_retry_errors(base_sets, tmp_path):
    """An error row of a set with a checksum is kept on a re-run (the same bytes and options
    give the same error); --retry-errors identifies those sets again and only those."""
    names = [base_sets["pho-a"], base_sets["free"]]
    out = tmp_path / "rows.parquet"
    # --mass is a free-decay option: the pho set's identify refuses it (a per-set error)
    first = json.loads(cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1",
                           "--json").stdout)
    assert first["errors"] == 1 and first["computed"] == 2
    table = pd.read_parquet(out).set_index("set")
    pho, free = (str(f.resolve()) for f in names)
    assert table.loc[pho, "status"] == "error" and table.loc[free, "status"] == "ok"
    again = json.loads(cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1",
                           "--json").stdout)
    assert again["skipped"] == 2 and again["computed"] == 0
    retried = json.loads(cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1",
                             "--retry-errors", "--json").stdout)
    assert retried["skipped"] == 1 and retried["computed"] == 1
    after = pd.read_parquet(out).set_index("set")
    assert after.loc[pho, "finished"] > table.loc[pho, "finished"]  # identified again
    pd.testing.assert_series_equal(after.loc[free], table.loc[free])  # the ok row kept


def test_the_summary_counts_mean_what_their_words_say(base_sets, tmp_path):
    """"identified" is the sets this run identified, "with an error" those this run failed on,
    "already done" those it skipped (an earlier run's error row among them is not counted
    again as an error of this run); the three add up to the sets named."""
    names = [base_sets["pho-a"], base_sets["free"], tmp_path / "missing"]
    out = tmp_path / "rows.parquet"
    # the pho set refuses --mass (a free-decay option) and the missing folder is no set: two
    # errors; the free set identifies
    first = cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1").stdout
    assert "3 sets: 1 identified, 2 with an error, 0 already done;" in first, first
    # again: the pho set's error row (same bytes, same options) and the free row are skipped;
    # the missing folder (no checksum) is tried again and fails again
    again = cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1").stdout
    assert ("3 sets: 0 identified, 1 with an error, 2 already done (1 of them an error row, "
            "not retried: --retry-errors);") in again, again
    counts = json.loads(cli("batch", *names, "--out", out, "--workers", "0", "--mass", "1",
                            "--json").stdout)
    jsonschema.validate(counts, json.loads(SCHEMA.read_text(encoding="utf-8")))
    assert counts == {**counts, "sets": 3, "identified": 0, "computed_errors": 1,
                      "computed": 1, "skipped": 2, "skipped_errors": 1,
                      # `errors` keeps the meaning it had before the other counts were added
                      # (the contract: docs/format.md): every error row of the sets named
                      "errors": 2}
    assert (counts["identified"] + counts["computed_errors"] + counts["skipped"]
            == counts["sets"])


def test_rows_equal_identify_json_and_a_rerun_skips_them(base_sets, tmp_path):
    """Serial batch (--workers 0): one row per set, the numbers of `phoid identify --json`,
    [metadata] as columns, a missing folder as an error row; the same command again computes
    nothing and leaves every row as it was."""
    sets = dict(base_sets)
    meta = tmp_path / "with-meta"
    shutil.copytree(base_sets["pho-a"], meta)
    _add_metadata(meta, 'axis = "X2"\ntime = 2026-11-30T08:15:00Z\noperator = "ann"\n'
                        "temperature = 21.5\n")
    sets["with-meta"] = meta
    names = [*sets.values(), tmp_path / "missing"]
    out = tmp_path / "out" / "rows.parquet"
    r = cli("batch", *names, "--out", out, "--workers", "0", "--json")
    counts = json.loads(r.stdout)
    jsonschema.validate(counts, json.loads(SCHEMA.read_text(encoding="utf-8")))
    assert counts["sets"] == len(names) and counts["computed"] == len(names)
    assert counts["errors"] == 1  # the missing folder
    table = pd.read_parquet(out).set_index("set")
    assert len(table) == len(names)
    csv = pd.read_csv(out.with_suffix(".csv"))
    assert sorted(csv["set"]) == sorted(table.index)
    for name, folder in sets.items():
        row = table.loc[str(folder.resolve())]
        assert row["status"] == "ok", (name, row["error"])
        _assert_row_is_identify_json(row, _expected(folder), folder)
    missing = table.loc[str((tmp_path / "missing").resolve())]
    assert missing["status"] == "error" and "no experiment set here" in missing["error"]
    row = table.loc[str(meta.resolve())]
    assert row["axis"] == "X2" and row["meta_operator"] == "ann"
    assert row["meta_temperature"] == 21.5
    assert row["time"] == pd.Timestamp("2026-11-30T08:15:00Z")
    assert json.loads(row["options"]) == {"delay": None, "estimator": None, "friction": False,
                                          "mass": None, "no_compensation": False, "noise": None}
    assert not out.with_suffix(".journal.jsonl").exists()  # finished: all in the table

    again = json.loads(cli("batch", *names, "--out", out, "--workers", "0", "--json").stdout)
    # the missing folder has no checksum: tried again; every other set is skipped
    assert again["skipped"] == len(names) - 1 and again["computed"] == 1
    after = pd.read_parquet(out).set_index("set")
    done = [str(f.resolve()) for f in sets.values()]
    pd.testing.assert_frame_equal(after.loc[done], table.loc[done])


def test_options_reach_every_set_as_in_identify(base_sets, tmp_path):
    """--estimator ols on pho sets: the rows are `identify --estimator ols --json`'s; a free
    set with --estimator is an error row with identify's message."""
    out = tmp_path / "ols.parquet"
    cli("batch", base_sets["pho-a"], base_sets["free"], "--out", out, "--workers", "0",
        "--estimator", "ols")
    table = pd.read_parquet(out).set_index("set")
    _assert_row_is_identify_json(table.loc[str(base_sets["pho-a"].resolve())],
                                 _expected(base_sets["pho-a"], "--estimator", "ols"),
                                 base_sets["pho-a"])
    free = table.loc[str(base_sets["free"].resolve())]
    refused = cli("identify", base_sets["free"], "--estimator", "ols", code=2)
    assert free["status"] == "error" and free["error"] in refused.output
    assert json.loads(free["options"])["estimator"] == "ols"


def test_a_changed_set_is_identified_again(base_sets, tmp_path):
    """The checksum covers the data files: a set whose data changed is not skipped."""
    folder = tmp_path / "set"
    shutil.copytree(base_sets["pho-b"], folder)
    out = tmp_path / "rows.parquet"
    cli("batch", folder, "--out", out, "--workers", "0")
    first = pd.read_parquet(out).iloc[0]
    shutil.copy(base_sets["pho-c"] / "run02.csv.gz", folder / "run02.csv.gz")
    again = json.loads(cli("batch", folder, "--out", out, "--workers", "0", "--json").stdout)
    assert again["computed"] == 1 and again["skipped"] == 0
    second = pd.read_parquet(out)
    assert len(second) == 1 and second.iloc[0]["checksum"] != first["checksum"]


def test_the_journal_of_a_killed_batch_is_kept(base_sets, tmp_path):
    """A journal left by a killed batch (its last line cut off mid-write) is read: its rows
    are kept, not recomputed, and the cut line is dropped."""
    out = tmp_path / "rows.parquet"
    cli("batch", base_sets["pho-a"], base_sets["forced"], "--out", out, "--workers", "0")
    rows = pd.read_parquet(out)
    out.unlink()
    out.with_suffix(".csv").unlink()
    journal = out.with_suffix(".journal.jsonl")
    lines = []
    for row in rows.to_dict("records"):
        row = {k: (None if v is pd.NA or (isinstance(v, float) and v != v) else
                   v.isoformat() if hasattr(v, "isoformat") else v) for k, v in row.items()}
        lines.append(json.dumps(row))
    journal.write_text("\n".join(lines) + '\n{"set": "/cut/off', encoding="utf-8")
    again = json.loads(cli("batch", base_sets["pho-a"], base_sets["forced"], "--out", out,
                           "--workers", "0", "--json").stdout)
    assert again["skipped"] == 2 and again["computed"] == 0
    after = pd.read_parquet(out)
    assert list(after["finished"]) == list(rows["finished"])
    assert not journal.exists()


@pytest.mark.parametrize("content, why", [
    (b"set,value\n/a,1\n", "not a Parquet file"),
    (None, "no 'phoid' key"),
    ("other-schema", "'phoid-batch/0'"),
])
def test_an_output_of_another_kind_is_refused(base_sets, tmp_path, content, why):
    """A file at --out that is not a phoid batch output (or of another schema): one line
    naming the file and why, exit status 2, the file unchanged."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = tmp_path / "results.parquet"
    if content is None or content == "other-schema":
        table = pa.table({"set": ["/a"], "m": [1.0]})
        if content == "other-schema":
            table = table.replace_schema_metadata({b"phoid": b"phoid-batch/0"})
        pq.write_table(table, out)
    else:
        out.write_bytes(content)
    before = out.read_bytes()
    r = cli("batch", base_sets["free"], "--out", out, "--workers", "0", code=2)
    assert r.output.count("\n") == 1 and str(out) in r.output and why in r.output
    assert out.read_bytes() == before
    assert not out.with_suffix(".csv").exists()


def test_a_csv_of_another_kind_is_refused(base_sets, tmp_path):
    out = tmp_path / "results.parquet"
    out.with_suffix(".csv").write_text("a,b\n1,2\n", encoding="utf-8")
    r = cli("batch", base_sets["free"], "--out", out, "--workers", "0", code=2)
    assert "results.csv" in r.output and "not a phoid batch output" in r.output
    assert out.with_suffix(".csv").read_text(encoding="utf-8") == "a,b\n1,2\n"


def test_sets_by_glob_and_list_file(base_sets, tmp_path):
    """A glob pattern and a list file (relative lines from its folder, comments skipped) name
    the same sets; a pattern that matches nothing is one line, exit status 2."""
    from phoid.batch.sets import expand_sets

    root = base_sets["free"].parent
    listing = root / "sets.txt"
    listing.write_text("# the two pho sets\npho-a\n\npho-b\n", encoding="utf-8")
    assert expand_sets([str(root / "pho-[ab]")]) == expand_sets([listing])
    assert expand_sets([listing]) == [str((root / n).resolve()) for n in ("pho-a", "pho-b")]
    r = cli("batch", str(tmp_path / "nothing-*"), "--out", tmp_path / "r.parquet",
            "--workers", "0", code=2)
    assert r.output.count("\n") == 1 and "matches no set" in r.output


def test_without_the_extra_one_line_says_what_to_install(base_sets, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed: ImportError
    r = cli("batch", base_sets["free"], "--out", tmp_path / "r.parquet", code=2)
    assert r.output == ("phoid: error: phoid batch needs the batch extra: "
                        "pip install 'phoid[batch]'\n")
    assert not (tmp_path / "r.parquet").exists()


def test_a_scheduler_that_does_not_answer(base_sets, tmp_path):
    """A closed local port: one line naming the address, exit 2, within the timeout (2 s)
    plus the time to give up; nothing written."""
    with socket.socket() as s:  # a port just freed: nothing listens on it
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    r = cli("batch", base_sets["free"], "--out", tmp_path / "r.parquet", "--scheduler",
            address, "--timeout", "2", code=2)
    assert r.output.count("\n") == 1 and address in r.output and "does not answer" in r.output


def test_identify_many_from_python(base_sets, tmp_path):
    """phoid.identify_many in this process (workers=0): a DataFrame, one row per set named,
    in order; an unknown option refused before any work."""
    import phoid

    table = phoid.identify_many([base_sets["free"], base_sets["pho-a"]], workers=0)
    assert list(table["set"]) == [str(base_sets["free"].resolve()),
                                  str(base_sets["pho-a"].resolve())]
    assert list(table["status"]) == ["ok", "ok"]
    with pytest.raises(ValueError, match="unknown identify option 'estimatr'"):
        phoid.identify_many([base_sets["free"]], workers=0, estimatr="ols")


def test_map_unordered_returns_exceptions_as_results():
    """On a real local cluster of 2 processes: every item comes back once, a failing one as
    its exception (not raised)."""
    from phoid.batch.cluster import cluster_client, map_unordered

    with cluster_client(workers=2) as client:
        got = dict(map_unordered(client, _reciprocal, [1.0, 0.0, 4.0], description="test"))
    assert got[0] == 1.0 and got[2] == 0.25
    assert isinstance(got[1], ZeroDivisionError)


def _reciprocal(x: float) -> float:
    return 1.0 / x


# ------------------------------------------------------------------------------------------
# the acceptance test: 50 + 2 sets on a local cluster of 2 worker processes, killed, resumed
def _fleet(base_sets: dict[str, Path], root: Path) -> list[Path]:
    """52 sets: copies of the base sets (every method), each with its own [metadata] (so its
    own checksum), and two broken ones (a data file missing, a manifest that is not TOML)."""
    names = ["pho-a", "pho-b", "forced", "free", "pho-c", "forced", "free", "pho-a", "free",
             "tracking"]  # a tracking set takes ~2 s, the others ~0.1-0.5 s: one in ten
    sets = []
    for i in range(50):
        folder = root / f"set{i:02d}"
        shutil.copytree(base_sets[names[i % len(names)]], folder)
        _add_metadata(folder, f'axis = "A{i % 4}"\ntime = "2026-11-{1 + i % 28:02d}T10:00:00Z"\n')
        sets.append(folder)
    cut = root / "broken-data"
    shutil.copytree(base_sets["pho-a"], cut)
    (cut / "run02.csv.gz").unlink()
    bad = root / "broken-manifest"
    bad.mkdir()
    (bad / "experiment.toml").write_text("format = 'phoid/1\n", encoding="utf-8")
    return [*sets, cut, bad]


@pytest.mark.slow
def test_a_batch_killed_halfway_finishes_without_recomputing(base_sets, tmp_path):
    """`phoid batch` as a subprocess on a local cluster of 2 worker processes, interrupted
    (SIGINT, as Ctrl-C) once a dozen rows are in its journal, then run again: one row per set,
    the broken ones with their error, the rows finished before the interruption unchanged (same
    `finished` and `worker`), and the numbers of `phoid identify --json`."""
    sets = _fleet(base_sets, tmp_path / "fleet")
    listing = tmp_path / "sets.txt"
    listing.write_text("\n".join(str(s) for s in sets) + "\n", encoding="utf-8")
    out = tmp_path / "out" / "results.parquet"
    journal = out.with_suffix(".journal.jsonl")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT / "src"), *filter(None, [os.environ.get("PYTHONPATH")])])}
    command = [sys.executable, "-c", "from phoid.cli import main; main()", "batch",
               str(listing), "--out", str(out), "--workers", "2"]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if journal.exists() and journal.read_bytes().count(b"\n") >= 12:
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.05)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err.decode()
    assert b"interrupted" in err
    first = pd.read_parquet(out).set_index("set")
    assert 12 <= len(first) < len(sets)
    # the broken sets have no checksum (a file missing, a manifest that does not parse): their
    # rows are made before any task and made again by every run; every other row is kept
    first = first[first["checksum"].notna()]
    assert len(first) >= 10

    done = subprocess.run([*command, "--json"], env=env, capture_output=True, timeout=180)
    assert done.returncode == 0, done.stderr.decode()
    counts = json.loads(done.stdout)
    assert counts["sets"] == len(sets) and counts["skipped"] == len(first)
    assert counts["computed"] == len(sets) - len(first) and counts["errors"] == 2
    assert "broken" not in " ".join(first.index)
    table = pd.read_parquet(out).set_index("set")
    assert sorted(table.index) == sorted(str(s.resolve()) for s in sets)
    for column in ("finished", "worker", "seconds", "checksum"):
        pd.testing.assert_series_equal(table.loc[first.index, column], first[column])
    assert table.loc[table["checksum"].notna(), "worker"].str.startswith("tcp://").all()
    broken = table.loc[[str(sets[-2].resolve()), str(sets[-1].resolve())]]
    assert (broken["status"] == "error").all()
    assert "run02.csv.gz" in broken["error"].iloc[0]
    assert "experiment.toml" in broken["error"].iloc[1]
    ok = table[table["status"] == "ok"]
    assert len(ok) == 50 and set(ok["method"]) == {"pho", "forced", "free", "tracking"}
    for folder in sets[:10]:  # each base set: the numbers of `phoid identify --json`
        _assert_row_is_identify_json(table.loc[str(folder.resolve())], _expected(folder),
                                     folder)
