"""What the text report prints (issue 30): gains exactly as the manifest gives them, no null,
lines that fit 100 columns, one notation with an ASCII fallback."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from tracking_sets import write_tracking_set

from phoid.reports.statistics import statistics_lines
from phoid.reports.text import format_gain


def phoid(*args: str, env: dict[str, str] | None = None,
          cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`phoid ARGS` in a real subprocess (UTF-8 stdout unless ``env`` says otherwise)."""
    full = {**os.environ, "PYTHONIOENCODING": "utf-8", **(env or {})}
    return subprocess.run([sys.executable, "-m", "phoid.cli", *args], capture_output=True,
                          text=True, timeout=300, env=full, cwd=cwd,
                          encoding=None if env and "PYTHONIOENCODING" in env else "utf-8")


@pytest.fixture(scope="module")
def example_text(sample_set_path) -> str:
    res = phoid("identify", str(sample_set_path))
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_gains_are_printed_exactly_as_the_manifest_gives_them(sample_set_path, example_text):
    # expected: the manifest's own numbers (12.625 was printed 12.62 with .4g; a gain of
    # 0.8999999999999999 is not 0.9)
    manifest = tomllib.loads((sample_set_path / "experiment.toml").read_text())
    rows: dict[str, list[str]] = {}  # each run's first row (its gains, σ, …)
    for line in example_text.splitlines():
        if line.strip().startswith("run") and ".csv" in line:
            rows.setdefault(line.split()[0], line.split())
    assert len(rows) == len(manifest["run"])
    for run in manifest["run"]:
        cells = rows[run["file"]]
        assert float(cells[1]) == run["P"] and float(cells[2]) == run["D"], cells
        assert cells[1] == format_gain(run["P"])
    assert "12.625" in example_text and "12.62 " not in example_text


def test_format_gain_round_trips():
    for v in (12.625, 0.1 + 0.2, 3.0, 1e-300, 2.5e17, -7.125):
        assert float(format_gain(v)) == v
    assert format_gain(3.0) == "3" and format_gain(12.625) == "12.625"


def test_a_fit_without_chi2_says_so_in_words(sample_set_path):
    res = phoid("identify", str(sample_set_path), "--estimator", "ols")
    assert res.returncode == 0, res.stderr
    assert "null" not in res.stdout and "None" not in res.stdout
    block = res.stdout.split("[[Fit statistics]]")[1].split("[[")[0]
    assert "not computed" in block and "OLS" in block


def test_a_single_missing_statistic_reads_not_computed():
    # a weighted fit whose dof is known but whose χ²/dof is not (dof = 0)
    lines = statistics_lines({"chi2": 1.0, "dof": 0, "chi2_dof": None, "p_value": None,
                              "of": "a fit", "weighted": True})
    assert not any("null" in x or "None" in x for x in lines)
    assert any("χ²/dof" in x and "not computed" in x for x in lines)


# --- width: every line of `phoid identify` fits 100 columns, on every kind of set ----------
def _long_names(sample_set_path: Path, folder: Path) -> Path:
    """The example set with its first run's file renamed to a 60-character name."""
    import shutil

    shutil.copytree(sample_set_path, folder)
    long = "a-run-file-name-that-is-much-longer-than-the-column-run01.csv.gz"
    (folder / "run01.csv.gz").rename(folder / long)
    manifest = folder / "experiment.toml"
    manifest.write_text(manifest.read_text().replace('"run01.csv.gz"', f'"{long}"'))
    return folder


SIMULATE = {  # `phoid simulate` options of each kind (as the method's own tests give them)
    "friction": ["--m", "1", "--c", "2", "--k", "100", "--fc", "0.05", "--P", "0:150:5",
                 "--D", "0.5:3:5", "--delay", "0.02", "--duration", "6", "--noise", "1e-5",
                 "--quantum", "1e-6", "--x0", "0.008", "--seed", "3"],
    "free": ["--method", "free", "--m", "1", "--c", "2", "--k", "100", "--duration", "6",
             "--noise", "1e-5", "--seed", "3"],
    "forced": ["--method", "forced", "--omega", "2:14:6", "--duration", "20", "--fs", "250",
               "--noise", "1e-5", "--offset", "1e-3", "--seed", "12"],
    "digital": ["--m", "2", "--c", "1", "--k", "64", "--P", "0.25:25:6", "--D", "0.6:6:6",
                "--sample-time", "0.01", "--delay-samples", "1", "--duration", "8",
                "--noise", "1e-5", "--seed", "4"],
}
IDENTIFY = {"friction": ["--friction"], "free": ["--mass", "1"], "forced": [], "digital": [],
            "free-friction": ["--friction"]}


