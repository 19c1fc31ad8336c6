"""Hostile numbers for `phoid simulate` and hostile `[loop]` / top-level keys for `phoid identify`
(the hostile prober's findings D–H), through the real command line (typer's CliRunner).

The contract checked for each case: exit status 2, exactly one line `phoid: error: …` on stderr
naming the option (simulate) or the manifest and the key (identify); never an internal error
(exit 1), never a silently accepted value. Every case is refused before any simulation or fit
of size, so the file runs in seconds.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from phoid.cli import app

runner = CliRunner()


def _one_line_error(result, *needles: str) -> str:
    """Exit status 2 and a single 'phoid: error:' line on stderr holding every needle."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --- simulate: every number by its option ---------------------------------------------------

# each option with values it must refuse (0, -0, negative where a sign is required; nan, inf;
# 1e-300 and 1e300, beyond the 1e-30 … 1e30 magnitudes a rig's SI quantities take; the
# simulator divided by the plant's rate and raised ZeroDivisionError for --m 1e-300, --c 1e300)
_BAD = ["nan", "inf", "-inf", "1e-300", "1e300", "-1e300"]
_OPTIONS = {
    "--m": ["0", "-0", "-1", *_BAD], "--c": _BAD, "--k": _BAD, "--fc": ["-1", *_BAD],
    "--delay": ["-1", *_BAD], "--duration": ["0", "-0", "-1", *_BAD],
    "--fs": ["0", "-1", *_BAD], "--x0": _BAD, "--hold": ["-1", *_BAD],
    "--noise": ["-1", *_BAD], "--quantum": ["-1", *_BAD], "--offset": _BAD,
    "--u-noise": ["-1", *_BAD],
}


@pytest.mark.parametrize(("option", "value"),
                         [(o, v) for o, vals in _OPTIONS.items() for v in vals])
def test_simulate_number_out_of_range_names_the_option(tmp_path: Path, option: str,
                                                       value: str) -> None:
    res = runner.invoke(app, ["simulate", str(tmp_path / "s"), f"{option}={value}"])
    _one_line_error(res, f"{option} must be")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize(("args", "option"), [
    (["--sample-time=0"], "--sample-time"), (["--sample-time=1e-300"], "--sample-time"),
    (["--sample-time=nan"], "--sample-time"),
    (["--sample-time=0.001", "--velocity=filtered", "--cutoff=-1"], "--cutoff"),
    (["--sample-time=0.001", "--velocity=filtered", "--cutoff=1e300"], "--cutoff"),
    (["--method=forced", "--B=1e300"], "--B"), (["--method=forced", "--omega=0,1"], "--omega"),
    (["--method=free", "--v0=inf"], "--v0"),
    (["--seed=-1"], "--seed"),  # numpy's "expected non-negative integer" named nothing
    (["--seed=99999999999999999999999999"], "--seed"),  # no TOML integer holds it
    (["--bias=-1"], "--bias"), (["--P=1e300", "--D=1"], "--P"), (["--P=1", "--D=nan"], "--D"),
])
def test_simulate_other_options_are_named(tmp_path: Path, args: list[str], option: str) -> None:
    _one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "s"), *args]), option)


@pytest.mark.parametrize(("option", "text", "words"), [
    # the count is checked before a list is built: 1e9 values were 23 GB before
    ("--P", "1:2:1000000000", "20,000"),
    ("--omega", "2:14:100000000", "20,000"),
    ("--P", "1:2:0", "count"),
    ("--P", "1:2:1.5", "whole count"),
    ("--P", "1,,2", "value 2 is empty"),  # an empty value was dropped silently
    ("--P", "1,2,", "value 3 is empty"),
    ("--P", "1:2", "start:stop:count"),
    ("--P", "1:nan:3", "finite"),
])
def test_simulate_lists_are_checked_before_they_are_built(tmp_path: Path, option: str,
                                                          text: str, words: str) -> None:
    args = ["--method=forced"] if option == "--omega" else ["--D=1"]
    res = runner.invoke(app, ["simulate", str(tmp_path / "s"), *args, f"{option}={text}"])
    _one_line_error(res, option, words)


