"""Hostile input to `phoid identify` and `phoid design --check` (issue 15, Part 2, items 1, 2,
5 and 8 on the identification side), through the real command line.

Every case is a realistic mistake made on a small simulated set (`phoid simulate`: m = 2 kg,
c = 1 N s/m, k = 64 N/m, loop delay 20 ms, six runs, 500 Hz, 8 s, the force u recorded). The
contract checked for each: exit status 0 or 2, never 1 (an internal error, or a warning that
pytest's warnings-as-errors turns into one: no numpy RuntimeWarning leaks); an error is exactly
one line on stderr and names what is probably wrong; a result that is returned carries the
expected warning; every --json output parses with a strict parser (no NaN, no Infinity).
"""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from phoid.cli import app

runner = CliRunner()
SIGN = "u = -(P x(t - delay) + D x'(t - delay))"  # the convention the messages state


def _strict(text: str):
    """json.loads that refuses NaN and ±Infinity (not JSON, rejected by strict parsers)."""

    def refuse(name):
        raise ValueError(f"{name} in JSON output")

    return json.loads(text, parse_constant=refuse)


def _manifest_edit(folder: Path, fn) -> None:
    p = folder / "experiment.toml"
    p.write_text(fn(p.read_text()))


def _nth_run_field(text: str, run: int, field: str, value: str) -> str:
    """Set `field` of the run-th [[run]] table (1-based) to `value`."""
    parts = text.split("[[run]]")
    parts[run] = re.sub(rf"(?m)^{field} = .*$", f"{field} = {value}", parts[run], count=1)
    return "[[run]]".join(parts)


