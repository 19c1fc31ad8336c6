"""The manifest's ``[units]`` table (docs/format.md, "The `[units]` table") and the warnings
that name it where a set's time axis is implausible for its loop.

Sets in other units are made from SI sets by shifting each cell's decimal point (Python's
``decimal``: exact), so the ms/mm set holds the very numbers of the SI set, written in other
units. Expected values therefore come from the SI set itself: the converted set must read as the
same arrays — bit for bit for a t written in whole ms (a correctly rounded division by 1000 of
an integer is the double nearest to the decimal the SI file holds), to one rounding (1 ulp)
for values that were rounded once more when read in the other unit — and so identify the same
m, c, k to rounding.
"""

from __future__ import annotations

import gzip
import json
import shutil
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid
from phoid.cli import app
from phoid.errors import ExperimentError
from phoid.io import read_experiment, write_experiment
from phoid.io.units import check_units, unit_hint

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
runner = CliRunner()

# powers of ten by which a unit's numbers exceed the SI ones (0.001 s = 1 ms)
SHIFT = {"ms": 3, "us": 6, "mm": 3, "um": 6, "kN": -3, "mN": 3}
# The identifications compared here see data that differ by at most one rounding (1 ulp,
# 1.1e-16 relative); the estimates move by that times the fit's condition number, which for
# these small, well-posed sets is far below 1e7, so 1e-9 relative cannot fail by rounding and
# still catches any real rescaling (a unit off by even 1e-6 relative)
REL = 1e-9


def convert(src: Path, dst: Path, units: dict[str, str], *, declare: bool = True) -> Path:
    """Copy the set ``src`` to ``dst`` with the columns of ``units`` rewritten in those units
    (plain CSV), and a ``[units]`` table when ``declare``."""
    dst.mkdir(parents=True)
    manifest = (src / "experiment.toml").read_text(encoding="utf-8")
    for f in sorted(src.iterdir()):
        if not f.name.lower().endswith((".csv", ".csv.gz")):
            continue
        raw = f.read_bytes()
        text = (gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw).decode()
        lines = text.splitlines()
        head = lines[0].split(",")
        out = [lines[0]]
        for line in lines[1:]:
            if not line.strip():
                continue
            cells = line.split(",")
            out.append(",".join(
                str(Decimal(c).scaleb(SHIFT[units[h]])) if h in units else c
                for h, c in zip(head, cells, strict=True)))
        name = f.name[:-3] if f.name.lower().endswith(".gz") else f.name
        (dst / name).write_text("\n".join(out) + "\n")
        manifest = manifest.replace(f'"{f.name}"', f'"{name}"')
    if declare:
        table = "".join(f'{k} = "{v}"\n' for k, v in units.items())
        manifest += f"\n[units]\n{table}"
    (dst / "experiment.toml").write_text(manifest, encoding="utf-8")
    return dst


def same_arrays(a, b, columns=("t", "x", "u", "F", "r")):
    for ra, rb in zip(a.runs, b.runs, strict=True):
        for key in columns:
            va, vb = getattr(ra, key, None), getattr(rb, key, None)
            assert (va is None) == (vb is None), key
            if va is not None:
                np.testing.assert_array_max_ulp(va, vb, maxulp=1)


def estimates(result) -> np.ndarray:
    return np.array([result.m.value, result.c.value, result.k.value])


# --- pho --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ms_sample(tmp_path_factory):
    """examples/paper-sample with t in ms and x in mm, declared in [units]."""
    return convert(SAMPLE, tmp_path_factory.mktemp("units") / "ms", {"t": "ms", "x": "mm"})


def test_pho_in_ms_and_mm_reads_as_the_si_set(ms_sample):
    si, ms = read_experiment(SAMPLE), read_experiment(ms_sample)
    same_arrays(si, ms)
    # t was written to the ms (whole numbers): its conversion is exact
    for a, b in zip(si.runs, ms.runs, strict=True):
        np.testing.assert_array_equal(a.t, b.t)
    assert "units" not in ms.extra  # converted, not kept


