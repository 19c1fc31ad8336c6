"""phoid.io: the phoid/1 experiment-set format (docs/format.md).

Expected values come from the files themselves: the sample set's manifest is parsed here with
tomllib independently of phoid, and its sampling (1 ms, 15 200 rows from t = 0) is what
examples/paper-sample (examples/make_paper_sample.py) and, as a cross-check where present,
../shared/data/paper-sample were written with. Round trips are compared bit for bit (int64 views),
since the writer promises the shortest repr that reads back to the same double. Error tests
check that the one-line message names the manifest, the run and the key/column/line at fault.
Every fixture lives in pytest's tmp_path.
"""

from __future__ import annotations

import gzip
import math
import os
import pickle
import tomllib
from pathlib import Path

import numpy as np
import pytest

from phoid.errors import ExperimentError
from phoid.io import (
    ExperimentSet,
    Run,
    read_experiment,
    run_from_arrays,
    write_experiment,
)

# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
MANIFEST = """\
title = "tiny"
format = "phoid/1"
method = "pho"

[loop]
delay = 0.1

[[run]]
file = "run01.csv.gz"
P = 1.0
D = 0.5

[[run]]
file = "run02.csv.gz"
P = 2.0
D = 0.75

[[run]]
file = "run03.csv.gz"
P = 3.0
D = 1.0
"""

N_ROWS = 100  # data rows per generated file: lines 2..101


def rows(n: int = N_ROWS, dt: float = 1e-3, amplitude: float = 0.01) -> list[list[str]]:
    """Rows of t,x,u as text (repr: exact)."""
    t = np.arange(n) * dt
    x = amplitude * np.exp(-2 * t) * np.cos(30 * t)
    u = -0.5 * x
    return [[repr(float(a)), repr(float(b)), repr(float(c))] for a, b, c in zip(t, x, u,
                                                                              strict=True)]


def csv_text(header: str = "t,x,u", body: list[list[str]] | None = None) -> str:
    body = rows() if body is None else body
    return header + "\n" + "".join(",".join(r) + "\n" for r in body)