@pytest.fixture(scope="module")
def sets(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("hostile")
    base = root / "base"
    common = ["--delay", "0.02", "--duration", "8", "--fs", "500", "--noise", "1e-5",
              "--no-gzip", "--seed", "1"]
    r = runner.invoke(app, ["simulate", str(base), "--P", "2:20:6", "--D", "1:4:6", *common])
    assert r.exit_code == 0, r.output
    out = {"base": base}

    def copy(name: str) -> Path:
        shutil.copytree(base, root / name)
        out[name] = root / name
        return root / name

    # every D with the other sign (the usual sign-convention mistake)
    _manifest_edit(copy("neg_d"), lambda s: re.sub(r"(?m)^D = ", "D = -", s))
    # every P and D with the other sign
    _manifest_edit(copy("neg_pd"),
                   lambda s: re.sub(r"(?m)^D = ", "D = -", re.sub(r"(?m)^P = ", "P = -", s)))
    # the wrong signs and no delay given (the delay is then estimated)
    _manifest_edit(copy("neg_d_nodelay"),
                   lambda s: re.sub(r"(?m)^D = ", "D = -", s.replace("[loop]\ndelay = 0.02\n",
                                                                      "")))
    # one run's t in ms
    f = copy("t_ms") / "run02.csv"
    with f.open(newline="") as fh:
        rows = list(csv.reader(fh))
    with f.open("w", newline="") as fh:
        csv.writer(fh).writerows([rows[0]] + [[repr(float(r[0]) * 1000), *r[1:]]
                                              for r in rows[1:]])
    # one run's x scaled absurdly, and one run's x in mm
    for name, scale in (("x_1e300", 1e300), ("x_mm", 1e3)):
        f = copy(name) / "run01.csv"
        with f.open(newline="") as fh:
            rows = list(csv.reader(fh))
        with f.open("w", newline="") as fh:
            csv.writer(fh).writerows([rows[0]] + [[r[0], repr(float(r[1]) * scale), r[2]]
                                                  for r in rows[1:]])
    # one run's P absurd
    _manifest_edit(copy("p_1e20"), lambda s: _nth_run_field(s, 3, "P", "1e20"))
    # one run's added mass absurd
    _manifest_edit(copy("added_1e300"), lambda s: _nth_run_field(
        s, 2, "D", "1.6\nadded_mass = 1e300"))
    # every gain doubled (u, recorded, says they are not)
    _manifest_edit(copy("gains_x2"), lambda s: re.sub(
        r"(?m)^(P|D) = (.*)$", lambda m: f"{m.group(1)} = {2 * float(m.group(2))!r}", s))
    # a digital loop whose sample time is absurdly short
    dig = root / "digital"
    r = runner.invoke(app, ["simulate", str(dig), "--P", "2:20:6", "--D", "1:4:6",
                            "--sample-time", "0.002", "--delay-samples", "1", *common[2:]])
    assert r.exit_code == 0, r.output
    _manifest_edit(dig, lambda s: re.sub(r"(?m)^sample_time = .*$", "sample_time = 1e-300", s))
    out["digital_1e-300"] = dig
    # two runs only (OLS: no residual, so no stderr)
    two = root / "two"
    r = runner.invoke(app, ["simulate", str(two), "--P", "2,10", "--D", "1,3", *common])
    assert r.exit_code == 0, r.output
    out["two"] = two
    # a low sample rate: 12 Hz, the release between two samples (hold 0.2 s = 2.4 samples)
    low = root / "fs12"
    r = runner.invoke(app, ["simulate", str(low), "--P", "2:20:6", "--D", "1:4:6", "--fs", "12",
                            "--hold", "0.2", "--delay", "0.02", "--duration", "20",
                            "--noise", "1e-5", "--no-gzip", "--seed", "1"])
    assert r.exit_code == 0, r.output
    out["fs12"] = low
    return out


# (name, set, extra arguments, expected exit status, words the message or a warning must hold)
CASES = [
    # item 1: realistic mistakes that crashed with "The truth value of an array …"
    ("delay 2.5x too long", "base", ["--delay", "0.05"], 0, ["delay 0.05 s", "too long"]),
    ("every D negated", "neg_d", [], 2, ["other sign", "D negated", SIGN]),
    ("every P and D negated", "neg_pd", [], 2, ["other sign", "P and D negated", SIGN]),
    ("D negated, delay estimated", "neg_d_nodelay", [], 2, ["D negated", SIGN]),
    ("one run's t in ms", "t_ms", [], 2, ["run 2", "t must be in seconds", "ms"]),
    ("P = 1e20 in one run", "p_1e20", [], 2, ["run 3", "P = 1e+20"]),
    # item 2: other crashes
    ("added_mass = 1e300", "added_1e300", [], 2, ["run 2", "added_mass = 1e+300"]),
    ("sample_time = 1e-300", "digital_1e-300", [], 2, ["sample_time = 1e-300", "seconds"]),
    ("negative delay", "base", ["--delay", "-1"], 2, ["--delay", "≥ 0"]),
    ("delay longer than the records", "base", ["--delay", "5"], 2, ["too long", "seconds"]),
    ("delay far below the sample step", "base", ["--delay", "1e-300"], 2,
     ["shorter than the records' sample step", "seconds"]),
    ("one run's x times 1e300", "x_1e300", [], 0, ["run 1", "set aside", "is it in m?"]),
    # item 5: silently wrong numbers
    ("one run's x in mm, u recorded", "x_mm", [], 0, ["run 1", "u contradicts",
                                                     "units of x (m)"]),
    ("gains doubled, u recorded", "gains_x2", [], 0, ["u contradicts the given gains"]),
    ("release between samples at 12 Hz", "fs12", [], 0, ["sampled coarsely"]),
    ("two runs, OLS", "two", ["--estimator", "ols"], 0, ["standard errors", "null in --json"]),
    # item 8: CLI words
    ("--no-compensation with gls", "base", ["--no-compensation"], 2, ["--no-compensation"]),
]


@pytest.mark.parametrize(("name", "which", "args", "status", "words"), CASES,
                         ids=[c[0] for c in CASES])
def test_identify_hostile(sets, name, which, args, status, words):
    r = runner.invoke(app, ["identify", str(sets[which]), "--json", *args])
    assert r.exit_code == status, (name, r.exit_code, r.output, r.exception)
    assert "Traceback" not in r.output and "np.float64" not in r.output
    assert "compensate=" not in r.output and "`skip`" not in r.output  # API words
    if status == 2:
        err = r.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("phoid: error:"), r.stderr
        text = err[0]
        assert r.stdout == ""
    else:
        text = "\n".join(_strict(r.stdout)["warnings"])
    for w in words:
        assert w in text, (name, w, text)


def test_two_run_ols_stderr_is_null(sets):
    """A stderr the data cannot give is null in --json (not NaN), and a warning says why."""
    r = runner.invoke(app, ["identify", str(sets["two"]), "--json", "--estimator", "ols"])
    assert r.exit_code == 0, r.output
    out = _strict(r.stdout)
    assert all(out[q]["stderr"] is None for q in ("m", "c", "k"))
    # the values themselves are still there: two runs determine both lines exactly
    assert out["m"]["value"] == pytest.approx(2.0, rel=1e-3)  # the simulated plant, 1e-5 noise


def test_valid_set_has_no_false_alarm(sets):
    """The diagnostics stay silent on the valid set (right gains, delay, units and u)."""
    r = runner.invoke(app, ["identify", str(sets["base"]), "--json"])
    assert r.exit_code == 0, r.output
    assert _strict(r.stdout)["warnings"] == []


@pytest.mark.parametrize(("which", "args", "status", "words"), [
    ("neg_d", [], 2, ["D negated", SIGN]),
    # with the prior given nothing is identified: the gains are checked as given, are unsafe
    # (status 1, the documented answer of --check to an unsafe run), and the sign is named
    ("neg_d", ["--m", "2", "--c", "1", "--k", "64"], 1, ["every run's D is negative", SIGN]),
    # the identification's warnings are carried through (its chi2/dof ~1e5 no longer silent)
    ("base", ["--delay", "0.05"], 0, ["identification of the set", "runs disagree",
                                       "too long"]),
    # an absurd prior: refused before the loop computations, or their failure said in words
    ("base", ["--m", "1e300"], 2, ["`m` = 1e+300 kg", "is it in kg?"]),
], ids=["wrong sign", "wrong sign, prior given", "delay too long", "m = 1e300"])
def test_design_check_hostile(sets, which, args, status, words):
    r = runner.invoke(app, ["design", "--check", str(sets[which]), "--json", *args])
    # design --check exits 1 by design when a run is unsafe on the prior (documented, with the
    # full result on stdout); anything else is 0 (result) or 2 (one-line error)
    assert r.exit_code == status, (r.exit_code, r.output, r.exception)
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    if status == 2:
        err = r.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("phoid: error:"), r.stderr
        text = err[0]
    else:
        text = "\n".join(_strict(r.stdout)["warnings"])
    for w in words:
        assert w in text, (w, text)
