"""docs/format.md (the one definition of phoid/1) and docs/equations.md, kept honest.

Every key that the reader recognises (manifest, ``[loop]``, ``[[run]]``, columns, the reader's
limits) and every key of the JSON objects that the commands actually print must be named in the
page's section for it; the page's minimal example must be a set the reader accepts, and its JSON
example may show only keys that ``phoid identify --json`` prints. The JSON comes from small sets
that ``phoid simulate`` writes into a temporary folder (no shared data needed), identified in
process through the CLI (the whole file takes about 10 s of CPU time).

docs/equations.md: every correction the code or the tests cite as "ERRATA N" is explained
there, and every phoid function it names exists.

A key counts as named when it appears as inline code (`` `key` ``, or ``[loop]``/``[[run]]`` for
the tables) or quoted (``"key"``, as in the page's JSON shapes) inside the section.
"""

from __future__ import annotations

import gzip
import json
import re
import tomllib
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import phoid.io
import phoid.io._format
from phoid.cli import app
from phoid.dynamics.digital import VELOCITY_ESTIMATORS
from phoid.methods.pho_checks import DIGITAL_KEYS
from phoid.paper import reproduce_table1

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "format.md"
DOC = DOC_PATH.read_text(encoding="utf-8")

runner = CliRunner()


def section(heading: str, text: str = DOC) -> str:
    """The text under the first heading that contains ``heading``, up to the next heading of
    the same or a higher level (subsections included)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"(#+) ", line)
        if m and heading in line:
            level = len(m.group(1))
            end = next((j for j in range(i + 1, len(lines))
                        if (h := re.match(r"(#+) ", lines[j])) and len(h.group(1)) <= level),
                       len(lines))
            return "\n".join(lines[i:end])
    raise AssertionError(f"docs/format.md has no heading containing {heading!r}")


def named(key: str, text: str) -> bool:
    return any(form in text for form in (f"`{key}`", f'"{key}"', f"`[{key}]`", f"`[[{key}]]`"))


def missing(keys, text: str) -> list[str]:
    return sorted(k for k in set(keys) if not named(k, text))


def all_keys(obj: Any) -> set[str]:
    """Every key of every object inside a JSON value."""
    if isinstance(obj, dict):
        return set(obj).union(*(all_keys(v) for v in obj.values()))
    if isinstance(obj, list):
        return set().union(*(all_keys(v) for v in obj))
    return set()


def run_keys(out: dict) -> set[str]:
    return set().union(*(set(r) for r in out["runs"]))


def cli(*args: str, ok=(0,)) -> str:
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code in ok, (args, r.output)
    return r.stdout


def _not_json(name: str) -> None:
    raise AssertionError(f"{name} in the output: not strict JSON (the page promises null)")


def json_of(*args: str, ok=(0,)) -> dict:
    return json.loads(cli(*args, ok=ok), parse_constant=_not_json)


# --------------------------------------------------------------------------------------------
# the sets: conftest's varied_sets (small; only the keys matter here)
PLANT = ("--m", "1", "--c", "2", "--k", "100")  # the plant of varied_sets, for `design`


@pytest.fixture(scope="module")
def sets(varied_sets, tmp_path_factory) -> dict[str, Path]:
    """conftest's ``varied_sets`` and a folder for a designed schedule."""
    return {**varied_sets, "sched": tmp_path_factory.mktemp("format-doc") / "sched"}


@pytest.fixture(scope="module")
def outputs(sets) -> dict[str, dict]:
    """The JSON that each command prints on those sets."""
    out = {
        "given": json_of("identify", sets["pho"], "--json", "--delay", "0.02"),
        "x+u": json_of("identify", sets["pho"], "--json"),
        "x": json_of("identify", sets["nou"], "--json"),
        "digital": json_of("identify", sets["dig"], "--json"),
        "forced": json_of("identify", sets["forced"], "--json"),
        "free": json_of("identify", sets["free"], "--json"),
        "friction": json_of("identify", sets["fr"], "--json", "--friction"),
        "free-friction": json_of("identify", sets["free"], "--json", "--friction"),
        "design": json_of("design", *PLANT, "--delay", "0.02", "--runs", "3", "--json",
                          "--out", sets["sched"]),
        # exit status 1 is the verdict "a run is unsafe on the prior", not an error
        "check": json_of("design", "--check", sets["pho"], "--delay", "0.02", "--json",
                         ok=(0, 1)),
    }
    # the conditional parts are there: what the test below checks is actually exercised
    assert out["given"]["delay"]["source"] == "given"
    assert out["x+u"]["delay"]["from"] == "x+u" and "u" in out["x+u"]["runs"][0]
    assert out["x"]["delay"]["from"] == "x"
    assert out["digital"]["loop"]["model"] == "digital"
    assert "fc" in out["friction"] and "m" in out["free"]
    return out


# --------------------------------------------------------------------------------------------
# JSON output


