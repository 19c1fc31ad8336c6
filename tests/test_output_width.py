"""Every command's text, and every public result's ``report()``, in one shape (issue 30, item 4).

Each command runs through the command line (typer's CliRunner, whose streams have the encoding
asked: UTF-8, or ASCII as under ``PYTHONIOENCODING=ascii``) on sets made here (conftest's
``varied_sets``: pho, a sampled loop, forced, free with its mass, Coulomb friction; a tracking
set (tests/tracking_sets.py); examples/paper-sample), and its output is checked for what
issue 30 asks:

* no line wider than 100 columns (an error, or a warning beside --json, is one line however
  long: it names the file, run and field, and a program reads it as one; it is checked to be
  one line instead);
* no ``null``, ``None`` or ``nan`` where a word belongs;
* in a UTF-8 stream, one notation: σ, ω₀, ω_d, ζ, ±, χ² (not their ASCII spellings), every
  character of it with an ASCII spelling (none would print as ``?``); in an ASCII stream, only
  ASCII;
* no ``<bool>`` metavar in any --help;
* gains (and a given delay) exactly as given: the tables' P and D are the manifest's numbers.
"""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from tracking_sets import write_tracking_set
from typer.testing import CliRunner

import phoid
import phoid.io
from phoid._notation import ascii_text, fit_width, stream_notation
from phoid.cli import app
from phoid.reports.text import format_gain

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "paper-sample"
WIDTH = 100  # issue 30: "a text report that fits 100 columns"
# a missing value printed as a word a program uses for it (JSON's null, Python's None, nan)
FORBIDDEN = re.compile(r"\b(null|None|nan|NaN)\b")
# the ASCII spellings of the notation (phoid._notation), which a UTF-8 stream must not show
ASCII_SPELLINGS = re.compile(r"\b(sigma|omega0|omega_d|omega|zeta|chi2)\b|\+/-")
ENCODINGS = ["utf-8", "ascii"]
# an absolute path in a status line ("… written to /tmp/…")
PATH = re.compile(r"/\S+")


@pytest.fixture(scope="module")
def sets(varied_sets, tmp_path_factory) -> dict[str, Path]:
    """The sets every command runs on, and a batch output of three of them."""
    root = tmp_path_factory.mktemp("width")
    out = {**varied_sets, "example": EXAMPLE, "root": root,
           "track": write_tracking_set(root / "track", noise=1e-6)}  # 1 µm of sensor noise
    fleet = root / "fleet"
    for name in ("pho", "dig", "forced"):
        shutil.copytree(varied_sets[name], fleet / name)
    res = CliRunner().invoke(app, ["batch", str(fleet / "*"), "--out",
                                   str(root / "b" / "results.parquet"), "--workers", "0"])
    assert res.exit_code == 0, res.output
    out["results"] = root / "b" / "results.parquet"
    return out


# (id, arguments with {name} for a set's folder and {out} for a fresh output folder)
COMMANDS = [
    ("identify-example", ["identify", "{example}"]),
    ("identify-example-ols", ["identify", "{example}", "--estimator", "ols",
                              "--no-compensation"]),
    ("identify-pho", ["identify", "{pho}", "--delay", "0.02"]),
    ("identify-sampled", ["identify", "{dig}"]),
    ("identify-friction", ["identify", "{fr}", "--friction"]),
    ("identify-forced", ["identify", "{forced}"]),
    ("identify-free", ["identify", "{free}"]),
    ("identify-free-no-mass", ["identify", "{free}", "--mass", "1"]),
    ("identify-free-friction", ["identify", "{free}", "--friction"]),
    ("identify-tracking", ["identify", "{track}"]),
    ("replay", ["simulate", "{out}", "--replay", "{track}", "--m", "2", "--c", "15", "--fc",
                "1.5", "--offset-force", "-0.3"]),
    ("simulate-pho", ["simulate", "{out}", "--P", "1:5:3", "--D", "0.5", "--duration", "1",
                      "--fs", "200"]),
    ("simulate-forced", ["simulate", "{out}", "--method", "forced", "--omega", "5",
                         "--duration", "2", "--fs", "200"]),
    ("simulate-free", ["simulate", "{out}", "--method", "free", "--duration", "1", "--fs",
                       "200"]),
    ("paper", ["paper", "--out", "{out}", "--duration", "6", "--fs", "250"]),
    ("design", ["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.01", "--runs",
                "4", "--duration", "3"]),
    ("design-sampled", ["design", "--m", "1:3", "--c", "0.5:2", "--k", "50:80",
                        "--sample-time", "0.001", "--delay-samples", "2", "--runs", "4",
                        "--duration", "3"]),
    ("design-check", ["design", "--check", "{pho}", "--m", "1", "--c", "2", "--k", "100",
                      "--delay", "0.02"]),
    ("design-rehearse", ["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.01",
                         "--runs", "3", "--duration", "2", "--rehearse", "3", "--workers",
                         "0", "--seed", "1"]),
    ("batch", ["batch", "{pho}", "{free}", "--out", "{out}/r.parquet", "--workers", "0"]),
    ("trend", ["trend", "{results}", "--by", "method", "--baseline", "1"]),
]
# (id, arguments, exit status): errors are one line, whatever their length
ERRORS = [
    ("no-set", ["identify", "{root}/none"], 2),
    ("bad-range", ["simulate", "{out}", "--P", "1:2"], 2),
    ("no-prior", ["design"], 2),
    ("trend-no-unit", ["trend", "{results}", "--by", "axis"], 2),
    ("bad-option", ["identify", "{pho}", "--estimator", "nope"], 2),
]