def put(path: Path, content: str | bytes) -> None:
    """Write content; gzip it when the name ends in .gz and content is text."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, str):
        data = content.encode()
        if path.name.endswith(".gz"):
            data = gzip.compress(data, mtime=0)
    else:
        data = content
    path.write_bytes(data)


def make_set(tmp_path: Path, manifest: str = MANIFEST, **files: str | bytes | None) -> Path:
    """A set folder with the given manifest; run01..03.csv.gz default to good data.

    Keyword names are file names with '.' written as '_' (run03_csv_gz=...); None: no file.
    The default runs differ (release amplitude i cm for run i): the reader refuses two runs
    with byte-identical data.
    """
    folder = tmp_path / "tiny"
    folder.mkdir(exist_ok=True)
    put(folder / "experiment.toml", manifest)
    contents: dict[str, str | bytes | None] = {
        f"run0{i}.csv.gz": csv_text(body=rows(amplitude=0.01 * i)) for i in (1, 2, 3)}
    for key, value in files.items():
        contents[key.replace("_csv", ".csv").replace("_gz", ".gz")] = value
    for name, content in contents.items():
        if content is not None:
            put(folder / name, content)
    return folder


def error_of(path: Path | str) -> str:
    with pytest.raises(ExperimentError) as info:
        read_experiment(path)
    msg = str(info.value)
    assert "\n" not in msg, "messages are one line"
    assert isinstance(info.value, ValueError)
    return msg


def expect(msg: str, *parts: str) -> None:
    for part in parts:
        assert part in msg, f"{part!r} not in {msg!r}"


def with_row(i: int, row: list[str]) -> list[list[str]]:
    body = rows()
    body[i] = row
    return body


RUN3 = "run 3 (run03.csv.gz)"


# --------------------------------------------------------------------------------------------
# the independent sample sets: examples/paper-sample, and ../shared/data/paper-sample (written by
# another program, with other digits) as a cross-check, skipped where absent (conftest.py)
# --------------------------------------------------------------------------------------------
def test_sample_set(paper_sample) -> None:
    sample_set_path = paper_sample.path
    exp = read_experiment(sample_set_path)
    doc = tomllib.loads((sample_set_path / "experiment.toml").read_text())
    assert isinstance(exp, ExperimentSet)
    assert exp.path == sample_set_path / "experiment.toml"
    assert exp.folder == sample_set_path
    assert exp.method == "pho"
    assert exp.delay == doc["loop"]["delay"] == 0.1
    assert exp.title == doc["title"]
    assert exp.mass is None
    assert dict(exp.loop) == {"delay": 0.1}
    assert dict(exp.extra) == {}
    assert len(exp.runs) == len(exp) == 19
    for i, (run, table) in enumerate(zip(exp.runs, doc["run"], strict=True), start=1):
        assert run.index == i
        assert run.file == table["file"] == f"run{i:02d}.csv.gz"
        assert run.name == f"run {i} (run{i:02d}.csv.gz)"
        assert run.P == table["P"] and run.D == table["D"]  # exactly the manifest's doubles
        assert run.B is None and run.omega is None and run.added_mass == 0.0
        assert run.F is None
        assert run.u is not None
        assert run.n == run.t.size == run.x.size == run.u.size == 15200
        assert run.t[0] == 0.0
        # written with 6 (shared) or 3 (examples) decimals at 1 kHz: steps are 1 ms to the
        # parse's rounding (≤ 1e-16 · 15 s)
        np.testing.assert_allclose(np.diff(run.t), 1e-3, rtol=0, atol=1e-9)
        for a in (run.t, run.x, run.u):
            assert a.dtype == np.float64 and a.ndim == 1 and not a.flags.writeable
            assert np.isfinite(a).all()


def test_sample_set_by_manifest_path(sample_set_path: Path) -> None:
    by_folder = read_experiment(sample_set_path)
    by_file = read_experiment(str(sample_set_path / "experiment.toml"))
    assert by_file.path == by_folder.path
    for a, b in zip(by_folder.runs, by_file.runs, strict=True):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.t, b.t)


def test_sample_values_match_the_text(paper_sample) -> None:
    """The parsed numbers are the correctly rounded values of the text (float() reference)."""
    sample_set_path = paper_sample.path
    run = read_experiment(sample_set_path).runs[0]
    lines = gzip.decompress((sample_set_path / run.file).read_bytes()).decode().splitlines()
    assert lines[0] == "t,x,u"
    for k in (0, 1, 57, 7600, 15199):
        t, x, u = (float(c) for c in lines[k + 1].split(","))
        assert (run.t[k], run.x[k], run.u[k]) == (t, x, u)


# --------------------------------------------------------------------------------------------
# reading: accepted variations
# --------------------------------------------------------------------------------------------
def test_minimal_manifest_and_defaults(tmp_path: Path) -> None:
    folder = make_set(tmp_path, '[[run]]\nfile = "run01.csv.gz"\nP = 1\nD = 0\n')
    exp = read_experiment(folder)
    assert exp.method == "pho" and exp.delay is None and exp.title is None
    assert exp.runs[0].P == 1.0 and isinstance(exp.runs[0].P, float)
    assert exp.runs[0].D == 0.0


def test_csv_variants(tmp_path: Path) -> None:
    """Plain .csv, columns in any order, extra (even text) columns, spaces, CRLF, BOM, quotes,
    blank lines, a missing final newline, gzip content under a .csv name."""
    body = rows()
    t, x, u = (np.array([float(r[j]) for r in body]) for j in range(3))
    reordered = "note,x,\"u\" ,  t\n" + "".join(
        f"hello {i}, {r[1]} ,{r[2]},{r[0]}\n" for i, r in enumerate(body))
    crlf = ("\ufeff" + csv_text()).replace("\n", "\r\n")
    blanks = csv_text().replace("\n", "\n\n", 3) + "\n  \n"
    no_eol = csv_text().rstrip("\n")
    manifest = "method = 'free'\n" + "".join(
        f"[[run]]\nfile = '{f}'\n" for f in ("a.csv", "b.csv", "c.csv", "d.csv", "e.csv"))
    folder = make_set(tmp_path, manifest, a_csv=reordered, b_csv=crlf, c_csv=blanks,
                      d_csv=no_eol, e_csv=gzip.compress(csv_text().encode()))
    exp = read_experiment(folder)
    assert exp.method == "free"
    for run in exp.runs:
        assert np.array_equal(run.t, t), run.name
        assert np.array_equal(run.x, x), run.name
        assert np.array_equal(run.u, u), run.name
        assert run.F is None


def test_subfolder_and_symlink_inside(tmp_path: Path) -> None:
    manifest = ("method = 'free'\n[[run]]\nfile = 'data/r1.csv'\n"
                "[[run]]\nfile = 'link.csv'\n")
    folder = make_set(tmp_path, manifest, data_r1_csv=None)
    put(folder / "data" / "r1.csv", csv_text())
    put(folder / "data" / "r2.csv", csv_text(body=rows(50)))
    (folder / "link.csv").symlink_to(folder / "data" / "r2.csv")
    exp = read_experiment(folder)
    assert exp.runs[0].file == "data/r1.csv" and exp.runs[0].n == N_ROWS
    assert exp.runs[1].n == 50


def test_extensions_and_unknown_keys_kept(tmp_path: Path) -> None:
    manifest = """\
