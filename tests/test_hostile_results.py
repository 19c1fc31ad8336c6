"""Hostile inputs to the results' display, export and pandas input (issue 19's review).

Each test feeds what a careless or hostile user would and expects a one-line ValueError that
names the argument (or a result that says what it cannot know), never a traceback from deep
inside numpy, a MemoryError or a silently wrong number. Expected values come from the
definitions (Python's own ``format`` of the estimate's text, float round-trips), not from
the code under test.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import phoid
from phoid import Estimate
from phoid.interop import LinearPlant, closed_loop, linear_plant, sample_plants, to_lti
from phoid.interop.plant import MAX_DRAWS
from phoid.reports.text import format_estimate


def _result(cov, delay=0.0):
    """A PHO-like result by duck typing (what phoid.interop reads: m, c, k, cov, runs, delay)."""
    return SimpleNamespace(
        m=Estimate(2.0, math.sqrt(cov[0, 0]), "kg"), c=Estimate(1.0, math.sqrt(cov[1, 1]),
                                                                "N s/m"),
        k=Estimate(64.0, math.sqrt(cov[2, 2]), "N/m"), cov=cov, delay=delay,
        runs=(SimpleNamespace(file="r1", P=10.0, D=2.0, added_mass=0.0),))


# --------------------------------------------------------------------------------------------
# Estimate formatting


@pytest.mark.parametrize("spec", [">30", "<30", "^30", "*^30", "30", "s", ">30s"])
def test_an_alignment_spec_pads_the_whole_estimate_not_the_bare_value(spec):
    e = Estimate(2.000123, 0.0042, "kg")
    # Python's own padding of the empty-spec text "value ± stderr unit": the stderr and the
    # unit are not dropped by a width
    assert format(e, spec) == format(format(e, ""), spec)
    assert "± 0.0042 kg" in format(e, spec)


@pytest.mark.parametrize("spec", [".4f", "e", "+", "g", "010.3f"])
def test_a_numeric_spec_formats_the_value(spec):
    e = Estimate(2.000123, 0.0042, "kg")
    assert format(e, spec) == format(2.000123, spec)


def test_an_integer_spec_is_a_one_line_value_error():
    with pytest.raises(ValueError, match="Unknown format code 'd'"):
        format(Estimate(2.0, 0.1, "kg"), "d")


@pytest.mark.parametrize(("value", "se"), [(2.0, 1e-300), (1e300, 1e-300), (-3.5, 1e-40),
                                           (0.0, 1e-320)])
def test_a_stderr_below_double_resolution_prints_all_the_floats_digits_not_hundreds(value, se):
    text = format_estimate(value, se)
    shown = text.split(" ± ")[0]
    # the printed value is the float itself (17 significant digits round-trip a float64),
    # and no longer than 17 digits plus sign, point and exponent
    assert float(shown) == value and len(shown) <= 24, text
    assert text.endswith(f"± {se:.2g}")


def test_the_usual_stderr_still_rounds_to_its_two_digits():
    # the rule of format_estimate's docstring: decimals up to the stderr's second digit
    assert format_estimate(2.000123, 0.0042) == f"{2.000123:.4f} ± {0.0042:.2g}"


# --------------------------------------------------------------------------------------------
# pandas records


def test_complex_and_non_numeric_tables_are_refused_naming_the_column():
    pd = pytest.importorskip("pandas")
    t = np.arange(4) * 0.1
    with pytest.raises(ValueError, match=r"^t: the values \(x\) is complex") as info:
        phoid.run_from_arrays(pd.Series(np.zeros(4) + 1j, index=t))
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match=r"^data\[0\]: column 'u' is complex"):
        phoid.identify_data([pd.DataFrame({"x": np.zeros(4), "u": np.zeros(4) + 0j},
                                          index=t)], [1.0], [0.5], 0.0)
    with pytest.raises(ValueError, match=r"^t: the values \(x\) is not numeric"):
        phoid.run_from_arrays(pd.Series(["a"] * 4, index=t))
    with pytest.raises(ValueError, match=r"^t: the index \(t\) is neither real numbers"):
        phoid.run_from_arrays(pd.Series(np.zeros(4), index=t + 1j))


def test_identify_data_refuses_gains_that_do_not_match_the_runs():
    # five records and six gains: one run's gains would silently be dropped (or misplaced)
    t = np.arange(100) * 1e-3
    data = [(t, np.zeros_like(t))] * 5
    gains = np.arange(1.0, 7.0)
    with pytest.raises(ValueError, match=r"^`P` must give one entry per run \(5 runs\); got 6"):
        phoid.identify_data(data, gains, gains[:5], 0.0)
    with pytest.raises(ValueError, match=r"^`D` must give one entry per run \(5 runs\); got 6"):
        phoid.identify_data(data, gains[:5], gains, 0.0)
    with pytest.raises(ValueError, match=r"^`files` must give one entry per run"):
        phoid.identify_data(data, gains[:5], gains[:5], 0.0, files=["a", "b"])


# --------------------------------------------------------------------------------------------
# export


def test_a_result_without_standard_errors_exports_its_plant_and_refuses_to_sample():
    # two runs fitted by the eq. (35) lines: no residual, so the stderrs and cov are nan
    nan = _result(np.full((3, 3), np.nan))
    plant = linear_plant(nan)
    assert np.isnan(plant.cov).all() and any("unknown" in n for n in plant.notes)
    sys = to_lti(nan)
    assert sys.den.tolist() == [1.0, 1.0 / 2.0, 64.0 / 2.0]  # 1/(m s² + c s + k), monic
    with pytest.raises(ValueError, match=r"covariance of \(m, c, k\) is unknown"):
        sample_plants(nan, 3)
    with pytest.raises(ValueError, match="infinite"):
        LinearPlant(2.0, 1.0, 64.0, cov=np.diag([np.inf, 1.0, 1.0]))


@pytest.mark.parametrize("n", [MAX_DRAWS + 1, 10**9, 10**12])
def test_a_huge_sample_is_refused_before_any_memory_is_taken(n):
    with pytest.raises(ValueError, match=r"^`n` = \d+ plants is more than"):
        sample_plants(_result(np.diag([1e-6, 1e-6, 1e-4])), n)


@pytest.mark.parametrize("order", [0, -1, 10**6, 2.5, True])
def test_a_bad_pade_order_is_refused_even_where_it_would_not_be_used(order):
    pytest.importorskip("control")
    no_delay = _result(np.diag([1e-6, 1e-6, 1e-4]), delay=0.0)
    with pytest.raises(ValueError, match="`pade_order` must be a whole number"):
        closed_loop(no_delay, 0, pade_order=order)


# --------------------------------------------------------------------------------------------
# --html targets


@pytest.mark.parametrize("target", ["", ".", ".."])
def test_an_html_target_that_names_a_folder_is_one_line_naming_it(target, tmp_path,
                                                                  sample_set_path, monkeypatch):
    from typer.testing import CliRunner

    from phoid.cli import app

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["identify", str(sample_set_path), "--html", target])
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert "\n" not in line and "names a folder, not a file" in line, r.output
    assert "Traceback" not in r.output and list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# [units] that make a tracking set's r and x disagree


def test_a_tracking_set_whose_r_and_x_differ_by_a_units_factor_is_warned(tmp_path):
    from test_json_schema import _tracking_set

    folder = _tracking_set(tmp_path / "set")
    clean = phoid.identify(phoid.read_experiment(folder))
    assert not any("same units" in w for w in clean.warnings), clean.warnings
    # the same set, its r (written in m) declared in mm: read as 1/1000 of the real reference
    manifest = folder / "experiment.toml"
    manifest.write_text(manifest.read_text() + '\n[units]\nr = "mm"\n')
    exp = phoid.read_experiment(folder)
    res = phoid.identify(exp)
    note = [w for w in res.warnings if "same units" in w]
    assert len(note) == 1 and 'is x in mm? (then give [units] x = "mm")' in note[0], note
    # the ratio it quotes is that of the columns as read, computed here from their definition
    run = exp.runs[0]
    ratio = np.std(run.r) / np.std(run.x)
    assert f"varies {ratio:.3g} times" in note[0]


def test_a_series_beside_a_table_must_share_its_index():
    # a Series is read by position: one indexed otherwise would put its samples at the wrong
    # times without a word; the same Series on the table's own index is accepted as it is
    pd = pytest.importorskip("pandas")
    t = np.arange(5) * 0.1
    rec = pd.Series(np.zeros(5), index=t)
    u = pd.Series(np.arange(5.0), index=t[::-1])
    with pytest.raises(ValueError, match=r"^run_from_arrays: `u` is a Series whose index is not"):
        phoid.run_from_arrays(rec, u=u)
    assert phoid.run_from_arrays(rec, u=u.sort_index()).u.tolist() == [4.0, 3.0, 2.0, 1.0, 0.0]
    with pytest.raises(ValueError, match=r"^u\[0\] is a Series whose index is not that of data"):
        phoid.identify_data([rec], [1.0], [0.5], 0.0, u=[u])


def test_the_closed_loop_of_an_unstable_set_aside_run_says_so():
    pytest.importorskip("control")
    # P = 40 N/m, D = 0.5 N s/m with a 0.1 s delay on m, c, k = 2, 1, 64: the certified
    # rightmost root (phoid.dynamics, independent of the export) is in the right half-plane
    from phoid.dynamics import rightmost_roots

    res = _result(np.diag([1e-6, 1e-6, 1e-4]), delay=0.1)
    res.runs = (SimpleNamespace(file="r1", P=40.0, D=0.5, added_mass=0.0, used=False),)
    root = complex(rightmost_roots(2.0, 1.0, 64.0, 40.0, 0.5, 0.1, count=2)[0])
    assert root.real > 0
    notes = closed_loop(res, 0).phoid.notes
    assert any("set aside" in n for n in notes) and any("unstable" in n for n in notes), notes
    res.runs = (SimpleNamespace(file="r1", P=10.0, D=2.0, added_mass=0.0, used=True),)
    notes = closed_loop(res, 0).phoid.notes
    assert not any("set aside" in n or "unstable" in n for n in notes), notes


def test_the_notebook_view_of_nan_and_hostile_text_is_escaped_and_says_undefined():
    from phoid.reports.html import result_html, short_repr

    hostile = '<script>alert("x")</script>'
    res = SimpleNamespace(
        summary=lambda: {"method": "pho", "m": {"value": None, "stderr": 0.1, "unit": "kg"},
                         "c": {"value": float("nan"), "stderr": 0.1, "unit": "N s/m"},
                         "k": {"value": 64.0, "stderr": float("nan"), "unit": "N/m"},
                         "warnings": [hostile]})
    page = result_html(res, figure=False)
    assert hostile not in page and "&lt;script&gt;" in page
    # no relative stderr from a value or stderr that is not a finite number
    assert "nan %" not in page and "inf %" not in page
    assert short_repr(res).startswith("SimpleNamespace(m = undefined kg, c = undefined N s/m")


def test_one_figure_is_one_figure(tmp_path):
    # a one-run tracking set draws one figure (tracking_<run>.png): the count and its noun agree
    from test_json_schema import _tracking_set
    from typer.testing import CliRunner

    from phoid.cli import app

    folder = _tracking_set(tmp_path / "set")
    r = CliRunner().invoke(app, ["identify", str(folder), "--plots", str(tmp_path / "p")])
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "p").iterdir())) == 1
    assert f"1 figure written to {tmp_path / 'p'}" in r.output


@pytest.mark.parametrize("html", ["figs", "figs/lines.png"])
def test_an_html_report_that_would_overwrite_the_figures_is_refused_before_the_work(
        html, tmp_path, sample_set_path, monkeypatch):
    from typer.testing import CliRunner

    from phoid.cli import app

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["identify", str(sample_set_path), "--plots", "figs",
                                 "--html", html, "--overwrite"])
    assert r.exit_code == 2, r.output
    assert f"{html}: would collide with the figures written to figs" in r.output
    assert "\n" not in r.output.strip() and list(tmp_path.iterdir()) == []


def test_a_design_report_on_its_own_plot_file_is_refused(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from phoid.cli import app

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["design", "--m", "2", "--c", "1", "--k", "64", "--delay",
                                 "0.1", "--runs", "3", "--plot", "d.png", "--html", "d.png"])
    assert r.exit_code == 2, r.output
    assert "d.png: would collide with the figures written to d.png" in r.output
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("label", ["u", "F", "r", "w", "t"])
def test_a_series_named_after_another_column_is_not_taken_for_x(label):
    pd = pytest.importorskip("pandas")
    s = pd.Series(np.zeros(4), index=np.arange(4) * 0.1, name=label)
    with pytest.raises(ValueError, match=rf"^t: a Series is read as x .* named '{label}'"):
        phoid.run_from_arrays(s)
    assert phoid.run_from_arrays(s.rename("x")).x.tolist() == [0.0] * 4


def test_a_wrong_units_entry_for_u_is_named_as_a_possible_cause(tmp_path):
    # a simulated set (u in N, as simulate writes it) whose manifest claims u in kN: u reads
    # 1000 times the force -(P x + D x') that the gains imply, which the check reports
    from typer.testing import CliRunner

    from phoid.cli import app

    folder = tmp_path / "set"
    r = CliRunner().invoke(app, ["simulate", str(folder), "--P", "2:20:4", "--D", "1:4:4",
                                 "--duration", "6", "--noise", "1e-5", "--seed", "1"])
    assert r.exit_code == 0, r.output
    manifest = folder / "experiment.toml"
    manifest.write_text(manifest.read_text() + '\n[units]\nu = "kN"\n')
    res = phoid.identify(phoid.read_experiment(folder))
    note = [w for w in res.warnings if "contradicts the given gains" in w]
    assert len(note) == 1, res.warnings
    assert "a [units] entry given for them is the wrong one" in note[0], note


def test_a_tracking_result_without_a_covariance_says_so_in_its_export():
    fit = SimpleNamespace(free=("M", "Fv"), covariance=np.full((2, 2), np.nan))
    res = SimpleNamespace(estimates={"m": Estimate(2.0, None, "kg"),
                                     "c": Estimate(1.0, None, "N s/m"),
                                     "k": Estimate(0.0, 0.0, "N/m")}, fit=fit)
    plant = linear_plant(res)
    assert any("covariance of (m, c, k) is unknown" in n for n in plant.notes), plant.notes
    # the fixed k keeps its zero variance; m and c (IDIM's M and Fv) carry the unknown
    assert plant.cov[2, 2] == 0.0 and np.isnan(plant.cov[0, 0]) and np.isnan(plant.cov[1, 1])