def _args(args: list[str], sets: dict[str, Path], tmp_path: Path) -> list[str]:
    return [a.format(out=tmp_path / "out", **{k: str(v) for k, v in sets.items()})
            for a in args]


def _invoke(args: list[str], encoding: str):
    return CliRunner(charset=encoding).invoke(app, args, terminal_width=WIDTH)


def _check_text(text: str, encoding: str, what: str, *, notation: bool = True) -> None:
    """The rules every line of a command's output keeps (an error or warning line on stderr
    excepted from the width: it is one line by design, for a program that reads it).
    ``notation``: check the UTF-8 text's notation (not in --help, which names options such as
    --zeta and --omega)."""
    lines = text.splitlines()
    # a path is never split from its line (a status line naming the files written is read by
    # programs): a line may be wide by its paths alone
    wide = [x for x in lines if len(PATH.sub("P", x)) > WIDTH and not x.startswith("phoid: ")]
    assert not wide, f"{what}: lines wider than {WIDTH}: {wide}"
    bad = [x for x in lines if FORBIDDEN.search(x)]
    assert not bad, f"{what}: a program's word for a missing value: {bad}"
    if encoding == "ascii":
        assert text.isascii(), (what, [x for x in lines if not x.isascii()])
        return
    # every character the ASCII stream cannot show has a spelling there (none becomes "?")
    lost = [x for x in lines if ascii_text(x).count("?") != x.count("?")]
    assert not lost, f"{what}: characters without an ASCII spelling: {lost}"
    if notation:
        spelled = [x for x in lines if ASCII_SPELLINGS.search(x)]
        assert not spelled, f"{what}: ASCII spellings in a UTF-8 stream: {spelled}"


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize(("name", "args"), COMMANDS, ids=[c[0] for c in COMMANDS])
def test_command_text_fits_and_reads_one_way(sets, tmp_path, name, args, encoding):
    res = _invoke(_args(args, sets, tmp_path), encoding)
    # the check of the set's gains against a wider prior finds some unsafe (status 1, and
    # its table says which)
    assert res.exit_code == (1 if name == "design-check" else 0), (name, res.output)
    assert res.stdout.strip(), name
    _check_text(res.stdout, encoding, f"{name} stdout")
    _check_text(res.stderr, encoding, f"{name} stderr")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_a_status_line_keeps_its_long_path_whole(sets, tmp_path, encoding):
    # "… written to PATH" is one line however long PATH is: a program (or a user's copy and
    # paste) reads the path from it; wrapping would split it from its words
    deep = tmp_path.joinpath(*(["a-rather-long-folder-name"] * 5))
    plots, page = deep / "plots", deep / "report.html"
    res = _invoke(["identify", str(sets["free"]), "--plots", str(plots), "--html", str(page)],
                  encoding)
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert len(str(plots)) > WIDTH  # the case tested: a path wider than the width
    assert any(x.endswith(f" written to {plots}") for x in lines), lines
    assert f"report written to {page}" in lines, lines
    res = _invoke(["simulate", str(deep / "sim"), "--method", "free", "--duration", "2"],
                  encoding)
    assert res.exit_code == 0, res.output
    assert f"wrote 1 run to {deep / 'sim' / 'experiment.toml'}" in res.stdout.splitlines(), \
        res.stdout


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize(("name", "args", "code"), ERRORS, ids=[e[0] for e in ERRORS])
def test_errors_are_one_line_in_either_stream(sets, tmp_path, name, args, code, encoding):
    res = _invoke(_args(args, sets, tmp_path), encoding)
    assert res.exit_code == code, (name, res.output)
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), (name, res.stderr)
    _check_text(res.stderr, encoding, f"{name} stderr")
    assert "Traceback" not in res.output


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_json_warnings_are_one_line_each(sets, encoding):
    # beside --json each warning is one `phoid: warning:` line on stderr, however long (a
    # program reads them line by line), in the notation the stream can show
    res = _invoke(["identify", str(sets["track"]), "--json"], encoding)
    assert res.exit_code == 0, res.output
    warnings = json.loads(res.stdout)["warnings"]
    lines = res.stderr.splitlines()
    assert warnings and len(lines) == len(warnings), (warnings, lines)
    assert all(x.startswith("phoid: warning: ") for x in lines)
    _check_text(res.stderr, encoding, "identify --json stderr")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_help_has_no_bool_metavar_and_fits(encoding):
    import typer

    names = ["", *sorted(typer.main.get_command(app).commands)]
    for name in names:
        res = _invoke([name, "--help"] if name else ["--help"], encoding)
        assert res.exit_code == 0, (name, res.output)
        assert "<bool>" not in res.output, name
        _check_text(res.output, encoding, f"phoid {name} --help", notation=False)