format = "phoid/1"
method = "free"
mass = 2.5
operator = "A. N. Other"
future_table = { k = 1 }

[loop]
delay = 0.0
sample_time = 0.001
velocity = "filtered"
delay_samples = 3

[[run]]
file = "run01.csv.gz"
added_mass = 0.5
sensor = "encoder"
calibration = [1.0, 2.0]
"""
    exp = read_experiment(make_set(tmp_path, manifest))
    assert exp.mass == 2.5 and exp.delay == 0.0
    assert dict(exp.loop) == {"delay": 0.0, "sample_time": 0.001, "velocity": "filtered",
                              "delay_samples": 3}
    assert exp.extra["operator"] == "A. N. Other"
    assert dict(exp.extra["future_table"]) == {"k": 1}
    run = exp.runs[0]
    assert run.added_mass == 0.5 and run.P is None and run.D is None
    assert dict(run.extra) == {"sensor": "encoder", "calibration": (1.0, 2.0)}
    with pytest.raises(TypeError):
        run.extra["sensor"] = "x"  # type: ignore[index]
    with pytest.raises(AttributeError):
        run.P = 1.0  # type: ignore[misc]


def test_forced_set(tmp_path: Path) -> None:
    body = [[*r, repr(0.1 * i)] for i, r in enumerate(rows())]
    manifest = ("method = 'forced'\n[[run]]\nfile = 'f.csv'\nB = 1.0\nomega = 5.0\n"
                "[[run]]\nfile = 'g.csv'\n")
    folder = make_set(tmp_path, manifest, f_csv=csv_text("t,x,u,F", body),
                      g_csv=csv_text("F,t,x,u", [[r[3], *r[:3]] for r in body]))
    exp = read_experiment(folder)
    a, b = exp.runs
    assert a.B == 1.0 and a.omega == 5.0 and b.B is None
    assert np.array_equal(a.F, b.F) and a.F[3] == 0.1 * 3


def test_pickle_roundtrip(tmp_path: Path) -> None:
    exp = read_experiment(make_set(tmp_path))
    again = pickle.loads(pickle.dumps(exp))
    assert again.delay == exp.delay and dict(again.loop) == dict(exp.loop)
    assert np.array_equal(again.runs[1].x, exp.runs[1].x)
    assert "run 3 (run03.csv.gz)" in repr(exp.runs[2]) and "3 runs" in repr(exp)


# --------------------------------------------------------------------------------------------
# reading: manifest errors
# --------------------------------------------------------------------------------------------
def test_missing_manifest(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    expect(error_of(tmp_path / "empty"), "empty/experiment.toml", "manifest not found")
    expect(error_of(tmp_path / "nowhere"), "nowhere", "no such file")
    expect(error_of(tmp_path / "nowhere" / "experiment.toml"), "nowhere/experiment.toml")


def test_unreadable_manifest(tmp_path: Path) -> None:
    folder = make_set(tmp_path)
    (folder / "experiment.toml").write_bytes(b'title = "caf\xe9"\n')
    expect(error_of(folder), "experiment.toml", "not UTF-8", "line 1")


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root reads files whatever their permissions")
def test_manifest_without_permission(tmp_path: Path) -> None:  # pragma: no cover - not as root
    folder = make_set(tmp_path)
    (folder / "experiment.toml").chmod(0)
    try:
        expect(error_of(folder), "experiment.toml", "cannot read the manifest")
    finally:
        (folder / "experiment.toml").chmod(0o644)


def test_toml_syntax_error_names_the_line(tmp_path: Path) -> None:
    folder = make_set(tmp_path, MANIFEST.replace("P = 2.0", "P = 2.0.0"))
    line = MANIFEST.splitlines().index("P = 2.0") + 1
    expect(error_of(folder), "tiny/experiment.toml", "TOML syntax error", f"line {line}")


@pytest.mark.parametrize("value", ['"phoid/2"', '"PHOID/1"', "1"])
def test_unknown_format(tmp_path: Path, value: str) -> None:
    folder = make_set(tmp_path, MANIFEST.replace('format = "phoid/1"', f"format = {value}"))
    expect(error_of(folder), "experiment.toml", "'format'", "phoid/1")


@pytest.mark.parametrize("value", ['"step"', '"PHO"', "3"])
def test_unknown_method(tmp_path: Path, value: str) -> None:
    folder = make_set(tmp_path, MANIFEST.replace('method = "pho"', f"method = {value}"))
    expect(error_of(folder), "experiment.toml", "'method'", "'pho', 'forced', 'free'")


def test_no_runs(tmp_path: Path) -> None:
    head = MANIFEST.split("[[run]]")[0]
    expect(error_of(make_set(tmp_path, head)), "experiment.toml", "no runs", "[[run]]")
    expect(error_of(make_set(tmp_path, "run = []\n" + head)), "experiment.toml", "no runs")
    # a plural (unknown) key is named in the hint
    msg = error_of(make_set(tmp_path, head + "[[runs]]\nfile = 'run01.csv.gz'\nP = 1\nD = 1\n"))
    expect(msg, "no runs", "'runs'")


@pytest.mark.parametrize("text", ["run = 3\n", "[run]\nfile = 'run01.csv.gz'\n",
                                  "run = [1, 2]\n"])
def test_run_not_an_array_of_tables(tmp_path: Path, text: str) -> None:
    expect(error_of(make_set(tmp_path, text)), "experiment.toml", "'run'", "[[run]]")


def test_run_without_file(tmp_path: Path) -> None:
    folder = make_set(tmp_path, MANIFEST.replace('file = "run03.csv.gz"\n', 'fiel = "x"\n'))
    expect(error_of(folder), "experiment.toml: run 3:", "missing key 'file'", "'fiel'")


@pytest.mark.parametrize("text", ["file = 3", 'file = ""', "file = ['a.csv']"])
def test_file_not_a_name(tmp_path: Path, text: str) -> None:
    folder = make_set(tmp_path, MANIFEST.replace('file = "run03.csv.gz"', text))
    expect(error_of(folder), "experiment.toml: run 3", "'file'")


@pytest.mark.parametrize("key", ["P", "D"])
def test_pho_run_without_gain(tmp_path: Path, key: str) -> None:
    value = {"P": "P = 3.0\n", "D": "D = 1.0\n"}[key]
    folder = make_set(tmp_path, MANIFEST.replace(value, ""))
    expect(error_of(folder), f"experiment.toml: {RUN3}: missing key '{key}'", "pho")


def test_free_and_forced_runs_need_no_gains(tmp_path: Path) -> None:
    manifest = MANIFEST.replace('method = "pho"', 'method = "free"').replace("P = 3.0\n", "")
    assert read_experiment(make_set(tmp_path, manifest)).runs[2].P is None


@pytest.mark.parametrize(("key", "text", "words"), [
    ("P", 'P = "3.0"', ("must be a number", "'3.0'", "a string")),
    ("P", "P = nan", ("must be finite", "nan")),
    ("D", "D = inf", ("must be finite", "inf")),
    ("D", "D = -inf", ("must be finite",)),
    ("P", "P = true", ("must be a number", "true", "a boolean")),
    ("omega", "omega = 0.0", ("must be >",)),
    ("B", "B = nan", ("must be finite",)),
    ("added_mass", "added_mass = -0.1", ("must be ≥ 0 kg",)),
])
def test_bad_run_numbers(tmp_path: Path, key: str, text: str, words: tuple[str, ...]) -> None:
    folder = make_set(tmp_path, MANIFEST.replace("D = 1.0\n", f"D = 1.0\n{text}\n")
                      if key not in ("P", "D") else
                      MANIFEST.replace(f"{key} = {'3.0' if key == 'P' else '1.0'}", text))
    expect(error_of(folder), f"experiment.toml: {RUN3}: key '{key}'", *words)


@pytest.mark.parametrize(("text", "words"), [
    ("delay = nan", ("must be finite", "nan")),
    ("delay = inf", ("must be finite",)),
    ("delay = '0.1'", ("must be a number", "a string")),
    ("delay = -0.1", ("must be ≥ 0 s", "-0.1")),
])
def test_bad_delay(tmp_path: Path, text: str, words: tuple[str, ...]) -> None:
    folder = make_set(tmp_path, MANIFEST.replace("delay = 0.1", text))
    expect(error_of(folder), "experiment.toml: [loop]: key 'delay'", *words)


def test_bad_top_level_values(tmp_path: Path) -> None:
    expect(error_of(make_set(tmp_path, "mass = 0\n" + MANIFEST)), "key 'mass'", "> 0 kg")
    expect(error_of(make_set(tmp_path, MANIFEST.replace('title = "tiny"', "title = 1"))),
           "key 'title'", "string")
    expect(error_of(make_set(tmp_path, "loop = 0.1\n" + MANIFEST.replace("[loop]\ndelay = 0.1",
                                                                          ""))),
           "'loop' must be a table")


@pytest.mark.parametrize(("old", "new", "words"), [
    ("P = 3.0", "p = 3.0", ("run 3 (run03.csv.gz)", "'p'", "did you mean 'P'")),
    ('file = "run03.csv.gz"', 'File = "run03.csv.gz"', ("run 3", "'File'", "'file'")),
    ('method = "pho"', 'Method = "pho"', ("'Method'", "'method'")),
    ("delay = 0.1", "Delay = 0.1", ("[loop]", "'Delay'", "'delay'")),
])
def test_keys_differing_only_by_case(tmp_path: Path, old: str, new: str,
                                     words: tuple[str, ...]) -> None:
    msg = error_of(make_set(tmp_path, MANIFEST.replace(old, new)))
    expect(msg, "experiment.toml", "case-sensitive", *words)


# --------------------------------------------------------------------------------------------
# reading: data-file paths
# --------------------------------------------------------------------------------------------
def test_missing_data_file(tmp_path: Path) -> None:
    msg = error_of(make_set(tmp_path, run03_csv_gz=None))
    expect(msg, f"experiment.toml: {RUN3}: data file not found", "run03.csv.gz")


@pytest.mark.parametrize(("name", "words"), [
    ("/etc/passwd.csv", ("absolute path",)),
    ("../outside.csv", ("escapes the set's folder", "'..'")),
    ("sub/../../outside.csv", ("escapes the set's folder",)),
    ("sub\\\\run.csv", ("'/' as the path separator",)),
    ("C:/data/run.csv", ("absolute path",)),
    ("run03.txt", ("must end in .csv or .csv.gz",)),
])
def test_file_paths_that_escape_or_are_odd(tmp_path: Path, name: str,
                                           words: tuple[str, ...]) -> None:
    put(tmp_path / "outside.csv", csv_text())
    folder = make_set(tmp_path, MANIFEST.replace('"run03.csv.gz"', f'"{name}"'))
    expect(error_of(folder), "experiment.toml: run 3 (", "file", *words)


def test_symlink_pointing_outside(tmp_path: Path) -> None:
    put(tmp_path / "secret.csv.gz", csv_text())
    folder = make_set(tmp_path, run03_csv_gz=None)
    (folder / "run03.csv.gz").symlink_to(tmp_path / "secret.csv.gz")
    expect(error_of(folder), f"experiment.toml: {RUN3}: file 'run03.csv.gz' escapes",
           "secret.csv.gz")


def test_data_path_is_a_folder(tmp_path: Path) -> None:
    folder = make_set(tmp_path, run03_csv_gz=None)
    (folder / "run03.csv.gz").mkdir()
    expect(error_of(folder), RUN3, "not a regular file")


def test_same_file_twice(tmp_path: Path) -> None:
    folder = make_set(tmp_path, MANIFEST.replace('"run03.csv.gz"', '"./run01.csv.gz"'))
    expect(error_of(folder), "run 3 (./run01.csv.gz)", "already used by run 1")


# --------------------------------------------------------------------------------------------
# reading: data-file contents
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("header", "column"), [("x,u", "t"), ("t,u", "x"), ("t,X,u", "x")])
def test_missing_column(tmp_path: Path, header: str, column: str) -> None:
    body = [r[: len(header.split(","))] for r in rows()]
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(header, body)))
    expect(msg, f"experiment.toml: {RUN3}: missing column '{column}'", "the header names")
    if "X" in header:
        expect(msg, "case-sensitive")


def test_forced_run_without_F(tmp_path: Path) -> None:
    folder = make_set(tmp_path, "method = 'forced'\n[[run]]\nfile = 'run01.csv.gz'\n")
    expect(error_of(folder), "run 1 (run01.csv.gz): missing column 'F'", "forced")


def test_semicolon_separated(tmp_path: Path) -> None:
    text = csv_text().replace(",", ";")
    expect(error_of(make_set(tmp_path, run03_csv_gz=text)), RUN3, "missing column 't'",
           "separated by commas")


@pytest.mark.parametrize(("content", "words"), [
    ("", ("the data file is empty",)),
    (b"", ("the data file is empty",)),
    ("\n \n", ("the data file is empty",)),
    ("t,x,u\n", ("header but no data rows",)),
    ("t,x,u\n\n\n", ("header but no data rows",)),
    ("\nt,x,u\n0,1,2\n", ("line 1 is blank",)),
    ("0,1,2\n1,2,3\n", ("line 1 looks like data",)),
    ("t,x,u\n0,1,2\n", ("only 1 data row",)),
])
def test_empty_or_header_only(tmp_path: Path, content: str | bytes,
                              words: tuple[str, ...]) -> None:
    expect(error_of(make_set(tmp_path, run03_csv_gz=content)), f"experiment.toml: {RUN3}: ",
           *words)


@pytest.mark.parametrize(("row", "fields"), [(["0.055", "0.1"], 2),
                                             (["0.055", "0.1", "0.2", "9"], 4)])
def test_ragged_rows(tmp_path: Path, row: list[str], fields: int) -> None:
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=with_row(55, row))))
    expect(msg, f"experiment.toml: {RUN3}: line 57 has {fields} fields",
           "header names 3 columns")


def test_non_numeric_cell(tmp_path: Path) -> None:
    body = with_row(55, [rows()[55][0], "abc", "0"])
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=body)))
    assert msg.endswith(f"tiny/experiment.toml: {RUN3}: column 'x' has a non-numeric cell "
                        "at line 57: 'abc'")


@pytest.mark.parametrize("cell", ['"0.5"', "1_000", "0x10", "1,5", "1.2.3", "- 1"])
def test_other_non_numeric_cells(tmp_path: Path, cell: str) -> None:
    body = rows()
    body[10] = [body[10][0], body[10][1], cell]
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=body)))
    expect(msg, RUN3, "line 12")
    if "," not in cell:
        expect(msg, "column 'u' has a non-numeric cell at line 12")


def test_empty_cell(tmp_path: Path) -> None:
    body = with_row(55, ["", rows()[55][1], "0"])
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=body)))
    expect(msg, f"{RUN3}: column 't' has an empty cell at line 57")


def test_text_in_an_extra_column_is_fine_but_not_in_a_known_one(tmp_path: Path) -> None:
    body = [[*r, "ok" if i % 2 else ""] for i, r in enumerate(rows())]
    folder = make_set(tmp_path, run03_csv_gz=csv_text("t,x,u,note", body))
    assert read_experiment(folder).runs[2].n == N_ROWS


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-Infinity", "1e400"])
def test_non_finite_cell(tmp_path: Path, cell: str) -> None:
    body = with_row(55, [rows()[55][0], cell, "0"])
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=body)))
    expect(msg, f"{RUN3}: column 'x' has a non-finite value at line 57: '{cell}'")


@pytest.mark.parametrize("t_cell", ["0.054", "0.0539", "-1"])
def test_time_not_increasing(tmp_path: Path, t_cell: str) -> None:
    """Row 55 (line 57) repeats or goes back before row 54's t = 0.054 s."""
    body = with_row(55, [t_cell, "0.0", "0.0"])
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text(body=body)))
    expect(msg, f"{RUN3}: column 't' is not strictly increasing at line 57", "(line 56)")


