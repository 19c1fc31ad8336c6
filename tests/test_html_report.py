"""The results where users look: the short ``repr``, the notebook's ``_repr_html_`` and the
single-file HTML report (``phoid identify/design --html``), the report checked in a real
headless Chromium.

Expected values come from each result's own ``summary()`` (the JSON of ``--json``, pinned by
the methods' tests), computed here by the public API on the same sets; the page must show those
numbers, rounded as :func:`phoid.reports.format_estimate` rounds (the stderr to two significant
digits, the value to the same decimal place). The sets: examples/paper-sample (pho, in the
repository) and small sets simulated here (forced, free, friction, tracking).

The browser tests need selenium, /usr/bin/chromium and /usr/bin/chromedriver; they are skipped,
with the reason, where any is missing (CI installs the browser when it can: .ci/run).
"""

from __future__ import annotations

import dataclasses
import html
import json
import os
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid
import phoid.io
from phoid.cli import app
from phoid.dynamics.controller import SampledController
from phoid.dynamics.plant import Plant
from phoid.reports.html import column_label, report_html
from phoid.reports.text import format_estimate
from phoid.simulation.tracking import simulate_tracking

runner = CliRunner()
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
HOSTILE = '<script>alert("x")</script>'


def cli(*args, code=0):
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == code, r.output
    return r


