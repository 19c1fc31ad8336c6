"""`phoid design --rehearse` and `phoid.rehearse`: simulated replicas of a design identified.

The tolerances follow from the number of replicas n: under a correct prediction the
estimates' n − 1 SD²/σ² is χ² on n − 1 dof, n RMSE²/σ² is χ² on n dof (no bias), and the
number of replicas outside ±3 correct stderrs is binomial(n, 2 Φ(−3)); each band is the
central 99.9 % (or the upper 1e-4 tail) of that law, so a correct implementation fails by
chance with probability ~1e-3 at most (and the seeds are fixed).
"""

from __future__ import annotations

import json
import math
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid
from phoid.batch import rehearsal as rehearsal_module
from phoid.cli import app
from phoid.errors import IdentificationError
from phoid.methods.chi2 import chi2_isf

PAPER = dict(m=2.0, c=1.0, k=64.0, delay=0.1)  # the seed paper's plant and loop delay
OUTSIDE = math.erfc(3 / math.sqrt(2))  # Pr(|N(0,1)| > 3)


@pytest.fixture(scope="module")
def plan():
    """The paper's plant, a 6-run design at noise 1e-4 m, 4 s records (cheap replicas)."""
    return phoid.design(PAPER["m"], PAPER["c"], PAPER["k"], delay=PAPER["delay"], runs=6,
                        noise=1e-4, duration=4.0)


def _chi2_ratio_band(dof: int, q: float = 5e-4) -> tuple[float, float]:
    """The central 1 − 2q range of √(χ²_dof / dof)."""
    return math.sqrt(chi2_isf(1 - q, dof) / dof), math.sqrt(chi2_isf(q, dof) / dof)


def _binomial_upper(n: int, p: float, tail: float = 1e-4) -> int:
    """The smallest count c with Pr(X > c) < tail for X ~ binomial(n, p)."""
    cdf, c = 0.0, 0
    while True:
        cdf += math.comb(n, c) * p ** c * (1 - p) ** (n - c)
        if 1 - cdf < tail:
            return c
        c += 1


def _assert_calibrated(result, n):
    lo, hi = _chi2_ratio_band(n - 1)
    lo_rmse, hi_rmse = _chi2_ratio_band(n)
    outside = _binomial_upper(n, OUTSIDE)
    for p in result.parameters:
        assert lo <= p.sd_ratio <= hi, (p.name, p.sd_ratio, (lo, hi))
        assert lo_rmse <= p.rmse_ratio <= hi_rmse, (p.name, p.rmse_ratio)
        assert p.coverage >= 1 - outside / n, (p.name, p.coverage)
        # the reported stderrs are the prediction's (the design and the fit share the model)
        assert p.mean_stderr == pytest.approx(p.predicted, rel=0.1)


def test_statistics_on_a_known_sample():
    # errors ±1 about 10 with stderr 0.5: inside ±3·0.5, bias 0, RMSE 1, SD √(4/3)
    est = np.array([11.0, 9.0, 11.0, 9.0])
    stats = rehearsal_module._statistics("k", "N/m", 10.0, 2.0, est, np.full(4, 0.5))
    assert stats.coverage == 1.0 and stats.bias == 0.0 and stats.rmse == 1.0
    assert stats.observed_sd == pytest.approx(math.sqrt(4 / 3))
    assert stats.sd_ratio == pytest.approx(math.sqrt(4 / 3) / 2)
    assert stats.bias_mc == pytest.approx(math.sqrt(4 / 3) / 2)
    assert stats.rmse_ratio == 0.5
    # one error outside 3 stderr: coverage 3/4
    stats = rehearsal_module._statistics("k", "N/m", 10.0, 2.0, est, np.array([0.5, 0.5, 0.3,
                                                                                 0.5]))
    assert stats.coverage == 0.75


def test_the_same_seed_gives_the_same_replicas(plan):
    a = phoid.rehearse(plan, 8, seed=11)
    b = phoid.rehearse(plan, 8, seed=11)
    c = phoid.rehearse(plan, 8, seed=12)
    assert a.seed == 11 and a.identified == 8
    np.testing.assert_array_equal(a.estimates, b.estimates)
    np.testing.assert_array_equal(a.stderrs, b.stderrs)
    assert not np.any(a.estimates == c.estimates)
    # no seed: one is drawn and reported, and it repeats the replicas
    d = phoid.rehearse(plan, 3)
    np.testing.assert_array_equal(d.estimates, phoid.rehearse(plan, 3, seed=d.seed).estimates)


