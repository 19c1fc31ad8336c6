"""A logger's unusable clock repaired from a stated sample rate (docs/format.md, "Time from a
sample rate"): ``sample_rate`` (Hz) in the manifest, set-wide or per run, rebuilds
t = t₀ + n/fs; the t column is then optional and only its first value read.

The records are built here from the exact free response of m x'' + c x' + k x = 0 (the closed
form x = A e^(−σt) cos(ω_d t), written out below, not phoid's simulator), sampled uniformly,
with the logger's clock replaced by bursts: every 15 samples share one time stamp, as the PC
logger of the real torsion pendulum (../shared/data/real/pendulum/raw-time) stamps them.
"""

from __future__ import annotations

import gzip
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid.cli import app
from phoid.errors import ExperimentError
from phoid.io import read_experiment, write_experiment
from phoid.methods.free import identify_free

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "real" / "pendulum"
runner = CliRunner()

FS = 250.0          # Hz, the logger's true sample rate
N = 2500            # 10 s
SIGMA, OMEGA_D = 0.3, 12.0   # 1/s, rad/s: the plant's decay rate and damped frequency


def decay(n: int = N, fs: float = FS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Uniform times and x = 0.02 e^(−σt) cos(ω_d t) + 1e-5 white noise (the exact free
    response of an underdamped plant released at rest-velocity phase 0)."""
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    x = 0.02 * np.exp(-SIGMA * t) * np.cos(OMEGA_D * t) + 1e-5 * rng.standard_normal(n)
    return t, x


def bursty(t: np.ndarray, burst: int = 15) -> np.ndarray:
    """A PC logger's stamps: each block of ``burst`` samples carries its first sample's time."""
    return t[(np.arange(t.size) // burst) * burst]


def write_set(folder: Path, columns: dict[str, np.ndarray], manifest: str,
              file: str = "run01.csv") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    names = list(columns)
    rows = np.column_stack([columns[k] for k in names])
    text = ",".join(names) + "\n" + "\n".join(",".join(repr(float(v)) for v in row)
                                             for row in rows) + "\n"
    (folder / file).write_text(text, encoding="utf-8")
    (folder / "experiment.toml").write_text(manifest, encoding="utf-8")
    return folder


FREE = 'method = "free"\n'
RUN = '[[run]]\nfile = "run01.csv"\n'


def test_a_bursty_clock_is_refused_with_the_hint(tmp_path):
    t, x = decay()
    folder = write_set(tmp_path / "s", {"t": bursty(t), "x": x}, FREE + RUN)
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and "column 't' is not strictly increasing at line 3" in msg, msg
    # the message ends with the way out: the key, and the page that documents it
    assert re.search(r"\(if the logger's clock is unusable, give `sample_rate` .*"
                     r"docs/format\.md\)$", msg), msg
    r = runner.invoke(app, ["identify", str(folder)])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "sample_rate" in r.output


def test_sample_rate_rebuilds_t_and_says_so(tmp_path):
    t, x = decay()
    t0 = 3.25  # the logger's first stamp: kept as t₀
    folder = write_set(tmp_path / "s", {"t": t0 + bursty(t), "x": x},
                       FREE + f"sample_rate = {FS}\n" + RUN)
    exp = read_experiment(folder)
    # t₀ + n/fs, computed as the docs state it (one rounding per sample)
    np.testing.assert_array_equal(exp.runs[0].t, t0 + np.arange(N) / FS)
    (note,) = exp.notes
    assert note.startswith("run 1 (run01.csv): t rebuilt from sample_rate = 250 Hz"), note
    assert "not strictly increasing" in note  # what was wrong with the file's t column
    result = identify_free(exp)
    assert note in result.warnings
    # truth: ω₀² = σ² + ω_d², ζ = σ/ω₀; 1e-5 noise on a 0.02 amplitude over 30 cycles gives
    # stderr ~1e-4 relative, so 1e-3 relative (or 1e-2 on σ, the less determined) is > 5 stderr
    w0 = math.hypot(SIGMA, OMEGA_D)
    assert result.omega0.value == pytest.approx(w0, rel=1e-3)
    assert result.sigma.value == pytest.approx(SIGMA, rel=1e-2)
    out = runner.invoke(app, ["identify", str(folder), "--json"])
    assert out.exit_code == 0, out.output
    assert any("t rebuilt from sample_rate" in w for w in json.loads(out.stdout)["warnings"])


def test_the_t_column_is_optional_with_a_sample_rate(tmp_path):
    _t, x = decay()
    folder = write_set(tmp_path / "s", {"x": x}, FREE + f"sample_rate = {FS}\n" + RUN)
    exp = read_experiment(folder)
    np.testing.assert_array_equal(exp.runs[0].t, np.arange(N) / FS)  # t₀ = 0 without a t
    assert exp.notes == ()  # nothing was overridden


def test_a_runs_own_rate_overrides_the_sets(tmp_path):
    t, x = decay()
    manifest = (FREE + "sample_rate = 1000.0\n" + '[[run]]\nfile = "a.csv"\nsample_rate = 250.0\n'
                + '[[run]]\nfile = "b.csv"\n')
    folder = write_set(tmp_path / "s", {"t": bursty(t), "x": x}, manifest, "a.csv")
    write_set(folder, {"t": bursty(t), "x": x[::-1].copy()}, manifest, "b.csv")
    exp = read_experiment(folder)
    assert exp.runs[0].t[1] == 1 / 250.0 and exp.runs[1].t[1] == 1 / 1000.0
    assert len(exp.notes) == 2


def test_a_good_t_column_overridden_is_compared(tmp_path):
    t, x = decay()
    folder = write_set(tmp_path / "s", {"t": t * 1.01, "x": x},
                       FREE + f"sample_rate = {FS}\n" + RUN)
    (note,) = read_experiment(folder).notes
    assert "1.00% off the rebuilt" in note, note  # a clock 1 % fast: its span is 1 % long


def test_t_units_apply_to_t0(tmp_path):
    t, x = decay()
    folder = write_set(tmp_path / "s", {"t": 1000.0 * (2.0 + bursty(t)), "x": x},
                       FREE + f"sample_rate = {FS}\n[units]\nt = \"ms\"\n" + RUN)
    run = read_experiment(folder).runs[0]
    assert run.t[0] == 2.0 and run.t[1] == 2.0 + 1 / FS


@pytest.mark.parametrize(("value", "needle"), [
    ('"250"', "key 'sample_rate' must be a number"),
    ("true", "key 'sample_rate' must be a number"),
    ("0.0", "key 'sample_rate' must be > 0 Hz"),
    ("-250.0", "key 'sample_rate' must be > 0 Hz"),
    ("inf", "key 'sample_rate' must be finite"),
    ("nan", "key 'sample_rate' must be finite"),
    ("1e31", "key 'sample_rate' must be between 1e-30 and 1e+30 Hz"),
    ("1e-31", "key 'sample_rate' must be between 1e-30 and 1e+30 Hz"),
    ("[250.0]", "key 'sample_rate' must be a number"),
])
@pytest.mark.parametrize("place", ["top", "run"])
def test_bad_sample_rates_are_one_line_naming_file_run_and_key(tmp_path, value, needle, place):
    t, x = decay(100)
    manifest = (FREE + f"sample_rate = {value}\n" + RUN if place == "top"
                else FREE + RUN + f"sample_rate = {value}\n")
    folder = write_set(tmp_path / "s", {"t": t, "x": x}, manifest)
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and str(folder / "experiment.toml") in msg and needle in msg, msg
    if place == "run":
        assert "run 1 (run01.csv)" in msg, msg
    r = runner.invoke(app, ["identify", str(folder)])
    assert r.exit_code == 2 and r.output.count("\n") == 1


def test_a_rate_too_high_for_t0_is_refused(tmp_path):
    # t₀ = 1e6 s and fs = 1e30 Hz: t₀ + n/fs rounds to t₀ for every n (1e-30 ≪ ulp(1e6))
    folder = write_set(tmp_path / "s", {"t": np.full(50, 1e6), "x": decay(50)[1]},
                       FREE + "sample_rate = 1e30\n" + RUN)
    with pytest.raises(ExperimentError, match=r"does not make usable times .* strictly "
                                              r"increasing"):
        read_experiment(folder)


def test_tracking_sets_refuse_sample_rate(tmp_path):
    t, x = decay(100)
    manifest = ('method = "tracking"\nsample_rate = 100.0\n[loop]\nsample_time = 0.01\n'
                'P = 1.0\nD = 0.1\n' + RUN)
    folder = write_set(tmp_path / "s", {"t": t, "x": x, "r": x}, manifest)
    with pytest.raises(ExperimentError, match=r"'sample_rate' is not read in a tracking set"):
        read_experiment(folder)


def test_a_rebuilt_set_written_back_reads_the_same(tmp_path):
    t, x = decay(300)
    folder = write_set(tmp_path / "s", {"t": bursty(t), "x": x},
                       FREE + f"sample_rate = {FS}\n" + RUN)
    exp = read_experiment(folder)
    again = read_experiment(write_experiment(tmp_path / "w", exp))
    np.testing.assert_array_equal(again.runs[0].t, exp.runs[0].t)
    assert "sample_rate" not in (tmp_path / "w" / "experiment.toml").read_text()


@pytest.mark.skipif(not SHARED.is_dir(), reason="the real records (../shared/data/real) are "
                                                "not in this checkout; they may not be committed")
def test_real_pendulum_raw_time_with_its_rate_equals_the_uniform_set(tmp_path):
    # the PC logger's Time_Elapsed repeats within bursts; the uniform-time set beside it was
    # made with t = n/fs, fs = 259.9741 Hz (its manifest's fs_assumed_hz; convert.py there)
    raw = SHARED / "raw-time"
    with pytest.raises(ExperimentError, match="sample_rate"):
        read_experiment(raw)
    folder = tmp_path / "raw"
    shutil.copytree(raw, folder)
    text = (folder / "experiment.toml").read_text(encoding="utf-8")
    (folder / "experiment.toml").write_text("sample_rate = 259.9741\n" + text, encoding="utf-8")
    fixed = identify_free(read_experiment(folder))
    uniform = identify_free(read_experiment(SHARED))
    assert any("t rebuilt from sample_rate" in w for w in fixed.warnings)
    with gzip.open(raw / "run01.csv.gz", "rt") as f:
        assert sum(1 for _ in f) - 1 == fixed.runs[0].n_samples  # every sample used
    for key in ("sigma", "omega0", "zeta"):
        a, b = getattr(fixed, key), getattr(uniform, key)
        # the two time axes differ only by the rate's rounding to 4 decimals (≤ 2e-7
        # relative) and t's to 6 in the uniform file: far inside one stderr
        assert abs(a.value - b.value) <= b.stderr, (key, a, b)
