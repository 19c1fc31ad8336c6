"""`phoid trend` and `phoid.batch.drift`: the control chart of a batch output's estimates.

The batch output is built here with pandas in the schema of docs/format.md ("phoid batch
output"), so these tests do not depend on `phoid batch` itself. The chart's false alarm rate and
power are checked by simulating series whose true value and stderrs are known.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid.batch.drift import control_chart, trend
from phoid.cli import app

pd = pytest.importorskip("pandas")

ALPHA = math.erfc(3 / math.sqrt(2))  # 2 Φ(−3): the nominal false alarm rate of |z| > 3


def _binomial_band(n: int, p: float, sds: float = 4.5) -> tuple[float, float]:
    """The count's mean ± `sds` binomial standard deviations (4.5: a false failure ~1e-5)."""
    sd = math.sqrt(n * p * (1 - p))
    return n * p - sds * sd, n * p + sds * sd


# ------------------------------------------------------------------------------------------
# the chart's statistics


def test_a_step_of_five_stderr_is_flagged():
    # baseline of 5 points at 1.0 (stderr 0.1) then 1.5: z = 0.5/√(0.1² + 0.1²/5) = 4.56 > 3
    chart = control_chart([1.0] * 5 + [1.5], [0.1] * 6)
    assert chart["baseline"] == pytest.approx(1.0)
    assert chart["baseline_stderr"] == pytest.approx(0.1 / math.sqrt(5))
    assert chart["z"][-1] == pytest.approx(5 / math.sqrt(1.2))
    assert chart["flagged"].tolist() == [False] * 5 + [True]


def test_the_baseline_is_the_inverse_variance_weighted_mean():
    # weights 1/0.1² = 100 and 1/0.2² = 25: b = (100·1 + 25·2)/125 = 1.2, s_b = 1/√125
    chart = control_chart([1.0, 2.0, 1.2], [0.1, 0.2, 0.1], baseline=2)
    assert chart["baseline"] == pytest.approx(1.2)
    assert chart["baseline_stderr"] == pytest.approx(1 / math.sqrt(125))
    # χ² = 100·0.2² + 25·0.8² = 20 on 1 dof
    assert chart["chi2"] == pytest.approx(20.0)
    assert np.isnan(chart["z"][:2]).all() and chart["z"][2] == pytest.approx(0.0)


def test_the_false_alarm_rate_per_point_is_the_nominal_level():
    # drift-free series with correct, unequal stderrs: one tested point per series (a random
    # position, so that the counts are independent) is flagged with probability 2 Φ(−3)
    rng = np.random.default_rng(20)
    n_series, baseline, tested = 20000, 5, 20
    flags, zs = 0, []
    for _ in range(n_series):
        s = rng.lognormal(0.0, 0.5, baseline + tested)  # stderrs that vary from set to set
        x = 3.0 + s * rng.standard_normal(s.size)
        chart = control_chart(x, s, baseline=baseline)
        j = baseline + rng.integers(tested)
        flags += bool(chart["flagged"][j])
        zs.append(chart["z"][j])
    lo, hi = _binomial_band(n_series, ALPHA)
    assert lo <= flags <= hi, (flags, n_series * ALPHA)
    # and z is standard normal: mean within 4.5 SE, variance within 4.5 SE of 1 (SE √(2/n))
    zs = np.array(zs)
    assert abs(zs.mean()) < 4.5 / math.sqrt(n_series)
    assert abs(zs.var() - 1) < 4.5 * math.sqrt(2 / n_series)


def test_a_step_of_five_stderr_is_caught_with_the_predicted_power():
    # after a step of 5 stderr, z ~ N(5/√1.2, 1): Pr(|z| > 3) = Φ(5/√1.2 − 3) + Φ(−5/√1.2 − 3)
    mu = 5 / math.sqrt(1.2)
    power = 0.5 * math.erfc(-(mu - 3) / math.sqrt(2)) + 0.5 * math.erfc((mu + 3) / math.sqrt(2))
    rng = np.random.default_rng(21)
    n = 4000
    s = np.full(6, 0.01)
    hits = 0
    for _ in range(n):
        x = 2.0 + s * rng.standard_normal(6)
        x[5] += 5 * s[5]
        hits += bool(control_chart(x, s)["flagged"][5])
    lo, hi = _binomial_band(n, power)
    assert lo <= hits <= hi, (hits / n, power)


@pytest.mark.parametrize("bad", [dict(values=[1.0, np.nan], stderrs=[1.0, 1.0]),
                                 dict(values=[1.0, 2.0], stderrs=[1.0, 0.0]),
                                 dict(values=[1.0, 2.0], stderrs=[1.0])])
def test_control_chart_refuses_bad_series(bad):
    with pytest.raises(ValueError, match=r"values|stderrs"):
        control_chart(**bad)


# ------------------------------------------------------------------------------------------
# batch outputs