def test_line_numbers_count_blank_lines(tmp_path: Path) -> None:
    body = rows()
    body[55] = [body[55][0], "abc", "0"]
    text = csv_text(body=body).replace("\n", "\n\n", 2)  # two blank lines after lines 1, 2
    msg = error_of(make_set(tmp_path, run03_csv_gz=text))
    expect(msg, "column 'x' has a non-numeric cell at line 59: 'abc'")
    body = with_row(55, ["-1", "0", "0"])
    text = csv_text(body=body).replace("\n", "\n  \n", 1)
    msg = error_of(make_set(tmp_path, run03_csv_gz=text))
    expect(msg, "not strictly increasing at line 58", "(line 57)")


def test_duplicate_column_names(tmp_path: Path) -> None:
    body = [[*r, "1"] for r in rows()]
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text("t,x,u,x", body)))
    expect(msg, f"{RUN3}: the header names column 'x' twice (columns 2 and 4)")


def test_corrupt_gzip(tmp_path: Path) -> None:
    good = gzip.compress(csv_text().encode(), mtime=0)
    truncated = good[: len(good) // 2]
    bad_crc = good[:-8] + bytes([good[-8] ^ 0xFF]) + good[-7:]
    garbage = good[:10] + b"\x00garbage" * 20
    for content in (truncated, bad_crc, garbage):
        msg = error_of(make_set(tmp_path, run03_csv_gz=content))
        expect(msg, f"experiment.toml: {RUN3}: the data file is not a valid gzip file")
    msg = error_of(make_set(tmp_path, run03_csv_gz=csv_text().encode()))
    expect(msg, RUN3, "not a gzip file")


def test_first_bad_run_is_reported(tmp_path: Path) -> None:
    bad = csv_text(body=with_row(3, ["x", "0", "0"]))
    msg = error_of(make_set(tmp_path, run02_csv_gz=bad, run03_csv_gz=bad))
    expect(msg, "run 2 (run02.csv.gz)", "line 5")


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def hard_floats(rng: np.random.Generator, n: int) -> np.ndarray:
    """Doubles whose shortest repr needs 17 digits, extremes, subnormals, -0."""
    a = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
    a[:8] = [0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, 1 / 3,
             0.1, -123456789.12345679]
    return a


def test_round_trip_is_bitwise(tmp_path: Path) -> None:
    rng = np.random.default_rng(20261122)
    n = 2000
    t = np.cumsum(rng.uniform(1e-4, 2e-3, n))
    t[0] = 0.0
    runs = [
        run_from_arrays(t, hard_floats(rng, n), u=hard_floats(rng, n), P=1 / 3, D=0.1 + 0.2,
                        extra={"sensor": "enc", "cal": [1.0, 2.5]}),
        run_from_arrays(t[:500] * 7.1, rng.standard_normal(500), P=25.0,
                        D=5.999999999999999, added_mass=0.25),
    ]
    for gz in (True, False):
        folder = tmp_path / f"set-{gz}"
        manifest = write_experiment(folder, runs, delay=0.1, title="round trip", gzip=gz,
                                    mass=2.0, loop={"sample_time": 1e-3},
                                    extra={"operator": "me"})
        assert manifest == folder / "experiment.toml"
        suffix = ".csv.gz" if gz else ".csv"
        assert sorted(p.name for p in folder.iterdir()) == sorted(
            ["experiment.toml", f"run01{suffix}", f"run02{suffix}"])
        assert "[[run]]" in manifest.read_text()
        exp = read_experiment(folder)
        assert (exp.method, exp.delay, exp.title, exp.mass) == ("pho", 0.1, "round trip", 2.0)
        assert dict(exp.loop) == {"sample_time": 1e-3, "delay": 0.1}
        assert dict(exp.extra) == {"operator": "me"}
        for a, b in zip(runs, exp.runs, strict=True):
            for key in ("t", "x", "u", "F"):
                va, vb = getattr(a, key), getattr(b, key)
                assert (va is None) == (vb is None), key
                if va is not None:
                    assert np.array_equal(va.view(np.int64), vb.view(np.int64)), key
            assert (b.P, b.D, b.added_mass) == (a.P, a.D, a.added_mass)
            assert dict(b.extra) == {k: tuple(v) if isinstance(v, list) else v
                                     for k, v in a.extra.items()}
        assert exp.runs[1].u is None


def test_rewrite_a_read_set(tmp_path: Path, sample_set_path: Path) -> None:
    src = read_experiment(sample_set_path)
    out = write_experiment(tmp_path / "copy", src, names=[r.file for r in src.runs])
    again = read_experiment(out)
    assert (again.method, again.delay, again.title) == (src.method, src.delay, src.title)
    for a, b in zip(src.runs, again.runs, strict=True):
        assert a.file == b.file and a.P == b.P and a.D == b.D
        assert np.array_equal(a.x, b.x) and np.array_equal(a.t, b.t)
        assert np.array_equal(a.u, b.u)


def test_forced_round_trip_and_names(tmp_path: Path) -> None:
    t = np.linspace(0.0, 1.0, 101)
    run = run_from_arrays(t, np.sin(5 * t), F=np.cos(5 * t), B=1.0, omega=5.0)
    write_experiment(tmp_path / "f", [run], method="forced", names=["data/a.csv"])
    exp = read_experiment(tmp_path / "f")
    assert exp.method == "forced" and exp.delay is None and "loop" not in \
        tomllib.loads((tmp_path / "f" / "experiment.toml").read_text())
    assert exp.runs[0].file == "data/a.csv"
    assert np.array_equal(exp.runs[0].F, run.F) and exp.runs[0].omega == 5.0


def test_write_refuses_to_overwrite(tmp_path: Path) -> None:
    run = run_from_arrays([0.0, 1.0], [0.0, 1.0], P=1.0, D=1.0)
    write_experiment(tmp_path / "s", [run])
    with pytest.raises(ExperimentError, match="exists already"):
        write_experiment(tmp_path / "s", [run])
    write_experiment(tmp_path / "s", [run], overwrite=True, delay=0.2)
    assert read_experiment(tmp_path / "s").delay == 0.2


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"runs": []}, ("no runs",)),
    ({"method": "step"}, ("'method'",)),
    ({"delay": -1.0}, ("'delay'", "≥ 0")),
    ({"delay": math.nan}, ("'delay'", "finite")),
    ({"names": ["a.csv", "a.csv"]}, ("used twice",)),
    ({"names": ["../a.csv", "b.csv"]}, ("relative path inside the folder",)),
    ({"names": ["a.txt", "b.csv"]}, (".csv or .csv.gz",)),
    ({"names": ["a.csv"]}, ("1 entries for 2 runs",)),
    ({"nogains": True}, ("run 2 (run02.csv.gz): missing key 'P'",)),
    ({"method": "forced"}, ("missing column 'F'",)),
])
def test_write_rejects_bad_sets(tmp_path: Path, kwargs: dict, words: tuple[str, ...]) -> None:
    t = np.arange(5.0)
    runs = [run_from_arrays(t, t, P=1.0, D=1.0),
            run_from_arrays(t, t) if kwargs.pop("nogains", False)
            else run_from_arrays(t, t, P=2.0, D=1.0)]
    runs = kwargs.pop("runs", runs)
    with pytest.raises(ExperimentError) as info:
        write_experiment(tmp_path / "bad", runs, **kwargs)
    expect(str(info.value), "experiment.toml", *words)
    assert not (tmp_path / "bad" / "experiment.toml").exists()