@pytest.mark.parametrize(("name", "heading"), [
    ("given", "### `pho` sets"), ("x+u", "### `pho` sets"), ("x", "### `pho` sets"),
    ("digital", "### `pho` sets"), ("friction", "with `--friction`"),
    ("forced", "### `forced` sets"), ("free", "### `free` sets"),
    ("free-friction", "#### `free` sets with `--friction`"),
])
def test_identify_json_keys_are_documented(outputs, name, heading):
    out = outputs[name]
    sub = section(heading)
    assert missing(out, sub) == [], f"top-level keys of identify --json ({name}) not in {heading}"
    assert missing(run_keys(out), sub) == [], f"run keys of identify --json ({name})"
    # nested keys (an estimate's value/stderr/unit, delay's source, u's fields …) may be defined
    # once for every method, in the identify section
    assert missing(all_keys(out), section("## `phoid identify --json`")) == [], name


@pytest.mark.parametrize("name", ["design", "check"])
def test_design_json_keys_are_documented(outputs, name):
    assert missing(all_keys(outputs[name]), section("## `phoid design --json`")) == []


def test_paper_json_keys_are_documented():
    # the summary `phoid paper --json` prints (it adds the key "figures"), on a short simulation
    summary = reproduce_table1(duration=4.0, fs=250.0).summary() | {"figures": []}
    assert missing(all_keys(summary), section("## `phoid paper --json`")) == []


def test_the_json_example_shows_only_keys_that_identify_prints(outputs):
    block = re.search(r"```json\n(.*?)```", section("### `pho` sets"), re.S)
    example = json.loads(block.group(1))
    printed = outputs["given"]
    assert set(example) <= set(printed)
    assert run_keys(example) <= run_keys(printed)
    for key in ("m", "c", "k", "delay"):
        assert set(example[key]) <= set(printed[key]), key


# --------------------------------------------------------------------------------------------
# tracking sets: a small record made here (a 1 kHz loop tracking a sine with reversals)