# ------------------------------------------------------------------------------------------
# the sets and their results
@pytest.fixture(scope="module")
def sets(tmp_path_factory, sample_set_path):
    """Folder of each method's set: pho (the example), forced, free, friction, tracking."""
    root = tmp_path_factory.mktemp("sets")
    cli("simulate", root / "forced", "--method", "forced", "--omega", "2:14:4", "--duration",
        "20", "--fs", "250", "--noise", "1e-5", "--seed", "12")
    cli("simulate", root / "free", "--method", "free", "--m", "1", "--c", "2", "--k", "100",
        "--duration", "6", "--noise", "1e-5", "--seed", "3")
    cli("simulate", root / "friction", "--fc", "0.05", "--P", "0:20:4", "--D", "1:4:4",
        "--duration", "6", "--noise", "1e-5", "--seed", "2")
    # a tracking set as in tests/test_tracking_cli.py: a small axis under a 1 kHz PD loop
    # following a two-sine reference, u recorded
    ctrl = SampledController(sample_time=1e-3, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0, delay=0.4e-3)
    t = 1e-3 * np.arange(3000)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = simulate_tracking(Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3, x_init=[0.0])
    x = sim.x + 1e-6 * np.random.default_rng(0).standard_normal(t.size)
    run = phoid.io.run_from_arrays(t, x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    phoid.io.write_experiment(root / "tracking", [run], method="tracking", fixed={"k": 0.0},
                              loop={"sample_time": 1e-3, "velocity": "central-difference",
                                    "saturation": 200.0, "delay": 0.4e-3})
    return {"pho": sample_set_path, **{k: root / k for k in
                                        ("forced", "free", "friction", "tracking")}}


@pytest.fixture(scope="module")
def results(sets):
    """Every result and design class, made by the public API."""
    from phoid.methods import friction_evidence, identify_friction_set, replay_set

    read = phoid.io.read_experiment
    out = {"pho": phoid.identify(read(sets["pho"])),
           "forced": phoid.identify(read(sets["forced"])),
           "free": phoid.identify(read(sets["free"]))}
    fexp = read(sets["friction"])
    out["friction"] = identify_friction_set(fexp)
    out["friction-evidence"] = friction_evidence(
        [(r.t, r.x) for r in fexp.runs], np.array([r.P for r in fexp.runs]),
        np.array([r.D for r in fexp.runs]), fexp.delay)
    texp = read(sets["tracking"])
    out["tracking"] = phoid.identify(texp, estimator="idim")
    out["idim"] = out["tracking"].fit
    out["output-error"] = phoid.identify(texp, estimator="output-error").fit
    out["validation"] = out["tracking"].validation
    out["replay"] = replay_set(texp, {"m": 2.0, "c": 15.0, "k": 0.0, "fc": 1.5,
                                      "offset": -0.3, "delay": 0.4e-3})
    out["design"] = phoid.design(2.0, 1.0, 64.0, delay=0.1, runs=4)
    out["experiment"] = read(sets["pho"])
    return out


def _estimates(summary: dict) -> dict:
    """The estimate-shaped entries of a summary ({value, stderr, unit}), as the docs define."""
    found = {k: v for k, v in summary.items() if isinstance(v, dict) and "unit" in v
             and "value" in v}
    for group in ("parameters", "predicted"):
        found.update({k: v for k, v in (summary.get(group) or {}).items()
                      if isinstance(v, dict) and "value" in v})
    return found


RESULT_KEYS = ["pho", "forced", "free", "friction", "friction-evidence", "tracking", "idim",
               "output-error", "validation", "replay", "design"]


# ------------------------------------------------------------------------------------------
# repr and _repr_html_, no browser
@pytest.mark.parametrize("key", [*RESULT_KEYS, "experiment"])
def test_repr_is_one_short_line(results, key):
    text = repr(results[key])
    # before, a PHO Identification's repr was 19 kB of dataclass text; one line of at most a
    # few estimates fits 400 characters (the tracking fit's six estimates are the longest)
    assert "\n" not in text and len(text) < 400, text
    assert text.startswith(type(results[key]).__name__), text


@pytest.mark.parametrize("key", ["pho", "forced", "friction", "tracking", "design"])
def test_repr_shows_the_main_estimates_and_counts(results, key):
    res = results[key]
    summary = res.summary()
    ests = _estimates(summary)
    text = repr(res)
    for name in ("m", "c", "k"):
        e = ests[name]
        assert f"{name} = {format_estimate(e['value'], e['stderr'])} {e['unit']}" in text, text
    n = len(summary.get("runs") or summary.get("validation"))
    nw = len(summary["warnings"])
    assert f"{n} run" in text and f"{nw} warning" in text, text


class _Checker(HTMLParser):
    """Tag balance of an HTML fragment (void elements excepted) and its text."""

    VOID = frozenset({"br", "img", "meta", "hr", "input", "link", "col", "wbr"})

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack, self.errors, self.text, self.tags = [], [], [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
        else:
            self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def _parse(fragment: str) -> _Checker:
    p = _Checker()
    p.feed(fragment)
    p.close()
    assert not p.errors and not p.stack, (p.errors, p.stack)
    return p


@pytest.mark.parametrize("key", RESULT_KEYS)
def test_repr_html_is_balanced_and_shows_every_estimate(results, key):
    res = results[key]
    fragment = res._repr_html_()
    page = _parse(fragment)
    text = " ".join(page.text)
    ests = _estimates(res.summary()) if hasattr(res, "summary") else {
        n: {"value": getattr(res, n).value, "stderr": getattr(res, n).stderr}
        for n in ("m", "c", "k", "fc")}
    assert ests or key in ("validation", "replay")  # those two hold relative errors, no estimate
    for name, e in ests.items():
        if e["value"] is not None:
            assert format_estimate(e["value"], e["stderr"]) in text, (name, e)
    warnings = getattr(res, "warnings", ())
    assert (f"{len(warnings)} warning" in text) if warnings else ("No warnings." in text)


def test_repr_html_has_an_inline_figure_where_it_summarises(results):
    for key in ("pho", "forced", "design"):  # eq. (35) lines, eq. (20) lines, root locus
        tags = _parse(results[key]._repr_html_()).tags
        assert tags.count("img") == 1, key


class _Extended:
    """A result whose summary() has the optional keys the display reads (docs/format.md):
    statistics, covariance, correlation, per-run residual_noise_ratio; numbers made up."""

    warnings = ()

    def summary(self):
        return {
            "method": "pho",
            "m": {"value": 2.0, "stderr": 0.001, "unit": "kg"},
            "statistics": {"chi2": 31.5, "dof": 30, "chi2_dof": 1.05},
            "covariance": {"params": ["m", "k"], "units": ["kg", "N/m"],
                           "matrix": [[1e-6, 2e-6], [2e-6, 9e-4]]},
            "correlation": {"params": ["m", "k"], "matrix": [[1.0, 0.0667], [0.0667, 1.0]]},
            "runs": [{"file": "a.csv", "sigma": 0.5, "sigma_stderr": 0.01,
                      "residual_noise_ratio": 1.02, "used": True, "warnings": []},
                     {"file": "b.csv", "sigma": 0.7, "sigma_stderr": 0.02,
                      "residual_noise_ratio": 3.5, "used": False, "warnings": ["odd"]}],
            "warnings": [],
        }


def test_optional_summary_keys_are_shown():
    from phoid.reports.html import result_html

    fragment = result_html(_Extended())
    text = " ".join(_parse(fragment).text)
    for caption in ("Fit statistics", "Covariance", "Correlation"):
        assert caption in text
    # headed with words, not the JSON's keys (issue 30)
    assert "χ²/dof" in text and "chi2_dof" not in text and "1.05" in text
    assert "m (kg)" in text and "k (N/m)" in text and "0.0667" in text
    assert "resid/noise" in text and "residual_noise_ratio" not in text and "3.5" in text
    assert "0.500 ± 0.01" in text  # sigma ± sigma_stderr in one cell (format_estimate)
    assert fragment.count('class="phoid-aside"') == 1  # the run set aside is marked
    assert "odd" in text


@pytest.mark.parametrize("key", ["pho", "tracking", "design", "experiment"])
def test_ipython_displays_the_html_and_the_short_repr(results, key):
    formatters = pytest.importorskip("IPython.core.formatters",
                                     reason="IPython (ipykernel's) is not installed")
    data, _meta = formatters.DisplayFormatter().format(results[key])
    assert data["text/plain"] == repr(results[key])
    assert data["text/html"] == results[key]._repr_html_()


def test_experiment_set_repr_html_lists_the_runs(results):
    exp = results["experiment"]
    page = _parse(exp._repr_html_())
    text = " ".join(page.text)
    assert all(r.file in text for r in exp.runs)
    assert f"Runs ({len(exp.runs)})" in text


def test_hostile_names_are_escaped(results):
    res = results["pho"]
    runs = (dataclasses.replace(res.runs[0], file=HOSTILE, warnings=(HOSTILE,)), *res.runs[1:])
    bad = dataclasses.replace(res, runs=runs, warnings=(f"run 1: {HOSTILE}",), source=HOSTILE)
    fragment = bad._repr_html_()
    assert "<script" not in fragment
    assert html.escape(HOSTILE) in fragment
    assert HOSTILE in " ".join(_parse(fragment).text)  # shown as text, as written
    assert "<script" not in repr(bad)  # the repr shows no run names at all
    run = phoid.io.run_from_arrays(np.arange(5.0), np.zeros(5), P=1.0, D=1.0, file=HOSTILE)
    exp = phoid.io.ExperimentSet(path=Path("x") / "experiment.toml", runs=(run,),
                                 title=HOSTILE)
    assert "<script" not in exp._repr_html_()
    assert HOSTILE in " ".join(_parse(exp._repr_html_()).text)


def test_report_page_without_a_browser(results, tmp_path, sets):
    from phoid.reports.html import write_report

    path = write_report(results["free"], tmp_path / "r" / "free.html",
                        experiment=phoid.io.read_experiment(sets["free"]))
    page = path.read_text(encoding="utf-8")
    p = _parse(page.split("<!DOCTYPE html>\n", 1)[1])
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", page)  # self-contained
    # the manifest's SHA-256, computed here independently of the report
    import hashlib

    manifest = sets["free"] / "experiment.toml"
    assert hashlib.sha256(manifest.read_bytes()).hexdigest() in page
    text = " ".join(p.text)
    for key in ("phoid", "python", "numpy", "scipy"):
        assert key in text
    assert f"{np.__version__}" in text
    # the embedded figures are the files plot() writes, byte for byte (Agg renders the same
    # figure to the same PNG)
    import base64

    embedded = [base64.b64decode(s) for s in re.findall(r'src="data:image/png;base64,([^"]+)"',
                                                       page)]
    written = [f.read_bytes() for f in results["free"].plot(tmp_path / "plots")]
    assert embedded == written and len(written) == len(results["free"].runs)


def test_plots_and_html_together_draw_each_figure_once(sets, tmp_path, monkeypatch):
    # `identify --plots DIR --html FILE` embeds the PNG files it has just written into DIR:
    # drawing them again for the page would double the command's time (issue 30, item 5).
    # The drawing for the page is made to fail, so the command passes only if it is not called
    import base64

    import phoid.reports.html as html_report

    def drawn_again(result):
        raise AssertionError("the figures were drawn a second time for the HTML page")

    monkeypatch.setattr(html_report, "result_figures", drawn_again)
    out, page_path = tmp_path / "plots", tmp_path / "r.html"
    cli("identify", sets["free"], "--plots", out, "--html", page_path)
    page = page_path.read_text(encoding="utf-8")
    embedded = sorted(base64.b64decode(s) for s in
                      re.findall(r'src="data:image/png;base64,([^"]+)"', page))
    written = sorted(f.read_bytes() for f in out.glob("*.png"))
    assert written and embedded == written
    # --html alone still draws them (the page is not left without figures)
    monkeypatch.undo()
    cli("identify", sets["free"], "--html", tmp_path / "alone.html")
    alone = (tmp_path / "alone.html").read_text(encoding="utf-8")
    assert sorted(base64.b64decode(s) for s in
                  re.findall(r'src="data:image/png;base64,([^"]+)"', alone)) == written


def test_figure_files_embedded_are_regular_files_never_links(results, tmp_path):
    # report_html(figures=[paths]) reads files a command has just written: a link (to a file
    # outside the folder) or a FIFO put in their place is refused, not followed or waited on
    import os

    from phoid.reports.html import report_html

    secret = tmp_path / "secret.png"
    secret.write_bytes(b"not a figure of this result")
    (tmp_path / "plots").mkdir()
    link, fifo = tmp_path / "plots" / "run01.png", tmp_path / "plots" / "run02.png"
    link.symlink_to(secret)
    os.mkfifo(fifo)
    for bad in (link, fifo):
        with pytest.raises(OSError, match="cannot be embedded"):
            report_html(results["free"], figures=[bad])


@pytest.mark.parametrize("key", ["pho", "free", "forced", "friction", "tracking"])
def test_the_page_reads_in_the_notation_not_in_json(results, key):
    # issue 30 item 4: the page's tables in the text's notation (σ, k/m, 1/s²), the model checks
    # as a table (check, result, statistic, limit, detail) — not the summary's JSON (its keys,
    # its null); the JSON itself stays in its own section, below
    page = report_html(results[key], figures=False)
    body = page.split("<h2>Summary (JSON)")[0]
    text = html.unescape(re.sub(r"<[^>]+>", " ", body))
    for json_only in (r"\^2\b", r"\bsigma\b", r"\bk_over_m\b", r"\bc_over_m\b", r"\bnull\b",
                      r"\bchi2", r'"statistic"', r"\bNone\b"):
        assert not re.search(json_only, text), (key, json_only, re.findall(
            r".{0,40}" + json_only + r".{0,20}", text)[:2])
    ad = results[key].summary().get("adequacy")
    if isinstance(ad, dict) and ad.get("checks"):
        assert "Adequacy: the stderr reported are" in text, key
        for c in ad["checks"]:
            state = "n/a" if c["passed"] is None else "pass" if c["passed"] else "FAIL"
            assert re.search(rf"{re.escape(column_label(c['name']))}\s+{state}\b", text), (
                key, c["name"])


def test_design_html_without_a_browser(tmp_path):
    path = tmp_path / "design.html"
    cli("design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.1", "--runs", "3",
        "--html", path)
    page = path.read_text(encoding="utf-8")
    text = " ".join(_parse(page.split("<!DOCTYPE html>\n", 1)[1]).text)
    predicted = phoid.design(2.0, 1.0, 64.0, delay=0.1, runs=3).summary()["predicted"]
    for e in predicted.values():
        assert format_estimate(e["value"], e["stderr"]) in text
    assert page.count("<img ") == 1  # the design's one figure (root locus, uncertainties)
    assert "No input files were given." in text


def test_browser_skip_reason_names_what_is_missing(monkeypatch, tmp_path):
    import sys

    try:
        import selenium  # noqa: F401
        has_selenium = True
    except ImportError:
        has_selenium = False
    me = sys.modules[__name__]
    monkeypatch.setattr(me, "CHROMIUM", tmp_path / "no-chromium")
    reason = me._browser_missing()
    assert reason is not None
    # without selenium the reason names selenium first; with it, the missing browser
    assert ("no-chromium" if has_selenium else "selenium") in reason


# ------------------------------------------------------------------------------------------
# --html through the CLI: the _output rules, one-line errors
def _one_line_error(r, *words):
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error:"), r.output
    assert "Traceback" not in r.output
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_html_refuses_to_overwrite_then_replaces_with_overwrite(sets, tmp_path):
    target = tmp_path / "report.html"
    target.write_text("keep me")
    _one_line_error(runner.invoke(app, ["identify", str(sets["free"]), "--html", str(target)]),
                    str(target), "--overwrite")
    assert target.read_text() == "keep me"
    cli("identify", sets["free"], "--html", target, "--overwrite")
    assert target.read_text(encoding="utf-8").startswith("<!DOCTYPE html>")
    _one_line_error(runner.invoke(app, ["design", "--m", "2", "--c", "1", "--k", "64",
                                        "--delay", "0.1", "--runs", "3", "--html",
                                        str(target)]), "--overwrite")


def test_html_refuses_links_and_folders(sets, tmp_path):
    outside = tmp_path / "outside.html"
    outside.write_text("not phoid's")
    link = tmp_path / "out" / "report.html"
    link.parent.mkdir()
    link.symlink_to(outside)
    for extra in ([], ["--overwrite"]):  # a link is refused with or without --overwrite
        _one_line_error(runner.invoke(app, ["identify", str(sets["free"]), "--html",
                                            str(link), *extra]), "symbolic link")
    assert outside.read_text() == "not phoid's"
    dangling = tmp_path / "gone"
    dangling.symlink_to(tmp_path / "nowhere")
    _one_line_error(runner.invoke(app, ["identify", str(sets["free"]), "--html",
                                        str(dangling / "sub" / "r.html")]), "link")
    assert not (tmp_path / "nowhere").exists()
    (tmp_path / "folder.html").mkdir()
    _one_line_error(runner.invoke(app, ["identify", str(sets["free"]), "--html",
                                        str(tmp_path / "folder.html")]), "folder")


# ------------------------------------------------------------------------------------------
# the report in a real browser
def _browser_missing() -> str | None:
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install selenium; the `test` extra has it)"
    for path in (CHROMIUM, CHROMEDRIVER):
        if not path.is_file() or not os.access(path, os.X_OK):
            return (f"{path} is absent: install Debian's chromium and chromium-driver to run "
                    "the browser tests (.ci/run does where it runs as root)")
    return None


@pytest.fixture(scope="module")
def browser():
    reason = _browser_missing()
    if reason:
        pytest.skip(reason)
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                "--window-size=1300,1800"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=opts)
    yield driver
    driver.quit()