def _row(axis, time, m, c, k, *, status="ok", i=0, se=(1e-3, 1e-3, 0.05)):
    """One row of the batch output schema (docs/format.md, "phoid batch output")."""
    ok = status == "ok"
    return {
        "set": f"sets/{axis}-{i:03d}", "checksum": f"{i:064x}", "options": "{}",
        "status": status, "error": None if ok else "IdentificationError: no decay",
        "method": "pho", "axis": axis, "time": time,
        "m": m if ok else None, "m_stderr": se[0] if ok else None,
        "c": c if ok else None, "c_stderr": se[1] if ok else None,
        "k": k if ok else None, "k_stderr": se[2] if ok else None,
        "delay": None, "delay_stderr": None,
        "corr_m_c": 0.1, "corr_m_k": 0.9, "corr_c_k": 0.1, "chi2_dof": 1.0, "n_runs": 10,
        "n_warnings": 0, "warnings": "[]", "seconds": 0.2, "worker": "tcp://127.0.0.1:1",
        "finished": pd.Timestamp("2026-12-01T00:00:00Z") + pd.Timedelta(minutes=i),
        "phoid_version": "0.1.0",
    }


def _fleet(step_at: int = 8) -> pd.DataFrame:
    """Two axes identified nightly for 12 nights; axis y's c steps by +10 stderr from night
    `step_at`; one failed set; rows shuffled (the trend must sort them)."""
    rng = np.random.default_rng(3)
    rows = []
    for a, axis in enumerate(("x", "y")):
        for night in range(12):
            t = pd.Timestamp("2026-11-01T02:00:00Z") + pd.Timedelta(days=night)
            c = 1.0 + (10e-3 if axis == "y" and night >= step_at else 0.0)
            rows.append(_row(axis, t, 2 + 1e-3 * rng.standard_normal(),
                             c + 1e-3 * rng.standard_normal(),
                             64 + 0.05 * rng.standard_normal(), i=24 * a + night))
    rows.append(_row("x", pd.Timestamp("2026-11-20T02:00:00Z"), 0, 0, 0, status="error",
                     i=99))
    frame = pd.DataFrame(rows).sample(frac=1.0, random_state=1).reset_index(drop=True)
    frame["time"] = pd.to_datetime(frame["time"], utc=True)
    return frame


@pytest.fixture
def fleet_file(tmp_path):
    pytest.importorskip("pyarrow")
    path = tmp_path / "results.parquet"
    frame = _fleet()
    frame.to_parquet(path)
    frame.to_csv(tmp_path / "results.csv", index=False)
    return path


def test_trend_flags_the_step_and_nothing_on_the_steady_axis():
    result = trend(_fleet(step_at=8))
    units = {u.unit: u for u in result.units}
    assert set(units) == {"x", "y"}
    c_y = {ch.name: ch for ch in units["y"].charts}["c"]
    # sorted by time, the failed row left out: 12 points
    times = [p.time for p in c_y.points]
    assert times == sorted(times) and len(times) == 12
    # the step (10 stderr) at nights 8..11 is flagged; nights 5..7 are not (drift-free: a
    # false alarm there has probability 3 × 0.27 %, and this seed has none)
    assert [p.flagged for p in c_y.points[5:]] == [False] * 3 + [True] * 4
    assert all(p.z is None for p in c_y.points[:5])
    assert not any(p.flagged for ch in units["x"].charts for p in ch.points)
    assert set(ch.name for ch in units["x"].charts) == {"m", "c", "k"}  # delay is all null
    summary = result.summary()
    assert summary["false_alarm_rate"] == pytest.approx(ALPHA)
    assert summary["units"][1]["parameters"]["c"]["flagged"] == 4
    assert "flagged points" in result.report()


