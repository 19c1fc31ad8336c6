"""Hostile outputs (prober B, findings I, J, K and part of H).

I: no output of a command replaces one of its own inputs, even with --overwrite;
J: user-supplied text (file names, units, warnings) reaches a text report with its control and
   bidi-override characters escaped, so a name cannot split a row or reverse what follows;
K: numbers far from 1 print in exponent form, the trend's sums do not overflow, a subnormal
   stderr is left out with a warning;
H: batch --timeout is bounded before anything runs; design --check --delay is checked against
   the set's records, naming --delay.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from phoid._output import OutputFolder, protect_inputs, safe_text
from phoid.cli import app
from phoid.errors import OutputError
from phoid.reports.text import format_estimate, format_number, format_ratio

runner = CliRunner()

# a small valid set: 3 runs of 2 s at 200 Hz (test_output_safety's fixture settings)
_SIM = ["--P", "1,2,3", "--D", "0.6,0.9,1.2", "--duration", "2", "--fs", "200", "--seed", "1",
        "--no-gzip"]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("recorded") / "set"
    r = runner.invoke(app, ["simulate", str(out), *_SIM])
    assert r.exit_code == 0, r.output
    return out


def _copy(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for p in src.iterdir():
        (dst / p.name).write_bytes(p.read_bytes())
    return dst


def _refused(result, *needles: str) -> str:
    """Exit status 2 and one 'phoid: error:' line naming the needles."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error:"), result.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# ------------------------------------------------------------------------------------------
# I: an output never replaces an input


def test_html_over_the_manifest_is_refused_even_with_overwrite(tmp_path, recorded):
    s = _copy(recorded, tmp_path / "s")
    before = (s / "experiment.toml").read_bytes()
    r = runner.invoke(app, ["identify", str(s), "--html", str(s / "experiment.toml"),
                            "--overwrite"])
    _refused(r, "experiment.toml", "input", "--overwrite")
    assert (s / "experiment.toml").read_bytes() == before


def test_html_over_a_hard_link_of_a_data_file_is_refused(tmp_path, recorded):
    s = _copy(recorded, tmp_path / "s")
    before = (s / "run02.csv").read_bytes()
    os.link(s / "run02.csv", tmp_path / "report.html")  # the same file under another name
    r = runner.invoke(app, ["identify", str(s), "--html", str(tmp_path / "report.html"),
                            "--overwrite"])
    _refused(r, "report.html", "run02.csv")
    assert (s / "run02.csv").read_bytes() == before


def test_a_trend_figure_over_the_results_read_is_refused(tmp_path):
    # a batch output named like the figure of its unit a (trend-a.png), --plots its folder
    pd = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    path = tmp_path / "trend-a.png"
    _trend_rows(pd, [1.0] * 6, [0.1] * 6).to_parquet(path)
    before = path.read_bytes()
    r = runner.invoke(app, ["trend", str(path), "--baseline", "3", "--plots", str(tmp_path),
                            "--overwrite"])
    _refused(r, "trend-a.png", "input")
    assert path.read_bytes() == before


def test_protected_inputs_are_known_through_a_linked_folder(tmp_path):
    (tmp_path / "data").mkdir()
    f = tmp_path / "data" / "input.csv"
    f.write_text("t,x\n")
    (tmp_path / "alias").symlink_to(tmp_path / "data")
    with protect_inputs([f]), pytest.raises(OutputError, match=r"input\.csv.*input of this"):
        OutputFolder(tmp_path / "alias", overwrite=True).write("input.csv", b"x")
    assert f.read_text() == "t,x\n"
    # outside the context the same write is an ordinary replacement
    OutputFolder(tmp_path / "alias", overwrite=True).write("input.csv", b"x")
    assert f.read_text() == "x"


# ------------------------------------------------------------------------------------------
# J: control and bidi characters escaped


@pytest.mark.parametrize("ch", ["\n", "\r", "\x1b", "\x00", "\u202e", "\u2066", "\u2028",
                                "\u2029", "\u200b", "\x85"])
def test_safe_text_escapes_controls_format_characters_and_separators(ch):
    out = safe_text(f"a{ch}b")
    # the escape is Python's own spelling of the character (unicode_escape)
    assert out == "a" + ch.encode("unicode_escape").decode("ascii") + "b"
    assert out.isprintable()


