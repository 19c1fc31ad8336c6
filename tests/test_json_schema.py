"""The JSON Schemas of every command's ``--json`` output (src/phoid/schema, shipped as package
data; docs/format-extensions.md) are valid draft 2020-12 schemas, every command's actual output
validates against its schema, and outputs that break the contract do not.

The outputs come from small sets that ``phoid simulate`` writes into a temporary folder (no
shared data needed), from examples/paper-sample, and from ../shared/data where it is present
(those tests skip without it). Every object of the schemas is closed (``additionalProperties:
false``), so a key that a command prints and the schema does not know fails here: the schema,
docs/format.md and the code move together.
"""

from __future__ import annotations

import copy
import json
import shutil
import tomllib
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from typer.testing import CliRunner

import phoid.io
from phoid.cli import app

ROOT = Path(__file__).resolve().parents[1]
SCHEMA_DIR = ROOT / "src" / "phoid" / "schema"
SHARED = ROOT.parent / "shared" / "data"
NAMES = ("identify", "design", "paper", "replay")

runner = CliRunner()


def schema(name: str) -> dict:
    return json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text(encoding="utf-8"))


def validator(name: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(schema(name))


def _not_json(name: str) -> None:
    raise AssertionError(f"{name} in the output: not strict JSON")


def cli(*args, ok=(0,)) -> str:
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code in ok, (args, r.output)
    return r.stdout


def json_of(*args, ok=(0,)) -> dict:
    return json.loads(cli(*args, ok=ok), parse_constant=_not_json)


def errors(name: str, instance) -> list[str]:
    return [f"{list(e.absolute_path)}: {e.message[:200]}"
            for e in validator(name).iter_errors(instance)]


# --------------------------------------------------------------------------------------------
# the schemas themselves


@pytest.mark.parametrize("name", NAMES)
def test_the_schema_is_a_valid_draft_2020_12_schema(name):
    s = schema(name)
    assert s["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    jsonschema.Draft202012Validator.check_schema(s)


def test_the_schemas_ship_with_the_package():
    # package data: found through importlib.resources (an installed phoid has them too, as
    # pyproject's package-data lists them)
    for name in NAMES:
        assert (resources.files("phoid") / "schema" / f"{name}.schema.json").is_file()
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "schema/*.json" in pyproject["tool"]["setuptools"]["package-data"]["phoid"]


def _objects(node, path="#"):
    """Every object schema (a dict with "properties") inside a schema, with its path."""
    if isinstance(node, dict):
        if "properties" in node and node.get("type") == "object":
            yield path, node
        for k, v in node.items():
            yield from _objects(v, f"{path}/{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _objects(v, f"{path}/{i}")


@pytest.mark.parametrize("name", NAMES)
def test_every_object_of_the_schema_is_closed(name):
    # the contract: an undocumented key fails validation (docs/format-extensions.md)
    # (identify's root only dispatches on "method" to its closed per-method objects)
    open_ = [p for p, o in _objects(schema(name))
             if o.get("additionalProperties") is not False and "allOf" not in o]
    assert open_ == []
    if name == "identify":
        targets = [b["then"]["$ref"] for b in schema(name)["allOf"]]
        defs = schema(name)["$defs"]
        assert all(defs[t.rsplit("/", 1)[-1]]["additionalProperties"] is False for t in targets)


# --------------------------------------------------------------------------------------------
# the outputs (small sets: a few seconds of record; only the shapes matter here)

PLANT = ("--m", "1", "--c", "2", "--k", "100")
SMALL = ("--duration", "3", "--fs", "500", "--noise", "1e-5")


def _tracking_set(folder: Path, noise: float = 2e-6) -> Path:
    """A 1 kHz loop tracking a sine with reversals (as tests/test_format_doc.py), plus white
    position noise so that the residual/noise ratio has a noise to compare with."""
    from phoid.dynamics.controller import SampledController
    from phoid.dynamics.plant import Plant
    from phoid.simulation.tracking import simulate_tracking

    ctrl = SampledController(sample_time=1e-3, P=4000.0, D=60.0, velocity="central-difference",
                             saturation=200.0)
    t = 1e-3 * np.arange(1500)
    r = 0.02 * np.sin(2 * np.pi * 1.3 * t)
    sim = simulate_tracking(Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3, x_init=[0.0])
    x = sim.x + noise * np.random.default_rng(5).standard_normal(t.size)
    run = phoid.io.run_from_arrays(t, x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    phoid.io.write_experiment(folder, [run], method="tracking", fixed={"k": 0.0},
                              loop={"sample_time": 1e-3, "velocity": "central-difference",
                                    "saturation": 200.0, "delay": 0.0})
    return folder


@pytest.fixture(scope="module")
def outputs(tmp_path_factory, varied_sets) -> dict[str, tuple[str, dict]]:
    """name → (schema, the JSON the command printed), on conftest's ``varied_sets`` and a
    tracking set."""
    root = tmp_path_factory.mktemp("json-schema")
    s = varied_sets
    trk = _tracking_set(root / "trk")
    out = {
        "paper-sample": ("identify", json_of("identify", ROOT / "examples" / "paper-sample",
                                             "--json")),
        "pho-given": ("identify", json_of("identify", s["pho"], "--json", "--delay", "0.02")),
        "pho-x+u": ("identify", json_of("identify", s["pho"], "--json")),
        "pho-x": ("identify", json_of("identify", s["nou"], "--json")),
        "pho-digital": ("identify", json_of("identify", s["dig"], "--json")),
        "friction": ("identify", json_of("identify", s["fr"], "--json", "--friction")),
        "forced": ("identify", json_of("identify", s["forced"], "--json")),
        "free": ("identify", json_of("identify", s["free"], "--json")),
        "free-friction": ("identify", json_of("identify", s["free"], "--json", "--friction")),
        "tracking-idim": ("identify", json_of("identify", trk, "--json")),
        "tracking-oe": ("identify", json_of("identify", trk, "--json", "--estimator",
                                            "output-error")),
        "replay": ("replay", json_of("simulate", root / "replay", "--replay", trk, "--m", "2",
                                     "--c", "15", "--fc", "1.5", "--offset-force", "-0.3",
                                     "--json")),
        "design": ("design", json_of("design", *PLANT, "--delay", "0.02", "--runs", "3",
                                     "--json", "--out", root / "sched")),
        # exit status 1 is the verdict "a run is unsafe on the prior", not an error
        "check": ("design", json_of("design", "--check", s["pho"], "--delay", "0.02", "--json",
                                    ok=(0, 1))),
        "paper": ("paper", json_of("paper", "--json", "--duration", "4", "--fs", "250", "--out",
                                   root / "paper")),
    }
    # the conditional parts are there: what the tests below check is actually exercised
    assert out["pho-x+u"][1]["delay"]["from"] == "x+u" and "u" in out["pho-x+u"][1]["runs"][0]
    assert out["pho-x"][1]["delay"]["from"] == "x"
    assert out["pho-digital"][1]["loop"]["model"] == "digital"
    assert "fc" in out["friction"][1] and "m" in out["free"][1]
    assert out["free-friction"][1]["friction"] is True and "fc" in out["free-friction"][1]
    assert out["tracking-idim"][1]["estimator"] == "idim"
    assert out["tracking-oe"][1]["estimator"] == "output-error"
    assert {out["design"][1]["kind"], out["check"][1]["kind"]} == {"design", "check"}
    return out


OUTPUTS = ("paper-sample", "pho-given", "pho-x+u", "pho-x", "pho-digital", "friction", "forced",
           "free", "free-friction", "tracking-idim", "tracking-oe", "replay", "design", "check",
           "paper")


@pytest.mark.parametrize("name", OUTPUTS)
def test_the_output_validates_against_its_schema(outputs, name):
    which, out = outputs[name]
    assert errors(which, out) == []


def test_the_shared_paper_sample_validates():
    path = SHARED / "paper-sample"
    if not (path / "experiment.toml").is_file():
        pytest.skip(f"{path} is absent (it lies beside the checkout in CI, not in a clone)")
    assert errors("identify", json_of("identify", path, "--json")) == []


def test_the_emps_record_validates(tmp_path):
    mat = SHARED / "emps" / "DATA_EMPS.mat"
    if not mat.is_file():
        pytest.skip(f"the real EMPS record is not beside the checkout ({mat} is absent)")
    shutil.copy(ROOT / "examples" / "emps" / "experiment.toml", tmp_path)
    shutil.copy(mat, tmp_path)
    out = json_of("identify", tmp_path, "--json")
    assert errors("identify", out) == []
    # the real record's position misfit against its encoder noise: the model is far from
    # explaining it to the noise (quantisation and unmodelled friction), a number ≫ 1
    assert out["validation"][0]["residual_noise_ratio"] > 1.0


# --------------------------------------------------------------------------------------------
# outputs that break the contract fail


def _broken(outputs, name, change):
    which, out = outputs[name]
    bad = copy.deepcopy(out)
    change(bad)
    return errors(which, bad)


@pytest.mark.parametrize(("name", "change"), [
    # a key the schema does not know, at the top and deep inside
    ("paper-sample", lambda d: d.update(surprise=1)),
    ("paper-sample", lambda d: d["runs"][0].update(surprise=1)),
    ("paper-sample", lambda d: d["statistics"].update(surprise=1)),
    ("tracking-oe", lambda d: d["validation"][0]["signals"].update(jerk={})),
    ("design", lambda d: d["settings"].update(surprise=1)),
    ("paper", lambda d: d["simulation"].update(surprise=1)),
    ("replay", lambda d: d["parameters"].update(surprise=1.0)),
    # a required key missing
    ("paper-sample", lambda d: d.pop("statistics")),
    ("forced", lambda d: d["runs"][0].pop("residual_noise_ratio")),
    ("free", lambda d: d.pop("roots")),
    ("design", lambda d: d.pop("safe")),
    # a wrong type or value
    ("paper-sample", lambda d: d["m"].update(value="2.0")),
    ("paper-sample", lambda d: d["correlation"]["matrix"][0].__setitem__(1, 1.5)),
    ("paper-sample", lambda d: d["statistics"].update(dof=35.5)),
    ("friction", lambda d: d["runs"][0].update(reversals=None)),
    ("free", lambda d: d.update(regime="wobbly")),
    ("free-friction", lambda d: d["runs"][0].update(half_cycles=-1)),
    ("free-friction", lambda d: d["evidence"].pop("significant")),
    ("tracking-idim", lambda d: d.update(estimator="magic")),
    # the method's keys checked against the method: a pho result labelled forced, a friction
    # result without its fc
    ("paper-sample", lambda d: d.update(method="forced")),
    ("friction", lambda d: d.pop("fc")),
    # a free-friction result without its flag is read as a viscous free one (no roots)
    ("free-friction", lambda d: d.pop("friction")),
    ("replay", lambda d: d["validation"][0].update(method="other")),
])
def test_a_corrupted_output_fails(outputs, name, change):
    assert _broken(outputs, name, change) != []


def test_nan_is_not_json_and_null_is_allowed_where_documented(outputs):
    _, out = outputs["paper-sample"]
    bad = copy.deepcopy(out)
    bad["statistics"]["chi2"] = None
    assert errors("identify", bad) == []  # a χ² that was not computed (OLS) is null
    bad["statistics"]["chi2"] = float("nan")
    # NaN is no JSON number: json.dumps would write it only as a non-standard token
    with pytest.raises(ValueError):
        json.dumps(bad, allow_nan=False)
