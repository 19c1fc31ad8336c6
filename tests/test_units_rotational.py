"""Rotational sets and sensor units (docs/format.md, "The `[units]` table"): ``[units] x`` as
an angle (rad, mrad, deg, rev; converted to rad, results labelled J in kg m^2, N m s/rad,
N m/rad) or as a raw sensor signal (V, counts, ``{signal = "…"}``; not converted, only σ, ω₀,
ζ, c/m and k/m identifiable, so refused with a mass and in pho, forced and tracking sets).

Records come from the exact free response x = A e^(−σt) cos(ω_d t) written out here; the deg
file holds the very numbers of the rad file times 180/π, so the two must read as the same arrays
to one rounding and identify the same σ, ω₀ (expected values: the rad set's own).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from phoid.cli import app
from phoid.errors import ExperimentError
from phoid.io import read_experiment, run_from_arrays, write_experiment
from phoid.io.units import check_units, quantity_unit, relabel
from phoid.methods.free import identify_free

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
REAL = ROOT.parent / "shared" / "data" / "real"
runner = CliRunner()
no_shared = pytest.mark.skipif(not REAL.is_dir(), reason="the real records (../shared/data/real)"
                               " are not in this checkout; they may not be committed")

FS, N = 200.0, 2000
SIGMA, OMEGA_D = 0.4, 9.0


def decay() -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(N) / FS
    noise = 1e-5 * np.random.default_rng(1).standard_normal(N)
    return t, 0.3 * np.exp(-SIGMA * t) * np.cos(OMEGA_D * t) + noise  # rad


def write_csv(folder: Path, t: np.ndarray, x: np.ndarray, manifest: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    rows = "\n".join(f"{float(a)!r},{float(b)!r}" for a, b in zip(t, x, strict=True))
    (folder / "run01.csv").write_text("t,x\n" + rows + "\n", encoding="utf-8")
    (folder / "experiment.toml").write_text(manifest + '\n[[run]]\nfile = "run01.csv"\n',
                                            encoding="utf-8")
    return folder


def free_set(tmp_path: Path, units: str, scale: float = 1.0, extra: str = "") -> Path:
    t, x = decay()
    return write_csv(tmp_path / units.replace(" ", "_").replace('"', "").replace("=", ""),
                     t, x * scale, f'method = "free"\n{extra}[units]\n{units}\n')


# --- angles -----------------------------------------------------------------------------------

def test_angles_convert_by_their_definition():
    cases = {"mrad": 1e-3, "deg": math.pi / 180, "rev": 2 * math.pi}
    for unit, factor in cases.items():
        (_, mul, div), = check_units("m.toml", {"x": unit}, "free").values()
        assert mul / div == pytest.approx(factor, rel=1e-15), unit
    assert check_units("m.toml", {"x": "rad"}, "pho") == {}
    (_, mul, div), = check_units("m.toml", {"x": "rad", "u": "kN m"}, "pho").values()
    assert mul / div == 1e3


def test_a_free_decay_in_degrees_is_the_one_in_radians(tmp_path):
    rad = read_experiment(free_set(tmp_path, 'x = "rad"'))
    deg = read_experiment(free_set(tmp_path, 'x = "deg"', 180 / math.pi))
    assert rad.x_unit == deg.x_unit == "rad"
    # x·(180/π)·(π/180): two roundings of the deg file's numbers (≤ 4 ulp apart)
    np.testing.assert_array_max_ulp(deg.runs[0].x, rad.runs[0].x, maxulp=4)
    a, b = identify_free(rad, mass=2e-3), identify_free(deg, mass=2e-3)
    for key in ("sigma", "omega0", "zeta"):
        # data equal to a few ulp move a well-posed fit far below 1e-9 relative
        assert getattr(b, key).value == pytest.approx(getattr(a, key).value, rel=1e-9)
    # the truth: ω₀ = √(σ² + ω_d²); noise 1e-5 on 0.3 rad: stderr ~1e-6 relative
    assert a.omega0.value == pytest.approx(math.hypot(SIGMA, OMEGA_D), rel=1e-4)
    assert (b.m.unit, b.c.unit, b.k.unit) == ("kg m^2", "N m s/rad", "N m/rad")
    s = b.summary()
    assert s["x_unit"] == "rad" and s["c"]["unit"] == "N m s/rad"
    text = b.report()
    assert "moment of inertia J = 0.002 kg m²" in text and _unit_below(text, "x0") == "rad"
    assert _unit_below(text, "v0") == "rad/s" and " N s/m" not in text


def test_a_rotational_sets_forces_are_torques(tmp_path):
    folder = tmp_path / "p"
    shutil.copytree(SAMPLE, folder)
    with open(folder / "experiment.toml", "a", encoding="utf-8") as f:
        f.write('\n[units]\nx = "deg"\nu = "N"\n')
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and "u = 'N' is not a torque unit" in msg, msg
    assert "x is an angle" in msg and "N m" in msg


def test_a_rotational_set_written_back_keeps_its_angle(tmp_path):
    exp = read_experiment(free_set(tmp_path, 'x = "deg"', 180 / math.pi))
    back = read_experiment(write_experiment(tmp_path / "w", exp))
    assert back.x_unit == "rad"
    np.testing.assert_array_equal(back.runs[0].x, exp.runs[0].x)


# --- sensor units -----------------------------------------------------------------------------

@pytest.mark.parametrize(("units", "label"), [
    ('x = "V"', "V"), ('x = "counts"', "counts"), ('x = {signal = "uT"}', "uT")])
def test_a_free_decay_in_sensor_units_gives_rates_labelled_in_its_unit(tmp_path, units, label):
    folder = free_set(tmp_path, units, 1e3)
    exp = read_experiment(folder)
    assert exp.x_unit == label
    np.testing.assert_array_equal(exp.runs[0].x, decay()[1] * 1e3)  # not converted
    r = runner.invoke(app, ["identify", str(folder), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["x_unit"] == label and not {"m", "c", "k"} & set(s)
    assert s["omega0"]["value"] == pytest.approx(math.hypot(SIGMA, OMEGA_D), rel=1e-4)
    text = runner.invoke(app, ["identify", str(folder)]).stdout
    assert _unit_below(text, "x0") == label and _unit_below(text, "v0") == f"{label}/s"
    assert f"x is in sensor units, {label}" in " ".join(text.split())
    back = read_experiment(write_experiment(tmp_path / "w", exp))
    assert back.x_unit == label


def _unit_below(text: str, name: str) -> str:
    """The runs table's unit of column ``name``: the header row names the columns, the row
    below gives their units, each right-aligned with its name (text reports since issue 30)."""
    lines = text.splitlines()
    i = next(i for i, x in enumerate(lines) if x.split()[:1] == ["run"] and name in x.split())
    end = lines[i].index(f" {name}") + 1 + len(name)
    return lines[i + 1][:end].split("  ")[-1].strip()


def test_a_mass_with_sensor_units_is_refused(tmp_path):
    folder = free_set(tmp_path, 'x = "V"')
    r = runner.invoke(app, ["identify", str(folder), "--mass", "2"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "c and k need x in a length or an angle unit" in r.output
    folder = free_set(tmp_path / "m", 'x = "V"', extra="mass = 2.0\n")
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and "key 'mass'" in msg and "length or an angle" in msg, msg


@pytest.mark.parametrize("units", ['x = "V"', 'x = {signal = "lux"}'])
def test_pho_and_forced_sets_in_sensor_units_are_refused(tmp_path, units):
    folder = tmp_path / "p"
    shutil.copytree(SAMPLE, folder)
    with open(folder / "experiment.toml", "a", encoding="utf-8") as f:
        f.write(f"\n[units]\n{units}\n")
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and "is a sensor unit, not a position" in msg, msg
    assert "a pho set's gains" in msg
    r = runner.invoke(app, ["identify", str(folder)])
    assert r.exit_code == 2 and r.output.count("\n") == 1
    for method in ("forced", "tracking"):
        with pytest.raises(ExperimentError, match=f"a {method} set's"):
            check_units("m.toml", {"x": "V"}, method)


@pytest.mark.parametrize(("value", "needle"), [
    ('"volts"', "x = 'volts' is not a unit phoid knows"),
    ('{signal = "mm"}', "not a length, angle, time or force unit"),
    ('{signal = ""}', "the signal's unit must be a name"),
    ('{signal = 3}', "the signal's unit must be a name"),
    ('{signal = "V", gain = 2}', "x as a table must be {signal"),
    ("1.0", "key 'x' must be a unit name"),
])
def test_bad_x_units_are_one_line(tmp_path, value, needle):
    t, x = decay()
    folder = write_csv(tmp_path / "b", t, x, f'method = "free"\n[units]\nx = {value}\n')
    with pytest.raises(ExperimentError) as info:
        read_experiment(folder)
    msg = str(info.value)
    assert "\n" not in msg and "[units]" in msg and needle in msg, msg


def test_relabel_maps_every_unit_of_a_summary():
    summary = {"m": {"value": 1.0, "unit": "kg"}, "runs": [{"x0": 1.0}],
               "covariance": {"params": ["m", "c", "k"], "units": ["kg", "N s/m", "N/m"]},
               "omega0": {"unit": "rad/s"}, "fc": {"unit": "N"}}
    out = relabel(summary, "rad")
    assert out["m"]["unit"] == "kg m^2" and out["fc"]["unit"] == "N m"
    assert out["covariance"]["units"] == ["kg m^2", "N m s/rad", "N m/rad"]
    assert out["omega0"]["unit"] == "rad/s" and summary["m"]["unit"] == "kg"  # input kept
    assert relabel(summary, "m") is summary
    assert quantity_unit("m", "V") == "V" and quantity_unit("m/s", "counts") == "counts/s"


def test_in_memory_sets_check_x_unit():
    run = run_from_arrays(np.arange(20) / 10.0, np.sin(np.arange(20.0)), P=1.0, D=0.1)
    from phoid.io import ExperimentSet

    with pytest.raises(ExperimentError, match="sensor unit, not a position"):
        ExperimentSet(path=Path("m.toml"), runs=(run,), method="pho", x_unit="V")
    with pytest.raises(ExperimentError, match="`x_unit` must be"):
        ExperimentSet(path=Path("m.toml"), runs=(run,), method="pho", x_unit=3)


# --- the real records -------------------------------------------------------------------------

@no_shared
def test_real_pendulum_in_degrees_is_the_radian_set(tmp_path):
    # convert.py there wrote x = radians(angle in deg) with 7 decimals; the deg file here holds
    # those numbers times 180/π, so both read as the same radians to a few ulp
    rad = read_experiment(REAL / "pendulum")
    run = rad.runs[0]
    folder = write_csv(tmp_path / "deg", run.t, np.degrees(run.x),
                       'method = "free"\n[units]\nx = "deg"\n')
    deg = read_experiment(folder)
    a, b = identify_free(rad, mass=5e-4), identify_free(deg, mass=5e-4)
    for key in ("sigma", "omega0"):
        assert getattr(b, key).value == pytest.approx(getattr(a, key).value, rel=1e-9)
    assert (b.m.unit, b.c.unit, b.k.unit) == ("kg m^2", "N m s/rad", "N m/rad")
    # the README's k_t = J ω₀² = 5e-4 kg m² × 21.76² = 0.2368 N m/rad
    assert b.k.value == pytest.approx(0.2368, rel=1e-3)


@no_shared
def test_real_seismometer_in_volts(tmp_path):
    folder = tmp_path / "blow"
    shutil.copytree(REAL / "seismometer" / "blow", folder)
    with open(folder / "experiment.toml", "a", encoding="utf-8") as f:
        f.write('\n[units]\nx = "V"\n')  # its README: x is a position sensor's voltage
    r = runner.invoke(app, ["identify", str(folder), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["x_unit"] == "V" and "c" not in s
    # the README's phoid ω₀ for this record: 0.4046 rad/s
    assert s["omega0"]["value"] == pytest.approx(0.4046, rel=1e-3)
    r = runner.invoke(app, ["identify", str(folder), "--mass", "1"])
    assert r.exit_code == 2 and "length or an angle unit" in r.output