@pytest.fixture(scope="module")
def tracking(tmp_path_factory) -> dict[str, dict]:
    import numpy as np

    from phoid.dynamics.controller import SampledController
    from phoid.dynamics.plant import Plant
    from phoid.simulation.tracking import simulate_tracking

    root = tmp_path_factory.mktemp("format-doc-tracking")
    ctrl = SampledController(sample_time=1e-3, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0)
    t = 1e-3 * np.arange(1500)
    r = 0.02 * np.sin(2 * np.pi * 1.3 * t)
    sim = simulate_tracking(Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3, x_init=[0.0])
    run = phoid.io.run_from_arrays(t, sim.x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    phoid.io.write_experiment(root / "set", [run], method="tracking", fixed={"k": 0.0},
                              loop={"sample_time": 1e-3, "velocity": "central-difference",
                                    "saturation": 200.0, "delay": 0.0})
    out = {
        "idim": json_of("identify", root / "set", "--json"),
        "output-error": json_of("identify", root / "set", "--json", "--estimator",
                                "output-error"),
        "replay": json_of("simulate", root / "replay", "--replay", root / "set", "--m", "2",
                          "--c", "15", "--fc", "1.5", "--offset-force", "-0.3", "--json"),
    }
    out["written"] = tomllib.loads((root / "replay" / "experiment.toml").read_text("utf-8"))
    assert out["idim"]["estimator"] == "idim"
    assert out["output-error"]["estimator"] == "output-error"
    return out


@pytest.mark.parametrize("name", ["idim", "output-error"])
def test_tracking_json_keys_are_documented(tracking, name):
    out = tracking[name]
    sub = section("### `tracking` sets")
    assert missing(out, sub) == [], name
    assert missing(all_keys(out["fit"]), sub) == [], name
    assert missing(all_keys(out["validation"]), sub) == [], name
    # the estimate's shape (value, stderr, unit) is defined once for every method
    assert missing(all_keys(out), section("## `phoid identify --json`")) == [], name


def test_replay_json_and_written_keys_are_documented(tracking):
    text = section("## What `phoid simulate` writes")
    assert missing(tracking["replay"], text) == []
    assert missing(all_keys(tracking["replay"]["validation"]),
                   section("### `tracking` sets")) == []
    assert missing(tracking["written"]["simulated"], text) == []


# --------------------------------------------------------------------------------------------
# what the reader recognises


def test_reader_keys_are_documented():
    manifest = section("## The manifest")
    assert missing(phoid.io._format.TOP_KEYS, section("### Top-level keys")) == []
    assert missing(phoid.io._format.RUN_KEYS, section("### `[[run]]` keys")) == []
    assert missing(("delay", *DIGITAL_KEYS), section("### `[loop]` keys")) == []
    assert missing(phoid.io.METHODS, manifest) == []
    assert missing(VELOCITY_ESTIMATORS, section("### `[loop]` keys")) == []
    assert missing(phoid.io._format.COLUMNS, section("## Data files")) == []
    assert named(phoid.io.FORMAT, manifest) and named(phoid.io.MANIFEST, DOC)


def test_tracking_keys_are_documented():
    from phoid.io.tracking import (
        ESTIMATORS,
        FIXED_KEYS,
        TRACKING_COLUMNS,
        TRACKING_LOOP_KEYS,
        TRACKING_RUN_KEYS,
        VELOCITY_PRESETS,
        W_UNITS,
    )

    text = section("## Tracking sets")
    for keys in (ESTIMATORS, FIXED_KEYS, TRACKING_COLUMNS, TRACKING_LOOP_KEYS, TRACKING_RUN_KEYS,
                 VELOCITY_PRESETS, W_UNITS):
        assert missing(keys, text) == [], keys


def test_reader_limits_are_documented():
    # the reader's documented limits (constants MAX_… of phoid.io), each named in
    # "Limits"
    limits = [name for name in vars(phoid.io) if name.startswith("MAX_")]
    text = section("## Limits")
    assert missing(limits, text) == []
    # … with the value the code enforces (the table's last cell: "2 MiB", "5·10⁷", "20 000")
    sup = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹", "0123456789")
    for name in limits:
        row = next(line for line in text.splitlines() if f"`{name}`" in line)
        cell = row.rstrip(" |").rsplit(",", 1)[-1].strip()
        num = re.match(r"([\d ]+(?:\.\d+)?)(?:·10([⁰¹²³⁴⁵⁶⁷⁸⁹]+))?\s*(KiB|MiB|GiB)?", cell)
        assert num, (name, cell)
        value = float(num.group(1).replace(" ", ""))
        if num.group(2):
            value *= 10 ** int(num.group(2).translate(sup))
        value *= {"KiB": 2**10, "MiB": 2**20, "GiB": 2**30, None: 1}[num.group(3)]
        assert value == getattr(phoid.io, name), (name, cell)


def test_keys_that_tools_write_are_documented(sets, outputs):
    # the manifests written by `phoid design --out` and `phoid simulate`: every key beyond the
    # reader's own is one of the tool keys the page lists
    tools = section("### Keys written by")
    known = {*phoid.io._format.TOP_KEYS, *phoid.io._format.RUN_KEYS, "delay", *DIGITAL_KEYS}
    written: set[str] = set()
    for name in ("sched", "pho", "dig", "forced", "free", "fr"):
        doc = tomllib.loads((sets[name] / "experiment.toml").read_text(encoding="utf-8"))
        written |= all_keys(doc) - known
    assert {"design", "simulated", "predicted_sigma", "u_noise", "v0"} <= written
    assert missing(written, tools) == []


def test_the_minimal_example_is_a_valid_set(tmp_path):
    text = section("## A complete minimal example")
    toml = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    csv = re.search(r"```csv\n(.*?)```", text, re.S).group(1)
    (tmp_path / "experiment.toml").write_text(toml, encoding="utf-8")
    (tmp_path / "run01.csv").write_text(csv, encoding="utf-8")
    # the other runs: their own recordings (a copy of run01 would be refused as a duplicate)
    assert "0.0099," in csv
    (tmp_path / "run02.csv").write_text(csv.replace("0.0099,", "0.0098,"), encoding="utf-8")
    (tmp_path / "run03.csv.gz").write_bytes(gzip.compress(csv.replace("0.0099,", "0.0097,")
                                                          .encode()))
    exp = phoid.io.read_experiment(tmp_path)
    assert exp.method == "pho" and exp.delay == 0.02 and len(exp.runs) == 3
    assert [r.added_mass for r in exp.runs] == [0.0, 0.5, 0.0]
    assert all(r.u is not None and r.n == 3 for r in exp.runs)
    assert len({(r.P, r.D) for r in exp.runs}) == 3  # three distinct gain pairs, as it says


# --------------------------------------------------------------------------------------------
# docs/equations.md: the seed paper's equations and their corrections

EQUATIONS = (DOC_PATH.parent / "equations.md").read_text(encoding="utf-8")
SRC = Path(__file__).resolve().parents[1] / "src" / "phoid"


def test_every_erratum_the_code_cites_is_explained():
    # the code and the tests cite corrections as "ERRATA N"; each N has its own paragraph
    cited = {int(n) for p in [*SRC.glob("*.py"), *Path(__file__).parent.glob("*.py")]
             for n in re.findall(r"ERRATA (\d+)", p.read_text(encoding="utf-8"))}
    assert cited  # the pattern matches the citations
    explained = {int(n) for n in re.findall(r"\*\*ERRATA (\d+) — ", EQUATIONS)}
    assert cited <= explained, sorted(cited - explained)


def test_every_function_the_equations_page_names_exists():
    import importlib

    names = set(re.findall(r"`(phoid(?:\.\w+)+)`", EQUATIONS))
    assert len(names) > 20
    for name in sorted(names):
        parts = name.split(".")
        # the longest importable module, then attributes
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
                break
            except ModuleNotFoundError:
                continue
        for attr in parts[cut:]:
            assert hasattr(obj, attr), name
            obj = getattr(obj, attr)