def test_pho_in_ms_and_mm_identifies_the_same_plant(ms_sample):
    si = phoid.identify(read_experiment(SAMPLE))
    ms = phoid.identify(read_experiment(ms_sample))
    np.testing.assert_allclose(estimates(ms), estimates(si), rtol=REL)
    assert ms.warnings == si.warnings


def test_pho_in_ms_without_units_gets_the_warning(tmp_path):
    folder = convert(SAMPLE, tmp_path / "ms", {"t": "ms"}, declare=False)
    result = phoid.identify(read_experiment(folder))
    hint = [w for w in result.warnings if '[units] t = "ms"' in w]
    assert hint, result.warnings
    assert "time axis" in hint[0]


def test_pho_x_in_mm_without_units_names_them_in_the_u_check(tmp_path):
    # x read 1000× too large: u = −(P x + D ẋ)(t − Δt) holds only scaled by 1e-3, which the
    # check of the recorded u against the gains reports, naming the two unit mistakes that
    # give that scale (m, c, k come from the modes alone, which x's unit does not change)
    folder = convert(SAMPLE, tmp_path / "mm", {"x": "mm"}, declare=False)
    result = phoid.identify(read_experiment(folder))
    (warning,) = [w for w in result.warnings if "recorded u contradicts" in w]
    assert '[units] x = "mm"' in warning and '[units] u = "kN"' in warning


def test_read_write_round_trip_stays_si(ms_sample, tmp_path):
    first = read_experiment(ms_sample)
    write_experiment(tmp_path / "back", first.runs, method=first.method, loop=dict(first.loop),
                     title=first.title)
    manifest = (tmp_path / "back" / "experiment.toml").read_text()
    assert "[units]" not in manifest
    back = read_experiment(tmp_path / "back")
    for a, b in zip(first.runs, back.runs, strict=True):
        np.testing.assert_array_equal(a.t, b.t)  # phoid writes round-trip digits
        np.testing.assert_array_equal(a.x, b.x)


def test_extra_cannot_smuggle_a_units_table(ms_sample, tmp_path):
    first = read_experiment(ms_sample)
    with pytest.raises(ExperimentError, match="units"):
        write_experiment(tmp_path / "w", first.runs, method="pho", loop=dict(first.loop),
                         extra={"units": {"t": "ms"}})


def test_cli_reads_units_and_json_is_unchanged(ms_sample):
    a = json.loads(runner.invoke(app, ["identify", str(SAMPLE), "--json"]).stdout)
    b = json.loads(runner.invoke(app, ["identify", str(ms_sample), "--json"]).stdout)
    assert set(a) == set(b)  # the JSON's shape does not depend on [units]
    for q in "mck":
        assert b[q]["value"] == pytest.approx(a[q]["value"], rel=REL)


# --- bad [units] --------------------------------------------------------------------------------

@pytest.mark.parametrize(("table", "needles"), [
    ('v = "mm/s"', ["[units]", "'v'", "t (time), x (length), u (force), F (force)"]),
    ('t = "sec"', ["[units]", "t = 'sec'", "allowed: s, ms, us, µs, min"]),
    ('x = "MM"', ["[units]", "x = 'MM'", "allowed: m, mm, um, µm, nm, in"]),
    ('F = "kn"', ["[units]", "F = 'kn'", "allowed: N, kN, mN, lbf"]),
    ("t = 0.001", ["[units]", "'t' must be a unit name", "allowed time units: s, ms"]),
    ('T = "ms"', ["[units]", "did you mean 't'"]),
])
def test_bad_units_are_one_line_naming_file_key_and_units(tmp_path, table, needles):
    folder = tmp_path / "bad"
    shutil.copytree(SAMPLE, folder)
    with open(folder / "experiment.toml", "a", encoding="utf-8") as f:
        f.write(f"\n[units]\n{table}\n")
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and str(folder / "experiment.toml") in msg
    for needle in needles:
        assert needle in msg, msg
    r = runner.invoke(app, ["identify", str(folder)])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "[units]" in r.output


