"""The one method dispatch (phoid.methods.registry) and the one result base.

* every method of the format has an entry, and every entry's function, result, report and
  schema section exist (the table is not decoration: a misspelt name fails here);
* the same mistake gives the same exception and the same one-line message through
  ``phoid.identify``, ``identify_set`` (``phoid batch``) and the ``phoid identify`` command
  (a real subprocess), the option named in each caller's words;
* the result base's ``adequacy`` slot reaches ``summary()`` and changes nothing else.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import phoid
from phoid.errors import IdentificationError
from phoid.io import METHODS as FORMAT_METHODS
from phoid.io import read_experiment
from phoid.methods.dispatch import identify_set
from phoid.methods.registry import METHODS, OPTIONS, load

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
FORMAT_DOC = (ROOT / "docs" / "format.md").read_text(encoding="utf-8")


def _command(*args: object) -> list[str]:
    """The real ``phoid`` command (the entry point's main) in a fresh interpreter."""
    return [sys.executable, "-c", "from phoid.cli import main; main()", *map(str, args)]


_ENV = dict(os.environ, PYTHONPATH=str(ROOT / "src"))


def _phoid(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run(_command(*args), capture_output=True, text=True, env=_ENV,
                          timeout=120, check=False)


@pytest.fixture(scope="module")
def sets(tmp_path_factory) -> dict[str, Path]:
    """A set of each method: the committed PHO sample, short simulated forced and free sets,
    and a one-run tracking set (the refusals come before any fit, so the data only have to
    be a valid set of their method)."""
    root = tmp_path_factory.mktemp("sets")
    for method, extra in (("forced", ["--omega", "4,8,12"]), ("free", ["--write-mass"])):
        r = _phoid("simulate", root / method, "--method", method, "--duration", "3",
                   "--fs", "200", "--seed", "1", *extra)
        assert r.returncode == 0, r.stderr
    t = 1e-3 * np.arange(400)
    r = 0.01 * np.sin(2 * np.pi * 2.0 * t)
    run = phoid.io.run_from_arrays(t, r.copy(), r=r, u=np.zeros_like(t), P=4000.0, D=60.0,
                                   index=1)
    phoid.io.write_experiment(root / "tracking", [run], method="tracking", fixed={"k": 0.0},
                              loop={"sample_time": 1e-3, "velocity": "central-difference",
                                    "saturation": 200.0, "delay": 0.0})
    return {"pho": SAMPLE, "forced": root / "forced", "free": root / "free",
            "tracking": root / "tracking"}


# ---------------------------------------------------------------------------------------------
# the table


def test_every_method_of_the_format_has_an_entry():
    assert set(METHODS) == set(FORMAT_METHODS)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_each_variant_names_what_exists(method):
    """Its function takes the options it passes (by their keywords) and is documented; its
    result has summary, report and plot; its report is a function of phoid.reports; its
    schema section is a heading of docs/format.md's `phoid identify --json` chapter."""
    output = FORMAT_DOC[FORMAT_DOC.index("## `phoid identify --json`"):]
    output = output[:output.index("\n## ", 4)]
    defaults = [v for v in METHODS[method].variants if v.selected_by is None]
    assert len(defaults) == 1  # one default variant per method
    for v in METHODS[method].variants:
        fn = load(v.function)
        params = inspect.signature(fn).parameters
        keywords = {o.keyword for o in OPTIONS if o.name in v.passes}
        assert keywords <= set(params), (v.function, keywords - set(params))
        result = load(v.result)
        for attr in ("summary", "report", "plot", "warnings"):
            assert hasattr(result, attr) or attr in getattr(result, "__dataclass_fields__", {})
        assert v.report.startswith("phoid.reports.") and callable(load(v.report))
        # a result on the base names its report itself: the two must agree
        assert getattr(result, "REPORT", v.report) == v.report
        assert f"### {v.schema}\n" in output, v.schema
        assert v.selected_by is None or v.selected_by in {o.name for o in OPTIONS}


def test_every_option_applies_somewhere_and_is_a_cli_option():
    from phoid.cli import identify

    cli_options = set(inspect.signature(identify).parameters)
    for o in OPTIONS:
        assert any(m.accepts(o.name) for m in METHODS.values()), o.name
        assert o.name in cli_options and o.flag == "--" + o.name.replace("_", "-")
        assert o.keyword in inspect.signature(phoid.identify).parameters


# ---------------------------------------------------------------------------------------------
# the same mistake, three routes

# (method, command-line options, phoid.identify keywords, identify_set keywords, the option's
# words on the command line → in Python, as docs/architecture.md states them)
MISTAKES = [
    ("pho", ["--mass", "2"], {"mass": 2.0}, {"mass": 2.0}, {"--mass": "`mass`"}),
    ("pho", ["--no-compensation"], {"compensate": False}, {"no_compensation": True},
     {"--no-compensation": "`compensate=False`", "--estimator ols": "`estimator='ols'`"}),
    ("pho", ["--estimator", "idim"], {"estimator": "idim"}, {"estimator": "idim"},
     {"--estimator": "`estimator`"}),
    ("pho", ["--friction", "--estimator", "ols"], {"friction": True, "estimator": "ols"},
     {"friction": True, "estimator": "ols"},
     {"--estimator": "`estimator`", "--friction": "`friction=True`"}),
    ("pho", ["--friction", "--no-compensation", "--estimator", "ols"],
     {"friction": True, "compensate": False, "estimator": "ols"},
     {"friction": True, "no_compensation": True, "estimator": "ols"},
     {"--no-compensation": "`compensate=False`", "--friction": "`friction=True`",
      "--estimator": "`estimator`"}),
    ("free", ["--delay", "0.1"], {"delay": 0.1}, {"delay": 0.1}, {"--delay": "`delay`"}),
    ("forced", ["--mass", "2"], {"mass": 2.0}, {"mass": 2.0}, {"--mass": "`mass`"}),
    ("forced", ["--estimator", "gls"], {"estimator": "gls"}, {"estimator": "gls"},
     {"--estimator": "`estimator`"}),
    ("tracking", ["--mass", "2"], {"mass": 2.0}, {"mass": 2.0}, {"--mass": "`mass`"}),
    ("tracking", ["--estimator", "gls"], {"estimator": "gls"}, {"estimator": "gls"},
     {"--estimator": "`estimator`"}),
    ("tracking", ["--no-compensation"], {"compensate": False}, {"no_compensation": True},
     {"--no-compensation": "`compensate=False`"}),
    ("tracking", ["--friction"], {"friction": True}, {"friction": True},
     {"--friction": "`friction=True`"}),
]
if not METHODS["free"].accepts("friction"):  # until the free-decay friction fit is enabled
    MISTAKES.append(("free", ["--friction"], {"friction": True}, {"friction": True},
                     {"--friction": "`friction=True`"}))


@pytest.fixture(scope="module")
def cli_runs(sets) -> dict[str, tuple[int, str, str]]:
    """``phoid identify SET --json OPTIONS`` of every mistake, as subprocesses started
    together (each is mostly the interpreter's start-up): (status, stdout, stderr) by id."""
    procs = {key: subprocess.Popen(_command("identify", sets[m[0]], "--json", *m[1]),
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env=_ENV)
             for key, m in zip(MISTAKE_IDS, MISTAKES, strict=True)}
    out = {}
    for key, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=120)
        out[key] = (proc.returncode, stdout, stderr)
    return out


MISTAKE_IDS = [f"{m[0]}{''.join(m[1])}" for m in MISTAKES]


@pytest.mark.parametrize(("key", "method", "args", "api", "kwargs", "words"),
                         [(k, *m) for k, m in zip(MISTAKE_IDS, MISTAKES, strict=True)],
                         ids=MISTAKE_IDS)
def test_same_mistake_same_error_on_every_route(sets, cli_runs, key, method, args, api,
                                                kwargs, words):
    exp = read_experiment(sets[method])
    with pytest.raises(IdentificationError) as by_set:
        identify_set(exp, **kwargs)
    with pytest.raises(IdentificationError) as by_api:
        phoid.identify(exp, **api)
    status, stdout, stderr = cli_runs[key]
    assert status == 2 and stdout == "", (status, stdout)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    # the command line prints identify_set's message, word for word
    assert lines[0] == f"phoid: error: {by_set.value}"
    text = str(by_set.value)
    # one line naming the set, its method and (in the command line's words) the option
    assert "\n" not in text and text.startswith(str(exp.path))
    assert f"{method} sets" in text
    assert any(flag in text for flag in words), text
    assert "compensate=" not in text  # no Python words on the command line's route
    # Python's message: the same words with each option named by its keyword
    expected = text
    for flag in sorted(words, key=len, reverse=True):
        expected = expected.replace(flag, words[flag])
    assert str(by_api.value) == expected


def test_batch_rows_carry_the_same_message(sets):
    """A batch's error row (the task identify_job, run in this process) holds the message of
    identify_set for the same set and options."""
    from phoid.batch.engine import identify_job

    exp = read_experiment(sets["free"])
    with pytest.raises(IdentificationError) as info:
        identify_set(exp, delay=0.1)
    options = {"estimator": None, "delay": 0.1, "no_compensation": False, "mass": None,
               "friction": False}
    row = identify_job((str(sets["free"]), "", {}, options))
    assert row["status"] == "error" and row["error"] == str(info.value)


@pytest.mark.parametrize(("kw", "named"), [({"delay": "0.1"}, "`delay`"),
                                            ({"mass": [2.0]}, "`mass`"),
                                            ({"friction": "yes"}, "`friction`"),
                                            ({"compensate": "no"}, "`compensate`"),
                                            ({"estimator": 3}, "`estimator`")])
def test_a_value_of_the_wrong_type_is_named(sets, kw, named):
    exp = read_experiment(sets["pho"])
    with pytest.raises(IdentificationError) as info:
        phoid.identify(exp, **kw)
    assert str(info.value).startswith(str(exp.path)) and named in str(info.value)


def test_python_and_command_line_options_give_the_same_numbers(sets):
    """compensate=False (Python) is --no-compensation (identify_set): the same result."""
    exp = read_experiment(sets["pho"])
    a = phoid.identify(exp, estimator="ols", compensate=False).summary()
    b = identify_set(exp, estimator="ols", no_compensation=True).summary()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    free = read_experiment(sets["free"])
    assert phoid.identify(free, mass=3.0).c == identify_set(free, mass=3.0).c


def test_friction_selects_the_free_decay_friction_fit(sets):
    """--friction on a free set: the Coulomb + viscous decay, the same result on both routes
    (and with the mass, fc in N)."""
    free = read_experiment(sets["free"])
    a = phoid.identify(free, friction=True, mass=2.0).summary()
    b = identify_set(free, friction=True, mass=2.0).summary()
    assert a["friction"] is True and "fc" in a
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


# ---------------------------------------------------------------------------------------------
# the result base


class _Checks:
    """A stand-in for the adequacy result: what the base reads of it is its to_dict()."""

    def to_dict(self) -> dict:
        return {"residual_white": False, "chi2_noise_ratio": 4.2}


@pytest.mark.parametrize("method", ["pho", "forced"])
def test_adequacy_slot_reaches_the_summary_and_nothing_else(sets, method):
    result = dataclasses.replace(phoid.identify(read_experiment(sets[method])), adequacy=None)
    assert "adequacy" not in result.summary()  # no checks made: no key
    with_checks = dataclasses.replace(result, adequacy=_Checks())
    s, s0 = with_checks.summary(), result.summary()
    assert s["adequacy"] == _Checks().to_dict()
    del s["adequacy"]
    assert json.dumps(s) == json.dumps(s0)  # every other key, value and their order