@pytest.mark.parametrize(("args", "option"), [
    # a delay longer than the record: the feedback never acts (1e30 s held 1e33 grid steps)
    (["--delay=2", "--duration=1"], "--delay"),
    # a command delay of 1e9 periods allocated (runs, 1e9) arrays (MemoryError, exit 1)
    (["--sample-time=0.001", "--delay-samples=1000000000", "--duration=1"], "--delay-samples"),
    (["--sample-time=2", "--duration=1"], "--sample-time"),
    # a velocity filter slower than the record: the D term would not show in it
    (["--sample-time=0.001", "--velocity=filtered", "--cutoff=1e-3", "--duration=1"],
     "--cutoff"),
])
def test_simulate_loop_longer_than_the_record_is_named(tmp_path: Path, args: list[str],
                                                       option: str) -> None:
    _one_line_error(runner.invoke(app, ["simulate", str(tmp_path / "s"), *args]), option)


def test_simulate_rates_beyond_the_step_limit_are_refused_not_divided(tmp_path: Path) -> None:
    # m = 1e-30 kg with c = 1e30 N s/m: a rate of 1e60/s, far beyond MAX_STEPS (2e8) steps;
    # before, a rate that overflowed to inf divided by zero (internal error, exit 1)
    res = runner.invoke(app, ["simulate", str(tmp_path / "s"), "--m=1e-30", "--c=1e30"])
    _one_line_error(res, "internal steps")


# --- identify: the [loop] table and misplaced top-level tables ------------------------------


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """Three pho runs (m = 2 kg, c = 1 N s/m, k = 64 N/m, delay 0.1 s, 8 s at 1 kHz)."""
    out = tmp_path_factory.mktemp("hostile_inputs") / "small"
    res = runner.invoke(app, ["simulate", str(out), "--P", "1,5,10", "--D", "0.6,1,1.5",
                              "--duration", "8", "--noise", "1e-5", "--seed", "1", "--no-gzip"])
    assert res.exit_code == 0, res.output
    return out


def _edited(small: Path, tmp_path: Path, old: str, new: str) -> Path:
    folder = tmp_path / "set"
    shutil.copytree(small, folder)
    manifest = folder / "experiment.toml"
    text = manifest.read_text()
    assert old in text
    manifest.write_text(text.replace(old, new, 1))
    return folder


_LOOP = "[loop]\nnoise = \"outside\"\ndelay = 0.1\n"  # as `phoid simulate --noise` writes it


@pytest.mark.parametrize(("loop", "words"), [
    # wrong types were accepted (a string, a boolean), or blamed m ("`m` must be > 0 kg")
    ('sample_time = "0.001"\n', "[loop] sample_time must be a number"),
    ("sample_time = true\n", "[loop] sample_time must be a number"),
    ("sample_time = -0.001\n", "[loop] sample_time must be a finite number > 0"),
    ("sample_time = 0.001\ndelay_samples = 1.5\n", "[loop] delay_samples must be a whole"),
    ("sample_time = 0.001\ndelay_samples = -1\n", "[loop] delay_samples must be a whole"),
    ("sample_time = 0.001\ndelay_samples = true\n", "[loop] delay_samples must be a whole"),
    ("sample_time = 0.001\nvelocity = 3\n", "[loop] velocity must be one of"),
    ('sample_time = 0.001\nvelocity = "filtered"\ncutoff = "100"\n',
     "[loop] cutoff must be a number"),
    ('sample_time = 0.001\nvelocity = "filtered"\ncutoff = true\n',
     "[loop] cutoff must be a number"),
    # values the 8 s records cannot show: named, not "no usable runs: … window [1.5e+300, …]"
    ("sample_time = 1e300\n", "[loop] sample_time = 1e+300 s is longer than the record"),
    ("sample_time = 0.01\ndelay_samples = 900\n", "[loop] delay_samples = 900 periods"),
    ("sample_time = 0.0001\ndelay_samples = 1001\n", "at most 1000 controller periods"),
    ('sample_time = 0.001\ndelay_samples = 100\nvelocity = "filtered"\ncutoff = 1e-300\n',
     "[loop] cutoff = 1e-300 rad/s"),
])
def test_identify_digital_loop_keys_are_checked(small: Path, tmp_path: Path, loop: str,
                                                words: str) -> None:
    folder = _edited(small, tmp_path, _LOOP, "[loop]\n" + loop)
    _one_line_error(runner.invoke(app, ["identify", str(folder)]), "experiment.toml", words)