def test_units_must_be_a_table(tmp_path):
    folder = tmp_path / "bad"
    shutil.copytree(SAMPLE, folder)
    text = (folder / "experiment.toml").read_text()
    (folder / "experiment.toml").write_text('units = "ms"\n' + text)
    with pytest.raises(ExperimentError, match=r"'units' must be a table"):
        read_experiment(folder)


def test_si_units_change_nothing():
    assert check_units("m.toml", {"t": "s", "x": "m", "u": "N", "F": "N"}, "pho") == {}


def test_every_unit_converts_by_its_definition():
    # the definitions (SI brochure; 1 in = 25.4 mm and 1 lbf = 4.4482216152605 N exactly)
    cases = {("t", "ms"): 1e-3, ("t", "us"): 1e-6, ("t", "µs"): 1e-6, ("t", "min"): 60.0,
             ("x", "mm"): 1e-3, ("x", "um"): 1e-6, ("x", "nm"): 1e-9, ("x", "in"): 0.0254,
             ("u", "kN"): 1e3, ("F", "mN"): 1e-3, ("F", "lbf"): 4.4482216152605}
    for (key, unit), factor in cases.items():
        (_, mul, div), = check_units("m.toml", {key: unit}, "pho").values()
        assert mul / div == pytest.approx(factor, rel=1e-15), (key, unit)


def test_unit_hint_names_the_likely_unit():
    assert 'give [units] t = "ms"' in unit_hint("t", 1000.0)
    assert 'give [units] t = "us"' in unit_hint("t", 1.1e6)
    assert 'give [units] t = "min"' in unit_hint("t", 1 / 60)
    assert 'give [units] x = "mm"' in unit_hint("x", 900.0)
    assert 'give [units] F = "kN"' in unit_hint("F", 1e-3)
    assert unit_hint("t", 5.0) == "" and unit_hint("t", float("nan")) == ""


# --- forced -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def forced_si(tmp_path_factory):
    out = tmp_path_factory.mktemp("forced") / "si"
    r = runner.invoke(app, ["simulate", str(out), "--method", "forced", "--m", "2", "--c", "1",
                            "--k", "64", "--omega", "3,5,6,7,9", "--noise", "1e-6",
                            "--seed", "2", "--duration", "20"])
    assert r.exit_code == 0, r.output
    return out


def test_forced_in_ms_mm_kn_identifies_the_same_plant(forced_si, tmp_path):
    units = {"t": "ms", "x": "mm", "F": "kN"}
    folder = convert(forced_si, tmp_path / "ms", units)
    si, other = read_experiment(forced_si), read_experiment(folder)
    same_arrays(si, other)
    a, b = phoid.identify(si), phoid.identify(other)
    np.testing.assert_allclose(estimates(b), estimates(a), rtol=REL)


def test_forced_in_ms_without_units_names_them(forced_si, tmp_path):
    folder = convert(forced_si, tmp_path / "ms", {"t": "ms"}, declare=False)
    result = phoid.identify(read_experiment(folder))
    # each run's manifest omega (rad/s, SI) is 1000× the frequency read from F
    assert any('give [units] t = "ms"' in w for w in result.warnings), result.warnings


# --- tracking -----------------------------------------------------------------------------------