# --------------------------------------------------------------------------------------------
# in-memory values
# --------------------------------------------------------------------------------------------
def test_run_from_arrays_copies_and_freezes() -> None:
    t = np.arange(4) * 0.5
    x = [0.0, 1.0, 2.0, 3.0]
    run = run_from_arrays(t, x, P=1, D=2, file="r.csv", index=2)
    t[0] = 99.0
    assert run.t[0] == 0.0 and not run.t.flags.writeable
    assert run.P == 1.0 and isinstance(run.P, float)
    assert run.name == "run 2 (r.csv)"
    assert run_from_arrays(t[1:], t[1:]).name == "run"
    with pytest.raises(ValueError, match="read-only"):
        run.x[0] = 1.0


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"x": [0.0, math.nan, 0.0]}, ("column 'x'", "non-finite", "index 1")),
    ({"x": [0.0, 1.0]}, ("column 'x' has 2 samples but 't' has 3",)),
    ({"t": [0.0, 1.0, 1.0]}, ("'t' is not strictly increasing at index 2",)),
    ({"t": [0.0]}, ("at least 2",)),
    ({"t": [[0.0, 1.0, 2.0]]}, ("1-dimensional",)),
    ({"u": [0.0, math.inf, 0.0]}, ("column 'u'", "non-finite")),
    ({"F": [0.0, 1.0]}, ("column 'F'",)),
    ({"x": ["a", "b", "c"]}, ("column 'x'", "real numbers")),
    ({"P": math.nan}, ("key 'P'", "finite")),
    ({"D": "1"}, ("key 'D'", "number")),
    ({"omega": -1.0}, ("key 'omega'",)),
    ({"added_mass": -1.0}, ("key 'added_mass'",)),
    ({"extra": {"P": 1.0}}, ("not an extra key",)),
    ({"extra": {"d": 1.0}}, ("case-sensitive", "'D'")),
])
def test_run_from_arrays_checks(kwargs: dict, words: tuple[str, ...]) -> None:
    args = {"t": [0.0, 1.0, 2.0], "x": [0.0, 1.0, 2.0], "file": "r.csv", "index": 4} | kwargs
    with pytest.raises(ExperimentError) as info:
        run_from_arrays(**args)
    expect(str(info.value), "run 4 (r.csv)", *words)