@pytest.mark.parametrize(("old", "new", "words"), [
    # below the [simulated] header these were keys of [simulated]: the stated delay was lost
    (_LOOP, 'loop = "fast"\n', "[simulated] loop"),
    (_LOOP, "loop = [0.1]\n", "[simulated] loop"),
    ("[loop]\n", 'units = "ms"\n[loop]\n', "[simulated] units"),
    ("D = 0.6\n", 'D = 0.6\nunits = "ms"\n', "[[run]] 1 units"),
    # at the top level: the reader's own type checks
    ('method = "pho"\n', 'method = "pho"\nunits = "ms"\n', "'units' must be a table"),
])
def test_identify_misplaced_or_mistyped_top_level_tables(small: Path, tmp_path: Path, old: str,
                                                         new: str, words: str) -> None:
    folder = _edited(small, tmp_path, old, new)
    _one_line_error(runner.invoke(app, ["identify", str(folder)]), "experiment.toml", words)


@pytest.mark.parametrize("delay_samples", ["700", "1000"])
def test_identify_a_digital_delay_the_modes_cannot_fit_names_the_loop(
        small: Path, tmp_path: Path, delay_samples: str) -> None:
    # the runs (made with a 0.1 s continuous delay) read as a loop of 0.7 or 1 s: before, the
    # fit's start (m < 0) or a trial step whose delay powers overflow raised the library's
    # "`m` must be > 0 kg; got -1.93" or "Array must not contain infs or NaNs", naming nothing
    folder = _edited(small, tmp_path, _LOOP,
                     f"[loop]\nsample_time = 0.001\ndelay_samples = {delay_samples}\n")
    _one_line_error(runner.invoke(app, ["identify", str(folder)]), "experiment.toml",
                    "[loop] sample_time, delay_samples")


def test_identify_metadata_keys_are_the_users_whatever_their_names(small: Path,
                                                                   tmp_path: Path) -> None:
    # docs/format.md: [metadata]'s keys are the user's own (phoid batch copies them as
    # meta_<key>): a key named like a top-level table is metadata, not a misplaced table
    folder = _edited(small, tmp_path, "[loop]\n",
                     '[metadata]\nrun = "A12"\nunits = "mm"\nloop = "inner"\n\n[loop]\n')
    res = runner.invoke(app, ["identify", str(folder), "--json"])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize(("old", "new", "words"), [
    # a gain beyond 1e30 (SI) is refused by name; before: "the gains look like they have the
    # other sign" (P = 1e300) or "the weighted fit … did not converge" naming nothing
    ("P = 1.0\n", "P = 1e300\n", "run 1 (run01.csv): P = 1e+300 N/m is beyond"),
    ("D = 0.6\n", "D = 1e300\n", "run 1 (run01.csv): D = 1e+300"),
])
def test_identify_gain_beyond_any_loop_is_named(small: Path, tmp_path: Path, old: str, new: str,
                                                words: str) -> None:
    folder = _edited(small, tmp_path, old, new)
    _one_line_error(runner.invoke(app, ["identify", str(folder)]), "experiment.toml", words)