def test_safe_text_keeps_printable_text_and_optionally_newlines():
    assert safe_text("rün 01 ± 2 kg") == "rün 01 ± 2 kg"
    assert safe_text("a\nb\x1b", newlines=True) == "a\nb\\x1b"


def test_a_file_name_with_a_newline_and_a_bidi_override_stays_on_its_row(tmp_path, recorded):
    s = _copy(recorded, tmp_path / "s")
    name = "a\nb\u202ec.csv"
    (s / "run01.csv").rename(s / name)
    manifest = s / "experiment.toml"
    manifest.write_text(manifest.read_text().replace('"run01.csv"', '"a\\nb\\u202ec.csv"'))
    r = runner.invoke(app, ["identify", str(s)])
    assert r.exit_code == 0, r.output
    assert "\u202e" not in r.stdout
    row = [line for line in r.stdout.splitlines() if line.startswith("  a\\nb\\u202ec.csv")]
    # the row on one line in each block of the table (a table wider than 100 columns is
    # wrapped into blocks, the name repeated): name, then the gains of run 1 (P = 1) and the
    # other columns, none on a line of their own
    assert row and row[0].split()[1] == "1", r.stdout
    assert sum(len(x.split()) - 1 for x in row) >= 9, r.stdout


def test_a_trend_unit_with_controls_is_escaped_in_the_table():
    pd = pytest.importorskip("pandas")
    from phoid.batch.drift import trend

    rows = _trend_rows(pd, [2.0] * 6, [0.1] * 6, unit="X\x1b[31m\n1\u202e")
    text = trend(rows, baseline=3).report()
    assert "\x1b" not in text and "\u202e" not in text
    table = [line for line in text.splitlines() if line.startswith("X")]
    assert table == [line for line in table if "X\\x1b[31m\\n1\\u202e" in line] and table


# ------------------------------------------------------------------------------------------
# K: numbers


def _trend_rows(pd, values, stderrs, unit="a"):
    return pd.DataFrame([
        {"set": f"sets/{unit}-{i}", "checksum": f"{i:064x}", "options": "{}", "status": "ok",
         "method": "pho", "axis": unit,
         "time": pd.Timestamp("2026-11-01T02:00Z") + pd.Timedelta(days=i),
         "finished": pd.Timestamp("2026-12-01T00:00Z"), "m": v, "m_stderr": s}
        for i, (v, s) in enumerate(zip(values, stderrs, strict=True))])


def test_trend_of_equal_values_near_the_largest_float_flags_nothing():
    # finding: m = 1e308 everywhere gave change -inf, z -inf and flagged points: the weighted
    # sums overflowed. Equal values: the baseline is the value, every z is 0.
    pd = pytest.importorskip("pandas")
    from phoid.batch.drift import trend

    result = trend(_trend_rows(pd, [1e308] * 8, [1e-4] * 8), baseline=3)
    chart = result.units[0].charts[0]
    assert chart.baseline == 1e308 and chart.flagged == 0
    assert all(p.z == 0.0 for p in chart.points if not p.baseline)
    assert "inf" not in result.report()


@pytest.mark.parametrize("tiny", [1e-320, 5e-324])
def test_a_subnormal_stderr_is_left_out_with_a_warning_naming_the_set(tiny):
    pd = pytest.importorskip("pandas")
    from phoid.batch.drift import trend

    stderrs = [0.1] * 7 + [tiny]
    result = trend(_trend_rows(pd, [1.0] * 8, stderrs), baseline=3)
    assert len(result.units[0].charts[0].points) == 7
    assert any("1 of 8" in w and "sets/a-7" in w for w in result.warnings), result.warnings


def test_trend_command_on_a_subnormal_stderr_is_not_an_error(tmp_path):
    pd = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    path = tmp_path / "results.parquet"
    _trend_rows(pd, [2.0] * 10, [1e-320] * 10).to_parquet(path)
    r = runner.invoke(app, ["trend", str(path), "--baseline", "3"])
    assert r.exit_code == 0, r.output
    assert "sets/a-0" in r.stdout and "left out" in r.stdout


@pytest.mark.parametrize(("value", "se"), [(5.000047e-300, 8.7e-306), (1e300, 1e297),
                                           (-3e-200, 1e-203), (0.0, 1e-300)])