# the figures each result's plot() writes (the plot functions' docstrings): a PHO set one per
# used run, the eq. (35) lines and the m-k ellipse; forced one per used run, the eq. (20) lines
# and the ellipse; free and tracking one per run; a design one; the friction fit one per used
# run and the ellipse
def _used(s):
    return sum(1 for r in s["runs"] if r.get("used", True))


CASES = {
    "pho": (["identify", "{pho}"], lambda s: _used(s) + 2),
    "forced": (["identify", "{forced}"], lambda s: _used(s) + 2),
    "free": (["identify", "{free}"], lambda s: len(s["runs"])),
    "friction": (["identify", "{friction}", "--friction"], lambda s: _used(s) + 1),
    "tracking": (["identify", "{tracking}", "--estimator", "idim"],
                 lambda s: len(s["validation"])),
    "design": (["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.1", "--runs", "4"],
               lambda s: 1),
}
NUMBER = r"[-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?"


@pytest.mark.parametrize("key", list(CASES))
def test_report_in_a_browser(key, browser, sets, results, tmp_path, artefact):
    args, figures = CASES[key]
    path = tmp_path / f"{key}.html"
    out = cli(*(a.format(**sets) for a in args), "--html", path, "--json")
    json.loads(out.stdout)  # standard output stays one JSON object ("report written" on stderr)
    summary = results[key].summary()
    browser.get(path.resolve().as_uri())
    severe = [e for e in browser.get_log("browser") if e.get("level") == "SEVERE"]
    assert not severe, severe
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.alt])")
    assert len(images) == figures(summary), images
    assert all(done and width > 0 for done, width, _ in images), images
    # and every image decodes whole (a truncated PNG still reports its header's width)
    decoded = browser.execute_async_script("""
        const done = arguments[arguments.length - 1];
        Promise.all(Array.from(document.images).map(
            i => i.decode().then(() => true, () => false))).then(done);""")
    assert decoded == [True] * len(images), decoded
    # nothing was fetched from anywhere: every resource is the page itself or a data: URL
    fetched = browser.execute_script(
        "return performance.getEntriesByType('resource').map(e => e.name)")
    assert all(n.startswith("data:") for n in fetched), fetched
    assert browser.execute_script("return document.scripts.length") == 0
    # the estimates table, read back and compared with summary() to its rounding
    rows = browser.execute_script("""
        const t = Array.from(document.querySelectorAll('table')).find(
            t => t.caption && t.caption.textContent === 'Estimates');
        return Array.from(t.rows).slice(1).map(r => Array.from(r.cells).map(
            c => c.textContent));""")
    # each estimate under its words (ω₀ for omega0, as the text report writes it)
    shown = {r[0]: r[1] for r in rows}
    ests = {column_label(k): e for k, e in _estimates(summary).items()}
    assert set(ests) <= set(shown), (set(ests), set(shown))
    for name, e in ests.items():
        if e["value"] is None:
            continue
        m = re.fullmatch(rf"({NUMBER})(?: ± ({NUMBER}))?", shown[name])
        assert m, shown[name]
        value, se = float(m.group(1)), m.group(2)
        if se is None:  # no stderr: 6 significant digits (format_estimate)
            assert value == pytest.approx(e["value"], rel=5e-6)
            continue
        # the stderr to two significant digits (≤ 5 % off), the value to the stderr's second
        # digit (≤ half a unit of that place, ≤ 0.05 stderr)
        assert float(se) == pytest.approx(e["stderr"], rel=0.05), (name, se, e)
        assert abs(value - e["value"]) <= 0.051 * e["stderr"] + 1e-12 * abs(e["value"])
    body = browser.find_element("tag name", "body").text
    for w in summary["warnings"]:
        assert " ".join(w.split())[:60] in " ".join(body.split())
    shot = artefact(f"{key}.png")
    assert browser.save_screenshot(str(shot)) and shot.stat().st_size > 10_000