def test_pho_gains_are_the_manifests_numbers(sets):
    # expected: each run's P and D as the manifest writes them (format_gain: repr, no ".0"),
    # in the example set, whose D are decimals (0.9, not 0.8999999999999999), and in a set
    # simulated from a start:stop:count range of gains
    for folder in (sets["example"], sets["pho"]):
        manifest = tomllib.loads((folder / "experiment.toml").read_text(encoding="utf-8"))
        res = _invoke(["identify", str(folder), "--delay", "0.1" if folder == EXAMPLE
                       else "0.02"], "utf-8")
        assert res.exit_code == 0, res.output
        rows: dict[str, list[str]] = {}  # each run's first row (a wrapped table repeats it)
        for line in res.stdout.splitlines():
            if line.strip().startswith("run") and ".csv" in line:
                rows.setdefault(line.split()[0], line.split())
        for run in manifest["run"]:
            assert rows[run["file"]][1:3] == [format_gain(run["P"]), format_gain(run["D"])]
    # a checked schedule's gains too: the table's P and D are the set's (rows: run number,
    # P, D, …)
    manifest = tomllib.loads((sets["pho"] / "experiment.toml").read_text(encoding="utf-8"))
    res = _invoke(["design", "--check", str(sets["pho"]), "--m", "1", "--c", "2", "--k", "100",
                   "--delay", "0.02"], "utf-8")
    cells = [x.split() for x in res.stdout.splitlines() if x[:1].isdigit()]
    assert [c[1:3] for c in cells] == [[format_gain(r["P"]), format_gain(r["D"])]
                                       for r in manifest["run"]], res.stdout
    example = tomllib.loads((EXAMPLE / "experiment.toml").read_text(encoding="utf-8"))
    # the paper's D_i = 0.6 + 0.3 i N s/m as the decimals it prints (i = 0 … 18)
    assert [r["D"] for r in example["run"]] == [float(f"{0.6 + 0.3 * i:.1f}")
                                                 for i in range(19)]


def test_a_range_of_gains_is_its_decimals(tmp_path):
    # expected: --D 0.6:6:19 means 0.6, 0.9, …, 6.0 (the binary steps of linspace give
    # 0.8999999999999999 for the second); the ends exactly as typed
    res = _invoke(["simulate", str(tmp_path / "s"), "--P", "0.25:25:19", "--D", "0.6:6:19",
                   "--duration", "0.5", "--fs", "100"], "utf-8")
    assert res.exit_code == 0, res.output
    runs = tomllib.loads((tmp_path / "s" / "experiment.toml").read_text())["run"]
    assert [r["D"] for r in runs] == [float(f"{0.6 + 0.3 * i:.1f}") for i in range(19)]
    assert [r["P"] for r in runs] == [0.25 + 1.375 * i for i in range(19)]  # exact in binary
    assert res.stdout.strip().startswith("wrote 19 runs")
    # a step with no short decimal (20/3 apart: 11.666…) stays the binary step, not a
    # 15-digit rounding of it
    thirds = _invoke(["simulate", str(tmp_path / "t"), "--P", "5:25:4", "--D", "1",
                      "--duration", "0.5", "--fs", "100"], "utf-8")
    assert thirds.exit_code == 0, thirds.output
    runs3 = tomllib.loads((tmp_path / "t" / "experiment.toml").read_text())["run"]
    assert [r["P"] for r in runs3] == np.linspace(5.0, 25.0, 4).tolist()
    one = _invoke(["simulate", str(tmp_path / "one"), "--P", "0.30000000000000004", "--D", "1",
                   "--duration", "0.5", "--fs", "100"], "utf-8")
    assert one.exit_code == 0, one.output
    assert one.stdout.strip().startswith("wrote 1 run to")  # one run, not "1 runs"
    run = tomllib.loads((tmp_path / "one" / "experiment.toml").read_text())["run"][0]
    assert run["P"] == 0.1 + 0.2  # a single value exactly as given, every digit


