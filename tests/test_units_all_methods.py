"""Every method's result labelled by its set's x unit, in one place (the registry's
``labelled``), and the set's reading notes among every method's warnings (issue 27: "angles
cannot be declared … and reports label rad, V and m/s² as m").

The sets are written here: examples/paper-sample with its x column converted to degrees
(np.degrees of the metres, 17 significant digits: the rotational set whose angles in rad are
the example's numbers, to one rounding), and a Coulomb decay in rad integrated by
scipy.integrate.solve_ivp (independent of phoid's exact model).
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from typer.testing import CliRunner

import phoid
from phoid.cli import app

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _cli(*args: object) -> str:
    r = runner.invoke(app, [str(a) for a in args])
    assert r.exit_code == 0, (args, r.output)
    return r.stdout


def _deg_pho_set(folder: Path, *, sample_rate: bool = False) -> Path:
    """examples/paper-sample (four of its runs, for speed) with x written in degrees and
    ``[units] x = "deg"``; with ``sample_rate`` its t rebuilt from a stated 1 kHz (the
    example's own rate), which the reader notes."""
    src = ROOT / "examples" / "paper-sample"
    folder.mkdir()
    text = (src / "experiment.toml").read_text()
    blocks = text.split("[[run]]")
    head, runs = blocks[0], blocks[1:5]
    out = []
    for block in runs:
        name = block.split('file = "')[1].split('"')[0]
        with gzip.open(src / name, "rt") as fh:
            data = np.loadtxt(fh, delimiter=",", skiprows=1)
        data[:, 1] = np.degrees(data[:, 1])
        csv = name.removesuffix(".gz")
        np.savetxt(folder / csv, data, delimiter=",", header="t,x,u", comments="", fmt="%.17g")
        out.append(block.replace(name, csv))
    rate = "sample_rate = 1000.0\n" if sample_rate else ""
    manifest = head.replace('method = "pho"\n', f'method = "pho"\n{rate}')
    manifest += "".join("[[run]]" + b for b in out) + '\n[units]\nx = "deg"\n'
    (folder / "experiment.toml").write_text(manifest)
    return folder


def _coulomb(t: np.ndarray, w0sq: float, a: float, y0: float) -> np.ndarray:
    """y'' + ω₀²y + a·sgn(y') = 0 released at rest from y0 (rad), half-cycle by half-cycle
    with solve_ivp, stuck where |ω₀²y| ≤ a at a velocity zero."""
    out = np.empty_like(t)
    t_now, state, sgn = 0.0, np.array([y0, 0.0]), -math.copysign(1.0, y0)
    for _ in range(1000):  # bounded: one half-cycle per pass
        def rhs(_t, z, s=sgn):
            return [z[1], -w0sq * z[0] - a * s]

        def zero_velocity(_t, z):
            return z[1]

        zero_velocity.terminal = True
        zero_velocity.direction = -sgn
        sol = solve_ivp(rhs, (t_now, t[-1] + 1.0), state, events=zero_velocity, rtol=1e-11,
                        atol=1e-14, dense_output=True, first_step=1e-4)
        t_ev = sol.t_events[0][0] if sol.t_events[0].size else math.inf
        seg = (t >= t_now) & (t < t_ev)
        out[seg] = sol.sol(t[seg])[0]
        if t_ev > t[-1]:
            return out
        y_ev = float(sol.y_events[0][0][0])
        if abs(w0sq * y_ev) <= a:
            out[t >= t_ev] = y_ev
            return out
        t_now, state, sgn = t_ev, np.array([y_ev, 0.0]), -math.copysign(1.0, y_ev)
    raise AssertionError("more than 1000 half-cycles")


def _rad_free_set(folder: Path) -> Path:
    """A free decay in rad with Coulomb friction, its inertia given (0.5 kg m^2)."""
    folder.mkdir()
    t = np.arange(2000) / 200.0
    y = _coulomb(t, (2 * math.pi * 2.0) ** 2, 0.4, 0.1)
    x = 0.002 + y + 1e-3 * np.random.default_rng(1).standard_normal(t.size)
    np.savetxt(folder / "run01.csv", np.column_stack([t, x]), delimiter=",", header="t,x",
               comments="", fmt="%.17g")
    (folder / "experiment.toml").write_text(
        'format = "phoid/1"\nmethod = "free"\nmass = 0.5\n\n[[run]]\nfile = "run01.csv"\n\n'
        '[units]\nx = "rad"\n')
    return folder


@pytest.fixture(scope="module")
def deg_set(tmp_path_factory) -> Path:
    return _deg_pho_set(tmp_path_factory.mktemp("units") / "deg")


def test_a_pho_set_in_degrees_reports_j_and_rotational_units(deg_set):
    s = json.loads(_cli("identify", deg_set, "--json"))
    assert s["x_unit"] == "rad"
    # the rotational quantities (docs/format.md, "The [units] table")
    assert (s["m"]["unit"], s["c"]["unit"], s["k"]["unit"]) == ("kg m^2", "N m s/rad",
                                                                 "N m/rad")
    assert s["covariance"]["units"][:3] == ["kg m^2", "N m s/rad", "N m/rad"]
    text = _cli("identify", deg_set)
    # the text report writes a unit's power as a superscript (docs: one notation), JSON "^2"
    assert "kg m²" in text and "N m s/rad" in text and "N m/rad" in text
    # the runs table: names in a header row, units in the row below (P in N m/rad, resid rad)
    lines = text.splitlines()
    head = next(i for i, x in enumerate(lines) if x.split()[:2] == ["run", "P"])
    names, units = lines[head], lines[head + 1]
    p_at = names.index(" P ") + 2
    assert units[:p_at + 1].rstrip().endswith("N m/rad")
    resid = next(i for i, x in enumerate(lines) if "resid" in x.split() and x.split()[0] == "run")
    r_at = lines[resid].index("resid") + len("resid")
    assert lines[resid + 1][:r_at].rstrip().endswith("rad")
    assert " kg\n" not in text and "N s/m" not in text.replace("N m s/rad", "")


def test_the_same_runs_in_si_and_in_degrees_give_the_same_numbers(deg_set, tmp_path):
    # the four runs in SI: the deg set's numbers must be the same, only labelled differently
    si_dir = tmp_path / "si"
    si_dir.mkdir()
    manifest = (deg_set / "experiment.toml").read_text().replace('\n[units]\nx = "deg"\n', "")
    for f in deg_set.glob("*.csv"):
        data = np.loadtxt(f, delimiter=",", skiprows=1)
        data[:, 1] = np.radians(data[:, 1])
        np.savetxt(si_dir / f.name, data, delimiter=",", header="t,x,u", comments="",
                   fmt="%.17g")
    (si_dir / "experiment.toml").write_text(manifest)
    rot = phoid.identify(phoid.read_experiment(deg_set))
    lin = phoid.identify(phoid.read_experiment(si_dir))
    for key in ("m", "c", "k"):
        # 1e-9: the degree round trip's rounding (1e-16 relative) moves the fit far less
        assert getattr(rot, key).value == pytest.approx(getattr(lin, key).value, rel=1e-9)
    assert (lin.m.unit, lin.x_unit) == ("kg", "m") and (rot.m.unit, rot.x_unit) == ("kg m^2",
                                                                                     "rad")
    assert "(kg m^2)" not in lin._repr_html_() and "rad" in rot._repr_html_()


def test_the_reading_notes_reach_every_method(tmp_path):
    folder = _deg_pho_set(tmp_path / "rate", sample_rate=True)
    exp = phoid.read_experiment(folder)
    assert exp.notes  # the reader noted the rebuilt clock
    res = phoid.identify(exp)
    for note in exp.notes:
        assert note in res.warnings
    s = json.loads(_cli("identify", folder, "--json"))
    assert all(n in s["warnings"] for n in exp.notes)


def test_a_free_friction_set_in_rad_reports_rotational_units(tmp_path):
    folder = _rad_free_set(tmp_path / "rad")
    s = json.loads(_cli("identify", folder, "--friction", "--json"))
    assert s["x_unit"] == "rad" and s["friction"] is True
    assert s["fc_over_m"]["unit"] == "rad/s^2"
    assert (s["m"]["unit"], s["c"]["unit"], s["k"]["unit"], s["fc"]["unit"]) == (
        "kg m^2", "N m s/rad", "N m/rad", "N m")
    assert s["covariance"]["units"] == ["1/s", "1/s^2", "rad/s^2"]
    assert s["adequacy"]["units"] == ["1/s", "1/s^2", "rad/s^2"]
    text = _cli("identify", folder, "--friction")
    assert "moment of inertia J = 0.5 kg m²" in text
    # the runs table: "stuck at" with its unit, rad, in the units row below the names
    lines = text.splitlines()
    head = next(i for i, x in enumerate(lines) if "stuck at" in x)
    col = lines[head].index("stuck at") + len("stuck at")  # right-aligned: the unit ends there
    assert lines[head + 1][:col].endswith("rad"), lines[head:head + 2]
    assert "N m/rad" in text and "rad/s²" in text
    assert "m/s²" not in text.replace("rad/s²", "") and "^" not in text