def test_a_replica_that_fails_is_counted_not_fatal(plan, monkeypatch):
    real = rehearsal_module.rehearse_replica

    def flaky(spec, seed):
        if seed.spawn_key[-1] == 2:
            raise IdentificationError("replica data cannot determine m, c, k")
        return real(spec, seed)

    monkeypatch.setattr(rehearsal_module, "rehearse_replica", flaky)
    result = phoid.rehearse(plan, 5, seed=1)
    assert (result.replicas, result.identified) == (5, 4)
    assert result.errors == ("replica 3: replica data cannot determine m, c, k",)
    assert "1 of 5 replicas did not identify" in result.warnings[0]

    def broken(spec, seed):
        raise TypeError("a bug")

    monkeypatch.setattr(rehearsal_module, "rehearse_replica", broken)
    with pytest.raises(TypeError, match="a bug"):  # a fault of phoid's is not a count
        phoid.rehearse(plan, 3, seed=1)


@pytest.mark.parametrize("n", [1, 0, 2.5, True, 100_001])
def test_bad_replica_counts_are_refused(plan, n):
    with pytest.raises(ValueError, match="replicas"):
        phoid.rehearse(plan, n)


def test_cli_options_are_checked_before_the_work():
    runner = CliRunner()
    base = ["design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.1"]
    res = runner.invoke(app, [*base, "--rehearse", "1"])
    assert res.exit_code == 2 and "--rehearse must be from 2" in res.stderr
    res = runner.invoke(app, [*base, "--seed", "3"])
    assert res.exit_code == 2 and "--seed applies to --rehearse only" in res.stderr


@pytest.mark.slow
def test_rehearsal_on_a_local_cluster_is_calibrated_and_reproducible(plan):
    # 60 replicas on 2 worker processes: the spread, RMSE and coverage agree with the
    # Cramér–Rao prediction within the χ² and binomial bands of n = 60, and the numbers equal
    # those of the same seed run in this process (the replica, not the worker, owns its seed)
    pytest.importorskip("distributed")
    from phoid.batch.cluster import cluster_client

    n = 60
    with cluster_client(workers=2) as client:
        result = phoid.rehearse(plan, n, client=client, seed=2026)
    assert result.identified == n
    _assert_calibrated(result, n)
    here = phoid.rehearse(plan, n, seed=2026)
    np.testing.assert_array_equal(result.estimates, here.estimates)
    np.testing.assert_array_equal(result.stderrs, here.stderrs)


@pytest.mark.slow
def test_design_rehearse_json_follows_the_schema(plan):
    pytest.importorskip("distributed")
    jsonschema = pytest.importorskip("jsonschema")
    res = CliRunner().invoke(app, [
        "design", "--m", "2", "--c", "1", "--k", "64", "--delay", "0.1", "--runs", "6",
        "--noise", "1e-4", "--duration", "4", "--rehearse", "6", "--workers", "2", "--seed",
        "5", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    schema = json.loads(resources.files("phoid").joinpath("schema/design.schema.json")
                        .read_text())
    assert list(jsonschema.Draft202012Validator(schema).iter_errors(out)) == []
    reh = out["rehearsal"]
    # every key of the block is named, in backticks, in docs/format.md's section
    doc = (Path(__file__).parents[1] / "docs" / "format.md").read_text(encoding="utf-8")
    start = doc.index("### `rehearsal`")
    text = doc[start:doc.index("\n## ", start)]
    keys = set(reh) | set().union(*(set(v) for v in reh["parameters"].values()))
    assert sorted(k for k in keys if f"`{k}`" not in text) == []
    assert (reh["replicas"], reh["identified"], reh["seed"]) == (6, 6, 5)
    # the CLI's replicas are phoid.rehearse's with the same design and seed
    here = phoid.rehearse(plan, 6, seed=5)
    for j, name in enumerate("mck"):
        got = reh["parameters"][name]
        assert got["rmse"] == pytest.approx(here.parameters[j].rmse, rel=1e-12)
        assert got["predicted"] == pytest.approx(out["predicted"][name]["stderr"], rel=1e-12)
