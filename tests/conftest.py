"""Shared fixtures: the independent sample set, in the repository and (cross-check) beside it.

* ``examples/paper-sample`` (in the repository, so the suite runs from a clone alone): the seed
  paper's Table 1 experiment made by jitcdde (examples/make_paper_sample.py, not by phoid), with
  its truth in ``examples/paper-sample/truth.json``. Fixtures ``sample_set_path`` and ``truth``.
* ``../shared/data/paper-sample`` (beside the checkout: the project's own independent set, made
  by someone else's jitcdde run; CI has it, a clone does not): the same experiment with another
  noise draw and other digits written. Tests that *additionally* cross-check against it use
  ``shared_sample_set_path`` / ``shared_truth`` or the parametrised ``paper_sample``, and are
  skipped, with the reason, where it is absent.

Both truths give m, c, k, fc, delay, noise, x0, fs, T and ``crb_sd``; their ``crb_sd`` differ in
the amplitude model (examples: each run's dominant-mode residue, bench/crb.py's default, the
model of phoid.planning.fisher; shared: the release's own initial conditions, ≈2 % lower).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "paper-sample"
EXAMPLE_TRUTH = EXAMPLE / "truth.json"
SHARED = ROOT.parent / "shared"
SHARED_SAMPLE = SHARED / "data" / "paper-sample"
SHARED_TRUTH = SHARED / "data" / "truth.json"
SHARED_ABSENT = (
    f"cross-check against the project's shared sample set skipped: {SHARED_SAMPLE} is absent "
    "(it lies beside the checkout in CI, not in a clone; the check runs on "
    "examples/paper-sample all the same)"
)


@pytest.fixture(autouse=True)
def _fresh_working_directory(tmp_path_factory, monkeypatch):
    """Every test runs in an empty working directory of its own.

    A test that read or wrote a relative path would otherwise depend on where pytest was
    started and on what an earlier command left there (``make demo`` writes ``phoid-out/``
    into the checkout, and ``phoid paper`` then refuses to replace it), and could leave files
    in the user's checkout. Paths into the repository are built from ``ROOT``."""
    monkeypatch.chdir(tmp_path_factory.mktemp("cwd"))


@dataclass(frozen=True)
class SampleSet:
    """An independent (jitcdde-made) paper-sample set: where it is, its truth, and its source."""

    path: Path
    truth: dict
    source: str  # "examples" or "shared"


def _example() -> SampleSet:
    if not (EXAMPLE / "experiment.toml").is_file() or not EXAMPLE_TRUTH.is_file():
        pytest.fail(f"the example set is missing from the checkout: {EXAMPLE} "
                    "(remake it with `python examples/make_paper_sample.py`)")
    return SampleSet(EXAMPLE, json.loads(EXAMPLE_TRUTH.read_text()), "examples")


def _shared() -> SampleSet:
    if not SHARED_SAMPLE.is_dir() or not SHARED_TRUTH.is_file():
        pytest.skip(SHARED_ABSENT)
    return SampleSet(SHARED_SAMPLE, json.loads(SHARED_TRUTH.read_text())["paper-sample"],
                     "shared")


@pytest.fixture(scope="session")
def sample_set_path() -> Path:
    """examples/paper-sample (in the repository)."""
    return _example().path


@pytest.fixture(scope="session")
def truth() -> dict:
    """examples/paper-sample/truth.json."""
    return _example().truth


@pytest.fixture(scope="session")
def shared_sample_set_path() -> Path:
    """../shared/data/paper-sample; the test is skipped where it is absent."""
    return _shared().path


@pytest.fixture(scope="session")
def shared_truth() -> dict:
    """../shared/data/truth.json's "paper-sample"; the test is skipped where it is absent."""
    return _shared().truth


@pytest.fixture(scope="session", params=["examples", "shared"])
def paper_sample(request) -> SampleSet:
    """Both independent sets in turn: the repository's, then (a cross-check, skipped where
    absent) the shared one."""
    return _example() if request.param == "examples" else _shared()


# --------------------------------------------------------------------------------------------
# small sets of every kind of identify output (a few seconds of record at 500 Hz: only the
# output's keys matter to their users, tests/test_format_doc.py and tests/test_json_schema.py)
VARIED_PLANT = ("--m", "1", "--c", "2", "--k", "100")
VARIED_SMALL = ("--duration", "3", "--fs", "500", "--noise", "1e-5")


@pytest.fixture(scope="session")
def varied_sets(tmp_path_factory) -> dict[str, Path]:
    """Folders of simulated sets: ``pho`` (continuous loop, no delay in the manifest, u
    recorded with noise), ``nou`` (the same runs without u), ``dig`` (a sampled loop),
    ``forced``, ``free`` (with its mass), ``fr`` (Coulomb friction)."""
    import dataclasses

    from typer.testing import CliRunner

    import phoid.io
    from phoid.cli import app

    runner = CliRunner()

    def cli(*args) -> None:
        r = runner.invoke(app, [str(a) for a in args])
        assert r.exit_code == 0, (args, r.output)

    root = tmp_path_factory.mktemp("varied-sets")
    s = {name: root / name for name in ("pho", "nou", "dig", "forced", "free", "fr")}
    cli("simulate", s["pho"], *VARIED_PLANT, "--P", "20:200:4", "--D", "0.5:3:4", "--delay",
        "0.02", *VARIED_SMALL, "--u-noise", "1e-3", "--omit-delay", "--seed", "1")
    exp = phoid.io.read_experiment(s["pho"])
    phoid.io.write_experiment(
        s["nou"], [dataclasses.replace(r, u=None) for r in exp.runs], method="pho")
    cli("simulate", s["dig"], *VARIED_PLANT, "--P", "20:200:4", "--D", "0.5:5:4",
        "--sample-time", "0.002", "--delay-samples", "3", "--velocity", "filtered",
        "--cutoff", "300", *VARIED_SMALL, "--seed", "4")
    cli("simulate", s["forced"], "--method", "forced", *VARIED_PLANT, "--omega", "6,9,14",
        "--duration", "8", "--fs", "200", "--noise", "1e-5", "--seed", "1")
    cli("simulate", s["free"], "--method", "free", *VARIED_PLANT, *VARIED_SMALL, "--seed", "3",
        "--write-mass")
    cli("simulate", s["fr"], *VARIED_PLANT, "--fc", "0.05", "--P", "0:150:3", "--D",
        "0.5:3:3", "--delay", "0.02", "--duration", "2", "--fs", "500", "--noise", "1e-5",
        "--x0", "0.008", "--seed", "3")
    return s


@pytest.fixture
def artefact(tmp_path, request):
    """``artefact(name)``: the path a test writes a file worth keeping to (a browser's
    screenshot): under ``$PHOID_TEST_ARTEFACTS/<test module>/<test>/`` where that variable names
    a folder (.ci/run sets it to ``test-artefacts/`` in the checkout, git-ignored, so CI keeps
    the screenshots of the HTML reports and of the documentation site), else in the test's
    ``tmp_path``. The folder is made; an existing file of that name is replaced (the same
    test's earlier run)."""
    import os
    import re

    root = os.environ.get("PHOID_TEST_ARTEFACTS")
    if root:
        test = re.sub(r"[^\w.-]+", "_", request.node.name)
        folder = Path(root) / Path(request.node.fspath).stem / test
    else:
        folder = tmp_path
    folder.mkdir(parents=True, exist_ok=True)
    return lambda name: folder / name