@pytest.mark.parametrize("kind", ["example", "ols", "long-names", "friction", "free",
                                  "free-friction", "forced", "digital", "tracking"])
def test_every_line_fits_100_columns(kind, sample_set_path, tmp_path):
    # relative paths, as a user types them (the report names the set as given)
    args: list[str] = []
    if kind in ("example", "ols"):
        folder = sample_set_path
        args = ["--estimator", "ols"] if kind == "ols" else []
    elif kind == "long-names":
        folder = _long_names(sample_set_path, tmp_path / "long")
    elif kind == "tracking":
        folder = write_tracking_set(tmp_path / "tracking")
    else:
        folder = tmp_path / kind
        sim = phoid("simulate", kind, *SIMULATE[kind.replace("free-friction", "free")],
                    cwd=tmp_path)
        assert sim.returncode == 0, sim.stderr
        args = IDENTIFY[kind]
    if folder.is_relative_to(tmp_path):
        folder = folder.relative_to(tmp_path)
    res = phoid("identify", str(folder), *args, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    wide = [line for line in res.stdout.splitlines() if len(line) > 100]
    assert not wide, f"{len(wide)} lines over 100 columns, e.g.\n" + "\n".join(wide[:3])
    assert len(res.stdout.splitlines()) > 5


# --- one notation, and ASCII where the stream cannot show it -----------------------------
def test_an_ascii_stdout_gets_the_ascii_notation_aligned(sample_set_path, tmp_path):
    uni = phoid("identify", str(sample_set_path))
    asc = phoid("identify", str(sample_set_path), env={"PYTHONIOENCODING": "ascii"})
    assert uni.returncode == 0 and asc.returncode == 0, asc.stderr
    assert "ω₀" in uni.stdout and "ζ" in uni.stdout and "±" in uni.stdout
    assert asc.stdout.isascii(), [c for c in asc.stdout if not c.isascii()][:5]
    for word in ("omega0 = ", "zeta = ", "+/-", "sigma +/- stderr", "chi2/dof"):
        assert word in asc.stdout, word
    assert "?" not in asc.stdout  # every symbol spelt out, none replaced
    # the runs table stays aligned: each cell of the units row ends where its name ends
    lines = asc.stdout.splitlines()
    head = next(i for i, x in enumerate(lines) if x.split()[:2] == ["run", "P"])
    for name, unit in (("sigma +/- stderr", "1/s"), ("omega_d +/- stderr", "rad/s")):
        end = lines[head].index(name) + len(name)
        assert lines[head + 1][:end].endswith(unit), (name, lines[head + 1])
    assert max(len(x) for x in lines) <= 100
    # the same numbers in both: only the notation differs
    assert [x.split()[0] for x in lines if ".csv" in x] == [
        x.split()[0] for x in uni.stdout.splitlines() if ".csv" in x]


def test_an_ascii_stderr_gets_errors_in_ascii(tmp_path):
    # "--hold must be finite and ≥ 0 s" (cli.py's own message) on an ASCII stderr
    res = phoid("simulate", str(tmp_path / "o"), "--hold", "-1",
                env={"PYTHONIOENCODING": "ascii"})
    assert res.returncode == 2
    assert res.stderr.isascii() and ">= 0" in res.stderr, res.stderr


def test_the_stream_text_is_unchanged_where_the_stream_encodes_it():
    import io

    from phoid._notation import stream_text

    text = "ω₀ = 5.6567 ± 0.0002 rad/s"
    utf8 = io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
    latin = io.TextIOWrapper(io.BytesIO(), encoding="latin-1")  # has ± but no ω
    assert stream_text(text, utf8) == text
    assert stream_text(text, latin) == "omega0 = 5.6567 +/- 0.0002 rad/s"


def test_a_table_too_wide_is_wrapped_into_blocks_and_left_columns_stay_left():
    from phoid.reports.text import text_table

    # 8 columns of 18 characters: 2 + 5 + 8·20 = 167 > 100, so two blocks, the label repeated
    cols = [("run", ""), *((f"c{j}", "s") for j in range(8))]
    rows = [["r1", *(f"{j:>18}" for j in range(8))]]
    out = text_table(cols, rows)
    assert max(len(x) for x in out) <= 100
    assert sum(x.split()[0] == "r1" for x in out if x.strip()) == 2
    # left=2: the second column (a name) starts right after the label's gap, padded after
    out = text_table([("unit", ""), ("parameter", ""), ("n", "")],
                     [["x", "ω₀", "3"], ["x", "m", "12"]], indent=0, left=2)
    assert out[1] == "x     ω₀          3" and out[2] == "x     m          12"


# --- the [[Adequacy]] block: a failed check is never followed by "every check passed" -----
def test_a_failed_check_with_white_stderr_says_they_were_not_widened_and_why(sample_set_path):
    # the OLS lines without the delay's compensation: the eq. (35) points lie off their lines
    # (χ²/dof ~8e3, the warning's numbers), so the lines check fails while the OLS stderr
    # (from the points' scatter, docs/adequacy.md) stand
    res = phoid("identify", str(sample_set_path), "--estimator", "ols", "--no-compensation")
    assert res.returncode == 0, res.stderr
    block = " ".join(res.stdout.split("[[Adequacy]]")[1].split("warnings:")[0].split())
    assert "lines FAIL" in block
    assert "every check passed" not in block
    stderr_line = block.split("stderr:")[1]
    assert stderr_line.startswith(" not widened although lines failed")
    assert "biased" in stderr_line


def test_the_adequacy_block_never_claims_every_check_passed_when_one_failed():
    # any result whose adequacy failed a check but keeps its white stderr (the OLS route, a
    # friction fit with no sandwich, or a future one without a note of its own)
    from types import SimpleNamespace

    from phoid.reports.text import adequacy_lines

    def result(passed: bool, note: str = "") -> SimpleNamespace:
        checks = (SimpleNamespace(name="noise", statistic=3.0, threshold=1.1, passed=passed),
                  SimpleNamespace(name="structure", statistic=float("nan"),
                                  threshold=float("nan"), passed=None))
        return SimpleNamespace(adequacy=SimpleNamespace(
            checks=checks, passed=passed, stderr="white", stderr_note=note, names=("m",),
            inflation=(1.0,)))

    assert adequacy_lines(result(True))[-1].endswith("(every check passed)")
    failed = adequacy_lines(result(False))[-1]
    assert "every check passed" not in failed and "not widened although noise failed" in failed
    noted = adequacy_lines(result(False, "the fit's own, for a reason"))[-1]
    assert noted.endswith("noise failed: the fit's own, for a reason")


def test_the_robust_stderr_line_names_the_parameters_in_the_notation():
    # the robust stderr's inflation per parameter, named as the report names them (σ, k/m),
    # not by the result's keys (sigma, k_over_m): the real pendulum record's report showed them
    from types import SimpleNamespace

    from phoid.reports.text import adequacy_lines, symbol

    checks = (SimpleNamespace(name="noise", statistic=30.0, threshold=1.1, passed=False),)
    res = SimpleNamespace(adequacy=SimpleNamespace(
        checks=checks, passed=False, stderr="robust", stderr_note="",
        names=("sigma", "k_over_m"), inflation=(595.0, 287.0)))
    text = " ".join(adequacy_lines(res))
    assert f"{symbol('sigma')} ×595, {symbol('k_over_m')} ×287" in text, text
    assert symbol("sigma") != "sigma" and "k_over_m" not in text


def test_a_block_whose_columns_have_no_unit_gets_no_units_row():
    from phoid.reports.text import text_table

    # 8 columns of 18 characters with units, then one without: 4 fit beside the label in
    # 100 columns (2 + 3 + 4·20 = 85; 105 with a fifth), so three blocks, the last holding the
    # unitless column alone: it gets no (empty) units row
    cols = [("run", ""), *((f"c{j}", "s") for j in range(8)), ("ratio", "")]
    rows = [["r1", *(f"{j:>18}" for j in range(8)), f"{1.0:>18}"]]
    out = text_table(cols, rows)
    heads = [i for i, x in enumerate(out) if x.split()[:1] == ["run"]]
    assert len(heads) == 3 and out[heads[-1]].split() == ["run", "ratio"], out
    assert out[heads[0] + 1].split() == ["s"] * len(out[heads[0]].split()[1:])
    assert out[heads[-1] + 1].split()[0] == "r1", out  # the row, not a blank units row
    assert all(x.strip() or (i and out[i - 1].split()[:1] != ["run"])
               for i, x in enumerate(out)), out


def test_the_ols_report_prints_no_empty_units_row(sample_set_path):
    # the OLS runs table wraps its resid/noise column into a block of its own on the example
    # set with --no-compensation (the reviewer's case): no blank line under its header
    res = phoid("identify", str(sample_set_path), "--estimator", "ols", "--no-compensation")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    for i, x in enumerate(lines[:-1]):
        if x.split()[:1] == ["run"]:
            assert lines[i + 1].strip(), lines[i:i + 3]


# --- one notation: units, the fit statistics, design and tracking warnings ----------------
@pytest.mark.parametrize("kind, unit, ascii_unit", [
    ("free", "1/s²", "1/s^2"),  # k/m
    ("free-friction", "m/s²", "m/s^2"),  # f_c/m
])
def test_units_are_written_with_superscripts_and_spelt_out_in_ascii(kind, unit, ascii_unit,
                                                                    tmp_path):
    sim = phoid("simulate", "set", *SIMULATE["free"], cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    uni = phoid("identify", "set", *IDENTIFY[kind], cwd=tmp_path)
    asc = phoid("identify", "set", *IDENTIFY[kind], cwd=tmp_path,
                env={"PYTHONIOENCODING": "ascii"})
    assert uni.returncode == 0 and asc.returncode == 0, (uni.stderr, asc.stderr)
    assert unit in uni.stdout and "^" not in uni.stdout, uni.stdout
    assert ascii_unit in asc.stdout and asc.stdout.isascii()


def test_the_fit_statistics_block_is_in_the_notation(sample_set_path, example_text):
    # the GLS fit's "χ² of": the runs' modes (σᵢ, ω_dᵢ), spelt out on an ASCII stream
    block = example_text.split("[[Fit statistics]]")[1].split("[[")[0]
    assert "(σᵢ, ω_dᵢ)" in block and "sigma" not in block, block
    asc = phoid("identify", str(sample_set_path), env={"PYTHONIOENCODING": "ascii"})
    assert asc.returncode == 0, asc.stderr
    assert "(sigma_i, omega_d_i)" in asc.stdout.split("[[Fit statistics]]")[1]


def test_design_warnings_are_in_the_notation_and_spelt_out_in_ascii():
    from phoid._notation import ascii_text
    from phoid.planning import check

    # the paper's plant (m 2, c 1, k 64, delay 0.1 s): run 4 (D 0.1) rings below the ζ band
    # 0.03-0.2, runs 3-4 exceed --pmax 5 / --dmax 10, and no run's other modes decay 50 times
    # faster than its ringing one
    d = check([0.25, 3.0, 25.0, 10.0], [0.6, 2.5, 6.0, 0.1], 2.0, 1.0, 64.0, delay=0.1,
              pmax=5.0, dmax=10.0, separation=50.0)
    text = "\n".join(d.warnings)
    for uni, asc in (("50× faster", "50x faster"), ("|P| ≤ 5 N/m", "|P| <= 5 N/m"),
                     ("band 0.03–0.2", "band 0.03-0.2"), ("runs 3–4", "runs 3-4")):
        assert uni in text, (uni, text)
        assert asc in ascii_text(text), asc
    assert "<=" not in text and "50x" not in text


def test_a_tracking_warning_says_not_reported_rather_than_null():
    import math

    from phoid.methods.estimate import Estimate
    from phoid.methods.tracking_identification import _simulable

    # a stderr that overflowed: the text must not say null (JSON writes the stderr as null)
    est = {"m": Estimate(2.0, math.inf, "kg"), "c": Estimate(1.0, 0.1, "N s/m"),
           "k": Estimate(0.0, 0.0, "N/m"), "fc": Estimate(0.5, 0.01, "N")}
    warnings: list[str] = []
    _simulable(est, warnings)
    (w,) = warnings
    assert "stderr of m" in w and "not reported" in w and "null" not in w