def test_trend_cli_table_json_and_figures(fleet_file, tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["trend", str(fleet_file), "--plots", str(tmp_path / "figs"),
                              "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["by"] == "axis" and [u["unit"] for u in out["units"]] == ["x", "y"]
    assert out["units"][1]["parameters"]["c"]["flagged"] == 4
    pngs = sorted(p.name for p in (tmp_path / "figs").iterdir())
    assert pngs == ["trend-x.png", "trend-y.png"]
    assert all((tmp_path / "figs" / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    # the CSV beside the Parquet file gives the same chart
    res_csv = runner.invoke(app, ["trend", str(tmp_path / "results.csv"), "--json"])
    assert res_csv.exit_code == 0, res_csv.output
    assert json.loads(res_csv.stdout)["units"] == out["units"]
    # the text table: one line per unit and parameter
    res_txt = runner.invoke(app, ["trend", str(fleet_file)])
    assert res_txt.exit_code == 0
    assert sum(line.startswith(("x ", "y ")) for line in res_txt.stdout.splitlines()) == 6
    # figures in the way are refused (one line), replaced with --overwrite
    again = runner.invoke(app, ["trend", str(fleet_file), "--plots", str(tmp_path / "figs")])
    assert again.exit_code == 2 and "overwrite" in again.stderr
    assert runner.invoke(app, ["trend", str(fleet_file), "--plots", str(tmp_path / "figs"),
                               "--overwrite"]).exit_code == 0


def test_a_unit_identified_with_other_options_is_warned_about():
    frame = _fleet()
    frame.loc[frame.index[:3], "options"] = '{"estimator": "ols"}'
    units = set(frame.loc[frame.index[:3], "axis"])
    warnings = trend(frame).warnings
    assert {w.split(":")[0] for w in warnings if "different options" in w} == {
        f"axis {u}" for u in units}


def test_a_unit_without_times_is_ordered_by_finished_with_a_warning(tmp_path):
    frame = _fleet()
    frame.loc[frame["axis"] == "x", "time"] = pd.NaT
    result = trend(frame)
    x = {u.unit: u for u in result.units}["x"]
    assert x.ordered_by == "finished"
    order = [p.order for p in x.charts[0].points]
    assert order == sorted(order)
    assert any("axis x" in w and "finished" in w for w in result.warnings)


@pytest.mark.parametrize("drop", ["status", "time", "axis"])
def test_a_file_that_is_not_a_batch_output_is_one_line(tmp_path, drop):
    pytest.importorskip("pyarrow")
    path = tmp_path / "other.parquet"
    _fleet().drop(columns=[drop]).to_parquet(path)
    res = CliRunner().invoke(app, ["trend", str(path)])
    assert res.exit_code == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and f"'{drop}'" in lines[0]


def test_unreadable_inputs_are_one_line(tmp_path):
    runner = CliRunner()
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"not parquet at all")
    for path, words in ((junk, "not a phoid batch output"), (tmp_path / "none.parquet",
                                                              "no such file")):
        res = runner.invoke(app, ["trend", str(path)])
        assert res.exit_code == 2 and words in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
    frame = _fleet()
    frame["status"] = "error"
    pytest.importorskip("pyarrow")
    frame.to_parquet(tmp_path / "failed.parquet")
    res = runner.invoke(app, ["trend", str(tmp_path / "failed.parquet"), "--by", "axis"])
    assert res.exit_code == 2 and "no row with status 'ok'" in res.stderr


def test_the_json_keys_are_documented(fleet_file):
    # every key `phoid trend --json` prints is named, in backticks, in docs/format.md's section
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "format.md").read_text(encoding="utf-8")
    start = doc.index("## `phoid trend --json`")
    text = doc[start:doc.index("\n## ", start + 1)]
    res = CliRunner().invoke(app, ["trend", str(fleet_file), "--json"])

    def keys(obj):
        if isinstance(obj, dict):
            return set(obj).union(*(keys(v) for v in obj.values()))
        if isinstance(obj, list):
            return set().union(*(keys(v) for v in obj))
        return set()

    names = keys(json.loads(res.stdout)) - {"m", "c", "k"}  # parameter names, not keys
    assert sorted(k for k in names if f"`{k}`" not in text) == []


@pytest.mark.slow
def test_trend_reads_what_phoid_batch_writes(tmp_path):
    # two axes, 7 nightly sets each (simulated, 3 runs of 3 s); axis B's plant loses stiffness
    # by 3 % from night 6: `phoid batch` identifies them on 2 workers, `phoid trend` flags k of
    # axis B at nights 6 and 7, and with it ω0 = √(k/m) and ζ = c/(2√(mk)), which move by
    # 1.5 %, and nothing else (the steps are many stderrs here; a false alarm among the other
    # ~20 tested points has probability ~5 %, and this seed has none)
    pytest.importorskip("distributed")
    pytest.importorskip("pyarrow")
    from phoid.dynamics import Plant
    from phoid.io import run_from_arrays, write_experiment
    from phoid.simulation import simulate

    rng = np.random.default_rng(8)
    P, D = np.array([20.0, 40.0, 60.0]), np.array([-0.5, 0.0, 0.5])
    folders = []
    for axis in ("A", "B"):
        for night in range(1, 8):
            k = 64.0 * (0.97 if axis == "B" and night >= 6 else 1.0)
            sim = simulate(Plant(2.0, 1.0, k), P, D, delay=0.01, duration=3.0, fs=500.0,
                           noise=1e-5, rng=rng)
            runs = [run_from_arrays(sim.t, sim.x[i], P=P[i], D=D[i], index=i + 1)
                    for i in range(3)]
            folder = tmp_path / "sets" / f"{axis}-{night}"
            write_experiment(folder, runs, method="pho", delay=0.01)
            manifest = folder / "experiment.toml"
            manifest.write_text(manifest.read_text(encoding="utf-8") + "\n[metadata]\n"
                                f'axis = "{axis}"\ntime = 2026-11-0{night}T02:00:00Z\n',
                                encoding="utf-8")
            folders.append(str(folder))
    runner = CliRunner()
    out = tmp_path / "results.parquet"
    res = runner.invoke(app, ["batch", *folders, "--out", str(out), "--workers", "2"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["trend", str(out), "--json"])
    assert res.exit_code == 0, res.output
    units = {u["unit"]: u for u in json.loads(res.stdout)["units"]}
    assert set(units) == {"A", "B"} and all(u["ordered_by"] == "time" for u in units.values())
    flagged = {(u, name, p["time"][:10]) for u, unit in units.items()
               for name, chart in unit["parameters"].items()
               for p in chart["points"] if p["flagged"]}
    assert flagged == {("B", name, f"2026-11-0{night}") for name in ("k", "omega0", "zeta")
                       for night in (6, 7)}