def test_hostile_report_runs_no_script_in_a_browser(browser, results, tmp_path):
    from phoid.reports.html import write_report

    res = results["free"]
    runs = (dataclasses.replace(res.runs[0], file=HOSTILE),)
    bad = dataclasses.replace(res, runs=runs, warnings=(HOSTILE,), source=HOSTILE)
    path = write_report(bad, tmp_path / "hostile.html")
    browser.get(path.resolve().as_uri())
    assert browser.execute_script("return document.scripts.length") == 0
    assert HOSTILE in browser.find_element("tag name", "body").text
    assert not [e for e in browser.get_log("browser") if e.get("level") == "SEVERE"]


def test_summary_json_in_the_page_matches(results, tmp_path):
    from phoid.reports.html import report_html

    page = report_html(results["forced"], figures=False)
    pre = re.search(r"<pre>(.*?)</pre>", page, re.S).group(1)
    assert json.loads(html.unescape(pre)) == json.loads(json.dumps(results["forced"].summary()))


# the kinds of result whose report has a runs table, a statistics block or a design's tables
WIDE = ["pho", "forced", "free", "friction", "tracking", "design", "replay"]


@pytest.mark.parametrize("key", WIDE)
def test_no_table_overflows_its_box_at_1200_px(key, browser, results, tmp_path):
    # issue 30: the runs table ran past the page at 1200 px; every table must fit the box it
    # is in (no sideways scroll) and the page must not scroll sideways
    path = tmp_path / f"{key}.html"
    path.write_text(report_html(results[key], figures=False), encoding="utf-8")
    size = browser.get_window_size()
    browser.set_window_size(1200, 900)
    try:
        browser.get(path.resolve().as_uri())
        # each table's box (its scroll box) inside the box it is in, and the tables that
        # only fit by scrolling sideways
        page, boxes, scrolled = browser.execute_script("""
            const de = document.documentElement;
            const tables = Array.from(document.querySelectorAll('table'));
            const name = t => t.caption ? t.caption.textContent : '';
            return [[de.scrollWidth, de.clientWidth],
                    tables.filter(t => t.parentElement.getBoundingClientRect().right >
                                       t.parentElement.parentElement.getBoundingClientRect()
                                       .right + 1).map(name),
                    tables.filter(t => t.getBoundingClientRect().width >
                                       t.parentElement.clientWidth + 1).map(name)];""")
    finally:
        browser.set_window_size(size["width"], size["height"])
    assert page[0] <= page[1], page  # the page never scrolls sideways
    assert not boxes, boxes
    # the set's runs table fits without scrolling (it ran to 1256 px on the example set);
    # only a table of many columns (a forced set's 17, a design's long exact gains) may
    # scroll inside its box
    if key in ("pho", "free", "tracking"):
        assert not scrolled, scrolled
    # words, not the JSON's keys, heading every table: its header cells and the first cell
    # of each row (a key-value table's key); the values may quote anything
    page_text = path.read_text(encoding="utf-8")
    heads = re.findall(r"<th[^>]*>(.*?)</th>", page_text)
    heads += re.findall(r"<tr[^>]*><td[^>]*>(.*?)</td>", page_text)
    assert heads
    for key_name in ("c_prime", "k_prime", "chi2_dof", "omega_d", "residual_rms", "p_value",
                     "omega0", "residual_noise_ratio", "x_unit"):
        assert not [h for h in heads if key_name in h], key_name