def _tracking_si(folder: Path) -> Path:
    """One tracking run from the exact loop simulator (a small axis under a 1 kHz PD loop;
    tests/test_tracking_cli.py's recipe), written by phoid in SI."""
    ctrl = phoid.SampledController(sample_time=1e-3, P=4000.0, D=60.0,
                                   velocity="central-difference", saturation=200.0)
    n = 3000
    t = 1e-3 * np.arange(n)
    r = 0.02 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * np.sin(2 * np.pi * 1.9 * t + 0.3)
    sim = phoid.simulate_tracking(phoid.Plant(2.0, 15.0, 0.0, 1.5), ctrl, r, offset=-0.3,
                                  x_init=[0.0])
    run = phoid.run_from_arrays(t, sim.x, r=r, u=sim.command, P=4000.0, D=60.0, index=1)
    loop = {"sample_time": 1e-3, "velocity": "central-difference", "saturation": 200.0,
            "delay": 0.0}
    write_experiment(folder, [run], method="tracking", fixed={"k": 0.0}, loop=loop)
    return folder


def test_tracking_in_ms_and_mm_identifies_the_same_plant(tmp_path):
    si_folder = _tracking_si(tmp_path / "si")
    folder = convert(si_folder, tmp_path / "ms", {"t": "ms", "x": "mm", "r": "mm"})
    si, other = read_experiment(si_folder), read_experiment(folder)
    same_arrays(si, other, columns=("t", "x", "r", "u"))
    a = phoid.identify(si, estimator="idim")
    b = phoid.identify(other, estimator="idim")
    # IDIM differentiates x twice: a 1-ulp change of x becomes ~(ωT)⁻² ≈ 10⁴ ulp of the
    # acceleration (ω = 2π·1.9 rad/s, T = 1 ms), times the regression's condition number;
    # 1e-6 relative leaves room for that and still catches a unit off by any real factor
    for key in ("m", "c", "fc", "offset"):
        assert b.estimates[key].value == pytest.approx(a.estimates[key].value, rel=1e-6)


def test_tracking_in_ms_without_units_names_them(tmp_path):
    folder = convert(_tracking_si(tmp_path / "si"), tmp_path / "ms", {"t": "ms"},
                     declare=False)
    with pytest.raises(ValueError) as info:
        phoid.identify(read_experiment(folder), estimator="idim")
    assert 'give [units] t = "ms"' in str(info.value)


def test_tracking_refuses_units_for_command_columns(tmp_path):
    folder = _tracking_si(tmp_path / "si")
    with open(folder / "experiment.toml", "a", encoding="utf-8") as f:
        f.write('\n[units]\nu = "N"\n')
    with pytest.raises(ExperimentError, match="command units"):
        read_experiment(folder)


# --- a digital pho loop -------------------------------------------------------------------------

def test_digital_pho_in_ms_without_units_names_them(tmp_path):
    si_folder = tmp_path / "si"
    r = runner.invoke(app, ["simulate", str(si_folder), "--sample-time", "0.002",
                            "--delay-samples", "3", "--fs", "500", "--P", "0.25:25:6",
                            "--D", "0.6:6:6", "--noise", "1e-5", "--seed", "1"])
    assert r.exit_code == 0, r.output
    si = phoid.identify(read_experiment(si_folder))
    assert not any("[units]" in w for w in si.warnings), si.warnings
    folder = convert(si_folder, tmp_path / "ms", {"t": "ms"}, declare=False)
    # the records' step (2 "s") is 1000 controller periods (sample_time 0.002 s). Read as
    # seconds, every mode is 1000× too slow; whether the weighted fit of m, c, k still
    # converges on such rates depends on the CPU's rounding (it does on some x86-64 machines,
    # not on others), so either outcome is right as long as it names the cause and the cure:
    # a result with the hint among its warnings, or a refusal whose one line gives it.
    try:
        result = phoid.identify(read_experiment(folder))
    except phoid.PhoidError as exc:
        message = str(exc)
        assert "\n" not in message, message
        assert "ms" in message and '[units] t = "ms"' in message, message
    else:
        hint = [w for w in result.warnings if "sampled every" in w]
        assert hint and '[units] t = "ms"' in hint[0], result.warnings
    declared = phoid.identify(read_experiment(convert(si_folder, tmp_path / "d", {"t": "ms"})))
    np.testing.assert_allclose(estimates(declared), estimates(si), rtol=REL)