def _widths(text: str) -> list[int]:
    return [len(x) for x in text.splitlines()]


def test_python_reports_fit_100_columns(sets):
    # report() from Python, not only through the command line: every public result's text
    ident = phoid.identify(EXAMPLE)
    plan = phoid.design(2.0, 1.0, 64.0, delay=0.01, runs=3, duration=2.0)
    results = {
        "identify": ident,
        "identify-free": phoid.identify(sets["free"]),
        "identify-forced": phoid.identify(sets["forced"]),
        "identify-tracking": phoid.identify(sets["track"]),
        "design": plan,
        "rehearsal": phoid.rehearse(plan, 3, seed=1),  # in this process (no client)
        "identify-free-friction": phoid.identify(sets["free"], friction=True),
        "trend": phoid.trend(sets["results"], by="method", baseline=1),
        "replay": phoid.replay_set(phoid.read_experiment(sets["track"]),
                                   {"m": 2.0, "c": 15.0, "k": 0.0, "fc": 1.5,
                                    "offset": -0.3}),
    }
    for name, result in results.items():
        text = result.report()
        assert max(_widths(text)) <= WIDTH, (name, [x for x in text.splitlines()
                                                    if len(x) > WIDTH])
        assert not FORBIDDEN.search(text), (name, text)
        assert not ASCII_SPELLINGS.search(text), (name, text)
    # the long warning lines of a report are wrapped, none cut: every word is still there
    words = " ".join(ident.warnings).split()
    assert all(w in ident.report().split() for w in words)


class _AsciiStream:
    """A stream that says it writes ASCII (as stdout under PYTHONIOENCODING=ascii)."""

    encoding = "ascii"


def test_a_report_is_fitted_in_the_notation_it_is_printed_in(sets):
    # in an ASCII stream "≤" is printed "<=", a column wider: the prose is wrapped where its
    # lines are as printed, so that no wrap leaves a word alone on a line of its own
    line = "  " + "a" * 92 + " x ≤ b"  # 100 columns in unicode, 101 in ASCII
    assert fit_width(line) == line
    with stream_notation(_AsciiStream()):
        assert fit_width(line).splitlines() == ["  " + "a" * 92 + " x <=", "    b"]
        text = phoid.identify(sets["free"], friction=True).report()
    # report() from Python inside the ASCII notation: all of it spelled out, and fitted
    assert text.isascii() and max(_widths(text)) <= WIDTH


def test_paper_errors_name_the_option(tmp_path):
    # the simulator's words name its keyword (`fs`); the command names its option
    res = _invoke(["paper", "--fs", "1", "--out", str(tmp_path / "p")], "utf-8")
    assert res.exit_code == 2 and res.stderr.startswith("phoid: error: --fs must be"), res.stderr
    assert "`fs`" not in res.stderr


def test_a_given_delay_is_printed_as_given(sets):
    # expected: the option's own digits (":g" printed 0.0200000001 as 0.02)
    res = _invoke(["identify", str(sets["pho"]), "--delay", "0.0200000001"], "utf-8")
    assert res.exit_code == 0, res.output
    assert "delay 0.0200000001 s" in res.stdout.splitlines()[1], res.stdout


@pytest.mark.parametrize("env", [{"PYTHONIOENCODING": "ascii"},
                                 {"LC_ALL": "C", "LANG": "C", "PYTHONCOERCECLOCALE": "0",
                                  "PYTHONUTF8": "0"}], ids=["pythonioencoding", "c-locale"])
def test_a_real_ascii_terminal_gets_ascii(env, tmp_path):
    # a real process whose stdout is ASCII (PYTHONIOENCODING=ascii, or the C locale without
    # Python's UTF-8 coercion): the design report spelled in ASCII (é too), and fitted
    import os
    import subprocess
    import sys

    full = {k: v for k, v in os.environ.items() if k not in ("PYTHONUTF8", "LC_ALL", "LANG")}
    res = subprocess.run([sys.executable, "-m", "phoid.cli", "design", "--m", "2", "--c", "1",
                          "--k", "64", "--sample-time", "0.01", "--delay-samples", "1",
                          "--runs", "3", "--duration", "3"], capture_output=True, timeout=120,
                         env={**full, **env}, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    out = res.stdout.decode("ascii")  # raises if a byte is not ASCII
    assert "sigma" in out and "+/-" in out and "Cramer-Rao" in out
    assert max(len(x) for x in out.splitlines()) <= WIDTH