def test_estimates_far_from_one_print_in_exponent_form(value, se):
    text = format_estimate(value, se)
    shown = text.split(" ± ")[0]
    # at most 17 significant digits plus sign, point and exponent, and the value itself to the
    # stderr's place (so within one stderr of it)
    assert len(shown) <= 24 and "e" in shown, text
    assert abs(float(shown) - value) <= se, text


def test_format_number_switches_to_exponent_form():
    assert format_number(1e300, 2) == f"{1e300:.2e}"
    assert format_number(-2.5e-9, 3) == f"{-2.5e-9:.3e}"
    assert format_number(4.16, 2) == "4.16"
    assert format_number(-math.inf, 2) == "-inf"


def test_format_ratio_of_an_overflowing_quotient():
    # 1e-3 / 5e-324 overflows a float; its value is 10^(log10(1e-3) - log10(5e-324))
    text = format_ratio(1e-3, 5e-324)
    assert "inf" not in text
    expected = 10 ** (math.log10(1e-3) - math.log10(5e-324) - 320)
    assert text.endswith("e+320") and abs(float(text[:-5]) - expected) < 0.01, text
    assert format_ratio(3.0, 2.0) == "1.5"


def test_free_decay_with_a_tiny_mass_prints_no_hundreds_of_digits(tmp_path):
    out = tmp_path / "free"
    r = runner.invoke(app, ["simulate", str(out), "--method", "free", "--duration", "2",
                            "--fs", "200", "--noise", "1e-6", "--seed", "1"])
    assert r.exit_code == 0, r.output
    # the smallest mass phoid takes (physical numbers are bounded to 1e-30 … 1e30, docs/format.md)
    r = runner.invoke(app, ["identify", str(out), "--mass", "1e-30"])
    assert r.exit_code == 0, r.output
    assert max(len(line) for line in r.stdout.splitlines()) < 200, r.stdout
    c_line = next(line for line in r.stdout.splitlines() if line.strip().startswith("c ="))
    # c = (c/m)·m in exponent form: the report's own c/m times 1e-30, to its printed digits
    cm_line = next(line for line in r.stdout.splitlines() if line.strip().startswith("c/m ="))
    c_over_m = float(cm_line.split("=")[1].split("±")[0])
    c = float(c_line.split("=")[1].split("±")[0])
    assert "e-3" in c_line and abs(c / (c_over_m * 1e-30) - 1) < 1e-5, (c_line, cm_line)
    # one below it is refused in one line naming the set and the option, not printed
    r = runner.invoke(app, ["identify", str(out), "--mass", "1e-300"])
    assert r.exit_code == 2 and "--mass" in r.stderr and "experiment.toml" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------------------------------
# H: --timeout and --delay


@pytest.mark.parametrize("timeout", ["1e10", "inf", "0", "-1", "nan"])
def test_batch_timeout_out_of_range_is_refused_before_anything(tmp_path, recorded, timeout):
    pytest.importorskip("distributed")
    out = tmp_path / "o" / "r.parquet"
    r = runner.invoke(app, ["batch", str(recorded), "--out", str(out), "--scheduler",
                            "tcp://127.0.0.1:1", "--timeout", timeout])
    _refused(r, "--timeout")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("delay", ["100", "1e300", "30"])
def test_design_check_delay_longer_than_the_records_names_delay(recorded, delay):
    r = runner.invoke(app, ["design", "--check", str(recorded), "--m", "2", "--c", "1",
                            "--k", "64", "--delay", delay])
    line = _refused(r, "--delay", "experiment.toml")
    assert "units" not in line  # not the plant's units blamed


def test_simulate_over_its_own_schedule_is_refused_even_with_overwrite(tmp_path):
    # `simulate OUT --schedule PLAN` with OUT the plan's folder would replace the plan's
    # manifest with the simulated set's (docs/format.md: outputs never replace inputs)
    plan = tmp_path / "plan"
    r = runner.invoke(app, ["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.01",
                            "--noise", "1e-5", "--out", str(plan)])
    assert r.exit_code == 0, r.output
    before = sorted(p.name for p in plan.iterdir()), (plan / "experiment.toml").read_bytes()
    for schedule in (plan, plan / "experiment.toml"):
        r = runner.invoke(app, ["simulate", str(plan), "--schedule", str(schedule),
                                "--overwrite"])
        _refused(r, "experiment.toml", "input", "--overwrite")
        after = sorted(p.name for p in plan.iterdir()), (plan / "experiment.toml").read_bytes()
        assert after == before  # not a run file written beside it either