def test_experiment_set_checks(tmp_path: Path) -> None:
    t = np.arange(3.0)
    run = run_from_arrays(t, t, P=1.0, D=1.0, file="a.csv", index=1)
    exp = ExperimentSet(tmp_path / "experiment.toml", [run], loop={"delay": 0.25})
    assert exp.delay == 0.25 and isinstance(exp.runs, tuple)
    with pytest.raises(ExperimentError, match="disagrees"):
        ExperimentSet(tmp_path / "e.toml", (run,), delay=0.1, loop={"delay": 0.2})
    with pytest.raises(ExperimentError, match="no runs"):
        ExperimentSet(tmp_path / "e.toml", ())
    with pytest.raises(ExperimentError, match="Run objects"):
        ExperimentSet(tmp_path / "e.toml", ("a.csv",))  # type: ignore[arg-type]
    with pytest.raises(ExperimentError, match="'mass'"):
        ExperimentSet(tmp_path / "e.toml", (run,), mass=0.0)
    free = run_from_arrays(t, t, file="b.csv", index=1)
    with pytest.raises(ExperimentError, match=r"run 1 \(b.csv\): missing key 'P'"):
        ExperimentSet(tmp_path / "e.toml", (free,))
    assert ExperimentSet(tmp_path / "e.toml", (free,), method="free").runs[0] is free
    assert Run("c.csv", t, t).P is None


def test_read_errors_from_the_os(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """OS-level read failures (as root, chmod cannot provoke them) name the file at fault."""
    folder = make_set(tmp_path)
    real_open = os.open

    def failing(path: str | os.PathLike[str], flags: int, *args: int) -> int:
        if Path(path).name == target:
            raise PermissionError(13, "Permission denied")
        return real_open(path, flags, *args)

    monkeypatch.setattr(os, "open", failing)
    target = "experiment.toml"
    expect(error_of(folder), "tiny/experiment.toml: cannot read the manifest",
           "Permission denied")
    target = "run03.csv.gz"
    expect(error_of(folder), f"experiment.toml: {RUN3}: cannot read the data file",
           "Permission denied")
